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
//! [`convert`] converts a whole capture in memory; [`Recorder`] does the same conversion as a
//! stream (what `vfp record` uses): rows are written as their frames arrive, comments where their
//! line was read, the totals (`# sample_rate_hz=…`, `# frames=…`, …) at the end, and nothing
//! grows with the capture.
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

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::io::{BufRead, Write};
use std::path::Path;

use firmware::telemetry::{EventKind, Frame};

use crate::board::capture::{classify, CaptureLine};
use crate::board::sequence::SeqTracker;

use crate::log::{Log, RowLayout, Sample};

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
    /// Totals. [`convert`] keeps every gap, bad line and restart in the lists above; the
    /// streaming [`Recorder`] keeps the first few (the log has them all as comments) and counts
    /// the rest here, so its memory does not grow with the capture.
    pub counts: Counts,
}

/// Totals of a capture.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct Counts {
    /// Log rows written (one per chamber per frame).
    pub rows: usize,
    /// Sequence gaps.
    pub gaps: usize,
    /// Frames missing in all gaps.
    pub missing_frames: u64,
    /// Lines with a telemetry marker that did not decode.
    pub corrupted: usize,
    /// Frames that decoded but could not become log rows.
    pub rejected: usize,
    /// Reboots.
    pub restarts: usize,
}

impl Recording {
    /// Frames missing in all gaps.
    pub fn missing_frames(&self) -> u64 {
        self.counts.missing_frames
    }

    /// Whether every frame between the first and the last arrived and every line was usable.
    pub fn is_complete(&self) -> bool {
        let n = &self.counts;
        n.gaps == 0 && n.corrupted == 0 && n.rejected == 0
    }

