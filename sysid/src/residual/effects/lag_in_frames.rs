//! The output lags (sensor lag, air compliance's dynamic part) as an averaging sensor reports
//! them: each column of the design is rebuilt at the instants a frame averages
//! (`inframe::frame_instants`), run through the lags there and averaged back over each frame,
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
use crate::residual::inframe::{self, LagChain, SubMotion};
use crate::residual::signal;

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
/// docs). One pass over the frames for all columns at once: each frame's values at its instants
/// are made in a small buffer (the baseline's Chebyshev factors once per instant, shared by its
/// columns), shifted to the frame's value, run through the lags column by column in step and
/// averaged, so nothing is held at the instants' resolution.
pub fn apply(
    prep: &Prepared,
    inputs: Option<&(Vec<f64>, Vec<f64>)>,
    nb: usize,
    taus: &[Vec<f64>],
    cols: &mut [Vec<f64>],
) {
    let n = prep.series.len();
    if n < 2 || cols.iter().any(|c| c.len() != n) || taus.is_empty() {
        return;
    }
    let sub = prep.sub_motion();
    let t = &prep.series.t;
    let slopes: Vec<Vec<f64>> = cols[nb..]
        .iter()
        .map(|c| signal::akima_slopes(t, c))
        .collect();
    let chain = LagChain::new(t, taus);
    // Columns are independent: a share of them on each core.
    crate::par::par_chunks_mut(cols, 8, |c0, cols| {
        let shared = Shared {
            prep,
            sub,
            inputs,
            chain: &chain,
            slopes: &slopes,
            nb,
        };
        run_columns(&shared, c0, cols);
    });
}

/// What every share of the columns of [`apply`] reads.
struct Shared<'a> {
    prep: &'a Prepared,
    sub: &'a SubMotion,
    inputs: Option<&'a (Vec<f64>, Vec<f64>)>,
    chain: &'a LagChain,
    /// The added columns' Akima slopes (column `nb + a`'s at `a`).
    slopes: &'a [Vec<f64>],
    /// The baseline's columns are the first `nb` of the design.
    nb: usize,
}

/// [`apply`] on the design's columns `c0 ..` (`cols`).
fn run_columns(sh: &Shared<'_>, c0: usize, cols: &mut [Vec<f64>]) {
    let (n, nc) = (sh.prep.series.len(), cols.len());
    let t = &sh.prep.series.t;
    let mut frame = Frame::new(c0, nc, sh.chain.lags());
    // The frames' values a block at a time, frame by frame (one column after another, the reads
    // and writes stream; frame by frame across 50 columns, they would miss the cache).
    let mut tile = Vec::with_capacity(TILE * nc);
    for k0 in (0..n).step_by(TILE) {
        let k1 = (k0 + TILE).min(n);
        tile.clear();
        tile.resize((k1 - k0) * nc, 0.0);
        for (c, col) in cols.iter().enumerate() {
            for (i, &x) in col[k0..k1].iter().enumerate() {
                tile[i * nc + c] = x;
            }
        }
        for (k, row) in (k0..k1).zip(tile.chunks_exact_mut(nc)) {
            frame.coefficients(sh.chain, k);
            frame.baseline(sh, k);
            frame.added(sh, &inframe::frame_instants(t, k), cols, k);
            frame.lag_and_average(row);
        }
        for (c, col) in cols.iter_mut().enumerate() {
            for (i, x) in col[k0..k1].iter_mut().enumerate() {
                *x = tile[i * nc + c];
            }
        }
    }
}

/// Frames per block of [`apply`].
const TILE: usize = 128;

/// Instants per frame.
const S: usize = signal::SUB_SAMPLES;

/// The working state of [`apply`]: one frame's values at its instants, the lags' states and
/// coefficients, per column.
struct Frame {
    /// The design's index of the first column here, and the number of columns.
    c0: usize,
    nc: usize,
    lags: usize,
    /// `x[j·nc + c]`: column c at the frame's instant j.
    x: Vec<f64>,
    /// Per lag s and column c (`s·nc + c`), the lag's output and input at the last instant.
    y: Vec<f64>,
    xin: Vec<f64>,
    /// Per lag s and instant j (`s·S + j`), the coefficients of the interval ending there.
    coef: Vec<(f64, f64)>,
    /// Column c's frame value before it was replaced (the cubic of the next frame needs it).
    prev: Vec<f64>,
    /// Per column: the shift to the frame's value, the running sum, the value passing the lags.
    shift: Vec<f64>,
    sum: Vec<f64>,
    u: Vec<f64>,
    started: bool,
}

impl Frame {
    fn new(c0: usize, nc: usize, lags: usize) -> Self {
        Self {
            c0,
            nc,
            lags,
            x: vec![0.0; S * nc],
            y: vec![0.0; lags * nc],
            xin: vec![0.0; lags * nc],
            coef: vec![(0.0, 1.0); lags * S],
            prev: vec![0.0; nc],
            shift: vec![0.0; nc],
            sum: vec![0.0; nc],
            u: vec![0.0; nc],
            started: false,
        }
    }

    /// The lags' coefficients over frame k's instants.
    fn coefficients(&mut self, chain: &LagChain, k: usize) {
        for s in 0..self.lags {
            for j in 0..S {
                self.coef[s * S + j] = chain.coefficients(s, k, j);
            }
        }
    }

