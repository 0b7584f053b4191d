//! The log format (docs/log-format.md): round trip, errors with file/line/column, no panics,
//! and the per-chamber dataset (derived flow, cycles, split).

use proptest::prelude::*;
use sysid::dataset::{self, Dataset, DatasetConfig, FlowSource, Split};
use sysid::log::{parse_log, read_log, write_log_to, LogError, Sample};

fn parse(text: &str) -> Result<sysid::log::Log, LogError> {
    parse_log(text.as_bytes(), "test.csv")
}

#[test]
fn round_trip_keeps_values_metadata_and_unknown_columns() {
    let text = "# sample_rate_hz=25\n# rig=bench A\nnote,time_s,chamber,volume_mm3,pressure_kpa,flow_mm3_s,force_n\n\
                a,0.0,1,0.04,0.1,10,\n\"b,c\",0.04,1,0.08,0.30000000000000004,10.5,0.25\nz,0.0,0,1e3,2,,\n";
    let log = parse(text).unwrap();
    assert_eq!(log.metadata("sample_rate_hz"), Some("25"));
    assert_eq!(log.metadata("rig"), Some("bench A"));
    assert_eq!(log.extra_columns, ["note"]);
    assert_eq!(log.extra[1], ["b,c"]);
    assert_eq!(log.chambers(), [0, 1]);
    assert_eq!(log.samples[1].pressure_kpa, 0.30000000000000004);
    assert_eq!(log.samples[0].force_n, None);
    assert_eq!(log.samples[2].flow_mm3_s, None);
    assert_eq!(log.samples[2].volume_mm3, 1000.0);
    let mut out = Vec::new();
    write_log_to(&mut out, &log).unwrap();
    let again = parse_log(&out[..], "out.csv").unwrap();
    assert_eq!(again, log);
}

#[test]
fn whitespace_around_fields_and_names_is_not_part_of_them() {
    let tight = "time_s,chamber,volume_mm3,pressure_kpa,note\n0,0,1.5,2,a b\n0.04,1,2,3,c\n";
    let loose = " time_s ,\tchamber, volume_mm3 ,pressure_kpa\u{a0},note\n \
                 0 , 0 ,1.5\t, 2,  a b \n0.04 ,1\u{2009}, 2,3 , c\u{a0}\n";
    assert_eq!(parse(loose).unwrap(), parse(tight).unwrap());
}

#[test]
fn errors_name_file_line_and_column() {
    let head = "# comment\ntime_s,volume_mm3,pressure_kpa\n";
    let e = parse(&format!("{head}0,1,2\n0.1,x,3\n")).unwrap_err();
    assert!(
        matches!(
            e,
            LogError::BadValue {
                line: 4,
                ref column,
                ..
            } if column == "volume_mm3"
        ),
        "{e:?}"
    );
    assert_eq!(
        e.to_string(),
        "test.csv:4: column `volume_mm3`: cannot parse as a number: \"x\""
    );
    let e = parse(&format!("{head}0,1,NaN\n")).unwrap_err();
    assert!(
        matches!(
            e,
            LogError::BadValue {
                line: 3,
                ref column,
                ..
            } if column == "pressure_kpa"
        ),
        "{e:?}"
    );
    let e = parse(&format!("{head}0,1,2\n0,1,2\n")).unwrap_err();
    assert!(
        matches!(e, LogError::TimeNotIncreasing { line: 4, .. }),
        "{e:?}"
    );
    let e = parse(&format!("{head}0,1,2\n0.1,1\n")).unwrap_err();
    assert!(matches!(e, LogError::Malformed { line: 4, .. }), "{e:?}");
    let e = parse("time_s,pressure_kpa\n0,1\n").unwrap_err();
    assert!(
        matches!(
            e,
            LogError::MissingColumn {
                ref column,
                line: 1,
                ..
            } if column == "volume_mm3"
        ),
        "{e:?}"
    );
    let e = parse("time_s,chamber,volume_mm3,pressure_kpa\n0,3,1,2\n").unwrap_err();
    assert!(matches!(e, LogError::BadChamber { line: 2, .. }), "{e:?}");
    assert!(matches!(parse("# only\n"), Err(LogError::Empty { .. })));
    assert!(matches!(
        parse("time_s,volume_mm3,pressure_kpa\n"),
        Err(LogError::Empty { .. })
    ));
    let e = read_log("/nonexistent/dir/log.csv").unwrap_err();
    assert!(e.to_string().starts_with("/nonexistent/dir/log.csv: "));
}

