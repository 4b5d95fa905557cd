//! Writes the committed seed corpora `seeds/<target>/` from real values
//! (the targets barely got past PEM/DER parsing from empty corpora). Run:
//!   FUZZ_WRITE_SEEDS=1 cargo test --release --no-default-features \
//!     --manifest-path certs/fuzz/Cargo.toml --test seeds -- --ignored
use std::path::Path;
use std::time::SystemTime;

use rand::{rngs::StdRng, SeedableRng};
use telextiles_certs::{
    Identity, PairingCode, PairingMessage, PairingRole, PairingSession, PeerRecord, TrustStore,
};

fn write(target: &str, name: &str, bytes: &[u8]) {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("seeds")
        .join(target);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(dir.join(name), bytes).unwrap();
}

#[test]
#[ignore = "writes the seed corpus; run with FUZZ_WRITE_SEEDS=1"]
fn write_seeds() {
    assert!(std::env::var_os("FUZZ_WRITE_SEEDS").is_some());
    let a = Identity::generate().unwrap();
    let b = Identity::generate().unwrap();
    write("certificate", "device-cert.der", a.cert_der());
    write("identity_pem", "identity.pem", a.to_pem().as_bytes());
    write(
        "device_id_text",
        "device-id",
        a.device_id().to_string().as_bytes(),
    );
    let code = PairingCode::generate(&mut StdRng::seed_from_u64(1));
    write(
        "device_id_text",
        "pairing-code",
        code.to_string().as_bytes(),
    );

    let tmp = std::env::temp_dir().join(format!("txc-seeds-{}", std::process::id()));
    std::fs::create_dir_all(&tmp).unwrap();
    let mut store = TrustStore::empty_in(&tmp);
    let mut rec = PeerRecord::new(b.peer_key(), "bob", SystemTime::UNIX_EPOCH);
    rec.last_addresses = vec!["192.0.2.7:4797".parse().unwrap()];
    store.insert(rec);
    store.save().unwrap();
    let json = std::fs::read(TrustStore::path_in(&tmp)).unwrap();
    write("trust_store", "one-peer.json", &json);
    std::fs::remove_dir_all(&tmp).unwrap();

    // pairing_messages: first byte picks the role and the code (as in the
    // target), then bincode messages as a peer would send them.
    let cfg = bincode::config::standard().with_limit::<4096>();
    for first in [0u8, 1] {
        let mut rng = StdRng::seed_from_u64(u64::from(first));
        let code = PairingCode::generate(&mut rng);
        let role = if first & 1 == 0 {
            PairingRole::EntersCode
        } else {
            PairingRole::ShowsCode
        };
        let (_, start) =
            PairingSession::start(role, code, &b.peer_key(), &a.peer_key(), &mut rng).unwrap();
        let mut bytes = vec![first];
        bytes.extend(bincode::serde::encode_to_vec(&start, cfg).unwrap());
        let abort = PairingMessage::Abort(telextiles_certs::pairing::PairingAbort::WrongCode);
        let mut with_abort = bytes.clone();
        with_abort.extend(bincode::serde::encode_to_vec(&abort, cfg).unwrap());
        write("pairing_messages", &format!("start-{first}"), &bytes);
        write(
            "pairing_messages",
            &format!("start-abort-{first}"),
            &with_abort,
        );
    }
}
