//! Speed of the exponential (k = 1..10) and neural-network (d = 1..15) sweeps on ~83,000-sample,
//! SBA-like logs: volume on the 0.04 mm³ step grid swept 0..550 mm³ at 20..100 mm³/s, 25 Hz.
//! The exponential sweep runs on two logs: a synthetic one whose volumes fall on a coarse 0.8 mm³
//! grid (few distinct volumes), and the simulated rig's (firmware tasks on host-sim, the paper's
//! protocol with 26 cycles per rate, chamber 0), where ~14,000 distinct volumes make the
//! per-trial cost depend on the data reduction.
//!
//! Run: `cargo bench -p sysid --bench exp_nn` (one sweep: append `-- exp/` or `-- nn`).

use criterion::{criterion_group, criterion_main, Criterion};
use host_sim::{simulate, PlantConfig, Protocol, Scenario};
use std::time::Duration;
use sysid::{exp, nn};

const N: usize = 83_000;

/// The paper's protocol (Sec. II): strokes 0 → 550 → 0 mm³ at 20, 40, .., 100 mm³/s, sampled at
/// 25 Hz, so volumes lie on a 0.8 mm³ grid. Pressure: two exponentials, a flow term with a
/// flow-volume interaction, and a deterministic ripple standing in for noise.
fn sba_log(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let (mut v, mut q, mut p) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    let dt = 0.04;
    let (mut steps, mut dir, mut stroke) = (0i64, 1i64, 0usize);
    for t in 0..n {
        let rate = 20.0 * (1 + stroke % 5) as f64;
        let next = (steps + dir * (rate * dt / 0.04).round() as i64).clamp(0, 13_750);
        if next == 13_750 {
            dir = -1;
        } else if next == 0 {
            dir = 1;
            stroke += 1;
        }
        let vol = next as f64 * 0.04;
        let flow = (next - steps) as f64 * 0.04 / dt;
        steps = next;
        let elastic = 2.0 * (vol / 120.0).exp() - 1.5 * (-vol / 40.0).exp();
        let ripple = 0.3 * (t as f64 * 1.7).sin();
        v.push(vol);
        q.push(flow);
        p.push(elastic + 0.05 * flow * (1.0 + vol / 550.0) + ripple);
    }
    (v, q, p)
}

/// Chamber 0 of the simulated rig running the paper's protocol with 26 cycles per rate.
fn hostsim_log() -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let protocol = Protocol {
        cycles: 26,
        ..Protocol::paper()
    };
    let run = simulate(&Scenario::protocol(
        "bench",
        PlantConfig::default(),
        &protocol,
    ))
    .expect("the paper protocol simulates");
    let (mut v, mut q, mut p) = (Vec::new(), Vec::new(), Vec::new());
    for r in run.rows().filter(|r| r.chamber == 0) {
        v.push(f64::from(r.volume_mm3));
        q.push(f64::from(r.flow_mm3_s));
        p.push(f64::from(r.pressure_kpa));
    }
    (v, q, p)
}

fn bench_exp(c: &mut Criterion) {
    let (v, q, p) = sba_log(N);
    let mut g = c.benchmark_group("exp");
    g.sample_size(20);
    g.bench_function("sweep_k1_10_83k", |b| b.iter(|| exp::sweep(&v, &q, &p, 10)));
    let (v, q, p) = hostsim_log();
    let name = format!("sweep_k1_10_hostsim_{}k", v.len() / 1000);
    g.bench_function(name, |b| b.iter(|| exp::sweep(&v, &q, &p, 10)));
    g.finish();
}

/// The paper's neural sweep d = 1..15 (p = 0) with the default training settings, on 2 threads.
fn bench_nn(c: &mut Criterion) {
    let (v, q, p) = sba_log(N);
    let cfg = nn::SweepConfig {
        threads: 2,
        ..nn::SweepConfig::default()
    };
    let inputs = nn::Inputs {
        v: &v,
        vdot: &q,
        ar_order: 0,
    };
    let mut g = c.benchmark_group("nn");
    g.sample_size(10);
    g.measurement_time(Duration::from_secs(60));
    g.bench_function("sweep_d1_15_83k_2threads", |b| {
        b.iter(|| nn::sweep(&inputs, &p, &cfg))
    });
    // What `vfp identify --family nn` trains (Table III): d = 1..15 at p = 0, then p = 1..5 at
    // d = 8, as two sweeps.
    let ar = nn::SweepConfig {
        depths: vec![8],
        ar_orders: (1..=5).collect(),
        ..cfg.clone()
    };
    g.bench_function("paper_d1_15_and_ar1_5_d8_83k_2threads", |b| {
        b.iter(|| (nn::sweep(&inputs, &p, &cfg), nn::sweep(&inputs, &p, &ar)))
    });
    g.finish();
}

criterion_group!(benches, bench_exp, bench_nn);
criterion_main!(benches);
