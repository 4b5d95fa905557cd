//! Contact detection: compare each frame with a no-contact reference.
//!
//! The score is the mean absolute difference (0..255) between the frame and
//! the reference, both averaged over 4x4 blocks (60x80 blocks x 3 channels),
//! after the best per-channel gain has been taken out of the frame
//! (`gain_compensated`, least squares over the blocks): a wander of the
//! LEDs' brightness or the camera's exposure changes every block of a
//! channel by the same factor and scores as noise, while contact changes
//! the gel's shading from place to place. Thresholds are relative to the
//! noise floor (the score of untouched frames, mostly camera noise, about
//! 0.4 on a DIGIT), which is tracked while idle.
//! Hysteresis: contact starts after a run of consecutive frames with
//! score >= floor + `enter` and ends after a run of consecutive frames with
//! score < floor + `exit` (`exit` < `enter`). A run counts in frames and in
//! capture time: it starts a press at `min_enter_frames` frames, or sooner
//! once it spans `enter_ms` (never on one frame), and ends one at
//! `min_exit_frames` frames, or sooner once it spans `exit_ms`. The
//! defaults start a press on the second frame in a row at any frame rate
//! and end one on the fifth at 60 fps, or once the run spans 60 ms (the
//! third at 30 fps), so a press ends as soon after its last contact at
//! 30 fps as at 60 rather than twice as late. Timestamps that do not
//! advance (a clock that is not there) leave the frame counts in force.
//! Press-start carries the timestamp of the first frame of the run that
//! crossed `enter`.
//!
//! The reference is the mean of the first `reference_frames` frames (the
//! sensor must not be touched at start), or of the frames after
//! [`ContactDetector::recapture`]. A capture restarts while the frames move
//! (a hand on the sensor at start-up): every frame of it must stay within
//! `capture_motion` of the first. The detector keeps the reference twice: as
//! 4x4 block means for scoring, and at full resolution
//! ([`ContactDetector::reference_pixels`], with a version number that changes
//! whenever it does) for encoders that subtract it, so the detector is the
//! one place a pipeline's reference lives.
//!
//! The reference is kept fresh three ways:
//! - while there is no contact and the score is below `exit`, it follows the
//!   frames slowly (exponential average with weight `background_alpha`;
//!   the full-resolution copy every `full_every` quiet frames), absorbing
//!   LED warm-up and temperature drift;
//! - after every release it is re-established: once the gel has settled
//!   (`settle_ms` of quiet frames), the mean of the next `reference_frames`
//!   quiet frames replaces it (`renew_after_release`);
//! - a reference gone stale while "in contact" (the gel settled, the LEDs
//!   changed) shows as a contact whose score stays flat for
//!   `stale_after_ms`; then the reference is re-captured from the
//!   current frames and the press ends with [`EndReason::StaleReference`].
//!
//! A reference captured while something touched the sensor (a press that
//! started before the daemon did) holds fabric detail that an untouched
//! sensor does not show. When a "press" starts on a frame with clearly less
//! fine detail than the reference (`touched_reference_ratio`), it is the
//! release of that earlier touch, not a press: no press starts
//! ([`ContactEvent::ReferenceRejected`]) and the reference is re-captured.
//!
//! Pure and deterministic: timestamps come with the frames.

use image::RgbImage;

use crate::frame::{FRAME_H, FRAME_W};

const STEP: usize = 4;
const SAMPLES_X: usize = FRAME_W as usize / STEP;
const SAMPLES_Y: usize = FRAME_H as usize / STEP;
const SAMPLES: usize = SAMPLES_X * SAMPLES_Y * 3;
/// Values in a full-resolution frame.
const FULL: usize = (FRAME_W * FRAME_H * 3) as usize;

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
    /// Consecutive frames at or above `enter` that start a press.
    pub min_enter_frames: u32,
    /// A run of two or more frames at or above `enter` that spans this many
    /// milliseconds of capture time (from its first frame to this one)
    /// starts a press before `min_enter_frames` (0 = frames only).
    pub enter_ms: f32,
    /// Consecutive frames below `exit` that end a press.
    pub min_exit_frames: u32,
    /// A run of two or more frames below `exit` that spans this many
    /// milliseconds ends a press before `min_exit_frames` (0 = frames only).
    pub exit_ms: f32,
    /// Weight of a no-contact frame in the slowly updated reference (0 = frozen).
    pub background_alpha: f32,
    /// A contact whose score varies by less than `stale_band` for this
    /// long (milliseconds of frame time) is taken as a stale reference
    /// (0 = never), unless the frame shows fabric: clearly more fine
    /// detail than the reference (by `touched_reference_ratio`), which a
    /// steady press held in a jig does and a settled gel or a changed LED
    /// does not; then the wait starts again.
    pub stale_after_ms: f32,
    /// Score band for the stale test.
    pub stale_band: f32,
    /// A reference capture restarts when a frame's score against the first
    /// frame of the capture reaches this (the sensor is moving).
    pub capture_motion: f32,
    /// After this many restarts the capture is accepted anyway.
    pub max_capture_restarts: u32,
    /// Re-establish the reference after each release.
    pub renew_after_release: bool,
    /// Milliseconds of quiet frames after a release before the new
    /// reference is averaged (the gel relaxes).
    pub settle_ms: f32,
    /// The full-resolution reference follows every n-th quiet frame.
    pub full_every: u32,
    /// A press start whose frame has less fine detail than the reference
    /// by this factor means the reference was captured touched (0 = off).
    pub touched_reference_ratio: f32,
    /// A would-be press that a per-channel gain change of the reference
    /// explains (what is left is below `exit` and under a quarter of the
    /// score) is a lighting change (an LED or exposure step), not contact:
    /// the reference is re-captured. Off by default: a weak press of a soft
    /// fabric can be mostly a brightness shift, and losing it would be
    /// worse than a rare false press after an unannounced LED step (which
    /// the stale-reference rule ends); LED changes the daemon makes itself
    /// re-capture the reference. With `gain_compensated` a gain change
    /// already scores as noise, and the check never fires.
    pub lighting_check: bool,
    /// Score what is left of the change after the best per-channel gain
    /// (least squares over the blocks) has been taken out: a brightness
    /// wander of the LEDs or the camera's exposure, which changes every
    /// block by the same factor, scores as noise, while contact, which
    /// changes the gel's shading from place to place, still scores.
    pub gain_compensated: bool,
    /// Score the most changed region rather than the whole frame: the
    /// frame is cut into tiles of `tile` x `tile` blocks (4 px each;
    /// partial tiles at the edges count as tiles) and the score is the
    /// highest tile's mean (0 = the whole frame's mean). A domed gel
    /// touches first at one place (its crown, or the side a tilt
    /// lowers), which a whole-frame mean dilutes; noise and lighting
    /// change everywhere alike.
    pub tile: u32,
}

