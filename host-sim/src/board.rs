//! The simulated board: the firmware's hardware traits ([`firmware::hal`]) implemented on the
//! plant.
//!
//! Every handle shares one [`Rig`] (single thread, `Rc<RefCell<_>>`):
//! - [`SimSteppers`]: each STEP pulse moves the plant's motor by one step at the pulse's planned
//!   instant (the firmware passes it), in the direction last written to DIR; pulses while the
//!   drivers are disabled are counted and ignored.
//! - [`SimAdc`]: a conversion request stays pending until the simulation loop has run every task
//!   to a standstill at the current instant (so every step due by then has been applied), then
//!   samples the plant at exactly that instant. The result does not depend on task polling order.
//! - [`SimSerial`]: command bytes queued by the scenario, with the receive errors a scenario
//!   injects; replies are captured with their time.
//! - [`SimTelemetry`]: every line handed over is captured with its time; during a scenario's
//!   telemetry stall (the host not reading) every line is refused, and kept apart.
//! - [`SimWatchdog`]: feeds are timed; the longest gap is reported.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::rc::Rc;
use std::task::{Poll, Waker};

use embassy_time::Instant;
use firmware::hal::{
    Direction, PressureAdc, SerialError, SerialPort, Steppers, TelemetrySink, Watchdog, AXES,
};

use crate::plant::{ChamberTruth, Plant, CHAMBERS};

/// Truth sampled at one ADC conversion.
#[derive(Clone, Copy, Debug)]
pub struct ReadTruth {
    /// Conversion instant, µs.
    pub t_us: u64,
    /// True external force, N.
    pub force_n: f64,
    /// Per chamber.
    pub chambers: [ChamberTruth; AXES],
}

/// The truth behind one telemetry frame: the mean over the frame's ADC conversions (the firmware
/// averages the same conversions into the frame).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameTruth {
    /// Mean conversion instant, µs (equals the frame's `t_us`).
    pub t_us: u64,
    /// True external force, N.
    pub force_n: f64,
    /// Per chamber (each field the mean over the conversions).
    pub chambers: [ChamberTruth; CHAMBERS],
}

/// State shared by the board's handles and the simulation loop.
pub struct Rig {
    /// The physical plant.
    pub plant: Plant,
    dir: [Direction; AXES],
    enabled: bool,
    /// Keep every step and conversion (else only the per-frame aggregates).
    detail: bool,
    /// Step pulses applied, if `detail`: (instant µs, axis, inflate).
    pub steps: Vec<(u64, u8, bool)>,
    /// Step pulses applied per axis.
    pub step_count: [u64; AXES],
    /// Instant of the last step pulse per axis, µs.
    pub last_step_us: [Option<u64>; AXES],
    /// Pulses received while the drivers were disabled.
    pub ignored_steps: u64,
    /// Pulses whose planned instant lay before the plant's time (applied late; should stay 0).
    pub late_steps: u64,
    /// Longest time between a pulse's planned instant and the virtual time the stepper task
    /// issued it, µs (up to one executor quantum when the board keeps up).
    pub max_step_delay_us: u64,
    read_waker: Option<Waker>,
    read_pending: bool,
    read_result: Option<[u16; AXES]>,
    /// Truth at every conversion, in order, if `detail`.
    pub reads: Vec<ReadTruth>,
    /// Conversions per frame (the firmware's oversampling).
    oversample: usize,
    /// The current frame's conversions.
    group: Vec<ReadTruth>,
    /// Truth per completed frame (mean over its conversions).
    pub frame_truth: Vec<FrameTruth>,
    rx: VecDeque<Rx>,
    rx_waker: Option<Waker>,
    /// Reply lines from the command port with their time, µs.
    pub replies: Vec<(u64, String)>,
    reply_buf: String,
    /// Every byte the board wrote to the command port, in order: reply lines and the binary
    /// telemetry packets between them (`firmware::wire`, after `telemetry on`).
    pub serial_out: Vec<u8>,
    /// Telemetry lines with their time, µs.
    pub telemetry: Vec<(u64, String)>,
    /// Times the host does not read telemetry, `[start, end)` µs.
    pub stalls: Vec<(u64, u64)>,
    /// Lines refused during a stall, with their time, µs.
    pub refused: Vec<(u64, String)>,
    last_feed_us: u64,
    /// Longest time between two watchdog feeds (or from boot to the first), µs.
    pub max_feed_gap_us: u64,
}

