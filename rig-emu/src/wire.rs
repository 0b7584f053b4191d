//! The host's reader of the command port: text reply lines and binary telemetry packets
//! (`firmware::wire`: `0x00 | COBS(...) | 0x00`) share the line.

use firmware::telemetry::Frame;
use firmware::wire::{self, Record, MAX_RAW};

/// One thing the host read.
#[derive(Clone, Debug, PartialEq)]
pub enum Received {
    /// A text line (terminator removed), with the instant its last byte arrived, ns.
    Line(u64, String),
    /// A telemetry frame, with the instant its packet ended, ns.
    Frame(u64, Frame),
    /// A telemetry event's text line.
    Event(u64, String),
    /// A packet that did not decode (damaged or unknown), with the reason.
    BadPacket(u64, String),
}

#[derive(Clone, Debug, Default, PartialEq, Eq)]
enum State {
    #[default]
    Text,
    Packet,
}

/// The reader's state.
#[derive(Clone, Debug, Default)]
pub struct Stream {
    state: State,
    buf: Vec<u8>,
    items: Vec<Received>,
}

impl Stream {
    /// One byte from the line, arrived at `at_ns`.
    pub fn push(&mut self, at_ns: u64, b: u8) {
        match self.state {
            State::Text => match b {
                0 => {
                    self.flush_text(at_ns);
                    self.state = State::Packet;
                }
                b'\n' => {
                    let line = String::from_utf8_lossy(&self.buf).into_owned();
                    self.buf.clear();
                    self.items.push(Received::Line(at_ns, line));
                }
                b'\r' => {}
                _ => self.buf.push(b),
            },
            State::Packet => {
                if b != 0 {
                    self.buf.push(b);
                } else if !self.buf.is_empty() {
                    // The packet's closing delimiter (its opening one switched state).
                    let mut stuffed = vec![0];
                    stuffed.extend_from_slice(&self.buf);
                    stuffed.push(0);
                    self.buf.clear();
                    self.state = State::Text;
                    let mut scratch = [0u8; MAX_RAW];
                    self.items.push(match wire::decode(&stuffed, &mut scratch) {
                        Ok(Record::Frame(f)) => Received::Frame(at_ns, f),
                        Ok(Record::Event(_, text)) => Received::Event(at_ns, text.to_string()),
                        Err(e) => Received::BadPacket(at_ns, format!("{e:?}")),
                    });
                }
            }
        }
    }

    fn flush_text(&mut self, at_ns: u64) {
        if !self.buf.is_empty() {
            // Text cut by a packet: keep it as a (partial) line so nothing is lost silently.
            let line = String::from_utf8_lossy(&self.buf).into_owned();
            self.buf.clear();
            self.items.push(Received::Line(at_ns, line));
        }
    }

    /// Everything read so far.
    pub fn items(&self) -> &[Received] {
        &self.items
    }

    /// The text lines read so far.
    pub fn lines(&self) -> Vec<String> {
        self.items
            .iter()
            .filter_map(|r| match r {
                Received::Line(_, l) => Some(l.clone()),
                _ => None,
            })
            .collect()
    }

    /// The telemetry frames read so far.
    pub fn frames(&self) -> Vec<Frame> {
        self.items
            .iter()
            .filter_map(|r| match r {
                Received::Frame(_, f) => Some(*f),
                _ => None,
            })
            .collect()
    }
}
