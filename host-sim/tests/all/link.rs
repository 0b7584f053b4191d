//! The board's links to the host under trouble: a host that stops reading telemetry for seconds
//! (the board drops and counts lines, and nothing else changes), and a serial port that loses or
//! garbles command bytes (the line is refused, never executed).

use firmware::motion::Trapezoid;
use firmware::telemetry::{Event, EventKind, Flags, Frame};
use host_sim::{
    simulate, Scenario, SerialFault, SerialFaultKind, SimRun, TelemetryStall, TimedCommand,
};

/// Frames the board produced, from both what the host received and what the transport refused.
fn refused_frames(run: &SimRun) -> Vec<(u64, Frame)> {
    run.refused_telemetry
        .iter()
        .filter(|(_, l)| l.starts_with("$F"))
        .map(|(t, l)| (*t, Frame::decode(l).expect("a refused frame line decodes")))
        .collect()
}

/// Every frame number appears exactly once, received or refused, 40 ms apart; each seq gap in
/// what the host received is exactly the frames refused there, and each frame's `drops` counts
/// every line (frame or event) refused before it.
fn check_every_frame_accounted_for(run: &SimRun) {
    let refused = refused_frames(run);
    assert!(!refused.is_empty(), "the stall refused frames");
    let mut all: Vec<Frame> = run.frames.to_vec();
    all.extend(refused.iter().map(|(_, f)| *f));
    all.sort_by_key(|f| f.seq);
    for (i, f) in all.iter().enumerate() {
        assert_eq!(f.seq, i as u32, "every frame produced once");
        // Oversamples every 5 ms, the mean instant 22.5 ms into each 40 ms frame: sampling
        // went on undisturbed through the stall.
        assert_eq!(
            f.t_us,
            40_000 * i as u64 + 22_500,
            "frame {i} sampled on time"
        );
    }
    // The received frames, with the send time of each.
    let received: Vec<(u64, Frame)> = run
        .telemetry
        .iter()
        .filter(|(_, l)| l.starts_with("$F"))
        .map(|(t, l)| (*t, Frame::decode(l).unwrap()))
        .collect();
    for w in received.windows(2) {
        let ((t1, f1), (t2, f2)) = (w[0], w[1]);
        let frames_between = refused
            .iter()
            .filter(|(_, f)| f.seq > f1.seq && f.seq < f2.seq)
            .count() as u32;
        assert_eq!(
            f2.seq - f1.seq - 1,
            frames_between,
            "gap before frame {}",
            f2.seq
        );
        let lines_between = run
            .refused_telemetry
            .iter()
            .filter(|(t, _)| (t1..t2).contains(t))
            .count() as u32;
        assert_eq!(
            f2.drops - f1.drops,
            lines_between,
            "drops reported by frame {}",
            f2.seq
        );
    }
    for (t, f) in &received {
        let before = run.refused_telemetry.iter().filter(|(r, _)| r < t).count() as u32;
        assert_eq!(
            f.drops, before,
            "frame {} counts every line dropped before it",
            f.seq
        );
    }
    let last = received.last().unwrap().1;
    assert_eq!(last.drops as usize, run.refused_telemetry.len());
}

