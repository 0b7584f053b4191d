//! System identification and analyses on actuation logs, and the library behind the `vfp` tool.
//!
//! Data flow: [`log`] (read/write the CSV log format) → [`dataset`] (per-chamber v, v̇, v̈, P,
//! cycles, training / held-out split) → model families ([`poly`], [`polyar`], [`exp`], [`nn`])
//! → [`metrics`] (RMSE, R²adj, AICc, BIC, joint cost) → [`identify`] (the paper's §II–III in one
//! call) → [`cli::export`] (coefficients for the device).

pub mod cli;
pub mod dataset;
pub mod demo;
pub mod deploy;
pub mod diag;
pub mod exp;
pub mod figure;
pub mod identify;
pub mod linreg;
pub mod log;
pub mod metrics;
pub mod nn;
pub mod poly;
pub mod polyar;
pub mod record;
pub mod residual;
pub mod synth;
