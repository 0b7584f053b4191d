//! Signal transforms the effect library is built from: play operator, first-order lag, fractional
//! delay, running integral, derivatives and smoothing, all on possibly non-uniform time grids.

/// Play (backlash) operator of width `w` (Krasnosel'skii–Pokrovskii): the output follows the input
/// only once the input has moved `w/2` past it, `z_k = clamp(z_{k−1}, x_k − w/2, x_k + w/2)`, started
/// at rest, `z_0 = x_0`. It is the elementary rate-independent hysteron: its output depends on the
/// order of input values, never on their speed.
pub fn play(x: &[f64], w: f64) -> Vec<f64> {
    let h = 0.5 * w.max(0.0);
    let mut out = Vec::with_capacity(x.len());
    let mut z = x.first().copied().unwrap_or(0.0);
    for &xi in x {
        z = z.clamp(xi - h, xi + h);
        out.push(z);
    }
    out
}

/// Duhem hysteron of transition volume `w`: `dh = (s − h)|dx|/w`, `s = sign(dx)`, integrated
/// exactly over each sample step (x linear in between, one direction per step):
/// `h_k = s + (h_{k−1} − s)·exp(−|x_k − x_{k−1}|/w)`, started at `h_0 = 0`. Rate-independent: the
/// output depends on the order of input values, never on their speed.
pub fn duhem(x: &[f64], w: f64) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    let mut h = 0.0;
    let mut prev = x.first().copied().unwrap_or(0.0);
    for &xi in x {
        let dx = xi - prev;
        if dx != 0.0 {
            let s = dx.signum();
            h = s + (h - s) * (-dx.abs() / w.max(f64::MIN_POSITIVE)).exp();
        }
        out.push(h);
        prev = xi;
    }
    out
}

/// Exact response of `τ ẏ + y = x` to an input that is linear between samples (first-order hold),
/// with a per-sample time constant `tau[k]` (a constant lag passes a slice of one repeated value):
///
/// ```text
/// a = exp(−Δt/τ),  g = (τ/Δt)(1 − a),
/// y_k = a·y_{k−1} + (1 − a)·x_{k−1} + (1 − g)·(x_k − x_{k−1}),   y_0 = x_0 (at rest).
/// ```
///
/// The loop's lags on frame means use the cubic input of [`lag_cubic_coeffs`] (a straight line
/// between frames puts every corner of the motion at a frame instant); this first-order hold is
/// the tests' reference, which the cubic must reproduce when its slopes are the secants.
#[cfg(test)]
pub fn lag_foh(t: &[f64], x: &[f64], tau: impl Fn(usize) -> f64) -> Vec<f64> {
    lag_apply(&lag_coeffs(t, tau), x)
}

/// Per-sample coefficients `(a, 1 − g)` of the first-order-hold lag (see [`lag_foh`]).
#[cfg(test)]
pub fn lag_coeffs(t: &[f64], tau: impl Fn(usize) -> f64) -> Vec<(f64, f64)> {
    per_interval(t, tau, (0.0, 1.0), foh)
}

/// Coefficients `(a, 1 − g)` of the exact response of `τ ẏ + y = x` over an interval `h` on which
/// x is linear: `y₁ = a y₀ + (1 − a) x₀ + (1 − g)(x₁ − x₀)`, `a = e^{−h/τ}`, `g = (τ/h)(1 − a)`
/// (`1 − a = −expm1(−h/τ)` without cancellation; g by its series for tiny h/τ); `(0, 1)` (the
/// output is the input) when τ is negligible.
pub fn foh(h: f64, tau: f64) -> (f64, f64) {
    if tau <= 1e-9 * h || h <= 0.0 {
        return (0.0, 1.0);
    }
    let r = h / tau;
    let one_minus_a = -(-r).exp_m1();
    let g = if r < 1e-6 {
        1.0 - 0.5 * r
    } else {
        one_minus_a / r
    };
    (1.0 - one_minus_a, 1.0 - g)
}

/// Per-sample coefficients of a lag: `identity` at the first sample and wherever τ is negligible
/// (the output is the input), `coeffs(Δt, τ)` elsewhere. A log's intervals repeat (a fixed frame
/// rate), so the last coefficients are reused when Δt and τ repeat.
fn per_interval<C: Copy>(
    t: &[f64],
    tau: impl Fn(usize) -> f64,
    identity: C,
    coeffs: impl Fn(f64, f64) -> C,
) -> Vec<C> {
    let mut c = Vec::with_capacity(t.len());
    c.push(identity);
    let mut last = (f64::NAN, f64::NAN, identity);
    for k in 1..t.len() {
        let dt = t[k] - t[k - 1];
        let tk = tau(k);
        if dt == last.0 && tk == last.1 {
            c.push(last.2);
            continue;
        }
        let ck = if tk <= 1e-9 * dt {
            identity
        } else {
            coeffs(dt, tk)
        };
        last = (dt, tk, ck);
        c.push(ck);
    }
    c
}

/// Slopes of a signal from its past only: `m_k = d_k + ½(d_k − d_{k−1})`, `d_k = (x_k − x_{k−1})/Δt_k`
/// (the three-point backward difference on a uniform grid), the secant `d_1` at the second
/// sample and 0 at the first (at rest). The board's sensor lag runs on the cubic with these
/// slopes (`model_core::chain`): unlike Akima's ([`akima_slopes`]) they need no later frame.
/// ([`LagStream`] computes them a block at a time.)
#[cfg(test)]
pub fn backward_slopes(t: &[f64], x: &[f64]) -> Vec<f64> {
    let mut m = Vec::with_capacity(x.len());
    backward_slopes_range(t, x, 0, x.len(), &mut m);
    m
}

/// [`backward_slopes`] at samples `lo..hi` only, appended to `out`.
fn backward_slopes_range(t: &[f64], x: &[f64], lo: usize, hi: usize, out: &mut Vec<f64>) {
    let d = |k: usize| (x[k] - x[k - 1]) / (t[k] - t[k - 1]);
    out.extend((lo..hi).map(|k| match k {
        0 => 0.0,
        1 => d(1),
        _ => {
            let dk = d(k);
            dk + 0.5 * (dk - d(k - 1))
        }
    }));
}

/// The lag of [`lag_cubic_coeffs`] applied to every column in place, each column reconstructed
/// between samples by the cubic with [`backward_slopes`] (causal: the board's sensor lag),
/// started at rest.
pub fn lag_causal_apply_all(t: &[f64], coeffs: &[[f64; 5]], cols: &mut [Vec<f64>]) {
    lag_apply_all(t, coeffs, LagSlopes::Backward, cols);
}

/// Applies precomputed lag coefficients: `y_k = a y_{k−1} + (1 − a) x_{k−1} + (1 − g)(x_k − x_{k−1})`.
#[cfg(test)]
pub fn lag_apply(coeffs: &[(f64, f64)], x: &[f64]) -> Vec<f64> {
    let mut y = Vec::with_capacity(x.len());
    if x.is_empty() {
        return y;
    }
    y.push(x[0]);
    for k in 1..x.len() {
        let (a, h) = coeffs[k];
        let prev = y[k - 1];
        y.push(a * prev + (1.0 - a) * x[k - 1] + h * (x[k] - x[k - 1]));
    }
    y
}

