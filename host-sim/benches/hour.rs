//! One hour of rig time: three chambers cycling, every step event applied to the plant, 25 Hz
//! frames from the firmware's own tasks. Target ≤ 10 s on the project's 2-core machine.
//!
//! `cargo bench -p host-sim --bench hour`
use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::{simulate, Scenario};

fn hour(c: &mut Criterion) {
    let mut g = c.benchmark_group("rig_hour");
    // Each iteration is seconds long: the minimum sample count, no extra warm-up.
    g.sample_size(10);
    g.warm_up_time(std::time::Duration::from_millis(1));
    g.measurement_time(std::time::Duration::from_secs(30));
    for (name, full) in [("paper_rates_20_40_60", false), ("full_speed_100", true)] {
        let sc = Scenario::rig_hour(full);
        g.bench_function(name, |b| {
            b.iter(|| {
                let run = simulate(&sc).expect("valid scenario");
                assert_eq!(run.frames.len(), 90_000);
                run.stats.steps
            })
        });
    }
    g.finish();
}

criterion_group!(benches, hour);
criterion_main!(benches);
