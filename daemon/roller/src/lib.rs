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
//! The protocol itself is the sans-IO state machine [`link::RollerLink`]
//! (fed explicit time and bytes, returning [`link::Action`]s); the task is
//! wiring: it opens the port, writes the frames, reads into the link, sleeps
//! until [`link::RollerLink::poll_timeout`] and publishes events and state.
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
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

use std::path::{Path, PathBuf};
use std::time::Duration;
use telextiles_proto::roller::{self as wire, Command};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::sync::{broadcast, watch};
use tokio::task::JoinHandle;
use tokio::time::Instant;
use tokio_serial::{SerialPort, SerialPortBuilderExt, SerialPortType, SerialStream};

pub mod link;

pub use link::{Action, LinkConfig, RollerLink};
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
    // The link's clock: microseconds since the task started.
    let epoch = Instant::now();
    let now = || epoch.elapsed().as_micros() as u64;
    let mut link = RollerLink::new(LinkConfig::from(&cfg));
    let mut port: Option<SerialStream> = None;
    let mut buf = [0u8; 256];
    if let Some(t) = *target_rx.borrow_and_update() {
        link.set_target(t, now());
    }
    loop {
        while let Some(action) = link.poll() {
            match action {
                Action::Open => match open_port(&cfg) {
                    Ok((name, p)) => {
                        port = Some(p);
                        link.handle_opened(name, now());
                    }
                    Err(e) => link.handle_open_failed(e.to_string(), now()),
                },
                Action::Transmit { frame, target } => {
                    let Some(p) = port.as_mut() else { continue };
                    match p.write_all(frame.as_bytes()).await {
                        Ok(()) => {
                            if let Some(target) = target {
                                let at = std::time::Instant::now();
                                let _ = events.send(RollerEvent::TargetWritten { target, at });
                            }
                        }
                        Err(e) => link.handle_port_error(format!("write failed: {e}"), now()),
                    }
                }
                Action::Close => port = None,
                Action::Event(e) => {
                    let _ = events.send(e);
                }
            }
        }
        // Events first, then state: whoever waits on the state finds the
        // events already in the channel.
        state_tx.send_if_modified(|st| {
            let changed = st != link.state();
            if changed {
                *st = link.state().clone();
            }
            changed
        });
        let wake = link
            .poll_timeout()
            .map(|t| epoch + Duration::from_micros(t));
        tokio::select! {
            changed = target_rx.changed() => {
                if changed.is_err() {
                    return;
                }
                if let Some(t) = *target_rx.borrow_and_update() {
                    link.set_target(t, now());
                }
            }
            r = read_some(port.as_mut(), &mut buf) => match r {
                Ok(0) => link.handle_port_error("end of file on the port", now()),
                Ok(n) => link.handle_bytes(&buf[..n], now()),
                Err(e) => link.handle_port_error(format!("read failed: {e}"), now()),
            },
            _ = sleep_until(wake) => link.handle_timeout(now()),
        }
    }
}

/// Reads from the port; never completes without one.
async fn read_some(port: Option<&mut SerialStream>, buf: &mut [u8]) -> std::io::Result<usize> {
    match port {
        Some(p) => p.read(buf).await,
        None => std::future::pending().await,
    }
}

/// Sleeps until `at`; forever without one.
async fn sleep_until(at: Option<Instant>) {
    match at {
        Some(at) => tokio::time::sleep_until(at).await,
        None => std::future::pending().await,
    }
}
