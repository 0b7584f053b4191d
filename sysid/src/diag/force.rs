//! `vfp force --ident IDENT.csv --test TEST.csv`: proprioceptive external force from pressure
//! residuals (paper §IV-C, Fig. 8).
//!
//! A polynomial P̂_c(v, v̇) is identified per chamber c on the force-free log. On the test log the
//! residual r_c(t) = P_c(t) − P̂_c(v_c(t), v̇_c(t)) of each chamber, times its effective area A_c
//! (default 22 mm² each), summed over the chambers, is the force magnitude:
//!
//! F̂(t) = Σ_c A_c r_c(t)   (kPa · mm² = mN).
//!
//! The sum is `model_core::force::estimate`, the device's own code (f32). Its signed total is
//! kept (not the magnitude |Σ|), so noise averages out instead of biasing F̂ up at zero force.
//! Chambers are matched by time: for each sample of the chamber with fewest samples, the nearest
//! sample of every other chamber within half a sample period.
//!
//! # What limits the accuracy
//! With independent pressure noise σ_c per chamber, F̂ carries noise of standard deviation
//! √(Σ_c A_c² σ_c²) = A σ √3 for equal chambers: a floor no model can beat without filtering
//! (σ = 0.1 kPa gives 3.8 mN). The report gives this floor twice: from σ_c estimated on the test
//! log from fourth differences of the residual (σ ≈ std(Δ⁴r)/√70, blind to the slow force signal),
//! and from the identification RMSE (which adds the model's own misfit). An optional centred
//! moving average over M samples (`--smooth M`) divides white noise by √M but costs bandwidth:
//! its −3 dB frequency is ≈ 0.443·f_s/M (0.443 being where |sin(πfM/f_s)/(M sin(πf/f_s))| = 1/√2
//! for large M), stated in the report.
//!
//! `vfp force --augmented` (the residual loop's models run by the firmware's own estimator) is the
//! board side of this analysis, `sysid::board::force`: it hands its residuals to this file's
//! summary (`summarize`), so both reports are made alike.

use super::DiagError;
use crate::dataset::{Dataset, LogData};
use crate::poly::{self, Xy};
use serde::Serialize;
use std::collections::BTreeMap;

/// What `vfp force` estimates with.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceOptions {
    /// Polynomial shape per chamber.
    pub shape: super::Shape,
    /// Effective area per chamber in mm², one value for all or one per chamber.
    pub area: Vec<f64>,
    /// Centred moving average over this many samples (1 = no filter).
    pub smooth: usize,
}

/// Per-chamber information of the report.
#[derive(Debug, Clone, Serialize)]
pub struct ChamberForce {
    /// Chamber index.
    pub chamber: u8,
    /// Effective area (mm²).
    pub area_mm2: f64,
    /// RMSE of the identified model on the force-free log (kPa).
    pub ident_rmse_kpa: f64,
    /// Pressure noise σ on the test log from fourth differences of the residual (kPa).
    pub test_noise_kpa: f64,
    /// Mean residual on the test log (kPa).
    pub mean_residual_kpa: f64,
}

/// The report of `vfp force` (its `--json` document). Forces in N.
#[derive(Debug, Serialize)]
pub struct ForceReport {
    /// Identification log.
    pub ident: String,
    /// Test log.
    pub test: String,
    /// Polynomial shape.
    pub shape: super::Shape,
    /// Samples (time instants) where all chambers were matched.
    pub samples: usize,
    /// Test-log instants dropped because a chamber had no sample within half a period.
    pub unmatched: usize,
    /// Chambers used.
    pub chambers: Vec<ChamberForce>,
    /// Mean estimated force (N).
    pub mean_force_n: f64,
    /// Mean of (estimate − truth) (N), when the test log has `force_n`.
    pub mean_error_n: Option<f64>,
    /// Standard deviation of (estimate − truth) (N).
    pub std_error_n: Option<f64>,
    /// RMS of (estimate − truth) (N).
    pub rmse_n: Option<f64>,
    /// Noise floor √(Σ A²σ²) from the test-log noise estimate (N), after the filter.
    pub noise_floor_n: f64,
    /// The same from the identification RMSE (includes model misfit) (N), after the filter.
    pub model_floor_n: f64,
    /// Moving-average length (1 = none).
    pub smooth_samples: usize,
    /// Sample rate of the test log (Hz).
    pub sample_rate_hz: f64,
    /// −3 dB bandwidth of the filter (Hz); Nyquist when unfiltered.
    pub bandwidth_hz: f64,
}

