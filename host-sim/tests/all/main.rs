//! The `host-sim` integration tests in one test binary: each former `tests/NAME.rs` is the module
//! `NAME` here (run one with `cargo test -p host-sim --test all NAME::`). One binary links once,
//! where eight binaries linked eight times (issue 33). Simulations still run one at a time (the
//! MockDriver is process-global; `host_sim::simulate` holds a lock), as they did in each binary.

mod chain;
mod forms;
mod link;
mod plant;
mod presets;
mod reset;
mod rest_zero;
mod scenarios;
mod strokes;
