//! Contact detection: compare each frame with a no-contact reference.
//!
//! The score is the mean absolute difference (0..255) between the frame and
//! the reference, both averaged over 4x4 blocks (60x80 blocks x 3 channels).
//! Thresholds are relative to the noise floor (the score of untouched frames,
//! mostly camera noise, about 0.4 on a DIGIT), which is tracked while idle.
//! Hysteresis: contact starts after `min_enter_frames` consecutive frames with
//! score >= floor + `enter` and ends after `min_exit_frames` consecutive
//! frames with score < floor + `exit` (`exit` < `enter`). Press-start carries the timestamp of the
//! first frame of the run that crossed `enter`.
//!
//! The reference is the mean of the first `reference_frames` frames (the
//! sensor must not be touched at start), or of the frames after
//! [`ContactDetector::recapture`]. It is kept fresh: while there is no contact
//! and the score is below `exit`, it follows the frames slowly (exponential
//! average with weight `background_alpha`), absorbing LED warm-up and
//! temperature drift. A reference gone stale while "in contact" (the gel
//! settled, the LEDs changed) shows as a contact whose score stays flat for
//! `stale_after_frames`; then the reference is re-captured from the current
//! frames and the press ends with [`EndReason::StaleReference`].
//!
//! Pure and deterministic: timestamps come with the frames.

use image::RgbImage;

use crate::frame::{FRAME_H, FRAME_W};

const STEP: usize = 4;
const SAMPLES_X: usize = FRAME_W as usize / STEP;
const SAMPLES_Y: usize = FRAME_H as usize / STEP;
const SAMPLES: usize = SAMPLES_X * SAMPLES_Y * 3;

/// Contact-detector tuning.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactConfig {
    /// Frames averaged into a (re)captured reference.
    pub reference_frames: u32,
    /// Score above the noise floor at or above which a frame counts towards contact.
    pub enter: f32,
    /// Score above the noise floor below which a frame counts towards release (`exit < enter`).
    pub exit: f32,
    /// Noise floor assumed until idle frames have been seen.
    pub initial_floor: f32,
    /// The tracked floor never exceeds this.
    pub max_floor: f32,
    /// Consecutive frames at or above `enter` to start a press.
    pub min_enter_frames: u32,
    /// Consecutive frames below `exit` to end a press.
    pub min_exit_frames: u32,
    /// Weight of a no-contact frame in the slowly updated reference (0 = frozen).
    pub background_alpha: f32,
    /// A contact whose score varies by less than `stale_band` for this many
    /// frames is taken as a stale reference (0 = never).
    pub stale_after_frames: u32,
    /// Score band for the stale test.
    pub stale_band: f32,
}

impl Default for ContactConfig {
    fn default() -> Self {
        ContactConfig {
            reference_frames: 8,
            enter: 0.35,
            exit: 0.2,
            initial_floor: 0.5,
            max_floor: 2.0,
            min_enter_frames: 3,
            min_exit_frames: 5,
            background_alpha: 0.01,
            stale_after_frames: 1800,
            stale_band: 0.3,
        }
    }
}

/// Why a press ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EndReason {
    /// The score fell below `exit`.
    Released,
    /// The reference was re-captured on command during the press.
    Recapture,
    /// The contact looked like a stale reference and the reference was re-captured.
    StaleReference,
}

/// Events from the detector.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ContactEvent {
    /// A reference was captured (at start, on command, or after a stale one).
    ReferenceCaptured {
        /// Timestamp of the last frame averaged.
        t_us: u64,
    },
    /// A press started.
    PressStart {
        /// Timestamp of the first frame over `enter` in the run that started it.
        t_us: u64,
    },
    /// A press ended.
    PressEnd {
        /// When the press started.
        start_us: u64,
        /// Timestamp of the frame that ended it.
        t_us: u64,
        /// Why.
        reason: EndReason,
    },
}

/// Result of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactUpdate {
    /// Mean absolute difference from the reference (0 while capturing it).
    pub score: f32,
    /// Whether a press is in progress after this frame.
    pub in_contact: bool,
    /// What happened on this frame, if anything.
    pub event: Option<ContactEvent>,
    /// The frame counts as untouched: it went into the reference (captured,
    /// or idle with a score below the exit threshold). Encoders that
    /// subtract the background follow these frames.
    pub quiet: bool,
}

