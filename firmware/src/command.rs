//! The serial command protocol: one ASCII line per command, one reply line per command.
//!
//! Lines end with `\n` (a preceding `\r` is ignored), hold at most [`MAX_LINE`] bytes, and
//! are split on spaces/tabs. Numbers are decimal (`12`, `-0.5`, `1.5e-3`); floats must be
//! finite. `<axes>` is `all` or a set of channel digits (`0`, `12`, `012`). Volumes in mm³,
//! flows in mm³/s, accelerations in mm³/s², pressures in kPa.
//!
//! | command | effect |
//! | --- | --- |
//! | `move <axes> <volume> [<flow> [<accel>]]` | move to an absolute volume (from rest) |
//! | `run <axes> <v_low> <v_high> <cycles> <dwell_ms> <flow>…` | characterisation protocol (paper Fig. 1c): go to `v_low`, then per flow (1..=8 flows) `cycles` × (inflate to `v_high`, dwell, deflate to `v_low`, dwell) |
//! | `stop` | stop all motion now (cancels `run`) |
//! | `clear` | clear latched faults |
//! | `zero` | re-take the pressure zero (syringes at rest, ~1 s) |
//! | `status` | one-line state report |
//! | `limit <axes> <p_max_kpa> <capacity_mm3>` | set the safety limits |
//! | `origin <axes> [<volume>]` | declare the current volume (default 0), at rest |
//! | `model <ch> begin <n> <m> <p> <v_off> <v_scale> <f_off> <f_scale>` | start loading a model |
//! | `model <ch> coef <index> <b>…` | scaled coefficients `b_ij` from `index` (= i·(m+1)+j), 1..=8 per line |
//! | `model <ch> ar <index> <b>…` | scaled AR coefficients, flattened `b_11 b_12 b_21 …`, from `index` |
//! | `model <ch> commit` | check and install the staged model |
//! | `model <ch> default` | reinstall the paper's SBA1 model |
//! | `model <ch> read` | `ok <n> <m> <p> <v_off> <v_scale> <f_off> <f_scale>` of the installed model |
//! | `model <ch> read coef <index>` / `model <ch> read ar <index>` | `ok` and up to 8 installed (scaled, flattened AR) coefficients from `index` |
//! | `model <ch> effect <name> <param>…` | add an effect to the staged model's chain (`model_core::chain`; at most 4, one per kind): `hysteresis <w> <H0> <H1>`, `sensor_lag <tau>`, `delivery_lag <tau>`, `transport_delay <d>`, `backlash <b>`, `inertance <L>`, `pump_ripple <period> <a> <b>`, `air_compliance <V_a>`, `leak <lambda>` (mm³, kPa, s) |
//! | `model <ch> read effect <index>` | `ok <name> <param>…` of the installed chain's effect `index` (in evaluation order); `err out-of-range 4` past the last |
//! | `rls <ch> on [<lambda>]` / `rls <ch> off` | online RLS identification (chamber force-free!) |
//! | `checksum require` / `checksum optional` / `checksum` | require a checksum on every line (the default at boot), or not; alone: `ok require` or `ok optional` |
//! | `telemetry on` / `telemetry off` / `telemetry` | the binary telemetry stream on this serial port ([`crate::wire`]) on or off (off at boot); alone: `ok on` or `ok off` |
//!
//! Replies: `ok` (possibly followed by fields) or `err <code> [<detail>]`. The parser never
//! panics; every bad line gets an `err` reply naming the argument.
//!
//! # Checksummed lines
//! A line carries a checksum in front of its command: `*LLCC <command>`, where `LL` is the
//! command's length in bytes and `CC` its CRC-8 (SMBus polynomial 0x07, initial value 0), each
//! two upper-case hex digits, and exactly one space separates them from the command
//! ([`write_checksummed`] builds such a line). Any line that holds a `*` is checked as one:
//! a wrong length, CRC or layout is refused with `err bad-checksum`. Every single byte dropped,
//! duplicated or replaced in a checksummed line is refused without being executed:
//! - in the command: a drop or duplication changes the length, a replacement the CRC (a CRC-8
//!   catches every error confined to 8 consecutive bits);
//! - in the prefix: the layout breaks, or the length/CRC no longer match; a lost `*` leaves a
//!   first word of four hex digits, which is no command;
//! - a byte turned into a line break splits the line in two: the first part fails its check,
//!   and the line after a failed check must itself carry a checksum (`err checksum-required`),
//!   so the second part is refused too; a byte turned into `\r` is dropped (`\r` is ignored).
//!
//! `stop` is obeyed in any form: a plain `stop` in `checksum require` mode or after a failed
//! check, and a `stop` behind a damaged prefix (stopping is safe whatever the line was).
//!
//! The checksum is required at boot: a plain line other than `stop` gets
//! `err checksum-required` and changes nothing, so no single flipped bit on the wire (the UART
//! has no parity) executes a command. `checksum optional`, itself checksummed
//! (`*1104 checksum optional`, the line a person at a terminal types once), accepts plain lines
//! too until `checksum require` or the next reset. A receive error on the serial port (framing,
//! overrun, noise, parity) rejects the line being received with `err line-corrupt`, whatever
//! the mode.

use core::fmt;
use core::str::FromStr;
use model_core::chain::{EffectKind, MAX_EFFECTS, MAX_EFFECT_PARAMS};

use heapless::Vec;

use crate::hal::AXES;

/// Longest accepted command line, bytes (without the terminator).
pub const MAX_LINE: usize = 200;
/// Most flow rates in one `run`.
pub const MAX_FLOWS: usize = 8;
/// Most coefficients on one `model … coef`/`ar` line.
pub const MAX_CHUNK: usize = 8;

/// A set of axes/channels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct AxisSet(pub u8);

impl AxisSet {
    /// Every axis.
    pub const ALL: AxisSet = AxisSet((1 << AXES) - 1);
    /// Whether `axis` is in the set.
    pub fn contains(self, axis: usize) -> bool {
        self.0 & (1 << axis) != 0
    }
    /// The axes in the set, ascending.
    pub fn iter(self) -> impl Iterator<Item = usize> {
        (0..AXES).filter(move |&a| self.contains(a))
    }
}

/// The characterisation protocol's parameters (paper Fig. 1c).
#[derive(Clone, Debug, PartialEq)]
pub struct ProtocolSpec {
    /// Axes driven together.
    pub axes: AxisSet,
    /// Lower volume of each cycle, mm³.
    pub v_low: f32,
    /// Upper volume of each cycle, mm³.
    pub v_high: f32,
    /// Inflate/deflate cycles per flow rate.
    pub cycles: u16,
    /// Dwell at each end, ms.
    pub dwell_ms: u32,
    /// Flow rates, mm³/s, in the order run.
    pub flows: Vec<f32, MAX_FLOWS>,
}

