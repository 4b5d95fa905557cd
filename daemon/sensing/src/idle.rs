//! The contact detector on a resting sensor: does it start presses that
//! nobody made?
//!
//! [`IdleCheck`] runs a [`ContactDetector`] over footage of an untouched
//! sensor, frame by frame as the daemon does, and counts what it would have
//! done: presses started (each a false press), the time spent "in contact"
//! and re-capturing the reference, and how close the score came to starting
//! one: the highest level above the noise floor that the detector's
//! `min_enter_frames` frames in a row all reached, against the threshold
//! `enter`. `telextilesd record --idle` runs it on a live sensor; the
//! detector's defaults were chosen on simulated idle footage only
//! (docs/benchmarks.md, "The contact detector"), so this is how an owner
//! checks them on a real one.
//!
//! Pure and deterministic: timestamps come with the frames.

use std::collections::VecDeque;

use image::RgbImage;
use serde::Serialize;

use crate::contact::{ContactConfig, ContactDetector, ContactEvent, ContactUpdate};

/// What the detector did on idle footage ([`IdleCheck::summary`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IdleSummary {
    /// Frames seen.
    pub frames: u64,
    /// Capture time spanned, first frame to last plus one frame period.
    pub seconds: f64,
    /// Mean frame rate.
    pub fps: f64,
    /// Presses the detector started: on an untouched sensor, every one is
    /// false.
    pub false_presses: u64,
    /// When each started, seconds from the first frame.
    pub press_starts_s: Vec<f64>,
    /// Share of the capture time spent in a press.
    pub in_contact_share: f64,
    /// Share of the capture time spent (re)capturing the reference, after
    /// the first capture.
    pub capturing_share: f64,
    /// The noise floor at the end (score of untouched frames).
    pub floor: f32,
    /// Score above the floor at or above which a frame counts towards a press.
    pub enter: f32,
    /// Frames in a row that start a press (`min_enter_frames`).
    pub run_frames: u32,
    /// The highest score above the floor that `run_frames` frames in a row
    /// reached outside presses (0 before the reference is captured).
    pub peak_run: f32,
    /// `enter - peak_run`: how much more the resting sensor's score would
    /// have to rise to start a press. Negative when it did.
    pub margin: f32,
}

impl IdleSummary {
    /// No press started and the score stayed below the threshold.
    pub fn ok(&self) -> bool {
        self.false_presses == 0 && self.margin > 0.0
    }
}

/// Runs a contact detector over idle footage (see the module docs).
pub struct IdleCheck {
    det: ContactDetector,
    frames: u64,
    first_us: Option<u64>,
    last_us: u64,
    /// State after the previous frame: (in contact, capturing after the first capture).
    last_state: (bool, bool),
    captured_once: bool,
    press_starts_us: Vec<u64>,
    in_contact_us: u64,
    capturing_us: u64,
    run: VecDeque<f32>,
    peak_run: f32,
}

impl IdleCheck {
    /// A check of the detector `cfg`.
    pub fn new(cfg: ContactConfig) -> IdleCheck {
        let n = cfg.min_enter_frames.max(1) as usize;
        IdleCheck {
            det: ContactDetector::new(cfg),
            frames: 0,
            first_us: None,
            last_us: 0,
            last_state: (false, false),
            captured_once: false,
            press_starts_us: Vec::new(),
            in_contact_us: 0,
            capturing_us: 0,
            run: VecDeque::with_capacity(n),
            peak_run: 0.0,
        }
    }

    /// The detector, as the frames have left it.
    pub fn detector(&self) -> &ContactDetector {
        &self.det
    }

    /// Feed the next frame, captured at `t_us`; returns what the detector
    /// made of it.
    pub fn push(&mut self, image: &RgbImage, t_us: u64) -> ContactUpdate {
        if self.first_us.is_some() {
            // The time since the previous frame counts in that frame's state.
            let dt = t_us.saturating_sub(self.last_us);
            if self.last_state.0 {
                self.in_contact_us += dt;
            }
            if self.last_state.1 {
                self.capturing_us += dt;
            }
        } else {
            self.first_us = Some(t_us);
        }
        self.last_us = t_us;
        self.frames += 1;
        let u = self.det.update(image, t_us);
        if let Some(ContactEvent::PressStart { t_us: start }) = u.event {
            self.press_starts_us.push(start);
        }
        let capturing = self.det.capturing();
        if !capturing {
            self.captured_once = true;
        }
        self.last_state = (u.in_contact, capturing && self.captured_once);
        let n = self.det.config().min_enter_frames.max(1) as usize;
        if capturing || u.in_contact || u.event.is_some() {
            // A press's frames, and the capture's, are no measure of rest.
            self.run.clear();
        } else {
            if self.run.len() == n {
                self.run.pop_front();
            }
            self.run.push_back(u.score - self.det.floor());
            if self.run.len() == n {
                let held = self.run.iter().copied().fold(f32::INFINITY, f32::min);
                self.peak_run = self.peak_run.max(held);
            }
        }
        u
    }

