//! The paper's characterisation protocol (Sec. II, Fig. 1c): the selected axes go to `v_low`,
//! then for each flow rate in turn run `cycles` inflate/deflate cycles between `v_low` and
//! `v_high`, dwelling at each end.
//!
//! Segments follow each other on an absolute time base: the next segment starts `dwell` after
//! the planned end of the previous one (or at the wake-up, if that is later), so the protocol
//! does not drift by the stepper task's latency.

use crate::command::ProtocolSpec;
use crate::hal::AXES;
use crate::motion::{Motion, MotionConfig, MotionError, PlannedMove, Trapezoid};

/// Where the protocol is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Leg {
    /// Initial move to `v_low` (at the first flow rate).
    Prime,
    /// Inflating to `v_high`.
    Up,
    /// Deflating to `v_low`.
    Down,
}

/// A protocol in progress.
///
/// Every profile it will run is planned when it is created (outside any critical section): the
/// prime move of each axis, and one `v_low`↔`v_high` profile per flow rate (up and down legs
/// share it). Starting a leg is then O(1) per axis, inside the stepper's short lock.
#[derive(Clone, Debug)]
pub struct ProtocolRun {
    spec: ProtocolSpec,
    leg: Leg,
    flow_idx: usize,
    cycle: u16,
    /// When the current leg's moves end (planned, µs); `None` before the first leg starts.
    leg_end_us: Option<u64>,
    /// `v_low`, `v_high` in steps.
    lo: i32,
    hi: i32,
    /// The prime move per axis.
    prime: [Option<PlannedMove>; AXES],
    /// The cycle profile per flow rate.
    cycles: heapless::Vec<Trapezoid, { crate::command::MAX_FLOWS }>,
}

/// What the protocol wants next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ProtocolPoll {
    /// Axes are moving: poll again when they are idle.
    Moving,
    /// Dwelling: poll again at this instant (µs).
    WaitUntil(u64),
    /// All cycles done.
    Done,
}

impl ProtocolRun {
    /// A protocol about to start from `positions`, within `capacity_steps`, with `accel` for
    /// every move: plans every profile it will need (or the reason one cannot run).
    pub fn new(
        spec: ProtocolSpec,
        accel: f32,
        cfg: &MotionConfig,
        positions: [i32; AXES],
        capacity_steps: [i32; AXES],
    ) -> Result<Self, MotionError> {
        let lo = cfg.volume_to_steps(spec.v_low);
        let hi = cfg.volume_to_steps(spec.v_high);
        let first = *spec.flows.first().ok_or(MotionError::BadRate)?;
        let mut prime = [None; AXES];
        for a in spec.axes.iter() {
            prime[a] = Some(cfg.plan(positions[a], lo, capacity_steps[a], first, accel)?);
        }
        let mut cycles = heapless::Vec::new();
        for &f in &spec.flows {
            // Up and down legs cover the same distance: one profile serves both.
            let up = cfg.plan(lo, hi, i32::MAX, f, accel)?;
            let profile = up.profile.ok_or(MotionError::OutOfRange)?;
            let _ = cycles.push(profile);
        }
        Ok(Self {
            spec,
            leg: Leg::Prime,
            flow_idx: 0,
            cycle: 0,
            leg_end_us: None,
            lo,
            hi,
            prime,
            cycles,
        })
    }

    /// The axes the protocol drives.
    pub fn axes(&self) -> crate::command::AxisSet {
        self.spec.axes
    }

