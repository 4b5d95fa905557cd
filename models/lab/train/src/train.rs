//! MoCo v2-style contrastive training with burn: query encoder + projection
//! head trained with SGD, momentum (EMA) key encoder, a queue of negatives and
//! InfoNCE with a temperature. The contrastive instance is a *press*: the
//! positive pair is two augmented frames of the same press, so the
//! near-identical frames of one press are never each other's negatives
//! (the queue holds fewer keys than there are presses). Batch norm statistics are computed in
//! `bn_splits` groups, with the key batch shuffled across groups (the
//! single-device form of MoCo's shuffling BN).

use anyhow::{bail, ensure, Context, Result};
use burn::module::{Module, ModuleMapper, ModuleVisitor, Param};
use burn::optim::decay::WeightDecayConfig;
use burn::optim::momentum::MomentumConfig;
use burn::optim::{GradientsParams, ModuleOptimizer, SgdConfig};
use burn::tensor::activation::log_softmax;
use burn::tensor::{Device, Tensor, TensorData};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::augment::{augment_into, AugConfig};
use crate::data::{write_atomic, ImageKind, ImageSet};
use crate::model::{l2_normalize, ArchConfig, Encoder, MocoNet};
use telextiles_graphs::knn::{embedding_std, knn_score, normalize_rows, KnnScore};
use telextiles_graphs::preprocess::normalize_into;

/// Hyper-parameters of a training run (saved with every checkpoint).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TrainConfig {
    /// Encoder architecture.
    pub arch: ArchConfig,
    /// Output size of the projection head.
    pub proj_dim: usize,
    /// Images per step (each gives a query and a key view).
    pub batch: usize,
    /// Number of negatives in the queue.
    pub queue: usize,
    /// InfoNCE temperature.
    pub temperature: f32,
    /// EMA factor of the key encoder.
    pub key_momentum: f32,
    /// Base learning rate (cosine-decayed over the run).
    pub lr: f64,
    /// SGD momentum.
    pub sgd_momentum: f64,
    /// L2 weight decay.
    pub weight_decay: f32,
    /// Epochs to train.
    pub epochs: usize,
    /// Steps per epoch; `None` = one pass over the training presses.
    pub steps_per_epoch: Option<usize>,
    /// Seed of initialisation, shuffling and augmentation.
    pub seed: u64,
    /// Augmentation strengths.
    pub aug: AugConfig,
    /// Batch-norm groups (shuffled BN emulation); 1 disables.
    pub bn_splits: usize,
}

impl TrainConfig {
    /// Defaults of the paper / MoCo v2 for a given architecture.
    pub fn new(arch: ArchConfig) -> Self {
        TrainConfig {
            arch,
            proj_dim: 128,
            batch: 64,
            queue: 512,
            temperature: 0.2,
            key_momentum: 0.99,
            lr: 0.03,
            sgd_momentum: 0.9,
            weight_decay: 1e-4,
            epochs: 10,
            steps_per_epoch: None,
            seed: 0,
            aug: AugConfig::default(),
            bn_splits: 2,
        }
    }
}

/// Metrics of one epoch (one line of `metrics.jsonl`).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct EpochMetrics {
    /// Epoch number, from 1.
    pub epoch: usize,
    /// Mean InfoNCE loss over the epoch.
    pub loss: f64,
    /// Loss of the first 10% of the epoch's steps.
    pub loss_first: f64,
    /// Loss of the last 10% of the epoch's steps.
    pub loss_last: f64,
    /// Learning rate at the end of the epoch.
    pub lr: f64,
    /// Std of L2-normalised held-out embeddings.
    pub emb_std: f64,
    /// kNN top-1 (k=1), paper split within held-out presses.
    pub knn_within: f64,
    /// kNN top-1 (k=1), index from one held-out person, queries from another.
    pub knn_cross: f64,
    /// Mean seconds per training step.
    pub step_s: f64,
    /// Wall time of the epoch in seconds (training + evaluation).
    pub epoch_s: f64,
}

struct Collect(Vec<Tensor<1>>);
impl ModuleVisitor for Collect {
    fn visit_float<const D: usize>(&mut self, p: &Param<Tensor<D>>) {
        self.0.push(p.val().detach().flatten(0, D - 1));
    }
}

