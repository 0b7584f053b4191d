//! The output lags (sensor lag, air compliance's dynamic part) as an averaging sensor reports
//! them: each column of the design is rebuilt at the instants a frame averages
//! (`inframe::sub_instants`), run through the lags there and averaged back over each frame,
//!
//! ```text
//! X̄_k = (1/S) Σ_j y(t_kj),   τ_s(t) ẏ_s + y_s = y_{s−1},   y_0 = x(t),
//! ```
//!
//! exact for every coefficient at once because the lags and the mean are linear. Inside a frame:
//!
//! * a baseline column `T_a(v) T_b(v̇)` is evaluated on the motion itself, rebuilt at those
//!   instants (`inframe::sparse_motion`: the flow with the logged means and the fewest corners),
//!   moved by what the input transforms changed at that frame (held over the frame);
//! * an added column, which is a frame value only, follows its cubic between frames (Akima's
//!   slopes, as the frame-level lag used).
//!
//! Either is then shifted so that its mean over the frame is the frame's value, so with no lag
//! the design is the frame-level one exactly.

use super::{Effect, Prepared};
use crate::residual::inframe::{LagChain, SubMotion};
use crate::residual::signal;

/// Frames per block: the baseline's columns are evaluated at the instants of one block at a
/// time, so the design is never held at the instants' resolution.
const BLOCK: usize = 2048;

/// The lags' per-frame time constants in the order they act, when every filter in `filters`
/// (in stage order) is a lag in the loop's frame-mean form; `None` otherwise (a filter in the
/// board's form, [`Effect::point_sampled`], keeps its own frame-level filter).
pub fn lag_time_constants(prep: &Prepared, filters: &[&Effect]) -> Option<Vec<Vec<f64>>> {
    filters
        .iter()
        .map(|e| {
            if e.point_sampled {
                return None;
            }
            e.kind.lag_time_constants(e, prep)
        })
        .collect()
}

/// Replaces every column of `cols` (the first `nb` the baseline's, on the inputs `inputs` when a
/// transform changed them) by its frame means through the lags `taus` inside the frames (module
/// docs).
pub fn apply(
    prep: &Prepared,
    inputs: Option<&(Vec<f64>, Vec<f64>)>,
    nb: usize,
    taus: &[Vec<f64>],
    cols: &mut [Vec<f64>],
) {
    let n = prep.series.len();
    if n < 2 || cols.iter().any(|c| c.len() != n) {
        return;
    }
    let sub = prep.sub_motion();
    let slopes: Vec<Vec<f64>> = cols[nb..]
        .iter()
        .map(|c| signal::akima_slopes(&prep.series.t, c))
        .collect();
    let mut chain = LagChain::new(&sub.t, taus, cols.len());
    let mut out: Vec<Vec<f64>> = vec![Vec::with_capacity(n); cols.len()];
    let mut x = Vec::new();
    for k0 in (0..n).step_by(BLOCK) {
        let k1 = (k0 + BLOCK).min(n);
        let base = baseline_at_instants(prep, sub, inputs, k0..k1);
        chain.block(k0..k1);
        for (c, col) in cols.iter().enumerate() {
            x.clear();
            match c.checked_sub(nb) {
                None => x.extend_from_slice(&base[c]),
                Some(a) => {
                    cubic_at_instants(&prep.series.t, &sub.t, col, &slopes[a], k0..k1, &mut x)
                }
            }
            keep_means(&mut x, &col[k0..k1]);
            chain.frames(c, &x, &mut out[c]);
        }
    }
    for (c, o) in cols.iter_mut().zip(out) {
        *c = o;
    }
}

/// The baseline's columns at the instants of frames `frames`: the rebuilt motion, moved by the
/// input transforms' change at each frame (`inputs` minus the logged volume and flow).
fn baseline_at_instants(
    prep: &Prepared,
    sub: &SubMotion,
    inputs: Option<&(Vec<f64>, Vec<f64>)>,
    frames: std::ops::Range<usize>,
) -> Vec<Vec<f64>> {
    let s = signal::SUB_SAMPLES;
    let rows = frames.start * s..frames.end * s;
    let (mut v, mut f) = (sub.v[rows.clone()].to_vec(), sub.f[rows].to_vec());
    if let Some((vi, fi)) = inputs {
        let se = &prep.series;
        for (i, k) in frames.clone().enumerate() {
            let (dv, df) = (vi[k] - se.v[k], fi[k] - se.vdot[k]);
            v[i * s..(i + 1) * s].iter_mut().for_each(|x| *x += dv);
            f[i * s..(i + 1) * s].iter_mut().for_each(|x| *x += df);
        }
    }
    prep.basis.columns(&v, &f)
}

/// A frame-level column `x` (Akima slopes `m`) at the instants `ts` of frames `frames`: the cubic
/// Hermite of the interval each instant falls in (held beyond the first and last frames).
fn cubic_at_instants(
    t: &[f64],
    ts: &[f64],
    x: &[f64],
    m: &[f64],
    frames: std::ops::Range<usize>,
    out: &mut Vec<f64>,
) {
    let s = signal::SUB_SAMPLES;
    let n = t.len();
    for k in frames {
        for &u in &ts[k * s..(k + 1) * s] {
            let j = if u < t[k] { k.checked_sub(1) } else { Some(k) };
            let Some(j) = j.filter(|&j| j + 1 < n) else {
                out.push(x[k]);
                continue;
            };
            let h = t[j + 1] - t[j];
            let r = (u - t[j]) / h;
            let (r2, r3) = (r * r, r * r * r);
            out.push(
                (2.0 * r3 - 3.0 * r2 + 1.0) * x[j]
                    + (r3 - 2.0 * r2 + r) * h * m[j]
                    + (3.0 * r2 - 2.0 * r3) * x[j + 1]
                    + (r3 - r2) * h * m[j + 1],
            );
        }
    }
}

/// Shifts each frame's values in `x` (S per frame) so that their mean is the frame's `mean`.
fn keep_means(x: &mut [f64], mean: &[f64]) {
    let s = signal::SUB_SAMPLES;
    for (frame, &m) in x.chunks_mut(s).zip(mean) {
        let shift = m - frame.iter().sum::<f64>() / s as f64;
        frame.iter_mut().for_each(|x| *x += shift);
    }
}
