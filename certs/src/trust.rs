//! The trust store: peers this device has paired with, kept as JSON in
//! `peers.json` (mode 0600) in the data directory, always replaced
//! atomically.
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use rustls::pki_types::CertificateDer;
use serde::{Deserialize, Serialize};

use crate::device_id::{DeviceId, DeviceIdError, GROUPS, GROUP_LEN};
use crate::key::PeerKey;
use crate::store::{self, StoreError};

/// File name of the trust store inside the data directory.
pub const TRUST_FILE: &str = "peers.json";
/// Format number written in the file.
pub const TRUST_FORMAT: u32 = 2;
/// The format before 2 (peers kept by certificate), still read.
pub const TRUST_FORMAT_CERTS: u32 = 1;
/// How many last-known addresses are remembered per peer.
pub const MAX_ADDRESSES: usize = 8;
/// Longest peer name kept (characters).
pub const MAX_NAME_CHARS: usize = 64;

const CORRUPT_HINT: &str = "Restore it from a backup, or move it away and pair your peers again";

/// One paired peer.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "RecordFile")]
pub struct PeerRecord {
    /// The peer's device ID (hash of `key`).
    pub device_id: DeviceId,
    /// A name for people (sanitised: no control characters, at most
    /// [`MAX_NAME_CHARS`]).
    pub name: String,
    /// The peer's public key as authenticated during pairing: what the
    /// link dials. Stores of format 1 kept the peer's certificate instead;
    /// its key is read from it (the next write stores the key).
    pub key: PeerKey,
    /// When pairing completed, seconds since the Unix epoch.
    pub paired_at: u64,
    /// Addresses the peer was last reached at, newest first.
    #[serde(default)]
    pub last_addresses: Vec<SocketAddr>,
    /// When the peer was last connected, seconds since the Unix epoch.
    #[serde(default)]
    pub last_seen: Option<u64>,
}

/// A record as either format writes it: format 1 with the certificate,
/// format 2 with the key.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RecordFile {
    device_id: DeviceId,
    name: String,
    #[serde(default)]
    key: Option<PeerKey>,
    #[serde(default, with = "cert_base64")]
    cert: Option<CertificateDer<'static>>,
    paired_at: u64,
    #[serde(default)]
    last_addresses: Vec<SocketAddr>,
    #[serde(default)]
    last_seen: Option<u64>,
}

impl TryFrom<RecordFile> for PeerRecord {
    type Error = String;

    fn try_from(r: RecordFile) -> Result<PeerRecord, String> {
        let key = match (r.key, r.cert) {
            (Some(k), _) => k,
            (None, Some(cert)) => {
                PeerKey::from_cert(&cert).map_err(|e| format!("peer {}: {e}", r.device_id))?
            }
            (None, None) => {
                return Err(format!("peer {}: neither key nor certificate", r.device_id))
            }
        };
        Ok(PeerRecord {
            device_id: r.device_id,
            name: r.name,
            key,
            paired_at: r.paired_at,
            last_addresses: r.last_addresses,
            last_seen: r.last_seen,
        })
    }
}

/// Seconds since the Unix epoch (0 for times before it).
pub fn unix_seconds(t: SystemTime) -> u64 {
    t.duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs())
}

/// `SystemTime` from seconds since the Unix epoch.
pub fn from_unix_seconds(s: u64) -> SystemTime {
    UNIX_EPOCH + Duration::from_secs(s)
}

