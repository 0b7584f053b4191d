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
//! 4. Forward selection (`forward`; each candidate's search and the tests in [`search`]): add the
//!    candidate that most improves held-out RMSE, keep it only if an autocorrelation-corrected
//!    nested F-test says so *and* the held-out gain clears a stated threshold *and* its fit is
//!    physically possible (inertance ≥ 0, hysteresis gap ≥ 0; searched lags, delays, widths, air
//!    volume and leak are positive by construction); re-tune (`retune`); repeat until nothing
//!    passes. A candidate that passes the test with an impossible fit is reported among the
//!    remaining structure (`unphysical_fit`), not added. Then each kept effect's look-alikes are
//!    tried in its place (`swaps`), and after a swap forward selection goes on; effects a swap
//!    left without a use, and at the end effects indistinct from absent, are taken out
//!    (leave-one-out, `prune`).
//! 5. Whatever structure the final residual still has (Ljung–Box rejects whiteness) is reported by
//!    its signature — lag, input followed, frequency, direction — not forced onto a name
//!    (`report`).
//!
//! [`diagnose`] runs these steps in order, one private module each; `state` holds what they hand
//! on to each other.
//!
//! Errors are free-run (simulation) errors from the inputs v, v̇, v̈ and time, except that the leak
//! and air-compliance effects schedule on the *measured* pressure; a report that contains
//! them says so.

// Index loops over several aligned signals read more plainly than zipped iterators here.
#![allow(clippy::needless_range_loop)]

pub mod alternatives;
pub mod analysis;
mod basis;
pub mod decide;
pub mod effects;
mod forward;
pub(crate) mod inframe;
pub mod interval;
mod lsq;
mod prune;
mod report;
pub mod reshape;
mod retune;
pub mod search;
pub(crate) mod signal;
mod state;
mod swaps;
#[cfg(test)]
mod test_plant;
pub mod validate;

use serde::Serialize;

use crate::dataset::Dataset;
use crate::progress::{tell, Progress};

pub use analysis::{ResidualAnalysis, Signature};
pub use basis::PolyBasis;
pub use effects::{Effect, EffectKind, EffectModel, REGISTRY};
pub use reshape::{ModelCv, ReshapeReport};
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
    /// Whether the rows are the firmware's frames with its logged flow: means of the pressure,
    /// step count and commanded flow over the instants each frame averages
    /// ([`series_from_dataset`] of a log with the firmware's `flags` column and a flow column,
    /// `Dataset::firmware_frames`). The inertance's acceleration is then each frame's mean of it
    /// over the motion rebuilt inside the frames (`inframe::SubMotion::frame_mean_accelerations`),
    /// as the averaging sensor reports `L·v̈`; otherwise (samples at instants, another rig's log,
    /// [`Series::new`], a derived flow) it is `vddot`.
    pub flow_in_frames: bool,
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
    /// The volume's resolution (mm³) where it is a count of motor steps: on the firmware's frames
    /// ([`series_from_dataset`]) its step, [`crate::synth::STEP_MM3`]. The count trails the
    /// motion it counts by up to a step, so no parameter is known better than a shift of half a
    /// step would move it ([`super::residual::interval`]). `None`: no known quantum.
    pub volume_step: Option<f64>,
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
            flow_in_frames: false,
            p,
            train,
            cycle_s: None,
            rig: Rig::Syringe,
            volume_step: None,
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
    /// Whether [`diagnose_dataset`] chooses the baseline's shape again with the effects
    /// ([`reshape`]) when it selected the shape (default: no; `vfp diagnose --reshape`: on the
    /// loop benchmark its gains do not pay for the CPU it adds, the guide has the numbers).
    pub reshape: bool,
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
            reshape: false,
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
    /// Where it has alternatives: a short motion of the firmware's own commands whose log would
    /// tell them apart, with the separation expected ([`decide`]); `vfp diagnose LOG --decide
    /// OTHER.csv` decides on the log recorded with it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub experiment: Option<decide::Experiment>,
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
    /// The first round's leading candidates as searched on the baseline ([`reshape`]).
    #[serde(skip)]
    pub leads: Vec<effects::Effect>,
    /// The baseline's shape chosen again with the effects ([`reshape`]): the shape selected at
    /// the start, the one the final model uses and why; absent when the shape was given, and
    /// when no richer shape was tried again and `Config::reshape` is off.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reshape: Option<ReshapeReport>,
    /// The log's volume range, fastest flow and noise (what an experiment may ask of the rig,
    /// [`decide`]).
    #[serde(skip)]
    pub envelope: decide::Envelope,
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
    /// The shape chosen again with the effects ([`reshape`]): its probe, and the loop from the
    /// other start when it ran twice (the loop whose model was not kept, or the first one).
    pub reshape: f64,
    /// The whole loop.
    pub total: f64,
    /// Each round of forward selection in order (rounds after a swap included).
    pub rounds: Vec<RoundTiming>,
}

