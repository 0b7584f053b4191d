//! Tests of the model store: serialisation by hand, power cuts at every byte of an update on
//! sequential-storage's mock flash, corrupt stores, and the application's write gating.

use super::*;
use crate::app::{persist_once, CommandError, Config, Sampler, Shared};
use crate::command;
use crate::reset::tests::crc32_bitwise;
use embassy_futures::block_on;
use proptest::prelude::*;
use sequential_storage::mock_flash::{MockFlashBase, WriteCountCheck};
use std::string::String;
use std::vec::Vec;

/// 4 pages of 2 KiB with 4-byte words (the F4's x32 programming): about five models a page,
/// so a few updates fill a page and the next one erases and migrates.
type Flash = MockFlashBase<4, 4, 512>;
const RANGE: Range<u32> = 0..4 * 2048;

fn flash() -> Flash {
    // Each word written once between erases, as on the STM32F4.
    Flash::new(WriteCountCheck::OnceOnly, None, true)
}

fn store(f: Flash) -> ModelStore<Flash> {
    ModelStore::new(f, RANGE).expect("range of whole pages")
}

/// A model distinguishable by `k`: the default's coefficients scaled by (1 + k/64); odd `k`
/// also carry an effect chain (hysteresis of width 4 + k/8 mm³ and a sensor lag), so the
/// store's tests write items of both versions.
fn variant(k: u32) -> Model {
    let d = model_core::poly::sba1();
    let coef: Vec<f32> = d
        .scaled()
        .iter()
        .map(|c| c * (1.0 + k as f32 / 64.0))
        .collect();
    let poly = PolyModel::from_scaled(d.shape(), &coef, d.ar(), d.scaling()).unwrap();
    let mut chain = Chain::new();
    if k % 2 == 1 {
        let hyst = [4.0 + k as f32 / 8.0, 0.3, -0.05];
        chain
            .push(Effect::new(EffectKind::Hysteresis, &hyst).unwrap())
            .unwrap();
        chain
            .push(Effect::new(EffectKind::SensorLag, &[0.1]).unwrap())
            .unwrap();
    }
    Model { poly, chain }
}

/// A poly-AR model with every field in use (n = 2, m = 1, p = 2).
fn ar_model() -> PolyModel {
    let shape = Shape::new(2, 1, 2).unwrap();
    let scaling = Scaling::new(250.0, 250.0, -5.0, 80.0).unwrap();
    let coef = [1.0, -2.5, 0.125, 3.0e-3, -7.0, 42.0];
    PolyModel::from_scaled(shape, &coef, &[[0.5, -0.25], [0.0625, 1.0e-6]], scaling).unwrap()
}

#[test]
fn serialised_model_by_hand() {
    let m = ar_model();
    let mut b = [0u8; MODEL_BYTES];
    let n = encode_model(&m, &mut b);
    // 20 header bytes, 6 coefficients, 4 AR values.
    assert_eq!(n, 20 + 4 * (6 + 4));
    assert_eq!(&b[..4], &[1, 2, 1, 2]);
    assert_eq!(&b[4..8], &250.0f32.to_le_bytes());
    assert_eq!(&b[12..16], &(-5.0f32).to_le_bytes());
    assert_eq!(&b[20..24], &1.0f32.to_le_bytes());
    assert_eq!(&b[40..44], &42.0f32.to_le_bytes());
    assert_eq!(&b[44..48], &0.5f32.to_le_bytes());
    assert_eq!(&b[56..60], &1.0e-6f32.to_le_bytes());
    assert_eq!(decode_model(&b[..n]), Ok(m));
    assert_eq!(model_crc(&m), crc32_bitwise(&b[..n]));
    // The default round-trips too, and its CRC is that of its bytes.
    let d = model_core::poly::sba1();
    let n = encode_model(&d, &mut b);
    assert_eq!(n, 20 + 4 * 12);
    assert_eq!(decode_model(&b[..n]), Ok(d));
    assert_eq!(model_crc(&d), crc32_bitwise(&b[..n]));
    assert_ne!(model_crc(&d), crc(&variant(2)));
    assert_ne!(crc(&variant(2)), crc(&variant(1)));
}

