//! Delivery lag: the commanded motion reaching the chamber through a critically damped
//! second-order lag, two first-order lags `L_τ` (`τ ẏ + y = x`) of time constant τ, the input
//! transform `v' = L_τ² v`, `v̇' = L_τ² v̇`: late by 2τ and rounded off.
//!
//! ```text
//! τ²·v̈' + 2τ·v̇' + v' = v        (the same for v̇'),   mean delay 2τ
//! ```
//!
//! **Its form (issue 34).** A chain of motor, screw, seal and tube is generally overdamped, two
//! time constants `τ₁ ≠ τ₂` (`τ₁τ₂·v̈' + (τ₁ + τ₂)·v̇' + v' = v`); the critically damped lag is
//! its special case `τ₁ = τ₂ = τ`. The form is not widened to two time constants: the drive's
//! lag is a few milliseconds against a 40 ms frame, and two lags of the same mean delay
//! `τ₁ + τ₂ = 2τ` differ in the frames only through their spread (`τ₁² + τ₂²` against `2τ²`), a
//! term of order (τ/frame)² behind the delay's τ/frame. On host-sim's overdamped drive (poles
//! 1.6τ_d and 0.4τ_d) the critically damped lag, searched that low, was found with the mean delay
//! planted (benchmark rig 14 of seed 1, τ_d = 1.47 ms: τ = 1.58 ms), and the device export
//! stays as it is.
//!
//! The search runs from 5 % of the frame interval (2 ms at 25 Hz). Below it a drive's lag is
//! found as a sensor lag of about its mean delay (benchmark rig 14: 3.2 ms for 2τ_d = 2.9 ms):
//! in frames a first-order lag of the output and a second-order lag of the inputs with the same
//! mean delay are told apart only by terms of order (τ/frame)². Searching from 1 % (0.4 ms) was
//! tried (issue 34, `vfp bench-loop --rigs 100 --seed 1`, usual and `--forms other`): it named
//! two fast drives' lags rightly (rigs 13 and 14) but took two sensor lags of 3–3.6 ms (rigs 19
//! and 99) and a transport delay's name from the sensor lag, a wash (usual forms: recall 0.656 →
//! 0.648; other forms: 0.582 → 0.590; the share of rigs ending ≤ 1.10 σ unchanged on both), so
//! the bracket stays. Tried again from 2.5 % (1 ms: the mean delay 2τ from the sensor lag's floor
//! of 2 ms) once the benchmark planted its lags on the servo's motion (300 rigs of seed 1): 22
//! delivery lags named rightly where 16 were, but three sensor lags and five transport delays
//! named delivery lags, precision 0.768 → 0.776 and recall at oracle gain ≥ 5 % 0.778 → 0.788,
//! within their errors, and one rig's diagnosis 5.7 → 9.5 s: left out. Tried a third time once
//! the transport delay was searched from 5 % too (2026-11-28): precision counting alternatives
//! 0.872 → 0.897, recall at oracle gain ≥ 5 % 0.782 → 0.789, but the same rig 8.2 → 10.1 s, over
//! the loop's 10 s budget: left out.
//!
//! What a fast drive leaves unexplained is not a lag's shape but the motor's **step train**: with
//! τ well below the step interval (0.4–2 ms at the strokes' flows), each 0.04 mm³ step arrives as
//! a pulse of flow about τ wide, which the law's `v̇²` terms rectify and the sensor's eight
//! conversions per frame alias (benchmark rigs 37 and 84 of seed 1, τ_d = 0.38 and 0.59 ms: 9 and
//! 14 σ left, a spectral peak holding half the residual, while no lag of any time constant gains
//! 1 % of held-out RMSE). The logged motion, smooth between frames, cannot show where the steps
//! fall; this effect does not claim it. (The loop benchmark now plants its delivery lags on the
//! servo's continuous motion, `host_sim::plant::Drive::LaggedServo`, so that a planted lag is a
//! lag; host-sim's default rig keeps the step train.)

use super::{
    param, DeviceSupport, Effect, EffectModel, Fitted, Inputs, Param, Prepared, Scales, Search,
};
use crate::residual::inframe::LagChain;
use crate::residual::signal;