/// Result of the estimation, for the report and the plots.
#[derive(Debug, Clone)]
pub struct ForceTrace {
    /// Times of matched instants (s).
    pub t: Vec<f64>,
    /// Estimated force (N).
    pub est: Vec<f64>,
    /// Truth (N), when present.
    pub truth: Option<Vec<f64>>,
    /// Per chamber: (measured, predicted) pressure at the matched instants.
    pub pressures: BTreeMap<u8, (Vec<f64>, Vec<f64>)>,
}

/// Matches chambers by time; returns per matched instant the sample index of each chamber, and
/// the number of instants dropped.
pub(crate) fn match_times(chambers: &BTreeMap<u8, &Dataset>) -> (Vec<BTreeMap<u8, usize>>, usize) {
    let (&rc, rs) = chambers
        .iter()
        .min_by_key(|(_, s)| s.len())
        .expect("at least one chamber");
    let mut dts: Vec<f64> = rs.t.windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_by(f64::total_cmp);
    let tol = 0.5 * dts.get(dts.len() / 2).copied().unwrap_or(f64::INFINITY);
    let mut out = Vec::new();
    let mut unmatched = 0;
    for (i, &t) in rs.t.iter().enumerate() {
        let mut row = BTreeMap::new();
        row.insert(rc, i);
        let ok = chambers.iter().filter(|(&c, _)| c != rc).all(|(&c, s)| {
            let j = s.t.partition_point(|&x| x < t);
            let best = [j.saturating_sub(1), j.min(s.len() - 1)]
                .into_iter()
                .min_by(|&a, &b| (s.t[a] - t).abs().total_cmp(&(s.t[b] - t).abs()))
                .expect("non-empty");
            if (s.t[best] - t).abs() <= tol {
                row.insert(c, best);
                true
            } else {
                false
            }
        });
        if ok {
            out.push(row);
        } else {
            unmatched += 1;
        }
    }
    (out, unmatched)
}

/// Centred moving average over `m` samples (shorter windows at the ends).
pub fn moving_average(x: &[f64], m: usize) -> Vec<f64> {
    if m <= 1 {
        return x.to_vec();
    }
    let (before, after) = ((m - 1) / 2, m / 2);
    let mut prefix = vec![0.0; x.len() + 1];
    for (i, v) in x.iter().enumerate() {
        prefix[i + 1] = prefix[i] + v;
    }
    (0..x.len())
        .map(|i| {
            let (a, b) = (i.saturating_sub(before), (i + after + 1).min(x.len()));
            (prefix[b] - prefix[a]) / (b - a) as f64
        })
        .collect()
}

/// σ of white noise under a smooth signal from fourth differences: Δ⁴ of white noise has
/// variance C(8, 4)·σ² = 70σ², while Δ⁴ of a sinusoid of frequency f is scaled by
/// (2 sin(πf/f_s))⁴ (0.004 for 1 Hz at 25 Hz), so the pushes themselves hardly leak in.
pub fn difference_noise(x: &[f64]) -> f64 {
    if x.len() < 6 {
        return f64::NAN;
    }
    let d: Vec<f64> = x
        .windows(5)
        .map(|w| w[4] - 4.0 * w[3] + 6.0 * w[2] - 4.0 * w[1] + w[0])
        .collect();
    let mean = d.iter().sum::<f64>() / d.len() as f64;
    let var = d.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (d.len() - 1) as f64;
    (var / 70.0).sqrt()
}

