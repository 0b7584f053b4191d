//! The application: shared state, and the three tasks that drive it.
//!
//! All state lives in one plain [`State`] struct with `&mut self` methods (tested
//! synchronously below). [`Shared`] puts it behind a critical-section mutex and adds the one
//! wake-up signal the tasks need. The tasks are plain generic `async fn`s: the board binary
//! wraps each in an `#[embassy_executor::task]`, the simulator runs them under embassy-time's
//! mock driver.
//!
//! - [`stepper_task`]: sleeps until the earliest planned step instant, re-checks the fault
//!   state and the volume limit, and steps. It also advances the characterisation protocol.
//! - [`sampler_task`]: a `Ticker` at 25 Hz × K oversamples; each oversample reads the ADC and,
//!   under the same lock, the step positions and commanded flows, checks the safety limits
//!   (a fault stops every axis before its next step) and accumulates; every K-th completes a
//!   frame (estimation, telemetry). Feeds the watchdog while the stepper task is alive.
//! - [`command_task`]: reads command lines from the serial port, executes them, replies.

use core::cell::RefCell;
use core::fmt::Write;

use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Ticker, Timer};
use heapless::Deque;
use model_core::poly::{ArHistory, PolyModel, Scaling, Shape, MAX_AR, MAX_TERMS};
use model_core::rls::Rls;
use model_core::stats::KcStats;
use model_core::ModelError;

use crate::board;
use crate::command::{self, AxisSet, Command, LineAssembler, ModelCmd, ReadPart};
use crate::hal::{PressureAdc, SerialPort, Steppers, TelemetrySink, Watchdog, AXES};
use crate::motion::{Motion, MotionConfig, MotionError};
use crate::protocol::{ProtocolPoll, ProtocolRun};
use crate::reset::ResetCause;
use crate::store::{Loaded, Persist};
use crate::telemetry::{ChamberFrame, Event, EventKind, Flags, Frame, LineBuf};

/// Number of parameters the online RLS identifies: the paper's n = 3, m = 2 model.
pub const RLS_PARAMS: usize = 12;

/// Safety limits of one channel.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ChannelLimits {
    /// Pressure limit, kPa.
    pub p_max_kpa: f32,
    /// Syringe capacity: volume must stay in `0..=capacity`, mm³.
    pub capacity_mm3: f32,
}

impl Default for ChannelLimits {
    /// The paper's SBA1 envelope (Table V): 550 mm³, 80 kPa.
    fn default() -> Self {
        Self {
            p_max_kpa: 80.0,
            capacity_mm3: 550.0,
        }
    }
}

/// Everything configurable, with the paper rig's defaults.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Config {
    /// Motion hardware constants and limits.
    pub motion: MotionConfig,
    /// Frame rate, Hz (25 in the paper).
    pub frame_hz: u32,
    /// ADC conversions averaged per frame (the oversampling period must be whole ms).
    pub oversample: u32,
    /// Frames averaged for the pressure zero.
    pub zero_frames: u32,
    /// Per-channel safety limits.
    pub limits: [ChannelLimits; AXES],
    /// Largest plausible change between two conversions of one channel, kPa.
    pub sensor_jump_kpa: f32,
    /// Flow used when a `move` gives none, mm³/s.
    pub default_flow: f32,
    /// Acceleration used when a command gives none, mm³/s².
    pub default_accel: f32,
    /// Effective area per chamber for the force estimate, mm² (22 in the paper).
    pub area_mm2: [f32; AXES],
    /// RLS forgetting factor when `rls <ch> on` gives none.
    pub rls_lambda: f32,
    /// RLS initial covariance scale (scaled-coefficient units).
    pub rls_p0: f32,
    /// RLS updates only while |v̇| exceeds this, mm³/s (the chamber is moving).
    pub rls_min_flow: f32,
    /// RLS updates between two drift checks of k̄/c̄.
    pub drift_window: u32,
    /// Relative change of k̄ or c̄ from the first check that raises a drift warning.
    pub drift_frac: f32,
    /// The watchdog is fed only while the stepper task ran within this many µs.
    pub stepper_stale_us: u64,
    /// Why the board last reset (the binary reads it from the reset flags and the crash
    /// record, [`crate::reset`]).
    pub reset_cause: ResetCause,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            motion: MotionConfig::default(),
            frame_hz: 25,
            oversample: 8,
            zero_frames: 25,
            limits: [ChannelLimits::default(); AXES],
            sensor_jump_kpa: 15.0,
            default_flow: 50.0,
            default_accel: 500.0,
            area_mm2: model_core::force::DEFAULT_AREAS_MM2,
            rls_lambda: 0.999,
            rls_p0: 10.0,
            rls_min_flow: 1.0,
            drift_window: 250,
            drift_frac: 0.2,
            stepper_stale_us: 500_000,
            reset_cause: ResetCause::PowerOn,
        }
    }
}

impl Config {
    /// Oversampling period, µs.
    pub fn oversample_period_us(&self) -> u64 {
        1_000_000 / (self.frame_hz as u64 * self.oversample as u64)
    }
}

