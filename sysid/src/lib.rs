//! System identification and analyses on actuation logs: the library behind the `vfp` tool (the
//! `vfp` crate), usable on its own. No command-line, plotting or serial dependencies: every
//! analysis returns a typed report (serde `Serialize`) that the tool renders and that tests and
//! other programs use.
//!
//! Two halves. The analysis: [`log`] (read/write the CSV log format, `docs/log-format.md`) →
//! [`dataset`] (per-chamber v, v̇, v̈, P, cycles, training / held-out split;
//! [`dataset::LogData::read`] is the one way from a log file to datasets) → model families
//! ([`poly`], [`polyar`], [`exp`], [`nn`]) → [`metrics`] (RMSE, R²adj, AICc, BIC, joint cost) →
//! [`identify`] (the paper's §II–III in one call); [`residual`] traces a model's residual to
//! physical effects; [`diag`] holds the paper's §IV analyses. It needs no `firmware` crate. The
//! board-facing half, [`board`] (the `board` feature, on by default): the firmware's telemetry
//! turned into logs (capture, packets, sequence, record), the models turned into the device's
//! coefficients and effects (both exports), sent to it (deploy) and run by its own estimator
//! (replay, the board side of `vfp force`).

#[cfg(feature = "board")]
pub mod board;
pub mod columns;
pub mod cycles;
pub mod dataset;
pub mod diag;
pub mod exp;
pub mod identify;
pub mod linreg;
pub mod log;
pub mod metrics;
pub mod nn;
mod par;
pub mod poly;
pub mod polyar;
pub mod progress;
pub mod residual;
pub mod select;
pub mod synth;
#[cfg(test)]
mod test_motion;
