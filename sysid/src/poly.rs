//! The multivariate polynomial model P̂ = Σᵢ₌₀ⁿ Σⱼ₌₀ᵐ αᵢⱼ vⁱ v̇ʲ (paper Table II), fitted in a
//! well-conditioned basis.
//!
//! # Basis
//! v and v̇ are mapped affinely onto x, y ∈ [−1, 1] ([`Scaling`]: x = (v − v_offset)/v_scale,
//! y = (v̇ − f_offset)/f_scale) and the model is fitted in the Chebyshev product basis
//! Tᵢ(x)Tⱼ(y). It spans the same space as the monomials vⁱv̇ʲ, so the fit is the same model; the
//! coefficients are then converted exactly (integer Chebyshev-to-power tables, binomial
//! expansion of the offset) to the scaled power basis aᵢⱼ xⁱyʲ the device evaluates
//! ([`PolyFit::power`]) and to the paper's raw units αᵢⱼ ([`PolyFit::raw`]). Standard errors follow
//! by the same linear maps: Cov(α) = M Cov(c) Mᵀ.
//!
//! # One-pass sweep of all (n, m)
//! Since TₐT_b = (T_{a+b} + T_{|a−b|})/2, every Gram entry of every model with n, m ≤ 7 is
//! ⟨TᵢTⱼ, TₖTₗ⟩ = ¼ (μ_{i+k, j+l} + μ_{i+k, |j−l|} + μ_{|i−k|, j+l} + μ_{|i−k|, |j−l|})
//! with the moments μ_rs = Σ T_r(x)T_s(y), r, s ≤ 14, and Xᵀy needs only bᵢⱼ = Σ Tᵢ(x)Tⱼ(y)P.
//! [`sweep`] gathers these in one pass over the data (two threads), then solves each model by
//! Cholesky of the Jacobi-scaled Gram. Pressure is centred first (T₀ = 1 is in every model) so
//! SSE = Σ(P − P̄)² − 2cᵀb + cᵀGc suffers no cancellation beyond the fit's own precision; SSE is
//! never reported negative. Single fits ([`fit`]) use Householder QR on the design and
//! residuals computed directly.

use crate::dataset::Columns;
use crate::linreg::{self, CoefStat, FitError};
use crate::metrics::{self, Metrics};
use nalgebra::{DMatrix, DVector};

/// Samples per block of [`Moments`]' gathering (its matrix products).
const GATHER_ROWS: usize = 256;

/// Highest degree in v or v̇ the sweep supports (the paper's 7).
pub const MAX_DEGREE: usize = 7;
const K: usize = 2 * MAX_DEGREE + 1;

/// Affine maps of v and v̇ onto [−1, 1]: x = (v − v_offset)/v_scale, y = (v̇ − f_offset)/f_scale.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Scaling {
    /// Centre of the volume range, mm³.
    pub v_offset: f64,
    /// Half-width of the volume range, mm³.
    pub v_scale: f64,
    /// Centre of the flow range, mm³/s.
    pub f_offset: f64,
    /// Half-width of the flow range, mm³/s.
    pub f_scale: f64,
}

impl Scaling {
    /// The scaling mapping the data's ranges onto [−1, 1]. Errors on constant volume, zero flow
    /// everywhere, non-finite values or no data.
    pub fn from_data(v: &[f64], vdot: &[f64]) -> Result<Scaling, PolyError> {
        if v.is_empty() {
            return Err(PolyError::NoData);
        }
        let range = |xs: &[f64], column: &'static str| -> Result<(f64, f64), PolyError> {
            let mut lo = f64::INFINITY;
            let mut hi = f64::NEG_INFINITY;
            for (index, &x) in xs.iter().enumerate() {
                if !x.is_finite() {
                    return Err(PolyError::NotFinite { column, index });
                }
                lo = lo.min(x);
                hi = hi.max(x);
            }
            Ok((lo, hi))
        };
        let (vl, vh) = range(v, "volume")?;
        let (fl, fh) = range(vdot, "flow")?;
        // Negated on purpose: a NaN span must also count as constant.
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !(vh - vl > 1e-9 * vh.abs().max(vl.abs()).max(1e-300)) {
            return Err(PolyError::ConstantVolume { value: vl });
        }
        if fl == 0.0 && fh == 0.0 {
            return Err(PolyError::ZeroFlow);
        }
        #[allow(clippy::neg_cmp_op_on_partial_ord)]
        if !(fh - fl > 1e-9 * fh.abs().max(fl.abs())) {
            return Err(PolyError::ConstantFlow { value: fl });
        }
        Ok(Scaling {
            v_offset: 0.5 * (vh + vl),
            v_scale: 0.5 * (vh - vl),
            f_offset: 0.5 * (fh + fl),
            f_scale: 0.5 * (fh - fl),
        })
    }

    /// Pure scaling without offsets (x = v/v_scale): raw monomial terms stay single terms, which
    /// is what term pruning needs.
    pub fn without_offset(&self) -> Scaling {
        Scaling {
            v_offset: 0.0,
            v_scale: self.v_offset.abs() + self.v_scale,
            f_offset: 0.0,
            f_scale: self.f_offset.abs() + self.f_scale,
        }
    }

    /// (x, y) for (v, v̇).
    pub fn apply(&self, v: f64, vdot: f64) -> (f64, f64) {
        (
            (v - self.v_offset) / self.v_scale,
            (vdot - self.f_offset) / self.f_scale,
        )
    }
}

/// Why polynomial identification cannot proceed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PolyError {
    /// No samples.
    #[error("no samples to fit")]
    NoData,
    /// NaN or infinity in the data.
    #[error("{column} at sample {index} is not a finite number")]
    NotFinite {
        /// "volume", "flow" or "pressure".
        column: &'static str,
        /// Sample index.
        index: usize,
    },
    /// Volume never changes: no v terms can be identified.
    #[error("volume is constant ({value} mm³) over the whole data set; a volume-pressure model needs the volume to vary")]
    ConstantVolume {
        /// The constant value.
        value: f64,
    },
    /// Flow is zero everywhere: v̇ terms cannot be identified.
    #[error(
        "flow is zero everywhere; models with v̇ terms cannot be identified (did the pumps move?)"
    )]
    ZeroFlow,
    /// Flow never changes.
    #[error(
        "flow is constant ({value} mm³/s) over the whole data set; v̇ terms cannot be identified"
    )]
    ConstantFlow {
        /// The constant value.
        value: f64,
    },
    /// Degrees out of range.
    #[error("polynomial degrees n = {n}, m = {m} are outside 0..={MAX_DEGREE}")]
    Degree {
        /// n.
        n: usize,
        /// m.
        m: usize,
    },
    /// The least-squares problem failed.
    #[error("({n}, {m}) model: {source}")]
    Fit {
        /// n.
        n: usize,
        /// m.
        m: usize,
        /// Cause.
        source: FitError,
    },
}

