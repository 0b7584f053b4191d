//! The committed models kept in flash across resets.
//!
//! Each chamber's committed model (`model <ch> commit` or `model <ch> default`) is written to
//! flash with [`sequential-storage`](sequential_storage)'s map (key: the channel, value: the
//! serialised model), and loaded at boot. The map appends a new item for every update and
//! only then (logically) drops the old one; items carry a header and data CRC, and a write cut
//! by a reset or power loss leaves either the old or the new value readable (the tests below
//! cut an update at every byte). A channel whose key is missing or unreadable boots on the
//! built-in default, [`model_core::poly::sba1`], and says so on a `store` event.
//!
//! # Serialised model (version 1 without effects, 2 with)
//! | bytes | content |
//! | --- | --- |
//! | 0 | [`MODEL_VERSION`] (1), or [`CHAIN_VERSION`] (2) when the model has an effect chain |
//! | 1, 2, 3 | n, m, p |
//! | 4..20 | v_offset, v_scale, f_offset, f_scale (`f32` little-endian) |
//! | then | the (n+1)(m+1) scaled coefficients b_ij, index i·(m+1)+j (`f32` LE) |
//! | then | the 2p flattened AR coefficients b₁₁ b₁₂ b₂₁ … (`f32` LE) |
//! | version 2 only | the number of effects e (1..=4), then per effect, in the chain's evaluation order (`model_core::chain::EffectKind::ALL`): its stored code (`EffectKind::code`, one byte, fixed forever, never reused and independent of that order: the table of `model_core::spec`) and its parameters (`f32` LE, as many as the kind's row lists, in its order) |
//!
//! An effect code this firmware does not know is refused ([`DecodeError::UnknownEffect`]; the
//! channel boots on the default and says `store <ch> invalid`), never read as another kind. The
//! images of `store_tests.rs`' `stored_images_of_format_2_decode_as_written` are byte for byte
//! what this format is: a change that fails them would misread models boards hold.
//!
//! A model without effects serialises exactly as before the chain existed, so its CRC is
//! unchanged. The model's CRC ([`model_crc`], [`crc`]) is the CRC-32/ISO-HDLC (zlib's CRC-32) of
//! exactly these bytes: `status` and `model <ch> read crc` report it, so a host tool that serialises the model
//! it sent the same way can check, bit for bit, what the board committed.
//!
//! # When the board writes
//! Programming a word stalls every fetch from the same flash bank, so on the single-bank
//! STM32F446 the CPU (interrupts included) stands still while flash is written or erased:
//! about 1.3 ms for a model (~80 words at 16 µs), and 1–2 s when the store has to erase one of
//! its 128 KiB sectors (every few hundred commits). The board therefore writes only at rest
//! ([`Persist::begin`]: every axis idle, no `run`, no zero in progress, and
//! [`QUIET_US`] after the last command so that a host talking in lock-step is waiting, not
//! sending, when the stall comes), refuses motion while it writes, and lengthens the
//! independent watchdog's window around the write ([`FlashGuard`]). A committed model that is
//! not yet written shows as `pending` (flag 29). The application's
//! [`persist_task`](crate::app::persist_task) does the writing: this module has the store and
//! the bookkeeping, and nothing of the application's state.

use core::ops::Range;

use embedded_storage_async::nor_flash::NorFlash;
use model_core::chain::{Chain, Effect, EffectKind, MAX_EFFECTS, MAX_EFFECT_PARAMS};
use model_core::flags::Flags;
use model_core::poly::{PolyModel, Scaling, Shape, MAX_AR, MAX_TERMS};
use sequential_storage::cache::{Cache, Uncached};
use sequential_storage::map::{MapConfig, MapStorage, SerializationError, Value};

use crate::hal::AXES;
use crate::reset::CRC32;

/// Version byte of the serialised model without effects.
pub const MODEL_VERSION: u8 = 1;
/// Version byte of the serialised model with an effect chain.
pub const CHAIN_VERSION: u8 = 2;
/// Header bytes: version, n, m, p, four scaling floats.
const HEADER: usize = 4 + 16;
/// Longest serialised polynomial, bytes.
const POLY_BYTES: usize = HEADER + 4 * (MAX_TERMS + 2 * MAX_AR);
/// Longest serialised model (polynomial and a full chain), bytes.
pub const MODEL_BYTES: usize = POLY_BYTES + 1 + MAX_EFFECTS * (1 + 4 * MAX_EFFECT_PARAMS);

