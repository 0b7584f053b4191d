//! The baseline's shape chosen again with the effects (issue 34, `sysid::residual::reshape`).
//! Logs of the SBA1 law (n = 3, m = 2) with effects injected by their physics
//! (`residual_gen.rs`), diagnosed as `vfp diagnose LOG` does (the shape selected).

use crate::residual_gen as gen;

use gen::{generate, Inject};
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::residual::{diagnose_dataset, Config, Diagnosis};

const RATES: [f64; 5] = [20.0, 40.0, 60.0, 80.0, 100.0];

fn run(effects: &[Inject], cycles: usize, sigma: f64, seed: u64, reshape: bool) -> Diagnosis {
    let g = generate(effects, &RATES, cycles, sigma, seed);
    let ds = Dataset::from_columns(g.t, g.v, g.vdot, g.p, &DatasetConfig::default());
    let cfg = Config {
        reshape,
        ..Config::default()
    };
    diagnose_dataset(&ds, &cfg, false).expect("diagnosis runs")
}

fn show(what: &str, d: &Diagnosis) {
    let names: Vec<_> = d.effects.iter().map(|e| e.name).collect();
    eprintln!(
        "{what}: shape ({}, {}) effects {names:?} held-out {:.4} reshape {}",
        d.baseline.n,
        d.baseline.m,
        d.final_model.rmse_heldout,
        serde_json::to_string(&d.reshape).unwrap()
    );
}

const SIGMA: f64 = 0.35;

/// The SBA1 law's shape.
const LAW: (usize, usize) = (3, 2);

fn shape(d: &Diagnosis) -> (usize, usize) {
    (d.baseline.n, d.baseline.m)
}

fn named(d: &Diagnosis, name: &str) -> bool {
    d.effects.iter().any(|e| e.name == name)
}

/// A weak hysteresis (gap 0.81 kPa, width 15 mm³, at σ = 0.35 kPa: issue 34's case) on four
/// cycles per rate: the selection, which sees no effect, takes (7, 7), whose flow degrees absorb
/// the loop, and from there no effect passes. Chosen again with the effects, the baseline is the
/// law's (3, 2) with the hysteresis named near its planted gap, and the held-out error is lower.
#[test]
fn a_hysteresis_the_selected_shape_absorbs_is_found_from_a_simpler_one() {
    let hyst = [Inject::Hysteresis {
        gap_kpa: 0.81,
        width_mm3: 15.0,
    }];
    let before = run(&hyst, 4, SIGMA, 2, false);
    show("hysteresis, without", &before);
    // The case's premise: a high shape and nothing named.
    assert!(
        shape(&before).0 * shape(&before).1 >= 30,
        "{:?}",
        shape(&before)
    );
    assert!(!named(&before, "hysteresis"));
    let after = run(&hyst, 4, SIGMA, 2, true);
    show("hysteresis, with", &after);
    assert_eq!(shape(&after), LAW);
    assert!(named(&after, "hysteresis"));
    let r = after.reshape.as_ref().expect("reported");
    assert_eq!(r.selected, shape(&before));
    assert_eq!(r.used, LAW);
    let gap = after.effects[0]
        .params
        .iter()
        .find(|p| p.name == "gap_at_mid_volume")
        .expect("gap")
        .value;
    assert!((gap - 0.81).abs() < 0.15 * 0.81, "gap {gap}");
    assert!(
        after.final_model.rmse_heldout < before.final_model.rmse_heldout,
        "held-out {:.4} → {:.4}",
        before.final_model.rmse_heldout,
        after.final_model.rmse_heldout
    );
}

/// A sensor lag of 50 ms at σ = 0.35 kPa (two seeds, two and four cycles): the selection takes
/// (7, 2) or (7, 4), whose volume degrees absorb part of the lag's phase; the loop names the lag
/// there too. Chosen again with it, the baseline is the law's (3, 2) with the lag, its held-out
/// error no worse (within 0.1 %).
#[test]
fn a_sensor_lag_ends_on_the_laws_shape() {
    let lag = [Inject::SensorLag { tau_s: 0.05 }];
    for (seed, cycles) in [(1, 2), (2, 4)] {
        let before = run(&lag, cycles, SIGMA, seed, false);
        show("lag, without", &before);
        assert!(shape(&before).0 >= 7, "{:?}", shape(&before));
        let after = run(&lag, cycles, SIGMA, seed, true);
        show("lag, with", &after);
        assert_eq!(shape(&after), LAW, "seed {seed}");
        assert!(named(&after, "sensor_lag"));
        let tau = after.effects[0].params[0].value;
        assert!((tau - 0.05).abs() < 0.2 * 0.05, "τ {tau}");
        assert!(
            after.final_model.rmse_heldout <= 1.001 * before.final_model.rmse_heldout,
            "held-out {:.4} → {:.4}",
            before.final_model.rmse_heldout,
            after.final_model.rmse_heldout
        );
    }
}

