//! The virtual rig: the firmware ELF running on the emulated board, its STEP/DIR/EN pins driving
//! host-sim's plant, the plant's sensors on its ADC pins, and a host on its command port.
//!
//! The emulator runs on a thread of its own. Its driver ([`RigDriver`]) sees every peripheral
//! access the firmware makes: after each write to GPIOA or GPIOB it reads the STEP, DIR and EN
//! pins' electrical levels off the port models, and each rising STEP edge while the drivers are
//! enabled (EN low) is one motor step of the plant at the edge's virtual instant
//! ([`host_sim::plant::Plant::step`], the same physics as the simulated board's). When the
//! firmware starts a conversion (ADC1's SWSTART) the driver converts the plant's sensors at that
//! instant ([`Plant::adc_counts`]: pressure, sensor lag, noise, the firmware's own transfer
//! function) and puts the voltages on ADC1's pins, which the converter samples. Every virtual
//! millisecond the run stops, and there the test thread can act on the session: queue bytes on
//! the host's wire, read what the firmware sent, look at the pins and the plant.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::thread::JoinHandle;
use std::time::Duration;

use host_sim::plant::Plant;
use host_sim::PlantConfig;
use rigless::device::Level;
use rigless::emulator::{self, Access, AccessKind, Driver, Host, Settled, Start, Stop, StopReason};
use rigless::image::Image;
use rigless::session::Session;
use rigless::soc::Width;
use rigless::time::VirtualNanos;

use crate::board::{Nucleo, DIR, ENABLE, STEP};
use crate::wire::Stream;

/// GPIOA and GPIOB's register blocks (RM0390 table 1): the ports the step, direction and enable
/// pins are on.
const GPIO_AB: std::ops::Range<u64> = 0x4002_0000..0x4002_0800;
/// ADC1's CR2 (RM0390 13.13.3) and its SWSTART bit: a regular conversion starts.
const ADC1_CR2: u64 = 0x4001_2008;
const SWSTART: u64 = 1 << 30;
/// The flash interface's access control and control registers (RM0390 3.8): the caches and
/// the erase and program operations.
pub const FLASH_ACR: u64 = 0x4002_3C00;
/// See [`FLASH_ACR`].
pub const FLASH_CR: u64 = 0x4002_3C10;
/// How often the driver hands the test thread a stop (and reads the pins and the host's wire
/// there) while it runs.
const STOP_PERIOD_NS: u64 = 1_000_000;

/// One motor step the plant took.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepEvent {
    /// Virtual instant of the rising STEP edge, ns.
    pub at_ns: u64,
    /// Axis 0..3.
    pub axis: usize,
    /// DIR high (inflate) at the edge.
    pub inflate: bool,
}

/// What the driver keeps: the plant and everything it saw of the pins.
#[derive(Debug)]
pub struct Bench {
    /// host-sim's plant, driven by the pins.
    pub plant: Plant,
    /// Every step the plant took, in order.
    pub steps: Vec<StepEvent>,
    /// STEP edges seen while the drivers were disabled (EN high or floating high): not steps.
    pub steps_while_disabled: u64,
    /// Every change of the drivers' enable (true = enabled, EN low), with its instant, ns.
    pub enable_changes: Vec<(u64, bool)>,
    /// Every write the firmware made to [`FLASH_ACR`] or [`FLASH_CR`]: (instant ns, address,
    /// value). The flash model neither erases nor programs the array, but the sequence of
    /// operations and cache resets the firmware asks for is here.
    pub flash_writes: Vec<(u64, u64, u64)>,
    /// Whether the drivers are enabled now.
    pub enabled: bool,
    step_level: [Level; 3],
    /// The host-side reader of the command port (replies and telemetry packets).
    pub stream: Stream,
    /// Bytes of the host's record already fed to `stream`.
    fed: usize,
}

impl Bench {
    fn new(plant: Plant) -> Self {
        Self {
            plant,
            steps: Vec::new(),
            steps_while_disabled: 0,
            enable_changes: Vec::new(),
            flash_writes: Vec::new(),
            enabled: false,
            step_level: [Level::Low; 3],
            stream: Stream::default(),
            fed: 0,
        }
    }

    /// Net steps by axis.
    pub fn net_steps(&self) -> [i64; 3] {
        core::array::from_fn(|i| self.plant.steps(i))
    }

