//! The polynomial's selection on logs of other rigs (`host_sim::breath_logs`): operating-point
//! steps, changing rates, varied breaths, 100–512 Hz, laws of known flow degree.

use sysid::dataset::{Dataset, DatasetConfig};
use sysid::identify::{self, ChamberReport, Family, Options};
use sysid::select;

fn poly_only(ds: &Dataset) -> ChamberReport {
    identify::identify(
        ds,
        &Options {
            families: vec![Family::Poly],
            prune_k: 0,
            ..Options::default()
        },
    )
}

fn dataset(log: &host_sim::breath_logs::BreathLog) -> Dataset {
    let mut csv = Vec::new();
    log.write_log(&mut csv).unwrap();
    let parsed = sysid::log::parse_log(&csv[..], &format!("{}.csv", log.name)).unwrap();
    Dataset::from_log(&parsed, 0, &DatasetConfig::default()).unwrap()
}

/// What the selection made of one log: the selected shape, the reduced model's parameters and
/// held-out RMSE (what `vfp export` exports), the sweep's best held-out RMSE and its shape, and
/// the held-out RMSE of the shape with the lowest typical cross-validated error (the best the
/// training cycles can point to).
struct Outcome {
    shape: (usize, usize),
    nu: usize,
    heldout: f64,
    best: f64,
    best_shape: (usize, usize),
    cv_best_heldout: f64,
}

fn outcome(rep: &ChamberReport) -> Outcome {
    let sel = rep.poly_selection.as_ref().expect("a selection");
    let red = sel.reduced.as_ref().expect("a reduction");
    let rows = || rep.models.iter().filter(|r| r.family == Family::Poly);
    let best = rows()
        .filter(|r| r.rmse_heldout.is_some())
        .min_by(|a, b| a.rmse_heldout.unwrap().total_cmp(&b.rmse_heldout.unwrap()))
        .unwrap();
    let cv_best = rows()
        .find(|r| r.n == Some(sel.cv_best.n) && r.m == Some(sel.cv_best.m))
        .unwrap();
    Outcome {
        shape: (sel.selected.n, sel.selected.m),
        nu: red.nu,
        heldout: red.rmse_heldout.unwrap(),
        best: best.rmse_heldout.unwrap(),
        best_shape: (best.n.unwrap(), best.m.unwrap()),
        cv_best_heldout: cv_best.rmse_heldout.unwrap(),
    }
}

/// The generated logs of `host_sim::breath_logs::suite` for seeds 1 to 4, as `vfp` reads them.
fn generated() -> Vec<(String, Dataset)> {
    (1..=4)
        .flat_map(|seed| {
            host_sim::breath_logs::suite(seed)
                .into_iter()
                .map(move |log| (format!("{} seed {seed}", log.name), dataset(&log)))
        })
        .collect()
}

