//! The paper's §II–III on one chamber's data in one call: Table I (correlations and PCA), the
//! sweeps of every model family (Table II), selection by the joint cost (eq. 8), coefficient
//! statistics and term pruning (Table IV) of the selected polynomial.
//!
//! Every model is fitted on the training cycles and scored on both sets; selection uses the
//! training metrics (as the paper does) and the held-out metrics are reported next to them.

use crate::dataset::{Columns, Dataset};
use crate::linreg::CoefStat;
use crate::metrics::{self, CostWeights, Metrics};
use crate::poly::{self, PolyFit, PruneRow, Scaling, Xy};
use crate::select::{self, CvScore, Selection, Shape};
use crate::{exp, nn, polyar};
use serde::Serialize;
use std::collections::BTreeMap;
use std::time::Instant;

/// A model family of the paper's Table II.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Family {
    /// Σ αᵢ exp(βᵢ v) + γ v̇ + δ, k = 1..=10.
    Exp,
    /// ReLU networks, depth d, with optional AR inputs p.
    Nn,
    /// Σ αᵢⱼ vⁱ v̇ʲ, n, m = 1..=7.
    Poly,
    /// The polynomial plus linear AR input terms, p = 0..=5.
    PolyAr,
}

impl Family {
    /// All families in report order.
    pub const ALL: [Family; 4] = [Family::Exp, Family::Nn, Family::Poly, Family::PolyAr];

    /// The name used in JSON and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Family::Exp => "exp",
            Family::Nn => "nn",
            Family::Poly => "poly",
            Family::PolyAr => "poly-ar",
        }
    }
}

/// What to run.
#[derive(Debug, Clone)]
pub struct Options {
    /// Families to sweep (default: all).
    pub families: Vec<Family>,
    /// Joint-cost weights, eq. (8).
    pub weights: CostWeights,
    /// Highest n and m of the polynomial sweep.
    pub max_n: usize,
    /// See `max_n`.
    pub max_m: usize,
    /// Highest AR order of the poly-AR sweep.
    pub ar_max: usize,
    /// (n, m) of the poly-AR sweep; default: the polynomial family's selection, else (3, 2).
    pub ar_shape: Option<(usize, usize)>,
    /// Highest number of exponential terms.
    pub exp_k_max: usize,
    /// Settings of the neural sweep.
    pub nn: nn::SweepConfig,
    /// Highest AR order of the neural sweep.
    pub nn_ar_max: usize,
    /// Depth of the autoregressive networks (the paper's 8).
    pub nn_ar_depth: usize,
    /// Number of least significant terms tried in the pruning table.
    pub prune_k: usize,
    /// Told when the slow sweeps (exp, nn) start, change step and finish; `None`: silent.
    pub progress: Option<ProgressFn>,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            families: Family::ALL.to_vec(),
            weights: CostWeights::default(),
            max_n: 7,
            max_m: 7,
            ar_max: 5,
            ar_shape: None,
            exp_k_max: 10,
            nn: nn::SweepConfig::default(),
            nn_ar_max: 5,
            nn_ar_depth: 8,
            prune_k: 3,
            progress: None,
        }
    }
}

/// One fitted model's scores.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ModelRow {
    /// Family.
    pub family: Family,
    /// Highest power of v (poly, poly-ar).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub n: Option<usize>,
    /// Highest power of v̇ (poly, poly-ar).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub m: Option<usize>,
    /// Autoregressive order (poly-ar, nn).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub p: Option<usize>,
    /// Number of exponential terms (exp).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub k: Option<usize>,
    /// Network depth (nn).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub d: Option<usize>,
    /// Parameters ν.
    pub nu: usize,
    /// Training RMSE, kPa.
    pub rmse: f64,
    /// Training R²adj.
    pub r2_adj: f64,
    /// Training AICc.
    pub aicc: f64,
    /// Training BIC.
    pub bic: f64,
    /// Held-out RMSE, kPa.
    pub rmse_heldout: Option<f64>,
    /// Held-out R²adj.
    pub r2_adj_heldout: Option<f64>,
    /// Held-out AICc.
    pub aicc_heldout: Option<f64>,
    /// Held-out BIC.
    pub bic_heldout: Option<f64>,
    /// Joint cost J on the training metrics.
    pub cost: f64,
    /// Cross-validated RMSE on the training cycles, kPa (poly; see [`crate::select`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cv_rmse: Option<f64>,
    /// Its standard error across blocks, kPa (first-order: SE(ē) / (2√ē)).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cv_rmse_se: Option<f64>,
}

