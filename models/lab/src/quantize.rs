//! int8 versions of the ONNX models: ONNX Runtime's static quantisation
//! (`onnxruntime.quantization.quantize_static`, QDQ format), calibrated on
//! DIGIT frames. The quantiser is ONNX Runtime's own Python tool: this module
//! writes the calibration frames as `.npy`, runs `scripts/quantize.py`
//! (embedded in the binary) with the Python that has `onnxruntime`, loads
//! the result back through the `ort` contract checks and measures how far
//! its embeddings are from the float model's on other frames.

use anyhow::{bail, ensure, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};

use crate::data::ImageSet;
use crate::onnx::OrtEncoder;

/// Where `.ci/setup` puts a Python with onnxruntime 1.31.1, onnx and numpy.
pub const DEFAULT_PYTHON: &str = "/opt/telextiles/pyenv/bin/python3";

const SCRIPT: &str = include_str!("../scripts/quantize.py");

/// The Python to run the quantiser with: `$TELEXTILES_PYTHON`, else
/// [`DEFAULT_PYTHON`] if it exists, else `python3`.
pub fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("TELEXTILES_PYTHON") {
        return PathBuf::from(p);
    }
    if Path::new(DEFAULT_PYTHON).exists() {
        return PathBuf::from(DEFAULT_PYTHON);
    }
    PathBuf::from("python3")
}

/// Writes a little-endian f32 array as a NumPy `.npy` file (format 1.0).
pub fn write_npy(path: &Path, data: &[f32], shape: &[usize]) -> Result<()> {
    ensure!(
        shape.iter().product::<usize>() == data.len(),
        "npy: shape {shape:?} does not hold {} values",
        data.len()
    );
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let tuple = if dims.len() == 1 {
        format!("({},)", dims[0])
    } else {
        format!("({})", dims.join(", "))
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {tuple}, }}");
    // Magic (6) + version (2) + length (2) + header + '\n', padded to 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut buf = Vec::with_capacity(10 + header.len() + data.len() * 4);
    buf.extend_from_slice(b"\x93NUMPY\x01\x00");
    buf.extend_from_slice(&(header.len() as u16).to_le_bytes());
    buf.extend_from_slice(header.as_bytes());
    for v in data {
        buf.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(path, buf).with_context(|| format!("cannot write {}", path.display()))
}

/// How close the int8 model is to the float one.
#[derive(Clone, Debug, Serialize)]
pub struct QuantReport {
    /// Calibration frames.
    pub calibration_frames: usize,
    /// Frames compared.
    pub compared_frames: usize,
    /// Cosine similarity of int8 and float embeddings over the frames where
    /// both are finite: mean and minimum.
    pub cosine_mean: f64,
    pub cosine_min: f64,
    /// Compared frames whose int8 embedding has a NaN or infinity.
    pub nonfinite_frames: usize,
}

fn spread_indices(n: usize, k: usize) -> Vec<usize> {
    let k = k.min(n);
    (0..k).map(|i| i * n / k.max(1)).collect()
}

