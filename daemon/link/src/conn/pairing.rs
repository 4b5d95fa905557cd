//! Pairing over the control stream, sans-IO: the message exchange around
//! `telextiles_certs::PairingSession` (SPAKE2, itself sans-IO) with the
//! link's rules: only pairing messages are allowed, a failure the session
//! can explain is sent to the peer as `Abort` and the failure is reported
//! after a short linger (so the abort arrives before the close), and the
//! whole exchange has the handshake timeout.
//!
//! The two roles fail differently. The side showing the code gave its
//! single-use code to this exchange: any failure ends its pairing
//! (`ErrorKind::Pairing`, `session_failed` for the exchange's own
//! failures). The side entering the code dials devices that merely claim
//! to show a code (anyone can advertise `pair=1`); the device has proved
//! nothing until its confirmation checks out, so whatever it does instead
//! (an `Abort`, silence, a wrong confirmation, a foreign message) is
//! `ErrorKind::PairingAttempt` without `session_failed`: that device is
//! done with, pairing goes on. A genuine showing side's `Confirm` always
//! arrives before any `Abort` of its own (each side confirms as soon as it
//! has the other's `Start`), so the entering side judges the code itself
//! and never needs to believe an abort.
//!
//! What the code is (the one shown, taken once, or the one typed) and what
//! a success does (pin, trust store, pairing mode left, `Paired` event) are
//! the driver's: they touch shared state and files.

use std::collections::VecDeque;
use std::time::Duration;

use telextiles_certs::pairing::{PairingAbort, PairingError};
use telextiles_certs::{Paired, PairingCode, PairingRole, PairingSession, PairingStep, PeerKey};
use telextiles_proto::pairing::PairingMessage;
use telextiles_proto::peer::Control;

use super::clock::us;
use super::handshake::{describe, HsError};
use crate::ErrorKind;

/// The end of the entering side's [`ErrorKind::PairingAttempt`] messages.
pub(crate) const STILL_LOOKING: &str =
    "still looking for the device showing the code (this one is not tried again)";

/// How long a failure waits after its `Abort` was queued.
pub const ABORT_LINGER: Duration = Duration::from_millis(100);

/// What the driver must do, in order.
#[derive(Debug)]
pub enum PairAction {
    /// Write this on the control stream.
    Send(Control),
    /// Both sides proved the code: pin the peer.
    Paired(Paired),
    /// Pairing failed. `session_failed`: the exchange itself failed (wrong
    /// code, the peer aborted, ...), so this side leaves pairing mode
    /// (only ever on the side showing the code; the entering side's
    /// failures are `ErrorKind::PairingAttempt` and never set it).
    Fail {
        error: HsError,
        session_failed: bool,
    },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    Exchanging,
    Lingering,
    Done,
}

/// One pairing exchange. See the module docs.
pub struct PairingExchange {
    session: Option<PairingSession>,
    role: PairingRole,
    addr: String,
    timeout: Duration,
    state: State,
    deadline: Option<u64>,
    pending: Option<(HsError, bool)>,
    actions: VecDeque<PairAction>,
}

impl std::fmt::Debug for PairingExchange {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PairingExchange")
            .field("role", &self.role)
            .field("addr", &self.addr)
            .field("state", &self.state)
            .field("deadline", &self.deadline)
            .finish_non_exhaustive()
    }
}

impl PairingExchange {
    /// Starts pairing with the device at `addr` with `code`, or refuses at
    /// once when there is no code: `Err((abort, text))` (the abort, if any,
    /// is sent to the peer first). The exchange as a whole must end by
    /// `now + timeout`.
    #[allow(clippy::too_many_arguments)]
    pub fn start<R: rand::RngCore + rand::CryptoRng>(
        role: PairingRole,
        code: Result<PairingCode, (Option<PairingAbort>, String)>,
        own_key: &PeerKey,
        peer_key: &PeerKey,
        rng: &mut R,
        addr: String,
        now: u64,
        timeout: Duration,
    ) -> PairingExchange {
        let mut x = PairingExchange {
            session: None,
            role,
            addr,
            timeout,
            state: State::Exchanging,
            deadline: Some(now.saturating_add(us(timeout))),
            pending: None,
            actions: VecDeque::new(),
        };
        match code {
            Err((abort, text)) => {
                let err = HsError {
                    kind: x.kind(),
                    message: text,
                };
                match abort {
                    Some(a) => {
                        x.actions
                            .push_back(PairAction::Send(Control::Pair(PairingMessage::Abort(a))));
                        x.linger(now, err, false);
                    }
                    None => x.fail(err, false),
                }
            }
            Ok(code) => match PairingSession::start(role, code, own_key, peer_key, rng) {
                Ok((session, start)) => {
                    x.session = Some(session);
                    x.actions.push_back(PairAction::Send(Control::Pair(start)));
                }
                Err(e) => x.fail(
                    HsError {
                        kind: x.kind(),
                        message: e.to_string(),
                    },
                    false,
                ),
            },
        }
        x
    }

