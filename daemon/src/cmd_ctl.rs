//! `telextilesd ctl <cmd>`: talk to a running daemon over its control
//! socket, with human-friendly output or raw JSON lines (`--json`).

use crate::config::{Config, ConfigArgs};
use anyhow::{bail, Context};
use clap::builder::BoolishValueParser;
use std::io::Write;
use std::path::PathBuf;
use std::time::Duration;
use telextiles_control::client::{Client, EventLine};
use telextiles_control::format::{human_error, human_event, human_value};
use telextiles_control::protocol::{
    parse_server_line, Command, EventKind, GotoTarget, JogArgs, LedArgs, PairArgs, RecordPhase,
    RecordStartArgs, Reply, RequestId, ServerLine, SimPressArgs, SubscribeArgs, UnpairArgs,
    LED_MAX,
};

#[derive(clap::Args, Debug, Clone)]
pub struct Args {
    /// Print the daemon's raw JSON lines instead of human-friendly text
    #[arg(long, global = true)]
    pub json: bool,
    /// Config file (to find the socket) [env: TELEXTILESD_CONFIG]
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Control socket path [env: TELEXTILESD_SOCKET] [default: $XDG_RUNTIME_DIR/telextilesd/control.sock]
    #[arg(long, value_name = "PATH")]
    pub socket: Option<PathBuf>,
    /// Runtime directory holding the socket [env: TELEXTILESD_RUNTIME_DIR]
    #[arg(long, value_name = "DIR")]
    pub runtime_dir: Option<PathBuf>,
    /// Talk to the system-wide daemon (/run/telextilesd/control.sock) [env: TELEXTILESD_SYSTEM]
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true", value_parser = BoolishValueParser::new(), value_name = "BOOL")]
    pub system: Option<bool>,
    /// Seconds to wait for the reply (0 = no limit; `subscribe` streams regardless)
    #[arg(long, default_value_t = 30, value_name = "SECONDS")]
    pub timeout: u64,
    #[command(subcommand)]
    pub cmd: CtlCmd,
}

#[derive(clap::Subcommand, Debug, Clone, PartialEq)]
pub enum CtlCmd {
    /// Daemon state: name, sensor, roller, index, peers, clients
    Status,
    /// Paired and connected peers
    Peers,
    /// Pair with another daemon
    Pair {
        /// The pairing code shown by the other daemon (omit to show ours)
        #[arg(long)]
        code: Option<String>,
        /// Seconds to wait for the other side (1..=3600)
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=3600))]
        timeout_s: Option<u32>,
    },
    /// Forget a paired peer
    Unpair {
        /// Peer name or id as listed by `peers`
        peer: String,
    },
    /// Sensor control
    #[command(subcommand)]
    Sensor(SensorCmd),
    /// Roller control
    #[command(subcommand)]
    Roller(RollerCmd),
    /// The loaded textile index
    Index {
        #[command(subcommand)]
        cmd: Option<IndexCmd>,
    },
    /// Record labelled presses from the daemon's sensor (as `telextilesd record`)
    #[command(subcommand)]
    Record(RecordCmd),
    /// Stream events until interrupted (all kinds, or those named)
    Subscribe {
        /// Event kinds: contact, decision, peer_up, peer_down, roller_position, roller_arrived, error, record
        #[arg(value_parser = parse_kind)]
        events: Vec<EventKind>,
    },
    /// Stop the daemon
    Shutdown,
    /// Send one JSON request line; print the reply (raw with --json)
    Raw {
        /// e.g. '{"id":1,"cmd":"status"}'
        request: String,
    },
}

