//! Replay (behind `vfp replay MODEL LOG`): what the board would have estimated on a log. The
//! model file's uploads (`vfp export` lines, [`crate::board::deploy::parse_lines`], made the board's
//! models by [`crate::board::deploy::board_models`]) are installed into
//! the firmware library's own estimator (`firmware::app::Estimator`, the code the board runs,
//! compiled for the host), and the log's frames go through
//! `Estimator::estimate_frame` in order: the effect chain, P̂, residual `P − P̂`, k, c and the
//! force `Σ A_i·(P_i − P̂_i)` are the board's own `f32` arithmetic on the logged `v`, `v̇` and
//! zeroed `P`.
//!
//! The chamber's frames are matched by time as in `vfp force` (the chamber with fewest samples
//! sets the instants, the others' nearest sample within half a period). A chamber the log does
//! not have gets NaN inputs (no estimate, as a board with its sensor unplugged; the force, which
//! sums every chamber, is then NaN too); a chamber the model file does not load runs the board's
//! boot model (SBA1), as the board would. The frame period the chain uses is the board's
//! `1/frame_hz` with `frame_hz` the log's median sample rate rounded to whole Hz, and every
//! chain starts on the log's first matched frame (as after a model load or `origin`).
//!
//! Summaries: per chamber the RMSE of P̂ against the measured pressure over every frame with an
//! estimate and over the held-out cycles alone (the split of `vfp identify`); with a `force_n`
//! column, the force error `F̂ − F` (mean, standard deviation, RMSE, N).

use std::collections::BTreeMap;

use firmware::app::{Config, Estimator, EventBuf};
use firmware::store::Model;
use firmware::telemetry::{ChamberFrame, Frame};

use crate::dataset::{Dataset, LogData};

/// Number of chambers the board estimates (its axes, `firmware::hal::AXES`).
pub const CHAMBERS: usize = firmware::hal::AXES;

/// Why a replay could not run.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct ReplayError(pub String);

/// One replayed frame.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayFrame {
    /// Time of the log's frame, s.
    pub t: f64,
    /// The board's frame (P̂, residual, k, c per chamber, force).
    pub frame: Frame,
    /// Per chamber the load pressure the board's force is made of, kPa: the residual with the
    /// chain's sensor lag undone (`model_core::chain::Chain::load_pressure`).
    pub load_kpa: [f32; CHAMBERS],
    /// Reference force of the log, N, when it has one.
    pub force_ref: Option<f64>,
    /// Whether the frame lies in a held-out cycle.
    pub heldout: bool,
}

/// Per chamber: how well P̂ follows the measured pressure.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ChamberSummary {
    /// Chamber.
    pub chamber: u8,
    /// `file` when the model file loads it, else `boot` (the board's SBA1 default).
    pub model: &'static str,
    /// Effects of its chain, in evaluation order.
    pub effects: Vec<&'static str>,
    /// Frames with an estimate.
    pub frames: usize,
    /// Frames without one (out of the model's range, history filling).
    pub no_estimate: usize,
    /// RMSE of P̂ against the measured pressure, kPa.
    pub p_hat_rmse_kpa: f64,
    /// The same over the held-out cycles, kPa (NaN without any).
    pub p_hat_rmse_heldout_kpa: f64,
}

/// The board's force against the log's `force_n`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ForceError {
    /// Frames with both a force estimate and a reference.
    pub frames: usize,
    /// Mean of `F̂ − F`, N.
    pub mean_error_n: f64,
    /// Standard deviation of `F̂ − F`, N.
    pub std_error_n: f64,
    /// RMSE of `F̂ − F`, N.
    pub rmse_n: f64,
}

/// What `vfp replay --json` prints.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ReplaySummary {
    /// Frame rate the chains ran at, Hz.
    pub frame_hz: u32,
    /// Frames replayed (instants where the log's chambers were matched).
    pub frames: usize,
    /// Log instants dropped because a chamber had no sample near them.
    pub unmatched: usize,
    /// Per chamber of the log.
    pub chambers: Vec<ChamberSummary>,
    /// Force error, when the log has `force_n`.
    pub force: Option<ForceError>,
}

/// An estimator with `models` installed, its chains at `frame_hz`.
pub fn estimator(models: &[Option<Model>; CHAMBERS], frame_hz: u32) -> Estimator {
    let mut est = Estimator::new(Config {
        frame_hz,
        ..Config::default()
    });
    for (ch, m) in models.iter().enumerate() {
        if let Some(m) = m {
            est.install_boot(ch, *m);
        }
    }
    est
}

/// What the board's estimator made of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BoardFrame {
    /// The frame it streams.
    pub frame: Frame,
    /// Per chamber the load pressure behind its force, kPa.
    pub load_kpa: [f32; CHAMBERS],
}

