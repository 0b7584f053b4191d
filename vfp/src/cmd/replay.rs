//! `vfp replay MODEL LOG [-o OUT.csv] [--json]`: what the board would have estimated on a log.
//! The model file is `vfp export` output (its `model …` lines, the effect chain included); the
//! replay is [`sysid::board::replay`]: the firmware library's own estimator, compiled for the host, run
//! over the log's frames.

use crate::opts::{print_json, DataOpts};
use crate::Error;
use std::io::Write;
use std::path::PathBuf;
use sysid::board::deploy::{board_models, parse_lines};
use sysid::board::replay::{replay, ReplayFrame, ReplaySummary};

/// `vfp replay`: the board's estimator over a log.
#[derive(Debug, Clone, clap::Args)]
pub struct Args {
    /// Model lines as printed by `vfp export` (comments and Rust constants are skipped).
    pub model: PathBuf,
    /// The log to replay.
    pub log: PathBuf,
    /// Write every frame (time, per chamber P, P̂, residual, k, c; force and reference force) to
    /// this CSV file.
    #[arg(short = 'o', long = "out", value_name = "OUT.csv")]
    pub out: Option<PathBuf>,
    /// Print the summary as JSON.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub data: DataOpts,
}

/// Runs `vfp replay`.
pub fn run(args: &Args) -> Result<(), Error> {
    let name = args.model.display().to_string();
    let text =
        std::fs::read_to_string(&args.model).map_err(|e| Error::Msg(format!("{name}: {e}")))?;
    let uploads = parse_lines(&text, &name)?;
    let models = board_models(&uploads).map_err(|e| Error::Msg(format!("{name}: {e}")))?;
    let data = args.data.load(&args.log, None)?;
    let (summary, frames) = replay(&models, &data).map_err(|e| Error::Msg(e.to_string()))?;
    if let Some(out) = &args.out {
        write_csv(out, &frames)
            .map_err(|e| Error::Msg(format!("{}: cannot write: {e}", out.display())))?;
    }
    if args.json {
        print_json(&summary)
    } else {
        print!("{}", human(&summary));
        Ok(())
    }
}

/// Every frame as CSV: `time_s`, per chamber `p_i,p_hat_i,residual_i,k_i,c_i`, `force_n` (the
/// board's estimate) and `force_ref_n` (the log's, empty without one). Values are the board's
/// `f32` in shortest round-trip form.
pub fn write_csv(path: &std::path::Path, frames: &[ReplayFrame]) -> std::io::Result<()> {
    let mut w = std::io::BufWriter::new(std::fs::File::create(path)?);
    write!(w, "time_s")?;
    for ch in 0..sysid::board::replay::CHAMBERS {
        write!(w, ",p_{ch},p_hat_{ch},residual_{ch},k_{ch},c_{ch}")?;
    }
    writeln!(w, ",force_n,force_ref_n")?;
    for f in frames {
        write!(w, "{}", f.t)?;
        for c in &f.frame.chambers {
            write!(w, ",{},{},{},{},{}", c.p, c.p_hat, c.residual, c.k, c.c)?;
        }
        let r = f.force_ref.map(|x| x.to_string()).unwrap_or_default();
        writeln!(w, ",{},{r}", f.frame.force_n)?;
    }
    w.flush()
}

/// The human summary.
pub fn human(s: &ReplaySummary) -> String {
    let mut out = format!(
        "The board's estimator over {} frames at {} Hz{}\n\n  chamber  model  effects                      frames  no estimate  P̂ RMSE (kPa)  held-out (kPa)\n",
        s.frames,
        s.frame_hz,
        if s.unmatched > 0 {
            format!(" ({} log instants dropped: a chamber had no sample near them)", s.unmatched)
        } else {
            String::new()
        }
    );
    for c in &s.chambers {
        let fx = if c.effects.is_empty() {
            "-".to_string()
        } else {
            c.effects.join(",")
        };
        out += &format!(
            "  {:>7}  {:<5}  {:<27} {:>7} {:>12} {:>13.4} {:>15.4}\n",
            c.chamber,
            c.model,
            fx,
            c.frames,
            c.no_estimate,
            c.p_hat_rmse_kpa,
            c.p_hat_rmse_heldout_kpa
        );
    }
    match &s.force {
        Some(f) => {
            out += &format!(
                "\nforce error against force_n: {:.2} +/- {:.2} mN (mean +/- std), RMSE {:.2} mN over {} frames\n",
                f.mean_error_n * 1e3,
                f.std_error_n * 1e3,
                f.rmse_n * 1e3,
                f.frames
            )
        }
        None => out += "\nno force_n column (or no frame with every chamber): no force error\n",
    }
    out
}
