//! A tiny MoCo run on procedural frames: the loss goes down, the encoder
//! exports to ONNX, ONNX Runtime loads it (contract names, metadata, dynamic
//! batch) and its embeddings match burn's within 1e-4; a checkpoint resumes
//! to the same weights.

use burn::tensor::{Device, Tensor, TensorData};
use telextiles_lab::augment::AugConfig;
use telextiles_lab::data::{build_sets, PressKey, PressPlan};
use telextiles_lab::model::ArchConfig;
use telextiles_lab::onnx::{export_encoder, EncoderMeta, OrtEncoder};
use telextiles_lab::preprocess::normalize_into;
use telextiles_lab::synth::SynthSource;
use telextiles_lab::train::{make_views, train_loop, LoopOptions, RunDir, TrainConfig, Trainer};

fn tiny_arch() -> ArchConfig {
    ArchConfig {
        blocks: [1, 1, 1, 1],
        width: 4,
        input: 32,
        embed_dim: Some(16),
    }
}

fn plan(classes: usize, people: &[u32], frames: &[usize]) -> (Vec<String>, Vec<PressPlan>) {
    let names: Vec<String> = (1..=classes).map(|c| format!("T{c:03}")).collect();
    let mut p = Vec::new();
    for (ci, name) in names.iter().enumerate() {
        for &person in people {
            p.push(PressPlan {
                key: PressKey {
                    textile: name.clone(),
                    person,
                    sensor: 0,
                    jig: true,
                    seed: 1,
                },
                class: ci as u32,
                canvas_frames: frames.to_vec(),
                input_frames: vec![],
            });
        }
    }
    (names, p)
}

