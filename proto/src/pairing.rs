//! Pairing messages: the wire form of the PAKE exchange that lets two devices
//! pin each other's certificates.
//!
//! These are plain serde types so the peer protocol can carry them; the
//! cryptography (SPAKE2, key confirmation, verification string) and the state
//! machine that produces and consumes them live in `telextiles-certs`
//! (`telextiles_certs::pairing::PairingSession`).
//!
//! Exchange (both sides run the same machine, on one reliable, ordered stream):
//!
//! ```text
//!  shows the code                      enters the code
//!  Start { role: ShowsCode, pake } -->
//!                                  <-- Start { role: EntersCode, pake }
//!  Confirm { mac }                 -->
//!                                  <-- Confirm { mac }
//! ```
//!
//! Each side sends its `Start` at once, its `Confirm` as soon as it has the
//! peer's `Start`, and is paired when the peer's `Confirm` checks out. A wrong
//! code shows up on both sides as a `Confirm` that does not verify. `Abort`
//! tells the peer why this side gave up (e.g. the code expired) so both users
//! see the reason.
use alloc::vec::Vec;
use serde::{Deserialize, Serialize};

/// Version of the pairing exchange carried in [`PairingStart::version`].
pub const PAIRING_VERSION: u16 = 2;

/// Largest SPAKE2 message accepted (the Ed25519 group uses 33 bytes).
pub const MAX_PAKE_MESSAGE_LEN: usize = 64;

/// Which part a device plays in pairing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum PairingRole {
    /// This device generated the one-time code and shows it to its user.
    ShowsCode,
    /// This device's user typed the code shown on the other device.
    EntersCode,
}

impl PairingRole {
    /// The role the peer must have.
    pub fn other(self) -> PairingRole {
        match self {
            PairingRole::ShowsCode => PairingRole::EntersCode,
            PairingRole::EntersCode => PairingRole::ShowsCode,
        }
    }
}

/// One message of the pairing exchange.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairingMessage {
    /// First message of each side.
    Start(PairingStart),
    /// Key confirmation, sent after the peer's `Start` was processed.
    Confirm(PairingConfirm),
    /// This side gives up; the reason is shown to the peer's user.
    Abort(PairingAbort),
}

/// First message: this side's role and SPAKE2 message.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PairingStart {
    /// [`PAIRING_VERSION`] of the sender.
    pub version: u16,
    /// The sender's role; the two sides must differ.
    pub role: PairingRole,
    /// SPAKE2 (Ed25519 group) message, at most [`MAX_PAKE_MESSAGE_LEN`] bytes.
    pub pake: Vec<u8>,
}

/// Key confirmation: HMAC-SHA256 (keyed from the PAKE key and the sender's
/// role) over the transcript, which includes both certificates.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PairingConfirm {
    /// The 32-byte tag.
    pub mac: [u8; 32],
}

/// Why a side stopped pairing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum PairingAbort {
    /// The one-time code expired before the other device connected.
    CodeExpired,
    /// The one-time code was already used by an earlier attempt.
    CodeUsed,
    /// This device is not offering a code right now.
    NotPairing,
    /// The codes did not match (key confirmation failed).
    WrongCode,
    /// Both devices have the same role (both show, or both enter, a code).
    SameRole,
    /// The pairing version is not supported; carries the sender's version.
    UnsupportedVersion(u16),
    /// The peer sent something that does not fit the exchange.
    ProtocolViolation,
    /// The user cancelled.
    Cancelled,
}

impl PairingAbort {
    /// A sentence for the user of the device that received this abort.
    pub fn describe(self) -> &'static str {
        match self {
            PairingAbort::CodeExpired => {
                "the pairing code has expired on the other device; start pairing there again for a new code"
            }
            PairingAbort::CodeUsed => {
                "the pairing code was already used (one try per code); start pairing on the other device again for a new code"
            }
            PairingAbort::NotPairing => {
                "the other device is not waiting for pairing; run `telextilesd pair` there first"
            }
            PairingAbort::WrongCode => {
                "the other device says the pairing code did not match; the code is used up, start again for a new one"
            }
            PairingAbort::SameRole => {
                "both devices are in the same pairing role: one must show a code and the other must enter it"
            }
            PairingAbort::UnsupportedVersion(_) => {
                "the other device runs an incompatible pairing version; update both devices"
            }
            PairingAbort::ProtocolViolation => "the other device reported a pairing protocol error",
            PairingAbort::Cancelled => "pairing was cancelled on the other device",
        }
    }
}

impl core::fmt::Display for PairingAbort {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.describe())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn config() -> impl bincode::config::Config {
        bincode::config::standard().with_limit::<1024>()
    }

    #[test]
    fn messages_round_trip_through_bincode() {
        let msgs = [
            PairingMessage::Start(PairingStart {
                version: PAIRING_VERSION,
                role: PairingRole::EntersCode,
                pake: (0..33).collect(),
            }),
            PairingMessage::Confirm(PairingConfirm { mac: [7; 32] }),
            PairingMessage::Abort(PairingAbort::UnsupportedVersion(9)),
        ];
        for m in msgs {
            let bytes = bincode::serde::encode_to_vec(&m, config()).unwrap();
            let (back, used): (PairingMessage, usize) =
                bincode::serde::decode_from_slice(&bytes, config()).unwrap();
            assert_eq!(used, bytes.len());
            assert_eq!(back, m);
        }
    }

    #[test]
    fn roles_are_complementary() {
        assert_eq!(PairingRole::ShowsCode.other(), PairingRole::EntersCode);
        assert_eq!(PairingRole::EntersCode.other(), PairingRole::ShowsCode);
    }
}
