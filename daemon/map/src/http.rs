//! HTTP: one hyper HTTP/1.1 connection per client, routing, responses.

use crate::Shared;
use bytes::Bytes;
use http_body::{Frame, SizeHint};
use hyper::body::Incoming;
use hyper::header::{self, HeaderValue};
use hyper::{Method, Request, Response, StatusCode};
use hyper_util::rt::{TokioIo, TokioTimer};
use serde_json::{json, Value};
use std::convert::Infallible;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use telextiles_index::Index;
use tokio::net::TcpStream;
use tokio::sync::{broadcast, mpsc};

const INDEX_HTML: &[u8] = include_bytes!("../web/index.html");
const MAP_JS: &[u8] = include_bytes!("../web/map.js");
const MAP_CSS: &[u8] = include_bytes!("../web/map.css");
const PLOTLY_JS: &[u8] = include_bytes!("../web/vendor/plotly-basic.min.js");
const PLOTLY_LICENSE: &[u8] = include_bytes!("../web/vendor/plotly-LICENSE.txt");

const CSP: &str = "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; \
                   img-src 'self' data: blob:; connect-src 'self'; frame-ancestors 'none'";

/// Response body: a whole buffer, or an event stream fed by a task.
pub(crate) enum Body {
    Full(Option<Bytes>),
    Stream(mpsc::Receiver<Bytes>),
}

impl http_body::Body for Body {
    type Data = Bytes;
    type Error = Infallible;

    fn poll_frame(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Infallible>>> {
        match self.get_mut() {
            Body::Full(b) => Poll::Ready(b.take().map(|b| Ok(Frame::data(b)))),
            Body::Stream(rx) => rx.poll_recv(cx).map(|o| o.map(|b| Ok(Frame::data(b)))),
        }
    }

    fn is_end_stream(&self) -> bool {
        matches!(self, Body::Full(None))
    }

    fn size_hint(&self) -> SizeHint {
        match self {
            Body::Full(Some(b)) => SizeHint::with_exact(b.len() as u64),
            Body::Full(None) => SizeHint::with_exact(0),
            Body::Stream(_) => SizeHint::default(),
        }
    }
}

pub(crate) async fn serve_connection(shared: Arc<Shared>, stream: TcpStream) {
    let _ = stream.set_nodelay(true);
    let svc = hyper::service::service_fn(move |req| {
        let shared = shared.clone();
        async move { Ok::<_, Infallible>(handle(&shared, req).await) }
    });
    let conn = hyper::server::conn::http1::Builder::new()
        .timer(TokioTimer::new())
        .header_read_timeout(crate::HEADER_TIMEOUT)
        .max_buf_size(crate::MAX_REQUEST_HEAD)
        .serve_connection(TokioIo::new(stream), svc);
    if let Err(e) = conn.await {
        tracing::debug!("map server: connection ended: {e}");
    }
}

fn respond(status: StatusCode, ctype: &str, body: Bytes) -> Response<Body> {
    let mut r = Response::new(Body::Full(Some(body)));
    *r.status_mut() = status;
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_str(ctype)
            .unwrap_or(HeaderValue::from_static("application/octet-stream")),
    );
    h.insert(
        "x-content-type-options",
        HeaderValue::from_static("nosniff"),
    );
    r
}

fn error(status: StatusCode, msg: impl Into<String>) -> Response<Body> {
    let mut m = msg.into();
    m.push('\n');
    respond(status, "text/plain; charset=utf-8", Bytes::from(m))
}

fn with_cache(mut r: Response<Body>, cache: &'static str) -> Response<Body> {
    r.headers_mut()
        .insert(header::CACHE_CONTROL, HeaderValue::from_static(cache));
    r
}

async fn handle(s: &Arc<Shared>, req: Request<Incoming>) -> Response<Body> {
    let head = req.method() == Method::HEAD;
    let mut r = route(s, &req).await;
    if head {
        if let Body::Full(b) = r.body_mut() {
            *b = None;
        }
    }
    r
}

