//! Parsimonious selection of the polynomial's shape ([`sysid::select`]), the pruning table from
//! one factorisation ([`sysid::poly::prune`]) and cycles on noisy flow ([`sysid::cycles`]),
//! against known truth: synthetic plants of known order and noise, direct refits, and breaths of
//! known count.

use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::path::Path;
use sysid::dataset::{Dataset, DatasetConfig, LogData};
use sysid::identify::{self, Family, Options};
use sysid::poly::{self, Xy};
use sysid::select;
use sysid::synth::{self, Protocol, SBA1_RAW};

/// `identify` with the polynomial family only and no pruning table.
fn poly_only(ds: &Dataset) -> identify::ChamberReport {
    identify::identify(
        ds,
        &Options {
            families: vec![Family::Poly],
            prune_k: 0,
            ..Options::default()
        },
    )
}

fn plant(raw: &[f64], n: usize, m: usize, samples: usize, sigma: f64, seed: u64) -> Dataset {
    let tr = Protocol {
        samples,
        ..Protocol::default()
    }
    .trajectory();
    let p = synth::pressure(raw, n, m, &tr, sigma, seed);
    Dataset::from_columns(tr.t, tr.v, tr.vdot, p, &DatasetConfig::default())
}

#[test]
fn the_rule_picks_the_true_order_of_a_low_order_plant() {
    // The paper's SBA1 law, (3, 2), and a (2, 1) plant whose every term moves P by kPa over
    // the protocol's range (v ≤ 550 mm³, |v̇| ≤ 100 mm³/s); Gaussian noise of known σ.
    let low = [0.5, 0.02, 0.01, 1e-4, 2e-5, 2e-7];
    for (raw, n, m, sigma) in [(&SBA1_RAW[..], 3, 2, 0.5), (&low[..], 2, 1, 0.3)] {
        for seed in [3, 4] {
            let ds = plant(raw, n, m, 30_000, sigma, seed);
            let rep = poly_only(&ds);
            let sel = rep.poly_selection.expect("a selection");
            assert_eq!(
                (sel.selected.n, sel.selected.m),
                (n, m),
                "seed {seed}: {sel:?}"
            );
            assert_eq!(select::poly_shape(&ds), Some((n, m)));
            let aicc = sel.aicc_pick.expect("an AICc pick");
            assert!(aicc.nu >= sel.selected.nu, "AICc never picks fewer here");
        }
    }
}

#[test]
fn time_stretches_replace_cycles_when_there_are_too_few() {
    let ds = plant(&SBA1_RAW, 3, 2, 600, 0.5, 1);
    let b = select::training_blocks(&ds);
    assert!(
        ds.n_cycles < select::MIN_CYCLE_BLOCKS,
        "{} cycles",
        ds.n_cycles
    );
    assert_eq!(b.kind, select::BlockKind::TimeStretches);
    assert_eq!(b.ranges.len(), select::TIME_STRETCHES);
    assert_eq!(b.ranges.last().unwrap().end, ds.train().len());
}

/// A host-sim log (the paper's rig, `PlantConfig::default()`: the (3, 2) law with delivery lag and
/// sensor noise) of one protocol cycle, parsed as `vfp` reads it.
fn host_sim_log(cycles: u16, flows: &[f64], chamber: u8) -> Dataset {
    let protocol = host_sim::Protocol {
        cycles,
        flows: flows.to_vec(),
        ..host_sim::Protocol::paper()
    };
    let run = host_sim::simulate(&host_sim::Scenario::protocol(
        "selection",
        host_sim::PlantConfig::default(),
        &protocol,
    ))
    .unwrap();
    let mut csv = Vec::new();
    run.write_log(&mut csv).unwrap();
    let log = sysid::log::parse_log(&csv[..], "sim.csv").unwrap();
    Dataset::from_log(&log, chamber, &DatasetConfig::default()).unwrap()
}

/// One cycle at two flows, too few cycles for cycle blocks: the time stretches are short, so no
/// fold loses a whole flow level, and the rule finds the law's quadratic flow dependence (with
/// five long stretches every m ≥ 2 extrapolated to hundreds of kPa and (3, 1) was chosen).
#[test]
fn short_stretches_find_the_flow_order_of_a_one_cycle_log() {
    for chamber in 0..3 {
        let ds = host_sim_log(1, &[40.0, 100.0], chamber);
        assert!(ds.n_cycles < select::MIN_CYCLE_BLOCKS);
        let (n, m) = select::poly_shape(&ds).expect("a shape");
        assert_eq!(m, 2, "chamber {chamber}: ({n}, {m})");
        assert!(n >= 3, "chamber {chamber}: ({n}, {m})");
    }
}

