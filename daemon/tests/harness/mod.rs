//! Two live `telextilesd run` daemons on this machine, paired beforehand,
//! both pressing simulated textiles at 60 fps (so latents flow both ways;
//! or replaying recordings, `Setup::sensors`),
//! optionally through the userspace delay/jitter relay, with per-frame
//! latency traces (`--latency-trace`), process samples (CPU, RSS) and their
//! control-socket events. Shared by the latency benchmark
//! (`benches/session_latency.rs`) and the soak test (`tests/soak.rs`).
//!
//! Loopback only (127.0.0.1, mDNS off), or (`Setup::nat`) the two home
//! networks behind NAT routers of `telextiles_tests::nat` with
//! `telextilesd relay` on the lab's public network: nothing leaves the
//! machine.
#![allow(dead_code)]

use std::collections::{BTreeMap, BTreeSet};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use telextiles_certs::{Identity, PeerRecord, TrustStore};
use telextiles_control::client::{Client, EventLine};
use telextiles_control::{Command as Ctl, Event, SubscribeArgs};
use telextiles_tests::nat::{Mapping, NatLab};
use telextiles_tests::netns::Netns;
use telextiles_tests::relay::{Impairment, Relay};

pub const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");
/// The shipped model and index, which the daemons here run with.
pub const MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/encoder.onnx");
pub const INDEX: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/index.tlxi");

/// CLOCK_MONOTONIC in µs (the clock of the daemons' traces).
pub fn mono_us() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    t.tv_sec as u64 * 1_000_000 + t.tv_nsec as u64 / 1000
}

/// One side.
pub struct Side {
    pub name: &'static str,
    pub child: Child,
    pub socket: PathBuf,
    pub trace: PathBuf,
    pub log: PathBuf,
    /// (time µs, CPU seconds so far, RSS bytes).
    pub samples: Arc<Mutex<Vec<(u64, f64, u64)>>>,
    /// Control-socket events with their arrival time (mono µs).
    pub events: Arc<Mutex<Vec<(u64, Event)>>>,
}

