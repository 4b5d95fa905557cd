//! A userspace UDP relay that adds delay, jitter (hence reordering) and
//! optional loss between two endpoints — this kernel has no netem.
//!
//! Clients send to [`Relay::local_addr`]; each client gets its own upstream
//! socket towards `target`, so replies find their way back. Every packet, in
//! both directions, is held for `delay ± jitter` (uniform), independently,
//! so packets overtake each other whenever the jitter exceeds their spacing.
use std::collections::HashMap;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use rand::{Rng, SeedableRng};
use tokio::net::UdpSocket;
use tokio::task::JoinHandle;

/// What the relay does to each packet.
#[derive(Debug, Clone, Copy)]
pub struct Impairment {
    /// Mean one-way delay added.
    pub delay: Duration,
    /// Uniform ± spread around `delay`.
    pub jitter: Duration,
    /// Probability of dropping a packet (0 = none).
    pub loss: f64,
    pub seed: u64,
}

impl Impairment {
    /// `delay ± jitter`, no loss.
    pub fn delay(delay_ms: u64, jitter_ms: u64) -> Impairment {
        Impairment {
            delay: Duration::from_millis(delay_ms),
            jitter: Duration::from_millis(jitter_ms),
            loss: 0.0,
            seed: 1,
        }
    }
}

/// Counters since start.
#[derive(Debug, Default)]
pub struct RelayStats {
    pub received: AtomicU64,
    pub forwarded: AtomicU64,
    pub dropped: AtomicU64,
    /// Packets delivered after a packet that arrived later (per direction).
    pub reordered: AtomicU64,
}

/// Snapshot of [`RelayStats`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Counts {
    pub received: u64,
    pub forwarded: u64,
    pub dropped: u64,
    pub reordered: u64,
}

/// A running relay; stops on drop.
pub struct Relay {
    local: SocketAddr,
    stats: Arc<RelayStats>,
    task: JoinHandle<()>,
}

struct Direction {
    arrivals: AtomicU64,
    max_delivered: AtomicU64,
}

impl Direction {
    fn new() -> Arc<Direction> {
        Arc::new(Direction {
            arrivals: AtomicU64::new(0),
            max_delivered: AtomicU64::new(0),
        })
    }
}

type Rng64 = Arc<Mutex<rand_chacha::ChaCha8Rng>>;

fn schedule(
    imp: Impairment,
    rng: &Rng64,
    stats: &Arc<RelayStats>,
    dir: &Arc<Direction>,
    sock: Arc<UdpSocket>,
    to: Option<SocketAddr>,
    data: Vec<u8>,
) {
    stats.received.fetch_add(1, Ordering::Relaxed);
    let idx = dir.arrivals.fetch_add(1, Ordering::Relaxed) + 1;
    let (drop_it, wait) = {
        let mut r = rng.lock().unwrap_or_else(|p| p.into_inner());
        let drop_it = imp.loss > 0.0 && r.gen_bool(imp.loss.min(1.0));
        let j = imp.jitter.as_micros() as i64;
        let off = if j > 0 { r.gen_range(-j..=j) } else { 0 };
        let us = (imp.delay.as_micros() as i64 + off).max(0) as u64;
        (drop_it, Duration::from_micros(us))
    };
    if drop_it {
        stats.dropped.fetch_add(1, Ordering::Relaxed);
        return;
    }
    let stats = stats.clone();
    let dir = dir.clone();
    tokio::spawn(async move {
        tokio::time::sleep(wait).await;
        let prev = dir.max_delivered.fetch_max(idx, Ordering::Relaxed);
        if prev > idx {
            stats.reordered.fetch_add(1, Ordering::Relaxed);
        }
        let sent = match to {
            Some(a) => sock.send_to(&data, a).await,
            None => sock.send(&data).await,
        };
        if sent.is_ok() {
            stats.forwarded.fetch_add(1, Ordering::Relaxed);
        }
    });
}

