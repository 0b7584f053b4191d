//! `vfp air-scan LOG…`: stiffness and damping (see [`super::stiffness`]) over several logs, e.g.
//! air pockets of growing volume in the syringe (paper §IV-A, Fig. 7c–d), with the trend.
//!
//! The x value of each log is given by `--x 0,10,20,40`, else the metadata entry named by
//! `--x-key` (default `air_pocket_mm3`, from a `# air_pocket_mm3=20` comment line), else its
//! position on the command line.
//! The trend is called *falling* when k̄ (or c̄) strictly decreases from each log to the next in
//! order of x.

use super::input::read_log;
use super::plot::{self, Curve, Mark};
use super::stiffness::{analyze_log, Summary, UNITS};
use super::{DiagError, ModelOpts, OutputOpts};
use serde::Serialize;
use std::path::PathBuf;

/// `vfp air-scan`: stiffness and damping across logs.
#[derive(Debug, Clone, clap::Args)]
pub struct AirScanArgs {
    /// Actuation logs, e.g. one per air-pocket volume.
    #[arg(required = true, num_args = 1..)]
    pub logs: Vec<PathBuf>,
    /// Metadata key giving each log's x value (`# key=value` comment).
    #[arg(long, default_value = "air_pocket_mm3")]
    pub x_key: String,
    /// The x value of each log, in command-line order (overrides the metadata), e.g. `0,10,20,40`.
    #[arg(long, value_delimiter = ',')]
    pub x: Option<Vec<f64>>,
    #[command(flatten)]
    pub model: ModelOpts,
    #[command(flatten)]
    pub out: OutputOpts,
}

/// One log of the scan (the analysed chamber: `--chamber`, else the lowest in the log).
#[derive(Debug, Clone, Serialize)]
pub struct ScanEntry {
    /// The log.
    pub log: String,
    /// Its x value (metadata or position).
    pub x: f64,
    /// Whether `x` came from `--x` or the metadata (else: the log's position).
    pub x_from_meta: bool,
    /// Stiffness summary of the analysed chamber.
    #[serde(flatten)]
    pub summary: Summary,
}

/// Direction of a sequence.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Trend {
    /// Strictly decreasing.
    Falling,
    /// Strictly increasing.
    Rising,
    /// Neither (or fewer than two points).
    Mixed,
}

/// Strict monotonicity of `y` in the given order.
pub fn trend(y: &[f64]) -> Trend {
    if y.len() < 2 {
        Trend::Mixed
    } else if y.windows(2).all(|w| w[1] < w[0]) {
        Trend::Falling
    } else if y.windows(2).all(|w| w[1] > w[0]) {
        Trend::Rising
    } else {
        Trend::Mixed
    }
}

/// JSON document of `vfp air-scan --json`.
#[derive(Debug, Serialize)]
pub struct AirScanReport {
    /// Name of the x value.
    pub x_key: String,
    /// Units of k and c.
    pub units: super::stiffness::Units,
    /// Logs sorted by x.
    pub logs: Vec<ScanEntry>,
    /// Trend of k̄ with x.
    pub k_trend: Trend,
    /// Trend of c̄ with x.
    pub c_trend: Trend,
}

type Points = Vec<(f64, String, super::stiffness::Pointwise)>;

/// The scan's report (no output); see [`run`].
pub fn scan(args: &AirScanArgs) -> Result<AirScanReport, DiagError> {
    Ok(scan_with_points(args)?.0)
}

fn scan_with_points(args: &AirScanArgs) -> Result<(AirScanReport, Points), DiagError> {
    args.model.validate()?;
    if let Some(x) = &args.x {
        if x.len() != args.logs.len() || x.iter().any(|v| !v.is_finite()) {
            return Err(DiagError::Usage(format!(
                "--x has {} finite values for {} logs: give one per log",
                x.len(),
                args.logs.len()
            )));
        }
    }
    let mut entries = Vec::new();
    let mut points = Vec::new();
    for (i, path) in args.logs.iter().enumerate() {
        let log = read_log(path)?;
        let (chamber, _) = log.chamber(args.model.chamber)?;
        let opts = ModelOpts {
            chamber: Some(chamber),
            ..args.model.clone()
        };
        let res = analyze_log(&log, &opts)?.remove(0);
        let (x, from_meta) = match (&args.x, log.meta(&args.x_key)) {
            (Some(x), _) => (x[i], true),
            (None, Some(s)) => (
                s.parse::<f64>().map_err(|_| DiagError::Input {
                    path: path.clone(),
                    line: None,
                    column: None,
                    msg: format!("metadata `{}={s}` is not a number", args.x_key),
                })?,
                true,
            ),
            (None, None) => (i as f64, false),
        };
        entries.push(ScanEntry {
            log: path.display().to_string(),
            x,
            x_from_meta: from_meta,
            summary: res.summary.clone(),
        });
        points.push((x, log.label(), res.pointwise));
    }
    let mut order: Vec<usize> = (0..entries.len()).collect();
    order.sort_by(|&a, &b| entries[a].x.total_cmp(&entries[b].x));
    let entries: Vec<ScanEntry> = order.iter().map(|&i| entries[i].clone()).collect();
    let ks: Vec<f64> = entries.iter().map(|e| e.summary.k_mean).collect();
    let cs: Vec<f64> = entries.iter().map(|e| e.summary.c_mean).collect();
    let report = AirScanReport {
        x_key: args.x_key.clone(),
        units: UNITS,
        k_trend: trend(&ks),
        c_trend: trend(&cs),
        logs: entries,
    };
    let mut slots: Vec<Option<_>> = points.into_iter().map(Some).collect();
    let sorted: Points = order.iter().filter_map(|&i| slots[i].take()).collect();
    Ok((report, sorted))
}

