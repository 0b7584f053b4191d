//! The loop's search for effects (step 4): each candidate's search, the re-tune's descent and the
//! tests that keep an effect; the rounds of forward selection that call them are
//! `super::forward`. (`crate::select` is the baseline polynomial's shape; this module searches
//! effects.)
//!
//! Each round, every candidate not yet in the model has its nonlinear parameter θ searched on the
//! *training* rows (a log grid of 8 points, or 5 magnitudes of each sign, over a range set by the data's own
//! scales, then Brent's refinement between the best point's neighbours ([`brent`]); ripple starts from
//! the peaks of the residual's Welch spectrum), all linear coefficients refitted jointly by QR.
//! Behind a lag inside the frames, a candidate that moves the inputs is located on the model with
//! that lag taken between samples (a stand-in several times cheaper per trial) and polished on
//! the model itself (`Trials::polish`); every fit that is judged is on the model itself.
//! Candidates are ranked by held-out RMSE, and the best one is kept only if **both**
//!
//! 1. a nested F-test on the training rows rejects "no effect" at level α, with
//!    `F = [(SSE₀ − SSE₁)/q] / [SSE₁/(N − p₁)] · N_eff/N`, `q` = added linear coefficients + 1 per
//!    searched parameter, compared with `F(q, N_eff − p₁)`, where `N_eff = N(1 − ρ₁)/(1 + ρ₁)` and
//!    ρ₁ is the lag-1 autocorrelation of the augmented model's training residual. At 25 Hz a misfit
//!    leaves strongly correlated residuals; the naive F-test (N_eff = N) would then call almost any
//!    smooth regressor significant;
//! 2. held-out RMSE falls by at least `min_gain` (relative).
//!
//! If the best-ranked candidate fails, the next is tried; the loop ends when none passes. After an
//! effect is accepted, the parameters θ of the effects already in the model are re-tuned, since
//! each was found while the other effects were still missing: coordinate descent (Brent's method
//! in a bracket around each value) with Hooke and Jeeves' pattern move after each sweep, until a
//! sweep gains less than [`RETUNE_TOL`] ([`retune`]). Two effects that trade against each other
//! (an air pocket's lag and a sensor lag) walk their valley together; with one pass of brackets,
//! three effects at once on host-sim ended at 4.6 σ, with this at 1.6 σ.
//!
//! **Physical admissibility.** A candidate is kept only if every effect of the augmented model is
//! physically possible ([`unphysical`]): searched parameters are positive by construction (lags,
//! delays, widths, air volume, leak conductance, play), and the fitted linear parts are checked —
//! inertance `L ≥ 0` (the water column's mass), hysteresis gap `inflation − deflation ≥ 0` over the
//! whole volume range (a loop that returns energy is not friction). An inadmissible candidate is
//! not added however much it helps; the loop reports it with the structure it would have absorbed.
//!
//! Uncertainties: linear coefficients `σ̂²(XᵀX)⁻¹·N/N_eff`; a searched parameter from the curvature
//! of the profile SSE, `var θ = 2σ̂²/SSE''(θ)·N/N_eff` (Gaussian profile likelihood). The 95 %
//! intervals come from the joint cluster-robust covariance of the final model
//! ([`super::interval`]).

use std::sync::Arc;

use serde::Serialize;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::analysis::{self, lag1, n_eff};
use super::basis::PolyBasis;
use super::effects::{build, Design, Effect, EffectKind, Fitted, ModelView, Prepared, Search};
use super::lsq::{self, LsFit};

/// One fitted model: effects, design, coefficients and errors.
#[derive(Clone, Debug)]
pub struct Stage {
    /// Effects in the order added.
    pub effects: Vec<Effect>,
    /// Its regressors' labels and owners; the columns themselves are not kept (`cols` is empty:
    /// a round holds a stage per candidate, and the columns over every sample would make memory
    /// grow with candidates × columns × samples). [`Stage::columns`] rebuilds them.
    pub design: Design,
    /// Its least-squares fit on the training rows.
    pub fit: LsFit,
    /// Prediction over every sample.
    pub pred: Vec<f64>,
    /// Measured − predicted over every sample.
    pub resid: Vec<f64>,
    /// RMSE on training rows.
    pub rmse_train: f64,
    /// RMSE on held-out rows.
    pub rmse_heldout: f64,
}

impl Stage {
    /// Parameters: coefficients plus one per searched nonlinear parameter (a pump ripple's count
    /// lags included).
    pub fn n_params(&self) -> usize {
        self.fit.beta.len()
            + self
                .effects
                .iter()
                .map(|e| usize::from(e.kind.has_nonlinear()) + e.count_lag.lags.len())
                .sum::<usize>()
    }

    /// The design's columns over every sample, rebuilt ([`build`] is deterministic, so they are
    /// the columns the stage was fitted on).
    pub fn columns(&self, prep: &Prepared) -> Design {
        build(prep, &self.effects)
    }

    /// The design columns of effect `idx`, in order.
    pub fn owned_columns(&self, idx: usize) -> Vec<usize> {
        self.view().owned_columns(idx)
    }

    /// The model as an effect sees it: its effects and the numbers of its fit.
    pub fn view(&self) -> ModelView<'_> {
        ModelView {
            effects: &self.effects,
            beta: &self.fit.beta,
            owner: &self.design.owner,
            sse: self.fit.sse,
        }
    }
}

fn rms(x: &[f64], rows: &[usize]) -> f64 {
    (rows.iter().map(|&r| x[r] * x[r]).sum::<f64>() / rows.len().max(1) as f64).sqrt()
}

/// Fits the baseline augmented with `effects`; `None` if the design is rank-deficient.
pub fn fit_stage(prep: &Prepared, effects: &[Effect]) -> Option<Stage> {
    let mut design = build(prep, effects);
    let fit = lsq::fit(&design.cols, &prep.series.p, &prep.train_rows)?;
    let pred = lsq::predict(&design.cols, &fit.beta);
    design.release();
    let resid: Vec<f64> = prep
        .series
        .p
        .iter()
        .zip(&pred)
        .map(|(p, q)| p - q)
        .collect();
    if resid.iter().any(|r| !r.is_finite()) {
        return None;
    }
    let rmse_train = rms(&resid, &prep.train_rows);
    let rmse_heldout = rms(&resid, &prep.held_rows);
    Some(Stage {
        effects: effects.to_vec(),
        design,
        fit,
        pred,
        resid,
        rmse_train,
        rmse_heldout,
    })
}

/// Training SSE of the baseline augmented with `effects` (by moments where no output filter
/// forbids it, [`super::effects::sse_structured`]; with one lag between samples, streamed into
/// the Gram sum, [`super::effects::design::sse_lagged`]).
pub(crate) fn sse_of(prep: &Prepared, effects: &[Effect]) -> f64 {
    if let Some(sse) = super::effects::sse_structured(prep, effects) {
        return sse;
    }
    if let Some(sse) = super::effects::design::sse_lagged(prep, effects) {
        return sse;
    }
    let design = build(prep, effects);
    lsq::sse_fast(&design.cols, &prep.series.p, &prep.train_rows)
}

/// Minimises `f` on [a, b] (unimodal within the bracket) by Brent's method (argmin's
/// `BrentOpt`: parabolic steps through the three best points, golden-section steps where those
/// fail), to the precision `iters` golden-section steps would reach (a bracket shrunk to
/// `0.618^(iters+1)` of its width) and with at most as many evaluations (`iters + 2`); on a
/// smooth minimum it needs about half of them. Returns the best point evaluated and its value.
pub(crate) fn brent(a: f64, b: f64, iters: usize, f: impl FnMut(f64) -> f64) -> (f64, f64) {
    use argmin::core::{CostFunction, Error, Executor};
    use argmin::solver::brent::BrentOpt;
    use std::cell::{Cell, RefCell};

    /// The objective, and the best point it has seen (what is returned, whatever the solver's
    /// state: a non-finite value never wins).
    struct Objective<'a, F> {
        f: &'a RefCell<F>,
        best: &'a Cell<(f64, f64)>,
    }
    impl<F: FnMut(f64) -> f64> CostFunction for Objective<'_, F> {
        type Param = f64;
        type Output = f64;
        fn cost(&self, x: &f64) -> Result<f64, Error> {
            let y = (self.f.borrow_mut())(*x);
            if y < self.best.get().1 {
                self.best.set((*x, y));
            }
            Ok(if y.is_nan() { f64::INFINITY } else { y })
        }
    }
    let (a, b) = if a <= b { (a, b) } else { (b, a) };
    let f = RefCell::new(f);
    let best = Cell::new((0.5 * (a + b), f64::INFINITY));
    let golden = 0.5 * (5f64.sqrt() - 1.0);
    let precision = (b - a) * golden.powi(iters as i32 + 1);
    if precision > 0.0 {
        let solver = BrentOpt::new(a, b).set_tolerance(f64::EPSILON.sqrt(), 0.25 * precision);
        // Whatever ends the run (convergence, the iteration cap, an error), the best point seen
        // is the answer; the solver's first evaluation is outside its iterations.
        let _ = Executor::new(Objective { f: &f, best: &best }, solver)
            .configure(|state| state.max_iters(iters as u64 + 1))
            .run();
    }
    match best.get() {
        (x, y) if y < f64::INFINITY => (x, y),
        (mid, _) => (mid, (f.borrow_mut())(mid)),
    }
}

