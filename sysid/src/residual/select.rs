//! Forward selection of effects (step 4 of the loop).
//!
//! Each round, every candidate not yet in the model has its nonlinear parameter θ searched on the
//! *training* rows (a log grid of 8 points, or 5 magnitudes of each sign, over a range set by the data's own
//! scales, then golden-section refinement between the best point's neighbours; ripple starts from
//! the peaks of the residual's Welch spectrum), all linear coefficients refitted jointly by QR.
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
//! effect is accepted, the parameters θ of the effects already in the model are re-tuned once
//! (golden section in a bracket around their values), since each was found while the other effects
//! were still missing.
//!
//! **Physical admissibility.** A candidate is kept only if every effect of the augmented model is
//! physically possible ([`unphysical`]): searched parameters are positive by construction (lags,
//! delays, widths, air volume, leak conductance, play), and the fitted linear parts are checked —
//! inertance `L ≥ 0` (the water column's mass), hysteresis gap `inflation − deflation ≥ 0` over the
//! whole volume range (a loop that returns energy is not friction). An inadmissible candidate is
//! not added however much it helps; the loop reports it with the structure it would have absorbed.
//!
//! Uncertainties: linear coefficients `σ̂²(XᵀX)⁻¹·N/N_eff`; a searched parameter from the curvature
//! of the profile SSE, `var θ = 2σ̂²/SSE''(θ)·N/N_eff` (Gaussian profile likelihood).

use std::sync::Arc;

use serde::Serialize;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

use super::analysis::{self, lag1, n_eff};
use super::basis::PolyBasis;
use super::effects::{build, CountLag, Design, Effect, EffectKind, Prepared, Search, P_ATM_KPA};
use super::lsq::{self, LsFit};

/// One fitted model: effects, design, coefficients and errors.
#[derive(Clone, Debug)]
pub struct Stage {
    /// Effects in the order added.
    pub effects: Vec<Effect>,
    /// Its regressors.
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

    /// The design columns of effect `idx`, in order.
    pub fn owned_columns(&self, idx: usize) -> Vec<usize> {
        (0..self.design.owner.len())
            .filter(|&c| self.design.owner[c] == Some(idx))
            .collect()
    }

    /// The volume error `(a, b)` (mm³) of the pump ripple at `idx`: what is applied exactly as an
    /// input transform plus the first-order correction its two columns fitted.
    fn pump_ripple_error(&self, idx: usize) -> (f64, f64) {
        let cols = self.owned_columns(idx);
        let off = self.effects[idx].ripple_offset;
        (
            off.0 + self.fit.beta[cols[0]],
            off.1 + self.fit.beta[cols[1]],
        )
    }
}

fn rms(x: &[f64], rows: &[usize]) -> f64 {
    (rows.iter().map(|&r| x[r] * x[r]).sum::<f64>() / rows.len().max(1) as f64).sqrt()
}

