//! The identity file's content: never panics; what loads is consistent.
use telextiles_certs::{DeviceId, Identity};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    if let Ok(id) = Identity::from_pem(&String::from_utf8_lossy(data)) {
        assert_eq!(DeviceId::from_cert(id.cert_der()).unwrap(), id.device_id());
    }
}
