//! Force from pressure residuals (§IV-C) on data with a known force: pushes at 1 Hz on an
//! actuator held at 500 mm³, shared unevenly between three chambers with different laws.

// The same known-truth generator as sysid's diagnostics tests, from one file.
use crate::diag_common;
use diag_common::*;
use sysid::dataset::{DatasetConfig, LogData};
use sysid::diag::force::{self, ForceOptions};
use vfp::cmd::force::Args as ForceArgs;
use vfp::cmd::stiffness::ShapeOpts;
use vfp::opts::{DataOpts, OutputOpts};

fn read_log(path: &std::path::Path) -> Result<LogData, sysid::dataset::LoadError> {
    LogData::read(path, None, &DatasetConfig::default())
}

fn options(a: &ForceArgs) -> ForceOptions {
    a.options().unwrap()
}
use sysid::synth::{eval_raw, Trajectory};

const SIGMA: f64 = 0.05;
const AREA: f64 = 22.0;
const SHARES: [f64; 3] = [0.5, 0.3, 0.2];

fn laws() -> [[f64; 12]; 3] {
    [
        scaled_sba1(0.9, 1.0),
        scaled_sba1(1.0, 1.0),
        scaled_sba1(1.1, 0.9),
    ]
}

/// Writes the force-free identification log and the push log; returns their paths.
fn logs(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let n = 3000;
    let tr = protocol(n, 550.0);
    let ch: Vec<(u8, Vec<f64>, Vec<f64>)> = laws()
        .iter()
        .enumerate()
        .map(|(c, law)| {
            (
                c as u8,
                tr.v.clone(),
                pressure(law, &tr, &ar1_noise(n, SIGMA, 0.0, 10 + c as u64)),
            )
        })
        .collect();
    let ident = dir.join("ident.csv");
    write(&ident, &tr, &ch, None, &[]);

    // 20 s at 500 mm³, raised-cosine pushes of 0.3 N peak at 1 Hz.
    let m = 500;
    let t: Vec<f64> = (0..m).map(|i| i as f64 / 25.0).collect();
    let f: Vec<f64> = t
        .iter()
        .map(|&t| 0.3 * 0.5 * (1.0 - (std::f64::consts::TAU * t).cos()))
        .collect();
    let hold = Trajectory {
        t: t.clone(),
        v: vec![500.0; m],
        vdot: vec![0.0; m],
    };
    let ch: Vec<(u8, Vec<f64>, Vec<f64>)> = laws()
        .iter()
        .enumerate()
        .map(|(c, law)| {
            let noise = ar1_noise(m, SIGMA, 0.0, 20 + c as u64);
            // Share of the force over the area: N / mm² × 1e3 = kPa.
            let p = (0..m)
                .map(|i| eval_raw(law, 3, 2, 500.0, 0.0) + SHARES[c] * f[i] * 1e3 / AREA + noise[i])
                .collect();
            (c as u8, hold.v.clone(), p)
        })
        .collect();
    let test = dir.join("push.csv");
    write(&test, &hold, &ch, Some(&f), &[]);
    (ident, test)
}

fn args(ident: std::path::PathBuf, test: std::path::PathBuf, smooth: usize) -> ForceArgs {
    ForceArgs {
        ident,
        test,
        area: vec![AREA],
        shape: ShapeOpts { n: 3, m: 2 },
        smooth,
        plot_window: 10.0,
        augmented: false,
        data: DataOpts::default(),
        out: OutputOpts::default(),
    }
}

#[test]
fn force_error_sits_at_the_noise_floor() {
    let dir = tmpdir("force");
    let (ident, test) = logs(&dir);
    let a = args(ident.clone(), test.clone(), 1);
    let (r, trace) = force::estimate(
        &read_log(&ident).unwrap(),
        &read_log(&test).unwrap(),
        &options(&a),
    )
    .unwrap();
    // Floor: σ·A·√3 = 0.05 kPa × 22 mm² × 1.732 = 1.905 mN.
    let floor = SIGMA * AREA * 3f64.sqrt() * 1e-3;
    assert!(
        (r.noise_floor_n - floor).abs() < 0.15 * floor,
        "floor {} vs {floor}",
        r.noise_floor_n
    );
    let (mean, std) = (r.mean_error_n.unwrap(), r.std_error_n.unwrap());
    assert!(mean.abs() < 0.5e-3, "mean error {mean} N");
    assert!(
        (std - floor).abs() < 0.2 * floor,
        "std {std} N vs floor {floor}"
    );
    assert!((r.rmse_n.unwrap() - (mean * mean + std * std).sqrt()).abs() < 0.1e-3);
    assert_eq!(r.samples, 500);
    assert_eq!(trace.est.len(), 500);
    // The estimate follows the 0–0.3 N pushes.
    let peak = trace.est.iter().cloned().fold(f64::MIN, f64::max);
    assert!((peak - 0.3).abs() < 0.01, "peak {peak}");
}

#[test]
fn smoothing_trades_noise_for_bandwidth() {
    let dir = tmpdir("force-smooth");
    let (ident, test) = logs(&dir);
    let (il, tl) = (read_log(&ident).unwrap(), read_log(&test).unwrap());
    let (r1, _) =
        force::estimate(&il, &tl, &options(&args(ident.clone(), test.clone(), 1))).unwrap();
    let (r5, _) =
        force::estimate(&il, &tl, &options(&args(ident.clone(), test.clone(), 5))).unwrap();
    // Noise floor falls by √5; the stated −3 dB bandwidth is 0.443·25/5 = 2.2 Hz.
    assert!((r5.noise_floor_n * 5f64.sqrt() - r1.noise_floor_n).abs() < 1e-9);
    assert!(
        (r5.bandwidth_hz - 2.215).abs() < 0.01,
        "{}",
        r5.bandwidth_hz
    );
    assert!((r1.bandwidth_hz - 12.5).abs() < 1e-6);
    // A 5-sample mean passes 1 Hz with gain sin(π/5)/(5 sin(π/25)) = 0.938: the 0.15 N
    // oscillation loses about 9 mN of amplitude, more than the noise it removes.
    assert!(r5.rmse_n.unwrap() > r1.rmse_n.unwrap());
}

#[test]
fn command_runs_and_rejects_bad_options() {
    let dir = tmpdir("force-cmd");
    let (ident, test) = logs(&dir);
    let mut a = args(ident.clone(), test.clone(), 1);
    a.out = OutputOpts {
        json: true,
        plots: Some(dir.join("plots")),
        ..OutputOpts::default()
    };
    // In-process, progress would draw on the test's terminal: quiet, as the binary with `--quiet`.
    vfp::progress::set_quiet(true);
    vfp::cmd::force::run(&a).unwrap();
    let svg = std::fs::read_to_string(dir.join("plots/diag-force.svg")).unwrap();
    assert!(svg.contains("reference force_n"));
    let mut bad = args(ident.clone(), test.clone(), 1);
    bad.area = vec![22.0, -1.0, 22.0];
    assert!(vfp::cmd::force::run(&bad)
        .unwrap_err()
        .to_string()
        .contains("--area"));
    let mut bad = args(ident, dir.join("missing.csv"), 1);
    bad.smooth = 3;
    assert!(vfp::cmd::force::run(&bad)
        .unwrap_err()
        .to_string()
        .contains("missing.csv"));
}
