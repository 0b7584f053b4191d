//! `--units`: reports and figures in the lab's units. The truth is independent of the tool's
//! unit table: the factors are written out here by hand (1 mL = 1000 mm³, 1 cmH2O = 0.0980665 kPa,
//! the conventional centimetre of water), and the real bag-lung log is written once more in mL,
//! mL/s and cmH2O. Read with `--columns`, that copy's text report must carry every volume, flow
//! and pressure of the original's report times the hand factors, to the precision printed: a
//! number printed with its last digit worth u is within u/2 of the true value, so |y − f·x| ≤
//! (u_y + f·u_x)/2, plus 10⁻⁶ relative for the copy's rounding (each value went through
//! x / f and back, 2⁻⁵² relative; `lab_files` bounds what that does to the fit far below this).

use crate::common;
use common::root;

use std::path::{Path, PathBuf};
use std::process::Command;

const BAG: &str = "data/real/bag-lung-pip15-peep5.csv";
/// mm³ per mL.
const ML: f64 = 1000.0;
/// kPa per cmH2O.
const CMH2O: f64 = 0.0980665;
const SPEC: &str = "time=t,volume=V_ml:mL,flow=Q_ml_s:mL/s,pressure=P_cmH2O:cmH2O";

fn scratch(name: &str) -> PathBuf {
    common::scratch("units", name)
}

/// The bag log in mL, mL/s and cmH2O, by the hand factors.
fn lab_copy(out: &Path) {
    let log = sysid::log::read_log(root().join(BAG)).expect("the bag log reads");
    let mut text = String::from("t,V_ml,Q_ml_s,P_cmH2O\n");
    for s in &log.samples {
        let q = s.flow_mm3_s.expect("the bag log has flow");
        text += &format!(
            "{},{},{},{}\n",
            s.time_s,
            s.volume_mm3 / ML,
            q / ML,
            s.pressure_kpa / CMH2O
        );
    }
    std::fs::write(out, text).expect("writable");
}

/// Runs `vfp ARGS` and returns its standard output.
fn run(args: &[&str], log: &Path) -> String {
    let mut c = common::vfp();
    c.arg(args[0]).arg(log).args(&args[1..]);
    String::from_utf8(common::ok(&mut c).stdout).expect("UTF-8")
}

/// A number as printed and the worth of its last digit.
fn printed(word: &str) -> Option<(f64, f64)> {
    let w = word.trim_start_matches(['(', '[']);
    let x: f64 = w.parse().ok()?;
    let (mantissa, exp) = match w.split_once(['e', 'E']) {
        Some((m, e)) => (m, e.parse::<i32>().ok()?),
        None => (w, 0),
    };
    let decimals = mantissa.split_once('.').map_or(0, |(_, f)| f.len()) as i32;
    Some((x, 10f64.powi(exp - decimals)))
}

/// Every "NUMBER UNIT" of `text` whose unit is in `units` (and the first number of "X to Y UNIT",
/// "X → Y UNIT", "X against Y UNIT"), in order: (value, last digit's worth, unit).
fn pairs(text: &str, units: &[&str]) -> Vec<(f64, f64, String)> {
    let mut out = Vec::new();
    for line in text.lines() {
        let w: Vec<&str> = line.split_whitespace().collect();
        for i in 1..w.len() {
            let unit = w[i].trim_end_matches([',', ';', ')', ':']);
            if !units.contains(&unit) {
                continue;
            }
            let Some((x, u)) = printed(w[i - 1]) else {
                continue;
            };
            if i >= 3 && ["to", "→", "->", "against"].contains(&w[i - 2]) {
                if let Some((x0, u0)) = printed(w[i - 3]) {
                    out.push((x0, u0, unit.to_string()));
                }
            }
            out.push((x, u, unit.to_string()));
        }
    }
    out
}

/// Whether `y` (printed to `uy`) is `f·x` (printed to `ux`) to print precision.
fn close(y: f64, uy: f64, x: f64, ux: f64, f: f64) -> bool {
    (y - f * x).abs() <= 0.5 * uy + 0.5 * ux * f.abs() + 1e-6 * y.abs() + 1e-300
}

