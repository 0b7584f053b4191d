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
        if sel.model.effects.is_empty() && sel.leads.is_none() {
            sel.leads = Some(
                round
                    .iter()
                    .filter(|r| {
                        r.unphysical.is_none() && r.cand.stage.rmse_heldout < sel.model.rmse_heldout
                    })
                    .take(super::reshape::LEADS)
                    .filter_map(|r| r.cand.stage.effects.last().cloned())
                    .collect(),
            );
        }
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
/// round by [`super::EffectModel::cost_guess`]: the output filters, which rebuild and filter the
/// whole design at every trial θ, first). Dealing the candidates out in a fixed order had left
/// one worker with both filters while the other idled.
///
/// Then the candidates that can matter are refined ([`search::refined`]), again on the workers:
/// those whose search alone won back at least [`REFINE_SCREEN`] of the round's best held-out gain.
/// A refinement corrects a fit that is there (an air pocket's damping taken again from the
/// model with the pocket; a pump ripple's input transform once its columns are fitted); one
/// that wins back a small share of what another candidate does cannot lead the round, be its
/// look-alike or an alternative to it ([`LOOK_ALIKE_GAIN`], [`alternatives::SCREEN_GAIN`]). On
/// the 3-hour log an air pocket's refinement took 5 s in each round it lost.
///
/// Each search and refinement is independent of the schedule, so the results are too.
fn search_all(
    prep: &Prepared,
    cur: &Stage,
    todo: &[EffectKind],
    cfg: &Config,
    past: &mut HashMap<EffectKind, Past>,
) -> (Vec<search::Candidate>, BTreeMap<&'static str, f64>) {
    let guess = |k: EffectKind| k.cost_guess();
    let hints: Vec<Option<f64>> = todo.iter().map(|k| past.get(k).map(|p| p.theta)).collect();
    let mut order: Vec<usize> = (0..todo.len()).collect();
    // Stable sort: ties keep the library's order.
    order.sort_by(|&a, &b| {
        let cost = |i: usize| past.get(&todo[i]).map_or(guess(todo[i]), |p| p.secs);
        cost(b).total_cmp(&cost(a))
    });
    let finished = std::sync::atomic::AtomicUsize::new(0);
    let (mut out, mut secs) = on_workers(cfg.threads, &order, |i| {
        let found = search::search_from(prep, cur, todo[i], hints[i]);
        let done = 1 + finished.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        tell(
            cfg.progress,
            Progress::Step {
                done,
                what: todo[i].name(),
            },
        );
        found
    });
    let gains: Vec<f64> = out
        .iter()
        .map(|c| {
            c.as_ref()
                .map_or(f64::NAN, |c| cur.rmse_heldout - c.stage.rmse_heldout)
        })
        .collect();
    let mut refine = worth_refining(&gains);
    refine.sort_by(|&a, &b| secs[b].total_cmp(&secs[a]));
    // Each worker takes its candidate out of its slot (no copy of the fit).
    let searched: Vec<std::sync::Mutex<Option<search::Candidate>>> = refine
        .iter()
        .map(|&i| std::sync::Mutex::new(out[i].take()))
        .collect();
    let slots: Vec<usize> = (0..refine.len()).collect();
    let (done, more) = on_workers(cfg.threads, &slots, |j| {
        let c = searched[j].lock().map_or(None, |mut c| c.take());
        c.map(|c| search::refined(prep, cur, c))
    });
    for ((&i, c), s) in refine.iter().zip(done).zip(more) {
        out[i] = c;
        secs[i] += s;
    }
    let mut times = BTreeMap::new();
    for (i, c) in out.iter().enumerate() {
        let theta = c
            .as_ref()
            .and_then(|c| c.stage.effects.last())
            .map_or(f64::NAN, |e| e.theta);
        past.insert(
            todo[i],
            Past {
                secs: secs[i],
                theta,
            },
        );
        times.insert(todo[i].name(), secs[i]);
    }
    (out.into_iter().flatten().collect(), times)
}

/// The share of a round's best held-out gain a candidate's search must win back for the
/// candidate to be refined ([`search_all`]): the alternatives' screen.
pub(super) const REFINE_SCREEN: f64 = alternatives::SCREEN_GAIN;

