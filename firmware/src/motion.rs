//! Motion planning: trapezoidal velocity profiles in volume units turned into step instants.
//!
//! A move of `D` mm³ (an exact number of steps `N`, `D = N·Δ`, `Δ` = mm³ per step) starts and
//! ends at rest, accelerates at `a` up to `v` (mm³/s), cruises and decelerates at `a`:
//!
//! ```text
//! s_a = v²/(2a)                 distance to reach v
//! if 2·s_a ≥ D: triangle,       v_p = √(a·D), t_a = v_p/a, t_c = 0
//! else:                         v_p = v,      t_a = v/a,   t_c = (D − 2·s_a)/v
//! T = 2·t_a + t_c
//!
//! t(s) = √(2s/a)                          s ≤ s_p          (s_p = v_p²/(2a))
//!      = t_a + (s − s_p)/v_p              s_p < s ≤ D − s_p
//!      = T − √(2(D − s)/a)                otherwise
//! ```
//!
//! Step `k` (1..=N) is due when the profile reaches `k·Δ`: at `start + round(t(k·Δ))` µs. Each
//! instant is computed from the move's start on an absolute time base, never by adding
//! intervals, so rounding does not accumulate (no drift) and the last step lands at `T`.
//! The commanded volume is reached to the step: a move counts its steps, it does not integrate
//! a velocity.

use crate::hal::{Direction, AXES};

/// √x in f64 without a software square root: the FPU's single-precision root as the seed,
/// then one Newton step `y ← (y + x/y)/2`, which turns the seed's relative error δ ≤ 1.5·2⁻²⁴
/// (rounding x to f32, then the f32 root) into δ²/2 < 2⁻⁴⁷ ≈ 7e-15: 1 ns after a day and a
/// half of motion, far below the µs tick. The Cortex-M4F
/// has no double-precision unit, and a bitwise soft `sqrt` per step would cost more than the
/// rest of the step.
fn sqrt64(x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    let y = libm::sqrtf(x as f32) as f64;
    if y == 0.0 {
        // x below f32's range: √x < 1e-22, nothing at µs resolution.
        return 0.0;
    }
    0.5 * (y + x / y)
}

/// One move's velocity profile (pure math, seconds and mm³).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trapezoid {
    steps: u32,
    step_mm3: f64,
    accel: f64,
    v_peak: f64,
    s_acc: f64,
    t_acc: f64,
    t_cruise: f64,
}

impl Trapezoid {
    /// Profile for `steps` steps of `step_mm3` each, speed limit `flow` mm³/s and acceleration
    /// `accel` mm³/s². `flow`, `accel` and `step_mm3` must be finite and positive (checked by
    /// the caller: they come from validated commands and configuration).
    pub fn new(steps: u32, step_mm3: f32, flow: f32, accel: f32) -> Self {
        assert!(step_mm3 > 0.0 && flow > 0.0 && accel > 0.0);
        let (step_mm3, flow, accel) = (step_mm3 as f64, flow as f64, accel as f64);
        let d = steps as f64 * step_mm3;
        let s_full = flow * flow / (2.0 * accel);
        let (v_peak, t_cruise) = if 2.0 * s_full >= d {
            (sqrt64(accel * d), 0.0)
        } else {
            (flow, (d - 2.0 * s_full) / flow)
        };
        Self {
            steps,
            step_mm3,
            accel,
            v_peak,
            s_acc: v_peak * v_peak / (2.0 * accel),
            t_acc: v_peak / accel,
            t_cruise,
        }
    }

    /// Number of steps.
    pub fn steps(&self) -> u32 {
        self.steps
    }
    /// Total distance, mm³.
    pub fn distance(&self) -> f64 {
        self.steps as f64 * self.step_mm3
    }
    /// Peak speed actually reached, mm³/s.
    pub fn peak_flow(&self) -> f64 {
        self.v_peak
    }
    /// Duration `T`, s.
    pub fn duration(&self) -> f64 {
        2.0 * self.t_acc + self.t_cruise
    }

