//! Pointwise stiffness and damping of the identified polynomial (`vfp stiffness`; paper
//! §IV-A, eq. 13, Fig. 7c–d).
//!
//! With P̂(v, v̇) = Σᵢ Σⱼ αᵢⱼ vⁱ v̇ʲ fitted to the log (least squares over all its samples, one
//! chamber), every sample gets
//!
//! kᵢ = ∂P̂/∂v |₍vᵢ, v̇ᵢ₎ (kPa/mm³, stiffness) and cᵢ = ∂P̂/∂v̇ |₍vᵢ, v̇ᵢ₎ (kPa·s/mm³, damping),
//!
//! and k̄ = (1/N) Σ kᵢ, c̄ = (1/N) Σ cᵢ over all N samples. The inflation means take only
//! samples with v̇ > +δ, the deflation means only v̇ < −δ, where the dead band δ keeps samples at
//! rest, whose flow sign is noise, out of both phases; they still count in the overall means, as
//! in the paper.
//!
//! δ is the dataset's phase deadband ([`Dataset::deadband`]), the one that also segments the
//! log into inflation and deflation cycles: `--deadband` when given, else 5 % of the 95th
//! percentile of |v̇| per chamber ([`crate::dataset`]). One threshold for one concept, and it
//! scales with the log: the simulated rig's 20–100 mm³/s strokes give δ ≈ 5 mm³/s, the
//! ventilator logs' ±10⁵ mm³/s breaths δ in the thousands, where a fixed 2 mm³/s (the former
//! default here, two 0.04 mm³ steps per 25 Hz frame) would have counted every noisy sample at
//! rest as inflating or deflating.

use super::{DiagError, Shape};
use crate::dataset::{Dataset, LogData};
use crate::poly::{self, PolyFit, Xy};
use serde::Serialize;

/// Mean stiffness and damping over a set of samples.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Means {
    /// k̄ (kPa/mm³); `None` when the set is empty.
    pub k_mean: Option<f64>,
    /// c̄ (kPa·s/mm³); `None` when the set is empty.
    pub c_mean: Option<f64>,
    /// Number of samples in the set.
    pub samples: usize,
}

impl Means {
    fn of(k: &[f64], c: &[f64], keep: impl Fn(usize) -> bool) -> Means {
        let (mut sk, mut sc, mut n) = (0.0, 0.0, 0usize);
        for i in (0..k.len()).filter(|&i| keep(i)) {
            sk += k[i];
            sc += c[i];
            n += 1;
        }
        let mean = |s: f64| (n > 0).then(|| s / n as f64);
        Means {
            k_mean: mean(sk),
            c_mean: mean(sc),
            samples: n,
        }
    }
}

/// Pointwise kᵢ, cᵢ of one fitted model over one set of samples.
#[derive(Clone, Debug)]
pub struct Pointwise {
    /// kᵢ = ∂P̂/∂v at each sample.
    pub k: Vec<f64>,
    /// cᵢ = ∂P̂/∂v̇ at each sample.
    pub c: Vec<f64>,
}

/// Evaluates the partials of `fit` at every (vᵢ, v̇ᵢ).
pub fn pointwise(fit: &PolyFit, v: &[f64], q: &[f64]) -> Pointwise {
    let (k, c) = v.iter().zip(q).map(|(&a, &b)| fit.partials(a, b)).unzip();
    Pointwise { k, c }
}

/// Overall and per-phase means of one chamber.
#[derive(Clone, Debug, Serialize)]
pub struct Summary {
    /// Chamber index.
    pub chamber: u8,
    /// k̄ over all samples (kPa/mm³).
    pub k_mean: f64,
    /// c̄ over all samples (kPa·s/mm³).
    pub c_mean: f64,
    /// Samples with v̇ > dead band.
    pub inflation: Means,
    /// Samples with v̇ < −dead band.
    pub deflation: Means,
    /// All samples.
    pub samples: usize,
    /// Samples within the dead band (in the overall means only).
    pub rest_samples: usize,
    /// The dead band δ on |v̇| of the phase split (mm³/s).
    pub deadband_mm3_s: f64,
    /// In-sample RMSE of the fitted polynomial (kPa).
    pub fit_rmse_kpa: f64,
}

