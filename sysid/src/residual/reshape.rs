//! The baseline's shape chosen again with the effects (issue 34): a simpler polynomial plus an
//! effect can beat the complex polynomial alone, and the shape selection, which sees no effect,
//! cannot know it. A high shape's flow degrees absorb a weak hysteresis (a step in v̇'s sign is
//! what a degree-7 polynomial in v̇ approximates); from that shape no effect passes, and "after an
//! effect is kept" never comes.
//!
//! After the loop has run from the selected shape S ([`super::diagnose`]):
//!
//! 1. **Probe.** Models are scored by the shape selection's own cycle-blocked cross-validation
//!    ([`crate::select`]: the same training blocks and folds, each fold's fit from the other
//!    folds' moments, here the Gram moments of the model's design, so the effects' columns take
//!    part), at the effects' searched parameters: every shape T with at most [`SIMPLER`] times
//!    S's parameters whose own cross-validated typical RMSE is at most [`CLOSE`] times S's (the
//!    shapes where the choice is close: an effect the polynomial absorbs is a small share of the
//!    error), and S itself; each alone, with the effects the loop kept, and with each of the first
//!    round's leading candidates ([`LEADS`], those with a held-out gain, physical, as searched on
//!    S's baseline). The selection's rule chooses among them all, parameters counted with the
//!    effects' (their coefficients and searched parameters): the fewest parameters within one
//!    standard error of the lowest typical error (paired block by block) and at most
//!    [`crate::select::MAX_RMSE_RATIO`] times it.
//! 2. **Second start.** When that choice is a simpler shape T with an effect (a first-round lead
//!    must also pass the loop's test on T's baseline, `lead_passes`), the whole loop runs
//!    again from T (its effects found afresh, not carried over).
//! 3. **Outcome.** The two loops' final models (each at its effects' parameters) are compared by
//!    the same rule; the one it chooses is the diagnosis, and the report says which shape was
//!    selected, which one the final model uses and the numbers that decided.
//!
//! The held-out cycles take no part, so the held-out RMSE reported stays an honest estimate.
//!
//! **Off by default** (`Config::reshape`, `vfp diagnose --reshape`): on the loop benchmark it
//! finds one planted effect more in 122 and ends nine more rigs of 95 on the plant's law shape,
//! for 26 % more CPU (the guide's residual-loop chapter has the numbers).
//!
//! # Richer shapes (on by default)
//!
//! The selection errs the other way too: where one effect dominates a log's error, a shape
//! without a degree the law has is within the band of the best (what the degree would explain
//! is small beside the unmodelled effect), and the loop from it names the right effect but ends
//! above the noise. On the loop benchmark's breathing logs of host-sim's (3, 2) law the
//! selection took (3, 1) on rigs with an air pocket, a sensor lag or a leak alone, and the loop
//! ended at 1.2–2.2 σ with the right effect named; on a rig with an air pocket and a backlash,
//! (2, 1) and a sensor lag at 37 σ. So after every loop from a selected shape
//! ([`probe_richer`]): the loop's kept effects at their searched parameters are scored as in
//! step 1 with the selected shape and with every admissible shape of the sweep that contains it
//! (n′ ≥ n, m′ ≥ m: nested, never a worse fit in-sample) and has at most
//! [`select::MAX_PARAMS`] terms (the most a reduced model keeps), and the rule chooses. Where
//! it chooses a richer shape whose typical error the selected one exceeds by more than
//! [`RICHER_GAIN`], the loop runs again from it and the two final models are compared as in
//! step 3. Logs of more than [`MAX_SAMPLES`] samples are not probed. Without the cap, on
//! host-sim's air preset on the paper's protocol (`bench/long_logs.sh`) the probe went from
//! (7, 3) to (7, 7), 64 terms whose flow degrees took up the air pocket's form error, and the
//! loop from there named a backlash and a hysteresis the plant does not have, in 42 s of CPU
//! against 7.5 s.
//!
//! **Cost.** The probe builds one design per effect set on the training rows, with the largest
//! shape compared (at most 1 + 1 + [`LEADS`] designs), and solves small systems; the second loop
//! runs only where the probe chose a simpler shape, and costs less than the first (fewer
//! columns). Logs of more than [`MAX_SAMPLES`] samples are not probed (a design of 64 columns
//! over 270,000 samples is 140 MB and a second loop there would break the 3-hour log's budget);
//! the report says so.

