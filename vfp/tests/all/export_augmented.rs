//! `vfp export --augmented`: the residual loop's model carried to the firmware.
//!
//! Checked against independent truths: a known plant (the paper's SBA1 law plus an inertance
//! written as the backward difference the device computes, plus a sensor drift the device cannot
//! run), the firmware's own command handler and estimator (host-sim's simulated board running
//! its tasks), and a second least-squares implementation (`sysid::poly::fit`) for the
//! nothing-carried case.
#![allow(clippy::needless_range_loop)] // index loops walk several aligned signals

use firmware::telemetry::Frame;
use host_sim::{simulate, Effects, PlantConfig, Protocol, Scenario, TimedCommand};
use model_core::poly::{ArHistory, PolyModel, SBA1_RAW};
use sysid::board::augmented::{augmented_export, device_model, DeviceModel};
use sysid::board::deploy::{deploy, parse_lines, FirmwarePort, Readback};
use sysid::board::export::command_lines;
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::residual::effects::{Hysteresis, Inertance, OffsetDrift};
use sysid::residual::series_from_dataset;
use sysid::residual::{Config, EffectKind, Series};
use sysid::synth;

/// Sensor noise of the synthetic logs, kPa.
const SIGMA: f64 = 0.05;
/// Frame interval of the synthetic logs (25 Hz, the firmware's rate), s.
const DT: f64 = 0.04;

/// A synthetic log of a known plant: SBA1 (Table IV) + L·(v̇(t) − v̇(t−1))/Δt + a linear sensor
/// drift of `drift_kpa` over the log + N(0, σ²). Returns the columns and the noise-free pressure
/// without the drift (what a device model can at best predict).
struct Synthetic {
    t: Vec<f64>,
    v: Vec<f64>,
    vdot: Vec<f64>,
    p: Vec<f64>,
    truth_no_drift: Vec<f64>,
}

fn synthetic(l: f64, drift_kpa: f64, seed: u64) -> Synthetic {
    let tr = synth::Protocol {
        rates: vec![20.0, 60.0, 100.0],
        samples: 9_000,
        sample_hz: 1.0 / DT,
        ..synth::Protocol::default()
    }
    .trajectory();
    let noisy = synth::pressure(&SBA1_RAW, 3, 2, &tr, SIGMA, seed);
    let t_end = tr.t[tr.t.len() - 1];
    let mut p = noisy;
    let mut truth = Vec::with_capacity(p.len());
    for k in 0..p.len() {
        let inert = if k == 0 {
            0.0
        } else {
            l * (tr.vdot[k] - tr.vdot[k - 1]) / DT
        };
        truth.push(synth::eval_raw(&SBA1_RAW, 3, 2, tr.v[k], tr.vdot[k]) + inert);
        p[k] += inert + drift_kpa * tr.t[k] / t_end;
    }
    Synthetic {
        t: tr.t,
        v: tr.v,
        vdot: tr.vdot,
        p,
        truth_no_drift: truth,
    }
}

fn series_of(s: &Synthetic) -> Series {
    let ds = Dataset::from_columns(
        s.t.clone(),
        s.v.clone(),
        s.vdot.clone(),
        s.p.clone(),
        &DatasetConfig::default(),
    );
    series_from_dataset(&ds).expect("valid series")
}

/// Float-precision bound for an f32 evaluation of `model` against an f64 evaluation of the same
/// function (as in `tests/tests/all/deploy_predict.rs`): Horner on scaled inputs |x|, |y| ≲ 1 errs by at
/// most (n + m + 2)·u·Σ|b|, the AR terms by a few u·Σ|b_AR|; 32·u·(Σ|b| + Σ|b_AR|) bounds both.
fn f32_bound(model: &PolyModel) -> f64 {
    let u = f64::from(f32::EPSILON) / 2.0;
    let s: f64 = model
        .scaled()
        .iter()
        .chain(model.ar().iter().flatten())
        .map(|b| f64::from(b.abs()))
        .sum();
    32.0 * u * s
}

