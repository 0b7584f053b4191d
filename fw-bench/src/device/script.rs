//! The scripted run: the three tasks' work interleaved on a virtual clock, as the board's
//! executors would run it, with the single operations measured as they happen.
//!
//! Without an executor the tasks' loop bodies are called directly (see [`super::fw::Board`]):
//! - the stepper task wakes at the deadline its last wake-up returned (a planned step instant,
//!   or 50 ms later with nothing to do) and after every command (the firmware's wake signal);
//!   it has the higher priority: at equal instants the stepper goes first;
//! - the sampler task converts every 5 ms (8 conversions per 40 ms frame), estimates and sends
//!   the frame line on every 8th, and sends the queued event lines after every conversion;
//! - the command task executes a command line between two of those events;
//! - the host reads the telemetry channel after every conversion (not measured).
//!
//! The run, in order (≈ 1.9 s of rig time):
//! 1. boot and the pressure zero at rest (25 frames, nothing measured);
//! 2. commands at rest, each measured: `status`, `limit`, `origin`, the model read-back, and
//!    the same model loaded back (`begin`, 2 × `coef`, `commit`);
//! 3. `move 0 106 50 500`, `move 1 …`, `move 2 …` (6 mm³ from 100), started 270 µs apart so
//!    the axes' steps fall at different instants (step period 800 µs at cruise): every
//!    wake-up that issues one step is measured in the acceleration phase (steps 20–24 of each
//!    axis, `step_accel`) and at cruise (steps 70–74, `step_cruise`; the trapezoid accelerates
//!    over the first 62); every conversion (`oversample`) and every frame (`frame`, bare
//!    polynomial) and its telemetry line measured;
//! 4. the read-back model loaded into every chamber with a three-effect chain (hysteresis,
//!    sensor lag, delivery lag; `model <ch> effect …` measured as `cmd_model_effect`), then
//!    `move all 112 50 500` and back to 106: every frame measured as `frame_chain`; then the
//!    same model without effects loaded into each (the bare polynomial again);
//! 5. `rls <ch> on` on the three chambers, then `move all 116 20 500` (10 mm³ at 20 mm³/s): the
//!    three axes step at the same instants, one wake-up per batch of three (steps 20–24 and
//!    70–74: `step_batch3`); every frame measured as `frame_rls`; those on which the drift check
//!    runs (every `DRIFT_WINDOW` RLS updates) are retagged `frame_rls_drift`;
//! 6. `run` with 8 flows, 30 ms of its first leg, `stop`, `clear`, `rls 0 off`, `status`,
//!    `zero`, and one more frame.
//!
//! The sensors read a synthetic pressure that follows the syringe volume (0.064 kPa/mm³ above
//! the zero, a few counts of dither), well inside every safety limit: any fault stops the run.

use core::fmt::{self, Write as _};

use heapless::String;

use rtt_target::UpChannel;

use super::fw::{Board, FrameOut, CHANNELS};
use super::marks::*;
use super::measure;

/// RLS updates between two drift checks (the firmware's default is 250 frames, 10 s): short,
/// so drift-check frames come within the run; a check costs the same whatever the window.
const DRIFT_WINDOW: u32 = 4;
/// Drift threshold 0: every check after the first (which takes the baseline) takes the
/// warning path (event queued), the more expensive one.
const DRIFT_FRAC: f32 = 0.0;
/// Conversions per frame (the firmware's default `oversample`).
const OVERSAMPLE: u32 = 8;
/// Delay between the three single-axis moves' commands, µs (not a divisor of the 800 µs step
/// period: the axes never step at one instant at cruise).
const STAGGER_US: u64 = 270;
/// Raw counts at 0 kPa (1.0 V at the sensor through the 0.625 divider, 12 bits at 3.3 V).
const ZERO_COUNTS: f32 = 776.0;
/// Synthetic pressure: counts per mm³ of syringe volume.
const COUNTS_PER_MM3: f32 = 2.0;
/// Steps (per axis, from the start of a move) measured as acceleration-phase steps.
const ACCEL_STEPS: core::ops::Range<u32> = 20..25;
/// Steps measured as cruise steps.
const CRUISE_STEPS: core::ops::Range<u32> = 70..75;

/// How the conversions of the current phase are measured.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Measure {
    /// Not measured.
    Off,
    /// `oversample`, `frame`, `telemetry_line`.
    Bare,
    /// `oversample`, `frame_rls` (or `frame_rls_drift`), `telemetry_line`.
    Rls,
    /// `oversample`, `frame_chain`, `telemetry_line`.
    Chain,
}

/// What the run did (printed by the program at the end).
#[derive(Default)]
pub struct Summary {
    steps: u32,
    wakeups: u32,
    conversions: u32,
    frames: u32,
    commands: u32,
    drift_frames: u32,
    event_lines: u32,
    rig_us: u64,
}

