//! rustls configuration for the peer link: TLS 1.3 only, ring provider only,
//! mutual authentication with pinned device keys.
//!
//! Certificates are self-signed, so there is no chain to check. Instead the
//! verifiers accept a peer only by the hash of its public key
//! ([`DeviceId`]), and still verify the TLS 1.3 handshake signature with
//! [`rustls::crypto::verify_tls13_signature`], which proves the peer holds
//! the private key of the certificate it shows (a copied certificate is
//! useless).
use std::collections::BTreeSet;
use std::fmt;
use std::sync::{Arc, RwLock};

use rustls::client::danger::{HandshakeSignatureValid, ServerCertVerified, ServerCertVerifier};
use rustls::crypto::{CryptoProvider, WebPkiSupportedAlgorithms};
use rustls::pki_types::{CertificateDer, ServerName, UnixTime};
use rustls::server::danger::{ClientCertVerified, ClientCertVerifier};
use rustls::{
    CertificateError, ClientConfig, DigitallySignedStruct, DistinguishedName, OtherError,
    ServerConfig, SignatureScheme,
};

use crate::device_id::DeviceId;
use crate::identity::Identity;
use crate::trust::TrustStore;

/// ALPN protocol of the peer link.
pub const ALPN: &[u8] = b"telextiles/1";
/// Server name clients pass to `connect` (not checked: keys are pinned).
pub const SERVER_NAME: &str = crate::identity::CERT_NAME;

/// The ring crypto provider (the only one this project uses).
pub fn provider() -> Arc<CryptoProvider> {
    Arc::new(rustls::crypto::ring::default_provider())
}

/// A shared, updatable set of pinned device IDs. Clones share the set, so a
/// verifier built from it sees pairings and unpairings made later.
#[derive(Clone, Default)]
pub struct PinSet(Arc<RwLock<BTreeSet<DeviceId>>>);

impl fmt::Debug for PinSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_set().entries(self.snapshot()).finish()
    }
}

impl PinSet {
    /// A set of these IDs.
    pub fn new(ids: impl IntoIterator<Item = DeviceId>) -> PinSet {
        PinSet(Arc::new(RwLock::new(ids.into_iter().collect())))
    }

    /// The IDs of all peers in a trust store.
    pub fn from_store(store: &TrustStore) -> PinSet {
        PinSet::new(store.device_ids())
    }

    fn read(&self) -> std::sync::RwLockReadGuard<'_, BTreeSet<DeviceId>> {
        self.0.read().unwrap_or_else(|p| p.into_inner())
    }

    fn write(&self) -> std::sync::RwLockWriteGuard<'_, BTreeSet<DeviceId>> {
        self.0.write().unwrap_or_else(|p| p.into_inner())
    }

    /// Whether `id` is pinned.
    pub fn contains(&self, id: &DeviceId) -> bool {
        self.read().contains(id)
    }

    /// Pins `id`; returns whether it was new.
    pub fn insert(&self, id: DeviceId) -> bool {
        self.write().insert(id)
    }

    /// Unpins `id`; returns whether it was there.
    pub fn remove(&self, id: &DeviceId) -> bool {
        self.write().remove(id)
    }

    /// Replaces the set with the peers of `store` (e.g. after re-reading it).
    pub fn replace_from(&self, store: &TrustStore) {
        *self.write() = store.device_ids().collect();
    }

    /// Re-reads the trust store in `dir` and replaces the set with its
    /// peers, so unpairings (and pairings) made by another process, e.g.
    /// `telextilesd unpair`, apply to the next handshake. Blocking file I/O:
    /// call it from a blocking context.
    pub fn reload(&self, dir: &std::path::Path) -> Result<(), crate::StoreError> {
        let store = TrustStore::load(dir)?;
        self.replace_from(&store);
        Ok(())
    }

    /// A copy of the current IDs.
    pub fn snapshot(&self) -> Vec<DeviceId> {
        self.read().iter().copied().collect()
    }
}

/// Which peer certificates a verifier accepts. In every mode the handshake
/// signature is verified against the certificate's key.
#[derive(Clone, Debug)]
pub enum PeerPolicy {
    /// Any device whose ID is in the set (a server accepting paired peers,
    /// or a client that does not care which paired peer answers).
    Pinned(PinSet),
    /// Exactly this device (a client dialling a known peer, e.g. from its
    /// remembered addresses or mDNS).
    Expect(DeviceId),
    /// Pairing mode: any validly self-signed certificate. The caller MUST NOT trust
    /// the peer after the handshake until a [`crate::PairingSession`] over
    /// this connection succeeded, with the peer certificate taken from the
    /// connection (quinn: `Connection::peer_identity()`, see
    /// [`peer_device_id`]). A server in this mode also gets connections from
    /// paired peers: check `PinSet::contains(peer_device_id(..))` to tell
    /// them apart.
    AnyForPairing,
}

