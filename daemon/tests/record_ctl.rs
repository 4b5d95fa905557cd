//! Recording over the control socket: a real `telextilesd run` with the
//! simulated DIGIT, driven by `record.start` / `record.stop` as a script
//! would (docs/control-protocol.md#recording). Loopback only, mDNS off.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use telextiles_control::client::{Client, EventLine};
use telextiles_control::{
    Command as Ctl, ErrorCode, Event, EventKind, RecordPhase, RecordStartArgs, SubscribeArgs,
};

const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");

struct Daemon {
    child: Child,
    socket: PathBuf,
    log: PathBuf,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("repository root")
        .to_path_buf()
}

fn start(work: &Path) -> Daemon {
    let socket = work.join("control.sock");
    let log = work.join("daemon.log");
    std::fs::write(work.join("none.toml"), "").expect("config");
    let port = std::net::UdpSocket::bind("127.0.0.1:0")
        .and_then(|s| s.local_addr())
        .expect("free port")
        .port();
    let child = Command::new(BIN)
        .arg("run")
        .args(["--name", "recorder"])
        .arg("--state-dir")
        .arg(work.join("state"))
        .arg("--data-dir")
        .arg(work.join("data"))
        .arg("--runtime-dir")
        .arg(work)
        .arg("--socket")
        .arg(&socket)
        .arg("--config")
        .arg(work.join("none.toml"))
        .arg("--model")
        .arg(repo().join("models/encoder.onnx"))
        .arg("--index")
        .arg(repo().join("models/index.tlxi"))
        .args(["--sensor", "sim:T030"])
        .args(["--roller", "none", "--map=false", "--mdns=false"])
        .args(["--listen", &format!("127.0.0.1:{port}")])
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).expect("log"))
        .spawn()
        .expect("start telextilesd run");
    Daemon { child, socket, log }
}

