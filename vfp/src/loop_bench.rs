//! Scoring of the residual loop's benchmark (`vfp bench-loop`): what each rig planted against what
//! the loop named, summed into a confusion matrix, precision, recall by effect size, parameter
//! errors, the share of rigs ending near the noise, false alarms and CPU; rendered as markdown.
//!
//! # Matching
//! A planted effect is **found** when the loop names the kind it corresponds to
//! ([`PlantedResult::expects`]). A named effect is **right** when it is the expected name of an
//! effect planted in its rig. Precision = right named / all named (clean rigs included); recall =
//! found / planted. Counting alternatives (issue 34), a named effect is also right when every
//! effect of one of the alternatives the loop could not tell from it was planted ("cannot tell
//! apart, the truth among the alternatives"); both precisions are reported, with how often
//! "cannot tell" was said, the mean number of alternatives per named effect and the share of
//! right names right only through them, so that listing alternatives everywhere shows.
//!
//! # Confusion matrix
//! Rows: planted kinds, `clean` (a rig without effects) and `(extra)`; columns: the loop's names
//! and `nothing`. Each planted effect adds one to (its kind, its expected name) when found. When
//! missed, it adds one to (its kind, n) for every named effect n of its rig that matches nothing
//! planted (the look-alike that took its place), or to (its kind, `nothing`) when there is none.
//! A clean rig adds one to (`clean`, n) for each name, or to (`clean`, `nothing`). A named effect
//! matching nothing planted in a rig where every planted effect was found adds to (`(extra)`, n).

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde::Serialize;

/// Bins of the oracle's held-out gain (relative RMSE reduction) for recall, lower edges.
pub const GAIN_BINS: [f64; 4] = [0.0, 0.01, 0.05, 0.20];

/// Bins of the oracle's RMS of the effect relative to σ, lower edges.
pub const RMS_BINS: [f64; 4] = [0.0, 0.3, 1.0, 3.0];

/// A parameter the plant and the loop both state, with the same meaning.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ParamCompare {
    /// The loop's parameter name.
    pub name: String,
    /// The plant's value, in the loop's unit.
    pub truth: f64,
    /// The loop's value (absent when the effect was not named).
    pub named: Option<f64>,
    /// The loop's 95 % interval (absent when not named or without an interval).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub ci95: Option<[f64; 2]>,
}

impl ParamCompare {
    /// (named − truth) / |truth|.
    pub fn relative_error(&self) -> Option<f64> {
        self.named
            .filter(|_| self.truth != 0.0)
            .map(|n| (n - self.truth) / self.truth.abs())
    }
}

/// One planted effect of a rig and what became of it.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct PlantedResult {
    /// host-sim's kind (`air`, `hysteresis`, …, `delivery-lag`).
    pub kind: String,
    /// The loop's name for it.
    pub expects: String,
    /// Main parameter in host-sim's units (`host_sim::rigs::Planted::size`).
    pub size: f64,
    /// Size relative to host-sim's preset.
    pub relative_size: f64,
    /// Oracle: RMS over the held-out frames of the sensor output with the effect minus without it
    /// (mean removed), over σ.
    pub oracle_rms_sigma: f64,
    /// Oracle: held-out gain of the true effect as a known regressor (relative RMSE reduction of
    /// the baseline plus every true effect against the same without this one).
    pub oracle_gain: f64,
    /// Whether the loop named `expects`.
    pub found: bool,
    /// Planted in host-sim's other form of the kind (`vfp bench-loop --forms`).
    pub other_form: bool,
    /// Parameters compared (none for an effect in its other form).
    pub params: Vec<ParamCompare>,
}

/// One named effect with its parameters.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct NamedResult {
    /// The loop's name.
    pub name: String,
    /// Parameters (name, value).
    pub params: Vec<(String, f64)>,
    /// Whether the 95 % interval of the effect's presence parameter (its gap, time constant,
    /// volume, amplitude: `EffectModel::presence`) reaches the value that means "absent", 0.
    pub reaches_absent: bool,
    /// The explanations the loop could not tell from it on held-out data (issue 34), each as the
    /// names of its effects (one, or two together).
    #[serde(skip_serializing_if = "Vec::is_empty", default)]
    pub alternatives: Vec<Vec<String>>,
}

impl NamedResult {
    /// The name, with the alternatives the loop could not tell from it: `sensor_lag (or
    /// delivery_lag | air_compliance + sensor_lag)`.
    pub fn label(&self) -> String {
        if self.alternatives.is_empty() {
            return self.name.clone();
        }
        let alts: Vec<String> = self.alternatives.iter().map(|a| a.join(" + ")).collect();
        format!("{} (or {})", self.name, alts.join(" | "))
    }

    /// Whether the name is right in `rig`: the expected name of an effect planted there.
    fn right(&self, rig: &RigResult) -> bool {
        rig.planted.iter().any(|p| p.expects == self.name)
    }

    /// Whether the name is right counting its alternatives: right, or one of its alternatives
    /// has every one of its effects planted in `rig` (the truth among the alternatives).
    fn right_with_alternatives(&self, rig: &RigResult) -> bool {
        self.right(rig)
            || self.alternatives.iter().any(|a| {
                !a.is_empty()
                    && a.iter()
                        .all(|n| rig.planted.iter().any(|p| &p.expects == n))
            })
    }
}

/// One rig's outcome.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RigResult {
    /// Index within the seed.
    pub index: usize,
    /// What it was (`rig 3: sba1 protocol 9120 frames, air + leak`).
    pub label: String,
    /// Frames of chamber 0 the loop saw.
    pub samples: usize,
    /// Noise σ of the logged pressure (truth: logged minus what the sensor element saw), kPa.
    pub sigma_kpa: f64,
    /// Effects planted.
    pub planted: Vec<PlantedResult>,
    /// Effects named, in the loop's order.
    pub named: Vec<NamedResult>,
    /// The baseline polynomial's shape (n, m) the loop selected.
    pub baseline_shape: (usize, usize),
    /// Baseline held-out RMSE, kPa.
    pub baseline_rmse_kpa: f64,
    /// Final held-out RMSE, kPa.
    pub final_rmse_kpa: f64,
    /// Held-out RMSE of the oracle's complete model (the baseline shape plus every effect's true
    /// contribution), kPa: what the loop could reach with every effect exactly right.
    pub oracle_rmse_kpa: f64,
    /// Process CPU seconds of the diagnosis (every thread; `None` where unavailable).
    pub cpu_s: Option<f64>,
    /// The loop's stages, wall-clock seconds (`vfp diagnose --timings`).
    pub stages_s: BTreeMap<String, f64>,
    /// Why the rig could not be scored (simulation fault, unreadable log, failed diagnosis).
    pub error: Option<String>,
}