/// Whether `c` must not reach a terminal from a peer: control characters
/// (C0, DEL, C1: ANSI escape sequences start with ESC or CSI) and the
/// Unicode bidirectional overrides and isolates, which can make printed
/// text read differently from what it is.
pub fn is_unsafe_char(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

/// Cleans peer-supplied text before it is printed or logged: every
/// [`is_unsafe_char`] becomes a space and at most `max_chars` characters
/// are kept.
pub fn sanitize_text(text: &str, max_chars: usize) -> String {
    text.chars()
        .map(|c| if is_unsafe_char(c) { ' ' } else { c })
        .take(max_chars)
        .collect()
}

/// Cleans a peer-supplied name: control characters and bidi overrides
/// become spaces, outer whitespace is trimmed, length is capped; empty
/// becomes `"unnamed"`.
pub fn sanitize_name(name: &str) -> String {
    let cleaned = sanitize_text(name, MAX_NAME_CHARS);
    let trimmed = cleaned.trim();
    if trimmed.is_empty() {
        "unnamed".into()
    } else {
        trimmed.into()
    }
}

impl PeerRecord {
    /// A record for a freshly paired peer; the device ID is computed from
    /// the key.
    pub fn new(key: PeerKey, name: &str, paired_at: SystemTime) -> PeerRecord {
        PeerRecord {
            device_id: key.device_id(),
            name: sanitize_name(name),
            key,
            paired_at: unix_seconds(paired_at),
            last_addresses: Vec::new(),
            last_seen: None,
        }
    }

    fn check(&self) -> Result<(), String> {
        let actual = self.key.device_id();
        if actual != self.device_id {
            return Err(format!(
                "peer {}: its key belongs to a different device ({actual})",
                self.device_id
            ));
        }
        Ok(())
    }
}

mod cert_base64 {
    use rustls::pki_types::CertificateDer;
    use serde::{Deserialize, Deserializer};

    pub fn deserialize<'de, D: Deserializer<'de>>(
        d: D,
    ) -> Result<Option<CertificateDer<'static>>, D::Error> {
        let Some(text) = Option::<String>::deserialize(d)? else {
            return Ok(None);
        };
        data_encoding::BASE64
            .decode(text.as_bytes())
            .map(|b| Some(CertificateDer::from(b)))
            .map_err(|e| serde::de::Error::custom(format!("certificate is not base64: {e}")))
    }
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct TrustFile {
    format: u32,
    peers: Vec<PeerRecord>,
}

/// Why a peer could not be looked up by what a user typed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LookupError {
    /// The text looks like a full device ID but has a typo.
    #[error(transparent)]
    BadId(#[from] DeviceIdError),
    /// Nothing matches.
    #[error("no paired peer matches {query:?} (`telextilesd peers` lists them)")]
    NotFound { query: String },
    /// Several peers match a prefix or name.
    #[error("{query:?} matches {} paired peers ({}); give more of the device ID", matches.len(), matches.join(", "))]
    Ambiguous { query: String, matches: Vec<String> },
}

/// The paired peers, with the file they came from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TrustStore {
    path: PathBuf,
    peers: Vec<PeerRecord>,
}

impl TrustStore {
    /// Path of the trust store file in `dir`.
    pub fn path_in(dir: &Path) -> PathBuf {
        dir.join(TRUST_FILE)
    }

    /// An empty store that [`save`](Self::save)s to `dir`.
    pub fn empty_in(dir: &Path) -> TrustStore {
        TrustStore {
            path: TrustStore::path_in(dir),
            peers: Vec::new(),
        }
    }

    /// Loads the store from `dir`; an absent file is an empty store. A file
    /// that does not parse, or whose records are inconsistent (a certificate
    /// that does not hash to its device ID, duplicates), is
    /// [`StoreError::Corrupt`].
    pub fn load(dir: &Path) -> Result<TrustStore, StoreError> {
        let path = TrustStore::path_in(dir);
        let Some(bytes) = store::read_bounded(&path)? else {
            return Ok(TrustStore::empty_in(dir));
        };
        let s = TrustStore::parse(dir, &bytes)?;
        store::restrict_permissions(&path)?;
        Ok(s)
    }

    /// Parses the content of a trust store file (no I/O); `dir` is where it
    /// came from and where [`save`](Self::save) writes. Same checks and
    /// errors as [`load`](Self::load).
    pub fn parse(dir: &Path, bytes: &[u8]) -> Result<TrustStore, StoreError> {
        let path = TrustStore::path_in(dir);
        let corrupt = |reason: String| StoreError::Corrupt {
            path: path.clone(),
            reason,
            hint: CORRUPT_HINT,
        };
        let file: TrustFile = serde_json::from_slice(bytes)
            .map_err(|e| corrupt(format!("not a trust store ({e})")))?;
        if file.format != TRUST_FORMAT && file.format != TRUST_FORMAT_CERTS {
            return Err(corrupt(format!(
                "format {} is not supported (this program reads format {TRUST_FORMAT})",
                file.format
            )));
        }
        let mut seen = std::collections::BTreeSet::new();
        for p in &file.peers {
            p.check().map_err(&corrupt)?;
            if !seen.insert(p.device_id) {
                return Err(corrupt(format!("peer {} is listed twice", p.device_id)));
            }
        }
        let mut s = TrustStore {
            path,
            peers: file.peers,
        };
        s.sort();
        Ok(s)
    }

    /// Writes the store atomically (temp file, fsync, rename), mode 0600,
    /// under the directory lock. Prefer [`update`](Self::update), which
    /// also re-reads the file first.
    pub fn save(&self) -> Result<(), StoreError> {
        let _lock = store::DirLock::acquire(self.dir())?;
        self.write_file()
    }

