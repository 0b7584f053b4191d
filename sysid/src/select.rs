//! Choosing the polynomial's shape (n, m): the simplest model the data cannot tell apart from the
//! best, by cycle-blocked cross-validation and Breiman's one-standard-error rule.
//!
//! # Why not AICc alone
//! AICc (and BIC) assume independent errors. At 25-100 Hz the residual of a P(v, v̇) model is
//! strongly autocorrelated (lag-1 correlations of 0.8 are common), so there are far fewer
//! independent observations than samples, and every added term looks worth its penalty: on real
//! logs AICc picks the sweep's ceiling, (7, 7) with 64 parameters, even where a 12-parameter
//! model predicts held-out cycles as well or better. The paper's message is that a low-complexity
//! model suffices; the selection should find the lowest complexity the data support.
//!
//! # The rule
//! 1. The training cycles are the blocks (a cycle is the unit of repetition, and the errors within
//!    one are correlated). With fewer than [`MIN_CYCLE_BLOCKS`] training cycles, the training
//!    samples are cut into [`TIME_STRETCHES`] short stretches of time instead, so that every fold
//!    leaves out several short pieces spread over the log: a few long stretches of a log that
//!    visits its flow levels one after another would each hold a whole flow level, and the folds
//!    would measure extrapolation to flows they never saw (on a one-cycle, two-flow simulated log
//!    every shape with m ≥ 2 scored hundreds of kPa that way, and the rule fell back to (3, 1),
//!    linear in flow, which the plant's (3, 2) law is not).
//! 2. Blocks are dealt to K = min([`MAX_FOLDS`], blocks) folds in time order (block b to fold
//!    b mod K). Each shape is fitted K times, each time without one fold, and scored on the
//!    blocks of the fold it left out. All of it comes from per-block Chebyshev moments
//!    ([`crate::poly::Moments`]): a fold's fit sums the other blocks' moments, a block's error is
//!    yy − 2cᵀb + cᵀGc on its own moments. No design matrix is built.
//! 3. The cross-validated error of a shape is its pooled mean squared error over all blocks,
//!    ē = Σ SSE_b / Σ n_b (e_b = SSE_b / n_b, weights w_b = n_b / N), and its *typical* block
//!    error is the geometric mean ẽ = exp(mean_b ln(e_b + ε)), ε = [`ERROR_FLOOR`] · Var(P) (a
//!    guard against log 0 only). On cycle blocks shapes are ranked by ẽ; on time stretches by ē
//!    (step 5 says why).
//! 4. A shape is *admissible* when on every block its error is at most the variance of the
//!    training pressure, e_b ≤ Var(P): a prediction that misses by more than the pressure's own
//!    spread on some stretch of the log is worse there than the constant mean (R² below zero),
//!    whatever it does elsewhere. Only admissible shapes are compared (all of them, if none is).
//!    The paired rule below cannot do this by itself: when the whole excess sits in one block
//!    (one fold whose fit extrapolates), the standard error of the excess equals the excess, and
//!    "within one standard error" holds however large it is (on a simulated rig log whose last
//!    training cycle is cut short, (1, 4) at 68 kPa passed against (7, 2) at 0.06 kPa).
//! 5. The selected shape is the one with the fewest parameters ν = (n+1)(m+1) whose excess over
//!    the best is at most one standard error of that excess, paired block by block (Breiman et
//!    al., *Classification and Regression Trees*, 1984, §3.4.3; Hastie, Tibshirani and Friedman,
//!    *The Elements of Statistical Learning*, §7.10), and whose typical RMSE is at most
//!    [`MAX_RMSE_RATIO`] times the best's. Equal ν: the lower error. Every shape is scored on the
//!    same blocks, so variation from block to block that all shapes share cancels.
//!    - On cycle blocks the excess is the mean log ratio d̄ = mean_b ln((e_b + ε)/(e_b,best + ε))
//!      and SE² = Σ (d_b − d̄)² / (B(B−1)): every cycle counts once, on its own scale. Cycles at
//!      different operating points, rates or depths are not exchangeable: a breath outside what
//!      the other folds saw (a PEEP step, a breath 40 % deeper) makes every fold fit extrapolate,
//!      its error is 10-100 times the others', and in the pooled ē it decides both the best shape
//!      and the standard error, which then opens the band to tiny shapes. On a host-sim breath log
//!      (`host_sim::breath_logs`, varied breaths, seed 2) the pooled rule took (2, 3), worse than
//!      the best on 18 of 19 training cycles, at 4.7 times the sweep's best held-out RMSE; this
//!      rule takes (5, 7).
//!    - On time stretches (fewer than [`MIN_CYCLE_BLOCKS`] cycles) the blocks are phases of one or
//!      two strokes (rest, inflation, deflation), whose errors differ by orders of magnitude by
//!      phase; a ratio at rest would count like one in motion. There the excess is the pooled
//!      difference ē − ē_best with SE² = B/(B−1) · Σ w_b² (d_b − d̄)², d_b = e_b − e_b,best.
//!
//! # Terms
//! A shape's (n+1)(m+1) raw terms αᵢⱼ vⁱv̇ʲ are not all needed: the paper reduces its models by
//! dropping negligible terms while keeping their general form. The selected shape's terms are
//! reduced by the same cross-validation and the same rule ([`BlockMoments::reduce_terms`]):
//! 1. backward elimination on the training data: from the full shape, drop the raw term (never
//!    the constant) whose removal raises the training SSE least, and repeat down to one term
//!    (restricted least squares: the fit without the terms S is the full fit under the constraint
//!    α_S = 0, as in [`crate::poly::prune`]);
//! 2. every step of that path is cross-validated on the same blocks as the shapes: each fold's
//!    fit without S is the fold's full fit under α_S = 0, and each block's error follows from its
//!    own moments (still no design matrix);
//! 3. the reduced model is the step with the fewest terms within the band of step 5 of the lowest
//!    error seen (the sweep's and the path's), among admissible steps; when that step has more
//!    than [`MAX_PARAMS`] terms, the admissible step of at most [`MAX_PARAMS`] with the lowest
//!    error instead.
//!
//! The path comes from the training fit and the cross-validation only chooses where to stop
//! along it (as for the shapes, where the sweep is fixed and the cross-validation chooses): a
//! path chosen by cross-validated error at every step costs ν times more and fits the blocks'
//! noise.
//!
//! Dropping terms the data cannot use often *lowers* the cross-validated error (a degree-7
//! polynomial's raw terms are nearly collinear, and the dropped ones only fit noise). On the
//! QuickLung log in `data/real/` the selected (7, 5) keeps 39 of its 48 terms (held-out RMSE
//! 0.0532 → 0.0528 kPa), where no smaller *shape* came within the band: the data resolve the
//! degree in v and v̇, not every term of it. The
//! reduced model is what `vfp export` exports by default; the full shape is what the residual
//! loop starts from (its effects are fitted jointly with the shape's columns).
//!
//! The textbook rule takes the standard error of ē_best alone (reported as `cv_limit_rmse`). On
//! the real logs in `data/real/` that band is far wider than the differences between shapes,
//! because breaths differ in difficulty: it took a 6-parameter (2, 1) on the bag-lung log whose
//! held-out RMSE is 29 % above the sweep's best, and (6, 3) on the QuickLung log, 14 % above,
//! while the paired differences showed both consistently worse on every cycle (5 to 13 SE).
//!
//! The held-out cycles take no part in it, so the held-out RMSE reported for the selected model
//! stays an honest estimate. The AICc pick and the paper's joint-cost pick (eq. (8) here, with the
//! weights given) are reported beside it.

