//! Roller serial protocol: framing, messages, a bounded incremental decoder.
//!
//! Sans-IO and `no_std` without `alloc`: the ESP32 firmware, the host
//! simulator and the daemon driver all share this module. The byte layout is
//! documented in `docs/roller-protocol.md`; in short:
//!
//! ```text
//! A5 5A | LEN | SEQ | KIND | BODY (LEN bytes, 0..=32) | CRC16 (big-endian)
//! ```
//!
//! The CRC is CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF) over
//! `LEN SEQ KIND BODY`. Multi-byte body fields are little-endian.
//!
//! The host numbers its commands with `SEQ`; every reply to a command carries
//! the command's `SEQ`. Unsolicited frames (`Arrived`, periodic `Status`)
//! carry the `SEQ` of the move command they belong to.

use core::fmt;

/// First sync byte.
pub const SYNC0: u8 = 0xA5;
/// Second sync byte.
pub const SYNC1: u8 = 0x5A;
/// Largest body a frame may carry.
pub const MAX_BODY: usize = 32;
/// Header bytes before the body: sync (2), length, sequence, kind.
pub const HEADER_LEN: usize = 5;
/// Largest encoded frame.
pub const MAX_FRAME: usize = HEADER_LEN + MAX_BODY + 2;
/// Protocol version exchanged in `Hello` / `Version`.
pub const PROTOCOL_VERSION: u8 = 1;
/// One full turn in millidegrees.
pub const FULL_TURN_MDEG: u32 = 360_000;

/// CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor).
pub fn crc16(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &b in data {
        crc ^= (b as u16) << 8;
        for _ in 0..8 {
            crc = if crc & 0x8000 != 0 {
                (crc << 1) ^ 0x1021
            } else {
                crc << 1
            };
        }
    }
    crc
}

/// Message kinds (the `KIND` byte). Commands are `0x01..=0x7F`, replies
/// `0x81..=0xFF`.
pub mod kind {
    pub const HELLO: u8 = 0x01;
    pub const GOTO_SLOT: u8 = 0x02;
    pub const GOTO_ANGLE: u8 = 0x03;
    pub const GOTO_STEPS: u8 = 0x04;
    pub const ZERO: u8 = 0x05;
    pub const SET_MOTION: u8 = 0x06;
    pub const SET_SLOTS: u8 = 0x07;
    pub const QUERY_STATUS: u8 = 0x08;
    pub const STOP: u8 = 0x09;

    pub const VERSION: u8 = 0x81;
    pub const ACK: u8 = 0x82;
    pub const ARRIVED: u8 = 0x83;
    pub const ERROR: u8 = 0x84;
    pub const STATUS: u8 = 0x85;
}

/// A frame as it travels on the wire: sequence number, kind, raw body.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Frame {
    pub seq: u8,
    pub kind: u8,
    body: [u8; MAX_BODY],
    body_len: u8,
}

impl Frame {
    /// A frame with the given body; `None` if the body is longer than [`MAX_BODY`].
    pub fn new(seq: u8, kind: u8, body: &[u8]) -> Option<Frame> {
        if body.len() > MAX_BODY {
            return None;
        }
        let mut b = [0u8; MAX_BODY];
        b[..body.len()].copy_from_slice(body);
        Some(Frame {
            seq,
            kind,
            body: b,
            body_len: body.len() as u8,
        })
    }

    pub fn body(&self) -> &[u8] {
        &self.body[..self.body_len as usize]
    }

    /// Encodes the frame (sync, header, body, CRC) into `out`; returns the
    /// number of bytes written, or `None` if `out` is too small.
    pub fn encode_into(&self, out: &mut [u8]) -> Option<usize> {
        let n = HEADER_LEN + self.body_len as usize + 2;
        if out.len() < n {
            return None;
        }
        out[0] = SYNC0;
        out[1] = SYNC1;
        out[2] = self.body_len;
        out[3] = self.seq;
        out[4] = self.kind;
        out[HEADER_LEN..HEADER_LEN + self.body_len as usize].copy_from_slice(self.body());
        let crc = crc16(&out[2..n - 2]);
        out[n - 2..n].copy_from_slice(&crc.to_be_bytes());
        Some(n)
    }

