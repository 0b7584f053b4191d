//! Random rigs for the residual loop's benchmark (`vfp bench-loop`): plants, trajectories and
//! sensors drawn from a seed, each a [`Scenario`] the firmware's own tasks run.
//!
//! A rig is drawn from `(seed, index)` alone (ChaCha8, the seed as key, the index as stream), so
//! rig 17 of seed 1 is the same whether 20 or 500 rigs are drawn. What is drawn:
//!
//! * **effects**: none on a fifth of the rigs (clean), one on two fifths, two on a quarter, three
//!   on the rest, distinct kinds drawn uniformly from [`PlantedKind::ALL`] (host-sim's ten effect
//!   presets and the delivery lag of the lagged drive). Each effect's size is log-uniform from
//!   [`SIZE_RANGE`] times its preset ([`crate::Effects::preset`]; 3 ms for the delivery lag), from
//!   well below what a log can show to three times the preset; its second parameter (a
//!   hysteresis's transition, a ripple's period, a drift's time constant) is drawn around the
//!   preset's. Rigs without a delivery lag use the ideal drive, so a clean rig is clean; a
//!   delivery lag is planted on the ideal drive's continuous motion
//!   ([`crate::plant::Drive::LaggedServo`]), not on the step train, so that its size is the
//!   size of a lag: on the step train a τ_d below about a millisecond is a train of flow pulses
//!   that no lag explains (seed 1 of the 300-rig benchmark: 17 of 20 such rigs ended 1.5–40
//!   times the noise, counted as missed lags), and the step count trails the commanded motion
//!   by half a step, a further lag of 0.02 mm³ over the flow that the named time constant
//!   took in (2.3–4.2 ms planted, 2.5–9.8 ms named);
//! * **forms** ([`FormChoice`], `vfp bench-loop --forms`): the usual forms of the effects (those
//!   of [`crate::plant`]'s module docs, which the residual loop's effects were written against),
//!   host-sim's other form of each kind that has one ([`crate::plant::Forms`]), or either at even
//!   odds; drawn from a stream of their own, so the rest of a rig is the same whatever the choice;
//! * **trajectory** ([`Trajectory`]): the paper's protocol, irregular strokes (short dwells),
//!   random moves with long dwells, or breathing-like cycles ([`crate::scenario::Breathing`]);
//! * **length**: log-uniform in `samples` frames per chamber (default 5,000–20,000, 200–800 s at
//!   25 Hz); the trajectory is sized to it;
//! * **design**: SBA1 (half the rigs), SBA2 or SBA3 (the paper's rescaled laws, `crate::law`), the
//!   flows scaled as [`crate::Protocol::for_design`] does. SBA4 (7000 mm³) is left out: at its
//!   scaled flows one stroke takes half an hour;
//! * **sensor** ([`crate::SensorSpec`]): noise log-uniform in 0.03–0.5 kPa per conversion, Gaussian
//!   (70 %), Student's t with 3–8 degrees of freedom (15 %) or Gaussian with rare spikes (15 %).

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::law::Design;
use crate::plant::{
    Drive, Effects, Forms, Hysteresis, NoiseTails, PlantConfig, Ripple, SensorSpec, ThermalDrift,
    CHAMBERS,
};
use crate::scenario::{Breathing, Protocol, Scenario, Strokes, TimedCommand, START_S};

/// Each effect's size is drawn log-uniformly between these multiples of its preset.
pub const SIZE_RANGE: (f64, f64) = (0.1, 3.0);

/// Frame rate of the firmware's telemetry, Hz (sizes the trajectories to a number of samples).
const FRAME_HZ: f64 = 25.0;