use crate::dataset::Dataset;
use crate::metrics::CostWeights;
use crate::poly::{self, Moments, PolyError, Scaling, Xy};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;
use std::ops::Range;

/// Fewest training cycles used as blocks; with fewer, time stretches are used.
pub const MIN_CYCLE_BLOCKS: usize = 5;
/// Most folds of the cross-validation.
pub const MAX_FOLDS: usize = 10;
/// Number of time stretches used as blocks when there are too few cycles: four per fold, so
/// each fold leaves out four short pieces spread over the log.
pub const TIME_STRETCHES: usize = 4 * MAX_FOLDS;
/// Largest ratio of the selected model's typical cross-validated RMSE to the lowest (module
/// docs, step 5): however wide the standard error, the rule never trades more accuracy than this
/// for fewer terms.
pub const MAX_RMSE_RATIO: f64 = 1.05;
/// Most parameters of the reduced model (module docs, "Terms"), when a model of at most this
/// many is admissible.
pub const MAX_PARAMS: usize = 40;
/// Floor added to every block's mean squared error before its logarithm is taken, as a fraction
/// of the training pressure's variance: it only keeps a block that some shape fits exactly
/// (a flat stretch of a quantised log) from deciding the comparison by log 0.
pub const ERROR_FLOOR: f64 = 1e-6;

/// What the cross-validation's blocks are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum BlockKind {
    /// One block per training cycle.
    Cycles,
    /// Equal stretches of training samples in time (too few cycles).
    TimeStretches,
}

/// The cross-validation blocks: contiguous sample ranges of the training columns.
#[derive(Debug, Clone, PartialEq)]
pub struct Blocks {
    /// What the blocks are.
    pub kind: BlockKind,
    /// Each block's samples, as a range of the training columns (`Dataset::train`).
    pub ranges: Vec<Range<usize>>,
}

/// The training cycles of `ds` as blocks of its training columns (see the module docs).
pub fn training_blocks(ds: &Dataset) -> Blocks {
    let mut ranges: Vec<Range<usize>> = Vec::new();
    let mut last: Option<usize> = None;
    let mut k = 0usize;
    for (&c, &h) in ds.cycle.iter().zip(&ds.heldout) {
        if h {
            last = None;
            continue;
        }
        match (last, ranges.last_mut()) {
            (Some(l), Some(r)) if l == c => r.end = k + 1,
            _ => ranges.push(k..k + 1),
        }
        last = Some(c);
        k += 1;
    }
    if ranges.len() >= MIN_CYCLE_BLOCKS {
        return Blocks {
            kind: BlockKind::Cycles,
            ranges,
        };
    }
    Blocks {
        kind: BlockKind::TimeStretches,
        ranges: time_stretches(k, TIME_STRETCHES),
    }
}

/// `n` samples cut into `parts` contiguous stretches of (nearly) equal length.
pub fn time_stretches(n: usize, parts: usize) -> Vec<Range<usize>> {
    let parts = parts.min(n).max(1);
    (0..parts)
        .map(|b| b * n / parts..(b + 1) * n / parts)
        .filter(|r| !r.is_empty())
        .collect()
}

