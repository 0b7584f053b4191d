//! `vfp record` on telemetry captured from host-sim: every removed frame is reported as a gap
//! with its sequence numbers, every corrupted line by its line number, and the frames that arrive
//! are the simulator's frames exactly; the recorded log reads into `identify` unchanged.

use e2e_tests::{probe_rs_text, scratch, short_protocol};
use firmware::telemetry::Frame;
use host_sim::{simulate, PlantConfig};
use sysid::board::record::{convert, Gap};
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::identify::{identify, Family, Options};

#[test]
fn gaps_and_corrupted_lines_are_reported_and_nothing_else_is_lost() {
    let run = simulate(&short_protocol(PlantConfig::default())).expect("valid scenario");
    let total = run.frames.len();
    assert!(total > 400, "{total} frames");
    let mut text = probe_rs_text(&run.telemetry);
    // Index of the printed line of frame `seq` (frame lines carry "$F <seq> ").
    let line_of = |text: &[String], seq: u32| {
        let tag = format!("$F {seq} ");
        text.iter()
            .position(|l| l.contains(&tag))
            .expect("frame present")
    };
    // Corrupt three frames (truncated, a garbled number, the marker destroyed) ...
    let i50 = line_of(&text, 50);
    let cut = text[i50].find("$F").unwrap() + 30;
    text[i50].truncate(cut);
    let i51 = line_of(&text, 51);
    text[i51] = text[i51].replacen("$F 51 ", "$F 51 x", 1);
    let i100 = line_of(&text, 100);
    text[i100] = text[i100].replace("$F", "F");
    // ... and drop four (with their location lines), last first so indices stay valid.
    for seq in [300u32, 12, 11, 10] {
        let i = line_of(&text, seq);
        text.drain(i..i + 2);
    }
    // Capture line numbers (1-based) of the corrupted lines and of the frames after each gap.
    let corrupted_lines: Vec<usize> = text
        .iter()
        .enumerate()
        .filter(|(_, l)| l.contains("$F 50 ") || l.contains("$F 51 "))
        .map(|(i, _)| i + 1)
        .collect();
    assert_eq!(corrupted_lines.len(), 2);
    let after = |seq: u32| line_of(&text, seq) + 1;
    let capture = text.join("\n") + "\n";

    let rec = convert(capture.as_bytes(), "capture.txt").expect("frames present");
    assert_eq!(
        rec.gaps,
        vec![
            Gap {
                line: after(13),
                first: 10,
                last: 12
            },
            Gap {
                line: after(52),
                first: 50,
                last: 51
            },
            Gap {
                line: after(101),
                first: 100,
                last: 100
            },
            Gap {
                line: after(301),
                first: 300,
                last: 300
            },
        ]
    );
    assert_eq!(rec.missing_frames(), 7);
    assert_eq!(
        rec.corrupted.iter().map(|b| b.line).collect::<Vec<_>>(),
        corrupted_lines
    );
    assert!(rec.rejected.is_empty() && rec.restarts.is_empty());
    assert_eq!(rec.frames, total - 7);
    assert_eq!(rec.events, run.events.len());

    // The rows are the simulator's frames, value for value, in the log's units.
    let lost = [10u32, 11, 12, 50, 51, 100, 300];
    let kept: Vec<&Frame> = run
        .frames
        .iter()
        .filter(|f| !lost.contains(&f.seq))
        .collect();
    assert_eq!(rec.log.samples.len(), 3 * kept.len());
    for (k, f) in kept.iter().enumerate() {
        for c in 0..3 {
            let s = &rec.log.samples[3 * k + c];
            let ch = &f.chambers[c];
            assert_eq!(s.time_s, f.t_us as f64 / 1e6);
            assert_eq!(s.chamber as usize, c);
            assert_eq!(
                (s.volume_mm3 as f32, s.pressure_kpa as f32),
                (ch.v, ch.p),
                "seq {} chamber {c}",
                f.seq
            );
            assert_eq!(s.flow_mm3_s.map(|x| x as f32), Some(ch.vdot));
            assert_eq!(rec.log.extra[3 * k + c][0], f.seq.to_string());
        }
    }
    // The summary names the missing ranges and the corrupted line numbers.
    let summary = rec.summary("capture.txt");
    assert!(summary.contains("seq 10..=12 (3 frames)"), "{summary}");
    assert!(
        summary.contains(&format!("line {}:", corrupted_lines[0])),
        "{summary}"
    );
}

#[test]
fn a_recorded_log_reads_into_identify_unchanged() {
    let run = simulate(&short_protocol(PlantConfig::default())).expect("valid scenario");
    let dir = scratch("record-identify");
    let capture = probe_rs_text(&run.telemetry).join("\n");
    let rec = convert(capture.as_bytes(), "capture.txt").expect("frames present");
    assert!(rec.is_complete());
    let path = dir.join("recorded.csv");
    sysid::log::write_log(&path, &rec.log).expect("writable");
    let recorded = sysid::log::read_log(&path).expect("the recorded log is a valid log");

    // The simulator's own log writer is the independent reference for the same frames.
    let mut reference = Vec::new();
    run.write_log(&mut reference).expect("in memory");
    let reference = sysid::log::parse_log(&reference[..], "host-sim.csv").expect("valid log");
    assert_eq!(recorded.samples.len(), reference.samples.len());
    for (a, b) in recorded.samples.iter().zip(&reference.samples) {
        assert_eq!(
            (
                a.time_s,
                a.chamber,
                a.volume_mm3,
                a.flow_mm3_s,
                a.pressure_kpa
            ),
            (
                b.time_s,
                b.chamber,
                b.volume_mm3,
                b.flow_mm3_s,
                b.pressure_kpa
            )
        );
    }
    assert_eq!(recorded.metadata("sample_rate_hz"), Some("25"));

    // identify sees the same data, so it selects and scores the same models.
    let opt = Options {
        families: vec![Family::Poly],
        max_n: 3,
        max_m: 2,
        prune_k: 0,
        ..Options::default()
    };
    for c in 0..3 {
        let a = identify(
            &Dataset::from_log(&recorded, c, &DatasetConfig::default()).unwrap(),
            &opt,
        );
        let b = identify(
            &Dataset::from_log(&reference, c, &DatasetConfig::default()).unwrap(),
            &opt,
        );
        assert_eq!(a.models, b.models, "chamber {c}");
        assert!(a.selected.is_some());
    }
    let _ = std::fs::remove_dir_all(&dir);
}
