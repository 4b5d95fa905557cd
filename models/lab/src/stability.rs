//! Where methods fail: accuracy and decision flip-rate of every method as
//! one condition of the press moves away from the index's, on simulated
//! presses rendered for the purpose (issue "Speed vs accuracy chart and the
//! stability suite", part 3); and accuracy against time since first
//! contact across people (part 1, "accuracy vs frames aggregated").
//!
//! **Stability protocol.** The index holds two reference presses of every
//! training textile by person 0 on sensor 0 with the jig, at 0° and 4 N
//! (6 frames each, spread over the hold). A query is a fresh press (other
//! seed, so another window of the cloth) under the same conditions with
//! one factor changed; `frames` consecutive frames of its hold (60 fps) are
//! embedded. Per level: top-1 of the press (mean of its frame embeddings),
//! top-1 per frame, and the flip rate (the share of consecutive frame pairs
//! whose nearest textile differs: what a decider has to smooth over).
//!
//! Factors: in-plane rotation (15° steps over 360°), force, tilt (jig),
//! hand-held presses (people 0..5, no jig), LED intensity drift (every
//! channel of the frame scaled: the LEDs light both the gel and the
//! background), sensor swap (queries on other units, index from sensor 0;
//! and again with the index pooled over units 0..=3),
//! extra camera noise, a stale background (the sensor's no-contact image
//! shifted since the reference was taken; background-subtracting methods
//! keep subtracting the old reference) and unseen textiles (scored by the
//! ground-truth attribute rank of the decided textile).
//!
//! Asked for by name, not in [`Factor::ALL`]: where on the cloth the
//! query presses, against the spot and the swatch (region of the bolt,
//! catalogue 2) of the textile's first index press. `spot`: the same
//! swatch, the index press's spot moved by the level in mm along both
//! axes (0: the very spot, pressed again). `swatch` (catalogue 2 only):
//! a random spot on the index press's swatch (0) or on a swatch neither
//! index press saw (1). Together they say how much of what a method
//! misses is the cloth itself (another spot, another region with its own
//! stretch, shear, relief and wear) rather than the press.
//!
//! Also asked for by name: how many index presses per textile a fabric
//! needs (`coverage`, jig queries; `coverage-hand`, hand-held queries by a
//! person no model was trained on). The level is the number of index
//! presses per textile (1 to 16, each at a random spot and swatch; the
//! suite's two are the first two); the same query presses (three per
//! textile) are decided at every level against the nearest index frame,
//! the nearest textile centroid (`index build --sim`) and the nearest of
//! centroid and press means (`index build --presses`).

use anyhow::{anyhow, Context, Result};
use image::RgbImage;
use serde::Serialize;
use telextiles_sim::{PressSpec, Simulator};

use crate::data::{FrameMeta, ImageKind, ImageSet};
use crate::knn::{normalize_rows, top_k};
use crate::methods::{background_of, mean_rows, Embedder, Method};
use crate::preprocess::centre_crop_resize;
use crate::protocol::{spread, view_set, BASE_SIDE};

/// A condition varied by the suite.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
pub enum Factor {
    /// In-plane rotation of the fabric, degrees.
    Rotation,
    /// Press force, N (the index's presses: 4 N).
    Force,
    /// Jig tilt about the sensor's x axis, degrees.
    Tilt,
    /// Hand-held presses (no jig); the level is the person.
    HandHeld,
    /// LED intensity: every channel of the frame times this gain.
    LedDrift,
    /// Sensor unit of the queries (the index is from sensor 0).
    SensorSwap,
    /// Sensor unit of the queries, the index pooled over units 0..=3 (as
    /// a manufacturer would build it with several sensors).
    SensorPool,
    /// Extra Gaussian camera noise, DN (standard deviation).
    Noise,
    /// Shift of the no-contact background since the reference, px.
    StaleBackground,
    /// The 20 unseen textiles (no right answer: attribute rank).
    Unseen,
    /// Distance (mm, along both axes) of the query's spot from the first
    /// index press's, on its swatch.
    Spot,
    /// 0: a random spot on the first index press's swatch; 1: on a swatch
    /// neither index press saw (catalogue 2).
    Swatch,
    /// Index presses per textile (the level; the suite's index is the first
    /// two of them), each at a fresh random spot and swatch; the queries
    /// are the nominal jig presses.
    Coverage,
    /// The same indexes; the queries are hand-held presses by person
    /// [`COVERAGE_HAND_PERSON`], whom no trained model saw.
    CoverageHand,
}

/// The hand-held person of [`Factor::CoverageHand`]: the protocol's first
/// held-out person.
pub const COVERAGE_HAND_PERSON: u32 = 8;

impl Factor {
    /// The default suite, in table order ([`Factor::Spot`] and
    /// [`Factor::Swatch`] are asked for by name).
    pub const ALL: [Factor; 10] = [
        Factor::Rotation,
        Factor::Force,
        Factor::Tilt,
        Factor::HandHeld,
        Factor::LedDrift,
        Factor::SensorSwap,
        Factor::SensorPool,
        Factor::Noise,
        Factor::StaleBackground,
        Factor::Unseen,
    ];

