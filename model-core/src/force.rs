//! External force from pressure residuals (paper, Sec. "External Force Estimation"):
//!
//! ```text
//! F_i = (P_i,measured − P̂_i) · A_i,        F = | Σ_i F_i |
//! ```
//!
//! with the effective chamber area A_i (22 mm² in the paper). Units: kPa · mm² = 10³ N/m² · 10⁻⁶ m²
//! = 1 mN, so F_i in N = (r_i in kPa) · (A_i in mm²) · 10⁻³.

use crate::error::{finite, ModelError};

/// Effective cross-sectional area of one SBA chamber used in the paper, mm².
pub const DEFAULT_AREA_MM2: f32 = 22.0;
/// The default area for all three chambers.
pub const DEFAULT_AREAS_MM2: [f32; 3] = [DEFAULT_AREA_MM2; 3];
/// Largest accepted effective area, mm² (a 1 m² "chamber" is certainly a unit mistake).
pub const MAX_AREA_MM2: f32 = 1.0e6;

/// Force estimate of one sample.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct ForceEstimate {
    /// Magnitude of the summed chamber forces, |Σ F_i|, N (the paper's estimate).
    pub total_n: f32,
    /// Signed contribution of each chamber, F_i = r_i · A_i, N; positive when the measured pressure
    /// exceeds the prediction (the chamber is being pushed in).
    pub per_chamber_n: [f32; 3],
}

impl ForceEstimate {
    /// The signed sum Σ F_i, N (positive: compression).
    pub fn signed_total_n(&self) -> f32 {
        self.per_chamber_n.iter().sum()
    }
}

/// Per-chamber residual r_i = measured − predicted, kPa (`NonFinite` if any is NaN/∞).
pub fn residuals(measured_kpa: [f32; 3], predicted_kpa: [f32; 3]) -> Result<[f32; 3], ModelError> {
    let mut r = [0.0f32; 3];
    for i in 0..3 {
        r[i] = finite(finite(measured_kpa[i])? - finite(predicted_kpa[i])?)?;
    }
    Ok(r)
}

/// Force from per-chamber residuals (kPa) and effective areas (mm²).
///
/// Errors: `NonFinite` for a NaN/∞ residual or area, `BadParameter` for an area ≤ 0 or above
/// [`MAX_AREA_MM2`].
pub fn estimate(residual_kpa: [f32; 3], area_mm2: [f32; 3]) -> Result<ForceEstimate, ModelError> {
    let mut per = [0.0f32; 3];
    for i in 0..3 {
        let a = finite(area_mm2[i])?;
        if a <= 0.0 || a > MAX_AREA_MM2 {
            return Err(ModelError::BadParameter);
        }
        // kPa · mm² = mN.
        per[i] = finite(finite(residual_kpa[i])? * a * 1.0e-3)?;
    }
    let sum = finite(per[0] + per[1] + per[2])?;
    Ok(ForceEstimate {
        total_n: libm::fabsf(sum),
        per_chamber_n: per,
    })
}
