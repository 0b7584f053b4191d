//! Test-data generator for the residual loop: the paper's SBA1 law (Table IV) on a protocol-like
//! trajectory, with one or more physical effects applied *by their physics* on a 1 ms grid and
//! sampled at 25 Hz, plus Gaussian sensor noise of known σ. The effects here are written from the
//! physics (Duhem-type hysteresis, a continuous lag, an integrated air-pocket ODE, …), not from the
//! regressors `sysid::residual` fits, so a diagnosis is checked against an independent truth.
//! (Used by `residual_effects.rs`: the candidates' shapes exactly as the library writes them, and
//! effects host-sim cannot inject, e.g. a ripple periodic in time; the acceptance on host-sim logs is
//! `residual_hostsim.rs`.)
#![allow(dead_code)]

use model_core::poly::SBA1_RAW;
use rand::Rng;
use rand::SeedableRng;
use rand_distr::{Distribution, Normal, StudentT};

/// An injected effect with its physical parameters.
#[derive(Clone, Copy, Debug)]
pub enum Inject {
    /// Duhem hysteresis: `dh/dv = (sgn v̇ − h)/w`, pressure `+ gap/2 · h`.
    Hysteresis { gap_kpa: f64, width_mm3: f64 },
    /// Air pocket of `volume_mm3` at atmospheric pressure in the syringe.
    Air { volume_mm3: f64 },
    /// First-order sensor lag.
    SensorLag { tau_s: f64 },
    /// Pressure reported `delay_s` late.
    Delay { delay_s: f64 },
    /// Inertance `L v̈`.
    Inertance { l: f64 },
    /// Sensor zero creeping `a (1 − e^{−t/T})`.
    OffsetDrift { kpa: f64, tau_s: f64 },
    /// Volume reading drifting at `rate` mm³/s.
    VolumeDrift { rate: f64 },
    /// Lead-screw play.
    Backlash { play_mm3: f64 },
    /// Sinusoidal ripple.
    Ripple { amp_kpa: f64, freq_hz: f64 },
    /// Sinusoidal ripple only while the plunger moves (a pump's vibration).
    GatedRipple { amp_kpa: f64, freq_hz: f64 },
    /// Leak flow `λ P`.
    Leak { lambda: f64 },
}

/// A generated log: samples at 25 Hz with the held-out mask of every 5th cycle.
pub struct Generated {
    pub t: Vec<f64>,
    pub v: Vec<f64>,
    pub vdot: Vec<f64>,
    pub p: Vec<f64>,
    pub sigma: f64,
}

fn sba1(v: f64, f: f64) -> f64 {
    let mut s = 0.0;
    for i in 0..4 {
        for j in 0..3 {
            s += SBA1_RAW[i * 3 + j] * v.powi(i as i32) * f.powi(j as i32);
        }
    }
    s
}

/// Position, velocity and acceleration at time `s` into a trapezoidal stroke of length `len` at
/// `rate` with acceleration `acc` (duration `len/rate + rate/acc`).
fn trapezoid(s: f64, len: f64, rate: f64, acc: f64) -> (f64, f64, f64) {
    let tacc = rate / acc;
    let dur = len / rate + tacc;
    if s < tacc {
        (0.5 * acc * s * s, acc * s, acc)
    } else if s < dur - tacc {
        (0.5 * acc * tacc * tacc + rate * (s - tacc), rate, 0.0)
    } else {
        let r = dur - s;
        (len - 0.5 * acc * r * r, acc * r, -acc)
    }
}

/// Commanded trajectory: for each rate, `cycles` trapezoidal inflate/deflate strokes 0 ↔ 550 mm³
/// (acceleration 400 mm³/s²), 0.5 s dwell at each end. Returns (t, v, v̇, v̈) on a 1 ms grid.
fn trajectory(rates: &[f64], cycles: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let dt = 1e-3;
    let acc = 400.0;
    let vmax = 550.0;
    let mut t = vec![];
    let mut v = vec![];
    let mut f = vec![];
    let mut a = vec![];
    let mut now = 0.0;
    let push_phase = |start: f64,
                      dir: f64,
                      rate: f64,
                      dur: f64,
                      t: &mut Vec<f64>,
                      v: &mut Vec<f64>,
                      f: &mut Vec<f64>,
                      a: &mut Vec<f64>,
                      now: &mut f64| {
        let steps = (dur / dt).round() as usize;
        for k in 0..steps {
            let (pos, vel, ac) = trapezoid(k as f64 * dt, vmax, rate, acc);
            t.push(*now);
            v.push(start + dir * pos);
            f.push(dir * vel);
            a.push(dir * ac);
            *now += dt;
        }
    };
    for &rate in rates {
        for _ in 0..cycles {
            let dur = vmax / rate + rate / acc;
            push_phase(
                0.0, 1.0, rate, dur, &mut t, &mut v, &mut f, &mut a, &mut now,
            );
            push_phase(
                vmax, 0.0, 0.0, 0.5, &mut t, &mut v, &mut f, &mut a, &mut now,
            );
            push_phase(
                vmax, -1.0, rate, dur, &mut t, &mut v, &mut f, &mut a, &mut now,
            );
            push_phase(0.0, 0.0, 0.0, 0.5, &mut t, &mut v, &mut f, &mut a, &mut now);
        }
    }
    (t, v, f, a)
}

