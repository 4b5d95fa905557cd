//! Recording presses: cut a frame stream into presses by contact, each with
//! its own no-contact reference (`telextilesd record`, the control socket's
//! `record.start`).
//!
//! Sans-IO: [`Recorder::push`] takes every frame with the [`ContactUpdate`]
//! that [`crate::contact::ContactDetector::update`] returned for it, and
//! [`Recorder::poll`] hands out what happened ([`RecordEvent`]): waiting for
//! an untouched sensor, ready ("press now"), press started, hold progress,
//! released, and a complete press ([`RecordedPress`], a
//! [`telextiles_recording::Press`] ready for `telextiles_recording::recording::write_press`)
//! or a rejected one. No clocks (timestamps come with the frames), no files.
//!
//! A recorded press is: the last quiet frames before contact (at most
//! `pre_frames`; the frames the detector called `quiet`), the frames that
//! led into contact, the press, and `post_frames` frames after the release.
//! `meta.reference_frames` is the number of leading quiet frames: their mean
//! is the recording's own no-contact reference. Timestamps are relative to
//! the first kept frame; `meta.fps` is the given rate, else the rate measured
//! from the kept frames' timestamps.
//!
//! Checks (see [`RecordWarning`]):
//! * fewer than `min_quiet_frames` quiet frames right before contact (pressed
//!   before the sensor was seen untouched, or a second press right after the
//!   first): **rejected**, since the recording would have no reference;
//! * held for less than `min_press_ms`: **rejected** (a tap, nothing to
//!   classify: a decision needs about 120 ms of contact);
//! * longer than `max_press_frames` in contact: **rejected** (bounds memory);
//! * the reference re-captured during the press: **rejected**;
//! * peak contact score below `min_peak`: **kept, with a warning** (soft
//!   fabrics score low; the person may press harder next time);
//! * the stream ended while still in contact ([`Recorder::finish`]): **kept,
//!   with a warning** (no margin after the release).
//!
//! Memory is bounded: a ring of `pre_frames + approach_frames` frames before
//! contact, at most `max_press_frames` in contact, `post_frames` after.

use std::collections::VecDeque;
use std::fmt;

use image::RgbImage;
use telextiles_recording::{Press, PressMeta};

use crate::contact::{ContactEvent, ContactUpdate, EndReason};
use crate::frame::Frame;
use crate::pipeline::Deepest;

/// Recorder tuning (defaults for a 60 fps DIGIT).
#[derive(Clone, Debug, PartialEq)]
pub struct RecorderConfig {
    /// Quiet frames kept before contact (the recording's reference), at most.
    pub pre_frames: usize,
    /// Non-quiet frames between the last quiet frame and the press start that
    /// are kept (the approach); older ones leave the ring.
    pub approach_frames: usize,
    /// Fewer quiet frames than this right before contact rejects the press.
    pub min_quiet_frames: usize,
    /// Quiet frames in a row before the recorder says it is ready ("press now").
    pub ready_frames: usize,
    /// Frames kept after the release.
    pub post_frames: usize,
    /// Frames in contact after which the press is rejected as too long.
    pub max_press_frames: usize,
    /// A press held for less than this (ms, contact start to release) is rejected.
    pub min_press_ms: f64,
    /// A press whose peak contact score stays below this is kept with a warning.
    pub min_peak: f32,
    /// A press that covers less of the gel than this at its deepest frame
    /// ([`ContactUpdate::coverage`]) is kept with a warning (held tilted).
    pub min_coverage: f32,
    /// Frame rate to record in the metadata; None: measured from timestamps.
    pub fps: Option<f32>,
}

impl Default for RecorderConfig {
    fn default() -> Self {
        RecorderConfig {
            pre_frames: 30,
            approach_frames: 30,
            min_quiet_frames: 8,
            ready_frames: 15,
            post_frames: 20,
            max_press_frames: 900,
            min_press_ms: 250.0,
            min_peak: 1.0,
            min_coverage: crate::pipeline::PARTIAL_COVERAGE,
            fps: None,
        }
    }
}

