//! The command parser, the checksum rules and the line assembler never panic, and whatever
//! parses executes without panicking on a fresh application state.
#![no_main]

use firmware::app::{Config, Shared};
use firmware::command::{parse, LineAssembler, LinkState, RawLine};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = parse(data);
    let _ = LinkState::default().check(data);
    let mut asm = LineAssembler::new();
    let shared = Shared::new(Config::default());
    // Positions declared (`origin all 0`), so that motion commands get past the origin check.
    let _ = shared.declare_origin(0.0);
    let mut reply = String::new();
    // Plain lines accepted, so that the fuzzer's lines reach the parser and the commands
    // (at boot only checksummed lines do).
    shared.command_line(b"*1104 checksum optional", 0, &mut reply);
    assert_eq!(reply, "ok");
    for (i, &b) in data.iter().enumerate() {
        if b == 0xff {
            asm.error();
            continue;
        }
        if let Some(line) = asm.push(b) {
            reply.clear();
            let mut est = shared.estimator().try_lock().unwrap();
            shared.command_raw(&mut est, line, i as u64 * 1_000, &mut reply);
            assert!(reply.starts_with("ok") || reply.starts_with("err "));
            if let RawLine::Corrupt = line {
                assert_eq!(reply, "err line-corrupt");
            }
        }
    }
});
