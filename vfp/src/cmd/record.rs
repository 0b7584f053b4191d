//! `vfp record CAPTURE -o LOG.csv`: the firmware's telemetry text turned into an actuation log
//! as it arrives; the conversion is [`sysid::board::record::Recorder`].
//!
//! A reader thread reads the capture line by line and a signal thread waits for SIGINT, SIGTERM
//! or SIGHUP; both hand their news to this thread through one channel, in order. Every line read
//! is converted and written before a signal that came after it is acted on, and the log is flushed
//! whenever no line is waiting, so the file always holds whole rows of what was received. End of
//! input (including a closed pipe) and the first signal end the log the same way: the totals are
//! appended, the summary printed, exit status 0. A second signal ends the process at once.
//!
//! With `--port DEV` the source is the board's serial port instead: the binary stream is switched
//! on (`telemetry on`), its packets decoded by [`sysid::board::packets`] into the same items a text
//! capture gives, and switched off again when recording stops.

use crate::Error;
use std::io::{BufRead, BufReader, Read, Write};
use std::path::PathBuf;
use std::sync::mpsc::{sync_channel, Receiver, SyncSender, TryRecvError};
use sysid::board::capture::CaptureLine;
use sysid::board::record::{Recorder, Recording};

/// `vfp record`: convert a telemetry capture into an actuation log.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Telemetry capture: the output of `probe-rs run` (or raw `$F`/`$E` lines); `-` reads stdin
    /// (e.g. `cargo fw-run | vfp record - -o LOG.csv`, ended by Ctrl-C). Not with `--port`.
    #[arg(required_unless_present = "port", conflicts_with = "port")]
    pub capture: Option<PathBuf>,
    /// Read the board's serial port instead of a probe's capture (e.g. /dev/ttyACM0, COM3):
    /// switches its binary telemetry on and records it (no debug probe needed).
    #[arg(long, value_name = "DEV")]
    pub port: Option<String>,
    /// CAPTURE holds the board's binary serial stream (bytes as the port gave them, e.g. the
    /// `LOG.capture.bin` that `vfp monitor --port -o LOG.csv` keeps), not text.
    #[arg(long, conflicts_with = "port")]
    pub binary: bool,
    /// Baud rate of `--port` (the firmware's UART runs at 115200).
    #[arg(long, default_value_t = crate::port::DEFAULT_BAUD, requires = "port")]
    pub baud: u32,
    /// Log file to write (CSV, docs/log-format.md). Rows are written as frames arrive; on end of
    /// input, Ctrl-C (SIGINT), SIGTERM or SIGHUP the log is completed and the summary printed.
    #[arg(short, long, value_name = "LOG.csv")]
    pub out: PathBuf,
    /// Exit with an error (after writing the log) when any frame is missing or any line is bad.
    #[arg(long)]
    pub strict: bool,
}

