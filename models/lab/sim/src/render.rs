//! The press renderer: fabric window -> gel contact -> calibrated optics.

use crate::calib::{self, Calibration, BINS, HEIGHT as H, WIDTH as W};
use crate::catalogue::{hash_str, mix64, Catalogue, Textile, CATALOGUE_VERSION};
use crate::fabric::{self, HeightField, MM_PER_PX, PATCH};
use crate::sensor2::sensor_model_v2;
use crate::{Press, PressMeta, PressParams, PressSpec, SimError, FPS};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::HashMap;
use std::f32::consts::PI;
use std::sync::{Arc, Mutex};

pub(crate) const N: usize = W * H;
/// Depth fractions (of the full indentation) at which the contact is solved;
/// frames interpolate between these key states.
pub(crate) const KEYS: [f32; 7] = [0.0, 0.12, 0.28, 0.48, 0.72, 1.0, 1.3];
pub(crate) const FULL_KEY: usize = 5;
/// Gaussian width of the gel low-pass per mm of elastomer thickness (mm/mm).
pub const GEL_BLUR_PER_MM: f32 = 0.13;

/// How a simulated person presses.
#[derive(Clone, Debug, PartialEq)]
pub struct PersonStyle {
    /// Typical hand-held force, N.
    pub force_n: f32,
    /// Relative spread of the force between presses.
    pub force_sd: f32,
    /// Rotation habits: (angle in degrees, weight).
    pub rotation_habits: Vec<(f32, f32)>,
    /// Spread around the habit, degrees.
    pub rotation_sd_deg: f32,
    /// Probability of an arbitrary angle.
    pub any_angle: f32,
    /// Hand-held tilt spread per axis, degrees.
    pub tilt_sd_deg: f32,
    /// Hand-held force wobble (relative amplitude).
    pub wobble: f32,
    /// Hand-held slip during the hold, mm (spread).
    pub slip_mm: f32,
    /// Typical first contact frame.
    pub contact_frame: f32,
    /// Typical ramp length, frames.
    pub ramp_frames: f32,
    /// Probability the press releases before the end.
    pub release_prob: f32,
}

/// The consistent style of person `id` (0..11 in the paper protocol).
pub fn person_style(id: u32) -> PersonStyle {
    let mut r = ChaCha8Rng::seed_from_u64(mix64(0x9e50_0000 + id as u64));
    let main = [0.0, 90.0, 180.0, 270.0][r.gen_range(0..4)];
    let second = main + if r.gen_bool(0.5) { 90.0 } else { 180.0 };
    let w_main = r.gen_range(0.5..0.9);
    PersonStyle {
        force_n: r.gen_range(2.5..7.0),
        force_sd: r.gen_range(0.08..0.25),
        rotation_habits: vec![(main, w_main), (second % 360.0, 1.0 - w_main)],
        rotation_sd_deg: r.gen_range(4.0..25.0),
        any_angle: r.gen_range(0.0..0.3),
        tilt_sd_deg: r.gen_range(0.5..2.0),
        wobble: r.gen_range(0.04..0.2),
        slip_mm: r.gen_range(0.1..0.9),
        contact_frame: r.gen_range(8.0..40.0),
        ramp_frames: r.gen_range(8.0..30.0),
        release_prob: r.gen_range(0.0..0.6),
    }
}

/// Variation between physical sensor units.
#[derive(Clone, Debug, PartialEq)]
pub struct SensorModel {
    /// LED / channel gain of the optical response.
    pub led_gain: [f32; 3],
    /// Gain of the background per channel.
    pub bg_gain: [f32; 3],
    /// Offset of the background per channel.
    pub bg_offset: [f32; 3],
    /// Radial vignetting strength (fraction lost at the corners).
    pub vignette: f32,
    /// Shift of the background image, px.
    pub bg_shift: (i32, i32),
    /// Elastomer thickness, mm (sets the gel's low-pass width).
    pub gel_thickness_mm: f32,
    /// Dome height of the gel at the corners, mm.
    pub dome_mm: f32,
    /// Read noise (DN) and shot-noise gain.
    pub read_noise: f32,
    pub shot_gain: f32,
}

