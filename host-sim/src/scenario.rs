//! Scenarios: what to simulate, as data.
//!
//! A scenario is a TOML file (or a [`Scenario`] built in code). Vocabulary, every key optional
//! unless marked:
//!
//! ```toml
//! name = "paper-protocol"          # label, copied into the log metadata
//! description = "…"
//! seed = 1                          # noise seed: same seed, same log, byte for byte
//! duration_s = 3000.0               # simulated time limit, s (required)
//! stop_on = "protocol-done"         # end early, `tail_s` after the first event line of this kind
//! tail_s = 1.0                      #   (boot, fault, cleared, zeroed, drift, protocol-done, model)
//! quantum_us = 1000                 # virtual-time step of the executor loop, µs
//! record_detail = false             # keep every step and ADC conversion's truth (tests)
//!
//! [plant]                           # the physics (crate::plant::PlantConfig)
//! design = "sba1"                   # sba1 | sba2 | sba3 | sba4 (paper Table V)
//! drive = "lagged"                 # lagged: the step train through τ_d (≈ 2τ_d = 6 ms late);
//!                                   # ideal: rate-matched, no lag (only the sensor deviates)
//! delivery_time_constant_s = 0.003  # motor/screw/tubing smoothing of the step train (lagged)
//! mm3_per_step = 0.04
//! area_mm2 = [22.0, 22.0, 22.0]     # effective area per chamber (force share → pressure)
//! max_substep_s = 0.001             # backward-Euler sub-step limit
//! [plant.sensor]                    # always on
//! noise_kpa = 0.05
//! offset_kpa = [0.42, -0.31, 0.18]
//! [plant.effects]                   # each off unless given
//! air_pocket_mm3 = [20.0, 0.0, 0.0]
//! hysteresis = { amplitude_kpa = 1.0, transition_mm3 = 20.0 }
//! sensor_lag_s = 0.02
//! inertance_kpa_s2_per_mm3 = 3e-4
//! thermal_drift = { offset_change_kpa = 1.0, time_constant_s = 600.0 }
//! backlash_mm3 = 0.4
//! ripple = { amplitude_mm3 = 0.2, period_mm3 = 8.0 }
//! leak_mm3_per_s_per_kpa = 0.001
//! transport_delay_s = 0.01          # the sensor reports the pressure of 10 ms ago
//! volume_creep_mm3_per_s = 0.01     # the chamber loses volume at a constant rate
//!
//! [[force]]                         # raised-cosine pulse trains on the tip
//! start_s = 10.0
//! duration_s = 10.0
//! frequency_hz = 1.0
//! peak_n = 0.3
//! azimuth_deg = 30.0                # chamber i sits at 120°·i
//! tilt_deg = 60.0                   # from the actuator axis
//!
//! [[commands]]                      # lines sent to the firmware's command port (its protocol)
//! at_s = 1.5
//! line = "run all 0 550 20 200 20 40 60 80 100"
//! framing = "checksummed"           # sent as `*LLCC <line>`, as a host does (the firmware
//!                                   # requires it); plain: the line as written (refused at
//!                                   # boot unless `stop`; or a line framed by hand)
//!
//! [[serial_faults]]                 # a byte of one command line goes wrong on the UART
//! command = 0                       # index into `commands` (in file order)
//! byte = 7                          # byte of the line as sent, its `*LLCC ` prefix included
//!                                   # (0-based; the `\n` is the last)
//! kind = "lose"                     # lose: lost, the UART reports an overrun
//!                                   # flag: arrives, with a framing error reported
//!                                   # drop: lost, no error reported (only a checksum can tell)
//!
//! [[telemetry_stalls]]              # the host stops reading telemetry: the transport is full
//! start_s = 3.0
//! duration_s = 4.0
//!
//! [[faults]]                        # injected hardware faults
//! at_s = 5.0
//! unplug = 1                        # sensor 1's connector comes off
//! ```
//!
//! The firmware takes its pressure zero during the first second after boot and refuses motion
//! until then, so commands usually start at 1.5 s.

use serde::{Deserialize, Serialize};

use crate::law::Design;
use crate::plant::{Effects, ForcePush, PlantConfig, CHAMBERS};

