//! This device's identity: an Ed25519 key and a self-signed certificate,
//! kept in one PEM file (mode 0600) in the data directory.
use std::fmt;
use std::path::{Path, PathBuf};

use rustls::pki_types::{CertificateDer, PrivateKeyDer, PrivatePkcs8KeyDer};

use crate::device_id::DeviceId;
use crate::key::PeerKey;
use crate::store::{self, StoreError};

/// File name of the identity inside the data directory.
pub const IDENTITY_FILE: &str = "identity.pem";
/// DNS name in the certificate's subjectAltName (and the TLS server name the
/// link uses; it is not checked, the key is pinned instead).
pub const CERT_NAME: &str = "telextiles";

const PEM_KEY: &str = "PRIVATE KEY";
const PEM_CERT: &str = "CERTIFICATE";
const CORRUPT_HINT: &str = "Move the file away to make a new identity (then pair this device again), or restore it from a backup";

/// A device's private key and self-signed certificate.
pub struct Identity {
    key: PrivatePkcs8KeyDer<'static>,
    cert: CertificateDer<'static>,
    id: DeviceId,
    /// The certificate's (and the private key's) public key.
    public: PeerKey,
}

impl Clone for Identity {
    fn clone(&self) -> Identity {
        Identity {
            key: self.key.clone_key(),
            cert: self.cert.clone(),
            id: self.id,
            public: self.public,
        }
    }
}

impl fmt::Debug for Identity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Identity")
            .field("device_id", &self.id)
            .finish_non_exhaustive()
    }
}

impl Identity {
    /// Makes a fresh identity in memory (Ed25519 key from the system RNG,
    /// self-signed certificate valid 1975..4096, with CN naming the device
    /// ID). Nothing is written.
    pub fn generate() -> Result<Identity, StoreError> {
        let key = rcgen::KeyPair::generate_for(&rcgen::PKCS_ED25519)
            .map_err(|e| StoreError::Generate(e.to_string()))?;
        let id = DeviceId::from_spki_der(&key.public_key_der());
        let mut params = rcgen::CertificateParams::new(vec![CERT_NAME.to_string()])
            .map_err(|e| StoreError::Generate(e.to_string()))?;
        params
            .distinguished_name
            .push(rcgen::DnType::CommonName, format!("telextiles {id}"));
        let cert = params
            .self_signed(&key)
            .map_err(|e| StoreError::Generate(e.to_string()))?;
        let public =
            PeerKey::from_cert(cert.der()).map_err(|e| StoreError::Generate(e.to_string()))?;
        let identity = Identity {
            key: PrivatePkcs8KeyDer::from(key.serialize_der()),
            cert: cert.der().clone(),
            id,
            public,
        };
        debug_assert_eq!(DeviceId::from_cert(&identity.cert).ok(), Some(id));
        Ok(identity)
    }

    /// Builds an identity from PKCS#8 key and certificate DER, checking that
    /// the certificate carries the key's public half.
    pub fn from_der(key_pkcs8: &[u8], cert: CertificateDer<'static>) -> Result<Identity, String> {
        let key = rcgen::KeyPair::try_from(key_pkcs8)
            .map_err(|e| format!("the private key is unusable ({e})"))?;
        let cert_id = DeviceId::from_cert(&cert).map_err(|e| format!("the certificate: {e}"))?;
        let key_id = DeviceId::from_spki_der(&key.public_key_der());
        if cert_id != key_id {
            return Err("the certificate does not belong to the private key".into());
        }
        let public = PeerKey::from_cert(&cert)
            .map_err(|_| "the key is not an Ed25519 key (the peer link signs with Ed25519)")?;
        let identity = Identity {
            key: PrivatePkcs8KeyDer::from(key.serialize_der()),
            cert,
            id: cert_id,
            public,
        };
        if identity.secret_seed().is_none() {
            return Err("the private key is not an Ed25519 PKCS#8 key".into());
        }
        Ok(identity)
    }

    /// Parses the PEM text written by [`Identity::to_pem`].
    pub fn from_pem(text: &str) -> Result<Identity, String> {
        let blocks = pem::parse_many(text).map_err(|e| format!("not valid PEM ({e})"))?;
        let mut key = None;
        let mut cert = None;
        for b in blocks {
            let slot = match b.tag() {
                PEM_KEY => &mut key,
                PEM_CERT => &mut cert,
                other => return Err(format!("unexpected PEM block {other:?}")),
            };
            if slot.replace(b.into_contents()).is_some() {
                return Err("more than one key or certificate".into());
            }
        }
        let key = key.ok_or("no PRIVATE KEY block")?;
        let cert = cert.ok_or("no CERTIFICATE block")?;
        Identity::from_der(&key, CertificateDer::from(cert))
    }