    /// Time (s after the start) at which the profile has covered `s` mm³ (`0 ≤ s ≤ D`).
    pub fn time_at_distance(&self, s: f64) -> f64 {
        let d = self.distance();
        if s <= self.s_acc {
            sqrt64(2.0 * s / self.accel)
        } else if s <= d - self.s_acc {
            self.t_acc + (s - self.s_acc) / self.v_peak
        } else {
            self.duration() - sqrt64(2.0 * (d - s) / self.accel)
        }
    }

    /// Instant of step `k` (1..=N), in whole µs after the start.
    pub fn step_offset_us(&self, k: u32) -> u64 {
        libm::round(self.time_at_distance(k as f64 * self.step_mm3) * 1e6) as u64
    }

    /// Speed (unsigned, mm³/s) at `t` s after the start; 0 outside the move.
    pub fn flow_at(&self, t: f64) -> f64 {
        let total = self.duration();
        if t <= 0.0 || t >= total {
            0.0
        } else if t < self.t_acc {
            self.accel * t
        } else if t <= self.t_acc + self.t_cruise {
            self.v_peak
        } else {
            self.accel * (total - t)
        }
    }

    /// Distance covered (mm³) at `t` s after the start.
    pub fn distance_at(&self, t: f64) -> f64 {
        let total = self.duration();
        if t <= 0.0 {
            0.0
        } else if t >= total {
            self.distance()
        } else if t < self.t_acc {
            0.5 * self.accel * t * t
        } else if t <= self.t_acc + self.t_cruise {
            self.s_acc + self.v_peak * (t - self.t_acc)
        } else {
            let r = total - t;
            self.distance() - 0.5 * self.accel * r * r
        }
    }
}

/// Why a move was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum MotionError {
    /// The axis is still executing a move (moves start from rest; `stop` first).
    Busy,
    /// Target volume outside `0..=capacity`.
    OutOfRange,
    /// Flow or acceleration not finite, not positive, or above the firmware's maximum.
    BadRate,
}

/// A move in progress on one axis.
#[derive(Clone, Copy, Debug)]
struct ActiveMove {
    /// Profile time zero, µs.
    start_us: u64,
    /// +1 inflate, −1 deflate.
    sign: i32,
    profile: Trapezoid,
    /// Next step to take (1..=N).
    next: u32,
    /// Planned instant of step `next`, µs (computed once per step).
    next_at_us: u64,
}

/// One axis: absolute position and the current move.
#[derive(Clone, Copy, Debug, Default)]
struct Axis {
    /// Steps from the origin (volume 0).
    pos: i32,
    mv: Option<ActiveMove>,
    /// Direction the DIR line is set to, and when it was set (µs).
    dir: Option<(Direction, u64)>,
    /// Direction a new move needs, not yet written to the DIR line.
    pending_dir: Option<Direction>,
}

/// Motion limits and hardware constants.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionConfig {
    /// Volume per (micro)step, mm³ (0.04 on the paper's rig).
    pub mm3_per_step: f32,
    /// Highest flow the firmware accepts, mm³/s.
    pub max_flow: f32,
    /// Highest acceleration the firmware accepts, mm³/s².
    pub max_accel: f32,
    /// Driver DIR-to-STEP set-up time, µs.
    pub dir_setup_us: u32,
    /// Delay between accepting a move and its profile's time zero, µs: covers the DIR set-up and
    /// the stepper task's wake-up, so the first step is never late.
    pub start_lead_us: u32,
}

impl Default for MotionConfig {
    fn default() -> Self {
        Self {
            mm3_per_step: 0.04,
            // 10 000 steps/s at 0.04 mm³/step: what the stepper task is dimensioned for.
            max_flow: 400.0,
            max_accel: 10_000.0,
            dir_setup_us: 5,
            start_lead_us: 1_000,
        }
    }
}

