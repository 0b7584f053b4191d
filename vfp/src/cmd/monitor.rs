//! `vfp monitor -|FILE [-o LOG.csv]`: a live terminal view of the board's telemetry.
//!
//! Three parts: the pure [`MonitorState`] (lines in, counts and recent history out), [`render`]
//! (the state drawn on any ratatui backend) and the terminal loop here. A reader thread takes
//! each line as it arrives, appends it to the raw capture (when recording) and updates the state;
//! the screen is redrawn at a fixed rate from the latest state, so a slow terminal never holds up
//! the reading. q, Esc or Ctrl-C quits; then the log is converted from the raw capture by
//! `vfp record`'s own converter ([`sysid::board::record`]), so it is the same CSV `vfp record` writes
//! for the lines received, every frame in it.
//!
//! With `--port DEV` the source is the board's serial port: its binary telemetry is switched on
//! and read packet by packet ([`sysid::board::packets`]); the raw bytes go to `LOG.capture.bin` and the
//! log is converted from them the same way ([`sysid::board::record::convert_packets`]).

mod render;
mod state;

use std::fs::File;
use std::io::{BufRead, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use ratatui::crossterm::event::{self, Event, KeyCode, KeyEventKind, KeyModifiers};
use ratatui::{backend::Backend, DefaultTerminal, Terminal};
use sysid::board::packets::PacketReader;
use sysid::board::record::{convert_file, convert_packets, Recording};

use crate::Error;
pub use render::{buffer_text, flag_names, render, View};
pub use state::{Counts, MonitorState, Point};

/// `vfp monitor`: watch the board's telemetry live, and record it.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Telemetry: `-` reads stdin (`cargo fw-run | vfp monitor -`), otherwise a file or a named
    /// pipe holding `probe-rs run` output or raw `$F`/`$E` lines. Not with `--port`.
    #[arg(required_unless_present = "port", conflicts_with = "port")]
    pub input: Option<PathBuf>,
    /// Watch the board's serial port instead (e.g. /dev/ttyACM0, COM3): switches its binary
    /// telemetry on (no debug probe needed) and off again on quitting.
    #[arg(long, value_name = "DEV")]
    pub port: Option<String>,
    /// Baud rate of `--port` (the firmware's UART runs at 115200).
    #[arg(long, default_value_t = crate::port::DEFAULT_BAUD, requires = "port")]
    pub baud: u32,
    /// Record as it goes: every line received is appended to LOG.capture.txt beside the log at
    /// once (the bytes of `--port` to LOG.capture.bin), and on quitting the log (the same CSV
    /// `vfp record` writes) is made from it.
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

/// The raw bytes of a binary stream written beside `LOG.csv`: `LOG.capture.bin`.
pub fn binary_capture_path(out: &Path) -> PathBuf {
    out.with_extension("capture.bin")
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
    /// The input is the binary serial stream.
    binary: bool,
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
        Self::start_with(source, out, window_s, false, move |s| pump(input, s))
    }

    /// Starts reading the binary serial stream `input` ([`sysid::board::packets`]) on a thread of its
    /// own; with `out`, records to it (the raw bytes to [`binary_capture_path`]).
    pub fn start_binary(
        input: Box<dyn Read + Send>,
        source: &str,
        out: Option<&Path>,
        window_s: f64,
    ) -> Result<Self, Error> {
        Self::start_with(source, out, window_s, true, move |s| pump_binary(input, s))
    }

    fn start_with(
        source: &str,
        out: Option<&Path>,
        window_s: f64,
        binary: bool,
        pump: impl FnOnce(&Mutex<Shared>) + Send + 'static,
    ) -> Result<Self, Error> {
        let capture = match out {
            Some(o) => {
                let path = match binary {
                    true => binary_capture_path(o),
                    false => capture_path(o),
                };
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
            .spawn(move || pump(&for_reader))?;
        Ok(Self {
            shared,
            reader: Some(reader),
            out: out.map(Path::to_path_buf),
            binary,
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
        let path = match self.binary {
            true => binary_capture_path(&out),
            false => capture_path(&out),
        };
        capture
            .into_inner()
            .map_err(|e| Error::output(&path, e.error()))?
            .sync_all()
            .map_err(|e| Error::output(&path, e))?;
        let rec = if self.binary {
            let f =
                File::open(&path).map_err(|e| Error::Msg(format!("{}: {e}", path.display())))?;
            convert_packets(std::io::BufReader::new(f), &path.display().to_string())?
        } else {
            convert_file(&path)?
        };
        sysid::log::write_log(&out, &rec.log)?;
        Ok(Some(rec))
    }
}

impl Shared {
    /// The input ended, at its end or by an error (shown in the log pane).
    fn end(&mut self, err: Option<std::io::Error>) {
        self.state.input_ended = true;
        if let Some(e) = err {
            self.state
                .push_line(format!("vfp monitor: reading the input failed: {e}").as_bytes());
        }
    }

    /// Appends `bytes` to the raw capture and flushes it; if that fails recording stops and the
    /// screen says so (the view goes on).
    fn keep(&mut self, bytes: &[u8]) {
        let Some(w) = self.capture.as_mut() else {
            return;
        };
        if !(w.write_all(bytes).is_ok() && w.flush().is_ok()) {
            self.capture = None;
            self.state
                .push_line(b"vfp monitor: writing the raw capture failed; recording stopped");
        }
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
            Ok(0) => return s.end(None),
            Ok(_) => {}
            Err(e) => return s.end(Some(e)),
        }
        if !buf.ends_with(b"\n") {
            buf.push(b'\n');
        }
        s.keep(&buf);
        s.state.push_line(&buf);
    }
}

/// The reader thread for the binary stream: the bytes to the raw capture (flushed), each packet
/// or text line to the state, until the input ends.
fn pump_binary(mut input: Box<dyn Read + Send>, shared: &Mutex<Shared>) {
    let mut packets = PacketReader::new();
    let mut buf = [0u8; 4096];
    loop {
        let read = input.read(&mut buf);
        let mut s = lock(shared);
        let n = match read {
            Ok(0) => {
                if let Some(item) = packets.finish() {
                    s.state.push_item(item);
                }
                return s.end(None);
            }
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return s.end(Some(e)),
        };
        s.keep(&buf[..n]);
        packets.feed(&buf[..n], |item| s.state.push_item(item));
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
    let input = open_input(args)?;
    // The terminal first: without one nothing is started and no file is made.
    let mut terminal = ratatui::try_init()
        .map_err(|e| Error::Msg(format!("vfp monitor needs a terminal to draw on: {e}")))?;
    let source = input.source.clone();
    let started = match input.reader {
        Reader::Text(r) => Session::start(r, &source, args.out.as_deref(), args.window),
        Reader::Binary(r) => Session::start_binary(r, &source, args.out.as_deref(), args.window),
    };
    let session = match started {
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
    drop(input.switch);
    let recorded = session.finish();
    shown?;
    if let Some(rec) = recorded? {
        eprint!("{}", rec.summary(&source));
        let out = args.out.as_deref().unwrap_or(Path::new(""));
        println!(
            "wrote {} (raw capture: {})",
            out.display(),
            match args.port {
                Some(_) => binary_capture_path(out),
                None => capture_path(out),
            }
            .display()
        );
    }
    Ok(())
}

enum Reader {
    Text(Box<dyn BufRead + Send>),
    Binary(Box<dyn Read + Send>),
}

/// The opened input: its reader, its name, and the serial stream's switch (off when dropped).
struct Input {
    reader: Reader,
    source: String,
    switch: Option<crate::port::StreamSwitch>,
}

fn open_input(args: &Args) -> Result<Input, Error> {
    if let Some(dev) = &args.port {
        let (reader, switch) = crate::port::open(dev, args.baud)?;
        return Ok(Input {
            reader: Reader::Binary(Box::new(reader)),
            source: format!("{dev} (binary telemetry)"),
            switch: Some(switch),
        });
    }
    let path = args
        .input
        .as_deref()
        .ok_or_else(|| Error::Usage("an INPUT or --port DEV".into()))?;
    let (reader, source): (Box<dyn BufRead + Send>, String) = if path.as_os_str() == "-" {
        (
            Box::new(std::io::BufReader::new(std::io::stdin())),
            "<stdin>".into(),
        )
    } else {
        let f = File::open(path).map_err(|e| Error::Msg(format!("{}: {e}", path.display())))?;
        (
            Box::new(std::io::BufReader::new(f)),
            path.display().to_string(),
        )
    };
    Ok(Input {
        reader: Reader::Text(reader),
        source,
        switch: None,
    })
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
