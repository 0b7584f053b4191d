//! Physics-inspired exponential model (paper Table II):
//!
//! ```text
//! P̂(t) = Σ_{i=1..k} αᵢ exp(βᵢ v(t)) + γ v̇(t) + δ
//! ```
//!
//! The exponentials stand for the hyper-elastic chamber, the affine flow term for Hagen–Poiseuille
//! losses in the tubing. The paper sweeps k = 1..10 (Table III lists k = 1..5).
//!
//! # Method: variable projection
//! For fixed β the model is linear in θ = (α, δ, γ), so θ is eliminated by linear least squares and
//! only β is optimised (Golub & Pereyra 1973, SIAM J. Numer. Anal. 10(2); Jacobian approximation of
//! Kaufman 1975, BIT 15):
//!
//! ```text
//! r(β) = P⊥_{A(β)} y,     Jᵢ = −αᵢ P⊥_{A(β)} ∂A/∂βᵢ e_i = −αᵢ P⊥ (v ⊙ exp(βᵢ v)),
//! ```
//!
//! with a Levenberg–Marquardt step `(JᵀJ + λ diag JᵀJ) Δβ = −Jᵀr`, accepted only when it lowers the
//! sum of squared errors (SSE). One Householder QR of the augmented, column-normalised block
//! `[A | ∂A/∂β | y]` gives everything at once: the triangle of A for θ, and the rows below it
//! hold the components orthogonal to span(A), so `P⊥ y`, `(P⊥hᵢ)ᵀ(P⊥hⱼ)` and `(P⊥hᵢ)ᵀ(P⊥y)` are
//! inner products of short columns of R — no normal equations on the nearly collinear exp columns.
//! θ is then taken from that triangle by a truncated SVD, so near-equal βs give a minimum-norm θ
//! instead of blowing up.
//!
//! β is optimised in the scaled volume u = (v − v_min)/(v_max − v_min) ∈ [0, 1] (b = β·span) so that
//! exp stays in range whatever the volume units or offset; |b| ≤ [`B_MAX`].
//!
//! # Exact data reduction
//! The exponential basis depends on v only, and a syringe volume takes few distinct values (steps ×
//! 0.04 mm³). Grouping the N samples by distinct volume j (count nⱼ, means v̇̄ⱼ, P̄ⱼ) and writing
//! each sample as group mean plus deviation, the cross terms vanish and
//!
//! ```text
//! SSE = Σⱼ nⱼ (P̄ⱼ − f(vⱼ) − γ v̇̄ⱼ)² + (√S_vv γ − S_vp/√S_vv)² + (S_pp − S_vp²/S_vv),
//! ```
//!
//! where f(v) = Σ αᵢ e^{βᵢ v} + δ and S are the within-group (co)variances of v̇ and P. That is an
//! exactly equivalent least-squares problem with one row per distinct volume plus one row for γ.
//!
//! # Exact projection onto a Chebyshev subspace
//! A log at 25 Hz from a 0.04 mm³-step pump still has ~10⁴ distinct volumes, and every LM trial
//! would factor a 10⁴-row matrix. But every column that depends on β is smooth in u: e^{bu} and
//! u·e^{bu} (|b| ≤ [`B_MAX`]) equal their Chebyshev series of degree [`CHEB_DEGREE`] in
//! x = 2u − 1 to within ~1e−16 of their largest value (coefficients 2·I_n(b/2)·e^{b/2}, with
//! I_n(20)/e^{20} < 1e−17 for n ≥ 40). So all model columns lie in the fixed subspace
//!
//! ```text
//! S = span{ √nⱼ·T₀(xⱼ), …, √nⱼ·T_D(xⱼ), √nⱼ·v̇̄ⱼ }          (plus √S_vv in the γ row)
//! ```
//!
//! and `‖y − Aθ‖² = ‖Qᵀy − QᵀAθ‖² + ‖(I − QQᵀ)y‖²` for any orthonormal basis Q of S: the second
//! term does not depend on β or θ. The Gram matrix of S comes from weighted Chebyshev moments in
//! one pass (`T_a T_b = ½(T_{a+b} + T_{|a−b|})`, the same device as the polynomial sweep), Q from
//! its eigen-decomposition after unit-diagonal scaling (directions with eigenvalue below 1e−13 of
//! the largest are invisible on the data and dropped), and a column with Chebyshev coefficients
//! c has coordinates `Λ^{1/2} Vᵀ S c` in Q. The constant `‖(I − QQᵀ)y‖²` is computed directly as
//! the residual of y on S, not by subtraction. Every LM trial then factors a matrix of at most
//! D + 2 rows, whatever the log's length, and the result is the exact-data optimum — no binning.
//! The reported SSE is recomputed on the grouped rows.
//!
//! # Nesting
//! The k-term search starts from the (k−1)-term βs plus one new β, the best of a log-spaced grid
//! (adding a column never raises a least-squares residual), and LM only accepts decreases, so the
//! k-term SSE is never above the (k−1)-term one. The final exact solve is checked against that too:
//! should rounding make it worse, the (k−1)-term model with αₖ = 0 is returned, which is a valid
//! k-term model with the same SSE.

use core::fmt;
use nalgebra::{DMatrix, DVector};