#[test]
fn tiny_training_lowers_loss_and_exports_onnx_that_matches_burn() {
    let (classes, p) = plan(8, &[0, 1], &[10, 40, 70, 100]);
    let (train, _) = build_sets(&SynthSource, classes, &p, 32, 48, 2, &|_, _| {}).unwrap();
    assert_eq!(train.len(), 64);

    let mut cfg = TrainConfig::new(tiny_arch());
    cfg.batch = 16;
    cfg.queue = 8;
    cfg.bn_splits = 1;
    cfg.proj_dim = 16;
    cfg.epochs = 20;
    cfg.steps_per_epoch = Some(6);
    cfg.lr = 0.01;
    cfg.key_momentum = 0.9;
    cfg.seed = 7;
    cfg.aug = AugConfig {
        jitter_p: 0.0,
        min_scale: 0.8,
        ..AugConfig::default()
    };
    let dir = tempfile::tempdir().unwrap();
    let run = RunDir(dir.path().to_path_buf());
    let mut trainer = Trainer::new(cfg.clone());
    // Fixed views of one frame per press.
    let probe: Vec<(usize, usize)> = (0..train.len()).step_by(4).map(|i| (i, i + 1)).collect();
    let mut vrng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(11);
    let (pq, pk) = make_views(&train, &probe, &cfg, &mut vrng);
    let before = trainer
        .eval_loss(pq.clone(), pk.clone(), probe.len())
        .unwrap();
    let opts = LoopOptions {
        progress_every: 0,
        max_steps: None,
        keep: 2,
        eval_every: 1,
    };
    let losses = train_loop(&mut trainer, &train, None, &run, &opts).unwrap();
    assert_eq!(losses.len(), 120);
    assert!(losses.iter().all(|l| l.is_finite()));
    let after = trainer.eval_loss(pq, pk, probe.len()).unwrap();
    eprintln!("loss on fixed views: {before:.4} -> {after:.4}");
    assert!(
        after < before - 0.1,
        "loss on fixed views did not decrease: {before:.4} -> {after:.4}"
    );

    // Resume from the last checkpoint gives the same encoder.
    let latest = run.latest().expect("a checkpoint was written");
    assert!(latest.ends_with("epoch-0020"));
    assert!(
        !run.0.join("ckpt/epoch-0010").exists(),
        "old checkpoints are pruned"
    );
    let resumed = Trainer::load(&latest).unwrap();
    assert_eq!(resumed.epoch, 20);
    assert_eq!(resumed.step, 120);
    // A resumed copy keeps training (one more epoch) from where it stopped.
    let mut more = Trainer::load(&latest).unwrap();
    more.cfg.epochs = 21;
    let extra = train_loop(&mut more, &train, None, &run, &opts).unwrap();
    assert_eq!(extra.len(), 6);
    assert_eq!(more.step, 126);
    assert!(run.latest().unwrap().ends_with("epoch-0021"));

    // Export and run through ONNX Runtime.
    let encoder = trainer.encoder();
    let meta = EncoderMeta {
        arch: tiny_arch(),
        crop: 48,
        train_data_hash: train.hash(),
        subtract: false,
    };
    let onnx = export_encoder(&encoder, &meta).unwrap();
    let mut ort = OrtEncoder::from_bytes(&onnx, 1).unwrap();
    assert_eq!(ort.input_size, 32);
    assert_eq!(ort.dim, 16);
    assert_eq!(ort.meta["telextiles.format"], "1");
    assert_eq!(ort.meta["telextiles.crop"], "48");
    assert_eq!(ort.meta["telextiles.arch"], "resnet-d1111-w4-s32-e16");
    assert_eq!(ort.meta["telextiles.embedding_dim"], "16");
    assert_eq!(ort.meta["telextiles.background"], "none");
    assert_eq!(ort.meta["telextiles.train_data_hash"], train.hash());
    assert!(ort.meta["telextiles.mean"].starts_with("0.37932"));

    // Batch of 3 (dynamic axis) of real augmented views.
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(3);
    let (x, _) = make_views(&train, &[(0, 0), (17, 17), (33, 33)], &cfg, &mut rng);
    let got = ort.embed(&x).unwrap();
    let device = Device::flex();
    let want: Vec<f32> = encoder
        .forward(Tensor::<4>::from_data(
            TensorData::new(x.clone(), [3, 3, 32, 32]),
            &device,
        ))
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    assert_eq!(got.len(), want.len());
    let diff = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(diff < 1e-4, "ort vs burn max abs diff {diff}");
    let resumed_out: Vec<f32> = resumed
        .encoder()
        .forward(Tensor::<4>::from_data(
            TensorData::new(x, [3, 3, 32, 32]),
            &device,
        ))
        .into_data()
        .try_to_vec::<f32>()
        .unwrap();
    let rdiff = resumed_out
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    assert!(rdiff < 1e-6, "resumed encoder differs by {rdiff}");

    // A batch of 1 works too, and preprocessing of an input-size image matches.
    let mut one = Vec::new();
    normalize_into(&vec![128u8; 32 * 32 * 3], 32, &mut one);
    assert_eq!(ort.embed(&one).unwrap().len(), 16);
    assert!(ort.embed(&one[..100]).is_err());
}

#[test]
fn ort_refuses_models_without_the_contract() {
    let encoder = tiny_arch().init_encoder(&Device::flex());
    let meta = EncoderMeta {
        arch: tiny_arch(),
        crop: 168,
        train_data_hash: "00".into(),
        subtract: false,
    };
    let onnx = export_encoder(&encoder, &meta).unwrap();
    // Strip the metadata: refused with a clear message.
    let mut model = <onnx_ir::ModelProto as onnx_ir::Message>::parse_from_bytes(&onnx).unwrap();
    model.metadata_props.clear();
    let bare = onnx_ir::Message::write_to_bytes(&model).unwrap();
    let err = OrtEncoder::from_bytes(&bare, 1)
        .err()
        .expect("refused")
        .to_string();
    assert!(err.contains("telextiles.input_size"), "{err}");
    assert!(OrtEncoder::from_bytes(b"not onnx", 1).is_err());
}
