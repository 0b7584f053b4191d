//! `log_from_table`: an in-memory table is the file it would be written as. The truth is the file
//! reader on the text `write_log_to` writes for the same samples (bit-identical f64 by the
//! shortest round-trip form), and hand-written expectations for units and errors.

use proptest::prelude::*;
use sysid::columns::ColumnMap;
use sysid::log::{log_from_table, parse_log, write_log_to, Log, ReadOptions, Sample, TableColumn};

fn numbers(name: &str, x: Vec<f64>) -> (String, TableColumn) {
    (name.to_string(), TableColumn::Numbers(x))
}

/// The table of a log's samples under the format's names (NaN where an optional value is absent).
fn table_of(log: &Log) -> Vec<(String, TableColumn)> {
    let s = &log.samples;
    vec![
        numbers("time_s", s.iter().map(|r| r.time_s).collect()),
        numbers("chamber", s.iter().map(|r| f64::from(r.chamber)).collect()),
        numbers("volume_mm3", s.iter().map(|r| r.volume_mm3).collect()),
        numbers(
            "flow_mm3_s",
            s.iter().map(|r| r.flow_mm3_s.unwrap_or(f64::NAN)).collect(),
        ),
        numbers("pressure_kpa", s.iter().map(|r| r.pressure_kpa).collect()),
        (
            "flags".to_string(),
            TableColumn::Text(s.iter().map(|r| (r.chamber * 2).to_string()).collect()),
        ),
    ]
}

proptest! {
    #[test]
    fn a_table_reads_as_its_file(
        rows in prop::collection::vec(
            (0.0f64..1.0, 0u8..3, -1e6f64..1e6, prop::option::of(-1e5f64..1e5), -50.0f64..200.0),
            1..40,
        )
    ) {
        let mut log = Log { extra_columns: vec!["flags".into()], ..Log::default() };
        let mut t = 0.0;
        for (dt, chamber, v, q, p) in rows {
            t += dt + 1e-3;
            log.samples.push(Sample { flow_mm3_s: q, ..Sample::new(t, chamber, v, p) });
            log.extra.push(vec![(chamber * 2).to_string()]);
        }
        let mut text = Vec::new();
        write_log_to(&mut text, &log).unwrap();
        let from_file = parse_log(&text[..], "f.csv").unwrap();
        let from_table = log_from_table("t", &table_of(&log), &ReadOptions::default()).unwrap();
        prop_assert_eq!(&from_table.samples, &from_file.samples);
        prop_assert_eq!(&from_table.samples, &log.samples);
        prop_assert_eq!(from_table.extra, from_file.extra);
    }
}

#[test]
fn lab_names_and_units_are_mapped() {
    let opts = ReadOptions {
        columns: "time=t:ms,volume=V:mL,pressure=P:cmH2O"
            .parse::<ColumnMap>()
            .unwrap(),
        chamber_base: 0,
    };
    let table = vec![
        numbers("t", vec![0.0, 40.0]),
        numbers("V", vec![0.5, 1.5]),
        numbers("P", vec![10.0, 20.0]),
    ];
    let log = log_from_table("lab", &table, &opts).unwrap();
    assert_eq!(log.samples[1].time_s, 40.0 * 1e-3);
    assert_eq!(log.samples[1].volume_mm3, 1500.0);
    assert_eq!(log.samples[0].pressure_kpa, 10.0 * 0.0980665);
}

#[test]
fn errors_name_the_table_the_row_and_the_column() {
    let table = |p: Vec<f64>| {
        vec![
            numbers("time_s", vec![0.0, 0.1, 0.2]),
            numbers("volume_mm3", vec![0.0, 1.0, 2.0]),
            numbers("pressure_kpa", p),
        ]
    };
    let err = |t: Vec<(String, TableColumn)>| {
        log_from_table("frame", &t, &ReadOptions::default())
            .unwrap_err()
            .to_string()
    };
    // Row 1 (from 0) is line 3: the header is line 1.
    assert_eq!(
        err(table(vec![1.0, f64::INFINITY, 2.0])),
        "frame:3: column `pressure_kpa`: not a finite number: \"inf\""
    );
    assert_eq!(
        err(table(vec![1.0, 2.0, f64::NAN])),
        "frame:4: column `pressure_kpa`: required value is empty: \"\""
    );
    let mut short = table(vec![1.0, 2.0, 3.0]);
    short[1] = numbers("volume_mm3", vec![0.0]);
    assert_eq!(
        err(short),
        "frame:1: column `volume_mm3` has 1 rows but column `time_s` has 3"
    );
    assert!(
        err(vec![numbers("time_s", vec![0.0])]).starts_with("frame:1: missing column `volume_mm3`")
    );
    assert!(err(table(vec![])).contains("column `pressure_kpa` has 0 rows"));
    let empty = vec![
        numbers("time_s", vec![]),
        numbers("volume_mm3", vec![]),
        numbers("pressure_kpa", vec![]),
    ];
    assert!(err(empty).starts_with("frame: no data rows"));
}
