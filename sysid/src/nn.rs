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
//! hₗ = relu(aₗ hₗ₋₁ + wₗ·x + cₗ),   l = 2..d − 1
//! h_d = a_d h_{d−1} + w_d·x + c_d   (the last neuron is linear)
//! ŷ  = o h_d + e                    (then un-standardised: P̂ = μ_P + σ_P ŷ)
//! ν  = (n + 1) + (d − 1)(n + 2) + 2 = d(n + 2) + 1      (= 4d + 1 for n = 2)
//! ```
//!
//! For the AR networks this gives ν = d(2p + 4) + 1; the paper's AR rows (Table III, d = 8:
//! ν = 41, 57, .., 105 for p = 1..5) imply one input fewer than its own Table II definition
//! (lags 0..p of both signals), which is the one followed here.
//!
//! # Scaling
//! Every input column is standardised with its signal's mean and standard deviation (all lags of
//! v share v's, all lags of v̇ share v̇'s), and the target with the mean and standard deviation of
//! the whole pressure column, the same for every AR order, so a net of one order can be carried
//! over to another exactly. Units and offsets of the log therefore do not matter; a constant
//! column gets σ = 1.
//!
//! # Growing the nets: d from d − 1, AR from p = 0
//! Training a deep chain from a random start leaves units dead (inactive on every row, so no
//! gradient reaches them or anything below them), and independently trained depths then share
//! errors. Instead each net starts from a trained smaller one, with a new unit added so that the
//! network function is *exactly* unchanged:
//!
//! * d = 1 is linear in x and is solved exactly by least squares (no training).
//! * d from the trained d − 1 net, in [`SweepConfig::candidates`] ways, each trained and the best
//!   kept. Candidate 0 (and 2, 3, ..) puts a new ReLU unit below the chain, `h₁ = relu(w·x + c)`,
//!   coupled to the old first layer by a = 0; the unit is the best of 32 random proposals
//!   (He-scaled w ~ N(0, 2/n), kink through a random row: c = −w·x_r, so it is active on part
//!   of the data) by |Σᵢ gᵢ h₁(xᵢ)| / ‖h₁‖, where gᵢ is the loss gradient at the old first
//!   layer's pre-activation on row i: the rate at which moving a off 0 lowers the loss, so the
//!   unit starts where it helps. Candidate 1 inserts an identity pass
//!   `u = relu(1·hⱼ + 0·x + 0) = hⱼ` after a random hidden unit j (exact because hⱼ ≥ 0; from
//!   d − 1 = 1, with no hidden unit, another bottom unit).
//! * An AR net (p ≥ 1) of depth d starts as the trained p = 0 net of depth d with all lag weights
//!   zero, so it starts exactly where p = 0 ended; when the sweep also has the order-p net of
//!   depth d − 1, a net grown from that is a second candidate.
//!
//! Training keeps the parameters with the lowest training error seen, the start included. So, by
//! construction and not by a check, the training error (the [`NnFit::sse`] the sweep minimises)
//! never rises with d, and an AR net is never worse on its rows than the p = 0 net it started
//! from: a run that finds nothing better returns its start unchanged.
//!
//! A training run may still find nothing better than its grown start (the tests allow one such
//! depth per sweep; none occurred on their logs); that depth then repeats the error of the one
//! below it and reports its new unit as dead (cut off by a = 0), never a higher error.
//!
//! # Training
//! Mean squared error on the standardised target over every row given, mini-batch Adam
//! (Kingma & Ba 2015, β₁ = 0.9, β₂ = 0.999) with gradients by hand-written backpropagation:
//!
//! ```text
//! ∂L/∂ŷ = 2(ŷ − y)/B,   ∂L/∂o = Σ ∂L/∂ŷ h_d,   ∂L/∂e = Σ ∂L/∂ŷ,
//! gₗ = ∂L/∂zₗ (zₗ the pre-activation):  g_d = ∂L/∂ŷ · o,
//!                                        gₗ₋₁ = gₗ aₗ 1[zₗ₋₁ > 0],
//! ∂L/∂wₗ = Σ gₗ x,  ∂L/∂cₗ = Σ gₗ,  ∂L/∂aₗ = Σ gₗ hₗ₋₁
//! ```
//!
//! (checked against central finite differences in the tests), with
//!
//! * a step size η that ramps up linearly over the first min(100, steps per epoch) steps after
//!   every (re)start of Adam, so its first, sign-like steps do not throw a trained start away;
//! * gradient clipping: a step whose gradient norm exceeds 4× the running (EMA, 0.98) norm is
//!   scaled down to that bound, so single rows far out (spikes in a differentiated flow) cannot
//!   kick the parameters out of range;
//! * epochs of one pass over the rows, or of 200 steps over repeated passes if that is more (a
//!   short log would otherwise judge progress on a handful of steps);
//! * a plateau schedule: after every epoch the training MSE over all rows is computed; if the
//!   best one has not improved by the relative [`SweepConfig::tolerance`] for
//!   [`SweepConfig::patience`] epochs, the best parameters are restored, Adam's moments reset and
//!   η halved. After [`SweepConfig::lr_halvings`] halvings, a further stall means the net has
//!   *converged* ([`NnFit::converged`]); otherwise training stops at [`SweepConfig::epochs`]
//!   epochs ([`NnFit::epochs_run`] says how many ran);
//! * a non-finite loss restores the best parameters and halves η (it never ends the sweep);
//! * dead-unit restarts: after every epoch, a hidden unit inactive on every row gets fresh
//!   He-scaled weights with its kink through a random row, and the weight from it into the next
//!   layer is set to 0, so the function on the data is unchanged but the unit can learn again.
//!   [`NnFit::dead_units`] reports the units of the final net that cannot reach the output
//!   (inactive everywhere, or cut off by a zero weight or such a unit above them).
//!
//! # Determinism
//! Every random choice comes from a stream seeded by [`SweepConfig::seed`] and the model's shape
//! and candidate index; threads only decide which model is trained where, and all reductions run
//! in a fixed order. A sweep is a pure function of its data and configuration, bit for bit,
//! whatever [`SweepConfig::threads`].
//!
//! Why not an ML framework: these nets have 5..105 parameters in 1-neuron layers, where a
//! framework's per-operation overhead dominates and its dependency tree is large; the whole
//! forward/backward pass is the thirty lines of `Net::loss_grad`.

