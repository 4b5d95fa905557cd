//! The hello/ack handshake of one connection, sans-IO.
//!
//! After the control stream is open (and, on the dialing side, after any
//! pairing), both sides send [`Hello`], compare the peer's with their own
//! ([`check_hello`]: protocol version, encoder hash, index fingerprint,
//! embedding dimension) and answer `HelloAck` or `Mismatch`. Streaming
//! starts when each has the other's `HelloAck`.
//!
//! The accepting side learns from the dialer's first message whether it
//! wants to pair (`Pair(Start)`): the machine hands that to the driver
//! ([`HsAction::Pair`]), which runs the pairing exchange
//! (`telextiles_certs::PairingSession`, itself sans-IO) and then calls
//! [`Handshake::handle_paired`].
//!
//! Before `HelloAck` only the expected message is allowed: the peer's
//! `Hello` (once), then its `HelloAck` or `Mismatch`; a pairing `Abort` as
//! the first message. Anything else (a second `Hello`, a ping, a press) is
//! a protocol error. Each wait has the handshake timeout.

use std::collections::VecDeque;
use std::time::Duration;

use telextiles_certs::pairing::PairingAbort;
use telextiles_certs::trust::{sanitize_name, sanitize_text};
use telextiles_certs::DeviceId;
use telextiles_proto::pairing::PairingMessage;
use telextiles_proto::peer::{check_hello, Control, Hello};

use super::clock::us;
use crate::ErrorKind;

/// Which end of the connection this side is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Role {
    /// Opened the connection and the control stream; says hello first.
    Dialer,
    /// Waits for the dialer's first message (hello or pairing).
    Acceptor,
}

/// Settings of a [`Handshake`].
#[derive(Clone, Debug)]
pub struct HandshakeConfig {
    /// Our hello.
    pub ours: Hello,
    /// Each wait for the peer's next message.
    pub timeout: Duration,
    /// After sending `Mismatch`: how long to wait for the peer (its own
    /// `Mismatch`, or the close) before failing, so ours arrives.
    pub mismatch_linger: Duration,
    /// After refusing a pairing attempt: how long before failing, so the
    /// `Abort` arrives.
    pub abort_linger: Duration,
}

impl HandshakeConfig {
    pub fn new(ours: Hello, timeout: Duration) -> HandshakeConfig {
        HandshakeConfig {
            ours,
            timeout,
            mismatch_linger: Duration::from_millis(300),
            abort_linger: Duration::from_millis(100),
        }
    }
}

/// What the link knows about the peer when one of its messages arrives.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Local {
    /// The peer's key is pinned here (paired).
    pub peer_pinned: bool,
    /// This side shows a pairing code (`pair --show`).
    pub showing_code: bool,
}

/// Why the handshake failed, for the user.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct HsError {
    pub kind: ErrorKind,
    pub message: String,
}

/// What the driver must do, in order.
#[derive(Clone, Debug, PartialEq)]
pub enum HsAction {
    /// Write this on the control stream.
    Send(Control),
    /// Finish our side of the control stream (nothing more will be sent).
    FinishSend,
    /// The dialer asks to pair and this side shows a code: run the pairing
    /// exchange (this side shows the code) starting with this message, then
    /// call [`Handshake::handle_paired`] (or drop the machine if it failed).
    Pair(PairingMessage),
    /// Compatible: streaming may start. The peer's hello, its name made
    /// safe to show.
    Up(Hello),
    /// The handshake failed; close the connection.
    Fail(HsError),
}

/// Where the handshake is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HsState {
    /// Acceptor: waiting for the dialer's first message.
    AwaitFirst,
    /// Acceptor: the driver is pairing.
    Pairing,
    /// Our hello is sent; waiting for the peer's. `after_pairing`: the
    /// peer just paired.
    AwaitHello {
        after_pairing: bool,
    },
    /// Their hello is compatible, our ack sent; waiting for theirs.
    AwaitAck,
    /// A failure is decided; waiting (bounded) so our last message arrives.
    Lingering {
        end_on_message: bool,
    },
    Up,
    Failed,
}

/// The hello/ack handshake of one connection. See the module docs.
#[derive(Debug)]
pub struct Handshake {
    cfg: HandshakeConfig,
    role: Role,
    addr: String,
    peer: DeviceId,
    state: HsState,
    deadline: Option<u64>,
    their: Option<Hello>,
    pending_fail: Option<HsError>,
    actions: VecDeque<HsAction>,
}

