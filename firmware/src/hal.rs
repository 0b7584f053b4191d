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
    /// Emit STEP pulses on every axis in `axes` (bit `a` = axis `a`), all planned for `at`, back
    /// to back. The default pulses them one after the other; the board raises all of them
    /// together so they land within a few cycles of each other.
    fn step_axes(&mut self, axes: u8, at: Instant) {
        for a in 0..AXES {
            if axes & (1 << a) != 0 {
                self.step(a, at);
            }
        }
    }
    /// Enable or disable all drivers (disabled drivers hold no torque).
    fn set_enabled(&mut self, enabled: bool);
}

/// The three pressure-sensor ADC channels.
pub trait PressureAdc {
    /// One conversion of all channels, raw counts (12-bit right aligned).
    async fn read(&mut self) -> [u16; AXES];
}

/// A receive error of the serial port: some bytes were lost or are wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum SerialError {
    /// A stop bit was not where it should be.
    Framing,
    /// A byte arrived before the previous one was taken (the receive buffer overflowed).
    Overrun,
    /// Noise on the line while a byte was sampled.
    Noise,
    /// Wrong parity.
    Parity,
}

/// The command serial port (ST-LINK virtual COM port on the Nucleo).
pub trait SerialPort {
    /// Read at least one byte into `buf`, returning how many were read, or report a receive
    /// error (the bytes around it may be lost: the line being received is corrupt).
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, SerialError>;
    /// Write all of `data`.
    async fn write_all(&mut self, data: &[u8]);
}

/// Where telemetry lines go (an RTT up-channel on the board, a buffer in the simulator).
pub trait TelemetrySink {
    /// Hand over one complete line (ending in `\n`) whole, now, or not at all: `false` when the
    /// transport cannot take it at once (the host is not reading). Never waits.
    fn try_send(&mut self, line: &str) -> bool;
}

/// The independent watchdog.
pub trait Watchdog {
    /// Reload the watchdog counter.
    fn feed(&mut self);
}
