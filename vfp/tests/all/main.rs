//! The `vfp` integration tests in one test binary: each former `tests/NAME.rs` is the module
//! `NAME` here (run one with `cargo test -p vfp --test all NAME::`). One binary links the tool's
//! library and its dependencies once, where sixteen binaries linked them sixteen times (issue 33).
//! The tests that run the tool as a user does spawn the `vfp` binary with `--quiet`; the ones that
//! call its commands in-process set [`vfp::progress::set_quiet`], so no progress reaches the
//! test's terminal.

#[path = "../common/mod.rs"]
mod common;
#[path = "../../../sysid/tests/diag_common/mod.rs"]
mod diag_common;

mod bench_loop;
mod diag_force;
mod diag_hostsim;
mod diag_stiffness;
mod diagnose_decide;
mod diagnose_validate;
mod docs;
mod export_augmented;
mod export_cli;
mod figures;
mod force_augmented;
mod golden;
mod identify_cli;
mod lab_files;
mod monitor;
mod record_stream;
mod replay_board;
mod residual_real_log;
mod serial_record;
mod units;
