//! The shipped encoder `models/encoder.onnx` (the shipped-default rule's
//! pick, docs/benchmarks.md: the colour-whitened spectrum of the 240-px
//! crop at 120 px under a Tukey window, minus the no-contact reference, with a trained linear
//! head; models/MODEL_CARD.md) against the daemon's own encoder loader and
//! preprocessing (real ONNX Runtime): it passes the contract checks, gives
//! unit-norm 128-d embeddings, and frames of one press of a simulated
//! textile are closer to each other than to frames of other textiles,
//! across people and sensor units.

use std::path::PathBuf;

use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sim::{PressSpec, Simulator};

fn shipped_model() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../models/encoder.onnx")
}

fn cos(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[test]
fn shipped_encoder_loads_in_the_daemon_and_separates_presses() {
    let mut enc = Encoder::open(&shipped_model(), &EncoderOptions::default()).unwrap();
    assert_eq!(enc.dim(), 128);
    assert_eq!(enc.info().arch, "wspec-c240-s120-t25-bg+lin128");
    assert_eq!(enc.info().background, "subtract");
    assert_eq!(enc.info().preprocess.crop, 240);
    assert_eq!(enc.info().preprocess.size, 120);
    let sim = Simulator::new().unwrap();
    let mut per_textile = Vec::new();
    for id in ["T005", "T047", "T090"] {
        // Two presses of each textile by different people on different
        // sensor units, each against its own unit's no-contact frame.
        let mut embs = Vec::new();
        for (person, sensor, seed) in [(9, 0, 77), (3, 5, 78)] {
            let spec = PressSpec {
                person,
                sensor,
                ..PressSpec::new(id, seed)
            };
            enc.set_reference(&sim.background(sensor)).unwrap();
            let meta = sim.press_meta(&spec).unwrap();
            let f = meta.params.as_ref().unwrap().hold_frame as usize + 10;
            let e = enc
                .encode(&sim.render_frame(&spec, f).unwrap())
                .unwrap()
                .to_vec();
            let norm: f32 = e.iter().map(|v| v * v).sum::<f32>().sqrt();
            assert!((norm - 1.0).abs() < 1e-4, "norm {norm}");
            embs.push(e);
        }
        per_textile.push(embs);
    }
    for (i, a) in per_textile.iter().enumerate() {
        let same = cos(&a[0], &a[1]);
        for (j, b) in per_textile.iter().enumerate() {
            if i != j {
                let other = cos(&a[0], &b[0]);
                assert!(
                    same > other,
                    "textile {i}: cos across people {same} <= cos to textile {j} {other}"
                );
            }
        }
    }
}