#[derive(clap::Subcommand, Debug, Clone, PartialEq)]
pub enum SensorCmd {
    /// Re-capture the no-contact background frame (lift the sensor first)
    Recalibrate,
    /// Set LED intensity: one value for all channels, or R G B (each 0..=15)
    Led {
        #[arg(num_args = 1..=3, required = true, value_parser = clap::value_parser!(u8).range(0..=(LED_MAX as i64)))]
        values: Vec<u8>,
    },
    /// Simulated sensor only: press a textile (id, e.g. T012 or U03), or `none` to lift
    Sim {
        textile: String,
        /// Simulated person (0..=10; hand pressure, tilt habits)
        #[arg(long)]
        person: Option<u32>,
        /// Simulated sensor unit
        #[arg(long)]
        sensor: Option<u32>,
        /// Press without the spring jig (hand-held)
        #[arg(long)]
        no_jig: bool,
        /// Seed of the press (noise, placement)
        #[arg(long)]
        seed: Option<u64>,
        /// In-plane rotation of the fabric, degrees
        #[arg(long, allow_hyphen_values = true)]
        rotation: Option<f64>,
        /// Pressing force, newtons
        #[arg(long)]
        force: Option<f64>,
    },
}

#[derive(clap::Subcommand, Debug, Clone, PartialEq)]
pub enum RollerCmd {
    /// Turn to a slot number, or to the slot carrying a textile id (e.g. T012)
    Goto { target: String },
    /// Home the roller
    Home,
    /// Turn by an angle in degrees (-360..=360; negative = backwards)
    Jog {
        #[arg(allow_hyphen_values = true)]
        degrees: f64,
    },
}

#[derive(clap::Subcommand, Debug, Clone, PartialEq)]
pub enum RecordCmd {
    /// Start recording presses into <out>/<textile>/NNNN (next free numbers)
    Start {
        /// Textile id (a directory name)
        #[arg(long)]
        textile: String,
        /// Human-readable name, stored in <out>/<textile>/textile.json
        #[arg(long)]
        name: Option<String>,
        /// Presses to record
        #[arg(long, value_parser = clap::value_parser!(u32).range(1..=10_000))]
        presses: u32,
        /// Directory of recordings (made absolute here: the daemon runs elsewhere)
        #[arg(long)]
        out: PathBuf,
        /// Stay and print the recording's events until it is done or stopped
        #[arg(long)]
        follow: bool,
    },
    /// Stop recording (the press in progress is dropped; saved presses stay)
    Stop,
}

#[derive(clap::Subcommand, Debug, Clone, PartialEq)]
pub enum IndexCmd {
    /// Size, fingerprint, encoder hash and roller layout
    Info,
}

fn parse_kind(s: &str) -> Result<EventKind, String> {
    EventKind::parse(s).ok_or_else(|| {
        let kinds: Vec<&str> = EventKind::ALL.iter().map(|k| k.as_str()).collect();
        format!("unknown event kind `{s}`; kinds: {}", kinds.join(", "))
    })
}