/// One shape's cross-validated error.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct CvScore {
    /// Highest power of v.
    pub n: usize,
    /// Highest power of v̇.
    pub m: usize,
    /// Parameters (n+1)(m+1).
    pub nu: usize,
    /// Pooled cross-validated mean squared error ē, kPa².
    pub mse: f64,
    /// Its standard error across blocks, kPa².
    pub se: f64,
    /// Every block's error is at most the training pressure's variance (module docs).
    pub admissible: bool,
    /// The typical block's error: the geometric mean over blocks of (e_b + floor), kPa²
    /// (module docs, step 3).
    pub typical_mse: f64,
    /// The floor added to each block's error, kPa² ([`ERROR_FLOOR`] × Var(P)).
    #[serde(skip)]
    pub floor: f64,
    /// Compared with other shapes on log ratios of block errors (cycle blocks); otherwise on the
    /// pooled difference (time stretches), and `typical_mse` is ē (module docs, step 5).
    #[serde(skip)]
    pub log_ratios: bool,
    /// Each block's SSE under the fold that left it out, kPa².
    #[serde(skip)]
    pub block_sse: Vec<f64>,
    /// Each block's samples.
    #[serde(skip)]
    pub block_n: Vec<usize>,
}

impl CvScore {
    /// √ē, kPa.
    pub fn rmse(&self) -> f64 {
        self.mse.sqrt()
    }

    /// The typical block's RMSE, kPa (√ of [`CvScore::typical_mse`]).
    pub fn typical_rmse(&self) -> f64 {
        self.typical_mse.sqrt()
    }
}

/// Cross-validated errors of every (n, m), 1 ≤ n ≤ max_n, 1 ≤ m ≤ max_m (row-major in n), on
/// `train` cut into `blocks`. A shape some fold cannot fit is an `Err` entry; data no shape can
/// use (no samples, non-finite values, fewer than two blocks) is the outer `Err`.
#[allow(clippy::type_complexity)]
pub fn cv_sweep(
    train: Xy,
    blocks: &[Range<usize>],
    scaling: &Scaling,
    max_n: usize,
    max_m: usize,
) -> Result<Vec<Result<CvScore, PolyError>>, PolyError> {
    if max_n > poly::MAX_DEGREE || max_m > poly::MAX_DEGREE {
        return Err(PolyError::Degree { n: max_n, m: max_m });
    }
    Ok(BlockMoments::new(train, blocks, scaling)?.sweep(max_n, max_m))
}

/// What every fold's fit and every block's error come from: each block's Chebyshev moments and
/// each fold's sum of the other folds' blocks (module docs, step 2).
pub struct BlockMoments {
    per_block: Vec<Moments>,
    fold_fits: Vec<Moments>,
    /// The sum over every block: the training data's moments.
    total: Moments,
    scaling: Scaling,
    centre: f64,
    var_p: f64,
    log_ratios: bool,
}

impl BlockMoments {
    /// One pass over `train` cut into `blocks`. `Err` on no samples, non-finite pressure or fewer
    /// than two blocks.
    pub fn new(
        train: Xy,
        blocks: &[Range<usize>],
        scaling: &Scaling,
    ) -> Result<BlockMoments, PolyError> {
        if train.p.is_empty() {
            return Err(PolyError::NoData);
        }
        if let Some(index) = train.p.iter().position(|x| !x.is_finite()) {
            return Err(PolyError::NotFinite {
                column: "pressure",
                index,
            });
        }
        if blocks.len() < 2 {
            return Err(PolyError::NoData);
        }
        let centre = train.p.iter().sum::<f64>() / train.p.len() as f64;
        let var_p =
            train.p.iter().map(|p| (p - centre).powi(2)).sum::<f64>() / train.p.len() as f64;
        let per_block = gather_blocks(train, scaling, centre, blocks);
        let folds = MAX_FOLDS.min(blocks.len());
        let fold_fits: Vec<Moments> = (0..folds)
            .map(|k| {
                let mut s = Moments::zero();
                for (b, mb) in per_block.iter().enumerate() {
                    if b % folds != k {
                        s.add(mb);
                    }
                }
                s
            })
            .collect();
        let mut total = Moments::zero();
        for b in &per_block {
            total.add(b);
        }
        Ok(BlockMoments {
            per_block,
            fold_fits,
            total,
            scaling: *scaling,
            centre,
            var_p,
            log_ratios: true,
        })
    }

    /// Compares shapes on the pooled difference instead of log ratios (time-stretch blocks,
    /// module docs, step 5).
    pub fn pooled(mut self) -> BlockMoments {
        self.log_ratios = false;
        self
    }

    /// Every (n, m) up to (`max_n`, `max_m`), row-major in n (see [`cv_sweep`]).
    pub fn sweep(&self, max_n: usize, max_m: usize) -> Vec<Result<CvScore, PolyError>> {
        crate::par::par_map(max_n * max_m, |k| {
            let (n, m) = (1 + k / max_m, 1 + k % max_m);
            score_shape(
                &self.per_block,
                &self.fold_fits,
                (n, m),
                self.var_p,
                self.log_ratios,
            )
        })
    }
}

