//! An experiment that decides (issue 34): where the held-out data cannot tell a kept effect from
//! another explanation ([`super::alternatives`]), a short motion the firmware runs with its own
//! `run` command, chosen so that the two models as fitted predict pressures as different as
//! possible against the noise; and, on a second log recorded with it
//! (`vfp diagnose LOG --decide OTHER.csv`), the decision.
//!
//! **Proposal** ([`propose`]). Each candidate is one `run all <v_low> <v_high> <cycles>
//! <dwell_ms> <flow>…` line (the firmware's characterisation command: strokes between two
//! volumes, a dwell at each end, at one or two flows), from a few families over the log's own
//! envelope (its volume range and its fastest flow, at most [`MAX_FLOW`]): strokes of an eighth to
//! the whole of the range, at the bottom, middle or top of it; at the fastest flow, half of it,
//! a fifth of it (slow ramps), or a fifth then the fastest; dwells of 0 (flow reversals), 200
//! and 1,000 ms. Each is turned into the volume and flow columns a log of it would hold
//! ([`Run::series`]: the firmware's trapezoidal profile at its default acceleration, [`ACCEL`],
//! to the step, each 40 ms frame the mean of 8 instants; an approximation of the planner's
//! timing to within its rounding, the motion before the first stroke left out), with the motion
//! inside the frames as planned (the loop otherwise rebuilds it from the frame means). The kept
//! model and each alternative, as fitted (polynomial coefficients, effects at their parameters,
//! their linear coefficients), predict the pressure along it ([`predict`]; an effect scheduled
//! on the chamber's pressure reads the polynomial's prediction while candidates are compared,
//! the model's own for the one proposed). The second log's polynomial is refitted, so what it
//! can absorb of the difference does not count: the difference `d` is taken beyond the
//! polynomial's span on the experiment's samples (least squares, [`beyond_polynomial`]). The
//! effects' own linear coefficients are refitted too, which the measure does not take off: it
//! errs towards separating. The expected separation is [`expected_z`]: with white noise σ and
//! one of the two models true, the other's squared errors exceed its own by `Σd²` on average with
//! a standard deviation `2σ√(Σd²)`, a z of `√(Σd²)/(2σ)`, over the held-out share of the
//! samples. Candidates are compared over one cycle, scaled to as many cycles as fit in
//! [`BUDGET_S`], one coordinate at a time (the flows and dwell on a quarter-range stroke in the
//! middle, then the stroke's length and place, then the dwell again: about 25 of the grid's
//! 150, each run's columns and kept prediction made once for every effect). The one whose
//! smallest z over the alternatives is largest is proposed, with as many cycles as its z needs
//! to reach [`TARGET_Z`] (z grows as the square root of the length; between [`MIN_S`] and
//! [`MAX_S`]), then evaluated over its full length. σ is the final model's held-out RMSE (the
//! noise plus what the model still misses).
//!
//! **Decision** ([`decide`]). On the second log, its own polynomial (the first log's shape, its
//! own scaling) is refitted on its training cycles with the kept model's effects, and with each
//! alternative model's, the effects at the parameters found on the first log (the hypotheses as
//! the proposal simulated them; re-tuning them would let each adapt to the new motion, and the
//! proposal's prediction would no longer be the one tested). Both are scored on its held-out
//! cycles by the loop's paired test ([`validate::paired_z`]). The explanation with the lowest
//! held-out error is supported when its errors are smaller than every other's with a paired z of
//! at least [`ALT_Z`]; otherwise the second log still cannot tell them apart.

use std::fmt::Write as _;

use serde::Serialize;

use super::alternatives::ALT_Z;
use super::effects::design::build;
use super::effects::Prepared;
use super::lsq;
use super::validate::{self, FittedModel};
use super::{signal, DiagnoseError, Diagnosis, PolyBasis, Rig, Series};

/// Volume of one motor step, mm³ (the rig's lead screw and microstepping).
pub const STEP_MM3: f64 = 0.04;
/// Fastest flow an experiment asks for, mm³/s (the rig's safe limit; never above the log's own
/// fastest flow, where the polynomial has no data).
pub const MAX_FLOW: f64 = 100.0;
/// The firmware's default acceleration, mm³/s² (`run` moves at it).
pub const ACCEL: f64 = 500.0;
/// A telemetry frame, s (25 Hz).
pub const FRAME_S: f64 = 0.04;
/// Instants (ADC conversions) a frame is the mean of.
pub const OVERSAMPLE: usize = signal::SUB_SAMPLES;
/// Motion the candidates are compared over, s (the cycles that fit in it; at least one).
pub const BUDGET_S: f64 = 60.0;
/// Expected z the proposed experiment is made long enough for (above [`ALT_Z`], with a margin
/// for the approximations of the prediction), within [`MIN_S`] and [`MAX_S`].
pub const TARGET_Z: f64 = 3.0;
/// Shortest experiment proposed, s (enough held-out cycles for the paired test).
pub const MIN_S: f64 = 30.0;
/// Longest experiment proposed, s: where even this does not reach [`TARGET_Z`] the proposal
/// says so by its expected z.
pub const MAX_S: f64 = 600.0;
/// Rest at `v_low` before the first stroke in the predicted columns, s (the lags settle).
const REST_S: f64 = 1.0;
/// Shortest stroke tried, mm³.
const MIN_STROKE: f64 = 5.0;