/// Windows line ends and a last comment without a line end: errors still name the row's own
/// line, and the comment is no row.
#[test]
fn crlf_lines_and_a_last_comment_read_like_the_rest() {
    let e = parse("# c\r\ntime_s,volume_mm3,pressure_kpa\r\n0,1,2\r\n0.1,x,3\r\n").unwrap_err();
    assert!(matches!(e, LogError::BadValue { line: 4, .. }), "{e:?}");
    let log = parse("time_s,volume_mm3,pressure_kpa\r\n0,1,2\r\n# end").unwrap();
    assert_eq!(log.samples.len(), 1);
    assert_eq!(log.comments, ["end"]);
}

#[test]
fn time_may_interleave_across_chambers() {
    let log =
        parse("time_s,chamber,volume_mm3,pressure_kpa\n0,0,1,2\n0,1,1,2\n0.1,0,1,2\n0.1,1,1,2\n")
            .unwrap();
    assert_eq!(log.samples.len(), 4);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    #[test]
    fn random_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = parse_log(&bytes[..], "fuzz.csv");
    }

    #[test]
    fn random_lines_never_panic(lines in proptest::collection::vec("[-#0-9a-z_.,e\" ]{0,30}", 0..12)) {
        let text = format!("time_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa\n{}", lines.join("\n"));
        match parse(&text) {
            Ok(log) => prop_assert!(!log.samples.is_empty()),
            Err(e) => prop_assert!(e.to_string().starts_with("test.csv")),
        }
    }

    /// A number cell is read as Rust's `str::parse::<f64>` reads it (the reader uses a faster
    /// parser of the same syntax): the same value, or the same refusal.
    #[test]
    fn numbers_read_as_str_parse_reads_them(
        cell in "[ ]?[-+]?[0-9]{0,4}[.]?[0-9]{0,4}([eE][-+]?[0-9]{0,4})?[ ]?|[-+]?(inf|Inf|INF|infinity|Infinity|nan|NaN|[0-9.eE+-]{1,8}|[a-f0-9x_]{1,6})"
    ) {
        let text = format!("time_s,volume_mm3,pressure_kpa\n0,1,{cell}\n");
        let expect = cell.trim().parse::<f64>();
        match (parse(&text), expect) {
            (Ok(log), Ok(x)) => prop_assert_eq!(log.samples[0].pressure_kpa.to_bits(), x.to_bits()),
            (Err(LogError::BadValue { problem, .. }), Ok(x)) => {
                prop_assert!(!x.is_finite(), "{:?} refused ({}) but std reads {}", cell, problem, x);
                prop_assert_eq!(problem, "not a finite number:");
            }
            (Err(LogError::BadValue { problem, .. }), Err(_)) if !cell.trim().is_empty() => {
                prop_assert_eq!(problem, "cannot parse as a number:", "{:?}", cell);
            }
            (Err(LogError::BadValue { problem, .. }), Err(_)) => {
                prop_assert_eq!(problem, "required value is empty:");
            }
            (got, want) => prop_assert!(false, "{:?}: read {:?}, std {:?}", cell, got, want),
        }
    }

    #[test]
    fn random_flags_cells_never_panic(cells in proptest::collection::vec("[-0-9a-z +.]{0,12}", 3..40)) {
        // Whatever the flags column holds, the dataset is built or refused with an error naming
        // the sample, and exactly the rows whose cell is an integer with NOT_ZEROED are left out.
        let mut text = String::from("time_s,volume_mm3,pressure_kpa,flags\n");
        for (k, c) in cells.iter().enumerate() {
            text.push_str(&format!("{},{k},1.0,{c}\n", 0.04 * k as f64));
        }
        let Ok(log) = parse(&text) else { return Ok(()) };
        let parsed: Vec<Option<u32>> = log
            .extra
            .iter()
            .map(|e| {
                let c = e[0].trim();
                if c.is_empty() { Some(0) } else { c.parse().ok() }
            })
            .collect();
        let dropped = parsed.iter().filter(|p| p.is_some_and(|b| b & (1 << 16) != 0)).count();
        match Dataset::from_log(&log, 0, &DatasetConfig::default()) {
            Ok(ds) => {
                prop_assert!(parsed.iter().all(Option::is_some));
                prop_assert_eq!(ds.not_zeroed, dropped);
                prop_assert_eq!(ds.len() + dropped, cells.len());
            }
            Err(e) => {
                let m = e.to_string();
                prop_assert!(
                    parsed.iter().any(Option::is_none) || cells.len() - dropped < 3,
                    "{}", m
                );
            }
        }
    }
}

