//! Acceptance of the residual loop on logs of the simulated rig (host-sim: the firmware's own tasks
//! driving a plant with known physics), each effect injected and *not declared* to the tool.
//!
//! The rig runs the paper's protocol (0–550 mm³ at 20…100 mm³/s, two cycles per rate: 6,500
//! frames, one cycle in five held out) with the **ideal drive** (`host_sim::plant::Drive::Ideal`,
//! a servo that follows the firmware's commanded profile), so the only deviations from the paper's
//! law are the sensor's and the injected effect's. Effects at their preset sizes
//! (`host_sim::Effects::preset`).
//!
//! The noise σ is taken from truth: the standard deviation, over the held-out frames, of the logged
//! pressure minus what the sensor element saw (`FrameTruth::sensed_kpa`: the true pressure after any
//! sensor lag or delay) minus the known offset drift. (The sensor spec through the firmware's
//! eight-fold averaging gives the same: √(0.05² + 0.032²/12)/√8 = 0.0180 kPa.)
//!
//! Every effect is named (with its parameter against the injected truth) and every log ends
//! within 15 % of σ.

use crate::hostsim_common;

use host_sim::plant::Drive;
use host_sim::{simulate, Effects, PlantConfig, Protocol, Scenario, SimRun};
use hostsim_common::{names, run, Outcome};
use sysid::residual::Diagnosis;

fn scenario(name: &str, effects: Effects, drive: Drive, seed: u64) -> Scenario {
    let plant = PlantConfig {
        drive,
        effects,
        ..PlantConfig::default()
    };
    let protocol = Protocol {
        cycles: 2,
        ..Protocol::paper()
    };
    Scenario {
        seed,
        ..Scenario::protocol(name, plant, &protocol)
    }
}

fn preset(name: &str) -> Effects {
    Effects::preset(name).expect("known preset")
}

/// The first effect's parameter `param`.
fn first_param(d: &Diagnosis, param: &str) -> f64 {
    d.effects[0]
        .params
        .iter()
        .find(|p| p.name == param)
        .unwrap_or_else(|| panic!("{} has no {param}", d.effects[0].name))
        .value
}

/// Parameter `param` of the alternative `effect` listed under the first kept effect of `d`.
fn first_alternative_param(d: &Diagnosis, effect: &str, param: &str) -> f64 {
    let e = &d.effects[0];
    e.alternatives
        .iter()
        .find(|a| a.effect == effect)
        .unwrap_or_else(|| panic!("{effect} is not among {}'s alternatives", e.name))
        .params
        .iter()
        .find(|p| p.name == param)
        .unwrap_or_else(|| panic!("{effect} has no {param}"))
        .value
}

/// The injected effect is the first one named, and its parameter is within `rel` of the truth.
fn assert_named(o: &Outcome, expect: &str, param: &str, truth: f64, rel: f64) {
    let found = names(&o.d);
    assert_eq!(found.first().copied(), Some(expect), "named {found:?}");
    let got = first_param(&o.d, param);
    assert!(
        (got - truth).abs() <= rel * truth.abs(),
        "{expect}: {param} = {got}, injected {truth} (±{:.0} %)",
        100.0 * rel
    );
}

fn assert_within_15pct(o: &Outcome) {
    assert!(
        o.d.final_model.rmse_heldout <= 1.15 * o.sigma,
        "held-out RMSE after {:.5} kPa exceeds 1.15 σ = {:.5} kPa",
        o.d.final_model.rmse_heldout,
        1.15 * o.sigma
    );
}

fn ideal(name: &str, effects: Effects, seed: u64) -> Outcome {
    run(&scenario(name, effects, Drive::Ideal, seed))
}

