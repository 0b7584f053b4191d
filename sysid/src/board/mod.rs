//! The board-facing half: everything that speaks the firmware's formats or runs its code
//! (behind the `board` feature, the only thing that pulls the `firmware` crate into `sysid`).
//!
//! From the board to the analysis: [`capture`] reads the telemetry text one line at a time,
//! [`packets`] the binary stream of the board's serial port (from any `Read`), [`sequence`]
//! places each frame (gaps, reboots, drops) for every reader, and [`record`] turns either into an
//! actuation log. From the analysis back to the board: [`export`] (a polynomial's coefficients as
//! the device's command lines) and [`augmented`] (the residual loop's model in the board's form,
//! `vfp export --augmented`), [`deploy`] (the firmware's command protocol over any
//! `Read + Write`), [`replay`] (the firmware's own estimator over a log) and [`force`] (`vfp force
//! --augmented`: the force the board would estimate with the loop's models).
//!
//! The analysis half (the log, datasets, model families, the residual loop, the §IV diagnostics)
//! imports nothing from here and builds without the `firmware` crate
//! (`cargo build -p sysid --no-default-features`); the frame's status bits it reads are
//! `model_core::flags`.

pub mod augmented;
pub mod capture;
pub mod deploy;
pub mod export;
pub mod force;
pub mod packets;
pub mod record;
pub mod replay;
pub mod sequence;
