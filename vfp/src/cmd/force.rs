//! `vfp force --ident A.csv --test B.csv [--augmented]`: external force from pressure residuals
//! (paper §IV-C, Fig. 8); the method is [`sysid::diag::force`], with `--augmented`
//! [`sysid::board::force::estimate_augmented`] (the residual loop's models as the board runs them).

use super::stiffness::ShapeOpts;
use crate::opts::{DataOpts, OutputOpts};
use crate::plots::diag::{self as plot, Curve, Mark};
use crate::units::DisplayUnits;
use crate::Error;
use std::path::PathBuf;
use sysid::board::force::{estimate_augmented, AugmentedForceReport};
use sysid::diag::force::{estimate, ForceOptions, ForceReport, ForceTrace};

/// `vfp force`: external force from pressure residuals.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Force-free log to identify one model per chamber on.
    #[arg(long)]
    pub ident: PathBuf,
    /// Log to estimate the force on (with `force_n` for a comparison).
    #[arg(long)]
    pub test: PathBuf,
    /// Effective area per chamber in mm², one value for all or one per chamber (`22,22,22`).
    #[arg(long, value_delimiter = ',', default_value = "22")]
    pub area: Vec<f64>,
    #[command(flatten)]
    pub shape: ShapeOpts,
    /// Centred moving average over this many samples (1 = no filter).
    #[arg(long, default_value_t = 1)]
    pub smooth: usize,
    /// Seconds of the test log shown in the time plot (from 1 s before the first push, or from
    /// the start when the log has no force_n).
    #[arg(long, default_value_t = 10.0)]
    pub plot_window: f64,
    /// Estimate with the augmented models, as the board would: per chamber the residual loop
    /// (as `vfp diagnose`, baseline shape --n/--m) on the identification log, its model built as
    /// `vfp export --augmented` builds it (polynomial and effect chain), and the test log replayed
    /// through the firmware's own estimator (`vfp replay`). The report adds the effects each
    /// chamber's board ran and those that stay on the host.
    #[arg(long)]
    pub augmented: bool,
    #[command(flatten)]
    pub data: DataOpts,
    #[command(flatten)]
    pub out: OutputOpts,
}

impl Args {
    /// The estimation options, checked.
    pub fn options(&self) -> Result<ForceOptions, Error> {
        let shape = self.shape.shape()?;
        if !(self.area.len() == 1 || self.area.len() == 3)
            || self.area.iter().any(|a| !(a.is_finite() && *a > 0.0))
        {
            return Err(Error::Usage(format!(
                "--area {:?}: give one positive area in mm2 for all chambers or three (a,b,c)",
                self.area
            )));
        }
        if self.smooth == 0 {
            return Err(Error::Usage(
                "--smooth 0: the window is at least 1 sample".into(),
            ));
        }
        Ok(ForceOptions {
            shape,
            area: self.area.clone(),
            smooth: self.smooth,
        })
    }
}

/// Settings of the residual loop behind `--augmented` (those of `vfp diagnose`, the baseline
/// shape from --n/--m), checked.
pub fn loop_config(args: &Args) -> Result<sysid::residual::Config, Error> {
    if args.data.holdout_every < 2 {
        return Err(Error::Usage(format!(
            "--holdout-every {}: --augmented compares models on held-out cycles (2 or more)",
            args.data.holdout_every
        )));
    }
    let shape = args.shape.shape()?;
    Ok(sysid::residual::Config {
        n: shape.n,
        m: shape.m,
        progress: crate::progress::shown()
            .then_some(crate::progress::stages as sysid::progress::ProgressFn),
        ..sysid::residual::Config::default()
    })
}

/// Runs `vfp force`.
pub fn run(args: &Args) -> Result<(), Error> {
    let o = args.options()?;
    let cfg = args.augmented.then(|| loop_config(args)).transpose()?;
    let ident = args.data.load(&args.ident, None)?;
    let test = args.data.load(&args.test, None)?;
    let w = args.plot_window;
    let u = args.out.display_units(&args.data);
    match cfg {
        None => {
            let (report, trace) = estimate(&ident, &test, &o)?;
            args.out.emit(
                &report,
                |r| human(r, &u),
                |dir, f| plot_force(dir, f, &trace, w, &u),
            )
        }
        Some(cfg) => {
            let (report, trace) = estimate_augmented(&ident, &test, &o, &cfg)?;
            args.out.emit(
                &report,
                |r| human_augmented(r, &u),
                |dir, f| plot_force(dir, f, &trace, w, &u),
            )
        }
    }
}

/// The human report of `--augmented`: the bare report's text, then the board models.
pub fn human_augmented(r: &AugmentedForceReport, u: &DisplayUnits) -> String {
    let mut s = format!(
        "Augmented models as the board runs them (residual loop on {}, `vfp export \
         --augmented`'s model, the firmware's estimator over the test log; ident RMSE below is \
         the board model's held-out RMSE)\n",
        r.force.ident
    );
    for a in &r.augmented {
        let fx = if a.effects.is_empty() {
            "none (bare polynomial refitted)".to_string()
        } else {
            a.effects.join(", ")
        };
        s += &format!(
            "  chamber {}: effects on the board: {fx}; held-out RMSE {:.4} {} (baseline {:.4})\n",
            a.chamber,
            u.p(a.device_heldout_rmse_kpa),
            u.pressure(),
            u.p(a.baseline_heldout_rmse_kpa)
        );
        for d in &a.host_only {
            s += &format!(
                "    kept by the loop, not on the board: {} ({})\n",
                d.name, d.reason
            );
        }
    }
    if r.no_estimate > 0 {
        s += &format!(
            "  {} test instants without a board estimate (history filling or out of the model's \
             range) left out\n",
            r.no_estimate
        );
    }
    s + "\n" + &human(&r.force, u)
}

