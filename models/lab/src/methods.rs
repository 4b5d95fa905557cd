//! Speed against accuracy, measured in one run on the same held-out presses
//! (issue "Speed vs accuracy chart"): classical descriptors and ONNX models
//! (trained encoders, descriptor graphs, their int8 versions), each timed
//! per frame and scored by kNN top-1 per frame, per press (the mean of a
//! press's frame embeddings) and against the number of frames aggregated
//! (time to a decision at 60 fps).
//!
//! Protocol: the across-people case of `docs/evaluation.md`: the index holds
//! the training people's index frames, the queries are every frame of the
//! held-out people's presses (their index and query frames; none of it was
//! seen in training). Every method gets its own view (centre crop, input
//! size) of the same cached frames ([`crate::protocol::view_set`]).

use anyhow::{Context, Result};
use serde::Serialize;
use std::collections::HashMap;
use std::time::Instant;

use crate::baselines::Baseline;
use crate::bench::{median, quantile};
use crate::data::ImageSet;
use crate::knn::{knn_score, normalize_rows};
use crate::onnx::OrtEncoder;
use crate::preprocess::normalize_into;
use crate::protocol::{view_set, Sets};

/// The frame budget of a 60 fps DIGIT, ms.
pub const FRAME_BUDGET_MS: f64 = 1000.0 / 60.0;

/// A method on the chart.
pub enum Method {
    /// A classical descriptor computed in Rust on the `crop` x `crop`
    /// centre square at native resolution (LBP, which has no ONNX graph).
    Rust {
        /// The descriptor.
        base: Baseline,
        /// Centre crop (px).
        crop: u32,
    },
    /// An ONNX model run through ONNX Runtime as the daemon runs it: a
    /// trained encoder, a descriptor graph ([`crate::graph`]), or an int8
    /// version of either.
    Onnx {
        /// Name in tables and charts.
        name: String,
        /// The model file.
        bytes: Vec<u8>,
        /// `telextiles.crop`.
        crop: u32,
        /// `telextiles.input_size`.
        input: u32,
        /// `telextiles.arch`.
        arch: String,
        /// `telextiles.background = subtract`: the input is the normalised
        /// frame minus the normalised no-contact reference.
        subtract: bool,
    },
}

impl Method {
    /// An ONNX model; crop and input size come from its metadata.
    pub fn onnx(name: impl Into<String>, bytes: Vec<u8>) -> Result<Method> {
        let name = name.into();
        let enc = OrtEncoder::from_bytes(&bytes, 1).with_context(|| format!("model {name}"))?;
        let crop: u32 = enc
            .meta
            .get("telextiles.crop")
            .context("model metadata lacks telextiles.crop")?
            .parse()
            .context("telextiles.crop is not a number")?;
        let arch = enc.meta.get("telextiles.arch").cloned().unwrap_or_default();
        let subtract = enc
            .subtracts_background()
            .with_context(|| format!("model {name}"))?;
        Ok(Method::Onnx {
            name,
            bytes,
            crop,
            input: enc.input_size as u32,
            arch,
            subtract,
        })
    }

    /// Name in tables and charts.
    pub fn name(&self) -> String {
        match self {
            Method::Rust { base, crop } => {
                let kind = Baseline {
                    bgsub: false,
                    ..*base
                }
                .name();
                format!("{kind}-c{crop}{}", if base.bgsub { " -bg" } else { "" })
            }
            Method::Onnx { name, .. } => name.clone(),
        }
    }

    /// (crop, input size) of the method's view of a frame.
    pub fn view(&self) -> (u32, u32) {
        match self {
            Method::Rust { crop, .. } => (*crop, *crop),
            Method::Onnx { crop, input, .. } => (*crop, *input),
        }
    }

    /// Where it runs: "ort" or "rust".
    pub fn runtime(&self) -> &'static str {
        match self {
            Method::Rust { .. } => "rust",
            Method::Onnx { .. } => "ort",
        }
    }

    /// Whether it needs the sensor's no-contact reference.
    pub fn needs_background(&self) -> bool {
        match self {
            Method::Rust { base, .. } => base.bgsub,
            Method::Onnx { subtract, .. } => *subtract,
        }
    }
}

/// A method ready to embed frames (an ONNX Runtime session where needed).
pub struct Embedder<'a> {
    method: &'a Method,
    enc: Option<OrtEncoder>,
}