/// Stiffness `k = ∂P/∂v` of a stage's baseline part on the raw inputs, per sample.
fn stiffness_of(prep: &Prepared, stage: &Stage) -> Arc<Vec<f64>> {
    baseline_derivative(prep, stage, PolyBasis::stiffness)
}

/// Damping `c = ∂P/∂v̇` of a stage's baseline part on the raw inputs, per sample.
fn damping_of(prep: &Prepared, stage: &Stage) -> Arc<Vec<f64>> {
    baseline_derivative(prep, stage, PolyBasis::damping)
}

/// A partial derivative (`PolyBasis::stiffness` or `damping`) of a stage's baseline part on the
/// raw inputs, per sample.
fn baseline_derivative(
    prep: &Prepared,
    stage: &Stage,
    d: fn(&PolyBasis, &[f64], f64, f64) -> f64,
) -> Arc<Vec<f64>> {
    basis_derivative(prep, &stage.fit.beta[..prep.basis.len()], d)
}

/// A partial derivative (`PolyBasis::stiffness` or `damping`) of the polynomial with basis
/// coefficients `poly` on `prep`'s raw inputs, per sample.
pub(super) fn basis_derivative(
    prep: &Prepared,
    poly: &[f64],
    d: fn(&PolyBasis, &[f64], f64, f64) -> f64,
) -> Arc<Vec<f64>> {
    let s = &prep.series;
    Arc::new(
        (0..s.len())
            .map(|k| d(&prep.basis, poly, s.v[k], s.vdot[k]))
            .collect(),
    )
}

/// Coordinate for the search: log for positive parameters, identity for signed ones.
#[derive(Clone, Copy)]
enum Coord {
    Log,
    Lin,
}

impl Coord {
    /// The coordinate search walks re-tuning: none for parameters searched another way.
    fn of_search(search: Search) -> Option<Coord> {
        match search {
            Search::Log(..) => Some(Coord::Log),
            Search::Signed(..) | Search::Spectral => Some(Coord::Lin),
            Search::VolumeSpectral | Search::Degree(_) | Search::None => None,
        }
    }

    /// The coordinate u of a parameter value θ (the inverse of [`Coord::to`]).
    fn from(self, theta: f64) -> f64 {
        match self {
            Coord::Log => theta.ln(),
            Coord::Lin => theta,
        }
    }

    /// The parameter value θ at coordinate u.
    fn to(self, u: f64) -> f64 {
        match self {
            Coord::Log => u.exp(),
            Coord::Lin => u,
        }
    }
}

/// Result of searching one candidate.
#[derive(Clone, Debug)]
pub struct Candidate {
    /// The candidate.
    pub kind: EffectKind,
    /// The augmented model with the candidate last.
    pub stage: Stage,
    /// Where its parameter was located on a stand-in and is still to be polished on the model
    /// itself ([`refined`]).
    pub unpolished: Option<Unpolished>,
}

/// The bracket of a [`Trials::polish`] not yet made: the grid step (in `ln θ`) and the search's
/// range of magnitudes.
#[derive(Clone, Copy, Debug)]
pub struct Unpolished {
    step: f64,
    lo: f64,
    hi: f64,
}

/// `base` with `e` appended.
pub(crate) fn with(base: &[Effect], e: Effect) -> Vec<Effect> {
    let mut v = base.to_vec();
    v.push(e);
    v
}

/// Searches the nonlinear parameter of `kind` added to `cur`, returning the best augmented model
/// (after the effect's own [`super::effects::EffectModel::refine`], [`refined`]).
pub fn search(prep: &Prepared, cur: &Stage, kind: EffectKind) -> Option<Candidate> {
    search_from(prep, cur, kind, None).map(|c| refined(prep, cur, c))
}

/// Searches made in the kept effects' places, by the model searched on (its effects) and the
/// kind: a look-alike swap ([`super::swaps`]) searches each look-alike on the model without the
/// effect it may replace, and the alternatives ([`super::alternatives`]) search each close lead
/// of a kept effect on the final model without it: the same searches, where no swap was made in
/// between. On a random rig of the loop benchmark (an offset drift, a delivery lag and a
/// hysteresis kept) seven searches, 2.0 s, were made twice.
#[derive(Default)]
pub(crate) struct Searched(std::sync::Mutex<Vec<Made>>);

/// A search [`Searched`] keeps: the effects of the model searched on, the kind, its result.
type Made = (Vec<Effect>, EffectKind, Option<Candidate>);

impl Searched {
    /// [`search`] of `kind` on `cur`, or its result where it was made before on the same effects
    /// ([`same_model`]).
    pub(crate) fn search(
        &self,
        prep: &Prepared,
        cur: &Stage,
        kind: EffectKind,
    ) -> Option<Candidate> {
        let made = |list: &[Made]| {
            list.iter()
                .find(|(e, k, _)| *k == kind && same_model(e, &cur.effects))
                .map(|(_, _, c)| c.clone())
        };
        if let Some(c) = self.0.lock().ok().and_then(|l| made(&l)) {
            return c;
        }
        let found = search(prep, cur, kind);
        if let Ok(mut l) = self.0.lock() {
            l.push((cur.effects.clone(), kind, found.clone()));
        }
        found
    }
}

/// Whether two effects are the same at the same parameters (kind, parameter to the bit, sampling
/// form, ripple offset and the leak's form).
pub(crate) fn same_effect(a: &Effect, b: &Effect) -> bool {
    a.kind == b.kind
        && a.theta.to_bits() == b.theta.to_bits()
        && a.point_sampled == b.point_sampled
        && a.ripple_offset == b.ripple_offset
        && a.one_way == b.one_way
}

/// [`same_effect`] for each of two lists of effects, in order.
pub(crate) fn same_effects(a: &[Effect], b: &[Effect]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| same_effect(x, y))
}

/// [`same_effects`], and each effect's data taken from the model it was added to (an air
/// pocket's damping) the very same: what a model searched on is made of, so that a search made
/// on one is a search made on the other.
fn same_model(a: &[Effect], b: &[Effect]) -> bool {
    let same_data = |x: &Option<Arc<Vec<f64>>>, y: &Option<Arc<Vec<f64>>>| match (x, y) {
        (None, None) => true,
        (Some(x), Some(y)) => Arc::ptr_eq(x, y),
        _ => false,
    };
    same_effects(a, b)
        && a.iter().zip(b).all(|(x, y)| {
            same_data(&x.damping, &y.damping) && same_data(&x.stiffness, &y.stiffness)
        })
}

/// A searched candidate on `cur` after its effect's own refinement
/// ([`super::effects::EffectModel::refine`]; most effects have none), its parameter first
/// polished on the model itself where the search located it on a stand-in ([`located_on`],
/// [`Trials::polish`]). A round refines only the candidates that can matter
/// (`forward::search_all`): a refinement corrects a fit, it does not make one. The polish moves a
/// parameter by at most a quarter of a grid step, which cannot lift a candidate that wins back a
/// small share of another's gain to lead the round; behind an air pocket's lag each costs up to
/// six rebuilds of the whole design at the frames' instants.
pub fn refined(prep: &Prepared, cur: &Stage, cand: Candidate) -> Candidate {
    let stage = match cand.unpolished {
        Some(u) => polished(prep, cur, cand.kind, cand.stage, u),
        None => cand.stage,
    };
    Candidate {
        kind: cand.kind,
        stage: refine_stage(prep, &cur.effects, cand.kind, stage),
        unpolished: None,
    }
}

/// `stage`, the search's fit of `kind` on `cur` located on a stand-in, with its parameter
/// polished on the model itself ([`Trials::polish`]) and fitted there.
fn polished(prep: &Prepared, cur: &Stage, kind: EffectKind, stage: Stage, u: Unpolished) -> Stage {
    let Some(found) = stage.effects.last() else {
        return stage;
    };
    let trials = Trials::new(prep, cur, kind);
    trials.point.set(found.point_sampled);
    let theta = trials.polish(found.theta, u.step, u.lo, u.hi);
    if theta == found.theta {
        return stage;
    }
    trials.fit(theta).unwrap_or(stage)
}

