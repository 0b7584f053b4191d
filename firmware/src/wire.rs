//! Binary telemetry over the command UART: the frames and events of [`crate::telemetry`], as
//! checksummed COBS packets, for a host without a debug probe.
//!
//! # Packet
//! ```text
//! 0x00 | COBS( version | kind | payload | crc32 ) | 0x00
//! ```
//! - `version` (u8) is [`VERSION`]; a reader refuses any other.
//! - `kind` (u8) is [`KIND_FRAME`] (`b'F'`) or [`KIND_EVENT`] (`b'E'`).
//! - A frame's payload is [`FRAME_PAYLOAD`] = 108 bytes, little-endian: `seq` u32, `t_us` u64,
//!   `flags` u32, `force_n` f32, then per chamber (3×) `v vdot p p_hat residual k c` as f32, then
//!   `drops` u32: every field of [`Frame`], bit for bit (NaN payloads included).
//! - An event's payload is its text line exactly as [`Event::encode`] writes it (`$E …`, at
//!   most [`MAX_EVENT_TEXT`] bytes): events are rare and their text is already their one
//!   definition.
//! - `crc32` is the CRC-32/ISO-HDLC (zlib's) of `version | kind | payload`, little-endian.
//!
//! COBS (consistent overhead byte stuffing, the `cobs` crate) removes every zero byte from the
//! packet at the cost of one byte per 254, so `0x00` only ever delimits packets: a reader that
//! lost bytes finds the next packet at the next zero and loses at most the packets the damage
//! touched; the CRC refuses a damaged packet. A frame packet is 117 bytes on the wire (2.9 kB/s
//! at 25 Hz, a quarter of 115,200 baud).
//!
//! The command replies share the line: they are ASCII text (no zero byte) written between two
//! packets, never inside one. A packet's second byte is its version, a control character, so a
//! reader can tell a packet from a reply line before it ends.
//!
//! # Losing nothing silently
//! The board never waits for the host: a packet goes into a bounded queue ([`SerialTelemetry`],
//! [`QUEUE`] packets) that the command task drains onto the UART; when the queue is full the
//! packet is dropped and counted ([`SerialOut`]), and the next frame's `drops` carries the count
//! of packets this transport dropped since boot. A frame lost anywhere shows as a gap in `seq`.

use core::sync::atomic::{AtomicBool, Ordering};

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;

use crate::reset::CRC32;
use crate::telemetry::{ChamberFrame, Event, Flags, Frame, TelemetryError};

/// Format version carried by every packet.
pub const VERSION: u8 = 1;
/// Kind byte of a frame packet.
pub const KIND_FRAME: u8 = b'F';
/// Kind byte of an event packet.
pub const KIND_EVENT: u8 = b'E';
/// Bytes of a frame's payload.
pub const FRAME_PAYLOAD: usize = 4 + 8 + 4 + 4 + 3 * 7 * 4 + 4;
/// Longest event text carried (the longest event line is shorter; see the tests).
pub const MAX_EVENT_TEXT: usize = 144;
/// Longest packet before stuffing: header, payload, CRC.
pub const MAX_RAW: usize = 2 + MAX_EVENT_TEXT + 4;
/// Longest packet on the wire: stuffed, with both delimiters.
pub const MAX_PACKET: usize = cobs::max_encoding_length(MAX_RAW) + 2;
/// Packets the queue holds (about 0.16 s of frames).
pub const QUEUE: usize = 4;

/// One packet as it goes on the wire (delimiters included).
pub type Packet = heapless::Vec<u8, MAX_PACKET>;

/// Why bytes between two delimiters are not a packet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum WireError {
    /// Longer than any packet.
    TooLong,
    /// Not valid COBS (a code byte points past the end).
    Stuffing,
    /// Shorter than a header and CRC.
    TooShort,
    /// The CRC does not match: bytes were lost or changed.
    Crc,
    /// A format version this reader does not know.
    Version(u8),
    /// An unknown kind byte.
    Kind(u8),
    /// A frame payload of the wrong length.
    Length(u16),
    /// An event payload that is not a valid event line.
    Event(TelemetryError),
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooLong => write!(f, "longer than {MAX_PACKET} bytes"),
            Self::Stuffing => f.write_str("invalid COBS stuffing"),
            Self::TooShort => f.write_str("shorter than a header and CRC"),
            Self::Crc => f.write_str("CRC mismatch"),
            Self::Version(v) => write!(f, "format version {v} (this reader knows {VERSION})"),
            Self::Kind(k) => write!(f, "unknown packet kind {k:#04x}"),
            Self::Length(n) => write!(f, "frame payload of {n} bytes ({FRAME_PAYLOAD} expected)"),
            Self::Event(e) => write!(f, "event: {e}"),
        }
    }
}

