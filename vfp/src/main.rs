//! `vfp`: the host command-line tool. Wiring only: each subcommand's arguments and `run` live in
//! `vfp::cmd::*`; add one by writing its module and one line in each list below.

use clap::{Parser, Subcommand};
use std::process::ExitCode;
use vfp::cmd;

/// One malloc arena for every thread (glibc): the threads of a long search free large designs
/// that another thread allocates next, which per-thread arenas would each keep (vfp/Cargo.toml).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn one_malloc_arena() {
    // SAFETY: `mallopt` sets one of the allocator's parameters and touches no memory of ours;
    // it runs first in `main`, before any other thread exists.
    unsafe {
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
}

/// Volume-flow-pressure identification and analyses for hydraulic soft actuators.
#[derive(Parser)]
#[command(name = "vfp", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
    /// No progress on stderr (bars and stage lines); results and errors are still printed.
    #[arg(long, short, global = true)]
    quiet: bool,
}

#[derive(Subcommand)]
enum Command {
    /// The whole loop on the simulated rig: simulate, record, identify, diagnose, deploy, force pushes, report.
    Demo(cmd::demo::Args),
    /// Identify models from a log: Tables I, II and IV of the paper (every model family).
    Identify(cmd::identify::Args),
    /// Export identified models for the device (serial command lines, Rust constants).
    Export(cmd::export::Args),
    /// Run the firmware's own tasks on the simulated rig and write the log it reports.
    Simulate(cmd::simulate::Args),
    /// Pointwise stiffness k = ∂P/∂v and damping c = ∂P/∂v̇ of the identified polynomial (§IV-A, Fig. 7).
    Stiffness(cmd::stiffness::Args),
    /// Stiffness and damping across logs, e.g. air pockets of growing volume (§IV-A, Fig. 7c–d).
    AirScan(cmd::air_scan::Args),
    /// Chow test between logs with a common polynomial shape (§IV-B, Table VI).
    Chow(cmd::chow::Args),
    /// External force from pressure residuals, identified on a force-free log (§IV-C, Fig. 8).
    Force(cmd::force::Args),
    /// Trace a model's residual to physical effects it lacks, add them, report the error before and after.
    Diagnose(cmd::diagnose::Args),
    /// Convert the firmware's telemetry (probe-rs output) into an actuation log.
    Record(cmd::record::Args),
    /// Live terminal view of the board's telemetry (probe-rs output on stdin or a file), recording it.
    Monitor(cmd::monitor::Args),
    /// The residual loop judged on random simulated rigs: confusion matrix, precision, recall by effect size, CPU.
    BenchLoop(cmd::bench_loop::Args),
    /// Send a model to a board over its serial port and read it back.
    Deploy(cmd::deploy::Args),
    /// What the board would have estimated on a log: the firmware's estimator over its frames with an exported model.
    Replay(cmd::replay::Args),
}

fn main() -> ExitCode {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    one_malloc_arena();
    let cli = Cli::parse();
    vfp::progress::set_quiet(cli.quiet);
    let result = match &cli.command {
        Command::Demo(a) => cmd::demo::run(a),
        Command::Identify(a) => cmd::identify::run(a),
        Command::Export(a) => cmd::export::run(a),
        Command::Simulate(a) => cmd::simulate::run(a),
        Command::Stiffness(a) => cmd::stiffness::run(a),
        Command::AirScan(a) => cmd::air_scan::run(a),
        Command::Chow(a) => cmd::chow::run(a),
        Command::Force(a) => cmd::force::run(a),
        Command::Diagnose(a) => cmd::diagnose::run(a),
        Command::Record(a) => cmd::record::run(a),
        Command::Monitor(a) => cmd::monitor::run(a),
        Command::BenchLoop(a) => cmd::bench_loop::run(a),
        Command::Deploy(a) => cmd::deploy::run(a),
        Command::Replay(a) => cmd::replay::run(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vfp: {e}");
            ExitCode::FAILURE
        }
    }
}
