//! The whole per-frame path: the front end ([`crate::front`]: contact
//! detection and the reference → only while in contact preprocess →
//! encode) → index search → decide, with per-stage timings.

use std::time::Instant;

use crate::contact::{ContactConfig, ContactEvent, EndReason};
use crate::decide::{DecideConfig, DecideStep, Decider, PressOutcome, TextileIndex};
use crate::encoder::{Encoder, EncoderError};
use crate::frame::Frame;
use crate::front::FrontEnd;

/// Stages timed per frame.
pub const STAGES: [&str; 6] = [
    "decode",
    "contact",
    "preprocess",
    "encode",
    "search",
    "decide",
];

/// Nanoseconds spent per stage on one frame (0 for stages not run).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StageTimes {
    /// Obtaining and decoding the frame (filled in by whoever reads the source).
    pub decode_ns: u64,
    /// Contact detection.
    pub contact_ns: u64,
    /// Crop, resize, normalise.
    pub preprocess_ns: u64,
    /// ONNX inference and L2 normalisation.
    pub encode_ns: u64,
    /// Running mean and nearest-textile search.
    pub search_ns: u64,
    /// Hysteresis.
    pub decide_ns: u64,
}

impl StageTimes {
    /// Per stage, in [`STAGES`] order.
    pub fn as_array(&self) -> [u64; 6] {
        [
            self.decode_ns,
            self.contact_ns,
            self.preprocess_ns,
            self.encode_ns,
            self.search_ns,
            self.decide_ns,
        ]
    }
    /// Sum over stages.
    pub fn total_ns(&self) -> u64 {
        self.as_array().iter().sum()
    }
}

/// Collects stage times and reports percentiles.
#[derive(Clone, Debug, Default)]
pub struct StageStats {
    samples: [Vec<u64>; 6],
    totals: Vec<u64>,
}

/// Percentiles of one stage, in milliseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct StageSummary {
    /// Frames in which the stage ran.
    pub frames: usize,
    /// Median.
    pub p50_ms: f64,
    /// 90th percentile.
    pub p90_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
}

fn summarise(v: &[u64]) -> StageSummary {
    if v.is_empty() {
        return StageSummary::default();
    }
    let mut s = v.to_vec();
    s.sort_unstable();
    let q = |p: f64| s[((s.len() - 1) as f64 * p).round() as usize] as f64 / 1e6;
    StageSummary {
        frames: s.len(),
        p50_ms: q(0.5),
        p90_ms: q(0.9),
        p99_ms: q(0.99),
    }
}

impl StageStats {
    /// Room for `n` frames without reallocating.
    pub fn with_capacity(n: usize) -> StageStats {
        StageStats {
            samples: std::array::from_fn(|_| Vec::with_capacity(n)),
            totals: Vec::with_capacity(n),
        }
    }
    /// Record one frame (stages at 0 ns did not run and are not counted,
    /// except in the total).
    pub fn record(&mut self, t: &StageTimes) {
        for (v, ns) in self.samples.iter_mut().zip(t.as_array()) {
            if ns > 0 {
                v.push(ns);
            }
        }
        self.totals.push(t.total_ns());
    }
    /// Forget everything.
    pub fn clear(&mut self) {
        self.samples.iter_mut().for_each(Vec::clear);
        self.totals.clear();
    }
    /// Percentiles per stage, in [`STAGES`] order, then the whole frame.
    pub fn summary(&self) -> (Vec<(&'static str, StageSummary)>, StageSummary) {
        let per = STAGES
            .iter()
            .zip(&self.samples)
            .map(|(n, v)| (*n, summarise(v)))
            .collect();
        (per, summarise(&self.totals))
    }
}

/// Pipeline tuning.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PipelineConfig {
    /// Contact detection.
    pub contact: ContactConfig,
    /// Decisions.
    pub decide: DecideConfig,
    /// Also encode the frames of the run that starts a press
    /// ([`FrontEnd::set_encode_run`]; the daemon's `encode_run`).
    pub encode_run: bool,
}

