//! `models/encoder.onnx` is what the commands in `models/MODEL_CARD.md`
//! write: the `wspec` descriptor graph under a Tukey 0.25 window
//! (`telextiles-lab export-descriptor --kind wspec --crop 240 --input 120
//! --subtract --taper 25`, built by this crate's graph builder) with the
//! trained linear head of `telextiles-lab train-spectral --front wspec
//! --taper 25 --frames-per-press 6 --ramp-frames 3 --hidden 0`. The head's weights are read
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
/// sets them: `--front wspec --taper 25 --frames-per-press 6 --ramp-frames 3
/// --hidden 0 --dim 128 --presses-per-textile 48 --val-presses 3 --augs 3
/// --steps 4000` (the rest at their defaults).
fn card_config() -> SpectralConfig {
    let mut cfg = SpectralConfig::new();
    cfg.front = Front::WSpec;
    cfg.taper = 25;
    cfg.data.frames_per_press = 6;
    cfg.data.ramp_frames = 3;
    cfg.hidden = 0;
    cfg.out = 128;
    cfg.data.presses_per_textile = 48;
    cfg.data.val_presses = 3;
    cfg.augs_per_frame = 3;
    cfg.steps = 4000;
    cfg
}

/// The `wspec` front end of the 240-px crop at 120 px under a window of
/// `taper` % (100: the Hann window).
fn wspec_spec(taper: u32) -> DescriptorSpec {
    DescriptorSpec {
        kind: BaselineKind::WSpec,
        crop: 240,
        input: 120,
        subtract: true,
        min_bin: 1,
        taper,
    }
}

#[test]
fn the_shipped_model_is_the_exported_descriptor_with_its_trained_head() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../encoder.onnx");
    let shipped = std::fs::read(&path).unwrap();
    let spec = wspec_spec(25);
    assert_eq!(spec.arch(), "wspec-c240-s120-t25-bg");
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

/// The model shipped from 2026-11-26 to 2026-12-02 (`wspec-c240-s120-bg+lin128`,
/// the Hann window and one ramp frame per press: the card command without
/// `--taper 25 --frames-per-press 6 --ramp-frames 3`) still has the settings
/// hash recorded in its file, so its command in models/MODEL_CARD.md still
/// reproduces it: the settings added since (`taper`, `ramp_frames`) stay out
/// of the hash at their old values.
#[test]
fn the_previous_models_settings_still_hash_as_recorded_in_it() {
    let mut cfg = card_config();
    cfg.taper = 100;
    cfg.data.frames_per_press = 4;
    cfg.data.ramp_frames = 1;
    assert_eq!(run_hash(&cfg).unwrap(), "effef2013361db83");
    assert_ne!(run_hash(&card_config()).unwrap(), "effef2013361db83");
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
/// what this crate's graph builder writes, byte for byte. It keeps the
/// Hann window: the model's Tukey window was chosen for the model with its
/// head, by the rule; the front end alone was not put through it
/// (models/MODEL_CARD.md).
#[test]
fn the_shipped_fallback_is_the_hann_windowed_spectrum() {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../descriptor.onnx");
    let shipped = std::fs::read(&path).unwrap();
    let spec = wspec_spec(100);
    assert_eq!(spec.arch(), "wspec-c240-s120-bg");
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