/// Bound on the scaled rate |b| = |β|·(v_max − v_min); e^40 ≈ 2·10¹⁷ is far past any chamber.
pub const B_MAX: f64 = 40.0;
/// Degree D of the Chebyshev subspace the problem is projected onto (see the module docs).
pub const CHEB_DEGREE: usize = 48;
/// Smallest gap between scaled rates, and between a rate and 0 (the δ column). Closer rates make
/// nearly collinear columns whose least-squares amplitudes cancel in huge ± pairs (the optimum of
/// an over-parameterised k drifts there); over u ∈ [0, 1], e^{bu} and e^{(b+0.5)u} differ by at
/// most a factor 1.65, so little fit is lost.
pub const B_GAP: f64 = 0.5;
/// Levenberg–Marquardt iteration cap per k.
const MAX_ITER: usize = 100;
/// LM stops when an accepted step lowers the SSE by less than this fraction.
const REL_TOL: f64 = 1e-8;
/// Starting values tried for each new scaled rate b.
const B_GRID: [f64; 14] = [
    -24.0, -12.0, -6.0, -3.0, -1.5, -0.7, -0.3, 0.3, 0.7, 1.5, 3.0, 6.0, 12.0, 24.0,
];

/// A fitted exponential model `P̂ = Σ αᵢ exp(βᵢ v) + γ v̇ + δ`, in log units (mm³, mm³/s, kPa).
#[derive(Debug, Clone, PartialEq)]
pub struct ExpFit {
    /// Number of exponential terms.
    pub k: usize,
    /// Amplitudes αᵢ (kPa).
    pub alpha: Vec<f64>,
    /// Rates βᵢ (1/mm³).
    pub beta: Vec<f64>,
    /// Flow coefficient γ (kPa·s/mm³).
    pub gamma: f64,
    /// Offset δ (kPa).
    pub delta: f64,
    /// Sum of squared errors on the fitted samples (kPa²).
    pub sse: f64,
}

impl ExpFit {
    /// Predicted pressure at volume `v` and flow `vdot`.
    pub fn predict(&self, v: f64, vdot: f64) -> f64 {
        let elastic: f64 = self
            .alpha
            .iter()
            .zip(&self.beta)
            .map(|(a, b)| a * (b * v).exp())
            .sum();
        elastic + self.gamma * vdot + self.delta
    }

    /// Number of fitted parameters ν = 2k + 2 (Table III).
    pub fn n_params(&self) -> usize {
        2 * self.k + 2
    }
}

/// Why an exponential fit could not be made.
#[derive(Debug, Clone, PartialEq)]
pub enum ExpError {
    /// k = 0 was asked for; the model needs at least one exponential term.
    ZeroTerms,
    /// The three columns differ in length.
    LengthMismatch { v: usize, vdot: usize, p: usize },
    /// A value is NaN or infinite (`column` is `v`, `vdot` or `p`; `index` is the sample index).
    NonFinite { column: &'static str, index: usize },
    /// Fewer samples than parameters + 1.
    TooFewSamples { needed: usize, got: usize },
    /// Fewer distinct volumes than the 2k + 1 parameters of the volume part (e.g. constant v).
    TooFewVolumes { needed: usize, distinct: usize },
    /// The solve produced a non-finite value (data far outside the range exp can represent).
    NoConvergence { k: usize },
}

impl fmt::Display for ExpError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ExpError::ZeroTerms => write!(f, "exponential model needs k >= 1 terms"),
            ExpError::LengthMismatch { v, vdot, p } => write!(
                f,
                "columns differ in length: volume {v}, flow {vdot}, pressure {p} samples"
            ),
            ExpError::NonFinite { column, index } => {
                write!(f, "non-finite {column} at sample {index}; clean or drop that row")
            }
            ExpError::TooFewSamples { needed, got } => write!(
                f,
                "exponential fit needs at least {needed} samples, got {got}"
            ),
            ExpError::TooFewVolumes { needed, distinct } => write!(
                f,
                "exponential fit needs at least {needed} distinct volumes, the data has {distinct}; \
                 the log must sweep the volume range"
            ),
            ExpError::NoConvergence { k } => write!(
                f,
                "exponential fit with k = {k} produced non-finite values; \
                 check the volume range and units"
            ),
        }
    }
}

impl std::error::Error for ExpError {}

/// Fits the k-term model. Runs the nested sweep 1..=k internally (each k warm-starts the next).
pub fn fit(v: &[f64], vdot: &[f64], p: &[f64], k: usize) -> Result<ExpFit, ExpError> {
    if k == 0 {
        return Err(ExpError::ZeroTerms);
    }
    sweep(v, vdot, p, k)
        .pop()
        .expect("sweep returns k_max results")
}

