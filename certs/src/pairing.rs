//! Pairing, sans-IO: one-time codes and the SPAKE2 state machine that
//! authenticates the exchange of both devices' public keys.
//!
//! * The device that shows the code makes a [`CodeOffer`] (8 digits, the last
//!   one a Damm check digit, valid for [`DEFAULT_CODE_TTL`]); the caller
//!   passes `now` in. [`CodeOffer::take`] hands the code out once: one
//!   attempt per code.
//! * The other user types it; [`PairingCode::from_str`] catches typos (check
//!   digit) before any network traffic.
//! * Both sides, once connected (each side has the other's public key from
//!   the link's TLS handshake), run a [`PairingSession`]:
//!   SPAKE2 (Ed25519 group) with both device IDs as the SPAKE2 identities,
//!   then key confirmation: each side sends HMAC-SHA256 over a transcript
//!   hash of both keys' SubjectPublicKeyInfo and both SPAKE2 messages, with a key derived
//!   from the PAKE key and its role. A wrong code, or a machine in the middle
//!   (which would show each side a different key), makes both
//!   confirmations fail: [`PairingError::WrongCode`] on both sides.
//! * On success both get a [`Paired`]: the peer's key and ID to pin,
//!   and a 6-digit [`VerificationCode`] derived from the PAKE key and the
//!   transcript that users may compare.
use core::fmt;
use core::str::FromStr;
use std::time::{Duration, Instant};

use hmac::{Hmac, Mac};
use rand::{CryptoRng, RngCore};
use sha2::{Digest, Sha256};
use spake2::{Ed25519Group, Identity as SpakeIdentity, Password, Spake2};

pub use telextiles_proto::pairing::{
    PairingAbort, PairingConfirm, PairingMessage, PairingRole, PairingStart, MAX_PAKE_MESSAGE_LEN,
    PAIRING_VERSION,
};

use crate::device_id::DeviceId;
use crate::key::PeerKey;

type HmacSha256 = Hmac<Sha256>;

/// Digits in a pairing code (the last one is a check digit).
pub const CODE_DIGITS: usize = 8;
/// How long a shown code stays valid by default.
pub const DEFAULT_CODE_TTL: Duration = Duration::from_secs(5 * 60);

const LABEL: &[u8] = b"telextiles pairing v1";

// Damm algorithm: a weakly totally antisymmetric quasigroup of order 10.
// Catches every single-digit error and every swap of neighbouring digits.
const DAMM: [[u8; 10]; 10] = [
    [0, 3, 1, 7, 5, 9, 8, 6, 4, 2],
    [7, 0, 9, 2, 1, 5, 4, 8, 6, 3],
    [4, 2, 0, 6, 8, 7, 1, 3, 5, 9],
    [1, 7, 5, 0, 9, 8, 3, 4, 2, 6],
    [6, 1, 2, 3, 0, 4, 5, 9, 7, 8],
    [3, 6, 7, 4, 2, 0, 9, 5, 8, 1],
    [5, 8, 6, 9, 7, 2, 0, 1, 3, 4],
    [8, 9, 4, 5, 3, 6, 2, 0, 1, 7],
    [9, 4, 3, 8, 6, 1, 7, 2, 0, 5],
    [2, 5, 8, 1, 4, 3, 6, 7, 9, 0],
];

/// Damm interim digit of a digit sequence (0 means "valid" when the check
/// digit is included).
pub fn damm(digits: &[u8]) -> u8 {
    digits
        .iter()
        .fold(0u8, |i, &d| DAMM[usize::from(i)][usize::from(d % 10)])
}

/// A one-time pairing code: 8 decimal digits, shown as `1234-5678`.
#[derive(Clone, PartialEq, Eq)]
pub struct PairingCode([u8; CODE_DIGITS]);

impl fmt::Debug for PairingCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("PairingCode(..)")
    }
}

