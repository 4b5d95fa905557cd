//! The contrastive encoder's recipe (issue 20): what the trained encoder
//! sees is exactly the deployment contract with the reference subtracted
//! (`telextiles.background = subtract`: `normalise(frame) -
//! normalise(reference)`, the same functions the daemon's contract is tested
//! equal to), and what it is taught is which presses are the same fabric.
//!
//! * **Data**: presses rendered by the simulator for this purpose
//!   ([`render_set`]): every training textile pressed by the training people
//!   on many sensor units (never the held-out units 4 and 5 of the
//!   evaluation protocol, nor the validation unit), at a rotation drawn
//!   uniformly over the full circle (the simulator renders the rotated
//!   fabric; no image is rotated, so the LED colour code stays physical),
//!   jig and hand-held, and frames taken from the ramp as well as the hold.
//! * **Positives**: every batch holds `classes_per_batch` textiles with
//!   `views_per_class` frames each, every frame from a *different* press
//!   (other person, unit, rotation, swatch): supervised contrastive learning
//!   (SupCon). The maker knows what it pressed.
//! * **Augmentations** that a sensor produces ([`augment_diff`]): a
//!   per-channel gain (LED intensity of a unit), a contact scale (force,
//!   soft fabrics), partial contact (a ramp across the window), a blur (gel
//!   thickness, focus), spatially correlated noise, a small translation and
//!   a small stretch (±5 %, fabric stretch). No zoom beyond that (it changes
//!   yarn spacing), no arbitrary-angle image rotation, no flips.
//! * **Validation**: a person and a unit neither trained on nor reported
//!   (person 7 on unit 15); the checkpoint kept is the one with the best
//!   validation top-1 per press.
//! * **Model**: a small, fully convolutional ResNet on the 192-px crop
//!   (resized to the input size), global average pooling, L2-normalised.

use anyhow::{ensure, Context, Result};
use burn::module::Module;
use burn::optim::{AdamWConfig, GradientsParams, ModuleOptimizer};
use burn::tensor::activation::log_softmax;
use burn::tensor::{Device, Tensor, TensorData};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::Instant;

use crate::model::{l2_normalize, ArchConfig, Encoder};
use telextiles_graphs::preprocess::{DIGIT_MEAN, DIGIT_STD};
use telextiles_sensing::preprocess::{PreprocessSpec, Preprocessor};

/// Recipe and schedule of a run (saved next to the checkpoint).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SupConConfig {
    /// Encoder architecture (its input size is the network input).
    pub arch: ArchConfig,
    /// Deployment centre crop (px of the frame).
    pub crop: u32,
    /// Simulator catalogue and texture generator of the training presses.
    pub catalogue: u32,
    pub generator: u32,
    /// Training people.
    pub people: Vec<u32>,
    /// Training sensor units.
    pub units: Vec<u32>,
    /// Presses per training textile.
    pub presses_per_textile: usize,
    /// Frames kept per press (spread over ramp and hold).
    pub frames_per_press: usize,
    /// How many of them come from the contact ramp: 1 (the recipe so far) is
    /// one frame late in the ramp; more are spread over the whole ramp, from
    /// the first frame in contact, where the first tenth of a second of a
    /// press lies. Left out of the saved settings at 1, so earlier runs keep
    /// their hashes.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub ramp_frames: usize,
    /// Share of hand-held presses.
    pub handheld_share: f32,
    /// Only the first N training textiles (quick runs).
    pub max_textiles: Option<usize>,
    /// Validation person and unit (neither trained on nor reported).
    pub val_person: u32,
    pub val_unit: u32,
    /// Validation presses per textile (each a query of the validation top-1).
    #[serde(default = "one")]
    pub val_presses: usize,
    /// Batch: textiles x frames (each frame from another press).
    pub classes_per_batch: usize,
    pub views_per_class: usize,
    /// SupCon temperature.
    pub temperature: f32,
    /// AdamW learning rate (cosine decay after a linear warm-up).
    pub lr: f64,
    pub weight_decay: f32,
    pub warmup_steps: usize,
    /// Steps in total, and a validation every this many.
    pub steps: usize,
    pub eval_every: usize,
    /// Stop at this wall time (seconds; the budget of the recipe is 2 h on
    /// 2 cores), keeping the best checkpoint so far.
    pub max_seconds: Option<f64>,
    pub seed: u64,
}

impl SupConConfig {
    /// The recipe's defaults for an architecture.
    pub fn new(arch: ArchConfig) -> Self {
        SupConConfig {
            arch,
            crop: 192,
            catalogue: 2,
            generator: 1,
            people: (0..7).collect(),
            // Units 4 and 5 are the protocol's held-out units, 15 the
            // validation unit.
            units: vec![0, 1, 2, 3, 6, 7, 8, 9, 10, 11, 12, 13, 14],
            presses_per_textile: 14,
            frames_per_press: 4,
            ramp_frames: 1,
            handheld_share: 0.5,
            max_textiles: None,
            val_person: 7,
            val_unit: 15,
            val_presses: 1,
            classes_per_batch: 16,
            views_per_class: 4,
            temperature: 0.1,
            lr: 2e-3,
            weight_decay: 1e-4,
            warmup_steps: 100,
            steps: 3000,
            eval_every: 250,
            max_seconds: None,
            seed: 0,
        }
    }

