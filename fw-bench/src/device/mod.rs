//! The bench program (runs under QEMU on a Cortex-M4: `netduinoplus2`, flash at 0x0800_0000).
//!
//! Measurement protocol, read by the runner from the execution trace:
//! - every measured operation runs between a call to a *begin marker* `fwb_begin_<region>` and
//!   a call to the *end marker* `fwb_end`; markers are naked functions (one `bx lr`, never
//!   inlined) whose addresses the runner reads from the ELF's symbol table. The count of a region
//!   is the number of instructions executed after the begin marker returned and before the call
//!   instruction into `fwb_end` (that `bl` is not counted);
//! - `fwb_retag_<region>`, called right after a region, renames the region just closed (a frame
//!   turns out to have run the drift check only once it is done);
//! - `fwb_script_begin` / `fwb_script_end` bracket the scripted run, over which the runner
//!   reports the longest interrupts-disabled window;
//! - the calibration regions come first and have known lengths (see [`calibrate`]).
//!
//! The program ends through semihosting (`exit 0`, or `exit 1` after a message on a panic or a
//! fault), so QEMU terminates by itself.

mod fw;
mod script;

use core::arch::asm;
use core::panic::PanicInfo;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::{debug, hprintln};

/// Defines the marker functions: each is a naked `bx lr` with an unmangled symbol.
macro_rules! markers {
    ($($name:ident),* $(,)?) => {
        $(
            #[unsafe(naked)]
            #[unsafe(no_mangle)]
            pub extern "C" fn $name() {
                core::arch::naked_asm!("bx lr")
            }
        )*
    };
}

pub(crate) mod marks {
    markers!(
        fwb_end,
        fwb_script_begin,
        fwb_script_end,
        // calibration
        fwb_begin_calib_empty,
        fwb_begin_calib_nop100,
        fwb_begin_calib_loop50,
        fwb_begin_calib_irq40,
        fwb_begin_calib_cs40,
        // stepper task
        fwb_begin_step_accel,
        fwb_begin_step_cruise,
        fwb_begin_step_batch3,
        // sampler task
        fwb_begin_oversample,
        fwb_begin_frame,
        fwb_begin_frame_rls,
        fwb_retag_frame_rls_drift,
        fwb_begin_frame_chain,
        fwb_begin_telemetry_line,
        // command task
        fwb_begin_cmd_status,
        fwb_begin_cmd_move,
        fwb_begin_cmd_run,
        fwb_begin_cmd_model_begin,
        fwb_begin_cmd_model_coef,
        fwb_begin_cmd_model_commit,
        fwb_begin_cmd_model_effect,
        fwb_begin_cmd_model_read,
        fwb_begin_cmd_model_read_coef,
        fwb_begin_cmd_limit,
        fwb_begin_cmd_origin,
        fwb_begin_cmd_stop,
        fwb_begin_cmd_clear,
        fwb_begin_cmd_rls,
        fwb_begin_cmd_zero,
    );
}

/// Run `op` between the begin marker `begin` and the end marker.
#[inline(always)]
pub(crate) fn measure<R>(begin: extern "C" fn(), op: impl FnOnce() -> R) -> R {
    begin();
    let r = op();
    marks::fwb_end();
    r
}

/// Regions of known length; the runner checks each count exactly and stops if one is off.
fn calibrate() {
    // Nothing between the markers: 0.
    measure(marks::fwb_begin_calib_empty, || {});
    // 100 `nop`s: 100.
    measure(marks::fwb_begin_calib_nop100, || unsafe {
        asm!(
            ".rept 100",
            "nop",
            ".endr",
            options(nomem, nostack, preserves_flags)
        );
    });
    // A loop of 50 trips: 1 (`movs`) + 50 × 2 (`subs`, `bne`) = 101.
    measure(marks::fwb_begin_calib_loop50, || unsafe {
        asm!(
            "movs {r}, #50",
            "2:",
            "subs {r}, #1",
            "bne 2b",
            r = out(reg) _,
            options(nomem, nostack),
        );
    });
    // Interrupts off for `cpsid i`, 40 `nop`s, `cpsie i`: a 42-instruction window (both ends
    // counted), and a 42-instruction region.
    measure(marks::fwb_begin_calib_irq40, || unsafe {
        asm!(
            "cpsid i",
            ".rept 40",
            "nop",
            ".endr",
            "cpsie i",
            options(nomem, nostack)
        );
    });
    // Two nested critical sections the way cortex-m's `critical-section` implementation does
    // them (save PRIMASK, `cpsid i`; restore PRIMASK by `msr`): interrupts are off from the
    // outer `cpsid` to the outer `msr`, 1 + 20 + (1 + 1 + 5 + 1) + 10 + 1 = 40 instructions;
    // the region also counts the outer `mrs`: 41.
    measure(marks::fwb_begin_calib_cs40, || unsafe {
        asm!(
            "mrs {outer}, PRIMASK",
            "cpsid i",
            ".rept 20",
            "nop",
            ".endr",
            "mrs {inner}, PRIMASK",
            "cpsid i",
            ".rept 5",
            "nop",
            ".endr",
            "msr PRIMASK, {inner}",
            ".rept 10",
            "nop",
            ".endr",
            "msr PRIMASK, {outer}",
            outer = out(reg) _,
            inner = out(reg) _,
            options(nomem, nostack),
        );
    });
}

#[entry]
fn main() -> ! {
    // RTT as the board binary sets it up (`vfp-fw.rs`): channel 0 for defmt (rtt-target is the
    // defmt global logger), channel 1 for the telemetry lines, non-blocking.
    let rtt = rtt_target::rtt_init! {
        up: {
            0: { size: fw::DEFMT_RTT_BYTES, name: "defmt" }
            1: {
                size: fw::TELEMETRY_RTT_BYTES,
                mode: rtt_target::ChannelMode::NoBlockSkip,
                name: "telemetry"
            }
        }
    };
    rtt_target::set_defmt_channel(rtt.up.0);
    calibrate();
    marks::fwb_script_begin();
    let summary = script::run(rtt.up.1);
    marks::fwb_script_end();
    hprintln!("fw-bench: {}", summary);
    debug::exit(debug::EXIT_SUCCESS);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[panic_handler]
fn panic(info: &PanicInfo) -> ! {
    hprintln!("fw-bench: panic: {}", info);
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[exception]
unsafe fn HardFault(ef: &ExceptionFrame) -> ! {
    hprintln!("fw-bench: HardFault at pc {:#010x}", ef.pc());
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}
