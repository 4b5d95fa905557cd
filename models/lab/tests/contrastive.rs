//! The contrastive recipes of issue 20 end to end on a few simulated
//! textiles: `supcon::train` (the CNN on frame minus reference) and
//! `spectral::train` (a head on the shipped spectrum), each exported and
//! run by the daemon's own encoder (`telextiles_sensing::encoder`, real
//! ONNX Runtime) with a no-contact reference, giving what the lab computes.

use image::RgbImage;
use telextiles_lab::model::ArchConfig;
use telextiles_lab::onnx::{export_encoder, EncoderMeta};
use telextiles_lab::spectral::{self, SpectralConfig};
use telextiles_lab::supcon::{self, SupConConfig};
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sim::{PressSpec, Simulator};

/// A frame in contact and its unit's reference (catalogue 2).
fn press_frame() -> (RgbImage, RgbImage) {
    let sim = Simulator::with_catalogue(2).unwrap();
    let spec = PressSpec {
        sensor: 3,
        ..PressSpec::new("T002", 5)
    };
    let meta = sim.press_meta(&spec).unwrap();
    let hold = meta.params.unwrap().hold_frame as usize;
    (
        sim.render_frame(&spec, hold + 10).unwrap(),
        sim.background_for(&spec).unwrap(),
    )
}

fn daemon_embedding(model: &[u8], frame: &RgbImage, reference: &RgbImage) -> Vec<f32> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.onnx");
    std::fs::write(&path, model).unwrap();
    let mut enc = Encoder::open(&path, &EncoderOptions::default()).unwrap();
    assert!(enc.subtracts_background());
    enc.set_reference(reference).unwrap();
    enc.encode(frame).unwrap().to_vec()
}

fn max_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn the_cnn_recipe_trains_and_the_daemon_runs_it_as_trained() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = SupConConfig::new(ArchConfig::parse("resnet-d1111-w4-s32").unwrap());
    cfg.crop = 64;
    cfg.max_textiles = Some(4);
    cfg.presses_per_textile = 3;
    cfg.frames_per_press = 2;
    cfg.classes_per_batch = 4;
    cfg.views_per_class = 2;
    cfg.steps = 6;
    cfg.eval_every = 3;
    cfg.warmup_steps = 1;
    cfg.val_presses = 3;
    let (enc, val) = supcon::train(&cfg, dir.path(), 2).unwrap();
    assert!((0.0..=1.0).contains(&val));
    let metrics = std::fs::read_to_string(dir.path().join("metrics.jsonl")).unwrap();
    assert_eq!(metrics.lines().count(), 2, "{metrics}");
    // 4 textiles x 3 validation presses.
    for line in metrics.lines() {
        let m: supcon::StepMetrics = serde_json::from_str(line).unwrap();
        assert_eq!(m.val_presses, 12, "{line}");
    }
    assert!(dir.path().join("best.bpk").exists());
    let (reloaded, _) = supcon::load_best(dir.path()).unwrap();
    let bytes = export_encoder(
        &reloaded,
        &EncoderMeta {
            arch: cfg.arch.clone(),
            crop: 64,
            train_data_hash: "test".into(),
            subtract: true,
        },
    )
    .unwrap();
    let (frame, reference) = press_frame();
    let got = daemon_embedding(&bytes, &frame, &reference);
    // The lab's view of the same frame: the daemon's preprocessing, minus
    // the reference, through burn.
    let x = supcon::diff_input(&frame, &reference, 64, 32).unwrap();
    let set = supcon::DiffSet {
        side: 32,
        data: x,
        class: vec![0],
        press: vec![0],
        classes: vec!["T002".into()],
    };
    let (want, _) = supcon::embed(&enc, &set, 32).unwrap();
    assert!(max_diff(&got, &want) < 1e-4, "{got:?} vs {want:?}");
}

