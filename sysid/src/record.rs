//! `vfp record CAPTURE -o LOG.csv`: the firmware's telemetry text turned into an actuation log.
//!
//! Input is text as printed by `probe-rs run` for the `vfp-fw` binary (each defmt line with its
//! timestamp, level and colour codes in front, the `└─ module @ file:line` location on the next
//! line), or the raw `$F`/`$E` lines (as the simulator captures them). Each telemetry line is found
//! by its `$` marker and decoded by the firmware's own parser
//! ([`firmware::telemetry::parse_line`]), so the format has one definition.
//!
//! Output is the log format (`docs/log-format.md`): one row per chamber per frame with
//! `time_s, chamber, volume_mm3, flow_mm3_s, pressure_kpa`, plus the device's own numbers as extra
//! columns `seq, flags, p_hat_kpa, residual_kpa, k_kpa_per_mm3, c_kpa_s_per_mm3, force_est_n`.
//! Event lines (zero offsets, faults, model loads) become `# event …` comments.
//!
//! # Nothing is lost silently
//! - A jump in the frame sequence number is a **gap**: the missing range is reported with the
//!   capture line where it was noticed, and written into the log's comments.
//! - A line that carries a `$F`/`$E` marker but does not decode (truncated, garbled) is
//!   **corrupted**: reported with its line number and the parser's reason; conversion goes on.
//!   A frame whose marker itself was destroyed shows up as a gap instead.
//! - A frame that decodes but cannot be a log row (a non-finite volume or pressure, a sequence
//!   number that goes backwards without a reboot) is **rejected** and reported the same way.
//! - A reboot (a `boot` event, or `seq` restarting at 0) starts a new segment; `time_s` continues
//!   from the previous segment's last frame plus one period, so time still increases, and the
//!   restart is reported.
//!
//! # Units
//! Converted exactly once: `t_us` (µs) → `time_s` = t_us / 10⁶. Every other number is already in
//! the log's units (mm³, mm³/s, kPa, N). The device's `f32` values are carried over as the
//! shortest decimal that reads back to the same `f32` — the digits printed on the telemetry line —
//! so the log shows what the device sent, digit for digit.

use std::fmt::Write as _;
use std::io::BufRead;
use std::path::Path;

use firmware::telemetry::{self, EventKind, Frame, Line};

use crate::log::{Log, Sample};

/// Names of the extra columns, in order.
pub const EXTRA_COLUMNS: [&str; 7] = [
    "seq",
    "flags",
    "p_hat_kpa",
    "residual_kpa",
    "k_kpa_per_mm3",
    "c_kpa_s_per_mm3",
    "force_est_n",
];

/// How many individual gaps / bad lines are listed in the summary (all are counted).
const LIST_LIMIT: usize = 20;

/// Frames missing between two received frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Gap {
    /// Capture line (1-based) of the first frame after the gap.
    pub line: usize,
    /// First missing sequence number.
    pub first: u32,
    /// Last missing sequence number.
    pub last: u32,
}

impl Gap {
    /// Number of missing frames.
    pub fn frames(&self) -> u64 {
        u64::from(self.last - self.first) + 1
    }
}

/// A line that could not be used, and why.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct BadLine {
    /// Capture line, 1-based.
    pub line: usize,
    /// Why, one phrase.
    pub reason: String,
}

/// A reboot seen in the capture.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct Restart {
    /// Capture line of the first frame after the reboot.
    pub line: usize,
    /// Its sequence number.
    pub seq: u32,
    /// Offset added to its `t_us` to keep time increasing, µs.
    pub time_offset_us: u64,
}

/// A converted capture.
#[derive(Debug, Clone)]
pub struct Recording {
    /// The log (comments, rows, extra columns).
    pub log: Log,
    /// Frames written (each gives one row per chamber).
    pub frames: usize,
    /// Event lines decoded.
    pub events: usize,
    /// Sequence gaps, in capture order.
    pub gaps: Vec<Gap>,
    /// Lines with a telemetry marker that did not decode.
    pub corrupted: Vec<BadLine>,
    /// Frames that decoded but could not become log rows.
    pub rejected: Vec<BadLine>,
    /// Reboots.
    pub restarts: Vec<Restart>,
    /// Lines read in all.
    pub lines: usize,
    /// Lines without telemetry (printer decorations, other log messages), skipped by design.
    pub other_lines: usize,
    /// Sequence number of the first frame (a capture may start mid-run).
    pub first_seq: Option<u32>,
}

impl Recording {
    /// Frames missing in all gaps.
    pub fn missing_frames(&self) -> u64 {
        self.gaps.iter().map(Gap::frames).sum()
    }

