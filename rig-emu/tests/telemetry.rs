//! Binary telemetry over the command port of the real firmware: 25 Hz frames, none lost, while
//! commands arrive.

use std::time::Duration;

use rig_emu::{default_elf, Rig, RigConfig};

/// Virtual seconds of telemetry (`RIG_TELEMETRY_S` to change).
fn seconds() -> u64 {
    std::env::var("RIG_TELEMETRY_S")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60)
}

#[test]
fn frames_at_25_hz_with_none_lost_while_commands_arrive() {
    let mut rig = Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts");
    rig.ready().unwrap();
    assert_eq!(rig.command("telemetry on").unwrap().as_deref(), Some("ok"));
    let secs = seconds();
    let mut replies = 0;
    for k in 0..secs * 4 {
        // A command every 250 ms, a move now and then.
        let cmd = if k % 8 == 4 {
            format!("move 012 {} 50", 10 * (k % 3))
        } else {
            "status".into()
        };
        let r = rig.command(&cmd).unwrap().expect("a reply");
        assert!(r.starts_with("ok"), "{cmd}: {r}");
        replies += 1;
        rig.run_for(Duration::from_millis(240)).unwrap();
    }
    let (frames, bad) = rig
        .with(|_, b| {
            let bad = b
                .stream
                .items()
                .iter()
                .filter(|r| matches!(r, rig_emu::Received::BadPacket(..)))
                .count();
            (b.stream.frames(), bad)
        })
        .unwrap();
    assert_eq!(bad, 0, "damaged packets");
    assert!(replies > 0);
    let n = frames.len() as u64;
    assert!(n + 2 >= secs * 25, "{n} frames in {secs} s");
    for w in frames.windows(2) {
        assert_eq!(w[1].seq, w[0].seq + 1, "a frame lost");
        let dt = w[1].t_us - w[0].t_us;
        assert!((39_000..=41_000).contains(&dt), "frames {dt} µs apart");
    }
    assert!(
        frames.iter().all(|f| f.drops == 0),
        "the board dropped frames"
    );
}
