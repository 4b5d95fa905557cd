//! Connection life cycle: accepting, pairing, hello and the streaming
//! session of one connection, accepted or dialled (dialling and its
//! backoff are in `dial.rs`).
use std::net::IpAddr;
use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime};

use iroh::endpoint::{Connection, ConnectionError, IncomingAddr, RecvStream, SendStream};
use iroh::EndpointId;
use telextiles_certs::trust::sanitize_text;
use telextiles_certs::{DeviceId, PairingMessage, PairingRole, PeerKey, PeerRecord, TrustStore};
use telextiles_proto::peer::{self, Control, FrameDecoder, LatentFrame, LatestWins};
use tokio::sync::mpsc;

use crate::addr::{key_of, route_of, Route};
use crate::conn::connection::{Action, Connection as ConnMachine};
use crate::conn::duplicate::{self, Keep};
use crate::conn::pairing::{PairAction, PairingExchange, STILL_LOOKING};
use crate::conn::{ClockConfig, HandshakeConfig, Local, Role};
use crate::{
    close_code, limits, lock, now_us, ErrorKind, Latent, LinkEvent, PairingMode, PeerSlot,
    RateLimit, Shared,
};

/// How often a live connection's path is looked at for a change of route.
pub(crate) const PATH_POLL: Duration = Duration::from_millis(100);

/// Why a connection ended, for the user.
#[derive(Debug)]
pub(crate) struct End {
    pub(crate) kind: ErrorKind,
    pub(crate) message: String,
    /// Report as an error event (otherwise just PeerDown / nothing).
    pub(crate) report: bool,
}

impl End {
    fn err(kind: ErrorKind, message: impl Into<String>) -> End {
        End {
            kind,
            message: message.into(),
            report: true,
        }
    }
    fn quiet(message: impl Into<String>) -> End {
        End {
            kind: ErrorKind::Connection,
            message: message.into(),
            report: false,
        }
    }
}

/// Explains a connection error seen on a fresh connection. `addr`
/// describes the peer (`key@address` or a route) for the user.
pub(crate) fn explain(e: &ConnectionError, addr: &str) -> End {
    match e {
        ConnectionError::ApplicationClosed(c)
            if u64::from(c.error_code) == close_code::NOT_PAIRED as u64 =>
        {
            End::err(
                ErrorKind::RefusedByPeer,
                format!(
                    "the device at {addr} refused this device in the handshake: it is not paired with this device (run `telextilesd pair` on both devices) [{e}]"
                ),
            )
        }
        ConnectionError::ApplicationClosed(c)
            if u64::from(c.error_code) == close_code::PAIRING as u64 =>
        {
            End::err(
                ErrorKind::Pairing,
                format!(
                    "the device at {addr} closed the connection: {}",
                    peer_reason(&c.reason)
                ),
            )
        }
        ConnectionError::ApplicationClosed(c)
            if u64::from(c.error_code) == close_code::INCOMPATIBLE as u64 =>
        {
            End::err(
                ErrorKind::Incompatible(Vec::new()),
                format!(
                    "the device at {addr} refused to stream: {}",
                    peer_reason(&c.reason)
                ),
            )
        }
        ConnectionError::ApplicationClosed(c)
            if u64::from(c.error_code) == close_code::DUPLICATE as u64 =>
        {
            End::quiet("replaced by another connection to the same peer")
        }
        _ if peer_shut_down(e) => End::quiet(format!("the device at {addr} shut down")),
        _ => End::quiet(format!("connection to {addr} lost: {e}")),
    }
}

/// Whether the peer closed the connection because its daemon shut down.
pub(crate) fn peer_shut_down(e: &ConnectionError) -> bool {
    matches!(e, ConnectionError::ApplicationClosed(c)
        if u64::from(c.error_code) == close_code::BYE as u64
            && &c.reason[..] == close_code::SHUTDOWN_REASON)
}

/// Whether a failed dial found nobody accepting: no answer, or an endpoint
/// refusing new connections (one that is closing does).
pub(crate) fn not_there(e: &ConnectionError) -> bool {
    match e {
        ConnectionError::TimedOut => true,
        ConnectionError::ConnectionClosed(c) => {
            c.error_code == iroh::endpoint::TransportErrorCode::CONNECTION_REFUSED
        }
        _ => false,
    }
}

/// A close reason sent by the peer, made safe to print.
fn peer_reason(reason: &[u8]) -> String {
    sanitize_text(&String::from_utf8_lossy(reason), 200)
}

