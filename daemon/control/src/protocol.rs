//! The control protocol, sans-IO: request parsing with typed, validated
//! arguments, replies, events and a bounded line framer.
//!
//! Nothing here does I/O, reads a clock or spawns; every function is a pure
//! transformation of bytes or values, so it can be fuzzed and property-tested.
//! Decoders return errors, never panic, on any input.
//!
//! Wire format (one JSON document per line, `\n`-terminated, UTF-8):
//! - request: `{"id": 1, "cmd": "roller.goto", "args": {"slot": 3}}`
//! - reply: `{"id": 1, "ok": true, "data": ...}` or
//!   `{"id": 1, "ok": false, "error": {"code": "invalid_args", "message": "..."}}`
//! - event (after `subscribe`): `{"event": "decision", "textile": "T012", ...}`
//!
//! See `docs/control-protocol.md` for the full reference.

use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use std::collections::VecDeque;
use std::fmt;

pub use crate::event::{ContactPhase, Event, EventFilter, EventKind, RecordPhase};

/// Longest request line the server accepts (bytes, without the newline).
pub const MAX_LINE: usize = 64 * 1024;

/// Longest `id` string accepted (bytes).
pub const MAX_ID_LEN: usize = 256;

/// Commands the server understands, with a one-line description each.
pub const COMMANDS: &[(&str, &str)] = &[
    (
        "status",
        "daemon state: name, sensor, roller, index, peers, clients",
    ),
    ("peers", "paired and connected peers"),
    ("pair", "pair with another daemon (args: code?, timeout_s?)"),
    ("unpair", "forget a paired peer (args: peer)"),
    (
        "sensor.recalibrate",
        "re-capture the no-contact background frame",
    ),
    (
        "sensor.led",
        "set LED intensity (args: intensity | r, g, b; 0..=15)",
    ),
    (
        "roller.goto",
        "turn the roller to a slot (args: slot | textile)",
    ),
    (
        "sensor.sim",
        "simulated sensor only: press a textile (args: textile, person?, sensor?, jig?, seed?, rotation_deg?, force?) or lift (textile = \"none\")",
    ),
    ("roller.home", "home the roller"),
    ("roller.jog", "turn the roller by an angle (args: degrees)"),
    (
        "index.info",
        "the loaded textile index: size, fingerprint, roller layout",
    ),
    (
        "record.start",
        "record labelled presses from the sensor into a directory (args: textile, presses, out, name?)",
    ),
    ("record.stop", "stop recording (the press in progress is dropped)"),
    (
        "subscribe",
        "stream events on this connection (args: events?)",
    ),
    ("shutdown", "stop the daemon"),
];

/// Machine-readable error class, serialised in snake_case.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorCode {
    /// The line is not valid JSON (or not UTF-8).
    ParseError,
    /// Valid JSON but not a request object (missing/ill-typed `cmd`, `id`, unknown field).
    InvalidRequest,
    /// `cmd` names no command.
    UnknownCommand,
    /// An argument is missing, unknown, of the wrong type or out of range.
    InvalidArgs,
    /// The line exceeded [`MAX_LINE`]; the server resyncs at the next newline.
    LineTooLong,
    /// Too many clients; the connection is closed.
    Busy,
    /// The subsystem the command needs is not running (no roller, no sensor...).
    Unavailable,
    /// The command was valid but failed.
    Failed,
    /// A bug or unexpected condition in the daemon.
    Internal,
    /// The daemon is shutting down.
    ShuttingDown,
    /// A code this client version does not know (forward compatibility).
    #[serde(other)]
    Unknown,
}

