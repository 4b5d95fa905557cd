//! [`ClockSync`] in simulated time: two ends with skewed, drifting clocks
//! over delaying, jittering, lossy channels; hostile pongs.

use std::time::Duration;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use telextiles_proto::peer::Control;

use super::clock::{ClockConfig, ClockSync, PongOutcome};
use super::sim::{Channel, SimClock};

const MS: u64 = 1_000;
const S: u64 = 1_000_000;

struct World {
    a: ClockSync,
    b: ClockSync,
    ca: SimClock,
    cb: SimClock,
    ab: Channel<Control>,
    ba: Channel<Control>,
    t: u64,
    a_outcomes: Vec<PongOutcome>,
}

impl World {
    fn new(ca: SimClock, cb: SimClock, ab: Channel<Control>, ba: Channel<Control>) -> World {
        let cfg = ClockConfig::new(Duration::from_millis(500));
        World {
            a: ClockSync::new(cfg.clone(), ca.at(0)),
            b: ClockSync::new(cfg, cb.at(0)),
            ca,
            cb,
            ab,
            ba,
            t: 0,
            a_outcomes: Vec::new(),
        }
    }

    /// True `B clock − A clock` now.
    fn true_offset(&self) -> i64 {
        self.cb.at(self.t) as i64 - self.ca.at(self.t) as i64
    }

    fn run_until(&mut self, end: u64) {
        loop {
            let next = [
                self.ca.true_time(self.a.poll_timeout()),
                self.cb.true_time(self.b.poll_timeout()),
                self.ab.next_at().unwrap_or(u64::MAX),
                self.ba.next_at().unwrap_or(u64::MAX),
            ]
            .into_iter()
            .min()
            .unwrap();
            if next > end {
                self.t = end;
                return;
            }
            self.t = next.max(self.t);
            let t = self.t;
            while let Some(m) = self.ab.recv(t) {
                deliver(&mut self.b, self.cb.at(t), m, &mut Vec::new());
            }
            while let Some(m) = self.ba.recv(t) {
                deliver(&mut self.a, self.ca.at(t), m, &mut self.a_outcomes);
            }
            if self.ca.at(t) >= self.a.poll_timeout() {
                self.a.handle_timeout(self.ca.at(t));
            }
            if self.cb.at(t) >= self.b.poll_timeout() {
                self.b.handle_timeout(self.cb.at(t));
            }
            while let Some(m) = self.a.poll() {
                self.ab.send(t, m);
            }
            while let Some(m) = self.b.poll() {
                self.ba.send(t, m);
            }
        }
    }
}

fn deliver(s: &mut ClockSync, now: u64, m: Control, out: &mut Vec<PongOutcome>) {
    match m {
        Control::Ping { id, t1_us } => {
            s.handle_ping(now, id, t1_us);
        }
        Control::Pong {
            id,
            t1_us,
            t2_us,
            t3_us,
        } => out.push(s.handle_pong(now, id, t1_us, t2_us, t3_us)),
        other => panic!("unexpected {other:?}"),
    }
}

fn clock(offset: i128, ppm: i64) -> SimClock {
    SimClock { offset, ppm }
}

/// Offsets far apart (B's clock 11 days ahead of A's), 5 ms ± 2 ms each
/// way: both ends know the offset to within half the jitter, a latent's
/// one-way latency likewise, and the pings go out every 500 ms.
#[test]
fn skewed_clocks_with_delay_and_jitter_give_offset_and_latency() {
    for seed in 0..20 {
        let mut w = World::new(
            clock(5 * S as i128, 0),
            clock(987_654 * S as i128, 0),
            Channel::new(5 * MS, 2 * MS, 0.0, seed),
            Channel::new(5 * MS, 2 * MS, 0.0, seed + 1000),
        );
        assert_eq!(w.a.offset_us(), None, "no estimate before a pong");
        w.run_until(10 * S);
        let truth = w.true_offset();
        let a_off = w.a.offset_us().unwrap();
        let b_off = w.b.offset_us().unwrap();
        assert!(
            (a_off - truth).abs() <= MS as i64,
            "seed {seed}: {a_off} vs {truth}"
        );
        assert!(
            (b_off + truth).abs() <= MS as i64,
            "seed {seed}: {b_off} vs {}",
            -truth
        );
        let rtt = w.a.rtt_us().unwrap();
        assert!((10 * MS as i64..=14 * MS as i64).contains(&rtt), "{rtt}");
        // Pings at 0, 0.5, ..., 10 s.
        assert_eq!(w.a.stats().pings_sent, 21);
        assert_eq!(w.b.stats().pings_sent, 21);
        assert!(w
            .a_outcomes
            .iter()
            .all(|o| matches!(o, PongOutcome::Sample { .. })));
        // A latent captured on A now, received on B 7 ms later.
        let cap = w.ca.at(w.t);
        let recv = w.cb.at(w.t + 7 * MS);
        let one_way = w.b.one_way_us(cap, recv).unwrap();
        assert!((one_way - 7_000).abs() <= MS as i64, "{one_way}");
    }
}