use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, StandardNormal};
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
    /// Depths d to train (paper: 1..=15). Depths in between are trained too (each net grows
    /// from the one before it) but only these are reported.
    pub depths: Vec<usize>,
    /// AR orders to train at every depth; empty means just `Inputs::ar_order`.
    pub ar_orders: Vec<usize>,
    /// Most passes over the rows per net.
    pub epochs: usize,
    /// Seed of every random choice (new units, batch order).
    pub seed: u64,
    /// Models trained in parallel (results do not depend on it).
    pub threads: usize,
    /// Rows per Adam step.
    pub batch_size: usize,
    /// Initial Adam step size η (on standardised data), halved on every plateau.
    pub learning_rate: f64,
    /// Epochs without a relative improvement of `tolerance` before η is halved.
    pub patience: usize,
    /// Relative improvement of the best training MSE that counts as progress.
    pub tolerance: f64,
    /// Halvings of η before a plateau means convergence.
    pub lr_halvings: usize,
    /// Ways of growing each net from the one before it, trained and the best kept (≥ 1).
    pub candidates: usize,
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
            learning_rate: 0.01,
            patience: 3,
            tolerance: 1e-4,
            lr_halvings: 3,
            candidates: 2,
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
    /// Sum of squared errors over all N − p rows, the training error (kPa²).
    pub sse: f64,
    /// Rows the SSE is over (N − p).
    pub n_rows: usize,
    /// Always NaN: the nets train on every row given (hold data out by predicting on it, as
    /// `identify` does with its held-out cycles). Kept for compatibility.
    pub val_rmse: f64,
    /// Epochs run on this net (0 for d = 1, solved by least squares).
    pub epochs_run: usize,
    /// Whether training stopped on the relative-improvement criterion (rather than the epoch
    /// limit); d = 1 is exact and counts as converged.
    pub converged: bool,
    /// Hidden units of the final net that cannot reach the output on the training rows.
    pub dead_units: usize,
    net: Net,
}

impl NnFit {
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

