//! Replay of recorded presses (the simulator crate's on-disk format), at the
//! recorded pace or as fast as possible.

use std::path::Path;
use std::time::{Duration, Instant};

use telextiles_sim::{Press, PressMeta};

use super::{FrameSource, SourceError};
use crate::frame::{Frame, FrameError};

/// How fast to replay.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Pace {
    /// Deliver each frame at its recorded time after the first.
    RealTime,
    /// Deliver frames as fast as they are asked for (timestamps unchanged).
    AsFastAsPossible,
}

/// Replays one press, optionally looping.
pub struct RecordedSource {
    name: String,
    meta: PressMeta,
    frames: Vec<image::RgbImage>,
    timestamps: Vec<u64>,
    period_us: u64,
    next: usize,
    loops: u64,
    looping: bool,
    pace: Pace,
    started: Option<Instant>,
    seq: u64,
    /// First frame whose timestamp is before its predecessor's, if any.
    backwards: Option<usize>,
}

impl RecordedSource {
    /// Read a press directory. Unreadable → [`SourceError::Fatal`].
    pub fn open(dir: &Path, pace: Pace) -> Result<RecordedSource, SourceError> {
        let press = telextiles_sim::recording::read_press(dir)
            .map_err(|e| SourceError::Fatal(format!("cannot replay {}: {e}", dir.display())))?;
        Ok(RecordedSource::from_press(
            press,
            pace,
            dir.display().to_string(),
        ))
    }

    /// Replay an in-memory press.
    pub fn from_press(press: Press, pace: Pace, name: impl Into<String>) -> RecordedSource {
        let fps = if press.meta.fps.is_finite() && press.meta.fps > 0.0 {
            press.meta.fps
        } else {
            60.0
        };
        let period_us = (1e6 / fps as f64).round() as u64;
        let n = press.frames.len();
        let timestamps = if press.meta.timestamps_us.len() == n {
            press.meta.timestamps_us.clone()
        } else {
            (0..n as u64).map(|i| i * period_us).collect()
        };
        let backwards = timestamps
            .windows(2)
            .position(|w| w[1] < w[0])
            .map(|i| i + 1);
        RecordedSource {
            backwards,
            name: name.into(),
            meta: press.meta,
            frames: press.frames,
            timestamps,
            period_us,
            next: 0,
            loops: 0,
            looping: false,
            pace,
            started: None,
            seq: 0,
        }
    }

    /// Start again from the first frame after the last (timestamps keep increasing).
    pub fn looping(mut self, on: bool) -> Self {
        self.looping = on;
        self
    }

    /// The press metadata.
    pub fn meta(&self) -> &PressMeta {
        &self.meta
    }

    /// Number of frames in the press.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether the press has no frames.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }
}

impl FrameSource for RecordedSource {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        if self.next >= self.frames.len() {
            if !self.looping || self.frames.is_empty() {
                return Err(SourceError::Ended);
            }
            self.next = 0;
            self.loops += 1;
        }
        let i = self.next;
        if self.backwards == Some(i) {
            return Err(SourceError::Fatal(format!(
                "cannot replay {}: its timestamps go backwards at frame {i} ({} us after {} us)",
                self.name,
                self.timestamps[i],
                self.timestamps[i - 1]
            )));
        }
        self.next += 1;
        let first = self.timestamps[0];
        let span = self
            .timestamps
            .last()
            .copied()
            .unwrap_or(0)
            .saturating_sub(first)
            + self.period_us;
        let t = (self.timestamps[i] - first).saturating_add(self.loops.saturating_mul(span));
        if self.pace == Pace::RealTime {
            let start = *self.started.get_or_insert_with(Instant::now);
            let due = start + Duration::from_micros(t);
            let now = Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
        }
        let img = &self.frames[i];
        out.timestamp_us = t;
        out.seq = self.seq;
        self.seq += 1;
        if (img.width(), img.height()) != (crate::frame::FRAME_W, crate::frame::FRAME_H) {
            return Err(SourceError::BadFrame(FrameError::WrongSize {
                width: img.width(),
                height: img.height(),
            }));
        }
        out.image.clone_from(img);
        Ok(())
    }

    fn describe(&self) -> String {
        format!(
            "recorded press {} ({} frames of {})",
            self.name,
            self.frames.len(),
            self.meta.textile
        )
    }
}