    /// Advance: start the next leg when the axes are idle and the dwell is over. O(1) per axis
    /// (the profiles were planned by [`new`](Self::new)).
    pub fn poll(
        &mut self,
        motion: &mut Motion,
        capacity_steps: [i32; AXES],
        now_us: u64,
    ) -> Result<ProtocolPoll, MotionError> {
        if !self.spec.axes.iter().all(|a| motion.is_idle(a)) {
            return Ok(ProtocolPoll::Moving);
        }
        let dwell = self.spec.dwell_ms as u64 * 1_000;
        let start = match self.leg_end_us {
            None => now_us,
            Some(end) => {
                let due = end + dwell;
                if now_us < due {
                    return Ok(ProtocolPoll::WaitUntil(due));
                }
                // Next leg. Prime -> Up; Up -> Down; Down -> Up (next cycle / flow) or Done.
                match self.leg {
                    Leg::Prime => self.leg = Leg::Up,
                    Leg::Up => self.leg = Leg::Down,
                    Leg::Down => {
                        self.cycle += 1;
                        if self.cycle >= self.spec.cycles {
                            self.cycle = 0;
                            self.flow_idx += 1;
                        }
                        if self.flow_idx >= self.spec.flows.len() {
                            return Ok(ProtocolPoll::Done);
                        }
                        self.leg = Leg::Up;
                    }
                }
                // The planned instant: start_planned adds its start lead to it.
                due
            }
        };
        let mut end = start;
        for a in self.spec.axes.iter() {
            let plan = match self.leg {
                Leg::Prime => self.prime[a].ok_or(MotionError::Busy)?,
                Leg::Up | Leg::Down => {
                    let (from, target) = if self.leg == Leg::Up {
                        (self.lo, self.hi)
                    } else {
                        (self.hi, self.lo)
                    };
                    PlannedMove {
                        from,
                        target,
                        profile: Some(self.cycles[self.flow_idx]),
                    }
                }
            };
            if !(0..=capacity_steps[a]).contains(&plan.target) {
                return Err(MotionError::OutOfRange);
            }
            motion.start_planned(a, &plan, start)?;
            end = end.max(motion.move_end_us(a).unwrap_or(start));
        }
        self.leg_end_us = Some(end);
        Ok(ProtocolPoll::Moving)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::command::AxisSet;
    use crate::motion::MotionConfig;

    /// Drive the protocol and the planner to completion; collect (axis, step instant, position).
    #[test]
    fn runs_every_cycle_at_every_flow_with_dwell() {
        let spec = ProtocolSpec {
            axes: AxisSet(0b011),
            v_low: 10.0,
            v_high: 20.0,
            cycles: 2,
            dwell_ms: 100,
            flows: heapless::Vec::from_slice(&[10.0, 20.0]).unwrap(),
        };
        let mut m = Motion::new(MotionConfig::default());
        let cap = [13_750; 3];
        let mut run = ProtocolRun::new(spec, 500.0, m.config(), [0; 3], cap).unwrap();
        let mut now = 0u64;
        let mut legs = std::vec::Vec::new(); // (start µs, target steps of axis 0)
        let mut reversals = 0;
        let mut last_pos = m.position(0);
        let mut last_dir = 0;
        let mut last_end = None;
        loop {
            match run.poll(&mut m, cap, now).unwrap() {
                ProtocolPoll::Done => break,
                ProtocolPoll::WaitUntil(t) => {
                    assert!(t > now);
                    now = t;
                    continue;
                }
                ProtocolPoll::Moving => {}
            }
            // A new leg started in this poll when its planned end changed.
            if run.leg_end_us != last_end {
                last_end = run.leg_end_us;
                legs.push((now, run.leg));
            }
            while m.take_direction_change(now).is_some() {}
            let Some((axis, at)) = m.next_step() else {
                continue;
            };
            now = at;
            let pos = m.record_step(axis);
            if axis == 0 {
                let dir = (pos - last_pos).signum();
                if dir != last_dir && last_dir != 0 {
                    reversals += 1;
                }
                last_dir = dir;
                last_pos = pos;
            }
        }
        // Prime (0 -> 250 steps), then 2 flows × 2 cycles × (up, down).
        assert_eq!(legs.len(), 1 + 2 * 2 * 2);
        assert_eq!(legs[0].1, Leg::Prime);
        assert_eq!(m.position(0), 250);
        assert_eq!(m.position(1), 250);
        assert_eq!(m.position(2), 0, "axis 2 not in the protocol");
        // Direction changes: prime up, then up/down alternate: 8 legs after prime -> the
        // direction reverses at every leg boundary except prime -> first up (both inflate).
        assert_eq!(reversals, 7);
        // Dwell: each leg starts exactly 100 ms after the previous leg's planned end; the
        // cycle at 10 mm³/s takes 1 s + 0.02 s (accel 500: t_a = 0.02 s, 10 mm³ -> T = 1.02 s).
        let t_leg_slow = 1_020_000u64;
        let lead = MotionConfig::default().start_lead_us as u64;
        assert_eq!(legs[1].0 - legs[0].0, lead + 1_020_000 + 100_000);
        assert_eq!(legs[2].0 - legs[1].0, lead + t_leg_slow + 100_000);
    }
}
