//! The ONNX encoder: one `ort` session, reused; preallocated input and output
//! tensors bound once through an `IoBinding`, so a frame costs no allocation
//! of ours: preprocessing writes straight into the bound input tensor and
//! ONNX Runtime writes the embedding into the bound output tensor.
//!
//! The model is checked completely at [`Encoder::open`]: `telextiles.*`
//! metadata present and sane, input `frames` f32 `[N,3,S,S]` with S equal to
//! `telextiles.input_size`, output `embedding` f32 `[N,D]` with D equal to
//! `telextiles.embedding_dim`, `telextiles.mm_per_px` (when given) the
//! frame's scale, and one dry run on a blank frame producing D
//! finite values. Anything else is a clear error before the first frame.
//!
//! `telextiles.background = subtract`: the model takes the frame minus the
//! sensor's no-contact reference, both preprocessed (`normalise(frame) -
//! normalise(reference)`). The encoder holds the preprocessed reference it
//! is given ([`Encoder::set_reference`], [`Encoder::set_reference_pixels`]);
//! where that reference comes from and when it changes is the contact
//! detector's business (see [`crate::front`]). Encoding before there is one
//! is an error.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use image::RgbImage;
use ort::environment::Environment;
use ort::memory::Allocator;
use ort::session::builder::GraphOptimizationLevel;
use ort::session::{Session, SessionOutputs};
use ort::value::{Tensor, TensorElementType, ValueType};
use sha2::{Digest, Sha256};

use crate::frame::Frame;
use crate::preprocess::{PreprocessSpec, Preprocessor};
use telextiles_index::Features;

/// Where ONNX Runtime is loaded from when `ORT_DYLIB_PATH` is not set.
pub const DEFAULT_ORT_LIBRARY: &str = "/usr/local/lib/libonnxruntime.so.1.31.1";
/// Model input name (contract).
pub const INPUT_NAME: &str = "frames";
/// Model output name (contract).
pub const OUTPUT_NAME: &str = "embedding";

