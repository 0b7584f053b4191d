//! Pump ripple: the lead screw's pitch error makes the plunger run ahead of and behind the step
//! count once per screw turn, a volume error `δ = a sin 2πv/Λ + b cos 2πv/Λ` (Λ the volume per
//! turn). To first order it adds `k δ + c δ̇` to the pressure (k, c the model's stiffness and
//! damping, [`pump_ripple_columns`]); the search reads Λ off a periodogram of the residual against
//! volume ([`pump_ripple_periods`]), then applies what the columns found exactly as an input
//! transform `u = v + δ` ([`pump_ripple_inputs`]) by Gauss–Newton steps, with the phase taken at
//! the plunger, which the logged count trails by a lag fitted per cruise speed ([`CountLag`]).

use std::sync::Arc;

use super::ripple::amplitude;
use super::{
    build, param, Column, DeviceSupport, Effect, EffectModel, Fitted, Inputs, ModelView, Needs,
    Param, Prepared, Scales, Scan, Search,
};
use crate::residual::lsq;
use crate::residual::search::{fit_stage, with, Stage};
use crate::residual::signal::{self, Instants};

/// Ripple periodic in plunger position (lead-screw pitch error, once per screw turn).
pub struct PumpRipple;

impl EffectModel for PumpRipple {
    fn name(&self) -> &'static str {
        "pump_ripple"
    }

    fn story(&self) -> &'static str {
        "The lead screw's pitch error makes the plunger run ahead of and behind the step count once per screw turn, so pressure ripples periodically in volume (in time its frequency follows the flow): the stiffness times the volume error plus the damping times its rate."
    }

    fn generic(&self) -> Option<(&'static str, &'static str)> {
        Some((
            "periodic_in_volume",
            "The pressure ripples periodically in volume, at a period fixed in volume whatever the flow (in time, its frequency follows the flow): an input whose delivered volume runs ahead of and behind the logged one once per period. The name claims no more.",
        ))
    }

    fn search(&self, _sc: &Scales) -> Search {
        Search::VolumeSpectral
    }

    /// A period no longer than the volume range the log covers: a ripple periodic in volume is
    /// told from the law only by repeating; one whose period exceeds the whole range never shows
    /// a single period on the log, and over the range it is a smooth bend of the law in v (or a
    /// trend), which the polynomial and the other effects own. (The scan looks no further than a
    /// tenth of the range, [`pump_ripple_periods`]; this guards every other way a period is
    /// reached.) The sign of Λ only mirrors the phase: |Λ| is the period.
    fn unphysical(&self, e: &Effect, _coefs: &[f64], sc: &Scales) -> Option<String> {
        let period = e.theta.abs();
        if !period.is_finite() || period == 0.0 {
            return Some(format!(
                "its period in volume {:.4e} mm³ is not a period",
                e.theta
            ));
        }
        (period > sc.v_range).then(|| {
            format!(
                "its period in volume {period:.4e} mm³ is {:.1} times the volume range the log covers ({:.4e} mm³): the log does not show it even once",
                period / sc.v_range,
                sc.v_range
            )
        })
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn needs(&self) -> Needs {
        Needs {
            damping: true,
            stiffness: true,
        }
    }

    fn scan(&self, prep: &Prepared, resid: &[f64], trial: &Effect) -> Scan {
        let (Some(k), Some(c)) = (&trial.stiffness, &trial.damping) else {
            return Scan::default();
        };
        pump_ripple_periods(prep, resid, k, c)
    }

    /// The volume error the columns fitted applied exactly (`ripple_gauss_newton`), then the
    /// count lag at each cruise speed (`count_lag_gauss_newton`): the last effect whose fit
    /// lowered the training SSE, `None` where none did.
    fn refine(
        &self,
        prep: &Prepared,
        base: &[Effect],
        found: &Effect,
        model: &ModelView,
    ) -> Option<Effect> {
        let at = GaussNewton::of(found, model);
        let sse = at.sse;
        let at = ripple_gauss_newton(prep, base, at);
        let at = count_lag_gauss_newton(prep, base, at);
        (at.sse < sse).then_some(at.effect)
    }

    /// A count lag of 0 at each cruise speed where refinement fitted none (as it starts from).
    fn complete(&self, prep: &Prepared, e: &mut Effect) {
        if e.count_lag.lags.is_empty() {
            e.count_lag = CountLag::zero(prep.cruise_speeds.clone());
        }
    }

    fn input_stage(&self) -> Option<u32> {
        Some(30)
    }

    /// Only once the columns' first-order fit has been applied ([`Effect::ripple_offset`]).
    fn transforms_inputs(&self, e: &Effect) -> bool {
        e.ripple_offset != (0.0, 0.0)
    }

    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        let mut key = memo_key(e);
        key.push(u64::from(inputs.raw));
        let made = prep.memo_ripple(key, &[], Some((&inputs.v, &inputs.f)), || {
            let (lambda, ab, lag) = (e.theta, e.ripple_offset, &e.count_lag);
            if inputs.raw {
                return pump_ripple_inputs(&prep.subframe(), lambda, ab, lag);
            }
            let edges = signal::ppm_edges(&inputs.f);
            let sub = signal::FrameMotion::new(&prep.series.t, &inputs.v, &inputs.f, &edges);
            pump_ripple_inputs(&sub, lambda, ab, lag)
        });
        (inputs.v, inputs.f) = (made.0.clone(), made.1.clone());
    }

    fn columns(&self, e: &Effect, prep: &Prepared, _v: &[f64]) -> Vec<Column> {
        let zero = Arc::new(vec![0.0; prep.series.len()]);
        let k = e.stiffness.as_ref().unwrap_or(&zero);
        let c = e.damping.as_ref().unwrap_or(&zero);
        let make = || pump_ripple_columns(&prep.subframe(), k, c, e.theta, &e.count_lag);
        let (a, b) = match (&e.stiffness, &e.damping) {
            (Some(k), Some(c)) => {
                let made = prep.memo_ripple(memo_key(e), &[k, c], None, make);
                (made.0.clone(), made.1.clone())
            }
            _ => make(),
        };
        vec![
            Column::new(a, "pump ripple in phase"),
            Column::new(b, "pump ripple quadrature"),
        ]
    }

    fn nonnegative(&self, name: &str) -> bool {
        name == "amplitude"
    }
    fn presence(&self) -> Option<&'static str> {
        Some("amplitude")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        // The columns carry the correction to the volume error δ already applied: a, b in mm³.
        let e = f.effect;
        let (amp, se) = amplitude(f, e.ripple_offset);
        let mut ps = vec![
            param("period", e.theta, f.theta_se, "mm3"),
            param("amplitude", amp, se, "mm3"),
        ];
        let lag = &e.count_lag;
        for (i, (&l, &se)) in lag.lags.iter().zip(&lag.se).enumerate() {
            ps.push(match lag.speeds.get(i) {
                Some(s) => param(&format!("count_lag_at_{s:.3}_mm3_s"), l, se, "mm3"),
                None => param("count_lag", l, se, "mm3"),
            });
        }
        ps
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::host_only("the loop's form needs the exact volume transform and a count lag per cruise speed; the board's chain has only the first-order ripple at the step count, which on host-sim's ripple preset fitted 0.61 kPa held out against the loop's 0.17 (baseline 0.25)")
    }
}