/// A shape whose fold fits extrapolate on one block (error above the pressure's variance there)
/// is not a candidate, however its paired standard error turns out; the true law's shape is.
/// Two cycles at three flows: the last training cycle is cut short, and with the excess all in
/// that block (1, 4) passed the paired rule at 68 kPa of cross-validated RMSE (law: 0.07 kPa).
#[test]
fn shapes_worse_than_the_mean_on_a_block_are_not_candidates() {
    let ds = host_sim_log(2, &[20.0, 60.0, 100.0], 0);
    let train = ds.train();
    let mean = train.p.iter().sum::<f64>() / train.len() as f64;
    let var = train.p.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / train.len() as f64;
    let all = ds.all();
    let sc = poly::Scaling::from_data(&all.v, &all.vdot).unwrap();
    let (_, scores) = select::cross_validate(&ds, &sc, 7, 7).unwrap();
    let ok: Vec<_> = scores.into_iter().flatten().collect();
    for s in &ok {
        let worst = s
            .block_sse
            .iter()
            .zip(&s.block_n)
            .map(|(e, &n)| e / n as f64)
            .fold(0.0, f64::max);
        assert_eq!(s.admissible, worst <= var, "({}, {})", s.n, s.m);
    }
    let law = ok.iter().find(|s| (s.n, s.m) == (3, 2)).unwrap();
    assert!(law.admissible);
    let chosen = select::one_se_rule(&ok).unwrap();
    assert!(chosen.admissible, "{chosen:?}");
    // The choice fits the training cycles about as well as the law's own shape does.
    let rmse = |n, m| {
        poly::fit(Xy::from(&train), n, m, Some(sc))
            .unwrap()
            .train
            .rmse
    };
    assert!(
        rmse(chosen.n, chosen.m) <= 1.5 * rmse(3, 2),
        "({}, {})",
        chosen.n,
        chosen.m
    );
}

/// The acceptance of issue #17 on every real log in `data/real/`: the selected polynomial (the
/// selected shape with its raw terms reduced by the same rule, what `vfp export` exports) has at
/// most 40 parameters and a held-out RMSE within 10 % of the sweep's best held-out RMSE.
///
/// The shape alone did not get there on the 31 s QuickLung log: (7, 5), 48 parameters, is better
/// than every shape of at most 40 on every one of its 8 training cycles (the best of those,
/// (7, 4), by 7.7 paired standard errors). Its terms reduce to at most 40.
#[test]
fn real_logs_select_at_most_40_parameters_within_10_percent_of_the_best() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/real");
    let mut files: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|x| x == "csv"))
        .collect();
    files.sort();
    assert!(files.len() >= 3);
    for f in &files {
        let data = LogData::read(f, None, &DatasetConfig::default()).unwrap();
        let rep = poly_only(data.first());
        let sel = rep.poly_selection.as_ref().expect("a selection");
        let red = sel.reduced.as_ref().expect("a reduction");
        let best = rep
            .models
            .iter()
            .filter(|r| r.family == Family::Poly)
            .filter_map(|r| r.rmse_heldout)
            .fold(f64::INFINITY, f64::min);
        let chosen = red.rmse_heldout.expect("held-out cycles");
        let name = f.file_name().unwrap().to_string_lossy().to_string();
        eprintln!(
            "{name}: ({}, {}) with {} of {} terms, held-out {chosen:.4} best {best:.4} ratio {:.3}",
            red.n,
            red.m,
            red.nu,
            red.active.len(),
            chosen / best
        );
        assert!(red.nu <= 40, "{name}: {red:?}");
        assert!(chosen <= 1.10 * best, "{name}: {red:?}");
        assert_eq!((red.n, red.m), (sel.selected.n, sel.selected.m));
        assert_eq!(red.kept.len(), red.nu);
        assert_eq!(red.active.iter().filter(|&&a| a).count(), red.nu);
    }
}

