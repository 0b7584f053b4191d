//! Binary telemetry packets (`firmware::wire`): decoding arbitrary bytes never panics, and every
//! packet that decodes to a frame re-encodes to the same bytes (the format has one spelling).
#![no_main]

use firmware::wire::{decode, encode_frame, Packet, Record, MAX_RAW};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    // The bytes between two delimiters never hold a zero: split as a reader does.
    for chunk in data.split(|&b| b == 0) {
        let mut scratch = [0u8; MAX_RAW];
        if let Ok(Record::Frame(f)) = decode(chunk, &mut scratch) {
            let mut p = Packet::new();
            encode_frame(&f, &mut p);
            assert_eq!(&p[1..p.len() - 1], chunk);
        }
    }
});
