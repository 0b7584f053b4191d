//! Cost of the stepper task's per-step work on the host: the same `Shared::stepper_tick` call the
//! task makes at each wake-up (pick the due axes, check, record, plan the next instant, pulse),
//! minus the timer. Three axes at 400 mm³/s = 10 000 steps/s each.
use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use embassy_time::Instant;
use firmware::app::{Config, Sampler, Shared};
use firmware::hal::{Direction, Steppers};

/// Pulses go nowhere.
struct NoPins;
impl Steppers for NoPins {
    fn set_direction(&mut self, _: usize, _: Direction) {}
    fn step(&mut self, _: usize, _: Instant) {}
    fn set_enabled(&mut self, _: bool) {}
}

fn moving_state() -> Shared {
    let cfg = Config {
        zero_frames: 1,
        ..Config::default()
    };
    let shared = Shared::new(cfg);
    shared.declare_origin(0.0).unwrap();
    let mut sampler = Sampler::new(&cfg);
    // Take the (one-frame) pressure zero so motion commands are accepted.
    let mid = firmware::board::kpa_to_counts(0.0).round() as u16;
    for i in 1..=8 {
        if let Some(acc) = shared.conversion(&mut sampler, [mid; 3], i * 5_000).frame {
            let mut est = shared.estimator().try_lock().unwrap();
            shared.finish_frame(&mut est, &acc);
        }
    }
    let mut reply = String::new();
    let mut line = String::new();
    firmware::command::write_checksummed("move all 500 400 10000", &mut line).unwrap();
    shared.command_line(line.as_bytes(), 100_000, &mut reply);
    assert_eq!(reply, "ok");
    shared
}

fn bench(c: &mut Criterion) {
    const WAKEUPS: u64 = 1_000;
    let mut g = c.benchmark_group("stepper");
    g.throughput(Throughput::Elements(3 * WAKEUPS));
    g.bench_function("tick_3_axes", |b| {
        b.iter_batched(
            moving_state,
            |s| {
                let mut now = 0;
                for _ in 0..WAKEUPS {
                    now = s.stepper_tick(now, &mut NoPins);
                }
                s
            },
            BatchSize::SmallInput,
        )
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
