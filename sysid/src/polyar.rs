//! The polynomial model with linear autoregressive input terms (paper Table II):
//! P̂(t) = Σᵢⱼ αᵢⱼ vⁱ(t) v̇ʲ(t) + Σₖ₌₁ᵖ (βₖ₁ v(t − kΔt) + βₖ₂ v̇(t − kΔt)).
//!
//! The lagged terms are on the inputs only, so a one-step-ahead prediction and a free-run
//! simulation are the same computation: no past *pressure* is fed back. Reports say so instead
//! of printing two identical columns.
//!
//! All orders p = 0..=p_max are fitted on the same rows (samples with p_max predecessors) so they
//! are nested and comparable, from one Householder QR of the p_max design whose columns are
//! ordered [Tᵢ(x)Tⱼ(y) …, x(t−1), y(t−1), …, x(t−p_max), y(t−p_max)]: order p is the column
//! prefix of length (n+1)(m+1) + 2p ([`crate::linreg::lstsq_prefixes`]). x and y use the same
//! scaling as [`crate::poly`], so the β's are per unit of the scaled inputs; [`PolyArFit::beta_raw`]
//! converts them to mm³ and mm³/s.

use crate::dataset::Dataset;
use crate::linreg::{self, FitError};
use crate::metrics::{self, Metrics};
use crate::poly::{chebyshev, PolyError, Scaling, MAX_DEGREE};
use nalgebra::DMatrix;

/// One fitted autoregressive order.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PolyArFit {
    /// Highest power of v.
    pub n: usize,
    /// Highest power of v̇.
    pub m: usize,
    /// Autoregressive order p.
    pub p: usize,
    /// Parameters (n+1)(m+1) + 2p.
    pub nu: usize,
    /// Coefficients in column order (Chebyshev terms, then lag pairs).
    pub coef: Vec<f64>,
    /// Scaling of v and v̇.
    pub scaling: Scaling,
    /// In-sample metrics (direct residuals; one-step = free-run).
    pub train: Metrics,
    /// Held-out metrics, if there is a held-out set.
    pub heldout: Option<Metrics>,
}

impl PolyArFit {
    /// Polynomial part in the scaled power basis aᵢⱼ xⁱyʲ (index i·(m+1)+j).
    pub fn power(&self) -> Vec<f64> {
        crate::poly::chebyshev_to_power_2d(
            &self.coef[..(self.n + 1) * (self.m + 1)],
            self.n,
            self.m,
        )
    }

    /// Scaled AR pairs [b_k1, b_k2] on the affinely scaled past inputs x(t−k), y(t−k).
    pub fn ar_scaled(&self) -> Vec<[f64; 2]> {
        let base = (self.n + 1) * (self.m + 1);
        (0..self.p)
            .map(|k| [self.coef[base + 2 * k], self.coef[base + 2 * k + 1]])
            .collect()
    }

    /// The model as the device stores it (same scaled basis; model-core's AR terms are on the
    /// affinely scaled past inputs too).
    pub fn to_model_core(&self) -> Result<model_core::poly::PolyModel, model_core::ModelError> {
        crate::poly::to_model_core(
            self.n,
            self.m,
            &self.power(),
            &self.ar_scaled(),
            &self.scaling,
        )
    }

    /// β per lag in raw units: (β_k1 per mm³, β_k2 per mm³/s), k = 1..=p.
    pub fn beta_raw(&self) -> Vec<(f64, f64)> {
        let base = (self.n + 1) * (self.m + 1);
        (0..self.p)
            .map(|k| {
                (
                    self.coef[base + 2 * k] / self.scaling.v_scale,
                    self.coef[base + 2 * k + 1] / self.scaling.f_scale,
                )
            })
            .collect()
    }
}

