//! The augmented model on the device (`vfp export --augmented`): the model the residual loop ends
//! with, carried into the firmware's [`PolyModel`] wherever its terms can run there, and an honest
//! account of what cannot.
//!
//! # What the device can evaluate
//! The firmware evaluates (model-core, paper Table II "autoregressive multivariate polynomial")
//!
//! ```text
//! P̂(t) = Σ_kl b_kl x(t)^k y(t)^l + Σ_{k=1..p} ( b_k1 x(t−k) + b_k2 y(t−k) ),
//! x = (v − v_o)/v_s,  y = (v̇ − f_o)/f_s,
//! ```
//!
//! i.e. a polynomial in the present (v, v̇) plus terms *linear* in past inputs, and around it the
//! effect chain (`model_core::chain`: hysteresis, sensor and delivery lag, transport delay,
//! backlash, leak, air compliance, … in a causal `f32` form, at most
//! [`model_core::chain::MAX_EFFECTS`] of them). Each effect says whether the board can run it
//! ([`crate::residual::EffectModel::device_support`]) and, for a chain effect, its parameters in the
//! chain's form ([`crate::residual::EffectModel::device_params`], in the effect's own file); inertance is
//! folded into the polynomial (below). Effects tied to the log's clock (ripple in time, offset
//! and volume drift) and pump ripple stay on the host and are listed by name with the reason.
//!
//! # The chain's effects
//! The device model is refitted with the kept chain effects in the board's form (same design,
//! the polynomial's scaling rounded to `f32` first), so the polynomial and the effects'
//! coefficients (the hysteresis gap) are fitted together; the chain then carries θ and those
//! coefficients. The chain's effects are causal where the loop's may look a frame or two ahead
//! (Akima slopes, sub-frame play on frame means), so the lags' τ is searched again in the
//! board's form (`device_form`); the exported model's error is measured as the board computes
//! it, by running the firmware's estimator over the log ([`crate::board::replay`]), and reported next
//! to the loop's.
//!
//! # Inertance as an AR(1) term
//! The augmented export carries inertance in the board's chain (`L·v̈` with v̈ the end slope of
//! the volume's cubic over the last frame, `signal::acceleration_causal`, refitted in that form:
//! on host-sim its held-out error on the board is within 0.4 % of the loop's). [`device_model`]
//! can instead fold it into the polynomial, for a model without a chain:
//! the loop's inertance term is `L·v̈` with v̈ a smoothed (Hermite or three-point) derivative, which
//! looks one sample ahead. The device only has the past, so it takes the backward difference
//! `v̈(t) ≈ (v̇(t) − v̇(t−1))/Δt` at its frame interval Δt. With `v̇ = f_o + f_s·y`,
//!
//! ```text
//! L·(v̇(t) − v̇(t−1))/Δt = γ·y(t) − γ·y(t−1),   γ = L·f_s/Δt,
//! ```
//!
//! (the offsets cancel), which is exactly `b_01 += γ` (the v̇-linear coefficient) plus the AR(1)
//! pair `[b_11, b_12] = [0, −γ]`. The device model is therefore *refitted* with that
//! backward-difference column in place of the loop's v̈, on the same training rows, so the model
//! fitted and the model exported are one and the same function (the round trip is tested to
//! float precision); effects the device cannot run are left out of this refit rather than
//! truncated from a joint fit, which would leave the remaining coefficients biased.
//!
//! # Errors reported
//! Held-out RMSE of (a) the full augmented model as the loop fitted it, (b) the exported model
//! evaluated in f32 exactly as the firmware does (history of past samples included) and (c) the
//! baseline polynomial, so the cost of what stays on the host is visible.

use model_core::poly::PolyModel;

use crate::board::replay;
use crate::dataset::median_dt;

use crate::residual::effects::{Effect, Prepared};
use crate::residual::search::{brent, fit_stage, sse_of, Stage};
use crate::residual::{diagnose, Config, DiagnoseError, Diagnosis, EffectKind, PolyBasis, Series};

