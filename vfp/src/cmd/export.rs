//! `vfp export LOG.csv`: identify each chamber's polynomial (or poly-AR) model and print it in the
//! forms the device loads (serial command lines, Rust constants); see [`sysid::board::export`] for the
//! forms and the model choice, and [`sysid::board::augmented`] for `--augmented`.

use crate::opts::{effect_parser, LogInput};
use crate::Error;
use sysid::board::augmented::export_dataset;
use sysid::board::export::{augmented_report, board_lines, export_log, rust_constants};
use sysid::dataset::Dataset;
use sysid::poly;
use sysid::residual::{self, EffectKind};

/// Export identified models for the device (serial command lines and Rust constants).
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// The log, `--chamber` (default: every chamber) and the data options.
    #[command(flatten)]
    pub input: LogInput,
    /// Highest power of v (default: the shape `vfp identify` selects).
    #[arg(long)]
    pub n: Option<usize>,
    /// Highest power of v̇ (default: the shape `vfp identify` selects).
    #[arg(long)]
    pub m: Option<usize>,
    /// Autoregressive order (0..=5) of the exported model.
    #[arg(long, default_value_t = 0)]
    pub p: usize,
    /// What to print.
    #[arg(long, value_enum, default_value_t = Format::Both)]
    pub format: Format,
    /// Fit on all samples instead of the training cycles only.
    #[arg(long)]
    pub all_samples: bool,
    /// Export the model `vfp diagnose` ends with: run the residual loop on each chamber (baseline
    /// shape from --n/--m, default the selected shape), refit it with the kept effects the board
    /// can run (hysteresis, sensor and delivery lag, transport delay, backlash, leak, air
    /// compliance as `model <ch> effect …` lines of its effect chain; inertance L·v̈ as an AR(1)
    /// flow term, v̈ the backward difference at the log's frame interval), and name those it
    /// cannot with the reason. Comment
    /// lines (`//`, skipped by `vfp deploy`) give the held-out RMSE of the full augmented model, of
    /// the exported model as the device evaluates it, and of the baseline.
    #[arg(long)]
    pub augmented: bool,
    /// With --augmented: restrict the loop's candidate effects (repeatable; default: the whole
    /// library, as `vfp diagnose`).
    #[arg(long = "effect", value_parser = effect_parser(), requires = "augmented")]
    pub effects: Vec<EffectKind>,
    /// With --augmented: level of the loop's nested F-test (default 1e-3, as `vfp diagnose`).
    #[arg(long, requires = "augmented")]
    pub alpha: Option<f64>,
    /// With --augmented: smallest relative held-out RMSE gain for an effect to be kept (default
    /// 0.01, as `vfp diagnose`).
    #[arg(long, requires = "augmented")]
    pub min_gain: Option<f64>,
}

/// Output forms.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// Serial command lines only.
    Lines,
    /// Rust constants only.
    Rust,
    /// Both, lines first.
    Both,
}

