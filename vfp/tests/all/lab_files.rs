//! A lab's own files give the same identification as the log they were made from: a
//! semicolon-delimited copy of the real bag-lung log, and a copy in the lab's own column names
//! and units (`t,V_ml,Q_ml_s,P_cmH2O`: s, mL, mL/s, cmH2O) read with `--columns`.
//!
//! The semicolon copy holds the same digits, so its numbers are the same f64s and the report must
//! be identical. The unit copy is not bit-identical: each value x was written as x / f (rounded
//! to the nearest f64, then printed exactly) and read back as (x / f) × f (rounded again), so
//! every volume, flow and pressure differs from the original by at most two roundings, 2⁻⁵² ≈
//! 2.2 × 10⁻¹⁶ relative. Least squares turns such data perturbations into model changes of the
//! order of the condition number of the regression times that; the degree-7 polynomials here
//! keep the RMSE within 10⁻⁹ relative (measured here: 2.6 × 10⁻¹⁰ at most; the run is
//! deterministic, so this margin does not fluctuate),
//! far below any difference between two models (the RMSEs of neighbouring shapes differ by
//! 10⁻³ relative and more), so the same model is selected.

use crate::common;
use common::root;

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use sysid::columns::Quantity;

const BAG: &str = "data/real/bag-lung-pip15-peep5.csv";

fn scratch(name: &str) -> PathBuf {
    common::scratch("lab", name)
}

fn identify(log: &Path, extra: &[&str]) -> Value {
    let out = common::ok(
        common::vfp()
            .arg("identify")
            .arg(log)
            .args(["--json", "--family", "poly", "--family", "poly-ar"])
            .args(extra),
    );
    serde_json::from_slice(&out.stdout).expect("JSON")
}

/// The models' (family, n, m, p) and RMSE, selected first.
fn models(v: &Value) -> Vec<(String, f64)> {
    let key = |m: &Value| format!("{} n={} m={} p={}", m["family"], m["n"], m["m"], m["p"]);
    std::iter::once(&v["selected"])
        .chain(v["models"].as_array().expect("models"))
        .map(|m| (key(m), m["rmse"].as_f64().expect("rmse")))
        .collect()
}

/// The log in the lab's own columns and units, converted from the original.
fn lab_copy(original: &Path, out: &Path) {
    let log = sysid::log::read_log(original).expect("the bag log reads");
    let unit = |q: Quantity, u: &str| q.factor(u).expect("known unit").1;
    let (ml, ml_s, cmh2o) = (
        unit(Quantity::Volume, "mL"),
        unit(Quantity::Flow, "mL/s"),
        unit(Quantity::Pressure, "cmH2O"),
    );
    let mut text = String::from("t,V_ml,Q_ml_s,P_cmH2O\n");
    for s in &log.samples {
        let q = s.flow_mm3_s.expect("the bag log has flow");
        text += &format!(
            "{},{},{},{}\n",
            s.time_s,
            s.volume_mm3 / ml,
            q / ml_s,
            s.pressure_kpa / cmh2o
        );
    }
    std::fs::write(out, text).expect("writable");
}

#[test]
fn semicolon_and_own_unit_copies_identify_like_the_original() {
    let dir = scratch("copies");
    let original = root().join(BAG);
    let semicolon = dir.join("bag-semicolon.csv");
    let text = std::fs::read_to_string(&original).expect("bag log");
    let converted: String = text
        .lines()
        .map(|l| {
            if l.starts_with('#') {
                l.to_string()
            } else {
                l.replace(',', ";")
            }
        })
        .collect::<Vec<_>>()
        .join("\n");
    std::fs::write(&semicolon, converted).expect("writable");
    let lab = dir.join("bag-lab-units.csv");
    lab_copy(&original, &lab);

    let want = models(&identify(&original, &[]));
    assert_eq!(models(&identify(&semicolon, &[])), want, "semicolon copy");

    let spec = "time=t,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O";
    let got = models(&identify(&lab, &["--columns", spec]));
    assert_eq!(got.len(), want.len());
    let mut worst = 0.0f64;
    for ((ka, a), (kb, b)) in got.iter().zip(&want) {
        assert_eq!(ka, kb, "the same models, the same selection");
        worst = worst.max(((a - b) / b).abs());
    }
    assert!(worst < 1e-9, "largest relative RMSE difference {worst:e}");
    eprintln!("largest relative RMSE difference, unit copy vs original: {worst:e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_missing_column_names_the_option() {
    let dir = scratch("missing");
    let lab = dir.join("bag-lab-units.csv");
    lab_copy(&root().join(BAG), &lab);
    let out = Command::new(env!("CARGO_BIN_EXE_vfp"))
        .args(["--quiet", "identify"])
        .arg(&lab)
        .output()
        .expect("vfp runs");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(
        err.contains(&format!("{}:1: missing column `time_s`", lab.display())),
        "{err}"
    );
    assert!(err.contains("--columns time=NAME[:UNIT]"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