/// The kinds of plant effect a rig can carry.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlantedKind {
    /// An air pocket in every syringe.
    Air,
    /// Rate-independent wall hysteresis.
    Hysteresis,
    /// First-order lag of the pressure sensor.
    SensorLag,
    /// Fluid inertance of the line.
    Inertance,
    /// Thermal drift of the sensor offset.
    ThermalDrift,
    /// Lead-screw backlash.
    Backlash,
    /// Lead-screw pitch error (pump ripple).
    Ripple,
    /// Laminar leak.
    Leak,
    /// Transport delay of the sensed pressure.
    TransportDelay,
    /// Creep of the chamber volume.
    VolumeCreep,
    /// The drive's delivery lag (τ_d), on the servo's continuous motion.
    DeliveryLag,
}

impl PlantedKind {
    /// Every kind, in the order of [`crate::EFFECT_PRESETS`], the delivery lag last.
    pub const ALL: [PlantedKind; 11] = [
        PlantedKind::Air,
        PlantedKind::Hysteresis,
        PlantedKind::SensorLag,
        PlantedKind::Inertance,
        PlantedKind::ThermalDrift,
        PlantedKind::Backlash,
        PlantedKind::Ripple,
        PlantedKind::Leak,
        PlantedKind::TransportDelay,
        PlantedKind::VolumeCreep,
        PlantedKind::DeliveryLag,
    ];

    /// Name as in [`crate::EFFECT_PRESETS`] (`delivery-lag` for the drive's lag).
    pub fn name(self) -> &'static str {
        match self {
            PlantedKind::Air => "air",
            PlantedKind::Hysteresis => "hysteresis",
            PlantedKind::SensorLag => "sensor-lag",
            PlantedKind::Inertance => "inertance",
            PlantedKind::ThermalDrift => "thermal-drift",
            PlantedKind::Backlash => "backlash",
            PlantedKind::Ripple => "ripple",
            PlantedKind::Leak => "leak",
            PlantedKind::TransportDelay => "transport-delay",
            PlantedKind::VolumeCreep => "volume-creep",
            PlantedKind::DeliveryLag => "delivery-lag",
        }
    }

    /// Whether host-sim has another form of the kind than the usual one ([`Forms`]): all but
    /// the inertance (a mass of water), the backlash (a dead band) and the transport delay (a
    /// delay).
    pub fn has_other_form(self) -> bool {
        !matches!(
            self,
            PlantedKind::Inertance | PlantedKind::Backlash | PlantedKind::TransportDelay
        )
    }

    /// The preset size of the kind's main parameter ([`Planted::size`]).
    pub fn preset_size(self) -> f64 {
        match self {
            PlantedKind::Air => 20.0,
            PlantedKind::Hysteresis => 1.0,
            PlantedKind::SensorLag => 0.02,
            PlantedKind::Inertance => 3.0e-4,
            PlantedKind::ThermalDrift => 1.0,
            PlantedKind::Backlash => 0.4,
            PlantedKind::Ripple => 0.2,
            PlantedKind::Leak => 0.002,
            PlantedKind::TransportDelay => 0.01,
            PlantedKind::VolumeCreep => 0.01,
            PlantedKind::DeliveryLag => 0.003,
        }
    }
}

/// One effect planted in a rig, in host-sim's units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Planted {
    /// Which.
    pub kind: PlantedKind,
    /// Its main parameter: air mm³, hysteresis half-height H_a kPa, sensor lag s, inertance
    /// kPa·s²/mm³, drift's final offset change kPa, backlash mm³, ripple amplitude mm³, leak
    /// mm³/(s·kPa), transport delay s, creep mm³/s, delivery time constant τ_d s.
    pub size: f64,
    /// Its second parameter, where it has one: hysteresis transition mm³, ripple period mm³,
    /// drift time constant s (0 otherwise).
    pub shape: f64,
    /// Planted in its other form ([`PlantedKind::has_other_form`], [`Planted::apply`]).
    pub other_form: bool,
}

impl Planted {
    /// Size relative to the preset.
    pub fn relative_size(&self) -> f64 {
        self.size / self.kind.preset_size()
    }

