//! `vfp identify` refuses what it cannot do, with a clear message and a non-zero exit.

use std::path::PathBuf;
use std::process::Command;

fn write_log(name: &str, rows: usize, volume: impl Fn(f64) -> f64) -> PathBuf {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("vfp-identify-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(name);
    let mut s = String::from("time_s,volume_mm3,flow_mm3_s,pressure_kpa\n");
    for i in 0..rows {
        let t = i as f64 * 0.04;
        let (v, q) = (volume(t), 100.0 * (t * 1.3).cos());
        s.push_str(&format!("{t},{v},{q},{}\n", 1.0 + 0.01 * v + 0.002 * q));
    }
    std::fs::write(&path, s).unwrap();
    path
}

fn identify(args: &[&str]) -> (bool, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_vfp"))
        .args(["--quiet", "identify"])
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn a_log_too_short_for_a_held_out_set_is_refused() {
    let log = write_log("short.csv", 56, |t| 200.0 + 150.0 * (t * 1.3).sin());
    let (ok, err) = identify(&[log.to_str().unwrap(), "--family", "poly", "--json"]);
    assert!(!ok);
    assert!(
        err.contains("short.csv, chamber 0: too few samples") && err.contains("held-out"),
        "{err}"
    );
}

#[test]
fn nothing_fitted_is_an_error() {
    let log = write_log("flat.csv", 2_000, |_| 300.0);
    let (ok, err) = identify(&[log.to_str().unwrap(), "--family", "poly", "--json"]);
    assert!(!ok);
    assert!(
        err.contains("no model could be fitted") && err.contains("volume is constant"),
        "{err}"
    );
}

/// `identify` names the model `export` and `diagnose` use, and it is the one they use: the
/// shape and kept terms `vfp export` writes for the same log (issue 35: identify printed
/// "Selected: nn (5, 8)" while export and diagnose used a polynomial).
#[test]
fn identify_names_the_model_export_uses() {
    use crate::common::{ok, vfp};
    let log = "data/real/bag-lung-pip15-peep5.csv";
    let out = ok(vfp().args(["identify", log, "--family", "poly", "--family", "exp"]));
    let text = String::from_utf8_lossy(&out.stdout);
    let line = text
        .lines()
        .find(|l| l.starts_with("Model used by export and diagnose: poly ("))
        .unwrap_or_else(|| panic!("no model line in:\n{text}"));
    assert!(text.contains("Lowest joint cost J among the families' choices:"));
    // "poly (5, 3), 16 of its 24 terms kept (…)" against export's "(n = 5, m = 3, 16 of 24 terms".
    let shape = &line[line.find('(').unwrap() + 1..line.find(')').unwrap()];
    let (n, m) = shape.split_once(", ").unwrap();
    let kept: Vec<&str> = line.split(", ").nth(2).unwrap().split(' ').collect();
    let (k, total) = (kept[0], kept[3]);
    let export = ok(vfp().args(["export", log]));
    let export = String::from_utf8_lossy(&export.stdout);
    let expected = format!("(n = {n}, m = {m}, {k} of {total} terms");
    assert!(export.contains(&expected), "{line}\n{expected}\n{export}");
}
