//! Why the board last reset: the RCC reset flags combined with a crash record that the panic
//! and HardFault handlers leave in RAM that start-up does not initialise.
//!
//! # The crash record
//! The binary's panic and HardFault handlers disable the stepper drivers, write a
//! [`RECORD_WORDS`]-word record into a `.uninit` RAM section (cortex-m-rt leaves it untouched at
//! start-up, and a system reset keeps SRAM powered) and reset through `SCB.AIRCR.SYSRESETREQ`.
//! The next boot decodes it with [`Crash::decode`] and clears it. Layout, little-endian `u32`
//! words:
//!
//! | word | panic | HardFault |
//! | --- | --- | --- |
//! | 0 | [`MAGIC`] | [`MAGIC`] |
//! | 1 | [`KIND_PANIC`] | [`KIND_HARDFAULT`] |
//! | 2 | line | stacked PC |
//! | 3 | column | stacked LR |
//! | 4..=10 | last 28 bytes of the file path | xPSR, CFSR, HFSR, MMFAR, BFAR, 0, 0 |
//! | 11 | CRC-32 (ISO-HDLC) of the bytes of words 0..=10 | same |
//!
//! After a power-on the RAM holds noise: a record is accepted only if the magic, the kind and the
//! CRC all match (a chance of about 2⁻⁶⁴ for random contents), and only when the reset flags say
//! the reset was a software reset, the one the handlers trigger ([`ResetCause::from_reset`]).
//!
//! # Reset flags
//! RCC_CSR of the STM32F4 (RM0390 §6.3.21): BORRSTF bit 25, PINRSTF 26, PORRSTF 27, SFTRSTF 28,
//! IWDGRSTF 29, WWDGRSTF 30, LPWRRSTF 31. Two facts of that register shape the decision:
//! a power-on sets both PORRSTF and BORRSTF (a brown-out only BORRSTF), and every internal
//! reset (software, watchdog) also pulls the NRST pin, so PINRSTF accompanies them. The
//! decision therefore goes power-on, brown-out, independent watchdog, window watchdog,
//! low-power, software (with or without a crash record), and only then pin.

use core::fmt::{self, Write};

use crc::{Crc, CRC_32_ISO_HDLC};

/// Words in the crash record.
pub const RECORD_WORDS: usize = 12;
/// First word of a valid record ("VFRC").
pub const MAGIC: u32 = 0x5646_5243;
/// Record kind: a Rust panic.
pub const KIND_PANIC: u32 = 1;
/// Record kind: a HardFault exception.
pub const KIND_HARDFAULT: u32 = 2;
/// Bytes of the panic's file path kept (its end, where the file name is).
pub const FILE_TAIL: usize = 28;

/// CRC-32/ISO-HDLC (zlib's), with its one lookup table in flash: the crash record and the
/// model store ([`crate::store::model_crc`]) both use it.
pub(crate) const CRC32: Crc<u32> = Crc::<u32>::new(&CRC_32_ISO_HDLC);

/// CRC-32 of the record's first 11 words, as little-endian bytes.
fn record_crc(words: &[u32]) -> u32 {
    let mut d = CRC32.digest();
    for w in words {
        d.update(&w.to_le_bytes());
    }
    d.finalize()
}

/// The end of a source path, at most [`FILE_TAIL`] bytes, as printable ASCII without spaces
/// (anything else becomes `_`), so it is one word on an event line.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct FileTail {
    bytes: [u8; FILE_TAIL],
    len: u8,
}

impl FileTail {
    /// The last [`FILE_TAIL`] bytes of `path`, sanitised; `?` for an empty path.
    pub fn new(path: &str) -> Self {
        Self::from_bytes(path.as_bytes())
    }

    fn from_bytes(b: &[u8]) -> Self {
        let b = &b[b.len().saturating_sub(FILE_TAIL)..];
        let mut bytes = [0u8; FILE_TAIL];
        for (d, &s) in bytes.iter_mut().zip(b) {
            *d = if s.is_ascii_graphic() { s } else { b'_' };
        }
        if b.is_empty() {
            bytes[0] = b'?';
            return Self { bytes, len: 1 };
        }
        Self {
            bytes,
            len: b.len() as u8,
        }
    }

