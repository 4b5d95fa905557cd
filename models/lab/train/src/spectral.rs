//! A trained contrastive head on the shipped spectrum (issue 20): the fixed
//! front end is the radially averaged log power spectrum of the frame minus
//! its reference (`fft-radial-c<crop>-bg`, the shipped descriptor, exactly
//! its ONNX graph), and a small MLP on top is trained with supervised
//! contrastive learning (SupCon) on presses of the same textile by other
//! people, on other units, at other rotations, with the same physical
//! augmentations as the CNN ([`crate::supcon::augment_diff`]).
//!
//! Why a head on the spectrum: the spectrum is already invariant to
//! rotation and translation and costs 0.9 ms; what it cannot do is weigh
//! its bands: which scales tell fabrics apart and which ones a sensor
//! unit's blur, noise or gain colour. That is what a few thousand weights
//! can learn from data, at almost no extra inference cost
//! (`telextiles.arch = fft-radial-c192-bg+mlp<hidden>-<out>`).

use anyhow::{ensure, Context, Result};
use burn::module::Module;
use burn::nn::{Linear, LinearConfig};
use burn::optim::{AdamWConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::activation::relu;
use burn::tensor::{Device, Tensor, TensorData};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

use crate::model::l2_normalize;
use crate::onnx::OrtEncoder;
use crate::supcon::{
    augment_diff, make_plans, press_top1, render_press, supcon_loss, PressGroups, SupConConfig,
};
use telextiles_graphs::graph::{descriptor_model, descriptor_with_head, DescriptorSpec, MlpHead};

/// The fixed front end a head is trained on.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Front {
    /// `fft-radial-c192-bg`: the luma spectrum of the 192-px crop (the
    /// first shipped descriptor).
    #[default]
    Fft,
    /// `wspec-c240-s120-bg`: the colour-whitened spectrum with angular
    /// harmonics of the 240-px crop at 120 px ([`telextiles_graphs::wspec`]).
    WSpec,
    /// `wspec-cw-c240-s120-bg`: the same under a window centred on the
    /// contact ([`telextiles_graphs::wspec::Window::Contact`]).
    #[serde(rename = "wspec-cw")]
    WSpecCw,
}

impl std::str::FromStr for Front {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "fft" => Ok(Front::Fft),
            "wspec" => Ok(Front::WSpec),
            "wspec-cw" => Ok(Front::WSpecCw),
            o => Err(format!(
                "unknown front end {o:?}: expected fft, wspec or wspec-cw"
            )),
        }
    }
}

/// The head: `x * scale` → Linear → ReLU → Linear, or, with no hidden
/// layer, `x * scale` → Linear. `attr` (training only, never exported)
/// predicts the textile's measured attributes from the embedding when the
/// attribute objective is on.
#[derive(Module, Debug)]
pub struct Head {
    l1: Linear,
    l2: Option<Linear>,
    attr: Option<Linear>,
}

impl Head {
    /// `hidden == 0`: a linear head.
    pub fn new(input: usize, hidden: usize, out: usize, attrs: usize, device: &Device) -> Head {
        let first = if hidden == 0 { out } else { hidden };
        Head {
            l1: LinearConfig::new(input, first).init(device),
            l2: (hidden > 0).then(|| LinearConfig::new(hidden, out).init(device)),
            attr: (attrs > 0).then(|| LinearConfig::new(out, attrs).init(device)),
        }
    }

    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        let x = self.l1.forward(x);
        match &self.l2 {
            Some(l2) => l2.forward(relu(x)),
            None => x,
        }
    }

    /// Weights as plain arrays for the ONNX graph (`w` row-major `[in,
    /// out]`, as ONNX MatMul takes them).
    pub fn to_mlp(&self, scale: Vec<f32>) -> Result<MlpHead> {
        let v = |t: Tensor<2>| -> Result<Vec<f32>> {
            t.into_data()
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("{e:?}"))
        };
        let b = |t: Tensor<1>| -> Result<Vec<f32>> {
            t.into_data()
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("{e:?}"))
        };
        let [i, h] = self.l1.weight.val().dims();
        let w1 = v(self.l1.weight.val())?;
        let b1 = b(self.l1.bias.as_ref().context("layer 1 has no bias")?.val())?;
        let Some(l2) = &self.l2 else {
            return Ok(MlpHead {
                scale,
                w1,
                b1,
                w2: Vec::new(),
                b2: Vec::new(),
                input: i,
                hidden: 0,
                out: h,
            });
        };
        let [_, o] = l2.weight.val().dims();
        Ok(MlpHead {
            scale,
            w1,
            b1,
            w2: v(l2.weight.val())?,
            b2: b(l2.bias.as_ref().context("layer 2 has no bias")?.val())?,
            input: i,
            hidden: h,
            out: o,
        })
    }
}

