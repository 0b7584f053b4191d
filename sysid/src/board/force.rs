//! `vfp force --augmented`: the force the board would estimate with the residual loop's models
//! (paper §IV-C with the augmented models). The board side of [`crate::diag::force`]: the models
//! are built for the board as `vfp export --augmented` builds them ([`crate::board::augmented`]),
//! run by the firmware's own estimator ([`crate::board::replay`]), and the board's residuals
//! summarised by the analysis' own code ([`crate::diag::force`]'s filter, error statistics and
//! noise floors), so the two reports compare like with like.

use std::collections::BTreeMap;

use serde::Serialize;

use crate::dataset::LogData;
use crate::diag::force::{
    area_of, ident_dataset, signed_force, summarize, too_few, ForceOptions, ForceReport,
    ForceTrace, Residuals,
};
use crate::diag::DiagError;

/// Per chamber: the board model `vfp force --augmented` estimated with.
#[derive(Debug, Clone, Serialize)]
pub struct AugmentedChamber {
    /// Chamber index.
    pub chamber: u8,
    /// Effects the board's model carries (inertance folded into the polynomial, then the chain's
    /// effects in evaluation order); empty: the residual loop kept none the board can run.
    pub effects: Vec<&'static str>,
    /// Effects the loop kept that stay on the host, with the reason.
    pub host_only: Vec<crate::board::augmented::Dropped>,
    /// Held-out RMSE of the board's model on the identification log, run by the firmware's
    /// estimator in f32 (kPa); also the report's `ident_rmse_kpa`.
    pub device_heldout_rmse_kpa: f64,
    /// Held-out RMSE of the loop's baseline polynomial on the same cycles (kPa).
    pub baseline_heldout_rmse_kpa: f64,
}

/// The report of `vfp force --augmented`: every key of [`ForceReport`] plus the board models.
#[derive(Debug, Serialize)]
pub struct AugmentedForceReport {
    /// The estimate, with the keys of the bare report.
    #[serde(flatten)]
    pub force: ForceReport,
    /// Matched test-log instants where the board gave no estimate (a chain's or AR history still
    /// filling, or a sample outside the model's range), left out of every statistic.
    pub no_estimate: usize,
    /// The model each chamber's board ran.
    pub augmented: Vec<AugmentedChamber>,
}

/// `vfp force --augmented`: the force the board would estimate with the augmented models.
///
/// Per chamber of `test`, the residual loop runs on `ident`'s data set of that chamber with
/// `cfg` and its model is built for the board exactly as `vfp export --augmented` builds it
/// ([`crate::board::augmented::export_dataset`]: polynomial, folded inertance and effect chain).
/// The three models are installed in the firmware's own estimator and `test`'s frames replayed
/// through it ([`crate::board::replay::replay`]: the chain's state carried from frame to frame, `f32`).
/// The force is the board's residuals through the device's force law with the areas of `args`,
/// kept signed as in [`estimate`] (the board's telemetry sends `|Σ Aᵢ·rᵢ|`), then filtered and
/// summarised as there, so the two reports compare like with like.
pub fn estimate_augmented(
    ident: &LogData,
    test: &LogData,
    args: &ForceOptions,
    cfg: &crate::residual::Config,
) -> Result<(AugmentedForceReport, ForceTrace), DiagError> {
    let BoardModels {
        models,
        chambers: augmented,
    } = augmented_models(ident, test, cfg)?;
    let (summary, frames) =
        crate::board::replay::replay(&models, test).map_err(|e| DiagError::Input {
            path: test.path.clone(),
            line: None,
            column: None,
            msg: e.0,
        })?;
    let ident_rmse = augmented
        .iter()
        .map(|a| (a.chamber, a.device_heldout_rmse_kpa))
        .collect();
    let (res, no_estimate) = board_residuals(test, args, &frames, ident_rmse, summary.unmatched)?;
    if res.t.len() < 3 {
        return Err(too_few(
            test,
            "where every chamber has a sample and the board an estimate",
        ));
    }
    let (force, trace) = summarize(ident, test, args, res);
    Ok((
        AugmentedForceReport {
            force,
            no_estimate,
            augmented,
        },
        trace,
    ))
}