/// A decoded packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Record<'a> {
    /// A frame.
    Frame(Frame),
    /// An event and its text line.
    Event(Event, &'a str),
}

/// Stuff `raw[..n]` (header and payload) with its CRC into `out`, delimiters included.
fn finish(raw: &mut [u8; MAX_RAW], n: usize, out: &mut Packet) {
    let crc = CRC32.checksum(&raw[..n]);
    raw[n..n + 4].copy_from_slice(&crc.to_le_bytes());
    out.clear();
    // MAX_PACKET bytes of room: enough for any MAX_RAW input (the encoder cannot fail).
    let _ = out.resize(MAX_PACKET, 0);
    let len = cobs::encode_including_sentinels(&raw[..n + 4], out);
    out.truncate(len);
}

/// The frame as a packet in `out`.
pub fn encode_frame(f: &Frame, out: &mut Packet) {
    let mut raw = [0u8; MAX_RAW];
    raw[0] = VERSION;
    raw[1] = KIND_FRAME;
    let mut at = 2;
    let mut put = |b: &[u8]| {
        raw[at..at + b.len()].copy_from_slice(b);
        at += b.len();
    };
    put(&f.seq.to_le_bytes());
    put(&f.t_us.to_le_bytes());
    put(&f.flags.0.to_le_bytes());
    put(&f.force_n.to_le_bytes());
    for c in &f.chambers {
        for x in [c.v, c.vdot, c.p, c.p_hat, c.residual, c.k, c.c] {
            put(&x.to_le_bytes());
        }
    }
    put(&f.drops.to_le_bytes());
    finish(&mut raw, 2 + FRAME_PAYLOAD, out);
}

/// The event as a packet in `out`; `false` (and `out` empty) if its line does not fit
/// [`MAX_EVENT_TEXT`] (no event of this firmware is that long).
pub fn encode_event(e: &Event, out: &mut Packet) -> bool {
    let mut text = heapless::String::<MAX_EVENT_TEXT>::new();
    out.clear();
    if e.encode(&mut text).is_err() {
        return false;
    }
    let mut raw = [0u8; MAX_RAW];
    raw[0] = VERSION;
    raw[1] = KIND_EVENT;
    raw[2..2 + text.len()].copy_from_slice(text.as_bytes());
    finish(&mut raw, 2 + text.len(), out);
    true
}

/// Decode the bytes between two delimiters (no zero byte among them) into a packet. `scratch`
/// receives the unstuffed bytes (an event's text is borrowed from it). Never panics.
pub fn decode<'s>(stuffed: &[u8], scratch: &'s mut [u8; MAX_RAW]) -> Result<Record<'s>, WireError> {
    if stuffed.len() > MAX_PACKET - 2 {
        return Err(WireError::TooLong);
    }
    let n = cobs::decode(stuffed, scratch)
        .map_err(|_| WireError::Stuffing)?
        .frame_size();
    let raw = &scratch[..n];
    if n < 2 + 4 {
        return Err(WireError::TooShort);
    }
    let (body, crc) = raw.split_at(n - 4);
    if CRC32.checksum(body).to_le_bytes() != crc {
        return Err(WireError::Crc);
    }
    if body[0] != VERSION {
        return Err(WireError::Version(body[0]));
    }
    let payload = &body[2..];
    match body[1] {
        KIND_FRAME => decode_frame(payload).map(Record::Frame),
        KIND_EVENT => {
            let text = core::str::from_utf8(payload)
                .map_err(|_| WireError::Event(TelemetryError::BadTag))?;
            let ev = Event::decode(text).map_err(WireError::Event)?;
            Ok(Record::Event(ev, text))
        }
        k => Err(WireError::Kind(k)),
    }
}