/// A move of all three axes while the host reads no telemetry for 4 s: every planned step at
/// its instant, every frame sampled, every dropped line counted.
#[test]
fn a_telemetry_stall_changes_nothing_but_the_lines_the_host_sees() {
    let sc = Scenario {
        name: "stall-move".into(),
        duration_s: 10.0,
        record_detail: true,
        commands: vec![TimedCommand::new(1.5, "move all 300 50")],
        telemetry_stalls: vec![TelemetryStall {
            start_s: 2.0,
            duration_s: 4.0,
        }],
        ..Scenario::default()
    };
    let run = simulate(&sc).unwrap();
    assert_eq!(run.replies.len(), 1);
    assert_eq!(run.replies[0].1, "ok");
    // Motion: 7500 steps per axis, each at the profile's instant from the command + 1 ms lead.
    let plan = Trapezoid::new(7_500, 0.04, 50.0, 500.0);
    let t0 = run.replies[0].0 + 1_000;
    for axis in 0..3u8 {
        let steps: Vec<u64> = run
            .steps
            .iter()
            .filter(|s| s.1 == axis)
            .map(|s| {
                assert!(s.2, "inflating");
                s.0
            })
            .collect();
        assert_eq!(steps.len(), 7_500, "axis {axis}");
        for (k, &at) in steps.iter().enumerate() {
            assert_eq!(
                at,
                t0 + plan.step_offset_us(k as u32 + 1),
                "axis {axis} step {}",
                k + 1
            );
        }
        assert_eq!(run.step_count[axis as usize], 7_500);
    }
    assert_eq!(run.stats.late_steps, 0);
    assert!(
        run.stats.max_step_delay_us <= sc.quantum_us,
        "every step issued within one executor quantum of its instant: {} µs",
        run.stats.max_step_delay_us
    );
    check_conversions_every_5_ms(&run);
    // The stall was during the move.
    assert!(run
        .steps
        .iter()
        .any(|s| (2_000_000..6_000_000).contains(&s.0)));
    let last = run.frames.last().unwrap();
    for c in &last.chambers {
        assert_eq!(c.v, 300.0, "final volume exact");
    }
    check_every_frame_accounted_for(&run);
    // Nothing was refused outside the stall, and the watchdog was fed throughout.
    assert!(run
        .refused_telemetry
        .iter()
        .all(|(t, _)| (2_000_000..6_000_000).contains(t)));
    assert!(run.stats.max_watchdog_gap_us <= 5_000);
}

/// An over-pressure while the host reads nothing: the fault still latches at the conversion
/// that sees it and stops every motor; its event line is dropped and counted, and the first
/// frame after the stall carries the fault.
#[test]
fn an_over_pressure_during_a_telemetry_stall_still_stops_motion() {
    let sc = Scenario {
        name: "stall-over-pressure".into(),
        seed: 4,
        duration_s: 12.0,
        record_detail: true,
        commands: vec![
            TimedCommand::new(1.2, "limit all 30 550"),
            TimedCommand::new(1.5, "move all 550 100"),
        ],
        telemetry_stalls: vec![TelemetryStall {
            start_s: 2.0,
            duration_s: 8.0,
        }],
        ..Scenario::default()
    };
    let run = simulate(&sc).unwrap();
    let fault = run
        .refused_telemetry
        .iter()
        .filter_map(|(_, l)| Event::decode(l).ok())
        .find_map(|e| match e.kind {
            EventKind::Fault { flags } => Some((e.t_us, flags)),
            _ => None,
        });
    let (t_f, flags) = fault.expect("the fault event was offered during the stall");
    assert!((2_000_000..10_000_000).contains(&t_f), "fault at {t_f} µs");
    assert!(Flags(flags).has(Flags::OVER_PRESSURE * 0b111), "{flags:#x}");
    assert!(
        run.first_event("fault").is_none(),
        "the host never saw the event line"
    );
    // Stopped at the conversion: no step after it, none of the motors reached 550 mm³.
    for (i, last) in run.last_step_us.iter().enumerate() {
        assert!(last.unwrap() <= t_f, "axis {i} stepped after the fault");
        assert!(run.step_count[i] < 13_750);
    }
    check_conversions_every_5_ms(&run);
    // The tripping conversion is the first one above the limit (to 6σ of noise), as without a
    // stall: no conversion before it was certainly over.
    let zero = refused_or_received_zero(&run);
    let sigma6 = 6.0 * sc.plant.sensor.noise_kpa;
    let offset = sc.plant.sensor.offset_kpa;
    let reading = |c: &host_sim::board::ReadTruth| {
        (0..3)
            .map(|i| c.chambers[i].sensed_kpa + offset[i] - zero[i] as f64)
            .fold(f64::MIN, f64::max)
    };
    for c in run.conversions.iter().filter(|c| c.t_us < t_f) {
        assert!(reading(c) <= 30.0 + sigma6, "missed {} kPa", reading(c));
    }
    // After the stall the host sees the fault in the flags, and the count of what it missed.
    let after: Vec<&Frame> = run.frames.iter().filter(|f| f.t_us > t_f).collect();
    assert!(!after.is_empty());
    assert!(after[0].flags.is_fault());
    check_every_frame_accounted_for(&run);
}

