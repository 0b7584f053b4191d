//! Logs of other rigs: a lung-like chamber breathed by a ventilator, written straight through a
//! known law at any sample rate (no firmware, no syringe).
//!
//! The firmware's sampler runs at one frame rate and the plant is a syringe pump; the logs other
//! labs bring (ventilators, lung simulators, 100–512 Hz) differ in what matters to the selection
//! of the polynomial's shape: the operating point moves during the log (a PEEP step), the breath
//! rate changes, breaths differ from one another, and the law's flow dependence ranges from linear
//! to strongly nonlinear. This module writes such logs in the actuation-log format
//! (`docs/log-format.md`) with every sample computed from a law whose form and coefficients are
//! known, so a selection can be scored against the truth.
//!
//! # Boundary
//! Simulated: the volume and flow a pressure-controlled ventilator delivers (exponential flow
//! decay in inspiration and passive expiration, per breath), the chamber's pressure from a known
//! law of volume and flow, operating-point steps (end-expiratory volume and pressure baseline),
//! changing rates, breath-to-breath variation, and Gaussian noise on pressure and flow. Not
//! simulated: the ventilator's control loop, sensor dynamics, the firmware, anything a syringe
//! does.
//!
//! # The trajectory of breath k
//! Period T_k (the rate goes linearly from `period_s.0` to `period_s.1` over the log),
//! inspiration T_i = f_k T_k, tidal volume V_k, time constant τ_k; f, V and τ vary from breath to
//! breath by a factor (1 + `variation`·z), z standard normal clipped to ±2. With t from the
//! breath's start and s = t − T_i:
//!
//! ```text
//! v(t) = b(t) + V_k (1 − e^(−t/τ_k)) / (1 − e^(−T_i/τ_k))                  inspiration
//! v(t) = b(t) + V_k (e^(−s/τ_e) − e^(−T_e/τ_e)) / (1 − e^(−T_e/τ_e))       expiration, τ_e = 1.5 τ_k
//! ```
//!
//! b(t) is the end-expiratory volume: each operating-point step adds Δv (1 − e^(−(t−t_s)/τ_s)),
//! τ_s = 2 s (the lung fills to the new PEEP over a few breaths), and the pressure baseline steps
//! by Δp at t_s. The logged flow is dv/dt (analytic) plus noise.
//!
//! # The law
//! P = p₀ + Δp(t) + E(v) + R(v̇) with
//!
//! ```text
//! E(v) = e·v + a (e^(v/v_s) − 1)           elastance, stiffening above v_s (a = 0: linear)
//! R(q) = r₁ q + r₂ q|q|                    Rohrer (r₂ = 0: linear resistance)
//!      + r_v q_v tanh(q / q_v)             a flow-limiting valve (r_v = 0: none)
//! ```
//!
//! Linear resistance needs flow degree 1; the Rohrer term (|q| is not a polynomial) and the valve
//! need high odd flow degrees, more the sharper they are.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use std::io::Write;

/// A chamber's law of volume and flow (module docs, "The law"). Units: mm³, mm³/s, kPa.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LungLaw {
    /// Pressure at zero volume and flow p₀, kPa.
    pub p0_kpa: f64,
    /// Linear elastance e, kPa/mm³.
    pub elastance: f64,
    /// Amplitude a of the stiffening term, kPa (0: linear elastance).
    pub stiffening_kpa: f64,
    /// Volume scale v_s of the stiffening, mm³.
    pub stiffening_mm3: f64,
    /// Linear resistance r₁, kPa·s/mm³.
    pub r1: f64,
    /// Turbulent resistance r₂ (Rohrer), kPa·s²/mm⁶.
    pub r2: f64,
    /// Valve resistance r_v at small flow, kPa·s/mm³ (0: no valve).
    pub valve_r: f64,
    /// Flow q_v at which the valve saturates, mm³/s.
    pub valve_q: f64,
}

impl LungLaw {
    /// P at volume `v` and flow `q`, without the baseline step Δp.
    pub fn pressure(&self, v: f64, q: f64) -> f64 {
        let stiff = if self.stiffening_kpa != 0.0 {
            self.stiffening_kpa * (libm::exp(v / self.stiffening_mm3) - 1.0)
        } else {
            0.0
        };
        let valve = if self.valve_r != 0.0 {
            self.valve_r * self.valve_q * libm::tanh(q / self.valve_q)
        } else {
            0.0
        };
        self.p0_kpa + self.elastance * v + stiff + self.r1 * q + self.r2 * q * q.abs() + valve
    }
}