/// What `model <ch> …` does.
#[derive(Clone, Debug, PartialEq)]
pub enum ModelCmd {
    /// Start staging a model of this shape and scaling.
    Begin {
        /// Degree in v.
        n: u8,
        /// Degree in v̇.
        m: u8,
        /// AR order.
        p: u8,
        /// `[v_offset, v_scale, f_offset, f_scale]`.
        scaling: [f32; 4],
    },
    /// Scaled polynomial coefficients from `start`.
    Coef {
        /// Index of the first value.
        start: u8,
        /// Values.
        values: Vec<f32, MAX_CHUNK>,
    },
    /// Flattened scaled AR coefficients from `start`.
    Ar {
        /// Index of the first value.
        start: u8,
        /// Values.
        values: Vec<f32, MAX_CHUNK>,
    },
    /// Install the staged model.
    Commit,
    /// Install the built-in SBA1 model.
    Default,
    /// Read back part of the installed model.
    Read(ReadPart),
}

/// What `model <ch> read …` reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadPart {
    /// Shape and scaling: `n m p v_off v_scale f_off f_scale`.
    Header,
    /// Up to [`MAX_CHUNK`] scaled coefficients from `start`.
    Coef {
        /// Index of the first value.
        start: u8,
    },
    /// Up to [`MAX_CHUNK`] flattened AR coefficients from `start`.
    Ar {
        /// Index of the first value.
        start: u8,
    },
    /// The installed chain's effect `index`: `<name> <param>…`.
    Effect {
        /// Index in the chain's evaluation order.
        index: u8,
    },
    /// The committed model's CRC-32 and where it stands against flash
    /// ([`crate::store`]): `<crc hex> flash|pending|failed|default`.
    Crc,
}

/// A parsed command.
#[derive(Clone, Debug, PartialEq)]
pub enum Command {
    /// Move to an absolute volume.
    Move {
        /// Axes.
        axes: AxisSet,
        /// Target volume, mm³.
        volume: f32,
        /// Flow limit, mm³/s (configured default if absent).
        flow: Option<f32>,
        /// Acceleration, mm³/s² (configured default if absent).
        accel: Option<f32>,
    },
    /// Run the characterisation protocol.
    Run(ProtocolSpec),
    /// Stop all motion.
    Stop,
    /// Clear latched faults.
    Clear,
    /// Re-take the pressure zero.
    Zero,
    /// Report state.
    Status,
    /// Set safety limits.
    Limit {
        /// Channels.
        axes: AxisSet,
        /// Pressure limit, kPa.
        p_max_kpa: f32,
        /// Syringe capacity (volume limit), mm³.
        capacity_mm3: f32,
    },
    /// Declare the current volume.
    Origin {
        /// Axes.
        axes: AxisSet,
        /// Volume, mm³.
        volume: f32,
    },
    /// Model loading.
    Model {
        /// Channel.
        ch: u8,
        /// What to do.
        cmd: ModelCmd,
    },
    /// `model <ch> effect …`: add an effect to the staged model's chain. A command of its own
    /// rather than a [`ModelCmd`], so that host code matching every `ModelCmd` of a bare upload
    /// keeps compiling.
    ModelEffect {
        /// Channel.
        ch: u8,
        /// Which effect.
        kind: EffectKind,
        /// Its parameters (exactly `kind.params()`).
        params: Vec<f32, MAX_EFFECT_PARAMS>,
    },
    /// Online RLS on or off.
    Rls {
        /// Channel.
        ch: u8,
        /// `Some(lambda)` to switch on (configured default if not given), `None` for off.
        lambda: Option<Option<f32>>,
    },
    /// Require a checksum on every line (`Some(true)`), accept plain lines (`Some(false)`), or
    /// report the mode (`None`).
    Checksum {
        /// The new mode.
        require: Option<bool>,
    },
    /// Switch the binary telemetry stream on this port on (`Some(true)`) or off, or report it
    /// (`None`).
    Telemetry {
        /// The new state.
        on: Option<bool>,
    },
}

/// Why a line did not parse. `index` counts words from 0 (the command name).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(target_os = "none", derive(defmt::Format))]
pub enum ParseError {
    /// Nothing but white space.
    Empty,
    /// The line is longer than [`MAX_LINE`].
    TooLong,
    /// The line is not ASCII.
    NotAscii,
    /// The first word is not a command.
    UnknownCommand,
    /// A required argument is missing.
    Missing {
        /// Word index.
        index: u8,
    },
    /// An argument is not a (finite) number or not a known keyword.
    Invalid {
        /// Word index.
        index: u8,
    },
    /// An argument is a number outside its allowed range.
    OutOfRange {
        /// Word index.
        index: u8,
    },
    /// More arguments than the command takes.
    TooMany {
        /// Word index of the first extra one.
        index: u8,
    },
    /// The serial port reported a receive error (framing, overrun, noise, parity) while the
    /// line arrived: some of its bytes may be lost or wrong.
    LineCorrupt,
    /// The line holds a `*` but not a valid `*LLCC ` prefix, or its length or CRC do not match.
    BadChecksum,
    /// The line has no checksum, but one is required (at boot and after `checksum require`,
    /// or the line follows a line that failed its checksum).
    ChecksumRequired,
}

impl ParseError {
    /// Short machine-readable code used in `err` replies.
    pub fn code(&self) -> &'static str {
        match self {
            Self::Empty => "empty",
            Self::TooLong => "too-long",
            Self::NotAscii => "not-ascii",
            Self::UnknownCommand => "unknown-command",
            Self::Missing { .. } => "missing-argument",
            Self::Invalid { .. } => "invalid-argument",
            Self::OutOfRange { .. } => "out-of-range",
            Self::TooMany { .. } => "too-many-arguments",
            Self::LineCorrupt => "line-corrupt",
            Self::BadChecksum => "bad-checksum",
            Self::ChecksumRequired => "checksum-required",
        }
    }
}

impl fmt::Display for ParseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.code())?;
        match self {
            Self::Missing { index }
            | Self::Invalid { index }
            | Self::OutOfRange { index }
            | Self::TooMany { index } => write!(f, " {index}"),
            Self::TooLong => write!(f, " {MAX_LINE}"),
            _ => Ok(()),
        }
    }
}

/// Words of a line with their indices.
struct Words<'a> {
    it: core::str::SplitAsciiWhitespace<'a>,
    index: u8,
}

