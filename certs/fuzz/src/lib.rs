//! Fuzz target bodies of telextiles-certs. Each `<name>::run` is called by
//! `fuzz_targets/<name>.rs` under libFuzzer (`cargo +nightly fuzz run
//! <name> seeds/<name>`) and by the stable harness `tests/stable.rs`
//! (seed corpus plus mutated inputs for a bounded time; `.ci/run`).
pub mod certificate;
pub mod device_id_text;
pub mod identity_pem;
pub mod pairing_messages;
pub mod trust_store;

/// Every target: name and body.
pub const TARGETS: &[(&str, fn(&[u8]))] = &[
    ("certificate", certificate::run),
    ("device_id_text", device_id_text::run),
    ("identity_pem", identity_pem::run),
    ("pairing_messages", pairing_messages::run),
    ("trust_store", trust_store::run),
];
