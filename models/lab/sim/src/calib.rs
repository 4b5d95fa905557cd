//! The real DIGIT optical calibration (Taxim `polycalib.npz`) and the real
//! no-contact frame (tacto), both embedded in the binary.
//!
//! The `.npz` is an uncompressed zip of `.npy` arrays; we parse the few bytes
//! of zip and npy framing we need ourselves (no zip dependency).
//!
//! Pixel convention (worked out from the data, see docs/simulator.md): the
//! quadratic `c0 x^2 + c1 y^2 + c2 xy + c3 x + c4 y + c5` is evaluated in
//! *pixel units* with x = column (0..239) and y = row (0..319) of the
//! 240-wide x 320-tall frame that digit-interface delivers.

use crate::SimError;

/// Number of slope-angle (magnitude) and slope-direction bins.
pub const BINS: usize = 125;
/// Frame width (columns) as delivered by digit-interface.
pub const WIDTH: usize = 240;
/// Frame height (rows).
pub const HEIGHT: usize = 320;

static NPZ: &[u8] = include_bytes!("../data/digit_polycalib.npz");
static BACKGROUND_JPG: &[u8] = include_bytes!("../data/digit_background_240x320.jpg");

/// Calibration table: `coef[((mag * BINS + dir) * 3 + channel) * 6 + k]`.
pub struct Calibration {
    pub coef: Vec<f32>,
}

impl Calibration {
    /// Parse the embedded calibration.
    pub fn embedded() -> Result<Calibration, SimError> {
        Self::from_npz(NPZ)
    }

    /// Parse a Taxim `polycalib.npz` (stored, uncompressed zip).
    pub fn from_npz(bytes: &[u8]) -> Result<Calibration, SimError> {
        let entries = read_stored_zip(bytes)?;
        let mut chans: [Option<Vec<f64>>; 3] = [None, None, None];
        for (name, data) in entries {
            let ch = match name.as_str() {
                "grad_r.npy" => 0,
                "grad_g.npy" => 1,
                "grad_b.npy" => 2,
                _ => continue,
            };
            let (shape, values) =
                read_npy_f64(data).map_err(|e| SimError::Calibration(format!("{name}: {e}")))?;
            if shape != [BINS, BINS, 6] {
                return Err(SimError::Calibration(format!(
                    "{name}: shape {shape:?}, expected [{BINS}, {BINS}, 6]"
                )));
            }
            chans[ch] = Some(values);
        }
        let mut coef = vec![0f32; BINS * BINS * 3 * 6];
        for (ch, v) in chans.iter().enumerate() {
            let v = v.as_ref().ok_or_else(|| {
                SimError::Calibration(format!("missing grad_{} array", ["r", "g", "b"][ch]))
            })?;
            for m in 0..BINS {
                for d in 0..BINS {
                    for k in 0..6 {
                        coef[((m * BINS + d) * 3 + ch) * 6 + k] = v[(m * BINS + d) * 6 + k] as f32;
                    }
                }
            }
        }
        Ok(Calibration { coef })
    }

    /// Evaluate the RGB response of bin (mag, dir) at pixel (x = column, y = row).
    #[inline]
    pub fn eval(&self, mag: usize, dir: usize, x: f32, y: f32) -> [f32; 3] {
        let base = (mag * BINS + dir) * 18;
        let c = &self.coef[base..base + 18];
        let b = [x * x, y * y, x * y, x, y, 1.0];
        let mut out = [0f32; 3];
        for (ch, o) in out.iter_mut().enumerate() {
            let cc = &c[ch * 6..ch * 6 + 6];
            *o = cc[0] * b[0] + cc[1] * b[1] + cc[2] * b[2] + cc[3] * b[3] + cc[4] * b[4] + cc[5];
        }
        out
    }
}

impl Calibration {
    /// One channel of `eval` (the RGB change of channel `ch` for bin (mag, dir)).
    #[inline]
    pub fn eval_channel(&self, mag: usize, dir: usize, ch: usize, x: f32, y: f32) -> f32 {
        let base = (mag * BINS + dir) * 18 + ch * 6;
        let cc = &self.coef[base..base + 6];
        cc[0] * x * x + cc[1] * y * y + cc[2] * x * y + cc[3] * x + cc[4] * y + cc[5]
    }
}

