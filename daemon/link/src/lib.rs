//! Peer link: mDNS discovery, pairing over the connection, and QUIC
//! streaming between two paired Telextiles daemons, on an iroh endpoint.
//!
//! One iroh endpoint (one UDP socket, plus a relay when one is configured)
//! both listens and dials. Its key is the device's identity key
//! ([`Identity::secret_seed`]), so a peer is dialled by its
//! [`PeerKey`] and the dial pins it (TLS 1.3 with raw public keys, ALPN
//! [`ALPN`]). An incoming connection from a device that is not paired is
//! closed by the endpoint's after-handshake hook ([`close_code::NOT_PAIRED`])
//! before the link sees it or any application data (outside pairing mode).
//! Between two networks the endpoint meets its peer through the relay and
//! goes direct when hole punching succeeds (iroh's QUIC NAT traversal).
//!
//! On each connection the dialing side opens one bidirectional **control
//! stream** ([`telextiles_proto::peer::Control`] frames). Pairing messages go
//! first if the peer is not yet paired; then both sides exchange
//! [`Hello`](telextiles_proto::peer::Hello) and either `HelloAck` (streaming
//! starts: [`LinkEvent::PeerUp`]) or `Mismatch` (both users get a clear
//! [`LinkEvent::Error`], nothing is streamed). Latent vectors travel as QUIC
//! datagrams, latest wins. Pings every [`Timing::ping_interval`] feed an
//! NTP-style clock-offset estimate so received latents carry their one-way
//! latency.
//!
//! The connection protocol (hello/ack, pairing exchange, ping/pong and the
//! clock offset, duplicate resolution, a connection's life cycle) is in
//! [`conn`] as sans-IO state machines tested in simulated time; the tokio
//! code here and in `session.rs` drives them.
//!
//! Who dials: a peer found by mDNS or remembered in the trust store is
//! dialled by the side with the smaller device ID; addresses given with
//! `--connect` ([`LinkConfig::connect`]) are always dialled. If two
//! connections to one peer exist, both sides keep the one dialled by the
//! smaller ID (newest if both were), so they agree without talking.
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

mod addr;
pub mod conn;
mod dial;
pub mod discovery;
mod session;

use std::collections::HashMap;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use iroh::endpoint::{AfterHandshakeOutcome, Connection, EndpointHooks, QuicTransportConfig};
use telextiles_certs::{
    CodeOffer, DeviceId, Identity, PairingCode, PeerKey, PinSet, VerificationCode,
};
use telextiles_proto::peer::{self, Control, LatentFrame, QuantVec, FLAG_FINAL};
use tokio::sync::{mpsc, watch, Notify};

pub use addr::{PeerAddr, PeerAddrError, RelaySpec, Route};
pub use discovery::{DiscoveryConfig, Interfaces, SERVICE_TYPE};

/// The application protocol of the peer link (ALPN). The number follows
/// [`PROTOCOL_VERSION`].
pub const ALPN: &[u8] = b"telextiles/2";
pub use telextiles_proto::peer::{Hello, MismatchReason, PROTOCOL_VERSION};

/// QUIC application close codes used by the link.
pub mod close_code {
    /// Normal shutdown.
    pub const BYE: u32 = 0;
    /// The reason sent with [`BYE`] when the daemon itself shuts down (not
    /// just one session ending): its peers know it went away on purpose.
    pub const SHUTDOWN_REASON: &[u8] = b"shutdown";
    /// Superseded by another connection to the same peer.
    pub const DUPLICATE: u32 = 1;
    /// Hello mismatch (protocol, encoder, index).
    pub const INCOMPATIBLE: u32 = 2;
    /// Pairing failed or the peer is not paired.
    pub const PAIRING: u32 = 3;
    /// The peer broke the protocol.
    pub const PROTOCOL: u32 = 4;
    /// Refused by the endpoint's after-handshake hook: this device does not
    /// pin the dialler (it is not paired here), before any data.
    pub const NOT_PAIRED: u32 = 5;
    /// The reason sent with [`NOT_PAIRED`].
    pub const NOT_PAIRED_REASON: &[u8] = b"not paired with this device";
}

