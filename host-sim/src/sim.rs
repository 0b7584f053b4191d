//! The simulation loop: the firmware's own tasks on the simulated board, in virtual time.
//!
//! The three task futures ([`firmware::app::stepper_task`], [`firmware::app::sampler_task`],
//! [`firmware::app::command_task`]) are polled by a `FuturesUnordered` (only woken tasks are
//! polled). Virtual time is embassy-time's global `MockDriver`; the loop is
//!
//! 1. poll every woken task until none is woken (a standstill at this instant);
//! 2. if the sampler asked for a conversion, sample the plant now, wake it, go to 1;
//! 3. send the commands and inject the faults that are due, go to 1 if any;
//! 4. advance the driver by one quantum (1 ms; the firmware's 5 ms sampling instants are whole
//!    ms) and go to 1.
//!
//! Steps are applied at their planned instants (µs) whenever the stepper task issues them, which
//! is no later than the quantum boundary after that instant and always before a conversion at
//! that boundary is taken (step 2 waits for the standstill). The MockDriver is global, so one
//! simulation runs at a time per process: [`simulate`] holds a global lock.

use std::cell::RefCell;
use std::future::Future;
use std::io::Write;
use std::pin::Pin;
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::task::Context;

use embassy_time::{Duration, Instant, MockDriver};
use firmware::app::{self, Config, Shared};
use firmware::reset::ResetCause;
use firmware::telemetry::{Event, EventKind, Frame};
use futures::stream::{FuturesUnordered, StreamExt};
use futures::task::ArcWake;

use crate::board::{
    FrameTruth, ReadTruth, Rig, Rx, SimAdc, SimSerial, SimSteppers, SimTelemetry, SimWatchdog,
};
use crate::plant::{Plant, CHAMBERS};
use crate::scenario::Scenario;
use crate::scenario::SerialFaultKind;
use crate::SimError;
use firmware::hal::SerialError;

/// One simulation at a time: the MockDriver is process-global.
static SIM_LOCK: Mutex<()> = Mutex::new(());

/// Counters of one run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RunStats {
    /// Simulated time at the end, µs.
    pub end_us: u64,
    /// Executor quanta advanced.
    pub quanta: u64,
    /// Step pulses applied to the plant.
    pub steps: u64,
    /// Step pulses received while the drivers were disabled.
    pub ignored_steps: u64,
    /// Step pulses whose instant lay behind the plant (must be 0).
    pub late_steps: u64,
    /// Longest delay between a step's planned instant and its issue in virtual time, µs (at
    /// most one quantum when the board keeps up).
    pub max_step_delay_us: u64,
    /// Longest gap between watchdog feeds, µs.
    pub max_watchdog_gap_us: u64,
}

/// Everything a run produced.
#[derive(Clone, Debug)]
pub struct SimRun {
    /// The scenario that was run.
    pub scenario: Scenario,
    /// Every telemetry line the board handed over, with its time, µs.
    pub telemetry: Vec<(u64, String)>,
    /// Lines the board offered during a telemetry stall and the transport refused, with their
    /// time, µs (the board counts them in its frames' `drops`).
    pub refused_telemetry: Vec<(u64, String)>,
    /// Decoded frame lines, in order.
    pub frames: Vec<Frame>,
    /// The truth behind each frame (same index).
    pub truth: Vec<FrameTruth>,
    /// Decoded event lines, in order.
    pub events: Vec<Event>,
    /// Command replies with their time, µs.
    pub replies: Vec<(u64, String)>,
    /// Every byte written to the command port: the boot event line, the replies and, after
    /// `telemetry on`, the binary telemetry packets (`firmware::wire`) between them.
    pub serial_out: Vec<u8>,
    /// Step pulses applied per axis.
    pub step_count: [u64; CHAMBERS],
    /// Instant of the last step pulse per axis, µs.
    pub last_step_us: [Option<u64>; CHAMBERS],
    /// Every step pulse (instant µs, axis, inflate), if the scenario's `record_detail`.
    pub steps: Vec<(u64, u8, bool)>,
    /// Truth at every ADC conversion, if the scenario's `record_detail`.
    pub conversions: Vec<ReadTruth>,
    /// Counters.
    pub stats: RunStats,
}

/// Sets a flag when any task is woken.
struct WakeFlag(AtomicBool);

impl ArcWake for WakeFlag {
    fn wake_by_ref(arc_self: &Arc<Self>) {
        arc_self.0.store(true, Ordering::Relaxed);
    }
}

type Task<'a> = Pin<Box<dyn Future<Output = ()> + 'a>>;

