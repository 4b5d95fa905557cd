//! The control server over real Unix sockets: requests and errors, oversize
//! lines, hundreds of clients, vanishing clients, slow subscribers, stale
//! sockets, a live owner, permissions and shutdown.

mod common;

use common::{eventually, read_json, TestServer};
use serde_json::{json, Value};
use std::os::unix::fs::{MetadataExt, PermissionsExt};
use std::sync::Arc;
use std::time::Duration;
use telextiles_control::protocol::{
    Command, ErrorCode, Event, EventKind, GotoTarget, SubscribeArgs,
};
use telextiles_control::{Access, BindError, Client, Server, ServerConfig, SocketSpec};
use tokio::io::{AsyncWriteExt, BufReader};
use tokio::net::UnixStream;

async fn raw(
    path: &std::path::Path,
) -> (
    BufReader<tokio::net::unix::OwnedReadHalf>,
    tokio::net::unix::OwnedWriteHalf,
) {
    let s = UnixStream::connect(path).await.unwrap();
    let (r, w) = s.into_split();
    (BufReader::new(r), w)
}

fn error_event(seq: usize, pad: usize) -> Event {
    Event::Error {
        source: "test".into(),
        message: format!("{seq:08} {}", "x".repeat(pad)),
    }
}

fn seq_of(v: &Value) -> usize {
    v["message"].as_str().unwrap()[..8].parse().unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn requests_errors_and_ids_on_one_connection() {
    let srv = TestServer::start(|_| {}).await;
    let (mut r, mut w) = raw(&srv.path).await;
    let lines = concat!(
        "{\"id\":1,\"cmd\":\"status\"}\n",
        "{\"id\":\"two\",\"cmd\":\"roller.goto\",\"args\":{\"slot\":3}}\r\n",
        "this is not json\n",
        "\n",
        "{\"id\":4,\"cmd\":\"fly\"}\n",
        "{\"id\":5,\"cmd\":\"roller.goto\",\"args\":{\"slot\":\"3\"}}\n",
        "{\"id\":6,\"cmd\":\"roller.goto\",\"args\":{\"textile\":\"T999\"}}\n",
        "{\"id\":7,\"cmd\":\"sensor.recalibrate\"}\n",
        "[1,2,3]\n",
        "{\"id\":9,\"cmd\":\"status\"}\n",
    );
    w.write_all(lines.as_bytes()).await.unwrap();
    let mut got = Vec::new();
    for _ in 0..9 {
        got.push(read_json(&mut r).await.expect("a reply"));
    }
    assert_eq!(got[0]["id"], 1);
    assert_eq!(got[0]["ok"], true);
    assert_eq!(got[0]["data"]["name"], "test");
    assert_eq!(
        got[1],
        json!({"id": "two", "ok": true, "data": {"slot": 3}})
    );
    assert_eq!(got[2]["id"], Value::Null);
    assert_eq!(got[2]["ok"], false);
    assert_eq!(got[2]["error"]["code"], "parse_error");
    assert_eq!(got[3]["id"], 4);
    assert_eq!(got[3]["error"]["code"], "unknown_command");
    assert!(got[3]["error"]["message"]
        .as_str()
        .unwrap()
        .contains("`fly`"));
    assert_eq!(got[4]["id"], 5);
    assert_eq!(got[4]["error"]["code"], "invalid_args");
    assert!(got[4]["error"]["message"]
        .as_str()
        .unwrap()
        .contains("argument `slot` must be an integer"));
    assert_eq!(got[5]["error"]["code"], "failed");
    assert_eq!(got[6]["error"]["code"], "unavailable");
    assert_eq!(got[7]["error"]["code"], "invalid_request");
    assert_eq!(got[8]["id"], 9);
    assert_eq!(got[8]["ok"], true);
    // Blank lines are not requests; the errors did not reach the handler.
    assert_eq!(
        srv.handler.calls.load(std::sync::atomic::Ordering::SeqCst),
        5
    );
    drop((r, w));
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversize_line_gets_an_error_and_the_connection_resyncs() {
    let srv = TestServer::start(|c| c.max_line = 1024).await;
    let (mut r, mut w) = raw(&srv.path).await;
    // 100 KiB without a newline, then its end, then a good request.
    let big = vec![b'a'; 100 * 1024];
    w.write_all(&big).await.unwrap();
    let e = read_json(&mut r).await.unwrap();
    assert_eq!(e["ok"], false);
    assert_eq!(e["error"]["code"], "line_too_long");
    assert!(e["error"]["message"]
        .as_str()
        .unwrap()
        .contains("1024 bytes"));
    w.write_all(b"aaaa\n{\"id\":2,\"cmd\":\"status\"}\n")
        .await
        .unwrap();
    let ok = read_json(&mut r).await.unwrap();
    assert_eq!(ok["id"], 2);
    assert_eq!(ok["ok"], true);
    // A line of exactly the limit is fine; one byte more is not.
    let mut exact = br#"{"id":3,"cmd":"status","args":{}}"#.to_vec();
    let pad = 1024 - exact.len();
    exact.splice(0..0, std::iter::repeat_n(b' ', pad));
    exact.push(b'\n');
    w.write_all(&exact).await.unwrap();
    assert_eq!(read_json(&mut r).await.unwrap()["id"], 3);
    exact.insert(0, b' ');
    w.write_all(&exact).await.unwrap();
    assert_eq!(
        read_json(&mut r).await.unwrap()["error"]["code"],
        "line_too_long"
    );
    drop((r, w));
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_hundred_concurrent_clients_are_served_or_shed() {
    const CLIENTS: usize = 300;
    const LIMIT: usize = 256;
    let srv = TestServer::start(|c| c.max_clients = LIMIT).await;

    // A subscriber connected first must keep receiving events throughout.
    let mut watcher = Client::connect(&srv.path).await.unwrap();
    watcher
        .subscribe(SubscribeArgs {
            events: Some(vec![EventKind::Decision]),
        })
        .await
        .unwrap()
        .unwrap();

    let barrier = Arc::new(tokio::sync::Barrier::new(CLIENTS + 1));
    let mut tasks = Vec::new();
    for _ in 0..CLIENTS {
        let path = srv.path.clone();
        let barrier = barrier.clone();
        tasks.push(tokio::spawn(async move {
            let mut c = Client::connect(&path).await.expect("connect");
            let r = c.call(&Command::Status).await;
            // Hold the connection until every client has its answer.
            barrier.wait().await;
            r
        }));
    }
    barrier.wait().await;
    let (mut ok, mut busy) = (0, 0);
    for t in tasks {
        match t.await.unwrap() {
            Ok(Ok(v)) => {
                assert_eq!(v["name"], "test");
                ok += 1;
            }
            Ok(Err(e)) => {
                assert_eq!(e.code, ErrorCode::Busy, "{e}");
                assert!(e.message.contains("too many control clients"));
                busy += 1;
            }
            Err(e) => panic!("client failed: {e}"),
        }
    }
    assert_eq!(ok, LIMIT - 1, "the watcher holds one slot");
    assert_eq!(busy, CLIENTS - (LIMIT - 1));
    assert_eq!(srv.stats.rejected_busy(), busy as u64);

    // The watcher was unaffected.
    let ev = Event::Decision {
        textile: "T003".into(),
        name: None,
        slot: 1,
        distance: 0.1,
        unknown: false,
        latency_ms: 12.0,
        peer: None,
        press: None,
        final_decision: false,
        since_contact_ms: None,
    };
    srv.events.send(ev.clone()).unwrap();
    let got = tokio::time::timeout(Duration::from_secs(5), watcher.next_event())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert_eq!(got, telextiles_control::client::EventLine::Known(ev));

    // Slots are released when clients leave.
    let stats = srv.stats.clone();
    eventually("clients to leave", || stats.clients() == 1).await;
    let mut late = Client::connect(&srv.path).await.unwrap();
    assert!(late.call(&Command::Status).await.unwrap().is_ok());
    drop((late, watcher));
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_subscriber_is_dropped_with_a_notice_and_others_are_unaffected() {
    const N: usize = 3000;
    let srv = TestServer::start_with_capacity(
        |c| {
            c.client_buffer = 64;
            // Long enough that the stalled write is still pending when the
            // slow client finally reads, however loaded the machine is.
            c.write_timeout = Duration::from_secs(60);
        },
        8192,
    )
    .await;
    // The slow one subscribes, then does not read.
    let (mut slow_r, mut slow_w) = raw(&srv.path).await;
    slow_w
        .write_all(b"{\"id\":1,\"cmd\":\"subscribe\",\"args\":{\"events\":[\"error\"]}}\n")
        .await
        .unwrap();
    let fast_path = srv.path.clone();
    let mut fast = Client::connect(&fast_path).await.unwrap();
    fast.subscribe(SubscribeArgs::default())
        .await
        .unwrap()
        .unwrap();
    let stats = srv.stats.clone();
    eventually("two subscribers", || stats.subscribers() == 2).await;

    let received = Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counter = received.clone();
    let reader = tokio::spawn(async move {
        let mut seqs = Vec::with_capacity(N);
        while seqs.len() < N {
            match fast.next_event().await.unwrap() {
                Some(telextiles_control::client::EventLine::Known(Event::Error {
                    message,
                    ..
                })) => {
                    seqs.push(message[..8].parse::<usize>().unwrap());
                    counter.store(seqs.len(), std::sync::atomic::Ordering::SeqCst);
                }
                other => panic!("fast subscriber got {other:?}"),
            }
        }
        seqs
    });
    // ~1 KiB events in batches of 32; the publisher waits for the reading
    // client to catch up after each batch (so it never has more than 32
    // queued), while the slow one falls behind for sure.
    for i in 0..N {
        srv.events.send(error_event(i, 1000)).unwrap();
        if i % 32 == 31 || i == N - 1 {
            let want = i + 1;
            eventually("fast subscriber to catch up", || {
                received.load(std::sync::atomic::Ordering::SeqCst) >= want
            })
            .await;
        }
    }
    let seqs = tokio::time::timeout(Duration::from_secs(60), reader)
        .await
        .unwrap()
        .unwrap();
    assert_eq!(
        seqs,
        (0..N).collect::<Vec<_>>(),
        "fast subscriber got every event in order"
    );
    assert_eq!(srv.stats.dropped_subscribers(), 1);

    // Now the slow one reads: its subscribe reply, a gap-free prefix of the
    // events, the notice, then EOF.
    let reply = read_json(&mut slow_r).await.unwrap();
    assert_eq!(reply["ok"], true);
    assert_eq!(reply["data"]["events"], json!(["error"]));
    let mut next = 0;
    let notice = loop {
        let v = read_json(&mut slow_r).await.expect("notice before EOF");
        if v["event"] == "dropped" {
            break v;
        }
        assert_eq!(v["event"], "error");
        assert_eq!(seq_of(&v), next);
        next += 1;
    };
    assert!(
        next > 0 && next < N,
        "slow subscriber got {next} events before the drop"
    );
    assert!(
        notice["reason"]
            .as_str()
            .unwrap()
            .contains("slow subscriber"),
        "{notice}"
    );
    assert_eq!(
        read_json(&mut slow_r).await,
        None,
        "closed after the notice"
    );

    // Others are still served.
    let mut c = Client::connect(&srv.path).await.unwrap();
    assert!(c.call(&Command::Status).await.unwrap().is_ok());
    drop((c, slow_w));
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn vanishing_clients_only_end_their_own_connection() {
    let srv = TestServer::start(|_| {}).await;
    let mut watcher = Client::connect(&srv.path).await.unwrap();
    watcher
        .subscribe(SubscribeArgs::default())
        .await
        .unwrap()
        .unwrap();
    let stats = srv.stats.clone();

    // 1. a subscriber vanishes while events stream to it;
    let (r, mut w) = raw(&srv.path).await;
    w.write_all(b"{\"id\":1,\"cmd\":\"subscribe\"}\n")
        .await
        .unwrap();
    eventually("second subscriber", || stats.subscribers() == 2).await;
    for i in 0..50 {
        srv.events.send(error_event(i, 100)).unwrap();
    }
    drop((r, w));
    // 2. one vanishes in the middle of a request line;
    let (r, mut w) = raw(&srv.path).await;
    w.write_all(b"{\"id\":1,\"cmd\":\"shut").await.unwrap();
    drop((r, w));
    // 3. one vanishes while its (slow) command runs;
    let (r, mut w) = raw(&srv.path).await;
    w.write_all(b"{\"id\":1,\"cmd\":\"peers\"}\n")
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    drop((r, w));
    // 4. one half-closes after a request and still gets its reply.
    let (mut r, mut w) = raw(&srv.path).await;
    w.write_all(b"{\"id\":\"hc\",\"cmd\":\"status\"}\n")
        .await
        .unwrap();
    w.shutdown().await.unwrap();
    let v = read_json(&mut r).await.unwrap();
    assert_eq!(v["id"], "hc");
    assert_eq!(read_json(&mut r).await, None);
    drop((r, w));

    for i in 50..60 {
        srv.events.send(error_event(i, 100)).unwrap();
    }
    eventually("vanished clients to be reaped", || {
        stats.clients() == 1 && stats.subscribers() == 1
    })
    .await;
    // The daemon did not shut down from the half line, and the watcher got everything.
    for i in 0..60 {
        match watcher.next_event().await.unwrap().unwrap() {
            telextiles_control::client::EventLine::Known(Event::Error { message, .. }) => {
                assert_eq!(message[..8].parse::<usize>().unwrap(), i)
            }
            other => panic!("{other:?}"),
        }
    }
    assert!(watcher.call(&Command::Status).await.unwrap().is_ok());
    drop(watcher);
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn subscription_filter_and_events_during_a_running_command() {
    let srv = TestServer::start(|_| {}).await;
    let mut c = Client::connect(&srv.path).await.unwrap();
    let data = c
        .subscribe(SubscribeArgs {
            events: Some(vec![EventKind::RollerArrived, EventKind::PeerUp]),
        })
        .await
        .unwrap()
        .unwrap();
    assert_eq!(data, json!({"events": ["peer_up", "roller_arrived"]}));
    let (mut r, mut w) = {
        drop(c);
        raw(&srv.path).await
    };
    w.write_all(b"{\"id\":1,\"cmd\":\"subscribe\",\"args\":{\"events\":[\"roller_arrived\",\"peer_up\"]}}\n")
        .await
        .unwrap();
    assert_eq!(read_json(&mut r).await.unwrap()["ok"], true);
    // `peers` takes 300 ms in the test handler; events published meanwhile
    // arrive before its reply, filtered.
    w.write_all(b"{\"id\":2,\"cmd\":\"peers\"}\n")
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(50)).await;
    srv.events
        .send(Event::Contact {
            phase: telextiles_control::protocol::ContactPhase::Start,
            score: Some(0.5),
            coverage: None,
        })
        .unwrap();
    srv.events
        .send(Event::RollerArrived {
            slot: 4,
            angle_deg: 90.0,
        })
        .unwrap();
    srv.events
        .send(Event::PeerUp {
            peer: "alice".into(),
            addr: Some("[::1]:4433".into()),
        })
        .unwrap();
    assert_eq!(
        read_json(&mut r).await.unwrap(),
        json!({"event": "roller_arrived", "slot": 4, "angle_deg": 90.0})
    );
    assert_eq!(
        read_json(&mut r).await.unwrap(),
        json!({"event": "peer_up", "peer": "alice", "addr": "[::1]:4433"})
    );
    let reply = read_json(&mut r).await.unwrap();
    assert_eq!(reply["id"], 2);
    assert_eq!(reply["data"][0]["name"], "alice");
    // Re-subscribing replaces the filter.
    w.write_all(b"{\"id\":3,\"cmd\":\"subscribe\",\"args\":{\"events\":[\"contact\"]}}\n")
        .await
        .unwrap();
    assert_eq!(
        read_json(&mut r).await.unwrap()["data"]["events"],
        json!(["contact"])
    );
    srv.events
        .send(Event::RollerArrived {
            slot: 1,
            angle_deg: 22.5,
        })
        .unwrap();
    srv.events
        .send(Event::Contact {
            phase: telextiles_control::protocol::ContactPhase::End,
            score: None,
            coverage: None,
        })
        .unwrap();
    assert_eq!(
        read_json(&mut r).await.unwrap(),
        json!({"event": "contact", "phase": "end"})
    );
    srv.events
        .send(Event::Contact {
            phase: telextiles_control::protocol::ContactPhase::End,
            score: Some(2.0),
            coverage: Some(0.375),
        })
        .unwrap();
    assert_eq!(
        read_json(&mut r).await.unwrap(),
        json!({"event": "contact", "phase": "end", "score": 2.0, "coverage": 0.375})
    );
    drop((r, w));
    srv.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stale_socket_is_replaced_and_live_owner_refused() {
    let dir = tempfile::Builder::new()
        .prefix("txc")
        .tempdir_in("/tmp")
        .unwrap();
    let sockdir = dir.path().join("telextilesd");
    let spec = SocketSpec::in_dir(&sockdir, Access::User);
    std::fs::create_dir_all(&sockdir).unwrap();
    std::fs::set_permissions(&sockdir, std::fs::Permissions::from_mode(0o700)).unwrap();
    // A socket file nobody listens on (a crashed daemon leaves this).
    drop(std::os::unix::net::UnixListener::bind(&spec.path).unwrap());
    assert!(spec.path.exists());
    assert!(std::os::unix::net::UnixStream::connect(&spec.path).is_err());

    let server = Server::bind(ServerConfig::new(spec.clone())).expect("stale socket replaced");
    assert!(server.replaced_stale());
    let (events, _) = tokio::sync::broadcast::channel(16);
    let stop = Arc::new(tokio::sync::Notify::new());
    let handler = Arc::new(common::TestHandler {
        calls: Default::default(),
        shutdown: stop.clone(),
    });
    let s2 = stop.clone();
    let join = tokio::spawn(server.serve(handler, events, async move { s2.notified().await }));
    let mut c = Client::connect(&spec.path).await.unwrap();
    assert!(c.call(&Command::Status).await.unwrap().is_ok());

    // A second daemon on the same socket is refused with a clear error,
    // and the first keeps working.
    let err = Server::bind(ServerConfig::new(spec.clone()))
        .err()
        .expect("refused");
    assert!(matches!(err, BindError::AlreadyRunning { .. }), "{err:?}");
    let msg = err.to_string();
    assert!(
        msg.contains("already running") && msg.contains(&spec.path.display().to_string()),
        "{msg}"
    );
    assert!(c
        .call(&Command::RollerGoto(GotoTarget::Slot(2)))
        .await
        .unwrap()
        .is_ok());

    // Shutdown over the socket: the reply arrives, then the socket file is gone.
    let r = c.call(&Command::Shutdown).await.unwrap().unwrap();
    assert_eq!(r, json!("shutting down"));
    tokio::time::timeout(Duration::from_secs(10), join)
        .await
        .unwrap()
        .unwrap();
    assert!(!spec.path.exists(), "socket removed on shutdown");
    assert!(Client::connect(&spec.path).await.is_err());

    // Something that is not a socket is never removed.
    std::fs::write(&spec.path, b"precious").unwrap();
    let err = Server::bind(ServerConfig::new(spec.clone())).err().unwrap();
    assert!(matches!(err, BindError::NotASocket { .. }), "{err}");
    assert_eq!(std::fs::read(&spec.path).unwrap(), b"precious");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn permissions_user_and_group_modes() {
    let dir = tempfile::Builder::new()
        .prefix("txc")
        .tempdir_in("/tmp")
        .unwrap();
    // User mode: a pre-existing too-open directory is tightened to 0700.
    let udir = dir.path().join("user");
    std::fs::create_dir(&udir).unwrap();
    std::fs::set_permissions(&udir, std::fs::Permissions::from_mode(0o755)).unwrap();
    let server = Server::bind(ServerConfig::new(SocketSpec::in_dir(&udir, Access::User))).unwrap();
    assert_eq!(std::fs::metadata(&udir).unwrap().mode() & 0o7777, 0o700);
    assert_eq!(
        std::fs::metadata(server.path()).unwrap().mode() & 0o7777,
        0o600
    );
    drop(server);
    assert!(!udir.join("control.sock").exists(), "unlinked on drop");

    // Group (system-wide) mode, with our own primary group (chown to a
    // group we belong to needs no privilege): created fresh, nested.
    let gid = std::fs::metadata(dir.path()).unwrap().gid();
    let gdir = dir.path().join("run").join("telextilesd");
    let server = Server::bind(ServerConfig::new(SocketSpec::in_dir(
        &gdir,
        Access::Group { gid },
    )))
    .unwrap();
    let dm = std::fs::metadata(&gdir).unwrap();
    assert_eq!(dm.mode() & 0o7777, 0o750);
    assert_eq!(dm.gid(), gid);
    let sm = std::fs::metadata(server.path()).unwrap();
    assert_eq!(sm.mode() & 0o7777, 0o660);
    assert_eq!(sm.gid(), gid);
    drop(server);

    // No XDG_RUNTIME_DIR: a clear error instead of a guess.
    let msg = BindError::NoRuntimeDir.to_string();
    assert!(msg.contains("XDG_RUNTIME_DIR") && msg.contains("--socket"));
}