/// Borrowed data for a fit: volume, flow, pressure (same lengths).
#[derive(Debug, Clone, Copy)]
pub struct Xy<'a> {
    /// v, mm³.
    pub v: &'a [f64],
    /// v̇, mm³/s.
    pub vdot: &'a [f64],
    /// P, kPa.
    pub p: &'a [f64],
}

impl<'a> From<&'a crate::dataset::Dataset> for Xy<'a> {
    fn from(d: &'a crate::dataset::Dataset) -> Self {
        Xy {
            v: &d.v,
            vdot: &d.vdot,
            p: &d.p,
        }
    }
}

impl<'a> From<&'a Columns> for Xy<'a> {
    fn from(c: &'a Columns) -> Self {
        Xy {
            v: &c.v,
            vdot: &c.vdot,
            p: &c.p,
        }
    }
}

impl Xy<'_> {
    fn check(&self) -> Result<(), PolyError> {
        assert!(
            self.v.len() == self.vdot.len() && self.v.len() == self.p.len(),
            "column lengths differ"
        );
        if self.p.is_empty() {
            return Err(PolyError::NoData);
        }
        for (column, xs) in [
            ("volume", self.v),
            ("flow", self.vdot),
            ("pressure", self.p),
        ] {
            if let Some(index) = xs.iter().position(|x| !x.is_finite()) {
                return Err(PolyError::NotFinite { column, index });
            }
        }
        Ok(())
    }
}

/// Chebyshev values T₀(x) ..= T_{len−1}(x) by the three-term recurrence (stable on [−1, 1]).
#[inline]
pub fn chebyshev(x: f64, out: &mut [f64]) {
    if out.is_empty() {
        return;
    }
    out[0] = 1.0;
    if out.len() > 1 {
        out[1] = x;
    }
    for k in 2..out.len() {
        out[k] = 2.0 * x * out[k - 1] - out[k - 2];
    }
}

/// Power-basis coefficients of T₀ ..= T_deg: `t[i][k]` is the coefficient of xᵏ in Tᵢ (exact
/// integers in f64).
pub fn chebyshev_to_power(deg: usize) -> Vec<Vec<f64>> {
    let mut t = vec![vec![0.0; deg + 1]; deg + 1];
    t[0][0] = 1.0;
    if deg >= 1 {
        t[1][1] = 1.0;
    }
    for i in 2..=deg {
        for k in 0..=deg {
            let up = if k > 0 { 2.0 * t[i - 1][k - 1] } else { 0.0 };
            t[i][k] = up - t[i - 2][k];
        }
    }
    t
}

/// Name of the term vⁱv̇ʲ in the paper's notation ("1", "v", "v^2 vdot", ...).
pub fn term_name(i: usize, j: usize) -> String {
    let p = |s: &str, k: usize| match k {
        0 => String::new(),
        1 => s.to_string(),
        _ => format!("{s}^{k}"),
    };
    let parts: Vec<String> = [p("v", i), p("vdot", j)]
        .into_iter()
        .filter(|s| !s.is_empty())
        .collect();
    if parts.is_empty() {
        "1".into()
    } else {
        parts.join(" ")
    }
}

/// A fitted polynomial model with coefficient statistics.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PolyFit {
    /// Highest power of v.
    pub n: usize,
    /// Highest power of v̇.
    pub m: usize,
    /// The map to the basis variables x, y.
    pub scaling: Scaling,
    /// aᵢⱼ of P̂ = Σ aᵢⱼ xⁱyʲ at index i·(m+1)+j (0 for pruned terms).
    pub power: Vec<f64>,
    /// The paper-unit coefficients αᵢⱼ (kPa / (mm³)ⁱ (mm³/s)ʲ) with SE, t and p at index i·(m+1)+j.
    pub raw: Vec<CoefStat>,
    /// Which terms are in the model (all unless pruned).
    pub active: Vec<bool>,
    /// Estimated parameters ν.
    pub nu: usize,
    /// Residual variance σ̂² = SSE/(N − ν).
    pub sigma2: f64,
    /// In-sample metrics (residuals computed directly).
    pub train: Metrics,
}

impl PolyFit {
    /// Index of the term vⁱv̇ʲ.
    pub fn index(&self, i: usize, j: usize) -> usize {
        i * (self.m + 1) + j
    }

    /// Predicted pressure, kPa (Horner in x, then y).
    pub fn predict(&self, v: f64, vdot: f64) -> f64 {
        let (x, y) = self.scaling.apply(v, vdot);
        let mut acc = 0.0;
        for i in (0..=self.n).rev() {
            let row = &self.power[i * (self.m + 1)..(i + 1) * (self.m + 1)];
            let inner = row.iter().rev().fold(0.0, |a, &c| a * y + c);
            acc = acc * x + inner;
        }
        acc
    }

    /// Predictions for many samples (on the available cores; each is [`PolyFit::predict`]'s).
    pub fn predict_all(&self, v: &[f64], vdot: &[f64]) -> Vec<f64> {
        crate::par::par_map_items(v.len().min(vdot.len()), |k| self.predict(v[k], vdot[k]))
    }

    /// (∂P/∂v, ∂P/∂v̇): instantaneous stiffness k (kPa/mm³) and damping c (kPa·s/mm³), Sec. IV-A.
    pub fn partials(&self, v: f64, vdot: f64) -> (f64, f64) {
        let (x, y) = self.scaling.apply(v, vdot);
        let (mut dx, mut dy) = (0.0, 0.0);
        for i in 0..=self.n {
            for j in 0..=self.m {
                let a = self.power[self.index(i, j)];
                if i > 0 {
                    dx += a * i as f64 * x.powi(i as i32 - 1) * y.powi(j as i32);
                }
                if j > 0 {
                    dy += a * j as f64 * x.powi(i as i32) * y.powi(j as i32 - 1);
                }
            }
        }
        (dx / self.scaling.v_scale, dy / self.scaling.f_scale)
    }

    /// The model as the device stores it ([`model_core::poly::PolyModel`], f32).
    pub fn to_model_core(&self) -> Result<model_core::poly::PolyModel, model_core::ModelError> {
        to_model_core(self.n, self.m, &self.power, &[], &self.scaling)
    }

    /// Term names in index order.
    pub fn term_names(&self) -> Vec<String> {
        (0..=self.n)
            .flat_map(|i| (0..=self.m).map(move |j| term_name(i, j)))
            .collect()
    }
}

/// Converts Chebyshev coefficients cᵢⱼ of Tᵢ(x)Tⱼ(y) (index i·(m+1)+j) to power-basis coefficients
/// aₖₗ of xᵏyˡ, exactly: aₖₗ = Σᵢⱼ cᵢⱼ tᵢₖ tⱼₗ.
pub fn chebyshev_to_power_2d(c: &[f64], n: usize, m: usize) -> Vec<f64> {
    assert_eq!(c.len(), (n + 1) * (m + 1), "one coefficient per term");
    let (tn, tm) = (chebyshev_to_power(n), chebyshev_to_power(m));
    let mut a = vec![0.0; c.len()];
    for i in 0..=n {
        for j in 0..=m {
            let cij = c[i * (m + 1) + j];
            for k in 0..=i {
                for l in 0..=j {
                    a[k * (m + 1) + l] += cij * tn[i][k] * tm[j][l];
                }
            }
        }
    }
    a
}