/// The board models of [`estimate_augmented`], by chamber (`None`: not in the test log), and
/// what each carries.
struct BoardModels {
    models: [Option<firmware::store::Model>; crate::board::replay::CHAMBERS],
    chambers: Vec<AugmentedChamber>,
}

/// Per chamber of `test` the loop on `ident`'s data set and `vfp export --augmented`'s model.
fn augmented_models(
    ident: &LogData,
    test: &LogData,
    cfg: &crate::residual::Config,
) -> Result<BoardModels, DiagError> {
    use crate::board::replay::CHAMBERS;
    let mut models = [None; CHAMBERS];
    let mut augmented = Vec::new();
    for s in &test.datasets {
        let c = s.chamber;
        if c as usize >= CHAMBERS {
            return Err(DiagError::Input {
                path: test.path.clone(),
                line: None,
                column: Some("chamber".into()),
                msg: format!("chamber {c}: the board has chambers 0..={}", CHAMBERS - 1),
            });
        }
        let x = crate::board::augmented::export_dataset(ident_dataset(ident, c)?, cfg).map_err(
            |e| {
                DiagError::fit(
                    format!("{}, chamber {c}", ident.path.display()),
                    e.to_string(),
                )
            },
        )?;
        models[c as usize] = Some(x.device.board_model());
        augmented.push(AugmentedChamber {
            chamber: c,
            effects: x.carried.iter().map(|e| e.name).collect(),
            host_only: x.dropped.clone(),
            device_heldout_rmse_kpa: x.rmse.device,
            baseline_heldout_rmse_kpa: x.rmse.baseline,
        });
    }
    Ok(BoardModels {
        models,
        chambers: augmented,
    })
}

/// The replayed frames as [`Residuals`] (frames where a chamber of `test` has no board estimate
/// left out and counted): the board's load pressures (its residuals with the chain's sensor lag
/// undone, `ReplayFrame::load_kpa`) through the device's force law, signed.
fn board_residuals(
    test: &LogData,
    args: &ForceOptions,
    frames: &[crate::board::replay::ReplayFrame],
    ident_rmse: BTreeMap<u8, f64>,
    unmatched: usize,
) -> Result<(Residuals, usize), DiagError> {
    let areas: [f32; 3] = core::array::from_fn(|c| area_of(args, c as u8) as f32);
    let used: Vec<u8> = ident_rmse.keys().copied().collect();
    let mut res = Residuals {
        t: Vec::new(),
        raw: Vec::new(),
        truth: frames.iter().any(|f| f.force_ref.is_some()).then(Vec::new),
        pressures: BTreeMap::new(),
        ident_rmse,
        unmatched,
    };
    let mut no_estimate = 0;
    for f in frames {
        let chambers = &f.frame.chambers;
        if used.iter().any(|&c| !f.load_kpa[c as usize].is_finite()) {
            no_estimate += 1;
            continue;
        }
        // Chambers absent from the test log contribute a zero residual, as in `estimate`.
        let mut r = [0.0f32; 3];
        for &c in &used {
            let ch = &chambers[c as usize];
            r[c as usize] = f.load_kpa[c as usize];
            let e = res.pressures.entry(c).or_default();
            e.0.push(f64::from(ch.p));
            e.1.push(f64::from(ch.p_hat));
        }
        res.raw.push(signed_force(r, areas, test, f.t)?);
        res.t.push(f.t);
        if let Some(tr) = &mut res.truth {
            tr.push(f.force_ref.unwrap_or(f64::NAN));
        }
    }
    Ok((res, no_estimate))
}