#[test]
fn derived_flow_is_exact_for_quadratic_volume() {
    // v = 3 t² on jittered times: a local quadratic fit differentiates it exactly.
    let t: Vec<f64> = (0..40)
        .map(|i| i as f64 * 0.04 + if i % 3 == 0 { 0.003 } else { 0.0 })
        .collect();
    let v: Vec<f64> = t.iter().map(|t| 3.0 * t * t).collect();
    let (d1, d2) = dataset::local_quadratic_derivatives(&t, &v, 2);
    for i in 0..t.len() {
        assert!((d1[i] - 6.0 * t[i]).abs() < 1e-9, "v̇ at {i}");
        assert!((d2[i] - 6.0).abs() < 1e-7, "v̈ at {i}");
    }
}

#[test]
fn dataset_derives_flow_and_splits_cycles() {
    // Three triangle cycles at 50 mm³/s with dwell, 25 Hz, no flow column.
    let mut log = sysid::log::Log::default();
    let mut t = 0.0;
    let mut v = 0.0f64;
    for _cycle in 0..10 {
        for (q, secs) in [(50.0, 4.0), (0.0, 1.0), (-50.0, 4.0), (0.0, 1.0)] {
            for _ in 0..(secs * 25.0) as usize {
                log.push(Sample::new(t, 2, v, 0.1 * v));
                t += 0.04;
                v += q * 0.04;
            }
        }
    }
    let ds = Dataset::from_log(&log, 2, &DatasetConfig::default()).unwrap();
    assert_eq!(ds.flow_source, FlowSource::Derived { half_width: 2 });
    assert_eq!(ds.n_cycles, 10);
    assert_eq!(ds.split, Split::EveryKthCycle { k: 5 });
    // Away from corners the derived flow is the commanded one.
    assert!((ds.vdot[50] - 50.0).abs() < 1e-9 && (ds.vdot[175] + 50.0).abs() < 1e-9);
    let held: std::collections::BTreeSet<usize> = (0..ds.len())
        .filter(|&i| ds.heldout[i])
        .map(|i| ds.cycle[i])
        .collect();
    assert_eq!(held.into_iter().collect::<Vec<_>>(), [4, 8]);
    assert!(Dataset::from_log(&log, 0, &DatasetConfig::default()).is_err());
}

#[test]
fn ventilator_breaths_are_the_cycles() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../data/real/test-lung-pip15-peep5.csv"
    );
    let log = read_log(path).expect("the repository's real log parses");
    let ds = Dataset::from_log(&log, 0, &DatasetConfig::default()).unwrap();
    assert_eq!(ds.flow_source, FlowSource::Logged);
    // 12 breaths/min for about 233 s.
    assert!((44..=49).contains(&ds.n_cycles), "{} cycles", ds.n_cycles);
}

