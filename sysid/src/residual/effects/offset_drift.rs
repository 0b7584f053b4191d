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
    use super::legendre;

    #[test]
    fn legendre_known_values() {
        assert!((legendre(2, 0.5) - (-0.125)).abs() < 1e-15);
        assert!((legendre(3, 0.5) - (-0.4375)).abs() < 1e-15);
        assert!((legendre(3, 1.0) - 1.0).abs() < 1e-15);
    }
}
