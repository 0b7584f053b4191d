//! The physical plant: three syringe pumps, their lines and the three chambers of one SBA, and the
//! three pressure sensors.
//!
//! # Per chamber
//! The motor moves the plunger in steps of `mm3_per_step` (0.04 mm³ on the paper's rig); the
//! plunger follows the motor through the lead screw's backlash (a play operator of width b) and its
//! periodic pitch error (ripple, amplitude A, period one screw turn Λ):
//!
//! ```text
//! u = plunger + A·sin(2π·plunger/Λ)           displaced syringe volume, mm³
//! ```
//!
//! Motor steps are impulses of volume; the motor's rotor, the screw, the plunger seal and the
//! tubing deliver them as a smooth flow. The delivered volume w follows the plunger's staircase u
//! through a critically damped second-order lag (delivery time constant τ_d, a few ms, far below
//! the 40 ms frame period, so it smooths the 500–2500 Hz step train without visibly delaying the
//! flow):
//!
//! ```text
//! τ_d²·ẅ + 2τ_d·ẇ + w = u                      solved in closed form between steps
//! ```
//!
//! That lag is the default drive ([`Drive::Lagged`]); it delays the delivered flow by about 2τ_d
//! (6 ms) behind the motion the firmware logs. [`Drive::Ideal`] is a rig without it, whose only
//! deviations from the paper's law are the sensor's (noise, offset, quantisation): an ideal servo
//! whose motor follows the firmware's commanded profile itself (the trapezoid whose flow the
//! firmware logs), continuously instead of in steps:
//!
//! ```text
//! ẋ(t) = commanded flow (piecewise linear in t),  x = ∫ẋ dt,  u = x through backlash and ripple
//! w = u,  ẇ = ẋ·∂u/∂x                           no delivery lag
//! ```
//!
//! Why not the step train: a causal drive can only move after a step arrives, but the firmware's
//! profile (and the flow it logs) starts moving before the first step of a move (12.6 ms at
//! 500 mm³/s²) and has stopped before the last one is delivered; on SBA1, where ∂P/∂v̇ ≈ 0.15
//! kPa·s/mm³, that one step of volume (0.04 mm³) in the wrong place costs ≈ 0.15 kPa in the first
//! and last frame of every move, eight times the noise of a frame. And τ_d → 0 does not work
//! either: C(v, v̇)·v̇ would see each step as an impulse of flow. The simulator hands the plant the
//! commanded flow at the start and end of every 1 ms quantum ([`Plant::command_flow`]); the profile
//! is linear between its corners, so this is exact except within the quantum holding a corner (a
//! volume error below 10⁻⁴ mm³, and samples fall on quantum boundaries, where the flow is exact).
//! The flow is continuous, so the inertance's v̈ is the profile's acceleration and the implicit
//! solve differences it as it does for the lagged drive. The log's volume is the step count, which
//! trails the continuous x by half a step while moving (±0.02 mm³, the counter's quantisation); at
//! rest x is set to the count (they agree to 10⁻⁴ mm³ there).
//!
//! The paper identified its law against the syringe volume, so tubing compliance is already inside
//! K and C; what it did not contain is an air pocket. An isothermal bubble of V₀ mm³ at atmospheric
//! pressure P_atm (Boyle) sits between plunger and water, and a leak loses water:
//!
//! ```text
//! x(P) = V₀·P / (P_atm + P)                    volume taken up by compressing the bubble, mm³
//! v    = w − x(P) − L − r_c·t                   chamber volume
//! v̇    = ẇ − ẋ − L̇ − r_c,   L̇ = G·max(P, 0)    chamber flow (laminar leak G, creep r_c)
//! P    = K(v) + C(v, v̇)·v̇ + H + I·v̈ + ΔP_F(t)  the chamber law (paper Eq. 9) + effects
//! ```
//!
//! H is a rate-independent hysteresis term (a Duhem model in volume, not time: dH = (s·H_a − H)
//! |dv| / v_h with s = sign(dv), so the loop it adds does not depend on flow rate), I the fluid
//! inertance, ΔP_F the external force's share (below), r_c a slow creep of the chamber volume away
//! from the delivered volume at a constant, pressure-independent rate (water permeating the
//! elastomer wall). With no effects P = K(w) + C(w, ẇ)·ẇ: the
//! paper's law at the delivered syringe volume and flow.
//!
//! # Integration
//! Without a bubble, leak, inertance or sensor lag the pressure is an explicit function of the
//! filter state, evaluated exactly at every step and sample instant. Otherwise the system is an
//! implicit ODE in v, stiff for small bubbles (time constant τ ≈ x'(P)·∂P/∂v̇: 90 ms for 50 mm³,
//! 18 µs for 0.01 mm³). Each chamber is then integrated with backward Euler (L-stable; ẋ and L̇ are
//! differenced, ẇ is exact, and v is tied to w and P algebraically, so no volume drifts) on a grid
//! holding every step instant exactly and no sub-step longer than `max_substep_s`. A step solves
//! r(P) = P_law(P) − P = 0 for the new pressure; r falls monotonically in P (more pressure, more
//! compression, less chamber flow, less law pressure), so Newton's method safeguarded by a sign
//! bracket always converges.
//!
//! # External force
//! A push of magnitude F(t) on the tip, with azimuth φ and tilt α from the actuator's axis, raises
//! chamber i's pressure by F·w_i / A_i, with weights w_i ≥ 0, Σ w_i = 1:
//!
//! ```text
//! w_i = (1 − sin α)/3 + sin α · max(0, cos(φ − φ_i)) / Σ_j max(0, cos(φ − φ_j)),   φ_i = 120°·i
//! ```
//!
//! An axial push loads the chambers equally, a sideways one the chambers on its side. Σ ΔP_i·A_i = F
//! exactly, which is the premise of the paper's estimator (Sec. IV-C): the plant makes it true and
//! the firmware's model error is what the estimate has to overcome.
//!
//! # Sensors
//! Each sensor reads P through a first-order lag (τ_s) and, optionally, a transport delay d (it
//! reports the pressure of d seconds ago: a long sensing line or a skew between the ADC's sampling
//! instant and the step counter it is logged with; linear interpolation in the integrator's
//! history), adds its offset, a slow thermal drift of
//! the offset D·(1 − e^(−t/τ_D)) and white Gaussian noise, and the ADC turns that into counts with
//! the firmware's own transfer function ([`firmware::board::kpa_to_counts`]), rounded and clamped
//! to 12 bits. An unplugged sensor reads 0 counts (the divider's bottom resistor pulls the pin low).

//!
//! # Other forms
//! Each effect above has one form, and the residual loop's effects were written against those
//! forms. [`Forms`] switches an effect to another, so a benchmark can judge the loop on plants
//! it was not written for: a polytropic air pocket (`(P_atm + P)·V^n` constant, n = 1.4 for a
//! fast compression), hysteresis switching linearly in volume and saturating, a second-order
//! sensor lag (two stages of τ_s/2), a pitch error with a second harmonic, a leak turning to
//! orifice flow (`G·P/√(1 + |P|/P_t)`), a thermal drift that ramps linearly to D at 2τ_D, a creep
//! that slows down (`r_c·τ_c·(1 − e^(−t/τ_c))`), an overdamped delivery lag (poles at 1.6τ_d and
//! 0.4τ_d). The default is
//! every usual form.