/// Why an augmented export failed.
#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    /// The residual loop itself failed.
    #[error(transparent)]
    Diagnose(#[from] DiagnoseError),
    /// The device-runnable model cannot be fitted.
    #[error("the device model cannot be fitted: {0}")]
    Degenerate(String),
    /// The fitted model does not fit the device's model (shape, scaling, non-finite values).
    #[error("the device model cannot be built: {0}")]
    Device(String),
    /// An effect was asked to be folded into the device model that this exporter cannot fold.
    #[error("`{0}` cannot be folded into the device's model")]
    NotFoldable(&'static str),
}

/// An effect the exported model carries, in the device's form.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Carried {
    /// Machine name.
    pub name: &'static str,
    /// How it runs on the device.
    pub how: String,
    /// Its parameter as refitted for the device (inertance: kPa·s²/mm³).
    pub value: f64,
    /// Unit of `value`.
    pub unit: &'static str,
}

/// A kept effect the exported model leaves out.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Dropped {
    /// Machine name.
    pub name: &'static str,
    /// Why the device cannot run it.
    pub reason: String,
}

/// Held-out RMSE (kPa) of the three models the user chooses between.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Rmses {
    /// (a) The full augmented model the loop ended with.
    pub augmented: f64,
    /// (b) The exported model, evaluated in f32 as the firmware evaluates it.
    pub device: f64,
    /// (b) The same model evaluated in f64 on the host (a gap to `device` is f32 round-off).
    pub device_f64: f64,
    /// (c) The baseline polynomial.
    pub baseline: f64,
    /// Held-out samples behind `device` (the first sample of a log has no history for AR terms).
    pub device_samples: usize,
}

/// The f64 host form of the exported model's polynomial part: Chebyshev polynomial plus
/// `L·(v̇ − v̇_prev)/Δt` (the chain, [`DeviceModel::chain`], runs on the board's estimator).
#[derive(Clone, Debug)]
pub struct HostModel {
    /// Basis of the polynomial part (its scaling is the exported one, exactly representable in f32).
    pub basis: PolyBasis,
    /// Chebyshev coefficients of the polynomial part.
    pub beta: Vec<f64>,
    /// Inertance L (kPa·s²/mm³) when carried.
    pub inertance: Option<f64>,
    /// Frame interval Δt of the backward difference (s).
    pub dt: f64,
}

impl HostModel {
    /// Predicted pressure (kPa) from the present volume and flow and the previous frame's flow
    /// (ignored without inertance; `None` is only valid then).
    pub fn predict(&self, v: f64, vdot: f64, vdot_prev: Option<f64>) -> Option<f64> {
        let poly = self.basis.eval(&self.beta, v, vdot);
        match self.inertance {
            None => Some(poly),
            Some(l) => vdot_prev.map(|q| poly + l * (vdot - q) / self.dt),
        }
    }
}

/// A device-runnable model refitted on a series: the baseline polynomial plus the carried terms.
#[derive(Clone, Debug)]
pub struct DeviceModel {
    /// The model for the device (its polynomial part).
    pub model: PolyModel,
    /// The effect chain the board runs around [`Self::model`] (empty: none).
    pub chain: model_core::chain::Chain,
    /// The same model in f64 on the host.
    pub host: HostModel,
    /// The device-form refit (its `pred` is the host prediction on the rows it was fitted over).
    pub refit: Stage,
    /// Index in the input series of the refit's first row (1 when an AR term needs a previous
    /// sample, else 0).
    pub first_row: usize,
}

impl DeviceModel {
    /// What the board installs: the polynomial and its chain.
    pub fn board_model(&self) -> firmware::store::Model {
        firmware::store::Model {
            poly: self.model,
            chain: self.chain,
        }
    }
}

/// The augmented model as exported to the device.
#[derive(Clone, Debug)]
pub struct AugmentedExport {
    /// What the loop found.
    pub diagnosis: Diagnosis,
    /// Kept effects the exported model carries.
    pub carried: Vec<Carried>,
    /// Kept effects it leaves out, with the reason.
    pub dropped: Vec<Dropped>,
    /// The exported model.
    pub device: DeviceModel,
    /// Held-out errors of (a) augmented, (b) device, (c) baseline.
    pub rmse: Rmses,
}

impl AugmentedExport {
    /// True when the loop kept at least one effect but none made it onto the device (the export
    /// is then the refitted baseline).
    pub fn nothing_carried(&self) -> bool {
        self.carried.is_empty() && !self.dropped.is_empty()
    }
}

/// Whether this exporter can fold `kind` into a [`PolyModel`] (see the module docs): the effect
/// says so ([`crate::residual::EffectModel::folds_into_polynomial`]).
pub fn foldable(kind: EffectKind) -> bool {
    kind.folds_into_polynomial() && kind.device_support().runs_on_device
}