async fn connect(d: &Daemon) -> Client {
    let t0 = Instant::now();
    loop {
        match Client::connect(&d.socket).await {
            Ok(c) => return c,
            Err(e) if t0.elapsed() > Duration::from_secs(60) => panic!(
                "control socket did not come up: {e}; log:\n{}",
                std::fs::read_to_string(&d.log).unwrap_or_default()
            ),
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

/// Record events until one matches `until` (or 60 s pass).
async fn events_until(c: &mut Client, until: impl Fn(&Event) -> bool, log: &Path) -> Vec<Event> {
    let mut got = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        let ev = tokio::time::timeout(left, c.next_event())
            .await
            .unwrap_or_else(|_| {
                panic!(
                    "no end of recording within 60 s; events: {got:?}; log:\n{}",
                    std::fs::read_to_string(log).unwrap_or_default()
                )
            })
            .expect("event stream")
            .expect("daemon closed the connection");
        if let EventLine::Known(e) = ev {
            let stop = until(&e);
            got.push(e);
            if stop {
                return got;
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn record_start_over_the_control_socket_writes_presses_and_reports() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let work = tmp.path();
    let d = start(work);
    // Commands on their own connection: a call skips the events that arrive
    // while it waits for its reply, and record.stop's reply comes after the
    // `stopped` event.
    let mut ctl = connect(&d).await;
    let mut c = connect(&d).await;
    c.subscribe(SubscribeArgs {
        events: Some(vec![EventKind::Record, EventKind::Contact]),
    })
    .await
    .expect("io")
    .expect("subscribe");
    let out = work.join("recordings");

    // Bad requests are refused before anything is recorded.
    let blocker = work.join("a-file");
    std::fs::write(&blocker, "").expect("file");
    let e = ctl
        .call(&Ctl::RecordStart(RecordStartArgs {
            textile: "T030".into(),
            name: None,
            presses: 1,
            out: blocker.display().to_string(),
        }))
        .await
        .expect("io")
        .expect_err("a file is no directory");
    assert_eq!(e.code, ErrorCode::Failed, "{e:?}");

    let reply = ctl
        .call(&Ctl::RecordStart(RecordStartArgs {
            textile: "T030".into(),
            name: Some("twill".into()),
            presses: 2,
            out: out.display().to_string(),
        }))
        .await
        .expect("io")
        .expect("record.start");
    assert_eq!(reply["first"], "0001", "{reply}");
    assert_eq!(reply["presses"], 2, "{reply}");
    let events = events_until(
        &mut c,
        |e| {
            matches!(
                e,
                Event::Record {
                    state: RecordPhase::Done | RecordPhase::Stopped,
                    ..
                }
            )
        },
        &d.log,
    )
    .await;
    assert!(
        matches!(
            events.last(),
            Some(Event::Record {
                state: RecordPhase::Done,
                ..
            })
        ),
        "{events:?}"
    );
    let saved: Vec<&str> = events
        .iter()
        .filter_map(|e| match e {
            Event::RecordSaved { path, .. } => Some(path.as_str()),
            _ => None,
        })
        .collect();
    assert_eq!(saved.len(), 2, "{events:?}");
    for (n, p) in ["0001", "0002"].iter().zip(&saved) {
        let dir = out.join("T030").join(n);
        assert_eq!(Path::new(p), dir);
        let m = telextiles_sim::recording::read_meta(&dir).expect("press.json");
        assert_eq!(m.textile, "T030");
        assert_eq!(m.source, "sim");
        assert!(m.reference_frames.is_some_and(|k| k >= 8), "{m:?}");
    }
    for want in [
        RecordPhase::Ready,
        RecordPhase::Contact,
        RecordPhase::Released,
    ] {
        assert!(
            events
                .iter()
                .any(|e| matches!(e, Event::Record { state, .. } if *state == want)),
            "no {want:?} in {events:?}"
        );
    }
    // Each press's contact end says how much of the gel it touched: the
    // simulated DIGIT presses flat, in the jig (the first press's end
    // comes before the second press; the last one's may follow `done`).
    let ends: Vec<Option<f32>> = events
        .iter()
        .filter_map(|e| match e {
            Event::Contact {
                phase: telextiles_control::ContactPhase::End,
                coverage,
                ..
            } => Some(*coverage),
            _ => None,
        })
        .collect();
    assert!(!ends.is_empty(), "{events:?}");
    for c in ends {
        assert!(c.is_some_and(|c| (0.5..=1.0).contains(&c)), "{events:?}");
    }
    let info = std::fs::read_to_string(out.join("T030/textile.json")).expect("textile.json");
    assert!(info.contains("twill"), "{info}");

    // A second recording, stopped early: nothing half-written is left.
    ctl.call(&Ctl::RecordStart(RecordStartArgs {
        textile: "T030".into(),
        name: None,
        presses: 50,
        out: out.display().to_string(),
    }))
    .await
    .expect("io")
    .expect("record.start");
    events_until(
        &mut c,
        |e| {
            matches!(
                e,
                Event::Record {
                    state: RecordPhase::Contact,
                    ..
                }
            )
        },
        &d.log,
    )
    .await;
    let r = ctl
        .call(&Ctl::RecordStop)
        .await
        .expect("io")
        .expect("record.stop");
    assert_eq!(r["stopped"], true, "{r}");
    let events = events_until(
        &mut c,
        |e| {
            matches!(
                e,
                Event::Record {
                    state: RecordPhase::Stopped,
                    ..
                }
            )
        },
        &d.log,
    )
    .await;
    let Some(Event::Record {
        reason: Some(reason),
        ..
    }) = events.last()
    else {
        panic!("{events:?}")
    };
    assert!(reason.starts_with("record.stop"), "{reason}");
    let entries: Vec<String> = std::fs::read_dir(out.join("T030"))
        .expect("dir")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert!(entries.iter().all(|n| !n.contains(".tmp-")), "{entries:?}");
    let saved_before_stop = r["saved"].as_u64().expect("saved");
    assert_eq!(
        entries.len() as u64,
        2 + 1 + saved_before_stop,
        "{entries:?}"
    );
    // Nothing running now.
    let r = ctl
        .call(&Ctl::RecordStop)
        .await
        .expect("io")
        .expect("record.stop");
    assert_eq!(r["stopped"], false, "{r}");
}