/// What an experiment may ask of the rig and how it is judged: the log's envelope and noise.
#[derive(Clone, Copy, Debug, Default)]
pub struct Envelope {
    /// Lowest and highest volume of the log, mm³.
    pub v_min: f64,
    /// See `v_min`.
    pub v_max: f64,
    /// Fastest |flow| of the log, mm³/s.
    pub max_flow: f64,
    /// Noise the separation is measured against, kPa (the final model's held-out RMSE).
    pub sigma: f64,
    /// Share of a log's samples its held-out cycles hold (the first log's).
    pub held_share: f64,
    /// The rig (the effects' names).
    pub rig: Rig,
}

impl Envelope {
    /// The envelope of `series`, with noise `sigma`.
    pub fn of(series: &Series, sigma: f64) -> Self {
        let fold = |x: &[f64]| {
            x.iter()
                .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &v| {
                    (lo.min(v), hi.max(v))
                })
        };
        let (v_min, v_max) = fold(&series.v);
        let max_flow = series.vdot.iter().fold(0.0f64, |m, q| m.max(q.abs()));
        let held = series.train.iter().filter(|&&b| !b).count();
        Self {
            v_min,
            v_max,
            max_flow,
            sigma,
            held_share: held as f64 / series.len().max(1) as f64,
            rig: series.rig,
        }
    }
}

/// One `run all …` line: strokes between `v_low` and `v_high`, `cycles` at each flow in turn,
/// dwelling `dwell_ms` at each end.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Run {
    /// Lower volume, mm³.
    pub v_low: f64,
    /// Upper volume, mm³.
    pub v_high: f64,
    /// Cycles per flow.
    pub cycles: u32,
    /// Dwell at each end, ms.
    pub dwell_ms: u32,
    /// Flows, mm³/s, in order.
    pub flows: Vec<f64>,
}

/// The trapezoidal profile of a move of `d` mm³ at `flow` and [`ACCEL`]: peak flow, time to
/// reach it, cruise time, whole time.
fn profile(d: f64, flow: f64) -> (f64, f64, f64, f64) {
    let s_a = flow * flow / (2.0 * ACCEL);
    if 2.0 * s_a >= d {
        let vp = (ACCEL * d).sqrt();
        let ta = vp / ACCEL;
        (vp, ta, 0.0, 2.0 * ta)
    } else {
        let ta = flow / ACCEL;
        let tc = (d - 2.0 * s_a) / flow;
        (flow, ta, tc, 2.0 * ta + tc)
    }
}

/// Distance covered and flow `t` s into a move of `d` mm³ at `flow`.
fn along(d: f64, flow: f64, t: f64) -> (f64, f64) {
    let (vp, ta, tc, total) = profile(d, flow);
    if t <= 0.0 {
        (0.0, 0.0)
    } else if t < ta {
        (0.5 * ACCEL * t * t, ACCEL * t)
    } else if t < ta + tc {
        (0.5 * vp * ta + vp * (t - ta), vp)
    } else if t < total {
        let r = total - t;
        (d - 0.5 * ACCEL * r * r, ACCEL * r)
    } else {
        (d, 0.0)
    }
}

impl Run {
    /// The firmware command line (`docs/guide/src/protocol.md`).
    pub fn line(&self) -> String {
        let flows: Vec<String> = self.flows.iter().map(|f| format!("{f}")).collect();
        format!(
            "run all {} {} {} {} {}",
            self.v_low,
            self.v_high,
            self.cycles,
            self.dwell_ms,
            flows.join(" ")
        )
    }

    /// One cycle's length, s: at each flow up and down, a dwell after each.
    pub fn cycle_s(&self) -> f64 {
        let d = self.v_high - self.v_low;
        self.flows
            .iter()
            .map(|&f| 2.0 * (profile(d, f).3 + self.dwell_ms as f64 * 1e-3))
            .sum()
    }

    /// The strokes' length, s (the move to `v_low` before them not included).
    pub fn duration_s(&self) -> f64 {
        self.cycles as f64 * self.cycle_s()
    }