/// Why a command was refused after parsing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CommandError {
    /// A fault is latched: `clear` first.
    Faulted,
    /// An axis is moving, or the zero is being taken.
    Busy,
    /// Target outside `0..=capacity`, a rate above the firmware's maximum, or a coefficient
    /// index past the staged model's shape.
    OutOfRange,
    /// The word `index` of the line (a `model … read` index) is past the installed model's
    /// shape: the same reply as the parser's [`command::ParseError::OutOfRange`].
    OutOfRangeArg {
        /// Word index.
        index: u8,
    },
    /// `model … coef/ar/commit` without a matching `begin` on that channel.
    NoStagedModel,
    /// `commit` before every coefficient was sent.
    Incomplete,
    /// The model was refused by model-core.
    Model(ModelError),
    /// RLS needs a model with exactly [`RLS_PARAMS`] parameters.
    RlsShape,
    /// The axis' position is unknown since the last reset: `origin` first.
    OriginNeeded,
}

impl CommandError {
    fn code(&self) -> &'static str {
        match self {
            Self::Faulted => "faulted",
            Self::Busy => "busy",
            Self::OutOfRange | Self::OutOfRangeArg { .. } => "out-of-range",
            Self::NoStagedModel => "no-staged-model",
            Self::Incomplete => "incomplete-model",
            Self::Model(_) => "bad-model",
            Self::RlsShape => "rls-shape",
            Self::OriginNeeded => "origin-needed",
        }
    }
}

impl core::fmt::Display for CommandError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.code())?;
        match self {
            Self::Model(e) => write!(f, " {e}"),
            Self::OutOfRangeArg { index } => write!(f, " {index}"),
            _ => Ok(()),
        }
    }
}

impl From<MotionError> for CommandError {
    fn from(e: MotionError) -> Self {
        match e {
            MotionError::Busy => Self::Busy,
            MotionError::OutOfRange | MotionError::BadRate => Self::OutOfRange,
        }
    }
}

/// A model being received over the serial port.
#[derive(Clone, Copy, Debug)]
struct Staged {
    ch: u8,
    shape: Shape,
    scaling: Scaling,
    coef: [f32; MAX_TERMS],
    ar: [f32; 2 * MAX_AR],
    /// Bit i set when coefficient i arrived (poly terms, then AR values from bit 64).
    got: u128,
}

/// Online identification state of one chamber.
#[derive(Clone, Debug)]
struct Online {
    rls: Rls<RLS_PARAMS>,
    frames: u32,
    baseline: Option<(f32, f32)>,
}

/// Estimation state of one chamber.
#[derive(Clone, Debug)]
struct Chamber {
    model: PolyModel,
    hist: ArHistory,
    online: Option<Online>,
}

/// Running sums for the frame being sampled.
#[derive(Clone, Copy, Debug, Default)]
struct FrameAcc {
    n: u32,
    t_sum: u64,
    counts: [u32; AXES],
    steps: [i64; AXES],
    flow: [f32; AXES],
}

/// Largest number of queued event lines.
const EVENT_QUEUE: usize = 8;

/// The whole application state.
#[derive(Debug)]
pub struct State {
    cfg: Config,
    motion: Motion,
    protocol: Option<ProtocolRun>,
    /// Latched faults plus the STOPPED bit.
    latched: u32,
    /// Current (non-latching) warnings.
    warnings: u32,
    zero_kpa: [f32; AXES],
    zeroing: Option<(u32, [f32; AXES])>,
    last_kpa: [Option<f32>; AXES],
    acc: FrameAcc,
    seq: u32,
    chambers: [Chamber; AXES],
    staged: Option<Staged>,
    events: Deque<Event, EVENT_QUEUE>,
    stepper_seen_us: u64,
    /// The committed models against their flash copies.
    store: Persist,
}

impl State {
    /// Boot state: axes at volume 0, SBA1 model on every chamber, pressure zero pending.
    pub fn new(cfg: Config) -> Self {
        let chamber = Chamber {
            model: model_core::poly::sba1(),
            hist: ArHistory::new(),
            online: None,
        };
        let mut s = Self {
            motion: Motion::new(cfg.motion),
            protocol: None,
            latched: if cfg.reset_cause.is_fault() {
                Flags::FAULT_RESET
            } else {
                0
            },
            warnings: Flags::NOT_ZEROED
                | if cfg.reset_cause.positions_trusted() {
                    0
                } else {
                    Flags::ORIGIN_NEEDED * 0b111
                },
            zero_kpa: [0.0; AXES],
            zeroing: Some((cfg.zero_frames, [0.0; AXES])),
            last_kpa: [None; AXES],
            acc: FrameAcc::default(),
            seq: 0,
            chambers: [chamber.clone(), chamber.clone(), chamber],
            staged: None,
            events: Deque::new(),
            stepper_seen_us: 0,
            store: Persist::new(),
            cfg,
        };
        s.event(
            0,
            EventKind::Boot {
                cause: cfg.reset_cause,
            },
        );
        s
    }

    /// Boot: install the models found in flash (or the default, `how` saying why) and report
    /// each channel on a `store` event.
    pub fn restore_models(&mut self, models: &[(PolyModel, Loaded); AXES], now_us: u64) {
        for (ch, (model, how)) in models.iter().enumerate() {
            self.chambers[ch] = Chamber {
                model: *model,
                hist: ArHistory::new(),
                online: None,
            };
            let what = self.store.booted(ch, model, *how);
            let crc = self.store.crc(ch);
            let ch = ch as u8;
            self.event(now_us, EventKind::Store { ch, what, crc });
        }
    }