/// The error inside `CertificateError::Other` when a peer is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PeerRejected {
    /// The device is not paired with this one.
    #[error("device {0} is not paired with this device")]
    NotPaired(DeviceId),
    /// A different device than the one dialled answered.
    #[error("expected device {expected}, but {got} answered")]
    Unexpected { expected: DeviceId, got: DeviceId },
    /// The certificate could not be parsed.
    #[error("the peer's certificate is unusable: {0}")]
    BadCert(String),
    /// The peer sent a certificate chain; devices use one self-signed cert.
    #[error("the peer sent {0} extra certificates; a device presents exactly one")]
    Chain(usize),
    /// Pairing mode: the certificate is not validly self-signed.
    #[error("the peer's certificate is not a valid self-signed certificate: {0}")]
    NotSelfSigned(String),
}

impl PeerRejected {
    /// Finds the rejection inside a rustls error (e.g. the one a failed
    /// handshake returns), for a clear message.
    pub fn from_rustls(err: &rustls::Error) -> Option<&PeerRejected> {
        match err {
            rustls::Error::InvalidCertificate(CertificateError::Other(OtherError(e))) => {
                e.downcast_ref::<PeerRejected>()
            }
            _ => None,
        }
    }
}

fn reject(r: PeerRejected) -> rustls::Error {
    rustls::Error::InvalidCertificate(CertificateError::Other(OtherError(Arc::new(r))))
}

/// Device ID of the first (end-entity) certificate a peer presented.
pub fn peer_device_id(certs: &[CertificateDer<'_>]) -> Result<DeviceId, PeerRejected> {
    let first = certs
        .first()
        .ok_or_else(|| PeerRejected::BadCert("no certificate".into()))?;
    DeviceId::from_cert(first).map_err(|e| PeerRejected::BadCert(e.to_string()))
}

/// Which end of the TLS connection the peer is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PeerSide {
    /// The peer is the server (we dialled it).
    Server,
    /// The peer is the client (it dialled us).
    Client,
}

/// Pinning verifier for both ends of the connection (implements
/// [`ServerCertVerifier`] and [`ClientCertVerifier`]).
#[derive(Debug)]
pub struct PeerVerifier {
    policy: PeerPolicy,
    algs: WebPkiSupportedAlgorithms,
}

impl PeerVerifier {
    /// A verifier with `policy`, using the ring provider's signature
    /// algorithms.
    pub fn new(policy: PeerPolicy) -> PeerVerifier {
        PeerVerifier {
            policy,
            algs: rustls::crypto::ring::default_provider().signature_verification_algorithms,
        }
    }

    /// The policy.
    pub fn policy(&self) -> &PeerPolicy {
        &self.policy
    }

    /// Applies the policy to a certificate presented at `now` by a peer
    /// acting as `side` (the chain must be just the end-entity certificate).
    /// Pinned modes compare the key hash only; pairing mode also requires a
    /// valid self-signature (checked with webpki, the certificate as its own
    /// trust anchor). The handshake signature is checked separately by
    /// rustls through this verifier.
    pub fn check(
        &self,
        end_entity: &CertificateDer<'_>,
        intermediates: &[CertificateDer<'_>],
        side: PeerSide,
        now: UnixTime,
    ) -> Result<DeviceId, PeerRejected> {
        if !intermediates.is_empty() {
            return Err(PeerRejected::Chain(intermediates.len()));
        }
        let id =
            DeviceId::from_cert(end_entity).map_err(|e| PeerRejected::BadCert(e.to_string()))?;
        match &self.policy {
            PeerPolicy::Pinned(pins) if pins.contains(&id) => Ok(id),
            PeerPolicy::Pinned(_) => Err(PeerRejected::NotPaired(id)),
            PeerPolicy::Expect(e) if *e == id => Ok(id),
            PeerPolicy::Expect(e) => Err(PeerRejected::Unexpected {
                expected: *e,
                got: id,
            }),
            PeerPolicy::AnyForPairing => {
                self.self_signed(end_entity, side, now)?;
                Ok(id)
            }
        }
    }

    fn self_signed(
        &self,
        cert: &CertificateDer<'_>,
        side: PeerSide,
        now: UnixTime,
    ) -> Result<(), PeerRejected> {
        let bad = |e: webpki::Error| PeerRejected::NotSelfSigned(format!("{e:?}"));
        let anchor = webpki::anchor_from_trusted_cert(cert).map_err(bad)?;
        let ee = webpki::EndEntityCert::try_from(cert).map_err(bad)?;
        let usage = match side {
            PeerSide::Server => webpki::KeyUsage::server_auth(),
            PeerSide::Client => webpki::KeyUsage::client_auth(),
        };
        ee.verify_for_usage(self.algs.all, &[anchor], &[], now, usage, None, None)
            .map(|_| ())
            .map_err(bad)
    }

    fn tls13(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        rustls::crypto::verify_tls13_signature(message, cert, dss, &self.algs)
    }
}

fn tls12_refused() -> rustls::Error {
    rustls::Error::General("TLS 1.2 is not supported by the telextiles peer link".into())
}

impl ServerCertVerifier for PeerVerifier {
    fn verify_server_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        intermediates: &[CertificateDer<'_>],
        _server_name: &ServerName<'_>,
        _ocsp_response: &[u8],
        now: UnixTime,
    ) -> Result<ServerCertVerified, rustls::Error> {
        self.check(end_entity, intermediates, PeerSide::Server, now)
            .map_err(reject)?;
        Ok(ServerCertVerified::assertion())
    }

