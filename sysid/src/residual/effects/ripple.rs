//! Ripple: a periodic disturbance at one frequency f, two added columns
//! `a sin 2πf(t − t₀) + b cos 2πf(t − t₀)`; f is read off the residual's Welch spectrum and refined
//! ([`Search::Spectral`]).

use super::{
    param, Column, DeviceSupport, Effect, EffectModel, Fitted, Param, Prepared, Scales, Search,
};

/// Periodic ripple at one frequency.
pub struct Ripple;

impl EffectModel for Ripple {
    fn name(&self) -> &'static str {
        "ripple"
    }

    fn story(&self) -> &'static str {
        "A periodic disturbance at one frequency (pump or motor ripple, mains pickup) rides on the pressure."
    }

    fn search(&self, _sc: &Scales) -> Search {
        Search::Spectral
    }

    /// Not at the cycle rate or one of its first 20 harmonics when the log's cycles repeat
    /// regularly (`Scales::cycle_s`): a sinusoid locked to the cycles is the model's misfit over a
    /// cycle (its shape, repeated every cycle), not a disturbance of its own. Within
    /// `max(1/duration, 1 % of f)` of `h/T` counts as locked: the frequency resolution of the log,
    /// or the cycle period's own spread at that harmonic.
    fn unphysical(&self, e: &Effect, _coefs: &[f64], sc: &Scales) -> Option<String> {
        if !e.theta.is_finite() {
            return Some("ripple frequency is not finite".into());
        }
        let period = sc.cycle_s?;
        cycle_harmonic(e.theta, sc).map(|h| {
            format!(
                "its frequency {:.4} Hz is harmonic {h} of the cycle rate ({:.4} Hz, period {period:.3} s): structure locked to the cycles is the model's misfit over a cycle, not a ripple",
                e.theta,
                1.0 / period
            )
        })
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn columns(&self, e: &Effect, prep: &Prepared, _v: &[f64]) -> Vec<Column> {
        let t = &prep.series.t;
        let t0 = t[0];
        let w = 2.0 * std::f64::consts::PI * e.theta;
        vec![
            Column::new(
                t.iter().map(|&tk| (w * (tk - t0)).sin()).collect(),
                "ripple sin",
            ),
            Column::new(
                t.iter().map(|&tk| (w * (tk - t0)).cos()).collect(),
                "ripple cos",
            ),
        ]
    }

    fn nonnegative(&self, name: &str) -> bool {
        name == "amplitude"
    }
    fn presence(&self) -> Option<&'static str> {
        Some("amplitude")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        let (amp, se) = amplitude(f, (0.0, 0.0));
        vec![
            param("frequency", f.effect.theta, f.theta_se, "Hz"),
            param("amplitude", amp, se, "kPa"),
        ]
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::host_only(
            "depends on absolute phase of a clock the device does not share with the log",
        )
    }
}

/// The harmonic h of the log's cycle rate (1 ≤ h ≤ 20) that `f_hz` is locked to, when the log's
/// cycles repeat regularly (`Scales::cycle_s`): within `max(1/duration, 1 % of f)` of `h/T`, the
/// frequency resolution of the log or the cycle period's own spread at that harmonic.
pub fn cycle_harmonic(f_hz: f64, sc: &Scales) -> Option<f64> {
    let period = sc.cycle_s?;
    let h = (f_hz * period).round();
    let tol = (1.0 / sc.duration).max(0.01 * f_hz);
    ((1.0..=20.0).contains(&h) && (f_hz - h / period).abs() <= tol).then_some(h)
}

/// Amplitude `√(a² + b²)` of a sine–cosine pair, `(a, b)` the first two columns' coefficients
/// plus `offset`, with its standard error by the delta method,
/// `var = s²(a² Σ_aa + b² Σ_bb + 2ab Σ_ab)/(a² + b²)`.
pub fn amplitude(f: &Fitted, offset: (f64, f64)) -> (f64, f64) {
    let (a, c) = (f.coef(0) + offset.0, f.coef(1) + offset.1);
    let amp = a.hypot(c);
    let (saa, scc, sac) = (f.cov(0, 0), f.cov(1, 1), f.cov(0, 1));
    let var = f.s2 * (a * a * saa + c * c * scc + 2.0 * a * c * sac) / (amp * amp).max(1e-300);
    (amp, var.sqrt())
}
