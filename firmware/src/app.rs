//! The application: its state, split by who needs it how fast, and the four tasks.
//!
//! # Two halves, two kinds of lock
//! - [`Control`], the motion side: the planner, the protocol, latched faults, safety limits, the
//!   event queue. The stepper task needs it at every step, so it sits behind a critical-section
//!   mutex ([`Shared::with_control`]), and every operation done under that lock is O(1) and
//!   short (well under 2,000 instructions): it only hands data over. Step instants, move plans
//!   and protocol profiles are computed outside it.
//! - [`Estimator`], the estimation side: pressure zero, models, staged model, online RLS, drift
//!   statistics, frame counter. Only the sampler task (frame estimation) and the command task
//!   (model and RLS commands) use it, both in thread mode, through an async mutex
//!   ([`Shared::estimator`]) that never keeps interrupts off while it is held.
//!
//! Interrupts are therefore never off for longer than one of [`Control`]'s O(1) operations:
//! estimation, RLS, drift checks and the formatting of replies and telemetry all run with
//! interrupts on.
//!
//! # Per-tick entry points (what the tasks call, and what tests and benchmarks call)
//! | function | called by | under the critical section |
//! | --- | --- | --- |
//! | [`Shared::stepper_tick`] | stepper task, every wake-up | one short lock per batch of steps due at one instant (protocol advance, DIR changes, fault/limit check, recording); the pulses and the wait follow outside it |
//! | [`Shared::conversion`] | sampler task, every ADC conversion | one short lock: safety checks, positions, commanded flows ([`Control::on_conversion`]) |
//! | [`Shared::finish_frame`] | sampler task, every K-th conversion | estimation outside; one short lock to post its events, the new zero and read the latched flags |
//! | [`Sampler::send_frame`], [`Shared::send_events`] | sampler task | formatting and hand-over outside; one short lock per event popped |
//! | [`Shared::command_raw`], [`Shared::execute`] | command task, every line | short locks to check and hand over (a `move` is planned outside, then started in O(1)); replies formatted outside |
//! | [`Shared::persist_begin`], [`Shared::persist_end`] | persist task, every [`PERSIST_POLL_MS`] | one short lock each, around the flash write; the CRC computed outside |
//!
//! The tasks ([`stepper_task`], [`sampler_task`], [`command_task`], and [`persist_task`], which
//! writes committed models to flash at rest) are thin async loops around these synchronous
//! functions. The board binary wraps each in an `#[embassy_executor::task]`; the simulator runs
//! the first three under embassy-time's mock driver (it has no flash).

use core::cell::{Cell, RefCell};
use core::fmt::Write;

use crate::rest_zero::{RestOutcome, RestZero, RestZeroConfig};
use embassy_futures::select::{select, Either};
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::mutex::Mutex as AsyncMutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Ticker, Timer};
use embedded_storage_async::nor_flash::NorFlash;
use heapless::Deque;
use model_core::chain::{Chain, ChainInput, ChainState, Effect, EffectKind};
use model_core::poly::{ArHistory, PolyModel, Scaling, Shape, MAX_AR, MAX_TERMS};
use model_core::rls::Rls;
use model_core::ModelError;

use crate::board;
use crate::command::{
    self, AxisSet, Command, LineAssembler, LinkState, ModelCmd, RawLine, ReadPart,
};
use crate::hal::{Direction, PressureAdc, SerialPort, Steppers, TelemetrySink, Watchdog, AXES};
use crate::motion::{Motion, MotionConfig, MotionError, PlannedMove, StepBatch};
use crate::protocol::{ProtocolPoll, ProtocolRun};
use crate::reset::ResetCause;
use crate::store::{FlashGuard, Loaded, Model, ModelStore, Persist};
use crate::telemetry::{ChamberFrame, Event, EventKind, Flags, Frame, LineBuf};
use crate::wire::{SerialOut, SerialTelemetry};

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
    /// Largest plausible zero, kPa: the sensor's offset tolerance. A channel whose mean at the
    /// zero reads further from 0 kPa than this is not at rest (a syringe pressurised when the
    /// board reset) or not a working sensor: its zero is not taken (it keeps the one it had, the
    /// nominal transfer function's at boot), so the over-pressure limit is not moved by it, and
    /// `NOT_ZEROED` stays set until a `zero` succeeds.
    pub zero_max_kpa: f32,
    /// The zero's drift corrected at rest at the zero's volume ([`crate::rest_zero`]); `None`:
    /// the zero moves only at boot and on `zero`.
    pub rest_zero: Option<RestZeroConfig>,
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
            zero_max_kpa: 5.0,
            rest_zero: Some(RestZeroConfig::default()),
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
    /// The effects received so far (`model <ch> effect …`).
    chain: Chain,
}

/// Online identification state of one chamber.
#[derive(Clone, Debug)]
struct Online {
    rls: Rls<RLS_PARAMS>,
    frames: u32,
    baseline: Option<(f32, f32)>,
}

/// Estimation state of one chamber. `hist` holds the inputs the polynomial saw (after the
/// chain's input transforms); `state` is the chain's, reset at boot, `origin` and model load.
#[derive(Clone, Debug)]
struct Chamber {
    model: PolyModel,
    chain: Chain,
    state: ChainState,
    hist: ArHistory,
    online: Option<Online>,
}

impl Chamber {
    fn new(model: Model, dt: f32) -> Self {
        let mut c = Chamber {
            model: model.poly,
            chain: model.chain,
            state: ChainState::new(),
            hist: ArHistory::new(),
            online: None,
        };
        c.reset_chain(dt);
        c
    }

    /// Boot, `origin`, model load: the chain starts over, its per-frame constants computed here
    /// (outside the frame; a bad `dt` leaves them to the first frame, which then reports it).
    fn reset_chain(&mut self, dt: f32) {
        self.state.reset();
        let _ = self.state.prepare(&self.chain, dt);
    }
}

impl Config {
    /// The frame period, s (the chain's Δt).
    pub fn frame_dt(&self) -> f32 {
        1.0 / self.frame_hz.max(1) as f32
    }
}

/// Largest number of queued event lines.
const EVENT_QUEUE: usize = 8;

/// Events produced by one estimator call, posted to the queue afterwards in one short lock.
pub type EventBuf = heapless::Vec<Event, 4>;

fn push_event(buf: &mut EventBuf, t_us: u64, kind: EventKind) {
    // At most one zero and three drift events per frame, one model event per command.
    let _ = buf.push(Event { t_us, kind });
}

// ==================================================================== motion side

/// What the stepper task waits for after a wake-up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepperWait {
    /// The next step is planned at `at_us`.
    Step {
        /// Planned instant, µs.
        at_us: u64,
    },
    /// Nothing to step before this instant (protocol dwell, or a protocol leg to start now).
    Until(u64),
    /// Nothing planned.
    Idle,
}

/// What one conversion handed over: positions and commanded flows at its instant, and the
/// state the sampler acts on.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Conversion {
    /// Step positions.
    pub positions: [i32; AXES],
    /// Commanded flows at the conversion instant, mm³/s.
    pub flows: [f32; AXES],
    /// A fault is latched (the stepper is woken to re-plan at once).
    pub faulted: bool,
    /// The stepper task ran recently: the watchdog may be fed.
    pub alive: bool,
}

/// What `status` reports from the motion side.
#[derive(Clone, Copy, Debug)]
struct StatusSnapshot {
    flags: u32,
    crc: [u32; AXES],
    saved: [crate::store::Saved; AXES],
    moving: u8,
    run: bool,
    volumes: [f32; AXES],
    limits: [ChannelLimits; AXES],
}