    /// Side of the stored frames: the crop plus a margin for translation,
    /// at the network's scale.
    pub fn stored_side(&self) -> usize {
        self.arch.input + self.margin() * 2
    }

    /// Translation margin in network pixels (8 frame px).
    pub fn margin(&self) -> usize {
        ((8 * self.arch.input) as f32 / self.crop as f32)
            .round()
            .max(1.0) as usize
    }

    /// Frame px of the stored crop.
    fn stored_crop(&self) -> u32 {
        (self.stored_side() as f32 * self.crop as f32 / self.arch.input as f32).round() as u32
    }

    /// The frames kept per press add up: the ramp's are among them, and at
    /// least one is left for the hold.
    pub fn check_frames(&self) -> Result<()> {
        ensure!(
            self.ramp_frames >= 1 && self.ramp_frames < self.frames_per_press,
            "--ramp-frames {} must be at least 1 and below --frames-per-press {} (the rest are hold frames)",
            self.ramp_frames,
            self.frames_per_press
        );
        Ok(())
    }
}

fn is_one(v: &usize) -> bool {
    *v == 1
}

fn one() -> usize {
    1
}

/// Rendered frames: each the normalised frame minus the normalised
/// reference, CHW f32, `side` x `side`, with its textile and press.
pub struct DiffSet {
    pub side: usize,
    pub data: Vec<f32>,
    pub class: Vec<u32>,
    pub press: Vec<u32>,
    pub classes: Vec<String>,
}

impl DiffSet {
    pub fn len(&self) -> usize {
        self.class.len()
    }

    pub fn is_empty(&self) -> bool {
        self.class.is_empty()
    }

    /// Presses in the set (frames carry their press's index, in order).
    pub fn presses(&self) -> usize {
        self.press.last().map_or(0, |p| *p as usize + 1)
    }

    pub fn image(&self, i: usize) -> &[f32] {
        let n = 3 * self.side * self.side;
        &self.data[i * n..(i + 1) * n]
    }
}

/// The deployment input of one frame, computed by the daemon's own code
/// (`telextiles_sensing::preprocess::Preprocessor`, the one
/// implementation of the contract): centre crop, resize, normalise, minus
/// the reference treated the same way.
pub fn diff_input(
    frame: &image::RgbImage,
    reference: &image::RgbImage,
    crop: u32,
    size: u32,
) -> Result<Vec<f32>> {
    let pre = Preprocessor::new(PreprocessSpec {
        crop,
        size,
        mean: DIGIT_MEAN,
        std: DIGIT_STD,
    })
    .map_err(|e| anyhow::anyhow!("{e}"))?;
    ensure!(
        frame.dimensions() == (240, 320) && reference.dimensions() == (240, 320),
        "frames must be 240x320"
    );
    let mut x = vec![0f32; pre.len()];
    pre.run(frame, &mut x);
    let mut r = vec![0f32; pre.len()];
    pre.run(reference, &mut r);
    for (v, r) in x.iter_mut().zip(&r) {
        *v -= r;
    }
    Ok(x)
}

/// A press to render: textile (class), person, unit, jig, rotation, seed.
#[derive(Clone, Debug)]
pub(crate) struct Plan {
    pub(crate) class: u32,
    textile: String,
    person: u32,
    unit: u32,
    jig: bool,
    rotation: f32,
    seed: u64,
}

