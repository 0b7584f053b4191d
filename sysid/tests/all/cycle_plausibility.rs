//! The log's own cycle period, and the plausibility rule that uses it: a ripple locked to the
//! cycles (at the cycle rate or a harmonic) is the model's misfit over a cycle, not a ripple.
//!
//! Truths: synthetic motions whose period is set by construction, and hand-computed harmonics.

use sysid::residual::effects::{Effect, EffectKind, Scales};
use sysid::residual::{cycle_period, motion_period};

/// Cycle indices for cycles of the given durations, sampled every `dt` s.
fn split(durations: &[f64], dt: f64) -> (Vec<f64>, Vec<usize>) {
    let (mut t, mut c) = (Vec::new(), Vec::new());
    let mut start = 0.0;
    for (i, d) in durations.iter().enumerate() {
        let mut x = start;
        while x < start + d - 1e-9 {
            t.push(x);
            c.push(i);
            x += dt;
        }
        start += d;
    }
    (t, c)
}

#[test]
fn a_regular_split_gives_its_period_and_an_irregular_one_none() {
    let regular: Vec<f64> = (0..10)
        .map(|i| 5.0 + 0.05 * ((i % 3) as f64 - 1.0))
        .collect();
    let (t, c) = split(&regular, 0.01);
    let p = cycle_period(&t, &c).expect("regular cycles");
    // The inner cycles' mean (first and last left out), to the sampling step.
    let want = regular[1..9].iter().sum::<f64>() / 8.0;
    assert!((p - want).abs() < 0.02, "{p} vs {want}");
    // A breath split at its pause: 1.6 s and 8.4 s alternating.
    let (t, c) = split(&[1.6, 8.4, 1.6, 8.4, 1.6, 8.4, 1.6, 8.4], 0.01);
    assert_eq!(cycle_period(&t, &c), None);
    // Too few cycles to tell.
    let (t, c) = split(&[5.0, 5.0, 5.0, 5.0], 0.01);
    assert_eq!(cycle_period(&t, &c), None);
}

#[test]
fn a_repeating_flow_gives_its_period_and_a_changing_one_none() {
    // A breathing-like flow: 1 s inspiration, 4 s expiration, period 5 s, 100 Hz, 60 s, with a
    // deterministic pseudo-noise of 5 % of the peak.
    let dt = 0.01;
    let t: Vec<f64> = (0..6000).map(|k| k as f64 * dt).collect();
    let q: Vec<f64> = t
        .iter()
        .enumerate()
        .map(|(k, &x)| {
            let ph = x % 5.0;
            let breath = if ph < 1.0 {
                400.0
            } else {
                -100.0 * (-(ph - 1.0)).exp()
            };
            breath + 20.0 * ((k as f64 * 12.9898).sin() * 43758.5453).fract()
        })
        .collect();
    let p = motion_period(&t, &q).expect("a repeating flow");
    assert!((p - 5.0).abs() < 0.05, "{p}");
    // The paper's protocol: fill and empty at 20, 40, …, 100 mm³/s, each cycle shorter than the
    // last: no period.
    let (mut t, mut q) = (Vec::new(), Vec::new());
    let mut x = 0.0;
    for rate in [20.0, 40.0, 60.0, 80.0, 100.0] {
        let leg = 550.0 / rate;
        for (dir, len) in [(1.0, leg), (0.0, 2.0), (-1.0, leg), (0.0, 2.0)] {
            let n = (len / 0.04) as usize;
            for _ in 0..n {
                t.push(x);
                q.push(dir * rate);
                x += 0.04;
            }
        }
    }
    assert_eq!(motion_period(&t, &q), None);
}

