//! The study on recorded presses (`--source presses:<dir>`): the methods of
//! the simulator bench ([`crate::methods::Method`]) on a user's own
//! recordings, with splits that fit such data.
//!
//! **Input.** A directory of recordings in the on-disk press format
//! (`telextiles_sim::recording`: one directory with `press.json` and PNG
//! frames per press, found recursively, as `telextilesd record` writes
//! them; the textile is `press.json`'s `textile`), or, when no `press.json`
//! is found, the PyTouch layout `root/<class>/<serial>/*.png` (one
//! recording per `<class>/<serial>` directory, and one for frames directly
//! under `<class>`; timed as the reader times them: at the DIGIT's stream
//! rate for the frames' size, or at `--fps`). Recordings are taken in
//! sorted path order.
//!
//! **One reference per recording.** Every recording is processed alone,
//! from a clean state, with its own no-contact reference and never with
//! anything left from another recording: ONNX models run the daemon's
//! per-frame path itself ([`telextiles_sensing::front::FrontEnd`], reset
//! to the recording's reference from
//! [`telextiles_sensing::front::recording_reference`]), and the Rust
//! descriptors get the frames in contact and the reference from
//! [`telextiles_sensing::front::segment`] (the same contact detector).
//! The embeddings of a recording therefore do not depend on which other
//! recordings are in the run, nor on their order; every split below is
//! scored from the same per-recording embeddings.
//!
//! **Splits.** `IndexPresses(K)`: for each textile the first K recordings
//! in sorted path order build the index, the rest are queries (a textile
//! with K or fewer recordings has no queries; it stays in the index).
//! `Lopo` (leave one press out): every recording is a query against an
//! index of all the other recordings.
//!
//! **Scores.** Index: up to `frames_per_press` frames in contact of each
//! index recording, spread evenly over its contact. Per frame: each of
//! those frames of a query recording, nearest index frame (kNN, k = 1).
//! Per press: the mean of *all* the query's frames in contact (L2-normalised
//! embeddings, mean direction), nearest index frame, as the simulator
//! bench scores a press; also against the textiles' centroids (the
//! normalised mean of the index frames of each textile), as `index build`
//! and the daemon's decider do. The daemon's decider itself runs over each
//! query's frames twice: against those centroids, and against the index
//! `telextilesd index build --presses` makes by default (the same
//! `IndexBuilder`: centroids and every index press's mean embedding), and
//! the known presses it flags unknown are counted. Per-class accuracy and
//! the confusion matrix are per press (kNN). Against time: the running mean of the frames whose
//! timestamp is at most T after the press started (the contact detector's
//! first frame over threshold), from each recording's own timestamps; a
//! press with no frame in contact by T counts as wrong.

use anyhow::{bail, ensure, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

use telextiles_index::{Index, IndexBuilder, TextileRecord};
use telextiles_sensing::contact::{ContactConfig, ContactEvent};
use telextiles_sensing::decide::{DecideConfig, Decider, PressMean, TextileIndex};
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sensing::frame::Frame;
use telextiles_sensing::front::{self, FrontEnd, References};
use telextiles_sim::recording;
use telextiles_sim::Press;

use crate::baselines::Baseline;
use crate::data::{ImageKind, ImageSet};
use crate::methods::{self, Method, MethodResult};
use crate::preprocess::centre_crop_resize;

/// Where a `--source` takes its frames from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Source {
    /// A built-in source (simulator, synthetic gratings).
    Builtin(crate::protocol::SourceKind),
    /// Recorded presses (press format, else PyTouch layout) under a directory.
    Presses(PathBuf),
}

impl std::str::FromStr for Source {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Source, String> {
        if let Some(dir) = s.strip_prefix("presses:") {
            if dir.is_empty() {
                return Err("presses: needs a directory, e.g. presses:recordings/".into());
            }
            return Ok(Source::Presses(PathBuf::from(dir)));
        }
        match s {
            "sim" => Ok(Source::Builtin(crate::protocol::SourceKind::Sim)),
            "synth" => Ok(Source::Builtin(crate::protocol::SourceKind::Synth)),
            _ => Err(format!(
                "unknown source {s:?}: expected sim, synth or presses:<dir>"
            )),
        }
    }
}

/// How recordings are split into index and queries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum Split {
    /// The first K recordings of each textile (sorted path order) build the
    /// index, the rest are queries.
    IndexPresses(usize),
    /// Leave one press out: each recording against all the others.
    Lopo,
}

impl Split {
    /// Text for reports.
    pub fn describe(&self) -> String {
        match self {
            Split::IndexPresses(k) => format!(
                "the first {k} recordings of each textile (sorted path order) build the index, the others are queries"
            ),
            Split::Lopo => {
                "leave one press out: each recording is a query against an index of all the other recordings".into()
            }
        }
    }
}

/// On-disk layout of a recording.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub enum Layout {
    /// `telextiles_sim::recording` press directory.
    Press,
    /// PyTouch `<class>/<serial>/*.png` (or `<class>/*.png`).
    Pytouch,
}

/// A recording found on disk (not loaded yet).
#[derive(Clone, Debug, PartialEq)]
pub struct RecordingRef {
    /// Its directory.
    pub path: PathBuf,
    /// Textile id (press.json `textile`, or the PyTouch class).
    pub textile: String,
    /// Layout.
    pub layout: Layout,
    /// Where its frames are (shared with the daemon).
    recording: recording::Recording,
}

/// The recordings under `dir`, in sorted path order: press directories
/// found recursively (symbolic links followed, as the daemon's
/// `classify` and `index build` read them), else the PyTouch layout
/// (`telextiles_sim::recording::find_recordings_at`), those saved without
/// timestamps spaced at `fps` when given.
pub fn list_recordings(dir: &Path, fps: Option<f32>) -> Result<Vec<RecordingRef>> {
    ensure!(dir.is_dir(), "{} is not a directory", dir.display());
    recording::find_recordings_at(dir, fps)?
        .into_iter()
        .map(|r| {
            let (textile, layout) = match &r {
                recording::Recording::Press(p) => (recording::read_meta(p)?.textile, Layout::Press),
                recording::Recording::Pytouch { entry, .. } => {
                    (entry.class.clone(), Layout::Pytouch)
                }
            };
            Ok(RecordingRef {
                path: r.path(),
                textile,
                layout,
                recording: r,
            })
        })
        .collect()
}

impl RecordingRef {
    /// Load the recording's frames.
    pub fn load(&self) -> Result<Press> {
        Ok(self.recording.load()?)
    }
}

/// One method's embeddings of one recording's frames in contact.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PressEmbedding {
    /// Embedding length.
    pub dim: usize,
    /// L2-normalised rows, one per frame in contact, in order.
    pub rows: Vec<f32>,
    /// Index of each row's frame in the recording.
    pub frames: Vec<usize>,
    /// Milliseconds from the press start (first frame over the contact
    /// threshold) to each row's frame, from the recording's timestamps.
    pub t_ms: Vec<f64>,
    /// Each row's weight in the press's running mean (the daemon's
    /// `contact_weight` of the frame's contact score); empty: all 1.
    pub weights: Vec<f32>,
    /// Leading rows that are frames of the run that started the press,
    /// encoded when the detector started it (the front end's
    /// `FrontOutput::earlier`); without that, a press's embeddings would
    /// begin at row `early`.
    pub early: usize,
}

impl PressEmbedding {
    /// Rows.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// No rows.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Row `i`.
    pub fn row(&self, i: usize) -> &[f32] {
        &self.rows[i * self.dim..(i + 1) * self.dim]
    }
}

