//! Shared helpers for the sensing tests.
#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::{Arc, OnceLock};

use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sim::Simulator;

pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

pub fn fixture_encoder() -> Encoder {
    Encoder::open(&fixture("fixture_encoder.onnx"), &EncoderOptions::default())
        .expect("fixture encoder loads")
}

pub fn sim() -> Arc<Simulator> {
    static SIM: OnceLock<Arc<Simulator>> = OnceLock::new();
    SIM.get_or_init(|| Arc::new(Simulator::new().expect("simulator")))
        .clone()
}
