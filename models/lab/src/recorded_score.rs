//! Scoring the recorded-presses study ([`crate::recorded`]): every split's
//! index and queries from the per-recording embeddings, per frame, per
//! press (kNN and centroids), the daemon's decider against those centroids
//! and against the index `index build --presses` makes, the open set and
//! accuracy against time.

use crate::data::{ImageKind, ImageSet};
use crate::methods::{self, Method, MethodResult};
use crate::preprocess::centre_crop_resize;
use crate::preprocess::reference_image;
use crate::recorded::*;
use anyhow::{bail, ensure, Context, Result};
use std::time::Instant;
use telextiles_index::{Index, IndexBuilder, TextileRecord};
use telextiles_sensing::decide::{DecideConfig, Decider, PressMean, TextileIndex};
use telextiles_sensing::front::{self};

/// Index rows of spread frames: (row data, press, class).
struct Bank {
    rows: Vec<f32>,
    press: Vec<usize>,
    class: Vec<u32>,
    dim: usize,
}

pub(crate) fn sample(n: usize, k: usize) -> Vec<usize> {
    if k == 0 || n <= k {
        (0..n).collect()
    } else {
        crate::protocol::spread(0, n, k)
    }
}

fn unit_mean<'a>(rows: impl Iterator<Item = &'a [f32]>, dim: usize) -> Option<Vec<f32>> {
    let mut m = vec![0f32; dim];
    let mut any = false;
    for r in rows {
        any = true;
        for (s, v) in m.iter_mut().zip(r) {
            *s += v;
        }
    }
    if !any {
        return None;
    }
    crate::knn::normalize_rows(&mut m, dim.max(1));
    Some(m)
}

