//! The `vfp` command-line tool on top of the [`sysid`] library: one module per subcommand
//! ([`cmd`]), the options they share ([`opts`]), one error type ([`Error`]) and the figures
//! ([`plots`], [`figure`]) in the units of [`units`]. The numbers come from `sysid`; this crate parses arguments, reads
//! files, renders reports and draws.

pub mod cmd;
pub mod error;
pub mod figure;
pub mod loop_bench;
pub mod opts;
pub mod plots;
pub mod port;
pub mod progress;
pub mod units;

pub use error::Error;