    /// The text.
    pub fn as_str(&self) -> &str {
        // Only ASCII graphic bytes are ever stored.
        core::str::from_utf8(&self.bytes[..self.len as usize]).unwrap_or("?")
    }
}

impl fmt::Debug for FileTail {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_str())
    }
}

/// Where a panic happened.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PanicSite {
    /// End of the source file's path.
    pub file: FileTail,
    /// Line.
    pub line: u32,
    /// Column.
    pub column: u32,
}

/// The state a HardFault left: the stacked exception frame's PC, LR and xPSR, and the System
/// Control Block's fault status and address registers.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FaultFrame {
    /// Stacked program counter: the faulting instruction (or the one after it).
    pub pc: u32,
    /// Stacked link register.
    pub lr: u32,
    /// Stacked program status register.
    pub xpsr: u32,
    /// Configurable Fault Status Register (0xE000_ED28): MMFSR, BFSR, UFSR.
    pub cfsr: u32,
    /// HardFault Status Register (0xE000_ED2C): FORCED (bit 30), VECTTBL (bit 1).
    pub hfsr: u32,
    /// MemManage Fault Address Register (valid when CFSR.MMARVALID, bit 7).
    pub mmfar: u32,
    /// BusFault Address Register (valid when CFSR.BFARVALID, bit 15).
    pub bfar: u32,
}

impl FaultFrame {
    /// CFSR.MSTKERR (bit 4): the MemManage unit refused the exception entry's stacking.
    pub const MSTKERR: u32 = 1 << 4;
    /// CFSR.STKERR (bit 12): the bus refused the exception entry's stacking.
    pub const STKERR: u32 = 1 << 12;
    /// What the handler records for the stacked PC, LR and xPSR when the frame's address is not
    /// in RAM (no stacked PC is odd, so no real frame reads so).
    pub const NO_FRAME: u32 = u32::MAX;

    /// Whether the fault's exception frame lay outside RAM (the handler found the stack pointer
    /// below it) or the core could not stack it (CFSR.STKERR, MSTKERR): under flip-link, whose
    /// stack sits at the bottom of RAM, a stack overflow.
    pub fn stack_overflow(&self) -> bool {
        self.pc == Self::NO_FRAME || self.cfsr & (Self::STKERR | Self::MSTKERR) != 0
    }
}

/// What the crash handlers record.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Crash {
    /// A Rust panic.
    Panic(PanicSite),
    /// A HardFault (also the escalation of any disabled configurable fault).
    HardFault(FaultFrame),
}

impl Crash {
    /// The record's RAM image, checksum included.
    pub fn encode(&self) -> [u32; RECORD_WORDS] {
        let mut w = [0u32; RECORD_WORDS];
        w[0] = MAGIC;
        match self {
            Crash::Panic(p) => {
                w[1] = KIND_PANIC;
                w[2] = p.line;
                w[3] = p.column;
                let mut tail = [0u8; FILE_TAIL];
                tail[..p.file.len as usize].copy_from_slice(&p.file.bytes[..p.file.len as usize]);
                for (k, c) in tail.chunks_exact(4).enumerate() {
                    w[4 + k] = u32::from_le_bytes([c[0], c[1], c[2], c[3]]);
                }
            }
            Crash::HardFault(f) => {
                w[1] = KIND_HARDFAULT;
                w[2..9].copy_from_slice(&[f.pc, f.lr, f.xpsr, f.cfsr, f.hfsr, f.mmfar, f.bfar]);
            }
        }
        w[RECORD_WORDS - 1] = record_crc(&w[..RECORD_WORDS - 1]);
        w
    }

    /// Decode a RAM image; `None` unless the magic, kind and checksum all match (so the noise
    /// SRAM holds after power-on reads as no record).
    pub fn decode(w: &[u32; RECORD_WORDS]) -> Option<Crash> {
        if w[0] != MAGIC || w[RECORD_WORDS - 1] != record_crc(&w[..RECORD_WORDS - 1]) {
            return None;
        }
        match w[1] {
            KIND_PANIC => {
                let mut tail = [0u8; FILE_TAIL];
                for (k, c) in tail.chunks_exact_mut(4).enumerate() {
                    c.copy_from_slice(&w[4 + k].to_le_bytes());
                }
                let len = tail.iter().position(|&b| b == 0).unwrap_or(FILE_TAIL);
                Some(Crash::Panic(PanicSite {
                    file: FileTail::from_bytes(&tail[..len]),
                    line: w[2],
                    column: w[3],
                }))
            }
            KIND_HARDFAULT => Some(Crash::HardFault(FaultFrame {
                pc: w[2],
                lr: w[3],
                xpsr: w[4],
                cfsr: w[5],
                hfsr: w[6],
                mmfar: w[7],
                bfar: w[8],
            })),
            _ => None,
        }
    }
}

