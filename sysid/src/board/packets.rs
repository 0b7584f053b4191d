//! The board's binary telemetry stream (`telemetry on` on its serial port), read from any byte
//! source into the same items as a text capture ([`CaptureLine`]), so `vfp record` and
//! `vfp monitor` treat both paths alike. The packet format is `firmware::wire`'s (and
//! `docs/serial-telemetry.md`); no serial-port code here: the bytes come from any `Read` or
//! slice.
//!
//! Splitting: a zero byte ends a packet. Between packets the port carries the command replies,
//! plain text lines; a line made only of printable ASCII is handed on at its `\n` as a captured
//! line ([`classify`]: usually [`CaptureLine::Other`]). A packet never looks like such a line
//! (its second byte is the format version, a control character), so a packet is never cut at a
//! `\n` inside it. What lies between two zeros and is neither a valid packet nor text is
//! [`CaptureLine::Corrupted`], with the reason (CRC, stuffing, version…). Memory is bounded:
//! a run of more than [`MAX_CHUNK`] bytes without a delimiter is handed on as it is.
//!
//! Losses: a lost or changed byte damages only the packet it is in (a lost delimiter merges
//! a packet with the text beside it, which a zero or `\n` ends); the CRC refuses the damaged
//! packet, and the frames' `seq` shows the gap. The property test below checks this on random
//! streams with bytes dropped and changed.

use std::borrow::Cow;
use std::io::Read;

use firmware::wire::{self, Record, MAX_RAW};

use crate::board::capture::{classify, CaptureLine};

/// Longest run of bytes kept without a delimiter or line end.
pub const MAX_CHUNK: usize = 1024;

/// Splits a byte stream into packets and text lines.
pub struct PacketReader {
    chunk: Vec<u8>,
    scratch: [u8; MAX_RAW],
}

impl Default for PacketReader {
    fn default() -> Self {
        Self::new()
    }
}

fn is_text(bytes: &[u8]) -> bool {
    bytes
        .iter()
        .all(|&b| matches!(b, 0x20..=0x7E | b'\t' | b'\r'))
}

/// The text after any blank lines, when that is what a `\n` ends as a line.
fn line_body(chunk: &[u8]) -> Option<&[u8]> {
    let body = &chunk[chunk.iter().take_while(|&&c| c == b'\n').count()..];
    (!body.is_empty() && is_text(body)).then_some(body)
}

impl PacketReader {
    /// Nothing read yet.
    pub fn new() -> Self {
        Self {
            chunk: Vec::with_capacity(256),
            scratch: [0; MAX_RAW],
        }
    }

    /// Takes one byte; the item it completes, if any.
    pub fn push(&mut self, b: u8) -> Option<CaptureLine<'static>> {
        if b == 0 {
            return self.end_chunk();
        }
        // A line end after text. Blank lines before it (`\n`s kept while the chunk could still
        // have been a packet's start) are dropped.
        if b == b'\n' {
            if let Some(line) = line_body(&self.chunk).map(|t| classify(t).into_owned()) {
                self.chunk.clear();
                return Some(line);
            }
        }
        self.chunk.push(b);
        if self.chunk.len() >= MAX_CHUNK {
            self.end_chunk()
        } else {
            None
        }
    }

    /// Takes a slice of bytes, handing each completed item to `each`.
    pub fn feed(&mut self, bytes: &[u8], mut each: impl FnMut(CaptureLine<'static>)) {
        for &b in bytes {
            if let Some(item) = self.push(b) {
                each(item);
            }
        }
    }

    /// End of input: whatever is pending (a packet without its closing zero, a line without its
    /// `\n`), as an item.
    pub fn finish(&mut self) -> Option<CaptureLine<'static>> {
        self.end_chunk()
    }

    fn end_chunk(&mut self) -> Option<CaptureLine<'static>> {
        if self.chunk.is_empty() {
            return None;
        }
        let item = match wire::decode(&self.chunk, &mut self.scratch) {
            Ok(Record::Frame(f)) => CaptureLine::Frame(f),
            Ok(Record::Event(e, text)) => CaptureLine::Event(e, Cow::Owned(text.to_string())),
            Err(_) if is_text(&self.chunk) => classify(&self.chunk).into_owned(),
            Err(e) => CaptureLine::Corrupted(format!("packet of {} bytes: {e}", self.chunk.len())),
        };
        self.chunk.clear();
        Some(item)
    }
}

/// Reads `input` to its end, handing every item to `each` (in order, the pending one at the
/// end); stops at the first error of `input` or `each`.
pub fn read_all<E: From<std::io::Error>>(
    mut input: impl Read,
    mut each: impl FnMut(CaptureLine<'static>) -> Result<(), E>,
) -> Result<(), E> {
    let mut reader = PacketReader::new();
    let mut buf = [0u8; 4096];
    loop {
        let n = match input.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(e.into()),
        };
        for &b in &buf[..n] {
            if let Some(item) = reader.push(b) {
                each(item)?;
            }
        }
    }
    match reader.finish() {
        Some(item) => each(item),
        None => Ok(()),
    }
}

#[cfg(test)]
#[path = "packets_tests.rs"]
mod tests;