/// Walks `series` through `model` as the firmware does (history of past frames) and returns the
/// largest |device − host| against `host(k)` and the number of samples compared.
fn max_gap(
    model: &PolyModel,
    series: &Series,
    host: impl Fn(usize) -> Option<f64>,
) -> (f64, usize) {
    let mut hist = ArHistory::new();
    let (mut worst, mut n) = (0.0f64, 0);
    for k in 0..series.len() {
        let (v, q) = (series.v[k] as f32, series.vdot[k] as f32);
        if let (Ok(e), Some(h)) = (model.eval_ar(v, q, &hist), host(k)) {
            worst = worst.max((f64::from(e.p) - h).abs());
            n += 1;
        }
        hist.push(v, q);
    }
    (worst, n)
}

/// The algebra of the module docs: the exported PolyModel (AR form) equals the device-form
/// augmented model's own prediction (Chebyshev basis + L·backward-difference column) on every
/// sample of the log, to float precision.
fn assert_algebra(dm: &DeviceModel, series: &Series) {
    let tol = f32_bound(&dm.model);
    let (worst, n) = max_gap(&dm.model, series, |k| {
        k.checked_sub(dm.first_row).map(|i| dm.refit.pred[i])
    });
    assert_eq!(
        n,
        series.len() - dm.first_row,
        "every sample with a history"
    );
    assert!(
        worst <= tol,
        "AR form vs augmented prediction: {worst:.3e} > {tol:.3e} kPa"
    );
    assert!(
        tol < 1e-3,
        "the bound is far below the sensor noise: {tol:.2e}"
    );
}

#[test]
fn inertance_runs_on_the_device_and_drift_is_named_as_not() {
    let l_true = 1.5e-3;
    let s = synthetic(l_true, 0.6, 21);
    let series = series_of(&s);
    let cfg = Config {
        n: 3,
        m: 2,
        candidates: vec![
            EffectKind(&Inertance),
            EffectKind(&OffsetDrift),
            EffectKind(&Hysteresis),
        ],
        ..Config::default()
    };
    let x = augmented_export(series.clone(), &cfg).expect("export");
    let mut kept: Vec<&str> = x.diagnosis.effects.iter().map(|e| e.name).collect();
    kept.sort_unstable();
    assert_eq!(kept, ["inertance", "offset_drift"], "loop kept {kept:?}");

    // Inertance is carried in the board's chain, with the plant's L to 25 %. This plant's
    // inertance is L times the backward difference of its sampled flow (the AR(1) form, which
    // `device_model` folds, below: L to 2 %); the chain takes v̈ from the volume's cubic, and this
    // plant's volume is point-sampled whole motor steps (0.04 mm³, 150 mm³/s² of v̈ noise at
    // 25 Hz), which pulls the fitted L down: 1.22e-3 here. (On host-sim, whose frames average the
    // steps as the board does, the chain's L is 9 % low and its held-out error within 0.4 % of
    // the loop's: `replay_board`.)
    assert_eq!(x.carried.len(), 1);
    assert_eq!(x.carried[0].name, "inertance");
    let l = x.carried[0].value;
    assert!(
        (l - l_true).abs() < 0.25 * l_true,
        "device L {l:.4e} vs plant {l_true:.4e}"
    );
    // The drift is named with the library's reason.
    assert_eq!(x.dropped.len(), 1);
    assert_eq!(x.dropped[0].name, "offset_drift");
    assert_eq!(
        x.dropped[0].reason,
        EffectKind(&OffsetDrift).device_support().reason
    );
    assert!(!x.nothing_carried());

    // The exported form: the board's chain adds `inertance L`; the polynomial has no AR term.
    let dm = &x.device;
    assert_eq!(dm.model.shape().p, 0);
    let chain: Vec<(&str, f32)> = dm
        .chain
        .effects()
        .iter()
        .map(|e| (e.kind().name(), e.params()[0]))
        .collect();
    assert_eq!(chain, [("inertance", l as f32)]);
    assert!(dm.host.inertance.is_none());
    // The board (the firmware's estimator, replayed) runs the device-form refit.
    let r = x.rmse;
    assert!(
        (r.device - r.device_f64).abs() <= 0.002 * r.device_f64,
        "{r:?}"
    );

    // What is lost: the device cannot follow the drift, the baseline lacks the inertance too.
    let r = x.rmse;
    eprintln!(
        "held-out RMSE: augmented {:.4}, device {:.4} (f64 {:.4}), baseline {:.4}",
        r.augmented, r.device, r.device_f64, r.baseline
    );
    assert!(r.augmented < r.device && r.device < r.baseline, "{r:?}");
    assert!((r.device - r.device_f64).abs() < 1e-4, "{r:?}");
    assert_eq!(r.device_samples, x.diagnosis.samples.1);
}

