//! Alternatives (issue 34, "cannot tell apart"): for each effect of the final model, the other
//! explanations that do as well on the held-out data, within its noise.
//!
//! An alternative is another effect of the library (or two together) fitted in the kept
//! effect's place with the rest of the final model kept as it is (its searched parameters as
//! tuned, the linear coefficients refitted on the training rows), and compared with the final
//! model on the held-out cycles by the loop's one paired test ([`validate::paired_z`]: per unit
//! of held-out time the log ratio of the two models' squared errors, its mean over its
//! AR(1)-corrected standard error). Where `|z| <` [`ALT_Z`] the data cannot tell the two apart:
//! the report says so and lists the alternative with its parameters, held-out RMSE and z. The
//! model keeps the effect the loop kept.
//!
//! What is tried, so that the check costs little more than the comparisons themselves:
//!
//! - the candidates of the kept effect's own round whose held-out errors were within
//!   [`SCREEN_Z`] of the winner's by the same paired test (computed from the round's residuals,
//!   no fit): a candidate far worse in its round is not tried again. Where the rest of the model
//!   is still the one that round searched it on (the same effects at the same parameters: a model
//!   of one effect, or the last one kept without a re-tune that moved the others), the round's
//!   fit is the alternative as it stands (fitted again from its effects: one least-squares
//!   fit; the round keeps the effects only, not a fit over every sample); otherwise it is searched again in the final model's
//!   company ([`search::search`], one candidate's search);
//! - an effect a look-alike swap took out ([`super::SwapReport`]), in the place of what came in
//!   (one effect, or the two that together replaced it: the air pocket and the sensor lag that
//!   took a delivery lag's place);
//! - the pair of look-alikes the swap trials fitted in a kept effect's place and did not take
//!   (the air pocket and sensor lag for a delivery lag kept), where the rest of the model is
//!   still the one they were fitted with;
//! - for a kept lag or delay, each other lag or delay at the same mean delay
//!   ([`super::effects::EffectModel::mean_delay`]) where that is below its search's floor (its
//!   search could not go there; one fit each): lags of one mean delay differ in the frames only
//!   at order (τ/frame)², and on the loop benchmark (seed 1) drive lags of 1.0–1.5 ms (mean
//!   delays 2–3 ms, under the delivery lag's 2 ms floor) were named sensor lags of 2–3 ms with
//!   no delivery lag among their alternatives.
//!
//! An alternative must be an explanation: in the kept effect's place it must win back at least
//! [`super::LOOK_ALIKE_GAIN`] (half) of the kept effect's held-out gain over the model without
//! it, as a look-alike of its round must; on a short log with few held-out cycles the paired
//! test has little power, and a candidate that explains next to nothing would otherwise be
//! "within the noise" of a strong effect. It must be physical ([`search::unphysical`]). It is not re-tuned with the rest,
//! which can only make it look worse than it could be: the list errs towards telling apart.

use std::cell::RefCell;

use serde::Serialize;

use super::effects::{Effect, EffectKind, Prepared, Search, REGISTRY};
use super::search::{self, Param, Stage};
use super::validate;

/// Paired z below which (in absolute value) an alternative is within the noise of the kept
/// effect: under no difference between the two models z is about standard normal over the
/// held-out units, and `|z| ≥ 2` happens about 4.6 % of the time (two-sided); the carry-over's
/// threshold ([`validate::CARRY_Z`]) is the same.
pub const ALT_Z: f64 = 2.0;

/// Paired z (a candidate's held-out errors against its round's winner's) under which a candidate
/// is tried again as an alternative in the final model: looser than [`ALT_Z`], since the final
/// model's company differs from the round's.
pub const SCREEN_Z: f64 = 3.0;

/// Another explanation the held-out data cannot tell from a kept effect.
#[derive(Clone, Debug, Serialize)]
pub struct Alternative {
    /// The effect fitted in the kept effect's place, or two joined by ` + `, named as the report
    /// names effects.
    pub effect: String,
    /// The kept effects it stands in for: this one, or the two a look-alike swap put in its
    /// place.
    pub replaces: Vec<&'static str>,
    /// Its parameters as fitted there (for two effects, each name prefixed with its effect's).
    pub params: Vec<Param>,
    /// Held-out RMSE of the final model with it in their place, kPa.
    pub rmse_heldout: f64,
    /// Paired z over the held-out units ([`validate::paired_z`]), positive where the kept
    /// effect's errors are the smaller.
    pub z: f64,
    /// Parameters of the model with it less those of the final model (negative: it is the
    /// simpler).
    pub extra_params: i64,
    /// The final model with it in their place, as fitted (its effects, their per-sample
    /// schedules left out, and its coefficients): what an experiment that decides is planned
    /// with ([`super::decide`]) and what a second log scores.
    #[serde(skip)]
    pub model: validate::FittedModel,
}

