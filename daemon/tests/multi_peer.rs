//! More than two devices, end to end (real `telextilesd run` processes,
//! real QUIC on loopback, simulated DIGITs and rollers): a shop shows one
//! fabric to two customers at once (one sender, two receivers), and two
//! customers press at the same time towards the shop (two senders, one
//! receiver), each press decided on its own.
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use telextiles_certs::{Identity, PeerRecord, TrustStore};
use telextiles_control::client::{Client, EventLine};
use telextiles_control::{Command as Ctl, Event, SimPressArgs, SubscribeArgs};

const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");
const MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/encoder.onnx");
const INDEX: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/index.tlxi");

struct Node {
    name: &'static str,
    id: String,
    child: Child,
    socket: std::path::PathBuf,
    log: std::path::PathBuf,
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn port() -> SocketAddr {
    let p = std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    format!("127.0.0.1:{p}").parse().unwrap()
}

/// Three devices: `shop` paired with both customers, each customer paired
/// with the shop only; customers dial the shop.
fn start(work: &Path) -> (Node, Node, Node) {
    let names = ["shop", "c1", "c2"];
    let ids: Vec<Identity> = names
        .iter()
        .map(|_| Identity::generate().unwrap())
        .collect();
    let pairs: [(usize, &[usize]); 3] = [(0, &[1, 2]), (1, &[0]), (2, &[0])];
    for (me, peers) in pairs {
        let state = work.join(names[me]).join("state");
        std::fs::create_dir_all(&state).unwrap();
        ids[me].save(&state).unwrap();
        let mut st = TrustStore::load(&state).unwrap();
        for &p in peers {
            st.insert(PeerRecord::new(
                ids[p].peer_key(),
                names[p],
                SystemTime::now(),
            ));
        }
        st.save().unwrap();
    }
    let shop_addr = port();
    let spawn = |k: usize, listen: SocketAddr, connect: Option<SocketAddr>| {
        let dir = work.join(names[k]);
        std::fs::write(dir.join("none.toml"), "").unwrap();
        let log = dir.join("daemon.log");
        let mut cmd = Command::new(BIN);
        cmd.arg("run")
            .args(["--name", names[k]])
            .arg("--config")
            .arg(dir.join("none.toml"))
            .arg("--state-dir")
            .arg(dir.join("state"))
            .arg("--data-dir")
            .arg(dir.join("data"))
            .arg("--runtime-dir")
            .arg(&dir)
            .arg("--socket")
            .arg(dir.join("control.sock"))
            .args([
                "--sensor",
                "sim",
                "--roller",
                "sim",
                "--map=false",
                "--mdns=false",
            ])
            .args([
                "--listen",
                &listen.to_string(),
                "--model",
                MODEL,
                "--index",
                INDEX,
            ])
            .env("TELEXTILESD_SIM_ROLLER_SPEED", "8")
            .env("RUST_LOG", "warn")
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap());
        if let Some(c) = connect {
            cmd.args(["--connect", &format!("{}@{c}", ids[0].peer_key())]);
        }
        Node {
            name: names[k],
            id: ids[k].device_id().to_string(),
            child: cmd.spawn().unwrap(),
            socket: dir.join("control.sock"),
            log,
        }
    };
    (
        spawn(0, shop_addr, None),
        spawn(1, port(), Some(shop_addr)),
        spawn(2, port(), Some(shop_addr)),
    )
}