impl ModelRow {
    fn new(family: Family, train: &Metrics, held: Option<&Metrics>, w: &CostWeights) -> Self {
        ModelRow {
            family,
            n: None,
            m: None,
            p: None,
            k: None,
            d: None,
            nu: train.nu,
            rmse: train.rmse,
            r2_adj: train.r2_adj,
            aicc: train.aicc,
            bic: train.bic,
            rmse_heldout: held.map(|h| h.rmse),
            r2_adj_heldout: held.map(|h| h.r2_adj),
            aicc_heldout: held.map(|h| h.aicc),
            bic_heldout: held.map(|h| h.bic),
            cost: w.cost(train),
            cv_rmse: None,
            cv_rmse_se: None,
        }
    }

    /// The shape as text, e.g. "(3, 2)", "k = 3", "(p, d) = (5, 8)".
    pub fn shape(&self) -> String {
        match self.family {
            Family::Exp => format!("{}", self.k.unwrap_or(0)),
            Family::Nn => format!("({}, {})", self.p.unwrap_or(0), self.d.unwrap_or(0)),
            Family::Poly => format!("({}, {})", self.n.unwrap_or(0), self.m.unwrap_or(0)),
            Family::PolyAr => format!(
                "({}, {}, {})",
                self.p.unwrap_or(0),
                self.n.unwrap_or(0),
                self.m.unwrap_or(0)
            ),
        }
    }
}

/// A model that could not be fitted, and why.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Failed {
    /// Family.
    pub family: Family,
    /// Shape as text.
    pub shape: String,
    /// The error, one sentence.
    pub error: String,
}

/// Table I: correlations of P with v, v̇, v̈ and the PCA of the normalised [v, v̇, v̈, P].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table1 {
    /// corr(P, v); `None` when a column is constant.
    pub corr_v: Option<f64>,
    /// corr(P, v̇).
    pub corr_vdot: Option<f64>,
    /// corr(P, v̈).
    pub corr_vddot: Option<f64>,
    /// Eigenvectors: `vectors[row][pc]`, rows v, v̇, v̈, P; columns PC1..PC4 by decreasing
    /// eigenvalue, each signed so its P loading is ≥ 0.
    pub vectors: Option<[[f64; 4]; 4]>,
    /// λ / tr Λ, decreasing.
    pub lambda_norm: Option<[f64; 4]>,
}