    fn pins(&mut self, board: &mut Nucleo, at_ns: u64) {
        let enabled = board.level(ENABLE) == Level::Low;
        if enabled != self.enabled {
            self.enabled = enabled;
            self.enable_changes.push((at_ns, enabled));
        }
        for axis in 0..3 {
            let level = board.level(STEP[axis]);
            if level == Level::High && self.step_level[axis] == Level::Low {
                if self.enabled {
                    let inflate = board.level(DIR[axis]) == Level::High;
                    self.plant.step(axis, at_ns / 1000, inflate);
                    self.steps.push(StepEvent {
                        at_ns,
                        axis,
                        inflate,
                    });
                } else {
                    self.steps_while_disabled += 1;
                }
            }
            self.step_level[axis] = level;
        }
    }

    fn feed_host(&mut self, board: &mut Nucleo) {
        let bytes = board.host().received_bytes();
        for &(at, b) in &bytes[self.fed..] {
            self.stream.push(at.0, b);
        }
        self.fed = bytes.len();
    }
}

type Action = Box<dyn FnOnce(&mut Session<Nucleo>, &mut Bench, &mut dyn Host) + Send>;

enum Request {
    RunUntil(u64),
    With(Action),
    Finish,
}

/// The emulator's driver: the pins to the plant, the plant to the ADC, the test's requests.
struct RigDriver {
    bench: Bench,
    requests: Receiver<Request>,
    reached: Sender<u64>,
    target_ns: u64,
}

impl RigDriver {
    fn convert(&mut self, session: &mut Session<Nucleo>, now_ns: u64) {
        let counts = self.bench.plant.adc_counts(now_ns / 1000);
        session.board_mut().set_sensor_counts(counts);
    }
}

impl Driver<Nucleo> for RigDriver {
    fn on_settled(
        &mut self,
        session: &mut Session<Nucleo>,
        _host: &mut dyn Host,
        settled: Settled,
    ) {
        let access = match settled {
            Settled::Access { access, .. } => access,
            // A reset puts the ports back to inputs with no access the driver would see.
            Settled::Stop(stop) if stop.reason == StopReason::Reset => {
                self.bench.pins(session.board_mut(), stop.at.0);
                return;
            }
            _ => return,
        };
        if access.kind != AccessKind::Write {
            return;
        }
        if access.address == FLASH_ACR || access.address == FLASH_CR {
            self.bench
                .flash_writes
                .push((access.virtual_time.0, access.address, access.value));
        } else if GPIO_AB.contains(&access.address) {
            self.bench.pins(session.board_mut(), access.virtual_time.0);
        } else if access.address == ADC1_CR2 && access.value & SWSTART != 0 {
            // The converter samples its pin when the conversion starts (the model computes the
            // word at its end, from the input then): the plant's sensors at this instant.
            self.convert(session, access.virtual_time.0);
        }
    }

    fn on_stop(
        &mut self,
        session: &mut Session<Nucleo>,
        stop: Stop,
        host: &mut dyn Host,
    ) -> Option<VirtualNanos> {
        let now = stop.at.0;
        self.bench.feed_host(session.board_mut());
        if now >= self.target_ns {
            if self.reached.send(now).is_err() {
                return None;
            }
            loop {
                match self.requests.recv() {
                    Ok(Request::With(action)) => {
                        action(session, &mut self.bench, host);
                        self.bench.feed_host(session.board_mut());
                    }
                    Ok(Request::RunUntil(t)) => {
                        self.target_ns = t.max(now + 1);
                        break;
                    }
                    Ok(Request::Finish) | Err(_) => return None,
                }
            }
        }
        // Both are past `now`: the target was set past it, the next whole millisecond is.
        let next_ms = (now / STOP_PERIOD_NS + 1) * STOP_PERIOD_NS;
        Some(VirtualNanos(self.target_ns.min(next_ms)))
    }
}

/// How to build a virtual rig.
#[derive(Clone, Debug)]
pub struct RigConfig {
    /// The firmware ELF (the `firmware` profile's `vfp-fw`).
    pub elf: PathBuf,
    /// The plant (host-sim's), its effects and its sensors.
    pub plant: PlantConfig,
    /// Seed of the plant's noise streams.
    pub seed: u64,
}

impl RigConfig {
    /// The default plant (host-sim's SBA1 rig with its 3 ms delivery lag and sensor noise).
    pub fn new(elf: impl Into<PathBuf>) -> Self {
        Self {
            elf: elf.into(),
            plant: PlantConfig::default(),
            seed: 1,
        }
    }
}

