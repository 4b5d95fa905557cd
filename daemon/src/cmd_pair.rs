//! `telextilesd pair`: pair with another device, then run a live link
//! session with it.
//!
//! * Not yet paired (or `--show`): this device shows a one-time code and
//!   waits; the other user runs `telextilesd pair --enter` (types the code)
//!   or `telextilesd pair --code 1234-5678`. The device that enters the code
//!   finds the one that shows it by mDNS (or `--connect host:port`).
//! * Both users see the same verification code and can compare it.
//! * Once paired (or if already paired) the command stays in a live link
//!   session: hello (encoder/index check), keep-alive, reconnects, and prints
//!   when the peer comes and goes. Ctrl-C ends it.
use std::io::{BufRead, Write};
use std::time::Instant;

use anyhow::bail;
use telextiles_certs::{CodeOffer, Identity, PairingCode, PinSet, TrustStore, DEFAULT_CODE_TTL};
use telextiles_link::{ErrorKind, HelloInfo, Link, LinkConfig, LinkEvent, PairingMode};

use crate::config::{Config, ConfigArgs};
use crate::live::discovery::{discovery_config, enter_expired_message};

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    #[command(flatten)]
    pub config: Box<ConfigArgs>,
    /// Enter the code shown on the other device (asked for on the terminal)
    #[arg(long, conflicts_with_all = ["code", "show"])]
    pub enter: bool,
    /// The code shown on the other device, e.g. 1234-5678
    #[arg(long, value_name = "CODE", conflicts_with = "show")]
    pub code: Option<String>,
    /// Show a new code even if this device is already paired
    #[arg(long)]
    pub show: bool,
    /// Only pair, then exit (no live session)
    #[arg(long)]
    pub no_session: bool,
    /// Speed factor of the simulated roller (1 = a real roller's timing)
    #[arg(long, hide = true, env = "TELEXTILESD_SIM_ROLLER_SPEED")]
    pub sim_roller_speed: Option<f64>,
    /// Write a per-frame latency trace to this file (diagnostic; see
    /// daemon/src/trace.rs and docs/benchmarks.md)
    #[arg(
        long,
        hide = true,
        value_name = "FILE",
        env = "TELEXTILESD_LATENCY_TRACE"
    )]
    pub latency_trace: Option<std::path::PathBuf>,
    /// Lifetime of a shown code and how long entering a code keeps trying,
    /// in ms (tests; default: the code lifetime, 5 minutes)
    #[arg(long, hide = true, env = "TELEXTILESD_PAIRING_TTL_MS")]
    pub pairing_ttl_ms: Option<u64>,
}

impl Args {
    /// The code lifetime this run uses.
    pub fn code_ttl(&self) -> std::time::Duration {
        self.pairing_ttl_ms
            .map_or(DEFAULT_CODE_TTL, std::time::Duration::from_millis)
    }
}

fn say(line: &str) {
    println!("{line}");
    let _ = std::io::stdout().flush();
}

fn ask_code() -> anyhow::Result<PairingCode> {
    let stdin = std::io::stdin();
    for attempt in 1..=3 {
        eprint!("Type the code shown on the other device: ");
        let _ = std::io::stderr().flush();
        let mut line = String::new();
        if stdin.lock().read_line(&mut line)? == 0 {
            bail!("no code typed (end of input)");
        }
        match line.trim().parse::<PairingCode>() {
            Ok(c) => return Ok(c),
            Err(e) if attempt < 3 => eprintln!("{e}"),
            Err(e) => return Err(e.into()),
        }
    }
    unreachable!("the loop returns on its third attempt")
}

fn hello_info(cfg: &Config) -> HelloInfo {
    match telextiles_index::Index::read(&cfg.index) {
        Ok(index) => HelloInfo {
            encoder_hash: index.encoder_hash.clone(),
            index_fingerprint: index.fingerprint(),
            embedding_dim: index.dim.min(u16::MAX as usize) as u16,
        },
        Err(e) => {
            eprintln!(
                "note: no usable textile index at {} ({e}); the hello says \"none\" and only matches a peer without an index either",
                cfg.index.display()
            );
            HelloInfo {
                encoder_hash: "none".into(),
                index_fingerprint: "none".into(),
                embedding_dim: 0,
            }
        }
    }
}

