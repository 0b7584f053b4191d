//! `vfp simulate`: run the firmware's own tasks against the simulated plant (`host-sim`) and
//! write what the device reported as an actuation log (`docs/log-format.md`), with the
//! simulator's truth (`force_n`, true chamber volume, flow and pressure) in extra columns.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::time::Instant;

use host_sim::plant::Drive;
use host_sim::{simulate, PresetOptions, Scenario};

use crate::Error;

/// Arguments of `vfp simulate`.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// What to run: `paper` (the paper's protocol on SBA1), `air:MM3` (an air pocket of MM3 in
    /// every syringe), `design:sba1|sba2|sba3|sba4`, `effect:NAME` (one plant effect: air,
    /// hysteresis, sensor-lag, inertance, thermal-drift, backlash, ripple, leak, transport-delay,
    /// volume-creep), `force` (1 Hz pushes at 500 mm³, with truth).
    #[arg(long, default_value = "paper", conflicts_with = "scenario")]
    pub preset: String,
    /// A scenario file (TOML; vocabulary in `host-sim/src/scenario.rs`) instead of a preset.
    #[arg(long, value_name = "FILE")]
    pub scenario: Option<PathBuf>,
    /// Cycles per flow rate (protocol presets; the paper runs ≥ 20).
    #[arg(long)]
    pub cycles: Option<u16>,
    /// Flow rates, mm³/s, comma separated (protocol presets; the paper: 20,40,60,80,100).
    #[arg(long, value_delimiter = ',')]
    pub flows: Option<Vec<f64>>,
    /// Peak push force, N (`force` preset).
    #[arg(long, default_value_t = 0.5)]
    pub force_peak_n: f64,
    /// Seconds of pushing (`force` preset).
    #[arg(long, default_value_t = 20.0)]
    pub force_seconds: f64,
    /// Seed of the sensor noise (the same seed gives the same log byte for byte).
    #[arg(long)]
    pub seed: Option<u64>,
    /// How steps become delivered volume: `lagged` (the default rig: a critically damped 3 ms
    /// delivery lag between the commanded and the delivered water) or `ideal` (a servo that
    /// delivers exactly the commanded profile, so only the sensor deviates from the law).
    /// Default: the preset's or scenario file's.
    #[arg(long, value_enum)]
    pub drive: Option<DriveArg>,
    /// Where to write the log.
    #[arg(long, short, value_name = "LOG.csv")]
    pub out: PathBuf,
}

/// `--drive` values (host-sim's [`Drive`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DriveArg {
    /// Delivery through the plant's second-order lag.
    Lagged,
    /// Exactly the commanded profile.
    Ideal,
}

/// Builds the scenario the arguments describe.
pub fn scenario(args: &Args) -> Result<Scenario, Error> {
    let mut sc = match &args.scenario {
        Some(path) => Scenario::load(path).map_err(|e| Error::Msg(e.to_string()))?,
        None => preset(args)?,
    };
    if let Some(seed) = args.seed {
        sc.seed = seed;
    }
    if let Some(d) = args.drive {
        sc.plant.drive = match d {
            DriveArg::Lagged => Drive::Lagged,
            DriveArg::Ideal => Drive::Ideal,
        };
    }
    sc.validate().map_err(|e| Error::Msg(e.to_string()))?;
    Ok(sc)
}

fn preset(args: &Args) -> Result<Scenario, Error> {
    let opts = PresetOptions {
        cycles: args.cycles,
        flows: args.flows.clone(),
        force_peak_n: args.force_peak_n,
        force_seconds: args.force_seconds,
    };
    Scenario::preset(&args.preset, &opts).map_err(Error::Msg)
}

/// Runs `vfp simulate`.
pub fn run(args: &Args) -> Result<(), Error> {
    let sc = scenario(args)?;
    eprintln!("simulating {}: {}", sc.name, sc.description);
    let started = Instant::now();
    let sim = simulate(&sc).map_err(|e| Error::Msg(format!("simulation failed: {e}")))?;
    let wall = started.elapsed().as_secs_f64();
    let file = File::create(&args.out)
        .map_err(|e| Error::Msg(format!("cannot create {}: {e}", args.out.display())))?;
    let mut w = BufWriter::new(file);
    sim.write_log(&mut w)
        .and_then(|()| w.flush())
        .map_err(|e| Error::Msg(format!("cannot write {}: {e}", args.out.display())))?;
    let rig_s = sim
        .frames
        .last()
        .zip(sim.frames.first())
        .map_or(0.0, |(l, f)| (l.t_us - f.t_us) as f64 * 1e-6);
    let steps: u64 = sim.step_count.iter().sum();
    eprintln!(
        "wrote {}: {} frames ({:.0} s of rig time, {} steps) simulated in {:.2} s",
        args.out.display(),
        sim.frames.len(),
        rig_s,
        steps,
        wall
    );
    if let Some(f) = sim.first_event("fault") {
        eprintln!("note: the firmware latched a fault during the run: {f:?}");
    }
    Ok(())
}
