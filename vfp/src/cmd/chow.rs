//! `vfp chow A.csv B.csv [C.csv …]`: are two logs described by the same polynomial? (paper
//! §IV-B, Table VI; Chow 1960); the method is [`sysid::diag::chow`].

use super::stiffness::ShapeOpts;
use crate::opts::{method_parser, ChamberOpt, DataOpts, OutputOpts};
use crate::plots::diag::{self as plot, Curve, Mark};
use crate::units::DisplayUnits;
use crate::Error;
use std::path::PathBuf;
use sysid::dataset::LogData;
use sysid::diag::chow::{chow_logs, ChowOptions, ChowReport, Method};

/// `vfp chow`: pairwise Chow tests between logs.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Two or more actuation logs.
    #[arg(required = true, num_args = 2..)]
    pub logs: Vec<PathBuf>,
    /// The common polynomial's shape.
    #[command(flatten)]
    pub shape: ShapeOpts,
    /// Chamber to compare (default: the lowest chamber in each log).
    #[command(flatten)]
    pub chamber: ChamberOpt,
    #[command(flatten)]
    pub data: DataOpts,
    /// Significance level.
    #[arg(long, default_value_t = 0.0005)]
    pub alpha: f64,
    /// Statistic that decides: `gls` (prewhitened; robust to serially correlated errors) or
    /// `classic` (Chow 1960, independent errors).
    #[arg(long, value_parser = method_parser(), default_value = "gls")]
    pub method: Method,
    /// Highest AR order of the residual model for prewhitening (chosen by AIC up to this).
    #[arg(long, default_value_t = 10)]
    pub ar_max: usize,
    /// Force the AR order of the residual model.
    #[arg(long)]
    pub ar_order: Option<usize>,
    #[command(flatten)]
    pub out: OutputOpts,
}

/// Runs `vfp chow`.
pub fn run(args: &Args) -> Result<(), Error> {
    if !(args.alpha > 0.0 && args.alpha < 1.0) {
        return Err(Error::Usage(format!(
            "--alpha {}: must lie in (0, 1)",
            args.alpha
        )));
    }
    let shape = args.shape.shape()?;
    let logs = args
        .logs
        .iter()
        .map(|p| args.data.load(p, args.chamber.chamber))
        .collect::<Result<Vec<_>, _>>()?;
    let o = ChowOptions {
        shape,
        alpha: args.alpha,
        method: args.method,
        ar_max: args.ar_max,
        ar_order: args.ar_order,
    };
    let report = chow_logs(&logs, &o)?;
    let u = args.out.display_units(&args.data);
    args.out.emit(&report, human, |dir, format| {
        plot_chow(dir, format, &logs, &report, &u)
    })
}

fn fmt_p(p: f64) -> String {
    if p < 1e-300 {
        "<1e-300".into()
    } else {
        format!("{p:.3e}")
    }
}

/// The human report.
pub fn human(r: &ChowReport) -> String {
    let k = r.shape.terms();
    let mut s = format!(
        "Chow test, common polynomial n = {}, m = {} ({k} coefficients), alpha = {}, verdict by \
         {} F\n",
        r.shape.n,
        r.shape.m,
        r.alpha,
        match r.method {
            Method::Gls => "the prewhitened (AR-GLS)",
            Method::Classic => "the classic (independent-errors)",
        }
    );
    for (i, l) in r.logs.iter().enumerate() {
        s += &format!("  [{i}] {l}\n");
    }
    s += "\nF matrix (Table VI):\n        ";
    for i in 0..r.logs.len() {
        s += &format!("{:>12}", format!("[{i}]"));
    }
    s += "\n";
    for (i, row) in r.matrix.iter().enumerate() {
        s += &format!("  {:>6}", format!("[{i}]"));
        for f in row {
            s += &f
                .map(|f| format!("{f:>12.2}"))
                .unwrap_or_else(|| format!("{:>12}", "-"));
        }
        s += "\n";
    }
    s += "\npairs:\n";
    for (pi, p) in r.pairs.iter().enumerate() {
        let t = &p.test;
        let ia = r.logs.iter().position(|l| *l == p.a).unwrap_or(pi);
        let ib = r.logs.iter().position(|l| *l == p.b).unwrap_or(pi);
        s += &format!(
            "  [{ia}] vs [{ib}]: F = {:.3} (df {}, {}), p = {}, critical {:.3} -> {}\n      \
             classic F = {:.3} (p = {}); residual AR({}) {}\n",
            t.f,
            t.df1,
            t.df2,
            fmt_p(t.p),
            t.critical,
            if t.reject {
                "DIFFERENT (H0 rejected)"
            } else {
                "not distinguishable"
            },
            t.f_classic,
            fmt_p(t.p_classic),
            t.ar.len(),
            if t.ar.is_empty() {
                "(none: independent errors)".to_string()
            } else {
                format!(
                    "phi = {:?}",
                    t.ar.iter()
                        .map(|x| (x * 1000.0).round() / 1000.0)
                        .collect::<Vec<_>>()
                )
            },
        );
    }
    s
}