impl Rig {
    /// A rig around `plant`, drivers disabled, DIR lines at "inflate". `oversample` conversions
    /// make a frame; `detail` keeps every step and conversion.
    pub fn new(plant: Plant, oversample: usize, detail: bool) -> Self {
        Self {
            plant,
            detail,
            step_count: [0; AXES],
            last_step_us: [None; AXES],
            oversample: oversample.max(1),
            group: Vec::new(),
            frame_truth: Vec::new(),
            dir: [Direction::Inflate; AXES],
            enabled: false,
            steps: Vec::new(),
            ignored_steps: 0,
            late_steps: 0,
            max_step_delay_us: 0,
            read_waker: None,
            read_pending: false,
            read_result: None,
            reads: Vec::new(),
            rx: VecDeque::new(),
            rx_waker: None,
            replies: Vec::new(),
            reply_buf: String::new(),
            serial_out: Vec::new(),
            telemetry: Vec::new(),
            stalls: Vec::new(),
            refused: Vec::new(),
            last_feed_us: 0,
            max_feed_gap_us: 0,
        }
    }

    /// Whether a conversion is waiting to be fulfilled.
    pub fn read_pending(&self) -> bool {
        self.read_pending && self.read_result.is_none()
    }

    /// Take the pending conversion at `t_us` and wake the reader.
    pub fn fulfil_read(&mut self, t_us: u64) {
        let counts = self.plant.adc_counts(t_us);
        let chambers = core::array::from_fn(|i| self.plant.truth(i));
        let truth = ReadTruth {
            t_us,
            force_n: self.plant.force_n(t_us),
            chambers,
        };
        if self.detail {
            self.reads.push(truth);
        }
        self.group.push(truth);
        if self.group.len() == self.oversample {
            self.frame_truth.push(mean_truth(&self.group));
            self.group.clear();
        }
        self.read_result = Some(counts);
        if let Some(w) = self.read_waker.take() {
            w.wake();
        }
    }

    /// Queue bytes on the command port and wake its reader.
    pub fn send(&mut self, bytes: &[u8]) {
        self.send_with(bytes.iter().map(|&b| Rx::Byte(b)));
    }

    /// Queue bytes and receive errors on the command port and wake its reader.
    pub fn send_with(&mut self, items: impl IntoIterator<Item = Rx>) {
        self.rx.extend(items);
        if let Some(w) = self.rx_waker.take() {
            w.wake();
        }
    }

    /// Account the watchdog up to `t_us` (the gap since the last feed).
    pub fn watchdog_gap(&self, t_us: u64) -> u64 {
        t_us.saturating_sub(self.last_feed_us)
    }
}

/// The truth behind one frame: the mean over its conversions (as the firmware averages them).
fn mean_truth(group: &[ReadTruth]) -> FrameTruth {
    let n = group.len() as f64;
    let mean = |g: &dyn Fn(&ChamberTruth) -> f64, i: usize| {
        group.iter().map(|r| g(&r.chambers[i])).sum::<f64>() / n
    };
    FrameTruth {
        t_us: group.iter().map(|r| r.t_us).sum::<u64>() / group.len() as u64,
        force_n: group.iter().map(|r| r.force_n).sum::<f64>() / n,
        chambers: core::array::from_fn(|i| ChamberTruth {
            motor_mm3: mean(&|c| c.motor_mm3, i),
            syringe_mm3: mean(&|c| c.syringe_mm3, i),
            delivered_mm3: mean(&|c| c.delivered_mm3, i),
            chamber_mm3: mean(&|c| c.chamber_mm3, i),
            flow_mm3_s: mean(&|c| c.flow_mm3_s, i),
            pressure_kpa: mean(&|c| c.pressure_kpa, i),
            sensed_kpa: mean(&|c| c.sensed_kpa, i),
            air_mm3: mean(&|c| c.air_mm3, i),
            leaked_mm3: mean(&|c| c.leaked_mm3, i),
        }),
    }
}

/// What the simulated UART receives: a byte, or a receive error reported at that point.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rx {
    /// A received byte.
    Byte(u8),
    /// A receive error.
    Error(SerialError),
}

/// Shared handle to the rig.
pub type RigRef = Rc<RefCell<Rig>>;