    /// The model store's state (CRCs, flash status).
    pub fn store(&self) -> &Persist {
        &self.store
    }

    /// Start writing a pending committed model if the board is at rest ([`Persist::begin`]);
    /// motion is refused until [`persist_end`](Self::persist_end).
    pub fn persist_begin(&mut self, now_us: u64) -> Option<(u8, PolyModel)> {
        let at_rest = self.motion.all_idle() && self.protocol.is_none() && self.zeroing.is_none();
        self.store.begin(at_rest, now_us)
    }

    /// The write started by [`persist_begin`](Self::persist_begin) ended.
    pub fn persist_end(&mut self, ch: usize, model: &PolyModel, ok: bool, now_us: u64) {
        let what = self.store.end(ok);
        let crc = crate::store::model_crc(model);
        let ch = ch as u8;
        self.event(now_us, EventKind::Store { ch, what, crc });
    }

    /// The configuration.
    pub fn config(&self) -> &Config {
        &self.cfg
    }
    /// The motion planner (read-only).
    pub fn motion(&self) -> &Motion {
        &self.motion
    }
    /// Current flags: latched faults, STOPPED and warnings.
    pub fn flags(&self) -> Flags {
        Flags(self.latched | self.warnings | self.store.flags())
    }
    /// The model of a chamber.
    pub fn model(&self, ch: usize) -> &PolyModel {
        &self.chambers[ch].model
    }
    /// Pressure zero offsets, kPa.
    pub fn zero_kpa(&self) -> [f32; AXES] {
        self.zero_kpa
    }
    /// Next queued event line, oldest first.
    pub fn pop_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }

    fn event(&mut self, t_us: u64, kind: EventKind) {
        // A full queue drops the new event: events are also reflected in every frame's flags.
        let _ = self.events.push_back(Event { t_us, kind });
    }

    fn capacity_steps(&self) -> [i32; AXES] {
        core::array::from_fn(|a| self.motion.volume_to_steps(self.cfg.limits[a].capacity_mm3))
    }

    /// Latch fault bits; stops every axis and the protocol at once.
    pub fn raise(&mut self, bits: u32, t_us: u64) {
        let new = bits & !self.latched;
        if new == 0 {
            return;
        }
        self.latched |= bits;
        self.motion.stop_all();
        self.protocol = None;
        self.event(
            t_us,
            EventKind::Fault {
                flags: self.latched,
            },
        );
    }

    fn motion_allowed(&self) -> bool {
        self.latched & Flags::FAULT_MASK == 0
    }

    // ---------------------------------------------------------------- stepper side

    /// Called by the stepper task on every wake-up: heartbeat, DIR changes to write now,
    /// protocol progress. Returns what to wait for: the next step `(axis, instant µs)`, or a
    /// wake-up instant with nothing to step.
    pub fn stepper_poll(
        &mut self,
        now_us: u64,
        mut set_dir: impl FnMut(usize, crate::hal::Direction),
    ) -> StepperWait {
        self.stepper_seen_us = now_us;
        // A leg can be empty (already at its target): then the protocol moves on at once,
        // a bounded number of legs per wake-up.
        for _ in 0..4 {
            let Some(run) = &mut self.protocol else { break };
            let caps = core::array::from_fn(|a| {
                self.motion.volume_to_steps(self.cfg.limits[a].capacity_mm3)
            });
            match run.poll(&mut self.motion, caps, now_us) {
                Ok(ProtocolPoll::Moving) => {
                    if run.axes().iter().any(|a| !self.motion.is_idle(a)) {
                        break;
                    }
                }
                Ok(ProtocolPoll::WaitUntil(t)) => {
                    while let Some((a, d)) = self.motion.take_direction_change(now_us) {
                        set_dir(a, d);
                    }
                    return StepperWait::Until(t);
                }
                Ok(ProtocolPoll::Done) => {
                    self.protocol = None;
                    self.event(now_us, EventKind::ProtocolDone);
                }
                Err(_) => {
                    // Limits changed under the protocol: stop it, keep what was done.
                    self.motion.stop_all();
                    self.protocol = None;
                    self.latched |= Flags::STOPPED;
                }
            }
        }
        if self.protocol.is_some() && self.motion.all_idle() {
            return StepperWait::Until(now_us);
        }
        while let Some((a, d)) = self.motion.take_direction_change(now_us) {
            set_dir(a, d);
        }
        match self.motion.next_step() {
            Some((axis, at)) => StepperWait::Step { axis, at_us: at },
            None => StepperWait::Idle,
        }
    }

    /// Called at a step's instant: re-checks faults and the volume limit, then records the
    /// step. `false` means do not pulse (fault, stop, or the plan changed meanwhile).
    pub fn try_step(&mut self, axis: usize, at_us: u64) -> bool {
        if self.motion.next_step() != Some((axis, at_us)) {
            return false;
        }
        if !self.motion_allowed() {
            self.motion.stop_all();
            return false;
        }
        if let Some(next) = self.motion.position_after_next_step(axis) {
            if !(0..=self.capacity_steps()[axis]).contains(&next) {
                self.raise(Flags::channel(Flags::VOLUME_LIMIT, axis), at_us);
                return false;
            }
        }
        self.motion.record_step(axis);
        true
    }

    // ---------------------------------------------------------------- sampler side

    /// One oversample: raw conversions taken at `t_us`. Checks the safety limits on each
    /// conversion (latching a fault stops motion before any further step) and returns the
    /// frame when this was the K-th oversample.
    pub fn on_oversample(&mut self, raw: [u16; AXES], t_us: u64) -> Option<Frame> {
        let mut bits = 0;
        for ch in 0..AXES {
            let kpa = board::counts_to_kpa(raw[ch] as f32);
            if board::at_rail(raw[ch]) {
                bits |= Flags::channel(Flags::SENSOR_RAIL, ch);
            } else {
                if let Some(prev) = self.last_kpa[ch] {
                    if libm::fabsf(kpa - prev) > self.cfg.sensor_jump_kpa {
                        bits |= Flags::channel(Flags::SENSOR_JUMP, ch);
                    }
                }
                self.last_kpa[ch] = Some(kpa);
                if kpa - self.zero_kpa[ch] > self.cfg.limits[ch].p_max_kpa {
                    bits |= Flags::channel(Flags::OVER_PRESSURE, ch);
                }
            }
            let pos = self.motion.position(ch);
            if !(0..=self.capacity_steps()[ch]).contains(&pos) {
                bits |= Flags::channel(Flags::VOLUME_LIMIT, ch);
            }
        }
        if bits != 0 {
            self.raise(bits, t_us);
        }
        let acc = &mut self.acc;
        acc.n += 1;
        acc.t_sum += t_us;
        for ch in 0..AXES {
            acc.counts[ch] += raw[ch] as u32;
            acc.steps[ch] += self.motion.position(ch) as i64;
            acc.flow[ch] += self.motion.flow_at(ch, t_us);
        }
        if acc.n < self.cfg.oversample {
            return None;
        }
        let acc = core::mem::take(&mut self.acc);
        Some(self.finish_frame(&acc))
    }

    fn finish_frame(&mut self, acc: &FrameAcc) -> Frame {
        let n = acc.n as f32;
        let t_us = acc.t_sum / acc.n as u64;
        let step = self.cfg.motion.mm3_per_step;
        let mut raw_kpa = [0.0; AXES];
        let mut chambers = [ChamberFrame::default(); AXES];
        for ch in 0..AXES {
            raw_kpa[ch] = board::counts_to_kpa(acc.counts[ch] as f32 / n);
            chambers[ch].v = (acc.steps[ch] as f64 / acc.n as f64) as f32 * step;
            chambers[ch].vdot = acc.flow[ch] / n;
        }
        // The frame that completes the zero is reported zeroed (its flags no longer say
        // NOT_ZEROED, so its pressure must not be raw).
        self.update_zero(raw_kpa, t_us);
        for ch in 0..AXES {
            chambers[ch].p = raw_kpa[ch] - self.zero_kpa[ch];
        }
        self.warnings &= !(Flags::MODEL_RANGE * 0b111);
        for (ch, c) in chambers.iter_mut().enumerate() {
            if let Err(flag) = self.estimate(ch, c, t_us) {
                self.warnings |= flag;
            }
        }
        let residual = core::array::from_fn(|ch| chambers[ch].residual);
        let force_n = model_core::force::estimate(residual, self.cfg.area_mm2)
            .map_or(f32::NAN, |f| f.total_n);
        let frame = Frame {
            seq: self.seq,
            t_us,
            flags: self.flags(),
            force_n,
            chambers,
        };
        self.seq = self.seq.wrapping_add(1);
        frame
    }

    fn update_zero(&mut self, raw_kpa: [f32; AXES], t_us: u64) {
        let Some((left, sum)) = &mut self.zeroing else {
            return;
        };
        for ch in 0..AXES {
            sum[ch] += raw_kpa[ch];
        }
        *left = left.saturating_sub(1);
        if *left == 0 {
            let n = self.cfg.zero_frames.max(1) as f32;
            let offset = sum.map(|s| s / n);
            self.zero_kpa = offset;
            self.zeroing = None;
            self.warnings &= !Flags::NOT_ZEROED;
            self.event(t_us, EventKind::Zeroed { offset_kpa: offset });
        }
    }

    /// P̂, residual, k, c for one chamber; the RLS update and drift check when online.
    fn estimate(&mut self, ch: usize, c: &mut ChamberFrame, t_us: u64) -> Result<(), u32> {
        let range = Flags::channel(Flags::MODEL_RANGE, ch);
        let cfg = self.cfg;
        let chamber = &mut self.chambers[ch];
        let eval = if chamber.model.shape().p == 0 {
            chamber.model.eval(c.v, c.vdot)
        } else {
            chamber.model.eval_ar(c.v, c.vdot, &chamber.hist)
        };
        let result = match eval {
            Ok(e) => {
                c.p_hat = e.p;
                c.residual = c.p - e.p;
                c.k = e.k;
                c.c = e.c;
                Ok(())
            }
            Err(_) => {
                // Outside the model's range (or history still filling): report NaN, not a guess.
                c.p_hat = f32::NAN;
                c.residual = f32::NAN;
                c.k = f32::NAN;
                c.c = f32::NAN;
                Err(range)
            }
        };
        let drift = chamber
            .online
            .as_mut()
            .and_then(|online| online_update(online, &mut chamber.model, &chamber.hist, c, &cfg));
        chamber.hist.push(c.v, c.vdot);
        if let Some((k_mean, c_mean, k_base, c_base)) = drift {
            self.warnings |= Flags::channel(Flags::DRIFT, ch);
            self.event(
                t_us,
                EventKind::Drift {
                    ch: ch as u8,
                    k_mean,
                    c_mean,
                    k_base,
                    c_base,
                },
            );
        }
        result
    }

    // ---------------------------------------------------------------- commands

    /// Execute a parsed command at `now_us`, writing the reply's fields after `ok` into `out`.
    pub fn execute(
        &mut self,
        cmd: &Command,
        now_us: u64,
        out: &mut impl Write,
    ) -> Result<(), CommandError> {
        self.store.note_command(now_us);
        match cmd {
            Command::Move {
                axes,
                volume,
                flow,
                accel,
            } => {
                self.check_can_move(*axes)?;
                let flow = flow.unwrap_or(self.cfg.default_flow);
                let accel = accel.unwrap_or(self.cfg.default_accel);
                let caps = self.capacity_steps();
                let target = self.volume_target(*volume)?;
                // Validate every axis before starting any, so a refused command moves nothing.
                let mut probe = self.motion.clone();
                for a in axes.iter() {
                    probe.start_move(a, target, caps[a], flow, accel, now_us)?;
                }
                self.motion = probe;
                self.latched &= !Flags::STOPPED;
            }
            Command::Run(spec) => {
                self.check_can_move(spec.axes)?;
                let caps = self.capacity_steps();
                let hi = self.volume_target(spec.v_high)?;
                let lo = self.volume_target(spec.v_low)?;
                let max_flow = self.cfg.motion.max_flow;
                if hi <= lo
                    || spec.axes.iter().any(|a| hi > caps[a] || lo < 0)
                    || spec.flows.iter().any(|&f| f > max_flow)
                {
                    return Err(CommandError::OutOfRange);
                }
                if spec.axes.iter().any(|a| !self.motion.is_idle(a)) {
                    return Err(CommandError::Busy);
                }
                self.protocol = Some(ProtocolRun::new(spec.clone(), self.cfg.default_accel));
                self.latched &= !Flags::STOPPED;
            }
            Command::Stop => {
                self.motion.stop_all();
                self.protocol = None;
                self.latched |= Flags::STOPPED;
            }
            Command::Clear => {
                self.latched = 0;
                self.warnings &= !(Flags::DRIFT * 0b111);
                // Re-arm the jump check from the next conversion.
                self.last_kpa = [None; AXES];
                self.event(now_us, EventKind::Cleared);
            }
            Command::Zero => {
                if !self.motion.all_idle() || self.protocol.is_some() {
                    return Err(CommandError::Busy);
                }
                self.zeroing = Some((self.cfg.zero_frames, [0.0; AXES]));
                self.warnings |= Flags::NOT_ZEROED;
            }
            Command::Status => self.status(out),
            Command::Limit {
                axes,
                p_max_kpa,
                capacity_mm3,
            } => {
                let steps = self.motion.volume_to_steps(*capacity_mm3);
                if axes.iter().any(|a| self.motion.position(a) > steps) {
                    // Current volume already beyond the new capacity: refuse, do not fault.
                    return Err(CommandError::OutOfRange);
                }
                for a in axes.iter() {
                    self.cfg.limits[a] = ChannelLimits {
                        p_max_kpa: *p_max_kpa,
                        capacity_mm3: *capacity_mm3,
                    };
                }
            }
            Command::Origin { axes, volume } => {
                if self.protocol.is_some() || axes.iter().any(|a| !self.motion.is_idle(a)) {
                    return Err(CommandError::Busy);
                }
                let steps = self.volume_target(*volume)?;
                if axes.iter().any(|a| steps > self.capacity_steps()[a]) {
                    return Err(CommandError::OutOfRange);
                }
                for a in axes.iter() {
                    self.motion.set_position(a, steps)?;
                    self.chambers[a].hist.clear();
                    self.warnings &= !Flags::channel(Flags::ORIGIN_NEEDED, a);
                }
            }
            Command::Model { ch, cmd } => self.model_cmd(*ch, cmd, now_us, out)?,
            Command::Rls { ch, lambda } => {
                let ch = *ch as usize;
                match lambda {
                    None => self.chambers[ch].online = None,
                    Some(l) => {
                        let model = &self.chambers[ch].model;
                        if model.shape().params() != RLS_PARAMS {
                            return Err(CommandError::RlsShape);
                        }
                        let mut theta = [0.0; RLS_PARAMS];
                        model.params(&mut theta).map_err(CommandError::Model)?;
                        let lambda = l.unwrap_or(self.cfg.rls_lambda);
                        let mut rls =
                            Rls::new(lambda, self.cfg.rls_p0).map_err(CommandError::Model)?;
                        rls.set_coeffs(&theta).map_err(CommandError::Model)?;
                        self.chambers[ch].online = Some(Online {
                            rls,
                            frames: 0,
                            baseline: None,
                        });
                    }
                }
                let on = self.chambers[ch].online.is_some();
                let bit = Flags::channel(Flags::RLS_ACTIVE, ch);
                self.warnings = if on {
                    self.warnings | bit
                } else {
                    self.warnings & !(bit | Flags::channel(Flags::DRIFT, ch))
                };
            }
        }
        Ok(())
    }

    fn check_can_move(&self, axes: AxisSet) -> Result<(), CommandError> {
        if !self.motion_allowed() {
            return Err(CommandError::Faulted);
        }
        if self.zeroing.is_some() || self.protocol.is_some() || self.store.writing() {
            return Err(CommandError::Busy);
        }
        if axes
            .iter()
            .any(|a| self.warnings & Flags::channel(Flags::ORIGIN_NEEDED, a) != 0)
        {
            return Err(CommandError::OriginNeeded);
        }
        if axes.iter().any(|a| !self.motion.is_idle(a)) {
            return Err(CommandError::Busy);
        }
        Ok(())
    }

    fn volume_target(&self, volume: f32) -> Result<i32, CommandError> {
        let steps = volume / self.cfg.motion.mm3_per_step;
        if !(steps.is_finite() && (0.0..=i32::MAX as f32 / 2.0).contains(&libm::roundf(steps))) {
            return Err(CommandError::OutOfRange);
        }
        Ok(self.motion.volume_to_steps(volume))
    }

    fn status(&self, out: &mut impl Write) {
        let moving = (0..AXES).fold(0u8, |m, a| m | (u8::from(!self.motion.is_idle(a)) << a));
        let _ = write!(
            out,
            " flags {} seq {} moving {} run {} v",
            self.flags().0,
            self.seq,
            moving,
            u8::from(self.protocol.is_some())
        );
        for a in 0..AXES {
            let _ = write!(out, " {}", self.motion.volume(a));
        }
        let _ = out.write_str(" pmax");
        for l in &self.cfg.limits {
            let _ = write!(out, " {}", l.p_max_kpa);
        }
        let _ = out.write_str(" cap");
        for l in &self.cfg.limits {
            let _ = write!(out, " {}", l.capacity_mm3);
        }
        let _ = out.write_str(" crc");
        for ch in 0..AXES {
            let _ = write!(out, " {:#010x}", self.store.crc(ch));
        }
        let _ = out.write_str(" store");
        for ch in 0..AXES {
            let _ = write!(out, " {}", self.store.saved(ch).name());
        }
    }

    /// `model <ch> read …`: the installed model's values, each printed so that it parses back
    /// to the same `f32` (at most 8 values, well inside [`REPLY_LEN`]).
    fn read_model(
        &self,
        ch: usize,
        part: ReadPart,
        out: &mut impl Write,
    ) -> Result<(), CommandError> {
        let model = &self.chambers[ch].model;
        let (values, start) = match part {
            ReadPart::Header => {
                let (sh, sc) = (model.shape(), model.scaling());
                let _ = write!(out, " {} {} {}", sh.n, sh.m, sh.p);
                for x in [sc.v_offset, sc.v_scale, sc.f_offset, sc.f_scale] {
                    let _ = crate::telemetry::num(out, x);
                }
                return Ok(());
            }
            ReadPart::Coef { start } => (model.scaled(), start as usize),
            ReadPart::Ar { start } => (model.ar().as_flattened(), start as usize),
            ReadPart::Crc => {
                let st = &self.store;
                let _ = write!(out, " {:#010x} {}", st.crc(ch), st.saved(ch).name());
                return Ok(());
            }
        };
        // The index is word 4 of `model <ch> read coef|ar <index>`.
        let chunk = values
            .get(start..)
            .filter(|v| !v.is_empty())
            .ok_or(CommandError::OutOfRangeArg { index: 4 })?;
        for &x in chunk.iter().take(command::MAX_CHUNK) {
            let _ = crate::telemetry::num(out, x);
        }
        Ok(())
    }

    fn model_cmd(
        &mut self,
        ch: u8,
        cmd: &ModelCmd,
        now_us: u64,
        out: &mut impl Write,
    ) -> Result<(), CommandError> {
        match cmd {
            ModelCmd::Begin { n, m, p, scaling } => {
                let shape = Shape::new(*n, *m, *p).map_err(CommandError::Model)?;
                let [vo, vs, fo, fs] = *scaling;
                let scaling = Scaling::new(vo, vs, fo, fs).map_err(CommandError::Model)?;
                self.staged = Some(Staged {
                    ch,
                    shape,
                    scaling,
                    coef: [0.0; MAX_TERMS],
                    ar: [0.0; 2 * MAX_AR],
                    got: 0,
                });
            }
            ModelCmd::Coef { start, values } | ModelCmd::Ar { start, values } => {
                let is_ar = matches!(cmd, ModelCmd::Ar { .. });
                let st = self.staged.as_mut().filter(|s| s.ch == ch);
                let st = st.ok_or(CommandError::NoStagedModel)?;
                let (len, base) = if is_ar {
                    (2 * st.shape.p as usize, 64)
                } else {
                    (st.shape.poly_terms(), 0)
                };
                let start = *start as usize;
                if start + values.len() > len {
                    return Err(CommandError::OutOfRange);
                }
                let dst = if is_ar {
                    &mut st.ar[..]
                } else {
                    &mut st.coef[..]
                };
                dst[start..start + values.len()].copy_from_slice(values);
                for i in start..start + values.len() {
                    st.got |= 1u128 << (base + i);
                }
            }
            ModelCmd::Commit => {
                let st = self.staged.filter(|s| s.ch == ch);
                let st = st.ok_or(CommandError::NoStagedModel)?;
                let terms = st.shape.poly_terms();
                let ar_len = 2 * st.shape.p as usize;
                let want = low_bits(terms) | (low_bits(ar_len) << 64);
                if st.got != want {
                    return Err(CommandError::Incomplete);
                }
                let mut pairs = [[0.0f32; 2]; MAX_AR];
                for (k, pair) in pairs.iter_mut().enumerate().take(st.shape.p as usize) {
                    *pair = [st.ar[2 * k], st.ar[2 * k + 1]];
                }
                let model = PolyModel::from_scaled(
                    st.shape,
                    &st.coef[..terms],
                    &pairs[..st.shape.p as usize],
                    st.scaling,
                )
                .map_err(CommandError::Model)?;
                self.install(ch as usize, model, now_us);
                self.staged = None;
            }
            ModelCmd::Default => self.install(ch as usize, model_core::poly::sba1(), now_us),
            ModelCmd::Read(part) => self.read_model(ch as usize, *part, out)?,
        }
        Ok(())
    }

    fn install(&mut self, ch: usize, model: PolyModel, now_us: u64) {
        self.store.committed(ch, &model);
        self.chambers[ch] = Chamber {
            model,
            hist: ArHistory::new(),
            online: None,
        };
        self.warnings &=
            !(Flags::channel(Flags::RLS_ACTIVE, ch) | Flags::channel(Flags::DRIFT, ch));
        self.event(now_us, EventKind::ModelLoaded { ch: ch as u8 });
    }

    /// Whether the watchdog may be fed at `now_us` (the stepper task is alive).
    pub fn stepper_alive(&self, now_us: u64) -> bool {
        now_us.saturating_sub(self.stepper_seen_us) <= self.cfg.stepper_stale_us
    }
}