impl BlockMoments {
    /// The raw terms of the (n, m) model reduced by the selection's own rule (module docs,
    /// "Terms"): backward elimination on the training fit, each step cross-validated, then the
    /// fewest terms within the band of the lowest error seen, the sweep's `scores` included.
    /// `Err` when the full shape cannot be fitted on some fold or no score of the sweep is finite.
    pub fn reduce_terms(
        &self,
        n: usize,
        m: usize,
        scores: &[CvScore],
    ) -> Result<Reduction, PolyError> {
        let reference = lowest(scores).ok_or(PolyError::NoData)?;
        let nu = (n + 1) * (m + 1);
        let folds: Vec<FoldMaps> =
            crate::par::par_map(self.fold_fits.len(), |f| self.fold_maps(f, n, m))
                .into_iter()
                .collect::<Result<_, _>>()?;
        let block_n: Vec<usize> = self.per_block.iter().map(|b| b.n).collect();
        let score = |dropped: &[usize]| -> Option<CvScore> {
            let mut block_sse = vec![0.0; self.per_block.len()];
            for f in &folds {
                for (b, e) in f.block_errors(dropped)? {
                    block_sse[b] = e;
                }
            }
            Some(cv_score(
                n,
                m,
                nu - dropped.len(),
                block_sse,
                block_n.clone(),
                self.var_p,
                self.log_ratios,
            ))
        };
        let full = score(&[]).ok_or(PolyError::Fit {
            n,
            m,
            source: crate::linreg::FitError::RankDeficient {
                term: poly::term_name(n, m),
            },
        })?;
        // Every step scored on its own (the order does not depend on the scores); the path ends
        // before the first step whose constraints are degenerate.
        let order = self.elimination_order(n, m)?;
        let steps = crate::par::par_map(order.len(), |k| score(&order[..=k]));
        let mut path = vec![(None, full)];
        path.extend(
            order
                .iter()
                .zip(steps)
                .map_while(|(&t, s)| Some((Some(t), s?))),
        );
        let mut lowest = reference;
        for (_, s) in &path {
            if s.admissible && s.typical_mse < lowest.typical_mse {
                lowest = s;
            }
        }
        let by_nu = |a: &CvScore, b: &CvScore| {
            a.nu.cmp(&b.nu)
                .then(a.typical_mse.total_cmp(&b.typical_mse))
        };
        let mut pick = path
            .iter()
            .enumerate()
            .filter(|(_, (_, s))| s.admissible && within_band(s, lowest))
            .min_by(|(_, a), (_, b)| by_nu(&a.1, &b.1))
            .map_or(0, |(k, _)| k);
        // More than MAX_PARAMS terms within the band: the best admissible step of at most
        // MAX_PARAMS terms instead, if there is one.
        let mut limited = false;
        if path[pick].1.nu > MAX_PARAMS {
            if let Some((k, _)) = path
                .iter()
                .enumerate()
                .filter(|(_, (_, s))| s.admissible && s.nu <= MAX_PARAMS)
                .min_by(|(_, a), (_, b)| a.1.typical_mse.total_cmp(&b.1.typical_mse))
            {
                pick = k;
                limited = true;
            }
        }
        let mut red = Reduction::of_path(n, m, &path, pick, lowest);
        red.limited = limited;
        Ok(red)
    }

    /// RMSE on `held` of the reduction `red` fitted on all the training blocks (restricted least
    /// squares on their summed moments, scored on `held`'s moments: no design matrix). `None`
    /// without held-out samples or when the constraints are degenerate.
    pub fn heldout_rmse(&self, red: &Reduction, held: Xy) -> Option<f64> {
        if held.p.is_empty() {
            return None;
        }
        let r =
            poly::Restricted::new(&self.total, red.n, red.m, &self.scaling, self.centre).ok()?;
        let dropped: Vec<usize> = (0..red.active.len()).filter(|&t| !red.active[t]).collect();
        let (c, _) = r.without(&dropped)?;
        let mh = Moments::gather(held, &self.scaling, self.centre);
        Some((mh.sse(red.n, red.m, &c) / mh.n as f64).sqrt())
    }

    /// The order in which backward elimination drops the raw terms of the (n, m) fit on all the
    /// training blocks (never the constant): at each step the term whose removal raises the
    /// training SSE least. The SSE without the terms S exceeds the full fit's by
    /// α̂_Sᵀ M_SS⁻¹ α̂_S = |L⁻¹α̂_S|² (M_SS = L Lᵀ, [`poly::ConstraintMaps`]), so a candidate t
    /// costs one triangular solve against the factor of the terms already dropped, which grows by
    /// one row per step. Stops early if the remaining constraints are degenerate.
    fn elimination_order(&self, n: usize, m: usize) -> Result<Vec<usize>, PolyError> {
        let maps =
            poly::Restricted::new(&self.total, n, m, &self.scaling, self.centre)?.constraint_maps();
        let nu = maps.alpha.len();
        // Jacobi scaling of M (and α̂ with it) keeps the factor's pivots comparable.
        let d: Vec<f64> = (0..nu)
            .map(|t| 1.0 / maps.m[(t, t)].max(f64::MIN_POSITIVE).sqrt())
            .collect();
        let ms = |a: usize, b: usize| maps.m[(a, b)] * d[a] * d[b];
        let mut order: Vec<usize> = Vec::new();
        // Rows of L (lower triangular, row k for order[k]) and y = L⁻¹ α̂_S.
        let mut l: Vec<Vec<f64>> = Vec::new();
        let mut y: Vec<f64> = Vec::new();
        while order.len() + 2 <= nu {
            let mut best: Option<(f64, usize, Vec<f64>, f64, f64)> = None;
            for t in (1..nu).filter(|t| !order.contains(t)) {
                // w = L⁻¹ M_S,t (forward substitution).
                let mut w = Vec::with_capacity(order.len());
                for (k, row) in l.iter().enumerate() {
                    let acc: f64 = (0..k).map(|j| row[j] * w[j]).sum();
                    w.push((ms(order[k], t) - acc) / row[k]);
                }
                let pivot = ms(t, t) - w.iter().map(|x| x * x).sum::<f64>();
                if pivot <= 1e-12 {
                    continue;
                }
                let diag = pivot.sqrt();
                let yt = (maps.alpha[t] * d[t] - w.iter().zip(&y).map(|(a, b)| a * b).sum::<f64>())
                    / diag;
                if best.as_ref().is_none_or(|b| yt * yt < b.0) {
                    best = Some((yt * yt, t, w, diag, yt));
                }
            }
            let Some((_, t, mut w, diag, yt)) = best else {
                break;
            };
            w.push(diag);
            l.push(w);
            y.push(yt);
            order.push(t);
        }
        Ok(order)
    }

