//! Roller firmware core, `no_std`, host-testable.
//!
//! [`Roller`] is the whole firmware minus the pins: it parses command frames
//! ([`telextiles_proto::roller`]), plans steps ([`motion::Planner`]), tracks
//! the position, runs the link watchdog and queues replies. It has no clock:
//! every call takes `now_us`, so the ESP32 binding (`firmware/esp32/`), the
//! host simulator ([`sim`], binary `roller-sim`) and the tests drive exactly
//! the same code.
//!
//! Driving it:
//! ```
//! use roller_firmware::{Config, Roller};
//! let mut fw = Roller::new(Config::default());
//! let cmd = telextiles_proto::roller::Command::GotoSlot { slot: 4 }.encode(1);
//! fw.receive(cmd.as_bytes(), 0);
//! let mut now = 0;
//! while let Some(at) = fw.next_step_at() {
//!     now = at;
//!     // on hardware: set DIR from the returned direction, pulse STEP
//!     fw.step(now);
//! }
//! assert_eq!(fw.position_steps(), 800); // slot 4 of 16 = 90 degrees
//! let mut out = [0u8; 256];
//! let n = fw.take_output(&mut out); // Ack, then Arrived
//! assert!(n > 0);
//! ```
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod motion;
#[cfg(feature = "std")]
pub mod sim;

use motion::{Planner, MAX_ACCEL_LIMIT, MAX_SPEED_LIMIT};
use telextiles_proto::roller::{
    self as wire, status_flags, Command, ErrorCode, Frame, FrameDecoder, Reply, Status, Version,
    PROTOCOL_VERSION,
};

/// Firmware version reported in `Version`.
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];

/// Default top speed, microsteps/s: 3 rev/s at 1/16 microstepping (a
/// step every 104 µs, well within the ESP32 loop's reach).
pub const DEFAULT_MAX_SPEED: u32 = 3 * 3200;
/// Default acceleration, microsteps/s^2: 30 rev/s^2. An 8 cm plate of 3 mm
/// acrylic with its samples (about 30 g, 2.4e-5 kg m^2) needs under 5 mN m
/// for it, a small share of a NEMA 17's torque at 3 rev/s.
pub const DEFAULT_ACCEL: u32 = 30 * 3200;

/// Static configuration of a roller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Config {
    /// Full steps per motor revolution (200 for a 1.8 degree stepper).
    pub full_steps: u32,
    /// Microstepping set on the driver (A4988: 1, 2, 4, 8 or 16).
    pub microsteps: u32,
    /// Slots on the wheel, N.
    pub slots: u16,
    /// Maximum speed, microsteps/s.
    pub max_speed: u32,
    /// Acceleration, microsteps/s^2.
    pub accel: u32,
    /// Link watchdog: after this long without a valid host frame the wheel
    /// decelerates to a stop and the driver is disabled.
    pub watchdog_us: u64,
    /// While moving, a `Status` frame is sent this often.
    pub status_interval_us: u64,
}

/// The paper's wheel: an ST-42BYH1004 (NEMA 17, 1.8 degrees, 200 full
/// steps) through an A4988 at 1/16 microstepping, 16 fabric samples on an
/// 8 cm plate (one sample every 15.7 mm of rim). Speed and acceleration are
/// a fast step generator's, at the cautious end of what such a motor does
/// with so light a load: 3 rev/s ([`DEFAULT_MAX_SPEED`]) and 30 rev/s^2
/// ([`DEFAULT_ACCEL`]). One slot takes 91 ms, a quarter turn 183 ms and a
/// half turn 267 ms from rest to rest.
impl Default for Config {
    fn default() -> Self {
        Config {
            full_steps: 200,
            microsteps: 16,
            slots: 16,
            max_speed: DEFAULT_MAX_SPEED,
            accel: DEFAULT_ACCEL,
            watchdog_us: 2_000_000,
            status_interval_us: 100_000,
        }
    }
}

impl Config {
    /// Microsteps per wheel revolution.
    pub fn steps_per_rev(&self) -> u32 {
        (self.full_steps * self.microsteps).max(1)
    }
}

/// Bytes waiting to go out on the serial line.
const OUTBOX: usize = 512;

/// The firmware core.
#[derive(Clone)]
pub struct Roller {
    cfg: Config,
    spr: u32,
    slots: u16,
    planner: Planner,
    decoder: FrameDecoder,
    outbox: [u8; OUTBOX],
    out_len: usize,
    dropped_replies: u32,
    enabled: bool,
    watchdog_tripped: bool,
    last_host_us: Option<u64>,
    /// Sequence number of the command that set the current target.
    move_seq: u8,
    awaiting_arrival: bool,
    last_status_us: u64,
    bad_frames: u32,
}

impl Roller {
    pub fn new(cfg: Config) -> Roller {
        Roller {
            spr: cfg.steps_per_rev(),
            slots: cfg.slots.max(1),
            planner: Planner::new(cfg.max_speed, cfg.accel),
            cfg,
            decoder: FrameDecoder::new(),
            outbox: [0; OUTBOX],
            out_len: 0,
            dropped_replies: 0,
            enabled: false,
            watchdog_tripped: false,
            last_host_us: None,
            move_seq: 0,
            awaiting_arrival: false,
            last_status_us: 0,
            bad_frames: 0,
        }
    }