    /// Whether every frame between the first and the last arrived and every line was usable.
    pub fn is_complete(&self) -> bool {
        self.gaps.is_empty() && self.corrupted.is_empty() && self.rejected.is_empty()
    }

    /// A human summary: counts, then the first gaps and bad lines by line number.
    pub fn summary(&self, source: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{source}: {} lines, {} frames ({} log rows), {} events, {} other lines",
            self.lines,
            self.frames,
            self.log.samples.len(),
            self.events,
            self.other_lines
        );
        if let Some(q) = self.first_seq.filter(|&q| q != 0) {
            let _ = writeln!(
                s,
                "  capture starts at frame seq {q} (frames before it were not captured)"
            );
        }
        let _ = writeln!(
            s,
            "  missing frames: {} in {} gap(s)",
            self.missing_frames(),
            self.gaps.len()
        );
        for g in self.gaps.iter().take(LIST_LIMIT) {
            let _ = writeln!(
                s,
                "    seq {}..={} ({} frames) before line {}",
                g.first,
                g.last,
                g.frames(),
                g.line
            );
        }
        more(&mut s, self.gaps.len());
        for (what, list) in [
            ("corrupted lines", &self.corrupted),
            ("rejected frames", &self.rejected),
        ] {
            let _ = writeln!(s, "  {what}: {}", list.len());
            for b in list.iter().take(LIST_LIMIT) {
                let _ = writeln!(s, "    line {}: {}", b.line, b.reason);
            }
            more(&mut s, list.len());
        }
        for r in &self.restarts {
            let _ = writeln!(
                s,
                "  board restarted before line {} (seq {}); time continues (+{:.3} s)",
                r.line,
                r.seq,
                r.time_offset_us as f64 * 1e-6
            );
        }
        s
    }
}

fn more(s: &mut String, n: usize) {
    if n > LIST_LIMIT {
        let _ = writeln!(s, "    … and {} more", n - LIST_LIMIT);
    }
}

/// Why a capture could not be converted at all.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    /// Reading the capture failed.
    #[error("{file}: {source}")]
    Io {
        /// The capture.
        file: String,
        /// The operating-system error.
        source: std::io::Error,
    },
    /// Not a single frame in the capture.
    #[error(
        "{file}: no telemetry frame (`$F …` line) in {lines} lines; record the output of \
         `probe-rs run` for the vfp-fw firmware"
    )]
    NoFrames {
        /// The capture.
        file: String,
        /// Lines read.
        lines: usize,
    },
}

/// Removes ANSI escape sequences (`ESC [ … final`), which `probe-rs` adds on a terminal.
fn strip_ansi(s: &str) -> std::borrow::Cow<'_, str> {
    if !s.contains('\x1b') {
        return s.into();
    }
    let mut out = String::with_capacity(s.len());
    let mut it = s.chars().peekable();
    while let Some(c) = it.next() {
        if c != '\x1b' {
            out.push(c);
            continue;
        }
        if it.peek() == Some(&'[') {
            it.next();
            // Parameters and intermediates up to the final byte in '@'..='~'.
            for d in it.by_ref() {
                if ('@'..='~').contains(&d) {
                    break;
                }
            }
        }
    }
    out.into()
}

/// The telemetry part of a printed line: from the `$` marker, with a location suffix that some
/// printer formats put on the same line (`… (src/x.rs:12)`, `… @ src/x.rs:12`) removed.
fn telemetry_part(text: &str) -> Option<&str> {
    let start = [telemetry::FRAME_TAG, telemetry::EVENT_TAG]
        .iter()
        .filter_map(|t| text.find(t))
        .min()?;
    let rest = text[start..].trim_end();
    for sep in [" └─", " @ ", " ("] {
        if let Some(i) = rest.find(sep) {
            return Some(rest[..i].trim_end());
        }
    }
    Some(rest)
}

/// The shortest decimal of an `f32`, as the device printed it, read as `f64`.
fn decimal(x: f32) -> f64 {
    // Display prints the shortest round-trip digits; parsing them as f64 keeps those digits.
    format!("{x}").parse().unwrap_or(f64::NAN)
}

/// State of the conversion between lines.
struct Converter {
    rec: Recording,
    last: Option<(u32, u64)>,
    boot_seen: bool,
    offset_us: u64,
    /// Largest time written so far (with offset), µs.
    last_time_us: Option<u64>,
    periods: Vec<u64>,
}

