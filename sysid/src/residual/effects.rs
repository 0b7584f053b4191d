//! The library of candidate effects: each a physically meaningful augmentation of the polynomial
//! model with a name, a one-sentence physical story and parameters in physical units.
//!
//! Every augmented model stays *linear in its coefficients once its nonlinear parameters θ are
//! fixed*, so it is fitted by least squares and θ (a time constant, width, delay, frequency, air
//! volume, leak conductance or drift rate) is found by search. An effect enters the model in one
//! of three ways:
//!
//! * **input transform**: the baseline polynomial is evaluated on what the chamber really sees,
//!   `P = Σ α_ij T_i(x') T_j(y')` with `(v', v̇')` the transformed volume and flow:
//!   transport delay `v'(t) = v(t − d)`; delivery lag `v' = L_τ² v`, `v̇' = L_τ² v̇` (the
//!   commanded motion through a critically damped second-order lag, two first-order lags `L_τ`
//!   of time constant τ: motor, screw, seal and tubing deliver it late by 2τ and rounded); backlash `v' = play_b(v)` (the plunger waits `b` mm³ of nut
//!   travel after each reversal, with zero flow meanwhile); volume drift `v' = v − r·t`; leak
//!   `v' = v − λ ∫P dt` (flow out ∝ pressure); air compliance `v' = v − V_a·P/(P_atm + P)`
//!   (isothermal gas of volume `V_a` at atmospheric pressure, Boyle's law);
//! * **added columns**: hysteresis `H(v)·h_w(t)`, `h_w ∈ [−1, 1]` a rate-independent direction
//!   memory that switches exponentially in volume after each reversal, `dh_w = (s − h_w)|dv|/w`
//!   with `s = sign(dv)` (a Duhem hysteron: its output depends on the path of v, never on its
//!   speed; w is the volume over which 63 % of the switch happens), with `H(v) = H₀ + H₁ x`; inertance `L·v̈`; offset drift `Σ_d c_d P_d(s)` (Legendre in scaled
//!   time); ripple `a sin 2πft + b cos 2πft`; pump ripple, a volume error `δ = a sin 2πv/Λ +
//!   b cos 2πv/Λ` once per screw turn entered to first order, `k δ + c δ̇` (k, c the model's
//!   stiffness and damping), its phase taken at the plunger, which the logged step count trails
//!   by a lag fitted per cruise speed ([`CountLag`]), and then applied exactly as an input
//!   transform by Gauss–Newton steps;
//! * **output filter** on every column (exact because the model is linear in its coefficients):
//!   sensor lag `τ Ṗ_m + P_m = P`; air compliance's dynamic part, `τ(t) Ṗ + P = P_static` with
//!   `τ(t) = c(v, v̇)·V_a·P_atm/(P_atm + P)²` — the line resistance `c = ∂P/∂v̇` (paper's damping,
//!   Section V-A) charging the gas spring `dV/dP`, so an air pocket lags most at low pressure.
//!
//! A log's frame is the mean of the sensor's conversions over its interval, and an effect acts
//! inside it. The filters therefore lag each column's Akima interpolant between frames exactly
//! (`signal::lag_cubic_coeffs`; a mean commutes with a linear filter, so this is the lag of the
//! frame-averaged signal), and backlash runs its play operator on the nut's motion rebuilt at
//! eight instants per frame and averages the plunger back (`signal::play_frames`): a dead band
//! shorter than a frame is then neither all-or-nothing nor placed at a frame instant.
//!
//! Where a transform needs the pressure itself (leak, air compliance) it uses the measured
//! pressure unfiltered; it only schedules or integrates it, never differentiates it, so the
//! sensor noise does not leak into the regressors. A prediction with these effects therefore uses
//! measured pressure as a scheduling input (stated in the report).

use serde::Serialize;

use super::basis::PolyBasis;
use super::lsq;
use super::signal;
use super::Series;

/// Atmospheric pressure (kPa) for the isothermal air pocket.
pub const P_ATM_KPA: f64 = 101.325;

/// The candidate effects the loop knows.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum EffectKind {
    /// Direction-dependent, rate-independent pressure offset.
    Hysteresis,
    /// Compressible air between plunger and chamber.
    AirCompliance,
    /// First-order lag of the pressure sensor.
    SensorLag,
    /// Pure time delay between volume and pressure.
    TransportDelay,
    /// The commanded motion delivered through a critically damped lag.
    DeliveryLag,
    /// Fluid inertance of the line (v̈ term).
    Inertance,
    /// Slow drift of the pressure sensor's zero.
    OffsetDrift,
    /// Slow drift of the volume reading.
    VolumeDrift,
    /// Lead-screw backlash (dead band at reversals).
    Backlash,
    /// Periodic ripple at one frequency.
    Ripple,
    /// Ripple periodic in plunger position (lead-screw pitch error, once per screw turn).
    PumpRipple,
    /// Leak: volume lost at a rate proportional to pressure.
    Leak,
}

/// How a nonlinear parameter is searched.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Search {
    /// Positive, searched on a log grid between the bounds.
    Log(f64, f64),
    /// Either sign, searched on a symmetric log grid of magnitudes between the bounds.
    Signed(f64, f64),
    /// Frequency read off the residual spectrum, then refined.
    Spectral,
    /// Period in volume read off the residual's periodogram against volume, then refined.
    VolumeSpectral,
    /// A small integer (polynomial degree), chosen by AICc.
    Degree(usize),
    /// No nonlinear parameter.
    None,
}

impl EffectKind {
    /// Every candidate, in the order they are reported when tied.
    pub const ALL: [EffectKind; 12] = [
        EffectKind::Hysteresis,
        EffectKind::AirCompliance,
        EffectKind::SensorLag,
        EffectKind::TransportDelay,
        EffectKind::DeliveryLag,
        EffectKind::Inertance,
        EffectKind::OffsetDrift,
        EffectKind::VolumeDrift,
        EffectKind::Backlash,
        EffectKind::Ripple,
        EffectKind::PumpRipple,
        EffectKind::Leak,
    ];

