//! Recursive least squares with exponential forgetting, in Bierman's U-D factored form.
//!
//! Model: y_t = φ_tᵀ θ + e_t, with φ the scaled regressor row of [`crate::poly`]. The textbook
//! update with forgetting factor λ ∈ (0, 1] (Ljung & Söderström, *Theory and Practice of Recursive
//! Identification*, 1983) is
//!
//! ```text
//! ε = y − φᵀθ                          (prior residual, returned by `update`)
//! K = Pφ / (λ + φᵀPφ)
//! θ ← θ + K ε
//! P ← (P − K φᵀ P) / λ
//! ```
//!
//! Propagating P itself loses symmetry and positive definiteness in f32 after many updates. Here
//! P = U D Uᵀ is kept as a unit upper-triangular U and a diagonal D > 0 and updated with Bierman's
//! algorithm (G. J. Bierman, *Factorization Methods for Discrete Sequential Estimation*, 1977),
//! with the "measurement variance" set to λ and D divided by λ:
//!
//! ```text
//! f = Uᵀφ,  g = D f,  α₀ = λ
//! for j = 1..N:
//!     α_j = α_{j−1} + f_j g_j
//!     d_j ← d_j · α_{j−1} / (α_j · λ)
//!     b_j = g_j,  p_j = −f_j / α_{j−1}
//!     for i < j:  u_ij ← u_ij + b_i p_j,   b_i ← b_i + u_ij(old) g_j
//! K = b / α_N
//! ```
//!
//! Every α_j ≥ λ > 0, so each d_j stays positive and P = U D Uᵀ stays symmetric positive definite
//! by construction. Forgetting with poor excitation divides the unexcited d_j by λ at every step
//! (estimator wind-up), so after each update every d_j is clamped to [d_min, d_max]: the covariance
//! of an unexcited direction stops growing at d_max (by default the initial p0), and d_min keeps D
//! away from f32 underflow under very rich excitation with λ = 1. A step whose numbers are not
//! finite is refused before any state changes.

use crate::error::ModelError;

/// RLS estimator of N parameters, U-D factored (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rls<const N: usize> {
    theta: [f32; N],
    /// Unit upper-triangular factor; only the strict upper triangle (i < j) is used.
    u: [[f32; N]; N],
    d: [f32; N],
    lambda: f32,
    p0: f32,
    d_min: f32,
    d_max: f32,
    updates: u64,
}

impl<const N: usize> Rls<N> {
    /// A fresh estimator: θ = 0, P = p0·I, forgetting factor `lambda`, D bounded to
    /// [p0·1e-12, p0].
    ///
    /// Errors: `BadParameter` unless 0 < λ ≤ 1 and p0 is finite and > 0.
    pub fn new(lambda: f32, p0: f32) -> Result<Self, ModelError> {
        if !(lambda > 0.0 && lambda <= 1.0 && p0.is_finite() && p0 > 0.0) {
            return Err(ModelError::BadParameter);
        }
        Ok(Rls {
            theta: [0.0; N],
            u: [[0.0; N]; N],
            d: [p0; N],
            lambda,
            p0,
            d_min: p0 * 1.0e-12,
            d_max: p0,
            updates: 0,
        })
    }

    /// Replaces the bounds of the D factor. `BadParameter` unless 0 < d_min ≤ d_max < ∞.
    pub fn with_bounds(mut self, d_min: f32, d_max: f32) -> Result<Self, ModelError> {
        if !(d_min > 0.0 && d_min <= d_max && d_max.is_finite()) {
            return Err(ModelError::BadParameter);
        }
        self.d_min = d_min;
        self.d_max = d_max;
        for d in self.d.iter_mut() {
            *d = d.clamp(d_min, d_max);
        }
        Ok(self)
    }

