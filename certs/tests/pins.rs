//! The pin set: shared between clones (the link's handshake gate sees
//! pairings and unpairings made later) and reloaded from the trust store.
use telextiles_certs::{Identity, PeerRecord, PinSet, TrustStore};

#[test]
fn pin_set_changes_are_seen_by_every_clone() {
    let (a, b) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let pins = PinSet::new([a.device_id()]);
    let gate = pins.clone();
    assert!(gate.contains(&a.device_id()));
    assert!(!gate.contains(&b.device_id()));
    assert!(pins.insert(b.device_id()));
    assert!(!pins.insert(b.device_id()), "already pinned");
    assert!(gate.contains(&b.device_id()));
    assert!(pins.remove(&a.device_id()));
    assert!(!gate.contains(&a.device_id()));
    assert_eq!(gate.snapshot(), vec![b.device_id()]);
}

#[test]
fn pin_set_reloads_from_the_trust_store() {
    let (a, b) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let tmp = tempfile::tempdir().unwrap();
    let pins = PinSet::new([a.device_id()]);
    pins.reload(tmp.path()).unwrap();
    assert!(pins.snapshot().is_empty());
    TrustStore::update(tmp.path(), |s| {
        let r = PeerRecord::new(b.peer_key(), "b", std::time::SystemTime::now());
        (true, s.insert(r))
    })
    .unwrap();
    pins.reload(tmp.path()).unwrap();
    assert_eq!(pins.snapshot(), vec![b.device_id()]);
}
