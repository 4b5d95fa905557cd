//! The daemon's configuration: a TOML file, environment variables and
//! command-line flags, merged with the precedence
//! **flag > environment (`TELEXTILESD_*`) > file > default**.
//!
//! Every file key `foo_bar` is also the flag `--foo-bar` and the variable
//! `TELEXTILESD_FOO_BAR` (see [`KEYS`]; a test checks all three exist).
//! The file is `$XDG_CONFIG_HOME/telextiles/telextilesd.toml` (or
//! `~/.config/...`; `/etc/telextiles/telextilesd.toml` in system mode), or
//! the one named by `--config` / `TELEXTILESD_CONFIG`. Unknown keys are an
//! error naming the key. Documented in `docs/configuration.md`.
//!
//! Environment lookups go through an injectable function so resolution is
//! deterministic in tests; clap parses only the flags.

// Parts of the public surface (socket_spec, to_toml, KEYS) are for the
// daemon's `run` wiring; until it lands they are unused in the binary.
#![allow(dead_code)]

use clap::builder::BoolishValueParser;
use serde::Deserialize;
use std::ffi::OsString;
use std::fmt;
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use telextiles_recording::profile::{Mode, SensorProfile};

/// Prefix of every environment variable.
pub const ENV_PREFIX: &str = "TELEXTILESD_";

/// Every configuration key (file key; flag = `--` + key with `-`; env =
/// `TELEXTILESD_` + uppercase key).
pub const KEYS: &[&str] = &[
    "name",
    "state_dir",
    "data_dir",
    "runtime_dir",
    "socket",
    "system",
    "group",
    "sensor",
    "sensor_profile",
    "sensor_mm_per_px",
    "sensor_mode",
    "reference",
    "replay_fps",
    "contact_enter",
    "contact_frames",
    "contact_tile",
    "commit_margin",
    "encode_run",
    "motion",
    "model",
    "index",
    "roller",
    "listen",
    "connect",
    "relay",
    "relay_cert",
    "mdns",
    "mdns_allow",
    "mdns_deny",
    "map",
    "map_bind",
    "log",
];

impl Config {
    /// The contact detector these settings ask for.
    pub fn contact(&self) -> telextiles_sensing::contact::ContactConfig {
        // Checked when the configuration was resolved.
        telextiles_sensing::contact::ContactConfig::with_entry(
            self.contact_enter,
            self.contact_frames,
        )
        .and_then(|c| c.with_tile(self.contact_tile))
        .unwrap_or_default()
    }

    /// The decider these settings ask for (on presses this daemon
    /// receives): the shipped one with `commit_margin`.
    pub fn decide(&self) -> telextiles_sensing::decide::DecideConfig {
        decide_with(self.commit_margin)
    }
}

/// The shipped decider with this commit margin: the daemon's and
/// `classify`'s, from one place.
fn decide_with(commit_margin: f32) -> telextiles_sensing::decide::DecideConfig {
    telextiles_sensing::decide::DecideConfig {
        commit_margin,
        ..Default::default()
    }
}

/// The decision-speed settings for `classify`, as the daemons take them
/// from their configuration (`commit_margin` on the receiving daemon,
/// `encode_run` on the sending one): give the same as to the daemons, so
/// that replayed presses are decided as a live pair decides them.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct DecisionArgs {
    /// The decider's commit margin, as the receiving daemon's
    /// `commit_margin` (0 to 2; lower decides sooner and is wrong more
    /// often) [default: 0.08]
    #[arg(long, value_name = "DISTANCE", value_parser = parse_commit_margin)]
    pub commit_margin: Option<f32>,
    /// Also encode the frames of the run that starts a press, as the
    /// sending daemon's `encode_run` [default: false]
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true", value_parser = BoolishValueParser::new(), value_name = "BOOL")]
    pub encode_run: Option<bool>,
}

impl DecisionArgs {
    /// The pipeline these settings and `contact` ask for: the daemons'
    /// decider and front end with the same settings.
    pub fn pipeline(
        &self,
        contact: telextiles_sensing::contact::ContactConfig,
    ) -> telextiles_sensing::pipeline::PipelineConfig {
        let shipped = telextiles_sensing::decide::DecideConfig::default();
        telextiles_sensing::pipeline::PipelineConfig {
            contact,
            decide: decide_with(self.commit_margin.unwrap_or(shipped.commit_margin)),
            encode_run: self.encode_run.unwrap_or(false),
        }
    }
}

/// The contact detector's settings for the offline tools (`record`,
/// `classify`, `index build`, `index check`), as the daemon takes them from
/// its configuration (`contact_enter`, `contact_frames`, `contact_tile`):
/// give the same to both, so that presses are cut as the live session cuts
/// them.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct ContactArgs {
    /// Contact detector: score above the noise floor (grey levels) at which
    /// a frame counts towards a press, as the daemon's `contact_enter`
    /// [default: 0.35]
    #[arg(long, value_name = "SCORE", value_parser = parse_contact_enter)]
    pub contact_enter: Option<f32>,
    /// Contact detector: frames in a row over it that start a press, as
    /// the daemon's `contact_frames` [default: 2]
    #[arg(long, value_name = "N", value_parser = parse_contact_frames)]
    pub contact_frames: Option<u32>,
    /// Contact detector: score the most changed tile of N x N blocks of
    /// 4 px instead of the whole frame (0), as the daemon's `contact_tile`
    /// [default: 0]
    #[arg(long, value_name = "N", value_parser = parse_contact_tile)]
    pub contact_tile: Option<u32>,
}

