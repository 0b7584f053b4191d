//! The residual loop on host-sim logs of other shapes than the paper's protocol (issue #17): the
//! firmware's own tasks driving the plant through irregular strokes (random targets, flows and
//! dwells: [`host_sim::Strokes`]), effects at a third of their preset sizes, three effects at
//! once, and sensor noise with heavy tails ([`host_sim::NoiseTails`]). Effects are not declared;
//! σ comes from truth (see `residual_hostsim.rs`).

use crate::hostsim_common;

use host_sim::plant::{Drive, Hysteresis};
use host_sim::{Effects, NoiseTails, PlantConfig, Scenario, SensorSpec, Strokes};
use hostsim_common::{names, run, Outcome};

fn strokes(name: &str, effects: Effects, sensor: SensorSpec, seed: u64) -> Scenario {
    let plant = PlantConfig {
        drive: Drive::Ideal,
        effects,
        sensor,
        ..PlantConfig::default()
    };
    Scenario {
        seed,
        ..Scenario::strokes(
            name,
            plant,
            &Strokes {
                seed,
                ..Strokes::default()
            },
        )
    }
}

fn preset(name: &str) -> Effects {
    Effects::preset(name).expect("known preset")
}

/// Every name in `expect` is kept, and the held-out RMSE ends within 10 % of σ.
fn check(o: &Outcome, expect: &[&str]) {
    let found = names(&o.d);
    for e in expect {
        assert!(found.contains(e), "{e} not named, found {found:?}");
    }
    assert!(
        o.d.final_model.rmse_heldout <= 1.10 * o.sigma,
        "held-out RMSE after {:.5} kPa exceeds 1.10 σ = {:.5} kPa",
        o.d.final_model.rmse_heldout,
        1.10 * o.sigma
    );
}

/// The injected effect's searched parameter, as the diagnosis reports it.
fn param(o: &Outcome, effect: &str, name: &str) -> f64 {
    let e =
        o.d.effects
            .iter()
            .find(|e| e.name == effect)
            .expect("named");
    e.params
        .iter()
        .find(|p| p.name == name)
        .expect("parameter")
        .value
}

fn gaussian() -> SensorSpec {
    SensorSpec::default()
}

#[test]
fn clean_irregular_strokes_get_no_effect() {
    let o = run(&strokes("clean", Effects::default(), gaussian(), 32));
    assert!(o.d.effects.is_empty(), "{:?}", names(&o.d));
}

#[test]
fn hysteresis_on_irregular_strokes() {
    let o = run(&strokes("hysteresis", preset("hysteresis"), gaussian(), 31));
    check(&o, &["hysteresis"]);
    // The plant's loop: half-height 1 kPa (a 2 kPa gap), 20 mm³ transition.
    assert!((param(&o, "hysteresis", "width") - 20.0).abs() < 3.0);
}

/// Hysteresis at a third of its preset size (a 0.67 kPa gap).
#[test]
fn third_size_hysteresis_on_irregular_strokes() {
    let h = Effects {
        hysteresis: Some(Hysteresis {
            amplitude_kpa: 1.0 / 3.0,
            transition_mm3: 20.0,
        }),
        ..Effects::default()
    };
    check(
        &run(&strokes("hysteresis / 3", h, gaussian(), 36)),
        &["hysteresis"],
    );
}

/// The lags on irregular strokes: a sensor lag, and an air pocket at a third of its preset size
/// (6.7 mm³), are named with their parameters. The board's frame is the mean of 8 conversions
/// over its 40 ms, and the lags act inside it; the loop runs them over the motion rebuilt at
/// those instants (`lag_in_frames`), so a move starting or stopping inside a frame is not
/// smeared over the frames around it (the cubic between frames ended at 1.106 σ and 1.146 σ).
#[test]
fn lags_on_irregular_strokes() {
    let o = run(&strokes("sensor lag", preset("sensor-lag"), gaussian(), 35));
    assert_eq!(names(&o.d), ["sensor_lag"]);
    assert!((param(&o, "sensor_lag", "time_constant") - 0.02).abs() < 0.003);
    check(&o, &["sensor_lag"]);
    let air = Effects {
        air_pocket_mm3: [20.0 / 3.0; 3],
        ..Effects::default()
    };
    let o = run(&strokes("air / 3", air, gaussian(), 38));
    assert_eq!(names(&o.d), ["air_compliance"]);
    assert!(
        (param(&o, "air_compliance", "air_volume_at_atmospheric_pressure") - 20.0 / 3.0).abs()
            < 1.0
    );
    check(&o, &["air_compliance"]);
}

/// A full-size air pocket (20 mm³) on irregular strokes. Its lag linearises the law's flow term
/// about the pump's flow, and the law is quadratic in flow: at a move's start the pocket takes
/// much of the flow, and the linearised lag missed the square of it (1.105 σ). The damping the lag
/// runs on is now the law's at the flow midway between the pump's and the chamber's, which for a
/// quadratic makes it exact (`AirCompliance::refine`).
#[test]
fn full_size_air_pocket_on_irregular_strokes() {
    let o = run(&strokes("air", preset("air"), gaussian(), 33));
    assert_eq!(names(&o.d), ["air_compliance"]);
    // A strong single effect: the data tell it from every other explanation.
    assert!(
        o.d.effects[0].alternatives.is_empty(),
        "{:?}",
        o.d.effects[0].alternatives
    );
    assert!((param(&o, "air_compliance", "air_volume_at_atmospheric_pressure") - 20.0).abs() < 0.6);
    check(&o, &["air_compliance"]);
}