/// The peer's key and device ID (authenticated by the handshake).
pub(crate) fn peer_of(conn: &Connection) -> (PeerKey, DeviceId) {
    let key = key_of(&conn.remote_id());
    (key, key.device_id())
}

/// The peer as users read it: its short ID and its route now.
pub(crate) fn describe(conn: &Connection) -> String {
    let (route, _) = route_of(conn);
    match route {
        Route::Unknown => peer_of(conn).1.short(),
        r => r.to_string(),
    }
}

// ---------------------------------------------------------------------------
// Accepting and dialing
// ---------------------------------------------------------------------------

pub(crate) async fn accept_loop(shared: Arc<Shared>) {
    let mut stop = shared.shutdown.subscribe();
    loop {
        let incoming = tokio::select! {
            i = shared.endpoint.accept() => i,
            _ = stop.changed() => return,
        };
        let Some(incoming) = incoming else { return };
        let Some(slot) = ConnSlot::reserve(&shared, Origin::of(&incoming.remote_addr())) else {
            // Over the overall or per-address limit: refused before any
            // handshake work or state.
            incoming.refuse();
            continue;
        };
        let shared = shared.clone();
        let mut stop2 = shared.shutdown.subscribe();
        let owner = shared.clone();
        owner.spawn(async move {
            let _slot = slot;
            // Cancelled at shutdown so nothing keeps the endpoint alive.
            tokio::select! {
                _ = accept_one(shared, incoming) => {}
                _ = stop2.changed() => {}
            }
        });
    }
}

/// Where an incoming connection comes from, for the per-origin cap: its
/// IP address, or through a relay the key the relay authenticated.
#[derive(Debug, Clone, PartialEq, Eq, Hash)]
pub(crate) enum Origin {
    Ip(IpAddr),
    Relayed(EndpointId),
    Other,
}

impl Origin {
    fn of(addr: &IncomingAddr) -> Origin {
        match addr {
            IncomingAddr::Ip(a) => Origin::Ip(a.ip()),
            IncomingAddr::Relay { endpoint_id, .. } => Origin::Relayed(*endpoint_id),
            _ => Origin::Other,
        }
    }
}

impl std::fmt::Display for Origin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Origin::Ip(ip) => write!(f, "{ip}"),
            Origin::Relayed(id) => {
                write!(f, "{} through the relay", key_of(id).device_id().short())
            }
            Origin::Other => f.write_str("an unknown transport"),
        }
    }
}

/// One accepted connection's place in [`limits::MAX_CONNECTIONS`] and
/// [`limits::MAX_CONNECTIONS_PER_IP`], given back when dropped.
struct ConnSlot {
    shared: Arc<Shared>,
    ip: Origin,
}

impl ConnSlot {
    fn reserve(shared: &Arc<Shared>, ip: Origin) -> Option<ConnSlot> {
        let mut conns = lock(&shared.conns);
        let total: usize = conns.values().sum();
        let here = conns.get(&ip).copied().unwrap_or(0);
        if total >= limits::MAX_CONNECTIONS || here >= limits::MAX_CONNECTIONS_PER_IP {
            return None;
        }
        *conns.entry(ip.clone()).or_insert(0) += 1;
        Some(ConnSlot {
            shared: shared.clone(),
            ip,
        })
    }
}

impl Drop for ConnSlot {
    fn drop(&mut self) {
        let mut conns = lock(&self.shared.conns);
        if let Some(n) = conns.get_mut(&self.ip) {
            *n -= 1;
            if *n == 0 {
                conns.remove(&self.ip);
            }
        }
    }
}

/// Reports an error caused by a remote sender, rate-limited (see
/// [`limits::ERRORS_PER_WINDOW`]).
async fn report_limited(shared: &Shared, peer: Option<DeviceId>, kind: ErrorKind, message: String) {
    let msg = lock(&shared.refusals).check(std::time::Instant::now(), message);
    if let Some(message) = msg {
        shared
            .emit(LinkEvent::Error {
                peer,
                kind,
                message,
            })
            .await;
    }
}

