//! The demo's whole chain on a short run: simulate with a planted effect → capture → record →
//! identify → residual loop → export and deploy to a fresh simulated board → force pushes →
//! report. Checked against what was planted, not against what the code printed before.

use e2e_tests::scratch;
use sysid::identify::Family;
use vfp::cmd::demo::{run_plan, Plan};

#[test]
fn the_demo_chain_runs_and_finds_what_was_planted() {
    let plan = Plan {
        // Six cycles, so one in five is held out (not a time-based tail), at three flows, so the
        // polynomial sees slow flows near the pushes' v̇ = 0.
        cycles: 2,
        flows: vec![20.0, 60.0, 100.0],
        push_s: 3.0,
        families: vec![Family::Poly, Family::PolyAr],
        max_degree: 3,
        ar_max: 1,
        ..Plan::new(true)
    };
    let out = scratch("demo-chain");
    // In-process, the stage spinners would draw on the test's terminal: quiet, as `vfp -q demo`.
    vfp::progress::set_quiet(true);
    let r = run_plan(plan, 3, &out).expect("the chain runs");

    // Nothing lost between the board and the log.
    assert_eq!(r.record.1, 0, "missing frames");
    assert_eq!(r.record.2, 0, "corrupted lines");
    // Every chamber deployed, every line acknowledged, the board predicting as sysid does.
    assert_eq!(r.deployed.len(), 3);
    for d in &r.deployed {
        assert_eq!(d.acked, d.lines.len());
        assert!(d.frames_compared > 50);
        assert!(
            d.max_p_hat_rel_diff < 1e-5,
            "chamber {}: {}",
            d.chamber,
            d.max_p_hat_rel_diff
        );
    }
    // The residual loop names the planted effect first, with a gap near the planted 2 kPa.
    let d = r.diagnosis.as_ref().expect("the residual loop ran");
    let first = d.effects.first().expect("an effect was found");
    assert_eq!(first.name, "hysteresis");
    let gap = first
        .params
        .iter()
        .find(|p| p.name == "gap_at_mid_volume")
        .expect("gap reported")
        .value;
    assert!((gap - 2.0).abs() < 0.5, "gap {gap} kPa, planted 2 kPa");
    // The force estimate carries the hysteresis bias the device model cannot remove: the planted
    // half-height 1 kPa on the inflation branch × 22 mm² × 3 chambers = 66 mN, within the noise.
    let f = r.force.as_ref().expect("force frames");
    assert!(
        (f.mean_error_mn - 66.0).abs() < 20.0,
        "mean error {} mN",
        f.mean_error_mn
    );
    // The augmented models (export --augmented's lines) carry the hysteresis in every chamber's
    // chain, and on the same pushes the board's bias is gone: the truth is host-sim's push force.
    assert_eq!(r.augmented.len(), 3);
    for (c, fx) in &r.augmented {
        assert!(fx.iter().any(|e| e == "hysteresis"), "chamber {c}: {fx:?}");
    }
    let fa = r.force_augmented.as_ref().expect("augmented force frames");
    assert!(
        fa.mean_error_mn.abs() < 10.0 && fa.mean_error_mn.abs() < 0.2 * f.mean_error_mn.abs(),
        "augmented mean error {} mN (bare {} mN)",
        fa.mean_error_mn,
        f.mean_error_mn
    );
    for file in [
        "report.md",
        "report.json",
        "telemetry.txt",
        "identification.csv",
        "figures/force.svg",
    ] {
        assert!(out.join(file).exists(), "{file}");
    }
    // Every figure written is linked from the report.
    let md = std::fs::read_to_string(out.join("report.md")).expect("report");
    for entry in std::fs::read_dir(out.join("figures")).expect("figures") {
        let name = entry
            .expect("entry")
            .file_name()
            .to_string_lossy()
            .into_owned();
        assert!(
            md.contains(&format!("](figures/{name})")),
            "{name} is not linked"
        );
    }
    let _ = std::fs::remove_dir_all(&out);
}
