//! The plant against physics it must obey: the paper's law, Boyle's law, mass balance, the force
//! premise, rate independence, and integration accuracy against a much finer reference.

use super::ramp;
use host_sim::law::Design;
use host_sim::plant::{
    Drive, ForcePush, Hysteresis, Plant, PlantConfig, Ripple, ATMOSPHERE_KPA, CHAMBERS,
};

fn quiet() -> PlantConfig {
    let mut c = PlantConfig::default();
    c.sensor.noise_kpa = 0.0;
    c
}

#[test]
fn without_effects_pressure_follows_the_paper_law_at_the_syringe_volume() {
    let cfg = quiet();
    let law = Design::Sba1.law();
    for rate in [20.0, 60.0, 100.0] {
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        // 0 → 400 mm³ at constant rate, then look half a step later.
        let t_end = ramp(&mut p, 0, 10_000, rate, true);
        p.advance_to(t_end + (0.5 * 0.04 / rate * 1e6) as u64);
        let tr = p.truth(0);
        // The delivery lag (critically damped, τ_d = 3 ms) trails a ramp by 2·τ_d·rate, and
        // smooths the step train to a flow within 3 % of the rate (the residual step ripple).
        let lag = 2.0 * cfg.delivery_time_constant_s * rate;
        assert!(
            (tr.motor_mm3 - tr.delivered_mm3 - lag).abs() < 0.04,
            "lag {}",
            tr.motor_mm3 - tr.delivered_mm3
        );
        assert!(
            (tr.flow_mm3_s - rate).abs() < 0.03 * rate,
            "flow {}",
            tr.flow_mm3_s
        );
        // P is the paper's law at the delivered volume and flow, and within 0.3 kPa of the law at
        // the motor's volume and the nominal rate (what a model driven by step counts sees).
        let exact = law.eval(tr.delivered_mm3, tr.flow_mm3_s).p;
        assert!((tr.pressure_kpa - exact).abs() < 1e-9);
        let nominal = law.eval(tr.motor_mm3, rate).p;
        assert!(
            (tr.pressure_kpa - nominal).abs() < 0.3,
            "rate {rate}: {} vs {nominal}",
            tr.pressure_kpa
        );
        assert_eq!(tr.chamber_mm3, tr.delivered_mm3);
    }
}

#[test]
fn at_rest_the_law_is_elastic_only() {
    let cfg = quiet();
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 7_500, 100.0, true); // 300 mm³
    p.advance_to(t + 2_000_000);
    let tr = p.truth(1);
    assert!((tr.chamber_mm3 - 300.0).abs() < 1e-9);
    let k = Design::Sba1.law().k(300.0);
    assert!(
        (tr.pressure_kpa - k).abs() < 1e-6,
        "{} vs {k}",
        tr.pressure_kpa
    );
    assert!(tr.flow_mm3_s.abs() < 1e-6);
}

/// Boyle: the bubble's volume at rest is V₀·P_atm/(P_atm + P), and the chamber holds what the
/// syringe displaced minus the bubble's (and the tubing's) compression.
#[test]
fn air_pocket_obeys_boyle_and_mass_balance() {
    for v0 in [0.1, 5.0, 50.0] {
        let mut cfg = quiet();
        cfg.effects.air_pocket_mm3 = [v0; CHAMBERS];
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        let t = ramp(&mut p, 0, 10_000, 50.0, true); // 400 mm³
        p.advance_to(t + 5_000_000);
        let tr = p.truth(0);
        let air = v0 * ATMOSPHERE_KPA / (ATMOSPHERE_KPA + tr.pressure_kpa);
        assert!((tr.air_mm3 - air).abs() < 1e-12);
        assert!(
            (tr.delivered_mm3 - (v0 - air) - tr.chamber_mm3).abs() < 1e-9,
            "v0 {v0}"
        );
        // At rest the pressure is K at the *chamber* volume, below K at the syringe volume.
        let law = Design::Sba1.law();
        assert!((tr.pressure_kpa - law.k(tr.chamber_mm3)).abs() < 1e-6);
        assert!(tr.chamber_mm3 < tr.syringe_mm3 - 0.9 * (v0 - air));
    }
}