    /// Fold `f`'s full (n, m) fit and, for each block it leaves out, what its error under a
    /// restricted fit needs (see [`FoldMaps::block_errors`]).
    fn fold_maps(&self, f: usize, n: usize, m: usize) -> Result<FoldMaps, PolyError> {
        let r = poly::Restricted::new(&self.fold_fits[f], n, m, &self.scaling, self.centre)?;
        let maps = r.constraint_maps();
        let folds = self.fold_fits.len();
        let blocks = (0..self.per_block.len())
            .filter(|b| b % folds == f)
            .map(|b| {
                let mb = &self.per_block[b];
                let g = mb.gram(n, m);
                let resid = mb.xty(n, m) - &g * &maps.c;
                HeldBlock {
                    index: b,
                    sse: mb.sse(n, m, &maps.c),
                    g: maps.q.transpose() * resid,
                    h: maps.q.transpose() * &g * &maps.q,
                }
            })
            .collect();
        Ok(FoldMaps {
            alpha: maps.alpha,
            m: maps.m,
            blocks,
        })
    }
}

/// One fold's full fit in the form restricted fits need ([`poly::ConstraintMaps`]).
struct FoldMaps {
    alpha: DVector<f64>,
    m: DMatrix<f64>,
    blocks: Vec<HeldBlock>,
}

/// A block the fold leaves out: its SSE under the full fit ĉ, g = Qᵀ(b − Gĉ) and H = QᵀGQ on its
/// own moments (G, b), so that the SSE of c = ĉ − Q_Sλ is sse + 2λᵀg_S + λᵀH_SSλ.
struct HeldBlock {
    index: usize,
    sse: f64,
    g: DVector<f64>,
    h: DMatrix<f64>,
}

impl FoldMaps {
    /// Each held-out block's SSE under the fold's fit without the raw terms `dropped`
    /// (α_S = 0: M_SS λ = α̂_S, solved Jacobi-scaled). `None` when the constraints are degenerate.
    fn block_errors(&self, dropped: &[usize]) -> Option<Vec<(usize, f64)>> {
        let k = dropped.len();
        let lambda = if k == 0 {
            DVector::zeros(0)
        } else {
            let d = DVector::from_fn(k, |i, _| {
                1.0 / self.m[(dropped[i], dropped[i])]
                    .max(f64::MIN_POSITIVE)
                    .sqrt()
            });
            let ms = DMatrix::from_fn(k, k, |i, j| self.m[(dropped[i], dropped[j])] * d[i] * d[j]);
            let rhs = DVector::from_fn(k, |i, _| self.alpha[dropped[i]] * d[i]);
            let mu = ms.cholesky()?.solve(&rhs);
            mu.component_mul(&d)
        };
        Some(
            self.blocks
                .iter()
                .map(|b| {
                    let lin: f64 = (0..k).map(|i| lambda[i] * b.g[dropped[i]]).sum();
                    let quad: f64 = (0..k)
                        .map(|i| {
                            lambda[i]
                                * (0..k)
                                    .map(|j| b.h[(dropped[i], dropped[j])] * lambda[j])
                                    .sum::<f64>()
                        })
                        .sum();
                    (b.index, (b.sse + 2.0 * lin + quad).max(0.0))
                })
                .collect(),
        )
    }
}

/// One step of the backward elimination of raw terms ([`BlockMoments::reduce_terms`]).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TermStep {
    /// The raw term dropped at this step (none for the full shape).
    pub dropped: Option<String>,
    /// Terms left.
    pub nu: usize,
    /// Cross-validated RMSE of the model with the terms left, kPa.
    pub cv_rmse: f64,
    /// Every block's error at most the training pressure's variance (module docs).
    pub admissible: bool,
}

/// The selected shape with the terms its data cannot use taken out (module docs, "Terms").
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Reduction {
    /// Highest power of v of the shape reduced.
    pub n: usize,
    /// Highest power of v̇.
    pub m: usize,
    /// Terms kept: the reduced model's parameters.
    pub nu: usize,
    /// Which raw terms αᵢⱼ are kept, at index i·(m+1)+j.
    pub active: Vec<bool>,
    /// The kept terms' names.
    pub kept: Vec<String>,
    /// The dropped terms' names, in the order they were dropped.
    pub dropped: Vec<String>,
    /// The reduced model's cross-validated RMSE (pooled over blocks), kPa.
    pub cv_rmse: f64,
    /// The reduced model's typical block RMSE, kPa.
    pub typical_rmse: f64,
    /// The lowest typical block RMSE of the sweep and the elimination, kPa.
    pub typical_lowest_rmse: f64,
    /// The reduced model's excess over the lowest ([`paired_excess`]: mean log ratio of block
    /// errors on cycle blocks, pooled difference in kPa² on time stretches).
    pub excess: f64,
    /// Its standard error across blocks.
    pub excess_se: f64,
    /// The fewest terms within the band were more than [`MAX_PARAMS`], and the best admissible
    /// step of at most [`MAX_PARAMS`] was taken instead.
    pub limited: bool,
    /// The reduced model refitted on the training cycles and scored on the held-out ones, kPa
    /// (filled by [`crate::identify`]).
    pub rmse_heldout: Option<f64>,
    /// Every step of the elimination, the full shape first.
    pub path: Vec<TermStep>,
}

