//! The `sysid` integration tests in one test binary: each former `tests/NAME.rs` is the module
//! `NAME` here (run one with `cargo test -p sysid --test all NAME::`). One binary links once and
//! shares its compiled dependencies, where fourteen binaries linked fourteen times (issue 33).
//! Apart stay the tests that need a process of their own: `log_memory.rs` and `record_memory.rs`
//! count the heap with a global allocator, and `chain_agrees.rs` keeps its proptest regressions
//! file next to it.

#[path = "../diag_common/mod.rs"]
mod diag_common;
#[path = "../hostsim_common/mod.rs"]
mod hostsim_common;

mod cycle_plausibility;
mod diag_chow;
mod lab_files;
mod log_format;
mod log_table;
mod nn_sweep;
mod poly_identification;
mod poly_selection;
mod residual_custom_effect;
mod residual_decide;
mod residual_effects;
mod residual_gen;
mod residual_hostsim;
mod residual_hostsim_shapes;
mod residual_range;
mod residual_reshape;
mod residual_shapes;
mod selection_other_rigs;
