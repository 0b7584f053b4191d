//! Leak: fluid escaping at a rate proportional to pressure, `q_leak = λ P`, the input transform
//! `v' = v − λ ∫P dt`, `v̇' = v̇ − λ P`, with the measured pressure (the chamber's, behind a sensor lag the model has; integrated, never
//! differentiated, so its noise does not enter the regressors).

use super::{
    param, DeviceSupport, Effect, EffectModel, Fitted, Inputs, Param, Prepared, Scales, Search,
};

/// Leak: volume lost at a rate proportional to pressure.
pub struct Leak;

impl EffectModel for Leak {
    fn name(&self) -> &'static str {
        "leak"
    }

    fn story(&self) -> &'static str {
        "Fluid escapes through a seal or fitting at a rate proportional to pressure, so the chamber slowly holds less than the syringe has delivered."
    }

    /// One conductance: a single minimum of the SSE over the search range.
    fn one_minimum(&self) -> bool {
        true
    }

    /// λ from the volume range over `∫P dt`; no search when the pressure never rose.
    fn search(&self, sc: &Scales) -> Search {
        if sc.p_integral > 0.0 {
            Search::Log(
                0.002 * sc.v_range / sc.p_integral,
                1.0 * sc.v_range / sc.p_integral,
            )
        } else {
            Search::None
        }
    }

    /// A leak that loses more than a quarter of the stroke over the log (`λ ∫P dt`) would have
    /// emptied a chamber a lab would notice; the fit follows something else (a drifting volume
    /// reading, a slow pressure trend).
    fn unphysical(&self, e: &Effect, _coefs: &[f64], sc: &Scales) -> Option<String> {
        if !e.theta.is_finite() {
            return Some("leak conductance is not finite".into());
        }
        let lost = e.theta * sc.p_integral;
        (lost > 0.25 * sc.v_range).then(|| {
            format!(
                "the leak would lose {lost:.4e} mm³ over the log, {:.0} % of the stroke ({:.4e} mm³)",
                100.0 * lost / sc.v_range,
                sc.v_range
            )
        })
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn input_stage(&self) -> Option<u32> {
        Some(50)
    }

    /// The water lost with the chamber's pressure: `∫ P dt` taken off the volume, `P` off the flow.
    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        let p = e.scheduled_pressure(prep);
        let int = match e.pressure {
            Some(_) => std::borrow::Cow::Owned(crate::residual::signal::cumulative_integral(
                &prep.series.t,
                p,
            )),
            None => std::borrow::Cow::Borrowed(&prep.p_int),
        };
        for k in 0..inputs.v.len() {
            inputs.v[k] -= e.theta * int[k];
            inputs.f[k] -= e.theta * p[k];
        }
    }

    fn uses_measured_pressure(&self) -> bool {
        true
    }

    fn presence(&self) -> Option<&'static str> {
        Some("conductance")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        let (e, pi) = (f.effect, f.prep.scales.p_integral);
        vec![
            param("conductance", e.theta, f.theta_se, "mm3/(kPa*s)"),
            param("volume_lost_over_log", e.theta * pi, f.theta_se * pi, "mm3"),
        ]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::Leak)
    }

    fn device_params(&self, e: &Effect, coefs: &[f64]) -> Option<Vec<f64>> {
        let _ = coefs;
        Some(vec![e.theta])
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device(
            "the board's chain integrates the measured pressure (`model <ch> effect leak <lambda>`)",
        )
    }
}