/// Akima's slopes (1970) for a piecewise-cubic interpolant through `(t_k, x_k)`: at each sample
/// the mean of the neighbouring secants `d_{k−1}`, `d_k` weighted by how much the *other* side's
/// secants change,
///
/// ```text
/// m_k = (|d_{k+1} − d_k|·d_{k−1} + |d_{k−1} − d_{k−2}|·d_k) / (|d_{k+1} − d_k| + |d_{k−1} − d_{k−2}|),
/// ```
///
/// the plain mean where both weights vanish, with Akima's linear extrapolation of the secants past
/// each end. Unlike a spline or Catmull–Rom it does not overshoot at a corner: where a signal is
/// straight on one side of a sample (a constant flow phase), the slope there is that side's. That
/// is why it reconstructs a frame-averaged signal between frames: a flow ramp's corner inside a
/// frame stays a corner instead of ringing into the neighbouring frames.
pub fn akima_slopes(t: &[f64], x: &[f64]) -> Vec<f64> {
    let inv: Vec<f64> = t.windows(2).map(|w| 1.0 / (w[1] - w[0])).collect();
    akima_slopes_inv(&inv, x)
}

/// [`akima_slopes`] with the reciprocal sample intervals given (shared by many columns).
fn akima_slopes_inv(inv_dt: &[f64], x: &[f64]) -> Vec<f64> {
    let (mut m, mut secants) = (Vec::with_capacity(x.len()), Vec::new());
    akima_slopes_range(inv_dt, x, 0, x.len(), &mut secants, &mut m);
    m
}

/// [`akima_slopes`] at samples `lo..hi` only, appended to `out` (`secants`: scratch). Sample k
/// needs the secants of intervals k − 2 ..= k + 1, with Akima's linear extrapolation of two
/// secants past each end.
fn akima_slopes_range(
    inv_dt: &[f64],
    x: &[f64],
    lo: usize,
    hi: usize,
    secants: &mut Vec<f64>,
    out: &mut Vec<f64>,
) {
    let n = x.len();
    if n < 2 {
        out.extend((lo..hi).map(|_| 0.0));
        return;
    }
    // d(e) is the secant of interval e − 2 (e = 2..=n), extrapolated for e = 0, 1, n + 1, n + 2.
    let sec = |j: usize| (x[j + 1] - x[j]) * inv_dt[j];
    let (first, last) = (sec(0), sec(n - 2));
    let second = if n >= 3 { sec(1) } else { first };
    let before_last = if n >= 3 { sec(n - 3) } else { last };
    let d1 = 2.0 * first - second;
    let end = 2.0 * last - before_last;
    let d = |e: usize| match e {
        0 => 2.0 * d1 - first,
        1 => d1,
        e if e <= n => sec(e - 2),
        e if e == n + 1 => end,
        _ => 2.0 * end - last,
    };
    secants.clear();
    // The interior secants (e = 2..=n) in one pass over the samples, the extrapolated ones at
    // the ends by `d`.
    let (a, b) = (lo.clamp(2, n + 1), (hi + 3).clamp(2, n + 1));
    secants.extend((lo..a.max(lo).min(hi + 3)).map(d));
    if a < b {
        let (xs, xe, inv) = (&x[a - 2..b - 2], &x[a - 1..b - 1], &inv_dt[a - 2..b - 2]);
        secants.extend(
            xe.iter()
                .zip(xs)
                .zip(inv)
                .map(|((x1, x0), inv)| (x1 - x0) * inv),
        );
    }
    secants.extend((b.max(lo)..hi + 3).map(d));
    out.extend(secants.windows(4).map(|w| {
        // Sample k sits between w[1] (left secant) and w[2] (right secant). Both values are
        // computed and one chosen (no branch: the loop vectorises).
        let (w_left, w_right) = ((w[3] - w[2]).abs(), (w[1] - w[0]).abs());
        let sum = w_left + w_right;
        let weighted = (w_left * w[1] + w_right * w[2]) / sum;
        let mean = 0.5 * (w[1] + w[2]);
        if sum > 1e-12 * (w[1].abs() + w[2].abs()) && sum > 0.0 {
            weighted
        } else {
            mean
        }
    }));
}

/// `I_q = ∫₀¹ r e^{−r(1−s)} s^q ds`, q = 0..3: the response at the end of an interval of a
/// first-order lag (r = Δt/τ) to the input `s^q`. By parts `I_q = 1 − (q/r) I_{q−1}`,
/// `I_0 = 1 − e^{−r}`; for r < 1/2 that recurrence cancels, so the series
/// `I_q = r Σ_k (−r)^k q!/(q + k + 1)!` is summed instead.
fn lag_moments(r: f64) -> [f64; 4] {
    let mut out = [0.0; 4];
    if r >= 0.5 {
        out[0] = -(-r).exp_m1();
        for q in 1..4 {
            out[q] = 1.0 - (q as f64 / r) * out[q - 1];
        }
    } else {
        for (q, o) in out.iter_mut().enumerate() {
            let mut term = r / (q as f64 + 1.0);
            let mut sum = 0.0;
            for k in 0..60 {
                sum += term;
                if term.abs() <= 1e-17 * sum.abs() {
                    break;
                }
                term *= -r / (q as f64 + k as f64 + 2.0);
            }
            *o = sum;
        }
    }
    out
}

/// Per-interval weights `[a, w_x0, w_x1, w_m0, w_m1]` of the exact response of `τ ẏ + y = u` to
/// an input that is a cubic Hermite interpolant on each interval (values x, slopes m at the ends):
///
/// ```text
/// y_k = a·y_{k−1} + w_x0·x_{k−1} + w_x1·x_k + w_m0·m_{k−1} + w_m1·m_k,
/// a = e^{−r}, r = Δt/τ,  w_x0 = 2I₃ − 3I₂ + I₀,  w_x1 = 3I₂ − 2I₃,
/// w_m0 = Δt(I₃ − 2I₂ + I₁),  w_m1 = Δt(I₃ − I₂)
/// ```
///
/// (the Hermite basis functions weighted by the lag's impulse response, [`lag_moments`]). With
/// the slopes equal to each interval's secant it is exactly [`lag_foh`]'s first-order hold.
pub fn lag_cubic_coeffs(t: &[f64], tau: impl Fn(usize) -> f64) -> Vec<[f64; 5]> {
    per_interval(t, tau, [0.0, 0.0, 1.0, 0.0, 0.0], |dt, tk| {
        let r = dt / tk;
        let i = lag_moments(r);
        [
            (-r).exp(),
            2.0 * i[3] - 3.0 * i[2] + i[0],
            3.0 * i[2] - 2.0 * i[3],
            dt * (i[3] - 2.0 * i[2] + i[1]),
            dt * (i[3] - i[2]),
        ]
    })
}

