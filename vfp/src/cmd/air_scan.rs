//! `vfp air-scan LOG…`: stiffness and damping over several logs, e.g. air pockets of growing volume
//! in the syringe (paper §IV-A, Fig. 7c–d), with the trend; the method is
//! [`sysid::diag::air_scan`].

use super::stiffness::ShapeOpts;
use crate::opts::{ChamberOpt, DataOpts, OutputOpts};
use crate::plots::diag::{self as plot, Curve, Mark};
use crate::units::DisplayUnits;
use crate::Error;
use std::path::PathBuf;
use sysid::diag::air_scan::{scan, AirScanReport, ScanPoints, Trend};
use sysid::diag::stiffness::Summary;

/// `vfp air-scan`: stiffness and damping across logs.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Actuation logs, e.g. one per air-pocket volume.
    #[arg(required = true, num_args = 1..)]
    pub logs: Vec<PathBuf>,
    /// Metadata key giving each log's x value (`# key=value` comment).
    #[arg(long, default_value = "air_pocket_mm3")]
    pub x_key: String,
    /// The x value of each log, in command-line order (overrides the metadata), e.g. `0,10,20,40`.
    #[arg(long, value_delimiter = ',')]
    pub x: Option<Vec<f64>>,
    /// The chamber analysed in every log (default: the lowest in each).
    #[command(flatten)]
    pub chamber: ChamberOpt,
    #[command(flatten)]
    pub data: DataOpts,
    #[command(flatten)]
    pub shape: ShapeOpts,
    #[command(flatten)]
    pub out: OutputOpts,
}

/// The scan's report and pointwise values (no output); see [`run`].
pub fn scan_logs(args: &Args) -> Result<(AirScanReport, Vec<ScanPoints>), Error> {
    let shape = args.shape.shape()?;
    let logs = args
        .logs
        .iter()
        .map(|p| args.data.load(p, args.chamber.chamber))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(scan(&logs, args.x.as_deref(), &args.x_key, shape)?)
}

/// Runs `vfp air-scan`.
pub fn run(args: &Args) -> Result<(), Error> {
    let (report, points) = scan_logs(args)?;
    let u = args.out.display_units(&args.data);
    args.out.emit(
        &report,
        |r| human(r, &u),
        |dir, format| plot_scan(dir, format, &report, &points, &u),
    )
}

fn opt(x: Option<f64>, u: &DisplayUnits) -> String {
    x.map(|x| format!("{:>10.5}", u.k(x)))
        .unwrap_or_else(|| format!("{:>10}", "-"))
}

/// The human report, its numbers in `u`.
pub fn human(r: &AirScanReport, u: &DisplayUnits) -> String {
    let mut s = format!(
        "Mean stiffness k ({}) and damping c ({}) per log, by {}\n\n  {:>8} {:>10} \
         {:>10} {:>10} {:>10} {:>10} {:>10}  log\n",
        u.stiffness(),
        u.damping(),
        r.x_key,
        r.x_key,
        "k all",
        "c all",
        "k infl",
        "c infl",
        "k defl",
        "c defl"
    );
    for e in &r.logs {
        let m = &e.summary;
        s += &format!(
            "  {:>8} {:>10.5} {:>10.5} {} {} {} {}  {} (chamber {}){}\n",
            e.x,
            u.k(m.k_mean),
            u.k(m.c_mean),
            opt(m.inflation.k_mean, u),
            opt(m.inflation.c_mean, u),
            opt(m.deflation.k_mean, u),
            opt(m.deflation.c_mean, u),
            e.log,
            m.chamber,
            if e.x_from_meta {
                ""
            } else {
                " [x = position: no metadata]"
            }
        );
    }
    let word = |t: Trend| match t {
        Trend::Falling => "falls",
        Trend::Rising => "rises",
        Trend::Mixed => "is not monotone",
    };
    s += &format!(
        "\nAs {} grows, k {} and c {}.\n",
        r.x_key,
        word(r.k_trend),
        word(r.c_trend)
    );
    s
}

