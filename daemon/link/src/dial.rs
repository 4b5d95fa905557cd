//! Dialling: the dial loop of each known peer (only the side with the
//! smaller device ID dials discovered or remembered addresses), reconnects
//! with exponential backoff, dialling a device that shows a pairing code,
//! and the mDNS discovery loop that feeds them. Each connection it makes
//! runs in [`crate::session`].
use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use telextiles_certs::DeviceId;
use telextiles_proto::peer;
use tokio::sync::{mpsc, watch};

use crate::addr::{endpoint_addr, PeerAddr};
use crate::discovery::Discovered;
use crate::session::{not_there, peer_shut_down, run_connection};
use crate::{limits, lock, ErrorKind, LinkEvent, PairingMode, Shared, ALPN};
use iroh::endpoint::ConnectingError;

/// The addresses to dial for one peer, at most [`limits::MAX_PEER_ADDRS`],
/// without duplicates: the first half of `old` stays (the first addresses
/// a peer's list starts with are the ones it was really reached at, from
/// the trust store), then the newest claim `new`, then the rest of `old`.
/// mDNS adverts are claims anyone can make: they rotate through the second
/// half and can neither grow the list nor push out the remembered ones.
pub(crate) fn bounded_addrs(new: Vec<SocketAddr>, old: &[SocketAddr]) -> Vec<SocketAddr> {
    let half = limits::MAX_PEER_ADDRS / 2;
    let (keep, rest) = old.split_at(old.len().min(half));
    let mut out: Vec<SocketAddr> = Vec::with_capacity(limits::MAX_PEER_ADDRS);
    for &a in keep.iter().chain(&new).chain(rest) {
        if out.len() < limits::MAX_PEER_ADDRS && !out.contains(&a) {
            out.push(a);
        }
    }
    out
}

/// Starts (or updates the addresses of) the dial loop of a known peer.
/// Only the side with the smaller device ID dials discovered/remembered
/// peers.
pub(crate) fn ensure_dialing(shared: &Arc<Shared>, to: PeerAddr) {
    let peer = to.key.device_id();
    if shared.my_id >= peer {
        return;
    }
    let mut dialing = lock(&shared.dialing);
    if let Some(tx) = dialing.get(&peer) {
        let merged = PeerAddr::new(to.key, bounded_addrs(to.addrs, &tx.borrow().addrs));
        if *tx.borrow() != merged {
            let _ = tx.send(merged);
        }
        return;
    }
    let (tx, rx) = watch::channel(PeerAddr::new(to.key, bounded_addrs(to.addrs, &[])));
    dialing.insert(peer, tx);
    shared.spawn(dial_known(shared.clone(), rx));
}

async fn dial_known(shared: Arc<Shared>, mut addrs: watch::Receiver<PeerAddr>) {
    let first = addrs.borrow_and_update().clone();
    let (tx, mut rx) = watch::channel(first);
    // Owned by this dial: it forwards address updates while it runs.
    let _forward = crate::AbortOnDrop(tokio::spawn(async move {
        while addrs.changed().await.is_ok() {
            let v = addrs.borrow_and_update().clone();
            if tx.send(v).is_err() {
                return;
            }
        }
    }));
    dial_loop_inner(shared, &mut rx, false, false).await;
}

/// Dials `to` until shut down, reconnecting with exponential backoff.
/// `explicit`: a peer the user gave (`--connect`), dialled whether paired
/// or not (an unpaired one is refused after the handshake, or paired with
/// when this side enters a code).
pub(crate) async fn dial_loop(shared: Arc<Shared>, to: PeerAddr, explicit: bool) {
    let (_tx, mut rx) = watch::channel(to);
    dial_loop_inner(shared, &mut rx, explicit, false).await;
}

/// Dials a device that advertises a pairing code (found by mDNS) while
/// this side is entering a code. Gives up when pairing mode ends unless it
/// reached the device (which then goes on as a `--connect` peer).
pub(crate) async fn dial_for_pairing(shared: Arc<Shared>, to: PeerAddr) {
    let (_tx, mut rx) = watch::channel(to);
    dial_loop_inner(shared, &mut rx, true, true).await;
}