/// [`search`], started where the same candidate's search ended on the model before (`hint`, its
/// θ, from the previous round), where the candidate's SSE has one minimum in θ
/// ([`super::effects::EffectModel::one_minimum`]: a lag, a delay, a rate; not a width): its
/// parameter is sought by descent along its grid from the grid point nearest `hint`
/// ([`grid_descent`]), which walks on where the minimum lies beyond, instead of over the whole
/// grid. A model one effect larger moves such a minimum little; where it moved far, the walk
/// follows it a grid step at a time. The search's best fit, not yet refined nor, where it was
/// located on a stand-in, polished ([`refined`]).
pub fn search_from(
    prep: &Prepared,
    cur: &Stage,
    kind: EffectKind,
    hint: Option<f64>,
) -> Option<Candidate> {
    let mut trials = Trials::new(prep, cur, kind);
    trials.hint = hint.filter(|h| h.is_finite() && kind.one_minimum());
    trials.defer_polish = true;
    let found = trials.best_theta()?;
    let stage = match found.prefit.or_else(|| trials.fit(found.theta)) {
        Some(stage) => stage,
        // The searches' SSE tolerates a rank-deficient design, the reported QR fit does not
        // (e.g. a lag so long that the lagged flow is nearly constant): take the best grid point
        // the QR accepts, so the candidate is still tested and reported.
        None => trials.best_grid_fit()?,
    };
    Some(Candidate {
        kind,
        stage,
        unpolished: trials.deferred.get(),
    })
}

/// [`refined`]: `stage`, the fit the search found with its effect (of `kind`) last after `base`,
/// with that effect as it refines itself ([`super::effects::EffectModel::refine`]): the model
/// refitted with the refined effect where that lowers the training SSE, else as found; then the
/// effect completed with the parameters it has that its fit does not move
/// ([`super::effects::EffectModel::complete`]).
fn refine_stage(prep: &Prepared, base: &[Effect], kind: EffectKind, stage: Stage) -> Stage {
    let Some(found) = stage.effects.last() else {
        return stage;
    };
    let mut stage = match kind.refine(prep, base, found, &stage.view()) {
        Some(e) => match fit_stage(prep, &with(base, e)) {
            Some(better) if better.fit.sse < stage.fit.sse => better,
            _ => stage,
        },
        None => stage,
    };
    if let Some(e) = stage.effects.last_mut() {
        kind.complete(prep, e);
    }
    stage
}

/// The trials of one candidate on top of the current model: the effect at each θ with the data
/// its search attaches ([`super::effects::Needs`]), and the training SSE it leaves.
struct Trials<'a> {
    prep: &'a Prepared,
    cur: &'a Stage,
    kind: EffectKind,
    damping: Option<Arc<Vec<f64>>>,
    stiffness: Option<Arc<Vec<f64>>>,
    /// Whether the samples are taken as instants rather than frame means (tried both ways where
    /// the effect asks, [`super::effects::EffectModel::tries_point_sampled`]).
    point: std::cell::Cell<bool>,
    /// The current model's design through its output filters, made at the first trial that can
    /// use it ([`super::effects::design::sse_adding_columns`]).
    base: std::cell::OnceCell<Option<super::effects::design::FilteredBase>>,
    /// Where the search locates θ on a stand-in for the current model ([`located_on`]): its
    /// lags inside the frames taken on instants.
    proxy: Option<Vec<Effect>>,
    /// Where the previous round's search of the candidate ended ([`search_from`]).
    hint: Option<f64>,
    /// Whether [`Trials::polish`] is left to [`refined`] (`deferred` then records its bracket).
    defer_polish: bool,
    deferred: std::cell::Cell<Option<Unpolished>>,
}

/// The current model's effects with its output lags inside the frames taken on instants, on
/// which a candidate that moves the inputs (a transport delay, backlash, a delivery lag, a leak,
/// a volume drift) is located; `None` where the candidate is located on the model itself.
///
/// Such a candidate changes every baseline column, so each trial rebuilds the whole design, and
/// behind a lag inside the frames that means the columns at eight instants per frame, each run
/// through the lag: about three times the cost of the same lag between samples, streamed into
/// the Gram sum ([`super::effects::design::sse_lagged`]). The two forms of the lag differ only
/// within a frame, and what the candidate's parameter fits (a delay, a dead band, a drift) does
/// not: its minimum lies where it lies behind the exact form, to within the search's precision.
/// Only where θ is searched: every fit that is judged (the candidate's model, its held-out error,
/// its test, the forms compared) is on the model as it is; a kept effect is re-tuned there.
fn located_on(
    prep: &Prepared,
    cur: &Stage,
    kind: EffectKind,
    trial: &Effect,
) -> Option<Vec<Effect>> {
    let moves_inputs = kind.filter_stage().is_none()
        && kind.transforms_inputs(trial)
        && !kind.uses_measured_pressure();
    if !moves_inputs {
        return None;
    }
    stand_in(prep, &cur.effects)
}

/// `effects` with every output lag inside the frames taken on instants ([`located_on`]); `None`
/// where there is none (the stand-in would be the model itself).
pub(crate) fn stand_in(prep: &Prepared, effects: &[Effect]) -> Option<Vec<Effect>> {
    let in_frames = |e: &Effect| {
        e.kind.filter_stage().is_some()
            && e.kind.lag_time_constants(e, prep).is_some()
            && !e.point_sampled
    };
    if !effects.iter().any(in_frames) {
        return None;
    }
    Some(
        effects
            .iter()
            .map(|e| Effect {
                point_sampled: e.point_sampled || in_frames(e),
                ..e.clone()
            })
            .collect(),
    )
}

/// A searched parameter, with the model fitted at it when the search already made that fit.
struct Found {
    theta: f64,
    prefit: Option<Stage>,
}

impl<'a> Trials<'a> {
    fn new(prep: &'a Prepared, cur: &'a Stage, kind: EffectKind) -> Self {
        let needs = kind.needs();
        Self {
            prep,
            cur,
            kind,
            damping: needs.damping.then(|| damping_of(prep, cur)),
            stiffness: needs.stiffness.then(|| stiffness_of(prep, cur)),
            point: std::cell::Cell::new(false),
            base: std::cell::OnceCell::new(),
            proxy: located_on(prep, cur, kind, &Effect::new(kind, 0.0)),
            hint: None,
            defer_polish: false,
            deferred: std::cell::Cell::new(None),
        }
    }

    /// The effect at `theta`.
    fn make(&self, theta: f64) -> Effect {
        Effect {
            damping: self.damping.clone(),
            stiffness: self.stiffness.clone(),
            point_sampled: self.point.get(),
            ..Effect::new(self.kind, theta)
        }
    }

    /// Training SSE of the current model with the effect at `theta` added.
    fn objective(&self, theta: f64) -> f64 {
        if let Some(proxy) = &self.proxy {
            return sse_of(self.prep, &with(proxy, self.make(theta)));
        }
        self.exact(theta)
    }

    /// Training SSE of the current model itself (not a stand-in) with the effect at `theta`.
    fn exact(&self, theta: f64) -> f64 {
        let effects = with(&self.cur.effects, self.make(theta));
        // Behind the model's output filters, a candidate that only adds columns has only its own
        // columns filtered at each trial, the model's filtered once per search. Whether it moves
        // the inputs is the effect's own answer: a pump ripple is searched by its columns alone
        // (its input transform is applied only once they have been fitted, in its refinement).
        let base = self.base.get_or_init(|| {
            let k = self.kind;
            let adds_only = k.filter_stage().is_none()
                && !k.transforms_inputs(&self.make(theta))
                && !k.uses_measured_pressure();
            adds_only
                .then(|| super::effects::design::filtered_base(self.prep, &self.cur.effects))
                .flatten()
        });
        if let Some(sse) = base
            .as_ref()
            .and_then(|b| super::effects::design::sse_adding_columns(self.prep, b, &effects))
        {
            return sse;
        }
        sse_of(self.prep, &effects)
    }

    /// Where θ was located on a stand-in ([`located_on`]), the minimum of the model's own
    /// objective within a quarter of a grid step (`step`, in `ln θ`) either side, the magnitude's
    /// sign kept and the search's range `lo..hi` (magnitudes) kept: on the model itself to the
    /// precision of the search, in a few trials. Elsewhere θ as it is.
    fn polish(&self, theta: f64, step: f64, lo: f64, hi: f64) -> f64 {
        if self.proxy.is_none() || !(theta.is_finite() && theta != 0.0) {
            return theta;
        }
        if self.defer_polish {
            self.deferred.set(Some(Unpolished { step, lo, hi }));
            return theta;
        }
        let sign = theta.signum();
        let u = theta.abs().ln();
        let (a, b) = (
            (u - 0.25 * step).max(lo.ln()),
            (u + 0.25 * step).min(hi.ln()),
        );
        let (best, _) = brent(a, b, POLISH_ITERS, |x| self.exact(sign * x.exp()));
        sign * best.exp()
    }

    /// The current model with the effect at `theta` added, fitted.
    fn fit(&self, theta: f64) -> Option<Stage> {
        fit_stage(self.prep, &with(&self.cur.effects, self.make(theta)))
    }

