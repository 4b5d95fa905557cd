//! The ONNX encoder with the real ONNX Runtime and the fixture models.

mod common;

use image::{Rgb, RgbImage};
use telextiles_sensing::encoder::{Encoder, EncoderError, EncoderOptions};
use telextiles_sensing::preprocess::{PreprocessSpec, Preprocessor};

fn open(name: &str) -> Result<Encoder, EncoderError> {
    Encoder::open(&common::fixture(name), &EncoderOptions::default())
}

fn contract_msg(name: &str) -> String {
    match open(name) {
        Err(EncoderError::Contract { msg, .. }) => msg,
        Err(e) => panic!("{name}: expected a contract error, got {e}"),
        Ok(_) => panic!("{name}: accepted"),
    }
}

#[test]
fn fixture_model_loads_with_its_metadata() {
    let enc = common::fixture_encoder();
    let info = enc.info();
    assert_eq!(info.dim, 64);
    assert_eq!(info.preprocess.size, 64);
    assert_eq!(info.preprocess.crop, 224);
    assert_eq!(
        info.preprocess.mean,
        [0.379_323_63, 0.413_103_4, 0.383_360_82]
    );
    assert_eq!(info.background, "none");
    assert!(info.arch.starts_with("fixture"));
    let hash =
        telextiles_sensing::encoder::file_sha256(&common::fixture("fixture_encoder.onnx")).unwrap();
    assert_eq!(info.sha256, hash);
}

#[test]
fn embeddings_are_normalised_deterministic_and_depend_on_the_frame() {
    let sim = common::sim();
    let mut enc = common::fixture_encoder();
    let spec = telextiles_sim::PressSpec::new("T030", 1);
    let a = sim.render_frame(&spec, 100).unwrap();
    let b = sim
        .render_frame(&telextiles_sim::PressSpec::new("T110", 1), 100)
        .unwrap();
    let ea = enc.encode(&a).unwrap().to_vec();
    let eb = enc.encode(&b).unwrap().to_vec();
    let ea2 = enc.encode(&a).unwrap().to_vec();
    assert_eq!(ea.len(), 64);
    let n: f32 = ea.iter().map(|x| x * x).sum::<f32>().sqrt();
    assert!((n - 1.0).abs() < 1e-5);
    // The bound input tensor really is rewritten in place for every frame.
    assert_eq!(ea, ea2);
    let d: f32 = ea
        .iter()
        .zip(&eb)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt();
    assert!(
        d > 1e-3,
        "different textiles give different embeddings ({d})"
    );
    // A second session on the same model agrees (no hidden state).
    let mut enc2 = common::fixture_encoder();
    let eb2 = enc2.encode(&b).unwrap().to_vec();
    for (x, y) in eb.iter().zip(&eb2) {
        assert!((x - y).abs() < 1e-5);
    }
    // Threads are configurable and do not change the result beyond rounding.
    let mut enc4 = Encoder::open(
        &common::fixture("fixture_encoder.onnx"),
        &EncoderOptions {
            threads: 2,
            ..Default::default()
        },
    )
    .unwrap();
    let ea4 = enc4.encode(&a).unwrap();
    for (x, y) in ea.iter().zip(ea4) {
        assert!((x - y).abs() < 1e-4);
    }
}

#[test]
fn texture_features_join_the_embedding_as_the_index_asks() {
    use telextiles_index::Features;
    let sim = common::sim();
    let mut enc = common::fixture_encoder();
    let a = sim
        .render_frame(&telextiles_sim::PressSpec::new("T030", 1), 100)
        .unwrap();
    let b = sim
        .render_frame(&telextiles_sim::PressSpec::new("T110", 1), 100)
        .unwrap();
    let plain = enc.encode(&a).unwrap().to_vec();
    assert_eq!(enc.features(), Features::Encoder);
    enc.set_features(Features::EncoderLbp);
    assert_eq!(enc.dim(), 64 + telextiles_sensing::texture::LBP_DIM);
    assert_eq!(enc.info().dim, 64);
    let ea = enc.encode(&a).unwrap().to_vec();
    let eb = enc.encode(&b).unwrap().to_vec();
    assert_eq!(ea.len(), enc.dim());
    let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
    // Unit length as a whole; each part is half of it, the encoder's part
    // the same direction as before.
    assert!((norm(&ea) - 1.0).abs() < 1e-5);
    assert!((norm(&ea[..64]) - std::f32::consts::FRAC_1_SQRT_2).abs() < 1e-5);
    for (x, y) in ea[..64].iter().zip(&plain) {
        assert!((x * std::f32::consts::SQRT_2 - y).abs() < 1e-5);
    }
    // Two fabrics differ in their texture part too, and it is the same
    // on the same frame.
    let d: f32 = ea[64..]
        .iter()
        .zip(&eb[64..])
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt();
    assert!(d > 1e-3, "{d}");
    assert_eq!(enc.encode(&a).unwrap(), &ea[..]);
    // Back to the encoder alone.
    enc.set_features(Features::Encoder);
    assert_eq!(enc.encode(&a).unwrap(), &plain[..]);
}