/// How the simulated host puts a command line on the wire.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Framing {
    /// `*LLCC <line>` (`firmware::command::write_checksummed`), as every host sends: the
    /// firmware requires it from boot.
    #[default]
    Checksummed,
    /// The line as written: what a person types at a terminal (refused at boot unless it is
    /// `stop`), or a line framed by hand.
    Plain,
}

impl Framing {
    fn is_default(&self) -> bool {
        *self == Self::default()
    }
}

/// A command line sent at a given time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TimedCommand {
    /// When, s of simulated time.
    pub at_s: f64,
    /// The command, without terminator (the simulator appends `\n`).
    pub line: String,
    /// How it is sent: checksummed unless given.
    #[serde(default, skip_serializing_if = "Framing::is_default")]
    pub framing: Framing,
}

impl TimedCommand {
    /// A command at `at_s`, sent checksummed.
    pub fn new(at_s: f64, line: &str) -> Self {
        Self {
            at_s,
            line: line.into(),
            framing: Framing::Checksummed,
        }
    }

    /// A line at `at_s`, sent as written ([`Framing::Plain`]).
    pub fn plain(at_s: f64, line: &str) -> Self {
        Self {
            framing: Framing::Plain,
            ..Self::new(at_s, line)
        }
    }

    /// The bytes put on the wire, without the `\n`; `None` if the line cannot be checksummed
    /// (it holds a `*`, or is too long for its prefix).
    pub fn wire(&self) -> Option<String> {
        match self.framing {
            Framing::Plain => Some(self.line.clone()),
            Framing::Checksummed => {
                let mut s =
                    String::with_capacity(firmware::command::CHECKSUM_PREFIX + self.line.len());
                firmware::command::write_checksummed(&self.line, &mut s).ok()?;
                Some(s)
            }
        }
    }
}

/// What goes wrong with a byte on the UART.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SerialFaultKind {
    /// The byte is lost and the UART reports an overrun.
    Lose,
    /// The byte arrives, with a framing error reported.
    Flag,
    /// The byte is lost and nothing is reported.
    Drop,
}

/// One byte of one command line going wrong on the UART.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SerialFault {
    /// Index into the scenario's `commands`.
    pub command: usize,
    /// Byte of the line as sent (its `\n` is byte `line.len()`).
    pub byte: usize,
    /// What happens to it.
    pub kind: SerialFaultKind,
}

/// A time during which the host does not read telemetry: every line offered is refused.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TelemetryStall {
    /// Start, s of simulated time.
    pub start_s: f64,
    /// Length, s.
    pub duration_s: f64,
}

/// A hardware fault injected at a given time.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultInjection {
    /// When, s of simulated time.
    pub at_s: f64,
    /// Disconnect this sensor (it then reads 0 counts).
    pub unplug: usize,
}

/// Everything that defines one simulated run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Scenario {
    /// Label.
    pub name: String,
    /// What it shows.
    pub description: String,
    /// Seed of the sensor noise.
    pub seed: u64,
    /// Simulated time limit, s.
    pub duration_s: f64,
    /// End `tail_s` after the first event line of this kind (e.g. `protocol-done`).
    pub stop_on: Option<String>,
    /// See `stop_on`, s.
    pub tail_s: f64,
    /// Executor loop step, µs.
    pub quantum_us: u64,
    /// The physics.
    pub plant: PlantConfig,
    /// External force pushes.
    pub force: Vec<ForcePush>,
    /// Commands, in any order (sent in time order).
    pub commands: Vec<TimedCommand>,
    /// Injected faults.
    pub faults: Vec<FaultInjection>,
    /// Times the host does not read telemetry.
    pub telemetry_stalls: Vec<TelemetryStall>,
    /// Bytes of command lines going wrong on the UART.
    pub serial_faults: Vec<SerialFault>,
    /// Keep every step pulse and the truth at every ADC conversion in [`crate::SimRun`] (off by
    /// default: an hour holds millions of them).
    pub record_detail: bool,
}

impl Default for Scenario {
    fn default() -> Self {
        Self {
            name: "unnamed".into(),
            description: String::new(),
            seed: 1,
            duration_s: 10.0,
            stop_on: None,
            tail_s: 1.0,
            quantum_us: 1_000,
            plant: PlantConfig::default(),
            force: Vec::new(),
            commands: Vec::new(),
            faults: Vec::new(),
            telemetry_stalls: Vec::new(),
            serial_faults: Vec::new(),
            record_detail: false,
        }
    }
}

