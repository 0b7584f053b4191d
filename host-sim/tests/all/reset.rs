//! After a reset other than power-on the firmware does not trust its step counts: motion waits
//! for `origin`, `clear` does not lift that, and the boot event tells the causes apart. The
//! firmware's own tasks run against the plant; only the reset cause given to the firmware differs.

use firmware::app::Config;
use firmware::reset::{FaultFrame, FileTail, PanicSite, ResetCause};
use firmware::telemetry::{EventKind, Flags};
use host_sim::{simulate_with, Scenario, SimRun, TimedCommand};

const ORIGIN_NEEDED_ALL: u32 = Flags::ORIGIN_NEEDED * 0b111;

/// `move` (refused or not), `clear`, `move` again, `origin all`, `move` once more; then a
/// read of the status.
fn sequence() -> Scenario {
    let cmd = TimedCommand::new;
    Scenario {
        name: "reset".into(),
        duration_s: 5.0,
        // 1 s between the moves: a 20 mm³ move at the default 50 mm³/s takes 0.5 s.
        commands: vec![
            cmd(1.5, "move 0 20"),
            cmd(1.6, "clear"),
            cmd(2.5, "move 0 20"),
            cmd(2.6, "origin all 5"),
            cmd(2.7, "move 0 20"),
            cmd(4.5, "status"),
        ],
        ..Scenario::default()
    }
}

fn run(cause: ResetCause) -> SimRun {
    let cfg = Config {
        reset_cause: cause,
        ..Config::default()
    };
    simulate_with(&sequence(), cfg).unwrap_or_else(|e| panic!("{cause:?}: {e}"))
}

fn replies(r: &SimRun) -> Vec<&str> {
    r.replies.iter().map(|(_, l)| l.as_str()).collect()
}

fn boot_cause(r: &SimRun) -> ResetCause {
    match r.events.first().map(|e| e.kind) {
        Some(EventKind::Boot { cause }) => cause,
        other => panic!("first event {other:?}"),
    }
}

fn assert_refused_until_origin(cause: ResetCause) {
    let r = run(cause);
    let rep = replies(&r);
    // A fault reset (flag 13) refuses motion as a fault first; `clear` lifts that, not the
    // unknown positions.
    let first = if cause.is_fault() {
        "err faulted"
    } else {
        "err origin-needed"
    };
    assert_eq!(
        &rep[..5],
        &[first, "ok", "err origin-needed", "ok", "ok"],
        "{cause:?}"
    );
    assert_eq!(boot_cause(&r), cause);
    // Every frame before `origin` carries the three bits; none after the origin's frame.
    let origin_us = r.replies[3].0;
    for f in &r.frames {
        let bits = f.flags.0 & ORIGIN_NEEDED_ALL;
        if f.t_us + 40_000 < origin_us {
            assert_eq!(bits, ORIGIN_NEEDED_ALL, "{cause:?} frame {}", f.seq);
        } else if f.t_us > origin_us {
            assert_eq!(bits, 0, "{cause:?} frame {}", f.seq);
        }
    }
    // The move after `origin` ran from the declared 5 mm³ to 20 mm³: 375 steps.
    let last = r.frames.last().unwrap();
    assert!((last.chambers[0].v - 20.0).abs() < 1e-3, "{cause:?}");
    assert_eq!(r.step_count[0], 375, "{cause:?}");
}

#[test]
fn after_a_watchdog_reset_motion_waits_for_origin() {
    assert_refused_until_origin(ResetCause::Watchdog);
}

#[test]
fn after_a_panic_or_a_hardfault_motion_waits_for_origin() {
    assert_refused_until_origin(ResetCause::Panic(PanicSite {
        file: FileTail::new("firmware/src/app.rs"),
        line: 321,
        column: 9,
    }));
    assert_refused_until_origin(ResetCause::HardFault(FaultFrame {
        pc: 0x0800_2000,
        ..FaultFrame::default()
    }));
}

#[test]
fn after_a_reset_by_the_pin_or_software_motion_waits_for_origin() {
    assert_refused_until_origin(ResetCause::Pin);
    assert_refused_until_origin(ResetCause::Software);
}

#[test]
fn after_power_on_motion_is_accepted_at_once() {
    for cause in [ResetCause::PowerOn, ResetCause::BrownOut] {
        let r = run(cause);
        assert_eq!(&replies(&r)[..5], &["ok"; 5], "{cause:?}");
        assert_eq!(boot_cause(&r), cause);
        assert!(r.frames.iter().all(|f| f.flags.0 & ORIGIN_NEEDED_ALL == 0));
        // From 0 to 20 (the second `move 0 20` finds it there), then, after `origin all 5`,
        // from 5 to 20 mm³: 500 + 375 steps.
        assert_eq!(r.step_count[0], 875, "{cause:?}");
    }
}

#[test]
fn fault_resets_latch_flag_13_until_clear_and_the_others_do_not() {
    for (cause, latched) in [
        (ResetCause::Watchdog, true),
        (ResetCause::HardFault(FaultFrame::default()), true),
        (ResetCause::Pin, false),
        (ResetCause::PowerOn, false),
    ] {
        let r = run(cause);
        let first = &r.frames[0];
        assert_eq!(first.flags.has(Flags::FAULT_RESET), latched, "{cause:?}");
        // `clear` at 1.6 s lifts it.
        let clear_us = r.replies[1].0;
        assert!(r
            .frames
            .iter()
            .filter(|f| f.t_us > clear_us)
            .all(|f| !f.flags.has(Flags::FAULT_RESET)));
    }
}

#[test]
fn the_boot_event_tells_the_causes_apart() {
    let site = PanicSite {
        file: FileTail::new("src/motion.rs"),
        line: 77,
        column: 5,
    };
    let mut lines = Vec::new();
    for cause in [
        ResetCause::PowerOn,
        ResetCause::Watchdog,
        ResetCause::Panic(site),
    ] {
        let r = run(cause);
        let line = r
            .telemetry
            .iter()
            .map(|(_, l)| l.as_str())
            .find(|l| l.contains(" boot "))
            .unwrap()
            .to_string();
        lines.push(line);
    }
    assert_eq!(
        lines,
        [
            "$E 0 boot 0 power-on",
            "$E 0 boot 1 watchdog",
            "$E 0 boot 0 panic src/motion.rs 77 5"
        ]
    );
}