    /// From its command-line name (rotation, force, tilt, handheld, led,
    /// sensor, noise, stale, unseen).
    pub fn parse(s: &str) -> Result<Factor> {
        Ok(match s {
            "rotation" => Factor::Rotation,
            "force" => Factor::Force,
            "tilt" => Factor::Tilt,
            "handheld" => Factor::HandHeld,
            "led" => Factor::LedDrift,
            "sensor" => Factor::SensorSwap,
            "sensors" => Factor::SensorPool,
            "noise" => Factor::Noise,
            "stale" => Factor::StaleBackground,
            "unseen" => Factor::Unseen,
            "spot" => Factor::Spot,
            "swatch" => Factor::Swatch,
            "coverage" => Factor::Coverage,
            "coverage-hand" => Factor::CoverageHand,
            _ => anyhow::bail!(
                "unknown factor {s:?} (rotation, force, tilt, handheld, led, sensor, sensors, noise, stale, unseen, spot, swatch, coverage, coverage-hand)"
            ),
        })
    }

    /// Axis label.
    pub fn label(&self) -> &'static str {
        match self {
            Factor::Rotation => "in-plane rotation (°)",
            Factor::Force => "force (N; index at 4 N)",
            Factor::Tilt => "tilt (°, jig)",
            Factor::HandHeld => "hand-held, person",
            Factor::LedDrift => "LED intensity (gain)",
            Factor::SensorSwap => "query sensor unit (index: 0)",
            Factor::SensorPool => "query sensor unit (index: units 0-3)",
            Factor::Noise => "extra camera noise (DN, σ)",
            Factor::StaleBackground => "background shift since reference (px)",
            Factor::Unseen => "unseen textiles",
            Factor::Spot => "spot moved on the index press's swatch (mm, both axes)",
            Factor::Swatch => "swatch (0: the index press's, 1: another)",
            Factor::Coverage => "index presses per textile (jig queries)",
            Factor::CoverageHand => "index presses per textile (hand-held queries)",
        }
    }

    /// The level at which the queries match the index's conditions.
    pub fn nominal(&self) -> f64 {
        match self {
            Factor::Force => 4.0,
            Factor::LedDrift => 1.0,
            Factor::Coverage | Factor::CoverageHand => INDEX_PRESSES as f64,
            _ => 0.0,
        }
    }

    /// Whether the level is the index's size rather than a condition of
    /// the queries.
    pub fn is_coverage(&self) -> bool {
        matches!(self, Factor::Coverage | Factor::CoverageHand)
    }

    /// Levels of the full suite, or of the quick one (CI).
    pub fn levels(&self, quick: bool) -> Vec<f64> {
        let v: Vec<f64> = match (self, quick) {
            (Factor::Rotation, false) => (0..24).map(|k| 15.0 * k as f64).collect(),
            (Factor::Rotation, true) => vec![0.0, 90.0],
            (Factor::Force, false) => vec![1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0],
            (Factor::Force, true) => vec![2.0, 4.0],
            (Factor::Tilt, false) => vec![0.0, 0.5, 1.0, 1.5, 2.0, 3.0],
            (Factor::Tilt, true) => vec![0.0, 2.0],
            (Factor::HandHeld, false) => (0..6).map(f64::from).collect(),
            (Factor::HandHeld, true) => vec![0.0],
            (Factor::LedDrift, false) => vec![0.6, 0.7, 0.8, 0.9, 1.0, 1.1, 1.2, 1.3, 1.4],
            (Factor::LedDrift, true) => vec![0.7, 1.0],
            (Factor::SensorSwap | Factor::SensorPool, false) => (0..8).map(f64::from).collect(),
            (Factor::SensorSwap | Factor::SensorPool, true) => vec![0.0, 4.0],
            (Factor::Noise, false) => vec![0.0, 2.0, 4.0, 8.0, 12.0, 16.0, 24.0],
            (Factor::Noise, true) => vec![0.0, 8.0],
            (Factor::StaleBackground, false) => vec![0.0, 1.0, 2.0, 3.0, 4.0, 6.0, 8.0],
            (Factor::StaleBackground, true) => vec![0.0, 4.0],
            (Factor::Unseen, _) => vec![0.0],
            (Factor::Spot, false) => vec![0.0, 1.0, 2.0, 4.0, 8.0],
            (Factor::Spot, true) => vec![0.0, 8.0],
            (Factor::Swatch, _) => vec![0.0, 1.0],
            (Factor::Coverage | Factor::CoverageHand, false) => vec![1.0, 2.0, 4.0, 8.0, 16.0],
            (Factor::Coverage | Factor::CoverageHand, true) => vec![1.0, 2.0, 4.0],
        };
        v
    }
}

/// Suite settings.
#[derive(Clone, Debug, Serialize)]
pub struct SuiteConfig {
    /// Only the first N training textiles (all 119 by default).
    pub textiles: Option<usize>,
    /// Consecutive hold frames per query press.
    pub frames: usize,
    /// Render threads.
    pub threads: usize,
    /// Two levels per factor (CI).
    pub quick: bool,
    /// Factors to run.
    pub factors: Vec<Factor>,
    /// The index also holds its frames with the cloth stretched by
    /// `(1 ± a, 1)`, `(1, 1 ± a)`, `(1 ± a, 1 ± a)` and `(1 ± a, 1 ∓ a)`
    /// ([`stretched`]): what a swatch's own few-percent stretch does to a
    /// press. 0: the index as rendered. (The pooled index of
    /// [`Factor::SensorPool`] is not stretched.)
    #[serde(default)]
    pub index_stretch: f32,
}