impl ContactArgs {
    /// The contact detector asked for (the shipped one by default).
    pub fn contact(&self) -> anyhow::Result<telextiles_sensing::contact::ContactConfig> {
        let shipped = telextiles_sensing::contact::ContactConfig::default();
        telextiles_sensing::contact::ContactConfig::with_entry(
            self.contact_enter.unwrap_or(shipped.enter),
            self.contact_frames.unwrap_or(shipped.min_enter_frames),
        )
        .and_then(|c| c.with_tile(self.contact_tile.unwrap_or(shipped.tile)))
        .map_err(anyhow::Error::msg)
    }
}

/// Default QUIC listen address.
pub const DEFAULT_LISTEN: &str = "[::]:47800";
/// Default map (HTTP) bind address: loopback only.
pub const DEFAULT_MAP_BIND: &str = "127.0.0.1:47880";

/// Where frames come from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SensorSource {
    /// A DIGIT sensor over V4L2; `serial` picks one (e.g. `D20001`), else the first found.
    Digit { serial: Option<String> },
    /// A camera of the configured sensor profile over V4L2 (`sensor_profile`;
    /// a GelSight Mini, a generic UVC camera); `select` picks one by serial,
    /// device node or kernel name, else the first found.
    Camera { select: Option<String> },
    /// The built-in simulator, pressing `textile` (e.g. `T012`) or cycling through the catalogue.
    Sim { textile: Option<String> },
    /// Recorded presses from a directory.
    Replay { dir: PathBuf },
}

impl FromStr for SensorSource {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        let (kind, rest) = match s.split_once(':') {
            Some((k, r)) => (k, Some(r)),
            None => (s, None),
        };
        let nonempty = |r: Option<&str>| r.filter(|r| !r.is_empty()).map(str::to_string);
        match kind {
            "digit" => Ok(SensorSource::Digit {
                serial: nonempty(rest),
            }),
            "sim" => Ok(SensorSource::Sim {
                textile: nonempty(rest),
            }),
            "camera" => Ok(SensorSource::Camera {
                select: nonempty(rest),
            }),
            "replay" => match nonempty(rest) {
                Some(d) => Ok(SensorSource::Replay { dir: d.into() }),
                None => Err("`replay` needs a directory: replay:<dir>".into()),
            },
            _ => Err(format!(
                "unknown sensor source `{s}`; expected digit[:serial], camera[:serial|/dev/videoN], sim[:textile] or replay:<dir>"
            )),
        }
    }
}

impl fmt::Display for SensorSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SensorSource::Digit { serial: None } => f.write_str("digit"),
            SensorSource::Digit { serial: Some(s) } => write!(f, "digit:{s}"),
            SensorSource::Camera { select: None } => f.write_str("camera"),
            SensorSource::Camera { select: Some(s) } => write!(f, "camera:{s}"),
            SensorSource::Sim { textile: None } => f.write_str("sim"),
            SensorSource::Sim { textile: Some(t) } => write!(f, "sim:{t}"),
            SensorSource::Replay { dir } => write!(f, "replay:{}", dir.display()),
        }
    }
}

/// Which roller to drive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RollerSource {
    /// Find the roller among serial ports.
    Auto,
    /// The host simulator (firmware core on a pseudo-terminal).
    Sim,
    /// No roller (a sender-only daemon).
    None,
    /// This serial device, e.g. `/dev/ttyUSB0`.
    Path(PathBuf),
}

impl FromStr for RollerSource {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "auto" => Ok(RollerSource::Auto),
            "sim" => Ok(RollerSource::Sim),
            "none" => Ok(RollerSource::None),
            p if p.contains('/') => Ok(RollerSource::Path(p.into())),
            _ => Err(format!(
                "unknown roller `{s}`; expected auto, sim, none or a serial device path like /dev/ttyUSB0"
            )),
        }
    }
}

impl fmt::Display for RollerSource {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RollerSource::Auto => f.write_str("auto"),
            RollerSource::Sim => f.write_str("sim"),
            RollerSource::None => f.write_str("none"),
            RollerSource::Path(p) => write!(f, "{}", p.display()),
        }
    }
}

