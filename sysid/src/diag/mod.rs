//! Diagnostics of the paper's section IV on actuation logs (the `vfp` commands of the same names):
//!
//! - [`stiffness`]: pointwise stiffness kᵢ = ∂P/∂v and damping cᵢ = ∂P/∂v̇ of the identified
//!   polynomial, their means overall and per phase (§IV-A, Fig. 7c–d);
//! - [`air_scan`]: the same over several logs, e.g. air pockets of growing volume, with the trend;
//! - [`chow`]: the Chow test between logs with a common polynomial shape (§IV-B, Table VI), made
//!   robust to the serial correlation of 25 Hz residuals;
//! - [`force`]: external force from per-chamber pressure residuals (§IV-C, Fig. 8).
//!
//! Each returns a typed report (serde `Serialize`: the commands' `--json` documents) and the
//! values its figures need.

pub mod air_scan;
pub mod chow;
mod error;
pub mod force;
pub mod stiffness;

pub use error::DiagError;

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

    /// Checks the degrees (1..=7 each, the paper's sweep).
    pub fn validate(&self) -> Result<(), DiagError> {
        if !(1..=7).contains(&self.n) || !(1..=7).contains(&self.m) {
            return Err(DiagError::Usage(format!(
                "--n {} --m {}: degrees must be 1..=7 (the paper's sweep)",
                self.n, self.m
            )));
        }
        Ok(())
    }

    /// Number of coefficients (n + 1)(m + 1).
    pub fn terms(&self) -> usize {
        (self.n + 1) * (self.m + 1)
    }
}