/// What one frame produced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameOutput {
    /// Contact score.
    pub score: f32,
    /// Contact depth ([`crate::contact::ContactUpdate::depth`]).
    pub depth: f32,
    /// In contact after this frame.
    pub in_contact: bool,
    /// How much of the gel the contact covers on this frame
    /// ([`crate::contact::ContactUpdate::coverage`]; 0 out of contact).
    pub coverage: f32,
    /// Contact event on this frame.
    pub contact_event: Option<ContactEvent>,
    /// Decision step, if the frame was encoded.
    pub step: Option<DecideStep>,
    /// A press that ended on this frame, with why.
    pub ended: Option<(PressOutcome, EndReason)>,
}

/// Front end (contact detector + encoder) + decider + index.
pub struct Pipeline<I: TextileIndex> {
    front: FrontEnd,
    decider: Decider,
    index: I,
}

impl<I: TextileIndex> Pipeline<I> {
    /// Assemble; the index must have the encoder's dimension. `reference`:
    /// known no-contact pixels (240x320x3 RGB, 0..255; see
    /// [`crate::front::recording_reference`]), else the first frames are
    /// captured as one.
    pub fn new(
        mut encoder: Encoder,
        index: I,
        cfg: PipelineConfig,
        reference: Option<&[f32]>,
    ) -> Result<Pipeline<I>, String> {
        // Queries are made of what the index says (its texture features).
        encoder.set_features(index.features());
        if index.dim() != encoder.dim() {
            return Err(format!(
                "the index holds {}-d embeddings but the encoder {} produces {}-d ones (built for another encoder?)",
                index.dim(),
                encoder.info().path.display(),
                encoder.dim()
            ));
        }
        if index.is_empty() {
            return Err("the index has no textiles".into());
        }
        if reference.is_some_and(|r| r.len() != crate::frame::FRAME_BYTES) {
            return Err(format!(
                "reference frame: {} values, expected {} (240x320 RGB)",
                reference.map_or(0, |r| r.len()),
                crate::frame::FRAME_BYTES
            ));
        }
        let decider = Decider::new(cfg.decide, encoder.dim());
        let mut front = FrontEnd::new(encoder, cfg.contact, reference);
        front.set_encode_run(cfg.encode_run);
        Ok(Pipeline {
            front,
            decider,
            index,
        })
    }

    /// Start afresh for a new recording (its own `reference`, or capture
    /// one): no state of earlier frames remains, so a run over several
    /// recordings decides exactly as separate runs would.
    pub fn reset(&mut self, reference: Option<&[f32]>) {
        self.front.reset(reference);
        self.decider = Decider::new(self.decider.config().clone(), self.front.encoder().dim());
    }

    /// The index.
    pub fn index(&self) -> &I {
        &self.index
    }
    /// The encoder.
    pub fn encoder(&self) -> &Encoder {
        self.front.encoder()
    }
    /// Take the encoder back (to reuse its session in another pipeline).
    pub fn into_encoder(self) -> Encoder {
        self.front.into_encoder()
    }
    /// The front end (e.g. to re-capture the reference).
    pub fn front_mut(&mut self) -> &mut FrontEnd {
        &mut self.front
    }

    /// Process one frame; fills the stage times (all but decode).
    pub fn process(
        &mut self,
        frame: &Frame,
        times: &mut StageTimes,
    ) -> Result<FrameOutput, EncoderError> {
        let t = frame.timestamp_us();
        let out = self.front.process(frame)?;
        let c = out.contact;
        times.contact_ns = out.contact_ns;
        times.preprocess_ns = out.preprocess_ns;
        times.encode_ns = out.encode_ns;
        times.search_ns = 0;
        times.decide_ns = 0;
        let mut ended = None;
        match c.event {
            Some(ContactEvent::PressStart { t_us }) => self.decider.press_start(t_us),
            Some(ContactEvent::PressEnd { t_us, reason, .. }) => {
                ended = self
                    .decider
                    .press_end(&self.index, t_us)
                    .map(|o| (o, reason));
            }
            _ => {}
        }
        let mut step: Option<DecideStep> = None;
        // The run's earlier frames (on the frame that starts a press), then
        // this one, each at its own time.
        let frames = out
            .earlier
            .iter()
            .map(|e| (e.t_us, e.embedding.as_slice(), e.depth))
            .chain(out.embedding.map(|e| (t, e, c.depth)));
        for (t, emb, depth) in frames {
            if !self.decider.in_press() {
                break;
            }
            let t3 = Instant::now();
            // The encoder's embeddings are finite and of its dimension (it
            // checks), which the index shares (checked in `new`).
            let nearest = self
                .decider
                .accumulate_weighted(emb, crate::decide::contact_weight(depth))
                .and_then(|mean| self.index.nearest2(mean));
            let t4 = Instant::now();
            if let Some(n) = nearest {
                let mut s = self.decider.decide(&self.index, t, n);
                // A decision made on an earlier frame is still news.
                s.changed |= step.is_some_and(|p| p.changed);
                step = Some(s);
            }
            let t5 = Instant::now();
            times.search_ns += (t4 - t3).as_nanos() as u64;
            times.decide_ns += (t5 - t4).as_nanos() as u64;
        }
        Ok(FrameOutput {
            score: c.score,
            depth: c.depth,
            in_contact: c.in_contact,
            coverage: c.coverage,
            contact_event: c.event,
            step,
            ended,
        })
    }

