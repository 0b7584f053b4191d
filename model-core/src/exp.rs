//! Physics-inspired exponential model (paper, Table II):
//!
//! ```text
//! P̂ = Σ_{i=1..k} α_i · exp(β_i · v) + γ · v̇ + δ,        k ≤ 10
//! k_stiff = ∂P/∂v = Σ α_i β_i exp(β_i v),                 c = ∂P/∂v̇ = γ
//! ```
//!
//! Evaluation only (identification is the host's job). Raw units: v in mm³, v̇ in mm³/s, P in kPa.

use crate::error::{finite, ModelError};
use crate::poly::Eval;

/// Most exponential terms (the paper tried 1..=10).
pub const MAX_EXP_TERMS: usize = 10;

/// Σ α_i exp(β_i v) + γ v̇ + δ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ExpModel {
    alpha: [f32; MAX_EXP_TERMS],
    beta: [f32; MAX_EXP_TERMS],
    k: usize,
    gamma: f32,
    delta: f32,
}

impl ExpModel {
    /// A model with `alpha.len()` = `beta.len()` = k terms, 1 ≤ k ≤ 10.
    ///
    /// Errors: `BadLength` for mismatched lengths, `BadShape` for k outside 1..=10, `NonFinite` for
    /// any NaN/∞ parameter.
    pub fn new(alpha: &[f32], beta: &[f32], gamma: f32, delta: f32) -> Result<Self, ModelError> {
        if alpha.len() != beta.len() {
            return Err(ModelError::BadLength);
        }
        let k = alpha.len();
        if k == 0 || k > MAX_EXP_TERMS {
            return Err(ModelError::BadShape);
        }
        if !alpha
            .iter()
            .chain(beta)
            .chain([gamma, delta].iter())
            .all(|x| x.is_finite())
        {
            return Err(ModelError::NonFinite);
        }
        let mut m = ExpModel {
            alpha: [0.0; MAX_EXP_TERMS],
            beta: [0.0; MAX_EXP_TERMS],
            k,
            gamma,
            delta,
        };
        m.alpha[..k].copy_from_slice(alpha);
        m.beta[..k].copy_from_slice(beta);
        Ok(m)
    }

    /// Number of exponential terms k.
    pub fn terms(&self) -> usize {
        self.k
    }

    /// α_1..α_k.
    pub fn alpha(&self) -> &[f32] {
        &self.alpha[..self.k]
    }

    /// β_1..β_k, 1/mm³.
    pub fn beta(&self) -> &[f32] {
        &self.beta[..self.k]
    }

    /// γ, kPa·s/mm³.
    pub fn gamma(&self) -> f32 {
        self.gamma
    }

    /// δ, kPa.
    pub fn delta(&self) -> f32 {
        self.delta
    }

    /// P̂, k = ∂P/∂v, c = ∂P/∂v̇ at (v, v̇). `NonFinite` for NaN/∞ input or when an exponential
    /// overflows f32.
    pub fn eval(&self, v: f32, vdot: f32) -> Result<Eval, ModelError> {
        finite(v)?;
        finite(vdot)?;
        let (mut p, mut k) = (self.gamma * vdot + self.delta, 0.0f32);
        for i in 0..self.k {
            let e = finite(libm::expf(self.beta[i] * v))?;
            let t = self.alpha[i] * e;
            p += t;
            k += t * self.beta[i];
        }
        Ok(Eval {
            p: finite(p)?,
            k: finite(k)?,
            c: self.gamma,
        })
    }
}