/// The estimator's known limit: with 10 ms one way and 2 ms back it is off
/// by half the asymmetry (4 ms), whatever the seed.
#[test]
fn asymmetric_delay_biases_the_offset_by_half_the_asymmetry() {
    let mut w = World::new(
        clock(0, 0),
        clock(3 * S as i128, 0),
        Channel::new(10 * MS, 0, 0.0, 1),
        Channel::new(2 * MS, 0, 0.0, 2),
    );
    w.run_until(5 * S);
    let err = w.a.offset_us().unwrap() - w.true_offset();
    assert_eq!(err, 4_000);
}

/// B's clock runs 200 ppm fast: over 2 minutes the true offset moves by
/// 24 ms, and the estimate follows it (the window of 16 samples turns
/// over), staying within drift over the window (8 s · 200 ppm) + jitter.
#[test]
fn drifting_clock_is_followed() {
    let mut w = World::new(
        clock(1_000 * S as i128, 0),
        clock(7 * S as i128, 200),
        Channel::new(3 * MS, MS, 0.0, 3),
        Channel::new(3 * MS, MS, 0.0, 4),
    );
    let start = w.true_offset();
    for k in 1..=12 {
        w.run_until(k * 10 * S);
        let truth = w.true_offset();
        let err = (w.a.offset_us().unwrap() - truth).abs();
        assert!(err <= 2_200, "at {k}0 s: error {err} µs");
        let err_b = (w.b.offset_us().unwrap() + truth).abs();
        assert!(err_b <= 2_200, "at {k}0 s: B's error {err_b} µs");
    }
    assert!(w.true_offset() - start >= 23_000, "the drift is real");
}

/// Every pong lost for 5 s: no estimate, pings given up after the pong
/// timeout and never more than 16 outstanding; once pongs come through,
/// the estimate appears within a second.
#[test]
fn lost_pongs_bound_the_outstanding_pings_and_the_estimate_recovers() {
    let mut w = World::new(
        clock(0, 0),
        clock(40 * S as i128, 0),
        Channel::new(2 * MS, MS, 0.0, 5),
        Channel::new(2 * MS, MS, 1.0, 6),
    );
    for k in 1..=50 {
        w.run_until(k * 100 * MS);
        assert!(w.a.outstanding() <= 16);
    }
    assert_eq!(w.a.offset_us(), None);
    let st = w.a.stats();
    assert_eq!(st.pings_sent, 11);
    // Pong timeout max(8 · 500 ms, 2 s) = 4 s: at 5 s the pings of 0,
    // 0.5 and 1 s are given up.
    assert_eq!(st.pings_lost, 3, "{st:?}");
    w.ba.loss = 0.0;
    w.run_until(6 * S);
    assert!(w.a.offset_us().is_some());
    let err = (w.a.offset_us().unwrap() - w.true_offset()).abs();
    assert!(err <= MS as i64, "{err}");
}

/// 30 % of the pings and pongs lost both ways for 20 s: the estimate is as
/// good as without loss.
#[test]
fn random_loss_both_ways_keeps_the_estimate() {
    for seed in 0..10 {
        let mut w = World::new(
            clock(123, 0),
            clock(9_999 * S as i128, 0),
            Channel::new(4 * MS, 2 * MS, 0.3, seed),
            Channel::new(4 * MS, 2 * MS, 0.3, seed + 77),
        );
        w.run_until(20 * S);
        let err = (w.a.offset_us().unwrap() - w.true_offset()).abs();
        assert!(err <= MS as i64, "seed {seed}: {err}");
        assert!(w.a.outstanding() <= 16);
        assert!(w.a.stats().pings_lost > 0);
    }
}

/// Pongs that take longer than the pong timeout are ignored as unknown:
/// no estimate from answers to pings that were given up.
#[test]
fn pongs_after_the_timeout_are_ignored() {
    let mut w = World::new(
        clock(0, 0),
        clock(0, 0),
        Channel::new(MS, 0, 0.0, 7),
        Channel::new(5 * S, 0, 0.0, 8),
    );
    w.run_until(20 * S);
    assert_eq!(w.a.offset_us(), None);
    assert!(!w.a_outcomes.is_empty());
    assert!(w.a_outcomes.iter().all(|o| *o == PongOutcome::Unknown));
    assert!(w.a.outstanding() <= 16);
}

fn one_ping(s: &mut ClockSync, now: u64) -> (u32, u64) {
    s.handle_timeout(now);
    match s.poll() {
        Some(Control::Ping { id, t1_us }) => (id, t1_us),
        other => panic!("{other:?}"),
    }
}

