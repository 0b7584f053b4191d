//! The residual loop (`vfp diagnose`): find what a model lacks, add it, and report the error
//! before and after.
//!
//! 1. Fit the baseline polynomial `P = Σ α_ij vⁱ v̇ʲ` (paper Table II; a Chebyshev basis of the same
//!    span, see `basis`) on training cycles; compute its residual on held-out cycles.
//! 2. Look at the residual ([`analysis`]): autocorrelation with its white-noise band and Ljung–Box
//!    test, cross-correlation with v, v̇, v̈ and time, residual against v and v̇ split by direction,
//!    Welch spectrum.
//! 3. Hold a library of candidate effects ([`effects`]), each a physical augmentation with a name, a
//!    one-sentence story and parameters in physical units; nonlinear parameters found by search.
//! 4. Forward selection ([`search`]): add the candidate that most improves held-out RMSE, keep it
//!    only if an autocorrelation-corrected nested F-test says so *and* the held-out gain clears a
//!    stated threshold *and* its fit is physically possible (inertance ≥ 0, hysteresis gap ≥ 0;
//!    searched lags, delays, widths, air volume and leak are positive by construction); refit;
//!    repeat until nothing passes. A candidate that passes the test with an impossible fit is
//!    reported among the remaining structure (`unphysical_fit`), not added.
//! 5. Whatever structure the final residual still has (Ljung–Box rejects whiteness) is reported by
//!    its signature — lag, input followed, frequency, direction — not forced onto a name.
//!
//! Errors are free-run (simulation) errors from the inputs v, v̇, v̈ and time, except that the leak
//! and air-compliance effects schedule on the *measured* pressure; a report that contains
//! them says so.

// Index loops over several aligned signals read more plainly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

pub mod alternatives;
pub mod analysis;
mod basis;
pub mod effects;
pub(crate) mod inframe;
pub mod interval;
mod lsq;
pub mod search;
pub(crate) mod signal;
pub mod validate;

use serde::Serialize;

use crate::dataset::Dataset;
use crate::progress::{tell, Progress};

pub use analysis::{ResidualAnalysis, Signature};
pub use basis::PolyBasis;
pub use effects::{Effect, EffectKind, EffectModel, REGISTRY};
pub use search::{param, NestedTest, Param, Stage};

/// The kind of rig a log comes from, for the names of the effects the loop reports (issue 35):
/// an effect whose story is a mechanism of a syringe pump (lead-screw ripple, backlash, the
/// syringe's delivery lag) carries that name only on a syringe rig; elsewhere a neutral name that
/// claims no more than the signal ([`EffectModel::generic`]). Only names and stories change, never
/// a model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Rig {
    /// This project's syringe rig (its firmware's logs, host-sim's, or said with `--rig`).
    #[default]
    Syringe,
    /// Any other source: a ventilator, a lung simulator, a lab's own file.
    Generic,
}

impl Rig {
    /// The rig a log's header names: [`Rig::Syringe`] for the logs this project writes
    /// (`# source=vfp record …` from a board, `# source=host-sim …` from the simulated rig),
    /// [`Rig::Generic`] for any other.
    pub fn of_log(comments: &[String]) -> Rig {
        match crate::log::metadata(comments, "source") {
            Some(s) if s.starts_with("vfp record") || s.starts_with("host-sim") => Rig::Syringe,
            _ => Rig::Generic,
        }
    }

    /// `syringe` or `generic`.
    pub fn name(self) -> &'static str {
        match self {
            Rig::Syringe => "syringe",
            Rig::Generic => "generic",
        }
    }

    /// The name an effect called `name` is reported under on this rig.
    pub fn effect_name(self, name: &'static str) -> &'static str {
        match (self, EffectKind::named(name).and_then(|k| k.generic())) {
            (Rig::Generic, Some((neutral, _))) => neutral,
            _ => name,
        }
    }
}

impl std::str::FromStr for Rig {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "syringe" => Ok(Rig::Syringe),
            "generic" => Ok(Rig::Generic),
            _ => Err(format!("unknown rig `{s}` (syringe or generic)")),
        }
    }
}