/// Configuration flags (flatten into a subcommand with `#[command(flatten)]`).
/// Each flag can also be set by its environment variable or in the file.
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
#[command(next_help_heading = "Configuration (flag > TELEXTILESD_* env > file > default)")]
pub struct ConfigArgs {
    /// Config file [env: TELEXTILESD_CONFIG] [default: $XDG_CONFIG_HOME/telextiles/telextilesd.toml]
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// This daemon's name shown to peers [env: TELEXTILESD_NAME] [default: host name]
    #[arg(long)]
    pub name: Option<String>,
    /// Identity, trust store, calibration [env: TELEXTILESD_STATE_DIR] [default: $XDG_STATE_HOME/telextiles]
    #[arg(long, value_name = "DIR")]
    pub state_dir: Option<PathBuf>,
    /// Model and index [env: TELEXTILESD_DATA_DIR] [default: $XDG_DATA_HOME/telextiles]
    #[arg(long, value_name = "DIR")]
    pub data_dir: Option<PathBuf>,
    /// Runtime directory holding the control socket [env: TELEXTILESD_RUNTIME_DIR] [default: $XDG_RUNTIME_DIR/telextilesd]
    #[arg(long, value_name = "DIR")]
    pub runtime_dir: Option<PathBuf>,
    /// Control socket path [env: TELEXTILESD_SOCKET] [default: <runtime_dir>/control.sock]
    #[arg(long, value_name = "PATH")]
    pub socket: Option<PathBuf>,
    /// System-wide mode: /etc, /var/lib, /run/telextilesd, group-shared socket [env: TELEXTILESD_SYSTEM]
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true", value_parser = BoolishValueParser::new(), value_name = "BOOL")]
    pub system: Option<bool>,
    /// Group allowed on the system-wide socket [env: TELEXTILESD_GROUP] [default: telextiles]
    #[arg(long)]
    pub group: Option<String>,
    /// Frame source: digit[:serial] | camera[:serial|/dev/videoN] | sim[:textile] | replay:<dir> [env: TELEXTILESD_SENSOR] [default: digit]
    #[arg(long, value_name = "SOURCE")]
    pub sensor: Option<SensorSource>,
    /// Sensor profile of the frames (docs/sensors.md): digit, gelsight-mini or uvc [env: TELEXTILESD_SENSOR_PROFILE] [default: a camera's is found from its USB ids and name, recordings say their own, else digit]
    #[arg(long, value_name = "PROFILE", value_parser = parse_profile)]
    pub sensor_profile: Option<&'static SensorProfile>,
    /// Millimetres per pixel of the sensor's images in the mode it streams (a uvc camera needs it; others know theirs) [env: TELEXTILESD_SENSOR_MM_PER_PX]
    #[arg(long, value_name = "MM", value_parser = parse_mm_per_px)]
    pub sensor_mm_per_px: Option<f32>,
    /// Camera mode to ask for, WIDTHxHEIGHT@FPS, e.g. 640x480@30 [env: TELEXTILESD_SENSOR_MODE] [default: the profile's first the camera offers]
    #[arg(long, value_name = "MODE")]
    pub sensor_mode: Option<Mode>,
    /// No-contact frame for replayed recordings that carry none (PyTouch data cut to contact): PNG for every sensor, SERIAL=PNG for one; repeat it (comma-separate in the env) [env: TELEXTILESD_REFERENCE]
    #[arg(long, value_name = "[SERIAL=]PNG")]
    pub reference: Option<Vec<String>>,
    /// Frame rate of replayed recordings saved without timestamps (PyTouch data) [env: TELEXTILESD_REPLAY_FPS] [default: the DIGIT's stream rate at the frames' size: 60 fps QVGA, 30 VGA]
    #[arg(long, value_name = "FPS", value_parser = telextiles_recording::recording::parse_fps)]
    pub replay_fps: Option<f32>,
    /// Contact detector: score above the noise floor (grey levels) at which a frame counts towards a press; raise it if `record --idle` finds presses on your resting sensor [env: TELEXTILESD_CONTACT_ENTER] [default: 0.35]
    #[arg(long, value_name = "SCORE", value_parser = parse_contact_enter)]
    pub contact_enter: Option<f32>,
    /// Contact detector: frames in a row over contact_enter that start a press [env: TELEXTILESD_CONTACT_FRAMES] [default: 2]
    #[arg(long, value_name = "N", value_parser = parse_contact_frames)]
    pub contact_frames: Option<u32>,
    /// Contact detector: score the most changed tile of N x N blocks of 4 px instead of the whole frame (0); decides steady presses sooner, tilted hand-held ones less reliably (docs/configuration.md); raise contact_enter with it [env: TELEXTILESD_CONTACT_TILE] [default: 0]
    #[arg(long, value_name = "N", value_parser = parse_contact_tile)]
    pub contact_tile: Option<u32>,
    /// Decisions on presses this daemon receives: the first decision commits on the leader's second frame when it leads the runner-up by this distance (0 to 2; lower decides sooner and is wrong more often; docs/configuration.md) [env: TELEXTILESD_COMMIT_MARGIN] [default: 0.08]
    #[arg(long, value_name = "DISTANCE", value_parser = parse_commit_margin)]
    pub commit_margin: Option<f32>,
    /// Presses this daemon senses: also encode the frames of the run that starts a press, so the peer's decider counts from the first frame over the threshold (sooner; first decisions right less often on hand-held presses; docs/configuration.md) [env: TELEXTILESD_ENCODE_RUN] [default: false]
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true", value_parser = BoolishValueParser::new(), value_name = "BOOL")]
    pub encode_run: Option<bool>,
    /// Presses this daemon receives: when the roller moves during a press: `every` decision, once `confident[:CONFIDENCE[:HOLD_MS]]`, or `lead[:LEAD_MS]` (set off towards the leading textile before the first decision); every press ends at its final decision (docs/studies/2026-12-04-felt-latency.md) [env: TELEXTILESD_MOTION] [default: every]
    #[arg(long, value_name = "POLICY", value_parser = parse_motion)]
    pub motion: Option<telextiles_session::MotionPolicy>,
    /// Encoder ONNX model [env: TELEXTILESD_MODEL] [default: <data_dir>/encoder.onnx]
    #[arg(long, value_name = "FILE")]
    pub model: Option<PathBuf>,
    /// Textile index [env: TELEXTILESD_INDEX] [default: <data_dir>/index.tlxi]
    #[arg(long, value_name = "FILE")]
    pub index: Option<PathBuf>,
    /// Roller: auto | sim | none | serial device path [env: TELEXTILESD_ROLLER] [default: auto]
    #[arg(long, value_name = "ROLLER")]
    pub roller: Option<RollerSource>,
    /// QUIC listen address [env: TELEXTILESD_LISTEN] [default: [::]:47800]
    #[arg(long, value_name = "ADDR:PORT")]
    pub listen: Option<SocketAddr>,
    /// Peers to dial besides mDNS, by key (`telextilesd id` prints it): KEY@HOST:PORT, or KEY alone through the relay (repeat or comma-separate) [env: TELEXTILESD_CONNECT]
    #[arg(long, value_name = "KEY@HOST:PORT", value_delimiter = ',')]
    pub connect: Option<Vec<String>>,
    /// Relay to meet peers through beyond the LAN, https://HOST:PORT (`telextilesd relay` prints it; its UDP port of the same number serves address discovery) [env: TELEXTILESD_RELAY] [default: none]
    #[arg(long, value_name = "URL")]
    pub relay: Option<String>,
    /// The relay's self-signed certificate to pin (PEM) [env: TELEXTILESD_RELAY_CERT] [default: a certificate from a public CA]
    #[arg(long, value_name = "FILE")]
    pub relay_cert: Option<PathBuf>,
    /// mDNS discovery on/off [env: TELEXTILESD_MDNS] [default: true]
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true", value_parser = BoolishValueParser::new(), value_name = "BOOL")]
    pub mdns: Option<bool>,
    /// Only these interfaces for mDNS (repeat or comma-separate) [env: TELEXTILESD_MDNS_ALLOW] [default: all]
    #[arg(long, value_name = "IFACE", value_delimiter = ',')]
    pub mdns_allow: Option<Vec<String>>,
    /// Never these interfaces for mDNS [env: TELEXTILESD_MDNS_DENY]
    #[arg(long, value_name = "IFACE", value_delimiter = ',')]
    pub mdns_deny: Option<Vec<String>>,
    /// Serve the 2D textile map over HTTP [env: TELEXTILESD_MAP] [default: false]
    #[arg(long, num_args = 0..=1, require_equals = true, default_missing_value = "true", value_parser = BoolishValueParser::new(), value_name = "BOOL")]
    pub map: Option<bool>,
    /// Map HTTP bind address [env: TELEXTILESD_MAP_BIND] [default: 127.0.0.1:47880]
    #[arg(long, value_name = "ADDR:PORT")]
    pub map_bind: Option<SocketAddr>,
    /// Log filter (tracing EnvFilter syntax) [env: TELEXTILESD_LOG, then RUST_LOG] [default: info]
    #[arg(long, value_name = "FILTER")]
    pub log: Option<String>,
}

