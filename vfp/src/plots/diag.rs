//! Small SVG plotting helpers shared by the diagnostics commands (plotters, SVG backend, so no
//! system fonts are needed).

use crate::figure::{Canvas, PlotFormat};
use crate::Error;
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// How a curve is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Mark {
    /// Connected line.
    Line,
    /// Line with circles at the points.
    LineDots,
    /// Small dots only.
    Dots,
    /// Large circles only, unconnected (categorical points: nothing lies between them).
    Points,
    /// Upward triangles only.
    Triangles,
}

/// One labelled curve of a panel.
pub(crate) struct Curve {
    pub label: String,
    pub pts: Vec<(f64, f64)>,
    pub color: RGBColor,
    pub mark: Mark,
}

impl Curve {
    pub fn new(
        label: impl Into<String>,
        pts: Vec<(f64, f64)>,
        color: RGBColor,
        mark: Mark,
    ) -> Self {
        Curve {
            label: label.into(),
            pts,
            color,
            mark,
        }
    }
}

/// Distinct colours for series i = 0, 1, …
pub(crate) fn color(i: usize) -> RGBColor {
    const C: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
    ];
    C[i % C.len()]
}

/// Creates `dir` and returns `dir/name`.
pub(crate) fn target(dir: &Path, name: &str) -> Result<PathBuf, Error> {
    std::fs::create_dir_all(dir).map_err(|e| Error::output(dir, e))?;
    Ok(dir.join(name))
}

/// A new white canvas of the given size and format.
pub(crate) fn canvas(path: &Path, size: (u32, u32), format: PlotFormat) -> Canvas<'_> {
    let root = crate::figure::canvas(path, size, format);
    // Filling a fresh canvas cannot fail: it only writes to an in-memory buffer.
    root.fill(&WHITE).ok();
    root
}

/// Writes the canvas to disk.
pub(crate) fn finish(root: Canvas<'_>, path: &Path) -> Result<(), Error> {
    root.present().map_err(|e| Error::output(path, e))
}

fn range(vals: impl Iterator<Item = f64>) -> (f64, f64) {
    crate::figure::padded_range(vals)
}

/// Draws curves with axes, labels and a legend into `area`.
pub(crate) fn panel(
    area: &Canvas<'_>,
    path: &Path,
    title: &str,
    xdesc: &str,
    ydesc: &str,
    curves: &[Curve],
) -> Result<(), Error> {
    panel_with(area, path, [title, xdesc, ydesc], curves, &[])
}

fn category_tick(x: f64, categories: &[String]) -> String {
    let i = x.round();
    if (x - i).abs() > 1e-6 || i < 0.0 {
        return String::new();
    }
    categories.get(i as usize).cloned().unwrap_or_default()
}

/// [`panel`], and when `categories` is not empty a categorical x axis: point `i` stands for
/// `categories[i]`, and only whole positions get a tick label (its name).
pub(crate) fn panel_with(
    area: &Canvas<'_>,
    path: &Path,
    [title, xdesc, ydesc]: [&str; 3],
    curves: &[Curve],
    categories: &[String],
) -> Result<(), Error> {
    let e = |e: DrawingAreaErrorKind<_>| Error::output(path, e);
    let (x0, x1) = range(curves.iter().flat_map(|c| c.pts.iter().map(|p| p.0)));
    let (y0, y1) = range(curves.iter().flat_map(|c| c.pts.iter().map(|p| p.1)));
    // Headroom above the data for the legend (upper right): 15 % of the data's range per entry
    // leaves at least 60 px per entry on a 440 px panel, more than an entry's 20 px.
    let entries = curves.iter().filter(|c| !c.label.is_empty()).count();
    let y1 = y1 + (y1 - y0) * 0.15 * entries as f64;
    let mut chart = ChartBuilder::on(area)
        .caption(title, ("sans-serif", 17))
        .margin(12)
        .x_label_area_size(38)
        .y_label_area_size(62)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(e)?;
    chart
        .configure_mesh()
        .x_desc(xdesc)
        .y_desc(ydesc)
        .y_label_formatter(&|y| crate::figure::tick(*y))
        .x_label_formatter(&|x| match categories.is_empty() {
            true => crate::figure::tick(*x),
            false => category_tick(*x, categories),
        })
        .x_labels(match categories.is_empty() {
            true => 10,
            false => categories.len().clamp(1, 12),
        })
        .light_line_style(WHITE.mix(0.0))
        .draw()
        .map_err(e)?;
    for c in curves {
        let col = c.color;
        let pts = c
            .pts
            .iter()
            .copied()
            .filter(|p| p.0.is_finite() && p.1.is_finite());
        let anno = match c.mark {
            Mark::Line => chart.draw_series(LineSeries::new(pts, col.stroke_width(2))),
            Mark::LineDots => {
                let v: Vec<_> = pts.collect();
                chart
                    .draw_series(LineSeries::new(v.clone(), col.stroke_width(2)))
                    .map_err(e)?;
                chart.draw_series(v.into_iter().map(|p| Circle::new(p, 4, col.filled())))
            }
            Mark::Dots => chart.draw_series(pts.map(|p| Circle::new(p, 1, col.filled()))),
            Mark::Points => chart.draw_series(pts.map(|p| Circle::new(p, 5, col.filled()))),
            Mark::Triangles => {
                chart.draw_series(pts.map(|p| TriangleMarker::new(p, 6, col.filled())))
            }
        }
        .map_err(e)?;
        if !c.label.is_empty() {
            anno.label(c.label.as_str()).legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 18, y)], col.stroke_width(3))
            });
        }
    }
    if curves.iter().any(|c| !c.label.is_empty()) {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
    }
    Ok(())
}

/// Outline of a probability-density histogram of `values` over `[lo, hi]` with `bins` bins,
/// as points for a line curve (so several distributions can be overlaid).
pub(crate) fn density_outline(values: &[f64], lo: f64, hi: f64, bins: usize) -> Vec<(f64, f64)> {
    let w = (hi - lo) / bins as f64;
    let mut count = vec![0usize; bins];
    let mut n = 0usize;
    for &x in values {
        if x.is_finite() && x >= lo && x <= hi {
            let b = (((x - lo) / w) as usize).min(bins - 1);
            count[b] += 1;
            n += 1;
        }
    }
    let scale = if n > 0 { 1.0 / (n as f64 * w) } else { 0.0 };
    let mut pts = vec![(lo, 0.0)];
    for (b, &c) in count.iter().enumerate() {
        let h = c as f64 * scale;
        pts.push((lo + b as f64 * w, h));
        pts.push((lo + (b + 1) as f64 * w, h));
    }
    pts.push((hi, 0.0));
    pts
}

/// Central range [q_lo, q_hi] quantiles of several sets together (for histogram limits that
/// ignore the few extreme points near reversals).
pub(crate) fn quantile_range(sets: &[&[f64]], q_lo: f64, q_hi: f64) -> (f64, f64) {
    let mut all: Vec<f64> = sets
        .iter()
        .flat_map(|s| s.iter().copied())
        .filter(|x| x.is_finite())
        .collect();
    if all.is_empty() {
        return (0.0, 1.0);
    }
    all.sort_by(f64::total_cmp);
    let at = |q: f64| all[((all.len() - 1) as f64 * q).round() as usize];
    let (lo, hi) = (at(q_lo), at(q_hi));
    if hi > lo {
        (lo, hi)
    } else {
        (lo - 0.5 * lo.abs().max(1e-9), hi + 0.5 * hi.abs().max(1e-9))
    }
}