/// Fig. 7c (means against x, per phase) and 7d (distributions per log).
fn plot_scan(
    dir: &std::path::Path,
    format: crate::figure::PlotFormat,
    r: &AirScanReport,
    points: &[ScanPoints],
    u: &DisplayUnits,
) -> Result<PathBuf, Error> {
    let kd = format!("k ({})", u.stiffness());
    let cd = format!("c ({})", u.damping());
    let k = |x: Option<f64>| x.map(|x| u.k(x));
    let path = plot::target(dir, &format.file("diag-air-scan"))?;
    let root = plot::canvas(&path, (1100, 840), format);
    let (top, bottom) = root.split_vertically(420);
    let (tl, tr) = top.split_horizontally(550);
    let (bl, br) = bottom.split_horizontally(550);
    let k_means = mean_curves(
        r,
        |m| k(Some(m.k_mean)),
        |m| k(m.inflation.k_mean),
        |m| k(m.deflation.k_mean),
    );
    let c_means = mean_curves(
        r,
        |m| k(Some(m.c_mean)),
        |m| k(m.inflation.c_mean),
        |m| k(m.deflation.c_mean),
    );
    plot::panel(&tl, &path, "mean stiffness", &r.x_key, &kd, &k_means)?;
    plot::panel(&tr, &path, "mean damping", &r.x_key, &cd, &c_means)?;
    let conv = |x: &[f64]| x.iter().map(|&x| u.k(x)).collect::<Vec<f64>>();
    let (kv, cv): (Vec<Vec<f64>>, Vec<Vec<f64>>) = points
        .iter()
        .map(|p| (conv(&p.pointwise.k), conv(&p.pointwise.c)))
        .unzip();
    let ks: Vec<&[f64]> = kv.iter().map(Vec::as_slice).collect();
    let cs: Vec<&[f64]> = cv.iter().map(Vec::as_slice).collect();
    plot::panel(
        &bl,
        &path,
        "distribution of pointwise k",
        &kd,
        "density",
        &density_curves(r, points, &ks),
    )?;
    plot::panel(
        &br,
        &path,
        "distribution of pointwise c",
        &cd,
        "density",
        &density_curves(r, points, &cs),
    )?;
    plot::finish(root, &path)?;
    Ok(path.clone())
}

/// Fig. 7c's curves of one quantity against x: its mean over all samples, over inflation and over
/// deflation, one point per log.
fn mean_curves(
    r: &AirScanReport,
    all: impl Fn(&Summary) -> Option<f64>,
    inflation: impl Fn(&Summary) -> Option<f64>,
    deflation: impl Fn(&Summary) -> Option<f64>,
) -> Vec<Curve> {
    let series = |f: &dyn Fn(&Summary) -> Option<f64>| -> Vec<(f64, f64)> {
        r.logs
            .iter()
            .filter_map(|e| f(&e.summary).map(|y| (e.x, y)))
            .collect()
    };
    vec![
        Curve::new("all samples", series(&all), plot::color(0), Mark::LineDots),
        Curve::new(
            "inflation",
            series(&inflation),
            plot::color(3),
            Mark::Triangles,
        ),
        Curve::new("deflation", series(&deflation), RGB_BLUE, Mark::Triangles),
    ]
}

/// Fig. 7d's curves: the distribution of one pointwise quantity (`sets`, one per log of
/// `points`) over their common 0.5–99.5 % range.
fn density_curves(r: &AirScanReport, points: &[ScanPoints], sets: &[&[f64]]) -> Vec<Curve> {
    let (lo, hi) = plot::quantile_range(sets, 0.005, 0.995);
    sets.iter()
        .zip(points)
        .enumerate()
        .map(|(i, (s, p))| {
            Curve::new(
                format!("{} = {}", r.x_key, p.x),
                plot::density_outline(s, lo, hi, 50),
                plot::color(i),
                Mark::Line,
            )
        })
        .collect()
}

const RGB_BLUE: plotters::style::RGBColor = plotters::style::RGBColor(31, 60, 200);
