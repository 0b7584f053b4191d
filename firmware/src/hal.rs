//! The hardware boundary: what the application needs from a board.
//!
//! The Embassy binary implements these traits on the STM32; `host-sim` implements them on a
//! simulated plant. Nothing above this module knows which one it runs on.
#![allow(async_fn_in_trait)]

use embassy_time::Instant;

/// Number of actuation channels (syringe pump + pressure sensor + balloon chamber).
pub const AXES: usize = 3;

/// Direction of plunger travel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum Direction {
    /// Plunger pushes water into the chamber (volume rises).
    Inflate,
    /// Plunger withdraws water (volume falls).
    Deflate,
}

/// Step/dir outputs of the three stepper drivers.
pub trait Steppers {
    /// Set the DIR line of `axis`; the caller waits the driver's set-up time before the next step.
    fn set_direction(&mut self, axis: usize, dir: Direction);
    /// Emit one STEP pulse on `axis`. `at` is the instant the motion plan scheduled it for: real
    /// hardware pulses now (the caller already waited until `at`), the simulator uses `at` exactly.
    fn step(&mut self, axis: usize, at: Instant);
    /// Enable or disable all drivers (disabled drivers hold no torque).
    fn set_enabled(&mut self, enabled: bool);
}

/// The three pressure-sensor ADC channels.
pub trait PressureAdc {
    /// One conversion of all channels, raw counts (12-bit right aligned).
    async fn read(&mut self) -> [u16; AXES];
}

/// The command serial port (ST-LINK virtual COM port on the Nucleo).
pub trait SerialPort {
    /// Read at least one byte into `buf`, returning how many were read.
    async fn read(&mut self, buf: &mut [u8]) -> usize;
    /// Write all of `data`.
    async fn write_all(&mut self, data: &[u8]);
}

/// Where telemetry lines go (defmt-RTT on the board, a buffer in the simulator).
pub trait TelemetrySink {
    /// One complete telemetry or event line, without a line terminator.
    fn line(&mut self, line: &str);
}

/// The independent watchdog.
pub trait Watchdog {
    /// Reload the watchdog counter.
    fn feed(&mut self);
}
