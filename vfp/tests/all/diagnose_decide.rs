//! `vfp diagnose A --decide B` (issue 34): on a log where the loop cannot tell a kept effect from
//! its alternatives, the experiment it proposes, written as a host-sim scenario from the
//! report's own `scenario` lines and the plant, is simulated by `vfp simulate --scenario`; the
//! decision on that log is for the plant's truth.
//!
//! Truth: host-sim's plant, an air pocket of 2 mm³ and a sensor lag of 4 ms, which a short log
//! of irregular strokes (40 moves) reports as a delivery lag with the pair as an alternative.

use crate::common;

use common::{ok, scratch, vfp};
use host_sim::plant::Drive;
use host_sim::{simulate, Effects, PlantConfig, Scenario, SensorSpec, Strokes};
use std::path::Path;

/// The plant's `[plant]` table, as a scenario file writes it.
const PLANT: &str = "[plant]\ndrive = \"ideal\"\n[plant.effects]\nair_pocket_mm3 = [2.0, 2.0, 2.0]\nsensor_lag_s = 0.004\n";

fn first_log(path: &Path) {
    let plant = PlantConfig {
        drive: Drive::Ideal,
        effects: Effects {
            air_pocket_mm3: [2.0; 3],
            sensor_lag_s: 0.004,
            ..Effects::default()
        },
        sensor: SensorSpec::default(),
        ..PlantConfig::default()
    };
    let sc = Scenario {
        seed: 48,
        ..Scenario::strokes(
            "air + sensor lag, small",
            plant,
            &Strokes {
                seed: 48,
                moves: 40,
                ..Strokes::default()
            },
        )
    };
    let run = simulate(&sc).expect("scenario runs");
    let mut f = std::fs::File::create(path).expect("writable");
    run.write_log(&mut f).expect("log written");
}

fn json(out: &std::process::Output) -> serde_json::Value {
    serde_json::from_slice(&out.stdout).expect("JSON")
}

#[test]
fn the_proposed_experiment_simulated_decides_for_the_planted_pair() {
    let dir = scratch("decide", "pair");
    let a = dir.join("a.csv");
    first_log(&a);
    let d = json(&ok(vfp().arg("diagnose").arg(&a).arg("--json")));
    let e = &d["effects"][0];
    assert_eq!(e["name"], "delivery_lag", "{e}");
    let x = &e["experiment"];
    let snippet = x["scenario"].as_str().expect("scenario lines");
    assert!(x["expected_z"].as_f64().unwrap() >= 3.0, "{x}");
    // The report's lines with the rig's plant and another noise seed: a scenario file.
    let toml = dir.join("experiment.toml");
    std::fs::write(&toml, format!("seed = 1048\n{snippet}\n{PLANT}")).unwrap();
    let b = dir.join("b.csv");
    ok(vfp()
        .args(["simulate", "--scenario"])
        .arg(&toml)
        .arg("-o")
        .arg(&b));
    let out = ok(vfp()
        .arg("diagnose")
        .arg(&a)
        .arg("--decide")
        .arg(&b)
        .arg("--json"));
    let dec = &json(&out)["decision"]["effects"][0];
    let supports = dec["supports"].as_str().unwrap_or("still cannot tell");
    assert!(
        supports.contains("air_compliance") && supports.contains("sensor_lag"),
        "{dec}"
    );
    // The text report says so too, and names the experiment.
    let text = ok(vfp().arg("diagnose").arg(&a).arg("--decide").arg(&b));
    let text = String::from_utf8_lossy(&text.stdout);
    assert!(
        text.contains("experiment that decides: `run all "),
        "{text}"
    );
    assert!(
        text.contains("supports sensor_lag + air_compliance"),
        "{text}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Nothing to decide: with one candidate there is no alternative, and `--decide` says so.
#[test]
fn deciding_without_alternatives_is_a_clear_error() {
    let dir = scratch("decide", "none");
    let a = dir.join("a.csv");
    first_log(&a);
    let out = vfp()
        .arg("diagnose")
        .arg(&a)
        .args(["--effect", "delivery-lag", "--decide"])
        .arg(&a)
        .output()
        .expect("vfp runs");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("nothing to decide"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}