/// When commands start: after the firmware's 1 s boot zero.
pub const START_S: f64 = 1.5;

/// The paper's protocol parameters (Sec. II: 0–550 mm³, 20–100 mm³/s, ≥ 20 cycles per rate).
#[derive(Clone, Debug, PartialEq)]
pub struct Protocol {
    /// Lower volume, mm³.
    pub v_low: f64,
    /// Upper volume, mm³.
    pub v_high: f64,
    /// Cycles per flow rate.
    pub cycles: u16,
    /// Dwell at each end, ms.
    pub dwell_ms: u32,
    /// Flow rates, mm³/s.
    pub flows: Vec<f64>,
}

impl Protocol {
    /// The paper's protocol scaled to `design` (see [`Scenario::design`]), with `cycle_frac` of
    /// the cycles (at least one).
    pub fn for_design(design: Design, cycle_frac: f64) -> Self {
        let scale = Design::Sba1.mean_damping() / design.mean_damping();
        let cycles = if design == Design::Sba4 { 1.0 } else { 20.0 };
        Self {
            v_high: design.max_volume_mm3(),
            cycles: ((cycles * cycle_frac).round() as u16).max(1),
            flows: Self::paper()
                .flows
                .iter()
                .map(|f| (f * scale * 10.0).round() / 10.0)
                .collect(),
            ..Self::paper()
        }
    }

    /// The paper's: 0–550 mm³, 20 cycles at each of 20, 40, 60, 80, 100 mm³/s.
    pub fn paper() -> Self {
        Self {
            v_low: 0.0,
            v_high: 550.0,
            cycles: 20,
            dwell_ms: 200,
            flows: vec![20.0, 40.0, 60.0, 80.0, 100.0],
        }
    }

    /// The firmware command line that runs it on all axes.
    pub fn command(&self) -> String {
        let flows: Vec<String> = self.flows.iter().map(|f| format!("{f}")).collect();
        format!(
            "run all {} {} {} {} {}",
            self.v_low,
            self.v_high,
            self.cycles,
            self.dwell_ms,
            flows.join(" ")
        )
    }

    /// Time it takes, s (moves at constant flow plus dwells; acceleration phases ignored).
    pub fn duration_s(&self) -> f64 {
        let span = self.v_high - self.v_low;
        let per_flow: f64 = self
            .flows
            .iter()
            .map(|f| self.cycles as f64 * 2.0 * (span / f + self.dwell_ms as f64 * 1e-3))
            .sum();
        per_flow + self.v_low / 50.0 + 1.0
    }
}

/// Irregular strokes, unlike the paper's protocol: `moves` moves of all three axes to random
/// volumes in `v_low..=v_high`, each at a random flow in `flow_low..=flow_high` mm³/s, each
/// followed by a random dwell of up to `dwell_max_s`; drawn from `seed`. The protocol's trajectory
/// visits five flow levels, each on full strokes; these visit every flow, on strokes of every
/// length, and rest at every volume.
#[derive(Clone, Debug, PartialEq)]
pub struct Strokes {
    /// Number of moves.
    pub moves: usize,
    /// Lowest target volume, mm³.
    pub v_low: f64,
    /// Highest target volume, mm³.
    pub v_high: f64,
    /// Slowest flow, mm³/s.
    pub flow_low: f64,
    /// Fastest flow, mm³/s.
    pub flow_high: f64,
    /// Longest dwell after a move, s.
    pub dwell_max_s: f64,
    /// Seed of the draws.
    pub seed: u64,
}

impl Default for Strokes {
    /// 120 moves over the paper's range and rates (0–550 mm³, 20–100 mm³/s), dwells up to 1 s.
    fn default() -> Self {
        Self {
            moves: 120,
            v_low: 0.0,
            v_high: 550.0,
            flow_low: 20.0,
            flow_high: 100.0,
            dwell_max_s: 1.0,
            seed: 1,
        }
    }
}

