//! Looking at a residual the way a system-identification engineer would (Ljung, *System
//! Identification*, ch. 16.6 "model validation"): is it white, does it follow an input, does it
//! depend on direction, and where is its power in frequency?
//!
//! All statistics respect gaps: a residual on held-out cycles is several separate runs, and a
//! product `r_i r_{i+k}` is only formed inside one run.
//!
//! * autocorrelation `ρ_k = Σ (r_i − r̄)(r_{i+k} − r̄) / Σ (r_i − r̄)²`, with the white-noise band
//!   `±1.96/√N`;
//! * Ljung–Box `Q = N(N+2) Σ_{k=1}^{h} ρ_k²/(N − k)`, compared with χ²(h);
//! * cross-correlation with standardised v, v̇, v̈ and time, `ρ_{ru}(k) = corr(r_t, u_{t−k})`
//!   (positive k: the input leads the residual);
//! * residual means binned over v and |v̇| separately for inflation (v̇ > 0) and deflation;
//! * Welch power spectral density (Hann window, 50 % overlap) over the runs.

use realfft::RealFftPlanner;
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF};

use super::signal::runs;

/// Autocorrelation and whiteness test.
#[derive(Clone, Debug, Serialize)]
pub struct Whiteness {
    /// ρ_0 … ρ_L.
    pub acf: Vec<f64>,
    /// Lag spacing (s) of the acf entries.
    pub lag_s: f64,
    /// 95 % band for a white residual, 1.96/√N.
    pub band: f64,
    /// Ljung–Box lags h.
    pub lb_lags: usize,
    /// Ljung–Box Q.
    pub lb_q: f64,
    /// Ljung–Box p-value (χ²(h)).
    pub lb_p_value: f64,
}

/// Cross-correlation of the residual with one signal.
#[derive(Clone, Debug, Serialize)]
pub struct CrossCorr {
    /// `v`, `vdot`, `vddot` or `time`.
    pub input: &'static str,
    /// Lags in samples, −L … L.
    pub lags: Vec<i64>,
    /// Correlation at each lag.
    pub values: Vec<f64>,
    /// Lag (samples) of the largest |value|.
    pub peak_lag: i64,
    /// Value at that lag.
    pub peak_value: f64,
}

/// Residual binned by an input, one direction.
#[derive(Clone, Debug, Serialize)]
pub struct Binned {
    /// Bin centres.
    pub centre: Vec<f64>,
    /// Mean residual per bin (NaN-free: empty bins are dropped).
    pub mean: Vec<f64>,
    /// Samples per bin.
    pub count: Vec<usize>,
}

/// Residual split by direction of motion.
#[derive(Clone, Debug, Serialize)]
pub struct Direction {
    /// Residual vs volume while inflating.
    pub inflation_vs_v: Binned,
    /// Residual vs volume while deflating.
    pub deflation_vs_v: Binned,
    /// Residual vs |v̇| while inflating.
    pub inflation_vs_speed: Binned,
    /// Residual vs |v̇| while deflating.
    pub deflation_vs_speed: Binned,
    /// Mean residual while inflating (kPa).
    pub mean_inflation: f64,
    /// Mean residual while deflating (kPa).
    pub mean_deflation: f64,
    /// t statistic of the difference, with the sample counts shrunk by the residual's lag-1
    /// autocorrelation (effective sample size).
    pub t_stat: f64,
}

/// Power spectral density.
#[derive(Clone, Debug, Serialize)]
pub struct Spectrum {
    /// Frequencies (Hz).
    pub freq_hz: Vec<f64>,
    /// One-sided PSD (kPa²/Hz).
    pub psd: Vec<f64>,
    /// Frequency of the largest peak above the lowest bins (Hz).
    pub peak_hz: f64,
    /// Share of the total power in the peak ±1 bin.
    pub peak_share: f64,
    /// Peak PSD over the median PSD.
    pub peak_over_median: f64,
}

/// Everything the loop looks at in one residual.
#[derive(Clone, Debug, Serialize)]
pub struct ResidualAnalysis {
    /// Samples analysed.
    pub n: usize,
    /// RMS residual (kPa).
    pub rmse: f64,
    /// Mean residual (kPa).
    pub mean: f64,
    /// Autocorrelation and Ljung–Box.
    pub whiteness: Whiteness,
    /// Cross-correlations with v, v̇, v̈, time.
    pub cross: Vec<CrossCorr>,
    /// Direction split.
    pub direction: Direction,
    /// Spectrum.
    pub spectrum: Spectrum,
    /// Time (s), volume, flow and residual of the analysed samples, for figures.
    #[serde(skip)]
    pub points: Vec<[f64; 4]>,
}