/// What a pump ripple's columns and input transform are made from, besides the data: its period,
/// the volume error already applied, and its count lag (speeds and lags), as bits
/// ([`Prepared::memo_ripple`]).
fn memo_key(e: &Effect) -> Vec<u64> {
    let lag = &e.count_lag;
    let mut key = vec![
        e.theta.to_bits(),
        e.ripple_offset.0.to_bits(),
        e.ripple_offset.1.to_bits(),
        lag.speeds.len() as u64,
    ];
    key.extend(lag.speeds.iter().chain(&lag.lags).map(|x| x.to_bits()));
    key
}

/// Where the Gauss–Newton steps of a pump ripple's refinement stand: the effect last fitted, the
/// volume error `(a, b)` (mm³) of that fit (what is applied exactly as an input transform plus the
/// first-order correction its two columns fitted) and its training SSE.
struct GaussNewton {
    effect: Effect,
    error: (f64, f64),
    sse: f64,
}

impl GaussNewton {
    /// The pump ripple `e`, last in the fitted model `model`.
    fn of(e: &Effect, model: &ModelView) -> Self {
        let coefs = model.coefs(model.effects.len() - 1);
        let off = e.ripple_offset;
        Self {
            effect: e.clone(),
            error: (off.0 + coefs[0], off.1 + coefs[1]),
            sse: model.sse,
        }
    }

