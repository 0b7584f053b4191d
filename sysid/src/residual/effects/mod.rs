//! The library of candidate effects: each a physically meaningful augmentation of the polynomial
//! model with a name, a one-sentence physical story and parameters in physical units. Each effect
//! is one type implementing [`EffectModel`], in one file of this module; [`REGISTRY`] lists them
//! once, and [`super::Config::candidates`] (default: the registry) is what the loop tries.
//!
//! Every augmented model stays *linear in its coefficients once its nonlinear parameters θ are
//! fixed*, so it is fitted by least squares and θ (a time constant, width, delay, frequency, air
//! volume, leak conductance or drift rate) is found by search. An effect enters the model in one
//! of three ways (the design is assembled in [`design`]):
//!
//! * **input transform** ([`EffectModel::transform_inputs`]): the baseline polynomial is evaluated
//!   on what the chamber really sees, `P = Σ α_ij T_i(x') T_j(y')` with `(v', v̇')` the transformed
//!   volume and flow: transport delay `v'(t) = v(t − d)`; delivery lag `v' = L_τ² v`,
//!   `v̇' = L_τ² v̇` (the commanded motion through a critically damped second-order lag, two
//!   first-order lags `L_τ` of time constant τ: motor, screw, seal and tubing deliver it late by
//!   2τ and rounded); backlash `v' = play_b(v)` (the plunger waits `b` mm³ of nut travel after
//!   each reversal, with zero flow meanwhile); volume drift `v' = v − r·t`; leak
//!   `v' = v − λ ∫P dt` (flow out ∝ pressure); air compliance `v' = v − V_a·P/(P_atm + P)`
//!   (isothermal gas of volume `V_a` at atmospheric pressure, Boyle's law). The transforms are
//!   applied in the physical order along the chain ([`EffectModel::input_stage`]): timing,
//!   nut→plunger, then volume that never reaches the chamber;
//! * **added columns** ([`EffectModel::columns`]): hysteresis `H(v)·h_w(t)`, `h_w ∈ [−1, 1]` a
//!   rate-independent direction memory that switches exponentially in volume after each reversal,
//!   `dh_w = (s − h_w)|dv|/w` with `s = sign(dv)` (a Duhem hysteron: its output depends on the path
//!   of v, never on its speed; w is the volume over which 63 % of the switch happens), with
//!   `H(v) = H₀ + H₁ x`; inertance `L·v̈`; offset drift `Σ_d c_d P_d(s)` (Legendre in scaled time);
//!   ripple `a sin 2πft + b cos 2πft`; pump ripple, a volume error `δ = a sin 2πv/Λ + b cos 2πv/Λ`
//!   once per screw turn entered to first order, `k δ + c δ̇` (k, c the model's stiffness and
//!   damping), its phase taken at the plunger, which the logged step count trails by a lag fitted
//!   per cruise speed ([`CountLag`]), and then applied exactly as an input transform by
//!   Gauss–Newton steps;
//! * **output filter** on every column ([`EffectModel::filter`]; exact because the model is linear
//!   in its coefficients): sensor lag `τ Ṗ_m + P_m = P`; air compliance's dynamic part,
//!   `τ(t) Ṗ + P = P_static` with `τ(t) = c(v, v̇)·V_a·P_atm/(P_atm + P)²` — the line resistance
//!   `c = ∂P/∂v̇` (paper's damping, Section V-A) charging the gas spring `dV/dP`, so an air pocket
//!   lags most at low pressure. Air compliance filters before the sensor's own lag
//!   ([`EffectModel::filter_stage`]).
//!
//! A log's frame is the mean of the sensor's conversions over its interval, and an effect acts
//! inside it. The lags (sensor lag, air compliance's dynamic part, delivery lag) therefore run
//! over the motion rebuilt at the instants each frame averages, with the logged frame means and
//! the fewest corners of flow, and are averaged back over each frame ([`lag_in_frames`]): a move
//! that starts or stops inside a frame is neither smeared over the frames around it nor placed
//! at a frame instant. (On instants, [`Effect::point_sampled`], the output lags act on each
//! column's Akima cubic between samples, `signal::lag_cubic_coeffs`.) Backlash runs its play
//! operator on the nut's motion rebuilt at eight instants per frame and averages the plunger
//! back (`signal::play_frames`): a dead band shorter than a frame is then neither all-or-nothing
//! nor placed at a frame instant.
//!
//! Where a transform needs the pressure itself (leak, air compliance) it uses the measured
//! pressure unfiltered; it only schedules or integrates it, never differentiates it, so the
//! sensor noise does not leak into the regressors. A prediction with these effects therefore uses
//! measured pressure as a scheduling input (stated in the report).
//!
//! # Adding an effect
//!
//! An effect is a type implementing [`EffectModel`]: a name and a story are required, everything
//! else has a do-nothing default (no parameter searched, no transform, no column, no filter, not
//! on the device). In this crate it is one new file `effects/<name>.rs` and one line in
//! [`REGISTRY`]; outside it, one line added to the candidates the loop tries. Here a turbulent
//! loss across a restriction (Bernoulli: `ΔP = K·v̇|v̇|`), one added column whose coefficient K
//! must not be negative:
//!
//! ```
//! use sysid::residual::effects::{
//!     Column, DeviceSupport, Effect, EffectKind, EffectModel, Fitted, Prepared, Scales, REGISTRY,
//! };
//! use sysid::residual::{diagnose, param, Config, Param, Series};
//!
//! /// Turbulent pressure drop across a narrow fitting.
//! struct OrificeLoss;
//!
//! impl EffectModel for OrificeLoss {
//!     fn name(&self) -> &'static str {
//!         "orifice_loss"
//!     }
//!     fn story(&self) -> &'static str {
//!         "Flow through a narrow fitting loses pressure with the square of its speed (Bernoulli), in the direction of flow."
//!     }
//!     fn columns(&self, _e: &Effect, prep: &Prepared, _v: &[f64]) -> Vec<Column> {
//!         let q = &prep.series.vdot;
//!         vec![Column::new(q.iter().map(|q| q * q.abs()).collect(), "orifice vdot|vdot|")]
//!     }
//!     fn unphysical(&self, _e: &Effect, coefs: &[f64], _sc: &Scales) -> Option<String> {
//!         (coefs[0] < 0.0).then(|| "a restriction cannot push the flow along".to_string())
//!     }
//!     fn params(&self, f: &Fitted) -> Vec<Param> {
//!         vec![param("loss_coefficient", f.coef(0), f.coef_se(0), "kPa*s^2/mm6")]
//!     }
//!     fn device_support(&self) -> DeviceSupport {
//!         DeviceSupport::host_only("the device model is polynomial in the flow")
//!     }
//! }
//!
//! // A breathing-like motion whose pressure carries the loss (K = 4e-5 kPa·s²/mm⁶), with a
//! // deterministic pseudo-noise of about 0.01 kPa.
//! let t: Vec<f64> = (0..2500).map(|k| 0.04 * k as f64).collect();
//! let v: Vec<f64> = t.iter().map(|&t| 275.0 + 150.0 * (0.3 * t).sin() + 80.0 * (0.71 * t).sin()).collect();
//! let q: Vec<f64> = t.iter().map(|&t| 45.0 * (0.3 * t).cos() + 56.8 * (0.71 * t).cos()).collect();
//! let p: Vec<f64> = (0..t.len())
//!     .map(|k| 2.0 + 0.01 * v[k] + 0.002 * q[k] + 4e-5 * q[k] * q[k].abs() + 0.01 * (k as f64 * 12.9898).sin())
//!     .collect();
//! let train: Vec<bool> = (0..t.len()).map(|k| (k / 250) % 5 != 4).collect();
//! let series = Series::new(t, v, q, p, train).unwrap();
//!
//! let mut cfg = Config { max_effects: 1, ..Config::default() };
//! cfg.candidates.push(EffectKind(&OrificeLoss)); // the one line
//! assert_eq!(cfg.candidates.len(), REGISTRY.len() + 1);
//! let d = diagnose(series, &cfg).unwrap();
//! assert_eq!(d.effects[0].name, "orifice_loss");
//! let k = d.effects[0].params[0].value;
//! assert!((k - 4e-5).abs() < 0.05 * 4e-5, "K = {k}");
//! ```
//!
//! The trait's methods take data and give back data (columns, a search, a verdict on
//! plausibility, a device form, an [`Effect`]), never the loop's fitted stages. An effect that
//! takes something from the model it is added to (its damping or stiffness, [`EffectModel::needs`])
//! is handed that model read only, a [`ModelView`] (its effects, the polynomial's coefficients and
//! those of every column, its training SSE), in two places: [`EffectModel::refine`] improves the
//! effect the search found beyond its searched θ (an air pocket re-tuned on the damping of the
//! model that has it, a pump ripple's volume error applied exactly) and the loop refits the model
//! with it, keeping the refit only where it lowers the training SSE; [`EffectModel::reanchored`]
//! takes that data again from a model the re-tune has moved.