/// Renders presses for training (or validation) with `threads` threads.
#[allow(clippy::too_many_arguments)]
pub fn render_set(
    cfg: &SupConConfig,
    people: &[u32],
    units: &[u32],
    presses_per_textile: usize,
    seed: u64,
    threads: usize,
    label: &str,
) -> Result<DiffSet> {
    let sim = telextiles_sim::Simulator::with_options(cfg.catalogue, cfg.generator)
        .map_err(|e| anyhow::anyhow!("simulator: {e}"))?;
    let (textiles, plans) = make_plans(&sim, cfg, people, units, presses_per_textile, seed);
    let side = cfg.stored_side();
    let crop = cfg.stored_crop();
    let per = 3 * side * side;
    let bar = telextiles_progress::Progress::new(label, plans.len() as u64, "presses");
    let next = std::sync::atomic::AtomicUsize::new(0);
    let results = std::sync::Mutex::new(Vec::new());
    let first_err = std::sync::Mutex::new(None::<anyhow::Error>);
    std::thread::scope(|s| {
        for _ in 0..threads.max(1) {
            s.spawn(|| loop {
                let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                if i >= plans.len() {
                    return;
                }
                let p = &plans[i];
                match render_press(&sim, cfg, p, crop, side) {
                    Ok(frames) => results
                        .lock()
                        .unwrap_or_else(|p| p.into_inner())
                        .push((i, p.class, frames)),
                    Err(e) => {
                        first_err
                            .lock()
                            .unwrap_or_else(|p| p.into_inner())
                            .get_or_insert(e);
                        return;
                    }
                }
                bar.inc(1);
            });
        }
    });
    bar.finish();
    if let Some(e) = first_err.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(e);
    }
    let mut results = results.into_inner().unwrap_or_else(|p| p.into_inner());
    results.sort_by_key(|r| r.0);
    let mut set = DiffSet {
        side,
        data: Vec::new(),
        class: Vec::new(),
        press: Vec::new(),
        classes: textiles,
    };
    for (i, class, frames) in results {
        for f in frames {
            debug_assert_eq!(f.len(), per);
            set.data.extend(f);
            set.class.push(class);
            set.press.push(i as u32);
        }
    }
    Ok(set)
}

/// The presses of a set: every training textile `presses_per_textile`
/// times, people in turn, a random unit of `units`, jig or hand-held, a
/// rotation drawn over the full circle.
pub(crate) fn make_plans(
    sim: &telextiles_sim::Simulator,
    cfg: &SupConConfig,
    people: &[u32],
    units: &[u32],
    presses_per_textile: usize,
    seed: u64,
) -> (Vec<String>, Vec<Plan>) {
    let mut textiles: Vec<String> = sim.catalogue().training().map(|t| t.id.clone()).collect();
    if let Some(n) = cfg.max_textiles {
        textiles.truncate(n);
    }
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut plans = Vec::new();
    for (c, t) in textiles.iter().enumerate() {
        for k in 0..presses_per_textile {
            plans.push(Plan {
                class: c as u32,
                textile: t.clone(),
                person: people[(k + c) % people.len()],
                unit: units[rng.gen_range(0..units.len())],
                jig: rng.gen::<f32>() >= cfg.handheld_share,
                rotation: rng.gen_range(-180.0..180.0),
                seed: seed.wrapping_mul(1_000_003) ^ (c as u64 * 1000 + k as u64),
            });
        }
    }
    (textiles, plans)
}

/// The kept frames of one press as deployment inputs (`crop` px at `side`).
pub(crate) fn render_press(
    sim: &telextiles_sim::Simulator,
    cfg: &SupConConfig,
    p: &Plan,
    crop: u32,
    side: usize,
) -> Result<Vec<Vec<f32>>> {
    let spec = telextiles_sim::PressSpec {
        person: p.person,
        sensor: p.unit,
        jig: p.jig,
        rotation_deg: Some(p.rotation),
        ..telextiles_sim::PressSpec::new(p.textile.clone(), p.seed)
    };
    let meta = sim
        .press_meta(&spec)
        .map_err(|e| anyhow::anyhow!("{}: {e}", p.textile))?;
    let n = meta.timestamps_us.len();
    let (contact, hold, release) = match meta.params {
        Some(q) => (
            q.contact_frame as usize,
            q.hold_frame as usize,
            q.release_frame.map_or(n, |r| r as usize).min(n),
        ),
        None => (0, 0, n),
    };
    let mut frames = ramp_frames(contact, hold, cfg.ramp_frames);
    frames.extend(crate::protocol::spread(
        hold,
        release.max(hold + 1),
        cfg.frames_per_press.saturating_sub(frames.len()),
    ));
    let reference = sim
        .background_for(&spec)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    frames
        .into_iter()
        .map(|i| {
            let f = sim
                .render_frame(&spec, i.min(n - 1))
                .map_err(|e| anyhow::anyhow!("{}: {e}", p.textile))?;
            diff_input(&f, &reference, crop, side as u32)
        })
        .collect()
}

/// The training frames taken from a press's contact ramp (`contact`: its
/// first frame in contact, `hold`: the first of the hold). One (the recipe
/// so far): a frame late in the ramp, 3 frames before the hold. More: `n`
/// frames spread over the whole ramp, the first of them the first frame in
/// contact, so the light touches of a press's first tenth of a second are
/// trained on too.
pub fn ramp_frames(contact: usize, hold: usize, n: usize) -> Vec<usize> {
    if n <= 1 {
        let ramp_lo = hold.saturating_sub(6);
        return vec![(ramp_lo + hold) / 2];
    }
    let lo = contact.min(hold.saturating_sub(1));
    let hi = hold.max(lo + 1);
    let mut v: Vec<usize> = (0..n).map(|i| lo + i * (hi - lo) / n).collect();
    v.dedup();
    v
}

