//! The live session: sensing -> peer link -> decision -> roller, both ways.
//! This file is wiring only; the logic lives in the sans-IO session core
//! (`telextiles-session`: sender and receiver state machines) and the
//! sensing front end (`telextiles-sensing::front`).
//!
//! One daemon is both a sender (its DIGIT, or the simulator, pressed onto a
//! fabric: contact detection, encoding, latents streamed to the peers) and a
//! receiver (latents from the peers: per-peer decisions against the shared
//! index, roller commands). A control socket lets scripts watch and steer
//! it; the 2D map is served when enabled.
//!
//! Threads and tasks (all supervised: if any of them ends or panics before
//! shutdown, the session ends with an error, so systemd restarts it rather
//! than leaving a deaf daemon):
//! - the sensing thread (`live/sensing.rs`; blocking: camera reads and
//!   ONNX inference) owns the frame source and the front end; its sender
//!   core's messages go straight into the link (a datagram per frame, no
//!   queue);
//! - the receiver task (`live/receive.rs`) feeds link events to the
//!   receiver core and carries out its actions;
//! - the roller driver task (telextiles-roller) owns the serial port; its
//!   events go to the bus (`live/roller.rs`);
//! - the control server (`live/control.rs`) and the map server serve
//!   local clients.

mod control;
pub(crate) mod discovery;
mod map;
pub(crate) mod models;
mod receive;
pub(crate) mod recording;
mod roller;
mod sensing;
pub(crate) use sensing::camera_options;
mod supervise;

use supervise::{supervise, EndGuard};

use anyhow::{anyhow, Context, Result};
use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc as std_mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use telextiles_certs::{Identity, PinSet, TrustStore};
use telextiles_control::{Event, Server, ServerConfig};
use telextiles_index::Index;
use telextiles_link::{HelloInfo, LinkConfig, LinkHandle, PairingMode};
use telextiles_roller::RollerDriver;
use telextiles_sensing::encoder::ModelInfo;
use telextiles_session::{ReceiverConfig, ReceiverCore};
use tokio::sync::{broadcast, watch};

use crate::config::Config;
use sensing::SensorCmd;

/// Extra knobs of a session beyond the configuration.
#[derive(Debug, Default)]
pub struct SessionOptions {
    /// Pair first (the `telextilesd pair` flow).
    pub pairing: Option<PairingMode>,
    /// A shown pairing code expires at this time, or entering a code gives
    /// up at this time: the session ends with an error if pairing has not
    /// succeeded by then.
    pub pairing_deadline: Option<std::time::Instant>,
    /// The pairing code lifetime (for the message at the deadline).
    pub code_ttl: std::time::Duration,
    /// Simulated roller speed factor (1 = a real roller).
    pub sim_roller_speed: Option<f64>,
    /// No-contact frames between simulated presses.
    #[cfg_attr(not(feature = "sim"), allow(dead_code))]
    pub sim_gap_frames: Option<usize>,
    /// Write a per-frame latency trace here (`crate::trace`).
    pub latency_trace: Option<PathBuf>,
}

/// The receiver core, deciding against the shared index.
type Receiver = ReceiverCore<Index>;

#[derive(Default)]
struct Counters {
    frames: AtomicU64,
    presses_sent: AtomicU64,
    latents_sent: AtomicU64,
    presses_received: AtomicU64,
    latents_received: AtomicU64,
    decisions: AtomicU64,
    /// Frames the source or the encoder rejected.
    bad_frames: AtomicU64,
    /// Recordings of a replay (`sensor = replay:<dir>`) skipped because
    /// they could not be read, had no frames, or stopped being readable
    /// part-way (the rest of that one skipped).
    recordings_skipped: AtomicU64,
    /// Messages from peers the receiver core refused (a latent of the
    /// wrong dimension, not finite or zero; a press stop's final latent
    /// likewise): each dropped, nothing else changed.
    refused: AtomicU64,
}

/// A connected peer, as `ctl status` lists it.
#[derive(Clone, Debug, serde::Serialize)]
struct ConnectedPeer {
    /// Its device ID.
    id: String,
    /// The name it gave at hello.
    name: String,
    /// How its connection reaches it now: its address on a direct path,
    /// or `relay <url>`.
    addr: String,
    /// `direct`, `relay` or `unknown`.
    path: String,
    /// Round-trip time of that path, ms (when the link has measured it).
    rtt_ms: Option<f64>,
    /// When the path last changed (the session started or the link moved
    /// between the relay and a direct path), Unix seconds.
    path_since: u64,
}