impl ErrorCode {
    /// The snake_case wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            ErrorCode::ParseError => "parse_error",
            ErrorCode::InvalidRequest => "invalid_request",
            ErrorCode::UnknownCommand => "unknown_command",
            ErrorCode::InvalidArgs => "invalid_args",
            ErrorCode::LineTooLong => "line_too_long",
            ErrorCode::Busy => "busy",
            ErrorCode::Unavailable => "unavailable",
            ErrorCode::Failed => "failed",
            ErrorCode::Internal => "internal",
            ErrorCode::ShuttingDown => "shutting_down",
            ErrorCode::Unknown => "unknown",
        }
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// An error as sent in a reply: `{"code": "...", "message": "..."}`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, thiserror::Error)]
#[error("{code}: {message}")]
pub struct CtlError {
    pub code: ErrorCode,
    pub message: String,
}

impl CtlError {
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        CtlError {
            code,
            message: message.into(),
        }
    }
    pub fn invalid_args(message: impl Into<String>) -> Self {
        Self::new(ErrorCode::InvalidArgs, message)
    }
    pub fn unavailable(message: impl Into<String>) -> Self {
        Self::new(ErrorCode::Unavailable, message)
    }
    pub fn failed(message: impl Into<String>) -> Self {
        Self::new(ErrorCode::Failed, message)
    }
    pub fn internal(message: impl Into<String>) -> Self {
        Self::new(ErrorCode::Internal, message)
    }
}

/// A request id: whatever scalar the client sent (string, number or null),
/// echoed back verbatim in the reply.
#[derive(Debug, Clone, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(untagged)]
pub enum RequestId {
    #[default]
    Null,
    Num(serde_json::Number),
    Str(String),
}

impl fmt::Display for RequestId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            RequestId::Null => f.write_str("null"),
            RequestId::Num(n) => write!(f, "{n}"),
            RequestId::Str(s) => write!(f, "{s:?}"),
        }
    }
}

impl From<u64> for RequestId {
    fn from(v: u64) -> Self {
        RequestId::Num(v.into())
    }
}

/// Arguments of `pair`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct PairArgs {
    /// The pairing code shown by the other daemon; `None` = show ours and wait.
    pub code: Option<String>,
    /// How long to wait for the other side, 1..=3600 s; `None` = daemon default.
    pub timeout_s: Option<u32>,
}

/// Arguments of `unpair`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct UnpairArgs {
    /// Peer name or id as listed by `peers`.
    pub peer: String,
}

/// Arguments of `sensor.led`: per-channel intensity, each 0..=15 (DIGIT's range).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct LedArgs {
    pub r: u8,
    pub g: u8,
    pub b: u8,
}

/// Highest LED intensity accepted by `sensor.led`.
pub const LED_MAX: u8 = 15;

/// `sensor.sim`: what the simulated DIGIT presses next. `textile` "none"
/// lifts the sensor.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SimPressArgs {
    pub textile: String,
    pub person: Option<u32>,
    pub sensor: Option<u32>,
    pub jig: Option<bool>,
    pub seed: Option<u64>,
    pub rotation_deg: Option<f64>,
    pub force: Option<f64>,
}

/// Longest `record.start` output directory accepted (bytes).
pub const MAX_PATH_LEN: usize = 4096;

/// Most presses one `record.start` may ask for.
pub const MAX_RECORD_PRESSES: u32 = 10_000;

/// Arguments of `record.start`: record `presses` presses of `textile` into
/// `<out>/<textile>/NNNN` (the next free numbers), as `telextilesd record`
/// does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RecordStartArgs {
    /// Textile id: a plain directory name (no `/`, not `.` or `..`).
    pub textile: String,
    /// Human-readable name, stored in `<out>/<textile>/textile.json`.
    pub name: Option<String>,
    /// Presses to record, 1..=[`MAX_RECORD_PRESSES`].
    pub presses: u32,
    /// Directory of recordings, as the daemon sees it (absolute paths
    /// recommended: the daemon's working directory is not the client's).
    pub out: String,
}

/// Whether `id` can be a textile directory name.
pub fn valid_textile_dir(id: &str) -> bool {
    !id.is_empty()
        && id != "."
        && id != ".."
        && !id.contains(['/', '\\'])
        && !id.chars().any(char::is_control)
}