/// Inputs of an analysis: the residual over every sample and a mask of samples to use.
pub struct Signals<'a> {
    /// Sample times (s).
    pub t: &'a [f64],
    /// Volume (mm³).
    pub v: &'a [f64],
    /// Flow (mm³/s).
    pub vdot: &'a [f64],
    /// Volumetric acceleration (mm³/s²).
    pub vddot: &'a [f64],
}

fn masked_mean(x: &[f64], mask: &[bool]) -> (f64, usize) {
    let (s, n) = x
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m)
        .fold((0.0, 0usize), |(s, n), (x, _)| (s + x, n + 1));
    (if n > 0 { s / n as f64 } else { 0.0 }, n)
}

/// Cross-covariance at lag k of (a − ā) and (b − b̄) inside runs, normalised by N:
/// `Σ a_i b_{i−k}`.
fn cov_at(a: &[f64], b: &[f64], runs: &[(usize, usize)], k: i64, n: usize) -> f64 {
    let mut s = 0.0;
    for &(lo, hi) in runs {
        for i in lo..hi {
            let j = i as i64 - k;
            if j >= lo as i64 && j < hi as i64 {
                s += a[i] * b[j as usize];
            }
        }
    }
    s / n as f64
}

/// Lag-1 autocorrelation inside runs (used for effective sample sizes).
pub fn lag1(x: &[f64], mask: &[bool]) -> f64 {
    let (m, n) = masked_mean(x, mask);
    if n < 3 {
        return 0.0;
    }
    let c: Vec<f64> = x.iter().map(|v| v - m).collect();
    let r = runs(mask);
    let c0 = cov_at(&c, &c, &r, 0, n);
    if c0 <= 0.0 {
        return 0.0;
    }
    cov_at(&c, &c, &r, 1, n) / c0
}

/// Effective sample size for an AR(1)-like residual: `N (1 − ρ)/(1 + ρ)`, ρ clamped to [0, 0.98].
pub fn n_eff(n: usize, rho: f64) -> f64 {
    let r = rho.clamp(0.0, 0.98);
    n as f64 * (1.0 - r) / (1.0 + r)
}

fn binned(x: &[f64], r: &[f64], idx: &[usize], lo: f64, hi: f64, bins: usize) -> Binned {
    let mut sum = vec![0.0; bins];
    let mut cnt = vec![0usize; bins];
    let w = (hi - lo) / bins as f64;
    for &i in idx {
        if w > 0.0 {
            let b = (((x[i] - lo) / w) as usize).min(bins - 1);
            sum[b] += r[i];
            cnt[b] += 1;
        }
    }
    let mut out = Binned {
        centre: vec![],
        mean: vec![],
        count: vec![],
    };
    for b in 0..bins {
        if cnt[b] > 0 {
            out.centre.push(lo + (b as f64 + 0.5) * w);
            out.mean.push(sum[b] / cnt[b] as f64);
            out.count.push(cnt[b]);
        }
    }
    out
}

/// Welch PSD over the runs of `mask` (segments of `len`, Hann window, 50 % overlap).
pub fn welch(x: &[f64], mask: &[bool], fs: f64, max_len: usize) -> (Vec<f64>, Vec<f64>) {
    let r = runs(mask);
    let longest = r.iter().map(|(a, b)| b - a).max().unwrap_or(0);
    let mut len = 16usize;
    while len * 2 <= max_len && len * 2 <= longest {
        len *= 2;
    }
    let (mean, _) = masked_mean(x, mask);
    let window: Vec<f64> = (0..len)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / len as f64).cos())
        .collect();
    let wss: f64 = window.iter().map(|w| w * w).sum();
    let mut planner = RealFftPlanner::<f64>::new();
    let fft = planner.plan_fft_forward(len);
    let mut input = fft.make_input_vec();
    let mut spec = fft.make_output_vec();
    let mut psd = vec![0.0; len / 2 + 1];
    let mut segments = 0usize;
    for &(lo, hi) in &r {
        let mut start = lo;
        while start + len <= hi {
            for i in 0..len {
                input[i] = (x[start + i] - mean) * window[i];
            }
            if fft.process(&mut input, &mut spec).is_ok() {
                for (p, c) in psd.iter_mut().zip(&spec) {
                    *p += c.norm_sqr();
                }
                segments += 1;
            }
            start += len / 2;
        }
    }
    let freq: Vec<f64> = (0..psd.len()).map(|k| k as f64 * fs / len as f64).collect();
    if segments == 0 {
        return (freq, vec![0.0; psd.len()]);
    }
    let last = psd.len() - 1;
    for (k, p) in psd.iter_mut().enumerate() {
        // One-sided density: double every bin but DC and Nyquist.
        let one_sided = if k == 0 || k == last { 1.0 } else { 2.0 };
        *p *= one_sided / (fs * wss * segments as f64);
    }
    (freq, psd)
}

