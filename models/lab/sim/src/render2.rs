//! Catalogue version 2: sensor units with their own LED colour layouts, a
//! camera chain (optical blur, 8x8 block compression with 4:2:0 chroma,
//! spatially and colour-correlated noise, exposure drift), presses at
//! 25..60 fps with slow and fast ramps, partial contact and release, and
//! fabric bolts (`bolt`, generator 1; `gabor`, generator 2) with creases,
//! folds, seams, hems and cloth edges in some presses.
//!
//! Catalogue 1 (`render.rs`) is untouched by any of this.

use crate::calib::{BINS, HEIGHT as H, WIDTH as W};
use crate::catalogue::{hash_str, mix64, Family};
use crate::fabric::{HeightField, MM_PER_PX};
use crate::render::{
    blur_separable, gaussian_kernel, person_style, smooth, Setup, Simulator, FULL_KEY, KEYS, N,
};
use crate::{bolt, gabor, PressParams, PressSpec, SimError};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub(crate) use crate::sensor2::Camera;
/// Side of the fabric raster rendered per press: covers the rotated window
/// (half-diagonal 200 px), stretched and sheared (+5 %, +4 %) and slipped
/// (+13 px).
const RASTER: usize = 472;
pub use crate::sensor2::{sensor_model_v2, SensorModelV2, FPS_CHOICES, V2_UNITS};

/// Share of the cloth's relief left under the gel beyond what compliance
/// flattens (the gel rests on the load-bearing top; fibres and yarns
/// flatten): sets the contact contrast to the real median of ~2.5 DN.
const RELIEF_UNDER_GEL: f32 = 0.5;
/// The block size of the compression approximation.
const BLOCK: usize = 8;
/// Salt separating version-2 draws from version 1's.
const V2_SALT: u64 = 0x0002_0002_5eed_0002;
/// Swatches (regions of the bolt) per textile in catalogue 2.
pub const SWATCHES: u32 = 8;
use std::f32::consts::PI;

/// A press-level feature of the cloth in the window.
#[derive(Clone, Copy, Debug)]
enum Feature {
    /// Raised (or sunken) crease: height, half-width px.
    Crease { h: f32, w: f32 },
    /// Fold: the cloth doubles beyond the line.
    Fold { h: f32, w: f32 },
    /// Seam: two ridges (seam allowance) with a groove and stitches.
    Seam { h: f32, w: f32, stitch: f32 },
    /// Hem: a step up beyond the line with a stitch row.
    Hem {
        h: f32,
        w: f32,
        stitch: f32,
        row: f32,
    },
    /// Cloth edge: no cloth beyond the line.
    Edge,
}

#[derive(Clone, Copy, Debug)]
struct Placed {
    f: Feature,
    /// Unit normal of the line and its offset from the raster centre, px.
    nx: f32,
    ny: f32,
    d: f32,
}

impl Placed {
    /// Height added at raster offset (x, y) from the centre, mm.
    fn height(&self, x: f32, y: f32) -> f32 {
        let s = x * self.nx + y * self.ny - self.d; // signed distance
        let t = -x * self.ny + y * self.nx; // along the line
        match self.f {
            Feature::Crease { h, w } => h * (-(s * s) / (w * w)).exp(),
            Feature::Fold { h, w } => {
                let step = smooth(0.5 + s / (2.0 * w));
                let lip = 0.3 * h * (-(s * s) / (w * w)).exp();
                h * step + lip
            }
            Feature::Seam { h, w, stitch } => {
                let ridge = (-((s.abs() - w) * (s.abs() - w)) / (0.45 * w * w)).exp();
                let groove = (-(s * s) / (0.08 * w * w)).exp();
                let st = 0.5 + 0.5 * (2.0 * PI * t / stitch).cos();
                h * ridge - 0.4 * h * groove * (1.0 - 0.6 * st)
            }
            Feature::Hem { h, w, stitch, row } => {
                let step = smooth(0.5 + s / (2.0 * w));
                let r = s - row;
                let groove = (-(r * r) / (0.1 * w * w)).exp();
                let st = 0.5 + 0.5 * (2.0 * PI * t / stitch).cos();
                h * step - 0.3 * h * groove * (0.4 + 0.6 * st) * step
            }
            Feature::Edge => {
                if s > 0.0 {
                    -3.0
                } else {
                    0.0
                }
            }
        }
    }
}

