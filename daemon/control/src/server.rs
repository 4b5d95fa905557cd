//! The control server: accepts Unix-socket clients, parses JSON-line
//! requests with [`crate::protocol`], hands commands to a [`Handler`],
//! and streams [`Event`]s to subscribers.
//!
//! Robustness rules (see `docs/control-protocol.md`):
//! - at most `max_clients` connections; extra clients get a `busy` error line and are closed;
//! - request lines are capped at `max_line` bytes; an oversize line gets a
//!   `line_too_long` error and the connection resyncs at the next newline;
//! - every client has a bounded output queue (`client_buffer` lines); a
//!   subscriber that falls behind is sent `{"event":"dropped","reason":...}` and closed;
//! - a write that makes no progress for `write_timeout` closes the connection;
//! - a client vanishing at any point only ends its own connection.

use crate::protocol::{
    Command, CtlError, ErrorCode, Event, EventFilter, Frame, LineFramer, Reply, Request, RequestId,
    SubscribeArgs, MAX_LINE,
};
use crate::socket::{self, BindError, BoundSocket, Previous, SocketSpec};
use serde_json::Value;
use std::future::Future;
use std::path::Path;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::unix::OwnedWriteHalf;
use tokio::net::{UnixListener, UnixStream};
use tokio::sync::broadcast::error::RecvError;
use tokio::sync::{broadcast, mpsc, oneshot, watch, OwnedSemaphorePermit, Semaphore};
use tokio::task::{JoinHandle, JoinSet};

/// The future a [`Handler`] returns.
pub type HandlerFuture<'a> = Pin<Box<dyn Future<Output = Result<Value, CtlError>> + Send + 'a>>;

/// Answers commands. The daemon implements this against its subsystems.
///
/// `handle` is called once per request, concurrently for different clients
/// (sequentially within one connection). It never receives
/// [`Command::Subscribe`]: the server handles subscriptions itself. On
/// [`Command::Shutdown`] the handler should start the daemon's shutdown
/// (which eventually resolves the `shutdown` future given to
/// [`Server::serve`]) and return `Ok`; the reply is delivered before the
/// server closes connections.
///
/// ```
/// use telextiles_control::{Command, CtlError, Handler, HandlerFuture};
/// struct Daemon;
/// impl Handler for Daemon {
///     fn handle(&self, command: Command) -> HandlerFuture<'_> {
///         Box::pin(async move {
///             match command {
///                 Command::Status => Ok(serde_json::json!({"name": "studio"})),
///                 other => Err(CtlError::unavailable(format!("`{}` is not wired", other.name()))),
///             }
///         })
///     }
/// }
/// ```
pub trait Handler: Send + Sync + 'static {
    fn handle(&self, command: Command) -> HandlerFuture<'_>;
}

/// Server limits. [`ServerConfig::new`] gives the defaults.
#[derive(Debug, Clone)]
pub struct ServerConfig {
    pub socket: SocketSpec,
    /// Concurrent connections (default 256).
    pub max_clients: usize,
    /// Longest request line in bytes (default [`MAX_LINE`] = 64 KiB).
    pub max_line: usize,
    /// Lines queued per client before a subscriber is dropped (default 256).
    pub client_buffer: usize,
    /// A write making no progress this long closes the connection (default 5 s).
    pub write_timeout: Duration,
    /// How long shutdown waits for connections to flush (default 2 s).
    pub shutdown_grace: Duration,
}

impl ServerConfig {
    pub fn new(socket: SocketSpec) -> Self {
        ServerConfig {
            socket,
            max_clients: 256,
            max_line: MAX_LINE,
            client_buffer: 256,
            write_timeout: Duration::from_secs(5),
            shutdown_grace: Duration::from_secs(2),
        }
    }
}

/// Live counters, e.g. for the `status` reply.
#[derive(Debug, Default)]
pub struct ServerStats {
    clients: AtomicUsize,
    subscribers: AtomicUsize,
    requests: AtomicU64,
    rejected_busy: AtomicU64,
    dropped_subscribers: AtomicU64,
}