    /// The baseline's columns (those here) at frame k's instants: the rebuilt motion, moved by
    /// the input transforms' change at the frame (`inputs` minus the logged volume and flow).
    fn baseline(&mut self, sh: &Shared<'_>, k: usize) {
        let end = sh.nb.min(self.c0 + self.nc);
        if self.c0 >= end {
            return;
        }
        let se = &sh.prep.series;
        let (dv, df) = sh
            .inputs
            .map_or((0.0, 0.0), |(vi, fi)| (vi[k] - se.v[k], fi[k] - se.vdot[k]));
        let basis = &sh.prep.basis;
        let (dn, dm) = (basis.n, basis.m);
        // Column c is T_a(v)·T_b(v̇) with (a, b) = (c / w, c % w): runs of consecutive b per a.
        let w = dm + 1;
        let (mut tv, mut tf) = ([0.0; 16], [0.0; 16]);
        let (v, f) = (sh.sub.volumes(&se.t, &se.v, k), sh.sub.flows(k));
        for j in 0..S {
            let (xs, ys) = basis.scaling.apply(v[j] + dv, f[j] + df);
            crate::poly::chebyshev(xs, &mut tv[..=dn]);
            crate::poly::chebyshev(ys, &mut tf[..=dm]);
            let row = &mut self.x[j * self.nc..j * self.nc + end - self.c0];
            let mut c = self.c0;
            let mut at = 0;
            while c < end {
                let (a, b0) = (c / w, c % w);
                let run = (w - b0).min(end - c);
                let ta = tv[a];
                for (out, &tb) in row[at..at + run].iter_mut().zip(&tf[b0..b0 + run]) {
                    *out = ta * tb;
                }
                (c, at) = (c + run, at + run);
            }
        }
    }

    /// The added columns here (frame values only) at frame k's instants `ts`: each column's
    /// cubic Hermite (Akima slopes) of the interval each instant falls in, held beyond the first
    /// and last frames.
    fn added(&mut self, sh: &Shared<'_>, ts: &[f64], cols: &[Vec<f64>], k: usize) {
        let t = &sh.prep.series.t;
        let n = t.len();
        let first = sh.nb.max(self.c0) - self.c0;
        if first >= self.nc {
            return;
        }
        for (j, &u) in ts.iter().enumerate() {
            let lo = if u < t[k] { k.checked_sub(1) } else { Some(k) };
            let row = &mut self.x[j * self.nc..(j + 1) * self.nc];
            let Some(lo) = lo.filter(|&lo| lo + 1 < n) else {
                for c in first..self.nc {
                    row[c] = cols[c][k];
                }
                continue;
            };
            let h = t[lo + 1] - t[lo];
            let r = (u - t[lo]) / h;
            let (r2, r3) = (r * r, r * r * r);
            let w = [
                2.0 * r3 - 3.0 * r2 + 1.0,
                (r3 - 2.0 * r2 + r) * h,
                3.0 * r2 - 2.0 * r3,
                (r3 - r2) * h,
            ];
            let slopes = &sh.slopes[self.c0 + first - sh.nb..];
            for (c, m) in (first..self.nc).zip(slopes) {
                // The frame before's value as it was (`cols` may hold its new one).
                let x0 = if lo < k { self.prev[c] } else { cols[c][lo] };
                row[c] = w[0] * x0 + w[1] * m[lo] + w[2] * cols[c][lo + 1] + w[3] * m[lo + 1];
            }
        }
    }

    /// Each column's values shifted so that their mean is the frame's value, through the lags
    /// (started at rest at the first instant), averaged: the frame's new values replace its
    /// values `row` (one per column).
    fn lag_and_average(&mut self, row: &mut [f64]) {
        let nc = self.nc;
        for (c, sh) in self.shift.iter_mut().enumerate() {
            let sum: f64 = (0..S).map(|j| self.x[j * nc + c]).sum();
            *sh = row[c] - sum / S as f64;
        }
        if !self.started {
            for s in 0..self.lags {
                for c in 0..nc {
                    let x0 = self.x[c] + self.shift[c];
                    (self.y[s * nc + c], self.xin[s * nc + c]) = (x0, x0);
                }
            }
            self.started = true;
        }
        self.sum.fill(0.0);
        for (j, xj) in self.x.chunks_exact(nc).enumerate() {
            for ((u, x), sh) in self.u.iter_mut().zip(xj).zip(&self.shift) {
                *u = x + sh;
            }
            for ((y, xin), &(a, one_minus_g)) in self
                .y
                .chunks_exact_mut(nc)
                .zip(self.xin.chunks_exact_mut(nc))
                .zip(self.coef.iter().skip(j).step_by(S))
            {
                for ((y, xin), u) in y.iter_mut().zip(xin.iter_mut()).zip(self.u.iter_mut()) {
                    let out = a * *y + (1.0 - a) * *xin + one_minus_g * (*u - *xin);
                    (*y, *xin) = (out, *u);
                    *u = out;
                }
            }
            for (sum, u) in self.sum.iter_mut().zip(&self.u) {
                *sum += u;
            }
        }
        for ((x, prev), sum) in row.iter_mut().zip(&mut self.prev).zip(&self.sum) {
            *prev = *x;
            *x = sum / S as f64;
        }
    }
}
