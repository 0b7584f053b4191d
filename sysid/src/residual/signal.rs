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
/// The hold matters: a zero-order hold would add a spurious half-sample delay that a delay or lag
/// candidate would then have to explain.
///
/// [`lag_coeffs`] computes the per-sample `(a, 1 − g)` once, [`lag_apply`] applies them to each of
/// many columns (the exponentials would dominate otherwise).
#[cfg(test)]
pub fn lag_foh(t: &[f64], x: &[f64], tau: impl Fn(usize) -> f64) -> Vec<f64> {
    lag_apply(&lag_coeffs(t, tau), x)
}

/// Per-sample coefficients `(a, 1 − g)` of the first-order-hold lag (see [`lag_foh`]).
pub fn lag_coeffs(t: &[f64], tau: impl Fn(usize) -> f64) -> Vec<(f64, f64)> {
    let mut c = Vec::with_capacity(t.len());
    c.push((0.0, 1.0));
    // A log's intervals repeat (a fixed frame rate): reuse the last coefficients when Δt and τ do.
    let mut last = (f64::NAN, f64::NAN, (0.0, 1.0));
    for k in 1..t.len() {
        let dt = t[k] - t[k - 1];
        let tk = tau(k);
        if dt == last.0 && tk == last.1 {
            c.push(last.2);
            continue;
        }
        let ck = if tk <= 1e-9 * dt {
            (0.0, 1.0)
        } else {
            let r = dt / tk;
            // 1 − a = −expm1(−r) without cancellation; g = (1 − a)/r, by its series for tiny r.
            let one_minus_a = -(-r).exp_m1();
            let g = if r < 1e-6 {
                1.0 - 0.5 * r
            } else {
                one_minus_a / r
            };
            (1.0 - one_minus_a, 1.0 - g)
        };
        last = (dt, tk, ck);
        c.push(ck);
    }
    c
}

/// Applies precomputed lag coefficients: `y_k = a y_{k−1} + (1 − a) x_{k−1} + (1 − g)(x_k − x_{k−1})`.
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

/// [`lag_apply`] on many columns at once, in place. The recurrence is a serial chain per column
/// (latency-bound); stepping all columns together at each sample lets their independent chains
/// overlap in the pipeline, several times faster than one column after another.
pub fn lag_apply_all(coeffs: &[(f64, f64)], cols: &mut [Vec<f64>]) {
    let n = cols.first().map_or(0, Vec::len);
    if n == 0 || cols.iter().any(|c| c.len() != n) {
        for c in cols.iter_mut() {
            *c = lag_apply(coeffs, c);
        }
        return;
    }
    // Per column: (previous output, previous input).
    let mut state: Vec<(f64, f64)> = cols.iter().map(|c| (c[0], c[0])).collect();
    for k in 1..n {
        let (a, h) = coeffs[k];
        let b = 1.0 - a;
        for (c, st) in cols.iter_mut().zip(state.iter_mut()) {
            let x = c[k];
            let y = a * st.0 + b * st.1 + h * (x - st.1);
            c[k] = y;
            *st = (y, x);
        }
    }
}

/// Volume and flow delayed by `d`, `(v(t − d), v̇(t − d))`, reconstructed between samples by the
/// cubic Hermite interpolant of v with slopes v̇ (flow is then the interpolant's derivative, a
/// quadratic that matches both sample flows *and* the volume increment, so a trapezoid's corner
/// inside an interval is placed far better than by linear interpolation of the flow). Before the
/// first sample the first values are held (at rest before the log started).
pub fn delay_hermite(t: &[f64], v: &[f64], f: &[f64], d: f64) -> (Vec<f64>, Vec<f64>) {
    let n = t.len();
    let mut vo = Vec::with_capacity(n);
    let mut fo = Vec::with_capacity(n);
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
        fo.push(
            ((6.0 * s2 - 6.0 * s) * v[j] + (-6.0 * s2 + 6.0 * s) * v[j + 1]) / h
                + (3.0 * s2 - 4.0 * s + 1.0) * f[j]
                + (3.0 * s2 - 2.0 * s) * f[j + 1],
        );
    }
    (vo, fo)
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
            (-6.0 * dv + 2.0 * h * f[j] + 4.0 * h * f[j + 1]) / (h * h)
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
        let t: Vec<f64> = (0..300)
            .map(|k| k as f64 * 0.04 + 1e-4 * (k % 3) as f64)
            .collect();
        let cols: Vec<Vec<f64>> = (0..5)
            .map(|j| t.iter().map(|&s| (s * (j + 1) as f64).sin()).collect())
            .collect();
        let c = lag_coeffs(&t, |k| 0.05 + 0.001 * k as f64);
        let mut all = cols.clone();
        lag_apply_all(&c, &mut all);
        for (x, y) in cols.iter().zip(&all) {
            assert_eq!(&lag_apply(&c, x), y);
        }
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
        let (vd, fd) = delay_hermite(&t, &v, &f, 0.25);
        let ts = t[10] - 0.25;
        assert!((vd[10] - (ts * ts * ts - ts)).abs() < 1e-12);
        assert!((fd[10] - (3.0 * ts * ts - 1.0)).abs() < 1e-12);
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
