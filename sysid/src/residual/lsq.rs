//! Least squares for the augmented models, done the well-conditioned way: columns scaled to unit
//! RMS, Householder QR (nalgebra), `β = R⁻¹ Qᵀ y`, covariance `σ̂² (XᵀX)⁻¹ = σ̂² R⁻¹ R⁻ᵀ` mapped back
//! through the column scaling. No normal equations; SSE from the residuals themselves.
//!
//! The QR runs over blocks of rows (tall-skinny QR): `R` of the rows so far, stacked on the next
//! block of a few hundred rows with the response as an extra column, is factored again by
//! Householder, `R ← R([R; X_b  y_b])`. Every step is an orthogonal transformation of the same
//! rows, so the final triangle is the Householder `R` of the whole design (up to the signs of its
//! rows) and its last column is `Qᵀy`; each block's factorisation stays in the cache, where a
//! single factorisation of 20,000 × 65 streams the whole matrix from memory once per column.

use std::cell::RefCell;

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

/// R of the tall-skinny QR (module docs) of [X/scale  y] on `rows`: blocks of 8(p + 1) rows keep
/// each factorisation's matrix within a few hundred kB (on 18,000 × 65: 23 ms against 35 ms for
/// one factorisation of the whole; 4(p + 1) rows 26 ms, 16(p + 1) 23 ms). `None` without rows.
fn tall_skinny_r(
    cols: &[Vec<f64>],
    y: &[f64],
    rows: &[usize],
    scale: &[f64],
) -> Option<DMatrix<f64>> {
    let p = cols.len();
    let q = p + 1;
    let mut tri: Option<DMatrix<f64>> = None;
    for block in rows.chunks(8 * q) {
        let top = tri.as_ref().map_or(0, |t| t.nrows());
        let mut a = DMatrix::zeros(top + block.len(), q);
        if let Some(t) = &tri {
            a.view_mut((0, 0), (top, q)).copy_from(t);
        }
        for j in 0..q {
            let mut col = a.column_mut(j);
            if j < p {
                for (i, &r) in block.iter().enumerate() {
                    col[top + i] = cols[j][r] / scale[j];
                }
            } else {
                for (i, &r) in block.iter().enumerate() {
                    col[top + i] = y[r];
                }
            }
        }
        tri = Some(a.qr().r());
    }
    tri
}

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
    let q = p + 1;
    let tri = tall_skinny_r(cols, y, rows, &scale)?;
    if tri.nrows() < q {
        return None;
    }
    let r = tri.view((0, 0), (p, p)).into_owned();
    let rmax = (0..p).map(|i| r[(i, i)].abs()).fold(0.0, f64::max);
    if (0..p).any(|i| r[(i, i)].abs() <= RANK_TOL * rmax) {
        return None;
    }
    let head = tri.view((0, p), (p, 1)).into_owned();
    let b_scaled = r.solve_upper_triangular(&head)?;
    let r_inv = r.solve_upper_triangular(&DMatrix::identity(p, p))?;
    let mut xtx_inv = &r_inv * r_inv.transpose();
    for i in 0..p {
        for j in 0..p {
            xtx_inv[(i, j)] /= scale[i] * scale[j];
        }
    }
    let beta: Vec<f64> = (0..p).map(|j| b_scaled[j] / scale[j]).collect();
    // Prediction column by column (each row's terms added in the same order as a row-wise sum).
    let mut pred = vec![0.0; n];
    for (c, &b) in cols.iter().zip(&beta) {
        for (o, &r) in pred.iter_mut().zip(rows) {
            *o += c[r] * b;
        }
    }
    let sse = rows
        .iter()
        .zip(&pred)
        .map(|(&r, &pr)| (y[r] - pr).powi(2))
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
/// The training rows (whole cycles: a few contiguous runs) are copied into one column-major matrix
/// with the centred pressure as its last column, and `XᵀX` is one `matrixmultiply` product. Only
/// designs behind an output filter (sensor lag, air compliance) come here during the searches;
/// the others take [`sse_fast_poly`].
pub fn sse_fast(cols: &[Vec<f64>], y: &[f64], rows: &[usize]) -> f64 {
    if cols.iter().any(|c| c.len() != y.len()) {
        return f64::INFINITY;
    }
    // Straight from the columns into the Gram sum's copy (through `sse_fast_streamed`'s block
    // of rows, the design was copied twice per trial).
    sse_gram(cols.len(), y, rows, |_, runs, data| {
        for c in cols {
            for &(a, b) in runs {
                data.extend_from_slice(&c[a..b]);
            }
        }
    })
}

