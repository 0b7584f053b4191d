//! The NUCLEO-F446RE as a rigless board: the MCU, its clock and rail, the ST-LINK's virtual COM
//! port on USART2 as the host's wire, and the pins the actuation board uses
//! (`firmware::board`'s pin map).
//!
//! The MCU model is rigless's STM32F427, the F446's sibling in the F4 family. What the firmware
//! uses of the two is the same register map (RCC, PWR, FLASH, GPIO, USART2, DMA1, TIM5, ADC1,
//! IWDG, DBGMCU) with two differences, both harmless to this firmware and checked by the tests:
//! - `RCC_DCKCFGR2` (F446 only) is not modelled; embassy writes it once with 0 (the 48 MHz clock
//!   from the PLL's Q output, which the firmware never uses);
//! - the F427 has 2 MiB of flash where the F446 has 512 KiB: the program (256 KiB) and the model
//!   store (sectors 6 and 7, 0x0804_0000..0x0808_0000) sit at the same addresses on both.

use std::num::{NonZeroU32, NonZeroU64};

use rigless::chip::uart;
use rigless::cpu;
use rigless::device::Level;
use rigless::machine::{armv7m, Board, Crystal, HostWire, Supply, Target};
use rigless::mcu::{Mcu, Operate};
use rigless::snapshot::Store;
use rigless::soc::stm32f427::peripherals::adc::Channel;
use rigless::soc::stm32f427::peripherals::gpio::Pin;
use rigless::soc::stm32f427::Stm32f427;
use rigless::soc::Error;
use rigless::time::VirtualNanos;

use crate::host::HostPort;

/// The board's name (`rigless run --machine`).
pub const NAME: &str = "nucleo-f446re";
/// The one MCU's target name.
pub const MCU_NAME: &str = "stm32f446re";
/// The host's wire: the ST-LINK's virtual COM port.
pub const HOST_WIRE: &str = "USART2";
/// USART2's index in rigless's `SERIAL_PORTS`.
const USART2: usize = 1;

/// A GPIO pin as (port index in `PORTS`: 0 = A, 1 = B, …, pin number).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PinId {
    /// Port index (0 = GPIOA).
    pub port: usize,
    /// Pin number 0..16.
    pub pin: u8,
}

const fn pa(pin: u8) -> PinId {
    PinId { port: 0, pin }
}
const fn pb(pin: u8) -> PinId {
    PinId { port: 1, pin }
}

/// STEP outputs by axis (`firmware::board::STEP_PINS`: PA10, PB3, PB5).
pub const STEP: [PinId; 3] = [pa(10), pb(3), pb(5)];
/// DIR outputs by axis (`firmware::board::DIR_PINS`: PB4, PB10, PA8). High = inflate.
pub const DIR: [PinId; 3] = [pb(4), pb(10), pa(8)];
/// The drivers' shared enable (`firmware::board::ENABLE_PIN`: PA9), active low.
pub const ENABLE: PinId = pa(9);
/// The Nucleo's user button B1: PC13, pulled up on the board, low while pressed (UM1724 6.5).
pub const USER_BUTTON: PinId = PinId { port: 2, pin: 13 };
/// The sensors' ADC1 channels (`firmware::board::SENSOR_PINS`: PA0, PA1, PA4 = IN0, IN1, IN4).
pub const SENSOR_CHANNELS: [u8; 3] = [0, 1, 4];

/// The ADC's reference and inputs are given in microvolts, not millivolts: the converter model
/// answers the ratio of input to reference (RM0090 13.4), so the unit cancels, and a millivolt
/// (1.24 LSB at 3.3 V) would be coarser than the converter. 3.3 V, VDDA on the Nucleo.
pub const ADC_REFERENCE_UV: u32 = 3_300_000;

/// The Nucleo's clocks and rail: the ST-LINK's 8 MHz MCO into HSE (bypass), 3.3 V.
const HSE_HZ: u64 = 8_000_000;
const RAIL_MV: u32 = 3300;

/// The F446's Cortex-M4F at 180 MHz with 4 priority bits.
const CLOCK_HZ: NonZeroU64 = NonZeroU64::new(180_000_000).expect("a running clock");
const REFCLK_DIVIDER: NonZeroU32 = NonZeroU32::new(8).expect("SysTick's reference is HCLK/8");
const PRIORITY_BITS: u8 = 4;

/// The board: the MCU and what is wired to it.
#[derive(Debug)]
pub struct Nucleo {
    /// The MCU (rigless's STM32F427 model; see the module docs).
    pub mcu: Stm32f427,
    /// The ST-LINK's 8 MHz clock on HSE.
    pub hse: Crystal,
    /// The 3.3 V rail.
    pub rail: Supply,
}

impl Nucleo {
    /// A board out of the box: sensors at 0 kPa gauge, nothing on the host's wire yet.
    pub fn new() -> Result<Self, Error> {
        let mut board = Self {
            mcu: Stm32f427::new()?,
            hse: Crystal(HSE_HZ),
            rail: Supply(RAIL_MV),
        };
        board.mcu.rcc.attach_crystals(board.hse.0, Crystal::NONE.0);
        board.mcu.set_supply(board.rail.0);
        for converter in &mut board.mcu.adc {
            converter.set_reference(ADC_REFERENCE_UV);
            converter.set_backup_battery(RAIL_MV);
        }
        board.set_sensor_counts([counts_at_zero(); 3]);
        board.mcu.usart[USART2].attach(HostPort::default());
        // The stepper drivers' enable input has a pull-down (DRV8825 nENBL, A4988 ENABLE): while
        // the MCU does not drive EN, it reads low, drivers enabled. The MCU's output overrides it.
        let en = Pin::new(ENABLE.pin).expect("a port has sixteen pins");
        board
            .mcu
            .drive_port(VirtualNanos(0), ENABLE.port, |gpio, registers, context| {
                gpio.drive(en, Some(Level::Low), registers, context);
            });
        board.press_user_button(VirtualNanos(0), false);
        Ok(board)
    }