#[test]
fn device_form_recovers_the_known_plant() {
    // No drift: the device model is the whole plant, so it must predict the noise-free pressure.
    let s = synthetic(1.5e-3, 0.0, 22);
    let series = series_of(&s);
    let dm = device_model(&series, 3, 2, &[EffectKind(&Inertance)]).expect("fit");
    assert_algebra(&dm, &series);
    // L within 4 standard errors of the plant's (the refit's own σ̂²(XᵀX)⁻¹, inertance column
    // last), and that error is small enough for the check to mean something.
    let l = dm.host.inertance.expect("carried");
    let col = dm.refit.fit.beta.len() - 1;
    let se = (dm.refit.fit.sigma2() * dm.refit.fit.xtx_inv[(col, col)]).sqrt();
    assert!((l - 1.5e-3).abs() < 4.0 * se, "L {l:.4e} ± {se:.1e}");
    assert!(se < 0.05 * 1.5e-3, "se {se:.1e}");
    let mut hist = ArHistory::new();
    let mut sse = 0.0;
    for k in 0..series.len() {
        let (v, q) = (series.v[k] as f32, series.vdot[k] as f32);
        if k > 0 {
            let e = dm.model.eval_ar(v, q, &hist).expect("in range");
            sse += (f64::from(e.p) - s.truth_no_drift[k]).powi(2);
        }
        hist.push(v, q);
    }
    let rms = (sse / (series.len() - 1) as f64).sqrt();
    // 13 parameters from 9 000 samples of σ = 0.05 kPa: the error is a small fraction of σ.
    assert!(rms < 0.2 * SIGMA, "device model vs plant: {rms:.4} kPa");
    // Only AR-capable effects can be folded (hysteresis runs in the board's chain instead).
    assert!(device_model(&series, 3, 2, &[EffectKind(&Hysteresis)]).is_err());
}

/// A device-runnable effect written in its own file (here, outside the crate): the host form
/// (one added column, the volume's acceleration as the board computes it) and its device form
/// (the board's `inertance` row of `model_core::spec`). Nothing else is written for it: the
/// export asks the effect for its device form and the table for the rest.
struct LineMass;

impl sysid::residual::EffectModel for LineMass {
    fn name(&self) -> &'static str {
        "line_mass"
    }
    fn story(&self) -> &'static str {
        "The water in a long line has mass, so accelerating the flow takes a pressure."
    }
    fn columns(
        &self,
        _e: &sysid::residual::effects::Effect,
        prep: &sysid::residual::effects::Prepared,
        _v: &[f64],
    ) -> Vec<sysid::residual::effects::Column> {
        let se = &prep.series;
        let acc = causal_acceleration(&se.t, &se.v, &se.vdot);
        vec![sysid::residual::effects::Column::new(
            acc,
            "line mass vddot",
        )]
    }
    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::Inertance)
    }
    fn device_params(
        &self,
        _e: &sysid::residual::effects::Effect,
        coefs: &[f64],
    ) -> Option<Vec<f64>> {
        Some(vec![coefs[0]])
    }
    fn device_support(&self) -> sysid::residual::DeviceSupport {
        sysid::residual::DeviceSupport::on_device("the board's chain adds L·v̈")
    }
}