/// The three axes' motion state.
#[derive(Clone, Debug)]
pub struct Motion {
    cfg: MotionConfig,
    axes: [Axis; AXES],
}

impl Motion {
    /// All axes at volume 0, at rest.
    pub fn new(cfg: MotionConfig) -> Self {
        Self {
            cfg,
            axes: [Axis::default(); AXES],
        }
    }

    /// The configuration.
    pub fn config(&self) -> &MotionConfig {
        &self.cfg
    }

    /// Steps for a volume, rounded to the nearest step.
    pub fn volume_to_steps(&self, mm3: f32) -> i32 {
        libm::roundf(mm3 / self.cfg.mm3_per_step) as i32
    }

    /// Position of `axis` in steps.
    pub fn position(&self, axis: usize) -> i32 {
        self.axes[axis].pos
    }

    /// Volume of `axis`, mm³.
    pub fn volume(&self, axis: usize) -> f32 {
        self.axes[axis].pos as f32 * self.cfg.mm3_per_step
    }

    /// Whether `axis` has no move in progress.
    pub fn is_idle(&self, axis: usize) -> bool {
        self.axes[axis].mv.is_none()
    }

    /// Whether no axis moves.
    pub fn all_idle(&self) -> bool {
        self.axes.iter().all(|a| a.mv.is_none())
    }

    /// Commanded flow of `axis` at `t_us` (signed, mm³/s: positive inflates), from the profile.
    pub fn flow_at(&self, axis: usize, t_us: u64) -> f32 {
        match &self.axes[axis].mv {
            Some(m) if t_us > m.start_us => {
                let t = (t_us - m.start_us) as f64 * 1e-6;
                (m.sign as f64 * m.profile.flow_at(t)) as f32
            }
            _ => 0.0,
        }
    }

    /// Start a move of `axis` to the absolute `target` steps at `now_us`, limited to
    /// `capacity_steps`. A zero-length move succeeds and does nothing.
    pub fn start_move(
        &mut self,
        axis: usize,
        target: i32,
        capacity_steps: i32,
        flow: f32,
        accel: f32,
        now_us: u64,
    ) -> Result<(), MotionError> {
        let cfg = self.cfg;
        let rate_ok = |x: f32, max: f32| x.is_finite() && x > 0.0 && x <= max;
        if !rate_ok(flow, cfg.max_flow) || !rate_ok(accel, cfg.max_accel) {
            return Err(MotionError::BadRate);
        }
        if !(0..=capacity_steps).contains(&target) {
            return Err(MotionError::OutOfRange);
        }
        let a = &mut self.axes[axis];
        if a.mv.is_some() {
            return Err(MotionError::Busy);
        }
        let delta = target - a.pos;
        if delta == 0 {
            return Ok(());
        }
        let dir = if delta > 0 {
            Direction::Inflate
        } else {
            Direction::Deflate
        };
        if a.dir.map(|(d, _)| d) != Some(dir) {
            a.pending_dir = Some(dir);
        }
        let start_us = now_us + cfg.start_lead_us as u64;
        let profile = Trapezoid::new(delta.unsigned_abs(), cfg.mm3_per_step, flow, accel);
        a.mv = Some(ActiveMove {
            start_us,
            sign: delta.signum(),
            profile,
            next: 1,
            next_at_us: start_us + profile.step_offset_us(1),
        });
        Ok(())
    }

    /// Direction changes to write to the DIR lines now (call on every wake-up; the first
    /// step of that axis waits at least the set-up time after `now_us`).
    pub fn take_direction_change(&mut self, now_us: u64) -> Option<(usize, Direction)> {
        for (i, a) in self.axes.iter_mut().enumerate() {
            if let Some(d) = a.pending_dir.take() {
                a.dir = Some((d, now_us));
                return Some((i, d));
            }
        }
        None
    }