impl Handshake {
    /// The handshake with the device `peer` at `addr` (for messages),
    /// starting at `now`. A dialer sends its hello at once.
    pub fn new(
        cfg: HandshakeConfig,
        role: Role,
        addr: String,
        peer: DeviceId,
        now: u64,
    ) -> Handshake {
        let mut hs = Handshake {
            cfg,
            role,
            addr,
            peer,
            state: HsState::AwaitFirst,
            deadline: None,
            their: None,
            pending_fail: None,
            actions: VecDeque::new(),
        };
        match role {
            Role::Dialer => hs.send_hello(now, false),
            Role::Acceptor => hs.wait(now),
        }
        hs
    }

    pub fn state(&self) -> HsState {
        self.state
    }

    pub fn role(&self) -> Role {
        self.role
    }

    /// The peer's hello (sanitised name) once received and compatible.
    pub fn their_hello(&self) -> Option<&Hello> {
        self.their.as_ref()
    }

    pub fn poll(&mut self) -> Option<HsAction> {
        self.actions.pop_front()
    }

    /// When [`Handshake::handle_timeout`] is due; `None` while pairing,
    /// up or failed.
    pub fn poll_timeout(&self) -> Option<u64> {
        self.deadline
    }

    fn wait(&mut self, now: u64) {
        self.deadline = Some(now.saturating_add(us(self.cfg.timeout)));
    }

    fn send_hello(&mut self, now: u64, after_pairing: bool) {
        self.actions
            .push_back(HsAction::Send(Control::Hello(self.cfg.ours.clone())));
        self.state = HsState::AwaitHello { after_pairing };
        self.wait(now);
    }

    fn fail(&mut self, kind: ErrorKind, message: String) {
        self.state = HsState::Failed;
        self.deadline = None;
        self.actions
            .push_back(HsAction::Fail(HsError { kind, message }));
    }

    fn linger(&mut self, now: u64, for_: Duration, end_on_message: bool, err: HsError) {
        self.state = HsState::Lingering { end_on_message };
        self.deadline = Some(now.saturating_add(us(for_)));
        self.pending_fail = Some(err);
    }

    fn end_linger(&mut self) {
        if let Some(e) = self.pending_fail.take() {
            self.fail(e.kind, e.message);
        }
    }

    fn protocol(&mut self, what: &str, got: &Control) {
        let addr = self.addr.clone();
        self.fail(
            ErrorKind::Protocol,
            format!("expected {what} from {addr}, got {}", describe(got)),
        );
    }

    /// The pairing the machine asked for ([`HsAction::Pair`]) succeeded:
    /// the peer is pinned now; our hello goes out.
    pub fn handle_paired(&mut self, now: u64) {
        if self.state == HsState::Pairing {
            self.send_hello(now, true);
        }
    }

    /// The control stream ended or failed while reading. Returns true if
    /// the machine now has a [`HsAction::Fail`] to poll (it was lingering
    /// after a decided failure); false: the driver reports the read error.
    pub fn handle_read_error(&mut self) -> bool {
        if matches!(self.state, HsState::Lingering { .. }) {
            self.end_linger();
            return true;
        }
        false
    }

    /// The wait timed out (`now` ≥ [`Handshake::poll_timeout`]).
    pub fn handle_timeout(&mut self, now: u64) {
        match self.deadline {
            Some(d) if now >= d => {}
            _ => return,
        }
        let addr = self.addr.clone();
        let hs = self.cfg.timeout;
        match self.state {
            HsState::AwaitFirst
            | HsState::AwaitHello {
                after_pairing: false,
            } => self.fail(
                ErrorKind::Connection,
                format!("no hello from {addr} within {hs:?}"),
            ),
            HsState::AwaitHello {
                after_pairing: true,
            } => self.fail(ErrorKind::Connection, "no hello after pairing".into()),
            HsState::AwaitAck => self.fail(ErrorKind::Connection, "no hello ack".into()),
            HsState::Lingering { .. } => self.end_linger(),
            HsState::Pairing | HsState::Up | HsState::Failed => {}
        }
    }