/// The file's shape: every key optional, unknown keys rejected.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileConfig {
    name: Option<String>,
    state_dir: Option<PathBuf>,
    data_dir: Option<PathBuf>,
    runtime_dir: Option<PathBuf>,
    socket: Option<PathBuf>,
    system: Option<bool>,
    group: Option<String>,
    sensor: Option<String>,
    sensor_profile: Option<String>,
    sensor_mm_per_px: Option<f32>,
    sensor_mode: Option<String>,
    reference: Option<Vec<String>>,
    replay_fps: Option<f32>,
    contact_enter: Option<f32>,
    contact_frames: Option<u32>,
    contact_tile: Option<u32>,
    commit_margin: Option<f32>,
    encode_run: Option<bool>,
    motion: Option<String>,
    model: Option<PathBuf>,
    index: Option<PathBuf>,
    roller: Option<String>,
    listen: Option<SocketAddr>,
    connect: Option<Vec<String>>,
    relay: Option<String>,
    relay_cert: Option<PathBuf>,
    mdns: Option<bool>,
    mdns_allow: Option<Vec<String>>,
    mdns_deny: Option<Vec<String>>,
    map: Option<bool>,
    map_bind: Option<SocketAddr>,
    log: Option<String>,
}

/// The resolved configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Config {
    /// The file that was read, if any.
    pub config_file: Option<PathBuf>,
    pub name: String,
    pub state_dir: PathBuf,
    pub data_dir: PathBuf,
    pub runtime_dir: PathBuf,
    pub socket: PathBuf,
    pub system: bool,
    pub group: String,
    pub sensor: SensorSource,
    /// The sensor profile given (None: found or recorded, else a DIGIT).
    pub sensor_profile: Option<&'static SensorProfile>,
    /// Millimetres per pixel of its images, if given.
    pub sensor_mm_per_px: Option<f32>,
    /// The camera mode asked for, if any.
    pub sensor_mode: Option<Mode>,
    /// `[SERIAL=]PNG` no-contact frames for `sensor = replay:<dir>`
    /// (`telextiles_sensing::front::References::from_args`); paths from
    /// the file are already joined to the file's directory.
    pub reference: Vec<String>,
    /// Frame rate of replayed recordings saved without timestamps (None:
    /// by their frames' size, `telextiles_recording::recording::default_fps`).
    pub replay_fps: Option<f32>,
    /// The contact detector's entry threshold (`ContactConfig::with_entry`).
    pub contact_enter: f32,
    /// Frames in a row over it that start a press.
    pub contact_frames: u32,
    /// Blocks a side of the tile the detector scores (0: the whole frame).
    pub contact_tile: u32,
    /// The receiving decider's `DecideConfig::commit_margin`.
    pub commit_margin: f32,
    /// The sending front end encodes the run that starts a press
    /// (`FrontEnd::set_encode_run`).
    pub encode_run: bool,
    /// When the roller moves during a received press.
    pub motion: telextiles_session::MotionPolicy,
    pub model: PathBuf,
    pub index: PathBuf,
    pub roller: RollerSource,
    pub listen: SocketAddr,
    pub connect: Vec<String>,
    /// The relay's URL, checked (`https://HOST[:PORT]`).
    pub relay: Option<String>,
    /// Its pinned certificate (only with `relay`).
    pub relay_cert: Option<PathBuf>,
    pub mdns: bool,
    pub mdns_allow: Vec<String>,
    pub mdns_deny: Vec<String>,
    pub map: bool,
    pub map_bind: SocketAddr,
    pub log: String,
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("invalid config file {path}: {message}")]
    File { path: PathBuf, message: String },
    #[error("invalid environment variable {var}={value:?}: {message}")]
    Env {
        var: String,
        value: String,
        message: String,
    },
    #[error("{0}")]
    Invalid(String),
}

/// Creates `dir` (and missing parents) with mode 0700 from the start, so a
/// state directory holding the private key is never readable by others,
/// whatever the umask. An existing directory is left as it is.
pub fn create_private_dir(dir: &Path) -> std::io::Result<()> {
    use std::os::unix::fs::DirBuilderExt;
    std::fs::DirBuilder::new()
        .recursive(true)
        .mode(0o700)
        .create(dir)
}

/// Looks up an environment variable (injectable for tests).
pub type EnvLookup<'a> = &'a dyn Fn(&str) -> Option<OsString>;