/// Analyses `resid` on the samples where `mask` is true.
pub fn analyse(
    sig: &Signals<'_>,
    resid: &[f64],
    mask: &[bool],
    max_lag: usize,
) -> ResidualAnalysis {
    let (mean, n) = masked_mean(resid, mask);
    let rmse = (resid
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m)
        .map(|(r, _)| r * r)
        .sum::<f64>()
        / n.max(1) as f64)
        .sqrt();
    let rr = runs(mask);
    let c: Vec<f64> = resid.iter().map(|r| r - mean).collect();
    let c0 = cov_at(&c, &c, &rr, 0, n.max(1));
    let lags = max_lag.min(n / 4).max(1);
    let acf: Vec<f64> = (0..=lags)
        .map(|k| {
            if c0 > 0.0 {
                cov_at(&c, &c, &rr, k as i64, n) / c0
            } else {
                0.0
            }
        })
        .collect();
    let mut dts: Vec<f64> = sig.t.windows(2).map(|w| w[1] - w[0]).collect();
    dts.sort_by(f64::total_cmp);
    let dt = dts.get(dts.len() / 2).copied().unwrap_or(1.0);
    let whiteness = whiteness(acf, n, lags, dt);
    let cross = cross_correlations(sig, mask, &c, &rr, c0, n, lags);
    let direction = direction(sig, resid, mask);
    let spectrum = spectrum(resid, mask, dt);
    let points = (0..resid.len())
        .filter(|&i| mask[i])
        .map(|i| [sig.t[i], sig.v[i], sig.vdot[i], resid[i]])
        .collect();
    ResidualAnalysis {
        n,
        rmse,
        mean,
        whiteness,
        cross,
        direction,
        spectrum,
        points,
    }
}

/// Whiteness of a residual from its autocorrelation `acf` (lags 0..): the Ljung–Box statistic
/// `Q = N(N + 2) Σ_{k=1..h} ρ_k²/(N − k)`, h = min(lags, 20), against χ²(h), and the white-noise
/// band ±1.96/√N.
fn whiteness(acf: Vec<f64>, n: usize, lags: usize, dt: f64) -> Whiteness {
    let h = lags.min(20);
    let nf = n as f64;
    let q = nf
        * (nf + 2.0)
        * (1..=h)
            .map(|k| acf[k] * acf[k] / (nf - k as f64))
            .sum::<f64>();
    let lb_p_value = ChiSquared::new(h as f64)
        .map(|d| 1.0 - d.cdf(q))
        .unwrap_or(f64::NAN);
    Whiteness {
        acf,
        lag_s: dt,
        band: 1.96 / nf.max(1.0).sqrt(),
        lb_lags: h,
        lb_q: q,
        lb_p_value,
    }
}

