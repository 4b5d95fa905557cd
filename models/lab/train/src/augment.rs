//! The paper's augmentations adapted to DIGIT frames: rotation with p=1 over
//! [-180, 180), vertical flip with p=0.5, a mild random resized crop and
//! brightness/contrast/saturation jitter (no hue, no blur, no grayscale),
//! then DIGIT normalisation.
//!
//! Augmentations run on a *canvas*: the centre 240x240 square of a frame at
//! native resolution. A view samples it bilinearly (half-pixel centres, no
//! antialiasing) at `crop / S` canvas pixels per output pixel, so the
//! identity augmentation equals the deployment preprocessing exactly. With
//! `crop <= 169` a crop rotated by any angle stays inside the frame: no black
//! corners.

use rand::Rng;
use serde::{Deserialize, Serialize};
use telextiles_graphs::preprocess::{DIGIT_MEAN, DIGIT_STD, FRAME_W};

/// Augmentation strengths.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AugConfig {
    /// Smallest area fraction of the random resized crop (1.0 disables it).
    pub min_scale: f32,
    /// Rotation range in degrees: uniform in [-rot, rot).
    pub rotation_deg: f32,
    /// Probability of a vertical flip.
    pub vflip_p: f32,
    /// Probability of applying colour jitter.
    pub jitter_p: f32,
    /// Brightness/contrast/saturation factors are drawn in [1-j, 1+j].
    pub brightness: f32,
    /// Contrast jitter strength.
    pub contrast: f32,
    /// Saturation jitter strength.
    pub saturation: f32,
}

impl Default for AugConfig {
    fn default() -> Self {
        AugConfig {
            min_scale: 0.6,
            rotation_deg: 180.0,
            vflip_p: 0.5,
            jitter_p: 0.8,
            brightness: 0.4,
            contrast: 0.4,
            saturation: 0.4,
        }
    }
}

impl AugConfig {
    /// No augmentation at all (used for evaluation and tests).
    pub fn identity() -> Self {
        AugConfig {
            min_scale: 1.0,
            rotation_deg: 0.0,
            vflip_p: 0.0,
            jitter_p: 0.0,
            brightness: 0.0,
            contrast: 0.0,
            saturation: 0.0,
        }
    }
}

/// Side of a canvas: the centre square of the frame at native resolution.
pub const CANVAS_SIDE: u32 = FRAME_W;