/// An irregular trajectory with as many strokes as [`trajectory`]'s: each from where the last
/// ended to a random volume in 0..550 mm³ (at least 60 mm³ away), at a random rate between the
/// lowest and highest of `rates`, with a random dwell of 0.1–1.2 s after it (same acceleration;
/// a stroke too short to reach its rate is a triangle).
fn trajectory_irregular(
    rates: &[f64],
    cycles: usize,
    seed: u64,
) -> (Vec<f64>, Vec<f64>, Vec<f64>, Vec<f64>) {
    let (dt, acc, vmax) = (1e-3, 400.0, 550.0);
    let lo = rates.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = rates.iter().copied().fold(0.0, f64::max);
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x5eed);
    let (mut t, mut v, mut f, mut a) = (vec![], vec![], vec![], vec![]);
    let (mut now, mut pos) = (0.0, 0.0);
    for _ in 0..2 * rates.len() * cycles {
        let target = loop {
            let x: f64 = rng.random_range(0.0..vmax);
            if (x - pos).abs() >= 60.0 {
                break x;
            }
        };
        let len = (target - pos).abs();
        let dir = (target - pos).signum();
        let rate = rng.random_range(lo..=hi).min((acc * len).sqrt());
        let dur = len / rate + rate / acc;
        for k in 0..(dur / dt).round() as usize {
            let (x, vel, ac) = trapezoid(k as f64 * dt, len, rate, acc);
            t.push(now);
            v.push(pos + dir * x);
            f.push(dir * vel);
            a.push(dir * ac);
            now += dt;
        }
        pos = target;
        let dwell: f64 = rng.random_range(0.1..1.2);
        for _ in 0..(dwell / dt).round() as usize {
            t.push(now);
            v.push(pos);
            f.push(0.0);
            a.push(0.0);
            now += dt;
        }
    }
    (t, v, f, a)
}

/// The sensor noise's distribution, scaled to standard deviation σ.
#[derive(Clone, Copy, Debug, Default)]
pub enum Noise {
    /// Gaussian.
    #[default]
    Gaussian,
    /// Student's t with `dof` degrees of freedom (heavy tails; dof > 2).
    StudentT { dof: f64 },
    /// Gaussian, plus on a fraction `rate` of the samples a spike of ± `size` σ.
    Spikes { rate: f64, size: f64 },
}

/// How a generated log moves and how its noise is distributed.
#[derive(Clone, Copy, Debug, Default)]
pub struct Shape {
    /// Irregular strokes from this seed ([`trajectory_irregular`]) instead of the protocol.
    pub irregular: Option<u64>,
    /// The noise.
    pub noise: Noise,
}

/// Generates a log with `effects` injected, noise σ, seed.
pub fn generate(
    effects: &[Inject],
    rates: &[f64],
    cycles: usize,
    sigma: f64,
    seed: u64,
) -> Generated {
    generate_shaped(effects, rates, cycles, sigma, seed, Shape::default())
}

