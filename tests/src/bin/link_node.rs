//! Test-support node for the namespace tests: runs one `telextiles-link`
//! endpoint (or a UDP relay) and speaks a line protocol.
//!
//! ```text
//! link_node node --dir DIR --name NAME --listen ADDR [--connect KEY@ADDR]...
//!           [--mdns IFACE]... [--show-code | --code CODE] [--encoder HASH]
//!           [--idle-ms N]
//!           [--relay URL [--relay-cert FILE]]
//! link_node relay LISTEN TARGET DELAY_MS JITTER_MS
//! link_node iroh-relay LISTEN DIR (--open | KEY...)
//! ```
//!
//! stdout, one event per line: `id ID`, `listening ADDR`, `code CODE`,
//! `discovered ID`, `paired ID VERIFICATION`, `up ID NAME ADDR`,
//! `down ID REASON`, `error KIND MESSAGE`, `latent PRESS SEQ ONE_WAY_US`,
//! `decision PRESS CLASS LATENTS_RECEIVED`, `path ID KIND ROUTE RTTus`;
//! the iroh relay says `relay URL CERT_FILE`.
//! stdin: `press ID CLASS FRAMES` (stream a press of a known class),
//! `quit`.
//!
//! Known vectors: 16 class centroids (512-d, seeded), pairwise cosine ~0.5;
//! a press streams noisy versions of its class centroid and ends with
//! `PressStop` carrying the final latent; the receiver decides the nearest
//! centroid of that final latent.
use std::collections::HashMap;
use std::io::{BufRead, Write};
use std::net::SocketAddr;
use std::time::Duration;

use rand::{Rng, SeedableRng};
use telextiles_certs::{CodeOffer, Identity, PinSet, TrustStore, DEFAULT_CODE_TTL};
use telextiles_link::{
    now_us, DiscoveryConfig, HelloInfo, Interfaces, Link, LinkConfig, LinkEvent, PairingMode,
};
use telextiles_proto::peer::Control;
use telextiles_tests::relay::{Impairment, Relay};

const DIM: usize = 512;
const CLASSES: usize = 16;

fn unit(v: Vec<f32>) -> Vec<f32> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.into_iter().map(|x| x / n).collect()
}

fn gauss(r: &mut rand_chacha::ChaCha8Rng) -> f32 {
    let u1: f32 = r.gen_range(1e-7f32..1.0);
    let u2: f32 = r.gen_range(0.0f32..1.0);
    (-2.0 * u1.ln()).sqrt() * (2.0 * std::f32::consts::PI * u2).cos()
}

fn centroids() -> Vec<Vec<f32>> {
    let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(42);
    let shared = unit((0..DIM).map(|_| gauss(&mut r)).collect());
    (0..CLASSES)
        .map(|_| {
            let own = unit((0..DIM).map(|_| gauss(&mut r)).collect());
            unit(
                shared
                    .iter()
                    .zip(&own)
                    .map(|(s, o)| 0.7 * s + 0.7 * o)
                    .collect(),
            )
        })
        .collect()
}

fn noisy(c: &[f32], noise: f32, r: &mut rand_chacha::ChaCha8Rng) -> Vec<f32> {
    let n = unit((0..DIM).map(|_| gauss(r)).collect());
    unit(c.iter().zip(&n).map(|(a, b)| a + noise * b).collect())
}

fn nearest(cents: &[Vec<f32>], q: &[f32]) -> usize {
    let mut best = (0, f32::MIN);
    for (i, c) in cents.iter().enumerate() {
        let s: f32 = c.iter().zip(q).map(|(a, b)| a * b).sum();
        if s > best.1 {
            best = (i, s);
        }
    }
    best.0
}

fn say(line: &str) {
    let mut out = std::io::stdout().lock();
    let _ = writeln!(out, "{}", line.replace('\n', " "));
    let _ = out.flush();
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("tokio runtime");
    let res = match args.first().map(String::as_str) {
        Some("node") => rt.block_on(node(&args[1..])),
        Some("relay") => rt.block_on(relay(&args[1..])),
        Some("iroh-relay") => rt.block_on(iroh_relay(&args[1..])),
        _ => Err("usage: link_node node ... | link_node relay ...".into()),
    };
    if let Err(e) = res {
        say(&format!("fatal {e}"));
        std::process::exit(2);
    }
}

