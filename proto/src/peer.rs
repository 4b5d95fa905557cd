//! Peer-to-peer wire protocol between two Telextiles daemons (sans-IO).
//!
//! Two channels share one QUIC connection:
//!
//! * a reliable, ordered **control stream** carrying [`Control`] messages,
//!   each framed as `u32 little-endian length | bincode 2 payload`
//!   (see [`encode_control`] and [`FrameDecoder`]), at most
//!   [`MAX_CONTROL_FRAME`] bytes of payload;
//! * unreliable **latent datagrams** ([`LatentFrame`]) with a fixed,
//!   hand-laid binary layout (see [`LatentFrame::encode`]) so that one
//!   512-d quantised vector fits one QUIC datagram.
//!
//! Also here, because they are pure: the "latest wins" receiver filter
//! ([`LatestWins`]), the NTP-style clock-offset estimator
//! ([`ClockOffset`]) and the hello compatibility check ([`check_hello`]).
//!
//! Every decoder returns an error for bad input and never panics.
//! The full specification is `docs/peer-protocol.md`.

use alloc::string::String;
use alloc::vec::Vec;
use core::fmt;
use serde::{Deserialize, Serialize};

use crate::pairing::{PairingMessage, MAX_PAKE_MESSAGE_LEN};

/// Version of this protocol. Sent in [`Hello`] and in the mDNS TXT record.
/// 2: the link runs on iroh (raw-key TLS, ALPN `telextiles/2`); 1 ran on
/// quinn with certificates, and the two cannot connect.
pub const PROTOCOL_VERSION: u16 = 2;
/// Largest control payload (after the 4-byte length prefix) accepted.
pub const MAX_CONTROL_FRAME: usize = 64 * 1024;
/// Largest vector dimension carried by a latent frame.
pub const MAX_DIM: usize = 2048;
/// Longest device name, in bytes.
pub const MAX_NAME_LEN: usize = 64;
/// Longest hash / fingerprint string, in bytes.
pub const MAX_HASH_LEN: usize = 128;
/// Longest free-text message (errors), in bytes.
pub const MAX_TEXT_LEN: usize = 1024;
/// Version byte at the start of every latent datagram.
pub const DATAGRAM_VERSION: u8 = 1;
/// Bytes of a latent datagram before the vector payload.
pub const DATAGRAM_HEADER_LEN: usize = 25;
/// Largest magnitude a latent component may have after dequantisation.
/// Latents are L2-normalised (|x| <= 1); the bound leaves room for models
/// that are not, while keeping a receiver's f32 sums of squares finite for
/// every dimension up to [`MAX_DIM`].
pub const MAX_LATENT_ABS: f32 = 1.0e9;

/// Everything that can be wrong with bytes received from a peer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum PeerError {
    /// A control frame announced a payload larger than [`MAX_CONTROL_FRAME`].
    FrameTooLarge { len: usize, max: usize },
    /// The payload is not a valid bincode encoding of a [`Control`] message.
    Decode(String),
    /// The message was encoded but leaves bytes unconsumed.
    TrailingBytes { extra: usize },
    /// A field breaks a size or value limit.
    Limit(&'static str),
    /// A datagram is shorter than its header or vector says.
    Truncated { need: usize, got: usize },
    /// A datagram starts with an unknown version byte.
    BadDatagramVersion(u8),
    /// A datagram carries an unknown vector encoding.
    BadEncoding(u8),
    /// The message could not be encoded (too large or unencodable).
    Encode(String),
}

impl fmt::Display for PeerError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PeerError::FrameTooLarge { len, max } => {
                write!(f, "control frame of {len} bytes exceeds the {max}-byte limit")
            }
            PeerError::Decode(e) => write!(f, "malformed control message: {e}"),
            PeerError::TrailingBytes { extra } => {
                write!(f, "control message followed by {extra} unexpected bytes")
            }
            PeerError::Limit(what) => write!(f, "message field out of limits: {what}"),
            PeerError::Truncated { need, got } => {
                write!(f, "latent datagram truncated: need {need} bytes, got {got}")
            }
            PeerError::BadDatagramVersion(v) => write!(
                f,
                "latent datagram version {v} is not supported (this build speaks {DATAGRAM_VERSION})"
            ),
            PeerError::BadEncoding(e) => write!(f, "unknown latent vector encoding {e}"),
            PeerError::Encode(e) => write!(f, "cannot encode message: {e}"),
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for PeerError {}

