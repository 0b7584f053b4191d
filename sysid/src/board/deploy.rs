//! `vfp deploy LINES --port /dev/ttyACM0`: load a model into a board over its serial port with the
//! firmware's command protocol (`firmware::command`), then read it back to confirm.
//!
//! The lines are those printed by `vfp export --format lines` (`model <ch> begin …`, `coef`, `ar`,
//! `effect`, `commit`). Each is checked with the firmware's own parser before anything is sent, sent with
//! `\n`, and must be answered `ok`; the first `err` reply stops the upload and is reported with the
//! line that caused it. Before the upload a `status` command checks that the other end speaks the
//! protocol (stale bytes in the port are skipped).
//!
//! # Read-back
//! After `commit`, each channel is read back with `model <ch> read` (shape and scaling) and
//! `model <ch> read coef <i>` / `model <ch> read ar <i>` (up to 8 values from index i) and
//! `model <ch> read effect <i>` (the chain's effect i in evaluation order, name and parameters),
//! and every value is compared bit for bit (as `f32`) with what was sent; a board that holds more
//! effects than were sent is refused too. A firmware that does not know the
//! `read` verb answers `err …`; the deploy then says plainly that the model is confirmed by the
//! board's acknowledgements only.
//!
//! [`deploy`] works on any `Read + Write` (a serial port, or [`FirmwarePort`]: the firmware's own
//! command handler in memory, for tests and the demo).

use std::collections::VecDeque;
use std::io::{Read, Write};

use firmware::command::{self, Command, ModelCmd};
use firmware::hal::AXES;

use crate::board::capture::CaptureLine;
use crate::board::packets::PacketReader;

/// Everything sent to one channel, and the values it should hold afterwards.
#[derive(Debug, Clone, PartialEq)]
pub struct Upload {
    /// Channel.
    pub ch: u8,
    /// The lines, in order (the last is `commit`).
    pub lines: Vec<String>,
    /// `[n, m, p]`.
    pub shape: [u8; 3],
    /// `[v_offset, v_scale, f_offset, f_scale]`.
    pub scaling: [f32; 4],
    /// Scaled coefficients by index.
    pub coef: Vec<f32>,
    /// Flattened AR coefficients by index.
    pub ar: Vec<f32>,
    /// The effect chain (`model <ch> effect …` lines), in the order sent.
    pub effects: Vec<model_core::chain::Effect>,
}

impl Upload {
    /// The model the board installs on `commit`: the polynomial and its chain, or why the values
    /// do not make one (the firmware's own checks).
    pub fn model(&self) -> Result<firmware::store::Model, model_core::ModelError> {
        use model_core::poly::{PolyModel, Scaling, Shape};
        let [n, m, p] = self.shape;
        let [vo, vs, fo, fs] = self.scaling;
        let pairs: Vec<[f32; 2]> = self.ar.chunks_exact(2).map(|c| [c[0], c[1]]).collect();
        let poly = PolyModel::from_scaled(
            Shape::new(n, m, p)?,
            &self.coef,
            &pairs,
            Scaling::new(vo, vs, fo, fs)?,
        )?;
        let mut chain = model_core::chain::Chain::new();
        for e in &self.effects {
            chain.push(*e)?;
        }
        Ok(firmware::store::Model { poly, chain })
    }
}

/// Why a file's uploads do not make the board's models ([`board_models`]).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{0}")]
pub struct UploadError(pub String);

/// The models a file of uploads installs, by chamber (`None`: the board's boot model), as the
/// board would install them on `commit`.
pub fn board_models(
    uploads: &[Upload],
) -> Result<[Option<firmware::store::Model>; AXES], UploadError> {
    let mut out = [None; AXES];
    for up in uploads {
        let slot = out
            .get_mut(up.ch as usize)
            .ok_or_else(|| UploadError(format!("chamber {}: the board has 0..=2", up.ch)))?;
        *slot = Some(up.model().map_err(|e| {
            UploadError(format!(
                "chamber {}: the board would refuse the model ({e})",
                up.ch
            ))
        })?);
    }
    Ok(out)
}

