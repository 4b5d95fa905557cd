//! [`CaptureClock`]: a frame's capture time on the local clock, spaced as
//! the sensor spaced its frames.
//!
//! The peers' deciders time a press by its frames' `capture_us` (a leader
//! must lead for `confirm_ms`, a challenger for `switch_ms`). Stamping a
//! frame with the moment the sensing thread got it adds that thread's
//! scheduling and decoding jitter to every interval: a run of three frames
//! at 60 fps then spans 50 ms ± a millisecond, and a rule that waits 50 ms
//! decides on the third frame or the fourth at random. Offline tools
//! (`classify`, the benchmarks) time presses by the frames' own timestamps
//! (a DIGIT's V4L2 buffer times, a recording's), so the live session
//! decided a frame later than they did on some presses.
//!
//! The clock maps a frame's own timestamp onto the local clock:
//! `capture = timestamp + offset`, where `offset` is the least `arrival -
//! timestamp` seen over the last [`WINDOW_US`] or so (the frame that came
//! with the least delay). The window lets the offset follow the sensor's
//! clock drifting against the local one. Between presses a frame's capture
//! time is never later than its arrival, so the latency measured from it
//! stays an upper bound.
//!
//! A new least delay moves the offset, and with it one interval, by a few
//! µs: enough to make a 50 ms wait take a frame more. So during a press
//! ([`CaptureClock::hold`] on its first frame, [`CaptureClock::release`]
//! at its end) the offset stays the one the press began with, and every
//! interval of the press is exactly the sensor's. A frame of the press
//! that comes with less delay than that may then be stamped up to that
//! difference (µs) after its arrival. A timestamp that goes backwards
//! (another source, a replay starting again) or jumps ahead by more than
//! the window starts the clock afresh, and ends a hold.
//!
//! Pure: fed timestamps and arrival times, no clock of its own.

/// How long the least delay is remembered: the offset is the least over
/// the current block of half this length and the block before it.
pub const WINDOW_US: u64 = 2_000_000;

/// Maps frame timestamps onto the local clock (see the module docs).
#[derive(Clone, Debug, Default)]
pub struct CaptureClock {
    /// The last frame's timestamp.
    last_ts: Option<u64>,
    /// The block's start (local clock) and its least `arrival - timestamp`.
    block_start: u64,
    block_min: i64,
    /// The previous block's least delay, if it ended less than a block ago.
    prev_min: Option<i64>,
    /// The offset a press in progress began with ([`CaptureClock::hold`]).
    held: Option<i64>,
}

impl CaptureClock {
    /// A clock with no frame seen.
    pub fn new() -> CaptureClock {
        CaptureClock::default()
    }

    /// The capture time, on the local clock, of a frame with timestamp
    /// `ts_us` (the source's clock) that arrived at `now_us` (the local
    /// clock). Never later than `now_us`.
    pub fn stamp(&mut self, ts_us: u64, now_us: u64) -> u64 {
        let delay = now_us as i64 - ts_us as i64;
        let fresh = match self.last_ts {
            None => true,
            Some(last) => ts_us < last || ts_us - last > WINDOW_US,
        };
        if fresh {
            self.block_start = now_us;
            self.block_min = delay;
            self.prev_min = None;
            self.held = None;
        } else {
            if now_us.saturating_sub(self.block_start) >= WINDOW_US / 2 {
                // A new block; the one that ended is remembered for one
                // more block.
                self.prev_min = Some(self.block_min);
                self.block_start = now_us;
                self.block_min = delay;
            }
            self.block_min = self.block_min.min(delay);
        }
        self.last_ts = Some(ts_us);
        if self.held.is_some() {
            return self.map(ts_us);
        }
        // The least delay is this frame's or smaller, so this is at most
        // `now_us`; a clamp keeps it so whatever the arithmetic.
        (ts_us as i64 + self.least()).clamp(0, now_us as i64) as u64
    }

    /// The least delay over the window.
    fn least(&self) -> i64 {
        self.prev_min
            .map_or(self.block_min, |p| p.min(self.block_min))
    }

    /// The capture time of another frame of the same source (one held by
    /// the front end and encoded later), by the offset in use.
    pub fn map(&self, ts_us: u64) -> u64 {
        let offset = self.held.unwrap_or_else(|| self.least());
        (ts_us as i64 + offset).max(0) as u64
    }

    /// A press begins: keep the offset in use (the one the last
    /// [`CaptureClock::stamp`] used) until [`CaptureClock::release`]. A
    /// second hold keeps the first's.
    pub fn hold(&mut self) {
        if self.held.is_none() && self.last_ts.is_some() {
            self.held = Some(self.least());
        }
    }