/// Sensor unit `id`; 0 is the nominal unit with the real background unchanged.
pub fn sensor_model(id: u32) -> SensorModel {
    if id == 0 {
        return SensorModel {
            led_gain: [1.0; 3],
            bg_gain: [1.0; 3],
            bg_offset: [0.0; 3],
            vignette: 0.0,
            bg_shift: (0, 0),
            gel_thickness_mm: 1.0,
            dome_mm: 0.25,
            read_noise: 1.2,
            shot_gain: 0.02,
        };
    }
    let mut r = ChaCha8Rng::seed_from_u64(mix64(0x5e45_0000 + id as u64));
    let mut g3 = |lo: f32, hi: f32| {
        [
            r.gen_range(lo..hi),
            r.gen_range(lo..hi),
            r.gen_range(lo..hi),
        ]
    };
    let led_gain = g3(0.8, 1.2);
    let bg_gain = g3(0.85, 1.15);
    let bg_offset = g3(-10.0, 10.0);
    SensorModel {
        led_gain,
        bg_gain,
        bg_offset,
        vignette: r.gen_range(0.0..0.25),
        bg_shift: (r.gen_range(-6..=6), r.gen_range(-6..=6)),
        gel_thickness_mm: r.gen_range(0.8..1.4),
        dome_mm: r.gen_range(0.15..0.35),
        read_noise: r.gen_range(0.8..2.0),
        shot_gain: r.gen_range(0.01..0.04),
    }
}

/// Everything a press needs per frame, solved once per press.
pub(crate) struct Setup {
    pub(crate) params: PressParams,
    pub(crate) frames: usize,
    pub(crate) bg: Vec<f32>,
    /// RGB change at each key depth (interleaved, 3 per pixel); key 0 is zero.
    pub(crate) keys: Vec<Vec<f32>>,
    /// Change at full depth after the hold slip (hand-held only).
    pub(crate) slipped: Option<Vec<f32>>,
    /// Depth fraction per frame and slip progress per frame.
    pub(crate) depth: Vec<f32>,
    pub(crate) slip: Vec<f32>,
    pub(crate) noise_seed: u64,
    pub(crate) read_noise: f32,
    pub(crate) shot_gain: f32,
    /// Per-value noise standard deviation (read noise and shot noise).
    pub(crate) noise_sd: Vec<f32>,
    /// Frame rate of the press.
    pub(crate) fps: f32,
    /// The catalogue-2 camera chain (None: catalogue 1's per-pixel noise).
    pub(crate) v2: Option<crate::sensor2::Camera>,
}

/// No-contact footage from [`Simulator::idle_clip`].
pub struct IdleClip {
    setup: Setup,
    /// Capture time of each frame, microseconds from the first.
    pub timestamps_us: Vec<u64>,
}

impl IdleClip {
    /// Number of frames.
    pub fn len(&self) -> usize {
        self.setup.frames
    }
    /// Whether the clip has no frames.
    pub fn is_empty(&self) -> bool {
        self.setup.frames == 0
    }
}

/// The DIGIT press simulator. Cheap to share between threads (`Sync`).
pub struct Simulator {
    catalogue: Catalogue,
    pub(crate) calib: Calibration,
    background: image::RgbImage,
    /// Zero-slope response per pixel (subtracted so flat contact adds nothing).
    pub(crate) flat: Vec<f32>,
    pub(crate) normals: Vec<f32>,
    /// Catalogue version 2.
    pub(crate) catalogue2: Catalogue,
    /// The second real no-contact frame (tvl), a base of the v2 units.
    pub(crate) background_tvl: image::RgbImage,
    /// Catalogue version and generator of specs that leave them unset.
    default_catalogue: u32,
    default_generator: u32,
    patches: Mutex<HashMap<String, Arc<HeightField>>>,
    setups: Mutex<Vec<(String, Arc<Setup>)>>,
}

