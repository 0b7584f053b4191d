//! The board: pin map and pressure-sensor transfer function, in one place.
//!
//! Default board: NUCLEO-F446RE with a CNC-shield-style layout on the Arduino header.
//!
//! | signal | Arduino | STM32 pin | peripheral |
//! | --- | --- | --- | --- |
//! | STEP axis 0 / 1 / 2 | D2 / D3 / D4 | PA10 / PB3 / PB5 | GPIO out |
//! | DIR axis 0 / 1 / 2 | D5 / D6 / D7 | PB4 / PB10 / PA8 | GPIO out |
//! | EN (all drivers, active low) | D8 | PA9 | GPIO out |
//! | sensor 0 / 1 / 2 (through divider) | A0 / A1 / A2 | PA0 / PA1 / PA4 | ADC1 IN0 / IN1 / IN4 |
//! | command port TX / RX | (ST-LINK VCP) | PA2 / PA3 | USART2 |
//!
//! # Sensor transfer function
//! Assumption (state it on the bench): the Nidec Copal P-7100 is an amplified gauge transducer
//! supplied from 5 V whose output rises linearly from [`SENSOR_V_ZERO`] at 0 kPa to
//! [`SENSOR_V_FULL`] at [`SENSOR_FULL_SCALE_KPA`]. Its output exceeds 3.3 V, so each sensor
//! feeds the ADC through a divider `R_TOP` / `R_BOTTOM` (ratio [`DIVIDER_RATIO`]). With a
//! 12-bit ADC referenced to [`ADC_VREF`]:
//!
//! ```text
//! V_adc    = counts · V_ref / 4095
//! V_sensor = V_adc / r,                r = R_bottom / (R_top + R_bottom)
//! P        = (V_sensor − V_zero) · P_fs / (V_full − V_zero)      [kPa]
//! ```
//!
//! [`counts_to_kpa`] and [`kpa_to_counts`] are exact inverses of each other over the reals
//! (the simulator uses the second one to synthesise ADC readings). A per-channel zero taken at
//! start (syringes at rest) removes the sensor's offset tolerance, so `V_zero` only needs to be
//! nominal.

/// Number of pressure channels on the board.
pub const CHANNELS: usize = crate::hal::AXES;

/// STEP outputs, by axis (STM32 pin names, for documentation and the README).
pub const STEP_PINS: [&str; CHANNELS] = ["PA10", "PB3", "PB5"];
/// DIR outputs, by axis.
pub const DIR_PINS: [&str; CHANNELS] = ["PB4", "PB10", "PA8"];
/// Shared active-low driver enable.
pub const ENABLE_PIN: &str = "PA9";
/// Sensor inputs, by channel (ADC1).
pub const SENSOR_PINS: [&str; CHANNELS] = ["PA0", "PA1", "PA4"];

/// First byte of the model store ([`crate::store`]) in the address space: flash sectors 6 and
/// 7 of the STM32F446RE (2 × 128 KiB). Sequential-storage needs at least two erase pages; the
/// F446's sectors 0–3 are 16 KiB, 4 is 64 KiB and 5–7 are 128 KiB, so the last two sectors are
/// the two pages, and the program keeps sectors 0–5 (256 KiB, `memory.x`'s FLASH). Smaller
/// sectors would not spare the erase stall either: a 16 KiB erase takes 0.25–0.5 s, still far
/// beyond the 50 ms watchdog (see [`crate::store`] for how the board handles it).
pub const STORE_START: u32 = 0x0804_0000;
/// One past the model store's last byte (the end of the 512 KiB flash).
pub const STORE_END: u32 = 0x0808_0000;
/// Start of the flash region embassy-stm32 calls `bank1_region3` (sectors 5–7): the store's
/// offsets are counted from here.
pub const REGION3_START: u32 = 0x0802_0000;

