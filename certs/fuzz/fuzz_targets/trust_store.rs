//! The trust store file's content: never panics; what loads is consistent.
#![no_main]
use libfuzzer_sys::fuzz_target;
use telextiles_certs::{DeviceId, TrustStore};

fuzz_target!(|data: &[u8]| {
    if let Ok(s) = TrustStore::parse(std::path::Path::new("/nonexistent"), data) {
        for p in s.peers() {
            assert_eq!(DeviceId::from_cert(&p.cert).unwrap(), p.device_id);
        }
    }
});