#[test]
fn frames_flagged_not_zeroed_are_left_out_and_bad_flags_are_named() {
    // Our firmware's `flags` column: bit 16 (NOT_ZEROED) marks the boot frames whose pressure is
    // still the raw sensor offset. Five such frames at 0.4 kPa, then a zeroed ramp.
    let mut text = String::from("time_s,volume_mm3,pressure_kpa,flags\n");
    for k in 0..30 {
        let (v, p, flags) = if k < 5 {
            (0.0, 0.4, 65536)
        } else {
            (k as f64, 0.1 * k as f64, 0)
        };
        text.push_str(&format!("{},{v},{p},{flags}\n", 0.04 * k as f64));
    }
    let log = parse(&text).unwrap();
    let ds = Dataset::from_log(&log, 0, &DatasetConfig::default()).unwrap();
    assert_eq!(ds.not_zeroed, 5);
    assert_eq!(ds.len(), 25);
    assert_eq!(ds.t[0], 0.2);
    assert!(ds
        .p
        .iter()
        .zip(&ds.v)
        .all(|(p, v)| (p - 0.1 * v).abs() < 1e-12));
    assert!(ds
        .split_description()
        .contains("5 frames before the pressure zero"));
    // A log with the `flags` column is the firmware's frames (means over each frame); one
    // without it is not said to be.
    assert!(ds.firmware_frames);
    let plain = text
        .replace(",flags\n", "\n")
        .replace(",65536\n", "\n")
        .replace(",0\n", "\n");
    let ds = Dataset::from_log(&parse(&plain).unwrap(), 0, &DatasetConfig::default()).unwrap();
    assert!(!ds.firmware_frames && ds.not_zeroed == 0 && ds.len() == 30);
    // Other bits (a warning such as MODEL_RANGE) keep the row.
    let kept = parse(&text.replace(",65536\n", &format!(",{}\n", 1 << 17))).unwrap();
    let ds = Dataset::from_log(&kept, 0, &DatasetConfig::default()).unwrap();
    assert_eq!((ds.not_zeroed, ds.len()), (0, 30));
    // A cell that is not an unsigned integer is an error naming the sample.
    let bad = parse(&text.replacen(",0.4,65536\n", ",0.4,zero\n", 1)).unwrap();
    let err = Dataset::from_log(&bad, 0, &DatasetConfig::default()).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("t = 0 s") && msg.contains("\"zero\""), "{msg}");
}

#[test]
fn comments_anywhere_are_kept_and_lines_stay_the_files() {
    // Read row by row, a comment after the header is still collected, and an error after it
    // names the file's own line (the comment line counts).
    let text = "\u{feff}# a=1\ntime_s,volume_mm3,pressure_kpa\n0,1,2\n# b=2\n0.1,1,2\n";
    let log = parse(text).unwrap();
    assert_eq!(log.comments, ["a=1", "b=2"]);
    assert_eq!(log.samples.len(), 2);
    let e = parse(&format!("{text}0.2,x,2\n")).unwrap_err();
    assert!(matches!(e, LogError::BadValue { line: 6, .. }), "{e:?}");
    let mut bytes = b"time_s,volume_mm3,pressure_kpa\n0,1,2\n0.1,".to_vec();
    bytes.extend([0xff, 0xfe]);
    bytes.extend(b",2\n");
    let e = parse_log(&bytes[..], "bad.csv").unwrap_err();
    assert_eq!(e.to_string(), "bad.csv:3: invalid UTF-8");
}

/// What a reading loop produced: every (sample, extra cell) and then the comments or the first
/// error's message.
type Outcome = (Vec<(Sample, String)>, Result<Vec<String>, String>);

fn read_row_by_row(bytes: &[u8]) -> Outcome {
    let opts = sysid::log::ReadOptions::default();
    let mut rows = match sysid::log::LogReader::new(bytes, "t.csv", &opts) {
        Ok(r) => r,
        Err(e) => return (Vec::new(), Err(e.to_string())),
    };
    let mut out = Vec::new();
    loop {
        match rows.next_sample() {
            Ok(Some(s)) => out.push((s, rows.extra_cell(0).to_string())),
            Ok(None) => return (out, Ok(rows.into_comments())),
            Err(e) => return (out, Err(e.to_string())),
        }
    }
}