/// Why a deploy failed.
#[derive(Debug, thiserror::Error)]
pub enum DeployError {
    /// A line of the input is not a valid model command.
    #[error("{source_name}:{line}: {reason}: `{text}`")]
    BadInput {
        /// Input name.
        source_name: String,
        /// 1-based line.
        line: usize,
        /// The text.
        text: String,
        /// Why.
        reason: String,
    },
    /// Opening, reading or writing the port failed.
    #[error("{what}: {source}")]
    Io {
        /// What was being done.
        what: String,
        /// The error.
        source: std::io::Error,
    },
    /// No reply in time.
    #[error("no reply to `{sent}` within the timeout; is the board running vfp-fw and is this its command port?")]
    Timeout {
        /// The line sent.
        sent: String,
    },
    /// The port closed.
    #[error("the port closed while waiting for the reply to `{sent}`")]
    Closed {
        /// The line sent.
        sent: String,
    },
    /// The other end does not answer `status` like the firmware.
    #[error("the board does not speak the vfp-fw protocol: `status` got `{reply}`")]
    NotFirmware {
        /// What came back.
        reply: String,
    },
    /// The board refused a line.
    #[error(
        "channel {ch}: the board refused `{sent}` with `{reply}`; the upload was stopped there"
    )]
    Refused {
        /// Channel.
        ch: u8,
        /// The line.
        sent: String,
        /// The reply.
        reply: String,
    },
    /// A read-back value differs from what was sent.
    #[error("channel {ch}: read-back of {what} gave {got} but {sent} was sent")]
    Mismatch {
        /// Channel.
        ch: u8,
        /// Which value.
        what: String,
        /// Sent.
        sent: String,
        /// Read back.
        got: String,
    },
}

fn bad(source_name: &str, line: usize, text: &str, reason: impl Into<String>) -> DeployError {
    DeployError::BadInput {
        source_name: source_name.into(),
        line,
        text: text.into(),
        reason: reason.into(),
    }
}

/// Reads `vfp export` output into per-channel uploads. `model …` lines are kept; blank lines,
/// `#`/`//` comments and the Rust constants of `--format both` (`pub const …`) are skipped; any
/// other line, a line the firmware's parser refuses, or an upload without `begin`…`commit` is an
/// error naming the line.
pub fn parse_lines(text: &str, source_name: &str) -> Result<Vec<Upload>, DeployError> {
    let mut uploads = Uploads::default();
    let mut last_line = 0;
    for (i, raw) in text.lines().enumerate() {
        let no = i + 1;
        last_line = no;
        let t = raw.trim();
        if t.is_empty() || t.starts_with('#') || t.starts_with("//") || t.starts_with("pub const") {
            continue;
        }
        uploads
            .line(t)
            .map_err(|reason| bad(source_name, no, t, reason))?;
    }
    uploads
        .finish()
        .map_err(|(text, reason)| bad(source_name, last_line, &text, reason))
}

/// [`parse_lines`]'s state: the uploads committed so far and the one open (after its `begin`).
/// Each method's error is the reason the line is refused.
#[derive(Default)]
struct Uploads {
    done: Vec<Upload>,
    open: Option<Upload>,
}

impl Uploads {
    /// One `model …` line.
    fn line(&mut self, t: &str) -> Result<(), String> {
        if !t.starts_with("model") {
            return Err("not a `model …` line of `vfp export --format lines`".into());
        }
        let cmd = command::parse(t.as_bytes())
            .map_err(|e| format!("the firmware would refuse it ({e})"))?;
        match cmd {
            Command::ModelEffect { ch, kind, params } => self.effect(t, ch, kind, &params),
            Command::Model { ch, cmd } => self.model(t, ch, cmd),
            _ => Err("not a model command".into()),
        }
    }

    /// The open upload, if it is channel `ch`'s.
    fn open_for(&mut self, ch: u8) -> Result<&mut Upload, String> {
        self.open
            .as_mut()
            .filter(|u| u.ch == ch)
            .ok_or_else(|| "no `begin` for this channel before it".into())
    }

    /// `model <ch> effect …`: the board's chain must take it after the effects before it.
    fn effect(
        &mut self,
        t: &str,
        ch: u8,
        kind: model_core::chain::EffectKind,
        params: &[f32],
    ) -> Result<(), String> {
        let up = self.open_for(ch)?;
        let e = model_core::chain::Effect::new(kind, params)
            .map_err(|e| format!("the board would refuse it ({e})"))?;
        let mut chain = model_core::chain::Chain::new();
        for x in up.effects.iter().chain([&e]) {
            chain.push(*x).map_err(|err| {
                format!(
                    "the chain would not take it ({err}: at most {} effects, one of each kind)",
                    model_core::chain::MAX_EFFECTS
                )
            })?;
        }
        up.effects.push(e);
        up.lines.push(t.to_string());
        Ok(())
    }