/// The board's chain effect `kind` exports to, when `kind` runs on the board as one (not folded
/// into the polynomial): the effect says which ([`crate::residual::EffectModel::device_kind`]).
pub fn chain_kind(kind: EffectKind) -> Option<model_core::chain::EffectKind> {
    if !kind.device_support().runs_on_device {
        return None;
    }
    kind.device_kind()
}

/// Unit of the first parameter of the board's chain effect `kind` (a [`Carried`]'s `value`),
/// from its row in `model_core::spec`.
fn device_unit(kind: model_core::chain::EffectKind) -> &'static str {
    kind.spec().params[0].unit
}

/// Runs the residual loop on `series` and exports what it ends with (see the module docs).
pub fn augmented_export(series: Series, cfg: &Config) -> Result<AugmentedExport, ExportError> {
    let diagnosis = diagnose(series.clone(), cfg)?;
    from_diagnosis(diagnosis, &series)
}

/// One chamber of a log as `vfp export --augmented` exports it: the loop's series from the data
/// set ([`crate::residual::series_from_dataset`], its held-out cycles included), the loop and the export
/// ([`augmented_export`]). `vfp force --augmented` builds its board models through the same call.
pub fn export_dataset(
    ds: &crate::dataset::Dataset,
    cfg: &Config,
) -> Result<AugmentedExport, ExportError> {
    augmented_export(crate::residual::series_from_dataset(ds)?, cfg)
}

/// The diagnosis' kept effects sorted by how the device takes them: folded into the polynomial
/// (`carry`), run in the board's chain (with the loop's searched θ, at most
/// [`model_core::chain::MAX_EFFECTS`]), or left on the host with the reason.
fn sort_for_device(diagnosis: &Diagnosis) -> (Vec<EffectKind>, Vec<Effect>, Vec<Dropped>) {
    let mut carry = Vec::new();
    let mut chain = Vec::new();
    let mut dropped = Vec::new();
    for e in &diagnosis.effects {
        let kind = e.kind;
        let reason = kind.device_support().reason;
        let searched = diagnosis.final_effects.iter().find(|f| f.kind == kind);
        if let (Some(_), Some(f)) = (chain_kind(kind), searched) {
            if chain.len() < model_core::chain::MAX_EFFECTS {
                chain.push(f.clone());
            } else {
                dropped.push(Dropped {
                    name: kind.name(),
                    reason: format!(
                        "the board's chain holds at most {} effects; the loop kept these after the first {} it carries",
                        model_core::chain::MAX_EFFECTS,
                        model_core::chain::MAX_EFFECTS
                    ),
                });
            }
        } else if foldable(kind) {
            carry.push(kind);
        } else if kind.device_support().runs_on_device {
            dropped.push(Dropped {
                name: kind.name(),
                reason: format!(
                    "the device could evaluate it ({reason}), but this exporter does not yet know how to fold it into the model"
                ),
            });
        } else {
            dropped.push(Dropped {
                name: kind.name(),
                reason: reason.into(),
            });
        }
    }
    (carry, chain, dropped)
}

/// Exports the model of a finished diagnosis of `series` (the same series it was run on).
pub fn from_diagnosis(
    diagnosis: Diagnosis,
    series: &Series,
) -> Result<AugmentedExport, ExportError> {
    let (n, m) = (diagnosis.baseline.n, diagnosis.baseline.m);
    let (carry, chain, dropped) = sort_for_device(&diagnosis);
    let device = device_model_with(series, n, m, &carry, &chain)?;
    let mut carried: Vec<Carried> = device
        .host
        .inertance
        .zip(carry.first())
        .map(|(l, kind)| Carried {
            name: kind.name(),
            how: format!(
                "L·v̈ with v̈ = (v̇(t) − v̇(t−1))/Δt, Δt = {:.4} s: an AR(1) flow coefficient plus a change of the v̇ coefficient",
                device.host.dt
            ),
            value: l,
            unit: kind.device_kind().map_or("1", device_unit),
        })
        .into_iter()
        .collect();
    carried.extend(device.chain.effects().iter().map(|e| {
        let vals: Vec<String> = e.params().iter().map(|x| format!("{x:e}")).collect();
        Carried {
            name: e.kind().name(),
            how: format!(
                "the board's effect chain: `effect {} {}`",
                e.kind().name(),
                vals.join(" ")
            ),
            value: f64::from(e.params()[0]),
            unit: device_unit(e.kind()),
        }
    }));
    let (f32_rmse, device_samples) = device_rmse(&device.board_model(), series);
    let rmse = Rmses {
        augmented: diagnosis.final_model.rmse_heldout,
        device: f32_rmse,
        device_f64: device.refit.rmse_heldout,
        baseline: diagnosis.baseline.rmse_heldout,
        device_samples,
    };
    Ok(AugmentedExport {
        diagnosis,
        carried,
        dropped,
        device,
        rmse,
    })
}