/// Fits k = 1..=k_max; element i holds the (i+1)-term model. In-sample SSE never rises with k.
pub fn sweep(v: &[f64], vdot: &[f64], p: &[f64], k_max: usize) -> Vec<Result<ExpFit, ExpError>> {
    let exact = match Reduced::exact(v, vdot, p) {
        Ok(r) => r,
        Err(e) => return vec![Err(e); k_max],
    };
    // Few distinct volumes: the grouped problem is already small, solve it directly.
    let projected = (exact.len() > 4 * (CHEB_DEGREE + 2)).then(|| Projected::new(&exact));
    let search: &dyn Problem = match &projected {
        Some(p) => p,
        None => &exact,
    };
    let n = v.len();
    let mut out = Vec::with_capacity(k_max);
    let mut prev_b: Vec<f64> = Vec::new();
    let mut prev_fit: Option<ExpFit> = None;
    for k in 1..=k_max {
        let needed_n = 2 * k + 3;
        if n < needed_n {
            out.push(Err(ExpError::TooFewSamples {
                needed: needed_n,
                got: n,
            }));
            continue;
        }
        if exact.len() < 2 * k + 1 {
            out.push(Err(ExpError::TooFewVolumes {
                needed: 2 * k + 1,
                distinct: exact.len(),
            }));
            continue;
        }
        // Warm start: previous rates plus the best new rate from the grid.
        let mut best: Option<(Vec<f64>, f64)> = None;
        for &g in &B_GRID {
            let mut b = prev_b.clone();
            b.push(g);
            separate(&mut b);
            if let Some(s) = search.solve(&b, false) {
                if best.as_ref().is_none_or(|(_, bs)| s.sse < *bs) {
                    best = Some((b, s.sse));
                }
            }
        }
        let Some((b0, _)) = best else {
            out.push(Err(ExpError::NoConvergence { k }));
            continue;
        };
        let b = levenberg_marquardt(search, b0, MAX_ITER);
        let fit = search
            .solve(&b, false)
            .and_then(|s| exact.to_fit(&b, &s))
            .filter(|f| f.sse.is_finite());
        // Keep the better of this fit and the (k−1)-term fit padded with αₖ = 0.
        let fit = match (fit, &prev_fit) {
            (Some(f), Some(pf)) if f.sse > pf.sse => pad(pf, k),
            (Some(f), _) => f,
            (None, Some(pf)) => pad(pf, k),
            (None, None) => {
                out.push(Err(ExpError::NoConvergence { k }));
                continue;
            }
        };
        prev_b = fit
            .beta
            .iter()
            .map(|beta| beta * exact.span)
            .collect::<Vec<_>>();
        prev_fit = Some(fit.clone());
        out.push(Ok(fit));
    }
    out
}

/// The (k−1)-term fit as a k-term fit with a zero-amplitude last term (same predictions, same SSE).
fn pad(prev: &ExpFit, k: usize) -> ExpFit {
    let mut f = prev.clone();
    f.k = k;
    f.alpha.push(0.0);
    f.beta.push(*prev.beta.last().unwrap_or(&0.0));
    f
}

/// LM on the scaled rates b over the reduced problem; returns the best b seen.
fn levenberg_marquardt(red: &dyn Problem, mut b: Vec<f64>, max_iter: usize) -> Vec<f64> {
    let k = b.len();
    let Some(mut cur) = red.solve(&b, true) else {
        return b;
    };
    let mut lambda = 1e-3;
    for _ in 0..max_iter {
        let (jtj, jtr) = (&cur.jtj, &cur.jtr);
        let mut improved = false;
        while lambda < 1e12 {
            let mut m = jtj.clone();
            for i in 0..k {
                m[(i, i)] += lambda * jtj[(i, i)].max(1e-12 * (1.0 + jtj.diagonal().max()));
            }
            let Some(ch) = m.cholesky() else {
                lambda *= 4.0;
                continue;
            };
            let step = ch.solve(&(-jtr));
            let mut trial: Vec<f64> = b.iter().zip(step.iter()).map(|(bi, di)| bi + di).collect();
            separate(&mut trial);
            let moved = trial.iter().zip(&b).any(|(t, o)| (t - o).abs() > 1e-12);
            if !moved {
                lambda = f64::INFINITY;
                break;
            }
            match red.solve(&trial, true) {
                Some(s) if s.sse < cur.sse => {
                    let rel = (cur.sse - s.sse) / cur.sse.max(f64::MIN_POSITIVE);
                    b = trial;
                    cur = s;
                    lambda = (lambda * 0.3).max(1e-12);
                    improved = rel > REL_TOL;
                    break;
                }
                _ => lambda *= 4.0,
            }
        }
        if !improved {
            break;
        }
    }
    b
}

/// Moves the scaled rates into the feasible set: |b| ≤ [`B_MAX`], and every two of {b₁..b_k, 0}
/// at least [`B_GAP`] apart. Keeps order within each sign; LM accepts the moved point only if it
/// lowers the SSE, so this is a safeguard, not a projection with optimality claims.
fn separate(b: &mut [f64]) {
    b.sort_unstable_by(f64::total_cmp);
    let split = b.partition_point(|x| *x < 0.0);
    let (neg, pos) = b.split_at_mut(split);
    spread(pos);
    neg.iter_mut().for_each(|x| *x = -*x);
    neg.reverse();
    spread(neg);
    neg.reverse();
    neg.iter_mut().for_each(|x| *x = -*x);
}

/// Ascending positives: pushes up from B_GAP, then down from B_MAX, keeping gaps ≥ B_GAP.
fn spread(b: &mut [f64]) {
    let mut lo = B_GAP;
    for x in b.iter_mut() {
        *x = x.max(lo);
        lo = *x + B_GAP;
    }
    let mut hi = B_MAX;
    for x in b.iter_mut().rev() {
        *x = x.min(hi);
        hi = *x - B_GAP;
    }
}

/// Least-squares problem equivalent to the full one, one weighted row per volume (group or bin).
struct Reduced {
    /// Scaled volume of each row, in [0, 1].
    u: Vec<f64>,
    /// √(samples in the row).
    w: Vec<f64>,
    /// Mean flow of the row's samples.
    vdot: Vec<f64>,
    /// Mean pressure of the row's samples.
    p: Vec<f64>,
    /// Within-row Σ(v̇ − v̇̄)², Σ(v̇ − v̇̄)(P − P̄), Σ(P − P̄)².
    svv: f64,
    svp: f64,
    spp: f64,
    v_min: f64,
    span: f64,
}