impl Default for ContactConfig {
    fn default() -> Self {
        ContactConfig {
            reference_frames: 8,
            enter: 0.35,
            exit: 0.2,
            initial_floor: 0.5,
            max_floor: 2.0,
            // Two frames in a row (`telextiles-lab contact-choose`,
            // docs/benchmarks.md "The contact detector"): with the gain
            // taken out, no press started on 0.29 h of simulated idle
            // footage of 7 units, as rendered and with +0.25 % LED
            // flicker per channel. (The span is then
            // moot: a run of two frames always starts a press; kept at a
            // frame at 60 fps less the jitter margin, for a config that
            // asks for more frames.)
            min_enter_frames: 2,
            enter_ms: 1000.0 / 60.0 - 3.0,
            min_exit_frames: 5,
            exit_ms: 60.0,
            background_alpha: 0.01,
            stale_after_ms: 30_000.0,
            stale_band: 0.3,
            capture_motion: 1.2,
            max_capture_restarts: 240,
            renew_after_release: true,
            settle_ms: 250.0,
            full_every: 4,
            touched_reference_ratio: 1.3,
            // Off: a weak press of a soft fabric can look like a brightness
            // step; the daemon re-captures after the LED changes it makes.
            lighting_check: false,
            // On: without it, the exposure wander of catalogue 2's
            // simulated units starts hundreds of presses an hour at rest.
            gain_compensated: true,
            tile: 0,
        }
    }
}

impl ContactConfig {
    /// The shipped detector with another entry threshold and run, as a
    /// user sets them (`contact_enter`, `contact_frames`): the exit
    /// threshold is the shipped one, or 0.6 × the entry threshold when
    /// that is lower; a run of `frames` also starts a press once it spans
    /// (`frames` - 1) frames at 60 fps less 3 ms of capture time, so that
    /// at 30 fps it takes as long as at 60.
    pub fn with_entry(enter: f32, frames: u32) -> Result<ContactConfig, String> {
        if !(enter.is_finite() && enter > 0.0 && enter <= 50.0) {
            return Err(format!(
                "the contact threshold {enter} is out of range: 0 < enter <= 50 (score above the noise floor, 0..255 grey levels; shipped 0.35)"
            ));
        }
        if !(1..=30).contains(&frames) {
            return Err(format!(
                "{frames} frames in a row to start a press is out of range: 1 to 30 (shipped 2)"
            ));
        }
        let mut c = ContactConfig::default();
        c.enter = enter;
        c.exit = c.exit.min(0.6 * enter);
        c.min_enter_frames = frames;
        c.enter_ms = (frames.saturating_sub(1) as f32 * 1000.0 / 60.0 - 3.0).max(0.0);
        Ok(c)
    }

    /// This detector scoring the most changed tile of `tile` x `tile`
    /// blocks of 4 px (0: the whole frame, as shipped), as a user sets it
    /// (`contact_tile`). A tile's score is higher at rest than the whole
    /// frame's: the entry threshold must be raised with it
    /// (docs/benchmarks.md, "The most changed tile").
    pub fn with_tile(mut self, tile: u32) -> Result<ContactConfig, String> {
        if tile > SAMPLES_Y as u32 {
            return Err(format!(
                "a tile of {tile} blocks is out of range: 0 (the whole frame) to {SAMPLES_Y} blocks of 4 px (shipped 0)"
            ));
        }
        self.tile = tile;
        Ok(self)
    }
}

pub use telextiles_press::{ContactEvent, EndReason};