    /// The columns a log of the strokes would hold (module docs): [`REST_S`] at rest at `v_low`,
    /// the strokes, the last dwell; 40 ms frames (stamped at their middle), each the mean of
    /// [`OVERSAMPLE`] instants of the step position and the commanded flow. Pressure zero, every
    /// row training.
    pub fn series(&self, rig: Rig) -> Series {
        self.columns(rig).0
    }

    /// [`Run::series`] and the flow at each frame's instants (frame k's at `k·8 ..`).
    fn columns(&self, rig: Rig) -> (Series, Vec<f64>) {
        let d = self.v_high - self.v_low;
        let dwell = self.dwell_ms as f64 * 1e-3;
        // Legs: start time, direction, flow.
        let mut legs: Vec<(f64, f64, f64)> = Vec::new();
        let mut t = REST_S;
        for &f in &self.flows {
            for _ in 0..self.cycles {
                for dir in [1.0, -1.0] {
                    legs.push((t, dir, f));
                    t += profile(d, f).3 + dwell;
                }
            }
        }
        let end = t + 0.5;
        let frames = (end / FRAME_S).ceil() as usize;
        let at = |tc: f64| -> (f64, f64) {
            let k = legs.partition_point(|l| l.0 <= tc);
            if k == 0 {
                return (self.v_low, 0.0);
            }
            let (t0, dir, f) = legs[k - 1];
            let (s, q) = along(d, f, tc - t0);
            let s = (s / STEP_MM3 + 1e-9).floor() * STEP_MM3;
            let base = if dir > 0.0 { self.v_low } else { self.v_high };
            (base + dir * s, dir * q)
        };
        let mut tt = Vec::with_capacity(frames);
        let mut v = Vec::with_capacity(frames);
        let mut q = Vec::with_capacity(frames);
        let mut sub = Vec::with_capacity(frames * OVERSAMPLE);
        for k in 0..frames {
            let (mut sv, mut sq) = (0.0, 0.0);
            for j in 0..OVERSAMPLE {
                let tc = (k as f64 + (j as f64 + 0.5) / OVERSAMPLE as f64) * FRAME_S;
                let (a, b) = at(tc);
                sv += a;
                sq += b;
                sub.push(b);
            }
            tt.push((k as f64 + 0.5) * FRAME_S);
            v.push(sv / OVERSAMPLE as f64);
            q.push(sq / OVERSAMPLE as f64);
        }
        let n = tt.len();
        let series = Series {
            vddot: signal::acceleration_hermite(&tt, &v, &q),
            // The firmware's frames of its commanded flow, as a log of the loop reads them.
            flow_in_frames: true,
            t: tt,
            v,
            vdot: q,
            p: vec![0.0; n],
            train: vec![true; n],
            cycle_s: None,
            rig,
            volume_step: None,
        };
        (series, sub)
    }

    /// What kind of motion it is, in words.
    pub fn family(&self) -> String {
        let flows: Vec<String> = self.flows.iter().map(|f| format!("{f}")).collect();
        let how = if self.dwell_ms == 0 {
            "flow reversals (no dwell)".to_string()
        } else {
            format!("strokes with {} ms dwells", self.dwell_ms)
        };
        format!(
            "{how} of {} mm³ at {} mm³/s",
            self.v_high - self.v_low,
            flows.join(" then ")
        )
    }
}

/// `model`'s pressure along `series` (kPa per sample; module docs): its polynomial in `basis`
/// and its effects at their parameters, their per-sample schedules recomputed there; an effect
/// scheduled on the chamber's pressure reads the polynomial's prediction, then (with `passes`
/// 2 or more) the model's own from the pass before. `None` when the model's columns do not match
/// its coefficients.
pub fn predict(
    series: &Series,
    basis: &PolyBasis,
    model: &FittedModel,
    passes: usize,
) -> Option<Vec<f64>> {
    if series.len() < 2 {
        return None;
    }
    predict_in(&Prepared::new(series.clone(), basis.clone()), model, passes)
}

/// [`predict`] on a prepared series (its motion's reconstruction inside the frames, the costly
/// part, shared by every model predicted on it).
fn predict_in(prep: &Prepared, model: &FittedModel, passes: usize) -> Option<Vec<f64>> {
    let nb = prep.basis.len();
    if model.beta.len() < nb {
        return None;
    }
    let poly = &model.beta[..nb];
    let mut pred = lsq::predict(&build(prep, &[]).cols, poly);
    if model.effects.is_empty() {
        return Some(pred);
    }
    let on_pressure = model
        .effects
        .iter()
        .any(|e| e.kind.uses_measured_pressure());
    for _ in 0..if on_pressure { passes.max(1) } else { 1 } {
        let with_p;
        let prep = if on_pressure {
            with_p = with_pressure(prep, pred);
            &with_p
        } else {
            prep
        };
        let effects: Vec<_> = model
            .effects
            .iter()
            .map(|e| validate::with_schedules(prep, e, poly))
            .collect();
        let design = build(prep, &effects);
        if design.cols.len() != model.beta.len() {
            return None;
        }
        pred = lsq::predict(&design.cols, &model.beta);
    }
    Some(pred)
}