/// Encoder errors.
#[derive(Debug, thiserror::Error)]
pub enum EncoderError {
    /// ONNX Runtime could not be loaded.
    #[error("cannot load ONNX Runtime: {0}")]
    Runtime(String),
    /// The model file cannot be read or parsed.
    #[error("cannot load encoder model {path}: {msg}")]
    Model {
        /// The model.
        path: PathBuf,
        /// Why.
        msg: String,
    },
    /// The model does not follow the Telextiles encoder contract.
    #[error("encoder model {path} does not follow the Telextiles encoder contract: {msg}")]
    Contract {
        /// The model.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// Inference failed.
    #[error("encoder inference failed: {0}")]
    Inference(String),
    /// A background-subtracting model got a frame before any no-contact
    /// reference.
    #[error("the encoder subtracts the sensor's no-contact reference and has none yet (the sensor must be seen untouched first)")]
    NoReference,
    /// A frame of the wrong size.
    #[error(transparent)]
    Frame(#[from] crate::frame::FrameError),
}

/// Options for [`Encoder::open`].
#[derive(Clone, Debug)]
pub struct EncoderOptions {
    /// Intra-op threads (1 = run on the calling thread only).
    pub threads: usize,
    /// ONNX Runtime library (default: `$ORT_DYLIB_PATH`, else
    /// [`DEFAULT_ORT_LIBRARY`]). Only the first load in a process counts.
    pub ort_library: Option<PathBuf>,
}

impl Default for EncoderOptions {
    fn default() -> Self {
        EncoderOptions {
            threads: 1,
            ort_library: None,
        }
    }
}

/// What the model says about itself.
#[derive(Clone, Debug, PartialEq)]
pub struct ModelInfo {
    /// The file.
    pub path: PathBuf,
    /// Hex SHA-256 of the file (the index names it as `encoder_hash`).
    pub sha256: String,
    /// `telextiles.arch`.
    pub arch: String,
    /// `telextiles.train_data_hash`.
    pub train_data_hash: String,
    /// `telextiles.background`: "none", or "subtract" (the model takes
    /// the frame minus the no-contact reference).
    pub background: String,
    /// Embedding dimension D.
    pub dim: usize,
    /// Crop, input size and normalisation.
    pub preprocess: PreprocessSpec,
}

static RUNTIME: OnceLock<Result<Environment, String>> = OnceLock::new();

/// The ONNX Runtime library path that will be used.
pub fn ort_library_path(explicit: Option<&Path>) -> PathBuf {
    explicit
        .map(Path::to_path_buf)
        .or_else(|| std::env::var_os("ORT_DYLIB_PATH").map(PathBuf::from))
        .unwrap_or_else(|| PathBuf::from(DEFAULT_ORT_LIBRARY))
}

/// Load ONNX Runtime (once per process) and return the environment.
pub fn runtime(explicit: Option<&Path>) -> Result<&'static Environment, EncoderError> {
    let r = RUNTIME.get_or_init(|| {
        let path = ort_library_path(explicit);
        if !path.exists() {
            return Err(format!(
                "{} does not exist; install ONNX Runtime 1.31 (`bash .ci/setup`) or set ORT_DYLIB_PATH",
                path.display()
            ));
        }
        let builder = ort::init_from(&path).map_err(|e| {
            format!("{e} (ONNX Runtime >= 1.31 is needed; set ORT_DYLIB_PATH to a libonnxruntime.so of that version)")
        })?;
        builder
            .with_name("telextiles")
            .with_telemetry(false)
            .build()
            .map_err(|e| format!("cannot create the ONNX Runtime environment from {}: {e}", path.display()))
    });
    r.as_ref().map_err(|e| EncoderError::Runtime(e.clone()))
}

/// The encoder (see the module docs).
pub struct Encoder {
    session: Session,
    binding: ort::session::IoBinding,
    input: Tensor<f32>,
    output: Tensor<f32>,
    pre: Preprocessor,
    embedding: Vec<f32>,
    info: ModelInfo,
    /// `telextiles.background = subtract`.
    subtract: bool,
    /// The preprocessed no-contact reference (subtracting models).
    reference: Option<Vec<f32>>,
    /// What an embedding is made of beside the model's output (the
    /// index's [`Features`]), and the texture features' state.
    features: Features,
    texture: Option<crate::texture::Lbp>,
    gabor: Option<crate::gabor::Gabor>,
    /// The preprocessed input summed over its planes, once per frame, for
    /// every texture feature.
    grey: Vec<f32>,
}

fn contract(path: &Path, msg: impl Into<String>) -> EncoderError {
    EncoderError::Contract {
        path: path.to_path_buf(),
        msg: msg.into(),
    }
}

fn parse_triple(path: &Path, key: &str, v: &str) -> Result<[f32; 3], EncoderError> {
    let parts: Vec<Result<f32, _>> = v.split(',').map(|p| p.trim().parse::<f32>()).collect();
    match parts.as_slice() {
        [Ok(a), Ok(b), Ok(c)] if [a, b, c].iter().all(|x| x.is_finite()) => Ok([*a, *b, *c]),
        _ => Err(contract(
            path,
            format!("metadata {key} = {v:?} is not three comma-separated numbers"),
        )),
    }
}

fn dims(v: &ValueType) -> Option<(TensorElementType, Vec<i64>)> {
    match v {
        ValueType::Tensor { ty, shape, .. } => Some((*ty, shape.to_vec())),
        _ => None,
    }
}

impl Encoder {
    /// Load and check a model (see the module docs).
    pub fn open(path: &Path, opts: &EncoderOptions) -> Result<Encoder, EncoderError> {
        let bytes = std::fs::read(path).map_err(|e| EncoderError::Model {
            path: path.to_path_buf(),
            msg: e.to_string(),
        })?;
        let sha256 = hex(&Sha256::digest(&bytes));
        let env = runtime(opts.ort_library.as_deref())?;
        let model_err = |e: String| EncoderError::Model {
            path: path.to_path_buf(),
            msg: e,
        };
        let session = Session::builder(env)
            .map_err(|e| model_err(e.to_string()))?
            .with_optimization_level(GraphOptimizationLevel::All)
            .map_err(|e| model_err(e.to_string()))?
            .with_intra_threads(opts.threads.max(1))
            .map_err(|e| model_err(e.to_string()))?
            .with_inter_threads(1)
            .map_err(|e| model_err(e.to_string()))?
            .with_intra_op_spinning(false)
            .map_err(|e| model_err(e.to_string()))?
            .commit_from_memory(&bytes)
            .map_err(|e| model_err(e.to_string()))?;

        // Metadata.
        let meta = session.metadata().map_err(|e| model_err(e.to_string()))?;
        let get = |k: &str| -> Result<String, EncoderError> {
            meta.custom(k).ok_or_else(|| {
                contract(
                    path,
                    format!("metadata key {k} is missing (is this a Telextiles encoder export?)"),
                )
            })
        };
        let format = get("telextiles.format")?;
        if format != "1" {
            return Err(contract(
                path,
                format!("telextiles.format is {format:?}; this daemon reads format \"1\""),
            ));
        }
        let num = |k: &str| -> Result<u32, EncoderError> {
            let v = get(k)?;
            v.trim()
                .parse::<u32>()
                .ok()
                .filter(|n| *n > 0)
                .ok_or_else(|| {
                    contract(
                        path,
                        format!("metadata {k} = {v:?} is not a positive integer"),
                    )
                })
        };
        let size = num("telextiles.input_size")?;
        let crop = num("telextiles.crop")?;
        let dim = num("telextiles.embedding_dim")? as usize;
        let mean = parse_triple(path, "telextiles.mean", &get("telextiles.mean")?)?;
        let std = parse_triple(path, "telextiles.std", &get("telextiles.std")?)?;
        let arch = get("telextiles.arch")?;
        let train_data_hash = get("telextiles.train_data_hash")?;
        let background = get("telextiles.background")?;
        // The scale it reads frames at (optional; 0.08 mm per pixel, the
        // frame every sensor is mapped to, when absent).
        if let Some(v) = meta.custom("telextiles.mm_per_px") {
            let scale = telextiles_recording::profile::FRAME_MM_PER_PX;
            match v.trim().parse::<f32>() {
                Ok(mm) if (mm - scale).abs() <= 1e-4 => {}
                Ok(mm) => {
                    return Err(contract(
                        path,
                        format!(
                            "telextiles.mm_per_px = {mm}: the model reads frames at {mm} mm per pixel, and this daemon maps every sensor's images to {scale} (docs/sensors.md)"
                        ),
                    ))
                }
                Err(_) => {
                    return Err(contract(
                        path,
                        format!("metadata telextiles.mm_per_px = {v:?} is not a number"),
                    ))
                }
            }
        }
        let subtract = match background.as_str() {
            "none" => false,
            "subtract" => true,
            other => {
                return Err(contract(
                    path,
                    format!(
                        "telextiles.background = {other:?}; this daemon supports \"none\" and \"subtract\""
                    ),
                ))
            }
        };
        drop(meta);
        let spec = PreprocessSpec {
            crop,
            size,
            mean,
            std,
        };
        let pre = Preprocessor::new(spec.clone()).map_err(|m| contract(path, m))?;

        // Graph signature.
        let inputs = session.inputs();
        if inputs.len() != 1 || inputs[0].name() != INPUT_NAME {
            let names: Vec<&str> = inputs.iter().map(|i| i.name()).collect();
            return Err(contract(
                path,
                format!("expected one input named {INPUT_NAME:?}, the graph has {names:?}"),
            ));
        }
        let s = size as i64;
        match dims(inputs[0].dtype()) {
            Some((TensorElementType::Float32, d))
                if d.len() == 4 && d[0] <= 1 && d[1] == 3 && d[2] == s && d[3] == s => {}
            other => {
                return Err(contract(
                    path,
                    format!(
                        "input {INPUT_NAME:?} must be f32 [N,3,{s},{s}] (telextiles.input_size = {s}), the graph has {}",
                        describe(other)
                    ),
                ))
            }
        }
        let outputs = session.outputs();
        let Some(out) = outputs.iter().find(|o| o.name() == OUTPUT_NAME) else {
            let names: Vec<&str> = outputs.iter().map(|o| o.name()).collect();
            return Err(contract(
                path,
                format!("no output named {OUTPUT_NAME:?}; the graph has {names:?}"),
            ));
        };
        match dims(out.dtype()) {
            Some((TensorElementType::Float32, d)) if d.len() == 2 && d[0] <= 1 && (d[1] == dim as i64 || d[1] < 0) => {}
            other => {
                return Err(contract(
                    path,
                    format!(
                        "output {OUTPUT_NAME:?} must be f32 [N,{dim}] (telextiles.embedding_dim = {dim}), the graph has {}",
                        describe(other)
                    ),
                ))
            }
        }

        // Preallocated, bound tensors.
        let alloc = Allocator::default();
        let ort_err = |e: ort::Error| model_err(e.to_string());
        let input = Tensor::<f32>::new(&alloc, [1usize, 3, size as usize, size as usize])
            .map_err(ort_err)?;
        let mut output = Tensor::<f32>::new(&alloc, [1usize, dim]).map_err(ort_err)?;
        let mut binding = session.create_binding().map_err(ort_err)?;
        binding.bind_input(INPUT_NAME, &input).map_err(ort_err)?;
        binding
            .bind_output(OUTPUT_NAME, output.view_mut())
            .map_err(ort_err)?;

        let info = ModelInfo {
            path: path.to_path_buf(),
            sha256,
            arch,
            train_data_hash,
            background,
            dim,
            preprocess: spec,
        };
        let mut enc = Encoder {
            session,
            binding,
            input,
            output,
            pre,
            embedding: vec![0.0; dim],
            info,
            subtract,
            reference: None,
            features: Features::Encoder,
            texture: None,
            gabor: None,
            grey: Vec::new(),
        };
        // Dry run: shape and finiteness of the output, before any frame (a
        // subtracting model sees a blank frame against a blank reference). A
        // zero embedding is allowed here: fixed descriptors give one for a
        // featureless frame.
        let blank = Frame::blank().into_image();
        enc.set_reference(&blank)?;
        enc.preprocess(&blank)?;
        enc.run_raw()
            .map_err(|e| contract(path, format!("dry run on a blank frame failed: {e}")))?;
        enc.reference = None;
        Ok(enc)
    }