/// Where `roller.goto` turns the roller.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum GotoTarget {
    /// A roller slot, 0-based.
    Slot(u32),
    /// The slot carrying (or nearest to) this textile id, e.g. `"T012"`.
    Textile(String),
}

/// Arguments of `roller.jog`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JogArgs {
    /// Signed angle in degrees, finite, -360..=360; positive = forward.
    pub degrees: f64,
}

/// Arguments of `subscribe`.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct SubscribeArgs {
    /// Event kinds wanted; `None` = all kinds.
    pub events: Option<Vec<EventKind>>,
}

impl SubscribeArgs {
    pub fn filter(&self) -> EventFilter {
        match &self.events {
            None => EventFilter::all(),
            Some(kinds) => EventFilter::of(kinds),
        }
    }
}

/// A validated command with typed arguments.
#[derive(Debug, Clone, PartialEq)]
pub enum Command {
    Status,
    Peers,
    Pair(PairArgs),
    Unpair(UnpairArgs),
    SensorRecalibrate,
    SensorLed(LedArgs),
    SensorSim(SimPressArgs),
    RollerGoto(GotoTarget),
    RollerHome,
    RollerJog(JogArgs),
    IndexInfo,
    RecordStart(RecordStartArgs),
    RecordStop,
    Subscribe(SubscribeArgs),
    Shutdown,
}

impl Command {
    /// The wire name (`cmd`).
    pub fn name(&self) -> &'static str {
        match self {
            Command::Status => "status",
            Command::Peers => "peers",
            Command::Pair(_) => "pair",
            Command::Unpair(_) => "unpair",
            Command::SensorRecalibrate => "sensor.recalibrate",
            Command::SensorLed(_) => "sensor.led",
            Command::SensorSim(_) => "sensor.sim",
            Command::RollerGoto(_) => "roller.goto",
            Command::RollerHome => "roller.home",
            Command::RollerJog(_) => "roller.jog",
            Command::IndexInfo => "index.info",
            Command::RecordStart(_) => "record.start",
            Command::RecordStop => "record.stop",
            Command::Subscribe(_) => "subscribe",
            Command::Shutdown => "shutdown",
        }
    }

    /// The arguments as the JSON object sent on the wire.
    pub fn args_json(&self) -> Value {
        let mut m = Map::new();
        match self {
            Command::Pair(a) => {
                if let Some(c) = &a.code {
                    m.insert("code".into(), c.clone().into());
                }
                if let Some(t) = a.timeout_s {
                    m.insert("timeout_s".into(), t.into());
                }
            }
            Command::Unpair(a) => {
                m.insert("peer".into(), a.peer.clone().into());
            }
            Command::SensorLed(l) => {
                m.insert("r".into(), l.r.into());
                m.insert("g".into(), l.g.into());
                m.insert("b".into(), l.b.into());
            }
            Command::SensorSim(a) => {
                m.insert("textile".into(), a.textile.clone().into());
                if let Some(v) = a.person {
                    m.insert("person".into(), v.into());
                }
                if let Some(v) = a.sensor {
                    m.insert("sensor".into(), v.into());
                }
                if let Some(v) = a.jig {
                    m.insert("jig".into(), v.into());
                }
                if let Some(v) = a.seed {
                    m.insert("seed".into(), v.into());
                }
                if let Some(v) = a.rotation_deg {
                    m.insert("rotation_deg".into(), v.into());
                }
                if let Some(v) = a.force {
                    m.insert("force".into(), v.into());
                }
            }
            Command::RollerGoto(GotoTarget::Slot(s)) => {
                m.insert("slot".into(), (*s).into());
            }
            Command::RollerGoto(GotoTarget::Textile(t)) => {
                m.insert("textile".into(), t.clone().into());
            }
            Command::RollerJog(j) => {
                m.insert("degrees".into(), j.degrees.into());
            }
            Command::RecordStart(r) => {
                m.insert("textile".into(), r.textile.clone().into());
                if let Some(n) = &r.name {
                    m.insert("name".into(), n.clone().into());
                }
                m.insert("presses".into(), r.presses.into());
                m.insert("out".into(), r.out.clone().into());
            }
            Command::Subscribe(s) => {
                if let Some(ev) = &s.events {
                    m.insert(
                        "events".into(),
                        Value::Array(ev.iter().map(|k| Value::from(k.as_str())).collect()),
                    );
                }
            }
            Command::Status
            | Command::Peers
            | Command::SensorRecalibrate
            | Command::RollerHome
            | Command::IndexInfo
            | Command::RecordStop
            | Command::Shutdown => {}
        }
        Value::Object(m)
    }

    /// A full request line (with trailing newline) for this command.
    pub fn to_request_line(&self, id: &RequestId) -> String {
        let v = serde_json::json!({"id": id, "cmd": self.name(), "args": self.args_json()});
        let mut s = v.to_string();
        s.push('\n');
        s
    }
}