/// Table I for these columns (see [`Table1`]). PCA of X' = (X − μ)/σ: eigen-decomposition of
/// (1/(N−1)) X'ᵀX', the correlation matrix; λ_norm = λ / tr Λ.
pub fn table1(c: &Columns) -> Table1 {
    let cols = [&c.v, &c.vdot, &c.vddot, &c.p];
    let n = c.len() as f64;
    let mean: Vec<f64> = cols.iter().map(|x| x.iter().sum::<f64>() / n).collect();
    let sd: Vec<f64> = cols
        .iter()
        .zip(&mean)
        .map(|(x, m)| (x.iter().map(|a| (a - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt())
        .collect();
    let corr = |a: usize, b: usize| -> Option<f64> {
        if !(sd[a] > 0.0 && sd[b] > 0.0) || c.len() < 3 {
            return None;
        }
        let s: f64 = cols[a]
            .iter()
            .zip(cols[b])
            .map(|(x, y)| (x - mean[a]) * (y - mean[b]))
            .sum();
        Some(s / (n - 1.0) / (sd[a] * sd[b]))
    };
    let mut r = nalgebra::Matrix4::<f64>::identity();
    let mut ok = true;
    for a in 0..4 {
        for b in 0..4 {
            if a != b {
                match corr(a, b) {
                    Some(x) => r[(a, b)] = x,
                    None => ok = false,
                }
            }
        }
    }
    let (vectors, lambda_norm) = if ok {
        let e = nalgebra::SymmetricEigen::new(r);
        let mut order = [0usize, 1, 2, 3];
        order.sort_by(|&a, &b| e.eigenvalues[b].total_cmp(&e.eigenvalues[a]));
        let tr: f64 = e.eigenvalues.iter().sum();
        let mut vec = [[0.0; 4]; 4];
        let mut lam = [0.0; 4];
        for (pc, &k) in order.iter().enumerate() {
            let sign = if e.eigenvectors[(3, k)] < 0.0 {
                -1.0
            } else {
                1.0
            };
            for (row, v) in vec.iter_mut().enumerate() {
                v[pc] = sign * e.eigenvectors[(row, k)];
            }
            lam[pc] = e.eigenvalues[k] / tr;
        }
        (Some(vec), Some(lam))
    } else {
        (None, None)
    };
    Table1 {
        corr_v: corr(3, 0),
        corr_vdot: corr(3, 1),
        corr_vddot: corr(3, 2),
        vectors,
        lambda_norm,
    }
}

/// One coefficient of the selected polynomial in the paper's units.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Coefficient {
    /// Term, e.g. "v^2 vdot".
    pub term: String,
    /// Estimate, SE, t, p.
    #[serde(flatten)]
    pub stat: CoefStat,
}

/// Everything identified for one chamber.
#[derive(Debug, Clone, Serialize)]
pub struct ChamberReport {
    /// Chamber index.
    pub chamber: u8,
    /// Samples in all.
    pub samples: usize,
    /// Training samples.
    pub train_samples: usize,
    /// Held-out samples.
    pub heldout_samples: usize,
    /// Cycles found.
    pub cycles: usize,
    /// The held-out rule, in words.
    pub split: String,
    /// Where v̇ came from, in words.
    pub flow: String,
    /// Table I on all samples.
    pub table1: Table1,
    /// Every fitted model.
    pub models: Vec<ModelRow>,
    /// Models that could not be fitted.
    pub failed: Vec<Failed>,
    /// Each family's choice: the polynomial's by [`crate::select`] (the simplest shape within one
    /// standard error of the best cross-validated error), the others' by the lowest joint cost.
    pub best: Vec<ModelRow>,
    /// The lowest-cost model among the families' choices (`best`).
    pub selected: Option<ModelRow>,
    /// How the polynomial's shape was chosen, with the AICc and joint-cost picks beside it.
    pub poly_selection: Option<Selection>,
    /// The selected polynomial (n, m) refitted by QR, with statistics.
    #[serde(skip)]
    pub poly_fit: Option<PolyFit>,
    /// Its coefficients in the paper's units.
    pub poly_coefficients: Vec<Coefficient>,
    /// Table IV: refits without the least significant terms.
    pub pruning: Vec<PruneRow>,
    /// The best poly-AR fit (for export).
    #[serde(skip)]
    pub poly_ar_fit: Option<polyar::PolyArFit>,
    /// Notes for the reader (e.g. one-step = free-run for input-AR models).
    pub notes: Vec<String>,
    /// Seconds spent fitting each family's sweep.
    pub timing_s: BTreeMap<&'static str, f64>,
}

/// A model row tagged with its chamber (the document's `models` and `selected`).
#[derive(Debug, Clone, Serialize)]
pub struct Tagged<'a> {
    /// Chamber index.
    pub chamber: u8,
    /// The row.
    #[serde(flatten)]
    pub row: &'a ModelRow,
}

/// The whole identification of a log as one document (`vfp identify --json`, the Python
/// package's `identify`): the file, the weights, the first chamber's selection, every chamber's
/// models tagged with the chamber, the sweep times summed over chambers (s) and the per-chamber
/// reports.
#[derive(Debug, Clone, Serialize)]
pub struct Document<'a> {
    /// The log as reports name it.
    pub file: String,
    /// Joint-cost weights, eq. (8).
    pub weights: CostWeights,
    /// The first chamber's lowest-cost model.
    pub selected: Option<Tagged<'a>>,
    /// Every fitted model of every chamber.
    pub models: Vec<Tagged<'a>>,
    /// Seconds spent in each family's sweep, summed over chambers.
    pub timing_s: BTreeMap<&'static str, f64>,
    /// The per-chamber reports.
    pub chambers: &'a [ChamberReport],
}