    /// θ by the effect's [`Search`]; `None` when it cannot be searched on these data.
    fn best_theta(&self) -> Option<Found> {
        let objective = |x: f64| self.objective(x);
        let theta = match self.kind.search(&self.prep.scales) {
            Search::None => {
                if self.kind.has_nonlinear() {
                    return None;
                }
                0.0
            }
            Search::Degree(max) => self.best_degree(max),
            Search::Log(lo, hi) if fits_both_forms(self.kind, self.prep) => {
                return Some(self.both_forms(lo, hi))
            }
            Search::Log(lo, hi) => {
                let theta = self.on_grid(Coord::Log, log_grid(lo, hi, 8), &objective);
                self.polish(theta, (hi / lo).ln() / 7.0, lo, hi)
            }
            Search::Signed(lo, hi) => {
                let mags = log_grid(lo, hi, 5);
                let mut g: Vec<f64> = mags.iter().rev().map(|m| -m).collect();
                g.extend(mags);
                let theta = self.on_grid(Coord::Lin, g, &objective);
                self.polish(theta, (hi / lo).ln() / 4.0, lo, hi)
            }
            Search::VolumeSpectral => self.volume_scan()?,
            Search::Spectral => self.spectral()?,
        };
        Some(Found {
            theta,
            prefit: None,
        })
    }

    /// [`grid_search`] over `grid`, or with a hint ([`search_from`]) the descent along it from the
    /// grid point nearest the hint.
    fn on_grid(&self, coord: Coord, grid: Vec<f64>, objective: &impl Fn(f64) -> f64) -> f64 {
        match self.hint {
            Some(h) => grid_descent(coord, &grid, nearest(coord, &grid, h), objective).0,
            None => grid_search(coord, grid, objective),
        }
    }

    /// The degree `1..=max` of least training AICc.
    fn best_degree(&self, max: usize) -> f64 {
        let nt = self.prep.train_rows.len() as f64;
        let mut best = (f64::INFINITY, 1.0);
        for d in 1..=max {
            let sse = self.objective(d as f64);
            let p = (self.cur.fit.beta.len() + d) as f64;
            let aicc = nt * (sse / nt).ln() + 2.0 * p + 2.0 * p * (p + 1.0) / (nt - p - 1.0);
            if aicc < best.0 {
                best = (aicc, d as f64);
            }
        }
        best.1
    }

    /// Each sampling form's parameter by its training SSE; between the two forms, like between
    /// candidates, the held-out error decides (the forms have the same parameter count). The
    /// winner's fit is kept.
    ///
    /// On instants (the lag of the cubic between samples: cheap) by the grid and its refinement.
    /// On frame means the lag runs inside the frames, and each trial rebuilds the design at the
    /// frames' instants, several times the cost: the two forms' objectives have their best grid
    /// points at or near the same place (they differ by what happens within a frame), so that
    /// search refines around the instants' best grid point, moving along the grid only where
    /// the minimum lies beyond ([`grid_descent`]).
    fn both_forms(&self, lo: f64, hi: f64) -> Found {
        let objective = |x: f64| self.objective(x);
        let grid = log_grid(lo, hi, 8);
        self.point.set(true);
        let step = (hi / lo).ln() / 7.0;
        // From a hint, the descent on instants, and its value in the grid's place below.
        let (best, at_best, instants) = match self.hint {
            Some(h) => {
                let (instants, at) =
                    grid_descent(Coord::Log, &grid, nearest(Coord::Log, &grid, h), &objective);
                (nearest(Coord::Log, &grid, instants), at, instants)
            }
            None => {
                let vals: Vec<f64> = grid.iter().map(|&g| objective(g)).collect();
                let best = argmin(&vals);
                let instants = refine(Coord::Log, &grid, best, vals[best], &objective);
                (best, vals[best], instants)
            }
        };
        let fit_instants = self.fit(instants);
        // An output lag inside the frames differs from one between samples only within a frame:
        // where the lag on instants takes no more off the training SSE than a free parameter
        // does by chance (one residual variance), the same lag inside the frames (a design
        // rebuilt at the instants per trial) is not searched.
        let (nt, p) = (
            self.prep.train_rows.len() as f64,
            self.cur.fit.beta.len() as f64 + 1.0,
        );
        let chance = self.cur.fit.sse / (nt - p).max(1.0);
        let inside_frames = self
            .kind
            .lag_time_constants(&self.make(grid[best]), self.prep)
            .is_some();
        if inside_frames && self.cur.fit.sse - at_best <= chance {
            return Found {
                theta: instants,
                prefit: fit_instants,
            };
        }
        self.point.set(false);
        let (averaged, _) = grid_descent(Coord::Log, &grid, best, &objective);
        let fit_averaged = self.fit(averaged);
        let heldout = |s: &Option<Stage>| s.as_ref().map_or(f64::INFINITY, |s| s.rmse_heldout);
        let found = if heldout(&fit_instants) < heldout(&fit_averaged) {
            self.point.set(true);
            Found {
                theta: instants,
                prefit: fit_instants,
            }
        } else {
            Found {
                theta: averaged,
                prefit: fit_averaged,
            }
        };
        // Located on a stand-in: the form chosen, polished on the model itself.
        let theta = self.polish(found.theta, step, lo, hi);
        if theta == found.theta {
            return found;
        }
        Found {
            theta,
            prefit: None,
        }
    }

    /// [`Search::VolumeSpectral`]: the effect's scan, each start refined in `1/θ` within one
    /// scan step either side.
    fn volume_scan(&self) -> Option<f64> {
        let scan = self.kind.scan(self.prep, &self.cur.resid, &self.make(0.0));
        let mut best = (f64::INFINITY, f64::NAN);
        for lambda in scan.starts {
            let kappa = 1.0 / lambda;
            let (kb, s) = brent(kappa - scan.step, kappa + scan.step, 12, |x| {
                self.objective(1.0 / x)
            });
            if s < best.0 {
                best = (s, 1.0 / kb);
            }
        }
        best.1.is_finite().then_some(best.1)
    }

    /// [`Search::Spectral`]: the two strongest local maxima of the residual's Welch spectrum above
    /// its two lowest bins (slow trends are drift, not ripple), each refined within one bin.
    fn spectral(&self) -> Option<f64> {
        let fs = 1.0 / self.prep.scales.dt;
        let (freq, psd) = analysis::welch(&self.cur.resid, &self.prep.series.train, fs, 4096);
        let df = freq.get(1).copied().unwrap_or(fs);
        let mut peaks: Vec<usize> = (3..psd.len().saturating_sub(1))
            .filter(|&k| psd[k] > psd[k - 1] && psd[k] >= psd[k + 1])
            .collect();
        peaks.sort_by(|&a, &b| psd[b].total_cmp(&psd[a]));
        let mut best = (f64::INFINITY, f64::NAN);
        for &k in peaks.iter().take(2) {
            let (f, s) = brent(freq[k] - df, freq[k] + df, 12, |x| self.objective(x));
            if s < best.0 {
                best = (s, f);
            }
        }
        best.1.is_finite().then_some(best.1)
    }

    /// The best point of the log grid whose model the QR accepts.
    fn best_grid_fit(&self) -> Option<Stage> {
        let Search::Log(lo, hi) = self.kind.search(&self.prep.scales) else {
            return None;
        };
        let mut grid: Vec<(f64, f64)> = log_grid(lo, hi, 8)
            .into_iter()
            .map(|g| (self.objective(g), g))
            .collect();
        grid.sort_by(|a, b| a.0.total_cmp(&b.0));
        grid.iter().find_map(|&(_, g)| self.fit(g))
    }
}

/// [`brent`]'s iterations of [`Trials::polish`]: at most six trials, its bracket (half a grid
/// step) shrunk to 4.5 % of a step at worst; on a smooth minimum the parabolic steps reach far
/// closer.
const POLISH_ITERS: usize = 4;

/// The index of the point of `grid` nearest `x` in the coordinate `coord`.
fn nearest(coord: Coord, grid: &[f64], x: f64) -> usize {
    let u = coord.from(x);
    argmin(
        &grid
            .iter()
            .map(|&g| (coord.from(g) - u).abs())
            .collect::<Vec<_>>(),
    )
}

fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let (a, b) = (lo.ln(), hi.ln());
    (0..n)
        .map(|i| (a + (b - a) * i as f64 / (n - 1) as f64).exp())
        .collect()
}

/// Grid search then [`brent`] between the best point's neighbours.
fn grid_search(coord: Coord, grid: Vec<f64>, objective: &impl Fn(f64) -> f64) -> f64 {
    let vals: Vec<f64> = grid.iter().map(|&g| objective(g)).collect();
    let i = argmin(&vals);
    refine(coord, &grid, i, vals[i], objective)
}

/// The index of the smallest value (the first of equals; 0 when none is below infinity).
fn argmin(vals: &[f64]) -> usize {
    vals.iter()
        .enumerate()
        .fold(
            (0, f64::INFINITY),
            |a, (i, &v)| if v < a.1 { (i, v) } else { a },
        )
        .0
}

