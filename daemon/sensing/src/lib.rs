//! Frame sources (V4L2 DIGIT, recorded, simulated), contact detection, ONNX encoding and decisions
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod contact;
/// The decider lives in `telextiles-press` (pure, shared with the session core).
pub use telextiles_press::decide;
pub mod encoder;
pub mod frame;
pub mod front;
pub mod gabor;
pub mod idle;
pub mod pipeline;
pub mod preprocess;
pub mod record;
pub mod source;
pub mod texture;