    /// The pump ripple last in `stage`.
    fn fitted(stage: &Stage) -> Self {
        let last = stage.effects.len() - 1;
        Self::of(&stage.effects[last], &stage.view())
    }
}

/// How far (mm³) a logged step count trails the plunger while it moves, which shifts a pump
/// ripple's phase one way on inflation and the other on deflation.
///
/// A count trails continuous motion by up to one step, and by how much depends on the step rate:
/// the firmware reads the count at each of a frame's conversions, and where the step period
/// divides the conversion period (2 000 steps/s against 200 conversions/s) every conversion reads
/// the same fraction of a step; at other rates the fractions spread out and average to about
/// half a step. So the lag is one number per speed the log dwells at (its cruise speeds,
/// [`cruise_speeds`]), interpolated linearly in |v̇| between them and held beyond; a log without
/// plateaus of speed gets one lag for all speeds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CountLag {
    /// Speeds |v̇| (mm³/s, ascending) the lags are given at; empty: one lag for every speed.
    pub speeds: std::sync::Arc<Vec<f64>>,
    /// The lag at each speed (or the one lag), mm³; empty: no lag.
    pub lags: Vec<f64>,
    /// Standard error of each lag from the last linearised fit, mm³.
    pub se: Vec<f64>,
}

impl CountLag {
    /// No lag, to be fitted at `speeds` (one lag when `speeds` is empty).
    pub fn zero(speeds: std::sync::Arc<Vec<f64>>) -> Self {
        let n = speeds.len().max(1);
        Self {
            speeds,
            lags: vec![0.0; n],
            se: vec![f64::NAN; n],
        }
    }

    /// Linear-interpolation weights of the lags at `speed`: `(i, j, f)` with the lag
    /// `(1 − f)·lags[i] + f·lags[j]`.
    pub fn weights(&self, speed: f64) -> (usize, usize, f64) {
        let s = &self.speeds;
        if s.len() <= 1 {
            return (0, 0, 0.0);
        }
        match s.iter().position(|&k| k >= speed) {
            Some(0) => (0, 0, 0.0),
            None => (s.len() - 1, s.len() - 1, 0.0),
            Some(j) => (j - 1, j, (speed - s[j - 1]) / (s[j] - s[j - 1])),
        }
    }

    /// The lag at `speed`, mm³.
    pub fn at(&self, speed: f64) -> f64 {
        if self.lags.is_empty() {
            return 0.0;
        }
        let (i, j, f) = self.weights(speed);
        (1.0 - f) * self.lags[i] + f * self.lags[j]
    }
}

/// The speeds |v̇| (mm³/s, ascending) a log dwells at: clusters of frames whose flow is flat
/// (within 0.1 % of the top speed of both neighbours) and moving (above 2 % of it), clusters 1 %
/// of the top speed wide holding at least 2 % of the flat frames (and 25). At most 8, the most
/// populated; none when the flow has no plateaus (a ventilator's, say).
pub fn cruise_speeds(vdot: &[f64]) -> Vec<f64> {
    let top = vdot.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    if top <= 0.0 || vdot.len() < 3 {
        return Vec::new();
    }
    let mut flat: Vec<f64> = (1..vdot.len() - 1)
        .filter(|&k| {
            vdot[k].abs() > 0.02 * top
                && (vdot[k] - vdot[k - 1]).abs() <= 1e-3 * top
                && (vdot[k + 1] - vdot[k]).abs() <= 1e-3 * top
        })
        .map(|k| vdot[k].abs())
        .collect();
    flat.sort_by(f64::total_cmp);
    let min_size = 25.max(flat.len() / 50);
    let mut clusters: Vec<(usize, f64)> = Vec::new();
    let mut start = 0;
    for k in 1..=flat.len() {
        if k == flat.len() || flat[k] - flat[k - 1] > 0.01 * top {
            if k - start >= min_size {
                clusters.push((k - start, flat[(start + k) / 2]));
            }
            start = k;
        }
    }
    clusters.sort_by_key(|c| std::cmp::Reverse(c.0));
    clusters.truncate(8);
    let mut speeds: Vec<f64> = clusters.into_iter().map(|c| c.1).collect();
    speeds.sort_by(f64::total_cmp);
    speeds
}