/// [`grid_search`]'s refinement around grid point `start` without the grid: [`brent`] between
/// its neighbours, and where the best point found lies at an end of that bracket (the minimum
/// may lie beyond it), the same a grid step that way, until it lies inside or the grid ends. On
/// an objective unimodal over the grid that lands where the whole grid and the refinement do,
/// evaluating a few points near `start` instead of the grid. Returns the point and its value.
fn grid_descent(
    coord: Coord,
    grid: &[f64],
    start: usize,
    objective: &impl Fn(f64) -> f64,
) -> (f64, f64) {
    let u: Vec<f64> = grid.iter().map(|&g| coord.from(g)).collect();
    let last = u.len() - 1;
    let mut i = start.min(last);
    let mut way = 0i8;
    loop {
        let (lo, hi) = (u[i.saturating_sub(1)], u[(i + 1).min(last)]);
        let (x, at_x) = brent(lo, hi, 9, |x| objective(coord.to(x)));
        // Within 2 % of the bracket from an end: as far as the refinement tells ends apart.
        let near = 0.02 * (hi - lo);
        if x - lo <= near && i > 1 && way <= 0 {
            (i, way) = (i - 1, -1);
        } else if hi - x <= near && i + 1 < last && way >= 0 {
            (i, way) = (i + 1, 1);
        } else {
            return (coord.to(x), at_x);
        }
    }
}

/// [`brent`] between grid point i's neighbours, kept when below `at_i`, its value.
fn refine(coord: Coord, grid: &[f64], i: usize, at_i: f64, objective: &impl Fn(f64) -> f64) -> f64 {
    let u: Vec<f64> = grid.iter().map(|&g| coord.from(g)).collect();
    let lo = u[i.saturating_sub(1)];
    let hi = u[(i + 1).min(u.len() - 1)];
    let (ub, sb) = brent(lo, hi, 9, |x| objective(coord.to(x)));
    if sb < at_i {
        coord.to(ub)
    } else {
        grid[i]
    }
}

/// Re-tunes the searched parameters: Gauss–Newton steps on all of them at once
/// ([`gauss_newton`]), then coordinate descent from where those end: sweeps over the effects,
/// each parameter searched in a bracket around its current value, until a sweep improves the
/// training SSE by less than [`RETUNE_TOL`] (relative) or after [`RETUNE_SWEEPS`] sweeps. Two
/// effects that trade against each other (an air pocket's lag and a sensor lag) reach their
/// joint optimum in a few joint steps, where the sweeps alone walk there a bracket's width at a
/// time; the sweeps still take a start too far for the steps, and check where they settle.
pub fn retune(prep: &Prepared, stage: &Stage) -> Stage {
    retune_inner(prep, stage, None)
}

/// [`retune`] as a trial against a model of training SSE `target` (a swap): given up once the
/// training SSE cannot come below it ([`descend`]), and stopped at the sweep that brings it
/// below. A trial that only counts if it beats the model need not be re-tuned to the end to be
/// judged; the one taken is ([`retune`] from where this stopped). On a log of 18,449 frames a
/// pair that beat its model at the fourth sweep took ten more and two refreshes to settle, 10 s,
/// and was then turned down as unphysical.
pub fn retune_to_beat(prep: &Prepared, stage: &Stage, target: f64) -> Stage {
    retune_inner(prep, stage, Some(target))
}

/// Where [`descend_to_beat`] left a model's effects, and whether their training SSE came below
/// the target there.
pub(crate) struct Descended {
    pub effects: Vec<Effect>,
    pub beaten: bool,
}

/// [`retune_to_beat`]'s descent alone on `effects` (no forms chosen, no fit): its parameters
/// moved until their training SSE first comes below `target`, or given up once it cannot.
/// `None` where nothing is re-tunable.
pub(crate) fn descend_to_beat(
    prep: &Prepared,
    mut effects: Vec<Effect>,
    target: f64,
) -> Option<Descended> {
    if !effects.iter().any(|e| retune_bracket(prep, e).is_some()) {
        return None;
    }
    let start = sse_of(prep, &effects);
    let sse = descend(prep, &mut effects, start, Some(target));
    Some(Descended {
        effects,
        beaten: sse < target,
    })
}

/// [`retune`], given up above `target` and stopped below it where there is one.
fn retune_inner(prep: &Prepared, stage: &Stage, target: Option<f64>) -> Stage {
    // When the only re-tunable parameter is the one just searched (the last effect's), descent
    // would search the same one-dimensional objective again (and on a lag inside the frames each
    // trial rebuilds the design at the frames' instants).
    let tunable: Vec<usize> = (0..stage.effects.len())
        .filter(|&i| retune_bracket(prep, &stage.effects[i]).is_some())
        .collect();
    if tunable.is_empty() || tunable == [stage.effects.len() - 1] {
        return stage.clone();
    }
    let (mut effects, sse) = one_form(prep, stage.effects.clone(), stage.fit.sse);
    let mut sse = descend(prep, &mut effects, sse, target);
    let mut tuned = fit_stage(prep, &effects).unwrap_or_else(|| stage.clone());
    if target.is_some() {
        return tuned;
    }
    // What the effects took from the model they were added to (an air pocket's damping) is taken
    // again from the re-tuned one, and the descent resumed, while that lowers the SSE: an air
    // pocket added on top of a lag far from its value keeps a damping from a polynomial bent by
    // that lag, and its volume and the lag settle where that damping lets them
    // (`residual_hostsim_shapes`: air + sensor lag, seed 34).
    for _ in 0..RETUNE_REFRESHES {
        let mut fresh = effects.clone();
        let mut any = false;
        let model = tuned.view();
        for (i, e) in effects.iter().enumerate() {
            if let Some(f) = model
                .effects
                .get(i)
                .and_then(|t| e.kind.reanchored(prep, t, &model))
            {
                fresh[i] = f;
                any = true;
            }
        }
        if !any {
            break;
        }
        let start = sse_of(prep, &fresh);
        let s = descend(prep, &mut fresh, start, target);
        match fit_stage(prep, &fresh) {
            Some(next) if s < sse * (1.0 - RETUNE_TOL) => (effects, sse, tuned) = (fresh, s, next),
            _ => break,
        }
    }
    tuned
}

/// Whether `kind` is fitted both ways on these data
/// ([`super::effects::EffectModel::tries_point_sampled`], and on the firmware's frames
/// [`super::effects::EffectModel::point_sampled_on_frames`]).
fn fits_both_forms(kind: EffectKind, prep: &Prepared) -> bool {
    kind.tries_point_sampled() && (kind.point_sampled_on_frames() || !prep.series.flow_in_frames)
}

/// The effects with every one that is fitted both ways ([`Effect::point_sampled`]) in one form,
/// the one with the lower training SSE, where that is below `sse` (the SSE of `effects` as they
/// are); else `effects` as they are. Whether the log's samples are instants or frame means is a
/// property of the log, not of one effect; each effect's form was chosen when it was searched,
/// against the model of that round, and a lag in the instants' form takes every lag out of the
/// frames ([`super::effects::lag_in_frames`]). An air pocket and a sensor lag on frame means
/// (`residual_hostsim_shapes`, seed 34) were kept with the sensor lag in the instants' form:
/// 1.14 σ, against 1.02 σ in one form.
fn one_form(prep: &Prepared, effects: Vec<Effect>, sse: f64) -> (Vec<Effect>, f64) {
    let both: Vec<usize> = (0..effects.len())
        .filter(|&i| fits_both_forms(effects[i].kind, prep))
        .collect();
    let mut best = (effects, sse);
    if both.len() < 2 {
        return best;
    }
    for point in [false, true] {
        if both.iter().all(|&i| best.0[i].point_sampled == point) {
            continue;
        }
        let mut trial = best.0.clone();
        for &i in &both {
            trial[i].point_sampled = point;
        }
        let s = sse_of(prep, &trial);
        if s < best.1 {
            best = (trial, s);
        }
    }
    best
}

/// [`gauss_newton`]'s steps, then coordinate-descent sweeps with pattern moves ([`retune`]) from
/// `effects` at training SSE `sse`; the SSE where they stop. They also stop at the sweep that
/// brings the SSE below `target` ([`retune_to_beat`]), and while above it once the last sweep's
/// gain shows the target out of reach ([`out_of_reach`]): each further sweep is taken to gain at
/// most the last one's gain times the ratio of the last two (at least a half), a geometric
/// series. The SSE of a descent
/// that settles falls by such shrinking steps (`residual_hostsim_shapes`, air + sensor lag, seed
/// 35: 91 → 47 → 17 → 14 → 6.9 …, the model to beat at 57); on the 3-hour log an air pocket and a
/// sensor lag in a delivery lag's place, searched in turn, went 106 → 92.4 → 91.7 and settled at
/// 91.0 against the 89.8 to beat, ten sweeps of 15 s for nothing; started from their rounds' fits
/// ([`super::swaps::swap_for_pair`]) they go 666 → 116 → 103 and are given up there.
fn descend(prep: &Prepared, effects: &mut Vec<Effect>, sse: f64, target: Option<f64>) -> f64 {
    let (mut sse, steps) = gauss_newton(prep, effects, sse, target);
    if steps != Steps::Open {
        return sse;
    }
    let mut last_gain = f64::INFINITY;
    for _ in 0..RETUNE_SWEEPS {
        let (start, before) = (effects.clone(), sse);
        sse = retune_sweep(prep, effects, sse);
        if sse > before * (1.0 - RETUNE_TOL) {
            break;
        }
        sse = pattern_move(prep, &start, effects, sse);
        let gain = before - sse;
        if target.is_some_and(|t| sse < t || out_of_reach(gain, last_gain, sse, t)) {
            break;
        }
        last_gain = gain;
    }
    sse
}

