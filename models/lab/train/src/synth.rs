//! A cheap procedural frame source for tests and pipeline timing: every
//! textile is a sum of oriented gratings, every person/press/frame perturbs
//! it a little. It is *not* a DIGIT model (that is `telextiles-sim`); it only
//! exists so the training/export/eval machinery can be exercised in seconds.

use crate::data::{FrameSource, PressKey};
use anyhow::Result;
use image::RgbImage;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use sha2::{Digest, Sha256};

/// Procedural frame source.
pub struct SynthSource;

fn seed_of(parts: &[&[u8]]) -> u64 {
    let mut h = Sha256::new();
    for p in parts {
        h.update(p);
        h.update([0]);
    }
    u64::from_le_bytes(
        h.finalize()[..8]
            .try_into()
            .expect("a SHA-256 digest has 32 bytes"),
    )
}

impl FrameSource for SynthSource {
    fn describe(&self) -> String {
        "synthetic gratings v1".into()
    }

    fn frames_per_press(&self) -> usize {
        150
    }

    fn training_textiles(&self) -> Vec<String> {
        (1..=24).map(|i| format!("T{i:03}")).collect()
    }

    fn unseen_textiles(&self) -> Vec<String> {
        (1..=4).map(|i| format!("U{i:02}")).collect()
    }

    /// The frame with no grating: the flat grey the gratings sit on.
    fn background(&self, _sensor: u32) -> Result<Option<RgbImage>> {
        Ok(Some(RgbImage::from_pixel(
            240,
            320,
            image::Rgb([110, 125, 115]),
        )))
    }

    fn frames(&self, press: &PressKey, indices: &[usize]) -> Result<Vec<RgbImage>> {
        let mut trng = ChaCha8Rng::seed_from_u64(seed_of(&[press.textile.as_bytes()]));
        let gratings: Vec<(f32, f32, f32, [f32; 3])> = (0..3)
            .map(|_| {
                (
                    trng.gen_range(0.04..0.25f32),
                    trng.gen_range(0.0..std::f32::consts::PI),
                    trng.gen_range(0.0..std::f32::consts::TAU),
                    [
                        trng.gen_range(0.3..1.0),
                        trng.gen_range(0.3..1.0),
                        trng.gen_range(0.3..1.0),
                    ],
                )
            })
            .collect();
        let tint = [
            trng.gen_range(-40.0..40.0f32),
            trng.gen_range(-40.0..40.0f32),
            trng.gen_range(-40.0..40.0f32),
        ];
        let mut prng = ChaCha8Rng::seed_from_u64(seed_of(&[
            press.textile.as_bytes(),
            &press.person.to_le_bytes(),
            &press.seed.to_le_bytes(),
            &[press.jig as u8],
        ]));
        let base_rot = press.person as f32 * 0.35 + prng.gen_range(-0.2..0.2f32);
        let gain = 0.85 + 0.03 * press.person as f32;
        indices
            .iter()
            .map(|&f| {
                let mut frng = ChaCha8Rng::seed_from_u64(prng.gen::<u64>() ^ f as u64);
                let wobble = if press.jig { 0.02 } else { 0.25 };
                let rot = base_rot + frng.gen_range(-wobble..wobble);
                let (dx, dy) = (frng.gen_range(-3.0..3.0f32), frng.gen_range(-3.0..3.0f32));
                let (s, c) = rot.sin_cos();
                Ok(RgbImage::from_fn(240, 320, |x, y| {
                    let (xf, yf) = (x as f32 - 120.0 + dx, y as f32 - 160.0 + dy);
                    let mask = (1.0 - (xf / 100.0).powi(2) - (yf / 130.0).powi(2)).clamp(0.0, 1.0);
                    let (u, v) = (c * xf - s * yf, s * xf + c * yf);
                    let mut px = [
                        110.0 + mask * tint[0],
                        125.0 + mask * tint[1],
                        115.0 + mask * tint[2],
                    ];
                    for (freq, ori, ph, col) in &gratings {
                        let t = (freq * (u * ori.cos() + v * ori.sin()) + ph).sin();
                        for k in 0..3 {
                            px[k] += 40.0 * gain * mask * t * col[k];
                        }
                    }
                    image::Rgb(px.map(|p| p.clamp(0.0, 255.0) as u8))
                }))
            })
            .collect()
    }
}
