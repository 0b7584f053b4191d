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
//!
//! # Arithmetic (no `f64` on the step path)
//! The Cortex-M4F has a single-precision FPU and no double-precision unit, so the per-step
//! work uses integers and `f32` only. In µs, with `I = Δ/v` (the cruise step interval),
//! `H = v/(2a)` (half the acceleration time) and `C = 2Δ/a` (µs² per step):
//!
//! ```text
//! acceleration   k ≤ K_a:        t_k = √(k·C)                      (f32, from the move's start)
//! cruise         K_a < k ≤ N−K_a: t_k = k·I + H                     (Q32.32 fixed point)
//! deceleration   k > N − K_a:     t_k = T − √((N − k)·C)            (f32, back from the end)
//! ```
//!
//! with `K_a = s_a/Δ` and `T = N·I + 2H` (trapezoid) or `T = 2·√(N·C/2)` (triangle). `I`, `H`
//! and `T` are computed once per move in integer arithmetic ([`Trapezoid::new`], outside any
//! critical section), to better than 2⁻³⁸ relative, so the cruise instants and the last step
//! are exact to the µs over any move length. The square roots are measured from the phase's
//! own start (acceleration) or end (deceleration), so `f32` keeps its precision where it is
//! used: a correctly rounded `√` of an argument with two roundings is within 2⁻²³ relative,
//! i.e. within `δ·2⁻²³` of the exact instant, `δ` the time from the phase start or end (under
//! 0.12 µs for phases up to 1 s, 0.5 µs at 4 s) — then rounded to the µs tick.
//! A step costs one `f32` square root in the ramps, or one 32 × 64-bit product while cruising.

use crate::hal::{Direction, AXES};

/// 2⁻³² as `f32` (exact).
const TWO_POW_M32: f32 = 1.0 / 4_294_967_296.0;

/// `x = m·2^e` with an integer mantissa (finite, non-negative `x`).
fn parts(x: f32) -> (u64, i32) {
    let b = x.to_bits();
    let e = ((b >> 23) & 0xff) as i32;
    let f = (b & 0x7f_ffff) as u64;
    if e == 0 {
        (f, -149)
    } else {
        (f | 0x80_0000, e - 150)
    }
}

/// `round(num/den · scale · 2³²)` for finite positive `num`, `den` and `scale < 2²¹`, in
/// 64-bit integer arithmetic (the quotient keeps at least 38 significant bits, so its relative
/// error is below 2⁻³⁸); `None` when it does not fit in a `u64` or rounds to zero.
fn ratio_q32(num: f32, den: f32, scale: u32) -> Option<u64> {
    let (mn, en) = parts(num);
    let (md, ed) = parts(den);
    if mn == 0 || md == 0 || scale == 0 {
        return None;
    }
    // value = mn·scale/md · 2^(en − ed + 32); normalise the dividend to 63 bits first.
    let p = mn * scale as u64; // < 2⁴⁵
    let lz = p.leading_zeros() - 1;
    let (q, r) = ((p << lz) / md, (p << lz) % md);
    let q = q + u64::from(2 * r >= md); // ≥ 2³⁸
    let shift = en - ed + 32 - lz as i32;
    let v = if shift >= 0 {
        if shift >= 64 || q.leading_zeros() < shift as u32 {
            return None;
        }
        q << shift
    } else {
        let s = (-shift) as u32;
        if s >= 64 {
            return None;
        }
        (q >> s) + ((q >> (s - 1)) & 1)
    };
    (v > 0).then_some(v)
}

/// `√x` for `x` in Q32 µs² (below 2⁹⁴), in Q32 µs: the `f32` root, then one Newton step on the
/// exact residual (error far below 10⁻³ µs; no 128-bit division).
fn sqrt_q32(x_q: u128) -> u64 {
    if x_q == 0 {
        return 0;
    }
    // √(x_q·2³²) = √x_q · 2¹⁶.
    let y0 = (libm::sqrtf(x_q as f32) * 65_536.0) as u64;
    if y0 == 0 {
        return 0;
    }
    let residual = (x_q << 32) as i128 - (y0 as u128 * y0 as u128) as i128;
    let corr = residual as f32 / (2.0 * y0 as f32);
    y0.saturating_add_signed(corr as i64)
}

/// `k · q` for a Q32 value `q`, as two 32 × 32-bit products (no 128-bit multiply routine).
fn mul_q(k: u32, q: u64) -> u128 {
    let lo = k as u64 * (q & 0xffff_ffff);
    let hi = k as u64 * (q >> 32);
    ((hi as u128) << 32) + lo as u128
}

