//! Multivariate polynomial pressure model, optionally with linear autoregressive terms
//! (paper, Table II "Multivariate polynomial model" and "Autoregressive multivariate polynomial model"):
//!
//! ```text
//! P̂(t) = Σ_{i=0..n} Σ_{j=0..m} α_ij · v(t)^i · v̇(t)^j  +  Σ_{k=1..p} ( β_k1 · v(t−kΔt) + β_k2 · v̇(t−kΔt) )
//! ```
//!
//! with n, m ≤ 7 (the paper searched 1..=7, Table III) and p ≤ 5.
//!
//! # Scaled storage
//! The paper's raw coefficients span 1e-1 … 1e-11 (Table IV) and raw monomials reach 7000⁷ ≈ 8e26 for
//! SBA4, which f32 cannot evaluate without catastrophic cancellation. So a [`PolyModel`] stores its
//! coefficients against affinely scaled inputs
//!
//! ```text
//! x = (v − v_offset) / v_scale,      y = (v̇ − f_offset) / f_scale,
//! ```
//!
//! chosen ([`Scaling::for_range`]) so the working range maps onto [−1, 1]², and evaluates
//!
//! ```text
//! P̂ = Σ_j q_j(x) · y^j,   q_j(x) = Σ_i b_ij x^i          (Horner in x, then in y)
//! k = ∂P/∂v = (∂P/∂x) / v_scale,   c = ∂P/∂v̇ = (∂P/∂y) / f_scale
//! ```
//!
//! in f32. Conversion between raw α_ij and scaled b_ij happens in f64, only where a person reads or
//! writes coefficients ([`PolyModel::from_raw`], [`PolyModel::to_raw`]). Substituting
//! v = o + s·x into Σ_i α_i v^i gives, per axis,
//!
//! ```text
//! b_k = Σ_{i ≥ k} α_i · C(i, k) · o^(i−k) · s^k
//! ```
//!
//! and the inverse uses the inverse map x = (−o/s) + (1/s)·v in the same formula.
//!
//! # Autoregressive terms
//! AR coefficients are stored in scaled units too: the scaled model adds
//! Σ_k (b_k1 · x(t−k) + b_k2 · y(t−k)), where x, y are the *affinely* scaled past inputs. Because
//! β·v = β·s·x + β·o, the raw ↔ scaled conversion of an AR pair also moves β_k1·v_offset +
//! β_k2·f_offset into the constant term b_00. Scaled AR regressors are centred, which keeps the RLS
//! regressor matrix well conditioned.
//!
//! # Working range
//! Inputs whose scaled value leaves [−[`SCALED_LIMIT`], +[`SCALED_LIMIT`]] (i.e. more than half a
//! range width outside the fitted range) are refused with [`ModelError::OutOfRange`]: a polynomial
//! extrapolated that far is meaningless, and f32 accuracy is only stated inside the limit.

use crate::error::{finite, ModelError};

/// Highest supported degree of v (n) and of v̇ (m).
pub const MAX_DEG: usize = 7;
/// Highest supported autoregressive order p.
pub const MAX_AR: usize = 5;
/// Most polynomial terms: (MAX_DEG + 1)².
pub const MAX_TERMS: usize = (MAX_DEG + 1) * (MAX_DEG + 1);
/// Most parameters: polynomial terms plus two per AR lag.
pub const MAX_PARAMS: usize = MAX_TERMS + 2 * MAX_AR;
/// Largest accepted |x| or |y| (scaled input); see the module docs.
pub const SCALED_LIMIT: f32 = 2.0;

/// Shape of a poly-AR model: degree `n` in v, degree `m` in v̇, AR order `p`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Shape {
    /// Highest power of v (0..=7).
    pub n: u8,
    /// Highest power of v̇ (0..=7).
    pub m: u8,
    /// Autoregressive order (0..=5).
    pub p: u8,
}

impl Shape {
    /// The paper's optimal static model, n = 3, m = 2 (Table III, 12 coefficients).
    pub const PAPER: Shape = Shape { n: 3, m: 2, p: 0 };

