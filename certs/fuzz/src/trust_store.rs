//! The trust store file's content: never panics; what loads is consistent
//! (every peer's device id is the one its key hashes to).
use telextiles_certs::TrustStore;

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    if let Ok(s) = TrustStore::parse(std::path::Path::new("/nonexistent"), data) {
        for p in s.peers() {
            assert_eq!(p.key.device_id(), p.device_id);
        }
    }
}