use nalgebra::{DMatrix, DVector};
use serde::Serialize;

use super::basis::PolyBasis;
use super::effects::{build, Effect, Prepared};
use super::Series;
use crate::select::{self, BlockKind, Blocks, CvScore};

/// Largest ratio of a simpler shape's own cross-validated typical RMSE (without effects) to the
/// selected shape's for the simpler shape to be probed: where a shape is much worse than the
/// selected one alone, what it lacks is larger than an effect the selected one absorbs, which
/// the loop finds from the selected shape.
pub const CLOSE: f64 = 2.0;

/// Most parameters of a probed shape, as a share of the selected shape's: a second loop costs
/// about as much as the first, and on the loop benchmark (100 rigs of seed 1) the shapes less
/// simpler than this that the probe chose ((7, 7) → (6, 5), (7, 5) → (6, 5), (7, 3) → (5, 4))
/// ended on the same effects at the same error, at twice the CPU.
pub const SIMPLER: f64 = 0.5;

/// Smallest ratio of the selected shape's typical cross-validated RMSE (with the loop's effects)
/// to the richer shape's the rule chooses for the loop to run again from the richer one (module
/// docs, "Richer shapes"): the selection's own tolerance ([`select::MAX_RMSE_RATIO`]). Where
/// the richer shape gains less, the loop from it ends on the same effects at the same error: on
/// the loop benchmark (seed 1) rigs whose richer choice gained 0.03–1.8 % ended within 1.7 % of
/// their first loop's error, at twice its CPU.
pub const RICHER_GAIN: f64 = select::MAX_RMSE_RATIO;

/// Leading candidates of the first round probed (lowest held-out RMSE first).
pub const LEADS: usize = 3;

/// Longest log probed, samples (module docs, "Cost").
pub const MAX_SAMPLES: usize = 60_000;

/// One model's cross-validated error as the step compared it.
#[derive(Clone, Debug, Serialize)]
pub struct ModelCv {
    /// Degree in volume.
    pub n: usize,
    /// Degree in flow.
    pub m: usize,
    /// Its effects (machine names).
    pub effects: Vec<&'static str>,
    /// Parameters: the polynomial's, the effects' coefficients and searched parameters.
    pub nu: usize,
    /// Typical block RMSE (kPa; [`crate::select`], step 3).
    pub typical_rmse: f64,
    /// Pooled cross-validated RMSE (kPa).
    pub cv_rmse: f64,
    /// Its excess over the lowest typical error of its comparison and that excess's standard
    /// error ([`select::paired_excess`]: mean log ratio of block errors on cycle blocks): the
    /// rule admits an excess up to one standard error.
    pub excess: (f64, f64),
}

/// What the step did (JSON `reshape`; [`super::Diagnosis::reshape`]).
#[derive(Clone, Debug, Serialize)]
pub struct ReshapeReport {
    /// The shape selected at the start, without effects.
    pub selected: (usize, usize),
    /// The shape the final model uses.
    pub used: (usize, usize),
    /// What was decided, in words.
    pub verdict: String,
    /// The simpler shape the loop ran again from, if it did.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub second_start: Option<(usize, usize)>,
    /// The probe's choice and the selected shape's models, as scored (step 1).
    pub probe: Vec<ModelCv>,
    /// The two loops' final models, when the loop ran twice (step 3).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub outcomes: Vec<ModelCv>,
}

/// Each training block's Gram moments of one design (its columns scaled to unit RMS on the
/// training rows, the pressure centred), and each fold's fit moments: the other folds' blocks.
struct BlockGram {
    g: Vec<DMatrix<f64>>,
    b: Vec<DVector<f64>>,
    yy: Vec<f64>,
    n: Vec<usize>,
    fit_g: Vec<DMatrix<f64>>,
    fit_b: Vec<DVector<f64>>,
    /// Columns that are not zero on the training rows.
    usable: Vec<bool>,
}