    /// Starts at a given (unwrapped) position, e.g. one restored after a reset.
    pub fn with_position(mut self, steps: i64) -> Roller {
        self.planner.set_position(steps);
        self
    }

    pub fn config(&self) -> &Config {
        &self.cfg
    }

    pub fn steps_per_rev(&self) -> u32 {
        self.spr
    }

    pub fn slots(&self) -> u16 {
        self.slots
    }

    /// Position in microsteps, `0..steps_per_rev`.
    pub fn position_steps(&self) -> u32 {
        self.planner.position().rem_euclid(self.spr as i64) as u32
    }

    /// Unwrapped position in microsteps (counts whole turns).
    pub fn absolute_steps(&self) -> i64 {
        self.planner.position()
    }

    pub fn planner(&self) -> &Planner {
        &self.planner
    }

    /// Whether the driver's EN pin should be active.
    pub fn motor_enabled(&self) -> bool {
        self.enabled
    }

    pub fn watchdog_tripped(&self) -> bool {
        self.watchdog_tripped
    }

    /// Frames dropped for a bad checksum or length.
    pub fn bad_frames(&self) -> u32 {
        self.bad_frames
    }

    /// Replies dropped because the outbox was full.
    pub fn dropped_replies(&self) -> u32 {
        self.dropped_replies
    }

    pub fn status(&self) -> Status {
        let mut flags = 0;
        if self.planner.is_moving() {
            flags |= status_flags::MOVING;
        }
        if self.enabled {
            flags |= status_flags::ENABLED;
        }
        if self.watchdog_tripped {
            flags |= status_flags::WATCHDOG;
        }
        Status {
            position: self.position_steps(),
            target: self.planner.target().rem_euclid(self.spr as i64) as u32,
            speed: self.planner.speed(),
            slots: self.slots,
            flags,
        }
    }

    /// When the next step is due (`None` at rest).
    pub fn next_step_at(&self) -> Option<u64> {
        self.planner.next_step_at()
    }

    /// When [`Roller::tick`] next has something to do: a step, a status
    /// report or the watchdog.
    pub fn next_event_at(&self) -> Option<u64> {
        let mut t = self.planner.next_step_at();
        if self.planner.is_moving() {
            let s = self.last_status_us + self.cfg.status_interval_us;
            t = Some(t.map_or(s, |x| x.min(s)));
        }
        if let (Some(last), true) = (self.last_host_us, self.enabled && !self.watchdog_tripped) {
            let w = last + self.cfg.watchdog_us;
            t = Some(t.map_or(w, |x| x.min(w)));
        }
        t
    }

    /// Feeds bytes received on the serial line.
    pub fn receive(&mut self, bytes: &[u8], now_us: u64) {
        let mut decoder = self.decoder.clone();
        for item in decoder.feed(bytes) {
            match item {
                Ok(frame) => self.handle_frame(&frame, now_us),
                Err(_) => self.bad_frames = self.bad_frames.wrapping_add(1),
            }
        }
        self.decoder = decoder;
    }

    /// Moves bytes queued for the serial line into `out`; returns how many.
    pub fn take_output(&mut self, out: &mut [u8]) -> usize {
        let n = out.len().min(self.out_len);
        out[..n].copy_from_slice(&self.outbox[..n]);
        self.outbox.copy_within(n..self.out_len, 0);
        self.out_len -= n;
        n
    }

    /// Bytes waiting to be sent.
    pub fn output_len(&self) -> usize {
        self.out_len
    }

    /// Takes one step if it is due; returns its direction (+1 clockwise) so
    /// the binding can set DIR and pulse STEP. Also queues `Arrived` when the
    /// step ends the move.
    pub fn step(&mut self, now_us: u64) -> Option<i8> {
        if !self.enabled {
            return None;
        }
        let st = self.planner.step(now_us)?;
        if !self.planner.is_moving() {
            self.on_rest(st.at);
        }
        Some(st.dir)
    }

    /// Does everything due at `now_us`: all steps, the watchdog, periodic
    /// status. Returns the number of steps taken (a simulator's motor; a
    /// hardware binding calls [`Roller::step`] and [`Roller::service`]
    /// instead, so that every step becomes a pulse).
    pub fn tick(&mut self, now_us: u64) -> u32 {
        self.check_watchdog(now_us);
        let mut n = 0;
        while self.step(now_us).is_some() {
            n += 1;
        }
        self.service(now_us);
        n
    }

    /// Everything but steps: the link watchdog and the periodic status.
    pub fn service(&mut self, now_us: u64) {
        self.check_watchdog(now_us);
        if self.planner.is_moving() && now_us >= self.last_status_us + self.cfg.status_interval_us {
            self.last_status_us = now_us;
            self.send(self.move_seq, &Reply::Status(self.status()));
        }
    }

