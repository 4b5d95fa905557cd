//! Keys and certificates from files and adverts (a trust store of format
//! 1 keeps certificates; an mDNS advert carries a key): never panic, and a
//! key read back gives the ID its certificate does.
use rustls::pki_types::CertificateDer;
use telextiles_certs::{DeviceId, PeerKey};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    let cert = CertificateDer::from(data.to_vec());
    let id = DeviceId::from_cert(&cert);
    if let Ok(key) = PeerKey::from_cert(&cert) {
        assert_eq!(Ok(key.device_id()), id.map_err(|_| ()), "key and certificate disagree");
    }
    if let Ok(key) = PeerKey::from_spki_der(data) {
        assert_eq!(PeerKey::from_spki_der(&key.spki_der()), Ok(key));
    }
    if let Ok(text) = std::str::from_utf8(data) {
        if let Ok(key) = text.parse::<PeerKey>() {
            assert_eq!(key.to_string().parse::<PeerKey>(), Ok(key));
        }
    }
}