impl BlockGram {
    /// The moments of `cols` on the training rows `rows` cut into `blocks` (ranges of `rows`).
    fn new(
        cols: &[Vec<f64>],
        y: &[f64],
        rows: &[usize],
        blocks: &[std::ops::Range<usize>],
    ) -> Self {
        let p = cols.len();
        let nt = rows.len().max(1) as f64;
        let scale: Vec<f64> = cols
            .iter()
            .map(|c| (rows.iter().map(|&r| c[r] * c[r]).sum::<f64>() / nt).sqrt())
            .collect();
        let usable: Vec<bool> = scale.iter().map(|s| s.is_finite() && *s > 0.0).collect();
        let centre = rows.iter().map(|&r| y[r]).sum::<f64>() / nt;
        let (mut g, mut b, mut yy, mut n) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
        for range in blocks {
            let rs = &rows[range.clone()];
            let x = DMatrix::from_fn(rs.len(), p, |i, j| {
                if usable[j] {
                    cols[j][rs[i]] / scale[j]
                } else {
                    0.0
                }
            });
            let yb = DVector::from_iterator(rs.len(), rs.iter().map(|&r| y[r] - centre));
            g.push(x.tr_mul(&x));
            b.push(x.tr_mul(&yb));
            yy.push(yb.norm_squared());
            n.push(rs.len());
        }
        let folds = select::MAX_FOLDS.min(blocks.len()).max(1);
        let mut fit_g = vec![DMatrix::zeros(p, p); folds];
        let mut fit_b = vec![DVector::zeros(p); folds];
        for (k, (fg, fb)) in fit_g.iter_mut().zip(fit_b.iter_mut()).enumerate() {
            for blk in 0..g.len() {
                if blk % folds != k {
                    *fg += &g[blk];
                    *fb += &b[blk];
                }
            }
        }
        Self {
            g,
            b,
            yy,
            n,
            fit_g,
            fit_b,
            usable,
        }
    }

    /// Each block's SSE under the fold that left it out, for the model of columns `sub`; `None`
    /// when a fold cannot fit it.
    fn block_sse(&self, sub: &[usize]) -> Option<Vec<f64>> {
        let sub: Vec<usize> = sub.iter().copied().filter(|&j| self.usable[j]).collect();
        let s = sub.len();
        let folds = self.fit_g.len();
        let coefs: Vec<DVector<f64>> = (0..folds)
            .map(|k| {
                let a = DMatrix::from_fn(s, s, |i, j| self.fit_g[k][(sub[i], sub[j])]);
                let r = DVector::from_fn(s, |i, _| self.fit_b[k][sub[i]]);
                a.cholesky().map(|c| c.solve(&r))
            })
            .collect::<Option<_>>()?;
        Some(
            (0..self.g.len())
                .map(|blk| {
                    let c = &coefs[blk % folds];
                    let (g, b) = (&self.g[blk], &self.b[blk]);
                    let mut cgc = 0.0;
                    let mut cb = 0.0;
                    for i in 0..s {
                        cb += c[i] * b[sub[i]];
                        let mut row = 0.0;
                        for j in 0..s {
                            row += g[(sub[i], sub[j])] * c[j];
                        }
                        cgc += c[i] * row;
                    }
                    (self.yy[blk] - 2.0 * cb + cgc).max(0.0)
                })
                .collect(),
        )
    }
}

/// The training blocks of the shape selection ([`select::training_blocks`]) and the training
/// pressure's variance, on the loop's series.
pub(super) struct CvSetup {
    blocks: Blocks,
    var_p: f64,
}

impl CvSetup {
    /// The selection's blocks, checked against the series' training rows (the same samples).
    pub(super) fn new(blocks: Blocks, series: &Series) -> Option<Self> {
        let rows: Vec<usize> = (0..series.len()).filter(|&k| series.train[k]).collect();
        let covered = blocks.ranges.iter().map(|r| r.end).max().unwrap_or(0);
        if blocks.ranges.len() < 2 || covered > rows.len() {
            return None;
        }
        let nt = rows.len() as f64;
        let mean = rows.iter().map(|&r| series.p[r]).sum::<f64>() / nt;
        let var_p = rows
            .iter()
            .map(|&r| (series.p[r] - mean).powi(2))
            .sum::<f64>()
            / nt;
        Some(Self { blocks, var_p })
    }
}

/// Parameters of effects beside the polynomial: their coefficients (design columns) and searched
/// parameters (as [`super::search::Stage::n_params`] counts them).
fn effect_params(effects: &[Effect], columns: usize) -> usize {
    columns
        + effects
            .iter()
            .map(|e| usize::from(e.kind.has_nonlinear()) + e.count_lag.lags.len())
            .sum::<usize>()
}