impl<'a> Words<'a> {
    fn next_word(&mut self) -> Option<(u8, &'a str)> {
        let w = self.it.next()?;
        let i = self.index;
        self.index = self.index.saturating_add(1);
        Some((i, w))
    }
    fn word(&mut self) -> Result<(u8, &'a str), ParseError> {
        let index = self.index;
        self.next_word().ok_or(ParseError::Missing { index })
    }
    fn parse<T: FromStr>(&mut self) -> Result<(u8, T), ParseError> {
        let (i, w) = self.word()?;
        w.parse()
            .map(|x| (i, x))
            .map_err(|_| ParseError::Invalid { index: i })
    }
    /// A finite float within `lo..=hi`.
    fn float(&mut self, lo: f32, hi: f32) -> Result<f32, ParseError> {
        let (i, x): (u8, f32) = self.parse()?;
        check_float(i, x, lo, hi)
    }
    fn opt_float(&mut self, lo: f32, hi: f32) -> Result<Option<f32>, ParseError> {
        match self.next_word() {
            None => Ok(None),
            Some((i, w)) => {
                let x: f32 = w.parse().map_err(|_| ParseError::Invalid { index: i })?;
                check_float(i, x, lo, hi).map(Some)
            }
        }
    }
    fn int<T: FromStr + PartialOrd>(&mut self, lo: T, hi: T) -> Result<T, ParseError> {
        let (i, x): (u8, T) = self.parse()?;
        if x < lo || x > hi {
            return Err(ParseError::OutOfRange { index: i });
        }
        Ok(x)
    }
    fn axes(&mut self) -> Result<AxisSet, ParseError> {
        let (i, w) = self.word()?;
        parse_axes(w).ok_or(ParseError::Invalid { index: i })
    }
    fn channel(&mut self) -> Result<u8, ParseError> {
        self.int(0u8, AXES as u8 - 1)
    }
    /// 1..=MAX_CHUNK remaining floats, each finite.
    fn floats<const N: usize>(&mut self) -> Result<Vec<f32, N>, ParseError> {
        let mut out = Vec::new();
        while let Some((i, w)) = self.next_word() {
            let x: f32 = w.parse().map_err(|_| ParseError::Invalid { index: i })?;
            let x = check_float(i, x, f32::MIN, f32::MAX)?;
            out.push(x).map_err(|_| ParseError::TooMany { index: i })?;
        }
        if out.is_empty() {
            return Err(ParseError::Missing { index: self.index });
        }
        Ok(out)
    }
    fn end(mut self) -> Result<(), ParseError> {
        match self.next_word() {
            None => Ok(()),
            Some((index, _)) => Err(ParseError::TooMany { index }),
        }
    }
}

fn check_float(index: u8, x: f32, lo: f32, hi: f32) -> Result<f32, ParseError> {
    if !x.is_finite() {
        Err(ParseError::Invalid { index })
    } else if x < lo || x > hi {
        Err(ParseError::OutOfRange { index })
    } else {
        Ok(x)
    }
}

fn parse_axes(w: &str) -> Option<AxisSet> {
    if w == "all" {
        return Some(AxisSet::ALL);
    }
    if w.is_empty() || w.len() > AXES {
        return None;
    }
    let mut mask = 0u8;
    for b in w.bytes() {
        let d = b.checked_sub(b'0').filter(|&d| (d as usize) < AXES)?;
        if mask & (1 << d) != 0 {
            return None;
        }
        mask |= 1 << d;
    }
    Some(AxisSet(mask))
}

/// Bounds that no valid command exceeds (the application checks the configured limits).
const VOLUME_MAX: f32 = 1.0e6;
const FLOW_MAX: f32 = 1.0e4;
const ACCEL_MAX: f32 = 1.0e6;
const PRESSURE_MAX: f32 = 1.0e4;

/// Parse one command line (without its terminator; a trailing `\r` is allowed).
pub fn parse(line: &[u8]) -> Result<Command, ParseError> {
    if line.len() > MAX_LINE {
        return Err(ParseError::TooLong);
    }
    let line = core::str::from_utf8(line).map_err(|_| ParseError::NotAscii)?;
    if !line.is_ascii() {
        return Err(ParseError::NotAscii);
    }
    let mut w = Words {
        it: line.split_ascii_whitespace(),
        index: 0,
    };
    let (_, name) = w.next_word().ok_or(ParseError::Empty)?;
    let cmd = match name {
        "move" => Command::Move {
            axes: w.axes()?,
            volume: w.float(-VOLUME_MAX, VOLUME_MAX)?,
            flow: w.opt_float(f32::MIN_POSITIVE, FLOW_MAX)?,
            accel: w.opt_float(f32::MIN_POSITIVE, ACCEL_MAX)?,
        },
        "run" => {
            let axes = w.axes()?;
            let v_low = w.float(0.0, VOLUME_MAX)?;
            let v_high = w.float(0.0, VOLUME_MAX)?;
            if v_high <= v_low {
                return Err(ParseError::OutOfRange { index: 3 });
            }
            let cycles = w.int(1u16, u16::MAX)?;
            let dwell_ms = w.int(0u32, 3_600_000)?;
            let first = w.index;
            let flows = w.floats::<MAX_FLOWS>()?;
            for (k, &f) in flows.iter().enumerate() {
                check_float(first + k as u8, f, f32::MIN_POSITIVE, FLOW_MAX)?;
            }
            Command::Run(ProtocolSpec {
                axes,
                v_low,
                v_high,
                cycles,
                dwell_ms,
                flows,
            })
        }
        "stop" => Command::Stop,
        "clear" => Command::Clear,
        "zero" => Command::Zero,
        "status" => Command::Status,
        "limit" => Command::Limit {
            axes: w.axes()?,
            p_max_kpa: w.float(f32::MIN_POSITIVE, PRESSURE_MAX)?,
            capacity_mm3: w.float(f32::MIN_POSITIVE, VOLUME_MAX)?,
        },
        "origin" => Command::Origin {
            axes: w.axes()?,
            volume: w.opt_float(-VOLUME_MAX, VOLUME_MAX)?.unwrap_or(0.0),
        },
        "model" => {
            let ch = w.channel()?;
            let (i, verb) = w.word()?;
            let cmd = match verb {
                "begin" => ModelCmd::Begin {
                    n: w.int(0u8, model_core::poly::MAX_DEG as u8)?,
                    m: w.int(0u8, model_core::poly::MAX_DEG as u8)?,
                    p: w.int(0u8, model_core::poly::MAX_AR as u8)?,
                    scaling: [
                        w.float(-VOLUME_MAX, VOLUME_MAX)?,
                        w.float(f32::MIN_POSITIVE, VOLUME_MAX)?,
                        w.float(-FLOW_MAX, FLOW_MAX)?,
                        w.float(f32::MIN_POSITIVE, FLOW_MAX)?,
                    ],
                },
                "coef" => ModelCmd::Coef {
                    start: w.int(0u8, model_core::poly::MAX_TERMS as u8 - 1)?,
                    values: w.floats()?,
                },
                "ar" => ModelCmd::Ar {
                    start: w.int(0u8, 2 * model_core::poly::MAX_AR as u8 - 1)?,
                    values: w.floats()?,
                },
                "effect" => {
                    let (j, name) = w.word()?;
                    let kind =
                        EffectKind::from_name(name).ok_or(ParseError::Invalid { index: j })?;
                    let params: Vec<f32, MAX_EFFECT_PARAMS> = w.floats()?;
                    if params.len() < kind.params() {
                        return Err(ParseError::Missing {
                            index: j + 1 + params.len() as u8,
                        });
                    }
                    if params.len() > kind.params() {
                        return Err(ParseError::TooMany {
                            index: j + 1 + kind.params() as u8,
                        });
                    }
                    w.end()?;
                    return Ok(Command::ModelEffect { ch, kind, params });
                }
                "commit" => ModelCmd::Commit,
                "default" => ModelCmd::Default,
                "read" => ModelCmd::Read(match w.next_word() {
                    None => ReadPart::Header,
                    Some((_, "coef")) => ReadPart::Coef {
                        start: w.int(0u8, model_core::poly::MAX_TERMS as u8 - 1)?,
                    },
                    Some((_, "ar")) => ReadPart::Ar {
                        start: w.int(0u8, 2 * model_core::poly::MAX_AR as u8 - 1)?,
                    },
                    Some((_, "crc")) => ReadPart::Crc,
                    Some((_, "effect")) => ReadPart::Effect {
                        index: w.int(0u8, MAX_EFFECTS as u8 - 1)?,
                    },
                    Some((j, _)) => return Err(ParseError::Invalid { index: j }),
                }),
                _ => return Err(ParseError::Invalid { index: i }),
            };
            Command::Model { ch, cmd }
        }
        "checksum" => Command::Checksum {
            require: match w.next_word() {
                None => None,
                Some((_, "require")) => Some(true),
                Some((_, "optional")) => Some(false),
                Some((i, _)) => return Err(ParseError::Invalid { index: i }),
            },
        },
        "telemetry" => Command::Telemetry {
            on: match w.next_word() {
                None => None,
                Some((_, "on")) => Some(true),
                Some((_, "off")) => Some(false),
                Some((i, _)) => return Err(ParseError::Invalid { index: i }),
            },
        },
        "rls" => {
            let ch = w.channel()?;
            let (i, verb) = w.word()?;
            let lambda = match verb {
                "on" => Some(w.opt_float(0.5, 1.0)?),
                "off" => None,
                _ => return Err(ParseError::Invalid { index: i }),
            };
            Command::Rls { ch, lambda }
        }
        _ => return Err(ParseError::UnknownCommand),
    };
    w.end()?;
    Ok(cmd)
}

