//! Host-side roller driver over a serial link (tokio-serial).
//!
//! [`RollerDriver::start`] spawns a task that owns the serial port:
//!
//! * opens the port by path (a `/dev/ttyUSB0`, a `/dev/rfcomm0`, a simulator
//!   link) or auto-detects it ([`detect_port`]: ESP32 USB-UART bridges
//!   `10c4:ea60`, `1a86:7523`, `0403:6001`, or `/dev/rfcomm*`);
//! * says `Hello` and refuses a firmware speaking another protocol version
//!   (with a clear error);
//! * sends the **latest** target only: [`RollerDriver::set_target`] writes a
//!   `watch` channel, so a burst of decisions never piles up; at most one
//!   command is in flight, acknowledged or retried after
//!   [`DriverConfig::ack_timeout`];
//! * keeps the link alive with `QueryStatus` (also the firmware's watchdog
//!   feed) and reports the wheel's real position;
//! * when the port vanishes it reports [`RollerEvent::Disconnected`] with the
//!   reason, retries with exponential backoff, resynchronises the position
//!   on reconnect and re-sends the latest target, so the final target is
//!   always reached.
//!
//! Events go out on a `broadcast` channel ([`RollerDriver::subscribe`]); the
//! current state is a `watch` ([`RollerDriver::state`]).
//!
//! For demos and tests without hardware, [`SimRoller`] runs the real
//! firmware core on a pseudo-terminal in-process:
//!
//! ```no_run
//! # async fn demo() -> Result<(), Box<dyn std::error::Error>> {
//! use telextiles_roller::{DriverConfig, RollerDriver, SimConfig, SimRoller, Target};
//! let sim = SimRoller::spawn(SimConfig::default())?;
//! let roller = RollerDriver::start(DriverConfig::path(sim.path()));
//! roller.set_target(Target::Slot(5));
//! let status = roller.wait_arrived(Target::Slot(5), std::time::Duration::from_secs(5)).await?;
//! assert_eq!(status.position, 1000);
//! # Ok(()) }
//! ```
#![forbid(unsafe_code)]

use std::path::{Path, PathBuf};
use std::time::Duration;
use telextiles_proto::roller::{
    self as wire, Command, ErrorCode, FrameDecoder, Reply, PROTOCOL_VERSION,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, watch};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_serial::{SerialPort, SerialPortBuilderExt, SerialPortType, SerialStream};

pub use roller_firmware::sim::{Noise, SimConfig, SimRoller};
pub use telextiles_proto::roller::{Status, Version};

/// USB VID:PID pairs of the USB-UART bridges found on ESP32 boards.
pub const ESP32_USB_IDS: [(u16, u16); 3] = [
    (0x10c4, 0xea60), // Silicon Labs CP210x
    (0x1a86, 0x7523), // WCH CH340
    (0x0403, 0x6001), // FTDI FT232R
];

/// Where the roller is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum PortSpec {
    Path(PathBuf),
    /// First matching USB-UART bridge, else the first `/dev/rfcomm*`.
    Auto,
}

/// Driver settings.
#[derive(Clone, Debug)]
pub struct DriverConfig {
    pub port: PortSpec,
    pub baud: u32,
    /// Slot count to configure after `Hello` (`None`: keep the firmware's).
    pub slots: Option<u16>,
    /// Max speed (microsteps/s) and acceleration (microsteps/s^2) to
    /// configure after `Hello` (`None`: keep the firmware's).
    pub motion: Option<(u32, u32)>,
    /// How long to wait for the answer to a command before sending it again.
    pub ack_timeout: Duration,
    /// Sends of one command before the link is declared dead and reopened.
    pub max_tries: u32,
    /// Status poll period; also feeds the firmware's link watchdog, so keep
    /// it well below the watchdog (2 s by default).
    pub keepalive: Duration,
    /// Reconnect backoff, doubling from `min` to `max`.
    pub reconnect_min: Duration,
    pub reconnect_max: Duration,
}