fn read_two_threads(bytes: &[u8]) -> Outcome {
    let opts = sysid::log::ReadOptions::default();
    let rows = match sysid::log::LogReader::new(bytes, "t.csv", &opts) {
        Ok(r) => r,
        Err(e) => return (Vec::new(), Err(e.to_string())),
    };
    let mut out = Vec::new();
    let end = rows.for_each(|s, row| out.push((s.clone(), row.extra_cell(0).to_string())));
    (out, end.map_err(|e| e.to_string()))
}

/// The file reader's two-thread loop (`LogReader::for_each`, used by `LogData::read`) gives what
/// the one-row loop (`next_sample`) gives: the same samples, extra cells and comments, and the
/// same first error wherever it sits (in the first batch of rows, many batches in, on the last
/// line, past comment lines). The one-row loop stops at its first error; so does the other, and
/// the rows before it are the same.
#[test]
fn the_two_thread_reader_matches_the_row_loop() {
    let rows = 1_300;
    let line = |i: usize| {
        format!(
            "{},{},{},{},{},n{i}\n",
            0.04 * (i / 3) as f64 + 0.001,
            i % 3,
            (i % 97) as f64 * 1.5,
            (i % 13) as f64 - 6.0,
            0.01 * (i % 41) as f64
        )
    };
    let log = |bad: Option<(usize, &str)>| -> Vec<u8> {
        let mut s =
            String::from("# rig=A\ntime_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa,note\n");
        for i in 0..rows {
            if i % 250 == 7 {
                s += &format!("# comment {i}\n");
            }
            match bad {
                Some((k, text)) if k == i => s += text,
                _ => s += &line(i),
            }
        }
        s += "# last\n";
        s.into_bytes()
    };
    let mut cases = vec![log(None)];
    for at in [0, 3, 511, 512, 700, 1_299] {
        cases.push(log(Some((at, "1e9,0,x,0,0,bad\n"))));
        cases.push(log(Some((at, "0.5,0,1,2\n"))));
        if at > 3 {
            // Time going back within its chamber (not an error on the chamber's first row).
            cases.push(log(Some((at, "0,1,1,1,1,early\n"))));
        }
    }
    let mut utf8 = log(None);
    let at = utf8.len() / 2;
    utf8[at] = 0xff;
    cases.push(utf8);
    cases.push(b"time_s,volume_mm3,pressure_kpa\n# nothing\n".to_vec());
    for (k, bytes) in cases.iter().enumerate() {
        let one = read_row_by_row(bytes);
        let two = read_two_threads(bytes);
        assert_eq!(one.1, two.1, "case {k}");
        assert_eq!(one.0.len(), two.0.len(), "case {k}");
        assert!(one.0 == two.0, "case {k}: the rows differ");
    }
    // The good file and the errors are what the cases meant.
    let good = read_two_threads(&cases[0]);
    assert_eq!(good.0.len(), rows);
    assert_eq!(good.1.as_ref().unwrap().len(), 8);
    assert!(cases[1..].iter().all(|c| read_two_threads(c).1.is_err()));
}