/// Solution of the linear subproblem at fixed b.
struct Solved {
    /// θ = (a₁..a_k, δ, γ) in scaled-volume form: P̂ = Σ aᵢ e^{bᵢu} + δ + γ v̇.
    theta: Vec<f64>,
    /// SSE of the full data set (the constant part of the reduction included).
    sse: f64,
    /// Kaufman JᵀJ and Jᵀr (only when asked for).
    jtj: DMatrix<f64>,
    jtr: DVector<f64>,
}

impl Reduced {
    fn len(&self) -> usize {
        self.u.len()
    }

    /// Groups samples by exactly equal volume (the reduction is then exact).
    fn exact(v: &[f64], vdot: &[f64], p: &[f64]) -> Result<Self, ExpError> {
        if v.len() != vdot.len() || v.len() != p.len() {
            return Err(ExpError::LengthMismatch {
                v: v.len(),
                vdot: vdot.len(),
                p: p.len(),
            });
        }
        for (column, xs) in [("v", v), ("vdot", vdot), ("p", p)] {
            if let Some(index) = xs.iter().position(|x| !x.is_finite()) {
                return Err(ExpError::NonFinite { column, index });
            }
        }
        if v.len() < 5 {
            return Err(ExpError::TooFewSamples {
                needed: 5,
                got: v.len(),
            });
        }
        let mut idx: Vec<u32> = (0..v.len() as u32).collect();
        idx.sort_unstable_by(|&a, &b| v[a as usize].total_cmp(&v[b as usize]));
        let v_min = v[idx[0] as usize];
        let v_max = v[*idx.last().unwrap() as usize];
        let span = v_max - v_min;
        let mut red = Reduced {
            u: Vec::new(),
            w: Vec::new(),
            vdot: Vec::new(),
            p: Vec::new(),
            svv: 0.0,
            svp: 0.0,
            spp: 0.0,
            v_min,
            span: if span > 0.0 { span } else { 1.0 },
        };
        let mut start = 0;
        while start < idx.len() {
            let vj = v[idx[start] as usize];
            let mut end = start + 1;
            while end < idx.len() && v[idx[end] as usize] == vj {
                end += 1;
            }
            let g = &idx[start..end];
            let n = g.len() as f64;
            // Two passes (mean, then deviations) keep the within-group sums accurate.
            let mq = g.iter().map(|&i| vdot[i as usize]).sum::<f64>() / n;
            let mp = g.iter().map(|&i| p[i as usize]).sum::<f64>() / n;
            for &i in g {
                let (dq, dp) = (vdot[i as usize] - mq, p[i as usize] - mp);
                red.svv += dq * dq;
                red.svp += dq * dp;
                red.spp += dp * dp;
            }
            red.u.push((vj - v_min) / red.span);
            red.w.push(n.sqrt());
            red.vdot.push(mq);
            red.p.push(mp);
            start = end;
        }
        Ok(red)
    }

    /// The exact SSE of θ = (a₁..a_k, δ, γ) at scaled rates `b`, from the grouped rows.
    fn sse(&self, b: &[f64], theta: &[f64]) -> f64 {
        let k = b.len();
        let (delta, gamma) = (theta[k], theta[k + 1]);
        let between: f64 = (0..self.len())
            .map(|j| {
                let u = self.u[j];
                let f: f64 = (0..k).map(|i| theta[i] * (b[i] * u).exp()).sum();
                let r = self.w[j] * (self.p[j] - f - delta - gamma * self.vdot[j]);
                r * r
            })
            .sum();
        between + gamma * gamma * self.svv - 2.0 * gamma * self.svp + self.spp
    }

    /// Converts a scaled solution to the paper's parameters: aᵢe^{bᵢu} = αᵢe^{βᵢv} with
    /// βᵢ = bᵢ/span and αᵢ = aᵢ e^{−βᵢ v_min}; the SSE is recomputed on the grouped rows.
    fn to_fit(&self, b: &[f64], s: &Solved) -> Option<ExpFit> {
        let k = b.len();
        let beta: Vec<f64> = b.iter().map(|bi| bi / self.span).collect();
        let alpha: Vec<f64> = (0..k)
            .map(|i| s.theta[i] * (-beta[i] * self.v_min).exp())
            .collect();
        if alpha.iter().any(|a| !a.is_finite()) {
            return None;
        }
        Some(ExpFit {
            k,
            alpha,
            beta,
            delta: s.theta[k],
            gamma: s.theta[k + 1],
            sse: self.sse(b, &s.theta).max(0.0),
        })
    }
}

/// A separable least-squares problem in the scaled rates b: the weighted design block
/// `[A(b) | ∂A/∂b | y]` (columns e^{bᵢu}…, 1, v̇, u·e^{bᵢu}…, P) in some row basis, plus the
/// part of the SSE no column can reach.
trait Problem {
    /// The design block at `b` (derivative columns only with `jac`) and the unreachable SSE.
    fn assemble(&self, b: &[f64], jac: bool) -> Option<(DMatrix<f64>, f64)>;

    /// Solves for θ at `b`; with `jac`, also the Kaufman Jacobian products.
    fn solve(&self, b: &[f64], jac: bool) -> Option<Solved> {
        let (x, resid0) = self.assemble(b, jac)?;
        solve_block(x, resid0, b.len(), jac)
    }
}