/// A run's settings.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SpectralConfig {
    /// Presses, people, units, rotations, validation: as the CNN's recipe.
    pub data: SupConConfig,
    /// The fixed descriptor under the head.
    #[serde(default)]
    pub front: Front,
    /// Its window's taper in % (the centred front ends, `fft` and `wspec`;
    /// `wspec-cw` refuses it; 100: the Hann window, left out of the
    /// settings' record so that models trained before it keep their hash).
    #[serde(default = "hann_taper", skip_serializing_if = "is_hann_taper")]
    pub taper: u32,
    /// Augmented copies of every rendered frame.
    pub augs_per_frame: usize,
    pub hidden: usize,
    pub out: usize,
    pub steps: usize,
    pub classes_per_batch: usize,
    pub views_per_class: usize,
    pub lr: f64,
    pub temperature: f32,
    /// Weight of the attribute objective (0: off): the embedding must also
    /// predict the textile's tactile attributes (the maker's measured
    /// properties of its own sample book: roughness, density, softness,
    /// ...; standardised), so that unseen fabrics land near perceptually
    /// close known ones.
    #[serde(default)]
    pub attr_weight: f32,
}

fn hann_taper() -> u32 {
    100
}

fn is_hann_taper(t: &u32) -> bool {
    *t == 100
}

impl SpectralConfig {
    pub fn new() -> Self {
        let mut data = SupConConfig::new(
            crate::model::ArchConfig::parse("resnet-d1111-w16-s96").expect("a valid name"),
        );
        data.presses_per_textile = 24;
        SpectralConfig {
            data,
            front: Front::Fft,
            taper: 100,
            augs_per_frame: 3,
            hidden: 256,
            out: 128,
            steps: 4000,
            classes_per_batch: 32,
            views_per_class: 4,
            lr: 3e-3,
            temperature: 0.1,
            attr_weight: 0.0,
        }
    }

    /// The front end's descriptor (the 192-px crop of the recipe for
    /// `fft`; the whole 240-px width at 120 px for `wspec`).
    pub fn spec(&self) -> DescriptorSpec {
        match self.front {
            Front::Fft => DescriptorSpec {
                kind: telextiles_graphs::baselines::BaselineKind::Fft,
                crop: self.data.crop,
                input: self.data.crop,
                subtract: true,
                min_bin: 1,
                taper: self.taper,
            },
            Front::WSpec | Front::WSpecCw => DescriptorSpec {
                kind: if self.front == Front::WSpec {
                    telextiles_graphs::baselines::BaselineKind::WSpec
                } else {
                    telextiles_graphs::baselines::BaselineKind::WSpecCw
                },
                crop: 240,
                input: 120,
                subtract: true,
                min_bin: 1,
                taper: self.taper,
            },
        }
    }
}

impl Default for SpectralConfig {
    fn default() -> Self {
        Self::new()
    }
}

/// Spectra of rendered presses: rows of `dim`, with textile and press.
pub struct Features {
    pub dim: usize,
    pub rows: Vec<f32>,
    pub class: Vec<u32>,
    pub press: Vec<u32>,
}

