//! ReLU neural-network models (paper Table II): `P̂(t) = f_NN(v(t), v̇(t))`, and the
//! autoregressive variant `P̂(t) = f_NN_AR({v(t−i), v̇(t−i)}_{i=0..p})`.
//!
//! # Architecture: one ReLU neuron per layer, every layer sees the inputs
//! The paper keeps the networks at the parameter scale of the other families and reports
//! ν = 4d + 1 for depth d (Table III: d = 1 → 5, 2 → 9, 8 → 33, 15 → 61). That count is exactly a
//! chain of single ReLU neurons, each fed by the previous neuron and by the inputs x ∈ ℝⁿ
//! (n = 2(p + 1) inputs: v and v̇ at lags 0..p, standardised):
//!
//! ```text
//! h₁ = relu(w₁·x + c₁)
//! hₗ = relu(aₗ hₗ₋₁ + wₗ·x + cₗ),   l = 2..d
//! ŷ  = o h_d + e                    (then un-standardised: P̂ = μ_P + σ_P ŷ)
//! ν  = (n + 1) + (d − 1)(n + 2) + 2 = d(n + 2) + 1      (= 4d + 1 for n = 2)
//! ```
//!
//! For the AR networks this gives ν = d(2p + 4) + 1; the paper's AR rows (Table III, d = 8:
//! ν = 41, 57, .., 105 for p = 1..5) imply one input fewer than its own Table II definition
//! (lags 0..p of both signals), which is the one followed here.
//!
//! # Training
//! Mean squared error on the standardised target, mini-batch Adam (Kingma & Ba 2015) with
//! cosine-decayed step size and gradients by hand-written backpropagation:
//!
//! ```text
//! ∂L/∂ŷ = 2(ŷ − y)/B,   ∂L/∂o = Σ ∂L/∂ŷ h_d,   ∂L/∂e = Σ ∂L/∂ŷ,
//! gₗ = ∂L/∂zₗ (zₗ the pre-activation):  g_d = ∂L/∂ŷ · o · 1[z_d > 0],
//!                                        gₗ₋₁ = gₗ aₗ 1[zₗ₋₁ > 0],
//! ∂L/∂wₗ = Σ gₗ x,  ∂L/∂cₗ = Σ gₗ,  ∂L/∂aₗ = Σ gₗ hₗ₋₁
//! ```
//!
//! (checked against central finite differences in the tests). Every 64-row block whose index is
//! 9 mod 10 is held out for early stopping: the parameters with the best held-out error are kept.
//! Everything is seeded, so a fit is a pure function of data and [`SweepConfig`]; the sweep trains
//! its models on [`SweepConfig::threads`] threads, each model with its own seed-derived stream.
//!
//! Why not an ML framework: these nets have 5..105 parameters in 1-neuron layers, where a
//! framework's per-operation overhead dominates and its dependency tree is large; the whole
//! forward/backward pass is the twenty lines in `Net::loss_grad`.

use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use std::sync::atomic::{AtomicUsize, Ordering};

/// Network inputs: v, v̇ and the autoregressive order p. Rows t = p..N have a prediction (they
/// need v and v̇ at t − p): the training target is P(p..N).
#[derive(Debug, Clone, Copy)]
pub struct Inputs<'a> {
    /// Volume v (mm³).
    pub v: &'a [f64],
    /// Flow v̇ (mm³/s).
    pub vdot: &'a [f64],
    /// Autoregressive order p (0 = the plain network on v(t), v̇(t)).
    pub ar_order: usize,
}

/// Sweep and training settings.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepConfig {
    /// Depths d to train (paper: 1..=15).
    pub depths: Vec<usize>,
    /// AR orders to train at every depth; empty means just `Inputs::ar_order`.
    pub ar_orders: Vec<usize>,
    /// Passes over the training rows.
    pub epochs: usize,
    /// Seed of every random choice (initial weights, batch order).
    pub seed: u64,
    /// Models trained in parallel.
    pub threads: usize,
    /// Rows per Adam step.
    pub batch_size: usize,
    /// Initial Adam step size (on standardised data); decays by cosine to 1 % of it.
    pub learning_rate: f64,
    /// Stop when the held-out error has not improved for this many epochs.
    pub patience: usize,
}

impl Default for SweepConfig {
    fn default() -> Self {
        SweepConfig {
            depths: (1..=15).collect(),
            ar_orders: Vec::new(),
            epochs: 60,
            seed: 0x5BA,
            threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            batch_size: 256,
            learning_rate: 0.02,
            patience: 20,
        }
    }
}