#[test]
fn serialised_chain_by_hand() {
    // The default polynomial with a sensor lag and a hysteresis added in that order: stored in
    // evaluation order (hysteresis, code 5, before sensor lag, code 8).
    let d = model_core::poly::sba1();
    let mut chain = Chain::new();
    chain
        .push(Effect::new(EffectKind::SensorLag, &[0.25]).unwrap())
        .unwrap();
    chain
        .push(Effect::new(EffectKind::Hysteresis, &[6.0, 0.5, -0.125]).unwrap())
        .unwrap();
    let m = Model { poly: d, chain };
    let mut b = [0u8; MODEL_BYTES];
    let n = encode(&m, &mut b);
    let poly = 20 + 4 * 12;
    assert_eq!(n, poly + 1 + (1 + 12) + (1 + 4));
    assert_eq!(b[0], CHAIN_VERSION);
    let mut bare = [0u8; MODEL_BYTES];
    assert_eq!(encode_model(&d, &mut bare), poly);
    assert_eq!(
        &b[1..poly],
        &bare[1..poly],
        "the polynomial's bytes are unchanged"
    );
    assert_eq!(b[poly], 2);
    assert_eq!(b[poly + 1], 5);
    assert_eq!(&b[poly + 2..poly + 6], &6.0f32.to_le_bytes());
    assert_eq!(&b[poly + 10..poly + 14], &(-0.125f32).to_le_bytes());
    assert_eq!(b[poly + 14], 8);
    assert_eq!(&b[poly + 15..poly + 19], &0.25f32.to_le_bytes());
    assert_eq!(decode(&b[..n]), Ok(m));
    assert_eq!(crc(&m), crc32_bitwise(&b[..n]));
    assert_ne!(crc(&m), model_crc(&d));
    // Without effects: version 1, the CRC a host computes for a bare polynomial.
    assert_eq!(crc(&Model::from(d)), model_crc(&d));
    // Truncated, trailing bytes, no effects, an unknown code, a bad parameter, a duplicate.
    assert_eq!(decode(&b[..n - 1]), Err(DecodeError::Length));
    let mut long = b;
    long[n] = 0;
    assert_eq!(decode(&long[..n + 1]), Err(DecodeError::Length));
    let mut zero = b;
    zero[poly] = 0;
    assert_eq!(decode(&zero[..n]), Err(DecodeError::Length));
    let mut code = b;
    code[poly + 14] = 9;
    assert_eq!(decode(&code[..n]), Err(DecodeError::UnknownEffect(9)));
    let mut neg = b;
    neg[poly + 15..poly + 19].copy_from_slice(&(-1.0f32).to_le_bytes());
    assert_eq!(decode(&neg[..n]), Err(DecodeError::Model));
    let mut dup = b;
    dup[poly] = 2;
    dup[poly + 1] = 8;
    dup[poly + 2..poly + 6].copy_from_slice(&0.5f32.to_le_bytes());
    dup[poly + 6] = 8;
    dup[poly + 7..poly + 11].copy_from_slice(&0.25f32.to_le_bytes());
    assert_eq!(decode(&dup[..poly + 11]), Err(DecodeError::Model));
}

#[test]
fn the_longest_model_fits_the_buffer_and_a_small_page() {
    // n = m = 7, p = 5 and four effects, two of them with three parameters: exactly
    // MODEL_BYTES short of the two one-parameter effects' 8 bytes; stored and read back on
    // 512-byte pages.
    let shape = Shape::new(7, 7, 5).unwrap();
    let coef: Vec<f32> = (0..64).map(|i| 1.0 / (1.0 + i as f32)).collect();
    let poly = PolyModel::from_scaled(shape, &coef, &[[0.1, -0.1]; 5], Scaling::SBA1).unwrap();
    let mut chain = Chain::new();
    for (k, p) in [
        (EffectKind::Hysteresis, &[5.0, 0.1, 0.2][..]),
        (EffectKind::PumpRipple, &[8.0, 0.1, -0.1][..]),
        (EffectKind::SensorLag, &[0.1][..]),
        (EffectKind::Leak, &[0.01][..]),
    ] {
        chain.push(Effect::new(k, p).unwrap()).unwrap();
    }
    let m = Model { poly, chain };
    let mut b = [0u8; MODEL_BYTES];
    assert_eq!(encode(&m, &mut b), MODEL_BYTES - 2 * 8);
    let mut st = small(SmallFlash::new(WriteCountCheck::OnceOnly, None, true));
    for _ in 0..5 {
        block_on(st.save(0, &m)).unwrap();
    }
    let mut st = small(st.into_flash());
    assert_eq!(block_on(st.load(0)), Ok(m));
}