/// Refits the baseline polynomial of shape (n, m) plus the effects in `carry` in the device's form
/// on the training rows of `series`, and builds the [`PolyModel`] (module docs). Every kind in
/// `carry` must be [`foldable`].
pub fn device_model(
    series: &Series,
    n: usize,
    m: usize,
    carry: &[EffectKind],
) -> Result<DeviceModel, ExportError> {
    device_model_with(series, n, m, carry, &[])
}

/// [`device_model`] with the chain effects `chain` (each with its searched θ, each with a
/// [`chain_kind`]) refitted alongside and carried in the board's chain (module docs).
pub fn device_model_with(
    series: &Series,
    n: usize,
    m: usize,
    carry: &[EffectKind],
    chain: &[Effect],
) -> Result<DeviceModel, ExportError> {
    if let Some(k) = carry.iter().find(|&&k| !foldable(k)) {
        return Err(ExportError::NotFoldable(k.name()));
    }
    if let Some(e) = chain.iter().find(|e| chain_kind(e.kind).is_none()) {
        return Err(ExportError::NotFoldable(e.kind.name()));
    }
    let dt = median_dt(&series.t);
    // The folded effect (at most one: its column is the flow's backward difference).
    let folded = carry.first().copied();
    if carry.len() > 1 {
        return Err(ExportError::NotFoldable(carry[1].name()));
    }
    let folds = folded.is_some();
    // With an AR term the first sample has no predecessor: it is left out of the refit, as the
    // firmware reports no estimate before its history holds one frame.
    let first_row = usize::from(folds);
    let k0 = first_row;
    let prep = device_prepared(series, n, m, k0, folds.then_some(dt))?;
    let mut effects: Vec<Effect> = carry.iter().map(|&k| Effect::new(k, 0.0)).collect();
    effects.extend(chain.iter().map(|e| from_row(e, k0)));
    device_form(&prep, &mut effects, carry.len());
    let refit = fit_stage(&prep, &effects).ok_or_else(|| {
        ExportError::Degenerate(
            "its columns are linearly dependent on the training rows (is volume or flow constant?)"
                .into(),
        )
    })?;
    let nb = prep.basis.len();
    let beta = refit.fit.beta[..nb].to_vec();
    let l = folds.then(|| {
        let col = (0..refit.design.owner.len())
            .find(|&c| refit.design.owner[c].is_some_and(|i| Some(effects[i].kind) == folded))
            .unwrap_or(nb);
        refit.fit.beta[col]
    });
    let dev_chain = board_chain(&refit, &effects[carry.len()..], carry.len())?;
    let basis = prep.basis.clone();
    let mut power = crate::poly::chebyshev_to_power_2d(&beta, n, m);
    let mut ar = Vec::new();
    if let Some(l) = l {
        // γ·y(t) − γ·y(t−1), γ = L·f_s/Δt (module docs); index 1 is b_01, the v̇-linear term.
        let gamma = l * basis.scaling.f_scale / dt;
        power[1] += gamma;
        ar.push([0.0, -gamma]);
    }
    let scaling = basis.scaling;
    let model = crate::poly::to_model_core(n, m, &power, &ar, &scaling)
        .map_err(|e| ExportError::Device(e.to_string()))?;
    Ok(DeviceModel {
        model,
        chain: dev_chain,
        host: HostModel {
            basis,
            beta,
            inertance: l,
            dt,
        },
        refit,
        first_row,
    })
}