fn low_bits(n: usize) -> u128 {
    if n == 0 {
        0
    } else {
        u128::MAX >> (128 - n)
    }
}

/// One RLS update of a moving, force-free chamber; every `drift_window` updates the model's
/// mean stiffness and damping are compared with the first such check. Returns
/// `(k̄, c̄, k̄₀, c̄₀)` when either moved by more than `drift_frac` (relative).
///
/// The RLS regressor is the model's own scaled row φ = [x^i y^j …] and the measurement is the
/// zeroed pressure P, so θ converges to the scaled coefficients of the plant (paper Sec. IV-A
/// identifies the same 12 coefficients offline). k̄ and c̄ are averaged over a fixed grid of
/// operating points (the scaling's box, 5 volumes × 3 flows) rather than along the
/// trajectory, so they change only when the model does, not with where the chamber happens
/// to be in its cycle; a softening chamber (an air pocket) lowers both (paper Fig. 6c).
fn online_update(
    online: &mut Online,
    model: &mut PolyModel,
    hist: &ArHistory,
    c: &ChamberFrame,
    cfg: &Config,
) -> Option<(f32, f32, f32, f32)> {
    if libm::fabsf(c.vdot) <= cfg.rls_min_flow || !c.p.is_finite() {
        return None;
    }
    let mut phi = [0.0f32; RLS_PARAMS];
    model.regressors_ar(c.v, c.vdot, hist, &mut phi).ok()?;
    online.rls.update(&phi, c.p).ok()?;
    if let Ok(m) = PolyModel::from_params(model.shape(), online.rls.coeffs(), model.scaling()) {
        *model = m;
    }
    online.frames += 1;
    if online.frames < cfg.drift_window {
        return None;
    }
    online.frames = 0;
    let (k, cc) = grid_kc(model)?;
    match online.baseline {
        None => {
            online.baseline = Some((k, cc));
            None
        }
        Some((k0, c0)) => {
            let off = |x: f32, x0: f32| libm::fabsf(x - x0) > cfg.drift_frac * libm::fabsf(x0);
            (off(k, k0) || off(cc, c0)).then_some((k, cc, k0, c0))
        }
    }
}

