//! Helpers shared by the `vfp` integration tests (each test binary uses a subset).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The workspace root, where the tests run `vfp` so that `data/real/…` paths resolve.
pub fn root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

/// A fresh, empty scratch directory `vfp-<test>-<pid>-<name>` in the target directory's `tmp`
/// (Cargo's `CARGO_TARGET_TMPDIR`: `cargo clean` removes it; nothing is left in the system's temp
/// dir).
pub fn scratch(test: &str, name: &str) -> PathBuf {
    let d = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("vfp-{test}-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir is writable");
    d
}

/// The `vfp` binary, to run in the workspace root, quietly (`--quiet`: no progress on stderr).
pub fn vfp() -> std::process::Command {
    let mut c = std::process::Command::new(env!("CARGO_BIN_EXE_vfp"));
    c.current_dir(root()).arg("--quiet");
    c
}

/// Runs `cmd` and returns its output; a failing run fails the test with the tool's own error.
pub fn ok(cmd: &mut std::process::Command) -> std::process::Output {
    let out = cmd.output().expect("vfp runs");
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}
