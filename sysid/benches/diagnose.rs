//! `vfp diagnose` on a ~20,000-sample log of the simulated rig (host-sim, the firmware's own tasks;
//! the default lagged drive, a 20 ms sensor lag injected; six cycles of the paper's five-rate
//! protocol: 19,386 frames, 19,362 after the boot frames that take the pressure zero, 13 min at 25 Hz): the whole loop with the paper's (3, 2) baseline —
//! baseline, residual analysis, every candidate's parameter search, forward selection, final
//! analysis — and with a (7, 7) baseline (64 columns, the shape the CLI's AICc default often
//! picks). Simulating the log is not timed.
//!
//! `cargo bench -p sysid --bench diagnose`

use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::{simulate, Protocol, Scenario};
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::log::parse_log;
use sysid::residual::series_from_dataset;
use sysid::residual::{diagnose, Config};

fn bench(c: &mut Criterion) {
    let base = Scenario::effect("sensor-lag").expect("preset");
    let sc = Scenario::protocol(
        &base.name,
        base.plant,
        &Protocol {
            cycles: 6,
            ..Protocol::paper()
        },
    );
    let run = simulate(&sc).expect("scenario runs");
    let mut bytes = Vec::new();
    run.write_log(&mut bytes).expect("in memory");
    let log = parse_log(&bytes[..], "bench").expect("log parses");
    let ds = Dataset::from_log(&log, 0, &DatasetConfig::default()).expect("dataset");
    let n = ds.t.len();
    let series = series_from_dataset(&ds).expect("valid series");
    let mut group = c.benchmark_group("diagnose");
    group.sample_size(10);
    group.bench_function(format!("{n}_samples"), |b| {
        b.iter(|| diagnose(series.clone(), &Config::default()).expect("runs"))
    });
    // The CLI's default baseline is the AICc-selected shape, often (7, 7): 64 columns, where the
    // parameter searches' Gram matrices dominate.
    let big = Config {
        n: 7,
        m: 7,
        ..Config::default()
    };
    group.bench_function(format!("{n}_samples_baseline_7_7"), |b| {
        b.iter(|| diagnose(series.clone(), &big).expect("runs"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