#[derive(Clone, Debug, PartialEq)]
enum State {
    Capturing {
        n: u32,
    },
    Idle {
        run: u32,
        run_start: u64,
    },
    Contact {
        start: u64,
        run: u32,
        flat: u32,
        lo: f32,
        hi: f32,
    },
}

/// The contact detector (see the module docs).
#[derive(Clone, Debug)]
pub struct ContactDetector {
    cfg: ContactConfig,
    reference: Vec<f32>,
    acc: Vec<f32>,
    samples: Vec<f32>,
    state: State,
    pending_end: Option<(u64, EndReason)>,
    floor: f32,
}

impl ContactDetector {
    /// A detector that will capture its reference from the first frames.
    pub fn new(cfg: ContactConfig) -> ContactDetector {
        ContactDetector {
            floor: cfg.initial_floor,
            cfg,
            reference: vec![0.0; SAMPLES],
            acc: vec![0.0; SAMPLES],
            samples: vec![0.0; SAMPLES],
            state: State::Capturing { n: 0 },
            pending_end: None,
        }
    }

    /// A detector with a known reference frame (e.g. the simulator's background).
    pub fn with_reference(cfg: ContactConfig, reference: &RgbImage) -> ContactDetector {
        let mut d = ContactDetector::new(cfg);
        sample(reference, &mut d.reference);
        d.state = State::Idle {
            run: 0,
            run_start: 0,
        };
        d
    }

    /// The configuration.
    pub fn config(&self) -> &ContactConfig {
        &self.cfg
    }

    /// Whether a press is in progress.
    pub fn in_contact(&self) -> bool {
        matches!(self.state, State::Contact { .. })
    }

    /// The current noise floor estimate.
    pub fn floor(&self) -> f32 {
        self.floor
    }

    /// Whether the reference is being (re)captured.
    pub fn capturing(&self) -> bool {
        matches!(self.state, State::Capturing { .. })
    }

    /// Re-capture the reference from the next frames (the sensor must be
    /// free). A press in progress ends on the next frame with
    /// [`EndReason::Recapture`].
    pub fn recapture(&mut self) {
        if let State::Contact { start, .. } = self.state {
            self.pending_end = Some((start, EndReason::Recapture));
        }
        self.state = State::Capturing { n: 0 };
    }

    /// Forget a press in progress (the frames stopped: end of a recording),
    /// keeping the reference. The next touched frames start a new press.
    pub fn reset(&mut self) {
        self.pending_end = None;
        if !self.capturing() {
            self.state = State::Idle {
                run: 0,
                run_start: 0,
            };
        }
    }

    /// Score a frame against the reference without changing state.
    pub fn score(&mut self, image: &RgbImage) -> f32 {
        sample(image, &mut self.samples);
        mad(&self.samples, &self.reference)
    }

