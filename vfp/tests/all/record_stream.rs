//! `vfp record -` as it is used on the rig: telemetry piped in, ended by Ctrl-C while the pipe is
//! still open (or by SIGTERM, or by the end of input). The frames are the firmware's own
//! telemetry lines ([`Frame::encode`]) as `probe-rs run` prints them; the test waits until the
//! tool has put the last frame's rows in the file (rows are written as frames arrive), then
//! signals it and checks that the log it leaves is a valid log holding every frame, value for
//! value, with its totals.

#![cfg(unix)]

use crate::common;

use firmware::telemetry::{ChamberFrame, Flags, Frame};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, Command, Output, Stdio};

const FRAMES: u32 = 1_500;

fn scratch(name: &str) -> PathBuf {
    common::scratch("record", name)
}

/// Frame `seq` at 25 Hz with values that differ per frame and chamber.
fn frame(seq: u32) -> Frame {
    let x = seq as f32;
    let chamber = |c: usize| ChamberFrame {
        v: 0.04 * x + 100.0 * c as f32,
        vdot: 20.0 + c as f32 - 0.001 * x,
        p: 0.125 + 0.0031 * x + c as f32,
        p_hat: 0.12 + 0.003 * x,
        residual: 0.005 + 0.0001 * x,
        k: 0.0025,
        c: 0.0001,
    };
    Frame {
        seq,
        t_us: 40_000 * (u64::from(seq) + 1),
        flags: Flags(if seq < 3 { Flags::NOT_ZEROED } else { 0 }),
        force_n: -0.001 * x,
        chambers: [chamber(0), chamber(1), chamber(2)],
        drops: 0,
    }
}

/// The frames as `probe-rs run` prints them: timestamp and level in front, location after.
fn capture() -> String {
    let mut s = String::from("     Running `probe-rs run --chip STM32F446RETx vfp-fw`\n");
    for seq in 0..FRAMES {
        let mut line = String::new();
        frame(seq).encode(&mut line).expect("encodes");
        let t = frame(seq).t_us as f64 * 1e-6;
        s += &format!(
            "{t:.6} INFO {line}\n└─ vfp_fw::__sampler_task @ firmware/src/bin/vfp-fw.rs:56\n"
        );
    }
    s
}

fn spawn(out: &Path) -> (Child, ChildStdin) {
    let mut child = Command::new(env!("CARGO_BIN_EXE_vfp"))
        .args(["--quiet", "record", "-", "-o"])
        .arg(out)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("vfp runs");
    let stdin = child.stdin.take().expect("piped");
    (child, stdin)
}

/// Data rows in the file so far (whole lines only).
fn rows_on_disk(out: &Path) -> usize {
    let text = std::fs::read_to_string(out).unwrap_or_default();
    let complete = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
    complete
        .lines()
        .filter(|l| !l.starts_with('#') && !l.starts_with("time_s"))
        .count()
}

/// Waits until the tool has written every frame's rows: the proof that rows reach the file while
/// the pipe is still open. (The bound only turns a hang into a failure; nothing is timed.)
fn wait_for_all_rows(out: &Path, child: &mut Child) {
    for _ in 0..6_000 {
        if rows_on_disk(out) == 3 * FRAMES as usize {
            return;
        }
        if let Some(status) = child.try_wait().expect("child state") {
            panic!("vfp record exited early: {status}");
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    panic!(
        "after 120 s only {} of {} rows reached {}",
        rows_on_disk(out),
        3 * FRAMES,
        out.display()
    );
}

/// Checks the log holds every frame exactly, and the totals, and returns the summary text.
fn check_log(out: &Path, output: &Output, stopped: &str) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "{:?}\n{stderr}", output.status);
    assert!(
        stderr.contains(&format!("{FRAMES} frames ({} log rows)", 3 * FRAMES)),
        "{stderr}"
    );
    assert!(stderr.contains("missing frames: 0 in 0 gap(s)"), "{stderr}");
    assert!(
        stderr.contains(&format!("stopped by {stopped}")),
        "{stderr}"
    );

    let log = sysid::log::read_log(out).expect("a complete, valid log");
    assert_eq!(log.samples.len(), 3 * FRAMES as usize);
    let seq_col = log
        .extra_columns
        .iter()
        .position(|c| c == "seq")
        .expect("seq column");
    for seq in 0..FRAMES {
        let f = frame(seq);
        for (c, ch) in f.chambers.iter().enumerate() {
            let i = 3 * seq as usize + c;
            let s = &log.samples[i];
            assert_eq!(s.time_s, f.t_us as f64 / 1e6, "seq {seq}");
            assert_eq!(s.chamber as usize, c);
            assert_eq!(s.volume_mm3 as f32, ch.v, "seq {seq} chamber {c}");
            assert_eq!(s.pressure_kpa as f32, ch.p, "seq {seq} chamber {c}");
            assert_eq!(s.flow_mm3_s.map(|q| q as f32), Some(ch.vdot));
            assert_eq!(log.extra[i][seq_col], seq.to_string());
        }
    }
    assert_eq!(log.metadata("frames"), Some("1500"));
    assert_eq!(log.metadata("missing_frames"), Some("0"));
    assert_eq!(log.metadata("sample_rate_hz"), Some("25"));
    assert_eq!(log.metadata("stopped"), Some(stopped));
}

fn interrupted_by(signal: i32, name: &str) {
    let dir = scratch(name);
    let out = dir.join("LOG.csv");
    let (mut child, mut stdin) = spawn(&out);
    stdin.write_all(capture().as_bytes()).expect("pipe open");
    stdin.flush().expect("pipe open");
    wait_for_all_rows(&out, &mut child);
    // SAFETY: `kill` with a live child's pid and a valid signal number has no memory effects.
    assert_eq!(unsafe { libc::kill(child.id() as i32, signal) }, 0);
    let output = child.wait_with_output().expect("vfp ends");
    drop(stdin); // held open until the tool had ended: the signal, not the pipe, stopped it
    check_log(&out, &output, name);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sigint_with_the_pipe_open_leaves_every_frame() {
    interrupted_by(libc::SIGINT, "SIGINT");
}

#[test]
fn sigterm_with_the_pipe_open_leaves_every_frame() {
    interrupted_by(libc::SIGTERM, "SIGTERM");
}

#[test]
fn end_of_input_leaves_every_frame() {
    let dir = scratch("eof");
    let out = dir.join("LOG.csv");
    let (child, mut stdin) = spawn(&out);
    stdin.write_all(capture().as_bytes()).expect("pipe open");
    drop(stdin);
    let output = child.wait_with_output().expect("vfp ends");
    check_log(&out, &output, "end of input");
    let _ = std::fs::remove_dir_all(&dir);
}
