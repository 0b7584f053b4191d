//! Inertance: the water column's mass, one added column `L·v̈` (v̈ the volumetric acceleration,
//! on frame means its mean over each frame), no searched parameter; admissible only with `L ≥ 0`.

use super::{param, Column, DeviceSupport, Effect, EffectModel, Fitted, Param, Prepared, Scales};

/// Fluid inertance of the line (v̈ term).
pub struct Inertance;

impl EffectModel for Inertance {
    fn name(&self) -> &'static str {
        "inertance"
    }

    fn story(&self) -> &'static str {
        "The water column in the tube has mass, so accelerating the flow takes a pressure proportional to the volumetric acceleration."
    }

    /// On the firmware's frames with its logged flow (`Series::flow_in_frames`: a log with its
    /// `flags` column) the averaging sensor reports each frame's mean of `L·v̈` over the
    /// instants it averages: the column is that mean over the motion rebuilt inside the frames
    /// (`inframe::SubMotion::frame_mean_accelerations`). The Hermite acceleration at the frame,
    /// used before, spread a short ramp's acceleration over the neighbouring frames, and the
    /// inertance fitted on it was 5–20 % short on the loop benchmark (issue 34). Otherwise
    /// (samples at instants, another rig's log, `Series::new`, a derived flow) `Series::vddot`,
    /// which looks a sample ahead. The board's
    /// form ([`Effect::board_form`]) has only the past: the end slope of the volume's cubic over
    /// the last frame (`signal::acceleration_causal`, as `model_core::chain` computes it).
    fn columns(&self, e: &Effect, prep: &Prepared, _v: &[f64]) -> Vec<Column> {
        let se = &prep.series;
        let acc = if e.board_form {
            crate::residual::signal::acceleration_causal(&se.t, &se.v, &se.vdot)
        } else if se.flow_in_frames {
            prep.sub_motion().frame_mean_accelerations(&se.t)
        } else {
            se.vddot.clone()
        };
        vec![Column::new(acc, "inertance vddot")]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::Inertance)
    }

    fn folds_into_polynomial(&self) -> bool {
        true
    }

    fn device_params(&self, _e: &Effect, coefs: &[f64]) -> Option<Vec<f64>> {
        Some(vec![*coefs.first()?])
    }

    fn unphysical(&self, _e: &Effect, coefs: &[f64], _sc: &Scales) -> Option<String> {
        let &l = coefs.first()?;
        (l < 0.0).then(|| {
            format!("inertance L = {l:.3e} kPa·s²/mm³ is negative, which no mass of water gives")
        })
    }

    fn nonnegative(&self, name: &str) -> bool {
        name == "inertance"
    }
    fn presence(&self) -> Option<&'static str> {
        Some("inertance")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![param("inertance", f.coef(0), f.coef_se(0), "kPa*s^2/mm3")]
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device("the board's chain adds L·v̈ with v̈ the end slope of the volume's cubic over the last frame (`model <ch> effect inertance <L>`); `device_model` can fold it into the polynomial as an AR(1) flow term instead")
    }
}