/// What the acceptance rests on: with the ideal drive the chamber receives exactly the logged flow
/// and (to the step counter's quantisation) the logged volume; the default drive does not.
#[test]
fn ideal_drive_delivers_what_the_log_says() {
    let short = |drive| {
        let plant = PlantConfig {
            drive,
            ..PlantConfig::default()
        };
        let protocol = Protocol {
            cycles: 1,
            flows: vec![20.0, 100.0],
            ..Protocol::paper()
        };
        simulate(&Scenario::protocol("drive", plant, &protocol)).expect("runs")
    };
    let worst = |run: &SimRun| {
        run.frames
            .iter()
            .zip(&run.truth)
            .fold((0.0f64, 0.0f64), |(dv, df), (f, t)| {
                let (c, tc) = (&f.chambers[0], &t.chambers[0]);
                (
                    dv.max((c.v as f64 - tc.chamber_mm3).abs()),
                    df.max((c.vdot as f64 - tc.flow_mm3_s).abs()),
                )
            })
    };
    let (dv, df) = worst(&short(Drive::Ideal));
    // Flow: the same profile (the log carries it as f32). Volume: the count trails the
    // continuous motion by less than one step (0.04 mm³).
    assert!(df < 1e-3, "ideal drive: flow off by {df} mm³/s");
    assert!(dv < 0.04 + 1e-4, "ideal drive: volume off by {dv} mm³");
    let (_, df) = worst(&short(Drive::Lagged));
    // About 2τ_d·a = 6 ms × 500 mm³/s² = 3 mm³/s on the ramps.
    assert!(df > 1.0, "lagged drive: flow off by only {df} mm³/s");
}

#[test]
fn clean_ideal_log_gets_no_effect() {
    let o = ideal("clean", Effects::default(), 1);
    assert!(o.d.effects.is_empty(), "claimed {:?}", names(&o.d));
    assert_within_15pct(&o);
}

#[test]
fn inertance_is_named_and_explained() {
    let o = ideal("inertance", preset("inertance"), 2);
    // 3e-4 kPa·s²/mm³ adds only I·a = 0.15 kPa on the 0.2 s ramps: ±25 %.
    assert_named(&o, "inertance", "inertance", 3.0e-4, 0.25);
    assert_within_15pct(&o);
}

#[test]
fn thermal_drift_is_named_and_explained() {
    let o = ideal("thermal-drift", preset("thermal-drift"), 3);
    assert_eq!(names(&o.d).first().copied(), Some("offset_drift"));
    // D(1 − e^(−t/τ)) from the first frame to the last, ±20 %.
    let (a, b) = o.span;
    let change = 1.0 * ((-a / 300.0).exp() - (-b / 300.0).exp());
    let got = first_param(&o.d, "change_over_log");
    assert!((got - change).abs() < 0.2 * change, "{got} vs {change}");
    assert_within_15pct(&o);
}

#[test]
fn volume_creep_is_named_and_explained() {
    let o = ideal("volume-creep", preset("volume-creep"), 4);
    assert_named(&o, "volume_drift", "rate", 0.01, 0.1);
    assert_within_15pct(&o);
}

#[test]
fn leak_is_named_and_explained() {
    let o = ideal("leak", preset("leak"), 5);
    assert_named(&o, "leak", "conductance", 0.002, 0.15);
    assert_within_15pct(&o);
}

#[test]
fn two_effects_are_both_named() {
    let effects = Effects {
        inertance_kpa_s2_per_mm3: 3.0e-4,
        volume_creep_mm3_per_s: 0.01,
        ..Effects::default()
    };
    let o = ideal("inertance+creep", effects, 6);
    let found = names(&o.d);
    assert!(
        found.contains(&"inertance") && found.contains(&"volume_drift"),
        "found {found:?}"
    );
    assert_within_15pct(&o);
}

#[test]
fn air_pocket_is_named() {
    let o = ideal("air", preset("air"), 7);
    assert_named(
        &o,
        "air_compliance",
        "air_volume_at_atmospheric_pressure",
        20.0,
        0.15,
    );
}

#[test]
fn hysteresis_is_named_and_explained() {
    let o = ideal("hysteresis", preset("hysteresis"), 8);
    // Gap inflation − deflation 2·H_a = 2 kPa, switching over v_h = 20 mm³.
    assert_named(&o, "hysteresis", "gap_at_mid_volume", 2.0, 0.15);
    let w = first_param(&o.d, "width");
    assert!((w - 20.0).abs() < 0.25 * 20.0, "width {w} mm³, injected 20");
    assert_within_15pct(&o);
}

