//! The trust store file's content: never panics; what loads is consistent.
use telextiles_certs::{DeviceId, TrustStore};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    if let Ok(s) = TrustStore::parse(std::path::Path::new("/nonexistent"), data) {
        for p in s.peers() {
            assert_eq!(DeviceId::from_cert(&p.cert).unwrap(), p.device_id);
        }
    }
}
