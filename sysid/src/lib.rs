//! System identification and analyses on actuation logs: the library behind the `vfp` tool (the
//! `vfp` crate), usable on its own. No command-line, plotting or serial dependencies: every
//! analysis returns a typed report (serde `Serialize`) that the tool renders and that tests and
//! other programs use.
//!
//! Data flow: [`log`] (read/write the CSV log format, `docs/log-format.md`) → [`dataset`] (per-chamber
//! v, v̇, v̈, P, cycles, training / held-out split; [`dataset::LogData::read`] is the one way from a
//! log file to datasets) → model families ([`poly`], [`polyar`], [`exp`], [`nn`]) → [`metrics`]
//! (RMSE, R²adj, AICc, BIC, joint cost) → [`identify`] (the paper's §II–III in one call) →
//! [`export`] (coefficients for the device) → [`deploy`] (the firmware's command protocol over any
//! `Read + Write`). [`residual`] traces a model's residual to physical effects; [`diag`] holds the
//! paper's §IV analyses; [`record`] turns the firmware's telemetry into a log, [`capture`] reads it
//! one line at a time, [`packets`] reads the binary stream of the board's serial port (from any
//! `Read`), and [`sequence`] places each frame (gaps, reboots, drops) for every reader.

pub mod capture;
pub mod columns;
pub mod cycles;
pub mod dataset;
pub mod deploy;
pub mod diag;
pub mod exp;
pub mod export;
pub mod identify;
pub mod linreg;
pub mod log;
pub mod metrics;
pub mod nn;
pub mod packets;
mod par;
pub mod poly;
pub mod polyar;
pub mod progress;
pub mod record;
pub mod replay;
pub mod residual;
pub mod select;
pub mod sequence;
pub mod synth;