    /// PEM text: the PKCS#8 private key, then the certificate.
    pub fn to_pem(&self) -> String {
        let blocks = [
            pem::Pem::new(PEM_KEY, self.key.secret_pkcs8_der().to_vec()),
            pem::Pem::new(PEM_CERT, self.cert.to_vec()),
        ];
        pem::encode_many(&blocks)
    }

    /// Path of the identity file in `dir`.
    pub fn path_in(dir: &Path) -> PathBuf {
        dir.join(IDENTITY_FILE)
    }

    /// Loads the identity from `dir`; [`StoreError::NoIdentity`] if there is
    /// none. A file readable by others is tightened to 0600.
    pub fn load(dir: &Path) -> Result<Identity, StoreError> {
        let path = Identity::path_in(dir);
        let bytes = store::read_bounded(&path)?.ok_or_else(|| StoreError::NoIdentity {
            dir: dir.to_path_buf(),
        })?;
        let corrupt = |reason: String| StoreError::Corrupt {
            path: path.clone(),
            reason,
            hint: CORRUPT_HINT,
        };
        let text = String::from_utf8(bytes).map_err(|_| corrupt("not UTF-8 text".into()))?;
        let identity = Identity::from_pem(&text).map_err(corrupt)?;
        store::restrict_permissions(&path)?;
        Ok(identity)
    }

    /// Loads the identity from `dir`, or makes one and stores it (directory
    /// 0700 if created, file 0600, atomic write). Returns whether it was
    /// created. A corrupt file is an error, never silently replaced: the
    /// device's peers have pinned the old key. Creation happens under the
    /// directory lock ([`store::DirLock`]), so concurrent first runs agree
    /// on one identity.
    pub fn load_or_create(dir: &Path) -> Result<(Identity, bool), StoreError> {
        match Identity::load(dir) {
            Err(StoreError::NoIdentity { .. }) => {}
            other => return other.map(|id| (id, false)),
        }
        // Two processes starting at once must not both create one: under
        // the directory lock, look again before creating.
        let _lock = store::DirLock::acquire(dir)?;
        match Identity::load(dir) {
            Ok(id) => Ok((id, false)),
            Err(StoreError::NoIdentity { .. }) => {
                let id = Identity::generate()?;
                store::write_atomic(&Identity::path_in(dir), id.to_pem().as_bytes())?;
                Ok((id, true))
            }
            Err(e) => Err(e),
        }
    }

    /// Writes the identity to `dir` atomically, mode 0600.
    pub fn save(&self, dir: &Path) -> Result<(), StoreError> {
        store::ensure_dir(dir)?;
        store::write_atomic(&Identity::path_in(dir), self.to_pem().as_bytes())
    }

    /// This device's ID.
    pub fn device_id(&self) -> DeviceId {
        self.id
    }

    /// This device's public key: its address on the peer link.
    pub fn peer_key(&self) -> PeerKey {
        self.public
    }

    /// The 32-byte Ed25519 secret seed (RFC 8410 CurvePrivateKey), the
    /// same key as the certificate's: the peer link's endpoint signs with
    /// it. `None` only for a key that is not Ed25519 (never made here).
    pub fn secret_seed(&self) -> Option<[u8; 32]> {
        // PKCS#8 privateKey OCTET STRING (0x04 0x22) wrapping the
        // CurvePrivateKey OCTET STRING (0x04 0x20) of 32 bytes.
        let der = self.key.secret_pkcs8_der();
        let at = der.windows(4).position(|w| w == [0x04, 0x22, 0x04, 0x20])?;
        der.get(at + 4..at + 36)?.try_into().ok()
    }

    /// The self-signed certificate (DER).
    pub fn cert_der(&self) -> &CertificateDer<'static> {
        &self.cert
    }

    /// The private key (PKCS#8 DER) for rustls.
    pub fn private_key_der(&self) -> PrivateKeyDer<'static> {
        PrivateKeyDer::Pkcs8(self.key.clone_key())
    }
}
