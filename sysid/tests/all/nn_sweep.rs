//! The neural sweep on logs whose pressure law is known: the paper's Table IV polynomial
//! (`model_core::poly::SBA1_RAW`, P in kPa from v in mm³ and v̇ in mm³/s) over a trapezoid
//! protocol (fill 0 → 550 mm³ at 20, 40, .., 100 mm³/s, hold, empty, hold; 25 Hz), plus Gaussian
//! noise of a known σ. Held-out errors are measured on a second log: the same protocol with an
//! independent noise draw, so its RMSE is at least σ, and a model with bias b (RMSE against the
//! noise-free law) reads √(σ² + b²).
//!
//! What must hold: the best training error is non-increasing in the depth d and strictly
//! decreasing (no two depths stuck at the same error by dead units, which are reported and few);
//! the AR variants are within 5 % of the p = 0 net's held-out RMSE; the best net is within a
//! stated factor of σ; an input that used to blow the training up gives finite, sane fits; the
//! sweep is reproducible bit for bit and independent of the thread count.

use model_core::poly::SBA1_RAW;
use rand::rngs::StdRng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal};
use sysid::nn::{self, Inputs, NnFit, SweepConfig};

/// Sample period (s): 25 Hz, as the paper's rig.
const DT: f64 = 0.04;
/// The paper's log length (samples) for the sizes that matter to speed and statistics.
const N_PAPER: usize = 83_783;
/// Noise of the pressure sensor in the synthetic logs (kPa).
const SIGMA: f64 = 0.5;

/// The known law: the Table IV polynomial P = Σ c_ij vⁱ v̇ʲ, i ≤ 3, j ≤ 2 (kPa).
fn law(v: f64, q: f64) -> f64 {
    let mut p = 0.0;
    for i in 0..4 {
        for j in 0..3 {
            p += SBA1_RAW[3 * i + j] * v.powi(i as i32) * q.powi(j as i32);
        }
    }
    p
}

struct Log {
    v: Vec<f64>,
    q: Vec<f64>,
    /// Measured pressure: the law plus noise.
    p: Vec<f64>,
    /// The noise-free law at every sample.
    truth: Vec<f64>,
}

impl Log {
    fn inputs(&self) -> Inputs<'_> {
        Inputs {
            v: &self.v,
            vdot: &self.q,
            ar_order: 0,
        }
    }
}

/// `n` samples of the trapezoid protocol: cycle k runs at 20·(1 + k mod 5) mm³/s, filling
/// 0 → 550 mm³, holding 1 s, emptying, holding 1 s. The flow of a sample is the volume step to
/// the next one over DT (so the last step of a ramp is a partial one); noise N(0, σ²) is drawn
/// from `seed`.
fn trapezoid_log(n: usize, sigma: f64, seed: u64) -> Log {
    let mut rng = StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma).expect("σ ≥ 0");
    let (mut v, mut q, mut p, mut truth) = (
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
        Vec::with_capacity(n),
    );
    let hold = (1.0 / DT) as usize;
    let (mut vol, mut cycle, mut phase, mut held) = (0.0_f64, 0usize, 0u8, 0usize);
    while v.len() < n {
        let rate = 20.0 * (1 + cycle % 5) as f64;
        let next = match phase {
            0 => (vol + rate * DT).min(550.0),
            2 => (vol - rate * DT).max(0.0),
            _ => vol,
        };
        let flow = (next - vol) / DT;
        let clean = law(vol, flow);
        v.push(vol);
        q.push(flow);
        truth.push(clean);
        p.push(clean + noise.sample(&mut rng));
        vol = next;
        match phase {
            0 if vol >= 550.0 => phase = 1,
            2 if vol <= 0.0 => phase = 3,
            1 | 3 => {
                held += 1;
                if held == hold {
                    held = 0;
                    phase = (phase + 1) % 4;
                    if phase == 0 {
                        cycle += 1;
                    }
                }
            }
            _ => {}
        }
    }
    Log { v, q, p, truth }
}

fn rmse(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    (a.iter().zip(b).map(|(x, y)| (x - y).powi(2)).sum::<f64>() / a.len() as f64).sqrt()
}