/// Mean, sample standard deviation and RMS of `e`.
pub fn error_stats(e: &[f64]) -> (f64, f64, f64) {
    let n = e.len() as f64;
    let mean = e.iter().sum::<f64>() / n;
    let var = e.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    let rms = (e.iter().map(|x| x * x).sum::<f64>() / n).sqrt();
    (mean, var.sqrt(), rms)
}

/// The effective area of chamber `c` (one value for all, or one per chamber).
pub(crate) fn area_of(args: &ForceOptions, c: u8) -> f64 {
    if args.area.len() == 1 {
        args.area[0]
    } else {
        args.area[c as usize]
    }
}

/// The identification log's data set of chamber `c`, which the test log uses.
pub(crate) fn ident_dataset(ident: &LogData, c: u8) -> Result<&Dataset, DiagError> {
    ident.dataset(c).ok_or_else(|| DiagError::Input {
        path: ident.path.clone(),
        line: None,
        column: Some("chamber".into()),
        msg: format!(
            "the test log has chamber {c} but the identification log has none; identify \
             every chamber the test log uses"
        ),
    })
}

/// What an estimator hands [`summarize`]: per kept instant its time, the unfiltered force and the
/// truth, per chamber the measured and predicted pressure and the model's error on the
/// identification log.
pub(crate) struct Residuals {
    pub(crate) t: Vec<f64>,
    pub(crate) raw: Vec<f64>,
    pub(crate) truth: Option<Vec<f64>>,
    pub(crate) pressures: BTreeMap<u8, (Vec<f64>, Vec<f64>)>,
    pub(crate) ident_rmse: BTreeMap<u8, f64>,
    pub(crate) unmatched: usize,
}

/// Error when fewer than 3 instants are left to estimate on.
pub(crate) fn too_few(test: &LogData, why: &str) -> DiagError {
    DiagError::Input {
        path: test.path.clone(),
        line: None,
        column: Some("time_s".into()),
        msg: format!("fewer than 3 instants {why}"),
    }
}

/// Identifies per chamber on `ident`, estimates the force on `test`.
pub fn estimate(
    ident: &LogData,
    test: &LogData,
    args: &ForceOptions,
) -> Result<(ForceReport, ForceTrace), DiagError> {
    let shape = args.shape;
    let mut fits = BTreeMap::new();
    let mut test_series = BTreeMap::new();
    for s in &test.datasets {
        let c = s.chamber;
        let is = ident_dataset(ident, c)?;
        let fit = poly::fit(
            Xy {
                v: &is.v,
                vdot: &is.vdot,
                p: &is.p,
            },
            shape.n,
            shape.m,
            None,
        )
        .map_err(|e| {
            DiagError::fit(
                format!("{}, chamber {c}", ident.path.display()),
                e.to_string(),
            )
        })?;
        fits.insert(c, fit);
        test_series.insert(c, s);
    }
    let (rows, unmatched) = match_times(&test_series);
    if rows.len() < 3 {
        return Err(too_few(
            test,
            "where every chamber has a sample; chambers must be sampled at common times",
        ));
    }
    let (rc, rs) = test_series
        .iter()
        .min_by_key(|(_, s)| s.len())
        .map(|(c, s)| (*c, *s))
        .unwrap();
    let mut pressures: BTreeMap<u8, (Vec<f64>, Vec<f64>)> = BTreeMap::new();
    let mut raw = vec![0.0; rows.len()];
    let areas: [f32; 3] = core::array::from_fn(|c| area_of(args, c as u8) as f32);
    for (k, row) in rows.iter().enumerate() {
        // The device's own force law (model-core): Fᵢ = rᵢ·Aᵢ, chambers absent from the log
        // contribute a zero residual.
        let mut r = [0.0f32; 3];
        for (&c, &i) in row {
            let s = test_series[&c];
            let pred = fits[&c].predict(s.v[i], s.vdot[i]);
            let e = pressures.entry(c).or_default();
            e.0.push(s.p[i]);
            e.1.push(pred);
            r[c as usize] = (s.p[i] - pred) as f32;
        }
        raw[k] = signed_force(r, areas, test, rs.t[row[&rc]])?;
    }
    let res = Residuals {
        t: rows.iter().map(|r| rs.t[r[&rc]]).collect(),
        raw,
        truth: rs
            .force
            .as_ref()
            .map(|f| rows.iter().map(|r| f[r[&rc]]).collect()),
        pressures,
        ident_rmse: fits.iter().map(|(&c, f)| (c, f.train.rmse)).collect(),
        unmatched,
    };
    Ok(summarize(ident, test, args, res))
}