/// Runs `vfp air-scan`.
pub fn run(args: &AirScanArgs) -> Result<(), DiagError> {
    let (report, points) = scan_with_points(args)?;
    args.out.emit(&report, human, |dir| {
        let sorted: Vec<_> = points.iter().collect();
        plot_scan(dir, &report, &sorted)
    })
}

fn opt(x: Option<f64>) -> String {
    x.map(|x| format!("{x:>10.5}"))
        .unwrap_or_else(|| format!("{:>10}", "-"))
}

/// The human report.
pub fn human(r: &AirScanReport) -> String {
    let mut s = format!(
        "Mean stiffness k (kPa/mm3) and damping c (kPa s/mm3) per log, by {}\n\n  {:>8} {:>10} \
         {:>10} {:>10} {:>10} {:>10} {:>10}  log\n",
        r.x_key, r.x_key, "k all", "c all", "k infl", "c infl", "k defl", "c defl"
    );
    for e in &r.logs {
        let m = &e.summary;
        s += &format!(
            "  {:>8} {:>10.5} {:>10.5} {} {} {} {}  {} (chamber {}){}\n",
            e.x,
            m.k_mean,
            m.c_mean,
            opt(m.inflation.k_mean),
            opt(m.inflation.c_mean),
            opt(m.deflation.k_mean),
            opt(m.deflation.c_mean),
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
    r: &AirScanReport,
    points: &[&(f64, String, super::stiffness::Pointwise)],
) -> Result<PathBuf, DiagError> {
    let path = plot::target(dir, "diag-air-scan.svg")?;
    let root = plot::canvas(&path, (1100, 840));
    let (top, bottom) = root.split_vertically(420);
    let (tl, tr) = top.split_horizontally(550);
    let (bl, br) = bottom.split_horizontally(550);
    let series = |f: &dyn Fn(&Summary) -> Option<f64>| -> Vec<(f64, f64)> {
        r.logs
            .iter()
            .filter_map(|e| f(&e.summary).map(|y| (e.x, y)))
            .collect()
    };
    let means = |all: Vec<(f64, f64)>, inf: Vec<(f64, f64)>, def: Vec<(f64, f64)>| {
        vec![
            Curve::new("all samples", all, plot::color(0), Mark::LineDots),
            Curve::new("inflation", inf, plot::color(3), Mark::Triangles),
            Curve::new("deflation", def, RGB_BLUE, Mark::Triangles),
        ]
    };
    plot::panel(
        &tl,
        &path,
        "mean stiffness",
        &r.x_key,
        "k (kPa/mm3)",
        &means(
            series(&|m| Some(m.k_mean)),
            series(&|m| m.inflation.k_mean),
            series(&|m| m.deflation.k_mean),
        ),
    )?;
    plot::panel(
        &tr,
        &path,
        "mean damping",
        &r.x_key,
        "c (kPa s/mm3)",
        &means(
            series(&|m| Some(m.c_mean)),
            series(&|m| m.inflation.c_mean),
            series(&|m| m.deflation.c_mean),
        ),
    )?;
    let ks: Vec<&[f64]> = points.iter().map(|p| p.2.k.as_slice()).collect();
    let cs: Vec<&[f64]> = points.iter().map(|p| p.2.c.as_slice()).collect();
    let dist = |sets: &[&[f64]]| -> Vec<Curve> {
        let (lo, hi) = plot::quantile_range(sets, 0.005, 0.995);
        sets.iter()
            .zip(points)
            .enumerate()
            .map(|(i, (s, p))| {
                Curve::new(
                    format!("{} = {}", r.x_key, p.0),
                    plot::density_outline(s, lo, hi, 50),
                    plot::color(i),
                    Mark::Line,
                )
            })
            .collect()
    };
    plot::panel(
        &bl,
        &path,
        "distribution of pointwise k",
        "k (kPa/mm3)",
        "density",
        &dist(&ks),
    )?;
    plot::panel(
        &br,
        &path,
        "distribution of pointwise c",
        "c (kPa s/mm3)",
        "density",
        &dist(&cs),
    )?;
    plot::finish(root, &path)?;
    Ok(path.clone())
}

const RGB_BLUE: plotters::style::RGBColor = plotters::style::RGBColor(31, 60, 200);