/// A committed model: the polynomial and its effect chain.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Model {
    /// The polynomial (poly-AR) model.
    pub poly: PolyModel,
    /// The effects evaluated around it (empty: the bare polynomial).
    pub chain: Chain,
}

impl From<PolyModel> for Model {
    fn from(poly: PolyModel) -> Self {
        Model {
            poly,
            chain: Chain::new(),
        }
    }
}

impl From<&PolyModel> for Model {
    fn from(poly: &PolyModel) -> Self {
        Model::from(*poly)
    }
}

impl From<&Model> for Model {
    fn from(m: &Model) -> Self {
        *m
    }
}

impl Model {
    /// The built-in default: the paper's SBA1 model without effects.
    pub fn default_model() -> Self {
        Model::from(model_core::poly::sba1())
    }
}

/// Serialise `model` with its chain into `out` (see the module docs); returns the length.
pub fn encode(model: &Model, out: &mut [u8; MODEL_BYTES]) -> usize {
    let mut at = encode_poly(&model.poly, out);
    let effects = model.chain.effects();
    if effects.is_empty() {
        return at;
    }
    out[0] = CHAIN_VERSION;
    out[at] = effects.len() as u8;
    at += 1;
    for e in effects {
        out[at] = e.kind().code();
        at += 1;
        for x in e.params() {
            out[at..at + 4].copy_from_slice(&x.to_le_bytes());
            at += 4;
        }
    }
    at
}

/// Serialise a model without effects (version 1) into `out`; returns the length.
pub fn encode_model(model: &PolyModel, out: &mut [u8; MODEL_BYTES]) -> usize {
    encode_poly(model, out)
}
/// A command less than this long ago (µs) defers a pending write.
pub const QUIET_US: u64 = 300_000;

fn encode_poly(model: &PolyModel, out: &mut [u8; MODEL_BYTES]) -> usize {
    let sh = model.shape();
    let sc = model.scaling();
    out[..4].copy_from_slice(&[MODEL_VERSION, sh.n, sh.m, sh.p]);
    let mut at = 4;
    let floats = [sc.v_offset, sc.v_scale, sc.f_offset, sc.f_scale];
    for x in floats
        .iter()
        .chain(model.scaled())
        .chain(model.ar().as_flattened())
    {
        out[at..at + 4].copy_from_slice(&x.to_le_bytes());
        at += 4;
    }
    at
}

/// Why stored bytes are not a model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DecodeError {
    /// Another serialisation version.
    Version(u8),
    /// Too short, too long, or a shape past model-core's limits.
    Length,
    /// model-core refused the values (a scale ≤ 0, a non-finite coefficient, an effect's
    /// parameter outside its range, two effects of one kind).
    Model,
    /// An effect stored under a code no kind of this firmware has (`model_core::spec`: codes
    /// are never reused, so this is a kind from a newer firmware, or corrupt bytes): the model
    /// is refused, never read as another effect.
    UnknownEffect(u8),
}

/// Parse what [`encode_model`] or [`encode`] wrote, keeping only the polynomial.
pub fn decode_model(b: &[u8]) -> Result<PolyModel, DecodeError> {
    decode(b).map(|m| m.poly)
}