/// Quantises `model` (float ONNX with the encoder contract) with
/// `calibration` frames (in the model's view; `frames` of them, spread over
/// the set) and compares it with the float model on `compare` frames.
/// `references`: the sensors' no-contact frames in the same view, which a
/// background-subtracting model's inputs are taken against.
///
/// An int8 model that gives non-finite embeddings on any compared frame is
/// refused (a log of a power that rounded to zero, say) unless
/// `allow_nonfinite` (to put such a model on a chart, never to ship it).
pub fn quantize(
    model: &[u8],
    calibration: &ImageSet,
    frames: usize,
    compare: &ImageSet,
    references: &ImageSet,
    allow_nonfinite: bool,
) -> Result<(Vec<u8>, QuantReport)> {
    let mut float = OrtEncoder::from_bytes(model, 2).context("the float model")?;
    let subtract = float.subtracts_background()?;
    let input = |set: &ImageSet, i: usize, x: &mut Vec<f32>| -> Result<()> {
        let r = if subtract {
            let s = set.items[i].sensor;
            Some(
                crate::methods::background_of(references, s)
                    .with_context(|| format!("no reference frame of sensor {s}"))?,
            )
        } else {
            None
        };
        crate::methods::input_into(set.image(i), r, set.side, x);
        Ok(())
    };
    let s = float.input_size;
    ensure!(
        calibration.side == s && compare.side == s,
        "frames are {} px, the model takes {s}",
        calibration.side
    );
    let idx = spread_indices(calibration.len(), frames);
    ensure!(!idx.is_empty(), "no calibration frames");
    let mut x = Vec::with_capacity(idx.len() * 3 * s * s);
    for &i in &idx {
        input(calibration, i, &mut x)?;
    }
    let dir = tempfile::tempdir().context("temporary directory")?;
    let (src, npy, out, script) = (
        dir.path().join("in.onnx"),
        dir.path().join("calib.npy"),
        dir.path().join("out.onnx"),
        dir.path().join("quantize.py"),
    );
    std::fs::write(&src, model)?;
    std::fs::write(&script, SCRIPT)?;
    write_npy(&npy, &x, &[idx.len(), 3, s, s])?;
    let py = python();
    let o = std::process::Command::new(&py)
        .arg(&script)
        .arg(&src)
        .arg(&npy)
        .arg(&out)
        .output()
        .with_context(|| {
            format!(
                "cannot run {} (a Python with onnxruntime, onnx and numpy: `bash .ci/setup`, or set TELEXTILES_PYTHON)",
                py.display()
            )
        })?;
    if !o.status.success() {
        let err = String::from_utf8_lossy(&o.stderr);
        let tail: Vec<&str> = err.lines().rev().take(8).collect();
        bail!(
            "ONNX Runtime quantisation failed ({} {}): {}",
            py.display(),
            o.status,
            tail.into_iter().rev().collect::<Vec<_>>().join("\n")
        );
    }
    let bytes = std::fs::read(&out).context("the quantiser wrote no model")?;
    let mut q = OrtEncoder::from_bytes(&bytes, 2).context("the int8 model")?;
    ensure!(q.dim == float.dim, "int8 model changed the embedding size");
    let cidx = spread_indices(compare.len(), 256);
    let (mut sum, mut min, mut n, mut nonfinite) = (0.0f64, f64::INFINITY, 0usize, 0usize);
    for chunk in cidx.chunks(32) {
        let mut x = Vec::new();
        for &i in chunk {
            input(compare, i, &mut x)?;
        }
        let (a, b) = (float.embed(&x)?, q.embed(&x)?);
        for (u, v) in a.chunks_exact(float.dim).zip(b.chunks_exact(float.dim)) {
            if v.iter().any(|x| !x.is_finite()) {
                nonfinite += 1;
                continue;
            }
            n += 1;
            let dot: f64 = u.iter().zip(v).map(|(p, q)| (p * q) as f64).sum();
            let nu = u.iter().map(|p| (p * p) as f64).sum::<f64>().sqrt();
            let nv = v.iter().map(|p| (p * p) as f64).sum::<f64>().sqrt();
            let c = if nu > 0.0 && nv > 0.0 {
                dot / (nu * nv)
            } else {
                1.0
            };
            sum += c;
            min = min.min(c);
        }
    }
    ensure!(
        nonfinite == 0 || allow_nonfinite,
        "the int8 model gives non-finite embeddings on {nonfinite} of {} held-out frames (8-bit steps cannot hold what this model computes); not writing it",
        cidx.len()
    );
    Ok((
        bytes,
        QuantReport {
            calibration_frames: idx.len(),
            compared_frames: cidx.len(),
            cosine_mean: if n > 0 { sum / n as f64 } else { f64::NAN },
            cosine_min: if n > 0 { min } else { f64::NAN },
            nonfinite_frames: nonfinite,
        },
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_header_is_aligned_and_describes_the_array() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        write_npy(&p, &[1.0, 2.0, 3.0, 4.0, 5.0, 6.0], &[2, 3]).unwrap();
        let b = std::fs::read(&p).unwrap();
        assert_eq!(&b[..8], b"\x93NUMPY\x01\x00");
        let hl = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + hl) % 64, 0);
        let h = std::str::from_utf8(&b[10..10 + hl]).unwrap();
        assert!(h.contains("'shape': (2, 3)") && h.ends_with('\n'), "{h}");
        assert_eq!(b.len(), 10 + hl + 24);
        assert_eq!(
            f32::from_le_bytes(b[10 + hl..14 + hl].try_into().unwrap()),
            1.0
        );
        assert!(write_npy(&p, &[1.0], &[2]).is_err());
    }
}