/// The protocol command for a CLI command (`None` for `raw`).
pub fn to_command(cmd: &CtlCmd) -> anyhow::Result<Option<Command>> {
    Ok(Some(match cmd {
        CtlCmd::Status => Command::Status,
        CtlCmd::Peers => Command::Peers,
        CtlCmd::Pair { code, timeout_s } => Command::Pair(PairArgs {
            code: code.clone(),
            timeout_s: *timeout_s,
        }),
        CtlCmd::Unpair { peer } => Command::Unpair(UnpairArgs { peer: peer.clone() }),
        CtlCmd::Sensor(SensorCmd::Recalibrate) => Command::SensorRecalibrate,
        CtlCmd::Sensor(SensorCmd::Led { values }) => match values.as_slice() {
            [v] => Command::SensorLed(LedArgs {
                r: *v,
                g: *v,
                b: *v,
            }),
            [r, g, b] => Command::SensorLed(LedArgs {
                r: *r,
                g: *g,
                b: *b,
            }),
            _ => bail!("`sensor led` takes one intensity or three (R G B), each 0..={LED_MAX}"),
        },
        CtlCmd::Sensor(SensorCmd::Sim {
            textile,
            person,
            sensor,
            no_jig,
            seed,
            rotation,
            force,
        }) => Command::SensorSim(SimPressArgs {
            textile: textile.clone(),
            person: *person,
            sensor: *sensor,
            jig: no_jig.then_some(false),
            seed: *seed,
            rotation_deg: *rotation,
            force: *force,
        }),
        CtlCmd::Roller(RollerCmd::Goto { target }) => match target.parse::<u32>() {
            Ok(slot) => Command::RollerGoto(GotoTarget::Slot(slot)),
            Err(_) => Command::RollerGoto(GotoTarget::Textile(target.clone())),
        },
        CtlCmd::Roller(RollerCmd::Home) => Command::RollerHome,
        CtlCmd::Roller(RollerCmd::Jog { degrees }) => {
            if !degrees.is_finite() || degrees.abs() > 360.0 {
                bail!("`roller jog` takes degrees in -360..=360, got {degrees}");
            }
            Command::RollerJog(JogArgs { degrees: *degrees })
        }
        CtlCmd::Index { .. } => Command::IndexInfo,
        CtlCmd::Record(RecordCmd::Start {
            textile,
            name,
            presses,
            out,
            ..
        }) => {
            let out = std::path::absolute(out)
                .with_context(|| format!("cannot make {} absolute", out.display()))?;
            let Some(out) = out.to_str() else {
                bail!("the output directory {} is not UTF-8", out.display());
            };
            Command::RecordStart(RecordStartArgs {
                textile: textile.clone(),
                name: name.clone(),
                presses: *presses,
                out: out.to_string(),
            })
        }
        CtlCmd::Record(RecordCmd::Stop) => Command::RecordStop,
        CtlCmd::Subscribe { events } => Command::Subscribe(SubscribeArgs {
            events: (!events.is_empty()).then(|| events.clone()),
        }),
        CtlCmd::Shutdown => Command::Shutdown,
        CtlCmd::Raw { .. } => return Ok(None),
    }))
}

/// Entry point from `main`.
pub fn run(args: Args) -> anyhow::Result<()> {
    let socket = socket_path(&args)?;
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")?;
    let mut out = crate::out::stdout();
    rt.block_on(execute(&args, &socket, &mut out))
}

/// The socket `ctl` talks to, resolved like the daemon resolves it.
pub fn socket_path(args: &Args) -> anyhow::Result<PathBuf> {
    let cargs = ConfigArgs {
        config: args.config.clone(),
        socket: args.socket.clone(),
        runtime_dir: args.runtime_dir.clone(),
        system: args.system,
        ..ConfigArgs::default()
    };
    Ok(Config::load(&cargs)?.socket)
}