/// The pump ripple's two columns for period `lambda` (mm³): the pressure a volume error
/// `δ = a sin φ + b cos φ`, `φ = 2π v/Λ`, makes to first order through the model's stiffness k and
/// damping c, `k δ + c δ̇` with `δ̇ = (2π/Λ) v̇ (a cos φ − b sin φ)`, averaged over each frame's
/// instants (at 100 mm³/s an 8 mm³ period is 12.5 Hz, half the frame rate: the frame mean of the
/// ripple is a fraction of its amplitude, which the average reproduces).
pub fn pump_ripple_columns(
    sub: &impl Instants,
    k: &[f64],
    c: &[f64],
    lambda: f64,
    count_lag: &CountLag,
) -> (Vec<f64>, Vec<f64>) {
    let w = std::f64::consts::TAU / lambda;
    let ns = signal::SUB_SAMPLES;
    let n = k.len();
    let (mut a, mut b) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut f = 0;
    sub.each_frame(|xs, qs| {
        if f >= n {
            return;
        }
        let (mut sa, mut sb) = (0.0, 0.0);
        let mut turn = Turn::default();
        for (&x, &v) in xs.iter().zip(qs) {
            let (sin, cos) = turn.at(w * plunger(x, v, count_lag));
            let q = c[f] * w * v;
            sa += k[f] * sin + q * cos;
            sb += k[f] * cos - q * sin;
        }
        a.push(sa / ns as f64);
        b.push(sb / ns as f64);
        f += 1;
    });
    (a, b)
}

/// The sine and cosine of a frame's phases, one instant after another: the first (and any that
/// moves more than [`Turn::STEP`] radians from the one before) by `sin_cos`, the others by
/// rotating the one before through the small difference, whose sine and cosine are their Taylor
/// series to the 11th and 12th power (remainder below 1e-17 at 0.25 rad). A frame's eight
/// instants lie close in phase on all but the shortest periods, and the columns and the input
/// transform are recomputed at every trial of a search or re-tune: `sin_cos` was a sixth of a
/// ripple rig's CPU. Rounding adds about 1e-16 per rotation, restarted at each frame.
#[derive(Default)]
struct Turn {
    /// The last phase and its sine and cosine, once there is one.
    last: Option<(f64, f64, f64)>,
}

impl Turn {
    /// Largest phase difference (rad) taken by rotation.
    const STEP: f64 = 0.25;

    /// `(sin φ, cos φ)`.
    fn at(&mut self, phi: f64) -> (f64, f64) {
        let sc = match self.last {
            Some((p, s, c)) if (phi - p).abs() <= Self::STEP => {
                let d = phi - p;
                let d2 = d * d;
                // Horner's rule on the series' coefficients (constants, no division).
                let sd = d + d
                    * d2
                    * (-1.0 / 6.0
                        + d2 * (1.0 / 120.0
                            + d2 * (-1.0 / 5040.0
                                + d2 * (1.0 / 362_880.0 + d2 * (-1.0 / 39_916_800.0)))));
                let cd = 1.0
                    + d2 * (-0.5
                        + d2 * (1.0 / 24.0
                            + d2 * (-1.0 / 720.0
                                + d2 * (1.0 / 40_320.0
                                    + d2 * (-1.0 / 3_628_800.0 + d2 * (1.0 / 479_001_600.0))))));
                (s * cd + c * sd, c * cd - s * sd)
            }
            _ => phi.sin_cos(),
        };
        self.last = Some((phi, sc.0, sc.1));
        sc
    }
}

/// The plunger's position where the logged volume `x` trails it by `count_lag` in the direction
/// of motion `q`.
fn plunger(x: f64, q: f64, count_lag: &CountLag) -> f64 {
    if q == 0.0 {
        x
    } else {
        x + count_lag.at(q.abs()) * q.signum()
    }
}