    /// `model <ch> begin | coef | ar | commit`; `default` and `read` are not exported lines.
    fn model(&mut self, t: &str, ch: u8, cmd: ModelCmd) -> Result<(), String> {
        match cmd {
            ModelCmd::Begin { n, m, p, scaling } => {
                if self.open.is_some() {
                    return Err("`begin` before the previous upload's `commit`".into());
                }
                self.open = Some(Upload {
                    ch,
                    lines: vec![t.to_string()],
                    shape: [n, m, p],
                    scaling,
                    coef: vec![f32::NAN; (n as usize + 1) * (m as usize + 1)],
                    ar: vec![f32::NAN; 2 * p as usize],
                    effects: Vec::new(),
                });
            }
            ModelCmd::Coef { start, ref values } | ModelCmd::Ar { start, ref values } => {
                let is_ar = matches!(cmd, ModelCmd::Ar { .. });
                let up = self.open_for(ch)?;
                let dst = if is_ar { &mut up.ar } else { &mut up.coef };
                let start = start as usize;
                if start + values.len() > dst.len() {
                    return Err(format!(
                        "index past the {} values of the model's shape",
                        dst.len()
                    ));
                }
                dst[start..start + values.len()].copy_from_slice(values);
                up.lines.push(t.to_string());
            }
            ModelCmd::Commit => {
                let mut up = self
                    .open
                    .take()
                    .filter(|u| u.ch == ch)
                    .ok_or("`commit` without `begin`")?;
                if up.coef.iter().chain(&up.ar).any(|x| x.is_nan()) {
                    return Err("`commit` before every coefficient was given".into());
                }
                up.lines.push(t.to_string());
                self.done.push(up);
            }
            ModelCmd::Default => return Err("`model <ch> default` is not an exported model".into()),
            ModelCmd::Read(_) => {
                return Err("`model <ch> read` is not an exported model line".into())
            }
        }
        Ok(())
    }

    /// The committed uploads, or the text and reason of what is missing at the end.
    fn finish(self) -> Result<Vec<Upload>, (String, &'static str)> {
        if let Some(up) = self.open {
            return Err((
                up.lines[0].clone(),
                "upload never committed (`model <ch> commit` missing)",
            ));
        }
        if self.done.is_empty() {
            return Err((
                String::new(),
                "no model lines; pipe in `vfp export LOG --format lines`",
            ));
        }
        Ok(self.done)
    }
}

/// How a channel was confirmed.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(rename_all = "snake_case", tag = "kind")]
pub enum Readback {
    /// Every value read back equals the value sent, bit for bit.
    Verified {
        /// Values compared.
        values: usize,
    },
    /// The firmware has no `model <ch> read`: confirmed by the `ok` replies only.
    Unsupported {
        /// The board's reply to `model <ch> read`.
        reply: String,
    },
}

/// Result of one channel.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct ChannelResult {
    /// Channel.
    pub ch: u8,
    /// Lines sent and acknowledged.
    pub lines_acked: usize,
    /// Read-back.
    pub readback: Readback,
}

/// Line-based exchange over a byte port. The port may also carry the board's binary telemetry
/// (a board left streaming after `telemetry on`): its packets and event lines are split off by
/// [`PacketReader`] and skipped, so a reply is read between them.
struct Link<'a, P> {
    port: &'a mut P,
    reader: PacketReader,
    lines: VecDeque<String>,
    /// Bytes read since the last reply line (packets included).
    unanswered: usize,
}

/// Bytes read without a single reply line after which the device is taken for something else
/// than the firmware: a second of the binary stream at its full rate is about 7.5 KB.
const MAX_UNANSWERED: usize = 64 * 1024;

