//! `vfp chow A.csv B.csv [C.csv …]`: are two logs described by the same polynomial? (paper
//! §IV-B, Table VI; Chow 1960).
//!
//! # The classic statistic
//! Fit the same basis (shape n, m; k = (n+1)(m+1) coefficients) to log A (N₁ samples, residual sum
//! of squares S₁), to log B (N₂, S₂) and to both pooled (Sₚ). Under H₀ "one coefficient vector
//! generated both logs" with independent, homoscedastic Gaussian errors,
//!
//! F = ((Sₚ − (S₁ + S₂)) / k) / ((S₁ + S₂) / (N₁ + N₂ − 2k)) ~ F(k, N₁ + N₂ − 2k),
//!
//! and H₀ is rejected when F exceeds the critical value F⁻¹(1 − α; k, N₁ + N₂ − 2k) (α = 0.0005
//! as in the paper). With k = 12 and large N that critical value is ≈ 2.96; the paper's 5.9
//! matches k = 3 numerator degrees of freedom.
//!
//! # Serial correlation: the verdict uses the prewhitened (feasible GLS) form by default
//! At 25 Hz the errors of a P(v, v̇) fit are serially correlated (sensor dynamics, slow drift,
//! anything the polynomial lacks). The classic F assumes independence; with positively
//! correlated errors the coefficients scatter more than σ²(XᵀX)⁻¹ says and the test rejects two
//! runs of the same actuator far more often than α (with AR(1) noise of ρ = 0.5, about 9 runs in
//! 10 at α = 0.05 in our simulation). A Newey–West (HAC) Wald version was tried first and was not
//! calibrated either: the regressors (v̇ constant over whole strokes) are so persistent that the
//! 12 × 12 long-run covariance cannot be estimated from a few cycles.
//!
//! So the errors are modelled instead. The residuals of the two separate fits (the unrestricted
//! model, valid under H₀ and H₁) are described by one autoregression eₜ = Σᵢ₌₁ᵖ φᵢ eₜ₋ᵢ + uₜ (least squares within each log, never across the
//! boundary between logs; order p ≤ `p_max` by AIC = N ln σ̂ᵤ² + 2p), and every log's regression
//! is quasi-differenced by it (Cochrane–Orcutt; feasible GLS):
//!
//! yₜ* = yₜ − Σ φᵢ yₜ₋ᵢ,  xₜ* = xₜ − Σ φᵢ xₜ₋ᵢ  (t > p, each log separately),
//!
//! whose errors uₜ are independent when the AR model is right. The classic F above on the
//! transformed data, with df (k, N₁ + N₂ − 2p − 2k), decides. With independent errors p = 0 and
//! the two coincide. (Taking φ from the pooled residual instead would let the difference between
//! the logs pass for slow correlated noise, φ → 1, and erase the power.) The classic F on the raw data is
//! reported beside it, for comparison with the paper's Table VI.
//!
//! Both logs use one basis scaled over the pooled data (sysid's Chebyshev basis, [`design`]);
//! residual sums of squares do not depend on which basis of the polynomial space is used.

use super::{DiagError, Shape};
use crate::dataset::{Dataset, LogData};
use crate::linreg;
use crate::poly::{chebyshev, Scaling, Xy, MAX_DEGREE};
use nalgebra::{DMatrix, DVector};
use serde::Serialize;
use statrs::distribution::{ContinuousCDF, FisherSnedecor};

/// Which statistic decides.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Method {
    /// Chow F after prewhitening by an AR(p) model of the residual (feasible GLS).
    Gls,
    /// Chow's original F (independent errors assumed; over-rejects on 25 Hz time series).
    Classic,
}

impl Method {
    /// Both statistics.
    pub const ALL: [Method; 2] = [Method::Gls, Method::Classic];

    /// The name used in JSON and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Method::Gls => "gls",
            Method::Classic => "classic",
        }
    }
}

