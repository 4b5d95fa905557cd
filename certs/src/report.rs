//! Text and JSON views of the identity and the trust store, for
//! `telextilesd id`, `telextilesd peers` and `telextilesd unpair`.
use std::fmt::Write as _;
use std::path::Path;

use serde_json::{json, Value};

use crate::device_id::DeviceId;
use crate::key::PeerKey;
use crate::trust::{PeerRecord, TrustStore};

/// `YYYY-MM-DD HH:MM:SS UTC` for seconds since the Unix epoch.
pub fn format_utc(secs: u64) -> String {
    let (y, mo, d, h, mi, s) = civil(secs);
    format!("{y:04}-{mo:02}-{d:02} {h:02}:{mi:02}:{s:02} UTC")
}

/// RFC 3339 (`YYYY-MM-DDTHH:MM:SSZ`) for seconds since the Unix epoch.
pub fn format_rfc3339(secs: u64) -> String {
    let (y, mo, d, h, mi, s) = civil(secs);
    format!("{y:04}-{mo:02}-{d:02}T{h:02}:{mi:02}:{s:02}Z")
}

/// Calendar date and time (UTC) of a Unix timestamp (Howard Hinnant's
/// days-to-civil algorithm).
fn civil(secs: u64) -> (i64, u32, u32, u64, u64, u64) {
    let days = (secs / 86_400) as i64;
    let rem = secs % 86_400;
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    let y = yoe + era * 400 + i64::from(m <= 2);
    (y, m, d, rem / 3600, rem % 3600 / 60, rem % 60)
}

fn peer_json(p: &PeerRecord) -> Value {
    json!({
        "device_id": p.device_id.to_string(),
        "name": p.name,
        "paired_at": format_rfc3339(p.paired_at),
        "paired_at_unix": p.paired_at,
        "last_seen": p.last_seen.map(format_rfc3339),
        "last_seen_unix": p.last_seen,
        "last_addresses": p.last_addresses.iter().map(|a| a.to_string()).collect::<Vec<_>>(),
    })
}

/// The trust store as JSON: `{"store": path, "peers": [...]}`.
pub fn peers_json(store: &TrustStore) -> Value {
    json!({
        "store": store.path().display().to_string(),
        "peers": store.peers().iter().map(peer_json).collect::<Vec<_>>(),
    })
}

/// One peer as an indented block of text.
pub fn peer_text(p: &PeerRecord) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{}", p.name);
    let _ = writeln!(s, "  device ID  {}", p.device_id);
    let _ = writeln!(s, "  key        {}", p.key);
    let _ = writeln!(s, "  paired     {}", format_utc(p.paired_at));
    let _ = writeln!(
        s,
        "  last seen  {}",
        p.last_seen.map_or_else(|| "never".to_string(), format_utc)
    );
    let addrs = if p.last_addresses.is_empty() {
        "none known".to_string()
    } else {
        p.last_addresses
            .iter()
            .map(|a| a.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let _ = writeln!(s, "  addresses  {addrs}");
    s
}

/// The trust store as text for people.
pub fn peers_text(store: &TrustStore) -> String {
    if store.is_empty() {
        return format!(
            "No paired peers ({}).\nRun `telextilesd pair` on this device and on the other one to pair.\n",
            store.path().display()
        );
    }
    let n = store.len();
    let mut s = format!(
        "{n} paired peer{} ({}):\n",
        if n == 1 { "" } else { "s" },
        store.path().display()
    );
    for p in store.peers() {
        s.push('\n');
        s.push_str(&peer_text(p));
    }
    s
}

/// This device's ID and key as text; mentions a newly created identity.
pub fn identity_text(id: &DeviceId, key: &PeerKey, file: &Path, created: bool) -> String {
    let mut s = format!("This device's ID: {id}\n");
    let _ = writeln!(
        s,
        "This device's key: {key}\n(peers dial it with --connect {key}@HOST:PORT, or {key} alone through a relay)"
    );
    if created {
        let _ = writeln!(s, "(a new identity was created in {})", file.display());
    }
    s
}

/// This device's ID as JSON.
pub fn identity_json(id: &DeviceId, key: &PeerKey, file: &Path, created: bool) -> Value {
    json!({
        "device_id": id.to_string(),
        "key": key.to_string(),
        "identity_file": file.display().to_string(),
        "created": created,
    })
}