/// The training error the sweep minimises: RMSE over every row it was given.
fn train_rmse(f: &NnFit) -> f64 {
    (f.sse / f.n_rows as f64).sqrt()
}

/// RMSE of `f` on `log` over samples `from..` (the same rows for every AR order ≤ `from`).
fn rmse_from(f: &NnFit, log: &Log, from: usize) -> f64 {
    let pred = f.predict(&log.inputs());
    rmse(&pred[from..], &log.p[from..])
}

fn fits(sweep: nn::Sweep) -> Vec<NnFit> {
    let errors: Vec<String> = sweep.errors().map(|e| e.to_string()).collect();
    assert!(errors.is_empty(), "sweep errors: {errors:?}");
    sweep.into_iter().collect()
}

#[test]
fn the_generator_follows_the_law_and_the_noise() {
    let log = trapezoid_log(N_PAPER, SIGMA, 1);
    assert_eq!(log.v.len(), N_PAPER);
    // The noise is the stated σ (83,783 draws: ±1 % at 3 standard errors).
    let s = rmse(&log.p, &log.truth);
    assert!((s / SIGMA - 1.0).abs() < 0.01, "noise RMSE {s}");
    // The protocol covers the paper's range: 0..550 mm³, ±20..100 mm³/s and holds.
    let vmax = log.v.iter().cloned().fold(0.0, f64::max);
    let qmax = log.q.iter().cloned().fold(0.0, f64::max);
    let qmin = log.q.iter().cloned().fold(0.0, f64::min);
    assert_eq!(vmax, 550.0);
    assert!((qmax - 100.0).abs() < 1e-9 && (qmin + 100.0).abs() < 1e-9);
    assert!(log.q.iter().filter(|&&q| q == 0.0).count() > N_PAPER / 20);
    // The law spans tens of kPa, far above σ.
    let (lo, hi) = log
        .truth
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| {
            (a.min(x), b.max(x))
        });
    assert!(hi - lo > 40.0 * SIGMA, "law spans {lo}..{hi} kPa");
}