/// A trained network.
#[derive(Debug, Clone)]
pub struct NnFit {
    /// Depth d (hidden layers of one neuron).
    pub depth: usize,
    /// Autoregressive order p.
    pub ar_order: usize,
    /// Trainable parameters ν = d(2p + 4) + 1.
    pub n_params: usize,
    /// Sum of squared errors over all N − p rows, held-out ones included (kPa²).
    pub sse: f64,
    /// Rows the SSE is over (N − p).
    pub n_rows: usize,
    /// RMSE on the held-out rows (kPa); NaN when there are none.
    pub val_rmse: f64,
    /// Epochs run before early stopping or the limit.
    pub epochs_run: usize,
    net: Net,
}

impl NnFit {
    /// The early-stopping criterion: held-out RMSE, or the in-sample one without held-out rows.
    fn score(&self) -> f64 {
        if self.val_rmse.is_nan() {
            (self.sse / self.n_rows as f64).sqrt()
        } else {
            self.val_rmse
        }
    }

    /// Predictions aligned with the samples of `inputs` (N values): entry t is P̂(t); the first
    /// p entries are NaN, as those samples lack lagged inputs. The net's own AR order is used,
    /// whatever `inputs.ar_order` says.
    pub fn predict(&self, inputs: &Inputs) -> Vec<f64> {
        let n = inputs.v.len().min(inputs.vdot.len());
        let mut out = vec![f64::NAN; self.ar_order.min(n)];
        out.extend(self.predict_rows(inputs.v, inputs.vdot));
        out
    }

    /// Predictions for rows t = p..N of `v`, `vdot` only (N − p values; empty if N ≤ p).
    pub fn predict_rows(&self, v: &[f64], vdot: &[f64]) -> Vec<f64> {
        let x = features(v, vdot, self.ar_order, &self.net.x_mean, &self.net.x_std);
        self.net.predict(&x)
    }
}

/// Why a network could not be trained.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NnError {
    /// Depth 0 was asked for.
    #[error("network depth must be at least 1")]
    ZeroDepth,
    /// The columns differ in length.
    #[error("columns differ in length: volume {v}, flow {vdot}, pressure {p} samples")]
    LengthMismatch { v: usize, vdot: usize, p: usize },
    /// A value is NaN or infinite.
    #[error("non-finite {column} at sample {index}; clean or drop that row")]
    NonFinite { column: &'static str, index: usize },
    /// Fewer usable rows than parameters + 1.
    #[error("network with {n_params} parameters needs at least {needed} samples, got {got}")]
    TooFewSamples {
        n_params: usize,
        needed: usize,
        got: usize,
    },
    /// Training produced a non-finite loss.
    #[error("training diverged (depth {depth}, AR order {ar_order}); lower the learning rate")]
    Diverged { depth: usize, ar_order: usize },
}

/// Trains one network of the given depth on `inputs` (AR order `inputs.ar_order`).
pub fn fit(inputs: &Inputs, p: &[f64], depth: usize, cfg: &SweepConfig) -> Result<NnFit, NnError> {
    let data = Data::new(inputs, p, inputs.ar_order)?;
    train(&data, depth, cfg, None)
}

/// The outcome of a sweep: one entry per (AR order, depth), AR-order-major, in `cfg.depths`
/// order. Iterating it yields the successful fits; [`Sweep::results`] keeps the errors too.
#[derive(Debug, Clone)]
pub struct Sweep {
    /// Every model's fit or error.
    pub results: Vec<Result<NnFit, NnError>>,
}

impl Sweep {
    /// The models that could not be trained, with why.
    pub fn errors(&self) -> impl Iterator<Item = &NnError> {
        self.results.iter().filter_map(|r| r.as_ref().err())
    }
}

impl IntoIterator for Sweep {
    type Item = NnFit;
    type IntoIter = std::iter::Flatten<std::vec::IntoIter<Result<NnFit, NnError>>>;
    fn into_iter(self) -> Self::IntoIter {
        self.results.into_iter().flatten()
    }
}