    /// Encodes the frame into a fixed buffer (infallible).
    pub fn encode(&self) -> FrameBuf {
        let mut buf = FrameBuf {
            bytes: [0; MAX_FRAME],
            len: 0,
        };
        // MAX_FRAME always fits a frame.
        buf.len = self.encode_into(&mut buf.bytes).unwrap_or(0);
        buf
    }
}

impl fmt::Debug for Frame {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Frame")
            .field("seq", &self.seq)
            .field("kind", &format_args!("{:#04x}", self.kind))
            .field("body", &self.body())
            .finish()
    }
}

/// An encoded frame in a fixed buffer.
#[derive(Clone, Copy)]
pub struct FrameBuf {
    bytes: [u8; MAX_FRAME],
    len: usize,
}

impl FrameBuf {
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..self.len]
    }
}

impl fmt::Debug for FrameBuf {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "FrameBuf({:02x?})", self.as_bytes())
    }
}

/// A frame the decoder had to throw away.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FrameError {
    /// The header announced a body longer than [`MAX_BODY`].
    Length(u8),
    /// The checksum did not match: the frame was corrupted on the line.
    Crc { expected: u16, got: u16 },
}

impl fmt::Display for FrameError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            FrameError::Length(n) => write!(
                f,
                "roller frame announces a {n}-byte body, more than the {MAX_BODY} allowed"
            ),
            FrameError::Crc { expected, got } => write!(
                f,
                "roller frame checksum mismatch (computed {expected:#06x}, frame says {got:#06x})"
            ),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for FrameError {}

/// Counters kept by the decoder, for diagnostics.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DecoderStats {
    pub frames: u32,
    pub crc_errors: u32,
    pub length_errors: u32,
    /// Bytes dropped while hunting for a sync pattern.
    pub skipped_bytes: u32,
}

/// Bounded incremental frame decoder: push bytes, get frames.
///
/// It holds at most [`MAX_FRAME`] bytes. After garbage or a corrupted frame
/// it drops one byte and hunts for the next sync pattern among the bytes it
/// already holds, so a good frame right after a bad one is never lost. It
/// never panics and never allocates.
#[derive(Clone)]
pub struct FrameDecoder {
    buf: [u8; MAX_FRAME],
    len: usize,
    stats: DecoderStats,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

enum Parsed {
    NeedMore,
    NotSync,
    Bad(FrameError),
    Good(Frame, usize),
}

impl FrameDecoder {
    pub const fn new() -> FrameDecoder {
        FrameDecoder {
            buf: [0; MAX_FRAME],
            len: 0,
            stats: DecoderStats {
                frames: 0,
                crc_errors: 0,
                length_errors: 0,
                skipped_bytes: 0,
            },
        }
    }

    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    /// Bytes held waiting for the rest of a frame.
    pub fn buffered(&self) -> usize {
        self.len
    }

    /// Forgets any partial frame (e.g. after the link was reopened).
    pub fn reset(&mut self) {
        self.len = 0;
    }

    /// Feeds `data`; iterate the result to get every frame (or framing error)
    /// it completes. Bytes not consumed when the iterator is dropped early are
    /// lost, so iterate to the end.
    pub fn feed<'a>(&'a mut self, data: &'a [u8]) -> Feed<'a> {
        Feed { dec: self, data }
    }

    /// Pushes one byte; returns a frame or framing error if one completed.
    /// (Any further complete frames already buffered are returned by the
    /// next calls of [`FrameDecoder::poll`].)
    pub fn push(&mut self, byte: u8) -> Option<Result<Frame, FrameError>> {
        let mut data: &[u8] = &[byte];
        self.next_item(&mut data)
    }

    /// Returns a frame or error already complete in the buffer, if any.
    pub fn poll(&mut self) -> Option<Result<Frame, FrameError>> {
        let mut data: &[u8] = &[];
        self.next_item(&mut data)
    }