async fn accept_one(shared: Arc<Shared>, incoming: iroh::endpoint::Incoming) {
    let origin = Origin::of(&incoming.remote_addr());
    let accepting = match incoming.accept() {
        Ok(a) => a,
        Err(e) => {
            let msg = format!("incoming connection from {origin} failed: {e}");
            report_limited(&shared, None, ErrorKind::RefusedPeer, msg).await;
            return;
        }
    };
    // The handshake and the gate (`Gate`: an unpaired device is closed
    // here, before any stream or datagram reaches the link).
    match accepting.await {
        Ok(conn) => {
            let _ = run_connection(shared, conn, false, false).await;
        }
        Err(e) => {
            let text = e.to_string();
            let rejected = matches!(e, iroh::endpoint::ConnectingError::LocallyRejected { .. });
            let refused = lock(&shared.gate_refused).take();
            let msg = match refused {
                Some(id) if rejected => format!(
                    "refused a connection from {origin}: device {id} is not paired with this device (pair with `telextilesd pair` if this is your peer)"
                ),
                _ => format!("incoming connection from {origin} failed: {text}"),
            };
            report_limited(&shared, None, ErrorKind::RefusedPeer, msg).await;
        }
    }
}

// ---------------------------------------------------------------------------
// One connection
// ---------------------------------------------------------------------------

struct Ctrl {
    send: SendStream,
    recv: RecvStream,
    dec: FrameDecoder,
    buf: Vec<u8>,
}

impl Ctrl {
    async fn write(&mut self, msg: &Control) -> Result<(), String> {
        let bytes = peer::encode_control(msg).map_err(|e| e.to_string())?;
        self.send.write_all(&bytes).await.map_err(|e| e.to_string())
    }

    async fn read(&mut self) -> Result<Control, ReadFail> {
        loop {
            match self.dec.next_message() {
                Ok(Some(m)) => return Ok(m),
                Ok(None) => {}
                Err(e) => return Err(ReadFail::Protocol(e.to_string())),
            }
            match self.recv.read(&mut self.buf).await {
                Ok(Some(n)) => {
                    let chunk = self.buf[..n].to_vec();
                    self.dec.push(&chunk);
                }
                Ok(None) => {
                    return Err(ReadFail::Closed(
                        "the peer closed the control stream".into(),
                    ))
                }
                Err(iroh::endpoint::ReadError::ConnectionLost(e)) => return Err(ReadFail::Conn(e)),
                Err(e) => return Err(ReadFail::Closed(e.to_string())),
            }
        }
    }
}

enum ReadFail {
    Conn(ConnectionError),
    Closed(String),
    Protocol(String),
}

impl ReadFail {
    fn into_end(self, addr: &str) -> End {
        match self {
            ReadFail::Conn(e) => explain(&e, addr),
            ReadFail::Closed(s) => End::quiet(s),
            ReadFail::Protocol(s) => End::err(
                ErrorKind::Protocol,
                format!("the device at {addr} sent a bad message: {s}"),
            ),
        }
    }
}

async fn open_ctrl(conn: &Connection, dialed: bool) -> Result<Ctrl, ConnectionError> {
    let (send, recv) = if dialed {
        conn.open_bi().await?
    } else {
        conn.accept_bi().await?
    };
    Ok(Ctrl {
        send,
        recv,
        dec: FrameDecoder::new(),
        buf: vec![0u8; 16 * 1024],
    })
}

/// Runs a connection until it ends. `Ok` if it was up and ended normally.
/// `entering`: this side dialled a device showing a pairing code because
/// its user typed the code: it pairs even if it still pins that device
/// (the other side may have unpaired it).
pub(crate) async fn run_connection(
    shared: Arc<Shared>,
    conn: Connection,
    dialed: bool,
    entering: bool,
) -> Result<(), End> {
    let result = run_connection_inner(&shared, &conn, dialed, entering).await;
    if let Err(end) = &result {
        let code = match end.kind {
            ErrorKind::Incompatible(_) => close_code::INCOMPATIBLE,
            ErrorKind::Pairing | ErrorKind::PairingAttempt | ErrorKind::RefusedPeer => {
                close_code::PAIRING
            }
            ErrorKind::Protocol => close_code::PROTOCOL,
            _ => close_code::BYE,
        };
        if conn.close_reason().is_none() {
            let reason = truncate_bytes(end.message.as_bytes(), 200);
            conn.close(code.into(), reason);
        }
        if !dialed && end.report {
            // Dialers report via their loop (deduplicated); acceptors here,
            // rate-limited: anyone can open connections.
            report_limited(
                &shared,
                Some(peer_of(&conn).1),
                end.kind.clone(),
                end.message.clone(),
            )
            .await;
        }
    }
    result
}

