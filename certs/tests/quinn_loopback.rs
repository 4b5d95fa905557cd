//! Real QUIC (quinn on 127.0.0.1) with the certs configs: pairing over a
//! stream with the PAKE state machine, then pinned reconnection; a third
//! identity and a wrong code are refused.
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::{Instant, SystemTime};

use quinn::crypto::rustls::{QuicClientConfig, QuicServerConfig};
use rand::rngs::OsRng;
use rustls::pki_types::CertificateDer;
use telextiles_certs::{
    client_config, peer_device_id, server_config, CodeOffer, Identity, PairingCode, PairingError,
    PairingMessage, PairingRole, PairingSession, PairingStep, PeerPolicy, PeerRecord, PinSet,
    TrustStore, DEFAULT_CODE_TTL, SERVER_NAME,
};

fn server_endpoint(me: &Identity, policy: PeerPolicy) -> quinn::Endpoint {
    let crypto = QuicServerConfig::try_from(server_config(me, policy).unwrap()).unwrap();
    let cfg = quinn::ServerConfig::with_crypto(Arc::new(crypto));
    quinn::Endpoint::server(cfg, "127.0.0.1:0".parse().unwrap()).unwrap()
}

fn client_endpoint(me: &Identity, policy: PeerPolicy) -> quinn::Endpoint {
    let crypto = QuicClientConfig::try_from(client_config(me, policy).unwrap()).unwrap();
    let mut ep = quinn::Endpoint::client("127.0.0.1:0".parse().unwrap()).unwrap();
    ep.set_default_client_config(quinn::ClientConfig::new(Arc::new(crypto)));
    ep
}

fn peer_cert(conn: &quinn::Connection) -> CertificateDer<'static> {
    let certs = conn
        .peer_identity()
        .unwrap()
        .downcast::<Vec<CertificateDer<'static>>>()
        .unwrap();
    certs[0].clone()
}

fn cfg() -> impl bincode::config::Config {
    bincode::config::standard().with_limit::<4096>()
}

async fn send(s: &mut quinn::SendStream, m: &PairingMessage) {
    let bytes = bincode::serde::encode_to_vec(m, cfg()).unwrap();
    s.write_all(&(bytes.len() as u32).to_be_bytes())
        .await
        .unwrap();
    s.write_all(&bytes).await.unwrap();
}

async fn recv(r: &mut quinn::RecvStream) -> PairingMessage {
    let mut len = [0u8; 4];
    r.read_exact(&mut len).await.unwrap();
    let mut buf = vec![0u8; u32::from_be_bytes(len) as usize];
    assert!(buf.len() <= 4096);
    r.read_exact(&mut buf).await.unwrap();
    bincode::serde::decode_from_slice(&buf, cfg()).unwrap().0
}

/// Runs one side of pairing over a bidirectional stream.
async fn pair_over(
    me: &Identity,
    conn: &quinn::Connection,
    role: PairingRole,
    code: PairingCode,
    opens: bool,
) -> Result<telextiles_certs::Paired, PairingError> {
    let peer = peer_cert(conn);
    let (mut tx, mut rx) = if opens {
        conn.open_bi().await.unwrap()
    } else {
        conn.accept_bi().await.unwrap()
    };
    let (mut session, start) =
        PairingSession::start(role, code, me.cert_der(), &peer, &mut OsRng).unwrap();
    send(&mut tx, &start).await;
    loop {
        let msg = recv(&mut rx).await;
        match session.handle(&msg)? {
            PairingStep::Send(m) => send(&mut tx, &m).await,
            PairingStep::Paired(p) => {
                tx.finish().unwrap();
                return Ok(p);
            }
        }
    }
}

async fn pairing_round(
    a: &Identity,
    b: &Identity,
    shown: PairingCode,
    typed: PairingCode,
) -> (
    Result<telextiles_certs::Paired, PairingError>,
    Result<telextiles_certs::Paired, PairingError>,
    quinn::Endpoint,
    SocketAddr,
) {
    let server = server_endpoint(a, PeerPolicy::AnyForPairing);
    let addr = server.local_addr().unwrap();
    let client = client_endpoint(b, PeerPolicy::AnyForPairing);
    let a2 = a.clone();
    let srv = server.clone();
    let server_side = tokio::spawn(async move {
        let conn = srv.accept().await.unwrap().await.unwrap();
        let r = pair_over(&a2, &conn, PairingRole::ShowsCode, shown, false).await;
        // Hand the connection back so it stays open until both sides are done.
        (r, conn)
    });
    let conn = client.connect(addr, SERVER_NAME).unwrap().await.unwrap();
    let rb = pair_over(b, &conn, PairingRole::EntersCode, typed, true).await;
    let (ra, server_conn) = server_side.await.unwrap();
    conn.close(0u32.into(), b"done");
    server_conn.close(0u32.into(), b"done");
    (ra, rb, server, addr)
}

