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
//!
//! That answers "does A's model predict B?", which mixes two questions: A's polynomial
//! extrapolated to pressures and flows A never saw, and every effect added to it, compound.
//! **Carry-over** ([`CarryOver`]) asks the second alone: does each effect of A's final model, at
//! the parameters found on A, still explain something on B? B's own polynomial (A's shape, B's
//! own scaling) is refitted on B's training cycles with and without the effect, beside A's other
//! effects that hold on B (so that one effect's columns cannot take credit for another's
//! structure, nor suffer from an effect that fits only A); only linear coefficients are
//! refitted, the effects' searched parameters are A's. Which others hold is found by backward
//! elimination: while some effect does not carry against the rest, the one whose removal helps
//! most is dropped; each dropped one is then judged against those that hold. Both fits are
//! scored on B's held-out cycles; last, all of A's effects against the polynomial alone. The
//! paired z is over units of the held-out cycles (each cut into pieces of at most 5 s): the mean
//! log ratio of each unit's squared error without and with the effect, over its standard error
//! with the units' lag-1 autocorrelation taken into account. The per-cycle reduction of the squared error gives a paired z (mean over its
//! standard error, over the held-out cycles): an effect the rig has carries (gain > 0, z ≥ 2),
//! one that fitted A's accidents does not. Held-out cycles, not rows: an extra column always
//! lowers the error on the rows it was fitted on.

use serde::Serialize;

use super::effects::design::build;
use super::effects::{Effect, Prepared};
use super::lsq;
use super::search::basis_derivative;
use super::{DiagnoseError, Diagnosis, PolyBasis, Series, Stage};

/// The paired z over held-out units above which an effect's gain on the other log counts as
/// carried (about 2.3 % one-sided under no gain).
pub const CARRY_Z: f64 = 2.0;

/// One effect of A's final model on the other log: B's own polynomial and A's other effects that
/// hold there, refitted with and without it (module docs).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CarryOver {
    /// The effect (`all` for A's effects together).
    pub effect: String,
    /// Held-out RMSE on the other log of its own polynomial with A's other effects that hold
    /// there (for `all`: the polynomial alone), kPa.
    pub without_rmse: f64,
    /// The same with the effect added (for `all`: every effect of A's), kPa.
    pub with_rmse: f64,
    /// `1 − with_rmse / without_rmse`.
    pub gain: f64,
    /// Paired z of the per-unit log ratio of the squared errors (without over with) over the
    /// held-out units, AR(1)-corrected.
    pub z: f64,
    /// Held-out units compared: the held-out cycles, each cut into pieces of at most 5 s.
    pub units: usize,
    /// `gain > 0` and `z ≥` [`CARRY_Z`].
    pub carries: bool,
}

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

    /// The same model without the per-sample data its effects hold over the log it was fitted
    /// on (the damping and stiffness schedules, kept as empty markers: [`with_schedules`]
    /// recomputes them on the samples the model is evaluated at; the chamber's pressure, which
    /// the design sets): what is kept of a model to evaluate elsewhere, a few numbers.
    pub fn without_samples(mut self) -> Self {
        let empty = std::sync::Arc::new(Vec::new());
        for e in &mut self.effects {
            e.damping = e.damping.as_ref().map(|_| empty.clone());
            e.stiffness = e.stiffness.as_ref().map(|_| empty.clone());
            e.pressure = None;
        }
        self
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
    /// Each kept effect's carry-over, then all of them together (empty without kept effects, or
    /// when it could not be computed: `carry_over_note` says why).
    pub carry_over: Vec<CarryOver>,
    /// Why the carry-over is missing although effects were kept.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub carry_over_note: Option<String>,
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
        carry_over: Vec::new(),
        carry_over_note: None,
    })
}

