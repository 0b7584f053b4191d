//! Faults on the real firmware: the stepper drivers are disabled from the first instructions,
//! by every fault handler, and after a fault reset until the host clears it; the cause is
//! readable on the command port.

use std::time::Duration;

use rig_emu::rig::status_flags;
use rig_emu::{default_elf, fault_injection_elf, Rig, RigConfig};
use rigless::time::VirtualNanos;

/// ADC1's data register (RM0390 13.13.14), which the sampler reads.
const ADC1_DR: u64 = 0x4001_204C;
/// TIM5's CR1 (RM0390 16.4.1): the counter of embassy's time driver.
const TIM5_CR1: u64 = 0x4000_0C00;

fn rig() -> Rig {
    Rig::start(&RigConfig::new(default_elf())).expect("the virtual rig starts")
}

fn enabled(rig: &mut Rig) -> bool {
    rig.with(|_, b| b.enabled).unwrap()
}

#[test]
fn the_drivers_are_disabled_from_the_first_instructions_until_the_board_runs() {
    let mut rig = rig();
    rig.run_for(Duration::from_millis(20)).unwrap();
    let changes = rig.with(|_, b| b.enable_changes.clone()).unwrap();
    // From reset the enable input floats and the driver's pull-down enables it; the firmware's
    // first instructions drive it high.
    assert_eq!(changes.first(), Some(&(0, true)), "{changes:?}");
    let (off_at, off) = changes[1];
    assert!(
        !off && off_at < 100_000,
        "EN driven high at {off_at} ns: {changes:?}"
    );
    // Disabled through the clock start-up and the boot, until the stepper task runs.
    let status = rig.until_zeroed().unwrap();
    assert!(status.ends_with("reset power-on"), "{status}");
    assert!(enabled(&mut rig), "enabled after a clean boot");
    let changes = rig.with(|_, b| b.enable_changes.clone()).unwrap();
    assert_eq!(changes.len(), 3, "{changes:?}");
    assert!(changes[2].0 > 1_000_000, "{changes:?}");
}

#[test]
fn a_hardfault_disables_the_drivers_and_they_stay_disabled_until_clear() {
    let mut rig = rig();
    rig.until_zeroed().unwrap();
    assert!(enabled(&mut rig));
    // The sampler's next read of ADC1's data register fails on the bus: a precise BusFault,
    // escalated to HardFault (no BusFault handler is enabled).
    rig.fail_next(ADC1_DR, ADC1_DR + 4).unwrap();
    let boot = rig
        .next_boot(Duration::from_secs(2))
        .unwrap()
        .expect("the board restarts and says why");
    assert!(boot.contains(" boot 0 hardfault 0x"), "{boot}");
    safe_after_fault(&mut rig, "hardfault 0x");
    // The host clears the fault: the drivers come back.
    assert_eq!(rig.command("clear").unwrap().as_deref(), Some("ok"));
    rig.run_for(Duration::from_millis(10)).unwrap();
    assert!(enabled(&mut rig), "clear re-enables the drivers");
}

#[test]
fn stuck_tasks_are_reset_by_the_watchdog_and_the_drivers_stay_disabled() {
    let mut rig = rig();
    rig.until_zeroed().unwrap();
    // The time driver's counter stopped under the firmware (TIM5's CEN cleared): no timer ever
    // fires again, the sampler stops and with it the watchdog's feed.
    rig.poke(TIM5_CR1, 0).unwrap();
    let boot = rig
        .next_boot(Duration::from_secs(2))
        .unwrap()
        .expect("the watchdog resets the board");
    assert!(boot.contains(" boot 1 watchdog"), "{boot}");
    let status = rig.command("status").unwrap().expect("a reply");
    assert!(status.ends_with(" reset watchdog"), "{status}");
    rig.run_for(Duration::from_millis(500)).unwrap();
    assert!(!enabled(&mut rig), "drivers enabled after a watchdog reset");
}

/// The `fault-injection` build (the same binary but for a task that reads the user button).
fn fault_rig() -> Rig {
    let elf = fault_injection_elf();
    assert!(
        elf.exists(),
        "no fault-injection ELF at {}: `cargo fw --features fault-injection`, then copy \
         target/thumbv7em-none-eabihf/firmware/vfp-fw to that name (rig-emu/README.md)",
        elf.display()
    );
    Rig::start(&RigConfig::new(elf)).expect("the virtual rig starts")
}

