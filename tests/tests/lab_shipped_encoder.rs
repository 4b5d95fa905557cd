//! The shipped encoder `models/encoder.onnx` (trained by `telextiles-lab`)
//! against the daemon's own encoder loader and preprocessing (real ONNX
//! Runtime): it passes the contract checks, gives unit-norm 128-d
//! embeddings, and frames of one jig press of a simulated textile are closer
//! to each other than to frames of other textiles.

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
    assert_eq!(enc.info().arch, "resnet-d1111-w16-s64");
    assert_eq!(enc.info().preprocess.crop, 64);
    assert_eq!(enc.info().preprocess.size, 64);
    let sim = Simulator::new().unwrap();
    let mut per_textile = Vec::new();
    for id in ["T005", "T047", "T090"] {
        let spec = PressSpec {
            person: 9,
            sensor: 0,
            ..PressSpec::new(id, 77)
        };
        let meta = sim.press_meta(&spec).unwrap();
        let hold = meta.params.as_ref().unwrap().hold_frame as usize;
        let mut embs = Vec::new();
        for f in [hold + 2, hold + 12] {
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
                    "textile {i}: same-press cos {same} <= cos to textile {j} {other}"
                );
            }
        }
    }
}