    /// Stable machine name (JSON, CLI).
    pub fn name(self) -> &'static str {
        match self {
            EffectKind::Hysteresis => "hysteresis",
            EffectKind::AirCompliance => "air_compliance",
            EffectKind::SensorLag => "sensor_lag",
            EffectKind::TransportDelay => "transport_delay",
            EffectKind::DeliveryLag => "delivery_lag",
            EffectKind::Inertance => "inertance",
            EffectKind::OffsetDrift => "offset_drift",
            EffectKind::VolumeDrift => "volume_drift",
            EffectKind::Backlash => "backlash",
            EffectKind::Ripple => "ripple",
            EffectKind::PumpRipple => "pump_ripple",
            EffectKind::Leak => "leak",
        }
    }

    /// One sentence of physics, for the person reading the report.
    pub fn story(self) -> &'static str {
        match self {
            EffectKind::Hysteresis => {
                "Friction in the membrane folds or the plunger seal makes pressure on the way up exceed pressure on the way down by a gap that does not depend on speed, switching over a small volume after each reversal."
            }
            EffectKind::AirCompliance => {
                "A trapped air bubble compresses as pressure rises (Boyle's law), so the chamber receives less volume than the syringe delivers and the pressure lags the plunger, most at low pressure."
            }
            EffectKind::SensorLag => {
                "The pressure sensor (or its filter) responds to a step with a first-order exponential of time constant tau, so fast pressure changes are reported late and smoothed."
            }
            EffectKind::TransportDelay => {
                "Pressure is reported a fixed time after the volume that caused it (a sampling offset or pressure-wave travel), so the whole pressure trace is shifted in time."
            }
            EffectKind::DeliveryLag => {
                "The motor, lead screw, plunger seal and tubing deliver the commanded motion late and rounded off (a critically damped lag of time constant tau, about 2 tau late), so the chamber sees a smoothed, delayed copy of the logged volume and flow."
            }
            EffectKind::Inertance => {
                "The water column in the tube has mass, so accelerating the flow takes a pressure proportional to the volumetric acceleration."
            }
            EffectKind::OffsetDrift => {
                "The sensor's zero creeps slowly (warm-up, temperature), adding an offset that changes over minutes, independent of what the pump does."
            }
            EffectKind::VolumeDrift => {
                "The volume reading creeps away from the true volume at a steady rate (an integrated flow-sensor bias or miscounted steps), so the same pressure appears at a sliding volume."
            }
            EffectKind::Backlash => {
                "Play between lead-screw nut and plunger: after each reversal the motor turns through a dead band before the plunger moves, so volume and flow reach the chamber late and offset by half the play."
            }
            EffectKind::Ripple => {
                "A periodic disturbance at one frequency (pump or motor ripple, mains pickup) rides on the pressure."
            }
            EffectKind::PumpRipple => {
                "The lead screw's pitch error makes the plunger run ahead of and behind the step count once per screw turn, so pressure ripples periodically in volume (in time its frequency follows the flow): the stiffness times the volume error plus the damping times its rate."
            }
            EffectKind::Leak => {
                "Fluid escapes through a seal or fitting at a rate proportional to pressure, so the chamber slowly holds less than the syringe has delivered."
            }
        }
    }

    /// Number of added columns (input transforms and filters add none).
    pub fn added_columns(self, theta: f64) -> usize {
        match self {
            EffectKind::Hysteresis | EffectKind::Ripple | EffectKind::PumpRipple => 2,
            EffectKind::Inertance => 1,
            EffectKind::OffsetDrift => theta as usize,
            _ => 0,
        }
    }

    /// Whether the effect has a searched nonlinear parameter (counts as one parameter in tests).
    pub fn has_nonlinear(self) -> bool {
        !matches!(self, EffectKind::Inertance | EffectKind::OffsetDrift)
    }

    /// The search range, from the data's scales.
    pub fn search(self, sc: &Scales) -> Search {
        match self {
            EffectKind::Hysteresis => Search::Log(0.002 * sc.v_range, 0.5 * sc.v_range),
            // Down to a few motor steps of play (0.1 mm³ on a 550 mm³ stroke): at the paper's
            // stiffest point 0.1 mm³ is already 0.03 kPa, above a frame's noise.
            EffectKind::Backlash => Search::Log(0.0002 * sc.v_range, 0.2 * sc.v_range),
            EffectKind::AirCompliance => Search::Log(0.002 * sc.v_range, 1.0 * sc.v_range),
            EffectKind::SensorLag => {
                Search::Log(0.25 * sc.dt, (3.0f64).min(sc.duration / 20.0).max(sc.dt))
            }
            EffectKind::TransportDelay => {
                Search::Log(0.25 * sc.dt, (1.5f64).min(sc.duration / 20.0).max(sc.dt))
            }
            EffectKind::DeliveryLag => {
                Search::Log(0.05 * sc.dt, (0.75f64).min(sc.duration / 40.0).max(sc.dt))
            }
            EffectKind::VolumeDrift => Search::Signed(
                0.002 * sc.v_range / sc.duration,
                1.0 * sc.v_range / sc.duration,
            ),
            EffectKind::Leak => {
                if sc.p_integral > 0.0 {
                    Search::Log(
                        0.002 * sc.v_range / sc.p_integral,
                        1.0 * sc.v_range / sc.p_integral,
                    )
                } else {
                    Search::None
                }
            }
            EffectKind::Ripple => Search::Spectral,
            EffectKind::PumpRipple => Search::VolumeSpectral,
            EffectKind::OffsetDrift => Search::Degree(3),
            EffectKind::Inertance => Search::None,
        }
    }

    /// Whether the firmware's model (`model_core::poly::PolyModel`: polynomial plus linear AR terms
    /// on v(t−k), v̇(t−k)) can carry this effect, and why (not).
    pub fn device_support(self) -> (bool, &'static str) {
        match self {
            EffectKind::Inertance => (
                true,
                "L·v̈ with v̈ taken as the backward difference (v̇(t) − v̇(t−1))/Δt is the AR(1) flow term β·v̇(t−1) plus a change of the v̇ coefficient, which PolyModel evaluates",
            ),
            EffectKind::Hysteresis => (false, "needs the hysteron state of the volume history; PolyModel has no such state"),
            EffectKind::AirCompliance => (false, "needs the measured pressure and a pressure-scheduled lag; PolyModel has no output feedback"),
            EffectKind::SensorLag => (false, "a lag on the output needs past pressures (output autoregression), which PolyModel does not have"),
            EffectKind::TransportDelay => (false, "needs the polynomial evaluated on delayed inputs; PolyModel's AR terms are only linear in past inputs"),
            EffectKind::DeliveryLag => (false, "needs the polynomial evaluated on filtered inputs; PolyModel's AR terms are only linear in past inputs"),
            EffectKind::OffsetDrift => (false, "depends on wall-clock time since the log began; on the device re-zero the sensor instead"),
            EffectKind::VolumeDrift => (false, "depends on wall-clock time since the log began; correct the volume source instead"),
            EffectKind::Backlash => (false, "needs the play-operator state of the nut position; compensate in motion planning instead"),
            EffectKind::Ripple => (false, "depends on absolute phase of a clock the device does not share with the log"),
            EffectKind::PumpRipple => (false, "needs sines of the plunger position at the screw's period; PolyModel has polynomial and linear autoregressive terms only"),
            EffectKind::Leak => (false, "needs the integral of measured pressure since the start; PolyModel has no such state"),
        }
    }
}