/// Resource limits sized to the protocol (one control stream of frames of
/// at most [`peer::MAX_CONTROL_FRAME`] bytes, latent datagrams, a handful of
/// paired peers). Everything a peer can make this daemon hold is bounded by
/// these; `docs/peer-protocol.md` lists them with measured memory.
pub mod limits {
    /// Connections (handshaking or established) at once, all peers.
    pub const MAX_CONNECTIONS: usize = 16;
    /// Connections at once from one IP address (or, through a relay, from
    /// one endpoint key).
    pub const MAX_CONNECTIONS_PER_IP: usize = 4;
    /// Bidirectional streams a peer may open at once (the control stream).
    pub const MAX_BIDI_STREAMS: u32 = 1;
    /// Per-stream receive window: one maximal control frame plus slack.
    pub const STREAM_WINDOW: u32 = 128 * 1024;
    /// Per-connection receive window (all streams) and send window.
    pub const CONNECTION_WINDOW: u32 = 256 * 1024;
    pub const SEND_WINDOW: u64 = 256 * 1024;
    /// Received datagrams buffered before the reader takes them.
    pub const DATAGRAM_RECEIVE_BUFFER: usize = 64 * 1024;
    /// Control messages queued for one peer's writer (pongs, pings, presses);
    /// when full, pongs and pings are dropped (the clock estimate needs only
    /// some of them) and `send_control` reports the peer as not queued.
    pub const CONTROL_QUEUE: usize = 64;
    /// Peer errors (bad datagrams, refused handshakes) reported per
    /// [`ERROR_WINDOW`](self::ERROR_WINDOW) and source; the rest are counted
    /// and summarised in the next report.
    pub const ERRORS_PER_WINDOW: u32 = 5;
    pub const ERROR_WINDOW: std::time::Duration = std::time::Duration::from_secs(10);
    /// Addresses dialled for one paired peer (newest first, deduplicated).
    pub const MAX_PEER_ADDRS: usize = 8;
    /// Devices advertising a pairing code that one pairing session dials.
    pub const MAX_PAIRING_DIALS: usize = 8;
}

/// Lets through at most [`limits::ERRORS_PER_WINDOW`] messages per
/// [`limits::ERROR_WINDOW`]; the next message after a quiet spell says how
/// many were suppressed. A peer cannot flood the log.
#[derive(Debug)]
pub(crate) struct RateLimit {
    window_start: Option<Instant>,
    in_window: u32,
    suppressed: u64,
    per_window: u32,
    window: Duration,
}

impl RateLimit {
    pub(crate) fn new() -> Self {
        Self::with(limits::ERRORS_PER_WINDOW, limits::ERROR_WINDOW)
    }

    pub(crate) fn with(per_window: u32, window: Duration) -> Self {
        RateLimit {
            window_start: None,
            in_window: 0,
            suppressed: 0,
            per_window,
            window,
        }
    }

    /// `Some(message)` (with a suppression note if any) if it may be
    /// reported now, `None` if it is suppressed.
    pub(crate) fn check(&mut self, now: Instant, message: String) -> Option<String> {
        match self.window_start {
            Some(t) if now.duration_since(t) < self.window => {}
            _ => {
                self.window_start = Some(now);
                self.in_window = 0;
            }
        }
        if self.in_window >= self.per_window {
            self.suppressed = self.suppressed.saturating_add(1);
            return None;
        }
        self.in_window += 1;
        if self.suppressed > 0 {
            let n = std::mem::take(&mut self.suppressed);
            Some(format!("{message} ({n} similar messages suppressed)"))
        } else {
            Some(message)
        }
    }
}

/// Microseconds on this process's monotonic clock (origin: first call).
/// Use it for [`LinkHandle::send_latent`]'s capture time.
pub fn now_us() -> u64 {
    static ORIGIN: OnceLock<Instant> = OnceLock::new();
    ORIGIN.get_or_init(Instant::now).elapsed().as_micros() as u64
}

/// What this side tells the peer in its hello.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HelloInfo {
    pub encoder_hash: String,
    pub index_fingerprint: String,
    pub embedding_dim: u16,
}

/// Timers of the link.
#[derive(Debug, Clone)]
pub struct Timing {
    /// QUIC keep-alive (PING frames) interval.
    pub keep_alive: Duration,
    /// A connection with no packets for this long is dead.
    pub idle_timeout: Duration,
    /// First reconnect delay; doubles per failure up to `backoff_max`.
    pub backoff_min: Duration,
    pub backoff_max: Duration,
    /// Clock-offset ping interval.
    pub ping_interval: Duration,
    /// Time allowed for the hello (and pairing) exchange.
    pub handshake_timeout: Duration,
    /// One dial attempt (QUIC + TLS handshake) is abandoned after this and
    /// a fresh one starts, so a peer that comes back is found quickly.
    pub connect_timeout: Duration,
}

impl Default for Timing {
    fn default() -> Self {
        Timing {
            keep_alive: Duration::from_millis(500),
            idle_timeout: Duration::from_secs(2),
            backoff_min: Duration::from_millis(100),
            backoff_max: Duration::from_secs(1),
            ping_interval: Duration::from_millis(500),
            handshake_timeout: Duration::from_secs(10),
            connect_timeout: Duration::from_millis(750),
        }
    }
}

/// How latents are quantised for the datagram.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Quantisation {
    /// f16 if it fits the connection's datagram size, else int8.
    #[default]
    Auto,
    /// Always int8 with a per-vector scale.
    Int8,
}

/// Pairing over the link (the `telextilesd pair` flow).
#[derive(Debug)]
pub enum PairingMode {
    /// This side shows the code; accepts one pairing attempt from an
    /// unpaired device.
    Show(CodeOffer),
    /// This side's user typed the code; dials the device that shows it
    /// (found by mDNS with the pairing flag, or `--connect`).
    Enter(PairingCode),
}

