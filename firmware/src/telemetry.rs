//! Telemetry: one text line per 25 Hz frame, plus event lines.
//!
//! The board hands each line, whole or not at all, to a non-blocking
//! [`TelemetrySink`](crate::hal::TelemetrySink) (an RTT up-channel of its own on the device, a
//! buffer in the simulator): a line the transport cannot take at once is dropped and counted,
//! never waited for. The host tool parses the output of `probe-rs run` with [`parse_line`],
//! which skips whatever the printer put in front of the `$` marker (timestamps, log level).
//!
//! # Frame line
//! ```text
//! $F <seq> <t_us> <flags> <force_n> {<v> <vdot> <p> <p_hat> <residual> <k> <c>} × 3 chambers <drops>
//! ```
//! 26 space-separated fields after `$F`. `seq` (u32) counts frames from 0 and `t_us` (u64) is
//! the frame's mean sampling instant in µs since boot: a frame lost anywhere shows as a gap in
//! `seq` (and a `t_us` step of more than one period). `flags` is the [`Flags`] bit set in
//! decimal. `drops` (u32, wrapping) counts the telemetry lines (frames and events) the board
//! dropped since boot because the transport was full (plus events lost to a full event queue):
//! the change of `drops` between two received frames is the number of lines the board dropped
//! between them, so a `seq` gap that `drops` does not account for was lost on the way (the
//! host's side). Lines written before this field existed (25 fields) still decode, with
//! `drops = 0`. Units: v mm³, vdot mm³/s, p / p_hat / residual kPa, k kPa/mm³, c kPa·s/mm³,
//! force N. Floats are printed in the shortest decimal that reads back to the same `f32`
//! (plain for 1e-5 ≤ |x| < 1e9, else exponent form such as `1.5e-7`), so
//! `Frame::decode(encode(f)) == f` bit for bit (every NaN reads back as NaN).
//!
//! # Event line
//! ```text
//! $E <t_us> <kind> <args…>
//! ```
//! See [`Event`] for the kinds and their arguments.

use core::fmt::{self, Write};
use core::str::{FromStr, SplitAsciiWhitespace};

use crate::hal::AXES;
use crate::reset::ResetCause;
use crate::store::StoreEvent;

/// Fault and warning bits carried by every frame: defined in `model-core`, which the host's
/// analysis reads them from too.
pub use model_core::flags::Flags;

/// One chamber's numbers in a frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ChamberFrame {
    /// Syringe volume from the step count, mm³.
    pub v: f32,
    /// Commanded flow, mm³/s.
    pub vdot: f32,
    /// Measured gauge pressure after the zero, kPa.
    pub p: f32,
    /// Model prediction, kPa.
    pub p_hat: f32,
    /// `p − p_hat`, kPa.
    pub residual: f32,
    /// Stiffness ∂P/∂v, kPa/mm³.
    pub k: f32,
    /// Damping ∂P/∂v̇, kPa·s/mm³.
    pub c: f32,
}

/// One telemetry frame.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Frame {
    /// Frame sequence number, from 0, +1 per frame.
    pub seq: u32,
    /// Mean sampling instant of the frame, µs since boot.
    pub t_us: u64,
    /// Fault and warning bits.
    pub flags: Flags,
    /// External force estimate Σ residual × area, N.
    pub force_n: f32,
    /// Per chamber.
    pub chambers: [ChamberFrame; AXES],
    /// Telemetry lines dropped by the board since boot (wrapping), as of this frame.
    pub drops: u32,
}

/// Why a telemetry line did not decode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum TelemetryError {
    /// The line does not start with the expected tag (`$F` / `$E`).
    BadTag,
    /// Fewer fields than the line kind needs.
    MissingField {
        /// Index of the first missing field (0 = first after the tag).
        index: u8,
    },
    /// A field is not a number of the right type.
    BadNumber {
        /// Index of the field (0 = first after the tag).
        index: u8,
    },
    /// More fields than the line kind has.
    TrailingField,
    /// The event kind is unknown.
    UnknownEvent,
}

impl fmt::Display for TelemetryError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::BadTag => f.write_str("line does not start with $F or $E"),
            Self::MissingField { index } => write!(f, "field {index} missing"),
            Self::BadNumber { index } => write!(f, "field {index} is not a valid number"),
            Self::TrailingField => f.write_str("unexpected extra field"),
            Self::UnknownEvent => f.write_str("unknown event kind"),
        }
    }
}

/// Fields after a tag, numbered for error messages.
struct Fields<'a> {
    it: SplitAsciiWhitespace<'a>,
    index: u8,
}

