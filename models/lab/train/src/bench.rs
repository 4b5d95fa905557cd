//! Measurements: training step time per architecture (burn, this machine)
//! and per-frame encode latency through ONNX Runtime.

use anyhow::Result;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;

use crate::model::ArchConfig;
use crate::onnx::OrtEncoder;
use crate::train::{TrainConfig, Trainer};

/// Median of a sample (sorted copy).
pub fn median(v: &[f64]) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Quantile (nearest rank) of a sample.
pub fn quantile(v: &[f64], q: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    s[((q * s.len() as f64).ceil() as usize).clamp(1, s.len()) - 1]
}

/// Result of timing training steps of one architecture.
#[derive(Clone, Debug, serde::Serialize)]
pub struct StepTiming {
    /// Architecture name.
    pub arch: String,
    /// Parameters of the encoder.
    pub encoder_params: usize,
    /// Batch size.
    pub batch: usize,
    /// Median seconds per MoCo step (query fwd+bwd, key fwd, EMA, SGD).
    pub median_s: f64,
    /// Timed steps.
    pub steps: usize,
}

/// Time `steps` MoCo steps (after one warm-up step) on random inputs.
pub fn time_train_steps(arch: &ArchConfig, batch: usize, steps: usize) -> Result<StepTiming> {
    let mut cfg = TrainConfig::new(arch.clone());
    cfg.batch = batch;
    let mut t = Trainer::new(cfg);
    let params = burn::module::Module::num_params(&t.encoder());
    let s = arch.input;
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut times = Vec::new();
    for i in 0..steps + 1 {
        let xq: Vec<f32> = (0..batch * 3 * s * s)
            .map(|_| rng.gen_range(-2.0..2.0))
            .collect();
        let xk: Vec<f32> = (0..batch * 3 * s * s)
            .map(|_| rng.gen_range(-2.0..2.0))
            .collect();
        let t0 = Instant::now();
        t.train_step(xq, xk, batch, 0.03, &mut rng)?;
        if i > 0 {
            times.push(t0.elapsed().as_secs_f64());
        }
    }
    Ok(StepTiming {
        arch: arch.name(),
        encoder_params: params,
        batch,
        median_s: median(&times),
        steps,
    })
}

/// Per-frame latency through ONNX Runtime.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Latency {
    /// Intra-op threads.
    pub threads: usize,
    /// Median milliseconds per frame (batch 1).
    pub median_ms: f64,
    /// 90th percentile milliseconds.
    pub p90_ms: f64,
    /// Timed runs.
    pub runs: usize,
}

/// Median latency of single-frame inference (after `warmup` runs).
pub fn time_latency(model: &[u8], threads: usize, warmup: usize, runs: usize) -> Result<Latency> {
    let mut enc = OrtEncoder::from_bytes(model, threads)?;
    let s = enc.input_size;
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let x: Vec<f32> = (0..3 * s * s).map(|_| rng.gen_range(-2.0..2.0)).collect();
    let mut times = Vec::with_capacity(runs);
    for i in 0..warmup + runs {
        let t0 = Instant::now();
        let y = enc.embed(&x)?;
        std::hint::black_box(&y);
        if i >= warmup {
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    Ok(Latency {
        threads,
        median_ms: median(&times),
        p90_ms: quantile(&times, 0.9),
        runs,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_and_quantile() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert_eq!(
            quantile(&[1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0], 0.9),
            9.0
        );
        assert!(median(&[]).is_nan());
    }
}