/// The sweep d = 1..=`d_max` at p = 0 on an `n`-sample log: training error non-increasing, at
/// most `max_stalls` depths without a gain (each reported as a dead unit), few dead units,
/// convergence reported, the best held-out RMSE ≤ `factor`·σ.
fn depth_sweep(n: usize, d_max: usize, factor: f64, max_stalls: usize) {
    let train = trapezoid_log(n, SIGMA, 11);
    let held = trapezoid_log(n, SIGMA, 12);
    let cfg = SweepConfig {
        depths: (1..=d_max).collect(),
        threads: 2,
        ..SweepConfig::default()
    };
    let t0 = std::time::Instant::now();
    let fits = fits(nn::sweep(&train.inputs(), &train.p, &cfg));
    let secs = t0.elapsed().as_secs_f64();
    assert_eq!(fits.len(), d_max);
    let tr: Vec<f64> = fits.iter().map(train_rmse).collect();
    let ho: Vec<f64> = fits.iter().map(|f| rmse_from(f, &held, 0)).collect();
    let bias: Vec<f64> = fits
        .iter()
        .map(|f| rmse(&f.predict(&train.inputs()), &train.truth))
        .collect();
    for (i, f) in fits.iter().enumerate() {
        eprintln!(
            "d={:2} train {:.4} held-out {:.4} bias {:.4} epochs {:3} converged {} dead {}",
            f.depth, tr[i], ho[i], bias[i], f.epochs_run, f.converged, f.dead_units
        );
    }
    eprintln!("sweep of {n} samples, d = 1..={d_max}: {secs:.1} s");
    for (i, f) in fits.iter().enumerate() {
        assert_eq!(f.depth, i + 1);
        assert_eq!(f.n_params, 4 * f.depth + 1);
        // Few dead units: at most one per net (a unit inactive on every row, or cut off).
        assert!(
            f.dead_units <= 1,
            "d={}: {} dead units",
            f.depth,
            f.dead_units
        );
        assert!(f.epochs_run <= cfg.epochs);
        assert!(f.converged || f.epochs_run == cfg.epochs);
    }
    for d in 1..fits.len() {
        // Non-increasing by construction (each net starts as the one before it).
        assert!(
            tr[d] <= tr[d - 1],
            "training RMSE rose from d={} ({}) to d={} ({})",
            d,
            tr[d - 1],
            d + 1,
            tr[d]
        );
    }
    // A depth whose training found nothing better keeps its grown start: the same error, and
    // its new unit, cut off by a zero weight, counts as dead, so a stall is visible in the
    // report. Stalls stay rare (the target is none).
    let stalls: Vec<usize> = (1..fits.len())
        .filter(|&d| tr[d] == tr[d - 1])
        .map(|d| d + 1)
        .collect();
    for &d in &stalls {
        assert!(
            fits[d - 1].dead_units >= 1,
            "d={d} kept the d={} error without reporting the idle unit",
            d - 1
        );
    }
    assert!(
        stalls.len() <= max_stalls,
        "depths {stalls:?} share the training RMSE of the depth below"
    );
    // The ReLU layers capture the curvature: the deepest net is far better than the plane
    // (d = 1 is linear in v, v̇).
    assert!(
        tr[d_max - 1] < 0.25 * tr[0],
        "d={d_max} {} vs d=1 {}",
        tr[d_max - 1],
        tr[0]
    );
    // The best net on held-out data is within factor·σ: noise σ plus a model bias
    // b ≤ √(factor² − 1)·σ.
    let best = ho.iter().cloned().fold(f64::INFINITY, f64::min);
    assert!(best >= 0.97 * SIGMA, "held-out RMSE {best} below the noise");
    assert!(
        best <= factor * SIGMA,
        "best held-out RMSE {best} vs σ = {SIGMA}"
    );
    // Held-out and training errors agree: ≤ 61 parameters on thousands of rows do not overfit.
    for (t, h) in tr.iter().zip(&ho) {
        assert!((h / t - 1.0).abs() < 0.05, "train {t} vs held-out {h}");
    }
}

/// d = 1..8 on 12,000 samples (3.5 rounds of the protocol), in the default test profile.
#[test]
fn depth_sweep_on_a_known_law() {
    depth_sweep(12_000, 8, 1.5, 1);
}

/// The paper's sweep d = 1..15 on a paper-sized log.
#[test]
#[ignore = "paper-sized (83,783 samples, d = 1..15): seconds in release, minutes at opt-level 1; run with --release -- --ignored"]
fn depth_sweep_on_a_known_law_paper_sized() {
    depth_sweep(N_PAPER, 15, 1.3, 1);
}

/// AR inputs p = 1..=`p_max` at depth `d` on an `n`-sample log: no worse than p = 0 beyond
/// noise.
fn ar_sweep(n: usize, d: usize, p_max: usize) {
    let train = trapezoid_log(n, SIGMA, 21);
    let held = trapezoid_log(n, SIGMA, 22);
    let cfg = SweepConfig {
        depths: vec![d],
        ar_orders: (0..=p_max).collect(),
        threads: 2,
        ..SweepConfig::default()
    };
    let fits = fits(nn::sweep(&train.inputs(), &train.p, &cfg));
    assert_eq!(fits.len(), p_max + 1);
    // Every order scored on the same samples p_max..N.
    let ho: Vec<f64> = fits.iter().map(|f| rmse_from(f, &held, p_max)).collect();
    let tr: Vec<f64> = fits.iter().map(|f| rmse_from(f, &train, p_max)).collect();
    for (i, f) in fits.iter().enumerate() {
        eprintln!(
            "p={} d={} train {:.4} held-out {:.4} epochs {} converged {} dead {}",
            f.ar_order, f.depth, tr[i], ho[i], f.epochs_run, f.converged, f.dead_units
        );
        assert_eq!((f.ar_order, f.depth), (i, d));
        assert_eq!(f.n_params, d * (2 * i + 4) + 1);
    }
    for p in 1..=p_max {
        assert!(
            ho[p] <= 1.05 * ho[0],
            "p={p}: held-out RMSE {} vs p=0 {}",
            ho[p],
            ho[0]
        );
        // Each AR net starts as the p = 0 net (zero lag weights) and keeps its best training
        // error, so it is no worse there (up to the p rows p = 0 has in addition).
        assert!(
            tr[p] <= tr[0] * (1.0 + 1e-3),
            "p={p}: train {} vs {}",
            tr[p],
            tr[0]
        );
        assert!(ho[p].is_finite() && ho[p] < 2.0 * SIGMA);
    }
}

