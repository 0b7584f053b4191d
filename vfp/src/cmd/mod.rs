//! The subcommands: each module has its `clap::Args` struct and `run(&Args) -> Result<(), Error>`;
//! `main.rs` only dispatches, so a new subcommand is a module here plus one enum line there.

pub mod air_scan;
pub mod bench_loop;
pub mod chow;
pub mod demo;
pub mod deploy;
pub mod diagnose;
pub mod export;
pub mod force;
pub mod identify;
pub mod monitor;
pub mod record;
pub mod replay;
pub mod simulate;
pub mod stiffness;