/// One recording processed by every method.
#[derive(Clone, Debug, PartialEq)]
pub struct Processed {
    /// The recording's directory.
    pub path: String,
    /// Textile id.
    pub textile: String,
    /// Sensor serial (or unit number).
    pub sensor: String,
    /// Frames in the recording.
    pub frames: usize,
    /// Frame rate from its timestamps (median interval).
    pub fps: f64,
    /// Frames in contact (the contact detector's view).
    pub contact_frames: usize,
    /// The recording carries its own reference (`reference_frames`); else
    /// one was given (`given_reference`) or captured from its first steady
    /// frames.
    pub own_reference: bool,
    /// It carries none, and the one given for its sensor replayed it
    /// (`--reference`).
    pub given_reference: bool,
    /// Why it cannot be used (no reference, no contact); then `methods` is
    /// empty.
    pub skipped: Option<String>,
    /// Per method, in the order of the method list.
    pub methods: Vec<PressEmbedding>,
}

/// Frame rate from timestamps: 1 / median interval.
pub fn fps_of(timestamps_us: &[u64]) -> f64 {
    let d: Vec<f64> = timestamps_us
        .windows(2)
        .map(|w| w[1].saturating_sub(w[0]) as f64)
        .filter(|&x| x > 0.0)
        .collect();
    let m = crate::bench::median(&d);
    if m.is_finite() && m > 0.0 {
        1e6 / m
    } else {
        f64::NAN
    }
}

enum Runner {
    Rust { base: Baseline, crop: u32 },
    Front(Box<FrontEnd>),
}

/// Embeds recordings, one at a time, with every method (see the module
/// docs: nothing but the method's weights carries over between
/// recordings).
pub struct Processor {
    runners: Vec<Runner>,
    contact: ContactConfig,
    /// The run that starts a press is encoded too (the front end's
    /// `set_encode_run`; off by default, as in the daemon).
    encode_run: bool,
    /// References for recordings without their own.
    references: References,
    /// Model files for [`Encoder::open`].
    _dir: tempfile::TempDir,
}

/// Reference pixels (f32, 0..255) as an image.
pub(crate) fn reference_image(px: &[f32]) -> Result<image::RgbImage> {
    telextiles_sensing::front::image_of(px).context("reference of the wrong size")
}

impl Processor {
    /// Sessions for `methods`, `threads` ONNX Runtime threads each.
    pub fn new(methods: &[Method], threads: usize, contact: ContactConfig) -> Result<Processor> {
        let dir = tempfile::tempdir()?;
        let mut runners = Vec::new();
        for (i, m) in methods.iter().enumerate() {
            runners.push(match m {
                Method::Rust { base, crop } => Runner::Rust {
                    base: *base,
                    crop: *crop,
                },
                Method::Onnx { bytes, name, .. } => {
                    let path = dir.path().join(format!("model-{i}.onnx"));
                    std::fs::write(&path, bytes)?;
                    let enc = Encoder::open(
                        &path,
                        &EncoderOptions {
                            threads: threads.max(1),
                            ort_library: Some(crate::onnx::ort_dylib_path()),
                        },
                    )
                    .with_context(|| format!("model {name}"))?;
                    Runner::Front(Box::new(FrontEnd::new(enc, contact.clone(), None)))
                }
            });
        }
        Ok(Processor {
            runners,
            contact,
            encode_run: false,
            references: References::none(),
            _dir: dir,
        })
    }

    /// The references given for recordings that carry none
    /// ([`References::for_press`]; a recording's own always wins).
    pub fn set_references(&mut self, references: References) {
        self.references = references;
    }

    /// Encode the run of frames that starts a press too, with every method
    /// (`FrontEnd::set_encode_run`); its rows lead and are counted in
    /// [`PressEmbedding::early`].
    pub fn set_encode_run(&mut self, on: bool) {
        self.encode_run = on;
        for r in &mut self.runners {
            if let Runner::Front(fe) = r {
                fe.set_encode_run(on);
            }
        }
    }

    /// Process one loaded recording with every method.
    pub fn process(&mut self, path: &str, press: Press) -> Result<Processed> {
        let meta = &press.meta;
        ensure!(
            meta.timestamps_us.len() == press.frames.len(),
            "{path}: {} timestamps for {} frames",
            meta.timestamps_us.len(),
            press.frames.len()
        );
        let mut out = Processed {
            path: path.to_string(),
            textile: meta.textile.clone(),
            sensor: meta
                .sensor_serial
                .clone()
                .unwrap_or_else(|| format!("unit {}", meta.sensor)),
            frames: press.frames.len(),
            fps: fps_of(&meta.timestamps_us),
            contact_frames: 0,
            own_reference: meta.reference_frames.is_some_and(|k| k > 0),
            given_reference: false,
            skipped: None,
            methods: Vec::new(),
        };
        let reference = self.references.for_press(&press);
        out.given_reference = !out.own_reference && reference.is_some();
        let Some(mut seg) = front::segment_with(&press, &self.contact, reference.as_deref()) else {
            out.skipped = Some(if out.own_reference || out.given_reference {
                "no frame in contact".into()
            } else {
                "no quiet frames before contact (reference_frames), and no no-contact reference could be captured from its first frames (give the sensor's no-contact frame with --reference)".into()
            });
            return Ok(out);
        };
        if !self.encode_run {
            seg.contact.retain(|c| !c.early);
        }
        if seg.contact.is_empty() {
            out.skipped = Some("no frame in contact".into());
            return Ok(out);
        }
        out.contact_frames = seg.contact.len();
        let start = seg.contact[0].press_start_us;
        let ref_img = reference_image(&seg.reference)?;
        let mut views: std::collections::HashMap<u32, (image::RgbImage, Vec<image::RgbImage>)> =
            Default::default();
        // The frames as the front end takes them.
        let frames: Vec<Frame> = press
            .frames
            .into_iter()
            .zip(&meta.timestamps_us)
            .enumerate()
            .map(|(i, (image, &t))| Frame {
                image,
                timestamp_us: t,
                seq: i as u64,
            })
            .collect();
        for r in &mut self.runners {
            let mut e = PressEmbedding::default();
            match r {
                Runner::Rust { base, crop } => {
                    if !views.contains_key(crop) {
                        let rv = centre_crop_resize(&ref_img, *crop, *crop)?;
                        let fv = seg
                            .contact
                            .iter()
                            .map(|c| centre_crop_resize(&frames[c.index].image, *crop, *crop))
                            .collect::<Result<Vec<_>>>()?;
                        views.insert(*crop, (rv, fv));
                    }
                    let (rv, fv) = &views[crop];
                    let side = *crop as usize;
                    for (c, v) in seg.contact.iter().zip(fv) {
                        // The first press's run, counted as the front end does.
                        e.early += (c.early && e.early == e.frames.len()) as usize;
                        let f = base.features(v.as_raw(), side, side, Some(rv.as_raw()));
                        e.dim = f.len();
                        e.rows.extend(f);
                        e.frames.push(c.index);
                        e.t_ms.push(c.t_us.saturating_sub(start) as f64 / 1e3);
                        e.weights
                            .push(telextiles_sensing::decide::contact_weight(c.depth));
                    }
                }
                Runner::Front(fe) => {
                    fe.reset(reference.as_deref());
                    let mut press_start = None;
                    for (i, f) in frames.iter().enumerate() {
                        let o = fe
                            .process(f)
                            .with_context(|| format!("{path}: frame {i}"))?;
                        if let Some(ContactEvent::PressStart { t_us }) = o.contact.event {
                            press_start.get_or_insert(t_us);
                        }
                        // The run's earlier frames, then this one.
                        let first = e.frames.is_empty();
                        let n = o.earlier.len();
                        let earlier =
                            o.earlier.iter().enumerate().map(|(k, x)| {
                                (i - (n - k), x.t_us, x.embedding.as_slice(), x.depth)
                            });
                        let this = o
                            .embedding
                            .map(|emb| (i, f.timestamp_us, emb, o.contact.depth));
                        for (j, t, emb, depth) in earlier.chain(this) {
                            e.dim = emb.len();
                            e.rows.extend_from_slice(emb);
                            e.frames.push(j);
                            let s = press_start.unwrap_or(t);
                            e.t_ms.push(t.saturating_sub(s) as f64 / 1e3);
                            e.weights
                                .push(telextiles_sensing::decide::contact_weight(depth));
                        }
                        if first {
                            e.early = n;
                        }
                    }
                }
            }
            out.methods.push(e);
        }
        Ok(out)
    }
}