#[test]
fn a_ripple_at_a_harmonic_of_the_cycle_is_not_a_ripple() {
    let ripple = EffectKind::named("ripple").expect("ripple");
    let scales = |cycle_s| Scales {
        v_range: 500.0,
        dt: 0.01,
        duration: 41.0,
        p_integral: 100.0,
        p_pos_integral: 100.0,
        p_range: 10.0,
        cycle_s,
        rig: sysid::residual::Rig::Generic,
    };
    let judge =
        |f: f64, cycle_s| ripple.unphysical(&Effect::new(ripple, f), &[0.1, 0.1], &scales(cycle_s));
    // 2.1974 Hz on 5.009 s breaths: harmonic 11 (2.1960 Hz), inside max(1/41 s, 1 %) = 0.024 Hz.
    let why = judge(2.1974, Some(5.009)).expect("locked to the cycles");
    assert!(why.contains("harmonic 11"), "{why}");
    // The breathing rate itself.
    assert!(judge(0.19998, Some(5.0)).is_some());
    // Between harmonics (2.3 Hz is 0.1 Hz from 11/5.009 and 12/5.009 Hz): a ripple may be.
    assert_eq!(judge(2.3, Some(5.009)), None);
    // Above the 20th harmonic, or without a regular cycle, the rule says nothing.
    assert_eq!(judge(21.0 / 5.0, Some(5.0)), None);
    assert_eq!(judge(2.1974, None), None);
    // The same rule names the harmonic for the `periodic` signature of `remaining`.
    let h = sysid::residual::effects::ripple::cycle_harmonic;
    assert_eq!(h(2.1974, &scales(Some(5.009))), Some(11.0));
    assert_eq!(h(2.3, &scales(Some(5.009))), None);
}

#[test]
fn a_lag_of_a_good_part_of_the_cycle_is_named_pressure_dynamics() {
    let lag = EffectKind::named("sensor_lag").expect("sensor_lag");
    let scales = |cycle_s| Scales {
        v_range: 500.0,
        dt: 0.01,
        duration: 233.0,
        p_integral: 100.0,
        p_pos_integral: 100.0,
        p_range: 10.0,
        cycle_s,
        rig: sysid::residual::Rig::Generic,
    };
    let name = |tau: f64, cycle_s| {
        lag.neutral(&Effect::new(lag, tau), &scales(cycle_s))
            .map(|n| n.0)
    };
    // The test lung's 0.985 s on its 5 s breaths (20 %), the bag's 0.37 s (7 %).
    assert_eq!(name(0.985, Some(5.0)), Some("pressure_dynamics"));
    assert_eq!(name(0.37, Some(5.01)), Some("pressure_dynamics"));
    // The QuickLung's 32 ms on 3 s (1 %): a sensor lag. The boundary is 5 % of the period.
    assert_eq!(name(0.0316, Some(3.01)), None);
    assert_eq!(name(0.24, Some(5.0)), None);
    assert_eq!(name(0.26, Some(5.0)), Some("pressure_dynamics"));
    // No regular cycle (the paper's protocols): the name stands.
    assert_eq!(name(0.985, None), None);
}

#[test]
fn a_play_leak_or_air_pocket_of_a_large_part_of_the_stroke_is_not_kept() {
    let sc = Scales {
        v_range: 550.0,
        dt: 0.04,
        duration: 2000.0,
        p_integral: 20_000.0,
        p_pos_integral: 20_000.0,
        p_range: 10.0,
        cycle_s: None,
        rig: sysid::residual::Rig::Syringe,
    };
    let judge = |name: &str, theta: f64| {
        let k = EffectKind::named(name).expect("known effect");
        k.unphysical(&Effect::new(k, theta), &[0.1, 0.1], &sc)
    };
    // Play: 5 % of 550 mm³ is 27.5 mm³.
    let why = judge("backlash", 30.0).expect("30 mm³ of play");
    assert!(why.contains("5 % of the stroke"), "{why}");
    assert_eq!(judge("backlash", 25.0), None);
    // Leak: λ ∫P dt against a quarter of the stroke (137.5 mm³): λ = 0.01 loses 200 mm³.
    assert!(judge("leak", 0.01).is_some());
    assert_eq!(judge("leak", 0.005), None);
    // Air: half the stroke is 275 mm³ (the paper's pockets are 20–100 mm³).
    assert!(judge("air_compliance", 300.0).is_some());
    assert_eq!(judge("air_compliance", 100.0), None);
}