/// A head small enough to train in a test: 4 textiles, 3 presses each, 2
/// frames a press, one augmented view, 20 steps, 8 outputs (`hidden` 0: a
/// linear head).
fn tiny_head(hidden: usize) -> SpectralConfig {
    let mut cfg = SpectralConfig::new();
    cfg.data.max_textiles = Some(4);
    cfg.data.presses_per_textile = 3;
    cfg.data.frames_per_press = 2;
    cfg.augs_per_frame = 1;
    cfg.hidden = hidden;
    cfg.out = 8;
    cfg.steps = 20;
    cfg.classes_per_batch = 4;
    cfg.views_per_class = 2;
    cfg
}

#[test]
fn the_spectral_head_trains_with_and_without_attributes() {
    let dir = tempfile::tempdir().unwrap();
    let cache = dir.path().join("cache");
    let mut cfg = tiny_head(16);
    cfg.data.crop = 64;
    let (bytes, base, val) = spectral::train(&cfg, &dir.path().join("plain"), &cache, 2).unwrap();
    assert!((0.0..=1.0).contains(&base) && (0.0..=1.0).contains(&val));
    let (frame, reference) = press_frame();
    let got = daemon_embedding(&bytes, &frame, &reference);
    assert_eq!(got.len(), 8);
    assert!((got.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-4);
    // The rendered spectra are cached: the second run renders nothing and
    // its attribute objective shows in its loss.
    let files = std::fs::read_dir(&cache).unwrap().count();
    assert_eq!(files, 3);
    cfg.attr_weight = 1.0;
    spectral::train(&cfg, &dir.path().join("attr"), &cache, 2).unwrap();
    assert_eq!(std::fs::read_dir(&cache).unwrap().count(), 3);
    let first_loss = |run: &str| -> f64 {
        let m = std::fs::read_to_string(dir.path().join(run).join("metrics.jsonl")).unwrap();
        let v: serde_json::Value = serde_json::from_str(m.lines().next().unwrap()).unwrap();
        v["loss"].as_f64().unwrap()
    };
    assert!(
        first_loss("attr") > first_loss("plain") + 0.1,
        "the attribute term adds to the loss"
    );
}

/// Augmented spectra depend on the press, not on which render thread drew
/// it (runs are reproducible with any thread count).
#[test]
fn augmented_spectra_do_not_depend_on_the_thread_count() {
    let mut cfg = SpectralConfig::new();
    cfg.data.crop = 64;
    cfg.data.max_textiles = Some(3);
    cfg.data.frames_per_press = 2;
    let render = |threads| {
        spectral::render_features(&cfg, &[0, 1], &[0, 2], 2, 2, 7, threads, "test").unwrap()
    };
    let (a, b) = (render(1), render(2));
    assert!(!a.rows.is_empty());
    assert_eq!((a.rows, a.class, a.press), (b.rows, b.class, b.press));
}

/// The shipped recipe: a linear head on the whitened spectrum. It trains,
/// the daemon's encoder runs the export as trained (unit vectors of the
/// head's size), and the same command gives the same bytes (the shipped
/// model is reproducible from its card's command).
#[test]
fn a_linear_head_on_the_whitened_spectrum_trains_reproducibly() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = tiny_head(0);
    cfg.front = spectral::Front::WSpec;
    let run = |name: &str| {
        // Fresh caches: both runs render.
        let cache = dir.path().join(format!("cache-{name}"));
        spectral::train(&cfg, &dir.path().join(name), &cache, 2).unwrap()
    };
    let (a, _, _) = run("a");
    let (b, _, _) = run("b");
    assert!(a == b, "two runs of the same command differ");
    let (head, _) = telextiles_lab::graph::read_head(&a).unwrap().unwrap();
    assert_eq!((head.hidden, head.out), (0, 8));
    assert_eq!(head.input, telextiles_lab::wspec::dim(120));
    let (frame, reference) = press_frame();
    let got = daemon_embedding(&a, &frame, &reference);
    assert_eq!(got.len(), 8);
    assert!((got.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-4);
}
