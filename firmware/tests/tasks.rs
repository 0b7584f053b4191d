//! The three tasks together under embassy-time's mock driver, with fake hardware: a command
//! through the serial port turns into exactly the planned step instants, telemetry frames are
//! numbered without gaps, and an over-pressure reading stops the steps at that instant.
//!
//! One test per file: the mock driver's clock is process-global.

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::future::{poll_fn, Future};
use std::pin::pin;
use std::rc::Rc;
use std::task::{Context, Poll, Waker};

use embassy_futures::join::join3;
use embassy_time::{Duration, Instant, MockDriver};
use firmware::app::{command_task, sampler_task, stepper_task, Config, Shared};
use firmware::board::kpa_to_counts;
use firmware::hal::{self, Direction, AXES};
use firmware::motion::Trapezoid;
use firmware::telemetry::{parse_line, EventKind, Flags, Line};

#[derive(Default)]
struct Rig {
    steps: RefCell<Vec<(usize, u64)>>,
    dirs: RefCell<Vec<(usize, Direction, u64)>>,
    kpa: Cell<f32>,
    rx: RefCell<VecDeque<u8>>,
    tx: RefCell<Vec<u8>>,
    lines: RefCell<Vec<String>>,
    feeds: Cell<u32>,
}

struct Steppers(Rc<Rig>);
impl hal::Steppers for Steppers {
    fn set_direction(&mut self, axis: usize, dir: Direction) {
        let now = Instant::now().as_micros();
        self.0.dirs.borrow_mut().push((axis, dir, now));
    }
    fn step(&mut self, axis: usize, at: Instant) {
        self.0.steps.borrow_mut().push((axis, at.as_micros()));
    }
    fn set_enabled(&mut self, _: bool) {}
}

struct Adc(Rc<Rig>);
impl hal::PressureAdc for Adc {
    async fn read(&mut self) -> [u16; AXES] {
        [kpa_to_counts(self.0.kpa.get()).round() as u16; AXES]
    }
}

struct Serial(Rc<Rig>);
impl hal::SerialPort for Serial {
    async fn read(&mut self, buf: &mut [u8]) -> Result<usize, hal::SerialError> {
        poll_fn(|_| {
            let mut rx = self.0.rx.borrow_mut();
            if rx.is_empty() {
                return Poll::Pending;
            }
            let n = rx.len().min(buf.len());
            for b in buf.iter_mut().take(n) {
                *b = rx.pop_front().unwrap();
            }
            Poll::Ready(Ok(n))
        })
        .await
    }
    async fn write_all(&mut self, data: &[u8]) {
        self.0.tx.borrow_mut().extend_from_slice(data);
    }
}

struct Sink(Rc<Rig>);
impl hal::TelemetrySink for Sink {
    fn try_send(&mut self, line: &str) -> bool {
        assert!(line.ends_with('\n'), "one whole line");
        self.0.lines.borrow_mut().push(line.trim_end().to_string());
        true
    }
}

struct Wdg(Rc<Rig>);
impl hal::Watchdog for Wdg {
    fn feed(&mut self) {
        self.0.feeds.set(self.0.feeds.get() + 1);
    }
}