impl RigResult {
    /// Final held-out RMSE over σ.
    pub fn final_over_sigma(&self) -> f64 {
        self.final_rmse_kpa / self.sigma_kpa
    }

    /// Whether planted effect `p` was found counting alternatives: found, or a named effect that
    /// is not planted lists an alternative holding `p` whose effects are all planted ("cannot
    /// tell apart, the truth among the alternatives", as [`NamedResult::right_with_alternatives`]
    /// counts it for precision).
    fn found_with_alternatives(&self, p: &PlantedResult) -> bool {
        p.found
            || self.named.iter().any(|n| {
                !n.right(self)
                    && n.alternatives.iter().any(|a| {
                        a.contains(&p.expects)
                            && a.iter()
                                .all(|m| self.planted.iter().any(|q| &q.expects == m))
                    })
            })
    }

    /// Named effects that match nothing planted.
    fn unmatched_named(&self) -> Vec<&str> {
        self.named
            .iter()
            .map(|n| n.name.as_str())
            .filter(|n| !self.planted.iter().any(|p| p.expects == *n))
            .collect()
    }
}

/// Found over planted in one bin.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RecallBin {
    /// Lower edge.
    pub from: f64,
    /// Upper edge (infinite for the last).
    pub to: f64,
    /// Planted effects in the bin.
    pub planted: usize,
    /// Of them found.
    pub found: usize,
}

/// Errors of one parameter over the rigs where its effect was named.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ParamErrors {
    /// Planted kind.
    pub kind: String,
    /// The loop's parameter.
    pub param: String,
    /// Rigs compared.
    pub n: usize,
    /// Median relative error (signed).
    pub median_relative: f64,
    /// Median |relative error|.
    pub median_abs_relative: f64,
    /// Largest |relative error|.
    pub worst_abs_relative: f64,
}

/// Coverage of the 95 % intervals of one parameter (or of all: `param` = `all`) over the named
/// effects whose kind was planted.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Coverage {
    /// Planted kind (`all` for the total).
    pub kind: String,
    /// The loop's parameter.
    pub param: String,
    /// Named effects with an interval on it.
    pub n: usize,
    /// Of them, intervals containing the planted value.
    pub covered: usize,
}

impl Coverage {
    /// covered / n.
    pub fn share(&self) -> f64 {
        ratio(self.covered, self.n)
    }
}

/// Precision and recall had every named effect whose presence interval reaches 0 not been named
/// (`NamedResult::reaches_absent`; issue 34's rule, measured here, not applied by the loop).
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct AbsentRule {
    /// Named effects the rule would drop, and of them right.
    pub dropped: (usize, usize),
    /// Precision with the rule.
    pub precision: f64,
    /// Named, named right with the rule.
    pub named: (usize, usize),
    /// Recall over planted effects with oracle gain ≥ 5 % with the rule: (planted, found).
    pub gain_5pct: (usize, usize),
    /// Recall over all planted effects with the rule: (planted, found).
    pub all: (usize, usize),
    /// Clean rigs with a named effect left.
    pub false_alarm_rigs: usize,
}

/// Planted kind × named kind.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Confusion {
    /// Row labels.
    pub rows: Vec<String>,
    /// Column labels.
    pub cols: Vec<String>,
    /// counts[row][col].
    pub counts: Vec<Vec<usize>>,
}

impl Confusion {
    /// Count at (row, col) by label (0 for labels not present).
    pub fn get(&self, row: &str, col: &str) -> usize {
        match (
            self.rows.iter().position(|r| r == row),
            self.cols.iter().position(|c| c == col),
        ) {
            (Some(r), Some(c)) => self.counts[r][c],
            _ => 0,
        }
    }
}

/// CPU of the diagnoses.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct CpuSummary {
    /// Rigs with a figure.
    pub rigs: usize,
    /// Median per rig, s.
    pub median_s: f64,
    /// Worst rig, s.
    pub worst_s: f64,
    /// All rigs, s.
    pub total_s: f64,
    /// Each stage of the loop summed over the rigs, wall-clock s.
    pub stages_wall_s: BTreeMap<String, f64>,
}

