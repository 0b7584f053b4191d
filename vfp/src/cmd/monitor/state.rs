//! What the monitor knows about the stream: the latest frame, the recent history for the charts,
//! the counts of everything received, missed or unusable, and the last lines of other output.
//! Pure: lines in, numbers out; no terminal, no clock but the board's.
//!
//! A frame is placed by the tracker `vfp record` uses ([`sysid::board::sequence::SeqTracker`]), so the
//! monitor counts as frames exactly the frames that become rows of the log it records: a `seq`
//! jump is a gap, a `seq` restart at 0 (or after a `boot` event) a reboot, a `seq` or time that
//! does not advance is rejected, as is a frame with a non-finite volume, flow or pressure.

use std::collections::VecDeque;

use firmware::telemetry::{Event, EventKind, Frame};
use sysid::board::capture::{classify, CaptureLine};
use sysid::board::sequence::SeqTracker;

/// Lines kept for the log pane.
pub const LOG_KEEP: usize = 200;
/// Board time over which the frame rate is measured, s.
pub const RATE_WINDOW_S: f64 = 2.0;

/// One received frame, as the charts need it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Point {
    /// Board time, s.
    pub t_s: f64,
    /// Measured pressure per chamber, kPa.
    pub p: [f32; 3],
    /// Predicted pressure per chamber, kPa.
    pub p_hat: [f32; 3],
}

/// Counts since the monitor started.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counts {
    /// Lines read.
    pub lines: u64,
    /// Frames received and usable (each is one row per chamber in the recorded log).
    pub frames: u64,
    /// Event lines.
    pub events: u64,
    /// Fault events among them.
    pub fault_events: u64,
    /// Lines with a telemetry marker that did not decode.
    pub corrupted: u64,
    /// Frames that decoded but were not usable (duplicate, out of order, non-finite).
    pub rejected: u64,
    /// Other lines (logs, location lines).
    pub other: u64,
    /// Sequence gaps.
    pub gaps: u64,
    /// Frames missing in those gaps.
    pub missing: u64,
    /// Lines the board reports it dropped while the monitor was listening (the change of the
    /// frames' `drops` field).
    pub board_drops: u64,
    /// Missing frames that the board's `drops` does not account for: lost between the board
    /// and the monitor (at least this many).
    pub lost_in_transit: u64,
    /// Reboots of the board.
    pub restarts: u64,
}

/// The monitor's state.
#[derive(Debug, Clone)]
pub struct MonitorState {
    /// Chart window, s of board time.
    pub window_s: f64,
    /// Counts.
    pub counts: Counts,
    /// The latest usable frame.
    pub last: Option<Frame>,
    /// Recent frames, oldest first, covering at least `window_s`.
    history: VecDeque<Point>,
    /// Recent other lines, events and problems, oldest first.
    log: VecDeque<String>,
    /// Gaps, reboots and order.
    seq: SeqTracker,
    /// First `seq` seen.
    pub first_seq: Option<u32>,
    /// Whether the input has ended (the board's output closed).
    pub input_ended: bool,
}

impl MonitorState {
    /// An empty state with a chart window of `window_s` seconds.
    pub fn new(window_s: f64) -> Self {
        Self {
            window_s: window_s.max(0.1),
            counts: Counts::default(),
            last: None,
            history: VecDeque::new(),
            log: VecDeque::new(),
            seq: SeqTracker::new(),
            first_seq: None,
            input_ended: false,
        }
    }

    /// Takes one captured line (with or without its line end).
    pub fn push_line(&mut self, raw: &[u8]) {
        self.push_item(classify(raw));
    }

    /// Takes one item: a classified captured line, or a packet of the binary serial stream
    /// ([`sysid::board::packets`]); each counts as a line.
    pub fn push_item(&mut self, item: CaptureLine<'_>) {
        self.counts.lines += 1;
        match item {
            CaptureLine::Frame(f) => self.push_frame(&f),
            CaptureLine::Event(e, text) => self.push_event(&e, &text),
            CaptureLine::Corrupted(why) => {
                self.counts.corrupted += 1;
                let n = self.counts.lines;
                self.note(format!("corrupted line {n}: {why}"));
            }
            CaptureLine::Other(text) => {
                self.counts.other += 1;
                // The location lines under each defmt message say nothing to a person watching.
                let t = text.trim();
                if !t.is_empty() && !t.starts_with("└─") {
                    self.note(t.to_string());
                }
            }
        }
    }

