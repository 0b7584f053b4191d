//! Small synthetic plants for the unit tests of the loop's steps (compiled for tests only): a
//! (3, 2) polynomial with known effects planted at known parameters, on a few thousand frames of
//! two tones, and the loop's state as forward selection would have left it with a given model.

use super::basis::PolyBasis;
use super::effects::{build, Effect, Prepared};
use super::lsq;
use super::search::{self, Stage};
use super::state::{Findings, KeptStep};
use super::Series;

/// `n` frames at 25 Hz of two incommensurate strokes fast enough that lags of a few frames show
/// (1.3 and 3.1 rad/s): times (s), volume (mm³) and flow (mm³/s).
pub(crate) fn fast_tones(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
    let t: Vec<f64> = (0..n).map(|k| 0.04 * k as f64).collect();
    let v = t
        .iter()
        .map(|&t| 275.0 + 150.0 * (1.3 * t).sin() + 60.0 * (3.1 * t).sin())
        .collect();
    let f = t
        .iter()
        .map(|&t| 195.0 * (1.3 * t).cos() + 186.0 * (3.1 * t).cos())
        .collect();
    (t, v, f)
}

/// Deterministic noise of standard deviation `sigma` (a sum of four uniform draws of a linear
/// congruential generator, scaled).
pub(crate) fn noise(n: usize, sigma: f64) -> Vec<f64> {
    let mut x: u64 = 0x2545_f491_4f6c_dd1d;
    let mut uniform = move || {
        x = x
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        (x >> 11) as f64 / (1u64 << 53) as f64 - 0.5
    };
    // Four uniforms on [-1/2, 1/2] sum to variance 1/3.
    let scale = sigma * 3f64.sqrt();
    (0..n)
        .map(|_| scale * (uniform() + uniform() + uniform() + uniform()))
        .collect()
}

/// A plant inside the model class: the design of the `truth` effects at their parameters on
/// `n` frames of [`fast_tones`] times the coefficients that fit it best to a smooth (3, 2)
/// pressure, plus `drift(s)` (`s` the time scaled to [−1, 1]; a polynomial of the offset drift's
/// degree when one is planted), plus [`noise`] of `sigma` kPa. Every fifth block of 300 frames is
/// held out.
pub(crate) fn plant(
    n: usize,
    truth: &[Effect],
    drift: impl Fn(f64) -> f64,
    sigma: f64,
) -> Prepared {
    let (t, v, f) = fast_tones(n);
    let train: Vec<bool> = (0..n).map(|k| (k / 300) % 5 != 4).collect();
    let make = |p: Vec<f64>| {
        let series = Series::new(t.clone(), v.clone(), f.clone(), p, train.clone()).unwrap();
        let basis = PolyBasis::for_data(&series.v, &series.vdot, 3, 2).unwrap();
        Prepared::new(series, basis)
    };
    let smooth: Vec<f64> = (0..n)
        .map(|k| 2.0 + 0.01 * v[k] + 0.004 * f[k] + 2e-5 * v[k] * f[k])
        .collect();
    let prep = make(smooth.clone());
    let design = build(&prep, truth);
    let rows: Vec<usize> = (0..n).collect();
    let beta = lsq::fit(&design.cols, &smooth, &rows).unwrap().beta;
    let e = noise(n, sigma);
    let p = lsq::predict(&design.cols, &beta)
        .iter()
        .zip(&e)
        .enumerate()
        .map(|(k, (p, e))| p + drift(2.0 * k as f64 / (n - 1) as f64 - 1.0) + e)
        .collect();
    make(p)
}

/// The loop's state as forward selection leaves it with `model` kept, one effect a round in the
/// model's order, the `i`-th effect's round having found `rivals[i]` as its look-alikes.
pub(crate) fn kept(prep: &Prepared, model: &Stage, rivals: Vec<Vec<Effect>>) -> Findings {
    let baseline = search::fit_stage(prep, &[]).unwrap();
    let mut sel = Findings::new(&baseline);
    let mut prev = baseline;
    for (j, rivals) in rivals.into_iter().enumerate() {
        let after = search::fit_stage(prep, &model.effects[..=j]).unwrap();
        sel.kept.push(KeptStep {
            rivals,
            ..KeptStep::between(prep, &prev, &after)
        });
        prev = after;
    }
    sel.model = model.clone();
    sel
}