impl Default for SuiteConfig {
    fn default() -> Self {
        SuiteConfig {
            textiles: None,
            frames: 8,
            threads: 2,
            quick: false,
            factors: Factor::ALL.to_vec(),
            index_stretch: 0.0,
        }
    }
}

/// What is done to a rendered frame before it is embedded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Post {
    /// Nothing.
    None,
    /// Every channel times this gain (LED drift).
    Gain(f32),
    /// Extra Gaussian noise of this standard deviation (DN).
    Noise(f32),
    /// The background moved by this many px (right and down) since the
    /// reference was taken.
    Shift(i32),
}

/// One press to render: spec, class, which frames, what to do to them.
#[derive(Clone, Debug)]
pub struct Plan {
    pub spec: PressSpec,
    pub class: u32,
    /// `Some(n)`: n consecutive frames from hold + 4; `None`: `index_frames`
    /// spread over the hold.
    pub consecutive: Option<usize>,
    /// Consecutive frames from the first contact instead of the hold.
    pub from_contact: bool,
    pub post: Post,
}

fn hash64(parts: &[u64]) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for p in parts {
        for b in p.to_le_bytes() {
            h ^= b as u64;
            h = h.wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

/// A standard normal sample from a hash (Box–Muller on two uniforms).
fn normal(h: u64) -> f32 {
    let u1 = ((h >> 11) as f64 + 1.0) / (1u64 << 53) as f64;
    let h2 = hash64(&[h, 0x9e37]);
    let u2 = (h2 >> 11) as f64 / (1u64 << 53) as f64;
    ((-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()) as f32
}

/// Applies `post` to a full 240x320 frame of sensor `sensor`.
pub fn apply_post(sim: &Simulator, frame: &mut RgbImage, post: Post, sensor: u32, seed: u64) {
    match post {
        Post::None => {}
        Post::Gain(g) => {
            for v in frame.iter_mut() {
                *v = (*v as f32 * g).round().clamp(0.0, 255.0) as u8;
            }
        }
        Post::Noise(sd) => {
            for (i, v) in frame.iter_mut().enumerate() {
                let n = normal(hash64(&[seed, i as u64]));
                *v = (*v as f32 + sd * n).round().clamp(0.0, 255.0) as u8;
            }
        }
        Post::Shift(d) => {
            let bg = sim.background(sensor);
            let (w, h) = bg.dimensions();
            let mut out = frame.clone();
            for y in 0..h {
                for x in 0..w {
                    let sx = (x as i32 - d).clamp(0, w as i32 - 1) as u32;
                    let sy = (y as i32 - d).clamp(0, h as i32 - 1) as u32;
                    let (old, new) = (bg.get_pixel(x, y).0, bg.get_pixel(sx, sy).0);
                    let f = frame.get_pixel(x, y).0;
                    let mut p = [0u8; 3];
                    for c in 0..3 {
                        p[c] = (f[c] as i32 - old[c] as i32 + new[c] as i32).clamp(0, 255) as u8;
                    }
                    out.put_pixel(x, y, image::Rgb(p));
                }
            }
            *frame = out;
        }
    }
}

/// Renders the planned presses into a [`BASE_SIDE`] set (frames in capture
/// order within each press; `FrameMeta::press` numbers the plans).
pub fn render(
    sim: &Simulator,
    classes: &[String],
    plans: &[Plan],
    index_frames: usize,
    threads: usize,
) -> Result<ImageSet> {
    let threads = threads.max(1);
    type Part = Vec<(usize, Vec<FrameMeta>, Vec<u8>)>;
    let parts: Vec<Result<Part>> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..threads)
            .map(|t| {
                s.spawn(move || -> Result<Part> {
                    let mut out = Vec::new();
                    for (pi, p) in plans.iter().enumerate().skip(t).step_by(threads) {
                        let meta = sim
                            .press_meta(&p.spec)
                            .map_err(|e| anyhow!("simulator: {e}"))?;
                        let params = meta.params.context("simulated press without params")?;
                        let n = meta.timestamps_us.len();
                        let end = params.release_frame.map_or(n, |r| r as usize).min(n);
                        let hold = params.hold_frame as usize;
                        let frames: Vec<usize> = match (p.consecutive, p.from_contact) {
                            (Some(k), true) => {
                                let c = params.contact_frame as usize;
                                (c..(c + k).min(end)).collect()
                            }
                            (Some(k), false) => {
                                let start = (hold + 4).min(end.saturating_sub(k));
                                (start..(start + k).min(end)).collect()
                            }
                            (None, _) => spread(hold, end, index_frames),
                        };
                        let (mut metas, mut px) = (Vec::new(), Vec::new());
                        for &f in &frames {
                            let mut img = sim
                                .render_frame(&p.spec, f)
                                .map_err(|e| anyhow!("simulator: {e}"))?;
                            let seed = hash64(&[p.spec.seed, pi as u64, f as u64, p.class as u64]);
                            apply_post(sim, &mut img, p.post, p.spec.sensor, seed);
                            px.extend_from_slice(
                                centre_crop_resize(&img, BASE_SIDE, BASE_SIDE)?.as_raw(),
                            );
                            metas.push(FrameMeta {
                                class: p.class,
                                press: pi as u32,
                                person: p.spec.person,
                                sensor: p.spec.sensor,
                                jig: p.spec.jig,
                                frame: f as u32,
                            });
                        }
                        out.push((pi, metas, px));
                    }
                    Ok(out)
                })
            })
            .collect();
        hs.into_iter()
            .map(|h| h.join().expect("render thread panicked"))
            .collect()
    });
    let mut all = Vec::new();
    for p in parts {
        all.extend(p?);
    }
    all.sort_by_key(|x| x.0);
    let mut set = ImageSet {
        kind: ImageKind::Input,
        side: BASE_SIDE as usize,
        crop: BASE_SIDE,
        classes: classes.to_vec(),
        items: Vec::new(),
        pixels: Vec::new(),
        source: format!("telextiles-sim catalogue v{}", sim.catalogue().version),
    };
    for (_, m, p) in all {
        set.items.extend(m);
        set.pixels.extend(p);
    }
    Ok(set)
}

