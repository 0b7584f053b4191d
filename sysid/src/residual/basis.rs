//! Baseline regressors: the tensor Chebyshev basis `T_i(x)·T_j(y)`, i ≤ n, j ≤ m, on volume and
//! flow mapped affinely onto [−1, 1] (the basis `sysid`'s polynomial fit uses). It spans exactly the
//! paper's monomials `vⁱ v̇ʲ` (Table II, multivariate polynomial), so a fit in it is the paper's
//! model, but its columns are nearly orthogonal on a protocol's data where raw `v⁷` would not be.

use crate::poly::{PolyError, Scaling};

/// Chebyshev tensor basis of shape (n, m) with its input scaling (the crate's one
/// [`Scaling`]: `x = (v − v_offset)/v_scale`, `y = (v̇ − f_offset)/f_scale`).
#[derive(Clone, Debug, PartialEq)]
pub struct PolyBasis {
    /// Highest degree in volume.
    pub n: usize,
    /// Highest degree in flow.
    pub m: usize,
    /// The map of volume and flow onto [−1, 1].
    pub scaling: Scaling,
}

/// `T_0(x) … T_deg(x)` into `out[..=deg]`: the crate's one evaluator, [`crate::poly::chebyshev`].
fn chebyshev(x: f64, deg: usize, out: &mut [f64]) {
    crate::poly::chebyshev(x, &mut out[..=deg]);
}

/// `T_0 … T_deg` of `(x − offset)/scale` for every sample, one vector per degree.
fn chebyshev_columns(x: &[f64], offset: f64, scale: f64, deg: usize) -> Vec<Vec<f64>> {
    let s: Vec<f64> = x.iter().map(|&x| (x - offset) / scale).collect();
    let mut out: Vec<Vec<f64>> = vec![vec![1.0; x.len()]];
    if deg >= 1 {
        out.push(s.clone());
    }
    for k in 2..=deg {
        let next = (out[k - 1].iter().zip(&out[k - 2]).zip(&s))
            .map(|((a, b), s)| 2.0 * s * a - b)
            .collect();
        out.push(next);
    }
    out
}

impl PolyBasis {
    /// Basis with the scaling that maps the given data's ranges onto [−1, 1]
    /// ([`Scaling::from_data`]: an error on constant volume or flow, no data or non-finite
    /// values).
    pub fn for_data(v: &[f64], vdot: &[f64], n: usize, m: usize) -> Result<Self, PolyError> {
        Ok(Self {
            n,
            m,
            scaling: Scaling::from_data(v, vdot)?,
        })
    }

    /// Number of columns, (n + 1)(m + 1).
    pub fn len(&self) -> usize {
        (self.n + 1) * (self.m + 1)
    }

    /// Never empty: the constant term is always there.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Label of column `i·(m+1) + j`.
    pub fn label(&self, idx: usize) -> String {
        format!("T{}(v)T{}(vdot)", idx / (self.m + 1), idx % (self.m + 1))
    }

    /// Columns (column-major) evaluated on the given inputs.
    pub fn columns(&self, v: &[f64], vdot: &[f64]) -> Vec<Vec<f64>> {
        // Column-wise (each loop a plain vectorisable pass; the same operations as `chebyshev`),
        // a block of samples at a time: the factors of the whole series would hold another
        // n + m + 2 numbers per sample beside the columns (34 MB on a 3-hour log).
        const BLOCK: usize = 2048;
        let len = v.len().min(vdot.len());
        let mut cols: Vec<Vec<f64>> = (0..self.len()).map(|_| Vec::with_capacity(len)).collect();
        for start in (0..len).step_by(BLOCK) {
            let end = (start + BLOCK).min(len);
            let (v, vdot) = (&v[start..end], &vdot[start..end]);
            let tx = chebyshev_columns(v, self.scaling.v_offset, self.scaling.v_scale, self.n);
            let ty = chebyshev_columns(vdot, self.scaling.f_offset, self.scaling.f_scale, self.m);
            let mut out = cols.iter_mut();
            for a in &tx {
                for b in &ty {
                    let col = out.next().expect("(n + 1)(m + 1) columns");
                    col.extend(a.iter().zip(b).map(|(a, b)| a * b));
                }
            }
        }
        cols
    }