// ---------------------------------------------------------------------------
// Control messages
// ---------------------------------------------------------------------------

/// First message each side sends on the control stream.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Hello {
    /// Must stay the first field in every future version.
    pub protocol_version: u16,
    /// Human-readable name of the device (shown to the other user).
    pub device_name: String,
    /// Hex SHA-256 of the ONNX encoder file.
    pub encoder_hash: String,
    /// Content fingerprint of the textile index.
    pub index_fingerprint: String,
    /// Dimension of the latents this side sends.
    pub embedding_dim: u16,
}

/// Why two hellos are incompatible.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub enum MismatchReason {
    ProtocolVersion { ours: u16, theirs: u16 },
    EncoderHash { ours: String, theirs: String },
    IndexFingerprint { ours: String, theirs: String },
    EmbeddingDim { ours: u16, theirs: u16 },
}

impl fmt::Display for MismatchReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MismatchReason::ProtocolVersion { ours, theirs } => write!(
                f,
                "protocol version differs (this device speaks {ours}, the peer {theirs}): update both daemons to the same release"
            ),
            MismatchReason::EncoderHash { ours, theirs } => write!(
                f,
                "encoder model differs (this device {}, the peer {}): install the same encoder on both devices",
                short(ours),
                short(theirs)
            ),
            MismatchReason::IndexFingerprint { ours, theirs } => write!(
                f,
                "textile index differs (this device {}, the peer {}): install the same index on both devices",
                short(ours),
                short(theirs)
            ),
            MismatchReason::EmbeddingDim { ours, theirs } => write!(
                f,
                "embedding dimension differs (this device {ours}, the peer {theirs})"
            ),
        }
    }
}

fn short(s: &str) -> &str {
    s.get(..12).unwrap_or(s)
}

/// Error codes carried by [`Control::Error`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum ErrorCode {
    /// The peer broke the protocol (bad message, wrong order).
    Protocol,
    /// Hello mismatch; details in [`Control::Mismatch`].
    Incompatible,
    /// Pairing failed.
    Pairing,
    /// Anything else; see the message.
    Other,
}

/// A message on the reliable control stream.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum Control {
    Hello(Hello),
    /// The peer's hello is compatible; streaming may start.
    HelloAck,
    /// The peer's hello is incompatible; no streaming. Sent by both sides.
    Mismatch {
        reasons: Vec<MismatchReason>,
    },
    /// The sender starts pressing a fabric. `capture_us`: the capture time
    /// (sender's clock) of the first frame of the contact detector's run
    /// that started the press, encoded or not.
    PressStart {
        press_id: u32,
        capture_us: u64,
    },
    /// The press ended. Carries the press's final latent so the receiver's
    /// final decision never depends on a lost datagram.
    PressStop {
        press_id: u32,
        capture_us: u64,
        final_latent: Option<LatentFrame>,
    },
    /// Clock probe; `t1_us` is the sender's clock at sending.
    Ping {
        id: u32,
        t1_us: u64,
    },
    /// Answer: `t2_us` responder clock at receipt, `t3_us` at sending.
    Pong {
        id: u32,
        t1_us: u64,
        t2_us: u64,
        t3_us: u64,
    },
    Error {
        code: ErrorCode,
        message: String,
    },
    /// Pairing exchange (see [`crate::pairing`]).
    Pair(PairingMessage),
}

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard().with_limit::<MAX_CONTROL_FRAME>()
}

fn check_str(s: &str, max: usize, what: &'static str) -> Result<(), PeerError> {
    if s.len() > max {
        Err(PeerError::Limit(what))
    } else {
        Ok(())
    }
}

impl Hello {
    fn validate(&self) -> Result<(), PeerError> {
        check_str(&self.device_name, MAX_NAME_LEN, "device name too long")?;
        check_str(&self.encoder_hash, MAX_HASH_LEN, "encoder hash too long")?;
        check_str(
            &self.index_fingerprint,
            MAX_HASH_LEN,
            "index fingerprint too long",
        )?;
        if self.embedding_dim as usize > MAX_DIM {
            return Err(PeerError::Limit("embedding dimension too large"));
        }
        Ok(())
    }
}