/// Issue 35's acceptance on logs whose operating point moves, whose rate changes and whose
/// breaths differ (20 logs, 100–512 Hz, known laws): at most 40 parameters everywhere; within
/// 15 % of the sweep's best held-out RMSE on at least 16 of 20, and of the held-out RMSE of the
/// shape the training cycles rank best on at least 18 of 20; below twice the sweep's best
/// wherever the training cycles' best shape is itself within 1.5 times it (on one log, seed 1's
/// step-ramp-varied-turbulent, the held-out and the training cycles disagree: the shape best on
/// the training cycles is 1.96 times the sweep's best on the held-out ones, and no rule on the
/// training cycles can follow). Before issue 35 the pooled rule took (2, 3) on seed 2's
/// varied-breaths log at 4.7 times the sweep's best held-out RMSE.
///
/// `cargo test --release -p sysid --test all selection_other_rigs:: -- --nocapture` prints the
/// table of the user guide.
#[test]
fn a_baseline_that_holds_on_logs_of_other_rigs() {
    let logs = generated();
    assert_eq!(logs.len(), 20);
    let mut ratios = Vec::new();
    for (name, ds) in &logs {
        let o = outcome(&poly_only(ds));
        let ratio = o.heldout / o.best;
        eprintln!(
            "{name}: ({}, {}) with {} terms, held-out {:.4} kPa, sweep's best {:?} {:.4} kPa, \
             ratio {ratio:.3}; to the typical cross-validated best's held-out {:.3}",
            o.shape.0,
            o.shape.1,
            o.nu,
            o.heldout,
            o.best_shape,
            o.best,
            o.heldout / o.cv_best_heldout
        );
        assert!(o.nu <= select::MAX_PARAMS, "{name}: {} terms", o.nu);
        if o.cv_best_heldout <= 1.5 * o.best {
            assert!(ratio < 2.0, "{name}: ratio {ratio:.3}");
        }
        ratios.push((ratio, o.heldout / o.cv_best_heldout));
    }
    let within = ratios.iter().filter(|r| r.0 <= 1.15).count();
    let within_cv = ratios.iter().filter(|r| r.1 <= 1.15).count();
    eprintln!("within 15 % of the sweep's best: {within} of 20; of the cross-validated best's: {within_cv} of 20");
    assert!(within >= 16, "{within} of 20 within 15 %");
    assert!(within_cv >= 18, "{within_cv} of 20 within 15 %");
}

/// The rule on heterogeneous blocks, by hand: a small shape three times worse than a large one on
/// every block but one, where the large one extrapolates (an extreme breath). Pooled, that one
/// block decides and the small shape is "best"; on log ratios every block counts once, the large
/// shape ranks first and the small one is outside its band.
#[test]
fn one_extreme_block_does_not_open_the_band() {
    // Nine blocks of 100 samples: the small shape's error is 3e-3 everywhere, the large one's 1e-3
    // except on block 4, where it extrapolates to 0.1 and the small one errs 0.02.
    let n = vec![100usize; 9];
    let small: Vec<f64> = (0..9).map(|b| if b == 4 { 2.0 } else { 0.3 }).collect();
    let large: Vec<f64> = (0..9).map(|b| if b == 4 { 10.0 } else { 0.1 }).collect();
    let score = |nm: (usize, usize), sse: &[f64]| {
        let mse = sse.iter().sum::<f64>() / 900.0;
        let typical = (sse.iter().map(|e| (e / 100.0).ln()).sum::<f64>() / 9.0).exp();
        select::CvScore {
            n: nm.0,
            m: nm.1,
            nu: (nm.0 + 1) * (nm.1 + 1),
            mse,
            se: 0.0,
            admissible: true,
            typical_mse: typical,
            floor: 0.0,
            log_ratios: true,
            block_sse: sse.to_vec(),
            block_n: n.clone(),
        }
    };
    let (a, b) = (score((1, 1), &small), score((5, 5), &large));
    // Pooled: ē = 4.9e-3 against 1.2e-2, so the small shape is the pooled best; hand-computed
    // log ratio of the small to the large: (8 ln 3 + ln 0.2) / 9 = 0.798, every block but one at
    // ln 3.
    assert!(a.mse < b.mse);
    let (d, se) = select::paired_log_ratio(&a, &b);
    assert!(
        (d - (8.0 * 3f64.ln() + 0.2f64.ln()) / 9.0).abs() < 1e-6,
        "{d}"
    );
    let expected_sd = {
        let x: Vec<f64> = (0..9)
            .map(|k| if k == 4 { 0.2f64.ln() } else { 3f64.ln() })
            .collect();
        (x.iter().map(|v| (v - d).powi(2)).sum::<f64>() / 8.0 / 9.0).sqrt()
    };
    assert!((se - expected_sd).abs() < 1e-9);
    // The typical error ranks the large shape first and the small one is outside its band.
    assert_eq!(
        select::lowest(&[a.clone(), b.clone()]).map(|s| s.nu),
        Some(36)
    );
    assert_eq!(select::one_se_rule(&[a, b]).map(|s| s.nu), Some(36));
}
