//! telextiles-train: the lab's training — contrastive CNN encoders and
//! trained spectral heads with burn (`model`, `train`, `supcon`,
//! `spectral`), their ONNX export under the encoder contract (`onnx`), the
//! training step's cost (`bench`), and the data protocol they train and
//! are evaluated on (`data`, `augment`, `protocol`, `synth`,
//! `simsource`). burn is a dependency of this crate and of the lab's
//! studies only; the daemon never links it.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod augment;
pub mod bench;
pub mod data;
pub mod model;
pub mod onnx;
pub mod protocol;
pub mod simsource;
pub mod spectral;
pub mod supcon;
pub mod synth;
pub mod train;