/// Each log's V–P points (about 800 of each), coloured by its index.
fn vp_curves(logs: &[LogData], u: &DisplayUnits) -> Vec<Curve> {
    logs.iter()
        .enumerate()
        .map(|(i, l)| {
            let s = l.first();
            let step = (s.len() / 800).max(1);
            let pts =
                s.v.iter()
                    .zip(&s.p)
                    .step_by(step)
                    .map(|(&v, &p)| (u.v(v), u.p(p)))
                    .collect();
            Curve::new(
                format!("[{i}] {}", l.label()),
                pts,
                plot::color(i),
                Mark::Dots,
            )
        })
        .collect()
}

/// log₁₀ F of each pair and the critical value's line across them.
fn f_curves(r: &ChowReport) -> Vec<Curve> {
    let fs: Vec<(f64, f64)> = r
        .pairs
        .iter()
        .enumerate()
        .map(|(i, p)| (i as f64, p.test.f.max(1e-3).log10()))
        .collect();
    let crit = r
        .pairs
        .first()
        .map(|p| p.test.critical.log10())
        .unwrap_or(0.0);
    let n = r.pairs.len().max(1) as f64;
    vec![
        Curve::new("log10 F per pair", fs, plot::color(0), Mark::Points),
        Curve::new(
            format!("log10 critical value (alpha = {})", r.alpha),
            vec![(-0.5, crit), (n - 0.5, crit)],
            plot::color(3),
            Mark::Line,
        ),
    ]
}

/// V–P data of every log and the deciding F of every pair against the critical value.
fn plot_chow(
    dir: &std::path::Path,
    format: crate::figure::PlotFormat,
    logs: &[LogData],
    r: &ChowReport,
    u: &DisplayUnits,
) -> Result<PathBuf, Error> {
    let path = plot::target(dir, &format.file("diag-chow"))?;
    let root = plot::canvas(&path, (1100, 440), format);
    let (left, right) = root.split_horizontally(550);
    let vp = vp_curves(logs, u);
    plot::panel(
        &left,
        &path,
        "V-P of the compared logs",
        &format!("volume ({})", u.volume()),
        &format!("pressure ({})", u.pressure()),
        &vp,
    )?;
    let curves = f_curves(r);
    // The pair's logs by their index in the V-P panel's legend.
    let idx = |name: &str| {
        logs.iter()
            .position(|l| {
                let stem = std::path::Path::new(name).file_stem();
                l.label() == name || stem.and_then(|s| s.to_str()) == Some(l.label().as_str())
            })
            .map_or(name.to_string(), |i| i.to_string())
    };
    let pairs: Vec<String> = r
        .pairs
        .iter()
        .map(|p| format!("[{}]-[{}]", idx(&p.a), idx(&p.b)))
        .collect();
    plot::panel_with(
        &right,
        &path,
        ["Chow F per pair", "pair of logs", "log10 F"],
        &curves,
        &pairs,
    )?;
    plot::finish(root, &path)?;
    Ok(path.clone())
}
