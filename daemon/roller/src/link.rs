//! The roller link as a sans-IO state machine.
//!
//! [`RollerLink`] is the whole host side of the roller protocol
//! (`docs/roller-protocol.md`) without a port, a clock or a task: hello and
//! version check, the optional `SetSlots` / `SetMotion` after hello, the
//! position resync, latest target wins with at most one command in flight,
//! acknowledgements and retries after a timeout, keepalive status polls,
//! arrival (by `Arrived` or by a status at rest on the target), resync of a
//! firmware that lost our target, and reconnect with exponential backoff.
//!
//! It is driven like `roller_firmware::Roller` and quinn-proto's
//! `Connection`: every input carries the time (`now`, microseconds on any
//! monotonic clock the caller chooses), and the outputs are pulled:
//!
//! * inputs: [`RollerLink::set_target`], [`RollerLink::handle_opened`] /
//!   [`RollerLink::handle_open_failed`] (the answer to [`Action::Open`]),
//!   [`RollerLink::handle_bytes`] (whatever the port read),
//!   [`RollerLink::handle_port_error`] (read/write error, end of file),
//!   [`RollerLink::handle_timeout`] (when [`RollerLink::poll_timeout`] is
//!   reached);
//! * outputs: [`RollerLink::poll`] yields [`Action`]s in order (open the
//!   port, write a frame, close the port, emit an event), and
//!   [`RollerLink::state`] is the snapshot the driver publishes.
//!
//! The tokio driver ([`crate::RollerDriver`]) is thin wiring around it; the
//! tests in `tests/link_sim.rs` run it against the firmware core in
//! simulated time.

use std::collections::VecDeque;
use std::time::Duration;

use telextiles_proto::roller::{
    self as wire, Command, ErrorCode, FrameBuf, FrameDecoder, Reply, Status, Version,
    PROTOCOL_VERSION,
};

use crate::{DriverConfig, RollerEvent, RollerState, Target};

/// The protocol settings of a link (the part of [`DriverConfig`] that is not
/// about the port).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LinkConfig {
    /// Slot count to configure after `Hello` (`None`: keep the firmware's).
    pub slots: Option<u16>,
    /// Max speed and acceleration to configure after `Hello`.
    pub motion: Option<(u32, u32)>,
    /// How long to wait for the answer to a command before sending it again.
    pub ack_timeout: Duration,
    /// Sends of one command before the link is declared dead.
    pub max_tries: u32,
    /// Status poll period (also the firmware's watchdog feed).
    pub keepalive: Duration,
    /// Reconnect backoff, doubling from `reconnect_min` to `reconnect_max`.
    pub reconnect_min: Duration,
    pub reconnect_max: Duration,
}

impl From<&DriverConfig> for LinkConfig {
    fn from(c: &DriverConfig) -> LinkConfig {
        LinkConfig {
            slots: c.slots,
            motion: c.motion,
            ack_timeout: c.ack_timeout,
            max_tries: c.max_tries,
            keepalive: c.keepalive,
            reconnect_min: c.reconnect_min,
            reconnect_max: c.reconnect_max,
        }
    }
}

impl Default for LinkConfig {
    fn default() -> LinkConfig {
        LinkConfig::from(&DriverConfig::auto())
    }
}

/// What the caller must do next, in order.
#[derive(Clone, Debug)]
pub enum Action {
    /// Open the port; answer with [`RollerLink::handle_opened`] or
    /// [`RollerLink::handle_open_failed`].
    Open,
    /// Write this frame. `target` is set on the first send of a new
    /// target's command (the driver reports it as
    /// [`RollerEvent::TargetWritten`] once the write completed).
    Transmit {
        frame: FrameBuf,
        target: Option<Target>,
    },
    /// Close the port: the link is down ([`RollerEvent::Disconnected`] came
    /// just before); an [`Action::Open`] follows after the backoff.
    Close,
    /// Report this event (never [`RollerEvent::TargetWritten`], which the
    /// driver makes from [`Action::Transmit`]).
    Event(RollerEvent),
}