/// Outcome of one Chow test.
#[derive(Clone, Debug, Serialize)]
pub struct ChowTest {
    /// The statistic the verdict uses (prewhitened or classic F, per `method`).
    pub f: f64,
    /// Numerator degrees of freedom k.
    pub df1: usize,
    /// Denominator degrees of freedom of `f`.
    pub df2: usize,
    /// p-value of `f`.
    pub p: f64,
    /// Critical value of `f` at α.
    pub critical: f64,
    /// Whether H₀ (same model) is rejected at α.
    pub reject: bool,
    /// Statistic used.
    pub method: Method,
    /// Classic Chow F on the raw data (the kind of value in the paper's Table VI).
    pub f_classic: f64,
    /// p-value of the classic F.
    pub p_classic: f64,
    /// AR coefficients φ₁..φₚ of the residual used for prewhitening (empty: none).
    pub ar: Vec<f64>,
    /// Samples in each log.
    pub samples: [usize; 2],
}

/// Design matrix of the Chebyshev product basis Tᵢ(x)Tⱼ(y) (sysid's [`crate::poly`] basis),
/// column i·(m+1)+j, under one common scaling.
pub fn design(shape: Shape, scaling: &Scaling, v: &[f64], q: &[f64]) -> DMatrix<f64> {
    let (n, m) = (shape.n, shape.m);
    let mut x = DMatrix::zeros(v.len(), shape.terms());
    let (mut tx, mut ty) = ([0.0; MAX_DEGREE + 1], [0.0; MAX_DEGREE + 1]);
    for (r, (&a, &b)) in v.iter().zip(q).enumerate() {
        let (xa, yb) = scaling.apply(a, b);
        chebyshev(xa, &mut tx[..=n]);
        chebyshev(yb, &mut ty[..=m]);
        for i in 0..=n {
            for j in 0..=m {
                x[(r, i * (m + 1) + j)] = tx[i] * ty[j];
            }
        }
    }
    x
}

fn term_names(shape: Shape) -> Vec<String> {
    (0..=shape.n)
        .flat_map(|i| (0..=shape.m).map(move |j| crate::poly::term_name(i, j)))
        .collect()
}

/// Least squares by sysid's QR ([`linreg::lstsq`]); returns (β̂, residuals in sample order).
fn ols(x: &DMatrix<f64>, y: &[f64], names: &[String]) -> Result<(DVector<f64>, Vec<f64>), String> {
    let lf = linreg::lstsq(x.clone(), y, names).map_err(|e| e.to_string())?;
    let coef = DVector::from_vec(lf.coef);
    let fitted = x * &coef;
    Ok((
        coef,
        y.iter().zip(fitted.iter()).map(|(a, b)| a - b).collect(),
    ))
}

fn rss(x: &DMatrix<f64>, y: &[f64], names: &[String]) -> Result<f64, String> {
    Ok(ols(x, y, names)?.1.iter().map(|e| e * e).sum())
}

/// AR(p) of several residual series by least squares (lags never cross from one series into
/// another), with the order chosen by AIC among 0..=`p_max` on a common sample (t > p_max);
/// `Some(p)` forces the order. Returns φ₁..φₚ.
pub fn fit_ar(series: &[&[f64]], p_max: usize, forced: Option<usize>) -> Vec<f64> {
    let fit = |p: usize, start: usize| -> Option<(Vec<f64>, f64, usize)> {
        let rows: usize = series.iter().map(|s| s.len().saturating_sub(start)).sum();
        if rows <= p + 2 {
            return None;
        }
        if p == 0 {
            let ss: f64 = series
                .iter()
                .flat_map(|s| s.iter().skip(start))
                .map(|e| e * e)
                .sum();
            return Some((Vec::new(), ss / rows as f64, rows));
        }
        let mut x = DMatrix::zeros(rows, p);
        let mut y = Vec::with_capacity(rows);
        let mut r = 0;
        for s in series {
            for t in start..s.len() {
                for i in 0..p {
                    x[(r, i)] = s[t - 1 - i];
                }
                y.push(s[t]);
                r += 1;
            }
        }
        let lf = linreg::lstsq(x, &y, &[]).ok()?;
        Some((lf.coef, lf.sse / rows as f64, rows))
    };
    if let Some(p) = forced {
        return fit(p, p).map(|f| f.0).unwrap_or_default();
    }
    let mut best: Option<(f64, Vec<f64>)> = None;
    for p in 0..=p_max {
        if let Some((phi, s2, rows)) = fit(p, p_max) {
            let aic = rows as f64 * s2.max(f64::MIN_POSITIVE).ln() + 2.0 * p as f64;
            if best.as_ref().is_none_or(|b| aic < b.0) {
                best = Some((aic, phi));
            }
        }
    }
    // Re-estimate the chosen order on all usable samples.
    let p = best.map(|b| b.1.len()).unwrap_or(0);
    fit(p, p).map(|f| f.0).unwrap_or_default()
}

