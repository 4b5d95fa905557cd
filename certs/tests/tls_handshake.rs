//! Real rustls handshakes in memory (ClientConnection and ServerConnection
//! exchanging bytes): pinned peers accepted, unpaired ones refused, and a
//! copied certificate without its private key refused by the handshake
//! signature check.
use std::sync::Arc;

use rustls::client::ResolvesClientCert;
use rustls::pki_types::UnixTime;
use rustls::server::{ClientHello, ResolvesServerCert};
use rustls::sign::CertifiedKey;
use rustls::{
    CertificateError, ClientConfig, ClientConnection, Connection, ServerConfig, ServerConnection,
    SignatureScheme,
};
use telextiles_certs::{
    client_config, peer_device_id, provider, server_config, DeviceId, Identity, PeerPolicy,
    PeerRejected, PeerSide, PeerVerifier, PinSet, ALPN, SERVER_NAME,
};

#[derive(Debug)]
enum Failure {
    Client(rustls::Error),
    Server(rustls::Error),
}

/// Moves all pending TLS bytes from `from` to `to`; returns whether any
/// moved, or the receiver's error.
fn pump(from: &mut Connection, to: &mut Connection) -> Result<bool, rustls::Error> {
    let mut buf = Vec::new();
    while from.wants_write() {
        from.write_tls(&mut buf).unwrap();
    }
    if buf.is_empty() {
        return Ok(false);
    }
    let mut rd = &buf[..];
    while !rd.is_empty() {
        to.read_tls(&mut rd).unwrap();
        to.process_new_packets()?;
    }
    Ok(true)
}

struct Pair {
    client: Connection,
    server: Connection,
}

fn connect(client: ClientConfig, server: ServerConfig) -> (Pair, Result<(), Failure>) {
    let c = ClientConnection::new(Arc::new(client), SERVER_NAME.try_into().unwrap()).unwrap();
    let s = ServerConnection::new(Arc::new(server)).unwrap();
    let mut p = Pair {
        client: Connection::Client(c),
        server: Connection::Server(s),
    };
    let r = (|| {
        for _ in 0..20 {
            let a = pump(&mut p.client, &mut p.server).map_err(Failure::Server)?;
            let b = pump(&mut p.server, &mut p.client).map_err(Failure::Client)?;
            if !a && !b {
                break;
            }
        }
        assert!(!p.client.is_handshaking() && !p.server.is_handshaking());
        Ok(())
    })();
    (p, r)
}

fn ids(p: &Pair) -> (DeviceId, DeviceId) {
    (
        peer_device_id(p.client.peer_certificates().unwrap()).unwrap(),
        peer_device_id(p.server.peer_certificates().unwrap()).unwrap(),
    )
}

fn rejection(e: &rustls::Error) -> PeerRejected {
    PeerRejected::from_rustls(e)
        .unwrap_or_else(|| panic!("not a pinning rejection: {e:?}"))
        .clone()
}

fn is_bad_signature(e: &rustls::Error) -> bool {
    matches!(
        e,
        rustls::Error::InvalidCertificate(CertificateError::BadSignature)
            | rustls::Error::InvalidCertificate(CertificateError::BadEncoding)
    ) || matches!(e, rustls::Error::InvalidCertificate(CertificateError::Other(o)) if o.to_string().contains("Signature"))
}

struct Devices {
    a: Identity,
    b: Identity,
    c: Identity,
}

fn devices() -> Devices {
    Devices {
        a: Identity::generate().unwrap(),
        b: Identity::generate().unwrap(),
        c: Identity::generate().unwrap(),
    }
}

fn pinned(ids: &[&Identity]) -> PeerPolicy {
    PeerPolicy::Pinned(PinSet::new(ids.iter().map(|i| i.device_id())))
}