/// One augmented view of a stored difference frame (`side` x `side`, CHW),
/// written as `size` x `size` CHW into `out`. Only what a sensor does to a
/// press: see the module docs.
pub fn augment_diff<R: Rng>(src: &[f32], side: usize, size: usize, rng: &mut R, out: &mut [f32]) {
    let n = size * size;
    debug_assert_eq!(out.len(), 3 * n);
    // Geometry: translation within the margin, ±5 % stretch per axis.
    let margin = (side - size) as f32 / 2.0;
    let (sx, sy) = (rng.gen_range(0.95..1.05f32), rng.gen_range(0.95..1.05f32));
    let (ox, oy) = (
        rng.gen_range(-margin..=margin) * 0.8,
        rng.gen_range(-margin..=margin) * 0.8,
    );
    let c = side as f32 / 2.0;
    let h = size as f32 / 2.0;
    let max = (side - 1) as f32;
    let plane = side * side;
    for v in 0..size {
        let y = ((v as f32 + 0.5 - h) * sy + c + oy - 0.5).clamp(0.0, max);
        let y0 = y.floor() as usize;
        let y1 = (y0 + 1).min(side - 1);
        let fy = y - y0 as f32;
        for u in 0..size {
            let x = ((u as f32 + 0.5 - h) * sx + c + ox - 0.5).clamp(0.0, max);
            let x0 = x.floor() as usize;
            let x1 = (x0 + 1).min(side - 1);
            let fx = x - x0 as f32;
            for ch in 0..3 {
                let p = &src[ch * plane..(ch + 1) * plane];
                let top = p[y0 * side + x0] * (1.0 - fx) + p[y0 * side + x1] * fx;
                let bot = p[y1 * side + x0] * (1.0 - fx) + p[y1 * side + x1] * fx;
                out[ch * n + v * size + u] = top * (1.0 - fy) + bot * fy;
            }
        }
    }
    // Blur (gel thickness, focus): a 3x3 binomial, sometimes.
    if rng.gen::<f32>() < 0.3 {
        let mut tmp = out.to_vec();
        for ch in 0..3 {
            blur3(
                &mut out[ch * n..(ch + 1) * n],
                &mut tmp[ch * n..(ch + 1) * n],
                size,
            );
        }
    }
    // Contact: strength (force, soft fabrics) and, sometimes, a partial
    // contact ramp across the window.
    let strength = rng.gen_range(0.5..1.3f32);
    let gains: [f32; 3] = std::array::from_fn(|_| strength * rng.gen_range(0.7..1.4f32));
    let partial = rng.gen::<f32>() < 0.3;
    let (dx, dy) = {
        let a = rng.gen_range(0.0..std::f32::consts::TAU);
        (a.cos(), a.sin())
    };
    let edge = rng.gen_range(-0.3..0.5f32);
    for v in 0..size {
        for u in 0..size {
            let m = if partial {
                let t = ((u as f32 / size as f32 - 0.5) * dx + (v as f32 / size as f32 - 0.5) * dy)
                    - edge;
                (t * 4.0 + 0.5).clamp(0.0, 1.0)
            } else {
                1.0
            };
            for (ch, g) in gains.iter().enumerate() {
                out[ch * n + v * size + u] *= g * m;
            }
        }
    }
    // Camera noise: white noise smoothed over 3x3 (demosaicing,
    // compression), correlated across channels, 0.5 to 2 DN.
    let sigma_dn = rng.gen_range(0.5..2.0f32);
    let mut noise: Vec<f32> = (0..n).map(|_| gauss(rng)).collect();
    let mut tmp = vec![0f32; n];
    blur3(&mut noise, &mut tmp, size);
    for (ch, std) in telextiles_graphs::preprocess::DIGIT_STD.iter().enumerate() {
        // Smoothing divides the std by about 2.7; channels share 70 % of it.
        let s = sigma_dn / 255.0 / std * 2.7;
        for i in 0..n {
            let own = gauss(rng) * 0.3;
            out[ch * n + i] += s * (0.7 * noise[i] + own / 2.7);
        }
    }
}

fn blur3(x: &mut [f32], tmp: &mut [f32], side: usize) {
    let k = [0.25f32, 0.5, 0.25];
    for v in 0..side {
        for u in 0..side {
            let mut s = 0.0;
            for (j, w) in k.iter().enumerate() {
                let uu = (u + j).saturating_sub(1).min(side - 1);
                s += w * x[v * side + uu];
            }
            tmp[v * side + u] = s;
        }
    }
    for v in 0..side {
        for u in 0..side {
            let mut s = 0.0;
            for (j, w) in k.iter().enumerate() {
                let vv = (v + j).saturating_sub(1).min(side - 1);
                s += w * tmp[vv * side + u];
            }
            x[v * side + u] = s;
        }
    }
}