/// The cross-validated errors of the term elimination come from restricted fits on moments; here
/// every step of a path is checked against direct refits ([`poly::fit_terms`], QR on the kept
/// columns) of each fold, scored sample by sample on the blocks it leaves out.
#[test]
fn term_elimination_errors_match_direct_refits() {
    let ds = plant(&SBA1_RAW, 3, 2, 6_000, 0.5, 9);
    let sc = poly::Scaling::from_data(&ds.v, &ds.vdot).unwrap();
    let (blocks, bm) = select::block_moments(&ds, &sc).unwrap();
    let scores: Vec<_> = bm.sweep(4, 3).into_iter().flatten().collect();
    let red = bm.reduce_terms(4, 3, &scores).unwrap();
    let train = ds.train();
    let folds = select::MAX_FOLDS.min(blocks.ranges.len());
    let mut dropped: Vec<String> = Vec::new();
    for step in red.path.iter().take(8) {
        dropped.extend(step.dropped.clone());
        let active: Vec<bool> = (0..20)
            .map(|t| !dropped.contains(&poly::term_name(t / 4, t % 4)))
            .collect();
        let (mut sse, mut count) = (0.0, 0usize);
        for f in 0..folds {
            let keep = |b: usize| b % folds != f;
            let rows: Vec<usize> = (0..blocks.ranges.len())
                .filter(|&b| keep(b))
                .flat_map(|b| blocks.ranges[b].clone())
                .collect();
            let pick = |x: &[f64]| rows.iter().map(|&r| x[r]).collect::<Vec<f64>>();
            let (v, q, p) = (pick(&train.v), pick(&train.vdot), pick(&train.p));
            let fit = poly::fit_terms(
                Xy {
                    v: &v,
                    vdot: &q,
                    p: &p,
                },
                4,
                3,
                &active,
            )
            .unwrap();
            for b in (0..blocks.ranges.len()).filter(|&b| !keep(b)) {
                for r in blocks.ranges[b].clone() {
                    sse += (train.p[r] - fit.predict(train.v[r], train.vdot[r])).powi(2);
                    count += 1;
                }
            }
        }
        let direct = (sse / count as f64).sqrt();
        assert!(
            (direct - step.cv_rmse).abs() <= 1e-6 * direct,
            "{} terms: moments {} direct {direct}",
            step.nu,
            step.cv_rmse
        );
    }
}

/// A plant whose law leaves out known terms of its shape: the elimination removes the absent
/// terms before any term of the law, and the rule keeps every term of the law (Gaussian noise of
/// known σ, the protocol's trajectory).
#[test]
fn the_reduction_keeps_the_laws_terms_and_drops_the_absent_ones() {
    // (3, 2): P = 2 + 0.02 v + 1e-4 v² + 2e-7 v³ + 0.01 v̇ + 1e-4 v·v̇ + 5e-5 v̇²; zero: v²v̇, v³v̇,
    // v·v̇², v²v̇², v³v̇² (index i·3 + j).
    let mut raw = [0.0; 12];
    for (i, j, a) in [
        (0, 0, 2.0),
        (1, 0, 0.02),
        (2, 0, 1e-4),
        (3, 0, 2e-7),
        (0, 1, 0.01),
        (1, 1, 1e-4),
        (0, 2, 5e-5),
    ] {
        raw[i * 3 + j] = a;
    }
    for seed in [21, 22] {
        let ds = plant(&raw, 3, 2, 30_000, 0.2, seed);
        let rep = poly_only(&ds);
        let sel = rep.poly_selection.expect("a selection");
        assert_eq!((sel.selected.n, sel.selected.m), (3, 2), "seed {seed}");
        let red = sel.reduced.expect("a reduction");
        let law: Vec<String> = (0..12)
            .filter(|&k| raw[k] != 0.0)
            .map(|k| poly::term_name(k / 3, k % 3))
            .collect();
        let absent: std::collections::BTreeSet<String> = (0..12)
            .filter(|&k| raw[k] == 0.0)
            .map(|k| poly::term_name(k / 3, k % 3))
            .collect();
        // The elimination takes out exactly the absent terms first...
        let first: std::collections::BTreeSet<String> = red.path[1..=absent.len()]
            .iter()
            .filter_map(|s| s.dropped.clone())
            .collect();
        assert_eq!(first, absent, "seed {seed}: {red:?}");
        // ...and the rule keeps every term of the law (it may keep some absent ones: their
        // cost in cross-validated error is within noise, a ten-thousandth of σ² here).
        for t in &law {
            assert!(red.kept.contains(t), "seed {seed}: {t} dropped: {red:?}");
        }
        assert!(red.nu < 12, "seed {seed}: nothing dropped");
    }
}

