//! The command port of the real firmware: checksummed lines executed, damaged and plain ones
//! refused (checksums are required from boot), `stop` obeyed in any form, and the guide's line
//! for a person at a terminal.

use std::time::Duration;

use rig_emu::{default_elf, Rig, RigConfig};

fn booted() -> Rig {
    let mut rig = Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts");
    rig.run_for(Duration::from_millis(100)).unwrap();
    rig
}

/// The `v` fields of a status reply.
fn volumes(status: &str) -> [f32; 3] {
    let words: Vec<&str> = status.split_whitespace().collect();
    let at = words.iter().position(|w| *w == "v").expect("a v field") + 1;
    core::array::from_fn(|i| words[at + i].parse().expect("a volume"))
}

#[test]
fn an_unknown_command_is_refused_by_name() {
    let mut rig = booted();
    let reply = rig.command("fly 0 1").unwrap().expect("a reply");
    assert_eq!(reply, "err unknown-command");
}

#[test]
fn a_checksummed_line_with_a_flipped_bit_never_executes() {
    let mut rig = booted();
    let ok = rig.command("origin 0 100").unwrap().expect("a reply");
    assert_eq!(ok, "ok");
    let status = rig.command("status").unwrap().unwrap();
    assert_eq!(volumes(&status)[0], 100.0, "{status}");
    // Every single-bit flip of every byte of the command part of `*LLCC origin 0 200`, each on
    // its own line: none may execute (the origin stays at 100).
    let command = "origin 0 200";
    let mut line = String::new();
    firmware::command::write_checksummed(command, &mut line).unwrap();
    let prefix = line.len() - command.len();
    let mut refused = 0;
    for byte in prefix..line.len() {
        for bit in 0..7 {
            let mut bytes = line.clone().into_bytes();
            bytes[byte] ^= 1 << bit;
            if bytes[byte] == b'\n' || bytes[byte] == b'\r' {
                continue; // a split line: covered by the firmware's library tests
            }
            bytes.push(b'\n');
            let reply = rig
                .exchange(&bytes)
                .unwrap()
                .expect("a reply to every line");
            assert!(reply.starts_with("err"), "byte {byte} bit {bit}: {reply}");
            refused += 1;
        }
    }
    assert!(refused > 60, "{refused} damaged lines tried");
    let status = rig.command("status").unwrap().unwrap();
    assert_eq!(
        volumes(&status)[0],
        100.0,
        "a damaged line moved the origin: {status}"
    );
}

#[test]
fn words_arriving_with_noise_reject_their_line_and_nothing_else() {
    let mut rig = booted();
    // One word in twenty arrives with noise (rigless's line condition, drawn from the run's seed).
    rig.with(|s, _| {
        let errors = s.board_mut().host_line_errors();
        errors.noise.name = "usart2-noise";
        errors.noise.per_million = 50_000;
    })
    .unwrap();
    let mut last_ok = 0.0;
    let (mut oks, mut errs) = (0, 0);
    for k in 1..=40 {
        let v = 10.0 * k as f32;
        match rig.command(&format!("origin 0 {v}")).unwrap() {
            Some(r) if r == "ok" => {
                last_ok = v;
                oks += 1;
            }
            Some(r) => {
                assert!(r.starts_with("err"), "{r}");
                errs += 1;
            }
            None => errs += 1,
        }
    }
    rig.with(|s, _| s.board_mut().host_line_errors().noise.per_million = 0)
        .unwrap();
    // A line cut in two by a noisy terminator may still be pending: flush it.
    let _ = rig.command("status").unwrap();
    let status = rig
        .command("status")
        .unwrap()
        .expect("a reply once the line is clean");
    assert!(
        oks > 5 && errs > 5,
        "{oks} accepted, {errs} refused: the noise did not bite"
    );
    assert_eq!(volumes(&status)[0], last_ok, "{status}");
}

#[test]
fn stop_is_obeyed_plain_while_checksums_are_required() {
    let mut rig = Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts");
    rig.ready().unwrap();
    // Required from boot: a plain line is refused.
    assert_eq!(
        rig.command("checksum").unwrap().as_deref(),
        Some("ok require")
    );
    let refused = rig.exchange(b"status\n").unwrap();
    assert_eq!(refused.as_deref(), Some("err checksum-required"));
    // A slow move (100 mm³ at 20 mm³/s: 5 s), stopped by a plain `stop` after 300 ms.
    assert_eq!(rig.command("move 0 100 20").unwrap().as_deref(), Some("ok"));
    rig.run_for(Duration::from_millis(300)).unwrap();
    let moved = rig.with(|_, b| b.steps.len()).unwrap();
    assert!(moved > 50, "{moved} steps in 300 ms");
    let stopped = rig.exchange(b"stop\n").unwrap();
    assert_eq!(stopped.as_deref(), Some("ok"));
    let at_stop = rig.with(|_, b| b.steps.len()).unwrap();
    rig.run_for(Duration::from_millis(500)).unwrap();
    let after = rig.with(|_, b| b.steps.len()).unwrap();
    assert_eq!(after, at_stop, "steps after the stop's reply");
    // A stop behind a damaged prefix is obeyed too.
    assert_eq!(rig.command("move 0 50 20").unwrap().as_deref(), Some("ok"));
    rig.run_for(Duration::from_millis(200)).unwrap();
    let stopped = rig
        .exchange(
            b"*04ZZ stop
",
        )
        .unwrap();
    assert_eq!(stopped.as_deref(), Some("ok"));
    let at_stop = rig.with(|_, b| b.steps.len()).unwrap();
    rig.run_for(Duration::from_millis(300)).unwrap();
    assert_eq!(rig.with(|_, b| b.steps.len()).unwrap(), at_stop);
}

