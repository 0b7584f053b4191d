//! The effects' other forms ([`host_sim::plant::Forms`]) against hand-computed values: each
//! obeys its own law, and differs from the usual form where the two laws differ.

use super::ramp;
use host_sim::plant::{
    Forms, Hysteresis, Plant, PlantConfig, Ripple, ThermalDrift, ATMOSPHERE_KPA, CHAMBERS,
};

fn quiet(forms: Forms) -> PlantConfig {
    let mut c = PlantConfig::default();
    c.sensor.noise_kpa = 0.0;
    c.sensor.offset_kpa = [0.0; CHAMBERS];
    c.effects.forms = forms;
    c
}

/// A polytropic pocket (n = 1.4) keeps `(P_atm + P)·V^n` constant, and the water balance holds.
#[test]
fn a_polytropic_air_pocket_keeps_p_v_to_the_n() {
    let mut cfg = quiet(Forms {
        air_polytropic_index: 1.4,
        ..Forms::default()
    });
    cfg.effects.air_pocket_mm3 = [30.0; CHAMBERS];
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 10_000, 50.0, true);
    p.advance_to(t + 5_000_000);
    let tr = p.truth(0);
    assert!(tr.pressure_kpa > 5.0, "{}", tr.pressure_kpa);
    let pv = |p: f64, v: f64| (ATMOSPHERE_KPA + p) * v.powf(1.4);
    let ratio = pv(tr.pressure_kpa, tr.air_mm3) / pv(0.0, 30.0);
    assert!((ratio - 1.0).abs() < 1e-9, "{ratio}");
    assert!((tr.delivered_mm3 - (30.0 - tr.air_mm3) - tr.chamber_mm3).abs() < 1e-9);
    // Boyle's pocket at the same pressure would be smaller: the adiabatic gas is stiffer.
    let boyle = 30.0 * ATMOSPHERE_KPA / (ATMOSPHERE_KPA + tr.pressure_kpa);
    assert!(tr.air_mm3 > boyle + 0.1, "{} vs {boyle}", tr.air_mm3);
}

/// The linear hysteresis ramps at H_a/v_h per mm³ after a reversal and saturates at −H_a, at
/// any rate: 1.5 kPa, v_h 20 mm³ → 0 kPa 20 mm³ after the reversal, −1.5 kPa from 40 mm³ on
/// (the exponential form: 1.5 − 3·(1 − e⁻¹) = −0.40 kPa at 20 mm³).
#[test]
fn linear_hysteresis_ramps_and_saturates_whatever_the_rate() {
    let mut cfg = quiet(Forms {
        hysteresis_linear: true,
        ..Forms::default()
    });
    cfg.effects.hysteresis = Some(Hysteresis {
        amplitude_kpa: 1.5,
        transition_mm3: 20.0,
    });
    let law = host_sim::law::Design::Sba1.law();
    for rate in [20.0, 100.0] {
        for (back_steps, expect) in [(500, 0.0), (1_250, -1.5)] {
            let mut p = Plant::new(&cfg, &[], 1).unwrap();
            let t = ramp(&mut p, 0, 7_500, rate, true);
            let t = ramp(&mut p, t, back_steps, rate, false);
            p.advance_to(t + 3_000_000);
            let tr = p.truth(0);
            let excess = tr.pressure_kpa - law.k(tr.chamber_mm3);
            // The delivery lag rounds the reversal: the delivered volume turns about 2τ_d·rate
            // below the plunger's peak (0.6 mm³ at 100 mm³/s), H_a/v_h per mm³ of it.
            let rounding = 1.5 / 20.0 * 2.0 * cfg.delivery_time_constant_s * rate;
            assert!(
                (excess - expect).abs() < rounding + 0.005,
                "rate {rate}, {back_steps} steps back: {excess} vs {expect}"
            );
        }
    }
}

/// Two stages of τ/2 trail a ramp by τ·dP/dt as one stage of τ does (the same mean delay), but
/// respond to it later at its start (a second-order response is flat at first).
#[test]
fn a_second_order_sensor_lag_has_the_first_orders_delay_and_another_shape() {
    let sensed = |second_order: bool, steps: u32| {
        let mut cfg = quiet(Forms {
            sensor_lag_second_order: second_order,
            ..Forms::default()
        });
        cfg.effects.sensor_lag_s = 0.05;
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        let t = ramp(&mut p, 0, 12_500, 100.0, true);
        let t = ramp(&mut p, t, steps, 100.0, true);
        p.advance_to(t);
        let tr = p.truth(0);
        tr.pressure_kpa - tr.sensed_kpa
    };
    // Steady trail deep into a long ramp: within 3 % of each other.
    let (one, two) = (sensed(false, 5_000), sensed(true, 5_000));
    assert!(
        one > 0.1 && (two - one).abs() < 0.03 * one,
        "{one} vs {two}"
    );
    // 10 ms after the trail starts to build (a ramp from rest, 25 steps), the two-stage sensor
    // has followed more closely.
    let start = |second_order: bool| {
        let mut cfg = quiet(Forms {
            sensor_lag_second_order: second_order,
            ..Forms::default()
        });
        cfg.effects.sensor_lag_s = 0.05;
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        let t = ramp(&mut p, 0, 2_000, 100.0, true);
        p.advance_to(t + 2_000_000);
        let base = p.truth(0).sensed_kpa;
        let t = ramp(&mut p, t + 2_000_000, 25, 100.0, true);
        p.advance_to(t);
        p.truth(0).sensed_kpa - base
    };
    assert!(
        start(true) < 0.8 * start(false),
        "{} vs {}",
        start(true),
        start(false)
    );
}