impl Control {
    /// Checks every size limit of the message.
    pub fn validate(&self) -> Result<(), PeerError> {
        match self {
            Control::Hello(h) => h.validate(),
            Control::Mismatch { reasons } => {
                if reasons.len() > 8 {
                    return Err(PeerError::Limit("too many mismatch reasons"));
                }
                for r in reasons {
                    match r {
                        MismatchReason::EncoderHash { ours, theirs }
                        | MismatchReason::IndexFingerprint { ours, theirs } => {
                            check_str(ours, MAX_HASH_LEN, "hash too long")?;
                            check_str(theirs, MAX_HASH_LEN, "hash too long")?;
                        }
                        _ => {}
                    }
                }
                Ok(())
            }
            Control::PressStop {
                final_latent: Some(l),
                ..
            } => l.validate(),
            Control::Error { message, .. } => {
                check_str(message, MAX_TEXT_LEN, "error text too long")
            }
            Control::Pair(PairingMessage::Start(st)) => {
                if st.pake.len() > MAX_PAKE_MESSAGE_LEN {
                    Err(PeerError::Limit("pairing PAKE message too large"))
                } else {
                    Ok(())
                }
            }
            _ => Ok(()),
        }
    }
}

/// Encodes one control message as a frame: `u32 LE length | payload`.
pub fn encode_control(msg: &Control) -> Result<Vec<u8>, PeerError> {
    msg.validate()?;
    let payload = bincode::serde::encode_to_vec(msg, bincode_config())
        .map_err(|e| PeerError::Encode(alloc::format!("{e}")))?;
    if payload.len() > MAX_CONTROL_FRAME {
        return Err(PeerError::FrameTooLarge {
            len: payload.len(),
            max: MAX_CONTROL_FRAME,
        });
    }
    let mut out = Vec::with_capacity(4 + payload.len());
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(&payload);
    Ok(out)
}

/// Decodes one control payload (without the length prefix).
pub fn decode_control_payload(payload: &[u8]) -> Result<Control, PeerError> {
    if payload.len() > MAX_CONTROL_FRAME {
        return Err(PeerError::FrameTooLarge {
            len: payload.len(),
            max: MAX_CONTROL_FRAME,
        });
    }
    let (msg, used): (Control, usize) =
        bincode::serde::decode_from_slice(payload, bincode_config())
            .map_err(|e| PeerError::Decode(alloc::format!("{e}")))?;
    if used != payload.len() {
        return Err(PeerError::TrailingBytes {
            extra: payload.len() - used,
        });
    }
    msg.validate()?;
    Ok(msg)
}

/// Incremental decoder for the control stream: feed bytes as they arrive,
/// take whole messages out. After an error the stream is unusable.
#[derive(Debug, Default)]
pub struct FrameDecoder {
    buf: Vec<u8>,
}

impl FrameDecoder {
    pub fn new() -> Self {
        Self::default()
    }

    /// Appends received bytes.
    pub fn push(&mut self, bytes: &[u8]) {
        self.buf.extend_from_slice(bytes);
    }

    /// Bytes buffered but not yet decoded.
    pub fn buffered(&self) -> usize {
        self.buf.len()
    }

    /// Length the next frame needs in total, if its prefix is complete.
    /// Errors as soon as the prefix announces an oversized frame.
    pub fn next_frame_len(&self) -> Result<Option<usize>, PeerError> {
        if self.buf.len() < 4 {
            return Ok(None);
        }
        let len = u32::from_le_bytes([self.buf[0], self.buf[1], self.buf[2], self.buf[3]]) as usize;
        if len > MAX_CONTROL_FRAME {
            return Err(PeerError::FrameTooLarge {
                len,
                max: MAX_CONTROL_FRAME,
            });
        }
        Ok(Some(4 + len))
    }

    /// The next complete message, `Ok(None)` if more bytes are needed.
    pub fn next_message(&mut self) -> Result<Option<Control>, PeerError> {
        let Some(total) = self.next_frame_len()? else {
            return Ok(None);
        };
        if self.buf.len() < total {
            return Ok(None);
        }
        let msg = decode_control_payload(&self.buf[4..total]);
        self.buf.drain(..total);
        msg.map(Some)
    }
}