/// What the reader and signal threads report.
enum Msg {
    Line(Vec<u8>),
    Item(CaptureLine<'static>),
    End,
    ReadError(std::io::Error),
    Signal(&'static str),
}

/// Lines in flight between the reader and the writer (back-pressure beyond that).
const QUEUE: usize = 1024;

/// Runs `vfp record`.
pub fn run(args: &Args) -> Result<(), Error> {
    let (tx, rx) = sync_channel(QUEUE);
    let (source, switch) = match (&args.port, &args.capture) {
        (Some(dev), _) => {
            let (reader, switch) = crate::port::open(dev, args.baud)?;
            let tx = tx.clone();
            std::thread::spawn(move || read_packets(reader, &tx));
            (format!("{dev} (binary telemetry)"), Some(switch))
        }
        (None, Some(capture)) => {
            let stdin = capture.as_os_str() == "-";
            let source = match stdin {
                true => "<stdin>".to_string(),
                false => capture.display().to_string(),
            };
            let input: Box<dyn Read + Send> = if stdin {
                Box::new(std::io::stdin())
            } else {
                let f = std::fs::File::open(capture);
                Box::new(f.map_err(|e| Error::Msg(format!("{source}: {e}")))?)
            };
            let tx = tx.clone();
            match args.binary {
                true => std::thread::spawn(move || read_packets(input, &tx)),
                false => std::thread::spawn(move || read_lines(BufReader::new(input), &tx)),
            };
            (source, None)
        }
        (None, None) => return Err(Error::Usage("a CAPTURE or --port DEV".into())),
    };
    let out = std::fs::File::create(&args.out).map_err(|e| Error::output(&args.out, e))?;
    let mut rec = Recorder::new(out, &source).map_err(|e| Error::output(&args.out, e))?;
    watch_signals(tx)?;
    let (stopped, read_error) = pump(&rx, &mut rec).map_err(|e| Error::output(&args.out, e))?;
    drop(switch);
    let (recording, _) = rec
        .finish(stopped)
        .map_err(|e| Error::output(&args.out, e))?;
    report(args, &source, &recording, stopped);
    if let Some(e) = read_error {
        return Err(Error::Msg(format!(
            "{source}: {e} (the log holds every frame read before it)"
        )));
    }
    check(args, &source, &recording)
}

/// Converts lines until the input ends or a signal comes; returns why it stopped.
fn pump<W: Write>(
    rx: &Receiver<Msg>,
    rec: &mut Recorder<W>,
) -> std::io::Result<(&'static str, Option<std::io::Error>)> {
    loop {
        let msg = match rx.try_recv() {
            Ok(m) => m,
            Err(TryRecvError::Empty) => {
                // Nothing waiting: put what was received on disk before blocking.
                rec.flush()?;
                rx.recv().unwrap_or(Msg::End)
            }
            Err(TryRecvError::Disconnected) => Msg::End,
        };
        match msg {
            Msg::Line(l) => rec.line(&l)?,
            Msg::Item(i) => rec.item(i)?,
            Msg::End => return Ok(("end of input", None)),
            Msg::ReadError(e) => return Ok(("read error", Some(e))),
            Msg::Signal(s) => return Ok((s, None)),
        }
    }
}

fn read_lines(mut input: impl BufRead, tx: &SyncSender<Msg>) {
    loop {
        let mut buf = Vec::with_capacity(256);
        let msg = match input.read_until(b'\n', &mut buf) {
            Ok(0) => Msg::End,
            Ok(_) => Msg::Line(buf),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => Msg::ReadError(e),
        };
        let last = !matches!(msg, Msg::Line(_));
        if tx.send(msg).is_err() || last {
            return;
        }
    }
}

/// The binary stream's items, in order, then the end (or the read error).
fn read_packets(input: impl Read, tx: &SyncSender<Msg>) {
    let sent = sysid::board::packets::read_all(input, |item| {
        tx.send(Msg::Item(item))
            .map_err(|_| std::io::Error::other("the recorder stopped"))
    });
    let _ = tx.send(match sent {
        Ok(()) => Msg::End,
        Err(e) => Msg::ReadError(e),
    });
}

#[cfg(unix)]
fn watch_signals(tx: SyncSender<Msg>) -> Result<(), Error> {
    use signal_hook::consts::{SIGHUP, SIGINT, SIGTERM};
    let mut signals = signal_hook::iterator::Signals::new([SIGINT, SIGTERM, SIGHUP])
        .map_err(|e| Error::Msg(format!("cannot watch for Ctrl-C: {e}")))?;
    std::thread::spawn(move || {
        let mut seen = false;
        for s in signals.forever() {
            if seen {
                // Asked twice: stop now (rows already flushed stay in the file).
                std::process::exit(130);
            }
            seen = true;
            let name = match s {
                SIGINT => "SIGINT",
                SIGTERM => "SIGTERM",
                _ => "SIGHUP",
            };
            let _ = tx.send(Msg::Signal(name));
        }
    });
    Ok(())
}

#[cfg(not(unix))]
fn watch_signals(_tx: SyncSender<Msg>) -> Result<(), Error> {
    Ok(())
}

/// The summary on stderr, the file on stdout (a closed stdout is not an error here).
fn report(args: &Args, source: &str, rec: &Recording, stopped: &str) {
    eprint!("{}", rec.summary(source));
    eprintln!("  stopped by {stopped}");
    let _ = writeln!(std::io::stdout(), "wrote {}", args.out.display());
}

fn check(args: &Args, source: &str, rec: &Recording) -> Result<(), Error> {
    if rec.frames == 0 {
        return Err(sysid::board::record::RecordError::NoFrames {
            file: source.to_string(),
            lines: rec.lines,
        }
        .into());
    }
    if args.strict && !rec.is_complete() {
        return Err(Error::Msg(format!(
            "{source}: {} frames missing, {} corrupted lines, {} rejected frames (--strict); the log was written anyway",
            rec.missing_frames(),
            rec.counts.corrupted,
            rec.counts.rejected
        )));
    }
    Ok(())
}