/// Runs `frames` (time in s, per chamber `(v, v̇, P)`) through a fresh [`estimator`].
pub fn run(
    models: &[Option<Model>; CHAMBERS],
    frame_hz: u32,
    frames: impl IntoIterator<Item = (f64, [(f32, f32, f32); CHAMBERS])>,
) -> Vec<BoardFrame> {
    let mut est = estimator(models, frame_hz);
    let mut events = EventBuf::new();
    frames
        .into_iter()
        .map(|(t, x)| {
            let chambers = x.map(|(v, vdot, p)| ChamberFrame {
                v,
                vdot,
                p,
                ..ChamberFrame::default()
            });
            events.clear();
            let frame =
                est.estimate_frame(chambers, (t * 1e6).round().max(0.0) as u64, &mut events);
            BoardFrame {
                frame,
                load_kpa: est.load_kpa(),
            }
        })
        .collect()
}

/// The board's frame rate for a log sampled every `dt` s (median), whole Hz.
pub fn frame_hz(dt: f64) -> Result<u32, ReplayError> {
    let hz = (1.0 / dt).round();
    if !(hz.is_finite() && (1.0..=1000.0).contains(&hz)) {
        return Err(ReplayError(format!(
            "the log's median sample interval {dt} s is not a board frame rate (1 to 1000 Hz)"
        )));
    }
    Ok(hz as u32)
}

/// Replays `data` with `models` (module docs): every frame, and the summary.
pub fn replay(
    models: &[Option<Model>; CHAMBERS],
    data: &LogData,
) -> Result<(ReplaySummary, Vec<ReplayFrame>), ReplayError> {
    let by_ch: BTreeMap<u8, &Dataset> = data.datasets.iter().map(|d| (d.chamber, d)).collect();
    if let Some(&c) = by_ch.keys().find(|&&c| c as usize >= CHAMBERS) {
        return Err(ReplayError(format!(
            "{}: chamber {c}: the board has chambers 0..=2",
            data.path.display()
        )));
    }
    let (rows, unmatched) = crate::diag::force::match_times(&by_ch);
    let first = data.first();
    let hz = frame_hz(crate::dataset::median_dt(&first.t))?;
    let nan = (f32::NAN, f32::NAN, f32::NAN);
    let inputs = rows.iter().map(|row| {
        let (&c0, &i0) = row.iter().next().expect("a matched row has a chamber");
        let t = by_ch[&c0].t[i0];
        let x = core::array::from_fn(|ch| match row.get(&(ch as u8)) {
            Some(&i) => {
                let d = by_ch[&(ch as u8)];
                (d.v[i] as f32, d.vdot[i] as f32, d.p[i] as f32)
            }
            None => nan,
        });
        (t, x)
    });
    let board = run(models, hz, inputs);
    let frames: Vec<ReplayFrame> = rows
        .iter()
        .zip(board)
        .map(|(row, b)| {
            let (&c0, &i0) = row.iter().next().expect("a matched row has a chamber");
            let d = by_ch[&c0];
            ReplayFrame {
                t: d.t[i0],
                frame: b.frame,
                load_kpa: b.load_kpa,
                force_ref: d.force.as_ref().map(|f| f[i0]),
                heldout: d.heldout[i0],
            }
        })
        .collect();
    let chambers = by_ch
        .keys()
        .map(|&c| chamber_summary(c, models[c as usize].as_ref(), &frames))
        .collect();
    let summary = ReplaySummary {
        frame_hz: hz,
        frames: frames.len(),
        unmatched,
        chambers,
        force: force_error(&frames),
    };
    Ok((summary, frames))
}

fn rms(x: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = x.fold((0.0, 0usize), |(s, n), r| (s + r * r, n + 1));
    if n == 0 {
        f64::NAN
    } else {
        (s / n as f64).sqrt()
    }
}

fn chamber_summary(c: u8, model: Option<&Model>, frames: &[ReplayFrame]) -> ChamberSummary {
    let ch = c as usize;
    let res = |held: bool| {
        frames
            .iter()
            .filter(move |f| !held || f.heldout)
            .map(move |f| f.frame.chambers[ch].residual as f64)
            .filter(|r| r.is_finite())
    };
    let n = res(false).count();
    ChamberSummary {
        chamber: c,
        model: if model.is_some() { "file" } else { "boot" },
        effects: model
            .map(|m| m.chain.effects().iter().map(|e| e.kind().name()).collect())
            .unwrap_or_default(),
        frames: n,
        no_estimate: frames.len() - n,
        p_hat_rmse_kpa: rms(res(false)),
        p_hat_rmse_heldout_kpa: rms(res(true)),
    }
}

fn force_error(frames: &[ReplayFrame]) -> Option<ForceError> {
    let e: Vec<f64> = frames
        .iter()
        .filter_map(|f| Some(f.frame.force_n as f64 - f.force_ref?))
        .filter(|e| e.is_finite())
        .collect();
    if e.is_empty() {
        return None;
    }
    let n = e.len() as f64;
    let mean = e.iter().sum::<f64>() / n;
    let var = e.iter().map(|x| (x - mean) * (x - mean)).sum::<f64>() / n;
    Some(ForceError {
        frames: e.len(),
        mean_error_n: mean,
        std_error_n: var.sqrt(),
        rmse_n: rms(e.iter().copied()),
    })
}