/// A kept effect's candidates to try again (module docs).
#[derive(Clone, Debug, Default)]
pub(super) struct Leads {
    /// Close candidates of its round, each as the round fitted it: the model's effects with the
    /// candidate last (effects only, not the fit: a fit holds its prediction and residual over
    /// every sample, megabytes on a long log; where it can be reused it is fitted again, one
    /// least-squares fit).
    pub close: Vec<Vec<Effect>>,
}

/// An effect a look-alike swap took out, and the model it was in.
#[derive(Clone, Debug)]
pub(super) struct Replaced {
    /// The effect taken out, as it was.
    pub out: EffectKind,
    /// What came in.
    pub by: Vec<EffectKind>,
}

/// Squared errors per row.
pub(super) fn squares(resid: &[f64]) -> Vec<f64> {
    resid.iter().map(|r| r * r).collect()
}

/// Share of the round winner's held-out gain (over the model the round started from) a
/// candidate must win back in the round to be tried again as an alternative: looser than the
/// [`super::LOOK_ALIKE_GAIN`] an alternative must reach in the final model, as [`SCREEN_Z`] is
/// looser than [`ALT_Z`].
pub const SCREEN_GAIN: f64 = 0.25;

/// The close candidates of a round (module docs): every physical candidate but the winner whose
/// held-out errors are within [`SCREEN_Z`] of the winner's and whose held-out gain over `from`
/// (the round's starting model's held-out RMSE) is at least [`SCREEN_GAIN`] of the winner's.
pub(super) fn screen<'a>(
    blocks: &[Vec<usize>],
    from: f64,
    winner: &Stage,
    others: impl Iterator<Item = &'a Stage>,
) -> Vec<Vec<Effect>> {
    let win = squares(&winner.resid);
    let gain = from - winner.rmse_heldout;
    others
        .filter(|s| from - s.rmse_heldout >= SCREEN_GAIN * gain)
        .filter(|s| validate::paired_z(&squares(&s.resid), &win, blocks) < SCREEN_Z)
        .map(|s| s.effects.clone())
        .collect()
}

/// What the final model's alternatives are computed from.
pub(super) struct Inputs<'a> {
    /// The final model.
    pub model: &'a Stage,
    /// Each effect of the final model's leads, in the model's order.
    pub leads: Vec<&'a Leads>,
    /// Each effect of the final model's name in the report, in the model's order.
    pub names: Vec<&'static str>,
    /// The swaps' outs.
    pub replaced: &'a [Replaced],
    /// Pairs tried in a kept effect's place and not taken: the effect, and the model's effects
    /// with the pair last.
    pub pair_trials: &'a [(EffectKind, Vec<Effect>)],
    /// The searches made in the kept effects' places so far.
    pub searched: &'a search::Searched,
}