async fn dial_loop_inner(
    shared: Arc<Shared>,
    addrs: &mut watch::Receiver<PeerAddr>,
    explicit: bool,
    pairing_only: bool,
) {
    let mut stop = shared.shutdown.subscribe();
    let mut backoff = shared.timing.backoff_min;
    let mut last_error: Option<String> = None;
    let id = addrs.borrow().key.device_id();
    let mut reached = false;
    // The last connection ended because the peer's daemon shut down: until
    // it is reached again, finding nobody there (no answer, or an endpoint
    // still closing that refuses) is expected (its PeerDown said why), so
    // those failures are retried but not reported. Any other failure (a
    // refused handshake: the peer came back unpaired) still is.
    let mut peer_left = false;
    // Through a relay the first connection waits for the relay too.
    let connect_timeout = if shared.relayed {
        shared.timing.connect_timeout.max(RELAYED_CONNECT_TIMEOUT)
    } else {
        shared.timing.connect_timeout
    };
    loop {
        if *stop.borrow() || shared.stopped.load(Ordering::SeqCst) {
            return;
        }
        // An advertiser that never answered, once pairing is over.
        if pairing_only && !reached && !shared.pairing_mode() {
            return;
        }
        // A remembered/discovered peer that was unpaired meanwhile.
        if !explicit && !shared.pins.contains(&id) {
            return;
        }
        // Already connected (either direction): wait until that changes.
        if shared.is_up(&id) {
            let notified = shared.peers_changed.notified();
            tokio::pin!(notified);
            notified.as_mut().enable();
            if shared.is_up(&id) {
                tokio::select! {
                    _ = notified => {}
                    _ = stop.changed() => return,
                }
                continue;
            }
        }
        let to = addrs.borrow_and_update().clone();
        let label = to.to_string();
        let entering = explicit && matches!(*lock(&shared.pairing), Some(PairingMode::Enter(_)));
        // None: the attempt failed (back off); Some(pause): a connection
        // was made and ended.
        let after: Option<Duration> = 'attempt: {
            let target = match endpoint_addr(&to, &shared.relay_urls) {
                Ok(t) => t,
                Err(e) => {
                    shared
                        .emit(LinkEvent::Error {
                            peer: Some(id),
                            kind: ErrorKind::Local,
                            message: e.to_string(),
                        })
                        .await;
                    return;
                }
            };
            if to.addrs.is_empty() && shared.relay_urls.is_empty() {
                report_once(
                    &shared,
                    &mut last_error,
                    Some(id),
                    ErrorKind::Connection,
                    format!("cannot dial device {}: no address is known and no relay is configured (give KEY@host:port, or set relay_url)", id.short()),
                )
                .await;
                break 'attempt None;
            }
            let attempt = async {
                match shared
                    .endpoint
                    .connect_with_opts(target, ALPN, Default::default())
                    .await
                {
                    Ok(connecting) => connecting.await.map_err(|e| match e {
                        ConnectingError::ConnectionError { source, .. } => Failed::Conn(source),
                        e => Failed::Other(e.to_string()),
                    }),
                    Err(e) => Err(Failed::Other(e.to_string())),
                }
            };
            let conn = tokio::select! {
                c = tokio::time::timeout(connect_timeout, attempt) => match c {
                    Ok(c) => c,
                    Err(_) => Err(Failed::TimedOut),
                },
                _ = stop.changed() => return,
            };
            let conn = match conn {
                Ok(conn) => conn,
                Err(e) => {
                    if !(peer_left && e.not_there()) {
                        let text = format!("cannot connect to {label}: {e}");
                        report_once(
                            &shared,
                            &mut last_error,
                            Some(id),
                            ErrorKind::Connection,
                            text,
                        )
                        .await;
                    }
                    break 'attempt None;
                }
            };
            reached = true;
            let ended = conn.clone();
            let end = tokio::select! {
                e = run_connection(shared.clone(), conn, true, entering) => e,
                _ = stop.changed() => return,
            };
            peer_left = ended.close_reason().is_some_and(|e| peer_shut_down(&e));
            match end {
                Ok(()) => {
                    last_error = None;
                    backoff = shared.timing.backoff_min;
                    Some(backoff)
                }
                Err(end) => {
                    // One exchange per device showing a code: one that
                    // proved no code is not dialled again (redialling would
                    // give it another online guess at the code each time).
                    let attempt_over =
                        end.kind == ErrorKind::PairingAttempt && (entering || pairing_only);
                    if end.report {
                        report_once(
                            &shared,
                            &mut last_error,
                            Some(id),
                            end.kind.clone(),
                            end.message,
                        )
                        .await;
                    }
                    if attempt_over {
                        return;
                    }
                    match end.kind {
                        // No quick retry: the users must act.
                        ErrorKind::Incompatible(_)
                        | ErrorKind::Pairing
                        | ErrorKind::PairingAttempt
                        | ErrorKind::RefusedByPeer => Some(shared.timing.backoff_max * 10),
                        _ => None,
                    }
                }
            }
        };
        let pause = match after {
            Some(p) => p,
            None => {
                let p = backoff;
                backoff = (backoff * 2).min(shared.timing.backoff_max);
                p
            }
        };
        let jitter =
            Duration::from_micros(rand::random::<u64>() % (pause.as_micros() as u64 / 4 + 1));
        tokio::select! {
            _ = tokio::time::sleep(pause + jitter) => {}
            _ = stop.changed() => return,
        }
    }
}

