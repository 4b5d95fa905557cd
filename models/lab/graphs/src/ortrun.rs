//! Running an ONNX model that follows the Telextiles encoder contract
//! through ONNX Runtime (`ort`) — for verification, evaluation and latency
//! measurements — and the contract's names and `telextiles.*` metadata.

use anyhow::{anyhow, bail, ensure, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::preprocess::{DIGIT_MEAN, DIGIT_STD};

/// Name of the input tensor.
pub const INPUT_NAME: &str = "frames";
/// Name of the output tensor.
pub const OUTPUT_NAME: &str = "embedding";

/// The contract's `telextiles.*` metadata of a model with this input size,
/// crop, embedding length, architecture name and training-data hash.
/// `subtract`: the model takes the frame minus the sensor's no-contact
/// reference (`telextiles.background = subtract`: the input is
/// `normalise(frame) - normalise(reference)`), else the frame
/// (`none`).
pub fn contract_props(
    input: u32,
    crop: u32,
    dim: usize,
    arch: &str,
    train_data_hash: &str,
    subtract: bool,
) -> Vec<(String, String)> {
    let f3 = |v: [f32; 3]| format!("{},{},{}", v[0], v[1], v[2]);
    vec![
        ("telextiles.format".into(), "1".into()),
        ("telextiles.input_size".into(), input.to_string()),
        ("telextiles.crop".into(), crop.to_string()),
        ("telextiles.mean".into(), f3(DIGIT_MEAN)),
        ("telextiles.std".into(), f3(DIGIT_STD)),
        ("telextiles.embedding_dim".into(), dim.to_string()),
        ("telextiles.arch".into(), arch.to_string()),
        (
            "telextiles.train_data_hash".into(),
            train_data_hash.to_string(),
        ),
        (
            "telextiles.background".into(),
            if subtract { "subtract" } else { "none" }.into(),
        ),
    ]
}

/// Path of the ONNX Runtime library: `$ORT_DYLIB_PATH` or the CI install.
pub fn ort_dylib_path() -> PathBuf {
    std::env::var_os("ORT_DYLIB_PATH")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/local/lib/libonnxruntime.so.1.31.1"))
}

/// Load ONNX Runtime once per process and return its environment: the
/// sensing crate's (ONNX Runtime allows one environment per process, and
/// the study on recorded presses runs the daemon's encoder beside the
/// lab's sessions).
pub fn init_ort() -> Result<&'static ort::environment::Environment> {
    let path = ort_dylib_path();
    telextiles_sensing::encoder::runtime(Some(&path))
        .map_err(|e| anyhow!("cannot load ONNX Runtime from {}: {e}", path.display()))
}

/// An encoder loaded in ONNX Runtime.
pub struct OrtEncoder {
    session: ort::session::Session,
    /// Network input side.
    pub input_size: usize,
    /// Embedding dimension.
    pub dim: usize,
    /// `telextiles.*` metadata of the model.
    pub meta: BTreeMap<String, String>,
}

impl OrtEncoder {
    /// Whether the model takes the frame minus the sensor's no-contact
    /// reference (`telextiles.background`: "subtract", or "none"/absent).
    pub fn subtracts_background(&self) -> Result<bool> {
        match self.meta.get("telextiles.background").map(String::as_str) {
            Some("subtract") => Ok(true),
            Some("none") | None => Ok(false),
            Some(other) => anyhow::bail!("unknown telextiles.background {other:?}"),
        }
    }

    /// Load from bytes with `threads` intra-op threads; checks the contract.
    pub fn from_bytes(bytes: &[u8], threads: usize) -> Result<Self> {
        let env = init_ort()?;
        let session = ort::session::Session::builder(env)
            .map_err(|e| anyhow!("{e}"))?
            .with_intra_threads(threads)
            .map_err(|e| anyhow!("{e}"))?
            .with_inter_threads(1)
            .map_err(|e| anyhow!("{e}"))?
            .commit_from_memory(bytes)
            .map_err(|e| anyhow!("ONNX Runtime cannot load the model: {e}"))?;
        let md = session.metadata().map_err(|e| anyhow!("{e}"))?;
        let mut meta = BTreeMap::new();
        for k in md.custom_keys().map_err(|e| anyhow!("{e}"))? {
            if let Some(v) = md.custom(&k) {
                meta.insert(k, v);
            }
        }
        drop(md);
        let get = |k: &str| -> Result<usize> {
            meta.get(k)
                .with_context(|| format!("model metadata lacks {k}"))?
                .parse()
                .with_context(|| format!("model metadata {k} is not a number"))
        };
        let input_size = get("telextiles.input_size")?;
        let dim = get("telextiles.embedding_dim")?;
        let ins = session.inputs();
        let outs = session.outputs();
        ensure!(
            ins.len() == 1 && ins[0].name() == INPUT_NAME,
            "model input must be a single tensor named {INPUT_NAME:?}"
        );
        ensure!(
            outs.len() == 1 && outs[0].name() == OUTPUT_NAME,
            "model output must be a single tensor named {OUTPUT_NAME:?}"
        );
        let ishape: Vec<i64> = ins[0]
            .dtype()
            .tensor_shape()
            .context("input is not a tensor")?
            .to_vec();
        let s = input_size as i64;
        ensure!(
            ishape.len() == 4 && ishape[0] < 0 && ishape[1..] == [3, s, s],
            "model input shape {ishape:?} is not [N, 3, {s}, {s}] with dynamic N"
        );
        let oshape: Vec<i64> = outs[0]
            .dtype()
            .tensor_shape()
            .context("output is not a tensor")?
            .to_vec();
        ensure!(
            oshape.len() == 2 && oshape[1] == dim as i64,
            "model output shape {oshape:?} is not [N, {dim}]"
        );
        Ok(OrtEncoder {
            session,
            input_size,
            dim,
            meta,
        })
    }

    /// Load from a file.
    pub fn from_file(path: &Path, threads: usize) -> Result<Self> {
        let bytes =
            std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        Self::from_bytes(&bytes, threads).with_context(|| format!("model {}", path.display()))
    }

    /// Embed `n` preprocessed frames (`n * 3 * S * S` floats, NCHW).
    pub fn embed(&mut self, frames: &[f32]) -> Result<Vec<f32>> {
        let per = 3 * self.input_size * self.input_size;
        if frames.is_empty() || !frames.len().is_multiple_of(per) {
            bail!(
                "{} floats is not a whole number of {}-float frames",
                frames.len(),
                per
            );
        }
        let n = frames.len() / per;
        let s = self.input_size;
        let t = ort::value::TensorRef::from_array_view(([n, 3, s, s], frames))
            .map_err(|e| anyhow!("{e}"))?;
        let out = self
            .session
            .run(ort::inputs![INPUT_NAME => t])
            .map_err(|e| anyhow!("{e}"))?;
        let (shape, data) = out[OUTPUT_NAME]
            .try_extract_tensor::<f32>()
            .map_err(|e| anyhow!("{e}"))?;
        ensure!(
            shape.len() == 2 && shape[0] as usize == n && shape[1] as usize == self.dim,
            "bad output shape {shape:?}"
        );
        Ok(data.to_vec())
    }
}
