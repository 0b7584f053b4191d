//! The re-tunes: every searched parameter of a model tuned again together, since each was found
//! while effects that came later were still missing. These are the loop's entry points, each with
//! the rule that says whether the re-tuned model replaces the one it started from; the descent
//! itself is [`search::retune`] (coordinate sweeps and joint Gauss–Newton steps) and
//! [`search::retune_to_beat`] (the same, given up once it cannot reach a target).

use super::effects::Prepared;
use super::search::{self, Stage};

/// After forward selection keeps a candidate (`found`, the model it extends being `before`). The
/// re-tuned model replaces the candidate where it fits the training rows better, is physical, and
/// keeps the step's gain on the held-out rows (its error there below `before`'s): re-tuning
/// follows the training rows only, and a drift's time polynomial tuned there can run far off
/// over a held-out stretch.
pub(super) fn after_keep(prep: &Prepared, before: &Stage, found: Stage) -> Stage {
    let tuned = search::retune(prep, &found);
    if tuned.fit.sse <= found.fit.sse
        && tuned.rmse_heldout < before.rmse_heldout
        && search::unphysical(&tuned, &prep.scales).is_none()
    {
        tuned
    } else {
        found
    }
}

/// A look-alike searched alone in a kept effect's place (`found`), re-tuned with the rest so that
/// two lags that trade against each other find their joint optimum: the re-tuned model where it
/// fits the training rows no worse. (The swap judges the result on both sets of rows.)
pub(super) fn look_alike(prep: &Prepared, found: Stage) -> Stage {
    let tuned = search::retune(prep, &found);
    if tuned.fit.sse <= found.fit.sse {
        tuned
    } else {
        found
    }
}

/// A pair of look-alikes started in a kept effect's place, re-tuned until its training SSE first
/// comes below that of `model`, or given up once it cannot: on a 3-hour log one sweep takes
/// 15–20 s, and the pair is judged there first.
///
/// Where the pair or the model has an output lag inside the frames, the descent runs on their
/// stand-ins ([`search::stand_in`]: those lags on instants, a third of the cost per trial), the
/// target being the model's stand-in's SSE: whether the pair can reach the model is a question
/// of where its parameters go, which the two forms of a lag answer alike (they differ within a
/// frame). A pair that reaches it there is re-tuned on the model itself from where it got to,
/// and judged on its own fit; one that cannot is given up where the stand-in was (its own fit
/// at those parameters returned). On a random rig of the loop benchmark, a pair of lags in an
/// offset drift's place started at 24 times the model's SSE and took two sweeps of 0.7 s through
/// the frames to be given up.
pub(super) fn pair_to_beat(prep: &Prepared, start: &Stage, model: &Stage) -> Stage {
    let pair_in = search::stand_in(prep, &start.effects);
    let model_in = search::stand_in(prep, &model.effects);
    if pair_in.is_none() && model_in.is_none() {
        return search::retune_to_beat(prep, start, model.fit.sse);
    }
    let target = model_in.map_or(model.fit.sse, |m| search::sse_of(prep, &m));
    let Some(located) = search::descend_to_beat(
        prep,
        pair_in.unwrap_or_else(|| start.effects.clone()),
        target,
    ) else {
        return start.clone();
    };
    let mut effects = start.effects.clone();
    for (e, l) in effects.iter_mut().zip(&located.effects) {
        e.theta = l.theta;
    }
    let Some(there) = search::fit_stage(prep, &effects) else {
        return start.clone();
    };
    if located.beaten {
        search::retune_to_beat(prep, &there, model.fit.sse)
    } else {
        there
    }
}

/// A pair that passed where it first beat the model (`trial`), re-tuned to the end: the
/// re-tuned model where it fits the training rows strictly better.
pub(super) fn pair_settled(prep: &Prepared, trial: Stage) -> Stage {
    let tuned = search::retune(prep, &trial);
    if tuned.fit.sse < trial.fit.sse {
        tuned
    } else {
        trial
    }
}