#[test]
fn bad_bytes_are_refused() {
    let mut b = [0u8; MODEL_BYTES];
    let n = encode_model(&ar_model(), &mut b);
    let mut v3 = b;
    v3[0] = 3;
    assert_eq!(decode_model(&v3[..n]), Err(DecodeError::Version(3)));
    // Version 2 promises a chain after the polynomial.
    let mut v2 = b;
    v2[0] = 2;
    assert_eq!(decode_model(&v2[..n]), Err(DecodeError::Length));
    assert_eq!(decode_model(&b[..n - 4]), Err(DecodeError::Length));
    assert_eq!(decode_model(&b[..n + 4]), Err(DecodeError::Length));
    assert_eq!(decode_model(&[]), Err(DecodeError::Length));
    let mut big = b;
    big[1] = 8; // n = 8 > MAX_DEG
    assert_eq!(decode_model(&big[..n]), Err(DecodeError::Length));
    let mut nan = b;
    nan[20..24].copy_from_slice(&f32::NAN.to_le_bytes());
    assert_eq!(decode_model(&nan[..n]), Err(DecodeError::Model));
    let mut scale = b;
    scale[8..12].copy_from_slice(&0.0f32.to_le_bytes()); // v_scale = 0
    assert_eq!(decode_model(&scale[..n]), Err(DecodeError::Model));
}

proptest! {
    #[test]
    fn decode_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..400)) {
        let _ = decode_model(&bytes);
    }
}

#[test]
fn empty_store_boots_on_the_default_and_a_save_survives_a_reboot() {
    let mut st = store(flash());
    let boot = block_on(st.load_all());
    for (m, how) in boot {
        assert_eq!((m, how), (Model::default_model(), Loaded::Empty));
    }
    block_on(st.save(1, &ar_model())).unwrap();
    block_on(st.save(2, &variant(3))).unwrap();
    // Reboot: a new store over the same flash.
    let mut st = store(st.into_flash());
    let boot = block_on(st.load_all());
    assert_eq!(boot[0], (Model::default_model(), Loaded::Empty));
    assert_eq!(boot[1], (Model::from(ar_model()), Loaded::Stored));
    assert_eq!(boot[2], (variant(3), Loaded::Stored));
}

#[test]
fn many_updates_keep_the_latest_of_every_channel() {
    // Far more updates than the flash holds at once: pages are erased and live items moved.
    let mut st = store(flash());
    for k in 0..60u32 {
        let ch = (k % 3) as u8;
        block_on(st.save(ch, &variant(k))).unwrap();
    }
    let mut st = store(st.into_flash());
    let boot = block_on(st.load_all());
    for ch in 0..3 {
        assert_eq!(
            boot[ch],
            (variant(57 + ch as u32), Loaded::Stored),
            "ch {ch}"
        );
    }
}

/// 3 pages of 512 bytes: six items a page, so a short history already wraps around the pages
/// and makes an update erase one and move the live items out of it.
type SmallFlash = MockFlashBase<3, 4, 128>;

fn small(f: SmallFlash) -> ModelStore<SmallFlash> {
    ModelStore::new(f, 0..3 * 512).expect("range of whole pages")
}

