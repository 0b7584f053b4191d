//! `vfp monitor -|FILE [-o LOG.csv]`: a live terminal view of the board's telemetry.
//!
//! Three parts: the pure [`MonitorState`] (lines in, counts and recent history out), [`render`]
//! (the state drawn on any ratatui backend) and the terminal loop here. A reader thread takes
//! each line as it arrives, appends it to the raw capture (when recording) and updates the state;
//! the screen is redrawn at a fixed rate from the latest state, so a slow terminal never holds up
//! the reading. q, Esc or Ctrl-C quits; then the log is converted from the raw capture by
//! `vfp record`'s own converter ([`sysid::record`]), so it is the same CSV `vfp record` writes
//! for the lines received, every frame in it.

mod render;
mod state;

use std::fs::File;
use std::io::{BufRead, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use ratatui::{backend::Backend, DefaultTerminal, Terminal};
use sysid::record::{convert_file, Recording};

use crate::Error;
pub use render::{buffer_text, flag_names, render, View};
pub use state::{Counts, MonitorState, Point};

/// `vfp monitor`: watch the board's telemetry live, and record it.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Telemetry: `-` reads stdin (`cargo fw-run | vfp monitor -`), otherwise a file or a named
    /// pipe holding `probe-rs run` output or raw `$F`/`$E` lines.
    pub input: PathBuf,
    /// Record as it goes: every line received is appended to LOG.capture.txt beside the log at
    /// once, and on quitting the log (the same CSV `vfp record` writes) is made from it.
    #[arg(short, long, value_name = "LOG.csv")]
    pub out: Option<PathBuf>,
    /// Seconds of pressure history in the charts.
    #[arg(long, default_value_t = 10.0, value_name = "S")]
    pub window: f64,
    /// Screen refreshes per second.
    #[arg(long, default_value_t = 10.0, value_name = "HZ")]
    pub fps: f64,
}

/// The raw capture written beside `LOG.csv`: `LOG.capture.txt`.
pub fn capture_path(out: &Path) -> PathBuf {
    out.with_extension("capture.txt")
}

/// What the reader thread and the screen share.
struct Shared {
    state: MonitorState,
    /// The raw capture being written, while recording.
    capture: Option<BufWriter<File>>,
}

/// A running monitor: the reader thread and the state it fills.
pub struct Session {
    shared: Arc<Mutex<Shared>>,
    reader: Option<JoinHandle<()>>,
    out: Option<PathBuf>,
    view: View,
}

impl Session {
    /// Starts reading `input` on a thread of its own; with `out`, records to it.
    pub fn start(
        input: Box<dyn BufRead + Send>,
        source: &str,
        out: Option<&Path>,
        window_s: f64,
    ) -> Result<Self, Error> {
        let capture = match out {
            Some(o) => {
                let path = capture_path(o);
                let f = File::create(&path).map_err(|e| Error::output(&path, e))?;
                Some(BufWriter::new(f))
            }
            None => None,
        };
        let shared = Arc::new(Mutex::new(Shared {
            state: MonitorState::new(window_s),
            capture,
        }));
        let for_reader = Arc::clone(&shared);
        let reader = std::thread::Builder::new()
            .name("vfp-monitor-reader".into())
            .spawn(move || pump(input, &for_reader))?;
        Ok(Self {
            shared,
            reader: Some(reader),
            out: out.map(Path::to_path_buf),
            view: View {
                source: source.to_string(),
                recording: out.map(|o| o.display().to_string()),
            },
        })
    }

    /// Looks at the state as it is now (the reader waits meanwhile).
    pub fn with_state<R>(&self, f: impl FnOnce(&MonitorState) -> R) -> R {
        f(&lock(&self.shared).state)
    }

    /// Draws the latest state.
    pub fn draw<B: Backend>(&self, terminal: &mut Terminal<B>) -> Result<(), Error> {
        let shared = lock(&self.shared);
        terminal
            .draw(|f| render(f, &shared.state, &self.view))
            .map_err(|e| Error::Msg(format!("cannot draw the screen: {e}")))?;
        Ok(())
    }

    /// Waits until the input ends (for a file; a live pipe ends when the board's printer exits).
    pub fn wait_for_end_of_input(&mut self) {
        if let Some(r) = self.reader.take() {
            let _ = r.join();
        }
    }