/// The human report (forces in mN, pressures in `u`).
pub fn human(r: &ForceReport, u: &DisplayUnits) -> String {
    let mn = |x: f64| x * 1e3;
    let mut s = format!(
        "External force from pressure residuals (polynomial n = {}, m = {} per chamber, \
         identified on {})\ntest log {}: {} instants at {:.1} Hz{}\n\n",
        r.shape.n,
        r.shape.m,
        r.ident,
        r.test,
        r.samples,
        r.sample_rate_hz,
        if r.unmatched > 0 {
            format!(
                " ({} dropped: a chamber had no sample at that time)",
                r.unmatched
            )
        } else {
            String::new()
        }
    );
    let p = u.pressure();
    s += &format!(
        "  chamber  area (mm2)  {:>16}  {:>16}  {:>19}\n",
        format!("ident RMSE ({p})"),
        format!("test noise ({p})"),
        format!("mean residual ({p})")
    );
    for c in &r.chambers {
        s += &format!(
            "  {:>7} {:>11.1} {:>17.4} {:>17.4} {:>20.4}\n",
            c.chamber,
            c.area_mm2,
            u.p(c.ident_rmse_kpa),
            u.p(c.test_noise_kpa),
            u.p(c.mean_residual_kpa)
        );
    }
    s += &format!("\nmean estimated force: {:.2} mN\n", mn(r.mean_force_n));
    match (r.mean_error_n, r.std_error_n, r.rmse_n) {
        (Some(m), Some(sd), Some(rm)) => {
            s += &format!(
                "error against force_n: {:.2} +/- {:.2} mN (mean +/- std), RMSE {:.2} mN \
                 (paper: 1.60 +/- 7.50 mN)\n",
                mn(m),
                mn(sd),
                mn(rm)
            )
        }
        _ => s += "no force_n column in the test log: no error statistics\n",
    }
    s += &format!(
        "\nWhat limits the accuracy: pressure noise times area, summed over {} chambers, is a \
         floor of {:.2} mN (sqrt(sum (A sigma)^2) with sigma from the test log's fourth \
         differences); with the identification RMSE instead of sigma (adds model misfit) it is \
         {:.2} mN.\n",
        r.chambers.len(),
        mn(r.noise_floor_n),
        mn(r.model_floor_n)
    );
    if r.smooth_samples > 1 {
        s += &format!(
            "Filter: centred moving average over {} samples divides white noise by sqrt({}) and \
             limits the bandwidth to {:.2} Hz (-3 dB) of the {:.1} Hz Nyquist band.\n",
            r.smooth_samples,
            r.smooth_samples,
            r.bandwidth_hz,
            r.sample_rate_hz / 2.0
        );
    } else {
        s += &format!(
            "No filter: full bandwidth up to Nyquist ({:.1} Hz); --smooth M trades noise for \
             bandwidth (about 0.443 fs/M Hz).\n",
            r.bandwidth_hz
        );
    }
    s
}

/// Fig. 8c (truth and estimate over time) and Fig. 8a (measured vs predicted pressure).
fn plot_force(
    dir: &std::path::Path,
    format: crate::figure::PlotFormat,
    tr: &ForceTrace,
    window: f64,
    u: &DisplayUnits,
) -> Result<PathBuf, Error> {
    let path = plot::target(dir, &format.file("diag-force"))?;
    let root = plot::canvas(&path, (1000, 760), format);
    let (top, bottom) = root.split_vertically(380);
    // Show the pushes: start 1 s before the reference force first rises (else at the start).
    let first = tr
        .truth
        .as_ref()
        .and_then(|f| f.iter().position(|&x| x > 0.0));
    let t0 = match first {
        Some(i) => tr.t[i] - 1.0,
        None => tr.t.first().copied().unwrap_or(0.0),
    };
    let keep: Vec<usize> = (0..tr.t.len())
        .filter(|&i| tr.t[i] >= t0 && tr.t[i] - t0 <= window)
        .collect();
    let mut curves = Vec::new();
    if let Some(truth) = &tr.truth {
        curves.push(Curve::new(
            "reference force_n",
            keep.iter().map(|&i| (tr.t[i], truth[i] * 1e3)).collect(),
            RGB_BLACK,
            Mark::Line,
        ));
    }
    curves.push(Curve::new(
        "estimate (residual x area, summed)",
        keep.iter().map(|&i| (tr.t[i], tr.est[i] * 1e3)).collect(),
        plot::color(3),
        Mark::Line,
    ));
    plot::panel(
        &top,
        &path,
        "external force",
        "time (s)",
        "force (mN)",
        &curves,
    )?;
    let mut pc = Vec::new();
    for (k, (c, (meas, pred))) in tr.pressures.iter().enumerate() {
        pc.push(Curve::new(
            format!("chamber {c} measured"),
            keep.iter().map(|&i| (tr.t[i], u.p(meas[i]))).collect(),
            plot::color(k),
            Mark::Dots,
        ));
        pc.push(Curve::new(
            format!("chamber {c} model"),
            keep.iter().map(|&i| (tr.t[i], u.p(pred[i]))).collect(),
            plot::color(k),
            Mark::Line,
        ));
    }
    plot::panel(
        &bottom,
        &path,
        "chamber pressures",
        "time (s)",
        &format!("pressure ({})", u.pressure()),
        &pc,
    )?;
    plot::finish(root, &path)?;
    Ok(path.clone())
}

const RGB_BLACK: plotters::style::RGBColor = plotters::style::RGBColor(0, 0, 0);
