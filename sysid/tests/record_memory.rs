//! The streaming recorder's memory does not grow with the capture: the peak of live heap bytes
//! while converting 20,000 frames is the same as for 1,000 (a counting global allocator measures
//! it; this file holds one test so no other test allocates meanwhile). One frame in 100 is
//! dropped and one line in 50 is garbled, so the gap and bad-line bookkeeping is exercised too.

use firmware::telemetry::{ChamberFrame, Frame};
use sysid::board::record::Recorder;

mod heap;

#[global_allocator]
static A: heap::Counting = heap::Counting;

/// Peak live heap bytes above the start while streaming `n` frames into a sink.
fn peak_while_streaming(n: u32) -> (usize, usize, u64) {
    let base = heap::start();
    let mut rec = Recorder::new(std::io::sink(), "mem").expect("sink");
    let mut line = String::new();
    for seq in (0..n).filter(|s| s % 100 != 98) {
        let c = ChamberFrame {
            v: seq as f32 * 0.04,
            p: 0.5,
            ..ChamberFrame::default()
        };
        let f = Frame {
            seq,
            t_us: 40_000 * (u64::from(seq) + 1),
            chambers: [c; 3],
            ..Frame::default()
        };
        line.clear();
        f.encode(&mut line).expect("encodes");
        if seq % 50 == 25 {
            line.truncate(20);
        }
        line.push('\n');
        rec.line(line.as_bytes()).expect("sink");
        rec.line("└─ vfp_fw::task @ src/bin/vfp-fw.rs:56\n".as_bytes())
            .expect("sink");
    }
    let (summary, _) = rec.finish("end of input").expect("sink");
    let peak = heap::peak_since(base);
    (peak, summary.frames, summary.missing_frames())
}

#[test]
fn memory_does_not_grow_with_the_capture() {
    let (small, frames_small, missing_small) = peak_while_streaming(1_000);
    let (large, frames_large, missing_large) = peak_while_streaming(20_000);
    // The gaps were found (every 100th frame, and every 50th line garbled: 20 + 10 per 1,000).
    assert_eq!(missing_small, 30);
    assert_eq!(missing_large, 600);
    assert_eq!(frames_small, 1_000 - 30);
    assert_eq!(frames_large, 20_000 - 600);
    // Holding the rows would take 20 × as much for the large capture (> 3 MB); the peak is the
    // writer's buffer and a few lines, the same for both.
    eprintln!("peak heap: {small} B for 1,000 frames, {large} B for 20,000");
    assert!(
        large <= small + 1_024,
        "peak heap {small} B for 1,000 frames, {large} B for 20,000"
    );
    assert!(large < 64 * 1024, "peak heap {large} B");
}