impl Timings {
    /// The stages in the loop's order, each with its seconds and its name in the reports
    /// (`vfp diagnose --timings`, `vfp bench-loop`); `total` not included.
    pub fn stages(&self) -> [(&'static str, f64); 10] {
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
            ("shape with effects", self.reshape),
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

/// Share of a kept effect's held-out gain another candidate of its round must reach to be its
/// look-alike: one that explains most of the same structure ([`swaps`] tries each in the kept
/// effect's place; [`alternatives`] reports those the held-out data cannot tell from it).
pub(crate) const LOOK_ALIKE_GAIN: f64 = 0.5;

/// The name effect `e` is reported under: its neutral name where its parameters or the rig call
/// for one ([`neutral_of`]), else its own.
pub(crate) fn report_name(prep: &effects::Prepared, e: &Effect) -> &'static str {
    neutral_of(prep, e).map_or(e.kind.name(), |n| n.0)
}

/// The neutral name and story of effect `e`, if its parameters call for one
/// ([`EffectModel::neutral`]) or the rig does ([`EffectModel::generic`] off a syringe rig).
fn neutral_of(prep: &effects::Prepared, e: &Effect) -> Option<(&'static str, &'static str)> {
    e.kind.neutral(e, &prep.scales).or_else(|| {
        (prep.scales.rig == Rig::Generic)
            .then(|| e.kind.generic())
            .flatten()
    })
}

/// Runs the whole loop on one series, its steps in order: the baseline fit; forward selection
/// (`forward`) and the swaps of look-alikes (`swaps`) until no swap is left to make; the effects
/// indistinct from absent taken out (`prune`); each effect's alternatives ([`alternatives`]); the
/// report (`report`).
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
    let mut sel = state::Findings::new(&baseline);
    sel.timing.baseline = secs(started);
    // After a swap the replaced kind is out of the running, and forward selection goes on from
    // the swapped model.
    let mut banned: Vec<EffectKind> = Vec::new();
    loop {
        forward::rounds(&prep, cfg, &mut sel, &banned);
        let Some(swap) = swaps::best_swap(&prep, cfg, &mut sel, &banned) else {
            break;
        };
        banned.push(swap.out);
        swaps::apply_swap(&prep, cfg, &baseline, &mut sel, swap);
    }
    prune::drop_absent(&prep, cfg, &mut sel);
    say("alternatives");
    let t = std::time::Instant::now();
    sel.alternatives = alternatives::alternatives(
        &prep,
        &alternatives::Inputs {
            searched: &sel.searched,
            model: &sel.model,
            leads: sel.kept.iter().map(|k| &k.leads).collect(),
            names: sel
                .model
                .effects
                .iter()
                .map(|e| report_name(&prep, e))
                .collect(),
            replaced: &sel.replaced,
            pair_trials: &sel.pair_trials,
        },
    );
    sel.timing.alternatives = secs(t);
    say("residual analysis");
    let t = std::time::Instant::now();
    let mut d = report::report(&prep, cfg, &baseline, sel);
    d.timing.residual_analysis = secs(t);
    // The experiments that would decide between a kept effect and its alternatives: counted
    // with the alternatives, whose follow-up they are.
    let t = std::time::Instant::now();
    d.envelope = decide::Envelope::of(&prep.series, d.final_model.rmse_heldout);
    decide::attach(&mut d);
    d.timing.alternatives += secs(t);
    d.timing.total = secs(started);
    tell(cfg.progress, Progress::Done);
    Ok(d)
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
    s.flow_in_frames =
        ds.firmware_frames && matches!(ds.flow_source, crate::dataset::FlowSource::Logged);
    s.cycle_s = cycle_period(&ds.t, &ds.cycle).or_else(|| motion_period(&ds.t, &ds.vdot));
    s.volume_step = ds.firmware_frames.then_some(crate::synth::STEP_MM3);
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
/// shape is `cfg.n`, `cfg.m` when `shape_given`, else selected ([`diagnose_dataset`]).
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
    let mut cfg = cfg.clone();
    cfg.rig = Some(cfg.rig.unwrap_or_else(|| Rig::of_log(&data.comments)));
    diagnose_dataset(ds, &cfg, shape_given).map_err(wrap)
}

/// The loop on a data set ([`series_from_dataset`]; the rig `cfg.rig`, else this project's
/// syringe rig). The baseline shape is `cfg.n`, `cfg.m` when `shape_given`; else the
/// selection's ([`select_shape`], (3, 2) when the sweep fits nothing), and then chosen again
/// with the effects ([`reshape`]): where a richer shape with the loop's effects is the
/// cross-validated choice (always tried), or with `cfg.reshape` a simpler shape with an effect,
/// the loop runs again from it, and the two outcomes are compared by the same rule
/// ([`Diagnosis::reshape`] says which was kept and why; absent where the richer probe kept the
/// selected shape and `cfg.reshape` is off).
pub fn diagnose_dataset(
    ds: &Dataset,
    cfg: &Config,
    shape_given: bool,
) -> Result<Diagnosis, DiagnoseError> {
    let mut series = series_from_dataset(ds)?;
    series.rig = cfg.rig.unwrap_or_default();
    let mut cfg = cfg.clone();
    let t = std::time::Instant::now();
    let selection = if shape_given {
        None
    } else {
        crate::select::poly_shape_scores(ds)
    };
    if !shape_given {
        (cfg.n, cfg.m) = selection.as_ref().map_or((3, 2), |s| s.0);
    }
    let shape_s = secs(t);
    // The richer probe does not look at logs over `reshape::MAX_SAMPLES`; `--reshape` reports
    // that it did not.
    let keep_series = selection
        .as_ref()
        .filter(|_| cfg.reshape || series.len() <= reshape::MAX_SAMPLES)
        .map(|_| series.clone());
    let mut d = diagnose(series, &cfg)?;
    d.timing.shape_selection = shape_s;
    d.timing.total += shape_s;
    if let (Some(series), Some((shape, blocks, scores))) = (keep_series, selection) {
        let Some(setup) = reshape::CvSetup::new(blocks, &series) else {
            return Ok(d);
        };
        let again = ShapeAgain {
            series: &series,
            cfg: &cfg,
            shape,
            setup: &setup,
            scores: &scores,
        };
        d = again.richer(d)?;
        if cfg.reshape && d.reshape.is_none() {
            d = again.simpler(d)?;
        }
    }
    Ok(d)
}

/// What choosing the baseline's shape again with the effects ([`reshape`]) works from: the
/// series, the configuration, the selected shape, the selection's blocks and its sweep's scores.
struct ShapeAgain<'a> {
    series: &'a Series,
    cfg: &'a Config,
    shape: (usize, usize),
    setup: &'a reshape::CvSetup,
    scores: &'a [crate::select::CvScore],
}

