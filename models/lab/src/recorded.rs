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

use crate::preprocess::reference_image;
use anyhow::{ensure, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

use telextiles_sensing::contact::{ContactConfig, ContactEvent};
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sensing::frame::Frame;
use telextiles_sensing::front::{self, FrontEnd, References};
use telextiles_sim::recording;
use telextiles_sim::Press;

use crate::baselines::Baseline;
use crate::methods::{Method, MethodResult};
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
/// timestamps spaced at `fps` when given, of `sensor` when given (else
/// their own, or a DIGIT's: `Recording::assume_sensor`).
pub fn list_recordings(
    dir: &Path,
    fps: Option<f32>,
    sensor: Option<recording::Sensor>,
) -> Result<Vec<RecordingRef>> {
    ensure!(dir.is_dir(), "{} is not a directory", dir.display());
    let mut found = recording::find_recordings_at(dir, fps)?;
    recording::assume_sensor(&mut found, sensor)?;
    found
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
            .map(|(i, (image, &t))| Frame::new(image, t, i as u64))
            .collect::<Result<_, _>>()?;
        for r in &mut self.runners {
            let mut e = PressEmbedding::default();
            match r {
                Runner::Rust { base, crop } => {
                    if !views.contains_key(crop) {
                        let rv = centre_crop_resize(&ref_img, *crop, *crop)?;
                        let fv = seg
                            .contact
                            .iter()
                            .map(|c| centre_crop_resize(frames[c.index].image(), *crop, *crop))
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
                            .map(|emb| (i, f.timestamp_us(), emb, o.contact.depth));
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
    /// The sensor of recordings that do not name theirs
    /// (`--sensor-profile`); None: their own, else a DIGIT.
    pub sensor: Option<recording::Sensor>,
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
            sensor: None,
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
    let refs = list_recordings(&cfg.dir, cfg.fps, cfg.sensor)?;
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::SourceKind;
    use crate::recorded_report::{confusion_markdown, markdown};
    use crate::recorded_score::*;
    use telextiles_sensing::decide::DecideConfig;

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