impl<'a> Embedder<'a> {
    /// Open `m` with `threads` intra-op threads.
    pub fn new(m: &'a Method, threads: usize) -> Result<Self> {
        let enc = match m {
            Method::Onnx { bytes, name, .. } => Some(
                OrtEncoder::from_bytes(bytes, threads).with_context(|| format!("model {name}"))?,
            ),
            Method::Rust { .. } => None,
        };
        Ok(Embedder { method: m, enc })
    }

    /// Embeds every image of `set` (already in the method's view);
    /// `background(sensor)` gives the reference in the same view. Returns
    /// L2-normalised rows and their length.
    pub fn embed<'b>(
        &mut self,
        set: &ImageSet,
        background: impl Fn(u32) -> Option<&'b [u8]>,
    ) -> Result<(Vec<f32>, usize)> {
        let (crop, input) = self.method.view();
        anyhow::ensure!(
            set.side == input as usize && set.crop == crop,
            "{}: frames are a {}-px view of a {}-px crop, the method needs {input} of {crop}",
            self.method.name(),
            set.side,
            set.crop
        );
        let reference = |i: usize| -> Result<Option<&'b [u8]>> {
            if !self.method.needs_background() {
                return Ok(None);
            }
            let s = set.items[i].sensor;
            background(s).map(Some).with_context(|| {
                format!("{}: no reference frame of sensor {s}", self.method.name())
            })
        };
        match (&mut self.enc, self.method) {
            (Some(enc), _) => {
                let side = set.side;
                let mut out = Vec::with_capacity(set.len() * enc.dim);
                let mut x = Vec::new();
                for start in (0..set.len()).step_by(64) {
                    let end = (start + 64).min(set.len());
                    x.clear();
                    for i in start..end {
                        input_into(set.image(i), reference(i)?, side, &mut x);
                    }
                    out.extend(enc.embed(&x)?);
                }
                normalize_rows(&mut out, enc.dim);
                Ok((out, enc.dim))
            }
            (None, Method::Rust { base, .. }) => {
                let mut out = Vec::new();
                let mut dim = 0;
                for i in 0..set.len() {
                    let f = base.features(set.image(i), set.side, set.side, reference(i)?);
                    dim = f.len();
                    out.extend(f);
                }
                Ok((out, dim))
            }
            (None, Method::Onnx { .. }) => unreachable!("ONNX methods have a session"),
        }
    }
}

pub use telextiles_graphs::preprocess::input_into;

/// One method's figures.
#[derive(Clone, Debug, Serialize)]
pub struct MethodResult {
    pub name: String,
    /// "ort" or "rust".
    pub runtime: String,
    /// Centre crop and input size.
    pub crop: u32,
    pub input: u32,
    /// Descriptor or embedding length.
    pub dim: usize,
    /// Model file size (ONNX methods).
    pub model_bytes: Option<usize>,
    /// Per-frame time, batch 1: (threads, p50 ms, p95 ms). Rust
    /// descriptors are single-threaded and timed once.
    pub latency: Vec<(usize, f64, f64)>,
    /// kNN top-1 (k = 1) per frame.
    pub frame_top1: f64,
    /// kNN top-1 of the mean embedding of each press's frames.
    pub press_top1: f64,
    /// The same presses decided as the daemon decides: the press's mean
    /// against each textile's centroid ([`centroids`]; `index build`
    /// keeps centroids, and the decider searches them).
    #[serde(default)]
    pub press_top1_centroid: f64,
    /// (frames aggregated, top-1): the mean of a press's first n cached
    /// frames in capture order (9 frames spread over the press; the
    /// time-to-decision curve from consecutive frames is
    /// [`crate::decision_curve::decision_curve`]).
    pub by_frames: Vec<(usize, f64)>,
    pub queries: usize,
    pub presses: usize,
    /// Frames (index and queries) whose embedding has a NaN or infinity.
    #[serde(default)]
    pub nonfinite_frames: usize,
    /// Per-press top-1 of groups of queries against the same index:
    /// held-out people on training units, on held-out units, and
    /// hand-held presses.
    #[serde(default)]
    pub groups: Vec<GroupScore>,
}

/// Rows of an embedding matrix with a NaN or infinity.
pub fn nonfinite_rows(e: &[f32], dim: usize) -> usize {
    e.chunks_exact(dim.max(1))
        .filter(|r| r.iter().any(|v| !v.is_finite()))
        .count()
}

