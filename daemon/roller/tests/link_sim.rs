//! The link state machine against the firmware core, in simulated time.
//!
//! [`Pair`] is quinn-proto's `Pair` for the roller: a [`RollerLink`] and a
//! `roller_firmware::Roller` joined by an in-memory serial line with a
//! latency, on one simulated clock that jumps from one event (a delivery, a
//! firmware step, a link timer) to the next. Faults are injected on the line
//! (dropped or corrupted frames, garbage bursts, a mute firmware), at the
//! port (unplugged: opens fail, the open port reports an error) and in the
//! firmware (a reset where the wheel stands). No sleeps, no threads: every
//! run is deterministic, and the firmware's step count is the ground truth.
use std::collections::VecDeque;
use std::time::Duration;

use roller_firmware::{Config, Roller};
use telextiles_proto::roller::{kind, Command, FrameDecoder, Reply, Version};
use telextiles_roller::{Action, LinkConfig, RollerEvent, RollerLink, Target};

const MS: u64 = 1_000;
const S: u64 = 1_000_000;
const PORT: &str = "sim0";

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    fn chance(&mut self, p: f64) -> bool {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64 <= p && p > 0.0
    }
}

/// Line and firmware faults.
#[derive(Clone, Copy, Debug, Default)]
struct Faults {
    /// Probability that a frame (either way) is lost.
    drop: f64,
    /// Probability that a byte (either way) gets a bit flipped.
    corrupt_per_byte: f64,
    /// Probability that a burst of up to 80 garbage bytes (heavy in sync
    /// bytes) goes ahead of a frame.
    garbage: f64,
    /// Lose the next n frames host -> firmware.
    drop_next_to_fw: u32,
    /// Lose the next n frames firmware -> host.
    drop_next_to_host: u32,
    /// Lose every reply of this kind.
    drop_kind: Option<u8>,
    /// The firmware says nothing (hung, or a dead transmit line).
    mute: bool,
}

/// A command the host wrote.
#[derive(Clone, Debug)]
struct Written {
    at: u64,
    seq: u8,
    cmd: Command,
    bytes: Vec<u8>,
    /// First send of a new target.
    target: Option<Target>,
}

struct Pair {
    now: u64,
    link: RollerLink,
    fw: Roller,
    fw_cfg: Config,
    /// The port exists (an open succeeds).
    plugged: bool,
    /// The host holds the port open.
    open: bool,
    latency: u64,
    to_fw: VecDeque<(u64, Vec<u8>)>,
    to_host: VecDeque<(u64, Vec<u8>)>,
    fw_out: FrameDecoder,
    faults: Faults,
    rng: Rng,
    events: Vec<(u64, RollerEvent)>,
    written: Vec<Written>,
    /// Times of every open attempt and whether it succeeded.
    opens: Vec<(u64, bool)>,
}

fn slow_wheel() -> Config {
    Config {
        max_speed: 3200,
        accel: 6400,
        ..Config::default()
    }
}

fn link_config() -> LinkConfig {
    LinkConfig::default() // 250 ms acks, 4 tries, 400 ms keepalive, 50 ms..2 s backoff
}

impl Pair {
    /// The link against a slow wheel (1 rev/s, 2 rev/s^2, common
    /// AccelStepper settings): moves last long enough for the link's
    /// timing (acks, keepalives, a disconnect mid-move) to be exercised.
    fn new(cfg: LinkConfig) -> Pair {
        Pair::with_firmware(cfg, slow_wheel())
    }

    fn with_firmware(cfg: LinkConfig, fw_cfg: Config) -> Pair {
        Pair {
            now: 0,
            link: RollerLink::new(cfg),
            fw: Roller::new(fw_cfg),
            fw_cfg,
            plugged: true,
            open: false,
            latency: MS,
            to_fw: VecDeque::new(),
            to_host: VecDeque::new(),
            fw_out: FrameDecoder::new(),
            faults: Faults::default(),
            rng: Rng(0x5eed_0001),
            events: Vec::new(),
            written: Vec::new(),
            opens: Vec::new(),
        }
    }

    /// A pair already connected (and the events of that cleared).
    fn connected(cfg: LinkConfig) -> Pair {
        let mut p = Pair::new(cfg);
        p.run_until_event(S, |e| matches!(e, RollerEvent::Connected { .. }))
            .expect("connects");
        p.run_for(10 * MS);
        p.events.clear();
        p.written.clear();
        p
    }