// Transcendentals come from `libm` (pure Rust), not the platform's C library, so a seed gives the
// same log on every machine.
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::law::{ChamberLaw, Design};

/// Number of chambers (one actuator).
pub const CHAMBERS: usize = firmware::hal::AXES;

/// Atmospheric pressure, kPa absolute.
pub const ATMOSPHERE_KPA: f64 = 101.325;

/// Rate-independent hysteresis of the chamber wall (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Hysteresis {
    /// Half-height H_a of the loop it adds, kPa.
    pub amplitude_kpa: f64,
    /// Volume v_h over which the term switches after a reversal (63 %), mm³.
    pub transition_mm3: f64,
}

/// Slow drift of the sensor offset after the firmware's zero (warm-up).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ThermalDrift {
    /// Final change of the offset D, kPa.
    pub offset_change_kpa: f64,
    /// Time constant τ_D, s.
    pub time_constant_s: f64,
}

/// Periodic pitch error of the lead screw.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Ripple {
    /// Amplitude A of the displaced-volume error, mm³.
    pub amplitude_mm3: f64,
    /// Period Λ: displaced volume per screw turn, mm³.
    pub period_mm3: f64,
}

/// Other forms of the effects than the module docs give (which are the forms the residual loop's
/// own effects were written against): a benchmark drawing these does not judge the loop on the
/// forms it was built for. Every field's default is the usual form.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Forms {
    /// Polytropic index n of the air pocket, `(P_atm + P)·V^n` constant: 1.4 for a fast
    /// (adiabatic) compression; 0 or 1 is Boyle's isothermal law.
    pub air_polytropic_index: f64,
    /// The hysteresis term switches linearly in volume (a ramp of slope H_a/v_h, saturating at
    /// ±H_a: a friction element with a linear pre-sliding range) instead of exponentially.
    pub hysteresis_linear: bool,
    /// The sensor lag as two first-order stages of τ_s/2 each (a second-order response with the
    /// same mean delay τ_s).
    pub sensor_lag_second_order: bool,
    /// A second harmonic of the lead screw's pitch error, relative to its amplitude A (0: none).
    pub ripple_second_harmonic: f64,
    /// The leak turns from laminar to orifice flow: `G·P/√(1 + |P|/P_t)` with P_t this
    /// pressure, kPa (0: laminar, `G·P`).
    pub leak_orifice_kpa: f64,
    /// The thermal drift as a linear ramp reaching D at 2τ_D, then constant (instead of
    /// `D·(1 − e^(−t/τ_D))`).
    pub drift_ramp: bool,
    /// The creep slows down with this time constant, s: `r_c·τ_c·(1 − e^(−t/τ_c))` of volume
    /// (0: a constant rate, `r_c·t`).
    pub creep_time_constant_s: f64,
    /// The lagged drive's delivery lag overdamped, poles at 1.6τ_d and 0.4τ_d (the same mean
    /// delay 2τ_d as the critically damped lag's two at τ_d; the flow stays continuous).
    pub delivery_overdamped: bool,
}

/// Optional effects, each off by default and set in physical units.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Effects {
    /// Air pocket in each syringe, mm³ at atmospheric pressure (0: none).
    pub air_pocket_mm3: [f64; CHAMBERS],
    /// Rate-independent hysteresis of the chamber wall.
    pub hysteresis: Option<Hysteresis>,
    /// First-order lag of the pressure sensor, s (0: none).
    pub sensor_lag_s: f64,
    /// Fluid inertance of the line, kPa·s²/mm³ (a 1 m, 2 mm tube of water: about 3e-4).
    pub inertance_kpa_s2_per_mm3: f64,
    /// Thermal drift of the sensor offset.
    pub thermal_drift: Option<ThermalDrift>,
    /// Lead-screw backlash, mm³ of plunger travel.
    pub backlash_mm3: f64,
    /// Periodic pump ripple (lead-screw pitch error).
    pub ripple: Option<Ripple>,
    /// Laminar leak conductance, mm³/s per kPa (0: none).
    pub leak_mm3_per_s_per_kpa: f64,
    /// Transport delay of the sensed pressure, s (0: none).
    pub transport_delay_s: f64,
    /// Creep of the chamber volume away from the delivered volume, mm³/s (0: none; positive:
    /// the chamber holds less than was delivered).
    pub volume_creep_mm3_per_s: f64,
    /// The effects' forms (default: the module docs').
    pub forms: Forms,
}

/// Names of the single-effect presets ([`Effects::preset`]).
pub const EFFECT_PRESETS: [&str; 10] = [
    "air",
    "hysteresis",
    "sensor-lag",
    "inertance",
    "thermal-drift",
    "backlash",
    "ripple",
    "leak",
    "transport-delay",
    "volume-creep",
];

impl Effects {
    /// One effect switched on at a plausible size for the paper's rig, the others off; `None`
    /// for an unknown name (see [`EFFECT_PRESETS`]).
    pub fn preset(name: &str) -> Option<Self> {
        let mut e = Self::default();
        match name {
            "air" => e.air_pocket_mm3 = [20.0; CHAMBERS],
            "hysteresis" => {
                e.hysteresis = Some(Hysteresis {
                    amplitude_kpa: 1.0,
                    transition_mm3: 20.0,
                })
            }
            "sensor-lag" => e.sensor_lag_s = 0.02,
            // 1 m of 2 mm tube: ρL/A = 1000·1/3.14e-6 Pa·s²/m³ ≈ 3e-4 kPa·s²/mm³.
            "inertance" => e.inertance_kpa_s2_per_mm3 = 3.0e-4,
            "thermal-drift" => {
                e.thermal_drift = Some(ThermalDrift {
                    offset_change_kpa: 1.0,
                    time_constant_s: 300.0,
                })
            }
            "backlash" => e.backlash_mm3 = 0.4,
            // One turn of a screw at 200 full steps per turn and 0.04 mm³ per step: 8 mm³.
            "ripple" => {
                e.ripple = Some(Ripple {
                    amplitude_mm3: 0.2,
                    period_mm3: 8.0,
                })
            }
            "leak" => e.leak_mm3_per_s_per_kpa = 0.002,
            // A quarter of a 25 Hz frame: a sampling skew or a few metres of sensing line.
            "transport-delay" => e.transport_delay_s = 0.01,
            // 36 mm³ an hour, 6 % of the stroke: slow permeation through the elastomer.
            "volume-creep" => e.volume_creep_mm3_per_s = 0.01,
            _ => return None,
        }
        Some(e)
    }
}