impl MethodResult {
    /// Median ms per frame on one thread.
    pub fn ms(&self) -> f64 {
        self.latency.first().map_or(f64::NAN, |l| l.1)
    }
}

/// Median and p95 milliseconds of `f` over `runs` calls, after `runs / 10`
/// warm-up calls.
fn time_runs(runs: usize, mut f: impl FnMut() -> Result<()>) -> Result<(f64, f64)> {
    let mut t = Vec::with_capacity(runs);
    for i in 0..runs + runs / 10 {
        let t0 = Instant::now();
        f()?;
        if i >= runs / 10 {
            t.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    Ok((median(&t), quantile(&t, 0.95)))
}

/// Per-frame time of `m` on one image of `set` (in its view), batch 1:
/// (threads, p50 ms, p95 ms). ONNX models are timed with their
/// preprocessing (normalisation), Rust descriptors from the u8 crop.
pub fn time_method(
    m: &Method,
    set: &ImageSet,
    bg: Option<&[u8]>,
    threads: &[usize],
    runs: usize,
) -> Result<Vec<(usize, f64, f64)>> {
    let img = set.image(0);
    match m {
        Method::Rust { base, .. } => {
            let (p50, p95) = time_runs(runs, || {
                std::hint::black_box(base.features(img, set.side, set.side, bg));
                Ok(())
            })?;
            Ok(vec![(1, p50, p95)])
        }
        Method::Onnx {
            bytes, subtract, ..
        } => threads
            .iter()
            .map(|&th| {
                let mut enc = OrtEncoder::from_bytes(bytes, th)?;
                let mut x = Vec::new();
                // The reference is normalised once, as the daemon does.
                let mut rn = Vec::new();
                if let (true, Some(r)) = (*subtract, bg) {
                    normalize_into(r, set.side, &mut rn);
                }
                let (p50, p95) = time_runs(runs, || {
                    x.clear();
                    normalize_into(img, set.side, &mut x);
                    for (v, r) in x.iter_mut().zip(&rn) {
                        *v -= r;
                    }
                    std::hint::black_box(enc.embed(&x)?);
                    Ok(())
                })?;
                Ok((th, p50, p95))
            })
            .collect(),
    }
}

/// kNN top-1 with k = 1 ([`knn_score`]).
pub fn top1(index: &[f32], labels: &[u32], q: &[f32], qlabels: &[u32], dim: usize) -> f64 {
    if qlabels.is_empty() {
        return f64::NAN;
    }
    knn_score(index, labels, q, qlabels, dim, 1, 0.07).top1_k1
}

/// The evaluation frames as one method sees them.
pub struct View {
    /// The training people's index frames.
    pub train_index: ImageSet,
    /// The held-out people's frames (training textiles).
    pub heldout: ImageSet,
    /// The held-out people's presses of the unseen textiles.
    pub unseen: ImageSet,
    /// The first held-out person's hand-held presses (training textiles).
    pub handheld: ImageSet,
    /// The sensors' no-contact references.
    pub backgrounds: ImageSet,
}

/// The evaluation frames in every view a method asks for, made once.
pub struct Views<'a> {
    sets: &'a Sets,
    cache: HashMap<(u32, u32), View>,
}

impl<'a> Views<'a> {
    /// Views of `sets` (at [`crate::protocol::BASE_SIDE`]).
    pub fn new(sets: &'a Sets) -> Self {
        Views {
            sets,
            cache: HashMap::new(),
        }
    }

    /// The frames in the given view.
    pub fn get(&mut self, crop: u32, input: u32) -> Result<&View> {
        if !self.cache.contains_key(&(crop, input)) {
            let v = View {
                train_index: view_set(&self.sets.train_index, crop, input)?,
                heldout: view_set(&self.sets.heldout, crop, input)?,
                unseen: view_set(&self.sets.unseen, crop, input)?,
                handheld: view_set(&self.sets.handheld, crop, input)?,
                backgrounds: view_set(&self.sets.backgrounds, crop, input)?,
            };
            self.cache.insert((crop, input), v);
        }
        Ok(&self.cache[&(crop, input)])
    }
}

/// The reference frame of `sensor` in a set of references.
pub fn background_of(bgs: &ImageSet, sensor: u32) -> Option<&[u8]> {
    let i = bgs.items.iter().position(|m| m.sensor == sensor)?;
    Some(bgs.image(i))
}

/// Scores `m` on the across-people protocol: index from the training
/// people's frames (before 120), queries from the held-out people.
pub fn evaluate(
    m: &Method,
    views: &mut Views,
    threads: &[usize],
    runs: usize,
) -> Result<MethodResult> {
    let (crop, input) = m.view();
    let v = views.get(crop, input)?;
    let (train_index, heldout, bgs) = (&v.train_index, &v.heldout, &v.backgrounds);
    let mut emb = Embedder::new(m, threads.iter().copied().max().unwrap_or(1))?;
    let (ie, dim) = emb.embed(train_index, |s| background_of(bgs, s))?;
    let idx: Vec<usize> = (0..train_index.len())
        .filter(|&i| train_index.items[i].frame < crate::train::INDEX_FRAMES)
        .collect();
    let index = crate::train::rows(&ie, dim, &idx);
    let labels: Vec<u32> = idx.iter().map(|&i| train_index.items[i].class).collect();
    let (qe, _) = emb.embed(heldout, |s| background_of(bgs, s))?;
    let qlabels: Vec<u32> = heldout.items.iter().map(|x| x.class).collect();
    let frame_top1 = top1(&index, &labels, &qe, &qlabels, dim);
    // Presses: frames in capture order.
    let mut presses: std::collections::BTreeMap<(u32, u32, u32), Vec<usize>> = Default::default();
    for (i, it) in heldout.items.iter().enumerate() {
        presses
            .entry((it.person, it.press, it.class))
            .or_default()
            .push(i);
    }
    for v in presses.values_mut() {
        v.sort_by_key(|&i| heldout.items[i].frame);
    }
    let longest = presses.values().map(Vec::len).max().unwrap_or(0);
    let mut by_frames = Vec::new();
    for n in 1..=longest {
        let mut q = Vec::new();
        let mut ql = Vec::new();
        for (&(_, _, class), frames) in &presses {
            q.extend(mean_rows(&qe, dim, &frames[..n.min(frames.len())]));
            ql.push(class);
        }
        normalize_rows(&mut q, dim);
        by_frames.push((n, top1(&index, &labels, &q, &ql, dim)));
    }
    let press_top1 = by_frames.last().map_or(f64::NAN, |x| x.1);
    // The daemon's index: one centroid per textile.
    let (cindex, clabels) = centroids(&index, &labels, dim);
    let press_top1_centroid = {
        let (q, ql) = press_means(&qe, dim, &presses, |k| k.2);
        top1(&cindex, &clabels, &q, &ql, dim)
    };
    let centroid = (cindex.as_slice(), clabels.as_slice());
    // The same index against groups of queries: held-out people on a
    // sensor unit the training people used, on units nobody trained on,
    // and hand-held presses.
    let train_units: std::collections::BTreeSet<u32> =
        train_index.items.iter().map(|it| it.sensor).collect();
    let mut groups = vec![
        group_score(
            "held-out people, training units",
            (&index, &labels),
            centroid,
            &qe,
            dim,
            heldout,
            |it| train_units.contains(&it.sensor),
        ),
        group_score(
            "held-out people, held-out units",
            (&index, &labels),
            centroid,
            &qe,
            dim,
            heldout,
            |it| !train_units.contains(&it.sensor),
        ),
    ];
    if !v.handheld.is_empty() {
        let (he, _) = emb.embed(&v.handheld, |s| background_of(bgs, s))?;
        groups.push(group_score(
            "hand-held queries, jig index",
            (&index, &labels),
            centroid,
            &he,
            dim,
            &v.handheld,
            |_| true,
        ));
    }
    groups.retain(|g| g.presses > 0);
    let nonfinite_frames = nonfinite_rows(&ie, dim) + nonfinite_rows(&qe, dim);
    if nonfinite_frames > 0 {
        eprintln!(
            "warning: {} gives non-finite embeddings on {nonfinite_frames} frames",
            m.name()
        );
    }
    let bg0 = heldout
        .items
        .first()
        .and_then(|it| background_of(bgs, it.sensor));
    Ok(MethodResult {
        name: m.name(),
        runtime: m.runtime().into(),
        crop,
        input,
        dim,
        model_bytes: match m {
            Method::Onnx { bytes, .. } => Some(bytes.len()),
            Method::Rust { .. } => None,
        },
        latency: time_method(m, heldout, bg0, threads, runs)?,
        frame_top1,
        press_top1,
        press_top1_centroid,
        by_frames,
        queries: qlabels.len(),
        presses: presses.len(),
        nonfinite_frames,
        groups,
    })
}

/// Per-press top-1 of one group of queries (see [`MethodResult::groups`]).
#[derive(Clone, Debug, Serialize)]
pub struct GroupScore {
    /// What the group is.
    pub name: String,
    /// Query presses in it.
    pub presses: usize,
    /// kNN top-1 of the mean embedding of each press's frames.
    pub press_top1: f64,
    /// The same presses against each textile's centroid, as the daemon
    /// decides ([`MethodResult::press_top1_centroid`]).
    #[serde(default)]
    pub press_top1_centroid: f64,
}

/// Top-1 per press of the presses of `set` whose frames pass `keep`
/// (embeddings `qe`, rows in `set` order) against the index frames
/// `(rows, labels)` and against their textiles' `centroid`s.
fn group_score(
    name: &str,
    (index, labels): (&[f32], &[u32]),
    centroid: (&[f32], &[u32]),
    qe: &[f32],
    dim: usize,
    set: &ImageSet,
    keep: impl Fn(&crate::data::FrameMeta) -> bool,
) -> GroupScore {
    let mut presses: std::collections::BTreeMap<(u32, u32, u32), Vec<usize>> = Default::default();
    for (i, it) in set.items.iter().enumerate() {
        if keep(it) {
            presses
                .entry((it.person, it.press, it.class))
                .or_default()
                .push(i);
        }
    }
    let (q, ql) = press_means(qe, dim, &presses, |k| k.2);
    GroupScore {
        name: name.to_string(),
        presses: presses.len(),
        press_top1: top1(index, labels, &q, &ql, dim),
        press_top1_centroid: top1(centroid.0, centroid.1, &q, &ql, dim),
    }
}

/// One centroid per label, built by the daemon's own in-memory index
/// (`telextiles_sensing::decide::FlatIndex`, the same normalised mean of
/// normalised rows as `index build`). Returns the rows, in label order,
/// and their labels (none for an empty index).
pub fn centroids(index: &[f32], labels: &[u32], dim: usize) -> (Vec<f32>, Vec<u32>) {
    let mut by: std::collections::BTreeMap<u32, Vec<Vec<f32>>> = Default::default();
    for (row, &l) in index.chunks_exact(dim.max(1)).zip(labels) {
        by.entry(l).or_default().push(row.to_vec());
    }
    let out: Vec<u32> = by.keys().copied().collect();
    let entries: Vec<(String, Vec<Vec<f32>>)> = by
        .into_iter()
        .map(|(l, rows)| (l.to_string(), rows))
        .collect();
    match telextiles_sensing::decide::FlatIndex::from_embeddings(&entries) {
        Ok(flat) => (
            (0..out.len())
                .flat_map(|i| flat.centroid(i).to_vec())
                .collect(),
            out,
        ),
        Err(_) => (Vec::new(), Vec::new()),
    }
}

/// The normalised mean embedding of each press (`presses`: its frames'
/// rows in `qe`, by a key that names the press), and the press's class
/// (`class_of` its key).
pub(crate) fn press_means<K: Ord>(
    qe: &[f32],
    dim: usize,
    presses: &std::collections::BTreeMap<K, Vec<usize>>,
    class_of: impl Fn(&K) -> u32,
) -> (Vec<f32>, Vec<u32>) {
    let mut q = Vec::new();
    let mut ql = Vec::new();
    for (key, frames) in presses {
        q.extend(mean_rows(qe, dim, frames));
        ql.push(class_of(key));
    }
    normalize_rows(&mut q, dim);
    (q, ql)
}

/// Sum of the given rows (normalise afterwards for a mean direction).
pub fn mean_rows(e: &[f32], dim: usize, rows: &[usize]) -> Vec<f32> {
    weighted_sum_rows(e, dim, rows, |_| 1.0)
}

/// The sum of rows `rows` of `e`, row `i` times `weight(i)` (the daemon
/// weights each frame by its contact depth; normalise afterwards).
pub fn weighted_sum_rows(
    e: &[f32],
    dim: usize,
    rows: &[usize],
    weight: impl Fn(usize) -> f32,
) -> Vec<f32> {
    let mut m = vec![0f32; dim];
    for &i in rows {
        let w = weight(i);
        for (s, v) in m.iter_mut().zip(&e[i * dim..(i + 1) * dim]) {
            *s += w * v;
        }
    }
    m
}

/// Indices of the Pareto-optimal results (no other is both faster, by the
/// one-thread median, and at least as accurate per press).
pub fn pareto(results: &[MethodResult]) -> Vec<usize> {
    (0..results.len())
        .filter(|&i| {
            let (li, ai) = (results[i].ms(), results[i].press_top1);
            !results.iter().enumerate().any(|(j, o)| {
                j != i && o.ms() <= li && o.press_top1 >= ai && (o.ms() < li || o.press_top1 > ai)
            })
        })
        .collect()
}

/// The knee of the Pareto frontier: among the frontier methods that fit the
/// 60 fps frame budget on one thread, the one that maximises accuracy minus
/// the share of the frame budget it uses (`press_top1 - ms / 16.7`). That is
/// where the frontier's slope falls to one percentage point of accuracy per
/// one percent of the frame budget (the tangent of slope 100 % per 16.7 ms):
/// every step before it buys more accuracy than budget, every step after it
/// less. The two axes the chart is judged by, accuracy (0-100 %) and the
/// frame budget (0-16.7 ms), are weighed one for one.
pub fn knee(results: &[MethodResult]) -> Option<usize> {
    knee_within(results, FRAME_BUDGET_MS)
}

/// [`knee`] with another frame budget (one frame at the recordings' own
/// rate, e.g. 40 ms at 25 fps).
pub fn knee_within(results: &[MethodResult], budget_ms: f64) -> Option<usize> {
    pareto(results)
        .into_iter()
        .filter(|&i| results[i].ms() <= budget_ms && results[i].press_top1.is_finite())
        .max_by(|&a, &b| {
            knee_score_within(&results[a], budget_ms)
                .total_cmp(&knee_score_within(&results[b], budget_ms))
        })
}

/// Accuracy minus the share of the frame budget ([`knee`]).
pub fn knee_score(r: &MethodResult) -> f64 {
    knee_score_within(r, FRAME_BUDGET_MS)
}

/// Accuracy minus the share of a frame budget of `budget_ms`.
pub fn knee_score_within(r: &MethodResult, budget_ms: f64) -> f64 {
    r.press_top1 - r.ms() / budget_ms
}

/// The markdown table.
pub fn markdown(results: &[MethodResult]) -> String {
    markdown_within(results, FRAME_BUDGET_MS)
}

/// [`markdown`] with the knee judged by another frame budget.
pub fn markdown_within(results: &[MethodResult], budget_ms: f64) -> String {
    let front = pareto(results);
    let k = knee_within(results, budget_ms);
    let mut s = String::from(
        "| method | runtime | crop → input | dim | ms/frame p50 (1 thread) | p95 | ms p50 (2 threads) | p95 | top-1 per frame | top-1 per press | Pareto |\n|---|---|---|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    for (i, r) in results.iter().enumerate() {
        let l1 = r
            .latency
            .first()
            .copied()
            .unwrap_or((1, f64::NAN, f64::NAN));
        let (l2, l2p) = r
            .latency
            .iter()
            .find(|l| l.0 == 2)
            .map_or(("-".to_string(), "-".to_string()), |l| {
                (format!("{:.3}", l.1), format!("{:.3}", l.2))
            });
        let mark = if k == Some(i) {
            "**knee**"
        } else if front.contains(&i) {
            "yes"
        } else {
            ""
        };
        let name = if r.nonfinite_frames > 0 {
            format!(
                "{} (non-finite output on {} frames)",
                r.name, r.nonfinite_frames
            )
        } else {
            r.name.clone()
        };
        s.push_str(&format!(
            "| {} | {} | {} → {} | {} | {:.3} | {:.3} | {} | {} | {:.2}% | {:.2}% | {} |\n",
            name,
            r.runtime,
            r.crop,
            r.input,
            r.dim,
            l1.1,
            l1.2,
            l2,
            l2p,
            100.0 * r.frame_top1,
            100.0 * r.press_top1,
            mark
        ));
    }
    s
}

fn chart_err<E: std::fmt::Display>(x: E) -> anyhow::Error {
    anyhow::anyhow!("chart: {x}")
}

/// Accuracy (per press) against per-frame latency, log-x, the Pareto
/// frontier joined, the knee ringed, the 60 fps budget marked (SVG).
pub fn chart(results: &[MethodResult], speed_svg: &std::path::Path) -> Result<()> {
    chart_with(
        results,
        speed_svg,
        "Accuracy against speed (held-out people, kNN top-1 per press)",
        FRAME_BUDGET_MS,
        "knee of the frontier (shipped default)",
    )
}

/// [`chart`] with another caption and frame budget (one frame at the
/// recordings' rate).
pub fn chart_with(
    results: &[MethodResult],
    speed_svg: &std::path::Path,
    caption: &str,
    budget_ms: f64,
    knee_label: &str,
) -> Result<()> {
    use plotters::prelude::*;
    let e = chart_err;
    {
        let root = SVGBackend::new(speed_svg, (1000, 620)).into_drawing_area();
        root.fill(&WHITE).map_err(e)?;
        let xmax = results
            .iter()
            .map(|r| r.ms())
            .fold(budget_ms * 1.2, f64::max)
            * 2.0;
        let xmin = results.iter().map(|r| r.ms()).fold(1.0, f64::min).max(1e-4) / 2.0;
        let mut c = ChartBuilder::on(&root)
            .caption(caption, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d((xmin..xmax).log_scale(), 0.0..100.0)
            .map_err(e)?;
        c.configure_mesh()
            .x_desc("ms per frame, one thread, batch 1 (log scale)")
            .y_desc("top-1 per press, %")
            .draw()
            .map_err(e)?;
        c.draw_series(LineSeries::new(
            [(budget_ms, 0.0), (budget_ms, 100.0)],
            RED.mix(0.6).stroke_width(2),
        ))
        .map_err(e)?
        .label(format!(
            "{budget_ms:.1} ms: one frame at {:.0} fps",
            1000.0 / budget_ms
        ))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.mix(0.6).stroke_width(2)));
        let mut front: Vec<(f64, f64)> = pareto(results)
            .into_iter()
            .map(|i| (results[i].ms(), 100.0 * results[i].press_top1))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        c.draw_series(LineSeries::new(front, BLUE.stroke_width(2)))
            .map_err(e)?
            .label("Pareto frontier")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        if let Some(k) = knee_within(results, budget_ms) {
            // Methods on this curve are worth as much as the knee: one
            // percentage point of accuracy per 1 % of the frame budget.
            let v = knee_score_within(&results[k], budget_ms);
            let steps = 200;
            let curve: Vec<(f64, f64)> = (0..=steps)
                .map(|i| xmin * (xmax / xmin).powf(i as f64 / steps as f64))
                .map(|x| (x, 100.0 * (v + x / budget_ms)))
                .filter(|p| p.1 <= 100.0)
                .collect();
            c.draw_series(LineSeries::new(curve, GREEN.mix(0.5).stroke_width(1)))
                .map_err(e)?
                .label("as good as the knee: +1 point of accuracy per +1 % of the budget")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], GREEN.mix(0.5)));
            let p = (results[k].ms(), 100.0 * results[k].press_top1);
            c.draw_series(std::iter::once(Circle::new(p, 11, GREEN.stroke_width(3))))
                .map_err(e)?
                .label(knee_label)
                .legend(|(x, y)| Circle::new((x + 10, y), 5, GREEN.stroke_width(3)));
        }
        for (i, r) in results.iter().enumerate() {
            let p = (r.ms(), 100.0 * r.press_top1);
            let color = if r.runtime == "rust" {
                BLACK.mix(0.5)
            } else {
                BLACK.mix(1.0)
            };
            c.draw_series(std::iter::once(Circle::new(p, 5, color.filled())))
                .map_err(e)?;
            // Alternate label offsets so that neighbours do not overprint.
            let dy = if i % 2 == 0 { 2.0 } else { -4.0 };
            c.draw_series(std::iter::once(Text::new(
                r.name.clone(),
                (p.0 * 1.08, p.1 + dy),
                ("sans-serif", 12),
            )))
            .map_err(e)?;
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::LowerRight)
            .draw()
            .map_err(e)?;
        root.present().map_err(e)?;
    }
    Ok(())
}