/// The benchmark's figures.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Summary {
    /// Rigs drawn.
    pub rigs: usize,
    /// Rigs that could not be scored (left out of every figure below).
    pub failed: usize,
    /// Clean rigs scored.
    pub clean_rigs: usize,
    /// Clean rigs on which anything was named.
    pub false_alarm_rigs: usize,
    /// Effects named on clean rigs.
    pub false_alarm_effects: usize,
    /// Effects planted.
    pub planted: usize,
    /// Of them found.
    pub found: usize,
    /// Effects named.
    pub named: usize,
    /// Of them right.
    pub named_right: usize,
    /// named_right / named (1 when nothing was named).
    pub precision: f64,
    /// Of the named effects, right counting their alternatives: the name, or every effect of
    /// one of its alternatives, planted ("cannot tell apart, the truth among the alternatives").
    pub named_right_with_alternatives: usize,
    /// named_right_with_alternatives / named (1 when nothing was named).
    pub precision_with_alternatives: f64,
    /// Named effects reported with at least one alternative ("cannot tell apart").
    pub named_with_alternatives: usize,
    /// Alternatives listed per named effect, mean.
    pub mean_alternatives: f64,
    /// Of the named effects right counting alternatives, the share right only through them.
    pub right_only_through_alternatives: f64,
    /// found / planted (1 when nothing was planted).
    pub recall: f64,
    /// Recall over planted effects whose oracle gain is at least 5 %.
    pub recall_gain_5pct: f64,
    /// Planted effects whose oracle gain is at least 5 %, and of them found.
    pub gain_5pct: (usize, usize),
    /// Of the planted effects whose oracle gain is at least 5 %, found counting alternatives:
    /// found, or the truth among the alternatives of a name that stands in its place
    /// (`RigResult::found_with_alternatives`). Not the recall, which counts the name.
    pub found_gain_5pct_with_alternatives: usize,
    /// found_gain_5pct_with_alternatives over the planted effects of gain ≥ 5 %.
    pub recall_gain_5pct_with_alternatives: f64,
    /// Rigs scored (not failed), and of them ending ≤ 1.10 σ.
    pub within_1_10: (usize, usize),
    /// Recall by planted kind: (kind, planted, found).
    pub recall_by_kind: Vec<(String, usize, usize)>,
    /// Recall by the oracle's held-out gain ([`GAIN_BINS`]).
    pub recall_by_gain: Vec<RecallBin>,
    /// Recall by the oracle's RMS over σ ([`RMS_BINS`]).
    pub recall_by_rms: Vec<RecallBin>,
    /// Share of rigs whose final held-out RMSE is ≤ 1.10 σ.
    pub share_within_1_10: f64,
    /// Share of rigs whose oracle's complete model ([`RigResult::oracle_rmse_kpa`]) ends ≤ 1.10 σ:
    /// where the instrument itself can tell a loop short of the noise from a rig that cannot
    /// reach it.
    pub oracle_within_1_10: f64,
    /// The confusion matrix.
    pub confusion: Confusion,
    /// Parameter errors.
    pub params: Vec<ParamErrors>,
    /// Coverage of the 95 % intervals by planted kind and parameter, then over all (last).
    pub coverage: Vec<Coverage>,
    /// The rule "an effect whose interval reaches its absent value is not named", as it would
    /// have scored.
    pub absent_rule: AbsentRule,
    /// CPU.
    pub cpu: CpuSummary,
}

/// [`AbsentRule`] over the scored rigs.
fn absent_rule(ok: &[&RigResult]) -> AbsentRule {
    let mut r = AbsentRule::default();
    let (mut named, mut right) = (0, 0);
    for rig in ok {
        let kept: Vec<&NamedResult> = rig.named.iter().filter(|n| !n.reaches_absent).collect();
        for n in rig.named.iter().filter(|n| n.reaches_absent) {
            r.dropped.0 += 1;
            r.dropped.1 += usize::from(rig.planted.iter().any(|p| p.expects == n.name));
        }
        named += kept.len();
        right += kept
            .iter()
            .filter(|n| rig.planted.iter().any(|p| p.expects == n.name))
            .count();
        if rig.planted.is_empty() && !kept.is_empty() {
            r.false_alarm_rigs += 1;
        }
        for p in &rig.planted {
            let found = p.found && kept.iter().any(|n| n.name == p.expects);
            r.all.0 += 1;
            r.all.1 += usize::from(found);
            if p.oracle_gain >= 0.05 {
                r.gain_5pct.0 += 1;
                r.gain_5pct.1 += usize::from(found);
            }
        }
    }
    r.named = (named, right);
    r.precision = ratio(right, named);
    r
}

fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 {
        1.0
    } else {
        a as f64 / b as f64
    }
}

fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

fn bins(edges: &[f64], rigs: &[&RigResult], key: impl Fn(&PlantedResult) -> f64) -> Vec<RecallBin> {
    let mut out: Vec<RecallBin> = edges
        .iter()
        .enumerate()
        .map(|(i, &from)| RecallBin {
            from,
            to: edges.get(i + 1).copied().unwrap_or(f64::INFINITY),
            ..RecallBin::default()
        })
        .collect();
    for p in rigs.iter().flat_map(|r| &r.planted) {
        let x = key(p);
        // Below the first edge (a negative gain) counts in the first bin.
        let i = out.iter().rposition(|b| x >= b.from).unwrap_or(0);
        out[i].planted += 1;
        out[i].found += usize::from(p.found);
    }
    out
}