/// The always-present sensor imperfections. Defaults: a P-7100 class sensor (100 kPa full scale)
/// on the firmware's 12-bit ADC, where one count is 0.032 kPa.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorSpec {
    /// Standard deviation of white noise at the sensor output, kPa (0.05 %FS).
    pub noise_kpa: f64,
    /// Zero offset of each sensor, kPa (within the ±1 %FS of an amplified gauge sensor).
    pub offset_kpa: [f64; CHAMBERS],
    /// The noise's shape beyond its Gaussian core (default: Gaussian).
    pub tails: NoiseTails,
}

/// The shape of the sensor noise at each ADC conversion: Gaussian of σ = `noise_kpa` by default,
/// or heavier-tailed, as a sensor with a loose connector or a noisy supply gives.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case", deny_unknown_fields)]
pub enum NoiseTails {
    /// Gaussian, σ = `noise_kpa`.
    #[default]
    Gaussian,
    /// Student's t with `dof` degrees of freedom times `noise_kpa` (variance
    /// noise²·dof/(dof − 2); `dof` > 2).
    StudentT {
        /// Degrees of freedom.
        dof: f64,
    },
    /// The Gaussian plus, on a `fraction` of the conversions, a spike of ±`size_kpa` (random sign).
    Spikes {
        /// Share of conversions spiked, 0..=1.
        fraction: f64,
        /// Height of a spike, kPa.
        size_kpa: f64,
    },
}

impl Default for SensorSpec {
    fn default() -> Self {
        Self {
            noise_kpa: 0.05,
            offset_kpa: [0.42, -0.31, 0.18],
            tails: NoiseTails::Gaussian,
        }
    }
}

/// One push of an external force on the tip: a train of raised-cosine pulses.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ForcePush {
    /// Start, s of simulated time.
    pub start_s: f64,
    /// Length of the train, s.
    pub duration_s: f64,
    /// Pulse rate, Hz (the paper pushes at 1 Hz).
    pub frequency_hz: f64,
    /// Peak force, N.
    pub peak_n: f64,
    /// Azimuth φ of the push, degrees (chamber i sits at 120°·i).
    #[serde(default)]
    pub azimuth_deg: f64,
    /// Tilt α from the actuator axis, degrees (0: axial, 90: sideways).
    #[serde(default)]
    pub tilt_deg: f64,
}

impl ForcePush {
    /// Force magnitude at `t_s`, N: F_peak·(1 − cos 2πf(t − t₀))/2 inside the train, else 0.
    pub fn force_n(&self, t_s: f64) -> f64 {
        let dt = t_s - self.start_s;
        if dt < 0.0 || dt > self.duration_s {
            return 0.0;
        }
        let phase = core::f64::consts::TAU * self.frequency_hz * dt;
        self.peak_n * 0.5 * (1.0 - libm::cos(phase))
    }

    /// Share w_i of each chamber (module docs); Σ w_i = 1.
    pub fn shares(&self) -> [f64; CHAMBERS] {
        let tilt = libm::sin(self.tilt_deg.to_radians()).clamp(0.0, 1.0);
        let phi = self.azimuth_deg.to_radians();
        let lobe: [f64; CHAMBERS] = core::array::from_fn(|i| {
            let phi_i = (120.0 * i as f64).to_radians();
            libm::cos(phi - phi_i).max(0.0)
        });
        let sum: f64 = lobe.iter().sum(); // ≥ cos 60° = 0.5 for any φ
        core::array::from_fn(|i| (1.0 - tilt) / CHAMBERS as f64 + tilt * lobe[i] / sum)
    }
}

/// How the motor's step train becomes delivered volume (module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Drive {
    /// Critically damped second-order delivery lag of time constant τ_d (the default rig).
    #[default]
    Lagged,
    /// An ideal servo following the firmware's commanded profile: no lag (module docs).
    Ideal,
    /// The ideal servo's continuous motion through the delivery lag of [`Drive::Lagged`] (its
    /// form, its τ_d): a lag without the step train. On the step train a τ_d far below the
    /// steps' period is no lag at all but a train of flow pulses, which the chamber law's
    /// C(v, v̇)·v̇ turns into pressure that frames sample as noise near their Nyquist frequency
    /// (a random rig with τ_d = 0.86 ms: 38 times the noise), and the step count trails the
    /// commanded motion by half a step (a lag of 0.02 mm³ over the flow, 2 ms at 10 mm³/s);
    /// here a τ_d that small is a lag that small (the loop benchmark's planted delivery lag).
    LaggedServo,
}

impl Drive {
    /// Whether the motor follows the firmware's commanded profile continuously (the plant is
    /// handed it, [`Plant::command_flow`]) rather than step by step.
    pub fn follows_profile(self) -> bool {
        self != Drive::Lagged
    }
}

/// Everything physical about the rig.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PlantConfig {
    /// Actuator design (law and envelope).
    pub design: Design,
    /// Optional effects.
    pub effects: Effects,
    /// Sensor noise and offsets.
    pub sensor: SensorSpec,
    /// How the step train is delivered (`lagged` through τ_d, or `ideal`).
    pub drive: Drive,
    /// Delivery time constant τ_d of motor, screw, seal and tubing, s (> 0; lagged drive only).
    pub delivery_time_constant_s: f64,
    /// Effective area of each chamber for the external force, mm² (paper: 22).
    pub area_mm2: [f64; CHAMBERS],
    /// Longest backward-Euler sub-step, s.
    pub max_substep_s: f64,
    /// Displaced volume per motor step, mm³ (paper: 0.04).
    pub mm3_per_step: f64,
}

impl Default for PlantConfig {
    fn default() -> Self {
        Self {
            design: Design::Sba1,
            effects: Effects::default(),
            sensor: SensorSpec::default(),
            drive: Drive::Lagged,
            delivery_time_constant_s: 0.003,
            area_mm2: [model_core::force::DEFAULT_AREA_MM2 as f64; CHAMBERS],
            max_substep_s: 1.0e-3,
            mm3_per_step: 0.04,
        }
    }
}

/// A physical parameter outside its meaningful range.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("plant parameter `{name}` = {value}: {why}")]
pub struct ParamError {
    /// Parameter name as in scenario files.
    pub name: &'static str,
    /// The offending value.
    pub value: f64,
    /// What it must be.
    pub why: &'static str,
}

fn check(name: &'static str, value: f64, ok: bool, why: &'static str) -> Result<(), ParamError> {
    if value.is_finite() && ok {
        Ok(())
    } else {
        Err(ParamError { name, value, why })
    }
}