/// What a recording is of: written into every press's metadata.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RecordLabel {
    /// Textile id (the directory the presses go into).
    pub textile: String,
    /// "digit", "sim" or "replay".
    pub source: String,
    /// The sensor's serial number, if known.
    pub sensor_serial: Option<String>,
    /// Sensor unit number (the simulator's unit; 0 for a real sensor).
    pub sensor: u32,
    /// Person number (0 unless known).
    pub person: u32,
    /// Pressed with a jig.
    pub jig: bool,
    /// The sensor's profile (None: a DIGIT): the frames, mapped to the
    /// frame's scale, are saved with it.
    pub sensor_profile: Option<String>,
}

impl RecordLabel {
    /// A label for `textile` from `source`, everything else unknown.
    pub fn new(textile: impl Into<String>, source: impl Into<String>) -> RecordLabel {
        RecordLabel {
            textile: textile.into(),
            source: source.into(),
            sensor_serial: None,
            sensor: 0,
            person: 0,
            jig: false,
            sensor_profile: None,
        }
    }
}

/// Something wrong with a press: a reason to reject it, or a warning on a kept one.
#[derive(Clone, Debug, PartialEq)]
pub enum RecordWarning {
    /// Held for less than the minimum (rejected).
    TooShort {
        /// How long it was held.
        held_ms: f64,
        /// The minimum.
        min_ms: f64,
    },
    /// Peak contact score below the minimum (kept).
    TooWeak {
        /// The peak score.
        peak: f32,
        /// The minimum.
        min: f32,
    },
    /// The press covered little of the gel at its deepest (kept): the
    /// sensor was held tilted, and the press shows the encoder less cloth.
    Partial {
        /// Share of the gel the press covered at its deepest frame.
        coverage: f32,
        /// The minimum.
        min: f32,
    },
    /// Too few quiet frames right before contact: no reference (rejected).
    NoQuietBefore {
        /// Quiet frames found.
        quiet_frames: usize,
        /// Quiet frames needed.
        needed: usize,
    },
    /// In contact for more than the maximum number of frames (rejected).
    TooLong {
        /// The maximum.
        max_frames: usize,
    },
    /// The contact reference was re-captured during the press (rejected).
    Interrupted,
    /// The frames ended while still in contact (kept, without a margin after).
    NotReleased,
}

impl RecordWarning {
    /// Short machine-readable name ("too_short", "too_weak", "partial", "no_quiet_before",
    /// "too_long", "interrupted", "not_released").
    pub fn code(&self) -> &'static str {
        match self {
            RecordWarning::TooShort { .. } => "too_short",
            RecordWarning::TooWeak { .. } => "too_weak",
            RecordWarning::Partial { .. } => "partial",
            RecordWarning::NoQuietBefore { .. } => "no_quiet_before",
            RecordWarning::TooLong { .. } => "too_long",
            RecordWarning::Interrupted => "interrupted",
            RecordWarning::NotReleased => "not_released",
        }
    }
}

impl fmt::Display for RecordWarning {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RecordWarning::TooShort { held_ms, min_ms } => write!(
                f,
                "press too short ({held_ms:.0} ms, at least {min_ms:.0} ms): hold it a little longer"
            ),
            RecordWarning::TooWeak { peak, min } => write!(
                f,
                "press weak (peak contact {peak:.2}, below {min:.2}): press a little harder"
            ),
            RecordWarning::Partial { coverage, min } => write!(
                f,
                "partial contact (the press touched {:.0} % of the gel, below {:.0} %): hold the sensor flat on the fabric",
                100.0 * coverage,
                100.0 * min
            ),
            RecordWarning::NoQuietBefore {
                quiet_frames,
                needed,
            } => write!(
                f,
                "no untouched frames before contact ({quiet_frames}, need {needed}): lift, wait for \"press now\", then press"
            ),
            RecordWarning::TooLong { max_frames } => write!(
                f,
                "press too long (more than {max_frames} frames in contact): release sooner"
            ),
            RecordWarning::Interrupted => {
                write!(f, "the no-contact reference was re-captured during the press")
            }
            RecordWarning::NotReleased => {
                write!(f, "the frames ended before the release (no margin after it)")
            }
        }
    }
}