/// The series from row `k0` on, prepared with the (n, m) basis whose scaling is rounded to f32 (so
/// host and device scale the inputs identically); with `backward_dt`, v̈ is the backward
/// difference of v̇ at that frame interval, what the device can compute.
fn device_prepared(
    series: &Series,
    n: usize,
    m: usize,
    k0: usize,
    backward_dt: Option<f64>,
) -> Result<Prepared, ExportError> {
    let mut dev = Series::new(
        series.t[k0..].to_vec(),
        series.v[k0..].to_vec(),
        series.vdot[k0..].to_vec(),
        series.p[k0..].to_vec(),
        series.train[k0..].to_vec(),
    )?;
    if let Some(dt) = backward_dt {
        dev.vddot = (k0..series.len())
            .map(|k| (series.vdot[k] - series.vdot[k - 1]) / dt)
            .collect();
    }
    let r = |x: f64| f64::from(x as f32);
    let mut basis = PolyBasis::for_data(&dev.v, &dev.vdot, n, m)
        .map_err(|e| ExportError::Degenerate(e.to_string()))?;
    let sc = basis.scaling;
    basis.scaling = crate::poly::Scaling {
        v_offset: r(sc.v_offset),
        v_scale: r(sc.v_scale),
        f_offset: r(sc.f_offset),
        f_scale: r(sc.f_scale),
    };
    Ok(Prepared::new(dev, basis))
}

/// Puts the chain effects `effects[first..]` in the board's form and re-tunes the lags' θ there.
///
/// The board has only the past: its sensor and air lags run on the cubic between frames with
/// backward-difference slopes (`signal::backward_slopes`, where the loop's Akima slopes need the
/// next frames), the delivery lag's flow on the cubic whose slopes are the causal accelerations
/// (`signal::acceleration_causal`, also inertance's v̈), its play operator on each frame's motion
/// rebuilt from that frame alone ([`Effect::board_form`]), its delay on the volume's cubic Hermite
/// ([`Effect::point_sampled`], the form the loop also fits point samples in). The loop may have
/// kept the frame-mean form, whose τ is not the best device τ, so the τ of each effect whose
/// [`crate::residual::EffectModel::device_retune`] says so (the lags, whose causal form trails further
/// than the loop's at the same τ; the play and the delay are the loop's own point-sample forms,
/// and the play's error is discontinuous in its width, so a search would put the width on an
/// edge where f32 and f64 may fall on different sides) is searched again in the device form
/// around the loop's (Brent's method on ln τ over a factor e² either side, within the effect's
/// search range), minimising the training SSE with the polynomial refitted at each trial; a
/// trial is kept only if it lowers that SSE, so the device-form refit never fits worse than at
/// the loop's θ. A damping schedule (the air pocket's) is taken from the device-form refit as
/// the effect says the board takes it from its own polynomial ([`device_damping`]), before and
/// after the search. Every θ is finally rounded to the `f32` the board stores.
fn device_form(prep: &Prepared, effects: &mut [Effect], first: usize) {
    for e in &mut effects[first..] {
        e.point_sampled = true;
        e.board_form = true;
    }
    for i in first..effects.len() {
        let kind = effects[i].kind;
        let th = effects[i].theta;
        if kind.device_retune() && th > 0.0 {
            set_damping(prep, effects, i);
            let (lo, hi) = match kind.search(&prep.scales) {
                crate::residual::effects::Search::Log(lo, hi) => (lo.ln(), hi.ln()),
                _ => (f64::NEG_INFINITY, f64::INFINITY),
            };
            let mut trial = effects.to_vec();
            let mut sse = |x: f64| {
                trial[i].theta = x.exp();
                sse_of(prep, &trial)
            };
            let before = sse(th.ln());
            let (a, b) = ((th.ln() - 2.0).max(lo), (th.ln() + 2.0).min(hi));
            if a < b {
                let (u, after) = brent(a, b, 24, &mut sse);
                if after < before {
                    effects[i].theta = u.exp();
                }
            }
        }
        effects[i].theta = f64::from(effects[i].theta as f32);
        set_damping(prep, effects, i);
    }
}

/// Sets the damping schedule of `effects[i]` when it needs one ([`device_damping`]), to its
/// fixed point: the board takes the damping from the polynomial it runs, which is the one fitted
/// with that schedule, so the schedule `d` is iterated, `d ← d + ½(c(d) − d)` with `c(d)` the
/// damping of the polynomial fitted with `d` (the half step damps the oscillation a long air
/// lag causes), until `c(d)` is `d` to 10⁻⁹ of its largest value (at most 200 passes; should it
/// not converge, the board's own error, measured by replay, shows the cost).
fn set_damping(prep: &Prepared, effects: &mut [Effect], i: usize) {
    if !effects[i].kind.needs().damping {
        return;
    }
    for _ in 0..200 {
        let Some(c) = device_damping(prep, effects, i) else {
            return;
        };
        let Some(d) = effects[i].damping.clone() else {
            effects[i].damping = Some(c);
            continue;
        };
        let scale = c.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let moved = d
            .iter()
            .zip(c.iter())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        if moved <= 1e-9 * scale {
            effects[i].damping = Some(c);
            return;
        }
        let next = d.iter().zip(c.iter()).map(|(a, b)| a + 0.5 * (b - a));
        effects[i].damping = Some(std::sync::Arc::new(next.collect()));
    }
}