/// Cut the power at every byte of one update (written or erased), reboot, and check that the
/// channel reads exactly the old or exactly the new model and the other channels are intact;
/// then that the store still takes a write. `history` updates come first, so that over the
/// range of histories the cut update lands on a fresh page, mid-page, and on a page change
/// that erases and migrates.
#[test]
fn a_power_cut_at_any_byte_leaves_the_old_or_the_new_model() {
    let others = [Model::from(ar_model()), variant(99)];
    let mut checked = 0u32;
    let mut longest = 0u32;
    let mut saw_old = false;
    let mut saw_new = false;
    for history in 0..30u32 {
        let mut base = small(SmallFlash::new(WriteCountCheck::OnceOnly, None, true));
        block_on(base.save(1, &others[0])).unwrap();
        block_on(base.save(2, &others[1])).unwrap();
        for k in 0..=history {
            block_on(base.save(0, &variant(k))).unwrap();
        }
        let old = variant(history);
        let new = variant(100 + history);
        let base = base.into_flash();
        for cut in 0u32.. {
            let mut f = base.clone();
            f.bytes_until_shutoff = Some(cut);
            let mut st = small(f);
            let done = block_on(st.save(0, &new)).is_ok();
            let mut f = st.into_flash();
            f.bytes_until_shutoff = None;
            // Reboot.
            let mut st = small(f);
            let got = block_on(st.load(0));
            if done {
                assert_eq!(got, Ok(new), "history {history}: completed write");
            } else {
                assert!(
                    got == Ok(old) || got == Ok(new),
                    "history {history}, cut after {cut} bytes: {got:?}"
                );
                saw_old |= got == Ok(old);
                saw_new |= got == Ok(new);
            }
            assert_eq!(
                block_on(st.load(1)),
                Ok(others[0]),
                "history {history} cut {cut}"
            );
            assert_eq!(
                block_on(st.load(2)),
                Ok(others[1]),
                "history {history} cut {cut}"
            );
            // The store recovers: the next write succeeds and reads back after a reboot.
            let next = variant(200);
            block_on(st.save(0, &next))
                .unwrap_or_else(|e| panic!("history {history} cut {cut}: {e:?}"));
            let mut st = small(st.into_flash());
            assert_eq!(block_on(st.load(0)), Ok(next));
            checked += 1;
            longest = longest.max(cut);
            if done {
                break;
            }
        }
    }
    std::eprintln!("{checked} cut points; longest update {longest} bytes written or erased");
    // Cuts landed both before and after the update's commit point, and some update erased a
    // whole 512-byte page (and moved the live items) before it completed.
    assert!(saw_old && saw_new);
    assert!(longest > 512, "longest update {longest} bytes");
    assert!(checked > 30 * 80, "only {checked} cut points");
}

/// Bytes stored as they are (an item another firmware wrote).
struct Raw<'a>(&'a [u8]);

impl<'a> Value<'a> for Raw<'a> {
    fn serialize_into(&self, buffer: &mut [u8]) -> Result<usize, SerializationError> {
        buffer[..self.0.len()].copy_from_slice(self.0);
        Ok(self.0.len())
    }
    fn deserialize_from(buffer: &'a [u8]) -> Result<(Self, usize), SerializationError> {
        Ok((Raw(buffer), buffer.len()))
    }
}

#[test]
fn a_corrupt_or_foreign_store_boots_on_the_default() {
    // Garbage where the store should be (old code, a different layout): no panic, defaults,
    // and the store is usable again after a write.
    let mut f = flash();
    let mut x = 0x1234_5678u32;
    for b in f.as_bytes_mut() {
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        *b = x as u8;
    }
    let mut st = store(f);
    for (m, how) in block_on(st.load_all()) {
        assert_eq!(m, Model::default_model());
        assert_ne!(how, Loaded::Stored);
    }

    // A stored item whose bytes are not a model (a future version): invalid, default.
    let mut b = [0u8; MODEL_BYTES];
    let n = encode_model(&ar_model(), &mut b);
    b[0] = 2;
    let mut st = store(flash());
    let mut buf = [0u8; 512];
    block_on(st.map.store_item(&mut buf, &0u8, &Raw(&b[..n]))).unwrap();
    block_on(st.save(1, &ar_model())).unwrap();
    let boot = block_on(st.load_all());
    assert_eq!(boot[0], (Model::default_model(), Loaded::Invalid));
    assert_eq!(boot[1], (Model::from(ar_model()), Loaded::Stored));
    assert_eq!(boot[2], (Model::default_model(), Loaded::Empty));
}

#[test]
fn an_erased_or_corrupt_store_boots_on_the_default_and_announces_it() {
    // The boot path of the binary: load every channel, install, one `store` event each.
    let mut garbage = flash();
    garbage.as_bytes_mut()[..2048].fill(0x5A);
    for f in [flash(), garbage] {
        let mut st = store(f);
        let models = block_on(st.load_all());
        let mut s = App::new();
        events(&mut s);
        s.restore_models(&models, 3);
        let d = model_core::poly::sba1();
        for (ch, ev) in events(&mut s).into_iter().enumerate() {
            match ev {
                crate::telemetry::EventKind::Store { ch: c, what, crc } => {
                    assert_eq!(c as usize, ch);
                    assert!(matches!(what, StoreEvent::Empty | StoreEvent::Invalid));
                    assert_eq!(crc, model_crc(&d));
                }
                other => panic!("{other:?}"),
            }
            assert_eq!(s.model(ch), d);
            assert_eq!(s.saved(ch), Saved::Default);
        }
    }
}