/// The derivatives of a pump ripple's pressure `k δ + c δ̇` with respect to each of `count_lag`'s
/// lags (one column each), for the volume error `δ = a sin φ + b cos φ`, `φ = 2π x/Λ` at the
/// plunger, averaged over each frame's instants: shifting the plunger by `ℓ` in the direction of
/// motion `s = sign q` gives `∂δ/∂ℓ = s w (a cos φ − b sin φ)` and
/// `∂δ̇/∂ℓ = −s w² q (a sin φ + b cos φ)`, `w = 2π/Λ`, each weighted by the lag's share at the
/// instant's speed. One Gauss–Newton step in the lags fits these columns with the model.
pub fn count_lag_columns(
    sub: &impl Instants,
    k: &[f64],
    c: &[f64],
    lambda: f64,
    (a, b): (f64, f64),
    count_lag: &CountLag,
) -> Vec<Vec<f64>> {
    let w = std::f64::consts::TAU / lambda;
    let ns = signal::SUB_SAMPLES;
    let n = k.len();
    let mut cols = vec![vec![0.0; n]; count_lag.lags.len()];
    let mut f = 0;
    sub.each_frame(|xs, qs| {
        if f >= n {
            return;
        }
        let mut turn = Turn::default();
        for (&x, &q) in xs.iter().zip(qs) {
            if q == 0.0 {
                continue;
            }
            let (sin, cos) = turn.at(w * plunger(x, q, count_lag));
            let d =
                q.signum() * w * (k[f] * (a * cos - b * sin) - c[f] * w * q * (a * sin + b * cos))
                    / ns as f64;
            let (i0, i1, fr) = count_lag.weights(q.abs());
            cols[i0][f] += (1.0 - fr) * d;
            cols[i1][f] += fr * d;
        }
        f += 1;
    });
    cols
}

/// Frame means of the displaced volume `u = x + a sin φ + b cos φ`, `φ = 2π x/Λ`, and its rate
/// `u̇ = ẋ (1 + (2π/Λ)(a cos φ − b sin φ))`, over the instants of each frame
/// (`signal::FrameMotion`): at 100 mm³/s an 8 mm³ period is 12.5 Hz, and the flow ripple
/// (±16 % for 0.2 mm³) must be averaged where it happens, not at the frame's mean volume.
fn pump_ripple_inputs(
    sub: &impl Instants,
    lambda: f64,
    ab: (f64, f64),
    count_lag: &CountLag,
) -> (Vec<f64>, Vec<f64>) {
    let n = sub.frames();
    let (mut u, mut ud) = (Vec::with_capacity(n), Vec::with_capacity(n));
    sub.each_frame(|xs, qs| {
        let (a, b) = ripple_frame(xs, qs, lambda, ab, count_lag);
        u.push(a);
        ud.push(b);
    });
    (u, ud)
}

/// [`pump_ripple_inputs`] of one frame, its instants `xs` with flows `qs`.
fn ripple_frame(
    xs: &[f64],
    qs: &[f64],
    lambda: f64,
    (a, b): (f64, f64),
    count_lag: &CountLag,
) -> (f64, f64) {
    let w = std::f64::consts::TAU / lambda;
    let ns = signal::SUB_SAMPLES as f64;
    let (mut u, mut ud) = (0.0, 0.0);
    let mut turn = Turn::default();
    for (&x, &q) in xs.iter().zip(qs) {
        let (sin, cos) = turn.at(w * plunger(x, q, count_lag));
        u += x + a * sin + b * cos;
        ud += q * (1.0 + w * (a * cos - b * sin));
    }
    (u / ns, ud / ns)
}