/// Cross-correlation of the centred residual `c` with v, v̇, v̈ and time at lags ±`lags`, each with
/// its peak.
fn cross_correlations(
    sig: &Signals<'_>,
    mask: &[bool],
    c: &[f64],
    rr: &[(usize, usize)],
    c0: f64,
    n: usize,
    lags: usize,
) -> Vec<CrossCorr> {
    let mut cross = Vec::new();
    for (name, u) in [
        ("v", sig.v),
        ("vdot", sig.vdot),
        ("vddot", sig.vddot),
        ("time", sig.t),
    ] {
        let (um, _) = masked_mean(u, mask);
        let uc: Vec<f64> = u.iter().map(|x| x - um).collect();
        let u0 = cov_at(&uc, &uc, rr, 0, n.max(1));
        let norm = (u0 * c0).sqrt();
        let l = lags as i64;
        let lag_list: Vec<i64> = (-l..=l).collect();
        let values: Vec<f64> = lag_list
            .iter()
            .map(|&k| {
                if norm > 0.0 {
                    cov_at(c, &uc, rr, k, n) / norm
                } else {
                    0.0
                }
            })
            .collect();
        let (pi, pv) = values
            .iter()
            .enumerate()
            .fold((0usize, 0.0f64), |acc, (i, &v)| {
                if v.abs() > acc.1.abs() {
                    (i, v)
                } else {
                    acc
                }
            });
        cross.push(CrossCorr {
            input: name,
            peak_lag: lag_list[pi],
            peak_value: pv,
            lags: lag_list,
            values,
        });
    }
    cross
}

/// The residual split by direction of motion (flow beyond 5 % of its largest), binned against
/// volume and speed, with the mean gap's t statistic (sample sizes corrected for autocorrelation).
fn direction(sig: &Signals<'_>, resid: &[f64], mask: &[bool]) -> Direction {
    let vmax = sig
        .vdot
        .iter()
        .zip(mask)
        .filter(|(_, &m)| m)
        .map(|(f, _)| f.abs())
        .fold(0.0, f64::max);
    let dead = 0.05 * vmax;
    let inf: Vec<usize> = (0..resid.len())
        .filter(|&i| mask[i] && sig.vdot[i] > dead)
        .collect();
    let def: Vec<usize> = (0..resid.len())
        .filter(|&i| mask[i] && sig.vdot[i] < -dead)
        .collect();
    let (vlo, vhi) = (0..resid.len())
        .filter(|&i| mask[i])
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), i| {
            (a.min(sig.v[i]), b.max(sig.v[i]))
        });
    let speed: Vec<f64> = sig.vdot.iter().map(|f| f.abs()).collect();
    let stats = |idx: &[usize]| {
        let m = idx.iter().map(|&i| resid[i]).sum::<f64>() / idx.len().max(1) as f64;
        let var = idx.iter().map(|&i| (resid[i] - m).powi(2)).sum::<f64>()
            / (idx.len().max(2) - 1) as f64;
        (m, var, idx.len())
    };
    let (mi, vi, ni) = stats(&inf);
    let (md, vd, nd) = stats(&def);
    let rho = lag1(resid, mask);
    let se = (vi / n_eff(ni, rho).max(1.0) + vd / n_eff(nd, rho).max(1.0)).sqrt();
    Direction {
        inflation_vs_v: binned(sig.v, resid, &inf, vlo, vhi, 12),
        deflation_vs_v: binned(sig.v, resid, &def, vlo, vhi, 12),
        inflation_vs_speed: binned(&speed, resid, &inf, 0.0, vmax * 1.0001, 10),
        deflation_vs_speed: binned(&speed, resid, &def, 0.0, vmax * 1.0001, 10),
        mean_inflation: mi,
        mean_deflation: md,
        t_stat: if se > 0.0 && ni > 1 && nd > 1 {
            (mi - md) / se
        } else {
            0.0
        },
    }
}

/// The residual's Welch spectrum and its strongest peak above the two lowest bins.
fn spectrum(resid: &[f64], mask: &[bool], dt: f64) -> Spectrum {
    let (freq_hz, psd) = welch(resid, mask, 1.0 / dt, 1024);
    let skip = 2.min(psd.len().saturating_sub(1));
    let (pk, _) =
        psd.iter()
            .enumerate()
            .skip(skip)
            .fold((skip, f64::NEG_INFINITY), |acc, (i, &p)| {
                if p > acc.1 {
                    (i, p)
                } else {
                    acc
                }
            });
    let total: f64 = psd.iter().sum();
    let band: f64 = psd[pk.saturating_sub(1)..(pk + 2).min(psd.len())]
        .iter()
        .sum();
    let mut sorted = psd.clone();
    sorted.sort_by(f64::total_cmp);
    let median = sorted[sorted.len() / 2];
    Spectrum {
        peak_hz: freq_hz.get(pk).copied().unwrap_or(0.0),
        peak_share: if total > 0.0 { band / total } else { 0.0 },
        peak_over_median: if median > 0.0 { psd[pk] / median } else { 0.0 },
        freq_hz,
        psd,
    }
}