/// Mean k and c of a model over its scaling box: v = v₀ + s_v·{−1, −½, 0, ½, 1},
/// v̇ = f₀ + s_f·{−1, 0, 1}.
fn grid_kc(model: &PolyModel) -> Option<(f32, f32)> {
    let sc = model.scaling();
    let mut stats = KcStats::new(0.0).ok()?;
    for xv in [-1.0, -0.5, 0.0, 0.5, 1.0] {
        for yf in [-1.0, 0.0, 1.0] {
            let v = sc.v_offset + xv * sc.v_scale;
            let f = sc.f_offset + yf * sc.f_scale;
            let e = model.eval(v, f).ok()?;
            stats.push(e.k, e.c, f).ok()?;
        }
    }
    Some((stats.k_all.mean()?, stats.c_all.mean()?))
}

/// What the stepper task waits for.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepperWait {
    /// Step `axis` at `at_us`.
    Step {
        /// Axis.
        axis: usize,
        /// Planned instant, µs.
        at_us: u64,
    },
    /// Nothing to step before this instant (protocol dwell).
    Until(u64),
    /// Nothing planned.
    Idle,
}

/// The state shared by the tasks, plus the signal that wakes the stepper task.
pub struct Shared {
    /// All application state; locked briefly (no await inside).
    state: Mutex<CriticalSectionRawMutex, RefCell<State>>,
    /// Wakes the stepper task when the plan changes (new move, stop, fault).
    wake: Signal<CriticalSectionRawMutex, ()>,
}

