//! Slow zero drift, corrected at rest at the zero's own volume.
//!
//! The pressure zero is taken at boot and on `zero` (the mean raw pressure over
//! [`Config::zero_frames`](crate::app::Config::zero_frames) frames). A gauge sensor's offset then
//! creeps (warm-up, temperature: host-sim's `thermal-drift` moves it by 1 kPa), and every kPa of
//! offset is 22 mN of force per chamber that nobody applied. The board cannot tell a drift from a
//! push by the pressure alone, so it corrects the zero only where it knows what the pressure must
//! be and only by what a drift can do in that time:
//!
//! - **where**: the chamber is at rest (no commanded flow in the frame) at the volume it had when
//!   the zero was taken (within [`RestZeroConfig::tol_mm3`]). There the model's estimate P̂ (with
//!   its effect chain) is the same at every stay, so the residual `r = P − P̂` changes only by the
//!   zero's drift and by external loads;
//! - **when**: after [`RestZeroConfig::settle_frames`] frames at rest (the wall relaxes), the mean
//!   residual `r̄` over the next [`RestZeroConfig::window_frames`] frames; once per stay at that
//!   volume (the next one needs a move away and back). The first stay after a zero (at boot, the
//!   board's first seconds) gives the reference `r₀`: the model's own error there, which is the
//!   model's business and is left alone;
//! - **how much**: at a later stay, a change `d = r̄ − r₀` with `|d| ≤`
//!   [`RestZeroConfig::max_step_kpa`] moves the zero by `d` (`zero ← zero + d`, so the residual
//!   there is back at `r₀` from the next frame on) and posts a `zero` event with the new offsets.
//!   A larger change is a load, not a drift: the zero is left alone.
//!
//! What it costs: a load of at most `max_step_kpa` (0.5 kPa, 11 mN per chamber) held at the zero's
//! volume through a whole settle and window is taken for drift, once per stay; a load that stays
//! for many stays can walk the zero by that much per stay, and a load during the reference stay
//! is taken into `r₀` (the zero itself must be taken unloaded anyway). `origin` renames the
//! volumes (the step count restarts at the declared volume): the anchor moves with them, so it
//! stays the same plunger position, and the next stay there takes a new reference (P̂ at the
//! anchor's new volume differs); a model load also takes a new reference at the next stay. Online RLS (`rls <ch> on`) moves P̂ between stays, and
//! that move is taken for drift too (bounded the same way). Set
//! [`Config::rest_zero`](crate::app::Config) to `None` to turn it off.

/// When and by how much the zero may move at rest (module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RestZeroConfig {
    /// Frames at rest before the residual is averaged (the wall relaxes), 50 = 2 s at 25 Hz.
    pub settle_frames: u32,
    /// Frames averaged, 25 = 1 s.
    pub window_frames: u32,
    /// How close to the zero's volume counts as there, mm³.
    pub tol_mm3: f32,
    /// Largest correction taken for drift, kPa.
    pub max_step_kpa: f32,
}

impl Default for RestZeroConfig {
    fn default() -> Self {
        Self {
            settle_frames: 50,
            window_frames: 25,
            tol_mm3: 0.5,
            max_step_kpa: 0.5,
        }
    }
}

/// What a frame did to the rest correction of one chamber.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RestOutcome {
    /// Nothing completed.
    Pending,
    /// The first window after a zero completed: its mean residual is the reference `r₀`, kPa.
    Reference(f32),
    /// A later window changed by `d` within bounds: add `d` to the chamber's zero, kPa.
    Shift(f32),
    /// A later window changed by `d` over the bound (a load): zero unchanged, kPa.
    Refused(f32),
}

/// One chamber's rest-correction state.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RestZero {
    /// The volume at the last zero, mm³; `None` until a zero, and after `origin`.
    anchor: Option<f32>,
    /// The mean residual of the first stay after the zero, kPa.
    reference: Option<f32>,
    /// Frames at rest at the anchor so far.
    rest: u32,
    /// Sum and count of the window's residuals.
    sum: f32,
    n: u32,
    /// This stay's window has completed.
    done: bool,
}

impl RestZero {
    /// A zero was taken with the chamber at `v_mm3`.
    pub fn anchor(&mut self, v_mm3: f32) {
        *self = Self {
            anchor: Some(v_mm3),
            ..Self::default()
        };
    }

    /// A new model: P̂ at the anchor changed, so the next stay gives a new reference.
    pub fn new_model(&mut self) {
        self.reference = None;
    }

    /// The step count restarted (`origin`) `dv_mm3` above where it was: the anchor, the same
    /// plunger position, is now `dv_mm3` higher, and the next stay there gives a new reference.
    pub fn shift(&mut self, dv_mm3: f32) {
        *self = Self {
            anchor: self.anchor.map(|a| a + dv_mm3),
            ..Self::default()
        };
    }

