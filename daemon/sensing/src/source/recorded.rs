//! Replay of recorded presses (the simulator crate's on-disk format, and
//! PyTouch-style datasets), at the recorded pace or as fast as possible:
//! one press ([`RecordedSource`]), or every recording under a directory,
//! one after another ([`RecordingsSource`], the daemon's `replay:<dir>`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use telextiles_recording::recording::{find_recordings, Recording};
use telextiles_recording::{Press, PressMeta};

use super::{FrameSource, NewRecording, SourceError};
use crate::frame::Frame;
use crate::front::References;

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
        let press = telextiles_recording::recording::read_press(dir)
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
            super::sleep_until_due(&mut self.started, t);
        }
        out.set_time(t, self.seq);
        self.seq += 1;
        out.copy_image(&self.frames[i])?;
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

/// Every recording under a directory (press directories at any depth, else
/// a PyTouch-style dataset: `telextiles_recording::recording::find_recordings`),
/// replayed one after another in sorted order, optionally looping, as one
/// stream whose timestamps keep increasing (one frame period between the
/// last frame of a recording and the first of the next).
///
/// The first frame of each recording comes with a [`NewRecording`]
/// ([`FrameSource::new_recording`]) that carries the recording's reference:
/// its own quiet frames, else the one given for its sensor
/// ([`References::for_press`]), else None. Recordings are read one at a
/// time, when their turn comes. One that cannot be read, or has no frames,
/// or stops being readable (timestamps that go backwards) is skipped with
/// [`SourceError::Skipped`] naming it, and the replay goes on; when no
/// recording of a whole round gave a frame, the source fails for good
/// ([`SourceError::Fatal`]).
pub struct RecordingsSource {
    root: PathBuf,
    recordings: Vec<Recording>,
    references: References,
    pace: Pace,
    looping: bool,
    /// The recording to read next.
    next: usize,
    /// The recording being replayed, and whether it has given a frame.
    current: Option<(RecordedSource, bool)>,
    /// Stream time of the current recording's first frame.
    offset_us: u64,
    /// Stream time of the last frame delivered, and the frame period of
    /// its recording.
    last: Option<(u64, u64)>,
    /// Recordings in a row that gave no frame.
    failed: usize,
    pending: Option<NewRecording>,
    started: Option<Instant>,
    seq: u64,
}

impl RecordingsSource {
    /// The recordings under `root` (a press directory is one recording).
    /// None found, or `root` unreadable → [`SourceError::Fatal`] naming it.
    pub fn open(
        root: &Path,
        pace: Pace,
        references: References,
    ) -> Result<RecordingsSource, SourceError> {
        let recordings = find_recordings(root)
            .map_err(|e| SourceError::Fatal(format!("cannot replay {}: {e}", root.display())))?;
        Ok(RecordingsSource {
            root: root.to_path_buf(),
            recordings,
            references,
            pace,
            looping: false,
            next: 0,
            current: None,
            offset_us: 0,
            last: None,
            failed: 0,
            pending: None,
            started: None,
            seq: 0,
        })
    }

    /// Space the frames of recordings saved without timestamps (a
    /// PyTouch-style dataset) at `fps` (None: the DIGIT's stream rate at
    /// their size, `telextiles_recording::recording::default_fps`). Press
    /// directories carry their own timestamps: a rate given for them is
    /// refused ([`SourceError::Fatal`]).
    pub fn assume_fps(mut self, fps: Option<f32>) -> Result<Self, SourceError> {
        telextiles_recording::recording::assume_fps(&mut self.recordings, fps).map_err(|e| {
            SourceError::Fatal(format!("cannot replay {}: {e}", self.root.display()))
        })?;
        Ok(self)
    }

    /// Say which sensor made recordings that do not name it (PyTouch
    /// sequences: mapped to the frame and timed by its profile); a press
    /// directory naming another is refused ([`SourceError::Fatal`]
    /// naming both). None: recordings name their own, else a DIGIT.
    pub fn assume_sensor(
        mut self,
        sensor: Option<telextiles_recording::recording::Sensor>,
    ) -> Result<Self, SourceError> {
        telextiles_recording::recording::assume_sensor(&mut self.recordings, sensor).map_err(
            |e| SourceError::Fatal(format!("cannot replay {}: {e}", self.root.display())),
        )?;
        Ok(self)
    }

    /// After the last recording, start again from the first.
    pub fn looping(mut self, on: bool) -> Self {
        self.looping = on;
        self
    }

    /// The recordings, in the order they are replayed.
    pub fn recordings(&self) -> &[Recording] {
        &self.recordings
    }

    /// Read the next recording in turn; Ok(false) at the end of a round
    /// that does not loop.
    fn load_next(&mut self) -> Result<bool, SourceError> {
        if self.failed >= self.recordings.len() {
            return Err(SourceError::Fatal(format!(
                "cannot replay {}: none of its {} recordings gave a frame",
                self.root.display(),
                self.recordings.len()
            )));
        }
        if self.next == self.recordings.len() {
            if !self.looping {
                return Ok(false);
            }
            self.next = 0;
        }
        let rec = &self.recordings[self.next];
        self.next += 1;
        let name = rec.path().display().to_string();
        let press = rec.load().map_err(|e| {
            self.failed += 1;
            SourceError::Skipped(format!("skipping recording {name}: {e}"))
        })?;
        let reference = self.references.for_press(&press);
        self.offset_us = self.last.map_or(0, |(t, period)| t + period);
        self.current = Some((
            RecordedSource::from_press(press, Pace::AsFastAsPossible, name.clone()),
            false,
        ));
        self.pending = Some(NewRecording { name, reference });
        Ok(true)
    }
}

impl FrameSource for RecordingsSource {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        loop {
            if self.current.is_none() && !self.load_next()? {
                return Err(SourceError::Ended);
            }
            let (src, gave) = self.current.as_mut().expect("loaded above");
            match src.next_frame(out) {
                Ok(()) => {
                    *gave = true;
                    self.failed = 0;
                    let t = self.offset_us + out.timestamp_us();
                    if self.pace == Pace::RealTime {
                        super::sleep_until_due(&mut self.started, t);
                    }
                    self.last = Some((t, src.period_us));
                    out.set_time(t, self.seq);
                    self.seq += 1;
                    return Ok(());
                }
                Err(SourceError::Ended) => {
                    if !*gave {
                        self.failed += 1;
                        let name = src.name.clone();
                        self.current = None;
                        return Err(SourceError::Skipped(format!(
                            "skipping recording {name}: it has no frames"
                        )));
                    }
                    self.current = None;
                }
                Err(SourceError::Fatal(why)) => {
                    if !*gave {
                        self.failed += 1;
                    }
                    self.current = None;
                    return Err(SourceError::Skipped(format!("skipping the rest: {why}")));
                }
                Err(e) => return Err(e),
            }
        }
    }

    fn describe(&self) -> String {
        format!(
            "replay of {} recordings under {}",
            self.recordings.len(),
            self.root.display()
        )
    }

    fn new_recording(&mut self) -> Option<NewRecording> {
        self.pending.take()
    }
}