/// The first connection through a relay waits for this endpoint's own
/// relay connection as well as the peer's.
pub(crate) const RELAYED_CONNECT_TIMEOUT: Duration = Duration::from_secs(5);

/// Why a dial made no connection.
enum Failed {
    /// Nobody answered within the connect timeout.
    TimedOut,
    Conn(iroh::endpoint::ConnectionError),
    Other(String),
}

impl Failed {
    /// Nobody accepting: no answer, or an endpoint refusing new
    /// connections (one that is closing does).
    fn not_there(&self) -> bool {
        match self {
            Failed::TimedOut => true,
            Failed::Conn(e) => not_there(e),
            Failed::Other(_) => false,
        }
    }
}

impl std::fmt::Display for Failed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failed::TimedOut => f.write_str("timed out"),
            Failed::Conn(e) => write!(f, "{e}"),
            Failed::Other(s) => f.write_str(s),
        }
    }
}

async fn report_once(
    shared: &Shared,
    last: &mut Option<String>,
    peer: Option<DeviceId>,
    kind: ErrorKind,
    message: String,
) {
    if last.as_deref() == Some(message.as_str()) {
        return;
    }
    *last = Some(message.clone());
    shared
        .emit(LinkEvent::Error {
            peer,
            kind,
            message,
        })
        .await;
}

pub(crate) async fn discovery_loop(
    shared: Arc<Shared>,
    mut found: mpsc::Receiver<Discovered>,
    enter_mode: bool,
) {
    // Devices showing a pairing code that were dialled (bounded: a spoofed
    // or stale advert cannot keep the real one from being tried, and a
    // flood of adverts cannot start unbounded dialing).
    let mut pairing_dialled: Vec<DeviceId> = Vec::new();
    while let Some(d) = found.recv().await {
        if d.device_id == shared.my_id || d.addrs.is_empty() {
            continue;
        }
        shared
            .emit(LinkEvent::Discovered {
                peer: d.device_id,
                addrs: d.addrs.clone(),
                paired: shared.pins.contains(&d.device_id),
                pairing: d.pairing,
            })
            .await;
        if d.protocol_version != peer::PROTOCOL_VERSION {
            shared
                .emit(LinkEvent::Error {
                    peer: Some(d.device_id),
                    kind: ErrorKind::Incompatible(vec![peer::MismatchReason::ProtocolVersion {
                        ours: peer::PROTOCOL_VERSION,
                        theirs: d.protocol_version,
                    }]),
                    message: format!(
                        "found device {} on the network, but it speaks protocol {} (this one {}); update both daemons",
                        d.device_id.short(),
                        d.protocol_version,
                        peer::PROTOCOL_VERSION
                    ),
                })
                .await;
            continue;
        }
        // An advert without a key is of protocol 1 (said above).
        let Some(key) = d.key else { continue };
        if enter_mode
            && d.pairing
            && shared.pairing_mode()
            && !pairing_dialled.contains(&d.device_id)
            && pairing_dialled.len() < limits::MAX_PAIRING_DIALS
        {
            // A device showing a code (even one still pinned here: it may
            // have unpaired this one): dial every such advertiser, once.
            pairing_dialled.push(d.device_id);
            let to = PeerAddr::new(key, bounded_addrs(d.addrs, &[]));
            shared.spawn(dial_for_pairing(shared.clone(), to));
        } else if shared.pins.contains(&d.device_id) {
            ensure_dialing(&shared, PeerAddr::new(key, d.addrs));
        }
    }
}