/// [`sse_fast`] of the design whose columns are `cols` followed by `extra` (the same numbers as
/// of one list of them, without joining them).
pub fn sse_fast_parts(cols: &[Vec<f64>], extra: &[Vec<f64>], y: &[f64], rows: &[usize]) -> f64 {
    if cols.iter().chain(extra).any(|c| c.len() != y.len()) {
        return f64::INFINITY;
    }
    sse_gram(cols.len() + extra.len(), y, rows, |_, runs, data| {
        for c in cols.iter().chain(extra) {
            for &(a, b) in runs {
                data.extend_from_slice(&c[a..b]);
            }
        }
    })
}

/// [`sse_fast`] of a design that is produced in row order, a block at a time, and never held
/// whole: `advance(hi, out)` writes rows `lo..hi` of its `p` columns into `out` (column by
/// column, `p` runs of `hi − lo`), where `lo` is the `hi` of its previous call (0 at the first),
/// and returns `lo`. A filtered design (`signal::LagStream`) is summed this way in the memory of
/// one block.
pub fn sse_fast_streamed(
    p: usize,
    y: &[f64],
    rows: &[usize],
    mut advance: impl FnMut(usize, &mut Vec<f64>) -> usize,
) -> f64 {
    let mut rows_block = Vec::new();
    sse_gram(p, y, rows, |hi, runs, data| {
        let lo = advance(hi, &mut rows_block);
        let len = hi - lo;
        for c in 0..p {
            for &(a, b) in runs {
                data.extend_from_slice(&rows_block[c * len + a - lo..c * len + b - lo]);
            }
        }
    })
}

/// The Gram sum of [`sse_fast`] and [`sse_fast_streamed`]: `fill(hi, runs, data)` appends the `p`
/// columns' training rows of one block (`runs`, half-open runs of rows, the last ending at `hi`)
/// to `data`, column by column; the centred pressure follows as column `p`.
fn sse_gram(
    p: usize,
    y: &[f64],
    rows: &[usize],
    mut fill: impl FnMut(usize, &[(usize, usize)], &mut Vec<f64>),
) -> f64 {
    let n = rows.len();
    if n <= p || p == 0 {
        return f64::INFINITY;
    }
    let mean = rows.iter().map(|&r| y[r]).sum::<f64>() / n as f64;
    // Column p is the centred pressure. The Gram matrix XᵀX is a sum of matrix products over
    // blocks of GRAM_BLOCK rows (`matrixmultiply`: register-blocked kernels on the CPU's vector
    // units; splitting off the symmetric quarter saves less in the kernel than the extra packing
    // of the operands costs). A block is a whole number of the kernel's own row chunks (its `kc`
    // of 256), which it sums the same way, so the blocked sum equals one product of all rows to
    // the bit; the copy it works on stays a block (≈ 2 MB at 65 columns) however long the log.
    // That column-major copy lives in a per-thread buffer reused across calls: a fresh allocation
    // per trial θ costs more in page faults than the copy itself.
    let q = p + 1;
    let mut gram = DMatrix::zeros(q, q);
    GRAM_BUF.with_borrow_mut(|data| {
        for (k, block) in rows.chunks(GRAM_BLOCK).enumerate() {
            let hi = block[block.len() - 1] + 1;
            let runs = runs_of(block);
            data.clear();
            data.reserve(block.len() * q);
            fill(hi, &runs, data);
            for &(a, b) in &runs {
                data.extend(y[a..b].iter().map(|&yv| yv - mean));
            }
            at_b_into(data, block.len(), q, data, q, &mut gram, k > 0);
        }
    });
    sse_from_gram(p, |i, j| gram[(i, j)])
}

/// Rows per block of [`sse_fast`]'s Gram sum: a multiple of `matrixmultiply`'s f64 `kc` (256).
const GRAM_BLOCK: usize = 16 * 256;

