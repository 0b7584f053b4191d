//! Transport delay: pressure reported a fixed time d after the volume that caused it, the input
//! transform `v'(t) = v(t − d)`, `v̇'(t) = v̇(t − d)` on the Hermite interpolant of the samples, taken
//! as frame means or as instants (both tried, [`Effect::point_sampled`]).

use super::{
    param, DeviceSupport, Effect, EffectModel, Fitted, Inputs, Param, Prepared, Scales, Search,
};
use crate::residual::signal;

/// Pure time delay between volume and pressure.
pub struct TransportDelay;

impl EffectModel for TransportDelay {
    fn name(&self) -> &'static str {
        "transport_delay"
    }

    fn story(&self) -> &'static str {
        "Pressure is reported a fixed time after the volume that caused it (a sampling offset or pressure-wave travel), so the whole pressure trace is shifted in time."
    }

    /// One delay: a single minimum of the SSE over the search range.
    fn one_minimum(&self) -> bool {
        true
    }

    /// From a twentieth of a frame, as the sensor lag: on frame means a delay that short still
    /// moves each frame by d·Ṗ, as a lag of the same mean delay does, and only a delay that
    /// can be fitted there is listed beside the lags it cannot be told from. (From a quarter
    /// before: the loop benchmark's 2–9 ms delays were named lags with no delay among their
    /// alternatives; the user guide's benchmarks, "The delays' floors".)
    fn search(&self, sc: &Scales) -> Search {
        Search::Log(0.05 * sc.dt, (1.5f64).min(sc.duration / 20.0).max(sc.dt))
    }

    /// A delay's mean delay is the delay.
    fn mean_delay(&self, e: &Effect, _prep: &Prepared) -> Option<f64> {
        Some(e.theta)
    }

    fn theta_at_mean_delay(&self, d: f64) -> Option<f64> {
        Some(d)
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn tries_point_sampled(&self) -> bool {
        true
    }

    /// Not on the firmware's frames: they are means, and a delay between instants there took
    /// the place of a planted delivery lag on host-sim's step-train drive (`residual_decide`,
    /// seed 48: the experiment's log decided for a 6 ms delay between instants, z = 2.37).
    fn point_sampled_on_frames(&self) -> bool {
        false
    }

    fn input_stage(&self) -> Option<u32> {
        Some(10)
    }

    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        let t = &prep.series.t;
        (inputs.v, inputs.f) =
            signal::delay_hermite(t, &inputs.v, &inputs.f, e.theta, !e.point_sampled);
    }

    fn presence(&self) -> Option<&'static str> {
        Some("delay")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![
            param("delay", f.effect.theta, f.theta_se, "s"),
            f.frame_averaged(),
        ]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::TransportDelay)
    }

    fn device_params(&self, e: &Effect, coefs: &[f64]) -> Option<Vec<f64>> {
        let _ = coefs;
        Some(vec![e.theta])
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device(
            "the board's chain delays v and v̇ on the cubic Hermite through its last 40 frames (`model <ch> effect transport_delay <d>`, d ≤ 1.5 s)",
        )
    }
}