/// The process environment.
pub fn process_env(key: &str) -> Option<OsString> {
    std::env::var_os(key)
}

impl Config {
    /// Resolves from flags, the process environment and the file.
    pub fn load(args: &ConfigArgs) -> Result<Config, ConfigError> {
        Self::resolve(args, &process_env)
    }

    /// Resolves with an explicit environment.
    pub fn resolve(args: &ConfigArgs, env: EnvLookup<'_>) -> Result<Config, ConfigError> {
        let e = Env(env);
        let system = args
            .system
            .or(e.get("SYSTEM", parse_bool)?)
            .unwrap_or(false);
        // The file: explicit (must exist) or default (may be absent).
        let explicit = args.config.clone().or(e.get("CONFIG", parse_path)?);
        let (file_path, must_exist) = match explicit {
            Some(p) => (Some(p), true),
            None => (default_config_file(system, &e), false),
        };
        let mut file = FileConfig::default();
        let mut file_dir = PathBuf::new();
        let mut config_file = None;
        if let Some(path) = file_path {
            match std::fs::read_to_string(&path) {
                Ok(text) => {
                    file = toml::from_str(&text).map_err(|err| ConfigError::File {
                        path: path.clone(),
                        message: err.to_string().trim_end().to_string(),
                    })?;
                    file_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
                    config_file = Some(path);
                }
                Err(err) if !must_exist && err.kind() == std::io::ErrorKind::NotFound => {}
                Err(source) => return Err(ConfigError::Read { path, source }),
            }
        }
        let l = Layers {
            env: &e,
            file_path: config_file.as_deref(),
            file_dir: &file_dir,
        };

        // `system` from the file also counts (flag/env already decided above if given).
        let system = l
            .get("system", args.system, parse_bool, file.system)?
            .unwrap_or(system);

        let name = match l.get("name", args.name.clone(), parse_string, file.name)? {
            Some(n) if n.trim().is_empty() => {
                return Err(ConfigError::Invalid("`name` must not be empty".into()))
            }
            Some(n) => n,
            None => default_name(),
        };
        let state_dir = match l.path("state_dir", args.state_dir.clone(), file.state_dir)? {
            Some(p) => p,
            None if system => PathBuf::from("/var/lib/telextilesd"),
            None => xdg_dir(&e, "XDG_STATE_HOME", ".local/state", "state_dir")?.join("telextiles"),
        };
        let data_dir = match l.path("data_dir", args.data_dir.clone(), file.data_dir)? {
            Some(p) => p,
            None if system => PathBuf::from("/usr/share/telextiles"),
            None => xdg_dir(&e, "XDG_DATA_HOME", ".local/share", "data_dir")?.join("telextiles"),
        };
        let socket_given = l.path("socket", args.socket.clone(), file.socket)?;
        let runtime_dir = match l.path("runtime_dir", args.runtime_dir.clone(), file.runtime_dir)? {
            Some(p) => p,
            None if system => PathBuf::from(telextiles_control::socket::SYSTEM_DIR),
            None => match e.raw("XDG_RUNTIME_DIR") {
                Some(rt) => PathBuf::from(rt).join(telextiles_control::socket::USER_DIR_NAME),
                None => match &socket_given {
                    // Only the socket lives in the runtime dir; its parent will do.
                    Some(s) => s.parent().map(Path::to_path_buf).unwrap_or_default(),
                    None => {
                        return Err(ConfigError::Invalid(
                            "XDG_RUNTIME_DIR is not set, so there is no per-user runtime directory for the control socket; set it, or pass --runtime-dir DIR or --socket PATH, or use --system".into(),
                        ))
                    }
                },
            },
        };
        let socket = socket_given
            .unwrap_or_else(|| runtime_dir.join(telextiles_control::socket::SOCKET_NAME));
        let group = l
            .get("group", args.group.clone(), parse_string, file.group)?
            .unwrap_or_else(|| telextiles_control::socket::DEFAULT_GROUP.to_string());
        let sensor = l
            .checked(
                "sensor",
                args.sensor.clone(),
                parse_from_str,
                file.sensor,
                |s| {
                    Ok(match s.parse::<SensorSource>()? {
                        SensorSource::Replay { dir } => SensorSource::Replay {
                            dir: file_dir.join(dir),
                        },
                        other => other,
                    })
                },
            )?
            .unwrap_or(SensorSource::Digit { serial: None });
        let sensor_profile = l.checked(
            "sensor_profile",
            args.sensor_profile,
            parse_profile,
            file.sensor_profile,
            |s| parse_profile(&s),
        )?;
        let sensor_mm_per_px = l.checked(
            "sensor_mm_per_px",
            args.sensor_mm_per_px,
            parse_mm_per_px,
            file.sensor_mm_per_px,
            check_mm_per_px,
        )?;
        let sensor_mode = l.checked(
            "sensor_mode",
            args.sensor_mode,
            parse_from_str,
            file.sensor_mode,
            |s| s.parse(),
        )?;
        check_sensor(
            sensor_profile,
            sensor_mm_per_px,
            ("sensor_profile", "sensor_mm_per_px"),
        )
        .map_err(ConfigError::Invalid)?;
        let reference = l
            .checked(
                "reference",
                args.reference.clone(),
                parse_list,
                file.reference,
                |v| Ok(v.iter().map(|r| reference_in_file(&file_dir, r)).collect()),
            )?
            .unwrap_or_default();
        let replay_fps = l.checked(
            "replay_fps",
            args.replay_fps,
            telextiles_recording::recording::parse_fps,
            file.replay_fps,
            telextiles_recording::recording::check_fps,
        )?;
        let shipped = telextiles_sensing::contact::ContactConfig::default();
        let contact_enter = l
            .checked(
                "contact_enter",
                args.contact_enter,
                parse_contact_enter,
                file.contact_enter,
                check_contact_enter,
            )?
            .unwrap_or(shipped.enter);
        let contact_frames = l
            .checked(
                "contact_frames",
                args.contact_frames,
                parse_contact_frames,
                file.contact_frames,
                check_contact_frames,
            )?
            .unwrap_or(shipped.min_enter_frames);
        let contact_tile = l
            .checked(
                "contact_tile",
                args.contact_tile,
                parse_contact_tile,
                file.contact_tile,
                check_contact_tile,
            )?
            .unwrap_or(shipped.tile);
        let commit_margin = l
            .checked(
                "commit_margin",
                args.commit_margin,
                parse_commit_margin,
                file.commit_margin,
                check_commit_margin,
            )?
            .unwrap_or(telextiles_sensing::decide::DecideConfig::default().commit_margin);
        let encode_run = l
            .get("encode_run", args.encode_run, parse_bool, file.encode_run)?
            .unwrap_or(false);
        let motion = l
            .checked("motion", args.motion, parse_motion, file.motion, |v| {
                parse_motion(&v)
            })?
            .unwrap_or_default();
        let model = l
            .path("model", args.model.clone(), file.model)?
            .unwrap_or_else(|| data_dir.join("encoder.onnx"));
        let index = l
            .path("index", args.index.clone(), file.index)?
            .unwrap_or_else(|| data_dir.join("index.tlxi"));
        let roller = l
            .checked(
                "roller",
                args.roller.clone(),
                parse_from_str,
                file.roller,
                |s| {
                    Ok(match s.parse::<RollerSource>()? {
                        RollerSource::Path(p) => RollerSource::Path(file_dir.join(p)),
                        other => other,
                    })
                },
            )?
            .unwrap_or(RollerSource::Auto);
        let listen = l
            .get("listen", args.listen, parse_from_str, file.listen)?
            .unwrap_or_else(|| DEFAULT_LISTEN.parse().expect("valid default"));
        let connect = l
            .get("connect", args.connect.clone(), parse_list, file.connect)?
            .unwrap_or_default();
        for c in &connect {
            validate_peer(c).map_err(|m| ConfigError::Invalid(format!("`connect`: {m}")))?;
        }
        let relay = l.checked("relay", args.relay.clone(), parse_relay, file.relay, |u| {
            parse_relay(&u)
        })?;
        let relay_cert = l.path("relay_cert", args.relay_cert.clone(), file.relay_cert)?;
        if relay_cert.is_some() && relay.is_none() {
            return Err(ConfigError::Invalid(
                "`relay_cert` is set but `relay` is not: name the relay whose certificate it is"
                    .into(),
            ));
        }
        let mdns = l
            .get("mdns", args.mdns, parse_bool, file.mdns)?
            .unwrap_or(true);
        let mdns_allow = l
            .get(
                "mdns_allow",
                args.mdns_allow.clone(),
                parse_list,
                file.mdns_allow,
            )?
            .unwrap_or_default();
        let mdns_deny = l
            .get(
                "mdns_deny",
                args.mdns_deny.clone(),
                parse_list,
                file.mdns_deny,
            )?
            .unwrap_or_default();
        let map = l
            .get("map", args.map, parse_bool, file.map)?
            .unwrap_or(false);
        let map_bind = l
            .get("map_bind", args.map_bind, parse_from_str, file.map_bind)?
            .unwrap_or_else(|| DEFAULT_MAP_BIND.parse().expect("valid default"));
        // Logging: flag > TELEXTILESD_LOG > RUST_LOG > file > "info".
        let log = match l.get("log", args.log.clone(), parse_string, None)? {
            Some(l) => l,
            None => match e.raw("RUST_LOG") {
                Some(r) => r.to_string_lossy().into_owned(),
                None => file.log.unwrap_or_else(|| "info".into()),
            },
        };
        Ok(Config {
            config_file,
            name,
            state_dir,
            data_dir,
            runtime_dir,
            socket,
            system,
            group,
            sensor,
            sensor_profile,
            sensor_mm_per_px,
            sensor_mode,
            reference,
            replay_fps,
            contact_enter,
            contact_frames,
            contact_tile,
            commit_margin,
            encode_run,
            motion,
            model,
            index,
            roller,
            listen,
            connect,
            relay,
            relay_cert,
            mdns,
            mdns_allow,
            mdns_deny,
            map,
            map_bind,
            log,
        })
    }