impl DriverConfig {
    pub fn path(path: impl Into<PathBuf>) -> DriverConfig {
        DriverConfig {
            port: PortSpec::Path(path.into()),
            ..DriverConfig::auto()
        }
    }

    pub fn auto() -> DriverConfig {
        DriverConfig {
            port: PortSpec::Auto,
            baud: 115_200,
            slots: None,
            motion: None,
            ack_timeout: Duration::from_millis(250),
            max_tries: 4,
            keepalive: Duration::from_millis(400),
            reconnect_min: Duration::from_millis(50),
            reconnect_max: Duration::from_secs(2),
        }
    }
}

/// A wheel position to go to (the shorter way round).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Target {
    /// Slot index: angle = slot x 360 / N.
    Slot(u16),
    /// Absolute angle in millidegrees, 0..360000.
    AngleMdeg(u32),
    /// Absolute position in microsteps, 0..steps_per_rev.
    Steps(u32),
}

impl Target {
    fn command(self) -> Command {
        match self {
            Target::Slot(slot) => Command::GotoSlot { slot },
            Target::AngleMdeg(mdeg) => Command::GotoAngle {
                mdeg: mdeg % wire::FULL_TURN_MDEG,
            },
            Target::Steps(steps) => Command::GotoSteps { steps },
        }
    }

    /// The target in microsteps for a roller with this geometry.
    pub fn steps(self, slots: u16, steps_per_rev: u32) -> u32 {
        match self {
            Target::Slot(s) => wire::slot_to_steps(s, slots, steps_per_rev),
            Target::AngleMdeg(m) => wire::mdeg_to_steps(m, steps_per_rev),
            Target::Steps(s) => s % steps_per_rev.max(1),
        }
    }
}

/// What the driver reports.
#[derive(Clone, Debug, PartialEq)]
pub enum RollerEvent {
    /// Hello answered; the link is up.
    Connected { port: String, version: Version },
    /// The link went down (the reason says why); the driver keeps retrying.
    Disconnected { reason: String },
    /// The wheel's position as reported by the firmware.
    Position {
        steps: u32,
        mdeg: u32,
        slot: Option<u16>,
        moving: bool,
    },
    /// A new target's command was written to the serial port (first try;
    /// `at` is when the write completed). For latency measurements.
    TargetWritten {
        target: Target,
        at: std::time::Instant,
    },
    /// The wheel reached the latest target.
    Arrived { target: Target, status: Status },
    /// Something failed (a port that cannot be opened, a refused command,
    /// an incompatible firmware); the driver keeps going where it can.
    Error { message: String },
}

/// Snapshot of the driver's view.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RollerState {
    pub connected: bool,
    pub port: Option<String>,
    pub version: Option<Version>,
    /// Last status from the firmware.
    pub status: Option<Status>,
    /// The latest target asked for.
    pub target: Option<Target>,
    /// Set when the firmware reported arrival at `target`.
    pub arrived: Option<Target>,
    pub reconnects: u32,
}

/// Driver errors (for the waiting helpers; the task itself never gives up).
#[derive(Debug, thiserror::Error)]
pub enum RollerError {
    #[error("roller did not reach {target:?} within {timeout:?} (last status: {last:?})")]
    Timeout {
        target: Target,
        timeout: Duration,
        last: Option<Status>,
    },
    #[error("roller driver stopped")]
    Stopped,
    #[error("roller not connected within {timeout:?}")]
    NotConnected { timeout: Duration },
    #[error("no roller found: looked for USB serial bridges {ids} and /dev/rfcomm*")]
    NotFound { ids: String },
    #[error("cannot open roller port {port}: {source}")]
    Open {
        port: String,
        source: tokio_serial::Error,
    },
}

/// Handle on the driver task. Dropping it stops the task.
pub struct RollerDriver {
    target_tx: watch::Sender<Option<Target>>,
    events: broadcast::Sender<RollerEvent>,
    state: watch::Receiver<RollerState>,
    task: Option<JoinHandle<()>>,
}