    fn verify_tls12_signature(
        &self,
        _message: &[u8],
        _cert: &CertificateDer<'_>,
        _dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        Err(tls12_refused())
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        self.tls13(message, cert, dss)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.algs.supported_schemes()
    }
}

impl ClientCertVerifier for PeerVerifier {
    fn offer_client_auth(&self) -> bool {
        true
    }

    fn client_auth_mandatory(&self) -> bool {
        true
    }

    fn root_hint_subjects(&self) -> &[DistinguishedName] {
        &[]
    }

    fn verify_client_cert(
        &self,
        end_entity: &CertificateDer<'_>,
        intermediates: &[CertificateDer<'_>],
        now: UnixTime,
    ) -> Result<ClientCertVerified, rustls::Error> {
        self.check(end_entity, intermediates, PeerSide::Client, now)
            .map_err(reject)?;
        Ok(ClientCertVerified::assertion())
    }

    fn verify_tls12_signature(
        &self,
        _message: &[u8],
        _cert: &CertificateDer<'_>,
        _dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        Err(tls12_refused())
    }

    fn verify_tls13_signature(
        &self,
        message: &[u8],
        cert: &CertificateDer<'_>,
        dss: &DigitallySignedStruct,
    ) -> Result<HandshakeSignatureValid, rustls::Error> {
        self.tls13(message, cert, dss)
    }

    fn supported_verify_schemes(&self) -> Vec<SignatureScheme> {
        self.algs.supported_schemes()
    }
}

/// Server side: TLS 1.3, ring, this device's certificate, client
/// certificates required and checked by a [`PeerVerifier`] with `policy`,
/// ALPN [`ALPN`], no session resumption or tickets (every connection is
/// fully verified against the current pins). For quinn:
/// `quinn::crypto::rustls::QuicServerConfig::try_from(cfg)`.
pub fn server_config(
    identity: &Identity,
    policy: PeerPolicy,
) -> Result<ServerConfig, rustls::Error> {
    let mut cfg = ServerConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])?
        .with_client_cert_verifier(Arc::new(PeerVerifier::new(policy)))
        .with_single_cert(
            vec![identity.cert_der().clone()],
            identity.private_key_der(),
        )?;
    cfg.alpn_protocols = vec![ALPN.to_vec()];
    // No session resumption: a resumed session skips certificate
    // verification, so an unpaired device could come back on an old ticket.
    cfg.session_storage = Arc::new(rustls::server::NoServerSessionStorage {});
    cfg.send_tls13_tickets = 0;
    Ok(cfg)
}

/// Client side: TLS 1.3, ring, server checked by a [`PeerVerifier`] with
/// `policy`, this device's certificate as client certificate, ALPN
/// [`ALPN`], no session resumption. For quinn:
/// `quinn::crypto::rustls::QuicClientConfig::try_from(cfg)`;
/// connect with server name [`SERVER_NAME`].
pub fn client_config(
    identity: &Identity,
    policy: PeerPolicy,
) -> Result<ClientConfig, rustls::Error> {
    let mut cfg = ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])?
        .dangerous()
        .with_custom_certificate_verifier(Arc::new(PeerVerifier::new(policy)))
        .with_client_auth_cert(
            vec![identity.cert_der().clone()],
            identity.private_key_der(),
        )?;
    cfg.alpn_protocols = vec![ALPN.to_vec()];
    // No session resumption (see `server_config`): every connection runs
    // the full handshake and the verifier sees the current pins.
    cfg.resumption = rustls::client::Resumption::disabled();
    Ok(cfg)
}