impl Shared {
    /// Fresh shared state for one board (or one simulation).
    pub fn new(cfg: Config) -> Self {
        Self {
            state: Mutex::new(RefCell::new(State::new(cfg))),
            wake: Signal::new(),
        }
    }

    /// Run `f` on the state under the lock. `f` must not block.
    pub fn lock<R>(&self, f: impl FnOnce(&mut State) -> R) -> R {
        self.state.lock(|s| f(&mut s.borrow_mut()))
    }

    /// Parse and execute one command line, writing the reply line (no terminator) to `out`.
    pub fn command_line(&self, line: &[u8], now_us: u64, out: &mut impl Write) {
        match command::parse(line) {
            Ok(cmd) => self.command(&cmd, now_us, out),
            Err(e) => {
                let _ = write!(out, "err {e}");
            }
        }
    }

    /// Execute a parsed command, writing the reply line to `out`, and wake the stepper task.
    pub fn command(&self, cmd: &Command, now_us: u64, out: &mut impl Write) {
        let mut fields: heapless::String<REPLY_LEN> = heapless::String::new();
        let r = self.lock(|s| s.execute(cmd, now_us, &mut fields));
        self.wake.signal(());
        let _ = match r {
            Ok(()) => write!(out, "ok{fields}"),
            Err(e) => write!(out, "err {e}"),
        };
    }
}

