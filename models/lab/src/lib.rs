//! telextiles-lab: the manufacturer side of Telextiles. Trains the
//! contrastive encoder with burn (MoCo v2 style), exports it to ONNX with the
//! encoder contract, verifies it in ONNX Runtime, evaluates it as in the
//! paper and measures latency. burn is a dependency of this crate only; the
//! daemon never links it.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod attrmap;
pub mod augment;
pub mod baselines;
pub mod bench;
pub mod contact_idle;
pub mod data;
pub mod decider_timing;
pub mod decision_curve;
pub mod detector;
pub mod graph;
pub mod knn;
pub mod methods;
pub mod model;
pub mod mstats;
pub mod onnx;
pub mod paper_eval;
pub mod preprocess;
pub mod protocol;
pub mod quantize;
pub mod recorded;
pub mod recorded_report;
pub mod recorded_score;
pub mod report;
pub mod rule;
pub mod simsource;
pub mod spectral;
pub mod stability;
pub mod stability_charts;
pub mod supcon;
pub mod synth;
pub mod train;
pub mod usertest;
pub mod wspec;