/// Whether `target` is out of reach from training SSE `sse` after a sweep or step that gained
/// `gain` (the one before it `last_gain`): each further one is taken to gain at most the last
/// gain times the ratio of the last two (clamped to 0.5–0.9), a geometric series ([`descend`]).
fn out_of_reach(gain: f64, last_gain: f64, sse: f64, target: f64) -> bool {
    let ratio = (gain / last_gain).clamp(0.5, 0.9);
    gain * ratio / (1.0 - ratio) < sse - target
}

/// Gauss–Newton steps on the searched parameters jointly, before [`descend`]'s coordinate
/// sweeps: the model's prediction `X(u)β` moved by each parameter (in its search coordinate `u`,
/// log for positive ones) by a small step gives its derivative column `d_k = ∂(X β)/∂u_k`, and
/// the model's design with those columns added, fitted again, gives the step `Δu` as their
/// coefficients (variable projection, Kaufman's approximation: `X(u + Δu)β ≈ X(u)β + Σ Δu_k d_k`).
/// A step is taken when it lowers the training SSE (halved up to [`GN_HALVINGS`] times), each
/// parameter kept within its re-tune bracket ([`retune_bracket`]). One step costs a design per
/// parameter and two more; a coordinate sweep costs about twelve per parameter, and two lags
/// that trade against each other take a sweep per bracket's width. The steps end where none
/// lowers the SSE, or where one had to be cut and gained less than [`GN_WALKING`] of the SSE
/// (far from the optimum, where the objective is not near its quadratic model: the sweeps go on
/// from there, and judge whether a `target` is in reach); a cut step that still gains that much
/// is walking a valley the sweeps would walk a bracket at a time (on a random rig of the loop
/// benchmark, an air pocket and a sensor lag that trade, with a hysteresis beside them: a step
/// cut in half took the SSE from 16.0 to 11.5, the twelve sweeps that followed to 7.35 in 3.2 s
/// through the frames; five more steps reach 7.32 in 0.7 s), where
/// a full one gains less than [`RETUNE_TOL`] (settled: every parameter's derivative vanishes
/// together, and [`descend`] ends there without sweeps; on a random rig of the loop benchmark, a
/// leak, an air pocket and an offset drift, five sweeps of 0.4–0.8 s each after settled steps
/// moved nothing), where the step's own linear model predicts a gain below [`RETUNE_TOL`] (the
/// same, seen before the step is tried: on that rig a re-tune resumed from where the last one
/// settled, the air pocket's damping taken again, found no step that lowers the SSE and went on
/// to a sweep of 20 rebuilds that gained less than [`RETUNE_TOL`]), after [`GN_STEPS`] steps,
/// below `target`, or, after full steps, once their gains show `target` out of reach (the
/// sweeps' bound, [`out_of_reach`]). Returns the SSE and where the steps ended.
fn gauss_newton(
    prep: &Prepared,
    effects: &mut Vec<Effect>,
    mut sse: f64,
    target: Option<f64>,
) -> (f64, Steps) {
    let y = &prep.series.p;
    let rows = &prep.train_rows;
    let mut last_gain = f64::INFINITY;
    for _ in 0..GN_STEPS {
        let params: Vec<(usize, Coord, f64, f64)> = (0..effects.len())
            .filter_map(|i| {
                let (c, lo, hi) = retune_bracket(prep, &effects[i])?;
                Some((i, c, lo, hi))
            })
            .collect();
        if params.is_empty() {
            break;
        }
        let design = build(prep, effects);
        let Some(fit) = lsq::fit(&design.cols, y, rows) else {
            break;
        };
        let pred = lsq::predict(&design.cols, &fit.beta);
        // Held beside the moved designs where small; built again after them on a long log.
        let held = (design.cols.len() * y.len() * 8 <= GN_HOLD_BYTES).then_some(design);
        let mut derivs = Vec::with_capacity(params.len());
        for &(i, c, lo, hi) in &params {
            let u = c.from(effects[i].theta);
            let h = GN_STEP_FRACTION * (hi - lo);
            let mut trial = effects.clone();
            trial[i].theta = c.to(u + h);
            let moved = build(prep, &trial);
            if moved.cols.len() != fit.beta.len() {
                break;
            }
            let q = lsq::predict(&moved.cols, &fit.beta);
            derivs.push(
                q.iter()
                    .zip(&pred)
                    .map(|(a, b)| (a - b) / h)
                    .collect::<Vec<f64>>(),
            );
        }
        if derivs.len() != params.len() {
            break;
        }
        let mut cols = held.unwrap_or_else(|| build(prep, effects)).cols;
        let nb = cols.len();
        cols.extend(derivs);
        let Some(aug) = lsq::fit(&cols, y, rows) else {
            break;
        };
        drop(cols);
        // The step's own model of the objective predicts what it can gain: next to nothing where
        // the parameters sit at a joint minimum already (a re-tune resumed from where the last
        // one settled), and then no trial of it is needed, nor the sweeps that a step that does
        // not lower the SSE would hand over to.
        if fit.sse - aug.sse < RETUNE_TOL * fit.sse {
            return (sse, Steps::Settled);
        }
        let step: Vec<f64> = aug.beta[nb..].to_vec();
        let mut taken = None;
        let mut scale = 1.0;
        for _ in 0..=GN_HALVINGS {
            let mut trial = effects.clone();
            for (&(i, c, lo, hi), &d) in params.iter().zip(&step) {
                trial[i].theta = c.to((c.from(effects[i].theta) + scale * d).clamp(lo, hi));
            }
            let s = sse_of(prep, &trial);
            if s < sse {
                taken = Some((trial, s));
                break;
            }
            scale *= 0.5;
        }
        let Some((next, s)) = taken else {
            break;
        };
        let gain = sse - s;
        *effects = next;
        sse = s;
        if target.is_some_and(|t| sse < t) {
            return (sse, Steps::Beaten);
        }
        // A full step that gains next to nothing: the steps have settled where every parameter's
        // derivative vanishes together, which a coordinate sweep has nothing to add to.
        if scale == 1.0 && gain < RETUNE_TOL * (sse + gain) {
            return (sse, Steps::Settled);
        }
        // A step that had to be cut ends the steps unless it still walks a valley: the objective
        // is not near enough to its quadratic model for them, and the sweeps go on from there.
        if scale < 1.0 && gain < GN_WALKING * (sse + gain) {
            break;
        }
        // Full steps gain less and less as they settle (quadratically near the optimum); the
        // sweeps' bound on what is left ([`descend`]) holds for them a fortiori.
        if target.is_some_and(|t| out_of_reach(gain, last_gain, sse, t)) {
            return (sse, Steps::OutOfReach);
        }
        last_gain = gain;
    }
    (sse, Steps::Open)
}

/// Where [`gauss_newton`]'s steps ended.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Steps {
    /// Below the target.
    Beaten,
    /// Above the target, which full steps show out of reach.
    OutOfReach,
    /// A full step gained less than [`RETUNE_TOL`]: at the joint minimum.
    Settled,
    /// Cut, without a step that lowers the SSE, or out of steps: the sweeps go on from there.
    Open,
}

/// Most bytes of a design [`gauss_newton`] holds while it builds the moved ones.
const GN_HOLD_BYTES: usize = 64 << 20;

/// Most [`gauss_newton`] steps of one descent: a step costs a design per parameter and two to
/// four more, a sweep about twelve per parameter.
const GN_STEPS: usize = 16;

/// The share of the SSE a cut [`gauss_newton`] step must gain for the steps to go on.
const GN_WALKING: f64 = 0.1;

/// Most halvings of a [`gauss_newton`] step that does not lower the SSE.
const GN_HALVINGS: usize = 2;

/// A parameter's finite-difference step in [`gauss_newton`], as a share of its re-tune bracket.
const GN_STEP_FRACTION: f64 = 1e-3;

/// Most times [`retune`] takes the effects' model data again from the re-tuned model.
pub const RETUNE_REFRESHES: usize = 3;

/// Most coordinate-descent sweeps of [`retune`].
pub const RETUNE_SWEEPS: usize = 12;

/// Relative SSE gain below which [`retune`] stops.
pub const RETUNE_TOL: f64 = 1e-6;

/// The pattern move of Hooke and Jeeves after a sweep that went from `start` to `effects`: the
/// same step again, doubled while it keeps lowering the training SSE (searched parameters in
/// their search coordinate: log for positive ones). Coordinate steps alone crawl along the
/// valley two trading parameters make; this walks it. Returns the SSE where it stopped.
fn pattern_move(prep: &Prepared, start: &[Effect], effects: &mut Vec<Effect>, mut sse: f64) -> f64 {
    let mut scale = 1.0;
    for _ in 0..4 {
        let trial: Vec<Effect> = effects
            .iter()
            .zip(start)
            .map(|(e, s)| {
                let mut t = e.clone();
                let walks = match Coord::of_search(e.kind.search(&prep.scales)) {
                    Some(Coord::Log) if e.theta > 0.0 && s.theta > 0.0 => Some(Coord::Log),
                    Some(Coord::Lin) => Some(Coord::Lin),
                    _ => None,
                };
                if let Some(c) = walks {
                    let (u, u0) = (c.from(e.theta), c.from(s.theta));
                    t.theta = c.to(u + scale * (u - u0));
                }
                t
            })
            .collect();
        let s = sse_of(prep, &trial);
        if s.is_nan() || s >= sse {
            break;
        }
        *effects = trial;
        sse = s;
        scale *= 2.0;
    }
    sse
}

