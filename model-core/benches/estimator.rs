//! One 3-chamber estimator step on the host: per chamber P̂, k, c from the SBA1-shaped model, the
//! residual against a measured pressure, then the force estimate. Also one RLS update (N = 12).
//!
//! `CARGO_TARGET_DIR=/tmp/tgt-core cargo bench -p model-core --bench estimator`

use criterion::{criterion_group, criterion_main, Criterion};
use model_core::force::{self, DEFAULT_AREAS_MM2};
use model_core::poly::{self, PolyModel, Scaling, Shape};
use model_core::rls::Rls;
use std::hint::black_box;

fn models() -> [PolyModel; 3] {
    // Three slightly different chambers, as identified per chamber on the device.
    let base = poly::sba1();
    core::array::from_fn(|ch| {
        let mut b = [0.0f32; 12];
        b.copy_from_slice(base.scaled());
        b[1] *= 1.0 + 0.01 * ch as f32;
        PolyModel::from_scaled(Shape::PAPER, &b, &[], Scaling::SBA1).unwrap()
    })
}

fn step(
    models: &[PolyModel; 3],
    v: [f32; 3],
    vdot: [f32; 3],
    measured: [f32; 3],
) -> ([f32; 3], [f32; 3], f32) {
    let mut residual = [0.0f32; 3];
    let (mut k, mut c) = ([0.0f32; 3], [0.0f32; 3]);
    for ch in 0..3 {
        let e = models[ch].eval(v[ch], vdot[ch]).unwrap();
        residual[ch] = measured[ch] - e.p;
        k[ch] = e.k;
        c[ch] = e.c;
    }
    let f = force::estimate(residual, DEFAULT_AREAS_MM2).unwrap();
    (k, c, f.total_n)
}

fn bench(c: &mut Criterion) {
    let models = models();
    c.bench_function("estimator step, 3 chambers (P̂, k, c, force)", |b| {
        b.iter(|| {
            step(
                black_box(&models),
                black_box([310.0, 120.5, 499.0]),
                black_box([40.0, -75.0, 5.0]),
                black_box([20.0, 3.0, 45.0]),
            )
        })
    });
    let mut rls = Rls::<12>::new(0.995, 1.0e3).unwrap();
    let mut phi = [0.0f32; 12];
    let mut t = 0u32;
    c.bench_function("RLS update, N = 12 (U-D, one chamber)", |b| {
        b.iter(|| {
            t = t.wrapping_add(1);
            let v = (t % 550) as f32;
            let f = ((t % 200) as f32) - 100.0;
            poly::regressors(Shape::PAPER, Scaling::SBA1, v, f, &mut phi).unwrap();
            rls.update(black_box(&phi), black_box(20.0)).unwrap()
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);
