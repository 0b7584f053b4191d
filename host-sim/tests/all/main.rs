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

use host_sim::plant::{Plant, CHAMBERS};

/// Drives every chamber at a constant `rate` mm³/s from `t0_us` for `steps` steps (inflating or
/// not); the last step's instant, µs.
fn ramp(plant: &mut Plant, t0_us: u64, steps: u32, rate: f64, inflate: bool) -> u64 {
    let dt = 0.04 / rate * 1e6;
    let mut t = t0_us;
    for k in 1..=steps {
        t = t0_us + (k as f64 * dt).round() as u64;
        for i in 0..CHAMBERS {
            plant.step(i, t, inflate);
        }
    }
    t
}
