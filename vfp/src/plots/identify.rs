//! Figures of `vfp identify --plots DIR` (SVG or PNG, `--plot-format`):
//!
//! - `ch<c>-<family>-rmse-aicc.<ext>`: RMSE bars and AICc points per model (Figs. 2-4);
//! - `ch<c>-residual-vs-volume.<ext>`: held-out residuals of the selected polynomial against v (Fig. 5a);
//! - `ch<c>-error-histogram.<ext>`: its error distribution, 0.05 kPa bins (Fig. 5b; in another
//!   pressure unit the round width nearest to it, 0.5 cmH2O);
//! - `ch<c>-vp.<ext>`: measured and predicted V-P curves (Fig. 1c).
//!
//! Volumes and pressures are drawn in the report's units ([`DisplayUnits`], `--units`).
//!
//! Scatter plots draw at most [`MAX_POINTS`] points per set, evenly spaced through the data, so
//! a figure of a long log stays well under 1 MB (a point is some 100 bytes of SVG).

use crate::figure::{Canvas, PlotFormat};
use crate::units::DisplayUnits;
use crate::Error;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use sysid::dataset::Dataset;
use sysid::identify::{ChamberReport, Family};
use sysid::poly::PolyFit;

fn err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Msg(format!("{}: cannot write figure: {e}", path.display()))
}

fn bounds(xs: impl Iterator<Item = f64>) -> (f64, f64) {
    crate::figure::padded_range(xs)
}

/// Points per scatter set at most.
pub const MAX_POINTS: usize = 4_000;

/// Writes every figure for one chamber into `dir` (created if needed); returns the files in the
/// order written.
pub fn write_all(
    dir: &Path,
    format: PlotFormat,
    ds: &Dataset,
    rep: &ChamberReport,
    units: &DisplayUnits,
) -> Result<Vec<PathBuf>, Error> {
    std::fs::create_dir_all(dir).map_err(|e| err(dir, e))?;
    let file = |stem: String| dir.join(format.file(&stem));
    let mut written = family_figures(&file, format, rep, units)?;
    if let Some(fit) = &rep.poly_fit {
        let figs = FitFigures {
            file: &file,
            format,
            ds,
            chamber: rep.chamber,
            fit,
            name: format!("poly ({}, {})", fit.n, fit.m),
            units,
        };
        written.extend(figs.residuals()?);
        written.push(figs.vp()?);
    }
    Ok(written)
}

/// Each family's RMSE (bars) and AICc (points) over its models, the family's choice marked.
fn family_figures(
    file: &dyn Fn(String) -> PathBuf,
    format: PlotFormat,
    rep: &ChamberReport,
    u: &DisplayUnits,
) -> Result<Vec<PathBuf>, Error> {
    let mut written = Vec::new();
    for fam in Family::ALL {
        let rows: Vec<_> = rep.models.iter().filter(|m| m.family == fam).collect();
        if rows.is_empty() {
            continue;
        }
        let path = file(format!("ch{}-{}-rmse-aicc", rep.chamber, fam.name()));
        // Shapes without brackets or spaces ("1,7"), so each fits under its own bar upright.
        let labels: Vec<String> = rows
            .iter()
            .map(|r| r.shape().replace(['(', ')', ' '], ""))
            .collect();
        let rmse: Vec<f64> = rows.iter().map(|r| u.p(r.rmse)).collect();
        let aicc: Vec<f64> = rows.iter().map(|r| r.aicc).collect();
        let chosen = rep
            .best
            .iter()
            .find(|b| b.family == fam)
            .and_then(|b| rows.iter().position(|r| r.shape() == b.shape()));
        let shape_name = match fam {
            Family::Exp => "k, exponential terms",
            Family::Nn => "p,d: AR inputs, depth",
            Family::Poly => "n,m: highest powers of v and dv/dt",
            Family::PolyAr => "p,n,m: AR order, powers of v and dv/dt",
        };
        let title = match chosen {
            Some(i) => format!(
                "{}: RMSE (bars) and AICc (red); the family's choice {} in orange",
                fam.name(),
                rows[i].shape()
            ),
            None => format!("{}: RMSE (bars) and AICc (red)", fam.name()),
        };
        // 30 px per model (a label of up to five characters), at least the former 1000 px.
        let width = (120 + 30 * rows.len() as u32).max(1000);
        bars_and_points(
            &canvas(&path, (width, 640), format),
            &path,
            [
                &title,
                shape_name,
                &format!("RMSE, training ({})", u.pressure()),
            ],
            &labels,
            chosen,
            &rmse,
            &aicc,
        )?;
        written.push(path);
    }
    Ok(written)
}

