//! `vfp force --augmented` against host-sim's true push force: the residual loop's models, run
//! as the board runs them, on plants whose chambers have effects no polynomial holds.

use host_sim::plant::Hysteresis;
use host_sim::{simulate, Effects, PlantConfig, Protocol, Scenario};
use std::path::{Path, PathBuf};
use sysid::dataset::{DatasetConfig, LogData};
use sysid::diag::force::{
    error_stats, estimate, estimate_augmented, AugmentedForceReport, ForceReport, ForceTrace,
};
use vfp::cmd::force::{loop_config, Args as ForceArgs};
use vfp::cmd::stiffness::ShapeOpts;
use vfp::opts::{DataOpts, OutputOpts};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vfp-force-aug-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn plant(effects: &Effects) -> PlantConfig {
    PlantConfig {
        effects: effects.clone(),
        ..PlantConfig::default()
    }
}

/// Force-free identification: the paper's protocol, 2 cycles at each of 20, 60, 100 mm³/s, on
/// every chamber.
fn ident_scenario(effects: &Effects, seed: u64) -> Scenario {
    let protocol = Protocol {
        cycles: 2,
        flows: vec![20.0, 60.0, 100.0],
        ..Protocol::paper()
    };
    Scenario {
        seed,
        ..Scenario::protocol("ident", plant(effects), &protocol)
    }
}

/// `vfp simulate --preset force`'s pushes (1 Hz, 0.3 N peak, 10 s at 500 mm³) on the plant.
fn push_scenario(effects: &Effects, seed: u64) -> Scenario {
    Scenario {
        seed,
        plant: plant(effects),
        ..Scenario::force_pushes(0.3, 10.0)
    }
}

fn write(dir: &Path, name: &str, sc: &Scenario) -> PathBuf {
    let run = simulate(sc).expect("valid scenario");
    let path = dir.join(format!("{name}.csv"));
    let mut out = Vec::new();
    run.write_log(&mut out).unwrap();
    std::fs::write(&path, out).unwrap();
    path
}

fn args(ident: PathBuf, test: PathBuf) -> ForceArgs {
    ForceArgs {
        ident,
        test,
        area: vec![22.0],
        shape: ShapeOpts::default(),
        smooth: 1,
        plot_window: 10.0,
        augmented: true,
        data: DataOpts::default(),
        out: OutputOpts::default(),
    }
}

/// The reports and traces of bare and augmented `vfp force` on one pair of logs.
struct Both {
    bare: ForceReport,
    bare_trace: ForceTrace,
    aug: AugmentedForceReport,
    aug_trace: ForceTrace,
}

/// Bare and augmented `vfp force` on one pair of logs.
fn both(dir: &Path, effects: &Effects, test: &Scenario) -> Both {
    let ident = write(dir, "ident", &ident_scenario(effects, 11));
    let test = write(dir, "push", test);
    let a = args(ident.clone(), test.clone());
    let read = |p: &Path| LogData::read(p, None, &DatasetConfig::default()).unwrap();
    let (i, t) = (read(&ident), read(&test));
    let o = a.options().unwrap();
    let (bare, bare_trace) = estimate(&i, &t, &o).unwrap();
    let (aug, aug_trace) = estimate_augmented(&i, &t, &o, &loop_config(&a).unwrap()).unwrap();
    Both {
        bare,
        bare_trace,
        aug,
        aug_trace,
    }
}

/// The force the sensors can show: the true force through the sensor's first-order lag τ (the
/// plant's, exact for a force linear between samples), so `estimate − lagged` is the model's
/// share of the error and `lagged − true` the lag's, which no model of P̂ removes.
fn lagged_truth(tr: &ForceTrace, tau: f64) -> Vec<f64> {
    let f = tr.truth.as_ref().expect("the push log has force_n");
    let mut y = vec![f[0]; f.len()];
    for k in 1..f.len() {
        let h = tr.t[k] - tr.t[k - 1];
        if tau <= 0.0 {
            y[k] = f[k];
            continue;
        }
        let a = (-h / tau).exp();
        // Exact response of ẏ = (F − y)/τ to F linear over [t_{k−1}, t_k].
        let slope = (f[k] - f[k - 1]) / h;
        y[k] = f[k] - slope * tau + a * (y[k - 1] - f[k - 1] + slope * tau);
    }
    y
}

/// Standard deviation of the model's share of the force error (estimate against the lagged
/// truth), N.
fn model_share_std(tr: &ForceTrace, tau: f64) -> f64 {
    let y = lagged_truth(tr, tau);
    let e: Vec<f64> = tr.est.iter().zip(&y).map(|(a, b)| a - b).collect();
    error_stats(&e).1
}

fn show(what: &str, b: &Both, tau: f64) {
    let (bare, aug) = (&b.bare, &b.aug);
    let mn = |x: Option<f64>| x.unwrap() * 1e3;
    eprintln!(
        "{what}: model share std bare {:.2} aug {:.2} mN",
        model_share_std(&b.bare_trace, tau) * 1e3,
        model_share_std(&b.aug_trace, tau) * 1e3
    );
    eprintln!(
        "{what}: bare {:+.2} ± {:.2} mN, augmented {:+.2} ± {:.2} mN ({} samples, {} without estimate); effects {:?}",
        mn(bare.mean_error_n),
        mn(bare.std_error_n),
        mn(aug.force.mean_error_n),
        mn(aug.force.std_error_n),
        aug.force.samples,
        aug.no_estimate,
        aug.augmented
            .iter()
            .map(|a| (a.chamber, a.effects.clone(), a.host_only.iter().map(|d| d.name).collect::<Vec<_>>()))
            .collect::<Vec<_>>()
    );
}

