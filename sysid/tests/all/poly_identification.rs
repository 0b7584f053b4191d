//! The polynomial family against a known plant: simulated logs from the paper's SBA1 law
//! (Table IV) plus Gaussian noise of known σ.

use sysid::dataset::{Dataset, DatasetConfig};
use sysid::poly::{self, PolyError, Scaling, Xy};
use sysid::synth::{self, Protocol, SBA1_RAW};

const SIGMA: f64 = 0.5;

fn sba1_dataset(samples: usize, seed: u64) -> Dataset {
    let tr = Protocol {
        samples,
        ..Protocol::default()
    }
    .trajectory();
    let p = synth::pressure(&SBA1_RAW, 3, 2, &tr, SIGMA, seed);
    Dataset::from_columns(tr.t, tr.v, tr.vdot, p, &DatasetConfig::default())
}

#[test]
fn recovers_known_coefficients_within_three_standard_errors() {
    let ds = sba1_dataset(83_000, 7);
    let train = ds.train();
    let fit = poly::fit(Xy::from(&train), 3, 2, None).unwrap();
    for (k, (est, truth)) in fit.raw.iter().zip(SBA1_RAW).enumerate() {
        let z = (est.estimate - truth) / est.se;
        assert!(
            z.abs() < 3.0,
            "term {}: {} vs {} (SE {}, z {z})",
            fit.term_names()[k],
            est.estimate,
            truth,
            est.se
        );
    }
    // σ̂ estimates the noise.
    assert!((fit.sigma2.sqrt() / SIGMA - 1.0).abs() < 0.02);
}

#[test]
fn heldout_rmse_is_the_noise_level() {
    let ds = sba1_dataset(83_000, 11);
    assert!(ds.n_cycles >= 50, "protocol has {} cycles", ds.n_cycles);
    let (train, held) = (ds.train(), ds.heldout());
    assert!(
        held.len() > 10_000,
        "{} held out of {}",
        held.len(),
        ds.len()
    );
    let fit = poly::fit(Xy::from(&train), 3, 2, None).unwrap();
    let pred = fit.predict_all(&held.v, &held.vdot);
    let m = sysid::metrics::compute(&held.p, &pred, fit.nu).unwrap();
    assert!(
        (m.rmse / SIGMA - 1.0).abs() < 0.02,
        "held-out RMSE {} vs σ {SIGMA}",
        m.rmse
    );
}

#[test]
fn sweep_is_nested_monotone_and_matches_single_fits() {
    let ds = sba1_dataset(20_000, 3);
    let (train, held) = (ds.train(), ds.heldout());
    let all = ds.all();
    let scaling = Scaling::from_data(&all.v, &all.vdot).unwrap();
    let entries = poly::sweep(Xy::from(&train), Some(Xy::from(&held)), &scaling, 7, 7).unwrap();
    assert_eq!(entries.len(), 49);
    let rmse = |n: usize, m: usize| entries[(n - 1) * 7 + (m - 1)].as_ref().unwrap().train.rmse;
    for n in 1..=7 {
        for m in 1..=7 {
            let e = entries[(n - 1) * 7 + (m - 1)].as_ref().unwrap();
            assert_eq!((e.n, e.m, e.nu), (n, m, (n + 1) * (m + 1)));
            assert!(e.heldout.is_some());
            // Adding terms never raises the in-sample error (exact least squares on nested spaces).
            if n < 7 {
                assert!(
                    rmse(n + 1, m) <= rmse(n, m) * (1.0 + 1e-12),
                    "({n},{m}) → ({},{m})",
                    n + 1
                );
            }
            if m < 7 {
                assert!(
                    rmse(n, m + 1) <= rmse(n, m) * (1.0 + 1e-12),
                    "({n},{m}) → ({n},{})",
                    m + 1
                );
            }
        }
    }
    // The moment sweep and the QR fit are the same least-squares problem.
    let e = entries[2 * 7 + 1].as_ref().unwrap();
    let f = poly::fit(Xy::from(&train), 3, 2, Some(scaling)).unwrap();
    assert!(
        (e.train.rmse / f.train.rmse - 1.0).abs() < 1e-9,
        "{} vs {}",
        e.train.rmse,
        f.train.rmse
    );
    // Below the true degree the fit is clearly worse; at it, the error is the noise.
    assert!(rmse(2, 2) > 1.5 * SIGMA);
    assert!((rmse(3, 2) / SIGMA - 1.0).abs() < 0.03);
}

#[test]
fn chebyshev_power_and_raw_forms_agree() {
    let ds = sba1_dataset(10_000, 5);
    let all = ds.all();
    let f = poly::fit(Xy::from(&all), 3, 2, None).unwrap();
    let raw: Vec<f64> = f.raw.iter().map(|s| s.estimate).collect();
    for (v, q) in [(0.0, 0.0), (275.0, 50.0), (550.0, -100.0), (100.0, 20.0)] {
        let a = f.predict(v, q);
        let b = synth::eval_raw(&raw, 3, 2, v, q);
        assert!(
            (a - b).abs() < 1e-9 * (1.0 + a.abs()),
            "({v},{q}): {a} vs {b}"
        );
    }
}

