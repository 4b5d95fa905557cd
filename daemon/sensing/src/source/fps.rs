//! Whether a camera delivers the frame rate it was asked for: a GelSight
//! Mini asked for 25 fps often gives 15–18 on Linux, a DIGIT on a busy USB
//! bus fewer than 60. Nothing is resampled in time — the decider and the
//! recorder time everything by the frames' own timestamps — but a rate
//! well below the mode's is reported, once per drop, so the owner knows.
//! Pure: fed timestamps.

/// How long a window the rate is measured over, µs.
pub const WINDOW_US: u64 = 2_000_000;
/// Reported below this share of the asked rate.
pub const LOW_SHARE: f32 = 0.9;
/// Back to normal at or above this share (no report).
pub const OK_SHARE: f32 = 0.95;

/// Watches the rate of one stream (see the module docs).
#[derive(Clone, Debug)]
pub struct FpsWatch {
    asked: f32,
    /// The window's first timestamp and the frames after it.
    start: Option<u64>,
    frames: u64,
    last: Option<u64>,
    low: bool,
    measured: Option<f32>,
}

impl FpsWatch {
    /// A stream asked to run at `asked` frames per second.
    pub fn new(asked: f32) -> FpsWatch {
        FpsWatch {
            asked,
            start: None,
            frames: 0,
            last: None,
            low: false,
            measured: None,
        }
    }

    /// The rate over the last full window, if one has passed.
    pub fn measured(&self) -> Option<f32> {
        self.measured
    }

    /// One frame's timestamp (µs, the source's clock). Returns a message
    /// when a full window's rate first falls below [`LOW_SHARE`] of the
    /// asked rate (again only after it came back to [`OK_SHARE`]).
    pub fn push(&mut self, t_us: u64) -> Option<String> {
        if self.last.is_some_and(|l| t_us <= l) {
            // Time went back (another stream): start again.
            self.start = None;
        }
        self.last = Some(t_us);
        let Some(start) = self.start else {
            self.start = Some(t_us);
            self.frames = 0;
            return None;
        };
        self.frames += 1;
        let span = t_us - start;
        if span < WINDOW_US {
            return None;
        }
        let fps = self.frames as f32 / (span as f32 / 1e6);
        self.measured = Some(fps);
        self.start = Some(t_us);
        self.frames = 0;
        if fps < LOW_SHARE * self.asked && !self.low {
            self.low = true;
            return Some(format!(
                "the camera delivers {fps:.1} fps of the {} asked; presses are timed by the frames' own timestamps, nothing is resampled, but decisions come later and fewer frames are encoded",
                self.asked
            ));
        }
        if fps >= OK_SHARE * self.asked {
            self.low = false;
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames at `fps` for `seconds`, from `t0`, through the watch; the
    /// messages it gave.
    fn run(w: &mut FpsWatch, t0: u64, fps: f64, seconds: f64) -> (Vec<String>, u64) {
        let n = (fps * seconds) as u64;
        let mut out = Vec::new();
        let mut t = t0;
        for k in 0..n {
            t = t0 + (k as f64 * 1e6 / fps) as u64;
            out.extend(w.push(t));
        }
        (out, t)
    }

    #[test]
    fn a_camera_below_its_asked_rate_is_reported_once_per_drop() {
        let mut w = FpsWatch::new(25.0);
        // At its rate: nothing said, the rate measured.
        let (said, t) = run(&mut w, 0, 25.0, 5.0);
        assert!(said.is_empty());
        assert!((w.measured().unwrap() - 25.0).abs() < 0.5);
        // A GelSight Mini on Linux: 16 fps. Said once, not every window.
        let (said, t) = run(&mut w, t + 40_000, 16.0, 8.0);
        assert_eq!(said.len(), 1, "{said:?}");
        assert!(said[0].contains("fps of the 25 asked"), "{}", said[0]);
        assert!((w.measured().unwrap() - 16.0).abs() < 0.5);
        // Back to its rate, then down again: said again.
        let (said, t) = run(&mut w, t + 40_000, 25.0, 5.0);
        assert!(said.is_empty());
        let (said, _) = run(&mut w, t + 40_000, 20.0, 5.0);
        assert_eq!(said.len(), 1);
        // Slightly slow (within 10 %) is not worth a word.
        let mut v = FpsWatch::new(60.0);
        assert!(run(&mut v, 0, 56.0, 10.0).0.is_empty());
    }

    #[test]
    fn time_going_back_starts_the_window_again() {
        let mut w = FpsWatch::new(60.0);
        let (_, t) = run(&mut w, 5_000_000, 60.0, 1.5);
        // Another stream from 0: no bogus rate from the jump.
        let (said, _) = run(&mut w, 0, 60.0, 3.0);
        assert!(said.is_empty());
        assert!(w.measured().unwrap() > 59.0);
        assert!(t > 0);
    }
}
