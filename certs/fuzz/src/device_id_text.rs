//! Device IDs and pairing codes typed by people: never panic; whatever
//! parses prints back to the same value.
use telextiles_certs::{DeviceId, PairingCode};

/// The target body: must not panic for any input.
pub fn run(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(id) = text.parse::<DeviceId>() {
        assert_eq!(id.to_string().parse::<DeviceId>().unwrap(), id);
    }
    if let Ok(code) = text.parse::<PairingCode>() {
        assert_eq!(code.to_string().parse::<PairingCode>().unwrap(), code);
    }
}
