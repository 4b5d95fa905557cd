//! The live 2D textile map, served to a browser on the local machine.
//!
//! A small HTTP/1.1 server (hyper) with:
//! - `/` — the page (plotly.js, vendored and embedded in the binary, so it
//!   works with no internet);
//! - `/api/map` — the textiles as JSON: id, name, seen, structure,
//!   attributes, map position, roller slot, texture URL, and the index
//!   fingerprint;
//! - `/api/texture/<id>.png` — a texture image per textile ([`TextureSource`]);
//! - `/api/events` — Server-Sent Events: the live touch placed on the map with
//!   its nearest textiles, contact, decisions, roller position, peers.
//!
//! The daemon feeds [`MapEvent`]s on a `tokio::sync::broadcast` channel:
//!
//! ```no_run
//! # async fn f(index: std::sync::Arc<telextiles_index::Index>) -> std::io::Result<()> {
//! use telextiles_map::{MapEvent, MapServer, TextureSource};
//! let (events, _) = tokio::sync::broadcast::channel::<MapEvent>(256);
//! let server = MapServer::bind("127.0.0.1:8080".parse().unwrap(), index,
//!                              TextureSource::Simulated, &events).await?;
//! println!("map on http://{}/", server.local_addr());
//! tokio::spawn(server.serve());
//! // later, from the pipeline:
//! let _ = events.send(MapEvent::Touch { latent: vec![0.0; 512], peer: None });
//! # Ok(()) }
//! ```
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

#[cfg(feature = "sim")]
pub mod demo;
mod event;
mod http;
mod texture;

pub use event::{ContactPhase, Live, MapEvent, TOUCH_NEAREST};
pub use texture::TextureSource;

use bytes::Bytes;
use std::future::Future;
use std::io;
use std::net::SocketAddr;
use std::sync::atomic::AtomicU64;
use std::sync::{Arc, Mutex};
use std::time::Duration;
use telextiles_index::Index;
use tokio::net::TcpListener;
use tokio::sync::{broadcast, watch, Semaphore};
use tokio::task::JoinSet;

/// Default address: loopback only.
pub const DEFAULT_ADDR: &str = "127.0.0.1:8080";
/// Most connections served at once; more are closed at accept.
pub const MAX_CONNECTIONS: usize = 64;
/// Most event streams (open pages) at once; more get 503.
pub const MAX_EVENT_STREAMS: usize = 16;
/// Largest request head (request line + headers) accepted.
pub const MAX_REQUEST_HEAD: usize = 16 * 1024;
/// Time a client has to send a complete request head.
pub const HEADER_TIMEOUT: Duration = Duration::from_secs(10);
/// Keep-alive comment interval on event streams.
pub const SSE_PING: Duration = Duration::from_secs(15);

/// State shared by all connections.
pub(crate) struct Shared {
    pub(crate) index: Arc<Index>,
    pub(crate) fingerprint: String,
    /// A per-start id, so a page can tell the server restarted.
    pub(crate) instance: String,
    pub(crate) map_json: Bytes,
    pub(crate) textures: Arc<texture::Textures>,
    pub(crate) live: Mutex<Live>,
    /// Page messages, already in SSE form.
    pub(crate) out: broadcast::Sender<Bytes>,
    pub(crate) streams: Arc<Semaphore>,
    pub(crate) shutdown: watch::Receiver<bool>,
    pub(crate) loopback: bool,
    pub(crate) dropped_events: AtomicU64,
}

/// A bound map server; [`MapServer::serve`] runs it.
pub struct MapServer {
    listener: TcpListener,
    local: SocketAddr,
    shared: Arc<Shared>,
    events: broadcast::Receiver<MapEvent>,
    shutdown_tx: watch::Sender<bool>,
}