fn gauss(r: &mut ChaCha8Rng) -> f32 {
    let u1: f32 = r.gen_range(1e-7..1.0);
    let u2: f32 = r.gen();
    (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
}

/// Which swatch (region of the bolt) a press sees: from the seed and the
/// person, so presses of one textile by different people or seeds see
/// different cloth.
pub fn swatch_of(spec: &PressSpec) -> u32 {
    (mix64(
        spec.seed.wrapping_mul(0x2545_F491_4F6C_DD1D)
            ^ mix64(spec.person as u64 ^ 0x5a5a_0000)
            ^ hash_str(&spec.textile),
    ) % SWATCHES as u64) as u32
}

impl Simulator {
    /// Background of a version-2 unit before the camera: the real frames
    /// blended, turned, shifted, re-coloured, vignetted.
    fn raw_background_v2(&self, s: &SensorModelV2) -> Vec<f32> {
        let a = self.real_background();
        let b = &self.background_tvl;
        let mut out = vec![0f32; N * 3];
        let dirs: Vec<(f32, f32)> = s
            .layout_dir_deg
            .iter()
            .map(|d| d.to_radians().sin_cos())
            .collect();
        for y in 0..H {
            for x in 0..W {
                let mut sx = (x as i32 - s.bg_shift.0).clamp(0, W as i32 - 1) as u32;
                let mut sy = (y as i32 - s.bg_shift.1).clamp(0, H as i32 - 1) as u32;
                if s.turned {
                    sx = W as u32 - 1 - sx;
                    sy = H as u32 - 1 - sy;
                }
                let pa = a.get_pixel(sx, sy).0;
                let pb = b.get_pixel(sx, sy).0;
                let nx = (x as f32 - W as f32 / 2.0) / (W as f32 / 2.0);
                let ny = (y as f32 - H as f32 / 2.0) / (H as f32 / 2.0);
                let r2 = 0.5 * (nx * nx + ny * ny);
                let vig = 1.0 - s.vignette * r2;
                for c in 0..3 {
                    let base = pa[c] as f32 * (1.0 - s.base_mix) + pb[c] as f32 * s.base_mix;
                    let (sn, cs) = dirs[c];
                    let field = 1.0
                        + s.layout_amp[c] * (nx * cs + ny * sn)
                        + s.layout_radial[c] * (r2 - 0.5);
                    out[(y * W + x) * 3 + c] =
                        base * field.max(0.2) * s.bg_gain[c] * vig + s.bg_offset[c];
                }
            }
        }
        out
    }

    /// A version-2 unit's no-contact frame through its camera (no noise).
    pub(crate) fn background_v2(&self, s: &SensorModelV2) -> Vec<f32> {
        let mut bg = self.raw_background_v2(s);
        camera_linear(&mut bg, s);
        bg
    }

    /// Contact change of a penetration field through the gel and the unit's
    /// LEDs (each channel's direction response rotated and scaled).
    fn shade_v2(&self, gap: &[f32], d: f32, kernel: &[f32], s: &SensorModelV2) -> Vec<f32> {
        let mut pen: Vec<f32> = gap.iter().map(|g| (d - g).max(0.0)).collect();
        blur_separable(&mut pen, kernel);
        let mut out = vec![0f32; N * 3];
        let inv2 = 1.0 / (2.0 * MM_PER_PX);
        let mag_step = (PI / 2.0) / (BINS as f32 - 1.0);
        let dir_step = (2.0 * PI) / (BINS as f32 - 1.0);
        let rot: Vec<f32> = s.led_dir_deg.iter().map(|d| d.to_radians()).collect();
        for y in 1..H - 1 {
            for x in 1..W - 1 {
                let i = y * W + x;
                let gx = (pen[i + 1] - pen[i - 1]) * inv2;
                let gy = (pen[i + W] - pen[i - W]) * inv2;
                let m2 = gx * gx + gy * gy;
                if m2 < 1e-6 {
                    continue;
                }
                let ang = m2.sqrt().atan();
                let mb = ((ang / mag_step) as usize).min(BINS - 1);
                if mb == 0 {
                    continue;
                }
                let dir = gy.atan2(gx);
                for c in 0..3 {
                    let a = (dir + rot[c] + PI).rem_euclid(2.0 * PI);
                    let db = ((a / dir_step) as usize).min(BINS - 1);
                    let v = self.calib.eval_channel(mb, db, c, x as f32, y as f32);
                    out[i * 3 + c] = s.led_gain[c] * (v - self.flat[i * 3 + c]);
                }
            }
        }
        out
    }

    /// Solve a version-2 press.
    pub(crate) fn solve_v2(&self, spec: &PressSpec, generator: u32) -> Result<Setup, SimError> {
        let textile = self
            .catalogue_of(2)
            .get(&spec.textile)
            .ok_or_else(|| SimError::UnknownTextile(spec.textile.clone()))?;
        validate(spec)?;
        let person = person_style(spec.person);
        let sensor = sensor_model_v2(spec.sensor);
        let mut rng = ChaCha8Rng::seed_from_u64(mix64(
            spec.seed
                ^ hash_str(&spec.textile)
                ^ mix64(spec.person as u64 * 1_000_003 + spec.sensor as u64)
                ^ spec.jig as u64
                ^ V2_SALT
                ^ (generator as u64) << 40,
        ));
        let frames = spec.frames;
        // --- frame rate ---------------------------------------------------
        let drawn_fps = {
            let u: f32 = rng.gen();
            FPS_CHOICES[if u < 0.15 {
                0
            } else if u < 0.5 {
                1
            } else if u < 0.65 {
                2
            } else {
                3
            }]
        };
        let fps = spec.fps.unwrap_or(drawn_fps);
        // --- pose and force (as in catalogue 1) ------------------------------
        let habit = {
            let x: f32 = rng.gen();
            let mut acc = 0.0;
            let mut a = person.rotation_habits[0].0;
            for &(ang, w) in &person.rotation_habits {
                acc += w;
                if x <= acc {
                    a = ang;
                    break;
                }
            }
            a
        };
        let drawn_rot = if spec.jig {
            habit + 2.0 * gauss(&mut rng)
        } else if rng.gen::<f32>() < person.any_angle {
            rng.gen_range(-180.0..180.0)
        } else {
            habit + person.rotation_sd_deg * gauss(&mut rng)
        };
        let rotation_deg = spec.rotation_deg.unwrap_or(drawn_rot);
        let drawn_force = if spec.jig {
            4.0 * (1.0 + 0.03 * gauss(&mut rng))
        } else {
            (person.force_n * (1.0 + person.force_sd * gauss(&mut rng))).max(0.5)
        };
        let force_n = spec.force.unwrap_or(drawn_force);
        // the bolt is large: offsets within a swatch up to +-8 mm
        let max_off = 8.0;
        let drawn_off = [
            rng.gen_range(-max_off..max_off),
            rng.gen_range(-max_off..max_off),
        ];
        let offset_mm = spec.offset_mm.unwrap_or(drawn_off);
        let offset_mm = [
            offset_mm[0].clamp(-max_off, max_off),
            offset_mm[1].clamp(-max_off, max_off),
        ];
        let mut features = Vec::new();
        let tilt_sd = if spec.jig { 0.12 } else { person.tilt_sd_deg };
        let mut drawn_tilt = [tilt_sd * gauss(&mut rng), tilt_sd * gauss(&mut rng)];
        // partial contact: a strong tilt or a cloth edge in the window
        let partial_p = if spec.jig { 0.05 } else { 0.2 };
        let partial = rng.gen::<f32>() < partial_p;
        let edge = partial && rng.gen_bool(0.5);
        if partial && !edge && spec.tilt_deg.is_none() {
            let a: f32 = rng.gen_range(0.0..2.0 * PI);
            let m: f32 = rng.gen_range(1.5..3.0);
            drawn_tilt = [m * a.cos(), m * a.sin()];
            features.push("tilt".to_string());
        }
        let tilt_deg = spec.tilt_deg.unwrap_or(drawn_tilt);
        let (wobble, slip_mm) = if spec.jig {
            (0.01, [0.0, 0.0])
        } else {
            let s = person.slip_mm;
            (person.wobble, [s * gauss(&mut rng), s * gauss(&mut rng)])
        };
        let slip_mm = [slip_mm[0].clamp(-1.0, 1.0), slip_mm[1].clamp(-1.0, 1.0)];
        // --- timeline in seconds -------------------------------------------
        let contact_s = if spec.jig {
            rng.gen_range(0.25..0.6)
        } else {
            (person.contact_frame / 60.0) * (1.0 + 0.3 * gauss(&mut rng)).max(0.4)
        };
        let slow = rng.gen::<f32>() < if spec.jig { 0.1 } else { 0.4 };
        let ramp_s = if slow {
            features.push("slow-ramp".to_string());
            rng.gen_range(0.6..1.6)
        } else if spec.jig {
            rng.gen_range(0.1..0.3)
        } else {
            features.push("fast-ramp".to_string());
            (person.ramp_frames / 60.0 * rng.gen_range(0.4..1.0)).max(0.05)
        };
        // at least 3 untouched frames (fewer only in very short presses)
        let lo = 3.min(frames as u32 - 1);
        let hi = ((frames as f32 * 0.4) as u32).max(lo);
        let contact_frame = ((contact_s * fps).round() as u32).clamp(lo, hi);
        let hold_frame = (contact_frame as f32 + (ramp_s * fps).max(1.0)).round() as u32;
        let releases = spec.release.unwrap_or(
            rng.gen::<f32>()
                < if spec.jig {
                    0.4
                } else {
                    (person.release_prob + 0.45).min(0.95)
                },
        );
        let release_s: f32 = rng.gen_range(0.08..0.5);
        let release_frame = if releases {
            Some(
                ((frames as f32) * rng.gen_range(0.62..0.88))
                    .round()
                    .max(hold_frame as f32 + 1.0) as u32,
            )
        } else {
            None
        };
        // --- the cloth: swatch of the bolt, press features ------------------
        let swatch = swatch_of(spec);
        let sw = bolt::swatch(textile, swatch);
        let compliance = textile.compliance;
        let indentation_mm = 0.12 * force_n.powf(0.67) * (1.0 + 0.3 * compliance);
        let mut placed = Vec::new();
        let mut place = |rng: &mut ChaCha8Rng, f: Feature, spread: f32| {
            let a: f32 = rng.gen_range(0.0..PI);
            let (sn, cs) = a.sin_cos();
            placed.push(Placed {
                f,
                nx: cs,
                ny: sn,
                d: rng.gen_range(-spread..spread),
            });
        };
        let thick = textile.thickness_mm.min(3.0);
        if rng.gen::<f32>() < 0.2 {
            let h = rng.gen_range(0.04..0.22) * if rng.gen_bool(0.7) { 1.0 } else { -0.6 };
            let w = rng.gen_range(0.4..1.5) / MM_PER_PX;
            place(&mut rng, Feature::Crease { h, w }, 90.0);
            features.push("crease".to_string());
        }
        let u: f32 = rng.gen();
        if u < 0.04 {
            let h = (thick * rng.gen_range(0.3..0.6)).clamp(0.15, 1.0);
            let w = rng.gen_range(0.5..1.2) / MM_PER_PX;
            place(&mut rng, Feature::Fold { h, w }, 80.0);
            features.push("fold".to_string());
        } else if u < 0.09 {
            let h = (thick * rng.gen_range(0.2..0.4)).clamp(0.12, 0.5);
            let w = rng.gen_range(1.0..2.5) / MM_PER_PX;
            let stitch = rng.gen_range(2.5..4.0) / MM_PER_PX;
            place(&mut rng, Feature::Seam { h, w, stitch }, 80.0);
            features.push("seam".to_string());
        } else if u < 0.12 {
            let h = (thick * rng.gen_range(0.3..0.6)).clamp(0.15, 0.8);
            let w = rng.gen_range(0.4..0.8) / MM_PER_PX;
            let stitch = rng.gen_range(2.5..4.0) / MM_PER_PX;
            let row = rng.gen_range(3.0..6.0) / MM_PER_PX;
            place(&mut rng, Feature::Hem { h, w, stitch, row }, 80.0);
            features.push("hem".to_string());
        }
        if edge {
            place(&mut rng, Feature::Edge, 70.0);
            features.push("edge".to_string());
        }
        // the bolt raster around this press's window
        let centre = (
            offset_mm[0] / MM_PER_PX + sw.origin.0,
            offset_mm[1] / MM_PER_PX + sw.origin.1,
        );
        let ox = centre.0.round() as i64 - RASTER as i64 / 2;
        let oy = centre.1.round() as i64 - RASTER as i64 / 2;
        let mut raster = if generator == 2 {
            gabor::window(textile, &sw, ox, oy, RASTER)
        } else {
            bolt::window(textile, &sw, ox, oy, RASTER)
        };
        // Loops, tufts and pile bend under the gel until it rests on many of
        // them: their tallest stand at most ~0.6 indentations above the median.
        if matches!(
            textile.structure.family(),
            Family::Terry | Family::Loop | Family::Tuft | Family::Pile | Family::Fleece
        ) {
            let mut v: Vec<f32> = raster.h.iter().step_by(7).cloned().collect();
            v.sort_by(|a, b| a.total_cmp(b));
            let (p50, max) = (v[v.len() / 2], v[v.len() - 1]);
            let keep = RELIEF_UNDER_GEL * (1.0 - 0.6 * textile.compliance) * sw.relief_scale;
            let span = (max - p50) * keep;
            let target = 0.6 * indentation_mm;
            if span > target {
                let k = target / span;
                raster.h.iter_mut().for_each(|h| *h *= k);
            }
        }
        let params = PressParams {
            rotation_deg,
            force_n,
            offset_mm,
            tilt_deg,
            indentation_mm,
            gel_thickness_mm: sensor.gel_thickness_mm,
            contact_frame,
            hold_frame,
            release_frame,
            slip_mm,
            wobble,
            noise: spec.noise,
            catalogue_version: 2,
            generator,
            swatch: Some(swatch),
            features,
        };
        // --- per-frame depth and slip ---------------------------------------
        let phase: f32 = rng.gen_range(0.0..2.0 * PI);
        let hz: f32 = rng.gen_range(1.0..4.0);
        let mut jitter = 0.0f32;
        let mut depth = Vec::with_capacity(frames);
        let mut slip = Vec::with_capacity(frames);
        let hold_len = release_frame
            .unwrap_or(frames as u32)
            .saturating_sub(hold_frame)
            .max(1) as f32;
        let rel_frames = (release_s * fps).max(1.0);
        let jit_rho = (-1.0 / (0.1 * fps)).exp();
        for i in 0..frames {
            let f = i as f32;
            let (c, h) = (contact_frame as f32, hold_frame as f32);
            let mut u = if f < c {
                0.0
            } else if f < h {
                smooth((f - c + 1.0) / (h - c + 1.0))
            } else {
                jitter = jit_rho * jitter
                    + gauss(&mut rng) * if spec.jig { 0.003 } else { 0.02 } * (60.0 / fps).sqrt();
                1.0 + wobble * (2.0 * PI * hz * (f - h) / fps + phase).sin() + jitter
            };
            if let Some(r) = release_frame {
                let r = r as f32;
                if f >= r {
                    u *= 1.0 - smooth((f - r + 1.0) / rel_frames);
                }
            }
            // the first contact frame always touches
            if i as u32 >= contact_frame && u <= 0.0 && release_frame.is_none_or(|r| (i as u32) < r)
            {
                u = 1e-3;
            }
            depth.push(u.clamp(0.0, KEYS[KEYS.len() - 1]));
            let s = if f < hold_frame as f32 {
                0.0
            } else {
                ((f - hold_frame as f32) / hold_len).min(1.0)
            };
            slip.push(s);
        }
        // --- solve the contact at key depths --------------------------------
        let relief_keep = RELIEF_UNDER_GEL * (1.0 - 0.6 * compliance);
        let gap_a = gap_field_v2(
            &raster,
            &params,
            [0.0, 0.0],
            &sw,
            &placed,
            &sensor,
            relief_keep,
        );
        let sigma_px = sensor.gel_thickness_mm * crate::render::GEL_BLUR_PER_MM / MM_PER_PX;
        let kernel = gaussian_kernel(sigma_px);
        let mut keys = vec![Vec::new()];
        for &k in &KEYS[1..] {
            let mut key = self.shade_v2(&gap_a, k * indentation_mm, &kernel, &sensor);
            camera_linear(&mut key, &sensor);
            keys.push(key);
        }
        let slipped = if slip_mm != [0.0, 0.0] {
            let gap_b = gap_field_v2(
                &raster,
                &params,
                slip_mm,
                &sw,
                &placed,
                &sensor,
                relief_keep,
            );
            let mut key = self.shade_v2(&gap_b, indentation_mm, &kernel, &sensor);
            camera_linear(&mut key, &sensor);
            Some(key)
        } else {
            None
        };
        let bg = self.background_v2(&sensor);
        let (rn, shot) = if spec.noise {
            (sensor.read_noise, sensor.shot_gain)
        } else {
            (0.0, 0.0)
        };
        let noise_sd = bg
            .iter()
            .map(|g| (rn * rn + shot * g.max(0.0)).sqrt())
            .collect();
        // exposure: AR(1) wander with a 1.5 s time constant plus flicker
        let rho = (-1.0 / (1.5 * fps)).exp();
        let mut e = sensor.exposure_drift * gauss(&mut rng);
        let exposure = (0..frames)
            .map(|_| {
                e = rho * e + (1.0 - rho * rho).sqrt() * sensor.exposure_drift * gauss(&mut rng);
                if spec.noise {
                    1.0 + e + 0.002 * gauss(&mut rng)
                } else {
                    1.0
                }
            })
            .collect();
        let camera = Camera {
            exposure,
            noise: spec.noise,
            passes: sensor.noise_passes,
            white: sensor.noise_white,
            chroma: sensor.chroma_noise,
            luma_norm: luma_norm(sensor.noise_passes, sensor.noise_white),
            seed: mix64(spec.seed ^ 0x2A5A_5A5A ^ hash_str(&spec.textile) ^ spec.sensor as u64),
        };
        Ok(Setup {
            params,
            frames,
            bg,
            noise_sd,
            keys,
            slipped,
            depth,
            slip,
            noise_seed: camera.seed,
            read_noise: rn,
            shot_gain: shot,
            fps,
            v2: Some(camera),
        })
    }

    /// Frame `i` of a version-2 press: interpolated contact, exposure,
    /// correlated camera noise, 8-bit.
    pub(crate) fn frame_v2(&self, s: &Setup, cam: &Camera, i: usize) -> image::RgbImage {
        let u = s.depth[i];
        let mut k = 1;
        while k < KEYS.len() - 1 && KEYS[k] < u {
            k += 1;
        }
        let (k0, k1) = (k - 1, k);
        let t = ((u - KEYS[k0]) / (KEYS[k1] - KEYS[k0])).clamp(0.0, 1.0);
        let slip_w = s.slip[i] * u.min(1.0);
        let e = cam.exposure[i];
        let mut v: Vec<f32> = s.bg.clone();
        if u > 0.0 {
            let b = &s.keys[k1];
            if k0 == 0 {
                for (o, bv) in v.iter_mut().zip(b) {
                    *o += t * bv;
                }
            } else {
                let a = &s.keys[k0];
                for (o, (av, bv)) in v.iter_mut().zip(a.iter().zip(b)) {
                    *o += av + t * (bv - av);
                }
            }
            if let (Some(sl), true) = (&s.slipped, slip_w > 0.0) {
                let full = &s.keys[FULL_KEY];
                for (o, (sv, fv)) in v.iter_mut().zip(sl.iter().zip(full)) {
                    *o += slip_w * (sv - fv);
                }
            }
        }
        let mut raw = vec![0u8; N * 3];
        if cam.noise {
            let (luma, cr, cb) = self.noise_fields(cam, i);
            for (p, (l, (out, (val, sd)))) in luma
                .iter()
                .zip(
                    raw.chunks_exact_mut(3)
                        .zip(v.chunks_exact(3).zip(s.noise_sd.chunks_exact(3))),
                )
                .enumerate()
            {
                let (x, y) = (p % W, p / W);
                let q = (y / 2) * (W / 2) + x / 2;
                let (r_, b_) = (cam.chroma * cr[q], cam.chroma * cb[q]);
                let n = [l + r_, l - 0.5 * (r_ + b_), l + b_];
                for (c, nc) in n.iter().enumerate() {
                    out[c] = (val[c] * e + sd[c] * nc + 0.5).clamp(0.0, 255.0) as u8;
                }
            }
        } else {
            for (o, x) in raw.iter_mut().zip(&v) {
                *o = (x * e + 0.5).clamp(0.0, 255.0) as u8;
            }
        }
        image::RgbImage::from_raw(W as u32, H as u32, raw)
            .unwrap_or_else(|| image::RgbImage::new(W as u32, H as u32))
    }

    /// Luma noise (smoothed, unit variance) and half-resolution chroma noise.
    fn noise_fields(&self, cam: &Camera, i: usize) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let nseed = mix64(cam.seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let normals = &self.normals[..8192];
        let z = |k: u64| normals[((nseed ^ k).wrapping_mul(0x9E37_79B9_7F4A_7C15) >> 51) as usize];
        let white: Vec<f32> = (0..N as u64).map(z).collect();
        let mut l = white.clone();
        let mut tmp = vec![0f32; N];
        for _ in 0..cam.passes {
            for y in 0..H {
                let row = &l[y * W..(y + 1) * W];
                let out = &mut tmp[y * W..(y + 1) * W];
                out[0] = 0.5 * row[0] + 0.5 * row[1];
                for x in 1..W - 1 {
                    out[x] = 0.25 * row[x - 1] + 0.5 * row[x] + 0.25 * row[x + 1];
                }
                out[W - 1] = 0.5 * row[W - 1] + 0.5 * row[W - 2];
            }
            for y in 0..H {
                let (ym, yp) = (y.saturating_sub(1), (y + 1).min(H - 1));
                for x in 0..W {
                    l[y * W + x] =
                        0.25 * tmp[ym * W + x] + 0.5 * tmp[y * W + x] + 0.25 * tmp[yp * W + x];
                }
            }
        }
        let (a, b) = (1.0 - cam.white, cam.white);
        for (o, w) in l.iter_mut().zip(&white) {
            *o = (a * *o + b * w) * cam.luma_norm;
        }
        let half = (W / 2) * (H / 2);
        let cr: Vec<f32> = (0..half as u64).map(|k| z(k + 0x100_0000)).collect();
        let cb: Vec<f32> = (0..half as u64).map(|k| z(k + 0x200_0000)).collect();
        (l, cr, cb)
    }
}

fn validate(spec: &PressSpec) -> Result<(), SimError> {
    if spec.frames == 0 || spec.frames > 100_000 {
        return Err(SimError::InvalidSpec(format!("frames = {}", spec.frames)));
    }
    if let Some(f) = spec.force {
        if !(f.is_finite() && f > 0.0 && f <= 50.0) {
            return Err(SimError::InvalidSpec(format!(
                "force {f} N (0 < force <= 50)"
            )));
        }
    }
    if let Some(r) = spec.rotation_deg {
        if !r.is_finite() {
            return Err(SimError::InvalidSpec("rotation is not finite".into()));
        }
    }
    if let Some(t) = spec.tilt_deg {
        if !t.iter().all(|v| v.is_finite() && v.abs() <= 20.0) {
            return Err(SimError::InvalidSpec(format!(
                "tilt {t:?} degrees (each within -20..=20)"
            )));
        }
    }
    Ok(())
}

/// Scale giving `(1 - w) K*n + w n` unit variance, K = `passes` [1 2 1]
/// smoothings in x and y, n white.
fn luma_norm(passes: u32, w: f32) -> f32 {
    let mut k = vec![1.0f32];
    for _ in 0..passes {
        let mut nk = vec![0f32; k.len() + 2];
        for (i, v) in k.iter().enumerate() {
            nk[i] += 0.25 * v;
            nk[i + 1] += 0.5 * v;
            nk[i + 2] += 0.25 * v;
        }
        k = nk;
    }
    let s2: f32 = k.iter().map(|v| v * v).sum::<f32>().powi(2); // 2D sum of squares
    let centre = k[k.len() / 2].powi(2);
    let a = 1.0 - w;
    let var = a * a * s2 + w * w + 2.0 * a * w * centre;
    1.0 / var.sqrt()
}

/// The camera's linear part: optical blur, then 8x8 block compression with
/// 2x2-subsampled chroma (applied to the background and to each solved
/// contact change, so frames need only the noise per frame).
fn camera_linear(buf: &mut [f32], s: &SensorModelV2) {
    let k = gaussian_kernel(s.blur_px);
    let mut ch = vec![0f32; N];
    for c in 0..3 {
        for (p, v) in ch.iter_mut().enumerate() {
            *v = buf[p * 3 + c];
        }
        blur_separable(&mut ch, &k);
        for (p, v) in ch.iter().enumerate() {
            buf[p * 3 + c] = *v;
        }
    }
    // luma / chroma
    let mut y = vec![0f32; N];
    let mut cr = vec![0f32; N];
    let mut cb = vec![0f32; N];
    for p in 0..N {
        let (r, g, b) = (buf[p * 3], buf[p * 3 + 1], buf[p * 3 + 2]);
        let l = (r + g + b) / 3.0;
        y[p] = l;
        cr[p] = r - l;
        cb[p] = b - l;
    }
    block_plane(&mut y, BLOCK, s.block_q);
    for c in [&mut cr, &mut cb] {
        // 4:2:0: average 2x2
        for by in (0..H).step_by(2) {
            for bx in (0..W).step_by(2) {
                let i = by * W + bx;
                let m = 0.25 * (c[i] + c[i + 1] + c[i + W] + c[i + W + 1]);
                c[i] = m;
                c[i + 1] = m;
                c[i + W] = m;
                c[i + W + 1] = m;
            }
        }
        block_plane(c, 2 * BLOCK, (1.6 * s.block_q).min(0.9));
    }
    for p in 0..N {
        let (l, r_, b_) = (y[p], cr[p], cb[p]);
        buf[p * 3] = l + r_;
        buf[p * 3 + 2] = l + b_;
        buf[p * 3 + 1] = l - r_ - b_;
    }
}

/// In each `b` x `b` block keep the least-squares plane and scale the rest
/// by `1 - q` (compression drops a block's fine detail, keeps its DC and
/// lowest terms, and the blocks do not join smoothly).
fn block_plane(f: &mut [f32], b: usize, q: f32) {
    let keep = 1.0 - q;
    let c = (b as f32 - 1.0) / 2.0;
    let sxx: f32 = (0..b).map(|i| (i as f32 - c).powi(2)).sum::<f32>() * b as f32;
    for by in (0..H).step_by(b) {
        for bx in (0..W).step_by(b) {
            let (ye, xe) = ((by + b).min(H), (bx + b).min(W));
            if ye - by != b || xe - bx != b {
                continue;
            }
            let (mut m, mut gx, mut gy) = (0f32, 0f32, 0f32);
            for y in by..ye {
                for x in bx..xe {
                    let v = f[y * W + x];
                    m += v;
                    gx += v * (x - bx) as f32;
                    gy += v * (y - by) as f32;
                }
            }
            let n = (b * b) as f32;
            m /= n;
            gx = (gx - m * c * n) / sxx;
            gy = (gy - m * c * n) / sxx;
            for y in by..ye {
                for x in bx..xe {
                    let pl = m + gx * ((x - bx) as f32 - c) + gy * ((y - by) as f32 - c);
                    let v = &mut f[y * W + x];
                    *v = pl + keep * (*v - pl);
                }
            }
        }
    }
}

/// Gap between the gel and the cloth (mm), zero at first touch.
fn gap_field_v2(
    raster: &HeightField,
    p: &PressParams,
    extra_mm: [f32; 2],
    sw: &bolt::Swatch,
    placed: &[Placed],
    s: &SensorModelV2,
    relief_keep: f32,
) -> Vec<f32> {
    let (sin, cos) = (p.rotation_deg.to_radians()).sin_cos();
    let c0 = raster.size as f32 / 2.0;
    let ex = extra_mm[0] / MM_PER_PX;
    let ey = extra_mm[1] / MM_PER_PX;
    let tx = p.tilt_deg[0].to_radians().tan();
    let ty = p.tilt_deg[1].to_radians().tan();
    let feat_keep = relief_keep.sqrt();
    let mut gap = vec![0f32; N];
    let mut min = f32::MAX;
    for y in 0..H {
        let yc = y as f32 - (H as f32 - 1.0) / 2.0;
        for x in 0..W {
            let xc = x as f32 - (W as f32 - 1.0) / 2.0;
            // window -> cloth (rotation, slip), cloth -> bolt raster (stretch, shear)
            let u = xc * cos - yc * sin + ex;
            let v = xc * sin + yc * cos + ey;
            let bx = c0 + u * sw.stretch[0] + sw.shear * v;
            let by = c0 + v * sw.stretch[1];
            let hf = raster.sample(bx, by) * sw.relief_scale;
            let feat: f32 = placed.iter().map(|f| f.height(u, v)).sum();
            let nx = xc / (W as f32 / 2.0);
            let ny = yc / (H as f32 / 2.0);
            let dome = s.dome_mm * 0.5 * (nx * nx + ny * ny);
            let plane = tx * xc * MM_PER_PX + ty * yc * MM_PER_PX;
            let g = -(hf * relief_keep + feat * feat_keep) + dome + plane;
            gap[y * W + x] = g;
            min = min.min(g);
        }
    }
    // The gel settles on the load-bearing top of the cloth, not on its
    // single tallest point: isolated tall bits (pills, a stray loop, fibre
    // tips; the tallest 1 % of the window) sink into the gel instead of
    // holding it off the rest.
    let mut v: Vec<f32> = gap.iter().step_by(5).cloned().collect();
    v.sort_by(|a, b| a.total_cmp(b));
    let top = v[v.len() / 100].max(min);
    for g in gap.iter_mut() {
        *g -= top;
    }
    gap
}