    fn garbage(&mut self) -> Vec<u8> {
        let n = self.rng.below(80) as usize;
        (0..n)
            .map(|_| match self.rng.below(4) {
                0 => 0xA5,
                1 => 0x5A,
                _ => self.rng.next() as u8,
            })
            .collect()
    }

    /// Puts one frame on the line, through the faults.
    fn line(&mut self, bytes: &[u8], to_fw: bool) -> Option<Vec<u8>> {
        let f = self.faults;
        let next = if to_fw {
            &mut self.faults.drop_next_to_fw
        } else {
            &mut self.faults.drop_next_to_host
        };
        if *next > 0 {
            *next -= 1;
            return None;
        }
        if self.rng.chance(f.drop) {
            return None;
        }
        let mut out = if self.rng.chance(f.garbage) {
            self.garbage()
        } else {
            Vec::new()
        };
        for &b in bytes {
            let mut b = b;
            if self.rng.chance(f.corrupt_per_byte) {
                b ^= 1 << self.rng.below(8);
            }
            out.push(b);
        }
        Some(out)
    }

    /// Carries out the link's actions (as the tokio driver does).
    fn actions(&mut self) {
        while let Some(a) = self.link.poll() {
            match a {
                Action::Open => {
                    self.opens.push((self.now, self.plugged));
                    if self.plugged {
                        self.open = true;
                        self.link.handle_opened(PORT, self.now);
                    } else {
                        self.link.handle_open_failed(
                            format!("cannot open roller port {PORT}: No such file or directory"),
                            self.now,
                        );
                    }
                }
                Action::Transmit { frame, target } => {
                    let bytes = frame.as_bytes().to_vec();
                    let f = FrameDecoder::new()
                        .feed(&bytes)
                        .next()
                        .unwrap()
                        .expect("the link writes valid frames");
                    self.written.push(Written {
                        at: self.now,
                        seq: f.seq,
                        cmd: Command::from_frame(&f).expect("a command"),
                        bytes: bytes.clone(),
                        target,
                    });
                    assert!(self.open, "write on a closed port");
                    if let Some(b) = self.line(&bytes, true) {
                        self.to_fw.push_back((self.now + self.latency, b));
                    }
                }
                Action::Close => {
                    self.open = false;
                    self.to_host.clear();
                }
                Action::Event(e) => {
                    assert!(!matches!(e, RollerEvent::TargetWritten { .. }));
                    self.events.push((self.now, e));
                }
            }
        }
    }

    /// Advances to the next event and handles everything due then; false
    /// when nothing is scheduled before `limit`.
    fn step(&mut self, limit: u64) -> bool {
        self.actions();
        let next = [
            self.link.poll_timeout(),
            self.fw.next_event_at(),
            self.to_fw.front().map(|x| x.0),
            self.to_host.front().map(|x| x.0),
        ]
        .into_iter()
        .flatten()
        .min();
        let Some(next) = next.filter(|&t| t <= limit) else {
            self.now = self.now.max(limit);
            return false;
        };
        self.now = self.now.max(next);
        let now = self.now;
        while self.to_fw.front().is_some_and(|x| x.0 <= now) {
            let (_, b) = self.to_fw.pop_front().unwrap();
            self.fw.receive(&b, now);
        }
        self.fw.tick(now);
        let mut buf = [0u8; 512];
        loop {
            let n = self.fw.take_output(&mut buf);
            if n == 0 {
                break;
            }
            let frames: Vec<_> = self.fw_out.feed(&buf[..n]).flatten().collect();
            for f in frames {
                if self.faults.mute || !self.open || self.faults.drop_kind == Some(f.kind) {
                    continue;
                }
                if let Some(b) = self.line(f.encode().as_bytes(), false) {
                    self.to_host.push_back((now + self.latency, b));
                }
            }
        }
        while self.to_host.front().is_some_and(|x| x.0 <= now) {
            let (_, b) = self.to_host.pop_front().unwrap();
            self.link.handle_bytes(&b, now);
        }
        if self.link.poll_timeout().is_some_and(|t| t <= now) {
            self.link.handle_timeout(now);
        }
        self.actions();
        true
    }

    fn run_for(&mut self, d: u64) {
        let end = self.now + d;
        while self.step(end) {}
    }

    /// Runs until an event matching `f` (returns it and its time), at most `d`.
    fn run_until_event(
        &mut self,
        d: u64,
        f: impl Fn(&RollerEvent) -> bool,
    ) -> Option<(u64, RollerEvent)> {
        let end = self.now + d;
        let from = self.events.len();
        loop {
            if let Some(e) = self.events[from..].iter().find(|(_, e)| f(e)) {
                return Some(e.clone());
            }
            if !self.step(end) {
                return None;
            }
        }
    }