    /// Stops recording: the raw capture is completed and, when recording, the log is written
    /// from it. Lines that arrive after this are not read. Returns the conversion, if any.
    pub fn finish(self) -> Result<Option<Recording>, Error> {
        let capture = {
            let mut shared = lock(&self.shared);
            shared.capture.take()
        };
        let (Some(out), Some(capture)) = (self.out, capture) else {
            return Ok(None);
        };
        let path = capture_path(&out);
        capture
            .into_inner()
            .map_err(|e| Error::output(&path, e.error()))?
            .sync_all()
            .map_err(|e| Error::output(&path, e))?;
        let rec = convert_file(&path)?;
        sysid::log::write_log(&out, &rec.log)?;
        Ok(Some(rec))
    }
}

/// The lock, even if a thread panicked while holding it (the state stays usable).
fn lock(m: &Mutex<Shared>) -> MutexGuard<'_, Shared> {
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// The reader thread: each line to the raw capture (flushed, so it is on disk as it arrives),
/// then to the state, until the input ends.
fn pump(mut input: Box<dyn BufRead + Send>, shared: &Mutex<Shared>) {
    let mut buf = Vec::with_capacity(1024);
    loop {
        buf.clear();
        let read = input.read_until(b'\n', &mut buf);
        let mut s = lock(shared);
        match read {
            Ok(0) => {
                s.state.input_ended = true;
                return;
            }
            Ok(_) => {}
            Err(e) => {
                s.state.input_ended = true;
                s.state
                    .push_line(format!("vfp monitor: reading the input failed: {e}").as_bytes());
                return;
            }
        }
        if let Some(w) = s.capture.as_mut() {
            let ok = w.write_all(&buf).is_ok()
                && (buf.ends_with(b"\n") || w.write_all(b"\n").is_ok())
                && w.flush().is_ok();
            if !ok {
                // Recording stopped; the screen says so, the view goes on.
                s.capture = None;
                s.state
                    .push_line(b"vfp monitor: writing the raw capture failed; recording stopped");
            }
        }
        s.state.push_line(&buf);
    }
}

/// Runs `vfp monitor`.
pub fn run(args: &Args) -> Result<(), Error> {
    if !(args.window > 0.0 && args.window.is_finite()) {
        return Err(Error::Usage(format!(
            "--window {} (seconds > 0)",
            args.window
        )));
    }
    if !(args.fps >= 0.5 && args.fps <= 100.0) {
        return Err(Error::Usage(format!("--fps {} (0.5 to 100)", args.fps)));
    }
    let (input, source): (Box<dyn BufRead + Send>, String) = if args.input.as_os_str() == "-" {
        (
            Box::new(std::io::BufReader::new(std::io::stdin())),
            "<stdin>".into(),
        )
    } else {
        let f = File::open(&args.input)
            .map_err(|e| Error::Msg(format!("{}: {e}", args.input.display())))?;
        (
            Box::new(std::io::BufReader::new(f)),
            args.input.display().to_string(),
        )
    };
    // The terminal first: without one nothing is started and no file is made.
    let mut terminal = ratatui::try_init()
        .map_err(|e| Error::Msg(format!("vfp monitor needs a terminal to draw on: {e}")))?;
    let session = match Session::start(input, &source, args.out.as_deref(), args.window) {
        Ok(s) => s,
        Err(e) => {
            ratatui::restore();
            return Err(e);
        }
    };
    let shown = screen(
        &session,
        &mut terminal,
        Duration::from_secs_f64(1.0 / args.fps),
    );
    ratatui::restore();
    let recorded = session.finish();
    shown?;
    if let Some(rec) = recorded? {
        eprint!("{}", rec.summary(&source));
        let out = args.out.as_deref().unwrap_or(Path::new(""));
        println!(
            "wrote {} (raw capture: {})",
            out.display(),
            capture_path(out).display()
        );
    }
    Ok(())
}

/// The terminal loop: draw, wait up to one tick for a key, until q, Esc or Ctrl-C.
fn screen(session: &Session, terminal: &mut DefaultTerminal, tick: Duration) -> Result<(), Error> {
    loop {
        session.draw(terminal)?;
        if event::poll(tick)? {
            if let Event::Key(k) = event::read()? {
                let ctrl_c =
                    k.code == KeyCode::Char('c') && k.modifiers.contains(KeyModifiers::CONTROL);
                let quit = matches!(k.code, KeyCode::Char('q') | KeyCode::Esc) || ctrl_c;
                if quit && k.kind == KeyEventKind::Press {
                    return Ok(());
                }
            }
        }
    }
}
