//! Views used by `telextilesd id` / `peers`: dates, text and JSON.
use std::time::{Duration, UNIX_EPOCH};

use telextiles_certs::report::{
    format_rfc3339, format_utc, identity_json, identity_text, peers_json, peers_text,
};
use telextiles_certs::{Identity, PeerRecord, TrustStore};

#[test]
fn dates_are_correct_utc() {
    assert_eq!(format_utc(0), "1970-01-01 00:00:00 UTC");
    assert_eq!(format_rfc3339(951_782_400), "2000-02-29T00:00:00Z");
    assert_eq!(format_rfc3339(1_709_251_199), "2024-02-29T23:59:59Z");
    assert_eq!(format_rfc3339(4_102_444_800), "2100-01-01T00:00:00Z");
    // Cross-check every day boundary over ~3 years against a day counter.
    let mut y = 2023i64;
    let mut m = 1u32;
    let mut d = 1u32;
    let dim = |y: i64, m: u32| match m {
        2 if (y % 4 == 0 && y % 100 != 0) || y % 400 == 0 => 29,
        2 => 28,
        4 | 6 | 9 | 11 => 30,
        _ => 31,
    };
    let start = 1_672_531_200u64; // 2023-01-01
    for day in 0..1200u64 {
        let t = start + day * 86_400 + 3_723;
        assert_eq!(format_rfc3339(t), format!("{y:04}-{m:02}-{d:02}T01:02:03Z"));
        d += 1;
        if d > dim(y, m) {
            d = 1;
            m += 1;
            if m > 12 {
                m = 1;
                y += 1;
            }
        }
    }
}

#[test]
fn peers_text_and_json_show_every_field() {
    let tmp = tempfile::tempdir().unwrap();
    let mut store = TrustStore::empty_in(tmp.path());
    let empty = peers_text(&store);
    assert!(
        empty.contains("No paired peers") && empty.contains("telextilesd pair"),
        "{empty}"
    );
    assert_eq!(peers_json(&store)["peers"].as_array().unwrap().len(), 0);

    let peer = Identity::generate().unwrap();
    let rec = PeerRecord::new(
        peer.peer_key(),
        "kitchen",
        UNIX_EPOCH + Duration::from_secs(1_700_000_000),
    );
    store.insert(rec);
    let text = peers_text(&store);
    assert!(text.starts_with("1 paired peer ("), "{text}");
    assert!(text.contains("kitchen"));
    assert!(text.contains(&peer.device_id().to_string()));
    assert!(text.contains("2023-11-14 22:13:20 UTC"), "{text}");
    assert!(
        text.contains("never") && text.contains("none known"),
        "{text}"
    );

    let addr = "192.0.2.7:47800".parse().unwrap();
    store.note_addresses(
        &peer.device_id(),
        &[addr],
        UNIX_EPOCH + Duration::from_secs(1_700_000_060),
    );
    let text = peers_text(&store);
    assert!(
        text.contains("192.0.2.7:47800") && text.contains("22:14:20"),
        "{text}"
    );

    let j = peers_json(&store);
    let p = &j["peers"][0];
    assert_eq!(p["device_id"], peer.device_id().to_string());
    assert_eq!(p["name"], "kitchen");
    assert_eq!(p["paired_at"], "2023-11-14T22:13:20Z");
    assert_eq!(p["paired_at_unix"], 1_700_000_000u64);
    assert_eq!(p["last_seen_unix"], 1_700_000_060u64);
    assert_eq!(p["last_addresses"][0], "192.0.2.7:47800");
    assert!(j["store"].as_str().unwrap().ends_with("peers.json"));
}

#[test]
fn identity_views() {
    let me = Identity::generate().unwrap();
    let (id, key) = (me.device_id(), me.peer_key());
    let file = std::path::Path::new("/x/identity.pem");
    let t = identity_text(&id, &key, file, true);
    assert!(
        t.contains(&id.to_string()) && t.contains("/x/identity.pem"),
        "{t}"
    );
    assert!(t.contains(&format!("--connect {key}@")), "{t}");
    assert!(!identity_text(&id, &key, file, false).contains("created"));
    let j = identity_json(&id, &key, file, false);
    assert_eq!(j["device_id"], id.to_string());
    assert_eq!(j["key"], key.to_string());
    assert_eq!(j["created"], false);
}