impl Strokes {
    /// The `move all V F` command lines, timed from [`START_S`]: each sent when the one before
    /// has had time to finish (its length over its flow, plus 0.3 s for the ramps) and dwell;
    /// and the time the last one is done, s.
    pub fn commands(&self) -> (Vec<TimedCommand>, f64) {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.seed);
        let (mut t, mut v) = (START_S, 0.0f64);
        let mut out = Vec::with_capacity(self.moves);
        for _ in 0..self.moves {
            let target = self.v_low + (self.v_high - self.v_low) * rng.random::<f64>();
            let flow = self.flow_low + (self.flow_high - self.flow_low) * rng.random::<f64>();
            let target = (target * 10.0).round() / 10.0;
            let flow = (flow * 10.0).round() / 10.0;
            out.push(TimedCommand::new(t, &format!("move all {target} {flow}")));
            t += (target - v).abs() / flow + 0.3 + self.dwell_max_s * rng.random::<f64>();
            v = target;
        }
        (out, t)
    }
}

/// Breathing-like cycles, unlike strokes between random targets: all three axes inhale from
/// below `v_mid` to above it and exhale back, each breath's depth (0.6–1.4 × `amplitude_mm3` on
/// either side of `v_mid`) and inhaling flow (0.7–1.3 × `flow_mm3_s`) drawn anew, exhaling at
/// 0.6× the inhaling flow, holding 0.2 s at the top and pausing up to `pause_max_s` at the
/// bottom; drawn from `seed`, for `duration_s` of motion.
#[derive(Clone, Debug, PartialEq)]
pub struct Breathing {
    /// Length of the motion, s.
    pub duration_s: f64,
    /// Volume the breaths swing about, mm³.
    pub v_mid: f64,
    /// Mean swing to either side, mm³.
    pub amplitude_mm3: f64,
    /// Mean inhaling flow, mm³/s.
    pub flow_mm3_s: f64,
    /// Longest pause after exhaling, s.
    pub pause_max_s: f64,
    /// Seed of the draws.
    pub seed: u64,
}