/// Trains every (AR order, depth) pair of `cfg` (see [`Sweep`] for the order). Per AR order the depths, ascending, form two chains (every other depth). Each net is
/// trained twice, from a fresh start and warm-started from the previous net of its chain
/// (embedded so that the deeper net starts with exactly the shallower one's function), and the
/// one with the lower held-out error is kept; since training keeps its best parameters, a deeper
/// net is never worse on held-out rows than the one two steps shallower. Chains are the units of
/// parallel work (on `cfg.threads` threads); results do not depend on the thread count.
pub fn sweep(inputs: &Inputs, p: &[f64], cfg: &SweepConfig) -> Sweep {
    let orders = if cfg.ar_orders.is_empty() {
        vec![inputs.ar_order]
    } else {
        cfg.ar_orders.clone()
    };
    let datas: Vec<Result<Data, NnError>> =
        orders.iter().map(|&q| Data::new(inputs, p, q)).collect();
    let nd = cfg.depths.len();
    // Chains of job indices j = order index · nd + depth position.
    let mut chains: Vec<(usize, Vec<usize>)> = Vec::new();
    for oi in 0..orders.len() {
        let mut pos: Vec<usize> = (0..nd).collect();
        pos.sort_by_key(|&i| cfg.depths[i]);
        for parity in 0..2 {
            let chain: Vec<usize> = pos
                .iter()
                .skip(parity)
                .step_by(2)
                .map(|&i| oi * nd + i)
                .collect();
            if !chain.is_empty() {
                chains.push((oi, chain));
            }
        }
    }
    // Biggest chains first, so the threads finish together.
    let cost = |c: &(usize, Vec<usize>)| -> usize {
        c.1.iter()
            .map(|&j| cfg.depths[j % nd] * (orders[c.0] + 2))
            .sum()
    };
    chains.sort_by_key(|c| std::cmp::Reverse(cost(c)));
    let next = AtomicUsize::new(0);
    let threads = cfg.threads.clamp(1, chains.len().max(1));
    let done: Vec<Vec<(usize, Result<NnFit, NnError>)>> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut out = Vec::new();
                    while let Some((oi, chain)) = chains.get(next.fetch_add(1, Ordering::Relaxed)) {
                        let mut prev: Option<Net> = None;
                        for &j in chain {
                            let r = match &datas[*oi] {
                                Ok(data) => {
                                    let d = cfg.depths[j % nd];
                                    let fresh = train(data, d, cfg, None);
                                    match (fresh, prev.as_ref()) {
                                        (Ok(f), Some(pn)) => match train(data, d, cfg, Some(pn)) {
                                            Ok(w) if w.score() < f.score() => Ok(w),
                                            _ => Ok(f),
                                        },
                                        (r, _) => r,
                                    }
                                }
                                Err(e) => Err(e.clone()),
                            };
                            if let Ok(f) = &r {
                                prev = Some(f.net.clone());
                            }
                            out.push((j, r));
                        }
                    }
                    out
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| w.join().expect("training thread panicked"))
            .collect()
    });
    let mut results: Vec<Option<Result<NnFit, NnError>>> = vec![None; orders.len() * nd];
    for (j, r) in done.into_iter().flatten() {
        results[j] = Some(r);
    }
    Sweep {
        results: results
            .into_iter()
            .map(|r| r.expect("every job ran"))
            .collect(),
    }
}

/// Standardised input rows and target for one AR order.
struct Data {
    ar_order: usize,
    n_in: usize,
    /// Row-major, `rows × n_in`.
    x: Vec<f64>,
    /// Standardised target.
    y: Vec<f64>,
    x_mean: Vec<f64>,
    x_std: Vec<f64>,
    y_mean: f64,
    y_std: f64,
}

impl Data {
    fn new(inputs: &Inputs, p: &[f64], ar_order: usize) -> Result<Self, NnError> {
        let (v, vdot) = (inputs.v, inputs.vdot);
        if v.len() != vdot.len() || v.len() != p.len() {
            return Err(NnError::LengthMismatch {
                v: v.len(),
                vdot: vdot.len(),
                p: p.len(),
            });
        }
        for (column, xs) in [("v", v), ("vdot", vdot), ("p", p)] {
            if let Some(index) = xs.iter().position(|x| !x.is_finite()) {
                return Err(NnError::NonFinite { column, index });
            }
        }
        let n_in = 2 * (ar_order + 1);
        let rows = v.len().saturating_sub(ar_order);
        // Scalers from the signals themselves (every lag column shares its signal's scaler).
        let (mv, sv) = mean_std(v);
        let (mq, sq) = mean_std(vdot);
        let x_mean: Vec<f64> = (0..n_in)
            .map(|i| if i % 2 == 0 { mv } else { mq })
            .collect();
        let x_std: Vec<f64> = (0..n_in)
            .map(|i| if i % 2 == 0 { sv } else { sq })
            .collect();
        let x = features(v, vdot, ar_order, &x_mean, &x_std);
        let (y_mean, y_std) = mean_std(&p[ar_order.min(p.len())..]);
        let y = p[ar_order.min(p.len())..]
            .iter()
            .map(|x| (x - y_mean) / y_std)
            .collect();
        debug_assert_eq!(x.len(), rows * n_in);
        Ok(Data {
            ar_order,
            n_in,
            x,
            y,
            x_mean,
            x_std,
            y_mean,
            y_std,
        })
    }