    /// `T_0 … T_dx` of the scaled volume and `T_0 … T_dy` of the scaled flow, one vector per
    /// degree (the factors of [`Self::columns`]; with `dx = 2n`, `dy = 2m` they give every product of
    /// two basis columns by `T_i T_k = ½(T_{i+k} + T_{|i−k|})`).
    pub fn factors(
        &self,
        v: &[f64],
        vdot: &[f64],
        dx: usize,
        dy: usize,
    ) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        (
            chebyshev_columns(v, self.scaling.v_offset, self.scaling.v_scale, dx),
            chebyshev_columns(vdot, self.scaling.f_offset, self.scaling.f_scale, dy),
        )
    }

    /// `Σ β_idx T_i(x) T_j(y)` at one point.
    pub fn eval(&self, beta: &[f64], v: f64, vdot: f64) -> f64 {
        let mut tx = [0.0; 16];
        let mut ty = [0.0; 16];
        let (x, y) = self.scaling.apply(v, vdot);
        chebyshev(x, self.n, &mut tx);
        chebyshev(y, self.m, &mut ty);
        let mut s = 0.0;
        for i in 0..=self.n {
            for j in 0..=self.m {
                s += beta[i * (self.m + 1) + j] * tx[i] * ty[j];
            }
        }
        s
    }

    /// Stiffness `∂P/∂v` of `Σ β T_i T_j` at one point (central difference over 10⁻⁴ of the
    /// volume half-range: the model is a polynomial of degree ≤ 15, so the truncation error,
    /// ~h²·P‴/6, is far below any noise).
    pub fn stiffness(&self, beta: &[f64], v: f64, vdot: f64) -> f64 {
        let h = 1e-4 * self.scaling.v_scale;
        (self.eval(beta, v + h, vdot) - self.eval(beta, v - h, vdot)) / (2.0 * h)
    }

    /// Damping `∂P/∂v̇` of `Σ β T_i T_j` at one point (central difference over 10⁻⁴ of the flow
    /// half-range: exact to rounding for a polynomial of degree ≤ 2 in v̇, and far below noise above).
    pub fn damping(&self, beta: &[f64], v: f64, vdot: f64) -> f64 {
        let h = 1e-4 * self.scaling.f_scale;
        (self.eval(beta, v, vdot + h) - self.eval(beta, v, vdot - h)) / (2.0 * h)
    }
}

#[cfg(test)]
mod tests {
    use crate::poly::PolyError;

    /// One scaling for the crate: the residual basis refuses what the polynomial fit refuses
    /// (it once fell back to a scale of 1.0 on constant data) and maps data exactly as it does.
    #[test]
    fn the_basis_scales_as_the_polynomial_fit_does() {
        let v = [10.0, 10.0, 10.0];
        let f = [-5.0, 0.0, 5.0];
        assert_eq!(
            PolyBasis::for_data(&v, &f, 3, 2),
            Err(PolyError::ConstantVolume { value: 10.0 })
        );
        assert_eq!(
            PolyBasis::for_data(&f, &[0.0; 3], 3, 2),
            Err(PolyError::ZeroFlow)
        );
        let v = [0.0, 100.0, 550.0];
        let b = PolyBasis::for_data(&v, &f, 3, 2).unwrap();
        // The volume range [0, 550] onto [−1, 1] by hand: centre 275, half-width 275.
        assert_eq!(b.scaling.apply(550.0, 5.0), (1.0, 1.0));
        assert_eq!(b.scaling.apply(0.0, -5.0), (-1.0, -1.0));
        assert_eq!(b.scaling.v_offset, 275.0);
    }

    use super::*;

    #[test]
    fn chebyshev_matches_cosine_definition() {
        let mut t = [0.0; 8];
        for &x in &[-0.9, -0.2, 0.3, 0.99] {
            chebyshev(x, 7, &mut t);
            for (k, &tk) in t.iter().enumerate() {
                let expect = (k as f64 * f64::acos(x)).cos();
                assert!((tk - expect).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn columns_equal_pointwise_products() {
        let b = PolyBasis {
            n: 3,
            m: 2,
            scaling: Scaling {
                v_offset: 275.0,
                v_scale: 275.0,
                f_offset: 0.0,
                f_scale: 100.0,
            },
        };
        let v = [0.0, 100.0, 300.0, 550.0];
        let f = [-100.0, 20.0, 0.0, 60.0];
        let cols = b.columns(&v, &f);
        let (mut tx, mut ty) = ([0.0; 4], [0.0; 3]);
        for k in 0..4 {
            chebyshev((v[k] - 275.0) / 275.0, 3, &mut tx);
            chebyshev(f[k] / 100.0, 2, &mut ty);
            for i in 0..4 {
                for j in 0..3 {
                    assert_eq!(cols[i * 3 + j][k], tx[i] * ty[j]);
                }
            }
        }
    }

    #[test]
    fn damping_of_known_polynomial() {
        let b = PolyBasis {
            n: 1,
            m: 2,
            scaling: Scaling {
                v_offset: 0.0,
                v_scale: 1.0,
                f_offset: 0.0,
                f_scale: 1.0,
            },
        };
        // P = T0(x)T2(y) = 2y² − 1 → ∂P/∂y = 4y.
        let beta = [0.0, 0.0, 1.0, 0.0, 0.0, 0.0];
        assert!((b.damping(&beta, 0.3, 0.5) - 2.0).abs() < 1e-8);
    }
}