/// Name of an event kind as printed on its line.
fn kind_name(k: &EventKind) -> &'static str {
    match k {
        EventKind::Boot { .. } => "boot",
        EventKind::Fault { .. } => "fault",
        EventKind::Cleared => "cleared",
        EventKind::Zeroed { .. } => "zeroed",
        EventKind::Drift { .. } => "drift",
        EventKind::ProtocolDone => "protocol-done",
        EventKind::ModelLoaded { .. } => "model",
        EventKind::Store { .. } => "store",
    }
}

/// Run `scenario` with the firmware's default configuration.
pub fn simulate(scenario: &Scenario) -> Result<SimRun, SimError> {
    simulate_with(scenario, Config::default())
}

/// Run `scenario` with a given firmware configuration.
pub fn simulate_with(scenario: &Scenario, fw: Config) -> Result<SimRun, SimError> {
    scenario.validate()?;
    let plant = Plant::new(&scenario.plant, &scenario.force, scenario.seed)?;
    // A panicking earlier simulation poisons the lock but leaves nothing half-done that matters:
    // the driver is reset below.
    let _guard = SIM_LOCK.lock().unwrap_or_else(|e| e.into_inner());
    let driver = MockDriver::get();
    driver.reset();

    let rig = Rc::new(RefCell::new(Rig::new(
        plant,
        fw.oversample as usize,
        scenario.record_detail,
    )));
    let to_us = |s: f64| (s * 1e6).round() as u64;
    rig.borrow_mut().stalls = scenario
        .telemetry_stalls
        .iter()
        .map(|st| (to_us(st.start_s), to_us(st.start_s + st.duration_s)))
        .collect();
    let shared = Shared::new(fw);
    // The plant starts with its plungers at volume 0, and after a power-on or a brown-out the
    // simulated lab declares so (`origin all 0`), as a lab does at its bench before the first move.
    // After any other reset it has not: the firmware then refuses motion until a scenario's
    // own `origin`, as a board does.
    if matches!(fw.reset_cause, ResetCause::PowerOn | ResetCause::BrownOut) {
        shared
            .declare_origin(0.0)
            .map_err(|e| SimError::Internal(format!("origin at volume 0: {e}")))?;
    }

    let tasks: FuturesUnordered<Task<'_>> = FuturesUnordered::new();
    {
        let (s, r) = (&shared, rig.clone());
        tasks.push(Box::pin(async move {
            app::stepper_task(s, SimSteppers(r)).await;
        }));
        let r = rig.clone();
        tasks.push(Box::pin(async move {
            app::sampler_task(
                s,
                SimAdc(r.clone()),
                SimTelemetry(r.clone()),
                SimWatchdog(r),
            )
            .await;
        }));
        let r = rig.clone();
        tasks.push(Box::pin(async move {
            app::command_task(s, SimSerial(r)).await;
        }));
    }
    let mut tasks = tasks;

    let flag = Arc::new(WakeFlag(AtomicBool::new(true)));

    let mut commands: Vec<_> = scenario.commands.iter().enumerate().collect();
    commands.sort_by(|a, b| a.1.at_s.total_cmp(&b.1.at_s));
    let mut commands = commands.into_iter().peekable();
    let mut faults: Vec<_> = scenario.faults.iter().collect();
    faults.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
    let mut faults = faults.into_iter().peekable();
    let end_us = to_us(scenario.duration_s);
    let quantum = Duration::from_micros(scenario.quantum_us);
    let mut stop_at: Option<u64> = None;
    let mut seen_lines = 0usize;
    let mut quanta = 0u64;

    loop {
        run_until_stalled(&mut tasks, &flag)?;
        let now = Instant::now().as_micros();
        {
            let mut r = rig.borrow_mut();
            if r.read_pending() {
                r.fulfil_read(now);
                continue;
            }
        }
        let mut injected = false;
        while let Some((i, c)) = commands.next_if(|c| to_us(c.1.at_s) <= now) {
            // The scenario was validated: every line can be framed.
            let mut line = c.wire().unwrap_or_default().into_bytes();
            line.push(b'\n');
            let mut items = Vec::with_capacity(line.len() + 1);
            for (k, &b) in line.iter().enumerate() {
                let fault = scenario
                    .serial_faults
                    .iter()
                    .find(|f| f.command == i && f.byte == k);
                match fault.map(|f| f.kind) {
                    None => items.push(Rx::Byte(b)),
                    Some(SerialFaultKind::Lose) => items.push(Rx::Error(SerialError::Overrun)),
                    Some(SerialFaultKind::Flag) => {
                        items.push(Rx::Error(SerialError::Framing));
                        items.push(Rx::Byte(b));
                    }
                    Some(SerialFaultKind::Drop) => {}
                }
            }
            rig.borrow_mut().send_with(items);
            injected = true;
        }
        while let Some(f) = faults.next_if(|f| to_us(f.at_s) <= now) {
            rig.borrow_mut().plant.set_unplugged(f.unplug, true);
        }
        if injected {
            continue;
        }
        if let (Some(kind), None) = (&scenario.stop_on, stop_at) {
            let r = rig.borrow();
            for (t, line) in &r.telemetry[seen_lines..] {
                if let Ok(ev) = Event::decode(line) {
                    if kind_name(&ev.kind) == kind {
                        stop_at = Some(t + to_us(scenario.tail_s));
                        break;
                    }
                }
            }
            seen_lines = r.telemetry.len();
        }
        if now >= end_us || stop_at.is_some_and(|s| now >= s) {
            break;
        }
        if scenario.plant.drive.follows_profile() {
            // The ideal drive follows the commanded profile: hand it the next quantum's flow.
            let q = scenario.quantum_us;
            let flows: [(f32, f32); CHAMBERS] = shared.with_control(|c| {
                core::array::from_fn(|i| {
                    (c.motion().flow_at(i, now), c.motion().flow_at(i, now + q))
                })
            });
            let mut r = rig.borrow_mut();
            for (i, (f0, f1)) in flows.into_iter().enumerate() {
                r.plant.command_flow(i, now, now + q, f0 as f64, f1 as f64);
            }
        }
        driver.advance(quantum);
        quanta += 1;
    }
    drop(tasks);

    let end_us = Instant::now().as_micros();
    let rig = Rc::try_unwrap(rig)
        .map_err(|_| SimError::Internal("board handles outlived the tasks".into()))?
        .into_inner();
    let mut frames = Vec::new();
    let mut events = Vec::new();
    for (t, line) in &rig.telemetry {
        if line.starts_with(firmware::telemetry::FRAME_TAG) {
            frames.push(Frame::decode(line).map_err(|e| {
                SimError::Internal(format!("frame line at {t} µs did not decode ({e}): {line}"))
            })?);
        } else {
            events.push(Event::decode(line).map_err(|e| {
                SimError::Internal(format!("event line at {t} µs did not decode ({e}): {line}"))
            })?);
        }
    }
    let truth = frame_truth(&frames, &rig.frame_truth)?;
    let gap = rig.max_feed_gap_us.max(rig.watchdog_gap(end_us));
    Ok(SimRun {
        scenario: scenario.clone(),
        telemetry: rig.telemetry,
        refused_telemetry: rig.refused,
        frames,
        truth,
        events,
        replies: rig.replies,
        serial_out: rig.serial_out,
        stats: RunStats {
            end_us,
            quanta,
            steps: rig.step_count.iter().sum(),
            ignored_steps: rig.ignored_steps,
            late_steps: rig.late_steps,
            max_step_delay_us: rig.max_step_delay_us,
            max_watchdog_gap_us: gap,
        },
        step_count: rig.step_count,
        last_step_us: rig.last_step_us,
        steps: rig.steps,
        conversions: rig.reads,
    })
}