/// `telextilesd run`
#[derive(clap::Args, Debug, Clone)]
pub struct RunArgs {
    #[command(flatten)]
    pub config: Box<ConfigArgs>,
    /// Speed factor of the simulated roller (1 = a real roller's timing)
    #[arg(long, hide = true, env = "TELEXTILESD_SIM_ROLLER_SPEED")]
    pub sim_roller_speed: Option<f64>,
    /// Write a per-frame latency trace to this file (diagnostic; see
    /// daemon/src/trace.rs and docs/benchmarks.md)
    #[arg(
        long,
        hide = true,
        value_name = "FILE",
        env = "TELEXTILESD_LATENCY_TRACE"
    )]
    pub latency_trace: Option<std::path::PathBuf>,
}

/// The live session with already-paired peers, no pairing (systemd's entry).
pub fn run_session(args: RunArgs) -> anyhow::Result<()> {
    let cfg = Config::load(&args.config)?;
    crate::set_log_filter(cfg.env_filter()?);
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?
        .block_on(async move {
            if TrustStore::load(&cfg.state_dir)?.is_empty() {
                eprintln!("note: this device is not paired yet; run `telextilesd pair` to pair it (the session runs and waits)");
            }
            crate::live::run(
                cfg,
                crate::live::SessionOptions {
                    sim_roller_speed: args.sim_roller_speed,
                    latency_trace: args.latency_trace.clone(),
                    ..Default::default()
                },
            )
            .await
        })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let cfg = Config::load(&args.config)?;
    crate::set_log_filter(cfg.env_filter()?);
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()?
        .block_on(run_async(args, cfg))
}

