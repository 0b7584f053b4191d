//! The ONLY module of the bench that calls into the firmware library.
//!
//! Everything the bench does to the firmware goes through [`Board`], whose methods mirror, one to
//! one, what the board's tasks (`firmware::app::{stepper_task, sampler_task, command_task}`, as
//! spawned by `firmware/src/bin/vfp-fw.rs`) do between their awaits. When the firmware's API
//! changes, this file is the one to adapt.
//!
//! Firmware functions called by the measured operations (the tasks' per-tick entry points):
//! - stepper task: `app::Shared::stepper_tick` (one wake-up: `Control::stepper_wake` under one
//!   short critical section per batch of same-instant steps, then the pulses through the
//!   `hal::Steppers` trait, implemented here with no hardware behind it);
//! - sampler task: `app::Shared::conversion` (one conversion: `Control::on_conversion` under one
//!   short critical section, the frame sums outside), the estimator's async mutex
//!   (`app::Shared::estimator`, taken the way the task's `lock().await` takes it: its `lock()`
//!   future polled once, `embassy_futures::poll_once`, there being no executor here; it is always
//!   free, so the first poll is ready), `app::Shared::finish_frame`, `app::Sampler::send_frame`
//!   and `app::Shared::send_events` into the board's telemetry sink (below), and
//!   `app::Shared::send_serial_frame` (the binary packet of `firmware::wire` into the UART queue;
//!   the stream is switched on at set-up, and the bench drains and decodes the queue as the
//!   command task and the host would, `app::Shared::serial_telemetry`, `wire::decode`);
//! - command task: `command::LineAssembler::push` per byte, then, with the estimator taken as
//!   above, `app::Shared::command_raw` (checksum rules, parse, execute, reply) and the `\r\n`.
//!
//! Set-up and bookkeeping, never measured: `app::Config::default()` (fields `drift_window`,
//! `drift_frac`, `rls_min_flow`), `app::Shared::new`, `app::Shared::declare_origin`, `app::Sampler::{new, period_us, drops}`,
//! `app::Shared::with_control` with `app::Control::{motion, latched}`,
//! `motion::Motion::{volume, next_batch, all_idle}`, `telemetry::parse_line` (the bench reads
//! the telemetry channel back the way the host does), `command::write_checksummed` (the bench
//! frames each command line as a host does: the firmware requires the checksum from boot). `app::Shared::lock` is not used: it keeps
//! interrupts off for its whole closure and no task calls it.
//!
//! The telemetry sink is the binary's `RttSink`, copied: RTT up-channel 1 ("telemetry", 4 KiB,
//! `rtt-target`), mode set to `NoBlockSkip` before every line, the whole line or nothing. The
//! bench plays the host too: between operations it drains that channel (read pointer set to the
//! write pointer, as a probe does), so every measured line is a successful write, and it decodes
//! the lines to count the events the run produced.
//!
//! Types used: `app::{Config, Sampler, Shared, REPLY_LEN}`, `hal::{Direction, Steppers,
//! TelemetrySink, AXES}`, `motion::StepBatch`, `telemetry::{Event (field kind), EventKind, Flags,
//! Frame (fields chambers[].vdot/p/p_hat), Line}`, `embassy_time::Instant`.
//! The rest of the crate sees only [`Board`], [`FrameOut`], [`Telemetry`], [`CHANNELS`].
//!
//! The ADC, the step pulses, the DIR pins, the watchdog and the UART are the binary's (Embassy)
//! side and are not part of the measurement: here they only reach `black_box`.

use core::hint::black_box;
use core::task::Poll;

use embassy_time::Instant;
use firmware::app::{Config, Sampler, Shared, REPLY_LEN};
use firmware::command::LineAssembler;
use firmware::hal::{Direction, Steppers, TelemetrySink, AXES};
use firmware::telemetry::{self, EventKind, Flags, Frame, Line};
use rtt_target::{ChannelMode, UpChannel};

/// Number of channels (syringe + sensor + chamber).
pub const CHANNELS: usize = AXES;