/// The candidates to refine, by their searches' held-out gains over the round's model (`NaN`
/// for one not found): each that wins back at least [`REFINE_SCREEN`] of the best gain; none
/// where no candidate gains at all.
fn worth_refining(gains: &[f64]) -> Vec<usize> {
    let best = gains
        .iter()
        .copied()
        .filter(|g| !g.is_nan())
        .fold(0.0, f64::max);
    (0..gains.len())
        .filter(|&i| best > 0.0 && gains[i] >= REFINE_SCREEN * best)
        .collect()
}

/// `f(i)` for every `i` of `order`, on `threads` workers taking them from a shared queue in that
/// order; each result and the seconds it took, by `i` (`0..order.len()`, a permutation).
/// A worker that panicked leaves its results at `T::default()` (a candidate not found).
fn on_workers<T: Send + Default>(
    threads: usize,
    order: &[usize],
    f: impl Fn(usize) -> T + Sync,
) -> (Vec<T>, Vec<f64>) {
    let threads = threads.max(1).min(order.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut slots: Vec<Option<(T, f64)>> = (0..order.len()).map(|_| None).collect();
    std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let j = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(&i) = order.get(j) else { break };
                        let start = std::time::Instant::now();
                        let r = f(i);
                        mine.push((i, r, start.elapsed().as_secs_f64()));
                    }
                    mine
                })
            })
            .collect();
        for h in handles {
            if let Ok(results) = h.join() {
                for (i, r, secs) in results {
                    slots[i] = Some((r, secs));
                }
            }
        }
    });
    slots.into_iter().map(Option::unwrap_or_default).unzip()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::residual::effects::{AirCompliance, PumpRipple};
    use crate::residual::test_plant::plant;

    const AIR: EffectKind = EffectKind(&AirCompliance);
    const PR: EffectKind = EffectKind(&PumpRipple);

    /// By hand: the best gain 0.4, a quarter of it 0.1; a candidate not found (NaN) or losing is
    /// never refined, and where nothing gains nothing is.
    #[test]
    fn a_candidate_is_refined_where_its_search_wins_back_a_quarter_of_the_best_gain() {
        let gains = [0.4, 0.09, 0.1, -0.2, f64::NAN, 0.11];
        assert_eq!(worth_refining(&gains), vec![0, 2, 5]);
        assert!(worth_refining(&[-0.1, f64::NAN, 0.0]).is_empty());
        assert!(worth_refining(&[]).is_empty());
    }

    /// A plant with an air pocket of 40 mm³: the round's air candidate is its search refined
    /// (the damping taken again from the model with the pocket), and differs from the search
    /// alone; a pump ripple, which the plant does not have, wins back less than a quarter of
    /// what the air does and is left as searched (its refinement would have moved it).
    #[test]
    fn a_round_refines_the_candidate_that_leads_it_and_not_one_that_gains_little() {
        // The pocket with the damping of the plant's polynomial (what its lag needs).
        let smooth = plant(2000, &[], |_| 0.0, 0.0);
        let base = search::fit_stage(&smooth, &[]).unwrap();
        let found = search::search_from(&smooth, &base, AIR, None).unwrap();
        let pocket = Effect {
            theta: 40.0,
            ..found.stage.effects[0].clone()
        };
        let prep = plant(2000, &[pocket], |_| 0.0, 0.01);
        let cur = search::fit_stage(&prep, &[]).unwrap();
        let cfg = Config {
            candidates: vec![AIR, PR],
            ..Config::default()
        };
        let (found, _) = search_all(&prep, &cur, &[AIR, PR], &cfg, &mut HashMap::new());
        let of = |k: EffectKind| found.iter().find(|c| c.kind == k).unwrap();
        let theta = |s: &Stage| s.effects.last().unwrap().theta;
        let searched = search::search_from(&prep, &cur, AIR, None).unwrap();
        let refined = search::refined(&prep, &cur, searched.clone());
        assert_ne!(theta(&searched.stage), theta(&refined.stage));
        assert_eq!(theta(&of(AIR).stage), theta(&refined.stage));
        assert_eq!(of(AIR).stage.fit.sse, refined.stage.fit.sse);
        let ripple = search::search_from(&prep, &cur, PR, None).unwrap();
        let gain = |s: &Stage| cur.rmse_heldout - s.rmse_heldout;
        assert!(gain(&ripple.stage) < 0.25 * gain(&searched.stage));
        assert_eq!(of(PR).stage.fit.sse, ripple.stage.fit.sse);
        let ripple_refined = search::refined(&prep, &cur, ripple.clone());
        assert_ne!(ripple_refined.stage.fit.sse, ripple.stage.fit.sse);
    }
}