impl Reduction {
    /// The reduction that keeps the terms left at step `pick` of the elimination `path`, scored
    /// against the lowest error seen, `lowest`.
    fn of_path(
        n: usize,
        m: usize,
        path: &[(Option<usize>, CvScore)],
        pick: usize,
        lowest: &CvScore,
    ) -> Reduction {
        let nu = (n + 1) * (m + 1);
        let (excess, excess_se) = paired_excess(&path[pick].1, lowest);
        let gone: Vec<usize> = path[1..=pick].iter().filter_map(|(t, _)| *t).collect();
        let name = |t: usize| poly::term_name(t / (m + 1), t % (m + 1));
        Reduction {
            n,
            m,
            nu: nu - gone.len(),
            active: (0..nu).map(|t| !gone.contains(&t)).collect(),
            kept: (0..nu).filter(|t| !gone.contains(t)).map(name).collect(),
            dropped: gone.iter().map(|&t| name(t)).collect(),
            cv_rmse: path[pick].1.rmse(),
            typical_rmse: path[pick].1.typical_rmse(),
            typical_lowest_rmse: lowest.typical_rmse(),
            excess,
            excess_se,
            limited: false,
            rmse_heldout: None,
            path: path
                .iter()
                .map(|(t, s)| TermStep {
                    dropped: t.map(name),
                    nu: s.nu,
                    cv_rmse: s.rmse(),
                    admissible: s.admissible,
                })
                .collect(),
        }
    }
}

/// Per-block moments, the blocks shared among the available cores for large data.
fn gather_blocks(train: Xy, sc: &Scaling, centre: f64, blocks: &[Range<usize>]) -> Vec<Moments> {
    let one = |r: &Range<usize>| Moments::gather_range(train, sc, centre, r.clone());
    if train.p.len() < 20_000 {
        return blocks.iter().map(one).collect();
    }
    crate::par::par_map(blocks.len(), |b| one(&blocks[b]))
}

/// One shape's pooled cross-validated MSE and its standard error across blocks.
fn score_shape(
    per_block: &[Moments],
    fold_fits: &[Moments],
    (n, m): (usize, usize),
    var_p: f64,
    log_ratios: bool,
) -> Result<CvScore, PolyError> {
    let folds = fold_fits.len();
    let coefs: Vec<_> = fold_fits
        .iter()
        .map(|f| poly::solve_chebyshev(f, n, m))
        .collect::<Result<_, _>>()?;
    let block_sse = per_block
        .iter()
        .enumerate()
        .map(|(b, mb)| mb.sse(n, m, &coefs[b % folds]))
        .collect();
    let block_n = per_block.iter().map(|mb| mb.n).collect();
    Ok(cv_score(
        n,
        m,
        (n + 1) * (m + 1),
        block_sse,
        block_n,
        var_p,
        log_ratios,
    ))
}

/// A [`CvScore`] of ν parameters from each block's SSE and samples: pooled ē, its standard
/// error, and admissibility (every block's error at most `var_p`, module docs).
pub(crate) fn cv_score(
    n: usize,
    m: usize,
    nu: usize,
    block_sse: Vec<f64>,
    block_n: Vec<usize>,
    var_p: f64,
    log_ratios: bool,
) -> CvScore {
    let errs: Vec<(f64, usize)> = block_sse
        .iter()
        .copied()
        .zip(block_n.iter().copied())
        .collect();
    let (mse, se) = pooled(&errs);
    let floor = ERROR_FLOOR * var_p.max(f64::MIN_POSITIVE);
    let logs: Vec<f64> = errs
        .iter()
        .filter(|e| e.1 > 0)
        .map(|&(e, nb)| (e / nb as f64 + floor).ln())
        .collect();
    let typical_mse = if log_ratios {
        (logs.iter().sum::<f64>() / logs.len().max(1) as f64).exp()
    } else {
        mse
    };
    CvScore {
        n,
        m,
        nu,
        mse,
        se,
        admissible: errs
            .iter()
            .all(|&(e, nb)| nb == 0 || e / nb as f64 <= var_p),
        typical_mse,
        floor,
        log_ratios,
        block_sse,
        block_n,
    }
}

/// Pooled ē = Σ SSE_b / Σ n_b over (SSE_b, n_b) and its standard error across blocks, kPa².
fn pooled(errs: &[(f64, usize)]) -> (f64, f64) {
    let sse: f64 = errs.iter().map(|e| e.0).sum();
    let total: usize = errs.iter().map(|e| e.1).sum();
    let mse = sse / total.max(1) as f64;
    let big_b = errs.len() as f64;
    let var: f64 = errs
        .iter()
        .filter(|(_, nb)| *nb > 0)
        .map(|&(e, nb)| {
            let w = nb as f64 / total as f64;
            (w * (e / nb as f64 - mse)).powi(2)
        })
        .sum::<f64>()
        * big_b
        / (big_b - 1.0);
    (mse, var.sqrt())
}

/// ē_a − ē_b and its standard error across the (common) blocks, kPa².
pub fn paired_difference(a: &CvScore, b: &CvScore) -> (f64, f64) {
    let total: usize = a.block_n.iter().sum();
    let d_bar = a.mse - b.mse;
    let blocks = a.block_n.len().min(b.block_sse.len());
    if blocks < 2 || total == 0 {
        return (d_bar, f64::INFINITY);
    }
    let ss: f64 = (0..blocks)
        .filter(|&k| a.block_n[k] > 0)
        .map(|k| {
            let nb = a.block_n[k] as f64;
            let d = (a.block_sse[k] - b.block_sse[k]) / nb;
            (nb / total as f64 * (d - d_bar)).powi(2)
        })
        .sum();
    (d_bar, (ss * blocks as f64 / (blocks - 1) as f64).sqrt())
}

