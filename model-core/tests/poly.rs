//! Polynomial model: known answers, identities (C·v̇ + K = P, regressors·b = P), finite
//! differences, f32-vs-f64 accuracy over the working range, raw ↔ scaled round trips, bad input.

mod common;

use common::{c_raw, full_scale, k_raw, p_raw, range};
use model_core::poly::{self, ArHistory, PolyModel, Scaling, Shape, MAX_AR, MAX_PARAMS, SBA1_RAW};
use model_core::ModelError;
use proptest::prelude::*;

/// Stated accuracy of f32 evaluation against the f64 reference, as a fraction of the model's
/// full-scale magnitude Σ|α_ij|·V^i·F^j (and likewise for k and c), anywhere in the working range,
/// for every shape n, m ≤ 7 and ranges up to 7000 mm³ and ±500 mm³/s. (Measured worst case over
/// 150 000 random points: 1.9e-7.)
const F32_REL_TOL: f64 = 1.0e-6;
/// Stated accuracy of raw → scaled (f32) → raw, per coefficient, same measure (measured: 5.2e-7).
const ROUND_TRIP_TOL: f64 = 2.0e-6;

#[test]
fn sba1_matches_hand_computed_values() {
    let m = poly::sba1();
    // Σ α_i0·550^i from Table IV, by hand: 6.98225 − 24.40086 + 68.66129 = 51.24269 kPa.
    let e = m.eval(550.0, 0.0).unwrap();
    assert!((e.p - 51.24269).abs() < 2e-4, "{e:?}");
    // Pressure at rest and empty is the constant term, 0.
    assert!(m.eval(0.0, 0.0).unwrap().p.abs() < 1e-5);
    // c at v = 0, v̇ = 0 is α_01 = 0.1766 kPa·s/mm³; k is α_10 = 0.012695 kPa/mm³.
    let e0 = m.eval(0.0, 0.0).unwrap();
    assert!((e0.c - 0.1766).abs() < 1e-6, "{e0:?}");
    assert!((e0.k - 0.012695).abs() < 1e-7, "{e0:?}");
}

#[test]
fn sba1_f32_agrees_with_f64_on_a_dense_grid() {
    let m = poly::sba1();
    let shape = Shape::PAPER;
    let (sp, sk, sc) = full_scale(shape, &SBA1_RAW, 550.0, 100.0);
    let (mut ep, mut ek, mut ec) = (0.0f64, 0.0f64, 0.0f64);
    for a in 0..=110 {
        for b in 0..=40 {
            let (v, f) = (a as f32 * 5.0, -100.0 + b as f32 * 5.0);
            let e = m.eval(v, f).unwrap();
            let (v, f) = (v as f64, f as f64);
            ep = ep.max((e.p as f64 - p_raw(shape, &SBA1_RAW, v, f)).abs());
            ek = ek.max((e.k as f64 - k_raw(shape, &SBA1_RAW, v, f)).abs());
            ec = ec.max((e.c as f64 - c_raw(shape, &SBA1_RAW, v, f)).abs());
        }
    }
    assert!(
        ep / sp < F32_REL_TOL && ek / sk < F32_REL_TOL && ec / sc < F32_REL_TOL,
        "{ep} {ek} {ec}"
    );
    // In absolute terms: well below the sensor's resolution (≈ 0.1 kPa).
    assert!(ep < 1e-3, "max |ΔP| = {ep} kPa");
}

#[test]
fn regressors_dot_coefficients_is_p() {
    let m = poly::sba1();
    let mut phi = [0.0f32; MAX_PARAMS];
    let t = m.regressors(321.0, -42.0, &mut phi).unwrap();
    assert_eq!(t, 12);
    let dot: f32 = phi[..t].iter().zip(m.scaled()).map(|(a, b)| a * b).sum();
    assert!((dot - m.eval(321.0, -42.0).unwrap().p).abs() < 1e-4);
}

