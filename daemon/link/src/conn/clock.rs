//! Ping/pong and the clock-offset estimate, sans-IO.
//!
//! [`ClockSync`] decides when to ping, answers the peer's pings, checks the
//! peer's pongs against the pings it really sent, and keeps the NTP-style
//! estimate ([`ClockOffset`], min-RTT of the last samples) that gives a
//! received latent its one-way latency. Every input carries `now` (µs on
//! this process's monotonic clock, [`crate::now_us`] in the daemon); the
//! messages to send are pulled with [`ClockSync::poll`], and
//! [`ClockSync::poll_timeout`] says when [`ClockSync::handle_timeout`] is
//! due next.
//!
//! The driver may stamp a ping's `t1_us` and a pong's `t3_us` again when it
//! actually writes them (as late as possible); a pong is accepted if its
//! echoed `t1_us` lies between the time the ping was queued here and the
//! pong's receipt.

use std::collections::VecDeque;
use std::time::Duration;

use telextiles_proto::peer::{ClockOffset, ClockSample, Control};

/// Settings of [`ClockSync`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ClockConfig {
    /// A ping is sent this often.
    pub ping_interval: Duration,
    /// A ping with no pong after this is counted lost; a later pong for it
    /// is ignored.
    pub pong_timeout: Duration,
    /// Samples kept by the estimator (the min-RTT one is used).
    pub window: usize,
    /// Pings awaiting a pong at most; the oldest is given up beyond this.
    pub max_outstanding: usize,
    /// Messages (pings, pongs) waiting for [`ClockSync::poll`] at most;
    /// pongs beyond it are dropped (a peer flooding pings gets some).
    pub max_queued: usize,
}

impl ClockConfig {
    /// Defaults around `ping_interval`: pong timeout max(8 intervals, 2 s),
    /// 16 samples, 16 outstanding pings, 64 queued messages.
    pub fn new(ping_interval: Duration) -> ClockConfig {
        ClockConfig {
            ping_interval,
            pong_timeout: (ping_interval * 8).max(Duration::from_secs(2)),
            window: 16,
            max_outstanding: 16,
            max_queued: crate::limits::CONTROL_QUEUE,
        }
    }
}

/// What a pong did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PongOutcome {
    /// Answered an outstanding ping; the sample is in the estimator.
    Sample { rtt_us: i64, offset_us: i64 },
    /// No outstanding ping has this id: never sent, answered already
    /// (duplicate), or given up as lost.
    Unknown,
    /// Answers an outstanding ping (now consumed) but its times are
    /// impossible: echoed `t1` outside [sent, received], `t3 < t2`, or a
    /// negative round trip.
    Implausible,
}

/// Counters, for tests and diagnostics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ClockStats {
    pub pings_sent: u64,
    pub pongs_used: u64,
    pub pongs_unknown: u64,
    pub pongs_implausible: u64,
    /// Pings given up (timeout or too many outstanding).
    pub pings_lost: u64,
    /// Pings of the peer answered / dropped because the queue was full.
    pub pongs_queued: u64,
    pub pongs_dropped: u64,
}

/// Ping scheduling, pong checking and the clock-offset estimate of one
/// connection. See the module docs.
#[derive(Debug)]
pub struct ClockSync {
    cfg: ClockConfig,
    next_ping: u64,
    next_id: u32,
    /// (id, queued at), oldest first.
    outstanding: VecDeque<(u32, u64)>,
    queue: VecDeque<Control>,
    clock: ClockOffset,
    stats: ClockStats,
}

pub(crate) fn us(d: Duration) -> u64 {
    d.as_micros().min(u64::MAX as u128) as u64
}

impl ClockSync {
    /// A connection that became up at `now`: the first ping is due at once.
    pub fn new(cfg: ClockConfig, now: u64) -> ClockSync {
        let window = cfg.window;
        ClockSync {
            cfg,
            next_ping: now,
            next_id: 0,
            outstanding: VecDeque::new(),
            queue: VecDeque::new(),
            clock: ClockOffset::new(window),
            stats: ClockStats::default(),
        }
    }