fn gauss<R: Rng>(rng: &mut R) -> f32 {
    let u1: f32 = rng.gen_range(1e-7..1.0);
    let u2: f32 = rng.gen();
    (-2.0 * u1.ln()).sqrt() * (std::f32::consts::TAU * u2).cos()
}

/// The centre `size` x `size` of stored frames (no augmentation): what the
/// deployment preprocessing gives.
pub fn centre_of(src: &[f32], side: usize, size: usize) -> Vec<f32> {
    let m = (side - size) / 2;
    let mut out = Vec::with_capacity(3 * size * size);
    for ch in 0..3 {
        for v in 0..size {
            let row = ch * side * side + (v + m) * side + m;
            out.extend_from_slice(&src[row..row + size]);
        }
    }
    out
}

/// SupCon loss of L2-normalised embeddings `z` [N, D] with labels.
pub fn supcon_loss(z: Tensor<2>, labels: &[u32], temperature: f32, device: &Device) -> Tensor<1> {
    let n = labels.len();
    let sim = z.clone().matmul(z.transpose()).div_scalar(temperature);
    let mut self_mask = vec![0f32; n * n];
    let mut pos = vec![0f32; n * n];
    for i in 0..n {
        self_mask[i * n + i] = -1e4;
        let np = labels.iter().filter(|&&l| l == labels[i]).count() - 1;
        for j in 0..n {
            if i != j && labels[i] == labels[j] {
                pos[i * n + j] = 1.0 / (np.max(1) as f32 * n as f32);
            }
        }
    }
    let mask = Tensor::<2>::from_data(TensorData::new(self_mask, [n, n]), device);
    let pos = Tensor::<2>::from_data(TensorData::new(pos, [n, n]), device);
    let logp = log_softmax(sim + mask, 1);
    (logp * pos).sum().neg()
}

/// Embeds stored frames (their centre, no augmentation) with `enc`
/// (inference mode); L2-normalised rows.
pub fn embed(enc: &Encoder, set: &DiffSet, size: usize) -> Result<(Vec<f32>, usize)> {
    let device = Device::flex();
    let enc = enc.valid().to_device(&device);
    let mut out = Vec::new();
    let mut dim = 0;
    for start in (0..set.len()).step_by(64) {
        let end = (start + 64).min(set.len());
        let mut x = Vec::with_capacity((end - start) * 3 * size * size);
        for i in start..end {
            x.extend(centre_of(set.image(i), set.side, size));
        }
        let y = enc.forward(Tensor::<4>::from_data(
            TensorData::new(x, [end - start, 3, size, size]),
            &device,
        ));
        dim = y.dims()[1];
        out.extend(
            y.into_data()
                .try_to_vec::<f32>()
                .map_err(|e| anyhow::anyhow!("{e:?}"))?,
        );
    }
    telextiles_graphs::knn::normalize_rows(&mut out, dim.max(1));
    Ok((out, dim))
}

/// Top-1 per press of `queries` (mean of each press's frames; row `i`
/// belongs to press `press[i]` of class `class[i]`) against every row of
/// `index`, cosine nearest neighbour.
pub fn press_top1(
    index: &[f32],
    index_labels: &[u32],
    queries: &[f32],
    press: &[u32],
    class: &[u32],
    dim: usize,
) -> f64 {
    let mut presses: std::collections::BTreeMap<u32, (u32, Vec<f32>)> = Default::default();
    for (i, (&p, &c)) in press.iter().zip(class).enumerate() {
        let e = presses.entry(p).or_insert((c, vec![0f32; dim]));
        for (s, v) in e.1.iter_mut().zip(&queries[i * dim..(i + 1) * dim]) {
            *s += v;
        }
    }
    let mut right = 0;
    for (c, q) in presses.values() {
        let best = index
            .chunks_exact(dim)
            .zip(index_labels)
            .map(|(r, &l)| (r.iter().zip(q).map(|(a, b)| a * b).sum::<f32>(), l))
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .map(|x| x.1);
        right += usize::from(best == Some(*c));
    }
    right as f64 / presses.len().max(1) as f64
}

/// Rows of every class grouped by press (in press order): what a SupCon
/// batch draws its positives from.
pub struct PressGroups {
    by_class: Vec<Vec<Vec<usize>>>,
    nonempty: Vec<usize>,
}

impl PressGroups {
    /// Groups rows `i` by `class[i]` and `press[i]`.
    pub fn new(class: &[u32], press: &[u32]) -> PressGroups {
        let mut maps: Vec<std::collections::BTreeMap<u32, Vec<usize>>> = Vec::new();
        for (i, (&c, &p)) in class.iter().zip(press).enumerate() {
            let c = c as usize;
            if maps.len() <= c {
                maps.resize(c + 1, Default::default());
            }
            maps[c].entry(p).or_default().push(i);
        }
        let by_class: Vec<Vec<Vec<usize>>> = maps
            .into_iter()
            .map(|m| m.into_values().collect())
            .collect();
        let nonempty = (0..by_class.len())
            .filter(|&c| !by_class[c].is_empty())
            .collect();
        PressGroups { by_class, nonempty }
    }