fn truncate_bytes(b: &[u8], n: usize) -> &[u8] {
    &b[..b.len().min(n)]
}

async fn run_connection_inner(
    shared: &Arc<Shared>,
    conn: &Connection,
    dialed: bool,
    entering: bool,
) -> Result<(), End> {
    let addr = describe(conn);
    let addr = addr.as_str();
    let (peer_key, peer_id) = peer_of(conn);
    if peer_id == shared.my_id {
        return Err(End::quiet("connected to itself"));
    }
    let hs = shared.timing.handshake_timeout;
    let paired = shared.pins.contains(&peer_id);
    let entering = entering && matches!(*lock(&shared.pairing), Some(PairingMode::Enter(_)));
    // This side enters a code with this device (or would, and refuses).
    let enters_code = dialed && (!paired || entering);
    let mut ctrl = match tokio::time::timeout(hs, open_ctrl(conn, dialed)).await {
        Ok(Ok(c)) => c,
        Ok(Err(e)) => return Err(as_attempt(explain(&e, addr), enters_code)),
        Err(_) => {
            return Err(End::err(
                ErrorKind::Connection,
                format!("the device at {addr} opened no control stream within {hs:?}"),
            ))
        }
    };

    if enters_code {
        tokio::time::timeout(
            hs,
            pair_as(
                shared,
                &mut ctrl,
                PairingRole::EntersCode,
                &peer_key,
                peer_id,
                addr,
                None,
            ),
        )
        .await
        .map_err(|_| {
            End::err(
                ErrorKind::PairingAttempt,
                format!(
                    "the device at {addr} did not prove the code within {} s (it stopped answering); {STILL_LOOKING}",
                    hs.as_secs()
                ),
            )
        })??;
    }
    // Hello phase: the sans-IO machine decides; this loop moves messages
    // and time (the acceptor learns from the first message whether the
    // dialer wants to pair).
    let role = if dialed { Role::Dialer } else { Role::Acceptor };
    let mut machine = ConnMachine::new(
        HandshakeConfig::new(shared.hello.clone(), hs),
        ClockConfig::new(shared.timing.ping_interval),
        role,
        addr.to_string(),
        peer_id,
        now_us(),
    );
    let their_hello = 'hello: loop {
        while let Some(action) = machine.poll() {
            match action {
                Action::Send(msg) => {
                    let must = matches!(msg, Control::Hello(_) | Control::HelloAck);
                    match ctrl.write(&msg).await {
                        Err(e) if must => return Err(End::quiet(e)),
                        _ => {}
                    }
                }
                Action::FinishSend => {
                    let _ = ctrl.send.finish();
                }
                Action::Pair(start) => {
                    tokio::time::timeout(
                        hs,
                        pair_as(
                            shared,
                            &mut ctrl,
                            PairingRole::ShowsCode,
                            &peer_key,
                            peer_id,
                            addr,
                            Some(start),
                        ),
                    )
                    .await
                    .map_err(|_| End::err(ErrorKind::Pairing, "pairing timed out"))??;
                    machine.handle_paired(now_us());
                }
                Action::Up(h) => break 'hello h,
                Action::Fail(e) => return Err(End::err(e.kind, e.message)),
                // Only once up.
                Action::Deliver(_) => {}
            }
        }
        let read = match machine.poll_timeout() {
            Some(deadline) => {
                let wait = Duration::from_micros(deadline.saturating_sub(now_us()));
                tokio::time::timeout(wait, ctrl.read()).await.ok()
            }
            None => Some(ctrl.read().await),
        };
        match read {
            None => machine.handle_timeout(now_us().max(machine.poll_timeout().unwrap_or(0))),
            Some(Ok(msg)) => {
                let local = Local {
                    peer_pinned: shared.pins.contains(&peer_id),
                    showing_code: matches!(*lock(&shared.pairing), Some(PairingMode::Show(_))),
                };
                machine.handle_message(now_us(), msg, local);
            }
            Some(Err(f)) => {
                if !machine.handle_read_error() {
                    return Err(f.into_end(addr));
                }
            }
        }
    };

    // Up: register (resolving duplicates), then stream.
    let (ctrl_tx, ctrl_rx) = mpsc::channel(limits::CONTROL_QUEUE);
    let dialed_by_lower = duplicate::dialed_by_lower(dialed, &shared.my_id, &peer_id);
    {
        let mut peers = lock(&shared.peers);
        if let Some(old) = peers.get(&peer_id) {
            if duplicate::resolve(old.dialed_by_lower, dialed_by_lower) == Keep::Existing {
                drop(peers);
                conn.close(close_code::DUPLICATE.into(), b"duplicate connection");
                return Err(End::quiet("duplicate connection"));
            }
            old.conn.close(
                close_code::DUPLICATE.into(),
                b"replaced by a newer connection",
            );
        }
        peers.insert(
            peer_id,
            PeerSlot {
                conn: conn.clone(),
                ctrl: ctrl_tx.clone(),
                dialed_by_lower,
            },
        );
    }
    shared.peers_changed.notify_waiters();
    let (route, _) = route_of(conn);
    remember(shared, peer_id, route.direct(), &their_hello.device_name);
    shared
        .emit(LinkEvent::PeerUp {
            peer: peer_id,
            name: their_hello.device_name.clone(),
            addr: route,
        })
        .await;

    let machine = Arc::new(Mutex::new(machine));
    let reason = stream(shared, conn, peer_id, ctrl, ctrl_tx, ctrl_rx, machine).await;

    let mine = {
        let mut peers = lock(&shared.peers);
        match peers.get(&peer_id) {
            Some(s) if s.conn.stable_id() == conn.stable_id() => {
                peers.remove(&peer_id);
                true
            }
            _ => false,
        }
    };
    if mine {
        shared.peers_changed.notify_waiters();
        shared
            .emit(LinkEvent::PeerDown {
                peer: peer_id,
                reason,
            })
            .await;
    }
    Ok(())
}