impl<P: Read + Write> Link<'_, P> {
    fn send(&mut self, line: &str) -> Result<String, DeployError> {
        let io = |e| DeployError::Io {
            what: format!("sending `{line}`"),
            source: e,
        };
        // Every line carries the firmware's checksum prefix (`*LLCC `, length and CRC-8), so a
        // byte lost, doubled or damaged on the wire is refused, never executed.
        let mut framed = String::with_capacity(line.len() + 8);
        command::write_checksummed(line, &mut framed).map_err(|_| DeployError::Io {
            what: format!("adding the checksum to `{line}`"),
            source: std::io::Error::new(std::io::ErrorKind::InvalidInput, "line too long"),
        })?;
        self.port.write_all(framed.as_bytes()).map_err(io)?;
        self.port.write_all(b"\n").map_err(io)?;
        self.port.flush().map_err(io)?;
        self.reply(line)
    }

    fn reply(&mut self, sent: &str) -> Result<String, DeployError> {
        let mut buf = [0u8; 64];
        loop {
            if let Some(line) = self.lines.pop_front() {
                self.unanswered = 0;
                return Ok(line);
            }
            if self.unanswered > MAX_UNANSWERED {
                return Err(DeployError::NotFirmware {
                    reply: format!("{} bytes without a reply line", self.unanswered),
                });
            }
            match self.port.read(&mut buf) {
                Ok(0) => return Err(DeployError::Closed { sent: sent.into() }),
                Ok(n) => {
                    self.unanswered += n;
                    let lines = &mut self.lines;
                    self.reader.feed(&buf[..n], |item| {
                        // Frames, events and damaged packets are the stream's, not replies;
                        // nor is a blank line.
                        if let CaptureLine::Other(text) = item {
                            if !text.trim().is_empty() {
                                lines.push_back(text.trim_end().to_string());
                            }
                        }
                    });
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock
                    ) =>
                {
                    return Err(DeployError::Timeout { sent: sent.into() })
                }
                Err(e) => {
                    return Err(DeployError::Io {
                        what: format!("reading the reply to `{sent}`"),
                        source: e,
                    })
                }
            }
        }
    }
}

/// The CRC-32 the board must report for the model of `up` (`firmware::store::crc`, the chain
/// included), when the values form a valid model.
fn expected_crc(up: &Upload) -> Option<u32> {
    Some(firmware::store::crc(&up.model().ok()?))
}

/// After the values: `model <ch> read crc` must give the CRC-32 of exactly the uploaded model
/// (what the board will keep in flash). A board without the command is not checked.
fn verify_crc<P: Read + Write>(link: &mut Link<'_, P>, up: &Upload) -> Result<(), DeployError> {
    let ch = up.ch;
    let r = link.send(&format!("model {ch} read crc"))?;
    let Some(word) = r
        .strip_prefix("ok ")
        .and_then(|t| t.split_whitespace().next())
    else {
        return Ok(());
    };
    let got = word
        .strip_prefix("0x")
        .and_then(|h| u32::from_str_radix(h, 16).ok());
    match (expected_crc(up), got) {
        (Some(want), Some(got)) if want == got => Ok(()),
        (want, _) => Err(DeployError::Mismatch {
            ch,
            what: "the model's CRC-32".into(),
            sent: want.map_or("a valid model".into(), |w| format!("{w:#010x}")),
            got: r,
        }),
    }
}

/// Parses the `f32` words of a reply after `ok`.
fn reply_floats(reply: &str) -> Option<Vec<f32>> {
    reply
        .strip_prefix("ok")?
        .split_ascii_whitespace()
        .map(|w| w.parse().ok())
        .collect()
}

fn same(a: f32, b: f32) -> bool {
    a.to_bits() == b.to_bits()
}

/// Uploads every channel and reads it back (see the module docs).
pub fn deploy<P: Read + Write>(
    port: &mut P,
    uploads: &[Upload],
) -> Result<Vec<ChannelResult>, DeployError> {
    let mut link = Link {
        port,
        reader: PacketReader::new(),
        lines: VecDeque::new(),
        unanswered: 0,
    };
    // Skip stale lines (at most a few) until the status reply.
    let mut reply = link.send("status")?;
    for _ in 0..8 {
        if reply.starts_with("ok flags") {
            break;
        }
        reply = link.reply("status")?;
    }
    if !reply.starts_with("ok flags") {
        return Err(DeployError::NotFirmware { reply });
    }
    let mut results = Vec::new();
    for up in uploads {
        for l in &up.lines {
            let r = link.send(l)?;
            if r != "ok" && !r.starts_with("ok ") {
                return Err(DeployError::Refused {
                    ch: up.ch,
                    sent: l.clone(),
                    reply: r,
                });
            }
        }
        results.push(ChannelResult {
            ch: up.ch,
            lines_acked: up.lines.len(),
            readback: read_back(&mut link, up)?,
        });
    }
    Ok(results)
}

