//! Air compliance: an air pocket of volume `V_a` at atmospheric pressure between plunger and
//! chamber, an isothermal gas (Boyle's law). It stores `V_a·P/(P_atm + P)` of the delivered
//! volume, the input transform `v' = v − V_a·P/(P_atm + P)`, and, charged through the line
//! resistance `c = ∂P/∂v̇` (the model's damping, paper Section V-A), lags the pressure with the
//! time constant of that resistance and the gas spring `dV/dP`, the output filter
//! `τ(t) Ṗ + P = P_static`, `τ(t) = c(v, v̇)·V_a·P_atm/(P_atm + P)²`: most at low pressure. Both use
//! the measured pressure as a scheduling input: the chamber's, so behind a sensor lag the model
//! has, the reading with that lag undone ([`super::design::pressure_schedule`]).

use std::sync::Arc;

use super::{
    param, DeviceSupport, Effect, EffectModel, Fitted, Inputs, ModelView, Needs, Param, Prepared,
    Scales, Search, P_ATM_KPA,
};
use crate::residual::search::{brent, sse_of, with};
use crate::residual::signal;

/// Compressible air between plunger and chamber.
pub struct AirCompliance;

impl EffectModel for AirCompliance {
    fn name(&self) -> &'static str {
        "air_compliance"
    }

    fn story(&self) -> &'static str {
        "A trapped air bubble compresses as pressure rises (Boyle's law), so the chamber receives less volume than the syringe delivers and the pressure lags the plunger, most at low pressure."
    }

    /// One pocket, one time scale: a single minimum of the SSE over the search range.
    fn one_minimum(&self) -> bool {
        true
    }

    fn search(&self, sc: &Scales) -> Search {
        Search::Log(0.002 * sc.v_range, 1.0 * sc.v_range)
    }

    /// An air pocket of more than half the stroke (the paper's pockets are 4–18 % of it) turns
    /// the chamber into a gas spring; the fit follows something else.
    fn unphysical(&self, e: &Effect, _coefs: &[f64], sc: &Scales) -> Option<String> {
        if !e.theta.is_finite() {
            return Some("air volume is not finite".into());
        }
        (e.theta > 0.5 * sc.v_range).then(|| {
            format!(
                "an air pocket of {:.4e} mm³ is {:.0} % of the stroke ({:.4e} mm³)",
                e.theta,
                100.0 * e.theta / sc.v_range,
                sc.v_range
            )
        })
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn needs(&self) -> Needs {
        Needs {
            damping: true,
            stiffness: false,
        }
    }

    /// Rebuilds and filters the whole design at every trial volume.
    fn cost_guess(&self) -> f64 {
        1e3
    }

    /// The damping came from a model fitted without the air pocket (which lowers the apparent
    /// damping); take it once more from the augmented model, at the chamber's volume
    /// `v − V_a·P/(P_atm + P)` where the law is evaluated, and re-tune the air volume. (More
    /// passes were tried: they do not lower the SSE further.)
    ///
    /// The flow there is the one midway between the pump's, `v̇`, and the chamber's, `v̇ − ẋ`
    /// (`ẋ = x'(P)·Ṗ` what the pocket takes, from the scheduled pressure's slopes): the law at the
    /// chamber's flow is `g(v̇ − ẋ) = g(v̇) − g'(v̇ − ẋ/2)·ẋ` exactly when `g` is quadratic in flow
    /// (the paper's m = 2), so the lag `τ Ṗ + P = g(v̇)` with `τ = g'(v̇ − ẋ/2)·x'(P)` carries the
    /// law's flow-squared term, which the damping at `v̇` alone linearised away: at a move's start
    /// the pocket takes much of the flow (`residual_hostsim_shapes`: 20 mm³ on irregular strokes,
    /// 1.105 → 1.040 σ). `ẋ` enters only through the damping's slope in flow, so the slopes' noise
    /// does not reach the fit.
    ///
    /// The air volume returned is re-tuned on that damping; the engine keeps it where the refit
    /// lowers the training SSE.
    fn refine(
        &self,
        prep: &Prepared,
        base: &[Effect],
        found: &Effect,
        model: &ModelView,
    ) -> Option<Effect> {
        let fresh = self.reanchored(prep, found, model)?;
        let remake = |th: f64| Effect {
            theta: th,
            ..fresh.clone()
        };
        let va = fresh.theta;
        let (u, _) = brent(va.ln() - 0.7, va.ln() + 0.7, 10, |x| {
            sse_of(prep, &with(base, remake(x.exp())))
        });
        Some(remake(u.exp()))
    }

    /// The damping at the chamber's volume and the midway flow ([`Self::refine`]) from `model`'s
    /// polynomial and pressure schedule, with the pocket `e` has.
    fn reanchored(&self, prep: &Prepared, e: &Effect, model: &ModelView) -> Option<Effect> {
        let va = e.theta;
        let beta = model.polynomial(prep);
        let se = &prep.series;
        // The chamber's pressure behind the model's sensor lags, as the design will schedule it.
        let sched = super::design::pressure_schedule(prep, model.effects);
        let sched = sched.as_deref().unwrap_or(&prep.p_sched);
        let dp = signal::akima_slopes(&se.t, sched);
        let damping = (0..se.len())
            .map(|k| {
                let p = sched[k].max(-0.9 * P_ATM_KPA);
                let v = se.v[k] - va * p / (P_ATM_KPA + p);
                let xdot = va * P_ATM_KPA / (P_ATM_KPA + p).powi(2) * dp[k];
                prep.basis.damping(beta, v, se.vdot[k] - 0.5 * xdot)
            })
            .collect::<Vec<f64>>();
        Some(Effect {
            damping: Some(Arc::new(damping)),
            point_sampled: e.point_sampled,
            ..Effect::new(e.kind, va)
        })
    }

    /// The pocket lags the pressure by `τ_k = c_k·V_a·P_atm/(P_atm + P_k)²`, which changes with
    /// the pressure and the damping: the constant lag a least-squares fit would put in its place
    /// is `τ_k` weighted by the squared rate of the pressure it lags, `Σ τ_k Ṗ_k² / Σ Ṗ_k²` (to
    /// first order the lag moves each frame by `τ_k Ṗ_k`). On the loop benchmark (seed 1) drive
    /// lags of 0.4–1.2 ms were named pockets of 0.2–0.9 mm³ with no lag among their
    /// alternatives.
    fn mean_delay(&self, e: &Effect, prep: &Prepared) -> Option<f64> {
        let tau = time_constants(e, prep);
        let sched = e.scheduled_pressure(prep);
        let dp = signal::akima_slopes(&prep.series.t, sched);
        let (num, den) = tau
            .iter()
            .zip(&dp)
            .fold((0.0, 0.0), |(n, d), (t, s)| (n + t * s * s, d + s * s));
        let d = num / den;
        (d.is_finite() && d > 0.0).then_some(d)
    }

    fn input_stage(&self) -> Option<u32> {
        Some(60)
    }

    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        let sched = e.scheduled_pressure(prep);
        for k in 0..inputs.v.len() {
            let p = sched[k].max(-0.9 * P_ATM_KPA);
            inputs.v[k] -= e.theta * p / (P_ATM_KPA + p);
        }
    }

    fn filter_stage(&self) -> Option<u32> {
        Some(0)
    }

    /// A log's samples may be frame means (the lag acts inside each frame) or instants (the lag
    /// of the cubic between them); both are fitted, as for the sensor lag.
    fn tries_point_sampled(&self) -> bool {
        true
    }

    /// On frame means (the default) the lag runs inside the frames ([`Self::lag_time_constants`]).
    /// This filter is the other two forms: on instants ([`Effect::point_sampled`]), the lag of
    /// each column's cubic between samples with Akima's slopes; in the board's form
    /// ([`Effect::board_form`]), which only has the past, with backward-difference slopes.
    fn filter(&self, e: &Effect, prep: &Prepared, cols: &mut [Vec<f64>]) {
        let t = &prep.series.t;
        let tau = time_constants(e, prep);
        // Over each interval the time constant at its midpoint (the mean of its ends): second-order
        // accurate where τ changes fast, at the reversals.
        let mid = |k: usize| 0.5 * (tau[k] + tau[k.saturating_sub(1)]);
        let coeffs = signal::lag_cubic_coeffs(t, mid);
        if e.board_form {
            // The board's form: slopes from the past only (`signal::backward_slopes`).
            signal::lag_causal_apply_all(t, &coeffs, cols);
            return;
        }
        signal::lag_cubic_apply_all(t, &coeffs, cols);
    }

    /// `τ_k = c_k·V_a·P_atm/(P_atm + P_k)²` over frame k: the loop's form, run inside the frames
    /// (`lag_in_frames`).
    fn lag_time_constants(&self, e: &Effect, prep: &Prepared) -> Option<Vec<f64>> {
        Some(time_constants(e, prep))
    }

    /// [`Self::filter`]'s lag, for the searches' streamed sum.
    fn output_lag(
        &self,
        e: &Effect,
        prep: &Prepared,
    ) -> Option<(Vec<[f64; 5]>, signal::LagSlopes)> {
        let tau = time_constants(e, prep);
        let mid = |k: usize| 0.5 * (tau[k] + tau[k.saturating_sub(1)]);
        let coeffs = signal::lag_cubic_coeffs(&prep.series.t, mid);
        Some((coeffs, super::sensor_lag::slopes_of(e)))
    }

    fn uses_measured_pressure(&self) -> bool {
        true
    }

    fn presence(&self) -> Option<&'static str> {
        Some("air_volume_at_atmospheric_pressure")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        let e = f.effect;
        let cbar = e
            .damping
            .as_ref()
            .map_or(0.0, |d| d.iter().sum::<f64>() / d.len().max(1) as f64);
        vec![
            param(
                "air_volume_at_atmospheric_pressure",
                e.theta,
                f.theta_se,
                "mm3",
            ),
            param(
                "time_constant_at_0_kpa",
                cbar * e.theta / P_ATM_KPA,
                cbar * f.theta_se / P_ATM_KPA,
                "s",
            ),
        ]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::AirCompliance)
    }

    fn device_retune(&self) -> bool {
        // The board's causal lag trails further than the loop's at the same time constant.
        true
    }

    /// The damping `c = ∂P/∂v̇` per sample of the polynomial `beta`, at the chamber's volume
    /// `v − V_a·p̃/(P_atm + p̃)` and the flow midway between the pump's and the chamber's,
    /// `v̇ − ẋ/2`, `ẋ = x′(p̃)·Ṗ`, `x′(p̃) = V_a·P_atm/(P_atm + p̃)²` (the board's schedule of its
    /// air lag, from its own polynomial, `model_core::chain`). The board has only the past: Ṗ is
    /// the backward difference `(p̃_k − p̃_{k−1})/(t_k − t_{k−1})` (0 at k = 0), p̃ the scheduled
    /// pressure floored at −0.9 P_atm; the loop's form ([`Self::refine`]) takes Akima's slopes.
    fn device_damping(&self, prep: &Prepared, beta: &[f64], e: &Effect) -> Option<Arc<Vec<f64>>> {
        let (se, va) = (&prep.series, e.theta);
        let pt = |k: usize| prep.p_sched[k].max(-0.9 * P_ATM_KPA);
        Some(Arc::new(
            (0..se.len())
                .map(|k| {
                    let p = pt(k);
                    let v = se.v[k] - va * p / (P_ATM_KPA + p);
                    let pdot = if k == 0 {
                        0.0
                    } else {
                        (p - pt(k - 1)) / (se.t[k] - se.t[k - 1])
                    };
                    let xdot = va * P_ATM_KPA / (P_ATM_KPA + p).powi(2) * pdot;
                    prep.basis.damping(beta, v, se.vdot[k] - 0.5 * xdot)
                })
                .collect(),
        ))
    }

    fn device_params(&self, e: &Effect, coefs: &[f64]) -> Option<Vec<f64>> {
        let _ = coefs;
        Some(vec![e.theta])
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device(
            "the board's chain applies Boyle's law to the measured pressure and lags P̂ with the polynomial's damping (`model <ch> effect air_compliance <V_a>`)",
        )
    }
}

/// The air lag's time constant at every frame, `τ_k = c_k·V_a·P_atm/(P_atm + P_k)²` (c the damping
/// schedule, P the measured pressure, floored at −0.9 P_atm).
fn time_constants(e: &Effect, prep: &Prepared) -> Vec<f64> {
    let damping = e.damping.as_deref();
    let sched = e.scheduled_pressure(prep);
    (0..prep.series.len())
        .map(|k| {
            let c = damping.map_or(0.0, |d| d[k].max(0.0));
            let p = sched[k].max(-0.9 * P_ATM_KPA);
            c * e.theta * P_ATM_KPA / (P_ATM_KPA + p).powi(2)
        })
        .collect()
}