/// CRC-8/SMBus (polynomial 0x07, initial value 0, no reflection) of a command.
const CRC8: crc::Crc<u8> = crc::Crc::<u8>::new(&crc::CRC_8_SMBUS);

/// Length of the `*LLCC ` prefix of a checksummed line.
pub const CHECKSUM_PREFIX: usize = 6;

fn hex_digit(b: u8) -> Option<u8> {
    match b {
        b'0'..=b'9' => Some(b - b'0'),
        b'A'..=b'F' => Some(b - b'A' + 10),
        _ => None,
    }
}

fn hex_byte(hi: u8, lo: u8) -> Option<u8> {
    Some(hex_digit(hi)? << 4 | hex_digit(lo)?)
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

/// The `*LLCC` prefix for `command` (length mod 256 and CRC-8, upper-case hex), without the
/// space that follows it.
pub fn checksum_prefix(command: &[u8]) -> [u8; 5] {
    let len = command.len() as u8;
    let crc = CRC8.checksum(command);
    [
        b'*',
        HEX[(len >> 4) as usize],
        HEX[(len & 15) as usize],
        HEX[(crc >> 4) as usize],
        HEX[(crc & 15) as usize],
    ]
}

/// Write `command` as a checksummed line, `*LLCC <command>` (no terminator): what a host sends
/// so that any single corrupted byte is refused (see the module docs). `Err` if the command
/// holds `*`, `\r` or `\n`, or the line would be longer than [`MAX_LINE`].
pub fn write_checksummed(command: &str, out: &mut impl fmt::Write) -> fmt::Result {
    let bytes = command.as_bytes();
    if bytes.iter().any(|b| matches!(b, b'*' | b'\r' | b'\n'))
        || bytes.len() + CHECKSUM_PREFIX > MAX_LINE
    {
        return Err(fmt::Error);
    }
    let prefix = checksum_prefix(bytes);
    for &b in &prefix {
        out.write_char(b as char)?;
    }
    out.write_char(' ')?;
    out.write_str(command)
}

/// The one command obeyed whatever its framing ([`LinkState::check`]).
const STOP: &[u8] = b"stop";

/// Checksum policy and state of one command stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LinkState {
    /// Every line must carry a checksum (`checksum require`, the default).
    pub require: bool,
    /// The previous line failed its checksum: this one must carry one.
    after_bad: bool,
}

impl Default for LinkState {
    /// The state at boot: a checksum is required on every line but `stop`, so no line damaged
    /// on the wire (the UART has no parity) can execute anything else.
    fn default() -> Self {
        Self {
            require: true,
            after_bad: false,
        }
    }
}

impl LinkState {
    /// Check one received line (terminator removed, a trailing `\r` allowed) against the
    /// checksum rules and return the command text to parse.
    pub fn check<'a>(&mut self, line: &'a [u8]) -> Result<&'a [u8], ParseError> {
        let line = line.strip_suffix(b"\r").unwrap_or(line);
        // `stop` is always obeyed: plain in `checksum require` mode, after a failed check, or
        // behind a damaged prefix. Stopping is safe whatever the line was meant to be, and a
        // host (or a person at a terminal) that needs it must not be refused.
        if line == STOP || line.get(CHECKSUM_PREFIX..) == Some(STOP) && line[0] == b'*' {
            self.after_bad = false;
            return Ok(STOP);
        }
        let after_bad = core::mem::take(&mut self.after_bad);
        if !line.contains(&b'*') {
            if self.require || after_bad {
                return Err(ParseError::ChecksumRequired);
            }
            return Ok(line);
        }
        let verified = (|| {
            let (prefix, command) = line.split_at_checked(CHECKSUM_PREFIX)?;
            let [b'*', l1, l2, c1, c2, b' '] = *prefix else {
                return None;
            };
            let ok = hex_byte(l1, l2)? == command.len() as u8
                && hex_byte(c1, c2)? == CRC8.checksum(command);
            ok.then_some(command)
        })();
        verified.ok_or_else(|| {
            self.after_bad = true;
            ParseError::BadChecksum
        })
    }
}

/// A complete line from the serial port.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RawLine<'a> {
    /// The line's bytes (terminator and `\r` removed).
    Ok(&'a [u8]),
    /// Longer than [`MAX_LINE`].
    TooLong,
    /// A receive error was reported while it arrived.
    Corrupt,
}

impl<'a> RawLine<'a> {
    /// The command in the line: checksum rules ([`LinkState::check`]), then [`parse`].
    pub fn command(self, link: &mut LinkState) -> Result<Command, ParseError> {
        match self {
            RawLine::Ok(bytes) => parse(link.check(bytes)?),
            RawLine::TooLong => Err(ParseError::TooLong),
            RawLine::Corrupt => Err(ParseError::LineCorrupt),
        }
    }
}

/// Assembles command lines from serial bytes: `\n` ends a line, `\r` is dropped, an
/// over-long line is reported once (as [`RawLine::TooLong`]) when its terminator arrives, and a
/// line during which the port reported a receive error ([`error`](Self::error)) is reported as
/// [`RawLine::Corrupt`].
#[derive(Debug, Default)]
pub struct LineAssembler {
    buf: Vec<u8, MAX_LINE>,
    overflow: bool,
    corrupt: bool,
    /// The last call returned a line: clear before the next byte.
    done: bool,
}