/// The carry-over of each of `d`'s kept effects to `series` (another log with its own split into
/// training and held-out cycles), then of all of them together (module docs). Empty when `d`
/// kept no effect; an effect whose design cannot be fitted on the other log (its columns
/// dependent there) is left out; an error when the other log has fewer than
/// [`CARRY_MIN_UNITS`] held-out units.
pub fn carry_over(d: &Diagnosis, series: Series) -> Result<Vec<CarryOver>, DiagnoseError> {
    let Some(last) = d.models.last() else {
        return Ok(Vec::new());
    };
    if last.effects.is_empty() {
        return Ok(Vec::new());
    }
    let other = OtherLog::new(d, series)?;
    let (blocks, held_errors) = (&other.blocks, |e: &[Effect]| other.held_errors(e));
    let all: Vec<Effect> = last.effects.iter().map(|e| other.moved(e)).collect();
    let names: Vec<String> = d.effects.iter().map(|r| r.name.to_string()).collect();
    if names.len() != all.len() {
        return Err(DiagnoseError::Degenerate(
            "the final model's effects differ from the reported ones".into(),
        ));
    }
    let subset = |keep: &[usize]| -> Vec<Effect> { keep.iter().map(|&j| all[j].clone()).collect() };
    // Each effect of `set` against the others of it.
    let leave_one_out = |set: &[usize]| -> Option<Vec<CarryOver>> {
        let with = held_errors(&subset(set))?;
        set.iter()
            .map(|&k| {
                let others: Vec<usize> = set.iter().copied().filter(|&j| j != k).collect();
                let without = held_errors(&subset(&others))?;
                Some(compare(names[k].clone(), &without, &with, blocks))
            })
            .collect()
    };
    // Backward elimination: while an effect does not carry against the others, drop the one
    // whose removal helps most (lowest gain), so that an effect that fits only A's accidents
    // does not make the others look useful or useless; the rest are then judged among the
    // effects that hold, and each dropped one against those.
    let mut held: Vec<usize> = (0..all.len()).collect();
    let mut dropped: Vec<usize> = Vec::new();
    let mut judged = Vec::new();
    while !held.is_empty() {
        let Some(rows) = leave_one_out(&held) else {
            break;
        };
        let worst = rows
            .iter()
            .enumerate()
            .filter(|(_, c)| !c.carries)
            .min_by(|a, b| a.1.gain.total_cmp(&b.1.gain))
            .map(|(i, _)| i);
        match worst {
            Some(i) => dropped.push(held.remove(i)),
            None => {
                judged = held.iter().copied().zip(rows).collect();
                break;
            }
        }
    }
    if !held.is_empty() && judged.is_empty() {
        return Ok(Vec::new());
    }
    let Some(with_held) = held_errors(&subset(&held)) else {
        return Ok(Vec::new());
    };
    for k in dropped {
        let mut plus = held.clone();
        plus.push(k);
        if let Some(with) = held_errors(&subset(&plus)) {
            judged.push((k, compare(names[k].clone(), &with_held, &with, blocks)));
        }
    }
    judged.sort_by_key(|(k, _)| *k);
    let mut out: Vec<CarryOver> = judged.into_iter().map(|(_, c)| c).collect();
    if all.len() > 1 {
        let every: Vec<usize> = (0..all.len()).collect();
        if let (Some(without), Some(with)) = (held_errors(&[]), held_errors(&subset(&every))) {
            out.push(compare("all".into(), &without, &with, blocks));
        }
    }
    Ok(out)
}

/// RMSE over the rows of `blocks`, from squared errors per row.
fn blocks_rmse(sq: &[f64], blocks: &[Vec<usize>]) -> f64 {
    let rows: usize = blocks.iter().map(Vec::len).sum();
    (blocks.iter().flatten().map(|&k| sq[k]).sum::<f64>() / rows as f64).sqrt()
}

/// The other log as the carry-over and the decision ([`super::decide`]) score models on it: its
/// samples in the first log's polynomial shape (on its own scaling), its held-out units
/// ([`held_out_blocks`], at least [`CARRY_MIN_UNITS`]), and its bare polynomial fitted on its
/// training rows, whose derivatives give an effect moved there its schedules.
pub(super) struct OtherLog {
    pub(super) prep: Prepared,
    pub(super) blocks: Vec<Vec<usize>>,
    base_beta: Vec<f64>,
}

impl OtherLog {
    /// `series` (the other log) in `d`'s polynomial shape; an error when the polynomial cannot
    /// be fitted there or the held-out units are too few.
    pub(super) fn new(d: &Diagnosis, series: Series) -> Result<Self, DiagnoseError> {
        let basis = PolyBasis::for_data(&series.v, &series.vdot, d.basis.n, d.basis.m)
            .map_err(|e| DiagnoseError::Degenerate(format!("the other log's polynomial: {e}")))?;
        let prep = Prepared::new(series, basis);
        let blocks = held_out_blocks(&prep);
        if blocks.len() < CARRY_MIN_UNITS {
            return Err(DiagnoseError::Degenerate(format!(
                "{} held-out units of data on the other log, {CARRY_MIN_UNITS} needed",
                blocks.len()
            )));
        }
        let base = lsq::fit(&build(&prep, &[]).cols, &prep.series.p, &prep.train_rows)
            .ok_or_else(|| DiagnoseError::Degenerate("the other log's polynomial".into()))?;
        Ok(Self {
            prep,
            blocks,
            base_beta: base.beta,
        })
    }

