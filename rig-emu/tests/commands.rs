//! The command port of the real firmware: checksummed lines executed, damaged ones refused.

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
    rig.until_zeroed().unwrap();
    assert_eq!(
        rig.command("checksum require").unwrap().as_deref(),
        Some("ok")
    );
    // A plain line is refused now.
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
