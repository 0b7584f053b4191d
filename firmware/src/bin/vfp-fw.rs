//! Embassy wiring for the actuation board: clocks, pins, ADC, UART, watchdog, tasks.
//! Everything else is in the library (`firmware::app`), tested on the host.
//!
//! Stepper timing: task based. The stepper task awaits `Timer::at(planned instant)` for the
//! earliest due axis on a 1 MHz time base (`tick-hz-1_000_000`), so every step lands on its
//! planned µs. It runs on an interrupt executor at a higher priority than everything else, so
//! frame estimation and telemetry formatting (thread mode) never delay a step; the time
//! driver's alarm interrupt plus the executor poll costs a few µs per wake-up, i.e. ≈ 10 % of
//! the 180 MHz M4 at 3 × 10 000 steps/s, leaving step jitter at the few-µs level against a
//! 100 µs step interval. Timer-output (PWM) stepping would remove that jitter but cannot carry
//! exact per-step instants of a trapezoid without DMA-fed period tables; not needed here.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod device {
    use defmt_rtt as _;
    use embassy_executor::{InterruptExecutor, Spawner};
    use embassy_stm32::interrupt;
    use embassy_stm32::interrupt::{InterruptExt, Priority};
    use embassy_stm32::time::Hertz;
    use embassy_stm32::usart::{self, BufferedUart};
    use embassy_stm32::wdg::IndependentWatchdog;
    use embassy_stm32::{bind_interrupts, peripherals};
    use firmware::app::{self, Config, Shared};
    use firmware::board::device::{self as board, DeviceAdc, DeviceSteppers, DeviceWatchdog};
    use firmware::hal;
    use panic_probe as _;
    use static_cell::StaticCell;

    bind_interrupts!(struct Irqs {
        USART2 => usart::BufferedInterruptHandler<peripherals::USART2>;
    });

    /// Application state shared by the tasks.
    static SHARED: StaticCell<Shared> = StaticCell::new();
    /// UART ring buffers.
    static TX_BUF: StaticCell<[u8; 256]> = StaticCell::new();
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

    /// Telemetry through defmt-RTT.
    struct DefmtSink;
    impl hal::TelemetrySink for DefmtSink {
        fn line(&mut self, line: &str) {
            defmt::println!("{=str}", line);
        }
    }

    /// The command port.
    struct Serial(BufferedUart<'static>);
    impl hal::SerialPort for Serial {
        async fn read(&mut self, buf: &mut [u8]) -> usize {
            // A framing/overrun error drops those bytes; the line parser reports what is left.
            embedded_io_async::Read::read(&mut self.0, buf)
                .await
                .unwrap_or(0)
        }
        async fn write_all(&mut self, data: &[u8]) {
            let _ = embedded_io_async::Write::write_all(&mut self.0, data).await;
        }
    }

    #[embassy_executor::task]
    async fn stepper(shared: &'static Shared, s: DeviceSteppers) {
        app::stepper_task(shared, s).await
    }

    #[embassy_executor::task]
    async fn sampler(shared: &'static Shared, adc: DeviceAdc, wdg: DeviceWatchdog) {
        app::sampler_task(shared, adc, DefmtSink, wdg).await
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
        // Read the reset cause before init, then clear the flags for the next boot.
        let csr = embassy_stm32::pac::RCC.csr().read();
        let watchdog_reset = csr.wdgrstf();
        embassy_stm32::pac::RCC.csr().modify(|w| w.set_rmvf(true));

        let p = embassy_stm32::init(clocks());
        let (steppers, adc, rest) = board::split(p);

        let mut uart_cfg = usart::Config::default();
        uart_cfg.baudrate = 115_200;
        let uart = defmt::unwrap!(BufferedUart::new(
            rest.usart,
            rest.rx,
            rest.tx,
            TX_BUF.init([0; 256]),
            RX_BUF.init([0; 256]),
            Irqs,
            uart_cfg,
        ));

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
        spawner.spawn(defmt::unwrap!(sampler(shared, adc, DeviceWatchdog(iwdg))));
        spawner.spawn(defmt::unwrap!(command(shared, Serial(uart))));
    }
}

/// On the host this binary is only a placeholder: the firmware runs on the board or in `host-sim`.
#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("vfp-fw is device firmware: build it with `cargo fw`, simulate it with `cargo vfp simulate`");
}