/// Runs the pairing exchange on the control stream.
/// Leaves pairing mode when dropped while armed: an attempt on the code
/// this side shows that ends any way but success (error, timeout,
/// cancellation) burns the code, and the link goes back to accepting only
/// pinned peers at once instead of waiting, silent and accepting any
/// certificate, until the code expires.
struct ShowAttempt<'a> {
    shared: &'a Arc<Shared>,
    armed: bool,
}

impl Drop for ShowAttempt<'_> {
    fn drop(&mut self) {
        if self.armed {
            finish_pairing_mode(self.shared);
        }
    }
}

async fn pair_as(
    shared: &Arc<Shared>,
    ctrl: &mut Ctrl,
    role: PairingRole,
    peer_key: &PeerKey,
    peer_id: DeviceId,
    addr: &str,
    pending: Option<PairingMessage>,
) -> Result<(), End> {
    let mut attempt = ShowAttempt {
        shared,
        armed: false,
    };
    let result = pair_as_inner(
        shared,
        ctrl,
        role,
        peer_key,
        peer_id,
        addr,
        pending,
        &mut attempt.armed,
    )
    .await;
    match result {
        Err(end) if attempt.armed => {
            // The user must see it: the code is gone (`pair --show` ends).
            Err(End::err(
                ErrorKind::Pairing,
                format!(
                    "pairing with device {} at {addr} failed: {}; this pairing code is used up: run `telextilesd pair` again for a new one",
                    peer_id.short(),
                    end.message
                ),
            ))
        }
        // Whatever else ended the exchange on the entering side (the
        // device closed the stream or the connection, a write failed): it
        // proved no code, and it had its one try.
        Err(end) if role == PairingRole::EntersCode && end.kind != ErrorKind::PairingAttempt => {
            Err(End::err(
                ErrorKind::PairingAttempt,
                format!(
                    "device {} at {addr} left the pairing exchange without proving the code ({}); {STILL_LOOKING}",
                    peer_id.short(),
                    end.message
                ),
            ))
        }
        other => {
            attempt.armed = false;
            other
        }
    }
}

/// A refusal (a close with the pairing close code) from a device this side
/// enters a code with proved nothing: one failed attempt, not the end of
/// pairing.
fn as_attempt(end: End, enters_code: bool) -> End {
    if enters_code && end.kind == ErrorKind::Pairing {
        End {
            kind: ErrorKind::PairingAttempt,
            message: format!("{}; {STILL_LOOKING}", end.message),
            report: true,
        }
    } else {
        end
    }
}