/// Sums the rigs (those with an `error` are counted as failed and left out).
pub fn summarise(results: &[RigResult]) -> Summary {
    let ok: Vec<&RigResult> = results.iter().filter(|r| r.error.is_none()).collect();
    let mut cells: BTreeMap<(String, String), usize> = BTreeMap::new();
    let mut add = |row: &str, col: &str| *cells.entry((row.into(), col.into())).or_default() += 1;
    let (mut planted, mut found, mut named, mut right) = (0, 0, 0, 0);
    let (mut right_alt, mut with_alt, mut alts) = (0, 0, 0);
    let (mut clean, mut alarm_rigs, mut alarm_effects) = (0, 0, 0);
    for r in &ok {
        let unmatched = r.unmatched_named();
        named += r.named.len();
        right += r.named.len() - unmatched.len();
        for n in &r.named {
            right_alt += usize::from(n.right_with_alternatives(r));
            with_alt += usize::from(!n.alternatives.is_empty());
            alts += n.alternatives.len();
        }
        if r.planted.is_empty() {
            clean += 1;
            alarm_rigs += usize::from(!r.named.is_empty());
            alarm_effects += r.named.len();
            if r.named.is_empty() {
                add("clean", "nothing");
            }
            for n in &r.named {
                add("clean", &n.name);
            }
            continue;
        }
        for p in &r.planted {
            planted += 1;
            if p.found {
                found += 1;
                add(&p.kind, &p.expects);
            } else if unmatched.is_empty() {
                add(&p.kind, "nothing");
            } else {
                for u in &unmatched {
                    add(&p.kind, u);
                }
            }
        }
        if r.planted.iter().all(|p| p.found) {
            for u in &unmatched {
                add("(extra)", u);
            }
        }
    }
    let mut rows: Vec<String> = cells.keys().map(|k| k.0.clone()).collect();
    rows.dedup();
    // Planted kinds first, then `clean` and `(extra)`.
    rows.sort_by_key(|r| (r == "clean" || r == "(extra)", r == "(extra)", r.clone()));
    let mut cols: Vec<String> = cells.keys().map(|k| k.1.clone()).collect();
    cols.sort();
    cols.dedup();
    cols.retain(|c| c != "nothing");
    cols.push("nothing".into());
    let counts = rows
        .iter()
        .map(|r| {
            cols.iter()
                .map(|c| cells.get(&(r.clone(), c.clone())).copied().unwrap_or(0))
                .collect()
        })
        .collect();

    let mut by_kind: BTreeMap<String, (usize, usize)> = BTreeMap::new();
    for p in ok.iter().flat_map(|r| &r.planted) {
        let e = by_kind.entry(p.kind.clone()).or_default();
        e.0 += 1;
        e.1 += usize::from(p.found);
    }
    let strong: Vec<&PlantedResult> = ok
        .iter()
        .flat_map(|r| &r.planted)
        .filter(|p| p.oracle_gain >= 0.05)
        .collect();
    let strong_found = strong.iter().filter(|p| p.found).count();
    let strong_found_alt = ok
        .iter()
        .flat_map(|r| r.planted.iter().map(move |p| (r, p)))
        .filter(|(r, p)| p.oracle_gain >= 0.05 && r.found_with_alternatives(p))
        .count();

    let mut errs: BTreeMap<(String, String), Vec<f64>> = BTreeMap::new();
    for p in ok.iter().flat_map(|r| &r.planted) {
        for c in &p.params {
            if let Some(e) = c.relative_error() {
                errs.entry((p.kind.clone(), c.name.clone()))
                    .or_default()
                    .push(e);
            }
        }
    }
    let params = errs
        .into_iter()
        .map(|((kind, param), mut e)| {
            let mut abs: Vec<f64> = e.iter().map(|x| x.abs()).collect();
            ParamErrors {
                kind,
                param,
                n: e.len(),
                median_relative: median(&mut e),
                worst_abs_relative: abs.iter().copied().fold(0.0, f64::max),
                median_abs_relative: median(&mut abs),
            }
        })
        .collect();

    let mut cov: BTreeMap<(String, String), (usize, usize)> = BTreeMap::new();
    for p in ok.iter().flat_map(|r| &r.planted) {
        for c in &p.params {
            if let (Some(_), Some([lo, hi])) = (c.named, c.ci95) {
                let e = cov.entry((p.kind.clone(), c.name.clone())).or_default();
                e.0 += 1;
                e.1 += usize::from(lo <= c.truth && c.truth <= hi);
            }
        }
    }
    let mut coverage: Vec<Coverage> = cov
        .into_iter()
        .map(|((kind, param), (n, covered))| Coverage {
            kind,
            param,
            n,
            covered,
        })
        .collect();
    coverage.push(Coverage {
        kind: "all".into(),
        param: "all".into(),
        n: coverage.iter().map(|c| c.n).sum(),
        covered: coverage.iter().map(|c| c.covered).sum(),
    });
    let absent_rule = absent_rule(&ok);

    let mut cpu: Vec<f64> = ok.iter().filter_map(|r| r.cpu_s).collect();
    let mut stages: BTreeMap<String, f64> = BTreeMap::new();
    for r in &ok {
        for (k, v) in &r.stages_s {
            *stages.entry(k.clone()).or_default() += v;
        }
    }
    let within = ok.iter().filter(|r| r.final_over_sigma() <= 1.10).count();
    let oracle_within = ok
        .iter()
        .filter(|r| r.oracle_rmse_kpa / r.sigma_kpa <= 1.10)
        .count();
    Summary {
        rigs: results.len(),
        failed: results.len() - ok.len(),
        clean_rigs: clean,
        false_alarm_rigs: alarm_rigs,
        false_alarm_effects: alarm_effects,
        planted,
        found,
        named,
        named_right: right,
        precision: ratio(right, named),
        named_right_with_alternatives: right_alt,
        precision_with_alternatives: ratio(right_alt, named),
        named_with_alternatives: with_alt,
        mean_alternatives: if named == 0 {
            0.0
        } else {
            alts as f64 / named as f64
        },
        right_only_through_alternatives: if right_alt == 0 {
            0.0
        } else {
            (right_alt - right) as f64 / right_alt as f64
        },
        recall: ratio(found, planted),
        recall_gain_5pct: ratio(strong_found, strong.len()),
        gain_5pct: (strong.len(), strong_found),
        found_gain_5pct_with_alternatives: strong_found_alt,
        recall_gain_5pct_with_alternatives: ratio(strong_found_alt, strong.len()),
        within_1_10: (ok.len(), within),
        recall_by_kind: by_kind.into_iter().map(|(k, (n, f))| (k, n, f)).collect(),
        recall_by_gain: bins(&GAIN_BINS, &ok, |p| p.oracle_gain),
        recall_by_rms: bins(&RMS_BINS, &ok, |p| p.oracle_rms_sigma),
        share_within_1_10: ratio(within, ok.len()),
        oracle_within_1_10: ratio(oracle_within, ok.len()),
        confusion: Confusion { rows, cols, counts },
        params,
        coverage,
        absent_rule,
        cpu: CpuSummary {
            rigs: cpu.len(),
            worst_s: cpu.iter().copied().fold(f64::NAN, f64::max),
            total_s: cpu.iter().sum(),
            median_s: median(&mut cpu),
            stages_wall_s: stages,
        },
    }
}

/// Thresholds of the CI gate (`bench/loop-gate.toml`) and the subset they hold for.
#[derive(Clone, Debug, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Gate {
    /// Rigs of the subset.
    pub rigs: usize,
    /// Its seed.
    pub seed: u64,
    /// Length range of its logs, frames per chamber.
    pub samples: [usize; 2],
    /// Least precision.
    pub min_precision: f64,
    /// Least recall over effects whose oracle gain is ≥ 5 %.
    pub min_recall_gain_5pct: f64,
    /// Most clean rigs with anything named.
    pub max_false_alarm_rigs: usize,
    /// Least share of rigs ending ≤ 1.10 σ.
    pub min_share_within_1_10: f64,
    /// Most rigs that fail to simulate or diagnose.
    pub max_failed: usize,
}