    fn next_item(&mut self, input: &mut &[u8]) -> Option<Result<Frame, FrameError>> {
        loop {
            match self.parse() {
                Parsed::Good(frame, used) => {
                    self.consume(used);
                    self.stats.frames = self.stats.frames.wrapping_add(1);
                    return Some(Ok(frame));
                }
                Parsed::Bad(err) => {
                    match err {
                        FrameError::Length(_) => {
                            self.stats.length_errors = self.stats.length_errors.wrapping_add(1)
                        }
                        FrameError::Crc { .. } => {
                            self.stats.crc_errors = self.stats.crc_errors.wrapping_add(1)
                        }
                    }
                    self.resync();
                    return Some(Err(err));
                }
                Parsed::NotSync => self.resync(),
                Parsed::NeedMore => {
                    let (&b, rest) = input.split_first()?;
                    *input = rest;
                    if self.len == 0 && b != SYNC0 {
                        self.stats.skipped_bytes = self.stats.skipped_bytes.wrapping_add(1);
                        continue;
                    }
                    // parse() returned NeedMore, so len < the frame's length <= MAX_FRAME.
                    if let Some(slot) = self.buf.get_mut(self.len) {
                        *slot = b;
                        self.len += 1;
                    } else {
                        // Unreachable by the invariant; stay safe anyway.
                        self.resync();
                    }
                }
            }
        }
    }

    fn parse(&self) -> Parsed {
        let b = &self.buf[..self.len];
        if b.is_empty() {
            return Parsed::NeedMore;
        }
        if b[0] != SYNC0 {
            return Parsed::NotSync;
        }
        if b.len() < 2 {
            return Parsed::NeedMore;
        }
        if b[1] != SYNC1 {
            return Parsed::NotSync;
        }
        if b.len() < 3 {
            return Parsed::NeedMore;
        }
        let body_len = b[2] as usize;
        if body_len > MAX_BODY {
            return Parsed::Bad(FrameError::Length(b[2]));
        }
        let total = HEADER_LEN + body_len + 2;
        if b.len() < total {
            return Parsed::NeedMore;
        }
        let expected = crc16(&b[2..total - 2]);
        let got = u16::from_be_bytes([b[total - 2], b[total - 1]]);
        if expected != got {
            return Parsed::Bad(FrameError::Crc { expected, got });
        }
        match Frame::new(b[3], b[4], &b[HEADER_LEN..HEADER_LEN + body_len]) {
            Some(f) => Parsed::Good(f, total),
            None => Parsed::Bad(FrameError::Length(b[2])),
        }
    }

    fn consume(&mut self, n: usize) {
        let n = n.min(self.len);
        self.buf.copy_within(n..self.len, 0);
        self.len -= n;
    }

    /// Drops the first byte, then everything up to the next `SYNC0`.
    fn resync(&mut self) {
        if self.len == 0 {
            return;
        }
        let skip = self.buf[1..self.len]
            .iter()
            .position(|&x| x == SYNC0)
            .map(|p| p + 1)
            .unwrap_or(self.len);
        self.stats.skipped_bytes = self.stats.skipped_bytes.wrapping_add(skip as u32);
        self.consume(skip);
    }
}

/// Iterator returned by [`FrameDecoder::feed`].
pub struct Feed<'a> {
    dec: &'a mut FrameDecoder,
    data: &'a [u8],
}

impl Iterator for Feed<'_> {
    type Item = Result<Frame, FrameError>;
    fn next(&mut self) -> Option<Self::Item> {
        self.dec.next_item(&mut self.data)
    }
}

/// A frame that framed correctly but whose content is not a valid message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MessageError {
    UnknownKind(u8),
    BadLength { kind: u8, len: u8 },
    BadValue { kind: u8 },
}

impl MessageError {
    /// The error code the firmware reports for this error.
    pub fn code(&self) -> ErrorCode {
        match self {
            MessageError::UnknownKind(_) => ErrorCode::UnknownCommand,
            MessageError::BadLength { .. } => ErrorCode::BadLength,
            MessageError::BadValue { .. } => ErrorCode::BadArgument,
        }
    }
}

impl fmt::Display for MessageError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MessageError::UnknownKind(k) => write!(f, "unknown roller message kind {k:#04x}"),
            MessageError::BadLength { kind, len } => {
                write!(
                    f,
                    "roller message {kind:#04x} has a wrong body length {len}"
                )
            }
            MessageError::BadValue { kind } => {
                write!(f, "roller message {kind:#04x} carries an invalid value")
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for MessageError {}

/// Error codes carried by [`Reply::Error`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorCode {
    /// The command kind is not known to this firmware.
    UnknownCommand,
    /// The body length does not match the command.
    BadLength,
    /// A field is out of range (slot >= N, angle >= 360 degrees, zero speed, ...).
    BadArgument,
    /// The command needs the wheel at rest (e.g. `Zero` while moving).
    Busy,
    /// The host speaks a protocol version this firmware does not.
    UnsupportedProtocol,
    /// A code this side does not know (newer peer).
    Other(u8),
}

