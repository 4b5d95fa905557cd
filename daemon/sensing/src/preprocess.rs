//! Frame → encoder input, as the model's metadata says.
//!
//! 240x320 RGB u8 → centre crop of `crop` x `crop` (top-left at
//! `((240-crop)/2, (320-crop)/2)`, integer division) → bilinear resize to
//! S x S with half-pixel centres (`align_corners=false`, no antialiasing:
//! source coordinate `(o + 0.5) * crop / S - 0.5`, clamped to the crop) →
//! `(x/255 - mean[c]) / std[c]` → planar CHW f32.
//!
//! All index and weight tables are computed once; [`Preprocessor::run`]
//! writes into a caller-provided slice and allocates nothing.

use image::RgbImage;

use crate::frame::{FRAME_H, FRAME_W};

/// Preprocessing parameters (from the model metadata).
#[derive(Clone, Debug, PartialEq)]
pub struct PreprocessSpec {
    /// Side of the centre crop, in frame pixels (1..=240).
    pub crop: u32,
    /// Side of the encoder input (S).
    pub size: u32,
    /// Per-channel mean (RGB), on the 0..1 scale.
    pub mean: [f32; 3],
    /// Per-channel standard deviation (RGB).
    pub std: [f32; 3],
}

#[derive(Clone, Copy, Debug)]
struct Tap {
    i0: u32,
    i1: u32,
    w: f32,
}

/// Precomputed preprocessing (see the module docs).
#[derive(Clone, Debug)]
pub struct Preprocessor {
    spec: PreprocessSpec,
    x0: u32,
    y0: u32,
    taps: Vec<Tap>,
    lut: [[f32; 256]; 3],
}

impl Preprocessor {
    /// Check the spec and build the tables.
    pub fn new(spec: PreprocessSpec) -> Result<Preprocessor, String> {
        if spec.crop == 0 || spec.crop > FRAME_W {
            return Err(format!(
                "crop {} does not fit a {FRAME_W}x{FRAME_H} frame (1..={FRAME_W})",
                spec.crop
            ));
        }
        if spec.size == 0 || spec.size > 1024 {
            return Err(format!(
                "input size {} is out of range (1..=1024)",
                spec.size
            ));
        }
        if spec.std.iter().any(|s| !s.is_finite() || *s <= 0.0)
            || spec.mean.iter().any(|m| !m.is_finite())
        {
            return Err(format!(
                "bad normalisation: mean {:?} std {:?}",
                spec.mean, spec.std
            ));
        }
        let scale = spec.crop as f32 / spec.size as f32;
        let taps = (0..spec.size)
            .map(|o| {
                let s = ((o as f32 + 0.5) * scale - 0.5).clamp(0.0, (spec.crop - 1) as f32);
                let i0 = s.floor() as u32;
                let i1 = (i0 + 1).min(spec.crop - 1);
                Tap {
                    i0,
                    i1,
                    w: s - i0 as f32,
                }
            })
            .collect();
        let mut lut = [[0f32; 256]; 3];
        for (c, table) in lut.iter_mut().enumerate() {
            for (v, e) in table.iter_mut().enumerate() {
                *e = (v as f32 / 255.0 - spec.mean[c]) / spec.std[c];
            }
        }
        Ok(Preprocessor {
            x0: (FRAME_W - spec.crop) / 2,
            y0: (FRAME_H - spec.crop) / 2,
            taps,
            lut,
            spec,
        })
    }

    /// The spec.
    pub fn spec(&self) -> &PreprocessSpec {
        &self.spec
    }

    /// Number of f32 values written by [`Preprocessor::run`] (3*S*S).
    pub fn len(&self) -> usize {
        3 * (self.spec.size as usize).pow(2)
    }

    /// Whether [`Preprocessor::len`] is 0 (never, for a valid spec).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Write the CHW input for `frame` into `out` (`out.len() == self.len()`).
    ///
    /// # Panics
    /// If the frame is not 240x320 or `out` has the wrong length (both are
    /// checked by the callers before the hot path).
    pub fn run(&self, frame: &RgbImage, out: &mut [f32]) {
        assert_eq!(
            (frame.width(), frame.height()),
            (FRAME_W, FRAME_H),
            "frame size"
        );
        assert_eq!(out.len(), self.len(), "input buffer length");
        let s = self.spec.size as usize;
        let plane = s * s;
        let raw = frame.as_raw();
        let stride = FRAME_W as usize * 3;
        let (out_r, rest) = out.split_at_mut(plane);
        let (out_g, out_b) = rest.split_at_mut(plane);
        let [lr, lg, lb] = &self.lut;
        for (oy, ty) in self.taps.iter().enumerate() {
            let row0 = &raw[(self.y0 + ty.i0) as usize * stride..][..stride];
            let row1 = &raw[(self.y0 + ty.i1) as usize * stride..][..stride];
            let wy = ty.w;
            for (ox, tx) in self.taps.iter().enumerate() {
                let a = (self.x0 + tx.i0) as usize * 3;
                let b = (self.x0 + tx.i1) as usize * 3;
                let wx = tx.w;
                let o = oy * s + ox;
                let mix = |lut: &[f32; 256], c: usize| {
                    let top =
                        lut[row0[a + c] as usize] * (1.0 - wx) + lut[row0[b + c] as usize] * wx;
                    let bot =
                        lut[row1[a + c] as usize] * (1.0 - wx) + lut[row1[b + c] as usize] * wx;
                    top * (1.0 - wy) + bot * wy
                };
                out_r[o] = mix(lr, 0);
                out_g[o] = mix(lg, 1);
                out_b[o] = mix(lb, 2);
            }
        }
    }

    /// [`Preprocessor::run`] for full-resolution RGB values given as f32
    /// (240x320x3, interleaved, 0..255, e.g. a mean of frames): the same
    /// affine map without rounding to u8 first.
    ///
    /// # Panics
    /// If `pixels` or `out` has the wrong length.
    pub fn run_pixels(&self, pixels: &[f32], out: &mut [f32]) {
        assert_eq!(pixels.len(), (FRAME_W * FRAME_H * 3) as usize, "frame size");
        assert_eq!(out.len(), self.len(), "input buffer length");
        let s = self.spec.size as usize;
        let plane = s * s;
        let stride = FRAME_W as usize * 3;
        let scale: [f32; 3] = std::array::from_fn(|c| 1.0 / (255.0 * self.spec.std[c]));
        let shift: [f32; 3] = std::array::from_fn(|c| self.spec.mean[c] / self.spec.std[c]);
        for (oy, ty) in self.taps.iter().enumerate() {
            let row0 = &pixels[(self.y0 + ty.i0) as usize * stride..][..stride];
            let row1 = &pixels[(self.y0 + ty.i1) as usize * stride..][..stride];
            let wy = ty.w;
            for (ox, tx) in self.taps.iter().enumerate() {
                let a = (self.x0 + tx.i0) as usize * 3;
                let b = (self.x0 + tx.i1) as usize * 3;
                let wx = tx.w;
                let o = oy * s + ox;
                for c in 0..3 {
                    let top = row0[a + c] * (1.0 - wx) + row0[b + c] * wx;
                    let bot = row1[a + c] * (1.0 - wx) + row1[b + c] * wx;
                    out[c * plane + o] = (top * (1.0 - wy) + bot * wy) * scale[c] - shift[c];
                }
            }
        }
    }
}