async fn relay(args: &[String]) -> Result<(), String> {
    let [listen, target, delay, jitter] = args else {
        return Err("relay LISTEN TARGET DELAY_MS JITTER_MS".into());
    };
    let p = |s: &String| s.parse::<u64>().map_err(|e| e.to_string());
    let imp = Impairment::delay(p(delay)?, p(jitter)?);
    let r = Relay::start(
        listen.parse().map_err(|e| format!("{e}"))?,
        target.parse().map_err(|e| format!("{e}"))?,
        imp,
    )
    .await
    .map_err(|e| e.to_string())?;
    say(&format!("relay {}", r.local_addr()));
    loop {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let c = r.counts();
        say(&format!(
            "relaystats {} {} {} {}",
            c.received, c.forwarded, c.dropped, c.reordered
        ));
    }
}

/// The relay users run (`telextilesd relay`'s library), self-signed.
async fn iroh_relay(args: &[String]) -> Result<(), String> {
    let [listen, dir, rest @ ..] = args else {
        return Err("iroh-relay LISTEN DIR (--open | KEY...)".into());
    };
    let access = if rest == ["--open"] {
        telextiles_relay::AccessList::Open
    } else {
        telextiles_relay::AccessList::Keys(
            rest.iter()
                .map(|k| k.parse().map_err(|e| format!("{k}: {e}")))
                .collect::<Result<_, String>>()?,
        )
    };
    let r = telextiles_relay::RunningRelay::start(&telextiles_relay::RelayOptions {
        listen: listen.parse().map_err(|e| format!("{listen}: {e}"))?,
        names: Vec::new(),
        cert: telextiles_relay::CertSource::SelfSigned { dir: dir.into() },
        access,
    })
    .await
    .map_err(|e| e.to_string())?;
    say(&format!(
        "relay {} {}",
        r.url(),
        r.cert_file()
            .map(|p| p.display().to_string())
            .unwrap_or_default()
    ));
    std::future::pending::<()>().await;
    Ok(())
}

