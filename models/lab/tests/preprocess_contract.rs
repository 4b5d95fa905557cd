//! The model input contract is computed in two places: the daemon's
//! `telextiles_sensing::preprocess::Preprocessor` (live session, `classify`,
//! `index build`, and the contrastive trainer's input, `supcon::diff_input`)
//! and the lab's cached views (`preprocess::centre_crop_resize` +
//! `methods::input_into`, used by `bench` and `eval`). They must agree:
//! bit for bit when the crop is the input size (every shipped descriptor),
//! and within the lab caches' u8 rounding of the resized image (half a
//! grey level) when the crop is resized.

use image::RgbImage;
use rand::{Rng, SeedableRng};
use telextiles_lab::methods::input_into;
use telextiles_lab::preprocess::{centre_crop_resize, DIGIT_MEAN, DIGIT_STD};
use telextiles_sensing::preprocess::{PreprocessSpec, Preprocessor};

fn random_frame(seed: u64) -> RgbImage {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    RgbImage::from_fn(240, 320, |_, _| {
        image::Rgb([rng.gen(), rng.gen(), rng.gen()])
    })
}

/// The lab's model input of a frame (and reference), as `bench` computes it.
fn lab_input(frame: &RgbImage, reference: Option<&RgbImage>, crop: u32, size: u32) -> Vec<f32> {
    let f = centre_crop_resize(frame, crop, size).unwrap();
    let r = reference.map(|r| centre_crop_resize(r, crop, size).unwrap());
    let mut x = Vec::new();
    input_into(
        f.as_raw(),
        r.as_ref().map(|r| r.as_raw().as_slice()),
        size as usize,
        &mut x,
    );
    x
}

/// The daemon's (frame minus reference when given).
fn daemon_input(frame: &RgbImage, reference: Option<&RgbImage>, crop: u32, size: u32) -> Vec<f32> {
    let pre = Preprocessor::new(PreprocessSpec {
        crop,
        size,
        mean: DIGIT_MEAN,
        std: DIGIT_STD,
    })
    .unwrap();
    let mut x = vec![0f32; pre.len()];
    pre.run(frame, &mut x);
    if let Some(r) = reference {
        let mut rv = vec![0f32; pre.len()];
        pre.run(r, &mut rv);
        for (v, r) in x.iter_mut().zip(&rv) {
            *v -= r;
        }
    }
    x
}

#[test]
fn lab_and_daemon_inputs_are_equal_without_resampling() {
    for (seed, crop) in [(1u64, 64u32), (2, 192), (3, 240), (4, 33)] {
        let (f, r) = (random_frame(seed), random_frame(seed + 100));
        for reference in [None, Some(&r)] {
            let a = lab_input(&f, reference, crop, crop);
            let b = daemon_input(&f, reference, crop, crop);
            assert_eq!(a.len(), b.len());
            let worst = a
                .iter()
                .zip(&b)
                .map(|(x, y)| (x - y).abs())
                .fold(0.0f32, f32::max);
            assert!(
                worst <= 1e-6,
                "crop {crop}, reference {}: differ by {worst}",
                reference.is_some()
            );
        }
    }
}

#[test]
fn resampled_inputs_differ_only_by_the_caches_rounding() {
    // Half a grey level, in normalised units, per channel; twice that with
    // a reference (both rounded).
    let half: Vec<f32> = DIGIT_STD.iter().map(|s| 0.5 / 255.0 / s).collect();
    for (seed, crop, size) in [(5u64, 192u32, 96u32), (6, 168, 64), (7, 240, 112)] {
        let (f, r) = (random_frame(seed), random_frame(seed + 100));
        for reference in [None, Some(&r)] {
            let a = lab_input(&f, reference, crop, size);
            let b = daemon_input(&f, reference, crop, size);
            let n = (size * size) as usize;
            let k = if reference.is_some() { 2.0 } else { 1.0 };
            for (c, h) in half.iter().enumerate() {
                let worst = a[c * n..(c + 1) * n]
                    .iter()
                    .zip(&b[c * n..(c + 1) * n])
                    .map(|(x, y)| (x - y).abs())
                    .fold(0.0f32, f32::max);
                assert!(
                    worst <= k * h + 1e-5,
                    "crop {crop} -> {size}, channel {c}: differ by {worst} > {}",
                    k * h
                );
            }
        }
    }
}

#[test]
fn the_contrastive_trainer_feeds_the_daemon_input() {
    let (f, r) = (random_frame(8), random_frame(9));
    for (crop, size) in [(192u32, 96u32), (64, 64)] {
        let a = telextiles_lab::supcon::diff_input(&f, &r, crop, size).unwrap();
        let b = daemon_input(&f, Some(&r), crop, size);
        assert_eq!(a, b, "crop {crop} -> {size}");
    }
}