/// ADC full-scale code (12-bit, right aligned).
pub const ADC_MAX: u16 = 4095;
/// ADC reference voltage (VDDA on the Nucleo), volts.
pub const ADC_VREF: f32 = 3.3;
/// Divider top resistor (sensor output to ADC pin), ohms.
pub const R_TOP: f32 = 12_000.0;
/// Divider bottom resistor (ADC pin to ground), ohms.
pub const R_BOTTOM: f32 = 20_000.0;
/// Divider ratio `V_adc / V_sensor`: 5 V of sensor output reads 3.125 V, inside the ADC range.
pub const DIVIDER_RATIO: f32 = R_BOTTOM / (R_TOP + R_BOTTOM);
/// Sensor output at 0 kPa gauge, volts (nominal; the start-up zero absorbs the tolerance).
pub const SENSOR_V_ZERO: f32 = 1.0;
/// Sensor output at full scale, volts.
pub const SENSOR_V_FULL: f32 = 5.0;
/// Sensor full scale, kPa gauge.
pub const SENSOR_FULL_SCALE_KPA: f32 = 100.0;

/// Readings at or below this count are a sensor at the low rail: 0.2 V at the sensor, i.e.
/// −20 kPa. Fast deflation near an empty chamber sucks to about −15 kPa (the paper's SBA1 law at
/// −100 mm³/s), which must still read; lower means an open or shorted wire.
pub const RAIL_LOW_COUNTS: u16 = 155;
/// Readings at or above this count saturate the ADC: the sensor is above its range or a wire is
/// shorted to the supply.
pub const RAIL_HIGH_COUNTS: u16 = ADC_MAX - 8;

/// kPa per volt at the sensor output.
const KPA_PER_SENSOR_VOLT: f32 = SENSOR_FULL_SCALE_KPA / (SENSOR_V_FULL - SENSOR_V_ZERO);

/// ADC counts (may be a fractional average of several conversions) to volts at the ADC pin.
pub fn counts_to_adc_volts(counts: f32) -> f32 {
    counts * (ADC_VREF / ADC_MAX as f32)
}

/// Volts at the ADC pin to volts at the sensor output (undoes the divider).
pub fn adc_volts_to_sensor_volts(v_adc: f32) -> f32 {
    v_adc / DIVIDER_RATIO
}

/// Sensor output volts to gauge pressure in kPa (before the per-channel zero).
pub fn sensor_volts_to_kpa(v_sensor: f32) -> f32 {
    (v_sensor - SENSOR_V_ZERO) * KPA_PER_SENSOR_VOLT
}

/// Gauge pressure in kPa to sensor output volts.
pub fn kpa_to_sensor_volts(kpa: f32) -> f32 {
    kpa / KPA_PER_SENSOR_VOLT + SENSOR_V_ZERO
}

/// ADC counts (possibly averaged, hence `f32`) to gauge pressure in kPa.
pub fn counts_to_kpa(counts: f32) -> f32 {
    sensor_volts_to_kpa(adc_volts_to_sensor_volts(counts_to_adc_volts(counts)))
}

/// Gauge pressure in kPa to the ADC reading it produces (real-valued; round and clamp to
/// `0..=ADC_MAX` to get a conversion result). Inverse of [`counts_to_kpa`].
pub fn kpa_to_counts(kpa: f32) -> f32 {
    kpa_to_sensor_volts(kpa) * DIVIDER_RATIO * (ADC_MAX as f32 / ADC_VREF)
}

/// Whether a single conversion sits at a rail (sensor fault).
pub fn at_rail(counts: u16) -> bool {
    counts <= RAIL_LOW_COUNTS || counts >= RAIL_HIGH_COUNTS
}

/// The board's hardware behind the [`hal`](crate::hal) traits (device builds only).
#[cfg(target_os = "none")]
pub mod device {
    use embassy_stm32::adc::{Adc, AdcChannel, AnyAdcChannel, SampleTime};
    use embassy_stm32::gpio::{Level, Output, Speed};
    use embassy_stm32::peripherals::{ADC1, FLASH, IWDG};
    use embassy_stm32::wdg::IndependentWatchdog;
    use embassy_stm32::{Peri, Peripherals};
    use embassy_time::Instant;

