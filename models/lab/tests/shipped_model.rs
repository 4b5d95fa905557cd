//! `models/encoder.onnx` is exactly what the command in `models/MODEL_CARD.md`
//! writes (`telextiles-lab export-descriptor --kind fft --crop 192
//! --subtract`): the shipped model can be regenerated from source, and a
//! change to the graph builder that would change it is caught here.

use std::path::PathBuf;

use telextiles_lab::baselines::BaselineKind;
use telextiles_lab::graph::{descriptor_model, DescriptorSpec};

#[test]
fn the_shipped_model_is_the_exported_descriptor() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../encoder.onnx");
    let shipped = std::fs::read(&path).unwrap();
    let spec = DescriptorSpec {
        kind: BaselineKind::Fft,
        crop: 192,
        input: 192,
        subtract: true,
        min_bin: 1,
    };
    assert_eq!(spec.arch(), "fft-radial-c192-bg");
    let written = descriptor_model(&spec).unwrap();
    assert!(
        written == shipped,
        "{} ({} bytes) differs from the exported descriptor ({} bytes): \
         regenerate it with `cargo run -p telextiles-lab -- export-descriptor \
         --kind fft --crop 192 --subtract --out models/encoder.onnx` and rebuild the index",
        path.display(),
        shipped.len(),
        written.len()
    );
}