/// Structure left in a residual that no candidate explained, described by its signature: a
/// sentence, and for programs the numbers it names.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Signature {
    /// `autocorrelation`, `follows_input`, `periodic`, `direction`, `unphysical_fit` or
    /// `indistinct_from_absent` (an effect the test kept whose interval reaches its absent value).
    pub kind: &'static str,
    /// One plain sentence.
    pub description: String,
    /// The lag (s) of the largest autocorrelation, or at which the residual follows the input.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub lag_s: Option<f64>,
    /// The input the residual follows (`v`, `vdot`, `vddot`, …).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub input: Option<&'static str>,
    /// The spectral peak's frequency (Hz).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub frequency_hz: Option<f64>,
    /// Whether that frequency is the cycle rate or one of its first 20 harmonics; absent when
    /// the log's cycles do not repeat regularly.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cycle_locked: Option<bool>,
}

/// Signatures of a residual that fails the whiteness test (`lb_p_value < alpha`); empty otherwise.
/// `harmonic(f)` is the harmonic of the log's cycle rate a frequency is locked to, if any, and
/// `None` when the cycles do not repeat regularly (`effects::ripple::cycle_harmonic`).
pub fn signatures(
    a: &ResidualAnalysis,
    alpha: f64,
    harmonic: impl Fn(f64) -> Option<Option<f64>>,
) -> Vec<Signature> {
    let w = &a.whiteness;
    if w.lb_p_value.is_nan() || w.lb_p_value >= alpha {
        return Vec::new();
    }
    [
        Some(autocorrelation_signature(w)),
        input_signature(a),
        peak_signature(&a.spectrum, harmonic),
        direction_signature(a),
    ]
    .into_iter()
    .flatten()
    .collect()
}

/// The largest autocorrelation and how many lags stay correlated.
fn autocorrelation_signature(w: &Whiteness) -> Signature {
    let (k, r) = w
        .acf
        .iter()
        .enumerate()
        .skip(1)
        .fold((1usize, 0.0f64), |acc, (k, &r)| {
            if r.abs() > acc.1.abs() {
                (k, r)
            } else {
                acc
            }
        });
    let beyond = w
        .acf
        .iter()
        .skip(1)
        .take_while(|r| r.abs() > w.band)
        .count();
    Signature {
        kind: "autocorrelation",
        description: format!(
            "residual is not white (Ljung–Box Q = {:.1} over {} lags, p = {:.2e}); largest autocorrelation {:.2} at lag {} ({:.3} s); correlated for {} consecutive lags ({:.2} s)",
            w.lb_q,
            w.lb_lags,
            w.lb_p_value,
            r,
            k,
            k as f64 * w.lag_s,
            beyond,
            beyond as f64 * w.lag_s
        ),
        lag_s: Some(k as f64 * w.lag_s),
        ..Signature::default()
    }
}

/// The input the residual follows most (correlation over twice the whiteness band), if any.
fn input_signature(a: &ResidualAnalysis) -> Option<Signature> {
    let w = &a.whiteness;
    let c = a
        .cross
        .iter()
        .filter(|c| c.peak_value.abs() > 2.0 * w.band)
        .max_by(|x, y| x.peak_value.abs().total_cmp(&y.peak_value.abs()))?;
    Some(Signature {
        kind: "follows_input",
        description: format!(
            "residual follows {} (correlation {:.2} at lag {} samples = {:.3} s, {} leading)",
            c.input,
            c.peak_value,
            c.peak_lag,
            c.peak_lag as f64 * w.lag_s,
            if c.peak_lag >= 0 { "input" } else { "residual" }
        ),
        lag_s: Some(c.peak_lag as f64 * w.lag_s),
        input: Some(c.input),
        ..Signature::default()
    })
}

