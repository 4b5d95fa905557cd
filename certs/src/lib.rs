//! Device identity, paired-peer trust store, pairing and pinning verifiers
//! for the Telextiles peer link.
//!
//! Everything here is sans-IO except the two small file stores (identity and
//! trust store), which take the directory as an argument. No clocks (callers
//! pass `now`), no sockets, no async.
//!
//! # Pieces
//!
//! * [`DeviceId`]: SHA-256 of a certificate's SubjectPublicKeyInfo, shown as
//!   13 groups of 5 base32 characters (4 data + 1 Luhn mod 32 check
//!   character), e.g. `ABCDQ-...`. `FromStr` validates and names the group
//!   with a typo.
//! * [`Identity`]: this device's Ed25519 key and self-signed certificate, in
//!   `<dir>/identity.pem` (0600, atomic write, created under a [`DirLock`]).
//!   Use [`Identity::load_or_create`] with the daemon's state directory
//!   (`telextilesd` passes its configured `state_dir`), [`default_data_dir`],
//!   or a temporary directory in tests.
//! * [`TrustStore`]: paired peers ([`PeerRecord`]: ID, name, certificate,
//!   paired-at, last-seen, last addresses) in `<dir>/peers.json` (0600,
//!   atomic write). [`TrustStore::update`] locks the directory, re-reads,
//!   changes and saves, so processes never lose each other's changes;
//!   [`TrustStore::find`] resolves what a user typed (ID, prefix, name).
//! * [`pairing`]: [`CodeOffer`] / [`PairingCode`] (8 digits with a check
//!   digit, one attempt, expiry from a caller-supplied `now`) and the
//!   [`PairingSession`] state machine (SPAKE2 + HMAC key confirmation
//!   binding both certificates, 6-digit [`VerificationCode`]). Its messages
//!   are [`telextiles_proto::pairing::PairingMessage`] (re-exported here).
//! * [`report`]: text and JSON views for `telextilesd id` / `peers`.
//! * [`tls`]: [`PeerVerifier`] (rustls `ServerCertVerifier` and
//!   `ClientCertVerifier` that pin device IDs and still verify the TLS 1.3
//!   handshake signature; pairing mode also requires a valid self-signature),
//!   [`PeerPolicy`], [`PinSet`] (shared, live; [`PinSet::reload`] re-reads
//!   the trust store), [`PeerRejected`] (why a peer was refused; recover it
//!   from a rustls error with [`PeerRejected::from_rustls`]), and
//!   [`server_config`] / [`client_config`] (TLS 1.3 only, ring only, mutual
//!   auth, ALPN `telextiles/1`, no session resumption).
//!
//! # How the link uses it
//!
//! ```no_run
//! use telextiles_certs::*;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let dir = default_data_dir()?;
//! let (me, _created) = Identity::load_or_create(&dir)?;
//! let store = TrustStore::load(&dir)?;
//! let pins = PinSet::from_store(&store);
//! // Normal operation: accept only paired peers.
//! let server = server_config(&me, PeerPolicy::Pinned(pins.clone()))?;
//! // Dial a known peer:
//! let peer_id = store.peers()[0].device_id;
//! let client = client_config(&me, PeerPolicy::Expect(peer_id))?;
//! // quinn: QuicServerConfig::try_from(server), QuicClientConfig::try_from(client),
//! // endpoint.connect(addr, SERVER_NAME).
//! # let _ = (server, client); Ok(()) }
//! ```
//!
//! Pairing: both sides use `PeerPolicy::AnyForPairing`, take the peer's
//! certificate from the connection (quinn `peer_identity()` downcast to
//! `Vec<CertificateDer<'static>>`), then run [`PairingSession`] over a
//! reliable stream. On [`PairingStep::Paired`], store
//! `PeerRecord::new(paired.peer_cert, name, now)` with
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
pub mod pairing;
pub mod report;
pub mod store;
pub mod tls;
pub mod trust;

pub use device_id::{CertParseError, DeviceId, DeviceIdError};
pub use identity::{Identity, IDENTITY_FILE};
pub use pairing::{
    CodeError, CodeOffer, Paired, PairingCode, PairingError, PairingMessage, PairingRole,
    PairingSession, PairingStep, VerificationCode, DEFAULT_CODE_TTL,
};
pub use store::{data_dir_from, default_data_dir, write_atomic, DirLock, StoreError};
pub use tls::{
    client_config, peer_device_id, provider, server_config, PeerPolicy, PeerRejected, PeerSide,
    PeerVerifier, PinSet, ALPN, SERVER_NAME,
};
pub use trust::{LookupError, PeerRecord, TrustStore, TRUST_FILE};