/// The motion side: planner, protocol, latched faults, limits, event queue. Shared with the
/// stepper task under a critical section ([`Shared::with_control`]); every method is O(1).
#[derive(Debug)]
pub struct Control {
    cfg: Config,
    motion: Motion,
    protocol: Option<ProtocolRun>,
    /// Latched faults plus the STOPPED bit.
    latched: u32,
    /// Capacities in steps (from `cfg.limits`).
    cap_steps: [i32; AXES],
    /// The pressure zero in force (the estimator's, posted when it changes).
    zero_kpa: [f32; AXES],
    /// Last conversion per channel (sensor-jump check); cleared by `clear`.
    last_kpa: [Option<f32>; AXES],
    events: Deque<Event, EVENT_QUEUE>,
    /// Events lost to a full queue since the sampler last looked.
    lost_events: u32,
    stepper_seen_us: u64,
    /// Axes whose position is unknown (ORIGIN_NEEDED bits): every axis after any reset, power-on
    /// included (a power cut may have stopped a move anywhere, and a board cannot tell a cold
    /// start from that), until `origin` declares it; motion on them is refused, and `clear` does
    /// not lift them.
    origin_needed: u32,
    /// The estimator is taking the pressure zero (its state, posted here for the checks).
    zeroing: bool,
    /// The committed models against their flash copies.
    store: Persist,
}

impl Control {
    /// Boot state: axes at volume 0, no fault (or the watchdog-reset fault), a boot event.
    pub fn new(cfg: Config) -> Self {
        let motion = Motion::new(cfg.motion);
        let mut c = Self {
            cap_steps: core::array::from_fn(|a| motion.volume_to_steps(cfg.limits[a].capacity_mm3)),
            motion,
            protocol: None,
            latched: if cfg.reset_cause.is_fault() {
                Flags::FAULT_RESET
            } else {
                0
            },
            origin_needed: Flags::ORIGIN_NEEDED * 0b111,
            zeroing: true,
            zero_kpa: [0.0; AXES],
            last_kpa: [None; AXES],
            events: Deque::new(),
            lost_events: 0,
            stepper_seen_us: 0,
            store: Persist::new(),
            cfg,
        };
        c.push_event(Event {
            t_us: 0,
            kind: EventKind::Boot {
                cause: cfg.reset_cause,
            },
        });
        c
    }

    /// The model store's state (CRCs, flash status).
    pub fn store(&self) -> &Persist {
        &self.store
    }

    /// Start writing a pending committed model if the board is at rest (no motion, no
    /// protocol, no zero in progress) and the command port is quiet ([`Persist::begin`]);
    /// motion is refused until [`persist_end`](Self::persist_end). O(1) apart from copying the
    /// model out.
    pub fn persist_begin(&mut self, now_us: u64) -> Option<(u8, Model)> {
        let at_rest = self.motion.all_idle() && self.protocol.is_none() && !self.zeroing;
        self.store.begin(at_rest, now_us)
    }

    /// The write started by [`persist_begin`](Self::persist_begin) ended; `crc` is the
    /// written model's CRC-32 (computed by the caller, outside the lock).
    pub fn persist_end(&mut self, ch: usize, crc: u32, ok: bool, now_us: u64) {
        let what = self.store.end(ok);
        let ch = ch as u8;
        self.push_event(Event {
            t_us: now_us,
            kind: EventKind::Store { ch, what, crc },
        });
    }

    /// Every flag the motion side holds: latched faults and STOPPED, the axes whose position
    /// is unknown, and the store's.
    pub fn flag_bits(&self) -> u32 {
        self.latched | self.origin_needed | self.store.flags()
    }

    /// The configuration, with the limits in force.
    pub fn config(&self) -> &Config {
        &self.cfg
    }
    /// The motion planner (read-only).
    pub fn motion(&self) -> &Motion {
        &self.motion
    }
    /// Latched faults and the STOPPED bit.
    pub fn latched(&self) -> u32 {
        self.latched
    }
    /// Whether the characterisation protocol runs.
    pub fn protocol_running(&self) -> bool {
        self.protocol.is_some()
    }
    /// Next queued event, oldest first.
    pub fn pop_event(&mut self) -> Option<Event> {
        self.events.pop_front()
    }
    /// Events lost to a full queue since the last call.
    pub fn take_lost_events(&mut self) -> u32 {
        core::mem::take(&mut self.lost_events)
    }

    /// Queue an event line; a full queue drops it and counts it (the frame's `drops`).
    pub fn push_event(&mut self, ev: Event) {
        if self.events.push_back(ev).is_err() {
            self.lost_events = self.lost_events.wrapping_add(1);
        }
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
        self.push_event(Event {
            t_us,
            kind: EventKind::Fault {
                flags: self.latched,
            },
        });
    }

    fn motion_allowed(&self) -> bool {
        self.latched & Flags::FAULT_MASK == 0
    }

    /// Whether the watchdog may be fed at `now_us` (the stepper task is alive).
    pub fn stepper_alive(&self, now_us: u64) -> bool {
        now_us.saturating_sub(self.stepper_seen_us) <= self.cfg.stepper_stale_us
    }

    // ---------------------------------------------------------------- stepper side

    /// One stepper wake-up at `now_us`: heartbeat, protocol progress, DIR changes to write
    /// now (through `set_dir`), and the steps due by `now_us` at the earliest planned instant,
    /// all axes due at that instant together, checked (faults, volume limit) and recorded.
    /// Returns that batch, for the caller to pulse after the lock, and what to wait for next.
    pub fn stepper_wake(
        &mut self,
        now_us: u64,
        mut set_dir: impl FnMut(usize, Direction),
    ) -> (Option<StepBatch>, StepperWait) {
        self.stepper_seen_us = now_us;
        let dwell = if self.protocol.is_some() {
            self.poll_protocol(now_us)
        } else {
            None
        };
        while let Some((a, d)) = self.motion.take_direction_change(now_us) {
            set_dir(a, d);
        }
        let batch = match self.motion.next_batch() {
            Some(b) if b.at_us <= now_us => self.take_batch(b),
            _ => None,
        };
        let wait = match (self.motion.next_due_us(), dwell) {
            (Some(at_us), _) => StepperWait::Step { at_us },
            (None, Some(t)) => StepperWait::Until(t),
            // A leg just finished: poll the protocol again now.
            (None, None) if self.protocol.is_some() => StepperWait::Until(now_us),
            (None, None) => StepperWait::Idle,
        };
        (batch, wait)
    }

    /// The characterisation protocol's progress at a stepper wake-up (its next legs started
    /// when due); the instant its dwell ends, if it dwells. Kept out of line: the wake-ups of
    /// plain moves do not pay for it.
    #[inline(never)]
    fn poll_protocol(&mut self, now_us: u64) -> Option<u64> {
        let mut dwell = None;
        // A leg can be empty (already at its target): then the protocol moves on at once,
        // a bounded number of legs per wake-up.
        for _ in 0..4 {
            let Some(run) = &mut self.protocol else { break };
            match run.poll(&mut self.motion, self.cap_steps, now_us) {
                Ok(ProtocolPoll::Moving) => {
                    if run.axes().iter().any(|a| !self.motion.is_idle(a)) {
                        break;
                    }
                }
                Ok(ProtocolPoll::WaitUntil(t)) => {
                    dwell = Some(t);
                    break;
                }
                Ok(ProtocolPoll::Done) => {
                    self.protocol = None;
                    self.push_event(Event {
                        t_us: now_us,
                        kind: EventKind::ProtocolDone,
                    });
                }
                Err(_) => {
                    // Limits changed under the protocol: stop it, keep what was done.
                    self.motion.stop_all();
                    self.protocol = None;
                    self.latched |= Flags::STOPPED;
                }
            }
        }
        dwell
    }

    /// Check and record a batch of steps due now: nothing steps while a fault is latched, and a
    /// step that would leave `0..=capacity` latches the volume-limit fault instead.
    fn take_batch(&mut self, b: StepBatch) -> Option<StepBatch> {
        if !self.motion_allowed() {
            self.motion.stop_all();
            return None;
        }
        match self.motion.record_batch(b.axes, &self.cap_steps) {
            Ok(()) => Some(b),
            Err(a) => {
                self.raise(Flags::channel(Flags::VOLUME_LIMIT, a), b.at_us);
                None
            }
        }
    }

    // ---------------------------------------------------------------- sampler side