    /// Starts from known coefficients (e.g. a model identified offline); `NonFinite` if any is NaN/∞.
    pub fn set_coeffs(&mut self, theta: &[f32; N]) -> Result<(), ModelError> {
        if theta.iter().any(|t| !t.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        self.theta = *theta;
        Ok(())
    }

    /// Resets the covariance to p0·I and the update count to 0, keeping the coefficients.
    pub fn reset_covariance(&mut self) {
        self.u = [[0.0; N]; N];
        self.d = [self.p0.clamp(self.d_min, self.d_max); N];
        self.updates = 0;
    }

    /// Resets everything: θ = 0, P = p0·I.
    pub fn reset(&mut self) {
        self.theta = [0.0; N];
        self.reset_covariance();
    }

    /// One update with regressor row φ and measurement y. Returns the prior residual y − φᵀθ.
    ///
    /// Errors (state unchanged): `NonFinite` for NaN/∞ in φ or y, or when the update would overflow.
    pub fn update(&mut self, phi: &[f32; N], y: f32) -> Result<f32, ModelError> {
        if !y.is_finite() || phi.iter().any(|x| !x.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        let mut e = y;
        for (t, p) in self.theta.iter().zip(phi) {
            e -= t * p;
        }
        // f = Uᵀφ, g = D f.
        let mut f = [0.0f32; N];
        let mut g = [0.0f32; N];
        for j in 0..N {
            let mut s = phi[j];
            for i in 0..j {
                s += self.u[i][j] * phi[i];
            }
            f[j] = s;
            g[j] = self.d[j] * s;
        }
        // New D first (it needs only the α_j), so a step that would overflow changes nothing.
        let mut d_new = [0.0f32; N];
        let mut alpha = self.lambda;
        for j in 0..N {
            let a_prev = alpha;
            alpha = a_prev + f[j] * g[j];
            d_new[j] = self.d[j] * (a_prev / (alpha * self.lambda));
        }
        if !e.is_finite() || !alpha.is_finite() || d_new.iter().any(|d| !d.is_finite()) {
            return Err(ModelError::NonFinite);
        }
        self.d = d_new;
        let mut b = [0.0f32; N];
        let mut alpha = self.lambda;
        for j in 0..N {
            let a_prev = alpha;
            alpha = a_prev + f[j] * g[j];
            b[j] = g[j];
            let pj = -f[j] / a_prev;
            for i in 0..j {
                let uij = self.u[i][j];
                self.u[i][j] = uij + b[i] * pj;
                b[i] += uij * g[j];
            }
        }
        for j in 0..N {
            self.theta[j] += b[j] / alpha * e;
            self.d[j] = self.d[j].clamp(self.d_min, self.d_max);
        }
        self.updates += 1;
        Ok(e)
    }

    /// Like [`update`](Self::update) for a slice; `BadLength` unless `phi.len() == N`.
    pub fn update_slice(&mut self, phi: &[f32], y: f32) -> Result<f32, ModelError> {
        let phi: &[f32; N] = phi.try_into().map_err(|_| ModelError::BadLength)?;
        self.update(phi, y)
    }

    /// The prediction φᵀθ.
    pub fn predict(&self, phi: &[f32; N]) -> f32 {
        self.theta.iter().zip(phi).map(|(t, p)| t * p).sum()
    }

    /// Current coefficient estimate θ.
    pub fn coeffs(&self) -> &[f32; N] {
        &self.theta
    }

    /// The covariance P = U D Uᵀ (exactly symmetric: both triangles come from the same products).
    pub fn covariance(&self) -> [[f32; N]; N] {
        let mut p = [[0.0f32; N]; N];
        for i in 0..N {
            for j in i..N {
                // P_ij = Σ_{k ≥ max(i,j)} u_ik d_k u_jk with u_kk = 1.
                let mut s = 0.0f32;
                for k in j..N {
                    let uik = if k == i { 1.0 } else { self.u[i][k] };
                    let ujk = if k == j { 1.0 } else { self.u[j][k] };
                    s += uik * self.d[k] * ujk;
                }
                p[i][j] = s;
                p[j][i] = s;
            }
        }
        p
    }

    /// The diagonal factor D (all entries in [d_min, d_max]).
    pub fn d_factor(&self) -> &[f32; N] {
        &self.d
    }

    /// The unit upper-triangular factor U (strict upper triangle meaningful).
    pub fn u_factor(&self) -> &[[f32; N]; N] {
        &self.u
    }

    /// The forgetting factor λ.
    pub fn lambda(&self) -> f32 {
        self.lambda
    }

    /// Number of accepted updates since creation or the last reset.
    pub fn updates(&self) -> u64 {
        self.updates
    }
}
