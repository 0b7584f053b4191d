//! The effect chain against hand-computed values, identities and an independent `f64` reference.
//!
//! The reference ([`reference`]) evaluates the module table's equations over whole sequences in
//! `f64`, written apart from the device code: the polynomial term by term in raw units, each lag
//! by numerical quadrature of `y(t) = e^{−Δt/τ} y₀ + ∫ e^{−(Δt−s)/τ}/τ · u(s) ds` over the frame
//! (Simpson, 400 panels) instead of the closed-form weights, the delay by locating the delayed
//! instant on the time axis.

// Index loops mirror the subscripts of the documented equations.
#![allow(clippy::needless_range_loop)]

mod common;

use common::{c_raw, k_raw, p_raw};
use model_core::chain::{
    Chain, ChainInput, ChainState, Effect, EffectKind, MAX_DELAY_FRAMES, MAX_DELAY_S, MAX_EFFECTS,
    MAX_EFFECT_PARAMS, P_ATM_KPA,
};
use model_core::poly::{sba1, ArHistory, PolyModel, Scaling, Shape, SBA1_RAW};
use model_core::spec::{self, Stage};
use model_core::ModelError;
use proptest::prelude::*;

const DT: f32 = 0.04;

fn chain(effects: &[(EffectKind, &[f32])]) -> Chain {
    let mut c = Chain::new();
    for (k, p) in effects {
        c.push(Effect::new(*k, p).unwrap()).unwrap();
    }
    c
}

/// Runs a chain over frames, returning P̂ (NaN where a frame failed).
fn run(c: &Chain, model: &PolyModel, frames: &[ChainInput]) -> Vec<f32> {
    let mut st = ChainState::new();
    let hist = ArHistory::new();
    frames
        .iter()
        .map(|&f| c.eval(model, &hist, &mut st, f).map_or(f32::NAN, |e| e.p))
        .collect()
}

/// A linear model P = p0 + kv·v + cf·v̇ (raw units), so the lags' answers are hand-computable.
fn linear(p0: f64, kv: f64, cf: f64) -> PolyModel {
    let sc = Scaling::for_range(0.0, 1000.0, -200.0, 200.0).unwrap();
    PolyModel::from_raw(Shape::new(1, 1, 0).unwrap(), &[p0, cf, kv, 0.0], &[], sc).unwrap()
}

/// Smooth motion: two tones in volume (exact flow), a measured pressure from SBA1 plus a slow sine.
fn frames(len: usize, a1: f64, w1: f64, a2: f64, w2: f64) -> Vec<ChainInput> {
    (0..len)
        .map(|k| {
            let t = k as f64 * DT as f64;
            let v = 275.0 + a1 * (w1 * t).sin() + a2 * (w2 * t).sin();
            let f = a1 * w1 * (w1 * t).cos() + a2 * w2 * (w2 * t).cos();
            let p = p_raw(Shape::PAPER, &SBA1_RAW, v, f) + 0.3 * (0.7 * t).sin();
            ChainInput {
                v: v as f32,
                vdot: f as f32,
                p: p as f32,
                dt: DT,
            }
        })
        .collect()
}

/// The independent `f64` evaluation of a chain over a sequence (see the file docs).
mod reference {
    use super::*;

    /// Frame interval and frame inputs in f64.
    pub struct Seq {
        pub dt: f64,
        pub v: Vec<f64>,
        pub f: Vec<f64>,
        pub p: Vec<f64>,
    }

    impl Seq {
        pub fn of(frames: &[ChainInput]) -> Self {
            Seq {
                dt: DT as f64,
                v: frames.iter().map(|x| x.v as f64).collect(),
                f: frames.iter().map(|x| x.vdot as f64).collect(),
                p: frames.iter().map(|x| x.p as f64).collect(),
            }
        }
    }

    /// `y(Δt)` of `τẏ + y = u(s)` from `y0`, u given on [0, Δt], by Simpson's rule.
    fn lag_step(dt: f64, tau: f64, y0: f64, u: impl Fn(f64) -> f64) -> f64 {
        if tau <= 1e-9 * dt {
            return u(dt);
        }
        // Simpson's rule on the kernel e^{−(Δt−s)/τ}/τ: at least 10 steps per τ (a short τ puts
        // all the weight in the last few steps), even.
        let n = ((10.0 * dt / tau).ceil() as usize).clamp(400, 200_000);
        let n = n + n % 2;
        let h = dt / n as f64;
        let g = |s: f64| (-(dt - s) / tau).exp() / tau * u(s);
        let mut sum = g(0.0) + g(dt);
        for i in 1..n {
            sum += if i % 2 == 1 { 4.0 } else { 2.0 } * g(i as f64 * h);
        }
        (-dt / tau).exp() * y0 + sum * h / 3.0
    }

    /// Cubic Hermite on [0, h] with end values x0, x1 and slopes m0, m1, at s ∈ [0, h].
    fn hermite(h: f64, x0: f64, m0: f64, x1: f64, m1: f64, s: f64) -> f64 {
        let u = s / h;
        (2.0 * u.powi(3) - 3.0 * u * u + 1.0) * x0
            + (u.powi(3) - 2.0 * u * u + u) * h * m0
            + (-2.0 * u.powi(3) + 3.0 * u * u) * x1
            + (u.powi(3) - u * u) * h * m1
    }

    /// The lag of x, slopes `m` (None: the straight line between frames), started at rest.
    pub fn lag(dt: f64, tau: f64, x: &[f64], m: Option<&[f64]>) -> Vec<f64> {
        let mut y = vec![x[0]];
        for k in 1..x.len() {
            let (x0, x1) = (x[k - 1], x[k]);
            let next = match m {
                Some(m) => lag_step(dt, tau, y[k - 1], |s| {
                    hermite(dt, x0, m[k - 1], x1, m[k], s)
                }),
                None => lag_step(dt, tau, y[k - 1], |s| x0 + (x1 - x0) * s / dt),
            };
            y.push(next);
        }
        y
    }

