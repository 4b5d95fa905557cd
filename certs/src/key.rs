//! A device's public key: the Ed25519 key its identity signs with, which
//! is also its address on the peer link (an iroh endpoint ID). The
//! [`DeviceId`] people read and pin is the SHA-256 of this key's
//! SubjectPublicKeyInfo, so IDs stay what they were when the link ran on
//! certificates; the key is what a dial needs (a hash cannot be dialled).
//!
//! Text form: 64 lowercase hex characters (as iroh writes endpoint IDs).
use core::fmt;
use core::str::FromStr;

use rustls::pki_types::CertificateDer;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use crate::device_id::{CertParseError, DeviceId};

/// DER of an Ed25519 SubjectPublicKeyInfo up to its 32 key bytes
/// (RFC 8410: SEQUENCE { SEQUENCE { OID 1.3.101.112 } BIT STRING }).
const ED25519_SPKI_PREFIX: [u8; 12] = [
    0x30, 0x2a, 0x30, 0x05, 0x06, 0x03, 0x2b, 0x65, 0x70, 0x03, 0x21, 0x00,
];

/// An Ed25519 public key of a device.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct PeerKey([u8; 32]);

/// Why a text or certificate gives no key.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PeerKeyError {
    #[error("a device key is 64 hex characters (`telextilesd id` prints it), this one has {0}")]
    Length(usize),
    #[error("a device key is hex (0-9, a-f): {0:?} is not")]
    NotHex(char),
    #[error("the certificate's key is not an Ed25519 key")]
    NotEd25519,
    #[error(transparent)]
    Cert(#[from] CertParseError),
}

impl PeerKey {
    /// Wraps the 32 key bytes.
    pub const fn from_bytes(bytes: [u8; 32]) -> PeerKey {
        PeerKey(bytes)
    }

    /// The 32 key bytes.
    pub const fn as_bytes(&self) -> &[u8; 32] {
        &self.0
    }

    /// The key's SubjectPublicKeyInfo (DER), as a certificate or a TLS
    /// raw public key carries it.
    pub fn spki_der(&self) -> [u8; 44] {
        let mut out = [0u8; 44];
        out[..12].copy_from_slice(&ED25519_SPKI_PREFIX);
        out[12..].copy_from_slice(&self.0);
        out
    }

    /// The key of a DER SubjectPublicKeyInfo, if it is an Ed25519 one.
    pub fn from_spki_der(spki: &[u8]) -> Result<PeerKey, PeerKeyError> {
        match spki.strip_prefix(&ED25519_SPKI_PREFIX[..]) {
            Some(rest) => rest
                .try_into()
                .map(PeerKey)
                .map_err(|_| PeerKeyError::NotEd25519),
            None => Err(PeerKeyError::NotEd25519),
        }
    }

    /// The key a certificate carries (trust stores written before the
    /// link moved to raw keys kept each peer's certificate).
    pub fn from_cert(cert: &CertificateDer<'_>) -> Result<PeerKey, PeerKeyError> {
        let parsed =
            webpki::EndEntityCert::try_from(cert).map_err(|e| CertParseError(format!("{e:?}")))?;
        PeerKey::from_spki_der(parsed.subject_public_key_info().as_ref())
    }

    /// The device ID of this key (SHA-256 of its SubjectPublicKeyInfo).
    pub fn device_id(&self) -> DeviceId {
        DeviceId::from_spki_der(&self.spki_der())
    }
}

impl fmt::Display for PeerKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&data_encoding::HEXLOWER.encode(&self.0))
    }
}

impl fmt::Debug for PeerKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "PeerKey({self})")
    }
}

impl FromStr for PeerKey {
    type Err = PeerKeyError;

    fn from_str(s: &str) -> Result<PeerKey, PeerKeyError> {
        let s = s.trim();
        if let Some(c) = s.chars().find(|c| !c.is_ascii_hexdigit()) {
            return Err(PeerKeyError::NotHex(c));
        }
        if s.len() != 64 {
            return Err(PeerKeyError::Length(s.len()));
        }
        let bytes = data_encoding::HEXLOWER_PERMISSIVE
            .decode(s.as_bytes())
            .map_err(|_| PeerKeyError::Length(s.len()))?;
        let arr: [u8; 32] = bytes
            .try_into()
            .map_err(|_| PeerKeyError::Length(s.len()))?;
        Ok(PeerKey(arr))
    }
}

impl Serialize for PeerKey {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_string())
    }
}

impl<'de> Deserialize<'de> for PeerKey {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<PeerKey, D::Error> {
        let text = String::deserialize(d)?;
        text.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Identity;

    #[test]
    fn a_key_hashes_to_the_device_id_its_certificate_gave() {
        for _ in 0..4 {
            let me = Identity::generate().unwrap();
            let key = PeerKey::from_cert(me.cert_der()).unwrap();
            assert_eq!(key, me.peer_key());
            assert_eq!(key.device_id(), me.device_id());
            assert_eq!(PeerKey::from_spki_der(&key.spki_der()).unwrap(), key);
        }
    }

    #[test]
    fn text_round_trips_and_mistakes_are_named() {
        let key = PeerKey::from_bytes([0xab; 32]);
        let text = key.to_string();
        assert_eq!(text.len(), 64);
        assert_eq!(text.parse::<PeerKey>().unwrap(), key);
        assert_eq!(text.to_uppercase().parse::<PeerKey>().unwrap(), key);
        assert_eq!(
            text[..63].parse::<PeerKey>().unwrap_err(),
            PeerKeyError::Length(63)
        );
        assert_eq!(
            format!("{}z", &text[..63]).parse::<PeerKey>().unwrap_err(),
            PeerKeyError::NotHex('z')
        );
        assert_eq!(
            PeerKey::from_spki_der(&[0u8; 44]).unwrap_err(),
            PeerKeyError::NotEd25519
        );
    }
}