    /// Puts the effect into `plant`.
    pub fn apply(&self, plant: &mut PlantConfig) {
        let e = &mut plant.effects;
        match self.kind {
            PlantedKind::Air => e.air_pocket_mm3 = [self.size; CHAMBERS],
            PlantedKind::Hysteresis => {
                e.hysteresis = Some(Hysteresis {
                    amplitude_kpa: self.size,
                    transition_mm3: self.shape,
                })
            }
            PlantedKind::SensorLag => e.sensor_lag_s = self.size,
            PlantedKind::Inertance => e.inertance_kpa_s2_per_mm3 = self.size,
            PlantedKind::ThermalDrift => {
                e.thermal_drift = Some(ThermalDrift {
                    offset_change_kpa: self.size,
                    time_constant_s: self.shape,
                })
            }
            PlantedKind::Backlash => e.backlash_mm3 = self.size,
            PlantedKind::Ripple => {
                e.ripple = Some(Ripple {
                    amplitude_mm3: self.size,
                    period_mm3: self.shape,
                })
            }
            PlantedKind::Leak => e.leak_mm3_per_s_per_kpa = self.size,
            PlantedKind::TransportDelay => e.transport_delay_s = self.size,
            PlantedKind::VolumeCreep => e.volume_creep_mm3_per_s = self.size,
            PlantedKind::DeliveryLag => {
                plant.drive = Drive::LaggedServo;
                plant.delivery_time_constant_s = self.size;
            }
        }
        if !self.other_form {
            return;
        }
        let f: &mut Forms = &mut plant.effects.forms;
        match self.kind {
            PlantedKind::Air => f.air_polytropic_index = 1.4,
            PlantedKind::Hysteresis => f.hysteresis_linear = true,
            PlantedKind::SensorLag => f.sensor_lag_second_order = true,
            PlantedKind::ThermalDrift => f.drift_ramp = true,
            PlantedKind::Ripple => f.ripple_second_harmonic = 0.5,
            PlantedKind::Leak => f.leak_orifice_kpa = 5.0,
            PlantedKind::VolumeCreep => f.creep_time_constant_s = 300.0,
            PlantedKind::DeliveryLag => f.delivery_overdamped = true,
            PlantedKind::Inertance | PlantedKind::Backlash | PlantedKind::TransportDelay => {}
        }
    }

    /// The kind's name, with ` (other form)` when planted so.
    pub fn label(&self) -> String {
        if self.other_form {
            format!("{} (other form)", self.kind.name())
        } else {
            self.kind.name().to_string()
        }
    }
}

/// The motion a rig runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Trajectory {
    /// The paper's protocol (five flow levels on full strokes), cycles sized to the length.
    Protocol,
    /// Irregular strokes: random targets and flows, dwells up to 0.5 s.
    Strokes,
    /// Random moves with dwells up to 4 s.
    MovesWithDwells,
    /// Breathing-like cycles about mid volume, amplitude and rate varying breath to breath.
    Breathing,
}

impl Trajectory {
    /// Every kind.
    pub const ALL: [Trajectory; 4] = [
        Trajectory::Protocol,
        Trajectory::Strokes,
        Trajectory::MovesWithDwells,
        Trajectory::Breathing,
    ];

    /// Name (kebab case).
    pub fn name(self) -> &'static str {
        match self {
            Trajectory::Protocol => "protocol",
            Trajectory::Strokes => "strokes",
            Trajectory::MovesWithDwells => "moves-with-dwells",
            Trajectory::Breathing => "breathing",
        }
    }
}

/// Which forms the planted effects take ([`Forms`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FormChoice {
    /// The usual forms (the module docs of [`crate::plant`]: those the residual loop's effects
    /// were written against).
    #[default]
    Usual,
    /// The other form wherever a kind has one.
    Other,
    /// Each effect with another form in it with probability ½.
    Mixed,
}