/// Compares our hello with the peer's. `Err` lists every difference.
pub fn check_hello(ours: &Hello, theirs: &Hello) -> Result<(), Vec<MismatchReason>> {
    let mut reasons = Vec::new();
    if ours.protocol_version != theirs.protocol_version {
        reasons.push(MismatchReason::ProtocolVersion {
            ours: ours.protocol_version,
            theirs: theirs.protocol_version,
        });
    }
    if ours.encoder_hash != theirs.encoder_hash {
        reasons.push(MismatchReason::EncoderHash {
            ours: ours.encoder_hash.clone(),
            theirs: theirs.encoder_hash.clone(),
        });
    }
    if ours.index_fingerprint != theirs.index_fingerprint {
        reasons.push(MismatchReason::IndexFingerprint {
            ours: ours.index_fingerprint.clone(),
            theirs: theirs.index_fingerprint.clone(),
        });
    }
    if ours.embedding_dim != theirs.embedding_dim {
        reasons.push(MismatchReason::EmbeddingDim {
            ours: ours.embedding_dim,
            theirs: theirs.embedding_dim,
        });
    }
    if reasons.is_empty() {
        Ok(())
    } else {
        Err(reasons)
    }
}

// ---------------------------------------------------------------------------
// Latent datagrams
// ---------------------------------------------------------------------------

/// A quantised latent vector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum QuantVec {
    /// `value[i] = data[i] as f32 * scale`; `scale = max|x| / 127`.
    I8 { scale: f32, data: Vec<i8> },
    /// IEEE 754 binary16 bit patterns.
    F16(Vec<u16>),
}

const ENC_I8: u8 = 0;
const ENC_F16: u8 = 1;

fn abs(x: f32) -> f32 {
    if x < 0.0 {
        -x
    } else {
        x
    }
}

fn round_to_i8(y: f32) -> i8 {
    let r = if y >= 0.0 { y + 0.5 } else { y - 0.5 };
    // `as` saturates, and maps NaN to 0.
    r.clamp(-127.0, 127.0) as i8
}

impl QuantVec {
    /// Symmetric int8 quantisation with one f32 scale per vector.
    /// Non-finite inputs become 0.
    pub fn quantize_i8(v: &[f32]) -> QuantVec {
        let max =
            v.iter()
                .filter(|x| x.is_finite())
                .fold(0.0f32, |m, &x| if abs(x) > m { abs(x) } else { m });
        let scale = if max > 0.0 { max / 127.0 } else { 1.0 };
        let inv = 1.0 / scale;
        let data = v
            .iter()
            .map(|&x| {
                if x.is_finite() {
                    round_to_i8(x * inv)
                } else {
                    0
                }
            })
            .collect();
        QuantVec::I8 { scale, data }
    }

    /// Half-precision quantisation (round to nearest even). Non-finite
    /// inputs become 0 and values beyond the f16 range saturate at
    /// ±65504, so the result is always a valid latent.
    pub fn quantize_f16(v: &[f32]) -> QuantVec {
        QuantVec::F16(
            v.iter()
                .map(|&x| {
                    if x.is_finite() {
                        f32_to_f16(x.clamp(-65504.0, 65504.0))
                    } else {
                        0
                    }
                })
                .collect(),
        )
    }

    /// Number of components.
    pub fn dim(&self) -> usize {
        match self {
            QuantVec::I8 { data, .. } => data.len(),
            QuantVec::F16(d) => d.len(),
        }
    }

    /// Back to f32.
    pub fn dequantize(&self) -> Vec<f32> {
        match self {
            QuantVec::I8 { scale, data } => data.iter().map(|&q| q as f32 * scale).collect(),
            QuantVec::F16(d) => d.iter().map(|&h| f16_to_f32(h)).collect(),
        }
    }

    /// Encoded payload size in bytes.
    pub fn encoded_len(&self) -> usize {
        match self {
            QuantVec::I8 { data, .. } => 4 + data.len(),
            QuantVec::F16(d) => 2 * d.len(),
        }
    }
}