/// Scales of one data set, from which search ranges are set (so the library is not tuned to a rig).
#[derive(Clone, Copy, Debug)]
pub struct Scales {
    /// Volume range (mm³).
    pub v_range: f64,
    /// Median sample interval (s).
    pub dt: f64,
    /// Log duration (s).
    pub duration: f64,
    /// `∫ P dt` over the log (kPa·s).
    pub p_integral: f64,
}

/// One effect with its nonlinear parameter fixed.
#[derive(Clone, Debug)]
pub struct Effect {
    /// Which effect.
    pub kind: EffectKind,
    /// Its nonlinear parameter (width mm³, τ s, delay s, air mm³, rate mm³/s, λ mm³/(kPa·s),
    /// frequency Hz, drift degree), unused for inertance.
    pub theta: f64,
    /// Air compliance and pump ripple: the damping `c = ∂P/∂v̇` per sample, from the model it was
    /// added to.
    pub damping: Option<std::sync::Arc<Vec<f64>>>,
    /// Pump ripple: the stiffness `k = ∂P/∂v` per sample, from the model it was added to.
    pub stiffness: Option<std::sync::Arc<Vec<f64>>>,
    /// Backlash and transport delay: the log's samples are instants (a sampling sensor) rather
    /// than means over each frame (an averaging one, the default): the play operator then acts on
    /// the samples themselves, and a delayed flow is the volume interpolant's derivative. The
    /// search tries both and keeps the better fit.
    pub point_sampled: bool,
    /// Pump ripple: the volume error `(a, b)` (mm³) already applied exactly as an input
    /// transform, `u = v + a sin φ + b cos φ`; the two columns then fit the remaining correction
    /// to first order (the search iterates this Gauss–Newton step).
    pub ripple_offset: (f64, f64),
    /// Pump ripple: how far the logged volume trails the plunger while it moves, by speed
    /// ([`CountLag`]).
    pub count_lag: CountLag,
}

/// How far (mm³) a logged step count trails the plunger while it moves, which shifts a pump
/// ripple's phase one way on inflation and the other on deflation.
///
/// A count trails continuous motion by up to one step, and by how much depends on the step rate:
/// the firmware reads the count at each of a frame's conversions, and where the step period
/// divides the conversion period (2 000 steps/s against 200 conversions/s) every conversion reads
/// the same fraction of a step; at other rates the fractions spread out and average to about
/// half a step. So the lag is one number per speed the log dwells at (its cruise speeds,
/// [`cruise_speeds`]), interpolated linearly in |v̇| between them and held beyond; a log without
/// plateaus of speed gets one lag for all speeds.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CountLag {
    /// Speeds |v̇| (mm³/s, ascending) the lags are given at; empty: one lag for every speed.
    pub speeds: std::sync::Arc<Vec<f64>>,
    /// The lag at each speed (or the one lag), mm³; empty: no lag.
    pub lags: Vec<f64>,
    /// Standard error of each lag from the last linearised fit, mm³.
    pub se: Vec<f64>,
}

impl CountLag {
    /// No lag, to be fitted at `speeds` (one lag when `speeds` is empty).
    pub fn zero(speeds: std::sync::Arc<Vec<f64>>) -> Self {
        let n = speeds.len().max(1);
        Self {
            speeds,
            lags: vec![0.0; n],
            se: vec![f64::NAN; n],
        }
    }

    /// Linear-interpolation weights of the lags at `speed`: `(i, j, f)` with the lag
    /// `(1 − f)·lags[i] + f·lags[j]`.
    pub fn weights(&self, speed: f64) -> (usize, usize, f64) {
        let s = &self.speeds;
        if s.len() <= 1 {
            return (0, 0, 0.0);
        }
        match s.iter().position(|&k| k >= speed) {
            Some(0) => (0, 0, 0.0),
            None => (s.len() - 1, s.len() - 1, 0.0),
            Some(j) => (j - 1, j, (speed - s[j - 1]) / (s[j] - s[j - 1])),
        }
    }

    /// The lag at `speed`, mm³.
    pub fn at(&self, speed: f64) -> f64 {
        if self.lags.is_empty() {
            return 0.0;
        }
        let (i, j, f) = self.weights(speed);
        (1.0 - f) * self.lags[i] + f * self.lags[j]
    }
}

/// The speeds |v̇| (mm³/s, ascending) a log dwells at: clusters of frames whose flow is flat
/// (within 0.1 % of the top speed of both neighbours) and moving (above 2 % of it), clusters 1 %
/// of the top speed wide holding at least 2 % of the flat frames (and 25). At most 8, the most
/// populated; none when the flow has no plateaus (a ventilator's, say).
pub fn cruise_speeds(vdot: &[f64]) -> Vec<f64> {
    let top = vdot.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
    if top <= 0.0 || vdot.len() < 3 {
        return Vec::new();
    }
    let mut flat: Vec<f64> = (1..vdot.len() - 1)
        .filter(|&k| {
            vdot[k].abs() > 0.02 * top
                && (vdot[k] - vdot[k - 1]).abs() <= 1e-3 * top
                && (vdot[k + 1] - vdot[k]).abs() <= 1e-3 * top
        })
        .map(|k| vdot[k].abs())
        .collect();
    flat.sort_by(f64::total_cmp);
    let min_size = 25.max(flat.len() / 50);
    let mut clusters: Vec<(usize, f64)> = Vec::new();
    let mut start = 0;
    for k in 1..=flat.len() {
        if k == flat.len() || flat[k] - flat[k - 1] > 0.01 * top {
            if k - start >= min_size {
                clusters.push((k - start, flat[(start + k) / 2]));
            }
            start = k;
        }
    }
    clusters.sort_by_key(|c| std::cmp::Reverse(c.0));
    clusters.truncate(8);
    let mut speeds: Vec<f64> = clusters.into_iter().map(|c| c.1).collect();
    speeds.sort_by(f64::total_cmp);
    speeds
}

impl Effect {
    /// An effect without auxiliary data.
    pub fn new(kind: EffectKind, theta: f64) -> Self {
        Self {
            kind,
            theta,
            damping: None,
            stiffness: None,
            point_sampled: false,
            ripple_offset: (0.0, 0.0),
            count_lag: CountLag::default(),
        }
    }
}

