//! Shared helpers of the map server tests: a small index, a running server,
//! a raw HTTP/1.1 client over a real TCP socket.
#![allow(dead_code)]

use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use telextiles_index::Index;
use telextiles_map::{MapEvent, MapServer, TextureSource};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::sync::{broadcast, oneshot};
use tokio::task::JoinHandle;

/// An index of `n` built-in catalogue textiles with a roller of `roller`.
pub fn small_index(n: usize, roller: usize, seed: u64) -> Arc<Index> {
    Arc::new(telextiles_map::demo::catalogue_index(Some(n), roller, seed).expect("index"))
}

pub struct Running {
    pub addr: SocketAddr,
    pub events: broadcast::Sender<MapEvent>,
    stop: Option<oneshot::Sender<()>>,
    task: Option<JoinHandle<std::io::Result<()>>>,
}

impl Running {
    /// Stop the server; returns once it has closed everything.
    pub async fn stop(mut self) {
        let _ = self.stop.take().unwrap().send(());
        tokio::time::timeout(Duration::from_secs(10), self.task.take().unwrap())
            .await
            .expect("server stops within 10 s")
            .expect("server task")
            .expect("server result");
    }
}

pub async fn start(addr: &str, index: Arc<Index>, textures: TextureSource) -> Running {
    let (events, _) = broadcast::channel(1024);
    start_with(addr, index, textures, events).await
}

pub async fn start_with(
    addr: &str,
    index: Arc<Index>,
    textures: TextureSource,
    events: broadcast::Sender<MapEvent>,
) -> Running {
    let server = MapServer::bind(addr.parse().unwrap(), index, textures, &events)
        .await
        .expect("bind");
    let addr = server.local_addr();
    let (stop, rx) = oneshot::channel::<()>();
    let task = tokio::spawn(server.serve_until(async {
        let _ = rx.await;
    }));
    Running {
        addr,
        events,
        stop: Some(stop),
        task: Some(task),
    }
}

#[derive(Debug)]
pub struct Resp {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Resp {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k.eq_ignore_ascii_case(name))
            .map(|(_, v)| v.as_str())
    }
    pub fn text(&self) -> String {
        String::from_utf8_lossy(&self.body).into_owned()
    }
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body).unwrap_or_else(|e| panic!("{e}: {}", self.text()))
    }
}

/// Send raw bytes, read the whole response (the server closes or the
/// Content-Length says where it ends).
pub async fn raw(addr: SocketAddr, request: &[u8]) -> Resp {
    let mut s = TcpStream::connect(addr).await.expect("connect");
    s.write_all(request).await.expect("write");
    read_response(&mut s).await.expect("a response")
}

/// A GET with `Connection: close`.
pub async fn get(addr: SocketAddr, path: &str) -> Resp {
    raw(
        addr,
        format!(
            "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nConnection: close\r\n\r\n",
            addr.port()
        )
        .as_bytes(),
    )
    .await
}

/// Read one response; `None` if the server closed without one.
pub async fn read_response(s: &mut TcpStream) -> Option<Resp> {
    let mut buf = Vec::new();
    let mut tmp = [0u8; 8192];
    let head_end = loop {
        if let Some(p) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
            break p;
        }
        let n = tokio::time::timeout(Duration::from_secs(10), s.read(&mut tmp))
            .await
            .expect("response within 10 s")
            .ok()?;
        if n == 0 {
            return None;
        }
        buf.extend_from_slice(&tmp[..n]);
    };
    let head = String::from_utf8_lossy(&buf[..head_end]).into_owned();
    let mut lines = head.split("\r\n");
    let status: u16 = lines.next()?.split(' ').nth(1)?.parse().ok()?;
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_string(), v.trim().to_string()))
        .collect();
    let mut body = buf[head_end + 4..].to_vec();
    let len = headers
        .iter()
        .find(|(k, _)| k.eq_ignore_ascii_case("content-length"))
        .and_then(|(_, v)| v.parse::<usize>().ok());
    loop {
        if len.is_some_and(|l| body.len() >= l) {
            body.truncate(len.unwrap());
            break;
        }
        let n = tokio::time::timeout(Duration::from_secs(10), s.read(&mut tmp))
            .await
            .expect("body within 10 s")
            .unwrap_or(0);
        if n == 0 {
            break;
        }
        body.extend_from_slice(&tmp[..n]);
    }
    Some(Resp {
        status,
        headers,
        body,
    })
}

/// An open event stream (HTTP/1.0, so the body is not chunked).
pub struct Sse {
    s: TcpStream,
    buf: Vec<u8>,
}

impl Sse {
    pub async fn open(addr: SocketAddr) -> Sse {
        let mut s = TcpStream::connect(addr).await.expect("connect");
        s.write_all(
            format!(
                "GET /api/events HTTP/1.0\r\nHost: 127.0.0.1:{}\r\n\r\n",
                addr.port()
            )
            .as_bytes(),
        )
        .await
        .unwrap();
        let mut sse = Sse { s, buf: Vec::new() };
        let head = sse.read_until(b"\r\n\r\n").await.expect("response head");
        let head = String::from_utf8_lossy(&head);
        assert!(
            head.starts_with("HTTP/1.0 200") || head.starts_with("HTTP/1.1 200"),
            "{head}"
        );
        assert!(
            head.to_ascii_lowercase()
                .contains("content-type: text/event-stream"),
            "{head}"
        );
        sse
    }

    async fn read_until(&mut self, delim: &[u8]) -> Option<Vec<u8>> {
        let mut tmp = [0u8; 8192];
        loop {
            if let Some(p) = self.buf.windows(delim.len()).position(|w| w == delim) {
                let out = self.buf[..p].to_vec();
                self.buf.drain(..p + delim.len());
                return Some(out);
            }
            let n = tokio::time::timeout(Duration::from_secs(10), self.s.read(&mut tmp))
                .await
                .expect("event within 10 s")
                .ok()?;
            if n == 0 {
                return None;
            }
            self.buf.extend_from_slice(&tmp[..n]);
        }
    }

    /// The next `data:` message as JSON; `None` at the end of the stream.
    pub async fn next(&mut self) -> Option<serde_json::Value> {
        loop {
            let block = self.read_until(b"\n\n").await?;
            let block = String::from_utf8(block).expect("utf-8 event");
            let data: Vec<&str> = block
                .lines()
                .filter_map(|l| l.strip_prefix("data: "))
                .collect();
            if !data.is_empty() {
                return Some(serde_json::from_str(&data.join("\n")).expect("json event"));
            }
        }
    }

    /// Skip messages until one of `type`.
    pub async fn next_of(&mut self, ty: &str) -> serde_json::Value {
        loop {
            let m = self.next().await.expect("stream open");
            if m["type"] == ty {
                return m;
            }
        }
    }
}