/// A step of the operating point (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct OperatingStep {
    /// When, as a fraction of the log's breaths (0..1): the step starts with that breath.
    pub at_fraction: f64,
    /// Change of the end-expiratory volume Δv, mm³.
    pub volume_mm3: f64,
    /// Change of the pressure baseline Δp, kPa (what the volume column does not see).
    pub pressure_kpa: f64,
}

/// Everything that defines one breath log.
#[derive(Clone, Debug, PartialEq)]
pub struct BreathLog {
    /// Label, written to the log's metadata.
    pub name: String,
    /// Sample rate, Hz.
    pub sample_hz: f64,
    /// Number of breaths.
    pub breaths: usize,
    /// Breath period at the start and at the end of the log, s (linear in between).
    pub period_s: (f64, f64),
    /// Inspiratory fraction of the period.
    pub inspiratory_fraction: f64,
    /// Tidal volume, mm³.
    pub tidal_mm3: f64,
    /// Inspiratory time constant τ, s.
    pub tau_s: f64,
    /// Relative breath-to-breath variation of f, V and τ (standard deviation).
    pub variation: f64,
    /// Operating-point steps.
    pub steps: Vec<OperatingStep>,
    /// The law.
    pub law: LungLaw,
    /// Pressure noise (standard deviation), kPa.
    pub noise_kpa: f64,
    /// Flow noise, as a fraction of the mean peak flow.
    pub flow_noise: f64,
    /// Noise seed: same seed, same log.
    pub seed: u64,
}

/// The columns of a breath log.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct BreathRun {
    /// Time, s.
    pub t: Vec<f64>,
    /// Volume, mm³.
    pub v: Vec<f64>,
    /// Logged flow (true flow plus noise), mm³/s.
    pub q: Vec<f64>,
    /// Logged pressure (law plus noise), kPa.
    pub p: Vec<f64>,
    /// The law's pressure without noise, kPa.
    pub p_true: Vec<f64>,
}

/// Why a breath log cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("breath log {name}: {message}")]
pub struct BreathLogError {
    /// The log's name.
    pub name: String,
    /// What is wrong.
    pub message: String,
}

impl BreathLog {
    /// Samples the log (module docs). `Err` on a setting that gives no samples or no breath.
    pub fn run(&self) -> Result<BreathRun, BreathLogError> {
        let bad = |message: &str| BreathLogError {
            name: self.name.clone(),
            message: message.into(),
        };
        let positive = |x: f64| x.is_finite() && x > 0.0;
        if !positive(self.sample_hz) {
            return Err(bad("the sample rate must be positive"));
        }
        if self.breaths == 0 {
            return Err(bad("at least one breath is needed"));
        }
        if !positive(self.period_s.0) || !positive(self.period_s.1) || !positive(self.tau_s) {
            return Err(bad("periods and the time constant must be positive"));
        }
        if !(self.inspiratory_fraction > 0.05 && self.inspiratory_fraction < 0.95) {
            return Err(bad("the inspiratory fraction must lie in (0.05, 0.95)"));
        }
        if !(self.variation >= 0.0 && self.variation < 0.4) {
            return Err(bad("the variation must lie in [0, 0.4)"));
        }
        if !(self.noise_kpa >= 0.0 && self.flow_noise >= 0.0) {
            return Err(bad("noise must not be negative"));
        }
        let mut rng = ChaCha8Rng::seed_from_u64(self.seed);
        let z = Normal::new(0.0, 1.0).expect("unit normal");
        let jitter = |rng: &mut ChaCha8Rng| {
            let x: f64 = z.sample(rng);
            1.0 + self.variation * x.clamp(-2.0, 2.0)
        };
        let dt = 1.0 / self.sample_hz;
        let peak_flow = self.tidal_mm3 / self.tau_s;
        let flow_noise = Normal::new(0.0, self.flow_noise * peak_flow).expect("finite");
        let p_noise = Normal::new(0.0, self.noise_kpa).expect("finite");
        let tau_step = 2.0;
        let mut run = BreathRun::default();
        let mut start = 0.0;
        let mut step_times: Vec<(f64, OperatingStep)> = Vec::new();
        for k in 0..self.breaths {
            let frac = k as f64 / self.breaths as f64;
            for s in &self.steps {
                let first = (s.at_fraction * self.breaths as f64).round() as usize;
                if first == k {
                    step_times.push((start, *s));
                }
            }
            let period = self.period_s.0 + (self.period_s.1 - self.period_s.0) * frac;
            let ti = period * (self.inspiratory_fraction * jitter(&mut rng)).clamp(0.1, 0.8);
            let te = period - ti;
            let vt = self.tidal_mm3 * jitter(&mut rng);
            let tau = self.tau_s * jitter(&mut rng);
            let tau_e = 1.5 * tau;
            let ni = 1.0 - libm::exp(-ti / tau);
            let ne = 1.0 - libm::exp(-te / tau_e);
            // Samples on the log's own clock: the first at or after the breath's start.
            let mut i = (start / dt).ceil() as usize;
            loop {
                let t = i as f64 * dt;
                if t >= start + period {
                    break;
                }
                let tb = t - start;
                let (vr, qr) = if tb < ti {
                    let e = libm::exp(-tb / tau);
                    (vt * (1.0 - e) / ni, vt * e / (tau * ni))
                } else {
                    let s = tb - ti;
                    let e = libm::exp(-s / tau_e);
                    let end = libm::exp(-te / tau_e);
                    (vt * (e - end) / ne, -vt * e / (tau_e * ne))
                };
                let (mut vb, mut qb, mut dp) = (0.0, 0.0, 0.0);
                for (ts, s) in &step_times {
                    let e = libm::exp(-(t - ts) / tau_step);
                    vb += s.volume_mm3 * (1.0 - e);
                    qb += s.volume_mm3 * e / tau_step;
                    dp += s.pressure_kpa;
                }
                let (v, q) = (vb + vr, qb + qr);
                let p = self.law.pressure(v, q) + dp;
                run.t.push(t);
                run.v.push(v);
                run.q.push(q + flow_noise.sample(&mut rng));
                run.p.push(p + p_noise.sample(&mut rng));
                run.p_true.push(p);
                i += 1;
            }
            start += period;
        }
        if run.t.len() < 2 {
            return Err(bad("the log has fewer than two samples"));
        }
        Ok(run)
    }

