//! ONNX export (burn-onnx) of a trained encoder with the Telextiles
//! encoder contract; running it is [`telextiles_graphs::ortrun`]'s.

use anyhow::{anyhow, ensure, Context, Result};
use burn::module::Module;
use burn::tensor::{Device, Tensor};
use burn_onnx::export::{AxisSpec, InputSpec, OnnxExporter};
use onnx_ir::{Message, ModelProto};

use crate::model::{ArchConfig, Encoder};
pub use telextiles_graphs::ortrun::{
    contract_props, init_ort, ort_dylib_path, OrtEncoder, INPUT_NAME, OUTPUT_NAME,
};

/// Metadata written into `metadata_props` (keys `telextiles.*`).
#[derive(Clone, Debug, PartialEq)]
pub struct EncoderMeta {
    /// Architecture (also gives input size and embedding dim).
    pub arch: ArchConfig,
    /// Centre-crop side in px of the 240x320 frame.
    pub crop: u32,
    /// Hex hash of the training data.
    pub train_data_hash: String,
    /// The model takes the frame minus the no-contact reference
    /// (`telextiles.background = subtract`).
    pub subtract: bool,
}

impl EncoderMeta {
    /// All `telextiles.*` key/value pairs of the contract.
    pub fn props(&self) -> Vec<(String, String)> {
        contract_props(
            self.arch.input as u32,
            self.crop,
            self.arch.embedding_dim(),
            &self.arch.name(),
            &self.train_data_hash,
            self.subtract,
        )
    }
}

/// Export the encoder (inference mode) to ONNX bytes with named input/output,
/// a dynamic batch axis and the contract's metadata.
pub fn export_encoder(encoder: &Encoder, meta: &EncoderMeta) -> Result<Vec<u8>> {
    let device = Device::flex();
    let enc = encoder.valid().to_device(&device);
    let s = meta.arch.input;
    let sample = Tensor::<4>::zeros([1, 3, s, s], &device);
    let validation = Tensor::<4>::zeros([2, 3, s, s], &device);
    let specs = [InputSpec::new([
        AxisSpec::dynamic("batch"),
        AxisSpec::Static,
        AxisSpec::Static,
        AxisSpec::Static,
    ])];
    let onnx = OnnxExporter::new()
        .export_dynamic(&enc, sample, validation, &specs, Encoder::forward)
        .map_err(|e| anyhow!("burn-onnx export failed: {e}"))?;
    finish_model(onnx.as_bytes(), meta)
}

/// Rename the graph's single input/output to the contract names and set
/// `metadata_props`.
pub fn finish_model(bytes: &[u8], meta: &EncoderMeta) -> Result<Vec<u8>> {
    let mut model = ModelProto::parse_from_bytes(bytes).context("exported ONNX does not parse")?;
    let graph = model.graph.mut_or_insert_default();
    let inits: std::collections::HashSet<String> =
        graph.initializer.iter().map(|t| t.name.clone()).collect();
    let inputs: Vec<usize> = (0..graph.input.len())
        .filter(|&i| !inits.contains(&graph.input[i].name))
        .collect();
    ensure!(
        inputs.len() == 1,
        "expected one graph input, found {}",
        inputs.len()
    );
    ensure!(
        graph.output.len() == 1,
        "expected one graph output, found {}",
        graph.output.len()
    );
    let old_in = graph.input[inputs[0]].name.clone();
    let old_out = graph.output[0].name.clone();
    let rename = |s: &mut String| {
        if *s == old_in {
            *s = INPUT_NAME.to_string();
        } else if *s == old_out {
            *s = OUTPUT_NAME.to_string();
        }
    };
    for node in graph.node.iter_mut() {
        node.input.iter_mut().for_each(rename);
        node.output.iter_mut().for_each(rename);
    }
    for vi in graph
        .input
        .iter_mut()
        .chain(graph.output.iter_mut())
        .chain(graph.value_info.iter_mut())
    {
        rename(&mut vi.name);
    }
    model.producer_name = "telextiles-lab".into();
    model.producer_version = env!("CARGO_PKG_VERSION").into();
    model
        .metadata_props
        .retain(|p| !p.key.starts_with("telextiles."));
    for (k, v) in meta.props() {
        model.metadata_props.push(Default::default());
        let e = model.metadata_props.last_mut().expect("just pushed");
        e.key = k;
        e.value = v;
    }
    model.write_to_bytes().context("serialising ONNX")
}