use serde::Serialize;

pub mod air_compliance;
pub mod backlash;
pub mod delivery_lag;
pub mod design;
pub mod gated_ripple;
pub mod hysteresis;
pub mod inertance;
pub mod lag_in_frames;
pub mod leak;
pub mod offset_drift;
pub mod pump_ripple;
pub mod ripple;
pub mod sensor_lag;
pub mod transport_delay;
pub mod volume_drift;

pub use air_compliance::AirCompliance;
pub use backlash::Backlash;
pub use delivery_lag::DeliveryLag;
pub use design::{
    build, sse_structured, Design, DesignGate, Effect, Inputs, Prepared, Scales, DESIGN_MEMORY,
};
pub use gated_ripple::GatedRipple;
pub use hysteresis::Hysteresis;
pub use inertance::Inertance;
pub use leak::Leak;
pub use offset_drift::OffsetDrift;
pub use pump_ripple::{cruise_speeds, CountLag, PumpRipple};
pub use ripple::Ripple;
pub use sensor_lag::SensorLag;
pub use transport_delay::TransportDelay;
pub use volume_drift::VolumeDrift;

pub use super::search::{param, Param};
pub use super::DeviceSupport;

/// Atmospheric pressure (kPa) for the isothermal air pocket.
pub const P_ATM_KPA: f64 = 101.325;

