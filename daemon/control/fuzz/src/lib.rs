//! Fuzz target bodies of telextiles-control. Each `<name>::run` is called
//! by `fuzz_targets/<name>.rs` under libFuzzer (`cargo +nightly fuzz run
//! <name> seeds/<name>`) and by the stable harness `tests/stable.rs`
//! (seed corpus plus mutated inputs for a bounded time; `.ci/run`).
pub mod control_request;

/// Every target: name and body.
pub const TARGETS: &[(&str, fn(&[u8]))] = &[("control_request", control_request::run)];
