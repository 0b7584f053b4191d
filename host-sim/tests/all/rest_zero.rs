//! The board corrects a slow drift of its pressure zero at rest at the zero's volume
//! (`firmware::rest_zero`), and does not take a push for drift.
//!
//! The plant's sensor offset creeps by 1 kPa with a 100 s time constant after the boot zero
//! (host-sim's thermal drift), 22 mN of false force per chamber once it has crept. The rig cycles
//! all three syringes out to 200 mm³ and back to the boot volume every 20 s and rests there 9 s.
//! Truth: the plant's sensed pressure before its offset (`ChamberTruth::sensed_kpa`), and its
//! true external force.

use firmware::app::Config;
use firmware::telemetry::{EventKind, Frame};
use host_sim::plant::ThermalDrift;
use host_sim::{simulate_with, ForcePush, FrameTruth, Scenario, SimRun, TimedCommand};

const CYCLE_S: f64 = 20.0;
const CYCLES: usize = 14;

fn scenario(push: Option<ForcePush>) -> Scenario {
    let mut sc = Scenario {
        name: "rest-zero".into(),
        duration_s: 5.0 + CYCLE_S * CYCLES as f64,
        seed: 7,
        ..Scenario::default()
    };
    sc.plant.effects.thermal_drift = Some(ThermalDrift {
        offset_change_kpa: 1.0,
        time_constant_s: 100.0,
    });
    for k in 0..CYCLES {
        let t0 = 5.0 + CYCLE_S * k as f64;
        sc.commands.push(TimedCommand::new(t0, "move all 200 50"));
        sc.commands
            .push(TimedCommand::new(t0 + 7.0, "move all 0 50"));
    }
    sc.force.extend(push);
    sc
}

fn run(sc: &Scenario, rest_zero: bool) -> SimRun {
    let mut cfg = Config::default();
    if !rest_zero {
        cfg.rest_zero = None;
    }
    let run = simulate_with(sc, cfg).expect("valid scenario");
    assert!(
        run.replies.iter().all(|(_, r)| r == "ok"),
        "{:?}",
        run.replies
    );
    run
}

/// Frames at rest at the boot volume in the last 3 s of each rest from `from_s` on (the rig
/// has been back for 6 s), with their truth.
fn late_rest(run: &SimRun, from_s: f64) -> Vec<(&Frame, &FrameTruth)> {
    run.frames
        .iter()
        .zip(&run.truth)
        .filter(|(f, _)| {
            let t = f.t_us as f64 * 1e-6;
            let in_cycle = (t - 5.0).rem_euclid(CYCLE_S);
            t >= from_s && in_cycle > 17.0 && f.chambers.iter().all(|c| c.v.abs() < 0.5)
        })
        .collect()
}

/// Mean error of the zeroed pressure against the sensed pressure (kPa, all chambers) and of
/// the force (N), over `frames`.
fn errors(frames: &[(&Frame, &FrameTruth)]) -> (f64, f64) {
    let n = frames.len() as f64;
    let p = frames
        .iter()
        .map(|(f, t)| {
            (0..3)
                .map(|ch| f64::from(f.chambers[ch].p) - t.chambers[ch].sensed_kpa)
                .sum::<f64>()
                / 3.0
        })
        .sum::<f64>()
        / n;
    let force = frames
        .iter()
        .map(|(f, t)| f64::from(f.force_n) - t.force_n)
        .sum::<f64>()
        / n;
    (p, force)
}

#[test]
fn a_creeping_zero_is_followed_at_rest() {
    let sc = scenario(None);
    let (off, on) = (run(&sc, false), run(&sc, true));
    // The second half of the run: the offset has crept by 0.86-0.94 kPa since the boot zero.
    let from = 5.0 + CYCLE_S * (CYCLES / 2) as f64;
    let (p_off, f_off) = errors(&late_rest(&off, from));
    let (p_on, f_on) = errors(&late_rest(&on, from));
    assert!(
        p_off > 0.7,
        "without the correction the zero is off by {p_off} kPa"
    );
    assert!(
        p_on.abs() < 0.1,
        "with it, {p_on} kPa (without: {p_off} kPa)"
    );
    assert!(
        f_on.abs() < 0.2 * f_off.abs(),
        "force error at rest {f_on} N with the correction, {f_off} N without"
    );
    // Every correction is a small step: one `zero` event per stay at most, each within 0.5 kPa.
    let zeros: Vec<[f32; 3]> = on
        .events
        .iter()
        .filter_map(|e| match e.kind {
            EventKind::Zeroed { offset_kpa } => Some(offset_kpa),
            _ => None,
        })
        .collect();
    assert!(
        zeros.len() >= CYCLES / 2 && zeros.len() <= CYCLES + 1,
        "{zeros:?}"
    );
    for w in zeros.windows(2) {
        let step = w[0].iter().zip(&w[1]).map(|(a, b)| (b - a).abs());
        assert!(step.fold(0.0f32, f32::max) <= 0.5, "{zeros:?}");
    }
}

#[test]
fn a_push_at_rest_is_not_taken_for_drift() {
    // An axial push train through the whole of the 10th rest (peak 0.5 N, 1 Hz).
    let rest = 5.0 + CYCLE_S * 9.0 + 11.0;
    let push = ForcePush {
        start_s: rest,
        duration_s: 9.0,
        frequency_hz: 1.0,
        peak_n: 0.5,
        azimuth_deg: 0.0,
        tilt_deg: 0.0,
    };
    let run = run(&scenario(Some(push)), true);
    let zero_at = |t_s: f64| {
        run.events
            .iter()
            .rev()
            .filter(|e| (e.t_us as f64) * 1e-6 <= t_s)
            .find_map(|e| match e.kind {
                EventKind::Zeroed { offset_kpa } => Some(offset_kpa),
                _ => None,
            })
            .expect("a zero was taken")
    };
    // The zero does not move during the pushed stay.
    let (before, after) = (zero_at(rest), zero_at(rest + 9.0));
    assert_eq!(before, after, "the push moved the zero");
    // And the board sees the push: its mean force over the stay is the true mean within 20 %.
    let (est, truth): (Vec<f64>, Vec<f64>) = run
        .frames
        .iter()
        .zip(&run.truth)
        .filter(|(f, _)| {
            let t = f.t_us as f64 * 1e-6;
            t > rest + 1.0 && t < rest + 8.0
        })
        .map(|(f, t)| (f64::from(f.force_n), t.force_n))
        .unzip();
    let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len() as f64;
    let (e, t) = (mean(&est), mean(&truth));
    assert!(t > 0.2, "the push is there: {t} N");
    assert!((e - t).abs() < 0.2 * t, "estimated {e} N, true {t} N");
}