/// Figures of a recorded press.
#[derive(Clone, Debug, PartialEq)]
pub struct PressSummary {
    /// Frames in the recording.
    pub frames: usize,
    /// First to last kept frame, ms.
    pub duration_ms: f64,
    /// Contact start to release, ms.
    pub held_ms: f64,
    /// Peak contact score.
    pub peak: f32,
    /// Share of the gel the press covered at its deepest frame
    /// ([`ContactUpdate::coverage`]).
    pub coverage: f32,
    /// Leading quiet frames (the reference).
    pub reference_frames: u32,
    /// Frame rate written into the metadata.
    pub fps: f32,
    /// Warnings on this kept press.
    pub warnings: Vec<RecordWarning>,
}

/// A complete press, ready to write.
#[derive(Clone, Debug, PartialEq)]
pub struct RecordedPress {
    /// Frames and metadata.
    pub press: Press,
    /// Its figures.
    pub summary: PressSummary,
}

/// What the recorder is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RecordState {
    /// Waiting for enough untouched frames.
    Waiting,
    /// Ready for a press.
    Ready,
    /// A press is in progress (being recorded).
    Pressing,
    /// A rejected press is in progress: waiting for its release.
    Ignoring,
    /// Released: keeping the frames after it.
    Releasing,
}

/// What happened (see [`Recorder::poll`]).
#[derive(Clone, Debug, PartialEq)]
pub enum RecordEvent {
    /// Waiting for the sensor to be seen untouched (the no-contact reference).
    WaitingForReference,
    /// Enough quiet frames: press now.
    Ready,
    /// Contact.
    PressStarted {
        /// Timestamp of the first frame in contact (source clock).
        t_us: u64,
        /// Quiet frames right before it (kept as the reference).
        quiet_frames: usize,
    },
    /// One more frame of a press being recorded.
    Holding {
        /// Time since contact, ms.
        held_ms: f64,
        /// This frame's contact score.
        score: f32,
        /// Peak score so far.
        peak: f32,
    },
    /// The press ended.
    Released {
        /// Contact start to release, ms.
        held_ms: f64,
        /// Peak contact score.
        peak: f32,
    },
    /// A press is complete and should be written.
    PressComplete(Box<RecordedPress>),
    /// A press was rejected (or is being ignored) for this reason.
    Rejected(RecordWarning),
}

struct Held {
    image: RgbImage,
    t_us: u64,
    quiet: bool,
}

struct Take {
    frames: Vec<Held>,
    reference: usize,
    start_us: u64,
    end_us: u64,
    peak: f32,
    in_contact: usize,
    /// The deepest frame in contact.
    deepest: Deepest,
}

enum State {
    Waiting,
    Ready,
    Pressing(Take),
    Ignoring,
    Releasing(Take, usize),
}

/// Cuts presses out of a frame stream (see the module docs).
pub struct Recorder {
    cfg: RecorderConfig,
    label: RecordLabel,
    /// Frames before contact, oldest first.
    ring: VecDeque<Held>,
    /// Trailing quiet frames in a row (including the ring's last ones).
    quiet_run: usize,
    /// Recycled frame buffers.
    spare: Vec<RgbImage>,
    state: State,
    events: VecDeque<RecordEvent>,
}