    /// Number of classes (the highest class + 1).
    pub fn classes(&self) -> usize {
        self.by_class.len()
    }

    /// One batch: `classes` textiles drawn at random, `views` rows of each,
    /// every row from another press while the textile has enough; `f(rng,
    /// row, class)` is called for each, in batch order, with the same
    /// generator (augmentations draw from it in turn).
    pub fn batch<R: Rng>(
        &self,
        classes: usize,
        views: usize,
        rng: &mut R,
        mut f: impl FnMut(&mut R, usize, u32),
    ) {
        let picked: Vec<usize> = self
            .nonempty
            .choose_multiple(rng, classes.min(self.nonempty.len()))
            .copied()
            .collect();
        for c in picked {
            let chosen: Vec<&Vec<usize>> = self.by_class[c]
                .choose_multiple(rng, views.min(self.by_class[c].len()))
                .collect();
            for v in 0..views {
                let rows = chosen[v % chosen.len()];
                let i = rows[rng.gen_range(0..rows.len())];
                f(rng, i, c as u32);
            }
        }
    }
}

/// One line of `metrics.jsonl`.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct StepMetrics {
    pub step: usize,
    pub loss: f64,
    pub lr: f64,
    pub val_press_top1: f64,
    /// Validation query presses behind it.
    #[serde(default)]
    pub val_presses: usize,
    pub seconds: f64,
}

/// Trains with the recipe; writes `metrics.jsonl`, `config.json` and the
/// best checkpoint (`best.bpk`, by validation top-1 per press) into `run`.
/// Returns the best encoder and its validation top-1.
pub fn train(cfg: &SupConConfig, run: &Path, threads: usize) -> Result<(Encoder, f64)> {
    cfg.check_frames()?;
    ensure!(
        cfg.views_per_class >= 2 && cfg.classes_per_batch >= 2,
        "a batch needs at least 2 textiles with 2 views each"
    );
    ensure!(
        cfg.crop as usize >= cfg.arch.input,
        "the crop must be at least the input size"
    );
    std::fs::create_dir_all(run).with_context(|| format!("cannot create {}", run.display()))?;
    crate::data::write_atomic(
        &run.join("config.json"),
        serde_json::to_string_pretty(cfg)?.as_bytes(),
    )?;
    let t0 = Instant::now();
    let train_set = render_set(
        cfg,
        &cfg.people,
        &cfg.units,
        cfg.presses_per_textile,
        cfg.seed,
        threads,
        "rendering training presses",
    )?;
    let val_index = render_set(
        cfg,
        &cfg.people[..1],
        &cfg.units[..1],
        2,
        cfg.seed ^ 0xA11D,
        threads,
        "rendering validation index",
    )?;
    let val_q = render_set(
        cfg,
        &[cfg.val_person],
        &[cfg.val_unit],
        cfg.val_presses.max(1),
        cfg.seed ^ 0xBEEF,
        threads,
        "rendering validation queries",
    )?;
    eprintln!(
        "{} training frames of {} presses, {} validation presses; rendered in {:.0} s",
        train_set.len(),
        train_set.presses(),
        val_q.presses(),
        t0.elapsed().as_secs_f64()
    );
    let groups = PressGroups::new(&train_set.class, &train_set.press);
    let device = Device::flex().autodiff();
    device.seed(cfg.seed);
    let mut enc: Encoder = cfg.arch.init_encoder(&device);
    let mut optim: ModuleOptimizer = AdamWConfig::new()
        .with_weight_decay(cfg.weight_decay)
        .init();
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x5C);
    let s = cfg.arch.input;
    let per = 3 * s * s;
    let mut best = (f64::NEG_INFINITY, enc.valid());
    let mut metrics = String::new();
    let mut losses = Vec::new();
    let bar = telextiles_progress::Progress::new("training", cfg.steps as u64, "steps");
    let t_train = Instant::now();
    for step in 1..=cfg.steps {
        let lr = if step <= cfg.warmup_steps {
            cfg.lr * step as f64 / cfg.warmup_steps as f64
        } else {
            let p = (step - cfg.warmup_steps) as f64 / (cfg.steps - cfg.warmup_steps).max(1) as f64;
            cfg.lr * 0.5 * (1.0 + (std::f64::consts::PI * p).cos())
        };
        let mut labels = Vec::new();
        let mut x = vec![0f32; cfg.classes_per_batch * cfg.views_per_class * per];
        groups.batch(
            cfg.classes_per_batch,
            cfg.views_per_class,
            &mut rng,
            |rng, i, c| {
                let k = labels.len();
                augment_diff(
                    train_set.image(i),
                    train_set.side,
                    s,
                    rng,
                    &mut x[k * per..(k + 1) * per],
                );
                labels.push(c);
            },
        );
        x.truncate(labels.len() * per);
        let n = labels.len();
        let xt = Tensor::<4>::from_data(TensorData::new(x, [n, 3, s, s]), &device);
        let z = l2_normalize(enc.forward(xt));
        let loss = supcon_loss(z, &labels, cfg.temperature, &device);
        let lv: f32 = loss
            .clone()
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| anyhow::anyhow!("{e:?}"))?[0];
        ensure!(lv.is_finite(), "loss is {lv} at step {step}");
        losses.push(lv as f64);
        let grads = GradientsParams::from_grads(loss.backward(), &enc);
        enc = optim.step(lr, enc, grads);
        bar.inc(1);
        if step % cfg.eval_every == 0 || step == cfg.steps {
            let e = enc.valid();
            let (ie, dim) = embed(&e, &val_index, s)?;
            let (qe, _) = embed(&e, &val_q, s)?;
            let acc = press_top1(&ie, &val_index.class, &qe, &val_q.press, &val_q.class, dim);
            let recent = &losses[losses.len().saturating_sub(cfg.eval_every)..];
            let m = StepMetrics {
                step,
                loss: recent.iter().sum::<f64>() / recent.len().max(1) as f64,
                lr,
                val_press_top1: acc,
                val_presses: val_q.presses(),
                seconds: t_train.elapsed().as_secs_f64(),
            };
            bar.println(&format!(
                "step {step}: loss {:.3}, validation top-1 per press {:.1}% ({:.0} s)",
                m.loss,
                100.0 * acc,
                m.seconds
            ));
            metrics.push_str(&serde_json::to_string(&m)?);
            metrics.push('\n');
            crate::data::write_atomic(&run.join("metrics.jsonl"), metrics.as_bytes())?;
            if acc > best.0 {
                best = (acc, e.clone());
                let tmp = run.join("best.partial");
                e.clone()
                    .save_file(&tmp)
                    .map_err(|e| anyhow::anyhow!("{e:?}"))?;
                std::fs::rename(tmp.with_extension("partial.bpk"), run.join("best.bpk"))
                    .or_else(|_| std::fs::rename(&tmp, run.join("best.bpk")))
                    .context("cannot write best.bpk")?;
            }
            if cfg
                .max_seconds
                .is_some_and(|m| t0.elapsed().as_secs_f64() > m)
            {
                bar.println("time budget reached; keeping the best checkpoint");
                break;
            }
        }
    }
    bar.finish();
    Ok((best.1, best.0))
}

