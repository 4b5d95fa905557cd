//! Peer-link measurements over 127.0.0.1 (real QUIC, no root):
//! one-way latency of latent datagrams at 60 fps (receiver's clock-offset
//! estimate and, because both ends share one clock here, the true value),
//! datagram size, and reconnect time after the peer restarts.
//!
//! `cargo run --release -p telextiles-link --example link_bench`
//! Output is committed in docs/peer-protocol-bench.txt.
use std::time::{Duration, Instant};

use telextiles_certs::{Identity, PinSet};
use telextiles_link::{
    now_us, HelloInfo, Link, LinkConfig, LinkEvent, PeerAddr, Quantisation, Timing,
};
use tokio::sync::mpsc::Receiver;

fn cfg(name: &str, q: Quantisation) -> LinkConfig {
    let mut c = LinkConfig::new(
        name,
        "127.0.0.1:0".parse().unwrap(),
        HelloInfo {
            encoder_hash: "e".repeat(64),
            index_fingerprint: "f".repeat(64),
            embedding_dim: 512,
        },
    );
    c.timing = Timing {
        backoff_max: Duration::from_millis(500),
        ..Timing::default()
    };
    c.quantisation = q;
    c
}

async fn until_up(rx: &mut Receiver<LinkEvent>) {
    loop {
        match tokio::time::timeout(Duration::from_secs(10), rx.recv()).await {
            Ok(Some(LinkEvent::PeerUp { .. })) => return,
            Ok(Some(_)) => {}
            other => panic!("no PeerUp: {other:?}"),
        }
    }
}

fn pct(v: &mut [i64], p: f64) -> i64 {
    v.sort();
    v[((v.len() - 1) as f64 * p).round() as usize]
}

async fn latency(q: Quantisation, frames: usize) {
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let (a, mut ra) = Link::start(cfg("a", q), ia.clone(), PinSet::new([ib.device_id()]))
        .await
        .unwrap();
    let mut cb = cfg("b", q);
    cb.connect = vec![PeerAddr::at(a.peer_key(), a.local_addr())];
    let (b, mut rb) = Link::start(cb, ib, PinSet::new([ia.device_id()]))
        .await
        .unwrap();
    until_up(&mut ra).await;
    until_up(&mut rb).await;
    tokio::time::sleep(Duration::from_secs(1)).await; // pings
    let v: Vec<f32> = (0..512)
        .map(|i| ((i * 37 % 101) as f32 - 50.0) / 600.0)
        .collect();
    let mut est = Vec::new();
    let mut truth = Vec::new();
    let mut bytes = 0;
    let mut lost = 0;
    for _ in 0..frames {
        let sent = now_us();
        a.send_latent(1, &v, sent, false).unwrap();
        let got = loop {
            match tokio::time::timeout(Duration::from_millis(200), rb.recv()).await {
                Ok(Some(LinkEvent::Latent(l))) => break Some(l),
                Ok(Some(_)) => {}
                _ => break None,
            }
        };
        match got {
            Some(l) => {
                truth.push(now_us() as i64 - sent as i64);
                est.push(l.one_way_latency_us.unwrap_or(i64::MAX));
                bytes = l.wire_bytes;
            }
            None => lost += 1,
        }
        tokio::time::sleep(Duration::from_micros(16_667)).await;
    }
    println!(
        "{q:?}: {frames} latents at 60 fps, {bytes} B/datagram, lost {lost}; one-way latency \
         (true, shared clock) median {} us p95 {} us; receiver's estimate median {} us p95 {} us",
        pct(&mut truth, 0.5),
        pct(&mut truth, 0.95),
        pct(&mut est, 0.5),
        pct(&mut est, 0.95)
    );
    a.shutdown().await;
    b.shutdown().await;
}

async fn reconnect(trials: usize) {
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    let (b, mut rb) = Link::start(
        cfg("b", Quantisation::Auto),
        ib.clone(),
        PinSet::new([ia.device_id()]),
    )
    .await
    .unwrap();
    let b_addr = b.local_addr();
    let mut ca = cfg("a", Quantisation::Auto);
    ca.connect = vec![PeerAddr::at(ib.peer_key(), b_addr)];
    let (a, mut ra) = Link::start(ca, ia.clone(), PinSet::new([ib.device_id()]))
        .await
        .unwrap();
    until_up(&mut ra).await;
    until_up(&mut rb).await;
    let mut b = Some((b, rb));
    let mut times = Vec::new();
    for _ in 0..trials {
        let (bh, rbh) = b.take().unwrap();
        bh.shutdown().await;
        drop((bh, rbh));
        loop {
            if let Some(LinkEvent::PeerDown { .. }) = ra.recv().await {
                break;
            }
        }
        tokio::time::sleep(Duration::from_millis(1500)).await;
        // The old endpoint's socket is freed once its connections drained.
        let (t0, (nb, nrb)) = loop {
            let mut cb = cfg("b", Quantisation::Auto);
            cb.listen = b_addr;
            let t0 = Instant::now();
            match Link::start(cb, ib.clone(), PinSet::new([ia.device_id()])).await {
                Ok(x) => break (t0, x),
                Err(_) => tokio::time::sleep(Duration::from_millis(50)).await,
            }
        };
        until_up(&mut ra).await;
        times.push(t0.elapsed().as_micros() as i64);
        b = Some((nb, nrb));
    }
    println!(
        "reconnect after the peer restarts (peer down 1.5 s, backoff 100 ms..500 ms): {trials} trials, median {} ms, max {} ms",
        pct(&mut times, 0.5) / 1000,
        pct(&mut times, 1.0) / 1000
    );
    a.shutdown().await;
}

#[tokio::main(flavor = "multi_thread", worker_threads = 2)]
async fn main() {
    println!("telextiles-link loopback bench (127.0.0.1, release build)");
    latency(Quantisation::Auto, 600).await;
    latency(Quantisation::Int8, 600).await;
    reconnect(5).await;
}