    /// Takes one event.
    pub fn push_event(&mut self, e: &Event, text: &str) {
        self.counts.events += 1;
        match e.kind {
            EventKind::Boot { .. } => self.seq.boot(),
            EventKind::Fault { .. } => self.counts.fault_events += 1,
            _ => {}
        }
        self.note(format!("event at {:.3} s: {text}", e.t_us as f64 * 1e-6));
    }

    /// Takes one frame.
    pub fn push_frame(&mut self, f: &Frame) {
        let placed = match self.seq.frame(f) {
            Ok(p) => p,
            Err(why) => return self.reject(why),
        };
        if placed.restarted {
            self.counts.restarts += 1;
            self.history.clear();
            self.note(format!("board restarted (seq {})", f.seq));
        }
        let board = placed.board_drops;
        self.counts.board_drops += board;
        if let Some((a, b)) = placed.gap {
            let missing = placed.missing();
            self.counts.gaps += 1;
            self.counts.missing += missing;
            self.counts.lost_in_transit += missing.saturating_sub(board);
            self.note(format!(
                "gap: seq {a}..={b} missing ({missing} frames; the board dropped {board} lines)"
            ));
        }
        match placed.unusable {
            Some(why) => self.reject(why),
            None => self.accept(f),
        }
    }

    fn accept(&mut self, f: &Frame) {
        self.counts.frames += 1;
        self.first_seq.get_or_insert(f.seq);
        let t_s = f.t_us as f64 / 1e6;
        self.history.push_back(Point {
            t_s,
            p: f.chambers.map(|c| c.p),
            p_hat: f.chambers.map(|c| c.p_hat),
        });
        let keep_from = t_s - self.window_s.max(RATE_WINDOW_S);
        while self.history.front().is_some_and(|p| p.t_s < keep_from) {
            self.history.pop_front();
        }
        self.last = Some(*f);
    }

    fn reject(&mut self, why: String) {
        self.counts.rejected += 1;
        self.note(format!("rejected frame: {why}"));
    }

    fn note(&mut self, line: String) {
        if self.log.len() == LOG_KEEP {
            self.log.pop_front();
        }
        self.log.push_back(line);
    }

    /// The last lines of other output, events and problems, oldest first.
    pub fn log_lines(&self) -> impl DoubleEndedIterator<Item = &str> + ExactSizeIterator {
        self.log.iter().map(String::as_str)
    }

    /// Frames of the last `window_s` seconds, oldest first.
    pub fn window(&self) -> impl Iterator<Item = &Point> {
        let from = self.history.back().map_or(0.0, |p| p.t_s - self.window_s);
        self.history.iter().filter(move |p| p.t_s >= from)
    }