fn read_back<P: Read + Write>(
    link: &mut Link<'_, P>,
    up: &Upload,
) -> Result<Readback, DeployError> {
    let ch = up.ch;
    let cmd = format!("model {ch} read");
    let r = link.send(&cmd)?;
    if r.starts_with("err") {
        return Ok(Readback::Unsupported { reply: r });
    }
    let mismatch = |what: String, sent: String, got: String| DeployError::Mismatch {
        ch,
        what,
        sent,
        got,
    };
    let head = reply_floats(&r)
        .ok_or_else(|| mismatch("the header".into(), "numbers".into(), r.clone()))?;
    let want: Vec<f32> = up
        .shape
        .iter()
        .map(|&x| x as f32)
        .chain(up.scaling)
        .collect();
    if head.len() != want.len() || !head.iter().zip(&want).all(|(a, b)| same(*a, *b)) {
        return Err(mismatch("shape and scaling".into(), format!("{want:?}"), r));
    }
    let mut values = want.len();
    for (verb, sent) in [("coef", &up.coef), ("ar", &up.ar)] {
        for start in (0..sent.len()).step_by(command::MAX_CHUNK) {
            let c = format!("model {ch} read {verb} {start}");
            let r = link.send(&c)?;
            let got = reply_floats(&r)
                .ok_or_else(|| mismatch(format!("{verb} {start}"), "numbers".into(), r.clone()))?;
            let end = (start + command::MAX_CHUNK).min(sent.len());
            let exp = &sent[start..end];
            if got.len() != exp.len() || !got.iter().zip(exp).all(|(a, b)| same(*a, *b)) {
                return Err(mismatch(
                    format!("{verb} {start}..{end}"),
                    format!("{exp:?}"),
                    r,
                ));
            }
            values += exp.len();
        }
    }
    values += read_back_effects(link, up)?;
    verify_crc(link, up)?;
    Ok(Readback::Verified { values })
}

/// `model <ch> read effect <i>` for every effect sent, and one past them (which must be refused:
/// the board holds no more than was sent); returns the number of values compared (the kind's code
/// and the parameters). The chain is read in evaluation order, which is how [`Upload::model`]
/// orders it.
fn read_back_effects<P: Read + Write>(
    link: &mut Link<'_, P>,
    up: &Upload,
) -> Result<usize, DeployError> {
    let ch = up.ch;
    let want = up.model().map(|m| m.chain).unwrap_or_default();
    let mut values = 0;
    for i in 0..=want.len() {
        let r = link.send(&format!("model {ch} read effect {i}"))?;
        let Some(e) = want.effects().get(i) else {
            if r.starts_with("ok") {
                return Err(DeployError::Mismatch {
                    ch,
                    what: format!("effect {i}"),
                    sent: "no such effect".into(),
                    got: r,
                });
            }
            break;
        };
        let words: Vec<&str> = r.split_ascii_whitespace().collect();
        let got: Option<Vec<f32>> = words
            .get(2..)
            .and_then(|w| w.iter().map(|x| x.parse().ok()).collect());
        let ok = words.first() == Some(&"ok")
            && words.get(1) == Some(&e.kind().name())
            && got.is_some_and(|g| {
                g.len() == e.params().len() && g.iter().zip(e.params()).all(|(a, b)| same(*a, *b))
            });
        if !ok {
            let sent: Vec<String> = e.params().iter().map(|x| format!("{x:e}")).collect();
            return Err(DeployError::Mismatch {
                ch,
                what: format!("effect {i}"),
                sent: format!("{} {}", e.kind().name(), sent.join(" ")),
                got: r,
            });
        }
        values += 1 + e.params().len();
    }
    Ok(values)
}