/// Models of one effect set over shapes: the design built once with the largest shape, each
/// shape its columns.
struct SetScorer<'a> {
    prep: Prepared,
    setup: &'a CvSetup,
}

impl<'a> SetScorer<'a> {
    /// The scorer for the shapes `shapes` of `series`: one basis of the largest degrees among
    /// them (each shape's columns a subset of its), the series prepared on it. `None` without
    /// a shape or a basis.
    fn new(series: &Series, setup: &'a CvSetup, shapes: &[(usize, usize)]) -> Option<Self> {
        let nmax = shapes.iter().map(|s| s.0).max()?;
        let mmax = shapes.iter().map(|s| s.1).max()?;
        let basis = PolyBasis::for_data(&series.v, &series.vdot, nmax, mmax).ok()?;
        Some(Self {
            prep: Prepared::new(series.clone(), basis),
            setup,
        })
    }

    /// The scores of `effects` with each shape of `shapes` (a shape some fold cannot fit is left
    /// out).
    fn scores(&self, effects: &[Effect], shapes: &[(usize, usize)]) -> Vec<(CvScore, Vec<Effect>)> {
        let design = build(&self.prep, effects);
        let big = &self.prep.basis;
        let added: Vec<usize> = (big.len()..design.cols.len()).collect();
        let gram = BlockGram::new(
            &design.cols,
            &self.prep.series.p,
            &self.prep.train_rows,
            &self.setup.blocks.ranges,
        );
        drop(design);
        let log_ratios = self.setup.blocks.kind == BlockKind::Cycles;
        shapes
            .iter()
            .filter_map(|&(n, m)| {
                let mut sub: Vec<usize> = (0..=n)
                    .flat_map(|i| (0..=m).map(move |j| i * (big.m + 1) + j))
                    .collect();
                sub.extend(&added);
                let sse = gram.block_sse(&sub)?;
                let nu = (n + 1) * (m + 1) + effect_params(effects, added.len());
                let s =
                    select::cv_score(n, m, nu, sse, gram.n.clone(), self.setup.var_p, log_ratios);
                Some((s, effects.to_vec()))
            })
            .collect()
    }
}

/// A [`ModelCv`] of `s` (with `effects`) against `best`.
fn model_cv(s: &CvScore, effects: &[Effect], best: &CvScore) -> ModelCv {
    ModelCv {
        n: s.n,
        m: s.m,
        effects: effects.iter().map(|e| e.kind.name()).collect(),
        nu: s.nu,
        typical_rmse: s.typical_rmse(),
        cv_rmse: s.rmse(),
        excess: select::paired_excess(s, best),
    }
}

/// The rule's choice among `pool` and its lowest-error model, with their effects.
fn choose(pool: &[(CvScore, Vec<Effect>)]) -> Option<(usize, usize)> {
    let scores: Vec<CvScore> = pool.iter().map(|p| p.0.clone()).collect();
    let chosen = select::one_se_rule(&scores)?;
    let best = select::lowest(&scores)?;
    let idx = |t: &CvScore| scores.iter().position(|s| s == t);
    Some((idx(&chosen)?, idx(best)?))
}

/// What the probe decided.
pub(super) enum Probe {
    /// No simpler shape is worth a second start; the report's numbers.
    Stay(ReshapeReport),
    /// Run the loop again from this shape.
    Retry {
        shape: (usize, usize),
        probe: Vec<ModelCv>,
        /// The effects of the probe's choice, and whether the loop kept them (else they are a
        /// lead of its first round).
        effects: Vec<Effect>,
        kept: bool,
    },
}