/// Converts f32 to IEEE binary16 bits, round to nearest even; overflow → ±inf.
pub fn f32_to_f16(x: f32) -> u16 {
    let bits = x.to_bits();
    let sign = ((bits >> 16) & 0x8000) as u16;
    let exp = ((bits >> 23) & 0xff) as i32;
    let man = bits & 0x7f_ffff;
    if exp == 0xff {
        // inf or NaN (keep a quiet NaN)
        return sign | 0x7c00 | if man != 0 { 0x200 } else { 0 };
    }
    let e = exp - 127 + 15;
    if e >= 0x1f {
        return sign | 0x7c00;
    }
    if e <= 0 {
        if e < -10 {
            return sign;
        }
        let m = man | 0x80_0000;
        let shift = (14 - e) as u32;
        let half = m >> shift;
        let rem = m & ((1 << shift) - 1);
        let halfway = 1u32 << (shift - 1);
        let rounded = if rem > halfway || (rem == halfway && (half & 1) == 1) {
            half + 1
        } else {
            half
        };
        return sign | rounded as u16;
    }
    let half = ((e as u32) << 10) | (man >> 13);
    let rem = man & 0x1fff;
    let rounded = if rem > 0x1000 || (rem == 0x1000 && (half & 1) == 1) {
        half + 1
    } else {
        half
    };
    // A carry into the exponent is correct (and yields inf at the top).
    sign | rounded as u16
}

/// Converts IEEE binary16 bits to f32 (exact).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = ((h & 0x8000) as u32) << 16;
    let exp = ((h >> 10) & 0x1f) as u32;
    let man = (h & 0x3ff) as u32;
    let bits = if exp == 0 {
        if man == 0 {
            sign
        } else {
            // subnormal: normalise
            let mut e: i32 = -14;
            let mut m = man;
            while m & 0x400 == 0 {
                m <<= 1;
                e -= 1;
            }
            sign | (((e + 127) as u32) << 23) | ((m & 0x3ff) << 13)
        }
    } else if exp == 0x1f {
        sign | 0x7f80_0000 | (man << 13)
    } else {
        sign | ((exp + 127 - 15) << 23) | (man << 13)
    };
    f32::from_bits(bits)
}

/// Flag bit: this frame is the last of its press.
pub const FLAG_FINAL: u8 = 1;

/// One latent vector in flight, sent as a QUIC datagram.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LatentFrame {
    /// Per-sender, strictly increasing across presses.
    pub seq: u64,
    /// Sender's clock (µs) when the frame was captured.
    pub capture_us: u64,
    /// Press this frame belongs to.
    pub press_id: u32,
    /// [`FLAG_FINAL`], other bits reserved (0).
    pub flags: u8,
    pub vector: QuantVec,
}

impl LatentFrame {
    fn validate(&self) -> Result<(), PeerError> {
        if self.vector.dim() > MAX_DIM {
            return Err(PeerError::Limit("latent dimension too large"));
        }
        // Every component the receiver computes from the frame must be a
        // finite number of bounded size.
        match &self.vector {
            QuantVec::I8 { scale, .. } => {
                if !scale.is_finite() || *scale < 0.0 {
                    return Err(PeerError::Limit(
                        "latent scale not a finite non-negative number",
                    ));
                }
                if *scale > MAX_LATENT_ABS / 127.0 {
                    return Err(PeerError::Limit("latent scale too large"));
                }
            }
            QuantVec::F16(d) => {
                // Exponent all ones: infinity or NaN.
                if d.iter().any(|h| h & 0x7c00 == 0x7c00) {
                    return Err(PeerError::Limit("latent component not finite"));
                }
            }
        }
        Ok(())
    }

    /// Size of [`LatentFrame::encode`]'s output.
    pub fn encoded_len(&self) -> usize {
        DATAGRAM_HEADER_LEN + self.vector.encoded_len()
    }