impl ErrorCode {
    pub fn to_u8(self) -> u8 {
        match self {
            ErrorCode::UnknownCommand => 1,
            ErrorCode::BadLength => 2,
            ErrorCode::BadArgument => 3,
            ErrorCode::Busy => 4,
            ErrorCode::UnsupportedProtocol => 5,
            ErrorCode::Other(c) => c,
        }
    }
    pub fn from_u8(c: u8) -> ErrorCode {
        match c {
            1 => ErrorCode::UnknownCommand,
            2 => ErrorCode::BadLength,
            3 => ErrorCode::BadArgument,
            4 => ErrorCode::Busy,
            5 => ErrorCode::UnsupportedProtocol,
            c => ErrorCode::Other(c),
        }
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ErrorCode::UnknownCommand => f.write_str("unknown command"),
            ErrorCode::BadLength => f.write_str("bad command length"),
            ErrorCode::BadArgument => f.write_str("argument out of range"),
            ErrorCode::Busy => f.write_str("busy: the wheel must be at rest"),
            ErrorCode::UnsupportedProtocol => f.write_str("unsupported protocol version"),
            ErrorCode::Other(c) => write!(f, "error code {c}"),
        }
    }
}

/// Commands, host -> roller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Command {
    /// Opens a session; the roller answers `Version`. Also a keepalive.
    Hello { protocol: u8 },
    /// Go to slot `slot` (angle = slot x 360 / N), shortest direction.
    GotoSlot { slot: u16 },
    /// Go to an absolute wheel angle in millidegrees (0..360000), shortest direction.
    GotoAngle { mdeg: u32 },
    /// Go to an absolute position in microsteps (0..steps_per_rev), shortest direction.
    GotoSteps { steps: u32 },
    /// Declares the current position to be zero (wheel must be at rest).
    Zero,
    /// Sets the maximum speed (microsteps/s) and acceleration (microsteps/s^2).
    SetMotion { max_speed: u32, accel: u32 },
    /// Sets the number of slots N on the wheel.
    SetSlots { slots: u16 },
    /// Asks for a `Status` reply. Also a keepalive.
    QueryStatus,
    /// Decelerates to a stop; the stop point becomes the target.
    Stop,
}

/// The roller's state as carried by `Ack`, `Arrived` and `Status`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Status {
    /// Current position in microsteps, `0..steps_per_rev`, clockwise from zero.
    pub position: u32,
    /// Target position in microsteps, `0..steps_per_rev`.
    pub target: u32,
    /// Signed speed in microsteps/s, positive = clockwise.
    pub speed: i32,
    /// Number of slots N.
    pub slots: u16,
    /// See [`status_flags`].
    pub flags: u8,
}

/// Bits of [`Status::flags`].
pub mod status_flags {
    /// The wheel is moving.
    pub const MOVING: u8 = 0x01;
    /// The driver is enabled (coils powered).
    pub const ENABLED: u8 = 0x02;
    /// The link watchdog stopped the wheel since the last host frame.
    pub const WATCHDOG: u8 = 0x04;
}

impl Status {
    pub fn moving(&self) -> bool {
        self.flags & status_flags::MOVING != 0
    }
    pub fn enabled(&self) -> bool {
        self.flags & status_flags::ENABLED != 0
    }
    pub fn watchdog_tripped(&self) -> bool {
        self.flags & status_flags::WATCHDOG != 0
    }
}

/// Identity and configuration, the answer to `Hello`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Version {
    pub protocol: u8,
    /// Firmware version major.minor.patch.
    pub firmware: [u8; 3],
    /// Microsteps per wheel revolution (e.g. 200 x 16 = 3200).
    pub steps_per_rev: u32,
    pub slots: u16,
    /// Link watchdog: the wheel stops after this long without a host frame.
    pub watchdog_ms: u32,
    pub max_speed: u32,
    pub accel: u32,
}