#[test]
fn paired_peers_complete_mutual_tls_and_exchange_data() {
    let d = devices();
    for client_policy in [pinned(&[&d.a]), PeerPolicy::Expect(d.a.device_id())] {
        let (mut p, r) = connect(
            client_config(&d.b, client_policy).unwrap(),
            server_config(&d.a, pinned(&[&d.b])).unwrap(),
        );
        r.unwrap();
        assert_eq!(ids(&p), (d.a.device_id(), d.b.device_id()));
        assert_eq!(p.client.alpn_protocol(), Some(ALPN));
        assert_eq!(
            p.client.protocol_version(),
            Some(rustls::ProtocolVersion::TLSv1_3)
        );
        // Application data flows.
        use std::io::{Read, Write};
        p.client.writer().write_all(b"hello").unwrap();
        pump(&mut p.client, &mut p.server).unwrap();
        let mut got = [0u8; 5];
        p.server.reader().read_exact(&mut got).unwrap();
        assert_eq!(&got, b"hello");
    }
}

#[test]
fn unpaired_client_is_refused_and_learns_it() {
    let d = devices();
    let (mut p, r) = connect(
        client_config(&d.c, pinned(&[&d.a])).unwrap(),
        server_config(&d.a, pinned(&[&d.b])).unwrap(),
    );
    match r {
        Err(Failure::Server(e)) => {
            assert_eq!(rejection(&e), PeerRejected::NotPaired(d.c.device_id()));
            assert!(rejection(&e).to_string().contains("is not paired"), "{e}");
        }
        other => panic!("{other:?}"),
    }
    // The alert reaches the client (in QUIC, on its first read or write).
    let e = pump(&mut p.server, &mut p.client).unwrap_err();
    assert!(matches!(e, rustls::Error::AlertReceived(_)), "{e:?}");
}

#[test]
fn client_refuses_unpaired_or_unexpected_server() {
    let d = devices();
    let (_, r) = connect(
        client_config(&d.b, pinned(&[&d.a])).unwrap(),
        server_config(&d.c, pinned(&[&d.b])).unwrap(),
    );
    match r {
        Err(Failure::Client(e)) => {
            assert_eq!(rejection(&e), PeerRejected::NotPaired(d.c.device_id()))
        }
        other => panic!("{other:?}"),
    }
    let (_, r) = connect(
        client_config(&d.b, PeerPolicy::Expect(d.a.device_id())).unwrap(),
        // c is paired with b but is not the device b dialled.
        server_config(&d.c, pinned(&[&d.b])).unwrap(),
    );
    match r {
        Err(Failure::Client(e)) => assert_eq!(
            rejection(&e),
            PeerRejected::Unexpected {
                expected: d.a.device_id(),
                got: d.c.device_id()
            }
        ),
        other => panic!("{other:?}"),
    }
}

/// Presents someone else's certificate with its own (wrong) private key.
#[derive(Debug)]
struct Forged(Arc<CertifiedKey>);

fn forged(victim: &Identity, attacker: &Identity) -> Forged {
    let key = provider()
        .key_provider
        .load_private_key(attacker.private_key_der())
        .unwrap();
    Forged(Arc::new(CertifiedKey::new(
        vec![victim.cert_der().clone()],
        key,
    )))
}

impl ResolvesClientCert for Forged {
    fn resolve(&self, _: &[&[u8]], _: &[SignatureScheme]) -> Option<Arc<CertifiedKey>> {
        Some(self.0.clone())
    }
    fn has_certs(&self) -> bool {
        true
    }
}

impl ResolvesServerCert for Forged {
    fn resolve(&self, _: ClientHello<'_>) -> Option<Arc<CertifiedKey>> {
        Some(self.0.clone())
    }
}

fn forged_client(f: Forged, policy: PeerPolicy) -> ClientConfig {
    let mut c = ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .unwrap()
        .dangerous()
        .with_custom_certificate_verifier(Arc::new(PeerVerifier::new(policy)))
        .with_client_cert_resolver(Arc::new(f));
    c.alpn_protocols = vec![ALPN.to_vec()];
    c
}