/// The eight `(x, y)` stretches of [`SuiteConfig::index_stretch`] `a`:
/// each axis alone, both alike and both opposed, by `1 ± a`.
pub fn stretches(a: f32) -> Vec<(f32, f32)> {
    let (lo, hi) = (1.0 - a, 1.0 + a);
    vec![
        (lo, 1.0),
        (hi, 1.0),
        (1.0, lo),
        (1.0, hi),
        (lo, lo),
        (hi, hi),
        (lo, hi),
        (hi, lo),
    ]
}

/// `set` with each image's difference from its sensor's reference (in
/// `refs`) stretched by `sx`, `sy` about the image's centre (bilinear; the
/// edge repeated where the source falls outside) and the reference added
/// back: the same presses on cloth stretched as a swatch of the bolt
/// stretches it (`sx` > 1: the cloth's features lie farther apart).
pub fn stretched(set: &ImageSet, refs: &ImageSet, sx: f32, sy: f32) -> Result<ImageSet> {
    anyhow::ensure!(
        sx > 0.0 && sy > 0.0 && sx.is_finite() && sy.is_finite(),
        "stretch must be positive and finite"
    );
    anyhow::ensure!(refs.side == set.side, "references of another size");
    let n = set.side;
    let c = (n as f32 - 1.0) / 2.0;
    let mut out = ImageSet {
        pixels: Vec::with_capacity(set.pixels.len()),
        ..set.clone_meta()
    };
    // Source coordinate and weights of each output column / row.
    let axis = |s: f32| -> Vec<(usize, usize, f32)> {
        (0..n)
            .map(|x| {
                let u = (c + (x as f32 - c) / s).clamp(0.0, (n - 1) as f32);
                let i = u.floor() as usize;
                (i, (i + 1).min(n - 1), u - i as f32)
            })
            .collect()
    };
    let (ax, ay) = (axis(sx), axis(sy));
    for (i, m) in set.items.iter().enumerate() {
        let img = set.image(i);
        let bg = background_of(refs, m.sensor)
            .with_context(|| format!("no reference of sensor {}", m.sensor))?;
        let d = |x: usize, y: usize, ch: usize| {
            let k = (y * n + x) * 3 + ch;
            img[k] as f32 - bg[k] as f32
        };
        for (y, &(y0, y1, fy)) in ay.iter().enumerate() {
            for (x, &(x0, x1, fx)) in ax.iter().enumerate() {
                for ch in 0..3 {
                    let top = d(x0, y0, ch) * (1.0 - fx) + d(x1, y0, ch) * fx;
                    let bot = d(x0, y1, ch) * (1.0 - fx) + d(x1, y1, ch) * fx;
                    let v = bg[(y * n + x) * 3 + ch] as f32 + top * (1.0 - fy) + bot * fy;
                    out.pixels.push(v.round().clamp(0.0, 255.0) as u8);
                }
            }
        }
    }
    Ok(out)
}

/// No-contact references of the given sensors as a [`BASE_SIDE`] set.
pub fn references(sim: &Simulator, sensors: &[u32]) -> Result<ImageSet> {
    let mut set = ImageSet {
        kind: ImageKind::Input,
        side: BASE_SIDE as usize,
        crop: BASE_SIDE,
        classes: vec![],
        items: vec![],
        pixels: vec![],
        source: "references".into(),
    };
    for &s in sensors {
        set.pixels.extend_from_slice(
            centre_crop_resize(&sim.background(s), BASE_SIDE, BASE_SIDE)?.as_raw(),
        );
        set.items.push(FrameMeta {
            class: 0,
            press: 0,
            person: 0,
            sensor: s,
            jig: true,
            frame: 0,
        });
    }
    Ok(set)
}

/// Scores of one method at one level.
#[derive(Clone, Debug, Serialize)]
pub struct LevelScore {
    pub value: f64,
    /// Top-1 of the mean embedding of each press (unseen: share of presses
    /// whose decision is among the 10 textiles closest by attributes).
    pub press_top1: f64,
    /// Top-1 per frame (unseen: the same share per frame).
    pub frame_top1: f64,
    /// Share of consecutive frame pairs whose nearest textile differs.
    pub flip_rate: f64,
    /// Unseen only: median attribute rank (1 = the closest known textile) of
    /// the press decisions.
    pub attr_rank_median: Option<f64>,
    /// The coverage factors only: top-1 of the same press means against
    /// each textile's centroid (the normalised mean of its index frames,
    /// as `index build` keeps it) instead of the nearest index frame.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub press_top1_centroid: Option<f64>,
    /// The coverage factors only: against each textile's centroid and its
    /// presses' means (the index `index build --presses` keeps; a textile's
    /// distance is the nearest of them).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub press_top1_exemplars: Option<f64>,
    pub presses: usize,
}