/// A parsed request.
#[derive(Debug, Clone, PartialEq)]
pub struct Request {
    pub id: RequestId,
    pub command: Command,
}

/// A request that could not be parsed: the id (when it could be recovered,
/// so the reply still correlates) and the error to send back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RequestError {
    pub id: RequestId,
    pub error: CtlError,
}

impl RequestError {
    /// The error reply line for this failure.
    pub fn to_reply_line(&self) -> String {
        Reply::err(self.id.clone(), self.error.clone()).to_line()
    }
}

/// Parses one request line (without the newline; a trailing `\r` and
/// surrounding whitespace are ignored). Never panics.
pub fn parse_request(line: &[u8]) -> Result<Request, RequestError> {
    let no_id = |error| RequestError {
        id: RequestId::Null,
        error,
    };
    let v: Value = serde_json::from_slice(line).map_err(|e| {
        no_id(CtlError::new(
            ErrorCode::ParseError,
            format!("malformed JSON: {e}"),
        ))
    })?;
    let Value::Object(mut obj) = v else {
        return Err(no_id(CtlError::new(
            ErrorCode::InvalidRequest,
            format!(
                "a request must be a JSON object like {{\"id\":1,\"cmd\":\"status\"}}, got {}",
                describe(&v)
            ),
        )));
    };
    let id = match obj.remove("id") {
        None | Some(Value::Null) => RequestId::Null,
        Some(Value::Number(n)) => RequestId::Num(n),
        Some(Value::String(s)) if s.len() <= MAX_ID_LEN => RequestId::Str(s),
        Some(Value::String(_)) => {
            return Err(no_id(CtlError::new(
                ErrorCode::InvalidRequest,
                format!("`id` is longer than {MAX_ID_LEN} bytes"),
            )))
        }
        Some(other) => {
            return Err(no_id(CtlError::new(
                ErrorCode::InvalidRequest,
                format!(
                    "`id` must be a string, a number or null, got {}",
                    describe(&other)
                ),
            )))
        }
    };
    let fail = |error| RequestError {
        id: id.clone(),
        error,
    };
    let cmd = match obj.remove("cmd") {
        Some(Value::String(s)) => s,
        None | Some(Value::Null) => {
            return Err(fail(CtlError::new(
                ErrorCode::InvalidRequest,
                "missing `cmd` (e.g. {\"id\":1,\"cmd\":\"status\"})",
            )))
        }
        Some(other) => {
            return Err(fail(CtlError::new(
                ErrorCode::InvalidRequest,
                format!("`cmd` must be a string, got {}", describe(&other)),
            )))
        }
    };
    let args = match obj.remove("args") {
        None | Some(Value::Null) => Map::new(),
        Some(Value::Object(m)) => m,
        Some(other) => {
            return Err(fail(CtlError::invalid_args(format!(
                "`args` must be a JSON object, got {}",
                describe(&other)
            ))))
        }
    };
    if let Some(k) = obj.keys().next() {
        return Err(fail(CtlError::new(
            ErrorCode::InvalidRequest,
            format!(
                "unknown request field `{}` (a request has `id`, `cmd` and `args`)",
                truncate(k, 64)
            ),
        )));
    }
    let command = parse_command(&cmd, args).map_err(fail)?;
    Ok(Request { id, command })
}