/// One sweep of [`retune`]; the training SSE after it (`sse` when nothing moved).
fn retune_sweep(prep: &Prepared, effects: &mut [Effect], mut sse: f64) -> f64 {
    for i in 0..effects.len() {
        let e = effects[i].clone();
        let Some((coord, lo, hi)) = retune_bracket(prep, &e) else {
            continue;
        };
        let objective = |x: f64| {
            let mut trial = effects.to_vec();
            trial[i].theta = coord.to(x);
            sse_of(prep, &trial)
        };
        let current = objective(coord.from(e.theta));
        let (u, s) = brent(lo, hi, 10, objective);
        if s < current {
            effects[i].theta = coord.to(u);
            sse = s;
        }
    }
    sse
}

/// The coordinate and bracket [`retune_sweep`] searches effect `e`'s parameter in; `None` for
/// a parameter it leaves as found (a scan's or a degree) or none.
fn retune_bracket(prep: &Prepared, e: &Effect) -> Option<(Coord, f64, f64)> {
    let (coord, lo, hi) = match e.kind.search(&prep.scales) {
        Search::Log(..) => (Coord::Log, e.theta.ln() - 0.7, e.theta.ln() + 0.7),
        Search::Signed(..) => (Coord::Lin, e.theta * 0.5, e.theta * 1.5),
        Search::Spectral => {
            let df = 0.25 * prep.scales.dt.recip() / 4096.0_f64.min(prep.series.len() as f64);
            (Coord::Lin, e.theta - df, e.theta + df)
        }
        Search::VolumeSpectral | Search::Degree(_) | Search::None => return None,
    };
    Some(if lo <= hi {
        (coord, lo, hi)
    } else {
        (coord, hi, lo)
    })
}

/// Why a fitted model is not physically possible (the first offending effect: its index and the
/// reason, [`super::effects::EffectModel::unphysical`]), or `None` when every effect is admissible
/// (module docs).
pub fn unphysical(stage: &Stage, sc: &super::effects::Scales) -> Option<(usize, String)> {
    stage.effects.iter().enumerate().find_map(|(idx, e)| {
        let coefs = stage.view().coefs(idx);
        e.kind.unphysical(e, &coefs, sc).map(|why| (idx, why))
    })
}

/// Outcome of the nested test of `big` against `small`.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct NestedTest {
    /// F statistic after the effective-sample-size correction.
    pub f_statistic: f64,
    /// Numerator degrees of freedom (added parameters).
    pub df1: f64,
    /// Denominator degrees of freedom, `N_eff − p₁`.
    pub df2: f64,
    /// Effective sample size.
    pub n_eff: f64,
    /// p-value.
    pub p_value: f64,
}

/// The autocorrelation-corrected nested F-test (module docs).
pub fn nested_test(prep: &Prepared, small: &Stage, big: &Stage) -> NestedTest {
    let n = prep.train_rows.len();
    let p1 = big.n_params() as f64;
    let q = (big.n_params() as f64 - small.n_params() as f64).max(1.0);
    let rho = lag1(&big.resid, &prep.series.train);
    let ne = n_eff(n, rho);
    let df2 = ne - p1;
    let drop = (small.fit.sse - big.fit.sse).max(0.0);
    let f = (drop / q) / (big.fit.sse / (n as f64 - p1)) * ne / n as f64;
    let p_value = if df2 >= 1.0 && f.is_finite() {
        FisherSnedecor::new(q, df2)
            .map(|d| 1.0 - d.cdf(f))
            .unwrap_or(1.0)
    } else {
        1.0
    };
    NestedTest {
        f_statistic: f,
        df1: q,
        df2,
        n_eff: ne,
        p_value,
    }
}

/// A parameter with its uncertainty and unit.
#[derive(Clone, Debug, Serialize)]
pub struct Param {
    /// Name (snake case, unit-free).
    pub name: String,
    /// Value.
    pub value: f64,
    /// One standard error (`null` when the profile was flat).
    pub std_err: Option<f64>,
    /// Unit.
    pub unit: &'static str,
    /// 95 % interval `[lo, hi]` from the final model's joint cluster-robust covariance, about the
    /// value and about the least-squares minimum ([`super::interval`]); absent where the
    /// parameter has no standard error (a degree, a form) or the covariance could not be formed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ci95: Option<[f64; 2]>,
    /// Whether [`Self::ci95`] was clipped at the parameter's physical bound (0: a time constant,
    /// width, volume or amplitude cannot be negative); present only when it was.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub ci95_clipped: bool,
}

/// A parameter; a non-finite standard error is reported as `null`.
pub fn param(name: &str, value: f64, se: f64, unit: &'static str) -> Param {
    Param {
        name: name.into(),
        value,
        std_err: se.is_finite().then_some(se),
        unit,
        ci95: None,
        ci95_clipped: false,
    }
}

/// Standard error of a searched parameter from the profile SSE curvature.
fn theta_se(prep: &Prepared, stage: &Stage, i: usize, inflate: f64) -> f64 {
    let e = &stage.effects[i];
    let (coord, u0, h) = match e.kind.search(&prep.scales) {
        Search::Log(..) => (Coord::Log, e.theta.ln(), 0.05),
        Search::Signed(..) => (Coord::Lin, e.theta, 0.05 * e.theta.abs().max(1e-12)),
        Search::Spectral | Search::VolumeSpectral => {
            (Coord::Lin, e.theta, 1e-3 * e.theta.abs().max(1e-6))
        }
        Search::Degree(_) | Search::None => return f64::NAN,
    };
    let at = |u: f64| {
        let mut trial = stage.effects.clone();
        trial[i].theta = coord.to(u);
        sse_of(prep, &trial)
    };
    let s0 = at(u0);
    let curv = (at(u0 + h) - 2.0 * s0 + at(u0 - h)) / (h * h);
    if curv <= 0.0 {
        return f64::NAN;
    }
    let var_u = 2.0 * stage.fit.sigma2() / curv * inflate;
    match coord {
        Coord::Log => e.theta * var_u.sqrt(),
        Coord::Lin => var_u.sqrt(),
    }
}

/// Physical parameters of effect `i` of a fitted stage, with uncertainties
/// ([`super::effects::EffectModel::params`]); their 95 % intervals are
/// [`super::interval::effect_params_ci`]'s.
pub fn effect_params(prep: &Prepared, stage: &Stage, i: usize) -> Vec<Param> {
    stage.effects[i].kind.params(&fitted(prep, stage, i))
}

/// Effect `i` of `stage` as its parameters are read from it: its columns, θ's standard error and
/// the residual variance, both inflated for the autocorrelation (`n / n_eff`).
pub(crate) fn fitted<'a>(prep: &'a Prepared, stage: &'a Stage, i: usize) -> Fitted<'a> {
    let n = prep.train_rows.len();
    let rho = lag1(&stage.resid, &prep.series.train);
    let inflate = n as f64 / n_eff(n, rho).max(1.0);
    Fitted {
        prep,
        beta: &stage.fit.beta,
        xtx_inv: &stage.fit.xtx_inv,
        effect: &stage.effects[i],
        cols: stage.owned_columns(i),
        theta_se: theta_se(prep, stage, i, inflate),
        s2: stage.fit.sigma2() * inflate,
    }
}

#[cfg(test)]
mod tests {
    use super::{brent, build, fit_stage, gauss_newton, lsq, sse_of};
    use crate::residual::basis::PolyBasis;
    use crate::residual::effects::{Effect, EffectKind, Hysteresis, Prepared, SensorLag};
    use crate::residual::Series;

    /// 3,000 frames of two incommensurate strokes: their count, the flow, a smooth (3, 2)
    /// pressure on them, and the series with a given pressure prepared for a (3, 2) baseline (one
    /// block of 300 frames in five held out).
    fn two_tone_rig() -> (usize, Vec<f64>, Vec<f64>, impl Fn(Vec<f64>) -> Prepared) {
        let n = 3000;
        let (t, v, f) = crate::test_motion::two_tones(n);
        let p0: Vec<f64> = (0..n)
            .map(|k| 2.0 + 0.01 * v[k] + 0.002 * f[k] + 1e-5 * v[k] * f[k])
            .collect();
        let train: Vec<bool> = (0..n).map(|k| (k / 300) % 5 != 4).collect();
        let flow = f.clone();
        let make = move |p: Vec<f64>| {
            let series = Series::new(t.clone(), v.clone(), f.clone(), p, train.clone()).unwrap();
            let basis = PolyBasis::for_data(&series.v, &series.vdot, 3, 2).unwrap();
            Prepared::new(series, basis)
        };
        (n, flow, p0, make)
    }

