//! Real QUIC over 127.0.0.1 (no root needed): paired streaming both ways,
//! hello mismatch, an unpaired third device refused, pairing with the right
//! and a wrong code, reconnect after the peer restarts.
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use telextiles_certs::{CodeOffer, Identity, PairingCode, PinSet, DEFAULT_CODE_TTL};
use telextiles_link::{
    now_us, ErrorKind, HelloInfo, Link, LinkConfig, LinkEvent, LinkHandle, PairingMode, PeerAddr,
    Timing,
};
use telextiles_proto::peer::Control;
use tokio::sync::mpsc::Receiver;

fn hello() -> HelloInfo {
    HelloInfo {
        encoder_hash: "e".repeat(64),
        index_fingerprint: "f".repeat(64),
        embedding_dim: 512,
    }
}

fn loopback() -> SocketAddr {
    "127.0.0.1:0".parse().unwrap()
}

fn config(name: &str) -> LinkConfig {
    let mut c = LinkConfig::new(name, loopback(), hello());
    c.timing = Timing {
        keep_alive: Duration::from_millis(200),
        idle_timeout: Duration::from_millis(1500),
        backoff_min: Duration::from_millis(50),
        backoff_max: Duration::from_millis(500),
        ping_interval: Duration::from_millis(100),
        handshake_timeout: Duration::from_secs(5),
        connect_timeout: Duration::from_millis(500),
    };
    c
}

async fn start(
    cfg: LinkConfig,
    id: &Identity,
    pins: &[&Identity],
) -> (LinkHandle, Receiver<LinkEvent>) {
    let pins = PinSet::new(pins.iter().map(|i| i.device_id()));
    let (h, mut rx) = Link::start(cfg, id.clone(), pins).await.unwrap();
    match rx.recv().await {
        Some(LinkEvent::Listening { .. }) => {}
        other => panic!("expected Listening, got {other:?}"),
    }
    (h, rx)
}

/// Waits for the first event matching `f`, failing after `secs`.
async fn wait_for<T>(
    rx: &mut Receiver<LinkEvent>,
    secs: u64,
    what: &str,
    mut f: impl FnMut(&LinkEvent) -> Option<T>,
) -> T {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(secs);
    let mut seen = Vec::new();
    loop {
        match tokio::time::timeout_at(deadline, rx.recv()).await {
            Ok(Some(ev)) => {
                if let Some(t) = f(&ev) {
                    return t;
                }
                if !matches!(ev, LinkEvent::Latent(_)) {
                    seen.push(format!("{ev:?}"));
                }
            }
            Ok(None) => panic!("event channel closed waiting for {what}; saw {seen:#?}"),
            Err(_) => panic!("timed out waiting for {what}; saw {seen:#?}"),
        }
    }
}