/// The selected polynomial's figures for one chamber.
struct FitFigures<'a> {
    file: &'a dyn Fn(String) -> PathBuf,
    format: PlotFormat,
    ds: &'a Dataset,
    chamber: u8,
    fit: &'a PolyFit,
    /// The model as the titles name it.
    name: String,
    /// The units of the axes.
    units: &'a DisplayUnits,
}

impl FitFigures<'_> {
    /// The held-out residual against volume, and its histogram (the training rows when nothing is
    /// held out).
    fn residuals(&self) -> Result<Vec<PathBuf>, Error> {
        let (ds, fit, name, u) = (self.ds, self.fit, &self.name, self.units);
        let held = if ds.heldout.iter().any(|&h| h) {
            ds.heldout()
        } else {
            ds.train()
        };
        let resid: Vec<(f64, f64)> = held
            .v
            .iter()
            .zip(&held.vdot)
            .zip(&held.p)
            .map(|((&v, &q), &p)| (u.v(v), u.p(p - fit.predict(v, q))))
            .collect();
        let (vol, pres) = (u.volume(), u.pressure());
        // 0.05 kPa bins; in another unit the round width nearest to 0.05 kPa (0.5 cmH2O).
        let bin = if u.is_canonical() {
            0.05
        } else {
            round_width(u.p(0.05))
        };
        let scatter_path = (self.file)(format!("ch{}-residual-vs-volume", self.chamber));
        scatter(
            &canvas(&scatter_path, (900, 600), self.format),
            &scatter_path,
            &format!("{name}: held-out residual vs volume"),
            (&format!("volume ({vol})"), &format!("P - P_hat ({pres})")),
            &[(resid.clone(), BLUE.mix(0.3))],
        )?;
        let hist_path = (self.file)(format!("ch{}-error-histogram", self.chamber));
        histogram(
            &canvas(&hist_path, (900, 600), self.format),
            &hist_path,
            &format!(
                "{name}: held-out error distribution ({} {pres} bins)",
                crate::figure::tick(bin)
            ),
            &resid.iter().map(|r| r.1).collect::<Vec<_>>(),
            (bin, &format!("error ({pres})")),
        )?;
        Ok(vec![scatter_path, hist_path])
    }

    /// The measured and predicted V-P curves over every row (thinned to [`MAX_POINTS`]).
    fn vp(&self) -> Result<PathBuf, Error> {
        let (ds, fit, name, u) = (self.ds, self.fit, &self.name, self.units);
        let all = ds.all();
        let step = all.len().div_ceil(MAX_POINTS).max(1);
        let measured: Vec<(f64, f64)> = all
            .v
            .iter()
            .zip(&all.p)
            .step_by(step)
            .map(|(&v, &p)| (u.v(v), u.p(p)))
            .collect();
        let predicted: Vec<(f64, f64)> = all
            .v
            .iter()
            .zip(&all.vdot)
            .step_by(step)
            .map(|(&v, &q)| (u.v(v), u.p(fit.predict(v, q))))
            .collect();
        let path = (self.file)(format!("ch{}-vp", self.chamber));
        scatter(
            &canvas(&path, (900, 600), self.format),
            &path,
            &format!("V-P curves: measured (grey) and {name} (blue)"),
            (
                &format!("volume ({})", u.volume()),
                &format!("pressure ({})", u.pressure()),
            ),
            &[
                (predicted, BLUE.mix(0.25)),
                (measured, RGBColor(60, 60, 60).mix(0.5)),
            ],
        )?;
        Ok(path)
    }
}

/// The width of the form 1, 2 or 5 × 10ᵏ nearest to `x` (> 0) on a log scale.
fn round_width(x: f64) -> f64 {
    let k = x.log10().floor();
    let m = x / 10f64.powf(k);
    let best = [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .min_by(|a: &f64, b: &f64| (m / a).ln().abs().total_cmp(&(m / b).ln().abs()))
        .unwrap_or(1.0);
    best * 10f64.powf(k)
}

/// A white canvas.
fn canvas(path: &Path, size: (u32, u32), format: PlotFormat) -> Canvas<'_> {
    let root = crate::figure::canvas(path, size, format);
    // Filling a fresh canvas cannot fail: it only writes to an in-memory buffer.
    root.fill(&WHITE).ok();
    root
}

