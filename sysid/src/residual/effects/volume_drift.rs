//! Volume drift: the volume reading creeping away from the true volume at a steady rate r, the
//! input transform `v' = v − r·(t − t₀)`, `v̇' = v̇ − r`; r of either sign ([`Search::Signed`]).

use super::{
    param, DeviceSupport, Effect, EffectModel, Fitted, Inputs, Param, Prepared, Scales, Search,
};

/// Slow drift of the volume reading.
pub struct VolumeDrift;

impl EffectModel for VolumeDrift {
    fn name(&self) -> &'static str {
        "volume_drift"
    }

    fn story(&self) -> &'static str {
        "The volume reading creeps away from the true volume at a steady rate (an integrated flow-sensor bias or miscounted steps), so the same pressure appears at a sliding volume."
    }

    /// One rate: a single minimum of the SSE over the search range.
    fn one_minimum(&self) -> bool {
        true
    }

    fn search(&self, sc: &Scales) -> Search {
        Search::Signed(
            0.002 * sc.v_range / sc.duration,
            1.0 * sc.v_range / sc.duration,
        )
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn input_stage(&self) -> Option<u32> {
        Some(40)
    }

    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        let t = &prep.series.t;
        let t0 = t[0];
        for k in 0..inputs.v.len() {
            inputs.v[k] -= e.theta * (t[k] - t0);
            inputs.f[k] -= e.theta;
        }
    }

    fn presence(&self) -> Option<&'static str> {
        Some("rate")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        let (e, d) = (f.effect, f.prep.scales.duration);
        vec![
            param("rate", e.theta, f.theta_se, "mm3/s"),
            param("change_over_log", e.theta * d, f.theta_se * d, "mm3"),
        ]
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::host_only(
            "depends on wall-clock time since the log began; correct the volume source instead",
        )
    }
}