/// The pitch error with a second harmonic k: at a quarter turn (2 mm³ of an 8 mm³ period)
/// `A·sin(π/2) + k·A·sin(π + 0.7)`.
#[test]
fn ripple_with_a_second_harmonic() {
    let mut cfg = quiet(Forms {
        ripple_second_harmonic: 0.5,
        ..Forms::default()
    });
    cfg.effects.ripple = Some(Ripple {
        amplitude_mm3: 0.3,
        period_mm3: 8.0,
    });
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    ramp(&mut p, 0, 50, 100.0, true);
    let expect = 2.0 + 0.3 + 0.5 * 0.3 * (std::f64::consts::PI + 0.7).sin();
    assert!((p.truth(0).syringe_mm3 - expect).abs() < 1e-9);
}

/// The orifice leak loses `G·P/√(1 + P/P_t)` a second: at P ≫ P_t far less than the laminar
/// `G·P`.
#[test]
fn an_orifice_leak_loses_volume_at_its_own_rate() {
    let mut cfg = quiet(Forms {
        leak_orifice_kpa: 2.0,
        ..Forms::default()
    });
    cfg.effects.leak_mm3_per_s_per_kpa = 0.01;
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 10_000, 100.0, true);
    p.advance_to(t + 100_000);
    let a = p.truth(0);
    p.advance_to(t + 1_100_000);
    let b = p.truth(0);
    let q = |p: f64| p / (1.0 + p / 2.0).sqrt();
    let expect = -0.01 * 0.5 * (q(a.pressure_kpa) + q(b.pressure_kpa));
    let got = b.chamber_mm3 - a.chamber_mm3;
    assert!(
        (b.leaked_mm3 - a.leaked_mm3 + got).abs() < 1e-9,
        "mass balance"
    );
    assert!(
        (got - expect).abs() < 0.02 * expect.abs(),
        "{got} vs {expect}"
    );
    assert!(
        got.abs() < 0.7 * 0.01 * a.pressure_kpa,
        "below the laminar rate"
    );
}

/// The ramp drift reads D/2 at τ_D (the exponential: D·(1 − e⁻¹)) and D from 2τ_D on.
#[test]
fn the_ramp_drift_reaches_its_change_at_twice_its_time_constant() {
    let reading = |ramp_form: bool, t_us: u64| {
        let mut cfg = quiet(Forms {
            drift_ramp: ramp_form,
            ..Forms::default()
        });
        cfg.effects.thermal_drift = Some(ThermalDrift {
            offset_change_kpa: 3.2,
            time_constant_s: 10.0,
        });
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        let counts = p.adc_counts(t_us)[0];
        firmware::board::counts_to_kpa(counts as f32) as f64
    };
    let count = 0.033;
    assert!((reading(true, 10_000_000) - 1.6).abs() < count);
    assert!((reading(false, 10_000_000) - 3.2 * (1.0 - (-1.0f64).exp())).abs() < count);
    assert!((reading(true, 30_000_000) - 3.2).abs() < count);
}

/// A creep with time constant τ_c has taken `r·τ_c·(1 − e^(−t/τ_c))` by t, at rest and with no
/// pressure to speak of.
#[test]
fn a_slowing_creep_takes_its_volume() {
    let mut cfg = quiet(Forms {
        creep_time_constant_s: 20.0,
        ..Forms::default()
    });
    cfg.effects.volume_creep_mm3_per_s = 0.5;
    let mut p = Plant::new(&cfg, &[], 1).unwrap();
    let t = ramp(&mut p, 0, 10_000, 100.0, true);
    let end = t + 30_000_000;
    p.advance_to(end);
    let tr = p.truth(0);
    let t_s = end as f64 * 1e-6;
    let expect = 0.5 * 20.0 * (1.0 - (-t_s / 20.0).exp());
    assert!(
        (tr.delivered_mm3 - tr.chamber_mm3 - expect).abs() < 1e-9,
        "{} vs {expect}",
        tr.delivered_mm3 - tr.chamber_mm3
    );
}

/// The overdamped delivery lag (poles τ₁ = 1.6τ_d, τ₂ = 0.4τ_d): after one step at rest,
/// `w − u = −0.04·(4/3·e^(−t/τ₁) − 1/3·e^(−t/τ₂))` (critically damped:
/// `−0.04·(1 + t/τ_d)·e^(−t/τ_d)`).
#[test]
fn an_overdamped_delivery_lag_follows_a_step_with_its_two_poles() {
    let delivered = |overdamped: bool| {
        let cfg = quiet(Forms {
            delivery_overdamped: overdamped,
            ..Forms::default()
        });
        let tau_us = (cfg.delivery_time_constant_s * 1e6).round() as u64;
        let mut p = Plant::new(&cfg, &[], 1).unwrap();
        p.step(0, 1_000, true);
        p.advance_to(1_000 + tau_us);
        let tr = p.truth(0);
        tr.delivered_mm3 - tr.syringe_mm3
    };
    let e1 = (-1.0f64).exp();
    let two_poles = 4.0 / 3.0 * (-1.0f64 / 1.6).exp() - 1.0 / 3.0 * (-2.5f64).exp();
    assert!(
        (delivered(true) + 0.04 * two_poles).abs() < 1e-9,
        "{}",
        delivered(true)
    );
    assert!(
        (delivered(false) + 0.04 * 2.0 * e1).abs() < 1e-9,
        "{}",
        delivered(false)
    );
}