/// Every effect this crate knows, in the order they are reported when tied: the loop's default
/// candidates.
pub const REGISTRY: &[EffectKind] = &[
    EffectKind(&Hysteresis),
    EffectKind(&AirCompliance),
    EffectKind(&SensorLag),
    EffectKind(&TransportDelay),
    EffectKind(&DeliveryLag),
    EffectKind(&Inertance),
    EffectKind(&OffsetDrift),
    EffectKind(&VolumeDrift),
    EffectKind(&Backlash),
    EffectKind(&Ripple),
    EffectKind(&GatedRipple),
    EffectKind(&PumpRipple),
    EffectKind(&Leak),
];

/// How a nonlinear parameter is searched.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Search {
    /// Positive, searched on a log grid between the bounds.
    Log(f64, f64),
    /// Either sign, searched on a symmetric log grid of magnitudes between the bounds.
    Signed(f64, f64),
    /// Frequency read off the residual spectrum, then refined.
    Spectral,
    /// Period in volume from the effect's own scan of the residual ([`EffectModel::scan`]), then
    /// refined in spatial frequency within one scan step either side.
    VolumeSpectral,
    /// A small integer (polynomial degree), chosen by AICc.
    Degree(usize),
    /// No nonlinear parameter.
    None,
}

/// Per-sample data of the current model a search attaches to each trial [`Effect`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Needs {
    /// The damping `c = ∂P/∂v̇` ([`Effect::damping`]).
    pub damping: bool,
    /// The stiffness `k = ∂P/∂v` ([`Effect::stiffness`]).
    pub stiffness: bool,
}