fn bars_and_points(
    root: &Canvas<'_>,
    path: &Path,
    [title, xdesc, ydesc]: [&str; 3],
    labels: &[String],
    chosen: Option<usize>,
    bars: &[f64],
    points: &[f64],
) -> Result<(), Error> {
    let (top, bottom) = root.split_vertically(300);
    let n = labels.len();
    let ymax = bars.iter().cloned().fold(0.0, f64::max).max(1e-12) * 1.1;
    let fmt_label = |x: &f64| {
        let i = x.round();
        if (x - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < n {
            labels[i as usize].clone()
        } else {
            String::new()
        }
    };
    let bar_colour = |i: usize| match Some(i) == chosen {
        true => RGBColor(230, 140, 20),
        false => RGBColor(120, 120, 200),
    };
    {
        let mut c = ChartBuilder::on(&top)
            .caption(title, ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(8)
            .y_label_area_size(64)
            .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0.0..ymax)
            .map_err(|e| err(path, e))?;
        // The shapes are labelled once, under the AICc panel that shares this x axis.
        c.configure_mesh()
            .x_labels(0)
            .y_label_formatter(&|y| crate::figure::tick(*y))
            .y_desc(ydesc)
            .draw()
            .map_err(|e| err(path, e))?;
        c.draw_series(bars.iter().enumerate().map(|(i, &b)| {
            Rectangle::new(
                [(i as f64 - 0.35, 0.0), (i as f64 + 0.35, b)],
                bar_colour(i).filled(),
            )
        }))
        .map_err(|e| err(path, e))?;
    }
    let (lo, hi) = bounds(points.iter().copied());
    let mut c = ChartBuilder::on(&bottom)
        .margin(8)
        .x_label_area_size(48)
        .y_label_area_size(64)
        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, lo..hi)
        .map_err(|e| err(path, e))?;
    // One upright label per model under its own point: the canvas is 30 px per model wide.
    c.configure_mesh()
        .x_labels(n + 1)
        .x_label_formatter(&fmt_label)
        .x_label_style(("sans-serif", 12))
        .x_desc(xdesc)
        .y_desc("AICc")
        .y_label_formatter(&|y| crate::figure::tick(*y))
        .light_line_style(WHITE)
        .draw()
        .map_err(|e| err(path, e))?;
    if let Some(i) = chosen {
        c.draw_series(LineSeries::new(
            [(i as f64, lo), (i as f64, hi)],
            RGBColor(230, 140, 20).stroke_width(2),
        ))
        .map_err(|e| err(path, e))?;
    }
    c.draw_series(
        points
            .iter()
            .enumerate()
            .map(|(i, &a)| Circle::new((i as f64, a), 4, RED.filled())),
    )
    .map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))
}

fn scatter(
    root: &Canvas<'_>,
    path: &Path,
    title: &str,
    axes: (&str, &str),
    sets: &[(Vec<(f64, f64)>, RGBAColor)],
) -> Result<(), Error> {
    let (x0, x1) = bounds(sets.iter().flat_map(|s| s.0.iter().map(|p| p.0)));
    let (y0, y1) = bounds(sets.iter().flat_map(|s| s.0.iter().map(|p| p.1)));
    let mut c = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(path, e))?;
    c.configure_mesh()
        .x_desc(axes.0)
        .y_desc(axes.1)
        .x_label_formatter(&|x| crate::figure::tick(*x))
        .y_label_formatter(&|y| crate::figure::tick(*y))
        .draw()
        .map_err(|e| err(path, e))?;
    for (pts, color) in sets {
        let step = pts.len().div_ceil(MAX_POINTS).max(1);
        c.draw_series(
            pts.iter()
                .step_by(step)
                .map(|&p| Circle::new(p, 2, color.filled())),
        )
        .map_err(|e| err(path, e))?;
    }
    root.present().map_err(|e| err(path, e))
}

fn histogram(
    root: &Canvas<'_>,
    path: &Path,
    title: &str,
    xs: &[f64],
    (bin, xdesc): (f64, &str),
) -> Result<(), Error> {
    let (lo, hi) = bounds(xs.iter().copied());
    let nb = (((hi - lo) / bin).ceil() as usize).clamp(1, 2000);
    let mut counts = vec![0u32; nb];
    for &x in xs.iter().filter(|x| x.is_finite()) {
        counts[(((x - lo) / bin) as usize).min(nb - 1)] += 1;
    }
    let cmax = counts.iter().copied().max().unwrap_or(1).max(1) as f64;
    let mut c = ChartBuilder::on(root)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(lo..lo + nb as f64 * bin, 0.0..cmax * 1.05)
        .map_err(|e| err(path, e))?;
    c.configure_mesh()
        .x_desc(xdesc)
        .y_desc("count")
        .x_label_formatter(&|x| crate::figure::tick(*x))
        .y_label_formatter(&|y| crate::figure::tick(*y))
        .draw()
        .map_err(|e| err(path, e))?;
    c.draw_series(counts.iter().enumerate().map(|(i, &k)| {
        let x = lo + i as f64 * bin;
        Rectangle::new(
            [(x, 0.0), (x + bin, k as f64)],
            RGBColor(120, 120, 200).filled(),
        )
    }))
    .map_err(|e| err(path, e))?;
    root.present().map_err(|e| err(path, e))
}