/// Settings of the residual loop from the command line, checked.
fn loop_config(args: &Args, ds: &Dataset) -> Result<residual::Config, Error> {
    if args.p != 0 {
        return Err(Error::Msg(format!(
            "--p {}: the augmented export chooses its own AR terms (inertance becomes AR(1)); leave --p out",
            args.p
        )));
    }
    if args.all_samples {
        return Err(Error::Msg(
            "--all-samples: the augmented export compares models on held-out cycles; leave it out"
                .into(),
        ));
    }
    if args.input.data.holdout_every < 2 {
        return Err(Error::Msg(format!(
            "--holdout-every {}: the augmented export needs held-out cycles (2 or more)",
            args.input.data.holdout_every
        )));
    }
    let mut cfg = residual::Config::default();
    if let Some(a) = args.alpha {
        if !(a > 0.0 && a < 1.0) {
            return Err(Error::Msg(format!("--alpha {a}: must lie in (0, 1)")));
        }
        cfg.alpha = a;
    }
    if let Some(g) = args.min_gain {
        if !(0.0..1.0).contains(&g) {
            return Err(Error::Msg(format!("--min-gain {g}: must lie in [0, 1)")));
        }
        cfg.min_gain = g;
    }
    if !args.effects.is_empty() {
        cfg.candidates = args.effects.clone();
    }
    (cfg.n, cfg.m) = match (args.n, args.m) {
        (Some(n), Some(m))
            if (1..=poly::MAX_DEGREE).contains(&n) && (1..=poly::MAX_DEGREE).contains(&m) =>
        {
            (n, m)
        }
        (Some(n), Some(m)) => {
            return Err(Error::Msg(format!(
                "--n {n} --m {m}: the augmented export needs 1 ≤ n, m ≤ {}",
                poly::MAX_DEGREE
            )))
        }
        (None, None) => residual::select_shape(ds).unwrap_or((3, 2)),
        _ => {
            return Err(Error::Msg(
                "give both --n and --m, or neither (then the selected shape is used)".into(),
            ))
        }
    };
    Ok(cfg)
}

/// Runs `vfp export`.
pub fn run(args: &Args) -> Result<(), Error> {
    let data = args.input.load()?;
    let datasets = &data.datasets;
    let mut lines = Vec::new();
    let mut rust = String::new();
    for ds in datasets.iter().filter(|_| args.augmented) {
        let cfg = loop_config(args, ds)?;
        let wrap = |e: &dyn std::fmt::Display| {
            Error::Msg(format!(
                "{}, chamber {}: {e}",
                data.path.display(),
                ds.chamber
            ))
        };
        let x = export_dataset(ds, &cfg).map_err(|e| wrap(&e))?;
        let report = augmented_report(&data.path, ds.chamber, &x);
        for l in report
            .iter()
            .filter(|l| l.starts_with("NO") || l.starts_with("WARNING"))
        {
            eprintln!("chamber {}: {l}", ds.chamber);
        }
        let comments: Vec<String> = report.iter().map(|l| format!("// {l}")).collect();
        lines.extend(comments.iter().cloned());
        lines.extend(board_lines(ds.chamber, &x.device.board_model()));
        if args.format == Format::Rust {
            // With `both` the same comments already head the lines.
            for c in &comments {
                rust.push_str(c);
                rust.push('\n');
            }
        }
        let prov = format!(
            "{} (augmented: n = {}, m = {}, p = {}, held-out RMSE {:.4} kPa on the device)",
            data.path.display(),
            x.diagnosis.baseline.n,
            x.diagnosis.baseline.m,
            x.device.model.shape().p,
            x.rmse.device
        );
        rust.push_str(&rust_constants(ds.chamber, &x.device.model, &prov));
        for e in x.device.chain.effects() {
            // The constants hold the polynomial; the chain travels as protocol lines.
            let vals: Vec<String> = e.params().iter().map(|v| format!("{v:e}")).collect();
            rust.push_str(&format!(
                "// CH{} chain (not in these constants; load with the lines): model {} effect {} {}\n",
                ds.chamber,
                ds.chamber,
                e.kind().name(),
                vals.join(" ")
            ));
        }
    }
    if !args.augmented {
        for e in export_log(&data, args.n, args.m, args.p, args.all_samples)? {
            if let Some(w) = &e.warning {
                eprintln!("chamber {}: {w}", e.chamber);
                lines.push(format!("// chamber {}: {w}", e.chamber));
                if args.format == Format::Rust {
                    rust.push_str(&format!("// {w}\n"));
                }
            }
            lines.extend(e.lines);
            rust.push_str(&e.rust);
        }
    }
    if matches!(args.format, Format::Lines | Format::Both) {
        for l in &lines {
            println!("{l}");
        }
    }
    if matches!(args.format, Format::Rust | Format::Both) {
        if args.format == Format::Both {
            println!();
        }
        print!("{rust}");
    }
    Ok(())
}