    /// A checked shape: `BadShape` unless n, m ≤ [`MAX_DEG`] and p ≤ [`MAX_AR`].
    pub fn new(n: u8, m: u8, p: u8) -> Result<Self, ModelError> {
        if n as usize > MAX_DEG || m as usize > MAX_DEG || p as usize > MAX_AR {
            return Err(ModelError::BadShape);
        }
        Ok(Shape { n, m, p })
    }

    /// Number of polynomial terms, (n + 1)(m + 1).
    pub const fn poly_terms(&self) -> usize {
        (self.n as usize + 1) * (self.m as usize + 1)
    }

    /// Number of parameters, (n + 1)(m + 1) + 2p.
    pub const fn params(&self) -> usize {
        self.poly_terms() + 2 * self.p as usize
    }

    /// Index of the coefficient of x^i y^j: i·(m + 1) + j.
    pub const fn index(&self, i: usize, j: usize) -> usize {
        i * (self.m as usize + 1) + j
    }

    fn check(&self) -> Result<(), ModelError> {
        Shape::new(self.n, self.m, self.p).map(|_| ())
    }
}

/// Affine input scaling x = (v − v_offset) / v_scale, y = (v̇ − f_offset) / f_scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scaling {
    /// Volume at the centre of the working range, mm³.
    pub v_offset: f32,
    /// Half-width of the volume range, mm³ (> 0).
    pub v_scale: f32,
    /// Flow at the centre of the working range, mm³/s.
    pub f_offset: f32,
    /// Half-width of the flow range, mm³/s (> 0).
    pub f_scale: f32,
}

impl Scaling {
    /// The scaling used by [`sba1`]: 0..550 mm³, ±100 mm³/s (the paper's data range).
    pub const SBA1: Scaling = Scaling {
        v_offset: 275.0,
        v_scale: 275.0,
        f_offset: 0.0,
        f_scale: 100.0,
    };

    /// A checked scaling: offsets finite, scales finite and > 0, else `BadParameter`.
    pub fn new(
        v_offset: f32,
        v_scale: f32,
        f_offset: f32,
        f_scale: f32,
    ) -> Result<Self, ModelError> {
        let s = Scaling {
            v_offset,
            v_scale,
            f_offset,
            f_scale,
        };
        s.check()?;
        Ok(s)
    }

    /// The scaling that maps [v_min, v_max] × [f_min, f_max] onto [−1, 1]².
    pub fn for_range(v_min: f32, v_max: f32, f_min: f32, f_max: f32) -> Result<Self, ModelError> {
        if !(v_min.is_finite() && v_max.is_finite() && f_min.is_finite() && f_max.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        if v_max <= v_min || f_max <= f_min {
            return Err(ModelError::BadParameter);
        }
        // Halve before adding so ranges near f32::MAX do not overflow.
        Scaling::new(
            v_min / 2.0 + v_max / 2.0,
            v_max / 2.0 - v_min / 2.0,
            f_min / 2.0 + f_max / 2.0,
            f_max / 2.0 - f_min / 2.0,
        )
    }

    fn check(&self) -> Result<(), ModelError> {
        let ok = self.v_offset.is_finite()
            && self.f_offset.is_finite()
            && self.v_scale.is_finite()
            && self.f_scale.is_finite()
            && self.v_scale > 0.0
            && self.f_scale > 0.0;
        if ok {
            Ok(())
        } else {
            Err(ModelError::BadParameter)
        }
    }

    /// Scaled inputs (x, y): `NonFinite` for NaN/∞, `OutOfRange` beyond [`SCALED_LIMIT`].
    #[inline]
    pub fn to_scaled(&self, v: f32, vdot: f32) -> Result<(f32, f32), ModelError> {
        if !(v.is_finite() && vdot.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        let x = (v - self.v_offset) / self.v_scale;
        let y = (vdot - self.f_offset) / self.f_scale;
        if libm::fabsf(x) > SCALED_LIMIT || libm::fabsf(y) > SCALED_LIMIT {
            return Err(ModelError::OutOfRange);
        }
        Ok((x, y))
    }
}

/// Model output at one operating point.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Eval {
    /// Predicted pressure P̂, kPa.
    pub p: f32,
    /// Stiffness k = ∂P/∂v, kPa/mm³.
    pub k: f32,
    /// Damping c = ∂P/∂v̇, kPa·s/mm³.
    pub c: f32,
}

/// The last [`MAX_AR`] raw (v, v̇) samples, newest first, for the AR terms.
///
/// At each step evaluate with the history of *previous* samples, then push the current one.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ArHistory {
    buf: [(f32, f32); MAX_AR],
    head: usize,
    len: usize,
}

