use super::*;
use crate::reset::{FaultFrame, FileTail, PanicSite, ResetCause};
use crate::store::StoreEvent;
use crate::telemetry::{EventKind, LONGEST_F32};
use proptest::prelude::*;

fn unstuff(p: &[u8]) -> std::vec::Vec<u8> {
    assert_eq!((p[0], p[p.len() - 1]), (0, 0), "delimiters");
    assert!(!p[1..p.len() - 1].contains(&0), "no zero inside a packet");
    let mut raw = [0u8; MAX_RAW];
    let n = cobs::decode(&p[1..p.len() - 1], &mut raw)
        .unwrap()
        .frame_size();
    raw[..n].to_vec()
}

fn frame_bits(f: &Frame) -> std::vec::Vec<u64> {
    let mut v = std::vec![
        u64::from(f.seq),
        f.t_us,
        u64::from(f.flags.0),
        u64::from(f.drops)
    ];
    v.push(u64::from(f.force_n.to_bits()));
    for c in &f.chambers {
        for x in [c.v, c.vdot, c.p, c.p_hat, c.residual, c.k, c.c] {
            v.push(u64::from(x.to_bits()));
        }
    }
    v
}

fn any_frame() -> impl Strategy<Value = Frame> {
    use crate::telemetry::tests::{any_f32, chamber};
    (
        (any::<u32>(), any::<u64>(), any::<u32>(), any::<u32>()),
        any_f32(),
        [chamber(), chamber(), chamber()],
    )
        .prop_map(|((seq, t_us, flags, drops), force_n, chambers)| Frame {
            seq,
            t_us,
            flags: Flags(flags),
            force_n,
            drops,
            chambers,
        })
}

fn decode_packet(p: &Packet) -> Result<Frame, WireError> {
    let mut scratch = [0u8; MAX_RAW];
    match decode(&p[1..p.len() - 1], &mut scratch)? {
        Record::Frame(f) => Ok(f),
        Record::Event(..) => panic!("an event"),
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    /// Every bit of every field comes back, NaN payloads included (the text line keeps NaN-ness
    /// only).
    #[test]
    fn frames_round_trip_bit_for_bit(f in any_frame()) {
        let mut p = Packet::new();
        encode_frame(&f, &mut p);
        prop_assert_eq!(p.len(), 117);
        let g = decode_packet(&p).unwrap();
        prop_assert_eq!(frame_bits(&g), frame_bits(&f));
    }

    /// Any one byte inside a packet replaced by another non-zero value: refused, never decoded
    /// as some other frame.
    #[test]
    fn a_changed_byte_is_refused(f in any_frame(), at in 1usize..116, x in 1u8..=255) {
        let mut p = Packet::new();
        encode_frame(&f, &mut p);
        prop_assume!(p[at] != x);
        p[at] = x;
        prop_assert!(decode_packet(&p).is_err());
    }

    #[test]
    fn decode_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let mut scratch = [0u8; MAX_RAW];
        let _ = decode(&bytes, &mut scratch);
    }
}

#[test]
fn frame_layout_by_hand() {
    let f = Frame {
        seq: 0x0403_0201,
        t_us: 0x0C0B_0A09_0807_0605,
        flags: Flags(0x100F_0E0D),
        force_n: 1.0,
        drops: 0xAABB_CCDD,
        ..Frame::default()
    };
    let mut p = Packet::new();
    encode_frame(&f, &mut p);
    let raw = unstuff(&p);
    assert_eq!(raw.len(), 2 + 108 + 4);
    assert_eq!(&raw[..2], &[1, b'F']);
    assert_eq!(
        &raw[2..18],
        &[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 0x10]
    );
    // 1.0f32 = 0x3F80_0000, little-endian.
    assert_eq!(&raw[18..22], &[0, 0, 0x80, 0x3F]);
    assert_eq!(&raw[106..110], &[0xDD, 0xCC, 0xBB, 0xAA]);
    // The CRC is zlib's CRC-32 of everything before it (its check value: "123456789").
    let crc = u32::from_le_bytes(raw[110..114].try_into().unwrap());
    let zlib = crc::Crc::<u32>::new(&crc::CRC_32_ISO_HDLC);
    assert_eq!(zlib.checksum(b"123456789"), 0xCBF4_3926);
    assert_eq!(crc, zlib.checksum(&raw[..110]));
    // Chamber 1's pressure sits at 2 + 20 + 28 + 8.
    let mut g = f;
    g.chambers[1].p = -2.5;
    encode_frame(&g, &mut p);
    assert_eq!(&unstuff(&p)[58..62], &(-2.5f32).to_le_bytes());
}

#[test]
fn wrong_version_kind_and_length_are_named() {
    let bad = |raw: &[u8]| {
        let mut r = raw.to_vec();
        r.extend_from_slice(&CRC32.checksum(raw).to_le_bytes());
        let mut out = [0u8; MAX_PACKET];
        let n = cobs::encode(&r, &mut out);
        let mut scratch = [0u8; MAX_RAW];
        decode(&out[..n], &mut scratch).map(|_| ())
    };
    assert_eq!(bad(&[2, b'F']), Err(WireError::Version(2)));
    assert_eq!(bad(&[1, b'X']), Err(WireError::Kind(b'X')));
    assert_eq!(bad(&[1, b'F', 1, 2, 3]), Err(WireError::Length(3)));
    assert!(matches!(bad(b"\x01E$E 1 meteor"), Err(WireError::Event(_))));
    let mut scratch = [0u8; MAX_RAW];
    assert_eq!(decode(&[], &mut scratch), Err(WireError::Stuffing));
    assert_eq!(decode(&[3, 1, 2], &mut scratch), Err(WireError::TooShort));
    assert_eq!(
        decode(&[1; MAX_PACKET], &mut scratch),
        Err(WireError::TooLong)
    );
}