/// Builds a typed command from its name and argument object.
pub fn parse_command(cmd: &str, args: Map<String, Value>) -> Result<Command, CtlError> {
    let Some((name, _)) = COMMANDS.iter().find(|(n, _)| *n == cmd) else {
        let known: Vec<&str> = COMMANDS.iter().map(|(n, _)| *n).collect();
        return Err(CtlError::new(
            ErrorCode::UnknownCommand,
            format!(
                "unknown command `{}`; known commands: {}",
                truncate(cmd, 64),
                known.join(", ")
            ),
        ));
    };
    let mut a = Args {
        cmd: name,
        map: args,
    };
    let command = match *name {
        "status" => Command::Status,
        "peers" => Command::Peers,
        "pair" => {
            let code = a.opt_string("code", 1, 128)?;
            let timeout_s = a.opt_uint("timeout_s", 1, 3600)?.map(|v| v as u32);
            Command::Pair(PairArgs { code, timeout_s })
        }
        "unpair" => Command::Unpair(UnpairArgs {
            peer: a.req_string("peer", 1, 256)?,
        }),
        "sensor.recalibrate" => Command::SensorRecalibrate,
        "sensor.led" => {
            let max = u64::from(LED_MAX);
            let all = a.opt_uint("intensity", 0, max)?;
            let r = a.opt_uint("r", 0, max)?;
            let g = a.opt_uint("g", 0, max)?;
            let b = a.opt_uint("b", 0, max)?;
            match (all, r, g, b) {
                (Some(v), None, None, None) => Command::SensorLed(LedArgs {
                    r: v as u8,
                    g: v as u8,
                    b: v as u8,
                }),
                (None, Some(r), Some(g), Some(b)) => Command::SensorLed(LedArgs {
                    r: r as u8,
                    g: g as u8,
                    b: b as u8,
                }),
                (Some(_), _, _, _) => {
                    return Err(a.err("give either `intensity` or `r`, `g`, `b`, not both"))
                }
                _ => {
                    return Err(a.err(
                        "needs `intensity` (0..=15, all channels) or all of `r`, `g`, `b` (each 0..=15)",
                    ))
                }
            }
        }
        "sensor.sim" => Command::SensorSim(SimPressArgs {
            textile: a.req_string("textile", 1, 64)?,
            person: a.opt_uint("person", 0, 1000)?.map(|v| v as u32),
            sensor: a.opt_uint("sensor", 0, 1000)?.map(|v| v as u32),
            jig: a.opt_bool("jig")?,
            seed: a.opt_uint("seed", 0, u64::MAX)?,
            rotation_deg: a.opt_f64("rotation_deg", -360.0, 360.0)?,
            force: a.opt_f64("force", 0.0, 100.0)?,
        }),
        "roller.goto" => {
            let slot = a.opt_uint("slot", 0, 4095)?;
            let textile = a.opt_string("textile", 1, 64)?;
            match (slot, textile) {
                (Some(s), None) => Command::RollerGoto(GotoTarget::Slot(s as u32)),
                (None, Some(t)) => Command::RollerGoto(GotoTarget::Textile(t)),
                (Some(_), Some(_)) => {
                    return Err(a.err("give either `slot` or `textile`, not both"))
                }
                (None, None) => {
                    return Err(a.err("needs `slot` (integer) or `textile` (textile id)"))
                }
            }
        }
        "roller.home" => Command::RollerHome,
        "roller.jog" => {
            let degrees = a.req_f64("degrees", -360.0, 360.0)?;
            Command::RollerJog(JogArgs { degrees })
        }
        "index.info" => Command::IndexInfo,
        "record.start" => {
            let textile = a.req_string("textile", 1, 64)?;
            if !valid_textile_dir(&textile) {
                return Err(a.err(format!(
                    "argument `textile` must be a plain directory name (no `/`, not `.` or `..`), got {:?}",
                    truncate(&textile, 64)
                )));
            }
            let name = a.opt_string("name", 1, 256)?;
            let presses = a
                .opt_uint("presses", 1, u64::from(MAX_RECORD_PRESSES))?
                .ok_or_else(|| {
                    a.err(format!(
                        "missing argument `presses` (an integer in 1..={MAX_RECORD_PRESSES})"
                    ))
                })? as u32;
            let out = a.req_string("out", 1, MAX_PATH_LEN)?;
            if out.contains('\0') {
                return Err(a.err("argument `out` must not contain NUL"));
            }
            Command::RecordStart(RecordStartArgs {
                textile,
                name,
                presses,
                out,
            })
        }
        "record.stop" => Command::RecordStop,
        "subscribe" => {
            let events = match a.take("events") {
                None => None,
                Some(Value::Array(items)) => {
                    if items.is_empty() {
                        return Err(a.err(
                            "argument `events` must not be empty; omit it to receive all events",
                        ));
                    }
                    let mut kinds = Vec::with_capacity(items.len());
                    for (i, item) in items.iter().enumerate() {
                        let Value::String(s) = item else {
                            return Err(a.err(format!(
                                "argument `events[{i}]` must be a string, got {}",
                                describe(item)
                            )));
                        };
                        let k = EventKind::parse(s).ok_or_else(|| {
                            a.err(format!(
                                "argument `events[{i}]`: unknown event kind `{}`; kinds: {}",
                                truncate(s, 64),
                                EventKind::ALL
                                    .iter()
                                    .map(|k| k.as_str())
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            ))
                        })?;
                        if !kinds.contains(&k) {
                            kinds.push(k);
                        }
                    }
                    Some(kinds)
                }
                Some(other) => {
                    return Err(a.err(format!(
                        "argument `events` must be an array of event kinds, got {}",
                        describe(&other)
                    )))
                }
            };
            Command::Subscribe(SubscribeArgs { events })
        }
        "shutdown" => Command::Shutdown,
        _ => {
            return Err(CtlError::internal(format!(
                "command `{name}` is listed but has no parser"
            )))
        }
    };
    a.finish()?;
    Ok(command)
}