/// A spectral peak holding over a tenth of the power at 20× the median level, with whether it is
/// locked to the cycles.
fn peak_signature(
    s: &Spectrum,
    harmonic: impl Fn(f64) -> Option<Option<f64>>,
) -> Option<Signature> {
    let strong = s.peak_over_median > 20.0 && s.peak_share > 0.1;
    if !strong {
        return None;
    }
    let locked = harmonic(s.peak_hz);
    let lock = match locked {
        Some(Some(h)) => format!("; locked to the cycles (harmonic {h} of the cycle rate)"),
        Some(None) => "; not locked to the cycles".to_string(),
        None => String::new(),
    };
    Some(Signature {
        kind: "periodic",
        description: format!(
            "spectral peak at {:.3} Hz holding {:.0} % of the residual power ({:.0}× the median level){lock}",
            s.peak_hz,
            100.0 * s.peak_share,
            s.peak_over_median
        ),
        frequency_hz: Some(s.peak_hz),
        cycle_locked: locked.map(|h| h.is_some()),
        ..Signature::default()
    })
}

/// A mean residual that differs by direction (|t| > 3.29).
fn direction_signature(a: &ResidualAnalysis) -> Option<Signature> {
    let differs = a.direction.t_stat.abs() > 3.29;
    if !differs {
        return None;
    }
    Some(Signature {
        kind: "direction",
        description: format!(
            "residual differs by direction: {:+.3} kPa inflating vs {:+.3} kPa deflating (t = {:.1})",
            a.direction.mean_inflation, a.direction.mean_deflation, a.direction.t_stat
        ),
        ..Signature::default()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_noise_passes_and_sine_fails_whiteness() {
        // Deterministic white-ish sequence from a linear congruential generator.
        let mut s: u64 = 12345;
        let noise: Vec<f64> = (0..4000)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64) - 0.5
            })
            .collect();
        let t: Vec<f64> = (0..4000).map(|k| k as f64 * 0.04).collect();
        let zeros = vec![0.0; 4000];
        let sig = Signals {
            t: &t,
            v: &t,
            vdot: &zeros,
            vddot: &zeros,
        };
        let mask = vec![true; 4000];
        let a = analyse(&sig, &noise, &mask, 40);
        assert!(
            a.whiteness.lb_p_value > 0.001,
            "white noise rejected: {}",
            a.whiteness.lb_p_value
        );
        let sine: Vec<f64> = t
            .iter()
            .zip(&noise)
            .map(|(t, n)| (2.0 * std::f64::consts::PI * 3.0 * t).sin() + n)
            .collect();
        let b = analyse(&sig, &sine, &mask, 40);
        assert!(b.whiteness.lb_p_value < 1e-6);
        // Welch peak within one bin (25/1024 Hz) of 3 Hz.
        assert!(
            (b.spectrum.peak_hz - 3.0).abs() < 0.03,
            "peak {}",
            b.spectrum.peak_hz
        );
        let periodic = |h: Option<Option<f64>>| {
            signatures(&b, 0.01, |_| h)
                .into_iter()
                .find(|s| s.kind == "periodic")
                .expect("a periodic signature")
        };
        // Without a regular cycle the lock is not judged; otherwise it is said either way.
        let free = periodic(None);
        assert_eq!(
            (free.frequency_hz, free.cycle_locked),
            (Some(b.spectrum.peak_hz), None)
        );
        let locked = periodic(Some(Some(3.0)));
        assert_eq!(locked.cycle_locked, Some(true));
        assert!(locked.description.contains("harmonic 3 of the cycle rate"));
        let unlocked = periodic(Some(None));
        assert_eq!(unlocked.cycle_locked, Some(false));
        assert!(unlocked.description.contains("not locked"));
        // The autocorrelation's lag is a whole number of samples.
        let ac = signatures(&b, 0.01, |_| None).remove(0);
        assert_eq!(ac.kind, "autocorrelation");
        let lag = ac.lag_s.expect("a lag");
        assert!((lag / 0.04 - (lag / 0.04).round()).abs() < 1e-9 && lag > 0.0);
    }

    #[test]
    fn psd_integrates_to_variance() {
        // Parseval: ∫ PSD df ≈ variance for a sine of amplitude 2 (variance 2).
        let t: Vec<f64> = (0..8192).map(|k| k as f64 * 0.01).collect();
        let x: Vec<f64> = t
            .iter()
            .map(|t| 2.0 * (2.0 * std::f64::consts::PI * 7.3 * t).sin())
            .collect();
        let (f, p) = welch(&x, &vec![true; x.len()], 100.0, 1024);
        let df = f[1] - f[0];
        let power: f64 = p.iter().sum::<f64>() * df;
        assert!((power - 2.0).abs() < 0.05, "power {power}");
    }
}
