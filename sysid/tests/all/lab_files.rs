//! A lab's own CSV files (docs/log-format.md, "Other layouts"): the delimiter is detected, columns
//! and units are mapped by a `--columns` spec, chambers may count from 1, and the errors say
//! where and what. The spec parser never panics on any input and always says what is wrong.

use proptest::prelude::*;
use sysid::columns::{ColumnMap, Quantity, ReadOptions};
use sysid::log::{detect_delimiter, parse_log, parse_log_with, LogError};

const COMMA: &str = "# sample_rate_hz=25\ntime_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa\n\
                     0,0,0,10,0.5\n0.04,0,0.4,10,0.7\n0.08,0,0.8,10,0.9\n";

#[test]
fn semicolon_and_tab_files_read_like_the_comma_file() {
    let want = parse_log(COMMA.as_bytes(), "comma.csv").unwrap();
    for sep in [";", "\t"] {
        let text = COMMA.replace(',', sep);
        let got = parse_log(text.as_bytes(), "other.csv").unwrap();
        assert_eq!(got, want, "delimiter {sep:?}");
    }
    assert_eq!(detect_delimiter("# a,b,c\nx;y;z\n1;2;3\n"), b';');
    assert_eq!(detect_delimiter("\"a;b\",c\n"), b',');
    assert_eq!(detect_delimiter("single\n1\n"), b',');
}

#[test]
fn mapped_columns_and_units_convert_to_the_formats_units() {
    // 1.5 mL = 1500 mm³, 2 mL/s = 2000 mm³/s, 10 cmH2O = 0.980665 kPa, 40 ms = 0.04 s.
    let text =
        "t_ms;ch;V_ml;Q_ml_s;P_cmH2O;note\n0;1;1.5;2;10;a\n40;1;1.6;2;10.5;b\n40;2;0;0;0;c\n";
    let opts = ReadOptions {
        columns: "time=t_ms:ms,chamber=ch,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O"
            .parse()
            .unwrap(),
        chamber_base: 1,
    };
    let log = parse_log_with(text.as_bytes(), "lab.csv", &opts).unwrap();
    let s = &log.samples[0];
    assert_eq!((s.time_s, s.chamber), (0.0, 0));
    assert_eq!(s.volume_mm3, 1500.0);
    assert_eq!(s.flow_mm3_s, Some(2000.0));
    assert!((s.pressure_kpa - 0.980665).abs() < 1e-15);
    assert_eq!(log.samples[1].time_s, 0.04);
    assert_eq!(log.samples[2].chamber, 1);
    assert_eq!(log.extra_columns, ["note"]);
}

#[test]
fn errors_say_where_and_mention_columns() {
    let e = parse_log("t;V;P\n0;1;2\n".as_bytes(), "lab.csv").unwrap_err();
    let msg = e.to_string();
    assert!(
        msg.starts_with("lab.csv:1: missing column `time_s` (header has: t,V,P)"),
        "{msg}"
    );
    assert!(msg.contains("--columns time=NAME[:UNIT]"), "{msg}");

    let opts = ReadOptions {
        columns: "time=t,volume=V:mL,pressure=P:psi,flow=Q:L/min"
            .parse()
            .unwrap(),
        chamber_base: 0,
    };
    let e = parse_log_with("t,V,P\n0,1,2\n".as_bytes(), "lab.csv", &opts).unwrap_err();
    assert!(
        e.to_string()
            .contains("--columns maps `flow` to `Q`, which the header does not have"),
        "{e}"
    );
    let opts = ReadOptions {
        columns: "time=t,volume=V:mL,pressure=P:psi".parse().unwrap(),
        chamber_base: 0,
    };
    let e = parse_log_with("t,V,P\n0,1,2\n0.1,x,2\n".as_bytes(), "lab.csv", &opts).unwrap_err();
    assert_eq!(
        e.to_string(),
        "lab.csv:3: column `V`: cannot parse as a number: \"x\""
    );

    let e = parse_log(
        "time_s,chamber,volume_mm3,pressure_kpa\n0,3,1,2\n".as_bytes(),
        "l.csv",
    )
    .unwrap_err();
    assert!(matches!(e, LogError::BadChamber { line: 2, .. }), "{e:?}");
    assert!(e.to_string().contains("--chamber-base 1"), "{e}");
    let base1 = ReadOptions {
        chamber_base: 1,
        ..ReadOptions::default()
    };
    let e = parse_log_with(
        "time_s,chamber,volume_mm3,pressure_kpa\n0,0,1,2\n".as_bytes(),
        "l.csv",
        &base1,
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("\"0\" is not a chamber number 1..=3"),
        "{e}"
    );
}

// ---- the spec and the unit table ----

fn factor(q: Quantity, unit: &str) -> f64 {
    q.factor(unit).expect("known unit").1
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs()
}

