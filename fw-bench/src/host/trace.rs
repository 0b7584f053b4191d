//! The counter: one call per executed instruction (its PC, in trace order), and what the bench
//! program's markers and the interrupt mask did.
//!
//! - A region opens when the begin marker `fwb_begin_<name>` executes (its only instruction,
//!   `bx lr`, is not counted) and closes when `fwb_end` is entered. The branch into `fwb_end`
//!   (the instruction just before it) is not counted either, so a region's count is exactly the
//!   instructions the measured code executed.
//! - `fwb_retag_<name>` renames the region closed last.
//! - The counter models PRIMASK. cortex-m's `critical-section` implementation acquires with
//!   `mrs rX, PRIMASK; cpsid i` and releases with `msr PRIMASK, rX` (the saved value), strictly
//!   nested; the trace has no register values, so each `mrs … PRIMASK` pushes the modelled PRIMASK
//!   and each `msr PRIMASK, …` pops and restores it. A window starts when PRIMASK goes 0 → 1
//!   (`cpsid i`) and ends when it goes back to 0 (`cpsie i` or the outermost `msr`); its length
//!   counts both ends. An `msr` with nothing saved, a read left unpaired at the end, or a
//!   FAULTMASK write (`msr FAULTMASK`, `cps… f`) is an error.

use std::collections::HashMap;

/// What an executed instruction means to the counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// Anything else.
    Other,
    /// `cpsid i` (or `cpsid if`).
    IrqOff,
    /// `cpsie i` (or `cpsie if`).
    IrqOn,
    /// A branch (B, BL, BX, BLX; any form): the way into a marker.
    Branch,
    /// `mrs rX, PRIMASK`: a critical section saves the mask.
    PrimaskRead,
    /// `msr PRIMASK, rX`: a critical section restores it.
    PrimaskWrite,
    /// `msr FAULTMASK, …`, `cpsid f`, `cpsie f`: not followed by the counter.
    FaultMask,
    /// The first instruction of a marker function (see [`Layout::roles`]).
    Marker,
}

/// Decode the instruction that starts with halfword `h0` (followed by `h1`), Thumb-2.
pub fn decode(h0: u16, h1: u16) -> Kind {
    // CPS (T1): 1011 0110 011 im 0 A I F.
    if h0 & 0xffe8 == 0xb660 {
        let disable = h0 & 0x10 != 0;
        return match (h0 & 0x2 != 0, disable) {
            (true, true) => Kind::IrqOff,
            (true, false) => Kind::IrqOn,
            (false, _) if h0 & 0x1 != 0 => Kind::FaultMask,
            _ => Kind::Other,
        };
    }
    // BX / BLX (register): 0100 0111 L Rm 000.
    if h0 & 0xff00 == 0x4700 {
        return Kind::Branch;
    }
    // B (T2, unconditional, 16-bit): 11100 imm11.
    if h0 & 0xf800 == 0xe000 {
        return Kind::Branch;
    }
    // B (T1, conditional, 16-bit): 1101 cond imm8, cond not 1110/1111 (UDF, SVC).
    if h0 & 0xf000 == 0xd000 && h0 & 0x0e00 != 0x0e00 {
        return Kind::Branch;
    }
    // 32-bit encodings start with 0b11101, 0b11110 or 0b11111.
    if h0 & 0xf800 == 0xf000 {
        // B (T3/T4) and BL: 11110 … | 1 0/1 J1 x J2 …
        if h1 & 0x8000 != 0 && (h1 & 0x5000 != 0 || h1 & 0xd000 == 0x8000) {
            // Exclude the other "branches and miscellaneous control" encodings (MSR, MRS, hints,
            // barriers: h1 = 10x0 with op1 bits of h0 in 0b0111xxx).
            let misc = h1 & 0xd000 == 0x8000 && h0 & 0x0380 == 0x0380;
            if !misc {
                return Kind::Branch;
            }
        }
        // MSR (register), M profile: 1111 0011 1000 Rn | 1000 mask 00 SYSm.
        if h0 & 0xfff0 == 0xf380 && h1 & 0xf300 == 0x8000 {
            match h1 & 0xff {
                0x10 => return Kind::PrimaskWrite,
                0x13 => return Kind::FaultMask,
                _ => {}
            }
        }
        // MRS, M profile: 1111 0011 1110 1111 | 1000 Rd SYSm.
        if h0 == 0xf3ef && h1 & 0xf000 == 0x8000 && h1 & 0xff == 0x10 {
            return Kind::PrimaskRead;
        }
    }
    Kind::Other
}

