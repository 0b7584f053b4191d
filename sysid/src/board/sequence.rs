//! A frame's place in the stream: gaps, reboots, duplicates and drops, decided in one place for
//! every reader of the board's telemetry (`vfp record`'s [`crate::board::record`], `vfp monitor`).
//!
//! The rules, for a frame after the previous decoded frame (`seq₀`, `t₀`):
//! - **reboot**: `seq ≤ seq₀` and either a `boot` event came since that frame or `seq` is 0. The
//!   frame starts a new segment (the board counts `seq` and `drops` from 0 again).
//! - **out of order**: otherwise `seq ≤ seq₀` (a duplicate, or older), or `t_us ≤ t₀`: the frame
//!   is refused and changes nothing.
//! - **gap**: `seq > seq₀ + 1`: frames `seq₀+1 ..= seq−1` are missing. The change of `drops`
//!   since the previous frame of the same boot (wrapping) is what the board says it dropped
//!   itself; the rest of a gap was lost on the way.
//! - **unusable**: a frame in its place whose volume, flow or pressure is not finite: it counts in
//!   the sequence (the next frame is no gap) but gives no log row.

use firmware::telemetry::Frame;

/// Where a frame that is not out of order stands.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Placed {
    /// The board rebooted before this frame.
    pub restarted: bool,
    /// Sequence numbers missing right before this frame, `first..=last`.
    pub gap: Option<(u32, u32)>,
    /// Board time per sequence step since the previous frame, µs (same boot only).
    pub period_us: Option<u64>,
    /// Lines the board reports it dropped since the previous frame of this boot (0 for the
    /// first frame heard: what it dropped before is not this reader's).
    pub board_drops: u64,
    /// Why the frame gives no row, if it does not (a non-finite volume, flow or pressure).
    pub unusable: Option<String>,
}

impl Placed {
    /// Frames missing right before this one.
    pub fn missing(&self) -> u64 {
        self.gap.map_or(0, |(a, b)| u64::from(b - a) + 1)
    }
}

/// The sequence state between frames.
#[derive(Debug, Clone, Default)]
pub struct SeqTracker {
    /// `seq` and `t_us` of the last frame placed.
    last: Option<(u32, u64)>,
    /// Its `drops`, `None` before the first frame heard.
    last_drops: Option<u32>,
    boot_seen: bool,
}

impl SeqTracker {
    /// Before any frame.
    pub fn new() -> Self {
        Self::default()
    }

    /// A `boot` event arrived: the next frame with a `seq` not above the last is a reboot.
    pub fn boot(&mut self) {
        self.boot_seen = true;
    }

    /// Places a frame; `Err(why)` when it is out of order (nothing changes then).
    pub fn frame(&mut self, f: &Frame) -> Result<Placed, String> {
        let mut placed = Placed {
            restarted: false,
            gap: None,
            period_us: None,
            board_drops: 0,
            unusable: None,
        };
        if let Some((seq, t_us)) = self.last {
            if f.seq <= seq && (self.boot_seen || f.seq == 0) {
                placed.restarted = true;
                self.last_drops = Some(0);
            } else if f.seq <= seq {
                return Err(format!(
                    "seq {} does not follow seq {seq} (duplicate or out of order)",
                    f.seq
                ));
            } else if f.t_us <= t_us {
                return Err(format!(
                    "seq {}: time {} us is not after {t_us} us",
                    f.seq, f.t_us
                ));
            } else {
                if f.seq > seq + 1 {
                    placed.gap = Some((seq + 1, f.seq - 1));
                }
                placed.period_us = Some((f.t_us - t_us) / u64::from(f.seq - seq));
            }
        }
        placed.board_drops = self
            .last_drops
            .map_or(0, |d| u64::from(f.drops.wrapping_sub(d)));
        self.last_drops = Some(f.drops);
        self.boot_seen = false;
        self.last = Some((f.seq, f.t_us));
        if let Some(i) = f
            .chambers
            .iter()
            .position(|c| !(c.v.is_finite() && c.p.is_finite() && c.vdot.is_finite()))
        {
            placed.unusable = Some(format!(
                "seq {}: chamber {i} has a non-finite volume, flow or pressure",
                f.seq
            ));
        }
        Ok(placed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f(seq: u32, t_us: u64, drops: u32) -> Frame {
        Frame {
            seq,
            t_us,
            drops,
            ..Frame::default()
        }
    }

    #[test]
    fn the_rules_by_hand() {
        let mut s = SeqTracker::new();
        let first = s.frame(&f(5, 200_000, 9)).unwrap();
        assert_eq!(
            (first.gap, first.board_drops, first.restarted),
            (None, 0, false)
        );
        let next = s.frame(&f(6, 240_000, 9)).unwrap();
        assert_eq!((next.gap, next.period_us), (None, Some(40_000)));
        // Three missing, the board dropped two of them.
        let gap = s.frame(&f(10, 400_000, 11)).unwrap();
        assert_eq!(
            (gap.gap, gap.missing(), gap.board_drops),
            (Some((7, 9)), 3, 2)
        );
        assert_eq!(gap.period_us, Some(40_000));
        assert!(s
            .frame(&f(10, 400_000, 11))
            .unwrap_err()
            .contains("duplicate"));
        assert!(s
            .frame(&f(11, 400_000, 11))
            .unwrap_err()
            .contains("not after"));
        // A reboot: seq 0, drops counted from 0 again.
        let r = s.frame(&f(0, 40_000, 1)).unwrap();
        assert_eq!((r.restarted, r.board_drops, r.gap), (true, 1, None));
        // After a boot event any seq not above the last is a reboot too.
        s.boot();
        assert!(s.frame(&f(0, 40_000, 0)).unwrap().restarted);
        let mut nan = f(1, 80_000, 0);
        nan.chambers[2].p = f32::NAN;
        let u = s.frame(&nan).unwrap();
        assert!(u.unusable.unwrap().contains("chamber 2"));
        // The unusable frame still took its place: seq 2 follows without a gap.
        assert_eq!(s.frame(&f(2, 120_000, 0)).unwrap().gap, None);
        // drops wrap.
        let mut s = SeqTracker::new();
        s.frame(&f(0, 1, u32::MAX)).unwrap();
        assert_eq!(s.frame(&f(1, 2, 1)).unwrap().board_drops, 2);
    }
}