/// The device's own force law (model-core), its signed total `Σ Aᵢ·rᵢ` in N.
pub(crate) fn signed_force(
    r: [f32; 3],
    areas: [f32; 3],
    test: &LogData,
    t: f64,
) -> Result<f64, DiagError> {
    let f = model_core::force::estimate(r, areas).map_err(|e| DiagError::Input {
        path: test.path.clone(),
        line: None,
        column: None,
        msg: format!("force estimate at t = {t} s: {e}"),
    })?;
    Ok(f.signed_total_n() as f64)
}

/// The report and trace from the residuals of either estimator (filter, error statistics,
/// noise floors).
pub(crate) fn summarize(
    ident: &LogData,
    test: &LogData,
    args: &ForceOptions,
    res: Residuals,
) -> (ForceReport, ForceTrace) {
    let Residuals {
        t,
        raw,
        truth,
        pressures,
        ident_rmse,
        unmatched,
    } = res;
    let est = moving_average(&raw, args.smooth);
    let mut dts: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_by(f64::total_cmp);
    let fs = 1.0 / dts[dts.len() / 2];
    let m = args.smooth.max(1) as f64;
    let chambers: Vec<ChamberForce> = pressures
        .iter()
        .map(|(&c, (meas, pred))| {
            let r: Vec<f64> = meas.iter().zip(pred).map(|(a, b)| a - b).collect();
            ChamberForce {
                chamber: c,
                area_mm2: area_of(args, c),
                ident_rmse_kpa: ident_rmse[&c],
                test_noise_kpa: difference_noise(&r),
                mean_residual_kpa: r.iter().sum::<f64>() / r.len() as f64,
            }
        })
        .collect();
    let floor = |f: &dyn Fn(&ChamberForce) -> f64| {
        (chambers
            .iter()
            .map(|c| (c.area_mm2 * f(c)).powi(2))
            .sum::<f64>()
            / m)
            .sqrt()
            * 1e-3
    };
    let (mean_e, std_e, rms_e) = match &truth {
        Some(tr) => {
            let e: Vec<f64> = est.iter().zip(tr).map(|(a, b)| a - b).collect();
            let (a, b, c) = error_stats(&e);
            (Some(a), Some(b), Some(c))
        }
        None => (None, None, None),
    };
    let report = ForceReport {
        ident: ident.name(),
        test: test.name(),
        shape: args.shape,
        samples: t.len(),
        unmatched,
        mean_force_n: est.iter().sum::<f64>() / est.len() as f64,
        mean_error_n: mean_e,
        std_error_n: std_e,
        rmse_n: rms_e,
        noise_floor_n: floor(&|c| c.test_noise_kpa),
        model_floor_n: floor(&|c| c.ident_rmse_kpa),
        smooth_samples: args.smooth.max(1),
        sample_rate_hz: fs,
        bandwidth_hz: if args.smooth > 1 {
            0.443 * fs / m
        } else {
            fs / 2.0
        },
        chambers,
    };
    (
        report,
        ForceTrace {
            t,
            est,
            truth,
            pressures,
        },
    )
}