/// Bad input to the loop; each says what to do.
#[derive(Debug, thiserror::Error)]
pub enum DiagnoseError {
    /// The signal slices differ in length.
    #[error("signals differ in length ({what} has {got} samples, time has {expected})")]
    LengthMismatch {
        /// Which signal.
        what: &'static str,
        /// Its length.
        got: usize,
        /// Length of the time column.
        expected: usize,
    },
    /// A value is NaN or infinite.
    #[error("{what} at sample {index} is not a finite number")]
    NonFinite {
        /// Which signal.
        what: &'static str,
        /// Sample index.
        index: usize,
    },
    /// Time does not increase.
    #[error("time does not increase at sample {index}")]
    TimeNotIncreasing {
        /// Sample index.
        index: usize,
    },
    /// Too little data on one side of the split.
    #[error("too few samples: {train} training and {heldout} held-out, need at least {needed} of each (record more cycles or hold out fewer)")]
    TooFewSamples {
        /// Training samples.
        train: usize,
        /// Held-out samples.
        heldout: usize,
        /// Minimum of each.
        needed: usize,
    },
    /// Two candidates share a name.
    #[error("two candidate effects are named `{0}`; each candidate needs its own name")]
    DuplicateEffect(&'static str),
    /// The baseline cannot be fitted (e.g. constant volume or flow).
    #[error("the baseline polynomial cannot be fitted: {0}")]
    Degenerate(String),
}

/// One chamber's data with its training / held-out split.
#[derive(Clone, Debug)]
pub struct Series {
    /// Time (s), strictly increasing.
    pub t: Vec<f64>,
    /// Volume (mm³).
    pub v: Vec<f64>,
    /// Flow (mm³/s).
    pub vdot: Vec<f64>,
    /// Volumetric acceleration (mm³/s²), the three-point derivative of flow.
    pub vddot: Vec<f64>,
    /// Measured pressure (kPa).
    pub p: Vec<f64>,
    /// True on training samples, false on held-out samples.
    pub train: Vec<bool>,
    /// The period of the log's cycles (s) when they repeat regularly (a ventilator's breaths):
    /// what a plausible periodic effect must not be locked to. `None` (the default) when unknown
    /// or irregular; [`series_from_dataset`] sets it from the cycle split ([`cycle_period`]).
    pub cycle_s: Option<f64>,
    /// The rig the data come from, for the effects' names ([`Rig`]; [`Series::new`]: this
    /// project's syringe rig; [`diagnose_log`] reads it from the log's header).
    pub rig: Rig,
}

impl Series {
    /// Checks and assembles a series; v̈ is derived from v̇.
    pub fn new(
        t: Vec<f64>,
        v: Vec<f64>,
        vdot: Vec<f64>,
        p: Vec<f64>,
        train: Vec<bool>,
    ) -> Result<Self, DiagnoseError> {
        let n = t.len();
        for (what, len) in [
            ("volume", v.len()),
            ("flow", vdot.len()),
            ("pressure", p.len()),
            ("split mask", train.len()),
        ] {
            if len != n {
                return Err(DiagnoseError::LengthMismatch {
                    what,
                    got: len,
                    expected: n,
                });
            }
        }
        for (what, x) in [
            ("time", &t),
            ("volume", &v),
            ("flow", &vdot),
            ("pressure", &p),
        ] {
            if let Some(index) = x.iter().position(|x| !x.is_finite()) {
                return Err(DiagnoseError::NonFinite { what, index });
            }
        }
        if let Some(k) = t.windows(2).position(|w| w[1] <= w[0]) {
            return Err(DiagnoseError::TimeNotIncreasing { index: k + 1 });
        }
        let n_train = train.iter().filter(|&&b| b).count();
        let needed = 100;
        if n_train < needed || n - n_train < needed {
            return Err(DiagnoseError::TooFewSamples {
                train: n_train,
                heldout: n - n_train,
                needed,
            });
        }
        let vddot = signal::derivative(&t, &vdot);
        Ok(Self {
            t,
            v,
            vdot,
            vddot,
            p,
            train,
            cycle_s: None,
            rig: Rig::Syringe,
        })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
}

/// Settings of the loop.
#[derive(Clone, Debug)]
pub struct Config {
    /// Baseline degree in volume.
    pub n: usize,
    /// Baseline degree in flow.
    pub m: usize,
    /// Level of the nested F-test.
    pub alpha: f64,
    /// Smallest relative held-out RMSE gain for an effect to be kept.
    pub min_gain: f64,
    /// Level of the Ljung–Box test that decides whether structure remains.
    pub whiteness_alpha: f64,
    /// Candidates considered (default: [`REGISTRY`]; names must be unique).
    pub candidates: Vec<EffectKind>,
    /// Most effects added.
    pub max_effects: usize,
    /// Worker threads for the candidate searches.
    pub threads: usize,
    /// Bytes the full designs of the searches may hold at once, across the threads
    /// (`effects::DesignGate`; default `effects::DESIGN_MEMORY`, 192 MiB): on a long log the
    /// threads take turns with their designs instead of holding one each.
    pub design_memory: usize,
    /// Told as each stage starts (baseline, each round's searches, the final analysis) and as
    /// each candidate's search finishes; `None`: silent.
    pub progress: Option<crate::progress::ProgressFn>,
    /// The rig the effects are named for ([`Rig`]); `None`: the series' own ([`Series::rig`]),
    /// which [`diagnose_log`] takes from the log's header.
    pub rig: Option<Rig>,
}

impl Default for Config {
    fn default() -> Self {
        Self {
            n: 3,
            m: 2,
            alpha: 1e-3,
            min_gain: 0.01,
            whiteness_alpha: 0.01,
            candidates: REGISTRY.to_vec(),
            max_effects: 6,
            threads: std::thread::available_parallelism()
                .map_or(1, |n| n.get())
                .min(4),
            design_memory: effects::DESIGN_MEMORY,
            progress: None,
            rig: None,
        }
    }
}

/// The baseline's errors.
#[derive(Clone, Debug, Serialize)]
pub struct BaselineReport {
    /// Degree in volume.
    pub n: usize,
    /// Degree in flow.
    pub m: usize,
    /// Parameters.
    pub nu: usize,
    /// Training RMSE (kPa).
    pub rmse_train: f64,
    /// Held-out RMSE (kPa).
    pub rmse_heldout: f64,
}

/// One effect the loop added.
#[derive(Clone, Debug, Serialize)]
pub struct EffectReport {
    /// The effect.
    #[serde(skip)]
    pub kind: EffectKind,
    /// Machine name.
    pub name: &'static str,
    /// Physical story.
    pub story: &'static str,
    /// Parameters with uncertainties, from the final model.
    pub params: Vec<Param>,
    /// Held-out RMSE before adding it (kPa).
    pub rmse_heldout_before: f64,
    /// Held-out RMSE after adding it (kPa).
    pub rmse_heldout_after: f64,
    /// Training RMSE before (kPa).
    pub rmse_train_before: f64,
    /// Training RMSE after (kPa).
    pub rmse_train_after: f64,
    /// p-value of the nested F-test.
    pub p_value: f64,
    /// The test's details.
    pub test: NestedTest,
    /// Whether the firmware's model can run this term, and why (not).
    pub device: DeviceSupport,
    /// The candidate that came next in the round this effect was kept in (lowest held-out RMSE
    /// of the others), with its verdict (`reason`: "passes too", "significance" or why it is
    /// unphysical): when two candidates explain the same structure, how close the other came.
    pub runner_up: Option<Rejected>,
    /// Other explanations the held-out data cannot tell from this one (`|z| <`
    /// [`alternatives::ALT_Z`]), fitted in its place with the rest of the final model kept
    /// ([`alternatives`]); absent when the data tell it apart from every one tried.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub alternatives: Vec<alternatives::Alternative>,
}

/// Whether an effect term can run on the device.
#[derive(Clone, Debug, Serialize)]
pub struct DeviceSupport {
    /// True when `model_core::poly::PolyModel` can evaluate it.
    pub runs_on_device: bool,
    /// Why (not).
    pub reason: &'static str,
}

impl DeviceSupport {
    /// The device can run the term, because `reason`.
    pub const fn on_device(reason: &'static str) -> Self {
        Self {
            runs_on_device: true,
            reason,
        }
    }