impl LineAssembler {
    /// Empty.
    pub const fn new() -> Self {
        Self {
            buf: Vec::new(),
            overflow: false,
            corrupt: false,
            done: false,
        }
    }

    /// A receive error: the line being received (up to its `\n`) is corrupt.
    pub fn error(&mut self) {
        self.start();
        self.corrupt = true;
    }

    /// Whether part of a line has been received (bytes, or an error, since the last line ended).
    pub fn in_progress(&self) -> bool {
        !self.done && (!self.buf.is_empty() || self.overflow || self.corrupt)
    }

    fn start(&mut self) {
        if core::mem::take(&mut self.done) {
            self.buf.clear();
            self.overflow = false;
            self.corrupt = false;
        }
    }

    /// Feed one byte; returns the finished line at a `\n`.
    pub fn push(&mut self, b: u8) -> Option<RawLine<'_>> {
        self.start();
        match b {
            b'\n' => {
                self.done = true;
                Some(if self.corrupt {
                    RawLine::Corrupt
                } else if self.overflow {
                    RawLine::TooLong
                } else {
                    RawLine::Ok(&self.buf)
                })
            }
            b'\r' => None,
            _ => {
                if self.buf.push(b).is_err() {
                    self.overflow = true;
                }
                None
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn p(s: &str) -> Result<Command, ParseError> {
        parse(s.as_bytes())
    }

    #[test]
    fn parses_every_command() {
        assert_eq!(
            p("move 0 100"),
            Ok(Command::Move {
                axes: AxisSet(1),
                volume: 100.0,
                flow: None,
                accel: None
            })
        );
        assert_eq!(
            p(" move all 5.5 20 1e3\r"),
            Ok(Command::Move {
                axes: AxisSet::ALL,
                volume: 5.5,
                flow: Some(20.0),
                accel: Some(1000.0)
            })
        );
        let run = p("run 02 0 550 20 500 20 40 60 80 100").unwrap();
        match run {
            Command::Run(s) => {
                assert_eq!(s.axes, AxisSet(0b101));
                assert_eq!(
                    (s.v_low, s.v_high, s.cycles, s.dwell_ms),
                    (0.0, 550.0, 20, 500)
                );
                assert_eq!(&s.flows[..], &[20.0, 40.0, 60.0, 80.0, 100.0]);
            }
            other => panic!("{other:?}"),
        }
        for (s, c) in [
            ("stop", Command::Stop),
            ("clear", Command::Clear),
            ("zero", Command::Zero),
            ("status", Command::Status),
        ] {
            assert_eq!(p(s), Ok(c));
        }
        assert_eq!(
            p("limit 1 60 450"),
            Ok(Command::Limit {
                axes: AxisSet(2),
                p_max_kpa: 60.0,
                capacity_mm3: 450.0
            })
        );
        assert_eq!(
            p("origin 12"),
            Ok(Command::Origin {
                axes: AxisSet(6),
                volume: 0.0
            })
        );
        assert_eq!(
            p("model 2 begin 3 2 0 275 275 0 100"),
            Ok(Command::Model {
                ch: 2,
                cmd: ModelCmd::Begin {
                    n: 3,
                    m: 2,
                    p: 0,
                    scaling: [275.0, 275.0, 0.0, 100.0]
                }
            })
        );
        match p("model 0 coef 8 1.5 -2e-3").unwrap() {
            Command::Model {
                ch: 0,
                cmd: ModelCmd::Coef { start: 8, values },
            } => assert_eq!(&values[..], &[1.5, -2e-3]),
            other => panic!("{other:?}"),
        }
        for (s, part) in [
            ("model 1 read", ReadPart::Header),
            ("model 1 read coef 63", ReadPart::Coef { start: 63 }),
            ("model 1 read ar 9", ReadPart::Ar { start: 9 }),
            ("model 1 read crc", ReadPart::Crc),
        ] {
            assert_eq!(
                p(s),
                Ok(Command::Model {
                    ch: 1,
                    cmd: ModelCmd::Read(part)
                })
            );
        }
        assert_eq!(
            p("rls 1 on"),
            Ok(Command::Rls {
                ch: 1,
                lambda: Some(None)
            })
        );
        assert_eq!(
            p("rls 1 on 0.99"),
            Ok(Command::Rls {
                ch: 1,
                lambda: Some(Some(0.99))
            })
        );
        assert_eq!(
            p("rls 1 off"),
            Ok(Command::Rls {
                ch: 1,
                lambda: None
            })
        );
    }

    #[test]
    fn names_the_bad_argument() {
        assert_eq!(p(""), Err(ParseError::Empty));
        assert_eq!(p("   "), Err(ParseError::Empty));
        assert_eq!(p("jump 0 1"), Err(ParseError::UnknownCommand));
        assert_eq!(p("move"), Err(ParseError::Missing { index: 1 }));
        assert_eq!(p("move 3 10"), Err(ParseError::Invalid { index: 1 }));
        assert_eq!(p("move 00 10"), Err(ParseError::Invalid { index: 1 }));
        assert_eq!(p("move 0 ten"), Err(ParseError::Invalid { index: 2 }));
        assert_eq!(p("move 0 NaN"), Err(ParseError::Invalid { index: 2 }));
        assert_eq!(p("move 0 inf"), Err(ParseError::Invalid { index: 2 }));
        assert_eq!(p("move 0 10 -5"), Err(ParseError::OutOfRange { index: 3 }));
        assert_eq!(p("move 0 10 5 5 5"), Err(ParseError::TooMany { index: 5 }));
        assert_eq!(
            p("run 0 100 50 1 0 10"),
            Err(ParseError::OutOfRange { index: 3 })
        );
        assert_eq!(
            p("run 0 0 50 0 0 10"),
            Err(ParseError::OutOfRange { index: 4 })
        );
        assert_eq!(p("run 0 0 50 1 0"), Err(ParseError::Missing { index: 6 }));
        assert_eq!(
            p("run 0 0 50 1 0 1 2 3 4 5 6 7 8 9"),
            Err(ParseError::TooMany { index: 14 })
        );
        assert_eq!(
            p("run 0 0 50 1 0 10 0"),
            Err(ParseError::OutOfRange { index: 7 })
        );
        assert_eq!(
            p("model 3 commit"),
            Err(ParseError::OutOfRange { index: 1 })
        );
        assert_eq!(
            p("model 0 begin 8 2 0 1 1 0 1"),
            Err(ParseError::OutOfRange { index: 3 })
        );
        assert_eq!(
            p("model 0 begin 3 2 0 1 0 0 1"),
            Err(ParseError::OutOfRange { index: 7 })
        );
        assert_eq!(p("model 0 frob"), Err(ParseError::Invalid { index: 2 }));
        match p("model 2 effect hysteresis 8 0.4 -1e-2").unwrap() {
            Command::ModelEffect {
                ch: 2,
                kind,
                params,
            } => {
                assert_eq!(kind, EffectKind::Hysteresis);
                assert_eq!(params.as_slice(), &[8.0, 0.4, -1e-2]);
            }
            other => panic!("{other:?}"),
        }
        assert_eq!(
            p("model 0 read effect 3"),
            Ok(Command::Model {
                ch: 0,
                cmd: ModelCmd::Read(ReadPart::Effect { index: 3 })
            })
        );
        // Unknown (or clock-tied) name, too few and too many parameters, a non-finite one.
        assert_eq!(
            p("model 0 effect ripple 1"),
            Err(ParseError::Invalid { index: 3 })
        );
        assert_eq!(
            p("model 0 effect hysteresis 8 0.4"),
            Err(ParseError::Missing { index: 6 })
        );
        assert_eq!(
            p("model 0 effect sensor_lag 0.1 0.2"),
            Err(ParseError::TooMany { index: 5 })
        );
        assert_eq!(
            p("model 0 effect sensor_lag"),
            Err(ParseError::Missing { index: 4 })
        );
        assert!(p("model 0 effect leak nan").is_err());
        assert_eq!(
            p("model 0 read effect 4"),
            Err(ParseError::OutOfRange { index: 4 })
        );
        assert_eq!(
            p("model 0 read coef 64"),
            Err(ParseError::OutOfRange { index: 4 })
        );
        assert_eq!(
            p("model 0 read ar 10"),
            Err(ParseError::OutOfRange { index: 4 })
        );
        assert_eq!(
            p("model 0 read ar -1"),
            Err(ParseError::Invalid { index: 4 })
        );
        assert_eq!(
            p("model 0 read coef"),
            Err(ParseError::Missing { index: 4 })
        );
        assert_eq!(
            p("model 0 read frob 1"),
            Err(ParseError::Invalid { index: 3 })
        );
        assert_eq!(
            p("model 0 read coef 1 2"),
            Err(ParseError::TooMany { index: 5 })
        );
        assert_eq!(p("model 0 read 1"), Err(ParseError::Invalid { index: 3 }));
        assert_eq!(p("rls 0 maybe"), Err(ParseError::Invalid { index: 2 }));
        assert_eq!(p("status now"), Err(ParseError::TooMany { index: 1 }));
        assert_eq!(parse(&[b'm', 0xff]), Err(ParseError::NotAscii));
        assert_eq!(parse(&[b'a'; MAX_LINE + 1]), Err(ParseError::TooLong));
    }

    /// Feed bytes through an assembler and the checksum rules; every line's outcome.
    fn lines(bytes: &[u8], link: &mut LinkState) -> std::vec::Vec<Result<Command, ParseError>> {
        let mut a = LineAssembler::new();
        bytes
            .iter()
            .filter_map(|&b| a.push(b).map(|raw| raw.command(link)))
            .collect()
    }

    /// A link after `checksum optional`: plain lines accepted.
    fn optional() -> LinkState {
        LinkState {
            require: false,
            ..LinkState::default()
        }
    }

    #[test]
    fn assembler_splits_lines_and_reports_overflow_once() {
        let mut link = optional();
        assert_eq!(
            lines(b"stop\r\nzero\n", &mut link),
            [Ok(Command::Stop), Ok(Command::Zero)]
        );
        let mut a = LineAssembler::new();
        for _ in 0..1000 {
            assert_eq!(a.push(b'x'), None);
        }
        assert_eq!(a.push(b'\n'), Some(RawLine::TooLong));
        for &b in b"status" {
            a.push(b);
        }
        assert_eq!(
            a.push(b'\n').map(|r| r.command(&mut link)),
            Some(Ok(Command::Status))
        );
    }

    #[test]
    fn a_receive_error_rejects_the_line_it_hit() {
        let mut a = LineAssembler::new();
        let mut link = LinkState::default();
        for &b in b"move 0 1" {
            a.push(b);
        }
        a.error();
        for &b in b"2.5" {
            a.push(b);
        }
        assert_eq!(a.push(b'\n'), Some(RawLine::Corrupt));
        assert_eq!(
            RawLine::Corrupt.command(&mut link),
            Err(ParseError::LineCorrupt)
        );
        // The next line is clean again; an error between lines rejects the next one.
        for &b in b"stop" {
            a.push(b);
        }
        assert_eq!(a.push(b'\n'), Some(RawLine::Ok(b"stop")));
        a.error();
        for &b in b"zero" {
            a.push(b);
        }
        assert_eq!(a.push(b'\n'), Some(RawLine::Corrupt));
    }

    #[test]
    fn checksummed_lines_by_hand() {
        // The prefix by an independent bitwise CRC; the README's example line.
        fn crc8(bytes: &[u8]) -> u8 {
            let mut c = 0u8;
            for &b in bytes {
                c ^= b;
                for _ in 0..8 {
                    c = if c & 0x80 != 0 {
                        (c << 1) ^ 0x07
                    } else {
                        c << 1
                    };
                }
            }
            c
        }
        let mut s = std::string::String::new();
        write_checksummed("stop", &mut s).unwrap();
        assert_eq!(s, std::format!("*04{:02X} stop", crc8(b"stop")));
        assert_eq!(CRC8.checksum(b"123456789"), 0xF4, "CRC-8/SMBus check value");
        let mut readme = std::string::String::new();
        write_checksummed("move 0 12.5", &mut readme).unwrap();
        assert_eq!(readme, "*0BE1 move 0 12.5");
        // At boot a checksum is required.
        let mut link = LinkState::default();
        assert_eq!(link.check(b"zero"), Err(ParseError::ChecksumRequired));
        assert_eq!(link.check(b"*0429 zero"), Ok(&b"zero"[..]));
        // With checksums optional, after a failed check the next line needs a checksum; then
        // plain lines pass again.
        link.require = false;
        assert_eq!(link.check(s.as_bytes()), Ok(&b"stop"[..]));
        assert_eq!(link.check(b"*04ZZ zero"), Err(ParseError::BadChecksum));
        assert_eq!(link.check(b"zero"), Err(ParseError::ChecksumRequired));
        assert_eq!(link.check(b"zero"), Ok(&b"zero"[..]));
        link.require = true;
        assert_eq!(link.check(b"zero"), Err(ParseError::ChecksumRequired));
        assert_eq!(link.check(s.as_bytes()), Ok(&b"stop"[..]));
        // `stop` is obeyed in any form: plain while checksums are required, after a failed
        // check, and behind a damaged prefix.
        assert_eq!(link.check(b"stop"), Ok(&b"stop"[..]));
        assert_eq!(link.check(b"*04ZZ zero"), Err(ParseError::BadChecksum));
        assert_eq!(link.check(b"stop\r"), Ok(&b"stop"[..]));
        assert_eq!(link.check(b"*04ZZ stop"), Ok(&b"stop"[..]));
        assert_eq!(link.check(b"*05AB stopp"), Err(ParseError::BadChecksum));
        // Lower-case hex is not the checksum's form.
        assert_eq!(
            link.check(b"*0be1 move 0 12.5"),
            Err(ParseError::BadChecksum)
        );
        assert!(write_checksummed("a*b", &mut std::string::String::new()).is_err());
        assert_eq!(
            p("checksum require"),
            Ok(Command::Checksum {
                require: Some(true)
            })
        );
        assert_eq!(
            p("checksum optional"),
            Ok(Command::Checksum {
                require: Some(false)
            })
        );
        assert_eq!(p("checksum"), Ok(Command::Checksum { require: None }));
        assert_eq!(p("checksum maybe"), Err(ParseError::Invalid { index: 1 }));
    }

    #[test]
    fn telemetry_switch() {
        let p = |s: &str| parse(s.as_bytes());
        assert_eq!(p("telemetry on"), Ok(Command::Telemetry { on: Some(true) }));
        assert_eq!(
            p("telemetry off"),
            Ok(Command::Telemetry { on: Some(false) })
        );
        assert_eq!(p("telemetry"), Ok(Command::Telemetry { on: None }));
        assert_eq!(p("telemetry up"), Err(ParseError::Invalid { index: 1 }));
        assert_eq!(p("telemetry on x"), Err(ParseError::TooMany { index: 2 }));
    }

    /// Render a command back into a line (test oracle: the documented grammar).
    fn render(c: &Command) -> std::string::String {
        use std::fmt::Write as _;
        let axes = |a: AxisSet| {
            a.iter()
                .map(|i| char::from(b'0' + i as u8))
                .collect::<std::string::String>()
        };
        let mut s = std::string::String::new();
        match c {
            Command::Move {
                axes: a,
                volume,
                flow,
                accel,
            } => {
                write!(s, "move {} {volume:?}", axes(*a)).unwrap();
                if let Some(f) = flow {
                    write!(s, " {f:?}").unwrap();
                    if let Some(x) = accel {
                        write!(s, " {x:?}").unwrap();
                    }
                }
            }
            Command::Limit {
                axes: a,
                p_max_kpa,
                capacity_mm3,
            } => write!(s, "limit {} {p_max_kpa:?} {capacity_mm3:?}", axes(*a)).unwrap(),
            Command::Run(r) => {
                write!(
                    s,
                    "run {} {:?} {:?} {} {}",
                    axes(r.axes),
                    r.v_low,
                    r.v_high,
                    r.cycles,
                    r.dwell_ms
                )
                .unwrap();
                for f in &r.flows {
                    write!(s, " {f:?}").unwrap();
                }
            }
            Command::Stop => s.push_str("stop"),
            Command::Clear => s.push_str("clear"),
            Command::Zero => s.push_str("zero"),
            Command::Status => s.push_str("status"),
            Command::Telemetry { on } => s.push_str(match on {
                None => "telemetry",
                Some(true) => "telemetry on",
                Some(false) => "telemetry off",
            }),
            Command::Checksum { require } => s.push_str(match require {
                None => "checksum",
                Some(true) => "checksum require",
                Some(false) => "checksum optional",
            }),
            Command::Origin { axes: a, volume } => {
                write!(s, "origin {} {volume:?}", axes(*a)).unwrap()
            }
            Command::Rls { ch, lambda } => match lambda {
                None => write!(s, "rls {ch} off").unwrap(),
                Some(None) => write!(s, "rls {ch} on").unwrap(),
                Some(Some(l)) => write!(s, "rls {ch} on {l:?}").unwrap(),
            },
            _ => unreachable!(),
        }
        s
    }

    /// Any command `render` knows, with random arguments.
    fn any_command() -> impl Strategy<Value = Command> {
        let mv = (
            axes(),
            0.0f32..1000.0,
            0.01f32..400.0,
            0.1f32..10_000.0,
            0usize..3,
        )
            .prop_map(|(a, volume, flow, accel, extras)| Command::Move {
                axes: a,
                volume,
                flow: (extras >= 1).then_some(flow),
                accel: (extras >= 2).then_some(accel),
            });
        let run = (
            axes(),
            0.0f32..200.0,
            0.1f32..400.0,
            1u16..100,
            0u32..10_000,
            proptest::collection::vec(0.5f32..400.0, 1..=8),
        )
            .prop_map(|(a, lo, span, cycles, dwell, flows)| {
                Command::Run(ProtocolSpec {
                    axes: a,
                    v_low: lo,
                    v_high: lo + span,
                    cycles,
                    dwell_ms: dwell,
                    flows: Vec::from_slice(&flows).unwrap(),
                })
            });
        let limit = (axes(), 1.0f32..200.0, 1.0f32..1000.0).prop_map(|(a, p, c)| Command::Limit {
            axes: a,
            p_max_kpa: p,
            capacity_mm3: c,
        });
        let origin =
            (axes(), 0.0f32..550.0).prop_map(|(a, v)| Command::Origin { axes: a, volume: v });
        let rls = (
            0u8..3,
            proptest::option::of(proptest::option::of(0.5f32..1.0)),
        )
            .prop_map(|(ch, lambda)| Command::Rls { ch, lambda });
        prop_oneof![
            mv,
            run,
            limit,
            origin,
            rls,
            Just(Command::Stop),
            Just(Command::Clear),
            Just(Command::Zero),
            Just(Command::Status),
            Just(Command::Telemetry { on: Some(true) }),
            Just(Command::Telemetry { on: None }),
            Just(Command::Checksum {
                require: Some(false)
            }),
            Just(Command::Checksum { require: None }),
        ]
    }

    /// Every single-byte corruption of `line` (without its terminator): each drop, each
    /// duplication, and each replacement by every other byte value.
    fn corruptions(line: &[u8]) -> impl Iterator<Item = std::vec::Vec<u8>> + '_ {
        let n = line.len();
        let drops = (0..n).map(move |i| [&line[..i], &line[i + 1..]].concat());
        let dups = (0..n).map(move |i| [&line[..=i], &line[i..]].concat());
        let flips = (0..n).flat_map(move |i| {
            (0..=255u8).filter(move |&b| b != line[i]).map(move |b| {
                let mut v = line.to_vec();
                v[i] = b;
                v
            })
        });
        drops.chain(dups).chain(flips)
    }

    fn axes() -> impl Strategy<Value = AxisSet> {
        (1u8..8).prop_map(AxisSet)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(256))]