impl Gate {
    /// Every threshold the summary misses, in words (empty: the gate passes).
    pub fn check(&self, s: &Summary) -> Vec<String> {
        let mut out = Vec::new();
        if s.precision < self.min_precision {
            out.push(format!(
                "precision {:.3} < {}",
                s.precision, self.min_precision
            ));
        }
        if s.recall_gain_5pct < self.min_recall_gain_5pct {
            out.push(format!(
                "recall (oracle gain ≥ 5 %) {:.3} < {}",
                s.recall_gain_5pct, self.min_recall_gain_5pct
            ));
        }
        if s.false_alarm_rigs > self.max_false_alarm_rigs {
            out.push(format!(
                "{} clean rigs with a named effect > {}",
                s.false_alarm_rigs, self.max_false_alarm_rigs
            ));
        }
        if s.share_within_1_10 < self.min_share_within_1_10 {
            out.push(format!(
                "share of rigs ≤ 1.10 σ {:.3} < {}",
                s.share_within_1_10, self.min_share_within_1_10
            ));
        }
        if s.failed > self.max_failed {
            out.push(format!("{} rigs failed > {}", s.failed, self.max_failed));
        }
        out
    }
}

/// The binomial standard error of `k` of `n`, √(p(1 − p)/n) (0 without trials). Names and effects
/// of one rig are not independent, so it is a guide to the spread between seeds, not a bound.
pub fn binomial_se(k: usize, n: usize) -> f64 {
    if n == 0 {
        return 0.0;
    }
    let p = k as f64 / n as f64;
    (p * (1.0 - p) / n as f64).sqrt()
}

fn pct(x: f64) -> String {
    format!("{:.1} %", 100.0 * x)
}