    /// Only the host can run the term, because `reason`.
    pub const fn host_only(reason: &'static str) -> Self {
        Self {
            runs_on_device: false,
            reason,
        }
    }
}

/// A candidate that was tried in the last round and not kept.
#[derive(Clone, Debug, Serialize)]
pub struct Rejected {
    /// Machine name.
    pub name: &'static str,
    /// Held-out RMSE it would give (kPa).
    pub rmse_heldout: f64,
    /// Its test p-value.
    pub p_value: f64,
    /// Why it was not kept: `significance` (test or gain threshold not met) or
    /// `unphysical: <reason>` (its best fit is physically impossible).
    pub reason: String,
}

/// A kept effect replaced by a look-alike (`swap_look_alike`): forward selection adds one effect
/// at a time, so an effect that alone explains most of two others' structure (a delivery lag for
/// an air pocket's lag and a sensor lag together) is kept first and the others cannot follow.
#[derive(Clone, Debug, Serialize)]
pub struct SwapReport {
    /// The effect taken out.
    pub replaced: &'static str,
    /// The look-alikes put in its place: one, or two that together explain what it did.
    pub by: Vec<&'static str>,
    /// Held-out RMSE of the model with the replaced effect (kPa).
    pub rmse_heldout_before: f64,
    /// Held-out RMSE with the look-alike in its place, the other effects re-tuned (kPa).
    pub rmse_heldout_after: f64,
}

/// The final model's errors.
#[derive(Clone, Debug, Serialize)]
pub struct FinalReport {
    /// Parameters.
    pub nu: usize,
    /// Training RMSE (kPa).
    pub rmse_train: f64,
    /// Held-out RMSE (kPa).
    pub rmse_heldout: f64,
    /// Whether predictions use measured pressure as a scheduling input (leak, air compliance).
    pub uses_measured_pressure: bool,
}

/// Short summary of a residual analysis for the JSON report.
#[derive(Clone, Debug, Serialize)]
pub struct AnalysisSummary {
    /// RMS (kPa).
    pub rmse: f64,
    /// Ljung–Box p-value.
    pub ljung_box_p: f64,
    /// Lag-1 autocorrelation.
    pub acf_lag1: f64,
    /// Strongest cross-correlation: (input, lag in samples, value).
    pub strongest_input: (&'static str, i64, f64),
    /// Spectral peak (Hz).
    pub spectral_peak_hz: f64,
    /// Mean residual inflating minus deflating (kPa).
    pub direction_gap: f64,
}

impl From<&ResidualAnalysis> for AnalysisSummary {
    fn from(a: &ResidualAnalysis) -> Self {
        let c = a
            .cross
            .iter()
            .max_by(|x, y| x.peak_value.abs().total_cmp(&y.peak_value.abs()));
        Self {
            rmse: a.rmse,
            ljung_box_p: a.whiteness.lb_p_value,
            acf_lag1: a.whiteness.acf.get(1).copied().unwrap_or(0.0),
            strongest_input: c.map_or(("none", 0, 0.0), |c| (c.input, c.peak_lag, c.peak_value)),
            spectral_peak_hz: a.spectrum.peak_hz,
            direction_gap: a.direction.mean_inflation - a.direction.mean_deflation,
        }
    }
}

/// Everything the loop found.
#[derive(Clone, Debug, Serialize)]
pub struct Diagnosis {
    /// The rig the effects are named for.
    pub rig: Rig,
    /// Training / held-out sample counts.
    pub samples: (usize, usize),
    /// How significance is decided, in words.
    pub significance: String,
    /// The baseline.
    pub baseline: BaselineReport,
    /// Effects in the order added.
    pub effects: Vec<EffectReport>,
    /// The final model.
    #[serde(rename = "final")]
    pub final_model: FinalReport,
    /// Structure left unexplained: the final residual's signatures when it is not white, and any
    /// candidate that would have passed but whose best fit is unphysical (`unphysical_fit`).
    pub remaining: Vec<Signature>,
    /// Candidates tried in the last round and not kept.
    pub rejected_last_round: Vec<Rejected>,
    /// Kept effects replaced by a look-alike that explains the same structure better in the
    /// final model's company ([`SwapReport`]); absent when none was.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub swaps: Vec<SwapReport>,
    /// Residual summary before (baseline, held-out).
    pub before: AnalysisSummary,
    /// Residual summary after (final model, held-out).
    pub after: AnalysisSummary,
    /// Full analyses for the figures.
    #[serde(skip)]
    pub analysis_before: ResidualAnalysis,
    /// Full analyses for the figures.
    #[serde(skip)]
    pub analysis_after: ResidualAnalysis,
    /// The final model's effects with their searched parameters (what an export refits).
    #[serde(skip)]
    pub final_effects: Vec<effects::Effect>,
    /// The fitted models, baseline first, then the model after each kept effect (what
    /// [`validate`] evaluates on another log).
    #[serde(skip)]
    pub models: Vec<validate::FittedModel>,
    /// The polynomial basis (its scaling) the models were fitted in.
    #[serde(skip)]
    pub basis: basis::PolyBasis,
    /// Where the loop's time went ([`Timings`]; wall-clock seconds).
    #[serde(rename = "timing_s")]
    pub timing: Timings,
}

/// Where the loop's time went, in wall-clock seconds (`vfp diagnose --timings`; JSON `timing_s`,
/// which the golden comparisons leave out: it is the only part of a diagnosis that depends on the
/// machine). The stages do not overlap, so they add up to `total` (up to the bookkeeping between
/// them); the candidate searches run on `Config::threads` workers, so a round's `candidates` (each
/// search's own seconds) can add up to more than its wall time `searches`.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Timings {
    /// The baseline shape's selection (`diagnose_log` without a given shape; 0 otherwise).
    pub shape_selection: f64,
    /// The prepared data (scales, basis) and the baseline fit.
    pub baseline: f64,
    /// Every round's candidate searches and their tests (the sum of `rounds[..].searches`).
    pub searches: f64,
    /// Every round's re-tune of the kept model (the sum of `rounds[..].retune`).
    pub retune: f64,
    /// Trials of a kept effect's single look-alikes in its place.
    pub single_swaps: f64,
    /// Trials of a kept effect's two best look-alikes together in its place.
    pub pair_trials: f64,
    /// Putting a swap in place (leave-one-out drops, the steps rebuilt).
    pub apply_swaps: f64,
    /// The kept effects' alternatives ([`alternatives`]).
    pub alternatives: f64,
    /// The held-out residual analyses before and after, and the report's parameters.
    pub residual_analysis: f64,
    /// The whole loop.
    pub total: f64,
    /// Each round of forward selection in order (rounds after a swap included).
    pub rounds: Vec<RoundTiming>,
}

impl Timings {
    /// The stages in the loop's order, each with its seconds and its name in the reports
    /// (`vfp diagnose --timings`, `vfp bench-loop`); `total` not included.
    pub fn stages(&self) -> [(&'static str, f64); 9] {
        [
            ("shape selection", self.shape_selection),
            ("baseline fit", self.baseline),
            ("candidate searches", self.searches),
            ("re-tunes", self.retune),
            ("single swaps", self.single_swaps),
            ("pair trials", self.pair_trials),
            ("applying swaps", self.apply_swaps),
            ("alternatives", self.alternatives),
            ("residual analysis", self.residual_analysis),
        ]
    }
}

/// One round of forward selection's time ([`Timings::rounds`]).
#[derive(Clone, Debug, Default, Serialize)]
pub struct RoundTiming {
    /// Effects in the model the round extends.
    pub effects_before: usize,
    /// The round's searches and tests (wall).
    pub searches: f64,
    /// Each candidate's search (seconds on its worker).
    pub candidates: std::collections::BTreeMap<&'static str, f64>,
    /// The re-tune of the model with the kept candidate (0 when none was kept).
    pub retune: f64,
}

/// Seconds since `t`.
fn secs(t: std::time::Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

/// Device verdict for a list of effect names (for `vfp export`): per effect whether
/// `model_core::poly::PolyModel` can evaluate it and why (not). The whole augmented model runs on the
/// device only if every entry is `true`.
pub fn device_support(kinds: &[EffectKind]) -> Vec<(EffectKind, DeviceSupport)> {
    kinds.iter().map(|&k| (k, k.device_support())).collect()
}

/// One effect the loop kept: the errors before and after its round (RMSE, kPa) and its test.
struct KeptStep {
    kind: EffectKind,
    /// The model as kept.
    model: validate::FittedModel,
    heldout_before: f64,
    heldout_after: f64,
    train_before: f64,
    train_after: f64,
    test: NestedTest,
    /// The round's next-best candidate.
    runner_up: Option<Rejected>,
    /// The round's look-alikes: the other candidates that passed, physical, with at least
    /// [`LOOK_ALIKE_GAIN`] of the kept one's gain ([`swap_look_alike`] tries each in its place),
    /// each as its round fitted it.
    rivals: Vec<Effect>,
    /// What its alternatives are sought among ([`alternatives::Leads`]).
    leads: alternatives::Leads,
}

/// Share of a kept effect's held-out gain another candidate of its round must reach to be its
/// look-alike: one that explains most of the same structure.
pub(crate) const LOOK_ALIKE_GAIN: f64 = 0.5;

/// The name effect `e` is reported under: its neutral name where its parameters or the rig call
/// for one ([`neutral`]), else its own.
pub(crate) fn report_name(prep: &effects::Prepared, e: &Effect) -> &'static str {
    neutral_of(prep, e).map_or(e.kind.name(), |n| n.0)
}

/// What forward selection ends with.
struct Selection {
    /// The final model.
    model: Stage,
    /// The effects kept, in order.
    kept: Vec<KeptStep>,
    /// Candidates tried in the last round and not kept.
    rejected: Vec<Rejected>,
    /// Structure a candidate would have absorbed with an unphysical fit.
    unphysical: Vec<Signature>,
    /// Look-alikes swapped in.
    swaps: Vec<SwapReport>,
    /// Where the time went so far.
    timing: Timings,
    /// The final model's joint covariance ([`interval::joint_cov`]), once [`drop_absent`] formed
    /// it.
    final_cov: Option<interval::JointCov>,
    /// Effects look-alike swaps took out, and what came in.
    replaced: Vec<alternatives::Replaced>,
    /// Pairs of look-alikes tried in a kept effect's place and not taken ([`swap_for_pair`]):
    /// the effect, and the model's effects with the pair last.
    pair_trials: Vec<(EffectKind, Vec<Effect>)>,
    /// Each final effect's alternatives, in the model's order ([`alternatives::alternatives`]).
    alternatives: Vec<Vec<alternatives::Alternative>>,
}

/// One searched candidate of a round, judged against the model it would extend.
struct Ranked {
    cand: search::Candidate,
    test: NestedTest,
    /// The test rejects at `alpha` and the held-out gain clears `min_gain`.
    passes: bool,
    /// Why its best fit is not physical, if it is not.
    unphysical: Option<String>,
}

/// Runs the whole loop on one series.
pub fn diagnose(series: Series, cfg: &Config) -> Result<Diagnosis, DiagnoseError> {
    for (i, k) in cfg.candidates.iter().enumerate() {
        if cfg.candidates[..i].contains(k) {
            return Err(DiagnoseError::DuplicateEffect(k.name()));
        }
    }
    let say = |what: &str| tell(cfg.progress, Progress::Stage { what, total: 0 });
    say("baseline fit");
    let started = std::time::Instant::now();
    let basis = PolyBasis::for_data(&series.v, &series.vdot, cfg.n, cfg.m)
        .map_err(|e| DiagnoseError::Degenerate(e.to_string()))?;
    let mut prep = effects::Prepared::new(series, basis);
    prep.gate = effects::DesignGate::new(cfg.design_memory);
    let baseline = search::fit_stage(&prep, &[]).ok_or_else(|| {
        DiagnoseError::Degenerate(
            "its columns are linearly dependent on the training rows (is volume or flow constant?)"
                .into(),
        )
    })?;
    let baseline_s = secs(started);
    let mut selection = select_effects(&prep, &baseline, cfg);
    selection.timing.baseline = baseline_s;
    drop_absent(&prep, cfg, &mut selection);
    say("alternatives");
    let t = std::time::Instant::now();
    selection.alternatives = alternatives::alternatives(
        &prep,
        &alternatives::Inputs {
            model: &selection.model,
            leads: selection.kept.iter().map(|k| &k.leads).collect(),
            names: selection
                .model
                .effects
                .iter()
                .map(|e| report_name(&prep, e))
                .collect(),
            replaced: &selection.replaced,
            pair_trials: &selection.pair_trials,
        },
    );
    selection.timing.alternatives = secs(t);
    say("residual analysis");
    let t = std::time::Instant::now();
    let mut d = report(&prep, cfg, &baseline, selection);
    d.timing.residual_analysis = secs(t);
    d.timing.total = secs(started);
    tell(cfg.progress, Progress::Done);
    Ok(d)
}

/// Forward selection (step 4, [`search`]): each round searches every candidate not yet in the
/// model, keeps the best-ranked one that passes and is physical, and stops when none does. Then
/// each kept effect's look-alikes, one or two together, are tried in its place
/// ([`swap_look_alike`]); after a swap the
/// replaced kind is out of the running and forward selection goes on from the swapped model.
fn select_effects(prep: &effects::Prepared, baseline: &Stage, cfg: &Config) -> Selection {
    let mut sel = Selection {
        model: baseline.clone(),
        kept: Vec::new(),
        rejected: Vec::new(),
        unphysical: Vec::new(),
        swaps: Vec::new(),
        timing: Timings::default(),
        final_cov: None,
        replaced: Vec::new(),
        pair_trials: Vec::new(),
        alternatives: Vec::new(),
    };
    // Each candidate's search time in the previous round, to schedule the next (`search_all`).
    let mut costs = std::collections::HashMap::new();
    let mut banned: Vec<EffectKind> = Vec::new();
    loop {
        forward(prep, cfg, &mut sel, &mut costs, &banned);
        let what = "comparing look-alikes";
        tell(cfg.progress, Progress::Stage { what, total: 0 });
        let t = std::time::Instant::now();
        let one = swap_look_alike(prep, &sel, &banned);
        sel.timing.single_swaps += secs(t);
        // A pair is tried even where one look-alike wins: the one can leave the other's share to
        // an effect the plant does not have, taken in a later round.
        let t = std::time::Instant::now();
        let mut tried = Vec::new();
        let two = swap_for_pair(prep, cfg, &sel, &banned, &mut tried);
        sel.pair_trials.extend(tried);
        sel.timing.pair_trials += secs(t);
        let swap = match (one, two) {
            (Some(one), Some(two)) if two.stage.rmse_heldout < one.stage.rmse_heldout => two,
            (Some(one), _) => one,
            (None, Some(two)) => two,
            (None, None) => break,
        };
        banned.push(swap.out);
        let t = std::time::Instant::now();
        apply_swap(prep, cfg, baseline, &mut sel, swap);
        sel.timing.apply_swaps += secs(t);
    }
    sel
}

/// Rounds of forward selection from `sel`'s model, with the kinds in `banned` left out.
fn forward(
    prep: &effects::Prepared,
    cfg: &Config,
    sel: &mut Selection,
    costs: &mut std::collections::HashMap<EffectKind, f64>,
    banned: &[EffectKind],
) {
    while sel.model.effects.len() < cfg.max_effects {
        let t = std::time::Instant::now();
        let (mut round, candidates) = rank_round(prep, &sel.model, cfg, costs, banned);
        let searches = secs(t);
        sel.timing.searches += searches;
        sel.timing.rounds.push(RoundTiming {
            effects_before: sel.model.effects.len(),
            searches,
            candidates,
            retune: 0.0,
        });
        match round
            .iter()
            .position(|r| r.passes && r.unphysical.is_none())
        {
            Some(i) => {
                let what = "re-tuning the effects kept";
                tell(cfg.progress, Progress::Stage { what, total: 0 });
                let winner = round.remove(i);
                let runner_up = round.first().map(verdict);
                let gain = sel.model.rmse_heldout - winner.cand.stage.rmse_heldout;
                let rivals = round
                    .iter()
                    .filter(|r| {
                        r.passes
                            && r.unphysical.is_none()
                            && sel.model.rmse_heldout - r.cand.stage.rmse_heldout
                                >= LOOK_ALIKE_GAIN * gain
                    })
                    .filter_map(|r| r.cand.stage.effects.last().cloned())
                    .collect();
                let leads = alternatives::Leads {
                    close: alternatives::screen(
                        &validate::held_out_blocks(prep),
                        sel.model.rmse_heldout,
                        &winner.cand.stage,
                        round
                            .iter()
                            .filter(|r| r.unphysical.is_none())
                            .map(|r| &r.cand.stage),
                    ),
                };
                let t = std::time::Instant::now();
                keep(prep, sel, winner, runner_up, rivals, leads);
                let retune = secs(t);
                sel.timing.retune += retune;
                if let Some(r) = sel.timing.rounds.last_mut() {
                    r.retune = retune;
                }
            }
            None => {
                reject_round(sel, &round);
                break;
            }
        }
    }
}

/// A kept effect replaced by a look-alike: the model with it, and the replaced kind.
struct Swap {
    out: EffectKind,
    /// Where the replaced effect was in the model.
    at: usize,
    /// The model with the look-alikes in, last in its effects.
    stage: Stage,
    /// How many look-alikes came in (1 or 2).
    added: usize,
}

/// The best swap of one kept effect for one of its look-alikes ([`KeptStep::rivals`], not
/// in the model or `banned`): the look-alike searched on the model without the effect and,
/// where that already fits the training rows better, every searched parameter re-tuned
/// ([`search::retune`]), so that two lags that trade against each other find their joint
/// optimum. A swap must be physical, add no parameter, and lower
/// both the training SSE and the held-out RMSE. The best by held-out RMSE is returned
/// ([`select_effects`] weighs it against the best pair of look-alikes, [`swap_for_pair`]).
fn swap_look_alike(
    prep: &effects::Prepared,
    sel: &Selection,
    banned: &[EffectKind],
) -> Option<Swap> {
    let model = &sel.model;
    let mut best: Option<Swap> = None;
    for step in &sel.kept {
        // The last effect's look-alikes lost to it in its round, against the same company (up
        // to the re-tune): only an effect kept before others can have taken their share.
        let Some((at, rivals)) = open_rivals(step, model, banned) else {
            continue;
        };
        if at + 1 >= model.effects.len() {
            continue;
        }
        // The model without the effect, once for all its look-alikes.
        let mut without = model.effects.clone();
        without.remove(at);
        let Some(base) = search::fit_stage(prep, &without) else {
            continue;
        };
        for c in rivals.iter().map(|r| r.kind) {
            let Some(cand) = search::search(prep, &base, c) else {
                continue;
            };
            // Only a look-alike that already fits the training rows better, searched alone in
            // the model's company, is re-tuned with the rest (a re-tune runs every searched
            // parameter; on a 51,561-frame log one takes 6–10 s).
            if cand.stage.fit.sse >= model.fit.sse {
                continue;
            }
            let tuned = search::retune(prep, &cand.stage);
            let stage = if tuned.fit.sse <= cand.stage.fit.sse {
                tuned
            } else {
                cand.stage
            };
            let better = stage.fit.sse < model.fit.sse
                && stage.rmse_heldout < model.rmse_heldout
                && stage.n_params() <= model.n_params()
                && search::unphysical(&stage, &prep.scales).is_none()
                && best
                    .as_ref()
                    .is_none_or(|b| stage.rmse_heldout < b.stage.rmse_heldout);
            if better {
                best = Some(Swap {
                    out: step.kind,
                    at,
                    stage,
                    added: 1,
                });
            }
        }
    }
    best
}

/// Where the kept effect `step` is in `model`, and its look-alikes that may take its place (best
/// first): those neither in `banned` nor in the model.
fn open_rivals<'a>(
    step: &'a KeptStep,
    model: &Stage,
    banned: &[EffectKind],
) -> Option<(usize, Vec<&'a Effect>)> {
    let at = model.effects.iter().position(|e| e.kind == step.kind)?;
    let rivals = step
        .rivals
        .iter()
        .filter(|c| !banned.contains(&c.kind) && !model.effects.iter().any(|e| e.kind == c.kind))
        .collect();
    Some((at, rivals))
}

/// The best swap of one kept effect for its two best look-alikes together: one effect can hold
/// what two others share (a delivery lag for an air pocket's lag and a sensor lag in series),
/// and then each of the two alone loses to it, in its round and in its place. The pair starts
/// from each as its round fitted it, alone, in the effect's place, and every parameter is
/// re-tuned; it is kept only where it lowers both the training SSE and the held-out RMSE, is
/// physical, and each of the two passes the loop's test in the other's company (leave-one-out),
/// which pays for the parameter it adds ([`pair_passes`]). The re-tune gives up once it cannot
/// come below the model's training SSE and stops where it first does
/// ([`search::retune_to_beat`]): on a 3-hour log one sweep takes 15–20 s. A pair is judged
/// there; only one that passes is re-tuned to the end and judged again, as it settled.
fn swap_for_pair(
    prep: &effects::Prepared,
    cfg: &Config,
    sel: &Selection,
    banned: &[EffectKind],
    tried: &mut Vec<(EffectKind, Vec<Effect>)>,
) -> Option<Swap> {
    let model = &sel.model;
    let mut best: Option<Swap> = None;
    for step in &sel.kept {
        let Some((at, rivals)) = open_rivals(step, model, banned) else {
            continue;
        };
        let [a, b, ..] = rivals[..] else {
            continue;
        };
        // Each as its round fitted it, alone: two that share a structure each took more of it
        // than is theirs, and the descent walks them to their shares.
        let mut effects = model.effects.clone();
        effects.remove(at);
        effects.extend([a.clone(), b.clone()]);
        let Some(start) = search::fit_stage(prep, &effects) else {
            continue;
        };
        let trial = search::retune_to_beat(prep, &start, model.fit.sse);
        // Judged where it first beats the model; only a pair that passes there is re-tuned to
        // the end, and judged again.
        if !pair_passes(prep, cfg, model, &trial, best.as_ref()) {
            // Kept for the alternatives ([`alternatives`]) whatever comes of it.
            tried.push((step.kind, trial.effects.clone()));
            continue;
        }
        let tuned = search::retune(prep, &trial);
        let stage = if tuned.fit.sse < trial.fit.sse {
            tuned
        } else {
            trial
        };
        tried.push((step.kind, stage.effects.clone()));
        if !pair_passes(prep, cfg, model, &stage, best.as_ref()) {
            continue;
        }
        best = Some(Swap {
            out: step.kind,
            at,
            stage,
            added: 2,
        });
    }
    best
}

/// Whether a pair of look-alikes fitted in a kept effect's place (`stage`, the pair last) may
/// replace it in `model` ([`swap_for_pair`]): it lowers both the training SSE and the held-out
/// RMSE, more than the best swap so far does on the held-out rows, is physical, and each of the
/// two passes the loop's test in the other's company (leave-one-out).
fn pair_passes(
    prep: &effects::Prepared,
    cfg: &Config,
    model: &Stage,
    stage: &Stage,
    best: Option<&Swap>,
) -> bool {
    if !(stage.fit.sse < model.fit.sse && stage.rmse_heldout < model.rmse_heldout)
        || search::unphysical(stage, &prep.scales).is_some()
        || best.is_some_and(|b| stage.rmse_heldout >= b.stage.rmse_heldout)
    {
        return false;
    }
    let n = stage.effects.len();
    (n - 2..n).all(|j| leave_one_out(prep, cfg, stage, j).is_some_and(|(_, ok)| ok))
}

/// Puts a swap's model in place: the look-alike where the replaced effect was, then any effect
/// the swap left without a use dropped (its leave-one-out test no longer passes, the weakest
/// first), and the steps rebuilt from the baseline in the model's order, each from the model
/// with the effects before it (their parameters as tuned in the whole model).
fn apply_swap(
    prep: &effects::Prepared,
    cfg: &Config,
    baseline: &Stage,
    sel: &mut Selection,
    swap: Swap,
) {
    let before = sel.model.rmse_heldout;
    let mut effects = swap.stage.effects.clone();
    let new = effects.split_off(effects.len().saturating_sub(swap.added));
    let by: Vec<EffectKind> = new.iter().map(|e| e.kind).collect();
    for (o, e) in new.into_iter().enumerate() {
        effects.insert(swap.at + o, e);
    }
    let Some(mut model) = search::fit_stage(prep, &effects) else {
        return;
    };
    sel.replaced.push(alternatives::Replaced {
        out: swap.out,
        by: by.clone(),
    });
    sel.swaps.push(SwapReport {
        replaced: swap.out.name(),
        by: by.iter().map(|k| k.name()).collect(),
        rmse_heldout_before: before,
        rmse_heldout_after: model.rmse_heldout,
    });
    // Leave-one-out: the effect whose removal costs least, while that fails the loop's test.
    loop {
        let weakest = (0..model.effects.len())
            .filter_map(|j| {
                let (small, ok) = leave_one_out(prep, cfg, &model, j)?;
                let gain = small.rmse_heldout - model.rmse_heldout;
                (!ok).then_some((j, gain, small))
            })
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match weakest {
            Some((_, _, small)) => model = small,
            None => break,
        }
    }
    let old: Vec<KeptStep> = std::mem::take(&mut sel.kept);
    let mut prev = baseline.clone();
    for j in 0..model.effects.len() {
        let Some(after) = search::fit_stage(prep, &model.effects[..=j]) else {
            continue;
        };
        let kind = model.effects[j].kind;
        let was = old.iter().find(|k| k.kind == kind);
        let runner_up = if by.contains(&kind) {
            let names: Vec<&str> = by.iter().map(|k| k.name()).collect();
            Some(Rejected {
                name: swap.out.name(),
                rmse_heldout: before,
                p_value: f64::NAN,
                reason: format!(
                    "swapped out: {} in its place lowers held-out RMSE {before:.4} → {:.4} kPa",
                    names.join(" + "),
                    swap.stage.rmse_heldout
                ),
            })
        } else {
            was.and_then(|k| k.runner_up.clone())
        };
        sel.kept.push(KeptStep {
            kind,
            model: validate::FittedModel::of(&after),
            heldout_before: prev.rmse_heldout,
            heldout_after: after.rmse_heldout,
            train_before: prev.rmse_train,
            train_after: after.rmse_train,
            test: search::nested_test(prep, &prev, &after),
            runner_up,
            rivals: was.map(|k| k.rivals.clone()).unwrap_or_default(),
            leads: was.map(|k| k.leads.clone()).unwrap_or_default(),
        });
        prev = after;
    }
    sel.model = model;
}

/// Searches and tests every candidate not yet in `cur`, ranked by held-out RMSE.
fn rank_round(
    prep: &effects::Prepared,
    cur: &Stage,
    cfg: &Config,
    costs: &mut std::collections::HashMap<EffectKind, f64>,
    banned: &[EffectKind],
) -> (Vec<Ranked>, std::collections::BTreeMap<&'static str, f64>) {
    let todo: Vec<EffectKind> = cfg
        .candidates
        .iter()
        .copied()
        .filter(|k| !cur.effects.iter().any(|e| e.kind == *k) && !banned.contains(k))
        .collect();
    let what = format!(
        "round {}: searching {} candidates",
        cur.effects.len() + 1,
        todo.len()
    );
    tell(
        cfg.progress,
        Progress::Stage {
            what: &what,
            total: todo.len(),
        },
    );
    let (found, times) = search_all(prep, cur, &todo, cfg, costs);
    let mut ranked: Vec<Ranked> = found
        .into_iter()
        .map(|cand| {
            let test = search::nested_test(prep, cur, &cand.stage);
            Ranked {
                passes: passes(cfg, cur, &cand.stage, &test),
                unphysical: search::unphysical(&cand.stage, &prep.scales).map(|(_, why)| why),
                cand,
                test,
            }
        })
        .collect();
    ranked.sort_by(|a, b| {
        a.cand
            .stage
            .rmse_heldout
            .total_cmp(&b.cand.stage.rmse_heldout)
    });
    (ranked, times)
}

/// The loop's test of a model `big` against the model `small` it extends: the nested F-test
/// (`test`) rejects at `alpha` and the held-out RMSE falls by at least `min_gain` of `small`'s.
fn passes(cfg: &Config, small: &Stage, big: &Stage, test: &NestedTest) -> bool {
    test.p_value < cfg.alpha
        && small.rmse_heldout - big.rmse_heldout >= cfg.min_gain * small.rmse_heldout
}

/// `model` without its effect `j`, and whether `model` passes the loop's test against it
/// ([`passes`]); `None` when the smaller model cannot be fitted.
fn leave_one_out(
    prep: &effects::Prepared,
    cfg: &Config,
    model: &Stage,
    j: usize,
) -> Option<(Stage, bool)> {
    let mut rest = model.effects.clone();
    rest.remove(j);
    let small = search::fit_stage(prep, &rest)?;
    let ok = passes(
        cfg,
        &small,
        model,
        &search::nested_test(prep, &small, model),
    );
    Some((small, ok))
}

/// Keeps a candidate: re-tunes the model's searched parameters and records the step, its
/// "after" being the model as kept (so each step's "after" is the next step's "before"). The
/// re-tuned model replaces the candidate where it fits the training rows better, is physical,
/// and keeps the step's gain on the held-out rows (its error there below the model's before
/// the step): re-tuning follows the training rows only, and a drift's time polynomial tuned
/// there can run far off over a held-out stretch.
fn keep(
    prep: &effects::Prepared,
    sel: &mut Selection,
    r: Ranked,
    runner_up: Option<Rejected>,
    rivals: Vec<Effect>,
    leads: alternatives::Leads,
) {
    let tuned = search::retune(prep, &r.cand.stage);
    let model = if tuned.fit.sse <= r.cand.stage.fit.sse
        && tuned.rmse_heldout < sel.model.rmse_heldout
        && search::unphysical(&tuned, &prep.scales).is_none()
    {
        tuned
    } else {
        r.cand.stage
    };
    sel.kept.push(KeptStep {
        kind: r.cand.kind,
        model: validate::FittedModel::of(&model),
        heldout_before: sel.model.rmse_heldout,
        heldout_after: model.rmse_heldout,
        train_before: sel.model.rmse_train,
        train_after: model.rmse_train,
        test: r.test,
        runner_up,
        rivals,
        leads,
    });
    sel.model = model;
}

/// Records the last round's candidates as rejected; what an inadmissible candidate would have
/// absorbed is structure the model lacks, reported with the fit it would have needed.
fn reject_round(sel: &mut Selection, round: &[Ranked]) {
    sel.unphysical.clear();
    sel.rejected.clear();
    let cur = &sel.model;
    for r in round {
        let name = r.cand.kind.name();
        if let (true, Some(why)) = (r.passes, &r.unphysical) {
            sel.unphysical.push(Signature {
                kind: "unphysical_fit",
                description: format!(
                    "{name} would lower held-out RMSE {:.4} → {:.4} kPa (p = {:.1e}) but its best fit is not physical ({why}); the structure it follows is left unexplained",
                    cur.rmse_heldout, r.cand.stage.rmse_heldout, r.test.p_value
                ),
                ..Signature::default()
            });
        }
        sel.rejected.push(verdict(r));
    }
}

/// A searched candidate as reported when not kept: its held-out RMSE, p-value and why not
/// ("passes too" for one that would have passed, beaten by the kept one).
fn verdict(r: &Ranked) -> Rejected {
    Rejected {
        name: r.cand.kind.name(),
        rmse_heldout: r.cand.stage.rmse_heldout,
        p_value: r.test.p_value,
        reason: match (&r.unphysical, r.passes) {
            (Some(why), _) => format!("unphysical: {why}"),
            (None, true) => "passes too".to_string(),
            (None, false) => "significance".to_string(),
        },
    }
}

/// The final check of issue 34: an effect whose 95 % interval on its presence parameter
/// ([`EffectModel::presence`]: a gap, time constant, volume, amplitude) reaches 0, the value that
/// means it is absent, is not named, unless the model without it (the others refitted, their θ as
/// they were) loses at least `min_gain` of held-out RMSE: then the interval is wide because the
/// effect trades against another (a volume drift against an offset drift), not because the data
/// cannot tell it from nothing, and by the loop's own rule it still earns its place. Effects are
/// taken out one at a time, the one whose removal costs least first; what an effect taken out
/// followed is reported in `remaining` (`indistinct_from_absent`). Leaves the final model's
/// covariance in `sel.final_cov`.
fn drop_absent(prep: &effects::Prepared, cfg: &Config, sel: &mut Selection) {
    while !sel.kept.is_empty() {
        let Some(jc) = interval::joint_cov(prep, &sel.model) else {
            return;
        };
        let with = sel.model.rmse_heldout;
        let mut best: Option<(usize, Param, Stage)> = None;
        for i in 0..sel.model.effects.len() {
            let Some(name) = sel.model.effects[i].kind.presence() else {
                continue;
            };
            let params = interval::effect_params_ci(prep, &sel.model, i, Some(&jc));
            let Some(p) = params.into_iter().find(|p| p.name == name) else {
                continue;
            };
            let Some([lo, hi]) = p.ci95 else {
                continue;
            };
            if !(lo <= 0.0 && 0.0 <= hi) {
                continue;
            }
            let mut rest = sel.model.effects.clone();
            rest.remove(i);
            let Some(model) = search::fit_stage(prep, &rest) else {
                continue;
            };
            let gain = 1.0 - with / model.rmse_heldout;
            let better = best
                .as_ref()
                .is_none_or(|b| model.rmse_heldout < b.2.rmse_heldout);
            if gain < cfg.min_gain && better {
                best = Some((i, p, model));
            }
        }
        let Some((i, p, model)) = best else {
            sel.final_cov = Some(jc);
            return;
        };
        let name = prep
            .scales
            .rig
            .effect_name(sel.model.effects[i].kind.name());
        let [lo, hi] = p.ci95.unwrap_or([f64::NAN; 2]);
        sel.unphysical.push(Signature {
            kind: "indistinct_from_absent",
            description: format!(
                "{name} was kept by the test, but the 95 % interval of its {} ({lo:.3e} to {hi:.3e} {}) reaches 0, where it is absent, and the model without it does as well on held-out data ({:.4} kPa with it, {:.4} kPa without): not named",
                p.name, p.unit, with, model.rmse_heldout
            ),
            ..Signature::default()
        });
        sel.kept.remove(i);
        sel.model = model;
        if let Some(last) = sel.kept.last_mut() {
            last.model = validate::FittedModel::of(&sel.model);
        }
    }
}

/// Each kept effect's report, its parameters from the final model.
fn effect_reports(prep: &effects::Prepared, sel: &Selection) -> Vec<EffectReport> {
    let formed;
    let jc = match &sel.final_cov {
        Some(jc) => Some(jc),
        None if sel.kept.is_empty() => None,
        None => {
            formed = interval::joint_cov(prep, &sel.model);
            formed.as_ref()
        }
    };
    sel.kept
        .iter()
        .enumerate()
        .map(|(i, step)| EffectReport {
            kind: step.kind,
            name: neutral(prep, sel, i).map_or(step.kind.name(), |n| n.0),
            story: neutral(prep, sel, i).map_or(step.kind.story(), |n| n.1),
            params: interval::effect_params_ci(prep, &sel.model, i, jc),
            rmse_heldout_before: step.heldout_before,
            rmse_heldout_after: step.heldout_after,
            rmse_train_before: step.train_before,
            rmse_train_after: step.train_after,
            p_value: step.test.p_value,
            test: step.test,
            device: step.kind.device_support(),
            runner_up: step.runner_up.clone(),
            alternatives: sel.alternatives.get(i).cloned().unwrap_or_default(),
        })
        .collect()
}

/// The neutral name and story of the final model's `i`-th effect, if its parameters call for one
/// ([`EffectModel::neutral`]) or the rig does ([`EffectModel::generic`] off a syringe rig).
fn neutral(
    prep: &effects::Prepared,
    sel: &Selection,
    i: usize,
) -> Option<(&'static str, &'static str)> {
    neutral_of(prep, sel.model.effects.get(i)?)
}

/// The neutral name and story of effect `e` ([`neutral`]).
fn neutral_of(prep: &effects::Prepared, e: &Effect) -> Option<(&'static str, &'static str)> {
    e.kind.neutral(e, &prep.scales).or_else(|| {
        (prep.scales.rig == Rig::Generic)
            .then(|| e.kind.generic())
            .flatten()
    })
}

/// The held-out residual analysis (step 2) of a model's residual.
fn analyse_heldout(prep: &effects::Prepared, resid: &[f64]) -> ResidualAnalysis {
    let se = &prep.series;
    let sig = analysis::Signals {
        t: &se.t,
        v: &se.v,
        vdot: &se.vdot,
        vddot: &se.vddot,
    };
    let held: Vec<bool> = se.train.iter().map(|b| !b).collect();
    let max_lag = (2.0 / prep.scales.dt).round().max(10.0) as usize;
    analysis::analyse(&sig, resid, &held, max_lag)
}

/// The diagnosis of a finished selection (step 5: what structure remains).
fn report(prep: &effects::Prepared, cfg: &Config, baseline: &Stage, sel: Selection) -> Diagnosis {
    let effects = effect_reports(prep, &sel);
    let analysis_before = analyse_heldout(prep, &baseline.resid);
    let analysis_after = analyse_heldout(prep, &sel.model.resid);
    let sc = &prep.scales;
    let harmonic = |f: f64| sc.cycle_s.map(|_| effects::ripple::cycle_harmonic(f, sc));
    let mut remaining = analysis::signatures(&analysis_after, cfg.whiteness_alpha, harmonic);
    remaining.extend(sel.unphysical);
    let cur = &sel.model;
    let rig = prep.scales.rig;
    let name = |n: &'static str| rig.effect_name(n);
    let mut rejected = sel.rejected;
    rejected.iter_mut().for_each(|r| r.name = name(r.name));
    let mut swaps = sel.swaps;
    for s in &mut swaps {
        s.replaced = name(s.replaced);
        s.by.iter_mut().for_each(|b| *b = name(b));
    }
    let mut effects = effects;
    for e in &mut effects {
        if let Some(r) = &mut e.runner_up {
            r.name = name(r.name);
        }
    }
    Diagnosis {
        rig,
        samples: (prep.train_rows.len(), prep.held_rows.len()),
        significance: format!(
            "kept only if the nested F-test with autocorrelation-corrected effective sample size rejects at alpha = {} AND held-out RMSE falls by at least {:.1} % AND the fit is physical (inertance ≥ 0, hysteresis gap ≥ 0; lags, delays, widths, air, leak > 0 by construction)",
            cfg.alpha,
            100.0 * cfg.min_gain
        ),
        baseline: BaselineReport {
            n: cfg.n,
            m: cfg.m,
            nu: baseline.n_params(),
            rmse_train: baseline.rmse_train,
            rmse_heldout: baseline.rmse_heldout,
        },
        effects,
        final_model: FinalReport {
            nu: cur.n_params(),
            rmse_train: cur.rmse_train,
            rmse_heldout: cur.rmse_heldout,
            uses_measured_pressure: cur.effects.iter().any(|e| e.kind.uses_measured_pressure()),
        },
        remaining,
        rejected_last_round: rejected,
        swaps,
        before: (&analysis_before).into(),
        after: (&analysis_after).into(),
        analysis_before,
        analysis_after,
        final_effects: sel.model.effects.clone(),
        models: std::iter::once(validate::FittedModel::of(baseline))
            .chain(sel.kept.iter().map(|k| k.model.clone()))
            .collect(),
        basis: prep.basis.clone(),
        timing: sel.timing,
    }
}

/// Searches every candidate on `threads` workers. Each worker takes the next candidate from a
/// shared queue, costliest first (longest-processing-time-first scheduling), with each
/// candidate's cost its search time in the previous round (`costs`, updated here; before the first
/// round the output filters, which rebuild and filter the whole design at every trial θ, are
/// guessed costliest, [`EffectModel::cost_guess`]). Dealing the candidates out in a fixed order had left one worker with both
/// filters while the other idled. Each search is independent of the schedule, so the results are
/// too.
fn search_all(
    prep: &effects::Prepared,
    cur: &Stage,
    todo: &[EffectKind],
    cfg: &Config,
    costs: &mut std::collections::HashMap<EffectKind, f64>,
) -> (
    Vec<search::Candidate>,
    std::collections::BTreeMap<&'static str, f64>,
) {
    let threads = cfg.threads.max(1).min(todo.len().max(1));
    let finished = std::sync::atomic::AtomicUsize::new(0);
    let guess = |k: EffectKind| k.cost_guess();
    let mut order: Vec<usize> = (0..todo.len()).collect();
    // Stable sort: ties keep the library's order.
    order.sort_by(|&a, &b| {
        let cost = |i: usize| costs.get(&todo[i]).copied().unwrap_or(guess(todo[i]));
        cost(b).total_cmp(&cost(a))
    });
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<Option<search::Candidate>> = vec![None; todo.len()];
    let mut times = std::collections::BTreeMap::new();
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let j = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&i) = order.get(j) else { break };
                        let start = std::time::Instant::now();
                        let found = search::search(prep, cur, todo[i]);
                        mine.push((i, found, start.elapsed().as_secs_f64()));
                        let done = 1 + finished.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let what = todo[i].name();
                        tell(cfg.progress, Progress::Step { done, what });
                    }
                    mine
                })
            })
            .collect();
        for h in handles {
            if let Ok(results) = h.join() {
                for (i, c, secs) in results {
                    out[i] = c;
                    costs.insert(todo[i], secs);
                    times.insert(todo[i].name(), secs);
                }
            }
        }
    });
    (out.into_iter().flatten().collect(), times)
}

