//! An effect defined outside the crate, in this file, and added to the loop's candidates by one
//! line is tried by `diagnose`, and found where it is planted: seal friction that grows with
//! speed and saturates, `ΔP = c·tanh(v̇/q_s)`, on the paper's SBA1 law along the test protocol
//! (`residual_gen.rs`, no effect injected there) with Gaussian noise of known σ. Truth is the
//! planted `c` and `q_s`; the library's own twelve effects cannot absorb it.

use crate::residual_gen as gen;

use gen::generate;
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::residual::effects::{Column, Effect, Fitted, Prepared, Scales, Search};
use sysid::residual::{
    diagnose, param, series_from_dataset, Config, DiagnoseError, Diagnosis, EffectKind,
    EffectModel, Param, Series, REGISTRY,
};

const SIGMA: f64 = 0.05;
const RATES: [f64; 5] = [20.0, 40.0, 60.0, 80.0, 100.0];
/// Planted friction amplitude (kPa) and speed scale (mm³/s).
const C_KPA: f64 = 0.4;
const QS: f64 = 25.0;

/// Seal friction saturating with speed: one column `tanh(v̇/q_s)`, `q_s` searched.
struct SealFriction;

impl EffectModel for SealFriction {
    fn name(&self) -> &'static str {
        "seal_friction"
    }

    fn story(&self) -> &'static str {
        "The plunger seal's friction grows with speed and saturates, adding pressure against the motion."
    }

    fn search(&self, _scales: &Scales) -> Search {
        Search::Log(1.0, 300.0)
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn columns(&self, e: &Effect, prep: &Prepared, _v: &[f64]) -> Vec<Column> {
        let col = prep
            .series
            .vdot
            .iter()
            .map(|q| (q / e.theta).tanh())
            .collect();
        vec![Column::new(col, "seal friction tanh(vdot/q_s)")]
    }

    fn unphysical(&self, _e: &Effect, coefs: &[f64], _sc: &Scales) -> Option<String> {
        (coefs[0] < 0.0).then(|| "friction cannot help the motion along".to_string())
    }

    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![
            param("speed_scale", f.effect.theta, f.theta_se, "mm3/s"),
            param("friction", f.coef(0), f.coef_se(0), "kPa"),
        ]
    }
}

/// The generated log with the friction planted in its pressure.
fn planted_series(seed: u64) -> Series {
    let mut g = generate(&[], &RATES, 2, SIGMA, seed);
    for (p, q) in g.p.iter_mut().zip(&g.vdot) {
        *p += C_KPA * (q / QS).tanh();
    }
    let ds = Dataset::from_columns(g.t, g.v, g.vdot, g.p, &DatasetConfig::default());
    series_from_dataset(&ds).expect("valid series")
}

fn tried(d: &Diagnosis) -> Vec<&'static str> {
    let kept = d.effects.iter().map(|e| e.name);
    kept.chain(d.rejected_last_round.iter().map(|r| r.name))
        .collect()
}

#[test]
fn an_effect_added_by_one_line_is_tried_and_found() {
    let mut cfg = Config::default();
    cfg.candidates.push(EffectKind(&SealFriction)); // the one line
    assert_eq!(cfg.candidates.len(), REGISTRY.len() + 1);
    let d = diagnose(planted_series(3), &cfg).expect("diagnosis runs");
    let names: Vec<&str> = d.effects.iter().map(|e| e.name).collect();
    eprintln!(
        "baseline {:.4} → final {:.4} kPa, effects {names:?}, tried {:?}",
        d.baseline.rmse_heldout,
        d.final_model.rmse_heldout,
        tried(&d)
    );
    assert_eq!(names.first().copied(), Some("seal_friction"), "{names:?}");
    let p = &d.effects[0].params;
    let value = |name: &str| p.iter().find(|x| x.name == name).map(|x| x.value);
    let (qs, c) = (value("speed_scale").unwrap(), value("friction").unwrap());
    assert!((qs - QS).abs() < 0.1 * QS, "q_s = {qs} mm³/s, planted {QS}");
    assert!(
        (c - C_KPA).abs() < 0.05 * C_KPA,
        "c = {c} kPa, planted {C_KPA}"
    );
    assert!(
        d.final_model.rmse_heldout <= 1.15 * SIGMA,
        "held-out RMSE after {:.4} kPa exceeds 1.15 σ",
        d.final_model.rmse_heldout
    );
    assert!(d.effects[0].story.ends_with('.'));
    assert!(
        !d.effects[0].device.runs_on_device,
        "the default device verdict"
    );
}

#[test]
fn without_the_line_the_library_cannot_explain_it() {
    let d = diagnose(planted_series(3), &Config::default()).expect("diagnosis runs");
    let names: Vec<&str> = d.effects.iter().map(|e| e.name).collect();
    eprintln!(
        "registry only: baseline {:.4} → final {:.4} kPa, effects {names:?}",
        d.baseline.rmse_heldout, d.final_model.rmse_heldout
    );
    assert!(!tried(&d).contains(&"seal_friction"));
    assert!(
        d.final_model.rmse_heldout > 1.15 * SIGMA,
        "the registry alone reached {:.4} kPa",
        d.final_model.rmse_heldout
    );
}

#[test]
fn a_candidate_named_like_another_is_refused() {
    struct Impostor;
    impl EffectModel for Impostor {
        fn name(&self) -> &'static str {
            "hysteresis"
        }
        fn story(&self) -> &'static str {
            "Not the hysteresis the report would name."
        }
    }
    let mut cfg = Config::default();
    cfg.candidates.push(EffectKind(&Impostor));
    let err = diagnose(planted_series(4), &cfg).expect_err("duplicate name");
    assert!(
        matches!(err, DiagnoseError::DuplicateEffect("hysteresis")),
        "{err}"
    );
}