impl<'a> Fields<'a> {
    fn after_tag(line: &'a str, tag: &str) -> Result<Self, TelemetryError> {
        let mut it = line.trim().split_ascii_whitespace();
        if it.next() != Some(tag) {
            return Err(TelemetryError::BadTag);
        }
        Ok(Self { it, index: 0 })
    }
    fn word(&mut self) -> Result<&'a str, TelemetryError> {
        let index = self.index;
        self.index = self.index.saturating_add(1);
        self.it.next().ok_or(TelemetryError::MissingField { index })
    }
    fn num<T: FromStr>(&mut self) -> Result<T, TelemetryError> {
        let index = self.index;
        self.word()?
            .parse()
            .map_err(|_| TelemetryError::BadNumber { index })
    }
    fn has_more(&self) -> bool {
        self.it.clone().next().is_some()
    }
    fn end(mut self) -> Result<(), TelemetryError> {
        match self.it.next() {
            None => Ok(()),
            Some(_) => Err(TelemetryError::TrailingField),
        }
    }
}

/// Write `' '` and `x` in the shortest form that reads back to the same `f32`: plain decimals
/// in the everyday range, exponent form outside it (Rust's `{}` never uses an exponent, so
/// `f32::MAX` would take 39 digits).
pub(crate) fn num(out: &mut impl Write, x: f32) -> fmt::Result {
    let a = x.abs();
    if a == 0.0 || !a.is_finite() || (1e-5..1e9).contains(&a) {
        write!(out, " {x}")
    } else {
        write!(out, " {x:e}")
    }
}

/// Frame line tag.
pub const FRAME_TAG: &str = "$F";
/// Event line tag.
pub const EVENT_TAG: &str = "$E";
/// Longest frame line: 26 fields of at most 20 characters plus separators and the `\n`.
pub const MAX_LINE: usize = 560;

impl Frame {
    /// Write the frame line (no terminator).
    pub fn encode(&self, out: &mut impl Write) -> fmt::Result {
        write!(
            out,
            "{FRAME_TAG} {} {} {}",
            self.seq, self.t_us, self.flags.0
        )?;
        num(out, self.force_n)?;
        for c in &self.chambers {
            for x in [c.v, c.vdot, c.p, c.p_hat, c.residual, c.k, c.c] {
                num(out, x)?;
            }
        }
        write!(out, " {}", self.drops)
    }

    /// Parse a frame line as written by [`Frame::encode`] (surrounding whitespace allowed), or
    /// by firmware before the `drops` field (25 fields: `drops` reads as 0).
    pub fn decode(line: &str) -> Result<Frame, TelemetryError> {
        let mut f = Fields::after_tag(line, FRAME_TAG)?;
        let mut frame = Frame {
            seq: f.num()?,
            t_us: f.num()?,
            flags: Flags(f.num()?),
            force_n: f.num()?,
            ..Frame::default()
        };
        for c in &mut frame.chambers {
            *c = ChamberFrame {
                v: f.num()?,
                vdot: f.num()?,
                p: f.num()?,
                p_hat: f.num()?,
                residual: f.num()?,
                k: f.num()?,
                c: f.num()?,
            };
        }
        if f.has_more() {
            frame.drops = f.num()?;
        }
        f.end()?;
        Ok(frame)
    }
}

/// Something that happened, reported once on an event line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum EventKind {
    /// Firmware started, after a reset of this cause. The line is
    /// `boot <watchdog 0|1> <cause> [<details>…]` (see [`ResetCause::encode`]); a line with
    /// only the watchdog field (older firmware) reads as `watchdog` or `unknown`.
    Boot {
        /// Why the board reset.
        cause: ResetCause,
    },
    /// Fault bits newly latched (`flags` is the whole latched set).
    Fault {
        /// Latched flags after the change.
        flags: u32,
    },
    /// Faults cleared by command.
    Cleared,
    /// Pressure zero taken; offsets in kPa per channel.
    Zeroed {
        /// Offsets subtracted from each channel, kPa.
        offset_kpa: [f32; AXES],
    },
    /// Stiffness/damping drift warning on a channel: current mean k̄, c̄ against the baseline.
    Drift {
        /// Channel.
        ch: u8,
        /// Current mean stiffness, kPa/mm³.
        k_mean: f32,
        /// Current mean damping, kPa·s/mm³.
        c_mean: f32,
        /// Baseline mean stiffness.
        k_base: f32,
        /// Baseline mean damping.
        c_base: f32,
    },
    /// The characterisation protocol finished all its cycles.
    ProtocolDone,
    /// A model was loaded into a channel.
    ModelLoaded {
        /// Channel.
        ch: u8,
    },
    /// The model store ([`crate::store`]) for a channel: `store <ch> <what> <crc hex>`. At boot
    /// `loaded`, or `empty` / `invalid` when the built-in default is used instead; after a
    /// commit `saved` or `failed`. `crc` is the CRC-32 of the channel's committed model.
    Store {
        /// Channel.
        ch: u8,
        /// What happened.
        what: StoreEvent,
        /// CRC-32 of the committed model.
        crc: u32,
    },
}

