//! `vfp diagnose A --validate B`: the loop's models, fitted on A, on every row of B.
//!
//! Truths: an identity (validating on A itself reproduces the loop's own train and held-out
//! errors), and host-sim plants (the same wall hysteresis on another run of the rig lowers B's
//! error as it lowered A's; a rig without it gains nothing from it; an air pocket found on A does
//! not carry to a rig without air, while the rig's own delivery lag, which every host-sim rig
//! has, does).

use crate::common;

use common::{ok, scratch, vfp};
use std::path::{Path, PathBuf};

/// `vfp simulate --preset PRESET --cycles C --seed S` into `dir`.
fn simulate(dir: &Path, name: &str, preset: &str, cycles: u32, seed: u64) -> PathBuf {
    let out = dir.join(name);
    ok(vfp()
        .args(["simulate", "--preset", preset, "--cycles"])
        .arg(cycles.to_string())
        .arg("--seed")
        .arg(seed.to_string())
        .arg("-o")
        .arg(&out));
    out
}

fn diagnose(a: &Path, b: &Path, extra: &[&str]) -> serde_json::Value {
    let out = ok(vfp()
        .arg("diagnose")
        .arg(a)
        .arg("--validate")
        .arg(b)
        .arg("--json")
        .args(extra));
    serde_json::from_slice(&out.stdout).expect("JSON")
}

/// The names of the effects a diagnosis kept, in order.
fn effect_names(d: &serde_json::Value) -> Vec<&str> {
    d["effects"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| e["name"].as_str().unwrap())
        .collect()
}

fn f(v: &serde_json::Value, path: &[&str]) -> f64 {
    let mut x = v;
    for p in path {
        x = &x[*p];
    }
    x.as_f64().unwrap_or_else(|| panic!("{path:?} in {v}"))
}

