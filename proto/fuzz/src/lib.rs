//! Fuzz target bodies of telextiles-proto. Each `<name>::run` is called by
//! `fuzz_targets/<name>.rs` under libFuzzer (`cargo +nightly fuzz run
//! <name> seeds/<name>`) and by the stable harness `tests/stable.rs`
//! (seed corpus plus mutated inputs for a bounded time; `.ci/run`).
pub mod clock_offset;
pub mod latent_receive;
pub mod peer_decode;
pub mod roller_decode;

/// Every target: name and body.
pub const TARGETS: &[(&str, fn(&[u8]))] = &[
    ("clock_offset", clock_offset::run),
    ("latent_receive", latent_receive::run),
    ("peer_decode", peer_decode::run),
    ("roller_decode", roller_decode::run),
];