/// A configured relay, as `ctl status` lists it.
#[derive(Clone, Debug, serde::Serialize)]
struct RelayState {
    url: String,
    /// Whether this device is connected to it (so peers beyond the LAN
    /// can reach it).
    connected: bool,
    /// Why not, when the last attempt failed (e.g. the relay does not
    /// serve this device's key).
    error: Option<String>,
    /// When `connected` last changed (or the daemon started), Unix seconds.
    since: u64,
}

impl Counters {
    /// Count one; the new total.
    fn bump(counter: &AtomicU64) -> u64 {
        counter.fetch_add(1, Ordering::Relaxed) + 1
    }

    /// The current value of one counter.
    fn get(counter: &AtomicU64) -> u64 {
        counter.load(Ordering::Relaxed)
    }
}

/// What the tasks share (the session core's state is not here: the
/// receiver task owns it).
struct State {
    name: String,
    device_id: String,
    index: Arc<Index>,
    model: ModelInfo,
    link: LinkHandle,
    pins: PinSet,
    state_dir: PathBuf,
    roller: Option<RollerDriver>,
    roller_desc: String,
    sensor_desc: String,
    /// The sensor's profile (recordings are saved with it).
    sensor_profile: &'static telextiles_recording::profile::SensorProfile,
    sensor_tx: std_mpsc::Sender<SensorCmd>,
    /// The simulated DIGIT, when the sensor is one.
    sim: Option<sensing::Simulated>,
    events: broadcast::Sender<Event>,
    /// The connected peers, by device ID.
    peers: Mutex<BTreeMap<String, ConnectedPeer>>,
    /// The configured relays, by URL.
    relays: Mutex<BTreeMap<String, RelayState>>,
    counters: Counters,
    in_contact: AtomicBool,
    /// Last roller position: (millidegrees, slot, moving).
    roller_pos: Mutex<Option<(u32, Option<u16>, bool)>>,
    /// Felt latency of received presses: their final decisions against
    /// the roller's arrivals.
    felt: Mutex<telextiles_session::felt::LiveFelt>,
    map_tx: Option<broadcast::Sender<telextiles_map::MapEvent>>,
    /// A pairing was asked for and has not completed yet.
    pairing_pending: Mutex<bool>,
    /// Why the session must end with an error.
    fatal: Mutex<Option<String>>,
    shutdown: watch::Sender<bool>,
    started: Instant,
    trace: Option<crate::trace::Trace>,
}

