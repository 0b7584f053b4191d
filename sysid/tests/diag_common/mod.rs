//! Test data with known truth for the diagnostics tests.
//!
//! Generator: sysid's protocol trajectory (`synth::Protocol`, 0 ↔ v_max at several flow rates,
//! 25 Hz, step-quantised volume) through a known polynomial law (the paper's SBA1, Table IV, or a
//! scaled variant), plus Gaussian noise that is white (ρ = 0) or AR(1):
//! eₜ = ρ eₜ₋₁ + √(1 − ρ²) σ zₜ, zₜ ~ N(0, 1), so its variance is σ² either way.
#![allow(dead_code)]

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use sysid::log::{write_log, Log, Sample};
use sysid::synth::{eval_raw, Protocol, Trajectory, SBA1_RAW};

/// A short protocol: `samples` at 25 Hz over rates 20..100 mm³/s.
pub fn protocol(samples: usize, v_max: f64) -> Trajectory {
    Protocol {
        samples,
        v_max,
        ..Protocol::default()
    }
    .trajectory()
}

/// AR(1) Gaussian noise of standard deviation σ.
pub fn ar1_noise(n: usize, sigma: f64, rho: f64, seed: u64) -> Vec<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let z = Normal::new(0.0, 1.0).unwrap();
    let mut e = sigma * z.sample(&mut rng);
    (0..n)
        .map(|_| {
            let out = e;
            e = rho * e + (1.0 - rho * rho).sqrt() * sigma * z.sample(&mut rng);
            out
        })
        .collect()
}

/// Pressure of the law `raw` (n = 3, m = 2) on a trajectory, plus noise.
pub fn pressure(raw: &[f64], tr: &Trajectory, noise: &[f64]) -> Vec<f64> {
    tr.v.iter()
        .zip(&tr.vdot)
        .zip(noise)
        .map(|((&v, &q), e)| eval_raw(raw, 3, 2, v, q) + e)
        .collect()
}

/// The SBA1 law with the elastic part K(v) scaled by `ks` and the flow part C·v̇ by `cs`.
pub fn scaled_sba1(ks: f64, cs: f64) -> [f64; 12] {
    let mut r = SBA1_RAW;
    for (idx, a) in r.iter_mut().enumerate() {
        *a *= if idx % 3 == 0 { ks } else { cs };
    }
    r
}

/// Exact ∂P/∂v and ∂P/∂v̇ of a raw (n = 3, m = 2) law, by hand-differentiated monomials.
pub fn raw_partials(raw: &[f64], v: f64, q: f64) -> (f64, f64) {
    let (mut k, mut c) = (0.0, 0.0);
    for i in 0..=3 {
        for j in 0..=2 {
            let a = raw[i * 3 + j];
            if i > 0 {
                k += a * i as f64 * v.powi(i as i32 - 1) * q.powi(j as i32);
            }
            if j > 0 {
                c += a * j as f64 * v.powi(i as i32) * q.powi(j as i32 - 1);
            }
        }
    }
    (k, c)
}

/// Writes a one-chamber (or several identical-time chambers) log with flow and optional force.
pub fn write(
    path: &std::path::Path,
    tr: &Trajectory,
    chambers: &[(u8, Vec<f64>, Vec<f64>)],
    force: Option<&[f64]>,
    meta: &[(&str, String)],
) {
    let mut log = Log::default();
    for (k, v) in meta {
        log.set_metadata(k, v);
    }
    for i in 0..tr.t.len() {
        for (c, v, p) in chambers {
            let mut s = Sample::new(tr.t[i], *c, v[i], p[i]);
            s.flow_mm3_s = Some(tr.vdot[i]);
            s.force_n = force.map(|f| f[i]);
            log.push(s);
        }
    }
    write_log(path, &log).unwrap();
}

/// A fresh empty directory under the target's tmp dir.
pub fn tmpdir(name: &str) -> std::path::PathBuf {
    let d = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("vfp-diag-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}
