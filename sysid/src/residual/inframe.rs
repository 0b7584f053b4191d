//! Inside a frame: the motion rebuilt at the instants a frame averages, and first-order lags run
//! over those instants and averaged back, as an averaging sensor reports a lagged pressure.
//!
//! A frame is the mean of the sensor's conversions spread evenly over its interval, so a sensor
//! (or air-pocket) lag acts *inside* the frame and the board reports
//!
//! ```text
//! P̄_k = (1/S) Σ_j y(t_kj),   τ ẏ + y = P(v(t), v̇(t)),   t_kj = t_k + Δ_k((j + ½)/S − ½).
//! ```
//!
//! When the flow changes within a frame (a move starting, a short move's triangle of flow), the
//! lag weights the frame's late part more than its early part, so the lagged frame depends on
//! where in the frame the change happened, which the frame means alone do not say. A stepper's
//! motion plan changes its flow by constant accelerations: the flow is piecewise linear with few
//! corners. [`sparse_motion`] therefore rebuilds the flow at the instants `t_kj` as the one with
//! the frame means logged whose second differences are sparsest (least `Σ|Δ²q|`, by iteratively
//! reweighted least squares), and the volume by integrating it, placed on each frame's mean.
//! [`LagChain`] runs lags over those instants and averages each frame back.

use super::signal::{foh, SUB_SAMPLES};

/// Instants per frame (the firmware's oversampling, as [`SUB_SAMPLES`]).
const S: usize = SUB_SAMPLES;

/// The motion at [`SUB_SAMPLES`] instants per frame, kept as the flow there (S numbers per
/// frame); the instants and volumes are made a frame at a time from the log's frame times and
/// volumes ([`frame_instants`], [`SubMotion::volumes`]).
#[derive(Clone, Debug, Default)]
pub struct SubMotion {
    /// Flow at frame k's instants at `k·S ..`, mm³/s.
    pub f: Vec<f64>,
}

impl SubMotion {
    /// Frame k's flows at its instants.
    pub fn flows(&self, k: usize) -> [f64; S] {
        std::array::from_fn(|j| self.f[k * S + j])
    }

    /// Each frame's mean of the acceleration over the instants it averages (frame times `t`):
    /// at each instant the rebuilt flow's centred difference over its neighbouring instants
    /// (across frame boundaries; one-sided at the log's ends), averaged over the frame,
    ///
    /// ```text
    /// ā_k = (1/S) Σ_j (q(t_k,j+1) − q(t_k,j−1)) / (t_k,j+1 − t_k,j−1),
    /// ```
    ///
    /// which on evenly spaced instants is the rebuilt flow's change across the frame's span over
    /// the span: what an averaging sensor reports of a term `L·v̈`. The Hermite acceleration at
    /// the frame (`signal::acceleration_hermite`), the second derivative of the cubic through
    /// the frame means, is not that mean: on trapezoid moves (500 mm³/s², ramps of 0.5–3 frames)
    /// it spreads a ramp's acceleration over the neighbouring frames, and the coefficient fitted
    /// on it came out 5–20 % short on the loop benchmark (issue 34). The rebuild's limit is this
    /// one's: a move shorter than about two frames (a triangle of flow) is rebuilt flatter than
    /// it was (a 60 ms triangle to 15 mm³/s: 157 mm³/s² where the frame's mean was 361).
    pub fn frame_mean_accelerations(&self, t: &[f64]) -> Vec<f64> {
        let n = t.len();
        let m = self.f.len().min(n * S);
        if n < 2 || m < n * S {
            return vec![0.0; n];
        }
        let inst: Vec<f64> = (0..n).flat_map(|k| frame_instants(t, k)).collect();
        let slope = |i: usize| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(m - 1));
            let dt = inst[b] - inst[a];
            if dt > 0.0 {
                (self.f[b] - self.f[a]) / dt
            } else {
                0.0
            }
        };
        (0..n)
            .map(|k| (0..S).map(|j| slope(k * S + j)).sum::<f64>() / S as f64)
            .collect()
    }

    /// Frame k's volumes at its instants (frame times `t`, logged volumes `v`): the flow's
    /// trapezoidal integral over the frame, shifted so that its mean over the frame is `v[k]`.
    pub fn volumes(&self, t: &[f64], v: &[f64], k: usize) -> [f64; S] {
        let ts = frame_instants(t, k);
        let q = self.flows(k);
        let mut x = [0.0; S];
        for j in 1..S {
            x[j] = x[j - 1] + 0.5 * (q[j] + q[j - 1]) * (ts[j] - ts[j - 1]);
        }
        let shift = v[k] - x.iter().sum::<f64>() / S as f64;
        x.map(|x| x + shift)
    }
}