/// Replies, roller -> host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reply {
    Version(Version),
    /// The command with this frame's `SEQ` was accepted.
    Ack(Status),
    /// The wheel reached the target set by the command with this `SEQ`.
    Arrived(Status),
    /// The command with this `SEQ` failed (`command` is its kind, 0 if the
    /// kind could not be read).
    Error {
        code: ErrorCode,
        command: u8,
    },
    /// Answer to `QueryStatus`, and sent periodically while moving.
    Status(Status),
}

struct W<'a> {
    buf: &'a mut [u8; MAX_BODY],
    n: usize,
}

impl W<'_> {
    fn put(&mut self, b: &[u8]) {
        self.buf[self.n..self.n + b.len()].copy_from_slice(b);
        self.n += b.len();
    }
}

struct R<'a> {
    b: &'a [u8],
}

impl R<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        out.copy_from_slice(&self.b[..N]);
        self.b = &self.b[N..];
        out
    }
    fn u8(&mut self) -> u8 {
        self.take::<1>()[0]
    }
    fn u16(&mut self) -> u16 {
        u16::from_le_bytes(self.take())
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn i32(&mut self) -> i32 {
        i32::from_le_bytes(self.take())
    }
}

fn check_len(kind: u8, body: &[u8], want: usize) -> Result<R<'_>, MessageError> {
    if body.len() != want {
        return Err(MessageError::BadLength {
            kind,
            len: body.len() as u8,
        });
    }
    Ok(R { b: body })
}

const STATUS_LEN: usize = 15;
const VERSION_LEN: usize = 22;

impl Status {
    fn write(&self, w: &mut W<'_>) {
        w.put(&self.position.to_le_bytes());
        w.put(&self.target.to_le_bytes());
        w.put(&self.speed.to_le_bytes());
        w.put(&self.slots.to_le_bytes());
        w.put(&[self.flags]);
    }
    fn read(r: &mut R<'_>) -> Status {
        Status {
            position: r.u32(),
            target: r.u32(),
            speed: r.i32(),
            slots: r.u16(),
            flags: r.u8(),
        }
    }
}

impl Command {
    pub fn kind(&self) -> u8 {
        match self {
            Command::Hello { .. } => kind::HELLO,
            Command::GotoSlot { .. } => kind::GOTO_SLOT,
            Command::GotoAngle { .. } => kind::GOTO_ANGLE,
            Command::GotoSteps { .. } => kind::GOTO_STEPS,
            Command::Zero => kind::ZERO,
            Command::SetMotion { .. } => kind::SET_MOTION,
            Command::SetSlots { .. } => kind::SET_SLOTS,
            Command::QueryStatus => kind::QUERY_STATUS,
            Command::Stop => kind::STOP,
        }
    }

    /// Whether this command sets a new target (and so may later get `Arrived`).
    pub fn is_move(&self) -> bool {
        matches!(
            self,
            Command::GotoSlot { .. }
                | Command::GotoAngle { .. }
                | Command::GotoSteps { .. }
                | Command::Stop
        )
    }

    pub fn to_frame(&self, seq: u8) -> Frame {
        let mut body = [0u8; MAX_BODY];
        let mut w = W {
            buf: &mut body,
            n: 0,
        };
        match *self {
            Command::Hello { protocol } => w.put(&[protocol]),
            Command::GotoSlot { slot } => w.put(&slot.to_le_bytes()),
            Command::GotoAngle { mdeg } => w.put(&mdeg.to_le_bytes()),
            Command::GotoSteps { steps } => w.put(&steps.to_le_bytes()),
            Command::SetMotion { max_speed, accel } => {
                w.put(&max_speed.to_le_bytes());
                w.put(&accel.to_le_bytes());
            }
            Command::SetSlots { slots } => w.put(&slots.to_le_bytes()),
            Command::Zero | Command::QueryStatus | Command::Stop => {}
        }
        let n = w.n;
        Frame {
            seq,
            kind: self.kind(),
            body,
            body_len: n as u8,
        }
    }

    /// Encodes the command as a complete frame.
    pub fn encode(&self, seq: u8) -> FrameBuf {
        self.to_frame(seq).encode()
    }