/// Where the link is in its life cycle.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Port closed; it is opened again at `retry_at`.
    Closed { retry_at: u64 },
    /// [`Action::Open`] given, waiting for the caller's answer.
    Opening,
    /// Port open, saying hello and configuring the firmware.
    Handshake(Step),
    /// Connected: targets, keepalives, arrivals.
    Ready,
}

/// Handshake steps, in order (`Slots` and `Motion` only when configured).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    Hello,
    Slots,
    Motion,
    /// `QueryStatus`: the position resync before `Connected`.
    Resync,
}

#[derive(Clone, Copy, Debug)]
struct Outstanding {
    seq: u8,
    cmd: Command,
    target: Option<Target>,
    deadline: u64,
    tries: u32,
}

/// The host side of the roller link, without I/O. See the module docs.
pub struct RollerLink {
    cfg: LinkConfig,
    phase: Phase,
    actions: VecDeque<Action>,
    state: RollerState,
    /// The latest target asked for.
    target: Option<Target>,
    seq: u8,
    backoff: Duration,
    last_open_error: Option<String>,
    // Per connection (reset when the port is opened):
    port: String,
    decoder: FrameDecoder,
    version: Option<Version>,
    outstanding: Option<Outstanding>,
    /// The target the firmware acknowledged and the SEQ it acknowledged
    /// (or refused: then it is not re-sent until a new target comes).
    sent: Option<(Target, u8)>,
    /// A target the firmware refused (not re-sent by the resync).
    rejected: Option<Target>,
    next_keepalive: u64,
}

impl std::fmt::Debug for RollerLink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RollerLink")
            .field("phase", &self.phase)
            .field("port", &self.port)
            .field("target", &self.target)
            .field("sent", &self.sent)
            .field("outstanding", &self.outstanding)
            .field("state", &self.state)
            .finish_non_exhaustive()
    }
}

fn us(d: Duration) -> u64 {
    d.as_micros().min(u64::MAX as u128) as u64
}

impl RollerLink {
    /// A link whose first action is [`Action::Open`].
    pub fn new(cfg: LinkConfig) -> RollerLink {
        let backoff = cfg.reconnect_min;
        RollerLink {
            cfg,
            phase: Phase::Opening,
            actions: VecDeque::from([Action::Open]),
            state: RollerState::default(),
            target: None,
            seq: 0,
            backoff,
            last_open_error: None,
            port: String::new(),
            decoder: FrameDecoder::new(),
            version: None,
            outstanding: None,
            sent: None,
            rejected: None,
            next_keepalive: 0,
        }
    }