/// What a marker address does.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// `fwb_begin_<name>`: index into the region names.
    Begin(usize),
    /// `fwb_end`.
    End,
    /// `fwb_retag_<name>`: index into the region names.
    Retag(usize),
    /// `fwb_script_begin`.
    ScriptBegin,
    /// `fwb_script_end`.
    ScriptEnd,
}

/// The program's code as the counter needs it: marker addresses and instruction kinds.
#[derive(Debug, Default)]
pub struct Layout {
    /// Region names (the `<name>` of the markers).
    pub names: Vec<String>,
    /// Marker address → role.
    pub roles: HashMap<u32, Role>,
    /// Lowest code address covered by `kinds`.
    pub base: u32,
    /// Kind of an instruction starting at `base + 2 i`.
    pub kinds: Vec<Kind>,
}

impl Layout {
    /// Index of a region name, added if new.
    pub fn name_index(&mut self, name: &str) -> usize {
        match self.names.iter().position(|n| n == name) {
            Some(i) => i,
            None => {
                self.names.push(name.to_owned());
                self.names.len() - 1
            }
        }
    }

    /// A marker at `addr`, in code added before by [`Layout::add_code`]; `false` if outside.
    pub fn add_role(&mut self, addr: u32, role: Role) -> bool {
        let off = addr.wrapping_sub(self.base) as usize / 2;
        match self.kinds.get_mut(off) {
            Some(k) => {
                *k = Kind::Marker;
                self.roles.insert(addr, role);
                true
            }
            None => false,
        }
    }

    /// Kind of the instruction at `pc` (`Other` outside the code).
    #[inline]
    pub fn kind(&self, pc: u32) -> Kind {
        let off = pc.wrapping_sub(self.base) as usize / 2;
        self.kinds.get(off).copied().unwrap_or(Kind::Other)
    }

    /// Decode every halfword of a code section (at `addr`, even) into `kinds`.
    pub fn add_code(&mut self, addr: u32, bytes: &[u8]) {
        if self.kinds.is_empty() {
            self.base = addr;
        }
        if addr < self.base {
            let shift = ((self.base - addr) / 2) as usize;
            self.kinds
                .splice(0..0, std::iter::repeat_n(Kind::Other, shift));
            self.base = addr;
        }
        let first = ((addr - self.base) / 2) as usize;
        let halves: Vec<u16> = bytes
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        if self.kinds.len() < first + halves.len() {
            self.kinds.resize(first + halves.len(), Kind::Other);
        }
        for (i, &h0) in halves.iter().enumerate() {
            let h1 = halves.get(i + 1).copied().unwrap_or(0);
            self.kinds[first + i] = decode(h0, h1);
        }
    }
}

/// One measured occurrence of a region.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Region {
    /// Index into [`Layout::names`].
    pub name: usize,
    /// Instructions executed by the measured code.
    pub insns: u64,
    /// Longest interrupts-off window closed inside it.
    pub max_irq_off: u64,
}

/// An interrupts-off window.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Window {
    /// Instructions from `cpsid i` to `cpsie i`, both included.
    pub len: u64,
    /// PC of the `cpsid i`.
    pub start_pc: u32,
    /// The region occurrence it closed in (index into [`Counts::regions`]), if any.
    pub region: Option<usize>,
}