#[test]
fn conversions_match_hand_values() {
    use Quantity::*;
    // Standard atmosphere 101.325 kPa = 760 mmHg = 14.69595 psi = 1033.227 cmH2O = 1013.25 mbar.
    assert!(close(760.0 * factor(Pressure, "mmHg"), 101.325, 2e-7));
    assert!(close(14.69595 * factor(Pressure, "psi"), 101.325, 1e-6));
    assert!(close(1033.227 * factor(Pressure, "cmH2O"), 101.325, 1e-6));
    assert!(close(1013.25 * factor(Pressure, "mbar"), 101.325, 1e-15));
    assert!(close(101325.0 * factor(Pressure, "Pa"), 101.325, 1e-15));
    // 10 cmH2O = 0.980665 kPa exactly by definition; 1 psi = 70.307 cmH2O.
    assert!(close(10.0 * factor(Pressure, "cmH2O"), 0.980665, 1e-15));
    assert!(close(
        factor(Pressure, "psi") / factor(Pressure, "cmH2O"),
        70.307,
        1e-5
    ));
    // 1 L/min = 1,000,000 mm³ per 60 s; 2 mL/s = 2000 mm³/s; 0.5 L = 500,000 mm³.
    assert!(close(factor(Flow, "L/min"), 16_666.666_666_67, 1e-12));
    assert!(close(2.0 * factor(Flow, "mL/s"), 2000.0, 1e-15));
    assert!(close(3.0 * factor(Flow, "L/s"), 3e6, 1e-15));
    assert!(close(0.5 * factor(Volume, "L"), 5e5, 1e-15));
    assert!(close(1.5 * factor(Volume, "mL"), 1500.0, 1e-15));
    assert!(close(40.0 * factor(Time, "ms"), 0.04, 1e-15));
    assert_eq!(factor(Volume, "ML"), 1e3, "units match ignoring case");
}

#[test]
fn spec_of_the_issue() {
    let m: ColumnMap = "time=t,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O"
        .parse()
        .expect("valid");
    let t = m.get(Quantity::Time);
    assert_eq!((t.header.as_str(), t.factor, t.given), ("t", 1.0, true));
    assert_eq!(m.get(Quantity::Volume).factor, 1e3);
    assert_eq!(m.get(Quantity::Pressure).header, "P_cmH2O");
    let f = m.get(Quantity::Force);
    assert_eq!((f.header.as_str(), f.given), ("force_n", false));
    assert_eq!(
        m.to_string(),
        "time=t:s,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O"
    );
    assert_eq!(m.to_string().parse::<ColumnMap>(), Ok(m));
}

#[test]
fn bad_specs_say_where_and_what() {
    let e = "time=t,flow=Q:mL/m".parse::<ColumnMap>().unwrap_err();
    assert_eq!((e.item, e.at), (2, 8));
    assert!(e.problem.contains("unknown flow unit `mL/m`"), "{e}");
    assert!(e.problem.contains("L/min"), "{e}");
    let e = "temp=t".parse::<ColumnMap>().unwrap_err();
    assert!(e.to_string().contains("unknown quantity `temp`"), "{e}");
    let e = "time=t,time=u".parse::<ColumnMap>().unwrap_err();
    assert!(e.problem.contains("mapped twice"), "{e}");
    let e = "time=t,volume=t:mL".parse::<ColumnMap>().unwrap_err();
    assert!(e.problem.contains("already mapped"), "{e}");
    let e = "pressure".parse::<ColumnMap>().unwrap_err();
    assert!(e.problem.contains("QUANTITY=HEADER"), "{e}");
    let e = "chamber=ch:idx".parse::<ColumnMap>().unwrap_err();
    assert!(e.problem.contains("--chamber-base"), "{e}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(500))]

    #[test]
    fn column_spec_parser_never_panics_and_says_what(spec in "[-a-zA-Z0-9_=:,/ ]{0,60}") {
        match spec.parse::<ColumnMap>() {
            // A spec that parses prints as one that parses to the same map.
            Ok(m) => prop_assert_eq!(m.to_string().parse::<ColumnMap>(), Ok(m)),
            Err(e) => {
                let msg = e.to_string();
                prop_assert!(msg.starts_with("--columns: item "), "{}", msg);
                prop_assert!(e.item >= 1 && e.at >= 1 && e.at <= spec.chars().count() + 1, "{}", msg);
                prop_assert!(!e.problem.is_empty());
            }
        }
    }

    #[test]
    fn well_formed_specs_parse(
        unit in prop::sample::select(vec!["kPa", "Pa", "cmH2O", "mmHg", "psi", "mbar", "KPA"]),
        header in "[A-Za-z][A-Za-z0-9_ ]{0,12}",
    ) {
        let spec = format!("pressure={header}:{unit}");
        let m: ColumnMap = spec
            .parse()
            .map_err(|e: sysid::columns::ColumnSpecError| TestCaseError::fail(e.to_string()))?;
        let p = m.get(Quantity::Pressure);
        prop_assert_eq!(p.header, header.trim());
    }
}