/// Everything [`Link::start`] needs besides the identity.
#[derive(Debug)]
pub struct LinkConfig {
    /// Shown to the peer's user.
    pub device_name: String,
    /// UDP address to listen (and dial) on, e.g. `0.0.0.0:0` or `[::]:4797`.
    pub listen: SocketAddr,
    pub hello: HelloInfo,
    /// Peers to dial explicitly (`--connect KEY@host:port`, or `KEY` through
    /// the relay).
    pub connect: Vec<PeerAddr>,
    /// Relays to meet peers through beyond the LAN (`relay_url`); empty:
    /// direct addresses only. Never a public relay unless named here.
    pub relays: Vec<RelaySpec>,
    /// mDNS advertise + browse; `None` disables multicast entirely.
    pub discovery: Option<DiscoveryConfig>,
    /// Data directory of the trust store: remembered peer addresses are
    /// dialled and updated; new pairings are stored. `None`: memory only.
    pub data_dir: Option<PathBuf>,
    pub pairing: Option<PairingMode>,
    pub timing: Timing,
    pub quantisation: Quantisation,
}

impl LinkConfig {
    /// A config with defaults: no discovery, no explicit peers, no pairing.
    pub fn new(device_name: impl Into<String>, listen: SocketAddr, hello: HelloInfo) -> Self {
        LinkConfig {
            device_name: device_name.into(),
            listen,
            hello,
            connect: Vec::new(),
            relays: Vec::new(),
            discovery: None,
            data_dir: None,
            pairing: None,
            timing: Timing::default(),
            quantisation: Quantisation::Auto,
        }
    }
}

/// A received latent vector.
#[derive(Debug, Clone)]
pub struct Latent {
    pub peer: DeviceId,
    pub seq: u64,
    pub press_id: u32,
    /// Capture time on the peer's clock (µs).
    pub capture_us: u64,
    /// Last frame of its press.
    pub is_final: bool,
    /// Dequantised vector (not re-normalised).
    pub vector: Vec<f32>,
    /// Bytes of the datagram.
    pub wire_bytes: usize,
    /// Capture on the peer → receipt here, from the clock-offset estimate;
    /// `None` until the first pong.
    pub one_way_latency_us: Option<i64>,
    /// When the datagram was read here ([`now_us`] of this process).
    pub received_us: u64,
}

/// What [`LinkHandle::send_latent_timed`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SentLatent {
    /// Sequence number of the frame.
    pub seq: u64,
    /// When the vector was quantised and encoded ([`now_us`]), before the
    /// datagrams were queued.
    pub encoded_us: u64,
}

/// Why a peer connection ended or could not start.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ErrorKind {
    /// The peer's encoder/index/protocol differs: no streaming.
    Incompatible(Vec<MismatchReason>),
    /// The peer refused this device in the TLS handshake (not paired there).
    RefusedByPeer,
    /// This side refused a device that is not paired.
    RefusedPeer,
    /// Pairing failed (wrong code, expired, ...) in a way that ends this
    /// side's pairing: on the side showing the code (its code is single-use)
    /// or a refusal from a device authenticated by its pin.
    Pairing,
    /// One device showing a code refused, stalled or failed the exchange
    /// without proving the code; pairing continues with other devices.
    /// Only the side entering a code reports it: nothing an unproven device
    /// says (an `Abort`, silence, a wrong confirmation) can end
    /// `pair --enter`, and that device is not dialled again for pairing
    /// (one exchange per device, so no repeated online guesses).
    PairingAttempt,
    /// Could not reach the peer / the connection failed.
    Connection,
    /// The peer broke the protocol.
    Protocol,
    /// mDNS or trust-store trouble.
    Local,
}

/// Events for the daemon.
#[derive(Debug, Clone)]
pub enum LinkEvent {
    /// The endpoint is bound.
    Listening {
        addr: SocketAddr,
    },
    /// mDNS saw a device (a claim only; TLS proves identity).
    Discovered {
        peer: DeviceId,
        addrs: Vec<SocketAddr>,
        paired: bool,
        pairing: bool,
    },
    /// Pairing succeeded; the peer is pinned (and stored if `data_dir`).
    Paired {
        peer: DeviceId,
        verification: VerificationCode,
    },
    /// Hello exchanged and compatible: streaming works both ways.
    PeerUp {
        peer: DeviceId,
        name: String,
        /// How the connection reaches the peer now (direct address or relay).
        addr: Route,
    },
    /// The path a connection's packets take changed (relayed → direct
    /// after hole punching, or back).
    PathChanged {
        peer: DeviceId,
        route: Route,
        /// Smoothed round-trip time of that path.
        rtt: Duration,
    },
    /// The connection to a peer ended.
    PeerDown {
        peer: DeviceId,
        reason: String,
    },
    /// The connection to a configured relay came up, or went down or
    /// failed (a relay that does not serve this device's key says so in
    /// `error`). Told on each change; the first attempt's "connecting" is
    /// not told.
    Relay {
        url: String,
        connected: bool,
        error: Option<String>,
    },
    Latent(Latent),
    /// A control message other than hello/ping (press start/stop, errors).
    Control {
        peer: DeviceId,
        msg: Control,
    },
    /// Something the user should read.
    Error {
        peer: Option<DeviceId>,
        kind: ErrorKind,
        message: String,
    },
}