impl Breathing {
    /// The `move all V F` command lines, timed from [`START_S`] (each sent when the one before
    /// has had time to finish, plus 0.3 s for the ramps), and the time the last one is done, s.
    /// Targets stay within `0..=2·v_mid`.
    pub fn commands(&self) -> (Vec<TimedCommand>, f64) {
        use rand::{RngExt, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(self.seed);
        let round = |x: f64| (x * 10.0).round() / 10.0;
        let (lo, hi) = (0.0, 2.0 * self.v_mid);
        let (mut t, mut v) = (START_S, 0.0f64);
        let mut out = Vec::new();
        let go = |out: &mut Vec<TimedCommand>, t: &mut f64, v: &mut f64, to: f64, f: f64| {
            let (to, f) = (round(to.clamp(lo, hi)), round(f.max(1.0)));
            out.push(TimedCommand::new(*t, &format!("move all {to} {f}")));
            *t += (to - *v).abs() / f + 0.3;
            *v = to;
        };
        let depth = |u: f64| self.amplitude_mm3 * (0.6 + 0.8 * u);
        let first = self.v_mid - depth(rng.random::<f64>());
        go(&mut out, &mut t, &mut v, first, self.flow_mm3_s);
        while t < START_S + self.duration_s {
            let f_in = self.flow_mm3_s * (0.7 + 0.6 * rng.random::<f64>());
            let top = self.v_mid + depth(rng.random::<f64>());
            go(&mut out, &mut t, &mut v, top, f_in);
            t += 0.2;
            let bottom = self.v_mid - depth(rng.random::<f64>());
            go(&mut out, &mut t, &mut v, bottom, 0.6 * f_in);
            t += self.pause_max_s * rng.random::<f64>();
        }
        (out, t)
    }
}

/// The settings of [`Scenario::preset`] beyond its name.
#[derive(Debug, Clone, PartialEq)]
pub struct PresetOptions {
    /// Cycles per flow rate (protocol presets; default: the protocol's).
    pub cycles: Option<u16>,
    /// Flow rates, mm³/s (protocol presets; default: the protocol's).
    pub flows: Option<Vec<f64>>,
    /// Peak push force, N (`force` preset).
    pub force_peak_n: f64,
    /// Seconds of pushing (`force` preset).
    pub force_seconds: f64,
}

impl Default for PresetOptions {
    fn default() -> Self {
        Self {
            cycles: None,
            flows: None,
            force_peak_n: 0.5,
            force_seconds: 20.0,
        }
    }
}

impl Scenario {
    /// The scenario a preset names (`vfp simulate --preset`, the Python package's `simulate`):
    /// `paper` (the paper's protocol on SBA1), `air:MM3` (an air pocket of MM3 mm³ in every
    /// syringe), `design:sba1|sba2|sba3|sba4`, `effect:NAME` (one plant effect of
    /// [`crate::EFFECT_PRESETS`]), `force` (1 Hz pushes at 500 mm³, with truth); the protocol
    /// presets take `args.cycles` and `args.flows`. The error names the option at fault.
    pub fn preset(spec: &str, args: &PresetOptions) -> Result<Scenario, String> {
        let (kind, value) = match spec.split_once(':') {
            Some((k, v)) => (k, Some(v)),
            None => (spec, None),
        };
        let protocol_for = |base: Scenario, proto: Protocol| -> Result<Scenario, String> {
            let mut proto = proto;
            if let Some(c) = args.cycles {
                if c == 0 {
                    return Err("--cycles must be at least 1".into());
                }
                proto.cycles = c;
            }
            if let Some(f) = &args.flows {
                if f.is_empty() || f.iter().any(|x| !(x.is_finite() && *x > 0.0)) {
                    return Err(format!(
                        "--flows {f:?}: every flow must be a positive number of mm3/s"
                    ));
                }
                proto.flows = f.clone();
            }
            Ok(Self::protocol(&base.name, base.plant, &proto))
        };
        match (kind, value) {
            ("paper", None) => protocol_for(Self::paper_protocol(), Protocol::paper()),
            ("air", Some(v)) => {
                let mm3: f64 = v
                    .parse()
                    .ok()
                    .filter(|x: &f64| x.is_finite() && *x >= 0.0)
                    .ok_or_else(|| {
                        format!("--preset air:{v}: the air volume must be a number of mm3 >= 0")
                    })?;
                protocol_for(Self::air_pocket(mm3), Protocol::paper())
            }
            ("design", Some(v)) => {
                let design = Design::ALL
                    .into_iter()
                    .find(|d| d.name() == v.to_ascii_lowercase())
                    .ok_or_else(|| {
                        format!("--preset design:{v}: unknown design (sba1, sba2, sba3 or sba4)")
                    })?;
                protocol_for(Self::design(design), Protocol::for_design(design, 1.0))
            }
            ("effect", Some(v)) => {
                let base = Self::effect(v).ok_or_else(|| {
                    format!(
                        "--preset effect:{v}: unknown effect (one of {})",
                        crate::EFFECT_PRESETS.join(", ")
                    )
                })?;
                protocol_for(base, Protocol::paper())
            }
            ("force", None) => {
                if !(args.force_peak_n.is_finite() && args.force_seconds > 0.0) {
                    return Err(
                        "--force-peak-n and --force-seconds must be finite, seconds > 0".into(),
                    );
                }
                Ok(Self::force_pushes(args.force_peak_n, args.force_seconds))
            }
            _ => Err(format!(
                "--preset {}: unknown preset (paper, air:MM3, design:sbaN, effect:NAME, force)",
                spec
            )),
        }
    }

    /// Run `protocol` on all three chambers of `plant`, ending shortly after it is done.
    pub fn protocol(name: &str, plant: PlantConfig, protocol: &Protocol) -> Self {
        let d = plant.design;
        let mut commands = Vec::new();
        if d != Design::Sba1 {
            // The firmware's limits default to SBA1's envelope; widen them to the design's.
            commands.push(TimedCommand::new(
                START_S - 0.2,
                &format!(
                    "limit all {} {}",
                    d.max_pressure_kpa() * 1.5,
                    d.max_volume_mm3()
                ),
            ));
        }
        commands.push(TimedCommand::new(START_S, &protocol.command()));
        Self {
            name: name.into(),
            description: format!(
                "{} protocol {}–{} mm³, {} cycles at {:?} mm³/s",
                d.name(),
                protocol.v_low,
                protocol.v_high,
                protocol.cycles,
                protocol.flows
            ),
            duration_s: START_S + 1.5 * protocol.duration_s() + 10.0,
            stop_on: Some("protocol-done".into()),
            plant,
            commands,
            ..Self::default()
        }
    }