    /// Samples the log and writes it in the actuation-log format: metadata comments, then
    /// `time_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa` (chamber 0).
    pub fn write_log(&self, mut out: impl Write) -> Result<(), BreathLogError> {
        let run = self.run()?;
        let io = |e: std::io::Error| BreathLogError {
            name: self.name.clone(),
            message: format!("cannot write: {e}"),
        };
        (|| -> std::io::Result<()> {
            writeln!(
                out,
                "# source=host-sim breath log (a known law, no firmware)"
            )?;
            writeln!(out, "# scenario={}", self.name)?;
            writeln!(out, "# seed={}", self.seed)?;
            writeln!(out, "# sample_rate_hz={}", self.sample_hz)?;
            writeln!(out, "time_s,chamber,volume_mm3,flow_mm3_s,pressure_kpa")?;
            for k in 0..run.t.len() {
                writeln!(
                    out,
                    "{:.6},0,{:.3},{:.3},{:.5}",
                    run.t[k], run.v[k], run.q[k], run.p[k]
                )?;
            }
            Ok(())
        })()
        .map_err(io)
    }
}

/// A linear lung: compliance 500 mL/kPa (≈ 50 mL/cmH₂O), resistance 0.5 kPa per L/s, baseline
/// 0.5 kPa; the stiffening, Rohrer and valve terms off.
const LINEAR: LungLaw = LungLaw {
    p0_kpa: 0.5,
    elastance: 2.0e-6,
    stiffening_kpa: 0.0,
    stiffening_mm3: 1.0,
    r1: 5.0e-7,
    r2: 0.0,
    valve_r: 0.0,
    valve_q: 1.0,
};