/// What to run.
#[derive(Clone, Debug)]
pub struct StudyConfig {
    /// The recordings.
    pub dir: PathBuf,
    /// Index/query split.
    pub split: Split,
    /// Frames in contact per recording used as index frames and as
    /// per-frame queries (spread evenly; 0: all).
    pub frames_per_press: usize,
    /// ONNX Runtime threads per session while embedding.
    pub threads: usize,
    /// Recordings embedded at once (each worker with its own sessions; the
    /// results do not depend on it).
    pub workers: usize,
    /// Thread counts to time ONNX models with.
    pub time_threads: Vec<usize>,
    /// Timed frames per method and thread count (0: no timing).
    pub runs: usize,
    /// Decision times reported (ms since the press started).
    pub times_ms: Vec<f64>,
    /// The contact detector's tuning (the daemon's default).
    pub contact: ContactConfig,
    /// Encode the run of frames that starts each press too
    /// (`FrontEnd::set_encode_run`; off, as in the daemon).
    pub encode_run: bool,
    /// The decider's indexes learn a distance from their presses with this
    /// shrinkage, as `index build --presses` does by default
    /// (`IndexBuilder::metric_shrinkage`); None: cosine distance.
    pub metric: Option<f32>,
    /// Measure the unknown-textile flag on an open set (see
    /// [`OpenSetRow`]) with the decider's fixed distance and with a
    /// distance calibrated on each index's presses at each of these
    /// quantiles; empty (the default): not measured.
    pub unknown_quantiles: Vec<f32>,
    /// No-contact references for recordings that carry none
    /// (`--reference [SERIAL=]PNG`); empty: such recordings capture one
    /// from their first steady frames, as `classify` does.
    pub references: References,
    /// Frame rate of recordings saved without timestamps (`--fps`); None:
    /// the DIGIT's stream rate at their frames' size.
    pub fps: Option<f32>,
}

impl StudyConfig {
    /// Defaults for `dir` and `split`.
    pub fn new(dir: impl Into<PathBuf>, split: Split) -> StudyConfig {
        StudyConfig {
            dir: dir.into(),
            split,
            frames_per_press: 30,
            threads: 1,
            workers: 1,
            time_threads: vec![1],
            runs: 200,
            times_ms: vec![
                50.0, 100.0, 150.0, 200.0, 250.0, 300.0, 400.0, 500.0, 750.0, 1000.0, 1500.0,
                2000.0, 3000.0,
            ],
            contact: ContactConfig::default(),
            encode_run: false,
            metric: None,
            unknown_quantiles: Vec::new(),
            references: References::none(),
            fps: None,
        }
    }
}

/// One recording in the report.
#[derive(Clone, Debug, Serialize)]
pub struct RecordingRow {
    pub path: String,
    pub textile: String,
    pub sensor: String,
    pub frames: usize,
    pub fps: f64,
    pub contact_frames: usize,
    pub own_reference: bool,
    /// Replayed with the reference given for its sensor (`--reference`).
    pub given_reference: bool,
    /// "index", "query" (index-presses split) or "both" (leave one out);
    /// "skipped" when unusable.
    pub role: String,
    pub skipped: Option<String>,
}

/// Per textile, per press and per frame (one method).
#[derive(Clone, Debug, Serialize)]
pub struct ClassScore {
    pub textile: String,
    pub query_presses: usize,
    pub presses_correct: usize,
    pub query_frames: usize,
    pub frames_correct: usize,
}

/// One query recording's decision (one method).
#[derive(Clone, Debug, Serialize)]
pub struct PressDecision {
    /// Index into [`StudyReport::recordings`].
    pub recording: usize,
    pub truth: String,
    /// Nearest index frame to the press's mean embedding.
    pub knn: String,
    /// Nearest textile centroid.
    pub centroid: String,
    /// The daemon's decider at the end of the press ("-": undecided),
    /// against textile centroids.
    pub decider: String,
    /// The same against the index `index build --presses` makes by
    /// default (centroids and per-press exemplars).
    pub decider_exemplars: String,
    /// When its first decision came, ms since the press started.
    pub first_decision_ms: Option<f64>,
    /// Per-frame top-1 within this press.
    pub frame_top1: f64,
}

/// One method on recorded presses.
#[derive(Clone, Debug, Serialize)]
pub struct RecordedMethod {
    /// Name, view, timing and the headline accuracies (the simulator
    /// bench's record; `by_frames` is empty, see `by_time`).
    pub summary: MethodResult,
    /// Per press, nearest textile centroid.
    pub press_top1_centroid: f64,
    /// Per press, the daemon's decider (running mean against the
    /// centroids with its hysteresis, `telextiles_sensing::decide`) at the
    /// end of the press; an undecided press counts as wrong.
    pub press_top1_decider: f64,
    /// The same decider against the index `telextilesd index build
    /// --presses` makes by default: each textile's centroid and every
    /// index press's mean embedding (a textile as near as its nearest).
    pub press_top1_decider_exemplars: f64,
    /// Query presses (all of known textiles) whose final decision the
    /// decider flags unknown (`DecideConfig::unknown_distance`): against
    /// centroids, and against centroids and exemplars.
    pub unknown_flagged: usize,
    pub unknown_flagged_exemplars: usize,
    /// Median time of the decider's first decision, ms since the press
    /// started (decided presses).
    pub first_decision_ms: f64,
    /// Query presses the decider decided at all.
    pub decided_presses: usize,
    /// Changes of decision after the first, over all query presses.
    pub switches: usize,
    /// (ms since the press started, top-1 per press of the running mean).
    pub by_time: Vec<(f64, f64)>,
    /// Median over query presses of the time of their first embedded frame
    /// (ms since the press started): the earliest possible decision.
    pub first_frame_ms: f64,
    pub per_class: Vec<ClassScore>,
    /// Per press (kNN): `confusion[truth][predicted]`, in `textiles` order
    /// (a query the method embedded no frame of is undecided and not in it).
    pub confusion: Vec<Vec<usize>>,
    pub decisions: Vec<PressDecision>,
    /// The unknown-textile flag on an open set, one row per distance
    /// (`StudyConfig::unknown_quantiles`; empty when not measured).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub open_set: Vec<OpenSetRow>,
    /// How well two scores of a final decision tell the open set's unseen
    /// presses from its known ones, whatever the threshold (None when the
    /// open set is not measured).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub separation: Option<Separation>,
}

/// Threshold-free separation of the open set's known and unseen query
/// presses (see [`OpenSetRow`]): the area under the ROC curve, i.e. the
/// chance that a random unseen press scores higher than a random known
/// one (ties half). 0.5 is no separation, 1 perfect.
#[derive(Clone, Debug, Serialize)]
pub struct Separation {
    /// Scored by the final decision's distance `d1` (the decider's flag).
    pub distance_auroc: f64,
    /// Scored by `d1 / d2`, the distance over the nearest other textile's
    /// (`1 - confidence`): scale-free, the ratio test.
    pub ratio_auroc: f64,
    /// Decided presses scored: known, unseen.
    pub known: usize,
    pub unseen: usize,
}