impl ArHistory {
    /// An empty history.
    pub const fn new() -> Self {
        ArHistory {
            buf: [(0.0, 0.0); MAX_AR],
            head: 0,
            len: 0,
        }
    }

    /// Records a sample; the oldest one drops out once [`MAX_AR`] are held.
    pub fn push(&mut self, v: f32, vdot: f32) {
        self.head = (self.head + 1) % MAX_AR;
        self.buf[self.head] = (v, vdot);
        self.len = (self.len + 1).min(MAX_AR);
    }

    /// Number of samples held (at most [`MAX_AR`]).
    pub fn len(&self) -> usize {
        self.len
    }

    /// True when no sample has been pushed since creation or [`clear`](Self::clear).
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The sample `lag` steps back (1 = most recent push), if held.
    pub fn get(&self, lag: usize) -> Option<(f32, f32)> {
        if lag == 0 || lag > self.len {
            return None;
        }
        Some(self.buf[(self.head + MAX_AR - (lag - 1)) % MAX_AR])
    }

    /// Forgets all samples (e.g. after a gap in the data).
    pub fn clear(&mut self) {
        *self = ArHistory::new();
    }
}

/// A poly-AR pressure model with coefficients stored against scaled inputs (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PolyModel {
    shape: Shape,
    scaling: Scaling,
    coef: [f32; MAX_TERMS],
    ar: [[f32; 2]; MAX_AR],
}

/// Binomial coefficient C(i, k) for i ≤ MAX_DEG, exact in f64.
fn binom(i: usize, k: usize) -> f64 {
    let mut r = 1.0;
    for t in 0..k {
        r = r * (i - t) as f64 / (t + 1) as f64;
    }
    r
}

/// Rewrites `c` (index i·(m+1)+j, polynomial in (u, w)) as a polynomial in (s, t) where
/// u = a_v + b_v·s and w = a_f + b_f·t: per axis, d_k = Σ_{i≥k} c_i C(i,k) a^(i−k) b^k.
fn affine_substitute(
    c: &mut [f64; MAX_TERMS],
    n: usize,
    m: usize,
    a_v: f64,
    b_v: f64,
    a_f: f64,
    b_f: f64,
) {
    let w = m + 1;
    let mut tmp = [0.0f64; MAX_TERMS];
    // Along v, for each power of the flow.
    for j in 0..=m {
        for k in 0..=n {
            let mut acc = 0.0;
            for i in k..=n {
                acc += c[i * w + j] * binom(i, k) * libm::pow(a_v, (i - k) as f64);
            }
            tmp[k * w + j] = acc * libm::pow(b_v, k as f64);
        }
    }
    // Along the flow, for each power of v.
    for i in 0..=n {
        for l in 0..=m {
            let mut acc = 0.0;
            for j in l..=m {
                acc += tmp[i * w + j] * binom(j, l) * libm::pow(a_f, (j - l) as f64);
            }
            c[i * w + l] = acc * libm::pow(b_f, l as f64);
        }
    }
}

