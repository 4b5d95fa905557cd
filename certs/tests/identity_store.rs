//! Identity and trust store on disk: creation, permissions, reloads, atomic
//! replacement, and clear errors for corrupt files.
use std::fs;
use std::net::SocketAddr;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use telextiles_certs::{
    data_dir_from, write_atomic, DeviceId, Identity, LookupError, PeerRecord, StoreError,
    TrustStore, IDENTITY_FILE, TRUST_FILE,
};

fn mode(p: &Path) -> u32 {
    fs::metadata(p).unwrap().permissions().mode() & 0o777
}

fn t(secs: u64) -> SystemTime {
    UNIX_EPOCH + Duration::from_secs(secs)
}

#[test]
fn identity_is_created_once_with_private_permissions() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("nested").join("telextiles");
    let (a, created) = Identity::load_or_create(&dir).unwrap();
    assert!(created);
    assert_eq!(mode(&dir.join(IDENTITY_FILE)), 0o600);
    assert_eq!(mode(&dir), 0o700);
    let (b, created) = Identity::load_or_create(&dir).unwrap();
    assert!(!created);
    assert_eq!(a.device_id(), b.device_id());
    assert_eq!(a.cert_der(), b.cert_der());
    assert_eq!(DeviceId::from_cert(a.cert_der()).unwrap(), a.device_id());
    // No temporary files are left behind.
    let mut names: Vec<_> = fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    names.sort();
    assert_eq!(
        names,
        vec![telextiles_certs::store::LOCK_FILE, IDENTITY_FILE]
    );
}

#[test]
fn two_identities_differ() {
    let a = Identity::generate().unwrap();
    let b = Identity::generate().unwrap();
    assert_ne!(a.device_id(), b.device_id());
}

#[test]
fn loose_permissions_are_tightened_on_load() {
    let tmp = tempfile::tempdir().unwrap();
    Identity::load_or_create(tmp.path()).unwrap();
    let p = tmp.path().join(IDENTITY_FILE);
    fs::set_permissions(&p, fs::Permissions::from_mode(0o644)).unwrap();
    Identity::load(tmp.path()).unwrap();
    assert_eq!(mode(&p), 0o600);
}

#[test]
fn missing_identity_is_reported_by_load() {
    let tmp = tempfile::tempdir().unwrap();
    let e = Identity::load(tmp.path()).unwrap_err();
    assert!(matches!(e, StoreError::NoIdentity { .. }), "{e}");
}

#[test]
fn corrupt_identity_is_an_error_and_is_never_overwritten() {
    let tmp = tempfile::tempdir().unwrap();
    let (id, _) = Identity::load_or_create(tmp.path()).unwrap();
    let p = tmp.path().join(IDENTITY_FILE);
    let good = fs::read_to_string(&p).unwrap();
    let cases: Vec<(String, &str)> = vec![
        (good[..good.len() / 2].to_string(), "no CERTIFICATE"),
        // Ed25519 OID 1.3.101.112 turned into 1.3.101.113 (Ed448) in the key.
        (
            {
                let (key, cert) = good.split_at(good.find("-----END PRIVATE KEY").unwrap());
                assert!(key.contains("K2Vw"));
                format!("{}{cert}", key.replacen("K2Vw", "K2Vx", 1))
            },
            "private key",
        ),
        ("garbage".into(), "no PRIVATE KEY"),
        // A key with someone else's certificate.
        (
            {
                let other = Identity::generate().unwrap().to_pem();
                let key_end = good.find("-----END PRIVATE KEY-----").unwrap() + 25;
                let cert_start = other.find("-----BEGIN CERTIFICATE-----").unwrap();
                format!("{}\n{}", &good[..key_end], &other[cert_start..])
            },
            "does not belong",
        ),
    ];
    for (content, expect) in cases {
        fs::write(&p, &content).unwrap();
        let e = Identity::load_or_create(tmp.path()).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, StoreError::Corrupt { .. }), "{msg}");
        assert!(msg.contains(expect), "{msg}");
        assert!(msg.contains(IDENTITY_FILE) && msg.contains("pair"), "{msg}");
        assert_eq!(
            fs::read_to_string(&p).unwrap(),
            content,
            "file was replaced"
        );
    }
    fs::write(&p, [0xff, 0xfe, 0x00]).unwrap();
    assert!(Identity::load(tmp.path())
        .unwrap_err()
        .to_string()
        .contains("UTF-8"));
    fs::write(&p, &good).unwrap();
    assert_eq!(
        Identity::load(tmp.path()).unwrap().device_id(),
        id.device_id()
    );
}