impl FormChoice {
    /// Every choice.
    pub const ALL: [FormChoice; 3] = [FormChoice::Usual, FormChoice::Other, FormChoice::Mixed];

    /// Name (kebab case).
    pub fn name(self) -> &'static str {
        match self {
            FormChoice::Usual => "usual",
            FormChoice::Other => "other",
            FormChoice::Mixed => "mixed",
        }
    }
}

/// How rigs are drawn beyond the seed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigOptions {
    /// Range of the log's length, frames per chamber (drawn log-uniformly).
    pub samples: (usize, usize),
    /// The effects' forms.
    pub forms: FormChoice,
}

impl Default for RigOptions {
    fn default() -> Self {
        Self {
            samples: (5_000, 20_000),
            forms: FormChoice::Usual,
        }
    }
}

/// Why rigs cannot be drawn.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum RigError {
    /// The length range is empty or outside what a trajectory can be sized to.
    #[error(
        "samples {0}–{1}: the range must satisfy 500 ≤ low ≤ high ≤ 200000 frames per chamber"
    )]
    Samples(usize, usize),
}

/// One drawn rig.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RigSpec {
    /// The benchmark's seed.
    pub seed: u64,
    /// Index of the rig within the seed.
    pub index: usize,
    /// Design (chamber law).
    pub design: Design,
    /// Motion.
    pub trajectory: Trajectory,
    /// Target length, frames per chamber.
    pub samples: usize,
    /// Sensor noise and its kind.
    pub sensor: SensorSpec,
    /// Effects, none on a clean rig.
    pub planted: Vec<Planted>,
    /// Seed of the simulation's noise and of the trajectory's draws.
    pub sim_seed: u64,
}

/// Keys the stream of the effects' forms apart from the rig's own (`seed ^ FORMS_KEY`).
const FORMS_KEY: u64 = 0x666f_726d_7300_0000;

/// Log-uniform draw between `lo` and `hi`.
fn log_uniform(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    (lo.ln() + (hi.ln() - lo.ln()) * rng.random::<f64>()).exp()
}