#[test]
fn sensor_lag_is_named() {
    let o = ideal("sensor-lag", preset("sensor-lag"), 9);
    assert_named(&o, "sensor_lag", "time_constant", 0.02, 0.15);
}

#[test]
fn transport_delay_is_named() {
    let o = ideal("transport-delay", preset("transport-delay"), 10);
    assert_named(&o, "transport_delay", "delay", 0.01, 0.15);
}

#[test]
fn backlash_is_named() {
    let o = ideal("backlash", preset("backlash"), 11);
    assert_named(&o, "backlash", "play", 0.4, 0.3);
}

#[test]
fn air_pocket_within_15pct() {
    assert_within_15pct(&ideal("air", preset("air"), 7));
}

#[test]
fn sensor_lag_within_15pct() {
    assert_within_15pct(&ideal("sensor-lag", preset("sensor-lag"), 9));
}

#[test]
fn transport_delay_within_15pct() {
    assert_within_15pct(&ideal("transport-delay", preset("transport-delay"), 10));
}

#[test]
fn backlash_within_15pct() {
    assert_within_15pct(&ideal("backlash", preset("backlash"), 11));
}

#[test]
fn ripple_is_named() {
    // host-sim's ripple is the lead screw's pitch error, periodic in plunger position (8 mm³ per
    // turn, 0.2 mm³: 2.5–12.5 Hz at 20–100 mm³/s, so not one frequency in time).
    let o = ideal("ripple", preset("ripple"), 12);
    assert_named(&o, "pump_ripple", "period", 8.0, 0.01);
    let amp = first_param(&o.d, "amplitude");
    assert!(
        (amp - 0.2).abs() <= 0.05 * 0.2,
        "amplitude {amp} mm³ of 0.2"
    );
    // How far the logged count trails the plunger at each cruise speed, against the simulator's
    // truth on the same protocol without ripple (the same firmware timing): within a tenth of a
    // step. At
    // 100 mm³/s the ripple carries the instantaneous flow to 116 mm³/s, past the 100 mm³/s the
    // paper identified its law for, where the simulated law continues linearly (host_sim::law)
    // and the (3, 2) polynomial cannot follow; the lag fitted there absorbs part of that and is
    // not compared.
    for (speed, truth) in count_lags_from_truth() {
        if speed > 99.0 {
            continue;
        }
        let name = format!("count_lag_at_{speed:.3}_mm3_s");
        let got = first_param(&o.d, &name);
        assert!(
            (got - truth).abs() < 0.004,
            "{name}: {got} mm³, truth {truth} mm³"
        );
    }
}

/// The logged volume's lag behind the continuous plunger, mean over the cruise frames of each
/// protocol speed, from the truth of an ideal-drive run without effects: (speed, lag) in
/// mm³/s and mm³.
fn count_lags_from_truth() -> Vec<(f64, f64)> {
    // The same protocol as the ripple's run: the sub-step phase a speed locks to depends on when
    // its moves start (a one-cycle run locks 80 mm³/s at half the lag).
    let protocol = Protocol {
        cycles: 2,
        ..Protocol::paper()
    };
    let plant = PlantConfig {
        drive: Drive::Ideal,
        ..PlantConfig::default()
    };
    let run = simulate(&Scenario::protocol("lags", plant, &protocol)).expect("runs");
    protocol
        .flows
        .iter()
        .map(|&speed| {
            let lags: Vec<f64> = run
                .frames
                .iter()
                .zip(&run.truth)
                .filter(|(f, _)| (f64::from(f.chambers[0].vdot).abs() - speed).abs() < 1e-3)
                .map(|(f, t)| {
                    let c = &f.chambers[0];
                    (t.chambers[0].syringe_mm3 - f64::from(c.v)) * f64::from(c.vdot).signum()
                })
                .collect();
            assert!(
                lags.len() > 50,
                "{speed} mm³/s: {} cruise frames",
                lags.len()
            );
            (speed, lags.iter().sum::<f64>() / lags.len() as f64)
        })
        .collect()
}

#[test]
fn ripple_within_15pct() {
    assert_within_15pct(&ideal("ripple", preset("ripple"), 12));
}