async fn route(s: &Arc<Shared>, req: &Request<Incoming>) -> Response<Body> {
    if req.method() != Method::GET && req.method() != Method::HEAD {
        let mut r = error(
            StatusCode::METHOD_NOT_ALLOWED,
            format!(
                "method {} not allowed; the map is read-only (GET, HEAD)",
                req.method()
            ),
        );
        r.headers_mut()
            .insert(header::ALLOW, HeaderValue::from_static("GET, HEAD"));
        return r;
    }
    if let Err(msg) = check_host(req, s.loopback) {
        return error(StatusCode::MISDIRECTED_REQUEST, msg);
    }
    let has_body = req
        .headers()
        .get(header::CONTENT_LENGTH)
        .is_some_and(|v| v.as_bytes() != b"0")
        || req.headers().contains_key(header::TRANSFER_ENCODING);
    if has_body {
        return error(
            StatusCode::PAYLOAD_TOO_LARGE,
            "the map takes no request bodies",
        );
    }
    let path = req.uri().path();
    match path {
        "/" | "/index.html" => with_cache(
            with_csp(respond(
                StatusCode::OK,
                "text/html; charset=utf-8",
                Bytes::from_static(INDEX_HTML),
            )),
            "no-cache",
        ),
        "/map.js" => with_cache(
            respond(
                StatusCode::OK,
                "text/javascript; charset=utf-8",
                Bytes::from_static(MAP_JS),
            ),
            "no-cache",
        ),
        "/map.css" => with_cache(
            respond(
                StatusCode::OK,
                "text/css; charset=utf-8",
                Bytes::from_static(MAP_CSS),
            ),
            "no-cache",
        ),
        "/vendor/plotly-basic.min.js" => with_cache(
            respond(
                StatusCode::OK,
                "text/javascript; charset=utf-8",
                Bytes::from_static(PLOTLY_JS),
            ),
            "max-age=86400",
        ),
        "/vendor/plotly-LICENSE.txt" => respond(
            StatusCode::OK,
            "text/plain; charset=utf-8",
            Bytes::from_static(PLOTLY_LICENSE),
        ),
        "/api/map" => with_cache(
            respond(StatusCode::OK, "application/json", s.map_json.clone()),
            "no-store",
        ),
        "/api/health" => with_cache(
            respond(
                StatusCode::OK,
                "application/json",
                Bytes::from(
                    json!({"ok": true, "fingerprint": s.fingerprint, "instance": s.instance})
                        .to_string(),
                ),
            ),
            "no-store",
        ),
        "/api/events" => events(s),
        _ => {
            if let Some(rest) = path.strip_prefix("/api/texture/") {
                return texture(s, rest).await;
            }
            error(StatusCode::NOT_FOUND, format!("no such page: {path}"))
        }
    }
}

fn with_csp(mut r: Response<Body>) -> Response<Body> {
    r.headers_mut()
        .insert("content-security-policy", HeaderValue::from_static(CSP));
    r
}

/// When bound to loopback, only IP-literal or `localhost` Host headers are
/// served: a web page elsewhere cannot reach the map through DNS rebinding.
fn check_host(req: &Request<Incoming>, loopback: bool) -> Result<(), String> {
    let Some(host) = req.headers().get(header::HOST) else {
        return Err("missing Host header".into());
    };
    if !loopback {
        return Ok(());
    }
    let host = host.to_str().map_err(|_| "Host header is not ASCII")?;
    if host_is_local(host) {
        Ok(())
    } else {
        Err(format!(
            "host {host:?} is not served; open the map at http://127.0.0.1:<port>/ or http://localhost:<port>/"
        ))
    }
}

pub(crate) fn host_is_local(host: &str) -> bool {
    // Strip the port: "[::1]:8080", "127.0.0.1:8080", "localhost:8080".
    let name = if let Some(rest) = host.strip_prefix('[') {
        match rest.split_once(']') {
            Some((ip6, tail)) if tail.is_empty() || tail.starts_with(':') => {
                return ip6.parse::<std::net::Ipv6Addr>().is_ok();
            }
            _ => return false,
        }
    } else {
        host.rsplit_once(':').map_or(host, |(h, _)| h)
    };
    name.eq_ignore_ascii_case("localhost") || name.parse::<std::net::Ipv4Addr>().is_ok()
}

