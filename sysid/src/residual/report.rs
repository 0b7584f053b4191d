//! The report of a finished selection (step 5 of the loop): each kept effect with its parameters
//! from the final model, the held-out residual's analyses before and after, and what structure
//! remains, the effects named for the rig.

use super::analysis;
use super::effects::{ripple, Prepared};
use super::interval;
use super::search::Stage;
use super::state::Findings;
use super::validate;
use super::{
    neutral_of, BaselineReport, Config, Diagnosis, EffectReport, FinalReport, ResidualAnalysis,
};

/// Each kept effect's report, its parameters from the final model.
fn effect_reports(prep: &Prepared, sel: &Findings) -> Vec<EffectReport> {
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
            experiment: None,
        })
        .collect()
}

/// The neutral name and story of the final model's `i`-th effect, if its parameters call for one
/// ([`super::EffectModel::neutral`]) or the rig does ([`super::EffectModel::generic`] off a
/// syringe rig).
fn neutral(prep: &Prepared, sel: &Findings, i: usize) -> Option<(&'static str, &'static str)> {
    neutral_of(prep, sel.model.effects.get(i)?)
}

/// The held-out residual analysis (step 2) of a model's residual.
fn analyse_heldout(prep: &Prepared, resid: &[f64]) -> ResidualAnalysis {
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
pub(super) fn report(prep: &Prepared, cfg: &Config, baseline: &Stage, sel: Findings) -> Diagnosis {
    let effects = effect_reports(prep, &sel);
    let analysis_before = analyse_heldout(prep, &baseline.resid);
    let analysis_after = analyse_heldout(prep, &sel.model.resid);
    let sc = &prep.scales;
    let harmonic = |f: f64| sc.cycle_s.map(|_| ripple::cycle_harmonic(f, sc));
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
        leads: sel.leads.unwrap_or_default(),
        reshape: None,
        envelope: Default::default(),
        timing: sel.timing,
    }
}