impl Drop for Side {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

/// How to run the pair.
#[derive(Clone, Debug)]
pub struct Setup {
    /// Relay delay and jitter in ms between B (client) and A (server).
    pub relay: Option<(u64, u64)>,
    /// The sensors of A and of B (`--sensor`): by default each a
    /// simulated DIGIT pressing one textile again and again.
    pub sensors: (String, String),
    /// Further flags of A and of B (e.g. `--reference PNG`).
    pub flags: (Vec<String>, Vec<String>),
    /// Each daemon on its own home network behind a NAT router mapping
    /// this way, meeting through `telextilesd relay` (needs root; `relay`
    /// must then be `None`). B dials A by key alone, through the relay.
    pub nat: Option<Mapping>,
}

impl Default for Setup {
    fn default() -> Self {
        Setup {
            relay: None,
            sensors: ("sim:T012".into(), "sim:T047".into()),
            flags: Default::default(),
            nat: None,
        }
    }
}

pub struct Pair {
    pub a: Side,
    pub b: Side,
    pub relay: Option<Relay>,
    /// `Setup::nat`: the relay daemon, then the lab (dropped after the
    /// daemons, which live in its namespaces).
    pub meet: Option<Meet>,
    pub work: tempfile::TempDir,
    /// When the daemons were started.
    pub started: Instant,
    /// From their start to A listing B as connected.
    pub connected_after: Duration,
    stop: Arc<std::sync::atomic::AtomicBool>,
}

/// The NAT lab of a `Setup::nat` pair and the relay on its public network.
pub struct Meet {
    pub relay: Child,
    pub url: String,
    pub cert: PathBuf,
    pub lab: NatLab,
}

impl Drop for Meet {
    fn drop(&mut self) {
        let _ = self.relay.kill();
        let _ = self.relay.wait();
    }
}

/// The port `telextilesd relay` serves on in the NAT lab.
const RELAY_PORT: u16 = 3340;

/// Starts `telextilesd relay` on the lab's public network serving `keys`
/// with a self-signed certificate made in `dir`; its URL and certificate.
fn start_relay(lab: NatLab, dir: &Path, keys: &[String]) -> Meet {
    use std::io::BufRead;
    let mut cmd = lab.public.command(BIN);
    cmd.arg("relay")
        .args(["--listen", &format!("{}:{RELAY_PORT}", lab.relay_ip)])
        .args(["--name", &lab.relay_ip.to_string()])
        .arg("--state-dir")
        .arg(dir)
        .args(["--allow", &keys.join(",")])
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    let mut relay = cmd.spawn().expect("start telextilesd relay");
    let out = relay.stdout.take().unwrap();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in std::io::BufReader::new(out).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let (mut url, mut cert) = (None, None);
    while url.is_none() || cert.is_none() {
        let line = rx
            .recv_timeout(Duration::from_secs(20))
            .expect("telextilesd relay printed its URL and certificate");
        if let Some(u) = line.strip_prefix("Relay: ") {
            url = Some(u.trim().to_string());
        }
        if let Some(c) = line.strip_prefix("Self-signed certificate: ") {
            cert = c.split(" (").next().map(PathBuf::from);
        }
    }
    Meet {
        relay,
        url: url.unwrap(),
        cert: cert.unwrap(),
        lab,
    }
}

pub fn free_udp_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Starts one daemon `name` under `work/name` (whose `state/` holds its
/// identity and trust store), listening at `listen`, dialling `connect`
/// (`KEY@HOST:PORT`).
pub fn spawn(
    name: &'static str,
    work: &Path,
    listen: SocketAddr,
    connect: Option<String>,
    sensor: &str,
    flags: &[String],
) -> Side {
    spawn_in(None, name, work, listen, connect, sensor, flags)
}

/// [`spawn`], inside network namespace `ns` when given.
pub fn spawn_in(
    ns: Option<&Netns>,
    name: &'static str,
    work: &Path,
    listen: SocketAddr,
    connect: Option<String>,
    sensor: &str,
    flags: &[String],
) -> Side {
    let dir = work.join(name);
    let socket = dir.join("control.sock");
    let trace = dir.join("trace.txt");
    let log = dir.join("daemon.log");
    std::fs::write(dir.join("none.toml"), "").unwrap();
    let mut cmd = match ns {
        Some(ns) => ns.command(BIN),
        None => Command::new(BIN),
    };
    cmd.arg("run")
        .args(["--name", &format!("bench-{name}")])
        .arg("--state-dir")
        .arg(dir.join("state"))
        .arg("--data-dir")
        .arg(dir.join("data"))
        .arg("--runtime-dir")
        .arg(&dir)
        .arg("--socket")
        .arg(&socket)
        .args(["--sensor", sensor])
        .args(flags)
        .args(["--roller", "sim", "--map=false", "--mdns=false"])
        .args(["--listen", &listen.to_string()])
        .args(["--model", MODEL])
        // The shipped index, unless the flags name another.
        .args(if flags.iter().any(|f| f == "--index") {
            &[][..]
        } else {
            &["--index", INDEX][..]
        })
        .arg("--config")
        .arg(dir.join("none.toml"))
        .arg("--latency-trace")
        .arg(&trace)
        // The wheel in real time: the felt latency is a real wheel's.
        .env("TELEXTILESD_SIM_ROLLER_SPEED", "1")
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&log).unwrap());
    if let Some(c) = connect {
        cmd.args(["--connect", &c]);
    }
    let child = cmd.spawn().expect("start telextilesd");
    Side {
        name,
        child,
        socket,
        trace,
        log,
        samples: Arc::default(),
        events: Arc::default(),
    }
}

fn proc_sample(pid: u32) -> Option<(f64, u64)> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) in parentheses.
    let rest = &stat[stat.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split(' ').collect();
    let tick = 100.0; // USER_HZ
    let cpu = (f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?) / tick;
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let rss_kb: u64 = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))?
        .split_whitespace()
        .nth(1)?
        .parse()
        .ok()?;
    Some((cpu, rss_kb * 1024))
}