async fn texture(s: &Arc<Shared>, rest: &str) -> Response<Body> {
    let Some(enc) = rest.strip_suffix(".png") else {
        return error(
            StatusCode::NOT_FOUND,
            "texture URLs look like /api/texture/<id>.png",
        );
    };
    let id = match percent_decode(enc) {
        Ok(id) => id,
        Err(e) => return error(StatusCode::BAD_REQUEST, format!("bad textile id: {e}")),
    };
    if s.index.entry_by_id(&id).is_none() {
        return error(
            StatusCode::NOT_FOUND,
            format!("no textile {id:?} in the index"),
        );
    }
    match s.textures.png(&id).await {
        Ok(png) => with_cache(
            respond(StatusCode::OK, "image/png", png),
            "private, max-age=300",
        ),
        Err(e) => error(StatusCode::NOT_FOUND, e),
    }
}

/// Strict percent-decoding of one path segment into UTF-8.
pub(crate) fn percent_decode(s: &str) -> Result<String, String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'%' => {
                let hex = b
                    .get(i + 1..i + 3)
                    .and_then(|h| std::str::from_utf8(h).ok())
                    .and_then(|h| u8::from_str_radix(h, 16).ok())
                    .ok_or_else(|| format!("bad %-escape at byte {i}"))?;
                out.push(hex);
                i += 3;
            }
            b'/' => return Err("'/' in a textile id".into()),
            c => {
                out.push(c);
                i += 1;
            }
        }
    }
    let id = String::from_utf8(out).map_err(|_| "not UTF-8".to_string())?;
    if id.is_empty() {
        return Err("empty".into());
    }
    if id.chars().any(char::is_control) {
        return Err("control character".into());
    }
    Ok(id)
}

/// Percent-encode a textile id for a URL path segment.
pub(crate) fn percent_encode(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for b in s.bytes() {
        if b.is_ascii_alphanumeric() || matches!(b, b'-' | b'_' | b'.' | b'~') {
            out.push(b as char);
        } else {
            out.push_str(&format!("%{b:02X}"));
        }
    }
    out
}

/// One page message in SSE form.
pub(crate) fn sse_message(v: &Value) -> Bytes {
    Bytes::from(format!("data: {v}\n\n"))
}