    fn set_target(&mut self, t: Target) {
        self.link.set_target(t, self.now);
    }

    /// Sets `t` and runs until the link reports arrival there; checks the
    /// firmware is there. Returns the time taken and the path turned.
    fn go(&mut self, t: Target) -> (u64, i64) {
        let (t0, abs0) = (self.now, self.fw.absolute_steps());
        self.set_target(t);
        self.run_until_arrived(t);
        (self.now - t0, self.fw.absolute_steps() - abs0)
    }

    /// Runs until the link's state says arrived at `t` (which may already
    /// be true: the same target again sends nothing), then checks.
    fn run_until_arrived(&mut self, t: Target) {
        let end = self.now + 30 * S;
        while self.link.state().arrived != Some(t) {
            if !self.step(end) {
                panic!("never arrived at {t:?}: {:?}", self.link);
            }
        }
        self.check_at(t);
    }

    /// The firmware is at rest on `t`, and the link's state says arrived.
    fn check_at(&self, t: Target) {
        let want = t.steps(self.fw.slots(), self.fw.steps_per_rev());
        assert_eq!(
            self.fw.position_steps(),
            want,
            "firmware position for {t:?}"
        );
        assert!(!self.fw.planner().is_moving());
        let st = self.link.state();
        assert_eq!(st.arrived, Some(t));
        assert_eq!(st.target, Some(t));
        assert_eq!(st.status.map(|s| s.position), Some(want));
    }

    /// Unplugs the port: the open port reports an error (as the driver's
    /// read does) and opens fail until [`Pair::plug`]. The firmware keeps
    /// running.
    fn unplug(&mut self) {
        self.plugged = false;
        self.to_fw.clear();
        self.to_host.clear();
        self.link
            .handle_port_error("read failed: Input/output error (os error 5)", self.now);
        self.actions();
    }

    fn plug(&mut self) {
        self.plugged = true;
    }

    /// The firmware restarts where the wheel stands (it knows nothing of
    /// any target; its watchdog is unarmed).
    fn reset_firmware(&mut self) {
        let at = self.fw.absolute_steps();
        self.fw = Roller::new(self.fw_cfg).with_position(at);
        self.fw_out = FrameDecoder::new();
        self.to_fw.clear();
    }

    fn count(&self, f: impl Fn(&RollerEvent) -> bool) -> usize {
        self.events.iter().filter(|(_, e)| f(e)).count()
    }

    fn arrivals(&self) -> Vec<Target> {
        self.events
            .iter()
            .filter_map(|(_, e)| match e {
                RollerEvent::Arrived { target, .. } => Some(*target),
                _ => None,
            })
            .collect()
    }

    fn gotos(&self) -> Vec<&Written> {
        self.written
            .iter()
            .filter(|w| w.cmd.is_move() && w.cmd != Command::Stop)
            .collect()
    }
}

fn cmds(w: &[Written]) -> Vec<Command> {
    w.iter().map(|w| w.cmd).collect()
}

#[test]
fn hello_then_position_resync_then_connected() {
    let mut p = Pair::new(link_config());
    let (at, ev) = p
        .run_until_event(S, |e| matches!(e, RollerEvent::Connected { .. }))
        .unwrap();
    let RollerEvent::Connected { port, version } = ev else {
        unreachable!()
    };
    assert_eq!(port, PORT);
    assert_eq!(version.protocol, 1);
    assert_eq!((version.steps_per_rev, version.slots), (3200, 16));
    // Two round trips of 2 ms: Hello/Version, QueryStatus/Status.
    assert_eq!(at, 4 * MS);
    assert_eq!(
        cmds(&p.written),
        [Command::Hello { protocol: 1 }, Command::QueryStatus]
    );
    let st = p.link.state();
    assert!(st.connected);
    assert_eq!(st.port.as_deref(), Some(PORT));
    assert_eq!(st.version, Some(version));
    assert_eq!(st.status.map(|s| s.position), Some(0));
    // The Position event follows Connected.
    assert!(matches!(
        p.events.last(),
        Some((
            _,
            RollerEvent::Position {
                steps: 0,
                mdeg: 0,
                slot: Some(0),
                moving: false
            }
        ))
    ));
    assert_eq!(p.opens, [(0, true)]);
}