/// Checks that `lab`'s numbers in `map`'s second units are `canon`'s in its first units times
/// the factor: (canonical unit, lab unit, factor from the canonical to the lab unit).
fn same_numbers(canon: &str, lab: &str, map: &[(&str, &str, f64)]) -> usize {
    let a = pairs(canon, &map.iter().map(|m| m.0).collect::<Vec<_>>());
    let b = pairs(lab, &map.iter().map(|m| m.1).collect::<Vec<_>>());
    assert_eq!(
        a.len(),
        b.len(),
        "as many numbers with units:\n{a:?}\n{b:?}\n{lab}"
    );
    for ((x, ux, ua), (y, uy, ub)) in a.iter().zip(&b) {
        let (_, want, f) = map.iter().find(|m| m.0 == ua).expect("mapped");
        assert_eq!(ub, want, "{x} {ua} against {y} {ub}");
        assert!(
            close(*y, *uy, *x, *ux, *f),
            "{y} {ub} is not {x} {ua} × {f}"
        );
    }
    a.len()
}

/// Table II's training and held-out RMSE columns and Table IV's coefficients and standard errors
/// with the powers (i, j) of their term vⁱ v̇ʲ (RMSE rows: (0, 0)).
/// A number as printed and its last digit's worth.
type Printed = (f64, f64);

/// A coefficient and its standard error as printed, with the total power i + j of its term.
type Coefficient = (Printed, Printed, usize);

fn tables(text: &str) -> (Vec<Printed>, Vec<Coefficient>) {
    let mut rmse = Vec::new();
    let mut coef = Vec::new();
    let mut section = 0;
    for line in text.lines() {
        if line.starts_with("Table II.") {
            section = 2;
        } else if line.starts_with("Table IV.") {
            section = 4;
        } else if line.contains("Reduced models") || line.is_empty() {
            section = 0;
        }
        let w: Vec<&str> = line.split_whitespace().collect();
        if section == 2 && line.starts_with("  ") && line.contains(" | ") && !line.contains("RMSE")
        {
            let (left, right) = line.split_once(" | ").unwrap();
            let l: Vec<&str> = left.split_whitespace().collect();
            rmse.push(printed(l[l.len() - 4]).expect("training RMSE"));
            if let Some(h) = printed(right.split_whitespace().next().unwrap()) {
                rmse.push(h);
            }
        }
        if section == 4 && w.len() >= 5 && printed(w[w.len() - 4]).is_some() {
            let term = &w[..w.len() - 4];
            let power = |s: &str, base: &str| -> usize {
                if s == base {
                    1
                } else {
                    s.strip_prefix(base)
                        .and_then(|r| r.strip_prefix('^'))
                        .map_or(0, |k| k.parse().unwrap())
                }
            };
            // "1", "v^2", "vdot", "v^2 vdot^3": the total power of volume and flow, i + j.
            let ij: usize = term
                .iter()
                .map(|t| {
                    if t.starts_with("vdot") {
                        power(t, "vdot")
                    } else {
                        power(t, "v")
                    }
                })
                .sum();
            coef.push((
                printed(w[w.len() - 4]).unwrap(),
                printed(w[w.len() - 3]).unwrap(),
                ij,
            ));
        }
    }
    (rmse, coef)
}