/// Parse what [`encode`] wrote.
pub fn decode(b: &[u8]) -> Result<Model, DecodeError> {
    let (&version, rest) = b.split_first().ok_or(DecodeError::Length)?;
    if version != MODEL_VERSION && version != CHAIN_VERSION {
        return Err(DecodeError::Version(version));
    }
    let [n, m, p] = *rest.first_chunk::<3>().ok_or(DecodeError::Length)?;
    let shape = Shape::new(n, m, p).map_err(|_| DecodeError::Length)?;
    let (terms, ar_len) = (shape.poly_terms(), 2 * p as usize);
    let poly_len = HEADER + 4 * (terms + ar_len);
    let ok_len = if version == MODEL_VERSION {
        b.len() == poly_len
    } else {
        b.len() > poly_len
    };
    if !ok_len {
        return Err(DecodeError::Length);
    }
    let mut floats = b[4..poly_len]
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
    let mut next = || floats.next().unwrap_or(f32::NAN);
    let scaling = Scaling::new(next(), next(), next(), next()).map_err(|_| DecodeError::Model)?;
    let mut coef = [0.0f32; MAX_TERMS];
    coef[..terms].iter_mut().for_each(|c| *c = next());
    let mut ar = [[0.0f32; 2]; MAX_AR];
    ar[..p as usize]
        .iter_mut()
        .for_each(|a| *a = [next(), next()]);
    let poly = PolyModel::from_scaled(shape, &coef[..terms], &ar[..p as usize], scaling)
        .map_err(|_| DecodeError::Model)?;
    let chain = if version == CHAIN_VERSION {
        decode_chain(&b[poly_len..])?
    } else {
        Chain::new()
    };
    Ok(Model { poly, chain })
}

/// The chain part of a version-2 model: count, then code and parameters per effect, exactly.
fn decode_chain(b: &[u8]) -> Result<Chain, DecodeError> {
    let (&count, mut rest) = b.split_first().ok_or(DecodeError::Length)?;
    if count == 0 || count as usize > MAX_EFFECTS {
        return Err(DecodeError::Length);
    }
    let mut chain = Chain::new();
    for _ in 0..count {
        let (&code, tail) = rest.split_first().ok_or(DecodeError::Length)?;
        let kind = EffectKind::from_code(code).ok_or(DecodeError::UnknownEffect(code))?;
        let n = kind.params();
        let bytes = tail.get(..4 * n).ok_or(DecodeError::Length)?;
        let mut params = [0.0f32; MAX_EFFECT_PARAMS];
        for (x, c) in params.iter_mut().zip(bytes.chunks_exact(4)) {
            *x = f32::from_le_bytes([c[0], c[1], c[2], c[3]]);
        }
        let e = Effect::new(kind, &params[..n]).map_err(|_| DecodeError::Model)?;
        chain.push(e).map_err(|_| DecodeError::Model)?;
        rest = &tail[4 * n..];
    }
    if !rest.is_empty() {
        return Err(DecodeError::Length);
    }
    Ok(chain)
}

/// CRC-32/ISO-HDLC of the serialised model without effects (what a host that sends a bare
/// polynomial checks against).
pub fn model_crc(model: &PolyModel) -> u32 {
    crc(&Model::from(model))
}

/// CRC-32/ISO-HDLC of the serialised model with its chain.
pub fn crc(model: &Model) -> u32 {
    let mut buf = [0u8; MODEL_BYTES];
    let n = encode(model, &mut buf);
    CRC32.checksum(&buf[..n])
}

/// A model as a map value.
struct Stored(Model);

impl<'a> Value<'a> for Stored {
    fn serialize_into(&self, buffer: &mut [u8]) -> Result<usize, SerializationError> {
        let mut b = [0u8; MODEL_BYTES];
        let n = encode(&self.0, &mut b);
        buffer
            .get_mut(..n)
            .ok_or(SerializationError::BufferTooSmall)?
            .copy_from_slice(&b[..n]);
        Ok(n)
    }

    fn deserialize_from(buffer: &'a [u8]) -> Result<(Self, usize), SerializationError> {
        let m = decode(buffer).map_err(|_| SerializationError::InvalidFormat)?;
        Ok((Stored(m), buffer.len()))
    }
}

/// What loading a channel found.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Loaded {
    /// A valid stored model.
    Stored,
    /// No stored model for this channel (a new board, an erased store).
    Empty,
    /// The store could not be read, or the stored bytes are not a valid model.
    Invalid,
}

/// Why a write failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoreError {
    /// The flash range is not a whole number (≥ 2) of erase pages.
    Range,
    /// The flash reported an error, or the store is full or corrupt beyond repair.
    Flash,
}

/// Bytes of the store's item buffer: key, longest value, rounded up to whole words.
const BUF_BYTES: usize = (1 + MODEL_BYTES + 3) & !3;

/// A word-aligned buffer, as flash drivers want.
#[repr(C, align(4))]
struct Buf([u8; BUF_BYTES]);