/// `prep` with `p` as its measured pressure (what an effect scheduled on the pressure reads), the
/// rest shared.
fn with_pressure(prep: &Prepared, p: Vec<f64>) -> Prepared {
    let mut q = prep.clone();
    q.p_int = signal::cumulative_integral(&q.series.t, &p);
    q.scales.p_integral = q.p_int.last().copied().unwrap_or(0.0);
    let pos: Vec<f64> = p.iter().map(|&x| x.max(0.0)).collect();
    q.scales.p_pos_integral = signal::cumulative_integral(&q.series.t, &pos)
        .last()
        .copied()
        .unwrap_or(0.0);
    let (lo, hi) = p
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &x| {
            (lo.min(x), hi.max(x))
        });
    q.scales.p_range = hi - lo;
    q.p_sched = p.clone();
    q.series.p = p;
    q
}

/// `d` less its least-squares projection on the columns of `basis` along `series` (the part of a
/// difference a refitted polynomial cannot absorb); by the SVD's pseudo-inverse, so that columns
/// nearly dependent on a short motion do not fail it.
pub fn beyond_polynomial(series: &Series, basis: &PolyBasis, d: &[f64]) -> Vec<f64> {
    let cols = basis.columns(&series.v, &series.vdot);
    let (n, p) = (d.len(), cols.len());
    let x = nalgebra::DMatrix::from_fn(n, p, |i, j| cols[j][i]);
    let y = nalgebra::DVector::from_column_slice(d);
    let svd = x.clone().svd(true, true);
    let tol = svd.singular_values.max() * 1e-10;
    match svd.solve(&y, tol) {
        Ok(b) => {
            let fit = x * b;
            d.iter().zip(fit.iter()).map(|(a, b)| a - b).collect()
        }
        Err(_) => d.to_vec(),
    }
}

/// The expected paired z between two models' predictions `a` and `b` (kPa per sample) on a log
/// whose truth is one of them, with white noise `sigma` and the comparison over `share` of the
/// samples (module docs): `√(share · Σ(a − b)²) / (2σ)`. Zero for no samples; infinite for
/// `sigma ≤ 0` with a difference.
pub fn expected_z(a: &[f64], b: &[f64], sigma: f64, share: f64) -> f64 {
    let ss: f64 = a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum();
    if ss == 0.0 {
        return 0.0;
    }
    (share.max(0.0) * ss).sqrt() / (2.0 * sigma.max(0.0))
}

/// One alternative's expected separation from the kept effect by an experiment.
#[derive(Clone, Debug, Serialize)]
pub struct Separation {
    /// The alternative, as the report names it.
    pub alternative: String,
    /// Expected paired z on a log of the experiment ([`expected_z`], the difference beyond the
    /// polynomial).
    pub expected_z: f64,
    /// Its paired z on the log diagnosed, for comparison.
    pub z_on_this_log: f64,
    /// RMS of the two predictions' difference beyond the polynomial over the experiment, kPa.
    pub rms_difference: f64,
}

/// The experiment proposed for a kept effect with alternatives (module docs).
#[derive(Clone, Debug, Serialize)]
pub struct Experiment {
    /// The firmware's command lines, in order (after `origin` and, on a board, with telemetry
    /// recorded: `vfp record`).
    pub commands: Vec<String>,
    /// The `run` they are.
    pub run: Run,
    /// The motion, in words.
    pub family: String,
    /// Length of the strokes, s (plus the move to `v_low` first).
    pub duration_s: f64,
    /// The noise the separation is measured against, kPa.
    pub sigma: f64,
    /// Against each alternative.
    pub separations: Vec<Separation>,
    /// The smallest expected z over the alternatives (what the choice maximised).
    pub expected_z: f64,
    /// The same `run` as host-sim scenario lines (`[[commands]]`, to add to a scenario with the
    /// rig's `[plant]`: `vfp simulate --scenario`).
    pub scenario: String,
}

/// The grid the candidates are drawn from over `env` (module docs): stroke lengths, the lowest
/// and highest volume, the flow sets, the dwells; `None` when the envelope leaves no stroke.
struct Grid {
    lo: f64,
    hi: f64,
    strokes: Vec<f64>,
    flow_sets: Vec<Vec<f64>>,
    dwells: [u32; 3],
}