impl Simulator {
    /// Load the embedded DIGIT calibration and background and the built-in
    /// catalogue.
    pub fn new() -> Result<Simulator, SimError> {
        let calib = Calibration::embedded()?;
        let background = calib::embedded_background()?;
        let mut flat = vec![0f32; N * 3];
        for y in 0..H {
            for x in 0..W {
                let mut acc = [0f32; 3];
                for d in 0..BINS {
                    let v = calib.eval(0, d, x as f32, y as f32);
                    for c in 0..3 {
                        acc[c] += v[c];
                    }
                }
                for c in 0..3 {
                    flat[(y * W + x) * 3 + c] = acc[c] / BINS as f32;
                }
            }
        }
        // a table of standard normal samples for the camera noise
        let mut r = ChaCha8Rng::seed_from_u64(0x0015_e000);
        let normals = (0..8192)
            .map(|_| {
                let u1: f32 = r.gen_range(1e-7..1.0);
                let u2: f32 = r.gen();
                (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
            })
            .collect();
        let background_tvl = crate::sensor2::embedded_background_tvl()?;
        Ok(Simulator {
            catalogue: Catalogue::builtin(),
            calib,
            background,
            flat,
            normals,
            catalogue2: Catalogue::version(2).expect("catalogue 2 is built in"),
            background_tvl,
            default_catalogue: 1,
            default_generator: 1,
            patches: Mutex::new(HashMap::new()),
            setups: Mutex::new(Vec::new()),
        })
    }

    /// A simulator whose specs render catalogue `version` (1 or 2) unless
    /// they name one (`PressSpec::catalogue`).
    pub fn with_catalogue(version: u32) -> Result<Simulator, SimError> {
        Self::with_options(version, 1)
    }

    /// A simulator with a default catalogue version and texture generator
    /// (generator 2, the cross-generator test set, needs catalogue 2).
    pub fn with_options(version: u32, generator: u32) -> Result<Simulator, SimError> {
        check_versions(version, generator)?;
        let mut s = Simulator::new()?;
        s.default_catalogue = version;
        s.default_generator = generator;
        Ok(s)
    }

    /// The default catalogue version of this simulator.
    pub fn catalogue_version(&self) -> u32 {
        self.default_catalogue
    }

    /// The default texture generator of this simulator.
    pub fn generator(&self) -> u32 {
        self.default_generator
    }

    /// The textile catalogue the simulator renders by default.
    pub fn catalogue(&self) -> &Catalogue {
        self.catalogue_of(self.default_catalogue)
    }

    /// Catalogue `version` (1 or 2; anything else gives version 1's).
    pub fn catalogue_of(&self, version: u32) -> &Catalogue {
        if version == 2 {
            &self.catalogue2
        } else {
            &self.catalogue
        }
    }

    /// (catalogue version, generator) a spec renders with.
    pub fn resolve(&self, spec: &PressSpec) -> Result<(u32, u32), SimError> {
        let v = spec.catalogue.unwrap_or(self.default_catalogue);
        let g = spec
            .generator
            .unwrap_or(if v == 2 { self.default_generator } else { 1 });
        check_versions(v, g)?;
        if let Some(f) = spec.fps {
            if v == 1 && f != crate::FPS {
                return Err(SimError::InvalidSpec(format!(
                    "fps {f}: catalogue 1 renders 60 fps only"
                )));
            }
            if !(25.0..=60.0).contains(&f) {
                return Err(SimError::InvalidSpec(format!("fps {f} (25..=60)")));
            }
        }
        Ok((v, g))
    }

    /// The real no-contact frame as embedded (sensor 0's background).
    pub fn real_background(&self) -> &image::RgbImage {
        &self.background
    }

    /// The second real no-contact frame (another DIGIT unit, Max-Fu/tvl,
    /// Apache-2.0), a base of the catalogue-2 sensor units.
    pub fn real_background_tvl(&self) -> &image::RgbImage {
        &self.background_tvl
    }

    /// The no-contact frame of sensor `sensor` (no noise) in the default
    /// catalogue version (its sensor units).
    pub fn background(&self, sensor: u32) -> image::RgbImage {
        self.background_of(self.default_catalogue, sensor)
    }

    /// The no-contact frame (no noise) of the unit and catalogue version a
    /// spec renders with (what to subtract from that spec's frames).
    pub fn background_for(&self, spec: &PressSpec) -> Result<image::RgbImage, SimError> {
        let (version, _) = self.resolve(spec)?;
        Ok(self.background_of(version, spec.sensor))
    }

    /// The no-contact frame of sensor unit `sensor` of catalogue `version`
    /// (version 2: through the unit's camera chain, without noise or drift).
    pub fn background_of(&self, version: u32, sensor: u32) -> image::RgbImage {
        if version == 2 {
            return to_image(&self.background_v2(&sensor_model_v2(sensor)), None);
        }
        let bg = self.background_f32(&sensor_model(sensor));
        to_image(&bg, None)
    }

    fn background_f32(&self, s: &SensorModel) -> Vec<f32> {
        let mut out = vec![0f32; N * 3];
        for y in 0..H {
            for x in 0..W {
                let sx = (x as i32 - s.bg_shift.0).clamp(0, W as i32 - 1) as u32;
                let sy = (y as i32 - s.bg_shift.1).clamp(0, H as i32 - 1) as u32;
                let p = self.background.get_pixel(sx, sy).0;
                let nx = (x as f32 - W as f32 / 2.0) / (W as f32 / 2.0);
                let ny = (y as f32 - H as f32 / 2.0) / (H as f32 / 2.0);
                let vig = 1.0 - s.vignette * 0.5 * (nx * nx + ny * ny);
                for c in 0..3 {
                    out[(y * W + x) * 3 + c] = p[c] as f32 * s.bg_gain[c] * vig + s.bg_offset[c];
                }
            }
        }
        out
    }

    fn textile(&self, id: &str) -> Result<&Textile, SimError> {
        self.catalogue
            .get(id)
            .ok_or_else(|| SimError::UnknownTextile(id.to_string()))
    }

    /// The fabric patch of a textile (cached).
    pub fn patch(&self, textile: &Textile) -> Arc<HeightField> {
        if let Some(p) = self
            .patches
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&textile.id)
        {
            return p.clone();
        }
        let p = Arc::new(fabric::generate(textile));
        let mut cache = self.patches.lock().unwrap_or_else(|e| e.into_inner());
        if cache.len() >= 160 {
            cache.clear();
        }
        cache.insert(textile.id.clone(), p.clone());
        p
    }