impl Features {
    fn write(&self, path: &Path) -> Result<()> {
        let mut b = Vec::with_capacity(16 + self.rows.len() * 4 + self.class.len() * 8);
        b.extend((self.dim as u64).to_le_bytes());
        b.extend((self.class.len() as u64).to_le_bytes());
        b.extend(self.rows.iter().flat_map(|v| v.to_le_bytes()));
        b.extend(self.class.iter().flat_map(|v| v.to_le_bytes()));
        b.extend(self.press.iter().flat_map(|v| v.to_le_bytes()));
        crate::data::write_atomic(path, &b)
    }

    fn read(path: &Path) -> Result<Features> {
        let b = std::fs::read(path)?;
        ensure!(b.len() >= 16, "{}: truncated", path.display());
        let u = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes")) as usize;
        let (dim, n) = (u(0), u(8));
        ensure!(
            b.len() == 16 + n * dim * 4 + n * 8,
            "{}: wrong size",
            path.display()
        );
        let f32s = |at: usize, k: usize| -> Vec<f32> {
            b[at..at + 4 * k]
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect()
        };
        let u32s = |at: usize, k: usize| -> Vec<u32> {
            b[at..at + 4 * k]
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect()
        };
        let rows = f32s(16, n * dim);
        let class = u32s(16 + 4 * n * dim, n);
        let press = u32s(16 + 4 * n * dim + 4 * n, n);
        Ok(Features {
            dim,
            rows,
            class,
            press,
        })
    }
}

/// [`render_features`] through a cache file in `cache_dir` named after
/// everything that decides its content.
#[allow(clippy::too_many_arguments)]
pub fn cached_features(
    cache_dir: &Path,
    cfg: &SpectralConfig,
    people: &[u32],
    units: &[u32],
    presses_per_textile: usize,
    augs: usize,
    seed: u64,
    threads: usize,
    label: &str,
) -> Result<Features> {
    use sha2::Digest;
    let mut h = sha2::Sha256::new();
    h.update(serde_json::to_vec(&(
        &cfg.data,
        cfg.spec().arch(),
        people,
        units,
        presses_per_textile,
        augs,
        seed,
        "spectral-features-1",
    ))?);
    let path = cache_dir.join(format!(
        "spectra-{}.bin",
        &crate::data::hex(&h.finalize())[..16]
    ));
    if let Ok(f) = Features::read(&path) {
        eprintln!("{label}: using {}", path.display());
        return Ok(f);
    }
    let f = render_features(
        cfg,
        people,
        units,
        presses_per_textile,
        augs,
        seed,
        threads,
        label,
    )?;
    std::fs::create_dir_all(cache_dir)?;
    f.write(&path)?;
    Ok(f)
}

