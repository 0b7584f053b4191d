//! The simulated rig: a physical plant and a board that runs the firmware's own tasks.
//!
//! ```text
//! scenario ──► commands ──► SimSerial ─┐
//!                                      ▼
//!         firmware::app::{command_task, stepper_task, sampler_task}   (the device's code)
//!               │ STEP/DIR (planned µs)          ▲ ADC counts           │ telemetry lines
//!               ▼                                │                      ▼
//!         plant: motor → backlash → plunger → delivery lag → air pocket → chamber law
//!                + force on the tip, sensor lag/drift/noise → firmware::board::kpa_to_counts
//! ```
//!
//! # Boundary of the simulation
//! Simulated: the physics from motor step to ADC count — plunger motion (backlash, screw pitch
//! error), delivery of the step train as a flow, an air pocket, a leak, fluid inertance, the
//! chamber's volume-flow-pressure law (paper Table IV, designs of Table V), rate-independent
//! hysteresis, an external force on the tip, and the sensor (lag, offset, thermal drift, noise,
//! 12-bit quantisation through the firmware's own transfer function). Run unchanged: the
//! firmware's application — its three tasks, motion planner, protocol, safety checks, estimator,
//! command parser and telemetry encoder — under embassy-time's mock driver in virtual time.
//! Not simulated: the Embassy HAL and the `vfp-fw` binary's wiring (GPIO, ADC and UART drivers,
//! interrupt priorities, DMA, RTT/defmt transport), real-time execution cost (every task runs in
//! zero virtual time, so CPU overload and interrupt latency cannot show), electrical faults other
//! than an unplugged sensor, the watchdog's reset itself (only its feed gaps are reported), and
//! any mechanics of the balloon beyond the lumped law (no bending, no tip position).
//!
//! # Use
//! ```no_run
//! use host_sim::{simulate, Scenario};
//! let run = simulate(&Scenario::paper_protocol()).expect("valid scenario");
//! let mut log = Vec::new();
//! run.write_log(&mut log).expect("in memory");
//! ```
#![forbid(unsafe_code)]

pub mod board;
pub mod breath_logs;
pub mod law;
pub mod plant;
pub mod rigs;
pub mod scenario;
pub mod sim;

pub use board::FrameTruth;
pub use law::Design;
pub use plant::{
    ChamberTruth, Effects, ForcePush, NoiseTails, PlantConfig, SensorSpec, EFFECT_PRESETS,
};
pub use scenario::{
    Breathing, FaultInjection, Framing, PresetOptions, Protocol, Scenario, SerialFault,
    SerialFaultKind, Strokes, TelemetryStall, TimedCommand,
};
pub use sim::{simulate, simulate_with, LogRow, RunStats, SimRun, LOG_COLUMNS};

/// Why a simulation could not run.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A scenario file or field is invalid.
    #[error("scenario {origin}: {message}")]
    Scenario {
        /// File path or scenario name.
        origin: String,
        /// What is wrong.
        message: String,
    },
    /// A plant parameter is out of range.
    #[error(transparent)]
    Plant(#[from] plant::ParamError),
    /// A firmware task returned (they loop forever on the device).
    #[error("a firmware task ended")]
    TaskEnded,
    /// The simulator's own bookkeeping failed (a bug, reported rather than panicking).
    #[error("simulator: {0}")]
    Internal(String),
}