#[test]
fn unreadable_identity_path_is_an_io_error_naming_the_path() {
    let tmp = tempfile::tempdir().unwrap();
    fs::create_dir(tmp.path().join(IDENTITY_FILE)).unwrap();
    let e = Identity::load(tmp.path()).unwrap_err();
    assert!(matches!(e, StoreError::Io { .. }), "{e}");
    assert!(e.to_string().contains(IDENTITY_FILE), "{e}");
}

#[test]
fn data_dir_follows_xdg_then_home() {
    let p = |s: &str| Some(PathBuf::from(s));
    assert_eq!(
        data_dir_from(p("/x/data"), p("/home/u")).unwrap(),
        PathBuf::from("/x/data/telextiles")
    );
    // Relative XDG paths are ignored, as the XDG spec says.
    assert_eq!(
        data_dir_from(p("rel"), p("/home/u")).unwrap(),
        PathBuf::from("/home/u/.local/share/telextiles")
    );
    assert!(matches!(
        data_dir_from(None, None),
        Err(StoreError::NoDataDir)
    ));
}

#[test]
fn atomic_write_replaces_whole_file_and_leaves_no_temporaries() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tmp.path().join("f.json");
    write_atomic(&p, b"first version, long content").unwrap();
    write_atomic(&p, b"second").unwrap();
    assert_eq!(fs::read(&p).unwrap(), b"second");
    assert_eq!(mode(&p), 0o600);
    assert_eq!(fs::read_dir(tmp.path()).unwrap().count(), 1);
    // A failed write (target is a directory) keeps nothing half-written.
    let d = tmp.path().join("dir");
    fs::create_dir(&d).unwrap();
    fs::write(d.join("x"), b"x").unwrap();
    assert!(write_atomic(&d, b"data").is_err());
    assert_eq!(fs::read_dir(tmp.path()).unwrap().count(), 2);
}

fn record(name: &str, at: u64) -> PeerRecord {
    let id = Identity::generate().unwrap();
    PeerRecord::new(id.peer_key(), name, t(at))
}

#[test]
fn trust_store_add_list_remove_persist() {
    let tmp = tempfile::tempdir().unwrap();
    let mut s = TrustStore::load(tmp.path()).unwrap();
    assert!(s.is_empty());
    let (a, b) = (record("kitchen", 200), record("studio\u{7}\n", 100));
    assert!(s.insert(a.clone()).is_none());
    assert!(s.insert(b.clone()).is_none());
    s.save().unwrap();
    assert_eq!(mode(&tmp.path().join(TRUST_FILE)), 0o600);

    let mut s2 = TrustStore::load(tmp.path()).unwrap();
    assert_eq!(s2.len(), 2);
    // Oldest pairing first; names sanitised.
    assert_eq!(s2.peers()[0].device_id, b.device_id);
    assert_eq!(s2.peers()[0].name, "studio");
    assert_eq!(s2.peers()[1], a);
    assert!(s2.contains(&a.device_id));
    assert_eq!(s2.remove(&a.device_id).unwrap().name, "kitchen");
    assert!(s2.remove(&a.device_id).is_none());
    s2.save().unwrap();
    let s3 = TrustStore::load(tmp.path()).unwrap();
    assert_eq!(s3.device_ids().collect::<Vec<_>>(), vec![b.device_id]);
}

#[test]
fn last_addresses_are_newest_first_deduplicated_and_capped() {
    let tmp = tempfile::tempdir().unwrap();
    let mut s = TrustStore::empty_in(tmp.path());
    let r = record("p", 1);
    s.insert(r.clone());
    let a = |i: u16| -> SocketAddr { format!("192.0.2.1:{}", 4000 + i).parse().unwrap() };
    for i in 0..10 {
        assert!(s.note_addresses(&r.device_id, &[a(i)], t(1000 + u64::from(i))));
    }
    assert!(s.note_addresses(&r.device_id, &[a(5), a(20)], t(2000)));
    let p = s.get(&r.device_id).unwrap();
    assert_eq!(p.last_addresses[..3], [a(5), a(20), a(9)]);
    assert_eq!(p.last_addresses.len(), 8);
    assert_eq!(p.last_seen, Some(2000));
    assert!(!s.note_addresses(&record("x", 1).device_id, &[a(1)], t(1)));
    // Re-pairing keeps the addresses when the new record has none.
    let again = PeerRecord::new(r.key, "renamed", t(3000));
    let old = s.insert(again).unwrap();
    assert_eq!(old.name, "p");
    assert_eq!(s.get(&r.device_id).unwrap().last_addresses.len(), 8);
    assert_eq!(s.get(&r.device_id).unwrap().name, "renamed");
    s.save().unwrap();
    assert_eq!(TrustStore::load(tmp.path()).unwrap(), s);
}