#[test]
fn a_range_that_is_not_two_whole_pages_is_refused() {
    assert!(ModelStore::new(flash(), 0..2048).is_err());
    assert!(ModelStore::new(flash(), 100..4196).is_err());
}

// ------------------------------------------------------------------ the application's side

/// The board's state driven through the tasks' own entry points (as `app_tests` does).
struct App {
    shared: Shared,
    sampler: Sampler,
}

impl App {
    /// A board whose host declared the plungers at volume 0 (`origin all 0`).
    fn new() -> Self {
        let cfg = Config::default();
        let shared = Shared::new(cfg);
        shared.declare_origin(0.0).unwrap();
        Self {
            shared,
            sampler: Sampler::new(&cfg),
        }
    }
    fn restore_models(&mut self, models: &[(Model, Loaded); AXES], now: u64) {
        block_on(self.shared.restore_models(models, now));
    }
    fn pop_event(&mut self) -> Option<crate::telemetry::Event> {
        self.shared.with_control(|c| c.pop_event())
    }
    fn on_oversample(&mut self, raw: [u16; AXES], t_us: u64) {
        let c = self.shared.conversion(&mut self.sampler, raw, t_us);
        if let Some(acc) = c.frame {
            let mut est = self.shared.estimator().try_lock().unwrap();
            self.shared.finish_frame(&mut est, &acc);
        }
    }
    fn model(&self, ch: usize) -> PolyModel {
        self.shared.lock(|s| *s.model(ch))
    }
    fn saved(&self, ch: usize) -> Saved {
        self.shared.lock(|s| s.store().saved(ch))
    }
    fn flags(&self) -> Flags {
        self.shared.lock(|s| s.flags())
    }
    fn persist_begin(&self, now: u64) -> Option<(u8, Model)> {
        self.shared.persist_begin(now)
    }
    fn persist_end(&self, ch: usize, model: &Model, ok: bool, now: u64) {
        self.shared.persist_end(ch, model, ok, now);
    }
}

fn cmd(s: &mut App, line: &str, now: u64) -> Result<String, CommandError> {
    let c = command::parse(line.as_bytes()).expect("test lines parse");
    let mut out = String::new();
    let mut est = s.shared.estimator().try_lock().unwrap();
    s.shared.execute(&mut est, &c, now, &mut out).map(|()| out)
}

fn events(s: &mut App) -> Vec<crate::telemetry::EventKind> {
    core::iter::from_fn(|| s.pop_event())
        .map(|e| e.kind)
        .collect()
}

/// Zero every channel at rest (25 frames of 8 conversions); returns the last instant.
fn zero(s: &mut App) -> u64 {
    let mut t = 0;
    let code = crate::board::kpa_to_counts(0.0).round() as u16;
    for _ in 0..25 * 8 {
        t += 5_000;
        s.on_oversample([code; 3], t);
    }
    t
}

/// A state past its pressure zero at `t`.
fn ready() -> (App, u64) {
    let mut s = App::new();
    let t = zero(&mut s);
    events(&mut s);
    (s, t)
}

#[test]
fn boot_announces_what_each_channel_loaded() {
    let mut s = App::new();
    events(&mut s);
    let d = model_core::poly::sba1();
    s.restore_models(
        &[
            (Model::from(ar_model()), Loaded::Stored),
            (Model::from(d), Loaded::Empty),
            (Model::from(d), Loaded::Invalid),
        ],
        7,
    );
    use crate::telemetry::EventKind::Store;
    assert_eq!(
        events(&mut s),
        [
            Store {
                ch: 0,
                what: StoreEvent::Loaded,
                crc: model_crc(&ar_model())
            },
            Store {
                ch: 1,
                what: StoreEvent::Empty,
                crc: model_crc(&d)
            },
            Store {
                ch: 2,
                what: StoreEvent::Invalid,
                crc: model_crc(&d)
            },
        ]
    );
    assert_eq!(s.model(0), ar_model());
    let out = cmd(&mut s, "model 0 read crc", 8).unwrap();
    assert_eq!(out, std::format!(" {:#010x} flash", model_crc(&ar_model())));
    let out = cmd(&mut s, "model 2 read crc", 8).unwrap();
    assert_eq!(out, std::format!(" {:#010x} default", model_crc(&d)));
    assert!(!s.flags().has(Flags::MODEL_UNSAVED));
}