    /// What the detector did so far.
    pub fn summary(&self) -> IdleSummary {
        let first = self.first_us.unwrap_or(0);
        let span_us = self.last_us.saturating_sub(first) as f64;
        let period_us = if self.frames > 1 {
            span_us / (self.frames - 1) as f64
        } else {
            0.0
        };
        let seconds = (span_us + period_us) / 1e6;
        let share = |us: u64| {
            if seconds > 0.0 {
                us as f64 / 1e6 / seconds
            } else {
                0.0
            }
        };
        let cfg = self.det.config();
        IdleSummary {
            frames: self.frames,
            seconds,
            fps: if period_us > 0.0 {
                1e6 / period_us
            } else {
                0.0
            },
            false_presses: self.press_starts_us.len() as u64,
            press_starts_s: self
                .press_starts_us
                .iter()
                .map(|&t| t.saturating_sub(first) as f64 / 1e6)
                .collect(),
            in_contact_share: share(self.in_contact_us),
            capturing_share: share(self.capturing_us),
            floor: self.det.floor(),
            enter: cfg.enter,
            run_frames: cfg.min_enter_frames.max(1),
            peak_run: self.peak_run,
            margin: if self.press_starts_us.is_empty() {
                cfg.enter - self.peak_run
            } else {
                (cfg.enter - self.peak_run).min(0.0)
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use image::Rgb;

    fn noisy(base: u8, i: u64) -> RgbImage {
        // A fixed pattern of +-1 that changes from frame to frame.
        RgbImage::from_fn(240, 320, |x, y| {
            let h = (x as u64 * 7 + y as u64 * 13 + i * 31) % 3;
            let v = base as i32 + h as i32 - 1;
            Rgb([v as u8, v as u8, v as u8])
        })
    }

    #[test]
    fn rest_starts_nothing_and_a_touch_is_counted_with_its_time() {
        let cfg = ContactConfig {
            // Uniform frames: a step is a gain change, which the default
            // scores as nothing.
            gain_compensated: false,
            stale_after_ms: 0.0,
            ..Default::default()
        };
        let p = 16_667u64;
        let mut rest = IdleCheck::new(cfg.clone());
        for i in 0..600 {
            rest.push(&noisy(100, i), 1_000 + i * p);
        }
        let s = rest.summary();
        assert_eq!((s.frames, s.false_presses), (600, 0));
        assert!((s.seconds - 10.0).abs() < 1e-3, "{s:?}");
        assert!((s.fps - 60.0).abs() < 0.01, "{s:?}");
        assert_eq!(s.in_contact_share, 0.0);
        assert_eq!(s.capturing_share, 0.0);
        assert!(s.ok(), "{s:?}");
        assert!(s.margin > 0.0 && s.margin <= s.enter, "{s:?}");
        assert_eq!(s.run_frames, cfg.min_enter_frames);

        // A 1 s touch (a brightness step of 4) after 5 s: one press,
        // starting at 5 s, in contact for about a tenth of the time.
        let mut touched = IdleCheck::new(cfg);
        for i in 0..600 {
            let f = if (300..360).contains(&i) {
                noisy(104, i)
            } else {
                noisy(100, i)
            };
            touched.push(&f, i * p);
        }
        let s = touched.summary();
        assert_eq!(s.false_presses, 1, "{s:?}");
        assert!((s.press_starts_s[0] - 5.0).abs() < 0.001, "{s:?}");
        assert!(
            s.in_contact_share > 0.1 && s.in_contact_share < 0.12,
            "{s:?}"
        );
        assert!(!s.ok());
        assert!(s.margin <= 0.0);
    }

    #[test]
    fn the_peak_is_what_the_run_held_and_a_short_bump_is_no_run() {
        let cfg = ContactConfig {
            gain_compensated: false,
            stale_after_ms: 0.0,
            min_enter_frames: 3,
            enter_ms: 0.0,
            ..Default::default()
        };
        let p = 16_667u64;
        let mut c = IdleCheck::new(cfg);
        let mut t = 0;
        let mut feed = |c: &mut IdleCheck, v: u8, n: u64| {
            for _ in 0..n {
                c.push(&RgbImage::from_pixel(240, 320, Rgb([v, v, v])), t);
                t += p;
            }
        };
        feed(&mut c, 100, 60);
        // Two frames at +2, under the 3-frame run: no press, and no peak
        // of 2 (never held for 3 frames); then three at +0.2 (a 3-frame
        // run under the threshold) sets the peak.
        feed(&mut c, 102, 2);
        feed(&mut c, 100, 10);
        let before = c.summary();
        assert_eq!(before.false_presses, 0);
        assert!(before.peak_run < 0.1, "{before:?}");
        let mut c2 = c;
        let base = RgbImage::from_pixel(240, 320, Rgb([100, 100, 100]));
        // Every 5th pixel one grey level up: a score of about 0.2.
        let raised = RgbImage::from_fn(240, 320, |x, y| {
            let v = if (x + y * 240) % 5 == 0 { 101 } else { 100 };
            Rgb([v, v, v])
        });
        for _ in 0..3 {
            c2.push(&raised, t);
            t += p;
        }
        c2.push(&base, t);
        let s = c2.summary();
        assert_eq!(s.false_presses, 0, "{s:?}");
        assert!(s.peak_run > 0.1 && s.peak_run < s.enter, "{s:?}");
        assert!((s.margin - (s.enter - s.peak_run)).abs() < 1e-6);
    }
}