/// The model in the form the device evaluates (f32, same scaling and term order).
pub fn to_model_core(
    n: usize,
    m: usize,
    power: &[f64],
    ar: &[[f64; 2]],
    scaling: &Scaling,
) -> Result<model_core::poly::PolyModel, model_core::ModelError> {
    use model_core::poly::{PolyModel, Scaling as DevScaling, Shape};
    let shape = Shape::new(n as u8, m as u8, ar.len() as u8)?;
    let sc = DevScaling::new(
        scaling.v_offset as f32,
        scaling.v_scale as f32,
        scaling.f_offset as f32,
        scaling.f_scale as f32,
    )?;
    let b: Vec<f32> = power.iter().map(|&x| x as f32).collect();
    let ar32: Vec<[f32; 2]> = ar.iter().map(|p| [p[0] as f32, p[1] as f32]).collect();
    PolyModel::from_scaled(shape, &b, &ar32, sc)
}

/// Matrix mapping coefficients in the scaled power basis (offset o, scale s) to raw units, per
/// variable: raw_p = Σ_{k≥p} a_k C(k, p) (−o)ᵖ⁻ᵏ... i.e. x^k = ((v − o)/s)^k expanded.
#[allow(clippy::needless_range_loop)] // b[p][k] mirrors the binomial formula's indices
fn power_to_raw_1d(deg: usize, offset: f64, scale: f64) -> Vec<Vec<f64>> {
    // b[p][k]: coefficient of v^p in x^k.
    let mut b = vec![vec![0.0; deg + 1]; deg + 1];
    for k in 0..=deg {
        let sk = scale.powi(k as i32);
        let mut binom = 1.0f64;
        for p in 0..=k {
            if p > 0 {
                binom = binom * (k - p + 1) as f64 / p as f64;
            }
            b[p][k] = binom * (-offset).powi((k - p) as i32) / sk;
        }
    }
    b
}

/// Fits the full (n, m) model to `data` in the Chebyshev basis; `scaling` defaults to the data's
/// own ([`Scaling::from_data`]).
///
/// The fit comes from one pass of Chebyshev moments, without a design matrix: the coefficients
/// solve the Jacobi-scaled Gram system by Cholesky (as the sweep's, [`solve_chebyshev`]), the
/// covariance is σ̂² D Gs⁻¹ D, and σ̂² comes from the residuals computed directly (a second pass,
/// no cancellation). Normal equations square the condition number, so this route is taken only
/// when the scaled Gram's 1-norm condition number κ₁(Gs) = ‖Gs‖₁‖Gs⁻¹‖₁ is at most
/// [`MAX_GRAM_CONDITION`] (the coefficients then keep at least ten significant digits against
/// the QR's); otherwise, and when the Gram is not positive definite, the design is built and
/// factored by Householder QR ([`linreg::lstsq`]), whose errors name the dependent term.
pub fn fit(data: Xy, n: usize, m: usize, scaling: Option<Scaling>) -> Result<PolyFit, PolyError> {
    data.check()?;
    if n > MAX_DEGREE || m > MAX_DEGREE {
        return Err(PolyError::Degree { n, m });
    }
    let scaling = match scaling {
        Some(s) => s,
        None => Scaling::from_data(data.v, data.vdot)?,
    };
    let centre = data.p.iter().sum::<f64>() / data.p.len() as f64;
    let mt = Moments::gather(data, &scaling, centre);
    fit_moments(data, n, m, scaling, &mt, centre)
}

/// [`fit`] with `data`'s moments already gathered under `scaling`, its pressure centred at its
/// mean (as [`Moments::gather`] by [`fit`], or the training moments of a [`SweepMoments`]): the
/// same result without a second pass for them.
pub fn fit_from(
    data: Xy,
    n: usize,
    m: usize,
    scaling: Scaling,
    mt: &Moments,
) -> Result<PolyFit, PolyError> {
    data.check()?;
    if n > MAX_DEGREE || m > MAX_DEGREE {
        return Err(PolyError::Degree { n, m });
    }
    let centre = data.p.iter().sum::<f64>() / data.p.len() as f64;
    fit_moments(data, n, m, scaling, mt, centre)
}

/// [`fit`] and [`fit_from`] once `data` is checked and its moments `mt` gathered, the pressure
/// centred at `centre`.
fn fit_moments(
    data: Xy,
    n: usize,
    m: usize,
    scaling: Scaling,
    mt: &Moments,
    centre: f64,
) -> Result<PolyFit, PolyError> {
    let (c, xtx_inv, sse) = match Restricted::new(mt, n, m, &scaling, centre)
        .ok()
        .and_then(|g| g.inverse_if_conditioned())
    {
        Some((mut c, xtx_inv)) => {
            let sse = sse_direct(data, &scaling, n, m, &c, centre);
            c[0] += centre;
            (c, xtx_inv, sse)
        }
        None => fit_qr(data, n, m, &scaling)?,
    };
    let nu = (n + 1) * (m + 1);
    let dof = data.p.len() - nu;
    let sigma2 = sse / dof as f64;
    let (a_of_c, raw_of_c) = chebyshev_maps(n, m, &scaling);
    let power: Vec<f64> = (&a_of_c * &c).iter().copied().collect();
    let raw = &raw_of_c * &c;
    let cov_raw = &raw_of_c * (xtx_inv * sigma2) * raw_of_c.transpose();
    let raw_stats = linreg::coef_stats(raw.as_slice(), &cov_raw, dof);
    finish(
        data,
        n,
        m,
        scaling,
        power,
        raw_stats,
        vec![true; nu],
        sigma2,
    )
}

/// Largest 1-norm condition number of the Jacobi-scaled Gram matrix for which [`fit`] solves the
/// normal equations (relative error ≲ κ·ε ≈ 2·10⁻¹⁰); above it, QR.
pub const MAX_GRAM_CONDITION: f64 = 1e6;

/// SSE of the centred Chebyshev coefficients `c` on `data`, from the residuals themselves.
/// The residuals come from the available cores; their squares are summed in order.
fn sse_direct(data: Xy, sc: &Scaling, n: usize, m: usize, c: &DVector<f64>, centre: f64) -> f64 {
    let residual = |k: usize| {
        let mut tx = [0.0; MAX_DEGREE + 1];
        let mut ty = [0.0; MAX_DEGREE + 1];
        let (a, b) = sc.apply(data.v[k], data.vdot[k]);
        chebyshev(a, &mut tx[..=n]);
        chebyshev(b, &mut ty[..=m]);
        let mut pred = 0.0;
        for i in 0..=n {
            for j in 0..=m {
                pred += c[i * (m + 1) + j] * tx[i] * ty[j];
            }
        }
        data.p[k] - centre - pred
    };
    let mut sse = 0.0;
    for r in crate::par::par_map_items(data.p.len(), residual) {
        sse += r.powi(2);
    }
    sse
}