impl PolyModel {
    /// Builds a model from the paper's raw-unit coefficients α_ij (kPa, mm³, mm³/s; index
    /// i·(m+1)+j) and raw AR pairs [β_k1, β_k2] for k = 1..=p, converting them (in f64) to the
    /// scaled basis of `scaling`.
    pub fn from_raw(
        shape: Shape,
        raw: &[f64],
        ar_raw: &[[f64; 2]],
        scaling: Scaling,
    ) -> Result<Self, ModelError> {
        shape.check()?;
        scaling.check()?;
        if raw.len() != shape.poly_terms() || ar_raw.len() != shape.p as usize {
            return Err(ModelError::BadLength);
        }
        if raw
            .iter()
            .chain(ar_raw.iter().flatten())
            .any(|x| !x.is_finite())
        {
            return Err(ModelError::NonFinite);
        }
        let (n, m) = (shape.n as usize, shape.m as usize);
        let (ov, sv) = (scaling.v_offset as f64, scaling.v_scale as f64);
        let (of, sf) = (scaling.f_offset as f64, scaling.f_scale as f64);
        let mut c = [0.0f64; MAX_TERMS];
        c[..raw.len()].copy_from_slice(raw);
        affine_substitute(&mut c, n, m, ov, sv, of, sf);
        let mut ar = [[0.0f32; 2]; MAX_AR];
        for (k, b) in ar_raw.iter().enumerate() {
            // β1·v = β1·sv·x + β1·ov: the offset part joins the constant term.
            c[0] += b[0] * ov + b[1] * of;
            ar[k] = [(b[0] * sv) as f32, (b[1] * sf) as f32];
        }
        let mut coef = [0.0f32; MAX_TERMS];
        for (dst, src) in coef.iter_mut().zip(c.iter()) {
            *dst = *src as f32;
        }
        let model = PolyModel {
            shape,
            scaling,
            coef,
            ar,
        };
        model.check_finite()?;
        Ok(model)
    }

    /// Writes the raw-unit coefficients α_ij (index i·(m+1)+j) into `raw` and the raw AR pairs into
    /// `ar_raw`; their lengths must be exactly `poly_terms()` and `p`.
    pub fn to_raw(&self, raw: &mut [f64], ar_raw: &mut [[f64; 2]]) -> Result<(), ModelError> {
        let shape = self.shape;
        if raw.len() != shape.poly_terms() || ar_raw.len() != shape.p as usize {
            return Err(ModelError::BadLength);
        }
        let (n, m) = (shape.n as usize, shape.m as usize);
        let (ov, sv) = (self.scaling.v_offset as f64, self.scaling.v_scale as f64);
        let (of, sf) = (self.scaling.f_offset as f64, self.scaling.f_scale as f64);
        let mut c = [0.0f64; MAX_TERMS];
        for (dst, src) in c.iter_mut().zip(self.coef.iter()) {
            *dst = *src as f64;
        }
        for (k, b) in ar_raw.iter_mut().enumerate() {
            let (b1, b2) = (self.ar[k][0] as f64, self.ar[k][1] as f64);
            // b1·x = (b1/sv)·v − b1·ov/sv: undo the constant shift made by from_raw.
            c[0] -= b1 * ov / sv + b2 * of / sf;
            *b = [b1 / sv, b2 / sf];
        }
        affine_substitute(&mut c, n, m, -ov / sv, 1.0 / sv, -of / sf, 1.0 / sf);
        raw.copy_from_slice(&c[..raw.len()]);
        Ok(())
    }

    /// The same model re-expressed against another scaling (through the raw coefficients, in f64),
    /// e.g. to move a model fitted on one range onto a device's default range.
    pub fn rescaled(&self, scaling: Scaling) -> Result<Self, ModelError> {
        let mut raw = [0.0f64; MAX_TERMS];
        let mut ar = [[0.0f64; 2]; MAX_AR];
        let (t, p) = (self.shape.poly_terms(), self.shape.p as usize);
        self.to_raw(&mut raw[..t], &mut ar[..p])?;
        PolyModel::from_raw(self.shape, &raw[..t], &ar[..p], scaling)
    }

    /// Builds a model from scaled coefficients b_ij (index i·(m+1)+j) and scaled AR pairs.
    pub fn from_scaled(
        shape: Shape,
        scaled: &[f32],
        ar: &[[f32; 2]],
        scaling: Scaling,
    ) -> Result<Self, ModelError> {
        shape.check()?;
        scaling.check()?;
        if scaled.len() != shape.poly_terms() || ar.len() != shape.p as usize {
            return Err(ModelError::BadLength);
        }
        let mut model = PolyModel {
            shape,
            scaling,
            coef: [0.0; MAX_TERMS],
            ar: [[0.0; 2]; MAX_AR],
        };
        model.coef[..scaled.len()].copy_from_slice(scaled);
        model.ar[..ar.len()].copy_from_slice(ar);
        model.check_finite()?;
        Ok(model)
    }