#[tokio::test]
async fn pair_over_quic_then_reconnect_pinned_and_refuse_a_stranger() {
    let a = Identity::generate().unwrap();
    let b = Identity::generate().unwrap();
    let c = Identity::generate().unwrap();
    let (dir_a, dir_b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());

    let mut offer = CodeOffer::new(&mut OsRng, Instant::now(), DEFAULT_CODE_TTL);
    let typed: PairingCode = offer.display().parse().unwrap();
    let shown = offer.take(Instant::now()).unwrap();
    let (ra, rb, server, addr) = pairing_round(&a, &b, shown, typed).await;
    let (pa, pb) = (ra.unwrap(), rb.unwrap());
    assert_eq!(pa.peer_id, b.device_id());
    assert_eq!(pb.peer_id, a.device_id());
    assert_eq!(pa.verification, pb.verification);

    // Both pin each other in their trust stores.
    for (dir, p, name) in [(&dir_a, &pa, "b"), (&dir_b, &pb, "a")] {
        TrustStore::update(dir.path(), |s| {
            let rec = PeerRecord::new(p.peer_cert.clone(), name, SystemTime::now()).unwrap();
            (true, s.insert(rec))
        })
        .unwrap();
    }
    let store_a = TrustStore::load(dir_a.path()).unwrap();
    let pins_a = PinSet::from_store(&store_a);
    assert!(pins_a.contains(&b.device_id()));

    // The server switches to pinned mode; b reconnects expecting a.
    let crypto =
        QuicServerConfig::try_from(server_config(&a, PeerPolicy::Pinned(pins_a.clone())).unwrap())
            .unwrap();
    server.set_server_config(Some(quinn::ServerConfig::with_crypto(Arc::new(crypto))));
    let srv = server.clone();
    let accept = tokio::spawn(async move {
        let mut results = Vec::new();
        for _ in 0..2 {
            let incoming = srv.accept().await.unwrap();
            match incoming.await {
                Ok(conn) => {
                    let id = peer_device_id(&[peer_cert(&conn)]).unwrap();
                    let (mut tx, mut rx) = conn.accept_bi().await.unwrap();
                    let msg = rx.read_to_end(64).await.unwrap();
                    tx.write_all(&msg).await.unwrap();
                    tx.finish().unwrap();
                    let _ = conn.closed().await;
                    results.push(Ok(id));
                }
                Err(e) => results.push(Err(e.to_string())),
            }
        }
        results
    });

    let store_b = TrustStore::load(dir_b.path()).unwrap();
    let a_id = store_b.peers()[0].device_id;
    let client = client_endpoint(&b, PeerPolicy::Expect(a_id));
    let conn = client.connect(addr, SERVER_NAME).unwrap().await.unwrap();
    let (mut tx, mut rx) = conn.open_bi().await.unwrap();
    tx.write_all(b"press").await.unwrap();
    tx.finish().unwrap();
    assert_eq!(rx.read_to_end(64).await.unwrap(), b"press");
    conn.close(0u32.into(), b"bye");

    // A third identity is refused; it learns on its first read at the latest.
    let stranger = client_endpoint(&c, PeerPolicy::AnyForPairing);
    let refused = match stranger.connect(addr, SERVER_NAME).unwrap().await {
        Err(_) => true,
        Ok(conn) => match conn.open_bi().await {
            Err(_) => true,
            Ok((mut tx, mut rx)) => {
                let _ = tx.write_all(b"hi").await;
                let _ = tx.finish();
                rx.read_to_end(64).await.is_err()
            }
        },
    };
    assert!(refused);
    let results = accept.await.unwrap();
    assert_eq!(results[0], Ok(b.device_id()));
    let err = results[1].as_ref().unwrap_err();
    assert!(
        err.contains("not paired") || err.contains("certificate"),
        "{err}"
    );
}

#[tokio::test]
async fn wrong_code_over_quic_fails_on_both_sides() {
    let a = Identity::generate().unwrap();
    let b = Identity::generate().unwrap();
    let shown = PairingCode::generate(&mut OsRng);
    let mut typed = PairingCode::generate(&mut OsRng);
    while typed == shown {
        typed = PairingCode::generate(&mut OsRng);
    }
    let (ra, rb, _server, _) = pairing_round(&a, &b, shown, typed).await;
    assert_eq!(ra.unwrap_err(), PairingError::WrongCode);
    assert_eq!(rb.unwrap_err(), PairingError::WrongCode);
}