/// One added regressor column over every sample, with what it is.
#[derive(Clone, Debug, PartialEq)]
pub struct Column {
    /// Values over every sample (train and held-out).
    pub values: Vec<f64>,
    /// Label in reports.
    pub label: String,
}

impl Column {
    /// A column with its label.
    pub fn new(values: Vec<f64>, label: impl Into<String>) -> Self {
        Self {
            values,
            label: label.into(),
        }
    }
}

/// Candidate values of θ from an effect's scan of the current residual.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Scan {
    /// Starting values of θ, best first.
    pub starts: Vec<f64>,
    /// Spacing of the scanned grid in `1/θ`: each start is refined within one step either side.
    pub step: f64,
}

/// A fitted effect as its [`EffectModel::params`] sees it: its θ, its columns' coefficients and
/// their covariance, with the residual variance inflated for autocorrelation (`N/N_eff`).
pub struct Fitted<'a> {
    /// The data.
    pub prep: &'a Prepared,
    /// Every coefficient of the fitted model the effect belongs to (the polynomial's, then the
    /// effects' columns').
    pub beta: &'a [f64],
    /// That fit's `(XᵀX)⁻¹`, over the same coefficients.
    pub xtx_inv: &'a nalgebra::DMatrix<f64>,
    /// The effect.
    pub effect: &'a Effect,
    /// Design indices of the effect's columns, in order.
    pub cols: Vec<usize>,
    /// Standard error of θ from the profile SSE's curvature (NaN when flat or without θ).
    pub theta_se: f64,
    /// Residual variance `σ̂²·N/N_eff`.
    pub s2: f64,
}

impl Fitted<'_> {
    /// Coefficient of the effect's `k`-th column.
    pub fn coef(&self, k: usize) -> f64 {
        self.beta[self.cols[k]]
    }

    /// Standard error of [`Self::coef`].
    pub fn coef_se(&self, k: usize) -> f64 {
        (self.s2 * self.cov(k, k)).sqrt()
    }

    /// `(XᵀX)⁻¹` between the effect's columns `a` and `b` (multiply by [`Self::s2`]).
    pub fn cov(&self, a: usize, b: usize) -> f64 {
        self.xtx_inv[(self.cols[a], self.cols[b])]
    }

    /// Backlash, transport delay: 1 when the samples fitted best as frame means (an averaging
    /// sensor), 0 as instants ([`Effect::point_sampled`]).
    pub fn frame_averaged(&self) -> Param {
        let v = if self.effect.point_sampled { 0.0 } else { 1.0 };
        param("frame_averaged", v, f64::NAN, "1")
    }
}

/// A fitted model as an effect sees it, read only: its effects and the numbers of its fit. What
/// the engine hands an effect that takes something from the model it sits in
/// ([`EffectModel::refine`], [`EffectModel::reanchored`]).
#[derive(Clone, Copy, Debug)]
pub struct ModelView<'a> {
    /// The model's effects, in the order added.
    pub effects: &'a [Effect],
    /// Every coefficient: the polynomial's Chebyshev coefficients over `prep.basis` first
    /// ([`Self::polynomial`]), then those of the effects' columns.
    pub beta: &'a [f64],
    /// Per coefficient, the index in [`Self::effects`] of the effect whose column it is (`None`:
    /// the polynomial's).
    pub owner: &'a [Option<usize>],
    /// Training SSE.
    pub sse: f64,
}