    /// One ADC conversion (raw counts taken at `t_us`): the safety checks on every channel
    /// (a fault stops every axis before its next step), then the step positions and commanded
    /// flows at this instant.
    pub fn on_conversion(&mut self, raw: [u16; AXES], t_us: u64) -> Conversion {
        let mut bits = 0;
        for ch in 0..AXES {
            if board::at_rail(raw[ch]) {
                bits |= Flags::channel(Flags::SENSOR_RAIL, ch);
            } else {
                let kpa = board::counts_to_kpa(raw[ch] as f32);
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
            if !(0..=self.cap_steps[ch]).contains(&pos) {
                bits |= Flags::channel(Flags::VOLUME_LIMIT, ch);
            }
        }
        if bits != 0 {
            self.raise(bits, t_us);
        }
        Conversion {
            positions: core::array::from_fn(|a| self.motion.position(a)),
            flows: core::array::from_fn(|a| self.motion.flow_at(a, t_us)),
            faulted: Flags(self.latched).is_fault(),
            alive: self.stepper_alive(t_us),
        }
    }

    // ---------------------------------------------------------------- commands (O(1) parts)

    /// The checks every motion command makes, in order: fault, then zero/protocol, then busy
    /// axes. `zeroing` is the estimator's state.
    fn check_can_move(&self, axes: AxisSet, zeroing: bool) -> Result<(), CommandError> {
        if !self.motion_allowed() {
            return Err(CommandError::Faulted);
        }
        if zeroing || self.protocol.is_some() || self.store.writing() {
            return Err(CommandError::Busy);
        }
        if axes
            .iter()
            .any(|a| self.origin_needed & Flags::channel(Flags::ORIGIN_NEEDED, a) != 0)
        {
            return Err(CommandError::OriginNeeded);
        }
        if axes.iter().any(|a| !self.motion.is_idle(a)) {
            return Err(CommandError::Busy);
        }
        Ok(())
    }

    /// Positions and capacities for planning outside the lock, after the motion checks.
    fn plan_snapshot(
        &self,
        axes: AxisSet,
        zeroing: bool,
    ) -> Result<([i32; AXES], [i32; AXES]), CommandError> {
        self.check_can_move(axes, zeroing)?;
        Ok((
            core::array::from_fn(|a| self.motion.position(a)),
            self.cap_steps,
        ))
    }

    /// Start planned moves (O(1) each) if nothing changed since they were planned.
    fn start_moves(
        &mut self,
        axes: AxisSet,
        plans: &[Option<PlannedMove>; AXES],
        zeroing: bool,
        now_us: u64,
    ) -> Result<(), CommandError> {
        self.check_can_move(axes, zeroing)?;
        if axes
            .iter()
            .any(|a| plans[a].is_none_or(|p| p.from != self.motion.position(a)))
        {
            return Err(CommandError::Busy);
        }
        for a in axes.iter() {
            if let Some(p) = &plans[a] {
                self.motion.start_planned(a, p, now_us)?;
            }
        }
        self.latched &= !Flags::STOPPED;
        Ok(())
    }

    fn start_protocol(
        &mut self,
        run: ProtocolRun,
        positions: &[i32; AXES],
        zeroing: bool,
    ) -> Result<(), CommandError> {
        let axes = run.axes();
        self.check_can_move(axes, zeroing)?;
        if axes.iter().any(|a| positions[a] != self.motion.position(a)) {
            return Err(CommandError::Busy);
        }
        self.protocol = Some(run);
        self.latched &= !Flags::STOPPED;
        Ok(())
    }

    fn stop(&mut self) {
        self.motion.stop_all();
        self.protocol = None;
        self.latched |= Flags::STOPPED;
    }

    fn clear(&mut self, now_us: u64) {
        self.latched = 0;
        // Re-arm the jump check from the next conversion.
        self.last_kpa = [None; AXES];
        self.push_event(Event {
            t_us: now_us,
            kind: EventKind::Cleared,
        });
    }

    /// Whether the stepper drivers may be enabled: not while a fault reset is latched.
    pub fn drivers_allowed(&self) -> bool {
        self.latched & Flags::FAULT_RESET == 0
    }

    fn status_snapshot(&self) -> StatusSnapshot {
        StatusSnapshot {
            flags: self.flag_bits(),
            crc: core::array::from_fn(|ch| self.store.crc(ch)),
            saved: core::array::from_fn(|ch| self.store.saved(ch)),
            moving: (0..AXES).fold(0u8, |m, a| m | (u8::from(!self.motion.is_idle(a)) << a)),
            run: self.protocol.is_some(),
            volumes: core::array::from_fn(|a| self.motion.volume(a)),
            limits: self.cfg.limits,
        }
    }

    fn set_limits(
        &mut self,
        axes: AxisSet,
        limits: ChannelLimits,
        steps: i32,
    ) -> Result<(), CommandError> {
        if axes.iter().any(|a| self.motion.position(a) > steps) {
            // Current volume already beyond the new capacity: refuse, do not fault.
            return Err(CommandError::OutOfRange);
        }
        for a in axes.iter() {
            self.cfg.limits[a] = limits;
            self.cap_steps[a] = steps;
        }
        Ok(())
    }

    /// Declare `axes` at `steps`; the step positions they had before.
    fn set_origin(
        &mut self,
        axes: AxisSet,
        steps: Result<i32, CommandError>,
    ) -> Result<[i32; AXES], CommandError> {
        if self.protocol.is_some() || axes.iter().any(|a| !self.motion.is_idle(a)) {
            return Err(CommandError::Busy);
        }
        let steps = steps?;
        if axes.iter().any(|a| steps > self.cap_steps[a]) {
            return Err(CommandError::OutOfRange);
        }
        let before = core::array::from_fn(|a| self.motion.position(a));
        for a in axes.iter() {
            self.motion.set_position(a, steps)?;
            self.origin_needed &= !Flags::channel(Flags::ORIGIN_NEEDED, a);
        }
        Ok(before)
    }
}

// ==================================================================== estimation side

/// Running sums for the frame being sampled (the sampler's own, no lock).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameAcc {
    n: u32,
    t_sum: u64,
    counts: [u32; AXES],
    steps: [i64; AXES],
    flow: [f32; AXES],
}

impl FrameAcc {
    fn add(&mut self, raw: [u16; AXES], c: &Conversion, t_us: u64) {
        self.n += 1;
        self.t_sum += t_us;
        for ch in 0..AXES {
            self.counts[ch] += raw[ch] as u32;
            self.steps[ch] += c.positions[ch] as i64;
            self.flow[ch] += c.flows[ch];
        }
    }
}

/// The estimation side: pressure zero, models, staged model, online RLS and drift checks, frame
/// counter. Used by the sampler (frames) and the command task (model commands) through
/// [`Shared::estimator`]'s async mutex: nothing here runs with interrupts off.
#[derive(Debug)]
pub struct Estimator {
    cfg: Config,
    zero_kpa: [f32; AXES],
    zeroing: Option<(u32, [f32; AXES])>,
    /// Each chamber's correction of the zero at rest.
    rest: [RestZero; AXES],
    /// Each chamber's load pressure of the last frame, kPa ([`Chain::load_pressure`]).
    load_kpa: [f32; AXES],
    /// Current (non-latching) warnings.
    warnings: u32,
    seq: u32,
    chambers: [Chamber; AXES],
    staged: Option<Staged>,
}

impl Estimator {
    /// Boot state: SBA1 model on every chamber, pressure zero pending.
    pub fn new(cfg: Config) -> Self {
        let chamber = Chamber::new(Model::default_model(), cfg.frame_dt());
        Self {
            zero_kpa: [0.0; AXES],
            zeroing: Some((cfg.zero_frames, [0.0; AXES])),
            rest: [RestZero::default(); AXES],
            load_kpa: [f32::NAN; AXES],
            warnings: Flags::NOT_ZEROED,
            seq: 0,
            chambers: [chamber.clone(), chamber.clone(), chamber],
            staged: None,
            cfg,
        }
    }

