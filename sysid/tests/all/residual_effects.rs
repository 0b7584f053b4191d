//! Acceptance of the residual loop on logs with effects injected and *not declared*: the loop
//! must name each effect, and its held-out RMSE after must come within 15 % of the noise σ; a
//! clean log gets no effect; a log with two effects gets both.

use crate::residual_gen as gen;

use gen::{generate, Inject};
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::residual::series_from_dataset;
use sysid::residual::{diagnose, Config, Diagnosis};

const SIGMA: f64 = 0.05;
const RATES: [f64; 5] = [20.0, 40.0, 60.0, 80.0, 100.0];

fn run(effects: &[Inject], seed: u64) -> Diagnosis {
    let g = generate(effects, &RATES, 2, SIGMA, seed);
    let ds = Dataset::from_columns(g.t, g.v, g.vdot, g.p, &DatasetConfig::default());
    let series = series_from_dataset(&ds).expect("valid series");
    diagnose(series, &Config::default()).expect("diagnosis runs")
}

fn names(d: &Diagnosis) -> Vec<&'static str> {
    d.effects.iter().map(|e| e.name).collect()
}

fn check_single(effect: Inject, expect: &str, seed: u64) {
    let d = run(&[effect], seed);
    let found = names(&d);
    eprintln!(
        "{expect}: baseline {:.4} → final {:.4} kPa, effects {:?}, remaining {:?}",
        d.baseline.rmse_heldout, d.final_model.rmse_heldout, found, d.remaining
    );
    assert_eq!(
        found.first().copied(),
        Some(expect),
        "{effect:?} named {found:?}"
    );
    assert!(
        d.final_model.rmse_heldout <= 1.15 * SIGMA,
        "{expect}: held-out RMSE after {:.4} kPa exceeds 1.15 σ = {:.4}",
        d.final_model.rmse_heldout,
        1.15 * SIGMA
    );
}

#[test]
fn clean_log_gets_no_effect() {
    let d = run(&[], 1);
    assert!(d.effects.is_empty(), "clean log claimed {:?}", names(&d));
    assert!(d.final_model.rmse_heldout <= 1.15 * SIGMA);
}

#[test]
fn hysteresis_is_named() {
    check_single(
        Inject::Hysteresis {
            gap_kpa: 0.6,
            width_mm3: 8.0,
        },
        "hysteresis",
        2,
    );
}

#[test]
fn air_pocket_is_named() {
    check_single(Inject::Air { volume_mm3: 40.0 }, "air_compliance", 3);
}

/// A larger pocket (80 mm³). The first-order lag with the damping at the pump's flow left
/// 1.19 σ here: the law's flow-squared term is not linearisable across the reversal transients
/// of so large a pocket. With the damping at the flow midway between the pump's and the
/// chamber's (`AirCompliance::refine`), exact for a law quadratic in flow, it is within the
/// check's bound.
#[test]
fn large_air_pocket_is_named() {
    check_single(Inject::Air { volume_mm3: 80.0 }, "air_compliance", 3);
}

#[test]
fn sensor_lag_is_named() {
    check_single(Inject::SensorLag { tau_s: 0.12 }, "sensor_lag", 4);
}

#[test]
fn transport_delay_is_named() {
    check_single(Inject::Delay { delay_s: 0.1 }, "transport_delay", 5);
}

#[test]
fn inertance_is_named() {
    check_single(Inject::Inertance { l: 1.5e-3 }, "inertance", 6);
}

#[test]
fn offset_drift_is_named() {
    check_single(
        Inject::OffsetDrift {
            kpa: 0.5,
            tau_s: 150.0,
        },
        "offset_drift",
        7,
    );
}

#[test]
fn volume_drift_is_named() {
    check_single(Inject::VolumeDrift { rate: 0.05 }, "volume_drift", 8);
}

#[test]
fn backlash_is_named() {
    check_single(Inject::Backlash { play_mm3: 6.0 }, "backlash", 9);
}

#[test]
fn ripple_is_named() {
    check_single(
        Inject::Ripple {
            amp_kpa: 0.2,
            freq_hz: 3.7,
        },
        "ripple",
        10,
    );
}

#[test]
fn leak_is_named() {
    check_single(Inject::Leak { lambda: 0.004 }, "leak", 11);
}

/// The generator's leak is an open path (`λ P` at either sign) and the protocol's deflations go
/// below the atmosphere: the leak is named in that form (`one_way` 0), not as a seal that
/// closes under suction (host-sim's form, `residual_hostsim::a_leak_that_closes_under_suction`),
/// and its λ within 5 % of the planted one.
#[test]
fn an_open_leak_is_named_in_its_form() {
    let leak = [Inject::Leak { lambda: 0.004 }];
    // The premise: the log goes well below the atmosphere, where the two forms differ.
    let g = generate(&leak, &RATES, 2, SIGMA, 11);
    let lowest = g.p.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(lowest < -2.0, "lowest pressure {lowest} kPa");
    let d = run(&leak, 11);
    let leak = d.effects.first().expect("an effect is named");
    assert_eq!(leak.name, "leak");
    let param = |name: &str| {
        leak.params
            .iter()
            .find(|p| p.name == name)
            .unwrap_or_else(|| panic!("no {name}"))
            .value
    };
    assert_eq!(param("one_way"), 0.0);
    let lambda = param("conductance");
    assert!((lambda - 0.004).abs() <= 0.05 * 0.004, "λ {lambda}");
}

#[test]
fn two_effects_are_both_named() {
    let d = run(
        &[
            Inject::Hysteresis {
                gap_kpa: 0.6,
                width_mm3: 8.0,
            },
            Inject::Ripple {
                amp_kpa: 0.2,
                freq_hz: 3.7,
            },
        ],
        12,
    );
    let found = names(&d);
    assert!(
        found.contains(&"hysteresis") && found.contains(&"ripple"),
        "found {found:?}"
    );
    assert!(
        d.final_model.rmse_heldout <= 1.15 * SIGMA,
        "after {:.4}",
        d.final_model.rmse_heldout
    );
}

#[test]
fn a_design_budget_below_one_design_changes_the_schedule_only() {
    // The design budget (`Config::design_memory`) only makes the search threads take turns with
    // their designs: with a budget of one byte (every design waits for the others to be dropped)
    // the diagnosis of a log with two filtered effects (sensor lag, air pocket), whose searches
    // hold designs, is the same document as with the default budget.
    let g = generate(
        &[
            Inject::SensorLag { tau_s: 0.08 },
            Inject::Air { volume_mm3: 40.0 },
        ],
        &RATES,
        2,
        SIGMA,
        21,
    );
    let ds = Dataset::from_columns(g.t, g.v, g.vdot, g.p, &DatasetConfig::default());
    let series = series_from_dataset(&ds).expect("valid series");
    let cfg = Config {
        threads: 2,
        ..Config::default()
    };
    let free = diagnose(series.clone(), &cfg).expect("diagnosis runs");
    let tight = Config {
        design_memory: 1,
        ..cfg
    };
    let turns = diagnose(series, &tight).expect("diagnosis runs");
    assert!(!free.effects.is_empty(), "the effects are found");
    // Everything but where the time went (`timing_s`, wall-clock seconds).
    let document = |d: &Diagnosis| {
        let mut v = serde_json::to_value(d).unwrap();
        v.as_object_mut().unwrap().remove("timing_s");
        v
    };
    assert_eq!(document(&free), document(&turns));
}
