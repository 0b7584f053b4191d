//! The presets behave as the paper's experiments did, seen through the firmware's telemetry.

use host_sim::{simulate, Design, PlantConfig, Protocol, Scenario};

/// Peak measured pressure (chamber 0) near the top of the inflation strokes.
fn top_pressure(sc: &Scenario, v_top: f32) -> f32 {
    let run = simulate(sc).unwrap_or_else(|e| panic!("{}: {e}", sc.name));
    assert!(
        run.first_event("fault").is_none(),
        "{}: {:?}",
        sc.name,
        run.events
    );
    assert!(run.first_event("protocol-done").is_some(), "{}", sc.name);
    run.frames
        .iter()
        .filter(|f| f.chambers[0].vdot > 0.0 && f.chambers[0].v > 0.97 * v_top)
        .map(|f| f.chambers[0].p)
        .fold(f32::MIN, f32::max)
}

/// Sec. IV-A: an air pocket makes the actuation softer — for the same syringe volume the bubble
/// takes up volume and the chamber sees less, so the pressure at the top is lower, more so for
/// more air. Boyle sets how much: at ~50 kPa, 50 mm³ of air shrinks by 50·50/151 ≈ 17 mm³.
#[test]
fn air_pockets_soften_the_v_p_curve() {
    let protocol = Protocol {
        cycles: 1,
        flows: vec![40.0],
        ..Protocol::paper()
    };
    let with_air = |mm3: f64| {
        let mut sc = Scenario::air_pocket(mm3);
        sc.commands[0].line = protocol.command();
        sc.duration_s = 40.0;
        top_pressure(&sc, 550.0)
    };
    let (p0, p10, p50) = (with_air(0.0), with_air(10.0), with_air(50.0));
    assert!(p0 > p10 + 0.5 && p10 > p50 + 2.0, "{p0} {p10} {p50}");
    // The chamber law at 550 − 17 mm³ predicts the drop to within a couple of kPa.
    let law = Design::Sba1.law();
    let drop = law.k(550.0) - law.k(533.0);
    assert!(
        ((p0 - p50) as f64 - drop).abs() < 2.5,
        "{} vs {drop}",
        p0 - p50
    );
}

/// Table V: each design runs its scaled protocol and stays inside its envelope.
#[test]
fn each_design_runs_within_its_envelope() {
    for d in [Design::Sba1, Design::Sba2, Design::Sba3] {
        let mut protocol = Protocol::for_design(d, 0.05);
        protocol.flows.truncate(2);
        let sc = Scenario::protocol(
            d.name(),
            PlantConfig {
                design: d,
                ..PlantConfig::default()
            },
            &protocol,
        );
        let top = top_pressure(&sc, d.max_volume_mm3() as f32);
        assert!(
            top > 0.3 * d.max_pressure_kpa() as f32 && top < d.max_pressure_kpa() as f32,
            "{d:?}: {top} kPa"
        );
    }
}

/// Every effect preset runs a short protocol to completion through the firmware without a fault,
/// and changes what the device measures (the effect is really on).
#[test]
fn every_effect_preset_runs_and_shows() {
    let protocol = Protocol {
        cycles: 1,
        flows: vec![40.0],
        ..Protocol::paper()
    };
    let measure = |sc: &mut Scenario| {
        sc.commands[0].line = protocol.command();
        sc.duration_s = 40.0;
        let run = simulate(sc).unwrap_or_else(|e| panic!("{}: {e}", sc.name));
        assert!(
            run.first_event("fault").is_none(),
            "{}: {:?}",
            sc.name,
            run.events
        );
        run.frames
            .iter()
            .map(|f| f.chambers[0].p)
            .collect::<Vec<f32>>()
    };
    let mut base = Scenario::protocol("base", PlantConfig::default(), &protocol);
    let p0 = measure(&mut base);
    for name in host_sim::EFFECT_PRESETS {
        let mut sc = Scenario::effect(name).unwrap();
        let p = measure(&mut sc);
        let n = p0.len().min(p.len());
        let max_diff = (0..n).map(|i| (p[i] - p0[i]).abs()).fold(0.0f32, f32::max);
        // Same seed, same noise draws: without the effect the runs would agree exactly.
        assert!(max_diff > 0.05, "{name}: max difference {max_diff} kPa");
    }
    assert!(Scenario::effect("gremlins").is_none());
}