    use crate::hal::{self, Direction, AXES};

    /// STEP pulse width in CPU cycles: 2 µs at 180 MHz, above the DRV8825's 1.9 µs minimum
    /// (A4988: 1 µs, TMC2209: 100 ns).
    const STEP_PULSE_CYCLES: u32 = 360;

    /// STEP/DIR/EN outputs.
    pub struct DeviceSteppers {
        step: [Output<'static>; AXES],
        dir: [Output<'static>; AXES],
        enable: Output<'static>,
    }

    impl hal::Steppers for DeviceSteppers {
        fn set_direction(&mut self, axis: usize, dir: Direction) {
            // High = inflate (plunger forward); swap a motor's coil pair if it runs backwards.
            self.dir[axis].set_level(match dir {
                Direction::Inflate => Level::High,
                Direction::Deflate => Level::Low,
            });
        }
        fn step(&mut self, axis: usize, _at: Instant) {
            self.step[axis].set_high();
            cortex_m::asm::delay(STEP_PULSE_CYCLES);
            self.step[axis].set_low();
        }
        fn step_axes(&mut self, axes: u8, _at: Instant) {
            // All STEP lines rise within a few cycles, share one pulse width, fall together.
            for a in 0..AXES {
                if axes & (1 << a) != 0 {
                    self.step[a].set_high();
                }
            }
            cortex_m::asm::delay(STEP_PULSE_CYCLES);
            for a in 0..AXES {
                if axes & (1 << a) != 0 {
                    self.step[a].set_low();
                }
            }
        }
        fn set_enabled(&mut self, enabled: bool) {
            // The drivers' EN input is active low.
            self.enable
                .set_level(if enabled { Level::Low } else { Level::High });
        }
    }

    /// ADC1 with the three sensor channels.
    pub struct DeviceAdc {
        adc: Adc<'static, ADC1>,
        ch: [AnyAdcChannel<'static, ADC1>; AXES],
    }

    impl hal::PressureAdc for DeviceAdc {
        async fn read(&mut self) -> [u16; AXES] {
            // Blocking single conversions: 3 × (84 + 12) ADC cycles at 22.5 MHz ≈ 13 µs per
            // oversample, cheaper than setting up a DMA transfer for three values.
            core::array::from_fn(|i| {
                self.adc
                    .blocking_read(&mut self.ch[i], SampleTime::CYCLES84)
            })
        }
    }

    /// The independent watchdog.
    pub struct DeviceWatchdog(pub IndependentWatchdog<'static, IWDG>);

    impl hal::Watchdog for DeviceWatchdog {
        fn feed(&mut self) {
            self.0.pet();
        }
    }

    /// Peripherals the binary wires up itself (interrupt bindings and buffers live there).
    pub struct Rest {
        /// Command port.
        pub usart: Peri<'static, embassy_stm32::peripherals::USART2>,
        /// USART2 TX (ST-LINK VCP).
        pub tx: Peri<'static, embassy_stm32::peripherals::PA2>,
        /// USART2 RX (ST-LINK VCP).
        pub rx: Peri<'static, embassy_stm32::peripherals::PA3>,
        /// USART2 TX DMA (DMA1 stream 6, channel 4).
        pub tx_dma: Peri<'static, embassy_stm32::peripherals::DMA1_CH6>,
        /// USART2 RX DMA (DMA1 stream 5, channel 4).
        pub rx_dma: Peri<'static, embassy_stm32::peripherals::DMA1_CH5>,
        /// Watchdog.
        pub iwdg: Peri<'static, IWDG>,
        /// Flash controller (the model store).
        pub flash: Peri<'static, FLASH>,
        /// The Nucleo's user button B1 (PC13: external pull-up, low while pressed). Unused by
        /// the firmware a lab flashes; the `fault-injection` build reads it.
        pub user_button: Peri<'static, embassy_stm32::peripherals::PC13>,
    }

    /// Split the chip's peripherals by the pin map above: steppers (disabled), ADC, the rest.
    pub fn split(p: Peripherals) -> (DeviceSteppers, DeviceAdc, Rest) {
        let out = |pin: Peri<'static, embassy_stm32::gpio::AnyPin>, level| {
            Output::new(pin, level, Speed::VeryHigh)
        };
        let steppers = DeviceSteppers {
            step: [
                out(p.PA10.into(), Level::Low),
                out(p.PB3.into(), Level::Low),
                out(p.PB5.into(), Level::Low),
            ],
            dir: [
                out(p.PB4.into(), Level::Low),
                out(p.PB10.into(), Level::Low),
                out(p.PA8.into(), Level::Low),
            ],
            enable: out(p.PA9.into(), Level::High),
        };
        let adc = DeviceAdc {
            adc: Adc::new(p.ADC1),
            ch: [
                p.PA0.degrade_adc(),
                p.PA1.degrade_adc(),
                p.PA4.degrade_adc(),
            ],
        };
        let rest = Rest {
            usart: p.USART2,
            tx: p.PA2,
            rx: p.PA3,
            tx_dma: p.DMA1_CH6,
            rx_dma: p.DMA1_CH5,
            iwdg: p.IWDG,
            flash: p.FLASH,
            user_button: p.PC13,
        };
        (steppers, adc, rest)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zero_and_full_scale_by_hand() {
        // 0 kPa -> 1.0 V sensor -> 0.625 V at the pin -> 0.625 / 3.3 * 4095 = 775.568 counts.
        assert!((kpa_to_counts(0.0) - 775.568).abs() < 1e-2);
        // 100 kPa -> 5.0 V -> 3.125 V -> 3877.84 counts.
        assert!((kpa_to_counts(100.0) - 3877.84).abs() < 1e-2);
        // 1 kPa is 0.04 V at the sensor, 31.02 counts.
        assert!((kpa_to_counts(1.0) - kpa_to_counts(0.0) - 31.023).abs() < 1e-2);
    }

    #[test]
    fn directions_are_inverse_for_every_code() {
        for c in 0..=ADC_MAX {
            let back = kpa_to_counts(counts_to_kpa(c as f32));
            assert_eq!(back.round() as u16, c, "code {c}");
            assert!((back - c as f32).abs() < 2e-3, "code {c}: {back}");
        }
    }

    #[test]
    fn the_program_ends_where_the_model_store_begins() {
        // memory.x must leave the store's sectors to the store.
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../memory.x");
        let text = std::fs::read_to_string(path).unwrap();
        let flash = text
            .lines()
            .find(|l| l.trim_start().starts_with("FLASH"))
            .unwrap();
        assert!(flash.contains("ORIGIN = 0x08000000"), "{flash}");
        assert!(flash.contains("LENGTH = 256K"), "{flash}");
        assert_eq!(0x0800_0000 + 256 * 1024, STORE_START);
        // Two whole 128 KiB sectors (6 and 7), at offsets 128 KiB..384 KiB of region 3.
        assert_eq!(STORE_END - STORE_START, 2 * 128 * 1024);
        assert_eq!(STORE_START - REGION3_START, 128 * 1024);
        assert_eq!(STORE_END, 0x0800_0000 + 512 * 1024);
    }

    #[test]
    fn rails_lie_outside_the_sensor_range() {
        // The whole 0..full-scale span reads clear of both rails.
        assert!(!at_rail(kpa_to_counts(0.0) as u16));
        assert!(!at_rail(kpa_to_counts(SENSOR_FULL_SCALE_KPA) as u16));
        assert!(at_rail(0));
        assert!(at_rail(ADC_MAX));
    }
}