/// The lag of [`lag_cubic_coeffs`] on one signal `x` with known slopes `m` (e.g. a volume whose
/// flow is logged), started at rest.
pub fn lag_cubic(coeffs: &[[f64; 5]], x: &[f64], m: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    let Some(&x0) = x.first() else {
        return out;
    };
    let mut y = x0;
    out.push(y);
    for k in 1..x.len() {
        let [a, wx0, wx1, wm0, wm1] = coeffs[k];
        y = a * y + wx0 * x[k - 1] + wx1 * x[k] + wm0 * m[k - 1] + wm1 * m[k];
        out.push(y);
    }
    out
}

/// The lag of [`lag_cubic_coeffs`] applied to every column in place, each column reconstructed
/// between samples by its Akima interpolant ([`akima_slopes`]), started at rest (`y_0 = x_0`).
///
/// Why a cubic and not a first-order hold: a frame is the mean of the sensor's conversions over
/// its interval, and a mean commutes with any linear time-invariant filter, so the lagged frame is
/// the lag of the frame-averaged signal, which is smooth between frames except at a motion's
/// corners. Joining frames by straight lines puts every corner at a frame instant; the Akima cubic
/// places it within the frame and keeps the flat side flat.
pub fn lag_cubic_apply_all(t: &[f64], coeffs: &[[f64; 5]], cols: &mut [Vec<f64>]) {
    lag_apply_all(t, coeffs, LagSlopes::Akima, cols);
}

/// [`LagStream`] over whole columns, in place, a block of rows at a time.
fn lag_apply_all(t: &[f64], coeffs: &[[f64; 5]], slopes: LagSlopes, cols: &mut [Vec<f64>]) {
    let n = t.len();
    if n == 0 || coeffs.len() != n || cols.iter().any(|c| c.len() != n) {
        return;
    }
    let mut run = LagStream::new(t, coeffs, slopes, cols);
    // A block's slopes read the input up to three rows before it, so each block's output is
    // written back only after the next block has been lagged.
    let (mut out, mut pending) = (Vec::new(), Vec::new());
    let mut pending_rows = 0..0;
    for hi in (1..=n.div_ceil(LAG_BLOCK)).map(|b| (b * LAG_BLOCK).min(n)) {
        let lo = run.advance(cols, hi, &mut out);
        write_back(cols, &pending, pending_rows);
        std::mem::swap(&mut out, &mut pending);
        pending_rows = lo..hi;
    }
    write_back(cols, &pending, pending_rows);
}

/// Rows `rows` of every column from `lagged` (column by column).
fn write_back(cols: &mut [Vec<f64>], lagged: &[f64], rows: std::ops::Range<usize>) {
    if rows.is_empty() {
        return;
    }
    for (c, block) in cols.iter_mut().zip(lagged.chunks_exact(rows.len())) {
        c[rows.clone()].copy_from_slice(block);
    }
}

/// Rows per block of [`lag_apply_all`].
const LAG_BLOCK: usize = 4096;

/// The slopes of the cubic a [`LagStream`] reconstructs each column with between samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LagSlopes {
    /// Akima's ([`akima_slopes`]): the loop's form for frame means.
    Akima,
    /// From the past only ([`backward_slopes`]): the board's form.
    Backward,
}

/// The lag of [`lag_cubic_coeffs`] on many columns at once, run over the rows in order a block
/// at a time: each column's slopes are computed for the block as it is reached, and only the
/// lag's state (last output and input per column) is carried between blocks. What
/// [`lag_cubic_apply_all`] and [`lag_causal_apply_all`] do to whole columns, holding one block of
/// output instead of a second copy of the design (a search over τ filters it hundreds of times).
pub struct LagStream<'a> {
    t: &'a [f64],
    inv_dt: Vec<f64>,
    coeffs: &'a [[f64; 5]],
    slopes: LagSlopes,
    /// `(y_{k−1}, x_{k−1})` per column.
    state: Vec<(f64, f64)>,
    /// The next row to lag.
    pos: usize,
    /// Slopes of every column over the current block (and the row before it).
    m: Vec<f64>,
    secants: Vec<f64>,
}

impl<'a> LagStream<'a> {
    /// A lag of `cols` (equal lengths, that of `t` and `coeffs`) started at rest (`y_0 = x_0`).
    pub fn new(t: &'a [f64], coeffs: &'a [[f64; 5]], slopes: LagSlopes, cols: &[Vec<f64>]) -> Self {
        let inv_dt = match slopes {
            LagSlopes::Akima => t.windows(2).map(|w| 1.0 / (w[1] - w[0])).collect(),
            LagSlopes::Backward => Vec::new(),
        };
        Self {
            t,
            inv_dt,
            coeffs,
            slopes,
            state: cols.iter().map(|c| (c[0], c[0])).collect(),
            pos: 0,
            m: Vec::new(),
            secants: Vec::new(),
        }
    }

    /// Lags rows `pos..hi` of every column (the same `cols` at every call) into `out`, column by
    /// column (`cols.len()` runs of `hi − pos`), and returns `pos`, the first row written:
    ///
    /// ```text
    /// y_k = a y_{k−1} + w_x0 x_{k−1} + w_x1 x_k + w_m0 m_{k−1} + w_m1 m_k   (k ≥ 1),  y_0 = x_0.
    /// ```
    pub fn advance(&mut self, cols: &[Vec<f64>], hi: usize, out: &mut Vec<f64>) -> usize {
        let lo = self.pos;
        let len = hi - lo;
        let s0 = lo.saturating_sub(1);
        let w = hi - s0;
        self.m.clear();
        for c in cols {
            match self.slopes {
                LagSlopes::Akima => {
                    akima_slopes_range(&self.inv_dt, c, s0, hi, &mut self.secants, &mut self.m)
                }
                LagSlopes::Backward => backward_slopes_range(self.t, c, s0, hi, &mut self.m),
            }
        }
        out.clear();
        out.resize(cols.len() * len, 0.0);
        if len == 0 {
            return lo;
        }
        // Every column's recurrence is a serial chain (latency-bound: a multiply and four adds
        // per sample); stepping a group of columns together at each sample lets the independent
        // chains overlap in the pipeline, and within a group each column's rows stream from and
        // to contiguous slices (stepping all columns at once strode across every column's memory
        // at each sample, and cost several times the arithmetic).
        let start = usize::from(lo == 0);
        if lo == 0 {
            for (c, x) in cols.iter().enumerate() {
                out[c * len] = x[0];
            }
        }
        let coeffs = &self.coeffs[lo + start..hi];
        let groups = cols
            .chunks(LAG_GROUP)
            .zip(self.state.chunks_mut(LAG_GROUP))
            .zip(self.m.chunks(LAG_GROUP * w))
            .zip(out.chunks_mut(LAG_GROUP * len));
        for (((cs, st), m), o) in groups {
            // Row k's interval runs from slope k − 1 − s0 to k − s0: the first row's (k = lo +
            // start) starts at slope 0 of the block's (s0 = lo − 1, or lo = 0 with start = 1).
            let m: Vec<&[f64]> = m.chunks_exact(w).collect();
            let x: Vec<&[f64]> = cs.iter().map(|x| &x[lo + start..hi]).collect();
            let mut o: Vec<&mut [f64]> = o.chunks_exact_mut(len).map(|o| &mut o[start..]).collect();
            // A short group (the design's last columns) in groups of 4, 2 and 1.
            let mut j = 0;
            while j < cs.len() {
                let g = match cs.len() - j {
                    r if r >= LAG_GROUP => LAG_GROUP,
                    r if r >= 4 => 4,
                    r if r >= 2 => 2,
                    _ => 1,
                };
                let (x, m, st, o) = (
                    &x[j..j + g],
                    &m[j..j + g],
                    &mut st[j..j + g],
                    &mut o[j..j + g],
                );
                match g {
                    LAG_GROUP => lag_group::<LAG_GROUP>(coeffs, x, m, st, o),
                    4 => lag_group::<4>(coeffs, x, m, st, o),
                    2 => lag_group::<2>(coeffs, x, m, st, o),
                    _ => lag_group::<1>(coeffs, x, m, st, o),
                }
                j += g;
            }
        }
        self.pos = hi;
        lo
    }
}