    /// Training RMSE over the N − p rows (kPa).
    pub fn rmse(&self) -> f64 {
        (self.sse / self.n_rows.max(1) as f64).sqrt()
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
    /// The start of training already had a non-finite loss (inputs too extreme for f64).
    #[error("training diverged (depth {depth}, AR order {ar_order}); lower the learning rate")]
    Diverged { depth: usize, ar_order: usize },
}

/// Trains one network of the given depth on `inputs` (AR order `inputs.ar_order`); the smaller
/// nets it grows from are trained on the way (see the module docs).
pub fn fit(inputs: &Inputs, p: &[f64], depth: usize, cfg: &SweepConfig) -> Result<NnFit, NnError> {
    let cfg = SweepConfig {
        depths: vec![depth],
        ar_orders: vec![inputs.ar_order],
        ..cfg.clone()
    };
    sweep(inputs, p, &cfg)
        .results
        .pop()
        .expect("one depth, one order")
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

/// Trains every (AR order, depth) pair of `cfg` (see [`Sweep`] for the order). First the p = 0
/// chain d = 1..max(depths), each net grown from the one before it in `cfg.candidates` ways
/// trained in parallel; then every AR order p ≥ 1 (orders in parallel), each depth started from
/// the p = 0 net of that depth (see the module docs). Results do not depend on `cfg.threads`.
pub fn sweep(inputs: &Inputs, p: &[f64], cfg: &SweepConfig) -> Sweep {
    let orders = if cfg.ar_orders.is_empty() {
        vec![inputs.ar_order]
    } else {
        cfg.ar_orders.clone()
    };
    let d_max = cfg.depths.iter().copied().max().unwrap_or(0);
    let threads = cfg.threads.max(1);
    // The p = 0 chain, d = 1..=d_max (index d − 1).
    let chain: Vec<Result<NnFit, NnError>> = match Data::new(inputs, p, 0) {
        Err(e) => vec![Err(e); d_max],
        Ok(data) => {
            let mut chain: Vec<Result<NnFit, NnError>> = Vec::with_capacity(d_max);
            for d in 1..=d_max {
                let r = match chain.last() {
                    None => linear_fit(&data),
                    Some(Err(e)) => data.check_size(d).and(Err(e.clone())),
                    Some(Ok(prev)) => grow_p0(&data, prev, d, cfg, threads),
                };
                chain.push(r);
            }
            chain
        }
    };
    // The AR orders, each one job running its depths in ascending order.
    let mut ar: Vec<usize> = orders.iter().copied().filter(|&q| q > 0).collect();
    ar.sort_unstable();
    ar.dedup();
    let mut asc: Vec<usize> = cfg.depths.iter().copied().filter(|&d| d > 0).collect();
    asc.sort_unstable();
    asc.dedup();
    // Biggest orders first, so the threads finish together.
    let mut jobs: Vec<usize> = (0..ar.len()).collect();
    jobs.sort_by_key(|&i| std::cmp::Reverse(ar[i]));
    let per_job = parallel(jobs.len(), threads, |k| {
        let q = ar[jobs[k]];
        match Data::new(inputs, p, q) {
            Err(e) => asc.iter().map(|_| Err(e.clone())).collect::<Vec<_>>(),
            Ok(data) => {
                let mut out: Vec<Result<NnFit, NnError>> = Vec::with_capacity(asc.len());
                for (i, &d) in asc.iter().enumerate() {
                    let below = (i > 0 && asc[i - 1] + 1 == d)
                        .then(|| out[i - 1].as_ref().ok())
                        .flatten();
                    let r = match &chain[d - 1] {
                        Err(e) => data.check_size(d).and(Err(e.clone())),
                        Ok(base) => grow_ar(&data, base, below, d, cfg),
                    };
                    out.push(r);
                }
                out
            }
        }
    });
    let mut by_order: Vec<Vec<Result<NnFit, NnError>>> = vec![Vec::new(); ar.len()];
    for (k, out) in per_job.into_iter().enumerate() {
        by_order[jobs[k]] = out;
    }
    let mut results = Vec::with_capacity(orders.len() * cfg.depths.len());
    for &q in &orders {
        for &d in &cfg.depths {
            results.push(if d == 0 {
                Err(NnError::ZeroDepth)
            } else if q == 0 {
                chain[d - 1].clone()
            } else {
                let oi = ar.binary_search(&q).expect("every order has a job");
                let di = asc.binary_search(&d).expect("every depth is trained");
                by_order[oi][di].clone()
            });
        }
    }
    Sweep { results }
}

/// Runs `f(0..n)` on up to `threads` threads; the results in index order.
fn parallel<T: Send>(n: usize, threads: usize, f: impl Fn(usize) -> T + Sync) -> Vec<T> {
    let threads = threads.clamp(1, n.max(1));
    if threads == 1 {
        return (0..n).map(f).collect();
    }
    let next = AtomicUsize::new(0);
    let done: Vec<Vec<(usize, T)>> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut out = Vec::new();
                    loop {
                        let i = next.fetch_add(1, Ordering::Relaxed);
                        if i >= n {
                            break out;
                        }
                        out.push((i, f(i)));
                    }
                })
            })
            .collect();
        workers
            .into_iter()
            .map(|w| w.join().expect("training thread panicked"))
            .collect()
    });
    let mut slots: Vec<Option<T>> = (0..n).map(|_| None).collect();
    for (i, t) in done.into_iter().flatten() {
        slots[i] = Some(t);
    }
    slots
        .into_iter()
        .map(|t| t.expect("every job ran"))
        .collect()
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
        // Scalers from the signals themselves (every lag column shares its signal's scaler, and
        // every order the target's), so nets carry over between orders exactly.
        let (mv, sv) = mean_std(v);
        let (mq, sq) = mean_std(vdot);
        let x_mean: Vec<f64> = (0..n_in)
            .map(|i| if i % 2 == 0 { mv } else { mq })
            .collect();
        let x_std: Vec<f64> = (0..n_in)
            .map(|i| if i % 2 == 0 { sv } else { sq })
            .collect();
        let x = features(v, vdot, ar_order, &x_mean, &x_std);
        let (y_mean, y_std) = mean_std(p);
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

    /// A net of this data's shape and scalers with parameters `theta`.
    fn net(&self, depth: usize, theta: Vec<f64>) -> Net {
        debug_assert_eq!(theta.len(), depth * (self.n_in + 2) + 2);
        Net {
            depth,
            n_in: self.n_in,
            theta,
            x_mean: self.x_mean.clone(),
            x_std: self.x_std.clone(),
            y_mean: self.y_mean,
            y_std: self.y_std,
        }
    }

    /// `TooFewSamples` unless there are more rows than parameters (and at least 10).
    fn check_size(&self, depth: usize) -> Result<(), NnError> {
        let nu = n_params(depth, self.n_in);
        let needed = (nu + 1).max(10);
        if self.rows() < needed {
            return Err(NnError::TooFewSamples {
                n_params: nu,
                needed: needed + self.ar_order,
                got: self.rows() + self.ar_order,
            });
        }
        Ok(())
    }
}