/// Result of one frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactUpdate {
    /// The detector's score: the mean absolute difference from the
    /// reference over the whole frame, or over its most changed tile
    /// ([`ContactConfig::tile`]) (0 while capturing the reference).
    pub score: f32,
    /// How deep the contact is: the whole frame's mean absolute difference
    /// from the reference, scored as `score` is (after the gain), which
    /// weights the frame in a press's mean ([`crate::decide::contact_weight`]).
    /// It is `score` when the whole frame is scored; with a tile, a touch
    /// at one place scores high and is shallow (0 while capturing).
    pub depth: f32,
    /// Whether a press is in progress after this frame.
    pub in_contact: bool,
    /// How much of the gel the contact covers on this frame, 0..=1: the
    /// share of the frame's 4x4 blocks that it changed ([`coverage`]); 0
    /// when no press is in progress. A press held flat covers most of the
    /// gel; a tilted one touches a band or a corner, which tells the
    /// encoder less about the cloth (`docs/benchmarks.md`, "How much of the
    /// gel a press touches").
    pub coverage: f32,
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
        restarts: u32,
    },
    Idle {
        run: u32,
        run_start: u64,
        /// The reference is being re-established after a release (None:
        /// not renewing).
        renew: Option<Renew>,
    },
    Contact {
        start: u64,
        run: u32,
        /// Timestamp of the first frame of the release run (when `run` > 0).
        run_start: u64,
        /// When the score entered its current flat band.
        flat_since: u64,
        lo: f32,
        hi: f32,
    },
}

/// Re-establishing the reference after a release.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Renew {
    /// Timestamp of the first of the quiet frames in a row (None: the last
    /// frame was not quiet).
    quiet_since: Option<u64>,
    /// Frames averaged into the new reference so far.
    collected: u32,
}

impl Renew {
    const START: Renew = Renew {
        quiet_since: None,
        collected: 0,
    };
}

