//! Stiffness and damping (§IV-A) against a known polynomial law: the fitted model's pointwise
//! partials must reproduce the law's hand-differentiated ones.

// The same known-truth generator as sysid's diagnostics tests, from one file.
use crate::diag_common;
use diag_common::*;
use sysid::dataset::{DatasetConfig, LogData};
use sysid::diag::stiffness;
use sysid::diag::Shape;
use vfp::cmd::stiffness::{Args as StiffnessArgs, ShapeOpts};
use vfp::opts::{LogInput, OutputOpts};

fn read_log(path: &std::path::Path) -> Result<LogData, sysid::dataset::LoadError> {
    LogData::read(path, None, &DatasetConfig::default())
}
use sysid::synth::SBA1_RAW;

#[test]
fn means_match_the_known_law_overall_and_per_phase() {
    let n = 4000;
    let tr = protocol(n, 550.0);
    let p = pressure(&SBA1_RAW, &tr, &ar1_noise(n, 0.05, 0.0, 7));
    let dir = tmpdir("stiff-known");
    let path = dir.join("sba1.csv");
    write(&path, &tr, &[(0, tr.v.clone(), p)], None, &[]);
    let log = read_log(&path).unwrap();
    let res = stiffness::analyze_log(&log, Shape::PAPER).unwrap();
    let s = &res[0].summary;

    // Truth: the law's own partials at the same samples, split with the band the report states
    // (the dataset's phase deadband).
    let band = s.deadband_mm3_s;
    assert_eq!(band, log.first().deadband);
    let truth: Vec<(f64, f64)> =
        tr.v.iter()
            .zip(&tr.vdot)
            .map(|(&v, &q)| raw_partials(&SBA1_RAW, v, q))
            .collect();
    let mean = |keep: &dyn Fn(f64) -> bool| {
        let sel: Vec<_> = truth
            .iter()
            .zip(&tr.vdot)
            .filter(|(_, &q)| keep(q))
            .map(|(t, _)| *t)
            .collect();
        let k = sel.iter().map(|t| t.0).sum::<f64>() / sel.len() as f64;
        let c = sel.iter().map(|t| t.1).sum::<f64>() / sel.len() as f64;
        (k, c, sel.len())
    };
    let (k_all, c_all, _) = mean(&|_| true);
    let (k_in, c_in, n_in) = mean(&|q| q > band);
    let (k_de, c_de, n_de) = mean(&|q| q < -band);
    let close = |a: f64, b: f64, what: &str| {
        assert!(
            (a - b).abs() <= 0.01 * b.abs(),
            "{what}: estimated {a}, law {b}"
        );
    };
    close(s.k_mean, k_all, "k all");
    close(s.c_mean, c_all, "c all");
    close(s.inflation.k_mean.unwrap(), k_in, "k inflation");
    close(s.inflation.c_mean.unwrap(), c_in, "c inflation");
    close(s.deflation.k_mean.unwrap(), k_de, "k deflation");
    close(s.deflation.c_mean.unwrap(), c_de, "c deflation");
    assert_eq!((s.inflation.samples, s.deflation.samples), (n_in, n_de));
    assert_eq!(s.samples, n);
    // Independent physical check: this law stiffens with volume and its damping grows with
    // flow (α₀₂ > 0), so inflation (v̇ > 0) must show the larger c.
    assert!(s.inflation.c_mean.unwrap() > s.deflation.c_mean.unwrap());
}

#[test]
fn command_writes_figure_and_succeeds() {
    let n = 2500;
    let tr = protocol(n, 550.0);
    let p0 = pressure(&SBA1_RAW, &tr, &ar1_noise(n, 0.05, 0.0, 1));
    let p1 = pressure(&scaled_sba1(0.5, 0.5), &tr, &ar1_noise(n, 0.05, 0.0, 2));
    let dir = tmpdir("stiff-cmd");
    let path = dir.join("two-chambers.csv");
    write(
        &path,
        &tr,
        &[(0, tr.v.clone(), p0), (1, tr.v.clone(), p1)],
        None,
        &[],
    );
    let args = StiffnessArgs {
        input: LogInput::new(path.clone()),
        shape: ShapeOpts::default(),
        out: OutputOpts {
            json: true,
            plots: Some(dir.join("plots")),
            ..OutputOpts::default()
        },
    };
    vfp::cmd::stiffness::run(&args).unwrap();
    let svg = std::fs::read_to_string(dir.join("plots/diag-stiffness.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("chamber 1"));
    // Chamber 1's law is chamber 0's halved: so are its mean partials (linearity of ∂).
    let log = read_log(&path).unwrap();
    let res = stiffness::analyze_log(&log, Shape::PAPER).unwrap();
    let ratio = res[1].summary.k_mean / res[0].summary.k_mean;
    assert!((ratio - 0.5).abs() < 0.01, "k ratio {ratio}");
    let ratio = res[1].summary.c_mean / res[0].summary.c_mean;
    assert!((ratio - 0.5).abs() < 0.01, "c ratio {ratio}");
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let dir = tmpdir("stiff-bad");
    let missing = StiffnessArgs {
        input: LogInput::new(dir.join("nope.csv")),
        shape: ShapeOpts::default(),
        out: OutputOpts::default(),
    };
    let e = vfp::cmd::stiffness::run(&missing).unwrap_err().to_string();
    assert!(e.contains("nope.csv"), "{e}");

    // A log that never moves cannot determine a flow-dependent model.
    let still = dir.join("still.csv");
    std::fs::write(&still, "time_s,volume_mm3,flow_mm3_s,pressure_kpa\n0,10,0,1\n0.04,10,0,1.1\n0.08,10,0,0.9\n0.12,10,0,1\n").unwrap();
    let args = StiffnessArgs {
        input: LogInput::new(still),
        shape: ShapeOpts::default(),
        out: OutputOpts::default(),
    };
    let e = vfp::cmd::stiffness::run(&args).unwrap_err().to_string();
    assert!(e.contains("still.csv") && e.contains("chamber 0"), "{e}");

    let bad_shape = StiffnessArgs {
        input: LogInput::new(dir.join("x.csv")),
        shape: ShapeOpts { n: 9, m: 2 },
        out: OutputOpts::default(),
    };
    assert!(vfp::cmd::stiffness::run(&bad_shape)
        .unwrap_err()
        .to_string()
        .contains("--n 9"));
    let _ = Shape::PAPER;
}