impl fmt::Display for PairingCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, d) in self.0.iter().enumerate() {
            if i == CODE_DIGITS / 2 {
                f.write_str("-")?;
            }
            write!(f, "{d}")?;
        }
        Ok(())
    }
}

impl PairingCode {
    /// A random code (7 random digits and a check digit).
    pub fn generate<R: RngCore + CryptoRng>(rng: &mut R) -> PairingCode {
        let mut d = [0u8; CODE_DIGITS];
        for x in d.iter_mut().take(CODE_DIGITS - 1) {
            // Rejection sampling for an unbiased digit.
            *x = loop {
                let b = (rng.next_u32() & 0xff) as u8;
                if b < 250 {
                    break b % 10;
                }
            };
        }
        d[CODE_DIGITS - 1] = damm(&d[..CODE_DIGITS - 1]);
        PairingCode(d)
    }

    fn password_bytes(&self) -> [u8; CODE_DIGITS] {
        self.0.map(|d| b'0' + d)
    }
}

/// Why a typed code or a code offer cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CodeError {
    /// Not 8 digits.
    #[error("a pairing code has {CODE_DIGITS} digits (like 1234-5678); {0:?} has {1}")]
    Length(String, usize),
    /// Something other than digits, spaces and dashes.
    #[error("a pairing code has only digits (like 1234-5678); {0:?} contains {1:?}")]
    BadChar(String, char),
    /// The check digit does not match: a typo.
    #[error("pairing code {0} has a typo (its last digit is a check digit and does not match); look at the code again")]
    Typo(String),
    /// The offer's time ran out.
    #[error("the pairing code has expired; start pairing again for a new code")]
    Expired,
    /// The offer's code was already handed out.
    #[error(
        "the pairing code was already used (one try per code); start pairing again for a new code"
    )]
    Used,
}

impl CodeError {
    /// What to tell the peer, for errors of a code offer.
    pub fn abort_reason(&self) -> Option<PairingAbort> {
        match self {
            CodeError::Expired => Some(PairingAbort::CodeExpired),
            CodeError::Used => Some(PairingAbort::CodeUsed),
            _ => None,
        }
    }
}

impl FromStr for PairingCode {
    type Err = CodeError;

    fn from_str(s: &str) -> Result<PairingCode, CodeError> {
        let mut digits = Vec::with_capacity(CODE_DIGITS);
        for c in s.chars() {
            match c {
                '0'..='9' => digits.push(c as u8 - b'0'),
                '-' | '_' | '.' => {}
                c if c.is_whitespace() => {}
                other => return Err(CodeError::BadChar(s.to_string(), other)),
            }
        }
        let arr: [u8; CODE_DIGITS] = digits
            .try_into()
            .map_err(|d: Vec<u8>| CodeError::Length(s.to_string(), d.len()))?;
        if damm(&arr) != 0 {
            return Err(CodeError::Typo(PairingCode(arr).to_string()));
        }
        Ok(PairingCode(arr))
    }
}

/// A code shown on this device, valid until `expires_at` and for one
/// attempt. No clock inside: callers pass `now`.
#[derive(Debug)]
pub struct CodeOffer {
    code: PairingCode,
    expires_at: Instant,
    used: bool,
}

impl CodeOffer {
    /// A fresh random code valid for `ttl` from `now`.
    pub fn new<R: RngCore + CryptoRng>(rng: &mut R, now: Instant, ttl: Duration) -> CodeOffer {
        CodeOffer {
            code: PairingCode::generate(rng),
            expires_at: now + ttl,
            used: false,
        }
    }

    /// The code to show the user (`1234-5678`).
    pub fn display(&self) -> String {
        self.code.to_string()
    }

    /// When the code stops being accepted.
    pub fn expires_at(&self) -> Instant {
        self.expires_at
    }

    /// Time left at `now` (zero once expired).
    pub fn remaining(&self, now: Instant) -> Duration {
        self.expires_at.saturating_duration_since(now)
    }