struct Ema {
    src: std::vec::IntoIter<Tensor<1>>,
    m: f32,
}
impl ModuleMapper for Ema {
    fn map_float<const D: usize>(&mut self, p: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let q = self
            .src
            .next()
            .expect("key and query have the same structure");
        let m = self.m;
        p.map(|k| {
            let shape = k.shape();
            let q: Tensor<D> = q.reshape(shape);
            if m == 0.0 {
                q
            } else {
                k.detach().mul_scalar(m).add(q.mul_scalar(1.0 - m))
            }
            .detach()
        })
    }
}

/// key <- m * key + (1 - m) * query (m = 0 copies).
fn ema_update(key: MocoNet, query: &MocoNet, m: f32) -> MocoNet {
    let mut c = Collect(Vec::new());
    query.visit(&mut c);
    let mut e = Ema {
        src: c.0.into_iter(),
        m,
    };
    key.map(&mut e).no_grad()
}

/// Training state.
pub struct Trainer {
    /// Configuration.
    pub cfg: TrainConfig,
    device: Device,
    query: MocoNet,
    key: MocoNet,
    optim: ModuleOptimizer,
    queue: Vec<f32>,
    queue_ptr: usize,
    /// Completed epochs.
    pub epoch: usize,
    /// Completed steps.
    pub step: usize,
}

#[derive(Serialize, Deserialize)]
struct State {
    epoch: usize,
    step: usize,
    queue_ptr: usize,
    config: TrainConfig,
}

fn sgd(cfg: &TrainConfig) -> ModuleOptimizer {
    SgdConfig::new()
        .with_momentum(Some(MomentumConfig {
            momentum: cfg.sgd_momentum,
            dampening: 0.0,
            nesterov: false,
        }))
        .with_weight_decay(Some(WeightDecayConfig {
            penalty: cfg.weight_decay,
        }))
        .init()
}