    /// The lag with a per-frame time constant (air compliance), over the cubic with slopes `m`.
    pub fn lag_varying(dt: f64, tau: &[f64], x: &[f64], m: &[f64]) -> Vec<f64> {
        let mut y = vec![x[0]];
        for k in 1..x.len() {
            let t = 0.5 * (tau[k] + tau[k - 1]);
            let (x0, x1) = (x[k - 1], x[k]);
            y.push(lag_step(dt, t, y[k - 1], |s| {
                hermite(dt, x0, m[k - 1], x1, m[k], s)
            }));
        }
        y
    }

    /// Slopes from the past only: 0 on the first frame, the secant on the second, then the
    /// three-point backward difference `(3x_k − 4x_{k−1} + x_{k−2})/(2Δt)`.
    pub fn backward_slopes(dt: f64, x: &[f64]) -> Vec<f64> {
        (0..x.len())
            .map(|k| match k {
                0 => 0.0,
                1 => (x[1] - x[0]) / dt,
                _ => (3.0 * x[k] - 4.0 * x[k - 1] + x[k - 2]) / (2.0 * dt),
            })
            .collect()
    }

    /// The whole chain over `seq` for SBA1 (the effects as in the module table).
    pub fn chain(seq: &Seq, effects: &[(EffectKind, Vec<f64>)]) -> (Vec<f64>, Vec<bool>) {
        let n = seq.v.len();
        let dt = seq.dt;
        let get = |k: EffectKind| effects.iter().find(|e| e.0 == k).map(|e| e.1.clone());
        let (mut v, mut f) = (seq.v.clone(), seq.f.clone());
        let mut edge = vec![false; n];
        if let Some(p) = get(EffectKind::DeliveryLag) {
            for _ in 0..2 {
                // The flow's slopes: the end slope of the volume's cubic over each frame.
                let acc: Vec<f64> = (0..n)
                    .map(|k| match k {
                        0 => 0.0,
                        _ => {
                            (-6.0 * (v[k] - v[k - 1]) + 2.0 * dt * f[k - 1] + 4.0 * dt * f[k])
                                / (dt * dt)
                        }
                    })
                    .collect();
                let nv = lag(dt, p[0], &v, Some(&f));
                f = lag(dt, p[0], &f, Some(&acc));
                v = nv;
            }
        }
        if let Some(p) = get(EffectKind::TransportDelay) {
            let (v0, f0) = (v.clone(), f.clone());
            for k in 0..n {
                let ts = k as f64 * dt - p[0];
                if ts <= 0.0 {
                    (v[k], f[k]) = (v0[0], f0[0]);
                    continue;
                }
                let j = ((ts / dt).ceil() as usize).max(1) - 1;
                let s = ts - j as f64 * dt;
                v[k] = hermite(dt, v0[j], f0[j], v0[j + 1], f0[j + 1], s);
                // The cubic's derivative, by a central difference of the exact cubic.
                let e = 1e-6 * dt;
                let (a, b) = ((s - e).max(0.0), (s + e).min(dt));
                f[k] = (hermite(dt, v0[j], f0[j], v0[j + 1], f0[j + 1], b)
                    - hermite(dt, v0[j], f0[j], v0[j + 1], f0[j + 1], a))
                    / (b - a);
            }
        }
        if let Some(p) = get(EffectKind::Backlash) {
            let h = 0.5 * p[0];
            let mut z = f64::NAN;
            for k in 0..n {
                if h == 0.0 {
                    continue;
                }
                // The nut inside the frame from the frame alone, eight instants centred on it.
                let (mut sum, mut engaged) = (0.0, 0.0);
                for j in 0..8 {
                    let x = v[k] + f[k] * dt * ((j as f64 + 0.5) / 8.0 - 0.5);
                    if z.is_nan() {
                        z = x;
                    }
                    // Frames where the clamp's engagement is within 10⁻³ mm³ of going either
                    // way are left out of the comparison (f32 may decide otherwise).
                    let slack = (x - z).abs() - h;
                    edge[k] |= slack.abs() < 1e-3;
                    let before = z;
                    z = z.clamp(x - h, x + h);
                    if (z - before) * f[k] > 0.0 {
                        engaged += 1.0;
                    }
                    sum += z;
                }
                v[k] = sum / 8.0;
                f[k] *= engaged / 8.0;
            }
        }
        if let Some(p) = get(EffectKind::Leak) {
            let mut i = 0.0;
            for k in 0..n {
                if k > 0 {
                    i += 0.5 * (seq.p[k] + seq.p[k - 1]) * dt;
                }
                v[k] -= p[0] * i;
                f[k] -= p[0] * seq.p[k];
            }
        }
        let pt: Vec<f64> = seq
            .p
            .iter()
            .map(|&p| p.max(-0.9 * P_ATM_KPA as f64))
            .collect();
        let air = get(EffectKind::AirCompliance);
        let atm = P_ATM_KPA as f64;
        if let Some(p) = &air {
            for k in 0..n {
                v[k] -= p[0] * pt[k] / (atm + pt[k]);
            }
        }
        let sh = Shape::PAPER;
        let mut out: Vec<f64> = (0..n).map(|k| p_raw(sh, &SBA1_RAW, v[k], f[k])).collect();
        let c_poly: Vec<f64> = (0..n).map(|k| c_raw(sh, &SBA1_RAW, v[k], f[k])).collect();
        let k_poly: Vec<f64> = (0..n).map(|k| k_raw(sh, &SBA1_RAW, v[k], f[k])).collect();
        if let Some(p) = get(EffectKind::Hysteresis) {
            // On the chamber's volume: the transforms' output.
            let mut h = 0.0f64;
            for k in 0..n {
                let dv = if k == 0 { 0.0 } else { v[k] - v[k - 1] };
                if dv != 0.0 {
                    h = dv.signum() + (h - dv.signum()) * (-dv.abs() / p[0]).exp();
                }
                let x = (v[k] - 275.0) / 275.0;
                out[k] += (p[1] + p[2] * x) * h;
            }
        }
        if let Some(p) = get(EffectKind::Inertance) {
            for k in 1..n {
                let acc = (-6.0 * (seq.v[k] - seq.v[k - 1])
                    + 2.0 * dt * seq.f[k - 1]
                    + 4.0 * dt * seq.f[k])
                    / (dt * dt);
                out[k] += p[0] * acc;
            }
        }
        if let Some(p) = get(EffectKind::PumpRipple) {
            let w = std::f64::consts::TAU / p[0];
            for k in 0..n {
                let ph = w * seq.v[k];
                let delta = p[1] * ph.sin() + p[2] * ph.cos();
                let rate = w * seq.f[k] * (p[1] * ph.cos() - p[2] * ph.sin());
                out[k] += k_poly[k] * delta + c_poly[k] * rate;
            }
        }
        if let Some(p) = &air {
            // The damping at the flow midway between the pump's and the chamber's: v̇′ − ẋ/2,
            // ẋ = x′(p̃_k)·(p̃_k − p̃_{k−1})/Δt (0 on the first frame), x′ the gas spring.
            let tau: Vec<f64> = (0..n)
                .map(|k| {
                    let spring = p[0] * atm / (atm + pt[k]).powi(2);
                    let pdot = if k == 0 {
                        0.0
                    } else {
                        (pt[k] - pt[k - 1]) / dt
                    };
                    let c_mid = c_raw(sh, &SBA1_RAW, v[k], f[k] - 0.5 * spring * pdot);
                    c_mid.max(0.0) * spring
                })
                .collect();
            let m = backward_slopes(dt, &out);
            out = lag_varying(dt, &tau, &out, &m);
        }
        if let Some(p) = get(EffectKind::SensorLag) {
            // The cubic with backward-difference slopes (0 on the first frame, the secant on the
            // second).
            let m = backward_slopes(dt, &out);
            out = lag(dt, p[0], &out, Some(&m));
        }
        // An output lag remembers an edge frame's flow: the second after it is left out too, and
        // behind a sensor lag the seven time constants its memory takes to fall a thousandfold
        // (a 0.875 s lag after a 2.9 mm³ play's edge was still 7·10⁻⁵ of the range apart after
        // one second).
        if get(EffectKind::AirCompliance).is_some() || get(EffectKind::SensorLag).is_some() {
            let memory = get(EffectKind::SensorLag).map_or(0.0, |p| 7.0 * p[0] / dt);
            let span = (memory.ceil() as usize).max(26);
            let first: Vec<usize> = (0..n).filter(|&k| edge[k]).collect();
            for k in first {
                for e in edge.iter_mut().skip(k).take(span) {
                    *e = true;
                }
            }
        }
        (out, edge)
    }
}