#[allow(clippy::too_many_arguments)]
async fn pair_as_inner(
    shared: &Arc<Shared>,
    ctrl: &mut Ctrl,
    role: PairingRole,
    peer_key: &PeerKey,
    peer_id: DeviceId,
    addr: &str,
    mut pending: Option<PairingMessage>,
    code_taken: &mut bool,
) -> Result<(), End> {
    let code = {
        let mut mode = lock(&shared.pairing);
        match (&mut *mode, role) {
            (Some(PairingMode::Show(offer)), PairingRole::ShowsCode) => {
                match offer.take(std::time::Instant::now()) {
                    Ok(c) => {
                        *code_taken = true;
                        Ok(c)
                    }
                    Err(e) => Err((e.abort_reason(), e.to_string())),
                }
            }
            (Some(PairingMode::Enter(code)), PairingRole::EntersCode) => Ok(code.clone()),
            _ => Err((
                Some(telextiles_certs::pairing::PairingAbort::NotPairing),
                format!(
                    "device {} at {addr} is not paired with this device",
                    peer_id.short()
                ),
            )),
        }
    };
    // The exchange is the sans-IO machine's; this loop moves messages and
    // time.
    let mut x = PairingExchange::start(
        role,
        code,
        &shared.identity.peer_key(),
        peer_key,
        &mut rand::rngs::OsRng,
        addr.to_string(),
        now_us(),
        shared.timing.handshake_timeout,
    );
    if let Some(m) = pending.take() {
        x.handle_message(now_us(), Control::Pair(m));
    }
    let paired = 'pairing: loop {
        while let Some(action) = x.poll() {
            match action {
                PairAction::Send(msg) => {
                    let abort = matches!(msg, Control::Pair(PairingMessage::Abort(_)));
                    match ctrl.write(&msg).await {
                        Err(e) if !abort => return Err(End::quiet(e)),
                        _ => {}
                    }
                }
                PairAction::Paired(p) => break 'pairing p,
                PairAction::Fail {
                    error,
                    session_failed,
                } => {
                    if session_failed {
                        finish_pairing_mode(shared);
                    }
                    return Err(End::err(error.kind, error.message));
                }
            }
        }
        let read = match x.poll_timeout() {
            Some(deadline) => {
                let wait = Duration::from_micros(deadline.saturating_sub(now_us()));
                tokio::time::timeout(wait, ctrl.read()).await.ok()
            }
            None => Some(ctrl.read().await),
        };
        match read {
            None => x.handle_timeout(now_us().max(x.poll_timeout().unwrap_or(0))),
            Some(Ok(msg)) => x.handle_message(now_us(), msg),
            Some(Err(f)) => {
                if !x.handle_read_error() {
                    return Err(f.into_end(addr));
                }
            }
        }
    };
    // Pin now; store if we have a data dir.
    shared.pins.insert(paired.peer_id);
    if let Some(dir) = shared.data_dir.clone() {
        let key = paired.peer_key;
        let name = paired.peer_id.short();
        // Its address is remembered when the session comes up.
        let res = tokio::task::spawn_blocking(move || {
            TrustStore::update(&dir, |s| {
                s.insert(PeerRecord::new(key, &name, SystemTime::now()));
                (true, ())
            })
        })
        .await;
        let err = match res {
            Ok(Ok(())) => None,
            Ok(Err(e)) => Some(e.to_string()),
            Err(e) => Some(e.to_string()),
        };
        if let Some(e) = err {
            shared
                .emit(LinkEvent::Error {
                    peer: Some(peer_id),
                    kind: ErrorKind::Local,
                    message: format!("paired, but could not save the trust store: {e}"),
                })
                .await;
        }
    }
    finish_pairing_mode(shared);
    shared
        .emit(LinkEvent::Paired {
            peer: paired.peer_id,
            verification: paired.verification,
        })
        .await;
    Ok(())
}

/// One attempt per code: after any pairing outcome the link stops pairing
/// and only accepts pinned peers in the TLS handshake.
fn finish_pairing_mode(shared: &Arc<Shared>) {
    let was_show = matches!(lock(&shared.pairing).take(), Some(PairingMode::Show(_)));
    if was_show {
        shared.set_gate_open(false);
        // Withdraw `pair=1` from the mDNS advert.
        let advert = lock(&shared.advert).as_ref().and_then(|w| w.upgrade());
        if let Some(d) = advert {
            if let Err(e) = d.set_pairing(false) {
                shared.emit_now(LinkEvent::Error {
                    peer: None,
                    kind: ErrorKind::Local,
                    message: format!(
                        "could not withdraw the pairing flag from the mDNS advert: {e}"
                    ),
                });
            }
        }
    }
}