impl<'a> Document<'a> {
    /// The document of `reports` (in chamber order) identified from `file` with `weights`.
    pub fn new(file: String, weights: CostWeights, reports: &'a [ChamberReport]) -> Self {
        let mut timing_s: BTreeMap<&'static str, f64> = BTreeMap::new();
        for r in reports {
            for (k, v) in &r.timing_s {
                *timing_s.entry(k).or_default() += v;
            }
        }
        let tag = |r: &'a ChamberReport, row: &'a ModelRow| Tagged {
            chamber: r.chamber,
            row,
        };
        Document {
            file,
            weights,
            selected: reports
                .first()
                .and_then(|r| r.selected.as_ref().map(|row| tag(r, row))),
            models: reports
                .iter()
                .flat_map(|r| r.models.iter().map(move |row| tag(r, row)))
                .collect(),
            timing_s,
            chambers: reports,
        }
    }
}

/// What a slow sweep reports to [`Options::progress`] (the tool shows it as a spinner).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Progress<'a> {
    /// `family`'s sweep is doing `what`.
    Working {
        /// The family.
        family: Family,
        /// What it does now.
        what: &'a str,
    },
    /// `family`'s sweep has finished.
    Done {
        /// The family.
        family: Family,
    },
}

/// Receives [`Progress`] reports.
pub type ProgressFn = fn(Progress<'_>);

fn tell(opt: &Options, p: Progress<'_>) {
    if let Some(f) = opt.progress {
        f(p);
    }
}

/// Fewest samples on each side of the training / held-out split `identify` accepts (as the
/// residual loop, [`crate::residual::Series::new`]).
pub const MIN_SAMPLES: usize = 100;

/// Why a dataset cannot be identified.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum IdentifyError {
    /// Too little data on one side of the split.
    #[error("too few samples: {train} training and {heldout} held-out, need at least {needed} of each (record more cycles, or fit without a held-out set with --holdout-every 0)")]
    TooFewSamples {
        /// Training samples.
        train: usize,
        /// Held-out samples.
        heldout: usize,
        /// Minimum of each.
        needed: usize,
    },
    /// Every model failed.
    #[error("no model could be fitted: {0}")]
    NothingFitted(String),
}

/// Refuses a dataset too short for its split: fewer than [`MIN_SAMPLES`] training samples, or a
/// held-out set (when one was asked for) of fewer than [`MIN_SAMPLES`].
pub fn check_split(ds: &Dataset) -> Result<(), IdentifyError> {
    let held = ds.heldout.iter().filter(|&&h| h).count();
    let train = ds.len() - held;
    let wants_held = !matches!(ds.split, crate::dataset::Split::None);
    if train < MIN_SAMPLES || (wants_held && held < MIN_SAMPLES) {
        return Err(IdentifyError::TooFewSamples {
            train,
            heldout: held,
            needed: MIN_SAMPLES,
        });
    }
    Ok(())
}

/// `Err` naming every failure when `rep` holds no fitted model.
pub fn check_fitted(rep: &ChamberReport) -> Result<(), IdentifyError> {
    if !rep.models.is_empty() {
        return Ok(());
    }
    let why: Vec<String> = rep
        .failed
        .iter()
        .map(|f| format!("{} {}: {}", f.family.name(), f.shape, f.error))
        .collect();
    Err(IdentifyError::NothingFitted(if why.is_empty() {
        "no family was run".into()
    } else {
        why.join("; ")
    }))
}