#[test]
fn update_rereads_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (record("a", 1), record("b", 2));
    let mut stale = TrustStore::load(tmp.path()).unwrap();
    TrustStore::update(tmp.path(), |s| (true, s.insert(a.clone()))).unwrap();
    // Another process adds b through update; a is kept.
    TrustStore::update(tmp.path(), |s| (true, s.insert(b.clone()))).unwrap();
    assert_eq!(TrustStore::load(tmp.path()).unwrap().len(), 2);
    // A stale in-memory store would have dropped a: update avoids that.
    stale.insert(b.clone());
    assert_eq!(stale.len(), 1);
    let removed = TrustStore::update(tmp.path(), |s| {
        let r = s.remove(&a.device_id);
        (r.is_some(), r)
    })
    .unwrap();
    assert!(removed.is_some());
    assert_eq!(TrustStore::load(tmp.path()).unwrap().len(), 1);
}

#[test]
fn corrupt_trust_stores_are_refused_with_reasons() {
    let tmp = tempfile::tempdir().unwrap();
    let mut s = TrustStore::empty_in(tmp.path());
    let (a, b) = (record("a", 1), record("b", 2));
    s.insert(a.clone());
    s.insert(b.clone());
    s.save().unwrap();
    let p = tmp.path().join(TRUST_FILE);
    let good = fs::read_to_string(&p).unwrap();
    let a_id = a.device_id.to_string();
    let b_id = b.device_id.to_string();
    let cases = [
        (good[..good.len() - 10].to_string(), "not a trust store"),
        ("{\"format\": 99, \"peers\": []}".to_string(), "format 99"),
        // Swapped IDs: each key hashes to the other ID.
        (
            good.replace(&a_id, "@@")
                .replace(&b_id, &a_id)
                .replace("@@", &b_id),
            "different device",
        ),
        // Typo in a stored ID.
        (
            good.replacen(&a_id[..1], if &a_id[..1] == "A" { "B" } else { "A" }, 1),
            "typo",
        ),
        (good.replace("\"key\": \"", "\"key\": \"zz"), "hex"),
    ];
    for (content, expect) in cases {
        fs::write(&p, &content).unwrap();
        let e = TrustStore::load(tmp.path()).unwrap_err();
        let msg = e.to_string();
        assert!(matches!(e, StoreError::Corrupt { .. }), "{msg}");
        assert!(msg.contains(expect), "expected {expect:?} in {msg}");
        assert!(msg.contains(TRUST_FILE), "{msg}");
    }
    // Duplicates.
    let file: serde_json::Value = serde_json::from_str(&good).unwrap();
    let mut dup = file.clone();
    let first = dup["peers"][0].clone();
    dup["peers"].as_array_mut().unwrap().push(first);
    fs::write(&p, serde_json::to_string(&dup).unwrap()).unwrap();
    assert!(TrustStore::load(tmp.path())
        .unwrap_err()
        .to_string()
        .contains("twice"));
}