    /// Render a whole press (150 frames at 60 fps unless the spec says otherwise).
    pub fn render_press(&self, spec: &PressSpec) -> Result<Press, SimError> {
        let setup = self.setup(spec)?;
        let frames = (0..setup.frames)
            .map(|i| self.frame_from(&setup, i))
            .collect();
        Ok(Press {
            meta: self.meta(spec, &setup),
            frames,
        })
    }

    /// Render one frame of a press (the press is solved once and cached, so
    /// rendering frames one by one is cheap).
    pub fn render_frame(
        &self,
        spec: &PressSpec,
        frame_index: usize,
    ) -> Result<image::RgbImage, SimError> {
        let setup = self.setup(spec)?;
        if frame_index >= setup.frames {
            return Err(SimError::FrameOutOfRange {
                index: frame_index,
                frames: setup.frames,
            });
        }
        Ok(self.frame_from(&setup, frame_index))
    }

    /// Continuous no-contact footage of the sensor unit, camera and frame
    /// rate a press spec describes, `spec.frames` frames long (at most
    /// 100,000): the same background, camera noise, LED flicker and (in
    /// catalogue 2) exposure drift as the press, with nothing touching the
    /// gel. What a sensor shows while it rests; contact detectors are
    /// measured on it for false presses.
    pub fn idle_clip(&self, spec: &PressSpec) -> Result<IdleClip, SimError> {
        let (version, generator) = self.resolve(spec)?;
        let mut setup = if version == 2 {
            self.solve_v2(spec, generator)?
        } else {
            self.solve(spec)?
        };
        setup.depth.iter_mut().for_each(|d| *d = 0.0);
        setup.slip.iter_mut().for_each(|d| *d = 0.0);
        setup.slipped = None;
        setup.keys.iter_mut().skip(2).for_each(Vec::clear);
        let timestamps_us = self.meta(spec, &setup).timestamps_us;
        Ok(IdleClip {
            setup,
            timestamps_us,
        })
    }

