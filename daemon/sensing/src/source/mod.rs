//! Frame sources behind one trait: the DIGIT over V4L2, recorded presses, and
//! the live simulator; plus [`Resilient`], which reopens a source that went
//! away (with backoff) and rejects bad frames with a counted, logged error.

use std::time::Duration;

use crate::frame::{Frame, FrameError};

#[cfg(target_os = "linux")]
pub mod camera;
pub mod digit;
pub mod fps;
pub mod recorded;
#[cfg(feature = "sim")]
pub mod sim;
pub mod sysfs;
pub mod yuv;

/// Why a source produced no frame.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// The device is absent, unplugged or not streaming: reopen and retry.
    #[error("frame source unavailable: {0}")]
    Unavailable(String),
    /// One frame was bad (wrong size or format, undecodable); the source is
    /// still usable.
    #[error("bad frame: {0}")]
    BadFrame(#[from] FrameError),
    /// A finite source (a recording) has no more frames.
    #[error("end of frames")]
    Ended,
    /// Part of a finite source (one of several recordings) could not be
    /// read and was skipped; the source goes on with the rest.
    #[error("{0}")]
    Skipped(String),
    /// Cannot continue (bad configuration, unreadable recording).
    #[error("{0}")]
    Fatal(String),
}

/// The frame just delivered is the first of another recording (a source
/// that replays several, [`recorded::RecordingsSource`]): nothing of the
/// previous recording's frames says anything about this one's, so the
/// consumer ends any press in progress and starts afresh
/// ([`crate::front::FrontEnd::reset`]) with `reference` before it
/// processes the frame.
#[derive(Clone, Debug, PartialEq)]
pub struct NewRecording {
    /// The recording, as logs name it (its directory).
    pub name: String,
    /// Its no-contact reference (RGB 0..255, 240x320x3), or None: capture
    /// one from its first steady frames, as from a camera.
    pub reference: Option<Vec<f32>>,
}

/// Anything that yields DIGIT-shaped frames.
pub trait FrameSource: Send {
    /// Write the next frame into `out` (its buffer is reused where the source
    /// can decode in place). Blocks until a frame is due.
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError>;
    /// Short human-readable name for logs ("DIGIT D20118 on /dev/video0").
    fn describe(&self) -> String;
    /// Set the illumination, each colour 0..=15 (a DIGIT's LEDs). Sources
    /// without LEDs refuse, naming themselves.
    fn set_leds(&mut self, r: u8, g: u8, b: u8) -> Result<(), SourceError> {
        let _ = (r, g, b);
        Err(SourceError::Unavailable(format!(
            "{} has no LEDs to control (LED control needs a DIGIT)",
            self.describe()
        )))
    }
    /// Asked after each frame delivered: Some when that frame begins
    /// another recording (taken: asked again, None). A camera, the
    /// simulator and a single recording never say so.
    fn new_recording(&mut self) -> Option<NewRecording> {
        None
    }
    /// Asked after each frame delivered: something the owner should know
    /// about the stream (a camera delivering fewer frames per second than
    /// its mode, [`fps::FpsWatch`]), once (taken: asked again, None).
    fn take_notice(&mut self) -> Option<String> {
        None
    }
}

impl<S: FrameSource + ?Sized> FrameSource for Box<S> {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        (**self).next_frame(out)
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
    fn set_leds(&mut self, r: u8, g: u8, b: u8) -> Result<(), SourceError> {
        (**self).set_leds(r, g, b)
    }
    fn new_recording(&mut self) -> Option<NewRecording> {
        (**self).new_recording()
    }
    fn take_notice(&mut self) -> Option<String> {
        (**self).take_notice()
    }
}

/// Real-time pacing of a source that plays frames at their timestamps:
/// sleep until `t_us` after the first frame was delivered (`started`, set
/// on the first call).
pub(crate) fn sleep_until_due(started: &mut Option<std::time::Instant>, t_us: u64) {
    let start = *started.get_or_insert_with(std::time::Instant::now);
    let due = start + Duration::from_micros(t_us);
    let now = std::time::Instant::now();
    if due > now {
        std::thread::sleep(due - now);
    }
}

/// Exponential backoff between reopen attempts.
#[derive(Clone, Debug)]
pub struct Backoff {
    /// First delay.
    pub initial: Duration,
    /// Upper bound.
    pub max: Duration,
    next: Duration,
}

impl Backoff {
    /// Start at `initial`, double up to `max`.
    pub fn new(initial: Duration, max: Duration) -> Backoff {
        Backoff {
            initial,
            max,
            next: initial,
        }
    }
    /// The delay to wait now; the following one doubles.
    pub fn next_delay(&mut self) -> Duration {
        let d = self.next;
        self.next = (self.next * 2).min(self.max);
        d
    }
    /// Back to the initial delay (after a success).
    pub fn reset(&mut self) {
        self.next = self.initial;
    }
}

impl Default for Backoff {
    fn default() -> Self {
        Backoff::new(Duration::from_millis(250), Duration::from_secs(8))
    }
}

/// Counters kept by [`Resilient`].
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct SourceStats {
    /// Good frames delivered.
    pub frames: u64,
    /// Frames rejected (wrong size/format, undecodable).
    pub bad_frames: u64,
    /// Failed open attempts.
    pub open_failures: u64,
    /// Successful opens after the first (the device came back).
    pub reopens: u64,
}