/// The firmware's own command handler ([`firmware::app::Shared::command_line`]) behind
/// `Read + Write`: bytes written are command lines, replies come back as bytes, `\r\n`-terminated,
/// as from the board's UART. A read with no reply pending reports `TimedOut`, as a serial port
/// with a timeout does. Every line, `model <ch> read …` included, is answered by the firmware.
pub struct FirmwarePort {
    /// The firmware's state and command handler.
    pub shared: firmware::app::Shared,
    /// Time given to the handler, µs.
    pub now_us: u64,
    line: Vec<u8>,
    out: VecDeque<u8>,
}

impl Default for FirmwarePort {
    fn default() -> Self {
        Self::new()
    }
}

impl FirmwarePort {
    /// A freshly booted firmware with the default configuration.
    pub fn new() -> Self {
        Self {
            shared: firmware::app::Shared::new(firmware::app::Config::default()),
            now_us: 0,
            line: Vec::new(),
            out: VecDeque::new(),
        }
    }
}

impl Write for FirmwarePort {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        for &b in buf {
            if b != b'\n' {
                self.line.push(b);
                continue;
            }
            let line = std::mem::take(&mut self.line);
            let mut reply = String::new();
            self.shared.command_line(&line, self.now_us, &mut reply);
            self.out.extend(reply.as_bytes());
            self.out.extend(b"\r\n");
            self.now_us += 1_000;
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Read for FirmwarePort {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.out.is_empty() {
            return Err(std::io::Error::new(
                std::io::ErrorKind::TimedOut,
                "no reply pending",
            ));
        }
        let n = buf.len().min(self.out.len());
        for (d, s) in buf.iter_mut().zip(self.out.drain(..n)) {
            *d = s;
        }
        Ok(n)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const LINES: &str = "model 1 begin 3 2 0 275 275 0 100\n\
        model 1 coef 0 1e0 2e0 3e0 4e0 5e0 6e0 7e0 8e0\n\
        model 1 coef 8 9e0 1e1 1.1e1 -1.2e-3\n\
        model 1 commit\n";

    #[test]
    fn parses_export_lines_and_skips_rust_constants() {
        let text = format!("{LINES}\n// Chamber 1: x\npub const CH1_SHAPE: [u8; 3] = [3, 2, 0];\n");
        let up = parse_lines(&text, "x").unwrap();
        assert_eq!(up.len(), 1);
        assert_eq!(up[0].coef.len(), 12);
        assert_eq!(up[0].coef[11], -1.2e-3);
        assert_eq!(up[0].lines.len(), 4);
    }

    #[test]
    fn names_the_bad_line() {
        let e = parse_lines("model 1 begin 3 2 0 275 275 0 100\nmove 0 10\n", "f.txt").unwrap_err();
        assert!(e.to_string().starts_with("f.txt:2:"), "{e}");
        let e = parse_lines(
            "model 1 begin 3 2 0 275 275 0 100\nmodel 1 commit\n",
            "f.txt",
        )
        .unwrap_err();
        assert!(e.to_string().contains("every coefficient"), "{e}");
        let e = parse_lines("model 1 coef 0 x\n", "f.txt").unwrap_err();
        assert!(e.to_string().contains("f.txt:1"), "{e}");
    }

    #[test]
    fn deploys_into_the_firmware_and_reads_back() {
        let up = parse_lines(LINES, "x").unwrap();
        let mut port = FirmwarePort::new();
        let r = deploy(&mut port, &up).unwrap();
        // Read back by the firmware's own `model <ch> read` handler, every value bit for bit.
        assert_eq!(r[0].readback, Readback::Verified { values: 7 + 12 });
        assert_eq!(r[0].lines_acked, 4);
        // The firmware's installed model holds exactly the values sent.
        let m = port.shared.lock(|s| *s.model(1));
        assert_eq!(m.scaled(), &up[0].coef[..]);
    }

    #[test]
    fn reads_back_ar_coefficients_and_several_channels() {
        let text = "model 0 begin 1 1 2 -2.5e1 1.25e2 3e0 7.5e1\n\
            model 0 coef 0 1e-40 -0e0 3.4028235e38 -1.1754944e-38\n\
            model 0 ar 0 1e-1 -2e-1\n\
            model 0 ar 2 3.3333334e-1 1.0000001e-5\n\
            model 0 commit\n";
        let mut ups = parse_lines(text, "x").unwrap();
        ups.extend(parse_lines(LINES, "x").unwrap());
        let mut port = FirmwarePort::new();
        let r = deploy(&mut port, &ups).unwrap();
        assert_eq!(r[0].readback, Readback::Verified { values: 7 + 4 + 4 });
        assert_eq!(r[1].readback, Readback::Verified { values: 7 + 12 });
        let m = port.shared.lock(|s| *s.model(0));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(m.ar().as_flattened()), bits(&ups[0].ar));
        assert_eq!(bits(m.scaled()), bits(&ups[0].coef));
    }

