//! Every fuzz target of this crate under the stable harness: the committed
//! seed corpus, then mutated inputs for `FUZZ_SECONDS` per target (CI runs
//! this; see `.ci/run`).
#[path = "../harness.rs"]
mod harness;

#[test]
fn fuzz_targets_hold_on_seeds_and_mutations() {
    let seeds = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("seeds");
    harness::run_all(telextiles_proto_fuzz::TARGETS, &seeds);
}