/// A Q32 µs value rounded to whole µs.
fn round_q(t: u128) -> u64 {
    ((t + (1 << 31)) >> 32) as u64
}

/// One move's velocity profile, ready for per-step evaluation (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Trapezoid {
    steps: u32,
    /// Last step timed by the acceleration formula (`⌊K_a⌋`).
    acc_last: u32,
    /// First step timed by the deceleration formula.
    dec_first: u32,
    /// `C = 2Δ/a`, µs² per step.
    c_us2: f32,
    /// Cruise step interval `I`, Q32 µs.
    interval_q: u64,
    /// Cruise offset `H = t_a − s_a/v_p` (= `v/(2a)`), Q32 µs.
    offset_q: u64,
    /// Duration `T`, Q32 µs.
    end_q: u128,
    /// Acceleration time `t_a`, Q32 µs.
    acc_q: u64,
    /// Peak flow actually reached, mm³/s.
    v_peak: f32,
    /// Acceleration, mm³/s².
    accel: f32,
    /// Volume per step, mm³.
    step_mm3: f32,
}

impl Trapezoid {
    /// Longest acceleration (or deceleration) phase, µs: 2³¹ µs ≈ 36 min.
    pub const MAX_RAMP_US: u64 = 1 << 31;

    /// Profile for `steps` steps of `step_mm3` each, speed limit `flow` mm³/s and acceleration
    /// `accel` mm³/s². Panics where [`try_new`](Self::try_new) returns `None`.
    pub fn new(steps: u32, step_mm3: f32, flow: f32, accel: f32) -> Self {
        Self::try_new(steps, step_mm3, flow, accel).expect("a profile the planner can time")
    }

    /// The profile, or `None` when an input is not finite and positive, a cruise step would
    /// take 2³² µs or more, or a ramp longer than [`MAX_RAMP_US`](Self::MAX_RAMP_US) (flows and
    /// accelerations far below anything a syringe pump is run at). Integer and `f32`
    /// arithmetic; runs once per move, outside any critical section.
    pub fn try_new(steps: u32, step_mm3: f32, flow: f32, accel: f32) -> Option<Self> {
        let ok = |x: f32| x.is_finite() && x > 0.0;
        if !(ok(step_mm3) && ok(flow) && ok(accel)) {
            return None;
        }
        // C = 2·(Δ/a·10⁶)·10⁶ µs², from the exact ratio: one rounding to f32.
        let r = ratio_q32(step_mm3, accel, 1_000_000)?;
        let c_us2 = (r as u128 * 2_000_000) as f32 * TWO_POW_M32;
        if !ok(c_us2) {
            return None;
        }
        let mut p = Self {
            steps,
            acc_last: 0,
            dec_first: steps.max(1),
            c_us2,
            interval_q: 0,
            offset_q: 0,
            end_q: 0,
            acc_q: 0,
            v_peak: 0.0,
            accel,
            step_mm3,
        };
        if steps == 0 {
            return Some(p);
        }
        // Steps covered while accelerating to `flow`: K = v²/(2aΔ) (∞ when it overflows).
        let k_full = flow * flow / (2.0 * accel * step_mm3);
        if 2.0 * k_full >= steps as f32 {
            // Triangle: t_p² = N·Δ/a (µs² · 10⁻¹²), T = 2·t_p.
            let x_q = steps as u128 * r as u128 * 1_000_000;
            if x_q >> 94 != 0 {
                return None; // t_p ≥ 2³¹ µs
            }
            let t_q = sqrt_q32(x_q) as u128;
            p.acc_last = steps / 2;
            p.dec_first = steps / 2 + 1;
            p.end_q = 2 * t_q;
            p.acc_q = t_q as u64;
            p.v_peak = libm::sqrtf(accel * steps as f32 * step_mm3);
        } else {
            p.interval_q = ratio_q32(step_mm3, flow, 1_000_000)?;
            p.offset_q = ratio_q32(flow, accel, 500_000)?;
            if p.offset_q >> 62 != 0 || p.interval_q >> 63 != 0 {
                return None; // t_a = 2H ≥ 2³¹ µs
            }
            // Step k accelerates while k ≤ K_a, decelerates when k > N − K_a.
            let whole = k_full as u32; // < N/2
            p.acc_last = whole;
            p.dec_first = steps - whole + u32::from(whole as f32 == k_full);
            p.end_q = mul_q(steps, p.interval_q) + 2 * p.offset_q as u128;
            p.acc_q = 2 * p.offset_q;
            p.v_peak = flow;
        }
        Some(p)
    }