/// Typed access to an argument object, with errors that name the command
/// and the argument.
struct Args {
    cmd: &'static str,
    map: Map<String, Value>,
}

impl Args {
    fn err(&self, msg: impl fmt::Display) -> CtlError {
        CtlError::invalid_args(format!("`{}`: {msg}", self.cmd))
    }

    /// Removes an argument; JSON `null` counts as absent.
    fn take(&mut self, name: &str) -> Option<Value> {
        match self.map.remove(name) {
            None | Some(Value::Null) => None,
            Some(v) => Some(v),
        }
    }

    fn opt_uint(&mut self, name: &str, min: u64, max: u64) -> Result<Option<u64>, CtlError> {
        let Some(v) = self.take(name) else {
            return Ok(None);
        };
        match v.as_u64() {
            Some(n) if (min..=max).contains(&n) => Ok(Some(n)),
            _ => Err(self.err(format!(
                "argument `{name}` must be an integer in {min}..={max}, got {}",
                describe(&v)
            ))),
        }
    }

    fn opt_string(
        &mut self,
        name: &str,
        min: usize,
        max: usize,
    ) -> Result<Option<String>, CtlError> {
        let Some(v) = self.take(name) else {
            return Ok(None);
        };
        match v {
            Value::String(s) if (min..=max).contains(&s.len()) => Ok(Some(s)),
            Value::String(s) => Err(self.err(format!(
                "argument `{name}` must be {min}..={max} bytes long, got {} bytes",
                s.len()
            ))),
            other => Err(self.err(format!(
                "argument `{name}` must be a string, got {}",
                describe(&other)
            ))),
        }
    }

