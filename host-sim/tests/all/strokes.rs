//! Irregular strokes ([`host_sim::Strokes`]) and heavy-tailed sensor noise
//! ([`host_sim::NoiseTails`]): the commands are the firmware's own, the rig follows them, and bad
//! noise parameters are refused by name.

use firmware::command::{parse, Command};
use host_sim::plant::Drive;
use host_sim::{simulate, NoiseTails, PlantConfig, Scenario, SensorSpec, Strokes};

#[test]
fn strokes_are_firmware_moves_within_their_ranges() {
    let s = Strokes {
        moves: 40,
        seed: 7,
        ..Strokes::default()
    };
    let (cmds, end) = s.commands();
    assert_eq!(cmds.len(), 40);
    let mut last = 0.0;
    for c in &cmds {
        assert!(c.at_s >= last, "commands in time order");
        last = c.at_s;
        match parse(c.line.as_bytes()).expect("the firmware parses it") {
            Command::Move { volume, flow, .. } => {
                assert!((0.0..=550.0).contains(&volume), "{}", c.line);
                let f = flow.expect("a flow");
                assert!((20.0..=100.0).contains(&f), "{}", c.line);
            }
            other => panic!("{}: {other:?}", c.line),
        }
    }
    assert!(end > last);
    // Another seed, other strokes.
    let other = Strokes { seed: 8, ..s }.commands().0;
    assert_ne!(other[0].line, cmds[0].line);
}

/// The simulated rig reaches each target: at the end of each move's time slot (before the next
/// command) the logged volume is the target.
#[test]
fn the_rig_follows_the_strokes() {
    let strokes = Strokes {
        moves: 12,
        seed: 3,
        ..Strokes::default()
    };
    let plant = PlantConfig {
        drive: Drive::Ideal,
        ..PlantConfig::default()
    };
    let run = simulate(&Scenario::strokes("follow", plant, &strokes)).expect("runs");
    let (cmds, _) = strokes.commands();
    for pair in cmds.windows(2) {
        let target: f64 = pair[0]
            .line
            .split_whitespace()
            .nth(2)
            .unwrap()
            .parse()
            .unwrap();
        let before = (pair[1].at_s * 1e6) as u64;
        let frame = run
            .truth
            .iter()
            .rev()
            .find(|f| f.t_us < before)
            .expect("a frame before the next command");
        let v = frame.chambers[0].motor_mm3;
        assert!(
            (v - target).abs() < 0.1,
            "at {} s: {v} for {target}",
            pair[1].at_s
        );
    }
}

#[test]
fn bad_noise_tails_are_refused_by_name() {
    for (tails, name) in [
        (NoiseTails::StudentT { dof: 2.0 }, "sensor.tails.dof"),
        (
            NoiseTails::Spikes {
                fraction: 1.5,
                size_kpa: 1.0,
            },
            "sensor.tails.fraction",
        ),
    ] {
        let cfg = PlantConfig {
            sensor: SensorSpec {
                tails,
                ..SensorSpec::default()
            },
            ..PlantConfig::default()
        };
        assert_eq!(cfg.validate().unwrap_err().name, name);
    }
}