/// The shapes the rule compares: the admissible ones with a finite ē, or every finite one if
/// none is admissible (module docs).
fn candidates(scores: &[CvScore]) -> Vec<&CvScore> {
    let finite: Vec<&CvScore> = scores.iter().filter(|s| s.mse.is_finite()).collect();
    if finite.iter().any(|s| s.admissible) {
        finite.into_iter().filter(|s| s.admissible).collect()
    } else {
        finite
    }
}

/// The mean over blocks of ln((e_a,b + floor) / (e_b,b + floor)), the log of the ratio of `a`'s
/// typical block error to `b`'s, and its standard error across the (common) blocks, each block
/// counted once (module docs, step 5). Infinite standard error with fewer than two blocks.
pub fn paired_log_ratio(a: &CvScore, b: &CvScore) -> (f64, f64) {
    let floor = a.floor.max(b.floor);
    let d: Vec<f64> = (0..a.block_n.len().min(b.block_n.len()))
        .filter(|&k| a.block_n[k] > 0 && a.block_n[k] == b.block_n[k])
        .map(|k| {
            let nb = a.block_n[k] as f64;
            ((a.block_sse[k] / nb + floor) / (b.block_sse[k] / nb + floor)).ln()
        })
        .collect();
    let k = d.len() as f64;
    let mean = d.iter().sum::<f64>() / k.max(1.0);
    if d.len() < 2 {
        return (mean, f64::INFINITY);
    }
    let var = d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (k - 1.0);
    (mean, (var / k).sqrt())
}

/// The candidate with the lowest typical block error (module docs, step 5; admissible shapes
/// first).
pub fn lowest(scores: &[CvScore]) -> Option<&CvScore> {
    candidates(scores)
        .into_iter()
        .min_by(|a, b| a.typical_mse.total_cmp(&b.typical_mse))
}

/// `a`'s excess over `b` and its paired standard error, on `a`'s scale (module docs, step 5):
/// the mean log ratio of block errors ([`paired_log_ratio`]) for cycle blocks, the pooled
/// difference ē_a − ē_b, kPa² ([`paired_difference`]) for time stretches.
pub fn paired_excess(a: &CvScore, b: &CvScore) -> (f64, f64) {
    if a.log_ratios {
        paired_log_ratio(a, b)
    } else {
        paired_difference(a, b)
    }
}

/// Whether `s` is within the rule's band (module docs, step 5) of `best`, the lowest typical
/// error: its excess over `best` at most one paired standard error, and its typical RMSE at most
/// [`MAX_RMSE_RATIO`] × best's.
fn within_band(s: &CvScore, best: &CvScore) -> bool {
    let (d, se) = paired_excess(s, best);
    d <= se && s.typical_mse <= MAX_RMSE_RATIO * MAX_RMSE_RATIO * best.typical_mse
}

/// The rule's choice among `scores`: the fewest parameters within the band of the lowest typical
/// error (module docs, step 5; equal ν: the lower typical error). `None` when no score is finite.
pub fn one_se_rule(scores: &[CvScore]) -> Option<CvScore> {
    let best = lowest(scores)?;
    candidates(scores)
        .into_iter()
        .filter(|s| within_band(s, best))
        .min_by(|a, b| {
            a.nu.cmp(&b.nu)
                .then(a.typical_mse.total_cmp(&b.typical_mse))
        })
        .cloned()
}

/// A shape (n, m) with its parameter count.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Shape {
    /// Highest power of v.
    pub n: usize,
    /// Highest power of v̇.
    pub m: usize,
    /// Parameters (n+1)(m+1).
    pub nu: usize,
}

impl Shape {
    /// The shape (n, m).
    pub fn new(n: usize, m: usize) -> Shape {
        Shape {
            n,
            m,
            nu: (n + 1) * (m + 1),
        }
    }
}

/// The polynomial's selection, with the other criteria's picks beside it.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Selection {
    /// The rule that chose `selected`, in words.
    pub rule: String,
    /// The chosen shape (one-standard-error rule on cycle-blocked cross-validation).
    pub selected: Shape,
    /// The shape with the lowest typical block error.
    pub cv_best: Shape,
    /// Its typical block RMSE, kPa.
    pub typical_best_rmse: f64,
    /// Its cross-validated RMSE (pooled over blocks), kPa.
    pub cv_best_rmse: f64,
    /// The selected shape's typical block RMSE, kPa.
    pub typical_rmse: f64,
    /// The selected shape's cross-validated RMSE (pooled over blocks), kPa.
    pub cv_rmse: f64,
    /// The selected shape's excess over the best ([`paired_excess`]: mean log ratio of block
    /// errors on cycle blocks, pooled difference in kPa² on time stretches; module docs, step 5).
    pub excess: f64,
    /// Its standard error across blocks: the rule admits an excess up to this.
    pub excess_se: f64,
    /// The pooled rule's numbers (before issue 35), for comparison: ē_selected − ē_best, kPa²,
    /// and its standard error paired across blocks weighted by their samples, kPa².
    pub pooled_excess: (f64, f64),
    /// The lowest pooled cross-validated RMSE of the sweep, kPa, and its shape.
    pub pooled_best: (f64, Shape),
    /// The textbook rule's limit √(ē_best + SE_best), kPa (SE of the pooled best's ē alone; not
    /// used).
    pub cv_limit_rmse: f64,
    /// The shape with the lowest training AICc.
    pub aicc_pick: Option<Shape>,
    /// The shape with the lowest joint cost J (eq. (8) here) under `weights`.
    pub joint_cost_pick: Option<Shape>,
    /// The selected shape's raw terms reduced by the same rule (module docs, "Terms"): the
    /// model `vfp export` exports by default.
    pub reduced: Option<Reduction>,
    /// The joint cost's weights.
    pub weights: CostWeights,
    /// What the blocks are.
    pub blocks: BlockKind,
    /// Number of blocks.
    pub n_blocks: usize,
    /// Number of folds.
    pub folds: usize,
}