    fn rows(&self) -> usize {
        self.y.len()
    }
}

/// Mean and standard deviation; a constant signal gets σ = 1 (it carries no information, and
/// dividing by 0 would poison the net).
fn mean_std(xs: &[f64]) -> (f64, f64) {
    if xs.is_empty() {
        return (0.0, 1.0);
    }
    let n = xs.len() as f64;
    let m = xs.iter().sum::<f64>() / n;
    let s = (xs.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / n).sqrt();
    (m, if s > 0.0 { s } else { 1.0 })
}

/// Rows t = p..N of `[v(t), v̇(t), v(t−1), v̇(t−1), .., v(t−p), v̇(t−p)]`, standardised.
fn features(v: &[f64], vdot: &[f64], p: usize, mean: &[f64], std: &[f64]) -> Vec<f64> {
    let n = v.len().min(vdot.len());
    let n_in = 2 * (p + 1);
    let mut x = Vec::with_capacity(n.saturating_sub(p) * n_in);
    for t in p..n {
        for lag in 0..=p {
            x.push((v[t - lag] - mean[2 * lag]) / std[2 * lag]);
            x.push((vdot[t - lag] - mean[2 * lag + 1]) / std[2 * lag + 1]);
        }
    }
    x
}

/// Parameters and scalers. θ layout: layer l at l·(n+2): [aₗ, wₗ (n), cₗ], then [o, e]; a₁ is
/// stored but fixed at 0 (layer 1 has no predecessor) and not counted in ν.
#[derive(Debug, Clone)]
struct Net {
    depth: usize,
    n_in: usize,
    theta: Vec<f64>,
    x_mean: Vec<f64>,
    x_std: Vec<f64>,
    y_mean: f64,
    y_std: f64,
}

impl Net {
    fn stride(&self) -> usize {
        self.n_in + 2
    }

    /// Standardised output for one standardised input row; fills pre-activations `z` and
    /// activations `h` (length d; h_d = z_d).
    #[inline]
    fn forward(&self, x: &[f64], z: &mut [f64], h: &mut [f64]) -> f64 {
        let st = self.stride();
        let mut prev = 0.0;
        for l in 0..self.depth {
            let w = &self.theta[l * st..(l + 1) * st];
            let mut s = w[st - 1] + w[0] * prev;
            for (wi, xi) in w[1..st - 1].iter().zip(x) {
                s += wi * xi;
            }
            z[l] = s;
            // The last neuron is linear: a ReLU there would clip the prediction (and once dead
            // on every row, the net is stuck at the mean).
            prev = if l + 1 < self.depth { s.max(0.0) } else { s };
            h[l] = prev;
        }
        let out = self.depth * st;
        self.theta[out] * prev + self.theta[out + 1]
    }

    /// Mean squared error over `rows` (indices into `x`, `y`) and, added into `grad`, its
    /// gradient. Backpropagation as in the module docs.
    fn loss_grad(&self, x: &[f64], y: &[f64], rows: &[usize], grad: &mut [f64]) -> f64 {
        let (d, n, st) = (self.depth, self.n_in, self.stride());
        let out = d * st;
        let (mut z, mut h) = (vec![0.0; d], vec![0.0; d]);
        let scale = 2.0 / rows.len() as f64;
        let mut loss = 0.0;
        for &r in rows {
            let xr = &x[r * n..(r + 1) * n];
            let yhat = self.forward(xr, &mut z, &mut h);
            let e = yhat - y[r];
            loss += e * e;
            let g = scale * e;
            grad[out] += g * h[d - 1];
            grad[out + 1] += g;
            let mut gl = g * self.theta[out];
            for l in (0..d).rev() {
                if gl == 0.0 {
                    break; // a dead neuron stops the gradient for all layers below it
                }
                let gw = &mut grad[l * st..(l + 1) * st];
                if l > 0 {
                    gw[0] += gl * h[l - 1];
                }
                for (gi, xi) in gw[1..st - 1].iter_mut().zip(xr) {
                    *gi += gl * xi;
                }
                gw[st - 1] += gl;
                gl = if l > 0 && z[l - 1] > 0.0 {
                    gl * self.theta[l * st]
                } else {
                    0.0
                };
            }
        }
        loss / rows.len() as f64
    }