/// The span a frame averages over: half the distance between its neighbours (a whole interval
/// at the ends; 0 for a single frame).
pub fn frame_span(t: &[f64], k: usize) -> f64 {
    let n = t.len();
    match (k.checked_sub(1), (k + 1 < n).then_some(k + 1)) {
        (Some(a), Some(b)) => 0.5 * (t[b] - t[a]),
        (None, Some(b)) => t[b] - t[k],
        (Some(a), None) => t[k] - t[a],
        (None, None) => 0.0,
    }
}

/// Frame k's instants `t_kj = t_k + Δ_k((j + ½)/S − ½)`, spread evenly over its span Δ_k.
pub fn frame_instants(t: &[f64], k: usize) -> [f64; S] {
    let span = frame_span(t, k);
    std::array::from_fn(|j| t[k] + span * ((j as f64 + 0.5) / S as f64 - 0.5))
}

/// Frame k's intervals between instants ([`frame_instants`] of frame times `t`): the one ending
/// at its first instant (from the frame before's last; 0 for the first frame), and the one
/// between its own instants (all equal: a lag's coefficients are computed twice per frame rather
/// than at every instant).
pub fn frame_intervals(t: &[f64], k: usize) -> (f64, f64) {
    let h0 = match k.checked_sub(1) {
        None => 0.0,
        Some(b) => frame_instants(t, k)[0] - frame_instants(t, b)[S - 1],
    };
    (h0, frame_span(t, k) / S as f64)
}

/// The motion rebuilt at the instants of [`frame_instants`] from frame means of flow `f` (module
/// docs): the flow whose frame means are `f` with the sparsest second differences
/// ([`sparse_flow`]); the volumes follow from it ([`SubMotion::volumes`]).
pub fn sparse_motion(f: &[f64]) -> SubMotion {
    SubMotion { f: sparse_flow(f) }
}

/// Reweighting passes of [`sparse_flow`] at most.
const IRLS_PASSES: usize = 100;

/// Frames per window of [`sparse_flow`], and the frames of data a window sees beyond each end.
const WINDOW: usize = 256;
const MARGIN: usize = 24;

/// The flow at S instants per frame whose frame means are `fbar` and whose second differences
/// `d_i = q_{i−1} − 2q_i + q_{i+1}` are sparsest: `min Σ|d_i|` subject to `(1/S)Σ_j q_kj = f̄_k`,
/// by iteratively reweighted least squares, each pass
///
/// ```text
/// min Σ_i d_i²/(|d_i⁽ᵖ⁾| + ε) + W Σ_k ((1/S)Σ_j q_kj − f̄_k)²,
/// ```
///
/// ε = 10⁻⁴ of the largest |f̄| (below it a corner is not worth resolving), W large enough that
/// the means hold to 10⁻⁶ of that scale; from the flow held over each frame, until no sample moves
/// by more than 10⁻⁴ of the scale (a flow that close moves a lagged pressure by far less than a
/// sensor's noise). Each pass is a banded symmetric system (bandwidth S − 1).
///
/// Solved in windows of [`WINDOW`] frames, each with [`MARGIN`] frames of data either side (a
/// corner's pull on the flow dies out within a frame or two: the means pin every frame), on the
/// available cores: each window stops reweighting when it has settled, so quiet stretches cost a
/// pass or two and the memory is a window's.
pub fn sparse_flow(fbar: &[f64]) -> Vec<f64> {
    let scale = fbar.iter().fold(0.0f64, |a, f| a.max(f.abs()));
    let n = fbar.len();
    if scale == 0.0 || !scale.is_finite() || n < 2 {
        return fbar.iter().flat_map(|&f| [f; S]).collect();
    }
    let parts = crate::par::par_map(n.div_ceil(WINDOW), |w| {
        let (c0, c1) = (w * WINDOW, ((w + 1) * WINDOW).min(n));
        let (e0, e1) = (c0.saturating_sub(MARGIN), (c1 + MARGIN).min(n));
        let q = sparse_flow_window(&fbar[e0..e1], scale);
        q[(c0 - e0) * S..(c1 - e0) * S].to_vec()
    });
    parts.concat()
}