impl PlantConfig {
    /// Check every parameter's range.
    pub fn validate(&self) -> Result<(), ParamError> {
        let e = &self.effects;
        let nonneg = "must be finite and ≥ 0";
        let pos = "must be finite and > 0";
        for &a in &e.air_pocket_mm3 {
            check("effects.air_pocket_mm3", a, a >= 0.0, nonneg)?;
        }
        if let Some(h) = e.hysteresis {
            check(
                "effects.hysteresis.amplitude_kpa",
                h.amplitude_kpa,
                h.amplitude_kpa >= 0.0,
                nonneg,
            )?;
            check(
                "effects.hysteresis.transition_mm3",
                h.transition_mm3,
                h.transition_mm3 > 0.0,
                pos,
            )?;
        }
        check(
            "effects.sensor_lag_s",
            e.sensor_lag_s,
            e.sensor_lag_s >= 0.0,
            nonneg,
        )?;
        let i = e.inertance_kpa_s2_per_mm3;
        check("effects.inertance_kpa_s2_per_mm3", i, i >= 0.0, nonneg)?;
        if let Some(d) = e.thermal_drift {
            check(
                "effects.thermal_drift.offset_change_kpa",
                d.offset_change_kpa,
                true,
                "must be finite",
            )?;
            check(
                "effects.thermal_drift.time_constant_s",
                d.time_constant_s,
                d.time_constant_s > 0.0,
                pos,
            )?;
        }
        check(
            "effects.backlash_mm3",
            e.backlash_mm3,
            e.backlash_mm3 >= 0.0,
            nonneg,
        )?;
        if let Some(r) = e.ripple {
            check(
                "effects.ripple.amplitude_mm3",
                r.amplitude_mm3,
                r.amplitude_mm3 >= 0.0,
                nonneg,
            )?;
            check(
                "effects.ripple.period_mm3",
                r.period_mm3,
                r.period_mm3 > 0.0,
                pos,
            )?;
        }
        let g = e.leak_mm3_per_s_per_kpa;
        check("effects.leak_mm3_per_s_per_kpa", g, g >= 0.0, nonneg)?;
        let d = e.transport_delay_s;
        check(
            "effects.transport_delay_s",
            d,
            (0.0..1.0).contains(&d),
            "must be in [0, 1) s",
        )?;
        let r = e.volume_creep_mm3_per_s;
        check(
            "effects.volume_creep_mm3_per_s",
            r,
            r.abs() <= 10.0,
            "must be finite, |r| ≤ 10 mm³/s",
        )?;
        let f = &e.forms;
        check(
            "effects.forms.air_polytropic_index",
            f.air_polytropic_index,
            f.air_polytropic_index == 0.0 || (1.0..=1.67).contains(&f.air_polytropic_index),
            "must be 0 (isothermal) or in [1, 1.67]",
        )?;
        check(
            "effects.forms.ripple_second_harmonic",
            f.ripple_second_harmonic,
            (0.0..=1.0).contains(&f.ripple_second_harmonic),
            "must be in [0, 1]",
        )?;
        check(
            "effects.forms.leak_orifice_kpa",
            f.leak_orifice_kpa,
            f.leak_orifice_kpa >= 0.0,
            nonneg,
        )?;
        check(
            "effects.forms.creep_time_constant_s",
            f.creep_time_constant_s,
            f.creep_time_constant_s >= 0.0,
            nonneg,
        )?;
        let s = &self.sensor;
        check("sensor.noise_kpa", s.noise_kpa, s.noise_kpa >= 0.0, nonneg)?;
        match s.tails {
            NoiseTails::Gaussian => {}
            NoiseTails::StudentT { dof } => {
                check("sensor.tails.dof", dof, dof > 2.0, "must be finite and > 2")?;
            }
            NoiseTails::Spikes { fraction, size_kpa } => {
                check(
                    "sensor.tails.fraction",
                    fraction,
                    (0.0..=1.0).contains(&fraction),
                    "must be in 0..=1",
                )?;
                check(
                    "sensor.tails.size_kpa",
                    size_kpa,
                    size_kpa.abs() < 50.0,
                    "must be finite and within ±50 kPa",
                )?;
            }
        }
        for &o in &s.offset_kpa {
            check(
                "sensor.offset_kpa",
                o,
                o.abs() < 50.0,
                "must be finite and within ±50 kPa",
            )?;
        }
        let k = self.delivery_time_constant_s;
        check(
            "delivery_time_constant_s",
            k,
            k > 0.0 && k < 1.0,
            "must be in (0, 1) s",
        )?;
        for &a in &self.area_mm2 {
            check("area_mm2", a, a > 0.0, pos)?;
        }
        let m = self.mm3_per_step;
        check("mm3_per_step", m, m > 0.0, pos)?;
        let h = self.max_substep_s;
        check(
            "max_substep_s",
            h,
            h > 0.0 && h <= 0.1,
            "must be in (0, 0.1] s",
        )?;
        Ok(())
    }
}

/// What is true about one chamber at one instant (the simulator's ground truth).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChamberTruth {
    /// Motor position as volume: net steps × volume per step, mm³.
    pub motor_mm3: f64,
    /// Displaced syringe volume u (after backlash and ripple), mm³.
    pub syringe_mm3: f64,
    /// Delivered volume w (u through the delivery lag), mm³.
    pub delivered_mm3: f64,
    /// Chamber volume v, mm³.
    pub chamber_mm3: f64,
    /// Chamber flow v̇, mm³/s.
    pub flow_mm3_s: f64,
    /// Line pressure P, kPa gauge.
    pub pressure_kpa: f64,
    /// Pressure the sensor element reports (after its lag and transport delay, before offset and
    /// noise), kPa.
    pub sensed_kpa: f64,
    /// Air-pocket volume at the current pressure, mm³.
    pub air_mm3: f64,
    /// Volume lost through the leak so far, mm³.
    pub leaked_mm3: f64,
}

/// Dynamic state of one chamber.
#[derive(Clone, Debug)]
struct Chamber {
    /// Time of the state, µs.
    t_us: u64,
    /// Net steps.
    steps: i64,
    plunger: f64,
    /// Delivered volume w and flow ẇ.
    w: f64,
    wdot: f64,
    /// Ideal drive: the commanded continuous motor volume x, and the commanded flow over the
    /// current quantum (t₀ µs, t₁ µs, flow at t₀, flow at t₁).
    cmd: f64,
    segment: (u64, u64, f64, f64),
    /// Transport delay: (instant µs, sensed pressure) history, oldest first.
    history: std::collections::VecDeque<(u64, f64)>,
    p: f64,
    v: f64,
    vdot: f64,
    leak: f64,
    hyst: f64,
    sensed: f64,
    /// The first stage of a second-order sensor lag ([`Forms::sensor_lag_second_order`]).
    sensed_mid: f64,
    air0: f64,
    unplugged: bool,
    rng: ChaCha8Rng,
}

/// The plant: three chambers, their sensors and the external force.
#[derive(Clone, Debug)]
pub struct Plant {
    cfg: PlantConfig,
    law: ChamberLaw,
    pushes: Vec<ForcePush>,
    shares: Vec<[f64; CHAMBERS]>,
    ch: [Chamber; CHAMBERS],
    noise: Normal<f64>,
}

/// Result of one step of the chamber equations.
struct Solved {
    p: f64,
    v: f64,
    q: f64,
    leak: f64,
    hyst: f64,
}

