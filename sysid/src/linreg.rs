//! Linear least squares with coefficient statistics, by Householder QR (never normal equations).
//!
//! For a design X (N × ν, full column rank) and y: X = QR, β̂ = R⁻¹(Qᵀy)[..ν],
//! SSE = Σ_{i>ν} (Qᵀy)ᵢ² (no cancellation), σ̂² = SSE/(N − ν), Cov(β̂) = σ̂² R⁻¹R⁻ᵀ = σ̂²(XᵀX)⁻¹,
//! tⱼ = β̂ⱼ / SE(β̂ⱼ) and the two-sided p-value 2·(1 − F_t(|tⱼ|; N − ν)).
//!
//! Columns are equilibrated to unit norm before the factorisation and unscaled after it, so the
//! rank test (|Rⱼⱼ| small against the largest) does not depend on units.
//!
//! Nested prefixes come for free: for the first q columns, β̂ solves R[..q, ..q] β = (Qᵀy)[..q]
//! and SSE_q = SSE + Σ_{q≤i<ν} (Qᵀy)ᵢ². [`lstsq_prefixes`] uses this to fit a whole chain of
//! nested models (e.g. autoregressive orders p = 0..5) with one factorisation.

use nalgebra::{DMatrix, DVector};
use statrs::distribution::{ContinuousCDF, StudentsT};

/// Relative size of a pivot |Rⱼⱼ| (after equilibration) below which a column counts as
/// linearly dependent on the previous ones.
pub const RANK_TOL: f64 = 1e-10;

/// Why a linear fit failed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FitError {
    /// Fewer samples than parameters + 2 (no degrees of freedom left for σ̂² and AICc).
    #[error("{n} samples are too few for {nu} parameters (need at least {})", nu + 2)]
    TooFewSamples {
        /// N.
        n: usize,
        /// ν.
        nu: usize,
    },
    /// A column is (numerically) a combination of earlier ones.
    #[error("term `{term}` is not identifiable from these data (linearly dependent on the earlier terms)")]
    RankDeficient {
        /// Name of the offending term.
        term: String,
    },
    /// A value is NaN or infinite.
    #[error("non-finite value in {what} at sample {index}")]
    NotFinite {
        /// "design matrix" or "response".
        what: &'static str,
        /// Row.
        index: usize,
    },
}

/// A fitted linear model with statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearFit {
    /// β̂.
    pub coef: Vec<f64>,
    /// (XᵀX)⁻¹ (multiply by σ̂² for the covariance).
    pub xtx_inv: DMatrix<f64>,
    /// Residual sum of squares.
    pub sse: f64,
    /// Samples N.
    pub n: usize,
}

impl LinearFit {
    /// Parameters ν.
    pub fn nu(&self) -> usize {
        self.coef.len()
    }
    /// Residual degrees of freedom N − ν.
    pub fn dof(&self) -> usize {
        self.n - self.nu()
    }
    /// σ̂² = SSE / (N − ν).
    pub fn sigma2(&self) -> f64 {
        self.sse / self.dof() as f64
    }
    /// Covariance of β̂.
    pub fn cov(&self) -> DMatrix<f64> {
        &self.xtx_inv * self.sigma2()
    }
    /// Standard errors.
    pub fn se(&self) -> Vec<f64> {
        let s2 = self.sigma2();
        (0..self.nu())
            .map(|i| (self.xtx_inv[(i, i)] * s2).sqrt())
            .collect()
    }
}

/// Coefficient statistics for reporting: estimate, standard error, t and two-sided p-value.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct CoefStat {
    /// Estimate.
    pub estimate: f64,
    /// Standard error.
    pub se: f64,
    /// t = estimate / se.
    pub t: f64,
    /// Two-sided p-value under H₀: coefficient = 0.
    pub p: f64,
}