/// The default rig's drive (critically damped delivery lag τ_d = 3 ms, about 2τ_d = 6 ms late):
/// the loop names the lag with its delay, claims nothing unphysical, and reports what the 25 Hz
/// frames cannot resolve (the ramp corners) as remaining structure.
#[test]
fn default_drive_lag_is_named_and_nothing_unphysical() {
    let sc = scenario("lagged", Effects::default(), Drive::Lagged, 13);
    let tau_d = sc.plant.delivery_time_constant_s;
    let o = run(&sc);
    let first = o.d.effects.first().expect("an effect is named");
    let delay = match first.name {
        "delivery_lag" => first_param(&o.d, "effective_delay"),
        "transport_delay" => first_param(&o.d, "delay"),
        other => panic!("named {other}, not the drive's lag"),
    };
    assert!(
        (delay - 2.0 * tau_d).abs() <= 0.15 * 2.0 * tau_d,
        "delay {delay} s vs 2τ_d = {} s (±15 %)",
        2.0 * tau_d
    );
    for e in &o.d.effects {
        for p in &e.params {
            let must_be_positive = matches!(
                (e.name, p.name.as_str()),
                ("inertance", "inertance") | ("hysteresis", "gap_at_mid_volume")
            );
            assert!(
                !must_be_positive || p.value >= 0.0,
                "{} claimed with {} = {}",
                e.name,
                p.name,
                p.value
            );
        }
    }
    assert!(
        !o.d.remaining.is_empty(),
        "the corners a 25 Hz log cannot resolve should be reported as remaining structure"
    );
}

/// A fast overdamped drive lag, the loop benchmark's rig 14 of seed 1 (SBA1, moves with dwells;
/// host-sim's other form, poles at 1.6τ_d and 0.4τ_d, the same mean delay 2τ_d as the critically
/// damped lag) at τ_d = 1.47 ms, below the delivery lag's search bracket (2 ms): the frames see
/// the mean delay, and the loop names a lag that holds it within 15 % (a sensor lag's τ, a
/// delivery lag's 2τ or a transport delay; issue 34: in frames they differ only at order
/// (τ/frame)²). With the lag on the step train the rig drew before 2026-11-28, 5 σ was left,
/// the motor's step train (module docs of `delivery_lag`); on the servo's motion, 1.03 σ.
#[test]
fn a_fast_overdamped_drive_lag_is_found_by_its_mean_delay() {
    use host_sim::rigs::{draw, FormChoice, PlantedKind, RigOptions};
    let opts = RigOptions {
        forms: FormChoice::Other,
        ..RigOptions::default()
    };
    let spec = draw(1, 14, &opts).expect("rig 14 draws");
    let [planted] = &spec.planted[..] else {
        panic!("rig 14 plants one effect: {}", spec.label());
    };
    assert_eq!(planted.kind, PlantedKind::DeliveryLag);
    assert!(
        planted.other_form && planted.size < 0.002,
        "{}",
        spec.label()
    );
    let o = run(&spec.scenario());
    let first = o.d.effects.first().expect("an effect is named");
    let delay = match first.name {
        "delivery_lag" => first_param(&o.d, "effective_delay"),
        "sensor_lag" => first_param(&o.d, "time_constant"),
        "transport_delay" => first_param(&o.d, "delay"),
        other => panic!("named {other}, not a lag"),
    };
    let mean = 2.0 * planted.size;
    assert!(
        (delay - mean).abs() <= 0.15 * mean,
        "{}: delay {delay} s vs 2τ_d = {mean} s (±15 %)",
        first.name
    );
}