#[test]
fn a_commit_is_written_only_at_rest_and_after_the_port_is_quiet() {
    let (mut s, t) = ready();
    cmd(&mut s, "model 1 default", t).unwrap();
    assert!(s.flags().has(Flags::MODEL_UNSAVED));
    assert_eq!(s.saved(1), Saved::Pending);
    // Too soon after the command.
    assert_eq!(s.persist_begin(t + QUIET_US - 1), None);
    // Moving: deferred.
    cmd(&mut s, "move 0 10", t + 1).unwrap();
    assert_eq!(s.persist_begin(t + 1 + QUIET_US), None);
    cmd(&mut s, "stop", t + 2).unwrap();
    let now = t + 2 + QUIET_US;
    let (ch, model) = s.persist_begin(now).expect("at rest and quiet");
    assert_eq!((ch, model), (1, Model::default_model()));
    // While it writes, motion is refused and no second write starts.
    assert_eq!(cmd(&mut s, "move 0 10", now), Err(CommandError::Busy));
    assert_eq!(s.persist_begin(now + QUIET_US), None);
    s.persist_end(1, &model, true, now + 1);
    assert_eq!(s.saved(1), Saved::Flash);
    assert!(!s.flags().has(Flags::MODEL_UNSAVED));
    assert!(cmd(&mut s, "move 0 10", now + 2).is_ok());
}

#[test]
fn a_failed_write_is_flagged_and_a_commit_during_a_write_stays_pending() {
    let (mut s, t) = ready();
    cmd(&mut s, "model 0 default", t).unwrap();
    let now = t + QUIET_US;
    let (_, m) = s.persist_begin(now).unwrap();
    s.persist_end(0, &m, false, now);
    assert_eq!(s.saved(0), Saved::Failed);
    assert!(s.flags().has(Flags::STORE_FAILED | Flags::MODEL_UNSAVED));
    let out = cmd(&mut s, "status", now).unwrap();
    assert!(out.contains(" store failed default default "), "{out}");
    // A new commit retries; one committed while the write runs is written next.
    cmd(&mut s, "model 2 default", now).unwrap();
    let now = now + QUIET_US;
    let (ch, m) = s.persist_begin(now).unwrap();
    assert_eq!(ch, 2);
    cmd(&mut s, "model 2 default", now).unwrap();
    s.persist_end(2, &m, true, now);
    // Same model committed again: still pending, so written again.
    assert_eq!(s.saved(2), Saved::Pending);
}

#[test]
fn the_persist_task_writes_the_committed_model_to_flash() {
    let mut app = App::new();
    let mut st = store(flash());
    let mut reply = String::new();
    let mut line = String::new();
    command::write_checksummed("model 2 default", &mut line).unwrap();
    // Far enough in the past that the port is quiet at the mock clock's current instant.
    app.shared.command_line(line.as_bytes(), 0, &mut reply);
    assert_eq!(reply, "ok");
    embassy_time::MockDriver::get().advance(embassy_time::Duration::from_micros(QUIET_US));
    // Not zeroed yet at boot: the zero is in progress, so nothing is written.
    assert!(!block_on(persist_once(&app.shared, &mut st, &mut ())));
    zero(&mut app);
    assert!(block_on(persist_once(&app.shared, &mut st, &mut ())));
    assert_eq!(app.saved(2), Saved::Flash);
    let mut st = store(st.into_flash());
    assert_eq!(block_on(st.load(2)), Ok(Model::default_model()));
    assert_eq!(block_on(st.load(0)), Err(Loaded::Empty));
}

