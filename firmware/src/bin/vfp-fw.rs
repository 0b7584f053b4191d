//! Embassy wiring for the actuation board: clocks, pins, ADC, UART, watchdog, tasks.
//! Everything else is in the library (`firmware::app`), tested on the host.
//!
//! Stepper timing: task based. The stepper task awaits `Timer::at(planned instant)` for the
//! earliest due step on a 1 MHz time base (`tick-hz-1_000_000`), then `Shared::stepper_tick`
//! records every step due at that instant on any axis in one short critical section and pulses
//! them together (all STEP pins high, 2 µs, all low), so same-instant steps on three axes land
//! within a few cycles of each other. The task runs on an interrupt executor at a higher
//! priority than everything else, and no critical section anywhere lasts more than a few
//! hundred instructions (estimation, RLS, replies and telemetry run with interrupts on), so a
//! step is late only by the time-driver alarm plus the executor poll, a few µs. Per step: one
//! `f32` square root in the ramps or one integer product while cruising (`firmware::motion`),
//! no `f64`. Hardware-timer stepping (a timer's output compare per axis, the next compare value
//! written from its interrupt) would cut the jitter to the timer's clock, but needs one timer
//! channel per axis on pins the CNC-shield layout does not offer, and the same per-step instant
//! computation in the interrupt; at 10 000 steps/s per axis the few-µs software jitter is below
//! 5 % of a step interval, so it is not taken.
//!
//! Telemetry: its own RTT up-channel 1 ("telemetry"), in non-blocking mode, written whole lines
//! at a time without a critical section (`rtt-target`); a line that does not fit is dropped and
//! counted in the next frame's `drops` field. defmt logs keep channel 0 ("defmt", which
//! `probe-rs run` switches to blocking mode); they are only the boot message and a panic.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod device {
    use embassy_executor::{InterruptExecutor, Spawner};
    use embassy_stm32::interrupt;
    use embassy_stm32::interrupt::{InterruptExt, Priority};
    use embassy_stm32::time::Hertz;
    use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
    use embassy_stm32::wdg::IndependentWatchdog;
    use embassy_stm32::{bind_interrupts, peripherals};
    use firmware::app::{self, Config, Shared};
    use firmware::board::device::{self as board, DeviceAdc, DeviceSteppers, DeviceWatchdog};
    use firmware::hal;
    use panic_probe as _;
    use static_cell::StaticCell;

    bind_interrupts!(struct Irqs {
        USART2 => usart::InterruptHandler<peripherals::USART2>;
        DMA1_STREAM5 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH5>;
        DMA1_STREAM6 => embassy_stm32::dma::InterruptHandler<peripherals::DMA1_CH6>;
    });

    /// Application state shared by the tasks.
    static SHARED: StaticCell<Shared> = StaticCell::new();
    /// The command port's DMA receive ring.
    static RX_BUF: StaticCell<[u8; 256]> = StaticCell::new();
    /// High-priority executor for the stepper task (see the module docs).
    static EXECUTOR_HIGH: InterruptExecutor = InterruptExecutor::new();

    /// Watchdog timeout: 10 oversampling periods missed in a row (sampler feeds every 5 ms).
    const WATCHDOG_TIMEOUT_US: u32 = 50_000;

    #[interrupt]
    unsafe fn UART4() {
        // SAFETY: UART4 is unused by the board and serves only as the executor's interrupt.
        unsafe { EXECUTOR_HIGH.on_interrupt() }
    }

    /// RTT up-channel sizes: defmt logs (boot message, panics) and telemetry (~7.5 KB/s: a
    /// 4 KiB buffer holds half a second of it while the host is busy).
    const DEFMT_RTT_BYTES: usize = 1024;
    const TELEMETRY_RTT_BYTES: usize = 4096;

    /// Telemetry on its own RTT up-channel, non-blocking: a whole line or nothing.
    ///
    /// `UpChannel::write` takes no critical section (the channel is owned by this sink alone),
    /// copies the line and publishes it with one store of the write pointer, so the host only
    /// ever reads whole lines. In `NoBlockSkip` mode a line that does not fit is not written at
    /// all and `write` returns less than its length: the sampler counts it as dropped. The mode
    /// is set again before every line, so a host that switched the channel to blocking cannot
    /// make the board wait.
    struct RttSink(rtt_target::UpChannel);
    impl hal::TelemetrySink for RttSink {
        fn try_send(&mut self, line: &str) -> bool {
            self.0.set_mode(rtt_target::ChannelMode::NoBlockSkip);
            self.0.write(line.as_bytes()) == line.len()
        }
    }

    /// The command port: DMA transmit, DMA ring-buffered receive that reports receive errors.
    struct Serial {
        tx: UartTx<'static, embassy_stm32::mode::Async>,
        rx: RingBufferedUartRx<'static>,
    }
    impl hal::SerialPort for Serial {
        async fn read(&mut self, buf: &mut [u8]) -> Result<usize, hal::SerialError> {
            // After an error the driver restarts reception (the ring's unread bytes are lost
            // with it): the line being received is reported corrupt.
            self.rx.read(buf).await.map_err(|e| match e {
                usart::Error::Framing => hal::SerialError::Framing,
                usart::Error::Noise => hal::SerialError::Noise,
                usart::Error::Parity => hal::SerialError::Parity,
                _ => hal::SerialError::Overrun,
            })
        }
        async fn write_all(&mut self, data: &[u8]) {
            let _ = self.tx.write(data).await;
        }
    }

    #[embassy_executor::task]
    async fn stepper(shared: &'static Shared, s: DeviceSteppers) {
        app::stepper_task(shared, s).await
    }

    #[embassy_executor::task]
    async fn sampler(shared: &'static Shared, adc: DeviceAdc, tlm: RttSink, wdg: DeviceWatchdog) {
        app::sampler_task(shared, adc, tlm, wdg).await
    }

    #[embassy_executor::task]
    async fn command(shared: &'static Shared, port: Serial) {
        app::command_task(shared, port).await
    }

    /// 180 MHz from the ST-LINK's 8 MHz clock (HSE bypass): 8 / 4 × 180 / 2.
    fn clocks() -> embassy_stm32::Config {
        use embassy_stm32::rcc::*;
        let mut c = embassy_stm32::Config::default();
        c.rcc.hse = Some(Hse {
            freq: Hertz(8_000_000),
            mode: HseMode::Bypass,
        });
        c.rcc.pll_src = PllSource::HSE;
        c.rcc.pll = Some(Pll {
            prediv: PllPreDiv::DIV4,
            mul: PllMul::MUL180,
            divp: Some(PllPDiv::DIV2),
            divq: None,
            divr: None,
        });
        c.rcc.sys = Sysclk::PLL1_P;
        c.rcc.ahb_pre = AHBPrescaler::DIV1;
        c.rcc.apb1_pre = APBPrescaler::DIV4;
        c.rcc.apb2_pre = APBPrescaler::DIV2;
        c
    }

    #[embassy_executor::main]
    async fn main(spawner: Spawner) {
        // RTT first, so `probe-rs run` finds the control block at once.
        let rtt = rtt_target::rtt_init! {
            up: {
                0: { size: DEFMT_RTT_BYTES, name: "defmt" }
                1: {
                    size: TELEMETRY_RTT_BYTES,
                    mode: rtt_target::ChannelMode::NoBlockSkip,
                    name: "telemetry"
                }
            }
        };
        rtt_target::set_defmt_channel(rtt.up.0);
        let telemetry = RttSink(rtt.up.1);

        // Read the reset cause before init, then clear the flags for the next boot.
        let csr = embassy_stm32::pac::RCC.csr().read();
        let watchdog_reset = csr.wdgrstf();
        embassy_stm32::pac::RCC.csr().modify(|w| w.set_rmvf(true));

        let p = embassy_stm32::init(clocks());
        let (steppers, adc, rest) = board::split(p);

        let mut uart_cfg = usart::Config::default();
        uart_cfg.baudrate = 115_200;
        let uart = defmt::unwrap!(Uart::new(
            rest.usart,
            rest.rx,
            rest.tx,
            rest.tx_dma,
            rest.rx_dma,
            Irqs,
            uart_cfg,
        ));
        let (tx, rx) = uart.split();
        let serial = Serial {
            tx,
            rx: rx.into_ring_buffered(RX_BUF.init([0; 256])),
        };

        let mut iwdg = IndependentWatchdog::new(rest.iwdg, WATCHDOG_TIMEOUT_US);
        iwdg.unleash();

        let shared: &'static Shared = SHARED.init(Shared::new(Config {
            watchdog_reset,
            ..Config::default()
        }));
        defmt::info!("vfp-fw booted (watchdog reset: {})", watchdog_reset);

        interrupt::UART4.set_priority(Priority::P6);
        let high = EXECUTOR_HIGH.start(interrupt::UART4);
        high.spawn(defmt::unwrap!(stepper(shared, steppers)));
        spawner.spawn(defmt::unwrap!(sampler(
            shared,
            adc,
            telemetry,
            DeviceWatchdog(iwdg)
        )));
        spawner.spawn(defmt::unwrap!(command(shared, serial)));
    }
}

/// On the host this binary is only a placeholder: the firmware runs on the board or in `host-sim`.
#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("vfp-fw is device firmware: build it with `cargo fw`, simulate it with `cargo vfp simulate`");
}