/// The SBA1 model's pressure range over its box (0..550 mm³, ±100 mm³/s): the scale the
/// tolerances are stated against.
fn sba1_range() -> f64 {
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for i in 0..=55 {
        for j in 0..=20 {
            let p = p_raw(
                Shape::PAPER,
                &SBA1_RAW,
                10.0 * i as f64,
                -100.0 + 10.0 * j as f64,
            );
            lo = lo.min(p);
            hi = hi.max(p);
        }
    }
    hi - lo
}

/// Largest |f32 − f64| over the frames not at a backlash edge, relative to the model's range.
fn worst(effects: &[(EffectKind, Vec<f64>)], frames: &[ChainInput]) -> f64 {
    let mut c = Chain::new();
    for (k, p) in effects {
        let p32: Vec<f32> = p.iter().map(|&x| x as f32).collect();
        c.push(Effect::new(*k, &p32).unwrap()).unwrap();
    }
    let got = run(&c, &sba1(), frames);
    assert!(
        got.iter().all(|p| p.is_finite()),
        "every frame inside the model's range"
    );
    let (want, edge) = reference::chain(&reference::Seq::of(frames), effects);
    let range = sba1_range();
    got.iter()
        .zip(&want)
        .zip(&edge)
        .filter(|(_, &e)| !e)
        .map(|((g, w), _)| (*g as f64 - w).abs() / range)
        .fold(0.0, f64::max)
}

/// One representative parameter set per effect (the module table's units).
fn each_effect() -> Vec<(EffectKind, Vec<f64>)> {
    vec![
        (EffectKind::Hysteresis, vec![8.0, 0.4, 0.1]),
        (EffectKind::SensorLag, vec![0.15]),
        (EffectKind::DeliveryLag, vec![0.05]),
        (EffectKind::TransportDelay, vec![0.13]),
        (EffectKind::Backlash, vec![1.5]),
        (EffectKind::Inertance, vec![2e-4]),
        (EffectKind::PumpRipple, vec![8.0, 0.2, -0.07]),
        (EffectKind::AirCompliance, vec![120.0]),
        (EffectKind::Leak, vec![0.02]),
    ]
}

/// Tolerance of the f32 device form against the f64 reference, relative to SBA1's pressure range
/// (89.2 kPa on its 0..550 mm³ × ±100 mm³/s box): 2·10⁻⁵, i.e. 1.8 Pa; the worst seen is printed
/// by the test.
const REL_TOL: f64 = 2e-5;

#[test]
fn each_effect_matches_the_f64_reference() {
    let fr = frames(1500, 200.0, 0.31, 40.0, 1.3);
    let range = sba1_range();
    assert!(range > 5.0, "{range}");
    for e in each_effect() {
        let w = worst(std::slice::from_ref(&e), &fr);
        println!("{:?}: worst |f32 − f64| = {:.2e} of the range", e.0, w);
        assert!(w < REL_TOL, "{:?}: {w:e}", e.0);
    }
}

#[test]
fn a_four_effect_chain_matches_the_f64_reference() {
    let fr = frames(1500, 200.0, 0.31, 40.0, 1.3);
    let all = each_effect();
    for pick in [[0, 1, 2, 3], [4, 5, 6, 7], [8, 3, 0, 1], [2, 7, 6, 8]] {
        let effects: Vec<_> = pick.iter().map(|&i| all[i].clone()).collect();
        let w = worst(&effects, &fr);
        println!("{pick:?}: worst {w:.2e}");
        assert!(w < REL_TOL, "{pick:?}: {w:e}");
    }
}

