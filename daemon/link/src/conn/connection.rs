//! One connection's life cycle after its control stream is open, sans-IO:
//! the [`Handshake`] until both hellos are acknowledged, then the live
//! session: the [`ClockSync`] pings and pongs, and the peer's other control
//! messages handed to the daemon (its error texts made safe to show).
//! Latent datagrams do not pass through it; their one-way latency comes
//! from [`Connection::one_way_us`].
//!
//! Driven like the machines it is made of: inputs carry `now`,
//! [`Connection::poll`] yields [`Action`]s, [`Connection::poll_timeout`]
//! says when [`Connection::handle_timeout`] is due.

use std::collections::VecDeque;

use telextiles_certs::trust::sanitize_text;
use telextiles_certs::DeviceId;
use telextiles_proto::pairing::PairingMessage;
use telextiles_proto::peer::{self, Control, Hello};

use super::clock::{ClockConfig, ClockSync};
use super::handshake::{Handshake, HandshakeConfig, HsAction, HsError, Local, Role};

/// What the driver must do, in order.
#[derive(Clone, Debug, PartialEq)]
pub enum Action {
    /// Write this on the control stream. During the handshake every send
    /// matters; once up these are pings and pongs, which a full queue may
    /// drop.
    Send(Control),
    /// Finish our side of the control stream.
    FinishSend,
    /// Run the pairing exchange (this side shows the code), then
    /// [`Connection::handle_paired`].
    Pair(PairingMessage),
    /// Both hellos acknowledged: register the peer, streaming starts.
    Up(Hello),
    /// A control message for the daemon (press start/stop, errors, ...).
    Deliver(Control),
    /// The handshake failed; close the connection.
    Fail(HsError),
}

/// Where the connection is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    Handshake,
    Up,
    Failed,
}

/// One connection's protocol. See the module docs.
#[derive(Debug)]
pub struct Connection {
    hs: Handshake,
    clock_cfg: ClockConfig,
    clock: Option<ClockSync>,
    phase: Phase,
    actions: VecDeque<Action>,
}

impl Connection {
    pub fn new(
        hs: HandshakeConfig,
        clock: ClockConfig,
        role: Role,
        addr: String,
        peer: DeviceId,
        now: u64,
    ) -> Connection {
        let mut c = Connection {
            hs: Handshake::new(hs, role, addr, peer, now),
            clock_cfg: clock,
            clock: None,
            phase: Phase::Handshake,
            actions: VecDeque::new(),
        };
        c.pump(now);
        c
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    pub fn handshake(&self) -> &Handshake {
        &self.hs
    }

    /// The clock machine, once up.
    pub fn clock(&self) -> Option<&ClockSync> {
        self.clock.as_ref()
    }

    pub fn poll(&mut self) -> Option<Action> {
        self.actions.pop_front()
    }

    pub fn poll_timeout(&self) -> Option<u64> {
        match self.phase {
            Phase::Handshake => self.hs.poll_timeout(),
            Phase::Up => self.clock.as_ref().map(ClockSync::poll_timeout),
            Phase::Failed => None,
        }
    }

    /// One-way latency of a latent captured at `capture_us` (peer clock),
    /// received at `recv_us`; `None` before the first usable pong.
    pub fn one_way_us(&self, capture_us: u64, recv_us: u64) -> Option<i64> {
        self.clock.as_ref()?.one_way_us(capture_us, recv_us)
    }

    fn pump(&mut self, now: u64) {
        while let Some(a) = self.hs.poll() {
            let a = match a {
                HsAction::Send(m) => Action::Send(m),
                HsAction::FinishSend => Action::FinishSend,
                HsAction::Pair(m) => Action::Pair(m),
                HsAction::Up(h) => {
                    self.phase = Phase::Up;
                    self.clock = Some(ClockSync::new(self.clock_cfg.clone(), now));
                    Action::Up(h)
                }
                HsAction::Fail(e) => {
                    self.phase = Phase::Failed;
                    Action::Fail(e)
                }
            };
            self.actions.push_back(a);
        }
        if let Some(c) = self.clock.as_mut() {
            while let Some(m) = c.poll() {
                self.actions.push_back(Action::Send(m));
            }
        }
    }

    /// See [`Handshake::handle_paired`].
    pub fn handle_paired(&mut self, now: u64) {
        self.hs.handle_paired(now);
        self.pump(now);
    }

    /// See [`Handshake::handle_read_error`] (false once up: the driver
    /// reports the end of the stream).
    pub fn handle_read_error(&mut self) -> bool {
        if self.phase != Phase::Handshake {
            return false;
        }
        let r = self.hs.handle_read_error();
        self.pump(0);
        r
    }

    pub fn handle_timeout(&mut self, now: u64) {
        match self.phase {
            Phase::Handshake => self.hs.handle_timeout(now),
            Phase::Up => {
                if let Some(c) = self.clock.as_mut() {
                    c.handle_timeout(now);
                }
            }
            Phase::Failed => {}
        }
        self.pump(now);
    }

    /// A message from the peer at `now`. `local` matters only during the
    /// handshake.
    pub fn handle_message(&mut self, now: u64, msg: Control, local: Local) {
        match self.phase {
            Phase::Handshake => self.hs.handle_message(now, msg, local),
            Phase::Up => {
                let clock = self.clock.as_mut().expect("up has a clock");
                match msg {
                    Control::Ping { id, t1_us } => {
                        // Bounded: a flood of pings fills the queue and
                        // further pongs are dropped.
                        clock.handle_ping(now, id, t1_us);
                    }
                    Control::Pong {
                        id,
                        t1_us,
                        t2_us,
                        t3_us,
                    } => {
                        // Only answers to our own outstanding pings count.
                        let _ = clock.handle_pong(now, id, t1_us, t2_us, t3_us);
                    }
                    // Repeats of the handshake are harmless.
                    Control::Hello(_) | Control::HelloAck => {}
                    Control::Error { code, message } => {
                        let message = sanitize_text(&message, peer::MAX_TEXT_LEN);
                        self.actions
                            .push_back(Action::Deliver(Control::Error { code, message }));
                    }
                    other => self.actions.push_back(Action::Deliver(other)),
                }
            }
            Phase::Failed => {}
        }
        self.pump(now);
    }
}