/// Fits the baseline augmented with `effects`; `None` if the design is rank-deficient.
pub fn fit_stage(prep: &Prepared, effects: &[Effect]) -> Option<Stage> {
    let design = build(prep, effects);
    let fit = lsq::fit(&design.cols, &prep.series.p, &prep.train_rows)?;
    let pred = lsq::predict(&design.cols, &fit.beta);
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

fn sse_of(prep: &Prepared, effects: &[Effect]) -> f64 {
    if let Some(sse) = super::effects::sse_structured(prep, effects) {
        return sse;
    }
    let design = build(prep, effects);
    lsq::sse_fast(&design.cols, &prep.series.p, &prep.train_rows)
}

/// Golden-section minimisation of `f` on [a, b] (unimodal within the bracket).
fn golden(mut a: f64, mut b: f64, iters: usize, mut f: impl FnMut(f64) -> f64) -> (f64, f64) {
    let g = 0.5 * (5f64.sqrt() - 1.0);
    let mut c = b - g * (b - a);
    let mut d = a + g * (b - a);
    let mut fc = f(c);
    let mut fd = f(d);
    for _ in 0..iters {
        if fc < fd {
            b = d;
            d = c;
            fd = fc;
            c = b - g * (b - a);
            fc = f(c);
        } else {
            a = c;
            c = d;
            fc = fd;
            d = a + g * (b - a);
            fd = f(d);
        }
    }
    if fc < fd {
        (c, fc)
    } else {
        (d, fd)
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
    let beta = &stage.fit.beta[..prep.basis.len()];
    let s = &prep.series;
    Arc::new(
        (0..s.len())
            .map(|k| d(&prep.basis, beta, s.v[k], s.vdot[k]))
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
    /// The augmented model with the candidate last.
    pub stage: Stage,
}

fn with(base: &[Effect], e: Effect) -> Vec<Effect> {
    let mut v = base.to_vec();
    v.push(e);
    v
}

/// Searches the nonlinear parameter of `kind` added to `cur`, returning the best augmented model.
pub fn search(prep: &Prepared, cur: &Stage, kind: EffectKind) -> Option<Candidate> {
    let base = &cur.effects;
    let damping = matches!(kind, EffectKind::AirCompliance | EffectKind::PumpRipple)
        .then(|| damping_of(prep, cur));
    let stiffness = (kind == EffectKind::PumpRipple).then(|| stiffness_of(prep, cur));
    // Backlash, transport delay: whether the samples are instants rather than frame means (tried
    // both ways).
    let point = std::cell::Cell::new(false);
    // The fit at the searched parameter, when the search already made it.
    let mut prefit: Option<Stage> = None;
    let make = |theta: f64| Effect {
        damping: damping.clone(),
        stiffness: stiffness.clone(),
        point_sampled: point.get(),
        ..Effect::new(kind, theta)
    };
    // Sensor lag only filters the current design (it is the last step of `build`).
    let lag_base = (kind == EffectKind::SensorLag
        && !base.iter().any(|e| e.kind == EffectKind::SensorLag))
    .then(|| super::effects::LagBase::new(prep, &cur.design.cols));
    let objective = |theta: f64| match &lag_base {
        Some(lb) => lb.sse(prep, theta),
        None => sse_of(prep, &with(base, make(theta))),
    };
    let theta = match kind.search(&prep.scales) {
        Search::None => {
            if kind.has_nonlinear() {
                return None;
            }
            0.0
        }
        Search::Degree(max) => {
            let nt = prep.train_rows.len() as f64;
            let mut best = (f64::INFINITY, 1.0);
            for d in 1..=max {
                let sse = objective(d as f64);
                let p = (cur.fit.beta.len() + d) as f64;
                let aicc = nt * (sse / nt).ln() + 2.0 * p + 2.0 * p * (p + 1.0) / (nt - p - 1.0);
                if aicc < best.0 {
                    best = (aicc, d as f64);
                }
            }
            best.1
        }
        Search::Log(lo, hi)
            if matches!(kind, EffectKind::Backlash | EffectKind::TransportDelay) =>
        {
            // Each form's parameter by its training SSE; between the two forms, like between
            // candidates, the held-out error decides (the forms have the same parameter count).
            // The winner's fit is kept for below.
            let averaged = grid_search(Coord::Log, log_grid(lo, hi, 8), &objective);
            let fit_averaged = fit_stage(prep, &with(base, make(averaged)));
            point.set(true);
            let instants = grid_search(Coord::Log, log_grid(lo, hi, 8), &objective);
            let fit_instants = fit_stage(prep, &with(base, make(instants)));
            let heldout = |s: &Option<Stage>| s.as_ref().map_or(f64::INFINITY, |s| s.rmse_heldout);
            if heldout(&fit_instants) < heldout(&fit_averaged) {
                prefit = fit_instants;
                instants
            } else {
                point.set(false);
                prefit = fit_averaged;
                averaged
            }
        }
        Search::Log(lo, hi) => grid_search(Coord::Log, log_grid(lo, hi, 8), &objective),
        Search::Signed(lo, hi) => {
            let mags = log_grid(lo, hi, 5);
            let mut g: Vec<f64> = mags.iter().rev().map(|m| -m).collect();
            g.extend(mags);
            grid_search(Coord::Lin, g, &objective)
        }
        Search::VolumeSpectral => {
            let (Some(k), Some(c)) = (&stiffness, &damping) else {
                return None;
            };
            let mut best = (f64::INFINITY, f64::NAN);
            let (periods, dk) = super::effects::pump_ripple_periods(prep, &cur.resid, k, c);
            for lambda in periods {
                // Refine in spatial frequency within one periodogram bin either side.
                let kappa = 1.0 / lambda;
                let (kb, s) = golden(kappa - dk, kappa + dk, 12, |x| objective(1.0 / x));
                if s < best.0 {
                    best = (s, 1.0 / kb);
                }
            }
            if !best.1.is_finite() {
                return None;
            }
            best.1
        }
        Search::Spectral => {
            let fs = 1.0 / prep.scales.dt;
            let (freq, psd) = analysis::welch(&cur.resid, &prep.series.train, fs, 4096);
            let df = freq.get(1).copied().unwrap_or(fs);
            // Local maxima above the two lowest bins (slow trends are drift, not ripple).
            let mut peaks: Vec<usize> = (3..psd.len().saturating_sub(1))
                .filter(|&k| psd[k] > psd[k - 1] && psd[k] >= psd[k + 1])
                .collect();
            peaks.sort_by(|&a, &b| psd[b].total_cmp(&psd[a]));
            let mut best = (f64::INFINITY, f64::NAN);
            for &k in peaks.iter().take(2) {
                let (f, s) = golden(freq[k] - df, freq[k] + df, 12, &objective);
                if s < best.0 {
                    best = (s, f);
                }
            }
            if !best.1.is_finite() {
                return None;
            }
            best.1
        }
    };
    let mut stage = match prefit.or_else(|| fit_stage(prep, &with(base, make(theta)))) {
        Some(stage) => stage,
        // The searches' SSE tolerates a rank-deficient design, the reported QR fit does not
        // (e.g. a lag so long that the lagged flow is nearly constant): take the best grid point
        // the QR accepts, so the candidate is still tested and reported.
        None => {
            let Search::Log(lo, hi) = kind.search(&prep.scales) else {
                return None;
            };
            let mut grid: Vec<(f64, f64)> = log_grid(lo, hi, 8)
                .into_iter()
                .map(|g| (objective(g), g))
                .collect();
            grid.sort_by(|a, b| a.0.total_cmp(&b.0));
            grid.iter()
                .find_map(|&(_, g)| fit_stage(prep, &with(base, make(g))))?
        }
    };
    if kind == EffectKind::PumpRipple {
        stage = ripple_gauss_newton(prep, base, stage);
        stage = count_lag_gauss_newton(prep, base, stage);
    }
    if kind == EffectKind::AirCompliance {
        // The damping came from a model fitted without the air pocket (which lowers the apparent
        // damping); take it once more from the augmented model, at the chamber's volume
        // v − V_a·P/(P_atm + P) where the law is evaluated, and re-tune the air volume. (More
        // passes were tried: they do not lower the SSE further.)
        let va = stage.effects.last().map_or(theta, |e| e.theta);
        let beta = &stage.fit.beta[..prep.basis.len()];
        let se = &prep.series;
        let d2 = Arc::new(
            (0..se.len())
                .map(|k| {
                    let p = prep.p_sched[k].max(-0.9 * P_ATM_KPA);
                    let v = se.v[k] - va * p / (P_ATM_KPA + p);
                    prep.basis.damping(beta, v, se.vdot[k])
                })
                .collect::<Vec<f64>>(),
        );
        let remake = |th: f64| Effect {
            damping: Some(d2.clone()),
            ..Effect::new(kind, th)
        };
        let (u, _) = golden(va.ln() - 0.7, va.ln() + 0.7, 10, |x| {
            sse_of(prep, &with(base, remake(x.exp())))
        });
        if let Some(s2) = fit_stage(prep, &with(base, remake(u.exp()))) {
            if s2.fit.sse < stage.fit.sse {
                stage = s2;
            }
        }
    }
    Some(Candidate { stage })
}

/// The pump ripple's two columns fit the volume error to first order (stiffness × δ + damping ×
/// δ̇); apply what they found exactly, as an input transform, and fit what is left: a few
/// Gauss–Newton steps, kept while the training SSE falls by more than 0.1 %.
fn ripple_gauss_newton(prep: &Prepared, base: &[Effect], mut stage: Stage) -> Stage {
    for _ in 0..4 {
        let last = stage.effects.len() - 1;
        let mut e = stage.effects[last].clone();
        e.ripple_offset = stage.pump_ripple_error(last);
        match fit_stage(prep, &with(base, e)) {
            Some(next) if next.fit.sse < stage.fit.sse => {
                let small = next.fit.sse > (1.0 - 1e-3) * stage.fit.sse;
                stage = next;
                if small {
                    break;
                }
            }
            _ => break,
        }
    }
    stage
}

/// How far the logged count trails the plunger at each cruise speed ([`CountLag`]): Gauss–Newton
/// steps on the lags, each fitting their derivative columns
/// ([`super::effects::count_lag_columns`]) together with the model, applying the step, and
/// refitting the ripple's amplitude; kept while the training SSE falls by more than 0.1 %. The
/// last step's standard errors are the lags'.
fn count_lag_gauss_newton(prep: &Prepared, base: &[Effect], mut stage: Stage) -> Stage {
    let last = stage.effects.len() - 1;
    if stage.effects[last].count_lag.lags.is_empty() {
        stage.effects[last].count_lag = CountLag::zero(prep.cruise_speeds.clone());
    }
    for _ in 0..4 {
        let e = stage.effects[last].clone();
        let (Some(k), Some(c)) = (&e.stiffness, &e.damping) else {
            break;
        };
        let ab = stage.pump_ripple_error(last);
        let extra =
            super::effects::count_lag_columns(&prep.subframe, k, c, e.theta, ab, &e.count_lag);
        let mut cols = stage.design.cols.clone();
        let p0 = cols.len();
        cols.extend(extra);
        let Some(fit) = lsq::fit(&cols, &prep.series.p, &prep.train_rows) else {
            break;
        };
        let s2 = fit.sigma2();
        let mut next = e.clone();
        for (i, lag) in next.count_lag.lags.iter_mut().enumerate() {
            *lag += fit.beta[p0 + i];
        }
        next.count_lag.se = (0..next.count_lag.lags.len())
            .map(|i| (s2 * fit.xtx_inv[(p0 + i, p0 + i)]).sqrt())
            .collect();
        match fit_stage(prep, &with(base, next)) {
            Some(next) if next.fit.sse < stage.fit.sse => {
                let small = next.fit.sse > (1.0 - 1e-3) * stage.fit.sse;
                stage = ripple_gauss_newton(prep, base, next);
                if small {
                    break;
                }
            }
            _ => break,
        }
    }
    stage
}

fn log_grid(lo: f64, hi: f64, n: usize) -> Vec<f64> {
    let (a, b) = (lo.ln(), hi.ln());
    (0..n)
        .map(|i| (a + (b - a) * i as f64 / (n - 1) as f64).exp())
        .collect()
}

/// Grid search then golden refinement between the best point's neighbours.
fn grid_search(coord: Coord, grid: Vec<f64>, objective: &impl Fn(f64) -> f64) -> f64 {
    let vals: Vec<f64> = grid.iter().map(|&g| objective(g)).collect();
    let (i, _) = vals.iter().enumerate().fold(
        (0, f64::INFINITY),
        |a, (i, &v)| if v < a.1 { (i, v) } else { a },
    );
    let u: Vec<f64> = match coord {
        Coord::Log => grid.iter().map(|g| g.ln()).collect(),
        Coord::Lin => grid.clone(),
    };
    let lo = u[i.saturating_sub(1)];
    let hi = u[(i + 1).min(u.len() - 1)];
    let (ub, sb) = golden(lo, hi, 9, |x| objective(coord.to(x)));
    if sb < vals[i] {
        coord.to(ub)
    } else {
        grid[i]
    }
}

/// Re-tunes each searched parameter once, in a bracket around its current value.
pub fn retune(prep: &Prepared, stage: &Stage) -> Stage {
    let mut effects = stage.effects.clone();
    for i in 0..effects.len() {
        let e = effects[i].clone();
        let (coord, lo, hi) = match e.kind.search(&prep.scales) {
            Search::Log(..) => (Coord::Log, e.theta.ln() - 0.7, e.theta.ln() + 0.7),
            Search::Signed(..) => (Coord::Lin, e.theta * 0.5, e.theta * 1.5),
            Search::Spectral => {
                let df = 0.25 * prep.scales.dt.recip() / 4096.0_f64.min(prep.series.len() as f64);
                (Coord::Lin, e.theta - df, e.theta + df)
            }
            _ => continue,
        };
        let (lo, hi) = if lo <= hi { (lo, hi) } else { (hi, lo) };
        let objective = |x: f64| {
            let mut trial = effects.clone();
            trial[i].theta = coord.to(x);
            sse_of(prep, &trial)
        };
        let current = objective(match coord {
            Coord::Log => e.theta.ln(),
            Coord::Lin => e.theta,
        });
        let (u, s) = golden(lo, hi, 10, objective);
        if s < current {
            effects[i].theta = coord.to(u);
        }
    }
    fit_stage(prep, &effects).unwrap_or_else(|| stage.clone())
}

/// Why a fitted model is not physically possible (the first offending effect: its index and the
/// reason), or `None` when every effect is admissible (module docs).
pub fn unphysical(stage: &Stage) -> Option<(usize, String)> {
    for (idx, e) in stage.effects.iter().enumerate() {
        let cols: Vec<f64> = stage
            .owned_columns(idx)
            .into_iter()
            .map(|c| stage.fit.beta[c])
            .collect();
        match e.kind {
            EffectKind::Inertance => {
                if let Some(&l) = cols.first() {
                    if l < 0.0 {
                        return Some((
                            idx,
                            format!(
                                "inertance L = {l:.3e} kPa·s²/mm³ is negative, which no mass of water gives"
                            ),
                        ));
                    }
                }
            }
            EffectKind::Hysteresis => {
                if let [h0, h1] = cols[..] {
                    // Gap 2·(H₀ + H₁x) over x ∈ [−1, 1] (the data's volume range): least at one end.
                    let least = 2.0 * (h0 - h1.abs());
                    if least < 0.0 {
                        return Some((
                            idx,
                            format!(
                                "hysteresis gap inflation − deflation reaches {least:.3} kPa (mid-range {:.3} kPa); a loop with deflation above inflation returns energy, which friction cannot",
                                2.0 * h0
                            ),
                        ));
                    }
                }
            }
            _ => {
                // Searched parameters are confined to their physical range by the search itself.
                if e.kind.has_nonlinear() && !(e.theta.is_finite()) {
                    return Some((idx, format!("{} parameter is not finite", e.kind.name())));
                }
            }
        }
    }
    None
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
}

fn param(name: &str, value: f64, se: f64, unit: &'static str) -> Param {
    Param {
        name: name.into(),
        value,
        std_err: se.is_finite().then_some(se),
        unit,
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
        _ => return f64::NAN,
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

/// Physical parameters of effect `i` of a fitted stage, with uncertainties.
pub fn effect_params(prep: &Prepared, stage: &Stage, i: usize) -> Vec<Param> {
    let n = prep.train_rows.len();
    let rho = lag1(&stage.resid, &prep.series.train);
    let inflate = n as f64 / n_eff(n, rho).max(1.0);
    let s2 = stage.fit.sigma2() * inflate;
    let cols = stage.owned_columns(i);
    let b = |k: usize| stage.fit.beta[cols[k]];
    let se = |k: usize| (s2 * stage.fit.xtx_inv[(cols[k], cols[k])]).sqrt();
    let e = &stage.effects[i];
    let tse = theta_se(prep, stage, i, inflate);
    // Backlash, transport delay: 1 when the samples fitted best as frame means (an averaging
    // sensor), 0 as instants.
    let frame_averaged = param(
        "frame_averaged",
        if e.point_sampled { 0.0 } else { 1.0 },
        f64::NAN,
        "1",
    );
    match e.kind {
        EffectKind::Hysteresis => vec![
            // Volume over which 63 % of the switch happens after a reversal.
            param("width", e.theta, tse, "mm3"),
            param("gap_at_mid_volume", 2.0 * b(0), 2.0 * se(0), "kPa"),
            param("gap_change_to_range_ends", 2.0 * b(1), 2.0 * se(1), "kPa"),
        ],
        EffectKind::AirCompliance => {
            let cbar = e
                .damping
                .as_ref()
                .map_or(0.0, |d| d.iter().sum::<f64>() / d.len().max(1) as f64);
            vec![
                param("air_volume_at_atmospheric_pressure", e.theta, tse, "mm3"),
                param(
                    "time_constant_at_0_kpa",
                    cbar * e.theta / P_ATM_KPA,
                    cbar * tse / P_ATM_KPA,
                    "s",
                ),
            ]
        }
        EffectKind::SensorLag => vec![param("time_constant", e.theta, tse, "s")],
        EffectKind::TransportDelay => vec![param("delay", e.theta, tse, "s"), frame_averaged],
        EffectKind::DeliveryLag => vec![
            param("time_constant", e.theta, tse, "s"),
            param("effective_delay", 2.0 * e.theta, 2.0 * tse, "s"),
        ],
        EffectKind::Inertance => vec![param("inertance", b(0), se(0), "kPa*s^2/mm3")],
        EffectKind::OffsetDrift => {
            // Change over the log: Σ_d c_d (P_d(1) − P_d(−1)) = Σ_{d odd} 2 c_d.
            let g: Vec<f64> = (0..cols.len())
                .map(|k| if k % 2 == 0 { 2.0 } else { 0.0 })
                .collect();
            let val: f64 = (0..cols.len()).map(|k| g[k] * b(k)).sum();
            let mut var = 0.0;
            for a in 0..cols.len() {
                for c in 0..cols.len() {
                    var += g[a] * g[c] * stage.fit.xtx_inv[(cols[a], cols[c])];
                }
            }
            vec![
                param("degree", cols.len() as f64, f64::NAN, "1"),
                param("change_over_log", val, (s2 * var).sqrt(), "kPa"),
            ]
        }
        EffectKind::VolumeDrift => vec![
            param("rate", e.theta, tse, "mm3/s"),
            param(
                "change_over_log",
                e.theta * prep.scales.duration,
                tse * prep.scales.duration,
                "mm3",
            ),
        ],
        EffectKind::Backlash => vec![param("play", e.theta, tse, "mm3"), frame_averaged],
        EffectKind::Ripple | EffectKind::PumpRipple => {
            // A pump ripple's columns carry the correction to the error already applied.
            let (a, c) = (b(0) + e.ripple_offset.0, b(1) + e.ripple_offset.1);
            let amp = a.hypot(c);
            let (saa, scc, sac) = (
                stage.fit.xtx_inv[(cols[0], cols[0])],
                stage.fit.xtx_inv[(cols[1], cols[1])],
                stage.fit.xtx_inv[(cols[0], cols[1])],
            );
            let var =
                s2 * (a * a * saa + c * c * scc + 2.0 * a * c * sac) / (amp * amp).max(1e-300);
            if e.kind == EffectKind::PumpRipple {
                // The columns carry the volume error δ itself: a and b are in mm³.
                let mut ps = vec![
                    param("period", e.theta, tse, "mm3"),
                    param("amplitude", amp, var.sqrt(), "mm3"),
                ];
                let lag = &e.count_lag;
                for (i, (&l, &se)) in lag.lags.iter().zip(&lag.se).enumerate() {
                    ps.push(match lag.speeds.get(i) {
                        Some(s) => param(&format!("count_lag_at_{s:.3}_mm3_s"), l, se, "mm3"),
                        None => param("count_lag", l, se, "mm3"),
                    });
                }
                ps
            } else {
                vec![
                    param("frequency", e.theta, tse, "Hz"),
                    param("amplitude", amp, var.sqrt(), "kPa"),
                ]
            }
        }
        EffectKind::Leak => vec![
            param("conductance", e.theta, tse, "mm3/(kPa*s)"),
            param(
                "volume_lost_over_log",
                e.theta * prep.scales.p_integral,
                tse * prep.scales.p_integral,
                "mm3",
            ),
        ],
    }
}