    pub fn config(&self) -> &ClockConfig {
        &self.cfg
    }

    /// When [`ClockSync::handle_timeout`] is due (the next ping).
    pub fn poll_timeout(&self) -> u64 {
        self.next_ping
    }

    /// The next message to send (pings and pongs, in order).
    pub fn poll(&mut self) -> Option<Control> {
        self.queue.pop_front()
    }

    /// Gives up pings older than the pong timeout and, if a ping is due,
    /// queues it. A driver that wakes late sends one ping, not a burst.
    pub fn handle_timeout(&mut self, now: u64) {
        let timeout = us(self.cfg.pong_timeout);
        while let Some(&(_, at)) = self.outstanding.front() {
            if now.saturating_sub(at) < timeout {
                break;
            }
            self.outstanding.pop_front();
            self.stats.pings_lost += 1;
        }
        if now < self.next_ping {
            return;
        }
        let interval = us(self.cfg.ping_interval).max(1);
        self.next_ping = self.next_ping.saturating_add(interval);
        if self.next_ping <= now {
            self.next_ping = now.saturating_add(interval);
        }
        if self.queue.len() >= self.cfg.max_queued {
            return;
        }
        while self.outstanding.len() >= self.cfg.max_outstanding.max(1) {
            self.outstanding.pop_front();
            self.stats.pings_lost += 1;
        }
        self.next_id = self.next_id.wrapping_add(1);
        let id = self.next_id;
        self.outstanding.push_back((id, now));
        self.queue.push_back(Control::Ping { id, t1_us: now });
        self.stats.pings_sent += 1;
    }

    /// The peer's ping: queues the pong (`t2 = t3 = now`; the writer may
    /// restamp `t3`). Returns false if it was dropped (queue full).
    pub fn handle_ping(&mut self, now: u64, id: u32, t1_us: u64) -> bool {
        if self.queue.len() >= self.cfg.max_queued {
            self.stats.pongs_dropped += 1;
            return false;
        }
        self.queue.push_back(Control::Pong {
            id,
            t1_us,
            t2_us: now,
            t3_us: now,
        });
        self.stats.pongs_queued += 1;
        true
    }

    /// The peer's pong to one of our pings, received at `now`.
    pub fn handle_pong(
        &mut self,
        now: u64,
        id: u32,
        t1_us: u64,
        t2_us: u64,
        t3_us: u64,
    ) -> PongOutcome {
        let Some(pos) = self.outstanding.iter().position(|&(i, _)| i == id) else {
            self.stats.pongs_unknown += 1;
            return PongOutcome::Unknown;
        };
        let (_, sent) = self.outstanding.remove(pos).expect("position is valid");
        let sample = ClockSample {
            t1: t1_us,
            t2: t2_us,
            t3: t3_us,
            t4: now,
        };
        if t1_us < sent || t1_us > now || !self.clock.add(sample) {
            self.stats.pongs_implausible += 1;
            return PongOutcome::Implausible;
        }
        self.stats.pongs_used += 1;
        PongOutcome::Sample {
            rtt_us: sample.rtt(),
            offset_us: sample.offset(),
        }
    }

    /// Estimated `peer clock − our clock` (µs); `None` before the first
    /// usable pong.
    pub fn offset_us(&self) -> Option<i64> {
        self.clock.offset_us()
    }

    /// Round trip of the sample the estimate uses (µs).
    pub fn rtt_us(&self) -> Option<i64> {
        self.clock.rtt_us()
    }

    /// One-way latency of a latent captured at `capture_us` (peer clock)
    /// and received at `recv_us` (ours); saturates, never panics.
    pub fn one_way_us(&self, capture_us: u64, recv_us: u64) -> Option<i64> {
        self.clock.one_way_us(capture_us, recv_us)
    }

    /// Pings awaiting a pong.
    pub fn outstanding(&self) -> usize {
        self.outstanding.len()
    }

    /// Messages waiting for [`ClockSync::poll`].
    pub fn queued(&self) -> usize {
        self.queue.len()
    }

    pub fn stats(&self) -> ClockStats {
        self.stats
    }
}
