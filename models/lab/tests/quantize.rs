//! int8 static quantisation through ONNX Runtime's tool (the Python that
//! `.ci/setup` installs), calibrated on frames of the protocol: the result
//! keeps the encoder contract and stays close to the float model; a missing
//! Python is a clear error.

use telextiles_lab::model::ArchConfig;
use telextiles_lab::onnx::{export_encoder, EncoderMeta, OrtEncoder};
use telextiles_lab::protocol::{self, view_set, Protocol, SourceKind};
use telextiles_lab::quantize::quantize;

#[test]
fn int8_models_keep_the_contract_and_track_the_float_model() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = Protocol::paper(32, 32);
    p.max_textiles = Some(4);
    let sets = protocol::load_base(&p, SourceKind::Synth, dir.path(), 2).unwrap();
    let arch = ArchConfig {
        blocks: [1, 1, 1, 1],
        width: 8,
        input: 32,
        embed_dim: None,
    };
    let enc = arch.init_encoder(&burn::tensor::Device::flex());
    let float = export_encoder(
        &enc,
        &EncoderMeta {
            arch,
            crop: 32,
            train_data_hash: "untrained".into(),
            subtract: false,
        },
    )
    .unwrap();
    let calib = view_set(&sets.train_index, 32, 32).unwrap();
    let compare = view_set(&sets.heldout, 32, 32).unwrap();
    let refs = view_set(&sets.backgrounds, 32, 32).unwrap();
    let (q, report) = quantize(&float, &calib, 64, &compare, &refs, false).unwrap();
    assert_eq!(report.calibration_frames, 64);
    assert_eq!(report.nonfinite_frames, 0);
    assert!(report.cosine_mean > 0.95, "{report:?}");
    let m = OrtEncoder::from_bytes(&q, 1).unwrap();
    assert_eq!(m.dim, 64);
    assert_eq!(m.meta["telextiles.crop"], "32");
    assert!(
        m.meta["telextiles.quantization"].contains("int8 static QDQ"),
        "{:?}",
        m.meta
    );
    // The graph really is quantised: QuantizeLinear nodes, smaller weights.
    let model = <onnx_ir::ModelProto as onnx_ir::Message>::parse_from_bytes(&q).unwrap();
    let ops: Vec<&str> = model
        .graph
        .node
        .iter()
        .map(|n| n.op_type.as_str())
        .collect();
    assert!(ops.contains(&"QuantizeLinear"), "{ops:?}");
    assert!(q.len() < float.len(), "{} vs {}", q.len(), float.len());

    // Without a Python that has the tool: a clear error, nothing written.
    std::env::set_var("TELEXTILES_PYTHON", "/nonexistent/python3");
    let e = quantize(&float, &calib, 8, &compare, &refs, false).unwrap_err();
    std::env::remove_var("TELEXTILES_PYTHON");
    let msg = format!("{e:#}");
    assert!(
        msg.contains("TELEXTILES_PYTHON") && msg.contains("/nonexistent/python3"),
        "{msg}"
    );
}

/// The spectrum descriptor's int8 version gives non-finite embeddings (its
/// weak bins round to zero before the log): refused unless allowed, and
/// then reported.
#[test]
fn int8_models_with_non_finite_output_are_refused_unless_allowed() {
    use telextiles_lab::baselines::BaselineKind;
    use telextiles_lab::graph::{descriptor_model, DescriptorSpec};
    let dir = tempfile::tempdir().unwrap();
    let mut p = Protocol::paper(32, 32);
    p.max_textiles = Some(4);
    let sets = protocol::load_base(&p, SourceKind::Synth, dir.path(), 2).unwrap();
    let float = descriptor_model(&DescriptorSpec {
        kind: BaselineKind::Fft,
        crop: 32,
        input: 32,
        subtract: true,
        min_bin: 1,
        taper: 100,
    })
    .unwrap();
    let calib = view_set(&sets.train_index, 32, 32).unwrap();
    let compare = view_set(&sets.heldout, 32, 32).unwrap();
    let refs = view_set(&sets.backgrounds, 32, 32).unwrap();
    let e = quantize(&float, &calib, 64, &compare, &refs, false).unwrap_err();
    assert!(format!("{e:#}").contains("non-finite"), "{e:#}");
    let (_, report) = quantize(&float, &calib, 64, &compare, &refs, true).unwrap();
    assert!(report.nonfinite_frames > 0, "{report:?}");
}
