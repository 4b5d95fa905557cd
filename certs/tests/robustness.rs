//! Every parser of outside input in this crate, fed random and mutated
//! bytes: it must return an error (or a valid value), never panic.
use std::fs;
use std::sync::OnceLock;

use proptest::prelude::*;
use rustls::pki_types::CertificateDer;
use telextiles_certs::{
    DeviceId, Identity, PairingCode, PeerKey, PeerRecord, TrustStore, IDENTITY_FILE, TRUST_FILE,
};

struct Fixture {
    identity: Identity,
    pem: String,
    trust_json: Vec<u8>,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let identity = Identity::generate().unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let mut s = TrustStore::empty_in(tmp.path());
        for name in ["a", "b"] {
            let peer = Identity::generate().unwrap();
            s.insert(PeerRecord::new(
                peer.peer_key(),
                name,
                std::time::SystemTime::now(),
            ));
        }
        s.note_addresses(
            &s.peers()[0].device_id.clone(),
            &["[2001:db8::1]:47800".parse().unwrap()],
            std::time::SystemTime::now(),
        );
        s.save().unwrap();
        Fixture {
            pem: identity.to_pem(),
            identity,
            trust_json: fs::read(tmp.path().join(TRUST_FILE)).unwrap(),
        }
    })
}

fn mutate(base: &[u8], edits: &[(usize, u8)], cut: Option<usize>) -> Vec<u8> {
    let mut v = base.to_vec();
    for &(pos, byte) in edits {
        if !v.is_empty() {
            let i = pos % v.len();
            v[i] = byte;
        }
    }
    if let Some(c) = cut {
        v.truncate(c % (base.len() + 1));
    }
    v
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn certificate_parsing_never_panics(
        edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..6),
        cut in proptest::option::of(any::<usize>()),
        random in proptest::collection::vec(any::<u8>(), 0..300),
    ) {
        let f = fixture();
        let der = mutate(f.identity.cert_der(), &edits, cut);
        for bytes in [der, random] {
            let _ = PeerKey::from_spki_der(&bytes);
            let cert = CertificateDer::from(bytes);
            let id = DeviceId::from_cert(&cert);
            if let Ok(key) = PeerKey::from_cert(&cert) {
                // A key read from a certificate gives the certificate's ID.
                prop_assert_eq!(Some(key.device_id()), id.ok());
            }
        }
    }

    #[test]
    fn identity_pem_parsing_never_panics(
        edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..6),
        cut in proptest::option::of(any::<usize>()),
        text in ".{0,200}",
    ) {
        let f = fixture();
        let bytes = mutate(f.pem.as_bytes(), &edits, cut);
        let _ = Identity::from_pem(&String::from_utf8_lossy(&bytes));
        let _ = Identity::from_pem(&text);
        // Through the file loader too (also covers non-UTF-8).
        let tmp = tempfile::tempdir().unwrap();
        fs::write(tmp.path().join(IDENTITY_FILE), &bytes).unwrap();
        if let Ok(id) = Identity::load(tmp.path()) {
            // Whatever loads must be self-consistent.
            prop_assert_eq!(DeviceId::from_cert(id.cert_der()).unwrap(), id.device_id());
        }
    }

    #[test]
    fn trust_store_loading_never_panics(
        edits in proptest::collection::vec((any::<usize>(), any::<u8>()), 0..6),
        cut in proptest::option::of(any::<usize>()),
    ) {
        let f = fixture();
        let bytes = mutate(&f.trust_json, &edits, cut);
        let tmp = tempfile::tempdir().unwrap();
        fs::write(tmp.path().join(TRUST_FILE), &bytes).unwrap();
        if let Ok(s) = TrustStore::load(tmp.path()) {
            // Whatever loads is consistent: each key hashes to its ID.
            for p in s.peers() {
                prop_assert_eq!(p.key.device_id(), p.device_id);
            }
        }
    }

    #[test]
    fn pairing_code_parsing_never_panics(s in ".{0,40}", digits in "[0-9 -]{0,20}") {
        for t in [s, digits] {
            if let Ok(c) = t.parse::<PairingCode>() {
                // A parsed code prints back to something that parses to it.
                prop_assert_eq!(c.to_string().parse::<PairingCode>().unwrap(), c);
            }
        }
    }
}

/// Peer-supplied names and texts reach terminals and logs: no C0/C1
/// controls (ANSI escapes), no DEL, no bidi overrides or isolates (issue 19:
/// the old `sanitize_name` kept U+202E and friends).
#[test]
fn peer_text_is_cleaned_of_escapes_and_bidi_controls() {
    use telextiles_certs::trust::{is_unsafe_char, sanitize_name, sanitize_text};
    let evil = "\u{1b}[2J\u{1b}]0;owned\u{7}bob\u{9b}31m\u{7f}\u{202e}gpj.exe\u{2066}x\u{200f}";
    for cleaned in [sanitize_name(evil), sanitize_text(evil, 1000)] {
        assert!(
            !cleaned.chars().any(is_unsafe_char),
            "unsafe characters left in {cleaned:?}"
        );
        assert!(
            cleaned.contains("bob") && cleaned.contains("gpj.exe"),
            "{cleaned:?}"
        );
    }
    for c in [
        '\u{1b}', '\u{9b}', '\u{7f}', '\u{202e}', '\u{2067}', '\u{200e}',
    ] {
        assert!(is_unsafe_char(c), "{c:?}");
    }
    assert!(!is_unsafe_char('é') && !is_unsafe_char('a'));
    assert_eq!(sanitize_text("abcdef", 3), "abc");
    assert_eq!(sanitize_name("\u{202e}\u{1b}"), "unnamed");
}