/// Statistics from estimates and their covariance with `dof` residual degrees of freedom.
pub fn coef_stats(coef: &[f64], cov: &DMatrix<f64>, dof: usize) -> Vec<CoefStat> {
    coef.iter()
        .enumerate()
        .map(|(i, &estimate)| {
            let se = cov[(i, i)].max(0.0).sqrt();
            let t = if se > 0.0 {
                estimate / se
            } else {
                f64::INFINITY * estimate.signum()
            };
            CoefStat {
                estimate,
                se,
                t,
                p: two_sided_p(t, dof),
            }
        })
        .collect()
}

/// Two-sided p-value of a t statistic with `dof` degrees of freedom.
pub fn two_sided_p(t: f64, dof: usize) -> f64 {
    if !t.is_finite() {
        return if t.is_nan() { f64::NAN } else { 0.0 };
    }
    match StudentsT::new(0.0, 1.0, dof.max(1) as f64) {
        Ok(d) => (2.0 * d.sf(t.abs())).min(1.0),
        Err(_) => f64::NAN,
    }
}

/// Least squares for the full design. `names` label the columns in errors.
pub fn lstsq(x: DMatrix<f64>, y: &[f64], names: &[String]) -> Result<LinearFit, FitError> {
    let nu = x.ncols();
    let mut fits = lstsq_prefixes(x, y, names, &[nu])?;
    fits.pop().expect("one prefix requested")
}

/// Scales every column of `x` to unit norm (a zero column stays zero) and returns the factors;
/// an error names the first non-finite entry.
fn unit_columns(x: &mut DMatrix<f64>) -> Result<Vec<f64>, FitError> {
    let mut scale = vec![0.0; x.ncols()];
    for (j, s) in scale.iter_mut().enumerate() {
        let col = x.column(j);
        if let Some(index) = col.iter().position(|v| !v.is_finite()) {
            return Err(FitError::NotFinite {
                what: "design matrix",
                index,
            });
        }
        let norm = col.norm();
        *s = if norm > 0.0 { 1.0 / norm } else { 0.0 };
    }
    for (j, &s) in scale.iter().enumerate() {
        if s != 0.0 {
            x.column_mut(j).scale_mut(s);
        }
    }
    Ok(scale)
}

/// Least squares for each column prefix `x[.., ..q]`, q in `prefixes`, from one QR of `x`.
/// The outer error concerns the data as a whole; a prefix that reaches a dependent column is an
/// inner error while the shorter prefixes still fit.
#[allow(clippy::type_complexity)]
pub fn lstsq_prefixes(
    mut x: DMatrix<f64>,
    y: &[f64],
    names: &[String],
    prefixes: &[usize],
) -> Result<Vec<Result<LinearFit, FitError>>, FitError> {
    let (n, nu) = x.shape();
    assert_eq!(y.len(), n, "design rows and response length differ");
    assert!(
        prefixes.iter().all(|&q| q <= nu),
        "prefix longer than the design"
    );
    if n < nu + 2 {
        return Err(FitError::TooFewSamples { n, nu });
    }
    if let Some(index) = y.iter().position(|v| !v.is_finite()) {
        return Err(FitError::NotFinite {
            what: "response",
            index,
        });
    }
    let scale = unit_columns(&mut x)?;
    let qr = x.qr();
    let r = qr.r();
    // Columns have unit norm, so |Rⱼⱼ| is the part of column j not explained by columns < j.
    let first_bad = (0..nu)
        .find(|&j| scale[j] == 0.0 || r[(j, j)].abs() <= RANK_TOL)
        .unwrap_or(nu);
    let mut qty = DVector::from_column_slice(y);
    qr.q_tr_mul(&mut qty);
    let tail: f64 = qty.rows(nu, n - nu).norm_squared();
    let fits = prefixes
        .iter()
        .map(|&q| {
            if n < q + 2 {
                return Err(FitError::TooFewSamples { n, nu: q });
            }
            if q > first_bad {
                return Err(FitError::RankDeficient {
                    term: name(names, first_bad),
                });
            }
            let rq = r.view((0, 0), (q, q)).into_owned();
            let rinv = rq
                .clone()
                .solve_upper_triangular(&DMatrix::identity(q, q))
                .ok_or_else(|| FitError::RankDeficient {
                    term: name(names, q.saturating_sub(1)),
                })?;
            let b = rinv.clone() * qty.rows(0, q);
            let sse = tail + qty.rows(q, nu - q).norm_squared();
            let mut xtx_inv = &rinv * rinv.transpose();
            let coef: Vec<f64> = (0..q).map(|j| b[j] * scale[j]).collect();
            for i in 0..q {
                for j in 0..q {
                    xtx_inv[(i, j)] *= scale[i] * scale[j];
                }
            }
            Ok(LinearFit {
                coef,
                xtx_inv,
                sse,
                n,
            })
        })
        .collect();
    Ok(fits)
}

