#![allow(clippy::needless_range_loop)] // index loops mirror the basis formulas
//! `vfp export` round trip through the firmware's own command parser and model-core, and the
//! `vfp identify --json` document on a simulated log.

use firmware::command::{parse, Command, ModelCmd};
use model_core::poly::{PolyModel, Scaling, Shape};
use sysid::board::export::{command_lines, rust_constants};
use sysid::dataset::{Dataset, DatasetConfig};
use sysid::log::{write_log, Log, Sample};
use sysid::poly::{self, Xy};
use sysid::synth::{self, Protocol, SBA1_RAW};

/// Rebuilds a model from command lines the way the device does: parse, stage, commit.
fn load(lines: &[String]) -> PolyModel {
    let (mut shape, mut scaling, mut coef, mut ar) = (None, None, vec![], vec![]);
    for l in lines {
        match parse(l.as_bytes()).unwrap_or_else(|e| panic!("{l}: {e:?}")) {
            Command::Model { cmd, .. } => match cmd {
                ModelCmd::Begin {
                    n,
                    m,
                    p,
                    scaling: s,
                } => {
                    shape = Some(Shape::new(n, m, p).unwrap());
                    scaling = Some(Scaling::new(s[0], s[1], s[2], s[3]).unwrap());
                    coef = vec![f32::NAN; (n as usize + 1) * (m as usize + 1)];
                    ar = vec![f32::NAN; 2 * p as usize];
                }
                ModelCmd::Coef { start, values } => {
                    coef[start as usize..][..values.len()].copy_from_slice(&values)
                }
                ModelCmd::Ar { start, values } => {
                    ar[start as usize..][..values.len()].copy_from_slice(&values)
                }
                ModelCmd::Commit => {}
                other => panic!("unexpected {other:?}"),
            },
            other => panic!("unexpected {other:?}"),
        }
    }
    let pairs: Vec<[f32; 2]> = ar.chunks(2).map(|c| [c[0], c[1]]).collect();
    PolyModel::from_scaled(shape.unwrap(), &coef, &pairs, scaling.unwrap()).unwrap()
}

#[test]
fn exported_lines_reproduce_the_fitted_model_on_the_device() {
    let tr = Protocol {
        samples: 20_000,
        ..Protocol::default()
    }
    .trajectory();
    let p = synth::pressure(&SBA1_RAW, 3, 2, &tr, 0.3, 4);
    let fit = poly::fit(
        Xy {
            v: &tr.v,
            vdot: &tr.vdot,
            p: &p,
        },
        3,
        2,
        None,
    )
    .unwrap();
    let lines = command_lines(1, &fit.to_model_core().unwrap());
    assert!(lines[0].starts_with("model 1 begin 3 2 0 "));
    assert_eq!(lines.last().unwrap(), "model 1 commit");
    let dev = load(&lines);
    for (v, q) in [
        (0.0, 0.0),
        (100.0, 20.0),
        (275.0, -60.0),
        (540.0, 100.0),
        (400.0, -100.0),
    ] {
        let host = fit.predict(v, q);
        let e = dev.eval(v as f32, q as f32).unwrap();
        // f32 storage and evaluation: agreement to f32 precision of the ~50 kPa scale.
        assert!(
            (e.p as f64 - host).abs() < 1e-4 * (1.0 + host.abs()),
            "({v},{q}): device {} host {host}",
            e.p
        );
        let (k, c) = fit.partials(v, q);
        assert!(
            (e.k as f64 - k).abs() < 1e-4 * (1.0 + k.abs())
                && (e.c as f64 - c).abs() < 1e-4 * (1.0 + c.abs())
        );
    }
    let rust = rust_constants(1, &dev, "test");
    assert!(rust.contains("pub const CH1_COEF: [f32; 12] = ["));
}