/// [`sparse_flow`] on one window, `scale` the whole series' largest |f̄|.
fn sparse_flow_window(fbar: &[f64], scale: f64) -> Vec<f64> {
    let mut q: Vec<f64> = fbar.iter().flat_map(|&f| [f; S]).collect();
    if fbar.len() < 2 {
        return q;
    }
    let eps = 1e-4 * scale;
    let w_mean = 1e6 / eps * (S * S) as f64;
    for _ in 0..IRLS_PASSES {
        let weights: Vec<f64> = (0..q.len())
            .map(|i| match i {
                0 => 0.0,
                i if i + 1 == q.len() => 0.0,
                i => 1.0 / ((q[i - 1] - 2.0 * q[i] + q[i + 1]).abs() + eps),
            })
            .collect();
        let next = reweighted_pass(fbar, &weights, w_mean);
        let moved = next
            .iter()
            .zip(&q)
            .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
        q = next;
        if moved <= 1e-4 * scale {
            break;
        }
    }
    q
}

/// One pass of [`sparse_flow`]: the normal equations `(Dᵀ diag(w) D + W MᵀM) q = W Mᵀ f̄` (D the
/// second differences, weight `w_i` on `d_i`; M the frame means), solved by [`band_solve`].
fn reweighted_pass(fbar: &[f64], w: &[f64], w_mean: f64) -> Vec<f64> {
    let n = fbar.len() * S;
    let b = S - 1;
    let mut a = vec![0.0; n * (b + 1)];
    let mut y = vec![0.0; n];
    // a[i·(b+1) + d] is row i, column i + d (upper band).
    let mut add = |i: usize, j: usize, x: f64| {
        let (lo, hi) = (i.min(j), i.max(j));
        a[lo * (b + 1) + hi - lo] += x;
    };
    for (k, &f) in fbar.iter().enumerate() {
        let c = w_mean / (S * S) as f64;
        for i in k * S..(k + 1) * S {
            y[i] += w_mean / S as f64 * f;
            for j in i..(k + 1) * S {
                add(i, j, c);
            }
        }
    }
    for i in 1..n.saturating_sub(1) {
        let taps = [(i - 1, 1.0), (i, -2.0), (i + 1, 1.0)];
        for (p, &(r, cr)) in taps.iter().enumerate() {
            for &(s, cs) in &taps[p..] {
                add(r, s, w[i] * cr * cs);
            }
        }
    }
    band_solve(&mut a, &mut y, b);
    y
}

/// Solves `A x = y` in place for a symmetric positive definite band matrix with `b`
/// off-diagonals, its upper band stored by rows (`a[i·(b+1) + d] = A[i][i+d]`), by Cholesky
/// `A = UᵀU` (U overwriting the band) and two triangular solves.
fn band_solve(a: &mut [f64], y: &mut [f64], b: usize) {
    let n = y.len();
    let w = b + 1;
    for i in 0..n {
        let piv = a[i * w].max(f64::MIN_POSITIVE).sqrt();
        a[i * w] = piv;
        for d in 1..w.min(n - i) {
            a[i * w + d] /= piv;
        }
        for d1 in 1..w.min(n - i) {
            let u = a[i * w + d1];
            if u == 0.0 {
                continue;
            }
            for d2 in d1..w.min(n - i) {
                a[(i + d1) * w + d2 - d1] -= u * a[i * w + d2];
            }
        }
    }
    for i in 0..n {
        let mut s = y[i];
        for d in 1..w.min(i + 1) {
            s -= a[(i - d) * w + d] * y[i - d];
        }
        y[i] = s / a[i * w];
    }
    for i in (0..n).rev() {
        let mut s = y[i];
        for d in 1..w.min(n - i) {
            s -= a[i * w + d] * y[i + d];
        }
        y[i] = s / a[i * w];
    }
}

/// First-order lags in series, `τ_s(t) ẏ_s + y_s = y_{s−1}` (`y_0` the input), run over the
/// instants of [`frame_instants`] with the input linear between them ([`foh`]), each lag's time
/// constant that of the frame the interval ends in, started at rest; each frame's output is the
/// mean of the last lag over the frame's instants. Holds the lags' coefficients, two per frame
/// ([`frame_intervals`]): [`LagChain::frame_means`] runs a column through them;
/// `lag_in_frames` runs a whole design through them a frame at a time ([`LagChain::coefficients`]).
pub struct LagChain {
    /// Per lag and frame, the [`foh`] coefficients of the interval ending at the frame's first
    /// instant and of those between its instants.
    coeffs: Vec<Vec<[(f64, f64); 2]>>,
    frames: usize,
}