/// Mean and standard deviation (two passes, so large offsets do not cancel the spread); a
/// constant signal gets σ = 1 (it carries no information, and dividing by 0 would poison the
/// net), and so does a spread too large to square in f64 (its σ is then taken as the largest
/// deviation, which still brings the column to |x| ≤ 1).
fn mean_std(xs: &[f64]) -> (f64, f64) {
    if xs.is_empty() {
        return (0.0, 1.0);
    }
    let n = xs.len() as f64;
    // Mean of x/n terms: no overflow for any finite column.
    let m = xs.iter().map(|x| x / n).sum::<f64>();
    let dev_max = xs.iter().map(|x| (x - m).abs()).fold(0.0, f64::max);
    if dev_max.is_nan() || dev_max <= 0.0 || dev_max.is_infinite() {
        return (m, 1.0);
    }
    // Variance of the deviations scaled by their maximum: no overflow or underflow.
    let s = dev_max * (xs.iter().map(|x| ((x - m) / dev_max).powi(2)).sum::<f64>() / n).sqrt();
    (m, if s > 0.0 && s.is_finite() { s } else { 1.0 })
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

    /// Mean squared error over every row, and which hidden units are active (z > 0) on at least
    /// one row (`alive`, length d − 1).
    fn evaluate(&self, x: &[f64], y: &[f64], alive: &mut [bool]) -> f64 {
        let (d, n) = (self.depth, self.n_in);
        let (mut z, mut h) = (vec![0.0; d], vec![0.0; d]);
        alive.iter_mut().for_each(|a| *a = false);
        let mut sum = 0.0;
        for (xr, yr) in x.chunks_exact(n).zip(y) {
            let e = self.forward(xr, &mut z, &mut h) - yr;
            sum += e * e;
            for (a, zl) in alive.iter_mut().zip(&z) {
                *a |= *zl > 0.0;
            }
        }
        sum / y.len().max(1) as f64
    }

    #[cfg(test)]
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

    /// The hidden units that cannot reach the output: inactive on every row, or feeding the
    /// next layer through a zero weight, or feeding a unit that cannot.
    fn dead_units(&self, alive: &[bool]) -> usize {
        let (d, st) = (self.depth, self.stride());
        let mut reaches = true; // the linear last unit reaches the output (through o)
        let mut dead = 0;
        for l in (0..d.saturating_sub(1)).rev() {
            reaches = reaches && alive[l] && self.theta[(l + 1) * st] != 0.0;
            dead += usize::from(!reaches);
        }
        dead
    }

    /// This net with a new ReLU unit below the chain, coupled to the old first layer by a = 0
    /// (which that layer already has), so the function is unchanged. The unit is the best of
    /// [`PROPOSALS`] random He-scaled units with kinks through random rows: the one whose output
    /// h correlates most with the loss gradient g at the old first layer's pre-activation,
    /// |Σ gᵢhᵢ| / ‖h‖ (the rate at which a = 0 → ±ε lowers the loss), so that the new unit starts
    /// where it helps rather than at a saddle.
    fn grow_bottom(&self, x: &[f64], y: &[f64], rng: &mut StdRng) -> Net {
        let (n, st) = (self.n_in, self.stride());
        let g = self.bottom_gradients(x, y);
        let mut best = (f64::NEG_INFINITY, vec![0.0; st]);
        let mut block = vec![0.0; st];
        for _ in 0..PROPOSALS {
            he_unit(&mut block, n, x, rng);
            let (mut dot, mut sq) = (0.0, 0.0);
            for (xr, gi) in x.chunks_exact(n).zip(&g) {
                let zr = block[st - 1]
                    + block[1..st - 1]
                        .iter()
                        .zip(xr)
                        .map(|(w, x)| w * x)
                        .sum::<f64>();
                if zr > 0.0 {
                    dot += gi * zr;
                    sq += zr * zr;
                }
            }
            let score = if sq > 0.0 { dot.abs() / sq.sqrt() } else { 0.0 };
            if score > best.0 {
                best = (score, block.clone());
            }
        }
        let mut net = self.clone();
        net.depth += 1;
        net.theta.splice(0..0, best.1);
        debug_assert_eq!(net.theta[st], 0.0);
        net
    }

    /// Per row, the derivative of the squared error with respect to the first layer's
    /// pre-activation z₁ (back-propagated as in `loss_grad`).
    fn bottom_gradients(&self, x: &[f64], y: &[f64]) -> Vec<f64> {
        let (d, n, st) = (self.depth, self.n_in, self.stride());
        let (mut z, mut h) = (vec![0.0; d], vec![0.0; d]);
        x.chunks_exact(n)
            .zip(y)
            .map(|(xr, yr)| {
                let e = self.forward(xr, &mut z, &mut h) - yr;
                let mut gl = 2.0 * e * self.theta[d * st];
                for l in (1..d).rev() {
                    gl = if z[l - 1] > 0.0 {
                        gl * self.theta[l * st]
                    } else {
                        0.0
                    };
                }
                gl
            })
            .collect()
    }

    /// This net with an identity pass u = relu(1·hⱼ) = hⱼ inserted after hidden unit j (0-based,
    /// j < d − 1): the function is unchanged since hⱼ ≥ 0.
    fn grow_identity(&self, j: usize) -> Net {
        let st = self.stride();
        debug_assert!(j + 1 < self.depth);
        let mut block = vec![0.0; st];
        block[0] = 1.0;
        let mut net = self.clone();
        net.depth += 1;
        let at = (j + 1) * st;
        net.theta.splice(at..at, block);
        net
    }

    /// This net (of p = 0) with `n_in` inputs: the lag weights are zero, so it computes the same
    /// function of v(t), v̇(t). The scalers of the target data are taken (they agree, see
    /// [`Data::new`]).
    fn with_inputs(&self, data: &Data) -> Net {
        let (st, st2) = (self.stride(), data.n_in + 2);
        let mut theta = vec![0.0; self.depth * st2 + 2];
        for l in 0..self.depth {
            let (src, dst) = (&self.theta[l * st..(l + 1) * st], l * st2);
            theta[dst..dst + st - 1].copy_from_slice(&src[..st - 1]);
            theta[dst + st2 - 1] = src[st - 1];
        }
        theta[self.depth * st2..].copy_from_slice(&self.theta[self.depth * st..]);
        data.net(self.depth, theta)
    }
}

