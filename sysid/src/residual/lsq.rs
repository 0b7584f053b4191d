//! Least squares for the augmented models, done the well-conditioned way: columns scaled to unit
//! RMS, Householder QR (nalgebra), `β = R⁻¹ Qᵀ y`, covariance `σ̂² (XᵀX)⁻¹ = σ̂² R⁻¹ R⁻ᵀ` mapped back
//! through the column scaling. No normal equations; SSE from the residuals themselves.

use nalgebra::{DMatrix, DVector};

/// One linear least-squares fit on a subset of rows.
#[derive(Clone, Debug)]
pub struct LsFit {
    /// Coefficients, one per column.
    pub beta: Vec<f64>,
    /// `(XᵀX)⁻¹` in the columns' own units (multiply by σ̂² for the covariance).
    pub xtx_inv: DMatrix<f64>,
    /// Sum of squared residuals on the fitted rows.
    pub sse: f64,
    /// Rows fitted.
    pub n: usize,
}

impl LsFit {
    /// Residual variance estimate `SSE/(N − p)`.
    pub fn sigma2(&self) -> f64 {
        self.sse / (self.n.saturating_sub(self.beta.len()).max(1)) as f64
    }
}

/// Relative size below which a diagonal entry of R means the columns are linearly dependent.
const RANK_TOL: f64 = 1e-10;

/// Fits `y ≈ X β` on `rows`; `None` when the columns are rank-deficient on those rows (a candidate
/// that duplicates what the model already has) or there are no more rows than columns.
pub fn fit(cols: &[Vec<f64>], y: &[f64], rows: &[usize]) -> Option<LsFit> {
    let p = cols.len();
    let n = rows.len();
    if n <= p || p == 0 {
        return None;
    }
    let scale: Vec<f64> = cols
        .iter()
        .map(|c| {
            let s = (rows.iter().map(|&r| c[r] * c[r]).sum::<f64>() / n as f64).sqrt();
            if s > 0.0 && s.is_finite() {
                s
            } else {
                0.0
            }
        })
        .collect();
    if scale.contains(&0.0) {
        return None;
    }
    let x = DMatrix::from_fn(n, p, |i, j| cols[j][rows[i]] / scale[j]);
    let qr = x.qr();
    let r = qr.r();
    let rmax = (0..p).map(|i| r[(i, i)].abs()).fold(0.0, f64::max);
    if (0..p).any(|i| r[(i, i)].abs() <= RANK_TOL * rmax) {
        return None;
    }
    let mut qty = DVector::from_iterator(n, rows.iter().map(|&r| y[r]));
    qr.q_tr_mul(&mut qty);
    let head = qty.rows(0, p).into_owned();
    let b_scaled = r.solve_upper_triangular(&head)?;
    let r_inv = r.solve_upper_triangular(&DMatrix::identity(p, p))?;
    let mut xtx_inv = &r_inv * r_inv.transpose();
    for i in 0..p {
        for j in 0..p {
            xtx_inv[(i, j)] /= scale[i] * scale[j];
        }
    }
    let beta: Vec<f64> = (0..p).map(|j| b_scaled[j] / scale[j]).collect();
    let sse = rows
        .iter()
        .map(|&r| {
            let pred: f64 = cols.iter().zip(&beta).map(|(c, b)| c[r] * b).sum();
            (y[r] - pred).powi(2)
        })
        .sum();
    Some(LsFit {
        beta,
        xtx_inv,
        sse,
        n,
    })
}

/// SSE of the least-squares fit only, for parameter searches that evaluate hundreds of designs:
/// Jacobi-scaled Gram matrix, Cholesky, `SSE = ‖y − ȳ‖² − bᵀG⁻¹b` with the pressure centred (every
/// design holds a constant column, and every filter maps a constant to itself). The cancellation
/// costs about log₁₀(‖y − ȳ‖²/SSE) ≈ 5 of 16 digits — ample to rank candidates; every reported fit
/// goes through [`fit`].
///
/// The Gram matrix is accumulated straight from the columns over the contiguous runs of `rows`
/// (training rows are whole cycles), in blocks small enough to stay in L1 cache, with no copy of
/// the design: this is the loop's innermost cost.
pub fn sse_fast(cols: &[Vec<f64>], y: &[f64], rows: &[usize]) -> f64 {
    let p = cols.len();
    let n = rows.len();
    if n <= p || p == 0 || cols.iter().any(|c| c.len() != y.len()) {
        return f64::INFINITY;
    }
    let mean = rows.iter().map(|&r| y[r]).sum::<f64>() / n as f64;
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let (mut start, mut prev) = (rows[0], rows[0]);
    for &r in &rows[1..] {
        if r != prev + 1 {
            runs.push((start, prev + 1));
            start = r;
        }
        prev = r;
    }
    runs.push((start, prev + 1));
    // Column p of the accumulation is the centred pressure.
    let q = p + 1;
    let mut acc = vec![0.0; q * q];
    let mut yc = [0.0; BLOCK];
    const BLOCK: usize = 128;
    for &(a, b) in &runs {
        let mut lo = a;
        while lo < b {
            let hi = (lo + BLOCK).min(b);
            let len = hi - lo;
            for (k, v) in yc[..len].iter_mut().enumerate() {
                *v = y[lo + k] - mean;
            }
            let col = |i: usize| -> &[f64] {
                if i < p {
                    &cols[i][lo..hi]
                } else {
                    &yc[..len]
                }
            };
            for i in 0..q {
                let ci = col(i);
                for j in 0..=i {
                    acc[i * q + j] += dot(ci, col(j));
                }
            }
            lo = hi;
        }
    }
    let g = |i: usize, j: usize| {
        if i >= j {
            acc[i * q + j]
        } else {
            acc[j * q + i]
        }
    };
    let d: Vec<f64> = (0..p)
        .map(|i| 1.0 / g(i, i).max(f64::MIN_POSITIVE).sqrt())
        .collect();
    let gs = DMatrix::from_fn(p, p, |i, j| g(i, j) * d[i] * d[j]);
    let bs = DVector::from_fn(p, |i, _| g(p, i) * d[i]);
    let yy = g(p, p);
    let Some(chol) = nalgebra::Cholesky::new(gs) else {
        return f64::INFINITY;
    };
    let l = chol.l_dirty();
    if (0..p).any(|k| l[(k, k)] < 1e-7) {
        return f64::INFINITY;
    }
    let c = chol.solve(&bs);
    (yy - c.dot(&bs)).max(0.0)
}