#[allow(clippy::too_many_arguments)]
/// Renders presses and returns the descriptor's spectra of `augs` augmented
/// views of each kept frame (`augs == 0`: the frame as deployed, once).
pub fn render_features(
    cfg: &SpectralConfig,
    people: &[u32],
    units: &[u32],
    presses_per_textile: usize,
    augs: usize,
    seed: u64,
    threads: usize,
    label: &str,
) -> Result<Features> {
    let d = &cfg.data;
    let sim = telextiles_sim::Simulator::with_options(d.catalogue, d.generator)
        .map_err(|e| anyhow::anyhow!("simulator: {e}"))?;
    let (_, plans) = make_plans(&sim, d, people, units, presses_per_textile, seed);
    let spec = cfg.spec();
    let graph = descriptor_model(&spec)?;
    let (crop, size) = (spec.crop as usize, spec.input as usize);
    // 8 frame px of margin each side for the translation augmentation,
    // where the frame's width leaves them; stored at the input's scale.
    let stored_crop = (crop + 16).min(240);
    let stored = stored_crop * size / crop;
    let bar = telextiles_progress::Progress::new(label, plans.len() as u64, "presses");
    let next = std::sync::atomic::AtomicUsize::new(0);
    let out = std::sync::Mutex::new(Vec::new());
    let first_err = std::sync::Mutex::new(None::<anyhow::Error>);
    std::thread::scope(|s| {
        for _ in 0..threads.max(1) {
            let (graph, plans, sim, bar, next, out, first_err) =
                (&graph, &plans, &sim, &bar, &next, &out, &first_err);
            s.spawn(move || {
                let run = || -> Result<()> {
                    let mut enc = OrtEncoder::from_bytes(graph, 1)?;
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        if i >= plans.len() {
                            return Ok(());
                        }
                        // Per press, not per thread: the same spectra
                        // whichever thread renders the press.
                        let mut rng = ChaCha8Rng::seed_from_u64(
                            seed ^ (i as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15),
                        );
                        let p = &plans[i];
                        let frames = render_press(sim, d, p, stored_crop as u32, stored)?;
                        let mut x = Vec::new();
                        let mut n = 0;
                        for f in &frames {
                            if augs == 0 {
                                x.extend(crate::supcon::centre_of(f, stored, size));
                                n += 1;
                            }
                            for _ in 0..augs {
                                let mut v = vec![0f32; 3 * size * size];
                                augment_diff(f, stored, size, &mut rng, &mut v);
                                x.extend(v);
                                n += 1;
                            }
                        }
                        let rows = enc.embed(&x)?;
                        out.lock()
                            .unwrap_or_else(|p| p.into_inner())
                            .push((i, p.class, n, rows));
                        bar.inc(1);
                    }
                };
                if let Err(e) = run() {
                    first_err
                        .lock()
                        .unwrap_or_else(|p| p.into_inner())
                        .get_or_insert(e);
                }
            });
        }
    });
    bar.finish();
    if let Some(e) = first_err.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(e);
    }
    let mut res = out.into_inner().unwrap_or_else(|p| p.into_inner());
    res.sort_by_key(|r| r.0);
    let dim = cfg.spec().dim();
    let mut f = Features {
        dim,
        rows: Vec::new(),
        class: Vec::new(),
        press: Vec::new(),
    };
    for (i, class, n, rows) in res {
        ensure!(rows.len() == n * dim, "descriptor rows have the wrong size");
        f.rows.extend(rows);
        f.class.extend(std::iter::repeat_n(class, n));
        f.press.extend(std::iter::repeat_n(i as u32, n));
    }
    Ok(f)
}

fn embed_rows(head: &Head, scale: &[f32], rows: &[f32], dim: usize) -> Result<(Vec<f32>, usize)> {
    let device = Device::flex();
    let h = head.valid().to_device(&device);
    let n = rows.len() / dim;
    let x: Vec<f32> = rows
        .chunks_exact(dim)
        .flat_map(|r| r.iter().zip(scale).map(|(v, s)| v * s))
        .collect();
    let y = h.forward(Tensor::<2>::from_data(
        TensorData::new(x, [n, dim]),
        &device,
    ));
    let out_dim = y.dims()[1];
    let mut v = y
        .into_data()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("{e:?}"))?;
    telextiles_graphs::knn::normalize_rows(&mut v, out_dim);
    Ok((v, out_dim))
}

/// The hash of a run's settings that its model records as
/// `telextiles.train_data_hash` (the first 16 hex digits of the SHA-256 of
/// the configuration as JSON): the same command gives the same hash.
pub fn run_hash(cfg: &SpectralConfig) -> Result<String> {
    use sha2::Digest;
    let mut h = sha2::Sha256::new();
    h.update(serde_json::to_vec(cfg)?);
    Ok(crate::data::hex(&h.finalize())[..16].to_string())
}