/// The area under the ROC curve of `pos` against `neg` (higher scores
/// mean positive): P(pos > neg) + P(pos = neg) / 2. NaN when either is
/// empty.
pub fn auroc(neg: &[f64], pos: &[f64]) -> f64 {
    if neg.is_empty() || pos.is_empty() {
        return f64::NAN;
    }
    let mut sorted = neg.to_vec();
    sorted.sort_by(f64::total_cmp);
    let mut wins = 0.0;
    for &p in pos {
        let below = sorted.partition_point(|&n| n < p);
        let ties = sorted.partition_point(|&n| n <= p) - below;
        wins += below as f64 + ties as f64 / 2.0;
    }
    wins / (neg.len() * pos.len()) as f64
}

/// The decider's unknown-textile flag under one distance, against the
/// index `index build --presses` makes by default (centroids and
/// exemplars): how many known presses it flags (each query against the
/// study's index, as in the main table) and how many presses of a textile
/// the index does not have (each query again, against the index of the
/// other textiles' index presses, built, and calibrated, without it).
#[derive(Clone, Debug, Serialize)]
pub struct OpenSetRow {
    /// None: the decider's fixed `DecideConfig::unknown_distance`; else the
    /// quantile the index's distance was calibrated at.
    pub quantile: Option<f32>,
    /// Median distance used over the indexes (one index per query with
    /// leave one out, one per left-out textile for the unseen queries).
    pub median_distance_known: f64,
    pub median_distance_unseen: f64,
    /// Indexes that had too few presses to calibrate (the fixed distance
    /// was used instead).
    pub uncalibrated: usize,
    /// Known query presses decided, and flagged unknown.
    pub known_decided: usize,
    pub known_flagged: usize,
    /// Unseen query presses decided, and flagged unknown.
    pub unseen_decided: usize,
    pub unseen_flagged: usize,
}

/// Everything the study measured.
#[derive(Clone, Debug, Serialize)]
pub struct StudyReport {
    pub machine: String,
    pub date: String,
    pub command: String,
    pub source: String,
    pub layout: String,
    pub split: Split,
    pub split_text: String,
    pub frames_per_press: usize,
    /// The run of frames that starts each press was encoded too.
    #[serde(default)]
    pub encode_run: bool,
    /// The decider's indexes learned a distance with this shrinkage.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub index_metric: Option<f32>,
    /// The open-set measurement's quantiles (empty: not measured).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unknown_quantiles: Vec<f32>,
    /// Textiles (class order of the confusion matrices).
    pub textiles: Vec<String>,
    pub recordings: Vec<RecordingRow>,
    /// (fps rounded to 0.1, recordings).
    pub fps: Vec<(f64, usize)>,
    /// The frame budget the knee is judged by: one frame at the median
    /// recording frame rate.
    pub frame_budget_ms: f64,
    pub methods: Vec<RecordedMethod>,
    pub pareto: Vec<String>,
    pub knee: Option<String>,
    /// Methods given in detail in the markdown (models passed in, the
    /// best, the knee).
    pub featured: Vec<String>,
    pub seconds: Vec<(String, f64)>,
}