    /// A human summary: counts, then the first gaps and bad lines by line number.
    pub fn summary(&self, source: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{source}: {} lines, {} frames ({} log rows), {} events, {} other lines",
            self.lines, self.frames, self.counts.rows, self.events, self.other_lines
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
            self.counts.gaps
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
        more(&mut s, self.counts.gaps);
        for (what, list, n) in [
            ("corrupted lines", &self.corrupted, self.counts.corrupted),
            ("rejected frames", &self.rejected, self.counts.rejected),
        ] {
            let _ = writeln!(s, "  {what}: {n}");
            for b in list.iter().take(LIST_LIMIT) {
                let _ = writeln!(s, "    line {}: {}", b.line, b.reason);
            }
            more(&mut s, n);
        }
        for r in self.restarts.iter().take(LIST_LIMIT) {
            let _ = writeln!(
                s,
                "  board restarted before line {} (seq {}); time continues (+{:.3} s)",
                r.line,
                r.seq,
                r.time_offset_us as f64 * 1e-6
            );
        }
        more(&mut s, self.counts.restarts);
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

/// The shortest decimal of an `f32`, as the device printed it, read as `f64`.
fn decimal(x: f32) -> f64 {
    // Display prints the shortest round-trip digits; parsing them as f64 keeps those digits.
    format!("{x}").parse().unwrap_or(f64::NAN)
}

/// A comment the conversion of one line produced.
enum Note {
    /// An event line (`# event at …`).
    Event(String),
    /// A gap, a bad line or a restart (the same text as in the end-of-capture lists).
    Problem(String),
}

/// State of the conversion between lines. Each [`line`](Converter::line) leaves its output (log
/// rows and comments) in `rows` and `notes` for the caller to take.
struct Converter {
    rec: Recording,
    /// Keep every gap, bad line and restart in the lists (else the first [`LIST_LIMIT`]).
    keep_all: bool,
    seq: SeqTracker,
    offset_us: u64,
    /// Largest time written so far (with offset), µs.
    last_time_us: Option<u64>,
    /// Frame periods seen, µs → how often (a handful of distinct values on a healthy link).
    periods: BTreeMap<u64, u64>,
    rows: Vec<(Sample, Vec<String>)>,
    notes: Vec<Note>,
    /// Whole-capture mode ([`convert`]): rows go straight into the log, event notes into
    /// `event_comments`, after every item.
    collect: bool,
    event_comments: Vec<String>,
}

impl Converter {
    fn new(keep_all: bool) -> Self {
        Converter {
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
                counts: Counts::default(),
            },
            keep_all,
            seq: SeqTracker::new(),
            offset_us: 0,
            last_time_us: None,
            periods: BTreeMap::new(),
            rows: Vec::new(),
            notes: Vec::new(),
            collect: false,
            event_comments: Vec::new(),
        }
    }

    /// Converts one capture line (with or without its line terminator), classified by
    /// [`capture::classify`](crate::board::capture::classify), the one reading of a captured line.
    fn line(&mut self, bytes: &[u8]) {
        self.item(classify(bytes));
    }

    /// Converts one item of the capture: a classified text line, or a packet of the binary
    /// stream ([`crate::board::packets`]); each counts as one capture line.
    fn item(&mut self, item: CaptureLine<'_>) {
        self.rec.lines += 1;
        let no = self.rec.lines;
        match item {
            CaptureLine::Other(_) => self.rec.other_lines += 1,
            CaptureLine::Corrupted(why) => self.corrupted(no, why),
            CaptureLine::Event(ev, part) => {
                self.rec.events += 1;
                if matches!(ev.kind, EventKind::Boot { .. }) {
                    self.seq.boot();
                }
                self.notes.push(Note::Event(format!(
                    "event at {:.6} s (capture line {no}): {part}",
                    (ev.t_us + self.offset_us) as f64 * 1e-6
                )));
            }
            CaptureLine::Frame(f) => self.frame(&f, no),
        }
        if self.collect {
            for (s, extra) in self.rows.drain(..) {
                self.rec.log.samples.push(s);
                self.rec.log.extra.push(extra);
            }
            self.event_comments
                .extend(self.notes.drain(..).filter_map(|n| match n {
                    Note::Event(e) => Some(e),
                    Note::Problem(_) => None,
                }));
        }
    }

    /// Median frame period so far, µs.
    fn median_period(&self) -> Option<u64> {
        let n: u64 = self.periods.values().sum();
        let mut seen = 0;
        self.periods.iter().find_map(|(&p, &k)| {
            seen += k;
            (seen > n / 2).then_some(p)
        })
    }

    /// The frame rate from the median period, Hz (0 when unknown), rounded to 1 mHz.
    fn rate_hz(&self) -> f64 {
        self.median_period()
            .map_or(0.0, |p| (1e6 / p as f64 * 1000.0).round() / 1000.0)
    }

    fn corrupted(&mut self, line: usize, reason: String) {
        let b = BadLine { line, reason };
        self.notes.push(Note::Problem(corrupted_comment(&b)));
        self.rec.counts.corrupted += 1;
        if self.keep(self.rec.corrupted.len()) {
            self.rec.corrupted.push(b);
        }
    }

    fn rejected(&mut self, line: usize, reason: String) {
        let b = BadLine { line, reason };
        self.notes.push(Note::Problem(rejected_comment(&b)));
        self.rec.counts.rejected += 1;
        if self.keep(self.rec.rejected.len()) {
            self.rec.rejected.push(b);
        }
    }

    fn gap(&mut self, g: Gap) {
        self.notes.push(Note::Problem(gap_comment(&g)));
        self.rec.counts.gaps += 1;
        self.rec.counts.missing_frames += g.frames();
        if self.keep(self.rec.gaps.len()) {
            self.rec.gaps.push(g);
        }
    }

    fn restart(&mut self, r: Restart) {
        self.notes.push(Note::Problem(restart_comment(&r)));
        self.rec.counts.restarts += 1;
        if self.keep(self.rec.restarts.len()) {
            self.rec.restarts.push(r);
        }
    }

    fn keep(&self, len: usize) -> bool {
        self.keep_all || len < LIST_LIMIT
    }

    /// Places a frame in the sequence ([`SeqTracker`]: gaps, reboots, order) and writes its
    /// rows unless it was rejected.
    fn frame(&mut self, f: &Frame, line: usize) {
        let placed = match self.seq.frame(f) {
            Ok(p) => p,
            Err(why) => return self.rejected(line, why),
        };
        if placed.restarted {
            // Continue time one median period after the last frame written.
            let period = self.median_period().unwrap_or(40_000);
            let end = self.last_time_us.unwrap_or(0) + period;
            self.offset_us = end.saturating_sub(f.t_us);
            self.restart(Restart {
                line,
                seq: f.seq,
                time_offset_us: self.offset_us,
            });
        }
        if let Some((first, last)) = placed.gap {
            self.gap(Gap { line, first, last });
        }
        if let Some(p) = placed.period_us {
            *self.periods.entry(p).or_default() += 1;
        }
        if let Some(why) = placed.unusable {
            return self.rejected(line, why);
        }
        self.rec.first_seq.get_or_insert(f.seq);
        let t = f.t_us + self.offset_us;
        self.last_time_us = Some(t);
        let time_s = t as f64 / 1e6;
        for (ch, c) in f.chambers.iter().enumerate() {
            let mut s = Sample::new(time_s, ch as u8, decimal(c.v), decimal(c.p));
            s.flow_mm3_s = Some(decimal(c.vdot));
            let extra = vec![
                f.seq.to_string(),
                f.flags.0.to_string(),
                c.p_hat.to_string(),
                c.residual.to_string(),
                c.k.to_string(),
                c.c.to_string(),
                f.force_n.to_string(),
            ];
            self.rows.push((s, extra));
        }
        self.rec.counts.rows += f.chambers.len();
        self.rec.frames += 1;
    }

    /// The `# key=value` totals every recorded log carries.
    fn totals_comments(&self) -> Vec<String> {
        let n = &self.rec.counts;
        vec![
            format!("sample_rate_hz={}", self.rate_hz()),
            format!("frames={}", self.rec.frames),
            format!("missing_frames={}", n.missing_frames),
            format!("corrupted_lines={}", n.corrupted),
            format!("rejected_frames={}", n.rejected),
        ]
    }
}

const COLUMNS_COMMENT: &str = "columns seq..force_est_n are the device's own: frame sequence \
     number, flag bits, model prediction (kPa), residual (kPa), stiffness (kPa/mm3), damping \
     (kPa s/mm3), force estimate (N)";

fn gap_comment(g: &Gap) -> String {
    format!(
        "gap: frames seq {}..={} missing ({} frames) before capture line {}",
        g.first,
        g.last,
        g.frames(),
        g.line
    )
}

fn corrupted_comment(b: &BadLine) -> String {
    format!("corrupted capture line {}: {}", b.line, b.reason)
}

fn rejected_comment(b: &BadLine) -> String {
    format!("rejected frame at capture line {}: {}", b.line, b.reason)
}

fn restart_comment(r: &Restart) -> String {
    format!(
        "restart: board rebooted before capture line {} (seq {}), time offset {} us",
        r.line, r.seq, r.time_offset_us
    )
}

/// Converts a capture in memory. Never fails on bad lines (they are reported in the
/// [`Recording`]); fails only when the input cannot be read or holds no frame at all.
/// [`Recorder`] does the same conversion as a stream, straight into a file.
pub fn convert(mut reader: impl BufRead, source: &str) -> Result<Recording, RecordError> {
    convert_with(source, |c| {
        let mut buf = Vec::new();
        loop {
            buf.clear();
            if reader.read_until(b'\n', &mut buf)? == 0 {
                return Ok(());
            }
            c.line(&buf);
        }
    })
}

/// Converts a capture of the binary serial stream ([`crate::board::packets`]) in memory, like
/// [`convert`] does a text capture.
pub fn convert_packets(input: impl std::io::Read, source: &str) -> Result<Recording, RecordError> {
    convert_with(source, |c| {
        crate::board::packets::read_all::<std::io::Error>(input, |item| {
            c.item(item);
            Ok(())
        })
    })
}

/// The whole-capture conversion around `feed`, which hands the converter every item.
fn convert_with(
    source: &str,
    feed: impl FnOnce(&mut Converter) -> std::io::Result<()>,
) -> Result<Recording, RecordError> {
    let mut c = Converter::new(true);
    c.collect = true;
    feed(&mut c).map_err(|e| RecordError::Io {
        file: source.to_string(),
        source: e,
    })?;
    let event_comments = std::mem::take(&mut c.event_comments);
    if c.rec.frames == 0 {
        return Err(RecordError::NoFrames {
            file: source.to_string(),
            lines: c.rec.lines,
        });
    }
    let mut comments = vec![format!("source=vfp record {source}")];
    comments.extend(c.totals_comments());
    comments.push(COLUMNS_COMMENT.to_string());
    let r = &c.rec;
    comments.extend(r.gaps.iter().map(gap_comment));
    comments.extend(r.corrupted.iter().map(corrupted_comment));
    comments.extend(r.rejected.iter().map(rejected_comment));
    comments.extend(r.restarts.iter().map(restart_comment));
    comments.extend(event_comments);
    c.rec.log.comments = comments;
    Ok(c.rec)
}

/// The conversion as a stream: each capture line given to [`line`](Recorder::line) is converted
/// and its rows written at once, events, gaps and bad lines as `#` comments where they happened;
/// [`finish`](Recorder::finish) appends the totals. The file is a valid log after every
/// [`flush`](Recorder::flush) (whole rows only), so whatever stops the capture, what was
/// received is kept. Memory stays constant: rows are not held, and only the first few problems
/// are listed in the returned [`Recording`] (its `log` holds no rows).
pub struct Recorder<W: Write> {
    conv: Converter,
    out: std::io::BufWriter<W>,
    row: Vec<String>,
}

/// The known columns every recorded log carries.
const RECORDED: RowLayout = RowLayout {
    flow: true,
    force: false,
};

impl<W: Write> Recorder<W> {
    /// Starts a log on `out`: the leading comments and the header. `source` names the capture.
    pub fn new(out: W, source: &str) -> std::io::Result<Self> {
        let conv = Converter::new(false);
        let mut out = std::io::BufWriter::new(out);
        writeln!(out, "# source=vfp record {source}\n# {COLUMNS_COMMENT}")?;
        // Every recorded field is a number or a known name: nothing to quote.
        writeln!(
            out,
            "{}",
            RECORDED.header(&conv.rec.log.extra_columns).join(",")
        )?;
        Ok(Recorder {
            conv,
            out,
            row: Vec::new(),
        })
    }

