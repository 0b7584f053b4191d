//! Hardware-independent actuation firmware: everything here builds for the host and is tested there.
//!
//! - [`app`]: shared state ([`app::Shared`], [`app::Config`]) and the task entry points
//!   [`app::stepper_task`], [`app::sampler_task`], [`app::command_task`], [`app::persist_task`].
//! - [`motion`]: trapezoidal profiles → step instants; [`protocol`]: the characterisation cycles.
//! - [`command`]: the serial line protocol; [`telemetry`]: frame and event lines; [`wire`]: the
//!   same frames and events as binary packets over the command UART.
//! - [`board`]: pin map and pressure-sensor transfer function; [`hal`]: the hardware traits.
//! - [`reset`]: why the board reset (reset flags + the crash record); [`store`]: the committed
//!   models in flash; [`rest_zero`]: the zero's slow drift corrected at rest.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
// Channel loops index several parallel per-channel arrays at once.
#![allow(clippy::needless_range_loop)]

pub mod app;
pub mod board;
pub mod command;
pub mod hal;
pub mod motion;
pub mod protocol;
pub mod reset;
pub mod rest_zero;
pub mod store;
pub mod telemetry;
pub mod wire;
