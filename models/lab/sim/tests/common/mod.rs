//! Shared helpers of the simulator tests: simple hand-made image features.
#![allow(dead_code)]

use telextiles_sim::{PressSpec, RgbImage, Simulator};

pub const CROP: usize = 128;

/// Grey contact signal: |frame - background| summed over channels.
pub fn contact_signal(frame: &RgbImage, bg: &RgbImage) -> Vec<f32> {
    frame
        .pixels()
        .zip(bg.pixels())
        .map(|(a, b)| (0..3).map(|c| (a.0[c] as f32 - b.0[c] as f32).abs()).sum())
        .collect()
}

/// Mean absolute difference from the background.
pub fn mean_abs_diff(frame: &RgbImage, bg: &RgbImage) -> f32 {
    let s = contact_signal(frame, bg);
    s.iter().sum::<f32>() / s.len() as f32
}

/// Centre crop (CROP x CROP) of a 240x320 grey image, mean removed.
pub fn centre_crop(sig: &[f32]) -> Vec<f32> {
    let (w, h) = (240usize, 320usize);
    let (x0, y0) = ((w - CROP) / 2, (h - CROP) / 2);
    let mut out = Vec::with_capacity(CROP * CROP);
    for y in 0..CROP {
        for x in 0..CROP {
            out.push(sig[(y0 + y) * w + x0 + x]);
        }
    }
    let m = out.iter().sum::<f32>() / out.len() as f32;
    out.iter_mut().for_each(|v| *v -= m);
    out
}

/// 2D power spectrum of a CROP x CROP image (separable DFT with a Hann window).
pub fn power_spectrum(img: &[f32]) -> Vec<f32> {
    let n = CROP;
    let win: Vec<f32> = (0..n)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f32::consts::PI * i as f32 / n as f32).cos())
        .collect();
    let (cos, sin): (Vec<f32>, Vec<f32>) = (0..n)
        .map(|k| {
            let a = -2.0 * std::f32::consts::PI * k as f32 / n as f32;
            (a.cos(), a.sin())
        })
        .unzip();
    // rows
    let mut re = vec![0f32; n * n];
    let mut im = vec![0f32; n * n];
    for y in 0..n {
        for k in 0..n {
            let (mut sr, mut si) = (0.0, 0.0);
            for x in 0..n {
                let v = img[y * n + x] * win[x] * win[y];
                let t = (k * x) % n;
                sr += v * cos[t];
                si += v * sin[t];
            }
            re[y * n + k] = sr;
            im[y * n + k] = si;
        }
    }
    // columns
    let mut p = vec![0f32; n * n];
    for kx in 0..n {
        for ky in 0..n {
            let (mut sr, mut si) = (0.0, 0.0);
            for y in 0..n {
                let t = (ky * y) % n;
                let (c, s) = (cos[t], sin[t]);
                let (a, b) = (re[y * n + kx], im[y * n + kx]);
                sr += a * c - b * s;
                si += a * s + b * c;
            }
            p[ky * n + kx] = sr * sr + si * si;
        }
    }
    p
}

/// Radially averaged log power spectrum in `bins` bins (rotation invariant).
pub fn radial_spectrum(p: &[f32], bins: usize) -> Vec<f32> {
    let n = CROP as i64;
    let mut acc = vec![0f64; bins];
    let mut cnt = vec![0u32; bins];
    for ky in 0..n {
        for kx in 0..n {
            let fx = if kx > n / 2 { kx - n } else { kx };
            let fy = if ky > n / 2 { ky - n } else { ky };
            let r = ((fx * fx + fy * fy) as f64).sqrt();
            if r < 1.0 || r >= (n / 2) as f64 {
                continue;
            }
            let b = ((r - 1.0) / ((n / 2) as f64 - 1.0) * bins as f64) as usize;
            acc[b] += p[(ky * n + kx) as usize] as f64;
            cnt[b] += 1;
        }
    }
    let v: Vec<f32> = acc
        .iter()
        .zip(&cnt)
        .map(|(a, c)| ((a / (*c).max(1) as f64) + 1e-6).ln() as f32)
        .collect();
    // normalise the overall level away: shape only
    let m = v.iter().sum::<f32>() / v.len() as f32;
    v.iter().map(|x| x - m).collect()
}

/// Radial-spectrum feature of a frame.
pub fn feature(frame: &RgbImage, bg: &RgbImage) -> Vec<f32> {
    radial_spectrum(
        &power_spectrum(&centre_crop(&contact_signal(frame, bg))),
        24,
    )
}

/// Feature of a spec's mid-hold frame.
pub fn spec_feature(sim: &Simulator, spec: &PressSpec) -> Vec<f32> {
    let f = sim.render_frame(spec, 100).unwrap();
    feature(&f, &sim.background(spec.sensor))
}

pub fn dist(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

pub fn mean(v: &[Vec<f32>]) -> Vec<f32> {
    let mut m = vec![0f32; v[0].len()];
    for x in v {
        for (a, b) in m.iter_mut().zip(x) {
            *a += b / v.len() as f32;
        }
    }
    m
}

/// Dominant texture orientation (degrees, mod 180) from the structure tensor.
pub fn orientation_deg(sig: &[f32]) -> f32 {
    let n = CROP;
    let (mut jxx, mut jyy, mut jxy) = (0f64, 0f64, 0f64);
    for y in 1..n - 1 {
        for x in 1..n - 1 {
            let gx = (sig[y * n + x + 1] - sig[y * n + x - 1]) as f64;
            let gy = (sig[(y + 1) * n + x] - sig[(y - 1) * n + x]) as f64;
            jxx += gx * gx;
            jyy += gy * gy;
            jxy += gx * gy;
        }
    }
    let theta = 0.5 * (2.0 * jxy).atan2(jxx - jyy);
    (theta.to_degrees() as f32).rem_euclid(180.0)
}

/// Signed smallest difference of two angles mod 180, in -90..90.
pub fn angle_diff_180(a: f32, b: f32) -> f32 {
    let d = (a - b).rem_euclid(180.0);
    if d > 90.0 {
        d - 180.0
    } else {
        d
    }
}