impl<'a> ModelView<'a> {
    /// The polynomial's Chebyshev coefficients over `prep.basis`.
    pub fn polynomial(&self, prep: &Prepared) -> &'a [f64] {
        &self.beta[..prep.basis.len()]
    }

    /// The design indices of effect `idx`'s columns, in order.
    pub fn owned_columns(&self, idx: usize) -> Vec<usize> {
        (0..self.owner.len())
            .filter(|&c| self.owner[c] == Some(idx))
            .collect()
    }

    /// The coefficients of effect `idx`'s columns, in order.
    pub fn coefs(&self, idx: usize) -> Vec<f64> {
        self.owned_columns(idx)
            .into_iter()
            .map(|c| self.beta[c])
            .collect()
    }
}

/// One candidate effect: everything the loop needs to know about it. Only [`Self::name`] and
/// [`Self::story`] are required; every other method defaults to doing nothing (see "Adding an
/// effect" in the module docs).
pub trait EffectModel: Send + Sync {
    /// Stable machine name (JSON, CLI), snake case, unique among the candidates.
    fn name(&self) -> &'static str;

    /// One sentence of physics, for the person reading the report.
    fn story(&self) -> &'static str;

    /// How θ is searched, from the data's scales (default: no θ).
    fn search(&self, _scales: &Scales) -> Search {
        Search::None
    }

    /// Whether the effect has a searched nonlinear parameter θ, counted as one parameter by the
    /// nested test (default: no).
    fn has_nonlinear(&self) -> bool {
        false
    }

    /// Per-sample data of the current model each trial carries (default: none).
    fn needs(&self) -> Needs {
        Needs::default()
    }

    /// Whether the search fits θ twice, with the samples as frame means and as instants
    /// ([`Effect::point_sampled`]), and keeps the form with the lower held-out error.
    fn tries_point_sampled(&self) -> bool {
        false
    }

    /// Whether that second form is tried on the firmware's frames too (`Series::flow_in_frames`:
    /// each sample a mean over its frame, which the log says); default yes. An effect whose
    /// form between instants is another sensor's, not a stand-in for its form inside the
    /// frames, says no.
    fn point_sampled_on_frames(&self) -> bool {
        true
    }

    /// Whether a round's search of θ may start where the previous round's ended
    /// (`search::search_from`) instead of over the whole grid: true where the training SSE has
    /// one minimum in θ over the search range (one time constant, delay or rate), which one more
    /// effect in the model moves but does not split. A width (a hysteresis loop, a dead band)
    /// fits other features at other sizes, and is searched over the whole grid every round.
    fn one_minimum(&self) -> bool {
        false
    }

    /// Guessed cost of the search relative to a plain one, before its first round is timed (to
    /// start the costliest first).
    fn cost_guess(&self) -> f64 {
        1.0
    }

    /// [`Search::VolumeSpectral`]: candidate θ from a scan of the current model's residual
    /// `resid` (per sample, kPa), `trial` carrying the [`Self::needs`] data (default: none).
    fn scan(&self, _prep: &Prepared, _resid: &[f64], _trial: &Effect) -> Scan {
        Scan::default()
    }

    /// The effect the search found (`found`, last in `model`, the fitted model it was found in,
    /// with the rest of that model `base` before it) improved beyond its searched θ, or `None` to
    /// keep it as found (default). The engine refits the model with the returned effect in
    /// `found`'s place and keeps that fit only where its training SSE is lower than `model`'s.
    fn refine(
        &self,
        _prep: &Prepared,
        _base: &[Effect],
        _found: &Effect,
        _model: &ModelView,
    ) -> Option<Effect> {
        None
    }

    /// Gives the effect the model keeps (after [`Self::refine`]) the parameters it has that its
    /// fit has not moved from their start, which the model counts and the report lists: a pump
    /// ripple's count lag, 0 at each cruise speed where refinement fitted none. The fit stays as
    /// it is (default: nothing to add).
    fn complete(&self, _prep: &Prepared, _e: &mut Effect) {}