/// Columns [`LagStream::advance`] steps together.
const LAG_GROUP: usize = 8;

/// [`LagStream::advance`]'s recurrence on `G` columns over the rows of `coeffs`: column j's inputs
/// `x[j]`, its slopes `m[j]` from the row before the first (`m[j][i]`, `m[j][i + 1]` the slopes at
/// the ends of row i's interval), its state `st[j]` (last output and input), its outputs `o[j]`.
#[inline(always)]
fn lag_group<const G: usize>(
    coeffs: &[[f64; 5]],
    x: &[&[f64]],
    m: &[&[f64]],
    st: &mut [(f64, f64)],
    o: &mut [&mut [f64]],
) {
    let rows = coeffs.len();
    let x: [&[f64]; G] = std::array::from_fn(|j| &x[j][..rows]);
    let m: [&[f64]; G] = std::array::from_fn(|j| &m[j][..rows + 1]);
    let (mut y, mut xp): ([f64; G], [f64; G]) = (
        std::array::from_fn(|j| st[j].0),
        std::array::from_fn(|j| st[j].1),
    );
    for (i, &[a, wx0, wx1, wm0, wm1]) in coeffs.iter().enumerate() {
        for j in 0..G {
            let xk = x[j][i];
            let yk = a * y[j] + wx0 * xp[j] + wx1 * xk + wm0 * m[j][i] + wm1 * m[j][i + 1];
            o[j][i] = yk;
            (y[j], xp[j]) = (yk, xk);
        }
    }
    for j in 0..G {
        st[j] = (y[j], xp[j]);
    }
}

/// Sub-samples per frame at which [`play_frames`] runs the play operator.
pub const SUB_SAMPLES: usize = 8;

/// Lead-screw backlash of width `w` on frame-averaged signals: the frame means of the plunger's
/// position and flow when the nut follows the logged volume `v` and flow `f`.
///
/// A frame is the mean over its interval, and the dead band after a reversal lasts a fraction of
/// a frame, so the play operator cannot act on the frame values themselves (a whole frame would be
/// either engaged or not). Instead the nut's motion is reconstructed at [`SUB_SAMPLES`] instants
/// spread evenly over each frame's interval (centred on its time stamp): position by the cubic
/// Hermite interpolant of v with slopes f, flow by the Akima interpolant of f (no overshoot where
/// the flow is flat); the play operator runs on those instants (started at rest), the plunger's
/// flow is the nut's while the screw bears on it and zero in the dead band, and both are averaged
/// back over each frame.
///
/// The instants are made and consumed one frame at a time ([`FrameMotion`]), never held whole.
pub fn play_frames(t: &[f64], v: &[f64], f: &[f64], w: f64) -> (Vec<f64>, Vec<f64>) {
    play_instants(&FrameMotion::new(t, v, f, &ppm_edges(f)), w)
}

/// The play operator of half-width `h` over a frame's instants at a time, its plunger at `z`.
struct Play {
    h: f64,
    z: f64,
}

impl Play {
    /// Runs over one frame's instants `xs` (the nut) with flows `qs`; the frame means of the
    /// plunger's position and flow.
    fn frame(&mut self, xs: &[f64], qs: &[f64]) -> (f64, f64) {
        let h = self.h;
        let (mut zs, mut fs) = (0.0, 0.0);
        for (&x, &q) in xs.iter().zip(qs) {
            self.z = self.z.clamp(x - h, x + h);
            let gap = x - self.z;
            let engaged = gap.abs() >= h - 1e-9 * (1.0 + h) && gap * q > 0.0;
            zs += self.z;
            fs += if engaged { q } else { 0.0 };
        }
        (zs / SUB_SAMPLES as f64, fs / SUB_SAMPLES as f64)
    }
}

/// Lead-screw backlash of width `w` as the board runs it (`model_core::chain`, backlash): the
/// nut's motion inside frame k is rebuilt from that frame alone (the board has no next frame),
/// `x_j = v_k + f_k Δt_k ((j + ½)/S − ½)` at the [`SUB_SAMPLES`] instants `j` centred on the frame,
/// `Δt_k` the interval to the previous frame (the first frame: to the next); the play operator
/// runs over the instants (started at the first), and the plunger's mean and the nut's flow times
/// the fraction of instants at which it pushes the plunger (the clamp moves it along the flow)
/// come out.
pub fn play_frame_linear(t: &[f64], v: &[f64], f: &[f64], w: f64) -> (Vec<f64>, Vec<f64>) {
    let h = 0.5 * w.max(0.0);
    let n = v.len();
    if h == 0.0 || n == 0 {
        return (v.to_vec(), f.to_vec());
    }
    // The board's own operator, in its f32: a nut reaching the band's edge within f32's
    // resolution of a sub-sample engages there in f64 and not on the board (a property test
    // found one: `chain_agrees`, backlash).
    let (mut z, mut primed) = (0.0f32, false);
    let (mut vo, mut fo) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for k in 0..n {
        let dt = match k {
            0 if n > 1 => t[1] - t[0],
            0 => 0.0,
            _ => t[k] - t[k - 1],
        };
        let out =
            model_core::chain::play_frame(z, primed, v[k] as f32, f[k] as f32, dt as f32, h as f32);
        (z, primed) = (out.z, true);
        vo.push(f64::from(out.v));
        fo.push(f[k] * f64::from(out.engaged));
    }
    (vo, fo)
}

/// [`play_frames`] on motion at the instants of [`FrameMotion`], as held or as made
/// ([`Instants`]; the motion does not depend on the play, so a search prepares it once).
pub fn play_instants(sub: &impl Instants, w: f64) -> (Vec<f64>, Vec<f64>) {
    let h = 0.5 * w.max(0.0);
    let n = sub.frames();
    let (mut vo, mut fo) = (Vec::with_capacity(n), Vec::with_capacity(n));
    let mut play: Option<Play> = None;
    sub.each_frame(|xs, qs| {
        let p = play.get_or_insert(Play { h, z: xs[0] });
        let (z, q) = p.frame(xs, qs);
        vo.push(z);
        fo.push(q);
    });
    (vo, fo)
}