impl LagChain {
    /// Lags with per-frame time constants `taus[s][k]` over the instants of the frames at times
    /// `t` (a repeated time constant with an interval within 10⁻⁹ of the last reuses the last
    /// coefficients).
    pub fn new(t: &[f64], taus: &[Vec<f64>]) -> Self {
        let coeffs = taus
            .iter()
            .map(|tau| {
                let mut last = (f64::NAN, f64::NAN, (0.0, 1.0));
                // Intervals equal but for rounding (a fixed frame rate) share coefficients.
                let mut at = |h: f64, tk: f64| {
                    if tk != last.1 || (h - last.0).abs() > 1e-9 * h {
                        last = (h, tk, foh(h, tk));
                    }
                    last.2
                };
                (0..tau.len())
                    .map(|k| {
                        let (h0, h) = frame_intervals(t, k);
                        [at(h0, tau[k]), at(h, tau[k])]
                    })
                    .collect()
            })
            .collect();
        Self {
            coeffs,
            frames: t.len(),
        }
    }

    /// Number of lags.
    pub fn lags(&self) -> usize {
        self.coeffs.len()
    }

    /// Lag s's coefficients `(a, 1 − g)` at frame k's instant j.
    pub fn coefficients(&self, s: usize, k: usize, j: usize) -> (f64, f64) {
        self.coeffs[s][k][usize::from(j > 0)]
    }

