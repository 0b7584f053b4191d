//! `vfp deploy LINES --port /dev/ttyACM0`: load a model into a board over its serial port and read
//! it back; the protocol is [`sysid::board::deploy`].

use crate::Error;
use std::io::Read;
use std::path::PathBuf;
use std::time::Duration;
use sysid::board::deploy::{deploy, parse_lines, Readback};

/// `vfp deploy`: send a model to a board and read it back.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Model lines as printed by `vfp export --format lines` (`-` reads stdin).
    pub lines: PathBuf,
    /// Serial port of the board (e.g. /dev/ttyACM0, COM3).
    #[arg(long)]
    pub port: String,
    /// Baud rate (the firmware's UART runs at 115200).
    #[arg(long, default_value_t = 115_200)]
    pub baud: u32,
    /// Seconds to wait for each reply.
    #[arg(long, default_value_t = 2.0)]
    pub timeout_s: f64,
}

/// Runs `vfp deploy`.
pub fn run(args: &Args) -> Result<(), Error> {
    let name = args.lines.display().to_string();
    let text = if name == "-" {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .map_err(|e| Error::Msg(format!("<stdin>: {e}")))?;
        s
    } else {
        std::fs::read_to_string(&args.lines).map_err(|e| Error::Msg(format!("{name}: {e}")))?
    };
    let uploads = parse_lines(&text, &name)?;
    if !(args.timeout_s.is_finite() && args.timeout_s > 0.0) {
        return Err(Error::Msg(format!(
            "--timeout-s {}: must be a positive number of seconds",
            args.timeout_s
        )));
    }
    let mut port = serialport::new(&args.port, args.baud)
        .timeout(Duration::from_secs_f64(args.timeout_s))
        .open()
        .map_err(|e| Error::Msg(format!("{}: cannot open the serial port: {e}", args.port)))?;
    let results =
        deploy(&mut port, &uploads).map_err(|e| Error::Msg(format!("{}: {e}", args.port)))?;
    for r in &results {
        match &r.readback {
            Readback::Verified { values } => {
                println!("channel {}: {} lines acknowledged, {values} values read back and identical", r.ch, r.lines_acked)
            }
            Readback::Unsupported { reply } => println!(
                "channel {}: {} lines acknowledged; not read back: this firmware answers `model {} read` with `{reply}`, \
                 so the model is confirmed by the acknowledgements only",
                r.ch, r.lines_acked, r.ch
            ),
        }
    }
    Ok(())
}