impl Problem for Reduced {
    fn assemble(&self, b: &[f64], jac: bool) -> Option<(DMatrix<f64>, f64)> {
        let k = b.len();
        let nlin = k + 2;
        let nder = if jac { k } else { 0 };
        let cols = nlin + nder + 1;
        let rows = self.len() + 1;
        let last = rows - 1;
        let mut x = DMatrix::<f64>::zeros(rows, cols);
        for j in 0..self.len() {
            let (u, w) = (self.u[j], self.w[j]);
            for i in 0..k {
                let e = w * (b[i] * u).exp();
                x[(j, i)] = e;
                if jac {
                    x[(j, nlin + i)] = e * u;
                }
            }
            x[(j, k)] = w;
            x[(j, k + 1)] = w * self.vdot[j];
            x[(j, cols - 1)] = w * self.p[j];
        }
        // The γ row: within-row flow variation (zero when every flow is its row's mean).
        let mut resid0 = self.spp;
        if self.svv > 0.0 {
            let s = self.svv.sqrt();
            x[(last, k + 1)] = s;
            x[(last, cols - 1)] = self.svp / s;
            resid0 -= self.svp * self.svp / self.svv;
        }
        Some((x, resid0.max(0.0)))
    }
}

/// Solves the design block `x = [A | ∂A/∂b | y]` (k exponential columns, then 1 and v̇, then the
/// derivative columns when `jac`, then y) for θ, and the Kaufman JᵀJ, Jᵀr when `jac`.
/// `None` if anything turns non-finite.
fn solve_block(mut x: DMatrix<f64>, resid0: f64, k: usize, jac: bool) -> Option<Solved> {
    let nlin = k + 2;
    let cols = x.ncols();
    // Normalise columns: the QR is invariant, the triangle's conditioning is not.
    let mut scale = vec![1.0; cols];
    for (c, sc) in scale.iter_mut().enumerate() {
        let nrm = x.column(c).norm();
        if !nrm.is_finite() {
            return None;
        }
        if nrm > 0.0 {
            *sc = nrm;
            x.column_mut(c).unscale_mut(nrm);
        }
    }
    let r = x.qr().unpack_r();
    let m = r.nrows(); // min(rows, cols)
    let ysc = scale[cols - 1];
    // θ from the leading triangle by truncated SVD (minimum norm if columns are collinear).
    let nl = nlin.min(m);
    let r11 = r.view((0, 0), (nl, nlin)).clone_owned();
    let z1 = r.view((0, cols - 1), (nl, 1)).clone_owned();
    let svd = r11.clone().svd(true, true);
    let tol = 1e-10 * svd.singular_values.max();
    let th = svd.solve(&z1, tol).ok()?;
    let fit_gap = (&r11 * &th - &z1).norm_squared();
    let below = if m > nlin {
        r.view((nlin, cols - 1), (m - nlin, 1)).norm_squared()
    } else {
        0.0
    };
    let sse = (fit_gap + below) * ysc * ysc + resid0;
    let theta: Vec<f64> = (0..nlin).map(|c| th[c] * ysc / scale[c]).collect();
    if !sse.is_finite() || theta.iter().any(|t| !t.is_finite()) {
        return None;
    }
    let (mut jtj, mut jtr) = (DMatrix::zeros(0, 0), DVector::zeros(0));
    if jac {
        // Rows nlin..m of R hold the parts of hᵢ and y orthogonal to span(A):
        // Jᵢ = −aᵢ P⊥hᵢ, r = P⊥y.
        jtj = DMatrix::zeros(k, k);
        jtr = DVector::zeros(k);
        let tail = m.saturating_sub(nlin);
        let col = |c: usize| r.view((nlin, c), (tail, 1));
        for i in 0..k {
            let ci = scale[nlin + i] * theta[i];
            let hi = col(nlin + i);
            jtr[i] = -ci * ysc * hi.dot(&col(cols - 1));
            for l in 0..=i {
                let cl = scale[nlin + l] * theta[l];
                let v = ci * cl * hi.dot(&col(nlin + l));
                jtj[(i, l)] = v;
                jtj[(l, i)] = v;
            }
        }
    }
    Some(Solved {
        theta,
        sse,
        jtj,
        jtr,
    })
}

/// The grouped problem projected onto the Chebyshev subspace S (module docs): at most D + 2 rows.
struct Projected {
    /// Coordinates in Q of the basis vectors of S (rows: kept directions; columns: T₀..T_D, v̇).
    to_q: DMatrix<f64>,
    /// Coordinates of y in Q.
    y_q: DVector<f64>,
    /// ‖(I − QQᵀ)y‖² plus the within-group constant: the SSE no model column can reach.
    unreachable: f64,
    /// cos(n·θⱼ) at the Chebyshev nodes θⱼ = π(j + ½)/(D + 1), for interpolation.
    cos: DMatrix<f64>,
    /// The nodes in scaled volume, uⱼ = (cos θⱼ + 1)/2.
    nodes_u: Vec<f64>,
}

impl Projected {
    fn new(red: &Reduced) -> Self {
        let (g, by) = Self::gram(red);
        let (to_q, y_q, theta_s) = Self::whiten(g, &by);
        let nodes = CHEB_DEGREE + 1;
        let theta = |j: usize| std::f64::consts::PI * (j as f64 + 0.5) / nodes as f64;
        let cos = DMatrix::from_fn(nodes, nodes, |n, j| (n as f64 * theta(j)).cos());
        let nodes_u = (0..nodes).map(|j| 0.5 * (theta(j).cos() + 1.0)).collect();
        Projected {
            to_q,
            y_q,
            unreachable: Self::unreachable(red, &theta_s),
            cos,
            nodes_u,
        }
    }