#[test]
fn zero_size_effects_are_the_bare_polynomial_bit_for_bit() {
    let fr = frames(300, 200.0, 0.31, 40.0, 1.3);
    let bare = run(&Chain::new(), &sba1(), &fr);
    for (i, p) in bare.iter().enumerate() {
        let e = sba1().eval(fr[i].v, fr[i].vdot).unwrap();
        assert_eq!(p.to_bits(), e.p.to_bits());
    }
    let zero: [(EffectKind, &[f32]); 9] = [
        (EffectKind::Hysteresis, &[5.0, 0.0, 0.0]),
        (EffectKind::SensorLag, &[0.0]),
        (EffectKind::DeliveryLag, &[0.0]),
        (EffectKind::TransportDelay, &[0.0]),
        (EffectKind::Backlash, &[0.0]),
        (EffectKind::Inertance, &[0.0]),
        (EffectKind::PumpRipple, &[8.0, 0.0, 0.0]),
        (EffectKind::AirCompliance, &[0.0]),
        (EffectKind::Leak, &[0.0]),
    ];
    for group in zero.chunks(MAX_EFFECTS) {
        let got = run(&chain(group), &sba1(), &fr);
        for (g, b) in got.iter().zip(&bare) {
            // ±0 (a zero-size term adds −0.0 or +0.0): compare values, not bits.
            assert_eq!(g, b, "{group:?}");
        }
    }
}

#[test]
fn hysteron_hand_values() {
    // w = 2 mm³, gap H₀ = 1 kPa: up 6 mm³ in one frame → h = 1 − e⁻³; down 2 → −1 + (h + 1)e⁻¹.
    let model = linear(0.0, 0.0, 0.0);
    let c = chain(&[(EffectKind::Hysteresis, &[2.0, 1.0, 0.0])]);
    let at = |v: f32| ChainInput {
        v,
        vdot: 0.0,
        p: 0.0,
        dt: DT,
    };
    let p = run(&c, &model, &[at(500.0), at(506.0), at(504.0), at(504.0)]);
    let up = 1.0 - (-3.0f64).exp();
    let down = -1.0 + (up + 1.0) * (-1.0f64).exp();
    assert_eq!(p[0], 0.0);
    assert!((p[1] as f64 - up).abs() < 1e-6, "{}", p[1]);
    assert!((p[2] as f64 - down).abs() < 1e-6, "{}", p[2]);
    assert_eq!(p[3], p[2], "no motion, no change");
    // H₁ scales with x = (v − 500)/500 for this model's scaling: at v = 1000, x = 1.
    let c = chain(&[(EffectKind::Hysteresis, &[2.0, 0.0, 3.0])]);
    let p = run(&c, &model, &[at(960.0), at(1000.0)]);
    let h = 1.0 - (-20.0f64).exp();
    assert!((p[1] as f64 - 3.0 * h).abs() < 1e-5, "{}", p[1]);
}

#[test]
fn backlash_hand_values() {
    // Play b = 1.9 on P = v, frames of 1 mm³ at 25 mm³/s: inside a frame the nut runs from
    // v − 7/16 to v + 7/16 in steps of 1/8. The first frame starts the plunger at the nut's first
    // instant (499.5625) and the nut, 0.875 further at most, does not reach the far side (0.95
    // away); from the second frame's first instant on the plunger trails the nut by 0.95 (mean
    // v − 0.95); after the reversal the plunger stands at 503.4375 − 0.95 = 502.4875 while the
    // nut runs back from 502.4375 to 501.5625, and the nut pushes it down again from the next
    // frame's first instant on (mean v + 0.95). The flow reaches the model only while engaged.
    let model = linear(0.0, 1.0, 0.0);
    let c = chain(&[(EffectKind::Backlash, &[1.9])]);
    let nut = [500.0, 501.0, 502.0, 503.0, 502.0, 501.0, 500.0];
    let q = [25.0, 25.0, 25.0, 25.0, -25.0, -25.0, -25.0];
    let fr: Vec<ChainInput> = nut
        .iter()
        .zip(q)
        .map(|(&v, f)| ChainInput {
            v,
            vdot: f,
            p: 0.0,
            dt: DT,
        })
        .collect();
    let close = |got: Vec<f32>, want: &[f32]| {
        assert!(
            got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-4),
            "{got:?} vs {want:?}"
        );
    };
    close(
        run(&c, &model, &fr),
        &[499.5625, 500.05, 501.05, 502.05, 502.4875, 501.95, 500.95],
    );
    let flows = linear(0.0, 0.0, 1.0);
    close(
        run(&c, &flows, &fr),
        &[0.0, 25.0, 25.0, 25.0, 0.0, -25.0, -25.0],
    );
}

#[test]
fn lags_settle_on_the_polynomial_and_trail_a_ramp_by_tau() {
    // Constant inputs: every lag's output is its input.
    let model = sba1();
    let still = vec![
        ChainInput {
            v: 300.0,
            vdot: 0.0,
            p: 3.0,
            dt: DT
        };
        50
    ];
    let bare = model.eval(300.0, 0.0).unwrap().p;
    let lags: [(EffectKind, &[f32]); 3] = [
        (EffectKind::SensorLag, &[0.3]),
        (EffectKind::DeliveryLag, &[0.2]),
        (EffectKind::TransportDelay, &[0.5]),
    ];
    for p in run(&chain(&lags), &model, &still) {
        assert!((p - bare).abs() <= 1e-6 * bare.abs(), "{p} vs {bare}");
    }
    // P = v, v = 100 + 20 t: a sensor lag of τ trails by 20τ; the delivery lag (two stages of τ)
    // by 2·20τ; a delay d by 20 d — after the transients have died.
    let model = linear(0.0, 1.0, 0.0);
    let ramp: Vec<ChainInput> = (0..600)
        .map(|k| ChainInput {
            v: 100.0 + 20.0 * k as f32 * DT,
            vdot: 20.0,
            p: 0.0,
            dt: DT,
        })
        .collect();
    for (e, lag) in [
        ((EffectKind::SensorLag, &[0.3f32][..]), 20.0 * 0.3),
        ((EffectKind::DeliveryLag, &[0.3][..]), 2.0 * 20.0 * 0.3),
        ((EffectKind::TransportDelay, &[0.5][..]), 20.0 * 0.5),
    ] {
        let p = run(&chain(&[e]), &model, &ramp);
        let last = ramp.len() - 1;
        let trail = ramp[last].v - p[last];
        assert!((trail - lag).abs() < 2e-3, "{:?}: {trail} vs {lag}", e.0);
    }
}