/// Why a rig could not start or went away.
#[derive(Debug, thiserror::Error)]
pub enum RigError {
    /// The ELF could not be read or placed.
    #[error("firmware image {path}: {message}")]
    Image {
        /// The ELF's path.
        path: PathBuf,
        /// rigless's reason.
        message: String,
    },
    /// The board or the session could not be built.
    #[error("virtual board: {0}")]
    Board(String),
    /// The plant's configuration is invalid.
    #[error("plant: {0}")]
    Plant(String),
    /// The emulator stopped on its own (its error, or a panic on its thread).
    #[error("the emulator stopped: {0}")]
    Stopped(String),
}

/// What the emulator thread returns.
pub struct Outcome {
    /// Resets the session saw, as `(instant ns, cause)`.
    pub resets: Vec<(u64, String)>,
    /// Registers the part carries and no model implements that the firmware touched.
    pub unimplemented: Vec<String>,
    /// Addresses no register covers that the firmware touched.
    pub unmapped: Vec<String>,
}

/// A running virtual rig. Time stands still between calls.
pub struct Rig {
    requests: Sender<Request>,
    reached: Receiver<u64>,
    thread: Option<JoinHandle<Result<Outcome, RigError>>>,
    now_ns: u64,
}

impl Rig {
    /// Boot the ELF on a fresh board (power-on reset) and stop at the first millisecond.
    pub fn start(config: &RigConfig) -> Result<Self, RigError> {
        Self::start_with(config, |_| {})
    }

    /// Like [`Rig::start`], with `prepare` run on the board before the first instruction (bytes
    /// already on the host's wire, sensors not at rest).
    pub fn start_with(
        config: &RigConfig,
        prepare: impl FnOnce(&mut Nucleo) + Send + 'static,
    ) -> Result<Self, RigError> {
        let image = Image::read(&config.elf, None).map_err(|e| RigError::Image {
            path: config.elf.clone(),
            message: e.to_string(),
        })?;
        let plant = Plant::new(&config.plant, &[], config.seed)
            .map_err(|e| RigError::Plant(e.to_string()))?;
        let mut board = Nucleo::new().map_err(|e| RigError::Board(e.to_string()))?;
        prepare(&mut board);
        let mut bench = Bench::new(plant);
        bench.pins(&mut board, 0);
        let (req_tx, req_rx) = channel();
        let (reached_tx, reached_rx) = channel();
        let thread = std::thread::Builder::new()
            .name("virtual-rig".into())
            .spawn(move || {
                let session = Session::new(Box::new(board), 0, VirtualNanos(STOP_PERIOD_NS))
                    .map_err(|e| RigError::Board(e.to_string()))?;
                let driver = RigDriver {
                    bench,
                    requests: req_rx,
                    reached: reached_tx,
                    target_ns: STOP_PERIOD_NS,
                };
                let images = [image];
                let start = Start::new(&images);
                let finished = emulator::run(session, &start, driver)
                    .map_err(|e| RigError::Stopped(e.to_string()))?;
                let session = finished.session;
                Ok(Outcome {
                    resets: session
                        .resets()
                        .iter()
                        .map(|r| (r.at.0, format!("{:?}", r.cause)))
                        .collect(),
                    unimplemented: session
                        .unimplemented()
                        .values()
                        .map(|u| format!("{u:?}"))
                        .collect(),
                    unmapped: session.unmapped().iter().map(|u| u.to_string()).collect(),
                })
            })
            .map_err(|e| RigError::Board(e.to_string()))?;
        let mut rig = Self {
            requests: req_tx,
            reached: reached_rx,
            thread: Some(thread),
            now_ns: 0,
        };
        rig.wait()?;
        Ok(rig)
    }

    fn wait(&mut self) -> Result<(), RigError> {
        match self.reached.recv() {
            Ok(t) => {
                self.now_ns = t;
                Ok(())
            }
            Err(_) => Err(self.stopped()),
        }
    }