    /// The control socket to bind: user-only under the runtime dir, or
    /// group-shared in system mode (the group is resolved here).
    pub fn socket_spec(&self) -> Result<telextiles_control::SocketSpec, ConfigError> {
        use telextiles_control::{socket, Access, SocketSpec};
        let access = if self.system {
            let gid = socket::resolve_group(&self.group)
                .map_err(|e| ConfigError::Invalid(e.to_string()))?;
            Access::Group { gid }
        } else {
            Access::User
        };
        // The runtime dir is ours to manage (create 0700/0750, check the
        // owner, tighten its mode) only when the socket is inside it and it
        // is one of the daemon's own directories (`.../telextilesd`: the
        // per-user and the system default). A directory the user named, e.g.
        // `--runtime-dir /tmp`, may be shared and is never chmod-ed.
        let manage_dir = self.socket.parent() == Some(self.runtime_dir.as_path())
            && self.runtime_dir.file_name()
                == Some(std::ffi::OsStr::new(
                    telextiles_control::socket::USER_DIR_NAME,
                ));
        Ok(SocketSpec {
            path: self.socket.clone(),
            access,
            manage_dir,
        })
    }

    /// The `tracing` filter for [`Config::log`]; an invalid filter is an
    /// error naming the option (instead of being silently ignored).
    pub fn env_filter(&self) -> Result<tracing_subscriber::EnvFilter, ConfigError> {
        tracing_subscriber::EnvFilter::builder()
            .parse(&self.log)
            .map_err(|e| {
                ConfigError::Invalid(format!(
                    "invalid log filter `{}` (from --log, TELEXTILESD_LOG, RUST_LOG or `log`): {e}",
                    self.log
                ))
            })
    }