    /// Frame `i` of an idle clip.
    pub fn idle_frame(&self, clip: &IdleClip, i: usize) -> Result<image::RgbImage, SimError> {
        if i >= clip.setup.frames {
            return Err(SimError::FrameOutOfRange {
                index: i,
                frames: clip.setup.frames,
            });
        }
        Ok(self.frame_from(&clip.setup, i))
    }

    /// The metadata `render_press` would attach, without rendering frames.
    pub fn press_meta(&self, spec: &PressSpec) -> Result<PressMeta, SimError> {
        let setup = self.setup(spec)?;
        Ok(self.meta(spec, &setup))
    }

    fn meta(&self, spec: &PressSpec, setup: &Setup) -> PressMeta {
        PressMeta {
            textile: spec.textile.clone(),
            person: spec.person,
            sensor: spec.sensor,
            jig: spec.jig,
            fps: setup.fps,
            timestamps_us: if setup.v2.is_none() {
                (0..setup.frames as u64)
                    .map(|i| (i * 1_000_000 + 30) / 60)
                    .collect()
            } else {
                (0..setup.frames)
                    .map(|i| (i as f64 * 1e6 / setup.fps as f64).round() as u64)
                    .collect()
            },
            seed: Some(spec.seed),
            source: "sim".into(),
            // catalogue-2 units are other units than catalogue 1's
            sensor_serial: Some(if setup.v2.is_some() {
                format!("SIM2-{:04}", spec.sensor)
            } else {
                format!("SIM{:04}", spec.sensor)
            }),
            params: Some(setup.params.clone()),
            // Frames before the first contact show the untouched sensor.
            reference_frames: (setup.params.contact_frame > 0)
                .then_some(setup.params.contact_frame),
            sensor_profile: None,
            mm_per_px: None,
        }
    }

    fn setup(&self, spec: &PressSpec) -> Result<Arc<Setup>, SimError> {
        let (version, generator) = self.resolve(spec)?;
        let mut resolved = spec.clone();
        resolved.catalogue = Some(version);
        resolved.generator = Some(generator);
        let key =
            serde_json::to_string(&resolved).map_err(|e| SimError::InvalidSpec(e.to_string()))?;
        {
            let cache = self.setups.lock().unwrap_or_else(|e| e.into_inner());
            if let Some((_, s)) = cache.iter().find(|(k, _)| *k == key) {
                return Ok(s.clone());
            }
        }
        let s = Arc::new(if version == 2 {
            self.solve_v2(spec, generator)?
        } else {
            self.solve(spec)?
        });
        let mut cache = self.setups.lock().unwrap_or_else(|e| e.into_inner());
        if cache.len() >= 4 {
            cache.remove(0);
        }
        cache.push((key, s.clone()));
        Ok(s)
    }