impl Grid {
    fn over(env: &Envelope) -> Option<Self> {
        let lo = env.v_min.max(0.0).ceil();
        let hi = env.v_max.floor();
        let span = hi - lo;
        let fmax = env.max_flow.min(MAX_FLOW).floor();
        if !(span >= MIN_STROKE && fmax >= 5.0) {
            return None;
        }
        let slow = (fmax / 5.0).round().max(1.0);
        let mut strokes: Vec<f64> = [0.125, 0.25, 0.5, 1.0]
            .iter()
            .map(|f| (span * f).round())
            .filter(|&a| a >= MIN_STROKE)
            .collect();
        strokes.dedup();
        Some(Self {
            lo,
            hi,
            strokes,
            flow_sets: vec![
                vec![fmax],
                vec![(fmax / 2.0).round()],
                vec![slow],
                vec![slow, fmax],
            ],
            dwells: [0, 200, 1000],
        })
    }

    /// Where a stroke of `a` mm³ may sit: at the bottom, the middle or the top of the range.
    fn lows(&self, a: f64) -> Vec<f64> {
        let mut lows = vec![
            self.lo,
            (self.lo + 0.5 * (self.hi - self.lo - a)).round(),
            self.hi - a,
        ];
        lows.dedup();
        lows
    }

    fn run(&self, v_low: f64, a: f64, flows: &[f64], dwell_ms: u32) -> Run {
        Run {
            v_low,
            v_high: v_low + a,
            cycles: 1,
            dwell_ms,
            flows: flows.to_vec(),
        }
    }
}

/// Predictions along candidate runs, each computed once for every effect that asks (the kept
/// model's is the same for all of them).
struct Predictions<'a> {
    basis: &'a PolyBasis,
    env: &'a Envelope,
    kept: &'a FittedModel,
    /// Per run: its columns prepared and the kept model's pressure along them.
    done: std::cell::RefCell<Vec<(Run, Option<Along>)>>,
}

/// A run's columns prepared, and the kept model's pressure along them.
type Along = std::rc::Rc<(Prepared, Vec<f64>)>;

impl Predictions<'_> {
    /// The run's columns prepared and the kept model's prediction along them, with `passes`.
    fn along(&self, run: &Run, passes: usize) -> Option<Along> {
        let (series, sub) = run.columns(self.env.rig);
        let prep = Prepared::new(series, self.basis.clone()).with_sub_flows(sub);
        let k = predict_in(&prep, self.kept, passes)?;
        Some(std::rc::Rc::new((prep, k)))
    }

    /// [`Self::along`] with one pass, each run's made once.
    fn kept_along(&self, run: &Run) -> Option<Along> {
        if let Some((_, r)) = self.done.borrow().iter().find(|(r, _)| r == run) {
            return r.clone();
        }
        let made = self.along(run, 1);
        self.done.borrow_mut().push((run.clone(), made.clone()));
        made
    }

    /// Each alternative's expected z and the RMS difference over `run` against the kept model
    /// (`None` where a model cannot be evaluated); `passes` as [`predict`]'s (1 to compare
    /// candidates, 2 for the one proposed).
    fn separations(
        &self,
        run: &Run,
        alts: &[&FittedModel],
        passes: usize,
    ) -> Option<Vec<(f64, f64)>> {
        let made = if passes == 1 {
            self.kept_along(run)?
        } else {
            self.along(run, passes)?
        };
        let (prep, k) = (&made.0, &made.1);
        alts.iter()
            .map(|m| {
                let a = predict_in(prep, m, passes)?;
                let d: Vec<f64> = k.iter().zip(&a).map(|(x, y)| x - y).collect();
                let d = beyond_polynomial(&prep.series, self.basis, &d);
                let zero = vec![0.0; d.len()];
                let rms = (d.iter().map(|x| x * x).sum::<f64>() / d.len() as f64).sqrt();
                Some((
                    expected_z(&d, &zero, self.env.sigma, self.env.held_share),
                    rms,
                ))
            })
            .collect()
    }

    /// The smallest expected z over `alts` of `run` (one cycle) repeated for [`BUDGET_S`].
    fn score(&self, run: &Run, alts: &[&FittedModel]) -> Option<f64> {
        let cycles = (BUDGET_S / run.cycle_s()).floor().clamp(1.0, 1000.0);
        let sep = self.separations(run, alts, 1)?;
        let z = sep.iter().map(|s| s.0).fold(f64::INFINITY, f64::min) * cycles.sqrt();
        z.is_finite().then_some(z)
    }
}

