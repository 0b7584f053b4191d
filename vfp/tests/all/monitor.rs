//! `vfp monitor` headless: a stream from the simulated board (the firmware's own tasks; a move of
//! all three axes, a telemetry stall during which the board drops and counts lines), printed as
//! `probe-rs run` prints it, with lines deleted and one garbled on the way, goes through the
//! monitor's reader thread into its state, is drawn on ratatui's `TestBackend` and recorded.
//! The truth is the simulator's: the frames it sent, the lines its transport refused.

use crate::common;

use std::io::Cursor;
use std::path::PathBuf;

use firmware::telemetry::Frame;
use host_sim::{simulate, Scenario, SimRun, TelemetryStall, TimedCommand};
use ratatui::{backend::TestBackend, Terminal};
use vfp::cmd::monitor::{binary_capture_path, buffer_text, capture_path, Session};

/// Frames deleted from the capture (lost on the way), and the one garbled.
const DELETED: [u32; 4] = [20, 21, 22, 120];
const GARBLED: u32 = 40;

fn scenario() -> Scenario {
    Scenario {
        name: "monitor".into(),
        duration_s: 8.0,
        commands: vec![TimedCommand::new(1.5, "move all 300 50")],
        telemetry_stalls: vec![TelemetryStall {
            start_s: 3.0,
            duration_s: 1.0,
        }],
        ..Scenario::default()
    }
}

/// The capture as `probe-rs run` prints it (timestamp and level before each line, the location
/// line after, a few log messages of the firmware's own), with [`DELETED`] left out and
/// [`GARBLED`] cut short.
fn capture(run: &SimRun) -> String {
    let mut out = String::from("     Running `probe-rs run --chip STM32F446RETx vfp-fw`\n");
    out.push_str(
        "0.000050 INFO vfp-fw starting\n└─ vfp_fw::main @ firmware/src/bin/vfp-fw.rs:30\n",
    );
    for (t, line) in &run.telemetry {
        let seq = Frame::decode(line).ok().map(|f| f.seq);
        if seq.is_some_and(|q| DELETED.contains(&q)) {
            continue;
        }
        let line = match seq {
            Some(GARBLED) => &line[..40],
            _ => line.as_str(),
        };
        out.push_str(&format!("{:.6} INFO {line}\n", *t as f64 * 1e-6));
        out.push_str("└─ vfp_fw::__sampler_task @ firmware/src/bin/vfp-fw.rs:56\n");
        if seq == Some(130) {
            out.push_str("5.250000 WARN telemetry channel was full\n");
        }
    }
    out
}

fn scratch(name: &str) -> PathBuf {
    common::scratch("monitor", name)
}

/// Reads the whole capture through a session and draws it on a `width × height` test screen.
fn monitor(text: String, out: &std::path::Path, width: u16, height: u16) -> (Session, String) {
    let mut session = Session::start(
        Box::new(Cursor::new(text.into_bytes())),
        "capture.txt",
        Some(out),
        10.0,
    )
    .unwrap();
    session.wait_for_end_of_input();
    let mut terminal = Terminal::new(TestBackend::new(width, height)).unwrap();
    session.draw(&mut terminal).unwrap();
    let screen = buffer_text(terminal.backend().buffer());
    (session, screen)
}