    /// End a press in progress (end of a recording); its outcome, if any.
    /// The contact detector keeps its reference but forgets the contact.
    pub fn finish(&mut self, t_us: u64) -> Option<PressOutcome> {
        self.front.end_of_frames();
        self.decider.press_end(&self.index, t_us)
    }
}

/// Report of one press, as `telextilesd classify` prints it.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct PressReport {
    /// Decided textile id (None: the press was too short to decide).
    pub textile: Option<String>,
    /// Roller slot of the decided textile.
    pub slot: Option<usize>,
    /// Distance of the press's mean embedding to the decided textile.
    pub distance: Option<f32>,
    /// Distance margin to the next textile.
    pub margin: Option<f32>,
    /// Confidence, 0..=1.
    pub confidence: Option<f32>,
    /// Far from every known textile.
    pub unknown: bool,
    /// When the contact detector started the press (its run's first
    /// frame), in milliseconds of the source's clock: from a recording's
    /// first frame. The times below count from it.
    pub start_ms: f64,
    /// Contact to first stable decision, in milliseconds of capture time.
    pub decision_ms: Option<f64>,
    /// The first decision's textile id (where the roller went first):
    /// `textile` unless the decision changed.
    pub first_textile: Option<String>,
    /// Contact to the last change of decision, in milliseconds.
    pub stable_ms: Option<f64>,
    /// Changes of decision after the first.
    pub switches: u32,
    /// Press duration, milliseconds.
    pub duration_ms: f64,
    /// Frames encoded in the press.
    pub frames: u32,
    /// How much of the gel the press covered at its deepest frame, 0..=1
    /// ([`crate::contact::ContactUpdate::coverage`]; None when no frame
    /// was in contact). Below [`PARTIAL_COVERAGE`] the press touched only
    /// part of the gel (tilted), and is decided less reliably.
    pub coverage: Option<f32>,
    /// Why the press ended ("released", "end-of-recording", ...).
    pub ended: String,
    /// Per-stage timings over the press's frames.
    pub stages: std::collections::BTreeMap<String, StageSummary>,
    /// Whole per-frame pipeline time over the press's frames.
    pub frame_total: StageSummary,
    /// Contact and end of the press on the source's clock (microseconds).
    #[serde(skip)]
    pub start_us: u64,
    /// See `start_us`.
    #[serde(skip)]
    pub end_us: u64,
    /// What the decider knew after each encoded frame of the press, with
    /// the frame's time: what a motion policy for the wheel is fed
    /// (`telextiles_session::motion`), replayed offline.
    #[serde(skip)]
    pub steps: Vec<(u64, DecideStep)>,
}

/// What [`run_source`] saw.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunSummary {
    /// Frames processed.
    pub frames: u64,
    /// Frames rejected by the source or the pipeline.
    pub bad_frames: u64,
    /// Presses reported.
    pub presses: u64,
}

/// A press whose [`PressReport::coverage`] is below this touched only part
/// of the gel: on simulated hand-held presses (catalogue 1, the shipped
/// model) those are decided right about 70 % of the time, against 90 % and
/// more for presses that cover more (`docs/benchmarks.md`, "How much of the
/// gel a press touches").
pub const PARTIAL_COVERAGE: f32 = 0.5;

pub use telextiles_press::Deepest;