#[test]
fn leak_and_air_hand_values() {
    // Leak λ on P = v with constant measured p: I_k = p·kΔt, v′ = v − λ p k Δt.
    let model = linear(0.0, 1.0, 0.0);
    let c = chain(&[(EffectKind::Leak, &[0.5])]);
    let fr = vec![
        ChainInput {
            v: 400.0,
            vdot: 0.0,
            p: 10.0,
            dt: DT
        };
        26
    ];
    let p = run(&c, &model, &fr);
    assert!(
        (p[25] - (400.0 - 0.5 * 10.0 * 25.0 * DT)).abs() < 1e-4,
        "{}",
        p[25]
    );
    // Air on a model without damping (no lag): v′ = v − V_a p/(P_atm + p).
    let c = chain(&[(EffectKind::AirCompliance, &[200.0])]);
    let p = run(&c, &model, &fr[..1])[0];
    let want = 400.0 - 200.0 * 10.0 / (P_ATM_KPA + 10.0);
    assert!((p - want).abs() < 1e-4, "{p} vs {want}");
}

#[test]
fn inertance_is_l_times_the_cubic_end_acceleration() {
    // v = 100 + 5t² (exact flow 10t): the cubic through two frames with the true slopes is the
    // parabola itself, so v̈ = 10 exactly; P = L·v̈ on a zero model.
    let model = linear(0.0, 0.0, 0.0);
    let c = chain(&[(EffectKind::Inertance, &[0.25])]);
    let fr: Vec<ChainInput> = (0..20)
        .map(|k| {
            let t = k as f32 * DT;
            ChainInput {
                v: 1.0 + 5.0 * t * t,
                vdot: 10.0 * t,
                p: 0.0,
                dt: DT,
            }
        })
        .collect();
    let p = run(&c, &model, &fr);
    assert_eq!(p[0], 0.0, "first frame: at rest");
    for &x in &p[1..] {
        assert!((x - 2.5).abs() < 1e-3, "{x}");
    }
}

#[test]
fn reset_starts_over_and_a_failed_frame_changes_nothing() {
    let model = sba1();
    let c = chain(&[
        (EffectKind::Hysteresis, &[8.0, 0.4, 0.1]),
        (EffectKind::SensorLag, &[0.15]),
        (EffectKind::DeliveryLag, &[0.05]),
        (EffectKind::TransportDelay, &[0.13]),
    ]);
    let fr = frames(200, 200.0, 0.31, 40.0, 1.3);
    let hist = ArHistory::new();
    let mut st = ChainState::new();
    let first: Vec<f32> = fr
        .iter()
        .map(|&f| c.eval(&model, &hist, &mut st, f).unwrap().p)
        .collect();
    st.reset();
    assert_eq!(st, ChainState::new());
    // Prepared ahead: the same frames, bit for bit.
    st.prepare(&c, DT).unwrap();
    let prepared: Vec<f32> = fr
        .iter()
        .map(|&f| c.eval(&model, &hist, &mut st, f).unwrap().p)
        .collect();
    assert_eq!(first, prepared);
    st.reset();
    let again: Vec<f32> = fr
        .iter()
        .map(|&f| c.eval(&model, &hist, &mut st, f).unwrap().p)
        .collect();
    assert_eq!(first, again);
    // Out of range: an error, and the state is exactly as before.
    let before = st;
    let far = ChainInput {
        v: f32::NAN,
        vdot: 0.0,
        p: 0.0,
        dt: DT,
    };
    assert_eq!(
        c.eval(&model, &hist, &mut st, far),
        Err(ModelError::NonFinite)
    );
    assert_eq!(st, before);
    let bare = Chain::new();
    let far = ChainInput { v: 1e5, ..fr[0] };
    assert_eq!(
        bare.eval(&model, &hist, &mut st, far),
        Err(ModelError::OutOfRange)
    );
    assert_eq!(st, before);
    let leak = chain(&[(EffectKind::Leak, &[0.1])]);
    let nan = ChainInput {
        p: f32::NAN,
        ..fr[0]
    };
    assert_eq!(
        leak.eval(&model, &hist, &mut st, nan),
        Err(ModelError::NonFinite)
    );
}

#[test]
fn chain_stiffness_and_damping() {
    let model = sba1();
    let hist = ArHistory::new();
    let at = |v: f32, f: f32| ChainInput {
        v,
        vdot: f,
        p: 4.0,
        dt: DT,
    };
    // Without effects, and through lags at rest: the polynomial's own k and c.
    let e0 = model.eval(300.0, 20.0).unwrap();
    for c in [
        Chain::new(),
        chain(&[
            (EffectKind::SensorLag, &[0.2]),
            (EffectKind::DeliveryLag, &[0.1]),
        ]),
    ] {
        let e = c
            .eval(&model, &hist, &mut ChainState::new(), at(300.0, 20.0))
            .unwrap();
        assert_eq!((e.k, e.c), (e0.k, e0.c));
    }
    // Air: the gas spring V_a·P_atm/(P_atm + p)² in series with the chamber.
    let c = chain(&[(EffectKind::AirCompliance, &[150.0])]);
    let e = c
        .eval(&model, &hist, &mut ChainState::new(), at(300.0, 0.0))
        .unwrap();
    let ep = model.eval(e.v_in, 0.0).unwrap();
    let spring = 150.0 * P_ATM_KPA / (P_ATM_KPA + 4.0).powi(2);
    let want = 1.0 / (1.0 / ep.k + spring);
    assert!((e.k - want).abs() < 1e-6 * want, "{} vs {want}", e.k);
    // Hysteresis: k matches the finite difference of P̂ along the motion (same direction).
    let c = chain(&[(EffectKind::Hysteresis, &[8.0, 0.5, 0.2])]);
    let mut st = ChainState::new();
    for k in 0..10 {
        c.eval(&model, &hist, &mut st, at(280.0 + 2.0 * k as f32, 50.0))
            .unwrap();
    }
    let mut st2 = st;
    let e1 = c.eval(&model, &hist, &mut st, at(300.0, 50.0)).unwrap();
    let e2 = c.eval(&model, &hist, &mut st2, at(300.01, 50.0)).unwrap();
    let fd = (e2.p - e1.p) / 0.01;
    assert!((fd - e1.k).abs() < 2e-3 * e1.k.abs(), "{fd} vs {}", e1.k);
    // Backlash's dead band: neither k nor c.
    let c = chain(&[(EffectKind::Backlash, &[2.0])]);
    let e = c
        .eval(&model, &hist, &mut ChainState::new(), at(300.0, 10.0))
        .unwrap();
    assert_eq!((e.k, e.c), (0.0, 0.0));
}

