//! Device identity, paired-peer trust store, pairing and pins for the
//! Telextiles peer link.
//!
//! Everything here is sans-IO except the two small file stores (identity and
//! trust store), which take the directory as an argument. No clocks (callers
//! pass `now`), no sockets, no async.
//!
//! # Pieces
//!
//! * [`DeviceId`]: SHA-256 of a device key's SubjectPublicKeyInfo, shown as
//!   13 groups of 5 base32 characters (4 data + 1 Luhn mod 32 check
//!   character), e.g. `ABCDQ-...`. `FromStr` validates and names the group
//!   with a typo.
//! * [`PeerKey`]: the device's Ed25519 public key, what the link dials (an
//!   iroh endpoint ID); [`PeerKey::device_id`] gives its ID.
//! * [`Identity`]: this device's Ed25519 key and self-signed certificate, in
//!   `<dir>/identity.pem` (0600, atomic write, created under a [`DirLock`]).
//!   [`Identity::secret_seed`] is the key the link's endpoint signs with.
//!   Use [`Identity::load_or_create`] with the daemon's state directory
//!   (`telextilesd` passes its configured `state_dir`), [`default_data_dir`],
//!   or a temporary directory in tests.
//! * [`TrustStore`]: paired peers ([`PeerRecord`]: ID, name, key,
//!   paired-at, last-seen, last addresses) in `<dir>/peers.json` (0600,
//!   atomic write; format 1, which kept certificates, is read and
//!   migrated on the next write). [`TrustStore::update`] locks the
//!   directory, re-reads, changes and saves, so processes never lose each
//!   other's changes; [`TrustStore::find`] resolves what a user typed (ID,
//!   prefix, name).
//! * [`pairing`]: [`CodeOffer`] / [`PairingCode`] (8 digits with a check
//!   digit, one attempt, expiry from a caller-supplied `now`) and the
//!   [`PairingSession`] state machine (SPAKE2 + HMAC key confirmation
//!   binding both keys, 6-digit [`VerificationCode`]). Its messages
//!   are [`telextiles_proto::pairing::PairingMessage`] (re-exported here).
//! * [`PinSet`]: the paired IDs, shared and live ([`PinSet::reload`]
//!   re-reads the trust store); the link's handshake gate consults it.
//! * [`report`]: text and JSON views for `telextilesd id` / `peers`.
//!
//! # How the link uses it
//!
//! The link's iroh endpoint signs with [`Identity::secret_seed`]; it dials
//! a peer by its [`PeerKey`] (the dial pins it) and closes an incoming
//! connection whose key's [`DeviceId`] is not in the [`PinSet`] (outside
//! pairing mode). Pairing: both sides take the peer's key from the
//! connection, then run [`PairingSession`] over a
//! reliable stream. On [`PairingStep::Paired`], store
//! `PeerRecord::new(paired.peer_key, name, now)` with
//! [`TrustStore::update`], `pins.insert(paired.peer_id)`, and show
//! `paired.verification` to the user. The showing side gets its code from
//! [`CodeOffer::take`] when a peer's `Start` arrives (expired / used →
//! send `PairingMessage::Abort(err.abort_reason())`); any [`PairingError`]
//! ends the attempt, and [`PairingError::abort_message`] is what to tell the
//! peer.
//!
//! After `telextilesd unpair` (another process) a running link should call
//! [`PinSet::reload`] (e.g. before accepting or dialling) so the change
//! applies to the next handshake; connections already up are the link's to
//! close.
//!
//! See `docs/identity-and-pairing.md` for the formats and the protocol.
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod device_id;
pub mod identity;
pub mod key;
pub mod pairing;
pub mod pins;
pub mod report;
pub mod store;
pub mod trust;

pub use device_id::{CertParseError, DeviceId, DeviceIdError};
pub use identity::{Identity, IDENTITY_FILE};
pub use key::{PeerKey, PeerKeyError};
pub use pairing::{
    CodeError, CodeOffer, Paired, PairingCode, PairingError, PairingMessage, PairingRole,
    PairingSession, PairingStep, VerificationCode, DEFAULT_CODE_TTL,
};
pub use pins::PinSet;
pub use store::{data_dir_from, default_data_dir, write_atomic, DirLock, StoreError};
pub use trust::{LookupError, PeerRecord, TrustStore, TRUST_FILE};