/// An air pocket and a sensor lag at once (both at their preset sizes), on three seeds. A delivery
/// lag (a two-stage lag, like the two lags in series) alone explains most of both and takes the
/// first round; a sensor lag searched on top only makes it worse (1.53 σ on seed 33, 3.88 σ on
/// seed 35 with the delivery lag alone). The look-alike swap (`swap_look_alike`) tries the first
/// round's look-alikes in the delivery lag's place with the rest re-tuned: the sensor lag takes it
/// (seeds 33, 34), or the air pocket and the sensor lag together (seed 35, where each alone lost
/// to the delivery lag). The re-tune takes the pocket's damping again from the re-tuned model and
/// puts both lags in one form: without that seed 34 ended at 1.14–1.19 σ with the sensor lag
/// 6 % long.
fn air_pocket_and_sensor_lag_are_not_taken_by_a_look_alike(seed: u64) {
    let mut both = preset("air");
    both.sensor_lag_s = preset("sensor-lag").sensor_lag_s;
    let o = run(&strokes("air + sensor lag", both, gaussian(), seed));
    let found = names(&o.d);
    assert!(!found.contains(&"delivery_lag"), "seed {seed}: {found:?}");
    assert!(
        o.d.swaps
            .iter()
            .any(|s| s.replaced == "delivery_lag" && s.by.contains(&"sensor_lag")),
        "seed {seed}: {:?}",
        o.d.swaps
    );
    let tau = param(&o, "sensor_lag", "time_constant");
    assert!((tau - 0.02).abs() < 0.0015, "seed {seed}: τ {tau}");
    let air = param(&o, "air_compliance", "air_volume_at_atmospheric_pressure");
    assert!((air - 20.0).abs() < 0.6, "seed {seed}: air {air}");
    check(&o, &["sensor_lag", "air_compliance"]);
    // The data decide between the pair and the delivery lag here.
    for e in &o.d.effects {
        assert!(
            !e.alternatives
                .iter()
                .any(|a| a.effect.contains("delivery_lag")),
            "seed {seed}: {} {:?}",
            e.name,
            e.alternatives
        );
    }
}

// One test per seed, so that the test threads share them.
#[test]
fn air_pocket_and_sensor_lag_seed_33() {
    air_pocket_and_sensor_lag_are_not_taken_by_a_look_alike(33);
}

#[test]
fn air_pocket_and_sensor_lag_seed_34() {
    air_pocket_and_sensor_lag_are_not_taken_by_a_look_alike(34);
}

#[test]
fn air_pocket_and_sensor_lag_seed_35() {
    air_pocket_and_sensor_lag_are_not_taken_by_a_look_alike(35);
}

/// A sensor lag at a third of its preset size (6.7 ms, a sixth of a frame) is told from its
/// look-alike, a delivery lag, and sized.
#[test]
fn third_size_sensor_lag_on_irregular_strokes() {
    let lag = Effects {
        sensor_lag_s: 0.02 / 3.0,
        ..Effects::default()
    };
    let o = run(&strokes("sensor lag / 3", lag, gaussian(), 37));
    assert_eq!(names(&o.d), ["sensor_lag"]);
    assert!((param(&o, "sensor_lag", "time_constant") - 0.02 / 3.0).abs() < 0.001);
    check(&o, &["sensor_lag"]);
}

/// The three effects at once (hysteresis, sensor lag, air pocket, all at their preset sizes) on
/// host-sim's irregular strokes, three seeds: all three named and sized, nothing else. On seed 33
/// this was 1.340 σ before the air pocket's lag took the damping at the flow midway between the
/// pump's and the chamber's and its schedule the chamber's pressure behind the sensor lag
/// (`design::pressure_schedule`), 1.102 σ after (sensor lag 8 % long, pocket 6 % small), and
/// 1.031 σ once the re-tune took the pocket's damping again from the re-tuned model.
fn three_effects_at_once(seed: u64) {
    let mut three = preset("hysteresis");
    three.sensor_lag_s = preset("sensor-lag").sensor_lag_s;
    three.air_pocket_mm3 = preset("air").air_pocket_mm3;
    let o = run(&strokes("three at once", three, gaussian(), seed));
    let mut found = names(&o.d);
    found.sort_unstable();
    assert_eq!(
        found,
        ["air_compliance", "hysteresis", "sensor_lag"],
        "seed {seed}"
    );
    let width = param(&o, "hysteresis", "width");
    assert!((width - 20.0).abs() < 0.6, "seed {seed}: width {width}");
    let tau = param(&o, "sensor_lag", "time_constant");
    assert!((tau - 0.02).abs() < 0.0015, "seed {seed}: τ {tau}");
    let air = param(&o, "air_compliance", "air_volume_at_atmospheric_pressure");
    assert!((air - 20.0).abs() < 0.6, "seed {seed}: air {air}");
    check(&o, &["hysteresis", "sensor_lag", "air_compliance"]);
}