/// Longest reply line (the longest is `status` with every field at its widest, ≈ 230 bytes).
pub const REPLY_LEN: usize = 256;

/// Longest the stepper task sleeps with nothing to do (its heartbeat for the watchdog), µs.
const STEPPER_IDLE_US: u64 = 50_000;

/// Drive the stepper outputs: sleep until the earliest planned step, re-check, step.
///
/// A fault latched by the sampler (or a `stop`) is seen at the next step instant at the
/// latest, before the pulse; the wake signal makes the task re-plan at once.
pub async fn stepper_task<S: Steppers>(shared: &Shared, mut steppers: S) -> ! {
    steppers.set_enabled(true);
    loop {
        let now = Instant::now().as_micros();
        let wait = shared.lock(|s| s.stepper_poll(now, |a, d| steppers.set_direction(a, d)));
        let (deadline, step) = match wait {
            StepperWait::Step { axis, at_us } => (at_us, Some(axis)),
            StepperWait::Until(t) => (t.min(now + STEPPER_IDLE_US), None),
            StepperWait::Idle => (now + STEPPER_IDLE_US, None),
        };
        match select(
            Timer::at(Instant::from_micros(deadline)),
            shared.wake.wait(),
        )
        .await
        {
            Either::First(()) => {
                if let Some(axis) = step {
                    if shared.lock(|s| s.try_step(axis, deadline)) {
                        steppers.step(axis, Instant::from_micros(deadline));
                    }
                }
            }
            Either::Second(()) => {}
        }
    }
}