/// Saves the peer's direct address (if it was reached at one) and name in
/// the trust store (best effort).
fn remember(shared: &Arc<Shared>, peer: DeviceId, addr: Option<std::net::SocketAddr>, name: &str) {
    let Some(dir) = shared.data_dir.clone() else {
        return;
    };
    let name = name.to_string();
    tokio::task::spawn_blocking(move || {
        let _ = TrustStore::update(&dir, |s| {
            let addrs: Vec<_> = addr.into_iter().collect();
            let mut changed = s.note_addresses(&peer, &addrs, SystemTime::now());
            if let Some(rec) = s.get(&peer) {
                let clean = telextiles_certs::trust::sanitize_name(&name);
                if rec.name != clean {
                    let mut r = rec.clone();
                    r.name = clean;
                    s.insert(r);
                    changed = true;
                }
            }
            (changed, ())
        });
    });
}

/// The live session: control reader, control writer, pings, datagrams.
async fn stream(
    shared: &Arc<Shared>,
    conn: &Connection,
    peer_id: DeviceId,
    ctrl: Ctrl,
    ctrl_tx: mpsc::Sender<Control>,
    mut ctrl_rx: mpsc::Receiver<Control>,
    clock: Arc<Mutex<ConnMachine>>,
) -> String {
    let Ctrl {
        mut send,
        recv,
        dec,
        buf,
    } = ctrl;

    // Writer.
    let writer = crate::AbortOnDrop(tokio::spawn(async move {
        while let Some(msg) = ctrl_rx.recv().await {
            let msg = match msg {
                // Stamp pongs as late as possible.
                Control::Pong {
                    id, t1_us, t2_us, ..
                } => Control::Pong {
                    id,
                    t1_us,
                    t2_us,
                    t3_us: now_us(),
                },
                Control::Ping { id, .. } => Control::Ping {
                    id,
                    t1_us: now_us(),
                },
                m => m,
            };
            let Ok(bytes) = peer::encode_control(&msg) else {
                continue;
            };
            if send.write_all(&bytes).await.is_err() {
                return;
            }
        }
    }));

    // Pinger: sleeps until the clock machine's next ping is due.
    let ping_tx = ctrl_tx.clone();
    let pclock = clock.clone();
    let pinger = crate::AbortOnDrop(tokio::spawn(async move {
        loop {
            let Some(due) = lock(&pclock).poll_timeout() else {
                return;
            };
            let wait = due.saturating_sub(now_us());
            if wait > 0 {
                tokio::time::sleep(Duration::from_micros(wait)).await;
            }
            let actions = {
                let mut c = lock(&pclock);
                c.handle_timeout(now_us());
                std::iter::from_fn(|| c.poll()).collect::<Vec<_>>()
            };
            for a in actions {
                // A full queue (the peer does not read) skips this ping.
                if let Action::Send(m) = a {
                    if let Err(mpsc::error::TrySendError::Closed(_)) = ping_tx.try_send(m) {
                        return;
                    }
                }
            }
        }
    }));

    // Datagrams.
    let dconn = conn.clone();
    let dshared = shared.clone();
    let dclock = clock.clone();
    let datagrams = crate::AbortOnDrop(tokio::spawn(async move {
        let mut latest = LatestWins::new();
        let mut errors = RateLimit::new();
        while let Ok(bytes) = dconn.read_datagram().await {
            let recv_us = now_us();
            let frame = match LatentFrame::decode(&bytes) {
                Ok(f) => f,
                Err(e) => {
                    dshared.bad_datagrams.fetch_add(1, Ordering::Relaxed);
                    let msg = format!("dropped a bad latent datagram: {e}");
                    if let Some(message) = errors.check(std::time::Instant::now(), msg) {
                        dshared.emit_now(LinkEvent::Error {
                            peer: Some(peer_id),
                            kind: ErrorKind::Protocol,
                            message,
                        });
                    }
                    continue;
                }
            };
            if !latest.accept(frame.seq) {
                continue;
            }
            let one_way = lock(&dclock).one_way_us(frame.capture_us, recv_us);
            dshared.emit_now(LinkEvent::Latent(Latent {
                peer: peer_id,
                seq: frame.seq,
                press_id: frame.press_id,
                capture_us: frame.capture_us,
                is_final: frame.is_final(),
                vector: frame.vector.dequantize(),
                wire_bytes: bytes.len(),
                one_way_latency_us: one_way,
                received_us: recv_us,
            }));
        }
    }));

    // Path watcher: the route (relay or direct) and its round trip, told
    // when the route changes (hole punching moved it, or it fell back).
    let pconn = conn.clone();
    let pshared = shared.clone();
    let paths = crate::AbortOnDrop(tokio::spawn(async move {
        let mut last = route_of(&pconn).0;
        loop {
            tokio::time::sleep(PATH_POLL).await;
            let (route, rtt) = route_of(&pconn);
            if route != last {
                last = route.clone();
                pshared.emit_now(LinkEvent::PathChanged {
                    peer: peer_id,
                    route,
                    rtt: rtt.unwrap_or_default(),
                });
            }
        }
    }));

    // Control reader (this task).
    let mut ctrl = ReaderOnly { recv, dec, buf };
    let reason = loop {
        match ctrl.read().await {
            Ok(msg) => {
                let actions = {
                    let mut c = lock(&clock);
                    c.handle_message(now_us(), msg, Local::default());
                    std::iter::from_fn(|| c.poll()).collect::<Vec<_>>()
                };
                for a in actions {
                    match a {
                        // Pongs: a ping flood from a peer that does not read
                        // its pongs fills the bounded queue; the rest drop.
                        Action::Send(m) => {
                            let _ = ctrl_tx.try_send(m);
                        }
                        Action::Deliver(msg) => {
                            shared.emit(LinkEvent::Control { peer: peer_id, msg }).await;
                        }
                        _ => {}
                    }
                }
            }
            Err(ReadFail::Conn(_)) if !shared.pins.contains(&peer_id) => {
                break "unpaired on this device".to_string()
            }
            Err(ReadFail::Conn(e)) => break explain(&e, &describe(conn)).message,
            Err(ReadFail::Closed(s)) => break s,
            Err(ReadFail::Protocol(s)) => {
                conn.close(close_code::PROTOCOL.into(), b"bad control message");
                break format!("the peer sent a bad control message: {s}");
            }
        }
    };
    // Ended before the connection closes (and on any cancellation of this
    // future, by the guards' drop).
    drop((writer, pinger, datagrams, paths));
    if conn.close_reason().is_none() {
        conn.close(close_code::BYE.into(), b"session ended");
    }
    reason
}