/// Converts a capture. Never fails on bad lines (they are reported in the [`Recording`]); fails
/// only when the input cannot be read or holds no frame at all.
pub fn convert(mut reader: impl BufRead, source: &str) -> Result<Recording, RecordError> {
    let mut c = Converter {
        rec: Recording {
            log: Log {
                extra_columns: EXTRA_COLUMNS.iter().map(|s| s.to_string()).collect(),
                ..Log::default()
            },
            frames: 0,
            events: 0,
            gaps: Vec::new(),
            corrupted: Vec::new(),
            rejected: Vec::new(),
            restarts: Vec::new(),
            lines: 0,
            other_lines: 0,
            first_seq: None,
        },
        last: None,
        boot_seen: false,
        offset_us: 0,
        last_time_us: None,
        periods: Vec::new(),
    };
    let mut buf = Vec::new();
    let mut event_comments = Vec::new();
    loop {
        buf.clear();
        let n = reader
            .read_until(b'\n', &mut buf)
            .map_err(|e| RecordError::Io {
                file: source.to_string(),
                source: e,
            })?;
        if n == 0 {
            break;
        }
        c.rec.lines += 1;
        let no = c.rec.lines;
        let Ok(text) = std::str::from_utf8(&buf) else {
            // Only a line that claims to be telemetry matters; judge it on its readable part.
            if String::from_utf8_lossy(&buf).contains('$') {
                c.rec.corrupted.push(BadLine {
                    line: no,
                    reason: "not valid UTF-8".into(),
                });
            } else {
                c.rec.other_lines += 1;
            }
            continue;
        };
        let text = strip_ansi(text.trim_end_matches(['\n', '\r']));
        let Some(part) = telemetry_part(&text) else {
            c.rec.other_lines += 1;
            continue;
        };
        match telemetry::parse_line(part) {
            None => c.rec.other_lines += 1,
            Some(Err(e)) => c.rec.corrupted.push(BadLine {
                line: no,
                reason: format!("{e}: {}", clip(part)),
            }),
            Some(Ok(Line::Event(ev))) => {
                c.rec.events += 1;
                if matches!(ev.kind, EventKind::Boot { .. }) {
                    c.boot_seen = true;
                }
                event_comments.push(format!(
                    "event at {:.6} s (capture line {no}): {part}",
                    (ev.t_us + c.offset_us) as f64 * 1e-6
                ));
            }
            Some(Ok(Line::Frame(f))) => c.frame(&f, no),
        }
    }
    if c.rec.frames == 0 {
        return Err(RecordError::NoFrames {
            file: source.to_string(),
            lines: c.rec.lines,
        });
    }
    let rate = {
        c.periods.sort_unstable();
        c.periods
            .get(c.periods.len() / 2)
            .map_or(0.0, |&p| (1e6 / p as f64 * 1000.0).round() / 1000.0)
    };
    let mut comments = vec![
        format!("source=vfp record {source}"),
        format!("sample_rate_hz={rate}"),
        format!("frames={}", c.rec.frames),
        format!("missing_frames={}", c.rec.missing_frames()),
        format!("corrupted_lines={}", c.rec.corrupted.len()),
        format!("rejected_frames={}", c.rec.rejected.len()),
        "columns seq..force_est_n are the device's own: frame sequence number, flag bits, model \
         prediction (kPa), residual (kPa), stiffness (kPa/mm3), damping (kPa s/mm3), force estimate (N)"
            .to_string(),
    ];
    comments.extend(c.rec.gaps.iter().map(|g| {
        format!(
            "gap: frames seq {}..={} missing ({} frames) before capture line {}",
            g.first,
            g.last,
            g.frames(),
            g.line
        )
    }));
    comments.extend(
        c.rec
            .corrupted
            .iter()
            .map(|b| format!("corrupted capture line {}: {}", b.line, b.reason)),
    );
    comments.extend(
        c.rec
            .rejected
            .iter()
            .map(|b| format!("rejected frame at capture line {}: {}", b.line, b.reason)),
    );
    comments.extend(c.rec.restarts.iter().map(|r| {
        format!(
            "restart: board rebooted before capture line {} (seq {}), time offset {} us",
            r.line, r.seq, r.time_offset_us
        )
    }));
    comments.extend(event_comments);
    c.rec.log.comments = comments;
    Ok(c.rec)
}

fn clip(s: &str) -> String {
    const MAX: usize = 60;
    match s.char_indices().nth(MAX) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
}