/// More polls than this at one instant means a task never waits (10 000 steps/s at most are
/// due in one 1 ms quantum, each a few polls).
const MAX_POLLS_PER_INSTANT: u32 = 1_000_000;

/// Poll woken tasks until none is woken.
fn run_until_stalled(
    tasks: &mut FuturesUnordered<Task<'_>>,
    flag: &Arc<WakeFlag>,
) -> Result<(), SimError> {
    let waker = futures::task::waker_ref(flag);
    let mut cx = Context::from_waker(&waker);
    let mut polls = 0u32;
    while flag.0.swap(false, Ordering::Relaxed) {
        if tasks.poll_next_unpin(&mut cx).is_ready() {
            return Err(SimError::TaskEnded);
        }
        polls += 1;
        if polls > MAX_POLLS_PER_INSTANT {
            // A task that never waits would hang the device too: report it, do not spin.
            return Err(SimError::Internal(format!(
                "tasks still runnable after {MAX_POLLS_PER_INSTANT} polls at {} µs",
                Instant::now().as_micros()
            )));
        }
    }
    Ok(())
}

/// Match each frame with the truth of its conversions (frame `s` holds conversions `s·K..(s+1)·K`).
fn frame_truth(frames: &[Frame], truths: &[FrameTruth]) -> Result<Vec<FrameTruth>, SimError> {
    frames
        .iter()
        .map(|f| {
            let t = truths
                .get(f.seq as usize)
                .ok_or_else(|| SimError::Internal(format!("frame {} has no conversions", f.seq)))?;
            if t.t_us != f.t_us {
                return Err(SimError::Internal(format!(
                    "frame {} at {} µs does not match its conversions at {} µs",
                    f.seq, f.t_us, t.t_us
                )));
            }
            Ok(*t)
        })
        .collect()
}