    /// Feed one frame (must be 240x320; smaller images are sampled where they
    /// have pixels).
    pub fn update(&mut self, image: &RgbImage, t_us: u64) -> ContactUpdate {
        sample(image, &mut self.samples);
        if let State::Capturing { n } = self.state {
            if n == 0 {
                self.acc.iter_mut().for_each(|a| *a = 0.0);
            }
            for (a, s) in self.acc.iter_mut().zip(&self.samples) {
                *a += s;
            }
            let n = n + 1;
            let mut event =
                self.pending_end
                    .take()
                    .map(|(start_us, reason)| ContactEvent::PressEnd {
                        start_us,
                        t_us,
                        reason,
                    });
            if n >= self.cfg.reference_frames.max(1) {
                for (r, a) in self.reference.iter_mut().zip(&self.acc) {
                    *r = a / n as f32;
                }
                self.state = State::Idle {
                    run: 0,
                    run_start: t_us,
                };
                if event.is_none() {
                    event = Some(ContactEvent::ReferenceCaptured { t_us });
                }
            } else {
                self.state = State::Capturing { n };
            }
            return ContactUpdate {
                score: 0.0,
                in_contact: false,
                event,
                quiet: true,
            };
        }
        let score = mad(&self.samples, &self.reference);
        let cfg = &self.cfg;
        let (enter, exit) = (self.floor + cfg.enter, self.floor + cfg.exit);
        let mut event = None;
        let mut quiet = false;
        self.state = match self.state.clone() {
            State::Capturing { .. } => unreachable!("handled above"),
            State::Idle { run, run_start } => {
                if score >= enter {
                    let run_start = if run == 0 { t_us } else { run_start };
                    if run + 1 >= cfg.min_enter_frames.max(1) {
                        event = Some(ContactEvent::PressStart { t_us: run_start });
                        State::Contact {
                            start: run_start,
                            run: 0,
                            flat: 0,
                            lo: score,
                            hi: score,
                        }
                    } else {
                        State::Idle {
                            run: run + 1,
                            run_start,
                        }
                    }
                } else {
                    if score < exit {
                        quiet = true;
                        self.floor = (self.floor + 0.05 * (score - self.floor)).min(cfg.max_floor);
                        if cfg.background_alpha > 0.0 {
                            let a = cfg.background_alpha;
                            for (r, s) in self.reference.iter_mut().zip(&self.samples) {
                                *r += a * (s - *r);
                            }
                        }
                    }
                    State::Idle { run: 0, run_start }
                }
            }
            State::Contact {
                start,
                run,
                flat,
                lo,
                hi,
            } => {
                let (lo, hi) = (lo.min(score), hi.max(score));
                let (flat, lo, hi) = if hi - lo > cfg.stale_band {
                    (0, score, score)
                } else {
                    (flat + 1, lo, hi)
                };
                if score < exit {
                    if run + 1 >= cfg.min_exit_frames.max(1) {
                        event = Some(ContactEvent::PressEnd {
                            start_us: start,
                            t_us,
                            reason: EndReason::Released,
                        });
                        State::Idle {
                            run: 0,
                            run_start: t_us,
                        }
                    } else {
                        State::Contact {
                            start,
                            run: run + 1,
                            flat,
                            lo,
                            hi,
                        }
                    }
                } else if cfg.stale_after_frames > 0 && flat >= cfg.stale_after_frames {
                    tracing::warn!(
                        "contact score stayed at {score:.1} for {flat} frames: taking the reference as stale and re-capturing it"
                    );
                    event = Some(ContactEvent::PressEnd {
                        start_us: start,
                        t_us,
                        reason: EndReason::StaleReference,
                    });
                    // This frame is the first of the new reference.
                    self.reference.copy_from_slice(&self.samples);
                    self.acc.copy_from_slice(&self.samples);
                    State::Capturing { n: 1 }
                } else {
                    State::Contact {
                        start,
                        run: 0,
                        flat,
                        lo,
                        hi,
                    }
                }
            }
        };
        ContactUpdate {
            score,
            in_contact: self.in_contact(),
            event,
            quiet,
        }
    }
}

/// Mean of each 4x4 block (per channel): averaging cuts camera noise by 4
/// while keeping the contact's shading and texture.
fn sample(image: &RgbImage, out: &mut [f32]) {
    let (w, h) = (image.width() as usize, image.height() as usize);
    let raw = image.as_raw();
    out.fill(0.0);
    let rows = h.min(SAMPLES_Y * STEP);
    let cols = w.min(SAMPLES_X * STEP);
    for y in 0..rows {
        let row = &raw[y * w * 3..][..cols * 3];
        let base = (y / STEP) * SAMPLES_X * 3;
        for (sx, block) in row.chunks_exact(STEP * 3).enumerate() {
            let o = base + sx * 3;
            let mut acc = [0u32; 3];
            for px in block.chunks_exact(3) {
                acc[0] += px[0] as u32;
                acc[1] += px[1] as u32;
                acc[2] += px[2] as u32;
            }
            out[o] += acc[0] as f32;
            out[o + 1] += acc[1] as f32;
            out[o + 2] += acc[2] as f32;
        }
    }
    let inv = 1.0 / (STEP * STEP) as f32;
    out.iter_mut().for_each(|v| *v *= inv);
}

fn mad(a: &[f32], b: &[f32]) -> f32 {
    let s: f32 = a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum();
    s / a.len() as f32
}