    /// Converts one capture line and writes what it gives (buffered; see [`flush`](Self::flush)).
    pub fn line(&mut self, line: &[u8]) -> std::io::Result<()> {
        self.item(classify(line))
    }

    /// Converts one item (a classified text line, or a packet of the binary stream read by
    /// [`crate::board::packets::PacketReader`]) and writes what it gives, like [`line`](Self::line).
    pub fn item(&mut self, item: CaptureLine<'_>) -> std::io::Result<()> {
        self.conv.item(item);
        for (s, extra) in self.conv.rows.drain(..) {
            RECORDED.row(&s, &extra, &mut self.row);
            writeln!(self.out, "{}", self.row.join(","))?;
        }
        for n in self.conv.notes.drain(..) {
            let (Note::Event(n) | Note::Problem(n)) = n;
            writeln!(self.out, "# {n}")?;
        }
        Ok(())
    }

    /// Writes everything converted so far to the underlying writer (whole lines only).
    pub fn flush(&mut self) -> std::io::Result<()> {
        self.out.flush()
    }

    /// Frames written so far.
    pub fn frames(&self) -> usize {
        self.conv.rec.frames
    }

    /// Ends the log: the totals as `# key=value` comments, with `# stopped=<why>` (e.g. "end of
    /// input", "SIGINT"), then a flush; gives back the summary and the writer. The summary comes
    /// back even when no frame arrived (`frames == 0`: [`RecordError::NoFrames`] is the
    /// caller's to raise).
    pub fn finish(mut self, stopped: &str) -> std::io::Result<(Recording, W)> {
        let mut tail = self.conv.totals_comments();
        tail.push(format!("stopped={stopped}"));
        for c in &tail {
            writeln!(self.out, "# {c}")?;
        }
        let out = self.out.into_inner().map_err(|e| e.into_error())?;
        let mut rec = self.conv.rec;
        rec.log.comments = tail;
        Ok((rec, out))
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
