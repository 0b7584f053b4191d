//! `vfp`: the host command-line tool. Wiring only: each subcommand's arguments and `run` live in
//! the library (`sysid::cli::*`); add one by writing its module and one line in each list below.

use clap::{Parser, Subcommand};
use std::process::ExitCode;

/// Volume-flow-pressure identification and analyses for hydraulic soft actuators.
#[derive(Parser)]
#[command(name = "vfp", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// The whole loop on the simulated rig: simulate, record, identify, diagnose, deploy, force pushes, report.
    Demo(sysid::demo::DemoArgs),
    /// Identify models from a log: Tables I, II and IV of the paper (every model family).
    Identify(sysid::cli::identify::Args),
    /// Export identified models for the device (serial command lines, Rust constants).
    Export(sysid::cli::export::Args),
    /// Run the firmware's own tasks on the simulated rig and write the log it reports.
    Simulate(sysid::cli::simulate::Args),
    /// Pointwise stiffness k = ∂P/∂v and damping c = ∂P/∂v̇ of the identified polynomial (§IV-A, Fig. 7).
    Stiffness(sysid::diag::stiffness::StiffnessArgs),
    /// Stiffness and damping across logs, e.g. air pockets of growing volume (§IV-A, Fig. 7c–d).
    AirScan(sysid::diag::air_scan::AirScanArgs),
    /// Chow test between logs with a common polynomial shape (§IV-B, Table VI).
    Chow(sysid::diag::chow::ChowArgs),
    /// External force from pressure residuals, identified on a force-free log (§IV-C, Fig. 8).
    Force(sysid::diag::force::ForceArgs),
    /// Trace a model's residual to physical effects it lacks, add them, report the error before and after.
    Diagnose(sysid::residual::cli::DiagnoseArgs),
    /// Convert the firmware's telemetry (probe-rs output) into an actuation log.
    Record(sysid::record::RecordArgs),
    /// Send a model to a board over its serial port and read it back.
    Deploy(sysid::deploy::DeployArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result: Result<(), String> = match &cli.command {
        Command::Demo(a) => sysid::demo::run(a).map_err(|e| e.to_string()),
        Command::Identify(a) => sysid::cli::identify::run(a).map_err(|e| e.to_string()),
        Command::Export(a) => sysid::cli::export::run(a).map_err(|e| e.to_string()),
        Command::Simulate(a) => sysid::cli::simulate::run(a).map_err(|e| e.to_string()),
        Command::Stiffness(a) => sysid::diag::stiffness::run(a).map_err(|e| e.to_string()),
        Command::AirScan(a) => sysid::diag::air_scan::run(a).map_err(|e| e.to_string()),
        Command::Chow(a) => sysid::diag::chow::run(a).map_err(|e| e.to_string()),
        Command::Force(a) => sysid::diag::force::run(a).map_err(|e| e.to_string()),
        Command::Diagnose(a) => sysid::residual::cli::run(a).map_err(|e| e.to_string()),
        Command::Record(a) => sysid::record::run(a).map_err(|e| e.to_string()),
        Command::Deploy(a) => sysid::deploy::run(a).map_err(|e| e.to_string()),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("vfp: {e}");
            ExitCode::FAILURE
        }
    }
}
