//! Gated ripple: a periodic disturbance at one frequency that is there only while the plunger
//! moves (a pump's or motor's vibration, a stepper's resonance), ripple's two columns times the
//! motion indicator `g(t) = [|v̇(t)| > 1 % of the 95th percentile of |v̇|]`:
//! `g(t)·(a sin 2πf(t − t₀) + b cos 2πf(t − t₀))`. The frequency is found as ripple's
//! ([`Search::Spectral`]); where a ripple runs through the rests too, the ungated [`super::Ripple`]
//! fits better, and where it stops with the pump, this one does.

use super::{
    Column, DeviceSupport, Effect, EffectModel, Fitted, Param, Prepared, Ripple, Scales, Search,
};

/// Periodic ripple while the plunger moves.
pub struct GatedRipple;

impl EffectModel for GatedRipple {
    fn name(&self) -> &'static str {
        "gated_ripple"
    }

    fn story(&self) -> &'static str {
        "A periodic disturbance at one frequency rides on the pressure only while the plunger moves (the pump's or motor's vibration) and stops at the rests."
    }

    fn search(&self, _sc: &Scales) -> Search {
        Search::Spectral
    }

    /// As [`Ripple`]'s: not locked to the cycles.
    fn unphysical(&self, e: &Effect, coefs: &[f64], sc: &Scales) -> Option<String> {
        Ripple.unphysical(e, coefs, sc)
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn columns(&self, e: &Effect, prep: &Prepared, v: &[f64]) -> Vec<Column> {
        let moving = moving(&prep.series.vdot);
        let mut cols = Ripple.columns(e, prep, v);
        for c in &mut cols {
            for (x, &m) in c.values.iter_mut().zip(&moving) {
                if !m {
                    *x = 0.0;
                }
            }
            c.label = format!("gated {}", c.label);
        }
        cols
    }

    fn nonnegative(&self, name: &str) -> bool {
        name == "amplitude"
    }
    fn presence(&self) -> Option<&'static str> {
        Some("amplitude")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        Ripple.params(f)
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::host_only(
            "depends on absolute phase of a clock the device does not share with the log",
        )
    }
}

/// Whether the plunger moves at each sample: `|v̇|` over 1 % of its 95th percentile (a rest's
/// logged or derived flow is zero or noise far below any stroke's).
fn moving(vdot: &[f64]) -> Vec<bool> {
    let mut mag: Vec<f64> = vdot.iter().map(|q| q.abs()).collect();
    if mag.is_empty() {
        return Vec::new();
    }
    let k = (0.95 * (mag.len() - 1) as f64).round() as usize;
    let (_, p95, _) = mag.select_nth_unstable_by(k, f64::total_cmp);
    let threshold = 0.01 * *p95;
    vdot.iter().map(|q| q.abs() > threshold).collect()
}