    fn dir(&self) -> &Path {
        self.path
            .parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new("."))
    }

    fn write_file(&self) -> Result<(), StoreError> {
        let file = TrustFile {
            format: TRUST_FORMAT,
            peers: self.peers.clone(),
        };
        let mut text = serde_json::to_vec_pretty(&file).map_err(|e| StoreError::Corrupt {
            path: self.path.clone(),
            reason: format!("cannot serialise: {e}"),
            hint: "this is a bug",
        })?;
        text.push(b'\n');
        store::write_atomic(&self.path, &text)
    }

    /// Load, change, save, all under the directory lock
    /// ([`store::DirLock`]): changes made by another process (e.g.
    /// `telextilesd unpair` while the daemon pairs) are never lost. Saves
    /// only if `f` returns `true` in its first field. Do not call `save` or
    /// `update` inside `f`.
    pub fn update<T>(
        dir: &Path,
        f: impl FnOnce(&mut TrustStore) -> (bool, T),
    ) -> Result<T, StoreError> {
        let _lock = store::DirLock::acquire(dir)?;
        let mut s = TrustStore::load(dir)?;
        let (changed, out) = f(&mut s);
        if changed {
            s.write_file()?;
        }
        Ok(out)
    }

    /// The file this store saves to.
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn sort(&mut self) {
        self.peers.sort_by_key(|p| (p.paired_at, p.device_id));
    }

    /// All peers, oldest pairing first.
    pub fn peers(&self) -> &[PeerRecord] {
        &self.peers
    }

    /// Device IDs of all peers.
    pub fn device_ids(&self) -> impl Iterator<Item = DeviceId> + '_ {
        self.peers.iter().map(|p| p.device_id)
    }

    /// Number of peers.
    pub fn len(&self) -> usize {
        self.peers.len()
    }

    /// Whether there are no peers.
    pub fn is_empty(&self) -> bool {
        self.peers.is_empty()
    }

    /// The peer with this ID.
    pub fn get(&self, id: &DeviceId) -> Option<&PeerRecord> {
        self.peers.iter().find(|p| p.device_id == *id)
    }

    /// Whether this ID is paired.
    pub fn contains(&self, id: &DeviceId) -> bool {
        self.get(id).is_some()
    }

    /// Adds or replaces (same device ID) a peer; returns the replaced record.
    /// Addresses already known for the device are kept if the new record
    /// has none.
    pub fn insert(&mut self, mut record: PeerRecord) -> Option<PeerRecord> {
        record.name = sanitize_name(&record.name);
        record.last_addresses.truncate(MAX_ADDRESSES);
        let old = self.remove(&record.device_id);
        if let Some(o) = &old {
            if record.last_addresses.is_empty() {
                record.last_addresses = o.last_addresses.clone();
            }
        }
        self.peers.push(record);
        self.sort();
        old
    }

    /// Removes a peer; returns its record if it was there.
    pub fn remove(&mut self, id: &DeviceId) -> Option<PeerRecord> {
        let i = self.peers.iter().position(|p| p.device_id == *id)?;
        Some(self.peers.remove(i))
    }

    /// Remembers that the peer was reached at `addrs` (most relevant first)
    /// at `seen_at`: they move to the front, duplicates removed, at most
    /// [`MAX_ADDRESSES`] kept. Returns false if the peer is unknown.
    pub fn note_addresses(
        &mut self,
        id: &DeviceId,
        addrs: &[SocketAddr],
        seen_at: SystemTime,
    ) -> bool {
        let Some(p) = self.peers.iter_mut().find(|p| p.device_id == *id) else {
            return false;
        };
        let mut list: Vec<SocketAddr> = Vec::with_capacity(MAX_ADDRESSES);
        for a in addrs.iter().chain(p.last_addresses.iter()) {
            if !list.contains(a) && list.len() < MAX_ADDRESSES {
                list.push(*a);
            }
        }
        p.last_addresses = list;
        p.last_seen = Some(unix_seconds(seen_at));
        true
    }

    /// Finds the peer a user means: a full device ID (typos reported by
    /// group), a unique prefix of at least one group of its ID (dashes and
    /// case ignored), or its exact name (case ignored).
    pub fn find(&self, query: &str) -> Result<&PeerRecord, LookupError> {
        let cleaned = clean_id_text(query);
        let not_found = || LookupError::NotFound {
            query: query.to_string(),
        };
        if cleaned.len() == GROUPS * GROUP_LEN {
            let id: DeviceId = query.parse()?;
            return self.get(&id).ok_or_else(not_found);
        }
        let q = query.trim();
        let mut hits: Vec<&PeerRecord> = Vec::new();
        for p in &self.peers {
            let by_name = !q.is_empty() && p.name.eq_ignore_ascii_case(q);
            let by_prefix = cleaned.len() >= GROUP_LEN
                && clean_id_text(&p.device_id.to_string()).starts_with(&cleaned);
            if by_name || by_prefix {
                hits.push(p);
            }
        }
        match hits.len() {
            0 => Err(not_found()),
            1 => Ok(hits[0]),
            _ => Err(LookupError::Ambiguous {
                query: query.to_string(),
                matches: hits
                    .iter()
                    .map(|p| format!("{} {}", p.device_id.short(), p.name))
                    .collect(),
            }),
        }
    }
}

fn clean_id_text(s: &str) -> String {
    s.chars()
        .filter(|c| !c.is_whitespace() && *c != '-')
        .map(|c| match c.to_ascii_uppercase() {
            '0' => 'O',
            '1' => 'I',
            '8' => 'B',
            o => o,
        })
        .collect()
}