    /// Parses a command from a frame. Range checks that depend on the
    /// roller's configuration (slot < N, ...) are the firmware's job; this
    /// only rejects values that are invalid for every roller.
    pub fn from_frame(frame: &Frame) -> Result<Command, MessageError> {
        let k = frame.kind;
        let b = frame.body();
        Ok(match k {
            kind::HELLO => Command::Hello {
                protocol: check_len(k, b, 1)?.u8(),
            },
            kind::GOTO_SLOT => Command::GotoSlot {
                slot: check_len(k, b, 2)?.u16(),
            },
            kind::GOTO_ANGLE => {
                let mdeg = check_len(k, b, 4)?.u32();
                if mdeg >= FULL_TURN_MDEG {
                    return Err(MessageError::BadValue { kind: k });
                }
                Command::GotoAngle { mdeg }
            }
            kind::GOTO_STEPS => Command::GotoSteps {
                steps: check_len(k, b, 4)?.u32(),
            },
            kind::ZERO => {
                check_len(k, b, 0)?;
                Command::Zero
            }
            kind::SET_MOTION => {
                let mut r = check_len(k, b, 8)?;
                let (max_speed, accel) = (r.u32(), r.u32());
                if max_speed == 0 || accel == 0 {
                    return Err(MessageError::BadValue { kind: k });
                }
                Command::SetMotion { max_speed, accel }
            }
            kind::SET_SLOTS => {
                let slots = check_len(k, b, 2)?.u16();
                if slots == 0 {
                    return Err(MessageError::BadValue { kind: k });
                }
                Command::SetSlots { slots }
            }
            kind::QUERY_STATUS => {
                check_len(k, b, 0)?;
                Command::QueryStatus
            }
            kind::STOP => {
                check_len(k, b, 0)?;
                Command::Stop
            }
            _ => return Err(MessageError::UnknownKind(k)),
        })
    }
}

impl Reply {
    pub fn kind(&self) -> u8 {
        match self {
            Reply::Version(_) => kind::VERSION,
            Reply::Ack(_) => kind::ACK,
            Reply::Arrived(_) => kind::ARRIVED,
            Reply::Error { .. } => kind::ERROR,
            Reply::Status(_) => kind::STATUS,
        }
    }

    pub fn to_frame(&self, seq: u8) -> Frame {
        let mut body = [0u8; MAX_BODY];
        let mut w = W {
            buf: &mut body,
            n: 0,
        };
        match self {
            Reply::Version(v) => {
                w.put(&[v.protocol]);
                w.put(&v.firmware);
                w.put(&v.steps_per_rev.to_le_bytes());
                w.put(&v.slots.to_le_bytes());
                w.put(&v.watchdog_ms.to_le_bytes());
                w.put(&v.max_speed.to_le_bytes());
                w.put(&v.accel.to_le_bytes());
            }
            Reply::Ack(s) | Reply::Arrived(s) | Reply::Status(s) => s.write(&mut w),
            Reply::Error { code, command } => w.put(&[code.to_u8(), *command]),
        }
        let n = w.n;
        Frame {
            seq,
            kind: self.kind(),
            body,
            body_len: n as u8,
        }
    }

    pub fn encode(&self, seq: u8) -> FrameBuf {
        self.to_frame(seq).encode()
    }

    pub fn from_frame(frame: &Frame) -> Result<Reply, MessageError> {
        let k = frame.kind;
        let b = frame.body();
        Ok(match k {
            kind::VERSION => {
                let mut r = check_len(k, b, VERSION_LEN)?;
                Reply::Version(Version {
                    protocol: r.u8(),
                    firmware: r.take(),
                    steps_per_rev: r.u32(),
                    slots: r.u16(),
                    watchdog_ms: r.u32(),
                    max_speed: r.u32(),
                    accel: r.u32(),
                })
            }
            kind::ACK => Reply::Ack(Status::read(&mut check_len(k, b, STATUS_LEN)?)),
            kind::ARRIVED => Reply::Arrived(Status::read(&mut check_len(k, b, STATUS_LEN)?)),
            kind::STATUS => Reply::Status(Status::read(&mut check_len(k, b, STATUS_LEN)?)),
            kind::ERROR => {
                let mut r = check_len(k, b, 2)?;
                Reply::Error {
                    code: ErrorCode::from_u8(r.u8()),
                    command: r.u8(),
                }
            }
            _ => return Err(MessageError::UnknownKind(k)),
        })
    }
}