struct ReaderOnly {
    recv: RecvStream,
    dec: FrameDecoder,
    buf: Vec<u8>,
}

impl ReaderOnly {
    async fn read(&mut self) -> Result<Control, ReadFail> {
        loop {
            match self.dec.next_message() {
                Ok(Some(m)) => return Ok(m),
                Ok(None) => {}
                Err(e) => return Err(ReadFail::Protocol(e.to_string())),
            }
            match self.recv.read(&mut self.buf).await {
                Ok(Some(n)) => {
                    let chunk = self.buf[..n].to_vec();
                    self.dec.push(&chunk);
                }
                Ok(None) => {
                    return Err(ReadFail::Closed(
                        "the peer closed the control stream".into(),
                    ))
                }
                Err(iroh::endpoint::ReadError::ConnectionLost(e)) => return Err(ReadFail::Conn(e)),
                Err(e) => return Err(ReadFail::Closed(e.to_string())),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dial::bounded_addrs;
    use std::net::SocketAddr;

    fn a(i: u16) -> SocketAddr {
        SocketAddr::from(([192, 0, 2, 1], i))
    }

    /// Spoofed mDNS adverts claiming a paired peer cannot grow its dial
    /// list (issue 19: 30 of 30 attacker addresses were dialled), nor push
    /// out the addresses it was really reached at.
    #[test]
    fn dial_addresses_are_bounded_deduplicated_and_keep_the_known_ones() {
        let known = vec![a(1), a(2)];
        let mut list = bounded_addrs(known.clone(), &[]);
        for round in 0..30u16 {
            let spoofed: Vec<SocketAddr> = (0..30).map(|i| a(1000 + round * 30 + i)).collect();
            list = bounded_addrs(spoofed, &list);
            assert!(list.len() <= limits::MAX_PEER_ADDRS, "{}", list.len());
            for k in &known {
                assert!(list.contains(k), "round {round}: lost {k}");
            }
        }
        assert_eq!(
            bounded_addrs(vec![a(5), a(5), a(7)], &[a(6), a(5)]),
            vec![a(6), a(5), a(7)]
        );
        // A real new address from an advert is tried.
        assert!(bounded_addrs(vec![a(9)], &list).contains(&a(9)));
    }
}