    /// Number of steps.
    pub fn steps(&self) -> u32 {
        self.steps
    }
    /// Peak flow actually reached, mm³/s.
    pub fn peak_flow(&self) -> f32 {
        self.v_peak
    }
    /// Duration `T`, whole µs.
    pub fn duration_us(&self) -> u64 {
        round_q(self.end_q)
    }

    /// Instant of step `k` (1..=N), in whole µs after the start (see the module docs for the
    /// arithmetic and its precision).
    pub fn step_offset_us(&self, k: u32) -> u64 {
        if k <= self.acc_last {
            // y < 2³¹, so y + 0.5 is exact below 2²³ and the conversion truncates: round(y).
            let y = libm::sqrtf(k as f32 * self.c_us2);
            (y + 0.5) as u32 as u64
        } else if k < self.dec_first {
            round_q(mul_q(k, self.interval_q) + self.offset_q as u128)
        } else if k >= self.steps {
            round_q(self.end_q)
        } else {
            // T − δ, T = ti + tf: round(T − δ) = ti − ⌈δ − tf − ½⌉.
            let d = libm::sqrtf((self.steps - k) as f32 * self.c_us2);
            let ti = (self.end_q >> 32) as u64;
            let tf = (self.end_q as u32) as f32 * TWO_POW_M32;
            let y = d - tf - 0.5;
            let mut c = y as i32;
            if (c as f32) < y {
                c += 1;
            }
            ti.saturating_add_signed(-(c as i64))
        }
    }