    /// Builds a model from a flat parameter vector in regressor order (as produced by
    /// [`regressors_ar`](Self::regressors_ar) and estimated by [`crate::rls::Rls`]): the `poly_terms()`
    /// scaled coefficients, then b_11, b_12, b_21, b_22, ….
    pub fn from_params(shape: Shape, params: &[f32], scaling: Scaling) -> Result<Self, ModelError> {
        shape.check()?;
        if params.len() != shape.params() {
            return Err(ModelError::BadLength);
        }
        let t = shape.poly_terms();
        let mut ar = [[0.0f32; 2]; MAX_AR];
        for (k, pair) in params[t..].chunks_exact(2).enumerate() {
            ar[k] = [pair[0], pair[1]];
        }
        PolyModel::from_scaled(shape, &params[..t], &ar[..shape.p as usize], scaling)
    }

    /// Writes the flat parameter vector (see [`from_params`](Self::from_params)) into `out`
    /// (length ≥ `params()`), returning the number written.
    pub fn params(&self, out: &mut [f32]) -> Result<usize, ModelError> {
        let (t, np) = (self.shape.poly_terms(), self.shape.params());
        if out.len() < np {
            return Err(ModelError::BadLength);
        }
        out[..t].copy_from_slice(&self.coef[..t]);
        for k in 0..self.shape.p as usize {
            out[t + 2 * k] = self.ar[k][0];
            out[t + 2 * k + 1] = self.ar[k][1];
        }
        Ok(np)
    }

    fn check_finite(&self) -> Result<(), ModelError> {
        if self
            .scaled()
            .iter()
            .chain(self.ar().iter().flatten())
            .all(|x| x.is_finite())
        {
            Ok(())
        } else {
            Err(ModelError::NonFinite)
        }
    }

    /// The model's shape.
    pub fn shape(&self) -> Shape {
        self.shape
    }

    /// The model's input scaling.
    pub fn scaling(&self) -> Scaling {
        self.scaling
    }

    /// Scaled polynomial coefficients b_ij, index i·(m+1)+j.
    pub fn scaled(&self) -> &[f32] {
        &self.coef[..self.shape.poly_terms()]
    }

    /// Scaled AR pairs [b_k1, b_k2], k = 1..=p.
    pub fn ar(&self) -> &[[f32; 2]] {
        &self.ar[..self.shape.p as usize]
    }

    /// q_j(x) = Σ_i b_ij x^i and q_j'(x) for j = 0..=m, by Horner's scheme.
    #[inline]
    fn columns(&self, x: f32) -> ([f32; MAX_DEG + 1], [f32; MAX_DEG + 1]) {
        let (n, m) = (self.shape.n as usize, self.shape.m as usize);
        let w = m + 1;
        let mut q = [0.0f32; MAX_DEG + 1];
        let mut dq = [0.0f32; MAX_DEG + 1];
        for j in 0..=m {
            let mut p = self.coef[n * w + j];
            let mut dp = 0.0f32;
            for i in (0..n).rev() {
                dp = dp * x + p;
                p = p * x + self.coef[i * w + j];
            }
            q[j] = p;
            dq[j] = dp;
        }
        (q, dq)
    }

    /// Static part: P̂ = Σ α_ij v^i v̇^j, with k = ∂P/∂v and c = ∂P/∂v̇ (no AR terms).
    ///
    /// Errors: `NonFinite` for NaN/∞ input, `OutOfRange` outside the working range.
    #[inline]
    pub fn eval(&self, v: f32, vdot: f32) -> Result<Eval, ModelError> {
        let (x, y) = self.scaling.to_scaled(v, vdot)?;
        let (q, dq) = self.columns(x);
        // Horner in y for P and ∂P/∂x, and the derivative recurrence for ∂P/∂y.
        let m = self.shape.m as usize;
        let (mut p, mut px, mut py) = (q[m], dq[m], 0.0f32);
        for j in (0..m).rev() {
            py = py * y + p;
            p = p * y + q[j];
            px = px * y + dq[j];
        }
        Ok(Eval {
            p: finite(p)?,
            k: finite(px / self.scaling.v_scale)?,
            c: finite(py / self.scaling.f_scale)?,
        })
    }