        #[test]
        fn never_panics_on_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..260)) {
            let _ = parse(&bytes);
            let mut link = LinkState::default();
            let _ = lines(&bytes, &mut link);
            let _ = link.check(&bytes);
        }

        #[test]
        fn never_panics_on_wordy_lines(
            words in proptest::collection::vec(
                prop_oneof![
                    Just("move".to_string()), Just("run".to_string()), Just("model".to_string()),
                    Just("rls".to_string()), Just("limit".to_string()), Just("all".to_string()),
                    Just("begin".to_string()), Just("coef".to_string()), Just("on".to_string()),
                    Just("read".to_string()), Just("ar".to_string()),
                    "-?[0-9]{1,6}(\\.[0-9]{0,4})?(e-?[0-9]{1,2})?", "[a-z]{1,5}",
                ],
                0..16)
        ) {
            let line = words.join(" ");
            let _ = parse(line.as_bytes());
        }

        /// `model <ch> effect …` with random names and numbers: never panics; an accepted line
        /// names a known effect with exactly its number of finite parameters.
        #[test]
        fn never_panics_on_effect_lines(
            name in prop_oneof![
                Just("hysteresis".to_string()), Just("sensor_lag".to_string()),
                Just("pump_ripple".to_string()), Just("ripple".to_string()), "[a-z_]{0,12}",
            ],
            nums in proptest::collection::vec(
                prop_oneof!["-?[0-9]{1,4}", "[0-9]{1,3}\\.[0-9]e-?[0-9]", Just("nan".to_string()),
                    Just("inf".to_string()), "\\PC{1,3}"],
                0..5),
        ) {
            let line = format!("model 1 effect {name} {}", nums.join(" "));
            match parse(line.as_bytes()) {
                Ok(Command::ModelEffect { ch: 1, kind, params }) => {
                    prop_assert_eq!(kind.name(), name.as_str());
                    prop_assert_eq!(params.len(), kind.params());
                    prop_assert!(params.iter().all(|x| x.is_finite()));
                }
                Ok(other) => prop_assert!(false, "{line:?} parsed as {other:?}"),
                Err(ParseError::Missing { index } | ParseError::Invalid { index }
                    | ParseError::OutOfRange { index } | ParseError::TooMany { index }) => {
                    prop_assert!((3..=8).contains(&index), "{line:?}: word {index}")
                }
                Err(e) => prop_assert_eq!(e, ParseError::NotAscii, "{:?}", line),
            }
        }

        /// `model <ch> read …` with random tails: never panics; an accepted line is a read of
        /// an index in range, anything else is an `err` naming a word of the line.
        #[test]
        fn never_panics_on_read_forms(
            ch in "[0-4]|-1|x",
            tail in proptest::collection::vec(
                prop_oneof![
                    Just("coef".to_string()), Just("ar".to_string()), Just("read".to_string()),
                    Just("effect".to_string()), "-?[0-9]{1,4}", "[0-9]{1,3}\\.[0-9]", "[a-z]{1,4}", "\\PC{1,3}",
                ],
                0..4),
        ) {
            let line = format!("model {ch} read {}", tail.join(" "));
            match parse(line.as_bytes()) {
                Ok(Command::Model { ch, cmd: ModelCmd::Read(part) }) => {
                    prop_assert!((ch as usize) < AXES);
                    match part {
                        ReadPart::Header | ReadPart::Crc => {}
                        ReadPart::Coef { start } => {
                            prop_assert!((start as usize) < model_core::poly::MAX_TERMS)
                        }
                        ReadPart::Ar { start } => {
                            prop_assert!((start as usize) < 2 * model_core::poly::MAX_AR)
                        }
                        ReadPart::Effect { index } => prop_assert!((index as usize) < MAX_EFFECTS),
                    }
                }
                Ok(other) => prop_assert!(false, "{line:?} parsed as {other:?}"),
                Err(ParseError::Missing { index } | ParseError::Invalid { index }
                    | ParseError::OutOfRange { index } | ParseError::TooMany { index }) => {
                    prop_assert!((1..=5).contains(&index), "{line:?}: word {index}")
                }
                Err(e) => prop_assert_eq!(e, ParseError::NotAscii, "{:?}", line),
            }
        }

        #[test]
        fn valid_moves_round_trip(
            a in axes(), volume in 0.0f32..1000.0, flow in 0.01f32..400.0, accel in 0.1f32..10_000.0,
            extras in 0usize..3,
        ) {
            let c = Command::Move {
                axes: a, volume,
                flow: (extras >= 1).then_some(flow),
                accel: (extras >= 2).then_some(accel),
            };
            prop_assert_eq!(p(&render(&c)), Ok(c));
        }

        #[test]
        fn valid_runs_and_limits_round_trip(
            a in axes(), lo in 0.0f32..200.0, span in 0.1f32..400.0, cycles in 1u16..100,
            dwell in 0u32..10_000, flows in proptest::collection::vec(0.5f32..400.0, 1..=8),
            pmax in 1.0f32..200.0, cap in 1.0f32..1000.0,
        ) {
            let spec = ProtocolSpec {
                axes: a, v_low: lo, v_high: lo + span, cycles, dwell_ms: dwell,
                flows: Vec::from_slice(&flows).unwrap(),
            };
            let c = Command::Run(spec);
            prop_assert_eq!(p(&render(&c)), Ok(c));
            let l = Command::Limit { axes: a, p_max_kpa: pmax, capacity_mm3: cap };
            prop_assert_eq!(p(&render(&l)), Ok(l));
        }

        /// A checksummed line is accepted and parses to the same command; every single-byte
        /// drop, duplication or replacement of it is refused (every line it turns into gets an
        /// `err`), whether the checksum is required or optional.
        #[test]
        fn every_single_byte_corruption_of_a_checksummed_line_is_refused(
            c in any_command(), require in any::<bool>(),
        ) {
            let plain = render(&c);
            let mut line = std::string::String::new();
            write_checksummed(&plain, &mut line).unwrap();
            let fresh = LinkState { require, ..LinkState::default() };
            let mut link = fresh;
            let mut intact = line.clone().into_bytes();
            intact.push(b'\n');
            prop_assert_eq!(lines(&intact, &mut link), [Ok(c.clone())]);
            for mut bad in corruptions(line.as_bytes()) {
                bad.push(b'\n');
                let mut link = fresh;
                for r in lines(&bad, &mut link) {
                    // `stop` is obeyed behind a damaged prefix (stopping is always safe).
                    let safe = c == Command::Stop && r == Ok(Command::Stop);
                    prop_assert!(r.is_err() || safe, "{:?} accepted as {:?}", String::from_utf8_lossy(&bad), r);
                }
            }
        }

        /// At boot every plain line but `stop` is refused as `checksum-required`, the same
        /// command checksummed is accepted, and `stop` passes plain.
        #[test]
        fn a_plain_line_is_refused_at_boot(c in any_command()) {
            let plain = render(&c);
            let mut checked = std::string::String::new();
            write_checksummed(&plain, &mut checked).unwrap();
            let mut link = LinkState::default();
            let want = if c == Command::Stop {
                Ok(Command::Stop)
            } else {
                Err(ParseError::ChecksumRequired)
            };
            prop_assert_eq!(lines(std::format!("{plain}\n").as_bytes(), &mut link), [want]);
            prop_assert_eq!(lines(std::format!("{checked}\n").as_bytes(), &mut link), [Ok(c)]);
        }

        /// Any non-finite number in a numeric position is refused, naming that word.
        #[test]
        fn non_finite_numbers_are_refused(pos in 2usize..4, bad in prop_oneof![Just("nan"), Just("inf"), Just("-inf"), Just("1e39")]) {
            let mut words = ["move", "0", "10", "20"];
            words[pos] = bad;
            prop_assert_eq!(p(&words.join(" ")), Err(ParseError::Invalid { index: pos as u8 }));
        }
    }
}
