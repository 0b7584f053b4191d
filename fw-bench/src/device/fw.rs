//! The ONLY module of the bench that calls into the firmware library.
//!
//! Everything the bench does to the firmware goes through [`Board`], whose methods mirror, one to
//! one, what the board's tasks (`firmware::app::{stepper_task, sampler_task, command_task}`) do
//! between their awaits. When the firmware's API changes, this file is the one to adapt.
//!
//! Firmware functions called (today's API):
//! - `app::Config::default()` (fields `drift_window`, `drift_frac`, `rls_min_flow` read/set),
//!   `app::Shared::new`, `app::Shared::lock`, `app::Shared::command`;
//! - under `Shared::lock`: `app::State::stepper_poll`, `State::try_step`, `State::on_oversample`,
//!   `State::stepper_alive`, `State::flags` (+ `telemetry::Flags::is_fault`),
//!   `State::pop_event`, `State::motion` (+ `motion::Motion::volume`), `State::config`
//!   (+ `app::Config::oversample_period_us`);
//! - `command::LineAssembler::{new, push}` (which calls `command::parse`);
//! - `telemetry::Frame::encode`, `telemetry::Event::encode`, the `hal::TelemetrySink` trait
//!   (implemented here exactly as the binary's `DefmtSink`: one `defmt::println!` to RTT).
//!
//! Types and constants used: `app::{Config, Shared, StepperWait, REPLY_LEN}`, `hal::AXES`,
//! `telemetry::{Frame (fields chambers[].vdot/p/p_hat), Event (field kind), EventKind, LineBuf}`.
//! The rest of the crate sees only [`Board`], [`Wait`], [`FrameOut`], [`Events`], [`CHANNELS`].
//!
//! The ADC, the step pulses, the DIR pins, the watchdog and the UART are the binary's (Embassy)
//! side and are not part of the measurement.

use core::fmt::Write as _;
use core::hint::black_box;

use firmware::app::{Config, Shared, StepperWait, REPLY_LEN};
use firmware::command::LineAssembler;
use firmware::hal::{TelemetrySink, AXES};
use firmware::telemetry::{EventKind, Frame, LineBuf};

/// Number of channels (syringe + sensor + chamber).
pub const CHANNELS: usize = AXES;

/// What the stepper task waits for next (the firmware's `StepperWait`, copied).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wait {
    /// Step `axis` at `at_us`.
    Step { axis: usize, at_us: u64 },
    /// Nothing to step before this instant.
    Until(u64),
    /// Nothing planned.
    Idle,
}

/// The telemetry sink of the board binary (`DefmtSink` in `vfp-fw.rs`): one defmt-RTT line.
struct DefmtSink;

impl TelemetrySink for DefmtSink {
    fn line(&mut self, line: &str) {
        defmt::println!("{=str}", line);
    }
}

/// A completed frame, as the sampler task gets it from the state.
pub struct FrameOut(Frame);

/// Event lines sent after a conversion, by kind.
#[derive(Clone, Copy, Debug, Default)]
pub struct Events {
    /// Lines sent.
    pub lines: u32,
    /// Drift warnings among them.
    pub drift: u32,
    /// Faults among them.
    pub faults: u32,
}

/// The firmware's shared state plus the buffers its tasks own.
pub struct Board {
    shared: Shared,
    rls_min_flow: f32,
    /// The command task's line assembler and reply buffer.
    asm: LineAssembler,
    reply: heapless::String<{ REPLY_LEN + 8 }>,
    /// The sampler task's line buffer and sink.
    line: LineBuf,
    sink: DefmtSink,
}

impl Board {
    /// Boot state with the default configuration, except the RLS drift check's window and
    /// threshold (see the bench's docs: a short window so a drift-check frame comes within a
    /// few frames; threshold 0 so every check after the first takes the "drift" path).
    pub fn new(drift_window: u32, drift_frac: f32) -> Self {
        let cfg = Config {
            drift_window,
            drift_frac,
            ..Config::default()
        };
        Self {
            shared: Shared::new(cfg),
            rls_min_flow: cfg.rls_min_flow,
            asm: LineAssembler::new(),
            reply: heapless::String::new(),
            line: LineBuf::new(),
            sink: DefmtSink,
        }
    }