/// Quasi-differences rows t ≥ p: yₜ − Σ φᵢ yₜ₋ᵢ and the same for every column of x.
pub fn whiten(x: &DMatrix<f64>, y: &[f64], phi: &[f64]) -> (DMatrix<f64>, Vec<f64>) {
    let p = phi.len();
    let n = y.len().saturating_sub(p);
    let mut xs = DMatrix::zeros(n, x.ncols());
    let mut ys = vec![0.0; n];
    for r in 0..n {
        let t = r + p;
        ys[r] = y[t]
            - phi
                .iter()
                .enumerate()
                .map(|(i, f)| f * y[t - 1 - i])
                .sum::<f64>();
        for c in 0..x.ncols() {
            xs[(r, c)] = x[(t, c)]
                - phi
                    .iter()
                    .enumerate()
                    .map(|(i, f)| f * x[(t - 1 - i, c)])
                    .sum::<f64>();
        }
    }
    (xs, ys)
}

/// Classic Chow F of two designs: (F, df2).
fn chow_f(
    xa: &DMatrix<f64>,
    ya: &[f64],
    xb: &DMatrix<f64>,
    yb: &[f64],
    names: &[String],
) -> Result<(f64, usize), ChowError> {
    let k = xa.ncols();
    let sa = rss(xa, ya, names).map_err(|e| ChowError::Fit(0, e))?;
    let sb = rss(xb, yb, names).map_err(|e| ChowError::Fit(1, e))?;
    let (na, nb) = (ya.len(), yb.len());
    let mut xp = DMatrix::zeros(na + nb, k);
    xp.rows_mut(0, na).copy_from(xa);
    xp.rows_mut(na, nb).copy_from(xb);
    let yp: Vec<f64> = ya.iter().chain(yb).copied().collect();
    let sp = rss(&xp, &yp, names).map_err(|e| ChowError::Fit(2, e))?;
    let df2 = (na + nb)
        .checked_sub(2 * k)
        .filter(|&d| d > 0)
        .ok_or(ChowError::Degenerate)?;
    let s_sep = sa + sb;
    Ok((
        ((sp - s_sep).max(0.0) / k as f64) / (s_sep / df2 as f64),
        df2,
    ))
}

/// Options of [`chow`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChowOptions {
    /// Common polynomial shape.
    pub shape: Shape,
    /// Significance level.
    pub alpha: f64,
    /// Statistic of the verdict.
    pub method: Method,
    /// Highest AR order considered for prewhitening.
    pub ar_max: usize,
    /// Force this AR order instead of choosing by AIC.
    pub ar_order: Option<usize>,
}

impl Default for ChowOptions {
    fn default() -> Self {
        ChowOptions {
            shape: Shape::PAPER,
            alpha: 0.0005,
            method: Method::Gls,
            ar_max: 10,
            ar_order: None,
        }
    }
}