/// Runs the selected families on one chamber's dataset.
pub fn identify(ds: &Dataset, opt: &Options) -> ChamberReport {
    let w = opt.weights;
    let (train, held) = (ds.train(), ds.heldout());
    let all = ds.all();
    let mut rep = ChamberReport {
        chamber: ds.chamber,
        samples: ds.len(),
        train_samples: train.len(),
        heldout_samples: held.len(),
        cycles: ds.n_cycles,
        split: ds.split_description(),
        flow: match ds.flow_source {
            crate::dataset::FlowSource::Logged => "logged (flow_mm3_s column)".into(),
            crate::dataset::FlowSource::Derived { half_width } => format!(
                "derived from volume: local quadratic least squares over {} samples (Savitzky-Golay)",
                2 * half_width + 1
            ),
        },
        table1: table1(&all),
        models: Vec::new(),
        failed: Vec::new(),
        best: Vec::new(),
        selected: None,
        poly_selection: None,
        poly_fit: None,
        poly_coefficients: Vec::new(),
        pruning: Vec::new(),
        poly_ar_fit: None,
        notes: Vec::new(),
        timing_s: BTreeMap::new(),
    };
    let held_xy = (!held.is_empty()).then(|| Xy::from(&held));
    let scaling = Scaling::from_data(&all.v, &all.vdot);
    let fail =
        |rep: &mut ChamberReport, family: Family, shape: String, e: &dyn std::fmt::Display| {
            rep.failed.push(Failed {
                family,
                shape,
                error: e.to_string(),
            });
        };
    let score = |family: Family, yhat_train: &[f64], yhat_held: Option<&[f64]>, nu: usize| {
        let t = metrics::compute(&train.p, yhat_train, nu)?;
        let h = match yhat_held {
            Some(y) if !held.is_empty() => metrics::compute(&held.p, y, nu).ok(),
            _ => None,
        };
        Ok::<_, metrics::MetricsError>(ModelRow::new(family, &t, h.as_ref(), &w))
    };

    let mut poly_choice: Option<(usize, usize)> = None;
    for family in Family::ALL.into_iter().filter(|f| opt.families.contains(f)) {
        let t0 = Instant::now();
        match family {
            Family::Exp => {
                tell(
                    opt,
                    Progress::Working {
                        family,
                        what: "fitting",
                    },
                );
                let fits = exp::sweep(&train.v, &train.vdot, &train.p, opt.exp_k_max);
                tell(opt, Progress::Done { family });
                for (i, r) in fits.into_iter().enumerate() {
                    match r {
                        Ok(f) => {
                            let yt: Vec<f64> = train
                                .v
                                .iter()
                                .zip(&train.vdot)
                                .map(|(&v, &q)| f.predict(v, q))
                                .collect();
                            let yh: Vec<f64> = held
                                .v
                                .iter()
                                .zip(&held.vdot)
                                .map(|(&v, &q)| f.predict(v, q))
                                .collect();
                            match score(family, &yt, Some(&yh), 2 * f.k + 2) {
                                Ok(mut row) => {
                                    row.k = Some(f.k);
                                    rep.models.push(row);
                                }
                                Err(e) => fail(&mut rep, family, format!("k = {}", f.k), &e),
                            }
                        }
                        Err(e) => fail(&mut rep, family, format!("k = {}", i + 1), &e),
                    }
                }
            }
            Family::Nn => {
                // As in the paper: depths d = 1..=15 without AR inputs, then AR orders
                // p = 1..=nn_ar_max at depth `nn_ar_depth` (Table III).
                let mut plain = opt.nn.clone();
                plain.ar_orders = vec![0];
                let mut ar = opt.nn.clone();
                ar.depths = vec![opt.nn_ar_depth];
                ar.ar_orders = (1..=opt.nn_ar_max).collect();
                let it = nn::Inputs {
                    v: &train.v,
                    vdot: &train.vdot,
                    ar_order: 0,
                };
                let ih = nn::Inputs {
                    v: &held.v,
                    vdot: &held.vdot,
                    ar_order: 0,
                };
                let mut runs = vec![(plain, "depths 1..=15")];
                if opt.nn_ar_max > 0 {
                    runs.push((ar, "AR orders"));
                }
                for (cfg, what) in runs {
                    tell(
                        opt,
                        Progress::Working {
                            family,
                            what: &format!("training {what}"),
                        },
                    );
                    for r in nn::sweep(&it, &train.p, &cfg).results {
                        let f = match r {
                            Ok(f) => f,
                            Err(e) => {
                                fail(&mut rep, family, "(p, d)".into(), &e);
                                continue;
                            }
                        };
                        // The first p samples have no lagged inputs: score the rest.
                        let p = f.ar_order;
                        let yt = f.predict(&it);
                        let yh = f.predict(&ih);
                        let r = metrics::compute(
                            &train.p[p.min(train.len())..],
                            &yt[p.min(yt.len())..],
                            f.n_params,
                        )
                        .map(|t| {
                            let h = (held.len() > p + f.n_params + 1)
                                .then(|| {
                                    metrics::compute(
                                        &held.p[p..],
                                        &yh[p.min(yh.len())..],
                                        f.n_params,
                                    )
                                    .ok()
                                })
                                .flatten();
                            ModelRow::new(family, &t, h.as_ref(), &w)
                        });
                        match r {
                            Ok(mut row) => {
                                row.p = Some(f.ar_order);
                                row.d = Some(f.depth);
                                rep.models.push(row);
                            }
                            Err(e) => fail(
                                &mut rep,
                                family,
                                format!("(p, d) = ({}, {})", f.ar_order, f.depth),
                                &e,
                            ),
                        }
                    }
                }
                tell(opt, Progress::Done { family });
            }
            Family::Poly => match &scaling {
                Err(e) => fail(&mut rep, family, "all".into(), e),
                Ok(sc) => match poly::sweep(Xy::from(&train), held_xy, sc, opt.max_n, opt.max_m) {
                    Err(e) => fail(&mut rep, family, "all".into(), &e),
                    Ok(entries) => {
                        let mut idx = 0;
                        for n in 1..=opt.max_n {
                            for m in 1..=opt.max_m {
                                match &entries[idx] {
                                    Ok(e) => {
                                        let mut row =
                                            ModelRow::new(family, &e.train, e.heldout.as_ref(), &w);
                                        row.n = Some(n);
                                        row.m = Some(m);
                                        rep.models.push(row);
                                    }
                                    Err(e) => fail(&mut rep, family, format!("({n}, {m})"), e),
                                }
                                idx += 1;
                            }
                        }
                        poly_choice = choose_poly(&mut rep, ds, sc, opt);
                    }
                },
            },
            Family::PolyAr => {
                let (n, m) = opt.ar_shape.or(poly_choice).unwrap_or((3, 2));
                match scaling
                    .as_ref()
                    .map_err(|e| e.clone())
                    .and_then(|sc| polyar::sweep(ds, n, m, opt.ar_max, sc))
                {
                    Err(e) => fail(&mut rep, family, format!("({n}, {m})"), &e),
                    Ok(results) => {
                        let mut fits = Vec::new();
                        for (p, r) in results.into_iter().enumerate() {
                            match r {
                                Ok(f) => fits.push(f),
                                Err(e) => fail(&mut rep, family, format!("({p}, {n}, {m})"), &e),
                            }
                        }
                        for f in &fits {
                            let mut row = ModelRow::new(family, &f.train, f.heldout.as_ref(), &w);
                            row.n = Some(n);
                            row.m = Some(m);
                            row.p = Some(f.p);
                            rep.models.push(row);
                        }
                        let best = fits
                            .iter()
                            .min_by(|a, b| w.cost(&a.train).total_cmp(&w.cost(&b.train)));
                        rep.poly_ar_fit = best.cloned();
                        rep.notes.push(format!(
                            "poly-ar: the AR terms are past inputs v(t-k), v̇(t-k), never past pressure, so one-step-ahead and \
                             free-run (simulation) errors are identical; all orders use the same {} training rows \
                             (samples with {} predecessors)",
                            fits.first().map_or(0, |f| f.train.n),
                            opt.ar_max
                        ));
                    }
                }
            }
        }
        rep.timing_s
            .insert(family.name(), t0.elapsed().as_secs_f64());
    }

    // Statistics and pruning of the selected polynomial (a QR refit, residuals computed directly).
    if let Some((n, m)) = poly_choice {
        match poly::fit(Xy::from(&train), n, m, scaling.as_ref().ok().copied()) {
            Ok(f) => {
                rep.poly_coefficients = f
                    .term_names()
                    .into_iter()
                    .zip(&f.raw)
                    .map(|(term, stat)| Coefficient { term, stat: *stat })
                    .collect();
                rep.poly_fit = Some(f);
            }
            Err(e) => fail(&mut rep, Family::Poly, format!("({n}, {m}) refit"), &e),
        }
        if opt.prune_k > 0 {
            match poly::prune(Xy::from(&train), held_xy, n, m, opt.prune_k) {
                Ok(rows) => rep.pruning = rows,
                Err(e) => fail(&mut rep, Family::Poly, format!("({n}, {m}) pruning"), &e),
            }
        }
    }

    rep.best = Family::ALL
        .iter()
        .filter_map(|&f| match (f, poly_choice) {
            (Family::Poly, Some((n, m))) => rep
                .models
                .iter()
                .find(|r| r.family == f && r.n == Some(n) && r.m == Some(m))
                .cloned(),
            _ => best_of(&rep.models, f).cloned(),
        })
        .collect();
    rep.selected = rep
        .best
        .iter()
        .min_by(|a, b| a.cost.total_cmp(&b.cost))
        .cloned();
    rep
}

