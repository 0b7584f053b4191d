//! Validation on another log (`vfp diagnose A --validate B`): the loop's models, fitted on A, are
//! evaluated on every row of B without refitting anything, so an effect that holds for the rig
//! lowers B's error as it lowered A's held-out error, and one that fitted A's accidents does not.
//!
//! Each model (the baseline, then the model after each kept effect, in the order kept, the last
//! being the final model) is rebuilt on B's samples as the loop builds it on A's: the same
//! polynomial basis (A's scaling), each effect at the parameters found on A (its θ and, for the
//! searched offsets, the same values), and the coefficients fitted on A's training rows. The
//! per-sample schedules some effects take from the model they extend (air compliance's damping,
//! pump ripple's stiffness and damping) are the model's own polynomial part evaluated at B's
//! samples. Then `P̂_B = X_B β_A` and the RMSE is over every row of B.
//!
//! Effects tied to the log's own clock (`offset_drift`, `volume_drift`, `ripple`) are evaluated
//! on B's clock from B's first sample: they claim the same drift or the same phase over B,
//! which another log rarely has. The report names them (`clock_bound`), so a final model that is
//! worse on B because of them reads as what it is.

use serde::Serialize;

use super::effects::design::build;
use super::effects::{Effect, Prepared};
use super::lsq;
use super::select::basis_derivative;
use super::{DiagnoseError, Diagnosis, PolyBasis, Series, Stage};

/// A model as fitted: its effects and its coefficients (the design's column order).
#[derive(Clone, Debug, Default)]
pub struct FittedModel {
    /// Effects, in the order added, at their fitted parameters.
    pub effects: Vec<Effect>,
    /// Coefficients over the design's columns (polynomial basis first).
    pub beta: Vec<f64>,
}

impl FittedModel {
    /// The model of a stage of the loop.
    pub fn of(stage: &Stage) -> Self {
        Self {
            effects: stage.effects.clone(),
            beta: stage.fit.beta.to_vec(),
        }
    }
}

/// The error after one kept effect, on the other log.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ValidationStep {
    /// The effect kept at this step.
    pub effect: &'static str,
    /// RMSE of the model after it over every row of the other log, kPa.
    pub rmse: f64,
}

/// The loop's models on another log (module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Validation {
    /// The other log.
    pub log: String,
    /// Its rows used (all of them).
    pub samples: usize,
    /// RMSE of the baseline polynomial, kPa.
    pub baseline_rmse: f64,
    /// RMSE of the final model, kPa.
    pub final_rmse: f64,
    /// After each kept effect, in order.
    pub steps: Vec<ValidationStep>,
    /// Kept effects evaluated on the other log's own clock (module docs).
    pub clock_bound: Vec<&'static str>,
}

/// Effects whose columns follow the log's clock rather than its motion.
const CLOCK_BOUND: [&str; 3] = ["offset_drift", "volume_drift", "ripple"];

/// Evaluates `d`'s models on `series` (another log's chamber, named `log`).
pub fn validate(d: &Diagnosis, series: Series, log: String) -> Result<Validation, DiagnoseError> {
    let samples = series.len();
    let prep = Prepared::new(series, d.basis.clone());
    let rmse: Vec<f64> = d.models.iter().map(|m| rmse_on(&prep, m)).collect();
    let (Some(&baseline_rmse), Some(&final_rmse)) = (rmse.first(), rmse.last()) else {
        return Err(DiagnoseError::Degenerate(
            "no fitted model to validate".into(),
        ));
    };
    let steps = d
        .effects
        .iter()
        .zip(&rmse[1..])
        .map(|(e, &rmse)| ValidationStep {
            effect: e.name,
            rmse,
        })
        .collect();
    let clock_bound = d
        .effects
        .iter()
        .map(|e| e.name)
        .filter(|n| CLOCK_BOUND.contains(n))
        .collect();
    Ok(Validation {
        log,
        samples,
        baseline_rmse,
        final_rmse,
        steps,
        clock_bound,
    })
}

/// RMSE of `model` over every row of `prep` (NaN when its design does not have the model's
/// columns, which would be a bug).
fn rmse_on(prep: &Prepared, model: &FittedModel) -> f64 {
    let poly = &model.beta[..prep.basis.len().min(model.beta.len())];
    let effects: Vec<Effect> = model
        .effects
        .iter()
        .map(|e| with_schedules(prep, e, poly))
        .collect();
    let design = build(prep, &effects);
    if design.cols.len() != model.beta.len() {
        return f64::NAN;
    }
    let p = &prep.series.p;
    let pred = lsq::predict(&design.cols, &model.beta);
    let sse: f64 = p.iter().zip(&pred).map(|(p, q)| (p - q).powi(2)).sum();
    (sse / p.len().max(1) as f64).sqrt()
}

/// `e` with its per-sample schedules (damping, stiffness) recomputed on `prep`'s samples from the
/// polynomial part `poly` of the model it belongs to.
fn with_schedules(prep: &Prepared, e: &Effect, poly: &[f64]) -> Effect {
    let along = |d| basis_derivative(prep, poly, d);
    Effect {
        damping: e.damping.as_ref().map(|_| along(PolyBasis::damping)),
        stiffness: e.stiffness.as_ref().map(|_| along(PolyBasis::stiffness)),
        ..e.clone()
    }
}

/// [`validate`] on the first requested chamber of `data` (the other log, read as the first).
pub fn validate_log(
    d: &Diagnosis,
    data: &crate::dataset::LogData,
) -> Result<Validation, super::LogDiagnoseError> {
    let ds = data.first();
    let wrap = |source| super::LogDiagnoseError {
        path: data.name(),
        chamber: ds.chamber,
        source,
    };
    // Every row of the other log is used; its own split does not matter, but the series needs
    // one: alternate rows (so it needs at least 200 rows).
    let mut all = ds.clone();
    all.heldout = (0..all.t.len()).map(|k| k % 2 == 1).collect();
    let series = super::series_from_dataset(&all).map_err(wrap)?;
    validate(d, series, data.name()).map_err(wrap)
}