fn now_us() -> u64 {
    Instant::now().as_micros()
}

/// STEP/DIR/EN outputs.
pub struct SimSteppers(pub RigRef);

impl Steppers for SimSteppers {
    fn set_direction(&mut self, axis: usize, dir: Direction) {
        self.0.borrow_mut().dir[axis] = dir;
    }

    fn step(&mut self, axis: usize, at: Instant) {
        let mut rig = self.0.borrow_mut();
        if !rig.enabled {
            rig.ignored_steps += 1;
            return;
        }
        let mut t = at.as_micros();
        rig.max_step_delay_us = rig.max_step_delay_us.max(now_us().saturating_sub(t));
        if t < rig.plant.time_us(axis) {
            rig.late_steps += 1;
            t = rig.plant.time_us(axis);
        }
        let inflate = rig.dir[axis] == Direction::Inflate;
        rig.plant.step(axis, t, inflate);
        rig.step_count[axis] += 1;
        rig.last_step_us[axis] = Some(t);
        if rig.detail {
            rig.steps.push((t, axis as u8, inflate));
        }
    }

    fn set_enabled(&mut self, enabled: bool) {
        self.0.borrow_mut().enabled = enabled;
    }
}

/// The three sensor channels.
pub struct SimAdc(pub RigRef);

impl PressureAdc for SimAdc {
    async fn read(&mut self) -> [u16; AXES] {
        futures::future::poll_fn(|cx| {
            let mut rig = self.0.borrow_mut();
            if let Some(r) = rig.read_result.take() {
                rig.read_pending = false;
                return Poll::Ready(r);
            }
            rig.read_pending = true;
            rig.read_waker = Some(cx.waker().clone());
            Poll::Pending
        })
        .await
    }
}

/// The command port.
pub struct SimSerial(pub RigRef);

impl SerialPort for SimSerial {
    /// Bytes up to the next receive error; the error itself on the read after them.
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, SerialError> {
        futures::future::poll_fn(|cx| {
            let mut rig = self.0.borrow_mut();
            if rig.rx.is_empty() || buf.is_empty() {
                rig.rx_waker = Some(cx.waker().clone());
                return Poll::Pending;
            }
            if let Some(&Rx::Error(e)) = rig.rx.front() {
                rig.rx.pop_front();
                return Poll::Ready(Err(e));
            }
            let mut n = 0;
            while n < buf.len() {
                let Some(&Rx::Byte(b)) = rig.rx.front() else {
                    break;
                };
                rig.rx.pop_front();
                buf[n] = b;
                n += 1;
            }
            Poll::Ready(Ok(n))
        })
        .await
    }

    async fn write_all(&mut self, data: &[u8]) {
        let mut rig = self.0.borrow_mut();
        let t = now_us();
        rig.serial_out.extend_from_slice(data);
        // A binary telemetry packet is written whole, from its leading zero: not a reply.
        if data.first() == Some(&0) {
            return;
        }
        rig.reply_buf.push_str(&String::from_utf8_lossy(data));
        while let Some(end) = rig.reply_buf.find('\n') {
            let line: String = rig.reply_buf.drain(..=end).collect();
            let line = line.trim_end_matches(['\r', '\n']).to_string();
            // The boot event the command task writes when it starts is an event line, not a
            // reply (the log has it from the telemetry).
            if !line.starts_with(firmware::telemetry::EVENT_TAG) {
                rig.replies.push((t, line));
            }
        }
    }
}

/// Telemetry output.
pub struct SimTelemetry(pub RigRef);

impl TelemetrySink for SimTelemetry {
    fn try_send(&mut self, line: &str) -> bool {
        let t = now_us();
        let mut rig = self.0.borrow_mut();
        let line = line.trim_end_matches('\n').to_string();
        if rig.stalls.iter().any(|&(a, b)| (a..b).contains(&t)) {
            rig.refused.push((t, line));
            return false;
        }
        rig.telemetry.push((t, line));
        true
    }
}

/// The independent watchdog.
pub struct SimWatchdog(pub RigRef);

impl Watchdog for SimWatchdog {
    fn feed(&mut self) {
        let t = now_us();
        let mut rig = self.0.borrow_mut();
        let gap = rig.watchdog_gap(t);
        rig.max_feed_gap_us = rig.max_feed_gap_us.max(gap);
        rig.last_feed_us = t;
    }
}