    /// Received frames per second of board time over the last [`RATE_WINDOW_S`] (fewer than the
    /// board sent when frames are missing); `None` before two frames.
    pub fn received_rate_hz(&self) -> Option<f64> {
        let last = self.history.back()?;
        let recent = self
            .history
            .iter()
            .filter(|p| p.t_s >= last.t_s - RATE_WINDOW_S);
        let (n, first) = recent.fold((0usize, last.t_s), |(n, t0), p| (n + 1, t0.min(p.t_s)));
        let span = last.t_s - first;
        (n >= 2 && span > 0.0).then(|| (n - 1) as f64 / span)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A frame at 25 Hz: seq n at (n + 1) × 40 ms, chamber pressures tagged with the seq.
    fn frame(seq: u32, drops: u32) -> Frame {
        let mut f = Frame {
            seq,
            t_us: 40_000 * u64::from(seq + 1),
            drops,
            ..Frame::default()
        };
        for (i, c) in f.chambers.iter_mut().enumerate() {
            c.p = seq as f32 + i as f32 / 10.0;
            c.p_hat = c.p - 0.5;
        }
        f
    }

    fn line(f: &Frame) -> String {
        let mut s = String::from("0.1 INFO ");
        f.encode(&mut s).unwrap();
        s
    }

    #[test]
    fn gaps_count_missing_frames_and_drops_tell_board_from_transit() {
        let mut s = MonitorState::new(10.0);
        // seq 0..=9; 3..=4 missing with the board reporting 2 drops (its own), 7 missing with
        // no drop reported (lost on the way), then 2 more board drops with no gap (events).
        let drops = |seq: u32| match seq {
            0..=2 => 5, // lines dropped before the monitor listened: not counted
            3..=8 => 7,
            _ => 9,
        };
        for seq in (0..10).filter(|q| ![3, 4, 7].contains(q)) {
            s.push_line(line(&frame(seq, drops(seq))).as_bytes());
        }
        let c = s.counts;
        assert_eq!((c.frames, c.gaps, c.missing), (7, 2, 3));
        assert_eq!(c.board_drops, 4);
        assert_eq!(c.lost_in_transit, 1);
        assert_eq!(s.last.unwrap().seq, 9);
        assert_eq!(s.first_seq, Some(0));
        assert!(s.log_lines().any(|l| l.contains("seq 3..=4 missing")));
    }

    #[test]
    fn drops_wrap_and_reboot_restarts_the_count() {
        let mut s = MonitorState::new(10.0);
        s.push_frame(&frame(0, u32::MAX - 1));
        s.push_frame(&frame(1, 2)); // wrapped: 4 dropped
        s.push_line(b"$E 10 boot 0 power-on");
        s.push_frame(&frame(0, 3)); // new boot: 3 dropped since boot
        assert_eq!(s.counts.restarts, 1);
        assert_eq!(s.counts.board_drops, 7);
        assert_eq!((s.counts.gaps, s.counts.rejected), (0, 0));
    }

    #[test]
    fn duplicates_and_bad_lines_are_counted_not_shown() {
        let mut s = MonitorState::new(10.0);
        s.push_frame(&frame(0, 0));
        s.push_frame(&frame(1, 0));
        s.push_frame(&frame(1, 0));
        let mut nan = frame(2, 0);
        nan.chambers[1].p = f32::NAN;
        s.push_frame(&nan);
        s.push_line(b"0.2 INFO $F 3 oops");
        s.push_line(b"\xff\xfe garbage");
        s.push_line(b"0.3 INFO zero taken");
        s.push_line("└─ vfp_fw::task @ src/bin/vfp-fw.rs:56".as_bytes());
        let c = s.counts;
        assert_eq!((c.frames, c.rejected, c.corrupted, c.other), (2, 2, 1, 3));
        assert_eq!(s.last.unwrap().seq, 1);
        let log: Vec<_> = s.log_lines().collect();
        assert_eq!(log.len(), 5, "{log:?}");
        assert!(log[4] == "0.3 INFO zero taken", "{log:?}");
    }

    #[test]
    fn rate_counts_received_frames_per_board_second() {
        let mut s = MonitorState::new(10.0);
        assert_eq!(s.received_rate_hz(), None);
        for seq in 0..100 {
            s.push_frame(&frame(seq, 0));
        }
        // Last frame at 4.0 s: seq 49..=99 lie within 2 s of it, 50 intervals in 2 s.
        let r = s.received_rate_hz().unwrap();
        assert!((r - 25.0).abs() < 1e-9, "{r}");
        // Every other frame lost: 12.5 frames per second arrive.
        let mut s = MonitorState::new(10.0);
        for seq in (0..100).step_by(2) {
            s.push_frame(&frame(seq, 0));
        }
        let r = s.received_rate_hz().unwrap();
        assert!((r - 12.5).abs() < 1e-9, "{r}");
    }

    #[test]
    fn window_keeps_the_last_seconds() {
        let mut s = MonitorState::new(1.0);
        for seq in 0..100 {
            s.push_frame(&frame(seq, 0));
        }
        let w: Vec<u32> = s.window().map(|p| p.p[0] as u32).collect();
        // Last frame at 4.0 s; frames from 3.0 s on: seq 74..=99.
        assert_eq!(w, (74..100).collect::<Vec<_>>());
    }
}