/// Fills a unit's block [a, w, c] with He-scaled input weights w ~ N(0, 2/n), keeps a, and puts
/// its kink through a random row of `x` (the pre-activation there, without the chain term, is 0).
fn he_unit(block: &mut [f64], n: usize, x: &[f64], rng: &mut StdRng) {
    let st = n + 2;
    let sd = (2.0 / n as f64).sqrt();
    for wi in &mut block[1..st - 1] {
        let z: f64 = StandardNormal.sample(rng);
        *wi = sd * z;
    }
    let rows = x.len() / n;
    block[st - 1] = if rows == 0 {
        0.0
    } else {
        let r = rng.random_range(0..rows);
        -block[1..st - 1]
            .iter()
            .zip(&x[r * n..(r + 1) * n])
            .map(|(w, x)| w * x)
            .sum::<f64>()
    };
}

/// Fewest Adam steps per epoch (see `train`).
const MIN_EPOCH_STEPS: usize = 200;

/// Random units a new bottom unit is chosen from (see `Net::grow_bottom`).
const PROPOSALS: usize = 32;

/// Parameter count ν = d(n + 2) + 1 for n inputs.
fn n_params(depth: usize, n_in: usize) -> usize {
    depth * (n_in + 2) + 1
}

/// Seed of one training run: the sweep seed mixed with the model's shape and candidate
/// (SplitMix64 finaliser), so a result does not depend on which thread or in which order it ran.
fn model_seed(seed: u64, depth: usize, ar_order: usize, candidate: usize) -> u64 {
    let shape = (depth as u64) << 32 | (ar_order as u64) << 16 | candidate as u64;
    let mut z = seed ^ shape.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Random initial weights of a whole net (the tests' gradient check): He-scaled units with their
/// kinks through the origin shifted by a positive bias, chain weights in [0.25, 0.75].
#[cfg(test)]
fn init(depth: usize, n_in: usize, rng: &mut StdRng) -> Vec<f64> {
    let st = n_in + 2;
    let mut th = vec![0.0; depth * st + 2];
    for l in 0..depth {
        let w = &mut th[l * st..(l + 1) * st];
        he_unit(w, n_in, &[], rng);
        w[0] = if l == 0 {
            0.0
        } else {
            rng.random_range(0.25..0.75)
        };
        w[st - 1] = 0.5;
    }
    th[depth * st] = 0.7;
    th
}

/// d = 1: the net is affine in x, ŷ = o(w·x + c) + e; the least-squares plane, exactly (o = 1,
/// e = 0).
fn linear_fit(data: &Data) -> Result<NnFit, NnError> {
    data.check_size(1)?;
    let n = data.n_in;
    let k = n + 1;
    // Normal equations of [x 1] on the standardised data, solved by SVD (lag columns are nearly
    // collinear; the pseudo-inverse copes).
    let mut g = nalgebra::DMatrix::<f64>::zeros(k, k);
    let mut b = nalgebra::DVector::<f64>::zeros(k);
    let mut row = vec![1.0; k];
    for (xr, &yr) in data.x.chunks_exact(n).zip(&data.y) {
        row[..n].copy_from_slice(xr);
        for i in 0..k {
            b[i] += row[i] * yr;
            for j in 0..=i {
                g[(i, j)] += row[i] * row[j];
            }
        }
    }
    for i in 0..k {
        for j in 0..i {
            g[(j, i)] = g[(i, j)];
        }
    }
    let beta = g
        .svd(true, true)
        .solve(&b, 1e-12 * data.rows() as f64)
        .map_err(|_| NnError::Diverged {
            depth: 1,
            ar_order: data.ar_order,
        })?;
    let mut theta = vec![0.0; n + 4];
    theta[1..=n].copy_from_slice(&beta.as_slice()[..n]);
    theta[n + 1] = beta[n];
    theta[n + 2] = 1.0;
    finish(
        data,
        Trained {
            net: data.net(1, theta),
            epochs: 0,
            converged: true,
        },
    )
}

/// p = 0, depth d ≥ 2 from the trained d − 1 net: `cfg.candidates` grown starts, trained in
/// parallel, the lowest training error kept (ties: the lower candidate index).
fn grow_p0(
    data: &Data,
    prev: &NnFit,
    d: usize,
    cfg: &SweepConfig,
    threads: usize,
) -> Result<NnFit, NnError> {
    data.check_size(d)?;
    let base = &prev.net;
    let runs = parallel(cfg.candidates.max(1), threads, |c| {
        let mut rng = StdRng::seed_from_u64(model_seed(cfg.seed, d, 0, c));
        let start = if c == 1 && base.depth >= 2 {
            let j = rng.random_range(0..base.depth - 1);
            base.grow_identity(j)
        } else {
            base.grow_bottom(&data.x, &data.y, &mut rng)
        };
        train(data, start, cfg, &mut rng)
    });
    best_of(data, runs)
}

/// AR order p ≥ 1, depth d: from the p = 0 net of depth d with zero lag weights, and, when given,
/// grown from the order-p net of depth d − 1 (`below`); the lower training error kept.
fn grow_ar(
    data: &Data,
    base: &NnFit,
    below: Option<&NnFit>,
    d: usize,
    cfg: &SweepConfig,
) -> Result<NnFit, NnError> {
    data.check_size(d)?;
    let q = data.ar_order;
    let mut runs = Vec::new();
    let mut rng = StdRng::seed_from_u64(model_seed(cfg.seed, d, q, 0));
    runs.push(train(data, base.net.with_inputs(data), cfg, &mut rng));
    if let Some(b) = below {
        let mut rng = StdRng::seed_from_u64(model_seed(cfg.seed, d, q, 1));
        let start = b.net.grow_bottom(&data.x, &data.y, &mut rng);
        runs.push(train(data, start, cfg, &mut rng));
    }
    best_of(data, runs)
}

/// The run with the lowest training MSE (first on ties), finished into a fit.
fn best_of(data: &Data, runs: Vec<Result<(Trained, f64), NnError>>) -> Result<NnFit, NnError> {
    let mut best: Option<(Trained, f64)> = None;
    let mut err = None;
    for r in runs {
        match r {
            Ok(t) if best.as_ref().is_none_or(|b| t.1 < b.1) => best = Some(t),
            Ok(_) => {}
            Err(e) => err = err.or(Some(e)),
        }
    }
    match (best, err) {
        (Some((t, _)), _) => finish(data, t),
        (None, Some(e)) => Err(e),
        (None, None) => unreachable!("at least one candidate"),
    }
}

/// A trained net and how its training ended.
struct Trained {
    net: Net,
    epochs: usize,
    converged: bool,
}

/// The fit record of a trained net: SSE in kPa², dead units.
fn finish(data: &Data, t: Trained) -> Result<NnFit, NnError> {
    let d = t.net.depth;
    let mut alive = vec![false; d - 1];
    let mse = t.net.evaluate(&data.x, &data.y, &mut alive);
    if !mse.is_finite() {
        return Err(NnError::Diverged {
            depth: d,
            ar_order: data.ar_order,
        });
    }
    Ok(NnFit {
        depth: d,
        ar_order: data.ar_order,
        n_params: n_params(d, data.n_in),
        sse: mse * data.rows() as f64 * data.y_std * data.y_std,
        n_rows: data.rows(),
        val_rmse: f64::NAN,
        epochs_run: t.epochs,
        converged: t.converged,
        dead_units: t.net.dead_units(&alive),
        net: t.net,
    })
}

/// Adam state; `t` counts steps since the last reset.
struct Adam {
    m: Vec<f64>,
    v: Vec<f64>,
    t: usize,
}

impl Adam {
    fn new(np: usize) -> Self {
        Adam {
            m: vec![0.0; np],
            v: vec![0.0; np],
            t: 0,
        }
    }

    fn reset(&mut self) {
        self.m.iter_mut().for_each(|x| *x = 0.0);
        self.v.iter_mut().for_each(|x| *x = 0.0);
        self.t = 0;
    }

    /// One Adam step on `theta` with the gradient `grad` scaled by `k` (the clip), the step size
    /// `lr` ramped up linearly over the first `warmup` steps.
    fn step(&mut self, theta: &mut [f64], grad: &[f64], k: f64, lr: f64, warmup: f64) {
        let (b1, b2, eps) = (0.9_f64, 0.999_f64, 1e-8);
        self.t += 1;
        let t = self.t;
        let step = lr * (t as f64 / warmup).min(1.0);
        let (c1, c2) = (1.0 - b1.powi(t as i32), 1.0 - b2.powi(t as i32));
        let moments = self.m.iter_mut().zip(self.v.iter_mut());
        for ((th, gi), (m, v)) in theta.iter_mut().zip(grad).zip(moments) {
            let g = gi * k;
            *m = b1 * *m + (1.0 - b1) * g;
            *v = b2 * *v + (1.0 - b2) * g * g;
            *th -= step * (*m / c1) / ((*v / c2).sqrt() + eps);
        }
    }
}

/// The optimiser's state across the epochs of [`train`].
struct Optimiser {
    adam: Adam,
    grad: Vec<f64>,
    lr: f64,
    warmup: f64,
    batch: usize,
    /// Running norm of the gradient, for the clip (0 before the first step).
    norm_ema: f64,
}

impl Optimiser {
    /// Back to a fresh start with half the step size (after a blow-up or a stall).
    fn halve(&mut self) {
        self.adam.reset();
        self.lr *= 0.5;
    }

    /// One epoch: minibatches of `seq` in order. `false` when a loss or gradient was not finite
    /// (the epoch stops there).
    fn epoch(&mut self, net: &mut Net, data: &Data, seq: &[usize]) -> bool {
        for chunk in seq.chunks(self.batch) {
            self.grad.iter_mut().for_each(|g| *g = 0.0);
            let loss = net.loss_grad(&data.x, &data.y, chunk, &mut self.grad);
            let norm = self.grad.iter().map(|g| g * g).sum::<f64>().sqrt();
            if !loss.is_finite() || !norm.is_finite() {
                return false;
            }
            // Clip to 4× the running norm.
            let bound = 4.0 * self.norm_ema;
            let k = if self.norm_ema > 0.0 && norm > bound {
                bound / norm
            } else {
                1.0
            };
            self.norm_ema = if self.norm_ema == 0.0 {
                norm
            } else {
                0.98 * self.norm_ema + 0.02 * norm * k
            };
            self.adam
                .step(&mut net.theta, &self.grad, k, self.lr, self.warmup);
            // a₁ has no predecessor: keep it at 0 (its gradient is 0, but keep it exact).
            net.theta[0] = 0.0;
        }
        true
    }
}

/// Restarts the dead hidden units (`alive[l]` false): new weights, and a kink through a random
/// row once the units below are in place; the function on the rows does not change.
fn revive_dead_units(
    net: &mut Net,
    alive: &[bool],
    adam: &mut Adam,
    data: &Data,
    rng: &mut StdRng,
) {
    let (d, n, st) = (net.depth, net.n_in, net.stride());
    let mut revived = false;
    for (l, _) in alive.iter().enumerate().filter(|(_, a)| !**a) {
        let block = &mut net.theta[l * st..(l + 1) * st];
        he_unit(block, n, &[], rng);
        net.theta[(l + 1) * st] = 0.0;
        revived = true;
    }
    if !revived {
        return;
    }
    let rows = data.rows();
    let (mut z, mut h) = (vec![0.0; d], vec![0.0; d]);
    for l in 0..d - 1 {
        if !alive[l] {
            let r = rng.random_range(0..rows);
            net.forward(&data.x[r * n..(r + 1) * n], &mut z, &mut h);
            net.theta[l * st + st - 1] -= z[l];
            for i in (l * st..(l + 1) * st).chain([(l + 1) * st]) {
                adam.m[i] = 0.0;
                adam.v[i] = 0.0;
            }
        }
    }
}

/// The training schedule across epochs (module docs): the best parameters and their MSE, the
/// MSE the next progress is measured from, the epochs since, and the step size's halvings.
struct Schedule {
    best: Vec<f64>,
    best_mse: f64,
    reference: f64,
    stall: usize,
    halvings: usize,
}

impl Schedule {
    /// After an epoch whose training MSE is `mse` (finite): keeps the best parameters; after
    /// `patience` epochs without progress by the tolerance, halves the step size and goes back to
    /// the best, or, once halved `lr_halvings` times, returns `true` (converged).
    fn after_epoch(
        &mut self,
        mse: f64,
        net: &mut Net,
        opt: &mut Optimiser,
        cfg: &SweepConfig,
    ) -> bool {
        if mse < self.best_mse {
            self.best_mse = mse;
            self.best.clone_from(&net.theta);
        }
        if self.best_mse < self.reference * (1.0 - cfg.tolerance) {
            self.reference = self.best_mse;
            self.stall = 0;
        } else {
            self.stall += 1;
        }
        if self.stall >= cfg.patience.max(1) {
            if self.halvings >= cfg.lr_halvings {
                return true;
            }
            self.halvings += 1;
            opt.halve();
            net.theta.clone_from(&self.best);
            self.stall = 0;
            self.reference = self.best_mse;
        }
        false
    }

    /// After an epoch that diverged: back to the best parameters with half the step size.
    fn diverged(&mut self, net: &mut Net, opt: &mut Optimiser) {
        net.theta.clone_from(&self.best);
        opt.norm_ema = 0.0;
        opt.halve();
        self.stall = 0;
    }
}

/// Trains `start` (see the module docs for the schedule) and returns the parameters with the
/// lowest training MSE seen, the start included, with that MSE.
fn train(
    data: &Data,
    start: Net,
    cfg: &SweepConfig,
    rng: &mut StdRng,
) -> Result<(Trained, f64), NnError> {
    let d = start.depth;
    let rows = data.rows();
    let mut net = start;
    let mut alive = vec![false; d - 1];
    let best_mse = net.evaluate(&data.x, &data.y, &mut alive);
    if !best_mse.is_finite() {
        return Err(NnError::Diverged {
            depth: d,
            ar_order: data.ar_order,
        });
    }
    let mut order: Vec<usize> = (0..rows).collect();
    let batch = cfg.batch_size.clamp(1, rows.max(1));
    let np = net.theta.len();
    let mut opt = Optimiser {
        adam: Adam::new(np),
        grad: vec![0.0; np],
        lr: cfg.learning_rate,
        warmup: rows.div_ceil(batch).clamp(1, 100) as f64,
        batch,
        norm_ema: 0.0,
    };
    let mut sched = Schedule {
        best: net.theta.clone(),
        best_mse,
        reference: best_mse,
        stall: 0,
        halvings: 0,
    };
    let (mut epochs, mut converged) = (0, false);
    // An epoch is a pass over the rows, or MIN_EPOCH_STEPS steps over repeated passes if that
    // is more (short logs would otherwise judge progress on a handful of steps).
    let passes = MIN_EPOCH_STEPS.div_ceil(rows.div_ceil(batch)).max(1);
    let mut seq = Vec::with_capacity(passes * rows);
    while epochs < cfg.epochs {
        epochs += 1;
        seq.clear();
        for _ in 0..passes {
            order.shuffle(rng);
            seq.extend_from_slice(&order);
        }
        let mse = if opt.epoch(&mut net, data, &seq) {
            net.evaluate(&data.x, &data.y, &mut alive)
        } else {
            f64::NAN
        };
        if !mse.is_finite() {
            sched.diverged(&mut net, &mut opt);
            continue;
        }
        revive_dead_units(&mut net, &alive, &mut opt.adam, data, rng);
        if sched.after_epoch(mse, &mut net, &mut opt, cfg) {
            converged = true;
            break;
        }
    }
    let (best, best_mse) = (sched.best, sched.best_mse);
    net.theta = best;
    Ok((
        Trained {
            net,
            epochs,
            converged,
        },
        best_mse,
    ))
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

    /// Every way a net is grown (a unit below the chain, an identity pass, zero lag weights for
    /// an AR order) and a dead-unit restart leaves its predictions unchanged, bit for bit.
    #[test]
    fn growing_preserves_the_function_exactly() {
        let (v, q, p) = smooth_plant(500);
        let inp = Inputs {
            v: &v,
            vdot: &q,
            ar_order: 0,
        };
        let data = Data::new(&inp, &p, 0).unwrap();
        let data3 = Data::new(&inp, &p, 3).unwrap();
        let mut rng = StdRng::seed_from_u64(7);
        let net = data.net(4, init(4, 2, &mut rng));
        let before = net.predict(&data.x);
        let mut alive = vec![false; 3];
        net.evaluate(&data.x, &data.y, &mut alive);
        assert!(alive.iter().all(|&a| a), "the test net has live units");
        for grown in [
            net.grow_bottom(&data.x, &data.y, &mut rng),
            net.grow_identity(0),
            net.grow_identity(2),
        ] {
            assert_eq!(grown.depth, 5);
            assert_eq!(grown.theta.len(), 5 * 4 + 2);
            let after = grown.predict(&data.x);
            assert!(before
                .iter()
                .zip(&after)
                .all(|(a, b)| a.to_bits() == b.to_bits()));
        }
        // The p = 0 net carried over to p = 3 predicts the same for rows t ≥ 3.
        let ar = net.with_inputs(&data3);
        assert_eq!(ar.theta.len(), 4 * 10 + 2);
        let after = ar.predict(&data3.x);
        assert!(before[3..]
            .iter()
            .zip(&after)
            .all(|(a, b)| a.to_bits() == b.to_bits()));
        // A unit inactive on every row does not count as reaching the output, nor do the units
        // below it; a zero weight into the next unit cuts a unit off too.
        let mut dead = net.clone();
        dead.theta[net.stride() + net.stride() - 1] = -1e6; // unit 2 off everywhere
        dead.evaluate(&data.x, &data.y, &mut alive);
        assert_eq!(alive, [true, false, true]);
        assert_eq!(dead.dead_units(&alive), 2);
        let mut cut = net.clone();
        cut.theta[3 * net.stride()] = 0.0; // a₄ = 0: unit 3 cut off
        cut.evaluate(&data.x, &data.y, &mut alive);
        assert_eq!(cut.dead_units(&alive), 3);
        assert_eq!(net.dead_units(&[true; 3]), 0);
    }

    /// Training never returns anything worse than its start, and restarts units that are dead.
    #[test]
    fn training_keeps_the_start_and_revives_dead_units() {
        let (v, q, p) = smooth_plant(2000);
        let inp = Inputs {
            v: &v,
            vdot: &q,
            ar_order: 0,
        };
        let data = Data::new(&inp, &p, 0).unwrap();
        let mut rng = StdRng::seed_from_u64(3);
        let mut net = data.net(3, init(3, 2, &mut rng));
        // Unit 1 dead on every row.
        net.theta[4 - 1] = -1e3;
        let mut alive = vec![false; 2];
        let start = net.evaluate(&data.x, &data.y, &mut alive);
        assert_eq!(alive, [false, true]);
        let cfg = SweepConfig {
            epochs: 3,
            ..SweepConfig::default()
        };
        let (t, mse) = train(&data, net, &cfg, &mut rng).unwrap();
        assert!(mse <= start);
        t.net.evaluate(&data.x, &data.y, &mut alive);
        assert!(alive[0], "the dead unit was restarted");
        // A zero learning rate changes nothing: the start comes back, bit for bit.
        let net = data.net(3, init(3, 2, &mut rng));
        let cfg0 = SweepConfig {
            learning_rate: 0.0,
            epochs: 5,
            ..SweepConfig::default()
        };
        let (t, mse) = train(&data, net.clone(), &cfg0, &mut rng).unwrap();
        assert_eq!(t.net.theta, net.theta);
        assert_eq!(mse, net.evaluate(&data.x, &data.y, &mut alive));
    }

    #[test]
    fn scalers_survive_extreme_units() {
        let xs: Vec<f64> = (0..1000).map(|i| (i % 37) as f64).collect();
        let (m, s) = mean_std(&xs);
        for k in [1e-200, 1e-9, 1.0, 1e200] {
            let scaled: Vec<f64> = xs.iter().map(|x| x * k).collect();
            let (mk, sk) = mean_std(&scaled);
            assert!((mk / (m * k) - 1.0).abs() < 1e-12, "{k}: {mk}");
            assert!((sk / (s * k) - 1.0).abs() < 1e-12, "{k}: {sk}");
        }
        assert_eq!(mean_std(&[5.0; 10]), (5.0, 1.0));
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