fn events(s: &Arc<Shared>) -> Response<Body> {
    let Ok(permit) = s.streams.clone().try_acquire_owned() else {
        let mut r = error(
            StatusCode::SERVICE_UNAVAILABLE,
            format!(
                "too many open map pages (at most {})",
                crate::MAX_EVENT_STREAMS
            ),
        );
        r.headers_mut()
            .insert(header::RETRY_AFTER, HeaderValue::from_static("5"));
        return r;
    };
    let (tx, rx) = mpsc::channel::<Bytes>(64);
    // Subscribe before taking the snapshot, so nothing falls in between.
    let mut live_rx = s.out.subscribe();
    let hello = json!({"type": "hello", "fingerprint": s.fingerprint, "instance": s.instance,
                       "textiles": s.index.entries.len(), "version": env!("CARGO_PKG_VERSION")});
    let snapshot = s.live.lock().unwrap_or_else(|e| e.into_inner()).snapshot();
    let shared = s.clone();
    let mut shutdown = s.shutdown.clone();
    tokio::spawn(async move {
        let _permit = permit;
        let mut first = Vec::new();
        first.extend_from_slice(b"retry: 1000\n\n");
        first.extend_from_slice(&sse_message(&hello));
        first.extend_from_slice(&sse_message(&snapshot));
        if tx.send(Bytes::from(first)).await.is_err() {
            return;
        }
        let mut ping = tokio::time::interval(crate::SSE_PING);
        ping.tick().await;
        loop {
            let msg = tokio::select! {
                _ = tx.closed() => return,
                _ = shutdown.changed() => return,
                _ = ping.tick() => Bytes::from_static(b": ping\n\n"),
                r = live_rx.recv() => match r {
                    Ok(m) => m,
                    Err(broadcast::error::RecvError::Lagged(n)) => {
                        // A slow page: tell it, and give it the current state.
                        let snap = shared.live.lock().unwrap_or_else(|e| e.into_inner()).snapshot();
                        let mut b = sse_message(&json!({"type": "lagged", "missed": n})).to_vec();
                        b.extend_from_slice(&sse_message(&snap));
                        Bytes::from(b)
                    }
                    Err(broadcast::error::RecvError::Closed) => return,
                },
            };
            if tx.send(msg).await.is_err() {
                return;
            }
        }
    });
    let mut r = Response::new(Body::Stream(rx));
    let h = r.headers_mut();
    h.insert(
        header::CONTENT_TYPE,
        HeaderValue::from_static("text/event-stream"),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert("x-accel-buffering", HeaderValue::from_static("no"));
    r
}

/// The `/api/map` document.
pub(crate) fn map_json(
    index: &Index,
    fingerprint: &str,
    instance: &str,
    textures: bool,
) -> Vec<u8> {
    let mut slot_of = vec![None; index.entries.len()];
    for (k, &e) in index.roller.slots.iter().enumerate() {
        if let Some(s) = slot_of.get_mut(e) {
            *s = Some(k);
        }
    }
    let textiles: Vec<Value> = index
        .entries
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let attributes: Vec<Value> = e
                .attributes
                .iter()
                .map(|(n, v)| json!({"name": n, "value": v}))
                .collect();
            let texture = textures.then(|| {
                format!(
                    "/api/texture/{}.png?v={}",
                    percent_encode(&e.id),
                    &fingerprint[..fingerprint.len().min(12)]
                )
            });
            json!({
                "i": i, "id": e.id, "name": e.name, "seen": e.seen, "structure": e.structure,
                "attributes": attributes,
                "x": finite(e.map_xy[0]), "y": finite(e.map_xy[1]),
                "slot": slot_of[i], "nearest_slot": index.roller.entry_slot.get(i),
                "texture": texture,
            })
        })
        .collect();
    let doc = json!({
        "fingerprint": fingerprint,
        "instance": instance,
        "version": env!("CARGO_PKG_VERSION"),
        "encoder_arch": index.encoder_arch,
        "encoder_hash": index.encoder_hash,
        "dim": index.dim,
        "catalogue_version": index.catalogue_version,
        "map_method": index.map.method,
        "roller": {
            "n": index.roller.n(),
            "method": format!("{:?}", index.roller.method),
            "slots": index.roller.slots,
        },
        "textiles": textiles,
    });
    serde_json::to_vec(&doc).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}").into_bytes())
}

fn finite(v: f32) -> f32 {
    if v.is_finite() {
        v
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percent_round_trip() {
        for id in ["T001", "U07", "my fabric/1", "wool ÷ 2", "a%b", "~x_y.z-"] {
            let enc = percent_encode(id);
            assert!(!enc.contains('/'), "{enc}");
            assert_eq!(percent_decode(&enc).unwrap(), id);
        }
    }

    #[test]
    fn percent_decode_rejects() {
        for bad in ["", "%", "%4", "%zz", "%ff", "a/b", "%00", "%0a"] {
            assert!(percent_decode(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn hosts() {
        for ok in [
            "127.0.0.1",
            "127.0.0.1:8080",
            "localhost:1",
            "LOCALHOST",
            "[::1]:8080",
            "[::1]",
            "10.0.0.1:80",
        ] {
            assert!(host_is_local(ok), "{ok}");
        }
        for bad in [
            "evil.example",
            "evil.example:8080",
            "localhost.evil.example",
            "[::1",
            "[::1]x",
            "[nope]:1",
            "",
        ] {
            assert!(!host_is_local(bad), "{bad}");
        }
    }
}