/// One method's curve for one factor.
#[derive(Clone, Debug, Serialize)]
pub struct FactorCurve {
    pub factor: Factor,
    pub levels: Vec<LevelScore>,
}

/// One method's suite results.
#[derive(Clone, Debug, Serialize)]
pub struct MethodStability {
    pub name: String,
    pub curves: Vec<FactorCurve>,
}

/// The whole suite.
#[derive(Clone, Debug, Serialize)]
pub struct StabilityReport {
    pub config: SuiteConfig,
    pub textiles: usize,
    pub methods: Vec<MethodStability>,
    /// Seconds spent rendering and embedding.
    pub render_s: f64,
    pub embed_s: f64,
}

fn base_spec(textile: &str, seed: u64) -> PressSpec {
    PressSpec {
        rotation_deg: Some(0.0),
        force: Some(4.0),
        ..PressSpec::new(textile, seed)
    }
}

/// The first seed from `from` whose press of `base` (its seed replaced)
/// sees one of `swatches` (`same` true) or none of them (`same` false).
fn seed_on_swatch(base: &PressSpec, from: u64, swatches: &[u32], same: bool) -> Result<u64> {
    (from..from + 10_000)
        .find(|&seed| {
            let k = telextiles_sim::swatch_of(&PressSpec {
                seed,
                ..base.clone()
            });
            swatches.contains(&k) == same
        })
        .with_context(|| format!("{}: no seed found for swatch {swatches:?}", base.textile))
}

/// The query spec of [`Factor::Spot`] or [`Factor::Swatch`] at `value` for
/// textile `t`, from the first (and second) index press.
fn cloth_spec(
    sim: &Simulator,
    factor: Factor,
    value: f64,
    t: &str,
    seed: u64,
) -> Result<PressSpec> {
    let first = base_spec(t, INDEX_SEED);
    let s0 = telextiles_sim::swatch_of(&first);
    let s1 = telextiles_sim::swatch_of(&base_spec(t, INDEX_SEED + 1));
    let b = base_spec(t, seed);
    Ok(match factor {
        Factor::Spot => {
            let o = sim
                .press_meta(&first)
                .map_err(|e| anyhow!("simulator: {e}"))?
                .params
                .context("simulated press without params")?
                .offset_mm;
            // Towards the centre, so the spot stays within the bolt's
            // +-8 mm.
            let d = value as f32;
            let away = |x: f32| if x > 0.0 { x - d } else { x + d };
            PressSpec {
                seed: seed_on_swatch(&b, seed, &[s0], true)?,
                offset_mm: Some([away(o[0]), away(o[1])]),
                ..b
            }
        }
        Factor::Swatch => {
            let seed = if value == 0.0 {
                seed_on_swatch(&b, seed, &[s0], true)?
            } else {
                seed_on_swatch(&b, seed, &[s0, s1], false)?
            };
            PressSpec { seed, ..b }
        }
        _ => b,
    })
}

/// Seed of the first index press of each textile (the k-th is
/// `INDEX_SEED + k`).
const INDEX_SEED: u64 = 7000;

/// Index presses per textile of the suite (the coverage factors vary it).
pub const INDEX_PRESSES: usize = 2;

/// The index presses `first..end` of every textile (jig, person 0, unit 0,
/// 0°, 4 N; seeds from [`INDEX_SEED`]), and the number of each plan's
/// press within its textile (`first..end`).
fn index_plans(textiles: &[String], first: usize, end: usize) -> (Vec<Plan>, Vec<usize>) {
    textiles
        .iter()
        .enumerate()
        .flat_map(|(c, t)| {
            (first..end).map(move |k| {
                (
                    Plan {
                        spec: base_spec(t, INDEX_SEED + k as u64),
                        class: c as u32,
                        consecutive: None,
                        from_contact: false,
                        post: Post::None,
                    },
                    k,
                )
            })
        })
        .unzip()
}

/// Query plans of one level.
fn level_plans(
    sim: &Simulator,
    factor: Factor,
    value: f64,
    textiles: &[String],
    unseen: &[String],
    frames: usize,
) -> Result<Vec<Plan>> {
    level_plans_seeded(sim, factor, value, textiles, unseen, frames, QUERY_SEED)
}

/// Seed of the query presses (of every textile, at every level).
const QUERY_SEED: u64 = 8000;

/// Query presses per textile of the coverage factors (one in the quick
/// suite, whose first query press is every other factor's): the levels
/// differ by a few points, so they need more presses than one per textile.
fn coverage_queries(quick: bool) -> u64 {
    if quick {
        1
    } else {
        3
    }
}