/// The committed models in a flash range, one key per channel.
pub struct ModelStore<F: NorFlash> {
    map: MapStorage<u8, F, Cache<Uncached, Uncached, Uncached, u8>>,
    buf: Buf,
}

impl<F: NorFlash> ModelStore<F> {
    /// A store in `range` (flash offsets as `flash` counts them): whole erase pages, at
    /// least two (sequential-storage keeps one free to move live items into).
    pub fn new(flash: F, range: Range<u32>) -> Result<Self, StoreError> {
        let cfg = MapConfig::try_new(range).map_err(|_| StoreError::Range)?;
        Ok(Self {
            map: MapStorage::new(flash, cfg, Cache::new_uncached()),
            buf: Buf([0; BUF_BYTES]),
        })
    }

    /// The stored model of channel `ch`, if any and valid.
    pub async fn load(&mut self, ch: u8) -> Result<Model, Loaded> {
        match self.map.fetch_item::<Stored>(&mut self.buf.0, &ch).await {
            Ok(Some(Stored(m))) => Ok(m),
            Ok(None) => Err(Loaded::Empty),
            Err(_) => Err(Loaded::Invalid),
        }
    }

    /// Every channel's model for boot: the stored one, or the built-in default with the reason.
    pub async fn load_all(&mut self) -> [(Model, Loaded); AXES] {
        let mut out = [(Model::default_model(), Loaded::Empty); AXES];
        for (ch, o) in out.iter_mut().enumerate() {
            *o = match self.load(ch as u8).await {
                Ok(m) => (m, Loaded::Stored),
                Err(why) => (Model::default_model(), why),
            };
        }
        out
    }

    /// Store `model` (a [`Model`], or a bare polynomial) as channel `ch`'s.
    pub async fn save(&mut self, ch: u8, model: impl Into<Model>) -> Result<(), StoreError> {
        self.map
            .store_item(&mut self.buf.0, &ch, &Stored(model.into()))
            .await
            .map_err(|_| StoreError::Flash)
    }

    /// The flash back (tests).
    pub fn into_flash(self) -> F {
        self.map.destroy().0
    }
}

/// Where a channel's committed model stands against the flash copy.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Saved {
    /// The committed model is the one in flash.
    Flash,
    /// Committed, not yet written (waits for rest).
    Pending,
    /// The last write failed; retried at the next commit.
    Failed,
    /// The built-in default, because no valid copy was found at boot.
    Default,
}

impl Saved {
    /// The word on `status` and `model <ch> read crc`.
    pub fn name(self) -> &'static str {
        match self {
            Saved::Flash => "flash",
            Saved::Pending => "pending",
            Saved::Failed => "failed",
            Saved::Default => "default",
        }
    }
}

/// What the `store` event reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StoreEvent {
    /// Boot: the stored model was loaded.
    Loaded,
    /// Boot: no stored model; the built-in default is in use.
    Empty,
    /// Boot: the stored copy was unreadable; the built-in default is in use.
    Invalid,
    /// The committed model was written.
    Saved,
    /// Writing the committed model failed.
    Failed,
}

impl StoreEvent {
    /// The word on the event line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Loaded => "loaded",
            Self::Empty => "empty",
            Self::Invalid => "invalid",
            Self::Saved => "saved",
            Self::Failed => "failed",
        }
    }
    /// Inverse of [`name`](Self::name).
    pub fn from_name(w: &str) -> Option<Self> {
        [
            Self::Loaded,
            Self::Empty,
            Self::Invalid,
            Self::Saved,
            Self::Failed,
        ]
        .into_iter()
        .find(|e| e.name() == w)
    }
}

/// The application's view of the store: each channel's committed model, its CRC and whether
/// it is in flash. Part of [`State`](crate::app::State).
#[derive(Clone, Debug)]
pub struct Persist {
    committed: [Model; AXES],
    crc: [u32; AXES],
    saved: [Saved; AXES],
    /// Commits per channel, so that a write knows whether its model is still the latest.
    generation: [u32; AXES],
    /// The write in progress: channel and the generation it writes.
    writing: Option<(usize, u32)>,
    last_command_us: Option<u64>,
}

impl Default for Persist {
    fn default() -> Self {
        Self::new()
    }
}

