//! The board's serial port as a telemetry source (`vfp record --port`, `vfp monitor --port`):
//! opened, the binary stream switched on with the firmware's `telemetry on` command, its bytes
//! read as they come (`sysid::board::packets` decodes them), and the stream switched off again when
//! the reader is done. Both commands go checksummed ([`framed`]), as the firmware requires.

use std::io::{Read, Write};
use std::time::Duration;

use serialport::SerialPort;

use crate::Error;

/// The firmware's UART rate.
pub const DEFAULT_BAUD: u32 = 115_200;

/// How long one read waits before it looks again (a read never ends the stream by itself).
const POLL: Duration = Duration::from_millis(200);

/// The reading half: blocks until bytes arrive (a quiet line is not the end of input).
pub struct PortReader(Box<dyn SerialPort>);

impl Read for PortReader {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        loop {
            match self.0.read(buf) {
                Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
                r => return r,
            }
        }
    }
}

/// `command` as a line the firmware accepts from boot: `*LLCC <command>\n`, its length and CRC-8
/// in front (`firmware::command::write_checksummed`), so a byte damaged on the wire gets the
/// line refused, never executed. `command` is one of this module's constants.
fn framed(command: &str) -> Vec<u8> {
    let mut line = String::with_capacity(command.len() + 8);
    firmware::command::write_checksummed(command, &mut line)
        .expect("a short command without `*` or line breaks");
    line.push('\n');
    line.into_bytes()
}

/// The writing half: switches the stream off when dropped.
pub struct StreamSwitch {
    port: Box<dyn SerialPort>,
    name: String,
}

impl Drop for StreamSwitch {
    fn drop(&mut self) {
        // Best effort: the board may be gone; its stream is off at its next boot anyway.
        let _ = self.port.write_all(&framed("telemetry off"));
        let _ = self.port.flush();
    }
}

impl StreamSwitch {
    /// The port's name.
    pub fn name(&self) -> &str {
        &self.name
    }
}

/// Opens `dev` at `baud` and switches the board's binary telemetry on.
pub fn open(dev: &str, baud: u32) -> Result<(PortReader, StreamSwitch), Error> {
    let err =
        |e: &dyn std::fmt::Display| Error::Msg(format!("{dev}: cannot open the serial port: {e}"));
    let mut port = serialport::new(dev, baud)
        .timeout(POLL)
        .open()
        .map_err(|e| err(&e))?;
    port.write_all(&framed("telemetry on"))
        .and_then(|()| port.flush())
        .map_err(|e| Error::Msg(format!("{dev}: cannot send `telemetry on`: {e}")))?;
    let reader = port.try_clone().map_err(|e| err(&e))?;
    Ok((
        PortReader(reader),
        StreamSwitch {
            port,
            name: dev.to_string(),
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::framed;
    use std::io::{BufRead, BufReader, Write};

    /// The lines this module sends switch the stream of the firmware's own command handler,
    /// freshly booted (checksums required), on and off.
    #[test]
    fn the_stream_switches_are_accepted_by_a_freshly_booted_firmware() {
        let mut board = sysid::board::deploy::FirmwarePort::new();
        for (line, want) in [
            (framed("telemetry on"), "ok"),
            (framed("telemetry"), "ok on"),
            (framed("telemetry off"), "ok"),
            (framed("telemetry"), "ok off"),
            (b"telemetry on\n".to_vec(), "err checksum-required"),
            (framed("telemetry"), "ok off"),
        ] {
            board.write_all(&line).unwrap();
            let mut reply = String::new();
            BufReader::new(&mut board).read_line(&mut reply).unwrap();
            assert_eq!(reply.trim_end(), want, "{}", String::from_utf8_lossy(&line));
        }
    }
}
