//! `fw-bench`: instruction counts of the firmware library on an emulated Cortex-M4.
//!
//! One binary, two builds (the same trick as `firmware/src/bin/vfp-fw.rs`):
//! - for `thumbv7em-none-eabihf` ([`device`]) it is the bench program: it runs the firmware
//!   library's own code (steps, conversions, frames, telemetry, commands) in a scripted run and
//!   brackets each measured operation with calls to marker functions;
//! - on the host ([`host`]) it is the runner behind `cargo fw-bench`: it builds the device side at
//!   the firmware's profile, runs it under `qemu-system-arm` with a one-line-per-instruction
//!   execution trace streamed through a FIFO, and counts the instructions between the markers and
//!   inside every interrupts-disabled window.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod device;

#[cfg(not(target_os = "none"))]
mod host;

#[cfg(not(target_os = "none"))]
fn main() -> std::process::ExitCode {
    host::main()
}