#[test]
fn exported_ar_model_round_trips() {
    let tr = Protocol {
        samples: 8_000,
        ..Protocol::default()
    }
    .trajectory();
    let mut p = synth::pressure(&SBA1_RAW, 3, 2, &tr, 0.3, 8);
    // A lag effect the AR terms can pick up.
    for i in (1..p.len()).rev() {
        p[i] += 0.002 * tr.v[i - 1];
    }
    let ds = Dataset::from_columns(
        tr.t,
        tr.v,
        tr.vdot,
        p,
        &DatasetConfig {
            holdout_every: 0,
            ..Default::default()
        },
    );
    let all = ds.all();
    let sc = poly::Scaling::from_data(&all.v, &all.vdot).unwrap();
    let fits = sysid::polyar::sweep(&ds, 3, 2, 2, &sc).unwrap();
    let fit = fits[2].as_ref().unwrap();
    let dev = load(&command_lines(0, &fit.to_model_core().unwrap()));
    assert_eq!(dev.shape().p, 2);
    let mut hist = model_core::poly::ArHistory::new();
    let base = (fit.n + 1) * (fit.m + 1);
    for i in 0..200 {
        if i >= 2 {
            // Host prediction from the fitted design: Chebyshev part plus scaled lags.
            let (x, y) = sc.apply(ds.v[i], ds.vdot[i]);
            let (mut tx, mut ty) = ([0.0; 4], [0.0; 3]);
            poly::chebyshev(x, &mut tx);
            poly::chebyshev(y, &mut ty);
            let mut host = 0.0;
            for a in 0..4 {
                for b in 0..3 {
                    host += fit.coef[a * 3 + b] * tx[a] * ty[b];
                }
            }
            for k in 1..=2 {
                let (xl, yl) = sc.apply(ds.v[i - k], ds.vdot[i - k]);
                host += fit.coef[base + 2 * (k - 1)] * xl + fit.coef[base + 2 * (k - 1) + 1] * yl;
            }
            let e = dev
                .eval_ar(ds.v[i] as f32, ds.vdot[i] as f32, &hist)
                .unwrap();
            assert!(
                (e.p as f64 - host).abs() < 1e-3 * (1.0 + host.abs()),
                "sample {i}: {} vs {host}",
                e.p
            );
        }
        hist.push(ds.v[i] as f32, ds.vdot[i] as f32);
    }
}