/// The contact detector (see the module docs).
#[derive(Clone, Debug)]
pub struct ContactDetector {
    cfg: ContactConfig,
    reference: Vec<f32>,
    acc: Vec<f32>,
    samples: Vec<f32>,
    /// First frame of a capture (block means), for the motion test.
    first: Vec<f32>,
    /// Full-resolution reference, RGB interleaved, 0..255 (empty: none yet).
    full: Vec<f32>,
    full_acc: Vec<f32>,
    /// Bumped whenever `full` changes.
    version: u64,
    quiet_count: u32,
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
            first: vec![0.0; SAMPLES],
            full: Vec::new(),
            full_acc: vec![0.0; FULL],
            version: 0,
            quiet_count: 0,
            state: State::Capturing { n: 0, restarts: 0 },
            pending_end: None,
        }
    }

    /// A detector with a known reference frame (e.g. a recording's own
    /// no-contact frames, or the simulator's background).
    pub fn with_reference(cfg: ContactConfig, reference: &RgbImage) -> ContactDetector {
        let px: Vec<f32> = reference.as_raw().iter().map(|&v| v as f32).collect();
        ContactDetector::with_reference_pixels(cfg, &px)
    }

    /// A detector with a known reference given as full-resolution RGB
    /// values (240x320x3, interleaved, 0..255; e.g. the mean of a
    /// recording's quiet frames, see [`mean_pixels`]).
    ///
    /// # Panics
    /// If `pixels` is not 240x320x3 long.
    pub fn with_reference_pixels(cfg: ContactConfig, pixels: &[f32]) -> ContactDetector {
        assert_eq!(pixels.len(), FULL, "reference size");
        let mut d = ContactDetector::new(cfg);
        d.set_full(pixels);
        sample_f32(pixels, &mut d.reference);
        d.state = State::Idle {
            run: 0,
            run_start: 0,
            renew: None,
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

    /// Frames in the run that may start a press: consecutive frames at or
    /// above the entry threshold while idle, this one included (0 in a
    /// press, while capturing, or when the last frame was below it). The
    /// press starts on the frame that brings it to `min_enter_frames` (or
    /// sooner at a low frame rate, see [`ContactConfig::enter_ms`]), and
    /// its start is the run's first frame.
    pub fn pending_run(&self) -> u32 {
        match self.state {
            State::Idle { run, .. } => run,
            _ => 0,
        }
    }

    /// The score below which a frame counts towards release (noise floor +
    /// `exit`): frames of a press below it are already lifted.
    pub fn release_threshold(&self) -> f32 {
        self.floor + self.cfg.exit
    }

    /// The current noise floor estimate.
    pub fn floor(&self) -> f32 {
        self.floor
    }

    /// Whether the reference is being (re)captured.
    pub fn capturing(&self) -> bool {
        matches!(self.state, State::Capturing { .. })
    }

    /// Whether the reference is being re-established after a release.
    pub fn renewing(&self) -> bool {
        matches!(self.state, State::Idle { renew: Some(_), .. })
    }

    /// The full-resolution reference (240x320x3 RGB, interleaved, 0..255),
    /// None until the first capture completes.
    pub fn reference_pixels(&self) -> Option<&[f32]> {
        (!self.full.is_empty()).then_some(self.full.as_slice())
    }

    /// Changes whenever [`ContactDetector::reference_pixels`] does.
    pub fn reference_version(&self) -> u64 {
        self.version
    }

    /// Re-capture the reference from the next frames (the sensor must be
    /// free). A press in progress ends on the next frame with
    /// [`EndReason::Recapture`]. The current reference stays in use until
    /// the new one is complete.
    pub fn recapture(&mut self) {
        if let State::Contact { start, .. } = self.state {
            self.pending_end = Some((start, EndReason::Recapture));
        }
        self.state = State::Capturing { n: 0, restarts: 0 };
    }

    /// Forget a press in progress (the frames stopped: end of a recording),
    /// keeping the reference. The next touched frames start a new press.
    pub fn reset(&mut self) {
        self.pending_end = None;
        if !self.capturing() {
            self.state = State::Idle {
                run: 0,
                run_start: 0,
                renew: None,
            };
        }
    }

    fn set_full(&mut self, pixels: &[f32]) {
        self.full.clear();
        self.full.extend_from_slice(pixels);
        self.version += 1;
        self.quiet_count = 0;
    }

    /// Add a frame to the full-resolution accumulator (`n` frames so far).
    fn accumulate_full(&mut self, image: &RgbImage, n: u32) {
        let raw = image.as_raw();
        if raw.len() != FULL {
            return;
        }
        if n == 0 {
            for (a, &v) in self.full_acc.iter_mut().zip(raw) {
                *a = v as f32;
            }
        } else {
            for (a, &v) in self.full_acc.iter_mut().zip(raw) {
                *a += v as f32;
            }
        }
    }

    /// The accumulators (`n` frames) become the reference.
    fn commit_reference(&mut self, n: u32) {
        let inv = 1.0 / n.max(1) as f32;
        for (r, a) in self.reference.iter_mut().zip(&self.acc) {
            *r = a * inv;
        }
        self.full_acc.iter_mut().for_each(|a| *a *= inv);
        std::mem::swap(&mut self.full, &mut self.full_acc);
        if self.full_acc.len() != FULL {
            self.full_acc = vec![0.0; FULL];
        }
        self.version += 1;
        self.quiet_count = 0;
    }

    /// A quiet idle frame: the references follow it slowly.
    fn follow(&mut self, image: &RgbImage) {
        let a = self.cfg.background_alpha;
        if a <= 0.0 {
            return;
        }
        for (r, s) in self.reference.iter_mut().zip(&self.samples) {
            *r += a * (s - *r);
        }
        let every = self.cfg.full_every.max(1);
        self.quiet_count += 1;
        if self.quiet_count >= every && self.full.len() == FULL && image.as_raw().len() == FULL {
            self.quiet_count = 0;
            let a = (a * every as f32).min(1.0);
            for (r, &v) in self.full.iter_mut().zip(image.as_raw()) {
                *r += a * (v as f32 - *r);
            }
            self.version += 1;
        }
    }

    /// Score a frame against the reference without changing state.
    pub fn score(&mut self, image: &RgbImage) -> f32 {
        sample(image, &mut self.samples);
        self.score_samples().0
    }

    /// The score and the depth of the sampled frame (see
    /// [`ContactConfig::gain_compensated`], [`ContactUpdate::depth`]),
    /// and the per-channel gain they were taken after.
    fn score_samples(&self) -> (f32, f32, [f32; 3]) {
        let g = if self.cfg.gain_compensated {
            channel_gains(&self.samples, &self.reference)
        } else {
            [1.0; 3]
        };
        let (score, depth) = self.score_with(g);
        (score, depth, g)
    }

    /// The score and the depth after the best per-channel gain has been
    /// taken out.
    fn gain_residual(&self) -> (f32, f32) {
        self.score_with(channel_gains(&self.samples, &self.reference))
    }

    /// The score (over the whole frame or its worst tile) and the depth
    /// (over the whole frame) of the sampled frame against the reference
    /// scaled by `g` per channel.
    fn score_with(&self, g: [f32; 3]) -> (f32, f32) {
        if self.cfg.tile == 0 {
            let whole = residual(&self.samples, &self.reference, g);
            (whole, whole)
        } else {
            worst_tile(&self.samples, &self.reference, g, self.cfg.tile as usize)
        }
    }

    /// Feed one frame (must be 240x320; smaller images are sampled where they
    /// have pixels).
    pub fn update(&mut self, image: &RgbImage, t_us: u64) -> ContactUpdate {
        sample(image, &mut self.samples);
        if let State::Capturing { n, restarts } = self.state {
            let mut event =
                self.pending_end
                    .take()
                    .map(|(start_us, reason)| ContactEvent::PressEnd {
                        start_us,
                        t_us,
                        reason,
                    });
            let moved = n > 0
                && restarts < self.cfg.max_capture_restarts
                && mad(&self.samples, &self.first) >= self.cfg.capture_motion;
            let (n, restarts) = if moved {
                (0, restarts + 1)
            } else {
                (n, restarts)
            };
            if n == 0 {
                self.first.copy_from_slice(&self.samples);
                self.acc.iter_mut().for_each(|a| *a = 0.0);
            }
            for (a, s) in self.acc.iter_mut().zip(&self.samples) {
                *a += s;
            }
            self.accumulate_full(image, n);
            let n = n + 1;
            if n >= self.cfg.reference_frames.max(1) {
                self.commit_reference(n);
                self.state = State::Idle {
                    run: 0,
                    run_start: t_us,
                    renew: None,
                };
                if event.is_none() {
                    event = Some(ContactEvent::ReferenceCaptured { t_us });
                }
            } else {
                self.state = State::Capturing { n, restarts };
            }
            return ContactUpdate {
                score: 0.0,
                depth: 0.0,
                in_contact: false,
                coverage: 0.0,
                event,
                quiet: true,
            };
        }
        let (score, depth, gains) = self.score_samples();
        let cfg = &self.cfg;
        let (enter, exit) = (self.floor + cfg.enter, self.floor + cfg.exit);
        let mut event = None;
        let mut quiet = false;
        self.state = match self.state.clone() {
            State::Capturing { .. } => unreachable!("handled above"),
            State::Idle {
                run,
                run_start,
                renew,
            } => {
                if score >= enter {
                    let run_start = if run == 0 { t_us } else { run_start };
                    if run_done(run + 1, cfg.min_enter_frames, run_start, t_us, cfg.enter_ms) {
                        // Only a change that a gain explains almost entirely
                        // (what is left is noise, and a small part of the
                        // change): a soft fabric's weak press, whose change
                        // is partly a shift of brightness, must stay a press.
                        let lighting = cfg.lighting_check && {
                            let residual = self.gain_residual().0;
                            residual < exit && score >= 4.0 * residual
                        };
                        if lighting || self.touched_reference(image) {
                            if lighting {
                                tracing::warn!(
                                    "the sensor's lighting changed (score {score:.2}, but a per-channel gain explains it): re-capturing the reference"
                                );
                            } else {
                                tracing::warn!(
                                    "the no-contact reference shows more detail than the sensor does now: it was captured while touched; re-capturing it"
                                );
                            }
                            event = Some(ContactEvent::ReferenceRejected { t_us });
                            self.first.copy_from_slice(&self.samples);
                            self.acc.copy_from_slice(&self.samples);
                            self.accumulate_full(image, 0);
                            State::Capturing { n: 1, restarts: 0 }
                        } else {
                            event = Some(ContactEvent::PressStart { t_us: run_start });
                            State::Contact {
                                start: run_start,
                                run: 0,
                                run_start: t_us,
                                flat_since: t_us,
                                lo: score,
                                hi: score,
                            }
                        }
                    } else {
                        State::Idle {
                            run: run + 1,
                            run_start,
                            renew,
                        }
                    }
                } else if score < exit {
                    quiet = true;
                    self.floor = (self.floor + 0.05 * (score - self.floor)).min(cfg.max_floor);
                    let settle_us = (cfg.settle_ms.max(0.0) * 1000.0) as u64;
                    let frames = cfg.reference_frames.max(1);
                    let renew = match renew {
                        Some(r) => {
                            let since = r.quiet_since.unwrap_or(t_us);
                            if t_us.saturating_sub(since) >= settle_us {
                                // Settled: averaging the new reference.
                                let n = r.collected;
                                if n == 0 {
                                    self.acc.copy_from_slice(&self.samples);
                                } else {
                                    for (a, s) in self.acc.iter_mut().zip(&self.samples) {
                                        *a += s;
                                    }
                                }
                                self.accumulate_full(image, n);
                                if n + 1 >= frames {
                                    self.commit_reference(n + 1);
                                    event = Some(ContactEvent::ReferenceCaptured { t_us });
                                    None
                                } else {
                                    Some(Renew {
                                        quiet_since: Some(since),
                                        collected: n + 1,
                                    })
                                }
                            } else {
                                Some(Renew {
                                    quiet_since: Some(since),
                                    collected: 0,
                                })
                            }
                        }
                        None => {
                            self.follow(image);
                            None
                        }
                    };
                    State::Idle {
                        run: 0,
                        run_start,
                        renew,
                    }
                } else {
                    // Neither touched nor quiet: a renewal starts over.
                    State::Idle {
                        run: 0,
                        run_start,
                        renew: renew.map(|_| Renew::START),
                    }
                }
            }
            State::Contact {
                start,
                run,
                run_start,
                flat_since,
                lo,
                hi,
            } => {
                let (lo, hi) = (lo.min(score), hi.max(score));
                let (flat_since, lo, hi) = if hi - lo > cfg.stale_band {
                    (t_us, score, score)
                } else {
                    (flat_since, lo, hi)
                };
                let flat_us = t_us.saturating_sub(flat_since);
                if score < exit {
                    let run_start = if run == 0 { t_us } else { run_start };
                    if run_done(run + 1, cfg.min_exit_frames, run_start, t_us, cfg.exit_ms) {
                        event = Some(ContactEvent::PressEnd {
                            start_us: start,
                            t_us,
                            reason: EndReason::Released,
                        });
                        State::Idle {
                            run: 0,
                            run_start: t_us,
                            renew: cfg.renew_after_release.then_some(Renew::START),
                        }
                    } else {
                        State::Contact {
                            start,
                            run: run + 1,
                            run_start,
                            flat_since,
                            lo,
                            hi,
                        }
                    }
                } else if cfg.stale_after_ms > 0.0
                    && flat_us as f64 >= cfg.stale_after_ms as f64 * 1000.0
                {
                    if self.shows_fabric(image) {
                        // A steady press, held: not a stale reference; the
                        // wait starts again.
                        State::Contact {
                            start,
                            run: 0,
                            run_start,
                            flat_since: t_us,
                            lo: score,
                            hi: score,
                        }
                    } else {
                        tracing::warn!(
                            "contact score stayed at {score:.1} for {:.1} s: taking the reference as stale and re-capturing it",
                            flat_us as f64 / 1e6
                        );
                        event = Some(ContactEvent::PressEnd {
                            start_us: start,
                            t_us,
                            reason: EndReason::StaleReference,
                        });
                        // This frame is the first of the new reference.
                        self.reference.copy_from_slice(&self.samples);
                        self.first.copy_from_slice(&self.samples);
                        self.acc.copy_from_slice(&self.samples);
                        self.accumulate_full(image, 0);
                        State::Capturing { n: 1, restarts: 0 }
                    }
                } else {
                    State::Contact {
                        start,
                        run: 0,
                        run_start,
                        flat_since,
                        lo,
                        hi,
                    }
                }
            }
        };
        let in_contact = self.in_contact();
        // Against the reference the frame was scored on (a stale one is
        // re-captured above, and its press has ended).
        let coverage = if in_contact {
            coverage(&self.samples, &self.reference, gains, enter)
        } else {
            0.0
        };
        ContactUpdate {
            score,
            depth,
            in_contact,
            coverage,
            event,
            quiet,
        }
    }
}

impl ContactDetector {
    /// Whether the reference holds clearly more fine detail than `image`
    /// (see the module docs).
    fn touched_reference(&self, image: &RgbImage) -> bool {
        self.detail_of(image)
            .is_some_and(|(now, refd, ratio)| refd > ratio * now + 0.05)
    }

    /// Whether `image` holds clearly more fine detail than the reference
    /// (by `touched_reference_ratio`): fabric pressed on the gel, not a
    /// settled gel or a change of lighting (see
    /// [`ContactConfig::stale_after_ms`]).
    fn shows_fabric(&self, image: &RgbImage) -> bool {
        self.detail_of(image)
            .is_some_and(|(now, refd, ratio)| now > ratio * refd + 0.05)
    }

    /// The fine detail of `image` and of the reference, and the ratio
    /// that makes one clearly more detailed than the other; None when the
    /// check is off or either is not a full frame.
    fn detail_of(&self, image: &RgbImage) -> Option<(f32, f32, f32)> {
        let ratio = self.cfg.touched_reference_ratio;
        if ratio <= 0.0 || self.full.len() != FULL || image.as_raw().len() != FULL {
            return None;
        }
        let raw = image.as_raw();
        Some((detail(|i| raw[i] as f32), detail(|i| self.full[i]), ratio))
    }
}

/// Fine detail of a frame: the mean absolute difference between
/// horizontally and vertically adjacent pixels (green channel, every other
/// row), in the inner half of the frame where the gel is lit evenly.
fn detail(px: impl Fn(usize) -> f32) -> f32 {
    let (w, h) = (FRAME_W as usize, FRAME_H as usize);
    let (x0, x1, y0, y1) = (w / 4, 3 * w / 4, h / 4, 3 * h / 4);
    let mut s = 0.0f32;
    let mut n = 0u32;
    for y in (y0..y1).step_by(2) {
        for x in x0..x1 {
            let i = (y * w + x) * 3 + 1;
            let c = px(i);
            s += (c - px(i + 3)).abs() + (c - px(i + w * 3)).abs();
            n += 2;
        }
    }
    s / n.max(1) as f32
}

/// Mean of every frame of `frames` as full-resolution RGB values
/// (240x320x3, interleaved, 0..255): a recording's reference from its quiet
/// frames. None when `frames` is empty or a frame has another size.
pub fn mean_pixels(frames: &[RgbImage]) -> Option<Vec<f32>> {
    if frames.is_empty() || frames.iter().any(|f| f.as_raw().len() != FULL) {
        return None;
    }
    let mut acc = vec![0.0f32; FULL];
    for f in frames {
        for (a, &v) in acc.iter_mut().zip(f.as_raw()) {
            *a += v as f32;
        }
    }
    let inv = 1.0 / frames.len() as f32;
    acc.iter_mut().for_each(|a| *a *= inv);
    Some(acc)
}

/// Block means of full-resolution RGB values (as [`sample`] does for u8).
fn sample_f32(px: &[f32], out: &mut [f32]) {
    let w = FRAME_W as usize;
    out.fill(0.0);
    for y in 0..SAMPLES_Y * STEP {
        let base = (y / STEP) * SAMPLES_X * 3;
        for x in 0..SAMPLES_X * STEP {
            let o = base + (x / STEP) * 3;
            let i = (y * w + x) * 3;
            out[o] += px[i];
            out[o + 1] += px[i + 1];
            out[o + 2] += px[i + 2];
        }
    }
    let inv = 1.0 / (STEP * STEP) as f32;
    out.iter_mut().for_each(|v| *v *= inv);
}

/// Mean of each 4x4 block (per channel): averaging cuts camera noise by 4
/// while keeping the contact's shading and texture.
/// Whether a run of `frames` frames, the first at `first_us` and the last
/// at `t_us`, is long enough: `min_frames` of them, or two or more that
/// span `ms` (> 0) of capture time.
fn run_done(frames: u32, min_frames: u32, first_us: u64, t_us: u64, ms: f32) -> bool {
    frames >= min_frames.max(1)
        || (frames >= 2 && ms > 0.0 && t_us.saturating_sub(first_us) as f64 >= ms as f64 * 1e3)
}

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

/// The per-channel gain of `b` that fits `a` best (least squares; 1 for a
/// dark channel).
fn channel_gains(a: &[f32], b: &[f32]) -> [f32; 3] {
    let mut ab = [0.0f64; 3];
    let mut bb = [0.0f64; 3];
    for (i, (x, y)) in a.iter().zip(b).enumerate() {
        ab[i % 3] += (*x as f64) * (*y as f64);
        bb[i % 3] += (*y as f64) * (*y as f64);
    }
    std::array::from_fn(|c| {
        if bb[c] > 0.0 {
            (ab[c] / bb[c]) as f32
        } else {
            1.0
        }
    })
}

/// Mean absolute difference between `a` and `b` with each channel of `b`
/// scaled by `g`.
fn residual(a: &[f32], b: &[f32], g: [f32; 3]) -> f32 {
    let s: f32 = a
        .iter()
        .zip(b)
        .enumerate()
        .map(|(i, (x, y))| (x - g[i % 3] * y).abs())
        .sum();
    s / a.len().max(1) as f32
}

/// The highest mean of [`residual`] over tiles of `tile` x `tile` blocks
/// (the last row and column of tiles may be narrower), and the mean over
/// them all ([`residual`]).
fn worst_tile(a: &[f32], b: &[f32], g: [f32; 3], tile: usize) -> (f32, f32) {
    let tile = tile.max(1);
    let tiles_x = SAMPLES_X.div_ceil(tile);
    let tiles_y = SAMPLES_Y.div_ceil(tile);
    // On the stack (at most one tile per block, 19 KB): nothing allocated
    // per frame.
    let mut sums = [0.0f32; SAMPLES_X * SAMPLES_Y];
    let sum = &mut sums[..tiles_x * tiles_y];
    for (y, (ra, rb)) in a
        .chunks_exact(SAMPLES_X * 3)
        .zip(b.chunks_exact(SAMPLES_X * 3))
        .enumerate()
    {
        let row = (y / tile) * tiles_x;
        for (x, (pa, pb)) in ra.chunks_exact(3).zip(rb.chunks_exact(3)).enumerate() {
            sum[row + x / tile] += (pa[0] - g[0] * pb[0]).abs()
                + (pa[1] - g[1] * pb[1]).abs()
                + (pa[2] - g[2] * pb[2]).abs();
        }
    }
    // A tile's values: its blocks (fewer in the last row and column) x 3.
    let side = |t: usize, n: usize| tile.min(n - t * tile);
    let worst = sum
        .iter()
        .enumerate()
        .map(|(t, s)| s / (3 * side(t % tiles_x, SAMPLES_X) * side(t / tiles_x, SAMPLES_Y)) as f32)
        .fold(0.0, f32::max);
    (worst, sum.iter().sum::<f32>() / a.len().max(1) as f32)
}

/// A block counts as touched when its change is at least this share of
/// the frame's 95th-percentile block change ([`coverage`]).
pub const COVERAGE_SHARE: f32 = 0.2;

/// The share of the blocks (4x4 px block means, `a` against `b` with each
/// channel of `b` scaled by `g`) whose mean absolute change over the
/// three channels reaches both `min_change` (the press threshold: less is
/// camera noise) and [`COVERAGE_SHARE`] of the frame's 95th-percentile
/// block change (relative, so that a soft fabric's weak change and a hard
/// one's strong change both count where they are). 0 for empty input.
pub fn coverage(a: &[f32], b: &[f32], g: [f32; 3], min_change: f32) -> f32 {
    // On the stack (one value per block, 19 KB): nothing allocated per frame.
    let mut change = [0.0f32; SAMPLES_X * SAMPLES_Y];
    let n = (a.len().min(b.len()) / 3).min(change.len());
    if n == 0 {
        return 0.0;
    }
    for (c, (pa, pb)) in change
        .iter_mut()
        .zip(a.chunks_exact(3).zip(b.chunks_exact(3)))
    {
        *c = ((pa[0] - g[0] * pb[0]).abs()
            + (pa[1] - g[1] * pb[1]).abs()
            + (pa[2] - g[2] * pb[2]).abs())
            / 3.0;
    }
    let change = &change[..n];
    let mut sorted = [0.0f32; SAMPLES_X * SAMPLES_Y];
    let sorted = &mut sorted[..n];
    sorted.copy_from_slice(change);
    let k = ((n - 1) as f32 * 0.95) as usize;
    let (_, p95, _) = sorted.select_nth_unstable_by(k, f32::total_cmp);
    let threshold = (COVERAGE_SHARE * *p95).max(min_change);
    if !threshold.is_finite() {
        return 0.0;
    }
    change.iter().filter(|&&c| c >= threshold).count() as f32 / n as f32
}

fn mad(a: &[f32], b: &[f32]) -> f32 {
    let s: f32 = a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum();
    s / a.len() as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Block samples of a smooth, coloured background.
    fn background() -> Vec<f32> {
        (0..SAMPLES)
            .map(|i| {
                let (b, c) = (i / 3, i % 3);
                let (x, y) = ((b % SAMPLES_X) as f32, (b / SAMPLES_X) as f32);
                60.0 + 40.0 * c as f32 + 0.3 * x + 0.2 * y
            })
            .collect()
    }

    /// `b` with `dn` added to the blocks `x0..x1` x `y0..y1`.
    fn touched(b: &[f32], (x0, x1): (usize, usize), (y0, y1): (usize, usize), dn: f32) -> Vec<f32> {
        let mut a = b.to_vec();
        for y in y0..y1 {
            for x in x0..x1 {
                for c in 0..3 {
                    a[(y * SAMPLES_X + x) * 3 + c] += dn;
                }
            }
        }
        a
    }

    #[test]
    fn coverage_is_the_share_of_the_frame_a_contact_changed() {
        let b = background();
        let g = [1.0; 3];
        // the whole frame, a third of it (a tilted press's band), a corner
        let whole = touched(&b, (0, SAMPLES_X), (0, SAMPLES_Y), 6.0);
        assert!((coverage(&whole, &b, g, 0.75) - 1.0).abs() < 1e-6);
        let band = touched(&b, (0, SAMPLES_X / 3), (0, SAMPLES_Y), 6.0);
        assert!((coverage(&band, &b, g, 0.75) - 1.0 / 3.0).abs() < 1e-3);
        let corner = touched(&b, (0, SAMPLES_X / 4), (0, SAMPLES_Y / 4), 6.0);
        assert!((coverage(&corner, &b, g, 0.75) - 1.0 / 16.0).abs() < 1e-3);
        // nothing changed: no block reaches the press threshold
        assert_eq!(coverage(&b, &b, g, 0.75), 0.0);
        // relative: a soft fabric's weak change over the whole gel counts
        // in full, and a strong touch in one place does not make the
        // faint rest of the frame count
        let weak = touched(&b, (0, SAMPLES_X), (0, SAMPLES_Y), 1.0);
        assert!((coverage(&weak, &b, g, 0.75) - 1.0).abs() < 1e-6);
        let strong = touched(&band, (0, SAMPLES_X / 3), (0, SAMPLES_Y), 30.0);
        let faint_rest = touched(&strong, (SAMPLES_X / 3, SAMPLES_X), (0, SAMPLES_Y), 1.0);
        assert!((coverage(&faint_rest, &b, g, 0.75) - 1.0 / 3.0).abs() < 1e-3);
        // below the press threshold everywhere: camera noise, not contact
        let noise = touched(&b, (0, SAMPLES_X), (0, SAMPLES_Y), 0.5);
        assert_eq!(coverage(&noise, &b, g, 0.75), 0.0);
        // degenerate input
        assert_eq!(coverage(&[], &[], g, 0.75), 0.0);
    }

    #[test]
    fn a_tile_as_large_as_the_frame_scores_as_the_whole_frame() {
        let b = background();
        let a = touched(&b, (3, 17), (40, 52), 5.0);
        let g = channel_gains(&a, &b);
        let whole = residual(&a, &b, g);
        assert!(whole > 0.0);
        for tile in [SAMPLES_Y, SAMPLES_Y + 7] {
            assert!((worst_tile(&a, &b, g, tile).0 - whole).abs() < 1e-4);
        }
    }

    #[test]
    fn a_touch_in_one_place_scores_in_full_on_its_tile_and_diluted_on_the_frame() {
        let b = background();
        // One 40 px tile of 60 x 80 blocks' 48, changed by 3 DN.
        let a = touched(&b, (20, 30), (40, 50), 3.0);
        let g = [1.0; 3];
        let whole = residual(&a, &b, g);
        assert!((whole - 3.0 / 48.0).abs() < 1e-3, "{whole}");
        assert!((worst_tile(&a, &b, g, 10).0 - 3.0).abs() < 1e-3);
        // The depth stays the whole frame's.
        assert!((worst_tile(&a, &b, g, 10).1 - whole).abs() < 1e-4);
        // Straddling four tiles, the worst holds a quarter of it.
        let a = touched(&b, (15, 25), (35, 45), 3.0);
        assert!((worst_tile(&a, &b, g, 10).0 - 0.75).abs() < 1e-3);
        // Tiles that do not divide the frame: the last column's tiles are
        // 4 blocks wide and score their own mean.
        let a = touched(&b, (56, 60), (0, 7), 2.0);
        assert!((worst_tile(&a, &b, g, 7).0 - 2.0).abs() < 1e-3);
    }

    #[test]
    fn a_change_of_lighting_scores_as_nothing_on_every_tile() {
        let b = background();
        let a: Vec<f32> = b
            .iter()
            .enumerate()
            .map(|(i, v)| v * [1.03, 0.98, 1.01][i % 3])
            .collect();
        let g = channel_gains(&a, &b);
        assert!(worst_tile(&a, &b, g, 10).0 < 1e-3);
        assert!(worst_tile(&a, &b, [1.0; 3], 10).0 > 0.5);
    }
}
