//! mDNS in a private network namespace (root needed; without it the test
//! fails, it does not skip): the `pair=1` flag of a device showing a
//! pairing code is withdrawn from its advert as soon as pairing ends; fake
//! `pair=1` advertisers neither block nor end pairing.
//!
//! The outer test makes a namespace whose only interface is its own
//! loopback (multicast enabled), and re-runs this test binary inside it
//! (`ip netns exec`) for the inner test, so no multicast ever leaves it.
use std::process::Command;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

use telextiles_certs::{CodeOffer, Identity, PairingCode, PinSet, DEFAULT_CODE_TTL};
use telextiles_link::discovery::{Discovered, Discovery};
use telextiles_link::{
    DiscoveryConfig, HelloInfo, Link, LinkConfig, LinkEvent, PairingMode, PeerAddr,
};

const INNER_ENV: &str = "TELEXTILES_LINK_IN_NETNS";

fn ip(args: &[&str]) {
    let out = Command::new("ip").args(args).output().expect("run ip");
    assert!(
        out.status.success(),
        "ip {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

struct Netns(String);

impl Drop for Netns {
    fn drop(&mut self) {
        let _ = Command::new("ip").args(["netns", "del", &self.0]).status();
    }
}

/// Runs the ignored test `inner` of this binary inside a fresh namespace.
fn run_inner(inner: &str) {
    let uid = Command::new("id").arg("-u").output().expect("id -u");
    assert_eq!(
        String::from_utf8_lossy(&uid.stdout).trim(),
        "0",
        "this test needs root (it creates a network namespace)"
    );
    let ns = Netns(format!("txl-mdns-{}", std::process::id()));
    ip(&["netns", "add", &ns.0]);
    ip(&["-n", &ns.0, "link", "set", "lo", "up"]);
    ip(&["-n", &ns.0, "link", "set", "lo", "multicast", "on"]);
    ip(&["-n", &ns.0, "route", "add", "224.0.0.0/4", "dev", "lo"]);
    let exe = std::env::current_exe().unwrap();
    let out = Command::new("ip")
        .args(["netns", "exec", &ns.0])
        .arg(exe)
        .args(["--exact", inner, "--ignored", "--nocapture"])
        .env(INNER_ENV, "1")
        .output()
        .expect("run the inner test");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{text}");
    assert!(out.status.success(), "inner test failed:\n{text}");
    assert!(
        text.contains("1 passed"),
        "the inner test did not run:\n{text}"
    );
}

#[test]
fn pairing_flag_is_withdrawn_from_the_advert_once_paired() {
    run_inner("inner_pairing_flag_withdrawn");
}

/// A spoofed `pair=1` advert seen first (pointing at an address where
/// nothing answers) must not keep the device entering a code from pairing
/// with the real one; the old link dialled only the first advertiser.
#[test]
fn a_spoofed_pairing_advert_does_not_block_pairing() {
    run_inner("inner_spoofed_pairing_advert");
}

/// A `pair=1` advertiser that answers the entering side's `Start` with an
/// `Abort` (it proved no code) must not end `pair --enter` and must not be
/// dialled again (the old link failed pairing on the abort; its pairing
/// dial loop redialled after every failure): the mDNS path of
/// `hostile.rs::fake_devices_showing_a_code_neither_end_entering_nor_are_redialled`.
#[test]
fn an_aborting_pairing_advertiser_neither_ends_entering_nor_is_redialled() {
    run_inner("inner_aborting_pairing_advertiser");
}

fn hello() -> HelloInfo {
    HelloInfo {
        encoder_hash: "e".repeat(64),
        index_fingerprint: "f".repeat(64),
        embedding_dim: 512,
    }
}

async fn advert_of(
    rx: &mut tokio::sync::mpsc::Receiver<Discovered>,
    who: &Identity,
    pairing: bool,
    within: Duration,
) {
    let deadline = tokio::time::Instant::now() + within;
    let mut seen = Vec::new();
    loop {
        match tokio::time::timeout_at(deadline, rx.recv()).await {
            Ok(Some(d)) if d.device_id == who.device_id() && d.pairing == pairing => return,
            Ok(Some(d)) => seen.push(d),
            Ok(None) => panic!("browser stopped"),
            Err(_) => panic!("no advert with pair={pairing} within {within:?}; saw {seen:#?}"),
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "run inside a private network namespace by pairing_flag_is_withdrawn_from_the_advert_once_paired"]
async fn inner_pairing_flag_withdrawn() {
    assert!(
        std::env::var_os(INNER_ENV).is_some(),
        "run by the outer test only"
    );
    let (ia, ib, ic) = (
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
    );
    let offer = CodeOffer::new(
        &mut rand::rngs::OsRng,
        std::time::Instant::now(),
        DEFAULT_CODE_TTL,
    );
    let typed: PairingCode = offer.display().parse().unwrap();
    let mut ca = LinkConfig::new("alice", "127.0.0.1:0".parse().unwrap(), hello());
    ca.pairing = Some(PairingMode::Show(offer));
    ca.discovery = Some(DiscoveryConfig::only(&["lo"]));
    let (a, mut ra) = Link::start(ca, ia.clone(), PinSet::default())
        .await
        .unwrap();

    let (_browser, mut found) =
        Discovery::start(&DiscoveryConfig::only(&["lo"]), &ic.peer_key(), 9, false).unwrap();
    advert_of(&mut found, &ia, true, Duration::from_secs(10)).await;

    let mut cb = LinkConfig::new("bob", "127.0.0.1:0".parse().unwrap(), hello());
    cb.pairing = Some(PairingMode::Enter(typed));
    cb.connect = vec![PeerAddr::at(a.peer_key(), a.local_addr())];
    let (b, _rb) = Link::start(cb, ib, PinSet::default()).await.unwrap();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        match tokio::time::timeout_at(deadline, ra.recv()).await {
            Ok(Some(LinkEvent::Paired { .. })) => break,
            Ok(Some(_)) => {}
            other => panic!("alice did not pair: {other:?}"),
        }
    }
    advert_of(&mut found, &ia, false, Duration::from_secs(5)).await;
    println!("pair=1 withdrawn after pairing");
    a.shutdown().await;
    b.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "run inside a private network namespace by a_spoofed_pairing_advert_does_not_block_pairing"]
async fn inner_spoofed_pairing_advert() {
    assert!(
        std::env::var_os(INNER_ENV).is_some(),
        "run by the outer test only"
    );
    let (ia, ib, spoof) = (
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
    );
    let offer = CodeOffer::new(
        &mut rand::rngs::OsRng,
        std::time::Instant::now(),
        DEFAULT_CODE_TTL,
    );
    let typed: PairingCode = offer.display().parse().unwrap();
    // Bob enters the code and browses.
    let mut cb = LinkConfig::new("bob", "127.0.0.1:0".parse().unwrap(), hello());
    cb.pairing = Some(PairingMode::Enter(typed));
    cb.discovery = Some(DiscoveryConfig::only(&["lo"]));
    let (b, mut rb) = Link::start(cb, ib.clone(), PinSet::default())
        .await
        .unwrap();
    // The spoofed advert: a port where nothing answers QUIC.
    let dead = std::net::UdpSocket::bind("127.0.0.1:0").unwrap();
    let (_spoof_advert, _) = Discovery::start(
        &DiscoveryConfig::only(&["lo"]),
        &spoof.peer_key(),
        dead.local_addr().unwrap().port(),
        true,
    )
    .unwrap();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        match tokio::time::timeout_at(deadline, rb.recv()).await {
            Ok(Some(LinkEvent::Discovered { peer, .. })) if peer == spoof.device_id() => break,
            Ok(Some(_)) => {}
            other => panic!("bob did not see the spoofed advert: {other:?}"),
        }
    }
    // Then the real device shows its code.
    let mut ca = LinkConfig::new("alice", "127.0.0.1:0".parse().unwrap(), hello());
    ca.pairing = Some(PairingMode::Show(offer));
    ca.discovery = Some(DiscoveryConfig::only(&["lo"]));
    let (a, _ra) = Link::start(ca, ia.clone(), PinSet::default())
        .await
        .unwrap();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(15);
    loop {
        match tokio::time::timeout_at(deadline, rb.recv()).await {
            Ok(Some(LinkEvent::Paired { peer, .. })) => {
                assert_eq!(peer, ia.device_id());
                break;
            }
            Ok(Some(_)) => {}
            other => panic!("bob did not pair with the real device: {other:?}"),
        }
    }
    println!("paired with the real advertiser despite the spoofed one");
    a.shutdown().await;
    b.shutdown().await;
}

/// An iroh endpoint that accepts any device (like a device
/// showing a code) and answers the first message with an `Abort`. Returns
/// its endpoint and how many connection attempts reached it.
async fn aborting_server(me: &Identity) -> (iroh::Endpoint, Arc<AtomicUsize>) {
    let ep = iroh::Endpoint::builder(iroh::endpoint::presets::Minimal)
        .secret_key(iroh::SecretKey::from_bytes(&me.secret_seed().unwrap()))
        .alpns(vec![telextiles_link::ALPN.to_vec()])
        .relay_mode(iroh::RelayMode::Disabled)
        .clear_ip_transports()
        .bind_addr("127.0.0.1:0".parse::<std::net::SocketAddr>().unwrap())
        .unwrap()
        .portmapper_config(iroh::endpoint::PortmapperConfig::Disabled)
        .bind()
        .await
        .unwrap();
    let count = Arc::new(AtomicUsize::new(0));
    let (ep2, count2) = (ep.clone(), count.clone());
    tokio::spawn(async move {
        while let Some(incoming) = ep2.accept().await {
            count2.fetch_add(1, Ordering::SeqCst);
            tokio::spawn(async move {
                let Ok(accepting) = incoming.accept() else {
                    return;
                };
                let Ok(conn) = accepting.await else { return };
                let Ok((mut send, mut recv)) = conn.accept_bi().await else {
                    return;
                };
                let mut buf = [0u8; 4096];
                if !matches!(recv.read(&mut buf).await, Ok(Some(_))) {
                    return;
                }
                let abort =
                    telextiles_proto::peer::Control::Pair(telextiles_certs::PairingMessage::Abort(
                        telextiles_certs::pairing::PairingAbort::NotPairing,
                    ));
                let _ = send
                    .write_all(&telextiles_proto::peer::encode_control(&abort).unwrap())
                    .await;
                let _ = tokio::time::timeout(Duration::from_secs(20), conn.closed()).await;
            });
        }
    });
    (ep, count)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
#[ignore = "run inside a private network namespace by an_aborting_pairing_advertiser_neither_ends_entering_nor_is_redialled"]
async fn inner_aborting_pairing_advertiser() {
    assert!(
        std::env::var_os(INNER_ENV).is_some(),
        "run by the outer test only"
    );
    let (ia, ib, fake) = (
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
        Identity::generate().unwrap(),
    );
    let offer = CodeOffer::new(
        &mut rand::rngs::OsRng,
        std::time::Instant::now(),
        DEFAULT_CODE_TTL,
    );
    let typed: PairingCode = offer.display().parse().unwrap();
    // The fake advertiser first.
    let (fake_ep, dials) = aborting_server(&fake).await;
    let (_fake_advert, _) = Discovery::start(
        &DiscoveryConfig::only(&["lo"]),
        &fake.peer_key(),
        fake_ep.bound_sockets()[0].port(),
        true,
    )
    .unwrap();
    // Bob enters the code and browses; quick redials (the old loop came
    // back within 0.6 s of a failed pairing).
    let mut cb = LinkConfig::new("bob", "127.0.0.1:0".parse().unwrap(), hello());
    cb.pairing = Some(PairingMode::Enter(typed));
    cb.discovery = Some(DiscoveryConfig::only(&["lo"]));
    cb.timing.backoff_min = Duration::from_millis(20);
    cb.timing.backoff_max = Duration::from_millis(50);
    let (b, mut rb) = Link::start(cb, ib.clone(), PinSet::default())
        .await
        .unwrap();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
    loop {
        match tokio::time::timeout_at(deadline, rb.recv()).await {
            Ok(Some(LinkEvent::Error {
                kind: telextiles_link::ErrorKind::PairingAttempt,
                message,
                ..
            })) => {
                println!("bob: {message}");
                break;
            }
            Ok(Some(LinkEvent::Error {
                kind: telextiles_link::ErrorKind::Pairing,
                message,
                ..
            })) => panic!("the fake advertiser ended pairing: {message}"),
            Ok(Some(_)) => {}
            other => panic!("bob did not try the fake advertiser: {other:?}"),
        }
    }
    tokio::time::sleep(Duration::from_millis(1500)).await;
    assert_eq!(
        dials.load(Ordering::SeqCst),
        1,
        "the fake was dialled again"
    );
    // Then the real device shows its code.
    let mut ca = LinkConfig::new("alice", "127.0.0.1:0".parse().unwrap(), hello());
    ca.pairing = Some(PairingMode::Show(offer));
    ca.discovery = Some(DiscoveryConfig::only(&["lo"]));
    let (a, _ra) = Link::start(ca, ia.clone(), PinSet::default())
        .await
        .unwrap();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(15);
    loop {
        match tokio::time::timeout_at(deadline, rb.recv()).await {
            Ok(Some(LinkEvent::Paired { peer, .. })) => {
                assert_eq!(peer, ia.device_id());
                break;
            }
            Ok(Some(LinkEvent::Error {
                kind: telextiles_link::ErrorKind::Pairing,
                message,
                ..
            })) => panic!("pairing ended: {message}"),
            Ok(Some(_)) => {}
            other => panic!("bob did not pair with the real device: {other:?}"),
        }
    }
    assert_eq!(
        dials.load(Ordering::SeqCst),
        1,
        "the fake was dialled again"
    );
    println!("paired with the real advertiser after a fake one aborted");
    let _ = tokio::time::timeout(Duration::from_millis(100), fake_ep.close()).await;
    a.shutdown().await;
    b.shutdown().await;
}
