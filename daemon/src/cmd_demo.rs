//! `telextilesd demo`: a two-party session on one machine with no hardware.
//!
//! Two daemons with their own identities and state directories find each
//! other, pair with a code passed from one to the other, and a script of
//! simulated presses on side A (seen and unseen textiles, with and without
//! the jig) turns side B's simulated roller. A live view shows contact,
//! decided textile, roller slot and latency; a summary ends the run.
//!
//! Isolation: as root, each daemon runs in its own network namespace joined
//! by a veth pair, and mDNS is allowed on that veth only; otherwise both run
//! on loopback with `--connect` and mDNS off. Nothing is ever sent on the
//! machine's real interfaces.

use anyhow::{anyhow, bail, Context, Result};
use clap::Args as ClapArgs;
use serde_json::{json, Value};
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command as Proc, Stdio};
use std::time::{Duration, Instant};
use telextiles_control::{
    client::EventLine, Client, Command, ContactPhase, Event, SimPressArgs, SubscribeArgs,
};
use telextiles_sim::catalogue::{Book, Catalogue};

/// `telextilesd demo`
#[derive(ClapArgs, Debug)]
pub struct Args {
    /// Seen textiles pressed with the jig.
    #[arg(long, default_value_t = 8)]
    pub seen: usize,
    /// Seen textiles pressed hand-held (no jig).
    #[arg(long, default_value_t = 3)]
    pub handheld: usize,
    /// Unseen textiles (not in the index) pressed with the jig.
    #[arg(long, default_value_t = 2)]
    pub unseen: usize,
    /// Seed choosing the script's textiles.
    #[arg(long, default_value_t = 7)]
    pub seed: u64,
    /// Use loopback with --connect even when network namespaces are possible.
    #[arg(long)]
    pub loopback: bool,
    /// Give up on a press after this many seconds.
    #[arg(long, default_value_t = 10.0)]
    pub press_timeout_s: f64,
    /// Print the summary as one JSON object on the last line.
    #[arg(long)]
    pub json: bool,
    /// Keep the work directory (logs, identities) afterwards.
    #[arg(long)]
    pub keep: bool,
    /// Encoder both daemons run (the shipped one, from the repository root).
    #[arg(long, default_value = "models/encoder.onnx")]
    pub model: PathBuf,
    /// Textile index both daemons hold.
    #[arg(long, default_value = "models/index.tlxi")]
    pub index: PathBuf,
    /// When B's wheel moves during a press (the daemons' `motion`
    /// setting) [default: the daemon's]
    #[arg(long, value_name = "POLICY")]
    pub motion: Option<telextiles_session::MotionPolicy>,
}

struct Netns {
    a: String,
    b: String,
}