impl Trainer {
    /// Fresh model from the config's seed.
    pub fn new(cfg: TrainConfig) -> Self {
        let device = Device::flex().autodiff();
        device.seed(cfg.seed);
        let query = MocoNet::new(&cfg.arch, cfg.proj_dim, &device);
        let key = ema_update(MocoNet::new(&cfg.arch, cfg.proj_dim, &device), &query, 0.0);
        let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5155_4555);
        let mut queue: Vec<f32> = (0..cfg.queue * cfg.proj_dim)
            .map(|_| rng.gen_range(-1.0f32..1.0))
            .collect();
        normalize_rows(&mut queue, cfg.proj_dim);
        let optim = sgd(&cfg);
        Trainer {
            cfg,
            device,
            query,
            key,
            optim,
            queue,
            queue_ptr: 0,
            epoch: 0,
            step: 0,
        }
    }

    /// Inference copy of the query encoder (what gets exported).
    pub fn encoder(&self) -> Encoder {
        self.query.encoder.valid()
    }

    /// Total steps of the run (`train_presses` = contrastive instances).
    pub fn total_steps(&self, train_presses: usize) -> usize {
        self.cfg.epochs * self.steps_per_epoch(train_presses)
    }

    /// Steps in one epoch: one pass over the training presses.
    pub fn steps_per_epoch(&self, train_presses: usize) -> usize {
        self.cfg
            .steps_per_epoch
            .unwrap_or((train_presses / self.cfg.batch).max(1))
    }

    /// Cosine-decayed learning rate at step `t` of `total`.
    pub fn lr_at(&self, t: usize, total: usize) -> f64 {
        let p = t as f64 / total.max(1) as f64;
        self.cfg.lr * 0.5 * (1.0 + (std::f64::consts::PI * p.min(1.0)).cos())
    }

    fn forward_split(net: &MocoNet, x: Tensor<4>, splits: usize) -> Tensor<2> {
        let n = x.dims()[0];
        let splits = splits.clamp(1, n);
        if splits == 1 {
            return net.forward(x);
        }
        let per = n.div_ceil(splits);
        let outs: Vec<Tensor<2>> = (0..n)
            .step_by(per)
            .map(|start| net.forward(x.clone().narrow(0, start, per.min(n - start))))
            .collect();
        Tensor::cat(outs, 0)
    }

    /// One MoCo step on `n` query views and `n` key views (NCHW normalised).
    /// Returns the loss before the update.
    pub fn train_step(
        &mut self,
        xq: Vec<f32>,
        xk: Vec<f32>,
        n: usize,
        lr: f64,
        rng: &mut ChaCha8Rng,
    ) -> Result<f32> {
        let s = self.cfg.arch.input;
        let per = 3 * s * s;
        ensure!(
            xq.len() == n * per && xk.len() == n * per,
            "batch has the wrong size"
        );
        let d = self.cfg.proj_dim;
        // Keys: shuffle across BN groups, encode without gradients, unshuffle.
        let mut perm: Vec<usize> = (0..n).collect();
        perm.shuffle(rng);
        let mut xk_perm = Vec::with_capacity(xk.len());
        for &p in &perm {
            xk_perm.extend_from_slice(&xk[p * per..(p + 1) * per]);
        }
        let xk_t = Tensor::<4>::from_data(TensorData::new(xk_perm, [n, 3, s, s]), &self.device);
        let k_perm =
            l2_normalize(Self::forward_split(&self.key, xk_t, self.cfg.bn_splits)).detach();
        let k_perm: Vec<f32> = k_perm
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let mut k = vec![0f32; n * d];
        for (i, &p) in perm.iter().enumerate() {
            k[p * d..(p + 1) * d].copy_from_slice(&k_perm[i * d..(i + 1) * d]);
        }
        // Queries with gradients.
        let xq_t = Tensor::<4>::from_data(TensorData::new(xq, [n, 3, s, s]), &self.device);
        let q = l2_normalize(Self::forward_split(&self.query, xq_t, self.cfg.bn_splits));
        let k_t = Tensor::<2>::from_data(TensorData::new(k.clone(), [n, d]), &self.device);
        let queue_t = Tensor::<2>::from_data(
            TensorData::new(self.queue.clone(), [self.cfg.queue, d]),
            &self.device,
        );
        let l_pos = (q.clone() * k_t).sum_dim(1);
        let l_neg = q.matmul(queue_t.transpose());
        let logits = Tensor::cat(vec![l_pos, l_neg], 1).div_scalar(self.cfg.temperature);
        let loss = log_softmax(logits, 1).narrow(1, 0, 1).mean().neg();
        let loss_val: f32 = loss
            .clone()
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))?[0];
        if !loss_val.is_finite() {
            bail!("loss is {loss_val} at step {}", self.step);
        }
        let grads = loss.backward();
        let grads = GradientsParams::from_grads(grads, &self.query);
        self.query = self.optim.step(lr, self.query.clone(), grads);
        self.key = ema_update(self.key.clone(), &self.query, self.cfg.key_momentum);
        // Enqueue the keys.
        for row in k.chunks_exact(d) {
            let at = self.queue_ptr * d;
            self.queue[at..at + d].copy_from_slice(row);
            self.queue_ptr = (self.queue_ptr + 1) % self.cfg.queue;
        }
        self.step += 1;
        Ok(loss_val)
    }

    /// InfoNCE loss with in-batch negatives of fixed views (query network in
    /// inference mode for both views, no update): a deterministic measure of
    /// how well views of the same image match, used to check that training
    /// lowers the loss.
    pub fn eval_loss(&self, xq: Vec<f32>, xk: Vec<f32>, n: usize) -> Result<f32> {
        let s = self.cfg.arch.input;
        let device = Device::flex();
        let net = self.query.valid().to_device(&device);
        let q = l2_normalize(net.forward(Tensor::<4>::from_data(
            TensorData::new(xq, [n, 3, s, s]),
            &device,
        )));
        let k = l2_normalize(net.forward(Tensor::<4>::from_data(
            TensorData::new(xk, [n, 3, s, s]),
            &device,
        )));
        let logits = q.matmul(k.transpose()).div_scalar(self.cfg.temperature);
        let logp: Vec<f32> = log_softmax(logits, 1)
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        Ok(-(0..n).map(|i| logp[i * n + i]).sum::<f32>() / n as f32)
    }

    /// Save a checkpoint into `dir` (created; files replaced atomically).
    pub fn save(&self, dir: &Path) -> Result<()> {
        std::fs::create_dir_all(dir)?;
        let tmp = dir.join(".partial");
        std::fs::create_dir_all(&tmp)?;
        // `valid()` synchronises batch-norm running statistics (a plain
        // clone would record stale ones).
        self.query
            .valid()
            .save_file(tmp.join("query.bpk"))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        self.key
            .valid()
            .save_file(tmp.join("key.bpk"))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        self.optim
            .save(tmp.join("optim.bpk"))
            .map_err(|e| anyhow::anyhow!("{e:?}"))?;
        let q: Vec<u8> = self.queue.iter().flat_map(|v| v.to_le_bytes()).collect();
        write_atomic(&tmp.join("queue.f32"), &q)?;
        let st = State {
            epoch: self.epoch,
            step: self.step,
            queue_ptr: self.queue_ptr,
            config: self.cfg.clone(),
        };
        write_atomic(
            &tmp.join("state.json"),
            serde_json::to_string_pretty(&st)?.as_bytes(),
        )?;
        for f in [
            "query.bpk",
            "key.bpk",
            "optim.bpk",
            "queue.f32",
            "state.json",
        ] {
            std::fs::rename(tmp.join(f), dir.join(f))?;
        }
        std::fs::remove_dir(&tmp).ok();
        Ok(())
    }

    /// Load a checkpoint written by [`Trainer::save`].
    pub fn load(dir: &Path) -> Result<Self> {
        let st: State = serde_json::from_slice(
            &std::fs::read(dir.join("state.json"))
                .with_context(|| format!("no checkpoint in {}", dir.display()))?,
        )
        .context("corrupt state.json")?;
        let mut t = Trainer::new(st.config);
        let err =
            |e: burn::store::RecordError| anyhow::anyhow!("checkpoint {}: {e:?}", dir.display());
        t.query = t
            .query
            .clone()
            .try_load_file(dir.join("query.bpk"))
            .map_err(err)?;
        t.key = t
            .key
            .clone()
            .try_load_file(dir.join("key.bpk"))
            .map_err(err)?
            .no_grad();
        t.optim = sgd(&t.cfg).load(dir.join("optim.bpk")).map_err(err)?;
        let q = std::fs::read(dir.join("queue.f32"))?;
        ensure!(q.len() == t.queue.len() * 4, "queue.f32 has the wrong size");
        t.queue = q
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes(b.try_into().expect("chunks of 4 bytes")))
            .collect();
        t.queue_ptr = st.queue_ptr;
        t.epoch = st.epoch;
        t.step = st.step;
        Ok(t)
    }
}

