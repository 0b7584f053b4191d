//! What the loop's steps hand on to each other ([`super::diagnose`]): the model so far, each
//! effect kept with the round that kept it, what the report will say of the rest, and the loop's
//! test, by which every step judges a model against the one it extends ([`passes`]).

use std::collections::HashMap;

use super::alternatives;
use super::effects::{Effect, EffectKind};
use super::interval;
use super::search::{NestedTest, Stage};
use super::validate;
use super::{Config, Rejected, Signature, SwapReport, Timings};

/// One effect the loop kept: the errors before and after its round (RMSE, kPa) and its test.
pub(super) struct KeptStep {
    pub(super) kind: EffectKind,
    /// The model as kept.
    pub(super) model: validate::FittedModel,
    pub(super) heldout_before: f64,
    pub(super) heldout_after: f64,
    pub(super) train_before: f64,
    pub(super) train_after: f64,
    pub(super) test: NestedTest,
    /// The round's next-best candidate.
    pub(super) runner_up: Option<Rejected>,
    /// The round's look-alikes: the other candidates that passed, physical, with at least
    /// [`super::LOOK_ALIKE_GAIN`] of the kept one's gain (`swaps::swap_look_alike` tries each in
    /// its place), each as its round fitted it.
    pub(super) rivals: Vec<Effect>,
    /// What its alternatives are sought among ([`alternatives::Leads`]).
    pub(super) leads: alternatives::Leads,
}

impl KeptStep {
    /// The step from `prev` to `after` (its last effect kept), with the nested test between them,
    /// no runner-up, look-alikes or leads: those come from a round, where there was one.
    pub(super) fn between(prep: &super::effects::Prepared, prev: &Stage, after: &Stage) -> Self {
        Self {
            kind: after.effects.last().expect("a step keeps an effect").kind,
            model: validate::FittedModel::of(after),
            heldout_before: prev.rmse_heldout,
            heldout_after: after.rmse_heldout,
            train_before: prev.rmse_train,
            train_after: after.rmse_train,
            test: super::search::nested_test(prep, prev, after),
            runner_up: None,
            rivals: Vec::new(),
            leads: alternatives::Leads::default(),
        }
    }
}

/// A candidate's last search in forward selection.
#[derive(Clone, Copy, Debug)]
pub(super) struct Past {
    /// Its time, s.
    pub(super) secs: f64,
    /// Its searched parameter where it ended (NaN when it found none).
    pub(super) theta: f64,
}

/// What the loop has found so far: forward selection and the swaps extend it, leave-one-out
/// takes from it, the report reads it.
pub(super) struct Findings {
    /// The model so far.
    pub(super) model: Stage,
    /// The effects kept, in order.
    pub(super) kept: Vec<KeptStep>,
    /// Candidates tried in the last round and not kept.
    pub(super) rejected: Vec<Rejected>,
    /// Structure a candidate would have absorbed with an unphysical fit.
    pub(super) unphysical: Vec<Signature>,
    /// Look-alikes swapped in.
    pub(super) swaps: Vec<SwapReport>,
    /// Where the time went so far.
    pub(super) timing: Timings,
    /// Each candidate's last search: its time, to schedule the next, and where it ended, where
    /// the next starts (`forward::search_all`).
    pub(super) past: HashMap<EffectKind, Past>,
    /// The final model's joint covariance ([`interval::joint_cov`]), once
    /// `prune::drop_absent` formed it.
    pub(super) final_cov: Option<interval::JointCov>,
    /// Effects look-alike swaps took out, and what came in.
    pub(super) replaced: Vec<alternatives::Replaced>,
    /// Pairs of look-alikes tried in a kept effect's place and not taken
    /// (`swaps::swap_for_pair`): the effect, and the model's effects with the pair last.
    pub(super) pair_trials: Vec<(EffectKind, Vec<Effect>)>,
    /// Each final effect's alternatives, in the model's order ([`alternatives::alternatives`]).
    pub(super) alternatives: Vec<Vec<alternatives::Alternative>>,
    /// The first round's leading candidates (lowest held-out RMSE first; physical, with a
    /// held-out gain), each as searched on the baseline: what the shape's re-selection tries with
    /// a simpler polynomial ([`super::reshape`]).
    pub(super) leads: Option<Vec<Effect>>,
    /// The searches made in the kept effects' places ([`super::search::Searched`]).
    pub(super) searched: super::search::Searched,
}

impl Findings {
    /// Nothing found yet: the baseline, no effect kept.
    pub(super) fn new(baseline: &Stage) -> Self {
        Self {
            model: baseline.clone(),
            kept: Vec::new(),
            rejected: Vec::new(),
            unphysical: Vec::new(),
            swaps: Vec::new(),
            timing: Timings::default(),
            past: HashMap::new(),
            final_cov: None,
            replaced: Vec::new(),
            pair_trials: Vec::new(),
            alternatives: Vec::new(),
            leads: None,
            searched: Default::default(),
        }
    }
}

/// The loop's test of a model `big` against the model `small` it extends: the nested F-test
/// (`test`) rejects at `alpha` and the held-out RMSE falls by at least `min_gain` of `small`'s.
pub(super) fn passes(cfg: &Config, small: &Stage, big: &Stage, test: &NestedTest) -> bool {
    test.p_value < cfg.alpha
        && small.rmse_heldout - big.rmse_heldout >= cfg.min_gain * small.rmse_heldout
}