    fn mse(&self, x: &[f64], y: &[f64], rows: &[usize]) -> f64 {
        let (mut z, mut h) = (vec![0.0; self.depth], vec![0.0; self.depth]);
        let n = self.n_in;
        rows.iter()
            .map(|&r| {
                let e = self.forward(&x[r * n..(r + 1) * n], &mut z, &mut h) - y[r];
                e * e
            })
            .sum::<f64>()
            / rows.len().max(1) as f64
    }

    /// Predictions in pressure units for standardised rows `x`.
    fn predict(&self, x: &[f64]) -> Vec<f64> {
        let (mut z, mut h) = (vec![0.0; self.depth], vec![0.0; self.depth]);
        x.chunks_exact(self.n_in)
            .map(|xr| self.y_mean + self.y_std * self.forward(xr, &mut z, &mut h))
            .collect()
    }
}

/// Parameter count ν = d(n + 2) + 1 for n inputs.
fn n_params(depth: usize, n_in: usize) -> usize {
    depth * (n_in + 2) + 1
}

/// Seed of one model: the sweep seed mixed with the model's shape (SplitMix64 finaliser), so a
/// model's result does not depend on which thread or in which order it ran.
fn model_seed(seed: u64, depth: usize, ar_order: usize) -> u64 {
    let mut z = seed ^ ((depth as u64) << 32 | ar_order as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Initial weights: uniform with variance 1/fan-in; biases of 3 so that every neuron starts active
/// on standardised inputs (|x| ≲ 3), i.e. the net starts as a linear model with gradient reaching
/// every layer, instead of dead; chain weights aₗ ∈ [0.25, 0.75] keep hₗ = O(1) along the chain.
fn init(depth: usize, n_in: usize, rng: &mut StdRng) -> Vec<f64> {
    let st = n_in + 2;
    let mut th = vec![0.0; depth * st + 2];
    for l in 0..depth {
        let fan_in = if l == 0 { n_in } else { n_in + 1 } as f64;
        let r = (3.0 / fan_in).sqrt();
        let w = &mut th[l * st..(l + 1) * st];
        w[0] = if l == 0 {
            0.0
        } else {
            rng.random_range(0.25..0.75)
        };
        for wi in &mut w[1..st - 1] {
            *wi = rng.random_range(-r..r);
        }
        w[st - 1] = 3.0;
    }
    let out = depth * st;
    let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    th[out] = sign * rng.random_range(0.1..0.3);
    th[out + 1] = -3.0 * th[out];
    th
}

/// Puts each hidden neuron's kink through a random data row (bias = −pre-activation there), so
/// every neuron starts active on part of the data and bends the fit there, rather than starting
/// everywhere-active (a linear model that Adam tends to keep) or dead.
fn place_hinges(net: &mut Net, x: &[f64], rng: &mut StdRng) {
    let (d, n, st) = (net.depth, net.n_in, net.stride());
    let rows = x.len() / n;
    if rows == 0 {
        return;
    }
    let (mut z, mut h) = (vec![0.0; d], vec![0.0; d]);
    for l in 0..d.saturating_sub(1) {
        let r = rng.random_range(0..rows);
        net.forward(&x[r * n..(r + 1) * n], &mut z, &mut h);
        // z[l] was computed with the current bias; shift it so z[l] = 0 at row r.
        net.theta[l * st + st - 1] -= z[l];
    }
}

/// Revives hidden neurons that are inactive on every sampled training row (a dead ReLU gets no
/// gradient and would stay dead): re-places its kink through a random row and zeroes the next
/// layer's weight on it, so the network function is unchanged but that weight now gets gradient
/// and the neuron can learn again. Returns how many were revived.
fn revive_dead(net: &mut Net, x: &[f64], rows: &[usize], rng: &mut StdRng) -> usize {
    let (d, n, st) = (net.depth, net.n_in, net.stride());
    if d < 2 || rows.is_empty() {
        return 0;
    }
    let (mut z, mut h) = (vec![0.0; d], vec![0.0; d]);
    let mut alive = vec![false; d - 1];
    for &r in rows.iter().step_by(7) {
        net.forward(&x[r * n..(r + 1) * n], &mut z, &mut h);
        for (a, zl) in alive.iter_mut().zip(&z) {
            *a |= *zl > 0.0;
        }
    }
    let mut revived = 0;
    for l in 0..d - 1 {
        if alive[l] {
            continue;
        }
        let r = rows[rng.random_range(0..rows.len())];
        net.forward(&x[r * n..(r + 1) * n], &mut z, &mut h);
        net.theta[l * st + st - 1] -= z[l];
        net.theta[(l + 1) * st] = 0.0;
        revived += 1;
    }
    revived
}

/// Trains one net; `start`, a shallower trained net, is embedded as the top layers (its first
/// layer has a₁ = 0, so the new bottom layers change nothing at first and the deeper net starts
/// exactly where the shallower one ended).
fn train(
    data: &Data,
    depth: usize,
    cfg: &SweepConfig,
    start: Option<&Net>,
) -> Result<NnFit, NnError> {
    if depth == 0 {
        return Err(NnError::ZeroDepth);
    }
    let (p, n_in) = (data.ar_order, data.n_in);
    let nu = n_params(depth, n_in);
    let rows = data.rows();
    let needed = (nu + 1).max(10);
    if rows < needed {
        return Err(NnError::TooFewSamples {
            n_params: nu,
            needed: needed + p,
            got: rows + p,
        });
    }
    let mut rng = StdRng::seed_from_u64(model_seed(cfg.seed, depth, p));
    let mut net = Net {
        depth,
        n_in,
        theta: init(depth, n_in, &mut rng),
        x_mean: data.x_mean.clone(),
        x_std: data.x_std.clone(),
        y_mean: data.y_mean,
        y_std: data.y_std,
    };
    place_hinges(&mut net, &data.x, &mut rng);
    if let Some(s) = start.filter(|s| s.depth < depth && s.n_in == n_in) {
        let keep = (depth - s.depth) * net.stride();
        net.theta.truncate(keep);
        net.theta.extend_from_slice(&s.theta);
    }
    // Held-out blocks of 64 rows (block index 9 mod 10); none when the data is short.
    let (mut train_rows, mut val_rows): (Vec<usize>, Vec<usize>) =
        (0..rows).partition(|r| (r / 64) % 10 != 9);
    if val_rows.len() < 10 {
        train_rows = (0..rows).collect();
        val_rows.clear();
    }
    let batch = cfg.batch_size.clamp(1, train_rows.len());
    let steps_per_epoch = train_rows.len().div_ceil(batch);
    let total_steps = (cfg.epochs * steps_per_epoch).max(1);
    let (b1, b2, eps) = (0.9_f64, 0.999_f64, 1e-8);
    let np = net.theta.len();
    let (mut m, mut v, mut grad) = (vec![0.0; np], vec![0.0; np], vec![0.0; np]);
    // Early stopping watches the held-out rows, or the training rows when there are none.
    let score_rows = if val_rows.is_empty() {
        train_rows.clone()
    } else {
        val_rows.clone()
    };
    let score = |net: &Net| net.mse(&data.x, &data.y, &score_rows);
    let mut best = (score(&net), net.theta.clone());
    let (mut since_best, mut epochs_run, mut step) = (0, 0, 0usize);
    for _ in 0..cfg.epochs {
        train_rows.shuffle(&mut rng);
        for chunk in train_rows.chunks(batch) {
            grad.iter_mut().for_each(|g| *g = 0.0);
            let loss = net.loss_grad(&data.x, &data.y, chunk, &mut grad);
            if !loss.is_finite() {
                return Err(NnError::Diverged { depth, ar_order: p });
            }
            step += 1;
            let frac = step as f64 / total_steps as f64;
            let lr = cfg.learning_rate
                * (0.01 + 0.99 * 0.5 * (1.0 + (std::f64::consts::PI * frac).cos()));
            let (c1, c2) = (1.0 - b1.powi(step as i32), 1.0 - b2.powi(step as i32));
            for i in 0..np {
                m[i] = b1 * m[i] + (1.0 - b1) * grad[i];
                v[i] = b2 * v[i] + (1.0 - b2) * grad[i] * grad[i];
                net.theta[i] -= lr * (m[i] / c1) / ((v[i] / c2).sqrt() + eps);
            }
        }
        epochs_run += 1;
        revive_dead(&mut net, &data.x, &train_rows, &mut rng);
        let s = score(&net);
        if !s.is_finite() {
            return Err(NnError::Diverged { depth, ar_order: p });
        }
        if s < best.0 {
            best = (s, net.theta.clone());
            since_best = 0;
        } else {
            since_best += 1;
            if since_best >= cfg.patience {
                break;
            }
        }
    }
    net.theta = best.1;
    let all: Vec<usize> = (0..rows).collect();
    let sse = net.mse(&data.x, &data.y, &all) * rows as f64 * data.y_std * data.y_std;
    let val_rmse = if val_rows.is_empty() {
        f64::NAN
    } else {
        net.mse(&data.x, &data.y, &val_rows).sqrt() * data.y_std
    };
    Ok(NnFit {
        depth,
        ar_order: p,
        n_params: nu,
        sse,
        n_rows: rows,
        val_rmse,
        epochs_run,
        net,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn smooth_plant(n: usize) -> (Vec<f64>, Vec<f64>, Vec<f64>) {
        // Volume swept back and forth with varying rate; pressure a smooth, nonlinear function
        // of (v, v̇) with a flow-volume interaction — no noise, so the only error is the model's.
        let mut v = Vec::with_capacity(n);
        let mut q = Vec::with_capacity(n);
        let mut p = Vec::with_capacity(n);
        for t in 0..n {
            let s = t as f64 * 0.04;
            let vol = 275.0 - 270.0 * (0.31 * s).cos();
            let flow = 270.0 * 0.31 * (0.31 * s).sin();
            v.push(vol);
            q.push(flow);
            p.push(2.0 * (vol / 150.0).exp() + 0.03 * flow * (1.0 + vol / 550.0));
        }
        (v, q, p)
    }

    fn var(p: &[f64]) -> f64 {
        let m = p.iter().sum::<f64>() / p.len() as f64;
        p.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / p.len() as f64
    }

    #[test]
    fn gradient_matches_finite_differences() {
        let (v, q, p) = smooth_plant(300);
        for (depth, ar) in [(1, 0), (3, 0), (4, 2)] {
            let data = Data::new(
                &Inputs {
                    v: &v,
                    vdot: &q,
                    ar_order: ar,
                },
                &p,
                ar,
            )
            .unwrap();
            let mut rng = StdRng::seed_from_u64(42);
            let mut net = Net {
                depth,
                n_in: data.n_in,
                theta: init(depth, data.n_in, &mut rng),
                x_mean: data.x_mean.clone(),
                x_std: data.x_std.clone(),
                y_mean: data.y_mean,
                y_std: data.y_std,
            };
            let rows: Vec<usize> = (0..data.rows()).step_by(3).collect();
            let mut grad = vec![0.0; net.theta.len()];
            net.loss_grad(&data.x, &data.y, &rows, &mut grad);
            let h = 1e-6;
            // θ[0] = a₁ is fixed at 0 (layer 1 has no predecessor); its gradient is 0.
            for (i, &gi) in grad.iter().enumerate().skip(1) {
                let t0 = net.theta[i];
                net.theta[i] = t0 + h;
                let lp = net.mse(&data.x, &data.y, &rows);
                net.theta[i] = t0 - h;
                let lm = net.mse(&data.x, &data.y, &rows);
                net.theta[i] = t0;
                let fd = (lp - lm) / (2.0 * h);
                assert!(
                    (gi - fd).abs() <= 1e-6 * (1.0 + fd.abs()),
                    "d={depth} p={ar} θ[{i}]: analytic {gi} vs fd {fd}"
                );
            }
            assert_eq!(grad[0], 0.0);
        }
    }

    #[test]
    fn parameter_counts_follow_the_paper() {
        // Table III: d = 1, 2, 7, 8, 9, 14, 15 → ν = 5, 9, 29, 33, 37, 57, 61.
        for (d, nu) in [
            (1, 5),
            (2, 9),
            (7, 29),
            (8, 33),
            (9, 37),
            (14, 57),
            (15, 61),
        ] {
            assert_eq!(n_params(d, 2), nu);
            assert_eq!(init(d, 2, &mut StdRng::seed_from_u64(0)).len() - 1, nu);
        }
    }

    /// MSE of the least-squares plane P ≈ c₀ + c₁v + c₂v̇ (what a net no better than linear gets).
    fn linear_mse(v: &[f64], q: &[f64], p: &[f64]) -> f64 {
        let a = nalgebra::DMatrix::from_fn(v.len(), 3, |r, c| match c {
            0 => 1.0,
            1 => v[r] / 550.0,
            _ => q[r] / 100.0,
        });
        let y = nalgebra::DVector::from_column_slice(p);
        let coef = a.clone().svd(true, true).solve(&y, 1e-12).unwrap();
        (a * coef - y).norm_squared() / v.len() as f64
    }

    #[test]
    fn nets_fit_a_smooth_plant_far_better_than_the_mean_and_the_plane() {
        let (v, q, p) = smooth_plant(4000);
        let cfg = SweepConfig {
            depths: vec![1, 2, 3, 4],
            epochs: 30,
            threads: 2,
            ..SweepConfig::default()
        };
        let inputs = Inputs {
            v: &v,
            vdot: &q,
            ar_order: 0,
        };
        let swept = sweep(&inputs, &p, &cfg);
        assert_eq!(swept.errors().count(), 0);
        let fits: Vec<NnFit> = swept.into_iter().collect();
        let (base, plane) = (var(&p), linear_mse(&v, &q, &p));
        for f in &fits {
            let mse = f.sse / f.n_rows as f64;
            // No depth fails catastrophically: each is at least (about) as good as the plane,
            // which itself explains most of the variance of this plant (Adam stops a little short of the exact plane).
            assert!(
                mse < 1.25 * plane,
                "d={} mse {mse} vs plane {plane}",
                f.depth
            );
            // sse agrees with predict.
            let pred = f.predict_rows(&v, &q);
            let direct: f64 = pred.iter().zip(&p).map(|(a, b)| (a - b).powi(2)).sum();
            assert!((direct - f.sse).abs() <= 1e-9 * f.sse.max(1e-12));
        }
        assert!(plane < 0.2 * base);
        // With ReLU layers the curvature is captured: far below the plane.
        let best = fits
            .iter()
            .map(|f| f.sse / f.n_rows as f64)
            .fold(f64::INFINITY, f64::min);
        assert!(best < 0.05 * plane, "best {best} vs plane {plane}");
        // Determinism: the same config gives the same fits, whatever the thread count.
        let again = sweep(
            &inputs,
            &p,
            &SweepConfig {
                threads: 1,
                ..cfg.clone()
            },
        );
        for (a, b) in again.into_iter().zip(&fits) {
            assert_eq!(a.sse, b.sse);
        }
    }

    #[test]
    fn ar_rows_start_at_p() {
        let (v, q, p) = smooth_plant(1000);
        let cfg = SweepConfig {
            depths: vec![2],
            ar_orders: vec![0, 3],
            epochs: 5,
            ..SweepConfig::default()
        };
        let inputs = Inputs {
            v: &v,
            vdot: &q,
            ar_order: 0,
        };
        let fits: Vec<NnFit> = sweep(&inputs, &p, &cfg).into_iter().collect();
        let (f0, f3) = (&fits[0], &fits[1]);
        assert_eq!((f0.ar_order, f0.n_params, f0.n_rows), (0, 9, 1000));
        assert_eq!((f3.ar_order, f3.n_params, f3.n_rows), (3, 2 * 10 + 1, 997));
        let rows = f3.predict_rows(&v, &q);
        assert_eq!(rows.len(), 997);
        let aligned = f3.predict(&inputs);
        assert_eq!(aligned.len(), 1000);
        assert!(aligned[..3].iter().all(|x| x.is_nan()));
        assert_eq!(&aligned[3..], &rows[..]);
        assert!(f3.predict_rows(&v[..3], &q[..3]).is_empty());
    }

    #[test]
    fn bad_input_is_an_error() {
        let (v, q, mut p) = smooth_plant(200);
        let cfg = SweepConfig {
            epochs: 1,
            ..SweepConfig::default()
        };
        let inp = Inputs {
            v: &v,
            vdot: &q,
            ar_order: 0,
        };
        assert_eq!(fit(&inp, &p, 0, &cfg).unwrap_err(), NnError::ZeroDepth);
        assert!(matches!(
            fit(&inp, &p[..10], 1, &cfg),
            Err(NnError::LengthMismatch { .. })
        ));
        let short = Inputs {
            v: &v[..20],
            vdot: &q[..20],
            ar_order: 0,
        };
        assert!(matches!(
            fit(&short, &p[..20], 15, &cfg),
            Err(NnError::TooFewSamples { n_params: 61, .. })
        ));
        p[5] = f64::NAN;
        assert_eq!(
            fit(&inp, &p, 1, &cfg).unwrap_err(),
            NnError::NonFinite {
                column: "p",
                index: 5
            }
        );
        assert!(NnError::NonFinite {
            column: "p",
            index: 5
        }
        .to_string()
        .contains("sample 5"));
    }
}