/// The counter's result.
#[derive(Debug, Default)]
pub struct Counts {
    /// Regions in execution order.
    pub regions: Vec<Region>,
    /// Instructions executed in all.
    pub total: u64,
    /// Instructions between `fwb_script_begin` and `fwb_script_end`.
    pub script_insns: u64,
    /// Interrupts-off windows closed inside the scripted run.
    pub script_windows: u64,
    /// The longest of them.
    pub script_max_irq_off: Option<Window>,
}

struct Open {
    name: usize,
    insns: u64,
    last: Kind,
    max_irq_off: u64,
}

/// Feed it every executed PC in order ([`Counter::exec`]), then [`Counter::finish`].
pub struct Counter<'a> {
    layout: &'a Layout,
    idx: u64,
    open: Option<Open>,
    irq_off_since: Option<(u64, u32)>,
    /// PRIMASK values saved by `mrs` and not yet restored.
    saved: Vec<bool>,
    script_start: Option<u64>,
    script_done: bool,
    out: Counts,
}

impl<'a> Counter<'a> {
    /// A counter for a program with this layout.
    pub fn new(layout: &'a Layout) -> Self {
        Self {
            layout,
            idx: 0,
            open: None,
            irq_off_since: None,
            saved: Vec::new(),
            script_start: None,
            script_done: false,
            out: Counts::default(),
        }
    }

    /// One executed instruction.
    pub fn exec(&mut self, pc: u32) -> Result<(), String> {
        let pc = pc & !1;
        let idx = self.idx;
        self.idx += 1;
        let kind = self.layout.kind(pc);
        if kind == Kind::Marker {
            if let Some(&role) = self.layout.roles.get(&pc) {
                return self.marker(role, pc);
            }
        }
        match kind {
            Kind::IrqOff => self.set_primask(true, idx, pc),
            Kind::IrqOn => self.set_primask(false, idx, pc),
            Kind::PrimaskRead => self.saved.push(self.irq_off_since.is_some()),
            Kind::PrimaskWrite => {
                let v = self.saved.pop().ok_or_else(|| {
                    format!("`msr PRIMASK` at {pc:#010x} restores a value no `mrs` saved")
                })?;
                self.set_primask(v, idx, pc);
            }
            Kind::FaultMask => {
                return Err(format!(
                    "a FAULTMASK write executed at {pc:#010x}: the counter does not follow it"
                ));
            }
            Kind::Other | Kind::Branch | Kind::Marker => {}
        }
        if let Some(o) = &mut self.open {
            o.insns += 1;
            o.last = kind;
        }
        Ok(())
    }

    /// PRIMASK set (interrupts off) or cleared by the instruction `idx` at `pc`.
    fn set_primask(&mut self, off: bool, idx: u64, pc: u32) {
        match (off, self.irq_off_since) {
            (true, None) => self.irq_off_since = Some((idx, pc)),
            (false, Some((start, start_pc))) => {
                self.irq_off_since = None;
                self.window(Window {
                    len: idx - start + 1,
                    start_pc,
                    region: self.open.as_ref().map(|_| self.out.regions.len()),
                });
            }
            _ => {}
        }
    }

    fn window(&mut self, w: Window) {
        if let Some(o) = &mut self.open {
            o.max_irq_off = o.max_irq_off.max(w.len);
        }
        if self.script_start.is_some() && !self.script_done {
            self.out.script_windows += 1;
            if self.out.script_max_irq_off.is_none_or(|m| w.len > m.len) {
                self.out.script_max_irq_off = Some(w);
            }
        }
    }

