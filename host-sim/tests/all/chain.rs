//! A simulated board with an uploaded effect chain streams P̂ equal, bit for bit, to
//! model-core's chain evaluated offline on the frames it streamed.

use firmware::telemetry::EventKind;
use host_sim::{simulate, Scenario, TimedCommand};
use model_core::chain::{Chain, ChainInput, ChainState, Effect, EffectKind};
use model_core::poly::{sba1, ArHistory};

/// Upload lines of SBA1 with `effects` on chamber `ch` (`{:e}` round-trips every f32).
fn upload(ch: u8, effects: &[&str]) -> Vec<String> {
    let d = sba1();
    let sc = d.scaling();
    let mut lines = vec![format!(
        "model {ch} begin 3 2 0 {:e} {:e} {:e} {:e}",
        sc.v_offset, sc.v_scale, sc.f_offset, sc.f_scale
    )];
    for (k, chunk) in d.scaled().chunks(8).enumerate() {
        let vals: Vec<String> = chunk.iter().map(|x| format!("{x:e}")).collect();
        lines.push(format!("model {ch} coef {} {}", 8 * k, vals.join(" ")));
    }
    lines.extend(effects.iter().map(|e| format!("model {ch} effect {e}")));
    lines.push(format!("model {ch} commit"));
    lines
}

#[test]
fn the_boards_p_hat_is_the_offline_chain_bit_for_bit() {
    let effects = [
        "hysteresis 6 0.8 0.1",
        "sensor_lag 0.15",
        "delivery_lag 0.05",
        "transport_delay 0.1",
    ];
    let mut sc = Scenario {
        name: "chain".into(),
        duration_s: 9.0,
        ..Scenario::default()
    };
    for (i, l) in upload(0, &effects).iter().enumerate() {
        sc.commands
            .push(TimedCommand::new(1.5 + 0.01 * i as f64, l));
    }
    sc.commands.push(TimedCommand::new(2.0, "move 0 300 100"));
    sc.commands.push(TimedCommand::new(6.0, "move 0 150 60"));
    let run = simulate(&sc).expect("valid scenario");
    assert!(
        run.replies.iter().all(|(_, r)| r == "ok"),
        "{:?}",
        run.replies
    );
    let loaded = run
        .events
        .iter()
        .find(|e| matches!(e.kind, EventKind::ModelLoaded { ch: 0 }))
        .expect("the model was installed")
        .t_us;
    let mut chain = Chain::new();
    for (k, p) in [
        (EffectKind::Hysteresis, &[6.0f32, 0.8, 0.1][..]),
        (EffectKind::SensorLag, &[0.15][..]),
        (EffectKind::DeliveryLag, &[0.05][..]),
        (EffectKind::TransportDelay, &[0.1][..]),
    ] {
        chain.push(Effect::new(k, p).unwrap()).unwrap();
    }
    let replay = |from: usize| -> bool {
        let (model, hist, mut st) = (sba1(), ArHistory::new(), ChainState::new());
        run.frames[from..].iter().all(|f| {
            let c = &f.chambers[0];
            let inp = ChainInput {
                v: c.v,
                vdot: c.vdot,
                p: c.p,
                dt: 1.0 / 25.0,
            };
            chain
                .eval(&model, &hist, &mut st, inp)
                .is_ok_and(|e| e.p.to_bits() == c.p_hat.to_bits())
        })
    };
    // The chain starts on the first frame estimated after the commit: its conversions end
    // within a frame of its mean instant, so it is one of the first two frames stamped after
    // `loaded` − 40 ms.
    let near = run
        .frames
        .iter()
        .position(|f| f.t_us + 40_000 > loaded)
        .unwrap();
    let start = (near..near + 2).find(|&i| replay(i));
    assert!(
        start.is_some(),
        "no start frame near {near} replays bit for bit"
    );
    let start = start.unwrap();
    let moving = run.frames[start..]
        .iter()
        .filter(|f| f.chambers[0].vdot != 0.0)
        .count();
    assert!(
        run.frames.len() - start > 150 && moving > 100,
        "{} frames",
        run.frames.len()
    );
    // And the chain mattered: P̂ differs from the bare polynomial on the moving frames.
    let differs = run.frames[start..]
        .iter()
        .filter(|f| {
            let c = &f.chambers[0];
            sba1()
                .eval(c.v, c.vdot)
                .is_ok_and(|e| (e.p - c.p_hat).abs() > 0.1)
        })
        .count();
    assert!(differs > 50, "{differs} frames differ by > 0.1 kPa");
}