impl fmt::Display for Summary {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "scripted run: {} ms of rig time, {} steps in {} stepper wake-ups, {} conversions, {} frames ({} with the drift check), {} event lines, {} commands",
            self.rig_us / 1000,
            self.steps,
            self.wakeups,
            self.conversions,
            self.frames,
            self.drift_frames,
            self.event_lines,
            self.commands
        )
    }
}

struct Rig {
    b: Board,
    now: u64,
    period: u64,
    next_conv: u64,
    /// The stepper task's next wake-up.
    next_tick: u64,
    /// Steps taken per axis since the current move started.
    k: [u32; CHANNELS],
    measure_steps: bool,
    measure_conv: Measure,
    /// Chambers with RLS on, and their RLS updates so far.
    rls_on: [bool; CHANNELS],
    rls_updates: [u32; CHANNELS],
    dither: u32,
    s: Summary,
}

/// A line being built (commands and replies are far below this).
type Line = String<256>;

impl Rig {
    fn new(telemetry: UpChannel) -> Self {
        let b = Board::new(DRIFT_WINDOW, DRIFT_FRAC, telemetry);
        let period = b.oversample_period_us();
        Self {
            b,
            now: 0,
            period,
            next_conv: period,
            next_tick: 0,
            k: [0; CHANNELS],
            measure_steps: false,
            measure_conv: Measure::Off,
            rls_on: [false; CHANNELS],
            rls_updates: [0; CHANNELS],
            dither: 0x1234_5678,
            s: Summary::default(),
        }
    }

    /// Run the stepper and sampler tasks up to `until_us`.
    fn advance(&mut self, until_us: u64) {
        loop {
            if self.next_tick.min(self.next_conv) > until_us {
                break;
            }
            if self.next_tick <= self.next_conv {
                self.now = self.now.max(self.next_tick);
                self.tick();
            } else {
                self.now = self.next_conv;
                self.convert();
                self.next_conv += self.period;
            }
        }
        self.now = self.now.max(until_us);
    }

    /// One wake-up of the stepper task at `now`. Measured when steps are measured and it issues
    /// one step with index in `ACCEL_STEPS` or `CRUISE_STEPS` (`step_accel`, `step_cruise`), or
    /// a batch of three same-instant steps with such an index (`step_batch3`).
    fn tick(&mut self) {
        let due = self.b.due_axes(self.now);
        let k = (0..CHANNELS)
            .filter(|&a| due & (1 << a) != 0)
            .map(|a| self.k[a])
            .min()
            .unwrap_or(0);
        let region: Option<extern "C" fn()> = match (self.measure_steps, due.count_ones()) {
            (false, _) => None,
            (true, 1) if ACCEL_STEPS.contains(&k) => Some(fwb_begin_step_accel),
            (true, 1) if CRUISE_STEPS.contains(&k) => Some(fwb_begin_step_cruise),
            (true, 3) if ACCEL_STEPS.contains(&k) || CRUISE_STEPS.contains(&k) => {
                Some(fwb_begin_step_batch3)
            }
            _ => None,
        };
        let now = self.now;
        let b = &mut self.b;
        let deadline = match region {
            Some(r) => measure(r, || b.stepper_tick(now)),
            None => b.stepper_tick(now),
        };
        let pulsed = self.b.take_pulsed();
        if region.is_some() {
            assert_eq!(pulsed, due, "a measured wake-up issued other steps");
        }
        for a in 0..CHANNELS {
            if pulsed & (1 << a) != 0 {
                self.k[a] += 1;
                self.s.steps += 1;
            }
        }
        self.s.wakeups += 1;
        assert!(
            deadline > now,
            "the stepper task returned a deadline in the past"
        );
        self.next_tick = deadline;
    }

    fn next_dither(&mut self) -> u16 {
        // A 32-bit LCG (Numerical Recipes); the top bits give 0..=3 counts.
        self.dither = self
            .dither
            .wrapping_mul(1_664_525)
            .wrapping_add(1_013_904_223);
        (self.dither >> 30) as u16
    }