/// A control-socket client of `side`, once its socket is up (60 s at most).
pub async fn connect(side: &Side) -> Client {
    let t0 = Instant::now();
    loop {
        match Client::connect(&side.socket).await {
            Ok(c) => return c,
            Err(e) if t0.elapsed() > Duration::from_secs(60) => panic!(
                "daemon {}: control socket did not come up: {e}; log:\n{}",
                side.name,
                std::fs::read_to_string(&side.log).unwrap_or_default()
            ),
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

/// `dir/state` as `telextilesd pair` leaves it: `me`'s identity and a
/// trust store holding `peer` under `peer_name`.
pub fn paired_state(dir: &Path, me: &Identity, peer: &Identity, peer_name: &str) {
    let state = dir.join("state");
    std::fs::create_dir_all(&state).unwrap();
    me.save(&state).unwrap();
    let mut st = TrustStore::load(&state).unwrap();
    st.insert(PeerRecord::new(
        peer.peer_key(),
        peer_name,
        SystemTime::now(),
    ));
    st.save().unwrap();
}

impl Pair {
    /// Starts both daemons (already paired), waits until they are connected.
    pub async fn start(setup: &Setup) -> Pair {
        let work = tempfile::tempdir().unwrap();
        let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
        for (name, me, peer, peer_name) in [("a", &ia, &ib, "bench-b"), ("b", &ib, &ia, "bench-a")]
        {
            paired_state(&work.path().join(name), me, peer, peer_name);
        }
        let (a_addr, b_addr): (SocketAddr, SocketAddr) = match setup.nat {
            // Each in its own namespace: the same port will do.
            Some(_) => (
                "0.0.0.0:7000".parse().unwrap(),
                "0.0.0.0:7000".parse().unwrap(),
            ),
            None => (
                format!("127.0.0.1:{}", free_udp_port()).parse().unwrap(),
                format!("127.0.0.1:{}", free_udp_port()).parse().unwrap(),
            ),
        };
        let relay = match setup.relay {
            Some((d, j)) => Some(
                Relay::start(
                    "127.0.0.1:0".parse().unwrap(),
                    a_addr,
                    Impairment::delay(d, j),
                )
                .await
                .expect("start the relay"),
            ),
            None => None,
        };
        let meet = setup.nat.map(|mapping| {
            assert!(setup.relay.is_none(), "a NAT pair has no delay relay");
            let lab = NatLab::new(mapping).expect("build the NAT lab (needs root)");
            let keys = [ia.peer_key().to_string(), ib.peer_key().to_string()];
            start_relay(lab, &work.path().join("relay"), &keys)
        });
        let (mut flags_a, mut flags_b) = setup.flags.clone();
        let mut connect_b = {
            let target = relay.as_ref().map_or(a_addr, |r| r.local_addr());
            format!("{}@{target}", ia.peer_key())
        };
        if let Some(m) = &meet {
            for f in [&mut flags_a, &mut flags_b] {
                f.extend([
                    "--relay".to_string(),
                    m.url.clone(),
                    "--relay-cert".to_string(),
                    m.cert.display().to_string(),
                ]);
            }
            // By key alone: through the relay, where A's link is known.
            connect_b = ia.peer_key().to_string();
        }
        let ns = |home: fn(&NatLab) -> &Netns| meet.as_ref().map(|m| home(&m.lab));
        let started = Instant::now();
        let a = spawn_in(
            ns(|l| &l.a.host),
            "a",
            work.path(),
            a_addr,
            None,
            &setup.sensors.0,
            &flags_a,
        );
        let b = spawn_in(
            ns(|l| &l.b.host),
            "b",
            work.path(),
            b_addr,
            Some(connect_b),
            &setup.sensors.1,
            &flags_b,
        );
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        let mut pair = Pair {
            a,
            b,
            relay,
            meet,
            work,
            started,
            connected_after: Duration::ZERO,
            stop,
        };
        // Up: A sees B as a connected peer.
        let mut ctl = connect(&pair.a).await;
        let t0 = Instant::now();
        loop {
            let st = ctl.call(&Ctl::Status).await.unwrap().unwrap();
            if st["peers"].as_array().is_some_and(|p| !p.is_empty()) {
                pair.connected_after = started.elapsed();
                break;
            }
            assert!(
                t0.elapsed() < Duration::from_secs(60),
                "the daemons did not connect; logs:\n{}\n{}",
                std::fs::read_to_string(&pair.a.log).unwrap_or_default(),
                std::fs::read_to_string(&pair.b.log).unwrap_or_default()
            );
            tokio::time::sleep(Duration::from_millis(100)).await;
        }
        for side in [&pair.a, &pair.b] {
            // Events.
            let mut c = connect(side).await;
            c.subscribe(SubscribeArgs::default())
                .await
                .unwrap()
                .unwrap();
            let events = side.events.clone();
            tokio::spawn(async move {
                while let Ok(Some(e)) = c.next_event().await {
                    if let EventLine::Known(e) = e {
                        events.lock().unwrap().push((mono_us(), e));
                    }
                }
            });
            // Process samples every 500 ms.
            let pid = side.child.id();
            let samples = side.samples.clone();
            let stop = pair.stop.clone();
            std::thread::spawn(move || {
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    match proc_sample(pid) {
                        Some((cpu, rss)) => samples.lock().unwrap().push((mono_us(), cpu, rss)),
                        None => break,
                    }
                    std::thread::sleep(Duration::from_millis(500));
                }
            });
        }
        pair
    }

    /// The path `side` reaches its peer by now, as `ctl status` says
    /// (`direct`, `relay`, `unknown`), or `None` while it lists no peer.
    pub async fn path(side: &Side) -> Option<String> {
        let mut c = connect(side).await;
        let st = c.call(&Ctl::Status).await.unwrap().unwrap();
        st["peers"][0]["path"].as_str().map(str::to_string)
    }

    /// Waits (polling `ctl status` every 50 ms, `within` at most) until
    /// both sides say their path is `kind`; how long that took from the
    /// daemons' start, or `None`.
    pub async fn wait_path(&self, kind: &str, within: Duration) -> Option<Duration> {
        let t0 = Instant::now();
        loop {
            let (a, b) = (Pair::path(&self.a).await, Pair::path(&self.b).await);
            if a.as_deref() == Some(kind) && b.as_deref() == Some(kind) {
                return Some(self.started.elapsed());
            }
            if t0.elapsed() > within {
                return None;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }

    /// Stops both daemons (SIGTERM, then kill) and returns their traces.
    pub fn stop(mut self) -> (Traces, Traces, Side, Side) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        for side in [&mut self.a, &mut self.b] {
            let _ = Command::new("kill")
                .args(["-TERM", &side.child.id().to_string()])
                .status();
        }
        for side in [&mut self.a, &mut self.b] {
            let t0 = Instant::now();
            while matches!(side.child.try_wait(), Ok(None))
                && t0.elapsed() < Duration::from_secs(10)
            {
                std::thread::sleep(Duration::from_millis(50));
            }
        }
        // The trace writers flush whenever idle; give them a moment.
        std::thread::sleep(Duration::from_millis(200));
        let ta = Traces::read(&self.a.trace);
        let tb = Traces::read(&self.b.trace);
        let Pair { a, b, work, .. } = self;
        if std::env::var_os("TELEXTILES_KEEP").is_some() {
            eprintln!("keeping {}", work.keep().display());
        }
        (ta, tb, a, b)
    }
}

/// A counter of a side's `status` (e.g. `frames`).
pub async fn counter(side: &Side, key: &str) -> u64 {
    let mut c = connect(side).await;
    let st = c.call(&Ctl::Status).await.unwrap().unwrap();
    st["counters"][key].as_u64().unwrap_or(0)
}

/// One daemon's trace (`daemon/src/trace.rs`).
#[derive(Default, Debug)]
pub struct Traces {
    /// seq -> (press, [capture, contact, encoded, quantised, sent]).
    pub tx: BTreeMap<u64, (u32, [u64; 5])>,
    /// seq -> (press, [received, handled, decided], changed slot).
    pub rx: BTreeMap<u64, (u32, [u64; 3], Option<u32>)>,
    /// (slot, written).
    pub serial: Vec<(Option<u32>, u64)>,
}

impl Traces {
    pub fn read(path: &Path) -> Traces {
        let text = std::fs::read_to_string(path)
            .unwrap_or_else(|e| panic!("cannot read the trace {}: {e}", path.display()));
        let mut t = Traces::default();
        for line in text.lines().filter(|l| !l.starts_with('#')) {
            let f: Vec<&str> = line.split(' ').collect();
            let n = |i: usize| f.get(i).and_then(|x| x.parse::<u64>().ok());
            match f[0] {
                "tx" if f.len() == 8 => {
                    let v: Option<Vec<u64>> = (1..8).map(n).collect();
                    if let Some(v) = v {
                        t.tx.insert(v[0], (v[1] as u32, [v[2], v[3], v[4], v[5], v[6]]));
                    }
                }
                "rx" if f.len() == 8 => {
                    let v: Option<Vec<u64>> = (1..7).map(n).collect();
                    if let Some(v) = v {
                        let slot = (v[5] == 1).then(|| n(7).map(|s| s as u32)).flatten();
                        t.rx.insert(v[0], (v[1] as u32, [v[2], v[3], v[4]], slot));
                    }
                }
                "serial" if f.len() == 3 => {
                    if let Some(w) = n(2) {
                        t.serial.push((n(1).map(|s| s as u32), w));
                    }
                }
                _ => {} // a line cut short by the kill
            }
        }
        t
    }
}

/// Per-frame stage times (µs) of one direction, joined on the sender's seq.
#[derive(Default, Debug)]
pub struct Stages {
    /// One vector per stage of [`STAGES`].
    pub values: Vec<Vec<f64>>,
    /// Capture on the sender -> decision on the receiver.
    pub total_decided: Vec<f64>,
    /// The same minus the wire stage (software-added).
    pub software: Vec<f64>,
    /// Capture -> roller command written, for frames that changed the decision.
    pub total_serial: Vec<f64>,
    /// Contact (first encoded frame of a press) -> its first stable decision
    /// (the roller command is issued then, if the wheel is not there yet).
    pub contact_to_decision: Vec<f64>,
    /// Decision changes that needed no serial command (wheel already there).
    pub no_command: usize,
    /// Frames sent / received in the window.
    pub sent: usize,
    pub received: usize,
}

pub const STAGES: [&str; 8] = [
    "contact detection",
    "preprocess + encode",
    "quantise + frame",
    "send (QUIC)",
    "wire (QUIC + relay)",
    "receive (to session)",
    "decide",
    "serial write",
];

/// Joins `from.tx` with `to.rx` and `to.serial` for frames captured in `[t0, t1)`.
pub fn stages(from: &Traces, to: &Traces, t0: u64, t1: u64) -> Stages {
    let mut s = Stages {
        values: vec![Vec::new(); STAGES.len()],
        ..Default::default()
    };
    let us = |a: u64, b: u64| b.saturating_sub(a) as f64;
    let mut first_of_press: BTreeMap<u32, u64> = BTreeMap::new();
    for (press, t) in from.tx.values() {
        first_of_press.entry(*press).or_insert(t[0]);
    }
    // Decision changes on the receiver, in time order: a roller command
    // for one is looked for only until the next (latest target wins).
    let mut changes: Vec<u64> = to
        .rx
        .values()
        .filter(|r| r.2.is_some())
        .map(|r| r.1[2])
        .collect();
    changes.sort_unstable();
    let mut first_decision: BTreeSet<u32> = BTreeSet::new();
    for (seq, (press, t)) in &from.tx {
        if t[0] < t0 || t[0] >= t1 {
            continue;
        }
        s.sent += 1;
        let Some((_, r, changed)) = to.rx.get(seq) else {
            continue;
        };
        s.received += 1;
        let row = [
            us(t[0], t[1]),
            us(t[1], t[2]),
            us(t[2], t[3]),
            us(t[3], t[4]),
            us(t[4], r[0]),
            us(r[0], r[1]),
            us(r[1], r[2]),
        ];
        for (i, v) in row.iter().enumerate() {
            s.values[i].push(*v);
        }
        s.total_decided.push(us(t[0], r[2]));
        s.software.push(us(t[0], r[2]) - row[4]);
        let Some(slot) = changed else { continue };
        if first_decision.insert(*press) {
            // Only presses that began inside the window (their first
            // decision is then inside it too).
            if let Some(&c) = first_of_press.get(press).filter(|&&c| c >= t0) {
                s.contact_to_decision.push(us(c, r[2]));
            }
        }
        let next = changes
            .iter()
            .find(|&&c| c > r[2])
            .copied()
            .unwrap_or(u64::MAX);
        // No write when the wheel is already at (or already told) that slot.
        match to
            .serial
            .iter()
            .find(|(sl, w)| *sl == Some(*slot) && *w >= r[2] && *w < next)
        {
            Some(&(_, w)) => {
                s.values[7].push(us(r[2], w));
                s.total_serial.push(us(t[0], w));
            }
            None => s.no_command += 1,
        }
    }
    s
}

/// Percentile (nearest rank) of unsorted values.
pub fn pct(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut v = v.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    let i = ((p / 100.0) * (v.len() as f64 - 1.0)).round() as usize;
    v[i.min(v.len() - 1)]
}

/// CPU share of one core and peak RSS of a side within `[t0, t1]`.
pub fn usage(side: &Side, t0: u64, t1: u64) -> (f64, u64) {
    let s = side.samples.lock().unwrap();
    let w: Vec<&(u64, f64, u64)> = s.iter().filter(|x| x.0 >= t0 && x.0 <= t1).collect();
    let cpu = match (w.first(), w.last()) {
        (Some(a), Some(b)) if b.0 > a.0 => (b.1 - a.1) / ((b.0 - a.0) as f64 / 1e6),
        _ => f64::NAN,
    };
    (cpu, w.iter().map(|x| x.2).max().unwrap_or(0))
}

/// Presses of the sender whose last frame was captured in `[t0, t1 - 3 s)`
/// (well before the end) and that have no final decision on the receiver.
/// Returns (such presses, presses finished).
pub fn lost_finals(from: &Traces, to: &Side, t0: u64, t1: u64) -> (Vec<u32>, usize) {
    let mut last_frame: BTreeMap<u32, u64> = BTreeMap::new();
    for (press, t) in from.tx.values() {
        last_frame.insert(*press, t[0]);
    }
    let finals: BTreeSet<u32> = to
        .events
        .lock()
        .unwrap()
        .iter()
        .filter_map(|(_, e)| match e {
            Event::Decision {
                final_decision: true,
                press: Some(p),
                ..
            } => Some(*p),
            _ => None,
        })
        .collect();
    let done: Vec<u32> = last_frame
        .iter()
        .filter(|(_, &t)| t >= t0 && t + 3_000_000 < t1)
        .map(|(p, _)| *p)
        .collect();
    let n = done.len();
    (
        done.into_iter().filter(|p| !finals.contains(p)).collect(),
        n,
    )
}

/// Error events of a side with their times.
pub fn errors(side: &Side) -> Vec<(u64, String)> {
    side.events
        .lock()
        .unwrap()
        .iter()
        .filter_map(|(t, e)| match e {
            Event::Error { source, message } => Some((*t, format!("{source}: {message}"))),
            _ => None,
        })
        .collect()
}