/// RTT up-channel sizes of the board binary (`vfp-fw.rs`): defmt logs, telemetry.
pub const DEFMT_RTT_BYTES: usize = 1024;
pub const TELEMETRY_RTT_BYTES: usize = 4096;

/// The binary's telemetry sink (`RttSink` in `vfp-fw.rs`), the same two calls per line.
pub struct RttSink(pub UpChannel);

impl TelemetrySink for RttSink {
    fn try_send(&mut self, line: &str) -> bool {
        self.0.set_mode(ChannelMode::NoBlockSkip);
        self.0.write(line.as_bytes()) == line.len()
    }
}

/// Step and DIR outputs with nothing behind them; they remember which axes were pulsed.
#[derive(Default)]
struct BenchSteppers {
    /// Axes pulsed since the last [`Board::stepper_tick`] (bit `a` = axis `a`).
    pulsed: u8,
}

impl Steppers for BenchSteppers {
    fn set_direction(&mut self, axis: usize, dir: Direction) {
        black_box((axis, dir));
    }
    fn step(&mut self, axis: usize, at: Instant) {
        black_box(at);
        self.pulsed |= 1 << axis;
    }
    fn step_axes(&mut self, axes: u8, at: Instant) {
        black_box(at);
        self.pulsed |= axes;
    }
    fn set_enabled(&mut self, enabled: bool) {
        black_box(enabled);
    }
}

/// A completed frame, as the sampler task has it before sending it.
pub struct FrameOut(Frame);

/// What the host read from the telemetry channel since it last looked.
#[derive(Clone, Copy, Debug, Default)]
pub struct Telemetry {
    /// Frame lines.
    pub frames: u32,
    /// Event lines.
    pub events: u32,
    /// Drift warnings among them.
    pub drift: u32,
    /// Faults among them.
    pub faults: u32,
}

/// The firmware's shared state plus what its tasks own.
pub struct Board {
    shared: Shared,
    rls_min_flow: f32,
    /// The stepper task's outputs.
    steppers: BenchSteppers,
    /// The sampler task's own state and sink.
    sampler: Sampler,
    sink: RttSink,
    /// The command task's line assembler and reply buffer.
    asm: LineAssembler,
    reply: heapless::String<{ REPLY_LEN + 8 }>,
    /// The host's side of the telemetry channel: a partial line carried over.
    host_line: heapless::String<{ firmware::telemetry::MAX_LINE }>,
}

/// Take the estimator the way the tasks' `shared.est.lock().await` does: poll the lock future
/// (once: no executor here, and no other holder, so it is ready at once).
macro_rules! estimator {
    ($shared:expr) => {
        match embassy_futures::poll_once($shared.estimator().lock()) {
            Poll::Ready(est) => est,
            Poll::Pending => panic!("the estimator is held"),
        }
    };
}

impl Board {
    /// Boot state with the default configuration, except the RLS drift check's window and
    /// threshold (see the bench's docs: a short window so a drift-check frame comes within a
    /// few frames; threshold 0 so every check after the first takes the "drift" path).
    /// `telemetry` is RTT up-channel 1, initialised as the binary does.
    pub fn new(drift_window: u32, drift_frac: f32, telemetry: UpChannel) -> Self {
        let cfg = Config {
            drift_window,
            drift_frac,
            ..Config::default()
        };
        let board = Self {
            shared: Shared::new(cfg),
            rls_min_flow: cfg.rls_min_flow,
            steppers: BenchSteppers::default(),
            sampler: Sampler::new(&cfg),
            sink: RttSink(telemetry),
            asm: LineAssembler::new(),
            reply: heapless::String::new(),
            host_line: heapless::String::new(),
        };
        // The binary serial stream on (`telemetry on`), so every frame takes that path too.
        board.shared.serial_telemetry().set(true);
        // The plungers at volume 0, as the host's `origin all 0` declares them after a reset.
        board
            .shared
            .declare_origin(0.0)
            .expect("volume 0 is in range");
        board
    }

    /// The sampler task's conversion period, µs.
    pub fn oversample_period_us(&self) -> u64 {
        self.sampler.period_us()
    }

