//! Dialling: the dial loop of each known peer (only the side with the
//! smaller device ID dials discovered or remembered addresses), reconnects
//! with exponential backoff, dialling a device that shows a pairing code,
//! and the mDNS discovery loop that feeds them. Each connection it makes
//! runs in [`crate::session`].
use std::net::SocketAddr;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use telextiles_certs::{peer_device_id, DeviceId, PeerPolicy};
use telextiles_proto::peer;
use tokio::sync::{mpsc, watch};

use crate::discovery::Discovered;
use crate::session::{not_there, peer_cert, peer_shut_down, run_connection};
use crate::{limits, lock, ErrorKind, LinkEvent, PairingMode, Shared};

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
/// addresses.
pub(crate) fn ensure_dialing(shared: &Arc<Shared>, peer: DeviceId, addrs: Vec<SocketAddr>) {
    if shared.my_id >= peer {
        return;
    }
    let mut dialing = lock(&shared.dialing);
    if let Some(tx) = dialing.get(&peer) {
        let merged = bounded_addrs(addrs, &tx.borrow());
        if *tx.borrow() != merged {
            let _ = tx.send(merged);
        }
        return;
    }
    let (tx, rx) = watch::channel(bounded_addrs(addrs, &[]));
    dialing.insert(peer, tx);
    shared.spawn(dial_known(shared.clone(), peer, rx));
}

async fn dial_known(
    shared: Arc<Shared>,
    peer: DeviceId,
    mut addrs: watch::Receiver<Vec<SocketAddr>>,
) {
    let list = addrs.borrow_and_update().clone();
    let (tx, mut rx) = watch::channel(list);
    // Owned by this dial: it forwards address updates while it runs.
    let _forward = crate::AbortOnDrop(tokio::spawn(async move {
        while addrs.changed().await.is_ok() {
            let v = addrs.borrow_and_update().clone();
            if tx.send(v).is_err() {
                return;
            }
        }
    }));
    dial_loop_inner(shared, Some(peer), &mut rx, false, false).await;
}

/// Dials `addrs` until shut down, reconnecting with exponential backoff.
/// `explicit`: addresses the user gave (`--connect`), dialled whatever the
/// IDs; the peer's identity is learnt from the first connection.
pub(crate) async fn dial_loop(
    shared: Arc<Shared>,
    expect: Option<DeviceId>,
    addrs: Vec<SocketAddr>,
    explicit: bool,
) {
    let (_tx, mut rx) = watch::channel(addrs);
    dial_loop_inner(shared, expect, &mut rx, explicit, false).await;
}

/// Dials a device that advertises a pairing code (found by mDNS) while
/// this side is entering a code. Gives up when pairing mode ends unless it
/// reached the device (which then goes on as a `--connect` peer).
pub(crate) async fn dial_for_pairing(shared: Arc<Shared>, addrs: Vec<SocketAddr>) {
    let (_tx, mut rx) = watch::channel(addrs);
    dial_loop_inner(shared, None, &mut rx, true, true).await;
}

