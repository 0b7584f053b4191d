//! The end-to-end tests in one test binary: each former `tests/NAME.rs` is the module `NAME` here
//! (run one with `cargo test -p e2e-tests --test all NAME::`). One binary links the workspace's
//! crates once, where three binaries linked them three times (issue 33).

mod demo_chain;
mod deploy_predict;
mod record_to_identify;