fn forged_server(f: Forged, policy: PeerPolicy) -> ServerConfig {
    let mut s = ServerConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS13])
        .unwrap()
        .with_client_cert_verifier(Arc::new(PeerVerifier::new(policy)))
        .with_cert_resolver(Arc::new(f));
    s.alpn_protocols = vec![ALPN.to_vec()];
    s
}

#[test]
fn copied_certificate_without_its_key_is_refused_by_the_server() {
    let d = devices();
    for policy in [pinned(&[&d.b]), PeerPolicy::AnyForPairing] {
        // c shows b's (paired) certificate but signs with c's key.
        let (_, r) = connect(
            forged_client(forged(&d.b, &d.c), pinned(&[&d.a])),
            server_config(&d.a, policy).unwrap(),
        );
        match r {
            Err(Failure::Server(e)) => assert!(is_bad_signature(&e), "{e:?}"),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn copied_certificate_without_its_key_is_refused_by_the_client() {
    let d = devices();
    for policy in [
        pinned(&[&d.a]),
        PeerPolicy::Expect(d.a.device_id()),
        PeerPolicy::AnyForPairing,
    ] {
        // c answers with a's certificate but c's key.
        let (_, r) = connect(
            client_config(&d.b, policy).unwrap(),
            forged_server(forged(&d.a, &d.c), pinned(&[&d.b])),
        );
        match r {
            Err(Failure::Client(e)) => assert!(is_bad_signature(&e), "{e:?}"),
            other => panic!("{other:?}"),
        }
    }
}

#[test]
fn honest_forgery_harness_succeeds_with_matching_key() {
    // Guards the two tests above: the same harness with the right key works,
    // so their failures come from the signature check.
    let d = devices();
    let (p, r) = connect(
        forged_client(forged(&d.b, &d.b), pinned(&[&d.a])),
        forged_server(forged(&d.a, &d.a), pinned(&[&d.b])),
    );
    r.unwrap();
    assert_eq!(ids(&p), (d.a.device_id(), d.b.device_id()));
}

#[test]
fn pairing_mode_accepts_strangers_and_exposes_their_certificates() {
    let d = devices();
    let (p, r) = connect(
        client_config(&d.b, PeerPolicy::AnyForPairing).unwrap(),
        server_config(&d.a, PeerPolicy::AnyForPairing).unwrap(),
    );
    r.unwrap();
    assert_eq!(ids(&p), (d.a.device_id(), d.b.device_id()));
    assert_eq!(&p.server.peer_certificates().unwrap()[0], d.b.cert_der());
    assert_eq!(&p.client.peer_certificates().unwrap()[0], d.a.cert_der());
}

#[test]
fn pin_set_changes_apply_to_existing_configs() {
    let d = devices();
    let pins = PinSet::new([]);
    let server = server_config(&d.a, PeerPolicy::Pinned(pins.clone())).unwrap();
    let client = client_config(&d.b, PeerPolicy::Expect(d.a.device_id())).unwrap();
    let (_, r) = connect(client.clone(), server.clone());
    assert!(matches!(r, Err(Failure::Server(_))), "{r:?}");
    assert!(pins.insert(d.b.device_id()));
    let (_, r) = connect(client.clone(), server.clone());
    r.unwrap();
    assert!(pins.remove(&d.b.device_id()));
    let (_, r) = connect(client, server);
    assert!(matches!(r, Err(Failure::Server(_))));
}

#[test]
fn tls12_only_client_is_refused() {
    let d = devices();
    let mut c = ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS12])
        .unwrap()
        .dangerous()
        .with_custom_certificate_verifier(Arc::new(PeerVerifier::new(pinned(&[&d.a]))))
        .with_client_auth_cert(vec![d.b.cert_der().clone()], d.b.private_key_der())
        .unwrap();
    c.alpn_protocols = vec![ALPN.to_vec()];
    let (_, r) = connect(c, server_config(&d.a, pinned(&[&d.b])).unwrap());
    assert!(matches!(r, Err(Failure::Server(_))), "{r:?}");
}

fn now() -> UnixTime {
    UnixTime::since_unix_epoch(std::time::Duration::from_secs(1_800_000_000))
}

#[test]
fn non_certificate_bytes_are_refused_cleanly() {
    let v = PeerVerifier::new(PeerPolicy::AnyForPairing);
    let junk = rustls::pki_types::CertificateDer::from(vec![0x30, 0x82, 0xff]);
    let side = PeerSide::Client;
    assert!(matches!(
        v.check(&junk, &[], side, now()),
        Err(PeerRejected::BadCert(_))
    ));
    let d = devices();
    assert!(matches!(
        v.check(d.a.cert_der(), &[d.b.cert_der().clone()], side, now()),
        Err(PeerRejected::Chain(1))
    ));
    for side in [PeerSide::Client, PeerSide::Server] {
        assert_eq!(
            v.check(d.a.cert_der(), &[], side, now()).unwrap(),
            d.a.device_id()
        );
    }
}

/// A certificate for `key` signed by `issuer` (not self-signed).
fn issued_by(
    key: &rcgen::KeyPair,
    issuer: &rcgen::KeyPair,
) -> rustls::pki_types::CertificateDer<'static> {
    let ca_params = {
        let mut p = rcgen::CertificateParams::new(vec!["issuer".to_string()]).unwrap();
        p.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
        p
    };
    let ca = ca_params.self_signed(issuer).unwrap();
    let params = rcgen::CertificateParams::new(vec![SERVER_NAME.to_string()]).unwrap();
    params.signed_by(key, &ca, issuer).unwrap().der().clone()
}

