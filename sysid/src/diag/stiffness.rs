//! `vfp stiffness LOG`: pointwise stiffness and damping of the identified polynomial (paper
//! §IV-A, eq. 13, Fig. 7c–d).
//!
//! With P̂(v, v̇) = Σᵢ Σⱼ αᵢⱼ vⁱ v̇ʲ fitted to the log (least squares over all its samples, one
//! chamber), every sample gets
//!
//! kᵢ = ∂P̂/∂v |₍vᵢ, v̇ᵢ₎ (kPa/mm³, stiffness) and cᵢ = ∂P̂/∂v̇ |₍vᵢ, v̇ᵢ₎ (kPa·s/mm³, damping),
//!
//! and k̄ = (1/N) Σ kᵢ, c̄ = (1/N) Σ cᵢ over all N samples. The inflation means take only
//! samples with v̇ > +δ, the deflation means only v̇ < −δ, where the dead band δ (default
//! 2 mm³/s: two 0.04 mm³ steps per 25 Hz frame) keeps samples at rest, whose flow sign is noise,
//! out of both phases; they still count in the overall means, as in the paper.

use super::input::{read_log, Log, Series};
use super::plot::{self, Curve, Mark};
use super::Shape;
use super::{DiagError, ModelOpts, OutputOpts};
use crate::poly::{self, PolyFit, Xy};
use serde::Serialize;
use std::path::PathBuf;

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
    s: &Series,
    shape: Shape,
    deadband: f64,
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
    let summary = summarize(chamber, &pw, &s.vdot, deadband, fit.train.rmse);
    Ok(ChamberStiffness {
        fit,
        pointwise: pw,
        summary,
    })
}

/// Analyses every chamber of a log; returns them in chamber order.
pub fn analyze_log(log: &Log, opts: &ModelOpts) -> Result<Vec<ChamberStiffness>, DiagError> {
    let ctx = log.path.display().to_string();
    let chambers: Vec<u8> = match opts.chamber {
        Some(c) => vec![log.chamber(Some(c))?.0],
        None => log.chambers.keys().copied().collect(),
    };
    chambers
        .into_iter()
        .map(|c| analyze(&ctx, c, &log.chambers[&c], opts.shape(), opts.deadband))
        .collect()
}

/// `vfp stiffness`: stiffness and damping of one log.
#[derive(Debug, Clone, clap::Args)]
pub struct StiffnessArgs {
    /// Actuation log (shared/data-format.md).
    pub log: PathBuf,
    #[command(flatten)]
    pub model: ModelOpts,
    #[command(flatten)]
    pub out: OutputOpts,
}

/// JSON document of `vfp stiffness --json`: the first analysed chamber at the top level, all
/// chambers in `chambers`.
#[derive(Debug, Serialize)]
pub struct StiffnessReport {
    /// The log.
    pub log: String,
    /// Polynomial shape.
    pub shape: Shape,
    /// Dead band on |v̇| for the phase split (mm³/s).
    pub deadband_mm3_s: f64,
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

pub(crate) const UNITS: Units = Units {
    k: "kPa/mm^3",
    c: "kPa*s/mm^3",
};

/// Runs `vfp stiffness`.
pub fn run(args: &StiffnessArgs) -> Result<(), DiagError> {
    args.model.validate()?;
    let log = read_log(&args.log)?;
    let res = analyze_log(&log, &args.model)?;
    let report = StiffnessReport {
        log: args.log.display().to_string(),
        shape: args.model.shape(),
        deadband_mm3_s: args.model.deadband,
        flow_derived: log.flow_derived,
        units: UNITS,
        first: res[0].summary.clone(),
        chambers: res.iter().map(|r| r.summary.clone()).collect(),
    };
    args.out.emit(&report, human, |dir| {
        plot_distributions(dir, &log.label(), &res)
    })
}

fn opt(x: Option<f64>) -> String {
    x.map(|x| format!("{x:>12.5}"))
        .unwrap_or_else(|| format!("{:>12}", "-"))
}

/// The human report.
pub fn human(r: &StiffnessReport) -> String {
    let mut s = format!(
        "Stiffness k = dP/dv and damping c = dP/dvdot of the fitted polynomial (n = {}, m = {}) \
         at every sample of {}\n",
        r.shape.n, r.shape.m, r.log
    );
    if r.flow_derived {
        s += "(flow derived from volume and time: the log has no flow_mm3_s column)\n";
    }
    for c in &r.chambers {
        s += &format!(
            "\nchamber {}: {} samples, fit RMSE {:.4} kPa\n  {:<10} {:>12} {:>12} {:>8}\n",
            c.chamber,
            c.samples,
            c.fit_rmse_kpa,
            "phase",
            "k (kPa/mm3)",
            "c (kPa s/mm3)",
            "samples"
        );
        s += &format!(
            "  {:<10} {:>12.5} {:>12.5} {:>8}\n",
            "all", c.k_mean, c.c_mean, c.samples
        );
        for (name, m) in [("inflation", &c.inflation), ("deflation", &c.deflation)] {
            s += &format!(
                "  {:<10} {} {} {:>8}\n",
                name,
                opt(m.k_mean),
                opt(m.c_mean),
                m.samples
            );
        }
        s += &format!(
            "  ({} samples with |vdot| <= {} mm3/s count as rest: in 'all' only)\n",
            c.rest_samples, r.deadband_mm3_s
        );
    }
    s
}

/// Fig. 7d-style distributions of kᵢ and cᵢ per chamber; returns the file written.
fn plot_distributions(
    dir: &std::path::Path,
    label: &str,
    res: &[ChamberStiffness],
) -> Result<PathBuf, DiagError> {
    let path = plot::target(dir, "diag-stiffness.svg")?;
    let root = plot::canvas(&path, (1100, 420));
    let (left, right) = root.split_horizontally(550);
    let ks: Vec<&[f64]> = res.iter().map(|r| r.pointwise.k.as_slice()).collect();
    let cs: Vec<&[f64]> = res.iter().map(|r| r.pointwise.c.as_slice()).collect();
    let (klo, khi) = plot::quantile_range(&ks, 0.005, 0.995);
    let (clo, chi) = plot::quantile_range(&cs, 0.005, 0.995);
    let curves = |sets: &[&[f64]], lo, hi| -> Vec<Curve> {
        sets.iter()
            .zip(res)
            .enumerate()
            .map(|(i, (s, r))| {
                Curve::new(
                    format!("chamber {}", r.summary.chamber),
                    plot::density_outline(s, lo, hi, 60),
                    plot::color(i),
                    Mark::Line,
                )
            })
            .collect()
    };
    plot::panel(
        &left,
        &path,
        &format!("{label}: pointwise stiffness k"),
        "k = dP/dv (kPa/mm3)",
        "density",
        &curves(&ks, klo, khi),
    )?;
    plot::panel(
        &right,
        &path,
        &format!("{label}: pointwise damping c"),
        "c = dP/dvdot (kPa s/mm3)",
        "density",
        &curves(&cs, clo, chi),
    )?;
    plot::finish(root, &path)?;
    Ok(path.clone())
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