#[test]
fn slot_count_and_motion_are_set_after_hello_and_slots_mean_the_new_count() {
    let cfg = LinkConfig {
        slots: Some(12),
        motion: Some((1600, 3200)),
        ..link_config()
    };
    let mut p = Pair::new(cfg);
    let (_, ev) = p
        .run_until_event(S, |e| matches!(e, RollerEvent::Connected { .. }))
        .unwrap();
    let RollerEvent::Connected { version, .. } = ev else {
        unreachable!()
    };
    assert_eq!(
        cmds(&p.written),
        [
            Command::Hello { protocol: 1 },
            Command::SetSlots { slots: 12 },
            Command::SetMotion {
                max_speed: 1600,
                accel: 3200
            },
            Command::QueryStatus
        ]
    );
    assert_eq!(version.slots, 12);
    assert_eq!(p.fw.slots(), 12);
    assert_eq!(p.fw.planner().max_speed(), 1600);
    // Slot 3 of 12 is a quarter turn (800 microsteps), not 3/16 of a turn.
    let (_, turned) = p.go(Target::Slot(3));
    assert_eq!(turned, 800);
    assert_eq!(p.fw.position_steps(), 800);
    // After a firmware reset (back to 16 slots) and a reconnect, the count
    // is set again.
    p.unplug();
    p.reset_firmware();
    assert_eq!(p.fw.slots(), 16);
    p.plug();
    p.run_until_event(5 * S, |e| matches!(e, RollerEvent::Connected { .. }))
        .unwrap();
    assert_eq!(p.fw.slots(), 12);
    p.go(Target::Slot(9));
    assert_eq!(p.fw.position_steps(), 2400);
}

