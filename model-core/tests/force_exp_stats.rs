//! Force from residuals, the exponential model and the k/c statistics: known answers and bad input.

use model_core::exp::ExpModel;
use model_core::force::{self, DEFAULT_AREAS_MM2};
use model_core::stats::{KcStats, Phase, RunningMean};
use model_core::ModelError;

#[test]
fn force_is_residual_times_area_in_newtons() {
    // 1, 2, −0.5 kPa on 22 mm² each: 22, 44, −11 mN; |sum| = 55 mN.
    let f = force::estimate([1.0, 2.0, -0.5], DEFAULT_AREAS_MM2).unwrap();
    let want = [0.022, 0.044, -0.011];
    for (g, w) in f.per_chamber_n.iter().zip(want) {
        assert!((g - w).abs() < 1e-7, "{g} vs {w}");
    }
    assert!((f.total_n - 0.055).abs() < 1e-7);
    assert!((f.signed_total_n() - 0.055).abs() < 1e-7);
    // All chambers relieved: the magnitude is still positive, the signed sum negative.
    let g = force::estimate([-1.0, -1.0, -1.0], [10.0, 20.0, 30.0]).unwrap();
    assert!((g.total_n - 0.06).abs() < 1e-7 && (g.signed_total_n() + 0.06).abs() < 1e-7);
    let r = force::residuals([10.0, 20.0, 30.0], [9.0, 21.0, 30.0]).unwrap();
    assert_eq!(r, [1.0, -1.0, 0.0]);
}

#[test]
fn force_refuses_bad_input() {
    assert_eq!(
        force::estimate([f32::NAN, 0.0, 0.0], DEFAULT_AREAS_MM2),
        Err(ModelError::NonFinite)
    );
    assert_eq!(
        force::estimate([0.0; 3], [22.0, 0.0, 22.0]),
        Err(ModelError::BadParameter)
    );
    assert_eq!(
        force::estimate([0.0; 3], [22.0, -1.0, 22.0]),
        Err(ModelError::BadParameter)
    );
    assert_eq!(
        force::estimate([0.0; 3], [22.0, f32::INFINITY, 22.0]),
        Err(ModelError::NonFinite)
    );
    assert_eq!(
        force::residuals([0.0; 3], [0.0, f32::NAN, 0.0]),
        Err(ModelError::NonFinite)
    );
    // Finite inputs whose product overflows f32.
    assert_eq!(
        force::estimate([3e38, 3e38, 0.0], [1e5; 3]),
        Err(ModelError::NonFinite)
    );
}

#[test]
fn exp_model_known_values_and_derivatives() {
    // α = 2, β = 0.01/mm³ at v = 100 mm³: 2e¹; k = 0.02e¹; γ v̇ + δ = 0.5·10 + 1.
    let m = ExpModel::new(&[2.0], &[0.01], 0.5, 1.0).unwrap();
    let e = m.eval(100.0, 10.0).unwrap();
    let e1 = core::f32::consts::E;
    assert!((e.p - (2.0 * e1 + 6.0)).abs() < 1e-5, "{e:?}");
    assert!((e.k - 0.02 * e1).abs() < 1e-7);
    assert_eq!(e.c, 0.5);
    // Three terms: k against a central difference.
    let m3 = ExpModel::new(&[1.5, -0.7, 0.02], &[0.004, -0.01, 0.009], 0.17, -0.3).unwrap();
    for v in [0.0f32, 120.0, 333.0, 549.0] {
        let h = 0.5f32;
        let fd = (m3.eval(v + h, 20.0).unwrap().p - m3.eval(v - h, 20.0).unwrap().p) / (2.0 * h);
        let k = m3.eval(v, 20.0).unwrap().k;
        assert!(
            (k - fd).abs() < 1e-3 * (1.0 + k.abs()),
            "v = {v}: k {k} fd {fd}"
        );
    }
}

#[test]
fn exp_model_refuses_bad_input() {
    assert_eq!(
        ExpModel::new(&[1.0], &[1.0, 2.0], 0.0, 0.0).err(),
        Some(ModelError::BadLength)
    );
    assert_eq!(
        ExpModel::new(&[], &[], 0.0, 0.0).err(),
        Some(ModelError::BadShape)
    );
    assert_eq!(
        ExpModel::new(&[1.0; 11], &[1.0; 11], 0.0, 0.0).err(),
        Some(ModelError::BadShape)
    );
    assert_eq!(
        ExpModel::new(&[f32::NAN], &[1.0], 0.0, 0.0).err(),
        Some(ModelError::NonFinite)
    );
    let m = ExpModel::new(&[1.0], &[0.1], 0.0, 0.0).unwrap();
    // e^(0.1·7000) overflows f32.
    assert_eq!(m.eval(7000.0, 0.0), Err(ModelError::NonFinite));
    assert_eq!(m.eval(f32::NAN, 0.0), Err(ModelError::NonFinite));
}

#[test]
fn running_mean_and_variance_known_values() {
    let mut r = RunningMean::new();
    assert_eq!(r.mean(), None);
    for x in [2.0f32, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0] {
        r.push(x).unwrap();
    }
    assert_eq!(r.count(), 8);
    assert_eq!(r.mean(), Some(5.0));
    // Sum of squared deviations 32, N − 1 = 7.
    assert!((r.variance().unwrap() - 32.0 / 7.0).abs() < 1e-6);
    assert_eq!(r.push(f32::NAN), Err(ModelError::NonFinite));
    assert_eq!(r.count(), 8);
    // A large offset does not swamp a small spread over many samples.
    let mut big = RunningMean::new();
    for i in 0..1_000_000u32 {
        big.push(1000.0 + if i % 2 == 0 { 0.001 } else { -0.001 })
            .unwrap();
    }
    assert!((big.mean().unwrap() - 1000.0).abs() < 1e-4);
}

#[test]
fn kc_stats_split_by_flow_sign() {
    let mut s = KcStats::new(1.0).unwrap();
    assert_eq!(s.push(0.1, 0.2, 5.0), Ok(Phase::Inflating));
    assert_eq!(s.push(0.3, 0.4, 20.0), Ok(Phase::Inflating));
    assert_eq!(s.push(0.5, 0.6, -3.0), Ok(Phase::Deflating));
    assert_eq!(s.push(0.7, 0.8, 0.5), Ok(Phase::Holding));
    assert_eq!(s.push(f32::NAN, 0.8, 0.5), Err(ModelError::NonFinite));
    assert!((s.k_all.mean().unwrap() - 0.4).abs() < 1e-6);
    assert!((s.c_all.mean().unwrap() - 0.5).abs() < 1e-6);
    assert!((s.k_inflate.mean().unwrap() - 0.2).abs() < 1e-6);
    assert!((s.c_inflate.mean().unwrap() - 0.3).abs() < 1e-6);
    assert_eq!(s.k_deflate.mean(), Some(0.5));
    assert_eq!(s.c_deflate.count(), 1);
    s.reset();
    assert_eq!(s.k_all.count(), 0);
    assert_eq!(s.deadband(), 1.0);
    assert_eq!(KcStats::new(-1.0).err(), Some(ModelError::BadParameter));
}
