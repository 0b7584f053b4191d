//! The status bits every telemetry frame carries (its `flags` field), one definition for the
//! firmware that sets them and the host tools that read them (the frame line, the binary packet,
//! the log's `flags` column).
//!
//! Faults (bits 0..=15) stop motion and latch until `clear`; warnings (bits 16..) do not.
//! Per-channel flags take three bits, one per channel ([`Flags::channel`]).

/// Fault and warning bits carried by every frame.
///
/// Faults (bits 0..=15) stop motion and latch until `clear`; warnings (bits 16..) do not.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Flags(pub u32);

impl Flags {
    /// Pressure above the channel's limit (bit 0 + channel).
    pub const OVER_PRESSURE: u32 = 1 << 0;
    /// Volume outside `0..=capacity` (bit 3 + channel).
    pub const VOLUME_LIMIT: u32 = 1 << 3;
    /// Sensor reading at a rail (bit 6 + channel).
    pub const SENSOR_RAIL: u32 = 1 << 6;
    /// Sensor reading jumped implausibly between two conversions (bit 9 + channel).
    pub const SENSOR_JUMP: u32 = 1 << 9;
    /// Motion stopped by a `stop` command (cleared by the next motion command).
    pub const STOPPED: u32 = 1 << 12;
    /// The last reset was the firmware failing: the watchdog, a panic or a HardFault (fault
    /// until cleared; the boot event says which).
    pub const FAULT_RESET: u32 = 1 << 13;
    /// Former name of [`FAULT_RESET`](Self::FAULT_RESET), from when only the watchdog set it.
    pub const WATCHDOG_RESET: u32 = Self::FAULT_RESET;
    /// The pressure zero has not been taken yet (warning).
    pub const NOT_ZEROED: u32 = 1 << 16;
    /// Model evaluation failed (input outside the model's range) on a channel (bit 17 + channel).
    pub const MODEL_RANGE: u32 = 1 << 17;
    /// Stiffness or damping drifted from its baseline on a channel (bit 20 + channel): an air
    /// pocket, per the paper's Sec. IV-A.
    pub const DRIFT: u32 = 1 << 20;
    /// Online RLS is active on a channel (bit 23 + channel).
    pub const RLS_ACTIVE: u32 = 1 << 23;
    /// The axis' position is unknown after a reset other than power-on: motion is refused
    /// until `origin` declares it (bit 26 + channel; `clear` does not lift it).
    pub const ORIGIN_NEEDED: u32 = 1 << 26;
    /// A committed model is not in flash yet (or its write failed): see the firmware's `store`.
    pub const MODEL_UNSAVED: u32 = 1 << 29;
    /// Writing a committed model to flash failed.
    pub const STORE_FAILED: u32 = 1 << 30;

    /// Bits that stop motion and latch.
    pub const FAULT_MASK: u32 = 0xFFFF & !Self::STOPPED;

    /// The bit of a per-channel flag for channel `ch`.
    pub const fn channel(base: u32, ch: usize) -> u32 {
        base << ch
    }
    /// Whether any latched fault is set.
    pub const fn is_fault(self) -> bool {
        self.0 & Self::FAULT_MASK != 0
    }
    /// Whether `bit` is set.
    pub const fn has(self, bit: u32) -> bool {
        self.0 & bit != 0
    }
}
