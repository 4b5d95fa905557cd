//! The live session: sensing -> peer link -> decision -> roller, both ways.
//!
//! One daemon is both a sender (its DIGIT, or the simulator, pressed onto a
//! fabric: contact detection, encoding, latents streamed to the peer) and a
//! receiver (latents from the peer: running-mean decision with hysteresis
//! against the shared index, roller commands). A control socket lets
//! scripts watch and steer it; the 2D map is served when enabled.
//!
//! Threads and tasks:
//! - the sensing thread (blocking: camera reads and ONNX inference) owns the
//!   frame source, contact detector and encoder; it sends latents straight
//!   into the link (a datagram per frame, no queue) and events to the bus;
//! - the receiver task turns link events into decisions and roller targets;
//! - the roller driver task (telextiles-roller) owns the serial port;
//! - the control server and the map server serve local clients.

use anyhow::{anyhow, bail, Context, Result};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::mpsc as std_mpsc;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use telextiles_certs::{Identity, PinSet, TrustStore};
use telextiles_control::{
    Command, ContactPhase, CtlError, Event, GotoTarget, Handler, HandlerFuture, Server,
    ServerConfig,
};
use telextiles_index::Index;
use telextiles_link::{now_us, HelloInfo, LinkConfig, LinkEvent, LinkHandle, PairingMode};
use telextiles_proto::peer::Control;
use telextiles_proto::roller::steps_to_mdeg;
use telextiles_roller::{DriverConfig, RollerDriver, RollerEvent, Target};
use telextiles_sensing::contact::{ContactConfig, ContactEvent};
use telextiles_sensing::decide::{DecideConfig, Decider, TextileIndex};
use telextiles_sensing::encoder::{Encoder, EncoderOptions, ModelInfo};
use telextiles_sensing::frame::Frame;
use telextiles_sensing::front::FrontEnd;
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
use telextiles_sensing::source::sim::{SimCommand, SimHandle, SimSource};
use telextiles_sensing::source::FrameSource;
use tokio::sync::{broadcast, watch};

use crate::config::{Config, RollerSource, SensorSource};

/// Extra knobs of a session beyond the configuration.
#[derive(Debug, Default)]
pub struct SessionOptions {
    /// Pair first (the `telextilesd pair` flow).
    pub pairing: Option<PairingMode>,
    /// A shown pairing code expires at this time: the session ends with an
    /// error if no device used it by then.
    pub pairing_deadline: Option<std::time::Instant>,
    /// Simulated roller speed factor (1 = a real roller).
    pub sim_roller_speed: Option<f64>,
    /// No-contact frames between simulated presses.
    pub sim_gap_frames: Option<usize>,
    /// Write a per-frame latency trace here (`crate::trace`).
    pub latency_trace: Option<PathBuf>,
}

/// Commands for the sensing thread.
#[derive(Debug)]
enum SensorCmd {
    Recapture,
    Sim(SimCommand),
    Stop,
}

/// Per-press bookkeeping on the receiving side.
struct RxPress {
    peer: String,
    press_id: u32,
    contact_capture_us: u64,
    decider: Decider,
    decided: Option<usize>,
}

#[derive(Default)]
struct Counters {
    frames: u64,
    presses_sent: u64,
    latents_sent: u64,
    presses_received: u64,
    latents_received: u64,
    decisions: u64,
    bad_frames: u64,
}

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
    sensor_tx: std_mpsc::Sender<SensorCmd>,
    sim: Option<SimHandle>,
    simulator: Option<Arc<telextiles_sim::Simulator>>,
    events: broadcast::Sender<Event>,
    peers: Mutex<BTreeMap<String, Value>>,
    counters: Mutex<Counters>,
    in_contact: Mutex<bool>,
    /// Last roller position: (millidegrees, slot, moving).
    roller_pos: Mutex<Option<(u32, Option<u16>, bool)>>,
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

fn normalise(v: &mut [f32]) {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 && n.is_finite() {
        v.iter_mut().for_each(|x| *x /= n);
    }
}

/// The default model and index: the configured paths, else the ones
/// shipped in the source tree (for runs from a checkout).
pub fn resolve_model_paths(cfg: &Config) -> (PathBuf, PathBuf) {
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    let pick = |p: &Path, name: &str| {
        if p.exists() {
            p.to_path_buf()
        } else if shipped.join(name).exists() {
            shipped.join(name)
        } else {
            p.to_path_buf()
        }
    };
    (
        pick(&cfg.model, "encoder.onnx"),
        pick(&cfg.index, "index.tlxi"),
    )
}