/// Each effect of the final model's alternatives, in the model's order (module docs).
pub(super) fn alternatives(prep: &Prepared, inp: &Inputs) -> Vec<Vec<Alternative>> {
    let model = inp.model;
    let n = model.effects.len();
    let mut out: Vec<Vec<Alternative>> = vec![Vec::new(); n];
    if n == 0 {
        return out;
    }
    let blocks = validate::held_out_blocks(prep);
    if blocks.len() < validate::CARRY_MIN_UNITS {
        return out;
    }
    let kept_sq = squares(&model.resid);
    let in_model = |k: EffectKind| model.effects.iter().any(|e| e.kind == k);
    let without = |drop: &[usize]| -> Vec<Effect> {
        (0..n)
            .filter(|j| !drop.contains(j))
            .map(|j| model.effects[j].clone())
            .collect()
    };
    // The rest of the model without the effects at `at`, fitted once for all that is tried in
    // their place.
    let bases: RefCell<Vec<(Vec<usize>, Option<Stage>)>> = RefCell::new(Vec::new());
    let base = |at: &[usize]| -> Option<Stage> {
        let mut b = bases.borrow_mut();
        if let Some((_, s)) = b.iter().find(|(a, _)| a == at) {
            return s.clone();
        }
        let s = search::fit_stage(prep, &without(at));
        b.push((at.to_vec(), s.clone()));
        s
    };
    let search_in = |at: &[usize], k: EffectKind| -> Option<Stage> {
        inp.searched.search(prep, &base(at)?, k).map(|c| c.stage)
    };
    // Judges `alt` (a model with `added` effects last) in the place of the effects at `at`: an
    // explanation (at least [`super::LOOK_ALIKE_GAIN`] of their held-out gain over the model
    // without them), physical, and within the noise of the kept model.
    let judge = |alt: &Stage, added: usize, at: &[usize]| -> Option<Alternative> {
        let rest = base(at)?;
        let gain = rest.rmse_heldout - model.rmse_heldout;
        if rest.rmse_heldout - alt.rmse_heldout < super::LOOK_ALIKE_GAIN * gain
            || search::unphysical(alt, &prep.scales).is_some()
        {
            return None;
        }
        let z = validate::paired_z(&squares(&alt.resid), &kept_sq, &blocks);
        if z.is_nan() || z.abs() >= ALT_Z {
            return None;
        }
        let m = alt.effects.len();
        let idx: Vec<usize> = (m - added..m).collect();
        let names: Vec<&str> = idx
            .iter()
            .map(|&i| super::report_name(prep, &alt.effects[i]))
            .collect();
        let params = idx
            .iter()
            .zip(&names)
            .flat_map(|(&i, e)| {
                let mut p = search::effect_params(prep, alt, i);
                if added > 1 {
                    p.iter_mut()
                        .for_each(|p| p.name = format!("{e}.{}", p.name));
                }
                p
            })
            .collect();
        Some(Alternative {
            effect: names.join(" + "),
            replaces: at.iter().map(|&j| inp.names[j]).collect(),
            params,
            rmse_heldout: alt.rmse_heldout,
            z,
            extra_params: alt.n_params() as i64 - model.n_params() as i64,
            model: validate::FittedModel::of(alt).without_samples(),
        })
    };
    let mut found: Vec<(Vec<usize>, Alternative)> = Vec::new();
    for (i, leads) in inp.leads.iter().enumerate() {
        let rest = without(&[i]);
        for c in &leads.close {
            let Some(k) = c.last().map(|e| e.kind) else {
                continue;
            };
            if in_model(k) {
                continue;
            }
            let m = c.len();
            let alt = if search::same_effects(&c[..m - 1], &rest) {
                search::fit_stage(prep, c)
            } else {
                search_in(&[i], k)
            };
            if let Some(a) = alt.and_then(|alt| judge(&alt, 1, &[i])) {
                found.push((vec![i], a));
            }
        }
    }
    for r in inp.replaced {
        if in_model(r.out) {
            continue;
        }
        let at: Vec<usize> =
            r.by.iter()
                .filter_map(|&b| model.effects.iter().position(|e| e.kind == b))
                .collect();
        if at.len() != r.by.len() {
            continue;
        }
        if let Some(a) = search_in(&at, r.out).and_then(|alt| judge(&alt, 1, &at)) {
            found.push((at, a));
        }
    }
    for (k, effects) in inp.pair_trials {
        let Some(i) = model.effects.iter().position(|e| e.kind == *k) else {
            continue;
        };
        let m = effects.len();
        if m < 2 || effects[m - 2..].iter().any(|e| in_model(e.kind)) {
            continue;
        }
        if !search::same_effects(&effects[..m - 2], &without(&[i])) {
            continue;
        }
        let Some(stage) = search::fit_stage(prep, effects) else {
            continue;
        };
        if let Some(a) = judge(&stage, 2, &[i]) {
            found.push((vec![i], a));
        }
    }
    // A lag or delay whose search could not reach the kept one's mean delay (below its floor):
    // fitted there, in the kept one's place, and judged as the rest.
    for (i, e) in model.effects.iter().enumerate() {
        let Some(d) = e.kind.mean_delay(e, prep) else {
            continue;
        };
        for &k in REGISTRY {
            if in_model(k)
                || found
                    .iter()
                    .any(|(at, a)| at == &[i] && a.effect == k.name())
            {
                continue;
            }
            let (Some(theta), Search::Log(floor, _)) =
                (k.theta_at_mean_delay(d), k.search(&prep.scales))
            else {
                continue;
            };
            if !(theta > 0.0 && theta < floor) {
                continue;
            }
            let mut effects = without(&[i]);
            effects.push(Effect::new(k, theta));
            if let Some(a) = search::fit_stage(prep, &effects).and_then(|alt| judge(&alt, 1, &[i]))
            {
                found.push((vec![i], a));
            }
        }
    }
    for (at, a) in found {
        for j in at {
            if !out[j].iter().any(|b| b.effect == a.effect) {
                out[j].push(a.clone());
            }
        }
    }
    for alts in &mut out {
        alts.sort_by(|a, b| a.z.total_cmp(&b.z));
    }
    out
}
