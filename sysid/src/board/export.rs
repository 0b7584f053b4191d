//! Export (behind `vfp export`): each chamber's polynomial (or poly-AR) model in the forms the
//! device loads: serial command lines (firmware `command.rs`:
//! `model <ch> begin <n> <m> <p> <v_off> <v_scale> <f_off> <f_scale>`, `model <ch> coef <i> <b>…`,
//! `model <ch> ar <i> <b>…`, `model <ch> commit`) and Rust constants for build-time defaults.
//!
//! Coefficients are the scaled-basis bᵢⱼ of [`model_core::poly::PolyModel`] in f32, printed with
//! Rust's shortest round-trip formatting so the device parses back exactly the exported values.
//!
//! The augmented export (`vfp export --augmented`) first runs the residual loop of `vfp diagnose` on
//! each chamber and exports the model it ends with ([`crate::board::augmented`]): terms the device can run are folded into the
//! exported model (inertance as an AR(1) flow term), the others are named with the reason, and
//! `//` comment lines above each chamber's model state the held-out RMSE of the full augmented
//! model, of the exported model as the device evaluates it, and of the baseline. `vfp deploy`
//! skips those comments.

use crate::board::augmented::AugmentedExport;
use crate::dataset::Dataset;
use crate::poly::{self, Scaling, Xy};
use crate::polyar;
use model_core::poly::PolyModel;
use std::fmt::Write;
use std::path::Path;

/// Why a model could not be exported: one sentence naming the option or the fit at fault.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ExportError(pub String);

macro_rules! from_display {
    ($($t:ty),*) => {$(
        impl From<$t> for ExportError {
            fn from(e: $t) -> Self {
                ExportError(e.to_string())
            }
        }
    )*};
}
from_display!(
    crate::poly::PolyError,
    crate::metrics::MetricsError,
    model_core::ModelError
);

/// Most values on one `model … coef`/`ar` line (the firmware's `MAX_CHUNK`).
pub const CHUNK: usize = 8;

/// Serial command lines that load `model` into chamber `ch`.
pub fn command_lines(ch: u8, model: &PolyModel) -> Vec<String> {
    board_lines(ch, &firmware::store::Model::from(model))
}