/// One log row: one chamber of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LogRow {
    /// Frame time, s.
    pub time_s: f64,
    /// Chamber 0..=2.
    pub chamber: usize,
    /// Syringe volume from step counts (what the device reports), mm³.
    pub volume_mm3: f32,
    /// Commanded flow (device), mm³/s.
    pub flow_mm3_s: f32,
    /// Measured pressure after the zero (device), kPa.
    pub pressure_kpa: f32,
    /// True external force (simulator), N.
    pub force_n: f64,
    /// Model prediction (device), kPa.
    pub p_hat_kpa: f32,
    /// Force estimate (device), N.
    pub force_est_n: f32,
    /// Frame flags (device).
    pub flags: u32,
    /// True chamber volume, mm³.
    pub true_volume_mm3: f64,
    /// True chamber flow, mm³/s.
    pub true_flow_mm3_s: f64,
    /// True line pressure, kPa.
    pub true_pressure_kpa: f64,
}

/// Column names of [`SimRun::write_log`], in order.
pub const LOG_COLUMNS: &str = "time_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa,force_n,\
p_hat_kpa,force_est_n,flags,true_volume_mm3,true_flow_mm3_s,true_pressure_kpa";

impl SimRun {
    /// One row per chamber per frame, frame by frame.
    pub fn rows(&self) -> impl Iterator<Item = LogRow> + '_ {
        self.frames.iter().zip(&self.truth).flat_map(|(f, t)| {
            (0..CHAMBERS).map(move |i| {
                let c = &f.chambers[i];
                let tc = &t.chambers[i];
                LogRow {
                    time_s: f.t_us as f64 * 1e-6,
                    chamber: i,
                    volume_mm3: c.v,
                    flow_mm3_s: c.vdot,
                    pressure_kpa: c.p,
                    force_n: t.force_n,
                    p_hat_kpa: c.p_hat,
                    force_est_n: f.force_n,
                    flags: f.flags.0,
                    true_volume_mm3: tc.chamber_mm3,
                    true_flow_mm3_s: tc.flow_mm3_s,
                    true_pressure_kpa: tc.pressure_kpa,
                }
            })
        })
    }

    /// Write the run as an actuation log (`docs/log-format.md`): metadata comments, the
    /// header, then [`SimRun::rows`]. Device columns print as the firmware's `f32`s do.
    pub fn write_log(&self, mut out: impl Write) -> std::io::Result<()> {
        let s = &self.scenario;
        let frame_hz = if self.frames.len() >= 2 {
            let span = (self.frames[self.frames.len() - 1].t_us - self.frames[0].t_us) as f64;
            ((self.frames.len() - 1) as f64 / (span * 1e-6)).round()
        } else {
            0.0
        };
        writeln!(
            out,
            "# source=host-sim (firmware tasks on a simulated plant)"
        )?;
        writeln!(out, "# scenario={}", s.name)?;
        writeln!(out, "# description={}", s.description)?;
        writeln!(out, "# design={}", s.plant.design.name())?;
        writeln!(out, "# seed={}", s.seed)?;
        // The air pocket as metadata, so `vfp air-scan` finds each log's x without `--x`.
        let air = s.plant.effects.air_pocket_mm3;
        if air.iter().all(|&a| a == air[0]) {
            writeln!(out, "# air_pocket_mm3={}", air[0])?;
        }
        writeln!(out, "# sample_rate_hz={frame_hz}")?;
        writeln!(out, "# force_n is the simulator's true external force")?;
        writeln!(out, "{LOG_COLUMNS}")?;
        for r in self.rows() {
            writeln!(
                out,
                "{:.6},{},{},{},{},{:.6},{},{},{},{:.4},{:.4},{:.4}",
                r.time_s,
                r.chamber,
                r.volume_mm3,
                r.flow_mm3_s,
                r.pressure_kpa,
                r.force_n,
                r.p_hat_kpa,
                r.force_est_n,
                r.flags,
                r.true_volume_mm3,
                r.true_flow_mm3_s,
                r.true_pressure_kpa
            )?;
        }
        Ok(())
    }

    /// The first event of a kind (`fault`, `protocol-done`, …).
    pub fn first_event(&self, kind: &str) -> Option<&Event> {
        self.events.iter().find(|e| kind_name(&e.kind) == kind)
    }
}