/// [`generate`] on a trajectory and with noise of the given [`Shape`].
pub fn generate_shaped(
    effects: &[Inject],
    rates: &[f64],
    cycles: usize,
    sigma: f64,
    seed: u64,
    shape: Shape,
) -> Generated {
    let (t, v, f, a) = match shape.irregular {
        Some(s) => trajectory_irregular(rates, cycles, s),
        None => trajectory(rates, cycles),
    };
    let n = t.len();
    let dt = 1e-3;
    // Volume and flow the chamber sees.
    let mut vc = v.clone();
    let mut fc = f.clone();
    for e in effects {
        match *e {
            Inject::Backlash { play_mm3 } => {
                let h = 0.5 * play_mm3;
                let mut z = vc[0];
                for k in 0..n {
                    let prev = z;
                    z = z.clamp(vc[k] - h, vc[k] + h);
                    fc[k] = if k > 0 { (z - prev) / dt } else { 0.0 };
                    vc[k] = z;
                }
            }
            Inject::VolumeDrift { rate } => {
                for k in 0..n {
                    vc[k] -= rate * t[k];
                    fc[k] -= rate;
                }
            }
            _ => {}
        }
    }
    let mut p = vec![0.0; n];
    let air = effects.iter().find_map(|e| {
        if let Inject::Air { volume_mm3 } = e {
            Some(*volume_mm3)
        } else {
            None
        }
    });
    let leak = effects.iter().find_map(|e| {
        if let Inject::Leak { lambda } = e {
            Some(*lambda)
        } else {
            None
        }
    });
    if air.is_some() || leak.is_some() {
        // Integrate the chamber volume: leak removes λP, the air pocket stores V_a P/(P_atm + P).
        let va = air.unwrap_or(0.0);
        let lam = leak.unwrap_or(0.0);
        let patm = 101.325;
        let mut lost = 0.0; // leaked volume
        let mut x = vc[0]; // chamber volume (air case)
        for k in 0..n {
            let avail = vc[k] - lost;
            if va > 0.0 {
                // δ = avail − x stored in the gas: P = P_atm δ/(V_a − δ).
                let d = (avail - x).min(0.95 * va);
                let pk = patm * d / (va - d);
                // Chamber flow from P = f(x, y): solve the quadratic in y.
                let c0 = sba1(x, 0.0);
                let c1 = (sba1(x, 1.0) - sba1(x, -1.0)) / 2.0;
                let c2 = (sba1(x, 1.0) + sba1(x, -1.0)) / 2.0 - c0;
                let disc = (c1 * c1 - 4.0 * c2 * (c0 - pk)).max(0.0);
                let y = if c2.abs() < 1e-15 {
                    (pk - c0) / c1
                } else {
                    (-c1 + disc.sqrt()) / (2.0 * c2)
                };
                p[k] = pk;
                x += y * dt;
                lost += lam * pk * dt;
            } else {
                let pk = sba1(
                    avail,
                    fc[k] - lam * p.get(k.wrapping_sub(1)).copied().unwrap_or(0.0),
                );
                p[k] = pk;
                lost += lam * pk * dt;
            }
        }
    } else {
        for k in 0..n {
            p[k] = sba1(vc[k], fc[k]);
        }
    }
    for e in effects {
        match *e {
            Inject::Hysteresis { gap_kpa, width_mm3 } => {
                let mut h = 0.0;
                for k in 0..n {
                    let dv = f[k] * dt;
                    h += (dv.signum() * (dv != 0.0) as i32 as f64 - h) * dv.abs() / width_mm3;
                    p[k] += 0.5 * gap_kpa * h;
                }
            }
            Inject::Inertance { l } => {
                for k in 0..n {
                    p[k] += l * a[k];
                }
            }
            Inject::Delay { delay_s } => {
                let s = (delay_s / dt).round() as usize;
                let q = p.clone();
                for k in 0..n {
                    p[k] = q[k.saturating_sub(s)];
                }
            }
            Inject::Ripple { amp_kpa, freq_hz } => {
                for k in 0..n {
                    p[k] += amp_kpa * (2.0 * std::f64::consts::PI * freq_hz * t[k] + 0.7).sin();
                }
            }
            Inject::GatedRipple { amp_kpa, freq_hz } => {
                for k in (0..n).filter(|&k| f[k] != 0.0) {
                    p[k] += amp_kpa * (2.0 * std::f64::consts::PI * freq_hz * t[k] + 0.7).sin();
                }
            }
            _ => {}
        }
    }
    for e in effects {
        if let Inject::SensorLag { tau_s } = *e {
            let mut y = p[0];
            for pk in p.iter_mut().take(n) {
                y += (*pk - y) * (1.0 - (-dt / tau_s).exp());
                *pk = y;
            }
        }
        if let Inject::OffsetDrift { kpa, tau_s } = *e {
            for k in 0..n {
                p[k] += kpa * (1.0 - (-t[k] / tau_s).exp());
            }
        }
    }
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
    let normal = Normal::new(0.0, sigma).expect("valid sigma");
    let noise = |rng: &mut rand::rngs::StdRng| match shape.noise {
        Noise::Gaussian => normal.sample(rng),
        Noise::StudentT { dof } => {
            let t = StudentT::new(dof).expect("valid dof");
            sigma * ((dof - 2.0) / dof).sqrt() * t.sample(rng)
        }
        Noise::Spikes { rate, size } => {
            let spike = if rng.random::<f64>() < rate {
                size * sigma * if rng.random::<bool>() { 1.0 } else { -1.0 }
            } else {
                0.0
            };
            normal.sample(rng) + spike
        }
    };
    let every = 40; // 25 Hz from the 1 ms grid
    let mut out = Generated {
        t: vec![],
        v: vec![],
        vdot: vec![],
        p: vec![],
        sigma,
    };
    for k in (0..n).step_by(every) {
        out.t.push(t[k]);
        // The log reports the nut's volume and flow (step counts), as the firmware does.
        out.v.push(v[k]);
        out.vdot.push(f[k]);
        out.p.push(p[k] + noise(&mut rng));
    }
    out
}