/// Builds the loop's series from a `sysid` data set (its flow, v̈ and held-out mask).
pub fn series_from_dataset(ds: &Dataset) -> Result<Series, DiagnoseError> {
    let mut s = Series::new(
        ds.t.clone(),
        ds.v.clone(),
        ds.vdot.clone(),
        ds.p.clone(),
        ds.heldout.iter().map(|h| !h).collect(),
    )?;
    // With logged flow, v and v̇ are consistent samples of one trajectory: the Hermite
    // acceleration then places short acceleration phases exactly; a derived flow is already a
    // smoothed derivative, so its own v̈ is used.
    s.vddot = match ds.flow_source {
        crate::dataset::FlowSource::Logged => signal::acceleration_hermite(&ds.t, &ds.v, &ds.vdot),
        crate::dataset::FlowSource::Derived { .. } => ds.vddot.clone(),
    };
    s.cycle_s = cycle_period(&ds.t, &ds.cycle).or_else(|| motion_period(&ds.t, &ds.vdot));
    Ok(s)
}

/// The period (s) of a motion that repeats itself, from its flow (the volume may drift when it is
/// the integral of a measured flow): the lag of the first local maximum of the flow's
/// autocorrelation past its first zero crossing that reaches 0.8, within a third of the log (so
/// at least three periods). For logs whose cycle split is irregular (a breath split in two at a
/// pause). The flow is averaged over blocks to at most 2,000 points first; the peak is refined by
/// a parabola through its neighbours. `None` for a motion that does not repeat (the paper's
/// protocols change their rate from cycle to cycle).
pub fn motion_period(t: &[f64], q: &[f64]) -> Option<f64> {
    let n = q.len();
    if n < 16 || t.len() != n {
        return None;
    }
    let m = n.div_ceil(2000);
    let x: Vec<f64> = q
        .chunks(m)
        .filter(|c| c.len() == m)
        .map(|c| c.iter().sum::<f64>() / m as f64)
        .collect();
    let step = (t[n - 1] - t[0]) / (n - 1) as f64 * m as f64;
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let x: Vec<f64> = x.iter().map(|y| y - mean).collect();
    let var: f64 = x.iter().map(|y| y * y).sum();
    if var.is_nan() || var <= 0.0 {
        return None;
    }
    // The unbiased estimate (each lag's mean product over its own pairs, over the variance).
    let len = x.len() as f64;
    let acf = |lag: usize| {
        let s: f64 = x.iter().zip(&x[lag..]).map(|(a, b)| a * b).sum();
        s / (len - lag as f64) / (var / len)
    };
    let last = x.len() / 3;
    let r: Vec<f64> = (0..=last).map(acf).collect();
    let zero = r.iter().position(|&c| c < 0.0)?;
    // The first local maximum past the zero crossing that reaches 0.8 (later ones are its
    // multiples).
    let best =
        (zero.max(1)..last).find(|&k| r[k] >= 0.8 && r[k] >= r[k - 1] && r[k] >= r[k + 1])?;
    let peak = r[best];
    let (a, b, c) = (r[best - 1], peak, r[best + 1]);
    let denom = a - 2.0 * b + c;
    let shift = if denom < 0.0 {
        0.5 * (a - c) / denom
    } else {
        0.0
    };
    Some((best as f64 + shift) * step)
}