/// Wall hysteresis (a 1 kPa gap between inflation and deflation, switching over 20 mm³) and a
/// 0.1 s sensor lag in every chamber: sizes a real rig can have, set before the first run.
const HYSTERESIS_KPA: f64 = 0.5;
const SENSOR_LAG_S: f64 = 0.1;

fn rig_effects() -> Effects {
    Effects {
        hysteresis: Some(Hysteresis {
            amplitude_kpa: HYSTERESIS_KPA,
            transition_mm3: 20.0,
        }),
        sensor_lag_s: SENSOR_LAG_S,
        ..Effects::default()
    }
}

/// The acceptance run of issue #16: identification (seed 11) and pushes (seed 12) on a plant
/// with wall hysteresis and sensor lag in every chamber.
///
/// Measured (2026-11-24), force error mean ± std: bare 8.30 ± 48.67 mN, augmented 1.08 ± 35.29 mN (std ratio
/// 0.73); against the lagged truth (the model's share) 33.62 → 2.03 mN (0.06). The sensor lag
/// delays the force's own pressure too (a 1 Hz push of 0.3 N through τ = 0.1 s is ≈ 35 mN of
/// error), which no model of P̂ removes: the board's residual is `P − P̂` and the chain only
/// makes P̂ what the sensor would show without a push. So the whole-error ratio cannot reach 0.5
/// here; the model's share is asserted to at most half, the whole error to improve, and it must
/// stay above the lag's own floor (no estimate can undo the lag by accident).
#[test]
fn augmented_board_removes_the_model_error_of_hysteresis_and_sensor_lag() {
    let dir = tmpdir("rig");
    let e = rig_effects();
    let b = both(&dir, &e, &push_scenario(&e, 12));
    show("hysteresis + sensor lag", &b, SENSOR_LAG_S);
    for a in &b.aug.augmented {
        for want in ["hysteresis", "sensor_lag"] {
            assert!(
                a.effects.contains(&want),
                "chamber {}: the board model lacks {want}: {:?}",
                a.chamber,
                a.effects
            );
        }
    }
    let (bare, aug) = (
        b.bare.std_error_n.unwrap(),
        b.aug.force.std_error_n.unwrap(),
    );
    let (bare_model, aug_model) = (
        model_share_std(&b.bare_trace, SENSOR_LAG_S),
        model_share_std(&b.aug_trace, SENSOR_LAG_S),
    );
    assert!(
        aug_model <= 0.5 * bare_model,
        "model share of the error: augmented {aug_model} N, bare {bare_model} N"
    );
    assert!(aug < bare, "std error: augmented {aug} N, bare {bare} N");
    let truth = b.aug_trace.truth.as_ref().unwrap();
    let lag_only: Vec<f64> = lagged_truth(&b.aug_trace, SENSOR_LAG_S)
        .iter()
        .zip(truth)
        .map(|(y, f)| y - f)
        .collect();
    let floor = error_stats(&lag_only).1;
    assert!(
        aug > 0.9 * floor,
        "augmented std {aug} N below the lag's own error {floor} N"
    );
    assert!(
        b.aug.force.mean_error_n.unwrap().abs() < b.bare.mean_error_n.unwrap().abs(),
        "mean error: augmented {:?}, bare {:?}",
        b.aug.force.mean_error_n,
        b.bare.mean_error_n
    );
}

/// Control: the same pushes on the default rig (no planted effect; the drive's own 3 ms delivery
/// lag remains): the augmented board is not worse than the bare one by more than 10 %.
#[test]
fn augmented_board_is_no_worse_without_planted_effects() {
    let dir = tmpdir("control");
    let e = Effects::default();
    let b = both(&dir, &e, &push_scenario(&e, 12));
    show("no planted effect", &b, 0.0);
    let (bare, aug) = (
        b.bare.std_error_n.unwrap(),
        b.aug.force.std_error_n.unwrap(),
    );
    assert!(
        aug <= 1.1 * bare,
        "std error: augmented {aug} N, bare {bare} N"
    );
    assert_eq!(b.aug.force.samples + b.aug.no_estimate, b.bare.samples);
}

/// The numbers of the module docs and the README over a few rig sizes:
/// `cargo test -p vfp --test force_augmented -- --ignored --nocapture`.
#[test]
#[ignore]
fn sizes() {
    let dir = tmpdir("sizes");
    for (amp, tau) in [(0.5, 0.1), (0.25, 0.05), (1.0, 0.2)] {
        let e = Effects {
            hysteresis: Some(Hysteresis {
                amplitude_kpa: amp,
                transition_mm3: 20.0,
            }),
            sensor_lag_s: tau,
            ..Effects::default()
        };
        let b = both(&dir, &e, &push_scenario(&e, 12));
        show(&format!("H_a {amp} kPa, tau {tau} s"), &b, tau);
    }
}