async fn client(n: &Node) -> Client {
    let t0 = Instant::now();
    loop {
        match Client::connect(&n.socket).await {
            Ok(c) => return c,
            Err(e) if t0.elapsed() > Duration::from_secs(60) => panic!(
                "{}: no control socket: {e}\n{}",
                n.name,
                std::fs::read_to_string(&n.log).unwrap_or_default()
            ),
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

async fn wait_peers(n: &Node, want: usize) {
    let mut c = client(n).await;
    let t0 = Instant::now();
    loop {
        let st = c.call(&Ctl::Status).await.unwrap().unwrap();
        if st["peers"].as_array().is_some_and(|p| p.len() >= want) {
            return;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(60),
            "{} never saw {want} peers: {st}\n{}",
            n.name,
            std::fs::read_to_string(&n.log).unwrap_or_default()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Subscribe to decisions: (peer, textile, slot, final).
async fn finals(n: &Node) -> tokio::sync::mpsc::UnboundedReceiver<(String, String, u32, bool)> {
    let mut c = client(n).await;
    c.subscribe(SubscribeArgs::default())
        .await
        .unwrap()
        .unwrap();
    let (tx, rx) = tokio::sync::mpsc::unbounded_channel();
    tokio::spawn(async move {
        while let Ok(Some(e)) = c.next_event().await {
            if let EventLine::Known(Event::Decision {
                textile,
                slot,
                peer,
                final_decision,
                ..
            }) = e
            {
                let _ = tx.send((peer.unwrap_or_default(), textile, slot, final_decision));
            }
        }
    });
    rx
}

async fn press(n: &Node, textile: &str) {
    let mut c = client(n).await;
    c.call(&Ctl::SensorSim(SimPressArgs {
        textile: textile.into(),
        person: None,
        sensor: None,
        jig: Some(true),
        seed: Some(1),
        rotation_deg: None,
        force: None,
    }))
    .await
    .unwrap()
    .unwrap();
}

/// Final decisions of `n` peers: peer -> (textile, slot); and the peers
/// that also got a live decision before their press ended.
async fn collect_live(
    rx: &mut tokio::sync::mpsc::UnboundedReceiver<(String, String, u32, bool)>,
    n: usize,
    who: &Node,
) -> (
    BTreeMap<String, (String, u32)>,
    std::collections::BTreeSet<String>,
) {
    let mut out = BTreeMap::new();
    let mut live = std::collections::BTreeSet::new();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(40);
    while out.len() < n {
        match tokio::time::timeout_at(deadline, rx.recv()).await {
            Ok(Some((peer, _, _, false))) => {
                live.insert(peer);
            }
            Ok(Some((peer, textile, slot, true))) => {
                out.insert(peer, (textile, slot));
            }
            _ => panic!(
                "{}: {} of {n} final decisions: {out:?}\n{}",
                who.name,
                out.len(),
                std::fs::read_to_string(&who.log).unwrap_or_default()
            ),
        }
    }
    (out, live)
}

async fn collect(
    rx: &mut tokio::sync::mpsc::UnboundedReceiver<(String, String, u32, bool)>,
    n: usize,
    who: &Node,
) -> BTreeMap<String, (String, u32)> {
    collect_live(rx, n, who).await.0
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_shop_two_customers_both_ways() {
    let work = tempfile::tempdir().unwrap();
    let (shop, c1, c2) = start(work.path());
    wait_peers(&shop, 2).await;
    wait_peers(&c1, 1).await;
    wait_peers(&c2, 1).await;

    // The shop shows one fabric: both customers decide it, each on its own.
    let (mut f1, mut f2) = (finals(&c1).await, finals(&c2).await);
    press(&shop, "T030").await;
    let d1 = collect(&mut f1, 1, &c1).await;
    let d2 = collect(&mut f2, 1, &c2).await;
    assert_eq!(d1.keys().collect::<Vec<_>>(), [&shop.id]);
    assert_eq!(d2.keys().collect::<Vec<_>>(), [&shop.id]);
    assert_eq!(
        d1[&shop.id], d2[&shop.id],
        "both customers feel the same fabric"
    );
    assert_eq!(d1[&shop.id].0, "T030");

    // Two customers press different fabrics at the same time: the shop
    // decides each press on its own (one press per peer; they used to reset
    // each other), exactly as when each pressed alone.
    let mut fs = finals(&shop).await;
    press(&c1, "T030").await;
    let alone1 = collect(&mut fs, 1, &shop).await;
    press(&c2, "T110").await;
    let alone2 = collect(&mut fs, 1, &shop).await;
    tokio::join!(press(&c1, "T030"), press(&c2, "T110"));
    let (d, live) = collect_live(&mut fs, 2, &shop).await;
    // Decided live too, not only at the end of each press.
    assert!(live.contains(&c1.id) && live.contains(&c2.id), "{live:?}");
    assert_eq!(d[&c1.id], alone1[&c1.id], "{d:?}");
    assert_eq!(d[&c2.id], alone2[&c2.id], "{d:?}");
    assert_eq!(d[&c1.id].0, "T030", "{d:?}");
    assert_ne!(d[&c1.id], d[&c2.id], "{d:?}");
}