/// Stored images of the current format (versions 1 and 2) as boards hold them, written down byte
/// by byte from the format table (the `f32` little-endian bytes by Python's `struct.pack('<f')`,
/// the CRCs by `zlib.crc32`), not produced by [`encode`]. Every effect code appears once across
/// the three chain images. A firmware that reads them otherwise would misread the models boards
/// keep across an update: never edit these bytes to make a test pass.
mod images {
    /// The polynomial shared by the images after its version byte: n = m = p = 1, scaling
    /// (250, 250, −5, 80), coefficients (1.5, −2.25, 0.125, 3), AR (0.5, −0.25).
    #[rustfmt::skip]
    pub const V1: [u8; 44] = [
        0x01, 0x01, 0x01, 0x01,                                 // version 1, n, m, p
        0x00, 0x00, 0x7a, 0x43, 0x00, 0x00, 0x7a, 0x43,         // v_offset 250, v_scale 250
        0x00, 0x00, 0xa0, 0xc0, 0x00, 0x00, 0xa0, 0x42,         // f_offset −5, f_scale 80
        0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0x10, 0xc0,         // b00 1.5, b01 −2.25
        0x00, 0x00, 0x00, 0x3e, 0x00, 0x00, 0x40, 0x40,         // b10 0.125, b11 3
        0x00, 0x00, 0x00, 0x3f, 0x00, 0x00, 0x80, 0xbe,         // AR 0.5, −0.25
    ];
    /// Codes 0, 3, 5, 8.
    #[rustfmt::skip]
    pub const LAGS_LEAK_HYSTERESIS: [u8; 73] = [
        0x02, 0x01, 0x01, 0x01,                                 // version 2, n, m, p
        0x00, 0x00, 0x7a, 0x43, 0x00, 0x00, 0x7a, 0x43,
        0x00, 0x00, 0xa0, 0xc0, 0x00, 0x00, 0xa0, 0x42,
        0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0x10, 0xc0,
        0x00, 0x00, 0x00, 0x3e, 0x00, 0x00, 0x40, 0x40,
        0x00, 0x00, 0x00, 0x3f, 0x00, 0x00, 0x80, 0xbe,
        0x04,                                                   // four effects
        0x00, 0x00, 0x00, 0x80, 0x3d,                           // delivery_lag 0.0625 s
        0x03, 0x0a, 0xd7, 0x23, 0x3c,                           // leak 0.01
        0x05, 0x00, 0x00, 0xc0, 0x40, 0x00, 0x00, 0x00, 0x3f,   // hysteresis 6, 0.5,
        0x00, 0x00, 0x00, 0xbe,                                 //   −0.125
        0x08, 0x00, 0x00, 0x80, 0x3e,                           // sensor_lag 0.25 s
    ];
    /// Codes 1, 2, 4, 6.
    #[rustfmt::skip]
    pub const DELAY_PLAY_AIR_INERTANCE: [u8; 65] = [
        0x02, 0x01, 0x01, 0x01,
        0x00, 0x00, 0x7a, 0x43, 0x00, 0x00, 0x7a, 0x43,
        0x00, 0x00, 0xa0, 0xc0, 0x00, 0x00, 0xa0, 0x42,
        0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0x10, 0xc0,
        0x00, 0x00, 0x00, 0x3e, 0x00, 0x00, 0x40, 0x40,
        0x00, 0x00, 0x00, 0x3f, 0x00, 0x00, 0x80, 0xbe,
        0x04,
        0x01, 0x00, 0x00, 0xc0, 0x3e,                           // transport_delay 0.375 s
        0x02, 0x00, 0x00, 0xa0, 0x3f,                           // backlash 1.25 mm³
        0x04, 0x00, 0x00, 0x60, 0x40,                           // air_compliance 3.5 mm³
        0x06, 0x17, 0xb7, 0xd1, 0xb8,                           // inertance −1e-4
    ];
    /// Code 7.
    #[rustfmt::skip]
    pub const PUMP_RIPPLE: [u8; 58] = [
        0x02, 0x01, 0x01, 0x01,
        0x00, 0x00, 0x7a, 0x43, 0x00, 0x00, 0x7a, 0x43,
        0x00, 0x00, 0xa0, 0xc0, 0x00, 0x00, 0xa0, 0x42,
        0x00, 0x00, 0xc0, 0x3f, 0x00, 0x00, 0x10, 0xc0,
        0x00, 0x00, 0x00, 0x3e, 0x00, 0x00, 0x40, 0x40,
        0x00, 0x00, 0x00, 0x3f, 0x00, 0x00, 0x80, 0xbe,
        0x01,
        0x07, 0x00, 0x00, 0x00, 0x41, 0x00, 0x00, 0x00, 0x3e,   // pump_ripple 8, 0.125,
        0x00, 0x00, 0x80, 0xbd,                                 //   −0.0625
    ];
}