    /// Whether [`take`](Self::take) would succeed at `now`.
    pub fn is_usable(&self, now: Instant) -> bool {
        !self.used && now < self.expires_at
    }

    /// Hands out the code for one pairing attempt and burns it, whatever the
    /// outcome of that attempt. Errors if expired at `now` or already taken.
    pub fn take(&mut self, now: Instant) -> Result<PairingCode, CodeError> {
        if self.used {
            return Err(CodeError::Used);
        }
        if now >= self.expires_at {
            return Err(CodeError::Expired);
        }
        self.used = true;
        Ok(self.code.clone())
    }
}

/// The short string both users may compare after pairing: 6 digits shown as
/// `123 456`.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct VerificationCode(u32);

impl VerificationCode {
    /// The number (0..1_000_000).
    pub fn value(self) -> u32 {
        self.0
    }
}

impl fmt::Display for VerificationCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:03} {:03}", self.0 / 1000, self.0 % 1000)
    }
}

impl fmt::Debug for VerificationCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "VerificationCode({self})")
    }
}

/// The result of a successful pairing: pin `peer_key` (e.g. with
/// [`crate::PeerRecord::new`] and [`crate::TrustStore::insert`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Paired {
    /// The peer's device ID.
    pub peer_id: DeviceId,
    /// The peer's public key (as authenticated by the link's handshake).
    pub peer_key: PeerKey,
    /// The string both users may compare.
    pub verification: VerificationCode,
}

/// What the caller does after [`PairingSession::handle`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PairingStep {
    /// Send this message to the peer and keep reading.
    Send(PairingMessage),
    /// Done: both sides proved knowledge of the code.
    Paired(Paired),
}

/// Why pairing failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PairingError {
    /// Key confirmation failed: the codes differ (or someone tried to sit in
    /// the middle). Seen by both sides.
    #[error("the pairing code did not match: it was mistyped, or another device tried to pair; the code is used up, start pairing again for a new code")]
    WrongCode,
    /// The peer gave up and said why.
    #[error("the other device stopped pairing: {0}")]
    PeerAborted(PairingAbort),
    /// The peer speaks another pairing version.
    #[error(
        "the other device uses pairing version {theirs}, this one {ours}; update both devices"
    )]
    UnsupportedVersion { ours: u16, theirs: u16 },
    /// Both devices have the same role.
    #[error("both devices are set to {0:?}: one must show a code and the other must enter it")]
    SameRole(PairingRole),
    /// The peer's SPAKE2 message is malformed.
    #[error("the other device sent a malformed pairing message ({0})")]
    Malformed(String),
    /// A message arrived that does not fit the current step.
    #[error("unexpected pairing message {got} while {state}")]
    Unexpected {
        got: &'static str,
        state: &'static str,
    },
    /// `handle` was called after the session finished or failed.
    #[error("this pairing session is already over")]
    Over,
    /// Both keys are the same: a device cannot pair with itself.
    #[error("a device cannot pair with itself")]
    SelfPairing,
}

impl PairingError {
    /// The message to send to the peer so its user learns why, if any.
    pub fn abort_message(&self) -> Option<PairingMessage> {
        let reason = match self {
            PairingError::WrongCode => PairingAbort::WrongCode,
            PairingError::UnsupportedVersion { ours, .. } => {
                PairingAbort::UnsupportedVersion(*ours)
            }
            PairingError::SameRole(_) => PairingAbort::SameRole,
            PairingError::Malformed(_) | PairingError::Unexpected { .. } => {
                PairingAbort::ProtocolViolation
            }
            PairingError::PeerAborted(_) | PairingError::Over => return None,
            PairingError::SelfPairing => PairingAbort::ProtocolViolation,
        };
        Some(PairingMessage::Abort(reason))
    }
}

enum State {
    AwaitStart(Spake2<Ed25519Group>),
    AwaitConfirm {
        peer_key: [u8; 32],
        transcript: [u8; 32],
        verification: VerificationCode,
    },
    Over,
}