    /// [`eval`](Self::eval) at `(v, v̇)` and, from the same columns `q_j(x)`, the damping
    /// `∂P/∂v̇` at a second flow `(v, v̇ − δ)`: one more Horner pass in y (2m multiply-adds),
    /// `∂P/∂y (y − δ/f_scale) / f_scale`. The second flow is not range-checked (the law's slope
    /// there is the polynomial's continuation) and its damping is returned as computed (non-finite
    /// only when it overflows); the first is checked as in `eval`.
    ///
    /// The chain's air lag takes its time constant from the damping at the flow midway between
    /// the pump's and the chamber's ([`crate::chain`]).
    #[inline]
    pub fn eval_damping_at(
        &self,
        v: f32,
        vdot: f32,
        delta: f32,
    ) -> Result<(Eval, f32), ModelError> {
        let (x, y) = self.scaling.to_scaled(v, vdot)?;
        let y2 = y - delta / self.scaling.f_scale;
        let (q, dq) = self.columns(x);
        let m = self.shape.m as usize;
        let (mut p, mut px, mut py) = (q[m], dq[m], 0.0f32);
        let (mut p2, mut py2) = (q[m], 0.0f32);
        for j in (0..m).rev() {
            py = py * y + p;
            p = p * y + q[j];
            px = px * y + dq[j];
            py2 = py2 * y2 + p2;
            p2 = p2 * y2 + q[j];
        }
        Ok((
            Eval {
                p: finite(p)?,
                k: finite(px / self.scaling.v_scale)?,
                c: finite(py / self.scaling.f_scale)?,
            },
            py2 / self.scaling.f_scale,
        ))
    }

    /// Full poly-AR prediction: the static part plus Σ_k (b_k1 x(t−k) + b_k2 y(t−k)), with the past
    /// samples taken from `hist` (which must not yet contain the current sample). The AR terms do
    /// not depend on the current v, v̇, so k and c equal those of [`eval`](Self::eval).
    ///
    /// Errors: as `eval`, plus `ShortHistory` when `hist` holds fewer than p samples.
    pub fn eval_ar(&self, v: f32, vdot: f32, hist: &ArHistory) -> Result<Eval, ModelError> {
        let mut e = self.eval(v, vdot)?;
        e.p = finite(e.p + self.ar_sum(hist)?)?;
        Ok(e)
    }

    pub(crate) fn ar_sum(&self, hist: &ArHistory) -> Result<f32, ModelError> {
        let p = self.shape.p as usize;
        if hist.len() < p {
            return Err(ModelError::ShortHistory);
        }
        let mut s = 0.0f32;
        for (k, b) in self.ar().iter().enumerate() {
            let (vk, fk) = hist.get(k + 1).ok_or(ModelError::ShortHistory)?;
            let (xk, yk) = self.scaling.to_scaled(vk, fk)?;
            s += b[0] * xk + b[1] * yk;
        }
        Ok(s)
    }

    /// The split of the static part, paper eq. (9) in the shared source (`\label{eom}`; eq. (13) in
    /// the issue): P = C(v, v̇)·v̇ + K(v), with
    /// K(v) = Σ_i α_i0 v^i = P(v, 0) and C(v, v̇) = Σ_i Σ_{j≥1} α_ij v^i v̇^(j−1).
    ///
    /// In scaled form, with y₀ the scaled image of v̇ = 0, P(y) − P(y₀) = (y − y₀)·R(y) where R is
    /// the synthetic-division quotient of P(·) by (y − y₀); since v̇ = f_scale·(y − y₀),
    /// C = R(y) / f_scale and K = P(y₀). This needs no division by v̇, so it is exact at v̇ = 0.
    /// Returns (C in kPa·s/mm³, K in kPa).
    pub fn split(&self, v: f32, vdot: f32) -> Result<(f32, f32), ModelError> {
        let (x, y) = self.scaling.to_scaled(v, vdot)?;
        let (q, _) = self.columns(x);
        let m = self.shape.m as usize;
        let y0 = -self.scaling.f_offset / self.scaling.f_scale;
        // Synthetic division: d_m = q_m, d_j = q_j + y0·d_{j+1}; the remainder d_0 is P(y0) = K.
        let mut d = q[m];
        let mut r = 0.0f32;
        for j in (0..m).rev() {
            // R(y) = Σ_{j≥1} d_j y^(j−1) by Horner, fed with d_m, d_{m−1}, …, d_1.
            r = r * y + d;
            d = q[j] + y0 * d;
        }
        Ok((finite(r / self.scaling.f_scale)?, finite(d)?))
    }

