//! The identity file's content: never panics; what loads is consistent.
#![no_main]
use libfuzzer_sys::fuzz_target;
use telextiles_certs::{DeviceId, Identity};

fuzz_target!(|data: &[u8]| {
    if let Ok(id) = Identity::from_pem(&String::from_utf8_lossy(data)) {
        assert_eq!(DeviceId::from_cert(id.cert_der()).unwrap(), id.device_id());
    }
});