/// The end slope of the volume's cubic over the last frame (`model_core::chain`'s table:
/// `v̈_k = (−6(v_k − v_{k−1}) + 2Δt v̇_{k−1} + 4Δt v̇_k)/Δt²`, 0 on the first frame), written
/// here from the formula.
fn causal_acceleration(t: &[f64], v: &[f64], f: &[f64]) -> Vec<f64> {
    (0..t.len())
        .map(|k| {
            if k == 0 {
                return 0.0;
            }
            let dt = t[k] - t[k - 1];
            (-6.0 * (v[k] - v[k - 1]) + 2.0 * dt * f[k - 1] + 4.0 * dt * f[k]) / (dt * dt)
        })
        .collect()
}

#[test]
fn a_device_effect_in_its_own_file_reaches_the_board_unchanged() {
    // SBA1 plus L·v̈ (v̈ as the board computes it) plus noise of σ.
    const L: f64 = 1.5e-3;
    let mut s = synthetic(0.0, 0.0, 23);
    let acc = causal_acceleration(&s.t, &s.v, &s.vdot);
    for (p, a) in s.p.iter_mut().zip(&acc) {
        *p += L * a;
    }
    let series = series_of(&s);
    let e = sysid::residual::effects::Effect::new(EffectKind(&LineMass), 0.0);
    let dm = sysid::board::augmented::device_model_with(&series, 3, 2, &[], &[e]).expect("fit");
    // The board's chain carries it as the spec row says: one `inertance` with L.
    let fx = dm.chain.effects();
    assert_eq!(fx.len(), 1);
    assert_eq!(fx[0].kind(), model_core::chain::EffectKind::Inertance);
    let l = f64::from(fx[0].params()[0]);
    assert!((l - L).abs() < 0.05 * L, "L {l:.4e}, planted {L:.1e}");
    // And the firmware's own estimator, running that chain, predicts to the noise.
    let (rmse, n) = sysid::board::augmented::device_rmse(&dm.board_model(), &series);
    eprintln!(
        "line_mass on the board: L {l:.4e} (planted {L:.1e}), RMSE {rmse:.4} kPa over {n} frames"
    );
    assert!(n > 500, "{n} held-out frames");
    assert!(rmse < 1.15 * SIGMA, "board RMSE {rmse:.4} kPa, σ {SIGMA}");
}

/// One short host-sim run of the paper's protocol on SBA1 with `effects`, as a parsed log.
fn host_sim_log(effects: Effects, seed: u64) -> sysid::log::Log {
    let protocol = Protocol {
        cycles: 2,
        flows: vec![20.0, 60.0, 100.0],
        ..Protocol::paper()
    };
    let plant = PlantConfig {
        effects,
        ..PlantConfig::default()
    };
    let mut sc = Scenario::protocol("export-augmented", plant, &protocol);
    sc.seed = seed;
    let run = simulate(&sc).expect("valid scenario");
    let mut csv = Vec::new();
    run.write_log(&mut csv).expect("in memory");
    sysid::log::parse_log(&csv[..], "sim.csv").expect("valid log")
}