fn name(names: &[String], j: usize) -> String {
    names
        .get(j)
        .cloned()
        .unwrap_or_else(|| format!("column {j}"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn straight_line_known_answer() {
        // y = 1 + 2x exactly at x = 0..4 plus ±0.1 alternating: the textbook values follow.
        let xs = [0.0, 1.0, 2.0, 3.0, 4.0];
        let e = [0.1, -0.1, 0.1, -0.1, 0.1];
        let y: Vec<f64> = xs.iter().zip(e).map(|(x, e)| 1.0 + 2.0 * x + e).collect();
        let x = DMatrix::from_fn(5, 2, |i, j| if j == 0 { 1.0 } else { xs[i] });
        let f = lstsq(x, &y, &[]).unwrap();
        // By hand: x̄ = 2, Sxx = 10, Sxy = Σ(x−x̄)e = -0.2+0.1+0+(-0.1)+0.2 = 0 → slope 2.
        assert!((f.coef[1] - 2.0).abs() < 1e-12);
        // intercept = ȳ − 2x̄ = 1 + mean(e) = 1.02.
        assert!((f.coef[0] - 1.02).abs() < 1e-12);
        // SSE = Σ(e − ē)² = 3·0.08² + 2·0.12² = 0.048.
        assert!((f.sse - 0.048).abs() < 1e-12);
        // Var(slope) = σ̂²/Sxx = (0.048/3)/10.
        assert!((f.se()[1] - (0.0016f64).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn prefixes_match_separate_fits() {
        let n = 50;
        let t: Vec<f64> = (0..n).map(|i| i as f64 / n as f64).collect();
        let y: Vec<f64> = t
            .iter()
            .map(|t| (3.0 * t).sin() + 0.01 * (17.0 * t).cos())
            .collect();
        let x = DMatrix::from_fn(n, 4, |i, j| t[i].powi(j as i32));
        let all: Vec<LinearFit> = lstsq_prefixes(x.clone(), &y, &[], &[2, 3, 4])
            .unwrap()
            .into_iter()
            .map(Result::unwrap)
            .collect();
        for (k, q) in [2, 3, 4].into_iter().enumerate() {
            let alone = lstsq(x.columns(0, q).into_owned(), &y, &[]).unwrap();
            for j in 0..q {
                assert!((all[k].coef[j] - alone.coef[j]).abs() < 1e-9);
            }
            assert!((all[k].sse - alone.sse).abs() < 1e-12);
        }
        assert!(all[0].sse >= all[1].sse && all[1].sse >= all[2].sse);
    }

    #[test]
    fn dependent_column_is_named() {
        let x = DMatrix::from_fn(10, 3, |i, j| {
            if j == 2 {
                2.0 * i as f64
            } else {
                (i as f64).powi(j as i32)
            }
        });
        let names: Vec<String> = ["1", "x", "2x"].iter().map(|s| s.to_string()).collect();
        let y: Vec<f64> = (0..10).map(|i| i as f64).collect();
        assert_eq!(
            lstsq(x, &y, &names),
            Err(FitError::RankDeficient { term: "2x".into() })
        );
    }

    #[test]
    fn p_values_match_tables() {
        // t = 2.228 with 10 dof is the two-sided 5 % critical value (standard t table).
        assert!((two_sided_p(2.228, 10) - 0.05).abs() < 1e-3);
        assert!((two_sided_p(0.0, 5) - 1.0).abs() < 1e-12);
    }
}
