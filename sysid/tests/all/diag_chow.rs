//! Chow test (§IV-B): calibration under H₀ (the same actuator, new noise), power between
//! different laws, and the classic statistic against its defining formula.

use crate::diag_common;
use diag_common::*;
use sysid::diag::chow::{chow, ChowOptions, ChowTest, Method};
use sysid::poly::{self, Xy};
use sysid::synth::SBA1_RAW;

const N: usize = 1200;

fn pair(law_b: &[f64], rho: f64, seed: u64, o: &ChowOptions) -> ChowTest {
    let tr = protocol(N, 550.0);
    let pa = pressure(&SBA1_RAW, &tr, &ar1_noise(N, 0.2, rho, seed));
    let pb = pressure(law_b, &tr, &ar1_noise(N, 0.2, rho, seed + 1_000_000));
    let a = Xy {
        v: &tr.v,
        vdot: &tr.vdot,
        p: &pa,
    };
    let b = Xy {
        v: &tr.v,
        vdot: &tr.vdot,
        p: &pb,
    };
    chow(a, b, o).unwrap()
}

/// Repeated runs of one actuator with serially correlated noise (AR(1), ρ = 0.8, as a sensor
/// with dynamics gives): the prewhitened test rejects about α of them and its p-values are
/// uniform; the classic test, which assumes independent errors, rejects nearly all.
#[test]
fn same_actuator_false_rejection_rate_is_about_alpha() {
    let runs = 80;
    let o = ChowOptions {
        alpha: 0.05,
        ..ChowOptions::default()
    };
    let tests: Vec<ChowTest> = (0..runs).map(|s| pair(&SBA1_RAW, 0.8, s, &o)).collect();
    let rejected = tests.iter().filter(|t| t.reject).count();
    // Binomial(80, 0.05): mean 4, P(X ≥ 12) < 0.001.
    assert!(
        rejected <= 11,
        "prewhitened test rejected {rejected}/{runs} at alpha 0.05"
    );
    // Kolmogorov–Smirnov distance of the p-values from U(0, 1); 1.63/√80 = 0.18 is its 1 % point.
    let mut p: Vec<f64> = tests.iter().map(|t| t.p).collect();
    p.sort_by(f64::total_cmp);
    let ks = p
        .iter()
        .enumerate()
        .map(|(i, &x)| {
            ((i + 1) as f64 / runs as f64 - x)
                .abs()
                .max((x - i as f64 / runs as f64).abs())
        })
        .fold(0.0, f64::max);
    assert!(ks < 0.18, "p-values not uniform: KS distance {ks}");
    // At the paper's alpha no run of the same actuator is told apart.
    assert!(
        tests.iter().all(|t| t.p > 0.0005),
        "a same-actuator pair rejected at 0.0005"
    );
    // The classic F ignores the correlation and over-rejects massively.
    let classic = tests.iter().filter(|t| t.p_classic < 0.05).count();
    assert!(
        classic > runs as usize / 2,
        "classic rejected only {classic}/{runs}"
    );
    // The AR model found is the generator's: φ₁ ≈ 0.8.
    let phi1 = tests
        .iter()
        .map(|t| t.ar.first().copied().unwrap_or(0.0))
        .sum::<f64>()
        / runs as f64;
    assert!((phi1 - 0.8).abs() < 0.05, "mean phi1 {phi1}");
}

/// With independent noise the prewhitening finds (almost) nothing and both forms agree.
#[test]
fn white_noise_gives_the_classic_test() {
    let o = ChowOptions::default();
    let t = pair(&SBA1_RAW, 0.0, 3, &o);
    assert!(
        t.ar.len() <= 2 && t.ar.iter().all(|f| f.abs() < 0.1),
        "{:?}",
        t.ar
    );
    assert!(
        (t.f - t.f_classic).abs() < 0.3 * t.f_classic.max(1.0),
        "{} vs {}",
        t.f,
        t.f_classic
    );
}

/// Different actuators — a 10 % softer elastic part and 10 % lower damping — are told apart at
/// the paper's alpha, with the noise still correlated.
#[test]
fn different_laws_are_rejected() {
    let o = ChowOptions::default();
    for (ks, cs) in [(0.9, 1.0), (1.0, 0.9), (0.9, 0.9)] {
        let t = pair(&scaled_sba1(ks, cs), 0.8, 11, &o);
        assert!(
            t.reject && t.p < 1e-7,
            "ks {ks} cs {cs}: F {} p {}",
            t.f,
            t.p
        );
    }
}

/// The classic statistic is Chow's formula on residual sums of squares computed independently
/// by sysid's polynomial fit, and the critical value is the F quantile (k = 12, large N: ≈ 2.96
/// at alpha = 0.0005, χ²₁₂ quantile 35.5 / 12).
#[test]
fn classic_statistic_matches_its_formula() {
    let tr = protocol(N, 550.0);
    let pa = pressure(&SBA1_RAW, &tr, &ar1_noise(N, 0.2, 0.0, 5));
    let pb = pressure(&scaled_sba1(0.99, 1.0), &tr, &ar1_noise(N, 0.2, 0.0, 6));
    let o = ChowOptions {
        method: Method::Classic,
        ..ChowOptions::default()
    };
    let t = chow(
        Xy {
            v: &tr.v,
            vdot: &tr.vdot,
            p: &pa,
        },
        Xy {
            v: &tr.v,
            vdot: &tr.vdot,
            p: &pb,
        },
        &o,
    )
    .unwrap();
    let sse = |v: &[f64], q: &[f64], p: &[f64]| {
        poly::fit(Xy { v, vdot: q, p }, 3, 2, None)
            .unwrap()
            .train
            .sse
    };
    let (s1, s2) = (sse(&tr.v, &tr.vdot, &pa), sse(&tr.v, &tr.vdot, &pb));
    let cat = |a: &[f64], b: &[f64]| -> Vec<f64> { a.iter().chain(b).copied().collect() };
    let sp = sse(&cat(&tr.v, &tr.v), &cat(&tr.vdot, &tr.vdot), &cat(&pa, &pb));
    let df2 = 2 * N - 24;
    let f = ((sp - s1 - s2) / 12.0) / ((s1 + s2) / df2 as f64);
    assert!((t.f - f).abs() < 1e-6 * f, "{} vs {f}", t.f);
    assert_eq!((t.df1, t.df2), (12, df2));
    assert!((t.critical - 2.96).abs() < 0.05, "critical {}", t.critical);
}