/// One step of length `h` of the first-order lag `τ ẏ + y = x`, exact for an input `x` linear over
/// the step from `x0` to `x1` (the pressure between the integrator's sub-step ends, as the
/// transport delay's history interpolates it), from `y0`:
///
/// ```text
/// y1 = x1 + (y0 − x0)·e − (x1 − x0)·(τ/h)·(1 − e),   e = e^(−h/τ)
/// ```
///
/// A ramp is then followed exactly τ late, as the lag's definition says. Holding the input at
/// its end value `x1` over the step instead (`y1 = x1 + (y0 − x1)·e`) leads the ramp by `h/2`
/// to first order (a lag of `h/(e^(h/τ) − 1)` ≈ τ − h/2): with sub-steps of up to 1 ms, 0.2–0.5
/// ms short, which the benchmark's sensor-lag estimates showed (issue 34).
fn lag_step(y0: f64, x0: f64, x1: f64, h: f64, tau: f64) -> f64 {
    let e = libm::exp(-h / tau);
    x1 + (y0 - x0) * e - (x1 - x0) * (tau / h) * (1.0 - e)
}

impl Plant {
    /// A plant at rest (all syringes withdrawn, P = 0) at t = 0. Each chamber's noise stream is
    /// seeded from `seed` and its index, so runs are reproducible.
    pub fn new(cfg: &PlantConfig, pushes: &[ForcePush], seed: u64) -> Result<Self, ParamError> {
        cfg.validate()?;
        for p in pushes {
            check(
                "force.start_s",
                p.start_s,
                p.start_s >= 0.0,
                "must be finite and ≥ 0",
            )?;
            check(
                "force.duration_s",
                p.duration_s,
                p.duration_s >= 0.0,
                "must be finite and ≥ 0",
            )?;
            check(
                "force.frequency_hz",
                p.frequency_hz,
                p.frequency_hz > 0.0,
                "must be finite and > 0",
            )?;
            check(
                "force.peak_n",
                p.peak_n,
                p.peak_n.abs() <= 100.0,
                "must be finite, |F| ≤ 100 N",
            )?;
            check("force.azimuth_deg", p.azimuth_deg, true, "must be finite")?;
            check(
                "force.tilt_deg",
                p.tilt_deg,
                (0.0..=90.0).contains(&p.tilt_deg),
                "must be in 0..=90",
            )?;
        }
        let noise = Normal::new(0.0, cfg.sensor.noise_kpa).map_err(|_| ParamError {
            name: "sensor.noise_kpa",
            value: cfg.sensor.noise_kpa,
            why: "must be finite and ≥ 0",
        })?;
        let ch = core::array::from_fn(|i| Chamber {
            t_us: 0,
            steps: 0,
            plunger: 0.0,
            w: 0.0,
            wdot: 0.0,
            cmd: 0.0,
            segment: (0, 0, 0.0, 0.0),
            // At rest and at zero pressure since t = 0.
            history: std::collections::VecDeque::from([(0, 0.0)]),
            p: 0.0,
            v: 0.0,
            vdot: 0.0,
            leak: 0.0,
            hyst: 0.0,
            sensed: 0.0,
            sensed_mid: 0.0,
            air0: cfg.effects.air_pocket_mm3[i],
            unplugged: false,
            // Independent streams per chamber: ChaCha's stream id, not a reseeded copy.
            rng: {
                let mut r = ChaCha8Rng::seed_from_u64(seed);
                r.set_stream(i as u64 + 1);
                r
            },
        });
        Ok(Self {
            law: cfg.design.law(),
            shares: pushes.iter().map(ForcePush::shares).collect(),
            pushes: pushes.to_vec(),
            cfg: cfg.clone(),
            ch,
            noise,
        })
    }

    /// The configuration this plant was built from.
    pub fn config(&self) -> &PlantConfig {
        &self.cfg
    }

    /// True external force magnitude at `t_us`, N.
    pub fn force_n(&self, t_us: u64) -> f64 {
        let t = t_us as f64 * 1e-6;
        self.pushes.iter().map(|p| p.force_n(t)).sum()
    }

    /// Pressure the force adds to chamber `i` at `t_us`, kPa (N/mm² = 1000 kPa).
    fn force_kpa(&self, i: usize, t_us: u64) -> f64 {
        if self.pushes.is_empty() {
            return 0.0;
        }
        let t = t_us as f64 * 1e-6;
        let f: f64 = (self.pushes.iter().zip(&self.shares))
            .map(|(p, w)| p.force_n(t) * w[i])
            .sum();
        1000.0 * f / self.cfg.area_mm2[i]
    }

    /// Displaced syringe volume u of chamber `i` (after ripple).
    fn syringe(&self, i: usize) -> f64 {
        let c = &self.ch[i];
        c.plunger + self.ripple(c.plunger).0
    }

    /// The pitch error at plunger position `x` and its slope in `x`: `A·sin(2πx/Λ)`, plus
    /// `k·A·sin(4πx/Λ + 0.7)` with the second harmonic of [`Forms::ripple_second_harmonic`].
    fn ripple(&self, x: f64) -> (f64, f64) {
        let Some(r) = self.cfg.effects.ripple else {
            return (0.0, 0.0);
        };
        let w = core::f64::consts::TAU / r.period_mm3;
        let k = self.cfg.effects.forms.ripple_second_harmonic;
        let mut e = r.amplitude_mm3 * libm::sin(w * x);
        let mut slope = r.amplitude_mm3 * w * libm::cos(w * x);
        if k > 0.0 {
            e += k * r.amplitude_mm3 * libm::sin(2.0 * w * x + 0.7);
            slope += k * r.amplitude_mm3 * 2.0 * w * libm::cos(2.0 * w * x + 0.7);
        }
        (e, slope)
    }

    /// Bubble compression x(P) and x'(P) of chamber `i`.
    ///
    /// Boyle's law, or with [`Forms::air_polytropic_index`] n: `x = V₀·(1 − r^(1/n))`,
    /// `x' = V₀·r^(1/n)/(n·(P_atm + P))`, `r = P_atm/(P_atm + P)` (n = 1 is Boyle's).
    fn compression(&self, i: usize, p: f64) -> (f64, f64) {
        let a = self.ch[i].air0;
        if a <= 0.0 {
            return (0.0, 0.0);
        }
        let d = ATMOSPHERE_KPA + p;
        let n = self.cfg.effects.forms.air_polytropic_index;
        if n == 0.0 || n == 1.0 {
            (a * p / d, a * ATMOSPHERE_KPA / (d * d))
        } else {
            let rn = libm::pow(ATMOSPHERE_KPA / d, 1.0 / n);
            (a * (1.0 - rn), a * rn / (n * d))
        }
    }

    /// The leak's flow per unit conductance at pressure `p` > 0 and its slope: `p` (laminar), or
    /// `p/√(1 + p/P_t)` with [`Forms::leak_orifice_kpa`] P_t (laminar below P_t, an orifice's
    /// `√p` above).
    fn leak_law(&self, p: f64) -> (f64, f64) {
        let pt = self.cfg.effects.forms.leak_orifice_kpa;
        if pt <= 0.0 {
            return (p, 1.0);
        }
        let x = p / pt;
        let root = libm::sqrt(1.0 + x);
        (p / root, (1.0 + 0.5 * x) / (root * (1.0 + x)))
    }