/// A data set prepared for building designs: the series, the baseline basis, and derived signals.
#[derive(Clone, Debug)]
pub struct Prepared {
    /// The data.
    pub series: Series,
    /// The baseline basis (scaling from the raw inputs).
    pub basis: PolyBasis,
    /// Measured pressure as the scheduling signal of leak and air compliance.
    pub p_sched: Vec<f64>,
    /// `∫ P dt` from the first sample (kPa·s).
    pub p_int: Vec<f64>,
    /// Time mapped onto [−1, 1].
    pub s: Vec<f64>,
    /// Data scales.
    pub scales: Scales,
    /// The logged motion rebuilt at `signal::SUB_SAMPLES` instants per frame (position, flow).
    pub subframe: (Vec<f64>, Vec<f64>),
    /// The speeds the log dwells at ([`cruise_speeds`]), where a pump ripple's count lag is fitted.
    pub cruise_speeds: std::sync::Arc<Vec<f64>>,
    /// Training row indices.
    pub train_rows: Vec<usize>,
    /// Held-out row indices.
    pub held_rows: Vec<usize>,
    /// The baseline columns on the untransformed inputs, with the basis they were built with (a
    /// candidate search rebuilds the design hundreds of times; most candidates leave the inputs
    /// alone). Rebuilt whenever `basis` has been changed since.
    base_cols: std::sync::OnceLock<(PolyBasis, Vec<Vec<f64>>)>,
}

impl Prepared {
    /// Baseline columns on the raw inputs (cached for the current basis).
    fn raw_columns(&self) -> Vec<Vec<f64>> {
        let (basis, cols) = self.base_cols.get_or_init(|| {
            (
                self.basis.clone(),
                self.basis.columns(&self.series.v, &self.series.vdot),
            )
        });
        if *basis == self.basis {
            cols.clone()
        } else {
            self.basis.columns(&self.series.v, &self.series.vdot)
        }
    }
}

impl Prepared {
    /// Prepares a series for a baseline of shape (n, m).
    pub fn new(series: Series, n: usize, m: usize) -> Self {
        let basis = PolyBasis::for_data(&series.v, &series.vdot, n, m);
        // Unsmoothed: noise enters δ and τ only through factors ≪ 1 (V_a/P_atm·σ), while smoothing
        // would blur the pressure jumps at reversals where the air pocket matters most.
        let p_sched = series.p.clone();
        let p_int = signal::cumulative_integral(&series.t, &p_sched);
        let t0 = series.t[0];
        let duration = series.t[series.t.len() - 1] - t0;
        let s = series
            .t
            .iter()
            .map(|&t| 2.0 * (t - t0) / duration - 1.0)
            .collect();
        let mut dts: Vec<f64> = series.t.windows(2).map(|w| w[1] - w[0]).collect();
        dts.sort_by(f64::total_cmp);
        let dt = dts[dts.len() / 2];
        let v_range = 2.0 * basis.v_scale;
        let p_integral = *p_int.last().unwrap_or(&0.0);
        let train_rows = (0..series.len()).filter(|&k| series.train[k]).collect();
        let held_rows = (0..series.len()).filter(|&k| !series.train[k]).collect();
        let subframe = signal::frame_instants(&series.t, &series.v, &series.vdot);
        Self {
            subframe,
            cruise_speeds: std::sync::Arc::new(cruise_speeds(&series.vdot)),
            basis,
            p_sched,
            p_int,
            s,
            scales: Scales {
                v_range,
                dt,
                duration,
                p_integral,
            },
            train_rows,
            held_rows,
            series,
            base_cols: std::sync::OnceLock::new(),
        }
    }
}

/// Regressor columns of an augmented model, with labels and owners.
#[derive(Clone, Debug)]
pub struct Design {
    /// Columns over every sample (train and held-out).
    pub cols: Vec<Vec<f64>>,
    /// What each column is.
    pub labels: Vec<String>,
    /// Index into the effect list of the effect a column belongs to; `None` for the baseline.
    pub owner: Vec<Option<usize>>,
}

/// Legendre polynomial `P_d(s)` by Bonnet's recurrence.
fn legendre(d: usize, s: f64) -> f64 {
    let (mut p0, mut p1) = (1.0, s);
    if d == 0 {
        return 1.0;
    }
    for k in 1..d {
        let p2 = ((2 * k + 1) as f64 * s * p1 - k as f64 * p0) / (k + 1) as f64;
        p0 = p1;
        p1 = p2;
    }
    p1
}

/// Builds the design of the baseline augmented with `effects` (see the module docs for the order:
/// input transforms, baseline columns, added columns, output filters).
pub fn build(prep: &Prepared, effects: &[Effect]) -> Design {
    let mut cols = if transforms_inputs(effects) {
        input_transformed_columns(prep, effects)
    } else {
        prep.raw_columns()
    };
    let mut labels: Vec<String> = (0..cols.len()).map(|i| prep.basis.label(i)).collect();
    let mut owner: Vec<Option<usize>> = vec![None; cols.len()];
    added_and_filters(prep, effects, &mut cols, &mut labels, &mut owner);
    Design {
        cols,
        labels,
        owner,
    }
}

/// Whether any effect transforms the baseline's inputs.
fn transforms_inputs(effects: &[Effect]) -> bool {
    effects.iter().any(|e| {
        matches!(
            e.kind,
            EffectKind::DeliveryLag
                | EffectKind::TransportDelay
                | EffectKind::Backlash
                | EffectKind::VolumeDrift
                | EffectKind::Leak
                | EffectKind::AirCompliance
        ) || (e.kind == EffectKind::PumpRipple && e.ripple_offset != (0.0, 0.0))
    })
}

/// Training SSE of the baseline augmented with `effects`, for the parameter searches, without
/// building the design: the baseline block's Gram matrix from Chebyshev moments
/// (`lsq::sse_fast_poly`). `None` when an output filter (sensor lag, air compliance) makes the
/// filtered baseline columns no longer products of Chebyshev polynomials; then the caller builds
/// the design.
pub fn sse_structured(prep: &Prepared, effects: &[Effect]) -> Option<f64> {
    if effects
        .iter()
        .any(|e| matches!(e.kind, EffectKind::SensorLag | EffectKind::AirCompliance))
    {
        return None;
    }
    let se = &prep.series;
    let rows = &prep.train_rows;
    let gather = |x: &[f64]| -> Vec<f64> { rows.iter().map(|&r| x[r]).collect() };
    let (v, f) = if transforms_inputs(effects) {
        let (v, f) = transformed_inputs(prep, effects);
        (gather(&v), gather(&f))
    } else {
        (gather(&se.v), gather(&se.vdot))
    };
    // The span of T_i(x)T_j(y), i ≤ n, j ≤ m, is every polynomial of degree ≤ (n, m) in (v, v̇)
    // whatever the affine scaling, and so is the SSE; scaling onto the transformed inputs' own
    // range keeps the Gram matrix well conditioned when a transform (leak, drift) moves them
    // outside the baseline's [−1, 1].
    let b = &PolyBasis::for_data(&v, &f, prep.basis.n, prep.basis.m);
    let (tx, ty) = b.factors(&v, &f, 2 * b.n, 2 * b.m);
    let (mut extra, mut labels, mut owner) = (Vec::new(), Vec::new(), Vec::new());
    added_and_filters(prep, effects, &mut extra, &mut labels, &mut owner);
    let extra: Vec<Vec<f64>> = extra.iter().map(|c| gather(c)).collect();
    let y = gather(&se.p);
    let mean = y.iter().sum::<f64>() / y.len().max(1) as f64;
    let yc: Vec<f64> = y.iter().map(|p| p - mean).collect();
    Some(lsq::sse_fast_poly(&tx, &ty, b.n, b.m, &extra, &yc))
}