impl ServerStats {
    /// Connected clients now.
    pub fn clients(&self) -> usize {
        self.clients.load(Ordering::Relaxed)
    }
    /// Subscribed clients now.
    pub fn subscribers(&self) -> usize {
        self.subscribers.load(Ordering::Relaxed)
    }
    /// Requests answered so far (including errors).
    pub fn requests(&self) -> u64 {
        self.requests.load(Ordering::Relaxed)
    }
    /// Connections refused because `max_clients` were connected.
    pub fn rejected_busy(&self) -> u64 {
        self.rejected_busy.load(Ordering::Relaxed)
    }
    /// Subscribers dropped for being too slow.
    pub fn dropped_subscribers(&self) -> u64 {
        self.dropped_subscribers.load(Ordering::Relaxed)
    }
    /// All counters as a JSON object.
    pub fn to_json(&self) -> Value {
        serde_json::json!({
            "clients": self.clients(),
            "subscribers": self.subscribers(),
            "requests": self.requests(),
            "rejected_busy": self.rejected_busy(),
            "dropped_subscribers": self.dropped_subscribers(),
        })
    }
}

/// A bound control socket, ready to [`serve`](Server::serve).
pub struct Server {
    listener: UnixListener,
    bound: BoundSocket,
    previous: Previous,
    cfg: ServerConfig,
    stats: Arc<ServerStats>,
}

impl Server {
    /// Binds the socket (see [`socket::bind`]): creates the directory with
    /// its mode, replaces a stale socket, refuses if a live daemon answers.
    /// Must be called inside a tokio runtime.
    pub fn bind(cfg: ServerConfig) -> Result<Server, BindError> {
        let (std_listener, bound, previous) = socket::bind(&cfg.socket)?;
        let listener = UnixListener::from_std(std_listener).map_err(|source| BindError::Io {
            what: "register with the runtime",
            path: cfg.socket.path.clone(),
            source,
        })?;
        match previous {
            Previous::StaleRemoved => tracing::warn!(
                path = %bound.path().display(),
                "replaced a stale control socket (no daemon was answering on it)"
            ),
            Previous::None => {}
        }
        tracing::info!(path = %bound.path().display(), "control socket listening");
        Ok(Server {
            listener,
            bound,
            previous,
            cfg,
            stats: Arc::default(),
        })
    }

    pub fn path(&self) -> &Path {
        self.bound.path()
    }

    /// Whether a stale socket file was found and removed at bind time.
    pub fn replaced_stale(&self) -> bool {
        self.previous == Previous::StaleRemoved
    }

    pub fn stats(&self) -> Arc<ServerStats> {
        self.stats.clone()
    }

    /// Serves until `shutdown` resolves; then stops accepting, removes the
    /// socket file, lets connections flush for `shutdown_grace` and closes them.
    pub async fn serve<H: Handler + ?Sized>(
        self,
        handler: Arc<H>,
        events: broadcast::Sender<Event>,
        shutdown: impl Future<Output = ()>,
    ) {
        let Server {
            listener,
            bound,
            cfg,
            stats,
            ..
        } = self;
        let cfg = Arc::new(cfg);
        let (stop_tx, stop_rx) = watch::channel(false);
        let slots = Arc::new(Semaphore::new(cfg.max_clients));
        let mut conns = JoinSet::new();
        tokio::pin!(shutdown);
        loop {
            tokio::select! {
                _ = &mut shutdown => break,
                Some(_) = conns.join_next(), if !conns.is_empty() => {}
                accepted = listener.accept() => match accepted {
                    Ok((stream, _)) => match slots.clone().try_acquire_owned() {
                        Ok(permit) => {
                            let ctx = Ctx {
                                handler: handler.clone(),
                                events: events.clone(),
                                cfg: cfg.clone(),
                                stats: stats.clone(),
                            };
                            conns.spawn(connection(stream, ctx, stop_rx.clone(), permit));
                        }
                        Err(_) => {
                            stats.rejected_busy.fetch_add(1, Ordering::Relaxed);
                            tracing::warn!(max = cfg.max_clients, "control client refused: too many clients");
                            tokio::spawn(reject_busy(stream, cfg.max_clients));
                        }
                    },
                    Err(e) => {
                        // EMFILE and friends: back off instead of spinning.
                        tracing::warn!(error = %e, "control socket accept failed");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                    }
                }
            }
        }
        drop(listener);
        drop(bound); // unlink now: a new daemon may bind while we flush
        let _ = stop_tx.send(true);
        let drained = tokio::time::timeout(cfg.shutdown_grace, async {
            while conns.join_next().await.is_some() {}
        })
        .await;
        if drained.is_err() {
            tracing::debug!(
                left = conns.len(),
                "closing control connections after grace period"
            );
        }
        conns.abort_all();
        tracing::info!("control socket closed");
    }
}