/// Runs the cross-validation on `ds`'s training cycles and applies the one-SE rule. `scaling` is
/// the one every fit of `ds` uses (from all its samples). `Err` when no shape could be scored.
pub fn cross_validate(
    ds: &Dataset,
    scaling: &Scaling,
    max_n: usize,
    max_m: usize,
) -> Result<(Blocks, Vec<Result<CvScore, PolyError>>), PolyError> {
    if max_n > poly::MAX_DEGREE || max_m > poly::MAX_DEGREE {
        return Err(PolyError::Degree { n: max_n, m: max_m });
    }
    let (blocks, bm) = block_moments(ds, scaling)?;
    Ok((blocks, bm.sweep(max_n, max_m)))
}

/// The blocks of `ds`'s training cycles and their moments, for [`BlockMoments::sweep`] and
/// [`BlockMoments::reduce_terms`].
pub fn block_moments(ds: &Dataset, scaling: &Scaling) -> Result<(Blocks, BlockMoments), PolyError> {
    let train = ds.train();
    let blocks = training_blocks(ds);
    let bm = BlockMoments::new(Xy::from(&train), &blocks.ranges, scaling)?;
    let bm = match blocks.kind {
        BlockKind::Cycles => bm,
        BlockKind::TimeStretches => bm.pooled(),
    };
    Ok((blocks, bm))
}

/// The [`Selection`] from cross-validated `scores` and the training metrics' picks.
pub fn selection(
    blocks: &Blocks,
    scores: &[CvScore],
    aicc_pick: Option<Shape>,
    joint_cost_pick: Option<Shape>,
    weights: CostWeights,
) -> Option<Selection> {
    let chosen = one_se_rule(scores)?;
    let best = lowest(scores)?;
    let pooled_best = candidates(scores)
        .into_iter()
        .min_by(|a, b| a.mse.total_cmp(&b.mse))?;
    let (excess, excess_se) = paired_excess(&chosen, best);
    Some(Selection {
        rule: format!(
            "fewest parameters whose block errors exceed the lowest typical error's by at most one \
             standard error of their log ratio, paired block by block, and whose typical RMSE is \
             at most {MAX_RMSE_RATIO} times the lowest; training cycles as blocks, held-out \
             cycles not used"
        ),
        selected: Shape::new(chosen.n, chosen.m),
        cv_best: Shape::new(best.n, best.m),
        typical_best_rmse: best.typical_rmse(),
        cv_best_rmse: best.rmse(),
        typical_rmse: chosen.typical_rmse(),
        cv_rmse: chosen.rmse(),
        excess,
        excess_se,
        pooled_excess: paired_difference(&chosen, pooled_best),
        pooled_best: (pooled_best.rmse(), Shape::new(pooled_best.n, pooled_best.m)),
        cv_limit_rmse: (pooled_best.mse + pooled_best.se).sqrt(),
        aicc_pick,
        joint_cost_pick,
        reduced: None,
        weights,
        blocks: blocks.kind,
        n_blocks: blocks.ranges.len(),
        folds: MAX_FOLDS.min(blocks.ranges.len()),
    })
}

/// The polynomial shape `vfp export` exports and `vfp diagnose` starts from by default: the
/// one-SE choice on `ds` (see the module docs). `None` when no shape can be fitted.
pub fn poly_shape(ds: &Dataset) -> Option<(usize, usize)> {
    poly_shape_scores(ds).map(|(shape, _, _)| shape)
}

/// [`poly_shape`] with the blocks and every shape's score it chose from.
pub fn poly_shape_scores(ds: &Dataset) -> Option<((usize, usize), Blocks, Vec<CvScore>)> {
    let sc = Scaling::from_data(&ds.v, &ds.vdot).ok()?;
    let (blocks, scores) = cross_validate(ds, &sc, poly::MAX_DEGREE, poly::MAX_DEGREE).ok()?;
    let ok: Vec<CvScore> = scores.into_iter().flatten().collect();
    let s = one_se_rule(&ok)?;
    Some(((s.n, s.m), blocks, ok))
}

/// Shapes in the order a default export tries them: the one-SE choice, then the other candidates
/// (module docs) within one SE by ν (then ē), then the rest by ē, admissible shapes first.
pub fn ranked(scores: &[CvScore]) -> Vec<CvScore> {
    let Some(best) = lowest(scores) else {
        return Vec::new();
    };
    let cand = candidates(scores);
    let (mut within, mut rest): (Vec<CvScore>, Vec<CvScore>) = scores
        .iter()
        .cloned()
        .partition(|s| cand.contains(&s) && within_band(s, best));
    within.sort_by(|a, b| {
        a.nu.cmp(&b.nu)
            .then(a.typical_mse.total_cmp(&b.typical_mse))
    });
    rest.sort_by(|a, b| {
        (!a.admissible)
            .cmp(&!b.admissible)
            .then(a.typical_mse.total_cmp(&b.typical_mse))
    });
    within.extend(rest);
    within
}