    /// One pass of the sampler task's loop.
    fn convert(&mut self) {
        let v = self.b.volumes();
        let mut raw = [0u16; CHANNELS];
        for ch in 0..CHANNELS {
            raw[ch] = (ZERO_COUNTS + COUNTS_PER_MM3 * v[ch]) as u16 + self.next_dither();
        }
        let completes = (self.s.conversions + 1).is_multiple_of(OVERSAMPLE);
        self.s.conversions += 1;
        let now = self.now;
        let b = &mut self.b;
        let mut op = || b.conversion(raw, now);
        let region = match (self.measure_conv, completes) {
            (Measure::Off, _) => None,
            (_, false) => Some(fwb_begin_oversample as extern "C" fn()),
            (Measure::Bare, true) => Some(fwb_begin_frame as extern "C" fn()),
            (Measure::Rls, true) => Some(fwb_begin_frame_rls as extern "C" fn()),
            (Measure::Chain, true) => Some(fwb_begin_frame_chain as extern "C" fn()),
        };
        let frame = match region {
            Some(r) => measure(r, op),
            None => op(),
        };
        // Chambers whose RLS ran its drift check on this frame, and how many of those checks
        // were not the chamber's first (which only takes the baseline).
        let (mut checks, mut later) = (0u32, 0u32);
        let mut vdot = [0.0; CHANNELS];
        if let Some(f) = &frame {
            vdot = f.vdot();
            for (ch, updated) in self.b.rls_updated(f).into_iter().enumerate() {
                if updated && self.rls_on[ch] {
                    self.rls_updates[ch] += 1;
                    if self.rls_updates[ch].is_multiple_of(DRIFT_WINDOW) {
                        checks += 1;
                        later += u32::from(self.rls_updates[ch] > DRIFT_WINDOW);
                    }
                }
            }
            if checks > 0 && self.measure_conv == Measure::Rls {
                fwb_retag_frame_rls_drift();
                self.s.drift_frames += 1;
            }
        }
        assert_eq!(frame.is_some(), completes, "frame boundary");
        let sent = frame.is_some();
        if let Some(mut f) = frame {
            self.s.frames += 1;
            self.send(&mut f);
        }
        self.b.send_events();
        // The host reads the channel: the frame line and the event lines arrived whole.
        let tlm = self.b.read_telemetry();
        assert_eq!(tlm.frames, u32::from(sent), "frame lines read back");
        assert_eq!(self.b.drops(), 0, "telemetry lines dropped");
        assert_eq!(
            self.b.read_serial(),
            u32::from(sent),
            "serial frames read back"
        );
        assert_eq!(self.b.serial_drops(), 0, "serial packets dropped");
        self.s.event_lines += tlm.events;
        assert!(tlm.faults == 0 && !self.b.faulted(), "fault during the run");
        // Every drift check after a chamber's first warns (threshold 0), one event each; no
        // other frame warns. This checks the retagging above.
        assert_eq!(
            tlm.drift, later,
            "drift events (RLS updates per chamber {:?}, v̇ {:?})",
            self.rls_updates, vdot
        );
    }

    fn send(&mut self, f: &mut FrameOut) {
        if self.measure_conv == Measure::Off {
            self.b.send_frame(f);
            self.b.send_serial_frame(f);
        } else {
            let b = &mut self.b;
            measure(fwb_begin_telemetry_line, || b.send_frame(f));
            measure(fwb_begin_telemetry_packet, || b.send_serial_frame(f));
        }
    }

    /// One command line through the command task, measured as `region`; the reply must be `ok…`.
    fn command(&mut self, region: extern "C" fn(), line: &str) -> Line {
        let mut bytes: Line = String::new();
        assert!(
            Board::checksummed(line, &mut bytes).is_ok() && bytes.push('\n').is_ok(),
            "`{}` does not fit a line",
            line
        );
        let now = self.now;
        let b = &mut self.b;
        let reply = measure(region, || b.command_bytes(bytes.as_bytes(), now));
        let mut out = Line::new();
        let _ = out.push_str(reply.unwrap_or("(no reply)"));
        assert!(
            out.starts_with("ok"),
            "`{}` replied `{}`",
            line,
            out.trim_end()
        );
        self.s.commands += 1;
        // The command woke the stepper task: it re-plans now.
        self.tick();
        out
    }

    /// Run until every axis is idle (and at most `limit_us` more), then one more frame.
    fn finish_move(&mut self, limit_us: u64) {
        let end = self.now + limit_us;
        while self.now < end && !self.b.all_idle() {
            let t = self.now + self.period;
            self.advance(t);
        }
        assert!(self.b.all_idle(), "move did not end");
        let t = self.now + OVERSAMPLE as u64 * self.period;
        self.advance(t);
    }
}

/// The effects of the `frame_chain` phase: the three-effect chain.
const CHAIN: [&str; 3] = [
    "hysteresis 6 0.8 0.1",
    "sensor_lag 0.15",
    "delivery_lag 0.05",
];

