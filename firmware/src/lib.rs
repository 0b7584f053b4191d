//! Hardware-independent actuation firmware: everything here builds for the host and is tested there.
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]

pub mod hal;
