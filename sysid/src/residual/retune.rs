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
/// comes below `target` (the model's), or given up once it cannot: on a 3-hour log one sweep
/// takes 15–20 s, and the pair is judged there first.
pub(super) fn pair_to_beat(prep: &Prepared, start: &Stage, target: f64) -> Stage {
    search::retune_to_beat(prep, start, target)
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