#[test]
fn bad_effects_are_refused() {
    use EffectKind::*;
    assert_eq!(Effect::new(Hysteresis, &[1.0]), Err(ModelError::BadLength));
    assert_eq!(
        Effect::new(SensorLag, &[f32::NAN]),
        Err(ModelError::NonFinite)
    );
    assert_eq!(
        Effect::new(SensorLag, &[-0.1]),
        Err(ModelError::BadParameter)
    );
    assert_eq!(
        Effect::new(Hysteresis, &[0.0, 1.0, 1.0]),
        Err(ModelError::BadParameter)
    );
    assert_eq!(
        Effect::new(PumpRipple, &[-8.0, 1.0, 1.0]),
        Err(ModelError::BadParameter)
    );
    assert!(Effect::new(Inertance, &[-1e-4]).is_ok());
    let mut c = Chain::new();
    c.push(Effect::new(Leak, &[0.1]).unwrap()).unwrap();
    assert_eq!(
        c.push(Effect::new(Leak, &[0.2]).unwrap()),
        Err(ModelError::BadParameter)
    );
    let too_long = (MAX_DELAY_FRAMES - 1) as f32 * DT;
    assert_eq!(
        Effect::new(TransportDelay, &[too_long]),
        Err(ModelError::BadParameter)
    );
    assert!(Effect::new(TransportDelay, &[MAX_DELAY_S]).is_ok());
    assert!(Effect::new(Leak, &[0.0]).is_ok());
    assert_eq!(Effect::new(Leak, &[-1e-9]), Err(ModelError::BadParameter));
    assert_eq!(Effect::new(Leak, &[0.1, 0.2]), Err(ModelError::BadLength));
    for k in [SensorLag, Backlash, Inertance] {
        c.push(Effect::new(k, &[0.0]).unwrap()).unwrap();
    }
    assert_eq!(
        c.push(Effect::new(DeliveryLag, &[0.1]).unwrap()),
        Err(ModelError::BadLength)
    );
    // Kept in evaluation order whatever the order of pushing.
    let kinds: Vec<EffectKind> = c.effects().iter().map(|e| e.kind()).collect();
    assert_eq!(kinds, vec![Backlash, Leak, Inertance, SensorLag]);
    // A frame period that is not > 0, or too short a delay line for the delay: every frame fails.
    let mut st = ChainState::new();
    let at = |dt: f32| ChainInput {
        v: 300.0,
        vdot: 0.0,
        p: 0.0,
        dt,
    };
    let lag = chain(&[(SensorLag, &[0.1])]);
    assert_eq!(
        lag.eval(&sba1(), &ArHistory::new(), &mut st, at(0.0)),
        Err(ModelError::BadParameter)
    );
    let d = chain(&[(TransportDelay, &[1.5])]);
    assert!(d.eval(&sba1(), &ArHistory::new(), &mut st, at(DT)).is_ok());
    st.reset();
    assert_eq!(
        d.eval(&sba1(), &ArHistory::new(), &mut st, at(0.02)),
        Err(ModelError::BadParameter)
    );
    for k in EffectKind::ALL {
        assert_eq!(EffectKind::from_name(k.name()), Some(k));
        assert_eq!(EffectKind::from_code(k.code()), Some(k));
    }
    assert_eq!(EffectKind::from_code(9), None);
    assert_eq!(EffectKind::from_name("ripple"), None);
    assert_eq!(EffectKind::from_name("offset_drift"), None);
}