/// Tells a client it was refused, then closes (briefly draining what it
/// sent so the close is an orderly EOF, not a reset).
async fn reject_busy(stream: UnixStream, max: usize) {
    let line = Reply::err(
        RequestId::Null,
        CtlError::new(
            ErrorCode::Busy,
            format!("too many control clients (limit {max}); try again later"),
        ),
    )
    .to_line();
    let (mut rd, mut wr) = stream.into_split();
    let _ = tokio::time::timeout(Duration::from_millis(500), async {
        wr.write_all(line.as_bytes()).await?;
        wr.shutdown().await?;
        let mut sink = [0u8; 4096];
        let mut left = 64 * 1024usize;
        while left > 0 {
            let n = rd.read(&mut sink).await?;
            if n == 0 {
                break;
            }
            left = left.saturating_sub(n);
        }
        std::io::Result::Ok(())
    })
    .await;
}

struct Ctx<H: ?Sized> {
    handler: Arc<H>,
    events: broadcast::Sender<Event>,
    cfg: Arc<ServerConfig>,
    stats: Arc<ServerStats>,
}

/// Decrements a counter when dropped.
struct Gauge<'a>(&'a AtomicUsize);
impl<'a> Gauge<'a> {
    fn new(c: &'a AtomicUsize) -> Self {
        c.fetch_add(1, Ordering::Relaxed);
        Gauge(c)
    }
}
impl Drop for Gauge<'_> {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Aborts the task when dropped (the writer must not outlive its connection).
struct AbortOnDrop(JoinHandle<()>);
impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

struct Subscription {
    rx: broadcast::Receiver<Event>,
    filter: EventFilter,
}

/// Per-connection state shared by the read loop and the handler wait.
struct Conn<'s> {
    out: mpsc::Sender<String>,
    kill: Option<oneshot::Sender<String>>,
    sub: Option<Subscription>,
    capacity: usize,
    stats: &'s ServerStats,
    sub_gauge: Option<Gauge<'s>>,
}

impl Conn<'_> {
    fn forward(&mut self, ev: Result<Event, RecvError>) {
        let Some(sub) = &self.sub else { return };
        match ev {
            Ok(e) => {
                if !sub.filter.matches(&e) {
                    return;
                }
                match self.out.try_send(e.to_line()) {
                    Ok(()) => {}
                    Err(mpsc::error::TrySendError::Full(_)) => self.drop_subscriber(format!(
                        "slow subscriber: more than {} lines waiting to be read",
                        self.capacity
                    )),
                    Err(mpsc::error::TrySendError::Closed(_)) => self.sub = None,
                }
            }
            Err(RecvError::Lagged(n)) => {
                self.drop_subscriber(format!("slow subscriber: missed {n} events"))
            }
            Err(RecvError::Closed) => {
                // The daemon's event source went away (shutting down).
                self.sub = None;
                self.sub_gauge = None;
            }
        }
    }

    fn drop_subscriber(&mut self, reason: String) {
        tracing::warn!(%reason, "dropping control subscriber");
        self.sub = None;
        self.sub_gauge = None;
        self.stats
            .dropped_subscribers
            .fetch_add(1, Ordering::Relaxed);
        if let Some(k) = self.kill.take() {
            let _ = k.send(reason);
        }
    }
}

async fn next_event(sub: &mut Option<Subscription>) -> Result<Event, RecvError> {
    match sub {
        Some(s) => s.rx.recv().await,
        None => std::future::pending().await,
    }
}