/// Runs one CLI command against the socket, writing output to `out`.
pub async fn execute(
    args: &Args,
    socket: &std::path::Path,
    out: &mut (dyn Write + Send),
) -> anyhow::Result<()> {
    let mut client = Client::connect(socket).await?;
    let limit = (args.timeout > 0).then(|| Duration::from_secs(args.timeout));
    let Some(command) = to_command(&args.cmd)? else {
        let CtlCmd::Raw { request } = &args.cmd else {
            unreachable!("only raw has no command")
        };
        let line = request.trim();
        if line.contains('\n') {
            bail!("`raw` takes one JSON line");
        }
        client.send_raw(format!("{line}\n").as_bytes()).await?;
        let reply = with_limit(limit, client.read_line()).await??;
        match reply {
            Some(ServerLine::Reply(r)) => {
                write!(out, "{}", format_line(&r.to_line(), args.json)?)?;
                return if r.ok {
                    Ok(())
                } else {
                    bail!("the daemon answered with an error")
                };
            }
            Some(other) => bail!("unexpected line from the daemon: {other:?}"),
            None => bail!("the daemon closed the connection without answering"),
        }
    };
    let subscribe = matches!(command, Command::Subscribe(_));
    let follow = matches!(
        args.cmd,
        CtlCmd::Record(RecordCmd::Start { follow: true, .. })
    );
    if follow {
        // Subscribe first, so that no event of this recording is missed.
        let sub = Command::Subscribe(SubscribeArgs {
            events: Some(vec![EventKind::Record]),
        });
        if let Err(e) = with_limit(limit, client.call(&sub)).await?? {
            bail!("{}", human_error(&e));
        }
    }
    let result = with_limit(limit, client.call(&command)).await??;
    match result {
        Ok(data) => {
            if args.json {
                write!(out, "{}", Reply::ok(RequestId::from(1), data).to_line())?;
            } else if !subscribe {
                write!(out, "{}", human_value(&data))?;
            } else {
                let kinds = data["events"].as_array().map(|a| a.len()).unwrap_or(0);
                writeln!(out, "subscribed to {kinds} event kinds; Ctrl-C to stop")?;
            }
        }
        Err(e) => {
            if args.json {
                write!(
                    out,
                    "{}",
                    Reply::err(RequestId::from(1), e.clone()).to_line()
                )?;
            }
            bail!("{}", human_error(&e));
        }
    }
    out.flush()?;
    if follow {
        while let Some(ev) = client.next_event().await? {
            let EventLine::Known(e) = ev else { continue };
            if args.json {
                write!(out, "{}", e.to_line())?;
            } else {
                writeln!(out, "{}", human_event(&e))?;
            }
            out.flush()?;
            match e {
                telextiles_control::Event::Record {
                    state: RecordPhase::Done,
                    ..
                } => return Ok(()),
                telextiles_control::Event::Record {
                    state: RecordPhase::Stopped,
                    reason,
                    ..
                } => bail!(
                    "the recording stopped: {}",
                    reason.as_deref().unwrap_or("record.stop")
                ),
                telextiles_control::Event::Dropped { reason } => {
                    bail!("the daemon dropped this subscription: {reason}")
                }
                _ => {}
            }
        }
        bail!("the daemon closed the connection");
    }
    if subscribe {
        while let Some(ev) = client.next_event().await? {
            match (&ev, args.json) {
                (EventLine::Known(e), true) => write!(out, "{}", e.to_line())?,
                (EventLine::Known(e), false) => writeln!(out, "{}", human_event(e))?,
                (EventLine::Unknown(v), _) => writeln!(out, "{v}")?,
            }
            out.flush()?;
            if let EventLine::Known(telextiles_control::Event::Dropped { reason }) = ev {
                bail!("the daemon dropped this subscription: {reason}");
            }
        }
        bail!("the daemon closed the connection");
    }
    Ok(())
}

async fn with_limit<T>(
    limit: Option<Duration>,
    f: impl std::future::Future<Output = T>,
) -> anyhow::Result<T> {
    match limit {
        Some(d) => tokio::time::timeout(d, f).await.map_err(|_| {
            anyhow::anyhow!(
                "no reply from the daemon within {} s (see --timeout)",
                d.as_secs()
            )
        }),
        None => Ok(f.await),
    }
}