fn design_row(ds: &Dataset, sc: &Scaling, n: usize, m: usize, p: usize, i: usize, row: &mut [f64]) {
    let mut tx = [0.0; MAX_DEGREE + 1];
    let mut ty = [0.0; MAX_DEGREE + 1];
    let (x, y) = sc.apply(ds.v[i], ds.vdot[i]);
    chebyshev(x, &mut tx[..=n]);
    chebyshev(y, &mut ty[..=m]);
    let mut c = 0;
    for a in &tx[..=n] {
        for b in &ty[..=m] {
            row[c] = a * b;
            c += 1;
        }
    }
    for k in 1..=p {
        let (xl, yl) = sc.apply(ds.v[i - k], ds.vdot[i - k]);
        row[c] = xl;
        row[c + 1] = yl;
        c += 2;
    }
}

/// Names of the design's `width` columns: the `base` Chebyshev products of the (·, m) polynomial,
/// then v(t−k), v̇(t−k) for k = 1, 2, ….
fn column_names(m: usize, base: usize, width: usize) -> Vec<String> {
    (0..width)
        .map(|c| {
            if c < base {
                format!("T{}(x)T{}(y)", c / (m + 1), c % (m + 1))
            } else {
                let k = (c - base) / 2 + 1;
                if (c - base).is_multiple_of(2) {
                    format!("v(t-{k})")
                } else {
                    format!("vdot(t-{k})")
                }
            }
        })
        .collect()
}

/// Fits orders p = 0..=p_max of the (n, m) polynomial with AR inputs on the dataset's training
/// rows and scores each on its held-out rows.
/// The outer error concerns the data as a whole; an order whose lag columns are not identifiable
/// (e.g. constant-rate ramps make v(t−k) an exact combination of v(t) and v̇(t)) is an inner error.
#[allow(clippy::type_complexity)]
pub fn sweep(
    ds: &Dataset,
    n: usize,
    m: usize,
    p_max: usize,
    scaling: &Scaling,
) -> Result<Vec<Result<PolyArFit, PolyError>>, PolyError> {
    if n > MAX_DEGREE || m > MAX_DEGREE {
        return Err(PolyError::Degree { n, m });
    }
    let base = (n + 1) * (m + 1);
    let width = base + 2 * p_max;
    let rows_of = |held: bool| {
        (p_max..ds.len())
            .filter(|&i| ds.heldout[i] == held)
            .collect::<Vec<_>>()
    };
    let (train_rows, held_rows) = (rows_of(false), rows_of(true));
    let build = |rows: &[usize]| {
        let mut x = DMatrix::zeros(rows.len(), width);
        let mut row = vec![0.0; width];
        for (r, &i) in rows.iter().enumerate() {
            design_row(ds, scaling, n, m, p_max, i, &mut row);
            for (c, v) in row.iter().enumerate() {
                x[(r, c)] = *v;
            }
        }
        x
    };
    let x = build(&train_rows);
    let y: Vec<f64> = train_rows.iter().map(|&i| ds.p[i]).collect();
    let names = column_names(m, base, width);
    let prefixes: Vec<usize> = (0..=p_max).map(|p| base + 2 * p).collect();
    let fits = linreg::lstsq_prefixes(x.clone(), &y, &names, &prefixes)
        .map_err(|source| PolyError::Fit { n, m, source })?;
    let xh = build(&held_rows);
    let yh: Vec<f64> = held_rows.iter().map(|&i| ds.p[i]).collect();
    Ok(fits
        .into_iter()
        .enumerate()
        .map(|(p, lf)| {
            let lf = lf.map_err(|source| PolyError::Fit { n, m, source })?;
            let q = lf.coef.len();
            let predict = |x: &DMatrix<f64>| -> Vec<f64> {
                (0..x.nrows())
                    .map(|r| (0..q).map(|c| x[(r, c)] * lf.coef[c]).sum())
                    .collect()
            };
            let err = |_| PolyError::Fit {
                n,
                m,
                source: FitError::TooFewSamples { n: y.len(), nu: q },
            };
            let train = metrics::compute(&y, &predict(&x), q).map_err(err)?;
            let heldout = if yh.is_empty() {
                None
            } else {
                metrics::compute(&yh, &predict(&xh), q).ok()
            };
            Ok(PolyArFit {
                n,
                m,
                p,
                nu: q,
                coef: lf.coef,
                scaling: *scaling,
                train,
                heldout,
            })
        })
        .collect())
}
