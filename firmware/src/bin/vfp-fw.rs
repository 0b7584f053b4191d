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
//!
//! Serial telemetry (`telemetry on`, `firmware::wire`): the same frames and events as binary
//! packets on the command UART (USART2, the ST-LINK's virtual COM port). The library's command
//! task writes each queued packet with the port's DMA `write_all` between two replies (117 bytes,
//! about 10 ms at 115200 baud, during which reception continues into the 256-byte DMA ring); the
//! sampler only ever queues them, never waits. Nothing else here changes for it.
//!
//! Faults: the panic and HardFault handlers below drive the drivers' EN high (disabled) with
//! one store to GPIOA's BSRR, leave a crash record in `.uninit` RAM ([`firmware::reset`]) and
//! reset; nothing in them can block (no defmt: with probe-rs attached the RTT channel may be in
//! blocking mode, and a panic inside a defmt print would re-enter its logger). HardFault enters
//! through assembly that resets the stack pointer first, so a stack overflow (the stack below
//! RAM, under flip-link) still ends in a record and the reset, not a lockup. The next boot
//! reports the cause on its boot event and refuses motion until `origin`.
//!
//! Board settings: flash prefetch and both caches on after `embassy_stm32::init` (its F4 clock
//! set-up writes only the wait states), emptied again after every flash write; the time driver on TIM5 (32-bit); the watchdog frozen
//! while a debugger halts the core; defmt timestamps in µs since boot.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod device {
    use core::mem::MaybeUninit;
    use core::sync::atomic::{AtomicBool, Ordering};

    use cortex_m::peripheral::SCB;
    use embassy_embedded_hal::adapter::BlockingAsync;
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
    use firmware::reset::RECORD_WORDS;
    use firmware::reset::{Crash, FaultFrame, FileTail, PanicSite, ResetCause, ResetFlags};
    use firmware::store::{FlashGuard, ModelStore};
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

    defmt::timestamp!("{=u64:us}", embassy_time::Instant::now().as_micros());

    // ------------------------------------------------------------------ crash record, handlers

    /// The crash record: in `.uninit`, which cortex-m-rt neither zeroes nor initialises, so it
    /// survives the system reset the handlers request (SRAM stays powered).
    #[link_section = ".uninit.vfp_crash"]
    static mut CRASH: MaybeUninit<[u32; RECORD_WORDS]> = MaybeUninit::uninit();

    /// Set by the first panic: a panic inside the panic handler goes straight to the reset.
    static PANICKING: AtomicBool = AtomicBool::new(false);

    /// Disable every stepper driver: EN (PA9) is active low, so set it through GPIOA's BSRR
    /// (one store, no read-modify-write, no lock, no HAL state). Harmless before GPIOA is
    /// clocked (the write is ignored; the pin is still an input then).
    fn drivers_off() {
        embassy_stm32::pac::GPIOA
            .bsrr()
            .write(|w| w.set_bs(9, true));
    }

    fn write_record(words: &[u32; RECORD_WORDS]) {
        // SAFETY: only the fault handlers write it, with interrupts masked or from HardFault
        // (which nothing else preempts); a raw pointer, no reference to the static.
        unsafe { core::ptr::write_volatile(core::ptr::addr_of_mut!(CRASH).cast(), *words) }
    }

    /// Read the record left by the last crash, and clear it so that it is reported once.
    fn take_record() -> Option<Crash> {
        let p = core::ptr::addr_of_mut!(CRASH).cast::<[u32; RECORD_WORDS]>();
        // SAFETY: runs once at boot before anything else touches the record. The RAM holds
        // whatever it held (noise after power-on); every bit pattern is a valid `[u32; N]`, and
        // `Crash::decode` accepts only a record with the magic and a matching CRC.
        let raw = unsafe { core::ptr::read_volatile(p) };
        unsafe { core::ptr::write_volatile(p, [0; RECORD_WORDS]) };
        Crash::decode(&raw)
    }

    #[panic_handler]
    fn panic(info: &core::panic::PanicInfo) -> ! {
        cortex_m::interrupt::disable();
        drivers_off();
        if !PANICKING.swap(true, Ordering::Relaxed) {
            let site = match info.location() {
                Some(l) => PanicSite {
                    file: FileTail::new(l.file()),
                    line: l.line(),
                    column: l.column(),
                },
                None => PanicSite {
                    file: FileTail::new(""),
                    line: 0,
                    column: 0,
                },
            };
            write_record(&Crash::Panic(site).encode());
        }
        SCB::sys_reset()
    }

    /// SRAM (SRAM1 and SRAM2, contiguous; `memory.x`'s RAM): where a stacked exception frame
    /// can be read.
    const RAM: core::ops::Range<u32> = 0x2000_0000..0x2002_0000;

    // HardFault's entry, in assembly: no Rust may run on the stack the fault left. Under
    // flip-link the stack sits at the bottom of RAM, so an overflow leaves SP below 0x2000_0000;
    // the core then stacks the HardFault frame into no memory (CFSR.STKERR) and enters with SP
    // there, and the first push of a Rust handler would fault again inside HardFault: a lockup,
    // with no record and the drivers as they were (what cortex-m-rt's trampoline and a Rust
    // handler do). So: take the frame's address (MSP or PSP, by EXC_RETURN bit 2) into r0, move
    // MSP back to the stack's top (`_stack_start`, 8-byte aligned; nothing returns from here, so
    // what the stack held is not needed), and only then enter the Rust handler.
    core::arch::global_asm!(
        ".section .HardFault.user,\"ax\"",
        ".global HardFault",
        ".type HardFault,%function",
        ".thumb_func",
        "HardFault:",
        "tst lr, #4",
        "ite eq",
        "mrseq r0, msp",
        "mrsne r0, psp",
        "ldr r1, =_stack_start",
        "bic r1, r1, #7",
        "msr msp, r1",
        "b vfp_hard_fault",
        ".ltorg",
    );

    /// The HardFault handler proper, on the stack [`HardFault`'s entry](self) reset: drivers
    /// off, the record, reset. The stacked PC, LR and xPSR are read only where the frame lies in
    /// RAM; after a stack overflow it lies below, and they are recorded as
    /// [`FaultFrame::NO_FRAME`] (the cause then reads `stack-overflow`).
    #[no_mangle]
    unsafe extern "C" fn vfp_hard_fault(frame: u32) -> ! {
        drivers_off();
        // SAFETY: reads of the System Control Block's fault status and address registers.
        let scb = unsafe { &*SCB::PTR };
        let stacked = |word: u32| -> u32 {
            let at = frame.wrapping_add(4 * word);
            if frame.is_multiple_of(4) && RAM.contains(&frame) && RAM.contains(&(at + 3)) {
                // SAFETY: an aligned word inside SRAM.
                unsafe { core::ptr::read_volatile(at as *const u32) }
            } else {
                FaultFrame::NO_FRAME
            }
        };
        // The exception frame: r0-r3, r12, lr, pc, xpsr.
        let frame = FaultFrame {
            pc: stacked(6),
            lr: stacked(5),
            xpsr: stacked(7),
            cfsr: scb.cfsr.read(),
            hfsr: scb.hfsr.read(),
            mmfar: scb.mmfar.read(),
            bfar: scb.bfar.read(),
        };
        write_record(&Crash::HardFault(frame).encode());
        SCB::sys_reset()
    }

    // ------------------------------------------------------------------ fault injection

    /// The `fault-injection` build's user button (B1, PC13, low while pressed): a press of a
    /// second or more overflows the stack, a shorter one panics, so the virtual rig shows the
    /// fault handlers of the binary at work. Never in the firmware a lab flashes.
    #[cfg(feature = "fault-injection")]
    #[embassy_executor::task]
    async fn fault_injection(button: embassy_stm32::Peri<'static, peripherals::PC13>) {
        use embassy_stm32::gpio::{Input, Pull};
        use embassy_time::{Duration, Instant, Timer};
        let button = Input::new(button, Pull::None);
        loop {
            while button.is_high() {
                Timer::after_millis(10).await;
            }
            let pressed = Instant::now();
            while button.is_low() {
                Timer::after_millis(10).await;
            }
            if pressed.elapsed() >= Duration::from_secs(1) {
                let depth = overflow(core::hint::black_box(0));
                defmt::info!("recursion ended at {=u32}", depth);
            } else {
                panic!("fault injection: the user button");
            }
        }
    }

    /// Recursion with a 128-byte frame that ends only at `u32::MAX` levels: far past the stack.
    #[cfg(feature = "fault-injection")]
    #[inline(never)]
    fn overflow(depth: u32) -> u32 {
        let frame = core::hint::black_box([depth; 32]);
        if core::hint::black_box(depth) == u32::MAX {
            return 0;
        }
        overflow(depth + 1).wrapping_add(frame[depth as usize % 32])
    }

    // ------------------------------------------------------------------ board settings

    /// Flash prefetch and instruction/data caches on, both emptied first (RM0390 §3.5.2: reset
    /// a cache only while it is disabled). embassy-stm32's F4 clock set-up writes FLASH_ACR with
    /// the wait states only; at 180 MHz (5 wait states) every uncached fetch would stall. Called
    /// at boot and again after every flash write and the store's load (which may erase): the
    /// caches would otherwise go on serving words an erase or a program has replaced, and
    /// embassy-stm32's F4 flash driver does not reset them.
    fn flash_accelerator() {
        use embassy_stm32::pac::FLASH;
        FLASH.acr().modify(|w| {
            w.set_icen(false);
            w.set_dcen(false);
        });
        FLASH.acr().modify(|w| {
            w.set_icrst(true);
            w.set_dcrst(true);
        });
        FLASH.acr().modify(|w| {
            w.set_icrst(false);
            w.set_dcrst(false);
        });
        FLASH.acr().modify(|w| {
            w.set_prften(true);
            w.set_icen(true);
            w.set_dcen(true);
        });
    }

    /// The independent watchdog stops counting while a debugger halts the core (a breakpoint
    /// would otherwise reset the board 50 ms later).
    fn freeze_watchdog_when_halted() {
        embassy_stm32::pac::DBGMCU
            .apb1fzr()
            .modify(|w| w.set_iwdg(true));
    }

    /// Around a flash write: stretches the independent watchdog's window, and empties the flash
    /// caches after it ([`flash_accelerator`]). A sector erase stalls
    /// the CPU for 1–2 s (RM0390/datasheet: 128 KiB erase, x32 parallelism, max 2 s), against
    /// a 50 ms window. Prescaler /64 and reload 4095 give 4096 × 64 / 32 kHz ≈ 8.2 s, still
    /// 5.6 s with the LSI at its 47 kHz worst case. The write happens only at rest (no
    /// motion), and the previous prescaler and reload come back after it.
    struct StoreGuard {
        saved: Option<(embassy_stm32::pac::iwdg::vals::Pr, u16)>,
    }

    impl StoreGuard {
        fn set(pr: embassy_stm32::pac::iwdg::vals::Pr, rl: u16) {
            use embassy_stm32::pac::{iwdg::vals::Key, IWDG};
            // Reload first: the change itself then has the old window's full length.
            IWDG.kr().write(|w| w.set_key(Key::RESET));
            IWDG.kr().write(|w| w.set_key(Key::ENABLE));
            IWDG.pr().write(|w| w.set_pr(pr));
            IWDG.rlr().write(|w| w.set_rl(rl));
            // The new values reach the watchdog's LSI domain a few LSI cycles later.
            while {
                let sr = IWDG.sr().read();
                sr.pvu() || sr.rvu()
            } {}
            IWDG.kr().write(|w| w.set_key(Key::RESET));
        }
    }

    impl FlashGuard for StoreGuard {
        fn before(&mut self) {
            use embassy_stm32::pac::{iwdg::vals::Pr, IWDG};
            self.saved = Some((IWDG.pr().read().pr(), IWDG.rlr().read().rl()));
            Self::set(Pr::DIVIDE_BY64, 0x0FFF);
        }
        fn after(&mut self) {
            flash_accelerator();
            if let Some((pr, rl)) = self.saved.take() {
                Self::set(pr, rl);
            }
        }
    }

    /// The model store's flash: sectors 6 and 7, through embassy's blocking region driver.
    type StoreFlash =
        BlockingAsync<embassy_stm32::flash::Bank1Region3<'static, embassy_stm32::flash::Blocking>>;

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

    /// The command port: DMA transmit (replies and, when switched on, telemetry packets), DMA
    /// ring-buffered receive that reports receive errors.
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

    #[embassy_executor::task]
    async fn persist(shared: &'static Shared, store: ModelStore<StoreFlash>) {
        app::persist_task(shared, store, StoreGuard { saved: None }).await
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

    // The drivers' EN (PA9, active low) driven high, as an output, first thing after reset
    // (cortex-m-rt's `__pre_init`, before the RAM's initialisation, so in assembly: no Rust may
    // run before it). From reset the pin is a floating input, and a DRV8825's or A4988's enable
    // input has a pull-down: the drivers would hold and step from reset until `board::split`.
    // RCC_AHB1ENR |= GPIOAEN (read back so the clock reaches the port, RM0390 6.3.10);
    // GPIOA_BSRR = BS9; GPIOA_MODER's MODER9 = 01 (output). embassy's start-up only enables the
    // GPIO clocks and leaves the port as set here; `board::split` takes the pin as an output,
    // high. A pull-up on EN covers the few cycles before this on the board.
    core::arch::global_asm!(
        ".section .text.__pre_init,\"ax\"",
        ".global __pre_init",
        ".type __pre_init,%function",
        ".thumb_func",
        "__pre_init:",
        "ldr r0, =0x40023830",
        "ldr r1, [r0]",
        "orr r1, r1, #1",
        "str r1, [r0]",
        "ldr r1, [r0]",
        "ldr r0, =0x40020018",
        "mov r1, #0x200",
        "str r1, [r0]",
        "ldr r0, =0x40020000",
        "ldr r1, [r0]",
        "bic r1, r1, #0xC0000",
        "orr r1, r1, #0x40000",
        "str r1, [r0]",
        "bx lr",
        ".ltorg",
    );

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

        // Read the reset cause before init, then clear the flags and the record for the next
        // boot.
        let csr = embassy_stm32::pac::RCC.csr().read().0;
        embassy_stm32::pac::RCC.csr().modify(|w| w.set_rmvf(true));
        let reset_cause = ResetCause::from_reset(ResetFlags(csr), take_record());

        let p = embassy_stm32::init(clocks());
        flash_accelerator();
        freeze_watchdog_when_halted();
        let (steppers, adc, rest) = board::split(p);

        // The command port next, before anything slow (the store's repair can take an erase):
        // from here on what the host sends lands in the DMA ring, and the command task, once it
        // runs, announces the boot on this port (`$E … boot …`) so the host knows it listens.
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
        let mut serial = Serial {
            tx,
            rx: rx.into_ring_buffered(RX_BUF.init([0; 256])),
        };
        serial.rx.start_uart();

        // The committed models, before the watchdog runs: a store left half-erased by a power
        // cut is repaired here, which can take an erase (seconds).
        let region = embassy_stm32::flash::Flash::new_blocking(rest.flash)
            .into_blocking_regions()
            .bank1_region3;
        use firmware::board::{REGION3_START, STORE_END, STORE_START};
        let range = STORE_START - REGION3_START..STORE_END - REGION3_START;
        let mut store = defmt::unwrap!(ModelStore::new(BlockingAsync::new(region), range).ok());
        let models = store.load_all().await;
        flash_accelerator();

        let mut iwdg = IndependentWatchdog::new(rest.iwdg, WATCHDOG_TIMEOUT_US);
        iwdg.unleash();

        let shared: &'static Shared = SHARED.init(Shared::new(Config {
            reset_cause,
            ..Config::default()
        }));
        shared
            .restore_models(&models, embassy_time::Instant::now().as_micros())
            .await;
        defmt::info!("vfp-fw booted (reset: {=str})", reset_cause.name());

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
        spawner.spawn(defmt::unwrap!(persist(shared, store)));
        #[cfg(feature = "fault-injection")]
        spawner.spawn(defmt::unwrap!(fault_injection(rest.user_button)));
    }
}

/// On the host this binary is only a placeholder: the firmware runs on the board or in `host-sim`.
#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("vfp-fw is device firmware: build it with `cargo fw`, simulate it with `cargo vfp simulate`");
}