/// Where the selection takes the law's own shape (two cycles: a hysteresis found from (3, 2);
/// and a clean log), nothing changes: the same shape, effects and errors as without the step.
#[test]
fn nothing_changes_where_the_selected_shape_is_the_laws() {
    let hyst = [Inject::Hysteresis {
        gap_kpa: 0.81,
        width_mm3: 15.0,
    }];
    for (effects, seed) in [(&hyst[..], 1), (&[][..], 2)] {
        let before = run(effects, 2, SIGMA, seed, false);
        let after = run(effects, 2, SIGMA, seed, true);
        show("law's shape, with", &after);
        assert_eq!(shape(&before), LAW);
        assert_eq!(shape(&after), LAW);
        let names = |d: &Diagnosis| d.effects.iter().map(|e| e.name).collect::<Vec<_>>();
        assert_eq!(names(&before), names(&after));
        assert_eq!(
            before.final_model.rmse_heldout,
            after.final_model.rmse_heldout
        );
        let r = after.reshape.as_ref().expect("reported");
        assert_eq!((r.selected, r.used, r.second_start), (LAW, LAW, None));
    }
}

/// The selection sees no effect: where one effect dominates a log's error, a shape without the
/// law's flow degree can be within the band of the best, and the loop then ends above the noise
/// with the right effect named. The loop benchmark's rigs 174 (an air pocket of 11 mm³) and 253
/// (a sensor lag of 25 ms) of seed 1, both SBA3 breathing (host-sim's plant, the law (3, 2)):
/// the selection takes (3, 1), and the loop from there names the right effect but ends at
/// 1.6 σ and 2.1 σ (σ from the simulator's truth). With the loop's effects the rule prefers a
/// richer shape, the loop runs again from it, and ends at 1.03 σ and 1.23 σ with the same
/// effect named (what rig 253 keeps above the noise is the lag's form, not the shape: from (4, 2)
/// and (3, 3) the loop ends there too).
#[test]
fn a_shape_without_the_laws_flow_degree_is_enriched_with_the_effects() {
    use host_sim::rigs::PlantedKind;
    for (index, kind, name) in [
        (174, PlantedKind::Air, "air_compliance"),
        (253, PlantedKind::SensorLag, "sensor_lag"),
    ] {
        let (_, sim, ds) = crate::hostsim_common::one_effect_rig(1, index, kind);
        let sigma = crate::hostsim_common::sigma_from_truth(&sim, &ds);
        let d = diagnose_dataset(&ds, &Config::default(), false).expect("diagnosis runs");
        show(&format!("rig {index}"), &d);
        let r = d.reshape.as_ref().expect("the richer shape is reported");
        // The premise: the selection's shape lacks the law's flow degree, and the loop from it
        // ends well above the noise.
        assert_eq!(r.selected, (3, 1), "rig {index}");
        let from_selected = Config {
            n: 3,
            m: 1,
            ..Config::default()
        };
        let before = diagnose_dataset(&ds, &from_selected, true).expect("diagnosis runs");
        show(&format!("rig {index} from (3, 1)"), &before);
        let ratio_before = before.final_model.rmse_heldout / sigma;
        assert!(ratio_before >= 1.5, "rig {index}: {ratio_before:.3} σ");
        assert!(
            r.used.0 >= LAW.0 && r.used.1 >= LAW.1,
            "rig {index}: {:?}",
            r.used
        );
        assert_eq!(d.effects.iter().map(|e| e.name).collect::<Vec<_>>(), [name]);
        let ratio = d.final_model.rmse_heldout / sigma;
        assert!(ratio <= 1.25, "rig {index}: {ratio:.3} σ");
    }
}