#[test]
fn bad_input_is_an_error_not_a_panic() {
    let m = poly::sba1();
    assert_eq!(m.eval(f32::NAN, 0.0), Err(ModelError::NonFinite));
    assert_eq!(m.eval(0.0, f32::INFINITY), Err(ModelError::NonFinite));
    // SCALED_LIMIT = 2: 0..550 mm³ accepts −275..825 mm³.
    assert!(m.eval(825.0, 0.0).is_ok());
    assert_eq!(m.eval(826.0, 0.0), Err(ModelError::OutOfRange));
    assert_eq!(m.eval(0.0, -201.0), Err(ModelError::OutOfRange));
    assert_eq!(m.split(f32::NAN, 0.0), Err(ModelError::NonFinite));
    assert_eq!(Shape::new(8, 2, 0), Err(ModelError::BadShape));
    assert_eq!(Shape::new(3, 2, 6), Err(ModelError::BadShape));
    assert_eq!(
        Scaling::for_range(1.0, 1.0, -1.0, 1.0),
        Err(ModelError::BadParameter)
    );
    assert_eq!(
        Scaling::for_range(0.0, f32::NAN, -1.0, 1.0),
        Err(ModelError::NonFinite)
    );
    assert_eq!(
        Scaling::new(0.0, -1.0, 0.0, 1.0),
        Err(ModelError::BadParameter)
    );
    let s = Scaling::SBA1;
    assert_eq!(
        PolyModel::from_raw(Shape::PAPER, &SBA1_RAW[..11], &[], s),
        Err(ModelError::BadLength)
    );
    let mut bad = SBA1_RAW;
    bad[4] = f64::NAN;
    assert_eq!(
        PolyModel::from_raw(Shape::PAPER, &bad, &[], s),
        Err(ModelError::NonFinite)
    );
    // Coefficients that overflow f32 once scaled.
    bad[4] = 1e300;
    assert_eq!(
        PolyModel::from_raw(Shape::PAPER, &bad, &[], s),
        Err(ModelError::NonFinite)
    );
    // Finite coefficients whose value overflows f32 at evaluation.
    let huge = PolyModel::from_scaled(Shape::new(1, 0, 0).unwrap(), &[3e38, 3e38], &[], s).unwrap();
    assert_eq!(huge.eval(550.0, 0.0), Err(ModelError::NonFinite));
    let mut raw = [0.0f64; 11];
    assert_eq!(
        poly::sba1().to_raw(&mut raw, &mut []),
        Err(ModelError::BadLength)
    );
}

#[test]
fn ar_terms_add_the_raw_lagged_inputs() {
    // Raw AR pairs and a flow offset exercise the constant-term shift of the conversion.
    let shape = Shape::new(3, 2, 3).unwrap();
    let ar_raw = [[0.01, -0.002], [0.005, 0.001], [-0.003, 0.0005]];
    let s = Scaling::for_range(0.0, 550.0, -80.0, 120.0).unwrap();
    let m = PolyModel::from_raw(shape, &SBA1_RAW, &ar_raw, s).unwrap();
    let mut h = ArHistory::new();
    assert_eq!(m.eval_ar(100.0, 10.0, &h), Err(ModelError::ShortHistory));
    let past = [(90.0f32, 20.0f32), (80.0, 30.0), (70.0, 40.0), (60.0, 50.0)];
    for &(v, f) in past.iter().rev() {
        h.push(v, f);
    }
    assert_eq!(h.len(), 4);
    assert_eq!(h.get(1), Some((90.0, 20.0)));
    let got = m.eval_ar(100.0, 10.0, &h).unwrap();
    let mut want = p_raw(Shape::PAPER, &SBA1_RAW, 100.0, 10.0);
    for (k, b) in ar_raw.iter().enumerate() {
        want += b[0] * past[k].0 as f64 + b[1] * past[k].1 as f64;
    }
    assert!((got.p as f64 - want).abs() < 1e-4, "{} vs {want}", got.p);
    // The AR part does not depend on the current input: k and c are those of the static part.
    let st = m.eval(100.0, 10.0).unwrap();
    assert_eq!((got.k, got.c), (st.k, st.c));
    // Regressor row of the full model reproduces the prediction.
    let mut phi = [0.0f32; MAX_PARAMS];
    let np = m.regressors_ar(100.0, 10.0, &h, &mut phi).unwrap();
    let mut params = [0.0f32; MAX_PARAMS];
    assert_eq!(m.params(&mut params).unwrap(), np);
    let dot: f32 = phi[..np]
        .iter()
        .zip(&params[..np])
        .map(|(a, b)| a * b)
        .sum();
    assert!((dot - got.p).abs() < 1e-4);
    assert_eq!(PolyModel::from_params(shape, &params[..np], s).unwrap(), m);
    // Round trip of the raw AR pairs.
    let (mut raw, mut arr) = ([0.0f64; 12], [[0.0f64; 2]; 3]);
    m.to_raw(&mut raw, &mut arr).unwrap();
    for k in 0..3 {
        for l in 0..2 {
            assert!((arr[k][l] - ar_raw[k][l]).abs() <= 1e-7 * ar_raw[k][l].abs());
        }
    }
    assert!(
        raw[0].abs() < 1e-5,
        "constant term after undoing the AR shift: {}",
        raw[0]
    );
    // The history keeps only MAX_AR samples.
    for i in 0..10 {
        h.push(i as f32, 0.0);
    }
    assert_eq!(h.len(), MAX_AR);
    assert_eq!(h.get(MAX_AR), Some((5.0, 0.0)));
    assert_eq!(h.get(MAX_AR + 1), None);
}