    /// A plant inside the model class, known exactly: a (3, 2) polynomial with hysteresis of width
    /// 12 mm³ behind a sensor lag of 60 ms (1.5 frames: the two trade through the damping), on
    /// 3,000 frames of two incommensurate strokes. Started with both parameters 40 % off, the
    /// joint steps find both to 0.5 % and the training SSE to a millionth of where they started,
    /// in a few steps (a coordinate sweep alone takes a bracket's width per sweep).
    #[test]
    fn gauss_newton_finds_two_trading_parameters_of_a_known_plant() {
        let (n, f, p0, make) = two_tone_rig();
        let truth = [
            Effect::new(EffectKind(&Hysteresis), 12.0),
            Effect::new(EffectKind(&SensorLag), 0.06),
        ];
        // The plant: the design at the true parameters times coefficients fitted to a smooth
        // pressure with a hysteresis gap of 0.3 kPa.
        let prep = make(p0.clone());
        let design = build(&prep, &truth);
        let mut p = p0;
        for (k, x) in p.iter_mut().enumerate() {
            *x += 0.3 * (f[k] / 60.0).tanh();
        }
        let rows: Vec<usize> = (0..n).collect();
        let beta = lsq::fit(&design.cols, &p, &rows).unwrap().beta;
        let plant = lsq::predict(&design.cols, &beta);
        let prep = make(plant);
        let mut effects = vec![
            Effect::new(EffectKind(&Hysteresis), 12.0 * 1.4),
            Effect::new(EffectKind(&SensorLag), 0.06 * 0.6),
        ];
        let start = sse_of(&prep, &effects);
        let (sse, _) = gauss_newton(&prep, &mut effects, start, None);
        let width = effects[0].theta;
        let tau = effects[1].theta;
        assert!((width / 12.0 - 1.0).abs() < 5e-3, "width {width}");
        assert!((tau / 0.06 - 1.0).abs() < 5e-3, "tau {tau}");
        assert!(sse < 1e-6 * start, "SSE {start} -> {sse}");
        // The same as a fit of the stage reports.
        let stage = fit_stage(&prep, &effects).unwrap();
        assert!((stage.fit.sse - sse).abs() <= 1e-9 * start.max(1.0));
    }

    /// A transport delay of 0.1 s (an input transform: every baseline column moves with it)
    /// behind a sensor lag of 60 ms inside the frames, on a plant inside the model class: the
    /// delay is located on the model with its lag taken on instants (the stand-in is in use) and
    /// polished on the model itself, where it lands on the planted delay and the fit of the
    /// plant is exact; located on the stand-in alone it lands off by the difference of the two
    /// lag forms.
    #[test]
    fn a_delay_located_behind_a_lag_in_the_frames_lands_on_the_plant() {
        use super::{located_on, search, Trials};
        use crate::residual::effects::TransportDelay;
        let (n, _, p0, make) = two_tone_rig();
        let lag = Effect::new(EffectKind(&SensorLag), 0.06);
        let delay = EffectKind(&TransportDelay);
        let truth = [lag.clone(), Effect::new(delay, 0.1)];
        let prep = make(p0.clone());
        let design = build(&prep, &truth);
        let rows: Vec<usize> = (0..n).collect();
        let beta = lsq::fit(&design.cols, &p0, &rows).unwrap().beta;
        let prep = make(lsq::predict(&design.cols, &beta));
        let cur = fit_stage(&prep, &[lag]).unwrap();
        assert!(located_on(&prep, &cur, delay, &Effect::new(delay, 0.1)).is_some());
        let found = search(&prep, &cur, delay).unwrap().stage;
        let theta = found.effects[1].theta;
        // Within the search's precision (the polish's bracket over an 8-point grid from a
        // twentieth of a frame: 0.24 % here, 0.1 % when the range began at a quarter of one).
        assert!((theta / 0.1 - 1.0).abs() < 3e-3, "delay {theta}");
        assert!(
            found.fit.sse < 1e-5 * cur.fit.sse,
            "SSE {} -> {}",
            cur.fit.sse,
            found.fit.sse
        );
        // The stand-in's own minimum, without the polish, is elsewhere: the polish is what puts
        // the delay on the plant.
        let trials = Trials::new(&prep, &cur, delay);
        let stand_in = |x: f64| trials.objective(x);
        let (u, _) = brent((0.05f64).ln(), (0.2f64).ln(), 30, |x| stand_in(x.exp()));
        let rough = u.exp();
        assert!(
            trials.exact(rough) > 10.0 * found.fit.sse.max(1e-30),
            "stand-in minimum {rough}: SSE {} against {}",
            trials.exact(rough),
            found.fit.sse
        );
    }

    /// A search started from the previous round's θ ([`super::search_from`]): a delivery lag (one
    /// minimum) started ten times too short walks along its grid to the planted 40 ms, as the
    /// whole grid finds it; a hysteresis width (not one minimum) ignores the hint and is searched
    /// over its whole grid, the same to the bit as without it.
    #[test]
    fn a_search_from_the_last_round_walks_to_the_minimum_and_widths_ignore_it() {
        use super::{search, search_from};
        use crate::residual::effects::DeliveryLag;
        let (n, f, p0, make) = two_tone_rig();
        let delay = EffectKind(&DeliveryLag);
        let truth = [Effect::new(delay, 0.04)];
        let prep = make(p0.clone());
        let design = build(&prep, &truth);
        let rows: Vec<usize> = (0..n).collect();
        let beta = lsq::fit(&design.cols, &p0, &rows).unwrap().beta;
        let prep = make(lsq::predict(&design.cols, &beta));
        let cur = fit_stage(&prep, &[]).unwrap();
        let theta = |c: Option<super::Candidate>| c.unwrap().stage.effects[0].theta;
        let walked = theta(search_from(&prep, &cur, delay, Some(0.004)));
        let whole = theta(search(&prep, &cur, delay));
        assert!((walked / 0.04 - 1.0).abs() < 2e-3, "from 4 ms: {walked}");
        assert!((whole / 0.04 - 1.0).abs() < 2e-3, "whole grid: {whole}");
        let width = EffectKind(&Hysteresis);
        let truth = [Effect::new(width, 12.0)];
        let prep = make(p0.clone());
        let design = build(&prep, &truth);
        let mut p = p0.clone();
        for (k, x) in p.iter_mut().enumerate() {
            *x += 0.3 * (f[k] / 60.0).tanh();
        }
        let beta = lsq::fit(&design.cols, &p, &rows).unwrap().beta;
        let prep = make(lsq::predict(&design.cols, &beta));
        let cur = fit_stage(&prep, &[]).unwrap();
        let hinted = theta(search_from(&prep, &cur, width, Some(200.0)));
        let plain = theta(search(&prep, &cur, width));
        assert!(
            (plain / 12.0 - 1.0).abs() < 2e-2,
            "hysteresis width {plain}"
        );
        assert_eq!(hinted.to_bits(), plain.to_bits(), "{hinted} vs {plain}");
    }

    /// Brent's refinement reaches the precision `iters` golden-section steps would, within as
    /// many evaluations, on minima it can and cannot fit by parabolas.
    #[test]
    fn brent_finds_the_minimum_to_the_golden_sections_precision_in_as_many_evaluations() {
        let golden = 0.5 * (5f64.sqrt() - 1.0);
        type Case = (&'static str, f64, fn(f64) -> f64);
        let cases: [Case; 4] = [
            ("quadratic", 0.37, |x| (x - 0.37).powi(2)),
            ("quartic", -0.8, |x| (x + 0.8).powi(4) + 3.0),
            ("kink", 1.3, |x| (x - 1.3).abs()),
            ("at the end", 2.0, |x| -x),
        ];
        for (name, at, f) in cases {
            for iters in [6, 9, 12] {
                let mut evals = 0;
                let (x, y) = brent(-2.0, 2.0, iters, |x| {
                    evals += 1;
                    f(x)
                });
                let precision = 4.0 * golden.powi(iters as i32 + 1);
                assert!((x - at).abs() <= precision, "{name}, {iters}: {x} for {at}");
                assert_eq!(y, f(x), "{name}: the value returned is the point's");
                assert!(evals <= iters + 2, "{name}, {iters}: {evals} evaluations");
            }
        }
        // A smooth minimum takes fewer evaluations than the golden section's 14.
        let mut evals = 0;
        brent(-2.0, 2.0, 12, |x| {
            evals += 1;
            (x - 0.37).powi(2) + 0.1 * (x - 0.37).powi(4)
        });
        assert!(evals <= 9, "{evals} evaluations on a smooth minimum");
    }

    /// A non-finite value never wins over a finite one (the search may stop at it: the best
    /// finite point seen is the answer); where every value is non-finite, the bracket's middle.
    #[test]
    fn brent_skips_non_finite_values() {
        let (x, y) = brent(0.0, 1.0, 9, |x| if x < 0.5 { f64::NAN } else { x });
        assert!(x >= 0.5 && y == x, "{x} {y}");
        let (x, y) = brent(0.0, 1.0, 9, |_| f64::NAN);
        assert!(x == 0.5 && y.is_nan());
    }
}