/// A `status` reply without its frame counter (`seq <n>`, which runs on with the frames).
fn without_seq(status: &str) -> String {
    let mut words: Vec<&str> = status.split_whitespace().collect();
    let at = words.iter().position(|w| *w == "seq").expect("a seq field");
    words.drain(at..at + 2);
    words.join(" ")
}

/// From boot, a plain line other than `stop` is refused with `err checksum-required` and changes
/// nothing: no step, the same status, checksum mode and telemetry switch. `origin 1 300` is the
/// issue's one-bit flip of `origin 1 100`, which the old default executed.
#[test]
fn a_plain_command_is_refused_from_boot_and_changes_nothing() {
    let mut rig = Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts");
    rig.ready().unwrap();
    let seen = |rig: &mut Rig| {
        [
            without_seq(&rig.command("status").unwrap().expect("status")),
            rig.command("checksum").unwrap().expect("checksum"),
            rig.command("telemetry").unwrap().expect("telemetry"),
        ]
    };
    let before = seen(&mut rig);
    let lines = [
        "origin 1 300",
        "move 0 100 20",
        "telemetry on",
        "checksum optional",
        "zero",
        "status",
    ];
    for line in lines {
        let reply = rig.exchange(format!("{line}\n").as_bytes()).unwrap();
        assert_eq!(reply.as_deref(), Some("err checksum-required"), "{line}");
    }
    rig.run_for(Duration::from_millis(500)).unwrap();
    assert_eq!(seen(&mut rig), before);
    assert_eq!(before[1..], ["ok require", "ok off"]);
    assert_eq!(rig.with(|_, b| b.steps.len()).unwrap(), 0, "steps");
    // The same `origin` checksummed runs, and the status shows it.
    assert_eq!(rig.command("origin 1 300").unwrap().as_deref(), Some("ok"));
    let status = rig.command("status").unwrap().unwrap();
    assert_eq!(volumes(&status), [0.0, 300.0, 0.0], "{status}");
}

/// The path the guide gives a person at a serial terminal (docs/guide/src/protocol.md): the
/// line `*1104 checksum optional`, typed as it stands there, lets plain lines through until
/// `checksum require` or the next reset.
#[test]
fn the_guides_terminal_line_allows_plain_lines_until_a_reset() {
    let mut rig = Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts");
    rig.until_zeroed().unwrap();
    let typed = |rig: &mut Rig, line: &str| {
        rig.exchange(format!("{line}\r\n").as_bytes())
            .unwrap()
            .expect("a reply")
    };
    assert_eq!(typed(&mut rig, "status"), "err checksum-required");
    // The guide's checksummed `origin all 0`, the first thing after a reset.
    assert_eq!(typed(&mut rig, "*0CBA origin all 0"), "ok");
    assert_eq!(typed(&mut rig, "*1104 checksum optional"), "ok");
    assert_eq!(typed(&mut rig, "checksum"), "ok optional");
    assert_eq!(typed(&mut rig, "origin 0 50"), "ok");
    let status = typed(&mut rig, "status");
    assert_eq!(volumes(&status), [50.0, 0.0, 0.0], "{status}");
    assert_eq!(typed(&mut rig, "checksum require"), "ok");
    assert_eq!(typed(&mut rig, "origin 0 60"), "err checksum-required");
    assert_eq!(typed(&mut rig, "*1104 checksum optional"), "ok");
    // A reset (the watchdog's, with TIM5 stopped under the firmware) requires checksums again.
    const TIM5_CR1: u64 = 0x4000_0C00;
    rig.poke(TIM5_CR1, 0).unwrap();
    let boot = rig.next_boot(Duration::from_secs(2)).unwrap();
    assert!(boot.is_some_and(|b| b.contains(" watchdog")), "no reset");
    assert_eq!(typed(&mut rig, "checksum"), "err checksum-required");
    assert_eq!(
        rig.command("checksum").unwrap().as_deref(),
        Some("ok require")
    );
}