/// Loads and embeds every recording under `cfg.dir` (each alone, see the
/// module docs), reporting progress.
pub fn embed_all(
    cfg: &StudyConfig,
    methods: &[Method],
) -> Result<(Vec<RecordingRef>, Vec<Processed>)> {
    let refs = list_recordings(&cfg.dir, cfg.fps)?;
    let progress = telextiles_progress::Progress::new(
        &format!(
            "embedding with {} method{}",
            methods.len(),
            if methods.len() == 1 { "" } else { "s" }
        ),
        refs.len() as u64,
        "recordings",
    );
    let workers = cfg.workers.clamp(1, refs.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let slots: std::sync::Mutex<Vec<Option<Processed>>> =
        std::sync::Mutex::new(vec![None; refs.len()]);
    // Each worker takes the next recording; every recording is processed
    // alone (see the module docs), so the order does not matter.
    let work = || -> Result<()> {
        let mut proc = Processor::new(methods, cfg.threads, cfg.contact.clone())?;
        proc.set_encode_run(cfg.encode_run);
        proc.set_references(cfg.references.clone());
        loop {
            let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            let Some(r) = refs.get(i) else {
                return Ok(());
            };
            progress.set_message(&r.path.display().to_string());
            let press = r
                .load()
                .with_context(|| format!("cannot read {}", r.path.display()))?;
            let p = proc.process(&r.path.display().to_string(), press)?;
            if let Some(why) = &p.skipped {
                progress.println(&format!("skipping {}: {why}", r.path.display()));
            }
            slots.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(p);
            progress.inc(1);
        }
    };
    std::thread::scope(|sc| {
        let handles: Vec<_> = (0..workers).map(|_| sc.spawn(work)).collect();
        handles
            .into_iter()
            .map(|h| {
                h.join()
                    .unwrap_or_else(|_| Err(anyhow::anyhow!("a worker panicked")))
            })
            .collect::<Result<Vec<()>>>()
    })?;
    progress.finish();
    let out = slots
        .into_inner()
        .unwrap_or_else(|e| e.into_inner())
        .into_iter()
        .map(|p| p.context("a recording was not processed"))
        .collect::<Result<Vec<_>>>()?;
    Ok((refs, out))
}

/// Index rows of spread frames: (row data, press, class).
struct Bank {
    rows: Vec<f32>,
    press: Vec<usize>,
    class: Vec<u32>,
    dim: usize,
}

fn sample(n: usize, k: usize) -> Vec<usize> {
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
enum Role {
    Index,
    Query,
    /// Leave one out: query against the others, index for them.
    Both,
    Skipped,
}

fn roles(processed: &[Processed], class_of: &[u32], split: Split) -> Vec<Role> {
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

fn ratio(a: usize, b: usize) -> f64 {
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

/// The whole study: embed every recording, score, and (with `out`) write
/// `bench.json`, `report.md` and the charts there.
pub fn run(cfg: &StudyConfig, methods: &[Method], out: Option<&Path>) -> Result<StudyReport> {
    ensure!(!methods.is_empty(), "no methods to measure");
    let t = Instant::now();
    let (refs, processed) = embed_all(cfg, methods)?;
    let embed_s = t.elapsed().as_secs_f64();
    let mut r = score_all(cfg, methods, &refs, &processed)?;
    r.seconds
        .insert(0, ("reading and embedding".into(), embed_s));
    if let Some(out) = out {
        write(&r, out)?;
    }
    Ok(r)
}

fn pct(x: f64) -> String {
    if x.is_finite() {
        format!("{:.1}%", 100.0 * x)
    } else {
        "-".into()
    }
}

/// Writes `bench.json`, `report.md`, `speed-accuracy.svg`,
/// `decision-time.svg` and `confusion-<method>.svg` (featured methods) into
/// `out`.
pub fn write(r: &StudyReport, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    crate::data::write_atomic(
        &out.join("bench.json"),
        serde_json::to_string_pretty(r)?.as_bytes(),
    )?;
    let summaries: Vec<MethodResult> = r.methods.iter().map(|m| m.summary.clone()).collect();
    if summaries.iter().any(|s| !s.latency.is_empty()) {
        methods::chart_with(
            &summaries,
            &out.join("speed-accuracy.svg"),
            "Accuracy against speed (recorded presses, kNN top-1 per press)",
            r.frame_budget_ms,
            "knee of the frontier",
        )?;
    }
    time_chart(r, &out.join("decision-time.svg"))?;
    for m in r
        .methods
        .iter()
        .filter(|m| r.featured.contains(&m.summary.name))
    {
        confusion_chart(
            r,
            m,
            &out.join(format!("confusion-{}.svg", file_name(&m.summary.name))),
        )?;
    }
    crate::data::write_atomic(&out.join("report.md"), markdown(r).as_bytes())?;
    Ok(())
}

/// A method name as a file name.
pub fn file_name(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// The report's tables.
pub fn markdown(r: &StudyReport) -> String {
    let mut s = String::new();
    let used = r.recordings.iter().filter(|x| x.skipped.is_none()).count();
    let idx = r.recordings.iter().filter(|x| x.role == "index").count();
    let q = r
        .recordings
        .iter()
        .filter(|x| x.role == "query" || x.role == "both")
        .count();
    let roles = if r.split == Split::Lopo {
        format!("each a query against the other {}", used.saturating_sub(1))
    } else {
        format!("{idx} index, {q} queries")
    };
    s.push_str(&format!(
        "# The study on recorded presses\n\nGenerated by `{}` on {} ({}).\n\nRecordings: `{}` ({} layout): {} recordings of {} textiles, {} used ({}). Split: {}. Frame rates (from the recordings' timestamps): {}. Index: up to {} frames in contact per recording; per-frame queries: the same number per query recording. Every recording is processed alone with its own no-contact reference{}.\n\n",
        r.command,
        r.date,
        r.machine,
        r.source,
        r.layout,
        r.recordings.len(),
        r.textiles.len(),
        used,
        roles,
        r.split_text,
        r.fps
            .iter()
            .map(|(f, n)| format!("{f} fps ({n})"))
            .collect::<Vec<_>>()
            .join(", "),
        if r.frames_per_press == 0 {
            "all".to_string()
        } else {
            r.frames_per_press.to_string()
        },
        if r.encode_run {
            "; the run of frames that starts each press is encoded too (`--encode-run`: embeddings and decisions begin at the press's first frame over the contact threshold, not on the frame the detector starts it on)"
        } else {
            ""
        },
    ));
    let given = r.recordings.iter().filter(|x| x.given_reference).count();
    if given > 0 {
        s.push_str(&format!(
            "{given} of {} recordings carry no reference and were replayed with the no-contact frame given for their sensor (`--reference`).\n\n",
            r.recordings.len()
        ));
    }
    s.push_str(&match r.index_metric {
        Some(a) => format!("The decider's indexes learn a distance from their presses (`--index-metric {a}`: within-fabric whitening, shrinkage {a}, as `telextilesd index build --presses` does by default).\n\n"),
        None => "The decider's indexes use cosine distance (no `--index-metric`; `telextilesd index build --presses --no-metric`).\n\n".into(),
    });
    let skipped: Vec<&RecordingRow> = r
        .recordings
        .iter()
        .filter(|x| x.skipped.is_some())
        .collect();
    if !skipped.is_empty() {
        s.push_str("Skipped recordings:\n\n");
        for x in skipped {
            s.push_str(&format!(
                "* `{}`: {}\n",
                x.path,
                x.skipped.as_deref().unwrap_or("")
            ));
        }
        s.push('\n');
    }
    s.push_str("## Methods\n\n");
    let summaries: Vec<MethodResult> = r.methods.iter().map(|m| m.summary.clone()).collect();
    s.push_str(&methods::markdown_within(&summaries, r.frame_budget_ms));
    s.push_str(&format!(
        "\nPareto frontier: {}. Knee (one frame at {:.0} fps = {:.1} ms as the budget): **{}**. Timing: one frame in contact of the first recording, batch 1.\n\n",
        r.pareto.join(", "),
        1000.0 / r.frame_budget_ms,
        r.frame_budget_ms,
        r.knee.as_deref().unwrap_or("-")
    ));
    s.push_str("Per press, by decision rule (query presses: ");
    s.push_str(
        &r.methods
            .first()
            .map_or(0, |m| m.summary.presses)
            .to_string(),
    );
    s.push_str("). \"decider\": the daemon's decider (`telextiles-sensing`: running mean against the index, with its hysteresis) at the end of the press, an undecided press counted wrong; against textile centroids, and against the index `telextilesd index build --presses` makes by default (centroids and every index press's mean embedding, a textile as near as its nearest); \"unknown\": query presses (all of known textiles) whose final decision is flagged unknown; \"first decision\" and \"switches\": the decider against centroids, median ms from the press start to its first decision.\n\n| method | top-1 per frame | per press, nearest index frame | per press, nearest textile centroid | decider, centroids | unknown | decider, centroids + exemplars | unknown | first decision | decided | switches |\n|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
    for m in &r.methods {
        s.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} | {} | {}/{} | {} |\n",
            m.summary.name,
            pct(m.summary.frame_top1),
            pct(m.summary.press_top1),
            pct(m.press_top1_centroid),
            pct(m.press_top1_decider),
            m.unknown_flagged,
            pct(m.press_top1_decider_exemplars),
            m.unknown_flagged_exemplars,
            if m.first_decision_ms.is_finite() {
                format!("{:.0} ms", m.first_decision_ms)
            } else {
                "-".into()
            },
            m.decided_presses,
            m.summary.presses,
            m.switches
        ));
    }
    if r.methods.iter().any(|m| !m.open_set.is_empty()) {
        s.push_str(&open_set_markdown(r));
    }
    // Against time.
    let cols: Vec<f64> = [50.0, 100.0, 250.0, 500.0, 1000.0]
        .into_iter()
        .filter(|t| {
            r.methods
                .first()
                .is_some_and(|m| m.by_time.iter().any(|x| x.0 == *t))
        })
        .collect();
    s.push_str("\n## Accuracy against time since first contact\n\nRunning mean of the frames in contact up to T ms after the press started (the recording's own timestamps), each frame weighted by its contact depth as the daemon's decider weights it, nearest index frame; a press without a frame in contact by T counts as wrong. \"first frame\": median time of the first frame in contact (the contact detector needs a few frames over threshold).\n\n| method | first frame |");
    for t in &cols {
        s.push_str(&format!(" {t:.0} ms |"));
    }
    s.push_str(" whole press |\n|---|---:|");
    for _ in &cols {
        s.push_str("---:|");
    }
    s.push_str("---:|\n");
    for m in &r.methods {
        s.push_str(&format!(
            "| {} | {} |",
            m.summary.name,
            if m.first_frame_ms.is_finite() {
                format!("{:.0} ms", m.first_frame_ms)
            } else {
                "-".into()
            }
        ));
        for t in &cols {
            let v = m
                .by_time
                .iter()
                .find(|x| x.0 == *t)
                .map_or(f64::NAN, |x| x.1);
            s.push_str(&format!(" {} |", pct(v)));
        }
        s.push_str(&format!(" {} |\n", pct(m.summary.press_top1)));
    }
    // Featured methods in detail.
    let featured: Vec<&RecordedMethod> = r
        .methods
        .iter()
        .filter(|m| r.featured.contains(&m.summary.name))
        .collect();
    if !featured.is_empty() {
        s.push_str("\n## Per textile\n\nQuery presses right (per press, nearest index frame) and frames right, for ");
        s.push_str(
            &featured
                .iter()
                .map(|m| format!("`{}`", m.summary.name))
                .collect::<Vec<_>>()
                .join(", "),
        );
        s.push_str(" (the models given, the most accurate method and the knee).\n\n| textile | query presses |");
        for m in &featured {
            s.push_str(&format!(" {} presses | frames |", m.summary.name));
        }
        s.push_str("\n|---|---:|");
        for _ in &featured {
            s.push_str("---:|---:|");
        }
        s.push('\n');
        for (c, t) in r.textiles.iter().enumerate() {
            let n = featured[0].per_class[c].query_presses;
            s.push_str(&format!("| {t} | {n} |"));
            for m in &featured {
                let pc = &m.per_class[c];
                s.push_str(&format!(
                    " {}/{} | {} |",
                    pc.presses_correct,
                    pc.query_presses,
                    pct(ratio(pc.frames_correct, pc.query_frames))
                ));
            }
            s.push('\n');
        }
        for m in &featured {
            s.push_str(&format!(
                "\n### Confusion, {} (per press; rows: true textile, columns: decided)\n\n",
                m.summary.name
            ));
            s.push_str(&confusion_markdown(&r.textiles, &m.confusion));
        }
        s.push_str("\n## Per recording\n\n| recording | textile | sensor | fps | frames | in contact | role |");
        for m in &featured {
            s.push_str(&format!(" {} |", m.summary.name));
        }
        s.push_str("\n|---|---|---|---:|---:|---:|---|");
        for _ in &featured {
            s.push_str("---|");
        }
        s.push('\n');
        for (i, x) in r.recordings.iter().enumerate() {
            s.push_str(&format!(
                "| {} | {} | {} | {:.1} | {} | {} | {} |",
                x.path, x.textile, x.sensor, x.fps, x.frames, x.contact_frames, x.role
            ));
            for m in &featured {
                let cell =
                    m.decisions
                        .iter()
                        .find(|d| d.recording == i)
                        .map_or(String::new(), |d| {
                            format!(
                                "{} {} ({} of frames)",
                                if d.knn == d.truth { "✓" } else { "✗" },
                                d.knn,
                                pct(d.frame_top1)
                            )
                        });
                s.push_str(&format!(" {cell} |"));
            }
            s.push('\n');
        }
    }
    s.push_str("\n## Run time\n\n| part | s |\n|---|---:|\n");
    for (p, t) in &r.seconds {
        s.push_str(&format!("| {p} | {t:.1} |\n"));
    }
    s
}

/// The open-set section (`--unknown-quantiles`).
fn open_set_markdown(r: &StudyReport) -> String {
    let fixed = DecideConfig::default().unknown_distance;
    let mut s = format!(
        "\n## Unknown textiles: the flag on an open set\n\nThe decider against the index `index build --presses` makes by default (centroids and exemplars), final decision of each press. \"known\": every query press against the study's index (its textile is in it), flagged unknown: a false alarm. \"unseen\": every query press again, against the index of the other textiles' index presses, built (and calibrated) without its textile, flagged unknown: a detection. Distances: the decider's fixed {fixed}, or the index's own calibrated on its presses at quantile q (`index build --presses --unknown-quantile q`: the q quantile of each index press's distance to its textile's entry, with the presses of one fold of every textile left out and the index and its metric made again without them); \"distance\": its median over the indexes (known / unseen); \"uncalibrated\": indexes with too few presses to calibrate, which keep the fixed distance.\n\n| method | distance | median distance (known / unseen) | known flagged | unseen flagged | uncalibrated |\n|---|---|---:|---:|---:|---:|\n"
    );
    for m in &r.methods {
        for row in &m.open_set {
            s.push_str(&format!(
                "| {} | {} | {:.3} / {:.3} | {} of {} ({}) | {} of {} ({}) | {} |\n",
                m.summary.name,
                match row.quantile {
                    None => format!("fixed {fixed}"),
                    Some(q) => format!("calibrated, q = {q}"),
                },
                row.median_distance_known,
                row.median_distance_unseen,
                row.known_flagged,
                row.known_decided,
                pct(ratio(row.known_flagged, row.known_decided)),
                row.unseen_flagged,
                row.unseen_decided,
                pct(ratio(row.unseen_flagged, row.unseen_decided)),
                row.uncalibrated,
            ));
        }
    }
    s.push_str("\nWhatever the threshold: the area under the ROC curve of the known against the unseen decided presses (the chance that an unseen press scores higher than a known one; 0.5 no separation, 1 perfect), scored by the final decision's distance d1 (what the flag thresholds) and by the ratio test d1 / d2 (d2: the nearest other textile's distance).\n\n| method | decided presses (known / unseen) | AUROC by d1 | AUROC by d1 / d2 |\n|---|---:|---:|---:|\n");
    for m in &r.methods {
        if let Some(x) = &m.separation {
            s.push_str(&format!(
                "| {} | {} / {} | {:.3} | {:.3} |\n",
                m.summary.name, x.known, x.unseen, x.distance_auroc, x.ratio_auroc
            ));
        }
    }
    s
}

/// A confusion matrix as a markdown table (up to 20 textiles), else the
/// most frequent confusions.
pub fn confusion_markdown(textiles: &[String], m: &[Vec<usize>]) -> String {
    let mut s = String::new();
    if textiles.len() <= 20 {
        s.push_str("| true \\ decided |");
        for t in textiles {
            s.push_str(&format!(" {t} |"));
        }
        s.push_str(" queries |\n|---|");
        for _ in textiles {
            s.push_str("---:|");
        }
        s.push_str("---:|\n");
        for (t, row) in textiles.iter().zip(m) {
            s.push_str(&format!("| {t} |"));
            for (j, v) in row.iter().enumerate() {
                if *v > 0 && textiles[j] == *t {
                    s.push_str(&format!(" **{v}** |"));
                } else if *v > 0 {
                    s.push_str(&format!(" {v} |"));
                } else {
                    s.push_str(" · |");
                }
            }
            s.push_str(&format!(" {} |\n", row.iter().sum::<usize>()));
        }
    } else {
        let mut pairs: Vec<(usize, usize, usize)> = Vec::new();
        for (i, row) in m.iter().enumerate() {
            for (j, &v) in row.iter().enumerate() {
                if i != j && v > 0 {
                    pairs.push((v, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| b.0.cmp(&a.0).then(a.1.cmp(&b.1)));
        s.push_str(&format!(
            "{} textiles (too many for a table; the full matrix is in bench.json). Most frequent confusions:\n\n| true | decided | presses |\n|---|---|---:|\n",
            textiles.len()
        ));
        for (v, i, j) in pairs.into_iter().take(30) {
            s.push_str(&format!("| {} | {} | {v} |\n", textiles[i], textiles[j]));
        }
    }
    s
}

fn chart_err<E: std::fmt::Display>(x: E) -> anyhow::Error {
    anyhow::anyhow!("chart: {x}")
}

/// Top-1 per press against ms since the press started.
fn time_chart(r: &StudyReport, svg: &Path) -> Result<()> {
    use plotters::prelude::*;
    let e = chart_err;
    let root = SVGBackend::new(svg, (1000, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(e)?;
    let xmax = r
        .methods
        .iter()
        .flat_map(|m| m.by_time.iter().map(|x| x.0))
        .fold(100.0, f64::max);
    let mut c = ChartBuilder::on(&root)
        .caption(
            "Accuracy against time since first contact (recorded presses, running mean)",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(0.0..xmax, 0.0..100.0)
        .map_err(e)?;
    c.configure_mesh()
        .x_desc("ms since the press started (recordings' own timestamps)")
        .y_desc("top-1 per press, %")
        .draw()
        .map_err(e)?;
    let shown: Vec<&RecordedMethod> = r
        .methods
        .iter()
        .filter(|m| r.featured.contains(&m.summary.name) || r.pareto.contains(&m.summary.name))
        .collect();
    for (i, m) in shown.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        c.draw_series(LineSeries::new(
            m.by_time
                .iter()
                .filter(|x| x.1.is_finite())
                .map(|&(t, a)| (t, 100.0 * a)),
            color.stroke_width(2),
        ))
        .map_err(e)?
        .label(m.summary.name.clone())
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
    }
    c.configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(SeriesLabelPosition::LowerRight)
        .draw()
        .map_err(e)?;
    root.present().map_err(e)?;
    Ok(())
}

/// The confusion matrix as a heat map (row-normalised).
fn confusion_chart(r: &StudyReport, m: &RecordedMethod, svg: &Path) -> Result<()> {
    use plotters::coord::ranged1d::SegmentValue;
    use plotters::prelude::*;
    let e = chart_err;
    let n = r.textiles.len();
    if n < 2 {
        return Ok(());
    }
    let side = (60 + 28 * n as u32).clamp(400, 1400);
    let root = SVGBackend::new(svg, (side + 120, side + 60)).into_drawing_area();
    root.fill(&WHITE).map_err(e)?;
    let mut c = ChartBuilder::on(&root)
        .caption(
            format!("Confusion per press, {} (row share)", m.summary.name),
            ("sans-serif", 16),
        )
        .margin(10)
        .x_label_area_size(70)
        .y_label_area_size(90)
        // A segmented 0..k has k + 1 segments.
        .build_cartesian_2d((0..n - 1).into_segmented(), (0..n - 1).into_segmented())
        .map_err(e)?;
    // Row 0 (the first textile) at the top.
    let label = |v: &SegmentValue<usize>, flip: bool| match v {
        SegmentValue::CenterOf(i) => {
            let k = if flip {
                (n - 1).checked_sub(*i)
            } else {
                Some(*i)
            };
            k.and_then(|k| r.textiles.get(k))
                .cloned()
                .unwrap_or_default()
        }
        _ => String::new(),
    };
    c.configure_mesh()
        .disable_mesh()
        .x_labels(n)
        .y_labels(n)
        .x_label_formatter(&|v| label(v, false))
        .y_label_formatter(&|v| label(v, true))
        .x_desc("decided")
        .y_desc("true")
        .draw()
        .map_err(e)?;
    for (i, row) in m.confusion.iter().enumerate() {
        let total = row.iter().sum::<usize>().max(1) as f64;
        let y = n - 1 - i;
        for (j, &v) in row.iter().enumerate() {
            let share = v as f64 / total;
            c.draw_series(std::iter::once(Rectangle::new(
                [
                    (SegmentValue::Exact(j), SegmentValue::Exact(y)),
                    (SegmentValue::Exact(j + 1), SegmentValue::Exact(y + 1)),
                ],
                BLUE.mix(share.max(0.02)).filled(),
            )))
            .map_err(e)?;
        }
    }
    root.present().map_err(e)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::SourceKind;

    #[test]
    fn sources_parse() {
        assert_eq!(
            "sim".parse::<Source>().unwrap(),
            Source::Builtin(SourceKind::Sim)
        );
        assert_eq!(
            "presses:rec/a".parse::<Source>().unwrap(),
            Source::Presses(PathBuf::from("rec/a"))
        );
        assert!("presses:".parse::<Source>().is_err());
        assert!("digit"
            .parse::<Source>()
            .unwrap_err()
            .contains("presses:<dir>"));
    }

    #[test]
    fn frame_rate_comes_from_the_timestamps() {
        let t25: Vec<u64> = (0..50).map(|i| i * 40_000).collect();
        assert!((fps_of(&t25) - 25.0).abs() < 1e-9);
        // A dropped frame does not move the median interval.
        let mut t60: Vec<u64> = (0..60).map(|i| (i * 1_000_000 + 30) / 60).collect();
        t60.remove(30);
        assert!((fps_of(&t60) - 60.0).abs() < 0.1, "{}", fps_of(&t60));
        assert!(fps_of(&[0]).is_nan());
    }

    fn processed(textile: &str, skipped: bool) -> Processed {
        Processed {
            path: String::new(),
            textile: textile.into(),
            sensor: String::new(),
            frames: 0,
            fps: 60.0,
            contact_frames: 0,
            own_reference: true,
            given_reference: false,
            skipped: skipped.then(|| "no frame in contact".into()),
            methods: Vec::new(),
        }
    }

    #[test]
    fn the_first_k_usable_recordings_of_each_textile_build_the_index() {
        let p: Vec<Processed> = [
            ("a", false),
            ("b", false),
            ("a", true),
            ("a", false),
            ("a", false),
            ("b", false),
        ]
        .iter()
        .map(|&(t, s)| processed(t, s))
        .collect();
        let class: Vec<u32> = p.iter().map(|x| (x.textile == "b") as u32).collect();
        use Role::*;
        assert_eq!(
            roles(&p, &class, Split::IndexPresses(2)),
            [Index, Index, Skipped, Index, Query, Index]
        );
        assert_eq!(
            roles(&p, &class, Split::Lopo),
            [Both, Both, Skipped, Both, Both, Both]
        );
        assert_eq!(sample(5, 0), [0, 1, 2, 3, 4]);
        assert_eq!(sample(3, 30), [0, 1, 2]);
        assert_eq!(sample(100, 4).len(), 4);
    }

    fn embedded(textile: &str, rows: &[[f32; 2]]) -> Processed {
        let mut p = processed(textile, false);
        let mut e = PressEmbedding {
            dim: 2,
            ..Default::default()
        };
        for (k, r) in rows.iter().enumerate() {
            let n = (r[0] * r[0] + r[1] * r[1]).sqrt();
            e.rows.extend([r[0] / n, r[1] / n]);
            e.frames.push(k);
            e.t_ms.push(k as f64 * 40.0);
        }
        p.contact_frames = rows.len();
        p.methods = vec![e];
        p
    }

    /// One method for studies of given embeddings (which method does not
    /// matter: `score_all` only reads the embeddings).
    fn one_method() -> Vec<Method> {
        vec![Method::Rust {
            base: Baseline {
                kind: crate::baselines::BaselineKind::Lbp,
                bgsub: false,
            },
            crop: 64,
        }]
    }

    #[test]
    fn scores_from_known_embeddings() {
        // Two textiles along the axes; a's query leans towards a, b's
        // query had no frame embedded (undecided: wrong, not confused).
        let a = [[1.0, 0.0]; 5];
        let b = [[0.0, 1.0]; 5];
        let processed = vec![
            embedded("a", &a),
            embedded("a", &a),
            embedded("a", &[[0.9, 0.3]; 10]),
            embedded("b", &b),
            embedded("b", &b),
            embedded("b", &[]),
        ];
        let methods = one_method();
        let mut cfg = StudyConfig::new("unused", Split::IndexPresses(2));
        cfg.runs = 0;
        let r = score_all(&cfg, &methods, &[], &processed).unwrap();
        let m = &r.methods[0];
        assert_eq!(m.summary.presses, 2);
        assert_eq!(m.summary.press_top1, 0.5);
        assert_eq!(m.press_top1_centroid, 0.5);
        assert_eq!(m.summary.frame_top1, 1.0);
        assert_eq!(m.summary.queries, 10);
        assert_eq!(m.confusion, vec![vec![1, 0], vec![0, 0]]);
        assert_eq!(m.per_class[1].query_presses, 1);
        assert_eq!(m.per_class[1].presses_correct, 0);
        // The decider decides a's query on its second frame (frames 40 ms
        // apart): a leads b by more than `commit_margin`, so it does not
        // wait `confirm_ms` (`min_ms` is 0).
        assert_eq!(m.decisions[0].decider, "a");
        let t = m.decisions[0].first_decision_ms.unwrap();
        let c = DecideConfig::default();
        assert!(c.min_ms == 0.0 && c.confirm_ms > 40.0 && c.commit_margin < 0.5);
        assert_eq!(t, 40.0);
        assert_eq!(m.decisions[1].decider, "-");
        assert_eq!(m.decided_presses, 1);
        assert_eq!(m.press_top1_decider, 0.5);
        // Against time: a's query is right from its first frame (0 ms).
        assert!(m.by_time.iter().all(|x| x.1 == 0.5), "{:?}", m.by_time);
        // Leave one out: six queries; the empty one is never an index press.
        cfg.split = Split::Lopo;
        let r = score_all(&cfg, &methods, &[], &processed).unwrap();
        let m = &r.methods[0];
        assert_eq!(m.summary.presses, 6);
        assert_eq!(m.summary.press_top1, 5.0 / 6.0);
    }

    #[test]
    fn the_decider_runs_against_centroids_and_against_press_exemplars() {
        // Textile a: index presses at 0° and 80° (centroid at 40°);
        // textile b: two at 60°. a's query at 75° is nearest b's centroid
        // and a's press at 80°; b's query at 100° is nearest b's centroid
        // (40° away: further than the unknown distance, 0.5 ≈ 29°) and
        // a's press at 80° (20°).
        let at = |deg: f32| [deg.to_radians().cos(), deg.to_radians().sin()];
        let processed = vec![
            embedded("a", &[at(0.0); 5]),
            embedded("a", &[at(80.0); 5]),
            embedded("a", &[at(75.0); 10]),
            embedded("b", &[at(60.0); 5]),
            embedded("b", &[at(60.0); 5]),
            embedded("b", &[at(100.0); 10]),
        ];
        let methods = one_method();
        let mut cfg = StudyConfig::new("unused", Split::IndexPresses(2));
        cfg.runs = 0;
        let r = score_all(&cfg, &methods, &[], &processed).unwrap();
        let m = &r.methods[0];
        let by: Vec<(&str, &str, &str)> = m
            .decisions
            .iter()
            .map(|d| {
                (
                    d.truth.as_str(),
                    d.decider.as_str(),
                    d.decider_exemplars.as_str(),
                )
            })
            .collect();
        assert_eq!(by, vec![("a", "b", "a"), ("b", "b", "a")]);
        assert_eq!(m.press_top1_decider, 0.5);
        assert_eq!(m.press_top1_decider_exemplars, 0.5);
        assert_eq!((m.unknown_flagged, m.unknown_flagged_exemplars), (1, 0));
        let md = markdown(&r);
        assert!(md.contains("| 50.0% | 1 | 50.0% | 0 |"), "{md}");
    }

    #[test]
    fn the_decider_s_indexes_learn_a_distance_with_index_metric() {
        // Presses of a and of b differ along y, c's a little along x: a's
        // query leans along y, towards c in cosine distance. The distance
        // learned from the index presses scales y down: a.
        let processed = vec![
            embedded("a", &[[1.0, 0.5]; 5]),
            embedded("a", &[[1.0, -0.5]; 5]),
            embedded("a", &[[0.35, 1.0]; 10]),
            embedded("b", &[[-1.0, 0.5]; 5]),
            embedded("b", &[[-1.0, -0.5]; 5]),
            embedded("b", &[[-1.0, 0.1]; 10]),
            embedded("c", &[[0.1, 1.0]; 5]),
            embedded("c", &[[-0.1, 1.0]; 5]),
            embedded("c", &[[0.0, 1.0]; 10]),
        ];
        let methods = one_method();
        let mut cfg = StudyConfig::new("unused", Split::IndexPresses(2));
        cfg.runs = 0;
        let decided = |cfg: &StudyConfig| {
            let r = score_all(cfg, &methods, &[], &processed).unwrap();
            let d: Vec<(String, String)> = r.methods[0]
                .decisions
                .iter()
                .map(|d| (d.decider.clone(), d.decider_exemplars.clone()))
                .collect();
            (d, markdown(&r), r.index_metric)
        };
        let (cosine, md, metric) = decided(&cfg);
        assert_eq!(cosine[0], ("c".into(), "c".into()));
        assert_eq!(metric, None);
        assert!(md.contains("use cosine distance"), "{md}");
        cfg.metric = Some(0.1);
        let (learned, md, metric) = decided(&cfg);
        assert_eq!(learned[0], ("a".into(), "a".into()));
        assert_eq!(&learned[1..], &cosine[1..]);
        assert_eq!(metric, Some(0.1));
        assert!(md.contains("`--index-metric 0.1`"), "{md}");
    }

    #[test]
    fn the_open_set_counts_false_alarms_and_detections_per_distance() {
        // Three textiles 20° apart, index presses 4° apart around each,
        // a query 1° off each centre. Each query is known to the study's
        // index (1° from a press); left out, its textile's query is 17°
        // from the nearest press of another (chord 0.30): within the fixed
        // 0.5, beyond the distance calibrated on the presses (chord of 4°).
        let at = |deg: f32| [deg.to_radians().cos(), deg.to_radians().sin()];
        let mut processed = Vec::new();
        for (t, c) in [("a", 0.0), ("b", 20.0), ("c", 40.0)] {
            processed.push(embedded(t, &[at(c - 2.0); 5]));
            processed.push(embedded(t, &[at(c + 2.0); 5]));
            processed.push(embedded(t, &[at(c + 1.0); 10]));
        }
        let methods = one_method();
        let mut cfg = StudyConfig::new("unused", Split::IndexPresses(2));
        cfg.runs = 0;
        let r = score_all(&cfg, &methods, &[], &processed).unwrap();
        assert!(r.methods[0].open_set.is_empty());
        assert!(r.methods[0].separation.is_none());
        assert!(!markdown(&r).contains("open set"));
        cfg.unknown_quantiles = vec![0.5, 1.0];
        let r = score_all(&cfg, &methods, &[], &processed).unwrap();
        let m = &r.methods[0];
        let rows: Vec<(Option<f32>, usize, usize, usize, usize, usize)> = m
            .open_set
            .iter()
            .map(|x| {
                (
                    x.quantile,
                    x.known_flagged,
                    x.known_decided,
                    x.unseen_flagged,
                    x.unseen_decided,
                    x.uncalibrated,
                )
            })
            .collect();
        assert_eq!(
            rows,
            vec![
                (None, 0, 3, 0, 3, 0),
                (Some(0.5), 0, 3, 3, 3, 0),
                (Some(1.0), 0, 3, 3, 3, 0)
            ]
        );
        // The fixed row is the main table's count.
        assert_eq!(m.unknown_flagged_exemplars, 0);
        let chord4 = 2.0 * (2f64.to_radians()).sin();
        let t = m.open_set[2].median_distance_known;
        assert!((t - chord4).abs() < 1e-4, "{t}");
        assert_eq!(m.open_set[0].median_distance_unseen, 0.5);
        // Every unseen press is farther than every known one, both ways.
        let sep = m.separation.as_ref().unwrap();
        assert_eq!((sep.known, sep.unseen), (3, 3));
        assert_eq!((sep.distance_auroc, sep.ratio_auroc), (1.0, 1.0));
        assert_eq!(r.unknown_quantiles, vec![0.5, 1.0]);
        let md = markdown(&r);
        assert!(md.contains("open set"), "{md}");
        assert!(
            md.contains(
                "| calibrated, q = 1 | 0.070 / 0.070 | 0 of 3 (0.0%) | 3 of 3 (100.0%) | 0 |"
            ),
            "{md}"
        );
        assert!(md.contains("| 3 / 3 | 1.000 | 1.000 |"), "{md}");
    }

    #[test]
    fn auroc_is_the_chance_a_positive_outscores_a_negative() {
        assert_eq!(auroc(&[0.1, 0.2], &[0.3, 0.4]), 1.0);
        assert_eq!(auroc(&[0.3, 0.4], &[0.1, 0.2]), 0.0);
        // Ties count half: 0.2 beats 0.1, ties 0.2, loses to 0.3.
        assert_eq!(auroc(&[0.1, 0.2, 0.3], &[0.2]), 0.5);
        assert_eq!(auroc(&[0.1, 0.3], &[0.2, 0.4]), 0.75);
        assert!(auroc(&[], &[0.1]).is_nan());
    }

    #[test]
    fn confusion_tables_list_the_worst_pairs_when_large() {
        let small = vec!["a".to_string(), "b".to_string()];
        let t = confusion_markdown(&small, &[vec![3, 1], vec![0, 2]]);
        assert!(t.contains("| a | **3** | 1 | 4 |"), "{t}");
        assert!(t.contains("| b | · | **2** | 2 |"), "{t}");
        let many: Vec<String> = (0..21).map(|i| format!("t{i}")).collect();
        let mut m = vec![vec![0; 21]; 21];
        m[3][7] = 2;
        m[5][5] = 4;
        let t = confusion_markdown(&many, &m);
        assert!(t.contains("| t3 | t7 | 2 |"), "{t}");
        assert!(!t.contains("| t5 | t5 |"), "{t}");
    }
}