/// Motion at [`SUB_SAMPLES`] instants per frame (position, flow), read a frame at a time in
/// frame order: held whole (a pair of vectors, frame k's instants at `k·SUB_SAMPLES ..`) or made
/// as it is read ([`FrameMotion`]).
pub trait Instants {
    /// Number of frames.
    fn frames(&self) -> usize;
    /// Calls `each(x, q)` with each frame's instants, in order.
    fn each_frame(&self, each: impl FnMut(&[f64], &[f64]));
}

impl Instants for (Vec<f64>, Vec<f64>) {
    fn frames(&self) -> usize {
        self.0.len() / SUB_SAMPLES
    }
    fn each_frame(&self, mut each: impl FnMut(&[f64], &[f64])) {
        for (xs, qs) in self.0.chunks(SUB_SAMPLES).zip(self.1.chunks(SUB_SAMPLES)) {
            each(xs, qs);
        }
    }
}

/// The motion rebuilt at [`SUB_SAMPLES`] instants spread evenly over each frame's interval
/// `[t_k − Δ/2, t_k + Δ/2]` (Δ the local frame spacing), treating each logged value as what it
/// is, the mean over that interval: flow by the piecewise-parabolic reconstruction of the frame
/// means ([`ppm_edges`]: flat where the flow is flat, no overshoot at a ramp's corner), position
/// by integrating that flow exactly within the frame, placed so that its mean over the frame's
/// instants is the logged volume.
///
/// Made a frame at a time as it is read, from the frame times, volumes and flows and the flow's
/// parabola edges: 2 numbers per frame kept instead of 2·[`SUB_SAMPLES`].
#[derive(Clone, Copy, Debug)]
pub struct FrameMotion<'a> {
    t: &'a [f64],
    v: &'a [f64],
    f: &'a [f64],
    edges: &'a [(f64, f64)],
}

impl<'a> FrameMotion<'a> {
    /// The motion of frame times `t`, volumes `v` and flows `f`, with `edges` the
    /// [`ppm_edges`] of `f`.
    pub fn new(t: &'a [f64], v: &'a [f64], f: &'a [f64], edges: &'a [(f64, f64)]) -> Self {
        Self { t, v, f, edges }
    }
}

impl Instants for FrameMotion<'_> {
    fn frames(&self) -> usize {
        self.t.len()
    }
    fn each_frame(&self, mut each: impl FnMut(&[f64], &[f64])) {
        each_frame_instants_from(self.t, self.v, self.f, self.edges, |xs, qs| each(xs, qs));
    }
}

/// Piecewise-parabolic reconstruction of cell averages (Colella & Woodward's PPM, 1984): for each
/// cell the values `(left, right)` at its edges of the parabola `q(x) = left + x(Δ + c(1 − x))`,
/// `x ∈ [0, 1]`, `Δ = right − left`, `c = 6(mean − (left + right)/2)`, whose average over the cell
/// is the given mean.
///
/// Edge values are the fourth-order interpolant of the neighbouring means,
/// `q_{k+½} = 7/12 (q̄_k + q̄_{k+1}) − 1/12 (q̄_{k−1} + q̄_{k+2})` (ends extended by repetition),
/// clamped between the two adjacent means; then the monotonicity limiter: a cell that is a local
/// extremum becomes flat, and a parabola that would overshoot inside its cell has the far edge
/// moved so that it does not. The grid is taken as uniform (frames at a fixed rate).
pub fn ppm_edges(mean: &[f64]) -> Vec<(f64, f64)> {
    let n = mean.len();
    let at = |i: isize| mean[i.clamp(0, n as isize - 1) as usize];
    // edge[k] is the value between cells k − 1 and k.
    let edge: Vec<f64> = (0..=n as isize)
        .map(|k| {
            let e = 7.0 / 12.0 * (at(k - 1) + at(k)) - 1.0 / 12.0 * (at(k - 2) + at(k + 1));
            let (lo, hi) = (at(k - 1).min(at(k)), at(k - 1).max(at(k)));
            e.clamp(lo, hi)
        })
        .collect();
    (0..n)
        .map(|k| {
            let (mut l, mut r, a) = (edge[k], edge[k + 1], mean[k]);
            if (r - a) * (a - l) <= 0.0 {
                (l, r) = (a, a);
            } else {
                let d = r - l;
                let c = 6.0 * (a - 0.5 * (l + r));
                if d * c > d * d {
                    l = 3.0 * a - 2.0 * r;
                } else if -d * d > d * c {
                    r = 3.0 * a - 2.0 * l;
                }
            }
            (l, r)
        })
        .collect()
}

/// The motion of [`FrameMotion`] held whole: frame k's instants at `k·SUB_SAMPLES ..`, in time
/// order.
#[cfg(test)]
pub fn frame_instants(t: &[f64], v: &[f64], f: &[f64]) -> (Vec<f64>, Vec<f64>) {
    let n = t.len();
    let (mut xo, mut qo) = (
        Vec::with_capacity(n * SUB_SAMPLES),
        Vec::with_capacity(n * SUB_SAMPLES),
    );
    each_frame_instants_from(t, v, f, &ppm_edges(f), |xs, qs| {
        xo.extend_from_slice(xs);
        qo.extend_from_slice(qs);
    });
    (xo, qo)
}

/// [`FrameMotion`]'s instants, the flow's [`ppm_edges`] given: `each(x, q)` with frame k's
/// instants (position, flow), k in order.
fn each_frame_instants_from(
    t: &[f64],
    v: &[f64],
    f: &[f64],
    edges: &[(f64, f64)],
    mut each: impl FnMut(&[f64; SUB_SAMPLES], &[f64; SUB_SAMPLES]),
) {
    let n = t.len();
    let mut pos = [0.0; SUB_SAMPLES];
    let (mut xs, mut qs) = ([0.0; SUB_SAMPLES], [0.0; SUB_SAMPLES]);
    for k in 0..n {
        let span = match (k.checked_sub(1), (k + 1 < n).then_some(k + 1)) {
            (Some(a), Some(b)) => 0.5 * (t[b] - t[a]),
            (None, Some(b)) => t[b] - t[k],
            (Some(a), None) => t[k] - t[a],
            (None, None) => 0.0,
        };
        let (l, r) = edges[k];
        let (d, c) = (r - l, 6.0 * (f[k] - 0.5 * (l + r)));
        let mut mean_pos = 0.0;
        for (j, p) in pos.iter_mut().enumerate() {
            let x = (j as f64 + 0.5) / SUB_SAMPLES as f64;
            qs[j] = l + x * (d + c * (1.0 - x));
            // ∫₀ˣ q = l x + Δ x²/2 + c (x²/2 − x³/3), in units of the frame's span.
            *p = span * (l * x + 0.5 * d * x * x + c * (0.5 * x * x - x * x * x / 3.0));
            mean_pos += *p / SUB_SAMPLES as f64;
        }
        for (x, p) in xs.iter_mut().zip(&pos) {
            *x = v[k] + p - mean_pos;
        }
        each(&xs, &qs);
    }
}