#[test]
fn exported_lines_run_on_the_firmware_as_in_sysid() {
    let effects = Effects {
        inertance_kpa_s2_per_mm3: 3.0e-4,
        ..Effects::default()
    };
    let log = host_sim_log(effects.clone(), 5);
    let ds = Dataset::from_log(&log, 0, &DatasetConfig::default()).expect("dataset");
    let series = series_from_dataset(&ds).expect("series");
    let dm = device_model(&series, 3, 2, &[EffectKind(&Inertance)]).expect("fit");
    assert_eq!(dm.model.shape().p, 1);
    assert_algebra(&dm, &series);
    let lines = command_lines(0, &dm.model);

    // The firmware's own command handler installs exactly the exported model.
    let uploads = parse_lines(&lines.join("\n"), "export").expect("lines parse");
    let mut port = FirmwarePort::new();
    let results = deploy(&mut port, &uploads).expect("deploys");
    assert_eq!(
        results[0].readback,
        Readback::Verified { values: 7 + 12 + 2 }
    );
    let installed = port.shared.lock(|s| *s.model(0));
    assert_eq!(installed, dm.model);

    // A simulated board loads the lines over its serial port and runs its estimator while moving;
    // every frame's P̂ equals the host model fed the same frames (previous frame's flow for v̈).
    let mut cmds: Vec<TimedCommand> = vfp::cmd::demo::upload_commands(&lines);
    for (at_s, line) in [
        (1.0, "move 0 400 80"),
        (7.0, "move 0 150 35"),
        (15.0, "move 0 300 100"),
    ] {
        cmds.push(TimedCommand::new(at_s, line));
    }
    let sc = Scenario {
        name: "export-augmented-board".into(),
        duration_s: 20.0,
        commands: cmds,
        plant: PlantConfig {
            effects,
            ..PlantConfig::default()
        },
        ..Scenario::default()
    };
    let run = simulate(&sc).expect("valid scenario");
    let acks = run
        .replies
        .iter()
        .take(lines.len())
        .filter(|r| r.1 == "ok")
        .count();
    assert_eq!(acks, lines.len(), "{:?}", run.replies);
    let tol = f32_bound(&dm.model);
    let (mut worst, mut compared, mut accelerating) = (0.0f64, 0, 0);
    for w in run.frames.windows(2) {
        let (prev, fr): (&Frame, &Frame) = (&w[0], &w[1]);
        if fr.t_us < 800_000 || fr.seq != prev.seq + 1 {
            continue;
        }
        let (c, cp) = (&fr.chambers[0], &prev.chambers[0]);
        let host = dm
            .host
            .predict(f64::from(c.v), f64::from(c.vdot), Some(f64::from(cp.vdot)))
            .expect("inertance model takes the previous flow");
        let d = (f64::from(c.p_hat) - host).abs();
        assert!(
            d <= tol,
            "seq {}: board {} vs host {host} (tol {tol:.2e})",
            fr.seq,
            c.p_hat
        );
        worst = worst.max(d);
        compared += 1;
        if c.vdot != cp.vdot {
            accelerating += 1;
        }
    }
    eprintln!("board vs host: max {worst:.2e} kPa over {compared} frames ({accelerating} with v̈ ≠ 0), bound {tol:.2e}");
    assert!(
        compared > 400 && accelerating > 10,
        "{compared} frames, {accelerating} accelerating"
    );
}

#[test]
fn nothing_runnable_exports_the_refitted_baseline_and_says_so() {
    // A sensor drift in time: tied to the log's clock, the board cannot run it.
    let log = host_sim_log(Effects::preset("thermal-drift").expect("preset"), 6);
    let ds = Dataset::from_log(&log, 0, &DatasetConfig::default()).expect("dataset");
    let series = series_from_dataset(&ds).expect("series");
    let cfg = Config {
        n: 3,
        m: 2,
        candidates: vec![EffectKind(&OffsetDrift)],
        ..Config::default()
    };
    let x = augmented_export(series.clone(), &cfg).expect("export");
    assert_eq!(
        x.diagnosis
            .effects
            .iter()
            .map(|e| e.name)
            .collect::<Vec<_>>(),
        ["offset_drift"]
    );
    assert!(x.nothing_carried());
    assert!(x.carried.is_empty() && x.device.host.inertance.is_none());
    assert_eq!(x.device.model.shape().p, 0);
    // It is the baseline least-squares fit on the training cycles: a second implementation
    // (sysid::poly::fit, same basis scaling) predicts the same to rounding.
    let sc = x.device.host.basis.scaling;
    let other = sysid::poly::fit(sysid::poly::Xy::from(&ds.train()), 3, 2, Some(sc)).expect("fit");
    for k in (0..series.len()).step_by(7) {
        let mine = x
            .device
            .host
            .predict(series.v[k], series.vdot[k], None)
            .unwrap();
        let theirs = other.predict(series.v[k], series.vdot[k]);
        assert!(
            (mine - theirs).abs() < 1e-8 * (1.0 + theirs.abs()),
            "{k}: {mine} vs {theirs}"
        );
    }
    let r = x.rmse;
    assert!((r.device - r.baseline).abs() < 1e-4, "{r:?}");
    assert!(r.augmented < r.baseline, "{r:?}");
}