    /// The press ended: the offset follows the least delay again.
    pub fn release(&mut self) {
        self.held = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: u64 = 16_667;

    /// Frames every `P` µs on the sensor's clock, arriving `base` µs later
    /// on the local clock plus a jitter drawn from `jitter`.
    fn stamps(clock: &mut CaptureClock, n: u64, base: u64, jitter: &[u64]) -> Vec<(u64, u64)> {
        (0..n)
            .map(|k| {
                let ts = 1_000_000 + k * P;
                let now = ts + base + jitter[k as usize % jitter.len()];
                (clock.stamp(ts, now), now)
            })
            .collect()
    }

    #[test]
    fn jittered_arrivals_get_the_sensors_own_spacing_and_never_a_later_time() {
        let mut c = CaptureClock::new();
        let jitter = [900, 150, 2_400, 40, 700, 1_300, 60, 3_100];
        let got = stamps(&mut c, 300, 5_000_000, &jitter);
        for (cap, now) in &got {
            assert!(cap <= now, "{cap} after its arrival {now}");
        }
        // Once the least delay (40 µs) has come, every interval is the
        // sensor's, and three frames span exactly 50 ms (less a µs).
        for w in got[3..].windows(2) {
            assert_eq!(w[1].0 - w[0].0, P);
        }
        assert_eq!(got[10].0 - got[7].0, 3 * P);
        // The capture time is the arrival less the jitter above the least
        // delay seen so far.
        assert_eq!(got[3].1 - got[3].0, 0);
        assert_eq!(got[2].1 - got[2].0, 2_400 - 150);
        // A frame held back and encoded later maps by the same offset.
        assert_eq!(c.map(1_000_000 + 298 * P), got[298].0);
    }

    #[test]
    fn a_press_keeps_its_offset_so_every_interval_is_the_sensors() {
        let mut c = CaptureClock::new();
        // Frames arriving 2 ms late, then one 1.5 ms late: between presses
        // its interval is shortened by the new least delay.
        let ts = |k: u64| 1_000_000 + k * P;
        let mut caps: Vec<u64> = (0..10).map(|k| c.stamp(ts(k), ts(k) + 2_000)).collect();
        caps.push(c.stamp(ts(10), ts(10) + 1_500));
        assert_eq!(caps[10] - caps[9], P - 500);
        // A press from frame 11 on: the offset it began with stays, a
        // lower delay (1 ms) changes no interval, and the frame that came
        // sooner than the offset says is stamped 500 µs after it arrived.
        let first = c.stamp(ts(11), ts(11) + 1_500);
        c.hold();
        let low = c.stamp(ts(12), ts(12) + 1_000);
        let next = c.stamp(ts(13), ts(13) + 1_700);
        assert_eq!((low - first, next - low), (P, P));
        assert_eq!(low - (ts(12) + 1_000), 500);
        assert_eq!(c.map(ts(11)), first);
        // A second hold keeps the first offset.
        c.hold();
        assert_eq!(c.stamp(ts(14), ts(14) + 1_000) - next, P);
        // Released: the least delay (1 ms) again, never after the arrival.
        c.release();
        let after = c.stamp(ts(15), ts(15) + 1_200);
        assert_eq!(after, ts(15) + 1_000);
        // A new epoch ends a hold.
        c.hold();
        assert_eq!(c.stamp(0, 90_000_000), 90_000_000);
        assert_eq!(c.stamp(P, 90_000_000 + P + 300), 90_000_000 + P);
    }

    #[test]
    fn the_offset_follows_a_sensor_clock_that_drifts() {
        // The sensor's clock runs 100 ppm slow: the arrival delay grows by
        // 1.7 µs a frame. The offset is at most one window's drift (about
        // 200 µs) below each frame's delay, not the whole run's.
        let mut c = CaptureClock::new();
        let mut worst_lag = 0;
        for k in 0..3_600u64 {
            let ts = k * P;
            let now = 1_000 + ts + ts / 10_000;
            let cap = c.stamp(ts, now);
            assert!(cap <= now);
            worst_lag = worst_lag.max(now - cap);
        }
        // A minute of frames drifts 6 ms; the lag stays within one and a
        // half windows' drift.
        assert!(worst_lag <= 300, "lag {worst_lag} µs");
    }

    #[test]
    fn a_timestamp_going_back_or_leaping_ahead_starts_afresh() {
        let mut c = CaptureClock::new();
        stamps(&mut c, 10, 1_000, &[0]);
        // A new epoch: timestamps from 0 again, arriving much later on the
        // local clock. The old offset would put it seconds early.
        let now = 50_000_000;
        assert_eq!(c.stamp(0, now), now);
        assert_eq!(c.stamp(P, now + P + 500), now + P);
        // A leap ahead of more than the window: afresh too.
        let ts = 10 * WINDOW_US;
        let now2 = now + 2 * P + 900;
        assert_eq!(c.stamp(ts, now2), now2);
        // Timestamps ahead of the local clock (another epoch) never give a
        // capture time after the arrival, nor below 0.
        let mut d = CaptureClock::new();
        assert_eq!(d.stamp(10_000_000, 5), 5);
        assert_eq!(d.stamp(10_000_000 + P, 5 + P), 5 + P);
    }
}