async fn node(args: &[String]) -> Result<(), String> {
    let mut dir = None;
    let mut name = "node".to_string();
    let mut listen: SocketAddr = "0.0.0.0:0".parse().unwrap();
    let mut connect = Vec::new();
    let mut mdns = Vec::new();
    let mut show = false;
    let mut code = None;
    let mut encoder = "e".repeat(64);
    let mut idle_ms = 2000u64;
    let mut relay = None;
    let mut relay_cert = None;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut val = || it.next().cloned().ok_or(format!("{a} needs a value"));
        match a.as_str() {
            "--dir" => dir = Some(std::path::PathBuf::from(val()?)),
            "--name" => name = val()?,
            "--listen" => listen = val()?.parse().map_err(|e| format!("--listen: {e}"))?,
            "--connect" => connect.push(val()?.parse().map_err(|e| format!("--connect: {e}"))?),
            "--mdns" => mdns.push(val()?),
            "--show-code" => show = true,
            "--code" => code = Some(val()?),
            "--encoder" => encoder = val()?,
            "--relay" => relay = Some(val()?),
            "--relay-cert" => relay_cert = Some(std::path::PathBuf::from(val()?)),
            "--idle-ms" => idle_ms = val()?.parse().map_err(|e| format!("--idle-ms: {e}"))?,
            other => return Err(format!("unknown argument {other}")),
        }
    }
    let dir = dir.ok_or("--dir is required")?;
    let (identity, _) = Identity::load_or_create(&dir).map_err(|e| e.to_string())?;
    let store = TrustStore::load(&dir).map_err(|e| e.to_string())?;
    let pins = PinSet::from_store(&store);
    say(&format!("id {}", identity.device_id()));

    let mut cfg = LinkConfig::new(
        name,
        listen,
        HelloInfo {
            encoder_hash: encoder,
            index_fingerprint: "i".repeat(64),
            embedding_dim: DIM as u16,
        },
    );
    cfg.connect = connect;
    if let Some(url) = relay {
        let cert = relay_cert
            .map(|p| telextiles_relay::read_pinned_cert(&p))
            .transpose()
            .map_err(|e| e.to_string())?;
        cfg.relays = vec![telextiles_link::RelaySpec::new(&url, cert)?];
    }
    cfg.data_dir = Some(dir);
    cfg.timing.idle_timeout = Duration::from_millis(idle_ms);
    cfg.timing.keep_alive = Duration::from_millis(idle_ms / 4);
    if !mdns.is_empty() {
        cfg.discovery = Some(DiscoveryConfig {
            interfaces: Interfaces::Only(mdns),
            instance_name: None,
        });
    }
    if show {
        let offer = CodeOffer::new(
            &mut rand::rngs::OsRng,
            std::time::Instant::now(),
            DEFAULT_CODE_TTL,
        );
        say(&format!("code {}", offer.display()));
        cfg.pairing = Some(PairingMode::Show(offer));
    } else if let Some(c) = code {
        cfg.pairing = Some(PairingMode::Enter(c.parse().map_err(|e| format!("{e}"))?));
    }
    let (link, mut events) = Link::start(cfg, identity, pins)
        .await
        .map_err(|e| e.to_string())?;

    // stdin commands on a thread.
    let (cmd_tx, mut cmd_rx) = tokio::sync::mpsc::unbounded_channel::<String>();
    std::thread::spawn(move || {
        for line in std::io::stdin().lock().lines() {
            let Ok(line) = line else { break };
            if cmd_tx.send(line).is_err() {
                break;
            }
        }
    });

    let cents = centroids();
    let mut received: HashMap<u32, u32> = HashMap::new();
    loop {
        tokio::select! {
            ev = events.recv() => {
                let Some(ev) = ev else { return Ok(()) };
                match ev {
                    LinkEvent::Listening { addr } => say(&format!("listening {addr}")),
                    LinkEvent::Discovered { peer, .. } => say(&format!("discovered {peer}")),
                    LinkEvent::Paired { peer, verification } => {
                        say(&format!("paired {peer} {}", verification.value()))
                    }
                    LinkEvent::PeerUp { peer, name, addr } => say(&format!("up {peer} {name} {addr}")),
                    LinkEvent::PeerDown { peer, reason } => say(&format!("down {peer} {reason}")),
                    LinkEvent::Relay { url, connected: true, .. } => say(&format!("relay-online {url}")),
                    LinkEvent::Relay { url, error, .. } => {
                        say(&format!("relay-down {url} {}", error.unwrap_or_default()))
                    }
                    LinkEvent::PathChanged { peer, route, rtt } => {
                        say(&format!("path {peer} {} {route} {}us", route.kind(), rtt.as_micros()))
                    }
                    LinkEvent::Error { kind, message, .. } => {
                        let k = format!("{kind:?}");
                        let k = k.split('(').next().unwrap_or("").to_string();
                        say(&format!("error {k} {message}"))
                    }
                    LinkEvent::Latent(l) => {
                        *received.entry(l.press_id).or_default() += 1;
                        say(&format!(
                            "latent {} {} {}",
                            l.press_id,
                            l.seq,
                            l.one_way_latency_us.map_or("-".into(), |v| v.to_string())
                        ));
                    }
                    LinkEvent::Control { msg: Control::PressStop { press_id, final_latent, .. }, .. } => {
                        let class = final_latent
                            .map(|f| nearest(&cents, &f.vector.dequantize()).to_string())
                            .unwrap_or_else(|| "-".into());
                        say(&format!(
                            "decision {press_id} {class} {}",
                            received.get(&press_id).copied().unwrap_or(0)
                        ));
                    }
                    LinkEvent::Control { .. } => {}
                }
            }
            cmd = cmd_rx.recv() => {
                let Some(cmd) = cmd else { return Ok(()) };
                let parts: Vec<&str> = cmd.split_whitespace().collect();
                match parts.as_slice() {
                    ["quit"] => {
                        link.shutdown().await;
                        return Ok(());
                    }
                    ["press", id, class, frames] => {
                        let (Ok(id), Ok(class), Ok(frames)) =
                            (id.parse::<u32>(), class.parse::<usize>(), frames.parse::<u32>())
                        else {
                            say("error Usage press ID CLASS FRAMES");
                            continue;
                        };
                        let c = &cents[class % CLASSES];
                        let mut r = rand_chacha::ChaCha8Rng::seed_from_u64(id as u64);
                        let _ = link.send_control(Control::PressStart { press_id: id, capture_us: now_us() });
                        let mut last = c.clone();
                        for f in 0..frames {
                            last = noisy(c, 0.3, &mut r);
                            let _ = link.send_latent(id, &last, now_us(), f + 1 == frames);
                            tokio::time::sleep(Duration::from_micros(16_667)).await;
                        }
                        match link.send_press_stop(id, Some(&last), now_us()) {
                            Ok(_) => say(&format!("sent {id}")),
                            Err(e) => say(&format!("error Send {e}")),
                        }
                    }
                    _ => say(&format!("error Usage unknown command {cmd}")),
                }
            }
        }
    }
}