/// An event line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Event {
    /// When, µs since boot.
    pub t_us: u64,
    /// What.
    pub kind: EventKind,
}

impl Event {
    /// Write the event line (no terminator).
    pub fn encode(&self, out: &mut impl Write) -> fmt::Result {
        write!(out, "{EVENT_TAG} {} ", self.t_us)?;
        match self.kind {
            EventKind::Boot { cause } => {
                let watchdog = u8::from(cause == ResetCause::Watchdog);
                write!(out, "boot {watchdog} ")?;
                cause.encode(out)
            }
            EventKind::Fault { flags } => write!(out, "fault {flags}"),
            EventKind::Cleared => out.write_str("cleared"),
            EventKind::Zeroed { offset_kpa: o } => {
                out.write_str("zeroed")?;
                o.iter().try_for_each(|&x| num(out, x))
            }
            EventKind::Drift {
                ch,
                k_mean,
                c_mean,
                k_base,
                c_base,
            } => {
                write!(out, "drift {ch}")?;
                [k_mean, c_mean, k_base, c_base]
                    .iter()
                    .try_for_each(|&x| num(out, x))
            }
            EventKind::ProtocolDone => out.write_str("protocol-done"),
            EventKind::ModelLoaded { ch } => write!(out, "model {ch}"),
            EventKind::Store { ch, what, crc } => {
                write!(out, "store {ch} {} {crc:#010x}", what.name())
            }
        }
    }

    /// Parse an event line as written by [`Event::encode`].
    pub fn decode(line: &str) -> Result<Event, TelemetryError> {
        let mut f = Fields::after_tag(line, EVENT_TAG)?;
        let t_us = f.num()?;
        let kind = match f.word()? {
            "boot" => {
                let watchdog = f.num::<u8>()? != 0;
                let index = f.index;
                let cause = if f.it.clone().next().is_none() {
                    // Older firmware: `boot <0|1>` only.
                    match watchdog {
                        true => ResetCause::Watchdog,
                        false => ResetCause::Unknown,
                    }
                } else {
                    ResetCause::decode(|| f.it.next()).ok_or(TelemetryError::BadNumber { index })?
                };
                EventKind::Boot { cause }
            }
            "fault" => EventKind::Fault { flags: f.num()? },
            "cleared" => EventKind::Cleared,
            "zeroed" => EventKind::Zeroed {
                offset_kpa: [f.num()?, f.num()?, f.num()?],
            },
            "drift" => EventKind::Drift {
                ch: f.num()?,
                k_mean: f.num()?,
                c_mean: f.num()?,
                k_base: f.num()?,
                c_base: f.num()?,
            },
            "protocol-done" => EventKind::ProtocolDone,
            "model" => EventKind::ModelLoaded { ch: f.num()? },
            "store" => {
                let ch = f.num()?;
                let index = f.index;
                let what =
                    StoreEvent::from_name(f.word()?).ok_or(TelemetryError::BadNumber { index })?;
                let index = f.index;
                let crc = f
                    .word()?
                    .strip_prefix("0x")
                    .and_then(|h| u32::from_str_radix(h, 16).ok())
                    .ok_or(TelemetryError::BadNumber { index })?;
                EventKind::Store { ch, what, crc }
            }
            _ => return Err(TelemetryError::UnknownEvent),
        };
        f.end()?;
        Ok(Event { t_us, kind })
    }
}

/// A decoded telemetry line.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Line {
    /// A frame.
    Frame(Frame),
    /// An event.
    Event(Event),
}

/// Find and decode the telemetry line in `text`, ignoring anything before the `$` marker
/// (e.g. a timestamp added by `probe-rs run`). `None` if the text holds no `$F`/`$E` line.
pub fn parse_line(text: &str) -> Option<Result<Line, TelemetryError>> {
    let start = [FRAME_TAG, EVENT_TAG]
        .iter()
        .filter_map(|tag| text.find(tag))
        .min()?;
    let rest = &text[start..];
    Some(if rest.starts_with(FRAME_TAG) {
        Frame::decode(rest).map(Line::Frame)
    } else {
        Event::decode(rest).map(Line::Event)
    })
}