    /// Run `strokes` on all three chambers of `plant` (see [`Strokes`]), ending 2 s after the
    /// last move is done.
    pub fn strokes(name: &str, plant: PlantConfig, strokes: &Strokes) -> Self {
        let (commands, end) = strokes.commands();
        Self {
            name: name.into(),
            description: format!(
                "{} irregular strokes, {}–{} mm³ at {}–{} mm³/s, dwells up to {} s (seed {})",
                strokes.moves,
                strokes.v_low,
                strokes.v_high,
                strokes.flow_low,
                strokes.flow_high,
                strokes.dwell_max_s,
                strokes.seed
            ),
            duration_s: end + 2.0,
            plant,
            commands,
            ..Self::default()
        }
    }

    /// Run `breathing` on all three chambers of `plant` (see [`Breathing`]), ending 2 s after
    /// the last move is done.
    pub fn breathing(name: &str, plant: PlantConfig, breathing: &Breathing) -> Self {
        let (commands, end) = breathing.commands();
        Self {
            name: name.into(),
            description: format!(
                "breathing about {} mm³, ±{} mm³ at {} mm³/s, pauses up to {} s (seed {})",
                breathing.v_mid,
                breathing.amplitude_mm3,
                breathing.flow_mm3_s,
                breathing.pause_max_s,
                breathing.seed
            ),
            duration_s: end + 2.0,
            plant,
            commands,
            ..Self::default()
        }
    }

    /// The paper's characterisation protocol on SBA1 (Fig. 1c).
    pub fn paper_protocol() -> Self {
        Self::protocol("paper-protocol", PlantConfig::default(), &Protocol::paper())
    }

    /// The paper's protocol with an air pocket of `mm3` in every syringe (Sec. IV-A).
    pub fn air_pocket(mm3: f64) -> Self {
        let plant = PlantConfig {
            effects: Effects {
                air_pocket_mm3: [mm3; CHAMBERS],
                ..Effects::default()
            },
            ..PlantConfig::default()
        };
        Self::protocol(&format!("air-{mm3}mm3"), plant, &Protocol::paper())
    }

    /// The paper's protocol scaled to `design`'s envelope (Sec. IV-B, Table V): 0 to its max
    /// volume, at the paper's rates × c̄_SBA1/c̄_design (Table VI), which keeps the flow part of
    /// the pressure — and the suction when deflating — at SBA1's level (the paper does not state
    /// the rates it used for SBA2–SBA4). SBA4 (7000 mm³) runs 1 cycle per rate, the others 20.
    pub fn design(design: Design) -> Self {
        let plant = PlantConfig {
            design,
            ..PlantConfig::default()
        };
        Self::protocol(design.name(), plant, &Protocol::for_design(design, 1.0))
    }

    /// The paper's protocol with one effect preset switched on (`None` for an unknown name; see
    /// [`crate::plant::EFFECT_PRESETS`]).
    pub fn effect(name: &str) -> Option<Self> {
        let plant = PlantConfig {
            effects: Effects::preset(name)?,
            ..PlantConfig::default()
        };
        Some(Self::protocol(
            &format!("effect-{name}"),
            plant,
            &Protocol::paper(),
        ))
    }

    /// One hour of rig time for the benchmark: all three chambers cycling for 3600 s.
    /// `full_speed`: 250–550 mm³ at 100 mm³/s throughout (2500 steps/s per motor, the most step
    /// events); otherwise the paper's 0–550 mm³ at 20, 40 and 60 mm³/s in turn.
    pub fn rig_hour(full_speed: bool) -> Self {
        let protocol = if full_speed {
            Protocol {
                v_low: 250.0,
                cycles: 2000,
                dwell_ms: 0,
                flows: vec![100.0],
                ..Protocol::paper()
            }
        } else {
            Protocol {
                cycles: 40,
                flows: vec![20.0, 40.0, 60.0],
                ..Protocol::paper()
            }
        };
        Self {
            duration_s: 3600.0,
            stop_on: None,
            ..Self::protocol("rig-hour", PlantConfig::default(), &protocol)
        }
    }