/// Dot product with four independent accumulators (the chains overlap in the pipeline).
fn dot(a: &[f64], b: &[f64]) -> f64 {
    let mut s = [0.0; 4];
    let (ca, cb) = (a.chunks_exact(4), b.chunks_exact(4));
    let (ra, rb) = (ca.remainder(), cb.remainder());
    for (x, y) in ca.zip(cb) {
        s[0] += x[0] * y[0];
        s[1] += x[1] * y[1];
        s[2] += x[2] * y[2];
        s[3] += x[3] * y[3];
    }
    let tail: f64 = ra.iter().zip(rb).map(|(x, y)| x * y).sum();
    (s[0] + s[1]) + (s[2] + s[3]) + tail
}

/// `X β` on every row.
pub fn predict(cols: &[Vec<f64>], beta: &[f64]) -> Vec<f64> {
    let len = cols.first().map_or(0, Vec::len);
    let mut out = vec![0.0; len];
    for (c, &b) in cols.iter().zip(beta) {
        for (o, &ci) in out.iter_mut().zip(c) {
            *o += b * ci;
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_exact_line_and_textbook_covariance() {
        // y = 2 + 3x on x = 0..4: exact fit; (XᵀX)⁻¹ for [1, x] is known in closed form.
        let x: Vec<f64> = (0..5).map(|k| k as f64).collect();
        let one = vec![1.0; 5];
        let y: Vec<f64> = x.iter().map(|&v| 2.0 + 3.0 * v).collect();
        let f = fit(&[one, x], &y, &[0, 1, 2, 3, 4]).unwrap();
        assert!((f.beta[0] - 2.0).abs() < 1e-12 && (f.beta[1] - 3.0).abs() < 1e-12);
        // XᵀX = [[5, 10], [10, 30]], det 50 → inverse [[0.6, −0.2], [−0.2, 0.1]].
        assert!((f.xtx_inv[(0, 0)] - 0.6).abs() < 1e-12);
        assert!((f.xtx_inv[(0, 1)] + 0.2).abs() < 1e-12);
        assert!((f.xtx_inv[(1, 1)] - 0.1).abs() < 1e-12);
        assert!(f.sse < 1e-20);
    }

    #[test]
    fn fast_sse_agrees_with_qr() {
        let x: Vec<f64> = (0..50).map(|k| k as f64 / 10.0).collect();
        let one = vec![1.0; 50];
        let x2: Vec<f64> = x.iter().map(|v| v * v).collect();
        let y: Vec<f64> = x.iter().map(|&v| 1.0 + 0.5 * v + (7.0 * v).sin()).collect();
        // Rows in two runs with a gap (like held-out cycles); below, runs longer than one block.
        let rows: Vec<usize> = (0..20).chain(27..50).collect();
        let cols = [one, x, x2];
        let a = fit(&cols, &y, &rows).unwrap().sse;
        let b = sse_fast(&cols, &y, &rows);
        assert!((a - b).abs() < 1e-9 * a, "{a} vs {b}");
        let t: Vec<f64> = (0..1000).map(|k| k as f64 / 500.0).collect();
        let long = [
            vec![1.0; 1000],
            t.clone(),
            t.iter().map(|v| (3.0 * v).cos()).collect::<Vec<_>>(),
        ];
        let yl: Vec<f64> = t.iter().map(|&v| v * v + (11.0 * v).sin()).collect();
        let rows: Vec<usize> = (0..300).chain(400..1000).collect();
        let a = fit(&long, &yl, &rows).unwrap().sse;
        let b = sse_fast(&long, &yl, &rows);
        assert!((a - b).abs() < 1e-9 * a, "{a} vs {b}");
    }

    #[test]
    fn duplicate_column_is_refused() {
        let x: Vec<f64> = (0..6).map(|k| k as f64).collect();
        let y = x.clone();
        assert!(fit(
            &[x.clone(), x.iter().map(|v| 2.0 * v).collect()],
            &y,
            &[0, 1, 2, 3, 4, 5]
        )
        .is_none());
    }
}