/// Trains the head; returns the ONNX model (descriptor graph + head) and
/// the validation top-1 per press of the descriptor alone and with the
/// head. Writes `config.json` and `metrics.jsonl` into `run`.
pub fn train(
    cfg: &SpectralConfig,
    run: &Path,
    cache_dir: &Path,
    threads: usize,
) -> Result<(Vec<u8>, f64, f64)> {
    cfg.data.check_frames()?;
    std::fs::create_dir_all(run).with_context(|| format!("cannot create {}", run.display()))?;
    crate::data::write_atomic(
        &run.join("config.json"),
        serde_json::to_string_pretty(cfg)?.as_bytes(),
    )?;
    let d = &cfg.data;
    let t0 = Instant::now();
    let train = cached_features(
        cache_dir,
        cfg,
        &d.people,
        &d.units,
        d.presses_per_textile,
        cfg.augs_per_frame,
        d.seed,
        threads,
        "rendering training spectra",
    )?;
    let val_index = cached_features(
        cache_dir,
        cfg,
        &d.people[..1],
        &d.units[..1],
        2,
        0,
        d.seed ^ 0xA11D,
        threads,
        "rendering validation index",
    )?;
    let val_q = cached_features(
        cache_dir,
        cfg,
        &[d.val_person],
        &[d.val_unit],
        d.val_presses.max(1),
        0,
        d.seed ^ 0xBEEF,
        threads,
        "rendering validation queries",
    )?;
    let dim = train.dim;
    eprintln!(
        "{} training spectra, rendered in {:.0} s",
        train.class.len(),
        t0.elapsed().as_secs_f64()
    );
    // Inputs scaled to unit variance per band (over the training rows).
    let n = train.class.len();
    let scale: Vec<f32> = (0..dim)
        .map(|j| {
            let m = (0..n).map(|i| train.rows[i * dim + j]).sum::<f32>() / n as f32;
            let v = (0..n)
                .map(|i| (train.rows[i * dim + j] - m).powi(2))
                .sum::<f32>()
                / n as f32;
            1.0 / v.sqrt().max(1e-3)
        })
        .collect();
    // The descriptor alone on the validation split.
    let norm = |rows: &[f32]| {
        let mut v = rows.to_vec();
        telextiles_graphs::knn::normalize_rows(&mut v, dim);
        v
    };
    let base = press_top1(
        &norm(&val_index.rows),
        &val_index.class,
        &norm(&val_q.rows),
        &val_q.press,
        &val_q.class,
        dim,
    );
    eprintln!(
        "validation top-1 per press, descriptor alone: {:.1}%",
        100.0 * base
    );
    let groups = PressGroups::new(&train.class, &train.press);
    // The training textiles' attributes, standardised (attribute
    // objective only).
    let attrs: Vec<Vec<f32>> = if cfg.attr_weight > 0.0 {
        let sim = telextiles_sim::Simulator::with_options(d.catalogue, d.generator)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let raw: Vec<Vec<f32>> = sim
            .catalogue()
            .training()
            .take(groups.classes())
            .map(|t| t.attributes.to_vec().to_vec())
            .collect();
        let k = raw.first().map_or(0, Vec::len);
        let mean: Vec<f32> = (0..k)
            .map(|j| raw.iter().map(|r| r[j]).sum::<f32>() / raw.len() as f32)
            .collect();
        let sd: Vec<f32> = (0..k)
            .map(|j| {
                (raw.iter().map(|r| (r[j] - mean[j]).powi(2)).sum::<f32>() / raw.len() as f32)
                    .sqrt()
                    .max(1e-6)
            })
            .collect();
        raw.iter()
            .map(|r| (0..k).map(|j| (r[j] - mean[j]) / sd[j]).collect())
            .collect()
    } else {
        Vec::new()
    };
    let n_attr = attrs.first().map_or(0, Vec::len);
    let device = Device::flex().autodiff();
    device.seed(d.seed);
    let mut head = Head::new(dim, cfg.hidden, cfg.out, n_attr, &device);
    let mut optim: ModuleOptimizer = AdamWConfig::new().with_weight_decay(1e-4).init();
    let mut rng = ChaCha8Rng::seed_from_u64(d.seed ^ 0x5E);
    let mut best: (f64, Option<Head>) = (f64::NEG_INFINITY, None);
    let mut metrics = String::new();
    let eval_every = (cfg.steps / 20).max(1);
    let bar = telextiles_progress::Progress::new("training the head", cfg.steps as u64, "steps");
    let mut losses = Vec::new();
    for step in 1..=cfg.steps {
        let p = step as f64 / cfg.steps as f64;
        let lr = cfg.lr * 0.5 * (1.0 + (std::f64::consts::PI * p).cos());
        let mut x = Vec::new();
        let mut labels = Vec::new();
        groups.batch(
            cfg.classes_per_batch,
            cfg.views_per_class,
            &mut rng,
            |_, i, c| {
                x.extend(
                    train.rows[i * dim..(i + 1) * dim]
                        .iter()
                        .zip(&scale)
                        .map(|(a, s)| a * s),
                );
                labels.push(c);
            },
        );
        let b = labels.len();
        let e = head.forward(Tensor::<2>::from_data(
            TensorData::new(x, [b, dim]),
            &device,
        ));
        let z = l2_normalize(e);
        let mut loss = supcon_loss(z.clone(), &labels, cfg.temperature, &device);
        if let Some(a) = &head.attr {
            let target: Vec<f32> = labels
                .iter()
                .flat_map(|&c| attrs[c as usize].iter().copied())
                .collect();
            let t = Tensor::<2>::from_data(TensorData::new(target, [b, n_attr]), &device);
            let mse = (a.forward(z) - t).powf_scalar(2.0).mean();
            loss = loss + mse.mul_scalar(cfg.attr_weight);
        }
        let lv: f32 = loss
            .clone()
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))?[0];
        ensure!(lv.is_finite(), "loss is {lv} at step {step}");
        losses.push(lv as f64);
        let grads = GradientsParams::from_grads(loss.backward(), &head);
        head = optim.step(lr, head, grads);
        bar.inc(1);
        if step % eval_every == 0 || step == cfg.steps {
            let h = head.valid();
            let (ie, od) = embed_rows(&h, &scale, &val_index.rows, dim)?;
            let (qe, _) = embed_rows(&h, &scale, &val_q.rows, dim)?;
            let acc = press_top1(&ie, &val_index.class, &qe, &val_q.press, &val_q.class, od);
            let recent = &losses[losses.len().saturating_sub(eval_every)..];
            let loss = recent.iter().sum::<f64>() / recent.len().max(1) as f64;
            bar.println(&format!(
                "step {step}: loss {loss:.3}, validation top-1 per press {:.1}% (descriptor alone {:.1}%)",
                100.0 * acc,
                100.0 * base
            ));
            metrics.push_str(&format!(
                "{{\"step\":{step},\"loss\":{loss},\"lr\":{lr},\"val_press_top1\":{acc},\"descriptor_val_press_top1\":{base}}}\n"
            ));
            crate::data::write_atomic(&run.join("metrics.jsonl"), metrics.as_bytes())?;
            if acc > best.0 {
                best = (acc, Some(h));
            }
        }
    }
    bar.finish();
    let head = best.1.context("no validation ran")?;
    let mlp = head.to_mlp(scale.clone())?;
    let hash = run_hash(cfg)?;
    let bytes = descriptor_with_head(&cfg.spec(), &mlp, &hash)?;
    // The exported graph must give what the head gives in burn.
    let mut enc = OrtEncoder::from_bytes(&bytes, 1)?;
    let base_graph = descriptor_model(&cfg.spec())?;
    let mut front = OrtEncoder::from_bytes(&base_graph, 1)?;
    // Probe at the deployment crop with a press never seen.
    let sim = telextiles_sim::Simulator::with_options(d.catalogue, d.generator)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let (_, plans) = make_plans(&sim, d, &[d.val_person], &[d.val_unit], 1, 123);
    let spec = cfg.spec();
    let frames = render_press(&sim, d, &plans[0], spec.crop, spec.input as usize)?;
    let mut x = Vec::new();
    for f in &frames {
        x.extend_from_slice(f);
    }
    let got = enc.embed(&x)?;
    let spectra = front.embed(&x)?;
    let (want, od) = embed_rows(&head, &scale, &spectra, dim)?;
    let mut got = got;
    telextiles_graphs::knn::normalize_rows(&mut got, od);
    let diff = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    ensure!(diff < 1e-3, "ONNX Runtime and burn differ by {diff}");
    Ok((bytes, base, best.0))
}
