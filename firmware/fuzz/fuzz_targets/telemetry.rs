//! Telemetry decoding never panics, and every decoded frame re-encodes to a line that decodes
//! to the same frame.
#![no_main]

use firmware::telemetry::{parse_line, Frame, Line, LineBuf};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = core::str::from_utf8(data) else { return };
    if let Some(Ok(Line::Frame(f))) = parse_line(text) {
        let mut buf = LineBuf::new();
        f.encode(&mut buf).expect("a decoded frame fits a line");
        let g = Frame::decode(&buf).expect("re-encoded frame decodes");
        let same = |a: f32, b: f32| a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan());
        assert_eq!((f.seq, f.t_us, f.flags), (g.seq, g.t_us, g.flags));
        assert!(same(f.force_n, g.force_n));
        for (a, b) in f.chambers.iter().zip(&g.chambers) {
            for (x, y) in [
                (a.v, b.v),
                (a.vdot, b.vdot),
                (a.p, b.p),
                (a.p_hat, b.p_hat),
                (a.residual, b.residual),
                (a.k, b.k),
                (a.c, b.c),
            ] {
                assert!(same(x, y));
            }
        }
    }
});
