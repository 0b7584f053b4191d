//! `vfp diagnose` on a ~20,000-sample log (13 min at 25 Hz) with one injected effect (sensor lag):
//! the whole loop — baseline, residual analysis, every candidate's parameter search, forward
//! selection, final analysis.
//!
//! `cargo bench -p sysid --bench diagnose`

use criterion::{criterion_group, criterion_main, Criterion};
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::residual::cli::series_from_dataset;
use sysid::residual::{diagnose, Config};

#[path = "../tests/residual_gen.rs"]
mod gen;

fn bench(c: &mut Criterion) {
    // 6 cycles per rate of the five-rate protocol: 19,800 samples at 25 Hz (13.2 min).
    let g = gen::generate(
        &[gen::Inject::SensorLag { tau_s: 0.12 }],
        &[20.0, 40.0, 60.0, 80.0, 100.0],
        6,
        0.05,
        7,
    );
    let n = g.t.len();
    let ds = Dataset::from_columns(g.t, g.v, g.vdot, g.p, &DatasetConfig::default());
    let series = series_from_dataset(&ds).expect("valid series");
    let mut group = c.benchmark_group("diagnose");
    group.sample_size(10);
    group.bench_function(format!("{n}_samples"), |b| {
        b.iter(|| diagnose(series.clone(), &Config::default()).expect("runs"))
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