    /// `e`, one of `model`'s effects, re-anchored on `model`: what it took from the model it was
    /// added to ([`Self::needs`]) taken again from `model` itself, once re-tuning has moved that
    /// model; `None` where the effect keeps nothing of the model (default).
    fn reanchored(&self, _prep: &Prepared, _e: &Effect, _model: &ModelView) -> Option<Effect> {
        None
    }

    /// Place along the input chain (lower first: delivery lag 0, transport delay 10, backlash
    /// 20, pump ripple 30, volume drift 40, leak 50, air compliance 60); `None` for no input
    /// transform (default).
    fn input_stage(&self) -> Option<u32> {
        None
    }

    /// Whether `e` transforms the inputs (default: whenever the effect has an input stage).
    fn transforms_inputs(&self, _e: &Effect) -> bool {
        self.input_stage().is_some()
    }

    /// Transforms the volume and flow the baseline is evaluated on.
    fn transform_inputs(&self, _e: &Effect, _prep: &Prepared, _inputs: &mut Inputs) {}

    /// Columns added to the design (default: none). `v` is the chamber's volume: the logged one
    /// moved by the input transforms ahead of the effect (an air pocket's compression, a
    /// delivery lag, a leak); an effect that follows the chamber (a wall's hysteresis) reads it,
    /// one that follows the pump reads `prep.series`.
    fn columns(&self, _e: &Effect, _prep: &Prepared, _v: &[f64]) -> Vec<Column> {
        Vec::new()
    }

    /// Place among the output filters (lower first: air compliance 0, sensor lag 10); `None` for
    /// no output filter (default).
    fn filter_stage(&self) -> Option<u32> {
        None
    }

    /// Filters every design column (each over every sample).
    fn filter(&self, _e: &Effect, _prep: &Prepared, _cols: &mut [Vec<f64>]) {}

    /// For an output filter whose [`Self::filter`] is one cubic lag of every column
    /// (`signal::LagStream`): its per-interval coefficients and the slopes its cubic takes. The
    /// searches then sum the lagged design's Gram matrix as the lag produces it, a block of rows
    /// at a time (`design::sse_lagged`), instead of lagging the whole design in place and copying
    /// it again; the numbers are the same.
    fn output_lag(
        &self,
        _e: &Effect,
        _prep: &Prepared,
    ) -> Option<(Vec<[f64; 5]>, crate::residual::signal::LagSlopes)> {
        None
    }

    /// For an output filter that is a first-order lag `τ(t) ẏ + y = x`: its time constant over
    /// each frame (s). The loop's form then runs it inside the frames ([`lag_in_frames`]) rather
    /// than through [`Self::filter`]; `None` (default) for no such lag.
    fn lag_time_constants(&self, _e: &Effect, _prep: &Prepared) -> Option<Vec<f64>> {
        None
    }

    /// Whether a prediction with the effect uses the measured pressure as a scheduling input
    /// (the chamber's, behind the model's sensor lags: [`Effect::scheduled_pressure`]).
    fn uses_measured_pressure(&self) -> bool {
        false
    }

    /// For a lag of the reading behind the chamber's pressure (a sensor's): its time constant (s),
    /// undone where an effect is scheduled on the chamber's pressure (`pressure_schedule`);
    /// `None` (default) for any other effect, and for a lag of the pressure itself.
    fn sensor_lag(&self, _e: &Effect, _sc: &Scales) -> Option<f64> {
        None
    }

    /// For a lag or delay of the motion or the reading: the mean delay it amounts to (s), the
    /// first moment of its impulse response (a first-order lag's τ, a two-stage lag's 2τ, a
    /// delay's d); `None` (default) for any other effect. Lags of the same mean delay differ in
    /// the frames only at order (τ/frame)² ([`super::alternatives`] fits each at the others').
    /// A lag whose time constant changes over the log (the air pocket's) gives the constant one
    /// a least-squares fit would put in its place on `prep`'s log.
    fn mean_delay(&self, _e: &Effect, _prep: &Prepared) -> Option<f64> {
        None
    }