/// Candidate periods (mm³) of a pump ripple in `resid`, best first, with the spacing of the
/// spatial-frequency grid they came from (1/mm³, [`Scan::step`]): a periodogram against volume over spatial
/// frequencies `1/Λ` from `1/(0.1·range)` up to two periods per frame of median motion, on a
/// uniform grid fine enough that the phase drifts by at most a quarter turn over the stroke (at
/// most [`RIPPLE_SCAN_STEPS`] steps), scored by the residual energy the two columns (at the frames'
/// mean volumes, on at most ~3,000 training frames) capture. Returns up to three local maxima.
pub fn pump_ripple_periods(prep: &Prepared, resid: &[f64], k: &[f64], c: &[f64]) -> Scan {
    let se = &prep.series;
    let mut moving: Vec<f64> = se
        .vdot
        .iter()
        .map(|f| f.abs())
        .filter(|&f| f > 1e-9)
        .collect();
    if moving.is_empty() {
        return Scan::default();
    }
    moving.sort_by(f64::total_cmp);
    let flow = moving[moving.len() / 2];
    let range = prep.scales.v_range;
    let lo = (0.5 * flow * prep.scales.dt).max(1e-6 * range);
    let hi = 0.1 * range;
    if lo >= hi {
        return Scan::default();
    }
    let (k_lo, k_hi) = (1.0 / hi, 1.0 / lo);
    let steps = ((k_hi - k_lo) * 4.0 * range)
        .ceil()
        .min(RIPPLE_SCAN_STEPS as f64) as usize;
    let dk = (k_hi - k_lo) / steps as f64;
    let stride = (prep.train_rows.len() / 3000).max(1);
    let rows: Vec<usize> = prep.train_rows.iter().copied().step_by(stride).collect();
    // Per row: the phase 2πκv as a unit complex number, advanced along the grid by a fixed
    // rotation (4 multiplications per step instead of a sine and a cosine).
    let tau = std::f64::consts::TAU;
    let mut z: Vec<(f64, f64)> = rows
        .iter()
        .map(|&r| {
            let (s, c) = (tau * k_lo * se.v[r]).sin_cos();
            (c, s)
        })
        .collect();
    let rot: Vec<(f64, f64)> = rows
        .iter()
        .map(|&r| {
            let (s, c) = (tau * dk * se.v[r]).sin_cos();
            (c, s)
        })
        .collect();
    let mut power = Vec::with_capacity(steps + 1);
    for i in 0..=steps {
        let w = tau * (k_lo + i as f64 * dk);
        let (mut g0, mut g1, mut a00, mut a01, mut a11) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (j, &r) in rows.iter().enumerate() {
            let (cos, sin) = z[j];
            let q = c[r] * w * se.vdot[r];
            let x0 = k[r] * sin + q * cos;
            let x1 = k[r] * cos - q * sin;
            g0 += x0 * resid[r];
            g1 += x1 * resid[r];
            a00 += x0 * x0;
            a01 += x0 * x1;
            a11 += x1 * x1;
            let (rc, rs) = rot[j];
            z[j] = (cos * rc - sin * rs, sin * rc + cos * rs);
        }
        let det = a00 * a11 - a01 * a01;
        power.push(if det <= 1e-12 * (a00 * a11).max(f64::MIN_POSITIVE) {
            0.0
        } else {
            (a11 * g0 * g0 - 2.0 * a01 * g0 * g1 + a00 * g1 * g1) / det
        });
    }
    Scan {
        starts: top_periods(&power, k_lo, dk),
        step: dk,
    }
}

/// The periods 1/κ of the three highest local maxima of `power` on the grid κ = k_lo + i·dk,
/// highest first.
fn top_periods(power: &[f64], k_lo: f64, dk: f64) -> Vec<f64> {
    let mut peaks: Vec<usize> = (1..power.len().saturating_sub(1))
        .filter(|&i| power[i] > power[i - 1] && power[i] >= power[i + 1])
        .collect();
    peaks.sort_by(|&a, &b| power[b].total_cmp(&power[a]));
    peaks
        .into_iter()
        .take(3)
        .map(|i| 1.0 / (k_lo + i as f64 * dk))
        .collect()
}

/// Most spatial frequencies the pump-ripple periodogram scans.
pub const RIPPLE_SCAN_STEPS: usize = 6000;

/// The pump ripple's two columns fit the volume error to first order (stiffness × δ + damping ×
/// δ̇); apply what they found exactly, as an input transform, and fit what is left: a few
/// Gauss–Newton steps, kept while the training SSE falls by more than 0.1 %.
fn ripple_gauss_newton(prep: &Prepared, base: &[Effect], mut at: GaussNewton) -> GaussNewton {
    for _ in 0..4 {
        let mut e = at.effect.clone();
        e.ripple_offset = at.error;
        match fit_stage(prep, &with(base, e)) {
            Some(next) if next.fit.sse < at.sse => {
                let small = next.fit.sse > (1.0 - 1e-3) * at.sse;
                at = GaussNewton::fitted(&next);
                if small {
                    break;
                }
            }
            _ => break,
        }
    }
    at
}