    /// The model of a chamber.
    pub fn model(&self, ch: usize) -> &PolyModel {
        &self.chambers[ch].model
    }
    /// The effect chain of a chamber.
    pub fn chain(&self, ch: usize) -> &Chain {
        &self.chambers[ch].chain
    }
    /// The model and chain of a chamber, as committed and stored.
    pub fn full_model(&self, ch: usize) -> Model {
        Model {
            poly: self.chambers[ch].model,
            chain: self.chambers[ch].chain,
        }
    }
    /// Pressure zero offsets, kPa.
    pub fn zero_kpa(&self) -> [f32; AXES] {
        self.zero_kpa
    }
    /// Each chamber's load pressure in the last frame, kPa: its residual with the chain's
    /// sensor lag undone ([`Chain::load_pressure`]); the force is these times the areas.
    pub fn load_kpa(&self) -> [f32; AXES] {
        self.load_kpa
    }
    /// Current warning bits (zero pending, model range, drift, RLS active).
    pub fn warnings(&self) -> u32 {
        self.warnings
    }
    /// Whether the pressure zero is being taken.
    /// Boot: install a model found in flash (or the default), without a `model` event.
    pub fn install_boot(&mut self, ch: usize, model: Model) {
        self.chambers[ch] = Chamber::new(model, self.cfg.frame_dt());
    }

    /// Whether the pressure zero is being taken.
    pub fn zeroing(&self) -> bool {
        self.zeroing.is_some()
    }
    /// Sequence number of the next frame.
    pub fn seq(&self) -> u32 {
        self.seq
    }

    /// Finish a frame from its sums: means, zero, model estimate, residual, k, c, force, and
    /// the RLS update and drift check of online chambers. Integer and `f32` arithmetic. Returns
    /// the frame (its flags hold the warnings only) and the new zero when this frame completed
    /// one; events go to `events`.
    pub fn finish_frame(
        &mut self,
        acc: &FrameAcc,
        events: &mut EventBuf,
    ) -> (Frame, Option<[f32; AXES]>) {
        let n = acc.n.max(1);
        let nf = n as f32;
        let t_us = acc.t_sum / n as u64;
        let step = self.cfg.motion.mm3_per_step;
        let mut raw_kpa = [0.0; AXES];
        let mut chambers = [ChamberFrame::default(); AXES];
        for ch in 0..AXES {
            raw_kpa[ch] = board::counts_to_kpa(acc.counts[ch] as f32 / nf);
            // Mean position: whole part and remainder in integers, so f32 sees only what it
            // holds exactly (the remainder is a multiple of 1/n).
            let (q, r) = (
                acc.steps[ch].div_euclid(n as i64),
                acc.steps[ch].rem_euclid(n as i64),
            );
            chambers[ch].v = (q as f32 + r as f32 / nf) * step;
            chambers[ch].vdot = acc.flow[ch] / nf;
        }
        // The frame that completes the zero is reported zeroed (its flags no longer say
        // NOT_ZEROED, so its pressure must not be raw).
        let new_zero = self.update_zero(raw_kpa, t_us, events);
        if new_zero.is_some() {
            for ch in 0..AXES {
                self.rest[ch].anchor(chambers[ch].v);
            }
        }
        for ch in 0..AXES {
            chambers[ch].p = raw_kpa[ch] - self.zero_kpa[ch];
        }
        let frame = self.estimate_frame(chambers, t_us, events);
        // A correction at rest applies from the next frame on.
        let rest_zero = match new_zero {
            Some(_) => None,
            None => self.rest_correction(&frame, t_us, events),
        };
        (frame, new_zero.or(rest_zero))
    }

    /// The zero's drift at rest ([`crate::rest_zero`]): each chamber's frame goes to its rest
    /// state; a completed window within bounds moves that chamber's zero and posts a `zero`
    /// event with all the offsets. Returns the new offsets when one moved.
    fn rest_correction(
        &mut self,
        frame: &Frame,
        t_us: u64,
        events: &mut EventBuf,
    ) -> Option<[f32; AXES]> {
        let cfg = self.cfg.rest_zero?;
        if self.zeroing.is_some() {
            return None;
        }
        let mut moved = false;
        for ch in 0..AXES {
            let c = &frame.chambers[ch];
            if let RestOutcome::Shift(d) = self.rest[ch].frame(&cfg, c.v, c.vdot, c.residual) {
                self.zero_kpa[ch] += d;
                moved = true;
            }
        }
        if !moved {
            return None;
        }
        Some(self.post_zero(t_us, events))
    }

    /// Post the `zero` event with the offsets in force; returns them.
    fn post_zero(&self, t_us: u64, events: &mut EventBuf) -> [f32; AXES] {
        push_event(
            events,
            t_us,
            EventKind::Zeroed {
                offset_kpa: self.zero_kpa,
            },
        );
        self.zero_kpa
    }

    /// The estimation half of [`finish_frame`](Self::finish_frame) on a frame's means: each
    /// chamber's `v` (mm³), `v̇` (mm³/s) and zeroed `p` (kPa) in, P̂, residual, k, c (the effect
    /// chain, RLS and drift checks as on the board) and the force out; the frame counter
    /// advances. `vfp replay` runs a log's frames through it (the board's own arithmetic on the
    /// host); the pressure zero is not touched.
    pub fn estimate_frame(
        &mut self,
        mut chambers: [ChamberFrame; AXES],
        t_us: u64,
        events: &mut EventBuf,
    ) -> Frame {
        self.warnings &= !(Flags::MODEL_RANGE * 0b111);
        for (ch, c) in chambers.iter_mut().enumerate() {
            if let Err(flag) = self.estimate(ch, c, t_us, events) {
                self.warnings |= flag;
            }
        }
        let force_n = model_core::force::estimate(self.load_kpa, self.cfg.area_mm2)
            .map_or(f32::NAN, |f| f.total_n);
        let frame = Frame {
            seq: self.seq,
            t_us,
            flags: Flags(self.warnings),
            force_n,
            chambers,
            drops: 0,
        };
        self.seq = self.seq.wrapping_add(1);
        frame
    }

    fn update_zero(
        &mut self,
        raw_kpa: [f32; AXES],
        t_us: u64,
        events: &mut EventBuf,
    ) -> Option<[f32; AXES]> {
        let (left, sum) = self.zeroing.as_mut()?;
        for ch in 0..AXES {
            sum[ch] += raw_kpa[ch];
        }
        *left = left.saturating_sub(1);
        if *left != 0 {
            return None;
        }
        let n = self.cfg.zero_frames.max(1) as f32;
        let mean = sum.map(|s| s / n);
        let mut refused = false;
        for ch in 0..AXES {
            // A NaN compares false: refused too.
            let plausible = libm::fabsf(mean[ch]) <= self.cfg.zero_max_kpa;
            if plausible {
                self.zero_kpa[ch] = mean[ch];
            } else {
                refused = true;
            }
        }
        self.zeroing = None;
        if !refused {
            self.warnings &= !Flags::NOT_ZEROED;
        }
        Some(self.post_zero(t_us, events))
    }