    /// The inverse of [`Self::mean_delay`]: the parameter θ at which the effect amounts to a
    /// mean delay of `d` s; `None` (default) where it has none.
    fn theta_at_mean_delay(&self, _d: f64) -> Option<f64> {
        None
    }

    /// Why the fitted effect is physically impossible or implausible on this log, from θ, its
    /// columns' coefficients and the log's own scales (its cycle period, duration, volume range),
    /// or `None` when it is admissible (default: θ, when searched, must be finite; the search keeps
    /// it inside its physical range). A rejected effect is not kept; the structure it would have
    /// absorbed is reported in `remaining` with this reason.
    fn unphysical(&self, e: &Effect, _coefs: &[f64], _sc: &Scales) -> Option<String> {
        (self.has_nonlinear() && !e.theta.is_finite())
            .then(|| format!("{} parameter is not finite", self.name()))
    }

    /// A name and story that claim no more than the evidence, when the fitted effect's
    /// parameters, measured against the log's own scales, say the structure is real but the
    /// effect's name overstates it (default: `None`, the effect's own name). The model is the
    /// same; only the report's `name` and `story` change.
    fn neutral(&self, _e: &Effect, _sc: &Scales) -> Option<(&'static str, &'static str)> {
        None
    }

    /// The name and story the effect is reported under on a log that does not come from a
    /// syringe rig (`crate::residual::Rig::Generic`), when its own name and story tell a
    /// mechanism of a syringe pump (default: `None`, the same name anywhere). They claim no more
    /// than the signal.
    fn generic(&self) -> Option<(&'static str, &'static str)> {
        None
    }

    /// Physical parameters with uncertainties and units (default: θ when searched, then each
    /// column's coefficient).
    fn params(&self, f: &Fitted) -> Vec<Param> {
        let theta = self
            .has_nonlinear()
            .then(|| param("theta", f.effect.theta, f.theta_se, "1"));
        theta
            .into_iter()
            .chain(
                (0..f.cols.len())
                    .map(|k| param(&format!("coefficient_{k}"), f.coef(k), f.coef_se(k), "1")),
            )
            .collect()
    }

    /// Whether the parameter called `name` cannot be negative, so that its 95 % interval is
    /// clipped at 0 ([`crate::residual::interval`]). A positive searched θ and whatever is derived
    /// from it alone are known to be so without this (default: no other).
    fn nonnegative(&self, _name: &str) -> bool {
        false
    }

    /// The parameter whose value 0 means the effect is absent (a gap, a time constant, a
    /// volume, an amplitude), if any (default: none).
    fn presence(&self) -> Option<&'static str> {
        None
    }

    /// The board's chain effect this effect exports to (its row in `model_core::spec` gives the
    /// wire name, the stored code, the parameters' order, units and bounds), when the board runs
    /// it as a chain effect (default: it does not). With [`Self::device_params`] the one place
    /// each effect is mapped to its device form (`vfp export --augmented`).
    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        None
    }

    /// The effect's parameters in the board's chain effect [`Self::device_kind`] (in the order of
    /// its row in `model_core::spec`) from θ and the coefficients of its columns (default: none).
    fn device_params(&self, _e: &Effect, _coefs: &[f64]) -> Option<Vec<f64>> {
        None
    }

    /// Whether the export searches θ again in the board's form (`board::augmented`'s
    /// `device_form`): an effect whose causal board form trails further than the loop's at the
    /// same θ, a lag's (default: no; the loop's θ is kept, rounded to `f32`).
    fn device_retune(&self) -> bool {
        false
    }

    /// For an effect whose trial carries the model's damping ([`Self::needs`]): that damping as
    /// the board schedules it from the polynomial it runs, per sample, given the polynomial's
    /// Chebyshev coefficients `beta` (in `prep.basis`) fitted with `e` (default: none; the
    /// loop's schedule is kept).
    fn device_damping(
        &self,
        _prep: &Prepared,
        _beta: &[f64],
        _e: &Effect,
    ) -> Option<std::sync::Arc<Vec<f64>>> {
        None
    }

    /// Whether `board::augmented::device_model` can fold the effect into the polynomial itself,
    /// its one column `θ·v̈` taken as the backward difference of the flow at the frame interval:
    /// an AR(1) flow coefficient plus a change of the v̇ coefficient (default: no).
    fn folds_into_polynomial(&self) -> bool {
        false
    }

    /// Whether `model_core::poly::PolyModel` (polynomial plus linear AR terms on v(t−k), v̇(t−k))
    /// or the board's effect chain around it can carry the effect, and why (not) (default: not).
    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::host_only("no device form is known for this effect")
    }
}