/// [`level_plans`] with the query presses' seed.
fn level_plans_seeded(
    sim: &Simulator,
    factor: Factor,
    value: f64,
    textiles: &[String],
    unseen: &[String],
    frames: usize,
    seed: u64,
) -> Result<Vec<Plan>> {
    let plan = |spec: PressSpec, class: usize, post: Post| Plan {
        spec,
        class: class as u32,
        consecutive: Some(frames),
        from_contact: false,
        post,
    };
    let list: Vec<(usize, &String)> = if factor == Factor::Unseen {
        unseen
            .iter()
            .enumerate()
            .map(|(i, t)| (textiles.len() + i, t))
            .collect()
    } else {
        textiles.iter().enumerate().collect()
    };
    list.into_iter()
        .map(|(class, t)| {
            let b = base_spec(t, seed);
            Ok(match factor {
                Factor::Rotation => plan(
                    PressSpec {
                        rotation_deg: Some(value as f32),
                        ..b
                    },
                    class,
                    Post::None,
                ),
                Factor::Force => plan(
                    PressSpec {
                        force: Some(value as f32),
                        ..b
                    },
                    class,
                    Post::None,
                ),
                Factor::Tilt => plan(
                    PressSpec {
                        tilt_deg: Some([value as f32, 0.0]),
                        ..b
                    },
                    class,
                    Post::None,
                ),
                Factor::HandHeld => plan(
                    PressSpec {
                        person: value as u32,
                        jig: false,
                        rotation_deg: Some(0.0),
                        force: None,
                        release: Some(false),
                        ..PressSpec::new(t.as_str(), seed)
                    },
                    class,
                    Post::None,
                ),
                Factor::SensorSwap | Factor::SensorPool => plan(
                    PressSpec {
                        sensor: value as u32,
                        ..b
                    },
                    class,
                    Post::None,
                ),
                Factor::LedDrift => plan(b, class, Post::Gain(value as f32)),
                Factor::Noise => plan(b, class, Post::Noise(value as f32)),
                Factor::StaleBackground => plan(b, class, Post::Shift(value as i32)),
                Factor::Unseen => plan(b, class, Post::None),
                Factor::Spot | Factor::Swatch => {
                    plan(cloth_spec(sim, factor, value, t, seed)?, class, Post::None)
                }
                Factor::Coverage => plan(b, class, Post::None),
                Factor::CoverageHand => plan(
                    PressSpec {
                        person: COVERAGE_HAND_PERSON,
                        jig: false,
                        rotation_deg: Some(0.0),
                        force: None,
                        release: Some(false),
                        ..PressSpec::new(t.as_str(), seed)
                    },
                    class,
                    Post::None,
                ),
            })
        })
        .collect()
}

/// kNN decisions (index row labels) of each row of `q`.
fn decide(index: &[f32], labels: &[u32], q: &[f32], dim: usize) -> Vec<u32> {
    top_k(index, q, dim, 1)
        .into_iter()
        .map(|r| labels[r[0].1])
        .collect()
}

/// Scores one method on one level's embedded queries.
#[allow(clippy::too_many_arguments)]
fn score_level(
    value: f64,
    set: &ImageSet,
    qe: &[f32],
    dim: usize,
    index: &[f32],
    labels: &[u32],
    unseen_rank: Option<&dyn Fn(u32, u32) -> usize>,
    presses_of_rows: Option<&[usize]>,
) -> LevelScore {
    let mut presses: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
    for (i, m) in set.items.iter().enumerate() {
        presses.entry(m.press).or_default().push(i);
    }
    let per_frame = decide(index, labels, qe, dim);
    let mut q = Vec::new();
    let mut classes = Vec::new();
    let (mut flips, mut pairs) = (0usize, 0usize);
    for rows in presses.values() {
        let mut m = mean_rows(qe, dim, rows);
        normalize_rows(&mut m, dim);
        q.extend(m);
        classes.push(set.items[rows[0]].class);
        for w in rows.windows(2) {
            pairs += 1;
            flips += (per_frame[w[0]] != per_frame[w[1]]) as usize;
        }
    }
    let per_press = decide(index, labels, &q, dim);
    let share = |index: &[f32], labels: &[u32]| {
        let got = decide(index, labels, &q, dim);
        let right = classes.iter().zip(&got).filter(|(t, g)| t == g).count();
        right as f64 / classes.len().max(1) as f64
    };
    let (press_top1_centroid, press_top1_exemplars) = match presses_of_rows {
        Some(ks) => {
            let (mut c, mut cl) = crate::methods::centroids(index, labels, dim);
            let by_centroid = share(&c, &cl);
            let (x, xl) = press_exemplars(index, labels, ks, dim);
            c.extend(x);
            cl.extend(xl);
            (Some(by_centroid), Some(share(&c, &cl)))
        }
        None => (None, None),
    };
    let ok = |truth: u32, got: u32| match unseen_rank {
        Some(rank) => rank(truth, got) <= 10,
        None => truth == got,
    };
    let press_ok = classes
        .iter()
        .zip(&per_press)
        .filter(|(t, g)| ok(**t, **g))
        .count();
    let frame_ok = set
        .items
        .iter()
        .zip(&per_frame)
        .filter(|(m, g)| ok(m.class, **g))
        .count();
    let attr_rank_median = unseen_rank.map(|rank| {
        let r: Vec<f64> = classes
            .iter()
            .zip(&per_press)
            .map(|(t, g)| rank(*t, *g) as f64)
            .collect();
        crate::bench::median(&r)
    });
    LevelScore {
        value,
        press_top1: press_ok as f64 / classes.len().max(1) as f64,
        frame_top1: frame_ok as f64 / set.len().max(1) as f64,
        flip_rate: flips as f64 / pairs.max(1) as f64,
        attr_rank_median,
        press_top1_centroid,
        press_top1_exemplars,
        presses: classes.len(),
    }
}

/// The rows (their labels and press numbers) of an index's first `k`
/// presses of every textile (`ks`: each row's press number within its
/// textile).
fn first_presses(
    rows: &[f32],
    labels: &[u32],
    ks: &[usize],
    dim: usize,
    k: usize,
) -> (Vec<f32>, Vec<u32>, Vec<usize>) {
    let mut index = Vec::new();
    let mut out = Vec::new();
    let mut out_ks = Vec::new();
    for ((row, &l), &pk) in rows.chunks_exact(dim.max(1)).zip(labels).zip(ks) {
        if pk < k {
            index.extend_from_slice(row);
            out.push(l);
            out_ks.push(pk);
        }
    }
    (index, out, out_ks)
}