/// The experiment for a kept effect whose alternatives are `alts` (name, z on this log, model)
/// (module docs); `None` when the envelope leaves no stroke or no model can be evaluated. The
/// candidates are searched one coordinate at a time: the flows and dwell on a quarter-range
/// stroke in the middle, then with the best of them the stroke's length and place, then the
/// dwell again (about 25 candidates of the grid's 150).
fn propose_with(preds: &Predictions, alts: &[(&str, f64, &FittedModel)]) -> Option<Experiment> {
    let env = preds.env;
    if alts.is_empty() || env.sigma.is_nan() || env.sigma <= 0.0 {
        return None;
    }
    let grid = Grid::over(env)?;
    let models: Vec<&FittedModel> = alts.iter().map(|a| a.2).collect();
    let mut best: Option<(f64, Run)> = None;
    let consider = |best: &mut Option<(f64, Run)>, run: Run| {
        if let Some(z) = preds.score(&run, &models) {
            if best.as_ref().is_none_or(|b| z > b.0) {
                *best = Some((z, run));
            }
        }
    };
    let a0 = grid.strokes[grid.strokes.len().saturating_sub(1).min(1)];
    let mid = grid.lows(a0)[grid.lows(a0).len() / 2];
    for flows in &grid.flow_sets {
        for &dwell in &grid.dwells {
            consider(&mut best, grid.run(mid, a0, flows, dwell));
        }
    }
    let (flows, dwell) = best.as_ref().map(|b| (b.1.flows.clone(), b.1.dwell_ms))?;
    for &a in &grid.strokes {
        for v_low in grid.lows(a) {
            consider(&mut best, grid.run(v_low, a, &flows, dwell));
        }
    }
    let (v_low, a) = best.as_ref().map(|b| (b.1.v_low, b.1.v_high - b.1.v_low))?;
    for &d in &grid.dwells {
        consider(&mut best, grid.run(v_low, a, &flows, d));
    }
    let (z_budget, mut run) = best?;
    // As many cycles as reach the target z (z grows as the square root of the length), within
    // the shortest and longest lengths proposed.
    let per_cycle = z_budget / (BUDGET_S / run.cycle_s()).floor().clamp(1.0, 1000.0).sqrt();
    let c = run.cycle_s();
    let lo = (MIN_S / c).ceil().max(1.0);
    let hi = (MAX_S / c).floor().max(lo);
    run.cycles = ((TARGET_Z / per_cycle).powi(2).ceil()).clamp(lo, hi) as u32;
    let smallest = |sep: &[(f64, f64)]| sep.iter().map(|s| s.0).fold(f64::INFINITY, f64::min);
    let mut sep = preds.separations(&run, &models, 2)?;
    // An effect tied to the clock (a drift) separates faster than the square root of the
    // length: halve the cycles while the target is still reached (at most three times).
    for _ in 0..3 {
        let half = run.cycles / 2;
        if smallest(&sep) < 2.0 * TARGET_Z || (half as f64) < lo {
            break;
        }
        let shorter = Run {
            cycles: half,
            ..run.clone()
        };
        match preds.separations(&shorter, &models, 2) {
            Some(s) if smallest(&s) >= TARGET_Z => (run, sep) = (shorter, s),
            _ => break,
        }
    }
    let separations: Vec<Separation> = alts
        .iter()
        .zip(&sep)
        .map(|(a, s)| Separation {
            alternative: a.0.to_string(),
            expected_z: s.0,
            z_on_this_log: a.1,
            rms_difference: s.1,
        })
        .collect();
    let expected_z = separations
        .iter()
        .map(|s| s.expected_z)
        .fold(f64::INFINITY, f64::min);
    let line = run.line();
    let duration_s = (run.duration_s() * 1e3).round() / 1e3;
    let mut scenario = String::new();
    let _ = writeln!(
        scenario,
        "duration_s = {:.1}\nstop_on = \"protocol-done\"\n\n[[commands]]\nat_s = 1.5\nline = \"{line}\"",
        1.5 + duration_s + (run.v_high / 10.0).ceil() + 5.0
    );
    Some(Experiment {
        commands: vec![line],
        family: run.family(),
        run,
        duration_s,
        sigma: env.sigma,
        separations,
        expected_z,
        scenario,
    })
}

/// The experiment for a kept effect whose alternatives are `alts` (name, z on this log, model),
/// the final model `kept` in `basis`, over `env` (module docs); `None` when the envelope leaves
/// no stroke or no model can be evaluated.
pub fn propose(
    basis: &PolyBasis,
    env: &Envelope,
    kept: &FittedModel,
    alts: &[(&str, f64, &FittedModel)],
) -> Option<Experiment> {
    let preds = Predictions {
        basis,
        env,
        kept,
        done: Default::default(),
    };
    propose_with(&preds, alts)
}