#[test]
fn tasks_step_on_plan_report_every_frame_and_stop_on_fault() {
    let rig = Rc::new(Rig::default());
    let shared = Shared::new(Config::default());
    // The host's `origin all 0`: the plungers start at volume 0.
    shared.declare_origin(0.0).unwrap();
    let tasks = join3(
        stepper_task(&shared, Steppers(rig.clone())),
        sampler_task(
            &shared,
            Adc(rig.clone()),
            Sink(rig.clone()),
            Wdg(rig.clone()),
        ),
        command_task(&shared, Serial(rig.clone())),
    );
    let mut tasks = pin!(tasks);
    let mut cx = Context::from_waker(Waker::noop());
    let driver = MockDriver::get();
    driver.reset();
    // Virtual time in 1 ms quanta, every task polled each quantum.
    let mut run_until_ms = |end_ms: u64, rig: &Rig, fault_at_ms: Option<u64>| {
        while Instant::now().as_millis() < end_ms {
            if Some(Instant::now().as_millis()) == fault_at_ms {
                rig.kpa.set(90.0);
            }
            assert!(tasks.as_mut().poll(&mut cx).is_pending());
            driver.advance(Duration::from_millis(1));
        }
    };

    // 1 s of pressure zero at rest, then one move.
    run_until_ms(1_100, &rig, None);
    // Checksummed, as a host sends it (plain lines are refused at boot), ended by `\r\n`.
    let framed = |command: &str, end: &str| {
        let mut line = String::new();
        firmware::command::write_checksummed(command, &mut line).unwrap();
        line + end
    };
    rig.rx
        .borrow_mut()
        .extend(framed("move 0 10 20 500", "\r\n").bytes());
    run_until_ms(3_000, &rig, None);
    // The boot event on the command port when the task started, then the move's reply.
    assert_eq!(
        String::from_utf8(rig.tx.borrow().clone()).unwrap(),
        "$E 0 boot 0 power-on\r\nok\r\n"
    );

    // Exactly 250 steps (10 mm³ / 0.04), each at its analytic instant: command at 1.1 s plus
    // the 1 ms start lead.
    let plan = Trapezoid::new(250, 0.04, 20.0, 500.0);
    let t0 = 1_100_000 + 1_000;
    let steps = rig.steps.borrow().clone();
    assert_eq!(steps.len(), 250);
    for (k, &(axis, at)) in steps.iter().enumerate() {
        assert_eq!(axis, 0);
        assert_eq!(at, t0 + plan.step_offset_us(k as u32 + 1), "step {}", k + 1);
    }
    // DIR was written before the first step, by at least the set-up time.
    let dirs = rig.dirs.borrow().clone();
    assert_eq!(dirs.len(), 1);
    assert_eq!((dirs[0].0, dirs[0].1), (0, Direction::Inflate));
    assert!(dirs[0].2 + 5 <= steps[0].1);

    // Deflate; 90 kPa appears at 3.5 s, during the move.
    rig.rx
        .borrow_mut()
        .extend(framed("move 0 0 20 500", "\n").bytes());
    run_until_ms(5_000, &rig, Some(3_500));
    let steps = rig.steps.borrow().clone();
    let after = &steps[250..];
    assert!(!after.is_empty(), "the move started");
    assert!(after.len() < 250, "the move was cut short");
    assert!(
        after.iter().all(|&(_, at)| at <= 3_500_000),
        "no step after the fault's sampling instant"
    );

    // Telemetry: frames numbered from 0 without gaps, 40 ms apart; the fault is an event and
    // a flag.
    let lines = rig.lines.borrow();
    let mut frames = Vec::new();
    let mut fault_event = false;
    for l in lines.iter() {
        match parse_line(l).expect("every line is telemetry").unwrap() {
            Line::Frame(f) => frames.push(f),
            Line::Event(e) => {
                if let EventKind::Fault { flags } = e.kind {
                    assert!(Flags(flags).has(Flags::channel(Flags::OVER_PRESSURE, 0)));
                    assert_eq!(e.t_us, 3_500_000);
                    fault_event = true;
                }
            }
        }
    }
    assert!(fault_event);
    // The last poll is at 4.999 s: the frame ending at 5 s is not complete yet.
    assert_eq!(frames.len(), 4_999 / 40);
    for (i, f) in frames.iter().enumerate() {
        assert_eq!(f.seq, i as u32);
        // Oversamples at 5, 10, …, 40 ms: the mean instant is 22.5 ms into each frame.
        assert_eq!(f.t_us, 40_000 * i as u64 + 22_500);
    }
    assert!(frames.last().unwrap().flags.is_fault());
    assert!(rig.feeds.get() >= 900, "watchdog fed every oversample");
}
