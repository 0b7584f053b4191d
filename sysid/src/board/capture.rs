//! One captured line at a time: what a line of `probe-rs run` output (or a raw `$F`/`$E` line)
//! holds, for readers that act on each line as it arrives (`vfp monitor`).
//!
//! The rules are those of [`crate::board::record::convert`], which reads a whole capture: ANSI colour
//! codes are removed, the telemetry part starts at its `$F`/`$E` marker and ends before a
//! location suffix (`… (src/x.rs:12)`, `… @ src/x.rs:12`, `… └─ …`), and the firmware's own
//! parser ([`firmware::telemetry::parse_line`]) decodes it. A line with a marker that does not
//! decode (or is not UTF-8) is corrupted; a line without a marker is some other output
//! (defmt logs, the `└─` location lines, probe-rs' own messages). The test below holds the two
//! readers to the same counts.

use std::borrow::Cow;

use firmware::telemetry::{self, Event, Frame, Line};

/// What one captured line holds.
#[derive(Debug, Clone, PartialEq)]
pub enum CaptureLine<'a> {
    /// A telemetry frame.
    Frame(Frame),
    /// An event, with its telemetry text (`$E …`).
    Event(Event, Cow<'a, str>),
    /// A line with a telemetry marker that did not decode: why, and the start of the text.
    Corrupted(String),
    /// Anything else, without its colour codes and line end.
    Other(Cow<'a, str>),
}

impl CaptureLine<'_> {
    /// The same item, owning its text.
    pub fn into_owned(self) -> CaptureLine<'static> {
        match self {
            CaptureLine::Frame(f) => CaptureLine::Frame(f),
            CaptureLine::Event(e, t) => CaptureLine::Event(e, Cow::Owned(t.into_owned())),
            CaptureLine::Corrupted(why) => CaptureLine::Corrupted(why),
            CaptureLine::Other(t) => CaptureLine::Other(Cow::Owned(t.into_owned())),
        }
    }
}

/// Classifies one captured line (with or without its line end).
pub fn classify(raw: &[u8]) -> CaptureLine<'_> {
    let Ok(text) = std::str::from_utf8(raw) else {
        let lossy = String::from_utf8_lossy(raw);
        return if lossy.contains('$') {
            CaptureLine::Corrupted("not valid UTF-8".into())
        } else {
            CaptureLine::Other(Cow::Owned(strip_ansi(lossy.trim_end()).into_owned()))
        };
    };
    let text = strip_ansi(text.trim_end_matches(['\n', '\r']));
    let Some(part) = telemetry_part(&text) else {
        return CaptureLine::Other(text);
    };
    match telemetry::parse_line(part) {
        None => CaptureLine::Other(Cow::Owned(text.to_string())),
        Some(Err(e)) => CaptureLine::Corrupted(format!("{e}: {}", clip(part))),
        Some(Ok(Line::Frame(f))) => CaptureLine::Frame(f),
        Some(Ok(Line::Event(e))) => CaptureLine::Event(e, Cow::Owned(part.to_string())),
    }
}

/// Removes ANSI escape sequences (`ESC [ … final`), which `probe-rs` adds on a terminal.
fn strip_ansi(s: &str) -> Cow<'_, str> {
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

/// The telemetry part of a printed line: from the `$` marker, without a location suffix.
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

fn clip(s: &str) -> String {
    const MAX: usize = 60;
    match s.char_indices().nth(MAX) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s.to_string(),
    }
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
    use crate::board::record::convert;

    fn frame_line(seq: u32) -> String {
        let f = Frame {
            seq,
            t_us: 40_000 * u64::from(seq + 1),
            ..Frame::default()
        };
        let mut s = String::new();
        f.encode(&mut s).unwrap();
        s
    }

    /// A capture with every kind of line, as probe-rs prints them.
    fn mixed_capture() -> Vec<Vec<u8>> {
        let mut lines: Vec<Vec<u8>> = vec![b"     Running `probe-rs run --chip X vfp-fw`".to_vec()];
        for seq in 0..6 {
            let l = frame_line(seq);
            lines.push(format!("\x1b[2m0.{seq}\x1b[0m \x1b[32mINFO\x1b[0m {l}").into_bytes());
            lines.push("└─ vfp_fw::__sampler_task @ firmware/src/bin/vfp-fw.rs:56".into());
        }
        lines.push(b"0.5 INFO $E 5 cleared (src/bin/vfp-fw.rs:56)".to_vec());
        lines.push(b"0.6 INFO $F 9 1 x".to_vec());
        lines.push(b"0.7 WARN $F \xff\xfe".to_vec());
        lines.push(b"0.8 INFO pressure zero taken".to_vec());
        lines
    }

    #[test]
    fn counts_agree_with_the_whole_capture_reader() {
        let lines = mixed_capture();
        let (mut frames, mut events, mut corrupted, mut other) = (0, 0, 0, 0);
        for l in &lines {
            match classify(l) {
                CaptureLine::Frame(_) => frames += 1,
                CaptureLine::Event(_, text) => {
                    assert_eq!(text, "$E 5 cleared");
                    events += 1
                }
                CaptureLine::Corrupted(_) => corrupted += 1,
                CaptureLine::Other(text) => {
                    assert!(!text.contains('\x1b'), "{text:?}");
                    other += 1
                }
            }
        }
        let capture = lines.join(&b'\n');
        let rec = convert(capture.as_slice(), "mem").unwrap();
        assert_eq!((frames, events, corrupted, other), (6, 1, 2, 8));
        assert_eq!(
            (rec.frames, rec.events, rec.corrupted.len(), rec.other_lines),
            (frames, events, corrupted, other)
        );
    }

    #[test]
    fn frame_reads_back_through_colour_and_location() {
        let l = format!("\x1b[2m0.2\x1b[0m {} (src/x.rs:1)\r\n", frame_line(3));
        match classify(l.as_bytes()) {
            CaptureLine::Frame(f) => assert_eq!((f.seq, f.t_us), (3, 160_000)),
            other => panic!("{other:?}"),
        }
    }
}