/// Draws rig `index` of `seed`.
pub fn draw(seed: u64, index: usize, opts: &RigOptions) -> Result<RigSpec, RigError> {
    let (lo, hi) = opts.samples;
    if !(500 <= lo && lo <= hi && hi <= 200_000) {
        return Err(RigError::Samples(lo, hi));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(index as u64);
    let count = match rng.random::<f64>() {
        u if u < 0.20 => 0,
        u if u < 0.60 => 1,
        u if u < 0.85 => 2,
        _ => 3,
    };
    let mut kinds = PlantedKind::ALL.to_vec();
    let mut planted = Vec::with_capacity(count);
    for _ in 0..count {
        let kind = kinds.remove(rng.random_range(0..kinds.len()));
        let size = kind.preset_size() * log_uniform(&mut rng, SIZE_RANGE.0, SIZE_RANGE.1);
        let shape = match kind {
            PlantedKind::Hysteresis => log_uniform(&mut rng, 8.0, 50.0),
            PlantedKind::Ripple => log_uniform(&mut rng, 5.0, 13.0),
            PlantedKind::ThermalDrift => log_uniform(&mut rng, 100.0, 1_000.0),
            _ => 0.0,
        };
        planted.push(Planted {
            kind,
            size,
            shape,
            other_form: false,
        });
    }
    planted.sort_by_key(|p| p.kind);
    // The forms from a stream of their own, so a rig's other draws do not depend on them.
    let mut forms = ChaCha8Rng::seed_from_u64(seed ^ FORMS_KEY);
    forms.set_stream(index as u64);
    for p in &mut planted {
        let coin = forms.random::<f64>() < 0.5;
        p.other_form = p.kind.has_other_form()
            && match opts.forms {
                FormChoice::Usual => false,
                FormChoice::Other => true,
                FormChoice::Mixed => coin,
            };
    }
    let trajectory = Trajectory::ALL[rng.random_range(0..Trajectory::ALL.len())];
    let design = match rng.random::<f64>() {
        u if u < 0.5 => Design::Sba1,
        u if u < 0.75 => Design::Sba2,
        _ => Design::Sba3,
    };
    let samples = log_uniform(&mut rng, lo as f64, hi as f64).round() as usize;
    let noise_kpa = log_uniform(&mut rng, 0.03, 0.5);
    let tails = match rng.random::<f64>() {
        u if u < 0.70 => NoiseTails::Gaussian,
        u if u < 0.85 => NoiseTails::StudentT {
            dof: 3.0 + 5.0 * rng.random::<f64>(),
        },
        _ => NoiseTails::Spikes {
            fraction: log_uniform(&mut rng, 1e-3, 1e-2),
            size_kpa: noise_kpa * log_uniform(&mut rng, 5.0, 20.0),
        },
    };
    let sensor = SensorSpec {
        noise_kpa,
        tails,
        ..SensorSpec::default()
    };
    Ok(RigSpec {
        seed,
        index,
        design,
        trajectory,
        samples,
        sensor,
        planted,
        sim_seed: rng.random::<u64>() >> 1,
    })
}

impl RigSpec {
    /// A short label: `rig 17: sba2 breathing 8,400 frames, air + leak`.
    pub fn label(&self) -> String {
        let effects = if self.planted.is_empty() {
            "clean".to_string()
        } else {
            self.planted
                .iter()
                .map(Planted::label)
                .collect::<Vec<_>>()
                .join(" + ")
        };
        format!(
            "rig {}: {} {} {} frames, {}",
            self.index,
            self.design.name(),
            self.trajectory.name(),
            self.samples,
            effects
        )
    }

    /// The plant with the planted effects `keep` accepts.
    pub fn plant(&self, keep: impl Fn(PlantedKind) -> bool) -> PlantConfig {
        let mut plant = PlantConfig {
            design: self.design,
            sensor: self.sensor.clone(),
            drive: Drive::Ideal,
            effects: Effects::default(),
            ..PlantConfig::default()
        };
        for p in self.planted.iter().filter(|p| keep(p.kind)) {
            p.apply(&mut plant);
        }
        plant
    }

    /// The scenario of the rig with every planted effect.
    pub fn scenario(&self) -> Scenario {
        self.scenario_without(None)
    }

    /// The scenario of the rig without one of its effects (`None`: with all): the same
    /// trajectory, sensor and noise seed, so the two runs differ by that effect alone.
    pub fn scenario_without(&self, without: Option<PlantedKind>) -> Scenario {
        self.scenario_with(|k| Some(k) != without)
    }

    /// The scenario of the rig with the planted effects `keep` accepts (same trajectory, sensor
    /// and noise seed).
    pub fn scenario_with(&self, keep: impl Fn(PlantedKind) -> bool) -> Scenario {
        let plant = self.plant(keep);
        let d = self.design;
        let scale = Design::Sba1.mean_damping() / d.mean_damping();
        let (flow_low, flow_high) = (20.0 * scale, 100.0 * scale);
        let v_max = d.max_volume_mm3();
        let target_s = self.samples as f64 / FRAME_HZ;
        let name = format!("bench-{}-{}", self.seed, self.index);
        let mut sc = match self.trajectory {
            Trajectory::Protocol => {
                let one = Protocol::for_design(d, 0.0);
                let per_cycle = one.duration_s() - 1.0;
                let cycles = ((target_s / per_cycle).round() as u16).max(1);
                Scenario::protocol(&name, plant, &Protocol { cycles, ..one })
            }
            Trajectory::Strokes | Trajectory::MovesWithDwells => {
                let dwell_max_s = if self.trajectory == Trajectory::Strokes {
                    0.5
                } else {
                    4.0
                };
                // Mean move: a third of the range over a uniform flow (the mean of 1/flow is
                // ln(high/low)/(high − low)), the ramps, half a dwell.
                let mean_s = v_max / 3.0 * (flow_high / flow_low).ln() / (flow_high - flow_low)
                    + 0.3
                    + 0.5 * dwell_max_s;
                let strokes = Strokes {
                    moves: ((target_s / mean_s).round() as usize).max(4),
                    v_low: 0.0,
                    v_high: v_max,
                    flow_low,
                    flow_high,
                    dwell_max_s,
                    seed: self.sim_seed,
                };
                Scenario::strokes(&name, plant, &strokes)
            }
            Trajectory::Breathing => {
                let breathing = Breathing {
                    duration_s: target_s,
                    v_mid: 0.5 * v_max,
                    amplitude_mm3: 0.3 * v_max,
                    flow_mm3_s: 0.5 * (flow_low + flow_high),
                    pause_max_s: 1.5,
                    seed: self.sim_seed,
                };
                Scenario::breathing(&name, plant, &breathing)
            }
        };
        if d != Design::Sba1 && self.trajectory != Trajectory::Protocol {
            // The firmware's limits default to SBA1's envelope (Scenario::protocol widens them).
            sc.commands.insert(
                0,
                TimedCommand::new(
                    START_S - 0.2,
                    &format!("limit all {} {}", d.max_pressure_kpa() * 1.5, v_max),
                ),
            );
        }
        sc.seed = self.sim_seed;
        sc
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_same_seed_and_index_give_the_same_rig() {
        let o = RigOptions::default();
        for i in 0..20 {
            let a = draw(7, i, &o).unwrap();
            assert_eq!(a, draw(7, i, &o).unwrap());
            assert_eq!(a.scenario(), draw(7, i, &o).unwrap().scenario());
        }
        // Another seed, other rigs.
        let differ = (0..20)
            .filter(|&i| draw(7, i, &o).unwrap() != draw(8, i, &o).unwrap())
            .count();
        assert_eq!(differ, 20);
    }

    /// The forms change nothing else about a rig: `usual` and `other` draw the same rigs, the
    /// second with every effect that has another form in it; `mixed` about half of them.
    #[test]
    fn the_forms_are_drawn_apart_from_the_rig() {
        let with = |forms| RigOptions {
            forms,
            ..RigOptions::default()
        };
        let (mut other, mut mixed, mut can) = (0, 0, 0);
        for i in 0..200 {
            let usual = draw(5, i, &with(FormChoice::Usual)).unwrap();
            let o = draw(5, i, &with(FormChoice::Other)).unwrap();
            let m = draw(5, i, &with(FormChoice::Mixed)).unwrap();
            assert!(usual.planted.iter().all(|p| !p.other_form));
            for r in [&o, &m] {
                let strip = |r: &RigSpec| {
                    let mut r = r.clone();
                    r.planted.iter_mut().for_each(|p| p.other_form = false);
                    r
                };
                assert_eq!(strip(r), usual, "rig {i}");
            }
            for (p, q) in o.planted.iter().zip(&m.planted) {
                assert_eq!(p.other_form, p.kind.has_other_form());
                assert!(!q.other_form || q.kind.has_other_form());
                can += usize::from(p.kind.has_other_form());
                other += usize::from(p.other_form);
                mixed += usize::from(q.other_form);
            }
        }
        assert_eq!(other, can);
        // Binomial(can, ½): within 4σ.
        let sd = (can as f64 / 4.0).sqrt();
        assert!(
            (mixed as f64 - can as f64 / 2.0).abs() < 4.0 * sd,
            "{mixed} of {can}"
        );
    }

    #[test]
    fn sizes_lengths_and_counts_stay_in_their_ranges() {
        let o = RigOptions {
            samples: (5_000, 9_000),
            ..RigOptions::default()
        };
        let rigs: Vec<RigSpec> = (0..400).map(|i| draw(3, i, &o).unwrap()).collect();
        let clean = rigs.iter().filter(|r| r.planted.is_empty()).count();
        // 20 % expected: 80 of 400, binomial σ = 8.
        assert!((56..=104).contains(&clean), "{clean} clean rigs of 400");
        for r in &rigs {
            assert!(r.planted.len() <= 3);
            assert!((5_000..=9_000).contains(&r.samples), "{}", r.samples);
            assert!((0.03..=0.5).contains(&r.sensor.noise_kpa));
            let mut kinds: Vec<_> = r.planted.iter().map(|p| p.kind).collect();
            kinds.dedup();
            assert_eq!(
                kinds.len(),
                r.planted.len(),
                "a kind twice: {:?}",
                r.planted
            );
            for p in &r.planted {
                let s = p.relative_size();
                assert!(
                    (SIZE_RANGE.0..=SIZE_RANGE.1).contains(&s),
                    "{:?}: {s}× its preset",
                    p
                );
            }
        }
        // Every kind and trajectory is drawn.
        for k in PlantedKind::ALL {
            assert!(rigs.iter().any(|r| r.planted.iter().any(|p| p.kind == k)));
        }
        for t in Trajectory::ALL {
            assert!(rigs.iter().any(|r| r.trajectory == t));
        }
    }

    #[test]
    fn a_clean_rig_has_no_effect_and_the_ideal_drive() {
        let o = RigOptions::default();
        let clean = (0..50)
            .map(|i| draw(11, i, &o).unwrap())
            .find(|r| r.planted.is_empty())
            .expect("a clean rig among 50");
        let plant = clean.scenario().plant;
        assert_eq!(plant.effects, Effects::default());
        assert_eq!(plant.drive, Drive::Ideal);
    }

    #[test]
    fn removing_an_effect_changes_only_that_effect() {
        let o = RigOptions::default();
        let rig = (0..100)
            .map(|i| draw(5, i, &o).unwrap())
            .find(|r| r.planted.len() == 3)
            .expect("a three-effect rig among 100");
        let all = rig.scenario();
        for p in &rig.planted {
            let without = rig.scenario_without(Some(p.kind));
            assert_eq!(all.commands, without.commands);
            assert_eq!(all.seed, without.seed);
            assert_ne!(all.plant, without.plant);
            // Putting it back gives the whole rig.
            let mut plant = without.plant.clone();
            p.apply(&mut plant);
            assert_eq!(plant, all.plant);
        }
    }

    #[test]
    fn breathing_swings_about_mid_volume_within_the_range() {
        let b = Breathing {
            duration_s: 300.0,
            v_mid: 275.0,
            amplitude_mm3: 165.0,
            flow_mm3_s: 60.0,
            pause_max_s: 1.5,
            seed: 4,
        };
        let (cmds, end) = b.commands();
        assert!(end >= START_S + 300.0, "ends at {end} s");
        let targets: Vec<f64> = cmds
            .iter()
            .map(|c| c.line.split(' ').nth(2).unwrap().parse().unwrap())
            .collect();
        assert!(targets.iter().all(|&v| (0.0..=550.0).contains(&v)));
        // Up and down in turn, after the first move to the bottom.
        for w in targets[1..].windows(2) {
            assert!((w[0] > 275.0) != (w[1] > 275.0), "{w:?}");
        }
        assert!(cmds.windows(2).all(|w| w[0].at_s < w[1].at_s));
    }

    #[test]
    fn an_empty_or_reversed_length_range_is_an_error() {
        for samples in [(9_000, 5_000), (10, 20), (5_000, 1_000_000)] {
            assert_eq!(
                draw(
                    1,
                    0,
                    &RigOptions {
                        samples,
                        ..RigOptions::default()
                    }
                ),
                Err(RigError::Samples(samples.0, samples.1))
            );
        }
    }
}