impl RollerDriver {
    /// Starts the driver task on the current tokio runtime.
    pub fn start(cfg: DriverConfig) -> RollerDriver {
        let (target_tx, target_rx) = watch::channel(None);
        let (events, _) = broadcast::channel(1024);
        let (state_tx, state) = watch::channel(RollerState::default());
        let task = tokio::spawn(driver_task(cfg, target_rx, events.clone(), state_tx));
        RollerDriver {
            target_tx,
            events,
            state,
            task: Some(task),
        }
    }

    /// Asks for a new target; replaces any target not yet sent.
    pub fn set_target(&self, target: Target) {
        self.target_tx.send_replace(Some(target));
    }

    pub fn subscribe(&self) -> broadcast::Receiver<RollerEvent> {
        self.events.subscribe()
    }

    /// The current state (clone).
    pub fn state(&self) -> RollerState {
        self.state.borrow().clone()
    }

    /// A watch on the state.
    pub fn watch_state(&self) -> watch::Receiver<RollerState> {
        self.state.clone()
    }

    /// Waits until the firmware reports arrival at `target` (which must be
    /// the latest target).
    pub async fn wait_arrived(
        &self,
        target: Target,
        timeout: Duration,
    ) -> Result<Status, RollerError> {
        let mut rx = self.state.clone();
        let res = tokio::time::timeout(timeout, async {
            loop {
                {
                    let s = rx.borrow_and_update();
                    if s.arrived == Some(target) && s.target == Some(target) {
                        if let Some(st) = s.status {
                            return Ok(st);
                        }
                    }
                }
                if rx.changed().await.is_err() {
                    return Err(RollerError::Stopped);
                }
            }
        })
        .await;
        match res {
            Ok(r) => r,
            Err(_) => Err(RollerError::Timeout {
                target,
                timeout,
                last: self.state.borrow().status,
            }),
        }
    }

    /// Waits until the link is up.
    pub async fn wait_connected(&self, timeout: Duration) -> Result<Version, RollerError> {
        let mut rx = self.state.clone();
        let r = tokio::time::timeout(timeout, rx.wait_for(|s| s.connected && s.version.is_some()))
            .await;
        match r {
            Ok(Ok(s)) => s.version.ok_or(RollerError::Stopped),
            Ok(Err(_)) => Err(RollerError::Stopped),
            Err(_) => Err(RollerError::NotConnected { timeout }),
        }
    }

    /// Stops the task and closes the port.
    pub async fn shutdown(mut self) {
        if let Some(t) = self.task.take() {
            t.abort();
            let _ = t.await;
        }
    }
}

impl Drop for RollerDriver {
    fn drop(&mut self) {
        if let Some(t) = self.task.take() {
            t.abort();
        }
    }
}

/// Finds a roller: the first serial port that is an ESP32 USB-UART bridge,
/// else the first `/dev/rfcomm*` (Bluetooth SPP).
pub fn detect_port() -> Result<String, RollerError> {
    let ports = tokio_serial::available_ports().unwrap_or_default();
    let rfcomm: Vec<String> = std::fs::read_dir("/dev")
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| format!("/dev/{}", e.file_name().to_string_lossy()))
                .collect()
        })
        .unwrap_or_default();
    pick_port(&ports, &rfcomm)
}

/// The choice [`detect_port`] makes, given the serial ports the system
/// lists and the device nodes in `/dev`: USB bridges with a known VID:PID
/// first (by name), then `/dev/rfcomm*` (by name).
pub fn pick_port(
    ports: &[tokio_serial::SerialPortInfo],
    dev_nodes: &[String],
) -> Result<String, RollerError> {
    let mut usb: Vec<&str> = ports
        .iter()
        .filter(|p| match &p.port_type {
            SerialPortType::UsbPort(u) => ESP32_USB_IDS.contains(&(u.vid, u.pid)),
            _ => false,
        })
        .map(|p| p.port_name.as_str())
        .collect();
    usb.sort();
    if let Some(p) = usb.first() {
        return Ok(p.to_string());
    }
    let mut rfcomm: Vec<&String> = dev_nodes
        .iter()
        .filter(|n| n.starts_with("/dev/rfcomm"))
        .collect();
    rfcomm.sort();
    rfcomm
        .first()
        .map(|s| s.to_string())
        .ok_or_else(|| RollerError::NotFound {
            ids: ESP32_USB_IDS
                .iter()
                .map(|(v, p)| format!("{v:04x}:{p:04x}"))
                .collect::<Vec<_>>()
                .join(", "),
        })
}