#[test]
fn identify_json_has_the_documented_fields() {
    let dir = std::path::Path::new(env!("CARGO_TARGET_TMPDIR"))
        .join(format!("vfp-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("sim.csv");
    let tr = Protocol {
        samples: 12_000,
        ..Protocol::default()
    }
    .trajectory();
    let p = synth::pressure(&SBA1_RAW, 3, 2, &tr, 0.5, 2);
    let mut log = Log::default();
    log.set_metadata("sample_rate_hz", "25");
    for i in 0..tr.t.len() {
        let mut s = Sample::new(tr.t[i], 0, tr.v[i], p[i]);
        s.flow_mm3_s = Some(tr.vdot[i]);
        log.push(s);
    }
    write_log(&path, &log).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vfp"))
        .args([
            "--quiet",
            "identify",
            path.to_str().unwrap(),
            "--json",
            "--family",
            "poly",
            "--family",
            "poly-ar",
        ])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let doc: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let sel = &doc["selected"];
    assert!(sel["family"].is_string() && sel["rmse"].is_f64() && sel["rmse_heldout"].is_f64());
    let models = doc["models"].as_array().unwrap();
    assert_eq!(models.iter().filter(|m| m["family"] == "poly").count(), 49);
    assert_eq!(
        models.iter().filter(|m| m["family"] == "poly-ar").count(),
        6
    );
    for k in ["nu", "rmse", "r2_adj", "aicc", "bic", "rmse_heldout"] {
        assert!(models[0][k].is_number(), "{k}");
    }
    assert!(doc["timing_s"]["poly"].is_f64() && doc["timing_s"]["poly-ar"].is_f64());
    // The known law is (3, 2): the selection is at least that rich and fits to the noise.
    assert!(sel["rmse"].as_f64().unwrap() < 0.52);

    // Bad input: one clear sentence, non-zero exit, no panic.
    std::fs::write(
        &path,
        "time_s,volume_mm3,pressure_kpa\n0,1,2\n0.04,oops,3\n",
    )
    .unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_vfp"))
        .args(["--quiet", "identify", path.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("sim.csv:3: column `volume_mm3`"), "{err}");
    assert!(!err.contains("panicked"));
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn export_warns_when_f32_cannot_carry_the_polynomial() {
    const ACCEL: f64 = 1000.0;
    use sysid::board::export::{f32_loss, f32_warning, model_for};
    // Fast ramps: the flow dwells on seven levels (0, ±20, ±60, ±100 mm³/s), so degree 7 in v̇
    // is barely determined and its coefficients cancel.
    let tr = Protocol {
        rates: vec![20.0, 60.0, 100.0],
        accel: ACCEL,
        samples: 9_000,
        ..Protocol::default()
    }
    .trajectory();
    let p = synth::pressure(&SBA1_RAW, 3, 2, &tr, 0.05, 5);
    let ds = Dataset::from_columns(tr.t, tr.v, tr.vdot, p, &DatasetConfig::default());
    let mut losses = Vec::new();
    for (n, m) in [(3, 2), (7, 7)] {
        let e = model_for(&ds, Some(n), Some(m), 0, false).unwrap();
        let loss = f32_loss(&e, &ds.v, &ds.vdot, &ds.p);
        // The same loss measured independently (the firmware's own command handler and model).
        let (direct, _) = device_loss(&ds, n, m);
        assert_eq!(loss.samples, ds.len());
        assert!(
            (loss.rms - direct).abs() <= 0.05 * direct + 1e-6,
            "({n}, {m}): {} vs {direct}",
            loss.rms
        );
        eprintln!(
            "({n}, {m}): f32 loss {:.2e} kPa, model RMSE {:.4} kPa",
            loss.rms, loss.model_rmse
        );
        losses.push((loss, f32_warning(&e, &ds)));
    }
    // The paper's shape fits in f32 to far below the noise; a warning would be a false alarm.
    assert!(
        losses[0].0.rms < 1e-4 && losses[0].1.is_none(),
        "{losses:?}"
    );
    // (7, 7) loses on the device more than its whole fit error above the noise (measured two
    // ways, above), and the export says so.
    let (l77, w77) = &losses[1];
    assert!(l77.rms > 0.5 * l77.model_rmse, "{losses:?}");
    assert!(
        w77.as_deref()
            .is_some_and(|w| w.starts_with("WARNING: f32 evaluation")),
        "{losses:?}"
    );
}

/// The f32 loss of shape (n, m) on `ds` measured independently of `sysid::board::export::f32_loss`: the
/// model as the firmware's command handler installs it, evaluated along the log, against sysid's
/// own f64 evaluation of the fit (Chebyshev basis). Returns (loss RMS, the fit's RMSE), kPa.
fn device_loss(ds: &Dataset, n: usize, m: usize) -> (f64, f64) {
    use sysid::board::deploy::{deploy, parse_lines, FirmwarePort};
    let e = sysid::board::export::model_for(ds, Some(n), Some(m), 0, false).unwrap();
    let fit = poly::fit(Xy::from(&ds.train()), n, m, Some(e.scaling)).unwrap();
    let ups = parse_lines(&command_lines(0, &e.model).join("\n"), "x").unwrap();
    let mut port = FirmwarePort::new();
    deploy(&mut port, &ups).unwrap();
    let dev = port.shared.lock(|s| *s.model(0));
    let (mut d2, mut e2) = (0.0, 0.0);
    for k in 0..ds.len() {
        let host = fit.predict(ds.v[k], ds.vdot[k]);
        let got = dev.eval(ds.v[k] as f32, ds.vdot[k] as f32).unwrap().p;
        d2 += (f64::from(got) - host).powi(2);
        e2 += (ds.p[k] - host).powi(2);
    }
    let len = ds.len() as f64;
    ((d2 / len).sqrt(), (e2 / len).sqrt())
}

/// Whether the device carries (n, m) on `ds`: its loss at most the export's limit of its fit error.
fn carried(ds: &Dataset, n: usize, m: usize) -> bool {
    let (loss, rmse) = device_loss(ds, n, m);
    loss <= sysid::board::export::F32_LOSS_LIMIT * rmse
}

/// The fast-ramp synthetic log of `export_warns_when_f32_cannot_carry_the_polynomial`: (7, 7)'s
/// coefficients cancel beyond f32 there, the paper's (3, 2) is carried.
fn fast_ramps() -> Dataset {
    let fast = Protocol {
        rates: vec![20.0, 60.0, 100.0],
        accel: 1000.0,
        samples: 9_000,
        ..Protocol::default()
    }
    .trajectory();
    let p = synth::pressure(&SBA1_RAW, 3, 2, &fast, 0.05, 5);
    Dataset::from_columns(fast.t, fast.v, fast.vdot, p, &DatasetConfig::default())
}

/// A shape the device cannot carry is passed over for the next in the order, and the one passed
/// over is named with its loss (checked against the device's own evaluation).
#[test]
fn export_passes_over_shapes_f32_cannot_carry() {
    let ds = fast_ramps();
    assert!(!carried(&ds, 7, 7) && carried(&ds, 3, 2));
    let all = ds.all();
    let sc = sysid::poly::Scaling::from_data(&all.v, &all.vdot).unwrap();
    let (e, over) =
        sysid::board::export::first_carried(&ds, &[(7, 7), (3, 2)], 0, false, sc).unwrap();
    let sh = e.model.shape();
    assert_eq!((sh.n, sh.m), (3, 2));
    let (n0, m0, l0) = over.expect("(7, 7) passed over");
    assert_eq!((n0, m0), (7, 7));
    let (direct, _) = device_loss(&ds, 7, 7);
    assert!(
        (l0.rms - direct).abs() <= 0.05 * direct,
        "{l0:?} vs {direct}"
    );
    // Nothing to pass over when the first is carried.
    let (e, over) =
        sysid::board::export::first_carried(&ds, &[(3, 2), (7, 7)], 0, false, sc).unwrap();
    assert!(over.is_none() && e.model.shape().m == 2);
}

/// With no --n/--m, export tries the shapes in the selection's order (`sysid::select::ranked`: the
/// one-SE choice first) and exports the first the device carries (judged here by the device's own
/// evaluation); the provenance names the selection's choice when it was passed over.
#[test]
fn default_export_follows_the_selection_order() {
    let protocol = host_sim::Protocol {
        cycles: 2,
        flows: vec![20.0, 60.0, 100.0],
        ..host_sim::Protocol::paper()
    };
    let run = host_sim::simulate(&host_sim::Scenario::protocol(
        "export-default",
        host_sim::PlantConfig::default(),
        &protocol,
    ))
    .unwrap();
    let mut csv = Vec::new();
    run.write_log(&mut csv).unwrap();
    let log = sysid::log::parse_log(&csv[..], "sim.csv").unwrap();
    let sim = Dataset::from_log(&log, 0, &DatasetConfig::default()).unwrap();
    for ds in [&sim, &fast_ramps()] {
        let all = ds.all();
        let sc = sysid::poly::Scaling::from_data(&all.v, &all.vdot).unwrap();
        let (_, scores) = sysid::select::cross_validate(ds, &sc, 7, 7).unwrap();
        let ok: Vec<_> = scores.into_iter().flatten().collect();
        let order: Vec<_> = sysid::select::ranked(&ok)
            .iter()
            .map(|s| (s.n, s.m))
            .collect();
        assert_eq!(Some(order[0]), sysid::select::poly_shape(ds));
        let expected = *order
            .iter()
            .find(|&&(n, m)| carried(ds, n, m))
            .expect("a carried shape");
        let e = sysid::board::export::model_for(ds, None, None, 0, false).unwrap();
        let sh = e.model.shape();
        assert_eq!((usize::from(sh.n), usize::from(sh.m)), expected);
        assert_eq!(
            e.prov.contains("passed over"),
            expected != order[0],
            "{}",
            e.prov
        );
        eprintln!("order starts {:?}, exported {expected:?}", &order[..3]);
    }
}