/// The damping per sample of the polynomial refitted with `effects`, as the board schedules it
/// for `effects[i]` ([`crate::residual::EffectModel::device_damping`], the air pocket's in its own file);
/// `None` when the refit fails or the effect keeps the loop's schedule.
fn device_damping(
    prep: &Prepared,
    effects: &[Effect],
    i: usize,
) -> Option<std::sync::Arc<Vec<f64>>> {
    let stage = fit_stage(prep, effects)?;
    let beta = &stage.fit.beta[..prep.basis.len()];
    effects[i].kind.device_damping(prep, beta, &effects[i])
}

/// `e` on the rows of a series from `k0` on (its per-sample data cut to match).
fn from_row(e: &Effect, k0: usize) -> Effect {
    let cut = |d: &Option<std::sync::Arc<Vec<f64>>>| {
        d.as_ref()
            .map(|d| std::sync::Arc::new(d[k0.min(d.len())..].to_vec()))
    };
    Effect {
        damping: cut(&e.damping),
        stiffness: cut(&e.stiffness),
        ..e.clone()
    }
}

/// The board's chain from the refit's chain effects (`effects`, the design's effects from index
/// `first`), each mapped by its [`crate::residual::EffectModel::device_params`].
fn board_chain(
    refit: &Stage,
    effects: &[Effect],
    first: usize,
) -> Result<model_core::chain::Chain, ExportError> {
    let mut out = model_core::chain::Chain::new();
    for (i, e) in effects.iter().enumerate() {
        let coefs: Vec<f64> = (0..refit.design.owner.len())
            .filter(|&c| refit.design.owner[c] == Some(first + i))
            .map(|c| refit.fit.beta[c])
            .collect();
        let name = e.kind.name();
        let (Some(kind), Some(p)) = (chain_kind(e.kind), e.kind.device_params(e, &coefs)) else {
            return Err(ExportError::NotFoldable(name));
        };
        let p: Vec<f32> = p.iter().map(|&x| x as f32).collect();
        let fx = model_core::chain::Effect::new(kind, &p)
            .and_then(|fx| out.push(fx))
            .map_err(|err| ExportError::Device(format!("{name} {p:?}: {err}")));
        fx?;
    }
    Ok(out)
}

/// The board's frames over `series` loaded as chamber 0 (the other chambers unplugged), at the
/// series' frame rate: the firmware's own estimator ([`crate::board::replay::run`]); `None` when the
/// series' sample interval is no board frame rate.
pub fn board_frames(
    model: &firmware::store::Model,
    series: &Series,
) -> Option<Vec<replay::BoardFrame>> {
    let hz = replay::frame_hz(median_dt(&series.t)).ok()?;
    let nan = (f32::NAN, f32::NAN, f32::NAN);
    let frames = (0..series.len()).map(|k| {
        let x = (
            series.v[k] as f32,
            series.vdot[k] as f32,
            series.p[k] as f32,
        );
        (series.t[k], [x, nan, nan])
    });
    Some(replay::run(&[Some(*model), None, None], hz, frames))
}

/// Held-out RMSE of the board's `model` (polynomial and chain) run over the series in order by
/// the firmware's own estimator ([`board_frames`], f32, the chain's state and the AR
/// history carried from frame to frame), with the number of held-out samples it produced an
/// estimate for.
pub fn device_rmse(model: &firmware::store::Model, series: &Series) -> (f64, usize) {
    let Some(out) = board_frames(model, series) else {
        return (f64::NAN, 0);
    };
    let (mut sse, mut n) = (0.0, 0usize);
    for (k, f) in out.iter().enumerate() {
        let c = &f.frame.chambers[0];
        if !series.train[k] && c.p_hat.is_finite() {
            let r = series.p[k] - f64::from(c.p_hat);
            sse += r * r;
            n += 1;
        }
    }
    ((sse / n.max(1) as f64).sqrt(), n)
}