    /// Datagram layout, all little-endian:
    /// `version u8 | encoding u8 | dim u16 | seq u64 | capture_us u64 |
    /// press_id u32 | flags u8 | payload`, payload = `scale f32 | dim × i8`
    /// (int8) or `dim × u16` (f16).
    pub fn encode(&self) -> Result<Vec<u8>, PeerError> {
        self.validate()?;
        let dim = self.vector.dim();
        let mut out = Vec::with_capacity(self.encoded_len());
        out.push(DATAGRAM_VERSION);
        out.push(match self.vector {
            QuantVec::I8 { .. } => ENC_I8,
            QuantVec::F16(_) => ENC_F16,
        });
        out.extend_from_slice(&(dim as u16).to_le_bytes());
        out.extend_from_slice(&self.seq.to_le_bytes());
        out.extend_from_slice(&self.capture_us.to_le_bytes());
        out.extend_from_slice(&self.press_id.to_le_bytes());
        out.push(self.flags);
        match &self.vector {
            QuantVec::I8 { scale, data } => {
                out.extend_from_slice(&scale.to_le_bytes());
                out.extend(data.iter().map(|&q| q as u8));
            }
            QuantVec::F16(d) => {
                for h in d {
                    out.extend_from_slice(&h.to_le_bytes());
                }
            }
        }
        Ok(out)
    }

    /// Parses a datagram; any malformed input is an error, never a panic.
    pub fn decode(b: &[u8]) -> Result<LatentFrame, PeerError> {
        if b.len() < DATAGRAM_HEADER_LEN {
            return Err(PeerError::Truncated {
                need: DATAGRAM_HEADER_LEN,
                got: b.len(),
            });
        }
        if b[0] != DATAGRAM_VERSION {
            return Err(PeerError::BadDatagramVersion(b[0]));
        }
        let enc = b[1];
        let dim = u16::from_le_bytes([b[2], b[3]]) as usize;
        if dim > MAX_DIM {
            return Err(PeerError::Limit("latent dimension too large"));
        }
        let u64_at = |i: usize| {
            let mut a = [0u8; 8];
            a.copy_from_slice(&b[i..i + 8]);
            u64::from_le_bytes(a)
        };
        let seq = u64_at(4);
        let capture_us = u64_at(12);
        let press_id = u32::from_le_bytes([b[20], b[21], b[22], b[23]]);
        let flags = b[24];
        let p = &b[DATAGRAM_HEADER_LEN..];
        let vector = match enc {
            ENC_I8 => {
                let need = 4 + dim;
                if p.len() != need {
                    return Err(PeerError::Truncated {
                        need: DATAGRAM_HEADER_LEN + need,
                        got: b.len(),
                    });
                }
                let scale = f32::from_le_bytes([p[0], p[1], p[2], p[3]]);
                QuantVec::I8 {
                    scale,
                    data: p[4..].iter().map(|&x| x as i8).collect(),
                }
            }
            ENC_F16 => {
                let need = 2 * dim;
                if p.len() != need {
                    return Err(PeerError::Truncated {
                        need: DATAGRAM_HEADER_LEN + need,
                        got: b.len(),
                    });
                }
                QuantVec::F16(
                    p.chunks_exact(2)
                        .map(|c| u16::from_le_bytes([c[0], c[1]]))
                        .collect(),
                )
            }
            other => return Err(PeerError::BadEncoding(other)),
        };
        let frame = LatentFrame {
            seq,
            capture_us,
            press_id,
            flags,
            vector,
        };
        frame.validate()?;
        Ok(frame)
    }

    /// Whether this is the last frame of its press.
    pub fn is_final(&self) -> bool {
        self.flags & FLAG_FINAL != 0
    }
}

/// Quantises `v` with the densest encoding that fits `max_datagram` bytes:
/// f16 if it fits, else int8. `None` if not even int8 fits.
pub fn quantize_to_fit(v: &[f32], max_datagram: usize) -> Option<QuantVec> {
    if DATAGRAM_HEADER_LEN + 2 * v.len() <= max_datagram {
        Some(QuantVec::quantize_f16(v))
    } else if DATAGRAM_HEADER_LEN + 4 + v.len() <= max_datagram {
        Some(QuantVec::quantize_i8(v))
    } else {
        None
    }
}

// ---------------------------------------------------------------------------
// Latest wins
// ---------------------------------------------------------------------------

/// Receiver filter: accepts a frame only if its sequence number is newer
/// than every frame accepted before. Reset it when a new connection starts.
#[derive(Debug, Default, Clone)]
pub struct LatestWins {
    last: Option<u64>,
    accepted: u64,
    dropped: u64,
}