/// Chow test of H₀ "a and b follow one polynomial" (module docs).
pub fn chow(a: Xy<'_>, b: Xy<'_>, o: &ChowOptions) -> Result<ChowTest, ChowError> {
    let shape = o.shape;
    let names = term_names(shape);
    let pv: Vec<f64> = a.v.iter().chain(b.v).copied().collect();
    let pq: Vec<f64> = a.vdot.iter().chain(b.vdot).copied().collect();
    let scaling = Scaling::from_data(&pv, &pq).map_err(|e| ChowError::Fit(2, e.to_string()))?;
    let k = shape.terms();
    let xa = design(shape, &scaling, a.v, a.vdot);
    let xb = design(shape, &scaling, b.v, b.vdot);
    let (f_classic, df2_classic) = chow_f(&xa, a.p, &xb, b.p, &names)?;
    let dist =
        |df2: usize| FisherSnedecor::new(k as f64, df2 as f64).map_err(|_| ChowError::Degenerate);
    let p_classic = dist(df2_classic)?.sf(f_classic);

    let (f, df2, ar) = match o.method {
        Method::Classic => (f_classic, df2_classic, Vec::new()),
        Method::Gls => {
            // The error model comes from each log's own fit (valid under H₀ and H₁ alike; the
            // pooled residual would carry the difference between the logs into φ).
            let (_, ea) = ols(&xa, a.p, &names).map_err(|e| ChowError::Fit(0, e))?;
            let (_, eb) = ols(&xb, b.p, &names).map_err(|e| ChowError::Fit(1, e))?;
            let phi = fit_ar(&[&ea, &eb], o.ar_max, o.ar_order);
            let (wa, ya) = whiten(&xa, a.p, &phi);
            let (wb, yb) = whiten(&xb, b.p, &phi);
            let (f, df2) = chow_f(&wa, &ya, &wb, &yb, &names)?;
            (f, df2, phi)
        }
    };
    let d = dist(df2)?;
    let critical = d.inverse_cdf(1.0 - o.alpha);
    Ok(ChowTest {
        f,
        df1: k,
        df2,
        p: d.sf(f),
        critical,
        reject: f > critical,
        method: o.method,
        f_classic,
        p_classic,
        ar,
        samples: [a.p.len(), b.p.len()],
    })
}

/// Why a Chow test could not be computed.
#[derive(Clone, Debug, PartialEq)]
pub enum ChowError {
    /// Fit 0 (first log), 1 (second) or 2 (pooled) is not determined by its data.
    Fit(usize, String),
    /// Degrees of freedom or covariance are degenerate (too few samples).
    Degenerate,
}

/// One pair in the JSON report.
#[derive(Debug, Serialize)]
pub struct Pair {
    /// First log.
    pub a: String,
    /// Second log.
    pub b: String,
    /// The test.
    #[serde(flatten)]
    pub test: ChowTest,
}

/// The report of `vfp chow` (its `--json` document).
#[derive(Debug, Serialize)]
pub struct ChowReport {
    /// Common shape.
    pub shape: Shape,
    /// Significance level.
    pub alpha: f64,
    /// Statistic of the verdict.
    pub method: Method,
    /// The logs in command-line order.
    pub logs: Vec<String>,
    /// Every pair i < j.
    pub pairs: Vec<Pair>,
    /// Table VI: `matrix[i][j]` is the deciding F of logs i and j (null on the diagonal).
    pub matrix: Vec<Vec<Option<f64>>>,
}

/// Pairwise Chow tests between the first chamber of each log (the one it was read with, else the
/// lowest), every pair i < j, with Table VI's matrix of deciding F values.
pub fn chow_logs(logs: &[LogData], o: &ChowOptions) -> Result<ChowReport, DiagError> {
    let names: Vec<String> = logs.iter().map(LogData::name).collect();
    let series: Vec<&Dataset> = logs.iter().map(LogData::first).collect();
    let mut pairs = Vec::new();
    let mut matrix = vec![vec![None; logs.len()]; logs.len()];
    for i in 0..logs.len() {
        for j in i + 1..logs.len() {
            let test = chow(series[i].into(), series[j].into(), o).map_err(|e| match e {
                ChowError::Fit(w, msg) => {
                    let what = match w {
                        0 => format!("{} (chamber {})", names[i], series[i].chamber),
                        1 => format!("{} (chamber {})", names[j], series[j].chamber),
                        _ => format!("pooled {} + {}", names[i], names[j]),
                    };
                    DiagError::fit(what, msg)
                }
                ChowError::Degenerate => DiagError::fit(
                    format!("{} vs {}", names[i], names[j]),
                    "too few samples for the degrees of freedom of the test",
                ),
            })?;
            matrix[i][j] = Some(test.f);
            matrix[j][i] = Some(test.f);
            pairs.push(Pair {
                a: names[i].clone(),
                b: names[j].clone(),
                test,
            });
        }
    }
    Ok(ChowReport {
        shape: o.shape,
        alpha: o.alpha,
        method: o.method,
        logs: names,
        pairs,
        matrix,
    })
}