    /// P̂, residual, k, c for one chamber from its effect chain (`model_core::chain`; the bare
    /// polynomial when the chain is empty); the RLS update and drift check when online.
    ///
    /// RLS and the drift check work on the polynomial part: its regressors are taken at the
    /// inputs the polynomial saw (v′, v̇′, after the chain's input transforms) and its target is
    /// the measured pressure less what the effects add on top of the polynomial,
    /// `P − (P̂ − P̂_poly)`. Without effects that is exactly `P` at `(v, v̇)`, as before.
    fn estimate(
        &mut self,
        ch: usize,
        c: &mut ChamberFrame,
        t_us: u64,
        events: &mut EventBuf,
    ) -> Result<(), u32> {
        let range = Flags::channel(Flags::MODEL_RANGE, ch);
        let cfg = self.cfg;
        let chamber = &mut self.chambers[ch];
        let inp = ChainInput {
            v: c.v,
            vdot: c.vdot,
            p: c.p,
            dt: cfg.frame_dt(),
        };
        let eval = chamber
            .chain
            .eval(&chamber.model, &chamber.hist, &mut chamber.state, inp);
        let (poly_in, result) = match eval {
            Ok(e) => {
                c.p_hat = e.p;
                c.residual = c.p - e.p;
                c.k = e.k;
                c.c = e.c;
                ((e.v_in, e.vdot_in, c.p - (e.p - e.p_poly)), Ok(()))
            }
            Err(_) => {
                // Outside the model's range (or history still filling): report NaN, not a guess.
                c.p_hat = f32::NAN;
                c.residual = f32::NAN;
                c.k = f32::NAN;
                c.c = f32::NAN;
                ((c.v, c.vdot, c.p), Err(range))
            }
        };
        // NaN without an estimate, which starts the load's difference over.
        self.load_kpa[ch] = chamber
            .chain
            .load_pressure(&mut chamber.state, c.residual, inp.dt);
        let drift = chamber.online.as_mut().and_then(|online| {
            online_update(online, &mut chamber.model, &chamber.hist, poly_in, &cfg)
        });
        chamber.hist.push(poly_in.0, poly_in.1);
        if let Some((k_mean, c_mean, k_base, c_base)) = drift {
            self.warnings |= Flags::channel(Flags::DRIFT, ch);
            push_event(
                events,
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
            ReadPart::Effect { index } => {
                let chain = &self.chambers[ch].chain;
                let e = chain
                    .effects()
                    .get(index as usize)
                    .ok_or(CommandError::OutOfRangeArg { index: 4 })?;
                let _ = write!(out, " {}", e.kind().name());
                for &x in e.params() {
                    let _ = crate::telemetry::num(out, x);
                }
                return Ok(());
            }
            // The CRC lives with the store on the motion side: `Shared::execute` answers it.
            ReadPart::Crc => return Ok(()),
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
        events: &mut EventBuf,
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
                    chain: Chain::new(),
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
                let model = Model {
                    poly: model,
                    chain: st.chain,
                };
                self.install(ch as usize, model, now_us, events);
                self.staged = None;
            }
            ModelCmd::Default => self.install(ch as usize, Model::default_model(), now_us, events),
            ModelCmd::Read(part) => self.read_model(ch as usize, *part, out)?,
        }
        Ok(())
    }

    /// `model <ch> effect …`: one more effect in the staged model's chain.
    fn model_effect(
        &mut self,
        ch: u8,
        kind: EffectKind,
        params: &[f32],
    ) -> Result<(), CommandError> {
        let st = self.staged.as_mut().filter(|s| s.ch == ch);
        let st = st.ok_or(CommandError::NoStagedModel)?;
        let e = Effect::new(kind, params).map_err(CommandError::Model)?;
        st.chain.push(e).map_err(CommandError::Model)
    }

    fn install(&mut self, ch: usize, model: Model, now_us: u64, events: &mut EventBuf) {
        self.chambers[ch] = Chamber::new(model, self.cfg.frame_dt());
        self.rest[ch].new_model();
        self.warnings &=
            !(Flags::channel(Flags::RLS_ACTIVE, ch) | Flags::channel(Flags::DRIFT, ch));
        push_event(events, now_us, EventKind::ModelLoaded { ch: ch as u8 });
    }

    fn rls(&mut self, ch: usize, lambda: Option<Option<f32>>) -> Result<(), CommandError> {
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
                let mut rls = Rls::new(lambda, self.cfg.rls_p0).map_err(CommandError::Model)?;
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
        Ok(())
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
/// The RLS regressor is the model's own scaled row φ = [x^i y^j …] at `(v, v̇)` and the
/// measurement is `p`: the zeroed pressure P (less the effect chain's part, [`Estimator`]'s
/// `estimate`), so θ converges to the scaled coefficients of the plant (paper Sec. IV-A
/// identifies the same 12 coefficients offline). k̄ and c̄ are averaged over a fixed grid of
/// operating points (the scaling's box, 5 volumes × 3 flows) rather than along the
/// trajectory, so they change only when the model does, not with where the chamber happens
/// to be in its cycle; a softening chamber (an air pocket) lowers both (paper Fig. 6c).
fn online_update(
    online: &mut Online,
    model: &mut PolyModel,
    hist: &ArHistory,
    (v, vdot, p): (f32, f32, f32),
    cfg: &Config,
) -> Option<(f32, f32, f32, f32)> {
    if libm::fabsf(vdot) <= cfg.rls_min_flow || !p.is_finite() {
        return None;
    }
    let mut phi = [0.0f32; RLS_PARAMS];
    model.regressors_ar(v, vdot, hist, &mut phi).ok()?;
    online.rls.update(&phi, p).ok()?;
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
/// v̇ = f₀ + s_f·{−1, 0, 1}. Plain `f32` sums of the 15 values (no `f64` on the frame path).
fn grid_kc(model: &PolyModel) -> Option<(f32, f32)> {
    let sc = model.scaling();
    let (mut k, mut c) = (0.0f32, 0.0f32);
    for xv in [-1.0, -0.5, 0.0, 0.5, 1.0] {
        for yf in [-1.0, 0.0, 1.0] {
            let v = sc.v_offset + xv * sc.v_scale;
            let f = sc.f_offset + yf * sc.f_scale;
            let e = model.eval(v, f).ok()?;
            k += e.k;
            c += e.c;
        }
    }
    (k.is_finite() && c.is_finite()).then_some((k / 15.0, c / 15.0))
}

// ==================================================================== the sampler's own state

/// The sampler task's own state: the frame being accumulated, the telemetry line buffer and
/// the count of lines dropped, and the serial stream's side ([`SerialOut`], its own count).
/// Not shared: no lock.
#[derive(Debug)]
pub struct Sampler {
    acc: FrameAcc,
    oversample: u32,
    period_us: u64,
    line: LineBuf,
    drops: u32,
    serial: SerialOut,
}

impl Sampler {
    /// For the configuration's frame rate and oversampling.
    pub fn new(cfg: &Config) -> Self {
        Self {
            acc: FrameAcc::default(),
            oversample: cfg.oversample.max(1),
            period_us: cfg.oversample_period_us(),
            line: LineBuf::new(),
            drops: 0,
            serial: SerialOut::default(),
        }
    }
    /// Conversion period, µs.
    pub fn period_us(&self) -> u64 {
        self.period_us
    }
    /// Telemetry lines dropped so far (wrapping).
    pub fn drops(&self) -> u32 {
        self.drops
    }
    /// Serial telemetry packets dropped so far (wrapping).
    pub fn serial_drops(&self) -> u32 {
        self.serial.drops()
    }

    /// Hand `self.line` plus `\n` to the sink; count it if refused.
    fn send(&mut self, tlm: &mut impl TelemetrySink) -> bool {
        let ok = self.line.push('\n').is_ok() && tlm.try_send(&self.line);
        if !ok {
            self.drops = self.drops.wrapping_add(1);
        }
        ok
    }

    /// Format a frame (with the drop count so far) and hand it over; `false` if the transport
    /// refused it (counted). Runs outside any lock.
    pub fn send_frame(&mut self, frame: &mut Frame, tlm: &mut impl TelemetrySink) -> bool {
        frame.drops = self.drops;
        self.line.clear();
        if frame.encode(&mut self.line).is_err() {
            self.drops = self.drops.wrapping_add(1);
            return false;
        }
        self.send(tlm)
    }

    /// Format an event line and hand it over; `false` if refused (counted).
    pub fn send_event(&mut self, ev: &Event, tlm: &mut impl TelemetrySink) -> bool {
        self.line.clear();
        if ev.encode(&mut self.line).is_err() {
            self.drops = self.drops.wrapping_add(1);
            return false;
        }
        self.send(tlm)
    }
}

/// What one conversion produced for the sampler task.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConversionResult {
    /// A fault is latched.
    pub faulted: bool,
    /// The watchdog may be fed.
    pub alive: bool,
    /// The frame's sums when this was its K-th conversion.
    pub frame: Option<FrameAcc>,
}

// ==================================================================== the two together

/// Read access to both halves at once (tests and host tools: [`Shared::lock`]).
pub struct State<'a> {
    ctl: &'a mut Control,
    est: &'a mut Estimator,
}

impl State<'_> {
    /// The motion side.
    pub fn control(&mut self) -> &mut Control {
        self.ctl
    }
    /// The estimation side.
    pub fn estimator(&mut self) -> &mut Estimator {
        self.est
    }
    /// The configuration, with the limits in force.
    pub fn config(&self) -> &Config {
        self.ctl.config()
    }
    /// The motion planner (read-only).
    pub fn motion(&self) -> &Motion {
        self.ctl.motion()
    }
    /// Current flags: latched faults, STOPPED and warnings.
    pub fn flags(&self) -> Flags {
        Flags(self.ctl.flag_bits() | self.est.warnings)
    }
    /// The model of a chamber.
    pub fn model(&self, ch: usize) -> &PolyModel {
        self.est.model(ch)
    }
    /// Pressure zero offsets, kPa.
    pub fn zero_kpa(&self) -> [f32; AXES] {
        self.est.zero_kpa()
    }
    /// The model store's state (CRCs, flash status).
    pub fn store(&self) -> &Persist {
        self.ctl.store()
    }
}

