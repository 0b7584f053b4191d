//! The command parser and line assembler never panic, and whatever parses executes without
//! panicking on a fresh application state.
#![no_main]

use firmware::app::{Config, Shared};
use firmware::command::{parse, LineAssembler};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = parse(data);
    let mut asm = LineAssembler::new();
    let shared = Shared::new(Config::default());
    let mut reply = String::new();
    for (i, &b) in data.iter().enumerate() {
        if let Some(Ok(cmd)) = asm.push(b) {
            reply.clear();
            shared.command(&cmd, i as u64 * 1_000, &mut reply);
            assert!(reply.starts_with("ok") || reply.starts_with("err "));
        }
    }
});
