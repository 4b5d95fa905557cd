//! telextiles-lab: the manufacturer side of Telextiles — its studies and
//! its command line (`telextiles-lab`). The descriptor graphs are
//! `telextiles-graphs` (no burn), the training `telextiles-train` (burn);
//! this crate evaluates them as in the paper, on held-out and recorded
//! presses, for stability, decision timing and cost, and writes the
//! reports. Their modules are re-exported under the names the studies use.
//! The daemon never links any of the three.
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub use telextiles_graphs::{baselines, graph, knn, mstats, ortrun, preprocess, wspec};
pub use telextiles_train::{
    augment, bench, data, model, onnx, protocol, simsource, spectral, supcon, synth, train,
};

pub mod attrmap;
pub mod contact_idle;
pub mod decider_timing;
pub mod decision_curve;
pub mod detector;
pub mod methods;
pub mod paper_eval;
pub mod quantize;
pub mod recorded;
pub mod recorded_report;
pub mod recorded_score;
pub mod report;
pub mod rule;
pub mod stability;
pub mod stability_charts;
pub mod usertest;