/// A file of many blocks (the reader checks UTF-8 and collects comments 64 KiB of whole lines at a
/// time once past the header): every comment is collected in order, wherever it falls, and an
/// error names its own line of the file, counted here line by line.
#[test]
fn a_long_file_keeps_its_comments_and_its_line_numbers() {
    let mut text = String::from("# head\ntime_s,volume_mm3,pressure_kpa,note\n");
    let mut comments = vec!["head".to_string()];
    // Rows of differing widths, so that comments land at every offset of a block.
    for i in 0..40_000 {
        if i % 997 == 13 {
            let c = format!("c{i}");
            text += &format!("# {c}\r\n");
            comments.push(c);
        }
        text += &format!(
            "{},{},{},{}\n",
            i,
            i % 89,
            (i % 7) as f64 * 0.5,
            "x".repeat(i % 17)
        );
    }
    let log = parse(&text).unwrap();
    assert_eq!(log.samples.len(), 40_000);
    assert_eq!(log.comments, comments);
    let lines: Vec<&str> = text.split_inclusive('\n').collect();
    assert!(text.len() > 10 * 64 * 1024, "{} bytes", text.len());
    // An error on each of a few lines far into the file: the line number is the file's.
    for target in [30_001usize, 33_333, lines.len()] {
        let at: usize = lines[..target - 1].iter().map(|l| l.len()).sum();
        if lines[target - 1].trim_start().starts_with('#') {
            continue;
        }
        let mut bytes = text.clone().into_bytes();
        bytes[at] = 0xff;
        let e = parse_log(&bytes[..], "big.csv").unwrap_err();
        assert_eq!(e.to_string(), format!("big.csv:{target}: invalid UTF-8"));
        let mut bad = text.clone();
        bad.replace_range(at..at + 1, "y");
        match parse(&bad).unwrap_err() {
            LogError::BadValue { line, .. } => assert_eq!(line, target as u64),
            e => panic!("{e:?}"),
        }
    }
}

/// A file that is no log stops at a clear error naming its line, with the rows before it read,
/// and without being read whole: a line of megabytes without a line end (in the header, in the
/// first block, far into the file) and a quote left open over megabytes of short lines. Rows and
/// lines of up to a megabyte still read.
#[test]
fn a_line_or_quoted_field_of_megabytes_is_an_error_at_its_line() {
    let head = "time_s,volume_mm3,pressure_kpa,note\n";
    let rows = |from: usize, n: usize| -> String {
        (from..from + n)
            .map(|i| format!("{},{},{},n\n", 0.04 * i as f64, i % 7, 0.5))
            .collect()
    };
    let blob = "x".repeat(3 << 20);
    // Read both ways (the two-thread file loop and the row loop): the rows before, the error.
    let check = |bytes: &[u8], good_rows: usize, line: u64, what: &str| {
        for (k, (out, end)) in [read_two_threads(bytes), read_row_by_row(bytes)]
            .into_iter()
            .enumerate()
        {
            assert_eq!(out.len(), good_rows, "{what}, reader {k}");
            let e = end.unwrap_err();
            assert!(
                e.starts_with(&format!("t.csv:{line}: ")),
                "{what}, reader {k}: {e}"
            );
            assert!(e.len() < 200, "{what}: the message quotes the blob");
        }
    };
    // The header line itself.
    check(format!("# a\n{blob}\n").as_bytes(), 0, 2, "header");
    // A long line right after the header and far into the file (past many blocks).
    for n in [0, 5_000] {
        let text = format!("{head}{}{blob}", rows(0, n));
        check(text.as_bytes(), n, n as u64 + 2, "line");
        let text = format!("{head}{}1,2,3,{blob}\n{}", rows(0, n), rows(n, 3));
        check(text.as_bytes(), n, n as u64 + 2, "line with its end");
    }
    // A quote left open, its field running on over short lines.
    let open = "y\n".repeat(1 << 20);
    for n in [0, 5_000] {
        let text = format!("{head}{}9,1,1,\"note\n{open}", rows(0, n));
        check(text.as_bytes(), n, n as u64 + 2, "open quote");
    }
    let text = format!("\"time_s\n{open}");
    check(text.as_bytes(), 0, 1, "open quote in the header");
    // Just under the limits: a long note and a quoted field over many lines read.
    let long = "z".repeat((1 << 20) - 100);
    let quoted = "q\n".repeat(200_000);
    let text = format!("{head}0,1,1,{long}\n0.04,1,1,\"{quoted}\"\n0.08,1,1,n\n");
    let (out, end) = read_two_threads(text.as_bytes());
    assert!(end.is_ok(), "{end:?}");
    assert_eq!(out.len(), 3);
}
