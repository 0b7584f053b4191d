//! `vfp force --augmented` against host-sim's true push force: the residual loop's models, run
//! as the board runs them, on plants whose chambers have effects no polynomial holds.

use host_sim::plant::Hysteresis;
use host_sim::{simulate, Effects, PlantConfig, Protocol, Scenario};
use std::path::{Path, PathBuf};
use sysid::board::force::{estimate_augmented, AugmentedForceReport};
use sysid::dataset::{DatasetConfig, LogData};
use sysid::diag::force::{estimate, ForceReport};
use vfp::cmd::force::{loop_config, Args as ForceArgs};
use vfp::cmd::stiffness::ShapeOpts;
use vfp::opts::{DataOpts, OutputOpts};

fn tmpdir(name: &str) -> PathBuf {
    let d = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("vfp-force-aug-{name}-{}", std::process::id()));
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
    aug: AugmentedForceReport,
}

/// Bare and augmented `vfp force` on one pair of logs.
fn both(dir: &Path, effects: &Effects, test: &Scenario) -> Both {
    let ident = write(dir, "ident", &ident_scenario(effects, 11));
    let test = write(dir, "push", test);
    let a = args(ident.clone(), test.clone());
    let read = |p: &Path| LogData::read(p, None, &DatasetConfig::default()).unwrap();
    let (i, t) = (read(&ident), read(&test));
    let o = a.options().unwrap();
    let (bare, _) = estimate(&i, &t, &o).unwrap();
    let (aug, _) = estimate_augmented(&i, &t, &o, &loop_config(&a).unwrap()).unwrap();
    Both { bare, aug }
}

fn show(what: &str, b: &Both) {
    let (bare, aug) = (&b.bare, &b.aug);
    let mn = |x: Option<f64>| x.unwrap() * 1e3;
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
/// with wall hysteresis and sensor lag in every chamber; the force error's std on the board
/// with the augmented model at most half the bare model's.
///
/// Measured (2026-11-24), force error mean ± std: bare +8.30 ± 48.67 mN, augmented
/// +0.93 ± 6.22 mN (0.13×). The sensor lag delays the push's own pressure as well as the
/// chamber's (a 1 Hz push of 0.3 N through τ = 0.1 s is ≈ 35 mN of error); the board undoes it
/// on the residual (`Chain::load_pressure`: r + τ ṙ), without which the augmented std was
/// 35.3 mN (0.73×).
#[test]
fn augmented_board_removes_the_model_error_of_hysteresis_and_sensor_lag() {
    let dir = tmpdir("rig");
    let e = rig_effects();
    let b = both(&dir, &e, &push_scenario(&e, 12));
    show("hysteresis + sensor lag", &b);
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
    assert!(
        aug <= 0.5 * bare,
        "std error: augmented {aug} N, bare {bare} N"
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
    show("no planted effect", &b);
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
/// `cargo test -p vfp --test all force_augmented:: -- --ignored --nocapture`.
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
        show(&format!("H_a {amp} kPa, tau {tau} s"), &b);
    }
}