impl Converter {
    fn frame(&mut self, f: &Frame, line: usize) {
        let reject =
            |rec: &mut Recording, reason: String| rec.rejected.push(BadLine { line, reason });
        if let Some((seq, t_us)) = self.last {
            let restarted = f.seq <= seq && (self.boot_seen || f.seq == 0);
            if restarted {
                // Continue time one median period after the last frame written.
                let period = self
                    .periods
                    .get(self.periods.len() / 2)
                    .copied()
                    .unwrap_or(40_000);
                let end = self.last_time_us.unwrap_or(0) + period;
                self.offset_us = end.saturating_sub(f.t_us);
                self.rec.restarts.push(Restart {
                    line,
                    seq: f.seq,
                    time_offset_us: self.offset_us,
                });
            } else if f.seq <= seq {
                return reject(
                    &mut self.rec,
                    format!(
                        "seq {} does not follow seq {seq} (duplicate or out of order)",
                        f.seq
                    ),
                );
            } else if f.t_us <= t_us {
                return reject(
                    &mut self.rec,
                    format!("seq {}: time {} us is not after {t_us} us", f.seq, f.t_us),
                );
            } else {
                if f.seq > seq + 1 {
                    self.rec.gaps.push(Gap {
                        line,
                        first: seq + 1,
                        last: f.seq - 1,
                    });
                }
                self.periods.push((f.t_us - t_us) / u64::from(f.seq - seq));
            }
        }
        self.boot_seen = false;
        if let Some(i) = f
            .chambers
            .iter()
            .position(|c| !(c.v.is_finite() && c.p.is_finite() && c.vdot.is_finite()))
        {
            self.last = Some((f.seq, f.t_us));
            return reject(
                &mut self.rec,
                format!(
                    "seq {}: chamber {i} has a non-finite volume, flow or pressure",
                    f.seq
                ),
            );
        }
        self.last = Some((f.seq, f.t_us));
        self.rec.first_seq.get_or_insert(f.seq);
        let t = f.t_us + self.offset_us;
        self.last_time_us = Some(t);
        let time_s = t as f64 / 1e6;
        for (ch, c) in f.chambers.iter().enumerate() {
            let mut s = Sample::new(time_s, ch as u8, decimal(c.v), decimal(c.p));
            s.flow_mm3_s = Some(decimal(c.vdot));
            self.rec.log.samples.push(s);
            self.rec.log.extra.push(vec![
                f.seq.to_string(),
                f.flags.0.to_string(),
                c.p_hat.to_string(),
                c.residual.to_string(),
                c.k.to_string(),
                c.c.to_string(),
                f.force_n.to_string(),
            ]);
        }
        self.rec.frames += 1;
    }
}

/// Converts the capture file (`-` = stdin).
pub fn convert_file(path: &Path) -> Result<Recording, RecordError> {
    let name = path.display().to_string();
    if path.as_os_str() == "-" {
        return convert(std::io::stdin().lock(), "<stdin>");
    }
    let f = std::fs::File::open(path).map_err(|e| RecordError::Io {
        file: name.clone(),
        source: e,
    })?;
    convert(std::io::BufReader::new(f), &name)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_colour_and_location() {
        let t = strip_ansi("\x1b[2m0.280012\x1b[0m \x1b[32mINFO\x1b[0m $F 1 2");
        assert_eq!(t, "0.280012 INFO $F 1 2");
        assert_eq!(
            telemetry_part("0.1 $E 5 cleared (src/bin/vfp-fw.rs:56)"),
            Some("$E 5 cleared")
        );
        assert_eq!(
            telemetry_part("└─ vfp_fw::task @ src/bin/vfp-fw.rs:56"),
            None
        );
    }

    fn frame_line(seq: u32, t_us: u64) -> String {
        let f = Frame {
            seq,
            t_us,
            ..Frame::default()
        };
        let mut s = String::new();
        f.encode(&mut s).unwrap();
        s
    }

    #[test]
    fn reboot_continues_time_and_duplicates_are_reported() {
        let lines = [
            frame_line(0, 40_000),
            frame_line(1, 80_000),
            frame_line(1, 80_000),
            "$E 0 boot 0".to_string(),
            frame_line(0, 40_000),
            frame_line(1, 80_000),
        ];
        let rec = convert(lines.join("\n").as_bytes(), "mem").unwrap();
        assert_eq!(rec.frames, 4);
        assert_eq!(rec.rejected.len(), 1);
        assert_eq!(rec.rejected[0].line, 3);
        assert_eq!(rec.restarts.len(), 1);
        assert_eq!(rec.restarts[0].line, 5);
        // After the reboot time goes on one period (40 ms) after the last frame written.
        let times: Vec<f64> = rec
            .log
            .samples
            .iter()
            .step_by(3)
            .map(|s| s.time_s)
            .collect();
        assert_eq!(times, vec![0.04, 0.08, 0.12, 0.16]);
        assert!(rec.gaps.is_empty());
        let e = convert("INFO nothing here\n".as_bytes(), "mem").unwrap_err();
        assert!(e.to_string().contains("no telemetry frame"), "{e}");
    }

    #[test]
    fn decimal_keeps_printed_digits() {
        assert_eq!(decimal(0.1f32), 0.1f64);
        assert_eq!(decimal(-123.456f32), -123.456f64);
        assert_eq!(decimal(1.5e-7f32), 1.5e-7f64);
    }
}