impl Relay {
    /// Listens on `listen` and relays to `target` with `imp`.
    pub async fn start(
        listen: SocketAddr,
        target: SocketAddr,
        imp: Impairment,
    ) -> std::io::Result<Relay> {
        let front = Arc::new(UdpSocket::bind(listen).await?);
        let local = front.local_addr()?;
        let stats = Arc::new(RelayStats::default());
        let rng: Rng64 = Arc::new(Mutex::new(rand_chacha::ChaCha8Rng::seed_from_u64(imp.seed)));
        let up_dir = Direction::new();
        let down_dir = Direction::new();
        let st = stats.clone();
        let task = tokio::spawn(async move {
            let mut clients: HashMap<SocketAddr, (Arc<UdpSocket>, JoinHandle<()>)> = HashMap::new();
            let mut buf = vec![0u8; 65536];
            loop {
                let Ok((n, from)) = front.recv_from(&mut buf).await else {
                    continue;
                };
                let up = match clients.get(&from) {
                    Some((u, _)) => u.clone(),
                    None => {
                        let bind: SocketAddr = if target.is_ipv4() {
                            SocketAddr::new(std::net::Ipv4Addr::UNSPECIFIED.into(), 0)
                        } else {
                            SocketAddr::new(std::net::Ipv6Addr::UNSPECIFIED.into(), 0)
                        };
                        let Ok(up) = UdpSocket::bind(bind).await else {
                            continue;
                        };
                        if up.connect(target).await.is_err() {
                            continue;
                        }
                        let up = Arc::new(up);
                        let (up2, front2, st2, rng2, down2) = (
                            up.clone(),
                            front.clone(),
                            st.clone(),
                            rng.clone(),
                            down_dir.clone(),
                        );
                        let back = tokio::spawn(async move {
                            let mut b = vec![0u8; 65536];
                            loop {
                                let n = match up2.recv(&mut b).await {
                                    Ok(n) => n,
                                    // A packet relayed before the target
                                    // listened came back as ICMP port
                                    // unreachable, which a connected UDP
                                    // socket reports on its next receive.
                                    // The target may listen now: keep
                                    // relaying its replies (a daemon that
                                    // dials before its peer is up is
                                    // otherwise never answered again from
                                    // the same source port).
                                    Err(e) if e.kind() == std::io::ErrorKind::ConnectionRefused => {
                                        continue
                                    }
                                    Err(_) => break,
                                };
                                schedule(
                                    imp,
                                    &rng2,
                                    &st2,
                                    &down2,
                                    front2.clone(),
                                    Some(from),
                                    b[..n].to_vec(),
                                );
                            }
                        });
                        clients.insert(from, (up.clone(), back));
                        up
                    }
                };
                schedule(imp, &rng, &st, &up_dir, up, None, buf[..n].to_vec());
            }
        });
        Ok(Relay { local, stats, task })
    }

    /// Where clients send.
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    pub fn counts(&self) -> Counts {
        Counts {
            received: self.stats.received.load(Ordering::Relaxed),
            forwarded: self.stats.forwarded.load(Ordering::Relaxed),
            dropped: self.stats.dropped.load(Ordering::Relaxed),
            reordered: self.stats.reordered.load(Ordering::Relaxed),
        }
    }
}