    /// Run the model on the bound input; checks the output's length and
    /// finiteness.
    fn run_raw(&mut self) -> Result<(), EncoderError> {
        let outputs: SessionOutputs<'_> = self
            .session
            .run_binding(&self.binding)
            .map_err(|e| EncoderError::Inference(e.to_string()))?;
        drop(outputs);
        let (shape, data) = self.output.extract_tensor();
        if data.len() != self.info.dim {
            return Err(EncoderError::Inference(format!(
                "the model produced {} values ({shape:?}), expected {}",
                data.len(),
                self.info.dim
            )));
        }
        if data.iter().any(|v| !v.is_finite()) {
            return Err(EncoderError::Inference(
                "the model produced non-finite values".into(),
            ));
        }
        Ok(())
    }

    /// What the model says about itself.
    pub fn info(&self) -> &ModelInfo {
        &self.info
    }

    /// Embedding dimension: the model's, plus the texture features' when
    /// the index asks for them ([`Encoder::set_features`]).
    pub fn dim(&self) -> usize {
        self.info.dim + self.features.extra_dim()
    }

    /// Make embeddings of `features` (the index's, which every daemon
    /// holding it computes alike): the model's output alone, or beside it
    /// the texture features of the same preprocessed input
    /// ([`crate::texture`]), each part of unit length and the whole scaled
    /// to unit length. Changes [`Encoder::dim`].
    pub fn set_features(&mut self, features: Features) {
        let side = self.info.preprocess.size as usize;
        let (lbp, gabor) = features.parts();
        self.features = features;
        self.texture = lbp.then(|| crate::texture::Lbp::new(side));
        self.gabor = gabor.then(|| crate::gabor::Gabor::new(side));
        self.grey = vec![0.0; if lbp || gabor { side * side } else { 0 }];
        self.embedding.resize(self.dim(), 0.0);
    }