#[test]
fn a_recorded_stream_is_shown_counted_and_logged_without_loss() {
    let run = simulate(&scenario()).unwrap();
    let refused_frames = run
        .refused_telemetry
        .iter()
        .filter(|(_, l)| l.starts_with("$F"))
        .count() as u64;
    assert!(
        refused_frames >= 20,
        "the stall dropped {refused_frames} frames"
    );
    let sent: Vec<&Frame> = run
        .frames
        .iter()
        .filter(|f| !DELETED.contains(&f.seq) && f.seq != GARBLED)
        .collect();
    let last = *sent.last().unwrap();
    assert!(
        last.seq > 150 && last.chambers.iter().all(|c| c.p > 1.0),
        "{last:?}"
    );

    let dir = scratch("stream");
    let out = dir.join("LOG.csv");
    let (session, screen) = monitor(capture(&run), &out, 150, 40);
    println!("{screen}");
    // The latest frame's numbers, per chamber.
    for c in &last.chambers {
        let shown = format!("P {:.3}  P̂ {:.3} kPa", c.p, c.p_hat);
        assert!(screen.contains(&shown), "{shown} not on screen");
        assert!(screen.contains(&format!("r {:+.3} kPa", c.residual)));
    }
    assert!(screen.contains(&format!("|F| {:.1} mN", last.force_n * 1e3)));
    // What was lost, and where: the board's own drops against the lines lost on the way.
    let missing = refused_frames + DELETED.len() as u64 + 1;
    let board = run.refused_telemetry.len();
    let expect = [
        format!("frames {} (seq 0..={})", sent.len(), last.seq),
        format!("missing {missing} in 4 gaps · board dropped {board} lines"),
        format!("lost on the way ≥ {}", DELETED.len() + 1),
        "corrupted 1 · rejected 0".to_string(),
        "25.0 frames/s".to_string(),
        "WARN telemetry channel was full".to_string(),
        "input ended".to_string(),
        "recording".to_string(),
    ];
    for e in &expect {
        assert!(screen.contains(e), "{e:?} not on screen");
    }
    let frames_seen = session.with_state(|s| s.counts.frames);
    assert_eq!(frames_seen, sent.len() as u64);

    // The log: every frame received, in order, with the device's digits.
    let rec = session.finish().unwrap().expect("recording");
    assert_eq!(rec.frames, sent.len());
    let log = sysid::log::read_log(&out).unwrap();
    assert_eq!(log.samples.len(), 3 * sent.len());
    let seq_col = log.extra_columns.iter().position(|c| c == "seq").unwrap();
    for (i, (s, extra)) in log.samples.iter().zip(&log.extra).enumerate() {
        let f = sent[i / 3];
        let c = &f.chambers[usize::from(s.chamber)];
        assert_eq!(extra[seq_col], f.seq.to_string());
        assert_eq!(s.pressure_kpa, format!("{}", c.p).parse::<f64>().unwrap());
        assert_eq!(s.volume_mm3, format!("{}", c.v).parse::<f64>().unwrap());
    }
    // The same log `vfp record` makes of the raw capture, which holds every line received.
    let raw = std::fs::read_to_string(capture_path(&out)).unwrap();
    assert_eq!(raw, capture(&run));
    let again = sysid::board::record::convert(raw.as_bytes(), "x").unwrap();
    let mut csv = Vec::new();
    sysid::log::write_log_to(&mut csv, &rec.log).unwrap();
    let mut csv_again = Vec::new();
    sysid::log::write_log_to(&mut csv_again, &again.log).unwrap();
    let written = std::fs::read(&out).unwrap();
    assert_eq!(written, csv);
    // Only the source name in the first comment differs.
    let body = |b: &[u8]| {
        String::from_utf8_lossy(b)
            .lines()
            .skip(1)
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(body(&written), body(&csv_again));
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn garbage_input_is_counted_and_nothing_is_recorded() {
    let dir = scratch("garbage");
    let out = dir.join("LOG.csv");
    let mut text = b"\xff\xfe\x00 binary noise\n$F 1 2 3\nplain text\n$E 1 nonsense".to_vec();
    text.extend_from_slice(&[0u8; 300]);
    let mut session =
        Session::start(Box::new(Cursor::new(text)), "noise", Some(&out), 10.0).unwrap();
    session.wait_for_end_of_input();
    let mut terminal = Terminal::new(TestBackend::new(100, 30)).unwrap();
    session.draw(&mut terminal).unwrap();
    let screen = buffer_text(terminal.backend().buffer());
    assert!(screen.contains("frames 0 ·"), "{screen}");
    assert!(screen.contains("corrupted 2"), "{screen}");
    assert!(screen.contains("waiting for frames"), "{screen}");
    // No frame, no log; the error says so, and the raw capture keeps what came.
    let e = session.finish().unwrap_err();
    assert!(e.to_string().contains("no telemetry frame"), "{e}");
    assert!(!out.exists());
    assert!(capture_path(&out).exists());
    let _ = std::fs::remove_dir_all(dir);
}

/// `vfp monitor --port`'s path: the simulated board's serial bytes after `telemetry on` (the same
/// stall of its RTT channel, which the serial stream does not share) through the binary reader
/// into the state and the recording: every frame the board made, none missing.
#[test]
fn the_serial_stream_is_shown_and_recorded() {
    let mut sc = scenario();
    sc.commands
        .insert(0, TimedCommand::new(0.0, "telemetry on"));
    let run = simulate(&sc).unwrap();
    assert!(
        !run.refused_telemetry.is_empty(),
        "the RTT stall dropped lines"
    );
    // Frames the board made: seq 0 ..= the last one RTT delivered (after the stall).
    let made = u64::from(run.frames.last().unwrap().seq) + 1;
    let dir = scratch("serial");
    let out = dir.join("LOG.csv");
    let mut session = Session::start_binary(
        Box::new(Cursor::new(run.serial_out.clone())),
        "serial",
        Some(&out),
        10.0,
    )
    .unwrap();
    session.wait_for_end_of_input();
    let c = session.with_state(|s| s.counts);
    assert!(c.frames >= made, "{} of {made}", c.frames);
    assert_eq!((c.gaps, c.missing, c.corrupted, c.rejected), (0, 0, 0, 0));
    assert_eq!(c.other, 2, "the replies `ok` (telemetry on, move)");
    let rec = session.finish().unwrap().expect("recording");
    assert_eq!(rec.frames as u64, c.frames);
    assert!(rec.is_complete());
    assert_eq!(
        std::fs::read(binary_capture_path(&out)).unwrap(),
        run.serial_out
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// The README's picture of the monitor: `VFP_MONITOR_SCREEN=FILE cargo test -p vfp --test all
/// monitor::readme_screen -- --ignored` writes the screen as text.
#[test]
#[ignore]
fn readme_screen() {
    let run = simulate(&scenario()).unwrap();
    let path = std::env::var("VFP_MONITOR_SCREEN").expect("VFP_MONITOR_SCREEN=FILE");
    // Recorded under the name the README's example uses (in the crate's directory, then removed).
    let out = PathBuf::from("run.csv");
    let (session, screen) = monitor(capture(&run), &out, 120, 36);
    session.finish().unwrap();
    std::fs::write(path, screen).unwrap();
    let _ = std::fs::remove_file(capture_path(&out));
    let _ = std::fs::remove_file(out);
}

/// How fast the reader takes lines, recording included (a measurement, not a check):
/// `cargo test -p vfp --test all monitor::throughput -- --ignored --nocapture`.
#[test]
#[ignore]
fn throughput() {
    let run = simulate(&scenario()).unwrap();
    let one = capture(&run);
    // An hour of frames at 25 Hz: the 8 s capture 450 times (seq restarts read as reboots).
    let text = one.repeat(450);
    let dir = scratch("throughput");
    let t0 = std::time::Instant::now();
    let mut session = Session::start(
        Box::new(Cursor::new(text.into_bytes())),
        "hour",
        Some(&dir.join("LOG.csv")),
        10.0,
    )
    .unwrap();
    session.wait_for_end_of_input();
    let read = t0.elapsed();
    let frames = session.with_state(|s| s.counts.frames);
    let rec = session.finish().unwrap().unwrap();
    println!(
        "{frames} frames read and spooled in {read:?} ({:.0} frames/s; the board sends 25), log of {} frames written after {:?}",
        frames as f64 / read.as_secs_f64(),
        rec.frames,
        t0.elapsed()
    );
    let _ = std::fs::remove_dir_all(dir);
}