    fn marker(&mut self, role: Role, pc: u32) -> Result<(), String> {
        let names = &self.layout.names;
        match role {
            Role::Begin(name) => {
                if let Some(o) = &self.open {
                    return Err(format!(
                        "region `{}` begins inside `{}`",
                        names[name], names[o.name]
                    ));
                }
                self.open = Some(Open {
                    name,
                    insns: 0,
                    last: Kind::Other,
                    max_irq_off: 0,
                });
            }
            Role::End => {
                let o = self
                    .open
                    .take()
                    .ok_or_else(|| format!("`fwb_end` ({pc:#010x}) outside any region"))?;
                if o.last != Kind::Branch || o.insns == 0 {
                    return Err(format!(
                        "region `{}` did not enter `fwb_end` by a branch",
                        names[o.name]
                    ));
                }
                self.out.regions.push(Region {
                    name: o.name,
                    insns: o.insns - 1,
                    max_irq_off: o.max_irq_off,
                });
            }
            Role::Retag(name) => {
                if self.open.is_some() {
                    return Err(format!("retag `{}` inside a region", names[name]));
                }
                let last = self
                    .out
                    .regions
                    .last_mut()
                    .ok_or_else(|| format!("retag `{}` before any region", names[name]))?;
                last.name = name;
            }
            Role::ScriptBegin => {
                if self.script_start.is_some() {
                    return Err("the scripted run began twice".into());
                }
                self.script_start = Some(self.idx);
            }
            Role::ScriptEnd => {
                let start = self
                    .script_start
                    .ok_or("the scripted run ended before it began")?;
                if self.script_done {
                    return Err("the scripted run ended twice".into());
                }
                // Instructions strictly between the two markers' `bx lr`.
                self.out.script_insns = self.idx - 1 - start;
                self.script_done = true;
            }
        }
        Ok(())
    }

    /// Instructions fed so far.
    pub fn instructions(&self) -> u64 {
        self.idx
    }

    /// The counts; an error if a region or the scripted run was left open.
    pub fn finish(mut self) -> Result<Counts, String> {
        if let Some(o) = &self.open {
            return Err(format!(
                "region `{}` never ended",
                self.layout.names[o.name]
            ));
        }
        if self.script_start.is_none() || !self.script_done {
            return Err("the scripted run did not complete".into());
        }
        if !self.saved.is_empty() {
            return Err(format!(
                "{} `mrs … PRIMASK` never restored: the PRIMASK model does not hold",
                self.saved.len()
            ));
        }
        self.out.total = self.idx;
        Ok(self.out)
    }
}