fn open_port(cfg: &DriverConfig) -> Result<(String, SerialStream), RollerError> {
    let name = match &cfg.port {
        PortSpec::Path(p) => p.to_string_lossy().into_owned(),
        PortSpec::Auto => detect_port()?,
    };
    let mut port = tokio_serial::new(&name, cfg.baud)
        .open_native_async()
        .map_err(|source| RollerError::Open {
            port: name.clone(),
            source,
        })?;
    // A pseudo-terminal (the simulator) is shared with its creator.
    let real = std::fs::canonicalize(Path::new(&name)).unwrap_or_default();
    if real.starts_with("/dev/pts") {
        let _ = port.set_exclusive(false);
    }
    let _ = port.clear(tokio_serial::ClearBuffer::Input);
    Ok((name, port))
}

async fn driver_task(
    cfg: DriverConfig,
    mut target_rx: watch::Receiver<Option<Target>>,
    events: broadcast::Sender<RollerEvent>,
    state_tx: watch::Sender<RollerState>,
) {
    let mut backoff = cfg.reconnect_min;
    let mut last_open_error: Option<String> = None;
    loop {
        match open_port(&cfg) {
            Err(e) => {
                let msg = format!("{e}; retrying in {backoff:?}");
                // Report a persistent failure once, not on every retry.
                if last_open_error.as_deref() != Some(&e.to_string()) {
                    tracing::warn!("{msg}");
                    let _ = events.send(RollerEvent::Error { message: msg });
                    last_open_error = Some(e.to_string());
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(cfg.reconnect_max);
            }
            Ok((name, port)) => {
                last_open_error = None;
                let mut s = Session {
                    cfg: &cfg,
                    name: name.clone(),
                    port,
                    dec: FrameDecoder::new(),
                    seq: 0,
                    events: &events,
                    state_tx: &state_tx,
                    target_rx: &mut target_rx,
                    version: None,
                    rejected: None,
                };
                let reason = s.run(&mut backoff).await;
                state_tx.send_modify(|st| {
                    if st.connected {
                        st.reconnects += 1;
                    }
                    st.connected = false;
                });
                match reason {
                    SessionEnd::Shutdown => return,
                    SessionEnd::Lost(reason) => {
                        let reason = format!("roller link {name} lost: {reason}");
                        tracing::warn!("{reason}");
                        let _ = events.send(RollerEvent::Disconnected { reason });
                    }
                }
                tokio::time::sleep(backoff).await;
                backoff = (backoff * 2).min(cfg.reconnect_max);
            }
        }
    }
}

enum SessionEnd {
    Shutdown,
    Lost(String),
}

struct Outstanding {
    seq: u8,
    cmd: Command,
    target: Option<Target>,
    deadline: Instant,
    tries: u32,
}

struct Session<'a> {
    cfg: &'a DriverConfig,
    name: String,
    port: SerialStream,
    dec: FrameDecoder,
    seq: u8,
    events: &'a broadcast::Sender<RollerEvent>,
    state_tx: &'a watch::Sender<RollerState>,
    target_rx: &'a mut watch::Receiver<Option<Target>>,
    version: Option<Version>,
    /// A target the firmware refused (not re-sent by the resync).
    rejected: Option<Target>,
}