/// Baseline columns on the inputs after the input transforms (module docs).
fn input_transformed_columns(prep: &Prepared, effects: &[Effect]) -> Vec<Vec<f64>> {
    let (v, f) = transformed_inputs(prep, effects);
    prep.basis.columns(&v, &f)
}

/// Volume and flow after the input transforms (module docs).
fn transformed_inputs(prep: &Prepared, effects: &[Effect]) -> (Vec<f64>, Vec<f64>) {
    let se = &prep.series;
    let t = &se.t;
    let mut v = se.v.clone();
    let mut f = se.vdot.clone();
    let t0 = t[0];
    // Whether v, f are still the logged ones (then the motion inside the frames is cached).
    let mut raw = true;
    // Input transforms, in the physical order along the chain: timing, nut→plunger, then volume
    // that never reaches the chamber.
    for kind in [
        EffectKind::DeliveryLag,
        EffectKind::TransportDelay,
        EffectKind::Backlash,
        EffectKind::PumpRipple,
        EffectKind::VolumeDrift,
        EffectKind::Leak,
        EffectKind::AirCompliance,
    ] {
        for e in effects.iter().filter(|e| e.kind == kind) {
            match kind {
                EffectKind::TransportDelay => {
                    (v, f) = signal::delay_hermite(t, &v, &f, e.theta, !e.point_sampled);
                }
                EffectKind::DeliveryLag => {
                    // Each stage lags the volume with the flow as its exact slopes (the lag of a
                    // derivative is the derivative of the lag), the flow with Akima slopes.
                    let c = signal::lag_cubic_coeffs(t, |_| e.theta);
                    for _ in 0..2 {
                        let fv = signal::lag_cubic(&c, &f, &signal::akima_slopes(t, &f));
                        v = signal::lag_cubic(&c, &v, &f);
                        f = fv;
                    }
                }
                EffectKind::Backlash if e.point_sampled => {
                    let z = signal::play(&v, e.theta);
                    let h = 0.5 * e.theta;
                    for k in 0..v.len() {
                        let gap = v[k] - z[k];
                        let engaged = gap.abs() >= h - 1e-9 * (1.0 + h) && gap * f[k] > 0.0;
                        if !engaged {
                            f[k] = 0.0;
                        }
                    }
                    v = z;
                }
                EffectKind::Backlash if raw => {
                    (v, f) = signal::play_instants(&prep.subframe, e.theta);
                }
                EffectKind::Backlash => {
                    (v, f) = signal::play_frames(t, &v, &f, e.theta);
                }
                EffectKind::PumpRipple if e.ripple_offset != (0.0, 0.0) => {
                    let fresh;
                    let sub = if raw {
                        &prep.subframe
                    } else {
                        fresh = signal::frame_instants(t, &v, &f);
                        &fresh
                    };
                    (v, f) = pump_ripple_inputs(sub, e.theta, e.ripple_offset, &e.count_lag);
                }
                EffectKind::PumpRipple => continue,
                EffectKind::VolumeDrift => {
                    for k in 0..v.len() {
                        v[k] -= e.theta * (t[k] - t0);
                        f[k] -= e.theta;
                    }
                }
                EffectKind::Leak => {
                    for k in 0..v.len() {
                        v[k] -= e.theta * prep.p_int[k];
                        f[k] -= e.theta * prep.p_sched[k];
                    }
                }
                EffectKind::AirCompliance => {
                    for k in 0..v.len() {
                        let p = prep.p_sched[k].max(-0.9 * P_ATM_KPA);
                        v[k] -= e.theta * p / (P_ATM_KPA + p);
                    }
                }
                _ => {}
            }
            raw = false;
        }
    }
    (v, f)
}

/// The pump ripple's two columns for period `lambda` (mm³): the pressure a volume error
/// `δ = a sin φ + b cos φ`, `φ = 2π v/Λ`, makes to first order through the model's stiffness k and
/// damping c, `k δ + c δ̇` with `δ̇ = (2π/Λ) v̇ (a cos φ − b sin φ)`, averaged over each frame's
/// instants (at 100 mm³/s an 8 mm³ period is 12.5 Hz, half the frame rate: the frame mean of the
/// ripple is a fraction of its amplitude, which the average reproduces).
pub fn pump_ripple_columns(
    sub: &(Vec<f64>, Vec<f64>),
    k: &[f64],
    c: &[f64],
    lambda: f64,
    count_lag: &CountLag,
) -> (Vec<f64>, Vec<f64>) {
    let w = std::f64::consts::TAU / lambda;
    let ns = signal::SUB_SAMPLES;
    let n = k.len();
    let (mut a, mut b) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for f in 0..n {
        let (mut sa, mut sb) = (0.0, 0.0);
        for j in f * ns..(f + 1) * ns {
            let (sin, cos) = (w * plunger(sub.0[j], sub.1[j], count_lag)).sin_cos();
            let q = c[f] * w * sub.1[j];
            sa += k[f] * sin + q * cos;
            sb += k[f] * cos - q * sin;
        }
        a.push(sa / ns as f64);
        b.push(sb / ns as f64);
    }
    (a, b)
}

/// The plunger's position where the logged volume `x` trails it by `count_lag` in the direction
/// of motion `q`.
fn plunger(x: f64, q: f64, count_lag: &CountLag) -> f64 {
    if q == 0.0 {
        x
    } else {
        x + count_lag.at(q.abs()) * q.signum()
    }
}

