//! Certificates presented by peers: never panic.
use rustls::pki_types::{CertificateDer, UnixTime};
use telextiles_certs::{DeviceId, PeerPolicy, PeerSide, PeerVerifier};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    let cert = CertificateDer::from(data.to_vec());
    let _ = DeviceId::from_cert(&cert);
    let now = UnixTime::since_unix_epoch(std::time::Duration::from_secs(1_800_000_000));
    let v = PeerVerifier::new(PeerPolicy::AnyForPairing);
    let _ = v.check(&cert, &[], PeerSide::Client, now);
    let _ = v.check(&cert, &[], PeerSide::Server, now);
}
