//! Backlash: play of b mm³ between lead-screw nut and plunger, the input transform
//! `v' = play_b(v)`: after each reversal the plunger waits b of nut travel, with zero flow
//! meanwhile. With frame-mean samples the play operator runs on the nut's motion rebuilt at
//! eight instants per frame and the plunger is averaged back (`signal::play_instants`,
//! `signal::play_frames`); with point samples it runs on the samples themselves. The board
//! rebuilds the nut inside a frame from that frame alone (it has no next frame), the form the
//! export fits ([`Effect::board_form`], `signal::play_frame_linear`).

use super::{
    param, DeviceSupport, Effect, EffectModel, Fitted, Inputs, Param, Prepared, Scales, Search,
};
use crate::residual::signal;

/// Lead-screw backlash (dead band at reversals).
pub struct Backlash;

impl EffectModel for Backlash {
    fn name(&self) -> &'static str {
        "backlash"
    }

    fn story(&self) -> &'static str {
        "Play between lead-screw nut and plunger: after each reversal the motor turns through a dead band before the plunger moves, so volume and flow reach the chamber late and offset by half the play."
    }

    fn generic(&self) -> Option<(&'static str, &'static str)> {
        Some((
            "dead_band",
            "After each reversal of the flow, the volume and flow reach the chamber late and offset, as through a dead band of the input: the model plays the logged volume through that band. The name claims no more.",
        ))
    }

    /// Down to a few motor steps of play (0.1 mm³ on a 550 mm³ stroke): at the paper's stiffest
    /// point 0.1 mm³ is already 0.03 kPa, above a frame's noise.
    fn search(&self, sc: &Scales) -> Search {
        Search::Log(0.0002 * sc.v_range, 0.2 * sc.v_range)
    }

    /// A play of more than 5 % of the stroke (27 mm³ on the paper's 550 mm³ syringe, hundreds
    /// of motor steps) is no lead screw's: the dead band is fitting something else.
    fn unphysical(&self, e: &Effect, _coefs: &[f64], sc: &Scales) -> Option<String> {
        if !e.theta.is_finite() {
            return Some("backlash play is not finite".into());
        }
        (e.theta > 0.05 * sc.v_range).then(|| {
            format!(
                "a play of {:.4e} mm³ is {:.0} % of the stroke ({:.4e} mm³), more than any lead screw's dead band",
                e.theta,
                100.0 * e.theta / sc.v_range,
                sc.v_range
            )
        })
    }

    fn has_nonlinear(&self) -> bool {
        true
    }

    fn tries_point_sampled(&self) -> bool {
        true
    }

    fn input_stage(&self) -> Option<u32> {
        Some(20)
    }

    fn transform_inputs(&self, e: &Effect, prep: &Prepared, inputs: &mut Inputs) {
        let Inputs { v, f, raw } = inputs;
        if e.board_form {
            (*v, *f) = signal::play_frame_linear(&prep.series.t, v, f, e.theta);
        } else if e.point_sampled {
            let z = signal::play(v, e.theta);
            let h = 0.5 * e.theta;
            for k in 0..v.len() {
                let gap = v[k] - z[k];
                let engaged = gap.abs() >= h - 1e-9 * (1.0 + h) && gap * f[k] > 0.0;
                if !engaged {
                    f[k] = 0.0;
                }
            }
            *v = z;
        } else if *raw {
            (*v, *f) = signal::play_instants(&prep.subframe(), e.theta);
        } else {
            (*v, *f) = signal::play_frames(&prep.series.t, v, f, e.theta);
        }
    }

    fn presence(&self) -> Option<&'static str> {
        Some("play")
    }
    fn params(&self, f: &Fitted) -> Vec<Param> {
        vec![
            param("play", f.effect.theta, f.theta_se, "mm3"),
            f.frame_averaged(),
        ]
    }

    fn device_kind(&self) -> Option<model_core::chain::EffectKind> {
        Some(model_core::chain::EffectKind::Backlash)
    }

    fn device_params(&self, e: &Effect, coefs: &[f64]) -> Option<Vec<f64>> {
        let _ = coefs;
        Some(vec![e.theta])
    }

    fn device_support(&self) -> DeviceSupport {
        DeviceSupport::on_device(
            "the board's chain runs the play operator on each frame's motion rebuilt from that frame (`model <ch> effect backlash <b>`)",
        )
    }
}