/// A candidate effect: a handle on its [`EffectModel`], compared, hashed and serialised by name.
#[derive(Clone, Copy)]
pub struct EffectKind(pub &'static dyn EffectModel);

impl EffectKind {
    /// The registry's effect called `name`.
    pub fn named(name: &str) -> Option<EffectKind> {
        REGISTRY.iter().copied().find(|k| k.name() == name)
    }
}

impl std::ops::Deref for EffectKind {
    type Target = dyn EffectModel;

    fn deref(&self) -> &Self::Target {
        self.0
    }
}

impl PartialEq for EffectKind {
    fn eq(&self, other: &Self) -> bool {
        self.name() == other.name()
    }
}

impl Eq for EffectKind {}

impl std::hash::Hash for EffectKind {
    fn hash<H: std::hash::Hasher>(&self, state: &mut H) {
        self.name().hash(state);
    }
}

impl std::fmt::Debug for EffectKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl Serialize for EffectKind {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_effect_has_story_and_unique_name() {
        let mut names: Vec<&str> = REGISTRY.iter().map(|k| k.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), REGISTRY.len());
        assert!(REGISTRY.iter().all(|k| k.story().ends_with('.')));
        assert!(REGISTRY
            .iter()
            .all(|k| EffectKind::named(k.name()) == Some(*k)));
    }

    /// Each effect's device form agrees with its row of `model_core::spec`: the same wire name,
    /// runnable on the board, and as many parameters as the row has (θ, when searched, then one
    /// per column), which the board's checks accept.
    #[test]
    fn device_forms_match_the_spec_table() {
        let mut exported = Vec::new();
        for k in REGISTRY {
            let Some(dk) = k.device_kind() else {
                continue;
            };
            let spec = dk.spec();
            assert_eq!(k.name(), spec.name);
            assert!(k.device_support().runs_on_device, "{}", k.name());
            let coefs = vec![0.25; spec.params.len() - usize::from(k.has_nonlinear())];
            let p = k.device_params(&Effect::new(*k, 1.0), &coefs).unwrap();
            assert_eq!(p.len(), spec.params.len(), "{}", k.name());
            let p32: Vec<f32> = p.iter().map(|&x| x as f32).collect();
            model_core::chain::Effect::new(dk, &p32).unwrap();
            exported.push(dk);
        }
        // Every board kind but pump ripple (whose loop form the board cannot run) has one.
        use model_core::chain::EffectKind as K;
        exported.sort();
        let mut expect: Vec<K> = K::ALL.into_iter().filter(|&k| k != K::PumpRipple).collect();
        expect.sort();
        assert_eq!(exported, expect);
        let retuned: Vec<&str> = REGISTRY
            .iter()
            .filter(|k| k.device_retune())
            .map(|k| k.name())
            .collect();
        assert_eq!(
            retuned,
            ["air_compliance", "sensor_lag", "delivery_lag", "leak"]
        );
        let folded: Vec<&str> = REGISTRY
            .iter()
            .filter(|k| k.folds_into_polynomial())
            .map(|k| k.name())
            .collect();
        assert_eq!(folded, ["inertance"]);
    }
}