/// The (n, m) fit by Householder QR of the design (uncentred Chebyshev coefficients, (XᵀX)⁻¹
/// and SSE): [`fit`]'s route when the Gram is ill-conditioned.
fn fit_qr(
    data: Xy,
    n: usize,
    m: usize,
    scaling: &Scaling,
) -> Result<(DVector<f64>, DMatrix<f64>, f64), PolyError> {
    let nu = (n + 1) * (m + 1);
    let rows = data.p.len();
    let mut x = DMatrix::zeros(rows, nu);
    let mut tx = [0.0; MAX_DEGREE + 1];
    let mut ty = [0.0; MAX_DEGREE + 1];
    for r in 0..rows {
        let (a, b) = scaling.apply(data.v[r], data.vdot[r]);
        chebyshev(a, &mut tx[..=n]);
        chebyshev(b, &mut ty[..=m]);
        for i in 0..=n {
            for j in 0..=m {
                x[(r, i * (m + 1) + j)] = tx[i] * ty[j];
            }
        }
    }
    let names: Vec<String> = (0..=n)
        .flat_map(|i| (0..=m).map(move |j| format!("T{i}(x)T{j}(y)")))
        .collect();
    let lf = linreg::lstsq(x, data.p, &names).map_err(|source| PolyError::Fit { n, m, source })?;
    Ok((DVector::from_column_slice(&lf.coef), lf.xtx_inv, lf.sse))
}

/// The linear maps from the (n, m) model's Chebyshev coefficients c (index i·(m+1)+j) to its
/// scaled power-basis coefficients a (a_kl = Σ_ij c_ij t_ik t_jl) and to its raw paper-unit
/// coefficients α (the binomial expansion of x = (v − o)/s), as (a_of_c, raw_of_c).
fn chebyshev_maps(n: usize, m: usize, scaling: &Scaling) -> (DMatrix<f64>, DMatrix<f64>) {
    let nu = (n + 1) * (m + 1);
    let tn = chebyshev_to_power(n);
    let tm = chebyshev_to_power(m);
    let a_of_c = DMatrix::from_fn(nu, nu, |row, col| {
        let (k, l) = (row / (m + 1), row % (m + 1));
        let (i, j) = (col / (m + 1), col % (m + 1));
        tn[i][k] * tm[j][l]
    });
    let bn = power_to_raw_1d(n, scaling.v_offset, scaling.v_scale);
    let bm = power_to_raw_1d(m, scaling.f_offset, scaling.f_scale);
    let raw_of_a = DMatrix::from_fn(nu, nu, |row, col| {
        let (p, q) = (row / (m + 1), row % (m + 1));
        let (k, l) = (col / (m + 1), col % (m + 1));
        bn[p][k] * bm[q][l]
    });
    let raw_of_c = &raw_of_a * &a_of_c;
    (a_of_c, raw_of_c)
}

/// Builds the [`PolyFit`] and its in-sample metrics from directly computed residuals.
#[allow(clippy::too_many_arguments)]
fn finish(
    data: Xy,
    n: usize,
    m: usize,
    scaling: Scaling,
    power: Vec<f64>,
    raw: Vec<CoefStat>,
    active: Vec<bool>,
    sigma2: f64,
) -> Result<PolyFit, PolyError> {
    let nu = active.iter().filter(|&&a| a).count();
    let mut f = PolyFit {
        n,
        m,
        scaling,
        power,
        raw,
        active,
        nu,
        sigma2,
        train: metrics::from_sse(0.0, 1.0, nu + 2, nu).expect("placeholder metrics are valid"),
    };
    let pred = f.predict_all(data.v, data.vdot);
    f.train = metrics::compute(data.p, &pred, nu).map_err(|_| PolyError::Fit {
        n,
        m,
        source: FitError::TooFewSamples {
            n: data.p.len(),
            nu,
        },
    })?;
    Ok(f)
}

/// Fits the (n, m) model with only the `active` raw terms αᵢⱼ (index i·(m+1)+j), in the scaled
/// monomial basis (x = v/s, y = v̇/s without offsets, so each raw term is one basis column).
pub fn fit_terms(data: Xy, n: usize, m: usize, active: &[bool]) -> Result<PolyFit, PolyError> {
    data.check()?;
    if n > MAX_DEGREE || m > MAX_DEGREE {
        return Err(PolyError::Degree { n, m });
    }
    let nu_full = (n + 1) * (m + 1);
    assert_eq!(active.len(), nu_full, "one flag per term");
    let scaling = Scaling::from_data(data.v, data.vdot)?.without_offset();
    let cols: Vec<usize> = (0..nu_full).filter(|&k| active[k]).collect();
    let rows = data.p.len();
    let mut x = DMatrix::zeros(rows, cols.len());
    for r in 0..rows {
        let (a, b) = scaling.apply(data.v[r], data.vdot[r]);
        for (c, &k) in cols.iter().enumerate() {
            x[(r, c)] = a.powi((k / (m + 1)) as i32) * b.powi((k % (m + 1)) as i32);
        }
    }
    let names: Vec<String> = cols
        .iter()
        .map(|&k| term_name(k / (m + 1), k % (m + 1)))
        .collect();
    let lf = linreg::lstsq(x, data.p, &names).map_err(|source| PolyError::Fit { n, m, source })?;
    let mut power = vec![0.0; nu_full];
    let mut raw = vec![
        CoefStat {
            estimate: 0.0,
            se: 0.0,
            t: 0.0,
            p: 1.0
        };
        nu_full
    ];
    let stats = linreg::coef_stats(&lf.coef, &lf.cov(), lf.dof());
    for (c, &k) in cols.iter().enumerate() {
        let unit =
            scaling.v_scale.powi((k / (m + 1)) as i32) * scaling.f_scale.powi((k % (m + 1)) as i32);
        power[k] = lf.coef[c];
        let s = stats[c];
        raw[k] = CoefStat {
            estimate: s.estimate / unit,
            se: s.se / unit,
            t: s.t,
            p: s.p,
        };
    }
    finish(
        data,
        n,
        m,
        scaling,
        power,
        raw,
        active.to_vec(),
        lf.sigma2(),
    )
}

/// Low-order moments of the data in the Chebyshev basis (see the module docs).
#[derive(Debug, Clone)]
pub struct Moments {
    /// Samples.
    pub n: usize,
    /// μ_rs = Σ T_r(x)T_s(y).
    pub mu: [[f64; K]; K],
    /// bᵢⱼ = Σ Tᵢ(x)Tⱼ(y)(P − centre).
    pub b: [[f64; MAX_DEGREE + 1]; MAX_DEGREE + 1],
    /// Σ (P − centre)².
    pub yy: f64,
    /// Σ (P − P̄)² about the data's own mean (for R²).
    pub sst: f64,
}