/// Embed an [`ImageKind::Input`] set with a burn encoder (inference mode).
/// Returns L2-normalised rows.
pub fn embed_set(encoder: &Encoder, set: &ImageSet, batch: usize) -> Result<Vec<f32>> {
    ensure!(
        set.kind == ImageKind::Input,
        "embedding needs an input-size image set"
    );
    let device = Device::flex();
    let enc = encoder.valid().to_device(&device);
    let s = set.side;
    let mut out = Vec::new();
    let mut dim = 0;
    for start in (0..set.len()).step_by(batch.max(1)) {
        let end = (start + batch).min(set.len());
        let mut x = Vec::with_capacity((end - start) * 3 * s * s);
        for i in start..end {
            normalize_into(set.image(i), s, &mut x);
        }
        let t = Tensor::<4>::from_data(TensorData::new(x, [end - start, 3, s, s]), &device);
        let y = enc.forward(t);
        dim = y.dims()[1];
        out.extend(
            y.into_data()
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?,
        );
    }
    normalize_rows(&mut out, dim.max(1));
    Ok(out)
}

/// Select rows of an embedding matrix.
pub fn rows(emb: &[f32], dim: usize, idx: &[usize]) -> Vec<f32> {
    idx.iter()
        .flat_map(|&i| emb[i * dim..(i + 1) * dim].iter().copied())
        .collect()
}

/// Paper split inside each press: frames < 120 are the index, the rest queries.
pub const INDEX_FRAMES: u32 = 120;

/// kNN of queries (frames >= 120) against index frames (< 120), both chosen by filters.
pub fn knn_between(
    set: &ImageSet,
    emb: &[f32],
    dim: usize,
    index_filter: impl Fn(&crate::data::FrameMeta) -> bool,
    query_filter: impl Fn(&crate::data::FrameMeta) -> bool,
) -> KnnScore {
    let ii: Vec<usize> = (0..set.len())
        .filter(|&i| set.items[i].frame < INDEX_FRAMES && index_filter(&set.items[i]))
        .collect();
    let qi: Vec<usize> = (0..set.len())
        .filter(|&i| set.items[i].frame >= INDEX_FRAMES && query_filter(&set.items[i]))
        .collect();
    let il: Vec<u32> = ii.iter().map(|&i| set.items[i].class).collect();
    let ql: Vec<u32> = qi.iter().map(|&i| set.items[i].class).collect();
    knn_score(
        &rows(emb, dim, &ii),
        &il,
        &rows(emb, dim, &qi),
        &ql,
        dim,
        20,
        0.07,
    )
}