/// Serial command lines that load the board's `full` model (polynomial and effect chain) into
/// chamber `ch`: [`command_lines`]' lines with the chain's `model <ch> effect <name> <param>…`
/// lines before `commit` (evaluation order, every value in shortest round-trip form).
pub fn board_lines(ch: u8, full: &firmware::store::Model) -> Vec<String> {
    let model = &full.poly;
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
    for e in full.chain.effects() {
        let vals: Vec<String> = e.params().iter().map(|x| format!("{x:e}")).collect();
        out.push(format!(
            "model {ch} effect {} {}",
            e.kind().name(),
            vals.join(" ")
        ));
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

/// The device model for one chamber's dataset: the requested (n, m), or by default the model
/// `vfp identify` selects ([`crate::select`]: the fewest parameters within one standard error of
/// the best cycle-blocked cross-validated error, then its raw terms reduced by the same rule; with
/// AR lags, `p` > 0, the full shape) **if the device evaluates it faithfully** (its f32 loss,
/// [`f32_loss`], at most a tenth of the fit's own RMSE; high degrees fitted on a few flow levels
/// have cancelling coefficients that f32 cannot hold). Otherwise the full shape, then the next
/// shapes in [`crate::select::ranked`] order, and the provenance names what was passed over and by
/// how much it would have lost.
pub fn model_for(
    ds: &Dataset,
    n: Option<usize>,
    m: Option<usize>,
    p: usize,
    all_samples: bool,
) -> Result<Exported, ExportError> {
    if p > model_core::poly::MAX_AR {
        return Err(ExportError(format!(
            "--p {p}: the device supports AR orders 0..={}",
            model_core::poly::MAX_AR
        )));
    }
    let all = ds.all();
    let sc = Scaling::from_data(&all.v, &all.vdot)?;
    match (n, m) {
        (Some(n), Some(m)) => build(ds, n, m, p, all_samples, sc),
        (None, None) => {
            let (_, bm) = crate::select::block_moments(ds, &sc)?;
            let ok: Vec<_> = bm
                .sweep(poly::MAX_DEGREE, poly::MAX_DEGREE)
                .into_iter()
                .flatten()
                .collect();
            let ranked = crate::select::ranked(&ok);
            let reduced = match (p, ranked.first()) {
                (0, Some(first)) => bm.reduce_terms(first.n, first.m, &ok).ok(),
                _ => None,
            };
            let mut skipped = String::new();
            if let Some(red) = reduced.filter(|r| r.nu < r.active.len()) {
                let e = build_terms(ds, &red, all_samples)?;
                let loss = f32_loss(&e, &ds.v, &ds.vdot, &ds.p);
                if loss.rms <= F32_LOSS_LIMIT * loss.model_rmse {
                    return Ok(e);
                }
                skipped = format!(
                    "; the selection's {} of {} terms passed over: in f32 on the device they would add {:.4} kPa RMS to their {:.4} kPa fit error",
                    red.nu,
                    red.active.len(),
                    loss.rms,
                    loss.model_rmse
                );
            }
            let order: Vec<(usize, usize)> = ranked.iter().map(|s| (s.n, s.m)).collect();
            let (mut e, passed_over) = first_carried(ds, &order, p, all_samples, sc)?;
            e.prov.push_str(&skipped);
            if let Some((n0, m0, l0)) = passed_over {
                e.prov.push_str(&format!(
                    "; the selection's choice (n = {n0}, m = {m0}) passed over: in f32 on the device it would add {:.4} kPa RMS to its {:.4} kPa fit error",
                    l0.rms, l0.model_rmse
                ));
            }
            Ok(e)
        }
        _ => Err(ExportError(
            "give both --n and --m, or neither (then the selection of `vfp identify` is used)"
                .into(),
        )),
    }
}

/// The first shape of `order` whose f32 loss ([`f32_loss`] on all of `ds`'s samples) is at most
/// [`F32_LOSS_LIMIT`] of its fit error, with the first shape passed over (if any) and its loss.
/// `Err` when none passes.
#[allow(clippy::type_complexity)]
pub fn first_carried(
    ds: &Dataset,
    order: &[(usize, usize)],
    p: usize,
    all_samples: bool,
    sc: Scaling,
) -> Result<(Exported, Option<(usize, usize, F32Loss)>), ExportError> {
    let mut passed_over: Option<(usize, usize, F32Loss)> = None;
    for &(n, m) in order {
        let e = build(ds, n, m, p, all_samples, sc)?;
        let loss = f32_loss(&e, &ds.v, &ds.vdot, &ds.p);
        if loss.rms <= F32_LOSS_LIMIT * loss.model_rmse {
            return Ok((e, passed_over));
        }
        passed_over.get_or_insert((n, m, loss));
    }
    Err(ExportError(
        "no polynomial shape of the sweep is evaluated by the device's f32 arithmetic within a tenth of its fit error; give --n and --m"
            .into(),
    ))
}

/// Most f32 loss, as a fraction of the fit's RMSE, the default shape selection accepts.
pub const F32_LOSS_LIMIT: f64 = 0.1;

/// Fits shape (n, m, p) on the training cycles (or all samples) with scaling `sc` and rounds it to
/// the device's form.
fn build(
    ds: &Dataset,
    n: usize,
    m: usize,
    p: usize,
    all_samples: bool,
    sc: Scaling,
) -> Result<Exported, ExportError> {
    let data = if all_samples { ds.all() } else { ds.train() };
    if p == 0 {
        let fit = poly::fit(Xy::from(&data), n, m, Some(sc))?;
        let model = fit.to_model_core()?;
        let prov = format!(
            "n = {n}, m = {m}, RMSE {:.4} kPa on {} samples",
            fit.train.rmse, fit.train.n
        );
        Ok(Exported::polynomial(model, prov, &fit))
    } else {
        let mut d = ds.clone();
        if all_samples {
            d.heldout.iter_mut().for_each(|h| *h = false);
        }
        let mut fits = polyar::sweep(&d, n, m, p, &sc)?;
        let fit = fits
            .pop()
            .ok_or_else(|| ExportError("poly-AR sweep returned nothing".into()))??;
        let model = fit.to_model_core()?;
        let prov = format!(
            "n = {n}, m = {m}, p = {p}, RMSE {:.4} kPa on {} samples",
            fit.train.rmse, fit.train.n
        );
        Ok(Exported {
            model,
            prov,
            power: fit.power(),
            ar: fit.ar_scaled(),
            scaling: fit.scaling,
        })
    }
}

/// Fits the selection's reduced model (the raw terms `red.active` of its shape, [`poly::fit_terms`])
/// on the training cycles (or all samples) and rounds it to the device's form.
fn build_terms(
    ds: &Dataset,
    red: &crate::select::Reduction,
    all_samples: bool,
) -> Result<Exported, ExportError> {
    let data = if all_samples { ds.all() } else { ds.train() };
    let fit = poly::fit_terms(Xy::from(&data), red.n, red.m, &red.active)?;
    let model = fit.to_model_core()?;
    let prov = format!(
        "n = {}, m = {}, {} of {} terms (the selection's reduction), RMSE {:.4} kPa on {} samples",
        red.n,
        red.m,
        red.nu,
        red.active.len(),
        fit.train.rmse,
        fit.train.n
    );
    Ok(Exported::polynomial(model, prov, &fit))
}

/// An exported model with the f64 fit it was rounded from.
#[derive(Clone, Debug)]
pub struct Exported {
    /// The model as the device stores it (f32).
    pub model: PolyModel,
    /// One-line provenance.
    pub prov: String,
    /// The fit's scaled power-basis coefficients (f64, index i·(m+1)+j).
    pub power: Vec<f64>,
    /// The fit's scaled AR pairs (f64).
    pub ar: Vec<[f64; 2]>,
    /// The fit's scaling (f64).
    pub scaling: Scaling,
}

impl Exported {
    /// A polynomial without AR terms, rounded to `model`, with the f64 `fit` it came from.
    fn polynomial(model: PolyModel, prov: String, fit: &poly::PolyFit) -> Exported {
        Exported {
            model,
            prov,
            power: fit.power.clone(),
            ar: Vec::new(),
            scaling: fit.scaling,
        }
    }
}

/// What the device's f32 arithmetic and storage lose against the f64 fit on a log.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct F32Loss {
    /// RMS over the samples of P̂ as the firmware computes it (f32 inputs, coefficients and
    /// arithmetic, [`PolyModel::eval_ar`] with its history) minus the f64 fit's P̂ (kPa).
    pub rms: f64,
    /// RMSE of the f64 fit against the measured pressure on the same samples (kPa): the scale
    /// to judge `rms` by.
    pub model_rmse: f64,
    /// Samples compared (the first p have no AR history).
    pub samples: usize,
}

/// Evaluates an exported model along a log twice: as the firmware does, and in f64 from the fit
/// it was rounded from, and returns the RMS difference. A polynomial whose coefficients cancel
/// (Σ|b| ≫ |P|, typical of high degrees fitted on a few flow levels) can lose in f32 far more
/// than its f64 fit error shows.
pub fn f32_loss(e: &Exported, v: &[f64], vdot: &[f64], p: &[f64]) -> F32Loss {
    let sh = e.model.shape();
    let (n, m) = (sh.n as usize, sh.m as usize);
    let mut hist = model_core::poly::ArHistory::new();
    let (mut d2, mut e2, mut count) = (0.0, 0.0, 0usize);
    for k in 0..v.len().min(vdot.len()).min(p.len()) {
        let (v32, q32) = (v[k] as f32, vdot[k] as f32);
        if let Ok(dev) = e.model.eval_ar(v32, q32, &hist) {
            let (x, y) = e.scaling.apply(v[k], vdot[k]);
            let mut acc = 0.0;
            for j in (0..=m).rev() {
                let mut qj = 0.0;
                for i in (0..=n).rev() {
                    qj = qj * x + e.power[i * (m + 1) + j];
                }
                acc = acc * y + qj;
            }
            for (lag, pair) in e.ar.iter().enumerate() {
                let (xl, yl) = e.scaling.apply(v[k - lag - 1], vdot[k - lag - 1]);
                acc += pair[0] * xl + pair[1] * yl;
            }
            d2 += (f64::from(dev.p) - acc).powi(2);
            e2 += (p[k] - acc).powi(2);
            count += 1;
        }
        hist.push(v32, q32);
    }
    let c = count.max(1) as f64;
    F32Loss {
        rms: (d2 / c).sqrt(),
        model_rmse: (e2 / c).sqrt(),
        samples: count,
    }
}

/// A warning when the board's own command parser (`firmware::command`, through
/// [`crate::board::deploy::parse_lines`]) refuses `lines`: a log far from a syringe rig's scales (a
/// ventilator's flows of 10⁵–10⁶ mm³/s) gives a scaling beyond the bounds its commands accept.
fn board_refusal(lines: &[String]) -> Option<String> {
    crate::board::deploy::parse_lines(&lines.join("\n"), "export").err().map(|e| {
        format!(
            "WARNING: the board would refuse these lines ({e}); its commands take volumes within ±1e6 mm³ and flows within ±1e4 mm³/s, so they are for the record only"
        )
    })
}

/// A warning when the device's f32 loss exceeds a tenth of the model's own error on the log.
pub fn f32_warning(e: &Exported, ds: &Dataset) -> Option<String> {
    let r = f32_loss(e, &ds.v, &ds.vdot, &ds.p);
    let sum_b: f32 = e.model.scaled().iter().map(|b| b.abs()).sum();
    (r.rms > F32_LOSS_LIMIT * r.model_rmse).then(|| {
        format!(
            "WARNING: f32 evaluation on the device adds {:.4} kPa RMS to this model's {:.4} kPa: its coefficients (Σ|b| = {sum_b:.3e}) cancel beyond f32 precision; a smaller --n/--m keeps the device accurate",
            r.rms, r.model_rmse
        )
    })
}

/// The account of one chamber's augmented export, one sentence per line (printed as `//` comments).
pub fn augmented_report(log: &Path, chamber: u8, x: &AugmentedExport) -> Vec<String> {
    let d = &x.diagnosis;
    let r = &x.rmse;
    let mut out = vec![format!(
        "vfp export --augmented {}, chamber {chamber}: baseline polynomial n = {}, m = {}",
        log.display(),
        d.baseline.n,
        d.baseline.m
    )];
    let kept: Vec<&str> = d.effects.iter().map(|e| e.name).collect();
    if kept.is_empty() {
        out.push(
            "the residual loop kept no effect: the exported model is the baseline polynomial"
                .into(),
        );
    } else {
        out.push(format!("the residual loop kept: {}", kept.join(", ")));
    }
    for c in &x.carried {
        out.push(format!(
            "on the device: {} = {:.4e} {} ({})",
            c.name, c.value, c.unit, c.how
        ));
    }
    for e in &x.dropped {
        out.push(format!("NOT on the device: {} ({})", e.name, e.reason));
    }
    if x.nothing_carried() {
        out.push(format!(
            "NONE of the kept effects can run on the device: the exported model is the baseline polynomial refitted on the training cycles, not the augmented model; on the device it gives {:.4} kPa held-out RMSE where the augmented model gives {:.4} kPa",
            r.device, r.augmented
        ));
    }
    out.push(format!(
        "held-out RMSE: (a) full augmented model {:.4} kPa{}; (b) exported model as the device evaluates it (f32) {:.4} kPa ({:.4} kPa in f64, {} samples); (c) baseline {:.4} kPa",
        r.augmented,
        if d.final_model.uses_measured_pressure {
            " (uses measured pressure as a scheduling input)"
        } else {
            ""
        },
        r.device,
        r.device_f64,
        r.device_samples,
        r.baseline
    ));
    if !x.device.chain.is_empty() && r.device > 1.05 * r.device_f64 + 1e-3 {
        out.push(format!(
            "NOTE: the board's chain is causal (its lags and delay do not look a frame ahead as the loop's do) and f32: on the device it costs {:.4} kPa over the loop's form of the same model",
            r.device - r.device_f64
        ));
    } else if r.device > 1.05 * r.device_f64 + 1e-3 {
        let sum_b: f32 = x.device.model.scaled().iter().map(|b| b.abs()).sum();
        out.push(format!(
            "WARNING: f32 evaluation on the device costs {:.4} kPa: the coefficients (Σ|b| = {sum_b:.3e}) cancel beyond f32 precision; a smaller --n/--m keeps the device accurate",
            r.device - r.device_f64
        ));
    }
    if x.device.host.inertance.is_some() {
        let frame_s = 1.0 / f64::from(firmware::app::Config::default().frame_hz);
        if (x.device.host.dt - frame_s).abs() > 0.01 * frame_s {
            out.push(format!(
                "WARNING: the log's frame interval {:.4} s differs from the firmware's default {:.4} s; the AR(1) inertance term is exact only at {:.4} s",
                x.device.host.dt, frame_s, x.device.host.dt
            ));
        }
    }
    out
}

/// One chamber's plain (not augmented) export: what `vfp export` prints for it.
#[derive(Clone, Debug, PartialEq)]
pub struct ChamberExport {
    /// The chamber.
    pub chamber: u8,
    /// The f32 warning ([`f32_warning`]), when there is one.
    pub warning: Option<String>,
    /// The serial command lines ([`command_lines`]).
    pub lines: Vec<String>,
    /// The Rust constants ([`rust_constants`]) with the log and the model's provenance.
    pub rust: String,
}

/// The plain export of every dataset of a log ([`model_for`] with these settings, per chamber).
pub fn export_log(
    data: &crate::dataset::LogData,
    n: Option<usize>,
    m: Option<usize>,
    p: usize,
    all_samples: bool,
) -> Result<Vec<ChamberExport>, ExportError> {
    data.datasets
        .iter()
        .map(|ds| {
            let e = model_for(ds, n, m, p, all_samples)?;
            let lines = command_lines(ds.chamber, &e.model);
            let warnings: Vec<String> = [f32_warning(&e, ds), board_refusal(&lines)]
                .into_iter()
                .flatten()
                .collect();
            Ok(ChamberExport {
                chamber: ds.chamber,
                warning: (!warnings.is_empty()).then(|| warnings.join("; ")),
                lines,
                rust: rust_constants(
                    ds.chamber,
                    &e.model,
                    &format!("{} ({})", data.name(), e.prov),
                ),
            })
        })
        .collect()
}