impl Moments {
    /// One pass over `data` (split over the available cores for large data). Pressure is centred
    /// at `centre`.
    pub fn gather(data: Xy, scaling: &Scaling, centre: f64) -> Moments {
        let n = data.p.len();
        let threads = if n < 20_000 {
            1
        } else {
            std::thread::available_parallelism()
                .map_or(1, |t| t.get())
                .min(8)
        };
        let chunk = n.div_ceil(threads.max(1)).max(1);
        let parts: Vec<Moments> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..n)
                .step_by(chunk)
                .map(|start| {
                    let end = (start + chunk).min(n);
                    s.spawn(move || Self::gather_serial(data, scaling, centre, start..end))
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("moment thread panicked"))
                .collect()
        });
        let mut total = Moments {
            n,
            mu: [[0.0; K]; K],
            b: [[0.0; MAX_DEGREE + 1]; MAX_DEGREE + 1],
            yy: 0.0,
            sst: 0.0,
        };
        for p in &parts {
            for r in 0..K {
                for s in 0..K {
                    total.mu[r][s] += p.mu[r][s];
                }
            }
            for i in 0..=MAX_DEGREE {
                for j in 0..=MAX_DEGREE {
                    total.b[i][j] += p.b[i][j];
                }
            }
            total.yy += p.yy;
        }
        let mean = data.p.iter().sum::<f64>() / n.max(1) as f64;
        total.sst = data.p.iter().map(|p| (p - mean).powi(2)).sum();
        total
    }

    /// All-zero moments of no samples (the neutral element of [`Moments::add`]).
    pub fn zero() -> Moments {
        Moments {
            n: 0,
            mu: [[0.0; K]; K],
            b: [[0.0; MAX_DEGREE + 1]; MAX_DEGREE + 1],
            yy: 0.0,
            sst: 0.0,
        }
    }

    /// Adds the sums of `o` (samples of another part of the data, same scaling and centre) to
    /// these. `sst` is not additive and is left alone.
    pub fn add(&mut self, o: &Moments) {
        self.n += o.n;
        for (row, orow) in self.mu.iter_mut().zip(&o.mu) {
            for (a, b) in row.iter_mut().zip(orow) {
                *a += b;
            }
        }
        for (row, orow) in self.b.iter_mut().zip(&o.b) {
            for (a, b) in row.iter_mut().zip(orow) {
                *a += b;
            }
        }
        self.yy += o.yy;
    }

    /// The moments of the samples `range` of `data`, in one thread (`sst` left at zero).
    pub fn gather_range(
        data: Xy,
        scaling: &Scaling,
        centre: f64,
        range: std::ops::Range<usize>,
    ) -> Moments {
        let n = range.len();
        Moments {
            n,
            ..Self::gather_serial(data, scaling, centre, range)
        }
    }

    /// Σ T_r(x)T_s(y), Σ Tᵢ(x)Tⱼ(y)(P − centre) and Σ (P − centre)² over `range`, in one thread.
    /// A block of [`GATHER_ROWS`] samples at a time: the Chebyshev values of x (K × rows) and of y
    /// with y·(P − centre) beside them (rows × (K + MAX_DEGREE + 1)) are filled, and one matrix
    /// product adds all their cross sums (nalgebra's `gemm`, vectorised by `matrixmultiply`).
    fn gather_serial(
        data: Xy,
        scaling: &Scaling,
        centre: f64,
        range: std::ops::Range<usize>,
    ) -> Moments {
        const W: usize = K + MAX_DEGREE + 1;
        let mut acc = DMatrix::<f64>::zeros(K, W);
        let mut tx = DMatrix::<f64>::zeros(K, GATHER_ROWS);
        let mut ty = DMatrix::<f64>::zeros(GATHER_ROWS, W);
        let mut yy = 0.0;
        let mut t = [0.0f64; K];
        let mut start = range.start;
        while start < range.end {
            let rows = GATHER_ROWS.min(range.end - start);
            for k in 0..rows {
                let r = start + k;
                let (x, y) = scaling.apply(data.v[r], data.vdot[r]);
                chebyshev(x, tx.column_mut(k).as_mut_slice());
                chebyshev(y, &mut t);
                let p = data.p[r] - centre;
                yy += p * p;
                for (s, &u) in t.iter().enumerate() {
                    ty[(k, s)] = u;
                }
                for (s, &u) in t[..=MAX_DEGREE].iter().enumerate() {
                    ty[(k, K + s)] = u * p;
                }
            }
            acc.gemm(1.0, &tx.columns(0, rows), &ty.rows(0, rows), 1.0);
            start += rows;
        }
        let mut mu = [[0.0f64; K]; K];
        let mut b = [[0.0f64; MAX_DEGREE + 1]; MAX_DEGREE + 1];
        for (r, row) in mu.iter_mut().enumerate() {
            for (s, x) in row.iter_mut().enumerate() {
                *x = acc[(r, s)];
            }
        }
        for (i, row) in b.iter_mut().enumerate() {
            for (j, x) in row.iter_mut().enumerate() {
                *x = acc[(i, K + j)];
            }
        }
        Moments {
            n: 0,
            mu,
            b,
            yy,
            sst: 0.0,
        }
    }

    /// Gram matrix of the (n, m) model's Chebyshev columns.
    pub fn gram(&self, n: usize, m: usize) -> DMatrix<f64> {
        let w = m + 1;
        DMatrix::from_fn((n + 1) * w, (n + 1) * w, |r, c| {
            let (i, j) = (r / w, r % w);
            let (k, l) = (c / w, c % w);
            let (sx, dx) = (i + k, i.abs_diff(k));
            let (sy, dy) = (j + l, j.abs_diff(l));
            0.25 * (self.mu[sx][sy] + self.mu[sx][dy] + self.mu[dx][sy] + self.mu[dx][dy])
        })
    }

    /// Xᵀy of the (n, m) model.
    pub fn xty(&self, n: usize, m: usize) -> DVector<f64> {
        DVector::from_fn((n + 1) * (m + 1), |r, _| self.b[r / (m + 1)][r % (m + 1)])
    }

    /// SSE of Chebyshev coefficients `c` (for centred pressure) on these data: yy − 2cᵀb + cᵀGc,
    /// clamped at zero.
    pub fn sse(&self, n: usize, m: usize, c: &DVector<f64>) -> f64 {
        // cᵀGc straight from the moments (no Gram matrix built): G's entry for (i, j), (k, l) is
        // ¼(μ[i+k][j+l] + μ[i+k][|j−l|] + μ[|i−k|][j+l] + μ[|i−k|][|j−l|]).
        let w = m + 1;
        let mut quad = 0.0;
        let mut lin = 0.0;
        for i in 0..=n {
            for j in 0..=m {
                lin += c[i * w + j] * self.b[i][j];
            }
            for k in 0..=n {
                let (sum, diff) = (&self.mu[i + k], &self.mu[i.abs_diff(k)]);
                for j in 0..=m {
                    let mut acc = 0.0;
                    for l in 0..=m {
                        let (sy, dy) = (j + l, j.abs_diff(l));
                        acc += c[k * w + l] * (sum[sy] + sum[dy] + diff[sy] + diff[dy]);
                    }
                    quad += c[i * w + j] * acc;
                }
            }
        }
        (self.yy - 2.0 * lin + 0.25 * quad).max(0.0)
    }
}