    /// The Gram matrix G of B = [T₀..T_D, v̇] on the grouped rows and Bᵀy, from one pass:
    /// Σ n T_d (d ≤ 2D), Σ n v̇ T_d, Σ n P T_d (d ≤ D), and the v̇, P products.
    fn gram(red: &Reduced) -> (DMatrix<f64>, DVector<f64>) {
        const D: usize = CHEB_DEGREE;
        let nb = D + 2;
        let mut m = vec![0.0; 2 * D + 1];
        let (mut mq, mut mp) = (vec![0.0; D + 1], vec![0.0; D + 1]);
        let (mut qq, mut qp) = (red.svv, red.svp);
        let mut t = vec![0.0; 2 * D + 1];
        for j in 0..red.len() {
            let x = 2.0 * red.u[j] - 1.0;
            let n = red.w[j] * red.w[j];
            let (q, p) = (red.vdot[j], red.p[j]);
            crate::poly::chebyshev(x, &mut t);
            for d in 0..=2 * D {
                m[d] += n * t[d];
            }
            for d in 0..=D {
                mq[d] += n * q * t[d];
                mp[d] += n * p * t[d];
            }
            qq += n * q * q;
            qp += n * q * p;
        }
        let mut g = DMatrix::<f64>::zeros(nb, nb);
        for a in 0..=D {
            for b in 0..=D {
                g[(a, b)] = 0.5 * (m[a + b] + m[a.abs_diff(b)]);
            }
            g[(a, D + 1)] = mq[a];
            g[(D + 1, a)] = mq[a];
        }
        g[(D + 1, D + 1)] = qq;
        let by = DVector::<f64>::from_iterator(nb, mp.iter().copied().chain([qp]));
        (g, by)
    }

    /// Unit-diagonal scaling, then eigen-decomposition of G: the map to the orthonormal
    /// coordinates, Q = B S⁻¹ V Λ^{−1/2} (directions with eigenvalue below 10⁻¹³ of the largest
    /// dropped), y's coordinates in Q, and θ_S, the least-squares coefficients of y on B.
    fn whiten(mut g: DMatrix<f64>, by: &DVector<f64>) -> (DMatrix<f64>, DVector<f64>, Vec<f64>) {
        let nb = g.nrows();
        let mut by = by.clone();
        let sc: Vec<f64> = (0..nb)
            .map(|i| {
                let d = g[(i, i)];
                if d > 0.0 {
                    d.sqrt()
                } else {
                    1.0
                }
            })
            .collect();
        for a in 0..nb {
            for b in 0..nb {
                g[(a, b)] /= sc[a] * sc[b];
            }
            by[a] /= sc[a];
        }
        let eig = nalgebra::SymmetricEigen::new(g);
        let lmax = eig.eigenvalues.max();
        let keep: Vec<usize> = (0..nb)
            .filter(|&i| eig.eigenvalues[i] > 1e-13 * lmax)
            .collect();
        let mut to_q = DMatrix::<f64>::zeros(keep.len(), nb);
        let mut y_q = DVector::<f64>::zeros(keep.len());
        let mut theta_s = vec![0.0; nb];
        for (r, &i) in keep.iter().enumerate() {
            let (l, vi) = (eig.eigenvalues[i], eig.eigenvectors.column(i));
            for c in 0..nb {
                to_q[(r, c)] = l.sqrt() * vi[c] * sc[c];
            }
            y_q[r] = vi.dot(&by) / l.sqrt();
            let z = vi.dot(&by) / l;
            for c in 0..nb {
                theta_s[c] += vi[c] * z / sc[c];
            }
        }
        (to_q, y_q, theta_s)
    }

    /// ‖y − B θ_S‖² on the grouped rows (Clenshaw for the Chebyshev part) and the γ row: the
    /// part of the error no model in the span can remove.
    fn unreachable(red: &Reduced, theta_s: &[f64]) -> f64 {
        const D: usize = CHEB_DEGREE;
        let mut unreachable = 0.0;
        for j in 0..red.len() {
            let x = 2.0 * red.u[j] - 1.0;
            let (mut b1, mut b2) = (0.0, 0.0);
            for d in (1..=D).rev() {
                let b0 = theta_s[d] + 2.0 * x * b1 - b2;
                b2 = b1;
                b1 = b0;
            }
            let poly = theta_s[0] + x * b1 - b2;
            let r = red.w[j] * (red.p[j] - poly - theta_s[D + 1] * red.vdot[j]);
            unreachable += r * r;
        }
        let gamma_s = theta_s[D + 1];
        unreachable += gamma_s * gamma_s * red.svv - 2.0 * gamma_s * red.svp + red.spp;
        unreachable.max(0.0)
    }

    /// Coordinates in Q of the column whose values at the Chebyshev nodes are `f`.
    fn coords(&self, f: &DVector<f64>) -> DVector<f64> {
        let nodes = f.len() as f64;
        let mut c = (&self.cos * f) * (2.0 / nodes);
        c[0] *= 0.5;
        self.to_q.columns(0, c.len()) * c
    }
}

