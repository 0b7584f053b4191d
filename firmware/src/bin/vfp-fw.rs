//! Embassy wiring for the actuation board: init, pins, spawn. Everything else is in the library.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
mod device {
    use defmt_rtt as _;
    use embassy_executor::Spawner;
    use panic_probe as _;

    #[embassy_executor::main]
    async fn main(_spawner: Spawner) {
        let _p = embassy_stm32::init(Default::default());
        defmt::info!("vfp-fw booted");
        loop {
            embassy_time::Timer::after_secs(1).await;
        }
    }
}

/// On the host this binary is only a placeholder: the firmware runs on the board or in `host-sim`.
#[cfg(not(target_os = "none"))]
fn main() {
    eprintln!("vfp-fw is device firmware: build it with `cargo fw`, simulate it with `cargo vfp simulate`");
}