/// The press's running mean up to `t_ms` as the daemon's decider keeps it
/// (each frame by its contact weight, [`telextiles_sensing::decide::PressMean`]),
/// normalised; None before the first frame.
fn weighted_mean_until(e: &PressEmbedding, dim: usize, t_ms: f64) -> Option<Vec<f32>> {
    let mut m = PressMean::new(dim, DecideConfig::default().depth_power);
    let mut any = false;
    for k in (0..e.len()).filter(|&k| e.t_ms[k] <= t_ms) {
        any |= m.add(e.row(k), e.weights.get(k).copied().unwrap_or(1.0));
    }
    if !any {
        return None;
    }
    let mut v = m.sum().to_vec();
    crate::knn::normalize_rows(&mut v, dim.max(1));
    Some(v)
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl Bank {
    /// Class of the nearest row whose press is allowed.
    fn nearest(&self, q: &[f32], allowed: &dyn Fn(usize) -> bool) -> Option<u32> {
        let mut best: Option<(f32, u32)> = None;
        for (i, r) in self.rows.chunks_exact(self.dim.max(1)).enumerate() {
            if !allowed(self.press[i]) {
                continue;
            }
            let s = dot(q, r);
            // NaN (non-finite embeddings) never wins.
            if s.is_finite() && best.is_none_or(|b| s > b.0) {
                best = Some((s, self.class[i]));
            }
        }
        best.map(|b| b.1)
    }
}

/// An index and its sorted calibration distances (empty unless asked
/// for; `IndexBuilder::build_calibrated`).
type Calibrated = (Index, Vec<f32>);

/// Which index [`press_index`] builds: with per-press exemplars, with a
/// metric learned with this shrinkage, with the calibration distances.
#[derive(Clone, Copy)]
struct IndexKind {
    exemplars: bool,
    metric: Option<f32>,
    calibrate: bool,
}

/// The index `telextilesd index build --presses` makes of these presses
/// (`telextiles_index::IndexBuilder`, the same code): one centroid per
/// textile, the normalised mean of its frames, and with `exemplars` each
/// press's mean embedding beside it (the default with `--presses`; a
/// textile is then as near as its nearest press). None when no textile
/// has a frame.
fn press_index(
    processed: &[Processed],
    m: usize,
    class_of: &[u32],
    textiles: &[String],
    presses: impl Iterator<Item = usize>,
    how: IndexKind,
) -> Option<Calibrated> {
    let IndexKind {
        exemplars,
        metric,
        calibrate,
    } = how;
    // Per textile: its frames' embeddings, and its presses' means.
    type Rows = Vec<Vec<f32>>;
    let mut per: Vec<(Rows, Rows)> = vec![Default::default(); textiles.len()];
    let mut dim = 0;
    for i in presses {
        let e = &processed[i].methods[m];
        if e.is_empty() {
            continue;
        }
        dim = e.dim;
        let slot = &mut per[class_of[i] as usize];
        let mut mean = vec![0f32; e.dim];
        for k in 0..e.len() {
            for (a, v) in mean.iter_mut().zip(e.row(k)) {
                *a += v / e.len() as f32;
            }
        }
        slot.1.push(mean);
        slot.0.extend((0..e.len()).map(|k| e.row(k).to_vec()));
    }
    let mut builder = IndexBuilder::new("", "lab", dim, 0);
    let mut n = 0;
    for (id, (embeddings, exemplars)) in textiles.iter().zip(per) {
        if embeddings.is_empty() {
            continue;
        }
        builder
            .add(TextileRecord {
                id: id.clone(),
                name: id.clone(),
                seen: true,
                structure: String::new(),
                attributes: Vec::new(),
                embeddings,
                exemplars,
                press_frames: Vec::new(),
            })
            .ok()?;
        n += 1;
    }
    builder.roller_n = n.min(16);
    builder.keep_exemplars = exemplars;
    builder.metric = telextiles_index::build::MetricFit::press_means(metric);
    if calibrate {
        builder.build_calibrated().ok()
    } else {
        builder.build().ok().map(|i| (i, Vec::new()))
    }
}

/// The daemon's decider over one press's frames (running mean against
/// the index, with its hysteresis).
fn decide_press(index: &impl TextileIndex, e: &PressEmbedding) -> Decided {
    let mut d = Decider::new(DecideConfig::default(), index.dim());
    d.press_start(0);
    for k in 0..e.len() {
        let t_us = (e.t_ms[k] * 1000.0).round().max(0.0) as u64;
        let w = e.weights.get(k).copied().unwrap_or(1.0);
        d.on_embedding_weighted(index, t_us, e.row(k), w);
    }
    let end = e.t_ms.last().map_or(0, |t| (t * 1000.0).round() as u64);
    match d.press_end(index, end) {
        Some(o) => Decided {
            textile: o.decision.map(|x| index.id(x.entry).to_string()),
            unknown: o.decision.is_some_and(|x| x.unknown),
            distance: o.decision.map(|x| x.distance),
            confidence: o.decision.map(|x| x.confidence),
            first_ms: o.first_decision_us.map(|t| t as f64 / 1e3),
            switches: o.switches,
        },
        None => Decided::default(),
    }
}

/// What [`decide_press`] decided: the final textile (None: undecided),
/// whether it was flagged unknown, when the first decision came (ms since
/// the press started) and how often it changed after that.
#[derive(Default)]
struct Decided {
    textile: Option<String>,
    unknown: bool,
    /// The final decision's distance.
    distance: Option<f32>,
    /// Its `(d2 - d1) / d2` against the nearest other textile.
    confidence: Option<f32>,
    first_ms: Option<f64>,
    switches: u32,
}

/// Score one method's embeddings under a split.
fn score(
    m: usize,
    processed: &[Processed],
    class_of: &[u32],
    roles: &[Role],
    ntex: usize,
    cfg: &StudyConfig,
    textiles: &[String],
) -> Score {
    let usable: Vec<usize> = (0..processed.len())
        .filter(|&i| roles[i] != Role::Skipped && !processed[i].methods[m].is_empty())
        .collect();
    let dim = usable
        .first()
        .map_or(0, |&i| processed[i].methods[m].dim)
        .max(1);
    let mut bank = Bank {
        rows: Vec::new(),
        press: Vec::new(),
        class: Vec::new(),
        dim,
    };
    // The sampled rows of every index press (bank).
    for &i in &usable {
        let e = &processed[i].methods[m];
        if roles[i] == Role::Query {
            continue;
        }
        for k in sample(e.len(), cfg.frames_per_press) {
            bank.rows.extend_from_slice(e.row(k));
            bank.press.push(i);
            bank.class.push(class_of[i]);
        }
    }
    let index_presses = |except: Option<usize>| {
        usable
            .iter()
            .copied()
            .filter(move |&i| roles[i] != Role::Query && Some(i) != except)
    };
    // Calibration distances only where the open set is measured (the
    // exemplars index; they cost a metric learned again per fold).
    let open = !cfg.unknown_quantiles.is_empty();
    let fixed_indexes = [false, true].map(|x| {
        press_index(
            processed,
            m,
            class_of,
            textiles,
            index_presses(None),
            IndexKind {
                exemplars: x,
                metric: cfg.metric,
                calibrate: open && x,
            },
        )
    });
    let mut open_set = OpenSet::new(&cfg.unknown_quantiles);
    // Per textile: the default index of the other textiles' index presses
    // (a query of it is then of a textile the index does not have).
    let mut without: Vec<Option<Option<Calibrated>>> = vec![None; ntex];
    let mut sc = Score {
        per_class: textiles
            .iter()
            .map(|t| ClassScore {
                textile: t.clone(),
                query_presses: 0,
                presses_correct: 0,
                query_frames: 0,
                frames_correct: 0,
            })
            .collect(),
        confusion: vec![vec![0; ntex]; ntex],
        by_time: cfg.times_ms.iter().map(|&t| (t, 0usize)).collect(),
        ..Score::default()
    };
    let mut first_ms = Vec::new();
    // Every query (a recording this method embedded no frame of counts as
    // undecided, hence wrong).
    let queries = (0..processed.len()).filter(|&i| matches!(roles[i], Role::Query | Role::Both));
    for q in queries {
        let e = &processed[q].methods[m];
        let lopo = roles[q] == Role::Both;
        let allowed = |p: usize| !lopo || p != q;
        let truth = class_of[q];
        // Per frame.
        let fr = sample(e.len(), cfg.frames_per_press);
        let mut fc = 0;
        for &k in &fr {
            if bank.nearest(e.row(k), &allowed) == Some(truth) {
                fc += 1;
            }
        }
        // Per press.
        let mean = unit_mean((0..e.len()).map(|k| e.row(k)), dim);
        let knn = mean.as_ref().and_then(|x| bank.nearest(x, &allowed));
        // The index the daemon would build of the other presses: its
        // centroids, and centroids with per-press exemplars.
        let own;
        let indexes = if lopo {
            own = [false, true].map(|x| {
                press_index(
                    processed,
                    m,
                    class_of,
                    textiles,
                    index_presses(Some(q)),
                    IndexKind {
                        exemplars: x,
                        metric: cfg.metric,
                        calibrate: open && x,
                    },
                )
            });
            &own
        } else {
            &fixed_indexes
        };
        let cent = mean.as_ref().and_then(|mean| {
            let (index, _) = indexes[0].as_ref()?;
            let best = &index.entries[index.nearest(mean)?.best].id;
            textiles.iter().position(|t| t == best).map(|c| c as u32)
        });
        // Against time.
        for (t, correct) in sc.by_time.iter_mut() {
            if let Some(mt) = weighted_mean_until(e, dim, *t) {
                if bank.nearest(&mt, &allowed) == Some(truth) {
                    *correct += 1;
                }
            }
        }
        if let Some(&t) = e.t_ms.first() {
            first_ms.push(t);
        }
        // The daemon's decider, against both indexes.
        let [by_centroid, by_exemplar] = indexes.each_ref().map(|index| match index {
            Some((index, _)) if !e.is_empty() => decide_press(index, e),
            _ => Decided::default(),
        });
        if open {
            if let Some((_, press_d)) = &indexes[1] {
                open_set.add(false, &by_exemplar, press_d);
            }
            let other = without[truth as usize].get_or_insert_with(|| {
                press_index(
                    processed,
                    m,
                    class_of,
                    textiles,
                    index_presses(None).filter(|&i| class_of[i] != truth),
                    IndexKind {
                        exemplars: true,
                        metric: cfg.metric,
                        calibrate: true,
                    },
                )
            });
            if let Some((index, press_d)) = other {
                let decided = if e.is_empty() {
                    Decided::default()
                } else {
                    decide_press(index, e)
                };
                open_set.add(true, &decided, press_d);
            }
        }
        let right = |d: &Decided| d.textile.as_deref() == Some(textiles[truth as usize].as_str());
        if right(&by_centroid) {
            sc.decider_correct += 1;
        }
        if right(&by_exemplar) {
            sc.exemplar_decider_correct += 1;
        }
        sc.unknown += by_centroid.unknown as usize;
        sc.exemplar_unknown += by_exemplar.unknown as usize;
        if let Some(t) = by_centroid.first_ms {
            sc.first_decision_ms.push(t);
        }
        sc.switches += by_centroid.switches as usize;
        let pc = &mut sc.per_class[truth as usize];
        pc.query_presses += 1;
        pc.query_frames += fr.len();
        pc.frames_correct += fc;
        sc.frames += fr.len();
        sc.frames_correct += fc;
        sc.presses += 1;
        if knn == Some(truth) {
            pc.presses_correct += 1;
            sc.knn_correct += 1;
        }
        if cent == Some(truth) {
            sc.centroid_correct += 1;
        }
        if let Some(p) = knn {
            sc.confusion[truth as usize][p as usize] += 1;
        }
        let name = |c: Option<u32>| c.map_or("-".to_string(), |c| textiles[c as usize].clone());
        sc.decisions.push(PressDecision {
            recording: q,
            truth: textiles[truth as usize].clone(),
            knn: name(knn),
            centroid: name(cent),
            decider: by_centroid.textile.unwrap_or_else(|| "-".into()),
            decider_exemplars: by_exemplar.textile.unwrap_or_else(|| "-".into()),
            first_decision_ms: by_centroid.first_ms,
            frame_top1: fc as f64 / fr.len().max(1) as f64,
        });
    }
    sc.nonfinite = usable
        .iter()
        .map(|&i| crate::methods::nonfinite_rows(&processed[i].methods[m].rows, dim))
        .sum();
    sc.first_frame_ms = crate::bench::median(&first_ms);
    sc.dim = dim;
    sc.separation = open_set.separation();
    sc.open_set = open_set.rows();
    sc
}

/// Accumulates [`OpenSetRow`]s: the fixed distance, then one row per
/// quantile.
struct OpenSet {
    rules: Vec<Option<f32>>,
    rows: Vec<OpenSetRow>,
    /// Per rule: the distances used for known and for unseen queries.
    used: Vec<[Vec<f64>; 2]>,
    /// Known, unseen decided presses: (d1, d1 / d2).
    scores: [Vec<(f64, f64)>; 2],
}

impl OpenSet {
    fn new(quantiles: &[f32]) -> OpenSet {
        let rules: Vec<Option<f32>> = if quantiles.is_empty() {
            Vec::new()
        } else {
            std::iter::once(None)
                .chain(quantiles.iter().map(|&q| Some(q)))
                .collect()
        };
        OpenSet {
            rows: rules
                .iter()
                .map(|&quantile| OpenSetRow {
                    quantile,
                    median_distance_known: f64::NAN,
                    median_distance_unseen: f64::NAN,
                    uncalibrated: 0,
                    known_decided: 0,
                    known_flagged: 0,
                    unseen_decided: 0,
                    unseen_flagged: 0,
                })
                .collect(),
            used: vec![Default::default(); rules.len()],
            scores: Default::default(),
            rules,
        }
    }

    fn separation(&self) -> Option<Separation> {
        if self.rules.is_empty() {
            return None;
        }
        let [k, u] = &self.scores;
        let by = |f: fn(&(f64, f64)) -> f64| {
            auroc(
                &k.iter().map(f).collect::<Vec<_>>(),
                &u.iter().map(f).collect::<Vec<_>>(),
            )
        };
        Some(Separation {
            distance_auroc: by(|s| s.0),
            ratio_auroc: by(|s| s.1),
            known: k.len(),
            unseen: u.len(),
        })
    }

    /// One query's final decision (its distance None: undecided) against
    /// an index whose sorted calibration distances are `press_d`.
    fn add(&mut self, unseen: bool, decided: &Decided, press_d: &[f32]) {
        if let (Some(d1), Some(c)) = (decided.distance, decided.confidence) {
            self.scores[unseen as usize].push((d1 as f64, 1.0 - c as f64));
        }
        let d1 = decided.distance;
        let fixed = DecideConfig::default().unknown_distance;
        for ((rule, row), used) in self.rules.iter().zip(&mut self.rows).zip(&mut self.used) {
            let t = match rule {
                None => fixed,
                Some(q) => match telextiles_index::build::calibrated_distance(press_d, *q) {
                    Some(t) => t,
                    None => {
                        row.uncalibrated += 1;
                        fixed
                    }
                },
            };
            used[unseen as usize].push(t as f64);
            let Some(d1) = d1 else { continue };
            let flagged = d1 > t;
            if unseen {
                row.unseen_decided += 1;
                row.unseen_flagged += flagged as usize;
            } else {
                row.known_decided += 1;
                row.known_flagged += flagged as usize;
            }
        }
    }

    fn rows(mut self) -> Vec<OpenSetRow> {
        for (row, [k, u]) in self.rows.iter_mut().zip(&self.used) {
            row.median_distance_known = crate::bench::median(k);
            row.median_distance_unseen = crate::bench::median(u);
        }
        self.rows
    }
}

#[derive(Default)]
struct Score {
    dim: usize,
    presses: usize,
    knn_correct: usize,
    centroid_correct: usize,
    frames: usize,
    frames_correct: usize,
    by_time: Vec<(f64, usize)>,
    first_frame_ms: f64,
    per_class: Vec<ClassScore>,
    confusion: Vec<Vec<usize>>,
    decisions: Vec<PressDecision>,
    nonfinite: usize,
    decider_correct: usize,
    exemplar_decider_correct: usize,
    /// Final decisions flagged unknown (every query's textile is known).
    unknown: usize,
    exemplar_unknown: usize,
    first_decision_ms: Vec<f64>,
    switches: usize,
    open_set: Vec<OpenSetRow>,
    separation: Option<Separation>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Role {
    Index,
    Query,
    /// Leave one out: query against the others, index for them.
    Both,
    Skipped,
}

pub(crate) fn roles(processed: &[Processed], class_of: &[u32], split: Split) -> Vec<Role> {
    let mut seen: std::collections::HashMap<u32, usize> = Default::default();
    processed
        .iter()
        .enumerate()
        .map(|(i, p)| {
            if p.skipped.is_some() {
                return Role::Skipped;
            }
            match split {
                Split::Lopo => Role::Both,
                Split::IndexPresses(k) => {
                    let n = seen.entry(class_of[i]).or_default();
                    *n += 1;
                    if *n <= k {
                        Role::Index
                    } else {
                        Role::Query
                    }
                }
            }
        })
        .collect()
}

pub(crate) fn ratio(a: usize, b: usize) -> f64 {
    if b == 0 {
        f64::NAN
    } else {
        a as f64 / b as f64
    }
}

/// Scores already embedded recordings (`processed[i].methods[j]` is
/// `methods[j]`'s embedding of recording i) under `cfg.split`; times the
/// methods on one frame in contact with its recording's reference unless
/// `cfg.runs` is 0.
pub fn score_all(
    cfg: &StudyConfig,
    methods: &[Method],
    refs: &[RecordingRef],
    processed: &[Processed],
) -> Result<StudyReport> {
    ensure!(
        processed
            .iter()
            .all(|p| p.skipped.is_some() || p.methods.len() == methods.len()),
        "embeddings do not match the method list"
    );
    let mut textiles: Vec<String> = processed.iter().map(|p| p.textile.clone()).collect();
    textiles.sort();
    textiles.dedup();
    let class_of: Vec<u32> = processed
        .iter()
        .map(|p| textiles.iter().position(|t| *t == p.textile).unwrap_or(0) as u32)
        .collect();
    let roles = roles(processed, &class_of, cfg.split);
    let queries = roles
        .iter()
        .filter(|r| matches!(r, Role::Query | Role::Both))
        .count();
    if queries == 0 {
        bail!(
            "no query recordings: {} usable recordings of {} textiles; with --index-presses K each textile needs more than K recordings",
            roles.iter().filter(|r| **r != Role::Skipped).count(),
            textiles.len()
        );
    }
    let mut fps: Vec<(f64, usize)> = Vec::new();
    for p in processed {
        let f = (p.fps * 10.0).round() / 10.0;
        match fps.iter_mut().find(|x| x.0 == f) {
            Some(x) => x.1 += 1,
            None => fps.push((f, 1)),
        }
    }
    fps.sort_by(|a, b| a.0.total_cmp(&b.0));
    let rates: Vec<f64> = processed
        .iter()
        .map(|p| p.fps)
        .filter(|f| f.is_finite())
        .collect();
    let frame_budget_ms = 1000.0 / crate::bench::median(&rates);
    let frame_budget_ms = if frame_budget_ms.is_finite() {
        frame_budget_ms
    } else {
        methods::FRAME_BUDGET_MS
    };
    // One frame in contact (and its recording's reference) to time on.
    let probe = processed
        .iter()
        .enumerate()
        .find(|(i, p)| roles[*i] != Role::Skipped && p.contact_frames > 0)
        .map(|(i, _)| i);
    let probe = match (probe, cfg.runs) {
        (Some(i), r) if r > 0 => {
            let press = refs[i].load()?;
            let seg = front::segment(&press, &cfg.contact).context("probe recording")?;
            let mid = seg.contact[seg.contact.len() / 2].index;
            Some((press.frames[mid].clone(), reference_image(&seg.reference)?))
        }
        _ => None,
    };
    let t = Instant::now();
    let mut out = Vec::new();
    for (j, m) in methods.iter().enumerate() {
        let s = score(
            j,
            processed,
            &class_of,
            &roles,
            textiles.len(),
            cfg,
            &textiles,
        );
        let (crop, input) = m.view();
        let latency = match &probe {
            Some((frame, reference)) => {
                let img = centre_crop_resize(frame, crop, input)?;
                let rv = centre_crop_resize(reference, crop, input)?;
                let set = ImageSet {
                    kind: ImageKind::Input,
                    side: input as usize,
                    crop,
                    classes: vec![],
                    items: vec![crate::data::FrameMeta {
                        class: 0,
                        press: 0,
                        person: 0,
                        sensor: 0,
                        jig: false,
                        frame: 0,
                    }],
                    pixels: img.into_raw(),
                    source: "recorded".into(),
                };
                methods::time_method(m, &set, Some(rv.as_raw()), &cfg.time_threads, cfg.runs)?
            }
            None => Vec::new(),
        };
        let by_time: Vec<(f64, f64)> = s
            .by_time
            .iter()
            .map(|&(t, c)| (t, ratio(c, s.presses)))
            .collect();
        out.push(RecordedMethod {
            summary: MethodResult {
                name: m.name(),
                runtime: m.runtime().into(),
                crop,
                input,
                dim: s.dim,
                model_bytes: match m {
                    Method::Onnx { bytes, .. } => Some(bytes.len()),
                    Method::Rust { .. } => None,
                },
                latency,
                frame_top1: ratio(s.frames_correct, s.frames),
                press_top1: ratio(s.knn_correct, s.presses),
                press_top1_centroid: ratio(s.centroid_correct, s.presses),
                by_frames: Vec::new(),
                queries: s.frames,
                presses: s.presses,
                nonfinite_frames: s.nonfinite,
                groups: Vec::new(),
            },
            press_top1_centroid: ratio(s.centroid_correct, s.presses),
            press_top1_decider: ratio(s.decider_correct, s.presses),
            press_top1_decider_exemplars: ratio(s.exemplar_decider_correct, s.presses),
            unknown_flagged: s.unknown,
            unknown_flagged_exemplars: s.exemplar_unknown,
            first_decision_ms: crate::bench::median(&s.first_decision_ms),
            decided_presses: s.first_decision_ms.len(),
            switches: s.switches,
            by_time,
            first_frame_ms: s.first_frame_ms,
            per_class: s.per_class,
            confusion: s.confusion,
            decisions: s.decisions,
            open_set: s.open_set,
            separation: s.separation,
        });
    }
    let scoring_s = t.elapsed().as_secs_f64();
    let summaries: Vec<MethodResult> = out.iter().map(|m| m.summary.clone()).collect();
    let pareto: Vec<String> = methods::pareto(&summaries)
        .into_iter()
        .map(|i| summaries[i].name.clone())
        .collect();
    let knee = if summaries.iter().all(|s| s.latency.is_empty()) {
        None
    } else {
        methods::knee_within(&summaries, frame_budget_ms).map(|i| summaries[i].name.clone())
    };
    let mut featured: Vec<String> = methods
        .iter()
        .filter(|m| matches!(m, Method::Onnx { .. }) && !crate::report::is_descriptor(&m.name()))
        .map(|m| m.name())
        .collect();
    if let Some(best) = summaries
        .iter()
        .filter(|s| s.press_top1.is_finite())
        .max_by(|a, b| {
            a.press_top1
                .total_cmp(&b.press_top1)
                .then(b.ms().total_cmp(&a.ms()))
        })
    {
        featured.push(best.name.clone());
    }
    featured.extend(knee.clone());
    let mut seen = std::collections::HashSet::new();
    featured.retain(|n| seen.insert(n.clone()));
    let recordings = processed
        .iter()
        .zip(&roles)
        .map(|(p, r)| RecordingRow {
            path: p.path.clone(),
            textile: p.textile.clone(),
            sensor: p.sensor.clone(),
            frames: p.frames,
            fps: p.fps,
            contact_frames: p.contact_frames,
            own_reference: p.own_reference,
            given_reference: p.given_reference,
            role: match r {
                Role::Index => "index",
                Role::Query => "query",
                Role::Both => "both",
                Role::Skipped => "skipped",
            }
            .into(),
            skipped: p.skipped.clone(),
        })
        .collect();
    Ok(StudyReport {
        machine: crate::report::machine(),
        date: crate::report::today(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        source: format!("presses:{}", cfg.dir.display()),
        layout: match refs.first().map(|r| &r.layout) {
            Some(Layout::Pytouch) => "pytouch".into(),
            _ => "press".into(),
        },
        split: cfg.split,
        split_text: cfg.split.describe(),
        frames_per_press: cfg.frames_per_press,
        encode_run: cfg.encode_run,
        index_metric: cfg.metric,
        unknown_quantiles: cfg.unknown_quantiles.clone(),
        textiles,
        recordings,
        fps,
        frame_budget_ms,
        methods: out,
        pareto,
        knee,
        featured,
        seconds: vec![("scoring and timing".into(), scoring_s)],
    })
}