    /// A board left streaming (`telemetry on`): every read hands a telemetry packet, blank
    /// lines or an event line, then the next reply line.
    struct Streaming {
        board: FirmwarePort,
        reads: u32,
        out: VecDeque<u8>,
    }

    impl Write for Streaming {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.board.write(buf)
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Read for Streaming {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            use firmware::wire::{encode_frame, Packet};
            if !self.out.is_empty() {
                let n = buf.len().min(self.out.len());
                for (d, s) in buf.iter_mut().zip(self.out.drain(..n)) {
                    *d = s;
                }
                return Ok(n);
            }
            self.reads += 1;
            let mut p = Packet::new();
            let frame = firmware::telemetry::Frame {
                seq: self.reads,
                ..Default::default()
            };
            encode_frame(&frame, &mut p);
            let mut out: Vec<u8> = match self.reads % 3 {
                0 => p.to_vec(),
                1 => b"\r\n\n".to_vec(),
                // The event line the firmware writes on its command port at boot.
                _ => b"$E 1200 boot 0 power-on\n".to_vec(),
            };
            // Then one whole reply line, if one is pending: the board writes a line and a
            // packet each whole, never one inside the other.
            let mut byte = [0u8; 1];
            while let Ok(1) = self.board.read(&mut byte) {
                out.push(byte[0]);
                if byte[0] == b'\n' {
                    break;
                }
            }
            self.out.extend(out);
            self.read(buf)
        }
    }

    #[test]
    fn deploys_to_a_board_left_streaming() {
        let text = LINES.replace(
            "model 1 commit",
            "model 1 effect hysteresis 6e0 8e-1 -1.0000001e-1\nmodel 1 commit",
        );
        let up = parse_lines(&text, "x").unwrap();
        let mut port = Streaming {
            board: FirmwarePort::new(),
            reads: 0,
            out: VecDeque::new(),
        };
        let r = deploy(&mut port, &up).unwrap();
        assert_eq!(r[0].readback, Readback::Verified { values: 7 + 12 + 4 });
        // Each reply came after stream content (a packet, blank lines or an event).
        assert!(port.reads >= 10, "{} reads", port.reads);
    }