/// The experiments of `d`'s kept effects that have alternatives, set on their reports; only on
/// this project's syringe rig, whose firmware runs the commands proposed.
pub fn attach(d: &mut Diagnosis) {
    let Some(kept) = d.models.last() else {
        return;
    };
    if d.rig != Rig::Syringe {
        return;
    }
    let preds = Predictions {
        basis: &d.basis,
        env: &d.envelope,
        kept,
        done: Default::default(),
    };
    let experiments: Vec<Option<Experiment>> = d
        .effects
        .iter()
        .map(|e| {
            let alts: Vec<(&str, f64, &FittedModel)> = e
                .alternatives
                .iter()
                .map(|a| (a.effect.as_str(), a.z, &a.model))
                .collect();
            propose_with(&preds, &alts)
        })
        .collect();
    for (e, x) in d.effects.iter_mut().zip(experiments) {
        e.experiment = x;
    }
}

/// One explanation scored on the second log.
#[derive(Clone, Debug, Serialize)]
pub struct Score {
    /// The kept effect's name, or the alternative's.
    pub explanation: String,
    /// Whether it is the loop's choice.
    pub kept: bool,
    /// Held-out RMSE on the second log, kPa.
    pub rmse_heldout: f64,
    /// Paired z of the kept model against it over the second log's held-out units (positive:
    /// the kept model's errors are the smaller; 0 for the kept one itself).
    pub z_kept_vs_this: f64,
}

/// What the second log says of one kept effect and its alternatives.
#[derive(Clone, Debug, Serialize)]
pub struct EffectDecision {
    /// The kept effect.
    pub effect: &'static str,
    /// It and each alternative.
    pub scores: Vec<Score>,
    /// The explanation the second log supports; `None`: it still cannot tell.
    pub supports: Option<String>,
    /// The explanation with the lowest held-out error.
    pub best: String,
    /// Its smallest paired z against the others (positive: its errors are the smaller).
    pub z: f64,
}

/// The decision on a second log (module docs).
#[derive(Clone, Debug, Serialize)]
pub struct Decision {
    /// The second log.
    pub log: String,
    /// Held-out units of its paired test.
    pub units: usize,
    /// Per kept effect with alternatives.
    pub effects: Vec<EffectDecision>,
}

/// Scores `d`'s kept effects with alternatives and the alternatives on `series` (the second
/// log's chamber with its own split), module docs. An error when `d` has no alternative, or the
/// second log is too short or its polynomial cannot be fitted.
pub fn decide(d: &Diagnosis, series: Series, log: String) -> Result<Decision, DiagnoseError> {
    let degenerate = |s: String| DiagnoseError::Degenerate(s);
    let kept = d
        .models
        .last()
        .ok_or_else(|| degenerate("no fitted model".into()))?;
    if d.effects.iter().all(|e| e.alternatives.is_empty()) {
        return Err(degenerate(
            "the log diagnosed has no kept effect with alternatives: there is nothing to decide"
                .into(),
        ));
    }
    let other = validate::OtherLog::new(d, series)?;
    let blocks = &other.blocks;
    let held = |m: &FittedModel| -> Option<Vec<f64>> {
        let effects: Vec<_> = m.effects.iter().map(|e| other.moved(e)).collect();
        other.held_errors(&effects)
    };
    let rmse = |e: &[f64]| other.rmse(e);
    let kept_sq = held(kept).ok_or_else(|| {
        degenerate("the final model's columns are dependent on the other log".into())
    })?;
    let mut effects = Vec::new();
    for e in d.effects.iter().filter(|e| !e.alternatives.is_empty()) {
        let mut errs: Vec<(String, bool, Vec<f64>)> = vec![(e.name.into(), true, kept_sq.clone())];
        for a in &e.alternatives {
            if let Some(sq) = held(&a.model) {
                errs.push((a.effect.clone(), false, sq));
            }
        }
        let scores: Vec<Score> = errs
            .iter()
            .map(|(name, is_kept, sq)| Score {
                explanation: name.clone(),
                kept: *is_kept,
                rmse_heldout: rmse(sq),
                z_kept_vs_this: if *is_kept {
                    0.0
                } else {
                    validate::paired_z(sq, &kept_sq, blocks)
                },
            })
            .collect();
        let b = (0..scores.len())
            .min_by(|&i, &j| scores[i].rmse_heldout.total_cmp(&scores[j].rmse_heldout))
            .unwrap_or(0);
        let z = (0..errs.len())
            .filter(|&j| j != b)
            .map(|j| validate::paired_z(&errs[j].2, &errs[b].2, blocks))
            .fold(f64::INFINITY, f64::min);
        effects.push(EffectDecision {
            effect: e.name,
            supports: (z >= ALT_Z).then(|| errs[b].0.clone()),
            best: errs[b].0.clone(),
            z,
            scores,
        });
    }
    Ok(Decision {
        log,
        units: blocks.len(),
        effects,
    })
}