/// Sorted row indices as half-open runs of consecutive rows.
fn runs_of(rows: &[usize]) -> Vec<(usize, usize)> {
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let Some(&first) = rows.first() else {
        return runs;
    };
    let (mut start, mut prev) = (first, first);
    for &r in &rows[1..] {
        if r != prev + 1 {
            runs.push((start, prev + 1));
            start = r;
        }
        prev = r;
    }
    runs.push((start, prev + 1));
    runs
}

thread_local! {
    /// [`sse_fast`]'s column-major copy of the design, kept between calls on each thread.
    static GRAM_BUF: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
    /// [`sse_fast_poly`]'s Chebyshev factors and cross-term operand, likewise.
    static POLY_BUF: RefCell<Vec<f64>> = const { RefCell::new(Vec::new()) };
}

/// `SSE = ‖y − ȳ‖² − bᵀG⁻¹b` from the Gram matrix of `p` columns augmented with the centred
/// pressure as column `p` (`g(i, j)`, symmetric): Jacobi scaling, Cholesky, and the rank test
/// shared by [`sse_fast`] and [`sse_fast_poly`].
fn sse_from_gram(p: usize, g: impl Fn(usize, usize) -> f64) -> f64 {
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

/// [`sse_fast`] for a design whose leading columns are the tensor Chebyshev basis
/// `T_i(x)·T_j(y)`, i ≤ n, j ≤ m (column `i·(m+1) + j`, as `PolyBasis::columns`), followed by
/// `extra` columns. Everything is given on the fitted rows only: `factors(rows)` gives
/// `T_a(x)` for a ≤ 2n and `T_b(y)` for b ≤ 2m over a range of them (`PolyBasis::factors`), asked
/// for a block of rows at a time so that only a block of them is ever held; `extra` and the
/// centred pressure `yc` over all of them.
///
/// The baseline block of the Gram matrix comes from the moments `M_ab = Σ_r T_a(x_r) T_b(y_r)` by
/// the product rule `T_i T_k = ½(T_{i+k} + T_{|i−k|})`:
/// `Σ T_i(x)T_j(y)·T_k(x)T_l(y) = ¼(M_{i+k,j+l} + M_{i+k,|j−l|} + M_{|i−k|,j+l} + M_{|i−k|,|j−l|})`,
/// so a (7, 7) baseline's 2,080 distinct Gram entries cost 225 sums over the rows instead of
/// 2,080 (an identity of the polynomials, exact up to rounding). Its cross terms with a column z
/// are `Σ T_i(x)·(T_j(y) z)`. The tail is [`sse_fast`]'s.
pub fn sse_fast_poly(
    factors: impl Fn(std::ops::Range<usize>) -> (Vec<Vec<f64>>, Vec<Vec<f64>>),
    n: usize,
    m: usize,
    extra: &[Vec<f64>],
    yc: &[f64],
) -> f64 {
    let len = yc.len();
    let nb = (n + 1) * (m + 1);
    let p = nb + extra.len();
    if len <= p || extra.iter().any(|z| z.len() != len) {
        return f64::INFINITY;
    }
    let mm = 2 * m + 1;
    // Columns after the baseline block: the extra columns, then the centred pressure.
    let tail: Vec<&[f64]> = extra
        .iter()
        .map(Vec::as_slice)
        .chain(std::iter::once(yc))
        .collect();
    let nt = tail.len();
    // Per block of rows, column-major matrices in one per-thread buffer (see `sse_fast`):
    // T_x(0..=2n), T_y(0..=2m), then W, whose column t·(m+1) + j is T_j(y)·z_t. The products go
    // to `matrixmultiply` and are summed over the blocks (bit-identical to one product, as in
    // `sse_fast`): the moments T_xᵀT_y, and the cross terms Σ T_i(x)·(T_j(y) z_t) = T_xᵀW.
    let mut mom = DMatrix::zeros(2 * n + 1, mm);
    let mut cw = DMatrix::zeros(n + 1, (m + 1) * nt);
    let complete = POLY_BUF.with_borrow_mut(|buf| {
        for (k, lo) in (0..len).step_by(GRAM_BLOCK).enumerate() {
            let hi = (lo + GRAM_BLOCK).min(len);
            let bl = hi - lo;
            let (tx, ty) = factors(lo..hi);
            if tx.len() < 2 * n + 1 || ty.len() < mm || tx.iter().chain(&ty).any(|c| c.len() != bl)
            {
                return false;
            }
            buf.clear();
            buf.reserve(bl * (2 * n + 1 + mm + (m + 1) * nt));
            for v in tx[..=2 * n].iter().chain(&ty[..mm]) {
                buf.extend_from_slice(v);
            }
            for z in &tail {
                for tj in &ty[..=m] {
                    buf.extend(tj.iter().zip(&z[lo..hi]).map(|(a, b)| a * b));
                }
            }
            let (txd, rest) = buf.split_at(bl * (2 * n + 1));
            let (tyd, wd) = rest.split_at(bl * mm);
            at_b_into(txd, bl, 2 * n + 1, tyd, mm, &mut mom, k > 0);
            let w_cols = (m + 1) * nt;
            at_b_into(&txd[..(n + 1) * bl], bl, n + 1, wd, w_cols, &mut cw, k > 0);
        }
        true
    });
    if !complete {
        return f64::INFINITY;
    }
    let mo = |a: usize, b: usize| mom[(a, b)];
    let cross = |t: usize, idx: usize| cw[(idx / (m + 1), t * (m + 1) + idx % (m + 1))];
    let mut tt = vec![0.0; nt * nt];
    for a in 0..nt {
        for b in 0..=a {
            let v = dot(tail[a], tail[b]);
            tt[a * nt + b] = v;
            tt[b * nt + a] = v;
        }
    }
    let g = |r: usize, c: usize| match (r < nb, c < nb) {
        (true, true) => {
            let (i, j, k, l) = (r / (m + 1), r % (m + 1), c / (m + 1), c % (m + 1));
            let (ip, im, jp, jm) = (i + k, i.abs_diff(k), j + l, j.abs_diff(l));
            0.25 * (mo(ip, jp) + mo(ip, jm) + mo(im, jp) + mo(im, jm))
        }
        (true, false) => cross(c - nb, r),
        (false, true) => cross(r - nb, c),
        (false, false) => tt[(r - nb) * nt + (c - nb)],
    };
    sse_from_gram(p, g)
}

/// `C ← AᵀB` (or `C ← C + AᵀB` when `accumulate`) for column-major `len × ka` and `len × kb`
/// matrices given as slices, by `matrixmultiply` (register-blocked kernels on the CPU's vector
/// units), reading `A` through strides, without a transposed copy; `c` is ka × kb.
fn at_b_into(
    a: &[f64],
    len: usize,
    ka: usize,
    b: &[f64],
    kb: usize,
    c: &mut DMatrix<f64>,
    accumulate: bool,
) {
    assert!(
        a.len() >= len * ka && b.len() >= len * kb && c.shape() == (ka, kb),
        "at_b: slices too short"
    );
    // SAFETY: Aᵀ (ka × len) has element (i, r) at a[i·len + r] (row stride len, column stride 1),
    // B (len × kb) has (r, j) at b[r + j·len], C (ka × kb, column-major, owned) has (i, j) at
    // i + j·ka; every index is within the slices, checked above, and C does not alias A or B.
    unsafe {
        matrixmultiply::dgemm(
            ka,
            len,
            kb,
            1.0,
            a.as_ptr(),
            len as isize,
            1,
            b.as_ptr(),
            1,
            len as isize,
            if accumulate { 1.0 } else { 0.0 },
            c.as_mut_ptr(),
            1,
            ka as isize,
        );
    }
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
    fn chebyshev_moment_sse_agrees_with_qr() {
        // A (3, 2) tensor Chebyshev design on scattered points, with two extra columns and a gap in
        // the rows: the moment route must give the SSE of the QR fit of the explicit design.
        let (n, m) = (3, 2);
        let len = 400;
        let x: Vec<f64> = (0..len).map(|k| (0.37 * k as f64).sin()).collect();
        let yv: Vec<f64> = (0..len).map(|k| (0.11 * k as f64).cos() * 0.9).collect();
        let cheb = |s: f64, d: usize| (d as f64 * s.acos()).cos();
        let mut cols: Vec<Vec<f64>> = Vec::new();
        for i in 0..=n {
            for j in 0..=m {
                cols.push((0..len).map(|k| cheb(x[k], i) * cheb(yv[k], j)).collect());
            }
        }
        let e1: Vec<f64> = (0..len).map(|k| (0.05 * k as f64).sin()).collect();
        let e2: Vec<f64> = (0..len).map(|k| (k as f64 / len as f64).powi(2)).collect();
        cols.push(e1.clone());
        cols.push(e2.clone());
        let p: Vec<f64> = (0..len)
            .map(|k| 1.0 + x[k].powi(3) - 2.0 * x[k] * yv[k] + (1.3 * k as f64).sin())
            .collect();
        let rows: Vec<usize> = (0..150).chain(200..len).collect();
        let qr = fit(&cols, &p, &rows).unwrap().sse;
        let g = |s: &[f64]| -> Vec<f64> { rows.iter().map(|&r| s[r]).collect() };
        let factors = |range: std::ops::Range<usize>| {
            let at = |s: &[f64], deg: usize| -> Vec<Vec<f64>> {
                (0..=deg)
                    .map(|d| rows[range.clone()].iter().map(|&r| cheb(s[r], d)).collect())
                    .collect()
            };
            (at(&x, 2 * n), at(&yv, 2 * m))
        };
        let pr = g(&p);
        let mean = pr.iter().sum::<f64>() / pr.len() as f64;
        let yc: Vec<f64> = pr.iter().map(|v| v - mean).collect();
        let fast = sse_fast_poly(factors, n, m, &[g(&e1), g(&e2)], &yc);
        assert!((fast - qr).abs() < 1e-9 * qr, "{fast} vs {qr}");
    }

    #[test]
    fn blocked_qr_equals_one_shot_householder() {
        // Three columns → blocks of 32 rows, so 900 rows take 29 block factorisations. The
        // reference is nalgebra's Householder QR of the whole scaled design in one piece, solved
        // by hand: β, (XᵀX)⁻¹ and SSE must agree to rounding.
        let len = 1000;
        let t: Vec<f64> = (0..len).map(|k| k as f64 / 100.0).collect();
        let cols = [
            vec![1.0; len],
            t.iter().map(|v| (1.3 * v).sin() * 40.0).collect::<Vec<_>>(),
            t.iter().map(|v| v * v).collect::<Vec<_>>(),
        ];
        let y: Vec<f64> = t
            .iter()
            .map(|&v| 3.0 - 0.02 * v * v + (5.0 * v).cos())
            .collect();
        let rows: Vec<usize> = (0..400).chain(500..len).collect();
        let f = fit(&cols, &y, &rows).unwrap();
        let x = DMatrix::from_fn(rows.len(), 3, |i, j| cols[j][rows[i]]);
        let yv = DVector::from_iterator(rows.len(), rows.iter().map(|&r| y[r]));
        let qr = x.clone().qr();
        let beta = qr
            .r()
            .solve_upper_triangular(&(qr.q().transpose() * &yv))
            .unwrap();
        let r_inv = qr.r().try_inverse().unwrap();
        let cov = &r_inv * r_inv.transpose();
        let sse = (&yv - &x * &beta).norm_squared();
        for j in 0..3 {
            assert!((f.beta[j] - beta[j]).abs() < 1e-10 * beta[j].abs().max(1e-3));
            for k in 0..3 {
                assert!((f.xtx_inv[(j, k)] - cov[(j, k)]).abs() < 1e-10 * cov[(j, j)].abs());
            }
        }
        assert!((f.sse - sse).abs() < 1e-10 * sse, "{} vs {sse}", f.sse);
        // The Gram route after a larger call on the same thread (its buffer is reused, shrunk).
        let g = sse_fast(&cols, &y, &rows);
        assert!((g - sse).abs() < 1e-8 * sse, "{g} vs {sse}");
        let few: Vec<usize> = (0..40).collect();
        let small = fit(&cols, &y, &few).unwrap().sse;
        assert!((sse_fast(&cols, &y, &few) - small).abs() < 1e-8 * small);
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