fn say(line: &str) {
    use std::io::Write;
    println!("{line}");
    let _ = std::io::stdout().flush();
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// A peer's name for people, or its ID when not connected.
fn peer_name(state: &State, id: &str) -> String {
    lock(&state.peers)
        .get(id)
        .map(|p| p.name.clone())
        .unwrap_or_else(|| id.to_string())
}

/// Run a session until shutdown (control `shutdown`, SIGINT or SIGTERM).
pub async fn run(cfg: Config, mut opts: SessionOptions) -> Result<()> {
    let trace = match &opts.latency_trace {
        Some(p) => Some(crate::trace::Trace::create(p)?),
        None => None,
    };
    let (encoder, index) = models::load_model(&cfg, 1)?;
    let index = Arc::new(index);
    let model = encoder.info().clone();

    crate::config::create_private_dir(&cfg.state_dir)
        .with_context(|| format!("cannot create {}", cfg.state_dir.display()))?;
    let (identity, created) = Identity::load_or_create(&cfg.state_dir)?;
    if created {
        eprintln!(
            "created this device's identity in {}",
            cfg.state_dir.display()
        );
    }
    let device_id = identity.device_id();
    let store = TrustStore::load(&cfg.state_dir)?;
    let pins = PinSet::from_store(&store);

    // Peer link.
    let hello = HelloInfo {
        encoder_hash: model.sha256.clone(),
        index_fingerprint: index.fingerprint(),
        embedding_dim: model.dim as u16,
    };
    let mut lc = LinkConfig::new(cfg.name.clone(), cfg.listen, hello);
    for c in &cfg.connect {
        lc.connect.push(crate::config::peer::resolve_peer(c)?);
    }
    if cfg.mdns {
        lc.discovery = Some(discovery::discovery_config(&cfg));
    }
    lc.data_dir = Some(cfg.state_dir.clone());
    lc.relays = crate::config::peer::relays(&cfg)?;
    let lc_relays = lc.relays.clone();
    lc.pairing = opts.pairing.take();
    let pairing = lc.pairing.is_some();
    let entering = matches!(lc.pairing, Some(PairingMode::Enter(_)));
    let (link, mut link_rx) = telextiles_link::Link::start(lc, identity, pins.clone()).await?;
    eprintln!(
        "{} ({}) listening on {}",
        cfg.name,
        device_id,
        link.local_addr()
    );

    // Roller, set to the index's slot count.
    let slots = u16::try_from(index.roller.n()).context("the index has too many roller slots")?;
    let (roller, roller_desc, _sim_roller) = roller::start_roller(&cfg, &opts, slots)?;

    // Events.
    let (events, _) = broadcast::channel::<Event>(1024);

    // Map: its own event channel (control events are forwarded, touches are
    // added by the receiver).
    let map_tx = cfg
        .map
        .then(|| broadcast::channel::<telextiles_map::MapEvent>(1024).0);

    // Sensing thread.
    let (sensor_tx, sensor_rx) = std_mpsc::channel();
    let sensing::OpenedSource {
        source,
        sim,
        desc: sensor_desc,
        profile: sensor_profile,
    } = sensing::open_source(&cfg, &opts, &index)?;
    let (shutdown, mut shutdown_rx) = watch::channel(false);
    let state = Arc::new(State {
        name: cfg.name.clone(),
        device_id: device_id.to_string(),
        index: index.clone(),
        model,
        link: link.clone(),
        pins,
        state_dir: cfg.state_dir.clone(),
        roller,
        roller_desc,
        sensor_desc,
        sensor_profile,
        sensor_tx,
        sim,
        events: events.clone(),
        peers: Mutex::new(BTreeMap::new()),
        relays: Mutex::new(
            lc_relays
                .iter()
                .map(|r| {
                    let url = r.url.to_string();
                    let state = RelayState {
                        url: url.clone(),
                        connected: false,
                        error: None,
                        since: receive::unix_now(),
                    };
                    (url, state)
                })
                .collect(),
        ),
        counters: Counters::default(),
        in_contact: AtomicBool::new(false),
        roller_pos: Mutex::new(None),
        felt: Mutex::new(Default::default()),
        pairing_pending: Mutex::new(pairing),
        fatal: Mutex::new(None),
        map_tx: map_tx.clone(),
        shutdown,
        started: Instant::now(),
        trace,
    });
    // Every task and the sensing thread report here when they end: before
    // shutdown that is fatal (a deaf daemon must not linger).
    let (ended_tx, mut ended_rx) =
        tokio::sync::mpsc::unbounded_channel::<(&'static str, Option<String>)>();
    let sensing = {
        let state = state.clone();
        let ended = ended_tx.clone();
        let (contact, encode_run) = (cfg.contact(), cfg.encode_run);
        std::thread::Builder::new()
            .name("sensing".into())
            .spawn(move || {
                let guard = EndGuard::new("sensing thread", ended);
                let r =
                    sensing::sensing_thread(state, source, encoder, contact, encode_run, sensor_rx);
                guard.done(r.err());
            })?
    };

    // Receiver: the session core, fed by the link.
    let receiver = {
        let state = state.clone();
        let mut rx = Receiver::new(index.clone(), receiver_config(&cfg));
        supervise("receiver task", &ended_tx, async move {
            while let Some(ev) = link_rx.recv().await {
                receive::on_link_event(&state, &mut rx, ev);
            }
            Some("the peer link closed".to_string())
        })
    };

    // Roller events -> bus.
    let roller_events = state.roller.as_ref().map(|r| {
        let mut sub = r.subscribe();
        let state = state.clone();
        supervise("roller events task", &ended_tx, async move {
            let mut last_pos = Instant::now() - Duration::from_secs(1);
            loop {
                match sub.recv().await {
                    Ok(ev) => roller::on_roller_event(&state, ev, &mut last_pos),
                    Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => {
                        return Some("the roller driver stopped".to_string())
                    }
                }
            }
        })
    });

    // Control socket.
    let spec = cfg.socket_spec()?;
    let server =
        Server::bind(ServerConfig::new(spec)).map_err(|e| anyhow!("control socket: {e}"))?;
    eprintln!("control socket {}", server.path().display());
    let control = {
        let handler = Arc::new(control::Daemon(state.clone()));
        let mut sd = state.shutdown.subscribe();
        tokio::spawn(server.serve(handler, events.clone(), async move {
            let _ = sd.wait_for(|v| *v).await;
        }))
    };

    // Map.
    let map = match &map_tx {
        Some(tx) => Some(map::spawn_map(&cfg, index.clone(), tx.clone(), &events, &state).await?),
        None => None,
    };

    // Wait for shutdown.
    let expiry = {
        let state = state.clone();
        async move {
            match opts.pairing_deadline {
                Some(t) => {
                    tokio::time::sleep_until(tokio::time::Instant::from_std(t)).await;
                    if *lock(&state.pairing_pending) {
                        return;
                    }
                    std::future::pending().await
                }
                None => std::future::pending().await,
            }
        }
    };
    tokio::select! {
        _ = shutdown_rx.wait_for(|v| *v) => {}
        _ = expiry => {
            *lock(&state.fatal) = Some(if entering {
                discovery::enter_expired_message(opts.code_ttl)
            } else {
                "the pairing code expired before the other device used it; run `telextilesd pair` again for a new code".into()
            });
        }
        _ = tokio::signal::ctrl_c() => { eprintln!("interrupted"); }
        _ = sigterm() => {}
        Some((what, why)) = ended_rx.recv() => {
            // (A task ending because shutdown was asked for is no failure.)
            let mut fatal = lock(&state.fatal);
            if !*state.shutdown.borrow() && fatal.is_none() {
                let why = why.unwrap_or_else(|| "it stopped".into());
                *fatal = Some(format!("the {what} ended: {why}"));
            }
        }
    }
    let _ = state.shutdown.send(true);
    let _ = state.sensor_tx.send(SensorCmd::Stop);
    link.shutdown().await;
    receiver.abort();
    if let Some(t) = roller_events {
        t.abort();
    }
    let _ = tokio::time::timeout(Duration::from_secs(3), control).await;
    if let Some(m) = map {
        m.abort();
    }
    let _ = tokio::task::spawn_blocking(move || sensing.join()).await;
    let fatal = lock(&state.fatal).take();
    if let Ok(state) = Arc::try_unwrap(state) {
        if let Some(r) = state.roller {
            r.shutdown().await;
        }
    }
    match fatal {
        Some(why) => Err(anyhow!(why)),
        None => Ok(()),
    }
}

async fn sigterm() {
    match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
        Ok(mut s) => {
            s.recv().await;
        }
        Err(_) => std::future::pending().await,
    }
}

/// The receiving session core's settings: the configured decider
/// (`commit_margin`, [`Config::decide`]) and the wheel's motion policy.
fn receiver_config(cfg: &Config) -> ReceiverConfig {
    ReceiverConfig {
        decide: cfg.decide(),
        motion: cfg.motion,
        ..ReceiverConfig::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ConfigArgs;

    /// The `commit_margin` setting reaches the decider of presses this
    /// daemon receives, and nothing else of the receiver changes.
    #[test]
    fn the_configured_commit_margin_reaches_the_receiving_decider() {
        let resolve = |margin: Option<f32>| {
            let args = ConfigArgs {
                commit_margin: margin,
                runtime_dir: Some("/r".into()),
                config: Some("/dev/null".into()),
                ..ConfigArgs::default()
            };
            Config::resolve(&args, &|k| (k == "HOME").then(|| "/h".into())).unwrap()
        };
        assert_eq!(receiver_config(&resolve(None)), ReceiverConfig::default());
        let r = receiver_config(&resolve(Some(0.02)));
        assert_eq!(r.decide.commit_margin, 0.02);
        assert_eq!(
            ReceiverConfig {
                decide: Default::default(),
                ..r
            },
            ReceiverConfig::default()
        );
    }

    /// The `motion` setting reaches the receiver core.
    #[test]
    fn the_configured_motion_policy_reaches_the_receiver() {
        let args = ConfigArgs {
            motion: Some("lead:45".parse().unwrap()),
            runtime_dir: Some("/r".into()),
            config: Some("/dev/null".into()),
            ..ConfigArgs::default()
        };
        let cfg = Config::resolve(&args, &|k| (k == "HOME").then(|| "/h".into())).unwrap();
        assert_eq!(
            receiver_config(&cfg).motion,
            telextiles_session::MotionPolicy::Lead { lead_ms: 45.0 }
        );
        let env = |k: &str| match k {
            "HOME" => Some("/h".into()),
            "TELEXTILESD_MOTION" => Some("fast".into()),
            _ => None,
        };
        let args = ConfigArgs {
            runtime_dir: Some("/r".into()),
            config: Some("/dev/null".into()),
            ..ConfigArgs::default()
        };
        let e = Config::resolve(&args, &env).unwrap_err().to_string();
        assert!(
            e.contains("TELEXTILESD_MOTION") && e.contains("unknown motion policy"),
            "{e}"
        );
    }
}