    fn solve(&self, spec: &PressSpec) -> Result<Setup, SimError> {
        let textile = self.textile(&spec.textile)?;
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
        let person = person_style(spec.person);
        let sensor = sensor_model(spec.sensor);
        let mut rng = ChaCha8Rng::seed_from_u64(mix64(
            spec.seed
                ^ hash_str(&spec.textile)
                ^ mix64(spec.person as u64 * 1_000_003 + spec.sensor as u64)
                ^ spec.jig as u64,
        ));
        let gauss = |r: &mut ChaCha8Rng| {
            let u1: f32 = r.gen_range(1e-7..1.0);
            let u2: f32 = r.gen();
            (-2.0 * u1.ln()).sqrt() * (2.0 * PI * u2).cos()
        };
        // --- draw the press parameters ------------------------------------
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
        let max_off = 40.0 * MM_PER_PX;
        let drawn_off = [
            rng.gen_range(-max_off..max_off),
            rng.gen_range(-max_off..max_off),
        ];
        let offset_mm = spec.offset_mm.unwrap_or(drawn_off);
        let offset_mm = [
            offset_mm[0].clamp(-max_off, max_off),
            offset_mm[1].clamp(-max_off, max_off),
        ];
        let tilt_sd = if spec.jig { 0.12 } else { person.tilt_sd_deg };
        let drawn_tilt = [tilt_sd * gauss(&mut rng), tilt_sd * gauss(&mut rng)];
        let tilt_deg = spec.tilt_deg.unwrap_or(drawn_tilt);
        let (wobble, slip_mm) = if spec.jig {
            (0.01, [0.0, 0.0])
        } else {
            let s = person.slip_mm;
            (person.wobble, [s * gauss(&mut rng), s * gauss(&mut rng)])
        };
        let slip_mm = [slip_mm[0].clamp(-1.0, 1.0), slip_mm[1].clamp(-1.0, 1.0)];
        let frames = spec.frames;
        let scale_t = frames as f32 / crate::PRESS_FRAMES as f32;
        let (contact, ramp) = if spec.jig {
            (20.0 + 3.0 * gauss(&mut rng), 15.0 + 2.0 * gauss(&mut rng))
        } else {
            (
                person.contact_frame * (1.0 + 0.2 * gauss(&mut rng)),
                person.ramp_frames * (1.0 + 0.2 * gauss(&mut rng)),
            )
        };
        let contact_frame = (contact * scale_t).clamp(0.0, frames as f32 * 0.4).round() as u32;
        let hold_frame = (contact_frame as f32 + (ramp * scale_t).max(1.0)).round() as u32;
        let releases = spec
            .release
            .unwrap_or(!spec.jig && rng.gen::<f32>() < person.release_prob);
        let release_frame = if releases {
            Some(
                ((frames as f32) * rng.gen_range(0.8..0.9))
                    .round()
                    .max(hold_frame as f32 + 1.0) as u32,
            )
        } else {
            None
        };
        // indentation: Hertz-like force law, softer fabric lets the gel in further
        let compliance = textile.compliance;
        let indentation_mm = 0.12 * force_n.powf(0.67) * (1.0 + 0.3 * compliance);
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
            catalogue_version: CATALOGUE_VERSION,
            generator: 1,
            swatch: None,
            features: Vec::new(),
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
        for i in 0..frames {
            let f = i as f32;
            let (c, h) = (contact_frame as f32, hold_frame as f32);
            let mut u = if f < c {
                0.0
            } else if f < h {
                smooth((f - c + 1.0) / (h - c + 1.0))
            } else {
                jitter = 0.85 * jitter + gauss(&mut rng) * if spec.jig { 0.003 } else { 0.02 };
                1.0 + wobble * (2.0 * PI * hz * (f - h) / FPS + phase).sin() + jitter
            };
            if let Some(r) = release_frame {
                let r = r as f32;
                if f >= r {
                    u *= 1.0 - smooth((f - r + 1.0) / 12.0);
                }
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
        let patch = self.patch(textile);
        let relief_keep = 1.0 - 0.6 * compliance;
        let gap_a = self.gap_field(&patch, &params, [0.0, 0.0], &sensor, relief_keep);
        let sigma_px = sensor.gel_thickness_mm * GEL_BLUR_PER_MM / MM_PER_PX;
        let kernel = gaussian_kernel(sigma_px);
        let mut keys = vec![Vec::new()];
        for &k in &KEYS[1..] {
            keys.push(self.shade(&gap_a, k * indentation_mm, &kernel, &sensor));
        }
        let slipped = if slip_mm != [0.0, 0.0] {
            let gap_b = self.gap_field(&patch, &params, slip_mm, &sensor, relief_keep);
            Some(self.shade(&gap_b, indentation_mm, &kernel, &sensor))
        } else {
            None
        };
        let bg = self.background_f32(&sensor);
        let (rn, shot) = if spec.noise {
            (sensor.read_noise, sensor.shot_gain)
        } else {
            (0.0, 0.0)
        };
        let noise_sd = bg
            .iter()
            .map(|g| (rn * rn + shot * g.max(0.0)).sqrt())
            .collect();
        Ok(Setup {
            params,
            frames,
            bg,
            noise_sd,
            keys,
            slipped,
            depth,
            slip,
            noise_seed: mix64(spec.seed ^ 0xA5A5_5A5A ^ hash_str(&spec.textile)),
            read_noise: if spec.noise { sensor.read_noise } else { 0.0 },
            shot_gain: if spec.noise { sensor.shot_gain } else { 0.0 },
            fps: FPS,
            v2: None,
        })
    }

    /// Gap between gel and fabric (mm) before indentation, zero at first touch.
    fn gap_field(
        &self,
        patch: &HeightField,
        p: &PressParams,
        extra_mm: [f32; 2],
        s: &SensorModel,
        relief_keep: f32,
    ) -> Vec<f32> {
        let (sin, cos) = (p.rotation_deg.to_radians()).sin_cos();
        let c0 = PATCH as f32 / 2.0;
        let ox = (p.offset_mm[0] + extra_mm[0]) / MM_PER_PX;
        let oy = (p.offset_mm[1] + extra_mm[1]) / MM_PER_PX;
        let tx = p.tilt_deg[0].to_radians().tan();
        let ty = p.tilt_deg[1].to_radians().tan();
        let mut gap = vec![0f32; N];
        let mut min = f32::MAX;
        for y in 0..H {
            let yc = y as f32 - (H as f32 - 1.0) / 2.0;
            for x in 0..W {
                let xc = x as f32 - (W as f32 - 1.0) / 2.0;
                let px = c0 + ox + xc * cos - yc * sin;
                let py = c0 + oy + xc * sin + yc * cos;
                let hf = patch.sample(px, py); // <= 0
                let nx = xc / (W as f32 / 2.0);
                let ny = yc / (H as f32 / 2.0);
                let dome = s.dome_mm * 0.5 * (nx * nx + ny * ny);
                let plane = tx * xc * MM_PER_PX + ty * yc * MM_PER_PX;
                let g = -hf * relief_keep + dome + plane;
                gap[y * W + x] = g;
                min = min.min(g);
            }
        }
        for g in gap.iter_mut() {
            *g -= min;
        }
        gap
    }

    /// Indent by `d` mm, low-pass through the gel, shade through the calibration.
    fn shade(&self, gap: &[f32], d: f32, kernel: &[f32], s: &SensorModel) -> Vec<f32> {
        let mut pen: Vec<f32> = gap.iter().map(|g| (d - g).max(0.0)).collect();
        blur_separable(&mut pen, kernel);
        let mut out = vec![0f32; N * 3];
        let inv2 = 1.0 / (2.0 * MM_PER_PX);
        let mag_step = (PI / 2.0) / (BINS as f32 - 1.0);
        let dir_step = (2.0 * PI) / (BINS as f32 - 1.0);
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
                let db = (((gy.atan2(gx) + PI) / dir_step) as usize).min(BINS - 1);
                let v = self.calib.eval(mb, db, x as f32, y as f32);
                for c in 0..3 {
                    out[i * 3 + c] = s.led_gain[c] * (v[c] - self.flat[i * 3 + c]);
                }
            }
        }
        out
    }

