//! The version-2 sensor units and camera chain (docs/simulator.md): each
//! unit's background, illumination and camera (`sensor_model_v2`), and the
//! per-frame camera state of a press (`Camera`). What the renderers of
//! both catalogues share of version 2, apart from the renderer itself
//! (`render2`), so that neither renderer imports the other's.

use crate::calib::{HEIGHT as H, WIDTH as W};
use crate::catalogue::mix64;
use crate::SimError;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Sensor units of the version-2 protocol (any u32 is a valid unit; these
/// are the ones the validation and tests use).
pub const V2_UNITS: u32 = 16;
/// Frame rates a version-2 press is drawn from (DIGIT runs QVGA at 30 or 60
/// fps; 25/50 are the PAL rates of other USB cameras).
pub const FPS_CHOICES: [f32; 4] = [25.0, 30.0, 50.0, 60.0];

static BACKGROUND_TVL_PNG: &[u8] = include_bytes!("../data/digit_background_tvl_240x320.png");

/// The second real DIGIT no-contact frame (Max-Fu/tvl, Apache-2.0).
pub(crate) fn embedded_background_tvl() -> Result<image::RgbImage, SimError> {
    let img = image::load_from_memory_with_format(BACKGROUND_TVL_PNG, image::ImageFormat::Png)
        .map_err(|e| SimError::Calibration(format!("tvl background png: {e}")))?
        .to_rgb8();
    if img.width() as usize != W || img.height() as usize != H {
        return Err(SimError::Calibration(format!(
            "tvl background is {}x{}, expected {W}x{H}",
            img.width(),
            img.height()
        )));
    }
    Ok(img)
}

/// A version-2 sensor unit: its background (LED colour layout), optics and
/// camera.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorModelV2 {
    /// Weight of the tvl frame in the base background (0 = the tacto frame,
    /// 1 = the tvl frame; in between: a blend of the two layouts).
    pub base_mix: f32,
    /// LED ring assembled half a turn round: background turned by 180 degrees
    /// and the LED directions with it.
    pub turned: bool,
    /// Per channel, a smooth gain field `1 + amp (nx cos d + ny sin d) +
    /// radial (r^2 - 0.5)` that moves where each LED colour is bright.
    pub layout_amp: [f32; 3],
    pub layout_dir_deg: [f32; 3],
    pub layout_radial: [f32; 3],
    pub bg_gain: [f32; 3],
    pub bg_offset: [f32; 3],
    pub bg_shift: (i32, i32),
    /// Radial vignetting (fraction lost at the corners).
    pub vignette: f32,
    /// LED intensity per channel on the optical response.
    pub led_gain: [f32; 3],
    /// Rotation of each channel's direction response (the LED's position
    /// around the gel), degrees.
    pub led_dir_deg: [f32; 3],
    pub gel_thickness_mm: f32,
    pub dome_mm: f32,
    /// Optical blur of the camera (Gaussian sigma, px).
    pub blur_px: f32,
    /// Compression strength: share of the in-block detail (beyond each 8x8
    /// block's plane) lost in luma; chroma loses more and is 2x2 subsampled.
    pub block_q: f32,
    /// Read noise (DN) and shot-noise gain.
    pub read_noise: f32,
    pub shot_gain: f32,
    /// Passes of a [1 2 1] smoothing on the luma noise (demosaicing) and the
    /// share of white noise mixed back in.
    pub noise_passes: u32,
    pub noise_white: f32,
    /// Chroma noise (2x2 blocks, half resolution) relative to luma noise.
    pub chroma_noise: f32,
    /// Exposure drift: standard deviation of the slowly wandering gain.
    pub exposure_drift: f32,
}

/// Version-2 sensor unit `id`. Units 0 and 1 are the two real frames as
/// they are (tacto and tvl); all others are drawn.
pub fn sensor_model_v2(id: u32) -> SensorModelV2 {
    let mut r = ChaCha8Rng::seed_from_u64(mix64(0x5e45_0002_0000 + id as u64));
    let g3 = |r: &mut ChaCha8Rng, lo: f32, hi: f32| {
        [
            r.gen_range(lo..hi),
            r.gen_range(lo..hi),
            r.gen_range(lo..hi),
        ]
    };
    let nominal = id < 2;
    let base_mix = if nominal {
        id as f32
    } else {
        let u: f32 = r.gen();
        if u < 0.42 {
            0.0
        } else if u < 0.84 {
            1.0
        } else {
            r.gen_range(0.25..0.75)
        }
    };
    let turned = !nominal && r.gen_bool(0.3);
    let layout_amp = if nominal {
        [0.0; 3]
    } else {
        g3(&mut r, 0.0, 0.2)
    };
    let layout_dir_deg = g3(&mut r, -180.0, 180.0);
    let layout_radial = if nominal {
        [0.0; 3]
    } else {
        g3(&mut r, -0.15, 0.15)
    };
    let bg_gain = if nominal {
        [1.0; 3]
    } else {
        g3(&mut r, 0.9, 1.1)
    };
    let bg_offset = if nominal {
        [0.0; 3]
    } else {
        g3(&mut r, -8.0, 8.0)
    };
    let bg_shift = if nominal {
        (0, 0)
    } else {
        (r.gen_range(-8..=8), r.gen_range(-8..=8))
    };
    let vignette = if nominal { 0.0 } else { r.gen_range(0.0..0.3) };
    let led_gain = if nominal {
        [1.0; 3]
    } else {
        g3(&mut r, 0.75, 1.3)
    };
    let mut led_dir_deg = if nominal {
        [0.0; 3]
    } else {
        g3(&mut r, -25.0, 25.0)
    };
    if turned {
        for d in led_dir_deg.iter_mut() {
            *d += 180.0;
        }
    }
    SensorModelV2 {
        base_mix,
        turned,
        layout_amp,
        layout_dir_deg,
        layout_radial,
        bg_gain,
        bg_offset,
        bg_shift,
        vignette,
        led_gain,
        led_dir_deg,
        gel_thickness_mm: if nominal { 1.0 } else { r.gen_range(0.6..1.6) },
        dome_mm: if nominal {
            0.25
        } else {
            r.gen_range(0.1..0.45)
        },
        blur_px: r.gen_range(0.5..1.1),
        block_q: r.gen_range(0.15..0.5),
        read_noise: r.gen_range(0.5..1.1),
        shot_gain: r.gen_range(0.003..0.008),
        noise_passes: r.gen_range(1..=2),
        noise_white: r.gen_range(0.05..0.3),
        chroma_noise: r.gen_range(0.3..0.8),
        exposure_drift: r.gen_range(0.002..0.012),
    }
}

/// Per-frame camera state of a version-2 press.
pub(crate) struct Camera {
    /// Exposure gain per frame (1 without noise).
    pub(crate) exposure: Vec<f32>,
    pub(crate) noise: bool,
    pub(crate) passes: u32,
    pub(crate) white: f32,
    pub(crate) chroma: f32,
    /// Scale that gives the smoothed-and-mixed luma noise unit variance.
    pub(crate) luma_norm: f32,
    pub(crate) seed: u64,
}