#[test]
fn validating_on_the_log_itself_gives_the_loops_own_errors() {
    let dir = scratch("validate", "self");
    let a = simulate(&dir, "a.csv", "effect:hysteresis", 2, 1);
    let d = diagnose(&a, &a, &[]);
    let (train, held) = (
        d["samples"][0].as_f64().unwrap(),
        d["samples"][1].as_f64().unwrap(),
    );
    // Every row of A is a training or a held-out row, so the RMSE over all of them is the two
    // RMSEs pooled.
    let pooled = |what: &str| {
        let (t, h) = (f(&d, &[what, "rmse_train"]), f(&d, &[what, "rmse_heldout"]));
        ((train * t * t + held * h * h) / (train + held)).sqrt()
    };
    let v = &d["validation"];
    assert_eq!(v["samples"].as_f64().unwrap(), train + held);
    for (what, key) in [("baseline", "baseline_rmse"), ("final", "final_rmse")] {
        let (got, want) = (f(v, &[key]), pooled(what));
        assert!((got - want).abs() <= 1e-9 * want, "{what}: {got} vs {want}");
    }
    let steps = v["steps"].as_array().expect("steps");
    assert_eq!(steps.len(), d["effects"].as_array().unwrap().len());
    assert_eq!(f(&steps[steps.len() - 1], &["rmse"]), f(v, &["final_rmse"]));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn an_effect_of_the_rig_holds_on_another_run_and_not_on_another_rig() {
    let dir = scratch("validate", "rigs");
    let a = simulate(&dir, "a.csv", "effect:hysteresis", 3, 1);
    let same = simulate(&dir, "same.csv", "effect:hysteresis", 2, 2);
    let other = simulate(&dir, "other.csv", "paper", 2, 3);
    let d = diagnose(&a, &same, &[]);
    let names = effect_names(&d);
    assert_eq!(names.first(), Some(&"hysteresis"), "{names:?}");
    let v = &d["validation"];
    let (base, fin) = (f(v, &["baseline_rmse"]), f(v, &["final_rmse"]));
    // The same rig: the error falls on B as on A's held-out cycles, to near A's final error.
    assert!(fin < 0.5 * base, "same rig: {base} -> {fin}");
    assert!(fin < 2.0 * f(&d, &["final", "rmse_heldout"]), "{d}");
    // And the hysteresis carries over: B's own polynomial gains from it.
    assert_eq!(carries(v, "hysteresis"), Some(true), "{v}");
    // Another rig (no wall hysteresis): the hysteresis step gains it next to nothing.
    let d = diagnose(&a, &other, &[]);
    let v = &d["validation"];
    let base = f(v, &["baseline_rmse"]);
    let hyst = f(&v["steps"][0], &["rmse"]);
    assert!(
        (base - hyst).abs() < 0.02 * base,
        "another rig: hysteresis moves {base} -> {hyst}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Whether `effect`'s carry-over in validation `v` says it carries (`None`: not listed).
fn carries(v: &serde_json::Value, effect: &str) -> Option<bool> {
    v["carry_over"]
        .as_array()?
        .iter()
        .find(|c| c["effect"] == effect)
        .map(|c| c["carries"].as_bool().unwrap())
}

#[test]
fn an_air_pocket_does_not_carry_to_a_rig_without_air() {
    let dir = scratch("validate", "carry");
    let a = simulate(&dir, "air.csv", "effect:air", 3, 4);
    let other = simulate(&dir, "other.csv", "paper", 2, 3);
    let d = diagnose(&a, &other, &[]);
    let names = effect_names(&d);
    assert!(names.contains(&"air_compliance"), "{names:?}");
    let v = &d["validation"];
    assert_eq!(carries(v, "air_compliance"), Some(false), "{v}");
    // A's whole model does not hold there either, while each effect that carries lowers B's
    // held-out error beside the others.
    let all = v["carry_over"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["effect"] == "all")
        .expect("all");
    assert_eq!(all["carries"], false, "{v}");
    for c in v["carry_over"].as_array().unwrap() {
        if c["carries"] == true {
            assert!(f(c, &["with_rmse"]) < f(c, &["without_rmse"]), "{c}");
        }
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_bad_other_log_is_a_clear_error() {
    let dir = scratch("validate", "bad");
    let a = simulate(&dir, "a.csv", "paper", 2, 1);
    let run = |b: &Path, extra: &[&str]| {
        let out = vfp()
            .arg("diagnose")
            .arg(&a)
            .arg("--validate")
            .arg(b)
            .args(extra)
            .output()
            .expect("runs");
        assert!(!out.status.success(), "{b:?} accepted");
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let missing = dir.join("missing.csv");
    let e = run(&missing, &[]);
    assert!(e.contains("missing.csv"), "{e}");
    // A chamber the other log does not have.
    let one = dir.join("one.csv");
    let text = std::fs::read_to_string(&a).unwrap();
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| {
            !l.starts_with(|c: char| c.is_ascii_digit()) || l.split(',').nth(1) == Some("1")
        })
        .collect();
    std::fs::write(&one, kept.join("\n")).unwrap();
    let e = run(&one, &["--chamber", "0"]);
    assert!(e.contains("one.csv") && e.contains("chamber"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// One rig at two operating points (issue 35): host-sim's wall-hysteresis preset run at 20 and
/// 40 mm³/s (A) and at 70 and 100 mm³/s (B), whose pressures and flows A never reaches. The
/// planted hysteresis carries both ways, as does the rig's own delivery lag: B's own polynomial,
/// refitted with and without it at A's parameters, gains from it on B's held-out cycles.
#[test]
fn a_planted_effect_carries_between_two_operating_points_of_one_rig() {
    let dir = scratch("validate", "operating-points");
    let run = |name: &str, flows: &str, seed: u64| {
        let out = dir.join(name);
        ok(vfp()
            .args(["simulate", "--preset", "effect:hysteresis", "--cycles", "3"])
            .args(["--flows", flows, "--seed"])
            .arg(seed.to_string())
            .arg("-o")
            .arg(&out));
        out
    };
    let lo = run("lo.csv", "20,40", 1);
    let hi = run("hi.csv", "70,100", 2);
    for (a, b) in [(&lo, &hi), (&hi, &lo)] {
        let d = diagnose(a, b, &[]);
        let names = effect_names(&d);
        assert!(names.contains(&"hysteresis"), "{names:?}");
        assert_eq!(carries(&d["validation"], "hysteresis"), Some(true), "{d}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}
