//! Stiffness and damping (see [`super::stiffness`]) over several logs, e.g.
//! air pockets of growing volume in the syringe (paper §IV-A, Fig. 7c–d), with the trend.
//!
//! The x value of each log is given by `--x 0,10,20,40`, else the metadata entry named by
//! `--x-key` (default `air_pocket_mm3`, from a `# air_pocket_mm3=20` comment line), else its
//! position on the command line.
//! The trend is called *falling* when k̄ (or c̄) strictly decreases from each log to the next in
//! order of x.

use super::stiffness::{analyze, Pointwise, Summary, UNITS};
use super::{DiagError, Shape};
use crate::dataset::LogData;
use serde::Serialize;

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

/// The report of `vfp air-scan` (its `--json` document).
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

/// One log's pointwise values in a scan (for the distribution figure).
#[derive(Clone, Debug)]
pub struct ScanPoints {
    /// The log's x value.
    pub x: f64,
    /// The log's label (file stem).
    pub label: String,
    /// kᵢ, cᵢ of the analysed chamber.
    pub pointwise: Pointwise,
}

/// Stiffness and damping of each log's first chamber (the one it was read with, else the lowest),
/// sorted by x: `xs` gives the x values in the logs' order, else each log's metadata `x_key`, else
/// its position. Returns the report and each log's pointwise values in the same order.
pub fn scan(
    logs: &[LogData],
    xs: Option<&[f64]>,
    x_key: &str,
    shape: Shape,
) -> Result<(AirScanReport, Vec<ScanPoints>), DiagError> {
    if let Some(x) = xs {
        if x.len() != logs.len() || x.iter().any(|v| !v.is_finite()) {
            return Err(DiagError::Usage(format!(
                "--x has {} finite values for {} logs: give one per log",
                x.len(),
                logs.len()
            )));
        }
    }
    let mut entries = Vec::new();
    let mut points = Vec::new();
    for (i, data) in logs.iter().enumerate() {
        let ds = data.first();
        let res = analyze(&data.name(), ds.chamber, ds, shape)?;
        let (x, from_meta) = match (xs, data.meta(x_key)) {
            (Some(x), _) => (x[i], true),
            (None, Some(s)) => (
                s.parse::<f64>().map_err(|_| DiagError::Input {
                    path: data.path.clone(),
                    line: None,
                    column: None,
                    msg: format!("metadata `{x_key}={s}` is not a number"),
                })?,
                true,
            ),
            (None, None) => (i as f64, false),
        };
        entries.push(ScanEntry {
            log: data.name(),
            x,
            x_from_meta: from_meta,
            summary: res.summary.clone(),
        });
        points.push(ScanPoints {
            x,
            label: data.label(),
            pointwise: res.pointwise,
        });
    }
    let mut order: Vec<usize> = (0..entries.len()).collect();
    order.sort_by(|&a, &b| entries[a].x.total_cmp(&entries[b].x));
    let entries: Vec<ScanEntry> = order.iter().map(|&i| entries[i].clone()).collect();
    let ks: Vec<f64> = entries.iter().map(|e| e.summary.k_mean).collect();
    let cs: Vec<f64> = entries.iter().map(|e| e.summary.c_mean).collect();
    let report = AirScanReport {
        x_key: x_key.to_string(),
        units: UNITS,
        k_trend: trend(&ks),
        c_trend: trend(&cs),
        logs: entries,
    };
    let mut slots: Vec<Option<ScanPoints>> = points.into_iter().map(Some).collect();
    let sorted: Vec<ScanPoints> = order.iter().filter_map(|&i| slots[i].take()).collect();
    Ok((report, sorted))
}