/// Errors of the [`LinkHandle`] API and of start-up.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("cannot bind the peer-link UDP socket on {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("TLS configuration failed: {0}")]
    Tls(#[from] rustls::Error),
    #[error("QUIC configuration failed: {0}")]
    Quic(String),
    #[error("the identity's key cannot be the link's key: {0}")]
    Key(String),
    #[error("mDNS discovery failed: {0}")]
    Discovery(String),
    #[error("no peer is connected")]
    NoPeer,
    #[error("the vector has {dim} components; no encoding fits the {max}-byte datagrams of this connection")]
    TooLarge { dim: usize, max: usize },
    #[error("invalid message: {0}")]
    Message(#[from] peer::PeerError),
    #[error("the link has shut down")]
    Closed,
}

pub(crate) struct PeerSlot {
    pub conn: Connection,
    pub ctrl: mpsc::Sender<Control>,
    pub dialed_by_lower: bool,
}

pub(crate) struct Shared {
    pub my_id: DeviceId,
    pub identity: Identity,
    pub pins: PinSet,
    pub endpoint: iroh::Endpoint,
    /// Whether the gate lets unpaired devices in (showing a pairing code).
    pub open_gate: Arc<AtomicBool>,
    /// A relay is configured: paired peers are dialled by key alone too.
    pub relayed: bool,
    pub gate_refused: Arc<Mutex<Option<DeviceId>>>,
    /// The relays' URLs, added to every dial.
    pub relay_urls: Vec<iroh::RelayUrl>,
    pub events: mpsc::Sender<LinkEvent>,
    pub peers: Mutex<HashMap<DeviceId, PeerSlot>>,
    pub peers_changed: Notify,
    pub pairing: Mutex<Option<PairingMode>>,
    pub hello: Hello,
    pub timing: Timing,
    pub quantisation: Quantisation,
    pub data_dir: Option<PathBuf>,
    pub shutdown: watch::Sender<bool>,
    pub dialing: Mutex<HashMap<DeviceId, watch::Sender<PeerAddr>>>,
    pub stopped: AtomicBool,
    /// Open accepted connections per origin (remote IP, or key through a
    /// relay).
    pub conns: Mutex<HashMap<session::Origin, usize>>,
    /// Rate limit of errors caused by unauthenticated senders (refused
    /// handshakes, failed incoming connections).
    pub refusals: Mutex<RateLimit>,
    /// The mDNS advert, to withdraw its pairing flag when pairing ends.
    pub advert: Mutex<Option<std::sync::Weak<discovery::Discovery>>>,
    /// What [`LinkHandle::stats`] reports.
    pub bad_datagrams: AtomicU64,
    pub latents_dropped: AtomicU64,
    /// The link's long-lived tasks (accepting, dialing, discovery, the
    /// trust-store watch, each accepted connection): owned here, aborted
    /// at shutdown and when the last [`LinkHandle`] goes; none detached. A
    /// connection's own writer, pinger and datagram reader are owned by its
    /// task ([`AbortOnDrop`]).
    pub tasks: Mutex<tokio::task::JoinSet<()>>,
}

/// A task aborted when this is dropped: its owner's future ended or was
/// cancelled.
pub(crate) struct AbortOnDrop(pub tokio::task::JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// The last [`LinkHandle`]'s end: the link's tasks, which hold the shared
/// state (and so the endpoint), are aborted.
struct Owner(Arc<Shared>);

impl Drop for Owner {
    fn drop(&mut self) {
        self.0.abort_tasks();
    }
}

impl Shared {
    /// Spawn one of the link's tasks ([`Shared::tasks`]); finished ones
    /// are reaped first, so the set holds only live tasks.
    pub(crate) fn spawn(&self, task: impl std::future::Future<Output = ()> + Send + 'static) {
        let mut tasks = lock(&self.tasks);
        while tasks.try_join_next().is_some() {}
        tasks.spawn(task);
    }

    /// Abort every task of the link.
    pub(crate) fn abort_tasks(&self) {
        lock(&self.tasks).abort_all();
    }

    /// Live tasks of the link (finished ones reaped).
    pub(crate) fn live_tasks(&self) -> usize {
        let mut tasks = lock(&self.tasks);
        while tasks.try_join_next().is_some() {}
        tasks.len()
    }

    pub(crate) async fn emit(&self, ev: LinkEvent) {
        let _ = self.events.send(ev).await;
    }

    /// Emits without waiting: an event that finds the channel full is
    /// dropped (a latent is counted in [`LinkStats::latents_dropped`]).
    pub(crate) fn emit_now(&self, ev: LinkEvent) {
        if let Err(mpsc::error::TrySendError::Full(LinkEvent::Latent(_))) = self.events.try_send(ev)
        {
            self.latents_dropped.fetch_add(1, Ordering::Relaxed);
        }
    }

    pub(crate) fn is_up(&self, id: &DeviceId) -> bool {
        lock(&self.peers).contains_key(id)
    }

    pub(crate) fn pairing_mode(&self) -> bool {
        lock(&self.pairing).is_some()
    }

    /// Revokes a peer at once: drops its pin (new handshakes are refused),
    /// stops dialing it and closes its live connection (the session ends
    /// with `PeerDown`).
    pub(crate) fn revoke(&self, id: &DeviceId) {
        self.pins.remove(id);
        lock(&self.dialing).remove(id);
        let conn = lock(&self.peers).get(id).map(|p| p.conn.clone());
        if let Some(c) = conn {
            c.close(close_code::PAIRING.into(), b"unpaired");
        }
        self.peers_changed.notify_waiters();
    }

    /// Lets unpaired devices through the handshake (while showing a
    /// pairing code) or not.
    pub(crate) fn set_gate_open(&self, open: bool) {
        self.open_gate.store(open, Ordering::SeqCst);
    }
}

pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The endpoint's after-handshake hook: an accepted connection from a
/// device this one does not pin is closed with [`close_code::NOT_PAIRED`]
/// before the link (or any stream or datagram) sees it, unless a pairing
/// code is shown. Dialled connections went to a key this side chose.
#[derive(Debug)]
struct Gate {
    pins: PinSet,
    open: Arc<AtomicBool>,
    /// The device refused last, for the accepting side's report.
    refused: Arc<Mutex<Option<DeviceId>>>,
}

impl EndpointHooks for Gate {
    async fn after_handshake(&self, conn: &Connection) -> AfterHandshakeOutcome {
        if conn.side() == iroh::endpoint::Side::Client || self.open.load(Ordering::SeqCst) {
            return AfterHandshakeOutcome::Accept;
        }
        let id = addr::key_of(&conn.remote_id()).device_id();
        if self.pins.contains(&id) {
            AfterHandshakeOutcome::Accept
        } else {
            *lock(&self.refused) = Some(id);
            AfterHandshakeOutcome::Reject {
                error_code: close_code::NOT_PAIRED.into(),
                reason: close_code::NOT_PAIRED_REASON.to_vec(),
            }
        }
    }
}

/// What the link dropped from paired peers, counted since it started
/// ([`LinkHandle::stats`]): the errors are reported rate-limited, these
/// count every one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct LinkStats {
    /// Datagrams from a connected peer that did not decode as a latent
    /// frame (each dropped; reported as rate-limited `Error` events).
    pub bad_datagrams: u64,
    /// Latents received and decoded but dropped because the event channel
    /// was full (the application did not keep up; latest wins, so a later
    /// latent of the press takes its place).
    pub latents_dropped: u64,
}

/// The running link. Dropping every handle does not stop it; call
/// [`LinkHandle::shutdown`].
pub struct Link;

/// Cheap to clone; talks to the running link.
#[derive(Clone)]
pub struct LinkHandle {
    shared: Arc<Shared>,
    _owner: Arc<Owner>,
    seq: Arc<AtomicU64>,
    local_addr: SocketAddr,
    _discovery: Option<Arc<discovery::Discovery>>,
}

impl Link {
    /// Binds the endpoint, starts discovery, dialing and accepting. Must be
    /// called inside a tokio runtime. Events arrive on the receiver
    /// (bounded; latents are dropped, never queued, when it is full).
    pub async fn start(
        config: LinkConfig,
        identity: Identity,
        pins: PinSet,
    ) -> Result<(LinkHandle, mpsc::Receiver<LinkEvent>), LinkError> {
        let LinkConfig {
            device_name,
            listen,
            hello,
            connect,
            relays,
            discovery,
            data_dir,
            pairing,
            timing,
            quantisation,
        } = config;
        let transport = QuicTransportConfig::builder()
            .keep_alive_interval(timing.keep_alive)
            .max_idle_timeout(Some(
                iroh::endpoint::IdleTimeout::try_from(timing.idle_timeout)
                    .map_err(|e| LinkError::Quic(e.to_string()))?,
            ))
            .max_concurrent_bidi_streams(limits::MAX_BIDI_STREAMS.into())
            .max_concurrent_uni_streams(0u32.into())
            .stream_receive_window(limits::STREAM_WINDOW.into())
            .receive_window(limits::CONNECTION_WINDOW.into())
            .send_window(limits::SEND_WINDOW)
            .datagram_receive_buffer_size(Some(limits::DATAGRAM_RECEIVE_BUFFER))
            // Latest wins at the sender too: a small send buffer makes QUIC
            // drop the oldest queued latents instead of delaying new ones.
            .datagram_send_buffer_size(4 * 1300)
            // Model-based congestion control: random loss (Wi-Fi) does not
            // collapse the window the way loss-based controllers do.
            .congestion_controller_factory(Arc::new(noq::congestion::Bbr3Config::default()))
            .build();
        let seed = identity
            .secret_seed()
            .ok_or_else(|| LinkError::Key("it is not an Ed25519 key".into()))?;
        let secret = iroh::SecretKey::from_bytes(&seed);
        if addr::key_of(&secret.public()) != identity.peer_key() {
            return Err(LinkError::Key(
                "its secret does not give its public key".into(),
            ));
        }
        let gate_refused = Arc::new(Mutex::new(None));
        let open_gate = Arc::new(AtomicBool::new(matches!(
            pairing,
            Some(PairingMode::Show(_))
        )));
        let endpoint = addr::bind_endpoint(
            secret,
            listen,
            &relays,
            transport,
            Gate {
                pins: pins.clone(),
                open: open_gate.clone(),
                refused: gate_refused.clone(),
            },
        )
        .await?;
        let local_addr =
            endpoint
                .bound_sockets()
                .into_iter()
                .next()
                .ok_or_else(|| LinkError::Bind {
                    addr: listen,
                    source: std::io::Error::other("the endpoint bound no socket"),
                })?;
        let (tx, rx) = mpsc::channel(1024);
        let (shutdown, _) = watch::channel(false);
        let enter_mode = matches!(pairing, Some(PairingMode::Enter(_)));
        let show_mode = matches!(pairing, Some(PairingMode::Show(_)));
        let my_id = identity.device_id();
        let shared = Arc::new(Shared {
            my_id,
            identity,
            pins,
            endpoint,
            open_gate,
            gate_refused,
            relayed: !relays.is_empty(),
            relay_urls: relays.iter().map(|r| r.url.clone()).collect(),
            events: tx,
            peers: Mutex::new(HashMap::new()),
            peers_changed: Notify::new(),
            pairing: Mutex::new(pairing),
            hello: Hello {
                protocol_version: PROTOCOL_VERSION,
                device_name: truncate(&device_name, peer::MAX_NAME_LEN),
                encoder_hash: hello.encoder_hash,
                index_fingerprint: hello.index_fingerprint,
                embedding_dim: hello.embedding_dim,
            },
            timing,
            quantisation,
            data_dir,
            shutdown,
            dialing: Mutex::new(HashMap::new()),
            stopped: AtomicBool::new(false),
            conns: Mutex::new(HashMap::new()),
            refusals: Mutex::new(RateLimit::new()),
            bad_datagrams: AtomicU64::new(0),
            latents_dropped: AtomicU64::new(0),
            advert: Mutex::new(None),
            tasks: Mutex::new(tokio::task::JoinSet::new()),
        });
        shared.emit(LinkEvent::Listening { addr: local_addr }).await;
        if shared.relayed {
            shared.spawn(watch_relay(shared.clone()));
        }

        shared.spawn(session::accept_loop(shared.clone()));
        if let Some(dir) = shared.data_dir.clone() {
            shared.spawn(watch_trust_store(shared.clone(), dir));
        }

        for addr in connect {
            shared.spawn(dial::dial_loop(shared.clone(), addr, true));
        }
        // Paired peers: at their remembered addresses, and through the
        // relay when one is configured.
        if let Some(dir) = &shared.data_dir {
            if let Ok(store) = telextiles_certs::TrustStore::load(dir) {
                for p in store.peers() {
                    if shared.pins.contains(&p.device_id)
                        && (shared.relayed || !p.last_addresses.is_empty())
                    {
                        let to = PeerAddr::new(p.key, p.last_addresses.clone());
                        dial::ensure_dialing(&shared, to);
                    }
                }
            }
        }
        let disc = match discovery {
            Some(dcfg) => {
                let (d, found) = discovery::Discovery::start(
                    &dcfg,
                    &shared.identity.peer_key(),
                    local_addr.port(),
                    show_mode,
                )?;
                shared.spawn(dial::discovery_loop(shared.clone(), found, enter_mode));
                let d = Arc::new(d);
                *lock(&shared.advert) = Some(Arc::downgrade(&d));
                if show_mode && !shared.pairing_mode() {
                    // Pairing already ended while discovery was starting.
                    let _ = d.set_pairing(false);
                }
                Some(d)
            }
            None => None,
        };
        Ok((
            LinkHandle {
                _owner: Arc::new(Owner(shared.clone())),
                shared,
                seq: Arc::new(AtomicU64::new(1)),
                local_addr,
                _discovery: disc,
            },
            rx,
        ))
    }
}

/// What a [`LinkEvent::Relay`] tells the user, one line.
pub fn relay_status_line(url: &str, connected: bool, error: Option<&str>) -> String {
    match (connected, error) {
        (true, _) => format!("Relay {url}: connected (peers beyond the LAN can reach this device)"),
        (false, Some(e)) => format!("Relay {url}: not connected, retrying: {e}"),
        (false, None) => format!("Relay {url}: not connected, retrying"),
    }
}

/// Tells the connection state of the home relay as it changes
/// ([`LinkEvent::Relay`]): a relay that is down, unreachable or refuses this
/// device's key is said, not only seen as peers that never come up.
async fn watch_relay(shared: Arc<Shared>) {
    use iroh::Watcher;
    let mut watcher = shared.endpoint.home_relay_status();
    let mut told: HashMap<String, (bool, Option<String>)> = HashMap::new();
    let mut value = watcher.get();
    loop {
        for status in &value {
            let url = status.url().to_string();
            let connected = status.is_connected();
            let error = match (status.auth_denied_reason(), status.last_error()) {
                (Some(why), _) => Some(format!("the relay refused this device: {why}")),
                (None, Some(e)) if !connected => Some(format!("{e:#}")),
                _ => None,
            };
            let state = (connected, error.clone());
            let first = !told.contains_key(&url);
            if told.get(&url) == Some(&state) || (first && !connected && error.is_none()) {
                continue;
            }
            told.insert(url.clone(), state);
            shared.emit_now(LinkEvent::Relay {
                url,
                connected,
                error,
            });
        }
        value = match watcher.updated().await {
            Ok(v) => v,
            Err(_) => return,
        };
    }
}

/// How often the trust store file is checked for changes made by another
/// process (`telextilesd unpair`).
pub const TRUST_STORE_POLL: Duration = Duration::from_millis(200);

/// Identity of the trust store file's current version (a rewrite replaces
/// the file, so the inode changes too).
fn store_stamp(path: &std::path::Path) -> Option<(u64, u64, i64, i64)> {
    use std::os::unix::fs::MetadataExt;
    let m = std::fs::metadata(path).ok()?;
    Some((m.ino(), m.len(), m.mtime(), m.mtime_nsec()))
}

/// Applies changes of the trust store on disk to the running link: a peer
/// removed from the file (unpaired by the CLI or another process) is
/// revoked within [`TRUST_STORE_POLL`]; one added is pinned.
async fn watch_trust_store(shared: Arc<Shared>, dir: PathBuf) {
    let path = telextiles_certs::TrustStore::path_in(&dir);
    let load = |dir: PathBuf| async move {
        tokio::task::spawn_blocking(move || {
            telextiles_certs::TrustStore::load(&dir)
                .map(|s| s.device_ids().collect::<std::collections::BTreeSet<_>>())
        })
        .await
        .ok()
        .and_then(Result::ok)
    };
    let mut stamp = store_stamp(&path);
    let mut known = match load(dir.clone()).await {
        Some(k) => k,
        None => shared.pins.snapshot().into_iter().collect(),
    };
    let mut stop = shared.shutdown.subscribe();
    loop {
        tokio::select! {
            _ = tokio::time::sleep(TRUST_STORE_POLL) => {}
            _ = stop.changed() => return,
        }
        let now = store_stamp(&path);
        if now == stamp {
            continue;
        }
        // A missing file is an empty store (every peer unpaired).
        let ids = if now.is_none() {
            Some(Default::default())
        } else {
            load(dir.clone()).await
        };
        let Some(ids) = ids else {
            // Unreadable or mid-write: try again next time.
            continue;
        };
        stamp = now;
        for gone in known.difference(&ids) {
            shared.revoke(gone);
        }
        for new in ids.difference(&known) {
            shared.pins.insert(*new);
        }
        known = ids;
    }
}

fn truncate(s: &str, max: usize) -> String {
    let mut end = s.len().min(max);
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    s[..end].to_string()
}

impl LinkHandle {
    /// The bound UDP address.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// This device's ID.
    pub fn device_id(&self) -> DeviceId {
        self.shared.my_id
    }

    /// Counts since the link started.
    pub fn stats(&self) -> LinkStats {
        LinkStats {
            bad_datagrams: self.shared.bad_datagrams.load(Ordering::Relaxed),
            latents_dropped: self.shared.latents_dropped.load(Ordering::Relaxed),
        }
    }

    /// Peers whose hello succeeded and whose connection is alive.
    pub fn connected_peers(&self) -> Vec<DeviceId> {
        lock(&self.shared.peers).keys().copied().collect()
    }

    /// Sends one latent vector to every connected peer as a datagram
    /// (fire and forget, latest wins). Returns the sequence number used.
    /// `final_frame` marks the last frame of a press.
    pub fn send_latent(
        &self,
        press_id: u32,
        vector: &[f32],
        capture_us: u64,
        final_frame: bool,
    ) -> Result<u64, LinkError> {
        self.send_latent_timed(press_id, vector, capture_us, final_frame)
            .map(|s| s.seq)
    }

    /// [`LinkHandle::send_latent`], also saying when the frame was
    /// quantised and encoded (for per-stage latency measurements).
    pub fn send_latent_timed(
        &self,
        press_id: u32,
        vector: &[f32],
        capture_us: u64,
        final_frame: bool,
    ) -> Result<SentLatent, LinkError> {
        let peers: Vec<Connection> = lock(&self.shared.peers)
            .values()
            .map(|p| p.conn.clone())
            .collect();
        if peers.is_empty() {
            return Err(LinkError::NoPeer);
        }
        let seq = self.seq.fetch_add(1, Ordering::Relaxed);
        let mut encoded_us = 0;
        let mut sent = 0;
        let mut last_err = None;
        for conn in peers {
            let max = conn.max_datagram_size().unwrap_or(0);
            let quant = match self.shared.quantisation {
                Quantisation::Auto => peer::quantize_to_fit(vector, max),
                Quantisation::Int8 => Some(QuantVec::quantize_i8(vector))
                    .filter(|q| peer::DATAGRAM_HEADER_LEN + q.encoded_len() <= max),
            };
            let Some(quant) = quant else {
                last_err = Some(LinkError::TooLarge {
                    dim: vector.len(),
                    max,
                });
                continue;
            };
            let frame = LatentFrame {
                seq,
                capture_us,
                press_id,
                flags: if final_frame { FLAG_FINAL } else { 0 },
                vector: quant,
            };
            let bytes = frame.encode()?;
            encoded_us = now_us();
            if conn.send_datagram(bytes::Bytes::from(bytes)).is_ok() {
                sent += 1;
            }
        }
        match (sent, last_err) {
            (0, Some(e)) => Err(e),
            _ => Ok(SentLatent { seq, encoded_us }),
        }
    }

    /// Sends a control message (reliable, ordered) to every connected peer.
    /// Returns how many peers it was queued for.
    pub fn send_control(&self, msg: Control) -> Result<usize, LinkError> {
        msg.validate()?;
        let peers = lock(&self.shared.peers);
        if peers.is_empty() {
            return Err(LinkError::NoPeer);
        }
        let mut n = 0;
        for p in peers.values() {
            if p.ctrl.try_send(msg.clone()).is_ok() {
                n += 1;
            }
        }
        Ok(n)
    }

    /// Convenience: `PressStop` carrying the press's final latent (int8), so
    /// the receiver's final decision never depends on a lost datagram.
    pub fn send_press_stop(
        &self,
        press_id: u32,
        final_vector: Option<&[f32]>,
        capture_us: u64,
    ) -> Result<usize, LinkError> {
        let final_latent = final_vector.map(|v| LatentFrame {
            seq: self.seq.fetch_add(1, Ordering::Relaxed),
            capture_us,
            press_id,
            flags: FLAG_FINAL,
            vector: QuantVec::quantize_i8(v),
        });
        self.send_control(Control::PressStop {
            press_id,
            capture_us,
            final_latent,
        })
    }

    /// Unpairs `peer` in the running link: its pin is dropped, it is no
    /// longer dialled, and its live connection is closed at once (the
    /// trust store on disk is the caller's to update; a change there made
    /// by another process is picked up within [`TRUST_STORE_POLL`] anyway).
    pub fn unpair(&self, peer: &DeviceId) {
        self.shared.revoke(peer);
    }

    /// Dials a peer (like `--connect`) from now on, with reconnects.
    pub fn connect(&self, to: PeerAddr) {
        self.shared
            .spawn(dial::dial_loop(self.shared.clone(), to, true));
    }

    /// This device's key: what peers dial (with an address, or alone
    /// through a relay).
    pub fn peer_key(&self) -> PeerKey {
        self.shared.identity.peer_key()
    }

    /// The route and round-trip time of each connected peer's connection
    /// now.
    pub fn routes(&self) -> Vec<(DeviceId, Route, Option<Duration>)> {
        lock(&self.shared.peers)
            .iter()
            .map(|(id, p)| {
                let (route, rtt) = addr::route_of(&p.conn);
                (*id, route, rtt)
            })
            .collect()
    }

    /// Closes every connection and stops dialing and accepting.
    pub async fn shutdown(&self) {
        self.shared.stopped.store(true, Ordering::SeqCst);
        let _ = self.shared.shutdown.send(true);
        let conns: Vec<Connection> = lock(&self.shared.peers)
            .drain()
            .map(|(_, p)| p.conn)
            .collect();
        for c in conns {
            c.close(close_code::BYE.into(), close_code::SHUTDOWN_REASON);
        }
        // Closes what is left and waits (bounded) for the closes to go out.
        let _ = tokio::time::timeout(Duration::from_secs(1), self.shared.endpoint.close()).await;
        // Whatever did not end with the signal ends now.
        self.shared.abort_tasks();
    }

    /// The link's live tasks (accepting, dialing, discovery, connections):
    /// none outlive the link.
    pub fn tasks(&self) -> usize {
        self.shared.live_tasks()
    }
}