    /// What an embedding is made of ([`Encoder::set_features`]).
    pub fn features(&self) -> Features {
        self.features
    }

    /// Whether the model takes the frame minus the no-contact reference.
    pub fn subtracts_background(&self) -> bool {
        self.subtract
    }

    /// Whether a subtracting model has a reference (always true otherwise).
    pub fn has_reference(&self) -> bool {
        !self.subtract || self.reference.is_some()
    }

    /// Take `frame` (untouched) as the no-contact reference. No-op for
    /// models that do not subtract it.
    pub fn set_reference(&mut self, frame: &RgbImage) -> Result<(), EncoderError> {
        if !self.subtract {
            return Ok(());
        }
        check_size(frame)?;
        let r = self.reference.get_or_insert_with(Vec::new);
        r.resize(self.pre.len(), 0.0);
        self.pre.run(frame, r);
        Ok(())
    }

    /// Take full-resolution RGB values (240x320x3, interleaved, 0..255:
    /// the contact detector's averaged reference) as the no-contact
    /// reference. No-op for models that do not subtract it.
    pub fn set_reference_pixels(&mut self, pixels: &[f32]) -> Result<(), EncoderError> {
        if !self.subtract {
            return Ok(());
        }
        if pixels.len() != crate::frame::FRAME_BYTES {
            return Err(crate::frame::FrameError::BadLength { got: pixels.len() }.into());
        }
        let r = self.reference.get_or_insert_with(Vec::new);
        r.resize(self.pre.len(), 0.0);
        self.pre.run_pixels(pixels, r);
        Ok(())
    }