/// Volume and flow delayed by `d`, `(v(t − d), v̇(t − d))`, reconstructed between samples by the
/// cubic Hermite interpolant of v with slopes v̇. The flow depends on what a sample is:
///
/// * `frame_means` (an averaging sensor, as our firmware's frames): flow by its own cubic with
///   Akima's slopes ([`akima_slopes`]): the frame-averaged flow of a move is flat between ramps and
///   smooth at the corners, and the volume cubic's derivative would ring into the flat part;
/// * instants: flow as the volume cubic's derivative, a quadratic that matches both sample flows
///   *and* the volume increment, which places a trapezoid's corner inside the interval.
///
/// Before the first sample the first values are held (at rest before the log started).
pub fn delay_hermite(
    t: &[f64],
    v: &[f64],
    f: &[f64],
    d: f64,
    frame_means: bool,
) -> (Vec<f64>, Vec<f64>) {
    let n = t.len();
    let mut vo = Vec::with_capacity(n);
    let mut fo = Vec::with_capacity(n);
    let fm = if frame_means {
        akima_slopes(t, f)
    } else {
        Vec::new()
    };
    let mut j = 0usize;
    for &tk in t {
        let ts = tk - d;
        if ts <= t[0] {
            vo.push(v[0]);
            fo.push(f[0]);
            continue;
        }
        while j + 1 < n && t[j + 1] < ts {
            j += 1;
        }
        if j + 1 >= n {
            vo.push(v[n - 1]);
            fo.push(f[n - 1]);
            continue;
        }
        let h = t[j + 1] - t[j];
        let s = (ts - t[j]) / h;
        let (s2, s3) = (s * s, s * s * s);
        vo.push(
            (2.0 * s3 - 3.0 * s2 + 1.0) * v[j]
                + (s3 - 2.0 * s2 + s) * h * f[j]
                + (-2.0 * s3 + 3.0 * s2) * v[j + 1]
                + (s3 - s2) * h * f[j + 1],
        );
        fo.push(if frame_means {
            (2.0 * s3 - 3.0 * s2 + 1.0) * f[j]
                + (s3 - 2.0 * s2 + s) * h * fm[j]
                + (-2.0 * s3 + 3.0 * s2) * f[j + 1]
                + (s3 - s2) * h * fm[j + 1]
        } else {
            ((6.0 * s2 - 6.0 * s) * v[j] + (-6.0 * s2 + 6.0 * s) * v[j + 1]) / h
                + (3.0 * s2 - 4.0 * s + 1.0) * f[j]
                + (3.0 * s2 - 2.0 * s) * f[j + 1]
        });
    }
    (vo, fo)
}

/// The second derivative at the end of an interval's cubic Hermite (length `h`, volume change
/// `dv`, slopes the flows `f0`, `f1`): `(−6Δv + 2h f₀ + 4h f₁)/h²`.
fn end_accel(h: f64, dv: f64, f0: f64, f1: f64) -> f64 {
    (-6.0 * dv + 2.0 * h * f0 + 4.0 * h * f1) / (h * h)
}

/// Volumetric acceleration at the samples from the past only: the second derivative at the end
/// of the last interval's cubic Hermite (slopes the flows), `(−6Δv + 2h f_{k−1} + 4h f_k)/h²`;
/// 0 at the first sample. The board's form (`model_core::chain`: delivery lag, inertance).
pub fn acceleration_causal(t: &[f64], v: &[f64], f: &[f64]) -> Vec<f64> {
    (0..t.len())
        .map(|k| match k {
            0 => 0.0,
            _ => end_accel(t[k] - t[k - 1], v[k] - v[k - 1], f[k - 1], f[k]),
        })
        .collect()
}

/// Volumetric acceleration at the samples from the same Hermite interpolant (mean of the
/// one-sided second derivatives of the neighbouring intervals). It uses the volume increments as
/// well as the sampled flows, so a short acceleration phase between samples is not smeared over a
/// differentiator's window. Only meaningful when the flow is logged (consistent with the volume).
pub fn acceleration_hermite(t: &[f64], v: &[f64], f: &[f64]) -> Vec<f64> {
    let n = t.len();
    if n < 2 {
        return vec![0.0; n];
    }
    // Second derivative of interval j's cubic at its start (s = 0) and end (s = 1).
    let at = |j: usize, end: bool| {
        let h = t[j + 1] - t[j];
        let dv = v[j + 1] - v[j];
        if end {
            end_accel(h, dv, f[j], f[j + 1])
        } else {
            (6.0 * dv - 4.0 * h * f[j] - 2.0 * h * f[j + 1]) / (h * h)
        }
    };
    (0..n)
        .map(|k| match k {
            0 => at(0, false),
            k if k == n - 1 => at(n - 2, true),
            k => 0.5 * (at(k - 1, true) + at(k, false)),
        })
        .collect()
}

/// Running trapezoidal integral `∫_{t_0}^{t_k} x dt`, zero at the first sample.
pub fn cumulative_integral(t: &[f64], x: &[f64]) -> Vec<f64> {
    let mut out = Vec::with_capacity(x.len());
    let mut acc = 0.0;
    for k in 0..x.len() {
        if k > 0 {
            acc += 0.5 * (x[k] + x[k - 1]) * (t[k] - t[k - 1]);
        }
        out.push(acc);
    }
    out
}

/// Derivative by the three-point formula for non-uniform grids (exact for quadratics), one-sided
/// at the ends.
pub fn derivative(t: &[f64], x: &[f64]) -> Vec<f64> {
    let n = x.len();
    if n < 2 {
        return vec![0.0; n];
    }
    let mut d = Vec::with_capacity(n);
    d.push((x[1] - x[0]) / (t[1] - t[0]));
    for k in 1..n - 1 {
        let h0 = t[k] - t[k - 1];
        let h1 = t[k + 1] - t[k];
        d.push(
            -h1 / (h0 * (h0 + h1)) * x[k - 1]
                + (h1 - h0) / (h0 * h1) * x[k]
                + h0 / (h1 * (h0 + h1)) * x[k + 1],
        );
    }
    d.push((x[n - 1] - x[n - 2]) / (t[n - 1] - t[n - 2]));
    d
}