    #[test]
    fn a_read_back_that_differs_is_reported() {
        // The board acknowledges the lines but holds other values than expected.
        let mut up = parse_lines(LINES, "x").unwrap();
        up[0].coef[9] = 10.000001;
        match deploy(&mut FirmwarePort::new(), &up) {
            Err(DeployError::Mismatch { ch: 1, what, .. }) => assert_eq!(what, "coef 8..12"),
            other => panic!("{other:?}"),
        }
        let mut up = parse_lines(LINES, "x").unwrap();
        up[0].scaling[3] = 100.00001;
        match deploy(&mut FirmwarePort::new(), &up) {
            Err(DeployError::Mismatch { ch: 1, what, .. }) => assert_eq!(what, "shape and scaling"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn deploys_an_effect_chain_and_reads_it_back() {
        // Effects sent out of evaluation order: the board orders them, the read-back follows.
        let text = LINES.replace(
            "model 1 commit",
            "model 1 effect sensor_lag 1.5e-1\nmodel 1 effect hysteresis 6e0 8e-1 -1.0000001e-1\nmodel 1 commit",
        );
        let up = parse_lines(&text, "x").unwrap();
        assert_eq!(up[0].effects.len(), 2);
        let mut port = FirmwarePort::new();
        let r = deploy(&mut port, &up).unwrap();
        // Header 7, coefficients 12, each effect its kind and parameters (1 + 3, 1 + 1).
        assert_eq!(
            r[0].readback,
            Readback::Verified {
                values: 7 + 12 + 4 + 2
            }
        );
        assert_eq!(r[0].lines_acked, 6);
        let chain = port.shared.lock(|s| *s.estimator().chain(1));
        let kinds: Vec<_> = chain.effects().iter().map(|e| e.kind().name()).collect();
        assert_eq!(kinds, ["hysteresis", "sensor_lag"]);
        assert_eq!(
            chain.effects()[0].params()[2].to_bits(),
            (-1.0000001e-1f32).to_bits()
        );
        assert_eq!(chain, up[0].model().unwrap().chain);
    }

    #[test]
    fn effect_lines_the_board_would_refuse_are_named() {
        let dup = LINES.replace(
            "model 1 commit",
            "model 1 effect sensor_lag 1e-1\nmodel 1 effect sensor_lag 2e-1\nmodel 1 commit",
        );
        let e = parse_lines(&dup, "f.txt").unwrap_err();
        assert!(e.to_string().starts_with("f.txt:5:"), "{e}");
        let neg = LINES.replace(
            "model 1 commit",
            "model 1 effect backlash -1e0\nmodel 1 commit",
        );
        let e = parse_lines(&neg, "f.txt").unwrap_err();
        assert!(e.to_string().starts_with("f.txt:4:"), "{e}");
        let e = parse_lines("model 2 effect leak 1e-3\n", "f.txt").unwrap_err();
        assert!(e.to_string().contains("no `begin`"), "{e}");
    }

    #[test]
    fn an_effect_read_back_that_differs_is_reported() {
        let text = LINES.replace("model 1 commit", "model 1 effect leak 1e-3\nmodel 1 commit");
        let mut up = parse_lines(&text, "x").unwrap();
        // The board is sent 1e-3 but the expectation says otherwise: the read-back must catch it.
        up[0].effects[0] =
            model_core::chain::Effect::new(model_core::chain::EffectKind::Leak, &[1.0001e-3])
                .unwrap();
        match deploy(&mut FirmwarePort::new(), &up) {
            Err(DeployError::Mismatch { ch: 1, what, .. }) => assert_eq!(what, "effect 0"),
            other => panic!("{other:?}"),
        }
        // Expecting no effect while the board holds one: refused at `read effect 0`.
        up[0].effects.clear();
        match deploy(&mut FirmwarePort::new(), &up) {
            Err(DeployError::Mismatch { ch: 1, what, .. }) => assert_eq!(what, "effect 0"),
            other => panic!("{other:?}"),
        }
    }

    /// Firmware that refuses `model <ch> read` the way its parser did before the verb existed.
    #[derive(Default)]
    struct OldFirmware {
        fw: FirmwarePort,
        line: Vec<u8>,
    }

    impl Write for OldFirmware {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            for &b in buf {
                self.line.push(b);
                if b != b'\n' {
                    continue;
                }
                let line = std::mem::take(&mut self.line);
                // The command after the checksum prefix (`*LLCC `) that deploy always sends.
                let words: Vec<&[u8]> = line
                    .split(|&c| c == b' ')
                    .skip_while(|w| w.first() == Some(&b'*'))
                    .collect();
                if words[0] == b"model" && words.get(2).map(|w| w.trim_ascii()) == Some(b"read") {
                    self.fw.out.extend(b"err invalid-argument 2\r\n");
                } else {
                    self.fw.write_all(&line)?;
                }
            }
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    impl Read for OldFirmware {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            self.fw.read(buf)
        }
    }

    #[test]
    fn firmware_without_read_is_confirmed_by_acks_only() {
        let up = parse_lines(LINES, "x").unwrap();
        let mut old = OldFirmware::default();
        let r = deploy(&mut old, &up).unwrap();
        assert_eq!(
            r[0].readback,
            Readback::Unsupported {
                reply: "err invalid-argument 2".into()
            }
        );
        // One reply per line: nothing left over.
        assert!(old.fw.out.is_empty());
    }

    #[test]
    fn reports_a_refused_line() {
        // An index past the shape: the firmware's staged-model check refuses it.
        let up = parse_lines(LINES, "x").unwrap();
        let mut port = FirmwarePort::new();
        let mut bad = up.clone();
        bad[0].lines[2] = "model 1 coef 11 9e0 1e1".into();
        match deploy(&mut port, &bad) {
            Err(DeployError::Refused { ch: 1, sent, reply }) => {
                assert_eq!(sent, "model 1 coef 11 9e0 1e1");
                assert!(reply.starts_with("err"), "{reply}");
            }
            other => panic!("{other:?}"),
        }
    }
}