/// The pairing state machine of one side. Feed it every pairing message
/// from the peer, in order, with [`handle`](Self::handle).
pub struct PairingSession {
    role: PairingRole,
    own_key: PeerKey,
    peer_key: PeerKey,
    own_id: DeviceId,
    peer_id: DeviceId,
    own_pake: Vec<u8>,
    state: State,
}

impl fmt::Debug for PairingSession {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let state = match self.state {
            State::AwaitStart(_) => "awaiting Start",
            State::AwaitConfirm { .. } => "awaiting Confirm",
            State::Over => "over",
        };
        f.debug_struct("PairingSession")
            .field("role", &self.role)
            .field("own_id", &self.own_id)
            .field("peer_id", &self.peer_id)
            .field("state", &state)
            .finish()
    }
}

fn spake_identity(id: &DeviceId) -> SpakeIdentity {
    let mut v = b"telextiles device ".to_vec();
    v.extend_from_slice(id.as_bytes());
    SpakeIdentity::new(&v)
}

fn confirm_label(role: PairingRole) -> &'static [u8] {
    match role {
        PairingRole::ShowsCode => b"confirm: shows code",
        PairingRole::EntersCode => b"confirm: enters code",
    }
}

fn hmac(key: &[u8], parts: &[&[u8]]) -> [u8; 32] {
    let mut m = <HmacSha256 as Mac>::new_from_slice(key).expect("HMAC takes any key length");
    for p in parts {
        m.update(p);
    }
    m.finalize().into_bytes().into()
}

impl PairingSession {
    /// Starts pairing. `code` is the one from [`CodeOffer::take`] (showing
    /// side) or typed by the user (entering side); `own_key` is this
    /// device's key and `peer_key` the one the peer authenticated with in
    /// the link's TLS handshake. Returns the session and the `Start` message to send
    /// at once.
    pub fn start<R: RngCore + CryptoRng>(
        role: PairingRole,
        code: PairingCode,
        own_key: &PeerKey,
        peer_key: &PeerKey,
        rng: &mut R,
    ) -> Result<(PairingSession, PairingMessage), PairingError> {
        let own_id = own_key.device_id();
        let peer_id = peer_key.device_id();
        if own_id == peer_id {
            return Err(PairingError::SelfPairing);
        }
        let (a, b) = match role {
            PairingRole::ShowsCode => (own_id, peer_id),
            PairingRole::EntersCode => (peer_id, own_id),
        };
        let password = Password::new(code.password_bytes());
        let (ida, idb) = (spake_identity(&a), spake_identity(&b));
        let (spake, msg) = match role {
            PairingRole::ShowsCode => {
                Spake2::<Ed25519Group>::start_a_with_rng(&password, &ida, &idb, &mut *rng)
            }
            PairingRole::EntersCode => {
                Spake2::<Ed25519Group>::start_b_with_rng(&password, &ida, &idb, &mut *rng)
            }
        };
        let start = PairingMessage::Start(PairingStart {
            version: PAIRING_VERSION,
            role,
            pake: msg.clone(),
        });
        Ok((
            PairingSession {
                role,
                own_key: *own_key,
                peer_key: *peer_key,
                own_id,
                peer_id,
                own_pake: msg,
                state: State::AwaitStart(spake),
            },
            start,
        ))
    }

    /// This side's role.
    pub fn role(&self) -> PairingRole {
        self.role
    }

    /// The peer's device ID (from its key).
    pub fn peer_id(&self) -> DeviceId {
        self.peer_id
    }

    /// Whether the session ended (paired or failed).
    pub fn is_over(&self) -> bool {
        matches!(self.state, State::Over)
    }