fn write_csv(s: &Synthetic, name: &str) -> std::path::PathBuf {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("vfp-export-aug-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("log.csv");
    let mut log = sysid::log::Log::default();
    log.set_metadata("sample_rate_hz", "25");
    for k in 0..s.t.len() {
        let mut smp = sysid::log::Sample::new(s.t[k], 0, s.v[k], s.p[k]);
        smp.flow_mm3_s = Some(s.vdot[k]);
        log.push(smp);
    }
    sysid::log::write_log(&path, &log).unwrap();
    path
}

fn vfp(args: &[&str]) -> (bool, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vfp"))
        .arg("--quiet")
        .args(args)
        .output()
        .unwrap();
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn cli_exports_the_augmented_model_and_states_what_is_lost() {
    let s = synthetic(1.5e-3, 0.6, 23);
    let path = write_csv(&s, "cli");
    let log = path.to_str().unwrap();
    let common = [
        "export",
        log,
        "--augmented",
        "--n",
        "3",
        "--m",
        "2",
        "--format",
        "lines",
    ];
    let (ok, out, err) = vfp(&[
        &common[..],
        &["--effect", "inertance", "--effect", "offset-drift"],
    ]
    .concat());
    assert!(ok, "{err}");
    eprintln!("{out}");
    assert!(out.contains("// the residual loop kept: "), "{out}");
    assert!(out.contains("// on the device: inertance = "), "{out}");
    assert!(
        out.contains("// NOT on the device: offset_drift (depends on wall-clock time"),
        "{out}"
    );
    let rmse_line = out
        .lines()
        .find(|l| l.starts_with("// held-out RMSE: "))
        .expect("RMSE line");
    for part in [
        "(a) full augmented model",
        "(b) exported model as the device evaluates it",
        "(c) baseline",
    ] {
        assert!(rmse_line.contains(part), "{rmse_line}");
    }
    assert!(
        err.contains("NOT on the device: offset_drift"),
        "stderr: {err}"
    );
    // `vfp deploy` reads the output as it is (comments skipped) into the firmware: shape and
    // scaling, 12 coefficients, the chain effect (its kind and L).
    let ups = parse_lines(&out, "stdout").expect("deployable");
    assert_eq!((ups.len(), ups[0].shape), (1, [3, 2, 0]));
    let r = deploy(&mut FirmwarePort::new(), &ups).expect("deploys");
    assert_eq!(r[0].readback, Readback::Verified { values: 7 + 12 + 2 });

    // Only an effect the device cannot run: said plainly, the refitted baseline exported.
    let (ok, out, err) = vfp(&[&common[..], &["--effect", "offset-drift"]].concat());
    assert!(ok, "{err}");
    assert!(out.contains("// NONE of the kept effects can run on the device: the exported model is the baseline polynomial refitted"), "{out}");
    assert!(err.contains("NONE of the kept effects"), "{err}");
    assert_eq!(parse_lines(&out, "stdout").unwrap()[0].shape, [3, 2, 0]);

    // Bad combinations: one clear sentence, non-zero exit.
    let (ok, _, err) = vfp(&["export", log, "--augmented", "--p", "2"]);
    assert!(
        !ok && err.contains("--p 2: the augmented export chooses its own AR terms"),
        "{err}"
    );
    let (ok, _, err) = vfp(&["export", log, "--augmented", "--holdout-every", "0"]);
    assert!(!ok && err.contains("needs held-out cycles"), "{err}");
    let (ok, _, err) = vfp(&["export", log, "--effect", "inertance"]);
    assert!(!ok && err.contains("--augmented"), "{err}");
}
