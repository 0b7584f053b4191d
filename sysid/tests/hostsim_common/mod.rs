//! What the host-sim acceptance tests of the residual loop share: run a scenario, diagnose its
//! chamber 0 as `vfp diagnose` would (effects not declared), and take σ from truth.
#![allow(dead_code)]

use host_sim::{simulate, Scenario, SimRun};
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::log::parse_log;
use sysid::residual::series_from_dataset;
use sysid::residual::{diagnose, Config, Diagnosis};

/// The run, its diagnosis on chamber 0 and σ from truth on the held-out frames.
pub struct Outcome {
    pub d: Diagnosis,
    pub sigma: f64,
    /// First and last frame time, s.
    pub span: (f64, f64),
}

/// σ of the logged pressure about what the sensor element saw (`FrameTruth::sensed_kpa`), minus the
/// known offset drift, over the held-out frames.
pub fn sigma_from_truth(run: &SimRun, ds: &Dataset) -> f64 {
    let drift = run.scenario.plant.effects.thermal_drift;
    let e: Vec<f64> = (0..ds.t.len())
        .filter(|&k| ds.heldout[k])
        .map(|k| {
            // The frames before the pressure zero are not in the dataset; the rest line up.
            let f = &run.truth[k + ds.not_zeroed];
            let t = f.t_us as f64 * 1e-6;
            let d = drift.map_or(0.0, |d| {
                d.offset_change_kpa * (1.0 - (-t / d.time_constant_s).exp())
            });
            ds.p[k] - f.chambers[0].sensed_kpa - d
        })
        .collect();
    let mean = e.iter().sum::<f64>() / e.len() as f64;
    (e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / e.len() as f64).sqrt()
}

/// Runs `sc` (the firmware must not fault) and reads chamber 0 of the log it wrote, as
/// `vfp diagnose` would.
pub fn simulated(sc: &Scenario) -> (SimRun, Dataset) {
    let sim = simulate(sc).expect("scenario runs");
    assert!(
        sim.first_event("fault").is_none(),
        "{}: the firmware faulted",
        sc.name
    );
    let mut bytes = Vec::new();
    sim.write_log(&mut bytes).expect("in memory");
    let log = parse_log(&bytes[..], &sc.name).expect("the simulator's log parses");
    let ds = Dataset::from_log(&log, 0, &DatasetConfig::default()).expect("dataset");
    (sim, ds)
}

/// Runs `sc`, diagnoses chamber 0 and prints the outcome.
pub fn run(sc: &Scenario) -> Outcome {
    let (sim, ds) = simulated(sc);
    // One row per frame, in order, after the boot frames that take the pressure zero: the truth
    // lines up by index from there.
    assert!(ds.not_zeroed > 0, "the log's flags mark the zeroing frames");
    assert_eq!(ds.t.len() + ds.not_zeroed, sim.truth.len());
    let sigma = sigma_from_truth(&sim, &ds);
    let series = series_from_dataset(&ds).expect("series");
    let d = diagnose(series, &Config::default()).expect("diagnosis");
    eprintln!(
        "{}: σ {:.4} kPa, baseline {:.4} → final {:.4} kPa ({:.3} σ), effects {:?}, remaining {:?}",
        sc.name,
        sigma,
        d.baseline.rmse_heldout,
        d.final_model.rmse_heldout,
        d.final_model.rmse_heldout / sigma,
        d.effects
            .iter()
            .map(|e| (e.name, e.params.iter().map(|p| p.value).collect::<Vec<_>>()))
            .collect::<Vec<_>>(),
        d.remaining.iter().map(|r| r.kind).collect::<Vec<_>>()
    );
    Outcome {
        d,
        sigma,
        span: (ds.t[0], ds.t[ds.t.len() - 1]),
    }
}

/// The names of the effects the diagnosis kept, in order.
pub fn names(d: &Diagnosis) -> Vec<&'static str> {
    d.effects.iter().map(|e| e.name).collect()
}

/// Rig `index` of the loop benchmark's `seed` (the usual forms), which plants one effect of
/// `kind` alone: the rig, its planted effect, the simulator's run and chamber 0's data set.
pub fn one_effect_rig(
    seed: u64,
    index: usize,
    kind: host_sim::rigs::PlantedKind,
) -> (host_sim::rigs::Planted, SimRun, Dataset) {
    use host_sim::rigs::{draw, RigOptions};
    let spec = draw(seed, index, &RigOptions::default()).expect("the rig draws");
    let [planted] = &spec.planted[..] else {
        panic!("rig {index} plants one effect: {}", spec.label());
    };
    assert_eq!(planted.kind, kind, "{}", spec.label());
    let (sim, ds) = simulated(&spec.scenario());
    (*planted, sim, ds)
}
