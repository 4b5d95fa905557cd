//! Frame preprocessing shared by training, evaluation and deployment.
//!
//! Contract (see the ONNX metadata written by `export`), identical to
//! `telextiles-sensing`'s preprocessing: a DIGIT frame, 240 wide x 320 tall
//! RGB u8 -> centre crop of `crop` x `crop` (top-left at
//! `((240-crop)/2, (320-crop)/2)`) -> bilinear resize to `S` x `S` with
//! half-pixel centres and no antialiasing (source coordinate
//! `(o + 0.5) * crop / S - 0.5`, clamped to the crop) -> `(x / 255 - mean) / std`
//! per channel, NCHW. The shipped model uses `crop == S` (no resampling).

use anyhow::{ensure, Result};
use image::RgbImage;

/// DIGIT normalisation from the paper (RGB).
pub const DIGIT_MEAN: [f32; 3] = [0.379_323_63, 0.413_103_4, 0.383_360_82];
/// DIGIT normalisation from the paper (RGB).
pub const DIGIT_STD: [f32; 3] = [0.114_766_28, 0.086_043_12, 0.165_905_93];

/// Width of a DIGIT frame.
pub const FRAME_W: u32 = 240;
/// Height of a DIGIT frame.
pub const FRAME_H: u32 = 320;

/// Centre crop of side `crop` from a frame, resized to `size` x `size`
/// (bilinear, half-pixel centres, no antialiasing; see the module docs).
pub fn centre_crop_resize(frame: &RgbImage, crop: u32, size: u32) -> Result<RgbImage> {
    let (w, h) = frame.dimensions();
    ensure!(
        crop > 0 && crop <= w && crop <= h,
        "crop {crop} does not fit a {w}x{h} frame"
    );
    ensure!(size > 0, "output size must be positive");
    let x0 = (w - crop) / 2;
    let y0 = (h - crop) / 2;
    let scale = crop as f32 / size as f32;
    let taps: Vec<(u32, u32, f32)> = (0..size)
        .map(|o| {
            let s = ((o as f32 + 0.5) * scale - 0.5).clamp(0.0, (crop - 1) as f32);
            let i0 = s.floor() as u32;
            (i0, (i0 + 1).min(crop - 1), s - i0 as f32)
        })
        .collect();
    let src = frame.as_raw();
    let px = |x: u32, y: u32, c: usize| src[(((y0 + y) * w + x0 + x) * 3) as usize + c] as f32;
    let mut out = RgbImage::new(size, size);
    for (oy, &(y0i, y1i, wy)) in taps.iter().enumerate() {
        for (ox, &(x0i, x1i, wx)) in taps.iter().enumerate() {
            let mut v = [0u8; 3];
            for (c, vc) in v.iter_mut().enumerate() {
                let top = px(x0i, y0i, c) * (1.0 - wx) + px(x1i, y0i, c) * wx;
                let bot = px(x0i, y1i, c) * (1.0 - wx) + px(x1i, y1i, c) * wx;
                *vc = (top * (1.0 - wy) + bot * wy).round().clamp(0.0, 255.0) as u8;
            }
            out.put_pixel(ox as u32, oy as u32, image::Rgb(v));
        }
    }
    Ok(out)
}

/// Normalise an RGB u8 image (HWC) into CHW f32, appending to `out`.
pub fn normalize_into(img: &[u8], side: usize, out: &mut Vec<f32>) {
    let n = side * side;
    let base = out.len();
    out.resize(base + 3 * n, 0.0);
    for (i, px) in img.chunks_exact(3).take(n).enumerate() {
        for c in 0..3 {
            out[base + c * n + i] = (px[c] as f32 / 255.0 - DIGIT_MEAN[c]) / DIGIT_STD[c];
        }
    }
}

/// Full contract preprocessing of one frame into a CHW f32 vector.
pub fn preprocess_frame(frame: &RgbImage, crop: u32, size: u32) -> Result<Vec<f32>> {
    let img = centre_crop_resize(frame, crop, size)?;
    let mut out = Vec::with_capacity(3 * (size * size) as usize);
    normalize_into(img.as_raw(), size as usize, &mut out);
    Ok(out)
}

/// Reference pixels (f32, 0..255) as an image.
pub fn reference_image(px: &[f32]) -> anyhow::Result<image::RgbImage> {
    telextiles_sensing::front::image_of(px)
        .ok_or_else(|| anyhow::anyhow!("reference of the wrong size"))
}
/// The model input of one image (HWC u8, `side` x `side`) appended to
/// `out` as CHW f32: the contract's normalisation, minus the normalised
/// reference when there is one (`telextiles.background = subtract`).
pub fn input_into(img: &[u8], reference: Option<&[u8]>, side: usize, out: &mut Vec<f32>) {
    let base = out.len();
    normalize_into(img, side, out);
    if let Some(r) = reference {
        let mut rn = Vec::with_capacity(3 * side * side);
        normalize_into(r, side, &mut rn);
        for (v, r) in out[base..].iter_mut().zip(&rn) {
            *v -= r;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crop_is_centred_and_normalised() {
        let mut f = RgbImage::new(FRAME_W, FRAME_H);
        // Mark the pixel just inside the top-left of a 168 crop.
        f.put_pixel(36, 76, image::Rgb([255, 0, 0]));
        let c = centre_crop_resize(&f, 168, 168).unwrap();
        assert_eq!(c.get_pixel(0, 0).0, [255, 0, 0]);
        let v = preprocess_frame(&f, 168, 168).unwrap();
        assert_eq!(v.len(), 3 * 168 * 168);
        assert!((v[0] - (1.0 - DIGIT_MEAN[0]) / DIGIT_STD[0]).abs() < 1e-6);
        assert!((v[1] - (0.0 - DIGIT_MEAN[0]) / DIGIT_STD[0]).abs() < 1e-6);
        assert!(centre_crop_resize(&f, 300, 64).is_err());
        // Downscaling by 2 averages 2x2 blocks (half-pixel centres).
        let g = RgbImage::from_fn(240, 320, |x, y| {
            image::Rgb([(x % 2 * 100 + y % 2 * 50) as u8, 0, 0])
        });
        let d = centre_crop_resize(&g, 100, 50).unwrap();
        assert!(d.pixels().all(|p| p.0[0] == 75), "{:?}", d.get_pixel(0, 0));
    }
}