/// Backward Euler on the 1 ms grid against a 5 µs reference: the pressure at 25 Hz sample
/// instants agrees within 0.1 kPa for bubbles from stiff (0.01 mm³, τ ≈ 2 µs) to soft (50 mm³).
#[test]
fn integration_is_accurate_and_stable_for_stiff_and_soft_air_pockets() {
    for v0 in [0.0, 0.01, 1.0, 50.0] {
        let mut coarse_cfg = quiet();
        coarse_cfg.effects.air_pocket_mm3 = [v0; CHAMBERS];
        let mut fine_cfg = coarse_cfg.clone();
        fine_cfg.max_substep_s = 5e-6;
        let mut a = Plant::new(&coarse_cfg, &[], 1).unwrap();
        let mut b = Plant::new(&fine_cfg, &[], 1).unwrap();
        // Inflate 1 s at 100 mm³/s then deflate, sampling at 25 Hz throughout.
        let period = 0.04 / 100.0 * 1e6;
        let mut worst: f64 = 0.0;
        let mut next_sample = 40_000u64;
        for k in 1..=5000u32 {
            let inflate = k <= 2500;
            let t = (k as f64 * period).round() as u64;
            while next_sample < t {
                a.advance_to(next_sample);
                b.advance_to(next_sample);
                let (pa, pb) = (a.truth(0).pressure_kpa, b.truth(0).pressure_kpa);
                assert!(pa.is_finite() && pa.abs() < 200.0, "v0 {v0}: unstable {pa}");
                worst = worst.max((pa - pb).abs());
                next_sample += 40_000;
            }
            a.step(0, t, inflate);
            b.step(0, t, inflate);
        }
        assert!(worst < 0.1, "air {v0} mm³: coarse vs reference {worst} kPa");
    }
}

/// A tiny bubble behaves like no bubble (the stiff limit is reached smoothly, no blow-up).
#[test]
fn vanishing_air_pocket_converges_to_no_air() {
    let mut with = quiet();
    with.effects.air_pocket_mm3 = [1e-4; CHAMBERS];
    let mut a = Plant::new(&with, &[], 1).unwrap();
    let mut b = Plant::new(&quiet(), &[], 1).unwrap();
    let t = ramp(&mut a, 0, 5_000, 100.0, true);
    ramp(&mut b, 0, 5_000, 100.0, true);
    a.advance_to(t);
    b.advance_to(t);
    assert!((a.truth(0).pressure_kpa - b.truth(0).pressure_kpa).abs() < 1e-3);
}

#[test]
fn force_shares_sum_to_one_and_follow_direction() {
    for (az, tilt) in [
        (0.0, 0.0),
        (0.0, 90.0),
        (33.0, 60.0),
        (200.0, 45.0),
        (-75.0, 90.0),
    ] {
        let push = ForcePush {
            start_s: 0.0,
            duration_s: 1.0,
            frequency_hz: 1.0,
            peak_n: 1.0,
            azimuth_deg: az,
            tilt_deg: tilt,
        };
        let w = push.shares();
        assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(w.iter().all(|&x| x >= 0.0));
    }
    let side = ForcePush {
        start_s: 0.0,
        duration_s: 1.0,
        frequency_hz: 1.0,
        peak_n: 1.0,
        azimuth_deg: 0.0,
        tilt_deg: 90.0,
    };
    // Straight at chamber 0 from the side: only chamber 0 is loaded.
    let w = side.shares();
    assert!((w[0] - 1.0).abs() < 1e-12 && w[1] == 0.0 && w[2] == 0.0);
}

/// The premise of the paper's estimator, true in the plant: Σ ΔP_i·A_i = F (within the small
/// volume the extra pressure pushes back into the compliant line; none without a bubble).
#[test]
fn a_push_raises_pressures_by_force_over_area() {
    let cfg = quiet();
    let push = ForcePush {
        start_s: 3.0,
        duration_s: 1.0,
        frequency_hz: 1.0,
        peak_n: 0.2,
        azimuth_deg: 30.0,
        tilt_deg: 50.0,
    };
    let mut with = Plant::new(&cfg, std::slice::from_ref(&push), 1).unwrap();
    let mut without = Plant::new(&cfg, &[], 1).unwrap();
    ramp(&mut with, 0, 5_000, 100.0, true);
    ramp(&mut without, 0, 5_000, 100.0, true);
    let t = 3_500_000; // peak of the pulse
    with.advance_to(t);
    without.advance_to(t);
    assert!((with.force_n(t) - 0.2).abs() < 1e-12);
    let sum: f64 = (0..CHAMBERS)
        .map(|i| (with.truth(i).pressure_kpa - without.truth(i).pressure_kpa) * 22.0e-3)
        .sum();
    assert!((sum - 0.2).abs() < 1e-9, "Σ ΔP·A = {sum} N");
}

