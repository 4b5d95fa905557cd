//! The on-disk format: `MAGIC` (4 bytes), format version (u32 LE), payload
//! length (u64 LE), payload (bincode 2, standard config), SHA-256 of the
//! payload (32 bytes). The fingerprint peers compare is the hex SHA-256 of the
//! payload, so any change of content changes it.
//!
//! Version 1's payload is the [`Index`] without a metric; version 2's is the
//! index followed by its [`Metric`](crate::Metric); version 3's is the index
//! followed by its optional metric and its optional calibrated
//! unknown-textile distance; version 4's is the index followed by its
//! optional metric, its optional unknown distance and its [`Features`]
//! (an index of texture features beside the encoder's); version 5's adds
//! the sensor profile its presses came from after those (an index of
//! another sensor than a DIGIT). Each index is
//! written in the oldest version that holds it: without either as version 1, byte for byte as before
//! version 2 existed (same fingerprint, readable by older builds); with a
//! metric only as version 2; with a calibrated distance as version 3; with
//! texture features as version 4; of another sensor as version 5. This
//! build reads all five.

use crate::{Features, Index, Metric, UnknownDistance};
use sha2::{Digest, Sha256};
use std::io::Write;
use std::path::{Path, PathBuf};

/// File magic.
pub const MAGIC: [u8; 4] = *b"TLXI";
/// Newest format version (an index with a calibrated unknown-textile
/// distance); older indexes are written in the oldest version that holds
/// them (see the module docs).
pub const FORMAT_VERSION: u32 = 5;
const HEADER: usize = 4 + 4 + 8;
const MAX_PAYLOAD: u64 = 256 << 20;

/// Errors reading, writing or validating an index.
#[derive(Debug, thiserror::Error)]
pub enum IndexError {
    /// File-system error.
    #[error("{path}: {source}")]
    Io {
        /// File concerned.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// Not an index file at all.
    #[error("{0}: not a Telextiles index file (bad magic)")]
    BadMagic(PathBuf),
    /// Written by another format version.
    #[error(
        "{path}: index format version {found}, this build reads versions 1 to {FORMAT_VERSION}"
    )]
    Version {
        /// File concerned.
        path: PathBuf,
        /// Version found.
        found: u32,
    },
    /// Shorter than its header says.
    #[error("{path}: truncated index file ({len} bytes, expected {expected})")]
    Truncated {
        /// File concerned.
        path: PathBuf,
        /// Actual length.
        len: u64,
        /// Expected length.
        expected: u64,
    },
    /// Checksum mismatch or undecodable payload.
    #[error("{path}: corrupt index file ({why})")]
    Corrupt {
        /// File concerned.
        path: PathBuf,
        /// What is wrong.
        why: String,
    },
    /// Content is inconsistent.
    #[error("invalid index: {0}")]
    Invalid(String),
    /// Built for another encoder.
    #[error("index was built for encoder {index_encoder}, but the loaded model is {model}: rebuild the index with `telextilesd index build`")]
    EncoderMismatch {
        /// Hash recorded in the index.
        index_encoder: String,
        /// Hash of the model in use.
        model: String,
    },
}

fn config() -> impl bincode::config::Config {
    bincode::config::standard().with_limit::<{ MAX_PAYLOAD as usize }>()
}

pub(crate) fn payload(index: &Index) -> Vec<u8> {
    if let Some(sensor) = &index.sensor {
        return bincode::serde::encode_to_vec(
            (index, &index.metric, index.unknown, index.features, sensor),
            config(),
        )
        .expect("an index always encodes");
    }
    if index.features != Features::Encoder {
        return bincode::serde::encode_to_vec(
            (index, &index.metric, index.unknown, index.features),
            config(),
        )
        .expect("an index always encodes");
    }
    match (&index.metric, index.unknown) {
        (None, None) => bincode::serde::encode_to_vec(index, config()),
        (Some(m), None) => bincode::serde::encode_to_vec((index, m), config()),
        (m, Some(t)) => bincode::serde::encode_to_vec((index, m, t), config()),
    }
    .expect("an index always encodes")
}

fn version_of(index: &Index) -> u32 {
    if index.sensor.is_some() {
        return 5;
    }
    if index.features != Features::Encoder {
        return 4;
    }
    match (&index.metric, index.unknown) {
        (None, None) => 1,
        (Some(_), None) => 2,
        (_, Some(_)) => 3,
    }
}

pub(crate) fn fingerprint(index: &Index) -> String {
    hex(&Sha256::digest(payload(index)))
}

pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Encode an index into the file format.
pub fn to_bytes(index: &Index) -> Vec<u8> {
    let p = payload(index);
    let mut out = Vec::with_capacity(HEADER + p.len() + 32);
    out.extend_from_slice(&MAGIC);
    out.extend_from_slice(&version_of(index).to_le_bytes());
    out.extend_from_slice(&(p.len() as u64).to_le_bytes());
    out.extend_from_slice(&p);
    out.extend_from_slice(&Sha256::digest(&p));
    out
}