/// Splits samples by flow sign with dead band `deadband` and averages k and c (module docs).
pub fn summarize(chamber: u8, pw: &Pointwise, q: &[f64], deadband: f64, fit_rmse: f64) -> Summary {
    let all = Means::of(&pw.k, &pw.c, |_| true);
    let inflation = Means::of(&pw.k, &pw.c, |i| q[i] > deadband);
    let deflation = Means::of(&pw.k, &pw.c, |i| q[i] < -deadband);
    Summary {
        chamber,
        k_mean: all.k_mean.unwrap_or(f64::NAN),
        c_mean: all.c_mean.unwrap_or(f64::NAN),
        rest_samples: all.samples - inflation.samples - deflation.samples,
        deadband_mm3_s: deadband,
        inflation,
        deflation,
        samples: all.samples,
        fit_rmse_kpa: fit_rmse,
    }
}

/// Fit, pointwise partials and summary of one chamber's series.
#[derive(Clone, Debug)]
pub struct ChamberStiffness {
    /// The fitted model.
    pub fit: PolyFit,
    /// kᵢ, cᵢ at every sample.
    pub pointwise: Pointwise,
    /// Means.
    pub summary: Summary,
}

/// Fits the polynomial of `shape` to one chamber and evaluates its partials at every sample.
pub fn analyze(
    context: &str,
    chamber: u8,
    s: &Dataset,
    shape: Shape,
) -> Result<ChamberStiffness, DiagError> {
    let fit = poly::fit(
        Xy {
            v: &s.v,
            vdot: &s.vdot,
            p: &s.p,
        },
        shape.n,
        shape.m,
        None,
    )
    .map_err(|e| DiagError::fit(format!("{context}, chamber {chamber}"), e.to_string()))?;
    let pw = pointwise(&fit, &s.v, &s.vdot);
    let summary = summarize(chamber, &pw, &s.vdot, s.deadband, fit.train.rmse);
    Ok(ChamberStiffness {
        fit,
        pointwise: pw,
        summary,
    })
}

/// Analyses every chamber of `data` (the chambers it was read with), in chamber order.
pub fn analyze_log(data: &LogData, shape: Shape) -> Result<Vec<ChamberStiffness>, DiagError> {
    let ctx = data.name();
    data.datasets
        .iter()
        .map(|ds| analyze(&ctx, ds.chamber, ds, shape))
        .collect()
}

/// The report of `vfp stiffness --json`: the first analysed chamber at the top level, all
/// chambers in `chambers`.
#[derive(Debug, Serialize)]
pub struct StiffnessReport {
    /// The log.
    pub log: String,
    /// Polynomial shape.
    pub shape: Shape,
    /// Whether v̇ was derived from volume and time.
    pub flow_derived: bool,
    /// Units of the numbers.
    pub units: Units,
    /// First analysed chamber (the one chosen with --chamber, else the lowest).
    #[serde(flatten)]
    pub first: Summary,
    /// Every analysed chamber.
    pub chambers: Vec<Summary>,
}

/// Units of the stiffness report.
#[derive(Debug, Serialize)]
pub struct Units {
    /// Unit of k.
    pub k: &'static str,
    /// Unit of c.
    pub c: &'static str,
}

/// The units of k and c in every report.
pub const UNITS: Units = Units {
    k: "kPa/mm^3",
    c: "kPa*s/mm^3",
};

/// Stiffness and damping of every chamber of `data`: the report and each chamber's fit and
/// pointwise values (for figures).
pub fn stiffness(
    data: &LogData,
    shape: Shape,
) -> Result<(StiffnessReport, Vec<ChamberStiffness>), DiagError> {
    let res = analyze_log(data, shape)?;
    let report = StiffnessReport {
        log: data.name(),
        shape,
        flow_derived: data.flow_derived(),
        units: UNITS,
        first: res[0].summary.clone(),
        chambers: res.iter().map(|r| r.summary.clone()).collect(),
    };
    Ok((report, res))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phase_split_respects_dead_band() {
        let pw = Pointwise {
            k: vec![1.0, 2.0, 3.0, 4.0, 5.0],
            c: vec![10.0, 20.0, 30.0, 40.0, 50.0],
        };
        let q = [5.0, 1.0, -1.0, -5.0, 30.0];
        let s = summarize(0, &pw, &q, 2.0, 0.0);
        assert_eq!(s.k_mean, 3.0);
        assert_eq!(s.c_mean, 30.0);
        assert_eq!(s.inflation.samples, 2);
        assert_eq!(s.inflation.k_mean, Some(3.0));
        assert_eq!(s.deflation.samples, 1);
        assert_eq!(s.deflation.c_mean, Some(40.0));
        assert_eq!(s.rest_samples, 2);
    }
}
