//! Independent f64 reference implementations for the tests (raw units, no scaling). A directory
//! module, so that Cargo does not build it as a test binary of its own.
#![allow(dead_code)]

use model_core::poly::{Scaling, Shape};

/// P = Σ α_ij v^i f^j evaluated term by term in f64 (raw units).
pub fn p_raw(shape: Shape, a: &[f64], v: f64, f: f64) -> f64 {
    let (n, m) = (shape.n as i32, shape.m as i32);
    let mut s = 0.0;
    for i in 0..=n {
        for j in 0..=m {
            s += a[(i * (m + 1) + j) as usize] * v.powi(i) * f.powi(j);
        }
    }
    s
}

/// ∂P/∂v in f64.
pub fn k_raw(shape: Shape, a: &[f64], v: f64, f: f64) -> f64 {
    let (n, m) = (shape.n as i32, shape.m as i32);
    let mut s = 0.0;
    for i in 1..=n {
        for j in 0..=m {
            s += a[(i * (m + 1) + j) as usize] * i as f64 * v.powi(i - 1) * f.powi(j);
        }
    }
    s
}

/// ∂P/∂v̇ in f64.
pub fn c_raw(shape: Shape, a: &[f64], v: f64, f: f64) -> f64 {
    let (n, m) = (shape.n as i32, shape.m as i32);
    let mut s = 0.0;
    for i in 0..=n {
        for j in 1..=m {
            s += a[(i * (m + 1) + j) as usize] * j as f64 * v.powi(i) * f.powi(j - 1);
        }
    }
    s
}

/// Full-scale magnitudes of P, k and c over a range: Σ |α_ij|·V^i·F^j and the same for the
/// derivative terms, with V, F the largest |v|, |v̇| in the range. Errors are stated against these.
pub fn full_scale(shape: Shape, a: &[f64], vmax: f64, fmax: f64) -> (f64, f64, f64) {
    let (n, m) = (shape.n as i32, shape.m as i32);
    let (mut sp, mut sk, mut sc) = (0.0, 0.0, 0.0);
    for i in 0..=n {
        for j in 0..=m {
            let t = a[(i * (m + 1) + j) as usize].abs();
            sp += t * vmax.powi(i) * fmax.powi(j);
            if i > 0 {
                sk += t * i as f64 * vmax.powi(i - 1) * fmax.powi(j);
            }
            if j > 0 {
                sc += t * j as f64 * vmax.powi(i) * fmax.powi(j - 1);
            }
        }
    }
    (sp, sk, sc)
}

/// The range corners of a scaling: (v_min, v_max, f_min, f_max).
pub fn range(s: Scaling) -> (f32, f32, f32, f32) {
    (
        s.v_offset - s.v_scale,
        s.v_offset + s.v_scale,
        s.f_offset - s.f_scale,
        s.f_offset + s.f_scale,
    )
}
