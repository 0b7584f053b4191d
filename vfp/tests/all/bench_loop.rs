//! `vfp bench-loop` as a user runs it: what it scores is what `vfp diagnose` says of the same log,
//! the rigs are the generator's, and bad input gets one clear sentence.

use crate::common::{ok, scratch, vfp};
use host_sim::rigs::{draw, RigOptions};

#[test]
fn bench_loop_scores_what_vfp_diagnose_names_on_the_rigs_it_drew() {
    let dir = scratch("bench_loop", "rigs");
    let json = dir.join("bench.json");
    // Rig 0 of seed 2 carries three effects, rig 1 none (the CI gate's first two).
    ok(vfp().args([
        "bench-loop",
        "--rigs",
        "2",
        "--seed",
        "2",
        "--samples",
        "5000,5200",
        "--json",
        json.to_str().unwrap(),
        "--keep-logs",
        dir.to_str().unwrap(),
    ]));
    let doc: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let rigs = doc["rigs"].as_array().unwrap();
    assert_eq!(rigs.len(), 2);
    let opts = RigOptions {
        samples: (5000, 5200),
        ..RigOptions::default()
    };
    for (i, rig) in rigs.iter().enumerate() {
        assert!(rig["error"].is_null(), "rig {i}: {}", rig["error"]);
        // The planted effects are the generator's.
        let spec = draw(2, i, &opts).unwrap();
        let planted: Vec<&str> = rig["planted"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["kind"].as_str().unwrap())
            .collect();
        let drawn: Vec<&str> = spec.planted.iter().map(|p| p.kind.name()).collect();
        assert_eq!(planted, drawn, "rig {i}");
        // The named effects and the final error are what `vfp diagnose` reports on its log.
        let log = dir.join(format!("bench-loop-2-{i}.csv"));
        let out = ok(vfp().args([
            "diagnose",
            log.to_str().unwrap(),
            "--chamber",
            "0",
            "--json",
        ]));
        let d: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        let by_diagnose: Vec<&str> = d["effects"]
            .as_array()
            .unwrap()
            .iter()
            .map(|e| e["name"].as_str().unwrap())
            .collect();
        let by_bench: Vec<&str> = rig["named"]
            .as_array()
            .unwrap()
            .iter()
            .map(|n| n["name"].as_str().unwrap())
            .collect();
        assert_eq!(by_bench, by_diagnose, "rig {i}");
        assert_eq!(rig["final_rmse_kpa"], d["final"]["rmse_heldout"], "rig {i}");
        // The oracle's complete model (every planted effect's true contribution) ends at the
        // noise, which is what makes σ the loop's target on these rigs.
        let oracle = rig["oracle_rmse_kpa"].as_f64().unwrap() / rig["sigma_kpa"].as_f64().unwrap();
        assert!(
            (0.9..1.1).contains(&oracle),
            "rig {i}: oracle at {oracle} σ"
        );
    }
    assert!(doc["summary"]["clean_rigs"].as_u64() == Some(1));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_arguments_and_gate_files_get_one_sentence() {
    let dir = scratch("bench_loop", "bad");
    let fails = |args: &[&str], needle: &str| {
        let out = vfp().arg("bench-loop").args(args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
    };
    fails(&["--samples", "9000,100"], "--samples 9000–100");
    fails(&["--samples", "9000"], "--samples expects LOW,HIGH");
    fails(&["--rigs", "0"], "--rigs must be at least 1");
    let missing = dir.join("none.toml");
    fails(&["--gate", missing.to_str().unwrap()], "cannot read");
    let typo = dir.join("typo.toml");
    std::fs::write(
        &typo,
        "rigs = 1\nseed = 1\nsamples = [5000, 6000]\nmin_precison = 0.9\n",
    )
    .unwrap();
    fails(&["--gate", typo.to_str().unwrap()], "min_precison");
    let _ = std::fs::remove_dir_all(&dir);
}