    /// The emulator thread's end, as an error.
    fn stopped(&mut self) -> RigError {
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(Err(e))) => e,
            Some(Ok(Ok(_))) => RigError::Stopped("the run ended".into()),
            Some(Err(panic)) => RigError::Stopped(
                panic
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| panic.downcast_ref::<&str>().map(|s| (*s).to_string()))
                    .unwrap_or_else(|| "a panic on the emulator's thread".into()),
            ),
            None => RigError::Stopped("already stopped".into()),
        }
    }

    /// Virtual time now, ns.
    pub fn now_ns(&self) -> u64 {
        self.now_ns
    }

    /// Run to the virtual instant `t_ns`.
    pub fn run_until(&mut self, t_ns: u64) -> Result<(), RigError> {
        if self.requests.send(Request::RunUntil(t_ns)).is_err() {
            return Err(self.stopped());
        }
        self.wait()
    }

    /// Run for `d` of virtual time.
    pub fn run_for(&mut self, d: Duration) -> Result<(), RigError> {
        self.run_until(self.now_ns + d.as_nanos() as u64)
    }

    /// Act on the session and the bench at the current instant.
    pub fn with<R: Send + 'static>(
        &mut self,
        f: impl FnOnce(&mut Session<Nucleo>, &mut Bench) -> R + Send + 'static,
    ) -> Result<R, RigError> {
        self.with_host(move |s, b, _| f(s, b))
    }

    /// Act on the session, the bench and the emulator's host (memory, core) at the current
    /// instant.
    pub fn with_host<R: Send + 'static>(
        &mut self,
        f: impl FnOnce(&mut Session<Nucleo>, &mut Bench, &mut dyn Host) -> R + Send + 'static,
    ) -> Result<R, RigError> {
        let (tx, rx) = channel();
        let action: Action = Box::new(move |s, b, h| {
            let _ = tx.send(f(s, b, h));
        });
        if self.requests.send(Request::With(action)).is_err() {
            return Err(self.stopped());
        }
        match rx.recv() {
            Ok(r) => Ok(r),
            Err(_) => Err(self.stopped()),
        }
    }

    /// Write `value` to the 32-bit register at `address` from outside the core, as a debugger
    /// does (the models see the write; no instruction made it): fault injection.
    pub fn poke(&mut self, address: u64, value: u32) -> Result<(), RigError> {
        let at = VirtualNanos(self.now_ns);
        self.with_host(move |s, _, h| {
            let access =
                Access::new(AccessKind::Write, address, Width::W32, u64::from(value)).at(0, at);
            let _ = s.access(access, h);
        })
    }

    /// Fail the core's next access to `from..to` (it takes it as a bus error; no model sees it).
    pub fn fail_next(&mut self, from: u64, to: u64) -> Result<(), RigError> {
        self.with(move |s, _| s.fail_next(from, to))
    }

    /// Put `bytes` on the host's wire from now on.
    pub fn send(&mut self, bytes: &[u8]) -> Result<(), RigError> {
        let bytes = bytes.to_vec();
        let at = VirtualNanos(self.now_ns);
        self.with(move |s, _| s.board_mut().host().send_at(at, &bytes))
    }

    /// Send `command` as a plain line, without a checksum: the firmware refuses it from boot
    /// (`err checksum-required`) unless it is `stop` or `checksum optional` came first.
    pub fn send_line(&mut self, command: &str) -> Result<(), RigError> {
        self.send(format!("{command}\n").as_bytes())
    }

    /// Text lines received so far.
    pub fn lines(&mut self) -> Result<Vec<String>, RigError> {
        self.with(|_, b| b.stream.lines())
    }

    /// Run in 5 ms slices until a text line received after `since` lines satisfies `pred`, for at
    /// most `limit` of virtual time; the line, or `None` when none came.
    pub fn wait_line(
        &mut self,
        since: usize,
        limit: Duration,
        pred: impl Fn(&str) -> bool,
    ) -> Result<Option<String>, RigError> {
        let end = self.now_ns + limit.as_nanos() as u64;
        loop {
            let lines = self.lines()?;
            if let Some(l) = lines.iter().skip(since).find(|l| pred(l)) {
                return Ok(Some(l.clone()));
            }
            if self.now_ns >= end {
                return Ok(None);
            }
            self.run_until((self.now_ns + 5_000_000).min(end))?;
        }
    }

    /// Send `command` (checksummed) and return the first reply line after it (`ok…` or `err…`),
    /// waiting at most a virtual second.
    pub fn command(&mut self, command: &str) -> Result<Option<String>, RigError> {
        let mut line = String::new();
        firmware::command::write_checksummed(command, &mut line)
            .map_err(|_| RigError::Board(format!("cannot checksum {command:?}")))?;
        line.push('\n');
        self.exchange(line.as_bytes())
    }

    /// Send `bytes` as they are and return the first reply line after them, waiting at most a
    /// virtual second.
    pub fn exchange(&mut self, bytes: &[u8]) -> Result<Option<String>, RigError> {
        let since = self.lines()?.len();
        self.send(bytes)?;
        self.wait_line(since, Duration::from_secs(1), is_reply)
    }

    /// Wait at most `limit` for the board's next boot event on the command port (`$E … boot …`).
    pub fn next_boot(&mut self, limit: Duration) -> Result<Option<String>, RigError> {
        let since = self.lines()?.len();
        self.wait_line(since, limit, |l| {
            l.starts_with("$E ") && l.contains(" boot ")
        })
    }

    /// Run until the board has taken its start-up pressure zero (`status` without
    /// `NOT_ZEROED`), polling every 100 ms for at most 5 virtual seconds; the last status.
    pub fn until_zeroed(&mut self) -> Result<String, RigError> {
        let not_zeroed = firmware::telemetry::Flags::NOT_ZEROED;
        let end = self.now_ns + 5_000_000_000;
        loop {
            let status = self.command("status")?.unwrap_or_default();
            let flags = status_flags(&status).unwrap_or(u32::MAX);
            if flags & not_zeroed == 0 || self.now_ns >= end {
                return Ok(status);
            }
            self.run_for(Duration::from_millis(100))?;
        }
    }

    /// [`Rig::until_zeroed`], then declare the plungers at volume 0 (`origin all 0`), as a lab
    /// does after every reset before the first move; the status after it.
    pub fn ready(&mut self) -> Result<String, RigError> {
        self.until_zeroed()?;
        match self.command("origin all 0")? {
            Some(reply) if reply == "ok" => {}
            other => {
                return Err(RigError::Stopped(format!(
                    "`origin all 0` answered {other:?}"
                )))
            }
        }
        Ok(self.command("status")?.unwrap_or_default())
    }

    /// Run until the board reports every axis idle and no `run` going (`status`), polling every
    /// virtual second for at most `limit`; whether it came to rest.
    pub fn until_at_rest(&mut self, limit: Duration) -> Result<bool, RigError> {
        let end = self.now_ns + limit.as_nanos() as u64;
        while self.now_ns < end {
            self.run_for(Duration::from_secs(1))?;
            let status = self.command("status")?.unwrap_or_default();
            if status.contains(" moving 0 run 0 ") {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// End the run and return what the session saw.
    pub fn finish(mut self) -> Result<Outcome, RigError> {
        let _ = self.requests.send(Request::Finish);
        match self.thread.take().map(JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => Err(RigError::Stopped("a panic on the emulator's thread".into())),
            None => Err(RigError::Stopped("already stopped".into())),
        }
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        let _ = self.requests.send(Request::Finish);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The `flags` field of a `status` reply.
pub fn status_flags(status: &str) -> Option<u32> {
    status
        .split_whitespace()
        .skip_while(|w| *w != "flags")
        .nth(1)?
        .parse()
        .ok()
}

/// Whether a text line is a command's reply.
pub fn is_reply(line: &str) -> bool {
    line.starts_with("ok") || line.starts_with("err")
}

/// A command running the main workspace's `vfp`: `VFP_BIN`, or its dev or release build (the
/// tests that close the loop through the command-line tool).
pub fn vfp() -> std::process::Command {
    let path = std::env::var_os("VFP_BIN").map(PathBuf::from).unwrap_or_else(|| {
        let target = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target");
        ["debug", "release"]
            .iter()
            .map(|p| target.join(p).join("vfp"))
            .find(|p| p.exists())
            .unwrap_or_else(|| {
                panic!("no vfp binary: build it first (`cargo build -p vfp` in the main workspace) or set VFP_BIN")
            })
    });
    std::process::Command::new(path)
}

/// The ELF the rig runs by default: `VFP_FW_ELF`, or the `firmware` profile's build in the main
/// workspace's target directory.
pub fn default_elf() -> PathBuf {
    if let Some(p) = std::env::var_os("VFP_FW_ELF") {
        return PathBuf::from(p);
    }
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/thumbv7em-none-eabihf/firmware/vfp-fw")
}

/// The `fault-injection` build of the firmware (its user button overflows the stack or panics):
/// `VFP_FW_FAULTS_ELF`, or `vfp-fw-fault-injection` beside the default ELF, where `.ci/run` and
/// the README's recipe put it (`cargo fw --features fault-injection`, then the copy).
pub fn fault_injection_elf() -> PathBuf {
    if let Some(p) = std::env::var_os("VFP_FW_FAULTS_ELF") {
        return PathBuf::from(p);
    }
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../target/thumbv7em-none-eabihf/firmware/vfp-fw-fault-injection")
}
