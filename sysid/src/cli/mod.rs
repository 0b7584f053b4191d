//! The `vfp` subcommands. Each module has a `#[derive(clap::Args)]` struct and a
//! `run(&Args) -> Result<(), E>` with `E: Display`; `src/bin/vfp.rs` only dispatches, so a new
//! subcommand is a module plus one enum line there.

pub mod export;
pub mod identify;
pub mod plots;
pub mod simulate;

use std::fmt;

/// A command-line failure: one sentence for the user (printed as `vfp: <sentence>`, exit 1).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CliError(pub String);

impl fmt::Display for CliError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for CliError {}

macro_rules! from_display {
    ($($t:ty),*) => {$(
        impl From<$t> for CliError {
            fn from(e: $t) -> Self {
                CliError(e.to_string())
            }
        }
    )*};
}
from_display!(
    crate::log::LogError,
    crate::dataset::DataError,
    crate::poly::PolyError,
    crate::metrics::MetricsError,
    model_core::ModelError
);

impl From<std::io::Error> for CliError {
    fn from(e: std::io::Error) -> Self {
        CliError(format!("I/O error: {e}"))
    }
}

/// Shared options for reading a log into datasets.
#[derive(Debug, Clone, clap::Args)]
pub struct DataOpts {
    /// Analyse only this chamber (0..=2); default: every chamber in the log.
    #[arg(long)]
    pub chamber: Option<u8>,
    /// Hold out one cycle in every K (rotating; 0 = no held-out set).
    #[arg(long, value_name = "K", default_value_t = 5)]
    pub holdout_every: usize,
    /// Derive v̇ from volume even when the log has a flow column.
    #[arg(long)]
    pub derive_flow: bool,
    /// Half-width h of the flow differentiator (window 2h+1 samples).
    #[arg(long, value_name = "H", default_value_t = 2)]
    pub diff_half_width: usize,
    /// Phase-switch deadband on |v̇|, mm³/s (default: 5 % of the 95th percentile of |v̇|).
    #[arg(long, value_name = "MM3_S")]
    pub deadband: Option<f64>,
}

impl DataOpts {
    /// Reads the log and builds the selected chambers' datasets.
    pub fn load(
        &self,
        path: &std::path::Path,
    ) -> Result<(crate::log::Log, Vec<crate::dataset::Dataset>), CliError> {
        let log = crate::log::read_log(path)?;
        if let Some(d) = self.deadband {
            if !(d.is_finite() && d >= 0.0) {
                return Err(CliError(format!(
                    "--deadband {d}: must be a finite flow >= 0 mm3/s"
                )));
            }
        }
        let cfg = crate::dataset::DatasetConfig {
            diff_half_width: self.diff_half_width.max(1),
            derive_flow: self.derive_flow,
            holdout_every: self.holdout_every,
            deadband: self.deadband,
            ..Default::default()
        };
        let chambers = match self.chamber {
            Some(c) if c >= crate::log::MAX_CHAMBERS => {
                return Err(CliError(format!("--chamber {c}: chambers are 0, 1 and 2")));
            }
            Some(c) => vec![c],
            None => log.chambers(),
        };
        let mut out = Vec::new();
        for c in chambers {
            let ds = crate::dataset::Dataset::from_log(&log, c, &cfg)
                .map_err(|e| CliError(format!("{}: {e}", path.display())))?;
            out.push(ds);
        }
        Ok((log, out))
    }
}

/// Formats a number for tables: 4 significant digits, scientific outside [1e-3, 1e5).
pub fn num(x: f64) -> String {
    if !x.is_finite() {
        return "-".into();
    }
    let a = x.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        format!("{x:.4e}")
    } else {
        format!("{x:.4}")
    }
}

/// Formats an optional number.
pub fn opt(x: Option<f64>) -> String {
    x.map_or_else(|| "-".into(), num)
}