    /// The stepper task, one wake-up at `now_us` (the body of its loop): `stepper_tick`, which
    /// issues the steps due and returns the instant to sleep until. The axes pulsed are kept for
    /// [`Self::take_pulsed`].
    #[inline(always)]
    pub fn stepper_tick(&mut self, now_us: u64) -> u64 {
        self.shared.stepper_tick(now_us, &mut self.steppers)
    }

    /// The axes pulsed since the last call (bit `a` = axis `a`).
    pub fn take_pulsed(&mut self) -> u8 {
        core::mem::take(&mut self.steppers.pulsed)
    }

    /// The steps a wake-up at `now_us` would issue: the planned batch's axes if it is due
    /// (bookkeeping, not measured).
    pub fn due_axes(&self, now_us: u64) -> u8 {
        self.shared.with_control(|c| match c.motion().next_batch() {
            Some(b) if b.at_us <= now_us => b.axes,
            _ => 0,
        })
    }

    /// Whether every axis is at rest.
    pub fn all_idle(&self) -> bool {
        self.shared.with_control(|c| c.motion().all_idle())
    }

    /// The sampler task, one conversion, up to the frame: `conversion` (its one short lock),
    /// the stepper wake on a fault, the watchdog feed (the binary's: `black_box`), and when the
    /// conversion completes a frame, the estimator taken and `finish_frame`.
    #[inline(always)]
    pub fn conversion(&mut self, raw: [u16; CHANNELS], now_us: u64) -> Option<FrameOut> {
        let c = self.shared.conversion(&mut self.sampler, raw, now_us);
        if c.faulted {
            self.shared.wake_stepper();
        }
        if c.alive {
            black_box(());
        }
        let acc = c.frame?;
        let mut est = estimator!(self.shared);
        Some(FrameOut(self.shared.finish_frame(&mut est, &acc)))
    }

    /// The sampler task, a completed frame: formatted and handed to the sink.
    #[inline(always)]
    pub fn send_frame(&mut self, frame: &mut FrameOut) {
        self.sampler.send_frame(&mut frame.0, &mut self.sink);
    }

    /// The sampler task, a completed frame, after the line: encoded as a binary packet and queued
    /// for the UART (`app::Shared::send_serial_frame`, `firmware::wire`).
    #[inline(always)]
    pub fn send_serial_frame(&mut self, frame: &FrameOut) {
        self.shared.send_serial_frame(&mut self.sampler, &frame.0);
    }

    /// Serial packets dropped so far (the queue was full): must stay 0, the bench drains it.
    pub fn serial_drops(&self) -> u32 {
        self.sampler.serial_drops()
    }

    /// The command task's side of the serial stream, and the host's: take every queued packet
    /// (`wire::SerialTelemetry::try_next`) and decode it (`wire::decode`); the frames read.
    pub fn read_serial(&mut self) -> u32 {
        let mut frames = 0;
        let mut scratch = [0u8; firmware::wire::MAX_RAW];
        while let Some(p) = self.shared.serial_telemetry().try_next() {
            match firmware::wire::decode(&p[1..p.len() - 1], &mut scratch) {
                Ok(firmware::wire::Record::Frame(_)) => frames += 1,
                Ok(firmware::wire::Record::Event(..)) => {}
                Err(_) => panic!("undecodable serial packet"),
            }
        }
        frames
    }

    /// The sampler task, after every conversion: the queued event lines to the sink.
    pub fn send_events(&mut self) {
        self.shared.send_events(&mut self.sampler, &mut self.sink);
    }

    /// Telemetry lines dropped so far (the sink refused them): must stay 0, the bench reads.
    pub fn drops(&self) -> u32 {
        self.sampler.drops()
    }

    /// The command task: the bytes of one line (with its `\n`) through the line assembler, the
    /// estimator taken, the line checked, parsed and executed and its reply formatted, then
    /// `\r\n`. The reply, or `None` if the bytes did not complete a line.
    #[inline(always)]
    pub fn command_bytes(&mut self, bytes: &[u8], now_us: u64) -> Option<&str> {
        let mut done = false;
        for &b in bytes {
            let Some(line) = self.asm.push(b) else {
                continue;
            };
            self.reply.clear();
            {
                let mut est = estimator!(self.shared);
                self.shared
                    .command_raw(&mut est, line, now_us, &mut self.reply);
            }
            let _ = self.reply.push_str("\r\n");
            done = true;
        }
        done.then_some(self.reply.as_str())
    }