/// A leak that closes under suction: host-sim's leak flows out at positive pressure only
/// (`G·max(P, 0)`), and the loop benchmark's rig 24 of seed 1 (SBA2, the protocol, 7,780 frames)
/// goes to −15 kPa in its fast deflations. Fitted as an open path (`λ P` at either sign) the leak
/// left 1.17 σ and an offset drift was named beside it to take up the rest, the water lost 5 %
/// low; the leak's one-way form (`Effect::one_way`, chosen by its fit) names the leak alone, in
/// that form, within 1.05 σ and the water lost within 2 % of the plant's.
#[test]
fn a_leak_that_closes_under_suction_is_fitted_one_way() {
    use host_sim::rigs::PlantedKind;
    let (_, sim, ds) = hostsim_common::one_effect_rig(1, 24, PlantedKind::Leak);
    let sigma = hostsim_common::sigma_from_truth(&sim, &ds);
    // The premise: the chamber goes well below the atmosphere.
    let lowest = ds.p.iter().copied().fold(f64::INFINITY, f64::min);
    assert!(lowest < -5.0, "lowest pressure {lowest} kPa");
    let skip = ds.not_zeroed;
    let leaked = |k: usize| sim.truth[k + skip].chambers[0].leaked_mm3;
    let lost = leaked(ds.t.len() - 1) - leaked(0);
    let series = sysid::residual::series_from_dataset(&ds).expect("series");
    let d =
        sysid::residual::diagnose(series, &sysid::residual::Config::default()).expect("diagnosis");
    assert_eq!(names(&d), ["leak"]);
    assert_eq!(first_param(&d, "one_way"), 1.0);
    let named = first_param(&d, "volume_lost_over_log");
    assert!(
        (named - lost).abs() <= 0.02 * lost,
        "lost {named} mm³ against the plant's {lost} mm³"
    );
    let ratio = d.final_model.rmse_heldout / sigma;
    assert!(ratio <= 1.05, "{ratio:.3} σ");
}

/// A drive lag below the delivery lag's search floor: the loop benchmark's rig 14 of seed 1
/// (SBA1, moves with dwells; a critically damped drive lag of τ_d = 1.47 ms, its mean delay
/// 2.9 ms, under the floor of 2 ms). The loop names a sensor lag of the same mean delay (in the
/// frames the two differ at order (τ/frame)²), and lists the delivery lag among its alternatives,
/// fitted at half the sensor lag's τ (its search could not go there), within 10 % of the planted
/// τ_d: "cannot tell apart", the truth among the alternatives.
#[test]
fn a_drive_lag_below_its_floor_is_an_alternative_at_the_same_mean_delay() {
    use host_sim::rigs::PlantedKind;
    let (planted, _, ds) = hostsim_common::one_effect_rig(1, 14, PlantedKind::DeliveryLag);
    let d = sysid::residual::diagnose_dataset(&ds, &sysid::residual::Config::default(), false)
        .expect("diagnosis");
    assert_eq!(names(&d), ["sensor_lag"]);
    let tau_s = first_param(&d, "time_constant");
    let tau_d = first_alternative_param(&d, "delivery_lag", "time_constant");
    assert!(
        (tau_d - 0.5 * tau_s).abs() < 1e-12,
        "{tau_d} against {tau_s}"
    );
    assert!(
        (tau_d - planted.size).abs() <= 0.10 * planted.size,
        "τ_d {tau_d} s against the planted {} s",
        planted.size
    );
}

/// A drive lag far below the delivery lag's search floor, named an air pocket: the loop
/// benchmark's rig 263 of seed 1 (SBA1, the protocol; a critically damped drive lag of
/// τ_d = 0.37 ms, its mean delay 0.73 ms). A pocket of well under a cubic millimetre lags the
/// pressure by a time constant that changes with the pressure; the constant lag a fit would put
/// in its place (`EffectModel::mean_delay`: the pocket's time constants weighted by the squared
/// pressure rate) is where the other lags are fitted in its place, and the delivery lag there is
/// among its alternatives, within 15 % of the planted τ_d. (Before the pocket had a mean delay,
/// it was named with no alternative.)
#[test]
fn a_drive_lag_named_a_small_air_pocket_is_among_its_alternatives() {
    use host_sim::rigs::PlantedKind;
    let (planted, _, ds) = hostsim_common::one_effect_rig(1, 263, PlantedKind::DeliveryLag);
    let d = sysid::residual::diagnose_dataset(&ds, &sysid::residual::Config::default(), false)
        .expect("diagnosis");
    assert_eq!(names(&d), ["air_compliance"]);
    let tau_d = first_alternative_param(&d, "delivery_lag", "time_constant");
    assert!(
        (tau_d - planted.size).abs() <= 0.15 * planted.size,
        "τ_d {tau_d} s against the planted {} s",
        planted.size
    );
}