    pub fn poll(&mut self) -> Option<PairAction> {
        self.actions.pop_front()
    }

    pub fn poll_timeout(&self) -> Option<u64> {
        self.deadline
    }

    /// Whether it ended (paired or failed).
    pub fn is_done(&self) -> bool {
        self.state == State::Done
    }

    fn entering(&self) -> bool {
        self.role == PairingRole::EntersCode
    }

    /// The kind of this side's pairing failures (see the module docs).
    fn kind(&self) -> ErrorKind {
        if self.entering() {
            ErrorKind::PairingAttempt
        } else {
            ErrorKind::Pairing
        }
    }

    /// What the entering side tells its user when a device it dialled
    /// failed to prove the code.
    fn attempt_message(&self, what: &str) -> String {
        format!("the device at {} {what}; {STILL_LOOKING}", self.addr)
    }

    fn fail(&mut self, error: HsError, session_failed: bool) {
        self.state = State::Done;
        self.deadline = None;
        self.session = None;
        self.actions.push_back(PairAction::Fail {
            error,
            session_failed,
        });
    }

    fn linger(&mut self, now: u64, error: HsError, session_failed: bool) {
        self.state = State::Lingering;
        self.session = None;
        self.deadline = Some(now.saturating_add(us(ABORT_LINGER)));
        self.pending = Some((error, session_failed));
    }

    fn end_linger(&mut self) {
        if let Some((e, s)) = self.pending.take() {
            self.fail(e, s);
        }
    }

    pub fn handle_timeout(&mut self, now: u64) {
        match self.deadline {
            Some(d) if now >= d => {}
            _ => return,
        }
        match self.state {
            State::Exchanging => {
                let message = if self.entering() {
                    self.attempt_message(&format!(
                        "did not prove the code within {} s (it stopped answering)",
                        self.timeout.as_secs()
                    ))
                } else {
                    "pairing timed out".into()
                };
                self.fail(
                    HsError {
                        kind: self.kind(),
                        message,
                    },
                    false,
                )
            }
            State::Lingering => self.end_linger(),
            State::Done => {}
        }
    }

    /// The stream ended. True if a failure is now ready to poll (it was
    /// lingering); false: the driver reports the read error.
    pub fn handle_read_error(&mut self) -> bool {
        if self.state == State::Lingering {
            self.end_linger();
            return true;
        }
        false
    }

    /// A message from the peer.
    pub fn handle_message(&mut self, now: u64, msg: Control) {
        if self.state != State::Exchanging {
            return;
        }
        let m = match msg {
            Control::Pair(m) => m,
            other => {
                let addr = self.addr.clone();
                let error = if self.entering() {
                    HsError {
                        kind: ErrorKind::PairingAttempt,
                        message: self.attempt_message(&format!(
                            "sent {} instead of a pairing message, without proving the code",
                            describe(&other)
                        )),
                    }
                } else {
                    HsError {
                        kind: ErrorKind::Protocol,
                        message: format!(
                            "expected a pairing message from {addr}, got {}",
                            describe(&other)
                        ),
                    }
                };
                self.fail(error, false);
                return;
            }
        };
        let Some(session) = self.session.as_mut() else {
            return;
        };
        match session.handle(&m) {
            Ok(PairingStep::Send(reply)) => {
                self.actions
                    .push_back(PairAction::Send(Control::Pair(reply)));
            }
            Ok(PairingStep::Paired(p)) => {
                self.state = State::Done;
                self.deadline = None;
                self.session = None;
                self.actions.push_back(PairAction::Paired(p));
            }
            Err(e) => {
                // The showing side's code is used up: it leaves pairing.
                // The entering side is done with this device only.
                let session_failed = !self.entering();
                let err = if self.entering() {
                    let what = match &e {
                        PairingError::WrongCode => {
                            "did not prove the code you typed: the codes did not match (a typo, or it is not the device showing the code; if it is, its code is used up: start again on both devices)".to_string()
                        }
                        PairingError::PeerAborted(a) => format!(
                            "stopped pairing without proving the code (it says: {})",
                            a.describe()
                        ),
                        other => format!("failed the pairing exchange without proving the code ({other})"),
                    };
                    HsError {
                        kind: ErrorKind::PairingAttempt,
                        message: self.attempt_message(&what),
                    }
                } else {
                    HsError {
                        kind: ErrorKind::Pairing,
                        message: format!("pairing with the device at {} failed: {e}", self.addr),
                    }
                };
                match e.abort_message() {
                    Some(abort) => {
                        self.actions
                            .push_back(PairAction::Send(Control::Pair(abort)));
                        self.linger(now, err, session_failed);
                    }
                    None => self.fail(err, session_failed),
                }
            }
        }
    }
}