#[test]
fn three_effects_at_once_seed_33() {
    three_effects_at_once(33);
}

#[test]
fn three_effects_at_once_seed_34() {
    three_effects_at_once(34);
}

#[test]
fn three_effects_at_once_seed_35() {
    three_effects_at_once(35);
}

/// Heavy-tailed sensor noise (Student's t with 3 degrees of freedom; 0.5 % of the conversions
/// spiked by 10 σ) on a plant with no effect: nothing is named.
#[test]
fn heavy_tailed_noise_raises_no_effect() {
    let t = SensorSpec {
        tails: NoiseTails::StudentT { dof: 3.0 },
        ..gaussian()
    };
    let o = run(&strokes("student t", Effects::default(), t, 34));
    assert!(o.d.effects.is_empty(), "Student t: {:?}", names(&o.d));
    let spikes = SensorSpec {
        tails: NoiseTails::Spikes {
            fraction: 0.005,
            size_kpa: 0.5,
        },
        ..gaussian()
    };
    let o = run(&strokes("spikes", Effects::default(), spikes, 39));
    assert!(o.d.effects.is_empty(), "spikes: {:?}", names(&o.d));
}

/// The lead screw's ripple is periodic in volume, so in time it is there only while the plunger
/// moves (gated by the motion itself).
#[test]
fn lead_screw_ripple_on_irregular_strokes() {
    let o = run(&strokes("ripple", preset("ripple"), gaussian(), 40));
    check(&o, &["pump_ripple"]);
}

/// Issue 34, "cannot tell apart": a small air pocket (2 mm³) and a short sensor lag (4 ms) on a
/// short log (40 moves). A delivery lag (two lags in series) is kept; the pair of the air pocket
/// and the sensor lag, fitted in its place with the re-tune, does better on the held-out cycles
/// but not by more than their noise (paired z below 2 over the held-out units), so the report
/// lists it as an alternative the data cannot tell from the delivery lag: the truth is among the
/// alternatives. (With a 4 mm³ pocket the data tell the pair apart: the next test.)
#[test]
fn air_pocket_and_sensor_lag_cannot_be_told_from_a_delivery_lag_on_a_short_log() {
    let sc = short_air_and_sensor_lag(2.0);
    let o = run(&sc);
    assert_eq!(names(&o.d), ["delivery_lag"]);
    let alts = &o.d.effects[0].alternatives;
    let pair = alts
        .iter()
        .find(|a| a.effect.contains("air_compliance") && a.effect.contains("sensor_lag"))
        .unwrap_or_else(|| panic!("the pair is not among the alternatives: {alts:?}"));
    assert!(
        pair.z.abs() < sysid::residual::alternatives::ALT_Z,
        "{pair:?}"
    );
    assert_eq!(pair.replaces, ["delivery_lag"]);
    // Both effects' parameters, named for their effects.
    for p in [
        "air_compliance.air_volume_at_atmospheric_pressure",
        "sensor_lag.time_constant",
    ] {
        assert!(
            pair.params.iter().any(|q| q.name == p),
            "{p} in {:?}",
            pair.params
        );
    }
}

/// The same log with an air pocket of 4 mm³: the pair of the air pocket and the sensor lag in the
/// delivery lag's place, re-tuned, is told from it on the held-out units (paired z ≥ 2), so it
/// replaces it and the plant's two effects are named. Before the pair's descent was located on a
/// stand-in, it gave up before reaching the delivery lag's training error, and the delivery lag
/// was kept with the pair as an alternative at z 1.4.
#[test]
fn a_pair_the_held_out_data_tell_apart_replaces_the_delivery_lag() {
    let sc = short_air_and_sensor_lag(4.0);
    let o = run(&sc);
    let mut named = names(&o.d);
    named.sort_unstable();
    assert_eq!(named, ["air_compliance", "sensor_lag"]);
    let swap = o.d.swaps.first().expect("a swap");
    assert_eq!(swap.replaced, "delivery_lag");
    assert!(
        swap.rmse_heldout_after < swap.rmse_heldout_before,
        "{swap:?}"
    );
}

/// An air pocket of `air_mm3` and a sensor lag of 4 ms on a short log of irregular strokes (40
/// moves, seed 48, the ideal drive).
fn short_air_and_sensor_lag(air_mm3: f64) -> Scenario {
    let plant = PlantConfig {
        drive: Drive::Ideal,
        effects: Effects {
            air_pocket_mm3: [air_mm3; 3],
            sensor_lag_s: 0.004,
            ..Effects::default()
        },
        sensor: gaussian(),
        ..PlantConfig::default()
    };
    Scenario {
        seed: 48,
        ..Scenario::strokes(
            "air + sensor lag, short",
            plant,
            &Strokes {
                seed: 48,
                moves: 40,
                ..Strokes::default()
            },
        )
    }
}