/// The embedded real DIGIT no-contact frame, 240 wide x 320 tall.
pub fn embedded_background() -> Result<image::RgbImage, SimError> {
    let img = image::load_from_memory_with_format(BACKGROUND_JPG, image::ImageFormat::Jpeg)
        .map_err(|e| SimError::Calibration(format!("background jpeg: {e}")))?
        .to_rgb8();
    if img.width() as usize != WIDTH || img.height() as usize != HEIGHT {
        return Err(SimError::Calibration(format!(
            "background is {}x{}, expected {WIDTH}x{HEIGHT}",
            img.width(),
            img.height()
        )));
    }
    Ok(img)
}

fn le16(b: &[u8], at: usize) -> Option<usize> {
    Some(u16::from_le_bytes(b.get(at..at + 2)?.try_into().ok()?) as usize)
}
fn le32(b: &[u8], at: usize) -> Option<usize> {
    Some(u32::from_le_bytes(b.get(at..at + 4)?.try_into().ok()?) as usize)
}

/// Walk the local file headers of a zip whose members are all stored.
fn read_stored_zip(b: &[u8]) -> Result<Vec<(String, &[u8])>, SimError> {
    let bad = |m: &str| SimError::Calibration(format!("npz: {m}"));
    let mut out = Vec::new();
    let mut at = 0usize;
    while b.get(at..at + 4) == Some(&[0x50, 0x4b, 0x03, 0x04][..]) {
        let flags = le16(b, at + 6).ok_or_else(|| bad("truncated header"))?;
        let method = le16(b, at + 8).ok_or_else(|| bad("truncated header"))?;
        let size = le32(b, at + 18).ok_or_else(|| bad("truncated header"))?;
        let name_len = le16(b, at + 26).ok_or_else(|| bad("truncated header"))?;
        let extra_len = le16(b, at + 28).ok_or_else(|| bad("truncated header"))?;
        if method != 0 || flags & 8 != 0 || size == 0xFFFF_FFFF {
            return Err(bad(
                "only stored members with sizes in the local header are supported",
            ));
        }
        let name_at = at + 30;
        let name = b
            .get(name_at..name_at + name_len)
            .ok_or_else(|| bad("truncated name"))?;
        let name = String::from_utf8_lossy(name).into_owned();
        let data_at = name_at + name_len + extra_len;
        let data = b
            .get(data_at..data_at + size)
            .ok_or_else(|| bad("truncated member"))?;
        out.push((name, data));
        at = data_at + size;
    }
    if out.is_empty() {
        return Err(bad("no zip members"));
    }
    Ok(out)
}

/// Minimal `.npy` reader for little-endian float64, C order.
fn read_npy_f64(b: &[u8]) -> Result<(Vec<usize>, Vec<f64>), String> {
    if b.get(..6) != Some(b"\x93NUMPY") {
        return Err("not an npy array".into());
    }
    let major = *b.get(6).ok_or("truncated")?;
    let (hlen, hstart) = match major {
        1 => (le16(b, 8).ok_or("truncated")?, 10),
        2 | 3 => (le32(b, 8).ok_or("truncated")?, 12),
        v => return Err(format!("npy version {v}")),
    };
    let header = std::str::from_utf8(b.get(hstart..hstart + hlen).ok_or("truncated header")?)
        .map_err(|_| "header not utf-8")?;
    if !header.contains("'descr': '<f8'") {
        return Err(format!("dtype is not <f8: {header}"));
    }
    if header.contains("'fortran_order': True") {
        return Err("fortran order".into());
    }
    let shape_str = header
        .split("'shape': (")
        .nth(1)
        .and_then(|s| s.split(')').next())
        .ok_or("no shape")?;
    let shape: Vec<usize> = shape_str
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("bad shape {shape_str}"))
        })
        .collect::<Result<_, _>>()?;
    let n: usize = shape.iter().product();
    let data = b.get(hstart + hlen..).ok_or("truncated data")?;
    if data.len() < n * 8 {
        return Err("truncated data".into());
    }
    let values = data[..n * 8]
        .chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])))
        .collect();
    Ok((shape, values))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn embedded_calibration_parses() {
        let c = Calibration::embedded().unwrap();
        // grad_r[0,0] constant term as read by numpy: 46.2518950
        assert!((c.coef[5] - 46.251_895).abs() < 1e-3);
        assert!(Calibration::from_npz(b"garbage").is_err());
        let bg = embedded_background().unwrap();
        assert_eq!((bg.width(), bg.height()), (240, 320));
    }
}