    fn req_string(&mut self, name: &str, min: usize, max: usize) -> Result<String, CtlError> {
        self.opt_string(name, min, max)?
            .ok_or_else(|| self.err(format!("missing argument `{name}` (a string)")))
    }

    fn opt_bool(&mut self, name: &str) -> Result<Option<bool>, CtlError> {
        match self.take(name) {
            None => Ok(None),
            Some(Value::Bool(b)) => Ok(Some(b)),
            Some(v) => Err(self.err(format!(
                "argument `{name}` must be true or false, got {}",
                describe(&v)
            ))),
        }
    }

    fn opt_f64(&mut self, name: &str, min: f64, max: f64) -> Result<Option<f64>, CtlError> {
        if self.map.get(name).is_none_or(Value::is_null) {
            self.map.remove(name);
            return Ok(None);
        }
        self.req_f64(name, min, max).map(Some)
    }

    fn req_f64(&mut self, name: &str, min: f64, max: f64) -> Result<f64, CtlError> {
        let Some(v) = self.take(name) else {
            return Err(self.err(format!("missing argument `{name}` (a number)")));
        };
        match v.as_f64() {
            Some(x) if x.is_finite() && (min..=max).contains(&x) => Ok(x),
            _ => Err(self.err(format!(
                "argument `{name}` must be a number in {min}..={max}, got {}",
                describe(&v)
            ))),
        }
    }

    /// Rejects any argument not consumed by the command's parser.
    fn finish(self) -> Result<(), CtlError> {
        if self.map.is_empty() {
            return Ok(());
        }
        let mut names: Vec<&str> = self.map.keys().map(|k| k.as_str()).collect();
        names.sort_unstable();
        let shown: Vec<String> = names
            .iter()
            .take(5)
            .map(|k| format!("`{}`", truncate(k, 64)))
            .collect();
        Err(self.err(format!("unknown argument {}", shown.join(", "))))
    }
}

/// A short human description of a JSON value's type and content, for errors.
fn describe(v: &Value) -> String {
    match v {
        Value::Null => "null".into(),
        Value::Bool(b) => format!("boolean {b}"),
        Value::Number(n) => format!("number {n}"),
        Value::String(s) => format!("string {:?}", truncate(s, 40)),
        Value::Array(a) => format!("an array of {} items", a.len()),
        Value::Object(_) => "an object".into(),
    }
}

/// At most `max` bytes of `s`, cut at a char boundary, with `...` if cut.
fn truncate(s: &str, max: usize) -> String {
    if s.len() <= max {
        return s.to_string();
    }
    let mut end = max;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}...", &s[..end])
}

/// A reply line: `{"id", "ok": true, "data"}` or `{"id", "ok": false, "error"}`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Reply {
    pub id: RequestId,
    pub ok: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub data: Option<Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error: Option<CtlError>,
}

impl Reply {
    pub fn ok(id: RequestId, data: Value) -> Self {
        Reply {
            id,
            ok: true,
            data: Some(data),
            error: None,
        }
    }
    pub fn err(id: RequestId, error: CtlError) -> Self {
        Reply {
            id,
            ok: false,
            data: None,
            error: Some(error),
        }
    }
    pub fn from_result(id: RequestId, r: Result<Value, CtlError>) -> Self {
        match r {
            Ok(v) => Reply::ok(id, v),
            Err(e) => Reply::err(id, e),
        }
    }
    /// The reply as one `\n`-terminated JSON line.
    pub fn to_line(&self) -> String {
        let mut s = serde_json::to_string(self).unwrap_or_else(|e| {
            format!(
                "{{\"id\":null,\"ok\":false,\"error\":{{\"code\":\"internal\",\"message\":{}}}}}",
                Value::from(format!("reply not serialisable: {e}"))
            )
        });
        s.push('\n');
        s
    }
    /// `data` on success, the error otherwise (a malformed `ok: false` reply
    /// without an error object becomes an `internal` error).
    pub fn into_result(self) -> Result<Value, CtlError> {
        if self.ok {
            Ok(self.data.unwrap_or(Value::Null))
        } else {
            Err(self
                .error
                .unwrap_or_else(|| CtlError::internal("error reply without an `error` object")))
        }
    }
}