/// One model of a sweep.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SweepEntry {
    /// Highest power of v.
    pub n: usize,
    /// Highest power of v̇.
    pub m: usize,
    /// Parameters (n+1)(m+1).
    pub nu: usize,
    /// Chebyshev coefficients cᵢⱼ at index i·(m+1)+j (constant term includes the centring).
    pub chebyshev: Vec<f64>,
    /// Metrics on the training data.
    pub train: Metrics,
    /// Metrics on the held-out data (if any).
    pub heldout: Option<Metrics>,
}

/// Rank threshold for Cholesky pivots of the Jacobi-scaled Gram (its accuracy is √ε-limited).
const CHOL_TOL: f64 = 1e-7;

/// Fits every (n, m) with 1 ≤ n ≤ max_n, 1 ≤ m ≤ max_m (row-major in n) on `train` and scores it on
/// `heldout`, from one pass of moments over each set. A model that cannot be fitted (too few
/// samples, rank-deficient) is an `Err` entry; data that no model can use is an outer `Err`.
#[allow(clippy::type_complexity)]
pub fn sweep(
    train: Xy,
    heldout: Option<Xy>,
    scaling: &Scaling,
    max_n: usize,
    max_m: usize,
) -> Result<Vec<Result<SweepEntry, PolyError>>, PolyError> {
    if max_n > MAX_DEGREE || max_m > MAX_DEGREE {
        return Err(PolyError::Degree { n: max_n, m: max_m });
    }
    SweepMoments::gather(train, heldout, scaling)?.sweep(max_n, max_m)
}

/// What [`sweep`] solves every shape from: the training set's moments and the held-out set's, in
/// one scaling, the pressure centred at the training mean. Kept, they also give the selected
/// shape's fit on the training set ([`fit_from`]) without another pass.
#[derive(Debug, Clone)]
pub struct SweepMoments {
    /// The training set's moments.
    pub train: Moments,
    /// The held-out set's, when it has samples.
    pub heldout: Option<Moments>,
    /// The training pressure's mean, where both are centred.
    pub centre: f64,
}

impl SweepMoments {
    /// One pass over each set. Errors as [`sweep`]'s: no training samples, a non-finite value.
    pub fn gather(
        train: Xy,
        heldout: Option<Xy>,
        scaling: &Scaling,
    ) -> Result<SweepMoments, PolyError> {
        train.check()?;
        let centre = train.p.iter().sum::<f64>() / train.p.len() as f64;
        let mt = Moments::gather(train, scaling, centre);
        let mh = match heldout {
            Some(h) if !h.p.is_empty() => {
                h.check()?;
                Some(Moments::gather(h, scaling, centre))
            }
            _ => None,
        };
        Ok(SweepMoments {
            train: mt,
            heldout: mh,
            centre,
        })
    }

    /// [`sweep`]'s entries, from these moments.
    #[allow(clippy::type_complexity)]
    pub fn sweep(
        &self,
        max_n: usize,
        max_m: usize,
    ) -> Result<Vec<Result<SweepEntry, PolyError>>, PolyError> {
        if max_n > MAX_DEGREE || max_m > MAX_DEGREE {
            return Err(PolyError::Degree { n: max_n, m: max_m });
        }
        Ok(crate::par::par_map(max_n * max_m, |k| {
            let (n, m) = (1 + k / max_m, 1 + k % max_m);
            solve_entry(&self.train, self.heldout.as_ref(), n, m, self.centre)
        }))
    }
}

fn solve_entry(
    mt: &Moments,
    mh: Option<&Moments>,
    n: usize,
    m: usize,
    centre: f64,
) -> Result<SweepEntry, PolyError> {
    let nu = (n + 1) * (m + 1);
    let err = |source| PolyError::Fit { n, m, source };
    let c = solve_chebyshev(mt, n, m)?;
    let sse = mt.sse(n, m, &c);
    let train = metrics::from_sse(sse, mt.sst, mt.n, nu)
        .map_err(|_| err(FitError::TooFewSamples { n: mt.n, nu }))?;
    let heldout = mh.and_then(|h| metrics::from_sse(h.sse(n, m, &c), h.sst, h.n, nu).ok());
    let mut chebyshev: Vec<f64> = c.iter().copied().collect();
    chebyshev[0] += centre;
    Ok(SweepEntry {
        n,
        m,
        nu,
        chebyshev,
        train,
        heldout,
    })
}

/// The least-squares Chebyshev coefficients of the (n, m) model (for the pressure centred as in
/// `mt`) from the moments alone: Cholesky of the Jacobi-scaled Gram, a pivot below [`CHOL_TOL`]
/// naming the term that is not identifiable.
pub fn solve_chebyshev(mt: &Moments, n: usize, m: usize) -> Result<DVector<f64>, PolyError> {
    let nu = (n + 1) * (m + 1);
    let err = |source| PolyError::Fit { n, m, source };
    if mt.n < nu + 2 {
        return Err(err(FitError::TooFewSamples { n: mt.n, nu }));
    }
    let g = mt.gram(n, m);
    let b = mt.xty(n, m);
    let d = DVector::from_fn(nu, |i, _| 1.0 / g[(i, i)].max(f64::MIN_POSITIVE).sqrt());
    let gs = DMatrix::from_fn(nu, nu, |i, j| g[(i, j)] * d[i] * d[j]);
    let chol = nalgebra::Cholesky::new(gs).ok_or_else(|| {
        err(FitError::RankDeficient {
            term: format!("{} (Gram not positive definite)", term_name(n, m)),
        })
    })?;
    let l = chol.l_dirty();
    if let Some(k) = (0..nu).find(|&k| l[(k, k)] < CHOL_TOL) {
        return Err(err(FitError::RankDeficient {
            term: term_name(k / (m + 1), k % (m + 1)),
        }));
    }
    let bs = b.component_mul(&d);
    Ok(chol.solve(&bs).component_mul(&d))
}

/// One row of a Table IV-style pruning report.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PruneRow {
    /// Names of the excluded terms.
    pub excluded: Vec<String>,
    /// Parameters left.
    pub nu: usize,
    /// In-sample metrics of the refit.
    pub train: Metrics,
    /// Held-out metrics of the refit.
    pub heldout: Option<Metrics>,
}