/// The state shared by the tasks, plus the signal that wakes the stepper task.
pub struct Shared {
    /// Configuration at boot (constants; the limits in force are [`Control::config`]'s).
    cfg: Config,
    /// The motion side, under a critical section held only for O(1) hand-overs.
    ctl: Mutex<CriticalSectionRawMutex, RefCell<Control>>,
    /// The estimation side, under an async mutex (interrupts stay on while it is held).
    est: AsyncMutex<CriticalSectionRawMutex, Estimator>,
    /// Checksum policy of the command stream (required at boot, [`LinkState::default`]).
    link: Mutex<CriticalSectionRawMutex, Cell<LinkState>>,
    /// Wakes the stepper task when the plan changes (new move, stop, fault).
    wake: Signal<CriticalSectionRawMutex, ()>,
    /// The binary telemetry stream on the command port: its switch and bounded queue.
    serial_tlm: SerialTelemetry,
}

/// Longest reply line: the longest is `status` with every field at its widest, ≈ 230 bytes, and a
/// HardFault's reset cause (`reset hardfault`, seven registers and `stack-overflow`, 108 bytes); a
/// test checks it.
pub const REPLY_LEN: usize = 352;

/// Longest the stepper task sleeps with nothing to do (its heartbeat for the watchdog), µs.
const STEPPER_IDLE_US: u64 = 50_000;

/// Most batches one stepper wake-up issues before returning to the executor (a wake-up far
/// behind schedule, as in a simulation quantum, catches up in bounded slices).
const STEPPER_BATCHES: u32 = 64;

impl Shared {
    /// Fresh shared state for one board (or one simulation).
    pub fn new(cfg: Config) -> Self {
        Self {
            cfg,
            ctl: Mutex::new(RefCell::new(Control::new(cfg))),
            est: AsyncMutex::new(Estimator::new(cfg)),
            link: Mutex::new(Cell::new(LinkState::default())),
            wake: Signal::new(),
            serial_tlm: SerialTelemetry::new(),
        }
    }

    /// The configuration the board booted with.
    pub fn config(&self) -> &Config {
        &self.cfg
    }

    /// Declare every axis at `volume_mm3` without a command line, as `origin all <volume>` does
    /// at boot: for a host that built the plant itself and so knows where the plungers are
    /// (host-sim, the tests, the benches), before the tasks start. A board learns its positions
    /// only from the host's `origin` (after every reset, power-on included).
    pub fn declare_origin(&self, volume_mm3: f32) -> Result<(), CommandError> {
        let steps = self.volume_target(volume_mm3);
        self.with_control(|c| c.set_origin(AxisSet::ALL, steps))
            .map(|_| ())
    }

    /// Run `f` on the motion side under the critical section (interrupts off on the board).
    /// `f` must be O(1) and short: hand data over, compute outside.
    pub fn with_control<R>(&self, f: impl FnOnce(&mut Control) -> R) -> R {
        self.ctl.lock(|c| f(&mut c.borrow_mut()))
    }

    /// The estimation side's async mutex (interrupts stay on while it is held).
    pub fn estimator(&self) -> &AsyncMutex<CriticalSectionRawMutex, Estimator> {
        &self.est
    }