    /// `e` (at the first log's parameters) with its schedules on this log ([`with_schedules`]).
    pub(super) fn moved(&self, e: &Effect) -> Effect {
        with_schedules(&self.prep, e, &self.base_beta)
    }

    /// Squared errors per row of the polynomial with `effects`, fitted on the training rows.
    pub(super) fn held_errors(&self, effects: &[Effect]) -> Option<Vec<f64>> {
        let p = &self.prep.series.p;
        let design = build(&self.prep, effects);
        let fit = lsq::fit(&design.cols, p, &self.prep.train_rows)?;
        let pred = lsq::predict(&design.cols, &fit.beta);
        Some(p.iter().zip(&pred).map(|(y, q)| (y - q).powi(2)).collect())
    }

    /// RMSE over the held-out units, from [`OtherLog::held_errors`].
    pub(super) fn rmse(&self, sq: &[f64]) -> f64 {
        blocks_rmse(sq, &self.blocks)
    }
}

/// Longest stretch of held-out time one unit of the paired comparison covers, s: a held-out
/// cycle longer than this is cut into pieces.
const UNIT_S: f64 = 5.0;
/// Units the held-out time is cut into at least, where [`MIN_UNIT_ROWS`] allows: a short log
/// with two held-out cycles still gives a dozen (their serial correlation is taken into account
/// in [`compare`]).
const MIN_UNITS: usize = 12;
/// Fewest rows of a unit.
const MIN_UNIT_ROWS: usize = 20;
/// Fewest units a carry-over is computed on.
pub const CARRY_MIN_UNITS: usize = 3;

/// The held-out rows of `prep` in runs of consecutive rows (its held-out cycles), each cut into
/// pieces of at most [`UNIT_S`], shorter where that gives fewer than [`MIN_UNITS`], never under
/// [`MIN_UNIT_ROWS`] rows (a shorter run is one unit).
pub(super) fn held_out_blocks(prep: &Prepared) -> Vec<Vec<usize>> {
    let (t, held) = (&prep.series.t, &prep.held_rows);
    let dt = prep.scales.dt;
    let held_s = held.len() as f64 * dt;
    let unit_s = UNIT_S
        .min(held_s / MIN_UNITS as f64)
        .max(MIN_UNIT_ROWS as f64 * dt);
    let mut blocks: Vec<Vec<usize>> = Vec::new();
    for &k in held {
        match blocks.last_mut() {
            Some(b) if b.last() == Some(&(k - 1)) && t[k] - t[b[0]] < unit_s - 0.5 * dt => {
                b.push(k)
            }
            _ => blocks.push(vec![k]),
        }
    }
    blocks
}

/// The paired z of two models' squared errors per row, `a` against `b`, over `blocks` (units of
/// consecutive held-out rows, [`held_out_blocks`]): per unit the log ratio of the sums of
/// squared errors, `ln(Σ a / Σ b)` (scale-free, so a unit where the models' difference is large
/// does not outweigh the rest: a consistent difference counts, not one large one), then its mean
/// over its standard error with the units' lag-1 autocorrelation ρ taken into account (the
/// variance of the mean of an AR(1) series, `s²/n · (1 + ρ)/(1 − ρ)`, ρ clamped to [0, 0.9]).
/// Positive when `b` has the smaller errors. The one paired test of the loop: carry-over to
/// another log ([`carry_over`]) and the alternatives the data cannot tell from a kept effect
/// ([`super::alternatives`]).
pub fn paired_z(a: &[f64], b: &[f64], blocks: &[Vec<usize>]) -> f64 {
    let d: Vec<f64> = blocks
        .iter()
        .map(|u| {
            let sum = |e: &[f64]| u.iter().map(|&k| e[k]).sum::<f64>().max(f64::MIN_POSITIVE);
            (sum(a) / sum(b)).ln()
        })
        .collect();
    let n = d.len() as f64;
    if d.len() < 2 {
        return 0.0;
    }
    let mean = d.iter().sum::<f64>() / n;
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
    // Neighbouring units of one cycle are alike: an AR(1) effective count n (1 − ρ)/(1 + ρ),
    // ρ ≥ 0 only.
    let rho = if var > 0.0 && d.len() > 2 {
        let c1 = d
            .windows(2)
            .map(|w| (w[0] - mean) * (w[1] - mean))
            .sum::<f64>()
            / (n - 1.0);
        (c1 / var).clamp(0.0, 0.9)
    } else {
        0.0
    };
    let se = (var / n * (1.0 + rho) / (1.0 - rho)).sqrt();
    if se > 0.0 {
        mean / se
    } else if mean > 0.0 {
        f64::INFINITY
    } else if mean < 0.0 {
        f64::NEG_INFINITY
    } else {
        0.0
    }
}