/// The PC of one QEMU `-d exec` line, `None` for any other line. The line reads
/// `Trace <cpu>: <host ptr> [<cs_base>/<pc>/<flags>…] [<symbol>]` (QEMU 7 to 10).
pub fn trace_pc(line: &[u8]) -> Option<u32> {
    let rest = line.strip_prefix(b"Trace ")?;
    let open = rest.iter().position(|&b| b == b'[')?;
    let rest = &rest[open + 1..];
    let slash = rest.iter().position(|&b| b == b'/')?;
    let rest = &rest[slash + 1..];
    let mut pc: u64 = 0;
    let mut digits = 0;
    for &b in rest {
        let d = match b {
            b'0'..=b'9' => b - b'0',
            b'a'..=b'f' => b - b'a' + 10,
            b'A'..=b'F' => b - b'A' + 10,
            b'/' => break,
            _ => return None,
        };
        pc = (pc << 4) | d as u64;
        digits += 1;
        if digits > 16 {
            return None;
        }
    }
    if digits == 0 {
        return None;
    }
    u32::try_from(pc).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    const BEGIN_A: u32 = 0x100;
    const BEGIN_B: u32 = 0x104;
    const END: u32 = 0x108;
    const RETAG_C: u32 = 0x10c;
    const S_BEGIN: u32 = 0x110;
    const S_END: u32 = 0x114;
    // Code at 0x200..: an `Other` at 0x200, a branch at 0x202, cpsid at 0x204, cpsie at 0x206,
    // an msr PRIMASK at 0x208, an mrs PRIMASK at 0x20c, an msr FAULTMASK at 0x210.
    const OTHER: u32 = 0x200;
    const BRANCH: u32 = 0x202;
    const CPSID: u32 = 0x204;
    const CPSIE: u32 = 0x206;
    const MSR: u32 = 0x208;
    const MRS: u32 = 0x20c;
    const MSR_F: u32 = 0x210;

    fn layout() -> Layout {
        let mut l = Layout::default();
        let a = l.name_index("a");
        let b = l.name_index("b");
        let c = l.name_index("c");
        // movs r0, #0 | bl (f000 f800) | cpsid i | cpsie i | msr PRIMASK, r0 (f380 8810)
        // | mrs r0, PRIMASK (f3ef 8010) | msr FAULTMASK, r0 (f380 8813)
        let code: [u16; 11] = [
            0x2000, 0xf000, 0xf800, 0xb672, 0xb662, 0xf380, 0x8810, 0xf3ef, 0x8010, 0xf380, 0x8813,
        ];
        let bytes: Vec<u8> = code.iter().flat_map(|h| h.to_le_bytes()).collect();
        // Lay them out so each starts where the constants say (the bl is 4 bytes).
        l.add_code(0x200, &bytes[0..2]);
        l.add_code(0x202, &bytes[2..6]);
        l.add_code(0x204, &bytes[6..8]);
        l.add_code(0x206, &bytes[8..10]);
        l.add_code(0x208, &bytes[10..14]);
        l.add_code(0x20c, &bytes[14..18]);
        l.add_code(0x210, &bytes[18..22]);
        // The markers: `bx lr` each.
        l.add_code(0x100, &[0x70, 0x47].repeat(12));
        for (addr, role) in [
            (BEGIN_A, Role::Begin(a)),
            (BEGIN_B, Role::Begin(b)),
            (END, Role::End),
            (RETAG_C, Role::Retag(c)),
            (S_BEGIN, Role::ScriptBegin),
            (S_END, Role::ScriptEnd),
        ] {
            assert!(l.add_role(addr, role));
        }
        assert!(!l.add_role(0x1000, Role::End));
        assert_eq!(l.kind(0x200), Kind::Other);
        assert_eq!(l.kind(0x116), Kind::Branch);
        assert_eq!(l.kind(0x118), Kind::Other);
        l
    }

    fn run(l: &Layout, pcs: &[u32]) -> Result<Counts, String> {
        let mut c = Counter::new(l);
        for &pc in pcs {
            c.exec(pc)?;
        }
        c.finish()
    }

    fn region(body: usize) -> Vec<u32> {
        let mut v = vec![BEGIN_A];
        v.extend(std::iter::repeat_n(OTHER, body));
        v.extend([BRANCH, END]);
        v
    }

    fn scripted(inner: Vec<u32>) -> Vec<u32> {
        let mut v = vec![OTHER, S_BEGIN];
        v.extend(inner);
        v.extend([S_END, OTHER]);
        v
    }

    #[test]
    fn decodes_the_interrupt_mask_and_branch_encodings() {
        assert_eq!(decode(0xb672, 0), Kind::IrqOff); // cpsid i
        assert_eq!(decode(0xb662, 0), Kind::IrqOn); // cpsie i
        assert_eq!(decode(0xb673, 0), Kind::IrqOff); // cpsid if
        assert_eq!(decode(0xb671, 0), Kind::FaultMask); // cpsid f
        assert_eq!(decode(0xf380, 0x8810), Kind::PrimaskWrite); // msr PRIMASK, r0
        assert_eq!(decode(0xf386, 0x8810), Kind::PrimaskWrite); // msr PRIMASK, r6
        assert_eq!(decode(0xf381, 0x8813), Kind::FaultMask); // msr FAULTMASK, r1
        assert_eq!(decode(0xf380, 0x8811), Kind::Other); // msr BASEPRI, r0
        assert_eq!(decode(0xf3ef, 0x8010), Kind::PrimaskRead); // mrs r0, PRIMASK
        assert_eq!(decode(0xf3ef, 0x8410), Kind::PrimaskRead); // mrs r4, PRIMASK
        assert_eq!(decode(0xf3ef, 0x8009), Kind::Other); // mrs r0, PSP
        assert_eq!(decode(0xf3bf, 0x8f4f), Kind::Other); // dsb sy
        assert_eq!(decode(0xf000, 0xf800), Kind::Branch); // bl
        assert_eq!(decode(0xf7ff, 0xbffe), Kind::Branch); // b.w
        assert_eq!(decode(0xf43f, 0xaffe), Kind::Branch); // beq.w
        assert_eq!(decode(0x4770, 0), Kind::Branch); // bx lr
        assert_eq!(decode(0x4788, 0), Kind::Branch); // blx r1
        assert_eq!(decode(0xe7fe, 0), Kind::Branch); // b .
        assert_eq!(decode(0xd1fc, 0), Kind::Branch); // bne
        assert_eq!(decode(0xdf00, 0), Kind::Other); // svc 0
        assert_eq!(decode(0xbf00, 0), Kind::Other); // nop
        assert_eq!(decode(0x2032, 0), Kind::Other); // movs r0, #50
    }

    #[test]
    fn a_region_counts_exactly_its_body() {
        let l = layout();
        for body in [0, 1, 100] {
            let c = run(&l, &scripted(region(body))).unwrap();
            assert_eq!(c.regions.len(), 1);
            assert_eq!(c.regions[0].insns, body as u64);
            assert_eq!(c.regions[0].name, 0);
        }
        // Instructions outside regions are not counted in any, but are in the total.
        let c = run(
            &l,
            &scripted([region(3), vec![OTHER; 7], region(5)].concat()),
        )
        .unwrap();
        let n: Vec<u64> = c.regions.iter().map(|r| r.insns).collect();
        assert_eq!(n, [3, 5]);
        // 2 + (1 + 3 + 2) + 7 + (1 + 5 + 2) + 2 fed instructions.
        assert_eq!(c.total, 25);
        assert_eq!(c.script_insns, 25 - 4);
    }

    #[test]
    fn a_repeated_pc_counts_each_time() {
        // A loop: the same two PCs fifty times.
        let l = layout();
        let mut v = vec![BEGIN_A, OTHER];
        for _ in 0..50 {
            v.extend([OTHER, BRANCH]);
        }
        v.extend([BRANCH, END]);
        let c = run(&l, &scripted(v)).unwrap();
        assert_eq!(c.regions[0].insns, 101);
    }

    #[test]
    fn interrupt_windows_count_both_ends_and_ignore_nesting() {
        let l = layout();
        // cpsid, 40 others, cpsie inside a region: a 42-instruction window and region.
        let mut v = vec![BEGIN_A, CPSID];
        v.extend(std::iter::repeat_n(OTHER, 40));
        v.extend([CPSIE, BRANCH, END]);
        let c = run(&l, &scripted(v)).unwrap();
        assert_eq!(c.regions[0].insns, 42);
        assert_eq!(c.regions[0].max_irq_off, 42);
        let w = c.script_max_irq_off.unwrap();
        assert_eq!((w.len, w.start_pc, w.region), (42, CPSID, Some(0)));
        // Nested: the inner cpsid does not restart the window; a stray cpsie is ignored.
        let v = vec![
            CPSIE, CPSID, OTHER, CPSID, OTHER, OTHER, CPSIE, OTHER, CPSID, CPSIE,
        ];
        let c = run(&l, &scripted(v)).unwrap();
        let w = c.script_max_irq_off.unwrap();
        assert_eq!((w.len, w.region), (6, None));
        assert_eq!(c.script_windows, 2);
    }

    #[test]
    fn critical_sections_restored_by_msr_nest() {
        let l = layout();
        // acquire (mrs, cpsid) · 3 · acquire (mrs, cpsid) · 2 · release (msr) · 4 · release (msr):
        // interrupts go off at the first cpsid and on at the last msr only.
        let mut v = vec![
            MRS, CPSID, OTHER, OTHER, OTHER, MRS, CPSID, OTHER, OTHER, MSR,
        ];
        v.extend([OTHER, OTHER, OTHER, OTHER, MSR, OTHER]);
        let c = run(&l, &scripted(v)).unwrap();
        let w = c.script_max_irq_off.unwrap();
        assert_eq!((w.len, w.start_pc), (14, CPSID));
        assert_eq!(c.script_windows, 1);
        // A critical section entered with interrupts already off restores "off".
        let v = vec![CPSID, MRS, CPSID, OTHER, MSR, OTHER, CPSIE];
        let c = run(&l, &scripted(v)).unwrap();
        assert_eq!(c.script_max_irq_off.unwrap().len, 7);
    }

    #[test]
    fn windows_outside_the_script_are_not_reported() {
        let l = layout();
        let v = vec![CPSID, OTHER, OTHER, CPSIE, S_BEGIN, CPSID, CPSIE, S_END];
        let c = run(&l, &v).unwrap();
        assert_eq!(c.script_max_irq_off.unwrap().len, 2);
        assert_eq!(c.script_windows, 1);
    }

    #[test]
    fn retag_renames_the_last_region() {
        let l = layout();
        let v = scripted([region(2), vec![RETAG_C]].concat());
        let c = run(&l, &v).unwrap();
        assert_eq!(l.names[c.regions[0].name], "c");
        // A window inside the retagged region is reported in it under its new name.
        let mut v = vec![
            BEGIN_A, OTHER, BRANCH, END, BEGIN_A, CPSID, CPSIE, BRANCH, END, RETAG_C,
        ];
        v.extend(region(1));
        let c = run(&l, &scripted(v)).unwrap();
        let w = c.script_max_irq_off.unwrap();
        assert_eq!(w.region, Some(1));
        assert_eq!(l.names[c.regions[w.region.unwrap()].name], "c");
    }

    #[test]
    fn protocol_errors_are_reported() {
        let l = layout();
        // Nested regions.
        let v = scripted(vec![BEGIN_A, OTHER, BEGIN_B, BRANCH, END, BRANCH, END]);
        assert!(run(&l, &v).unwrap_err().contains("inside"));
        // An end without a begin.
        assert!(run(&l, &scripted(vec![BRANCH, END])).is_err());
        // An end not reached by a branch.
        assert!(run(&l, &scripted(vec![BEGIN_A, OTHER, END])).is_err());
        // A region never closed, a script never ended.
        assert!(run(&l, &scripted(vec![BEGIN_A, OTHER])).is_err());
        assert!(run(&l, &[S_BEGIN, OTHER]).is_err());
        // A PRIMASK restore nothing saved, a save never restored, a FAULTMASK write.
        assert!(run(&l, &scripted(vec![CPSID, MSR]))
            .unwrap_err()
            .contains("PRIMASK"));
        assert!(run(&l, &scripted(vec![MRS, CPSID, CPSIE]))
            .unwrap_err()
            .contains("PRIMASK"));
        assert!(run(&l, &scripted(vec![MSR_F]))
            .unwrap_err()
            .contains("FAULTMASK"));
        // A retag before any region.
        assert!(run(&l, &scripted(vec![RETAG_C])).is_err());
    }

    #[test]
    fn reads_the_pc_of_qemu_exec_lines() {
        // QEMU 7.2 and 8+ (with flags and cflags), with and without a symbol.
        let l7 = b"Trace 0: 0x7f3a44000100 [00000000/08000400/00000000/ff200000] Reset\n";
        let l8 = b"Trace 0: 0x7f8e2c00a840 [00000000/0000000008001a2c/10200000/ff200000] \n";
        assert_eq!(trace_pc(l7), Some(0x0800_0400));
        assert_eq!(trace_pc(l8), Some(0x0800_1a2c));
        assert_eq!(trace_pc(b"Linking TBs 0x7f.. index 0 -> 0x7f..\n"), None);
        assert_eq!(trace_pc(b"Trace 0: 0x7f [00000000/zz/0/0]\n"), None);
        assert_eq!(trace_pc(b"Trace 0: 0x7f [00000000//0/0]\n"), None);
        assert_eq!(trace_pc(b""), None);
    }
}