/// Load encoder and index and check they belong together.
pub fn load_model(cfg: &Config, threads: usize) -> Result<(Encoder, Index)> {
    let (model, index_path) = resolve_model_paths(cfg);
    let enc = Encoder::open(
        &model,
        &EncoderOptions {
            threads,
            ..Default::default()
        },
    )
    .with_context(|| format!("cannot load the encoder {}", model.display()))?;
    let index = Index::read(&index_path)?;
    index.check_encoder(&enc.info().sha256)?;
    if index.dim != enc.dim() {
        bail!(
            "{} holds {}-d embeddings but {} produces {}-d ones",
            index_path.display(),
            index.dim,
            model.display(),
            enc.dim()
        );
    }
    Ok((enc, index))
}

/// Run a session until shutdown (control `shutdown`, SIGINT or SIGTERM).
pub async fn run(cfg: Config, mut opts: SessionOptions) -> Result<()> {
    let trace = match &opts.latency_trace {
        Some(p) => Some(crate::trace::Trace::create(p)?),
        None => None,
    };
    let (encoder, index) = load_model(&cfg, 1)?;
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
        lc.connect.push(resolve_addr(c)?);
    }
    if cfg.mdns {
        lc.discovery = Some(crate::cmd_pair::discovery_config(&cfg));
    }
    lc.data_dir = Some(cfg.state_dir.clone());
    lc.pairing = opts.pairing.take();
    let pairing = lc.pairing.is_some();
    let (link, mut link_rx) = telextiles_link::Link::start(lc, identity, pins.clone()).await?;
    eprintln!(
        "{} ({}) listening on {}",
        cfg.name,
        device_id,
        link.local_addr()
    );

    // Roller.
    let (roller, roller_desc, _sim_roller) = start_roller(&cfg, &opts)?;

    // Events.
    let (events, _) = broadcast::channel::<Event>(1024);

    // Map: its own event channel (control events are forwarded, touches are
    // added by the receiver).
    let map_tx = cfg
        .map
        .then(|| broadcast::channel::<telextiles_map::MapEvent>(1024).0);

    // Sensing thread.
    let (sensor_tx, sensor_rx) = std_mpsc::channel();
    let (source, sim, sensor_desc) = open_source(&cfg, &opts)?;
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
        sensor_tx,
        simulator: sim.as_ref().map(|s| s.1.clone()),
        sim: sim.map(|s| s.0),
        events: events.clone(),
        peers: Mutex::new(BTreeMap::new()),
        counters: Mutex::new(Counters::default()),
        in_contact: Mutex::new(false),
        roller_pos: Mutex::new(None),
        pairing_pending: Mutex::new(pairing),
        fatal: Mutex::new(None),
        map_tx: map_tx.clone(),
        shutdown,
        started: Instant::now(),
        trace,
    });
    let sensing = {
        let state = state.clone();
        std::thread::Builder::new()
            .name("sensing".into())
            .spawn(move || sensing_thread(state, source, encoder, sensor_rx))?
    };

    // Receiver.
    let receiver = {
        let state = state.clone();
        tokio::spawn(async move {
            let mut rx: Option<RxPress> = None;
            while let Some(ev) = link_rx.recv().await {
                on_link_event(&state, &mut rx, ev);
            }
        })
    };

    // Roller events -> bus.
    let roller_events = state.roller.as_ref().map(|r| {
        let mut sub = r.subscribe();
        let state = state.clone();
        tokio::spawn(async move {
            let mut last_pos = Instant::now() - Duration::from_secs(1);
            loop {
                match sub.recv().await {
                    Ok(ev) => on_roller_event(&state, ev, &mut last_pos),
                    Err(broadcast::error::RecvError::Lagged(_)) => continue,
                    Err(broadcast::error::RecvError::Closed) => break,
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
        let handler = Arc::new(Daemon(state.clone()));
        let mut sd = state.shutdown.subscribe();
        tokio::spawn(server.serve(handler, events.clone(), async move {
            let _ = sd.wait_for(|v| *v).await;
        }))
    };

    // Map.
    let map = match &map_tx {
        Some(tx) => Some(spawn_map(&cfg, index.clone(), tx.clone(), &events, &state).await?),
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
            *lock(&state.fatal) = Some("the pairing code expired before the other device used it; run `telextilesd pair` again for a new code".into());
        }
        _ = tokio::signal::ctrl_c() => { eprintln!("interrupted"); }
        _ = sigterm() => {}
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

/// Serve the map until shutdown; control events are forwarded to it.
async fn spawn_map(
    cfg: &Config,
    index: Arc<Index>,
    tx: broadcast::Sender<telextiles_map::MapEvent>,
    events: &broadcast::Sender<Event>,
    state: &Arc<State>,
) -> Result<tokio::task::JoinHandle<()>> {
    let server = telextiles_map::MapServer::bind(
        cfg.map_bind,
        index,
        telextiles_map::TextureSource::Simulated,
        &tx,
    )
    .await?;
    println!("map: http://{}/", server.local_addr());
    let mut sub = events.subscribe();
    let forward = tokio::spawn(async move {
        loop {
            match sub.recv().await {
                Ok(ev) => {
                    if let Ok(m) = telextiles_map::MapEvent::from_control_json(&ev.to_line()) {
                        let _ = tx.send(m);
                    }
                }
                Err(broadcast::error::RecvError::Lagged(_)) => continue,
                Err(broadcast::error::RecvError::Closed) => break,
            }
        }
    });
    let mut sd = state.shutdown.subscribe();
    Ok(tokio::spawn(async move {
        let stop = async move {
            let _ = sd.wait_for(|v| *v).await;
        };
        if let Err(e) = server.serve_until(stop).await {
            eprintln!("map server: {e}");
        }
        forward.abort();
    }))
}

async fn sigterm() {
    match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
        Ok(mut s) => {
            s.recv().await;
        }
        Err(_) => std::future::pending().await,
    }
}

fn resolve_addr(s: &str) -> Result<SocketAddr> {
    use std::net::ToSocketAddrs;
    s.to_socket_addrs()
        .with_context(|| format!("cannot resolve peer address {s:?}"))?
        .next()
        .ok_or_else(|| anyhow!("peer address {s:?} resolves to nothing"))
}

type SimRollerGuard = Option<telextiles_roller::SimRoller>;

fn start_roller(
    cfg: &Config,
    opts: &SessionOptions,
) -> Result<(Option<RollerDriver>, String, SimRollerGuard)> {
    let sim = |why: &str| -> Result<(Option<RollerDriver>, String, SimRollerGuard)> {
        let sim = telextiles_roller::SimRoller::spawn(telextiles_roller::SimConfig {
            speed: opts.sim_roller_speed.unwrap_or(1.0),
            ..Default::default()
        })
        .context("cannot start the simulated roller")?;
        let path = sim.path();
        let driver = RollerDriver::start(DriverConfig::path(&path));
        Ok((
            Some(driver),
            format!("simulated roller on {}{why}", path.display()),
            Some(sim),
        ))
    };
    match &cfg.roller {
        RollerSource::None => Ok((None, "none".into(), None)),
        RollerSource::Sim => sim(""),
        RollerSource::Path(p) => Ok((
            Some(RollerDriver::start(DriverConfig::path(p))),
            p.display().to_string(),
            None,
        )),
        RollerSource::Auto => match telextiles_roller::detect_port() {
            Ok(p) => Ok((Some(RollerDriver::start(DriverConfig::path(&p))), p, None)),
            Err(e) => {
                eprintln!("{e}; using the simulated roller");
                sim(" (no roller found)")
            }
        },
    }
}

/// The frame source, the simulator's handle (when simulated) and a
/// description for people.
type OpenedSource = (
    Box<dyn FrameSource>,
    Option<(SimHandle, Arc<telextiles_sim::Simulator>)>,
    String,
);

fn open_source(cfg: &Config, opts: &SessionOptions) -> Result<OpenedSource> {
    // A simulated DIGIT: pressing `textile` again and again, or (None)
    // lifted until `ctl sensor sim <textile>` asks for a press.
    let sim_source = |textile: Option<&str>, why: &str| -> Result<OpenedSource> {
        let simulator = Arc::new(telextiles_sim::Simulator::new()?);
        let spec = telextiles_sim::PressSpec::new(textile.unwrap_or("T001"), 1);
        let (src, handle) = SimSource::new(
            simulator.clone(),
            spec,
            opts.sim_gap_frames.unwrap_or(60),
            Pace::RealTime,
        )?;
        let (src, desc) = match textile {
            Some(t) => (src, format!("simulated DIGIT pressing {t} repeatedly{why}")),
            None => (
                src.start_idle(),
                format!(
                    "simulated DIGIT, lifted until `telextilesd ctl sensor sim <textile>`{why}"
                ),
            ),
        };
        let src: Box<dyn FrameSource> = Box::new(src);
        Ok((src, Some((handle, simulator)), desc))
    };
    match &cfg.sensor {
        SensorSource::Sim { textile } => sim_source(textile.as_deref(), ""),
        SensorSource::Replay { dir } => {
            let src = RecordedSource::open(dir, Pace::RealTime)?.looping(true);
            Ok((Box::new(src), None, format!("replay of {}", dir.display())))
        }
        SensorSource::Digit { serial } => {
            let opts = telextiles_sensing::source::digit::DigitOptions {
                serial: serial.clone(),
                ..Default::default()
            };
            match telextiles_sensing::source::digit::DigitSource::open(&opts) {
                Ok(src) => {
                    let desc = format!(
                        "DIGIT {} on {}",
                        src.info().serial,
                        src.info().node.display()
                    );
                    // The first open succeeded; later opens (after an unplug)
                    // retry with backoff.
                    let mut first = Some(src);
                    let src = telextiles_sensing::source::Resilient::new(move || {
                        if let Some(s) = first.take() {
                            return Ok(Box::new(s) as Box<dyn FrameSource>);
                        }
                        telextiles_sensing::source::digit::DigitSource::open(&opts)
                            .map(|s| Box::new(s) as Box<dyn FrameSource>)
                    });
                    Ok((Box::new(src), None, desc))
                }
                Err(e) if serial.is_none() => {
                    eprintln!("{e}; using the simulated DIGIT");
                    sim_source(None, " (no DIGIT found)")
                }
                Err(e) => Err(e.into()),
            }
        }
    }
}

fn sensing_thread(
    state: Arc<State>,
    mut source: Box<dyn FrameSource>,
    encoder: Encoder,
    cmds: std_mpsc::Receiver<SensorCmd>,
) {
    // The one per-frame path (as `classify` and `index build` run it):
    // contact detection and the no-contact reference, then encoding while
    // in contact.
    let mut front = FrontEnd::new(encoder, ContactConfig::default(), None);
    let mut frame = Frame::blank();
    let dim = front.encoder().dim();
    let mut press_id: u32 = 0;
    let mut sum = vec![0.0f32; dim];
    let mut mean = vec![0.0f32; dim];
    let mut frames_in_press = 0u32;
    loop {
        while let Ok(cmd) = cmds.try_recv() {
            match cmd {
                SensorCmd::Recapture => front.recapture(),
                SensorCmd::Sim(c) => {
                    if let Some(h) = &state.sim {
                        h.send(c);
                    }
                }
                SensorCmd::Stop => return,
            }
        }
        if *state.shutdown.borrow() {
            return;
        }
        if let Err(e) = source.next_frame(&mut frame) {
            let fatal = matches!(
                e,
                telextiles_sensing::source::SourceError::Fatal(_)
                    | telextiles_sensing::source::SourceError::Ended
            );
            let _ = state.events.send(Event::Error {
                source: "sensor".into(),
                message: e.to_string(),
            });
            lock(&state.counters).bad_frames += 1;
            if fatal {
                eprintln!("sensor: {e}");
                return;
            }
            continue;
        }
        let capture_us = now_us();
        lock(&state.counters).frames += 1;
        let out = match front.process(&frame) {
            Ok(o) => o,
            Err(e) => {
                lock(&state.counters).bad_frames += 1;
                let _ = state.events.send(Event::Error {
                    source: "encoder".into(),
                    message: e.to_string(),
                });
                continue;
            }
        };
        let up = out.contact;
        let contact_us = capture_us + out.contact_ns / 1000;
        match up.event {
            Some(ContactEvent::PressStart { .. }) => {
                press_id = press_id.wrapping_add(1);
                sum.iter_mut().for_each(|x| *x = 0.0);
                frames_in_press = 0;
                *lock(&state.in_contact) = true;
                lock(&state.counters).presses_sent += 1;
                let _ = state.link.send_control(Control::PressStart {
                    press_id,
                    capture_us,
                });
                let _ = state.events.send(Event::Contact {
                    phase: ContactPhase::Start,
                    score: Some(up.score),
                });
            }
            Some(ContactEvent::PressEnd { .. }) => {
                *lock(&state.in_contact) = false;
                let last = (frames_in_press > 0).then_some(mean.as_slice());
                let _ = state.link.send_press_stop(press_id, last, capture_us);
                let _ = state.events.send(Event::Contact {
                    phase: ContactPhase::End,
                    score: Some(up.score),
                });
            }
            _ => {}
        }
        if let Some(emb) = out.embedding {
            let encoded_us = contact_us + (out.preprocess_ns + out.encode_ns) / 1000;
            // The embedding is L2-normalised by the encoder.
            for (s, v) in sum.iter_mut().zip(emb) {
                *s += v;
            }
            frames_in_press += 1;
            mean.copy_from_slice(&sum);
            normalise(&mut mean);
            if let Ok(sent) = state
                .link
                .send_latent_timed(press_id, emb, capture_us, false)
            {
                let sent_us = now_us();
                lock(&state.counters).latents_sent += 1;
                if let Some(t) = &state.trace {
                    t.tx(
                        sent.seq,
                        press_id,
                        [capture_us, contact_us, encoded_us, sent.encoded_us, sent_us],
                    );
                }
            }
        }
    }
}

fn on_link_event(state: &Arc<State>, rx: &mut Option<RxPress>, ev: LinkEvent) {
    match ev {
        LinkEvent::Listening { addr } => say(&format!("Listening on {addr} (UDP/QUIC)")),
        LinkEvent::Discovered {
            peer,
            addrs,
            paired,
            pairing,
        } => {
            if pairing && !paired && *lock(&state.pairing_pending) {
                say(&format!(
                    "Found a device showing a pairing code: {} at {addrs:?}",
                    peer.short()
                ));
            } else if paired {
                say(&format!(
                    "Found paired device {} at {addrs:?}",
                    peer.short()
                ));
            }
        }
        LinkEvent::Paired { peer, verification } => {
            *lock(&state.pairing_pending) = false;
            say(&format!("Paired with {peer}."));
            say(&format!(
                "Verification code: {verification}  — the other device shows the same code; if not, run `telextilesd unpair {}`.",
                peer.short()
            ));
            state.pins.insert(peer);
        }
        LinkEvent::PeerUp { peer, name, addr } => {
            say(&format!(
                "Peer up: {name} ({}) at {addr} — live session running (Ctrl-C to stop)",
                peer.short()
            ));
            lock(&state.peers).insert(
                peer.to_string(),
                json!({"id": peer.to_string(), "name": name, "addr": addr.to_string()}),
            );
            let _ = state.events.send(Event::PeerUp {
                peer: name,
                addr: Some(addr.to_string()),
            });
        }
        LinkEvent::PeerDown { peer, reason } => {
            say(&format!(
                "Peer down: {} ({reason}); reconnecting when it is back",
                peer.short()
            ));
            let name = lock(&state.peers)
                .remove(&peer.to_string())
                .and_then(|v| v["name"].as_str().map(String::from))
                .unwrap_or_else(|| peer.to_string());
            let _ = state.events.send(Event::PeerDown { peer: name, reason });
        }
        LinkEvent::Error { kind, message, .. } => {
            eprintln!("error: {message}");
            if kind == telextiles_link::ErrorKind::Pairing && *lock(&state.pairing_pending) {
                *lock(&state.fatal) = Some("pairing failed".into());
                let _ = state.shutdown.send(true);
            }
            if let telextiles_link::ErrorKind::Incompatible(_) = kind {
                eprintln!("(no streaming with this peer until both devices have the same encoder and index)");
            }
            let _ = state.events.send(Event::Error {
                source: "link".into(),
                message,
            });
        }
        LinkEvent::Control { peer, msg } => match msg {
            Control::PressStart {
                press_id,
                capture_us,
            } => {
                start_rx_press(state, rx, peer.to_string(), press_id, capture_us);
            }
            Control::PressStop {
                press_id,
                final_latent,
                ..
            } => {
                let peer = peer.to_string();
                if let Some(l) = final_latent {
                    let mut v = l.vector.dequantize();
                    normalise(&mut v);
                    if rx
                        .as_ref()
                        .is_none_or(|p| p.press_id != press_id || p.peer != peer)
                    {
                        start_rx_press(state, rx, peer.clone(), press_id, l.capture_us);
                    }
                    // The press's own running mean decides the final answer, so
                    // lost datagrams never change it.
                    let p = rx.as_mut().expect("press started above");
                    if let Some(n) = state.index.nearest2(&v) {
                        let latency = now_us().saturating_sub(l.capture_us.min(now_us()));
                        decide(state, p, n.best, n.best_dist, latency, l.capture_us, true);
                    }
                }
                *rx = None;
            }
            _ => {}
        },
        LinkEvent::Latent(l) => {
            let handled_us = now_us();
            let peer = l.peer.to_string();
            lock(&state.counters).latents_received += 1;
            if rx
                .as_ref()
                .is_none_or(|p| p.press_id != l.press_id || p.peer != peer)
            {
                start_rx_press(state, rx, peer, l.press_id, l.capture_us);
            }
            let p = rx.as_mut().expect("press started above");
            let mut v = l.vector;
            normalise(&mut v);
            if let Some(tx) = &state.map_tx {
                if l.seq % 6 == 0 {
                    let _ = tx.send(telextiles_map::MapEvent::Touch {
                        latent: v.clone(),
                        peer: Some(peer_name(state, &p.peer)),
                    });
                }
            }
            let step = p.decider.on_embedding(&*state.index, l.capture_us, &v);
            let commanded = match step.map(|s| (s.changed, s.decision)) {
                Some((true, Some(d))) => {
                    let latency = l.one_way_latency_us.unwrap_or(0).max(0) as u64;
                    decide(state, p, d.entry, d.distance, latency, l.capture_us, false)
                }
                _ => None,
            };
            if let Some(t) = &state.trace {
                t.rx(
                    l.seq,
                    l.press_id,
                    [l.received_us, handled_us, now_us()],
                    commanded,
                );
            }
        }
    }
}

/// A peer's name for people, or its ID when not connected.
fn peer_name(state: &State, id: &str) -> String {
    lock(&state.peers)
        .get(id)
        .and_then(|v| v["name"].as_str().map(String::from))
        .unwrap_or_else(|| id.to_string())
}

fn start_rx_press(
    state: &Arc<State>,
    rx: &mut Option<RxPress>,
    peer: String,
    press_id: u32,
    capture_us: u64,
) {
    if rx
        .as_ref()
        .is_some_and(|p| p.press_id == press_id && p.peer == peer)
    {
        return;
    }
    let mut decider = Decider::new(DecideConfig::default(), state.index.dim);
    decider.press_start(capture_us);
    lock(&state.counters).presses_received += 1;
    *rx = Some(RxPress {
        peer,
        press_id,
        contact_capture_us: capture_us,
        decider,
        decided: None,
    });
}

/// Act on a decision: turn the roller (latest target wins) and tell watchers.
fn decide(
    state: &Arc<State>,
    p: &mut RxPress,
    entry: usize,
    distance: f32,
    latency_us: u64,
    capture_us: u64,
    final_decision: bool,
) -> Option<usize> {
    let changed = p.decided != Some(entry);
    if !changed && !final_decision {
        return None;
    }
    p.decided = Some(entry);
    let slot = state.index.slot_of_entry(entry);
    if changed {
        if let Some(r) = &state.roller {
            r.set_target(Target::Slot(slot as u16));
        }
    }
    lock(&state.counters).decisions += 1;
    let e = &state.index.entries[entry];
    let _ = state.events.send(Event::Decision {
        textile: e.id.clone(),
        name: Some(e.name.clone()),
        slot: slot as u32,
        distance,
        latency_ms: latency_us as f64 / 1000.0,
        peer: Some(p.peer.clone()),
        press: Some(p.press_id),
        final_decision,
        since_contact_ms: Some(
            capture_us.saturating_sub(p.contact_capture_us) as f64 / 1000.0
                + latency_us as f64 / 1000.0,
        ),
    });
    changed.then_some(slot)
}

fn on_roller_event(state: &Arc<State>, ev: RollerEvent, last_pos: &mut Instant) {
    let deg = |mdeg: u32| mdeg as f64 / 1000.0;
    match ev {
        RollerEvent::Position {
            mdeg, slot, moving, ..
        } => {
            *lock(&state.roller_pos) = Some((mdeg, slot, moving));
            if last_pos.elapsed() >= Duration::from_millis(100) {
                *last_pos = Instant::now();
                let _ = state.events.send(Event::RollerPosition {
                    angle_deg: deg(mdeg),
                    target_slot: slot.map(u32::from),
                });
            }
        }
        RollerEvent::Arrived { target, status } => {
            let steps_per_rev = state
                .roller
                .as_ref()
                .and_then(|r| r.state().version)
                .map_or(0, |v| v.steps_per_rev);
            let mdeg = steps_to_mdeg(status.position, steps_per_rev);
            let slot = match target {
                Target::Slot(s) => s as u32,
                _ => u32::MAX,
            };
            *lock(&state.roller_pos) =
                Some((mdeg, (slot != u32::MAX).then_some(slot as u16), false));
            let _ = state.events.send(Event::RollerArrived {
                slot,
                angle_deg: deg(mdeg),
            });
        }
        RollerEvent::Error { message } => {
            let _ = state.events.send(Event::Error {
                source: "roller".into(),
                message,
            });
        }
        RollerEvent::Disconnected { reason } => {
            let _ = state.events.send(Event::Error {
                source: "roller".into(),
                message: format!("disconnected: {reason}"),
            });
        }
        RollerEvent::Connected { .. } => {}
        RollerEvent::TargetWritten { target, at } => {
            if let Some(t) = &state.trace {
                let slot = match target {
                    Target::Slot(s) => Some(s),
                    _ => None,
                };
                t.serial(slot, at);
            }
        }
    }
}

struct Daemon(Arc<State>);

impl Daemon {
    fn status(&self) -> Value {
        let s = &self.0;
        let c = lock(&s.counters);
        let roller = s.roller.as_ref().map(|r| {
            let st = r.state();
            json!({
                "port": st.port, "connected": st.connected,
                "position": lock(&s.roller_pos).map(|(mdeg, slot, moving)| json!({"angle_deg": mdeg as f64 / 1000.0, "slot": slot, "moving": moving})),
                "moving": st.status.map(|x| x.moving()),
                "target": st.target.map(|t| format!("{t:?}")),
                "reconnects": st.reconnects,
            })
        });
        json!({
            "name": s.name,
            "device_id": s.device_id,
            "version": env!("CARGO_PKG_VERSION"),
            "uptime_s": s.started.elapsed().as_secs_f64(),
            "listen": s.link.local_addr().to_string(),
            "sensor": {"source": s.sensor_desc, "in_contact": *lock(&s.in_contact)},
            "roller": {"source": s.roller_desc, "state": roller},
            "peers": lock(&s.peers).values().cloned().collect::<Vec<_>>(),
            "model": {"path": s.model.path, "sha256": s.model.sha256, "arch": s.model.arch, "dim": s.model.dim},
            "index": {"fingerprint": s.index.fingerprint(), "textiles": s.index.entries.len(), "slots": s.index.roller.n()},
            "counters": {
                "frames": c.frames, "bad_frames": c.bad_frames,
                "presses_sent": c.presses_sent, "latents_sent": c.latents_sent,
                "presses_received": c.presses_received, "latents_received": c.latents_received,
                "decisions": c.decisions,
            },
        })
    }

    fn roller(&self) -> Result<&RollerDriver, CtlError> {
        self.0
            .roller
            .as_ref()
            .ok_or_else(|| CtlError::unavailable("this daemon drives no roller (roller = none)"))
    }
}

impl Handler for Daemon {
    fn handle(&self, command: Command) -> HandlerFuture<'_> {
        Box::pin(async move {
            let s = &self.0;
            match command {
                Command::Status => Ok(self.status()),
                Command::Peers => {
                    let store = TrustStore::load(&s.state_dir)
                        .map_err(|e| CtlError::failed(e.to_string()))?;
                    let connected = lock(&s.peers).clone();
                    Ok(Value::Array(
                        store
                            .peers()
                            .iter()
                            .map(|p| {
                                let id = p.device_id.to_string();
                                json!({"id": id, "name": p.name, "connected": connected.contains_key(&id)})
                            })
                            .collect(),
                    ))
                }
                Command::Pair(_) => Err(CtlError::unavailable(
                    "pairing runs from the command line: `telextilesd pair` on both devices",
                )),
                Command::Unpair(a) => {
                    let removed = TrustStore::update(&s.state_dir, |st| match st.find(&a.peer) {
                        Ok(p) => {
                            let id = p.device_id;
                            (true, Ok(st.remove(&id)))
                        }
                        Err(e) => (false, Err(e)),
                    })
                    .map_err(|e| CtlError::failed(e.to_string()))?
                    .map_err(|e| CtlError::invalid_args(e.to_string()))?
                    .ok_or_else(|| {
                        CtlError::invalid_args(format!("no paired peer {:?}", a.peer))
                    })?;
                    // Drops the pin and closes the live connection at once.
                    s.link.unpair(&removed.device_id);
                    Ok(json!({"unpaired": removed.device_id.to_string(), "name": removed.name}))
                }
                Command::SensorRecalibrate => {
                    s.sensor_tx
                        .send(SensorCmd::Recapture)
                        .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
                    Ok(json!({"recalibrating": true}))
                }
                Command::SensorLed(_) => Err(CtlError::unavailable(format!(
                    "LED control needs a DIGIT; the sensor is the {}",
                    s.sensor_desc
                ))),
                Command::SensorSim(a) => {
                    if s.sim.is_none() {
                        return Err(CtlError::unavailable(format!(
                            "the sensor is not simulated ({})",
                            s.sensor_desc
                        )));
                    }
                    if a.textile == "none" {
                        s.sensor_tx
                            .send(SensorCmd::Sim(SimCommand::Lift))
                            .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
                        return Ok(json!({"lifted": true}));
                    }
                    if telextiles_sim::catalogue::Catalogue::builtin()
                        .get(&a.textile)
                        .is_none()
                    {
                        return Err(CtlError::invalid_args(format!(
                            "unknown textile {:?}: the simulator knows T001..T119 and U01..U20",
                            a.textile
                        )));
                    }
                    let mut spec =
                        telextiles_sim::PressSpec::new(a.textile.clone(), a.seed.unwrap_or(1));
                    spec.jig = a.jig.unwrap_or(true);
                    spec.person = a.person.unwrap_or(0);
                    spec.sensor = a.sensor.unwrap_or(0);
                    spec.rotation_deg = a.rotation_deg.map(|v| v as f32);
                    spec.force = a.force.map(|v| v as f32);
                    if let Some(sim) = &s.simulator {
                        sim.press_meta(&spec)
                            .map_err(|e| CtlError::invalid_args(e.to_string()))?;
                    }
                    s.sensor_tx
                        .send(SensorCmd::Sim(SimCommand::PressOnce(spec.clone())))
                        .map_err(|_| CtlError::unavailable("the sensor has stopped"))?;
                    Ok(json!({
                        "pressing": spec.textile, "person": spec.person, "sensor": spec.sensor,
                        "jig": spec.jig, "seed": spec.seed,
                    }))
                }
                Command::RollerGoto(t) => {
                    let r = self.roller()?;
                    let slot = match t {
                        GotoTarget::Slot(n) if (n as usize) < s.index.roller.n() => n as usize,
                        GotoTarget::Slot(n) => {
                            return Err(CtlError::invalid_args(format!(
                                "slot {n} is out of range (the roller has {} slots)",
                                s.index.roller.n()
                            )))
                        }
                        GotoTarget::Textile(id) => {
                            let e = s.index.entry_by_id(&id).ok_or_else(|| {
                                CtlError::invalid_args(format!(
                                    "textile {id:?} is not in the index"
                                ))
                            })?;
                            s.index.slot_of_entry(e)
                        }
                    };
                    r.set_target(Target::Slot(slot as u16));
                    Ok(json!({"slot": slot}))
                }
                Command::RollerHome => {
                    self.roller()?.set_target(Target::Slot(0));
                    Ok(json!({"slot": 0}))
                }
                Command::RollerJog(j) => {
                    let r = self.roller()?;
                    let now = lock(&s.roller_pos).map(|p| p.0 as i64).unwrap_or(0);
                    let to = (now + (j.degrees * 1000.0).round() as i64).rem_euclid(360_000);
                    r.set_target(Target::AngleMdeg(to as u32));
                    Ok(json!({"angle_deg": to as f64 / 1000.0}))
                }
                Command::IndexInfo => Ok(json!({
                    "fingerprint": s.index.fingerprint(),
                    "encoder": s.index.encoder_hash,
                    "arch": s.index.encoder_arch,
                    "dim": s.index.dim,
                    "textiles": s.index.entries.len(),
                    "roller": s.index.roller.slots.iter().map(|&i| &s.index.entries[i].id).collect::<Vec<_>>(),
                    "selection": s.index.roller.method.to_string(),
                })),
                Command::Shutdown => {
                    let _ = s.shutdown.send(true);
                    Ok(json!({"shutting_down": true}))
                }
                Command::Subscribe(_) => {
                    Err(CtlError::internal("subscribe is handled by the server"))
                }
                Command::RecordStart(_) | Command::RecordStop => Err(CtlError::unavailable(
                    "recording over the control socket is not wired into this daemon yet; use `telextilesd record`",
                )),
            }
        })
    }
}