/// The RCC_CSR reset flags (the raw register value; other bits are ignored).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ResetFlags(pub u32);

impl ResetFlags {
    /// BOR reset flag (also set by a power-on).
    pub const BOR: u32 = 1 << 25;
    /// Pin reset flag (also set by every internal reset).
    pub const PIN: u32 = 1 << 26;
    /// POR/PDR reset flag.
    pub const POR: u32 = 1 << 27;
    /// Software reset flag.
    pub const SFT: u32 = 1 << 28;
    /// Independent watchdog reset flag.
    pub const IWDG: u32 = 1 << 29;
    /// Window watchdog reset flag.
    pub const WWDG: u32 = 1 << 30;
    /// Low-power reset flag.
    pub const LPWR: u32 = 1 << 31;

    fn has(self, bit: u32) -> bool {
        self.0 & bit != 0
    }
}

/// Why the board last reset.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ResetCause {
    /// Power-on (POR/PDR).
    PowerOn,
    /// Supply brown-out.
    BrownOut,
    /// The NRST pin (the Nucleo's reset button, or the debugger).
    Pin,
    /// A software reset without a crash record (a debugger's reset request, say).
    Software,
    /// The independent watchdog.
    Watchdog,
    /// The window watchdog (unused by this firmware).
    WindowWatchdog,
    /// An illegal entry into Stop/Standby.
    LowPower,
    /// The panic handler reset the board.
    Panic(PanicSite),
    /// The HardFault handler reset the board.
    HardFault(FaultFrame),
    /// No flag set (should not happen on the device).
    Unknown,
}

impl ResetCause {
    /// Combine the reset flags with the decoded crash record (see the module docs for the
    /// order). A record counts only with SFTRSTF: after any other reset it is stale or noise.
    pub fn from_reset(flags: ResetFlags, crash: Option<Crash>) -> Self {
        if flags.has(ResetFlags::POR) {
            Self::PowerOn
        } else if flags.has(ResetFlags::BOR) {
            Self::BrownOut
        } else if flags.has(ResetFlags::IWDG) {
            Self::Watchdog
        } else if flags.has(ResetFlags::WWDG) {
            Self::WindowWatchdog
        } else if flags.has(ResetFlags::LPWR) {
            Self::LowPower
        } else if flags.has(ResetFlags::SFT) {
            match crash {
                Some(Crash::Panic(p)) => Self::Panic(p),
                Some(Crash::HardFault(f)) => Self::HardFault(f),
                None => Self::Software,
            }
        } else if flags.has(ResetFlags::PIN) {
            Self::Pin
        } else {
            Self::Unknown
        }
    }

    /// Whether the reset was the firmware failing (watchdog, panic, HardFault): flag 13,
    /// latched until `clear`.
    pub fn is_fault(&self) -> bool {
        matches!(
            self,
            Self::Watchdog | Self::WindowWatchdog | Self::Panic(_) | Self::HardFault(_)
        )
    }