    /// The creep's volume by `t_s` and its rate: `r_c·t` and `r_c`, or with
    /// [`Forms::creep_time_constant_s`] τ_c, `r_c·τ_c·(1 − e^(−t/τ_c))` and `r_c·e^(−t/τ_c)`.
    fn creep(&self, t_s: f64) -> (f64, f64) {
        let r = self.cfg.effects.volume_creep_mm3_per_s;
        let tc = self.cfg.effects.forms.creep_time_constant_s;
        if r == 0.0 {
            (0.0, 0.0)
        } else if tc > 0.0 {
            let decay = libm::exp(-t_s / tc);
            (r * tc * (1.0 - decay), r * decay)
        } else {
            (r * t_s, r)
        }
    }

    /// Whether chamber `i` needs the implicit integrator (module docs).
    fn stiff(&self, i: usize) -> bool {
        let e = &self.cfg.effects;
        self.ch[i].air0 > 0.0
            || e.leak_mm3_per_s_per_kpa > 0.0
            || e.inertance_kpa_s2_per_mm3 > 0.0
            || e.sensor_lag_s > 0.0
    }

    /// Hysteresis term after a volume change `dv` from state `h0`, and its derivative in `dv`.
    fn hysteresis(&self, h0: f64, dv: f64) -> (f64, f64) {
        match self.cfg.effects.hysteresis {
            Some(hs) if self.cfg.effects.forms.hysteresis_linear => {
                // A ramp of slope H_a/v_h in volume, saturating at ±H_a.
                let a = hs.amplitude_kpa;
                let h = h0 + a / hs.transition_mm3 * dv;
                if h.abs() >= a {
                    (h.clamp(-a, a), 0.0)
                } else {
                    (h, a / hs.transition_mm3)
                }
            }
            Some(hs) => {
                let s = if dv > 0.0 {
                    1.0
                } else if dv < 0.0 {
                    -1.0
                } else {
                    0.0
                };
                let decay = libm::exp(-dv.abs() / hs.transition_mm3);
                let target = s * hs.amplitude_kpa;
                (
                    target + (h0 - target) * decay,
                    (hs.amplitude_kpa - s * h0) / hs.transition_mm3 * decay,
                )
            }
            None => (h0, 0.0),
        }
    }

    /// One step of length `h` s of chamber `i`'s equations ending at `t_s`, the drive state
    /// already at the end.
    fn solve(&self, i: usize, h: f64, dp_force: f64, t_s: f64) -> Solved {
        let c = &self.ch[i];
        let e = &self.cfg.effects;
        let g = e.leak_mm3_per_s_per_kpa;
        let inert = e.inertance_kpa_s2_per_mm3;
        // The creep is a function of time alone: once per step, not per Newton iteration.
        let (cv, cq) = self.creep(t_s);
        let (x0, _) = self.compression(i, c.p);
        let eval = |p: f64| -> (f64, f64, Solved) {
            let (x, dx) = self.compression(i, p);
            let (lk, dlk) = if p > 0.0 {
                let (q, dq) = self.leak_law(p);
                (h * g * q, h * g * dq)
            } else {
                (0.0, 0.0)
            };
            let v = c.w - x - c.leak - lk - cv;
            let dv_dp = -dx - dlk;
            // ẇ exact, ẋ and L̇ backward-differenced.
            let q = c.wdot - (x - x0 + lk) / h - cq;
            let dq_dp = dv_dp / h;
            let law = self.law.eval(v, q);
            let (hy, dhy) = self.hysteresis(c.hyst, v - c.v);
            let r = law.p + hy + inert * (q - c.vdot) / h + dp_force - p;
            let dr = (law.dp_dv + dhy) * dv_dp + (law.dp_dvdot + inert / h) * dq_dp - 1.0;
            let st = Solved {
                p,
                v,
                q,
                leak: c.leak + lk,
                hyst: hy,
            };
            (r, dr, st)
        };
        // r(P) falls monotonically: r > 0 means the root lies above P. With a bubble r → +∞ as
        // P → −P_atm (it expands without bound), so −P_atm bounds the root from below.
        let mut lo = if c.air0 > 0.0 {
            -ATMOSPHERE_KPA
        } else {
            f64::NEG_INFINITY
        };
        let mut hi = f64::INFINITY;
        let mut p = c.p;
        let mut best = None;
        for _ in 0..200 {
            let (r, dr, st) = eval(p);
            if r > 0.0 {
                lo = p;
            } else {
                hi = p;
            }
            let done = r.abs() <= 1e-10 * (1.0 + p.abs()) || hi - lo <= 1e-13 * (1.0 + p.abs());
            best = Some(st);
            if done {
                break;
            }
            let newton = p - r / dr;
            p = if dr < 0.0 && newton > lo && newton < hi {
                newton
            } else if lo.is_finite() && hi.is_finite() {
                0.5 * (lo + hi)
            } else if hi.is_finite() {
                hi - (1.0 + hi.abs())
            } else {
                lo + (1.0 + lo.abs())
            };
        }
        best.expect("at least one iteration")
    }

    /// The explicit case: no bubble, leak, inertance or lag, so P is a function of w, ẇ (and
    /// the creep at `t_s`).
    fn explicit(&self, i: usize, dp_force: f64, t_s: f64) -> Solved {
        let c = &self.ch[i];
        let (cv, cq) = self.creep(t_s);
        let (v, q) = (c.w - cv, c.wdot - cq);
        let (hy, _) = self.hysteresis(c.hyst, v - c.v);
        Solved {
            p: self.law.eval(v, q).p + hy + dp_force,
            v,
            q,
            leak: 0.0,
            hyst: hy,
        }
    }

    /// Move chamber `i`'s drive forward by `h` s to `t_us` (closed form: u constant over the
    /// interval on the step train, u the servo's motion taken linear over it on
    /// [`Drive::LaggedServo`]).
    fn deliver(&mut self, i: usize, h: f64, t_us: u64) {
        match self.cfg.drive {
            Drive::Ideal => self.servo(i, h, t_us),
            Drive::Lagged => {
                let u = self.syringe(i);
                self.lag(i, h, u, 0.0);
            }
            Drive::LaggedServo => {
                let (w, wdot, u0) = (self.ch[i].w, self.ch[i].wdot, self.syringe(i));
                self.servo(i, h, t_us);
                let u1 = self.syringe(i);
                let c = &mut self.ch[i];
                (c.w, c.wdot) = (w, wdot);
                let slope = if h > 0.0 { (u1 - u0) / h } else { 0.0 };
                self.lag(i, h, u0, slope);
            }
        }
    }

