//! End-to-end tests across the workspace's crates live in `tests/tests/`; this library holds
//! their shared helpers.
//!
//! - `record_to_identify`: telemetry captured from host-sim, with frames removed and lines
//!   corrupted, through `vfp record`'s converter; the recorded log read by `identify` unchanged.
//! - `deploy_predict`: a polynomial exported by sysid, loaded into the simulated firmware through
//!   its serial port, predicts the same pressure on the board as sysid does, to float precision.
//! - `demo_chain`: the demo's whole chain on a short run.

use std::path::PathBuf;

use host_sim::{PlantConfig, Protocol, Scenario};

/// A short characterisation run: one cycle at 50 and at 100 mm³/s over 0–550 mm³ (about 35 s
/// of rig time, some 900 frames).
pub fn short_protocol(plant: PlantConfig) -> Scenario {
    let p = Protocol {
        cycles: 1,
        flows: vec![50.0, 100.0],
        ..Protocol::paper()
    };
    Scenario::protocol("e2e-short", plant, &p)
}

/// A fresh, empty scratch directory for one test.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("vfp-e2e-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir is writable");
    d
}

/// The capture as `probe-rs run` prints it: a timestamp before each line, a location line after.
pub fn probe_rs_text(lines: &[(u64, String)]) -> Vec<String> {
    let mut out = vec!["     Running `probe-rs run --chip STM32F446RETx vfp-fw`".to_string()];
    for (t, l) in lines {
        out.push(format!("{:.6} {l}", *t as f64 * 1e-6));
        out.push("└─ vfp_fw::__sampler_task @ firmware/src/bin/vfp-fw.rs:56".to_string());
    }
    out
}