impl Recorder {
    /// A recorder; its first event is [`RecordEvent::WaitingForReference`].
    pub fn new(cfg: RecorderConfig, label: RecordLabel) -> Recorder {
        let mut events = VecDeque::new();
        events.push_back(RecordEvent::WaitingForReference);
        Recorder {
            cfg,
            label,
            ring: VecDeque::new(),
            quiet_run: 0,
            spare: Vec::new(),
            state: State::Waiting,
            events,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &RecorderConfig {
        &self.cfg
    }

    /// The label written into every press.
    pub fn label(&self) -> &RecordLabel {
        &self.label
    }

    /// What the recorder is doing.
    pub fn state(&self) -> RecordState {
        match self.state {
            State::Waiting => RecordState::Waiting,
            State::Ready => RecordState::Ready,
            State::Pressing(_) => RecordState::Pressing,
            State::Ignoring => RecordState::Ignoring,
            State::Releasing(..) => RecordState::Releasing,
        }
    }

    /// Frames held in memory now (ring, press, spare buffers).
    pub fn frames_held(&self) -> usize {
        let take = match &self.state {
            State::Pressing(t) | State::Releasing(t, _) => t.frames.len(),
            _ => 0,
        };
        self.ring.len() + take + self.spare.len()
    }

    /// The next event, if any.
    pub fn poll(&mut self) -> Option<RecordEvent> {
        self.events.pop_front()
    }

    /// Forget everything but the configuration (a press in progress is
    /// dropped without an event) and wait for quiet frames again.
    pub fn reset(&mut self) {
        let ring: Vec<Held> = self.ring.drain(..).collect();
        ring.into_iter().for_each(|h| self.recycle(h.image));
        self.quiet_run = 0;
        self.state = State::Waiting;
        self.events.push_back(RecordEvent::WaitingForReference);
    }

    /// The frames ended: complete a released press (with the margin it has),
    /// keep one still in contact (with [`RecordWarning::NotReleased`]).
    pub fn finish(&mut self) {
        match std::mem::replace(&mut self.state, State::Waiting) {
            State::Releasing(take, _) => self.complete(take, None),
            State::Pressing(mut take) => {
                take.end_us = take.frames.last().map(|h| h.t_us).unwrap_or(take.start_us);
                self.complete(take, Some(RecordWarning::NotReleased))
            }
            _ => {}
        }
        let ring: Vec<Held> = self.ring.drain(..).collect();
        ring.into_iter().for_each(|h| self.recycle(h.image));
        self.quiet_run = 0;
    }

    fn copy(&mut self, image: &RgbImage) -> RgbImage {
        match self.spare.pop() {
            Some(mut b) => {
                b.clone_from(image);
                b
            }
            None => image.clone(),
        }
    }

    fn recycle(&mut self, image: RgbImage) {
        if self.spare.len() < self.ring_cap() {
            self.spare.push(image);
        }
    }

    fn ring_cap(&self) -> usize {
        self.cfg.pre_frames + self.cfg.approach_frames + 1
    }

    fn push_ring(&mut self, frame: &Frame, quiet: bool) {
        let image = if self.ring.len() >= self.ring_cap() {
            let mut old = self.ring.pop_front().expect("ring is full").image;
            old.clone_from(frame.image());
            old
        } else {
            self.copy(frame.image())
        };
        self.ring.push_back(Held {
            image,
            t_us: frame.timestamp_us(),
            quiet,
        });
    }

    /// Feed one frame and the contact detector's update for it.
    pub fn push(&mut self, frame: &Frame, update: &ContactUpdate) {
        let t = frame.timestamp_us();
        self.quiet_run = if update.quiet { self.quiet_run + 1 } else { 0 };
        let state = std::mem::replace(&mut self.state, State::Waiting);
        self.state = match state {
            State::Waiting | State::Ready => {
                let was_ready = matches!(state, State::Ready);
                self.push_ring(frame, update.quiet);
                match update.event {
                    Some(ContactEvent::PressStart { t_us }) => self.start(t_us, update),
                    _ => {
                        if !was_ready && self.quiet_run >= self.cfg.ready_frames.max(1) {
                            self.events.push_back(RecordEvent::Ready);
                            State::Ready
                        } else {
                            state
                        }
                    }
                }
            }
            State::Ignoring => match update.event {
                Some(ContactEvent::PressEnd { .. }) => {
                    self.push_ring(frame, update.quiet);
                    State::Waiting
                }
                _ => State::Ignoring,
            },
            State::Pressing(mut take) => {
                let image = self.copy(frame.image());
                take.frames.push(Held {
                    image,
                    t_us: t,
                    quiet: update.quiet,
                });
                take.in_contact += 1;
                take.peak = take.peak.max(update.score);
                if update.in_contact {
                    take.deepest.add(update.depth, update.coverage);
                }
                let held_ms = t.saturating_sub(take.start_us) as f64 / 1000.0;
                match update.event {
                    Some(ContactEvent::PressEnd { reason, t_us, .. }) => {
                        if reason != EndReason::Released {
                            self.drop_take(take);
                            self.events
                                .push_back(RecordEvent::Rejected(RecordWarning::Interrupted));
                            self.events.push_back(RecordEvent::WaitingForReference);
                            State::Waiting
                        } else {
                            take.end_us = t_us;
                            let held_ms = t_us.saturating_sub(take.start_us) as f64 / 1000.0;
                            self.events.push_back(RecordEvent::Released {
                                held_ms,
                                peak: take.peak,
                            });
                            if self.cfg.post_frames == 0 {
                                self.complete(take, None);
                                State::Waiting
                            } else {
                                self.push_ring(frame, update.quiet);
                                State::Releasing(take, self.cfg.post_frames)
                            }
                        }
                    }
                    _ if take.in_contact > self.cfg.max_press_frames => {
                        self.drop_take(take);
                        self.events
                            .push_back(RecordEvent::Rejected(RecordWarning::TooLong {
                                max_frames: self.cfg.max_press_frames,
                            }));
                        State::Ignoring
                    }
                    _ => {
                        self.events.push_back(RecordEvent::Holding {
                            held_ms,
                            score: update.score,
                            peak: take.peak,
                        });
                        State::Pressing(take)
                    }
                }
            }
            State::Releasing(mut take, left) => {
                if let Some(ContactEvent::PressStart { t_us }) = update.event {
                    // A new press before the margin was complete: finish
                    // this one with what it has, then start the next.
                    self.complete(take, None);
                    self.push_ring(frame, update.quiet);
                    self.start(t_us, update)
                } else {
                    let image = self.copy(frame.image());
                    take.frames.push(Held {
                        image,
                        t_us: t,
                        quiet: update.quiet,
                    });
                    self.push_ring(frame, update.quiet);
                    if left <= 1 {
                        self.complete(take, None);
                        State::Waiting
                    } else {
                        State::Releasing(take, left - 1)
                    }
                }
            }
        };
    }

    /// Contact started (the current frame is the ring's last).
    fn start(&mut self, t_us: u64, update: &ContactUpdate) -> State {
        let score = update.score;
        let mut deepest = Deepest::default();
        deepest.add(update.depth, update.coverage);
        // The ring's tail: [.. quiet run][approach: not quiet .. current frame].
        let approach = self.ring.iter().rev().take_while(|h| !h.quiet).count();
        let quiet = self
            .ring
            .iter()
            .rev()
            .skip(approach)
            .take_while(|h| h.quiet)
            .count();
        let reference = quiet.min(self.cfg.pre_frames);
        self.events.push_back(RecordEvent::PressStarted {
            t_us,
            quiet_frames: quiet,
        });
        if quiet < self.cfg.min_quiet_frames {
            self.events
                .push_back(RecordEvent::Rejected(RecordWarning::NoQuietBefore {
                    quiet_frames: quiet,
                    needed: self.cfg.min_quiet_frames,
                }));
            return State::Ignoring;
        }
        let keep = reference + approach;
        let drop = self.ring.len() - keep;
        for _ in 0..drop {
            let h = self.ring.pop_front().expect("counted");
            self.recycle(h.image);
        }
        let mut frames = Vec::with_capacity(keep + 64);
        frames.extend(self.ring.drain(..));
        // Frames of the approach at or after the contact start are in contact.
        let in_contact = frames.iter().filter(|h| h.t_us >= t_us).count();
        self.quiet_run = 0;
        State::Pressing(Take {
            frames,
            reference,
            start_us: t_us,
            end_us: t_us,
            peak: score,
            in_contact,
            deepest,
        })
    }

    fn drop_take(&mut self, take: Take) {
        for h in take.frames {
            self.recycle(h.image);
        }
    }

    fn complete(&mut self, take: Take, extra: Option<RecordWarning>) {
        let held_ms = take.end_us.saturating_sub(take.start_us) as f64 / 1000.0;
        if held_ms < self.cfg.min_press_ms {
            self.drop_take(take);
            self.events
                .push_back(RecordEvent::Rejected(RecordWarning::TooShort {
                    held_ms,
                    min_ms: self.cfg.min_press_ms,
                }));
            return;
        }
        let mut warnings = Vec::new();
        if take.peak < self.cfg.min_peak {
            warnings.push(RecordWarning::TooWeak {
                peak: take.peak,
                min: self.cfg.min_peak,
            });
        }
        let coverage = take.deepest.coverage().unwrap_or(0.0);
        if coverage < self.cfg.min_coverage {
            warnings.push(RecordWarning::Partial {
                coverage,
                min: self.cfg.min_coverage,
            });
        }
        warnings.extend(extra);
        let t0 = take.frames.first().map(|h| h.t_us).unwrap_or(0);
        let t1 = take.frames.last().map(|h| h.t_us).unwrap_or(0);
        let n = take.frames.len();
        let fps = self
            .cfg
            .fps
            .unwrap_or_else(|| measured_fps(n, t1.saturating_sub(t0)));
        let timestamps_us: Vec<u64> = take
            .frames
            .iter()
            .map(|h| h.t_us.saturating_sub(t0))
            .collect();
        let frames: Vec<RgbImage> = take.frames.into_iter().map(|h| h.image).collect();
        let label = &self.label;
        let meta = PressMeta {
            textile: label.textile.clone(),
            person: label.person,
            sensor: label.sensor,
            jig: label.jig,
            fps,
            timestamps_us,
            seed: None,
            source: label.source.clone(),
            sensor_serial: label.sensor_serial.clone(),
            params: None,
            reference_frames: Some(take.reference as u32),
            // Saved as frames: at the frame's scale, whatever the sensor.
            mm_per_px: label
                .sensor_profile
                .as_ref()
                .map(|_| telextiles_recording::profile::FRAME_MM_PER_PX),
            sensor_profile: label.sensor_profile.clone(),
        };
        let summary = PressSummary {
            frames: n,
            duration_ms: t1.saturating_sub(t0) as f64 / 1000.0,
            held_ms,
            peak: take.peak,
            coverage,
            reference_frames: take.reference as u32,
            fps,
            warnings,
        };
        self.events
            .push_back(RecordEvent::PressComplete(Box::new(RecordedPress {
                press: Press { meta, frames },
                summary,
            })));
    }
}

/// `press` led by `n` frames of `reference` (a no-contact frame of its
/// sensor given from outside, 240x320x3 RGB values 0..255 as
/// [`crate::front::References`] holds them), declared as its reference
/// frames (`meta.reference_frames`): how a recording that carries no
/// reference of its own, and may start already pressed (PyTouch data cut
/// to the press), is replayed into presses that carry one (`telextilesd
/// record --sensor replay:<dir> --reference`). The lead-in frames come one
/// frame period apart (`meta.fps`) and the recording's own frames follow
/// the last of them one period on, their spacing kept.
///
/// # Panics
/// If `reference` is not 240x320x3 long.
pub fn lead_with_reference(press: &Press, reference: &[f32], n: usize) -> Press {
    let image = crate::front::image_of(reference).expect("a 240x320 RGB reference");
    let fps = if press.meta.fps.is_finite() && press.meta.fps > 0.0 {
        press.meta.fps as f64
    } else {
        60.0
    };
    let period = (1e6 / fps).round() as u64;
    let first = press.meta.timestamps_us.first().copied().unwrap_or(0);
    let mut meta = press.meta.clone();
    meta.timestamps_us = (0..n as u64)
        .map(|i| i * period)
        .chain(
            press
                .meta
                .timestamps_us
                .iter()
                .map(|&t| n as u64 * period + t.saturating_sub(first)),
        )
        .collect();
    meta.reference_frames = Some(n as u32);
    let mut frames = vec![image; n];
    frames.extend(press.frames.iter().cloned());
    Press { meta, frames }
}

/// Frames per second from `n` frames spanning `span_us` (60 when it cannot
/// be measured), rounded to 0.01.
pub fn measured_fps(n: usize, span_us: u64) -> f32 {
    if n < 2 || span_us == 0 {
        return 60.0;
    }
    let fps = (n - 1) as f64 * 1e6 / span_us as f64;
    ((fps * 100.0).round() / 100.0) as f32
}

#[cfg(test)]
mod tests;
