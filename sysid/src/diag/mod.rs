//! Diagnostics of the paper's section IV, as `vfp` commands on actuation logs:
//!
//! - [`stiffness`]: pointwise stiffness kᵢ = ∂P/∂v and damping cᵢ = ∂P/∂v̇ of the identified
//!   polynomial, their means overall and per phase (§IV-A, Fig. 7c–d);
//! - [`air_scan`]: the same over several logs, e.g. air pockets of growing volume, with the trend;
//! - [`chow`]: the Chow test between logs with a common polynomial shape (§IV-B, Table VI), made
//!   robust to the serial correlation of 25 Hz residuals;
//! - [`force`]: external force from per-chamber pressure residuals (§IV-C, Fig. 8).
//!
//! Each command has a human report, `--json` and `--plots DIR` (SVG figures).

pub mod air_scan;
pub mod chow;
mod error;
pub mod force;
pub mod input;
mod plot;
pub mod stiffness;

pub use error::DiagError;

use std::path::PathBuf;

/// Highest degrees of v (`n`) and of v̇ (`m`) of the polynomial P̂ = Σ αᵢⱼ vⁱ v̇ʲ; the paper's
/// choice is n = 3, m = 2 (12 coefficients).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Shape {
    /// Highest power of v.
    pub n: usize,
    /// Highest power of v̇.
    pub m: usize,
}

impl Shape {
    /// The paper's selected shape.
    pub const PAPER: Shape = Shape { n: 3, m: 2 };

    /// Number of coefficients (n + 1)(m + 1).
    pub fn terms(&self) -> usize {
        (self.n + 1) * (self.m + 1)
    }
}

/// Model options shared by the diagnostics commands.
#[derive(Debug, Clone, clap::Args)]
pub struct ModelOpts {
    /// Highest power of volume v in the polynomial.
    #[arg(long, default_value_t = 3)]
    pub n: usize,
    /// Highest power of flow v̇ in the polynomial.
    #[arg(long, default_value_t = 2)]
    pub m: usize,
    /// Analyse only this chamber (0..=2); default: every chamber in the log.
    #[arg(long)]
    pub chamber: Option<u8>,
    /// Dead band on |v̇| (mm³/s) separating inflation (v̇ > band) and deflation (v̇ < −band)
    /// from rest.
    #[arg(long, default_value_t = 2.0)]
    pub deadband: f64,
}

impl ModelOpts {
    /// The polynomial shape.
    pub fn shape(&self) -> Shape {
        Shape {
            n: self.n,
            m: self.m,
        }
    }

    /// Checks ranges (shape as in the paper's sweep, chamber 0..=2, finite non-negative band).
    pub fn validate(&self) -> Result<(), DiagError> {
        if !(1..=7).contains(&self.n) || !(1..=7).contains(&self.m) {
            return Err(DiagError::Usage(format!(
                "--n {} --m {}: degrees must be 1..=7 (the paper's sweep)",
                self.n, self.m
            )));
        }
        if let Some(c) = self.chamber {
            if c > 2 {
                return Err(DiagError::Usage(format!(
                    "--chamber {c}: chambers are 0, 1 and 2"
                )));
            }
        }
        if !(self.deadband.is_finite() && self.deadband >= 0.0) {
            return Err(DiagError::Usage(format!(
                "--deadband {}: must be a finite flow >= 0 mm3/s",
                self.deadband
            )));
        }
        Ok(())
    }
}

impl Default for ModelOpts {
    fn default() -> Self {
        ModelOpts {
            n: 3,
            m: 2,
            chamber: None,
            deadband: 2.0,
        }
    }
}

/// Output options shared by the diagnostics commands.
#[derive(Debug, Clone, Default, clap::Args)]
pub struct OutputOpts {
    /// Print one JSON document instead of the human report.
    #[arg(long)]
    pub json: bool,
    /// Write SVG figures into this directory (created if needed).
    #[arg(long, value_name = "DIR")]
    pub plots: Option<PathBuf>,
}

impl OutputOpts {
    /// Writes the figure when `--plots DIR` asks for it (`plot` gets the directory and returns the
    /// file it wrote), then the report: pretty JSON with `--json`, else `human(report)`.
    pub(crate) fn emit<T: serde::Serialize>(
        &self,
        report: &T,
        human: impl Fn(&T) -> String,
        plot: impl FnOnce(&std::path::Path) -> Result<PathBuf, DiagError>,
    ) -> Result<(), DiagError> {
        if let Some(dir) = &self.plots {
            let path = plot(dir)?;
            if !self.json {
                println!("figure: {}", path.display());
            }
        }
        if self.json {
            print_json(report);
        } else {
            print!("{}", human(report));
        }
        Ok(())
    }
}

/// Prints a serialisable report as pretty JSON on stdout (non-finite numbers become null).
pub(crate) fn print_json<T: serde::Serialize>(value: &T) {
    // Serialising plain structs of numbers and strings into a String cannot fail.
    let text =
        serde_json::to_string_pretty(value).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}"));
    println!("{text}");
}
