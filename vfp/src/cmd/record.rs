//! `vfp record CAPTURE -o LOG.csv`: the firmware's telemetry text turned into an actuation log;
//! the conversion is [`sysid::record`].

use crate::Error;
use std::path::PathBuf;
use sysid::record::convert_file;

/// `vfp record`: convert a telemetry capture into an actuation log.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Telemetry capture: the output of `probe-rs run` (or raw `$F`/`$E` lines); `-` reads stdin.
    pub capture: PathBuf,
    /// Log file to write (CSV, docs/log-format.md).
    #[arg(short, long, value_name = "LOG.csv")]
    pub out: PathBuf,
    /// Exit with an error (after writing the log) when any frame is missing or any line is bad.
    #[arg(long)]
    pub strict: bool,
}

/// Runs `vfp record`.
pub fn run(args: &Args) -> Result<(), Error> {
    let rec = convert_file(&args.capture)?;
    sysid::log::write_log(&args.out, &rec.log)?;
    eprint!("{}", rec.summary(&args.capture.display().to_string()));
    println!("wrote {}", args.out.display());
    if args.strict && !rec.is_complete() {
        return Err(Error::Msg(format!(
            "{}: {} frames missing, {} corrupted lines, {} rejected frames (--strict); the log was written anyway",
            args.capture.display(),
            rec.missing_frames(),
            rec.corrupted.len(),
            rec.rejected.len()
        )));
    }
    Ok(())
}