/// The mean period of complete cycles (s) when there are at least four and their durations vary
/// by at most 5 % (coefficient of variation): a protocol that repeats one cycle, as a
/// ventilator's breaths. The first and last cycles, which the log may cut, are left out; so are
/// the paper's protocols, whose cycles change length with the flow rate.
pub fn cycle_period(t: &[f64], cycle: &[usize]) -> Option<f64> {
    let mut spans: Vec<(usize, f64, f64)> = Vec::new();
    for (&c, &tk) in cycle.iter().zip(t) {
        match spans.last_mut() {
            Some(last) if last.0 == c => last.2 = tk,
            _ => spans.push((c, tk, tk)),
        }
    }
    // Complete cycles: each runs from its first sample to the next cycle's first.
    let inner: Vec<f64> = spans.windows(2).skip(1).map(|w| w[1].1 - w[0].1).collect();
    if inner.len() < 4 {
        return None;
    }
    let n = inner.len() as f64;
    let mean = inner.iter().sum::<f64>() / n;
    let sd = (inner.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
    (mean > 0.0 && sd <= 0.05 * mean).then_some(mean)
}

/// The shape the loop starts from by default: the polynomial's selection
/// ([`crate::select::poly_shape`], the simplest shape within one standard error of the best
/// cycle-blocked cross-validated error), as `vfp identify` and `vfp export` choose it.
pub fn select_shape(ds: &Dataset) -> Option<(usize, usize)> {
    crate::select::poly_shape(ds)
}

/// Why the loop could not run on a log: the log and chamber, then the reason.
#[derive(Debug, thiserror::Error)]
#[error("{path}, chamber {chamber}: {source}")]
pub struct LogDiagnoseError {
    /// The log as reports name it.
    pub path: String,
    /// The chamber.
    pub chamber: u8,
    /// Why.
    pub source: DiagnoseError,
}

/// The loop on the first requested chamber of a log, as `vfp diagnose` runs it: the baseline
/// shape is `cfg.n`, `cfg.m` when `shape_given`, else the training-AICc selection
/// ([`select_shape`], (3, 2) when the sweep fits nothing).
pub fn diagnose_log(
    data: &crate::dataset::LogData,
    cfg: &Config,
    shape_given: bool,
) -> Result<Diagnosis, LogDiagnoseError> {
    let ds = data.first();
    let wrap = |source| LogDiagnoseError {
        path: data.name(),
        chamber: ds.chamber,
        source,
    };
    let mut series = series_from_dataset(ds).map_err(wrap)?;
    series.rig = cfg.rig.unwrap_or_else(|| Rig::of_log(&data.comments));
    let mut cfg = cfg.clone();
    let t = std::time::Instant::now();
    if !shape_given {
        (cfg.n, cfg.m) = select_shape(ds).unwrap_or((3, 2));
    }
    let shape_s = secs(t);
    let mut d = diagnose(series, &cfg).map_err(wrap)?;
    d.timing.shape_selection = shape_s;
    d.timing.total += shape_s;
    Ok(d)
}

/// The `vfp diagnose --json` document (also the Python package's `diagnose`): the diagnosis at
/// top level (`baseline`, `effects`, `final`, `remaining`, …) plus `log`, `chamber` and `split`
/// of the log's first requested chamber. Non-finite numbers become `null`.
pub fn document(data: &crate::dataset::LogData, d: &Diagnosis) -> serde_json::Value {
    let ds = data.first();
    let mut doc = serde_json::to_value(d).unwrap_or_default();
    if let Some(obj) = doc.as_object_mut() {
        obj.insert("log".into(), data.name().into());
        obj.insert("chamber".into(), ds.chamber.into());
        obj.insert("split".into(), ds.split_description().into());
        obj.insert(
            "units".into(),
            serde_json::to_value(crate::columns::FORMAT_UNITS).unwrap_or_default(),
        );
    }
    doc
}

#[cfg(test)]
mod rig_tests {
    use super::Rig;

    #[test]
    fn the_rig_is_read_from_the_logs_header() {
        let header = |lines: &[&str]| lines.iter().map(|l| l.to_string()).collect::<Vec<_>>();
        assert_eq!(
            Rig::of_log(&header(&["source=vfp record /dev/ttyACM0", "x"])),
            Rig::Syringe
        );
        assert_eq!(
            Rig::of_log(&header(&[
                "source=host-sim (firmware tasks on a simulated plant)"
            ])),
            Rig::Syringe
        );
        // A ventilator's log (data/real's header), and a file with no header.
        assert_eq!(
            Rig::of_log(&header(&[
                "source: github RespiraWorks/Ventilator @ 718bce0"
            ])),
            Rig::Generic
        );
        assert_eq!(Rig::of_log(&[]), Rig::Generic);
        assert_eq!("generic".parse::<Rig>(), Ok(Rig::Generic));
        assert!("pump".parse::<Rig>().is_err());
    }

    #[test]
    fn a_pump_mechanism_is_named_for_the_signal_off_a_syringe_rig() {
        for (name, neutral) in [
            ("pump_ripple", "periodic_in_volume"),
            ("backlash", "dead_band"),
            ("delivery_lag", "input_lag"),
        ] {
            assert_eq!(Rig::Generic.effect_name(name), neutral);
            assert_eq!(Rig::Syringe.effect_name(name), name);
        }
        // Effects whose story is no pump's keep their name anywhere.
        for name in ["hysteresis", "sensor_lag", "air_compliance", "ripple"] {
            assert_eq!(Rig::Generic.effect_name(name), name);
        }
    }
}
