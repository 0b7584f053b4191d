//! Cost of the stepper task's per-step work on the host: pick the earliest due axis, check,
//! record, plan the next instant (the same `State` calls the task makes, minus the timer).
//! Three axes at 400 mm³/s = 10 000 steps/s each.
use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use firmware::app::{Config, State, StepperWait};
use firmware::command::parse;

fn moving_state() -> State {
    let cfg = Config {
        zero_frames: 1,
        ..Config::default()
    };
    let mut s = State::new(cfg);
    // Take the (one-frame) pressure zero so motion commands are accepted.
    let mid = firmware::board::kpa_to_counts(0.0).round() as u16;
    for i in 1..=8 {
        s.on_oversample([mid; 3], i * 5_000);
    }
    let cmd = parse(b"move all 500 400 10000").unwrap();
    s.execute(&cmd, 100_000, &mut heapless::String::<192>::new())
        .unwrap();
    s
}

fn bench(c: &mut Criterion) {
    const STEPS: u64 = 3_000;
    let mut g = c.benchmark_group("stepper");
    g.throughput(Throughput::Elements(STEPS));
    g.bench_function("poll_and_step_3_axes", |b| {
        b.iter_batched(
            moving_state,
            |mut s| {
                let mut now = 0;
                for _ in 0..STEPS {
                    match s.stepper_poll(now, |_, _| {}) {
                        StepperWait::Step { axis, at_us } => {
                            now = at_us;
                            assert!(s.try_step(axis, at_us));
                        }
                        other => panic!("{other:?}"),
                    }
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
