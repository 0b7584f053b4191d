//! Volume-flow-pressure model math shared by the device and the host tools.
#![no_std]
#![forbid(unsafe_code)]