    /// The word naming the cause on the boot event line.
    pub fn name(&self) -> &'static str {
        match self {
            Self::PowerOn => "power-on",
            Self::BrownOut => "brown-out",
            Self::Pin => "pin",
            Self::Software => "software",
            Self::Watchdog => "watchdog",
            Self::WindowWatchdog => "window-watchdog",
            Self::LowPower => "low-power",
            Self::Panic(_) => "panic",
            Self::HardFault(_) => "hardfault",
            Self::Unknown => "unknown",
        }
    }

    /// Write `<name> [<details>…]`: a panic adds `<file> <line> <column>`, a HardFault
    /// `<pc> <lr> <xpsr> <cfsr> <hfsr> <mmfar> <bfar>` as `0x` and 8 hex digits, and
    /// `stack-overflow` when the frame could not be stacked ([`FaultFrame::stack_overflow`]).
    pub fn encode(&self, out: &mut impl Write) -> fmt::Result {
        out.write_str(self.name())?;
        match self {
            Self::Panic(p) => write!(out, " {} {} {}", p.file.as_str(), p.line, p.column),
            Self::HardFault(f) => {
                for x in [f.pc, f.lr, f.xpsr, f.cfsr, f.hfsr, f.mmfar, f.bfar] {
                    write!(out, " {x:#010x}")?;
                }
                if f.stack_overflow() {
                    out.write_str(" stack-overflow")?;
                }
                Ok(())
            }
            _ => Ok(()),
        }
    }

    /// Parse what [`encode`](Self::encode) wrote, pulling words from `next`. `None` for an
    /// unknown name or a missing or malformed detail.
    pub fn decode<'a>(mut next: impl FnMut() -> Option<&'a str>) -> Option<Self> {
        let hex = |w: &str| u32::from_str_radix(w.strip_prefix("0x")?, 16).ok();
        Some(match next()? {
            "power-on" => Self::PowerOn,
            "brown-out" => Self::BrownOut,
            "pin" => Self::Pin,
            "software" => Self::Software,
            "watchdog" => Self::Watchdog,
            "window-watchdog" => Self::WindowWatchdog,
            "low-power" => Self::LowPower,
            "unknown" => Self::Unknown,
            "panic" => {
                let file = next()?;
                if file.len() > FILE_TAIL {
                    return None;
                }
                Self::Panic(PanicSite {
                    file: FileTail::new(file),
                    line: next()?.parse().ok()?,
                    column: next()?.parse().ok()?,
                })
            }
            "hardfault" => {
                let mut v = [0u32; 7];
                for x in &mut v {
                    *x = hex(next()?)?;
                }
                let [pc, lr, xpsr, cfsr, hfsr, mmfar, bfar] = v;
                let frame = FaultFrame {
                    pc,
                    lr,
                    xpsr,
                    cfsr,
                    hfsr,
                    mmfar,
                    bfar,
                };
                if frame.stack_overflow() && next()? != "stack-overflow" {
                    return None;
                }
                Self::HardFault(frame)
            }
            _ => return None,
        })
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use proptest::prelude::*;

    fn site() -> PanicSite {
        PanicSite {
            file: FileTail::new("firmware/src/app.rs"),
            line: 412,
            column: 17,
        }
    }

    fn frame() -> FaultFrame {
        FaultFrame {
            pc: 0x0800_1234,
            lr: 0xFFFF_FFF9,
            xpsr: 0x6100_0003,
            cfsr: 0x0000_8200,
            hfsr: 0x4000_0000,
            mmfar: 0xE000_EDF8,
            bfar: 0x1FFF_FFFC,
        }
    }

    #[test]
    fn records_round_trip() {
        for c in [Crash::Panic(site()), Crash::HardFault(frame())] {
            assert_eq!(Crash::decode(&c.encode()), Some(c));
        }
    }

    #[test]
    fn record_layout_by_hand() {
        let w = Crash::Panic(site()).encode();
        assert_eq!(w[0], 0x5646_5243);
        assert_eq!(w[1], 1);
        assert_eq!((w[2], w[3]), (412, 17));
        // "firmware/src/app.rs" is 19 bytes: "firm", "ware", "/src", "/app", ".rs" and a 0.
        assert_eq!(w[4], u32::from_le_bytes(*b"firm"));
        assert_eq!(w[8], u32::from_le_bytes([b'.', b'r', b's', 0]));
        // The checksum is the standard CRC-32 (zlib's) of the 44 bytes before it.
        let mut bytes = std::vec::Vec::new();
        for x in &w[..11] {
            bytes.extend_from_slice(&x.to_le_bytes());
        }
        assert_eq!(w[11], crc32_bitwise(&bytes));
    }

    /// CRC-32/ISO-HDLC bit by bit (reflected polynomial 0xEDB88320), independent of the crate.
    pub(crate) fn crc32_bitwise(data: &[u8]) -> u32 {
        let mut c = 0xFFFF_FFFFu32;
        for &b in data {
            c ^= b as u32;
            for _ in 0..8 {
                c = if c & 1 != 0 {
                    (c >> 1) ^ 0xEDB8_8320
                } else {
                    c >> 1
                };
            }
        }
        !c
    }

    #[test]
    fn crc_matches_the_check_value() {
        // The catalogue's check value of CRC-32/ISO-HDLC for "123456789".
        assert_eq!(crc32_bitwise(b"123456789"), 0xCBF4_3926);
        assert_eq!(CRC32.checksum(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn long_paths_keep_their_end_and_odd_bytes_are_replaced() {
        let t = FileTail::new("/home/someone/.cargo/registry/src/crate-1.0/src/lib.rs");
        assert_eq!(t.as_str(), "try/src/crate-1.0/src/lib.rs");
        assert_eq!(t.as_str().len(), FILE_TAIL);
        assert_eq!(FileTail::new("a b\tc").as_str(), "a_b_c");
        assert_eq!(FileTail::new("").as_str(), "?");
        // Non-ASCII bytes (here the 2 bytes of "é") become one `_` each.
        assert_eq!(FileTail::new("é.rs").as_str(), "__.rs");
    }

    #[test]
    fn a_single_flipped_bit_invalidates_the_record() {
        let good = Crash::HardFault(frame()).encode();
        for word in 0..RECORD_WORDS {
            for bit in 0..32 {
                let mut w = good;
                w[word] ^= 1 << bit;
                assert_eq!(Crash::decode(&w), None, "word {word} bit {bit}");
            }
        }
    }

    #[test]
    fn erased_and_zeroed_ram_are_no_record() {
        assert_eq!(Crash::decode(&[0; RECORD_WORDS]), None);
        assert_eq!(Crash::decode(&[u32::MAX; RECORD_WORDS]), None);
    }

    proptest! {
        #[test]
        fn random_ram_is_no_record(w in proptest::array::uniform12(any::<u32>())) {
            prop_assert_eq!(Crash::decode(&w), None);
        }

        #[test]
        fn random_ram_with_the_magic_is_no_record(mut w in proptest::array::uniform12(any::<u32>()), kind in 0u32..4) {
            w[0] = MAGIC;
            w[1] = kind;
            prop_assert_eq!(Crash::decode(&w), None);
        }

        #[test]
        fn panic_sites_round_trip(path in "\\PC{0,60}", line in any::<u32>(), column in any::<u32>()) {
            let c = Crash::Panic(PanicSite { file: FileTail::new(&path), line, column });
            prop_assert_eq!(Crash::decode(&c.encode()), Some(c));
        }
    }

    // Register values as RM0390 documents them.
    const POWER_ON: u32 = ResetFlags::POR | ResetFlags::BOR | ResetFlags::PIN;
    const SOFTWARE: u32 = ResetFlags::SFT | ResetFlags::PIN;
    const WATCHDOG: u32 = ResetFlags::IWDG | ResetFlags::PIN;

    #[test]
    fn causes_from_the_reset_flags() {
        let panic = Some(Crash::Panic(site()));
        let fault = Some(Crash::HardFault(frame()));
        let cause = |f: u32, c| ResetCause::from_reset(ResetFlags(f), c);
        // LSION/LSIRDY (bits 0, 1) are not reset flags.
        assert_eq!(cause(POWER_ON | 0b11, None), ResetCause::PowerOn);
        // RAM after power-on is noise: even a record that happens to decode is ignored.
        assert_eq!(cause(POWER_ON, panic), ResetCause::PowerOn);
        assert_eq!(
            cause(ResetFlags::BOR | ResetFlags::PIN, None),
            ResetCause::BrownOut
        );
        assert_eq!(cause(WATCHDOG, None), ResetCause::Watchdog);
        // A crash record left by an earlier crash does not mask a later watchdog reset.
        assert_eq!(cause(WATCHDOG, panic), ResetCause::Watchdog);
        assert_eq!(cause(SOFTWARE, panic), ResetCause::Panic(site()));
        assert_eq!(cause(SOFTWARE, fault), ResetCause::HardFault(frame()));
        assert_eq!(cause(SOFTWARE, None), ResetCause::Software);
        assert_eq!(cause(ResetFlags::PIN, None), ResetCause::Pin);
        assert_eq!(cause(ResetFlags::PIN, panic), ResetCause::Pin);
        assert_eq!(
            cause(ResetFlags::WWDG | ResetFlags::PIN, None),
            ResetCause::WindowWatchdog
        );
        assert_eq!(
            cause(ResetFlags::LPWR | ResetFlags::PIN, None),
            ResetCause::LowPower
        );
        assert_eq!(cause(0, None), ResetCause::Unknown);
    }

    #[test]
    fn fault_classes_and_round_trips() {
        let all = [
            ResetCause::PowerOn,
            ResetCause::BrownOut,
            ResetCause::Pin,
            ResetCause::Software,
            ResetCause::Watchdog,
            ResetCause::WindowWatchdog,
            ResetCause::LowPower,
            ResetCause::Panic(site()),
            ResetCause::HardFault(frame()),
            ResetCause::Unknown,
        ];
        let faults: std::vec::Vec<_> = all
            .iter()
            .filter(|c| c.is_fault())
            .map(|c| c.name())
            .collect();
        assert_eq!(
            faults,
            ["watchdog", "window-watchdog", "panic", "hardfault"]
        );
        for c in all {
            let mut s = std::string::String::new();
            c.encode(&mut s).unwrap();
            let mut it = s.split_ascii_whitespace();
            assert_eq!(ResetCause::decode(|| it.next()), Some(c), "{s}");
            assert_eq!(it.next(), None);
        }
    }

    #[test]
    fn hardfault_words_by_hand() {
        let mut s = std::string::String::new();
        ResetCause::HardFault(frame()).encode(&mut s).unwrap();
        assert_eq!(
            s,
            "hardfault 0x08001234 0xfffffff9 0x61000003 0x00008200 0x40000000 0xe000edf8 0x1ffffffc"
        );
        let mut it = "hardfault 0x1 zz".split_ascii_whitespace();
        assert_eq!(ResetCause::decode(|| it.next()), None);
        let mut it = "panic a.rs 12".split_ascii_whitespace();
        assert_eq!(ResetCause::decode(|| it.next()), None);
    }

    #[test]
    fn a_fault_that_could_not_stack_its_frame_is_named_a_stack_overflow() {
        // What the handler records after an overflow under flip-link on a board: no frame in
        // RAM (PC, LR and xPSR all ones), CFSR with STKERR (bit 12) and PRECISERR + BFARVALID
        // (bits 9, 15) for the push below 0x2000_0000, HFSR.FORCED.
        let overflow = FaultFrame {
            pc: FaultFrame::NO_FRAME,
            lr: FaultFrame::NO_FRAME,
            xpsr: FaultFrame::NO_FRAME,
            cfsr: 0x0000_9200,
            hfsr: 0x4000_0000,
            mmfar: 0,
            bfar: 0x1fff_fff8,
        };
        assert!(overflow.stack_overflow());
        assert!(!frame().stack_overflow());
        // Either sign alone: a frame outside RAM (an emulator whose unmapped stores land nowhere
        // sets no STKERR), or STKERR with a frame the handler could still read.
        assert!(FaultFrame {
            cfsr: 0x0002_0000,
            ..overflow
        }
        .stack_overflow());
        assert!(FaultFrame {
            pc: 0x0800_1234,
            ..overflow
        }
        .stack_overflow());
        let cause = ResetCause::HardFault(overflow);
        let mut s = std::string::String::new();
        cause.encode(&mut s).unwrap();
        assert_eq!(
            s,
            "hardfault 0xffffffff 0xffffffff 0xffffffff 0x00009200 0x40000000 0x00000000 \
             0x1ffffff8 stack-overflow"
        );
        let mut it = s.split_ascii_whitespace();
        assert_eq!(ResetCause::decode(|| it.next()), Some(cause));
        assert_eq!(it.next(), None);
        // The word must match the registers: missing or another word is refused.
        let registers = s.trim_end_matches(" stack-overflow");
        let mut it = registers.split_ascii_whitespace();
        assert_eq!(ResetCause::decode(|| it.next()), None);
        let other = format!("{registers} stack");
        let mut it = other.split_ascii_whitespace();
        assert_eq!(ResetCause::decode(|| it.next()), None);
    }
}
