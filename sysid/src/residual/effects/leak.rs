//! Leak: fluid escaping at a rate proportional to pressure, `q_leak = λ P`, the input transform
//! `v' = v − λ ∫P dt`, `v̇' = v̇ − λ P`, with the measured pressure (the chamber's, behind a sensor lag the model has; integrated, never
//! differentiated, so its noise does not enter the regressors).
//!
//! **Two forms.** Below the atmosphere's pressure an open path (a cracked fitting, a porous wall)
//! draws fluid back in at the same conductance, `q = λ P` at either sign; a seal that closes under
//! suction (a lip seal, a flap) leaks only outwards, `q = λ max(P, 0)` ([`Effect::one_way`]). The
//! two differ only where the chamber goes below the atmosphere (fast deflation through the
//! damping), and there by the whole leak: on host-sim's one-way leak (the loop benchmark, seed 1)
//! the open path's best fit left 1.14–1.17 σ on rigs 24 and 52, and lost a leak of 91 % oracle
//! gain beside a backlash (rig 217). The search fits the open path; its refinement
//! ([`EffectModel::refine`]) fits the one-way form too, its λ by Brent's method, and the model
//! keeps whichever has the lower training SSE (the form is a choice between two models with the
//! same parameters, not a parameter). The board runs the open path: the export refits λ there
//! ([`Effect::board_form`], [`EffectModel::device_retune`]).

use super::{
    param, DeviceSupport, Effect, EffectModel, Fitted, Inputs, ModelView, Param, Prepared, Scales,
    Search,
};
use crate::residual::search::{brent, sse_of, with};

/// `∫ P dt` over the log for a leak of form `one_way` (kPa·s): what it loses water with.
fn pressure_integral(one_way: bool, sc: &Scales) -> f64 {
    if one_way {
        sc.p_pos_integral
    } else {
        sc.p_integral
    }
}

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
        let lost = e.theta * pressure_integral(e.one_way && !e.board_form, sc);
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

    /// The water lost with the chamber's pressure: `∫ P dt` taken off the volume, `P` off the flow
    /// (of the one-way form, the pressure above the atmosphere's only).
    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        let p = e.scheduled_pressure(prep);
        let one_way = e.one_way && !e.board_form;
        let p: std::borrow::Cow<[f64]> = if one_way {
            std::borrow::Cow::Owned(p.iter().map(|&x| x.max(0.0)).collect())
        } else {
            std::borrow::Cow::Borrowed(p)
        };
        let int = if e.pressure.is_some() || one_way {
            std::borrow::Cow::Owned(crate::residual::signal::cumulative_integral(
                &prep.series.t,
                &p,
            ))
        } else {
            std::borrow::Cow::Borrowed(&prep.p_int)
        };
        for k in 0..inputs.v.len() {
            inputs.v[k] -= e.theta * int[k];
            inputs.f[k] -= e.theta * p[k];
        }
    }

    /// The one-way form ([`Effect::one_way`], module docs), its λ by Brent's method on `ln λ`
    /// from a factor e^½ below the open path's to a factor e above it (the one-way leak loses
    /// the water of the positive pressure only, so its λ is at least the open path's where the
    /// chamber spends time below the atmosphere); `None` where the chamber never goes below it
    /// (the two forms are one) or the one-way form fits worse.
    fn refine(
        &self,
        prep: &Prepared,
        base: &[Effect],
        found: &Effect,
        _model: &ModelView,
    ) -> Option<Effect> {
        if found.one_way
            || found.theta.is_nan()
            || found.theta <= 0.0
            || prep.scales.p_pos_integral <= prep.scales.p_integral
        {
            return None;
        }
        let remake = |th: f64| Effect {
            theta: th,
            one_way: true,
            ..found.clone()
        };
        let open = sse_of(prep, &with(base, found.clone()));
        let l = found.theta.ln();
        let (u, sse) = brent(l - 0.5, l + 1.0, 10, |x| {
            sse_of(prep, &with(base, remake(x.exp())))
        });
        (sse < open).then(|| remake(u.exp()))
    }

    /// The one-way form's λ refitted in the board's open path.
    fn device_retune(&self) -> bool {
        true
    }

    fn uses_measured_pressure(&self) -> bool {
        true
    }

    fn presence(&self) -> Option<&'static str> {
        Some("conductance")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        let e = f.effect;
        let pi = pressure_integral(e.one_way && !e.board_form, &f.prep.scales);
        // The form as a number, as the offset drift's degree: 1 one-way, 0 the open path.
        let one_way = if e.one_way && !e.board_form { 1.0 } else { 0.0 };
        vec![
            param("conductance", e.theta, f.theta_se, "mm3/(kPa*s)"),
            param("volume_lost_over_log", e.theta * pi, f.theta_se * pi, "mm3"),
            param("one_way", one_way, f64::NAN, "1"),
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
            "the board's chain integrates the measured pressure at either sign (`model <ch> effect leak <lambda>`); a one-way leak is exported in that form, its λ refitted there",
        )
    }
}
