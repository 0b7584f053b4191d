//! Synthetic data with a known answer: the paper's protocol-like trajectory and a known
//! polynomial pressure law plus Gaussian noise. Used by the tests, the benchmark and demos.
//!
//! The trajectory repeats inflation 0 → `v_max` and deflation back at each flow rate in turn
//! (trapezoidal flow with acceleration `accel`, a dwell at both ends), sampled at `sample_hz`,
//! with the volume quantised to the pump's 0.04 mm³ step as the real rig logs it.

use rand::SeedableRng;
use rand_distr::{Distribution, Normal};

/// Pump volume per motor step, mm³.
pub const STEP_MM3: f64 = 0.04;

/// The (n = 3, m = 2) law identified for SBA1 in the paper's Table IV (αᵢⱼ at index i·3 + j,
/// raw units): model-core's constant, re-exported for the generators here.
pub use model_core::poly::SBA1_RAW;

/// Evaluates Σ αᵢⱼ vⁱ v̇ʲ for raw coefficients at index i·(m+1)+j.
pub fn eval_raw(raw: &[f64], n: usize, m: usize, v: f64, vdot: f64) -> f64 {
    assert_eq!(raw.len(), (n + 1) * (m + 1));
    (0..=n)
        .map(|i| {
            (0..=m)
                .map(|j| raw[i * (m + 1) + j] * v.powi(i as i32) * vdot.powi(j as i32))
                .sum::<f64>()
        })
        .sum()
}

/// A protocol-like actuation trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Protocol {
    /// Flow rates visited in turn, mm³/s.
    pub rates: Vec<f64>,
    /// Inflation volume, mm³.
    pub v_max: f64,
    /// Flow ramp acceleration, mm³/s².
    pub accel: f64,
    /// Rest at each end, s.
    pub dwell_s: f64,
    /// Sampling rate, Hz.
    pub sample_hz: f64,
    /// Total samples.
    pub samples: usize,
}

impl Default for Protocol {
    /// The paper's protocol: 0 ↔ 550 mm³ at 20, 40, …, 100 mm³/s, 25 Hz, 83 000 samples.
    fn default() -> Self {
        Self {
            rates: vec![20.0, 40.0, 60.0, 80.0, 100.0],
            v_max: 550.0,
            accel: 200.0,
            dwell_s: 1.0,
            sample_hz: 25.0,
            samples: 83_000,
        }
    }
}

/// Sampled trajectory: time, step-quantised volume and the exact commanded flow.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    /// s.
    pub t: Vec<f64>,
    /// mm³ (multiples of [`STEP_MM3`]).
    pub v: Vec<f64>,
    /// mm³/s.
    pub vdot: Vec<f64>,
}

impl Protocol {
    /// Samples the trajectory.
    pub fn trajectory(&self) -> Trajectory {
        assert!(
            !self.rates.is_empty() && self.rates.iter().all(|&r| r > 0.0),
            "rates must be positive"
        );
        let dt = 1.0 / self.sample_hz;
        // Integrate the commanded flow on a fine grid (exact for the trapezoid up to dt/sub).
        let sub = 20;
        let h = dt / sub as f64;
        let mut out = Trajectory::default();
        let (mut v, mut q) = (0.0f64, 0.0f64);
        let mut seg = 0usize; // segment index: rate seg/2, even = inflate, odd = deflate
        let mut dwell_left = self.dwell_s;
        for k in 0..self.samples {
            out.t.push(k as f64 * dt);
            out.v.push((v / STEP_MM3).round() * STEP_MM3);
            out.vdot.push(q);
            for _ in 0..sub {
                let rate = self.rates[(seg / 2) % self.rates.len()];
                let dir = if seg.is_multiple_of(2) { 1.0 } else { -1.0 };
                if dwell_left > 0.0 {
                    dwell_left -= h;
                    q = 0.0;
                    continue;
                }
                let remaining = if dir > 0.0 { self.v_max - v } else { v };
                // Decelerate so the flow reaches zero at the end volume: q² = 2·a·remaining.
                let q_stop = (2.0 * self.accel * remaining.max(0.0)).sqrt();
                let target = rate.min(q_stop);
                let qa = q.abs();
                let next = if qa < target {
                    (qa + self.accel * h).min(target)
                } else {
                    target
                };
                q = dir * next;
                v += q * h;
                if remaining <= 1e-6 || (next == 0.0 && remaining < 1e-3) {
                    v = if dir > 0.0 { self.v_max } else { 0.0 };
                    q = 0.0;
                    seg += 1;
                    dwell_left = self.dwell_s;
                }
            }
        }
        out
    }
}

/// Pressure from raw (n, m) coefficients plus N(0, σ²) noise, seeded.
pub fn pressure(
    raw: &[f64],
    n: usize,
    m: usize,
    traj: &Trajectory,
    sigma: f64,
    seed: u64,
) -> Vec<f64> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let noise = Normal::new(0.0, sigma.max(0.0)).expect("σ is finite and non-negative");
    traj.v
        .iter()
        .zip(&traj.vdot)
        .map(|(&v, &q)| eval_raw(raw, n, m, v, q) + noise.sample(&mut rng))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn trajectory_follows_the_protocol() {
        let p = Protocol {
            samples: 5000,
            ..Protocol::default()
        };
        let tr = p.trajectory();
        let vmax = tr.v.iter().cloned().fold(f64::MIN, f64::max);
        let vmin = tr.v.iter().cloned().fold(f64::MAX, f64::min);
        assert!((vmax - 550.0).abs() < 1e-9 && vmin.abs() < 1e-9);
        assert!(tr.vdot.iter().all(|q| q.abs() <= 100.0 + 1e-9));
        // The volume is the integral of the flow (to quantisation and the ramp discretisation).
        let dt = 1.0 / p.sample_hz;
        for k in 1..tr.v.len() {
            let approx = 0.5 * (tr.vdot[k] + tr.vdot[k - 1]) * dt;
            assert!(
                (tr.v[k] - tr.v[k - 1] - approx).abs() < 0.2 + 100.0 * dt * 0.2,
                "k = {k}"
            );
        }
        assert!(tr
            .v
            .iter()
            .all(|v| ((v / STEP_MM3).round() * STEP_MM3 - v).abs() < 1e-9));
    }

    #[test]
    fn sba1_law_is_the_papers_scale() {
        // Table IV at 550 mm³ and rest: 6.98 − 24.40 + 68.66 ≈ 51.24 kPa (hand-computed).
        let p = eval_raw(&SBA1_RAW, 3, 2, 550.0, 0.0);
        assert!((p - 51.24).abs() < 0.05, "{p}");
    }
}