    /// Press (`true`) or release the user button B1 at `at`. Only the `fault-injection` build
    /// of the firmware reads it (`firmware/Cargo.toml`).
    pub fn press_user_button(&mut self, at: VirtualNanos, pressed: bool) {
        let pin = Pin::new(USER_BUTTON.pin).expect("a port has sixteen pins");
        let level = if pressed { Level::Low } else { Level::High };
        self.mcu
            .drive_port(at, USER_BUTTON.port, |gpio, registers, context| {
                gpio.drive(pin, Some(level), registers, context);
            });
    }

    /// Put the voltage that reads `counts` (a 12-bit conversion result) on each sensor's pin.
    pub fn set_sensor_counts(&mut self, counts: [u16; 3]) {
        for (ch, c) in SENSOR_CHANNELS.iter().zip(counts) {
            let channel = Channel::new(*ch).expect("a pin channel");
            self.mcu.adc[0].set_input(channel, counts_to_uv(c));
        }
    }

    /// The electrical level on `pin` now.
    pub fn level(&mut self, pin: PinId) -> Level {
        let (port, registers) = self.mcu.port(pin.port);
        port.level(
            Pin::new(pin.pin).expect("a port has sixteen pins"),
            registers,
        )
    }

    /// The host's end of USART2.
    pub fn host(&mut self) -> &mut HostPort {
        self.mcu.usart[USART2]
            .chip_mut::<HostPort>()
            .expect("the board hangs a HostPort on USART2")
    }

    /// USART2's line conditions (noise and framing errors on words arriving at the MCU).
    pub fn host_line_errors(&mut self) -> &mut uart::Errors {
        self.mcu.usart[USART2].errors_mut()
    }
}

/// The pin voltage, µV, whose conversion (floor of `uV · 4095 / reference`) is `counts`: the middle
/// of the code's bin.
pub fn counts_to_uv(counts: u16) -> u32 {
    let c = u64::from(counts.min(4095));
    let bin = u64::from(ADC_REFERENCE_UV) * 2 * c + u64::from(ADC_REFERENCE_UV);
    u32::try_from(bin / (2 * 4095)).expect("below the reference")
}

/// The conversion result of a sensor at 0 kPa gauge (the firmware's own transfer function).
pub fn counts_at_zero() -> u16 {
    firmware::board::kpa_to_counts(0.0).round() as u16
}

impl Store for Nucleo {}

impl Board for Nucleo {
    fn name(&self) -> &'static str {
        NAME
    }

    fn target_names(&self) -> Vec<&'static str> {
        vec![MCU_NAME]
    }

    fn mcu(&mut self, target: usize) -> Option<&mut dyn Mcu> {
        (target == 0).then_some(&mut self.mcu)
    }

    fn targets(&mut self) -> Vec<Target<'_>> {
        let core = armv7m::Core {
            variant: armv7m::Variant::M4,
            clock_hz: CLOCK_HZ,
            interrupt_lines: NonZeroU32::new(u32::from(Operate::cpu(&self.mcu).interrupt_lines))
                .expect("an MCU with interrupts"),
            priority_bits: PRIORITY_BITS,
            refclk_divider: REFCLK_DIVIDER,
            instructions_per_second: armv7m::INSTRUCTIONS_PER_SECOND,
            boot: "flash",
        }
        .spec_with_parts(
            &cpu::armv7m::windows(Mcu::bus(&self.mcu)),
            armv7m::Fpu::FpV4Sp,
            armv7m::MpuRegions::Eight,
        );
        vec![Target::new(MCU_NAME, &mut self.mcu, core)]
    }

    fn hosts(&self) -> Vec<HostWire> {
        vec![HostWire {
            name: HOST_WIRE,
            port: 5760,
        }]
    }

    fn attach_host(&mut self, name: &str, peer: Box<dyn uart::Peer>) -> bool {
        if name != HOST_WIRE {
            return false;
        }
        self.mcu.usart[USART2].attach_boxed(peer);
        true
    }

    fn host_mut(&mut self, name: &str) -> Option<&mut dyn uart::Peer> {
        if name != HOST_WIRE {
            return None;
        }
        self.mcu.usart[USART2].peer_mut()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_pin_voltage_converts_back_to_its_code() {
        // The converter model: floor(uV * 4095 / reference).
        for c in [0_u16, 1, 775, 776, 2048, 3877, 4094, 4095] {
            let uv = u64::from(counts_to_uv(c));
            let code = (uv * 4095 / u64::from(ADC_REFERENCE_UV)).min(4095);
            assert_eq!(code, u64::from(c), "code {c} at {uv} uV");
        }
    }

    #[test]
    fn zero_kpa_reads_the_firmware_zero() {
        // 0 kPa -> 1.0 V at the sensor -> 0.625 V at the pin -> 775.57 counts (by hand).
        assert_eq!(counts_at_zero(), 776);
    }
}