    /// The earliest due step over all axes: `(axis, instant µs)`.
    ///
    /// The instant is the planned one, except that a step never comes sooner than the driver's
    /// set-up time after its DIR change (only possible if the task woke later than the start
    /// lead allows for).
    pub fn next_step(&self) -> Option<(usize, u64)> {
        let setup = self.cfg.dir_setup_us as u64;
        self.axes
            .iter()
            .enumerate()
            .filter_map(|(i, a)| {
                let m = a.mv.as_ref()?;
                if a.pending_dir.is_some() {
                    // DIR not written yet: the task writes it before sleeping; plan after it.
                    return None;
                }
                let planned = m.next_at_us;
                let earliest = a.dir.map_or(0, |(_, t)| t + setup);
                Some((i, planned.max(earliest)))
            })
            .min_by_key(|&(_, t)| t)
    }

    /// Record the step of `axis` that [`next_step`](Self::next_step) returned. Returns the new
    /// position; finishes the move after its last step.
    pub fn record_step(&mut self, axis: usize) -> i32 {
        let a = &mut self.axes[axis];
        if let Some(m) = &mut a.mv {
            a.pos += m.sign;
            if m.next >= m.profile.steps() {
                a.mv = None;
            } else {
                m.next += 1;
                m.next_at_us = m.start_us + m.profile.step_offset_us(m.next);
            }
        }
        a.pos
    }

    /// The position `axis` would reach with its next step, if it has one.
    pub fn position_after_next_step(&self, axis: usize) -> Option<i32> {
        let a = &self.axes[axis];
        a.mv.as_ref().map(|m| a.pos + m.sign)
    }

    /// Abandon every move immediately (positions stay where the last step left them).
    pub fn stop_all(&mut self) {
        for a in &mut self.axes {
            a.mv = None;
        }
    }

    /// End time (µs) of `axis`'s current move, if any.
    pub fn move_end_us(&self, axis: usize) -> Option<u64> {
        self.axes[axis]
            .mv
            .as_ref()
            .map(|m| m.start_us + m.profile.step_offset_us(m.profile.steps()))
    }