/// Decode the file format; `path` only names the file in errors.
pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Index, IndexError> {
    let p = || path.to_path_buf();
    if bytes.len() < 4 || bytes[..4] != MAGIC {
        return Err(IndexError::BadMagic(p()));
    }
    if bytes.len() < HEADER {
        return Err(IndexError::Truncated {
            path: p(),
            len: bytes.len() as u64,
            expected: HEADER as u64,
        });
    }
    // The header's length was checked above: these fixed slices fit.
    let word = |r: std::ops::Range<usize>| {
        let mut b = [0u8; 8];
        b[..r.len()].copy_from_slice(&bytes[r]);
        u64::from_le_bytes(b)
    };
    let version = word(4..8) as u32;
    if !(1..=FORMAT_VERSION).contains(&version) {
        return Err(IndexError::Version {
            path: p(),
            found: version,
        });
    }
    let len = word(8..16);
    if len > MAX_PAYLOAD {
        return Err(IndexError::Corrupt {
            path: p(),
            why: format!("payload length {len} exceeds the {MAX_PAYLOAD}-byte limit"),
        });
    }
    let expected = HEADER as u64 + len + 32;
    if (bytes.len() as u64) < expected {
        return Err(IndexError::Truncated {
            path: p(),
            len: bytes.len() as u64,
            expected,
        });
    }
    if (bytes.len() as u64) > expected {
        return Err(IndexError::Corrupt {
            path: p(),
            why: format!("{} trailing bytes", bytes.len() as u64 - expected),
        });
    }
    let payload = &bytes[HEADER..HEADER + len as usize];
    let sum = &bytes[HEADER + len as usize..];
    if Sha256::digest(payload).as_slice() != sum {
        return Err(IndexError::Corrupt {
            path: p(),
            why: "checksum mismatch".into(),
        });
    }
    let undecodable = |e: bincode::error::DecodeError| IndexError::Corrupt {
        path: p(),
        why: format!("undecodable content: {e}"),
    };
    let (index, used): (Index, usize) = match version {
        1 => bincode::serde::decode_from_slice(payload, config()).map_err(undecodable)?,
        2 => {
            let ((mut index, metric), used): ((Index, Metric), usize) =
                bincode::serde::decode_from_slice(payload, config()).map_err(undecodable)?;
            index.metric = Some(metric);
            (index, used)
        }
        5 => {
            type V5 = (
                Index,
                Option<Metric>,
                Option<UnknownDistance>,
                Features,
                String,
            );
            let ((mut index, metric, unknown, features, sensor), used): (V5, usize) =
                bincode::serde::decode_from_slice(payload, config()).map_err(undecodable)?;
            index.metric = metric;
            index.unknown = unknown;
            index.features = features;
            index.sensor = Some(sensor);
            (index, used)
        }
        4 => {
            type V4 = (Index, Option<Metric>, Option<UnknownDistance>, Features);
            let ((mut index, metric, unknown, features), used): (V4, usize) =
                bincode::serde::decode_from_slice(payload, config()).map_err(undecodable)?;
            index.metric = metric;
            index.unknown = unknown;
            index.features = features;
            (index, used)
        }
        _ => {
            type V3 = (Index, Option<Metric>, UnknownDistance);
            let ((mut index, metric, unknown), used): (V3, usize) =
                bincode::serde::decode_from_slice(payload, config()).map_err(undecodable)?;
            index.metric = metric;
            index.unknown = Some(unknown);
            (index, used)
        }
    };
    if used != payload.len() {
        return Err(IndexError::Corrupt {
            path: p(),
            why: "payload has unused bytes".into(),
        });
    }
    index.validate().map_err(|e| IndexError::Corrupt {
        path: p(),
        why: e.to_string(),
    })?;
    Ok(index)
}

impl Index {
    /// Read and validate an index file.
    pub fn read(path: &Path) -> Result<Index, IndexError> {
        let bytes = std::fs::read(path).map_err(|source| IndexError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        from_bytes(&bytes, path)
    }

    /// Write atomically: a temporary file in the same directory, synced, then
    /// renamed over `path`. A crash leaves either the old or the new file.
    pub fn write(&self, path: &Path) -> Result<(), IndexError> {
        self.validate()?;
        let io = |source| IndexError::Io {
            path: path.to_path_buf(),
            source,
        };
        let dir = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty())
            .unwrap_or(Path::new("."));
        let name = path.file_name().ok_or_else(|| {
            io(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                "not a file path",
            ))
        })?;
        let tmp = dir.join(format!(
            ".{}.tmp-{}",
            name.to_string_lossy(),
            std::process::id()
        ));
        let result = (|| {
            let mut f = std::fs::File::create(&tmp)?;
            f.write_all(&to_bytes(self))?;
            f.sync_all()?;
            std::fs::rename(&tmp, path)?;
            if let Ok(d) = std::fs::File::open(dir) {
                let _ = d.sync_all();
            }
            Ok(())
        })();
        if result.is_err() {
            let _ = std::fs::remove_file(&tmp);
        }
        result.map_err(io)
    }

    /// Refuse an index built for another encoder.
    pub fn check_encoder(&self, model_hash: &str) -> Result<(), IndexError> {
        if self.encoder_hash != model_hash {
            return Err(IndexError::EncoderMismatch {
                index_encoder: self.encoder_hash.clone(),
                model: model_hash.to_string(),
            });
        }
        Ok(())
    }
}
