//! Device IDs: SHA-256 of a certificate's SubjectPublicKeyInfo, written in a
//! form people can read out, type and check.
//!
//! The 32 bytes are encoded in RFC 4648 base32 (alphabet `A-Z 2-7`, no
//! padding: 52 characters), cut into 13 groups of 4 characters, and each group
//! gets a fifth character: its Luhn mod 32 check character. Groups are joined
//! with `-`:
//!
//! ```text
//! MFRGG-ZDFMZ-...   (13 groups of 5 characters, 77 characters in all)
//! ```
//!
//! Every single mistyped character and most swaps of neighbouring characters
//! make the group's check fail, and the error names the group. Parsing is
//! lenient about case, spaces and dashes, and reads the digits `0`, `1`, `8`
//! (which base32 does not use) as `O`, `I`, `B`.
use core::fmt;
use core::str::FromStr;

use rustls::pki_types::CertificateDer;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use sha2::{Digest, Sha256};

const ALPHABET: &[u8; 32] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZ234567";
/// Data characters per group.
const DATA_PER_GROUP: usize = 4;
/// Characters per group including the check character.
pub const GROUP_LEN: usize = DATA_PER_GROUP + 1;
/// Number of groups.
pub const GROUPS: usize = 13;
/// Length of the canonical text form, dashes included.
pub const TEXT_LEN: usize = GROUPS * GROUP_LEN + GROUPS - 1;

/// A device's identity: SHA-256 of the SubjectPublicKeyInfo (DER) of its
/// certificate. `Display` gives the grouped, checked form; `FromStr` parses
/// and validates it; serde uses the text form.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct DeviceId([u8; 32]);

/// Why a text is not a device ID.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum DeviceIdError {
    /// Wrong number of characters (after removing spaces and dashes).
    #[error(
        "a device ID has {expected} characters (13 groups of 5, dashes aside), this one has {got}"
    )]
    Length { expected: usize, got: usize },
    /// A character outside the base32 alphabet.
    #[error("character {ch:?} in group {group} of the device ID is not a device-ID character (A-Z and 2-7)")]
    BadChar { ch: char, group: usize },
    /// A group's check character does not match: a typo in that group.
    #[error(
        "group {group} ({text}) of the device ID has a typo: its check character does not match"
    )]
    Checksum { group: usize, text: String },
    /// The last group encodes bits that a SHA-256 hash cannot have.
    #[error(
        "group {group} ({text}) of the device ID is not valid (its last character is impossible)"
    )]
    Trailing { group: usize, text: String },
}

/// Why a certificate gives no device ID.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("not a usable X.509 certificate: {0}")]
pub struct CertParseError(pub String);

impl DeviceId {
    /// Wraps raw hash bytes.
    pub const fn from_bytes(bytes: [u8; 32]) -> DeviceId {
        DeviceId(bytes)
    }

    /// The raw 32 bytes.
    pub const fn as_bytes(&self) -> &[u8; 32] {
        &self.0
    }

    /// SHA-256 of a DER SubjectPublicKeyInfo.
    pub fn from_spki_der(spki: &[u8]) -> DeviceId {
        DeviceId(Sha256::digest(spki).into())
    }

    /// Device ID of a DER certificate (hash of its SubjectPublicKeyInfo).
    pub fn from_cert(cert: &CertificateDer<'_>) -> Result<DeviceId, CertParseError> {
        let parsed =
            webpki::EndEntityCert::try_from(cert).map_err(|e| CertParseError(format!("{e:?}")))?;
        let spki = parsed.subject_public_key_info();
        Ok(DeviceId::from_spki_der(spki.as_ref()))
    }

    /// The first two groups, for logs and narrow tables (not unique enough to
    /// identify a device on its own; use the full ID for trust decisions).
    pub fn short(&self) -> String {
        let full = self.to_string();
        full[..2 * GROUP_LEN + 1].to_string()
    }

    /// Lowercase hex of the 32 bytes (for file names and debugging).
    pub fn to_hex(&self) -> String {
        data_encoding::HEXLOWER.encode(&self.0)
    }
}

fn value_of(c: u8) -> Option<u8> {
    match c {
        b'A'..=b'Z' => Some(c - b'A'),
        b'2'..=b'7' => Some(c - b'2' + 26),
        _ => None,
    }
}