    /// The sampler task's conversion period, µs.
    pub fn oversample_period_us(&self) -> u64 {
        self.shared.lock(|s| s.config().oversample_period_us())
    }

    /// Stepper task, top of its loop: `stepper_poll` under the lock (DIR writes are the
    /// binary's GPIO; here they only reach `black_box`).
    #[inline(always)]
    pub fn stepper_poll(&self, now_us: u64) -> Wait {
        let w = self.shared.lock(|s| {
            s.stepper_poll(now_us, |a, d| {
                black_box((a, d));
            })
        });
        match w {
            StepperWait::Step { axis, at_us } => Wait::Step { axis, at_us },
            StepperWait::Until(t) => Wait::Until(t),
            StepperWait::Idle => Wait::Idle,
        }
    }

    /// Stepper task at a step's instant: `try_step` under the lock (the pulse is the binary's).
    #[inline(always)]
    pub fn try_step(&self, axis: usize, at_us: u64) -> bool {
        self.shared.lock(|s| s.try_step(axis, at_us))
    }

    /// Sampler task, one conversion: the work it does under its one lock per conversion.
    #[inline(always)]
    pub fn conversion(&self, raw: [u16; CHANNELS], now_us: u64) -> Option<FrameOut> {
        let (frame, alive, faulted) = self.shared.lock(|s| {
            let f = s.on_oversample(raw, now_us);
            (f, s.stepper_alive(now_us), s.flags().is_fault())
        });
        black_box((alive, faulted));
        frame.map(FrameOut)
    }

    /// Sampler task, a completed frame: encode the line and hand it to the sink.
    #[inline(always)]
    pub fn send_frame(&mut self, frame: &FrameOut) {
        self.line.clear();
        if frame.0.encode(&mut self.line).is_ok() {
            self.sink.line(&self.line);
        }
    }

    /// Sampler task, after every conversion: pop and send the queued event lines.
    pub fn send_events(&mut self) -> Events {
        let mut n = Events::default();
        while let Some(ev) = self.shared.lock(|s| s.pop_event()) {
            self.line.clear();
            if ev.encode(&mut self.line).is_ok() {
                self.sink.line(&self.line);
            }
            n.lines += 1;
            match ev.kind {
                EventKind::Drift { .. } => n.drift += 1,
                EventKind::Fault { .. } => n.faults += 1,
                _ => {}
            }
        }
        n
    }

    /// Command task: the bytes of one line (with its `\n`) through the line assembler, the
    /// command executed and its reply formatted (`…\r\n`). The reply, or `None` if the bytes
    /// did not complete a line.
    #[inline(always)]
    pub fn command_bytes(&mut self, bytes: &[u8], now_us: u64) -> Option<&str> {
        let mut done = false;
        for &b in bytes {
            let Some(parsed) = self.asm.push(b) else {
                continue;
            };
            self.reply.clear();
            match parsed {
                Ok(cmd) => self.shared.command(&cmd, now_us, &mut self.reply),
                Err(e) => {
                    let _ = write!(self.reply, "err {e}");
                }
            }
            let _ = self.reply.push_str("\r\n");
            done = true;
        }
        done.then_some(self.reply.as_str())
    }

    /// Syringe volumes, mm³ (drives the synthetic sensors; not measured).
    pub fn volumes(&self) -> [f32; CHANNELS] {
        self.shared
            .lock(|s| core::array::from_fn(|a| s.motion().volume(a)))
    }

    /// Whether a fault is latched (the script must not trip one).
    pub fn faulted(&self) -> bool {
        self.shared.lock(|s| s.flags().is_fault())
    }

    /// Which chambers' RLS this frame updated (when RLS is on): the firmware updates a chamber
    /// when |v̇| exceeds `rls_min_flow`, the pressure is finite and the model evaluates.
    pub fn rls_updated(&self, frame: &FrameOut) -> [bool; CHANNELS] {
        frame
            .0
            .chambers
            .map(|c| c.vdot.abs() > self.rls_min_flow && c.p.is_finite() && c.p_hat.is_finite())
    }
}

impl FrameOut {
    /// The frame's mean flow of each chamber, mm³/s.
    pub fn vdot(&self) -> [f32; CHANNELS] {
        self.0.chambers.map(|c| c.vdot)
    }
}
