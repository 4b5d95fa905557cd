//! Certificates presented by peers: never panic.
#![no_main]
use libfuzzer_sys::fuzz_target;
use rustls::pki_types::{CertificateDer, UnixTime};
use telextiles_certs::{DeviceId, PeerPolicy, PeerSide, PeerVerifier};

fuzz_target!(|data: &[u8]| {
    let cert = CertificateDer::from(data.to_vec());
    let _ = DeviceId::from_cert(&cert);
    let now = UnixTime::since_unix_epoch(std::time::Duration::from_secs(1_800_000_000));
    let v = PeerVerifier::new(PeerPolicy::AnyForPairing);
    let _ = v.check(&cert, &[], PeerSide::Client, now);
    let _ = v.check(&cert, &[], PeerSide::Server, now);
});