/// The derivatives of a pump ripple's pressure `k δ + c δ̇` with respect to each of `count_lag`'s
/// lags (one column each), for the volume error `δ = a sin φ + b cos φ`, `φ = 2π x/Λ` at the
/// plunger, averaged over each frame's instants: shifting the plunger by `ℓ` in the direction of
/// motion `s = sign q` gives `∂δ/∂ℓ = s w (a cos φ − b sin φ)` and
/// `∂δ̇/∂ℓ = −s w² q (a sin φ + b cos φ)`, `w = 2π/Λ`, each weighted by the lag's share at the
/// instant's speed. One Gauss–Newton step in the lags fits these columns with the model.
pub fn count_lag_columns(
    sub: &(Vec<f64>, Vec<f64>),
    k: &[f64],
    c: &[f64],
    lambda: f64,
    (a, b): (f64, f64),
    count_lag: &CountLag,
) -> Vec<Vec<f64>> {
    let w = std::f64::consts::TAU / lambda;
    let ns = signal::SUB_SAMPLES;
    let n = k.len();
    let mut cols = vec![vec![0.0; n]; count_lag.lags.len()];
    for f in 0..n {
        for j in f * ns..(f + 1) * ns {
            let (x, q) = (sub.0[j], sub.1[j]);
            if q == 0.0 {
                continue;
            }
            let (sin, cos) = (w * plunger(x, q, count_lag)).sin_cos();
            let d =
                q.signum() * w * (k[f] * (a * cos - b * sin) - c[f] * w * q * (a * sin + b * cos))
                    / ns as f64;
            let (i0, i1, fr) = count_lag.weights(q.abs());
            cols[i0][f] += (1.0 - fr) * d;
            cols[i1][f] += fr * d;
        }
    }
    cols
}

/// Frame means of the displaced volume `u = x + a sin φ + b cos φ`, `φ = 2π x/Λ`, and its rate
/// `u̇ = ẋ (1 + (2π/Λ)(a cos φ − b sin φ))`, over the instants of each frame
/// (`signal::frame_instants`): at 100 mm³/s an 8 mm³ period is 12.5 Hz, and the flow ripple
/// (±16 % for 0.2 mm³) must be averaged where it happens, not at the frame's mean volume.
fn pump_ripple_inputs(
    (x, q): &(Vec<f64>, Vec<f64>),
    lambda: f64,
    (a, b): (f64, f64),
    count_lag: &CountLag,
) -> (Vec<f64>, Vec<f64>) {
    let w = std::f64::consts::TAU / lambda;
    let ns = signal::SUB_SAMPLES as f64;
    x.chunks(signal::SUB_SAMPLES)
        .zip(q.chunks(signal::SUB_SAMPLES))
        .map(|(xs, qs)| {
            let (mut u, mut ud) = (0.0, 0.0);
            for (&x, &q) in xs.iter().zip(qs) {
                let (sin, cos) = (w * plunger(x, q, count_lag)).sin_cos();
                u += x + a * sin + b * cos;
                ud += q * (1.0 + w * (a * cos - b * sin));
            }
            (u / ns, ud / ns)
        })
        .unzip()
}

/// A design about to be filtered by a sensor lag, with each column's Akima slopes, which do not
/// depend on τ: sensor lag is the last step of [`build`], so adding it to a model whose design is
/// known only filters that design, and a search over τ need not rebuild it.
pub struct LagBase {
    cols: Vec<Vec<f64>>,
    slopes: Vec<Vec<f64>>,
}

impl LagBase {
    /// The design `cols` (every sample) of the model the lag is added to.
    pub fn new(prep: &Prepared, cols: &[Vec<f64>]) -> Self {
        Self {
            cols: cols.to_vec(),
            slopes: signal::akima_slopes_all(&prep.series.t, cols),
        }
    }

    /// Training SSE of the design filtered by a sensor lag of time constant `tau`.
    pub fn sse(&self, prep: &Prepared, tau: f64) -> f64 {
        let mut cols = self.cols.clone();
        let coeffs = signal::lag_cubic_coeffs(&prep.series.t, |_| tau);
        signal::lag_cubic_apply_with(&coeffs, &mut cols, &self.slopes);
        lsq::sse_fast(&cols, &prep.series.p, &prep.train_rows)
    }
}

/// Candidate periods (mm³) of a pump ripple in `resid`, best first, with the spacing of the
/// spatial-frequency grid they came from (1/mm³): a periodogram against volume over spatial
/// frequencies `1/Λ` from `1/(0.1·range)` up to two periods per frame of median motion, on a
/// uniform grid fine enough that the phase drifts by at most a quarter turn over the stroke (at
/// most [`RIPPLE_SCAN_STEPS`] steps), scored by the residual energy the two columns (at the frames'
/// mean volumes, on at most ~3,000 training frames) capture. Returns up to three local maxima.
pub fn pump_ripple_periods(
    prep: &Prepared,
    resid: &[f64],
    k: &[f64],
    c: &[f64],
) -> (Vec<f64>, f64) {
    let se = &prep.series;
    let mut moving: Vec<f64> = se
        .vdot
        .iter()
        .map(|f| f.abs())
        .filter(|&f| f > 1e-9)
        .collect();
    if moving.is_empty() {
        return (Vec::new(), 0.0);
    }
    moving.sort_by(f64::total_cmp);
    let flow = moving[moving.len() / 2];
    let range = prep.scales.v_range;
    let lo = (0.5 * flow * prep.scales.dt).max(1e-6 * range);
    let hi = 0.1 * range;
    if lo >= hi {
        return (Vec::new(), 0.0);
    }
    let (k_lo, k_hi) = (1.0 / hi, 1.0 / lo);
    let steps = ((k_hi - k_lo) * 4.0 * range)
        .ceil()
        .min(RIPPLE_SCAN_STEPS as f64) as usize;
    let dk = (k_hi - k_lo) / steps as f64;
    let stride = (prep.train_rows.len() / 3000).max(1);
    let rows: Vec<usize> = prep.train_rows.iter().copied().step_by(stride).collect();
    // Per row: the phase 2πκv as a unit complex number, advanced along the grid by a fixed
    // rotation (4 multiplications per step instead of a sine and a cosine).
    let tau = std::f64::consts::TAU;
    let mut z: Vec<(f64, f64)> = rows
        .iter()
        .map(|&r| {
            let (s, c) = (tau * k_lo * se.v[r]).sin_cos();
            (c, s)
        })
        .collect();
    let rot: Vec<(f64, f64)> = rows
        .iter()
        .map(|&r| {
            let (s, c) = (tau * dk * se.v[r]).sin_cos();
            (c, s)
        })
        .collect();
    let mut power = Vec::with_capacity(steps + 1);
    for i in 0..=steps {
        let w = tau * (k_lo + i as f64 * dk);
        let (mut g0, mut g1, mut a00, mut a01, mut a11) = (0.0, 0.0, 0.0, 0.0, 0.0);
        for (j, &r) in rows.iter().enumerate() {
            let (cos, sin) = z[j];
            let q = c[r] * w * se.vdot[r];
            let x0 = k[r] * sin + q * cos;
            let x1 = k[r] * cos - q * sin;
            g0 += x0 * resid[r];
            g1 += x1 * resid[r];
            a00 += x0 * x0;
            a01 += x0 * x1;
            a11 += x1 * x1;
            let (rc, rs) = rot[j];
            z[j] = (cos * rc - sin * rs, sin * rc + cos * rs);
        }
        let det = a00 * a11 - a01 * a01;
        power.push(if det <= 1e-12 * (a00 * a11).max(f64::MIN_POSITIVE) {
            0.0
        } else {
            (a11 * g0 * g0 - 2.0 * a01 * g0 * g1 + a00 * g1 * g1) / det
        });
    }
    let mut peaks: Vec<usize> = (1..power.len().saturating_sub(1))
        .filter(|&i| power[i] > power[i - 1] && power[i] >= power[i + 1])
        .collect();
    peaks.sort_by(|&a, &b| power[b].total_cmp(&power[a]));
    let periods = peaks
        .into_iter()
        .take(3)
        .map(|i| 1.0 / (k_lo + i as f64 * dk))
        .collect();
    (periods, dk)
}

