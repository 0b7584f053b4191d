//! SVG figures of `vfp identify --plots DIR` (plotters' SVG backend: no fonts needed):
//!
//! - `ch<c>-<family>-rmse-aicc.svg`: RMSE bars and AICc points per model (Figs. 2-4);
//! - `ch<c>-residual-vs-volume.svg`: held-out residuals of the selected polynomial against v (Fig. 5a);
//! - `ch<c>-error-histogram.svg`: its error distribution, 0.05 kPa bins (Fig. 5b);
//! - `ch<c>-vp.svg`: measured and predicted V-P curves (Fig. 1c).

use crate::Error;
use plotters::prelude::*;
use std::path::Path;
use sysid::dataset::Dataset;
use sysid::identify::{ChamberReport, Family};

fn err(path: &Path, e: impl std::fmt::Display) -> Error {
    Error::Msg(format!("{}: cannot write figure: {e}", path.display()))
}

fn bounds(xs: impl Iterator<Item = f64>) -> (f64, f64) {
    crate::figure::padded_range(xs)
}

/// Writes every figure for one chamber into `dir` (created if needed).
pub fn write_all(dir: &Path, ds: &Dataset, rep: &ChamberReport) -> Result<(), Error> {
    std::fs::create_dir_all(dir).map_err(|e| err(dir, e))?;
    for fam in Family::ALL {
        let rows: Vec<_> = rep.models.iter().filter(|m| m.family == fam).collect();
        if rows.is_empty() {
            continue;
        }
        let path = dir.join(format!("ch{}-{}-rmse-aicc.svg", rep.chamber, fam.name()));
        let labels: Vec<String> = rows.iter().map(|r| r.shape()).collect();
        let rmse: Vec<f64> = rows.iter().map(|r| r.rmse).collect();
        let aicc: Vec<f64> = rows.iter().map(|r| r.aicc).collect();
        bars_and_points(
            &path,
            &format!("{}: RMSE (bars) and AICc (red)", fam.name()),
            &labels,
            &rmse,
            &aicc,
        )?;
    }
    let Some(fit) = &rep.poly_fit else {
        return Ok(());
    };
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
        .map(|((&v, &q), &p)| (v, p - fit.predict(v, q)))
        .collect();
    let name = format!("poly ({}, {})", fit.n, fit.m);
    scatter(
        &dir.join(format!("ch{}-residual-vs-volume.svg", rep.chamber)),
        &format!("{name}: held-out residual vs volume"),
        ("volume (mm3)", "P - P_hat (kPa)"),
        &[(resid.clone(), BLUE.mix(0.3))],
    )?;
    histogram(
        &dir.join(format!("ch{}-error-histogram.svg", rep.chamber)),
        &format!("{name}: held-out error distribution (0.05 kPa bins)"),
        &resid.iter().map(|r| r.1).collect::<Vec<_>>(),
        0.05,
    )?;
    let all = ds.all();
    let step = (all.len() / 20_000).max(1);
    let measured: Vec<(f64, f64)> = all
        .v
        .iter()
        .zip(&all.p)
        .step_by(step)
        .map(|(&v, &p)| (v, p))
        .collect();
    let predicted: Vec<(f64, f64)> = all
        .v
        .iter()
        .zip(&all.vdot)
        .step_by(step)
        .map(|(&v, &q)| (v, fit.predict(v, q)))
        .collect();
    scatter(
        &dir.join(format!("ch{}-vp.svg", rep.chamber)),
        &format!("V-P curves: measured (grey) and {name} (blue)"),
        ("volume (mm3)", "pressure (kPa)"),
        &[
            (measured, RGBColor(120, 120, 120).mix(0.3)),
            (predicted, BLUE.mix(0.3)),
        ],
    )
}

fn bars_and_points(
    path: &Path,
    title: &str,
    labels: &[String],
    bars: &[f64],
    points: &[f64],
) -> Result<(), Error> {
    let root = crate::figure::svg(path, (1000, 640));
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (top, bottom) = root.split_vertically(340);
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
    {
        let mut c = ChartBuilder::on(&top)
            .caption(title, ("sans-serif", 18))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(60)
            .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0.0..ymax)
            .map_err(|e| err(path, e))?;
        c.configure_mesh()
            .x_labels(n.min(50))
            .x_label_formatter(&fmt_label)
            .y_desc("RMSE (kPa)")
            .draw()
            .map_err(|e| err(path, e))?;
        c.draw_series(bars.iter().enumerate().map(|(i, &b)| {
            Rectangle::new(
                [(i as f64 - 0.35, 0.0), (i as f64 + 0.35, b)],
                RGBColor(120, 120, 200).filled(),
            )
        }))
        .map_err(|e| err(path, e))?;
    }
    let (lo, hi) = bounds(points.iter().copied());
    let mut c = ChartBuilder::on(&bottom)
        .margin(8)
        .x_label_area_size(30)
        .y_label_area_size(60)
        .build_cartesian_2d(-0.5f64..n as f64 - 0.5, lo..hi)
        .map_err(|e| err(path, e))?;
    c.configure_mesh()
        .x_labels(n.min(50))
        .x_label_formatter(&fmt_label)
        .y_desc("AICc")
        .y_label_formatter(&|y| format!("{y:.3e}"))
        .draw()
        .map_err(|e| err(path, e))?;
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
    path: &Path,
    title: &str,
    axes: (&str, &str),
    sets: &[(Vec<(f64, f64)>, RGBAColor)],
) -> Result<(), Error> {
    let root = crate::figure::svg(path, (900, 600));
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (x0, x1) = bounds(sets.iter().flat_map(|s| s.0.iter().map(|p| p.0)));
    let (y0, y1) = bounds(sets.iter().flat_map(|s| s.0.iter().map(|p| p.1)));
    let mut c = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(|e| err(path, e))?;
    c.configure_mesh()
        .x_desc(axes.0)
        .y_desc(axes.1)
        .draw()
        .map_err(|e| err(path, e))?;
    for (pts, color) in sets {
        let step = (pts.len() / 20_000).max(1);
        c.draw_series(
            pts.iter()
                .step_by(step)
                .map(|&p| Circle::new(p, 1, color.filled())),
        )
        .map_err(|e| err(path, e))?;
    }
    root.present().map_err(|e| err(path, e))
}

fn histogram(path: &Path, title: &str, xs: &[f64], bin: f64) -> Result<(), Error> {
    let root = crate::figure::svg(path, (900, 600));
    root.fill(&WHITE).map_err(|e| err(path, e))?;
    let (lo, hi) = bounds(xs.iter().copied());
    let nb = (((hi - lo) / bin).ceil() as usize).clamp(1, 2000);
    let mut counts = vec![0u32; nb];
    for &x in xs.iter().filter(|x| x.is_finite()) {
        counts[(((x - lo) / bin) as usize).min(nb - 1)] += 1;
    }
    let cmax = counts.iter().copied().max().unwrap_or(1).max(1) as f64;
    let mut c = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 18))
        .margin(10)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(lo..lo + nb as f64 * bin, 0.0..cmax * 1.05)
        .map_err(|e| err(path, e))?;
    c.configure_mesh()
        .x_desc("error (kPa)")
        .y_desc("count")
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