/// Microsteps for an angle in millidegrees, rounded to nearest, modulo one turn.
pub fn mdeg_to_steps(mdeg: u32, steps_per_rev: u32) -> u32 {
    if steps_per_rev == 0 {
        return 0;
    }
    let s = ((mdeg as u64 % FULL_TURN_MDEG as u64) * steps_per_rev as u64
        + FULL_TURN_MDEG as u64 / 2)
        / FULL_TURN_MDEG as u64;
    (s % steps_per_rev as u64) as u32
}

/// Angle in millidegrees for a position in microsteps (rounded to nearest).
pub fn steps_to_mdeg(steps: u32, steps_per_rev: u32) -> u32 {
    if steps_per_rev == 0 {
        return 0;
    }
    let m = ((steps % steps_per_rev) as u64 * FULL_TURN_MDEG as u64 + steps_per_rev as u64 / 2)
        / steps_per_rev as u64;
    (m % FULL_TURN_MDEG as u64) as u32
}

/// The paper's geometry: slot `slot` of `slots` sits at `slot x 360 / N`
/// degrees; in microsteps, rounded to nearest.
pub fn slot_to_steps(slot: u16, slots: u16, steps_per_rev: u32) -> u32 {
    if slots == 0 || steps_per_rev == 0 {
        return 0;
    }
    let s = ((slot % slots) as u64 * steps_per_rev as u64 + slots as u64 / 2) / slots as u64;
    (s % steps_per_rev as u64) as u32
}

/// The slot whose position equals `steps` exactly, if any.
pub fn steps_to_slot(steps: u32, slots: u16, steps_per_rev: u32) -> Option<u16> {
    if slots == 0 || steps_per_rev == 0 {
        return None;
    }
    let guess = ((steps as u64 * slots as u64 + steps_per_rev as u64 / 2) / steps_per_rev as u64)
        % slots as u64;
    let guess = guess as u16;
    (slot_to_steps(guess, slots, steps_per_rev) == steps % steps_per_rev).then_some(guess)
}

/// Shortest signed move in microsteps from `from` to `to` on a wheel of
/// `steps_per_rev` (positive = clockwise). The paper's rule: clockwise if
/// that is shorter, else counter-clockwise, so an exact half turn goes
/// counter-clockwise.
pub fn shortest_delta(from: u32, to: u32, steps_per_rev: u32) -> i32 {
    if steps_per_rev == 0 {
        return 0;
    }
    let spr = steps_per_rev as i64;
    let cw = (to as i64 - from as i64).rem_euclid(spr);
    if cw < spr - cw {
        cw as i32
    } else {
        (cw - spr) as i32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_check_value() {
        // The catalogue check value of CRC-16/CCITT-FALSE.
        assert_eq!(crc16(b"123456789"), 0x29B1);
    }

    #[test]
    fn hello_frame_bytes() {
        let f = Command::Hello { protocol: 1 }.encode(7);
        let b = f.as_bytes();
        assert_eq!(&b[..6], &[0xA5, 0x5A, 1, 7, 0x01, 1]);
        assert_eq!(
            u16::from_be_bytes([b[6], b[7]]),
            crc16(&[1, 7, 0x01, 1]),
            "crc over len, seq, kind, body"
        );
        assert_eq!(b.len(), 8);
    }

    #[test]
    fn geometry() {
        assert_eq!(slot_to_steps(0, 16, 3200), 0);
        assert_eq!(slot_to_steps(1, 16, 3200), 200);
        assert_eq!(slot_to_steps(15, 16, 3200), 3000);
        assert_eq!(slot_to_steps(1, 7, 3200), 457);
        assert_eq!(steps_to_slot(200, 16, 3200), Some(1));
        assert_eq!(steps_to_slot(201, 16, 3200), None);
        assert_eq!(mdeg_to_steps(90_000, 3200), 800);
        assert_eq!(steps_to_mdeg(800, 3200), 90_000);
        assert_eq!(shortest_delta(0, 200, 3200), 200);
        assert_eq!(shortest_delta(0, 3000, 3200), -200);
        assert_eq!(shortest_delta(3100, 100, 3200), 200);
        assert_eq!(shortest_delta(100, 3100, 3200), -200);
        assert_eq!(
            shortest_delta(0, 1600, 3200),
            -1600,
            "half turn: counter-clockwise"
        );
        assert_eq!(shortest_delta(5, 5, 3200), 0);
    }
}