/// p = 1..3 at d = 4 on 12,000 samples, in the default test profile.
#[test]
fn ar_variants_are_as_good_as_p0() {
    ar_sweep(12_000, 4, 3);
}

/// The paper's AR rows: p = 1..5 at d = 8 on a paper-sized log.
#[test]
#[ignore = "paper-sized (83,783 samples, six nets of depth 8 grown from d = 1): seconds in release, minutes at opt-level 1; run with --release -- --ignored"]
fn ar_variants_are_as_good_as_p0_paper_sized() {
    ar_sweep(N_PAPER, 8, 5);
}

/// Volumes and flows in extreme units (v in 10⁻²⁰⁰ mm³, v̇ in 10²⁰⁰ mm³/s, say): squaring them
/// under- or overflows f64, which used to turn a column's scale into 0 or ∞ and the net blind to
/// it. The fits stay finite and as good as in plain units.
#[test]
fn extreme_input_units_stay_finite() {
    let log = trapezoid_log(6_000, SIGMA, 41);
    let cfg = SweepConfig {
        depths: vec![1, 2, 3, 4],
        threads: 2,
        ..SweepConfig::default()
    };
    let plain = fits(nn::sweep(&log.inputs(), &log.p, &cfg));
    let v: Vec<f64> = log.v.iter().map(|v| v * 1e200).collect();
    let q: Vec<f64> = log.q.iter().map(|q| q * 1e-200).collect();
    let odd = Inputs {
        v: &v,
        vdot: &q,
        ar_order: 0,
    };
    let scaled = fits(nn::sweep(&odd, &log.p, &cfg));
    for (a, b) in plain.iter().zip(&scaled) {
        let (ra, rb) = (train_rmse(a), train_rmse(b));
        eprintln!("d={} plain {ra:.4} extreme units {rb:.4}", a.depth);
        assert!(rb.is_finite());
        assert!((rb / ra - 1.0).abs() < 0.02, "d={}: {rb} vs {ra}", a.depth);
        let pred = b.predict(&odd);
        assert!(pred.iter().all(|x| x.is_finite()));
    }
}

/// Same seed, same bits, whatever the thread count.
#[test]
fn reproducible_bit_for_bit_across_thread_counts() {
    let log = trapezoid_log(12_000, SIGMA, 31);
    let run = |threads: usize| {
        let cfg = SweepConfig {
            depths: vec![1, 2, 3, 5],
            ar_orders: vec![0, 2],
            threads,
            ..SweepConfig::default()
        };
        fits(nn::sweep(&log.inputs(), &log.p, &cfg))
    };
    let (a, b, c) = (run(1), run(2), run(2));
    assert_eq!(a.len(), 8);
    for ((x, y), z) in a.iter().zip(&b).zip(&c) {
        assert_eq!(x.sse.to_bits(), y.sse.to_bits());
        assert_eq!(y.sse.to_bits(), z.sse.to_bits());
        assert_eq!(x.epochs_run, y.epochs_run);
        let (px, py) = (x.predict(&log.inputs()), y.predict(&log.inputs()));
        assert!(px.iter().zip(&py).all(|(u, w)| u.to_bits() == w.to_bits()));
    }
    // A different seed gives a different (but equally good) sweep.
    let other = fits(nn::sweep(
        &log.inputs(),
        &log.p,
        &SweepConfig {
            depths: vec![1, 2, 3, 5],
            ar_orders: vec![0, 2],
            seed: 99,
            threads: 2,
            ..SweepConfig::default()
        },
    ));
    assert!(other.iter().zip(&a).any(|(x, y)| x.sse != y.sse));
}