#[test]
fn partials_match_finite_differences() {
    let ds = sba1_dataset(10_000, 9);
    let all = ds.all();
    let f = poly::fit(Xy::from(&all), 3, 2, None).unwrap();
    for (v, q) in [(50.0, 10.0), (300.0, -60.0), (500.0, 90.0)] {
        let (k, c) = f.partials(v, q);
        let h = 1e-3;
        let kf = (f.predict(v + h, q) - f.predict(v - h, q)) / (2.0 * h);
        let cf = (f.predict(v, q + h) - f.predict(v, q - h)) / (2.0 * h);
        assert!((k - kf).abs() < 1e-6 * (1.0 + k.abs()) && (c - cf).abs() < 1e-6 * (1.0 + c.abs()));
    }
}

#[test]
fn pruning_refits_without_the_least_significant_terms() {
    // Truth without the v·v̇ term: pruning must name it among the least significant, and dropping
    // it costs (almost) nothing while dropping a real term costs a lot.
    let mut raw = SBA1_RAW;
    raw[4] = 0.0;
    let tr = Protocol {
        samples: 30_000,
        ..Protocol::default()
    }
    .trajectory();
    let p = synth::pressure(&raw, 3, 2, &tr, SIGMA, 21);
    let xy = Xy {
        v: &tr.v,
        vdot: &tr.vdot,
        p: &p,
    };
    let rows = poly::prune(xy, None, 3, 2, 3).unwrap();
    let full = poly::fit_terms(xy, 3, 2, &[true; 12]).unwrap();
    assert_eq!(rows.len(), 6, "3 singles and 3 pairs as in Table IV");
    let single = rows
        .iter()
        .find(|r| r.excluded == ["v vdot"])
        .expect("v vdot is among the 3 least significant");
    assert!(single.train.rmse <= full.train.rmse * 1.001);
    let bad = poly::fit_terms(
        xy,
        3,
        2,
        &[
            true, true, true, false, true, true, true, true, true, true, true, true,
        ],
    )
    .unwrap();
    assert!(
        bad.train.rmse > 1.05 * full.train.rmse,
        "dropping v: {} vs full {} (dropping v vdot: {})",
        bad.train.rmse,
        full.train.rmse,
        single.train.rmse
    );
    for r in &rows {
        assert!(
            r.train.rmse >= full.train.rmse * (1.0 - 1e-9),
            "a refit on fewer terms cannot fit better"
        );
    }
}

#[test]
fn degenerate_inputs_are_clear_errors() {
    let v = vec![100.0; 50];
    let q: Vec<f64> = (0..50).map(|i| (i as f64).sin()).collect();
    let p = vec![1.0; 50];
    assert!(matches!(
        poly::fit(
            Xy {
                v: &v,
                vdot: &q,
                p: &p
            },
            3,
            2,
            None
        ),
        Err(PolyError::ConstantVolume { .. })
    ));
    let v2: Vec<f64> = (0..50).map(|i| i as f64).collect();
    let zero = vec![0.0; 50];
    assert_eq!(
        poly::fit(
            Xy {
                v: &v2,
                vdot: &zero,
                p: &p
            },
            3,
            2,
            None
        ),
        Err(PolyError::ZeroFlow)
    );
    let mut pn = p.clone();
    pn[7] = f64::NAN;
    assert_eq!(
        poly::fit(
            Xy {
                v: &v2,
                vdot: &q,
                p: &pn
            },
            3,
            2,
            None
        ),
        Err(PolyError::NotFinite {
            column: "pressure",
            index: 7
        })
    );
    // 10 samples, 12 parameters.
    let r = poly::fit(
        Xy {
            v: &v2[..10],
            vdot: &q[..10],
            p: &p[..10],
        },
        3,
        2,
        None,
    );
    assert!(
        matches!(
            r,
            Err(PolyError::Fit {
                source: sysid::linreg::FitError::TooFewSamples { .. },
                ..
            })
        ),
        "{r:?}"
    );
    let s = Scaling::from_data(&v2[..10], &q[..10]).unwrap();
    let e = poly::sweep(
        Xy {
            v: &v2[..10],
            vdot: &q[..10],
            p: &p[..10],
        },
        None,
        &s,
        7,
        7,
    )
    .unwrap();
    assert!(e[0].is_ok() && e.iter().filter(|r| r.is_err()).count() > 40);
    // Every error message is a sentence, never NaN.
    let msg = poly::fit(
        Xy {
            v: &v2,
            vdot: &zero,
            p: &p,
        },
        3,
        2,
        None,
    )
    .unwrap_err()
    .to_string();
    assert!(msg.contains("flow is zero everywhere"));
}