    /// The delivery lag of chamber `i` over `h` s with its input `u(t) = u0 + slope·t`, in closed
    /// form: the lag's steady response to the ramp, `w_p = u − d·slope` (`d` the lag's delay,
    /// 2τ critically damped, τ₁ + τ₂ overdamped), plus the homogeneous solution of `e = w − w_p`.
    fn lag(&mut self, i: usize, h: f64, u0: f64, slope: f64) {
        let tau = self.cfg.delivery_time_constant_s;
        let overdamped = self.cfg.effects.forms.delivery_overdamped;
        let c = &mut self.ch[i];
        if overdamped {
            // τ₁τ₂·ë + (τ₁ + τ₂)·ė + e = 0: e(t) = a·e^(−t/τ₁) + b·e^(−t/τ₂).
            let (t1, t2) = (1.6 * tau, 0.4 * tau);
            let p0 = u0 - (t1 + t2) * slope;
            let (e0, d0) = (c.w - p0, c.wdot - slope);
            let a = (d0 + e0 / t2) / (1.0 / t2 - 1.0 / t1);
            let b = e0 - a;
            let (d1, d2) = (libm::exp(-h / t1), libm::exp(-h / t2));
            c.w = p0 + slope * h + a * d1 + b * d2;
            c.wdot = slope - a / t1 * d1 - b / t2 * d2;
            return;
        }
        // e = w − w_p obeys τ²ë + 2τė + e = 0: e(t) = (e₀ + (ė₀ + e₀/τ)t)·e^(−t/τ).
        let p0 = u0 - 2.0 * tau * slope;
        let (e0, d0) = (c.w - p0, c.wdot - slope);
        let b = d0 + e0 / tau;
        let decay = libm::exp(-h / tau);
        c.w = p0 + slope * h + (e0 + b * h) * decay;
        c.wdot = slope + (d0 - b * h / tau) * decay;
    }

    /// Commanded flow at `t_us` from the current quantum's segment (linear; held outside it).
    fn commanded_flow(&self, i: usize, t_us: u64) -> f64 {
        let (t0, t1, f0, f1) = self.ch[i].segment;
        if t1 <= t0 || t_us <= t0 {
            f0
        } else if t_us >= t1 {
            f1
        } else {
            f0 + (f1 - f0) * (t_us - t0) as f64 / (t1 - t0) as f64
        }
    }

    /// Ideal drive: move the commanded volume forward by `h` s to `t_us` (trapezoid rule, exact
    /// for the linear flow), the plunger after it through backlash, and w = u with ẇ by the chain
    /// rule (module docs).
    fn servo(&mut self, i: usize, h: f64, t_us: u64) {
        let t_start = t_us.saturating_sub((h * 1e6).round() as u64);
        let (fa, fb) = (
            self.commanded_flow(i, t_start),
            self.commanded_flow(i, t_us),
        );
        let b = self.cfg.effects.backlash_mm3;
        let c = &mut self.ch[i];
        c.cmd += 0.5 * (fa + fb) * h;
        let before = c.plunger;
        c.plunger = c.plunger.clamp(c.cmd - 0.5 * b, c.cmd + 0.5 * b);
        // The plunger follows the motor only while the screw bears on it.
        let engaged = b == 0.0 || c.plunger != before;
        let plunger = c.plunger;
        let slope = 1.0 + self.ripple(plunger).1;
        let flow = if engaged { fb * slope } else { 0.0 };
        let u = self.syringe(i);
        let c = &mut self.ch[i];
        c.w = u;
        c.wdot = flow;
    }

    /// Ideal drive: the firmware's commanded flow of chamber `i` at `t0_us` and `t1_us` (the
    /// simulator's next quantum; mm³/s, positive inflates). At rest over the whole quantum the
    /// continuous motor volume is set to the step count (module docs). No effect on the step
    /// train's drive ([`Drive::follows_profile`]).
    pub fn command_flow(&mut self, i: usize, t0_us: u64, t1_us: u64, f0: f64, f1: f64) {
        if !self.cfg.drive.follows_profile() {
            return;
        }
        // Integrate up to the quantum's start on the previous segment first.
        self.advance_chamber(i, t0_us);
        let per = self.cfg.mm3_per_step;
        let c = &mut self.ch[i];
        c.segment = (t0_us, t1_us, f0, f1);
        if f0 == 0.0 && f1 == 0.0 {
            c.cmd = c.steps as f64 * per;
        }
    }

    /// Integrate chamber `i` to `t_us` with its plunger where it is.
    fn advance_chamber(&mut self, i: usize, t_us: u64) {
        let t0 = self.ch[i].t_us;
        if t_us <= t0 {
            return;
        }
        let span = (t_us - t0) as f64 * 1e-6;
        let stiff = self.stiff(i);
        let n = if stiff {
            (span / self.cfg.max_substep_s).ceil().max(1.0) as u64
        } else {
            1
        };
        let lag = self.cfg.effects.sensor_lag_s;
        let second_order = self.cfg.effects.forms.sensor_lag_second_order;
        let delay_us = self.cfg.effects.transport_delay_s * 1e6;
        let mut t_prev = t0;
        for k in 1..=n {
            // Sub-steps end on whole ticks; the last one lands on t_us.
            let t_end = t0 + (t_us - t0) * k / n;
            let h = (t_end - t_prev) as f64 * 1e-6;
            t_prev = t_end;
            if h <= 0.0 {
                continue;
            }
            self.deliver(i, h, t_end);
            let dp_force = self.force_kpa(i, t_end);
            let t_s = t_end as f64 * 1e-6;
            let s = if stiff {
                self.solve(i, h, dp_force, t_s)
            } else {
                self.explicit(i, dp_force, t_s)
            };
            let c = &mut self.ch[i];
            let p_before = c.p;
            c.p = s.p;
            c.vdot = s.q;
            c.v = s.v;
            c.leak = s.leak;
            c.hyst = s.hyst;
            c.sensed = if lag > 0.0 && second_order {
                // Two stages of τ_s/2, each exact for its input linear over the step.
                let mid_before = c.sensed_mid;
                c.sensed_mid = lag_step(c.sensed_mid, p_before, s.p, h, 0.5 * lag);
                lag_step(c.sensed, mid_before, c.sensed_mid, h, 0.5 * lag)
            } else if lag > 0.0 {
                lag_step(c.sensed, p_before, s.p, h, lag)
            } else {
                s.p
            };
            c.t_us = t_end;
            if delay_us > 0.0 {
                c.history.push_back((t_end, c.sensed));
                // Keep one entry at or before the delayed instant for the interpolation.
                let target = t_end as f64 - delay_us;
                while c.history.len() >= 2 && c.history[1].0 as f64 <= target {
                    c.history.pop_front();
                }
            }
        }
    }

    /// What the sensor element of chamber `i` reports now: the lagged pressure, `transport_delay_s`
    /// ago (linear interpolation in the history; before t = 0 the plant was at rest at 0 kPa).
    fn delayed_sensed(&self, i: usize) -> f64 {
        let c = &self.ch[i];
        let d = self.cfg.effects.transport_delay_s;
        if d <= 0.0 {
            return c.sensed;
        }
        let target = c.t_us as f64 - d * 1e6;
        let mut prev = match c.history.front() {
            Some(&first) if first.0 as f64 <= target => first,
            Some(&first) => return first.1,
            None => return c.sensed,
        };
        for &(t, p) in c.history.iter().skip(1) {
            if t as f64 >= target {
                let span = (t - prev.0) as f64;
                let w = if span > 0.0 {
                    (target - prev.0 as f64) / span
                } else {
                    1.0
                };
                return prev.1 + w * (p - prev.1);
            }
            prev = (t, p);
        }
        prev.1
    }