    /// Run `f` on both halves: for tests and host tools, where nothing else runs. It holds the
    /// critical section for as long as `f` runs, so the tasks never call it. Panics if the
    /// estimator is held elsewhere.
    pub fn lock<R>(&self, f: impl FnOnce(&mut State<'_>) -> R) -> R {
        let mut est = self
            .est
            .try_lock()
            .expect("Shared::lock: the estimator is held by a task");
        self.with_control(|ctl| f(&mut State { ctl, est: &mut est }))
    }

    /// Boot: install the models found in flash (or the default, `how` saying why) and report
    /// each channel on a `store` event (its CRC computed outside the lock).
    pub async fn restore_models(&self, models: &[(Model, Loaded); AXES], now_us: u64) {
        let mut est = self.est.lock().await;
        for (ch, (model, how)) in models.iter().enumerate() {
            est.install_boot(ch, *model);
            let crc = crate::store::crc(model);
            self.with_control(|c| {
                let what = c.store.booted(ch, model, *how, crc);
                let ch = ch as u8;
                c.push_event(Event {
                    t_us: now_us,
                    kind: EventKind::Store { ch, what, crc },
                });
            });
        }
    }

    /// One pass of the persist task's bookkeeping around a flash write: the model to write,
    /// if any ([`Control::persist_begin`], one short lock).
    pub fn persist_begin(&self, now_us: u64) -> Option<(u8, Model)> {
        self.with_control(|c| c.persist_begin(now_us))
    }

    /// The write of `model` on `ch` ended ([`Control::persist_end`]; CRC outside the lock).
    pub fn persist_end(&self, ch: usize, model: &Model, ok: bool, now_us: u64) {
        let crc = crate::store::crc(model);
        self.with_control(|c| c.persist_end(ch, crc, ok, now_us));
    }

    /// Wake the stepper task to re-plan now.
    pub fn wake_stepper(&self) {
        self.wake.signal(());
    }

    // ---------------------------------------------------------------- stepper

    /// One wake-up of the stepper task at `now_us`: issues every step due by then, each batch
    /// of same-instant steps back to back (one short lock per batch: [`Control::stepper_wake`];
    /// the pulses come after it), and returns the instant to sleep until.
    pub fn stepper_tick(&self, now_us: u64, steppers: &mut impl Steppers) -> u64 {
        for _ in 0..STEPPER_BATCHES {
            let (batch, wait) =
                self.with_control(|c| c.stepper_wake(now_us, |a, d| steppers.set_direction(a, d)));
            if let Some(b) = batch {
                steppers.step_axes(b.axes, Instant::from_micros(b.at_us));
            }
            let deadline = match wait {
                StepperWait::Step { at_us } => at_us,
                StepperWait::Until(t) => t.min(now_us + STEPPER_IDLE_US),
                StepperWait::Idle => now_us + STEPPER_IDLE_US,
            };
            if deadline > now_us {
                return deadline;
            }
        }
        now_us
    }

    // ---------------------------------------------------------------- sampler

    /// One conversion at `t_us` (one short lock: [`Control::on_conversion`]), added to the
    /// sampler's frame; the frame's sums when it is complete.
    pub fn conversion(
        &self,
        sampler: &mut Sampler,
        raw: [u16; AXES],
        t_us: u64,
    ) -> ConversionResult {
        let c = self.with_control(|ctl| ctl.on_conversion(raw, t_us));
        sampler.acc.add(raw, &c, t_us);
        let frame =
            (sampler.acc.n >= sampler.oversample).then(|| core::mem::take(&mut sampler.acc));
        ConversionResult {
            faulted: c.faulted,
            alive: c.alive,
            frame,
        }
    }

    /// Finish a frame: estimation on `est` (no lock), then one short lock to post its events
    /// and new zero and to read the latched flags into the frame.
    pub fn finish_frame(&self, est: &mut Estimator, acc: &FrameAcc) -> Frame {
        let mut events = EventBuf::new();
        let (mut frame, new_zero) = est.finish_frame(acc, &mut events);
        let zeroing = est.zeroing();
        let latched = self.with_control(|c| {
            if let Some(z) = new_zero {
                c.zero_kpa = z;
            }
            c.zeroing = zeroing;
            for e in events {
                c.push_event(e);
            }
            c.flag_bits()
        });
        frame.flags = Flags(frame.flags.0 | latched);
        frame
    }

    /// Hand every queued event line to the sink, and to the serial stream when it is on (one
    /// short lock per event; formatting outside).
    pub fn send_events(&self, sampler: &mut Sampler, tlm: &mut impl TelemetrySink) {
        loop {
            let (ev, lost) = self.with_control(|c| (c.pop_event(), c.take_lost_events()));
            sampler.drops = sampler.drops.wrapping_add(lost);
            sampler.serial.lost(&self.serial_tlm, lost);
            let Some(ev) = ev else { return };
            sampler.send_event(&ev, tlm);
            sampler.serial.event(&ev, &self.serial_tlm);
        }
    }

    /// Queue the frame on the serial stream when it is on ([`crate::wire`]: encoded here,
    /// outside any lock, never waiting; a full queue drops it and counts it). `false` if off or
    /// dropped.
    pub fn send_serial_frame(&self, sampler: &mut Sampler, frame: &Frame) -> bool {
        sampler.serial.frame(frame, &self.serial_tlm)
    }

    /// The serial stream's switch and queue (drained by the command task onto the port).
    pub fn serial_telemetry(&self) -> &SerialTelemetry {
        &self.serial_tlm
    }

    // ---------------------------------------------------------------- commands

    fn volume_target(&self, volume: f32) -> Result<i32, CommandError> {
        let steps = volume / self.cfg.motion.mm3_per_step;
        if !(steps.is_finite() && (0.0..=i32::MAX as f32 / 2.0).contains(&libm::roundf(steps))) {
            return Err(CommandError::OutOfRange);
        }
        Ok(self.cfg.motion.volume_to_steps(volume))
    }

    fn post(&self, events: EventBuf) {
        if !events.is_empty() {
            self.with_control(|c| events.into_iter().for_each(|e| c.push_event(e)));
        }
    }

    /// Execute a parsed command at `now_us`, writing the reply's fields after `ok` into `out`.
    /// The estimator is held by the caller; the motion side is locked only for O(1) checks and
    /// hand-overs (moves and protocols are planned before, replies formatted after).
    pub fn execute(
        &self,
        est: &mut Estimator,
        cmd: &Command,
        now_us: u64,
        out: &mut impl Write,
    ) -> Result<(), CommandError> {
        let cfg = &self.cfg;
        let zeroing = est.zeroing();
        self.with_control(|c| c.store.note_command(now_us));
        match cmd {
            Command::Move {
                axes,
                volume,
                flow,
                accel,
            } => {
                let (pos, caps) = self.with_control(|c| c.plan_snapshot(*axes, zeroing))?;
                let flow = flow.unwrap_or(cfg.default_flow);
                let accel = accel.unwrap_or(cfg.default_accel);
                let target = self.volume_target(*volume)?;
                // Plan every axis before starting any, so a refused command moves nothing.
                let mut plans = [None; AXES];
                for a in axes.iter() {
                    plans[a] = Some(cfg.motion.plan(pos[a], target, caps[a], flow, accel)?);
                }
                self.with_control(|c| c.start_moves(*axes, &plans, zeroing, now_us))?;
            }
            Command::Run(spec) => {
                let (pos, caps) = self.with_control(|c| c.plan_snapshot(spec.axes, zeroing))?;
                let hi = self.volume_target(spec.v_high)?;
                let lo = self.volume_target(spec.v_low)?;
                if hi <= lo
                    || spec.axes.iter().any(|a| hi > caps[a] || lo < 0)
                    || spec.flows.iter().any(|&f| f > cfg.motion.max_flow)
                {
                    return Err(CommandError::OutOfRange);
                }
                let run =
                    ProtocolRun::new(spec.clone(), cfg.default_accel, &cfg.motion, pos, caps)?;
                self.with_control(|c| c.start_protocol(run, &pos, zeroing))?;
            }
            Command::Stop => self.with_control(Control::stop),
            Command::Clear => {
                self.with_control(|c| c.clear(now_us));
                est.warnings &= !(Flags::DRIFT * 0b111);
            }
            Command::Zero => {
                let busy = self.with_control(|c| !c.motion.all_idle() || c.protocol.is_some());
                if busy {
                    return Err(CommandError::Busy);
                }
                est.zeroing = Some((est.cfg.zero_frames, [0.0; AXES]));
                est.warnings |= Flags::NOT_ZEROED;
                self.with_control(|c| c.zeroing = true);
            }
            Command::Status => {
                let s = self.with_control(|c| c.status_snapshot());
                let _ = write!(
                    out,
                    " flags {} seq {} moving {} run {} v",
                    s.flags | est.warnings,
                    est.seq,
                    s.moving,
                    u8::from(s.run)
                );
                for v in s.volumes {
                    let _ = write!(out, " {v}");
                }
                let _ = out.write_str(" pmax");
                for l in &s.limits {
                    let _ = write!(out, " {}", l.p_max_kpa);
                }
                let _ = out.write_str(" cap");
                for l in &s.limits {
                    let _ = write!(out, " {}", l.capacity_mm3);
                }
                let _ = out.write_str(" crc");
                for c in s.crc {
                    let _ = write!(out, " {c:#010x}");
                }
                let _ = out.write_str(" store");
                for v in s.saved {
                    let _ = write!(out, " {}", v.name());
                }
                // Why the board last started, last: a fault's detail (its file and line, or
                // its registers) runs to the end of the line.
                let _ = out.write_str(" reset ");
                let _ = self.cfg.reset_cause.encode(out);
            }
            Command::Limit {
                axes,
                p_max_kpa,
                capacity_mm3,
            } => {
                let steps = cfg.motion.volume_to_steps(*capacity_mm3);
                let limits = ChannelLimits {
                    p_max_kpa: *p_max_kpa,
                    capacity_mm3: *capacity_mm3,
                };
                self.with_control(|c| c.set_limits(*axes, limits, steps))?;
            }
            Command::Origin { axes, volume } => {
                let steps = self.volume_target(*volume);
                let before = self.with_control(|c| c.set_origin(*axes, steps))?;
                let steps = steps?;
                for a in axes.iter() {
                    est.chambers[a].hist.clear();
                    est.chambers[a].reset_chain(cfg.frame_dt());
                    let dv = (steps - before[a]) as f32 * cfg.motion.mm3_per_step;
                    est.rest[a].shift(dv);
                }
            }
            Command::Model {
                ch,
                cmd: ModelCmd::Read(ReadPart::Crc),
            } => {
                let ch = *ch as usize;
                let (crc, saved) = self.with_control(|c| (c.store.crc(ch), c.store.saved(ch)));
                let _ = write!(out, " {crc:#010x} {}", saved.name());
            }
            Command::Model { ch, cmd } => {
                let mut events = EventBuf::new();
                let r = est.model_cmd(*ch, cmd, now_us, out, &mut events);
                if r.is_ok() && matches!(cmd, ModelCmd::Commit | ModelCmd::Default) {
                    // The committed model waits for rest to be written to flash; its CRC is
                    // computed here, outside the lock.
                    let ch = *ch as usize;
                    let model = est.full_model(ch);
                    let crc = crate::store::crc(&model);
                    self.with_control(|c| c.store.committed(ch, &model, crc));
                }
                self.post(events);
                r?;
            }
            Command::ModelEffect { ch, kind, params } => est.model_effect(*ch, *kind, params)?,
            Command::Rls { ch, lambda } => est.rls(*ch as usize, *lambda)?,
            Command::Telemetry { on } => match on {
                Some(on) => self.serial_tlm.set(*on),
                None => {
                    let on = self.serial_tlm.is_on();
                    let _ = out.write_str(if on { " on" } else { " off" });
                }
            },
            Command::Checksum { require } => match require {
                Some(r) => self.link.lock(|l| {
                    let mut s = l.get();
                    s.require = *r;
                    l.set(s);
                }),
                None => {
                    let on = self.link.lock(|l| l.get().require);
                    let _ = out.write_str(if on { " require" } else { " optional" });
                }
            },
        }
        Ok(())
    }

    /// Execute a parsed command, write the reply line (no terminator) to `out`, and wake the
    /// stepper task.
    pub fn command(&self, est: &mut Estimator, cmd: &Command, now_us: u64, out: &mut impl Write) {
        let mut fields: heapless::String<REPLY_LEN> = heapless::String::new();
        let r = self.execute(est, cmd, now_us, &mut fields);
        self.wake.signal(());
        let _ = match r {
            Ok(()) => write!(out, "ok{fields}"),
            Err(e) => write!(out, "err {e}"),
        };
    }

    /// A line from the serial port: checksum rules, parse, execute; the reply line (no
    /// terminator) to `out`.
    pub fn command_raw(
        &self,
        est: &mut Estimator,
        line: RawLine<'_>,
        now_us: u64,
        out: &mut impl Write,
    ) {
        // The link state is copied out and back (two O(1) locks): checking and parsing the line
        // run with interrupts on. Only the command stream uses it.
        let mut link = self.link.lock(Cell::get);
        let parsed = line.command(&mut link);
        self.link.lock(|l| l.set(link));
        match parsed {
            Ok(cmd) => self.command(est, &cmd, now_us, out),
            Err(e) => {
                let _ = write!(out, "err {e}");
            }
        }
    }

    /// Check, parse and execute one command line (without its terminator; a checksummed line is
    /// checked first, and a plain line other than `stop` is refused until `checksum optional`),
    /// writing the reply line to `out`. For callers outside the tasks (tests,
    /// host tools); `err busy` if a task holds the estimator.
    pub fn command_line(&self, line: &[u8], now_us: u64, out: &mut impl Write) {
        match self.est.try_lock() {
            Ok(mut est) => self.command_raw(&mut est, RawLine::Ok(line), now_us, out),
            Err(_) => {
                let _ = write!(out, "err {}", CommandError::Busy);
            }
        }
    }
}

// ==================================================================== tasks

/// Drive the stepper outputs: sleep until the earliest planned step, then
/// [`Shared::stepper_tick`].
///
/// A fault latched by the sampler (or a `stop`) is seen at the next step instant at the
/// latest, before the pulse; the wake signal makes the task re-plan at once.
///
/// The drivers stay disabled while a fault reset is latched ([`Flags::FAULT_RESET`]: the last
/// run ended in a panic, a HardFault or the watchdog, whose handlers disabled them): the host
/// decides, with `clear`, when the motors may hold and move again.
pub async fn stepper_task<S: Steppers>(shared: &Shared, mut steppers: S) -> ! {
    let mut enabled = false;
    steppers.set_enabled(false);
    loop {
        let allowed = shared.with_control(|c| c.drivers_allowed());
        if allowed != enabled {
            steppers.set_enabled(allowed);
            enabled = allowed;
        }
        let now = Instant::now().as_micros();
        let deadline = shared.stepper_tick(now, &mut steppers);
        select(
            Timer::at(Instant::from_micros(deadline)),
            shared.wake.wait(),
        )
        .await;
    }
}

/// Sample the sensors at 25 Hz × K, check the limits, estimate, and send telemetry without
/// ever waiting for the host.
pub async fn sampler_task<A: PressureAdc, T: TelemetrySink, W: Watchdog>(
    shared: &Shared,
    mut adc: A,
    mut tlm: T,
    mut wdg: W,
) -> ! {
    let mut sampler = Sampler::new(shared.config());
    let mut ticker = Ticker::every(Duration::from_micros(sampler.period_us()));
    loop {
        ticker.next().await;
        let raw = adc.read().await;
        let now = Instant::now().as_micros();
        let c = shared.conversion(&mut sampler, raw, now);
        if c.faulted {
            // The stepper re-checks before every pulse anyway; this makes it re-plan now.
            shared.wake.signal(());
        }
        if c.alive {
            wdg.feed();
        }
        if let Some(acc) = c.frame {
            let mut frame = {
                let mut est = shared.est.lock().await;
                shared.finish_frame(&mut est, &acc)
            };
            sampler.send_frame(&mut frame, &mut tlm);
            shared.send_serial_frame(&mut sampler, &frame);
        }
        shared.send_events(&mut sampler, &mut tlm);
    }
}

/// Read command lines from the serial port, execute them, reply one line each (`\r\n`). A
/// receive error rejects the line it hit (`err line-corrupt`). Between lines it writes the
/// queued binary telemetry packets ([`crate::wire`], when switched on): a packet and a reply
/// never interleave, and the reads are never cancelled with bytes taken (the port's `read`
/// and the queue's `next` take nothing until they return).
pub async fn command_task<U: SerialPort>(shared: &Shared, mut port: U) -> ! {
    let mut asm = LineAssembler::new();
    let mut buf = [0u8; 32];
    let mut reply: heapless::String<{ REPLY_LEN + 8 }> = heapless::String::new();
    // Start-up: take what reached the port before the board announces itself, without waiting.
    // Whole lines that arrived intact are executed as usual. A receive error with no line in
    // progress is the port's own start (a frame cut by the receiver switching on mid-word, an
    // overrun before reception ran): what it lost was sent before the board listened, so it
    // does not condemn the host's next line.
    loop {
        match embassy_futures::poll_once(port.read(&mut buf)) {
            core::task::Poll::Ready(Ok(n)) => {
                let n = n.min(buf.len());
                lines(shared, &mut port, &mut asm, &buf[..n], &mut reply).await;
            }
            core::task::Poll::Ready(Err(_)) => {
                if asm.in_progress() {
                    asm.error();
                }
            }
            core::task::Poll::Pending => break,
        }
    }
    // The boot event on the command port, whether or not the binary telemetry is on: the host
    // learns the board restarted, why, and that it listens from here on.
    reply.clear();
    let boot = Event {
        t_us: Instant::now().as_micros(),
        kind: EventKind::Boot {
            cause: shared.cfg.reset_cause,
        },
    };
    let _ = boot.encode(&mut reply);
    let _ = reply.push_str("\r\n");
    port.write_all(reply.as_bytes()).await;
    loop {
        let read = match select(port.read(&mut buf), shared.serial_tlm.next()).await {
            Either::First(r) => r,
            Either::Second(packet) => {
                port.write_all(&packet).await;
                continue;
            }
        };
        let n = match read {
            Ok(n) => n.min(buf.len()),
            Err(_) => {
                asm.error();
                0
            }
        };
        lines(shared, &mut port, &mut asm, &buf[..n], &mut reply).await;
    }
}

/// Feed received bytes to the line assembler; execute each finished line and write its reply.
async fn lines<U: SerialPort>(
    shared: &Shared,
    port: &mut U,
    asm: &mut LineAssembler,
    bytes: &[u8],
    reply: &mut heapless::String<{ REPLY_LEN + 8 }>,
) {
    for &b in bytes {
        let Some(line) = asm.push(b) else { continue };
        reply.clear();
        let now = Instant::now().as_micros();
        {
            let mut est = shared.est.lock().await;
            shared.command_raw(&mut est, line, now, reply);
        }
        let _ = reply.push_str("\r\n");
        port.write_all(reply.as_bytes()).await;
    }
}

/// Poll period of [`persist_task`], ms.
pub const PERSIST_POLL_MS: u64 = 100;

/// One pass of [`persist_task`]: write one pending model if the board is at rest. Returns
/// whether it wrote (or tried to).
pub async fn persist_once<F: NorFlash, G: FlashGuard>(
    shared: &Shared,
    store: &mut ModelStore<F>,
    guard: &mut G,
) -> bool {
    let now = Instant::now().as_micros();
    let Some((ch, model)) = shared.persist_begin(now) else {
        return false;
    };
    guard.before();
    let r = store.save(ch, model).await;
    guard.after();
    let now = Instant::now().as_micros();
    shared.persist_end(ch as usize, &model, r.is_ok(), now);
    true
}

/// Write committed models to flash when the board is at rest ([`crate::store`]'s module docs:
/// when the board writes, and why).
pub async fn persist_task<F: NorFlash, G: FlashGuard>(
    shared: &Shared,
    mut store: ModelStore<F>,
    mut guard: G,
) -> ! {
    loop {
        Timer::after_millis(PERSIST_POLL_MS).await;
        persist_once(shared, &mut store, &mut guard).await;
    }
}

#[cfg(test)]
#[path = "app_tests.rs"]
mod tests;