/// Table IV: the `k` least significant raw terms of the full (n, m) model (largest p-value, then
/// smallest |t|) are excluded one at a time and in pairs, and each variant is scored on `train`
/// and `heldout`.
///
/// No variant is refitted. Leaving out the raw terms S is the full model under the constraint
/// α_S = W_S c = 0 (W: Chebyshev → raw coefficients), whose least-squares solution and error follow
/// from the full model's Gram matrix G alone (restricted least squares):
/// c_S = ĉ − G⁻¹W_Sᵀ M⁻¹ W_S ĉ and SSE_S = SSE + (W_S ĉ)ᵀ M⁻¹ (W_S ĉ), with M = W_S G⁻¹ W_Sᵀ
/// (1×1 or 2×2). G comes from one pass of Chebyshev moments and is factored once (Cholesky of its
/// Jacobi-scaled form); each variant then costs O(ν²). The held-out error of c_S comes from the
/// held-out moments. The t statistics that rank the terms are those of the full fit,
/// Var(α̂_k) = σ̂² w_kᵀ G⁻¹ w_k.
pub fn prune(
    train: Xy,
    heldout: Option<Xy>,
    n: usize,
    m: usize,
    k: usize,
) -> Result<Vec<PruneRow>, PolyError> {
    train.check()?;
    if n > MAX_DEGREE || m > MAX_DEGREE {
        return Err(PolyError::Degree { n, m });
    }
    let sc = Scaling::from_data(train.v, train.vdot)?;
    let centre = train.p.iter().sum::<f64>() / train.p.len() as f64;
    let mt = Moments::gather(train, &sc, centre);
    let mh = match heldout {
        Some(h) if !h.p.is_empty() => {
            h.check()?;
            Some(Moments::gather(h, &sc, centre))
        }
        _ => None,
    };
    let full = Restricted::new(&mt, n, m, &sc, centre)?;
    let cand = full.least_significant(k);
    let mut sets: Vec<Vec<usize>> = cand.iter().map(|&a| vec![a]).collect();
    for (x, &a) in cand.iter().enumerate() {
        for &b in &cand[x + 1..] {
            sets.push(vec![a, b]);
        }
    }
    let err = |source| PolyError::Fit { n, m, source };
    sets.into_iter()
        .map(|set| {
            let (c, sse) = full.without(&set).ok_or_else(|| {
                err(FitError::RankDeficient {
                    term: set
                        .iter()
                        .map(|&t| full.name(t))
                        .collect::<Vec<_>>()
                        .join(", "),
                })
            })?;
            let nu = full.nu - set.len();
            let train = metrics::from_sse(sse, mt.sst, mt.n, nu)
                .map_err(|_| err(FitError::TooFewSamples { n: mt.n, nu }))?;
            let heldout = mh
                .as_ref()
                .and_then(|h| metrics::from_sse(h.sse(n, m, &c), h.sst, h.n, nu).ok());
            Ok(PruneRow {
                excluded: set.iter().map(|&t| full.name(t)).collect(),
                nu,
                train,
                heldout,
            })
        })
        .collect()
}

/// See [`Restricted::constraint_maps`].
pub(crate) struct ConstraintMaps {
    /// ĉ: the full fit's centred Chebyshev coefficients.
    pub c: DVector<f64>,
    /// α̂: every raw coefficient of the full fit.
    pub alpha: DVector<f64>,
    /// M = W G⁻¹ Wᵀ.
    pub m: DMatrix<f64>,
    /// Q = G⁻¹ Wᵀ.
    pub q: DMatrix<f64>,
}

/// The full (n, m) fit from moments, factored once, for restricted refits (see [`prune`] and
/// [`crate::select::reduce_terms`]).
pub(crate) struct Restricted {
    m: usize,
    nu: usize,
    /// Chebyshev coefficients of the centred pressure.
    c: DVector<f64>,
    /// SSE of the full fit.
    sse: f64,
    /// Jacobi scaling D (G = D⁻¹ Gs D⁻¹).
    d: DVector<f64>,
    /// Cholesky factor of the scaled Gram Gs = D G D.
    chol: nalgebra::Cholesky<f64, nalgebra::Dyn>,
    /// Chebyshev → raw coefficients.
    raw_of_c: DMatrix<f64>,
    /// Residual degrees of freedom of the full fit.
    dof: usize,
    /// The pressure's centring (the fit is of P − centre).
    centre: f64,
}

impl Restricted {
    pub(crate) fn new(
        mt: &Moments,
        n: usize,
        m: usize,
        sc: &Scaling,
        mt_centre: f64,
    ) -> Result<Restricted, PolyError> {
        let nu = (n + 1) * (m + 1);
        let c = solve_chebyshev(mt, n, m)?;
        let g = mt.gram(n, m);
        let d = DVector::from_fn(nu, |i, _| 1.0 / g[(i, i)].max(f64::MIN_POSITIVE).sqrt());
        let gs = DMatrix::from_fn(nu, nu, |i, j| g[(i, j)] * d[i] * d[j]);
        let chol = nalgebra::Cholesky::new(gs).ok_or(PolyError::Fit {
            n,
            m,
            source: FitError::RankDeficient {
                term: term_name(n, m),
            },
        })?;
        let (_, raw_of_c) = chebyshev_maps(n, m, sc);
        Ok(Restricted {
            centre: mt_centre,
            m,
            nu,
            sse: mt.sse(n, m, &c),
            c,
            d,
            chol,
            raw_of_c,
            dof: mt.n - nu,
        })
    }

    fn name(&self, k: usize) -> String {
        term_name(k / (self.m + 1), k % (self.m + 1))
    }

    /// What restricted fits of many term sets share: the full fit's centred Chebyshev
    /// coefficients ĉ, every raw coefficient α̂ = W(ĉ + centre·e₀), M = W G⁻¹ Wᵀ and
    /// Q = G⁻¹ Wᵀ (W: Chebyshev → raw). The fit without the raw terms S is then
    /// c_S = ĉ − Q_S λ with M_SS λ = α̂_S (see [`Restricted::without`]).
    pub(crate) fn constraint_maps(&self) -> ConstraintMaps {
        let all: Vec<usize> = (0..self.nu).collect();
        let z = self.z(&all);
        let m = z.transpose() * &z;
        // Q = D L⁻ᵀ Z, column by column.
        let mut q = z;
        for col in 0..self.nu {
            let mut column = q.column_mut(col);
            self.lt_solve(column.as_mut_slice());
            column.component_mul_assign(&self.d);
        }
        ConstraintMaps {
            c: self.c.clone(),
            alpha: DVector::from_fn(self.nu, |t, _| self.raw(t)),
            m,
            q,
        }
    }

    /// The centred coefficients and (XᵀX)⁻¹ = D Gs⁻¹ D, when κ₁(Gs) ≤ [`MAX_GRAM_CONDITION`].
    fn inverse_if_conditioned(&self) -> Option<(DVector<f64>, DMatrix<f64>)> {
        let inv = self.chol.inverse();
        let l = self.chol.l_dirty();
        // Gs = L Lᵀ (the factor's upper triangle is not cleared: only its lower one is read).
        let gs = DMatrix::from_fn(self.nu, self.nu, |i, j| {
            (0..=i.min(j)).map(|k| l[(i, k)] * l[(j, k)]).sum::<f64>()
        });
        let norm1 = |a: &DMatrix<f64>| {
            a.column_iter()
                .map(|c| c.iter().map(|x| x.abs()).sum::<f64>())
                .fold(0.0, f64::max)
        };
        let kappa = norm1(&gs) * norm1(&inv);
        (kappa.is_finite() && kappa <= MAX_GRAM_CONDITION).then(|| {
            let xtx_inv =
                DMatrix::from_fn(self.nu, self.nu, |i, j| inv[(i, j)] * self.d[i] * self.d[j]);
            (self.c.clone(), xtx_inv)
        })
    }

