//! Sensor lag: the pressure sensor (or its filter) as a first-order lag `τ Ṗ_m + P_m = P`, an
//! output filter on every design column (exact because the model is linear in its coefficients).
//! The sensor lags each conversion and the frame averages them, so the loop runs the lag inside
//! the frames, on the motion rebuilt at the conversion instants (`super::lag_in_frames`); the
//! board's form lags each column's cubic between frames (`signal::lag_cubic_coeffs`).

use super::{param, DeviceSupport, Effect, EffectModel, Fitted, Param, Prepared, Scales, Search};
use crate::residual::signal::{self, LagSlopes};

/// The slopes a lag's cubic takes in `e`'s form: backward differences on the board, Akima's in
/// the loop.
pub(super) fn slopes_of(e: &Effect) -> LagSlopes {
    if e.board_form {
        LagSlopes::Backward
    } else {
        LagSlopes::Akima
    }
}

/// First-order lag of the pressure sensor.
pub struct SensorLag;

impl EffectModel for SensorLag {
    fn name(&self) -> &'static str {
        "sensor_lag"
    }

    fn story(&self) -> &'static str {
        "The pressure sensor (or its filter) responds to a step with a first-order exponential of time constant tau, so fast pressure changes are reported late and smoothed."
    }

    /// A pressure sensor with its tubing responds within milliseconds to tens of milliseconds;
    /// a first-order lag of more than 5 % of the log's cycle (250 ms on a 5 s breath) is the
    /// pressure's own slow response (the chamber, a lung, the tubing), so it is reported as
    /// `pressure_dynamics`: the same first-order lag of the output, named for what it shows.
    fn neutral(&self, e: &Effect, sc: &Scales) -> Option<(&'static str, &'static str)> {
        let period = sc.cycle_s?;
        (e.theta > 0.05 * period).then_some((
            "pressure_dynamics",
            "The pressure follows the model through a first-order lag of a good part of a cycle (over 5 %): a slow response of the pressure itself (chamber, lung, tubing) rather than of a sensor, which responds in milliseconds. Modelled as a first-order lag of the output; the name claims no more.",
        ))
    }

    /// One time constant: a single minimum of the SSE over the search range.
    fn one_minimum(&self) -> bool {
        true
    }

    /// From a twentieth of a frame (run inside the frames, a lag that short still moves each
    /// frame's mean: by τ times the pressure's rate) to 3 s.
    fn search(&self, sc: &Scales) -> Search {
        Search::Log(0.05 * sc.dt, (3.0f64).min(sc.duration / 20.0).max(sc.dt))
    }

    /// A first-order lag's mean delay is its τ.
    fn mean_delay(&self, e: &Effect, _prep: &Prepared) -> Option<f64> {
        Some(e.theta)
    }

    fn theta_at_mean_delay(&self, d: f64) -> Option<f64> {
        Some(d)
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    /// Rebuilds and lags the whole design inside the frames at every trial τ.
    fn cost_guess(&self) -> f64 {
        1e3
    }

    fn filter_stage(&self) -> Option<u32> {
        Some(10)
    }

    /// On frame means (the default) the lag runs inside the frames ([`Self::lag_time_constants`]).
    /// This filter is the other two forms: on instants ([`Effect::point_sampled`], a sampling
    /// sensor), the lag of each column's cubic between samples with Akima's slopes; in the
    /// board's form ([`Effect::board_form`]), which only has the past, the cubic's slopes are
    /// backward differences (`signal::backward_slopes`).
    fn filter(&self, e: &Effect, prep: &Prepared, cols: &mut [Vec<f64>]) {
        let t = &prep.series.t;
        let coeffs = signal::lag_cubic_coeffs(t, |_| e.theta);
        if e.board_form {
            signal::lag_causal_apply_all(t, &coeffs, cols);
        } else {
            signal::lag_cubic_apply_all(t, &coeffs, cols);
        }
    }

    fn output_lag(&self, e: &Effect, prep: &Prepared) -> Option<(Vec<[f64; 5]>, LagSlopes)> {
        let coeffs = signal::lag_cubic_coeffs(&prep.series.t, |_| e.theta);
        Some((coeffs, slopes_of(e)))
    }

    /// A log's samples may be frame means (our firmware: the lag acts inside each frame) or
    /// instants (a sampling sensor: the lag of the cubic between them); both are fitted.
    fn tries_point_sampled(&self) -> bool {
        true
    }

    /// τ over every frame: on frame means, run inside the frames (`lag_in_frames`).
    fn lag_time_constants(&self, e: &Effect, prep: &Prepared) -> Option<Vec<f64>> {
        Some(vec![e.theta; prep.series.len()])
    }

    /// A lag the neutral name calls the pressure's own dynamics ([`Self::neutral`]) is not the
    /// sensor's: what the chamber holds lags too, and its reading is not undone.
    fn sensor_lag(&self, e: &Effect, sc: &Scales) -> Option<f64> {
        self.neutral(e, sc).is_none().then_some(e.theta)
    }

    fn presence(&self) -> Option<&'static str> {
        Some("time_constant")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![param("time_constant", f.effect.theta, f.theta_se, "s")]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::SensorLag)
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
            "the board's chain lags P̂ by τ over the cubic between frames with backward-difference slopes (`model <ch> effect sensor_lag <tau>`; the loop's Akima slopes look ahead, the export refits τ in the board's form)",
        )
    }
}