#[test]
fn a_refused_slot_count_is_reported_and_the_link_still_comes_up() {
    let cfg = LinkConfig {
        slots: Some(5000), // more than 3200 microsteps per turn
        ..link_config()
    };
    let mut p = Pair::new(cfg);
    p.run_until_event(S, |e| matches!(e, RollerEvent::Connected { .. }))
        .unwrap();
    let errors: Vec<_> = p
        .events
        .iter()
        .filter_map(|(_, e)| match e {
            RollerEvent::Error { message } => Some(message.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(errors.len(), 1, "{errors:?}");
    assert!(
        errors[0].contains("refused 5000 slots") && errors[0].contains("argument out of range"),
        "{errors:?}"
    );
    assert_eq!(p.fw.slots(), 16);
}

#[test]
fn moves_take_the_shortest_path_in_the_planned_time_and_arrive_once() {
    let mut p = Pair::connected(link_config());
    // (target, path turned, move time from the planner table)
    let moves = [
        (Target::Slot(15), -200, 354 * MS),  // one slot back across zero
        (Target::Slot(2), 600, 0),           // three slots on across zero
        (Target::Slot(9), 1400, 0),          // 7 slots (shorter than 9 back)
        (Target::Slot(1), -1600, 1000 * MS), // a half turn goes backwards
        (Target::AngleMdeg(350_000), -289, 0),
        (Target::Steps(100), 189, 0),
    ];
    for (t, path, time) in moves {
        let (took, turned) = p.go(t);
        assert_eq!(turned, path, "{t:?}");
        if time > 0 {
            // Planned move time, plus the command's trip to the firmware
            // and the Arrived frame's trip back (1 ms each), within 1 ms.
            assert!(took.abs_diff(time + 2 * MS) <= MS, "{t:?} took {took} us");
        }
    }
    let targets: Vec<Target> = moves.iter().map(|m| m.0).collect();
    assert_eq!(p.arrivals(), targets);
    // Each target's command was written once, marked as a new target.
    let firsts: Vec<Target> = p.written.iter().filter_map(|w| w.target).collect();
    assert_eq!(firsts, targets);
    assert_eq!(p.gotos().len(), targets.len());
    assert!(p.count(|e| matches!(e, RollerEvent::Position { moving: true, .. })) > 10);
    assert!(p.events.iter().any(|(_, e)| matches!(
        e,
        RollerEvent::Position {
            slot: Some(9),
            moving: false,
            ..
        }
    )));
}

#[test]
fn retargeting_mid_move_only_the_latest_arrives() {
    let mut p = Pair::connected(link_config());
    p.set_target(Target::Slot(6)); // 1200 steps on
    while p.fw.absolute_steps() < 300 {
        assert!(p.step(u64::MAX));
    }
    assert!(p.fw.planner().is_moving());
    // Three new decisions at once while the first move is under way: the
    // first of them is sent at once, the last replaces the second while
    // that command is in flight.
    p.set_target(Target::Slot(4));
    p.set_target(Target::Slot(10));
    p.set_target(Target::Slot(13)); // behind: brake, reverse through zero
    p.go(Target::Slot(13));
    assert_eq!(p.fw.position_steps(), 2600);
    assert_eq!(p.arrivals(), [Target::Slot(13)]);
    let gotos: Vec<Command> = p.gotos().iter().map(|w| w.cmd).collect();
    assert_eq!(
        gotos,
        [
            Command::GotoSlot { slot: 6 },
            Command::GotoSlot { slot: 4 },
            Command::GotoSlot { slot: 13 }
        ]
    );
}

#[test]
fn a_burst_of_targets_becomes_two_frames() {
    let mut p = Pair::connected(link_config());
    for i in 0..500u32 {
        p.set_target(Target::Steps(i * 7 % 3200));
    }
    let last = Target::Steps(499 * 7 % 3200);
    p.go(last);
    // The first goes out at once; while it is in flight the other 499
    // replace each other, and only the last is sent.
    let gotos: Vec<Command> = p.gotos().iter().map(|w| w.cmd).collect();
    assert_eq!(
        gotos,
        [
            Command::GotoSteps { steps: 0 },
            Command::GotoSteps {
                steps: 499 * 7 % 3200
            }
        ]
    );
    assert_eq!(p.arrivals(), [last]);
}

#[test]
fn a_lost_command_is_resent_with_the_same_bytes_after_each_ack_timeout() {
    let mut p = Pair::connected(link_config());
    p.faults.drop_next_to_fw = 3;
    let t0 = p.now;
    let (took, turned) = p.go(Target::Slot(4));
    assert_eq!(turned, 800);
    let gotos = p.gotos();
    assert_eq!(gotos.len(), 4, "first send + 3 retries");
    for (i, w) in gotos.iter().enumerate() {
        assert_eq!(
            w.at - t0,
            i as u64 * 250 * MS,
            "try {i} at ack_timeout steps"
        );
        assert_eq!(
            w.bytes, gotos[0].bytes,
            "a retry is the same frame, same SEQ"
        );
    }
    assert_eq!(gotos.iter().filter(|w| w.target.is_some()).count(), 1);
    // The quarter turn starts with the fourth send.
    assert!(took.abs_diff(750 * MS + 707 * MS + 2 * MS) <= MS, "{took}");
    assert!(!p
        .events
        .iter()
        .any(|(_, e)| matches!(e, RollerEvent::Disconnected { .. })));
}

#[test]
fn a_lost_ack_is_retried_and_the_retry_does_not_disturb_the_move() {
    let mut p = Pair::connected(link_config());
    p.faults.drop_next_to_host = 1; // the Ack
    let (_, turned) = p.go(Target::Slot(8)); // a half turn, 1 s
    assert_eq!(turned, -1600, "the retry kept the course");
    let gotos = p.gotos();
    assert_eq!(gotos.len(), 2);
    assert_eq!(gotos[1].at - gotos[0].at, 250 * MS);
    assert_eq!(p.arrivals(), [Target::Slot(8)]);
}

#[test]
fn a_lost_arrived_frame_is_made_up_by_the_next_keepalive() {
    let mut p = Pair::connected(link_config());
    p.faults.drop_kind = Some(kind::ARRIVED);
    let (took, _) = p.go(Target::Slot(1)); // 0.354 s
                                           // The move ends at ~355 ms; the keepalive after it (every 400 ms from
                                           // the goto) sees the wheel at rest on the target.
    assert!(took > 355 * MS && took <= 400 * MS + 2 * MS, "{took}");
    assert_eq!(p.arrivals(), [Target::Slot(1)]);
}

#[test]
fn a_silent_firmware_is_declared_dead_after_max_tries_and_reopened_with_backoff() {
    let mut p = Pair::connected(link_config());
    p.set_target(Target::Slot(2));
    p.faults.mute = true;
    let t0 = p.now;
    let (at, ev) = p
        .run_until_event(10 * S, |e| matches!(e, RollerEvent::Disconnected { .. }))
        .unwrap();
    let RollerEvent::Disconnected { reason } = ev else {
        unreachable!()
    };
    assert_eq!(
        reason,
        "roller link sim0 lost: no answer to GotoSlot { slot: 2 } after 4 tries of 250ms"
    );
    assert_eq!(at - t0, 4 * 250 * MS);
    assert!(!p.link.state().connected);
    assert_eq!(p.link.state().reconnects, 1);
    // Each reopen says Hello 4 times and gives up after 1 s; the pauses
    // between the attempts double from 50 ms up to the 2 s cap.
    p.run_for(12 * S);
    let opens: Vec<u64> = p.opens[1..].iter().map(|o| o.0).collect();
    assert_eq!(opens[0] - at, 50 * MS);
    let gaps: Vec<u64> = opens.windows(2).map(|w| (w[1] - w[0]) / MS).collect();
    assert_eq!(gaps, [1100, 1200, 1400, 1800, 2600, 3000]);
    // The firmware speaks again: the link comes back, the target is reached.
    p.faults.mute = false;
    p.go(Target::Slot(2));
    assert!(p.link.state().connected);
    assert_eq!(p.link.state().reconnects, 1, "never connected in between");
    // A good connection resets the backoff: the next loss reopens after
    // 50 ms again.
    p.faults.mute = true;
    let n = p.opens.len();
    let (at, _) = p
        .run_until_event(10 * S, |e| matches!(e, RollerEvent::Disconnected { .. }))
        .unwrap();
    p.run_for(100 * MS);
    assert_eq!(p.opens[n].0 - at, 50 * MS);
    assert_eq!(p.link.state().reconnects, 2);
}

#[test]
fn a_missing_port_is_reported_once_and_retried_with_doubling_backoff() {
    let mut p = Pair::new(link_config());
    p.plugged = false;
    p.set_target(Target::Slot(2));
    p.run_for(10 * S);
    let opens: Vec<u64> = p.opens.iter().map(|o| o.0 / MS).collect();
    assert_eq!(opens, [0, 50, 150, 350, 750, 1550, 3150, 5150, 7150, 9150]);
    let errors: Vec<_> = p
        .events
        .iter()
        .filter_map(|(_, e)| match e {
            RollerEvent::Error { message } => Some(message.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(
        errors,
        ["cannot open roller port sim0: No such file or directory; retrying in 50ms"]
    );
    assert!(!p.link.state().connected);
    p.plug();
    let (took, _) = p.go(Target::Slot(2));
    // The next attempt is at 11.15 s; then the hello, the resync, the move.
    assert!(took < 2 * S, "{took}");
    assert_eq!(p.link.state().reconnects, 0);
}

#[test]
fn disconnect_mid_move_then_a_new_target_then_reconnect() {
    let mut p = Pair::connected(link_config());
    p.set_target(Target::Slot(8));
    p.run_for(300 * MS);
    assert!(p.fw.planner().is_moving());
    p.unplug();
    let reason = p
        .events
        .iter()
        .find_map(|(_, e)| match e {
            RollerEvent::Disconnected { reason } => Some(reason.clone()),
            _ => None,
        })
        .expect("Disconnected");
    assert_eq!(
        reason,
        "roller link sim0 lost: read failed: Input/output error (os error 5)"
    );
    assert!(!p.link.state().connected);
    // A new decision while the link is down: nothing is written, and the
    // latest wins after the reconnect.
    let n = p.written.len();
    p.set_target(Target::Slot(3));
    p.run_for(500 * MS);
    assert_eq!(p.written.len(), n);
    p.plug();
    p.go(Target::Slot(3));
    assert_eq!(p.fw.position_steps(), 600);
    assert_eq!(p.link.state().reconnects, 1);
    assert_eq!(p.arrivals(), [Target::Slot(3)]);
}

#[test]
fn a_watchdog_stop_during_a_long_outage_is_recovered() {
    let mut p = Pair::with_firmware(
        link_config(),
        Config {
            max_speed: 400,
            ..slow_wheel()
        },
    );
    p.run_until_event(S, |e| matches!(e, RollerEvent::Connected { .. }))
        .unwrap();
    p.set_target(Target::Slot(8)); // 1600 steps at 400/s: 4 s
    p.run_for(500 * MS);
    p.unplug();
    p.run_for(4 * S);
    // The firmware's 2 s watchdog stopped the silent move short of the target.
    assert!(p.fw.watchdog_tripped());
    assert!(!p.fw.planner().is_moving());
    assert!(!p.fw.motor_enabled());
    assert_ne!(p.fw.position_steps(), 1600);
    p.plug();
    p.go(Target::Slot(8));
    assert!(!p.fw.watchdog_tripped());
}

#[test]
fn a_firmware_reset_with_the_port_open_is_resynced_by_the_keepalive() {
    let mut p = Pair::connected(link_config());
    p.set_target(Target::Slot(4));
    p.run_for(200 * MS);
    assert!(p.fw.planner().is_moving());
    p.reset_firmware(); // stands where it was, target forgotten
    assert!(!p.fw.planner().is_moving());
    let (took, _) = p.go(Target::Slot(4));
    // The next keepalive (<= 400 ms) sees a target that is not ours.
    assert!(took < 400 * MS + 707 * MS, "{took}");
    let gotos = p.gotos();
    assert_eq!(gotos.len(), 2);
    assert_ne!(gotos[0].seq, gotos[1].seq, "a new command, not a retry");
    assert!(!p
        .events
        .iter()
        .any(|(_, e)| matches!(e, RollerEvent::Disconnected { .. })));
}

#[test]
fn a_firmware_reset_with_a_reconnect_resends_the_target() {
    let mut p = Pair::connected(link_config());
    p.set_target(Target::Slot(12));
    p.run_for(200 * MS);
    p.unplug();
    p.reset_firmware();
    p.plug();
    p.go(Target::Slot(12));
    assert_eq!(p.fw.position_steps(), 2400);
    assert_eq!(p.link.state().reconnects, 1);
}

#[test]
fn a_refused_target_is_reported_not_retried_forever() {
    let mut p = Pair::connected(link_config());
    p.set_target(Target::Slot(40));
    let (_, ev) = p
        .run_until_event(S, |e| matches!(e, RollerEvent::Error { .. }))
        .unwrap();
    let RollerEvent::Error { message } = ev else {
        unreachable!()
    };
    assert!(
        message.contains("GotoSlot { slot: 40 }") && message.contains("argument out of range"),
        "{message}"
    );
    let n = p.written.len();
    p.run_for(10 * S);
    // Only keepalives since, one per 400 ms: no retry storm.
    let since = cmds(&p.written[n..]);
    assert!(
        since.iter().all(|c| *c == Command::QueryStatus),
        "{since:?}"
    );
    assert_eq!(since.len(), 25);
    assert_eq!(p.count(|e| matches!(e, RollerEvent::Error { .. })), 1);
    p.go(Target::Slot(1));
}

#[test]
fn a_firmware_with_another_protocol_is_refused_with_a_clear_error() {
    let mut link = RollerLink::new(link_config());
    assert!(matches!(link.poll(), Some(Action::Open)));
    link.handle_opened(PORT, 0);
    let Some(Action::Transmit { frame, .. }) = link.poll() else {
        panic!("no Hello")
    };
    let f = FrameDecoder::new()
        .feed(frame.as_bytes())
        .next()
        .unwrap()
        .unwrap();
    assert_eq!(
        Command::from_frame(&f).unwrap(),
        Command::Hello { protocol: 1 }
    );
    let v = Version {
        protocol: 2,
        firmware: [9, 0, 0],
        steps_per_rev: 3200,
        slots: 16,
        watchdog_ms: 2000,
        max_speed: 3200,
        accel: 6400,
    };
    link.handle_bytes(Reply::Version(v).encode(f.seq).as_bytes(), 2 * MS);
    let actions: Vec<Action> = std::iter::from_fn(|| link.poll()).collect();
    let [Action::Event(RollerEvent::Error { message }), Action::Event(RollerEvent::Disconnected { .. }), Action::Close] =
        &actions[..]
    else {
        panic!("{actions:?}")
    };
    assert!(
        message.contains("protocol 2")
            && message.contains("firmware 9.0.0")
            && message.contains("update the firmware"),
        "{message}"
    );
    assert!(!link.state().connected);
    assert_eq!(link.state().version, None);
    // It tries again after the backoff.
    assert_eq!(link.poll_timeout(), Some(52 * MS));
    link.handle_timeout(52 * MS);
    assert!(matches!(link.poll(), Some(Action::Open)));
}

/// During the handshake only the expected answer counts: a periodic
/// `Status` or an `Arrived` from a move of an earlier connection that
/// happens to carry the Hello's SEQ is not taken for the answer.
#[test]
fn an_unsolicited_frame_with_the_hellos_seq_is_not_the_answer() {
    use telextiles_roller::link::{Phase, Step};
    let mut link = RollerLink::new(link_config());
    assert!(matches!(link.poll(), Some(Action::Open)));
    link.handle_opened(PORT, 0);
    let Some(Action::Transmit { frame, .. }) = link.poll() else {
        panic!("no Hello")
    };
    let seq = FrameDecoder::new()
        .feed(frame.as_bytes())
        .next()
        .unwrap()
        .unwrap()
        .seq;
    let moving = telextiles_proto::roller::Status {
        position: 100,
        target: 800,
        speed: 1000,
        slots: 16,
        flags: 3,
    };
    link.handle_bytes(Reply::Status(moving).encode(seq).as_bytes(), MS);
    link.handle_bytes(Reply::Arrived(moving).encode(seq).as_bytes(), MS);
    assert_eq!(link.phase(), Phase::Handshake(Step::Hello));
    assert!(link.poll().is_none());
    let v = Version {
        protocol: 1,
        firmware: [0, 1, 0],
        steps_per_rev: 3200,
        slots: 16,
        watchdog_ms: 2000,
        max_speed: 3200,
        accel: 6400,
    };
    link.handle_bytes(Reply::Version(v).encode(seq).as_bytes(), 2 * MS);
    assert_eq!(link.phase(), Phase::Handshake(Step::Resync));
}

#[test]
fn keepalives_hold_the_watchdog_off_for_an_hour_at_rest() {
    let mut p = Pair::connected(link_config());
    p.go(Target::Slot(5));
    let n = p.written.len();
    p.run_for(3600 * S);
    assert!(!p.fw.watchdog_tripped());
    assert!(p.fw.motor_enabled());
    let since = cmds(&p.written[n..]);
    assert!(since.iter().all(|c| *c == Command::QueryStatus));
    assert_eq!(since.len(), 9000);
    assert_eq!(p.arrivals(), [Target::Slot(5)]);
    assert_eq!(
        p.count(|e| matches!(e, RollerEvent::Disconnected { .. })),
        0
    );
}

#[test]
fn garbage_corruption_and_loss_both_ways_every_target_is_reached() {
    let mut p = Pair::connected(link_config());
    p.faults = Faults {
        drop: 0.05,
        corrupt_per_byte: 0.01,
        garbage: 0.3,
        ..Faults::default()
    };
    let mut rng = Rng(77);
    for i in 0..100 {
        let t = Target::Slot(rng.below(16) as u16);
        p.go(t);
        assert_eq!(p.fw.position_steps(), t.steps(16, 3200), "target {i}");
    }
    assert!(p.fw.bad_frames() > 50, "{}", p.fw.bad_frames());
    // Frames were lost badly enough to need retries...
    let retries = p
        .written
        .windows(2)
        .filter(|w| w[0].bytes == w[1].bytes)
        .count();
    assert!(retries > 20, "{retries}");
}

/// Random targets at random moments, with random faults, unplugs and
/// firmware resets, over many seeds: the final target is always reached,
/// and the link's view agrees with the firmware.
#[test]
fn random_targets_faults_and_outages_always_end_on_the_latest_target() {
    for seed in 1..=40u64 {
        let mut p = Pair::connected(link_config());
        let mut rng = Rng(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
        p.rng = Rng(seed | 1);
        p.faults = Faults {
            drop: 0.02 * rng.below(4) as f64,
            corrupt_per_byte: 0.002 * rng.below(4) as f64,
            garbage: 0.1 * rng.below(3) as f64,
            ..Faults::default()
        };
        let mut last = None;
        for _ in 0..30 {
            let t = match rng.below(3) {
                0 => Target::Slot(rng.below(16) as u16),
                1 => Target::AngleMdeg(rng.below(360_000) as u32),
                _ => Target::Steps(rng.below(3200) as u32),
            };
            p.set_target(t);
            last = Some(t);
            match rng.below(20) {
                0 => {
                    p.unplug();
                    p.run_for(rng.below(3000) * MS);
                    p.plug();
                }
                1 => p.reset_firmware(),
                _ => {}
            }
            p.run_for(rng.below(600) * MS);
        }
        let last = last.unwrap();
        p.faults = Faults::default();
        p.run_until_arrived(last);
        p.run_for(2 * S);
        p.check_at(last);
        assert!(p.link.state().connected, "seed {seed}");
    }
}

#[test]
fn link_config_comes_from_the_driver_config() {
    let d = telextiles_roller::DriverConfig {
        slots: Some(12),
        ack_timeout: Duration::from_millis(100),
        ..telextiles_roller::DriverConfig::path("/dev/null")
    };
    let c = LinkConfig::from(&d);
    assert_eq!(c.slots, Some(12));
    assert_eq!(c.ack_timeout, Duration::from_millis(100));
    assert_eq!(c.max_tries, 4);
    assert_eq!(c.keepalive, Duration::from_millis(400));
}