#[test]
fn leak_loses_volume_at_the_laminar_rate() {
    let mut cfg = quiet();
    cfg.effects.leak_mm3_per_s_per_kpa = 0.01;
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 10_000, 100.0, true);
    p.advance_to(t + 100_000);
    let a = p.truth(0);
    p.advance_to(t + 1_100_000);
    let b = p.truth(0);
    // Over 1 s: ΔV ≈ −G·P̄ (P barely changes over a second at this conductance).
    let expect = -0.01 * 0.5 * (a.pressure_kpa + b.pressure_kpa);
    let got = b.chamber_mm3 - a.chamber_mm3;
    assert!(
        (b.leaked_mm3 - a.leaked_mm3 + got).abs() < 1e-9,
        "mass balance"
    );
    assert!(
        (got - expect).abs() < 0.02 * expect.abs(),
        "{got} vs {expect}"
    );
    assert!(b.pressure_kpa < a.pressure_kpa);
}

/// Rate independence: the hysteresis term adds the same pressure after the same volume path,
/// whatever the speed.
#[test]
fn hysteresis_is_rate_independent() {
    let mut cfg = quiet();
    cfg.effects.hysteresis = Some(Hysteresis {
        amplitude_kpa: 1.5,
        transition_mm3: 20.0,
    });
    let law = Design::Sba1.law();
    let mut excess = Vec::new();
    for rate in [20.0, 100.0] {
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        let t = ramp(&mut p, 0, 7_500, rate, true);
        let t = ramp(&mut p, t, 1_250, rate, false); // back 50 mm³
        p.advance_to(t + 3_000_000);
        let tr = p.truth(0);
        excess.push(tr.pressure_kpa - law.k(tr.chamber_mm3));
    }
    // 50 mm³ after reversal: −1.5 + 3.0·e^(−50/20) ≈ −1.254 kPa, at both rates.
    let expect = -1.5 + 3.0 * (-50.0f64 / 20.0).exp();
    for e in &excess {
        assert!((e - expect).abs() < 0.02, "{e} vs {expect}");
    }
}

#[test]
fn backlash_delays_the_plunger_after_a_reversal() {
    let mut cfg = quiet();
    cfg.effects.backlash_mm3 = 0.4; // ten steps
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 100, 100.0, true);
    let before = p.truth(0).syringe_mm3;
    let t = ramp(&mut p, t, 10, 100.0, false);
    assert_eq!(
        p.truth(0).syringe_mm3,
        before,
        "the screw takes up the play first"
    );
    ramp(&mut p, t, 5, 100.0, false);
    assert!((p.truth(0).syringe_mm3 - (before - 0.2)).abs() < 1e-9);
}

#[test]
fn ripple_moves_the_syringe_volume_periodically() {
    let mut cfg = quiet();
    cfg.effects.ripple = Some(Ripple {
        amplitude_mm3: 0.3,
        period_mm3: 8.0,
    });
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    ramp(&mut p, 0, 50, 100.0, true); // 2 mm: a quarter turn
    let tr = p.truth(0);
    assert!((tr.syringe_mm3 - (2.0 + 0.3)).abs() < 1e-9);
}

#[test]
fn sensor_lag_and_drift_affect_only_the_reading() {
    let mut cfg = quiet();
    cfg.effects.sensor_lag_s = 0.05;
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 12_500, 100.0, true);
    p.advance_to(t);
    let tr = p.truth(0);
    // Ramp through a first-order lag: the reading trails by about τ·dP/dt.
    assert!(tr.sensed_kpa < tr.pressure_kpa - 0.5);
    p.advance_to(t + 1_000_000);
    let tr = p.truth(0);
    assert!((tr.sensed_kpa - tr.pressure_kpa).abs() < 1e-6);
}