type Opener = Box<dyn FnMut() -> Result<Box<dyn FrameSource>, SourceError> + Send>;
type Sleeper = Box<dyn FnMut(Duration) + Send>;

/// Wraps a source opener: opens lazily, reopens with backoff when the source
/// reports [`SourceError::Unavailable`], and skips bad frames (each one counted
/// and logged). Never panics; gives up only after `max_attempts` consecutive
/// failed opens (if set), or when the source ends or fails fatally.
pub struct Resilient {
    opener: Opener,
    sleeper: Sleeper,
    current: Option<Box<dyn FrameSource>>,
    backoff: Backoff,
    max_attempts: Option<u32>,
    max_consecutive_bad: u32,
    stats: SourceStats,
    opened_once: bool,
}

impl Resilient {
    /// `opener` is called to (re)open the source.
    pub fn new(
        opener: impl FnMut() -> Result<Box<dyn FrameSource>, SourceError> + Send + 'static,
    ) -> Resilient {
        Resilient {
            opener: Box::new(opener),
            sleeper: Box::new(std::thread::sleep),
            current: None,
            backoff: Backoff::default(),
            max_attempts: None,
            max_consecutive_bad: 120,
            stats: SourceStats::default(),
            opened_once: false,
        }
    }
    /// Replace the backoff schedule.
    pub fn with_backoff(mut self, backoff: Backoff) -> Self {
        self.backoff = backoff;
        self
    }
    /// Give up after this many consecutive failed opens (default: never).
    pub fn with_max_attempts(mut self, n: u32) -> Self {
        self.max_attempts = Some(n);
        self
    }
    /// After this many bad frames in a row the source is reopened (default 120).
    pub fn with_max_consecutive_bad(mut self, n: u32) -> Self {
        self.max_consecutive_bad = n.max(1);
        self
    }
    /// Replace the sleep function (tests pass one that records delays).
    pub fn with_sleeper(mut self, sleeper: impl FnMut(Duration) + Send + 'static) -> Self {
        self.sleeper = Box::new(sleeper);
        self
    }
    /// Counters so far.
    pub fn stats(&self) -> &SourceStats {
        &self.stats
    }
}

impl FrameSource for Resilient {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        let mut failed_opens = 0u32;
        let mut bad_in_a_row = 0u32;
        loop {
            if self.current.is_none() {
                match (self.opener)() {
                    Ok(s) => {
                        tracing::info!(source = %s.describe(), "frame source opened");
                        if self.opened_once {
                            self.stats.reopens += 1;
                        }
                        self.opened_once = true;
                        self.current = Some(s);
                    }
                    Err(SourceError::Unavailable(why)) => {
                        self.stats.open_failures += 1;
                        failed_opens += 1;
                        if self.max_attempts.is_some_and(|m| failed_opens >= m) {
                            return Err(SourceError::Unavailable(format!(
                                "{why} (gave up after {failed_opens} attempts)"
                            )));
                        }
                        let d = self.backoff.next_delay();
                        tracing::warn!("frame source unavailable: {why}; retrying in {d:?}");
                        (self.sleeper)(d);
                        continue;
                    }
                    Err(e) => return Err(e),
                }
            }
            let src = self.current.as_mut().expect("opened above");
            match src.next_frame(out) {
                Ok(()) => {
                    self.stats.frames += 1;
                    self.backoff.reset();
                    return Ok(());
                }
                Err(SourceError::BadFrame(e)) => {
                    self.stats.bad_frames += 1;
                    bad_in_a_row += 1;
                    tracing::warn!(
                        rejected = self.stats.bad_frames,
                        "rejected frame from {}: {e}",
                        src.describe()
                    );
                    if bad_in_a_row >= self.max_consecutive_bad {
                        let why = format!(
                            "{bad_in_a_row} bad frames in a row from {} (last: {e})",
                            src.describe()
                        );
                        self.current = None;
                        bad_in_a_row = 0;
                        failed_opens += 1;
                        if self.max_attempts.is_some_and(|m| failed_opens >= m) {
                            return Err(SourceError::Unavailable(format!(
                                "{why}; gave up after {failed_opens} attempts"
                            )));
                        }
                        let d = self.backoff.next_delay();
                        tracing::warn!("{why}; reopening in {d:?}");
                        (self.sleeper)(d);
                    }
                }
                Err(SourceError::Unavailable(why)) => {
                    tracing::warn!("frame source lost: {why}; reopening");
                    self.current = None;
                    let d = self.backoff.next_delay();
                    (self.sleeper)(d);
                }
                Err(e) => return Err(e),
            }
        }
    }

    fn describe(&self) -> String {
        match &self.current {
            Some(s) => s.describe(),
            None => "(not open)".into(),
        }
    }

    fn take_notice(&mut self) -> Option<String> {
        self.current.as_mut().and_then(|s| s.take_notice())
    }

    fn set_leds(&mut self, r: u8, g: u8, b: u8) -> Result<(), SourceError> {
        match &mut self.current {
            Some(s) => s.set_leds(r, g, b),
            None => Err(SourceError::Unavailable(
                "the sensor is not connected right now".into(),
            )),
        }
    }

    fn new_recording(&mut self) -> Option<NewRecording> {
        self.current.as_mut().and_then(|s| s.new_recording())
    }
}
