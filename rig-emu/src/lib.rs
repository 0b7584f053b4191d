//! The virtual rig: the `vfp-fw` ELF a lab flashes, run unmodified on an emulated STM32 (rigless's
//! STM32F427 models, the F446's sibling) on a NUCLEO-F446RE board model, its step, direction and
//! enable pins driving host-sim's plant and the plant's sensors on its ADC pins, with a host on
//! its command port.
//!
//! ```text
//! vfp-fw ELF ──► rigless core + STM32 models ──► GPIOA/B writes ──► RigDriver ──► host_sim Plant
//!      ▲                  ▲ ADC1 IN0/1/4 (sampled at each SWSTART) ◄──────────────────┘
//!      └── USART2 ◄──► HostPort (the host: commands, replies, telemetry packets)
//! ```
//!
//! Build the ELF first (`cargo fw` in the main workspace), then `cargo test` here. The tests read
//! the ELF from `VFP_FW_ELF` or `../target/thumbv7em-none-eabihf/firmware/vfp-fw`.
#![forbid(unsafe_code)]

pub mod board;
pub mod host;
pub mod rig;
pub mod wire;

pub use board::Nucleo;
pub use rig::{default_elf, fault_injection_elf, vfp, Bench, Rig, RigConfig, RigError, StepEvent};
pub use wire::{Received, Stream};