/// The images' polynomial, built from its numbers.
fn image_poly() -> PolyModel {
    let shape = Shape::new(1, 1, 1).unwrap();
    let scaling = Scaling::new(250.0, 250.0, -5.0, 80.0).unwrap();
    PolyModel::from_scaled(shape, &[1.5, -2.25, 0.125, 3.0], &[[0.5, -0.25]], scaling).unwrap()
}

#[test]
fn stored_images_of_format_2_decode_as_written() {
    use EffectKind::*;
    // (image, its effects in evaluation order, its CRC-32).
    type Case = (&'static [u8], &'static [(EffectKind, &'static [f32])], u32);
    let cases: [Case; 4] = [
        (&images::V1, &[], 0x4b2f_0062),
        (
            &images::LAGS_LEAK_HYSTERESIS,
            &[
                (DeliveryLag, &[0.0625]),
                (Leak, &[0.01]),
                (Hysteresis, &[6.0, 0.5, -0.125]),
                (SensorLag, &[0.25]),
            ],
            0x178a_6921,
        ),
        (
            &images::DELAY_PLAY_AIR_INERTANCE,
            &[
                (TransportDelay, &[0.375]),
                (Backlash, &[1.25]),
                (AirCompliance, &[3.5]),
                (Inertance, &[-1.0e-4]),
            ],
            0xc6c8_7d9a,
        ),
        (
            &images::PUMP_RIPPLE,
            &[(PumpRipple, &[8.0, 0.125, -0.0625])],
            0x455a_5923,
        ),
    ];
    for (image, effects, crc32) in cases {
        let m = decode(image).expect("a stored image decodes");
        assert_eq!(m.poly, image_poly());
        let got: Vec<(EffectKind, Vec<f32>)> = m
            .chain
            .effects()
            .iter()
            .map(|e| (e.kind(), e.params().to_vec()))
            .collect();
        let want: Vec<(EffectKind, Vec<f32>)> =
            effects.iter().map(|(k, p)| (*k, p.to_vec())).collect();
        assert_eq!(got, want);
        // What `status` reports for it, and the bytes the encoder writes back.
        assert_eq!(crc(&m), crc32);
        let mut b = [0u8; MODEL_BYTES];
        let n = encode(&m, &mut b);
        assert_eq!(&b[..n], image);
    }
}

#[test]
fn an_unknown_effect_code_is_refused_not_read_as_another() {
    // The leak's code (byte 50) replaced by each code no kind has: refused with that code, at
    // the next free code (a kind of a newer firmware) as at 255.
    let at = 44 + 1 + 5;
    assert_eq!(images::LAGS_LEAK_HYSTERESIS[at], 3);
    for code in [model_core::spec::NEXT_FREE_CODE, 42, 255] {
        let mut b = images::LAGS_LEAK_HYSTERESIS;
        b[at] = code;
        assert_eq!(decode(&b), Err(DecodeError::UnknownEffect(code)));
    }
    // A known code of another layout in its place is refused too (hysteresis takes three
    // parameters, which run into the next effect's bytes and leave too few behind).
    let mut b = images::LAGS_LEAK_HYSTERESIS;
    b[at] = 5;
    assert!(decode(&b).is_err());
    // On the board, as another firmware left them in flash: the images load as written, and
    // the channel holding the unknown code boots on the default and says the store is invalid.
    let mut st = store(flash());
    let mut buf = [0u8; 512];
    let mut unknown = images::DELAY_PLAY_AIR_INERTANCE;
    unknown[45] = model_core::spec::NEXT_FREE_CODE;
    for (ch, image) in [
        (0u8, &images::LAGS_LEAK_HYSTERESIS[..]),
        (1, &images::PUMP_RIPPLE[..]),
        (2, &unknown[..]),
    ] {
        block_on(st.map.store_item(&mut buf, &ch, &Raw(image))).unwrap();
    }
    let boot = block_on(st.load_all());
    assert_eq!(
        boot[0],
        (
            decode(&images::LAGS_LEAK_HYSTERESIS).unwrap(),
            Loaded::Stored
        )
    );
    assert_eq!(
        boot[1],
        (decode(&images::PUMP_RIPPLE).unwrap(), Loaded::Stored)
    );
    assert_eq!(boot[2], (Model::default_model(), Loaded::Invalid));
}