/// A server line for display: as is with `json`, human-friendly otherwise.
pub fn format_line(line: &str, json: bool) -> anyhow::Result<String> {
    if json {
        return Ok(format!("{}\n", line.trim_end()));
    }
    Ok(
        match parse_server_line(line.trim_end().as_bytes()).map_err(anyhow::Error::msg)? {
            ServerLine::Reply(r) => match r.into_result() {
                Ok(v) => human_value(&v),
                Err(e) => format!("{}\n", human_error(&e)),
            },
            ServerLine::Event(e) => format!("{}\n", human_event(&e)),
            ServerLine::UnknownEvent(v) => format!("{v}\n"),
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;
    use serde_json::json;
    use std::path::Path;
    use std::sync::Arc;
    use telextiles_control::RecordPhase;
    use telextiles_control::{
        Access, CtlError, Event, Handler, HandlerFuture, Server, ServerConfig, SocketSpec,
    };

    #[derive(Parser)]
    struct T {
        #[command(flatten)]
        a: Args,
    }

    fn parse(argv: &[&str]) -> Args {
        T::try_parse_from(std::iter::once("ctl").chain(argv.iter().copied()))
            .unwrap_or_else(|e| panic!("{e}"))
            .a
    }

    #[test]
    fn cli_definition_is_consistent() {
        use clap::CommandFactory;
        T::command().debug_assert();
        // `raw` and the global `--json` flag coexist.
        let a = parse(&["--json", "raw", "{}"]);
        assert!(a.json);
        assert_eq!(
            a.cmd,
            CtlCmd::Raw {
                request: "{}".into()
            }
        );
    }

    #[test]
    fn cli_maps_to_protocol_commands() {
        let c = |argv: &[&str]| to_command(&parse(argv).cmd).unwrap().unwrap();
        assert_eq!(c(&["status"]), Command::Status);
        assert_eq!(
            c(&["roller", "goto", "3"]),
            Command::RollerGoto(GotoTarget::Slot(3))
        );
        assert_eq!(
            c(&["roller", "goto", "T012"]),
            Command::RollerGoto(GotoTarget::Textile("T012".into()))
        );
        assert_eq!(
            c(&["roller", "jog", "-22.5"]),
            Command::RollerJog(JogArgs { degrees: -22.5 })
        );
        assert_eq!(
            c(&["sensor", "led", "5"]),
            Command::SensorLed(LedArgs { r: 5, g: 5, b: 5 })
        );
        assert_eq!(
            c(&["sensor", "led", "1", "2", "3"]),
            Command::SensorLed(LedArgs { r: 1, g: 2, b: 3 })
        );
        assert_eq!(c(&["index"]), Command::IndexInfo);
        assert_eq!(
            c(&[
                "record",
                "start",
                "--textile",
                "T030",
                "--name",
                "twill",
                "--presses",
                "3",
                "--out",
                "/data/rec"
            ]),
            Command::RecordStart(RecordStartArgs {
                textile: "T030".into(),
                name: Some("twill".into()),
                presses: 3,
                out: "/data/rec".into(),
            })
        );
        // A relative directory is sent as the absolute path it means here.
        let Command::RecordStart(r) = c(&[
            "record",
            "start",
            "--textile",
            "T030",
            "--presses",
            "1",
            "--out",
            "rec",
        ]) else {
            panic!("not record.start")
        };
        assert!(
            Path::new(&r.out).is_absolute() && r.out.ends_with("/rec"),
            "{}",
            r.out
        );
        assert_eq!(c(&["record", "stop"]), Command::RecordStop);
        assert_eq!(c(&["index", "info"]), Command::IndexInfo);
        assert_eq!(
            c(&["--json", "subscribe", "decision", "roller_arrived"]),
            Command::Subscribe(SubscribeArgs {
                events: Some(vec![EventKind::Decision, EventKind::RollerArrived])
            })
        );
        assert_eq!(
            c(&["subscribe"]),
            Command::Subscribe(SubscribeArgs { events: None })
        );
        assert_eq!(
            c(&["pair", "--code", "1234", "--timeout-s", "60"]),
            Command::Pair(PairArgs {
                code: Some("1234".into()),
                timeout_s: Some(60)
            })
        );
        assert!(parse(&["status", "--json"]).json);
        // Bad values are refused before anything is sent.
        for bad in [
            &["sensor", "led", "16"][..],
            &["sensor", "led", "1", "2"],
            &["subscribe", "nope"],
            &["pair", "--timeout-s", "0"],
            &["frobnicate"],
        ] {
            let parsed = T::try_parse_from(std::iter::once("ctl").chain(bad.iter().copied()));
            let failed = match parsed {
                Err(_) => true,
                Ok(t) => to_command(&t.a.cmd).is_err(),
            };
            assert!(failed, "{bad:?} accepted");
        }
        assert!(to_command(&parse(&["roller", "jog", "400"]).cmd).is_err());
    }

    #[test]
    fn formats_lines() {
        assert_eq!(
            format_line(r#"{"id":1,"ok":true,"data":{"slot":3}}"#, false).unwrap(),
            "slot: 3\n"
        );
        assert_eq!(
            format_line(
                r#"{"id":1,"ok":false,"error":{"code":"unavailable","message":"no roller"}}"#,
                false
            )
            .unwrap(),
            "error [unavailable]: no roller\n"
        );
        assert_eq!(
            format_line(
                r#"{"event":"roller_arrived","slot":2,"angle_deg":45.0}"#,
                false
            )
            .unwrap(),
            "roller    arrived at slot 2 (45.0 deg)\n"
        );
        assert_eq!(
            format_line("{\"event\":\"x\"}\n", true).unwrap(),
            "{\"event\":\"x\"}\n"
        );
    }

    /// A `Write` whose contents the test can read while `execute` runs.
    #[derive(Clone, Default)]
    struct SharedBuf(Arc<std::sync::Mutex<Vec<u8>>>);
    impl Write for SharedBuf {
        fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(buf);
            Ok(buf.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    struct H;
    impl Handler for H {
        fn handle(&self, command: Command) -> HandlerFuture<'_> {
            Box::pin(async move {
                match command {
                    Command::Status => Ok(json!({"name": "studio", "peers": 1})),
                    Command::RollerGoto(GotoTarget::Slot(s)) => Ok(json!({"slot": s})),
                    other => Err(CtlError::unavailable(format!("no {}", other.name()))),
                }
            })
        }
    }

    /// Answers record.start and then plays a recording's events.
    struct Recorder(tokio::sync::broadcast::Sender<Event>, RecordPhase);
    impl Handler for Recorder {
        fn handle(&self, command: Command) -> HandlerFuture<'_> {
            Box::pin(async move {
                let Command::RecordStart(a) = command else {
                    return Err(CtlError::unavailable("only record.start"));
                };
                let (tx, end) = (self.0.clone(), self.1);
                let textile = a.textile.clone();
                tokio::spawn(async move {
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    let state = |state, reason: Option<&str>| Event::Record {
                        state,
                        textile: textile.clone(),
                        press: 1,
                        presses: 1,
                        held_ms: None,
                        score: None,
                        reason: reason.map(String::from),
                    };
                    let _ = tx.send(state(RecordPhase::Ready, None));
                    let _ = tx.send(Event::RollerArrived {
                        slot: 1,
                        angle_deg: 1.0,
                    });
                    let _ = tx.send(state(end, Some("record.stop (0 of 1 presses saved)")));
                });
                Ok(json!({"first": "0001"}))
            })
        }
    }

    #[test]
    fn record_start_follow_prints_the_recording_until_it_ends() {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            for end in [RecordPhase::Done, RecordPhase::Stopped] {
                let dir = tempfile::tempdir().unwrap();
                let spec = SocketSpec::in_dir(&dir.path().join("rt"), Access::User);
                let server = Server::bind(ServerConfig::new(spec)).unwrap();
                let sock = server.path().to_path_buf();
                let (events, _) = tokio::sync::broadcast::channel(16);
                let stop = Arc::new(tokio::sync::Notify::new());
                let stop2 = stop.clone();
                let served = tokio::spawn(server.serve(
                    Arc::new(Recorder(events.clone(), end)),
                    events,
                    async move { stop2.notified().await },
                ));
                let a = parse(&[
                    "record",
                    "start",
                    "--textile",
                    "T030",
                    "--presses",
                    "1",
                    "--out",
                    "/r",
                    "--follow",
                ]);
                let mut out = Vec::new();
                let r = execute(&a, &sock, &mut out).await;
                let out = String::from_utf8(out).unwrap();
                // Only record events are followed.
                assert!(!out.contains("roller"), "{out}");
                assert!(
                    out.starts_with("first: 0001\nrecord    T030 1/1: press now\n"),
                    "{out}"
                );
                match end {
                    RecordPhase::Done => {
                        r.unwrap();
                        assert!(out.ends_with("record    T030: done, 1 presses\n"), "{out}");
                    }
                    _ => assert_eq!(
                        r.unwrap_err().to_string(),
                        "the recording stopped: record.stop (0 of 1 presses saved)"
                    ),
                }
                stop.notify_one();
                served.await.unwrap();
            }
        });
    }

    /// The real CLI code path against a real server on a real socket.
    #[test]
    fn cli_against_a_real_socket() {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let dir = tempfile::tempdir().unwrap();
            let spec = SocketSpec::in_dir(&dir.path().join("rt"), Access::User);
            let server = Server::bind(ServerConfig::new(spec)).unwrap();
            let sock = server.path().to_path_buf();
            let (events, _) = tokio::sync::broadcast::channel(16);
            let ev = events.clone();
            let stop = Arc::new(tokio::sync::Notify::new());
            let stop2 = stop.clone();
            let served = tokio::spawn(server.serve(Arc::new(H), ev, async move { stop2.notified().await }));
            let run = |argv: Vec<&'static str>| {
                let sock = sock.clone();
                async move {
                    let a = parse(&argv);
                    let mut out = Vec::new();
                    let r = execute(&a, &sock, &mut out).await;
                    (r, String::from_utf8(out).unwrap())
                }
            };
            let (r, out) = run(vec!["status"]).await;
            r.unwrap();
            assert!(out.contains("name: studio") && out.contains("peers: 1"), "{out}");
            let (r, out) = run(vec!["--json", "roller", "goto", "4"]).await;
            r.unwrap();
            assert_eq!(out, "{\"id\":1,\"ok\":true,\"data\":{\"slot\":4}}\n");
            let (r, _) = run(vec!["roller", "home"]).await;
            assert_eq!(r.unwrap_err().to_string(), "error [unavailable]: no roller.home");
            let (r, out) = run(vec![
                "--json",
                "raw",
                r#"{"id":"x","cmd":"roller.goto","args":{"slot":"4"}}"#,
            ])
            .await;
            assert!(r.is_err());
            assert!(out.contains("\"code\":\"invalid_args\"") && out.contains("\"id\":\"x\""), "{out}");

            let (r, out) = run(vec!["raw", r#"{"cmd":"roller.goto","args":{"slot":5}}"#]).await;
            r.unwrap();
            assert_eq!(out, "slot: 5\n");
            // subscribe streams events (filtered) until the daemon goes away.
            let shared = SharedBuf::default();
            let mut sink = shared.clone();
            let sub_args = parse(&["subscribe", "roller_arrived"]);
            let sub_sock = sock.clone();
            let sub = tokio::spawn(async move { execute(&sub_args, &sub_sock, &mut sink).await });
            let text = || String::from_utf8(shared.0.lock().unwrap().clone()).unwrap();
            for _ in 0..1000 {
                if text().starts_with("subscribed") {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            events
                .send(Event::Error {
                    source: "x".into(),
                    message: "filtered out".into(),
                })
                .unwrap();
            events
                .send(Event::RollerArrived {
                    slot: 2,
                    angle_deg: 45.0,
                })
                .unwrap();
            for _ in 0..1000 {
                if text().contains("arrived") {
                    break;
                }
                tokio::time::sleep(Duration::from_millis(10)).await;
            }
            stop.notify_one();
            served.await.unwrap();
            let r = sub.await.unwrap();
            assert_eq!(
                r.unwrap_err().to_string(),
                "the daemon closed the connection"
            );
            assert_eq!(
                text(),
                "subscribed to 1 event kinds; Ctrl-C to stop\nroller    arrived at slot 2 (45.0 deg)\n"
            );
        });
    }
}