#[test]
fn rescaled_model_predicts_the_same() {
    let shape = Shape::new(3, 2, 2).unwrap();
    let m = PolyModel::from_raw(
        shape,
        &SBA1_RAW,
        &[[0.01, 0.002], [-0.004, 0.001]],
        Scaling::SBA1,
    )
    .unwrap();
    let wide = Scaling::for_range(-100.0, 1000.0, -150.0, 250.0).unwrap();
    let r = m.rescaled(wide).unwrap();
    assert_eq!(r.scaling(), wide);
    let mut h = ArHistory::new();
    h.push(200.0, -20.0);
    h.push(210.0, 30.0);
    for (v, f) in [
        (0.0f32, 0.0f32),
        (275.0, 60.0),
        (550.0, -100.0),
        (400.0, 100.0),
    ] {
        let (a, b) = (m.eval_ar(v, f, &h).unwrap(), r.eval_ar(v, f, &h).unwrap());
        assert!((a.p - b.p).abs() < 1e-4, "{a:?} {b:?}");
        assert!(
            (a.k - b.k).abs() < 1e-6 && (a.c - b.c).abs() < 1e-6,
            "{a:?} {b:?}"
        );
    }
    // Out of the new range's limit.
    assert_eq!(r.eval(3000.0, 0.0), Err(ModelError::OutOfRange));
}