async fn run_async(args: Args, cfg: Config) -> anyhow::Result<()> {
    let (identity, created) = Identity::load_or_create(&cfg.state_dir)?;
    if created {
        say(&format!(
            "Created this device's identity in {}",
            cfg.state_dir.display()
        ));
    }
    let store = TrustStore::load(&cfg.state_dir)?;
    say(&format!(
        "This device: {} ({})",
        cfg.name,
        identity.device_id()
    ));
    say(&format!("This device's key: {}", identity.peer_key()));

    let mode = if args.enter {
        Some(PairingMode::Enter(ask_code()?))
    } else if let Some(c) = &args.code {
        Some(PairingMode::Enter(c.parse::<PairingCode>()?))
    } else if args.show || store.is_empty() {
        let offer = CodeOffer::new(&mut rand::rngs::OsRng, Instant::now(), args.code_ttl());
        say(&format!(
            "Pairing code: {}   (valid {} minutes, one try)",
            offer.display(),
            args.code_ttl().as_secs() / 60
        ));
        say("On the other device run:  telextilesd pair --enter   and type this code.");
        say(&format!(
            "(Not on this LAN? There, add  --connect {}@HOST:PORT  with this device's address, or just the key through a relay.)",
            identity.peer_key()
        ));
        Some(PairingMode::Show(offer))
    } else {
        for p in store.peers() {
            say(&format!("Paired with {} ({})", p.name, p.device_id.short()));
        }
        None
    };
    let pairing = mode.is_some();
    // A shown code expires; entering a code gives up after the same time
    // (devices that fail to prove the code do not end it, see
    // `ErrorKind::PairingAttempt`, so something must).
    let pairing_deadline = match &mode {
        Some(PairingMode::Show(o)) => Some(o.expires_at()),
        Some(PairingMode::Enter(_)) => Some(Instant::now() + args.code_ttl()),
        None => None,
    };
    let entering = matches!(mode, Some(PairingMode::Enter(_)));
    if !args.no_session {
        if !cfg.mdns && cfg.connect.is_empty() && matches!(mode, Some(PairingMode::Enter(_))) {
            bail!("mDNS is off and no --connect was given: there is no way to find the device showing the code (name it by its key: KEY@HOST:PORT, or KEY alone with a relay)");
        }
        // Pairing (if asked for) and then the live session: sensing, link,
        // decisions, roller, control socket.
        return crate::live::run(
            cfg,
            crate::live::SessionOptions {
                pairing: mode,
                pairing_deadline,
                code_ttl: args.code_ttl(),
                sim_roller_speed: args.sim_roller_speed,
                sim_gap_frames: None,
                latency_trace: args.latency_trace.clone(),
            },
        )
        .await;
    }

    let mut lc = LinkConfig::new(cfg.name.clone(), cfg.listen, hello_info(&cfg));
    lc.connect = crate::config::peer::resolve(&cfg.connect)?;
    lc.data_dir = Some(cfg.state_dir.clone());
    lc.relays = crate::config::peer::relays(&cfg)?;
    lc.pairing = mode;
    if cfg.mdns {
        lc.discovery = Some(discovery_config(&cfg));
    } else if lc.connect.is_empty() && matches!(lc.pairing, Some(PairingMode::Enter(_))) {
        bail!("mDNS is off and no --connect was given: there is no way to find the device showing the code (name it by its key: KEY@HOST:PORT, or KEY alone with a relay)");
    }
    let pins = PinSet::from_store(&store);
    let (link, mut events) = Link::start(lc, identity, pins).await?;

    let mut paired_now = !pairing;
    loop {
        let expiry = async {
            match pairing_deadline {
                Some(t) if !paired_now => {
                    tokio::time::sleep_until(tokio::time::Instant::from_std(t)).await
                }
                _ => std::future::pending().await,
            }
        };
        let ev = tokio::select! {
            ev = events.recv() => ev,
            _ = tokio::signal::ctrl_c() => {
                say("Stopping.");
                link.shutdown().await;
                return Ok(());
            }
            _ = expiry => {
                link.shutdown().await;
                if entering {
                    bail!("{}", enter_expired_message(args.code_ttl()));
                }
                bail!("the pairing code expired before the other device used it; run `telextilesd pair` again for a new code");
            }
        };
        let Some(ev) = ev else {
            bail!("the link stopped unexpectedly");
        };
        match ev {
            LinkEvent::Listening { addr } => say(&format!("Listening on {addr} (UDP/QUIC)")),
            LinkEvent::Discovered {
                peer,
                addrs,
                paired,
                pairing,
            } => {
                if pairing && !paired {
                    say(&format!(
                        "Found a device showing a pairing code: {} at {:?}",
                        peer.short(),
                        addrs
                    ));
                } else if paired {
                    say(&format!(
                        "Found paired device {} at {:?}",
                        peer.short(),
                        addrs
                    ));
                }
            }
            LinkEvent::Paired { peer, verification } => {
                paired_now = true;
                say(&format!("Paired with {peer}."));
                say(&format!(
                    "Verification code: {verification}  — the other device shows the same code; if not, run `telextilesd unpair {}`.",
                    peer.short()
                ));
                if args.no_session {
                    link.shutdown().await;
                    return Ok(());
                }
            }
            LinkEvent::PeerUp { peer, name, addr } => say(&format!(
                "Peer up: {name} ({}) at {addr} — live session running (Ctrl-C to stop)",
                peer.short()
            )),
            LinkEvent::PeerDown { peer, reason } => say(&format!(
                "Peer down: {} ({reason}); reconnecting when it is back",
                peer.short()
            )),
            LinkEvent::PathChanged { peer, route, rtt } => say(&format!(
                "Path to {}: {} ({route}, round trip {:.1} ms)",
                peer.short(),
                route.kind(),
                rtt.as_secs_f64() * 1e3
            )),
            LinkEvent::Relay {
                url,
                connected,
                error,
            } => say(&telextiles_link::relay_status_line(
                &url,
                connected,
                error.as_deref(),
            )),
            LinkEvent::Latent(_) | LinkEvent::Control { .. } => {}
            LinkEvent::Error { kind, message, .. } => {
                eprintln!("error: {message}");
                // `PairingAttempt`: one device failed to prove the code;
                // pairing goes on with the others (until the deadline).
                if kind == ErrorKind::Pairing && pairing && !paired_now {
                    link.shutdown().await;
                    bail!("pairing failed");
                }
                if let ErrorKind::Incompatible(_) = kind {
                    eprintln!("(no streaming with this peer until both devices have the same encoder and index)");
                }
            }
        }
    }
}