    /// u ← L⁻ᵀ u in place (L: the scaled Gram's Cholesky factor; back substitution).
    fn lt_solve(&self, u: &mut [f64]) {
        let l = self.chol.l_dirty();
        for i in (0..self.nu).rev() {
            let acc: f64 = (i + 1..self.nu).map(|j| l[(j, i)] * u[j]).sum();
            u[i] = (u[i] - acc) / l[(i, i)];
        }
    }

    /// Z = L⁻¹ D W_Sᵀ, so that W_S G⁻¹ W_Sᵀ = ZᵀZ.
    fn z(&self, set: &[usize]) -> DMatrix<f64> {
        let mut z = DMatrix::from_fn(self.nu, set.len(), |i, s| {
            self.raw_of_c[(set[s], i)] * self.d[i]
        });
        let l = self.chol.l_dirty();
        for col in 0..set.len() {
            for i in 0..self.nu {
                let acc: f64 = (0..i).map(|j| l[(i, j)] * z[(j, col)]).sum();
                z[(i, col)] = (z[(i, col)] - acc) / l[(i, i)];
            }
        }
        z
    }

    /// The raw terms ordered from least significant (largest p, then smallest |t|), first `k`,
    /// never all of them.
    fn least_significant(&self, k: usize) -> Vec<usize> {
        let s2 = self.sse / self.dof.max(1) as f64;
        let stats: Vec<(f64, f64)> = (0..self.nu)
            .map(|t| {
                let z = self.z(&[t]);
                let se = (s2 * z.norm_squared()).sqrt();
                let est = self.raw(t);
                let tt = if se > 0.0 {
                    est / se
                } else {
                    f64::INFINITY * est.signum()
                };
                (linreg::two_sided_p(tt, self.dof), tt.abs())
            })
            .collect();
        let mut order: Vec<usize> = (0..self.nu).collect();
        order.sort_by(|&a, &b| {
            stats[b]
                .0
                .total_cmp(&stats[a].0)
                .then(stats[a].1.total_cmp(&stats[b].1))
        });
        order.truncate(k.min(self.nu.saturating_sub(1)));
        order
    }

    /// Raw coefficient α_t of the full fit (the centring enters through the T₀T₀ column).
    fn raw(&self, t: usize) -> f64 {
        let centred: f64 = (0..self.nu)
            .map(|i| self.raw_of_c[(t, i)] * self.c[i])
            .sum();
        centred + self.centre * self.raw_of_c[(t, 0)]
    }

    /// The restricted fit without the raw terms `set`: its centred Chebyshev coefficients and its
    /// SSE. `None` when the constraints are degenerate.
    pub(crate) fn without(&self, set: &[usize]) -> Option<(DVector<f64>, f64)> {
        // The constraint is on the uncentred coefficients: W_S (ĉ + centre·e₀) = α̂_S must vanish.
        let resid = DVector::from_fn(set.len(), |s, _| self.raw(set[s]));
        let z = self.z(set);
        let mm = z.transpose() * &z;
        let lambda = mm.clone().cholesky()?.solve(&resid);
        let dsse = resid.dot(&lambda);
        // G⁻¹W_Sᵀλ = D L⁻ᵀ Z λ.
        let mut u = &z * &lambda;
        self.lt_solve(u.as_mut_slice());
        let c = DVector::from_fn(self.nu, |i, _| self.c[i] - self.d[i] * u[i]);
        Some((c, self.sse + dsse))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two incommensurate tones (so (v, v̇) fills an area) and a pressure of degree (3, 2) plus a
    /// deterministic pseudo-noise; `squeeze` < 1 crowds the flow towards one value.
    fn data(len: usize, squeeze: f64) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        let (_, v, q) = crate::test_motion::two_tones(len);
        let f: Vec<f64> = q
            .iter()
            .map(|&q| q.signum() * (q.abs() / 102.0).powf(1.0 / squeeze) * 102.0)
            .collect();
        let p: Vec<f64> = (0..len)
            .map(|k| {
                let (x, q) = (v[k] / 100.0, f[k] / 100.0);
                2.0 + 0.5 * x - 0.2 * x * x
                    + 0.03 * x * x * x
                    + 0.4 * q
                    + 0.1 * x * q * q
                    + 0.01 * (k as f64 * 12.9898).sin()
            })
            .collect();
        (v, f, p)
    }

    #[test]
    fn gram_route_equals_the_qr_fit() {
        // Identity: the moments' Cholesky and the design's Householder QR solve the same least
        // squares problem; on a well-conditioned basis they agree to far below the standard errors.
        let (v, f, p) = data(6000, 1.0);
        let xy = Xy {
            v: &v,
            vdot: &f,
            p: &p,
        };
        let sc = Scaling::from_data(&v, &f).unwrap();
        for (n, m) in [(1, 1), (3, 2), (7, 7)] {
            let g = fit(xy, n, m, Some(sc)).unwrap();
            let (c, xtx_inv, sse) = fit_qr(xy, n, m, &sc).unwrap();
            let sigma2 = sse / (p.len() - (n + 1) * (m + 1)) as f64;
            assert!((g.sigma2 - sigma2).abs() <= 1e-9 * sigma2, "({n}, {m})");
            let (_, raw_of_c) = chebyshev_maps(n, m, &sc);
            let raw = &raw_of_c * &c;
            let cov = &raw_of_c * (xtx_inv * sigma2) * raw_of_c.transpose();
            for (k, s) in g.raw.iter().enumerate() {
                let se = cov[(k, k)].sqrt();
                assert!(
                    (s.estimate - raw[k]).abs() <= 1e-8 * se,
                    "({n}, {m}) term {k}"
                );
                assert!((s.se - se).abs() <= 1e-8 * se, "({n}, {m}) term {k}");
            }
        }
    }

    #[test]
    fn an_ill_conditioned_gram_is_solved_by_qr() {
        // Flow crowded towards zero: the scaled Gram of degree 7 in v̇ is far beyond the limit,
        // so the fit is the QR's exactly.
        let (v, f, p) = data(6000, 0.15);
        let xy = Xy {
            v: &v,
            vdot: &f,
            p: &p,
        };
        let sc = Scaling::from_data(&v, &f).unwrap();
        let centre = p.iter().sum::<f64>() / p.len() as f64;
        let mt = Moments::gather(xy, &sc, centre);
        let g = Restricted::new(&mt, 3, 7, &sc, centre).unwrap();
        assert!(g.inverse_if_conditioned().is_none());
        let (c, _, sse) = fit_qr(xy, 3, 7, &sc).unwrap();
        let f = fit(xy, 3, 7, Some(sc)).unwrap();
        let (a_of_c, _) = chebyshev_maps(3, 7, &sc);
        let power: Vec<f64> = (&a_of_c * &c).iter().copied().collect();
        assert_eq!(f.power, power);
        assert_eq!(f.sigma2, sse / (p.len() - 32) as f64);
    }
}