/// A zeroed fault-injection rig whose user button is held for `held`: the boot line that
/// follows (the fault's reset).
fn fault_boot(held: Duration) -> (Rig, String) {
    let mut rig = fault_rig();
    rig.until_zeroed().unwrap();
    assert!(enabled(&mut rig));
    press(&mut rig, held);
    let boot = rig
        .next_boot(Duration::from_secs(2))
        .unwrap()
        .expect("the board restarts and says why");
    (rig, boot)
}

/// Hold the user button for `held`, then release it.
fn press(rig: &mut Rig, held: Duration) {
    let at = rig.now_ns();
    rig.with(move |s, _| s.board_mut().press_user_button(VirtualNanos(at), true))
        .unwrap();
    rig.run_for(held).unwrap();
    let at = rig.now_ns();
    rig.with(move |s, _| s.board_mut().press_user_button(VirtualNanos(at), false))
        .unwrap();
}

/// After a fault reset: the drivers disabled, the cause on the command port, and half a second
/// later still disabled, motion refused for the fault (the positions declared, so that the
/// refusal is the fault's and not `origin-needed`'s) until `clear`.
fn safe_after_fault(rig: &mut Rig, cause: &str) -> String {
    let (resets, changes) = rig
        .with(|s, b| (s.resets().len(), b.enable_changes.clone()))
        .unwrap();
    assert_eq!(resets, 1, "one reset");
    assert!(
        !changes.last().unwrap().1,
        "the drivers are disabled: {changes:?}"
    );
    let status = rig.command("status").unwrap().expect("a reply");
    assert!(status.contains(&format!(" reset {cause}")), "{status}");
    assert!(
        status_flags(&status).unwrap() & firmware::telemetry::Flags::FAULT_RESET != 0,
        "{status}"
    );
    rig.run_for(Duration::from_millis(500)).unwrap();
    assert!(!enabled(rig), "drivers re-enabled without clear");
    assert_eq!(rig.command("origin all 0").unwrap().as_deref(), Some("ok"));
    let refused = rig.command("move 0 10 50").unwrap().expect("a reply");
    assert_eq!(refused, "err faulted");
    assert_eq!(rig.with(|_, b| b.steps.len()).unwrap(), 0);
    status
}

#[test]
fn a_stack_overflow_ends_in_a_fault_record_and_the_safe_state() {
    // Held for 1.2 s: the firmware recurses without end. Under flip-link the stack runs out at
    // 0x2000_0000; the HardFault's frame cannot be stacked there, and a handler that ran on
    // that stack would lock the core up (no record, the drivers left enabled).
    let (mut rig, boot) = fault_boot(Duration::from_millis(1200));
    assert!(boot.contains(" boot 0 hardfault 0x"), "{boot}");
    assert!(boot.ends_with(" stack-overflow"), "{boot}");
    let status = safe_after_fault(&mut rig, "hardfault");
    assert!(status.ends_with(" stack-overflow"), "{status}");
    // Why it says so: the handler found the frame outside RAM (no stacked PC, LR, xPSR). On a
    // board the bus also refuses the stacking (CFSR.STKERR); rigless answers an access to an
    // address it maps to nothing with zero instead of a bus error, so here the recursion ran on
    // below 0x2000_0000 until it returned through a zero and faulted (INVSTATE), and the
    // emulator lists those accesses.
    let words: Vec<&str> = status.split_whitespace().collect();
    let at = words.iter().position(|w| *w == "hardfault").unwrap();
    assert_eq!(words[at + 1..at + 4], ["0xffffffff"; 3], "{status}");
    let below: Vec<u64> = rig
        .with(|s, _| s.unmapped().iter().map(|u| u.address).collect())
        .unwrap();
    assert!(
        below.iter().any(|a| (0x1fff_f000..0x2000_0000).contains(a)),
        "the stack ran below RAM: {below:x?}"
    );
}

#[test]
fn a_panic_ends_in_a_fault_record_and_the_safe_state() {
    // A short press: a panic.
    let (mut rig, boot) = fault_boot(Duration::from_millis(200));
    assert!(
        boot.contains(" boot 0 panic firmware/src/bin/vfp-fw.rs "),
        "{boot}"
    );
    safe_after_fault(&mut rig, "panic");
}