/// How far the logged count trails the plunger at each cruise speed ([`CountLag`]): Gauss–Newton
/// steps on the lags, each fitting their derivative columns
/// ([`count_lag_columns`]) together with the model, applying the step, and
/// refitting the ripple's amplitude; kept while the training SSE falls by more than 0.1 %. The
/// last step's standard errors are the lags'. The lags start at 0 ([`PumpRipple::complete`]);
/// where no step is kept, `at` is returned as it came.
fn count_lag_gauss_newton(prep: &Prepared, base: &[Effect], mut at: GaussNewton) -> GaussNewton {
    let mut from = at.effect.clone();
    PumpRipple.complete(prep, &mut from);
    for _ in 0..4 {
        let e = from.clone();
        let (Some(k), Some(c)) = (&e.stiffness, &e.damping) else {
            break;
        };
        let extra = count_lag_columns(&prep.subframe(), k, c, e.theta, at.error, &e.count_lag);
        // The design lives only for this fit: the refit below builds its own.
        let (p0, fit) = {
            let mut design = build(prep, &with(base, e.clone()));
            let p0 = design.cols.len();
            design.cols.extend(extra);
            (p0, lsq::fit(&design.cols, &prep.series.p, &prep.train_rows))
        };
        let Some(fit) = fit else {
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
            Some(next) if next.fit.sse < at.sse => {
                let small = next.fit.sse > (1.0 - 1e-3) * at.sse;
                at = ripple_gauss_newton(prep, base, GaussNewton::fitted(&next));
                from = at.effect.clone();
                if small {
                    break;
                }
            }
            _ => break,
        }
    }
    at
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_turn_gives_sine_and_cosine_to_rounding() {
        // Phases as a frame's instants give them: steps below and above the rotation's limit,
        // both signs, far from zero (a long stroke over a short period).
        let mut turn = super::Turn::default();
        let (mut phi, mut worst) = (1234.5_f64, 0.0_f64);
        for k in 0..20_000 {
            phi +=
                [0.01, -0.2, 0.249, 0.26, -1.7, 3e-9, 0.0][k % 7] * (1.0 + (k % 13) as f64 / 50.0);
            let (s, c) = turn.at(phi);
            let (es, ec) = phi.sin_cos();
            worst = worst.max((s - es).abs()).max((c - ec).abs());
            if k % 8 == 7 {
                turn = super::Turn::default();
            }
        }
        assert!(worst < 2e-15, "{worst:e}");
    }

    use super::*;
    use crate::residual::effects::EffectKind;

    /// The period rule against the log's own volume range: `fast_tones` swings 275 ± (150 + 60)
    /// mm³ at most, so its range is measured off the data (an independent number), and a period
    /// just beyond it is refused with both numbers named, one just inside it or the lead screw's
    /// 8 mm³ is not; a non-finite period never stands.
    #[test]
    fn a_period_longer_than_the_volume_range_is_not_kept() {
        let prep = crate::residual::test_plant::plant(3000, &[], |_| 0.0, 0.01);
        let v = &prep.series.v;
        let range = v.iter().fold(f64::NEG_INFINITY, |m, &x| m.max(x))
            - v.iter().fold(f64::INFINITY, |m, &x| m.min(x));
        assert!((prep.scales.v_range - range).abs() < 1e-9 * range);
        let kind = EffectKind(&PumpRipple);
        let judge =
            |period: f64| kind.unphysical(&Effect::new(kind, period), &[0.1, 0.1], &prep.scales);
        let why = judge(1.2 * range).expect("longer than the range");
        assert!(why.contains("1.2 times the volume range"), "{why}");
        assert!(why.contains(&format!("{range:.4e}")), "{why}");
        // The sign only mirrors the phase.
        assert!(judge(-1.2 * range).is_some());
        assert_eq!(judge(0.99 * range), None);
        assert_eq!(judge(8.0), None);
        assert_eq!(judge(-8.0), None);
        assert!(judge(f64::INFINITY).is_some());
        assert!(judge(f64::NAN).is_some());
    }

    #[test]
    fn cruise_speeds_are_the_plateaus_of_the_flow() {
        // 25 Hz: plateaus at +20, −20, +50 and −90 mm³/s joined by 500 mm³/s² ramps, dwell at 0.
        let mut f = Vec::new();
        let mut q: f64 = 0.0;
        for target in [20.0, 0.0, -20.0, 0.0, 50.0, 0.0, -90.0, 0.0] {
            while (q - target).abs() > 1e-9 {
                q += (target - q).clamp(-20.0, 20.0);
                f.push(q);
            }
            f.extend(std::iter::repeat_n(target, 100));
        }
        let s = cruise_speeds(&f);
        assert_eq!(s.len(), 3, "{s:?}");
        for (got, want) in s.iter().zip([20.0, 50.0, 90.0]) {
            assert!((got - want).abs() < 1e-9, "{s:?}");
        }
        // A breathing flow has no plateaus.
        let sine: Vec<f64> = (0..2000).map(|k| 80.0 * (0.05 * k as f64).sin()).collect();
        assert!(cruise_speeds(&sine).is_empty());
    }

    #[test]
    fn count_lag_interpolates_between_speeds_and_holds_beyond() {
        let lag = CountLag {
            speeds: std::sync::Arc::new(vec![20.0, 40.0, 80.0]),
            lags: vec![0.01, 0.03, -0.01],
            se: vec![f64::NAN; 3],
        };
        for (s, want) in [
            (5.0, 0.01),
            (20.0, 0.01),
            (30.0, 0.02),
            (60.0, 0.01),
            (200.0, -0.01),
        ] {
            assert!((lag.at(s) - want).abs() < 1e-15, "{s}: {}", lag.at(s));
        }
        let one = CountLag {
            lags: vec![0.02],
            ..CountLag::zero(std::sync::Arc::new(Vec::new()))
        };
        assert_eq!((one.at(3.0), one.at(300.0)), (0.02, 0.02));
        assert_eq!(CountLag::default().at(50.0), 0.0);
    }

    #[test]
    fn count_lag_columns_are_the_derivatives_of_the_ripple_pressure() {
        // Against central differences of the ripple's pressure a·A + b·B, (A, B) the columns of
        // `pump_ripple_columns`, in each lag.
        let n = 400;
        let t: Vec<f64> = (0..n).map(|k| 0.04 * k as f64).collect();
        let f: Vec<f64> = (0..n)
            .map(|k| match k / 100 {
                0 => 30.0,
                1 => -60.0,
                2 => 90.0,
                _ => -30.0,
            })
            .collect();
        let mut v = vec![100.0; n];
        for k in 1..n {
            v[k] = v[k - 1] + 0.02 * (f[k - 1] + f[k]);
        }
        let sub = signal::frame_instants(&t, &v, &f);
        let k: Vec<f64> = (0..n).map(|i| 0.05 + 1e-4 * i as f64).collect();
        let c: Vec<f64> = (0..n).map(|i| 0.1 - 1e-4 * i as f64).collect();
        let (lambda, ab) = (8.0, (0.2, -0.07));
        let lag = CountLag {
            speeds: std::sync::Arc::new(vec![30.0, 60.0, 90.0]),
            lags: vec![0.01, 0.02, 0.03],
            se: vec![f64::NAN; 3],
        };
        let pressure = |lag: &CountLag| {
            let (a, b) = pump_ripple_columns(&sub, &k, &c, lambda, lag);
            a.iter()
                .zip(&b)
                .map(|(a, b)| ab.0 * a + ab.1 * b)
                .collect::<Vec<f64>>()
        };
        let cols = count_lag_columns(&sub, &k, &c, lambda, ab, &lag);
        let h = 1e-6;
        for i in 0..3 {
            let (mut up, mut down) = (lag.clone(), lag.clone());
            up.lags[i] += h;
            down.lags[i] -= h;
            let (pu, pd) = (pressure(&up), pressure(&down));
            let scale = cols[i].iter().fold(0.0_f64, |m, x| m.max(x.abs()));
            assert!(scale > 0.1, "lag {i} moves the pressure");
            for r in 0..n {
                let fd = (pu[r] - pd[r]) / (2.0 * h);
                assert!(
                    (fd - cols[i][r]).abs() < 1e-6 * scale,
                    "lag {i}, frame {r}: {fd} vs {}",
                    cols[i][r]
                );
            }
        }
    }
}