    /// A message from the peer, received at `now`.
    pub fn handle_message(&mut self, now: u64, msg: Control, local: Local) {
        let addr = self.addr.clone();
        let short = self.peer.short();
        match self.state {
            HsState::AwaitFirst => match msg {
                Control::Pair(PairingMessage::Start(start)) => {
                    if local.showing_code {
                        self.state = HsState::Pairing;
                        self.deadline = None;
                        self.actions
                            .push_back(HsAction::Pair(PairingMessage::Start(start)));
                    } else {
                        self.actions.push_back(HsAction::Send(Control::Pair(
                            PairingMessage::Abort(PairingAbort::NotPairing),
                        )));
                        self.actions.push_back(HsAction::FinishSend);
                        let err = HsError {
                            kind: ErrorKind::RefusedPeer,
                            message: format!("device {short} at {addr} tried to pair, but this device is not showing a pairing code"),
                        };
                        self.linger(now, self.cfg.abort_linger, false, err);
                    }
                }
                Control::Hello(h) => {
                    if !local.peer_pinned {
                        self.fail(
                            ErrorKind::RefusedPeer,
                            format!(
                                "refused device {short} at {addr}: it is not paired with this device"
                            ),
                        );
                        return;
                    }
                    self.actions
                        .push_back(HsAction::Send(Control::Hello(self.cfg.ours.clone())));
                    self.check(now, h);
                }
                Control::Pair(PairingMessage::Abort(a)) => {
                    // Honoured only from a device authenticated by its pin;
                    // from anyone else it proved no code and must not end
                    // `pair --show`.
                    if !local.peer_pinned {
                        self.fail(
                            ErrorKind::RefusedPeer,
                            format!(
                                "ignored a pairing abort ({}) from device {short} at {addr}: it is not paired and proved no pairing code",
                                a.describe()
                            ),
                        );
                    } else {
                        self.fail(
                            ErrorKind::Pairing,
                            format!("the device at {addr}: {}", a.describe()),
                        );
                    }
                }
                other => self.protocol("hello", &other),
            },
            HsState::AwaitHello { after_pairing } => match msg {
                Control::Hello(h) => self.check(now, h),
                Control::Pair(PairingMessage::Abort(a)) if !after_pairing => self.fail(
                    ErrorKind::Pairing,
                    format!("the device at {addr}: {}", a.describe()),
                ),
                other => self.protocol("hello", &other),
            },
            HsState::AwaitAck => match msg {
                Control::HelloAck => {
                    self.state = HsState::Up;
                    self.deadline = None;
                    let h = self.their.clone().expect("hello before ack");
                    self.actions.push_back(HsAction::Up(h));
                }
                Control::Mismatch { reasons } => {
                    // The peer's strings (hashes) are shown: no escapes.
                    let text: Vec<String> = reasons
                        .iter()
                        .map(|r| sanitize_text(&r.to_string(), 400))
                        .collect();
                    let name = self
                        .their
                        .as_ref()
                        .map(|h| h.device_name.clone())
                        .unwrap_or_default();
                    self.fail(
                        ErrorKind::Incompatible(reasons),
                        format!("\"{name}\" refused to stream: {}", text.join("; ")),
                    );
                }
                other => self.protocol("hello ack", &other),
            },
            HsState::Lingering { end_on_message } => {
                if end_on_message {
                    self.end_linger();
                }
            }
            // Not reading: the driver owns the stream while pairing.
            HsState::Pairing | HsState::Up | HsState::Failed => {}
        }
    }

    fn check(&mut self, now: u64, mut h: Hello) {
        // The name is shown to the user and logged: no terminal escapes.
        h.device_name = sanitize_name(&h.device_name);
        match check_hello(&self.cfg.ours, &h) {
            Ok(()) => {
                self.actions.push_back(HsAction::Send(Control::HelloAck));
                self.their = Some(h);
                self.state = HsState::AwaitAck;
                self.wait(now);
            }
            Err(reasons) => {
                self.actions.push_back(HsAction::Send(Control::Mismatch {
                    reasons: reasons.clone(),
                }));
                let text: Vec<String> = reasons.iter().map(|r| r.to_string()).collect();
                let message = format!(
                    "cannot stream with \"{}\" ({}): {}",
                    h.device_name,
                    self.peer.short(),
                    text.join("; ")
                );
                let err = HsError {
                    kind: ErrorKind::Incompatible(reasons),
                    message,
                };
                self.linger(now, self.cfg.mismatch_linger, true, err);
            }
        }
    }
}

/// A message named for an error text, without the peer's strings (which
/// could carry terminal escapes) or large payloads.
pub(crate) fn describe(m: &Control) -> &'static str {
    match m {
        Control::Hello(_) => "Hello",
        Control::HelloAck => "HelloAck",
        Control::Mismatch { .. } => "Mismatch",
        Control::PressStart { .. } => "PressStart",
        Control::PressStop { .. } => "PressStop",
        Control::Ping { .. } => "Ping",
        Control::Pong { .. } => "Pong",
        Control::Error { .. } => "Error",
        Control::Pair(PairingMessage::Start(_)) => "Pair(Start)",
        Control::Pair(PairingMessage::Confirm(_)) => "Pair(Confirm)",
        Control::Pair(PairingMessage::Abort(_)) => "Pair(Abort)",
    }
}
