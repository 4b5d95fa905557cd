//! Simulated time for the state-machine tests: skewed clocks and an
//! ordered (stream-like), delaying, jittering, lossy one-way channel.

use std::collections::VecDeque;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

/// A process clock in true time `t` (µs): `offset + t·(1 + ppm·10⁻⁶)`,
/// clamped to `u64`.
#[derive(Clone, Copy, Debug)]
pub struct SimClock {
    pub offset: i128,
    pub ppm: i64,
}

impl SimClock {
    pub fn at(&self, t: u64) -> u64 {
        let v = self.offset + t as i128 + (t as i128 * self.ppm as i128) / 1_000_000;
        v.clamp(0, u64::MAX as i128) as u64
    }

    /// The first true time at which this clock reads at least `local`
    /// (`u64::MAX` if never).
    pub fn true_time(&self, local: u64) -> u64 {
        let rate = 1_000_000 + self.ppm as i128;
        let first = ((local as i128 - self.offset) * 1_000_000 / rate).max(0);
        (first..first + 4)
            .take_while(|&t| t <= u64::MAX as i128)
            .find(|&t| self.at(t as u64) >= local)
            .map_or(u64::MAX, |t| t as u64)
    }
}

/// One direction of a stream: each message takes `delay` + up to `jitter`
/// µs, is lost with probability `loss` (what a full send queue does to a
/// ping or pong), and is never overtaken (head-of-line, like a QUIC stream).
pub struct Channel<T> {
    pub delay: u64,
    pub jitter: u64,
    pub loss: f64,
    in_flight: VecDeque<(u64, T)>,
    last: u64,
    rng: StdRng,
    pub sent: u64,
    pub lost: u64,
}

impl<T> Channel<T> {
    pub fn new(delay: u64, jitter: u64, loss: f64, seed: u64) -> Channel<T> {
        Channel {
            delay,
            jitter,
            loss,
            in_flight: VecDeque::new(),
            last: 0,
            rng: StdRng::seed_from_u64(seed),
            sent: 0,
            lost: 0,
        }
    }

    pub fn send(&mut self, now: u64, msg: T) {
        self.sent += 1;
        if self.loss > 0.0 && self.rng.gen_bool(self.loss) {
            self.lost += 1;
            return;
        }
        let j = if self.jitter > 0 {
            self.rng.gen_range(0..=self.jitter)
        } else {
            0
        };
        let at = (now + self.delay + j).max(self.last);
        self.last = at;
        self.in_flight.push_back((at, msg));
    }

    pub fn next_at(&self) -> Option<u64> {
        self.in_flight.front().map(|(at, _)| *at)
    }

    pub fn recv(&mut self, now: u64) -> Option<T> {
        match self.in_flight.front() {
            Some((at, _)) if *at <= now => self.in_flight.pop_front().map(|(_, m)| m),
            _ => None,
        }
    }
}