/// Cross-validates the polynomial sweep on the training cycles, notes each row's cross-validated
/// RMSE, records the [`Selection`] and returns the chosen shape. When the cross-validation cannot
/// run (fewer than two blocks), the lowest joint cost chooses, and a note says so.
fn choose_poly(
    rep: &mut ChamberReport,
    ds: &Dataset,
    sc: &Scaling,
    opt: &Options,
) -> Option<(usize, usize)> {
    let rows = || rep.models.iter().filter(|r| r.family == Family::Poly);
    let shape_of = |r: &ModelRow| Some(Shape::new(r.n?, r.m?));
    let aicc = rows()
        .min_by(|a, b| a.aicc.total_cmp(&b.aicc))
        .and_then(shape_of);
    let cost = rows()
        .min_by(|a, b| a.cost.total_cmp(&b.cost))
        .and_then(shape_of);
    let fallback = cost.map(|s| (s.n, s.m));
    let (blocks, scores) = match select::cross_validate(ds, sc, opt.max_n, opt.max_m) {
        Ok(x) => x,
        Err(e) => {
            rep.notes.push(format!(
                "poly: no cross-validation ({e}); the lowest joint cost chose the shape"
            ));
            return fallback;
        }
    };
    let ok: Vec<CvScore> = scores.into_iter().flatten().collect();
    for r in rep.models.iter_mut().filter(|r| r.family == Family::Poly) {
        if let Some(s) = ok.iter().find(|s| Some(s.n) == r.n && Some(s.m) == r.m) {
            r.cv_rmse = Some(s.rmse());
            r.cv_rmse_se = Some(s.se / (2.0 * s.rmse()).max(f64::MIN_POSITIVE));
        }
    }
    match select::selection(&blocks, &ok, aicc, cost, opt.weights) {
        Some(sel) => {
            let pick = (sel.selected.n, sel.selected.m);
            rep.poly_selection = Some(sel);
            Some(pick)
        }
        None => {
            rep.notes.push(
                "poly: no shape could be cross-validated; the lowest joint cost chose the shape"
                    .into(),
            );
            fallback
        }
    }
}

fn best_of(rows: &[ModelRow], family: Family) -> Option<&ModelRow> {
    rows.iter()
        .filter(|r| r.family == family)
        .min_by(|a, b| a.cost.total_cmp(&b.cost))
}