/// Sampling went on: a conversion every 5 ms from the first to the last.
fn check_conversions_every_5_ms(run: &SimRun) {
    assert!(run.conversions.len() > 1_000);
    for (i, c) in run.conversions.iter().enumerate() {
        assert_eq!(c.t_us, 5_000 * (i as u64 + 1), "conversion {i}");
    }
}

/// The zero offsets the board took (the `zeroed` event: before the stall).
fn refused_or_received_zero(run: &SimRun) -> [f32; 3] {
    run.events
        .iter()
        .find_map(|e| match e.kind {
            EventKind::Zeroed { offset_kpa } => Some(offset_kpa),
            _ => None,
        })
        .expect("zeroed before the stall")
}

/// Bytes lost or flagged on the UART: the line is refused (`err line-corrupt`), a checksummed
/// line missing a byte is refused (`err bad-checksum`) and so is the plain line after it
/// (`err checksum-required`, even with plain lines allowed); none of them moves anything.
/// `move 0 12.5` losing its `.` would otherwise have moved axis 0 to 125 mm³.
#[test]
fn corrupted_command_bytes_never_move_anything() {
    // Every line checksummed (`*LLCC ` is the 6 bytes before the command) but one: plain lines
    // are allowed after `checksum optional`, except right after a failed check.
    let prefix = 6;
    let sc = Scenario {
        name: "uart-faults".into(),
        duration_s: 6.0,
        record_detail: true,
        commands: vec![
            TimedCommand::new(1.5, "move 0 12.5"),
            TimedCommand::new(2.0, "move 1 12.5"),
            TimedCommand::new(2.2, "checksum optional"),
            TimedCommand::new(2.5, "move 2 12.5"),
            TimedCommand::plain(3.0, "status"),
            TimedCommand::new(3.5, "move 0 5"),
        ],
        serial_faults: vec![
            // The '.' of "move 0 12.5" is lost; the UART reports an overrun.
            SerialFault {
                command: 0,
                byte: prefix + 9,
                kind: SerialFaultKind::Lose,
            },
            // A framing error on the '2' of "move 1 12.5".
            SerialFault {
                command: 1,
                byte: prefix + 8,
                kind: SerialFaultKind::Flag,
            },
            // The '.' of "move 2 12.5" lost with no error reported.
            SerialFault {
                command: 3,
                byte: prefix + 9,
                kind: SerialFaultKind::Drop,
            },
        ],
        ..Scenario::default()
    };
    let run = simulate(&sc).unwrap();
    let replies: Vec<&str> = run.replies.iter().map(|(_, r)| r.as_str()).collect();
    assert_eq!(
        replies,
        [
            "err line-corrupt",
            "err line-corrupt",
            "ok",
            "err bad-checksum",
            "err checksum-required",
            "ok"
        ]
    );
    // Only the last, intact command moved anything: axis 0 to 5 mm³ (125 steps), after 3.5 s.
    assert_eq!(run.step_count, [125, 0, 0]);
    assert!(run.steps.iter().all(|s| s.0 > 3_500_000));
    let last = run.frames.last().unwrap();
    assert_eq!(last.chambers[0].v, 5.0);
    assert_eq!((last.chambers[1].v, last.chambers[2].v), (0.0, 0.0));
}

/// A scenario's lines go checksummed, as a host sends them, unless they say
/// `framing = "plain"`: then the board refuses them from boot (`err checksum-required`), except
/// `stop`, and nothing moves until the same command comes checksummed.
#[test]
fn plain_lines_are_refused_from_boot() {
    let sc = Scenario::from_toml(
        r#"
duration_s = 4.0
record_detail = true
[[commands]]
at_s = 1.5
line = "move 0 12.5"
framing = "plain"
[[commands]]
at_s = 1.6
line = "stop"
framing = "plain"
[[commands]]
at_s = 2.0
line = "move 1 12"
"#,
        "plain.toml",
    )
    .unwrap();
    let run = simulate(&sc).unwrap();
    let replies: Vec<&str> = run.replies.iter().map(|(_, r)| r.as_str()).collect();
    assert_eq!(replies, ["err checksum-required", "ok", "ok"]);
    // Only the checksummed move ran: axis 1 to 12 mm³ (300 steps of 0.04 mm³), after 2 s.
    assert_eq!(run.step_count, [0, 300, 0]);
    assert!(run.steps.iter().all(|s| s.0 > 2_000_000));
}