    /// The resolved configuration as TOML (for `--print-config`-style output and docs).
    pub fn to_toml(&self) -> String {
        let q = |s: &str| toml_string(s);
        let list = |v: &[String]| {
            format!(
                "[{}]",
                v.iter().map(|s| q(s)).collect::<Vec<_>>().join(", ")
            )
        };
        let p = |p: &Path| q(&p.display().to_string());
        // Not set: left out (by the frames' size).
        let mut replay_fps = self
            .replay_fps
            .map(|f| format!("replay_fps = {f:?}\n"))
            .unwrap_or_default();
        // Sensor settings not given: left out (found or recorded).
        if let Some(p) = self.sensor_profile {
            replay_fps = format!("sensor_profile = {}\n{replay_fps}", q(p.name));
        }
        if let Some(mm) = self.sensor_mm_per_px {
            replay_fps = format!("sensor_mm_per_px = {mm:?}\n{replay_fps}");
        }
        if let Some(m) = self.sensor_mode {
            replay_fps = format!("sensor_mode = {}\n{replay_fps}", q(&m.to_string()));
        }
        // No relay: said as comments (an empty URL is not a relay).
        let relay_lines = match (&self.relay, &self.relay_cert) {
            (Some(r), Some(c)) => format!("relay = {}\nrelay_cert = {}\n", q(r), p(c)),
            (Some(r), None) => format!(
                "relay = {}\n# relay_cert: none (a CA-signed certificate)\n",
                q(r)
            ),
            (None, _) => "# relay: none (LAN and --connect addresses only)\n".to_string(),
        };
        format!(
            "name = {}\nstate_dir = {}\ndata_dir = {}\nruntime_dir = {}\nsocket = {}\nsystem = {}\ngroup = {}\nsensor = {}\nreference = {}\n{}contact_enter = {:?}\ncontact_frames = {}\ncontact_tile = {}\ncommit_margin = {:?}\nencode_run = {}\nmotion = {}\nmodel = {}\nindex = {}\nroller = {}\nlisten = {}\nconnect = {}\n{}mdns = {}\nmdns_allow = {}\nmdns_deny = {}\nmap = {}\nmap_bind = {}\nlog = {}\n",
            q(&self.name),
            p(&self.state_dir),
            p(&self.data_dir),
            p(&self.runtime_dir),
            p(&self.socket),
            self.system,
            q(&self.group),
            q(&self.sensor.to_string()),
            list(&self.reference),
            replay_fps,
            self.contact_enter,
            self.contact_frames,
            self.contact_tile,
            self.commit_margin,
            self.encode_run,
            q(&self.motion.to_string()),
            p(&self.model),
            p(&self.index),
            q(&self.roller.to_string()),
            q(&self.listen.to_string()),
            list(&self.connect),
            relay_lines,
            self.mdns,
            list(&self.mdns_allow),
            list(&self.mdns_deny),
            self.map,
            q(&self.map_bind.to_string()),
            q(&self.log),
        )
    }
}

impl Config {
    /// The sensor the configuration names (None: not given).
    pub fn sensor_given(&self) -> Option<telextiles_recording::recording::Sensor> {
        self.sensor_profile
            .map(|profile| telextiles_recording::recording::Sensor {
                profile,
                mm_per_px: self.sensor_mm_per_px,
            })
    }
}

fn parse_motion(s: &str) -> Result<telextiles_session::MotionPolicy, String> {
    s.parse()
}

fn toml_string(s: &str) -> String {
    // JSON string escaping is valid TOML basic-string escaping.
    serde_json::Value::from(s).to_string()
}

/// A `[SERIAL=]PNG` reference from the file, its path joined to the
/// file's directory, split as `References::from_args` splits it
/// (`front::split_reference_arg`, asked of the file's directory).
fn reference_in_file(file_dir: &Path, r: &str) -> String {
    let exists = |whole: &str| file_dir.join(whole).exists();
    match telextiles_sensing::front::split_reference_arg(r, exists) {
        Some((Some(serial), png)) => format!("{serial}={}", file_dir.join(png).display()),
        // A path, or a malformed value left for `from_args` to refuse.
        _ => file_dir.join(r).display().to_string(),
    }
}

/// The one resolver of a setting's layers: flag > `TELEXTILESD_<KEY>` >
/// the file's `key` > (the caller's default). The file's value is checked
/// (relative paths joined to the file's directory) and the variable parsed
/// even when a layer above overrides them, so a bad value is an error
/// naming where it is, never silently shadowed.
struct Layers<'a> {
    env: &'a Env<'a>,
    file_path: Option<&'a Path>,
    file_dir: &'a Path,
}

impl Layers<'_> {
    /// A setting whose file value needs no checking.
    fn get<T>(
        &self,
        key: &str,
        flag: Option<T>,
        parse: fn(&str) -> Result<T, String>,
        file: Option<T>,
    ) -> Result<Option<T>, ConfigError> {
        self.checked(key, flag, parse, file, Ok)
    }

    /// A path: the file's relative to the file's directory.
    fn path(
        &self,
        key: &str,
        flag: Option<PathBuf>,
        file: Option<PathBuf>,
    ) -> Result<Option<PathBuf>, ConfigError> {
        self.checked(key, flag, parse_path, file, |p| Ok(self.file_dir.join(p)))
    }

    /// A setting whose file value `check` turns into the setting (or
    /// refuses, the error naming the file and the key).
    fn checked<T, F>(
        &self,
        key: &str,
        flag: Option<T>,
        parse: fn(&str) -> Result<T, String>,
        file: Option<F>,
        check: impl FnOnce(F) -> Result<T, String>,
    ) -> Result<Option<T>, ConfigError> {
        let file = file
            .map(check)
            .transpose()
            .map_err(|message| ConfigError::File {
                path: self.file_path.map(Path::to_path_buf).unwrap_or_default(),
                message: format!("key `{key}`: {message}"),
            })?;
        let env = self.env.get(&key.to_ascii_uppercase(), parse)?;
        Ok(flag.or(env).or(file))
    }
}