/// [`decide`] on the first requested chamber of `data` (the other log, read as the first), with
/// its own split into training and held-out cycles.
pub fn decide_log(
    d: &Diagnosis,
    data: &crate::dataset::LogData,
) -> Result<Decision, super::LogDiagnoseError> {
    let ds = data.first();
    let wrap = |source| super::LogDiagnoseError {
        path: data.name(),
        chamber: ds.chamber,
        source,
    };
    let series = super::series_from_dataset(ds).map_err(wrap)?;
    decide(d, series, data.name()).map_err(wrap)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The separation by hand: predictions differing by 0.3 kPa on 4 samples and 0 on 4 more,
    /// σ = 0.1 kPa, the comparison over half the samples: Σd² = 4 · 0.09 = 0.36, half of it
    /// 0.18, z = √0.18 / 0.2 = 2.1213…; over every sample √0.36 / 0.2 = 3. Symmetric in the two
    /// models; no difference, no separation.
    #[test]
    fn the_expected_separation_by_hand() {
        let a = [1.3, 1.3, 1.3, 1.3, 2.0, 2.0, 2.0, 2.0];
        let b = [1.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0, 2.0];
        let z = expected_z(&a, &b, 0.1, 0.5);
        assert!((z - 0.18f64.sqrt() / 0.2).abs() < 1e-12, "{z}");
        assert!((expected_z(&a, &b, 0.1, 1.0) - 3.0).abs() < 1e-12);
        assert_eq!(expected_z(&b, &a, 0.1, 0.5), z);
        assert_eq!(expected_z(&a, &a, 0.1, 0.5), 0.0);
    }

    /// The trapezoid: a 100 mm³ move at 100 mm³/s and 500 mm³/s² accelerates for 0.2 s over
    /// 10 mm³, cruises 80 mm³ in 0.8 s, decelerates 0.2 s: 1.2 s. A 10 mm³ move never reaches
    /// 100 mm³/s: a triangle to √(500 · 10) = 70.7 mm³/s, 2 · 0.1414 s.
    #[test]
    fn the_profile_by_hand() {
        let (vp, ta, tc, t) = profile(100.0, 100.0);
        assert_eq!((vp, ta), (100.0, 0.2));
        assert!((tc - 0.8).abs() < 1e-12 && (t - 1.2).abs() < 1e-12);
        assert_eq!(along(100.0, 100.0, 0.2), (10.0, 100.0));
        assert!((along(100.0, 100.0, 0.7).0 - 60.0).abs() < 1e-12);
        assert_eq!(along(100.0, 100.0, 2.0), (100.0, 0.0));
        let (vp, _, tc, t) = profile(10.0, 100.0);
        assert!((vp - 5000f64.sqrt()).abs() < 1e-12 && tc == 0.0);
        assert!((t - 2.0 * 5000f64.sqrt() / 500.0).abs() < 1e-12);
    }

    /// The columns of a run: they start at rest at `v_low`, reach `v_high`, come back; the
    /// volume's increments match the mean flow over the frames (the flow column integrates to the
    /// volume) and the duration is the profile's.
    #[test]
    fn a_runs_columns_follow_its_profile() {
        let run = Run {
            v_low: 100.0,
            v_high: 200.0,
            cycles: 2,
            dwell_ms: 200,
            flows: vec![100.0],
        };
        assert!((run.duration_s() - 2.0 * 2.0 * 1.4).abs() < 1e-12);
        assert_eq!(run.line(), "run all 100 200 2 200 100");
        let s = run.series(Rig::Syringe);
        assert_eq!(s.v[0], 100.0);
        let top = s.v.iter().cloned().fold(f64::MIN, f64::max);
        assert!((top - 200.0).abs() < 1e-9, "{top}");
        assert!((s.v[s.len() - 1] - 100.0).abs() < 1e-9);
        let moved: f64 = s.vdot.iter().map(|q| q.abs()).sum::<f64>() * FRAME_S;
        assert!((moved - 400.0).abs() < 2.0, "{moved}");
        let t_end = REST_S + run.duration_s() + 0.5;
        assert!(
            (s.t[s.len() - 1] - t_end).abs() <= FRAME_S,
            "{}",
            s.t[s.len() - 1]
        );
    }
}
