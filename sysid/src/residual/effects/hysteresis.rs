//! Hysteresis: a direction-dependent, rate-independent pressure offset, two added columns
//! `H(v)·h_w(t)` with `H(v) = H₀ + H₁ x` (x the scaled volume; v the chamber's: the logged
//! volume after the input transforms, such as an air pocket's compression) and `h_w ∈ [−1, 1]` a Duhem
//! hysteron, `dh_w = (s − h_w)|dv|/w`, `s = sign(dv)`: it switches exponentially in volume after
//! each reversal, w the volume over which 63 % of the switch happens, and depends on the path of v,
//! never on its speed. Admissible only if the gap `inflation − deflation = 2(H₀ + H₁x)` is
//! nowhere negative on `x ∈ [−1, 1]` (a loop that returns energy is not friction).

use super::{
    param, Column, DeviceSupport, Effect, EffectModel, Fitted, Param, Prepared, Scales, Search,
};
use crate::residual::signal;

/// Direction-dependent, rate-independent pressure offset.
pub struct Hysteresis;

impl EffectModel for Hysteresis {
    fn name(&self) -> &'static str {
        "hysteresis"
    }

    fn story(&self) -> &'static str {
        "Friction in the membrane folds or the plunger seal makes pressure on the way up exceed pressure on the way down by a gap that does not depend on speed, switching over a small volume after each reversal."
    }

    fn search(&self, sc: &Scales) -> Search {
        Search::Log(0.002 * sc.v_range, 0.5 * sc.v_range)
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    /// The hysteron switches on the chamber's volume: the logged one moved by the input
    /// transforms (an air pocket's compression, a leak's loss).
    fn columns(&self, e: &Effect, prep: &Prepared, v: &[f64]) -> Vec<Column> {
        let h = signal::duhem(v, e.theta);
        let hx: Vec<f64> = h
            .iter()
            .zip(v)
            .map(|(h, v)| h * (v - prep.basis.scaling.v_offset) / prep.basis.scaling.v_scale)
            .collect();
        vec![
            Column::new(h, "hysteresis h_w"),
            Column::new(hx, "hysteresis h_w·x"),
        ]
    }

    fn unphysical(&self, _e: &Effect, coefs: &[f64], _sc: &Scales) -> Option<String> {
        let [h0, h1] = coefs[..] else { return None };
        // Gap 2·(H₀ + H₁x) over x ∈ [−1, 1] (the data's volume range): least at one end.
        let least = 2.0 * (h0 - h1.abs());
        (least < 0.0).then(|| {
            format!(
                "hysteresis gap inflation − deflation reaches {least:.3} kPa (mid-range {:.3} kPa); a loop with deflation above inflation returns energy, which friction cannot",
                2.0 * h0
            )
        })
    }

    fn nonnegative(&self, name: &str) -> bool {
        name == "gap_at_mid_volume"
    }
    fn presence(&self) -> Option<&'static str> {
        Some("gap_at_mid_volume")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![
            // Volume over which 63 % of the switch happens after a reversal.
            param("width", f.effect.theta, f.theta_se, "mm3"),
            param(
                "gap_at_mid_volume",
                2.0 * f.coef(0),
                2.0 * f.coef_se(0),
                "kPa",
            ),
            param(
                "gap_change_to_range_ends",
                2.0 * f.coef(1),
                2.0 * f.coef_se(1),
                "kPa",
            ),
        ]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::Hysteresis)
    }

    fn device_params(&self, e: &Effect, coefs: &[f64]) -> Option<Vec<f64>> {
        // Width, then the columns' coefficients H₀ (on h) and H₁ (on h·x), x in the model's scaling.
        let [h0, h1] = coefs[..] else { return None };
        Some(vec![e.theta, h0, h1])
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device(
            "the board's chain runs the same hysteron on the chamber's volume (the frames' volume after the input transforms: `model <ch> effect hysteresis <w> <H0> <H1>`)",
        )
    }
}
