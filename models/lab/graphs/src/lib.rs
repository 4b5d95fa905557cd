//! telextiles-graphs: the lab's fixed (untrained) descriptors — the
//! colour-whitened spectrum the shipped encoder is made of, the radial
//! spectrum, moment statistics — written as ONNX graphs under the
//! Telextiles encoder contract (`graph`, `wspec`), their Rust references
//! (`baselines`, `mstats`), the daemon's preprocessing as the lab applies
//! it (`preprocess`), nearest-neighbour helpers (`knn`), and running any
//! contract model in ONNX Runtime (`ortrun`). None of burn's training
//! stack (no autodiff, optimisers or ONNX export; onnx-ir, whose protobuf
//! types write the graphs, brings burn-tensor's data types): building or
//! checking a shipped descriptor never compiles the trainer.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod baselines;
pub mod graph;
pub mod knn;
pub mod mstats;
pub mod ortrun;
pub mod preprocess;
pub mod wspec;