/// Logs that move the selection's ground from under it (module docs), each from a known law:
/// operating-point steps, changing rates, breath-to-breath variation, 100 to 512 Hz, laws that
/// need flow degree 1 and laws that need high odd flow degrees. `seed` varies the noise and the
/// breaths, not the settings.
pub fn suite(seed: u64) -> Vec<BreathLog> {
    let base = BreathLog {
        name: String::new(),
        sample_hz: 100.0,
        breaths: 30,
        period_s: (4.0, 4.0),
        inspiratory_fraction: 0.35,
        tidal_mm3: 450_000.0,
        tau_s: 0.25,
        variation: 0.05,
        steps: Vec::new(),
        law: LINEAR,
        noise_kpa: 0.01,
        flow_noise: 0.005,
        seed,
    };
    vec![
        // PEEP 0.5 → 2 kPa mid-log: the lung fills by 300 mL and the baseline pressure the volume
        // column does not see rises by 0.3 kPa; Rohrer resistance (high flow degree).
        BreathLog {
            name: "peep-step-rohrer-100hz".into(),
            steps: vec![OperatingStep {
                at_fraction: 0.5,
                volume_mm3: 300_000.0,
                pressure_kpa: 0.3,
            }],
            law: LungLaw {
                r1: 2.0e-7,
                r2: 4.0e-13,
                ..LINEAR
            },
            ..base.clone()
        },
        // Rate from 10 to 30 breaths/min, a stiffening lung and linear resistance (flow
        // degree 1, high volume degree), 200 Hz.
        BreathLog {
            name: "rate-ramp-stiffening-200hz".into(),
            sample_hz: 200.0,
            breaths: 40,
            period_s: (6.0, 2.0),
            law: LungLaw {
                stiffening_kpa: 0.05,
                stiffening_mm3: 120_000.0,
                ..LINEAR
            },
            ..base.clone()
        },
        // Breaths differ by 20 % in tidal volume, inspiratory time and time constant; a
        // flow-limiting valve (saturating in flow: high odd flow degree), 512 Hz.
        BreathLog {
            name: "varied-breaths-valve-512hz".into(),
            sample_hz: 512.0,
            breaths: 24,
            period_s: (3.0, 3.0),
            variation: 0.2,
            law: LungLaw {
                r1: 1.0e-7,
                valve_r: 1.5e-6,
                valve_q: 6.0e5,
                ..LINEAR
            },
            ..base.clone()
        },
        // Two operating-point steps (up, then down past the start), the rate rising from 12 to
        // 20 breaths/min and 10 % breath variation; linear in flow, mildly stiffening, 100 Hz.
        BreathLog {
            name: "peep-up-down-linear-100hz".into(),
            breaths: 45,
            period_s: (5.0, 3.0),
            variation: 0.1,
            steps: vec![
                OperatingStep {
                    at_fraction: 0.33,
                    volume_mm3: 250_000.0,
                    pressure_kpa: 0.2,
                },
                OperatingStep {
                    at_fraction: 0.67,
                    volume_mm3: -350_000.0,
                    pressure_kpa: -0.3,
                },
            ],
            law: LungLaw {
                stiffening_kpa: 0.02,
                stiffening_mm3: 200_000.0,
                ..LINEAR
            },
            ..base.clone()
        },
        // Everything at once at 250 Hz: a step, a rate change, varied breaths and Rohrer plus
        // valve resistance.
        BreathLog {
            name: "step-ramp-varied-turbulent-250hz".into(),
            sample_hz: 250.0,
            breaths: 36,
            period_s: (3.0, 4.5),
            variation: 0.15,
            steps: vec![OperatingStep {
                at_fraction: 0.6,
                volume_mm3: 200_000.0,
                pressure_kpa: 0.5,
            }],
            law: LungLaw {
                r1: 1.0e-7,
                r2: 3.0e-13,
                valve_r: 6.0e-7,
                valve_q: 4.0e5,
                stiffening_kpa: 0.03,
                stiffening_mm3: 150_000.0,
                ..LINEAR
            },
            ..base
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_logged_flow_is_the_volumes_derivative() {
        let mut log = suite(1).remove(3);
        log.flow_noise = 0.0;
        let r = log.run().unwrap();
        let dt = 1.0 / log.sample_hz;
        let peak = r.q.iter().fold(0.0f64, |a, q| a.max(q.abs()));
        // Central differences away from the breath boundaries (where the flow jumps).
        let mut checked = 0;
        for k in 1..r.t.len() - 1 {
            let d = (r.v[k + 1] - r.v[k - 1]) / (2.0 * dt);
            let smooth = (r.q[k + 1] - r.q[k - 1]).abs() < 0.05 * peak;
            if smooth {
                assert!((d - r.q[k]).abs() < 0.02 * peak, "k {k}: {d} vs {}", r.q[k]);
                checked += 1;
            }
        }
        assert!(checked > r.t.len() / 2);
    }

    #[test]
    fn the_pressure_is_the_law_plus_the_baseline_step() {
        let mut log = suite(2).remove(0);
        log.noise_kpa = 0.0;
        log.flow_noise = 0.0;
        let r = log.run().unwrap();
        let half = r.t.len() / 2;
        // Before the step: exactly the law; long after it: the law plus Δp.
        for k in [10, half / 2] {
            assert_eq!(r.p[k], log.law.pressure(r.v[k], r.q[k]));
        }
        let k = r.t.len() - 10;
        assert!((r.p[k] - log.law.pressure(r.v[k], r.q[k]) - 0.3).abs() < 1e-12);
    }

    #[test]
    fn bad_settings_are_errors() {
        let mut log = suite(1).remove(0);
        log.sample_hz = 0.0;
        assert!(log.run().is_err());
        let mut log = suite(1).remove(0);
        log.breaths = 0;
        assert!(log.run().unwrap_err().to_string().contains("breath"));
    }
}