impl Drop for Relay {
    fn drop(&mut self) {
        self.task.abort();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Real UDP on loopback through the relay: delay is applied, packets
    /// are reordered, replies come back, loss drops about the set share.
    #[tokio::test]
    async fn delays_reorders_and_returns_replies() {
        let server = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let target = server.local_addr().unwrap();
        let relay = Relay::start(
            "127.0.0.1:0".parse().unwrap(),
            target,
            Impairment::delay(50, 20),
        )
        .await
        .unwrap();
        let client = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        let t0 = std::time::Instant::now();
        for i in 0u32..100 {
            client
                .send_to(&i.to_le_bytes(), relay.local_addr())
                .await
                .unwrap();
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        let mut order = Vec::new();
        let mut buf = [0u8; 16];
        let mut from = None;
        while order.len() < 100 {
            let (n, f) = tokio::time::timeout(Duration::from_secs(2), server.recv_from(&mut buf))
                .await
                .expect("all packets arrive")
                .unwrap();
            assert_eq!(n, 4);
            if order.is_empty() {
                assert!(t0.elapsed() >= Duration::from_millis(29), "delay applied");
            }
            from = Some(f);
            order.push(u32::from_le_bytes(buf[..4].try_into().unwrap()));
        }
        let mut sorted = order.clone();
        sorted.sort();
        assert_eq!(sorted, (0..100).collect::<Vec<_>>());
        assert_ne!(order, sorted, "jitter reorders packets");
        assert!(relay.counts().reordered > 0);
        // Reply path.
        server.send_to(b"pong", from.unwrap()).await.unwrap();
        let (n, f) = tokio::time::timeout(Duration::from_secs(1), client.recv_from(&mut buf))
            .await
            .expect("reply relayed")
            .unwrap();
        assert_eq!((&buf[..n], f), (&b"pong"[..], relay.local_addr()));

        let lossy = Relay::start(
            "127.0.0.1:0".parse().unwrap(),
            target,
            Impairment {
                loss: 0.5,
                ..Impairment::delay(0, 0)
            },
        )
        .await
        .unwrap();
        // Paced, so that the relay's socket buffer (a few hundred small
        // datagrams) never overflows while its task waits for a turn on a
        // busy machine: the loss counted is the relay's alone.
        for i in 0u32..400 {
            client
                .send_to(&i.to_le_bytes(), lossy.local_addr())
                .await
                .unwrap();
            if i % 50 == 49 {
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        }
        let t0 = std::time::Instant::now();
        while lossy.counts().received < 400 && t0.elapsed() < Duration::from_secs(5) {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        let c = lossy.counts();
        assert_eq!(c.received, 400);
        assert!((120..280).contains(&c.dropped), "{c:?}");
    }

    /// A client that sends before the target listens (as a daemon dials a
    /// peer still starting up) is answered once the target is up: the ICMP
    /// port unreachable that the first packet drew does not end the
    /// relay's reply path for that client.
    #[tokio::test]
    async fn replies_flow_after_the_target_starts_listening() {
        let target = std::net::UdpSocket::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap(); // closed again: nothing listens there yet
        let relay = Relay::start(
            "127.0.0.1:0".parse().unwrap(),
            target,
            Impairment::delay(0, 0),
        )
        .await
        .unwrap();
        let client = UdpSocket::bind("127.0.0.1:0").await.unwrap();
        client.send_to(b"early", relay.local_addr()).await.unwrap();
        // The relay forwards it to the closed port. On loopback the kernel
        // queues the port unreachable on the relay's socket within that
        // send, so once it counts as forwarded the error is pending there,
        // whenever the relay next receives.
        let t0 = std::time::Instant::now();
        while relay.counts().forwarded < 1 && t0.elapsed() < Duration::from_secs(2) {
            tokio::time::sleep(Duration::from_millis(5)).await;
        }
        let server = UdpSocket::bind(target).await.unwrap();
        let mut buf = [0u8; 16];
        // Each try sends again until the server has one (the early packet
        // is gone), then the server answers through the relay.
        let from = loop {
            client.send_to(b"ping", relay.local_addr()).await.unwrap();
            match tokio::time::timeout(Duration::from_millis(200), server.recv_from(&mut buf)).await
            {
                Ok(r) => break r.unwrap().1,
                Err(_) => assert!(
                    t0.elapsed() < Duration::from_secs(5),
                    "the relay forwards nothing"
                ),
            }
        };
        server.send_to(b"pong", from).await.unwrap();
        let (n, f) = tokio::time::timeout(Duration::from_secs(2), client.recv_from(&mut buf))
            .await
            .expect("the target's reply is relayed after the early packet's port unreachable")
            .unwrap();
        assert_eq!((&buf[..n], f), (&b"pong"[..], relay.local_addr()));
    }
}
