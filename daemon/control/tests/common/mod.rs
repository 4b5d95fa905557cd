//! Shared test harness: a real server on a real Unix socket in a temp dir,
//! with a test handler (tests only).
#![allow(dead_code)]

use serde_json::{json, Value};
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;
use telextiles_control::protocol::{Command, CtlError, Event, GotoTarget};
use telextiles_control::{
    Access, Handler, HandlerFuture, Server, ServerConfig, ServerStats, SocketSpec,
};
use tokio::sync::{broadcast, Notify};

/// Answers a few commands the way a daemon would; `peers` is slow (300 ms)
/// so tests can observe events flowing while a handler runs.
pub struct TestHandler {
    pub calls: AtomicUsize,
    pub shutdown: Arc<Notify>,
}

impl Handler for TestHandler {
    fn handle(&self, command: Command) -> HandlerFuture<'_> {
        let n = self.calls.fetch_add(1, Ordering::SeqCst) + 1;
        Box::pin(async move {
            match command {
                Command::Status => Ok(json!({"name": "test", "calls": n})),
                Command::Peers => {
                    tokio::time::sleep(Duration::from_millis(300)).await;
                    Ok(json!([{"name": "alice", "up": true}]))
                }
                Command::RollerGoto(GotoTarget::Slot(s)) => Ok(json!({"slot": s})),
                Command::RollerGoto(GotoTarget::Textile(t)) => Err(CtlError::failed(format!(
                    "textile `{t}` is not on the roller"
                ))),
                Command::Shutdown => {
                    self.shutdown.notify_one();
                    Ok(json!("shutting down"))
                }
                other => Err(CtlError::unavailable(format!(
                    "`{}` is not available in the test handler",
                    other.name()
                ))),
            }
        })
    }
}

pub struct TestServer {
    pub dir: tempfile::TempDir,
    pub path: PathBuf,
    pub events: broadcast::Sender<Event>,
    pub stats: Arc<ServerStats>,
    pub handler: Arc<TestHandler>,
    pub join: tokio::task::JoinHandle<()>,
}

impl TestServer {
    pub async fn start(tune: impl FnOnce(&mut ServerConfig)) -> TestServer {
        Self::start_with_capacity(tune, 4096).await
    }

    pub async fn start_with_capacity(
        tune: impl FnOnce(&mut ServerConfig),
        event_capacity: usize,
    ) -> TestServer {
        let dir = tempfile::Builder::new()
            .prefix("txc")
            .tempdir_in("/tmp")
            .unwrap();
        let spec = SocketSpec::in_dir(&dir.path().join("telextilesd"), Access::User);
        let mut cfg = ServerConfig::new(spec);
        tune(&mut cfg);
        let server = Server::bind(cfg).expect("bind");
        let path = server.path().to_path_buf();
        let stats = server.stats();
        let (events, _) = broadcast::channel(event_capacity);
        let shutdown = Arc::new(Notify::new());
        let handler = Arc::new(TestHandler {
            calls: AtomicUsize::new(0),
            shutdown: shutdown.clone(),
        });
        let h = handler.clone();
        let ev = events.clone();
        let join = tokio::spawn(async move {
            server
                .serve(h, ev, async move { shutdown.notified().await })
                .await
        });
        TestServer {
            dir,
            path,
            events,
            stats,
            handler,
            join,
        }
    }

    /// Stops the server via the shutdown notify and waits for it.
    pub async fn stop(self) {
        self.handler.shutdown.notify_one();
        tokio::time::timeout(Duration::from_secs(10), self.join)
            .await
            .expect("server stops")
            .unwrap();
    }
}

/// Polls `f` until it is true (at most 5 s).
pub async fn eventually(what: &str, mut f: impl FnMut() -> bool) {
    for _ in 0..500 {
        if f() {
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    panic!("timed out waiting for: {what}");
}

/// Reads one raw line from a tokio reader and parses it as JSON.
pub async fn read_json<R: tokio::io::AsyncBufRead + Unpin>(r: &mut R) -> Option<Value> {
    use tokio::io::AsyncBufReadExt;
    let mut line = String::new();
    let n = tokio::time::timeout(Duration::from_secs(10), r.read_line(&mut line))
        .await
        .expect("line within 10 s")
        .ok()?;
    if n == 0 {
        return None;
    }
    Some(serde_json::from_str(&line).unwrap_or_else(|e| panic!("bad JSON {line:?}: {e}")))
}