fn unit(seed: u32) -> Vec<f32> {
    let v: Vec<f32> = (0..512)
        .map(|i| {
            (((i as u32).wrapping_mul(2654435761) ^ seed.wrapping_mul(40503)) % 1000) as f32 / 500.0
                - 1.0
        })
        .collect();
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.into_iter().map(|x| x / n).collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn paired_peers_stream_both_ways_with_latency_estimate() {
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let (a, mut ra) = start(config("alice"), &ia, &[&ib]).await;
    let mut cb = config("bob");
    cb.connect = vec![PeerAddr::at(a.peer_key(), a.local_addr())];
    let (b, mut rb) = start(cb, &ib, &[&ia]).await;

    let up_a = wait_for(&mut ra, 10, "PeerUp on a", |e| match e {
        LinkEvent::PeerUp { peer, name, .. } => Some((*peer, name.clone())),
        _ => None,
    })
    .await;
    assert_eq!(up_a, (ib.device_id(), "bob".to_string()));
    wait_for(&mut rb, 10, "PeerUp on b", |e| match e {
        LinkEvent::PeerUp { peer, .. } if *peer == ia.device_id() => Some(()),
        _ => None,
    })
    .await;
    // Let a few pings pass so the clock estimate exists.
    tokio::time::sleep(Duration::from_millis(400)).await;

    // a -> b latents and control.
    let v = unit(7);
    a.send_control(Control::PressStart {
        press_id: 1,
        capture_us: now_us(),
    })
    .unwrap();
    let mut latencies = Vec::new();
    for _ in 0..20 {
        a.send_latent(1, &v, now_us(), false).unwrap();
        let l = wait_for(&mut rb, 5, "latent on b", |e| match e {
            LinkEvent::Latent(l) => Some(l.clone()),
            _ => None,
        })
        .await;
        assert_eq!(l.peer, ia.device_id());
        assert_eq!(l.press_id, 1);
        let cos: f32 = l.vector.iter().zip(&v).map(|(x, y)| x * y).sum();
        assert!(cos > 0.999, "cosine after quantisation {cos}");
        latencies.push(l.one_way_latency_us.expect("clock offset estimated"));
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    latencies.sort();
    let median = latencies[latencies.len() / 2];
    println!("loopback one-way latency median {median} us, all {latencies:?}");
    assert!(median.abs() < 50_000, "{median}");
    a.send_press_stop(1, Some(&v), now_us()).unwrap();
    let stop = wait_for(&mut rb, 5, "PressStop on b", |e| match e {
        LinkEvent::Control {
            msg:
                Control::PressStop {
                    press_id,
                    final_latent,
                    ..
                },
            ..
        } => Some((*press_id, final_latent.clone())),
        _ => None,
    })
    .await;
    assert_eq!(stop.0, 1);
    assert_eq!(stop.1.unwrap().vector.dim(), 512);

    // b -> a: full duplex.
    let w = unit(9);
    b.send_latent(5, &w, now_us(), true).unwrap();
    let l = wait_for(&mut ra, 5, "latent on a", |e| match e {
        LinkEvent::Latent(l) => Some(l.clone()),
        _ => None,
    })
    .await;
    assert_eq!((l.press_id, l.is_final, l.peer), (5, true, ib.device_id()));

    b.shutdown().await;
    let reason = wait_for(&mut ra, 5, "PeerDown on a", |e| match e {
        LinkEvent::PeerDown { peer, reason } if *peer == ib.device_id() => Some(reason.clone()),
        _ => None,
    })
    .await;
    println!("down reason: {reason}");
    assert!(a.send_latent(1, &v, now_us(), false).is_err());
    a.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hello_mismatch_is_reported_to_both_and_nothing_streams() {
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let (a, mut ra) = start(config("alice"), &ia, &[&ib]).await;
    let mut cb = config("bob");
    cb.hello.encoder_hash = "0".repeat(64);
    cb.connect = vec![PeerAddr::at(a.peer_key(), a.local_addr())];
    let (b, mut rb) = start(cb, &ib, &[&ia]).await;
    for (rx, who) in [(&mut ra, "a"), (&mut rb, "b")] {
        let msg = wait_for(rx, 10, &format!("mismatch error on {who}"), |e| match e {
            LinkEvent::PeerUp { .. } => panic!("{who}: peer up despite mismatch"),
            LinkEvent::Error {
                kind: ErrorKind::Incompatible(_),
                message,
                ..
            } => Some(message.clone()),
            _ => None,
        })
        .await;
        println!("{who}: {msg}");
        assert!(msg.contains("encoder model differs"), "{who}: {msg}");
    }
    assert!(a.connected_peers().is_empty() && b.connected_peers().is_empty());
    a.shutdown().await;
    b.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn unpaired_third_device_is_refused_and_told_why() {
    let (ia, ib, ic) = (
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
    );
    let (a, mut ra) = start(config("alice"), &ia, &[&ib]).await;
    // C believes it is paired with A, but A does not know C.
    let mut cc = config("mallory");
    cc.connect = vec![PeerAddr::at(a.peer_key(), a.local_addr())];
    let (c, mut rc) = start(cc, &ic, &[&ia]).await;
    let msg = wait_for(&mut rc, 10, "refusal on c", |e| match e {
        LinkEvent::PeerUp { .. } => panic!("unpaired device got a session"),
        LinkEvent::Error {
            kind: ErrorKind::RefusedByPeer,
            message,
            ..
        } => Some(message.clone()),
        _ => None,
    })
    .await;
    println!("c: {msg}");
    assert!(msg.contains("not paired"), "{msg}");
    let msg = wait_for(&mut ra, 10, "refusal on a", |e| match e {
        LinkEvent::PeerUp { .. } => panic!("a accepted an unpaired device"),
        LinkEvent::Error { message, .. } => Some(message.clone()),
        _ => None,
    })
    .await;
    println!("a: {msg}");
    assert!(msg.contains("refused"), "{msg}");
    assert!(
        msg.contains(&format!("device {} is not paired", ic.device_id())),
        "{msg}"
    );
    assert!(a.connected_peers().is_empty());
    a.shutdown().await;
    c.shutdown().await;
}

async fn pair(code_ok: bool) {
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let dir_a = tempfile::tempdir().unwrap();
    let dir_b = tempfile::tempdir().unwrap();
    let offer = CodeOffer::new(
        &mut rand::rngs::OsRng,
        std::time::Instant::now(),
        DEFAULT_CODE_TTL,
    );
    let shown = offer.display();
    let mut ca = config("alice");
    ca.pairing = Some(PairingMode::Show(offer));
    ca.data_dir = Some(dir_a.path().to_path_buf());
    let (a, mut ra) = start(ca, &ia, &[]).await;
    let typed: PairingCode = if code_ok {
        shown.parse().unwrap()
    } else {
        // A different valid code.
        loop {
            let o = CodeOffer::new(
                &mut rand::rngs::OsRng,
                std::time::Instant::now(),
                DEFAULT_CODE_TTL,
            );
            if o.display() != shown {
                break o.display().parse().unwrap();
            }
        }
    };
    let mut cb = config("bob");
    cb.pairing = Some(PairingMode::Enter(typed));
    cb.connect = vec![PeerAddr::at(a.peer_key(), a.local_addr())];
    cb.data_dir = Some(dir_b.path().to_path_buf());
    let (b, mut rb) = start(cb, &ib, &[]).await;
    if code_ok {
        let va = wait_for(&mut ra, 10, "Paired on a", |e| match e {
            LinkEvent::Paired { peer, verification } => Some((*peer, *verification)),
            _ => None,
        })
        .await;
        let vb = wait_for(&mut rb, 10, "Paired on b", |e| match e {
            LinkEvent::Paired { peer, verification } => Some((*peer, *verification)),
            _ => None,
        })
        .await;
        assert_eq!(va.0, ib.device_id());
        assert_eq!(vb.0, ia.device_id());
        assert_eq!(va.1, vb.1, "both users see the same verification string");
        // Straight into the live session.
        for rx in [&mut ra, &mut rb] {
            wait_for(rx, 10, "PeerUp after pairing", |e| match e {
                LinkEvent::PeerUp { .. } => Some(()),
                _ => None,
            })
            .await;
        }
        // Both trust stores now hold the peer, with its address and name.
        tokio::time::sleep(Duration::from_millis(200)).await;
        let sa = telextiles_certs::TrustStore::load(dir_a.path()).unwrap();
        let rec = sa.get(&ib.device_id()).expect("a stored b");
        assert_eq!(rec.name, "bob");
        assert_eq!(rec.last_addresses, vec![b.local_addr()]);
        let sb = telextiles_certs::TrustStore::load(dir_b.path()).unwrap();
        assert!(sb.contains(&ia.device_id()));
    } else {
        // a shows the code: its pairing ends (the code is used up). b
        // enters it: a failed to prove the code b typed, which ends that
        // attempt only (b keeps looking, see hostile.rs).
        for (rx, who, want) in [
            (&mut ra, "a", ErrorKind::Pairing),
            (&mut rb, "b", ErrorKind::PairingAttempt),
        ] {
            let msg = wait_for(rx, 10, &format!("pairing failure on {who}"), |e| match e {
                LinkEvent::Paired { .. } | LinkEvent::PeerUp { .. } => {
                    panic!("{who}: paired with a wrong code")
                }
                LinkEvent::Error { kind, message, .. }
                    if matches!(kind, ErrorKind::Pairing | ErrorKind::PairingAttempt) =>
                {
                    assert_eq!(*kind, want, "{who}: {message}");
                    Some(message.clone())
                }
                _ => None,
            })
            .await;
            println!("{who}: {msg}");
            assert!(msg.contains("did not match"), "{who}: {msg}");
        }
        assert!(telextiles_certs::TrustStore::load(dir_a.path())
            .unwrap()
            .is_empty());
        assert!(telextiles_certs::TrustStore::load(dir_b.path())
            .unwrap()
            .is_empty());
    }
    a.shutdown().await;
    b.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pairing_with_the_right_code_pins_both_and_goes_live() {
    pair(true).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn pairing_with_a_wrong_code_fails_on_both_sides() {
    pair(false).await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reconnects_after_the_peer_restarts() {
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let (b, mut rb) = start(config("bob"), &ib, &[&ia]).await;
    let b_addr = b.local_addr();
    let mut ca = config("alice");
    ca.connect = vec![PeerAddr::at(ib.peer_key(), b_addr)];
    let (a, mut ra) = start(ca, &ia, &[&ib]).await;
    wait_for(&mut ra, 10, "first PeerUp", |e| {
        matches!(e, LinkEvent::PeerUp { .. }).then_some(())
    })
    .await;
    wait_for(&mut rb, 10, "first PeerUp on b", |e| {
        matches!(e, LinkEvent::PeerUp { .. }).then_some(())
    })
    .await;
    b.shutdown().await;
    drop((b, rb));
    let reason = wait_for(&mut ra, 10, "PeerDown", |e| match e {
        LinkEvent::PeerDown { reason, .. } => Some(reason.clone()),
        _ => None,
    })
    .await;
    assert!(reason.ends_with("shut down"), "{reason}");
    // B comes back on the same port after a while. Meanwhile A keeps
    // dialling it (three timed-out attempts at least) without reporting
    // an error: B's going away was already told.
    let away = Instant::now();
    while away.elapsed() < Duration::from_millis(1600) {
        if let Ok(Some(e)) = tokio::time::timeout(Duration::from_millis(100), ra.recv()).await {
            assert!(
                !matches!(e, LinkEvent::Error { .. }),
                "an error while the peer was away: {e:?}"
            );
        }
    }
    let mut cb = config("bob");
    cb.listen = b_addr;
    let t0 = Instant::now();
    let (b2, _rb2) = start(cb, &ib, &[&ia]).await;
    wait_for(&mut ra, 10, "PeerUp after restart", |e| {
        matches!(e, LinkEvent::PeerUp { .. }).then_some(())
    })
    .await;
    let took = t0.elapsed();
    println!("reconnected {took:?} after the peer came back");
    assert!(took < Duration::from_secs(3), "{took:?}");
    a.shutdown().await;
    b2.shutdown().await;
}

/// The link's tasks are owned: a live pair runs accepting, dialing and a
/// connection's tasks on each side; when the last handle of a link goes
/// without a shutdown, every one of them ends and the endpoint's UDP port
/// is free again (before, the accept loop kept the endpoint alive). After a
/// shutdown, no task is left.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_links_tasks_end_with_it() {
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let (a, mut ra) = start(config("alice"), &ia, &[&ib]).await;
    let mut cb = config("bob");
    cb.connect = vec![PeerAddr::at(a.peer_key(), a.local_addr())];
    let (b, mut rb) = start(cb, &ib, &[&ia]).await;
    for (rx, what) in [(&mut ra, "PeerUp on a"), (&mut rb, "PeerUp on b")] {
        wait_for(rx, 10, what, |e| match e {
            LinkEvent::PeerUp { .. } => Some(()),
            _ => None,
        })
        .await;
    }
    assert!(a.tasks() >= 2, "accepting and a connection: {}", a.tasks());
    assert!(b.tasks() >= 2, "dialing and accepting: {}", b.tasks());

    // Dropped without a shutdown (a clone too): its port frees.
    let port = a.local_addr();
    let clone = a.clone();
    drop(a);
    assert!(
        std::net::UdpSocket::bind(port).is_err(),
        "a clone still holds it"
    );
    drop(clone);
    drop(ra);
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        if std::net::UdpSocket::bind(port).is_ok() {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "{port} still bound 5 s after the link's last handle went"
        );
        tokio::time::sleep(Duration::from_millis(20)).await;
    }

    b.shutdown().await;
    assert_eq!(b.tasks(), 0, "tasks left after shutdown");
}