async fn dial_loop_inner(
    shared: Arc<Shared>,
    mut expect: Option<DeviceId>,
    addrs: &mut watch::Receiver<Vec<SocketAddr>>,
    explicit: bool,
    pairing_only: bool,
) {
    let mut stop = shared.shutdown.subscribe();
    let mut backoff = shared.timing.backoff_min;
    let mut last_error: Option<String> = None;
    // The last connection ended because the peer's daemon shut down: until
    // it is reached again, finding nobody there (no answer, or an endpoint
    // still closing that refuses) is expected (its PeerDown said why), so
    // those failures are retried but not reported. Any other failure (a
    // refused handshake: the peer came back unpaired) still is.
    let mut peer_left = false;
    loop {
        if *stop.borrow() || shared.stopped.load(Ordering::SeqCst) {
            return;
        }
        // An advertiser that never answered, once pairing is over.
        if pairing_only && expect.is_none() && !shared.pairing_mode() {
            return;
        }
        // A remembered/discovered peer that was unpaired meanwhile.
        if let (false, Some(id)) = (explicit, expect) {
            if !shared.pins.contains(&id) {
                return;
            }
        }
        // Already connected (either direction): wait until that changes.
        if let Some(id) = expect {
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
        }
        let list = addrs.borrow_and_update().clone();
        // None: every address failed (back off); Some(pause): a connection
        // was made and ended.
        let mut after: Option<Duration> = None;
        for addr in list {
            let entering =
                explicit && matches!(*lock(&shared.pairing), Some(PairingMode::Enter(_)));
            let policy = match expect {
                _ if entering => PeerPolicy::AnyForPairing,
                Some(id) => PeerPolicy::Expect(id),
                None => PeerPolicy::Pinned(shared.pins.clone()),
            };
            let cfg = match shared.client_config(policy) {
                Ok(c) => c,
                Err(e) => {
                    shared
                        .emit(LinkEvent::Error {
                            peer: expect,
                            kind: ErrorKind::Local,
                            message: e.to_string(),
                        })
                        .await;
                    return;
                }
            };
            let connecting =
                match shared
                    .endpoint
                    .connect_with(cfg, addr, telextiles_certs::SERVER_NAME)
                {
                    Ok(c) => c,
                    Err(e) => {
                        report_once(
                            &shared,
                            &mut last_error,
                            expect,
                            ErrorKind::Connection,
                            format!("cannot dial {addr}: {e}"),
                        )
                        .await;
                        continue;
                    }
                };
            let conn = tokio::select! {
                c = tokio::time::timeout(shared.timing.connect_timeout, connecting) => match c {
                    Ok(c) => c,
                    Err(_) => Err(quinn::ConnectionError::TimedOut),
                },
                _ = stop.changed() => return,
            };
            match conn {
                Ok(conn) => {
                    if let Some(id) = peer_cert(&conn).and_then(|c| peer_device_id(&[c]).ok()) {
                        if expect.is_none() {
                            expect = Some(id);
                        }
                    }
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
                            after = Some(backoff);
                        }
                        Err(end) => {
                            // One exchange per device showing a code: one
                            // that proved no code is not dialled again
                            // (redialling would give it another online
                            // guess at the code each time).
                            let attempt_over =
                                end.kind == ErrorKind::PairingAttempt && (entering || pairing_only);
                            if end.report {
                                report_once(
                                    &shared,
                                    &mut last_error,
                                    expect,
                                    end.kind.clone(),
                                    end.message,
                                )
                                .await;
                            }
                            if attempt_over {
                                return;
                            }
                            after = match end.kind {
                                // No quick retry: the users must act.
                                ErrorKind::Incompatible(_)
                                | ErrorKind::Pairing
                                | ErrorKind::PairingAttempt
                                | ErrorKind::RefusedByPeer => Some(shared.timing.backoff_max * 10),
                                _ => None,
                            };
                        }
                    }
                    break;
                }
                Err(e) => {
                    if !(peer_left && not_there(&e)) {
                        let text = format!("cannot connect to {addr}: {e}");
                        report_once(
                            &shared,
                            &mut last_error,
                            expect,
                            ErrorKind::Connection,
                            text,
                        )
                        .await;
                    }
                }
            }
        }
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
        if enter_mode
            && d.pairing
            && shared.pairing_mode()
            && !pairing_dialled.contains(&d.device_id)
            && pairing_dialled.len() < limits::MAX_PAIRING_DIALS
        {
            // A device showing a code (even one still pinned here: it may
            // have unpaired this one): dial every such advertiser, once.
            pairing_dialled.push(d.device_id);
            let addrs = bounded_addrs(d.addrs, &[]);
            shared.spawn(dial_for_pairing(shared.clone(), addrs));
        } else if shared.pins.contains(&d.device_id) {
            ensure_dialing(&shared, d.device_id, d.addrs);
        }
    }
}
