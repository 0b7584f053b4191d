//! Sensor lag: the pressure sensor (or its filter) as a first-order lag `τ Ṗ_m + P_m = P`, an
//! output filter on every design column (exact because the model is linear in its coefficients;
//! each column's Akima interpolant between frames is lagged exactly, `signal::lag_cubic_coeffs`).
//! It is the last step of the design, so its search only filters the current model's design
//! ([`LagBase`]).

use super::{
    param, Design, DeviceSupport, Effect, EffectKind, EffectModel, Fitted, Param, Prepared, Scales,
    Search, Stage,
};
use crate::residual::lsq;
use crate::residual::signal;

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

    fn search(&self, sc: &Scales) -> Search {
        Search::Log(0.25 * sc.dt, (3.0f64).min(sc.duration / 20.0).max(sc.dt))
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    /// Filters the whole design at every trial τ (but see [`Self::fast_sse`]).
    fn cost_guess(&self) -> f64 {
        1e2
    }

    /// Added to a model without a sensor lag, the lag is the design's last step: filter the
    /// current design at each τ instead of rebuilding it.
    fn fast_sse<'a>(
        &self,
        prep: &'a Prepared,
        cur: &'a Stage,
    ) -> Option<Box<dyn Fn(f64) -> f64 + 'a>> {
        let me = EffectKind(&SensorLag);
        if cur.effects.iter().any(|e| e.kind == me) {
            return None;
        }
        let lb = LagBase::new(cur.columns(prep));
        Some(Box::new(move |tau| lb.sse(prep, tau)))
    }

    fn filter_stage(&self) -> Option<u32> {
        Some(10)
    }

    /// The lag of each column's cubic between samples: Akima's slopes on frame means; in the
    /// board's form ([`Effect::point_sampled`]), which only has the past, the backward
    /// differences (`signal::backward_slopes`).
    fn filter(&self, e: &Effect, prep: &Prepared, cols: &mut [Vec<f64>]) {
        let t = &prep.series.t;
        let coeffs = signal::lag_cubic_coeffs(t, |_| e.theta);
        if e.point_sampled {
            signal::lag_causal_apply_all(t, &coeffs, cols);
        } else {
            signal::lag_cubic_apply_all(t, &coeffs, cols);
        }
    }

    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![param("time_constant", f.effect.theta, f.theta_se, "s")]
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

/// A design about to be filtered by a sensor lag: sensor lag is the last step of
/// [`super::build`], so adding it to a model whose design is known only filters that design, and
/// a search over τ need not rebuild it. Each trial streams the filtered design into the Gram sum
/// a block of rows at a time (`signal::LagStream`, `lsq::sse_fast_streamed`): the design is held
/// once, whatever the number of trials.
pub struct LagBase {
    design: Design,
}

impl LagBase {
    /// The design (every sample) of the model the lag is added to.
    pub fn new(design: Design) -> Self {
        Self { design }
    }

    /// Training SSE of the design filtered by a sensor lag of time constant `tau`.
    pub fn sse(&self, prep: &Prepared, tau: f64) -> f64 {
        let (t, cols) = (&prep.series.t, &self.design.cols);
        if cols.iter().any(|c| c.len() != t.len()) {
            return f64::INFINITY;
        }
        let coeffs = signal::lag_cubic_coeffs(t, |_| tau);
        let mut run = signal::LagStream::new(t, &coeffs, signal::LagSlopes::Akima, cols);
        lsq::sse_fast_streamed(cols.len(), &prep.series.p, &prep.train_rows, |hi, out| {
            run.advance(cols, hi, out)
        })
    }
}