async fn connection<H: Handler + ?Sized>(
    stream: UnixStream,
    ctx: Ctx<H>,
    mut stop: watch::Receiver<bool>,
    _permit: OwnedSemaphorePermit,
) {
    let _client = Gauge::new(&ctx.stats.clients);
    if let Ok(cred) = stream.peer_cred() {
        tracing::debug!(uid = cred.uid(), pid = ?cred.pid(), "control client connected");
    }
    let cfg = &ctx.cfg;
    let (mut rd, wr) = stream.into_split();
    let (out_tx, out_rx) = mpsc::channel::<String>(cfg.client_buffer.max(1));
    let (kill_tx, kill_rx) = oneshot::channel::<String>();
    let mut writer = AbortOnDrop(tokio::spawn(writer_task(
        wr,
        out_rx,
        kill_rx,
        cfg.write_timeout,
    )));
    let mut conn = Conn {
        out: out_tx,
        kill: Some(kill_tx),
        sub: None,
        capacity: cfg.client_buffer.max(1),
        stats: &ctx.stats,
        sub_gauge: None,
    };
    let mut framer = LineFramer::new(cfg.max_line);
    let mut buf = vec![0u8; 8192];
    let mut eof = false;
    if *stop.borrow() {
        return;
    }
    'conn: loop {
        while let Some(frame) = framer.next_frame() {
            ctx.stats.requests.fetch_add(1, Ordering::Relaxed);
            let reply = match frame {
                Frame::TooLong => Reply::err(
                    RequestId::Null,
                    CtlError::new(
                        ErrorCode::LineTooLong,
                        format!(
                            "request line longer than {} bytes; discarded up to the next newline",
                            cfg.max_line
                        ),
                    ),
                ),
                Frame::Line(line) => match crate::protocol::parse_request(&line) {
                    Err(e) => {
                        tracing::debug!(error = %e.error, "bad control request");
                        Reply::err(e.id, e.error)
                    }
                    Ok(Request {
                        id,
                        command: Command::Subscribe(args),
                    }) => subscribe(&mut conn, &ctx.events, id, &args),
                    Ok(Request { id, command }) => {
                        let fut = ctx.handler.handle(command);
                        tokio::pin!(fut);
                        let result = loop {
                            tokio::select! {
                                r = &mut fut => break r,
                                ev = next_event(&mut conn.sub) => conn.forward(ev),
                                _ = &mut writer.0 => return,
                            }
                        };
                        Reply::from_result(id, result)
                    }
                },
            };
            if conn.out.send(reply.to_line()).await.is_err() {
                break 'conn;
            }
        }
        if eof && conn.sub.is_none() {
            break;
        }
        tokio::select! {
            _ = stop.changed() => break,
            _ = &mut writer.0 => return,
            ev = next_event(&mut conn.sub) => conn.forward(ev),
            r = rd.read(&mut buf), if !eof => match r {
                Ok(0) => {
                    eof = true;
                    if framer.pending() > 0 {
                        tracing::debug!(bytes = framer.pending(), "control client closed mid-line; partial request ignored");
                    }
                }
                Ok(n) => framer.feed(&buf[..n]),
                Err(e) => {
                    tracing::debug!(error = %e, "control client read failed");
                    break;
                }
            },
        }
    }
    // Flush what is queued, then close (bounded by the writer's timeout,
    // and by the server's grace period on shutdown).
    drop(conn);
    let _ = (&mut writer.0).await;
}

fn subscribe(
    conn: &mut Conn<'_>,
    events: &broadcast::Sender<Event>,
    id: RequestId,
    args: &SubscribeArgs,
) -> Reply {
    let filter = args.filter();
    match &mut conn.sub {
        Some(s) => s.filter = filter,
        None => {
            conn.sub = Some(Subscription {
                rx: events.subscribe(),
                filter,
            });
            conn.sub_gauge = Some(Gauge::new(&conn.stats.subscribers));
        }
    }
    let kinds: Vec<&str> = filter.kinds().iter().map(|k| k.as_str()).collect();
    Reply::ok(id, serde_json::json!({ "events": kinds }))
}

/// Writes queued lines in batches; on a kill signal writes the `dropped`
/// notice and stops. Any write stalled for `write_timeout` ends the task.
async fn writer_task(
    mut wr: OwnedWriteHalf,
    mut rx: mpsc::Receiver<String>,
    mut kill: oneshot::Receiver<String>,
    write_timeout: Duration,
) {
    let mut kill_armed = true;
    let mut reason = None;
    let mut batch = Vec::with_capacity(16 * 1024);
    loop {
        let first = tokio::select! {
            biased;
            r = &mut kill, if kill_armed => match r {
                Ok(r) => { reason = Some(r); break; }
                Err(_) => { kill_armed = false; continue; }
            },
            l = rx.recv() => l,
        };
        let Some(first) = first else { break };
        batch.clear();
        batch.extend_from_slice(first.as_bytes());
        while batch.len() < 64 * 1024 {
            match rx.try_recv() {
                Ok(l) => batch.extend_from_slice(l.as_bytes()),
                Err(_) => break,
            }
        }
        match tokio::time::timeout(write_timeout, wr.write_all(&batch)).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                tracing::debug!(error = %e, "control client write failed (client gone)");
                return;
            }
            Err(_) => {
                tracing::debug!("control client write timed out; closing");
                return;
            }
        }
    }
    if let Some(reason) = reason {
        let notice = Event::Dropped { reason }.to_line();
        let _ = tokio::time::timeout(write_timeout, wr.write_all(notice.as_bytes())).await;
    }
    let _ = tokio::time::timeout(write_timeout, wr.shutdown()).await;
}