/// One line received by a client: a reply, an event, or an event of a kind
/// this client does not know (kept as raw JSON).
#[derive(Debug, Clone, PartialEq)]
pub enum ServerLine {
    Reply(Reply),
    Event(Event),
    UnknownEvent(Value),
}

/// Parses a line sent by the server. Never panics.
pub fn parse_server_line(line: &[u8]) -> Result<ServerLine, String> {
    let v: Value =
        serde_json::from_slice(line).map_err(|e| format!("malformed JSON from server: {e}"))?;
    if v.get("event").is_some() {
        return Ok(match serde_json::from_value::<Event>(v.clone()) {
            Ok(e) => ServerLine::Event(e),
            Err(_) => ServerLine::UnknownEvent(v),
        });
    }
    serde_json::from_value::<Reply>(v)
        .map(ServerLine::Reply)
        .map_err(|e| format!("server line is neither a reply nor an event: {e}"))
}

/// Output of the [`LineFramer`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Frame {
    /// A complete, non-blank line without its `\n` (and without a trailing `\r`).
    Line(Vec<u8>),
    /// A line longer than the limit was discarded up to its newline; this is
    /// reported once per oversize line, as soon as the limit is exceeded.
    TooLong,
}

/// Splits a byte stream into `\n`-terminated lines with a hard length cap.
/// Memory use stays below `max + one read`; an oversize line is reported
/// as [`Frame::TooLong`] and skipped up to the next newline (resync).
#[derive(Debug)]
pub struct LineFramer {
    max: usize,
    buf: Vec<u8>,
    discarding: bool,
    ready: VecDeque<Frame>,
}

impl LineFramer {
    pub fn new(max: usize) -> Self {
        LineFramer {
            max,
            buf: Vec::new(),
            discarding: false,
            ready: VecDeque::new(),
        }
    }

    /// Feeds received bytes; complete frames become available via [`Self::next_frame`].
    pub fn feed(&mut self, mut data: &[u8]) {
        while !data.is_empty() {
            match data.iter().position(|&b| b == b'\n') {
                Some(i) => {
                    let chunk = &data[..i];
                    data = &data[i + 1..];
                    if self.discarding {
                        self.discarding = false;
                    } else if self.buf.len() + chunk.len() > self.max {
                        self.buf.clear();
                        self.ready.push_back(Frame::TooLong);
                    } else {
                        self.buf.extend_from_slice(chunk);
                        let mut line = std::mem::take(&mut self.buf);
                        if line.last() == Some(&b'\r') {
                            line.pop();
                        }
                        if !line.iter().all(u8::is_ascii_whitespace) {
                            self.ready.push_back(Frame::Line(line));
                        }
                    }
                }
                None => {
                    if !self.discarding {
                        if self.buf.len() + data.len() > self.max {
                            self.buf.clear();
                            self.buf.shrink_to(self.max.min(4096));
                            self.discarding = true;
                            self.ready.push_back(Frame::TooLong);
                        } else {
                            self.buf.extend_from_slice(data);
                        }
                    }
                    return;
                }
            }
        }
    }

    /// The next complete frame, if any.
    pub fn next_frame(&mut self) -> Option<Frame> {
        self.ready.pop_front()
    }

    /// Bytes of an unfinished line held (for diagnostics at EOF).
    pub fn pending(&self) -> usize {
        self.buf.len()
    }
}

#[cfg(test)]
mod tests;