/// The commanded motion delivered through a critically damped lag.
pub struct DeliveryLag;

impl EffectModel for DeliveryLag {
    fn name(&self) -> &'static str {
        "delivery_lag"
    }

    fn story(&self) -> &'static str {
        "The motor, lead screw, plunger seal and tubing deliver the commanded motion late and rounded off (a critically damped lag of time constant tau, about 2 tau late), so the chamber sees a smoothed, delayed copy of the logged volume and flow."
    }

    fn generic(&self) -> Option<(&'static str, &'static str)> {
        Some((
            "input_lag",
            "The chamber sees a smoothed, delayed copy of the logged volume and flow (a critically damped lag of time constant tau, about 2 tau late): the input is delivered late and rounded off. The name claims no more.",
        ))
    }

    /// One time constant: a single minimum of the SSE over the search range.
    fn one_minimum(&self) -> bool {
        true
    }

    fn search(&self, sc: &Scales) -> Search {
        Search::Log(0.05 * sc.dt, (0.75f64).min(sc.duration / 40.0).max(sc.dt))
    }

    /// Two stages of τ: a mean delay of 2τ.
    fn mean_delay(&self, e: &Effect, _prep: &Prepared) -> Option<f64> {
        Some(2.0 * e.theta)
    }

    fn theta_at_mean_delay(&self, d: f64) -> Option<f64> {
        Some(0.5 * d)
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn input_stage(&self) -> Option<u32> {
        Some(0)
    }

    /// On the logged motion (the loop's form), both stages run inside the frames: over the motion
    /// rebuilt at the instants each frame averages ([`Prepared::sub_motion`]), the volume and flow
    /// then averaged back over each frame, `v'_k = (1/S) Σ_j (L_τ² v)(t_kj)` (and v̇'), as the
    /// frames average what the chamber received. Otherwise each stage lags the volume with the
    /// flow as its exact slopes (the lag of a derivative is the derivative of the lag), the flow
    /// with Akima slopes; on point samples (the board's form, which only has the past) the flow
    /// with the accelerations at the samples as slopes, each the end slope of the volume's cubic
    /// over the last interval (`signal::acceleration_causal`).
    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        if inputs.raw && !e.point_sampled {
            let made = prep.memo_inputs(self.name(), e.theta, || {
                let (se, sub) = (&prep.series, prep.sub_motion());
                let chain = LagChain::new(&se.t, &vec![vec![e.theta; se.len()]; 2]);
                (
                    chain.frame_means(|k| sub.volumes(&se.t, &se.v, k)),
                    chain.frame_means(|k| sub.flows(k)),
                )
            });
            (inputs.v, inputs.f) = (made.0.clone(), made.1.clone());
            return;
        }
        let t = &prep.series.t;
        let c = signal::lag_cubic_coeffs(t, |_| e.theta);
        for _ in 0..2 {
            let f = &inputs.f;
            let slopes = if e.point_sampled {
                signal::acceleration_causal(t, &inputs.v, f)
            } else {
                signal::akima_slopes(t, f)
            };
            let fv = signal::lag_cubic(&c, f, &slopes);
            inputs.v = signal::lag_cubic(&c, &inputs.v, f);
            inputs.f = fv;
        }
    }

    fn presence(&self) -> Option<&'static str> {
        Some("time_constant")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![
            param("time_constant", f.effect.theta, f.theta_se, "s"),
            param(
                "effective_delay",
                2.0 * f.effect.theta,
                2.0 * f.theta_se,
                "s",
            ),
        ]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::DeliveryLag)
    }

    fn device_retune(&self) -> bool {
        // The board's causal lag trails further than the loop's at the same time constant.
        true
    }

    fn device_params(&self, e: &Effect, coefs: &[f64]) -> Option<Vec<f64>> {
        let _ = coefs;
        Some(vec![e.theta])
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device(
            "the board's chain lags v and v̇ (cubics between frames, slopes the flows and the causal accelerations) through two stages (`model <ch> effect delivery_lag <tau>`)",
        )
    }
}