impl MapServer {
    /// Bind `addr` (use [`DEFAULT_ADDR`] or port 0 for any free port) and
    /// subscribe to `events`. Fails if the address is taken.
    pub async fn bind(
        addr: SocketAddr,
        index: Arc<Index>,
        textures: TextureSource,
        events: &broadcast::Sender<MapEvent>,
    ) -> io::Result<MapServer> {
        let listener = TcpListener::bind(addr).await.map_err(|e| {
            io::Error::new(e.kind(), format!("map server: cannot bind {addr}: {e}"))
        })?;
        let local = listener.local_addr()?;
        if !local.ip().is_loopback() {
            tracing::warn!(
                "map server listens on {local}, reachable from other machines; \
                 use 127.0.0.1 unless that is intended"
            );
        }
        let fingerprint = index.fingerprint();
        let instance = instance_id();
        let textures = Arc::new(texture::Textures::new(textures));
        let map_json = Bytes::from(http::map_json(
            &index,
            &fingerprint,
            &instance,
            textures.enabled(),
        ));
        let (out, _) = broadcast::channel(256);
        let (shutdown_tx, shutdown) = watch::channel(false);
        let shared = Arc::new(Shared {
            live: Mutex::new(Live::new(index.clone())),
            index,
            fingerprint,
            instance,
            map_json,
            textures,
            out,
            streams: Arc::new(Semaphore::new(MAX_EVENT_STREAMS)),
            shutdown,
            loopback: local.ip().is_loopback(),
            dropped_events: AtomicU64::new(0),
        });
        Ok(MapServer {
            listener,
            local,
            shared,
            events: events.subscribe(),
            shutdown_tx,
        })
    }

    /// The address actually bound (the port, if 0 was asked for).
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// The index fingerprint the page is served with.
    pub fn fingerprint(&self) -> &str {
        &self.shared.fingerprint
    }

    /// Serve until the task is dropped.
    pub async fn serve(self) -> io::Result<()> {
        self.serve_until(std::future::pending()).await
    }

    /// Serve until `shutdown` completes; then every connection, event stream
    /// and the listener are closed before this returns.
    pub async fn serve_until(self, shutdown: impl Future<Output = ()>) -> io::Result<()> {
        let MapServer {
            listener,
            shared,
            events,
            shutdown_tx,
            ..
        } = self;
        let mut tasks = JoinSet::new();
        tasks.spawn(hub(shared.clone(), events));
        let conns = Arc::new(Semaphore::new(MAX_CONNECTIONS));
        tokio::pin!(shutdown);
        loop {
            tokio::select! {
                _ = &mut shutdown => break,
                r = listener.accept() => match r {
                    Ok((stream, peer)) => {
                        let Ok(permit) = conns.clone().try_acquire_owned() else {
                            tracing::warn!("map server: {MAX_CONNECTIONS} connections open, closing one from {peer}");
                            continue;
                        };
                        let shared = shared.clone();
                        tasks.spawn(async move {
                            http::serve_connection(shared, stream).await;
                            drop(permit);
                        });
                    }
                    Err(e) => {
                        // Out of file descriptors and the like: back off.
                        tracing::warn!("map server: accept failed: {e}");
                        tokio::time::sleep(Duration::from_millis(100)).await;
                    }
                },
                Some(_) = tasks.join_next(), if !tasks.is_empty() => {}
            }
        }
        let _ = shutdown_tx.send(true);
        drop(listener);
        tasks.shutdown().await;
        Ok(())
    }
}

/// Applies the daemon's events to the live state and broadcasts the page
/// messages.
async fn hub(shared: Arc<Shared>, mut events: broadcast::Receiver<MapEvent>) {
    use broadcast::error::RecvError;
    let mut bad = 0u64;
    loop {
        match events.recv().await {
            Ok(ev) => {
                let r = shared
                    .live
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .apply(&ev);
                match r {
                    Ok(msg) => {
                        let _ = shared.out.send(http::sse_message(&msg));
                    }
                    Err(e) => {
                        bad += 1;
                        if bad.is_power_of_two() {
                            tracing::warn!("map: ignoring event ({bad} so far): {e}");
                        }
                    }
                }
            }
            Err(RecvError::Lagged(n)) => {
                shared
                    .dropped_events
                    .fetch_add(n, std::sync::atomic::Ordering::Relaxed);
                tracing::debug!("map: fell {n} events behind the daemon");
            }
            Err(RecvError::Closed) => {
                tracing::debug!("map: event channel closed; serving the static map");
                return;
            }
        }
    }
}

fn instance_id() -> String {
    use std::hash::{BuildHasher, Hasher};
    let mut h = std::collections::hash_map::RandomState::new().build_hasher();
    h.write_u128(
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0),
    );
    h.write_u32(std::process::id());
    format!("{:016x}", h.finish())
}
