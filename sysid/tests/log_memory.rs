//! Reading a log keeps columns, not rows: the peak of live heap bytes while `LogData::read`
//! builds chamber 0's dataset is the same whether the file holds chamber 0 alone or the same rows
//! interleaved with two more chambers and a text column (a counting global allocator measures it;
//! this file holds one test so no other test allocates meanwhile). The file itself is never held.

use std::io::Write;
use sysid::dataset::{DatasetConfig, LogData};

mod heap;

#[global_allocator]
static A: heap::Counting = heap::Counting;

/// Writes `frames` frames of a triangle-wave protocol, chamber 0 only or all three chambers with
/// a `note` column, and returns the peak live heap (above the start) of reading chamber 0.
fn peak_reading(frames: usize, crowded: bool, dir: &std::path::Path) -> (usize, usize) {
    let path = dir.join(if crowded { "crowded.csv" } else { "alone.csv" });
    let mut w = std::io::BufWriter::new(std::fs::File::create(&path).unwrap());
    writeln!(w, "# sample_rate_hz=25").unwrap();
    if crowded {
        writeln!(w, "time_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa,note").unwrap();
    } else {
        writeln!(w, "time_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa").unwrap();
    }
    for k in 0..frames {
        let t = 0.04 * k as f64;
        let phase = (k % 500) as f64 / 250.0;
        let (v, f) = if phase < 1.0 {
            (500.0 * phase, 50.0)
        } else {
            (500.0 * (2.0 - phase), -50.0)
        };
        let p = 1.0 + 0.01 * v + 0.002 * f + 0.01 * (k as f64 * 12.9898).sin();
        for c in 0..if crowded { 3 } else { 1 } {
            write!(w, "{t:.2},{c},{v},{f},{p}").unwrap();
            if crowded {
                write!(w, ",a note of some length {k}").unwrap();
            }
            writeln!(w).unwrap();
        }
    }
    drop(w);
    let base = heap::start();
    let data = LogData::read(&path, Some(0), &DatasetConfig::default()).unwrap();
    let peak = heap::peak_since(base);
    (peak, data.first().len())
}

#[test]
fn memory_holds_the_requested_columns_only() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("sysid-log-memory-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (mut extra, mut alones) = (Vec::new(), Vec::new());
    for frames in [20_000, 80_000] {
        let (alone, n_alone) = peak_reading(frames, false, &dir);
        let (crowded, n_crowded) = peak_reading(frames, true, &dir);
        assert_eq!((n_alone, n_crowded), (frames, frames));
        eprintln!("{frames} frames, peak heap reading chamber 0: {alone} B alone, {crowded} B among 3 chambers");
        // Holding the crowded file's rows would add 3 × 20,000 rows × (≥ 56 B of sample + the
        // note) > 5 MB, four times that for 80,000; the columns of chamber 0 are the same in both
        // files. What the crowded file costs more is the reader's blocks in flight between its
        // threads (about a dozen blocks of 64 KiB of text with their rows and samples,
        // `LogReader::for_each`; how many are in flight at the peak varies from run to run),
        // which do not grow with the file.
        assert!(
            crowded <= alone + 4 * 1024 * 1024,
            "{frames} frames: peak heap {alone} B alone, {crowded} B among three chambers"
        );
        extra.push(crowded as i64 - alone as i64);
        alones.push(alone as i64);
    }
    // Four times the rows (15 MB more if they were held), not more in flight.
    assert!(
        extra[1] <= extra[0] + 4 * 1024 * 1024,
        "the crowded file's extra grows with its length: {extra:?} B"
    );
    // And 60,000 more samples cost a small multiple of chamber 0's own columns (a dataset keeps
    // 7 numbers per sample; columns grow by doubling).
    let per_sample = (alones[1] - alones[0]) / 60_000;
    assert!(
        per_sample <= 20 * 8,
        "{per_sample} B per sample ({alones:?} B)"
    );
    std::fs::remove_dir_all(&dir).ok();
}