    /// The host's side: `command` as the line a host sends, `*LLCC <command>` (not measured).
    pub fn checksummed(command: &str, out: &mut impl core::fmt::Write) -> core::fmt::Result {
        firmware::command::write_checksummed(command, out)
    }

    /// Syringe volumes, mm³ (drives the synthetic sensors; not measured).
    pub fn volumes(&self) -> [f32; CHANNELS] {
        self.shared
            .with_control(|c| core::array::from_fn(|a| c.motion().volume(a)))
    }

    /// Whether a fault is latched (the script must not trip one).
    pub fn faulted(&self) -> bool {
        self.shared.with_control(|c| Flags(c.latched()).is_fault())
    }

    /// Which chambers' RLS this frame updated (when RLS is on): the firmware updates a chamber
    /// when |v̇| exceeds `rls_min_flow`, the pressure is finite and the model evaluates.
    pub fn rls_updated(&self, frame: &FrameOut) -> [bool; CHANNELS] {
        frame
            .0
            .chambers
            .map(|c| c.vdot.abs() > self.rls_min_flow && c.p.is_finite() && c.p_hat.is_finite())
    }

    /// The host's side: read everything written to the telemetry channel since the last call
    /// (as a probe does: copy out, then move the read pointer) and decode the lines.
    pub fn read_telemetry(&mut self) -> Telemetry {
        let mut t = Telemetry::default();
        let mut buf = [0u8; TELEMETRY_RTT_BYTES];
        let n = host_read_telemetry(&mut buf);
        for &b in &buf[..n] {
            if b != b'\n' {
                assert!(
                    self.host_line.push(b as char).is_ok(),
                    "telemetry line too long"
                );
                continue;
            }
            match telemetry::parse_line(&self.host_line) {
                Some(Ok(Line::Frame(_))) => t.frames += 1,
                Some(Ok(Line::Event(ev))) => {
                    t.events += 1;
                    match ev.kind {
                        EventKind::Drift { .. } => t.drift += 1,
                        EventKind::Fault { .. } => t.faults += 1,
                        _ => {}
                    }
                }
                _ => panic!("undecodable telemetry line `{}`", self.host_line),
            }
            self.host_line.clear();
        }
        t
    }
}

impl FrameOut {
    /// The frame's mean flow of each chamber, mm³/s.
    pub fn vdot(&self) -> [f32; CHANNELS] {
        self.0.chambers.map(|c| c.vdot)
    }
}

/// Read RTT up-channel 1 the way the host does, through the control block `_SEGGER_RTT`
/// (SEGGER's layout, 32-bit words: 16-byte id, max up, max down, then per up channel: name,
/// buffer, size, write, read, flags). Returns the bytes copied into `out`.
fn host_read_telemetry(out: &mut [u8]) -> usize {
    unsafe extern "C" {
        #[link_name = "_SEGGER_RTT"]
        static mut CONTROL_BLOCK: [u32; 6];
    }
    const CHANNEL: usize = 1;
    // SAFETY: the control block is initialised by `rtt_init!` in `main` before the run; the
    // words read and the read pointer written are the host's side of the protocol (nothing on
    // the target writes them), accessed volatile as a probe would.
    unsafe {
        let cb = (&raw mut CONTROL_BLOCK).cast::<u32>();
        let ch = cb.add(6 + 6 * CHANNEL);
        let buffer = ch.add(1).read_volatile() as usize as *const u8;
        let size = ch.add(2).read_volatile() as usize;
        let write = ch.add(3).read_volatile() as usize;
        let mut read = ch.add(4).read_volatile() as usize;
        let mut n = 0;
        while read != write && n < out.len() {
            out[n] = buffer.add(read).read_volatile();
            n += 1;
            read = (read + 1) % size;
        }
        ch.add(4).write_volatile(read as u32);
        n
    }
}