    fn transcript(&self, peer_pake: &[u8]) -> [u8; 32] {
        let (key_a, key_b, pake_a, pake_b) = match self.role {
            PairingRole::ShowsCode => (
                self.own_key.spki_der(),
                self.peer_key.spki_der(),
                &self.own_pake[..],
                peer_pake,
            ),
            PairingRole::EntersCode => (
                self.peer_key.spki_der(),
                self.own_key.spki_der(),
                peer_pake,
                &self.own_pake[..],
            ),
        };
        let mut h = Sha256::new();
        h.update(LABEL);
        for part in [&key_a[..], &key_b[..], pake_a, pake_b] {
            h.update((part.len() as u64).to_be_bytes());
            h.update(part);
        }
        h.finalize().into()
    }

    /// Processes one message from the peer. Any error ends the session (the
    /// code stays burnt); [`PairingError::abort_message`] says what to tell
    /// the peer.
    pub fn handle(&mut self, msg: &PairingMessage) -> Result<PairingStep, PairingError> {
        let state = core::mem::replace(&mut self.state, State::Over);
        match (state, msg) {
            (State::Over, _) => Err(PairingError::Over),
            (_, PairingMessage::Abort(reason)) => Err(PairingError::PeerAborted(*reason)),
            (State::AwaitStart(spake), PairingMessage::Start(s)) => {
                if s.version != PAIRING_VERSION {
                    return Err(PairingError::UnsupportedVersion {
                        ours: PAIRING_VERSION,
                        theirs: s.version,
                    });
                }
                if s.role == self.role {
                    return Err(PairingError::SameRole(self.role));
                }
                if s.pake.len() > MAX_PAKE_MESSAGE_LEN {
                    return Err(PairingError::Malformed(format!(
                        "PAKE message of {} bytes",
                        s.pake.len()
                    )));
                }
                let key = spake
                    .finish(&s.pake)
                    .map_err(|e| PairingError::Malformed(format!("PAKE: {e}")))?;
                let t = self.transcript(&s.pake);
                let own_key = hmac(&key, &[LABEL, confirm_label(self.role)]);
                let peer_key = hmac(&key, &[LABEL, confirm_label(self.role.other())]);
                let own_mac = hmac(&own_key, &[&t]);
                let sas = hmac(&key, &[LABEL, b"verification string", &t]);
                let verification = VerificationCode(
                    u32::from_be_bytes([sas[0], sas[1], sas[2], sas[3]]) % 1_000_000,
                );
                self.state = State::AwaitConfirm {
                    peer_key,
                    transcript: t,
                    verification,
                };
                Ok(PairingStep::Send(PairingMessage::Confirm(PairingConfirm {
                    mac: own_mac,
                })))
            }
            (
                State::AwaitConfirm {
                    peer_key,
                    transcript,
                    verification,
                },
                PairingMessage::Confirm(c),
            ) => {
                // `verify_slice` compares in constant time.
                let mut m = <HmacSha256 as Mac>::new_from_slice(&peer_key)
                    .expect("HMAC takes any key length");
                m.update(&transcript);
                if m.verify_slice(&c.mac).is_err() {
                    return Err(PairingError::WrongCode);
                }
                Ok(PairingStep::Paired(Paired {
                    peer_id: self.peer_id,
                    peer_key: self.peer_key,
                    verification,
                }))
            }
            (State::AwaitStart(_), PairingMessage::Confirm(_)) => Err(PairingError::Unexpected {
                got: "Confirm",
                state: "waiting for the peer's Start",
            }),
            (State::AwaitConfirm { .. }, PairingMessage::Start(_)) => {
                Err(PairingError::Unexpected {
                    got: "Start",
                    state: "waiting for the peer's Confirm",
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn damm_reference_value() {
        // Wikipedia's worked example: 572 -> check digit 4.
        assert_eq!(damm(&[5, 7, 2]), 4);
        assert_eq!(damm(&[5, 7, 2, 4]), 0);
    }

    #[test]
    fn verification_code_formats_with_leading_zeros() {
        assert_eq!(VerificationCode(4_005).to_string(), "004 005");
    }
}