impl Problem for Projected {
    fn assemble(&self, b: &[f64], jac: bool) -> Option<(DMatrix<f64>, f64)> {
        let k = b.len();
        let nlin = k + 2;
        let nder = if jac { k } else { 0 };
        let cols = nlin + nder + 1;
        let rows = self.to_q.nrows();
        let mut x = DMatrix::<f64>::zeros(rows, cols);
        let nb = self.to_q.ncols();
        for (i, &bi) in b.iter().enumerate() {
            let f = DVector::from_iterator(
                self.nodes_u.len(),
                self.nodes_u.iter().map(|u| (bi * u).exp()),
            );
            x.set_column(i, &self.coords(&f));
            if jac {
                let fu = f.zip_map(&DVector::from_column_slice(&self.nodes_u), |e, u| e * u);
                x.set_column(nlin + i, &self.coords(&fu));
            }
        }
        x.set_column(k, &self.to_q.column(0));
        x.set_column(k + 1, &self.to_q.column(nb - 1));
        x.set_column(cols - 1, &self.y_q);
        Some((x, self.unreachable))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A made-up but SBA-like log: volume on the 0.04 mm³ step grid swept 0..550 at varying
    /// flow, sampled at 25 Hz.
    fn sba_like(n: usize) -> (Vec<f64>, Vec<f64>) {
        let (mut v, mut q) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let dt = 0.04;
        let mut steps: i64 = 0;
        let mut dir = 1i64;
        for t in 0..n {
            // Flow cycles through 20..100 mm³/s; direction flips at the ends of the stroke.
            let rate = 20.0 + 80.0 * (0.5 + 0.5 * (t as f64 * 0.0037).sin());
            let ds = dir * (rate * dt / 0.04).round() as i64;
            let next = steps + ds;
            let (next, flip) = if next > 13_750 {
                (13_750, true)
            } else if next < 0 {
                (0, true)
            } else {
                (next, false)
            };
            v.push(next as f64 * 0.04);
            q.push((next - steps) as f64 * 0.04 / dt);
            steps = next;
            if flip {
                dir = -dir;
            }
        }
        (v, q)
    }

    fn truth(v: &[f64], q: &[f64], a: &[f64], b: &[f64], g: f64, d: f64) -> Vec<f64> {
        let f = ExpFit {
            k: a.len(),
            alpha: a.to_vec(),
            beta: b.to_vec(),
            gamma: g,
            delta: d,
            sse: 0.0,
        };
        v.iter().zip(q).map(|(&v, &q)| f.predict(v, q)).collect()
    }

    /// Deterministic Gaussian noise (Box–Muller on a SplitMix64 stream), test-only.
    fn noise(n: usize, sigma: f64, mut s: u64) -> Vec<f64> {
        let mut unif = || {
            s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = s;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
        };
        (0..n)
            .map(|_| {
                let (u1, u2) = (unif().max(1e-300), unif());
                sigma * (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
            })
            .collect()
    }

    fn close(x: f64, want: f64, rel: f64) -> bool {
        (x - want).abs() <= rel * want.abs()
    }

    #[test]
    fn recovers_one_term_exactly() {
        let (v, q) = sba_like(3000);
        let p = truth(&v, &q, &[1.2], &[0.006], 0.03, 2.0);
        let f = fit(&v, &q, &p, 1).unwrap();
        assert!(close(f.alpha[0], 1.2, 1e-6), "{f:?}");
        assert!(close(f.beta[0], 0.006, 1e-6), "{f:?}");
        assert!(close(f.gamma, 0.03, 1e-6), "{f:?}");
        assert!(close(f.delta, 2.0, 1e-6), "{f:?}");
        assert!(f.sse < 1e-12 * p.iter().map(|x| x * x).sum::<f64>());
    }

    #[test]
    fn recovers_two_terms_noiseless_and_noisy() {
        let (v, q) = sba_like(20_000);
        let (a, b) = ([1.5, 0.02], [0.004, 0.011]);
        let p = truth(&v, &q, &a, &b, 0.05, 3.0);
        let f = fit(&v, &q, &p, 2).unwrap();
        let order = |f: &ExpFit| {
            if f.beta[0] < f.beta[1] {
                [0, 1]
            } else {
                [1, 0]
            }
        };
        let o = order(&f);
        for i in 0..2 {
            assert!(close(f.alpha[o[i]], a[i], 1e-5), "{f:?}");
            assert!(close(f.beta[o[i]], b[i], 1e-5), "{f:?}");
        }
        assert!(
            close(f.gamma, 0.05, 1e-6) && close(f.delta, 3.0, 1e-5),
            "{f:?}"
        );

        // σ = 0.2 kPa on pressures up to ~60 kPa: parameters within a few per cent, and the
        // residual is the noise (SSE/N ≈ σ²).
        let e = noise(p.len(), 0.2, 7);
        let pn: Vec<f64> = p.iter().zip(&e).map(|(x, e)| x + e).collect();
        let f = fit(&v, &q, &pn, 2).unwrap();
        let o = order(&f);
        for i in 0..2 {
            assert!(close(f.alpha[o[i]], a[i], 0.05), "{f:?}");
            assert!(close(f.beta[o[i]], b[i], 0.02), "{f:?}");
        }
        assert!(
            close(f.gamma, 0.05, 0.02) && close(f.delta, 3.0, 0.05),
            "{f:?}"
        );
        let mse = f.sse / p.len() as f64;
        assert!(close(mse, 0.04, 0.05), "mse {mse}");
    }

    #[test]
    fn nested_sweep_never_worse_and_exact_sse() {
        let (v, q) = sba_like(20_000);
        // Pressure that is not a sum of exponentials: a tanh knee plus a flow-volume interaction.
        let p: Vec<f64> = v
            .iter()
            .zip(&q)
            .map(|(&v, &q)| 5.0 * ((v - 300.0) / 80.0).tanh() + 0.02 * q * (1.0 + v / 550.0))
            .collect();
        let fits: Vec<ExpFit> = sweep(&v, &q, &p, 10)
            .into_iter()
            .map(|r| r.unwrap())
            .collect();
        for (i, f) in fits.iter().enumerate() {
            assert_eq!(f.k, i + 1);
            assert_eq!(f.n_params(), 2 * i + 4);
            // The reported SSE is the SSE of the reported parameters on the raw samples.
            let direct: f64 = (0..v.len())
                .map(|t| (p[t] - f.predict(v[t], q[t])).powi(2))
                .sum();
            assert!(
                close(f.sse, direct, 1e-6),
                "k={} {} vs {direct} {f:?}",
                f.k,
                f.sse
            );
        }
        for w in fits.windows(2) {
            assert!(
                w[1].sse <= w[0].sse,
                "k={}: {} > {}",
                w[1].k,
                w[1].sse,
                w[0].sse
            );
        }
        // More terms do help on this curve.
        assert!(fits[3].sse < 0.5 * fits[0].sse);
    }

    #[test]
    fn continuous_volume_is_projected_and_recovers() {
        // Every volume distinct: the search runs on the Chebyshev projection.
        let n = 5000;
        let v: Vec<f64> = (0..n)
            .map(|t| 275.0 + 270.0 * (t as f64 * 0.01).sin() + 1e-3 * t as f64)
            .collect();
        let q: Vec<f64> = (0..n).map(|t| 50.0 * (t as f64 * 0.013).cos()).collect();
        let p = truth(&v, &q, &[0.8], &[0.007], 0.04, -1.0);
        let f = fit(&v, &q, &p, 1).unwrap();
        assert!(
            close(f.beta[0], 0.007, 1e-6) && close(f.alpha[0], 0.8, 1e-5),
            "{f:?}"
        );
    }

    /// The projection is an identity, not an approximation: at any rates, the projected problem's
    /// θ and SSE equal those of the grouped problem (solved by QR on all its rows).
    #[test]
    fn projection_matches_the_grouped_problem() {
        let (v, q) = sba_like(20_000);
        let p: Vec<f64> = v
            .iter()
            .zip(&q)
            .zip(noise(v.len(), 0.3, 11))
            .map(|((&v, &q), e)| 5.0 * ((v - 300.0) / 80.0).tanh() + 0.02 * q + e)
            .collect();
        let exact = Reduced::exact(&v, &q, &p).unwrap();
        assert!(
            exact.len() > 4 * (CHEB_DEGREE + 2),
            "{} volumes",
            exact.len()
        );
        let proj = Projected::new(&exact);
        for b in [
            vec![2.0],
            vec![-35.0, 4.0],
            vec![-6.0, 1.5, 39.5],
            vec![-20.0, -3.0, 0.7, 9.0],
        ] {
            let (e, pr) = (
                exact.solve(&b, true).unwrap(),
                proj.solve(&b, true).unwrap(),
            );
            assert!(
                close(pr.sse, e.sse, 1e-9),
                "b {b:?}: {} vs {}",
                pr.sse,
                e.sse
            );
            for (x, y) in pr.theta.iter().zip(&e.theta) {
                assert!(
                    (x - y).abs() <= 1e-6 * (1.0 + y.abs()),
                    "b {b:?}: θ {x} vs {y}"
                );
            }
            for (x, y) in pr.jtr.iter().zip(e.jtr.iter()) {
                assert!(
                    (x - y).abs() <= 1e-6 * (1.0 + y.abs()),
                    "b {b:?}: Jᵀr {x} vs {y}"
                );
            }
        }
    }

    #[test]
    fn bad_input_is_an_error() {
        let (v, q) = sba_like(500);
        let p = truth(&v, &q, &[1.0], &[0.005], 0.0, 0.0);
        let mut pn = p.clone();
        pn[17] = f64::NAN;
        assert_eq!(
            fit(&v, &q, &pn, 1),
            Err(ExpError::NonFinite {
                column: "p",
                index: 17
            })
        );
        let mut qn = q.clone();
        qn[3] = f64::INFINITY;
        assert!(matches!(
            fit(&v, &qn, &p, 2),
            Err(ExpError::NonFinite {
                column: "vdot",
                index: 3
            })
        ));
        assert!(matches!(
            fit(&v[..10], &q, &p, 1),
            Err(ExpError::LengthMismatch { .. })
        ));
        assert!(matches!(
            fit(&v[..3], &q[..3], &p[..3], 1),
            Err(ExpError::TooFewSamples { .. })
        ));
        assert!(matches!(
            fit(&v[..6], &q[..6], &p[..6], 2),
            Err(ExpError::TooFewSamples { needed: 7, got: 6 })
        ));
        assert_eq!(fit(&v, &q, &p, 0), Err(ExpError::ZeroTerms));
        let flat = vec![100.0; 500];
        assert_eq!(
            fit(&flat, &q, &p, 1),
            Err(ExpError::TooFewVolumes {
                needed: 3,
                distinct: 1
            })
        );
        // Each error reads as a sentence.
        assert!(ExpError::NonFinite {
            column: "p",
            index: 17
        }
        .to_string()
        .contains("sample 17"));
    }

    #[test]
    fn constant_flow_and_few_volumes_give_finite_fits() {
        // Flow identical everywhere: γ and δ are collinear; the min-norm solve keeps it finite.
        let v: Vec<f64> = (0..200).map(|t| (t % 50) as f64 * 10.0).collect();
        let q = vec![10.0; 200];
        let p = truth(&v, &q, &[2.0], &[0.004], 0.1, 1.0);
        for r in sweep(&v, &q, &p, 4) {
            let f = r.unwrap();
            assert!(f.alpha.iter().chain(&f.beta).all(|x| x.is_finite()));
            assert!(f.gamma.is_finite() && f.delta.is_finite());
            assert!(f.sse < 1e-8, "{f:?}");
        }
    }
}