    /// A column's values at the instants (`x(k)`, frame k's) through the lags; its frame means.
    pub fn frame_means(&self, x: impl Fn(usize) -> [f64; S]) -> Vec<f64> {
        let mut st: Vec<(f64, f64)> = Vec::new();
        (0..self.frames)
            .map(|k| {
                let frame = x(k);
                if st.is_empty() {
                    st = vec![(frame[0], frame[0]); self.lags()];
                }
                let mut sum = 0.0;
                for (j, &xi) in frame.iter().enumerate() {
                    let mut u = xi;
                    for (s, (y, x0)) in st.iter_mut().enumerate() {
                        let (a, one_minus_g) = self.coefficients(s, k, j);
                        let out = a * *y + (1.0 - a) * *x0 + one_minus_g * (u - *x0);
                        (*y, *x0) = (out, u);
                        u = out;
                    }
                    sum += u;
                }
                sum / S as f64
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn band_solve_matches_a_dense_solve() {
        // A diagonally dominant band (b = 3): A x = y for a known x.
        let (n, b) = (12, 3);
        let at = |i: usize, j: usize| -> f64 {
            let d = i.abs_diff(j);
            match d {
                0 => 10.0 + i as f64,
                d if d <= b => 1.0 / (1.0 + d as f64 + (i + j) as f64 * 0.1),
                _ => 0.0,
            }
        };
        let x: Vec<f64> = (0..n).map(|i| (i as f64 * 0.7).sin()).collect();
        let mut y: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| at(i, j) * x[j]).sum())
            .collect();
        let mut a: Vec<f64> = (0..n)
            .flat_map(|i| (0..=b).map(move |d| if i + d < n { at(i, i + d) } else { 0.0 }))
            .collect();
        band_solve(&mut a, &mut y, b);
        for (u, v) in y.iter().zip(&x) {
            assert!((u - v).abs() < 1e-12, "{u} vs {v}");
        }
    }

    #[test]
    fn sparse_flow_rebuilds_a_trapezoid_of_flow_from_its_frame_means() {
        // Known answer: a move at constant acceleration 500 mm³/s² to 40 mm³/s, cruising, and
        // back, its corners at arbitrary instants inside frames; sampled at S instants per
        // 40 ms frame and averaged. The sparsest flow with those means is the trapezoid itself.
        let h = 0.04 / S as f64;
        let corners = [0.2013, 0.2813, 0.5577, 0.6377];
        let flow = |t: f64| -> f64 {
            let up = ((t - corners[0]) / (corners[1] - corners[0])).clamp(0.0, 1.0);
            let down = ((t - corners[2]) / (corners[3] - corners[2])).clamp(0.0, 1.0);
            40.0 * (up - down)
        };
        let frames = 25;
        let tq: Vec<f64> = (0..frames * S).map(|i| (i as f64 + 0.5) * h).collect();
        let q: Vec<f64> = tq.iter().map(|&t| flow(t)).collect();
        let fbar: Vec<f64> = q
            .chunks(S)
            .map(|c| c.iter().sum::<f64>() / S as f64)
            .collect();
        let rebuilt = sparse_flow(&fbar);
        let err = q
            .iter()
            .zip(&rebuilt)
            .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
        assert!(err < 0.05 * 40.0, "largest error {err} mm³/s");
        for (k, c) in rebuilt.chunks(S).enumerate() {
            let mean = c.iter().sum::<f64>() / S as f64;
            assert!((mean - fbar[k]).abs() < 1e-6 * 40.0);
        }
    }

    /// Known answer: three trapezoid moves at 500 mm³/s² (to 40, 60 and −25 mm³/s), corners at
    /// arbitrary instants inside 40 ms frames, sampled at S instants per frame and averaged.
    /// Each frame's mean acceleration over its span is the flow's change across the span over
    /// the span, `(q(t_k + Δ/2) − q(t_k − Δ/2))/Δ`; the frame means of the acceleration of the
    /// flow rebuilt from the frame means of flow match it: the least-squares coefficient of the
    /// one on the other is within 2 % of 1 (1.012). The Hermite acceleration of the frame means
    /// (the inertance's column before) is off by more (0.935: it spreads each ramp over the
    /// neighbouring frames and rings past it).
    #[test]
    fn frame_mean_accelerations_of_the_rebuilt_flow_are_those_of_the_motion() {
        let h = 0.04 / S as f64;
        // (start, peak flow, ramp time, cruise time): ramps of peak/500 s.
        let moves = [
            (0.2013, 40.0, 0.08, 0.1964),
            (0.7311, 60.0, 0.12, 0.0533),
            (1.1234, -25.0, 0.05, 0.2222),
        ];
        let flow = |t: f64| -> f64 {
            moves
                .iter()
                .map(|&(t0, peak, ramp, cruise)| {
                    let up = ((t - t0) / ramp).clamp(0.0, 1.0);
                    let down = ((t - t0 - ramp - cruise) / ramp).clamp(0.0, 1.0);
                    peak * (up - down)
                })
                .sum()
        };
        let frames = 50;
        let t: Vec<f64> = (0..frames).map(|k| 0.04 * (k as f64 + 0.5)).collect();
        let tq: Vec<f64> = (0..frames * S).map(|i| (i as f64 + 0.5) * h).collect();
        let q: Vec<f64> = tq.iter().map(|&s| flow(s)).collect();
        let fbar: Vec<f64> = q
            .chunks(S)
            .map(|c| c.iter().sum::<f64>() / S as f64)
            .collect();
        let exact: Vec<f64> = t
            .iter()
            .map(|&tk| (flow(tk + 0.02) - flow(tk - 0.02)) / 0.04)
            .collect();
        let coef = |col: &[f64]| {
            let (mut xy, mut xx) = (0.0, 0.0);
            for k in 1..frames - 1 {
                xy += exact[k] * col[k];
                xx += col[k] * col[k];
            }
            xy / xx
        };
        let ours = sparse_motion(&fbar).frame_mean_accelerations(&t);
        assert!((coef(&ours) - 1.0).abs() < 0.02, "{}", coef(&ours));
        // The frame means of volume, from the flow's integral at the instants.
        let mut vol = 0.0;
        let vq: Vec<f64> = q
            .iter()
            .map(|&x| {
                vol += x * h;
                vol
            })
            .collect();
        let vbar: Vec<f64> = vq
            .chunks(S)
            .map(|c| c.iter().sum::<f64>() / S as f64)
            .collect();
        let hermite = crate::residual::signal::acceleration_hermite(&t, &vbar, &fbar);
        assert!((coef(&hermite) - 1.0).abs() > 0.03, "{}", coef(&hermite));
    }

    #[test]
    fn lag_chain_is_the_exact_lag_of_a_ramp_and_the_identity_at_zero_lag() {
        // Known answer: a ramp x = r t through τ settles to r(t − τ); the mean over a frame's
        // instants of the settled output is r(mean t − τ). With τ = 0 each frame's mean is that
        // of its input.
        let t: Vec<f64> = (0..200).map(|k| 0.04 * k as f64).collect();
        let (r, tau) = (3.0, 0.05);
        let x = |k: usize| frame_instants(&t, k).map(|s| r * s);
        for (lag, want) in [(tau, r * (t[150] - tau)), (0.0, r * t[150])] {
            let taus = vec![vec![lag; t.len()]];
            let out = LagChain::new(&t, &taus).frame_means(x);
            assert!((out[150] - want).abs() < 1e-9, "{} vs {want}", out[150]);
        }
    }
}