#[test]
fn pairing_mode_requires_a_valid_self_signature() {
    let key = rcgen::KeyPair::generate_for(&rcgen::PKCS_ED25519).unwrap();
    let issuer = rcgen::KeyPair::generate_for(&rcgen::PKCS_ED25519).unwrap();
    let cert = issued_by(&key, &issuer);
    let id = telextiles_certs::DeviceId::from_cert(&cert).unwrap();
    let any = PeerVerifier::new(PeerPolicy::AnyForPairing);
    for side in [PeerSide::Client, PeerSide::Server] {
        let e = any.check(&cert, &[], side, now()).unwrap_err();
        assert!(matches!(e, PeerRejected::NotSelfSigned(_)), "{e}");
    }
    // The same certificate passes where only the key is pinned.
    let pinned = PeerVerifier::new(PeerPolicy::Expect(id));
    assert_eq!(
        pinned.check(&cert, &[], PeerSide::Server, now()).unwrap(),
        id
    );
    // A self-signed certificate whose signature bytes were altered fails.
    let d = devices();
    let mut bytes = d.a.cert_der().to_vec();
    let n = bytes.len();
    bytes[n - 5] ^= 0x55;
    let broken = rustls::pki_types::CertificateDer::from(bytes);
    assert!(matches!(
        any.check(&broken, &[], PeerSide::Server, now()),
        Err(PeerRejected::NotSelfSigned(_))
    ));
}

#[test]
fn pin_set_reloads_from_the_trust_store() {
    let d = devices();
    let tmp = tempfile::tempdir().unwrap();
    let pins = PinSet::new([d.a.device_id()]);
    pins.reload(tmp.path()).unwrap();
    assert!(pins.snapshot().is_empty());
    telextiles_certs::TrustStore::update(tmp.path(), |s| {
        let r = telextiles_certs::PeerRecord::new(
            d.b.cert_der().clone(),
            "b",
            std::time::SystemTime::now(),
        );
        (true, s.insert(r.unwrap()))
    })
    .unwrap();
    pins.reload(tmp.path()).unwrap();
    assert_eq!(pins.snapshot(), vec![d.b.device_id()]);
}