/// Pongs a hostile peer can make up: unknown ids, duplicates, echoed times
/// it never got, and u64 extremes: each is refused or saturates; nothing
/// panics.
#[test]
fn hostile_pongs_are_refused_or_saturate() {
    let cfg = ClockConfig::new(Duration::from_millis(500));
    let mut s = ClockSync::new(cfg.clone(), 1_000);
    let (id, t1) = one_ping(&mut s, 1_000);
    assert_eq!(s.handle_pong(2_000, id + 1, t1, 5, 5), PongOutcome::Unknown);
    assert!(matches!(
        s.handle_pong(2_000, id, t1, 1_500, 1_500),
        PongOutcome::Sample {
            rtt_us: 1_000,
            offset_us: 0
        }
    ));
    assert_eq!(s.handle_pong(2_100, id, t1, 0, 0), PongOutcome::Unknown);
    // Echoed t1 before the ping was queued, or after the pong arrived.
    let (id, _) = one_ping(&mut s, 600_000);
    assert_eq!(
        s.handle_pong(601_000, id, 599_999, 600_500, 600_500),
        PongOutcome::Implausible
    );
    assert_eq!(
        s.handle_pong(601_000, id, 600_000, 0, 0),
        PongOutcome::Unknown
    );
    let (id, _) = one_ping(&mut s, 1_200_000);
    assert_eq!(
        s.handle_pong(1_201_000, id, 1_201_001, 7, 7),
        PongOutcome::Implausible
    );
    // t3 < t2, or a negative round trip.
    let (id, t1) = one_ping(&mut s, 1_800_000);
    assert_eq!(
        s.handle_pong(1_801_000, id, t1, 9, 8),
        PongOutcome::Implausible
    );
    let (id, t1) = one_ping(&mut s, 2_400_000);
    assert_eq!(
        s.handle_pong(2_401_000, id, t1, 0, 10_000),
        PongOutcome::Implausible
    );
    assert_eq!(s.offset_us(), Some(0), "only the honest sample counts");

    // u64 extremes in every field the peer controls, at our clock's ends.
    let ext = [0, 1, i64::MAX as u64, u64::MAX / 2, u64::MAX - 1, u64::MAX];
    let mut rng = StdRng::seed_from_u64(42);
    for &now0 in &[0u64, 1_000, u64::MAX - 10 * S] {
        let mut s = ClockSync::new(cfg.clone(), now0);
        for i in 0..2_000u64 {
            let now = now0.saturating_add(i * 500 * MS);
            let (id, t1) = one_ping(&mut s, now);
            let pick = |r: &mut StdRng| {
                if r.gen_bool(0.5) {
                    ext[r.gen_range(0..ext.len())]
                } else {
                    r.gen()
                }
            };
            let (t2, t3) = (pick(&mut rng), pick(&mut rng));
            let echoed = if rng.gen_bool(0.8) {
                t1
            } else {
                pick(&mut rng)
            };
            let id = if rng.gen_bool(0.9) { id } else { rng.gen() };
            let rx = now.saturating_add(rng.gen_range(0..2 * MS));
            let _ = s.handle_pong(rx, id, echoed, t2, t3);
            for &c in &ext {
                for &r in &ext {
                    let _ = s.one_way_us(c, r);
                }
            }
            assert!(s.outstanding() <= 16);
        }
        if let Some(off) = s.offset_us() {
            // Extreme offsets saturate instead of wrapping.
            let _ = s.one_way_us(u64::MAX, 0);
            let _ = off;
        }
    }
    // A pong claiming the peer's clock at u64::MAX is a valid sample: the
    // latency of a latent stamped 0 on that clock saturates.
    let mut s = ClockSync::new(cfg, 0);
    let (id, t1) = one_ping(&mut s, 0);
    assert!(matches!(
        s.handle_pong(10, id, t1, u64::MAX - 5, u64::MAX - 5),
        PongOutcome::Sample { .. }
    ));
    assert_eq!(s.one_way_us(0, 10), Some(i64::MAX));
}

/// A peer flooding pings without reading gets a bounded queue of pongs;
/// the rest are dropped and counted. Our own ping is not queued behind a
/// full queue either.
#[test]
fn ping_flood_is_bounded() {
    let mut s = ClockSync::new(ClockConfig::new(Duration::from_millis(500)), 0);
    for i in 0..100_000u32 {
        s.handle_ping(u64::from(i), i, u64::MAX);
    }
    let max = s.config().max_queued;
    assert_eq!(s.queued(), max);
    assert_eq!(s.stats().pongs_dropped, 100_000 - max as u64);
    s.handle_timeout(0);
    assert_eq!(s.stats().pings_sent, 0);
    assert_eq!(s.queued(), max);
    let mut n = 0;
    while let Some(m) = s.poll() {
        assert!(matches!(m, Control::Pong { .. }));
        n += 1;
    }
    assert_eq!(n, max);
    s.handle_timeout(500 * MS);
    assert_eq!(s.stats().pings_sent, 1);
}

/// A driver that wakes 10 s late sends one ping, not twenty, and the next
/// one is due an interval later.
#[test]
fn a_late_wake_up_sends_one_ping() {
    let mut s = ClockSync::new(ClockConfig::new(Duration::from_millis(500)), 0);
    s.handle_timeout(0);
    assert!(s.poll().is_some());
    assert_eq!(s.poll_timeout(), 500 * MS);
    s.handle_timeout(100 * MS);
    assert!(s.poll().is_none(), "not due yet");
    s.handle_timeout(10 * S);
    assert!(matches!(s.poll(), Some(Control::Ping { .. })));
    assert!(s.poll().is_none());
    assert_eq!(s.poll_timeout(), 10 * S + 500 * MS);
}
