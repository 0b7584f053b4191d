//! Forward selection (step 4 of the loop): each round searches every candidate not yet in the
//! model ([`search::search`], on `Config::threads` workers), ranks them by held-out RMSE, and
//! keeps the best-ranked one that passes the loop's test ([`passes`]) and is physical, the model
//! re-tuned with it ([`retune::after_keep`]); the rounds stop when none does, or at
//! `Config::max_effects`. A kept effect records its round's look-alikes, which the swaps try in
//! its place afterwards ([`super::swaps`]).

use std::collections::{BTreeMap, HashMap};

use super::alternatives;
use super::effects::{Effect, EffectKind, Prepared};
use super::retune;
use super::search::{self, NestedTest, Stage};
use super::state::{passes, Findings, KeptStep, Past};
use super::validate;
use super::{secs, Config, Rejected, RoundTiming, Signature, LOOK_ALIKE_GAIN};
use crate::progress::{tell, Progress};

/// One searched candidate of a round, judged against the model it would extend.
struct Ranked {
    cand: search::Candidate,
    test: NestedTest,
    /// The test rejects at `alpha` and the held-out gain clears `min_gain`.
    passes: bool,
    /// Why its best fit is not physical, if it is not.
    unphysical: Option<String>,
}

/// Rounds of forward selection from `sel`'s model, with the kinds in `banned` left out.
pub(super) fn rounds(prep: &Prepared, cfg: &Config, sel: &mut Findings, banned: &[EffectKind]) {
    while sel.model.effects.len() < cfg.max_effects {
        let t = std::time::Instant::now();
        let (mut round, candidates) = rank_round(prep, &sel.model, cfg, &mut sel.past, banned);
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

/// Searches and tests every candidate not yet in `cur`, ranked by held-out RMSE.
fn rank_round(
    prep: &Prepared,
    cur: &Stage,
    cfg: &Config,
    past: &mut HashMap<EffectKind, Past>,
    banned: &[EffectKind],
) -> (Vec<Ranked>, BTreeMap<&'static str, f64>) {
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
    let (found, times) = search_all(prep, cur, &todo, cfg, past);
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

/// Keeps a candidate: re-tunes the model's searched parameters ([`retune::after_keep`]) and
/// records the step, its "after" being the model as kept (so each step's "after" is the next
/// step's "before").
fn keep(
    prep: &Prepared,
    sel: &mut Findings,
    r: Ranked,
    runner_up: Option<Rejected>,
    rivals: Vec<Effect>,
    leads: alternatives::Leads,
) {
    let model = retune::after_keep(prep, &sel.model, r.cand.stage);
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
fn reject_round(sel: &mut Findings, round: &[Ranked]) {
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

/// Searches every candidate on `threads` workers. Each worker takes the next candidate from a
/// shared queue, costliest first (longest-processing-time-first scheduling), with each
/// candidate's cost its search time in the previous round (`past`, updated here; before the first
/// round the output filters, which rebuild and filter the whole design at every trial θ, are
/// guessed costliest, [`super::EffectModel::cost_guess`]). Dealing the candidates out in a fixed order had left one worker with both
/// filters while the other idled. Each search is independent of the schedule, so the results are
/// too.
fn search_all(
    prep: &Prepared,
    cur: &Stage,
    todo: &[EffectKind],
    cfg: &Config,
    past: &mut HashMap<EffectKind, Past>,
) -> (Vec<search::Candidate>, BTreeMap<&'static str, f64>) {
    let threads = cfg.threads.max(1).min(todo.len().max(1));
    let finished = std::sync::atomic::AtomicUsize::new(0);
    let guess = |k: EffectKind| k.cost_guess();
    let hints: Vec<Option<f64>> = todo.iter().map(|k| past.get(k).map(|p| p.theta)).collect();
    let mut order: Vec<usize> = (0..todo.len()).collect();
    // Stable sort: ties keep the library's order.
    order.sort_by(|&a, &b| {
        let cost = |i: usize| past.get(&todo[i]).map_or(guess(todo[i]), |p| p.secs);
        cost(b).total_cmp(&cost(a))
    });
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut out: Vec<Option<search::Candidate>> = vec![None; todo.len()];
    let mut times = BTreeMap::new();
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let j = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&i) = order.get(j) else { break };
                        let start = std::time::Instant::now();
                        let found = search::search_from(prep, cur, todo[i], hints[i]);
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
                    let theta = c
                        .as_ref()
                        .and_then(|c| c.stage.effects.last())
                        .map_or(f64::NAN, |e| e.theta);
                    past.insert(todo[i], Past { secs, theta });
                    out[i] = c;
                    times.insert(todo[i].name(), secs);
                }
            }
        }
    });
    (out.into_iter().flatten().collect(), times)
}