/// Luhn mod 32 check value for a sequence of code points (0..32).
fn luhn32(values: &[u8]) -> u8 {
    let n = 32u32;
    let mut factor = 2u32;
    let mut sum = 0u32;
    for &v in values.iter().rev() {
        let mut addend = factor * u32::from(v);
        factor = if factor == 2 { 1 } else { 2 };
        addend = addend / n + addend % n;
        sum += addend;
    }
    ((n - sum % n) % n) as u8
}

impl fmt::Display for DeviceId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let data = data_encoding::BASE32_NOPAD.encode(&self.0);
        debug_assert_eq!(data.len(), GROUPS * DATA_PER_GROUP);
        let mut out = String::with_capacity(TEXT_LEN);
        for (i, chunk) in data.as_bytes().chunks(DATA_PER_GROUP).enumerate() {
            if i > 0 {
                out.push('-');
            }
            let values: Vec<u8> = chunk.iter().map(|&c| value_of(c).unwrap_or(0)).collect();
            out.push_str(core::str::from_utf8(chunk).unwrap_or("????"));
            out.push(ALPHABET[usize::from(luhn32(&values))] as char);
        }
        f.write_str(&out)
    }
}

impl fmt::Debug for DeviceId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "DeviceId({self})")
    }
}

impl FromStr for DeviceId {
    type Err = DeviceIdError;

    fn from_str(s: &str) -> Result<DeviceId, DeviceIdError> {
        let cleaned: Vec<char> = s
            .chars()
            .filter(|c| !c.is_whitespace() && *c != '-')
            .map(|c| match c.to_ascii_uppercase() {
                '0' => 'O',
                '1' => 'I',
                '8' => 'B',
                other => other,
            })
            .collect();
        let expected = GROUPS * GROUP_LEN;
        if cleaned.len() != expected {
            return Err(DeviceIdError::Length {
                expected,
                got: cleaned.len(),
            });
        }
        let mut data = String::with_capacity(GROUPS * DATA_PER_GROUP);
        for (g, group) in cleaned.chunks(GROUP_LEN).enumerate() {
            let mut values = [0u8; GROUP_LEN];
            for (v, &ch) in values.iter_mut().zip(group) {
                *v = u8::try_from(ch)
                    .ok()
                    .and_then(value_of)
                    .ok_or(DeviceIdError::BadChar { ch, group: g + 1 })?;
            }
            if luhn32(&values[..DATA_PER_GROUP]) != values[DATA_PER_GROUP] {
                return Err(DeviceIdError::Checksum {
                    group: g + 1,
                    text: group.iter().collect(),
                });
            }
            data.extend(&group[..DATA_PER_GROUP]);
        }
        let bytes = data_encoding::BASE32_NOPAD
            .decode(data.as_bytes())
            .map_err(|_| DeviceIdError::Trailing {
                group: GROUPS,
                text: cleaned[(GROUPS - 1) * GROUP_LEN..].iter().collect(),
            })?;
        let arr: [u8; 32] = bytes.try_into().map_err(|_| DeviceIdError::Trailing {
            group: GROUPS,
            text: cleaned[(GROUPS - 1) * GROUP_LEN..].iter().collect(),
        })?;
        Ok(DeviceId(arr))
    }
}

impl Serialize for DeviceId {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        serializer.collect_str(self)
    }
}

impl<'de> Deserialize<'de> for DeviceId {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<DeviceId, D::Error> {
        let s = String::deserialize(deserializer)?;
        s.parse().map_err(serde::de::Error::custom)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luhn32_matches_reference_definition() {
        // A group followed by its check character validates to 0 when the
        // check character is included and the factors restart at 1.
        for a in 0..32u8 {
            for b in [0u8, 5, 17, 31] {
                let vals = [a, b, 3, 30];
                let c = luhn32(&vals);
                let mut sum = 0u32;
                let mut factor = 1u32;
                for &v in [a, b, 3, 30, c].iter().rev() {
                    let addend = factor * u32::from(v);
                    factor = if factor == 2 { 1 } else { 2 };
                    sum += addend / 32 + addend % 32;
                }
                assert_eq!(sum % 32, 0);
            }
        }
    }

    #[test]
    fn text_form_has_expected_shape() {
        let id = DeviceId::from_bytes([0xAB; 32]);
        let s = id.to_string();
        assert_eq!(s.len(), TEXT_LEN);
        assert_eq!(s.split('-').count(), GROUPS);
        assert!(s.split('-').all(|g| g.len() == GROUP_LEN));
        assert_eq!(id.short().len(), 11);
        assert!(s.starts_with(&id.short()));
    }
}