/// Held-out metrics for the epoch log: (std, within-press top-1, cross-person top-1).
pub fn heldout_metrics(encoder: &Encoder, eval: &ImageSet) -> Result<(f64, f64, f64)> {
    let emb = embed_set(encoder, eval, 128)?;
    let dim = emb.len() / eval.len().max(1);
    let std = embedding_std(&emb, dim);
    let mut people: Vec<u32> = eval.items.iter().map(|m| m.person).collect();
    people.sort_unstable();
    people.dedup();
    let (mut within, mut wn) = (0.0, 0usize);
    let (mut cross, mut cn) = (0.0, 0usize);
    for &a in &people {
        let s = knn_between(eval, &emb, dim, |m| m.person == a, |m| m.person == a);
        within += s.top1_k1 * s.queries as f64;
        wn += s.queries;
        for &b in &people {
            if a != b {
                let s = knn_between(eval, &emb, dim, |m| m.person == a, |m| m.person == b);
                cross += s.top1_k1 * s.queries as f64;
                cn += s.queries;
            }
        }
    }
    Ok((
        std,
        within / wn.max(1) as f64,
        if cn > 0 { cross / cn as f64 } else { f64::NAN },
    ))
}

/// Canvas indices grouped by press (the contrastive instances).
pub fn presses(train: &ImageSet) -> Vec<Vec<usize>> {
    let mut map: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
    for (i, m) in train.items.iter().enumerate() {
        map.entry(m.press).or_default().push(i);
    }
    map.into_values().collect()
}

/// Fill a batch of views: the query view from canvas `a`, the key view from
/// canvas `b` of each pair (two frames of the same press, or the same frame).
pub fn make_views(
    train: &ImageSet,
    pairs: &[(usize, usize)],
    cfg: &TrainConfig,
    rng: &mut ChaCha8Rng,
) -> (Vec<f32>, Vec<f32>) {
    let s = cfg.arch.input;
    let crop = train.crop as f32;
    let mut xq = Vec::with_capacity(pairs.len() * 3 * s * s);
    let mut xk = Vec::with_capacity(pairs.len() * 3 * s * s);
    for &(a, b) in pairs {
        augment_into(train.image(a), train.side, s, crop, &cfg.aug, rng, &mut xq);
        augment_into(train.image(b), train.side, s, crop, &cfg.aug, rng, &mut xk);
    }
    (xq, xk)
}

/// Where a run keeps its files.
pub struct RunDir(pub PathBuf);

impl RunDir {
    /// Directory of the latest checkpoint, if any.
    pub fn latest(&self) -> Option<PathBuf> {
        let name = std::fs::read_to_string(self.0.join("ckpt").join("latest")).ok()?;
        let p = self.0.join("ckpt").join(name.trim());
        p.join("state.json").exists().then_some(p)
    }
}

/// Options of the training loop that do not change the result.
pub struct LoopOptions {
    /// Print a progress line every this many steps (0 = never).
    pub progress_every: usize,
    /// Stop after this many steps in this process (for tests/benchmarks).
    pub max_steps: Option<usize>,
    /// Keep at most this many epoch checkpoints.
    pub keep: usize,
    /// Held-out metrics every this many epochs (and at the last epoch).
    pub eval_every: usize,
}