impl Session<'_> {
    fn next_seq(&mut self) -> u8 {
        self.seq = self.seq.wrapping_add(1);
        self.seq
    }

    async fn write(&mut self, seq: u8, cmd: &Command) -> Result<(), String> {
        let f = cmd.encode(seq);
        self.port
            .write_all(f.as_bytes())
            .await
            .map_err(|e| format!("write failed: {e}"))
    }

    /// Sends `cmd` and waits for its answer (same `SEQ`), retrying; other
    /// frames meanwhile go to `on_other`.
    async fn request(&mut self, cmd: Command) -> Result<Reply, String> {
        let seq = self.next_seq();
        for _ in 0..self.cfg.max_tries {
            self.write(seq, &cmd).await?;
            let deadline = Instant::now() + self.cfg.ack_timeout;
            loop {
                let mut buf = [0u8; 256];
                let n = match tokio::time::timeout_at(deadline, self.port.read(&mut buf)).await {
                    Err(_) => break,
                    Ok(Ok(0)) => return Err("end of file on the port".into()),
                    Ok(Ok(n)) => n,
                    Ok(Err(e)) => return Err(format!("read failed: {e}")),
                };
                let frames: Vec<_> = self.dec.feed(&buf[..n]).filter_map(Result::ok).collect();
                for f in frames {
                    if let Ok(r) = Reply::from_frame(&f) {
                        if f.seq == seq && !matches!(r, Reply::Arrived(_)) {
                            return Ok(r);
                        }
                    }
                }
            }
        }
        Err(format!(
            "no answer to {cmd:?} after {} tries of {:?}",
            self.cfg.max_tries, self.cfg.ack_timeout
        ))
    }

    fn position_event(&self, s: &Status) {
        let (slots, spr) = self
            .version
            .map(|v| (s.slots.max(1), v.steps_per_rev))
            .unwrap_or((s.slots.max(1), 3200));
        let _ = self.events.send(RollerEvent::Position {
            steps: s.position,
            mdeg: wire::steps_to_mdeg(s.position, spr),
            slot: wire::steps_to_slot(s.position, slots, spr),
            moving: s.moving(),
        });
        let st = *s;
        self.state_tx.send_modify(|x| x.status = Some(st));
    }

    async fn run(&mut self, backoff: &mut Duration) -> SessionEnd {
        // Hello and version check.
        let version = match self
            .request(Command::Hello {
                protocol: PROTOCOL_VERSION,
            })
            .await
        {
            Ok(Reply::Version(v)) => v,
            Ok(other) => return SessionEnd::Lost(format!("unexpected answer to Hello: {other:?}")),
            Err(e) => return SessionEnd::Lost(e),
        };
        if version.protocol != PROTOCOL_VERSION {
            let message = format!(
                "roller on {} speaks protocol {} (firmware {}.{}.{}); this driver speaks {PROTOCOL_VERSION}: update the firmware",
                self.name,
                version.protocol,
                version.firmware[0],
                version.firmware[1],
                version.firmware[2]
            );
            let _ = self.events.send(RollerEvent::Error {
                message: message.clone(),
            });
            return SessionEnd::Lost(message);
        }
        self.version = Some(version);
        if let Some(slots) = self.cfg.slots {
            match self.request(Command::SetSlots { slots }).await {
                Ok(Reply::Ack(_)) => {}
                Ok(Reply::Error { code, .. }) => {
                    self.error(format!("roller refused {slots} slots: {code}"))
                }
                Ok(other) => return SessionEnd::Lost(format!("unexpected answer: {other:?}")),
                Err(e) => return SessionEnd::Lost(e),
            }
        }
        if let Some((max_speed, accel)) = self.cfg.motion {
            match self.request(Command::SetMotion { max_speed, accel }).await {
                Ok(Reply::Ack(_)) => {}
                Ok(Reply::Error { code, .. }) => self.error(format!(
                    "roller refused speed {max_speed}/s, acceleration {accel}/s^2: {code}"
                )),
                Ok(other) => return SessionEnd::Lost(format!("unexpected answer: {other:?}")),
                Err(e) => return SessionEnd::Lost(e),
            }
        }
        // Position resync.
        let status = match self.request(Command::QueryStatus).await {
            Ok(Reply::Status(s)) => s,
            Ok(other) => return SessionEnd::Lost(format!("unexpected answer: {other:?}")),
            Err(e) => return SessionEnd::Lost(e),
        };
        let version = Version {
            slots: self.cfg.slots.unwrap_or(version.slots),
            ..version
        };
        self.version = Some(version);
        *backoff = self.cfg.reconnect_min;
        self.state_tx.send_modify(|st| {
            st.connected = true;
            st.port = Some(self.name.clone());
            st.version = Some(version);
        });
        tracing::info!(
            "roller on {}: firmware {:?}, {} slots, {} steps/rev",
            self.name,
            version.firmware,
            version.slots,
            version.steps_per_rev
        );
        let _ = self.events.send(RollerEvent::Connected {
            port: self.name.clone(),
            version,
        });
        self.position_event(&status);
        self.main_loop().await
    }

    fn error(&self, message: String) {
        tracing::warn!("{message}");
        let _ = self.events.send(RollerEvent::Error { message });
    }

    async fn main_loop(&mut self) -> SessionEnd {
        // The target the firmware acknowledged (and the SEQ it acknowledged),
        // or rejected (then it is not re-sent until a new target comes).
        let mut sent: Option<(Target, u8)> = None;
        let mut outstanding: Option<Outstanding> = None;
        let mut next_keepalive = Instant::now() + self.cfg.keepalive;
        let mut buf = [0u8; 256];
        loop {
            // Send what is due: the latest target first, else a keepalive.
            if outstanding.is_none() {
                let latest = *self.target_rx.borrow_and_update();
                self.state_tx.send_if_modified(|st| {
                    let changed = st.target != latest;
                    st.target = latest;
                    changed
                });
                let cmd = match latest {
                    Some(t) if sent.map(|s| s.0) != Some(t) => {
                        self.state_tx.send_if_modified(|st| {
                            let changed = st.arrived.is_some();
                            st.arrived = None;
                            changed
                        });
                        Some((t.command(), Some(t)))
                    }
                    _ if Instant::now() >= next_keepalive => Some((Command::QueryStatus, None)),
                    _ => None,
                };
                if let Some((cmd, target)) = cmd {
                    let seq = self.next_seq();
                    if let Err(e) = self.write(seq, &cmd).await {
                        return SessionEnd::Lost(e);
                    }
                    if let Some(target) = target {
                        let _ = self.events.send(RollerEvent::TargetWritten {
                            target,
                            at: std::time::Instant::now(),
                        });
                    }
                    next_keepalive = Instant::now() + self.cfg.keepalive;
                    outstanding = Some(Outstanding {
                        seq,
                        cmd,
                        target,
                        deadline: Instant::now() + self.cfg.ack_timeout,
                        tries: 1,
                    });
                }
            }
            let wake = outstanding
                .as_ref()
                .map(|o| o.deadline)
                .unwrap_or(next_keepalive);
            tokio::select! {
                changed = self.target_rx.changed(), if outstanding.is_none() => {
                    if changed.is_err() {
                        return SessionEnd::Shutdown;
                    }
                }
                r = self.port.read(&mut buf) => {
                    let n = match r {
                        Ok(0) => return SessionEnd::Lost("end of file on the port".into()),
                        Ok(n) => n,
                        Err(e) => return SessionEnd::Lost(format!("read failed: {e}")),
                    };
                    let frames: Vec<_> = self.dec.feed(&buf[..n]).collect();
                    for f in frames {
                        let Ok(f) = f else {
                            tracing::debug!("roller: dropped a corrupted frame");
                            continue;
                        };
                        let Ok(reply) = Reply::from_frame(&f) else {
                            continue;
                        };
                        self.on_reply(f.seq, reply, &mut outstanding, &mut sent);
                    }
                }
                _ = tokio::time::sleep_until(wake) => {
                    if let Some(o) = outstanding.as_mut() {
                        if Instant::now() >= o.deadline {
                            if o.tries >= self.cfg.max_tries {
                                return SessionEnd::Lost(format!(
                                    "no answer to {:?} after {} tries of {:?}",
                                    o.cmd, o.tries, self.cfg.ack_timeout
                                ));
                            }
                            o.tries += 1;
                            o.deadline = Instant::now() + self.cfg.ack_timeout;
                            let (seq, cmd) = (o.seq, o.cmd);
                            tracing::debug!("roller: resending {cmd:?} (seq {seq})");
                            if let Err(e) = self.write(seq, &cmd).await {
                                return SessionEnd::Lost(e);
                            }
                        }
                    }
                }
            }
        }
    }

    /// Records arrival at `t` (once), if `t` is still the latest target.
    fn mark_arrived(&self, t: Target, s: Status) {
        if *self.target_rx.borrow() != Some(t) {
            return;
        }
        if self.state_tx.borrow().arrived == Some(t) {
            return;
        }
        // Event first, then state: whoever waits on the state finds the
        // event already in the channel.
        let _ = self.events.send(RollerEvent::Arrived {
            target: t,
            status: s,
        });
        self.state_tx.send_modify(|st| {
            st.arrived = Some(t);
            st.status = Some(s);
        });
    }

    fn on_reply(
        &mut self,
        seq: u8,
        reply: Reply,
        outstanding: &mut Option<Outstanding>,
        sent: &mut Option<(Target, u8)>,
    ) {
        let answers = outstanding.as_ref().is_some_and(|o| o.seq == seq);
        match reply {
            Reply::Ack(s) | Reply::Status(s) => {
                if answers
                    && !matches!(reply, Reply::Status(_) if outstanding.as_ref().is_some_and(|o| o.cmd != Command::QueryStatus))
                {
                    let o = outstanding.take().expect("answers implies outstanding");
                    if let Some(t) = o.target {
                        *sent = Some((t, seq));
                    }
                    // Resync: a firmware whose target is not ours (it was
                    // restarted, or its watchdog stopped it) gets ours again.
                    if o.cmd == Command::QueryStatus {
                        if let (Some((t, _)), Some(v)) = (*sent, self.version) {
                            let arrived = self.state_tx.borrow().arrived == Some(t);
                            let want = t.steps(s.slots, v.steps_per_rev);
                            let off_course = s.target != want
                                || (!s.moving() && s.position != want)
                                || (s.watchdog_tripped() && !arrived);
                            if off_course && self.rejected != Some(t) {
                                tracing::info!(
                                    "roller: target lost on the firmware, re-sending {t:?}"
                                );
                                *sent = None;
                            }
                        }
                    }
                }
                self.position_event(&s);
                // The status is authoritative: at rest on our target is
                // arrived, even if the Arrived frame itself was lost.
                if let (Some((t, _)), Some(v)) = (*sent, self.version) {
                    let want = t.steps(s.slots, v.steps_per_rev);
                    if !s.moving() && s.position == want && s.target == want {
                        self.mark_arrived(t, s);
                    }
                }
            }
            Reply::Arrived(s) => {
                self.position_event(&s);
                if let Some((t, acked_seq)) = *sent {
                    if acked_seq == seq {
                        self.mark_arrived(t, s);
                    }
                }
            }
            Reply::Error { code, command } => {
                if answers {
                    let o = outstanding.take().expect("answers implies outstanding");
                    if let Some(t) = o.target {
                        // Do not re-send a target the firmware refuses.
                        *sent = Some((t, seq));
                        self.rejected = Some(t);
                    }
                    self.error(format!(
                        "roller refused {:?} (kind {command:#04x}): {code}{}",
                        o.cmd,
                        if code == ErrorCode::BadArgument {
                            " (check the slot count and the target)"
                        } else {
                            ""
                        }
                    ));
                }
            }
            Reply::Version(_) => {}
        }
    }
}