/// Sample the sensors at 25 Hz × K, check the limits, estimate, and send telemetry.
pub async fn sampler_task<A: PressureAdc, T: TelemetrySink, W: Watchdog>(
    shared: &Shared,
    mut adc: A,
    mut tlm: T,
    mut wdg: W,
) -> ! {
    let period = shared.lock(|s| s.config().oversample_period_us());
    let mut ticker = Ticker::every(Duration::from_micros(period));
    let mut line = LineBuf::new();
    loop {
        ticker.next().await;
        let raw = adc.read().await;
        let now = Instant::now().as_micros();
        let (frame, alive, faulted) = shared.lock(|s| {
            let f = s.on_oversample(raw, now);
            (f, s.stepper_alive(now), s.flags().is_fault())
        });
        if faulted {
            // The stepper re-checks before every pulse anyway; this makes it re-plan now.
            shared.wake.signal(());
        }
        if alive {
            wdg.feed();
        }
        if let Some(frame) = frame {
            line.clear();
            if frame.encode(&mut line).is_ok() {
                tlm.line(&line);
            }
        }
        while let Some(ev) = shared.lock(|s| s.pop_event()) {
            line.clear();
            if ev.encode(&mut line).is_ok() {
                tlm.line(&line);
            }
        }
    }
}

/// Read command lines from the serial port, execute them, reply one line each (`\r\n`).
pub async fn command_task<U: SerialPort>(shared: &Shared, mut port: U) -> ! {
    let mut asm = LineAssembler::new();
    let mut buf = [0u8; 32];
    let mut reply: heapless::String<{ REPLY_LEN + 8 }> = heapless::String::new();
    loop {
        let n = port.read(&mut buf).await.min(buf.len());
        for &b in &buf[..n] {
            let Some(parsed) = asm.push(b) else { continue };
            reply.clear();
            let now = Instant::now().as_micros();
            match parsed {
                Ok(cmd) => shared.command(&cmd, now, &mut reply),
                Err(e) => {
                    let _ = write!(reply, "err {e}");
                }
            }
            let _ = reply.push_str("\r\n");
            port.write_all(reply.as_bytes()).await;
        }
    }
}

#[cfg(test)]
#[path = "app_tests.rs"]
mod tests;