/// Train for the configured epochs, checkpointing into `run/ckpt/epoch-NNNN`
/// after every epoch and appending to `run/metrics.jsonl`.
/// Returns the per-step losses of this process.
pub fn train_loop(
    trainer: &mut Trainer,
    train: &ImageSet,
    eval: Option<&ImageSet>,
    run: &RunDir,
    opts: &LoopOptions,
) -> Result<Vec<f32>> {
    ensure!(
        train.kind == ImageKind::Canvas,
        "training needs a canvas image set"
    );
    let groups = presses(train);
    ensure!(
        groups.len() >= trainer.cfg.batch,
        "fewer training presses ({}) than the batch size {}",
        groups.len(),
        trainer.cfg.batch
    );
    std::fs::create_dir_all(run.0.join("ckpt"))?;
    let spe = trainer.steps_per_epoch(groups.len());
    let total = trainer.total_steps(groups.len());
    let mut losses = Vec::new();
    let dim = trainer.cfg.arch.embedding_dim();
    while trainer.epoch < trainer.cfg.epochs {
        let epoch = trainer.epoch + 1;
        let t0 = Instant::now();
        let mut rng = ChaCha8Rng::seed_from_u64(
            trainer
                .cfg
                .seed
                .wrapping_mul(1_000_003)
                .wrapping_add(epoch as u64),
        );
        let mut order: Vec<usize> = (0..groups.len()).collect();
        order.shuffle(&mut rng);
        let mut ep_losses = Vec::with_capacity(spe);
        let mut step_time = 0.0;
        let first_step_in_epoch = trainer.step.saturating_sub((epoch - 1) * spe).min(spe);
        for st in first_step_in_epoch..spe {
            if let Some(m) = opts.max_steps {
                if losses.len() >= m {
                    return Ok(losses);
                }
            }
            let b = trainer.cfg.batch;
            let pairs: Vec<(usize, usize)> = (0..b)
                .map(|j| {
                    let g = &groups[order[(st * b + j) % order.len()]];
                    (g[rng.gen_range(0..g.len())], g[rng.gen_range(0..g.len())])
                })
                .collect();
            let ts = Instant::now();
            let (xq, xk) = make_views(train, &pairs, &trainer.cfg, &mut rng);
            let lr = trainer.lr_at(trainer.step, total);
            let loss = trainer.train_step(xq, xk, b, lr, &mut rng)?;
            step_time += ts.elapsed().as_secs_f64();
            losses.push(loss);
            ep_losses.push(loss as f64);
            if opts.progress_every > 0 && (st + 1) % opts.progress_every == 0 {
                let done = ep_losses.len() as f64;
                let per = step_time / done;
                eprint!(
                    "\repoch {epoch}/{} step {}/{spe} loss {loss:.4} lr {lr:.4} {:.2}s/step eta(epoch) {:.0}s   ",
                    trainer.cfg.epochs,
                    st + 1,
                    per,
                    per * (spe - st - 1) as f64
                );
            }
        }
        trainer.epoch = epoch;
        let n = ep_losses.len().max(1);
        let tenth = (n / 10).max(1);
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        let due = epoch.is_multiple_of(opts.eval_every.max(1)) || epoch == trainer.cfg.epochs;
        let (emb_std, knn_within, knn_cross) = match eval {
            Some(e) if due => heldout_metrics(&trainer.encoder(), e)?,
            _ => (f64::NAN, f64::NAN, f64::NAN),
        };
        let m = EpochMetrics {
            epoch,
            loss: mean(&ep_losses),
            loss_first: mean(&ep_losses[..tenth.min(ep_losses.len())]),
            loss_last: mean(&ep_losses[ep_losses.len().saturating_sub(tenth)..]),
            lr: trainer.lr_at(trainer.step, total),
            emb_std,
            knn_within,
            knn_cross,
            step_s: step_time / n as f64,
            epoch_s: t0.elapsed().as_secs_f64(),
        };
        if opts.progress_every > 0 {
            eprintln!();
        }
        let floor = 0.5 / (dim as f64).sqrt();
        println!(
            "epoch {epoch}/{}: loss {:.4} (first {:.4} last {:.4}) emb_std {:.4}{} kNN top-1 within-press {:.2}% cross-person {:.2}% | {:.2}s/step, epoch {:.0}s",
            trainer.cfg.epochs,
            m.loss,
            m.loss_first,
            m.loss_last,
            m.emb_std,
            if m.emb_std < floor { format!(" WARNING: below 0.5/sqrt(d)={floor:.4}, collapse?") } else { String::new() },
            100.0 * m.knn_within,
            100.0 * m.knn_cross,
            m.step_s,
            m.epoch_s
        );
        let name = format!("epoch-{epoch:04}");
        trainer.save(&run.0.join("ckpt").join(&name))?;
        write_atomic(&run.0.join("ckpt").join("latest"), name.as_bytes())?;
        let mut log = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(run.0.join("metrics.jsonl"))?;
        use std::io::Write;
        writeln!(log, "{}", serde_json::to_string(&m)?)?;
        if epoch > opts.keep {
            let old = run
                .0
                .join("ckpt")
                .join(format!("epoch-{:04}", epoch - opts.keep));
            std::fs::remove_dir_all(old).ok();
        }
    }
    Ok(losses)
}