impl Persist {
    /// Boot state before the store is read: the default model, not from flash.
    pub fn new() -> Self {
        let m = Model::default_model();
        Self {
            committed: [m; AXES],
            crc: [crc(&m); AXES],
            saved: [Saved::Default; AXES],
            generation: [0; AXES],
            writing: None,
            last_command_us: None,
        }
    }

    /// Channel `ch` booted on `model` (CRC-32 `crc`, [`crc`](fn@crc)), found as `how`; returns
    /// the event to report.
    pub fn booted(&mut self, ch: usize, model: &Model, how: Loaded, crc: u32) -> StoreEvent {
        self.committed[ch] = *model;
        self.crc[ch] = crc;
        let (saved, ev) = match how {
            Loaded::Stored => (Saved::Flash, StoreEvent::Loaded),
            Loaded::Empty => (Saved::Default, StoreEvent::Empty),
            Loaded::Invalid => (Saved::Default, StoreEvent::Invalid),
        };
        self.saved[ch] = saved;
        ev
    }

    /// A model was committed on `ch` (CRC-32 `crc`, [`crc`](fn@crc), computed by the caller
    /// outside any critical section): it waits for rest to be written.
    pub fn committed(&mut self, ch: usize, model: &Model, crc: u32) {
        self.committed[ch] = *model;
        self.crc[ch] = crc;
        self.saved[ch] = Saved::Pending;
        self.generation[ch] = self.generation[ch].wrapping_add(1);
    }

    /// A command arrived at `now_us`.
    pub fn note_command(&mut self, now_us: u64) {
        self.last_command_us = Some(now_us);
    }

    /// CRC of the committed model of `ch`.
    pub fn crc(&self, ch: usize) -> u32 {
        self.crc[ch]
    }

    /// Where `ch`'s committed model stands.
    pub fn saved(&self, ch: usize) -> Saved {
        self.saved[ch]
    }

    /// A write is in progress (motion is refused).
    pub fn writing(&self) -> bool {
        self.writing.is_some()
    }

    /// Flag 29 while a committed model is not in flash (pending or failed); flag 30 when a
    /// write failed.
    pub fn flags(&self) -> u32 {
        let mut f = 0;
        if self
            .saved
            .iter()
            .any(|s| matches!(s, Saved::Pending | Saved::Failed))
        {
            f |= Flags::MODEL_UNSAVED;
        }
        if self.saved.contains(&Saved::Failed) {
            f |= Flags::STORE_FAILED;
        }
        f
    }

    /// Start writing a pending model if the board is `at_rest` and the command port has been
    /// quiet for [`QUIET_US`]: returns the channel and the model to write, and refuses motion
    /// until [`end`](Self::end).
    pub fn begin(&mut self, at_rest: bool, now_us: u64) -> Option<(u8, Model)> {
        let quiet = self
            .last_command_us
            .is_none_or(|t| now_us.saturating_sub(t) >= QUIET_US);
        if self.writing.is_some() || !at_rest || !quiet {
            return None;
        }
        let ch = self.saved.iter().position(|s| *s == Saved::Pending)?;
        self.writing = Some((ch, self.generation[ch]));
        Some((ch as u8, self.committed[ch]))
    }

    /// The write started by [`begin`](Self::begin) ended (`ok`). A model committed on that
    /// channel meanwhile (even the same one again) stays pending, to be written next.
    pub fn end(&mut self, ok: bool) -> StoreEvent {
        if let Some((ch, generation)) = self.writing.take() {
            if self.generation[ch] == generation {
                self.saved[ch] = if ok { Saved::Flash } else { Saved::Failed };
            }
        }
        if ok {
            StoreEvent::Saved
        } else {
            StoreEvent::Failed
        }
    }
}

/// What the board does around a flash write: the device lengthens the independent watchdog's
/// window (an erase outlasts its 50 ms) and restores it after.
pub trait FlashGuard {
    /// Before the write.
    fn before(&mut self);
    /// After the write.
    fn after(&mut self);
}

/// No guard (the simulator has no watchdog to stretch).
impl FlashGuard for () {
    fn before(&mut self) {}
    fn after(&mut self) {}
}

#[cfg(test)]
#[path = "store_tests.rs"]
mod tests;