/// The model read back from chamber 0 (`model 0 read`, `read coef 0`, `read coef 8`) loaded
/// into chamber `ch` with `effects` (`begin`, `coef 0 …`, `coef 8 …`, an `effect` line each,
/// `commit`).
fn chain_upload(r: &mut Rig, ch: usize, effects: &[&str]) {
    let header = r.command(fwb_begin_cmd_model_read, "model 0 read");
    let c0 = r.command(fwb_begin_cmd_model_read_coef, "model 0 read coef 0");
    let c8 = r.command(fwb_begin_cmd_model_read_coef, "model 0 read coef 8");
    let fields = |reply: &Line| -> Line {
        let mut s = Line::new();
        let _ = s.push_str(reply.trim_end().trim_start_matches("ok").trim());
        s
    };
    let mut line = Line::new();
    let _ = write!(line, "model {ch} begin {}", fields(&header));
    r.command(fwb_begin_cmd_model_begin, &line);
    for (start, c) in [(0, &c0), (8, &c8)] {
        line.clear();
        let _ = write!(line, "model {ch} coef {start} {}", fields(c));
        r.command(fwb_begin_cmd_model_coef, &line);
    }
    for e in effects {
        line.clear();
        let _ = write!(line, "model {ch} effect {e}");
        r.command(fwb_begin_cmd_model_effect, &line);
    }
    line.clear();
    let _ = write!(line, "model {ch} commit");
    r.command(fwb_begin_cmd_model_commit, &line);
}

/// The whole scripted run.
pub fn run(telemetry: UpChannel) -> Summary {
    let mut r = Rig::new(telemetry);

    // 1. Boot and the pressure zero (25 frames at rest).
    r.advance(1_000_000 + r.period / 2);

    // 2. Commands at rest.
    r.command(fwb_begin_cmd_status, "status");
    r.command(fwb_begin_cmd_limit, "limit all 80 550");
    r.command(fwb_begin_cmd_origin, "origin all 100");
    // The model read back and loaded again into chamber 0, bare.
    chain_upload(&mut r, 0, &[]);
    let t = r.now + 2 * r.period;
    r.advance(t);

    // 3. Moves at 50 mm³/s, staggered: single steps, conversions, frames, telemetry (bare
    //    polynomial).
    r.k = [0; CHANNELS];
    r.measure_steps = true;
    r.measure_conv = Measure::Bare;
    for (i, line) in [
        "move 0 106 50 500",
        "move 1 106 50 500",
        "move 2 106 50 500",
    ]
    .into_iter()
    .enumerate()
    {
        if i > 0 {
            let t = r.now + STAGGER_US;
            r.advance(t);
        }
        r.command(fwb_begin_cmd_move, line);
    }
    r.finish_move(1_000_000);

    // 3b. The same model with a three-effect chain on every chamber, a move out and back:
    //     frames with the chain (`frame_chain`); then the bare model back on every chamber.
    r.measure_steps = false;
    r.measure_conv = Measure::Off;
    for ch in 0..CHANNELS {
        chain_upload(&mut r, ch, &CHAIN);
    }
    r.measure_conv = Measure::Chain;
    r.command(fwb_begin_cmd_move, "move all 112 50 500");
    r.finish_move(1_000_000);
    r.command(fwb_begin_cmd_move, "move all 106 50 500");
    r.finish_move(1_000_000);
    r.measure_conv = Measure::Off;
    for ch in 0..CHANNELS {
        chain_upload(&mut r, ch, &[]);
    }
    r.measure_steps = true;

    // 4. RLS on every chamber, a slower move: frames with RLS, drift checks.
    r.measure_conv = Measure::Off;
    r.command(fwb_begin_cmd_rls, "rls 0 on");
    r.command(fwb_begin_cmd_rls, "rls 1 on");
    r.command(fwb_begin_cmd_rls, "rls 2 on 0.995");
    r.rls_on = [true; CHANNELS];
    r.measure_conv = Measure::Rls;
    r.k = [0; CHANNELS];
    r.command(fwb_begin_cmd_move, "move all 116 20 500");
    r.finish_move(2_000_000);
    r.measure_steps = false;
    assert!(r.s.drift_frames >= 2, "too few drift-check frames");
    r.measure_conv = Measure::Off;

    // 5. The protocol started and stopped, and the remaining commands.
    r.command(
        fwb_begin_cmd_run,
        "run all 100 116 2 100 20 30 40 50 60 70 80 90",
    );
    let t = r.now + 30_000;
    r.advance(t);
    r.command(fwb_begin_cmd_status, "status");
    r.command(fwb_begin_cmd_stop, "stop");
    r.command(fwb_begin_cmd_clear, "clear");
    r.command(fwb_begin_cmd_rls, "rls 0 off");
    r.rls_on[0] = false;
    r.command(fwb_begin_cmd_zero, "zero");
    let t = r.now + OVERSAMPLE as u64 * r.period;
    r.advance(t);

    r.s.rig_us = r.now;
    r.s
}