fn report<I: TextileIndex>(
    index: &I,
    o: &PressOutcome,
    ended: &str,
    stats: &StageStats,
    deepest: Deepest,
    steps: &[(u64, DecideStep)],
) -> PressReport {
    let ms = |t: u64| t.saturating_sub(o.start_us) as f64 / 1000.0;
    let (per, total) = stats.summary();
    PressReport {
        textile: o.decision.map(|d| index.id(d.entry).to_string()),
        slot: o.decision.map(|d| d.slot),
        distance: o.decision.map(|d| d.distance),
        margin: o.decision.map(|d| d.margin),
        confidence: o.decision.map(|d| d.confidence),
        unknown: o.decision.is_some_and(|d| d.unknown),
        start_ms: o.start_us as f64 / 1000.0,
        decision_ms: o.first_decision_us.map(ms),
        first_textile: o.first_entry.map(|e| index.id(e).to_string()),
        stable_ms: o.stable_since_us.map(ms),
        switches: o.switches,
        duration_ms: ms(o.end_us),
        frames: o.frames,
        coverage: deepest.coverage(),
        ended: ended.to_string(),
        stages: per.into_iter().map(|(n, s)| (n.to_string(), s)).collect(),
        frame_total: total,
        start_us: o.start_us,
        end_us: o.end_us,
        steps: steps.to_vec(),
    }
}

/// Run frames from `source` through `pipeline` until the source ends (or
/// `max_frames`), calling `on_press` for every finished press. A press still
/// open when the source ends is reported with `ended = "end-of-frames"`. Bad
/// frames are counted and skipped; other source errors stop the run.
pub fn run_source<I: TextileIndex>(
    pipeline: &mut Pipeline<I>,
    source: &mut dyn crate::source::FrameSource,
    max_frames: Option<u64>,
    mut on_press: impl FnMut(PressReport),
) -> Result<RunSummary, String> {
    use crate::source::SourceError;
    let mut frame = Frame::blank();
    let mut stats = StageStats::with_capacity(1024);
    let mut deepest = Deepest::default();
    let mut steps: Vec<(u64, DecideStep)> = Vec::with_capacity(256);
    let mut summary = RunSummary::default();
    let mut last_t = 0;
    loop {
        if max_frames.is_some_and(|m| summary.frames >= m) {
            break;
        }
        let t0 = Instant::now();
        match source.next_frame(&mut frame) {
            Ok(()) => {}
            Err(SourceError::Ended) => break,
            Err(SourceError::BadFrame(e)) => {
                summary.bad_frames += 1;
                tracing::warn!(rejected = summary.bad_frames, "rejected frame: {e}");
                continue;
            }
            Err(e) => return Err(e.to_string()),
        }
        let mut times = StageTimes {
            decode_ns: t0.elapsed().as_nanos() as u64,
            ..Default::default()
        };
        let out = match pipeline.process(&frame, &mut times) {
            Ok(o) => o,
            Err(EncoderError::Frame(e)) => {
                summary.bad_frames += 1;
                tracing::warn!(rejected = summary.bad_frames, "rejected frame: {e}");
                continue;
            }
            Err(e) => return Err(e.to_string()),
        };
        summary.frames += 1;
        last_t = frame.timestamp_us();
        if let Some(ContactEvent::PressStart { .. }) = out.contact_event {
            stats.clear();
            deepest = Deepest::default();
            steps.clear();
        }
        if let Some(s) = out.step {
            steps.push((frame.timestamp_us(), s));
        }
        if out.in_contact || out.ended.is_some() {
            stats.record(&times);
        }
        if out.in_contact {
            deepest.add(out.depth, out.coverage);
        }
        if let Some((o, reason)) = out.ended {
            let why = match reason {
                EndReason::Released => "released",
                EndReason::Recapture => "reference-recaptured",
                EndReason::StaleReference => "stale-reference",
            };
            on_press(report(&pipeline.index, &o, why, &stats, deepest, &steps));
            summary.presses += 1;
        }
    }
    if let Some(o) = pipeline.finish(last_t) {
        on_press(report(
            &pipeline.index,
            &o,
            "end-of-frames",
            &stats,
            deepest,
            &steps,
        ));
        summary.presses += 1;
    }
    Ok(summary)
}