/// The loop `d` kept as it is after a probe of `s` seconds that chose no other shape, with the
/// probe's report where it makes one (the richer probe makes none).
fn stayed(mut d: Diagnosis, report: Option<ReshapeReport>, s: f64) -> Diagnosis {
    if report.is_some() {
        d.reshape = report;
    }
    d.timing.reshape += s;
    d.timing.total += s;
    d
}

impl ShapeAgain<'_> {
    /// The shape chosen again with the loop's effects among richer shapes ([`reshape`], "Richer
    /// shapes") after the loop `d` from `shape`: where the rule prefers a richer shape with them, the
    /// loop runs again from it. `d` unchanged (no report) where the rule keeps `shape`.
    fn richer(&self, d: Diagnosis) -> Result<Diagnosis, DiagnoseError> {
        let (series, cfg, shape, setup, scores) =
            (self.series, self.cfg, self.shape, self.setup, self.scores);
        let t = std::time::Instant::now();
        let probe = reshape::probe_richer(series, setup, shape, scores, &d.final_effects);
        let probe_s = secs(t);
        let Some((second, numbers)) = probe else {
            return Ok(stayed(d, None, probe_s));
        };
        tell(
            cfg.progress,
            Progress::Stage {
                what: "the loop again from a richer shape",
                total: 0,
            },
        );
        self.second_loop(d, second, numbers, probe_s)
    }

    /// The shape chosen again with the effects among simpler shapes ([`reshape`], `Config::reshape`)
    /// after the loop `d` from `shape`.
    fn simpler(&self, d: Diagnosis) -> Result<Diagnosis, DiagnoseError> {
        let (series, cfg, shape, setup, scores) =
            (self.series, self.cfg, self.shape, self.setup, self.scores);
        let t = std::time::Instant::now();
        let say = |what: &str| tell(cfg.progress, Progress::Stage { what, total: 0 });
        say("the baseline's shape with the effects");
        let probe = reshape::probe(series, setup, shape, scores, &d.final_effects, &d.leads);
        let (second, numbers) = match probe {
            reshape::Probe::Stay(report) => return Ok(stayed(d, Some(report), secs(t))),
            reshape::Probe::Retry {
                shape: second,
                probe,
                effects,
                kept,
            } => {
                if !kept
                    && !effects
                        .iter()
                        .all(|e| reshape::lead_passes(series, cfg, second, e))
                {
                    let verdict = format!(
                        "kept: the first round's lead the probe chose with ({}, {}) does not pass the loop's test there",
                        second.0, second.1
                    );
                    let report = ReshapeReport {
                        selected: shape,
                        used: shape,
                        verdict,
                        second_start: None,
                        probe,
                        outcomes: Vec::new(),
                    };
                    return Ok(stayed(d, Some(report), secs(t)));
                }
                (second, probe)
            }
        };
        let probe_s = secs(t);
        self.second_loop(d, second, numbers, probe_s)
    }

    /// The loop run again from `second` after the loop `d` from `shape`, and the two final models
    /// compared by the selection's rule ([`reshape::compare`]): the one it chooses is returned, with
    /// the report (`numbers` the probe's models; `probe_s` the probe's time).
    fn second_loop(
        &self,
        d: Diagnosis,
        second: (usize, usize),
        numbers: Vec<ModelCv>,
        probe_s: f64,
    ) -> Result<Diagnosis, DiagnoseError> {
        let (series, cfg, shape, setup) = (self.series, self.cfg, self.shape, self.setup);
        let mut cfg2 = cfg.clone();
        (cfg2.n, cfg2.m) = second;
        let d2 = diagnose(series.clone(), &cfg2)?;
        let t = std::time::Instant::now();
        let compared = reshape::compare(
            series,
            setup,
            shape,
            &d.final_effects,
            second,
            &d2.final_effects,
        );
        let (take, outcomes) = compared.unwrap_or((false, Vec::new()));
        let compare_s = secs(t);
        let verdict = if take {
            format!(
            "changed: from ({}, {}) the loop ended on a model the cross-validated rule prefers to the one from ({}, {})",
            second.0, second.1, shape.0, shape.1
        )
        } else {
            format!(
            "kept: the loop from ({}, {}) did not end on a model the cross-validated rule prefers",
            second.0, second.1
        )
        };
        // Time the step spent before (the richer probe): counted once, in the step's time.
        let mut d = d;
        let earlier = d.timing.reshape;
        d.timing.reshape = 0.0;
        d.timing.total -= earlier;
        let (mut kept, other) = if take { (d2, d) } else { (d, d2) };
        let used = (kept.baseline.n, kept.baseline.m);
        kept.reshape = Some(ReshapeReport {
            selected: shape,
            used,
            verdict,
            second_start: Some(second),
            probe: numbers,
            outcomes,
        });
        // The loop whose model was not kept is part of the step's time; the first loop's shape
        // selection stays where it was.
        let extra =
            earlier + probe_s + compare_s + other.timing.total - other.timing.shape_selection;
        if take {
            kept.timing.shape_selection = other.timing.shape_selection;
            kept.timing.total += other.timing.shape_selection;
        }
        kept.timing.reshape = extra;
        kept.timing.total += extra;
        Ok(kept)
    }
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