/// A fixed-capacity line buffer implementing `fmt::Write` (no allocation on the device).
pub type LineBuf = heapless::String<MAX_LINE>;

/// Candidates for the longest printed f32, at the edges of both notations (test data shared by
/// the telemetry and command-handler tests).
#[cfg(test)]
pub(crate) const LONGEST_F32: [f32; 7] = [
    -f32::MIN_POSITIVE / 3.0,
    -f32::MAX,
    -1.1754942e-38,
    -9.999999e8,
    -1.0000001e-5,
    -0.00012345679,
    -123456790.0,
];

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Any f32 bit pattern (also used by the wire codec's tests).
    pub(crate) fn any_f32() -> impl Strategy<Value = f32> {
        // Every bit pattern: normal, subnormal, ±0, ±inf, NaN payloads.
        any::<u32>().prop_map(f32::from_bits)
    }

    /// A chamber frame of arbitrary f32 bit patterns (also used by the wire codec's tests).
    pub(crate) fn chamber() -> impl Strategy<Value = ChamberFrame> {
        proptest::array::uniform7(any_f32()).prop_map(|a| ChamberFrame {
            v: a[0],
            vdot: a[1],
            p: a[2],
            p_hat: a[3],
            residual: a[4],
            k: a[5],
            c: a[6],
        })
    }

    fn bits(f: &Frame) -> [u32; 22] {
        let mut out = [0u32; 22];
        out[0] = f.force_n.to_bits();
        for (i, c) in f.chambers.iter().enumerate() {
            let v = [c.v, c.vdot, c.p, c.p_hat, c.residual, c.k, c.c];
            for (j, x) in v.iter().enumerate() {
                out[1 + 7 * i + j] = x.to_bits();
            }
        }
        out
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]
        #[test]
        fn frame_round_trips_bit_for_bit(
            seq in any::<u32>(), t_us in any::<u64>(), flags in any::<u32>(), force in any_f32(),
            c0 in chamber(), c1 in chamber(), c2 in chamber(), drops in any::<u32>(),
        ) {
            let f = Frame {
                seq, t_us, flags: Flags(flags), force_n: force, chambers: [c0, c1, c2], drops,
            };
            let mut s = LineBuf::new();
            f.encode(&mut s).expect("a frame fits MAX_LINE");
            let g = Frame::decode(&s).unwrap();
            prop_assert_eq!((g.seq, g.t_us, g.flags, g.drops), (seq, t_us, Flags(flags), drops));
            // NaN payloads: Rust prints every NaN as "NaN", so compare NaN-ness, others bitwise.
            let (a, b) = (bits(&f), bits(&g));
            for k in 0..22 {
                let (x, y) = (f32::from_bits(a[k]), f32::from_bits(b[k]));
                prop_assert!(a[k] == b[k] || (x.is_nan() && y.is_nan()), "field {}: {} vs {}", k, x, y);
            }
        }

        #[test]
        fn decode_never_panics(s in "\\PC{0,200}") {
            let _ = Frame::decode(&s);
            let _ = Event::decode(&s);
            let _ = parse_line(&s);
        }
    }

    #[test]
    fn longest_frame_fits() {
        let long = LONGEST_F32
            .into_iter()
            .max_by_key(|x| {
                let mut s = LineBuf::new();
                num(&mut s, *x).unwrap();
                s.len()
            })
            .unwrap();
        let c = ChamberFrame {
            v: long,
            vdot: long,
            p: long,
            p_hat: long,
            residual: long,
            k: long,
            c: long,
        };
        let f = Frame {
            seq: u32::MAX,
            t_us: u64::MAX,
            flags: Flags(u32::MAX),
            force_n: long,
            chambers: [c; 3],
            drops: u32::MAX,
        };
        let mut s = LineBuf::new();
        f.encode(&mut s).expect("fits");
        s.push('\n').expect("with its terminator");
    }

    #[test]
    fn a_line_without_the_drop_counter_still_decodes() {
        let f = Frame {
            seq: 3,
            t_us: 120_000,
            drops: 7,
            ..Frame::default()
        };
        let mut s = LineBuf::new();
        f.encode(&mut s).unwrap();
        assert!(s.ends_with(" 7"));
        let old = &s[..s.len() - 2];
        assert_eq!(Frame::decode(old), Ok(Frame { drops: 0, ..f }));
        assert_eq!(Frame::decode(&s), Ok(f));
    }

    #[test]
    fn events_round_trip() {
        let kinds = [
            EventKind::Boot {
                cause: ResetCause::Watchdog,
            },
            EventKind::Boot {
                cause: ResetCause::PowerOn,
            },
            EventKind::Boot {
                cause: ResetCause::Panic(crate::reset::PanicSite {
                    file: crate::reset::FileTail::new("src/app.rs"),
                    line: 42,
                    column: 9,
                }),
            },
            EventKind::Boot {
                cause: ResetCause::HardFault(crate::reset::FaultFrame {
                    pc: 0x0800_0400,
                    cfsr: 1 << 17,
                    hfsr: 1 << 30,
                    ..Default::default()
                }),
            },
            EventKind::Store {
                ch: 2,
                what: StoreEvent::Invalid,
                crc: 0xCBF4_3926,
            },
            EventKind::Fault { flags: 0x41 },
            EventKind::Cleared,
            EventKind::Zeroed {
                offset_kpa: [0.1, -0.25, 3.0e-3],
            },
            EventKind::Drift {
                ch: 2,
                k_mean: 0.1,
                c_mean: 0.12,
                k_base: 0.156,
                c_base: 0.175,
            },
            EventKind::ProtocolDone,
            EventKind::ModelLoaded { ch: 1 },
        ];
        for kind in kinds {
            let e = Event {
                t_us: 123_456,
                kind,
            };
            let mut s = LineBuf::new();
            e.encode(&mut s).unwrap();
            assert_eq!(Event::decode(&s), Ok(e), "{s}");
            assert_eq!(parse_line(&s), Some(Ok(Line::Event(e))));
        }
    }

    #[test]
    fn boot_and_store_lines_by_hand() {
        let ev = |s: &str| Event::decode(s).map(|e| e.kind);
        assert_eq!(
            ev("$E 5 boot 1 watchdog"),
            Ok(EventKind::Boot {
                cause: ResetCause::Watchdog
            })
        );
        assert_eq!(
            ev("$E 5 boot 0 panic app.rs 7 3"),
            Ok(EventKind::Boot {
                cause: ResetCause::Panic(crate::reset::PanicSite {
                    file: crate::reset::FileTail::new("app.rs"),
                    line: 7,
                    column: 3
                })
            })
        );
        // Older firmware printed the watchdog field alone.
        assert_eq!(
            ev("$E 0 boot 0"),
            Ok(EventKind::Boot {
                cause: ResetCause::Unknown
            })
        );
        assert_eq!(
            ev("$E 0 boot 1"),
            Ok(EventKind::Boot {
                cause: ResetCause::Watchdog
            })
        );
        assert_eq!(
            ev("$E 0 boot 0 meteor"),
            Err(TelemetryError::BadNumber { index: 3 })
        );
        assert_eq!(
            ev("$E 0 boot 0 panic app.rs x 3"),
            Err(TelemetryError::BadNumber { index: 3 })
        );
        assert_eq!(
            ev("$E 9 store 1 empty 0x0000abcd"),
            Ok(EventKind::Store {
                ch: 1,
                what: StoreEvent::Empty,
                crc: 0xABCD
            })
        );
        assert_eq!(
            ev("$E 9 store 1 lost 0x0"),
            Err(TelemetryError::BadNumber { index: 3 })
        );
        assert_eq!(
            ev("$E 9 store 1 saved 12"),
            Err(TelemetryError::BadNumber { index: 4 })
        );
        let mut s = LineBuf::new();
        Event {
            t_us: 1,
            kind: EventKind::Store {
                ch: 0,
                what: StoreEvent::Saved,
                crc: 0xAB,
            },
        }
        .encode(&mut s)
        .unwrap();
        assert_eq!(s, "$E 1 store 0 saved 0x000000ab");
    }

    #[test]
    fn parse_line_skips_printer_prefix_and_reports_errors() {
        let f = Frame {
            seq: 7,
            t_us: 280_000,
            ..Frame::default()
        };
        let mut s = LineBuf::new();
        f.encode(&mut s).unwrap();
        let printed = std::format!("0.280012 {s}");
        assert_eq!(parse_line(&printed), Some(Ok(Line::Frame(f))));
        assert_eq!(parse_line("INFO vfp-fw booted"), None);
        assert_eq!(
            Frame::decode("$F 1 2 3"),
            Err(TelemetryError::MissingField { index: 3 })
        );
        let bad_drops = std::format!("{s}x");
        assert_eq!(
            Frame::decode(&bad_drops),
            Err(TelemetryError::BadNumber { index: 25 })
        );
        assert_eq!(
            Frame::decode("$F 1 x 3"),
            Err(TelemetryError::BadNumber { index: 1 })
        );
        assert_eq!(Frame::decode("$G 1"), Err(TelemetryError::BadTag));
        let extra = std::format!("{s} 5");
        assert_eq!(Frame::decode(&extra), Err(TelemetryError::TrailingField));
    }
}
