//! A paired peer turned hostile, against a real `telextilesd run` (real
//! QUIC on loopback, mDNS off): the attacker is a raw quinn client in this
//! process whose key the daemon has pinned and whose hello matches its
//! encoder and index, so everything it sends reaches the receiver core.
//! It sends latents that decode but cannot be used (wrong dimension, all
//! zero), press stops carrying such final latents, stops and starts out of
//! order, a press whose capture times run from 0 to `u64::MAX`, and
//! datagrams that do not decode at all. The daemon counts each
//! refusal in `status` (`refused`), logs them rate-limited, reports the
//! undecodable datagrams as link errors and counts each (`bad_datagrams`),
//! keeps running, and decides the peer's next honest press as the fabric
//! it is.
#[path = "harness/mod.rs"]
mod harness;

use std::net::SocketAddr;
use std::time::{Duration, Instant};

use harness::*;
use telextiles_certs::Identity;
use telextiles_control::{Command as Ctl, Event};
use telextiles_proto::peer::{
    encode_control, Control, Hello, LatentFrame, QuantVec, FLAG_FINAL, PROTOCOL_VERSION,
};

fn datagram(seq: u64, press_id: u32, flags: u8, v: &[f32]) -> bytes::Bytes {
    datagram_at(seq, 1_000_000 + seq * 16_667, press_id, flags, v)
}

fn datagram_at(seq: u64, capture_us: u64, press_id: u32, flags: u8, v: &[f32]) -> bytes::Bytes {
    LatentFrame {
        seq,
        capture_us,
        press_id,
        flags,
        vector: QuantVec::quantize_f16(v),
    }
    .encode()
    .unwrap()
    .into()
}

fn stop(press_id: u32, capture_us: u64, final_latent: Option<(u64, &[f32])>) -> Vec<u8> {
    encode_control(&Control::PressStop {
        press_id,
        capture_us,
        final_latent: final_latent.map(|(seq, v)| LatentFrame {
            seq,
            capture_us,
            press_id,
            flags: FLAG_FINAL,
            vector: QuantVec::quantize_f16(v),
        }),
    })
    .unwrap()
}

fn start(press_id: u32, capture_us: u64) -> Vec<u8> {
    encode_control(&Control::PressStart {
        press_id,
        capture_us,
    })
    .unwrap()
}

async fn status(side: &Side) -> serde_json::Value {
    connect(side)
        .await
        .call(&Ctl::Status)
        .await
        .unwrap()
        .unwrap()
}