/// A random model: shape, range and raw coefficients whose terms are comparable in size at the
/// edge of the range (like Table IV), α_ij = 50 kPa · c_ij / (V^i F^j), c_ij ∈ [−1, 1].
fn model_strategy() -> impl Strategy<Value = (Shape, Scaling, Vec<f64>, f64, f64)> {
    (
        0u8..=7,
        0u8..=7,
        100.0f64..7000.0,
        20.0f64..500.0,
        -0.2f64..0.2,
        -0.3f64..0.3,
    )
        .prop_flat_map(|(n, m, vmax, fmax, vlo, fc)| {
            let shape = Shape::new(n, m, 0).unwrap();
            let coeffs = proptest::collection::vec(-1.0f64..1.0, shape.poly_terms());
            (
                Just(shape),
                Just(vmax),
                Just(fmax),
                Just(vlo),
                Just(fc),
                coeffs,
            )
        })
        .prop_map(|(shape, vmax, fmax, vlo, fc, c)| {
            // Volume range [vlo·vmax, vmax]; flow range centred at fc·fmax, half-width fmax.
            let (v0, f0) = (vlo * vmax, fc * fmax);
            let s = Scaling::for_range(
                v0 as f32,
                vmax as f32,
                (f0 - fmax) as f32,
                (f0 + fmax) as f32,
            )
            .unwrap();
            let (ve, fe) = (vmax, fmax * (1.0 + fc.abs()));
            let mut a = vec![0.0; shape.poly_terms()];
            for i in 0..=shape.n as i32 {
                for j in 0..=shape.m as i32 {
                    let ix = (i * (shape.m as i32 + 1) + j) as usize;
                    a[ix] = 50.0 * c[ix] / (ve.powi(i) * fe.powi(j));
                }
            }
            (shape, s, a, ve, fe)
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(96))]

    #[test]
    fn f32_eval_agrees_with_f64_reference(
        (shape, s, a, ve, fe) in model_strategy(),
        tx in 0.0f32..=1.0, ty in 0.0f32..=1.0,
    ) {
        let m = PolyModel::from_raw(shape, &a, &[], s).unwrap();
        let (v0, v1, f0, f1) = range(s);
        let (v, f) = (v0 + tx * (v1 - v0), f0 + ty * (f1 - f0));
        let e = m.eval(v, f).unwrap();
        let (sp, sk, sc) = full_scale(shape, &a, ve, fe);
        let (vd, fd) = (v as f64, f as f64);
        prop_assert!((e.p as f64 - p_raw(shape, &a, vd, fd)).abs() <= F32_REL_TOL * sp);
        prop_assert!((e.k as f64 - k_raw(shape, &a, vd, fd)).abs() <= F32_REL_TOL * sk + 1e-30);
        prop_assert!((e.c as f64 - c_raw(shape, &a, vd, fd)).abs() <= F32_REL_TOL * sc + 1e-30);
    }

    #[test]
    fn derivatives_agree_with_finite_differences(
        (shape, s, a, _ve, _fe) in model_strategy(),
        tx in 0.05f32..=0.95, ty in 0.05f32..=0.95,
    ) {
        // Central differences of the model's own f32 evaluation with step h (scaled units):
        // truncation ≤ h²/6·max|P'''| and rounding ≤ 2·ε_eval/(2h), both bounded from |b_ij|.
        let m = PolyModel::from_raw(shape, &a, &[], s).unwrap();
        let (v0, v1, f0, f1) = range(s);
        let (v, f) = (v0 + tx * (v1 - v0), f0 + ty * (f1 - f0));
        let e = m.eval(v, f).unwrap();
        let h = 1.0e-2f32;
        let b = m.scaled();
        let w = shape.m as usize + 1;
        let (mut sum, mut d3x, mut d3y) = (0.0f64, 0.0f64, 0.0f64);
        for i in 0..=shape.n as usize {
            for j in 0..w {
                let t = (b[i * w + j] as f64).abs();
                sum += t;
                d3x += t * (i * i.saturating_sub(1) * i.saturating_sub(2)) as f64;
                d3y += t * (j * j.saturating_sub(1) * j.saturating_sub(2)) as f64;
            }
        }
        let eval_err = 1e-6 * sum;
        let (hv, hf) = (h * s.v_scale, h * s.f_scale);
        let fd_k = (m.eval(v + hv, f).unwrap().p - m.eval(v - hv, f).unwrap().p) as f64 / (2.0 * hv as f64);
        let fd_c = (m.eval(v, f + hf).unwrap().p - m.eval(v, f - hf).unwrap().p) as f64 / (2.0 * hf as f64);
        let hh = h as f64;
        let tol_k = (hh * hh / 6.0 * d3x + eval_err / hh) / s.v_scale as f64;
        let tol_c = (hh * hh / 6.0 * d3y + eval_err / hh) / s.f_scale as f64;
        prop_assert!((e.k as f64 - fd_k).abs() <= tol_k, "k {} fd {} tol {}", e.k, fd_k, tol_k);
        prop_assert!((e.c as f64 - fd_c).abs() <= tol_c, "c {} fd {} tol {}", e.c, fd_c, tol_c);
    }

    #[test]
    fn split_reassembles_p(
        (shape, s, a, ve, fe) in model_strategy(),
        tx in 0.0f32..=1.0, ty in 0.0f32..=1.0,
    ) {
        let m = PolyModel::from_raw(shape, &a, &[], s).unwrap();
        let (v0, v1, f0, f1) = range(s);
        let (v, f) = (v0 + tx * (v1 - v0), f0 + ty * (f1 - f0));
        let (c, k) = m.split(v, f).unwrap();
        let p = m.eval(v, f).unwrap().p;
        let (sp, _, _) = full_scale(shape, &a, ve, fe);
        // Identity of eq. (9): C·v̇ + K = P, to f32 rounding of the model's magnitude.
        prop_assert!(((c * f + k) as f64 - p as f64).abs() <= 4.0 * F32_REL_TOL * sp);
        // The regressor row dotted with the scaled coefficients is P (what RLS relies on).
        let mut phi = [0.0f32; MAX_PARAMS];
        let t = m.regressors(v, f, &mut phi).unwrap();
        let dot: f64 = phi[..t].iter().zip(m.scaled()).map(|(a, b)| (a * b) as f64).sum();
        prop_assert!((dot - p as f64).abs() <= 4.0 * F32_REL_TOL * sp);
        // K(v) is P at zero flow, against the f64 reference.
        prop_assert!((k as f64 - p_raw(shape, &a, v as f64, 0.0)).abs() <= 4.0 * F32_REL_TOL * sp);
    }

    #[test]
    fn damping_at_a_second_flow_agrees_with_f64_reference(
        (shape, s, a, ve, fe) in model_strategy(),
        tx in 0.0f32..=1.0, ty in 0.0f32..=1.0, tz in 0.0f32..=1.0,
    ) {
        // `eval_damping_at(v, v̇, δ)`: `eval(v, v̇)` bit for bit, and ∂P/∂v̇ at (v, v̇ − δ) within
        // the stated f32 accuracy of the term-by-term f64 derivative.
        let m = PolyModel::from_raw(shape, &a, &[], s).unwrap();
        let (v0, v1, f0, f1) = range(s);
        let (v, f) = (v0 + tx * (v1 - v0), f0 + ty * (f1 - f0));
        let delta = f - (f0 + tz * (f1 - f0));
        let (e, c2) = m.eval_damping_at(v, f, delta).unwrap();
        prop_assert_eq!(e, m.eval(v, f).unwrap());
        let (_, _, sc) = full_scale(shape, &a, ve, fe);
        let want = c_raw(shape, &a, v as f64, f as f64 - delta as f64);
        prop_assert!((c2 as f64 - want).abs() <= F32_REL_TOL * sc + 1e-30, "{} vs {}", c2, want);
    }

    #[test]
    fn damping_at_the_midpoint_is_the_secant_of_a_law_quadratic_in_flow(
        (shape, s, mut a, ve, fe) in model_strategy(),
        tx in 0.0f32..=1.0, ty in 0.0f32..=1.0, tz in 0.0f32..=1.0,
    ) {
        // A law quadratic in flow (every α_ij with j > 2 zeroed): g(v̇) − g(v̇ − ẋ) = g′(v̇ − ẋ/2)·ẋ
        // exactly, so the damping at the midpoint (δ = ẋ/2) is the secant of P itself, evaluated
        // term by term in f64 (no derivative taken).
        let w = shape.m as usize + 1;
        for (ix, x) in a.iter_mut().enumerate() {
            if ix % w > 2 {
                *x = 0.0;
            }
        }
        let m = PolyModel::from_raw(shape, &a, &[], s).unwrap();
        let (v0, v1, f0, f1) = range(s);
        let (v, f) = (v0 + tx * (v1 - v0), f0 + ty * (f1 - f0));
        let xdot = f - (f0 + tz * (f1 - f0));
        prop_assume!(xdot.abs() as f64 > 1e-3 * fe);
        let (_, c_mid) = m.eval_damping_at(v, f, 0.5 * xdot).unwrap();
        let (vd, fd, xd) = (v as f64, f as f64, xdot as f64);
        let secant = (p_raw(shape, &a, vd, fd) - p_raw(shape, &a, vd, fd - xd)) / xd;
        let (_, _, sc) = full_scale(shape, &a, ve, fe);
        prop_assert!((c_mid as f64 - secant).abs() <= F32_REL_TOL * sc + 1e-30,
            "{} vs {}", c_mid, secant);
    }

    #[test]
    fn raw_scaled_round_trips(
        (shape, s, a, ve, fe) in model_strategy(),
    ) {
        // raw (f64) → scaled (f32) → raw: each coefficient back to f32 rounding of the model's
        // magnitude at the edge of the range.
        let m = PolyModel::from_raw(shape, &a, &[], s).unwrap();
        let mut back = vec![0.0; shape.poly_terms()];
        m.to_raw(&mut back, &mut []).unwrap();
        let (sp, _, _) = full_scale(shape, &a, ve, fe);
        let w = shape.m as i32 + 1;
        for i in 0..=shape.n as i32 {
            for j in 0..w {
                let ix = (i * w + j) as usize;
                let weight = ve.powi(i) * fe.powi(j);
                prop_assert!((back[ix] - a[ix]).abs() * weight <= ROUND_TRIP_TOL * sp,
                    "α_{i}{j}: {} vs {}", back[ix], a[ix]);
            }
        }
        // scaled → raw → scaled: the conversions are exact inverses in f64, so the f32 scaled
        // coefficients come back to within rounding.
        let m2 = PolyModel::from_raw(shape, &back, &[], s).unwrap();
        let sum: f32 = m.scaled().iter().map(|x| x.abs()).sum();
        for (x, y) in m.scaled().iter().zip(m2.scaled()) {
            prop_assert!((x - y).abs() <= 1e-6 * sum);
        }
    }
}
