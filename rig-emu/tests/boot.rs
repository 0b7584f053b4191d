//! The ELF boots on the virtual board and answers on its command port.

use std::time::Duration;

use rig_emu::rig::is_reply;
use rig_emu::{default_elf, Rig, RigConfig};

fn rig() -> Rig {
    Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts")
}

/// `RCC_DCKCFGR2` (RM0390 6.3.28, F446 only), which embassy writes once with 0: the one register
/// the F427's models do not cover.
const RCC_DCKCFGR2: &str = "at=0x40023894 ";

#[test]
fn boots_answers_status_with_the_reset_cause_and_keeps_running() {
    let mut rig = rig();
    let status = rig.until_zeroed().unwrap();
    // After power-on the positions are unknown (flags 26-28) until the host declares them.
    let origin_needed = firmware::telemetry::Flags::ORIGIN_NEEDED * 0b111;
    assert!(
        status.starts_with(&format!("ok flags {origin_needed} ")),
        "{status}"
    );
    assert!(status.ends_with(" reset power-on"), "{status}");
    assert_eq!(
        rig.command("move 0 10 50").unwrap().as_deref(),
        Some("err origin-needed")
    );
    assert_eq!(rig.command("origin all 0").unwrap().as_deref(), Some("ok"));
    let status = rig.command("status").unwrap().expect("a reply");
    assert!(status.starts_with("ok flags 0 "), "{status}");
    // Two virtual seconds more: the watchdog is fed (no reset), the frames go on.
    rig.run_for(Duration::from_secs(2)).unwrap();
    let status = rig.command("status").unwrap().expect("a reply");
    let seq: u32 = status.split_whitespace().nth(4).unwrap().parse().unwrap();
    assert!(seq >= 60, "{seq} frames after about 3 s: {status}");
    let out = rig.finish().unwrap();
    assert!(out.resets.is_empty(), "{:?}", out.resets);
    assert!(out.unimplemented.is_empty(), "{:?}", out.unimplemented);
    assert!(
        out.unmapped.iter().all(|u| u.contains(RCC_DCKCFGR2)),
        "{:?}",
        out.unmapped
    );
}

/// A host that speaks while the board boots (a reset it did not see, a script that opens the
/// port and writes at once): the board announces on its command port when it listens (the boot
/// event, with the reset cause), a line that reached it before is answered or was never
/// received (no UART hears a word before its clock runs, about a millisecond after reset), and
/// the host's next line is answered, never refused for what happened before.
#[test]
fn a_line_sent_during_boot_is_answered_or_lost_and_the_next_one_is_answered() {
    // Checksummed, as a host sends it (the firmware refuses plain lines from boot).
    let mut status = String::new();
    firmware::command::write_checksummed("status", &mut status).unwrap();
    status.push('\n');
    for at_us in [0_u64, 300, 1_000, 1_500, 2_000, 5_000] {
        let line = status.clone();
        let mut rig = Rig::start_with(&RigConfig::new(default_elf()), move |board| {
            board
                .host()
                .send_at(rigless::time::VirtualNanos(at_us * 1000), line.as_bytes());
        })
        .expect("the virtual rig starts");
        let boot = rig
            .wait_line(0, Duration::from_secs(1), |l| l.starts_with("$E "))
            .unwrap()
            .expect("the boot event on the command port");
        assert!(boot.contains(" boot 0 power-on"), "{boot}");
        rig.run_for(Duration::from_millis(50)).unwrap();
        let early: Vec<String> = rig.lines().unwrap();
        let replies: Vec<&String> = early.iter().filter(|l| is_reply(l)).collect();
        assert!(
            replies.is_empty() || (replies.len() == 1 && replies[0].starts_with("ok flags")),
            "status sent {at_us} µs after reset: {early:?}"
        );
        let next = rig.command("status").unwrap();
        assert!(
            next.as_deref().is_some_and(|l| l.starts_with("ok flags")),
            "sent {at_us} µs after reset: {:?}",
            rig.lines().unwrap()
        );
    }
}