fn ip(args: &[&str]) -> Result<()> {
    let out = Proc::new("ip")
        .args(args)
        .output()
        .with_context(|| "cannot run `ip` (iproute2)")?;
    if !out.status.success() {
        bail!(
            "ip {}: {}",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(())
}

/// Waits (at most 5 s) until `dev` in namespace `ns` is up with a carrier.
fn wait_for_carrier(ns: &str, dev: &str) -> Result<()> {
    let deadline = Instant::now() + Duration::from_secs(5);
    loop {
        let out = Proc::new("ip")
            .args(["-n", ns, "-o", "link", "show", "dev", dev])
            .output()
            .with_context(|| "cannot run `ip` (iproute2)")?;
        let text = String::from_utf8_lossy(&out.stdout);
        if text.contains("state UP") && !text.contains("NO-CARRIER") {
            return Ok(());
        }
        if Instant::now() > deadline {
            bail!("{dev} in {ns} has no carrier after 5 s: {}", text.trim());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

impl Netns {
    /// Two namespaces joined by a veth pair: 10.213.0.1 (A) and 10.213.0.2 (B).
    fn create() -> Result<Netns> {
        let tag = std::process::id() % 100_000;
        let ns = Netns {
            a: format!("tlxdemo{tag}a"),
            b: format!("tlxdemo{tag}b"),
        };
        let (va, vb) = (format!("tlxd{tag}a"), format!("tlxd{tag}b"));
        let setup = || -> Result<()> {
            ip(&["netns", "add", &ns.a])?;
            ip(&["netns", "add", &ns.b])?;
            ip(&["link", "add", &va, "type", "veth", "peer", "name", &vb])?;
            ip(&["link", "set", &va, "netns", &ns.a])?;
            ip(&["link", "set", &vb, "netns", &ns.b])?;
            for (n, v, addr) in [(&ns.a, &va, "10.213.0.1/24"), (&ns.b, &vb, "10.213.0.2/24")] {
                ip(&["-n", n, "addr", "add", addr, "dev", v])?;
                ip(&["-n", n, "link", "set", v, "up"])?;
                ip(&["-n", n, "link", "set", "lo", "up"])?;
            }
            // The veth carrier comes up asynchronously; a daemon started
            // before it loses its first mDNS packets and discovery then
            // waits for the next retry.
            for (n, v) in [(&ns.a, &va), (&ns.b, &vb)] {
                wait_for_carrier(n, v)?;
            }
            Ok(())
        };
        if let Err(e) = setup() {
            ns.remove();
            return Err(e);
        }
        Ok(ns)
    }

    fn veth(&self, side: char) -> String {
        format!("tlxd{}{side}", std::process::id() % 100_000)
    }

    fn remove(&self) {
        let _ = ip(&["netns", "del", &self.a]);
        let _ = ip(&["netns", "del", &self.b]);
    }
}

impl Drop for Netns {
    fn drop(&mut self) {
        self.remove();
    }
}

fn is_root() -> bool {
    telextiles_control::socket::current_uid()
        .map(|u| u == 0)
        .unwrap_or(false)
}

struct Daemon {
    name: &'static str,
    child: Child,
    socket: PathBuf,
    log: PathBuf,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = self.child.kill();
        }
        let _ = self.child.wait();
    }
}

#[allow(clippy::too_many_arguments)]
fn spawn_daemon(
    name: &'static str,
    work: &Path,
    netns: Option<&str>,
    listen: &str,
    connect: Option<&str>,
    mdns_iface: Option<&str>,
    pair_arg: &[&str],
    models: (&Path, &Path),
    motion: Option<telextiles_session::MotionPolicy>,
) -> Result<Daemon> {
    let exe = std::env::current_exe()?;
    let dir = work.join(name);
    std::fs::create_dir_all(&dir)?;
    let socket = dir.join("control.sock");
    let log = dir.join("daemon.log");
    let mut cmd = match netns {
        Some(ns) => {
            let mut c = Proc::new("ip");
            c.args(["netns", "exec", ns]).arg(&exe);
            c
        }
        None => Proc::new(&exe),
    };
    cmd.arg("pair")
        .args(pair_arg)
        .args(["--name", &format!("demo-{name}")])
        .arg("--state-dir")
        .arg(dir.join("state"))
        .arg("--data-dir")
        .arg(dir.join("data"))
        .arg("--runtime-dir")
        .arg(&dir)
        .arg("--socket")
        .arg(&socket)
        .args(["--sensor", "sim", "--roller", "sim", "--map=false"])
        .args(["--listen", listen])
        .arg("--model")
        .arg(models.0)
        .arg("--index")
        .arg(models.1)
        .arg("--config")
        .arg(dir.join("none.toml"))
        // The wheel in real time, so that the felt latency is a real
        // wheel's (the paper's: one slot in 91 ms, half a turn in 267).
        .env("TELEXTILESD_SIM_ROLLER_SPEED", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(&log)?);
    if let Some(m) = motion {
        cmd.arg("--motion").arg(m.to_string());
    }
    match mdns_iface {
        Some(i) => {
            cmd.args(["--mdns=true", "--mdns-allow", i]);
        }
        None => {
            cmd.args(["--mdns=false"]);
        }
    }
    if let Some(c) = connect {
        cmd.args(["--connect", c]);
    }
    std::fs::write(dir.join("none.toml"), "")?;
    let child = cmd.spawn().context("cannot start a daemon")?;
    Ok(Daemon {
        name,
        child,
        socket,
        log,
    })
}

/// Read a daemon's stdout until a line containing each of `markers` has
/// been seen; returns those lines, in the order of `markers`.
fn wait_lines(d: &mut Daemon, markers: &[&str], timeout: Duration) -> Result<Vec<String>> {
    let out = d.child.stdout.take().ok_or_else(|| anyhow!("no stdout"))?;
    let (tx, rx) = std::sync::mpsc::channel();
    let want: Vec<String> = markers.iter().map(|m| m.to_string()).collect();
    std::thread::spawn(move || {
        let mut found: Vec<Option<String>> = vec![None; want.len()];
        let mut sent = false;
        for line in BufReader::new(out).lines().map_while(Result::ok) {
            for (i, m) in want.iter().enumerate() {
                if found[i].is_none() && line.contains(m.as_str()) {
                    found[i] = Some(line.clone());
                }
            }
            if !sent && found.iter().all(Option::is_some) {
                sent = true;
                let _ = tx.send(found.iter().flatten().cloned().collect::<Vec<_>>());
            }
        }
    });
    rx.recv_timeout(timeout).map_err(|_| {
        anyhow!(
            "daemon {} did not print {:?} within {:?}; see {}",
            d.name,
            markers,
            timeout,
            d.log.display()
        )
    })
}

async fn connect_ctl(d: &Daemon, timeout: Duration) -> Result<Client> {
    let start = Instant::now();
    loop {
        match Client::connect(&d.socket).await {
            Ok(c) => return Ok(c),
            Err(e) if start.elapsed() > timeout => {
                bail!(
                    "daemon {}'s control socket {} did not come up: {e}; see {}",
                    d.name,
                    d.socket.display(),
                    d.log.display()
                )
            }
            Err(_) => tokio::time::sleep(Duration::from_millis(100)).await,
        }
    }
}

#[derive(Clone, Debug)]
struct Step {
    textile: String,
    jig: bool,
    seen: bool,
}

fn script(a: &Args) -> Vec<Step> {
    let cat = Catalogue::builtin();
    let seen: Vec<&str> = cat.training().map(|t| t.id.as_str()).collect();
    let unseen: Vec<&str> = cat
        .textiles
        .iter()
        .filter(|t| t.book == Book::Unseen)
        .map(|t| t.id.as_str())
        .collect();
    let pick = |list: &[&str], k: usize, salt: u64| -> String {
        let h =
            telextiles_sim::catalogue::mix64(a.seed ^ salt.wrapping_mul(0x9e37_79b9) ^ k as u64);
        list[(h % list.len() as u64) as usize].to_string()
    };
    let mut steps = Vec::new();
    for k in 0..a.seen {
        steps.push(Step {
            textile: pick(&seen, k, 1),
            jig: true,
            seen: true,
        });
    }
    for k in 0..a.handheld {
        steps.push(Step {
            textile: pick(&seen, k, 2),
            jig: false,
            seen: true,
        });
    }
    for k in 0..a.unseen {
        steps.push(Step {
            textile: pick(&unseen, k, 3),
            jig: true,
            seen: false,
        });
    }
    steps
}

fn percentile(v: &mut [f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    let k = ((p / 100.0) * (v.len() - 1) as f64).round() as usize;
    v[k]
}

pub fn run(a: Args) -> Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?;
    rt.block_on(demo(a))
}

async fn demo(a: Args) -> Result<()> {
    let started = Instant::now();
    let work = std::env::temp_dir().join(format!("telextiles-demo-{}", std::process::id()));
    std::fs::create_dir_all(&work)?;
    let result = demo_in(&a, &work, started).await;
    if a.keep || result.is_err() {
        eprintln!("work directory kept: {}", work.display());
    } else {
        let _ = std::fs::remove_dir_all(&work);
    }
    result
}

async fn demo_in(a: &Args, work: &Path, started: Instant) -> Result<()> {
    let model = std::path::absolute(&a.model)?;
    let index = std::path::absolute(&a.index)?;
    for (p, what, flag) in [(&model, "encoder", "--model"), (&index, "index", "--index")] {
        if !p.is_file() {
            bail!(
                "the demo's {what} {} is not there: run the demo from the repository root (models/ is shipped there), or pass {flag}",
                p.display()
            );
        }
    }
    let models = (model.as_path(), index.as_path());
    let netns = if !a.loopback && is_root() {
        match Netns::create() {
            Ok(n) => Some(n),
            Err(e) => {
                eprintln!("network namespaces unavailable ({e}); using loopback");
                None
            }
        }
    } else {
        None
    };
    let mode = if netns.is_some() {
        "two network namespaces joined by a veth pair, mDNS on the veth only"
    } else {
        "loopback with --connect, mDNS off"
    };
    println!("Telextiles demo: two daemons on {mode}");

    // A shows the code, B types it.
    let (listen_a, listen_b, connect_b) = match &netns {
        Some(_) => (
            "10.213.0.1:47800".to_string(),
            "10.213.0.2:47800".to_string(),
            None,
        ),
        None => {
            let pa = free_udp_port()?;
            let pb = free_udp_port()?;
            (
                format!("127.0.0.1:{pa}"),
                format!("127.0.0.1:{pb}"),
                Some(format!("127.0.0.1:{pa}")),
            )
        }
    };
    let veth_a = netns.as_ref().map(|n| n.veth('a'));
    let veth_b = netns.as_ref().map(|n| n.veth('b'));
    let mut da = spawn_daemon(
        "a",
        work,
        netns.as_ref().map(|n| n.a.as_str()),
        &listen_a,
        None,
        veth_a.as_deref(),
        &["--show"],
        models,
        a.motion,
    )?;
    let lines = wait_lines(
        &mut da,
        &["This device's key:", "Pairing code:"],
        Duration::from_secs(30),
    )?;
    let key_a = lines[0]
        .rsplit(' ')
        .next()
        .unwrap_or_default()
        .trim()
        .to_string();
    let line = &lines[1];
    let code = pairing_code_in(line).ok_or_else(|| anyhow!("no code in {line:?}"))?;
    // On loopback B dials A by its key at A's address (no mDNS there).
    let connect_b = connect_b.map(|addr| format!("{key_a}@{addr}"));
    println!("A shows pairing code {code}; typing it on B");
    let mut db = spawn_daemon(
        "b",
        work,
        netns.as_ref().map(|n| n.b.as_str()),
        &listen_b,
        connect_b.as_deref(),
        veth_b.as_deref(),
        &["--code", &code],
        models,
        a.motion,
    )?;
    let b_paired = wait_lines(&mut db, &["Paired with"], Duration::from_secs(30))?;
    println!("B: {}", b_paired[0].trim());

    let mut ctl_a = connect_ctl(&da, Duration::from_secs(30)).await?;
    let mut ev_a = connect_ctl(&da, Duration::from_secs(30)).await?;
    let mut ev_b = connect_ctl(&db, Duration::from_secs(30)).await?;
    let mut ctl_b = connect_ctl(&db, Duration::from_secs(30)).await?;
    ev_a.subscribe(SubscribeArgs::default()).await??;
    ev_b.subscribe(SubscribeArgs::default()).await??;

    // Wait until A sees B as a connected peer.
    let t0 = Instant::now();
    loop {
        let st = ctl_a.call(&Command::Status).await??;
        if st["peers"].as_array().is_some_and(|p| !p.is_empty()) {
            break;
        }
        if t0.elapsed() > Duration::from_secs(20) {
            bail!(
                "the daemons paired but did not connect; see {} and {}",
                da.log.display(),
                db.log.display()
            );
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    println!(
        "session up after {:.1} s\n",
        started.elapsed().as_secs_f64()
    );
    println!(
        "{:<4} {:<7} {:<5} {:<8} {:<28} {:>5} {:>9} {:>9}  roller",
        "#", "pressed", "jig", "book", "B decided", "slot", "latency", "decision"
    );

    let steps = script(a);
    let mut rows = Vec::new();
    let mut latencies = Vec::new();
    let mut decision_ms = Vec::new();
    let mut felt_ms = Vec::new();
    for (i, step) in steps.iter().enumerate() {
        ctl_a
            .call(&Command::SensorSim(SimPressArgs {
                textile: step.textile.clone(),
                jig: Some(step.jig),
                person: Some((i % 11) as u32),
                sensor: None,
                seed: Some(a.seed.wrapping_add(i as u64 * 7919)),
                rotation_deg: None,
                force: None,
            }))
            .await??;
        let deadline = Instant::now() + Duration::from_secs_f64(a.press_timeout_s);
        // Wait for A's next contact, then B's final decision and roller arrival.
        let mut contact = false;
        let mut first: Option<(f64, f64)> = None;
        let mut first_textile: Option<String> = None;
        let mut last: Option<Value> = None;
        let mut arrived: Option<u32> = None;
        let mut arrived_at: Option<Instant> = None;
        let mut final_seen = false;
        // B's press number, and what the receiving hand felt of it.
        let mut b_press: Option<u32> = None;
        let mut felt: Option<f64> = None;
        // Done at the final decision with the wheel there: B says what was
        // felt right after (or never, before its link has a clock offset).
        let done = |final_seen: bool, felt: Option<f64>, arrived_at: Option<Instant>| {
            final_seen
                && (felt.is_some()
                    || arrived_at.is_some_and(|t| t.elapsed() > Duration::from_millis(300)))
        };
        while Instant::now() < deadline && !done(final_seen, felt, arrived_at) {
            let remaining = deadline.saturating_duration_since(Instant::now());
            tokio::select! {
                e = ev_a.next_event() => {
                    if let Some(EventLine::Known(Event::Contact { phase: ContactPhase::Start, .. })) = e? {
                        contact = true;
                    }
                }
                e = ev_b.next_event() => {
                    match e? {
                        Some(EventLine::Known(Event::Decision { textile, name, slot, latency_ms, since_contact_ms, final_decision, distance, press, .. })) if contact => {
                            b_press = press.or(b_press);
                            if first.is_none() {
                                first = Some((latency_ms, since_contact_ms.unwrap_or(f64::NAN)));
                                first_textile = Some(textile.clone());
                            }
                            latencies.push(latency_ms);
                            if arrived.is_some_and(|a| a != slot) {
                                // A new slot: wait for the roller to get there.
                                arrived = None;
                                arrived_at = None;
                            }
                            last = Some(json!({"textile": textile, "name": name, "slot": slot, "distance": distance}));
                            if final_decision { final_seen = true; }
                        }
                        Some(EventLine::Known(Event::RollerArrived { slot, .. }))
                            if last.as_ref().is_some_and(|l| l["slot"] == slot) =>
                        {
                            arrived = Some(slot);
                            arrived_at.get_or_insert_with(Instant::now);
                        }
                        Some(EventLine::Known(Event::Felt { press, felt_ms: f, slot, .. }))
                            if contact && b_press == Some(press) =>
                        {
                            // At rest at the final sample (perhaps since
                            // before the press: then no new arrival).
                            felt = Some(f);
                            arrived = Some(slot);
                        }
                        None => bail!("daemon B closed its control socket; see {}", db.log.display()),
                        _ => {}
                    }
                }
                _ = tokio::time::sleep(remaining.min(Duration::from_millis(250))) => {
                    // The roller may already stand at the final slot (no new
                    // move, so no new arrival event): ask B where it is.
                    if final_seen && arrived.is_none() {
                        let st = ctl_b.call(&Command::Status).await??;
                        let pos = &st["roller"]["state"]["position"];
                        let want = last.as_ref().map(|l| l["slot"].clone());
                        if pos["moving"] == false && Some(pos["slot"].clone()) == want {
                            arrived = pos["slot"].as_u64().map(|v| v as u32);
                            arrived_at.get_or_insert_with(Instant::now);
                        }
                    }
                }
            }
        }
        let decided = last
            .as_ref()
            .and_then(|l| l["textile"].as_str())
            .unwrap_or("-")
            .to_string();
        let right = step.seen && decided == step.textile;
        if let Some((_, d)) = first {
            decision_ms.push(d);
        }
        felt_ms.extend(felt);
        println!(
            "{:<4} {:<7} {:<5} {:<8} {:<28} {:>5} {:>7.1}ms {:>7.0}ms  {}",
            i + 1,
            step.textile,
            if step.jig { "jig" } else { "hand" },
            if step.seen { "seen" } else { "unseen" },
            format!(
                "{} {}{}",
                decided,
                if !step.seen {
                    "(nearest known)"
                } else if right {
                    "ok"
                } else {
                    "WRONG"
                },
                if final_seen { "" } else { " (no final)" }
            ) + &match &first_textile {
                Some(f) if *f != decided => format!(", first {f}"),
                _ => String::new(),
            },
            last.as_ref()
                .map(|l| l["slot"].to_string())
                .unwrap_or_else(|| "-".into()),
            first.map(|f| f.0).unwrap_or(f64::NAN),
            first.map(|f| f.1).unwrap_or(f64::NAN),
            match (arrived, felt) {
                (Some(s), Some(f)) => format!("at rest at slot {s}, felt {f:.0} ms after contact"),
                (Some(s), None) => format!("arrived at slot {s}"),
                (None, _) => "not arrived".into(),
            },
        );
        rows.push(json!({
            "pressed": step.textile, "jig": step.jig, "seen": step.seen,
            "decided": decided, "right": right, "final": final_seen,
            "slot": last.as_ref().map(|l| l["slot"].clone()),
            "roller_arrived": arrived.is_some(),
            "first_decision_latency_ms": first.map(|f| f.0),
            "contact_to_decision_ms": first.map(|f| f.1),
            "felt_ms": felt,
            "first_decided": first_textile,
        }));
    }

    let _ = ctl_a.call(&Command::Shutdown).await;
    let _ = ctl_b.call(&Command::Shutdown).await;
    for d in [&mut da, &mut db] {
        let t = Instant::now();
        while matches!(d.child.try_wait(), Ok(None)) && t.elapsed() < Duration::from_secs(5) {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    }
    drop(netns);

    let seen_rows: Vec<&Value> = rows.iter().filter(|r| r["seen"] == true).collect();
    let right = seen_rows.iter().filter(|r| r["right"] == true).count();
    let jig_right = seen_rows
        .iter()
        .filter(|r| r["right"] == true && r["jig"] == true)
        .count();
    let jig_n = seen_rows.iter().filter(|r| r["jig"] == true).count();
    let finals = rows.iter().filter(|r| r["final"] == true).count();
    let arrived = rows.iter().filter(|r| r["roller_arrived"] == true).count();
    let summary = json!({
        "mode": if mode.starts_with("two") { "netns" } else { "loopback" },
        "presses": rows.len(),
        "final_decisions": finals,
        "roller_arrivals": arrived,
        "seen_presses": seen_rows.len(),
        "seen_right": right,
        "jig_right": jig_right, "jig_presses": jig_n,
        "unseen_presses": rows.len() - seen_rows.len(),
        "latency_ms": {"p50": percentile(&mut latencies, 50.0), "p95": percentile(&mut latencies, 95.0), "p99": percentile(&mut latencies, 99.0), "n": latencies.len()},
        "contact_to_decision_ms": {"p50": percentile(&mut decision_ms, 50.0), "p95": percentile(&mut decision_ms, 95.0)},
        "felt_ms": {"p50": percentile(&mut felt_ms, 50.0), "p90": percentile(&mut felt_ms, 90.0), "n": felt_ms.len()},
        "wall_s": started.elapsed().as_secs_f64(),
        "rows": rows,
    });
    println!(
        "\nsummary: {} presses, {} final decisions, {}/{} seen textiles right ({}/{} with jig), roller arrived {} times",
        summary["presses"], finals, right, seen_rows.len(), jig_right, jig_n, arrived
    );
    println!(
        "decision latency (capture on A -> decision on B): p50 {:.2} ms, p95 {:.2} ms, p99 {:.2} ms; contact -> first decision p50 {:.0} ms; {:.1} s in all",
        summary["latency_ms"]["p50"].as_f64().unwrap_or(f64::NAN),
        summary["latency_ms"]["p95"].as_f64().unwrap_or(f64::NAN),
        summary["latency_ms"]["p99"].as_f64().unwrap_or(f64::NAN),
        summary["contact_to_decision_ms"]["p50"].as_f64().unwrap_or(f64::NAN),
        started.elapsed().as_secs_f64()
    );
    println!(
        "felt latency (contact on A -> B's wheel at rest at the final sample, {} policy): p50 {:.0} ms, p90 {:.0} ms over {} presses",
        a.motion.unwrap_or_default(),
        summary["felt_ms"]["p50"].as_f64().unwrap_or(f64::NAN),
        summary["felt_ms"]["p90"].as_f64().unwrap_or(f64::NAN),
        felt_ms.len()
    );
    if a.json {
        println!("{summary}");
    }
    if finals == 0 {
        bail!(
            "no press reached a final decision on B; see {} and {}",
            da.log.display(),
            db.log.display()
        );
    }
    Ok(())
}

/// The code in A's "Pairing code: 1234-5678   (valid ...)" line.
fn pairing_code_in(line: &str) -> Option<String> {
    let rest = line.split_once("Pairing code:")?.1;
    let code = rest.split_whitespace().next()?;
    code.parse::<telextiles_certs::PairingCode>().ok()?;
    Some(code.to_string())
}

fn free_udp_port() -> Result<u16> {
    let s = std::net::UdpSocket::bind("127.0.0.1:0")?;
    Ok(s.local_addr()?.port())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_code_is_read_from_the_pair_output() {
        let offer = telextiles_certs::CodeOffer::new(
            &mut rand::rngs::OsRng,
            Instant::now(),
            telextiles_certs::DEFAULT_CODE_TTL,
        );
        let code = offer.display();
        let line = format!("Pairing code: {code}   (valid 5 minutes, one try)");
        assert_eq!(pairing_code_in(&line), Some(code));
        // A code whose check digit is wrong is not taken.
        assert_eq!(pairing_code_in("Pairing code: 1234-5678 "), None);
        assert_eq!(pairing_code_in("Pairing code: soon"), None);
        assert_eq!(pairing_code_in("Listening on [::]:47800"), None);
    }

    #[test]
    fn the_script_has_the_asked_mix_and_is_seeded() {
        let a = Args {
            seen: 4,
            handheld: 2,
            unseen: 3,
            seed: 7,
            loopback: true,
            press_timeout_s: 10.0,
            json: false,
            keep: false,
            model: PathBuf::from("m.onnx"),
            index: PathBuf::from("i.tlxi"),
            motion: None,
        };
        let s = script(&a);
        assert_eq!(s.len(), 9);
        assert_eq!(s.iter().filter(|x| x.seen && x.jig).count(), 4);
        assert_eq!(s.iter().filter(|x| x.seen && !x.jig).count(), 2);
        assert_eq!(s.iter().filter(|x| !x.seen).count(), 3);
        assert!(s
            .iter()
            .filter(|x| !x.seen)
            .all(|x| x.textile.starts_with('U')));
        let again: Vec<String> = script(&a).into_iter().map(|x| x.textile).collect();
        assert_eq!(
            again,
            s.iter().map(|x| x.textile.clone()).collect::<Vec<_>>()
        );
    }
}