    fn check_watchdog(&mut self, now_us: u64) {
        let Some(last) = self.last_host_us else {
            return;
        };
        if self.watchdog_tripped || !self.enabled {
            return;
        }
        if now_us.saturating_sub(last) >= self.cfg.watchdog_us {
            self.watchdog_tripped = true;
            self.awaiting_arrival = false;
            if self.planner.is_moving() {
                self.planner.stop(now_us);
            } else {
                self.enabled = false;
            }
        }
    }

    fn on_rest(&mut self, _now_us: u64) {
        if self.watchdog_tripped {
            self.enabled = false;
        }
        if self.awaiting_arrival {
            self.awaiting_arrival = false;
            self.send(self.move_seq, &Reply::Arrived(self.status()));
        }
    }

    fn send(&mut self, seq: u8, reply: &Reply) {
        let buf = reply.encode(seq);
        let b = buf.as_bytes();
        if self.out_len + b.len() > OUTBOX {
            self.dropped_replies = self.dropped_replies.wrapping_add(1);
            return;
        }
        self.outbox[self.out_len..self.out_len + b.len()].copy_from_slice(b);
        self.out_len += b.len();
    }

    fn error(&mut self, seq: u8, code: ErrorCode, command: u8) {
        self.send(seq, &Reply::Error { code, command });
    }

    fn handle_frame(&mut self, frame: &Frame, now_us: u64) {
        let cmd = match Command::from_frame(frame) {
            Ok(c) => c,
            Err(e) => {
                // Replies (our own echo, a confused peer) are ignored, not answered.
                if frame.kind & 0x80 == 0 {
                    self.error(frame.seq, e.code(), frame.kind);
                }
                return;
            }
        };
        self.last_host_us = Some(now_us);
        let seq = frame.seq;
        match cmd {
            Command::Hello { .. } => {
                // Always answer with our version; the host decides whether it
                // can talk to us (and says so clearly).
                self.watchdog_tripped = false;
                let v = Version {
                    protocol: PROTOCOL_VERSION,
                    firmware: FIRMWARE_VERSION,
                    steps_per_rev: self.spr,
                    slots: self.slots,
                    watchdog_ms: (self.cfg.watchdog_us / 1000) as u32,
                    max_speed: self.planner.max_speed(),
                    accel: self.planner.accel(),
                };
                self.send(seq, &Reply::Version(v));
            }
            Command::GotoSlot { slot } => {
                if slot >= self.slots {
                    return self.error(seq, ErrorCode::BadArgument, frame.kind);
                }
                let s = wire::slot_to_steps(slot, self.slots, self.spr);
                self.goto(s, seq, now_us);
            }
            Command::GotoAngle { mdeg } => {
                let s = wire::mdeg_to_steps(mdeg, self.spr);
                self.goto(s, seq, now_us);
            }
            Command::GotoSteps { steps } => {
                if steps >= self.spr {
                    return self.error(seq, ErrorCode::BadArgument, frame.kind);
                }
                self.goto(steps, seq, now_us);
            }
            Command::Zero => {
                if !self.planner.set_position(0) {
                    return self.error(seq, ErrorCode::Busy, frame.kind);
                }
                self.send(seq, &Reply::Ack(self.status()));
            }
            Command::SetMotion { max_speed, accel } => {
                if max_speed > MAX_SPEED_LIMIT || accel > MAX_ACCEL_LIMIT {
                    return self.error(seq, ErrorCode::BadArgument, frame.kind);
                }
                self.planner.set_motion(max_speed, accel);
                self.send(seq, &Reply::Ack(self.status()));
            }
            Command::SetSlots { slots } => {
                if slots as u32 > self.spr {
                    return self.error(seq, ErrorCode::BadArgument, frame.kind);
                }
                self.slots = slots;
                self.send(seq, &Reply::Ack(self.status()));
            }
            Command::QueryStatus => self.send(seq, &Reply::Status(self.status())),
            Command::Stop => {
                self.move_seq = seq;
                self.planner.stop(now_us);
                self.awaiting_arrival = true;
                self.send(seq, &Reply::Ack(self.status()));
                if !self.planner.is_moving() {
                    self.on_rest(now_us);
                }
            }
        }
    }

    /// Goes to `steps` (0..steps_per_rev) the shorter way round.
    fn goto(&mut self, steps: u32, seq: u8, now_us: u64) {
        self.enabled = true;
        self.watchdog_tripped = false;
        self.move_seq = seq;
        self.awaiting_arrival = true;
        let spr = self.spr as i64;
        let current_target = self.planner.target().rem_euclid(spr) as u32;
        // Same residue as the current target (a retry, or the same decision
        // again): keep the course; only the reported sequence changes.
        if current_target != steps || !self.planner.is_moving() {
            // The paper's rule, applied where the wheel can change direction:
            // from the point it would stop at, go the shorter way.
            let from = self.planner.stop_point();
            let delta = wire::shortest_delta(from.rem_euclid(spr) as u32, steps, self.spr);
            self.planner.set_target(from + delta as i64, now_us);
        }
        if self.planner.is_moving() {
            self.last_status_us = now_us;
        }
        self.send(seq, &Reply::Ack(self.status()));
        if !self.planner.is_moving() {
            self.on_rest(now_us);
        }
    }
}
