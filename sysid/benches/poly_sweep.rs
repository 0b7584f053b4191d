//! All 49 polynomial models (n, m = 1..=7) on 83 000 samples of the paper-like protocol with the
//! SBA1 law plus noise: one moment pass and 49 small Cholesky solves.
//!
//! Run: `cargo bench -p sysid --bench poly_sweep`

use criterion::{criterion_group, criterion_main, Criterion};
use sysid::poly::{self, Scaling, Xy};
use sysid::synth::{self, Protocol, SBA1_RAW};

fn bench(c: &mut Criterion) {
    let tr = Protocol::default().trajectory();
    let p = synth::pressure(&SBA1_RAW, 3, 2, &tr, 0.5, 1);
    let xy = Xy {
        v: &tr.v,
        vdot: &tr.vdot,
        p: &p,
    };
    let sc = Scaling::from_data(&tr.v, &tr.vdot).expect("protocol data are valid");
    c.bench_function("poly sweep 49 models, 83k samples", |b| {
        b.iter(|| {
            let r = poly::sweep(xy, None, &sc, 7, 7).expect("sweep runs");
            assert_eq!(r.len(), 49);
            r
        })
    });
    c.bench_function("poly fit (3,2) by QR with statistics, 83k samples", |b| {
        b.iter(|| poly::fit(xy, 3, 2, Some(sc)).expect("fit runs"))
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = bench
}
criterion_main!(benches);