/// Polls `status` until `f` holds (30 s at most); returns the last one.
async fn status_until(
    side: &Side,
    what: &str,
    f: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let t0 = Instant::now();
    loop {
        let st = status(side).await;
        if f(&st) {
            return st;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(30),
            "{what}: last status {st:#}\nlog:\n{}",
            std::fs::read_to_string(&side.log).unwrap_or_default()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_hostile_paired_peer_is_refused_counted_and_the_daemon_still_decides() {
    let work = tempfile::tempdir().unwrap();
    let (me, evil) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    paired_state(&work.path().join("a"), &me, &evil, "evil");
    let listen: SocketAddr = format!("127.0.0.1:{}", free_udp_port()).parse().unwrap();
    let daemon = spawn("a", work.path(), listen, None, "sim:T012", &[]);
    let st = status(&daemon).await;
    let dim = st["model"]["dim"].as_u64().unwrap() as usize;

    // The expected answer comes from the shipped index itself: a query
    // that lands on an entry's centroid, and the entry it is nearest to.
    let index = telextiles_index::Index::read(std::path::Path::new(INDEX)).unwrap();
    assert_eq!(index.dim, dim);
    assert_eq!(st["index"]["fingerprint"], index.fingerprint());
    let (want, query) = (0..index.entries.len())
        .find_map(|k| {
            let mut q = index.query_for(&index.entries[k].centroid)?;
            let n = q.iter().map(|x| x * x).sum::<f32>().sqrt();
            q.iter_mut().for_each(|x| *x /= n);
            (index.nearest(&q)?.best == k).then(|| (index.entries[k].id.clone(), q))
        })
        .expect("an entry whose centroid's query is nearest to it");

    // The attacker, paired and compatible.
    let ep = iroh::Endpoint::builder(iroh::endpoint::presets::Minimal)
        .secret_key(iroh::SecretKey::from_bytes(&evil.secret_seed().unwrap()))
        .relay_mode(iroh::RelayMode::Disabled)
        .clear_ip_transports()
        .bind_addr("127.0.0.1:0".parse::<SocketAddr>().unwrap())
        .unwrap()
        .portmapper_config(iroh::endpoint::PortmapperConfig::Disabled)
        .bind()
        .await
        .unwrap();
    let target = iroh::EndpointAddr::from_parts(
        iroh::EndpointId::from_bytes(me.peer_key().as_bytes()).unwrap(),
        [iroh::TransportAddr::Ip(listen)],
    );
    let conn = ep.connect(target, telextiles_link::ALPN).await.unwrap();
    let (mut send, _recv) = conn.open_bi().await.unwrap();
    let mut hello = encode_control(&Control::Hello(Hello {
        protocol_version: PROTOCOL_VERSION,
        device_name: "evil".into(),
        encoder_hash: st["model"]["sha256"].as_str().unwrap().into(),
        index_fingerprint: index.fingerprint(),
        embedding_dim: dim as u16,
    }))
    .unwrap();
    hello.extend(encode_control(&Control::HelloAck).unwrap());
    send.write_all(&hello).await.unwrap();
    status_until(&daemon, "the attacker connected as a peer", |s| {
        s["peers"].as_array().is_some_and(|p| !p.is_empty())
    })
    .await;
    let mut events = connect(&daemon).await;
    events
        .subscribe(telextiles_control::SubscribeArgs::default())
        .await
        .unwrap()
        .unwrap();

    // Latents that decode but cannot be used, on the datagram path.
    let mut seq = 0;
    let short = vec![0.5f32; 3];
    let long = vec![0.1f32; dim + 1];
    let zero = vec![0.0f32; dim];
    let bad_datagrams = 30;
    send.write_all(&start(1, 1_000_000)).await.unwrap();
    for k in 0..bad_datagrams {
        seq += 1;
        let v = [&zero, &short, &long][k % 3];
        conn.send_datagram(datagram(seq, 1, 0, v)).unwrap();
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    // Datagrams that do not decode: another version, truncated, an
    // unknown encoding, nothing at all.
    let mut garbage = datagram(seq + 1, 1, 0, &query).to_vec();
    garbage[0] = 0xee;
    conn.send_datagram(garbage.into()).unwrap();
    let good = datagram(seq + 1, 1, 0, &query);
    conn.send_datagram(good.slice(..good.len() - 7)).unwrap();
    let mut enc = good.to_vec();
    enc[1] = 9;
    conn.send_datagram(enc.into()).unwrap();
    conn.send_datagram(bytes::Bytes::new()).unwrap();
    // On the reliable stream: stops with unusable final latents, a stop of
    // a press never started, a stop repeated, a start of a finished press.
    let mut bad_stops = 0;
    for (press, v) in [(1, &short), (2, &zero), (3, &long)] {
        seq += 1;
        send.write_all(&stop(press, 2_000_000, Some((seq, v))))
            .await
            .unwrap();
        bad_stops += 1;
    }
    send.write_all(&stop(4, 2_100_000, None)).await.unwrap();
    send.write_all(&stop(4, 2_100_000, None)).await.unwrap();
    send.write_all(&start(1, 2_200_000)).await.unwrap();

    // Every latent that reached the receiver was refused, and every bad
    // final latent: `latents_received` says how many datagrams arrived
    // (loopback may drop one), the stream loses nothing.
    let st = status_until(&daemon, "the refusals counted", |s| {
        let c = &s["counters"];
        let got = c["latents_received"].as_u64().unwrap_or(0);
        got > 0
            && c["refused"].as_u64() == Some(got + bad_stops)
            && c["bad_datagrams"].as_u64() == Some(4)
    })
    .await;
    assert_eq!(st["counters"]["latents_dropped"], 0, "{st:#}");
    let c = &st["counters"];
    assert!(
        c["latents_received"].as_u64().unwrap() <= bad_datagrams as u64,
        "{c}"
    );
    // A press on a wild clock (its capture times at the ends of u64, its
    // stop before its start): usable latents, so decided as what they
    // are, with no panic and no refusal.
    send.write_all(&start(5, u64::MAX)).await.unwrap();
    for k in 0..6u64 {
        seq += 1;
        let at = [0, u64::MAX, 1][k as usize % 3];
        conn.send_datagram(datagram_at(seq, at, 5, 0, &query))
            .unwrap();
    }
    seq += 1;
    send.write_all(&stop(5, 0, Some((seq, &query))))
        .await
        .unwrap();
    let refused_before = c["refused"].as_u64().unwrap();
    eprintln!(
        "refused {refused_before} ({} of {bad_datagrams} latent datagrams arrived, {bad_stops} final latents)",
        c["latents_received"]
    );
    let decisions_before = c["decisions"].as_u64().unwrap();

    // The next honest press is decided as its fabric, live and at the end.
    let t = 3_000_000;
    send.write_all(&start(10, t)).await.unwrap();
    for k in 0..30 {
        seq += 1;
        conn.send_datagram(datagram(seq, 10, 0, &query)).unwrap();
        if k % 10 == 0 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }
    seq += 1;
    send.write_all(&stop(10, t + 600_000, Some((seq, &query))))
        .await
        .unwrap();
    let t0 = Instant::now();
    let mut finals = Vec::new();
    let mut link_errors = Vec::new();
    let mut wild = 0;
    while finals.is_empty() {
        let left = Duration::from_secs(30).saturating_sub(t0.elapsed());
        match tokio::time::timeout(left, events.next_event()).await {
            Ok(Ok(Some(telextiles_control::client::EventLine::Known(e)))) => match e {
                Event::Decision {
                    textile,
                    press: Some(10),
                    final_decision,
                    peer: Some(_),
                    ..
                } => {
                    assert_eq!(textile, want, "an honest press decided as another");
                    if final_decision {
                        finals.push(textile);
                    }
                }
                Event::Decision {
                    press: Some(5),
                    ref textile,
                    latency_ms,
                    ..
                } => {
                    assert_eq!(*textile, want, "{e:?}");
                    assert!(latency_ms.is_finite(), "{e:?}");
                    wild += 1;
                }
                Event::Decision { press, .. } if press != Some(10) && press.is_some() => {
                    panic!("a decision of a refused press: {e:?}")
                }
                Event::Error { source, message } if source == "link" => {
                    link_errors.push(message)
                }
                _ => {}
            },
            Ok(Ok(Some(_))) => {}
            other => panic!(
                "no final decision of the honest press ({other:?}); link errors {link_errors:?}\nlog:\n{}",
                std::fs::read_to_string(&daemon.log).unwrap_or_default()
            ),
        }
    }
    let st = status(&daemon).await;
    let c = &st["counters"];
    assert_eq!(
        c["refused"].as_u64().unwrap(),
        refused_before,
        "the honest press refused: {c}"
    );
    assert!(c["decisions"].as_u64().unwrap() > decisions_before, "{c}");
    assert!(wild > 0, "the wild-clock press was not decided");
    assert!(
        st["peers"].as_array().is_some_and(|p| p.len() == 1),
        "the attacker is still connected: {st:#}"
    );

    // The log says what was refused, at the 1st, 2nd, 4th, ... refusal
    // only, and the undecodable datagrams were reported by the link.
    let log = std::fs::read_to_string(&daemon.log).unwrap();
    let said: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("refused a message from"))
        .collect();
    let n = refused_before as f64;
    assert!(
        !said.is_empty() && said.len() as f64 <= n.log2().floor() + 1.0,
        "{} refusals logged in {said:#?}",
        refused_before
    );
    for why in ["dimension", "zero"] {
        assert!(
            said.iter().any(|l| l.to_lowercase().contains(why)),
            "no refusal for `{why}` in {said:#?}"
        );
    }
    assert!(
        !link_errors.is_empty() && log.contains("dropped a bad latent datagram"),
        "undecodable datagrams not reported:\n{log}"
    );
    eprintln!(
        "logged {} of {refused_before} refusals; {} link error events; decided {want}",
        said.len(),
        link_errors.len()
    );
    let mut daemon = daemon;
    assert!(
        matches!(daemon.child.try_wait(), Ok(None)),
        "the daemon exited:\n{log}"
    );
    conn.close(0u32.into(), b"bye");
    let _ = tokio::time::timeout(Duration::from_secs(1), ep.close()).await;
}