#[test]
fn same_seed_same_readings_other_seed_other_noise() {
    let cfg = PlantConfig::default();
    let read = |seed| {
        let mut p = Plant::new(&cfg, &[], seed).unwrap();
        (1..200)
            .map(|k| p.adc_counts(k * 40_000))
            .collect::<Vec<_>>()
    };
    assert_eq!(read(7), read(7));
    assert_ne!(read(7), read(8));
}

#[test]
fn adc_reads_through_the_firmware_transfer_function() {
    let mut cfg = quiet();
    cfg.sensor.offset_kpa = [0.0; CHAMBERS];
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 10_000, 100.0, true);
    p.advance_to(t + 2_000_000);
    let kpa = p.truth(0).pressure_kpa;
    let counts = p.adc_counts(t + 2_000_000)[0];
    let back = firmware::board::counts_to_kpa(counts as f32) as f64;
    // Within half a count (0.016 kPa) of the true pressure.
    assert!((back - kpa).abs() < 0.017, "{back} vs {kpa}");
    p.set_unplugged(0, true);
    assert_eq!(p.adc_counts(t + 2_040_000)[0], 0);
}

#[test]
fn bad_parameters_are_refused_with_their_name() {
    let mut cfg = PlantConfig::default();
    cfg.effects.air_pocket_mm3[1] = -1.0;
    let e = Plant::new(&cfg, &[], 1).unwrap_err();
    assert_eq!(e.name, "effects.air_pocket_mm3");
    let cfg = PlantConfig {
        delivery_time_constant_s: 0.0,
        ..PlantConfig::default()
    };
    assert_eq!(
        Plant::new(&cfg, &[], 1).unwrap_err().name,
        "delivery_time_constant_s"
    );
    let mut cfg = PlantConfig::default();
    cfg.sensor.noise_kpa = f64::NAN;
    assert_eq!(
        Plant::new(&cfg, &[], 1).unwrap_err().name,
        "sensor.noise_kpa"
    );
}

/// The lagged servo ([`Drive::LaggedServo`]) against the closed form of a critically damped
/// lag: a ramp at rate q is trailed by 2·τ_d·q once the start has died out, and the delivered
/// flow is the rate itself, with none of the step train's pulses (which the same τ_d on the
/// stepped drive leaves as pulses of flow).
#[test]
fn the_lagged_servo_trails_a_ramp_by_two_time_constants_without_pulses() {
    // 500 steps/s at this rate, 2 ms between steps. Overdamped (poles 1.6τ_d and 0.4τ_d) the
    // trail is (1.6 + 0.4)·τ_d·q as well.
    let rate = 20.0;
    for (tau, overdamped) in [(0.0005, false), (0.003, false), (0.003, true)] {
        let mut cfg = quiet();
        cfg.drive = Drive::LaggedServo;
        cfg.delivery_time_constant_s = tau;
        cfg.effects.forms.delivery_overdamped = overdamped;
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        let q_us = 1_000;
        let mut flows = Vec::new();
        for k in 0..1_000u64 {
            let t0 = k * q_us;
            p.command_flow(0, t0, t0 + q_us, rate, rate);
            // Four looks inside each quantum.
            for j in 1..=4 {
                p.advance_to(t0 + j * q_us / 4);
                if k >= 100 {
                    flows.push(p.truth(0).flow_mm3_s);
                }
            }
        }
        let tr = p.truth(0);
        let commanded = rate * 1.0; // 1 s at the rate
        assert!(
            (commanded - tr.delivered_mm3 - 2.0 * tau * rate).abs() < 1e-6,
            "τ {tau}: trails by {}",
            commanded - tr.delivered_mm3
        );
        let worst = flows.iter().map(|f| (f - rate).abs()).fold(0.0, f64::max);
        assert!(worst < 1e-6 * rate, "τ {tau}: flow off the rate by {worst}");
    }
    // The same τ_d of 0.5 ms on the step train: each step a pulse of flow.
    let mut cfg = quiet();
    cfg.delivery_time_constant_s = 0.0005;
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 500, rate, true);
    // Between the last step and the next one 2 ms later.
    let (mut lo, mut hi) = (f64::INFINITY, 0.0_f64);
    for j in 1..40 {
        p.advance_to(t + j * 50);
        let f = p.truth(0).flow_mm3_s;
        (lo, hi) = (lo.min(f), hi.max(f));
    }
    assert!(
        hi > 1.5 * rate && lo < 0.5 * rate,
        "step-train flow between {lo} and {hi}"
    );
}
