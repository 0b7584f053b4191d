//! The paper's §II–III on one chamber's data in one call: Table I (correlations and PCA), the
//! sweeps of every model family (Table II), selection by the joint cost (eq. 8), coefficient
//! statistics and term pruning (Table IV) of the selected polynomial.
//!
//! Every model is fitted on the training cycles and scored on both sets; selection uses the
//! training metrics (as the paper does) and the held-out metrics are reported next to them.

mod exp_family;
mod nn_family;
mod poly_ar_family;
mod poly_family;

use crate::dataset::{Columns, Dataset};
use crate::linreg::CoefStat;
use crate::metrics::{self, CostWeights, Metrics};
use crate::poly::{self, PolyFit, PruneRow, Scaling, Xy};
use crate::select::Selection;
use crate::{nn, polyar};
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

/// Table I for the columns v, v̇, v̈ and P, of one length (see [`Table1`]). PCA of
/// X' = (X − μ)/σ: eigen-decomposition of (1/(N−1)) X'ᵀX', the correlation matrix;
/// λ_norm = λ / tr Λ.
pub fn table1(cols: [&[f64]; 4]) -> Table1 {
    let len = cols[3].len();
    let n = len as f64;
    let mean: Vec<f64> = cols.iter().map(|x| x.iter().sum::<f64>() / n).collect();
    let sd: Vec<f64> = cols
        .iter()
        .zip(&mean)
        .map(|(x, m)| (x.iter().map(|a| (a - m).powi(2)).sum::<f64>() / (n - 1.0)).sqrt())
        .collect();
    let corr = |a: usize, b: usize| -> Option<f64> {
        if !(sd[a] > 0.0 && sd[b] > 0.0) || len < 3 {
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
    // Symmetric, and each product (x − μ_a)(y − μ_b) the same either way: six pairs.
    for a in 0..4 {
        for b in a + 1..4 {
            match corr(a, b) {
                Some(x) => (r[(a, b)], r[(b, a)]) = (x, x),
                None => ok = false,
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
    /// The units of every number: the format's ([`crate::columns::FORMAT_UNITS`]), whatever the
    /// log was read in.
    pub units: crate::columns::FormatUnits,
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
            units: crate::columns::FORMAT_UNITS,
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

/// A model family as [`identify`] runs it: its sweep over one chamber's data, with its rows,
/// failures and notes added to the report. One file per family (`identify/<family>.rs`), listed
/// once in [`FAMILIES`]; the models' own math lives in [`crate::exp`], [`crate::nn`],
/// [`crate::poly`] and [`crate::polyar`].
pub trait ModelFamily: Sync {
    /// Which family (its name in reports and on the command line).
    fn family(&self) -> Family;
    /// Sweeps the family on `cx`'s data, adding to `cx.rep`.
    fn sweep(&self, cx: &mut Sweep<'_>);
}

/// The families in the order [`identify`] runs them (poly-ar after poly, whose selected shape it
/// takes).
pub const FAMILIES: [&dyn ModelFamily; 4] = [
    &exp_family::ExpFamily,
    &nn_family::NnFamily,
    &poly_family::PolyFamily,
    &poly_ar_family::PolyArFamily,
];

/// What a family's sweep works on (one chamber's data, split, and the options) and the report
/// it adds to.
pub struct Sweep<'a> {
    /// The chamber's dataset.
    pub ds: &'a Dataset,
    /// The options.
    pub opt: &'a Options,
    /// Its training rows.
    pub train: Columns,
    /// Its held-out rows (empty without a split).
    pub held: Columns,
    /// The polynomial scaling of all its rows.
    pub scaling: Result<Scaling, poly::PolyError>,
    /// The report so far.
    pub rep: ChamberReport,
    /// The polynomial shape the poly family selected, once it has run.
    pub poly_choice: Option<(usize, usize)>,
    /// The moments the poly family's sweep was solved from, once it has run.
    pub poly_moments: Option<poly::SweepMoments>,
}

impl Sweep<'_> {
    /// The held-out rows as a fit's input, if there are any.
    pub fn held_xy(&self) -> Option<Xy<'_>> {
        (!self.held.is_empty()).then(|| Xy::from(&self.held))
    }

    /// Records that `family`'s model `shape` could not be fitted.
    pub fn fail(&mut self, family: Family, shape: String, e: &dyn std::fmt::Display) {
        self.rep.failed.push(Failed {
            family,
            shape,
            error: e.to_string(),
        });
    }

    /// A row for a model with `nu` parameters from its predictions on the training and (when
    /// given and the set is not empty) held-out rows.
    pub fn score(
        &self,
        family: Family,
        yhat_train: &[f64],
        yhat_held: Option<&[f64]>,
        nu: usize,
    ) -> Result<ModelRow, metrics::MetricsError> {
        let t = metrics::compute(&self.train.p, yhat_train, nu)?;
        let h = match yhat_held {
            Some(y) if !self.held.is_empty() => metrics::compute(&self.held.p, y, nu).ok(),
            _ => None,
        };
        Ok(ModelRow::new(family, &t, h.as_ref(), &self.opt.weights))
    }

    /// Tells [`Options::progress`].
    pub fn tell(&self, p: Progress<'_>) {
        tell(self.opt, p);
    }
}

/// Runs the selected families on one chamber's dataset.
pub fn identify(ds: &Dataset, opt: &Options) -> ChamberReport {
    let (train, held) = (ds.train(), ds.heldout());
    let rep = ChamberReport {
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
        table1: table1([&ds.v, &ds.vdot, &ds.vddot, &ds.p]),
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
    let mut cx = Sweep {
        ds,
        opt,
        scaling: Scaling::from_data(&ds.v, &ds.vdot),
        train,
        held,
        rep,
        poly_choice: None,
        poly_moments: None,
    };
    for fam in FAMILIES
        .iter()
        .filter(|f| opt.families.contains(&f.family()))
    {
        let t0 = Instant::now();
        fam.sweep(&mut cx);
        cx.rep
            .timing_s
            .insert(fam.family().name(), t0.elapsed().as_secs_f64());
    }
    poly_family::statistics(&mut cx);
    let (mut rep, poly_choice) = (cx.rep, cx.poly_choice);
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

fn best_of(rows: &[ModelRow], family: Family) -> Option<&ModelRow> {
    rows.iter()
        .filter(|r| r.family == family)
        .min_by(|a, b| a.cost.total_cmp(&b.cost))
}