    pub fn config(&self) -> &LinkConfig {
        &self.cfg
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The snapshot the driver publishes (updated by every input).
    pub fn state(&self) -> &RollerState {
        &self.state
    }

    /// The next action, in order; `None` when there is nothing to do until
    /// the next input.
    pub fn poll(&mut self) -> Option<Action> {
        self.actions.pop_front()
    }

    /// When [`RollerLink::handle_timeout`] is due (`None`: only an input
    /// can move the link, e.g. while waiting for an open).
    pub fn poll_timeout(&self) -> Option<u64> {
        match self.phase {
            Phase::Closed { retry_at } => Some(retry_at),
            Phase::Opening => None,
            Phase::Handshake(_) => self.outstanding.map(|o| o.deadline),
            Phase::Ready => Some(
                self.outstanding
                    .map(|o| o.deadline)
                    .unwrap_or(self.next_keepalive),
            ),
        }
    }

    /// Asks for a new target; it replaces any target not yet sent and is
    /// sent as soon as no command is in flight (after reconnecting, if the
    /// link is down).
    pub fn set_target(&mut self, target: Target, now: u64) {
        self.target = Some(target);
        self.state.target = Some(target);
        if self.phase == Phase::Ready {
            self.pump(now);
        }
    }

    /// The port opened (answer to [`Action::Open`]); the hello starts.
    pub fn handle_opened(&mut self, port: impl Into<String>, now: u64) {
        if self.phase != Phase::Opening {
            return;
        }
        self.last_open_error = None;
        self.port = port.into();
        self.decoder = FrameDecoder::new();
        self.version = None;
        self.outstanding = None;
        self.sent = None;
        self.rejected = None;
        self.phase = Phase::Handshake(Step::Hello);
        self.request(
            Command::Hello {
                protocol: PROTOCOL_VERSION,
            },
            None,
            now,
        );
    }

    /// The port could not be opened (answer to [`Action::Open`]): reported
    /// once per distinct error, retried after the backoff.
    pub fn handle_open_failed(&mut self, error: impl Into<String>, now: u64) {
        if self.phase != Phase::Opening {
            return;
        }
        let error = error.into();
        if self.last_open_error.as_deref() != Some(error.as_str()) {
            let message = format!("{error}; retrying in {:?}", self.backoff);
            tracing::warn!("{message}");
            self.event(RollerEvent::Error { message });
            self.last_open_error = Some(error);
        }
        self.close_for_backoff(now);
    }

    /// The port failed (read or write error, end of file): the link is lost.
    pub fn handle_port_error(&mut self, reason: impl Into<String>, now: u64) {
        if self.port_open() {
            self.lose(reason.into(), now);
        }
    }

    /// Bytes read from the port.
    pub fn handle_bytes(&mut self, bytes: &[u8], now: u64) {
        if !self.port_open() {
            return;
        }
        let mut decoder = std::mem::take(&mut self.decoder);
        for item in decoder.feed(bytes) {
            let Ok(frame) = item else {
                tracing::debug!("roller: dropped a corrupted frame");
                continue;
            };
            let Ok(reply) = Reply::from_frame(&frame) else {
                continue;
            };
            match self.phase {
                Phase::Handshake(step) => self.on_handshake_reply(step, frame.seq, reply, now),
                Phase::Ready => self.on_reply(frame.seq, reply, now),
                // The link was lost by an earlier frame of this read.
                Phase::Closed { .. } | Phase::Opening => break,
            }
        }
        self.decoder = decoder;
        if self.phase == Phase::Ready {
            self.pump(now);
        }
    }

    /// Time passed: reopen after the backoff, re-send an unanswered command
    /// (or give up on the link), send a keepalive.
    pub fn handle_timeout(&mut self, now: u64) {
        match self.phase {
            Phase::Closed { retry_at } => {
                if now >= retry_at {
                    self.phase = Phase::Opening;
                    self.actions.push_back(Action::Open);
                }
            }
            Phase::Opening => {}
            Phase::Handshake(_) | Phase::Ready => {
                if let Some(o) = self.outstanding.as_mut() {
                    if now >= o.deadline {
                        if o.tries >= self.cfg.max_tries {
                            let reason = format!(
                                "no answer to {:?} after {} tries of {:?}",
                                o.cmd, o.tries, self.cfg.ack_timeout
                            );
                            return self.lose(reason, now);
                        }
                        o.tries += 1;
                        o.deadline = now + us(self.cfg.ack_timeout);
                        let (seq, cmd) = (o.seq, o.cmd);
                        tracing::debug!("roller: resending {cmd:?} (seq {seq})");
                        self.transmit(seq, &cmd, None);
                    }
                }
                if self.phase == Phase::Ready {
                    self.pump(now);
                }
            }
        }
    }

    fn port_open(&self) -> bool {
        matches!(self.phase, Phase::Handshake(_) | Phase::Ready)
    }

    fn event(&mut self, e: RollerEvent) {
        self.actions.push_back(Action::Event(e));
    }

    fn error(&mut self, message: String) {
        tracing::warn!("{message}");
        self.event(RollerEvent::Error { message });
    }

    fn next_seq(&mut self) -> u8 {
        self.seq = self.seq.wrapping_add(1);
        self.seq
    }

    fn transmit(&mut self, seq: u8, cmd: &Command, target: Option<Target>) {
        self.actions.push_back(Action::Transmit {
            frame: cmd.encode(seq),
            target,
        });
    }

    /// Sends a new command (new SEQ) and waits for its answer.
    fn request(&mut self, cmd: Command, target: Option<Target>, now: u64) {
        let seq = self.next_seq();
        self.transmit(seq, &cmd, target);
        self.outstanding = Some(Outstanding {
            seq,
            cmd,
            target,
            deadline: now + us(self.cfg.ack_timeout),
            tries: 1,
        });
    }

    fn close_for_backoff(&mut self, now: u64) {
        self.phase = Phase::Closed {
            retry_at: now + us(self.backoff),
        };
        self.backoff = (self.backoff * 2).min(self.cfg.reconnect_max);
    }

    /// The link is down: report why, close the port, reopen after the backoff.
    fn lose(&mut self, reason: String, now: u64) {
        // Frames queued for the dead port are not written.
        self.actions
            .retain(|a| !matches!(a, Action::Transmit { .. }));
        if self.state.connected {
            self.state.reconnects += 1;
        }
        self.state.connected = false;
        let reason = format!("roller link {} lost: {reason}", self.port);
        tracing::warn!("{reason}");
        self.event(RollerEvent::Disconnected { reason });
        self.actions.push_back(Action::Close);
        self.outstanding = None;
        self.close_for_backoff(now);
    }

    fn on_handshake_reply(&mut self, step: Step, seq: u8, reply: Reply, now: u64) {
        let Some(o) = self.outstanding else { return };
        if o.seq != seq {
            return;
        }
        match (step, reply) {
            (Step::Hello, Reply::Version(v)) => {
                self.outstanding = None;
                if v.protocol != PROTOCOL_VERSION {
                    let message = format!(
                        "roller on {} speaks protocol {} (firmware {}.{}.{}); this driver speaks {PROTOCOL_VERSION}: update the firmware",
                        self.port, v.protocol, v.firmware[0], v.firmware[1], v.firmware[2]
                    );
                    self.event(RollerEvent::Error {
                        message: message.clone(),
                    });
                    return self.lose(message, now);
                }
                self.version = Some(v);
                self.next_step(Step::Hello, now);
            }
            (Step::Slots | Step::Motion, Reply::Ack(_)) => {
                self.outstanding = None;
                self.next_step(step, now);
            }
            (Step::Slots | Step::Motion, Reply::Error { code, .. }) => {
                self.outstanding = None;
                let message = match o.cmd {
                    Command::SetSlots { slots } => format!("roller refused {slots} slots: {code}"),
                    Command::SetMotion { max_speed, accel } => format!(
                        "roller refused speed {max_speed}/s, acceleration {accel}/s^2: {code}"
                    ),
                    other => format!("roller refused {other:?}: {code}"),
                };
                self.error(message);
                self.next_step(step, now);
            }
            (Step::Resync, Reply::Status(s)) => {
                self.outstanding = None;
                self.connected(s, now);
            }
            (_, Reply::Error { code, .. }) => {
                self.outstanding = None;
                self.lose(format!("roller refused {:?}: {code}", o.cmd), now);
            }
            // Unsolicited frames (a periodic status, an arrival) that happen
            // to carry this SEQ are not the answer.
            _ => {}
        }
    }

    /// Sends the handshake's next request after `done`: `SetSlots` and
    /// `SetMotion` when configured, then the `QueryStatus` resync.
    fn next_step(&mut self, done: Step, now: u64) {
        let slots = match (done, self.cfg.slots) {
            (Step::Hello, Some(slots)) => Some((Step::Slots, Command::SetSlots { slots })),
            _ => None,
        };
        let motion = match (done, self.cfg.motion) {
            (Step::Hello | Step::Slots, Some((max_speed, accel))) => {
                Some((Step::Motion, Command::SetMotion { max_speed, accel }))
            }
            _ => None,
        };
        let (step, cmd) = slots
            .or(motion)
            .unwrap_or((Step::Resync, Command::QueryStatus));
        self.phase = Phase::Handshake(step);
        self.request(cmd, None, now);
    }

    fn connected(&mut self, status: Status, now: u64) {
        let Some(v) = self.version else { return };
        let version = Version {
            slots: self.cfg.slots.unwrap_or(v.slots),
            ..v
        };
        self.version = Some(version);
        self.backoff = self.cfg.reconnect_min;
        self.phase = Phase::Ready;
        self.state.connected = true;
        self.state.port = Some(self.port.clone());
        self.state.version = Some(version);
        tracing::info!(
            "roller on {}: firmware {:?}, {} slots, {} steps/rev",
            self.port,
            version.firmware,
            version.slots,
            version.steps_per_rev
        );
        self.event(RollerEvent::Connected {
            port: self.port.clone(),
            version,
        });
        self.position_event(&status);
        self.next_keepalive = now + us(self.cfg.keepalive);
        self.pump(now);
    }

    /// Sends what is due when no command is in flight: the latest target if
    /// the firmware does not have it, else a keepalive when it is time.
    fn pump(&mut self, now: u64) {
        if self.outstanding.is_some() || self.phase != Phase::Ready {
            return;
        }
        let cmd = match self.target {
            Some(t) if self.sent.map(|s| s.0) != Some(t) => {
                self.state.arrived = None;
                (t.command(), Some(t))
            }
            _ if now >= self.next_keepalive => (Command::QueryStatus, None),
            _ => return,
        };
        self.request(cmd.0, cmd.1, now);
        self.next_keepalive = now + us(self.cfg.keepalive);
    }

    fn position_event(&mut self, s: &Status) {
        let spr = self.version.map_or(3200, |v| v.steps_per_rev);
        let slots = s.slots.max(1);
        self.event(RollerEvent::Position {
            steps: s.position,
            mdeg: wire::steps_to_mdeg(s.position, spr),
            slot: wire::steps_to_slot(s.position, slots, spr),
            moving: s.moving(),
        });
        self.state.status = Some(*s);
    }

    /// Records arrival at `t` (once), if `t` is still the latest target.
    fn mark_arrived(&mut self, t: Target, s: Status) {
        if self.target != Some(t) || self.state.arrived == Some(t) {
            return;
        }
        self.event(RollerEvent::Arrived {
            target: t,
            status: s,
        });
        self.state.arrived = Some(t);
        self.state.status = Some(s);
    }

    fn on_reply(&mut self, seq: u8, reply: Reply, _now: u64) {
        let answers = self.outstanding.is_some_and(|o| o.seq == seq);
        match reply {
            Reply::Ack(s) | Reply::Status(s) => {
                // A periodic status carries the SEQ of the move; it answers
                // only a QueryStatus.
                let is_answer = answers
                    && !matches!(reply, Reply::Status(_)
                        if self.outstanding.is_some_and(|o| o.cmd != Command::QueryStatus));
                if is_answer {
                    let o = self
                        .outstanding
                        .take()
                        .expect("answers implies outstanding");
                    if let Some(t) = o.target {
                        self.sent = Some((t, seq));
                    }
                    // Resync: a firmware whose target is not ours (it was
                    // restarted, or its watchdog stopped it) gets ours again.
                    if o.cmd == Command::QueryStatus {
                        if let (Some((t, _)), Some(v)) = (self.sent, self.version) {
                            let arrived = self.state.arrived == Some(t);
                            let want = t.steps(s.slots, v.steps_per_rev);
                            let off_course = s.target != want
                                || (!s.moving() && s.position != want)
                                || (s.watchdog_tripped() && !arrived);
                            if off_course && self.rejected != Some(t) {
                                tracing::info!(
                                    "roller: target lost on the firmware, re-sending {t:?}"
                                );
                                self.sent = None;
                            }
                        }
                    }
                }
                self.position_event(&s);
                // The status is authoritative: at rest on our target is
                // arrived, even if the Arrived frame itself was lost.
                if let (Some((t, _)), Some(v)) = (self.sent, self.version) {
                    let want = t.steps(s.slots, v.steps_per_rev);
                    if !s.moving() && s.position == want && s.target == want {
                        self.mark_arrived(t, s);
                    }
                }
            }
            Reply::Arrived(s) => {
                self.position_event(&s);
                if let Some((t, acked_seq)) = self.sent {
                    if acked_seq == seq {
                        self.mark_arrived(t, s);
                    }
                }
            }
            Reply::Error { code, command } => {
                if answers {
                    let o = self
                        .outstanding
                        .take()
                        .expect("answers implies outstanding");
                    if let Some(t) = o.target {
                        // Do not re-send a target the firmware refuses.
                        self.sent = Some((t, seq));
                        self.rejected = Some(t);
                    }
                    self.error(format!(
                        "roller refused {:?} (kind {command:#04x}): {code}{}",
                        o.cmd,
                        if code == ErrorCode::BadArgument {
                            " (check the slot count and the target)"
                        } else {
                            ""
                        }
                    ));
                }
            }
            Reply::Version(_) => {}
        }
    }
}