/// Contiguous runs `[start, end)` where `mask` is true.
pub fn runs(mask: &[bool]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut start = None;
    for (k, &m) in mask.iter().enumerate() {
        match (m, start) {
            (true, None) => start = Some(k),
            (false, Some(s)) => {
                out.push((s, k));
                start = None;
            }
            _ => {}
        }
    }
    if let Some(s) = start {
        out.push((s, mask.len()));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn play_follows_after_half_width() {
        let x = [0.0, 1.0, 2.0, 3.0, 2.0, 1.0, 0.0];
        // Width 2: output trails the rising input by 1, holds for one unit after the reversal.
        assert_eq!(play(&x, 2.0), vec![0.0, 0.0, 1.0, 2.0, 2.0, 2.0, 1.0]);
    }

    #[test]
    fn duhem_switches_exponentially_in_volume_whatever_the_speed() {
        // Up by 3w in one step or in 300: h = 1 − e^{−3} either way; then down by w: 63 % of the way.
        let w = 2.0;
        let fast = duhem(&[0.0, 6.0], w);
        let slow: Vec<f64> = (0..=300).map(|k| k as f64 * 0.02).collect();
        let slow = duhem(&slow, w);
        let up = 1.0 - (-3.0f64).exp();
        assert!((fast[1] - up).abs() < 1e-12 && (slow[300] - up).abs() < 1e-12);
        let back = duhem(&[0.0, 6.0, 4.0], w)[2];
        assert!((back - (-1.0 + (up + 1.0) * (-1.0f64).exp())).abs() < 1e-12);
    }

    #[test]
    fn lag_of_ramp_trails_by_tau() {
        // A ramp through a first-order lag settles to the ramp delayed by τ (known answer).
        let dt = 0.04;
        let t: Vec<f64> = (0..2000).map(|k| k as f64 * dt).collect();
        let x: Vec<f64> = t.iter().map(|&s| 3.0 * s).collect();
        let y = lag_foh(&t, &x, |_| 0.3);
        let last = t.len() - 1;
        assert!((x[last] - y[last] - 3.0 * 0.3).abs() < 1e-9);
    }

    #[test]
    fn lag_on_all_columns_equals_lag_on_each() {
        // 15 columns: a group of eight stepped together, then groups of four, two and one.
        let t: Vec<f64> = (0..300)
            .map(|k| k as f64 * 0.04 + 1e-4 * (k % 3) as f64)
            .collect();
        let cols: Vec<Vec<f64>> = (0..15)
            .map(|j| t.iter().map(|&s| (s * (j + 1) as f64).sin()).collect())
            .collect();
        let c = lag_cubic_coeffs(&t, |k| 0.05 + 0.001 * k as f64);
        let mut all = cols.clone();
        lag_cubic_apply_all(&t, &c, &mut all);
        for (x, y) in cols.iter().zip(&all) {
            assert_eq!(&lag_cubic(&c, x, &akima_slopes(&t, x)), y);
        }
    }

    #[test]
    fn streamed_lag_equals_the_whole_column_lag_across_blocks() {
        // Identity: over 2.3 blocks of rows, with irregular intervals and a varying τ, the
        // in-place lag of all columns (a block at a time, slopes computed per block) equals the
        // lag of each column with its slopes computed over the whole column, to the bit, for
        // Akima's slopes and for the board's backward ones.
        let n = 2 * LAG_BLOCK + 1234;
        let t: Vec<f64> = (0..n)
            .map(|k| k as f64 * 0.04 + 1e-4 * (k % 7) as f64)
            .collect();
        let cols: Vec<Vec<f64>> = (0..3)
            .map(|j| {
                t.iter()
                    .map(|&s| (s * (j + 1) as f64 * 0.7).sin() + (s * 0.05).cos().abs())
                    .collect()
            })
            .collect();
        let c = lag_cubic_coeffs(&t, |k| 0.05 + 0.1 * (k % 500) as f64 / 500.0);
        let mut akima = cols.clone();
        lag_cubic_apply_all(&t, &c, &mut akima);
        let mut causal = cols.clone();
        lag_causal_apply_all(&t, &c, &mut causal);
        for ((x, ya), yc) in cols.iter().zip(&akima).zip(&causal) {
            let first_diff = |a: &[f64], b: &[f64]| a.iter().zip(b).position(|(p, q)| p != q);
            let want = lag_cubic(&c, x, &akima_slopes(&t, x));
            assert_eq!(
                first_diff(&want, ya),
                None,
                "{:?}",
                first_diff(&want, ya).map(|k| (k, want[k], ya[k]))
            );
            let want = lag_cubic(&c, x, &backward_slopes(&t, x));
            assert_eq!(
                first_diff(&want, yc),
                None,
                "{:?}",
                first_diff(&want, yc).map(|k| (k, want[k], yc[k]))
            );
        }
    }

    #[test]
    fn akima_reproduces_a_line_and_keeps_a_corner_flat() {
        let t: Vec<f64> = (0..8).map(|k| 0.5 * k as f64).collect();
        let line: Vec<f64> = t.iter().map(|&s| 3.0 - 2.0 * s).collect();
        assert!(akima_slopes(&t, &line)
            .iter()
            .all(|m| (m + 2.0).abs() < 1e-12));
        // Flat, then a ramp of slope 4 from t = 1.5: the slope stays 0 on the flat side of the
        // corner (a spline would dip there) and is 4 once two secants on each side are straight.
        let x: Vec<f64> = t.iter().map(|&s| 4.0 * (s - 1.5).max(0.0)).collect();
        let m = akima_slopes(&t, &x);
        assert_eq!(&m[..3], &[0.0, 0.0, 0.0]);
        assert!((m[5] - 4.0).abs() < 1e-12);
    }

    #[test]
    fn lag_moments_series_and_recurrence_agree() {
        // Both routes at the switch-over point, and each against the closed forms
        // I_0 = 1 − e^{−r}, I_1 = 1 − (1 − e^{−r})/r.
        for r in [0.49999, 0.5, 0.05, 3.0] {
            let i = lag_moments(r);
            assert!((i[0] + (-r).exp_m1()).abs() < 1e-15);
            assert!((i[1] - (1.0 - (-(-r).exp_m1()) / r)).abs() < 1e-13, "r {r}");
        }
        let (a, b) = (lag_moments(0.4999999), lag_moments(0.5));
        for q in 0..4 {
            assert!((a[q] - b[q]).abs() < 1e-6, "q {q}: {} vs {}", a[q], b[q]);
        }
    }

    #[test]
    fn cubic_lag_with_secant_slopes_is_the_first_order_hold() {
        // Identity: a Hermite interval whose end slopes both equal its secant is the straight line.
        let t: Vec<f64> = (0..400).map(|k| k as f64 * 0.04).collect();
        let x: Vec<f64> = t.iter().map(|&s| (1.3 * s).sin() + 0.2 * s).collect();
        for tau in [0.002, 0.02, 0.3, 5.0] {
            let foh = lag_foh(&t, &x, |_| tau);
            let c = lag_cubic_coeffs(&t, |_| tau);
            let mut y = x[0];
            for k in 1..x.len() {
                let sec = (x[k] - x[k - 1]) / (t[k] - t[k - 1]);
                let [a, w0, w1, m0, m1] = c[k];
                y = a * y + w0 * x[k - 1] + w1 * x[k] + (m0 + m1) * sec;
                assert!(
                    (y - foh[k]).abs() < 1e-12,
                    "tau {tau} k {k}: {y} vs {}",
                    foh[k]
                );
            }
        }
    }

    #[test]
    fn cubic_lag_of_a_sampled_quadratic_is_exact() {
        // A cubic Hermite with the true slopes is the parabola itself, so the weights must give the
        // analytic response of τẏ + y = s² from rest: y = s² − 2τs + 2τ²(1 − e^{−s/τ}).
        let tau: f64 = 0.07;
        let t: Vec<f64> = (0..100).map(|k| k as f64 * 0.04).collect();
        let c = lag_cubic_coeffs(&t, |_| tau);
        let exact =
            |s: f64| s * s - 2.0 * tau * s + 2.0 * tau * tau - 2.0 * tau * tau * (-s / tau).exp();
        let mut y = 0.0;
        for k in 1..t.len() {
            let [a, w0, w1, m0, m1] = c[k];
            let (s0, s1) = (t[k - 1], t[k]);
            y = a * y + w0 * s0 * s0 + w1 * s1 * s1 + m0 * 2.0 * s0 + m1 * 2.0 * s1;
            assert!((y - exact(s1)).abs() < 1e-12, "k {k}: {y} vs {}", exact(s1));
        }
    }

    #[test]
    fn play_frames_of_a_slow_signal_is_the_play_operator() {
        // Known answer: a triangle wave sampled so finely that a frame is a point: plunger lags the
        // nut by w/2 and stands still for w of nut travel after each reversal.
        let dt = 0.001;
        let t: Vec<f64> = (0..4000).map(|k| k as f64 * dt).collect();
        let tri = |s: f64| 10.0 - (10.0 - 10.0 * s).abs();
        let v: Vec<f64> = t.iter().map(|&s| tri(s)).collect();
        let f: Vec<f64> = t
            .iter()
            .map(|&s| if s < 1.0 { 10.0 } else { -10.0 })
            .collect();
        let w = 0.5;
        let (z, q) = play_frames(&t, &v, &f, w);
        let exact = play(&v, w);
        for k in (0..4000).step_by(37) {
            assert!(
                (z[k] - exact[k]).abs() < 0.02,
                "k {k}: {} vs {}",
                z[k],
                exact[k]
            );
        }
        // Rising (after the first w/2): engaged; just after the top: in the dead band.
        assert!((q[500] - 10.0).abs() < 1e-9, "{}", q[500]);
        assert!(q[1010].abs() < 1e-9);
        assert!((q[1200] + 10.0).abs() < 1e-9);
    }

    #[test]
    fn ppm_keeps_each_mean_and_is_exact_for_a_line() {
        // Identity: each parabola's mean over its cell is the cell's mean (it is by construction
        // of c; checked through the edges the limiter produced). A line's cell means give back
        // the line's own edge values.
        let line: Vec<f64> = (0..10).map(|k| 2.0 + 3.0 * k as f64).collect();
        let e = ppm_edges(&line);
        for k in 2..8 {
            assert!((e[k].0 - (line[k] - 1.5)).abs() < 1e-12);
            assert!((e[k].1 - (line[k] + 1.5)).abs() < 1e-12);
        }
        // A ramp starting from rest: no undershoot below 0 in the flat part or the corner cell.
        let ramp: Vec<f64> = (0..10).map(|k| (k as f64 - 3.0).max(0.0)).collect();
        for (k, &(l, r)) in ppm_edges(&ramp).iter().enumerate() {
            assert!(l >= 0.0 && r >= 0.0, "cell {k}: {l} {r}");
            let c = 6.0 * (ramp[k] - 0.5 * (l + r));
            // Mean of the parabola: l + Δ/2 + c/6 = mean.
            assert!((l + 0.5 * (r - l) + c / 6.0 - ramp[k]).abs() < 1e-12);
        }
    }

    #[test]
    fn frame_instants_keep_the_logged_means() {
        let t: Vec<f64> = (0..50).map(|k| 0.04 * k as f64).collect();
        let f: Vec<f64> = t
            .iter()
            .map(|&s| 20.0 * (s - 0.5).clamp(0.0, 1.0))
            .collect();
        let v: Vec<f64> = t.iter().map(|&s| 10.0 * s * s).collect();
        let (x, q) = frame_instants(&t, &v, &f);
        for k in 0..t.len() {
            let xs = &x[k * SUB_SAMPLES..(k + 1) * SUB_SAMPLES];
            let mx = xs.iter().sum::<f64>() / SUB_SAMPLES as f64;
            assert!((mx - v[k]).abs() < 1e-12);
        }
        // On the flat parts of the flow the instants' flow is exactly the logged flow.
        assert!(q[5 * SUB_SAMPLES..6 * SUB_SAMPLES]
            .iter()
            .all(|&q| q == 0.0));
        assert!(q[45 * SUB_SAMPLES..46 * SUB_SAMPLES]
            .iter()
            .all(|&q| (q - 20.0).abs() < 1e-12));
    }

    #[test]
    fn lag_matches_exponential_step_response() {
        let dt = 0.01;
        let t: Vec<f64> = (0..200).map(|k| k as f64 * dt).collect();
        let x: Vec<f64> = (0..200).map(|k| if k == 0 { 0.0 } else { 1.0 }).collect();
        let y = lag_foh(&t, &x, |_| 0.2);
        // Input ramps 0→1 over the first interval, then holds: analytic value at t = 1 s.
        let tau: f64 = 0.2;
        let after_ramp = 1.0 - tau / dt * (1.0 - (-dt / tau).exp());
        let expected = 1.0 - (1.0 - after_ramp) * (-(1.0 - dt) / tau).exp();
        assert!((y[100] - expected).abs() < 1e-12);
    }

    #[test]
    fn delay_and_integral_and_derivative_known_answers() {
        let t: Vec<f64> = (0..50).map(|k| k as f64 * 0.1).collect();
        let x: Vec<f64> = t.iter().map(|&s| 2.0 * s + 1.0).collect();
        // Cubic volume, exact flow: the Hermite interpolant reproduces both exactly.
        let v: Vec<f64> = t.iter().map(|&s| s * s * s - s).collect();
        let f: Vec<f64> = t.iter().map(|&s| 3.0 * s * s - 1.0).collect();
        let ts = t[10] - 0.25;
        for frame_means in [false, true] {
            let (vd, fd) = delay_hermite(&t, &v, &f, 0.25, frame_means);
            assert!((vd[10] - (ts * ts * ts - ts)).abs() < 1e-12);
            // Akima's slopes are exact for a uniformly sampled quadratic too.
            assert!((fd[10] - (3.0 * ts * ts - 1.0)).abs() < 1e-12);
        }
        let a = acceleration_hermite(&t, &v, &f);
        assert!((a[20] - 6.0 * t[20]).abs() < 1e-9);
        let _ = x;
        let i = cumulative_integral(&t, &x);
        assert!((i[40] - (4.0f64.powi(2) + 4.0)).abs() < 1e-9);
        let q: Vec<f64> = t.iter().map(|&s| s * s).collect();
        let d = derivative(&t, &q);
        assert!((d[20] - 2.0 * t[20]).abs() < 1e-9);
        assert_eq!(
            runs(&[false, true, true, false, true]),
            vec![(1, 3), (4, 5)]
        );
    }
}