/// The longest event lines this firmware writes, each a packet that reads back.
#[test]
fn every_event_fits_and_round_trips() {
    let long = LONGEST_F32
        .into_iter()
        .max_by_key(|x| std::format!("{x}").len().max(std::format!("{x:e}").len()))
        .unwrap();
    let kinds = [
        EventKind::Boot {
            cause: ResetCause::HardFault(FaultFrame {
                pc: u32::MAX,
                lr: u32::MAX,
                xpsr: u32::MAX,
                cfsr: u32::MAX,
                hfsr: u32::MAX,
                mmfar: u32::MAX,
                bfar: u32::MAX,
            }),
        },
        EventKind::Boot {
            cause: ResetCause::Panic(PanicSite {
                file: FileTail::new("a/very/long/path/to/some/source/file_name.rs"),
                line: u32::MAX,
                column: u32::MAX,
            }),
        },
        EventKind::Drift {
            ch: 2,
            k_mean: long,
            c_mean: long,
            k_base: long,
            c_base: long,
        },
        EventKind::Zeroed {
            offset_kpa: [long; 3],
        },
        EventKind::Fault { flags: u32::MAX },
        EventKind::Store {
            ch: 2,
            what: StoreEvent::Invalid,
            crc: u32::MAX,
        },
    ];
    for kind in kinds {
        let e = Event {
            t_us: u64::MAX,
            kind,
        };
        let mut p = Packet::new();
        assert!(encode_event(&e, &mut p), "{kind:?}");
        let mut scratch = [0u8; MAX_RAW];
        match decode(&p[1..p.len() - 1], &mut scratch) {
            Ok(Record::Event(d, text)) => {
                assert_eq!(d, e);
                assert!(text.starts_with("$E "));
            }
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn a_full_queue_drops_and_counts_and_the_next_frame_says_so() {
    let link = SerialTelemetry::new();
    let mut out = SerialOut::default();
    let f = |seq| Frame {
        seq,
        ..Frame::default()
    };
    // Off: nothing queued, nothing counted.
    assert!(!out.frame(&f(0), &link));
    assert_eq!((out.drops(), link.try_next()), (0, None));
    link.set(true);
    for seq in 0..QUEUE as u32 + 3 {
        let queued = out.frame(&f(seq), &link);
        assert_eq!(queued, (seq as usize) < QUEUE);
    }
    assert_eq!(out.drops(), 3);
    // The host reads the queue: the first QUEUE frames, in order, then the next one sent
    // carries the 3 drops.
    for seq in 0..QUEUE as u32 {
        assert_eq!(decode_packet(&link.try_next().unwrap()).unwrap().seq, seq);
    }
    assert!(out.frame(&f(99), &link));
    let g = decode_packet(&link.try_next().unwrap()).unwrap();
    assert_eq!((g.seq, g.drops), (99, 3));
    // Events lost upstream count while on; switching off empties the queue.
    out.lost(&link, 2);
    assert!(out.event(
        &Event {
            t_us: 1,
            kind: EventKind::Cleared
        },
        &link
    ));
    link.set(false);
    assert_eq!((out.drops(), link.try_next()), (5, None));
}

/// A stream written by an independent encoder (Python: `zlib.crc32` and a hand-written COBS,
/// the fuzz seed `fuzz/seeds/wire/frame`): a frame packet, a reply line, an event packet.
#[test]
fn a_stream_from_an_independent_encoder_decodes() {
    let stream = include_bytes!("../fuzz/seeds/wire/frame");
    let chunks: std::vec::Vec<&[u8]> = stream
        .split(|&b| b == 0)
        .filter(|c| !c.is_empty())
        .collect();
    assert_eq!(chunks.len(), 3);
    assert_eq!(chunks[1], b"ok\r\n");
    let mut scratch = [0u8; MAX_RAW];
    let Ok(Record::Frame(f)) = decode(chunks[0], &mut scratch) else {
        panic!("not a frame")
    };
    assert_eq!(
        (f.seq, f.t_us, f.flags.0, f.force_n, f.drops),
        (7, 320_000, 1 << 16, 0.25, 2)
    );
    let all: std::vec::Vec<f32> = f
        .chambers
        .iter()
        .flat_map(|c| [c.v, c.vdot, c.p, c.p_hat, c.residual, c.k, c.c])
        .collect();
    assert_eq!(
        all,
        (0..21)
            .map(|i| 0.5 * i as f32)
            .collect::<std::vec::Vec<_>>()
    );
    match decode(chunks[2], &mut scratch) {
        Ok(Record::Event(e, text)) => {
            assert_eq!(
                (e.t_us, e.kind, text),
                (5, EventKind::Cleared, "$E 5 cleared")
            )
        }
        other => panic!("{other:?}"),
    }
}