fn decode_frame(p: &[u8]) -> Result<Frame, WireError> {
    let p: &[u8; FRAME_PAYLOAD] = p
        .try_into()
        .map_err(|_| WireError::Length(p.len() as u16))?;
    let u32_at = |i: usize| u32::from_le_bytes([p[i], p[i + 1], p[i + 2], p[i + 3]]);
    let f32_at = |i: usize| f32::from_bits(u32_at(i));
    let mut t = [0u8; 8];
    t.copy_from_slice(&p[4..12]);
    let mut f = Frame {
        seq: u32_at(0),
        t_us: u64::from_le_bytes(t),
        flags: Flags(u32_at(12)),
        force_n: f32_at(16),
        drops: u32_at(FRAME_PAYLOAD - 4),
        ..Frame::default()
    };
    for (i, c) in f.chambers.iter_mut().enumerate() {
        let at = |j: usize| f32_at(20 + 28 * i + 4 * j);
        *c = ChamberFrame {
            v: at(0),
            vdot: at(1),
            p: at(2),
            p_hat: at(3),
            residual: at(4),
            k: at(5),
            c: at(6),
        };
    }
    Ok(f)
}

/// The switch and the bounded queue between the sampler (which fills it, never waiting) and the
/// command task (which drains it onto the UART between replies). Off at boot.
pub struct SerialTelemetry {
    on: AtomicBool,
    queue: Channel<CriticalSectionRawMutex, Packet, QUEUE>,
}

impl Default for SerialTelemetry {
    fn default() -> Self {
        Self::new()
    }
}

impl SerialTelemetry {
    /// Off, queue empty.
    pub const fn new() -> Self {
        Self {
            on: AtomicBool::new(false),
            queue: Channel::new(),
        }
    }
    /// Switch the stream on or off; off also empties the queue, so that at most the packet
    /// being written follows the reply to `telemetry off`.
    pub fn set(&self, on: bool) {
        self.on.store(on, Ordering::Relaxed);
        if !on {
            self.queue.clear();
        }
    }
    /// Whether the stream is on.
    pub fn is_on(&self) -> bool {
        self.on.load(Ordering::Relaxed)
    }
    /// Queue a packet now; `false` (the packet dropped) when the queue is full.
    pub fn try_push(&self, p: Packet) -> bool {
        self.queue.try_send(p).is_ok()
    }
    /// The next queued packet, waiting for one (cancel safe: nothing is taken until it is
    /// returned).
    pub async fn next(&self) -> Packet {
        self.queue.receive().await
    }
    /// The next queued packet, if any (for callers without an executor: tests, benchmarks).
    pub fn try_next(&self) -> Option<Packet> {
        self.queue.try_receive().ok()
    }
}

/// The sampler's side of the serial stream: the packet buffer and the count of packets this
/// transport dropped since boot (wrapping), which each frame packet carries in `drops`.
#[derive(Debug, Default)]
pub struct SerialOut {
    drops: u32,
}

impl SerialOut {
    /// Packets dropped so far (wrapping).
    pub fn drops(&self) -> u32 {
        self.drops
    }
    /// Count `n` packets lost before they reached this transport (events lost to a full event
    /// queue), while the stream is on.
    pub fn lost(&mut self, link: &SerialTelemetry, n: u32) {
        if link.is_on() {
            self.drops = self.drops.wrapping_add(n);
        }
    }
    /// Queue the frame (with this transport's `drops`) if the stream is on; `false` if it is off
    /// or the packet was dropped (counted). Never waits.
    pub fn frame(&mut self, frame: &Frame, link: &SerialTelemetry) -> bool {
        if !link.is_on() {
            return false;
        }
        let mut p = Packet::new();
        encode_frame(
            &Frame {
                drops: self.drops,
                ..*frame
            },
            &mut p,
        );
        self.push(p, link)
    }
    /// Queue the event if the stream is on; `false` if off or dropped (counted).
    pub fn event(&mut self, ev: &Event, link: &SerialTelemetry) -> bool {
        if !link.is_on() {
            return false;
        }
        let mut p = Packet::new();
        if !encode_event(ev, &mut p) {
            self.drops = self.drops.wrapping_add(1);
            return false;
        }
        self.push(p, link)
    }
    fn push(&mut self, p: Packet, link: &SerialTelemetry) -> bool {
        let ok = link.try_push(p);
        if !ok {
            self.drops = self.drops.wrapping_add(1);
        }
        ok
    }
}

#[cfg(test)]
#[path = "wire_tests.rs"]
mod tests;