    /// Speed (unsigned, mm³/s) at `t_us` µs after the start; 0 outside the move. `f32` only.
    pub fn flow_at_us(&self, t_us: u64) -> f32 {
        let t_q = (t_us as u128) << 32;
        if t_us == 0 || t_q >= self.end_q {
            0.0
        } else if t_q < self.acc_q as u128 {
            self.accel * (t_us as f32 * 1e-6)
        } else if t_q + self.acc_q as u128 <= self.end_q {
            self.v_peak
        } else {
            let rest = self.end_q - t_q; // < t_a < 2³¹ µs
            let us = (rest >> 32) as u32 as f32 + (rest as u32) as f32 * TWO_POW_M32;
            self.accel * (us * 1e-6)
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
    /// Flow or acceleration not finite, not positive, above the firmware's maximum, or so low
    /// that the move cannot be timed (see [`Trapezoid::try_new`]).
    BadRate,
}

/// A move planned ahead (outside any critical section), started later by
/// [`Motion::start_planned`] in O(1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PlannedMove {
    /// Position the plan starts from, steps.
    pub from: i32,
    /// Target position, steps.
    pub target: i32,
    /// The profile (`None` for a zero-length move).
    pub profile: Option<Trapezoid>,
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
    /// Direction the DIR line is set to.
    dir: Option<Direction>,
    /// Direction a new move needs, not yet written to the DIR line.
    pending_dir: Option<Direction>,
    /// Earliest instant a step may come, µs: the DIR write plus the driver's set-up time (0
    /// before any write), [`NOT_DUE`] while a DIR change is pending.
    ready_us: u64,
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

impl MotionConfig {
    /// Steps for a volume, rounded to the nearest step.
    pub fn volume_to_steps(&self, mm3: f32) -> i32 {
        libm::roundf(mm3 / self.mm3_per_step) as i32
    }

    /// Plan a move from `from` to the absolute `target` (steps), limited to `capacity_steps`.
    /// Pure computation (the profile's constants): call it outside any critical section, then
    /// start it with [`Motion::start_planned`].
    pub fn plan(
        &self,
        from: i32,
        target: i32,
        capacity_steps: i32,
        flow: f32,
        accel: f32,
    ) -> Result<PlannedMove, MotionError> {
        let rate_ok = |x: f32, max: f32| x.is_finite() && x > 0.0 && x <= max;
        if !rate_ok(flow, self.max_flow) || !rate_ok(accel, self.max_accel) {
            return Err(MotionError::BadRate);
        }
        if !(0..=capacity_steps).contains(&target) {
            return Err(MotionError::OutOfRange);
        }
        let delta = target as i64 - from as i64;
        let profile = if delta == 0 {
            None
        } else {
            let n = u32::try_from(delta.unsigned_abs()).map_err(|_| MotionError::OutOfRange)?;
            Some(
                Trapezoid::try_new(n, self.mm3_per_step, flow, accel)
                    .ok_or(MotionError::BadRate)?,
            )
        };
        Ok(PlannedMove {
            from,
            target,
            profile,
        })
    }
}

/// Axes that step together at one instant (bit `a` = axis `a`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StepBatch {
    /// The planned instant, µs.
    pub at_us: u64,
    /// Axis mask.
    pub axes: u8,
}

impl StepBatch {
    /// The axes, ascending (one bit scan per axis in the batch, none for the others).
    pub fn iter(self) -> impl Iterator<Item = usize> {
        let mut rest = self.axes & ((1 << AXES) - 1);
        core::iter::from_fn(move || {
            let a = rest.trailing_zeros() as usize;
            rest &= rest.wrapping_sub(1);
            (a < AXES).then_some(a)
        })
    }
}

/// [`Motion`]'s instant for an axis that has no step to take (no move, or its DIR line not yet
/// written).
const NOT_DUE: u64 = u64::MAX;

/// The three axes' motion state.
///
/// Each axis's due instant is kept in `due_us`, recomputed ([`Motion::refresh_due`]) by every
/// method that changes what it depends on (the move's next step, the DIR line): a stepper
/// wake-up reads three `u64`s instead of re-deriving them from the moves.
#[derive(Clone, Debug)]
pub struct Motion {
    cfg: MotionConfig,
    axes: [Axis; AXES],
    /// When each axis is due to step next, [`NOT_DUE`] if it is not.
    due_us: [u64; AXES],
    /// Axes with a DIR change not yet written (bit `a` = axis `a`).
    pending_dirs: u8,
}

impl Motion {
    /// All axes at volume 0, at rest.
    pub fn new(cfg: MotionConfig) -> Self {
        Self {
            cfg,
            axes: [Axis::default(); AXES],
            due_us: [NOT_DUE; AXES],
            pending_dirs: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &MotionConfig {
        &self.cfg
    }

    /// Steps for a volume, rounded to the nearest step.
    pub fn volume_to_steps(&self, mm3: f32) -> i32 {
        self.cfg.volume_to_steps(mm3)
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
            Some(m) if t_us > m.start_us => m.sign as f32 * m.profile.flow_at_us(t_us - m.start_us),
            _ => 0.0,
        }
    }

    /// Plan and start a move of `axis` to the absolute `target` steps at `now_us`, limited to
    /// `capacity_steps` ([`MotionConfig::plan`] then [`start_planned`](Self::start_planned)).
    /// A zero-length move succeeds and does nothing.
    pub fn start_move(
        &mut self,
        axis: usize,
        target: i32,
        capacity_steps: i32,
        flow: f32,
        accel: f32,
        now_us: u64,
    ) -> Result<(), MotionError> {
        let plan = self
            .cfg
            .plan(self.axes[axis].pos, target, capacity_steps, flow, accel)?;
        self.start_planned(axis, &plan, now_us)
    }

    /// Start a planned move of `axis` at `now_us` (its profile's time zero is `now_us` plus the
    /// start lead). O(1): one step instant is computed. `Busy` if the axis moves or is no longer
    /// where the plan starts from.
    pub fn start_planned(
        &mut self,
        axis: usize,
        plan: &PlannedMove,
        now_us: u64,
    ) -> Result<(), MotionError> {
        let lead = self.cfg.start_lead_us as u64;
        let a = &mut self.axes[axis];
        if a.mv.is_some() || a.pos != plan.from {
            return Err(MotionError::Busy);
        }
        let Some(profile) = plan.profile else {
            return Ok(());
        };
        let dir = if plan.target > plan.from {
            Direction::Inflate
        } else {
            Direction::Deflate
        };
        if a.dir != Some(dir) {
            a.pending_dir = Some(dir);
            a.ready_us = NOT_DUE;
            self.pending_dirs |= 1 << axis;
        }
        let start_us = now_us + lead;
        a.mv = Some(ActiveMove {
            start_us,
            sign: (plan.target - plan.from).signum(),
            profile,
            next: 1,
            next_at_us: start_us + profile.step_offset_us(1),
        });
        self.refresh_due(axis);
        Ok(())
    }

    /// Direction changes to write to the DIR lines now (call on every wake-up; the first
    /// step of that axis waits at least the set-up time after `now_us`).
    pub fn take_direction_change(&mut self, now_us: u64) -> Option<(usize, Direction)> {
        if self.pending_dirs == 0 {
            return None;
        }
        let i = self.pending_dirs.trailing_zeros() as usize;
        self.pending_dirs &= !(1 << i);
        let a = &mut self.axes[i];
        let d = a.pending_dir.take()?;
        a.dir = Some(d);
        a.ready_us = now_us + self.cfg.dir_setup_us as u64;
        self.refresh_due(i);
        Some((i, d))
    }

    /// Recompute the instant `axis` is due to step next (after any change to its move or DIR):
    /// the planned instant of its next step, except that a step never comes sooner than the
    /// driver's set-up time after its DIR change (only possible if the task woke later than the
    /// start lead allows for), and none while the DIR change is not written (the task writes it
    /// before sleeping, the step is planned after it).
    fn refresh_due(&mut self, axis: usize) {
        let a = &self.axes[axis];
        self.due_us[axis] = a.mv.map_or(NOT_DUE, |m| m.next_at_us.max(a.ready_us));
    }

    /// The earliest due step over all axes: `(axis, instant µs)` (the lowest axis on a tie).
    pub fn next_step(&self) -> Option<(usize, u64)> {
        let b = self.next_batch()?;
        Some((b.axes.trailing_zeros() as usize, b.at_us))
    }

    /// The instant of the earliest due step over all axes, µs.
    pub fn next_due_us(&self) -> Option<u64> {
        let at_us = self.due_us.iter().fold(NOT_DUE, |m, &t| m.min(t));
        (at_us != NOT_DUE).then_some(at_us)
    }

    /// Every axis due at the earliest instant, together: the steps the task issues in one go.
    /// O(1) per axis (the cached instants).
    pub fn next_batch(&self) -> Option<StepBatch> {
        let at_us = self.next_due_us()?;
        let axes = (0..AXES).fold(0u8, |m, i| m | (u8::from(self.due_us[i] == at_us) << i));
        Some(StepBatch { at_us, axes })
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
        let pos = a.pos;
        self.refresh_due(axis);
        pos
    }

    /// Record the steps of the axes in `axes` (bit `a` = axis `a`, as in [`StepBatch`]), unless
    /// one of them would leave `0..=capacity_steps[a]`: then nothing is recorded and the first
    /// such axis (ascending) is the error.
    pub fn record_batch(&mut self, axes: u8, capacity_steps: &[i32; AXES]) -> Result<(), usize> {
        for a in 0..AXES {
            let Some(m) = self.axes[a].mv.as_ref().filter(|_| axes & (1 << a) != 0) else {
                continue;
            };
            if !(0..=capacity_steps[a]).contains(&(self.axes[a].pos + m.sign)) {
                return Err(a);
            }
        }
        for a in 0..AXES {
            if axes & (1 << a) != 0 {
                self.record_step(a);
            }
        }
        Ok(())
    }

    /// Abandon every move immediately (positions stay where the last step left them).
    pub fn stop_all(&mut self) {
        for a in &mut self.axes {
            a.mv = None;
        }
        self.due_us = [NOT_DUE; AXES];
    }

    /// End time (µs) of `axis`'s current move, if any.
    pub fn move_end_us(&self, axis: usize) -> Option<u64> {
        self.axes[axis]
            .mv
            .as_ref()
            .map(|m| m.start_us + m.profile.duration_us())
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

    /// The f64 closed-form trapezoid (the planner's former arithmetic): the test oracle.
    struct Reference {
        steps: u32,
        step: f64,
        accel: f64,
        v_peak: f64,
        s_acc: f64,
        t_acc: f64,
        t_cruise: f64,
    }

    impl Reference {
        fn new(steps: u32, step_mm3: f32, flow: f32, accel: f32) -> Self {
            let (step, flow, accel) = (step_mm3 as f64, flow as f64, accel as f64);
            let d = steps as f64 * step;
            let s_full = flow * flow / (2.0 * accel);
            let (v_peak, t_cruise) = if 2.0 * s_full >= d {
                ((accel * d).sqrt(), 0.0)
            } else {
                (flow, (d - 2.0 * s_full) / flow)
            };
            Self {
                steps,
                step,
                accel,
                v_peak,
                s_acc: v_peak * v_peak / (2.0 * accel),
                t_acc: v_peak / accel,
                t_cruise,
            }
        }
        fn distance(&self) -> f64 {
            self.steps as f64 * self.step
        }
        fn duration(&self) -> f64 {
            2.0 * self.t_acc + self.t_cruise
        }
        /// Distance covered (mm³) at `t` s after the start.
        fn distance_at(&self, t: f64) -> f64 {
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
        /// Speed at `t` s.
        fn flow_at(&self, t: f64) -> f64 {
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
        /// Time from the nearer ramp end (start of acceleration, end of deceleration) when step
        /// `k` falls in a ramp, µs; 0 while cruising. A step on a phase boundary counts as a
        /// ramp step (the planner may time it with a ramp's square root): the boundaries are
        /// widened by 10⁻¹² relative, far above this f64 arithmetic's rounding (the peak step of
        /// a triangle, `s = D/2`, came out 4·10⁻¹⁵ mm³ above `s_acc` = `v_p²/(2a)` and was
        /// taken for a cruise step).
        fn ramp_offset_us(&self, k: u32) -> f64 {
            let s = k as f64 * self.step;
            let s_acc = self.s_acc * (1.0 + 1e-12);
            if s <= s_acc {
                (2.0 * s / self.accel).sqrt() * 1e6
            } else if s < self.distance() - s_acc {
                0.0
            } else {
                (2.0 * (self.distance() - s) / self.accel).sqrt() * 1e6
            }
        }
    }

    #[test]
    fn hand_computed_trapezoid() {
        // 10 mm³ at 10 mm³/s, 100 mm³/s²: s_a = 0.5 mm³, t_a = 0.1 s, cruise 0.9 s, T = 1.1 s.
        let p = Trapezoid::new(250, DELTA, 10.0, 100.0);
        assert_eq!(p.duration_us(), 1_100_000);
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

    #[test]
    fn integer_helpers_by_hand() {
        // 0.04 / 10 · 10⁶ = 4000 µs exactly (0.04 is not exact in binary: the f32 value is
        // 0.039999999105930328…, so 3999.9999105930328 µs, × 2³²).
        let q = ratio_q32(0.04, 10.0, 1_000_000).unwrap();
        let exact = 0.04f32 as f64 / 10.0 * 1e6 * 4_294_967_296.0;
        assert!(
            (q as f64 - exact).abs() <= exact * 2f64.powi(-38),
            "{q} vs {exact}"
        );
        assert_eq!(ratio_q32(1.0, 1.0, 1), Some(1 << 32));
        assert_eq!(ratio_q32(1.0e-30, 1.0e30, 1), None, "rounds to zero");
        assert_eq!(ratio_q32(1.0e30, 1.0e-30, 1), None, "does not fit");
        for x in [
            1u128 << 32,
            3 << 40,
            (1 << 93) + 12345,
            987_654_321_987_654_321,
        ] {
            let want = (x as f64 * 4_294_967_296.0).sqrt();
            let got = sqrt_q32(x) as f64;
            // Within 10⁻⁴ µs (the f64 reference itself is good to 2⁻⁵² relative).
            assert!(
                (got - want).abs() <= 1e-4 * 4_294_967_296.0 + want * 1e-15,
                "{x}"
            );
        }
        assert_eq!(
            mul_q(u32::MAX, u64::MAX),
            u32::MAX as u128 * u64::MAX as u128
        );
    }

    #[test]
    fn untimeable_profiles_are_refused() {
        assert!(Trapezoid::try_new(10, DELTA, f32::NAN, 100.0).is_none());
        assert!(Trapezoid::try_new(10, DELTA, 10.0, 0.0).is_none());
        // A cruise step of 4000 s (1e-5 mm³/s): refused, as is a ramp of 2³¹ µs or more.
        assert!(Trapezoid::try_new(10_000, DELTA, 1.0e-5, 100.0).is_none());
        assert!(Trapezoid::try_new(1_000_000, DELTA, 100.0, 1.0e-6).is_none());
        let m = MotionConfig::default();
        assert_eq!(
            m.plan(0, 100, 1000, 1.0e-9, 100.0),
            Err(MotionError::BadRate)
        );
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
                // Each instant is the exact one rounded to the µs (±0.5 µs) plus the f32 error
                // of the ramps' square roots (≤ 0.25 µs for these ramps of at most 2 s, see the
                // module docs): within q = 1 µs, so an interval within 2q (it was q with the
                // former f64 arithmetic).
                let q = 1e-6;
                // From rest with |acceleration| ≤ a: k·Δ ≤ ½·a·t_k².
                for (k, &tk) in t.iter().enumerate() {
                    let el = tk - start + q;
                    prop_assert!((k + 1) as f64 * d <= 0.5 * a * el * el * (1.0 + 1e-9));
                }
                // Speed: each interval covers Δ no faster than v.
                let iv: std::vec::Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
                for &dt in &iv {
                    prop_assert!(d / (dt + 2.0 * q) <= v * (1.0 + 1e-9), "dt {} v {}", dt, v);
                }
                // Acceleration: mean speeds over adjacent intervals differ by at most a times
                // the span of both intervals (mean-value theorem), widened by the rounding.
                for w in iv.windows(2) {
                    let (q2, w0, w1) = (2.0 * q, w[0], w[1]);
                    let lo = d / (w0 + q2) - d / (w1 - q2);
                    let hi = d / (w0 - q2) - d / (w1 + q2);
                    let dv = if lo <= 0.0 && hi >= 0.0 { 0.0 } else { lo.abs().min(hi.abs()) };
                    prop_assert!(dv <= a * (w0 + w1 + 2.0 * q2) * (1.0 + 1e-9));
                }
            }
        }

        /// Each instant is the analytic trapezoid's crossing of k·Δ, rounded to the µs: check by
        /// evaluating the closed-form distance s(t) of the f64 reference (a different formula
        /// from the t(s) used by the planner) half a tick either side of the instant. The ramps'
        /// f32 square roots may move an instant by δ·2⁻²³ (δ: time from the ramp's start or end,
        /// see the module docs) before the rounding: the window is widened by twice that bound
        /// (≤ 1 µs here: ramps of at most 4 s); cruise instants and the last step are exact.
        #[test]
        fn step_instants_match_the_analytic_trapezoid(
            steps in 1u32..20_000, flow in 1.0f32..400.0, accel in 50.0f32..10_000.0,
        ) {
            let p = Trapezoid::new(steps, DELTA, flow, accel);
            let r = Reference::new(steps, DELTA, flow, accel);
            let d = DELTA as f64;
            let tol = 1e-9 * steps as f64 * d;
            for k in (1..=steps).step_by(1 + steps as usize / 500) {
                let t = p.step_offset_us(k) as f64 * 1e-6;
                let slack = 0.5e-6 + r.ramp_offset_us(k) * 2f64.powi(-22) * 1e-6;
                let target = k as f64 * d;
                prop_assert!(r.distance_at(t - slack) <= target + tol, "k {} early", k);
                prop_assert!(r.distance_at(t + slack) >= target - tol, "k {} late", k);
            }
            prop_assert_eq!(p.step_offset_us(steps), libm::round(r.duration() * 1e6) as u64);
            prop_assert_eq!(p.duration_us(), libm::round(r.duration() * 1e6) as u64);
            prop_assert!((p.peak_flow() as f64 - r.v_peak).abs() <= 1e-6 * r.v_peak);
        }

        /// The f32 flow at a sampling instant is the reference's to f32 precision.
        #[test]
        fn flow_matches_the_reference(
            steps in 1u32..20_000, flow in 1.0f32..400.0, accel in 50.0f32..10_000.0,
            frac in 0.0f64..1.0,
        ) {
            let p = Trapezoid::new(steps, DELTA, flow, accel);
            let r = Reference::new(steps, DELTA, flow, accel);
            let t_us = (frac * r.duration() * 1e6) as u64;
            let want = r.flow_at(t_us as f64 * 1e-6);
            let got = p.flow_at_us(t_us) as f64;
            prop_assert!((got - want).abs() <= 1e-5 * r.v_peak + 1e-6, "{} vs {}", got, want);
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
        // A plan made from another position is refused (the axis moved since).
        let plan = m.config().plan(5, 20, 50, 10.0, 100.0).unwrap();
        assert_eq!(m.start_planned(1, &plan, 0), Err(MotionError::Busy));
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

    /// Drive `m` the way the stepper task does, from `now` until every axis is idle or `stop_at`
    /// (then `stop_all`, before any step due at that instant): at each instant the moves of
    /// `starts` due then are started, the DIR changes written, and the batch due recorded.
    /// Returns each axis's step instants and the time it ended.
    fn drive(
        m: &mut Motion,
        mut now: u64,
        mut starts: std::vec::Vec<(u64, usize, i32, f32, f32)>,
        stop_at: Option<u64>,
    ) -> ([std::vec::Vec<u64>; AXES], u64) {
        let mut log: [std::vec::Vec<u64>; AXES] = Default::default();
        starts.sort_by_key(|s| s.0);
        starts.reverse();
        for _ in 0..100_000 {
            let next_start = starts.last().map(|s| s.0);
            let next_step = m.next_batch().map(|b| b.at_us);
            let Some(t) = [next_start, next_step].into_iter().flatten().min() else {
                return (log, now);
            };
            if let Some(stop) = stop_at.filter(|&s| s <= t && s >= now) {
                m.stop_all();
                return (log, stop);
            }
            now = t;
            while starts.last().is_some_and(|s| s.0 == now) {
                let (_, axis, target, flow, accel) = starts.pop().unwrap();
                m.start_move(axis, target, 10_000, flow, accel, now)
                    .unwrap();
            }
            while m.take_direction_change(now).is_some() {}
            if let Some(b) = m.next_batch().filter(|b| b.at_us <= now) {
                assert_eq!(b.at_us, now, "a step came late");
                m.record_batch(b.axes, &[10_000; AXES]).unwrap();
                for a in b.iter() {
                    log[a].push(now);
                }
            }
        }
        panic!("the moves never finished");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(48))]

        /// The cached due instants change nothing: moves started at arbitrary instants on three
        /// axes, possibly stopped part-way, then reversed together, step exactly at their
        /// profiles' instants (time zero = start + lead, then `Trapezoid::step_offset_us`, the
        /// planner's profile checked against the analytic trapezoid above), each once, every
        /// axis due at an instant in that instant's batch, and none after a stop.
        #[test]
        fn steps_come_at_the_profiles_instants(
            starts in proptest::array::uniform3(0u64..3_000),
            targets in proptest::array::uniform3(1i32..300),
            flows in proptest::array::uniform3(5.0f32..400.0),
            accels in proptest::array::uniform3(100.0f32..10_000.0),
            stop_at in proptest::option::of(1_000u64..400_000),
        ) {
            let cfg = MotionConfig::default();
            let lead = cfg.start_lead_us as u64;
            let mut m = Motion::new(cfg);
            let plan = (0..AXES).map(|a| (starts[a], a, targets[a], flows[a], accels[a]));
            let (log, end) = drive(&mut m, 0, plan.collect(), stop_at);
            for a in 0..AXES {
                let p = Trapezoid::new(targets[a] as u32, DELTA, flows[a], accels[a]);
                let want: std::vec::Vec<u64> = (1..=p.steps())
                    .map(|k| starts[a] + lead + p.step_offset_us(k))
                    .filter(|&t| stop_at.is_none_or(|s| t < s))
                    .collect();
                prop_assert_eq!(&log[a], &want, "axis {}", a);
                prop_assert_eq!(m.position(a), want.len() as i32);
            }
            prop_assert!(m.all_idle());
            // 0.1 s later (a step of a stopped move would have come by then), back to 0
            // together (a DIR change on every axis that moved), same rates.
            let t2 = end + 100_000;
            let back = (0..AXES).map(|a| (t2, a, 0, 100.0, 2_000.0));
            let from: [i32; AXES] = core::array::from_fn(|a| m.position(a));
            let (log, _) = drive(&mut m, end, back.collect(), None);
            for a in 0..AXES {
                let want: std::vec::Vec<u64> = match from[a] {
                    0 => std::vec::Vec::new(),
                    n => {
                        let p = Trapezoid::new(n as u32, DELTA, 100.0, 2_000.0);
                        (1..=p.steps()).map(|k| t2 + lead + p.step_offset_us(k)).collect()
                    }
                };
                prop_assert_eq!(&log[a], &want, "axis {} back", a);
                prop_assert_eq!(m.position(a), 0);
            }
        }
    }

    #[test]
    fn same_instant_steps_form_one_batch() {
        let mut m = Motion::new(MotionConfig::default());
        for a in 0..AXES {
            m.start_move(a, 50, 1000, 20.0, 500.0, 0).unwrap();
        }
        while m.take_direction_change(0).is_some() {}
        let b = m.next_batch().unwrap();
        assert_eq!(b.axes, 0b111);
        assert_eq!(b.iter().collect::<std::vec::Vec<_>>(), [0, 1, 2]);
        // Axis 1 one step ahead: it alone is due first.
        m.record_step(1);
        let b = m.next_batch().unwrap();
        assert_eq!(b.axes, 0b101);
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