    /// Declare the current position of `axis` to be `steps` (e.g. after a manual refill).
    /// Only at rest.
    pub fn set_position(&mut self, axis: usize, steps: i32) -> Result<(), MotionError> {
        let a = &mut self.axes[axis];
        if a.mv.is_some() {
            return Err(MotionError::Busy);
        }
        a.pos = steps;
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const DELTA: f32 = 0.04;

    #[test]
    fn hand_computed_trapezoid() {
        // 10 mm³ at 10 mm³/s, 100 mm³/s²: s_a = 0.5 mm³, t_a = 0.1 s, cruise 0.9 s, T = 1.1 s.
        let p = Trapezoid::new(250, DELTA, 10.0, 100.0);
        assert!((p.duration() - 1.1).abs() < 1e-6);
        // Step 1 (0.04 mm³, accelerating): √(2·0.04/100) = 0.0282843 s.
        assert_eq!(p.step_offset_us(1), 28_284);
        // Step 125 (5 mm³, cruising): 0.1 + 4.5/10 = 0.55 s.
        assert_eq!(p.step_offset_us(125), 550_000);
        // Step 240 (0.4 mm³ before the end): 1.1 − √(0.8/100) = 1.0105573 s.
        assert_eq!(p.step_offset_us(240), 1_010_557);
        assert_eq!(p.step_offset_us(250), 1_100_000);
    }

    #[test]
    fn hand_computed_triangle() {
        // 1 mm³ at up to 100 mm³/s, 100 mm³/s²: never reaches 100, peaks at √(100·1) = 10 mm³/s
        // after 0.1 s; T = 0.2 s; halfway (step 13 = 0.52 mm³, decelerating side):
        // 0.2 − √(2·0.48/100) = 0.1020204 s.
        let p = Trapezoid::new(25, DELTA, 100.0, 100.0);
        assert!((p.peak_flow() - 10.0).abs() < 1e-6);
        assert_eq!(p.step_offset_us(25), 200_000);
        assert_eq!(p.step_offset_us(13), 102_020);
    }

    /// Run a planner until every move finishes, recording (axis, instant, position).
    fn run(m: &mut Motion) -> std::vec::Vec<(usize, u64, i32)> {
        let mut out = std::vec::Vec::new();
        let mut now = 0;
        while !m.all_idle() {
            while m.take_direction_change(now).is_some() {}
            let (axis, at) = m.next_step().expect("a moving axis has a next step");
            assert!(at >= now, "steps in time order");
            now = at;
            let pos = m.record_step(axis);
            out.push((axis, at, pos));
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// Random concurrent moves: exact step counts, time order, and the step instants obey
        /// the speed and acceleration limits (to the 1 µs rounding of each instant).
        #[test]
        fn random_moves_exact_and_within_limits(
            targets in proptest::array::uniform3(0i32..5_000),
            flows in proptest::array::uniform3(1.0f32..400.0),
            accels in proptest::array::uniform3(50.0f32..10_000.0),
            starts in proptest::array::uniform3(0i32..5_000),
        ) {
            let mut m = Motion::new(MotionConfig::default());
            for i in 0..AXES {
                m.set_position(i, starts[i]).unwrap();
                m.start_move(i, targets[i], 13_750, flows[i], accels[i], 0).unwrap();
            }
            let log = run(&mut m);
            for i in 0..AXES {
                prop_assert_eq!(m.position(i), targets[i]);
                let steps: std::vec::Vec<u64> =
                    log.iter().filter(|s| s.0 == i).map(|s| s.1).collect();
                prop_assert_eq!(steps.len() as i32, (targets[i] - starts[i]).abs());
                let (v, a) = (flows[i] as f64, accels[i] as f64);
                let d = DELTA as f64;
                let start = MotionConfig::default().start_lead_us as f64 * 1e-6;
                let t: std::vec::Vec<f64> = steps.iter().map(|&u| u as f64 * 1e-6).collect();
                let q = 1e-6; // instants are rounded to the µs tick: ±0.5 µs each
                // From rest with |acceleration| ≤ a: k·Δ ≤ ½·a·t_k².
                for (k, &tk) in t.iter().enumerate() {
                    let el = tk - start + q;
                    prop_assert!((k + 1) as f64 * d <= 0.5 * a * el * el * (1.0 + 1e-9));
                }
                // Speed: each interval covers Δ no faster than v.
                let iv: std::vec::Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
                for &dt in &iv {
                    prop_assert!(d / (dt + q) <= v * (1.0 + 1e-9), "dt {} v {}", dt, v);
                }
                // Acceleration: mean speeds over adjacent intervals differ by at most a times
                // the span of both intervals (mean-value theorem), widened by the rounding.
                for w in iv.windows(2) {
                    let lo = d / (w[0] + q) - d / (w[1] - q);
                    let hi = d / (w[0] - q) - d / (w[1] + q);
                    let dv = if lo <= 0.0 && hi >= 0.0 { 0.0 } else { lo.abs().min(hi.abs()) };
                    prop_assert!(dv <= a * (w[0] + w[1] + 2.0 * q) * (1.0 + 1e-9));
                }
            }
        }

        /// Each instant is the analytic trapezoid's crossing of k·Δ, rounded to the µs: check by
        /// evaluating the closed-form distance s(t) (a different formula from the t(s) used by
        /// the planner) half a tick either side of the instant.
        #[test]
        fn step_instants_match_the_analytic_trapezoid(
            steps in 1u32..20_000, flow in 1.0f32..400.0, accel in 50.0f32..10_000.0,
        ) {
            let p = Trapezoid::new(steps, DELTA, flow, accel);
            let d = DELTA as f64;
            let tol = 1e-9 * steps as f64 * d;
            for k in (1..=steps).step_by(1 + steps as usize / 500) {
                let t = p.step_offset_us(k) as f64 * 1e-6;
                let target = k as f64 * d;
                prop_assert!(p.distance_at(t - 0.5e-6) <= target + tol, "k {} early", k);
                prop_assert!(p.distance_at(t + 0.5e-6) >= target - tol, "k {} late", k);
            }
            prop_assert_eq!(p.step_offset_us(steps), libm::round(p.duration() * 1e6) as u64);
        }
    }

    proptest! {
        #[test]
        fn sqrt64_matches_a_correctly_rounded_root(m in 1.0f64..2.0, e in -60i32..60) {
            let x = m * 2f64.powi(e);
            let r = sqrt64(x);
            // δ²/2 < 2⁻⁴⁷ (see sqrt64), plus f64 rounding of the Newton step.
            let bound = (2f64.powi(-47) + 2.0 * f64::EPSILON) * x.sqrt();
            prop_assert!((r - x.sqrt()).abs() <= bound, "{} {}", r, x.sqrt());
        }
    }

    #[test]
    fn refuses_bad_moves() {
        let mut m = Motion::new(MotionConfig::default());
        assert_eq!(
            m.start_move(0, 100, 50, 10.0, 100.0, 0),
            Err(MotionError::OutOfRange)
        );
        assert_eq!(
            m.start_move(0, -1, 50, 10.0, 100.0, 0),
            Err(MotionError::OutOfRange)
        );
        assert_eq!(
            m.start_move(0, 10, 50, f32::NAN, 100.0, 0),
            Err(MotionError::BadRate)
        );
        assert_eq!(
            m.start_move(0, 10, 50, 500.0, 100.0, 0),
            Err(MotionError::BadRate)
        );
        assert_eq!(
            m.start_move(0, 10, 50, 10.0, 0.0, 0),
            Err(MotionError::BadRate)
        );
        m.start_move(0, 10, 50, 10.0, 100.0, 0).unwrap();
        assert_eq!(
            m.start_move(0, 20, 50, 10.0, 100.0, 0),
            Err(MotionError::Busy)
        );
    }

    #[test]
    fn direction_change_precedes_first_step_by_setup_time() {
        let mut m = Motion::new(MotionConfig::default());
        m.start_move(1, 100, 1000, 50.0, 500.0, 0).unwrap();
        assert_eq!(m.next_step(), None, "no step before DIR is written");
        assert_eq!(m.take_direction_change(10), Some((1, Direction::Inflate)));
        run(&mut m);
        // Reverse: a new DIR, written late (at the first step's planned instant).
        m.start_move(1, 0, 1000, 50.0, 500.0, 2_000_000).unwrap();
        let planned = 2_000_000 + 1_000 + Trapezoid::new(100, DELTA, 50.0, 500.0).step_offset_us(1);
        assert_eq!(
            m.take_direction_change(planned),
            Some((1, Direction::Deflate))
        );
        let (_, at) = m.next_step().unwrap();
        assert_eq!(at, planned + MotionConfig::default().dir_setup_us as u64);
        // Same direction again: no DIR change needed.
        run(&mut m);
        m.set_position(1, 50).unwrap();
        m.start_move(1, 0, 1000, 50.0, 500.0, 9_000_000).unwrap();
        assert_eq!(m.take_direction_change(9_000_000), None);
    }

    #[test]
    fn flow_follows_profile_sign() {
        let mut m = Motion::new(MotionConfig::default());
        m.set_position(2, 1000).unwrap();
        m.start_move(2, 0, 2000, 20.0, 200.0, 0).unwrap();
        // Cruise at 20 mm³/s after 0.1 s of acceleration, deflating.
        assert_eq!(m.flow_at(2, 1_000 + 500_000), -20.0);
        assert!((m.flow_at(2, 1_000 + 50_000) + 10.0).abs() < 1e-3);
        assert_eq!(m.flow_at(0, 500_000), 0.0);
    }
}