#[test]
fn models_breaking_the_contract_are_refused_at_start_up() {
    let m = contract_msg("bad_no_metadata.onnx");
    assert!(
        m.contains("telextiles.format") && m.contains("missing"),
        "{m}"
    );
    let m = contract_msg("bad_input_size.onnx");
    assert!(m.contains("[N,3,64,64]") && m.contains("32"), "{m}");
    let m = contract_msg("bad_output_dim.onnx");
    assert!(m.contains("[N,64]") && m.contains("32"), "{m}");
    let m = contract_msg("bad_input_name.onnx");
    assert!(m.contains("\"frames\"") && m.contains("images"), "{m}");
}

/// `model` with one more metadata entry (ONNX `ModelProto` field 14,
/// `metadata_props`: appending a field to a protobuf message adds it).
fn with_metadata(model: &[u8], key: &str, value: &str) -> Vec<u8> {
    fn varint(mut n: usize, out: &mut Vec<u8>) {
        while n >= 0x80 {
            out.push((n as u8 & 0x7f) | 0x80);
            n >>= 7;
        }
        out.push(n as u8);
    }
    let mut entry = Vec::new();
    for (tag, s) in [(0x0a, key), (0x12, value)] {
        entry.push(tag);
        varint(s.len(), &mut entry);
        entry.extend_from_slice(s.as_bytes());
    }
    let mut out = model.to_vec();
    out.push(0x72);
    varint(entry.len(), &mut out);
    out.extend_from_slice(&entry);
    out
}

#[test]
fn a_model_for_another_frame_scale_is_refused_by_name() {
    let fixture = std::fs::read(common::fixture("fixture_encoder.onnx")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let at = |value: &str| {
        let p = dir.path().join(format!("m{value}.onnx"));
        std::fs::write(&p, with_metadata(&fixture, "telextiles.mm_per_px", value)).unwrap();
        Encoder::open(&p, &EncoderOptions::default())
    };
    // The frame's own scale is what every sensor is mapped to.
    assert!(at("0.08").is_ok());
    match at("0.04") {
        Err(EncoderError::Contract { msg, .. }) => {
            assert!(
                msg.contains("0.04 mm per pixel") && msg.contains("0.08"),
                "{msg}"
            )
        }
        other => panic!("expected a contract error, got {:?}", other.err()),
    }
    assert!(matches!(at("fine"), Err(EncoderError::Contract { .. })));
}

#[test]
fn missing_or_corrupt_model_files_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("none.onnx");
    match Encoder::open(&missing, &EncoderOptions::default()) {
        Err(e @ EncoderError::Model { .. }) => assert!(e.to_string().contains("none.onnx"), "{e}"),
        Err(e) => panic!("{e}"),
        Ok(_) => panic!("opened a missing model"),
    }
    let junk = dir.path().join("junk.onnx");
    std::fs::write(&junk, b"this is not a protobuf").unwrap();
    assert!(matches!(
        Encoder::open(&junk, &EncoderOptions::default()),
        Err(EncoderError::Model { .. })
    ));
}

#[test]
fn wrong_sized_frames_are_rejected_not_encoded() {
    let mut enc = common::fixture_encoder();
    let e = enc.encode(&RgbImage::new(320, 240)).unwrap_err();
    assert!(e.to_string().contains("320x240"), "{e}");
}

