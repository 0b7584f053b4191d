//! Telemetry without a probe, end to end: the simulated board (the firmware's own tasks in
//! host-sim) is switched to binary telemetry on its serial port by the `telemetry on` command;
//! the bytes it writes there (replies and packets) and the text lines it hands its RTT channel
//! go through `vfp record --binary` and `vfp record`; both logs must hold the same rows and the
//! same totals, and every frame the board produced.

use crate::common;

use host_sim::{simulate, Scenario, TimedCommand};

fn data_and_totals(csv: &str) -> Vec<&str> {
    csv.lines()
        .filter(|l| {
            !l.starts_with('#')
                || [
                    "sample_rate_hz=",
                    "frames=",
                    "missing_frames=",
                    "corrupted_lines=",
                    "rejected_frames=",
                ]
                .iter()
                .any(|k| l.starts_with(&format!("# {k}")))
        })
        .collect()
}

#[test]
fn the_serial_stream_and_the_probe_capture_give_the_same_log() {
    let mut sc = Scenario {
        name: "serial".into(),
        duration_s: 4.0,
        ..Scenario::default()
    };
    sc.commands = vec![
        TimedCommand::new(0.0, "telemetry on"),
        TimedCommand::new(1.5, "move 0 123.44 40"),
        TimedCommand::new(1.5, "move 1 250 100"),
        TimedCommand::new(2.0, "telemetry"),
    ];
    let run = simulate(&sc).expect("the scenario runs");
    assert!(
        run.replies.iter().any(|(_, r)| r == "ok on"),
        "{:?}",
        run.replies
    );
    assert!(run.frames.len() >= 95, "{} frames", run.frames.len());

    let dir = common::scratch("serial", "record");
    let text: String = run
        .telemetry
        .iter()
        .map(|(_, l)| format!("{l}\n"))
        .collect();
    std::fs::write(dir.join("capture.txt"), text).unwrap();
    std::fs::write(dir.join("capture.bin"), &run.serial_out).unwrap();
    let (a, b) = (dir.join("a.csv"), dir.join("b.csv"));
    common::ok(
        common::vfp()
            .args(["record"])
            .arg(dir.join("capture.txt"))
            .arg("-o")
            .arg(&a),
    );
    let out = common::ok(
        common::vfp()
            .args(["record", "--binary"])
            .arg(dir.join("capture.bin"))
            .arg("-o")
            .arg(&b)
            .arg("--strict"),
    );
    let summary = String::from_utf8_lossy(&out.stderr);
    assert!(
        summary.contains("missing frames: 0 in 0 gap(s)"),
        "{summary}"
    );
    let (a, b) = (
        std::fs::read_to_string(a).unwrap(),
        std::fs::read_to_string(b).unwrap(),
    );
    let (da, db) = (data_and_totals(&a), data_and_totals(&b));
    assert_eq!(da, db);
    // Header, three rows per frame the board produced, five totals.
    assert_eq!(db.len(), 1 + 3 * run.frames.len() + 5);
    assert!(db.contains(&format!("# frames={}", run.frames.len()).as_str()));
}