    /// Force pushes as in the paper's Sec. IV-C: inflate to 500 mm³, then push the tip at 1 Hz
    /// for `seconds` with `peak_n`, from a known direction (azimuth 30°, tilt 60°).
    pub fn force_pushes(peak_n: f64, seconds: f64) -> Self {
        let settle = START_S + 500.0 / 50.0 + 3.0;
        Self {
            name: "force-pushes".into(),
            description: format!(
                "inflate to 500 mm³, push {peak_n} N at 1 Hz for {seconds} s (az 30°, tilt 60°)"
            ),
            duration_s: settle + seconds + 2.0,
            force: vec![ForcePush {
                start_s: settle,
                duration_s: seconds,
                frequency_hz: 1.0,
                peak_n,
                azimuth_deg: 30.0,
                tilt_deg: 60.0,
            }],
            commands: vec![TimedCommand::new(START_S, "move all 500 50")],
            ..Self::default()
        }
    }

    /// Parse a scenario file's text; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, crate::SimError> {
        toml::from_str(text).map_err(|e| crate::SimError::Scenario {
            origin: origin.to_string(),
            message: e.to_string(),
        })
    }

    /// Read and parse a scenario file.
    pub fn load(path: &std::path::Path) -> Result<Self, crate::SimError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|e| crate::SimError::Scenario {
            origin: origin.clone(),
            message: e.to_string(),
        })?;
        Self::from_toml(&text, &origin)
    }

    /// Check the parts that are not the plant's (the plant checks itself).
    pub fn validate(&self) -> Result<(), crate::SimError> {
        let bad = |message: String| {
            Err(crate::SimError::Scenario {
                origin: self.name.clone(),
                message,
            })
        };
        if !(self.duration_s.is_finite() && self.duration_s > 0.0 && self.duration_s < 1.0e6) {
            return bad(format!(
                "duration_s = {}: must be in (0, 1e6) s",
                self.duration_s
            ));
        }
        if !(self.tail_s.is_finite() && self.tail_s >= 0.0) {
            return bad(format!("tail_s = {}: must be ≥ 0", self.tail_s));
        }
        if !(1..=40_000).contains(&self.quantum_us) {
            return bad(format!(
                "quantum_us = {}: must be in 1..=40000",
                self.quantum_us
            ));
        }
        for (i, c) in self.commands.iter().enumerate() {
            if !(c.at_s.is_finite() && c.at_s >= 0.0) {
                return bad(format!("commands[{i}].at_s = {}: must be ≥ 0", c.at_s));
            }
            if c.line.contains(['\n', '\r']) {
                return bad(format!("commands[{i}].line holds a line break"));
            }
            if c.wire().is_none() {
                return bad(format!(
                    "commands[{i}].line cannot be checksummed: it holds a `*` or is longer than \
                     {} bytes (a line framed by hand is sent with framing = \"plain\")",
                    firmware::command::MAX_LINE - firmware::command::CHECKSUM_PREFIX
                ));
            }
        }
        for (i, f) in self.serial_faults.iter().enumerate() {
            let Some(c) = self.commands.get(f.command) else {
                return bad(format!(
                    "serial_faults[{i}].command = {}: no such command",
                    f.command
                ));
            };
            let sent = c.wire().map_or(0, |w| w.len());
            if f.byte > sent {
                return bad(format!(
                    "serial_faults[{i}].byte = {}: the line as sent has {sent} bytes and its \
                     terminator",
                    f.byte
                ));
            }
        }
        for (i, st) in self.telemetry_stalls.iter().enumerate() {
            if !(st.start_s.is_finite() && st.start_s >= 0.0 && st.duration_s.is_finite())
                || st.duration_s < 0.0
            {
                return bad(format!(
                    "telemetry_stalls[{i}]: start_s and duration_s must be ≥ 0"
                ));
            }
        }
        for (i, f) in self.faults.iter().enumerate() {
            if !(f.at_s.is_finite() && f.at_s >= 0.0) {
                return bad(format!("faults[{i}].at_s = {}: must be ≥ 0", f.at_s));
            }
            if f.unplug >= CHAMBERS {
                return bad(format!(
                    "faults[{i}].unplug = {}: sensors are 0..=2",
                    f.unplug
                ));
            }
        }
        Ok(())
    }
}