impl LatestWins {
    pub fn new() -> Self {
        Self::default()
    }

    /// `true` if the frame is fresh (deliver it), `false` if stale/duplicate.
    pub fn accept(&mut self, seq: u64) -> bool {
        match self.last {
            Some(l) if seq <= l => {
                self.dropped += 1;
                false
            }
            _ => {
                self.last = Some(seq);
                self.accepted += 1;
                true
            }
        }
    }

    pub fn last(&self) -> Option<u64> {
        self.last
    }
    pub fn accepted(&self) -> u64 {
        self.accepted
    }
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

// ---------------------------------------------------------------------------
// Clock offset
// ---------------------------------------------------------------------------

/// One ping/pong exchange, all in µs: `t1` our send, `t2` peer receipt,
/// `t3` peer send (peer clock), `t4` our receipt.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockSample {
    pub t1: u64,
    pub t2: u64,
    pub t3: u64,
    pub t4: u64,
}

/// `v` clamped into `i64` (the estimator's results saturate instead of
/// overflowing on nonsense timestamps from a peer).
fn sat_i64(v: i128) -> i64 {
    v.clamp(i64::MIN as i128, i64::MAX as i128) as i64
}

impl ClockSample {
    /// Round-trip time minus the peer's processing time (µs). Every field
    /// comes (in part) from the peer, so the arithmetic is done in `i128`
    /// and saturates: no input can overflow or panic.
    pub fn rtt(&self) -> i64 {
        let (t1, t2, t3, t4) = (
            self.t1 as i128,
            self.t2 as i128,
            self.t3 as i128,
            self.t4 as i128,
        );
        sat_i64((t4 - t1) - (t3 - t2))
    }
    /// Estimated `peer_clock - our_clock` (µs), saturating like [`Self::rtt`].
    pub fn offset(&self) -> i64 {
        let (t1, t2, t3, t4) = (
            self.t1 as i128,
            self.t2 as i128,
            self.t3 as i128,
            self.t4 as i128,
        );
        sat_i64(((t2 - t1) + (t3 - t4)) / 2)
    }
}

/// NTP-style offset estimator: keeps the last `window` samples and trusts
/// the one with the smallest round trip (least queueing asymmetry).
#[derive(Debug, Clone)]
pub struct ClockOffset {
    samples: Vec<ClockSample>,
    window: usize,
    next: usize,
}

impl ClockOffset {
    /// `window` ≥ 1 samples are kept.
    pub fn new(window: usize) -> Self {
        Self {
            samples: Vec::new(),
            window: window.max(1),
            next: 0,
        }
    }

    /// Adds a sample; samples with a negative RTT (clock nonsense) are ignored.
    /// Returns whether it was kept.
    pub fn add(&mut self, s: ClockSample) -> bool {
        if s.rtt() < 0 || s.t4 < s.t1 || s.t3 < s.t2 {
            return false;
        }
        if self.samples.len() < self.window {
            self.samples.push(s);
        } else {
            self.samples[self.next] = s;
        }
        self.next = (self.next + 1) % self.window;
        true
    }

    /// The min-RTT sample, if any.
    pub fn best(&self) -> Option<ClockSample> {
        self.samples.iter().copied().min_by_key(|s| s.rtt())
    }

    /// Estimated `peer_clock - our_clock` in µs.
    pub fn offset_us(&self) -> Option<i64> {
        self.best().map(|s| s.offset())
    }

    /// RTT of the best sample, µs.
    pub fn rtt_us(&self) -> Option<i64> {
        self.best().map(|s| s.rtt())
    }

    /// One-way latency of a frame captured at peer time `capture_us` and
    /// received at our time `recv_us`, in µs (may be slightly negative
    /// within the estimator's error).
    pub fn one_way_us(&self, capture_us: u64, recv_us: u64) -> Option<i64> {
        self.offset_us()
            .map(|off| sat_i64(recv_us as i128 - (capture_us as i128 - off as i128)))
    }

    pub fn len(&self) -> usize {
        self.samples.len()
    }
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }
}

#[cfg(test)]
mod tests;