/// Loads `best.bpk` of a run.
pub fn load_best(run: &Path) -> Result<(Encoder, SupConConfig)> {
    let cfg: SupConConfig = serde_json::from_slice(
        &std::fs::read(run.join("config.json"))
            .with_context(|| format!("no config.json in {}", run.display()))?,
    )?;
    let device = Device::flex();
    let enc = cfg
        .arch
        .init_encoder(&device)
        .try_load_file(run.join("best.bpk"))
        .map_err(|e| anyhow::anyhow!("{}: {e:?}", run.display()))?;
    Ok((enc, cfg))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ramp_frames_keep_the_old_frame_at_one_and_cover_the_ramp_above() {
        // One: the recipe so far, 3 frames before the hold.
        assert_eq!(ramp_frames(20, 32, 1), vec![29]);
        assert_eq!(ramp_frames(0, 2, 1), vec![1]);
        // More: from the first frame in contact, spread over the ramp,
        // never reaching the hold.
        assert_eq!(ramp_frames(20, 32, 3), vec![20, 24, 28]);
        assert_eq!(ramp_frames(20, 26, 4), vec![20, 21, 23, 24]);
        // A ramp shorter than the frames asked for gives each frame once.
        assert_eq!(ramp_frames(20, 22, 4), vec![20, 21]);
        // A press with no ramp (or no timeline) still gives a frame.
        assert_eq!(ramp_frames(5, 5, 3), vec![4]);
        assert_eq!(ramp_frames(0, 0, 3), vec![0]);
        // The setting is left out of saved configs at 1 (earlier runs keep
        // their hashes) and recorded above.
        let mut c = SupConConfig::new(ArchConfig::parse("resnet-d1111-w16-s96").unwrap());
        assert!(!serde_json::to_string(&c).unwrap().contains("ramp_frames"));
        c.ramp_frames = 3;
        let j = serde_json::to_string(&c).unwrap();
        assert!(j.contains("\"ramp_frames\":3"));
        let back: SupConConfig = serde_json::from_str(&j).unwrap();
        assert_eq!(back.ramp_frames, 3);
        // The ramp's frames are among those kept, one left for the hold.
        c.frames_per_press = 6;
        assert!(c.check_frames().is_ok());
        for (ramp, kept) in [(4, 4), (6, 4), (0, 4)] {
            c.ramp_frames = ramp;
            c.frames_per_press = kept;
            let e = c.check_frames().unwrap_err().to_string();
            assert!(
                e.contains("--ramp-frames") && e.contains("--frames-per-press"),
                "{e}"
            );
        }
    }

    #[test]
    fn a_batch_takes_each_view_from_another_press_of_its_textile() {
        // 3 textiles: 4, 2 and 0 presses of 2 rows each (textile 2 has none
        // and is never drawn).
        let (mut class, mut press) = (Vec::new(), Vec::new());
        for (c, n) in [(0u32, 4u32), (1, 2)] {
            for p in 0..n {
                class.extend([c, c]);
                press.extend([c * 10 + p, c * 10 + p]);
            }
        }
        class.push(5);
        press.push(99);
        let g = PressGroups::new(&class, &press);
        assert_eq!(g.classes(), 6);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for _ in 0..20 {
            let mut got: Vec<(usize, u32)> = Vec::new();
            g.batch(2, 3, &mut rng, |_, i, c| got.push((i, c)));
            assert_eq!(got.len(), 6);
            for c in [0u32, 1, 5] {
                let rows: Vec<usize> = got.iter().filter(|x| x.1 == c).map(|x| x.0).collect();
                assert!(rows.iter().all(|&i| class[i] == c));
                let mut p: Vec<u32> = rows.iter().map(|&i| press[i]).collect();
                p.sort_unstable();
                p.dedup();
                // Textile 0 has 4 presses: 3 views, 3 presses; textile 1
                // has 2: both used; textile 5 has one.
                let want = match (c, rows.len()) {
                    (_, 0) => 0,
                    (0, _) => 3,
                    (1, _) => 2,
                    _ => 1,
                };
                assert_eq!(p.len(), want, "class {c}: {got:?}");
            }
        }
    }

    #[test]
    fn supcon_loss_prefers_embeddings_that_group_by_label() {
        let device = Device::flex();
        let labels = [0u32, 0, 1, 1];
        let grouped = Tensor::<2>::from_data(
            TensorData::new(vec![1.0f32, 0.0, 0.99, 0.14, 0.0, 1.0, 0.14, 0.99], [4, 2]),
            &device,
        );
        let mixed = Tensor::<2>::from_data(
            TensorData::new(vec![1.0f32, 0.0, 0.0, 1.0, 0.99, 0.14, 0.14, 0.99], [4, 2]),
            &device,
        );
        let v = |t: Tensor<1>| t.into_data().try_to_vec::<f32>().unwrap()[0];
        let a = v(supcon_loss(l2_normalize(grouped), &labels, 0.1, &device));
        let b = v(supcon_loss(l2_normalize(mixed), &labels, 0.1, &device));
        assert!(a.is_finite() && b.is_finite());
        assert!(a < 0.1 && b > 5.0, "grouped {a}, mixed {b}");
    }

    #[test]
    fn augmentation_keeps_the_scale_and_centre_is_the_deployment_view() {
        let side = 40;
        let size = 32;
        let src: Vec<f32> = (0..3 * side * side)
            .map(|i| ((i * 37) % 17) as f32 / 17.0 - 0.5)
            .collect();
        let c = centre_of(&src, side, size);
        assert_eq!(c.len(), 3 * size * size);
        assert_eq!(c[0], src[4 * side + 4]);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let mut out = vec![0f32; 3 * size * size];
        augment_diff(&src, side, size, &mut rng, &mut out);
        assert!(out.iter().all(|v| v.is_finite()));
        let rms = |v: &[f32]| (v.iter().map(|x| x * x).sum::<f32>() / v.len() as f32).sqrt();
        let r = rms(&out) / rms(&c);
        assert!((0.2..2.0).contains(&r), "rms ratio {r}");
    }

    #[test]
    fn stored_frames_centre_is_the_deployment_crop_exactly() {
        // The stored 208-px crop at 104 px, cut to its centre 96, equals
        // the deployment input of the 192-px crop at 96 px bit for bit.
        let cfg = SupConConfig::new(ArchConfig::parse("resnet-d1111-w16-s96").unwrap());
        assert_eq!((cfg.stored_side(), cfg.stored_crop()), (104, 208));
        let frame = image::RgbImage::from_fn(240, 320, |x, y| {
            image::Rgb([
                (x * 7 % 251) as u8,
                (y * 3 % 251) as u8,
                ((x * y) % 200) as u8,
            ])
        });
        let reference = image::RgbImage::from_fn(240, 320, |x, y| {
            image::Rgb([(x % 50) as u8, 90, (y % 70) as u8])
        });
        let stored = diff_input(&frame, &reference, 208, 104).unwrap();
        let direct = diff_input(&frame, &reference, 192, 96).unwrap();
        assert_eq!(centre_of(&stored, 104, 96), direct);
    }
}