    /// Integrate every chamber to `t_us`.
    pub fn advance_to(&mut self, t_us: u64) {
        for i in 0..CHAMBERS {
            self.advance_chamber(i, t_us);
        }
    }

    /// One motor step of chamber `i` at `t_us` (`inflate`: plunger pushes water in). The chamber is
    /// first integrated up to `t_us`; steps must come in time order per chamber.
    pub fn step(&mut self, i: usize, t_us: u64, inflate: bool) {
        self.advance_chamber(i, t_us);
        let b = self.cfg.effects.backlash_mm3;
        let per = self.cfg.mm3_per_step;
        let c = &mut self.ch[i];
        c.steps += if inflate { 1 } else { -1 };
        let motor = c.steps as f64 * per;
        // Play operator: the plunger moves only once the screw has taken up the backlash. (The
        // ideal drive's plunger follows the continuous commanded motion instead.)
        if self.cfg.drive == Drive::Lagged {
            c.plunger = c.plunger.clamp(motor - 0.5 * b, motor + 0.5 * b);
        }
    }

    /// Disconnect (or reconnect) sensor `i`.
    pub fn set_unplugged(&mut self, i: usize, unplugged: bool) {
        self.ch[i].unplugged = unplugged;
    }

    /// One conversion's noise on chamber `i`, kPa, of the sensor's [`NoiseTails`].
    fn noise_sample(&mut self, i: usize) -> f64 {
        use rand::RngExt;
        let rng = &mut self.ch[i].rng;
        match self.cfg.sensor.tails {
            NoiseTails::Gaussian => self.noise.sample(rng),
            NoiseTails::StudentT { dof } => {
                // Validated: dof > 2.
                let t = rand_distr::StudentT::new(dof).map_or(0.0, |d| d.sample(rng));
                t * self.cfg.sensor.noise_kpa
            }
            NoiseTails::Spikes { fraction, size_kpa } => {
                let n = self.noise.sample(rng);
                if rng.random_bool(fraction) {
                    n + if rng.random_bool(0.5) {
                        size_kpa
                    } else {
                        -size_kpa
                    }
                } else {
                    n
                }
            }
        }
    }

    /// Sensor output of chamber `i` in kPa (lagged pressure + offset + drift + noise); draws noise.
    fn sensor_kpa(&mut self, i: usize) -> f64 {
        let t = self.ch[i].t_us as f64 * 1e-6;
        let drift = match self.cfg.effects.thermal_drift {
            Some(d) if self.cfg.effects.forms.drift_ramp => {
                d.offset_change_kpa * (t / (2.0 * d.time_constant_s)).min(1.0)
            }
            Some(d) => d.offset_change_kpa * (1.0 - libm::exp(-t / d.time_constant_s)),
            None => 0.0,
        };
        let n = self.noise_sample(i);
        self.delayed_sensed(i) + self.cfg.sensor.offset_kpa[i] + drift + n
    }

    /// One ADC conversion of all channels at `t_us` (integrates the plant there first).
    pub fn adc_counts(&mut self, t_us: u64) -> [u16; CHAMBERS] {
        self.advance_to(t_us);
        core::array::from_fn(|i| {
            let kpa = self.sensor_kpa(i);
            if self.ch[i].unplugged {
                return 0;
            }
            let counts = firmware::board::kpa_to_counts(kpa as f32).round();
            counts.clamp(0.0, firmware::board::ADC_MAX as f32) as u16
        })
    }

    /// Ground truth of chamber `i` at its current time.
    pub fn truth(&self, i: usize) -> ChamberTruth {
        let c = &self.ch[i];
        let air = if c.air0 > 0.0 {
            c.air0 - self.compression(i, c.p).0
        } else {
            0.0
        };
        ChamberTruth {
            motor_mm3: c.steps as f64 * self.cfg.mm3_per_step,
            syringe_mm3: self.syringe(i),
            delivered_mm3: c.w,
            chamber_mm3: c.v,
            flow_mm3_s: c.vdot,
            pressure_kpa: c.p,
            sensed_kpa: self.delayed_sensed(i),
            air_mm3: air,
            leaked_mm3: c.leak,
        }
    }

    /// Net steps taken by motor `i`.
    pub fn steps(&self, i: usize) -> i64 {
        self.ch[i].steps
    }

    /// Time chamber `i` has been integrated to, µs.
    pub fn time_us(&self, i: usize) -> u64 {
        self.ch[i].t_us
    }
}

#[cfg(test)]
mod tests {
    use super::lag_step;

    /// A ramp `x = a·t` through the lag, stepped with sub-steps of uneven length (0.1–1 ms, as
    /// the integrator's are cut by motor steps and conversions): once the start has died out
    /// the output is the ramp exactly τ late, `a·(t − τ)`, whatever the sub-steps. Holding the
    /// input at each step's end value instead trails by `h/(e^(h/τ) − 1)` (hand-computed: 2.528 ms
    /// for τ = 3 ms and h = 1 ms, half a sub-step short).
    #[test]
    fn a_ramp_through_the_lag_trails_by_exactly_tau() {
        let (a, tau) = (40.0, 0.003);
        let (mut t, mut y, mut k) = (0.0f64, 0.0f64, 0u32);
        while t < 0.2 {
            // 0.1, 0.4, 0.7, 1.0 ms in turn.
            let h = 1e-4 * (1 + 3 * (k % 4)) as f64;
            y = lag_step(y, a * t, a * (t + h), h, tau);
            t += h;
            k += 1;
        }
        assert!(
            (y - a * (t - tau)).abs() < 1e-9 * a,
            "{y} vs {}",
            a * (t - tau)
        );

        // The end-held input, 1 ms sub-steps: a trail of h/(e^(h/τ) − 1).
        let (h, mut y, mut t) = (1e-3, 0.0f64, 0.0f64);
        while t < 0.2 {
            t += h;
            y = a * t + (y - a * t) * (-h / tau).exp();
        }
        let trail = (a * t - y) / a;
        assert!((trail - 0.002_527_7).abs() < 1e-7, "{trail}");
    }

    /// The step response: an input jumping from 0 to 1 over one short step and then held is
    /// `1 − e^(−t/τ)` after it, to the step's length (a linear ramp over it, not a jump).
    #[test]
    fn a_held_input_decays_as_the_exponential() {
        let tau = 0.02;
        let mut y = lag_step(0.0, 0.0, 1.0, 1e-6, tau);
        let mut t = 0.0;
        for _ in 0..50 {
            y = lag_step(y, 1.0, 1.0, 1e-3, tau);
            t += 1e-3;
        }
        let expect = 1.0 - (-t / tau).exp();
        assert!((y - expect).abs() < 1e-4, "{y} vs {expect}");
    }
}