#[test]
fn a_file_in_ml_and_cmh2o_is_reported_in_ml_and_cmh2o() {
    let dir = scratch("identify");
    let lab = dir.join("bag-ml-cmh2o.csv");
    lab_copy(&lab);
    let args = ["identify", "--family", "poly"];
    let canon = run(&args, &root().join(BAG));
    let mine = run(&[&args[..], &["--columns", SPEC]].concat(), &lab);
    // Every "NUMBER kPa" is a "NUMBER cmH2O" here, f = 1/0.0980665.
    let n = same_numbers(&canon, &mine, &[("kPa", "cmH2O", 1.0 / CMH2O)]);
    assert!(n >= 10, "{n} pressures compared");
    // The tables' RMSE columns, and αᵢⱼ × 1000^(i+j) / 0.0980665.
    let (ra, ca) = tables(&canon);
    let (rb, cb) = tables(&mine);
    assert_eq!((ra.len(), ca.len()), (rb.len(), cb.len()));
    assert!(
        ra.len() >= 49 * 2 && ca.len() >= 4,
        "{} {}",
        ra.len(),
        ca.len()
    );
    for ((x, ux), (y, uy)) in ra.iter().zip(&rb) {
        assert!(close(*y, *uy, *x, *ux, 1.0 / CMH2O), "RMSE {y} vs {x}");
    }
    for (a, b) in ca.iter().zip(&cb) {
        assert_eq!(a.2, b.2, "the same term");
        let f = ML.powi(a.2 as i32) / CMH2O;
        for ((x, ux), (y, uy)) in [(a.0, b.0), (a.1, b.1)] {
            assert!(close(y, uy, x, ux, f), "coefficient {y} vs {x} × {f}");
        }
    }
    assert!(mine.contains(
        "Table IV. Coefficients of the polynomial model (n = 5, m = 3), units cmH2O, mL, mL/s"
    ));
    // No number is left in the format's units but the AICc/BIC note says what stays.
    for line in mine.lines().filter(|l| !l.contains("AICc and BIC from")) {
        assert!(
            !line.contains(" kPa") && !line.contains(" mm3"),
            "left in the format's units: {line}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn units_override_the_files_units_and_the_default() {
    let dir = scratch("override");
    let lab = dir.join("bag-ml-cmh2o.csv");
    lab_copy(&lab);
    let canon = run(&["identify", "--family", "poly"], &root().join(BAG));
    // The mL/cmH2O file shown in the format's units again: the original's numbers.
    let back = run(
        &[
            "identify",
            "--family",
            "poly",
            "--columns",
            SPEC,
            "--units",
            "mm3,kPa",
        ],
        &lab,
    );
    let n = same_numbers(&canon, &back, &[("kPa", "kPa", 1.0)]);
    assert!(n >= 10);
    assert!(!back.contains("cmH2O"));
    // The original in L and Pa, in either order and any case: 1 kPa = 1000 Pa.
    let pa = run(
        &["identify", "--family", "poly", "--units", "pa,l"],
        &root().join(BAG),
    );
    same_numbers(&canon, &pa, &[("kPa", "Pa", 1000.0)]);
    assert!(pa.contains("units Pa, L, L/s"), "{pa}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bad_unit_name_says_what_is_accepted() {
    let out = Command::new(env!("CARGO_BIN_EXE_vfp"))
        .current_dir(root())
        .args(["--quiet", "identify", BAG, "--units", "mL,furlong"])
        .output()
        .expect("vfp runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let first = err.lines().next().unwrap_or_default();
    for want in [
        "--units",
        "unknown unit `furlong`",
        "volume: mm3, uL, mL, cm3, L",
        "pressure: kPa, Pa, hPa, mbar, bar, cmH2O, mmHg, psi",
    ] {
        assert!(
            first.contains(want),
            "{want:?} not in the first line: {err}"
        );
    }
}

/// The text of an SVG's `<text>` elements (plotters writes each on the line after its tag).
fn svg_text(path: &Path) -> Vec<String> {
    let svg = std::fs::read_to_string(path).expect("SVG");
    let lines: Vec<&str> = svg.lines().collect();
    lines
        .windows(2)
        .filter(|w| w[0].trim_start().starts_with("<text"))
        .map(|w| w[1].trim().to_string())
        .collect()
}

#[test]
fn figures_carry_the_units_in_their_axis_titles() {
    let dir = scratch("figures");
    let lab = dir.join("bag-ml-cmh2o.csv");
    lab_copy(&lab);
    let plots = dir.join("identify");
    let mut c = common::vfp();
    c.args(["identify"])
        .arg(&lab)
        .args(["--family", "poly", "--columns", SPEC, "--plots"])
        .arg(&plots);
    common::ok(&mut c);
    let vp = svg_text(&plots.join("ch0-vp.svg"));
    for want in ["volume (mL)", "pressure (cmH2O)"] {
        assert!(vp.iter().any(|t| t == want), "{want} not in {vp:?}");
    }
    let resid = svg_text(&plots.join("ch0-residual-vs-volume.svg"));
    assert!(resid.iter().any(|t| t == "P - P_hat (cmH2O)"), "{resid:?}");
    let bars = svg_text(&plots.join("ch0-poly-rmse-aicc.svg"));
    assert!(
        bars.iter().any(|t| t == "RMSE, training (cmH2O)"),
        "{bars:?}"
    );
    // The pressures drawn are the file's: the V-P figure's pressure ticks span cmH2O (5 to 15
    // cmH2O on this ventilator), not kPa (0.5 to 1.5).
    let ticks: Vec<f64> = vp.iter().filter_map(|t| t.parse().ok()).collect();
    assert!(ticks.iter().any(|&t| t >= 10.0), "{ticks:?}");

    let plots = dir.join("diagnose");
    let mut c = common::vfp();
    c.args(["diagnose", BAG, "--units", "mL,cmH2O", "--plots"])
        .arg(&plots);
    let text = String::from_utf8(common::ok(&mut c).stdout).expect("UTF-8");
    assert!(text.contains(" cmH2O") && !text.contains(" kPa"), "{text}");
    for f in ["resid-before.svg", "resid-after.svg"] {
        let t = svg_text(&plots.join(f));
        for want in [
            "residual (cmH2O)",
            "volume (mL)",
            "|flow| (mL/s)",
            "mean residual (cmH2O)",
            "log10 PSD (cmH2O²/Hz)",
        ] {
            assert!(t.iter().any(|x| x == want), "{f}: {want} not in {t:?}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn diagnose_reports_effect_parameters_in_the_units() {
    // A simulated log with hysteresis (a width in mm³, gaps in kPa), as the golden test makes it.
    let dir = scratch("diagnose");
    let mut c = common::vfp();
    c.current_dir(&dir).args([
        "simulate",
        "--preset",
        "effect:hysteresis",
        "--seed",
        "14",
        "--cycles",
        "1",
        "--flows",
        "40,100",
        "--out",
        "hysteresis.csv",
    ]);
    common::ok(&mut c);
    let log = dir.join("hysteresis.csv");
    let args = ["diagnose", "--chamber", "1"];
    let canon = run(&args, &log);
    let mine = run(&[&args[..], &["--units", "mL,cmH2O"]].concat(), &log);
    assert!(canon.contains("width = "), "{canon}");
    let n = same_numbers(
        &canon,
        &mine,
        &[
            ("kPa", "cmH2O", 1.0 / CMH2O),
            ("mm3", "mL", 1.0 / ML),
            ("mm3/s", "mL/s", 1.0 / ML),
        ],
    );
    assert!(n >= 8, "{n}");
    // The parameters' values ("NAME = VALUE ± SE UNIT"; the SE is among the pairs above).
    let values = |text: &str| -> Vec<((f64, f64), String)> {
        text.lines()
            .filter_map(|l| {
                let w: Vec<&str> = l.split_whitespace().collect();
                (w.len() >= 6 && w[1] == "=" && w[3] == "±")
                    .then(|| (printed(w[2]).expect("a value"), w[5].to_string()))
            })
            .collect()
    };
    let (va, vb) = (values(&canon), values(&mine));
    assert_eq!(va.len(), vb.len());
    assert!(va.len() >= 3, "{va:?}");
    for (((x, ux), ua), ((y, uy), ub)) in va.iter().zip(&vb) {
        let (want, f) = match ua.as_str() {
            "kPa" => ("cmH2O", 1.0 / CMH2O),
            "mm3" => ("mL", 1.0 / ML),
            "mm3/s" => ("mL/s", 1.0 / ML),
            other => (other, 1.0),
        };
        assert_eq!(ub, want);
        assert!(close(*y, *uy, *x, *ux, f), "{y} {ub} is not {x} {ua} × {f}");
    }
    let width = mine
        .lines()
        .find(|l| l.contains("width = "))
        .expect("the hysteresis width");
    assert!(width.contains(" mL "), "{width}");
    for line in mine.lines() {
        assert!(
            !line.contains(" kPa") && !line.contains(" mm3"),
            "left in the format's units: {line}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn stiffness_in_the_units_and_json_unchanged() {
    let bag = root().join(BAG);
    let json = run(&["stiffness", "--json"], &bag);
    // JSON stays in the format's units whatever --units says.
    assert_eq!(
        run(&["stiffness", "--json", "--units", "mL,cmH2O"], &bag),
        json
    );
    let v: serde_json::Value = serde_json::from_str(&json).expect("JSON");
    let (k, c) = (
        v["k_mean"].as_f64().expect("k_mean"),
        v["c_mean"].as_f64().expect("c_mean"),
    );
    let text = run(&["stiffness", "--units", "mL,cmH2O"], &bag);
    assert!(text.contains("k (cmH2O/mL) c (cmH2O s/mL)"), "{text}");
    let all: Vec<&str> = text
        .lines()
        .find(|l| l.trim_start().starts_with("all "))
        .expect("the all row")
        .split_whitespace()
        .collect();
    // kPa/mm³ → cmH2O/mL: × 1000 / 0.0980665 (k of a ventilator's bag is 10⁻⁵ kPa/mm³, 0.05
    // cmH2O/mL: five printed decimals show it only in the lab's units).
    let f = ML / CMH2O;
    for (word, x) in [(all[1], k), (all[2], c)] {
        let (y, uy) = printed(word).expect("a number");
        assert!(close(y, uy, x, 0.0, f), "{y} is not {x} × {f}");
        assert!(y != 0.0);
    }
}