#[test]
fn pruning_table_matches_direct_refits() {
    for (n, m, seed) in [(3, 2, 5), (5, 4, 6)] {
        let ds = plant(&SBA1_RAW, 3, 2, 20_000, 0.5, seed);
        let (train, held) = (ds.train(), ds.heldout());
        let (xt, xh) = (Xy::from(&train), Xy::from(&held));
        let rows = poly::prune(xt, Some(xh), n, m, 3).unwrap();
        assert_eq!(rows.len(), 6, "3 singles and 3 pairs");
        let full = poly::fit_terms(xt, n, m, &vec![true; (n + 1) * (m + 1)]).unwrap();
        let names = full.term_names();
        for r in &rows {
            let mask: Vec<bool> = names.iter().map(|t| !r.excluded.contains(t)).collect();
            let f = poly::fit_terms(xt, n, m, &mask).unwrap();
            let pred = f.predict_all(&held.v, &held.vdot);
            let h = sysid::metrics::compute(&held.p, &pred, f.nu).unwrap();
            let rel = |a: f64, b: f64| (a - b).abs() / b.abs();
            assert_eq!(r.nu, f.nu);
            assert!(
                rel(r.train.rmse, f.train.rmse) < 1e-9,
                "{r:?} vs {:?}",
                f.train
            );
            assert!(rel(r.train.aicc, f.train.aicc) < 1e-9);
            let rh = r.heldout.unwrap();
            assert!(
                rel(rh.rmse, h.rmse) < 1e-9,
                "{:?}: {} vs {}",
                r.excluded,
                rh.rmse,
                h.rmse
            );
            assert!(r.train.rmse >= full.train.rmse * (1.0 - 1e-9));
        }
    }
}

/// Breaths like a ventilator's into a bag: a fast inflation, an overshoot that pushes a quarter
/// of the volume back in, a deflation, a small bump, rest; flow = dv/dt plus heavy noise.
fn noisy_breaths(count: usize, noise_frac: f64, seed: u64) -> Dataset {
    let (hz, period, vmax) = (100.0, 5.0, 200_000.0);
    let shape = |s: f64| -> f64 {
        let lin = |s: f64, a: f64, b: f64, va: f64, vb: f64| va + (vb - va) * (s - a) / (b - a);
        match s {
            s if s < 0.5 => 0.0,
            s if s < 0.8 => lin(s, 0.5, 0.8, 0.0, 1.0),
            s if s < 1.1 => lin(s, 0.8, 1.1, 1.0, 0.45),
            s if s < 1.3 => lin(s, 1.1, 1.3, 0.45, 0.7),
            s if s < 2.5 => lin(s, 1.3, 2.5, 0.7, 0.0),
            s if s < 2.7 => lin(s, 2.5, 2.7, 0.0, 0.1),
            s if s < 2.9 => lin(s, 2.7, 2.9, 0.1, 0.0),
            _ => 0.0,
        }
    };
    let n = (count as f64 * period * hz) as usize;
    let t: Vec<f64> = (0..n).map(|i| i as f64 / hz).collect();
    let v: Vec<f64> = t.iter().map(|&x| vmax * shape(x % period)).collect();
    let peak = vmax / 0.3;
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, noise_frac * peak).unwrap();
    let vdot: Vec<f64> = (0..n)
        .map(|i| {
            let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
            (v[b] - v[a]) / (t[b] - t[a]) + noise.sample(&mut rng)
        })
        .collect();
    let p: Vec<f64> = v
        .iter()
        .zip(&vdot)
        .map(|(a, q)| 0.5 + a * 1e-5 + q * 1e-7 + rng.random::<f64>() * 0.01)
        .collect();
    Dataset::from_columns(t, v, vdot, p, &DatasetConfig::default())
}

#[test]
fn cycles_on_noisy_flow_count_the_breaths() {
    for (count, noise, seed) in [(9, 0.1, 1), (9, 0.3, 2), (20, 0.2, 3)] {
        let ds = noisy_breaths(count, noise, seed);
        assert_eq!(
            ds.n_cycles, count,
            "{count} breaths, flow noise {noise} of peak"
        );
        // Every cycle holds exactly one breath: one rise through 95 % of the peak volume.
        for c in 0..ds.n_cycles {
            let idx: Vec<usize> = (0..ds.len()).filter(|&i| ds.cycle[i] == c).collect();
            let rises = idx
                .windows(2)
                .filter(|w| ds.v[w[0]] < 190_000.0 && ds.v[w[1]] >= 190_000.0)
                .count();
            assert_eq!(rises, 1, "cycle {c} of {count} breaths, noise {noise}");
        }
    }
}

#[test]
fn the_flow_alone_cuts_these_breaths_into_more_cycles() {
    // The check above has teeth: the flow's phase switches alone find more cycles than breaths.
    let ds = noisy_breaths(9, 0.1, 1);
    let labels = sysid::dataset::segment_cycles(&ds.vdot, 0.05 * 200_000.0 / 0.3, 20);
    let flow_count = labels.last().unwrap() + 1;
    assert!(flow_count > 9, "{flow_count}");
    let (_, count) = sysid::cycles::keep_volume_cycles(&ds.v, &labels);
    assert_eq!(count, 9);
}