struct Env<'a>(EnvLookup<'a>);

impl Env<'_> {
    /// A non-empty raw variable.
    fn raw(&self, var: &str) -> Option<OsString> {
        (self.0)(var).filter(|v| !v.is_empty())
    }
    /// `TELEXTILESD_<key>` parsed; empty counts as unset.
    fn get<T>(
        &self,
        key: &str,
        parse: fn(&str) -> Result<T, String>,
    ) -> Result<Option<T>, ConfigError> {
        let var = format!("{ENV_PREFIX}{key}");
        let Some(raw) = self.raw(&var) else {
            return Ok(None);
        };
        let value = raw.to_str().ok_or_else(|| ConfigError::Env {
            var: var.clone(),
            value: raw.to_string_lossy().into_owned(),
            message: "not valid UTF-8".into(),
        })?;
        parse(value).map(Some).map_err(|message| ConfigError::Env {
            var,
            value: value.to_string(),
            message,
        })
    }
}

fn parse_string(s: &str) -> Result<String, String> {
    Ok(s.to_string())
}
fn check_contact_enter(v: f32) -> Result<f32, String> {
    telextiles_sensing::contact::ContactConfig::with_entry(v, 2).map(|_| v)
}
fn check_contact_frames(n: u32) -> Result<u32, String> {
    telextiles_sensing::contact::ContactConfig::with_entry(0.35, n).map(|_| n)
}
fn check_contact_tile(n: u32) -> Result<u32, String> {
    telextiles_sensing::contact::ContactConfig::default()
        .with_tile(n)
        .map(|_| n)
}
fn check_commit_margin(v: f32) -> Result<f32, String> {
    if v.is_finite() && (0.0..=2.0).contains(&v) {
        Ok(v)
    } else {
        Err(format!(
            "the commit margin {v} is out of range: 0 to 2 (a distance between unit vectors; shipped 0.08)"
        ))
    }
}
/// The decider's commit margin (`commit_margin`).
pub fn parse_commit_margin(s: &str) -> Result<f32, String> {
    let v: f32 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    check_commit_margin(v)
}
/// A contact threshold (`contact_enter`).
pub fn parse_contact_enter(s: &str) -> Result<f32, String> {
    let v: f32 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a number"))?;
    check_contact_enter(v)
}
/// Frames in a row that start a press (`contact_frames`).
pub fn parse_contact_frames(s: &str) -> Result<u32, String> {
    let n: u32 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a whole number"))?;
    check_contact_frames(n)
}
/// The detector's tile, blocks a side (`contact_tile`; 0 = the whole frame).
pub fn parse_contact_tile(s: &str) -> Result<u32, String> {
    let n: u32 = s
        .trim()
        .parse()
        .map_err(|_| format!("`{s}` is not a whole number"))?;
    check_contact_tile(n)
}
fn parse_path(s: &str) -> Result<PathBuf, String> {
    Ok(PathBuf::from(s))
}
fn parse_bool(s: &str) -> Result<bool, String> {
    match s.to_ascii_lowercase().as_str() {
        "1" | "true" | "yes" | "on" | "y" => Ok(true),
        "0" | "false" | "no" | "off" | "n" => Ok(false),
        _ => Err("expected true/false (or 1/0, yes/no, on/off)".into()),
    }
}
fn parse_list(s: &str) -> Result<Vec<String>, String> {
    Ok(s.split(',')
        .map(str::trim)
        .filter(|x| !x.is_empty())
        .map(String::from)
        .collect())
}
fn parse_from_str<T: FromStr>(s: &str) -> Result<T, String>
where
    T::Err: fmt::Display,
{
    s.parse::<T>().map_err(|e| e.to_string())
}

/// `host:port` or `[v6]:port` with a numeric port.
/// `KEY@HOST:PORT` or `KEY` (through the relay).
fn home(e: &Env<'_>, what: &str) -> Result<PathBuf, ConfigError> {
    e.raw("HOME").map(PathBuf::from).ok_or_else(|| {
        ConfigError::Invalid(format!(
            "neither HOME nor the XDG variable is set, so `{what}` has no default; pass --{}",
            what.replace('_', "-")
        ))
    })
}

fn xdg_dir(e: &Env<'_>, var: &str, fallback: &str, what: &str) -> Result<PathBuf, ConfigError> {
    match e.raw(var) {
        Some(v) if Path::new(&v).is_absolute() => Ok(PathBuf::from(v)),
        _ => Ok(home(e, what)?.join(fallback)),
    }
}

fn default_config_file(system: bool, e: &Env<'_>) -> Option<PathBuf> {
    if system {
        return Some(PathBuf::from("/etc/telextiles/telextilesd.toml"));
    }
    let base = match e.raw("XDG_CONFIG_HOME") {
        Some(v) if Path::new(&v).is_absolute() => PathBuf::from(v),
        _ => PathBuf::from(e.raw("HOME")?).join(".config"),
    };
    Some(base.join("telextiles").join("telextilesd.toml"))
}

fn default_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .or_else(|_| std::fs::read_to_string("/etc/hostname"))
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "telextiles".into())
}

pub mod peer;
use peer::{parse_relay, validate_peer};
mod sensor;
pub use sensor::SensorArgs;
use sensor::{check_mm_per_px, check_sensor, parse_mm_per_px, parse_profile};

#[cfg(test)]
mod tests;