#[test]
fn preprocessing_crops_resizes_and_normalises_as_specified() {
    let spec = PreprocessSpec {
        crop: 4,
        size: 2,
        mean: [0.5, 0.25, 0.0],
        std: [0.5, 0.25, 1.0],
    };
    let pre = Preprocessor::new(spec).unwrap();
    // Centre crop of 4x4 starts at (118, 158); fill it with known values.
    let mut img = RgbImage::from_pixel(240, 320, Rgb([0, 0, 0]));
    for y in 0..4 {
        for x in 0..4 {
            img.put_pixel(118 + x, 158 + y, Rgb([(x * 60) as u8, (y * 60) as u8, 255]));
        }
    }
    let mut out = vec![0f32; pre.len()];
    pre.run(&img, &mut out);
    // Output (0,0) samples source 0.5 -> mix of columns/rows 0 and 1.
    let r00 = ((30.0 / 255.0) - 0.5) / 0.5;
    assert!((out[0] - r00).abs() < 1e-5, "{} vs {r00}", out[0]);
    let g10 = ((150.0 / 255.0) - 0.25) / 0.25; // output row 1 samples source row 2.5
    assert!((out[4 + 2] - g10).abs() < 1e-5, "{} vs {g10}", out[4 + 2]);
    assert!(
        out[8..].iter().all(|b| (b - 1.0).abs() < 1e-6),
        "blue plane"
    );
    assert!(Preprocessor::new(PreprocessSpec {
        crop: 300,
        size: 2,
        mean: [0.0; 3],
        std: [1.0; 3]
    })
    .is_err());
    assert!(Preprocessor::new(PreprocessSpec {
        crop: 10,
        size: 2,
        mean: [0.0; 3],
        std: [0.0; 3]
    })
    .is_err());
}

/// `fixture_subtract.onnx`: the radially averaged log power spectrum of the
/// 32x32 centre crop minus the no-contact reference (`telextiles-lab
/// export-descriptor --kind fft --crop 32 --subtract`), 15-d.
#[test]
fn background_subtracting_models_keep_the_reference_they_are_given() {
    let sim = common::sim();
    let mut enc = open("fixture_subtract.onnx").unwrap();
    assert_eq!(enc.info().background, "subtract");
    assert_eq!(enc.dim(), 15);
    assert!(enc.subtracts_background() && !enc.has_reference());
    let spec = telextiles_sim::PressSpec::new("T030", 1);
    let touched = sim.render_frame(&spec, 100).unwrap();
    let untouched = sim.background(0);
    // No reference yet: a clear error, not a silent wrong embedding.
    let e = enc.encode(&touched).unwrap_err();
    assert!(matches!(e, EncoderError::NoReference), "{e}");
    assert!(e.to_string().contains("untouched"), "{e}");
    enc.set_reference(&untouched).unwrap();
    assert!(enc.has_reference());
    let with_bg = enc.encode(&touched).unwrap().to_vec();
    // Subtracting another reference gives another embedding.
    let other = sim.background(4);
    enc.set_reference(&other).unwrap();
    let with_other = enc.encode(&touched).unwrap().to_vec();
    let d: f32 = with_bg
        .iter()
        .zip(&with_other)
        .map(|(a, b)| (a - b).abs())
        .sum();
    assert!(d > 1e-3, "the reference is ignored");
    // A reference given as full-resolution values (the contact detector's
    // averaged reference) is the same reference, without rounding.
    enc.set_reference_pixels(&telextiles_sensing::front::pixels_of(&untouched))
        .unwrap();
    let from_pixels = enc.encode(&touched).unwrap().to_vec();
    for (a, b) in from_pixels.iter().zip(&with_bg) {
        assert!((a - b).abs() < 1e-4, "{a} vs {b}");
    }
    // Forgetting it: a clear error again.
    enc.clear_reference();
    assert!(matches!(
        enc.encode(&touched).unwrap_err(),
        EncoderError::NoReference
    ));
    // Models that do not subtract ignore references.
    let mut plain = common::fixture_encoder();
    assert!(!plain.subtracts_background() && plain.has_reference());
    let e1 = plain.encode(&touched).unwrap().to_vec();
    plain.set_reference(&other).unwrap();
    assert_eq!(plain.encode(&touched).unwrap(), &e1[..]);
}