fn effect_strategy() -> impl Strategy<Value = (EffectKind, Vec<f64>)> {
    prop_oneof![
        (1.0..40.0f64, -1.0..1.0f64, -0.5..0.5f64)
            .prop_map(|(w, a, b)| (EffectKind::Hysteresis, vec![w, a, b])),
        (0.0..1.0f64).prop_map(|t| (EffectKind::SensorLag, vec![t])),
        (0.0..0.5f64).prop_map(|t| (EffectKind::DeliveryLag, vec![t])),
        (0.0..1.5f64).prop_map(|t| (EffectKind::TransportDelay, vec![t])),
        (0.0..5.0f64).prop_map(|b| (EffectKind::Backlash, vec![b])),
        (-1e-3..1e-3f64).prop_map(|l| (EffectKind::Inertance, vec![l])),
        (2.0..20.0f64, -0.3..0.3f64, -0.3..0.3f64)
            .prop_map(|(l, a, b)| (EffectKind::PumpRipple, vec![l, a, b])),
        (0.0..200.0f64).prop_map(|v| (EffectKind::AirCompliance, vec![v])),
        (0.0..0.05f64).prop_map(|l| (EffectKind::Leak, vec![l])),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Random chains (up to four distinct effects, random parameters) on random two-tone motion:
    /// the f32 device form stays within `REL_TOL` of the f64 reference.
    #[test]
    fn random_chains_match_the_f64_reference(
        effects in proptest::collection::vec(effect_strategy(), 1..=MAX_EFFECTS),
        a1 in 20.0..200.0f64, w1 in 0.1..1.5f64, a2 in 0.0..40.0f64, w2 in 0.5..3.0f64,
    ) {
        let mut effects = effects;
        effects.sort_by_key(|e| e.0);
        effects.dedup_by_key(|e| e.0);
        // Flows inside the model's range (±2 scaled units of 100 mm³/s, with a margin).
        let peak = a1 * w1 + a2 * w2;
        let shrink = (150.0 / peak).min(1.0);
        let fr = frames(400, a1 * shrink, w1, a2 * shrink, w2);
        let w = worst(&effects, &fr);
        prop_assert!(w < REL_TOL, "{effects:?}: {w:e}");
    }

    /// The air lag's time constant on the second frame is `x′(p̃₁)·(P(v′₁, v̇₁) − P(v′₁, v̇₁ − ẋ))/ẋ`:
    /// the secant of SBA1's law (quadratic in flow) over the flow the pocket takes,
    /// `ẋ = x′(p̃₁)·(p̃₁ − p̃₀)/Δt`, which is the damping at the midway flow `v̇₁ − ẋ/2` the chain
    /// evaluates; here P term by term in f64, no derivative taken (on the first frame Ṗ = 0:
    /// the damping at v̇₀ itself). The two frames' output is the reference lag with those τ.
    #[test]
    fn the_air_lag_runs_on_the_secant_over_the_pockets_flow(
        v0 in 150.0..400.0f64, f0 in -80.0..80.0f64, f1 in -80.0..80.0f64,
        p0 in -5.0..40.0f64, dp in 0.3..3.0f64, up in any::<bool>(), va in 20.0..200.0f64,
    ) {
        let dt = DT as f64;
        let p1 = if up { p0 + dp } else { p0 - dp };
        let v1 = v0 + 0.5 * (f0 + f1) * dt;
        let fr: Vec<ChainInput> = [(v0, f0, p0), (v1, f1, p1)]
            .iter()
            .map(|&(v, f, p)| ChainInput { v: v as f32, vdot: f as f32, p: p as f32, dt: DT })
            .collect();
        let c = chain(&[(EffectKind::AirCompliance, &[va as f32])]);
        let got = run(&c, &sba1(), &fr);
        // The reference in f64 from the f32 inputs the chain saw.
        let atm = P_ATM_KPA as f64;
        let sh = Shape::PAPER;
        let va = va as f32 as f64;
        let (v, f, p): (Vec<f64>, Vec<f64>, Vec<f64>) = (
            fr.iter().map(|x| x.v as f64).collect(),
            fr.iter().map(|x| x.vdot as f64).collect(),
            fr.iter().map(|x| x.p as f64).collect(),
        );
        let spring = |p: f64| va * atm / (atm + p).powi(2);
        let vc: Vec<f64> = (0..2).map(|k| v[k] - va * p[k] / (atm + p[k])).collect();
        let x: Vec<f64> = (0..2).map(|k| p_raw(sh, &SBA1_RAW, vc[k], f[k])).collect();
        let xdot = spring(p[1]) * (p[1] - p[0]) / dt;
        let secant = (p_raw(sh, &SBA1_RAW, vc[1], f[1])
            - p_raw(sh, &SBA1_RAW, vc[1], f[1] - xdot))
            / xdot;
        let tau = [
            c_raw(sh, &SBA1_RAW, vc[0], f[0]).max(0.0) * spring(p[0]),
            secant.max(0.0) * spring(p[1]),
        ];
        let want = reference::lag_varying(dt, &tau, &x, &reference::backward_slopes(dt, &x));
        let tol = REL_TOL * sba1_range();
        for k in 0..2 {
            prop_assert!((got[k] as f64 - want[k]).abs() < tol, "frame {k}: {} vs {}", got[k], want[k]);
        }
    }

    /// Any finite inputs: an answer or an error, never a panic or a silent NaN.
    #[test]
    fn never_panics(
        effects in proptest::collection::vec(effect_strategy(), 0..=MAX_EFFECTS),
        inputs in proptest::collection::vec((-1e4..1e4f32, -1e3..1e3f32, -200.0..200.0f32), 1..50),
    ) {
        let mut c = Chain::new();
        for (k, p) in &effects {
            let p32: Vec<f32> = p.iter().map(|&x| x as f32).collect();
            let _ = c.push(Effect::new(*k, &p32).unwrap());
        }
        let mut st = ChainState::new();
        for (v, f, p) in inputs {
            if let Ok(e) = c.eval(&sba1(), &ArHistory::new(), &mut st, ChainInput { v, vdot: f, p, dt: DT }) {
                prop_assert!(e.p.is_finite() && e.k.is_finite() && e.c.is_finite());
            }
        }
    }
}

#[test]
fn the_load_pressure_undoes_the_sensor_lag_on_the_residual() {
    let dt = DT;
    let tau = 0.1f32;
    let lagged = chain(&[(EffectKind::SensorLag, &[tau])]);
    let plain = chain(&[(EffectKind::Hysteresis, &[5.0, 0.5, 0.0])]);
    let mut st = ChainState::new();
    // A load ramping at 2 kPa/s from t = 0, through the sensor's first-order lag (exact):
    // r(t) = a(t − τ) + aτe^{−t/τ}. Once r is linear (a few τ), r + τ ṙ is the load a·t exactly
    // (the backward difference of a straight line is its slope).
    let a = 2.0f64;
    let tau64 = f64::from(tau);
    let r = |t: f64| a * (t - tau64) + a * tau64 * (-t / tau64).exp();
    for k in 0..40 {
        let t = k as f64 * f64::from(dt);
        let load = lagged.load_pressure(&mut st, r(t) as f32, dt);
        if k == 0 {
            assert_eq!(
                load,
                r(0.0) as f32,
                "the first frame has no slope: r itself"
            );
        }
        if t > 8.0 * tau64 {
            assert!(
                (f64::from(load) - a * t).abs() < 1e-3,
                "t {t}: {load} vs {}",
                a * t
            );
        }
        // The residual alone is a·τ = 0.2 kPa late.
        if t > 8.0 * tau64 {
            assert!((r(t) - a * t + a * tau64).abs() < 1e-3);
        }
    }
    // A frame without a residual: NaN, and the next frame starts over (no slope across it).
    assert!(lagged.load_pressure(&mut st, f32::NAN, dt).is_nan());
    assert_eq!(lagged.load_pressure(&mut st, 1.5, dt), 1.5);
    // A reset starts over too.
    st.reset();
    assert_eq!(lagged.load_pressure(&mut st, 0.25, dt), 0.25);
    // Without a sensor lag the load is the residual.
    let mut st = ChainState::new();
    for r in [0.0f32, 1.0, -3.0, 0.5] {
        assert_eq!(plain.load_pressure(&mut st, r, dt), r);
    }
    assert_eq!(Chain::new().load_pressure(&mut st, 0.7, dt), 0.7);
}

/// The stored codes of the effect kinds and their parameter layouts, pinned (the table of
/// `model_core::spec`): boards keep models across firmware updates, so a code that changed would
/// decode every stored chain holding it as another effect, and a parameter moved or added would
/// read another kind's bytes. A failure here means a row of the table moved: give the kind its
/// old code and layout back, never change this table; a new kind is added with the next free
/// code (`spec::NEXT_FREE_CODE`), and a code is never reused.
#[test]
fn stored_effect_codes_never_change() {
    use EffectKind::*;
    // (kind, wire name, code, [(parameter, unit)], stage), written down by hand.
    type Row = (
        EffectKind,
        &'static str,
        u8,
        &'static [(&'static str, &'static str)],
        Stage,
    );
    let pinned: [Row; 9] = [
        (
            DeliveryLag,
            "delivery_lag",
            0,
            &[("time_constant", "s")],
            Stage::Input,
        ),
        (
            TransportDelay,
            "transport_delay",
            1,
            &[("delay", "s")],
            Stage::Input,
        ),
        (Backlash, "backlash", 2, &[("play", "mm3")], Stage::Input),
        (
            Leak,
            "leak",
            3,
            &[("conductance", "mm3/(kPa*s)")],
            Stage::Input,
        ),
        (
            AirCompliance,
            "air_compliance",
            4,
            &[("air_volume", "mm3")],
            Stage::Input,
        ),
        (
            Hysteresis,
            "hysteresis",
            5,
            &[("width", "mm3"), ("gap_h0", "kPa"), ("gap_h1", "kPa")],
            Stage::Added,
        ),
        (
            Inertance,
            "inertance",
            6,
            &[("inertance", "kPa*s^2/mm3")],
            Stage::Added,
        ),
        (
            PumpRipple,
            "pump_ripple",
            7,
            &[
                ("period", "mm3"),
                ("sin_amplitude", "mm3"),
                ("cos_amplitude", "mm3"),
            ],
            Stage::Added,
        ),
        (
            SensorLag,
            "sensor_lag",
            8,
            &[("time_constant", "s")],
            Stage::Output,
        ),
    ];
    assert_eq!(
        pinned.len(),
        EffectKind::ALL.len(),
        "a kind without a pinned code"
    );
    for (kind, name, code, params, stage) in pinned {
        let spec = kind.spec();
        assert_eq!((kind.code(), spec.code), (code, code), "{kind:?}");
        assert_eq!(kind.name(), name, "{kind:?}");
        assert_eq!(kind.stage(), stage, "{kind:?}");
        let layout: Vec<(&str, &str)> = spec.params.iter().map(|p| (p.name, p.unit)).collect();
        assert_eq!(layout, params, "{kind:?}");
        assert_eq!(kind.params(), params.len());
        assert!(kind.params() <= MAX_EFFECT_PARAMS);
        assert!(code < spec::NEXT_FREE_CODE, "{kind:?}");
    }
    // Every code below the next free one is taken, none twice; the rest decode as nothing.
    for code in 0..=u8::MAX {
        let holders = EffectKind::ALL.iter().filter(|k| k.code() == code).count();
        assert_eq!(
            holders,
            usize::from(code < spec::NEXT_FREE_CODE),
            "code {code}"
        );
        assert_eq!(
            EffectKind::from_code(code).map(|k| k.code()),
            (code < spec::NEXT_FREE_CODE).then_some(code)
        );
    }
}

/// The evaluation order runs the stages in order (inputs, added terms, output filters) and is
/// not the stored code's order; each parameter's range as the table states it, at its edges.
#[test]
fn spec_stages_and_bounds() {
    use EffectKind::*;
    assert_eq!(
        EffectKind::ALL,
        [
            DeliveryLag,
            TransportDelay,
            Backlash,
            Leak,
            AirCompliance,
            Hysteresis,
            Inertance,
            PumpRipple,
            SensorLag
        ]
    );
    let stages: Vec<Stage> = EffectKind::ALL.iter().map(|k| k.stage()).collect();
    assert!(stages.windows(2).all(|w| w[0] <= w[1]), "{stages:?}");
    for (kind, at_edge, below) in [
        (SensorLag, 0.0f32, -1e-30f32),
        (DeliveryLag, 0.0, -1e-30),
        (Backlash, 0.0, -1e-30),
        (AirCompliance, 0.0, -1e-30),
        (Leak, 0.0, -1e-30),
        (TransportDelay, 0.0, -1e-30),
    ] {
        assert!(Effect::new(kind, &[at_edge]).is_ok(), "{kind:?}");
        assert_eq!(
            Effect::new(kind, &[below]),
            Err(ModelError::BadParameter),
            "{kind:?}"
        );
    }
    assert_eq!(
        Effect::new(TransportDelay, &[1.5000001]),
        Err(ModelError::BadParameter)
    );
    for kind in [Hysteresis, PumpRipple] {
        assert!(Effect::new(kind, &[1e-30, -5.0, 5.0]).is_ok(), "{kind:?}");
        assert_eq!(
            Effect::new(kind, &[0.0, 1.0, 1.0]),
            Err(ModelError::BadParameter)
        );
    }
    assert!(Effect::new(Inertance, &[-3.0e5]).is_ok());
}