/// Held-out RMSEs, gain and paired z of `with` against `without` (squared errors per row).
fn compare(effect: String, without: &[f64], with: &[f64], blocks: &[Vec<usize>]) -> CarryOver {
    let (without_rmse, with_rmse) = (blocks_rmse(without, blocks), blocks_rmse(with, blocks));
    let gain = 1.0 - with_rmse / without_rmse;
    let z = paired_z(without, with, blocks);
    CarryOver {
        effect,
        without_rmse,
        with_rmse,
        gain,
        z,
        units: blocks.len(),
        carries: gain > 0.0 && z >= CARRY_Z,
    }
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
pub(super) fn with_schedules(prep: &Prepared, e: &Effect, poly: &[f64]) -> Effect {
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
    let mut v = validate(d, series, data.name()).map_err(wrap)?;
    // The carry-over refits on the other log's training cycles and scores its held-out ones.
    let own = super::series_from_dataset(ds).map_err(wrap)?;
    match carry_over(d, own) {
        Ok(c) => v.carry_over = c,
        Err(e) => v.carry_over_note = Some(format!("carry-over not computed: {e}")),
    }
    Ok(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The paired z by hand, with a lag-1 correlation: four units, the log ratios
    /// d = ln 8, ln 4, ln 2, ln 1 = (3, 2, 1, 0) ln 2. Mean 1.5 ln 2, deviations (1.5, 0.5, −0.5,
    /// −1.5) ln 2, s² = 5/3 (ln 2)², lag-1 sum (0.75 − 0.25 + 0.75)(ln 2)² = 1.25 (ln 2)², over
    /// n − 1: 5/12 (ln 2)², ρ = (5/12)/(5/3) = 1/4. se² = s²/4 · (5/4)/(3/4) = 25/36 (ln 2)²,
    /// se = 5/6 ln 2, z = 1.5 / (5/6) = 1.8. Swapping the models flips the sign; a single unit
    /// gives 0 (no spread to judge by).
    #[test]
    fn the_paired_z_by_hand() {
        let blocks = vec![vec![0], vec![1], vec![2], vec![3]];
        let a = [8.0, 4.0, 2.0, 1.0];
        let b = [1.0; 4];
        let z = paired_z(&a, &b, &blocks);
        assert!((z - 1.8).abs() < 1e-12, "{z}");
        assert!((paired_z(&b, &a, &blocks) + 1.8).abs() < 1e-12);
        assert_eq!(paired_z(&a, &b, &blocks[..1]), 0.0);
        // Sums within a unit: rows of 4 and 4 against 0.5 and 0.5 is ln 8, as one row of 8 is.
        let two = vec![vec![0, 1], vec![2, 3], vec![4, 5], vec![6, 7]];
        let a2 = [4.0, 4.0, 2.0, 2.0, 1.0, 1.0, 0.5, 0.5];
        assert!((paired_z(&a2, &[0.5; 8], &two) - 1.8).abs() < 1e-12);
        // Equal errors: no difference.
        assert_eq!(paired_z(&b, &b, &blocks), 0.0);
    }

    #[test]
    fn the_paired_comparison_by_hand() {
        // Three units of two rows; squared errors 4, 2, 1 without the effect, 1 with it: log
        // ratios ln 4, ln 2, 0, mean ln 2 and standard deviation ln 2, no lag-1 correlation
        // (deviations ln 2, 0, −ln 2), so z = ln 2 / (ln 2 / √3) = √3.
        let blocks = vec![vec![0, 1], vec![2, 3], vec![4, 5]];
        let without = [4.0, 4.0, 2.0, 2.0, 1.0, 1.0];
        let with = [1.0; 6];
        let c = compare("e".into(), &without, &with, &blocks);
        assert!((c.z - 3f64.sqrt()).abs() < 1e-12, "{c:?}");
        assert!((c.without_rmse - (14.0f64 / 6.0).sqrt()).abs() < 1e-12);
        assert_eq!(c.with_rmse, 1.0);
        assert!((c.gain - (1.0 - (6.0f64 / 14.0).sqrt())).abs() < 1e-12);
        assert_eq!(c.units, 3);
        assert!(!c.carries, "z below {CARRY_Z}");
        // The same reduction in every unit: no spread, as strong as it gets.
        let c = compare("e".into(), &[2.0; 6], &with, &blocks);
        assert_eq!(c.z, f64::INFINITY);
        assert!(c.carries);
        // Worse with it: never carries.
        let c = compare("e".into(), &with, &without, &blocks);
        assert!(c.z < 0.0 && c.gain < 0.0 && !c.carries, "{c:?}");
    }
}