#[test]
fn find_by_full_id_prefix_or_name() {
    let tmp = tempfile::tempdir().unwrap();
    let mut s = TrustStore::empty_in(tmp.path());
    let recs: Vec<PeerRecord> = (0..3).map(|i| record(&format!("peer{i}"), i)).collect();
    for r in &recs {
        s.insert(r.clone());
    }
    let id0 = recs[0].device_id.to_string();
    assert_eq!(s.find(&id0).unwrap().device_id, recs[0].device_id);
    assert_eq!(
        s.find(&id0.to_lowercase().replace('-', ""))
            .unwrap()
            .device_id,
        recs[0].device_id
    );
    // Unique prefix (two groups) and name.
    assert_eq!(s.find(&id0[..11]).unwrap().device_id, recs[0].device_id);
    assert_eq!(s.find("PEER1").unwrap().device_id, recs[1].device_id);
    // A typo in a full ID is reported as such.
    let mut typo: Vec<char> = id0.chars().collect();
    typo[0] = if typo[0] == 'A' { 'B' } else { 'A' };
    let typo: String = typo.into_iter().collect();
    assert!(matches!(s.find(&typo), Err(LookupError::BadId(_))));
    // Valid ID of an unknown device; too short a prefix; nothing.
    let other = Identity::generate().unwrap().device_id().to_string();
    assert!(matches!(s.find(&other), Err(LookupError::NotFound { .. })));
    assert!(matches!(s.find("AB"), Err(LookupError::NotFound { .. })));
    let e = s.find("nobody").unwrap_err();
    assert!(e.to_string().contains("telextilesd peers"), "{e}");
    // Ambiguous name.
    s.insert(record("peer1", 9));
    let e = s.find("peer1").unwrap_err();
    assert!(
        matches!(e, LookupError::Ambiguous { ref matches, .. } if matches.len() == 2),
        "{e}"
    );
}

#[test]
fn concurrent_first_runs_agree_on_one_identity() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("d");
    let ids: Vec<(DeviceId, bool)> = std::thread::scope(|sc| {
        let hs: Vec<_> = (0..8)
            .map(|_| {
                sc.spawn(|| {
                    let (id, created) = Identity::load_or_create(&dir).unwrap();
                    (id.device_id(), created)
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap()).collect()
    });
    assert!(ids.iter().all(|(id, _)| *id == ids[0].0), "{ids:?}");
    assert_eq!(ids.iter().filter(|(_, created)| *created).count(), 1);
    assert_eq!(Identity::load(&dir).unwrap().device_id(), ids[0].0);
}

#[test]
fn concurrent_updates_lose_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let records: Vec<PeerRecord> = (0..12).map(|i| record(&format!("p{i}"), i)).collect();
    std::thread::scope(|sc| {
        for r in &records {
            let dir = tmp.path();
            sc.spawn(move || {
                TrustStore::update(dir, |s| (true, s.insert(r.clone()))).unwrap();
            });
        }
    });
    let s = TrustStore::load(tmp.path()).unwrap();
    assert_eq!(s.len(), records.len());
    for r in &records {
        assert!(s.contains(&r.device_id));
    }
}

/// A trust store of format 1 (the link ran on certificates and kept each
/// peer's) is read: every peer keeps its ID and gets its key from its
/// certificate, and the next write stores format 2 with the keys. Nobody
/// has to pair again.
#[test]
fn a_format_1_store_of_certificates_is_read_and_migrated() {
    use telextiles_certs::PeerKey;
    let tmp = tempfile::tempdir().unwrap();
    let peers: Vec<Identity> = (0..2).map(|_| Identity::generate().unwrap()).collect();
    let records: Vec<serde_json::Value> = peers
        .iter()
        .enumerate()
        .map(|(i, p)| {
            serde_json::json!({
                "device_id": p.device_id().to_string(),
                "name": format!("peer {i}"),
                "cert": data_encoding::BASE64.encode(p.cert_der()),
                "paired_at": 1_700_000_000u64 + i as u64,
                "last_addresses": ["192.0.2.7:4797"],
                "last_seen": 1_700_000_100u64,
            })
        })
        .collect();
    let v1 = serde_json::json!({"format": 1, "peers": records});
    fs::write(
        tmp.path().join(TRUST_FILE),
        serde_json::to_vec_pretty(&v1).unwrap(),
    )
    .unwrap();
    let s = TrustStore::load(tmp.path()).unwrap();
    for p in &peers {
        let r = s.get(&p.device_id()).expect("peer kept");
        assert_eq!(r.key, p.peer_key());
        assert_eq!(r.last_addresses, vec!["192.0.2.7:4797".parse().unwrap()]);
    }
    TrustStore::update(tmp.path(), |_| (true, ())).unwrap();
    let text = fs::read_to_string(tmp.path().join(TRUST_FILE)).unwrap();
    let v2: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v2["format"], 2);
    assert!(!text.contains("\"cert\""), "{text}");
    let again = TrustStore::load(tmp.path()).unwrap();
    assert_eq!(again, s);
    let k: PeerKey = v2["peers"][0]["key"].as_str().unwrap().parse().unwrap();
    assert!(peers.iter().any(|p| p.peer_key() == k));
}