    /// One frame of the chamber: its volume (mm³), commanded flow (mm³/s) and residual (kPa,
    /// after the current zero). Non-finite residuals (model out of range) do not count.
    pub fn frame(&mut self, cfg: &RestZeroConfig, v: f32, vdot: f32, residual: f32) -> RestOutcome {
        let there = self
            .anchor
            .is_some_and(|a| vdot == 0.0 && (v - a).abs() <= cfg.tol_mm3);
        if !there {
            *self = Self {
                anchor: self.anchor,
                reference: self.reference,
                ..Self::default()
            };
            return RestOutcome::Pending;
        }
        if self.done {
            return RestOutcome::Pending;
        }
        self.rest = self.rest.saturating_add(1);
        if self.rest <= cfg.settle_frames || !residual.is_finite() {
            return RestOutcome::Pending;
        }
        self.sum += residual;
        self.n += 1;
        if self.n < cfg.window_frames.max(1) {
            return RestOutcome::Pending;
        }
        self.done = true;
        let mean = self.sum / self.n as f32;
        let Some(r0) = self.reference else {
            self.reference = Some(mean);
            return RestOutcome::Reference(mean);
        };
        let d = mean - r0;
        if d.abs() <= cfg.max_step_kpa {
            RestOutcome::Shift(d)
        } else {
            RestOutcome::Refused(d)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> RestZeroConfig {
        RestZeroConfig {
            settle_frames: 3,
            window_frames: 4,
            tol_mm3: 0.5,
            max_step_kpa: 0.5,
        }
    }

    /// Frames at (v, v̇, r) until something completes; the outcome and the frames it took.
    fn run(z: &mut RestZero, frames: usize, v: f32, vdot: f32, r: f32) -> (RestOutcome, usize) {
        for k in 1..=frames {
            let o = z.frame(&cfg(), v, vdot, r);
            if o != RestOutcome::Pending {
                return (o, k);
            }
        }
        (RestOutcome::Pending, frames)
    }

    /// A move away from the anchor and back.
    fn away(z: &mut RestZero) {
        z.frame(&cfg(), 150.0, 20.0, 0.0);
    }

    #[test]
    fn the_first_stay_is_the_reference_and_later_changes_move_the_zero_once_per_stay() {
        let mut z = RestZero::default();
        z.anchor(100.0);
        // Settle 3 frames, then a window of 4: the 7th frame completes.
        assert_eq!(
            run(&mut z, 20, 100.2, 0.0, 1.5),
            (RestOutcome::Reference(1.5), 7)
        );
        // Once per stay.
        assert_eq!(run(&mut z, 50, 100.2, 0.0, 1.75).0, RestOutcome::Pending);
        away(&mut z);
        assert_eq!(
            run(&mut z, 20, 100.0, 0.0, 1.75),
            (RestOutcome::Shift(0.25), 7)
        );
        away(&mut z);
        assert_eq!(
            run(&mut z, 20, 100.0, 0.0, 1.375).0,
            RestOutcome::Shift(-0.125)
        );
    }

    #[test]
    fn a_change_over_the_bound_is_a_load_and_is_refused() {
        let mut z = RestZero::default();
        z.anchor(0.0);
        assert_eq!(
            run(&mut z, 20, 0.0, 0.0, 0.0).0,
            RestOutcome::Reference(0.0)
        );
        away(&mut z);
        assert_eq!(run(&mut z, 20, 0.0, 0.0, 2.0).0, RestOutcome::Refused(2.0));
        // The reference stays: a small drift later is still measured from it.
        away(&mut z);
        assert_eq!(run(&mut z, 20, 0.0, 0.0, 0.25).0, RestOutcome::Shift(0.25));
    }

    #[test]
    fn motion_elsewhere_no_anchor_or_bad_residuals_take_nothing() {
        let mut z = RestZero::default();
        // No zero yet.
        assert_eq!(run(&mut z, 30, 0.0, 0.0, 0.125).0, RestOutcome::Pending);
        z.anchor(0.0);
        // Moving through the anchor.
        assert_eq!(run(&mut z, 30, 0.0, 5.0, 0.125).0, RestOutcome::Pending);
        // At rest, away from it.
        assert_eq!(run(&mut z, 30, 0.6, 0.0, 0.125).0, RestOutcome::Pending);
        // Out of the model's range: the frames do not count, the window waits.
        assert_eq!(run(&mut z, 30, 0.0, 0.0, f32::NAN).0, RestOutcome::Pending);
        assert_eq!(
            run(&mut z, 30, 0.0, 0.0, 0.125),
            (RestOutcome::Reference(0.125), 4)
        );
        // After `origin` declared the plunger 100 mm³ higher than counted, the anchor is at
        // 100: a stay at the old volume 0 is away from it, a stay at 100 gives a new reference.
        z.shift(100.0);
        away(&mut z);
        assert_eq!(run(&mut z, 30, 0.0, 0.0, 0.25).0, RestOutcome::Pending);
        assert_eq!(
            run(&mut z, 30, 100.0, 0.0, 0.25).0,
            RestOutcome::Reference(0.25)
        );
        // No zero yet: nothing to move.
        let mut fresh = RestZero::default();
        fresh.shift(100.0);
        assert_eq!(fresh, RestZero::default());
    }

    #[test]
    fn a_stay_interrupted_before_its_window_starts_over() {
        let mut z = RestZero::default();
        z.anchor(0.0);
        // Two frames short of completing, a frame of motion: the settle starts again.
        assert_eq!(run(&mut z, 5, 0.0, 0.0, 0.375).0, RestOutcome::Pending);
        z.frame(&cfg(), 0.0, 3.0, 0.375);
        assert_eq!(
            run(&mut z, 20, 0.0, 0.0, 0.375),
            (RestOutcome::Reference(0.375), 7)
        );
    }
}
