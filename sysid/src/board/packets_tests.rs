use super::*;
use crate::board::record::{Recorder, Recording};
use firmware::telemetry::{Event, EventKind, Frame};
use firmware::wire::{encode_event, encode_frame, Packet};
use proptest::prelude::*;

/// A frame at 25 Hz whose numbers depend on `seq` (so a frame read back in the wrong place
/// would show).
fn frame(seq: u32, t0: u64) -> Frame {
    let mut f = Frame {
        seq,
        t_us: t0 + 40_000 * u64::from(seq),
        drops: seq / 7,
        force_n: seq as f32 * 0.01 - 0.3,
        ..Frame::default()
    };
    for (i, c) in f.chambers.iter_mut().enumerate() {
        c.v = 10.0 + seq as f32 * 0.04 + i as f32;
        c.vdot = 0.5 * i as f32;
        c.p = 1.0 / (1.0 + seq as f32) + i as f32;
        c.p_hat = c.p - 0.01;
        c.residual = 0.01;
        c.k = 0.15;
        c.c = 0.2;
    }
    f
}

fn packet_of_frame(f: &Frame) -> Vec<u8> {
    let mut p = Packet::new();
    encode_frame(f, &mut p);
    p.to_vec()
}

/// What the board sends: frames, events and command replies.
enum Sent {
    Frame(Frame),
    Event(Event),
    Reply(&'static str),
}

fn text_capture(items: &[Sent]) -> Vec<u8> {
    let mut out = String::new();
    for it in items {
        match it {
            Sent::Frame(f) => f.encode(&mut out).unwrap(),
            Sent::Event(e) => e.encode(&mut out).unwrap(),
            // Replies are not in the probe's capture; a defmt log line stands in.
            Sent::Reply(_) => out.push_str("0.1 INFO vfp-fw booted"),
        }
        out.push('\n');
    }
    out.into_bytes()
}

fn binary_stream(items: &[Sent]) -> Vec<u8> {
    let mut out = Vec::new();
    for it in items {
        match it {
            Sent::Frame(f) => out.extend(packet_of_frame(f)),
            Sent::Event(e) => {
                let mut p = Packet::new();
                assert!(encode_event(e, &mut p));
                out.extend_from_slice(&p);
            }
            Sent::Reply(r) => out.extend_from_slice(format!("{r}\r\n").as_bytes()),
        }
    }
    out
}

fn record_text(capture: &[u8]) -> (Recording, String) {
    let mut rec = Recorder::new(Vec::new(), "test").unwrap();
    for line in capture.split_inclusive(|&b| b == b'\n') {
        rec.line(line).unwrap();
    }
    let (r, out) = rec.finish("end of input").unwrap();
    (r, String::from_utf8(out).unwrap())
}

fn record_binary(bytes: &[u8]) -> (Recording, String) {
    let mut rec = Recorder::new(Vec::new(), "test").unwrap();
    read_all::<std::io::Error>(bytes, |item| rec.item(item)).unwrap();
    let (r, out) = rec.finish("end of input").unwrap();
    (r, String::from_utf8(out).unwrap())
}

#[test]
fn both_paths_give_the_same_log_and_the_same_gaps() {
    let mut items = vec![
        Sent::Reply("ok on"),
        Sent::Event(Event {
            t_us: 1,
            kind: EventKind::Zeroed {
                offset_kpa: [0.1, -0.2, 0.3],
            },
        }),
    ];
    // seq 0..60 with 10..=12 and 31 lost, a duplicate, a NaN frame, then a reboot.
    for seq in (0..60).filter(|s| ![10, 11, 12, 31].contains(s)) {
        items.push(Sent::Frame(frame(seq, 40_000)));
        if seq == 20 {
            items.push(Sent::Frame(frame(seq, 40_000)));
            items.push(Sent::Reply("ok 1 2 3"));
        }
    }
    let mut nan = frame(60, 40_000);
    nan.chambers[1].p = f32::NAN;
    items.push(Sent::Frame(nan));
    items.push(Sent::Event(Event {
        t_us: 5,
        kind: EventKind::Boot {
            cause: firmware::reset::ResetCause::PowerOn,
        },
    }));
    for seq in 0..5 {
        items.push(Sent::Frame(frame(seq, 40_000)));
    }
    let (a, csv_a) = record_text(&text_capture(&items));
    let (b, csv_b) = record_binary(&binary_stream(&items));
    // Truth by construction: 60 + 1 + 5 frames sent, 4 lost in two gaps, one duplicate and one
    // NaN frame rejected, one reboot.
    assert_eq!((b.frames, b.events), (61 - 4 - 1 + 5, 2));
    assert_eq!((b.counts.gaps, b.counts.missing_frames), (2, 4));
    assert_eq!(
        (b.counts.rejected, b.counts.restarts, b.counts.corrupted),
        (2, 1, 0)
    );
    assert_eq!(a.counts, b.counts);
    assert_eq!((a.frames, a.events), (b.frames, b.events));
    // Every item is one capture line on both paths, so even the comments' line numbers agree.
    assert_eq!(csv_a, csv_b);
    assert_eq!(b.other_lines, 2, "the two replies");
    let whole =
        crate::board::record::convert_packets(binary_stream(&items).as_slice(), "test").unwrap();
    assert_eq!((whole.counts, whole.frames), (b.counts, b.frames));
    assert!(csv_b.lines().filter(|l| !l.starts_with('#')).count() > 60 * 3);
}

#[test]
fn text_before_and_after_packets_is_read_as_lines() {
    let mut bytes = b"ok\r\nerr unknown-command\r\n".to_vec();
    bytes.extend(packet_of_frame(&frame(3, 0)));
    bytes.extend_from_slice(b"ok off\r\n$F 1 2 3\r\ntail");
    let mut items = Vec::new();
    read_all::<std::io::Error>(bytes.as_slice(), |i| {
        items.push(i);
        Ok(())
    })
    .unwrap();
    let kinds: Vec<String> = items
        .iter()
        .map(|i| match i {
            CaptureLine::Frame(f) => format!("frame {}", f.seq),
            CaptureLine::Other(t) => format!("other {t}"),
            CaptureLine::Corrupted(_) => "corrupted".into(),
            CaptureLine::Event(..) => "event".into(),
        })
        .collect();
    assert_eq!(
        kinds,
        [
            "other ok",
            "other err unknown-command",
            "frame 3",
            "other ok off",
            "corrupted",
            "other tail"
        ]
    );
}

#[test]
fn a_damaged_packet_is_named() {
    let mut bytes = packet_of_frame(&frame(1, 0));
    bytes[40] ^= 0x10;
    let mut r = PacketReader::new();
    let mut items = Vec::new();
    r.feed(&bytes, |i| items.push(i));
    match &items[..] {
        [CaptureLine::Corrupted(why)] => assert!(why.contains("CRC"), "{why}"),
        other => panic!("{other:?}"),
    }
    // An endless run without a delimiter is handed on in bounded pieces.
    let mut r = PacketReader::new();
    let mut n = 0;
    r.feed(&[0x01; 10 * MAX_CHUNK], |_| n += 1);
    assert_eq!(n, 10);
}

/// A damage to the stream: drop the byte at a position, or replace it.
#[derive(Debug, Clone)]
struct Damage {
    at: usize,
    with: Option<u8>,
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]
    /// Random streams of frames and replies with bytes lost and changed: the reader never
    /// panics, every frame it gives is one that was sent, bit for bit, a damaged byte costs at
    /// most the packet it lies in (its delimiters included), and the recorder's gap count is
    /// exactly the frames missing between the first and the last received.
    #[test]
    fn lost_and_changed_bytes_cost_only_the_packets_they_touch(
        n in 5u32..40,
        replies in proptest::collection::vec(any::<bool>(), 40),
        damage in proptest::collection::vec(
            (any::<proptest::sample::Index>(), proptest::option::of(any::<u8>())), 0..6),
    ) {
        let mut bytes = Vec::new();
        // Byte ranges of each frame's packet, delimiters included.
        let mut spans = Vec::new();
        let sent: Vec<Frame> = (0..n).map(|s| frame(s, 40_000)).collect();
        for (f, &reply) in sent.iter().zip(&replies) {
            let start = bytes.len();
            bytes.extend(packet_of_frame(f));
            spans.push(start..bytes.len());
            if reply {
                bytes.extend_from_slice(b"ok 12.5 0\r\n");
            }
        }
        let damage: Vec<Damage> = damage
            .into_iter()
            .map(|(i, with)| Damage { at: i.index(bytes.len()), with })
            .collect();
        let touched = (0..sent.len())
            .filter(|&k| damage.iter().any(|d| spans[k].contains(&d.at)))
            .count();
        let mut damaged = Vec::with_capacity(bytes.len());
        for (i, &b) in bytes.iter().enumerate() {
            match damage.iter().rev().find(|d| d.at == i) {
                None => damaged.push(b),
                Some(Damage { with: None, .. }) => {}
                Some(Damage { with: Some(x), .. }) => damaged.push(*x),
            }
        }
        let mut got = Vec::new();
        read_all::<std::io::Error>(damaged.as_slice(), |item| {
            if let CaptureLine::Frame(f) = item {
                got.push(f);
            }
            Ok(())
        })
        .unwrap();
        for f in &got {
            prop_assert_eq!(f, &sent[f.seq as usize]);
        }
        prop_assert!(sent.len() - got.len() <= touched, "lost {} of {}, touched {}",
            sent.len() - got.len(), sent.len(), touched);
        let (rec, _) = record_binary(&damaged);
        if let (Some(first), Some(last)) = (got.first(), got.last()) {
            let between = u64::from(last.seq - first.seq) + 1;
            prop_assert_eq!(rec.counts.missing_frames, between - got.len() as u64);
            prop_assert_eq!(rec.frames, got.len());
        }
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..3000)) {
        let mut r = PacketReader::new();
        r.feed(&bytes, |_| {});
        let _ = r.finish();
    }
}
