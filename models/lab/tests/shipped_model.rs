//! `models/encoder.onnx` is what the commands in `models/MODEL_CARD.md`
//! write: the `wspec` descriptor graph (`telextiles-lab export-descriptor
//! --kind wspec --crop 240 --input 120 --subtract`, built by this crate's
//! graph builder) with the trained linear head of `telextiles-lab
//! train-spectral --front wspec --hidden 0`. The head's weights are read
//! back from the file and the model is rebuilt around them: the bytes must
//! be the same, so the front end, the head's place in the graph and the
//! metadata are the builder's, and a change to the builder that would
//! change the shipped model is caught here. (The head's weights themselves
//! come from the training command, which is deterministic:
//! `models/lab/tests/contrastive.rs`.)

use std::path::PathBuf;

use telextiles_lab::baselines::BaselineKind;
use telextiles_lab::graph::{descriptor_with_head, read_head, DescriptorSpec};
use telextiles_lab::spectral::{run_hash, Front, SpectralConfig};

/// The settings of the command in models/MODEL_CARD.md, as `train-spectral`
/// sets them: `--front wspec --hidden 0 --dim 128 --presses-per-textile 48
/// --val-presses 3 --augs 3 --steps 4000` (the rest at their defaults).
fn card_config() -> SpectralConfig {
    let mut cfg = SpectralConfig::new();
    cfg.front = Front::WSpec;
    cfg.hidden = 0;
    cfg.out = 128;
    cfg.data.presses_per_textile = 48;
    cfg.data.val_presses = 3;
    cfg.augs_per_frame = 3;
    cfg.steps = 4000;
    cfg
}

/// The shipped model's front end, `wspec-c240-s120-bg`.
fn wspec_spec() -> DescriptorSpec {
    DescriptorSpec {
        kind: BaselineKind::WSpec,
        crop: 240,
        input: 120,
        subtract: true,
        min_bin: 1,
        taper: 100,
    }
}

#[test]
fn the_shipped_model_is_the_exported_descriptor_with_its_trained_head() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../encoder.onnx");
    let shipped = std::fs::read(&path).unwrap();
    let spec = wspec_spec();
    assert_eq!(spec.arch(), "wspec-c240-s120-bg");
    let (head, hash) = read_head(&shipped)
        .unwrap()
        .expect("the shipped model has a trained head");
    assert_eq!(head.hidden, 0, "a linear head");
    assert_eq!((head.input, head.out), (spec.dim(), 128));
    assert_eq!(
        hash,
        run_hash(&card_config()).unwrap(),
        "the model was not trained with the command of models/MODEL_CARD.md"
    );
    let rebuilt = descriptor_with_head(&spec, &head, &hash).unwrap();
    assert!(
        rebuilt == shipped,
        "{} ({} bytes) is not the wspec graph with its own head ({} bytes): \
         regenerate it with the training command of models/MODEL_CARD.md and rebuild the index",
        path.display(),
        shipped.len(),
        rebuilt.len()
    );
}

/// The descriptor shipped from 2026-11-25 to 2026-11-26 (`fft-radial-c192-bg`,
/// still the incumbent of every committed study and a method of the bench)
/// is written byte for byte as it was shipped: its recorded sha256 in
/// models/MODEL_CARD.md stays reproducible.
#[test]
fn the_previous_descriptor_is_still_written_byte_for_byte() {
    use sha2::Digest;
    let spec = DescriptorSpec {
        kind: BaselineKind::Fft,
        crop: 192,
        input: 192,
        subtract: true,
        min_bin: 1,
        taper: 100,
    };
    let bytes = telextiles_lab::graph::descriptor_model(&spec).unwrap();
    assert_eq!(
        telextiles_lab::data::hex(&sha2::Sha256::digest(&bytes)),
        "12c205945c650bb7915c536cd7a77a2055aa04fd73a7b22f3b31ab464edbd028"
    );
}

/// `models/descriptor.onnx`, the fallback shipped beside the model (the
/// whitened spectrum alone, with no trained part: `telextiles-lab
/// export-descriptor --kind wspec --crop 240 --input 120 --subtract`), is
/// what this crate's graph builder writes, byte for byte: the shipped
/// model's own front end.
#[test]
fn the_shipped_fallback_is_the_untrained_front_end_of_the_model() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../descriptor.onnx");
    let shipped = std::fs::read(&path).unwrap();
    let spec = wspec_spec();
    let bytes = telextiles_lab::graph::descriptor_model(&spec).unwrap();
    assert!(
        bytes == shipped,
        "{} ({} bytes) is not the wspec-c240-s120-bg graph ({} bytes): regenerate it with \
         the command of models/MODEL_CARD.md",
        path.display(),
        shipped.len(),
        bytes.len()
    );
}