/// Most spatial frequencies the pump-ripple periodogram scans.
pub const RIPPLE_SCAN_STEPS: usize = 6000;

/// Appends the added columns and applies the output filters (module docs).
fn added_and_filters(
    prep: &Prepared,
    effects: &[Effect],
    cols: &mut Vec<Vec<f64>>,
    labels: &mut Vec<String>,
    owner: &mut Vec<Option<usize>>,
) {
    let se = &prep.series;
    let t = &se.t;
    let t0 = t[0];
    for (idx, e) in effects.iter().enumerate() {
        match e.kind {
            EffectKind::Hysteresis => {
                let h = signal::duhem(&se.v, e.theta);
                let hx: Vec<f64> = h
                    .iter()
                    .zip(&se.v)
                    .map(|(h, v)| h * (v - prep.basis.v_offset) / prep.basis.v_scale)
                    .collect();
                cols.push(h);
                cols.push(hx);
                labels.push("hysteresis h_w".into());
                labels.push("hysteresis h_w·x".into());
                owner.extend([Some(idx), Some(idx)]);
            }
            EffectKind::Inertance => {
                cols.push(se.vddot.clone());
                labels.push("inertance vddot".into());
                owner.push(Some(idx));
            }
            EffectKind::OffsetDrift => {
                for d in 1..=(e.theta as usize) {
                    cols.push(prep.s.iter().map(|&s| legendre(d, s)).collect());
                    labels.push(format!("offset drift P{d}(s)"));
                    owner.push(Some(idx));
                }
            }
            EffectKind::PumpRipple => {
                let zero = std::sync::Arc::new(vec![0.0; t.len()]);
                let k = e.stiffness.as_ref().unwrap_or(&zero);
                let c = e.damping.as_ref().unwrap_or(&zero);
                let (a, b) = pump_ripple_columns(&prep.subframe, k, c, e.theta, &e.count_lag);
                cols.push(a);
                cols.push(b);
                labels.push("pump ripple in phase".into());
                labels.push("pump ripple quadrature".into());
                owner.extend([Some(idx), Some(idx)]);
            }
            EffectKind::Ripple => {
                let w = 2.0 * std::f64::consts::PI * e.theta;
                cols.push(t.iter().map(|&tk| (w * (tk - t0)).sin()).collect());
                cols.push(t.iter().map(|&tk| (w * (tk - t0)).cos()).collect());
                labels.push("ripple sin".into());
                labels.push("ripple cos".into());
                owner.extend([Some(idx), Some(idx)]);
            }
            _ => {}
        }
    }
    // Output filters: air compliance's pressure-scheduled lag, then the sensor's own lag.
    for e in effects
        .iter()
        .filter(|e| e.kind == EffectKind::AirCompliance)
    {
        let damping = e.damping.clone();
        let tau: Vec<f64> = (0..t.len())
            .map(|k| {
                let c = damping.as_ref().map_or(0.0, |d| d[k].max(0.0));
                let p = prep.p_sched[k].max(-0.9 * P_ATM_KPA);
                c * e.theta * P_ATM_KPA / (P_ATM_KPA + p).powi(2)
            })
            .collect();
        // Over each interval the time constant at its midpoint (the mean of its ends): second-order
        // accurate where τ changes fast, at the reversals.
        let coeffs = signal::lag_cubic_coeffs(t, |k| 0.5 * (tau[k] + tau[k.saturating_sub(1)]));
        signal::lag_cubic_apply_all(t, &coeffs, cols);
    }
    for e in effects.iter().filter(|e| e.kind == EffectKind::SensorLag) {
        let coeffs = signal::lag_cubic_coeffs(t, |_| e.theta);
        signal::lag_cubic_apply_all(t, &coeffs, cols);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cruise_speeds_are_the_plateaus_of_the_flow() {
        // 25 Hz: plateaus at +20, −20, +50 and −90 mm³/s joined by 500 mm³/s² ramps, dwell at 0.
        let mut f = Vec::new();
        let mut q: f64 = 0.0;
        for target in [20.0, 0.0, -20.0, 0.0, 50.0, 0.0, -90.0, 0.0] {
            while (q - target).abs() > 1e-9 {
                q += (target - q).clamp(-20.0, 20.0);
                f.push(q);
            }
            f.extend(std::iter::repeat_n(target, 100));
        }
        let s = cruise_speeds(&f);
        assert_eq!(s.len(), 3, "{s:?}");
        for (got, want) in s.iter().zip([20.0, 50.0, 90.0]) {
            assert!((got - want).abs() < 1e-9, "{s:?}");
        }
        // A breathing flow has no plateaus.
        let sine: Vec<f64> = (0..2000).map(|k| 80.0 * (0.05 * k as f64).sin()).collect();
        assert!(cruise_speeds(&sine).is_empty());
    }

    #[test]
    fn count_lag_interpolates_between_speeds_and_holds_beyond() {
        let lag = CountLag {
            speeds: std::sync::Arc::new(vec![20.0, 40.0, 80.0]),
            lags: vec![0.01, 0.03, -0.01],
            se: vec![f64::NAN; 3],
        };
        for (s, want) in [
            (5.0, 0.01),
            (20.0, 0.01),
            (30.0, 0.02),
            (60.0, 0.01),
            (200.0, -0.01),
        ] {
            assert!((lag.at(s) - want).abs() < 1e-15, "{s}: {}", lag.at(s));
        }
        let one = CountLag {
            lags: vec![0.02],
            ..CountLag::zero(std::sync::Arc::new(Vec::new()))
        };
        assert_eq!((one.at(3.0), one.at(300.0)), (0.02, 0.02));
        assert_eq!(CountLag::default().at(50.0), 0.0);
    }

    #[test]
    fn count_lag_columns_are_the_derivatives_of_the_ripple_pressure() {
        // Against central differences of the ripple's pressure a·A + b·B, (A, B) the columns of
        // `pump_ripple_columns`, in each lag.
        let n = 400;
        let t: Vec<f64> = (0..n).map(|k| 0.04 * k as f64).collect();
        let f: Vec<f64> = (0..n)
            .map(|k| match k / 100 {
                0 => 30.0,
                1 => -60.0,
                2 => 90.0,
                _ => -30.0,
            })
            .collect();
        let mut v = vec![100.0; n];
        for k in 1..n {
            v[k] = v[k - 1] + 0.02 * (f[k - 1] + f[k]);
        }
        let sub = signal::frame_instants(&t, &v, &f);
        let k: Vec<f64> = (0..n).map(|i| 0.05 + 1e-4 * i as f64).collect();
        let c: Vec<f64> = (0..n).map(|i| 0.1 - 1e-4 * i as f64).collect();
        let (lambda, ab) = (8.0, (0.2, -0.07));
        let lag = CountLag {
            speeds: std::sync::Arc::new(vec![30.0, 60.0, 90.0]),
            lags: vec![0.01, 0.02, 0.03],
            se: vec![f64::NAN; 3],
        };
        let pressure = |lag: &CountLag| {
            let (a, b) = pump_ripple_columns(&sub, &k, &c, lambda, lag);
            a.iter()
                .zip(&b)
                .map(|(a, b)| ab.0 * a + ab.1 * b)
                .collect::<Vec<f64>>()
        };
        let cols = count_lag_columns(&sub, &k, &c, lambda, ab, &lag);
        let h = 1e-6;
        for i in 0..3 {
            let (mut up, mut down) = (lag.clone(), lag.clone());
            up.lags[i] += h;
            down.lags[i] -= h;
            let (pu, pd) = (pressure(&up), pressure(&down));
            let scale = cols[i].iter().fold(0.0_f64, |m, x| m.max(x.abs()));
            assert!(scale > 0.1, "lag {i} moves the pressure");
            for r in 0..n {
                let fd = (pu[r] - pd[r]) / (2.0 * h);
                assert!(
                    (fd - cols[i][r]).abs() < 1e-6 * scale,
                    "lag {i}, frame {r}: {fd} vs {}",
                    cols[i][r]
                );
            }
        }
    }

    /// `len` frames at 25 Hz of two incommensurate tones, so (v, v̇) fills an area (one tone traces
    /// an ellipse, on which the tensor basis is rank-deficient), prepared for a (3, 2) baseline.
    fn two_tones(len: usize) -> Prepared {
        let t: Vec<f64> = (0..len).map(|k| 0.04 * k as f64).collect();
        let v: Vec<f64> = t
            .iter()
            .map(|&t| 275.0 + 150.0 * (0.3 * t).sin() + 80.0 * (0.71 * t).sin())
            .collect();
        let f: Vec<f64> = t
            .iter()
            .map(|&t| 45.0 * (0.3 * t).cos() + 56.8 * (0.71 * t).cos())
            .collect();
        let p: Vec<f64> = (0..len)
            .map(|k| 2.0 + 0.01 * v[k] + 0.002 * f[k] + 0.05 * (1.7 * t[k]).sin())
            .collect();
        let train: Vec<bool> = (0..len).map(|k| (k / 300) % 5 != 4).collect();
        Prepared::new(Series::new(t, v, f, p, train).unwrap(), 3, 2)
    }

    #[test]
    fn structured_sse_equals_qr_fit_of_the_built_design() {
        // Identity: the moment route (rescaled onto the transformed inputs' own range) and the QR
        // fit of the explicitly built design minimise the same SSE — here with a leak large enough
        // to carry the volume far outside the baseline's [−1, 1], plus added columns.
        let prep = two_tones(3000);
        let lam = 2.0 * prep.scales.v_range / prep.scales.p_integral;
        for effects in [
            vec![Effect::new(EffectKind::Leak, lam)],
            vec![
                Effect::new(EffectKind::Hysteresis, 20.0),
                Effect::new(EffectKind::Ripple, 0.27),
                Effect::new(EffectKind::VolumeDrift, 3.0),
            ],
            vec![Effect::new(EffectKind::OffsetDrift, 2.0)],
        ] {
            let d = build(&prep, &effects);
            let qr = lsq::fit(&d.cols, &prep.series.p, &prep.train_rows)
                .expect("full rank")
                .sse;
            let fast = sse_structured(&prep, &effects).unwrap();
            assert!((fast - qr).abs() < 1e-8 * qr, "{effects:?}: {fast} vs {qr}");
        }
        assert!(sse_structured(&prep, &[Effect::new(EffectKind::SensorLag, 0.1)]).is_none());
    }

    #[test]
    fn filtering_the_known_design_equals_building_with_the_lag() {
        // Identity: sensor lag is build's last step, so LagBase's SSE is the SSE of the design
        // built with the lag, for a model with input transforms, added columns and air.
        let len = 1500;
        let prep = two_tones(len);
        let air = Effect {
            damping: Some(std::sync::Arc::new(vec![0.01; len])),
            ..Effect::new(EffectKind::AirCompliance, 10.0)
        };
        let base = vec![
            Effect::new(EffectKind::Backlash, 2.0),
            Effect::new(EffectKind::Hysteresis, 20.0),
            air,
        ];
        let lb = LagBase::new(&prep, &build(&prep, &base).cols);
        for tau in [0.01, 0.2] {
            let mut with = base.clone();
            with.push(Effect::new(EffectKind::SensorLag, tau));
            let d = build(&prep, &with);
            let direct = lsq::sse_fast(&d.cols, &prep.series.p, &prep.train_rows);
            assert!((lb.sse(&prep, tau) - direct).abs() <= 1e-12 * direct);
        }
    }

    #[test]
    fn legendre_known_values() {
        assert!((legendre(2, 0.5) - (-0.125)).abs() < 1e-15);
        assert!((legendre(3, 0.5) - (-0.4375)).abs() < 1e-15);
        assert!((legendre(3, 1.0) - 1.0).abs() < 1e-15);
    }

    #[test]
    fn every_effect_has_story_and_unique_name() {
        let mut names: Vec<&str> = EffectKind::ALL.iter().map(|k| k.name()).collect();
        names.sort_unstable();
        names.dedup();
        assert_eq!(names.len(), EffectKind::ALL.len());
        assert!(EffectKind::ALL.iter().all(|k| k.story().ends_with('.')));
    }
}