/// One augmented view of a canvas (`side` x `side` RGB u8, HWC), written as
/// normalised CHW f32 of `size` x `size` appended to `out`. `crop` is the
/// deployment crop in canvas (= frame) pixels.
#[allow(clippy::too_many_arguments)]
pub fn augment_into<R: Rng>(
    canvas: &[u8],
    side: usize,
    size: usize,
    crop: f32,
    cfg: &AugConfig,
    rng: &mut R,
    out: &mut Vec<f32>,
) {
    debug_assert_eq!(canvas.len(), side * side * 3);
    let s = size as f32;
    let base = crop;
    // Random resized crop (area fraction and aspect ratio), in canvas px.
    let (cw, ch) = if cfg.min_scale < 1.0 {
        let area = rng.gen_range(cfg.min_scale..=1.0);
        let log_r = rng.gen_range((0.75f32).ln()..=(4.0f32 / 3.0).ln());
        let r = log_r.exp();
        (
            (base * (area * r).sqrt()).min(base),
            (base * (area / r).sqrt()).min(base),
        )
    } else {
        (base, base)
    };
    let theta = if cfg.rotation_deg > 0.0 {
        rng.gen_range(-cfg.rotation_deg..cfg.rotation_deg)
            .to_radians()
    } else {
        0.0
    };
    let flip = cfg.vflip_p > 0.0 && rng.gen::<f32>() < cfg.vflip_p;
    let half = side as f32 / 2.0;
    let max_off = (half - (cw * cw + ch * ch).sqrt() / 2.0).max(0.0) * 0.5;
    let (ox, oy) = if max_off > 0.0 && cfg.min_scale < 1.0 {
        (
            rng.gen_range(-max_off..=max_off),
            rng.gen_range(-max_off..=max_off),
        )
    } else {
        (0.0, 0.0)
    };
    let (sin, cos) = theta.sin_cos();
    let (cx, cy) = (half + ox, half + oy);
    let n = size * size;
    let mut rgb = vec![0f32; 3 * n];
    let max = (side - 1) as f32;
    for v in 0..size {
        let mut y = ((v as f32 + 0.5) / s - 0.5) * ch;
        if flip {
            y = -y;
        }
        for u in 0..size {
            let x = ((u as f32 + 0.5) / s - 0.5) * cw;
            let sx = (cos * x - sin * y + cx - 0.5).clamp(0.0, max);
            let sy = (sin * x + cos * y + cy - 0.5).clamp(0.0, max);
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(side - 1), (y0 + 1).min(side - 1));
            let (fx, fy) = (sx - x0 as f32, sy - y0 as f32);
            let i = v * size + u;
            for c in 0..3 {
                let p = |xx: usize, yy: usize| canvas[(yy * side + xx) * 3 + c] as f32;
                let top = p(x0, y0) * (1.0 - fx) + p(x1, y0) * fx;
                let bot = p(x0, y1) * (1.0 - fx) + p(x1, y1) * fx;
                rgb[c * n + i] = (top * (1.0 - fy) + bot * fy) / 255.0;
            }
        }
    }
    if cfg.jitter_p > 0.0 && rng.gen::<f32>() < cfg.jitter_p {
        let mut order = [0u8, 1, 2];
        for i in (1..3).rev() {
            order.swap(i, rng.gen_range(0..=i));
        }
        for op in order {
            match op {
                0 if cfg.brightness > 0.0 => {
                    let b = rng.gen_range(1.0 - cfg.brightness..=1.0 + cfg.brightness);
                    rgb.iter_mut().for_each(|x| *x = (*x * b).clamp(0.0, 1.0));
                }
                1 if cfg.contrast > 0.0 => {
                    let c = rng.gen_range(1.0 - cfg.contrast..=1.0 + cfg.contrast);
                    let mean = (0..n).map(|i| gray(&rgb, n, i)).sum::<f32>() / n as f32;
                    rgb.iter_mut()
                        .for_each(|x| *x = (mean + (*x - mean) * c).clamp(0.0, 1.0));
                }
                2 if cfg.saturation > 0.0 => {
                    let sat = rng.gen_range(1.0 - cfg.saturation..=1.0 + cfg.saturation);
                    for i in 0..n {
                        let g = gray(&rgb, n, i);
                        for c in 0..3 {
                            let x = &mut rgb[c * n + i];
                            *x = (g + (*x - g) * sat).clamp(0.0, 1.0);
                        }
                    }
                }
                _ => {}
            }
        }
    }
    out.reserve(3 * n);
    for c in 0..3 {
        out.extend(
            rgb[c * n..(c + 1) * n]
                .iter()
                .map(|x| (x - DIGIT_MEAN[c]) / DIGIT_STD[c]),
        );
    }
}

fn gray(rgb: &[f32], n: usize, i: usize) -> f32 {
    0.299 * rgb[i] + 0.587 * rgb[n + i] + 0.114 * rgb[2 * n + i]
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use telextiles_graphs::preprocess::{centre_crop_resize, normalize_into};

    fn canvas(side: usize) -> Vec<u8> {
        (0..side * side * 3)
            .map(|i| ((i * 7919) % 251) as u8)
            .collect()
    }

    #[test]
    fn identity_augmentation_is_the_deployment_preprocessing() {
        let side = 20usize;
        let c = canvas(side);
        let img = image::RgbImage::from_raw(side as u32, side as u32, c.clone()).unwrap();
        // crop 10 -> 10 (no resampling) is exact; crop 16 -> 8 differs only by u8 rounding.
        for (crop, size, tol) in [(10u32, 10usize, 1e-4f32), (16, 8, 0.03)] {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
            let mut out = Vec::new();
            let id = AugConfig::identity();
            augment_into(&c, side, size, crop as f32, &id, &mut rng, &mut out);
            let centre = centre_crop_resize(&img, crop, size as u32).unwrap();
            let mut want = Vec::new();
            normalize_into(centre.as_raw(), size, &mut want);
            let diff = out
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f32::max);
            assert!(diff < tol, "crop {crop} size {size}: diff {diff}");
        }
    }

    #[test]
    fn default_augmentation_changes_pixels_and_stays_finite() {
        let side = CANVAS_SIDE as usize;
        let c = canvas(side);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
        let (mut a, mut b) = (Vec::new(), Vec::new());
        let cfg = AugConfig::default();
        augment_into(&c, side, 64, 96.0, &cfg, &mut rng, &mut a);
        augment_into(&c, side, 64, 96.0, &cfg, &mut rng, &mut b);
        assert_eq!(a.len(), 3 * 64 * 64);
        assert!(a.iter().all(|x| x.is_finite()));
        assert!(a.iter().zip(&b).any(|(x, y)| (x - y).abs() > 0.1));
    }
}