    fn frame_from(&self, s: &Setup, i: usize) -> image::RgbImage {
        if let Some(cam) = &s.v2 {
            return self.frame_v2(s, cam, i);
        }
        let u = s.depth[i];
        // find the key segment
        let mut k = 1;
        while k < KEYS.len() - 1 && KEYS[k] < u {
            k += 1;
        }
        let (k0, k1) = (k - 1, k);
        let t = ((u - KEYS[k0]) / (KEYS[k1] - KEYS[k0])).clamp(0.0, 1.0);
        let slip_w = s.slip[i] * u.min(1.0);
        let zero = &s.keys[1][..0];
        let (a, b) = if u > 0.0 {
            (&s.keys[k0][..], &s.keys[k1][..])
        } else {
            (zero, zero)
        };
        let (sl, full) = match (&s.slipped, u > 0.0 && slip_w > 0.0) {
            (Some(sl), true) => (&sl[..], &s.keys[FULL_KEY][..]),
            _ => (zero, zero),
        };
        let noise = s.read_noise > 0.0 || s.shot_gain > 0.0;
        let nseed = mix64(s.noise_seed ^ (i as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15));
        let flicker = if noise {
            1.0 + 0.002 * self.normals[(nseed >> 51) as usize]
        } else {
            1.0
        };
        let normals = &self.normals[..8192];
        let mut raw = vec![0u8; N * 3];
        // base: background plus the interpolated contact change
        let mut v: Vec<f32> = match (a.is_empty(), b.is_empty()) {
            (_, true) => s.bg.clone(),
            (true, false) => s.bg.iter().zip(b).map(|(g, bv)| g + t * bv).collect(),
            (false, false) => {
                s.bg.iter()
                    .zip(a.iter().zip(b))
                    .map(|(g, (av, bv))| g + av + t * (bv - av))
                    .collect()
            }
        };
        if !sl.is_empty() {
            for (o, (sv, fv)) in v.iter_mut().zip(sl.iter().zip(full)) {
                *o += slip_w * (sv - fv);
            }
        }
        if noise {
            // shot + read noise; its level follows the background brightness
            for (j, ((out, x), sd)) in raw.iter_mut().zip(&v).zip(&s.noise_sd).enumerate() {
                let h = (nseed ^ j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
                let z = normals[(h >> 51) as usize];
                *out = (x * flicker + sd * z + 0.5).clamp(0.0, 255.0) as u8;
            }
        } else {
            for (out, x) in raw.iter_mut().zip(&v) {
                *out = (x + 0.5).clamp(0.0, 255.0) as u8;
            }
        }
        image::RgbImage::from_raw(W as u32, H as u32, raw)
            .unwrap_or_else(|| image::RgbImage::new(W as u32, H as u32))
    }
}

pub(crate) fn smooth(t: f32) -> f32 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

pub(crate) fn to_image(buf: &[f32], _unused: Option<()>) -> image::RgbImage {
    let raw: Vec<u8> = buf
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    image::RgbImage::from_raw(W as u32, H as u32, raw)
        .unwrap_or_else(|| image::RgbImage::new(W as u32, H as u32))
}

pub(crate) fn gaussian_kernel(sigma: f32) -> Vec<f32> {
    let r = (3.0 * sigma).ceil().max(1.0) as i32;
    let mut k: Vec<f32> = (-r..=r)
        .map(|i| (-(i * i) as f32 / (2.0 * sigma * sigma)).exp())
        .collect();
    let s: f32 = k.iter().sum();
    for v in k.iter_mut() {
        *v /= s;
    }
    k
}

/// Separable Gaussian blur of a W x H field with clamped edges.
pub(crate) fn blur_separable(f: &mut [f32], k: &[f32]) {
    let r = (k.len() / 2) as i32;
    let mut tmp = vec![0f32; f.len()];
    for y in 0..H {
        let row = &f[y * W..(y + 1) * W];
        for x in 0..W {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let xx = (x as i32 + j as i32 - r).clamp(0, W as i32 - 1) as usize;
                s += kv * row[xx];
            }
            tmp[y * W + x] = s;
        }
    }
    for y in 0..H {
        for x in 0..W {
            let mut s = 0.0;
            for (j, kv) in k.iter().enumerate() {
                let yy = (y as i32 + j as i32 - r).clamp(0, H as i32 - 1) as usize;
                s += kv * tmp[yy * W + x];
            }
            f[y * W + x] = s;
        }
    }
}

fn check_versions(version: u32, generator: u32) -> Result<(), SimError> {
    if !crate::CATALOGUE_VERSIONS.contains(&version) {
        return Err(SimError::InvalidSpec(format!(
            "catalogue version {version} (known: 1, 2)"
        )));
    }
    if !crate::GENERATORS.contains(&generator) || (generator != 1 && version != 2) {
        return Err(SimError::InvalidSpec(format!(
            "generator {generator} (1, or 2 with catalogue 2)"
        )));
    }
    Ok(())
}
