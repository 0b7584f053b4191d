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

    /// A drift over the log smaller than the volume range the log covers. A drift of the reading
    /// is in the reading, `v_logged = v_chamber + r·(t − t₀)`: the logged range holds the chamber's
    /// own swing plus the drift, so a true drift is smaller than it. A fit at the whole range or
    /// beyond (the search's end is exactly one range, [`Self::search`]; to rounding) is no reading
    /// creeping: no volume the chamber held at the log's start would be held at its end, and the
    /// "drift" trades against a trend of the pressure (a PEEP step, a sensor's zero) instead.
    fn unphysical(&self, e: &Effect, _coefs: &[f64], sc: &Scales) -> Option<String> {
        if !e.theta.is_finite() {
            return Some("volume drift rate is not finite".into());
        }
        let drift = e.theta * sc.duration;
        (drift.abs() >= (1.0 - 1e-9) * sc.v_range).then(|| {
            format!(
                "a volume drift of {drift:.4e} mm³ over the log ({:.4e} mm³/s for {:.1} s) is {:.0} % of the volume range the log covers ({:.4e} mm³): a drift of the reading is inside the reading's range",
                e.theta,
                sc.duration,
                100.0 * drift.abs() / sc.v_range,
                sc.v_range
            )
        })
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::residual::effects::{EffectKind, Search};

    fn scales() -> Scales {
        Scales {
            v_range: 500.0,
            dt: 0.01,
            duration: 200.0,
            p_integral: 1000.0,
            p_pos_integral: 1000.0,
            p_range: 2.0,
            cycle_s: Some(5.0),
            rig: crate::residual::Rig::Generic,
        }
    }

    /// A drift over the log as large as the volume range (2.5 mm³/s for 200 s on 500 mm³) is
    /// refused, whatever its sign, with the numbers named; the search's end (exactly one range,
    /// to rounding) is refused too; a drift of a tenth of the range is kept.
    #[test]
    fn a_drift_as_large_as_the_volume_range_is_not_kept() {
        let sc = scales();
        let kind = EffectKind(&VolumeDrift);
        let judge = |rate: f64| kind.unphysical(&Effect::new(kind, rate), &[], &sc);
        let why = judge(3.0).expect("600 mm³ over the log");
        assert!(
            why.contains("6.0000e2 mm³") && why.contains("120 %"),
            "{why}"
        );
        assert!(why.contains("5.0000e2 mm³"), "{why}");
        assert!(judge(-3.0).is_some());
        let Search::Signed(_, top) = kind.search(&sc) else {
            panic!("a signed rate")
        };
        assert!(judge(top).is_some() && judge(-top).is_some());
        assert_eq!(judge(0.25), None);
        assert_eq!(judge(-0.25), None);
        assert_eq!(judge(0.98 * top), None);
        assert!(judge(f64::NAN).is_some());
    }
}