/// The markdown report: `command` (how it was run) heads it.
pub fn markdown(command: &str, s: &Summary, results: &[RigResult]) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "# Loop benchmark\n\n`{command}`\n");
    let _ = writeln!(o, "| figure | value |\n|---|---|");
    let rows: [(&str, String); 14] = [
        ("rigs (failed)", format!("{} ({})", s.rigs, s.failed)),
        (
            "precision (right / named)",
            format!(
                "{:.3} ± {:.3} ({} / {})",
                s.precision,
                binomial_se(s.named_right, s.named),
                s.named_right,
                s.named
            ),
        ),
        (
            "precision counting alternatives (right or the truth among its alternatives / named)",
            format!(
                "{:.3} ± {:.3} ({} / {}); right only through alternatives: {}",
                s.precision_with_alternatives,
                binomial_se(s.named_right_with_alternatives, s.named),
                s.named_right_with_alternatives,
                s.named,
                pct(s.right_only_through_alternatives)
            ),
        ),
        (
            "cannot tell apart (named effects with alternatives)",
            format!(
                "{} of {}; {:.2} alternatives per named effect",
                s.named_with_alternatives, s.named, s.mean_alternatives
            ),
        ),
        (
            "recall (found / planted)",
            format!(
                "{:.3} ± {:.3} ({} / {})",
                s.recall,
                binomial_se(s.found, s.planted),
                s.found,
                s.planted
            ),
        ),
        (
            "recall, oracle gain ≥ 5 %",
            format!(
                "{:.3} ± {:.3} ({} / {})",
                s.recall_gain_5pct,
                binomial_se(s.gain_5pct.1, s.gain_5pct.0),
                s.gain_5pct.1,
                s.gain_5pct.0
            ),
        ),
        (
            "recall, oracle gain ≥ 5 %, counting alternatives (found, or the truth among the alternatives of the name in its place)",
            format!(
                "{:.3} ± {:.3} ({} / {})",
                s.recall_gain_5pct_with_alternatives,
                binomial_se(s.found_gain_5pct_with_alternatives, s.gain_5pct.0),
                s.found_gain_5pct_with_alternatives,
                s.gain_5pct.0
            ),
        ),
        (
            "clean rigs with a false alarm",
            format!(
                "{} of {} ({} effects named)",
                s.false_alarm_rigs, s.clean_rigs, s.false_alarm_effects
            ),
        ),
        (
            "rigs ending ≤ 1.10 σ",
            format!(
                "{} ± {} ({} / {})",
                pct(s.share_within_1_10),
                pct(binomial_se(s.within_1_10.1, s.within_1_10.0)),
                s.within_1_10.1,
                s.within_1_10.0
            ),
        ),
        (
            "rigs whose oracle model ends ≤ 1.10 σ",
            pct(s.oracle_within_1_10),
        ),
        ("CPU per rig, median", format!("{:.2} s", s.cpu.median_s)),
        ("CPU per rig, worst", format!("{:.2} s", s.cpu.worst_s)),
        ("CPU, all rigs", format!("{:.1} s", s.cpu.total_s)),
        ("rigs with a CPU figure", format!("{}", s.cpu.rigs)),
    ];
    for (k, v) in rows {
        let _ = writeln!(o, "| {k} | {v} |");
    }

    let _ = writeln!(
        o,
        "\n## Confusion (planted × named)\n\nA missed effect counts under each look-alike named in its place, or under `nothing`.\n"
    );
    let c = &s.confusion;
    let _ = writeln!(o, "| planted \\ named | {} |", c.cols.join(" | "));
    let _ = writeln!(o, "|---|{}", "---|".repeat(c.cols.len()));
    for (r, row) in c.rows.iter().zip(&c.counts) {
        let cells: Vec<String> = row
            .iter()
            .map(|&n| if n == 0 { ".".into() } else { n.to_string() })
            .collect();
        let _ = writeln!(o, "| {r} | {} |", cells.join(" | "));
    }

    let _ = writeln!(
        o,
        "\n## Recall by planted kind\n\n| planted | planted | found | recall |\n|---|---|---|---|"
    );
    for (k, n, f) in &s.recall_by_kind {
        let _ = writeln!(o, "| {k} | {n} | {f} | {:.2} |", ratio(*f, *n));
    }

    for (title, bins) in [
        ("oracle held-out gain", &s.recall_by_gain),
        ("oracle RMS / σ", &s.recall_by_rms),
    ] {
        let _ = writeln!(
            o,
            "\n## Recall by {title}\n\n| bin | planted | found | recall |\n|---|---|---|---|"
        );
        for b in bins {
            let to = if b.to.is_finite() {
                format!("{}", b.to)
            } else {
                "∞".into()
            };
            let rec = if b.planted == 0 {
                "–".to_string()
            } else {
                format!("{:.2}", ratio(b.found, b.planted))
            };
            let _ = writeln!(
                o,
                "| {} – {to} | {} | {} | {rec} |",
                b.from, b.planted, b.found
            );
        }
    }

    let _ = writeln!(
        o,
        "\n## Parameter errors (named effects only; relative to the plant's value)\n\n| planted | parameter | n | median error | median abs | worst abs |\n|---|---|---|---|---|---|"
    );
    for p in &s.params {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {} | {} |",
            p.kind,
            p.param,
            p.n,
            pct(p.median_relative),
            pct(p.median_abs_relative),
            pct(p.worst_abs_relative)
        );
    }

    let _ = writeln!(
        o,
        "\n## Interval coverage (named effects whose kind was planted: the planted value inside the 95 % interval)\n\n| planted | parameter | n | covered | coverage |\n|---|---|---|---|---|"
    );
    for c in &s.coverage {
        let _ = writeln!(
            o,
            "| {} | {} | {} | {} | {} ± {} |",
            c.kind,
            c.param,
            c.n,
            c.covered,
            pct(c.share()),
            pct(binomial_se(c.covered, c.n))
        );
    }
    let a = &s.absent_rule;
    let _ = writeln!(
        o,
        "\nHad no effect been named whose presence interval (gap, time constant, volume, amplitude) reaches 0: {} named effects dropped ({} of them right); precision {:.3} ({} / {}), recall at oracle gain ≥ 5 % {:.3} ({} / {}), recall {:.3} ({} / {}), {} clean rigs with a false alarm.",
        a.dropped.0,
        a.dropped.1,
        a.precision,
        a.named.1,
        a.named.0,
        ratio(a.gain_5pct.1, a.gain_5pct.0),
        a.gain_5pct.1,
        a.gain_5pct.0,
        ratio(a.all.1, a.all.0),
        a.all.1,
        a.all.0,
        a.false_alarm_rigs
    );

    let _ = writeln!(
        o,
        "\n## Where the loop's time went (wall-clock s summed over the rigs)\n\n| stage | s |\n|---|---|"
    );
    for (k, v) in &s.cpu.stages_wall_s {
        let _ = writeln!(o, "| {k} | {v:.1} |");
    }

    let _ = writeln!(
        o,
        "\n## Rigs\n\nNamed: each name with, in brackets, the alternatives the loop could not tell from it on held-out data. Shape: the baseline (n, m) the loop selected. Oracle / σ: the held-out RMSE of the chamber law's shape (3, 2) plus every planted effect's true contribution. ✗: missed.\n\n| rig | planted (oracle gain, RMS/σ) | named | shape | final / σ | oracle / σ | CPU s |\n|---|---|---|---|---|---|---|"
    );
    for r in results {
        if let Some(e) = &r.error {
            let _ = writeln!(o, "| {} | failed: {e} | | | | | |", r.label);
            continue;
        }
        let planted: Vec<String> = r
            .planted
            .iter()
            .map(|p| {
                format!(
                    "{}{} ({}, {:.2})",
                    if p.found { "" } else { "✗ " },
                    p.kind,
                    pct(p.oracle_gain),
                    p.oracle_rms_sigma
                )
            })
            .collect();
        let named: Vec<String> = r.named.iter().map(NamedResult::label).collect();
        let _ = writeln!(
            o,
            "| {} | {} | {} | ({}, {}) | {:.3} | {:.3} | {} |",
            r.label,
            if planted.is_empty() {
                "–".into()
            } else {
                planted.join(", ")
            },
            if named.is_empty() {
                "–".into()
            } else {
                named.join(", ")
            },
            r.baseline_shape.0,
            r.baseline_shape.1,
            r.final_over_sigma(),
            r.oracle_rmse_kpa / r.sigma_kpa,
            r.cpu_s.map_or("–".into(), |c| format!("{c:.2}"))
        );
    }
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    fn planted(kind: &str, expects: &str, gain: f64, found: bool) -> PlantedResult {
        PlantedResult {
            kind: kind.into(),
            expects: expects.into(),
            oracle_gain: gain,
            oracle_rms_sigma: 10.0 * gain,
            found,
            ..PlantedResult::default()
        }
    }

    fn named(names: &[&str]) -> Vec<NamedResult> {
        names
            .iter()
            .map(|n| NamedResult {
                name: (*n).into(),
                params: Vec::new(),
                reaches_absent: false,
                alternatives: Vec::new(),
            })
            .collect()
    }

    /// Precision counting alternatives, by hand on the five rigs: rig 1's delivery_lag (leak
    /// planted, missed) with the alternatives `leak` and `sensor_lag + air_compliance` is right
    /// through the first; rig 3's sensor_lag on a clean rig with `air_compliance` stays wrong
    /// (nothing planted); rig 4's ripple with `hysteresis + ripple` stays wrong (ripple not
    /// planted: every effect of an alternative must be). Named 5, right 2 strictly, 3 with
    /// alternatives; 3 of 5 named effects said "cannot tell", with 4 alternatives; 1 of the 3
    /// right only through alternatives.
    #[test]
    fn precision_counting_alternatives_by_hand() {
        let strs = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        let mut r = rigs();
        r[0].named[1].alternatives = vec![strs(&["leak"]), strs(&["sensor_lag", "air_compliance"])];
        r[2].named[0].alternatives = vec![strs(&["air_compliance"])];
        r[3].named[1].alternatives = vec![strs(&["hysteresis", "ripple"])];
        let s = summarise(&r);
        assert_eq!((s.named, s.named_right), (5, 2));
        assert_eq!(s.named_right_with_alternatives, 3);
        assert!((s.precision_with_alternatives - 0.6).abs() < 1e-12);
        assert_eq!(s.named_with_alternatives, 3);
        assert!((s.mean_alternatives - 0.8).abs() < 1e-12);
        assert!((s.right_only_through_alternatives - 1.0 / 3.0).abs() < 1e-12);
        // Recall at gain ≥ 5 % counting alternatives: the leak's gain is 2 %, so the leak among
        // rig 1's delivery_lag's alternatives does not count; strictly 2 of 3 either way.
        assert_eq!(s.found_gain_5pct_with_alternatives, 2);
        // With rig 5's missed backlash (gain 6 %) among the alternatives of a wrong name there,
        // it counts; among those of a right name (rig 4's hysteresis) it would not.
        let mut r5 = r.clone();
        r5[4].named = named(&["dead_band"]);
        r5[4].named[0].alternatives = vec![strs(&["backlash"])];
        let s5 = summarise(&r5);
        assert_eq!(s5.found_gain_5pct_with_alternatives, 3);
        assert!((s5.recall_gain_5pct_with_alternatives - 1.0).abs() < 1e-12);
        assert_eq!(s5.gain_5pct, (3, 2));
        let mut r4 = r.clone();
        r4[3].named[0].alternatives = vec![strs(&["backlash"])];
        r4[3]
            .planted
            .push(planted("backlash", "backlash", 0.5, false));
        assert_eq!(summarise(&r4).found_gain_5pct_with_alternatives, 2);
        let md = markdown("vfp bench-loop", &s, &r);
        assert!(
            md.contains("| 0.600 ± 0.219 (3 / 5); right only through alternatives: 33.3 % |"),
            "{md}"
        );
        assert!(
            md.contains("| 3 of 5; 0.80 alternatives per named effect |"),
            "{md}"
        );
        // Without alternatives both precisions agree.
        let s = summarise(&rigs());
        assert_eq!(s.precision_with_alternatives, s.precision);
        assert_eq!((s.named_with_alternatives, s.mean_alternatives), (0, 0.0));
    }

    fn rig(planted: Vec<PlantedResult>, names: &[&str], over_sigma: f64, cpu: f64) -> RigResult {
        RigResult {
            planted,
            named: named(names),
            sigma_kpa: 0.1,
            final_rmse_kpa: 0.1 * over_sigma,
            oracle_rmse_kpa: 0.1,
            cpu_s: Some(cpu),
            stages_s: [("searches".to_string(), cpu / 2.0)].into_iter().collect(),
            ..RigResult::default()
        }
    }

    /// Five rigs worked by hand:
    /// 1. air found (air_compliance), leak missed with delivery_lag named instead;
    /// 2. clean, nothing named;
    /// 3. clean, sensor_lag named (a false alarm);
    /// 4. hysteresis found, ripple named besides (an extra);
    /// 5. backlash missed, nothing named; plus one failed rig.
    fn rigs() -> Vec<RigResult> {
        vec![
            rig(
                vec![
                    planted("air", "air_compliance", 0.30, true),
                    planted("leak", "leak", 0.02, false),
                ],
                &["air_compliance", "delivery_lag"],
                1.05,
                2.0,
            ),
            rig(vec![], &[], 1.00, 1.0),
            rig(vec![], &["sensor_lag"], 1.02, 4.0),
            rig(
                vec![planted("hysteresis", "hysteresis", 0.10, true)],
                &["hysteresis", "ripple"],
                1.30,
                3.0,
            ),
            rig(
                vec![planted("backlash", "backlash", 0.06, false)],
                &[],
                1.50,
                10.0,
            ),
            RigResult {
                error: Some("the firmware faulted".into()),
                ..RigResult::default()
            },
        ]
    }

    #[test]
    fn precision_recall_and_false_alarms_by_hand() {
        let s = summarise(&rigs());
        assert_eq!((s.rigs, s.failed), (6, 1));
        // Named: 2 + 0 + 1 + 2 + 0 = 5; right: air_compliance, hysteresis.
        assert_eq!((s.named, s.named_right), (5, 2));
        assert!((s.precision - 0.4).abs() < 1e-12);
        // Planted 4, found 2.
        assert_eq!((s.planted, s.found), (4, 2));
        assert!((s.recall - 0.5).abs() < 1e-12);
        // Gain ≥ 5 %: air (found), hysteresis (found), backlash (missed).
        assert!((s.recall_gain_5pct - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(s.gain_5pct, (3, 2));
        assert_eq!(s.within_1_10, (5, 3));
        // √(0.4 · 0.6 / 5) = 0.219…, printed with the counts.
        let md = markdown("vfp bench-loop", &s, &rigs());
        assert!(md.contains("| 0.400 ± 0.219 (2 / 5) |"), "{md}");
        assert_eq!(
            (s.clean_rigs, s.false_alarm_rigs, s.false_alarm_effects),
            (2, 1, 1)
        );
        // ≤ 1.10 σ: rigs 1, 2, 3 of the five scored; the oracle's model on all five.
        assert!((s.share_within_1_10 - 0.6).abs() < 1e-12);
        assert_eq!(s.oracle_within_1_10, 1.0);
        // An oracle model at 2 σ on the fifth rig (interactions it does not hold).
        let mut r = rigs();
        r[4].oracle_rmse_kpa = 0.2;
        assert!((summarise(&r).oracle_within_1_10 - 0.8).abs() < 1e-12);
    }

    #[test]
    fn confusion_matrix_by_hand() {
        let c = summarise(&rigs()).confusion;
        assert_eq!(
            c.rows,
            ["air", "backlash", "hysteresis", "leak", "clean", "(extra)"]
        );
        assert_eq!(c.cols.last().map(String::as_str), Some("nothing"));
        assert_eq!(c.get("air", "air_compliance"), 1);
        // The leak missed, delivery_lag named in its place.
        assert_eq!(c.get("leak", "delivery_lag"), 1);
        assert_eq!(c.get("leak", "nothing"), 0);
        assert_eq!(c.get("backlash", "nothing"), 1);
        assert_eq!(c.get("hysteresis", "hysteresis"), 1);
        assert_eq!(c.get("(extra)", "ripple"), 1);
        assert_eq!(c.get("clean", "nothing"), 1);
        assert_eq!(c.get("clean", "sensor_lag"), 1);
        let total: usize = c.counts.iter().flatten().sum();
        assert_eq!(total, 7);
    }

    #[test]
    fn recall_bins_and_cpu_by_hand() {
        let s = summarise(&rigs());
        // Gains 0.30 (found), 0.02 (missed), 0.10 (found), 0.06 (missed).
        let g: Vec<(usize, usize)> = s
            .recall_by_gain
            .iter()
            .map(|b| (b.planted, b.found))
            .collect();
        assert_eq!(g, [(0, 0), (1, 0), (2, 1), (1, 1)]);
        // RMS/σ = 10 × gain: 3.0, 0.2, 1.0, 0.6.
        let k: Vec<(&str, usize, usize)> = s
            .recall_by_kind
            .iter()
            .map(|(k, n, f)| (k.as_str(), *n, *f))
            .collect();
        assert_eq!(
            k,
            [
                ("air", 1, 1),
                ("backlash", 1, 0),
                ("hysteresis", 1, 1),
                ("leak", 1, 0)
            ]
        );
        let r: Vec<(usize, usize)> = s
            .recall_by_rms
            .iter()
            .map(|b| (b.planted, b.found))
            .collect();
        assert_eq!(r, [(1, 0), (1, 0), (1, 1), (1, 1)]);
        // CPU 2, 1, 4, 3, 10: median 3, worst 10, total 20; searches half of each.
        assert_eq!(s.cpu.rigs, 5);
        assert_eq!(
            (s.cpu.median_s, s.cpu.worst_s, s.cpu.total_s),
            (3.0, 10.0, 20.0)
        );
        assert_eq!(s.cpu.stages_wall_s["searches"], 10.0);
    }

    #[test]
    fn parameter_errors_by_hand() {
        let mut r = rigs();
        r[0].planted[0].params = vec![ParamCompare {
            name: "air_volume_at_atmospheric_pressure".into(),
            truth: 20.0,
            named: Some(22.0),
            ci95: Some([19.0, 25.0]),
        }];
        r[3].planted[0].params = vec![ParamCompare {
            name: "width".into(),
            truth: 20.0,
            named: Some(15.0),
            ci95: Some([14.0, 16.0]),
        }];
        // Not named: no error to count.
        r[4].planted[0].params = vec![ParamCompare {
            name: "play".into(),
            truth: 0.4,
            named: None,
            ci95: None,
        }];
        let s = summarise(&r);
        assert_eq!(s.params.len(), 2);
        let air = &s.params[0];
        assert_eq!((air.kind.as_str(), air.n), ("air", 1));
        assert!((air.median_relative - 0.1).abs() < 1e-12);
        let w = &s.params[1];
        assert!((w.median_relative + 0.25).abs() < 1e-12);
        assert!((w.worst_abs_relative - 0.25).abs() < 1e-12);
        // Coverage: the air's interval holds its truth, the width's does not; the total last.
        let cov: Vec<(&str, usize, usize)> = s
            .coverage
            .iter()
            .map(|c| (c.param.as_str(), c.n, c.covered))
            .collect();
        assert_eq!(
            cov,
            vec![
                ("air_volume_at_atmospheric_pressure", 1, 1),
                ("width", 1, 0),
                ("all", 2, 1)
            ]
        );
    }

    /// The rule "not named when the presence interval reaches 0", scored by hand: dropping a
    /// right name lowers recall, dropping a wrong one raises precision.
    #[test]
    fn the_absent_rule_by_hand() {
        let mut r = rigs();
        let before = summarise(&r);
        assert_eq!(before.absent_rule.dropped, (0, 0));
        assert_eq!(before.absent_rule.named, (before.named, before.named_right));
        // Rig 0 named air_compliance rightly: the rule drops it.
        let i = r[0]
            .named
            .iter()
            .position(|n| n.name == "air_compliance")
            .unwrap();
        r[0].named[i].reaches_absent = true;
        let s = summarise(&r);
        assert_eq!(s.absent_rule.dropped, (1, 1));
        assert_eq!(
            s.absent_rule.named,
            (before.named - 1, before.named_right - 1)
        );
        assert_eq!(s.absent_rule.all.1, before.found - 1);
    }

    #[test]
    fn the_gate_names_each_threshold_missed() {
        let s = summarise(&rigs());
        let gate = Gate {
            rigs: 6,
            seed: 1,
            samples: [5_000, 6_000],
            min_precision: 0.5,
            min_recall_gain_5pct: 0.6,
            max_false_alarm_rigs: 0,
            min_share_within_1_10: 0.6,
            max_failed: 1,
        };
        let missed = gate.check(&s);
        assert_eq!(missed.len(), 2, "{missed:?}");
        assert!(missed[0].starts_with("precision 0.400"));
        assert!(missed[1].starts_with("1 clean rigs"));
        let lenient = Gate {
            min_precision: 0.4,
            max_false_alarm_rigs: 1,
            ..gate
        };
        assert!(lenient.check(&s).is_empty());
    }

    #[test]
    fn the_committed_gate_file_parses_and_its_thresholds_are_ratios() {
        let text = include_str!("../../bench/loop-gate.toml");
        let g: Gate = toml::from_str(text).expect("bench/loop-gate.toml parses");
        assert!(g.rigs > 0 && g.samples[0] <= g.samples[1]);
        for x in [
            g.min_precision,
            g.min_recall_gain_5pct,
            g.min_share_within_1_10,
        ] {
            assert!((0.0..=1.0).contains(&x), "{x}");
        }
        // An unknown key (a misspelt threshold) is an error, not a gate that checks nothing.
        let typo = format!("{text}\nmin_recal = 0.9\n");
        assert!(toml::from_str::<Gate>(&typo).is_err());
    }

    #[test]
    fn no_rigs_give_no_nan_in_the_ratios() {
        let s = summarise(&[]);
        assert_eq!(
            (s.precision, s.recall, s.share_within_1_10),
            (1.0, 1.0, 1.0)
        );
        assert!(markdown("vfp bench-loop", &s, &[]).contains("# Loop benchmark"));
    }
}