/// The normalised mean of each index press's rows (a press: its label and
/// its number `ks` within the textile), and the press's label: the
/// exemplars `index build --presses` keeps.
fn press_exemplars(
    index: &[f32],
    labels: &[u32],
    ks: &[usize],
    dim: usize,
) -> (Vec<f32>, Vec<u32>) {
    let mut by: std::collections::BTreeMap<(u32, usize), Vec<usize>> = Default::default();
    for (row, (&l, &k)) in labels.iter().zip(ks).enumerate() {
        by.entry((l, k)).or_default().push(row);
    }
    crate::methods::press_means(index, dim, &by, |&(l, _)| l)
}

/// Runs the suite for every method.
pub fn run_suite(
    sim: &Simulator,
    methods: &[Method],
    cfg: &SuiteConfig,
    ort_threads: usize,
) -> Result<StabilityReport> {
    anyhow::ensure!(
        !cfg.factors.contains(&Factor::Swatch) || sim.catalogue().version >= 2,
        "the swatch factor needs catalogue 2 (catalogue 1 has no swatches)"
    );
    anyhow::ensure!(
        cfg.index_stretch == 0.0 || !cfg.factors.iter().any(Factor::is_coverage),
        "--index-stretch and the coverage factors exclude each other (the coverage indexes' further presses are not stretched)"
    );
    let mut textiles: Vec<String> = sim.catalogue().training().map(|t| t.id.clone()).collect();
    if let Some(n) = cfg.textiles {
        textiles.truncate(n);
    }
    let unseen: Vec<String> = sim.catalogue().unseen().map(|t| t.id.clone()).collect();
    let classes: Vec<String> = textiles.iter().chain(&unseen).cloned().collect();
    let attrs: Vec<Vec<f32>> = classes
        .iter()
        .map(|c| {
            sim.catalogue()
                .get(c)
                .map(|t| t.attributes.to_vec().to_vec())
                .unwrap_or_default()
        })
        .collect();
    let known = textiles.len();
    // Rank (1 = closest) of known textile `got` among the known textiles
    // by attribute distance to `truth`.
    let adist = |a: usize, b: usize| -> f64 {
        attrs[a]
            .iter()
            .zip(&attrs[b])
            .map(|(x, y)| ((x - y) as f64).powi(2))
            .sum::<f64>()
    };
    let rank = |truth: u32, got: u32| -> usize {
        let d = adist(truth as usize, got as usize);
        (0..known).filter(|&k| adist(truth as usize, k) < d).count() + 1
    };
    let t0 = std::time::Instant::now();
    let mut render_s = 0.0;
    let mut embed_s = 0.0;
    // The index: two reference presses per textile, 6 frames each.
    let (plans, mut press_k) = index_plans(&textiles, 0, INDEX_PRESSES);
    let mut index_set = render(sim, &classes, &plans, 6, cfg.threads)?;
    // The coverage factors' larger indexes: the same presses and more.
    let coverage_max = cfg
        .factors
        .iter()
        .filter(|f| f.is_coverage())
        .flat_map(|f| f.levels(cfg.quick))
        .fold(0.0f64, f64::max) as usize;
    let (more_plans, more_k) = index_plans(&textiles, INDEX_PRESSES, coverage_max);
    let more_set = if more_plans.is_empty() {
        None
    } else {
        Some(render(sim, &classes, &more_plans, 6, cfg.threads)?)
    };
    press_k.extend(more_k);
    // The pooled index of `SensorPool`: the same presses on units 0..=3.
    let pooled_set = if cfg.factors.contains(&Factor::SensorPool) {
        let plans: Vec<Plan> = textiles
            .iter()
            .enumerate()
            .flat_map(|(c, t)| {
                (0..4u32).flat_map(move |sensor| {
                    (0..2).map(move |k| Plan {
                        spec: PressSpec {
                            sensor,
                            ..base_spec(t, INDEX_SEED + k)
                        },
                        class: c as u32,
                        consecutive: None,
                        from_contact: false,
                        post: Post::None,
                    })
                })
            })
            .collect();
        Some(render(sim, &classes, &plans, 6, cfg.threads)?)
    } else {
        None
    };
    let sensors: Vec<u32> = (0..8).collect();
    let refs = references(sim, &sensors)?;
    if cfg.index_stretch != 0.0 {
        let copies = stretches(cfg.index_stretch)
            .into_iter()
            .map(|(sx, sy)| stretched(&index_set, &refs, sx, sy))
            .collect::<Result<Vec<_>>>()?;
        for s in copies {
            index_set.items.extend(s.items);
            index_set.pixels.extend(s.pixels);
        }
    }
    render_s += t0.elapsed().as_secs_f64();
    let mut embedders: Vec<Embedder> = methods
        .iter()
        .map(|m| Embedder::new(m, ort_threads))
        .collect::<Result<_>>()?;
    // Per method: its index embeddings (in its view).
    let mut indexes = Vec::new();
    let index_meta: Vec<u32> = index_set.items.iter().map(|m| m.press).collect();
    let t1 = std::time::Instant::now();
    for (m, e) in methods.iter().zip(embedders.iter_mut()) {
        let (crop, input) = m.view();
        let v = view_set(&index_set, crop, input)?;
        let r = view_set(&refs, crop, input)?;
        let (emb, dim) = e.embed(&v, |s| background_of(&r, s))?;
        let labels: Vec<u32> = v.items.iter().map(|m| m.class).collect();
        let pooled = match &pooled_set {
            Some(p) => {
                let v = view_set(p, crop, input)?;
                let (emb, _) = e.embed(&v, |s| background_of(&r, s))?;
                Some((emb, v.items.iter().map(|m| m.class).collect::<Vec<u32>>()))
            }
            None => None,
        };
        // The coverage factors: every index press's rows, and the number
        // of its press within its textile.
        let coverage = if coverage_max == 0 {
            None
        } else {
            let mut rows = emb.clone();
            let mut cl = labels.clone();
            let mut ks: Vec<usize> = index_meta.iter().map(|p| press_k[*p as usize]).collect();
            if let Some(more) = &more_set {
                let v = view_set(more, crop, input)?;
                let (more_emb, _) = e.embed(&v, |s| background_of(&r, s))?;
                rows.extend(more_emb);
                cl.extend(v.items.iter().map(|m| m.class));
                ks.extend(
                    v.items
                        .iter()
                        .map(|m| press_k[plans.len() + m.press as usize]),
                );
            }
            Some((rows, cl, ks))
        };
        indexes.push((emb, labels, dim, r, pooled, coverage));
    }
    embed_s += t1.elapsed().as_secs_f64();
    drop(index_set);
    drop(pooled_set);
    drop(more_set);
    let mut out: Vec<MethodStability> = methods
        .iter()
        .map(|m| MethodStability {
            name: m.name(),
            curves: Vec::new(),
        })
        .collect();
    for &factor in &cfg.factors {
        let mut curves: Vec<Vec<LevelScore>> = vec![Vec::new(); methods.len()];
        if factor.is_coverage() {
            // The same queries against ever larger indexes: rendered and
            // embedded once.
            let t = std::time::Instant::now();
            let mut plans = Vec::new();
            for j in 0..coverage_queries(cfg.quick) {
                let seed = QUERY_SEED + 100 * j;
                plans.extend(level_plans_seeded(
                    sim, factor, 0.0, &textiles, &unseen, cfg.frames, seed,
                )?);
            }
            let set = render(sim, &classes, &plans, 6, cfg.threads)?;
            render_s += t.elapsed().as_secs_f64();
            let t = std::time::Instant::now();
            for (mi, (m, e)) in methods.iter().zip(embedders.iter_mut()).enumerate() {
                let (crop, input) = m.view();
                let v = view_set(&set, crop, input)?;
                let (_, _, dim, refs, _, coverage) = &indexes[mi];
                let (rows, labels, ks) = coverage.as_ref().context("no coverage index")?;
                let (qe, _) = e.embed(&v, |s| background_of(refs, s))?;
                for value in factor.levels(cfg.quick) {
                    let (index, labels, kept) =
                        first_presses(rows, labels, ks, *dim, value as usize);
                    curves[mi].push(score_level(
                        value,
                        &v,
                        &qe,
                        *dim,
                        &index,
                        &labels,
                        None,
                        Some(&kept),
                    ));
                }
            }
            embed_s += t.elapsed().as_secs_f64();
            eprintln!(
                "stability {factor:?}: {} presses, {:.0} s so far",
                plans.len(),
                t0.elapsed().as_secs_f64()
            );
            for (o, c) in out.iter_mut().zip(curves) {
                o.curves.push(FactorCurve { factor, levels: c });
            }
            continue;
        }
        for value in factor.levels(cfg.quick) {
            let t = std::time::Instant::now();
            let plans = level_plans(sim, factor, value, &textiles, &unseen, cfg.frames)?;
            let set = render(sim, &classes, &plans, 6, cfg.threads)?;
            render_s += t.elapsed().as_secs_f64();
            let t = std::time::Instant::now();
            for (mi, (m, e)) in methods.iter().zip(embedders.iter_mut()).enumerate() {
                let (crop, input) = m.view();
                let v = view_set(&set, crop, input)?;
                let (index, labels, dim, refs, pooled, _) = &indexes[mi];
                let (index, labels) = match (factor, pooled) {
                    (Factor::SensorPool, Some((pi, pl))) => (pi, pl),
                    _ => (index, labels),
                };
                let (qe, _) = e.embed(&v, |s| background_of(refs, s))?;
                let r: &dyn Fn(u32, u32) -> usize = &rank;
                curves[mi].push(score_level(
                    value,
                    &v,
                    &qe,
                    *dim,
                    index,
                    labels,
                    (factor == Factor::Unseen).then_some(r),
                    None,
                ));
            }
            embed_s += t.elapsed().as_secs_f64();
            eprintln!(
                "stability {factor:?} {value}: {} presses, {:.0} s so far",
                plans.len(),
                t0.elapsed().as_secs_f64()
            );
        }
        for (o, c) in out.iter_mut().zip(curves) {
            o.curves.push(FactorCurve { factor, levels: c });
        }
    }
    Ok(StabilityReport {
        config: cfg.clone(),
        textiles: textiles.len(),
        methods: out,
        render_s,
        embed_s,
    })
}

/// One figure of a level (None where the level does not have it).
pub(crate) type LevelFigure = fn(&LevelScore) -> Option<f64>;

#[cfg(test)]
mod tests;