/// Step 1 (module docs): `selected` the start's shape, `shape_scores` the selection's sweep,
/// `kept` the loop's final effects and `leads` its first round's leading candidates.
pub(super) fn probe(
    series: &Series,
    setup: &CvSetup,
    selected: (usize, usize),
    shape_scores: &[CvScore],
    kept: &[Effect],
    leads: &[Effect],
) -> Probe {
    let stay = |verdict: String, probe: Vec<ModelCv>| {
        Probe::Stay(ReshapeReport {
            selected,
            used: selected,
            verdict,
            second_start: None,
            probe,
            outcomes: Vec::new(),
        })
    };
    if series.len() > MAX_SAMPLES {
        return stay(
            format!("not tried: the log has more than {MAX_SAMPLES} samples"),
            Vec::new(),
        );
    }
    let nu = (selected.0 + 1) * (selected.1 + 1);
    let Some(own) = shape_scores
        .iter()
        .find(|s| (s.n, s.m) == selected)
        .map(|s| s.typical_mse)
    else {
        return stay(
            "not tried: the selected shape has no score".into(),
            Vec::new(),
        );
    };
    let mut shapes: Vec<(usize, usize)> = shape_scores
        .iter()
        .filter(|s| {
            (s.nu as f64) <= SIMPLER * nu as f64
                && s.admissible
                && s.typical_mse.is_finite()
                && s.typical_mse <= CLOSE * CLOSE * own
        })
        .map(|s| (s.n, s.m))
        .collect();
    if shapes.is_empty() {
        return stay(
            format!(
                "kept: no shape of at most {SIMPLER} times the parameters comes within {CLOSE} times the selected shape's cross-validated error"
            ),
            Vec::new(),
        );
    }
    shapes.push(selected);
    let Some(scorer) = SetScorer::new(series, setup, &shapes) else {
        return stay("not tried: no basis".into(), Vec::new());
    };
    let mut sets: Vec<Vec<Effect>> = vec![Vec::new()];
    if !kept.is_empty() {
        sets.push(kept.to_vec());
    }
    for l in leads.iter().take(LEADS) {
        if !kept.iter().any(|k| k.kind == l.kind) {
            sets.push(vec![l.clone()]);
        }
    }
    let pool: Vec<(CvScore, Vec<Effect>)> = sets
        .iter()
        .flat_map(|set| scorer.scores(set, &shapes))
        .collect();
    let Some((ci, bi)) = choose(&pool) else {
        return stay("not tried: no model could be scored".into(), Vec::new());
    };
    let best = &pool[bi].0;
    let mut shown: Vec<usize> = vec![ci];
    for (i, (s, set)) in pool.iter().enumerate() {
        let is_selected = (s.n, s.m) == selected;
        let is_kept =
            set.len() == kept.len() && set.iter().zip(kept).all(|(a, b)| a.kind == b.kind);
        if is_selected && (set.is_empty() || is_kept) && !shown.contains(&i) {
            shown.push(i);
        }
    }
    let numbers: Vec<ModelCv> = shown
        .iter()
        .map(|&i| model_cv(&pool[i].0, &pool[i].1, best))
        .collect();
    let (c, set) = (&pool[ci].0, &pool[ci].1);
    if (c.n, c.m) == selected || set.is_empty() {
        return stay(
            format!(
                "kept: no simpler shape with an effect comes within one standard error of the lowest cross-validated error ({} simpler shapes probed)",
                shapes.len() - 1
            ),
            numbers,
        );
    }
    let is_kept = set.len() == kept.len() && set.iter().zip(kept).all(|(a, b)| a.kind == b.kind);
    Probe::Retry {
        shape: (c.n, c.m),
        probe: numbers,
        effects: set.clone(),
        kept: is_kept,
    }
}

/// The richer probe ([`super::diagnose_dataset`], module docs "Richer shapes"): the loop's kept
/// effects `kept` (at their searched parameters) with the selected shape and with every
/// admissible shape of the sweep `shape_scores` that contains it (n′ ≥ n, m′ ≥ m: nested, so
/// none fits the training data worse), chosen by the selection's rule. `None` when the rule
/// keeps the selected shape (or nothing could be scored); else the richer shape and the models
/// as scored (the choice and the selected shape's).
pub(super) fn probe_richer(
    series: &Series,
    setup: &CvSetup,
    selected: (usize, usize),
    shape_scores: &[CvScore],
    kept: &[Effect],
) -> Option<((usize, usize), Vec<ModelCv>)> {
    if kept.is_empty() || series.len() > MAX_SAMPLES {
        return None;
    }
    let mut shapes: Vec<(usize, usize)> = shape_scores
        .iter()
        .filter(|s| {
            s.n >= selected.0
                && s.m >= selected.1
                && (s.n, s.m) != selected
                && s.nu <= select::MAX_PARAMS
                && s.admissible
                && s.typical_mse.is_finite()
        })
        .map(|s| (s.n, s.m))
        .collect();
    if shapes.is_empty() {
        return None;
    }
    shapes.push(selected);
    let scorer = SetScorer::new(series, setup, &shapes)?;
    let pool = scorer.scores(kept, &shapes);
    let (ci, bi) = choose(&pool)?;
    let c = &pool[ci].0;
    let own = &pool.iter().find(|(s, _)| (s.n, s.m) == selected)?.0;
    if (c.n, c.m) == selected || own.typical_rmse() <= RICHER_GAIN * c.typical_rmse() {
        return None;
    }
    let best = &pool[bi].0;
    Some((
        (c.n, c.m),
        vec![model_cv(c, kept, best), model_cv(own, kept, best)],
    ))
}