    /// Scaled regressor row of the static part: out[i·(m+1)+j] = x^i y^j. Returns `poly_terms()`.
    pub fn regressors(&self, v: f32, vdot: f32, out: &mut [f32]) -> Result<usize, ModelError> {
        regressors(self.shape, self.scaling, v, vdot, out)
    }

    /// Full regressor row: the static part, then x(t−k), y(t−k) for k = 1..=p. Returns `params()`.
    pub fn regressors_ar(
        &self,
        v: f32,
        vdot: f32,
        hist: &ArHistory,
        out: &mut [f32],
    ) -> Result<usize, ModelError> {
        regressors_ar(self.shape, self.scaling, v, vdot, hist, out)
    }
}

/// Scaled regressor row x^i y^j (index i·(m+1)+j) for a shape and scaling, without a model
/// (what [`crate::rls::Rls`] needs before any coefficients exist). Returns `poly_terms()`.
pub fn regressors(
    shape: Shape,
    scaling: Scaling,
    v: f32,
    vdot: f32,
    out: &mut [f32],
) -> Result<usize, ModelError> {
    shape.check()?;
    let t = shape.poly_terms();
    if out.len() < t {
        return Err(ModelError::BadLength);
    }
    let (x, y) = scaling.to_scaled(v, vdot)?;
    let (n, m) = (shape.n as usize, shape.m as usize);
    let mut yp = [1.0f32; MAX_DEG + 1];
    for j in 1..=m {
        yp[j] = yp[j - 1] * y;
    }
    let mut xi = 1.0f32;
    for i in 0..=n {
        for j in 0..=m {
            out[i * (m + 1) + j] = xi * yp[j];
        }
        xi *= x;
    }
    Ok(t)
}

/// Full poly-AR regressor row (static part, then x(t−k), y(t−k) for k = 1..=p). Returns `params()`.
pub fn regressors_ar(
    shape: Shape,
    scaling: Scaling,
    v: f32,
    vdot: f32,
    hist: &ArHistory,
    out: &mut [f32],
) -> Result<usize, ModelError> {
    let np = shape.params();
    if out.len() < np {
        return Err(ModelError::BadLength);
    }
    if hist.len() < shape.p as usize {
        return Err(ModelError::ShortHistory);
    }
    let t = regressors(shape, scaling, v, vdot, out)?;
    for k in 0..shape.p as usize {
        let (vk, fk) = hist.get(k + 1).ok_or(ModelError::ShortHistory)?;
        let (xk, yk) = scaling.to_scaled(vk, fk)?;
        out[t + 2 * k] = xk;
        out[t + 2 * k + 1] = yk;
    }
    Ok(np)
}

/// The paper's SBA1 model (Table IV, n = 3, m = 2), raw units (kPa, mm³, mm³/s), index i·3 + j:
/// row i is the power of v, column j the power of v̇.
pub const SBA1_RAW: [f64; 12] = [
    0.0,
    1.7660e-1,
    2.3010e-4, // 1, v̇, v̇²
    1.2695e-2,
    -1.3896e-4,
    -3.0150e-6, // v, v·v̇, v·v̇²
    -8.0664e-5,
    6.6527e-7,
    1.3800e-8, // v², v²·v̇, v²·v̇²
    4.1269e-7,
    -7.3542e-10,
    -1.3773e-11, // v³, v³·v̇, v³·v̇²
];

/// The SBA1 model of Table IV with [`Scaling::SBA1`] (0..550 mm³, ±100 mm³/s).
pub fn sba1() -> PolyModel {
    // Constant, finite input with a valid shape and scaling: conversion cannot fail (tested).
    PolyModel::from_raw(Shape::PAPER, &SBA1_RAW, &[], Scaling::SBA1)
        .expect("SBA1 constants convert")
}
