//! `vfp export LOG.csv`: identify each chamber's polynomial (or poly-AR) model and print it in the
//! forms the device loads: serial command lines (firmware `command.rs`:
//! `model <ch> begin <n> <m> <p> <v_off> <v_scale> <f_off> <f_scale>`, `model <ch> coef <i> <b>…`,
//! `model <ch> ar <i> <b>…`, `model <ch> commit`) and Rust constants for build-time defaults.
//!
//! Coefficients are the scaled-basis bᵢⱼ of [`model_core::poly::PolyModel`] in f32, printed with
//! Rust's shortest round-trip formatting so the device parses back exactly the exported values.

use super::{CliError, DataOpts};
use crate::dataset::Dataset;
use crate::poly::{self, Scaling, Xy};
use crate::polyar;
use model_core::poly::PolyModel;
use std::fmt::Write;
use std::path::PathBuf;

/// Most values on one `model … coef`/`ar` line (the firmware's `MAX_CHUNK`).
pub const CHUNK: usize = 8;

/// Export identified models for the device (serial command lines and Rust constants).
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// The actuation log (CSV, shared/data-format.md).
    pub log: PathBuf,
    #[command(flatten)]
    pub data: DataOpts,
    /// Highest power of v (default: the polynomial sweep's AICc selection).
    #[arg(long)]
    pub n: Option<usize>,
    /// Highest power of v̇ (default: the polynomial sweep's AICc selection).
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

/// Serial command lines that load `model` into chamber `ch`.
pub fn command_lines(ch: u8, model: &PolyModel) -> Vec<String> {
    let sh = model.shape();
    let sc = model.scaling();
    let mut out = vec![format!(
        "model {ch} begin {} {} {} {} {} {} {}",
        sh.n, sh.m, sh.p, sc.v_offset, sc.v_scale, sc.f_offset, sc.f_scale
    )];
    for (c, chunk) in model.scaled().chunks(CHUNK).enumerate() {
        let vals: Vec<String> = chunk.iter().map(|x| format!("{x:e}")).collect();
        out.push(format!("model {ch} coef {} {}", c * CHUNK, vals.join(" ")));
    }
    let ar: Vec<f32> = model.ar().iter().flatten().copied().collect();
    for (c, chunk) in ar.chunks(CHUNK).enumerate() {
        let vals: Vec<String> = chunk.iter().map(|x| format!("{x:e}")).collect();
        out.push(format!("model {ch} ar {} {}", c * CHUNK, vals.join(" ")));
    }
    out.push(format!("model {ch} commit"));
    out
}

/// Rust constants (shape, scaling, scaled coefficients, AR pairs) for chamber `ch`, with the line
/// that rebuilds the model.
pub fn rust_constants(ch: u8, model: &PolyModel, provenance: &str) -> String {
    let sh = model.shape();
    let sc = model.scaling();
    let f = |x: f32| format!("{x:e}");
    let mut s = String::new();
    let _ = writeln!(s, "// Chamber {ch}: {provenance}");
    let _ = writeln!(
        s,
        "// PolyModel::from_scaled(Shape::new(CH{ch}_SHAPE[0], CH{ch}_SHAPE[1], CH{ch}_SHAPE[2])?, &CH{ch}_COEF, &CH{ch}_AR, \
         Scaling::new(CH{ch}_SCALING[0], CH{ch}_SCALING[1], CH{ch}_SCALING[2], CH{ch}_SCALING[3])?)"
    );
    let _ = writeln!(
        s,
        "pub const CH{ch}_SHAPE: [u8; 3] = [{}, {}, {}];",
        sh.n, sh.m, sh.p
    );
    let _ = writeln!(
        s,
        "pub const CH{ch}_SCALING: [f32; 4] = [{}, {}, {}, {}];",
        f(sc.v_offset),
        f(sc.v_scale),
        f(sc.f_offset),
        f(sc.f_scale)
    );
    let coef: Vec<String> = model.scaled().iter().map(|&x| f(x)).collect();
    let _ = writeln!(
        s,
        "pub const CH{ch}_COEF: [f32; {}] = [{}];",
        coef.len(),
        coef.join(", ")
    );
    let ar: Vec<String> = model
        .ar()
        .iter()
        .map(|p| format!("[{}, {}]", f(p[0]), f(p[1])))
        .collect();
    let _ = writeln!(
        s,
        "pub const CH{ch}_AR: [[f32; 2]; {}] = [{}];",
        ar.len(),
        ar.join(", ")
    );
    s
}

/// The device model for one chamber's dataset: the requested (n, m) or the AICc selection of the
/// 49-model sweep, with `p` AR lags. Returns the model and a one-line provenance.
pub fn model_for(
    ds: &Dataset,
    n: Option<usize>,
    m: Option<usize>,
    p: usize,
    all_samples: bool,
) -> Result<(PolyModel, String), CliError> {
    let data = if all_samples { ds.all() } else { ds.train() };
    let all = ds.all();
    let sc = Scaling::from_data(&all.v, &all.vdot)?;
    let (n, m) = match (n, m) {
        (Some(n), Some(m)) => (n, m),
        (None, None) => {
            let entries = poly::sweep(Xy::from(&data), None, &sc, 7, 7)?;
            entries
                .iter()
                .filter_map(|e| e.as_ref().ok())
                .min_by(|a, b| a.train.aicc.total_cmp(&b.train.aicc))
                .map(|e| (e.n, e.m))
                .ok_or_else(|| {
                    CliError("no polynomial model could be fitted to these data".into())
                })?
        }
        _ => {
            return Err(CliError(
                "give both --n and --m, or neither (then the AICc selection is used)".into(),
            ))
        }
    };
    if p > model_core::poly::MAX_AR {
        return Err(CliError(format!(
            "--p {p}: the device supports AR orders 0..={}",
            model_core::poly::MAX_AR
        )));
    }
    if p == 0 {
        let fit = poly::fit(Xy::from(&data), n, m, Some(sc))?;
        let model = fit.to_model_core()?;
        let prov = format!(
            "n = {n}, m = {m}, RMSE {:.4} kPa on {} samples",
            fit.train.rmse, fit.train.n
        );
        Ok((model, prov))
    } else {
        let mut d = ds.clone();
        if all_samples {
            d.heldout.iter_mut().for_each(|h| *h = false);
        }
        let mut fits = polyar::sweep(&d, n, m, p, &sc)?;
        let fit = fits
            .pop()
            .ok_or_else(|| CliError("poly-AR sweep returned nothing".into()))??;
        let model = fit.to_model_core()?;
        let prov = format!(
            "n = {n}, m = {m}, p = {p}, RMSE {:.4} kPa on {} samples",
            fit.train.rmse, fit.train.n
        );
        Ok((model, prov))
    }
}

/// Runs `vfp export`.
pub fn run(args: &Args) -> Result<(), CliError> {
    let (_, datasets) = args.data.load(&args.log)?;
    let mut lines = Vec::new();
    let mut rust = String::new();
    for ds in &datasets {
        let (model, prov) = model_for(ds, args.n, args.m, args.p, args.all_samples)?;
        lines.extend(command_lines(ds.chamber, &model));
        rust.push_str(&rust_constants(
            ds.chamber,
            &model,
            &format!("{} ({prov})", args.log.display()),
        ));
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