/// Whether a first-round lead `e` (as searched on the selected shape) passes the loop's test on
/// shape `shape`'s baseline ([`super::state::passes`]): a lead that does not would not be kept
/// there either, and the second loop is not run for it.
pub(super) fn lead_passes(
    series: &Series,
    cfg: &super::Config,
    shape: (usize, usize),
    e: &Effect,
) -> bool {
    let Ok(basis) = PolyBasis::for_data(&series.v, &series.vdot, shape.0, shape.1) else {
        return false;
    };
    let prep = Prepared::new(series.clone(), basis);
    let (Some(base), Some(with)) = (
        super::search::fit_stage(&prep, &[]),
        super::search::fit_stage(&prep, std::slice::from_ref(e)),
    ) else {
        return false;
    };
    let test = super::search::nested_test(&prep, &base, &with);
    super::state::passes(cfg, &base, &with, &test)
}

/// Step 3 (module docs): scores the final models of the loop from `selected` (its effects
/// `first`) and from `second` (`then`) and returns whether the second is chosen, with the
/// numbers.
pub(super) fn compare(
    series: &Series,
    setup: &CvSetup,
    selected: (usize, usize),
    first: &[Effect],
    second: (usize, usize),
    then: &[Effect],
) -> Option<(bool, Vec<ModelCv>)> {
    let scorer = SetScorer::new(series, setup, &[selected, second])?;
    let a = scorer.scores(first, &[selected]).pop()?;
    let b = scorer.scores(then, &[second]).pop()?;
    let pool = [a, b];
    let (ci, bi) = choose(&pool)?;
    let best = &pool[bi].0;
    let numbers = pool.iter().map(|(s, e)| model_cv(s, e, best)).collect();
    Some((ci == 1, numbers))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// By hand: two blocks of rows fitted by the constant alone: each block's error is its
    /// squared distance from the other block's mean (two folds, each fitted on the other).
    #[test]
    fn a_blocks_error_is_its_misfit_under_the_other_folds_fit() {
        let cols = vec![vec![1.0; 4]];
        let y = [1.0, 3.0, 10.0, 12.0];
        let rows = [0, 1, 2, 3];
        let g = BlockGram::new(&cols, &y, &rows, &[0..2, 2..4]);
        let sse = g.block_sse(&[0]).unwrap();
        // Block 0 (1, 3) predicted by block 1's mean 11: 100 + 64; block 1 (10, 12) by 2: 64 + 100.
        assert!((sse[0] - 164.0).abs() < 1e-9, "{sse:?}");
        assert!((sse[1] - 164.0).abs() < 1e-9, "{sse:?}");
        // With a slope column the line through the other block predicts exactly only when it is
        // the same line: y = 1 + 2x on x = 0, 1 and 10 + 2x' on x' = 0, 1 → not the same.
        let cols = vec![vec![1.0; 4], vec![0.0, 1.0, 4.5, 5.5]];
        let y2 = [1.0, 3.0, 10.0, 12.0];
        let g = BlockGram::new(&cols, &y2, &rows, &[0..2, 2..4]);
        // Each fold has two points and two unknowns: an exact fit of its own block; the lines are
        // y = 1 + 2x and y = 1 + 2x (10 = 1 + 2·4.5, 12 = 1 + 2·5.5): the same, so no error.
        let sse = g.block_sse(&[0, 1]).unwrap();
        assert!(sse.iter().all(|&e| e < 1e-9), "{sse:?}");
    }
}