    /// Forget the reference (a subtracting model then refuses to encode
    /// until it gets a new one).
    pub fn clear_reference(&mut self) {
        self.reference = None;
    }

    /// Preprocess a frame into the bound input tensor (minus the reference
    /// for subtracting models).
    pub fn preprocess(&mut self, frame: &RgbImage) -> Result<(), EncoderError> {
        check_size(frame)?;
        if self.subtract && self.reference.is_none() {
            return Err(EncoderError::NoReference);
        }
        let (_, data) = self.input.extract_tensor_mut();
        self.pre.run(frame, data);
        if let Some(r) = &self.reference {
            for (v, r) in data.iter_mut().zip(r) {
                *v -= r;
            }
        }
        Ok(())
    }

    /// Run the model on the preprocessed input; returns the L2-normalised
    /// embedding (valid until the next call).
    pub fn infer(&mut self) -> Result<&[f32], EncoderError> {
        self.run_raw()?;
        let (_, data) = self.output.extract_tensor();
        let norm = data.iter().map(|v| v * v).sum::<f32>().sqrt();
        if !norm.is_finite() || norm == 0.0 {
            return Err(EncoderError::Inference(format!(
                "the embedding has norm {norm}"
            )));
        }
        let d = self.info.dim;
        for (o, v) in self.embedding[..d].iter_mut().zip(data) {
            *o = v / norm;
        }
        if self.features != Features::Encoder {
            let (_, input) = self.input.extract_tensor();
            let mut ok = crate::texture::grey_of(input, 3, &mut self.grey);
            let mut at = d;
            let mut parts = 1;
            if let (true, Some(lbp)) = (ok, &mut self.texture) {
                let n = crate::texture::LBP_DIM;
                ok &= lbp.features_of_grey(&self.grey, &mut self.embedding[at..at + n]);
                at += n;
                parts += 1;
            }
            if let (true, Some(g)) = (ok, &mut self.gabor) {
                let n = crate::gabor::GABOR_DIM;
                ok &= g.features_of_grey(&self.grey, &mut self.embedding[at..at + n]);
                parts += 1;
            }
            if !ok {
                return Err(EncoderError::Inference(
                    "the texture features of the preprocessed frame are not finite".into(),
                ));
            }
            // Every part is of unit length: the whole is too after this.
            let k = 1.0 / (parts as f32).sqrt();
            self.embedding.iter_mut().for_each(|v| *v *= k);
        }
        Ok(&self.embedding)
    }

    /// Preprocess and run: the L2-normalised embedding of `frame`.
    pub fn encode(&mut self, frame: &RgbImage) -> Result<&[f32], EncoderError> {
        self.preprocess(frame)?;
        self.infer()
    }
}

fn check_size(frame: &RgbImage) -> Result<(), EncoderError> {
    if (frame.width(), frame.height()) != (crate::frame::FRAME_W, crate::frame::FRAME_H) {
        return Err(crate::frame::FrameError::WrongSize {
            width: frame.width(),
            height: frame.height(),
        }
        .into());
    }
    Ok(())
}

fn describe(d: Option<(TensorElementType, Vec<i64>)>) -> String {
    match d {
        Some((ty, shape)) => format!("{ty:?} {shape:?}"),
        None => "a non-tensor value".into(),
    }
}

/// Lower-case hex.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Hex SHA-256 of a file (what an index records as `encoder_hash`).
pub fn file_sha256(path: &Path) -> std::io::Result<String> {
    Ok(hex(&Sha256::digest(std::fs::read(path)?)))
}
