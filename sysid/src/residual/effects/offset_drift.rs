//! Offset drift: the sensor's zero creeping over the log, added columns `Σ_d c_d P_d(s)`,
//! d = 1…D, with `P_d` the Legendre polynomials in time scaled onto `s ∈ [−1, 1]`; the degree D
//! (at most 3) is chosen by AICc ([`Search::Degree`]).

use super::{
    param, Column, DeviceSupport, Effect, EffectModel, Fitted, Param, Prepared, Scales, Search,
};

/// Slow drift of the pressure sensor's zero.
pub struct OffsetDrift;

impl EffectModel for OffsetDrift {
    fn name(&self) -> &'static str {
        "offset_drift"
    }

    fn story(&self) -> &'static str {
        "The sensor's zero creeps slowly (warm-up, temperature), adding an offset that changes over minutes, independent of what the pump does."
    }

    fn search(&self, _sc: &Scales) -> Search {
        Search::Degree(3)
    }

    /// A drift that moves the sensor's zero over the log by less than the measured pressure's
    /// range. The drift is in the reading, so the logged pressure holds it: its range is the
    /// law's swing plus the drift's excursion, and a true drift moves less than it. A fitted
    /// excursion (max − min of `Σ c_d P_d(s)` over the log) beyond the whole range is cancelled by
    /// the law: the "drift" trades against a trend of the inputs (a volume reading creeping), not
    /// a zero.
    fn unphysical(&self, e: &Effect, coefs: &[f64], sc: &Scales) -> Option<String> {
        let x = excursion(coefs);
        if !x.is_finite() {
            return Some("offset drift is not finite".into());
        }
        (x > sc.p_range).then(|| {
            format!(
                "an offset drift of degree {} moves the sensor's zero by {x:.4} kPa over the log, {:.1} times the range of the measured pressure ({:.4} kPa): a drift of the reading is inside the reading's range",
                e.theta as usize,
                x / sc.p_range,
                sc.p_range
            )
        })
    }

    fn columns(&self, e: &Effect, prep: &Prepared, _v: &[f64]) -> Vec<Column> {
        (1..=(e.theta as usize))
            .map(|d| {
                let col = prep.s.iter().map(|&s| legendre(d, s)).collect();
                Column::new(col, format!("offset drift P{d}(s)"))
            })
            .collect()
    }

    fn presence(&self) -> Option<&'static str> {
        Some("change_over_log")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        // Change over the log: Σ_d c_d (P_d(1) − P_d(−1)) = Σ_{d odd} 2 c_d.
        let n = f.cols.len();
        let g: Vec<f64> = (0..n).map(|k| if k % 2 == 0 { 2.0 } else { 0.0 }).collect();
        let val: f64 = (0..n).map(|k| g[k] * f.coef(k)).sum();
        let mut var = 0.0;
        for a in 0..n {
            for c in 0..n {
                var += g[a] * g[c] * f.cov(a, c);
            }
        }
        vec![
            param("degree", n as f64, f64::NAN, "1"),
            param("change_over_log", val, (f.s2 * var).sqrt(), "kPa"),
        ]
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::host_only("depends on wall-clock time since the log began; on the device re-zero the sensor instead")
    }
}

/// How far the drift `Σ_d c_d P_d(s)` (`coefs[d − 1] = c_d`) moves over the log: max − min over
/// `s ∈ [−1, 1]`, on 401 points (a cubic at most: to a few parts in 10⁵ of its span).
fn excursion(coefs: &[f64]) -> f64 {
    let (lo, hi) = (0..=400).fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), i| {
        let s = i as f64 / 200.0 - 1.0;
        let y: f64 = coefs
            .iter()
            .enumerate()
            .map(|(k, c)| c * legendre(k + 1, s))
            .sum();
        (lo.min(y), hi.max(y))
    });
    hi - lo
}

/// Legendre polynomial `P_d(s)` by Bonnet's recurrence,
/// `(k + 1) P_{k+1} = (2k + 1) s P_k − k P_{k−1}`.
fn legendre(d: usize, s: f64) -> f64 {
    let (mut p0, mut p1) = (1.0, s);
    if d == 0 {
        return 1.0;
    }
    for k in 1..d {
        let p2 = ((2 * k + 1) as f64 * s * p1 - k as f64 * p0) / (k + 1) as f64;
        p0 = p1;
        p1 = p2;
    }
    p1
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::residual::effects::EffectKind;

    /// The excursion of the fitted drift against the measured pressure's range (2 kPa): a ramp
    /// `c₁ s` moves by 2|c₁|, an arch `c₂ P₂(s)` by 1.5|c₂| (P₂ runs from −1/2 to 1), the two
    /// together by what their sum spans; beyond the range the drift is refused with its numbers,
    /// inside it kept.
    #[test]
    fn a_drift_larger_than_the_pressure_range_is_not_kept() {
        let sc = Scales {
            v_range: 500.0,
            dt: 0.01,
            duration: 200.0,
            p_integral: 1000.0,
            p_pos_integral: 1000.0,
            p_range: 2.0,
            cycle_s: None,
            rig: crate::residual::Rig::Syringe,
        };
        let kind = EffectKind(&OffsetDrift);
        let judge =
            |coefs: &[f64]| kind.unphysical(&Effect::new(kind, coefs.len() as f64), coefs, &sc);
        assert!((excursion(&[1.5]) - 3.0).abs() < 1e-12);
        assert!((excursion(&[0.0, -2.0]) - 3.0).abs() < 1e-12);
        // s + P₂(s) = 1.5 s² + s − 0.5: from −2/3 at s = −1/3 to 2 at s = 1.
        assert!((excursion(&[1.0, 1.0]) - 8.0 / 3.0).abs() < 1e-4);
        let why = judge(&[1.5]).expect("3 kPa against 2");
        assert!(
            why.contains("3.0000 kPa") && why.contains("1.5 times"),
            "{why}"
        );
        assert!(why.contains("2.0000 kPa"), "{why}");
        assert!(judge(&[0.0, -2.0]).is_some());
        assert!(judge(&[1.0, 1.0]).is_some());
        assert_eq!(judge(&[0.9]), None);
        assert_eq!(judge(&[0.0, 1.2]), None);
        assert_eq!(judge(&[0.5, 0.3, -0.1]), None);
        assert!(judge(&[f64::NAN]).is_some());
    }

    #[test]
    fn legendre_known_values() {
        assert!((legendre(2, 0.5) - (-0.125)).abs() < 1e-15);
        assert!((legendre(3, 0.5) - (-0.4375)).abs() < 1e-15);
        assert!((legendre(3, 1.0) - 1.0).abs() < 1e-15);
    }
}
