//! Validation statistics of simulated (and real) DIGIT frames: how much
//! contrast a press gives, how periodic it is, how the camera noise is
//! correlated, how different two sensor units' backgrounds are, and how fast
//! presses render. `telextilesd sim stats` prints them (docs/simulator.md).

use crate::catalogue::{Book, Family};
use crate::{PressSpec, RgbImage, SimError, Simulator, HEIGHT, WIDTH};

const W: usize = WIDTH as usize;
const H: usize = HEIGHT as usize;
/// Side of the centre crop the contact statistics use.
pub const CROP: usize = 128;

/// Luminance (mean of R, G, B) of `frame - reference` over the centre
/// `CROP` x `CROP` crop.
pub fn centre_difference(frame: &RgbImage, reference: &[f32]) -> Vec<f32> {
    let (x0, y0) = ((W - CROP) / 2, (H - CROP) / 2);
    let raw = frame.as_raw();
    let mut out = Vec::with_capacity(CROP * CROP);
    for y in y0..y0 + CROP {
        for x in x0..x0 + CROP {
            let i = (y * W + x) * 3;
            let d: f32 = (0..3)
                .map(|c| raw[i + c] as f32 - reference[i + c])
                .sum::<f32>()
                / 3.0;
            out.push(d);
        }
    }
    out
}

/// Mean of frames as a float reference (interleaved RGB).
pub fn mean_frame(frames: &[&RgbImage]) -> Vec<f32> {
    let mut acc = vec![0f32; W * H * 3];
    for f in frames {
        for (a, v) in acc.iter_mut().zip(f.as_raw()) {
            *a += *v as f32;
        }
    }
    let k = frames.len().max(1) as f32;
    acc.iter_mut().for_each(|a| *a /= k);
    acc
}

/// Standard deviation of a signal.
pub fn std(v: &[f32]) -> f32 {
    let m = v.iter().sum::<f32>() / v.len() as f32;
    (v.iter().map(|x| (x - m).powi(2)).sum::<f32>() / v.len() as f32).sqrt()
}

/// Spectral peak-to-median ratio of a `CROP` x `CROP` signal: the 2D power
/// spectrum (mean removed, Hann window) in the texture band, 4 < radius <=
/// 32 bins (periods 4..32 px = 0.3..2.6 mm: yarns, loops, stitches; not
/// the shape of the contact patch or a crease, not the pixel-scale noise
/// and blur), its largest value over its median. A lattice gives a sharp
/// peak over a low floor; irregular relief spreads the power.
pub fn peak_to_median(sig: &[f32]) -> f64 {
    peak_to_median_at(sig).0
}

/// `peak_to_median` and the peak's frequency (cycles per crop along x, y).
pub fn peak_to_median_at(sig: &[f32]) -> (f64, (i32, i32)) {
    let n = CROP;
    assert_eq!(sig.len(), n * n);
    let m = sig.iter().map(|v| *v as f64).sum::<f64>() / (n * n) as f64;
    let win: Vec<f64> = (0..n)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / n as f64).cos())
        .collect();
    let (cos, sin): (Vec<f64>, Vec<f64>) = (0..n)
        .map(|k| {
            let a = -2.0 * std::f64::consts::PI * k as f64 / n as f64;
            (a.cos(), a.sin())
        })
        .unzip();
    let mut re = vec![0f64; n * n];
    let mut im = vec![0f64; n * n];
    for y in 0..n {
        for k in 0..n {
            let (mut sr, mut si) = (0.0, 0.0);
            for x in 0..n {
                let v = (sig[y * n + x] as f64 - m) * win[x] * win[y];
                let t = (k * x) % n;
                sr += v * cos[t];
                si += v * sin[t];
            }
            re[y * n + k] = sr;
            im[y * n + k] = si;
        }
    }
    let mut power = Vec::with_capacity(n * n);
    let mut peak = 0f64;
    let mut at = (0, 0);
    for k in 0..n {
        for l in 0..n {
            let (mut sr, mut si) = (0.0, 0.0);
            for y in 0..n {
                let t = (l * y) % n;
                let (a, b) = (re[y * n + k], im[y * n + k]);
                sr += a * cos[t] - b * sin[t];
                si += a * sin[t] + b * cos[t];
            }
            let p = sr * sr + si * si;
            let fk = if k > n / 2 { n - k } else { k } as f64;
            let fl = if l > n / 2 { n - l } else { l } as f64;
            let r = (fk * fk + fl * fl).sqrt();
            if r > 4.0 && r <= 32.0 {
                power.push(p);
            }
            if r > 4.0 && r <= 32.0 && p > peak {
                peak = p;
                let sk = if k > n / 2 {
                    k as i32 - n as i32
                } else {
                    k as i32
                };
                let sl = if l > n / 2 {
                    l as i32 - n as i32
                } else {
                    l as i32
                };
                at = (sk, sl);
            }
        }
    }
    power.sort_by(|a, b| a.total_cmp(b));
    let med = power[power.len() / 2];
    (peak / med.max(1e-12), at)
}

/// Lag-1 spatial autocorrelation (mean of horizontal and vertical, over
/// channels) of the difference of two frames of an untouched sensor: 0 for
/// white noise, towards 1 for smooth noise.
pub fn noise_lag1(a: &RgbImage, b: &RgbImage) -> f32 {
    let (ra, rb) = (a.as_raw(), b.as_raw());
    let mut total = 0.0;
    for c in 0..3 {
        let d: Vec<f32> = (0..W * H)
            .map(|p| rb[p * 3 + c] as f32 - ra[p * 3 + c] as f32)
            .collect();
        let m = d.iter().sum::<f32>() / d.len() as f32;
        let var: f32 = d.iter().map(|v| (v - m).powi(2)).sum::<f32>();
        let (mut h, mut v) = (0f32, 0f32);
        for y in 0..H {
            for x in 0..W {
                let e = d[y * W + x] - m;
                if x + 1 < W {
                    h += e * (d[y * W + x + 1] - m);
                }
                if y + 1 < H {
                    v += e * (d[(y + 1) * W + x] - m);
                }
            }
        }
        total += 0.5 * (h + v) / var.max(1e-9);
    }
    total / 3.0
}

/// Fine structure of one frame: the residual of each channel after a 5 x 5
/// mean filter (what remains is the noise and compression texture plus the
/// background's finest detail). Returns the residual's std (DN) and its
/// lag-1 spatial autocorrelation (mean of horizontal and vertical, over
/// channels). Works on a single frame, so it applies to the real
/// no-contact frames too.
pub fn residual_noise(f: &RgbImage) -> (f32, f32) {
    let raw = f.as_raw();
    let (mut sd, mut lag) = (0f32, 0f32);
    for c in 0..3 {
        let v: Vec<f32> = (0..W * H).map(|p| raw[p * 3 + c] as f32).collect();
        let mut res = Vec::with_capacity((W - 4) * (H - 4));
        for y in 2..H - 2 {
            for x in 2..W - 2 {
                let mut m = 0f32;
                for dy in 0..5 {
                    for dx in 0..5 {
                        m += v[(y + dy - 2) * W + x + dx - 2];
                    }
                }
                res.push(v[y * W + x] - m / 25.0);
            }
        }
        let (w, h) = (W - 4, H - 4);
        let mean = res.iter().sum::<f32>() / res.len() as f32;
        let var: f32 = res.iter().map(|r| (r - mean).powi(2)).sum();
        let (mut ch, mut cv) = (0f32, 0f32);
        for y in 0..h {
            for x in 0..w {
                let e = res[y * w + x] - mean;
                if x + 1 < w {
                    ch += e * (res[y * w + x + 1] - mean);
                }
                if y + 1 < h {
                    cv += e * (res[(y + 1) * w + x] - mean);
                }
            }
        }
        sd += (var / res.len() as f32).sqrt();
        lag += 0.5 * (ch + cv) / var.max(1e-9);
    }
    (sd / 3.0, lag / 3.0)
}

/// Correlation between channels of the frame-to-frame difference (mean of
/// the three channel pairs).
pub fn noise_colour_correlation(a: &RgbImage, b: &RgbImage) -> f32 {
    let (ra, rb) = (a.as_raw(), b.as_raw());
    let d: Vec<[f32; 3]> = (0..W * H)
        .map(|p| {
            let f = |c: usize| rb[p * 3 + c] as f32 - ra[p * 3 + c] as f32;
            [f(0), f(1), f(2)]
        })
        .collect();
    let mean = |c: usize| d.iter().map(|v| v[c]).sum::<f32>() / d.len() as f32;
    let ms = [mean(0), mean(1), mean(2)];
    let cov = |i: usize, j: usize| {
        d.iter()
            .map(|v| (v[i] - ms[i]) * (v[j] - ms[j]))
            .sum::<f32>()
    };
    let r = |i, j| cov(i, j) / (cov(i, i) * cov(j, j)).sqrt().max(1e-9);
    (r(0, 1) + r(0, 2) + r(1, 2)) / 3.0
}

/// Mean absolute difference of two backgrounds, DN per value.
pub fn background_difference(a: &RgbImage, b: &RgbImage) -> f32 {
    let s: f64 = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (*x as f64 - *y as f64).abs())
        .sum();
    (s / a.as_raw().len() as f64) as f32
}

/// Mean over pairs of units 0..`units` of the background difference.
pub fn unit_background_difference(sim: &Simulator, version: u32, units: u32) -> f32 {
    let bgs: Vec<RgbImage> = (0..units).map(|u| sim.background_of(version, u)).collect();
    let mut acc = 0.0;
    let mut k = 0;
    for i in 0..bgs.len() {
        for j in i + 1..bgs.len() {
            acc += background_difference(&bgs[i], &bgs[j]);
            k += 1;
        }
    }
    acc / k.max(1) as f32
}

/// What one press measured.
#[derive(Clone, Debug)]
pub struct PressStats {
    pub textile: String,
    pub family: Family,
    /// Std of the mid-hold frame minus the reference in the centre crop, DN.
    pub contact_std: f32,
    pub peak_to_median: f64,
    /// Lag-1 autocorrelation of the difference of the first two frames.
    pub noise_lag1: f32,
    pub noise_colour: f32,
    /// `residual_noise` of the first (untouched) frame: std and lag-1.
    pub residual: (f32, f32),
    /// Catalogue 2's press features (crease, seam, edge, ...).
    pub features: Vec<String>,
}

impl PressStats {
    /// No crease, fold, seam, hem or cloth edge in the window: the spectrum
    /// is the fabric's own (a line across the window puts a ridge through
    /// the spectrum that has nothing to do with the weave).
    pub fn plain_cloth(&self) -> bool {
        !self
            .features
            .iter()
            .any(|f| matches!(f.as_str(), "crease" | "fold" | "seam" | "hem" | "edge"))
    }
}

/// Measure one press: its mid-hold frame against the mean of its reference
/// frames (up to 8), as one would measure a recorded press; noise from
/// frames 0 and 1.
pub fn press_stats(sim: &Simulator, spec: &PressSpec) -> Result<PressStats, SimError> {
    let meta = sim.press_meta(spec)?;
    let p = meta.params.as_ref().expect("simulated press has params");
    let refs = meta.reference_frames.unwrap_or(1).clamp(1, 8) as usize;
    let ref_frames: Vec<RgbImage> = (0..refs)
        .map(|i| sim.render_frame(spec, i))
        .collect::<Result<_, _>>()?;
    let reference = mean_frame(&ref_frames.iter().collect::<Vec<_>>());
    let end = p.release_frame.unwrap_or(spec.frames as u32);
    let mid = ((p.hold_frame + end) / 2).min(spec.frames as u32 - 1) as usize;
    let frame = sim.render_frame(spec, mid)?;
    let d = centre_difference(&frame, &reference);
    let f1 = if refs >= 2 {
        ref_frames[1].clone()
    } else {
        sim.render_frame(spec, 1)?
    };
    let version = sim.resolve(spec)?.0;
    let family = sim
        .catalogue_of(version)
        .get(&spec.textile)
        .map(|t| t.structure.family())
        .unwrap_or(Family::Plain);
    Ok(PressStats {
        textile: spec.textile.clone(),
        family,
        contact_std: std(&d),
        peak_to_median: peak_to_median(&d),
        noise_lag1: noise_lag1(&ref_frames[0], &f1),
        noise_colour: noise_colour_correlation(&ref_frames[0], &f1),
        residual: residual_noise(&ref_frames[0]),
        features: p.features.clone(),
    })
}

/// The validation sample: up to `per_family` training textiles of each
/// family, one jig press each by person `k % 11` on unit `k % units`.
pub fn sample_specs(
    sim: &Simulator,
    version: u32,
    generator: u32,
    per_family: usize,
    units: u32,
) -> Vec<PressSpec> {
    let cat = sim.catalogue_of(version);
    let fams: &[Family] = if version == 2 {
        &Family::ALL_V2
    } else {
        &Family::ALL
    };
    let mut specs = Vec::new();
    for f in fams {
        for t in cat
            .textiles
            .iter()
            .filter(|t| t.book == Book::Training && t.structure.family() == *f)
            .take(per_family)
        {
            let k = specs.len() as u32;
            specs.push(PressSpec {
                person: k % 11,
                sensor: k % units.max(1),
                catalogue: Some(version),
                generator: (version == 2).then_some(generator),
                rotation_deg: Some(0.0),
                ..PressSpec::new(t.id.clone(), 1000 + k as u64)
            });
        }
    }
    specs
}

/// Summary row of the validation table.
#[derive(Clone, Debug)]
pub struct Summary {
    pub presses: usize,
    pub contact_std_median: f32,
    pub contact_std_soft: Option<f32>,
    pub contact_std_rough: Option<f32>,
    /// Over woven and knit presses without a crease, fold, seam, hem or edge.
    pub peak_wovens_knits_median: f64,
    pub peak_wovens_knits_max: f64,
    pub peak_presses: usize,
    pub noise_lag1: f32,
    pub noise_colour: f32,
    /// Median `residual_noise` of the presses' first frames (std, lag-1).
    pub residual_std: f32,
    pub residual_lag1: f32,
    pub unit_bg_difference: f32,
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(|a, b| a.total_cmp(b));
    v[v.len() / 2]
}

/// Summarise measured presses (and the unit background difference).
pub fn summarise(rows: &[PressStats], unit_bg_difference: f32) -> Summary {
    let med = |f: &dyn Fn(&PressStats) -> Option<f64>| {
        let v: Vec<f64> = rows.iter().filter_map(f).collect();
        (!v.is_empty()).then(|| median(v))
    };
    let woven_knit = |r: &PressStats| {
        matches!(
            r.family,
            Family::Plain
                | Family::Twill
                | Family::Satin
                | Family::Basket
                | Family::Crepe
                | Family::Knit
                | Family::Rib
        )
    };
    let peaks: Vec<f64> = rows
        .iter()
        .filter(|r| woven_knit(r) && r.plain_cloth())
        .map(|r| r.peak_to_median)
        .collect();
    Summary {
        presses: rows.len(),
        contact_std_median: med(&|r| Some(r.contact_std as f64)).unwrap_or(f64::NAN) as f32,
        contact_std_soft: med(&|r| {
            matches!(r.family, Family::Soft).then_some(r.contact_std as f64)
        })
        .map(|v| v as f32),
        contact_std_rough: med(&|r| {
            matches!(r.family, Family::Terry | Family::Tuft | Family::Loop)
                .then_some(r.contact_std as f64)
        })
        .map(|v| v as f32),
        peak_wovens_knits_median: median(peaks.clone()),
        peak_wovens_knits_max: peaks.iter().cloned().fold(f64::NAN, f64::max),
        peak_presses: peaks.len(),
        noise_lag1: med(&|r| Some(r.noise_lag1 as f64)).unwrap_or(f64::NAN) as f32,
        noise_colour: med(&|r| Some(r.noise_colour as f64)).unwrap_or(f64::NAN) as f32,
        residual_std: med(&|r| Some(r.residual.0 as f64)).unwrap_or(f64::NAN) as f32,
        residual_lag1: med(&|r| Some(r.residual.1 as f64)).unwrap_or(f64::NAN) as f32,
        unit_bg_difference,
    }
}

/// CPU time of this thread in seconds (Linux), else wall-clock.
pub fn thread_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = s.split_whitespace().next()?.parse().ok()?;
    Some(ns / 1e9)
}

/// Render whole presses (every frame) on this thread: frames per second of
/// thread CPU time (wall-clock where that is not available).
pub fn render_speed(sim: &Simulator, specs: &[PressSpec]) -> Result<f64, SimError> {
    let t0 = thread_cpu_s();
    let w0 = std::time::Instant::now();
    let mut frames = 0usize;
    for s in specs {
        let p = sim.render_press(s)?;
        frames += p.frames.len();
    }
    let secs = match (t0, thread_cpu_s()) {
        (Some(a), Some(b)) if b > a => b - a,
        _ => w0.elapsed().as_secs_f64(),
    };
    Ok(frames as f64 / secs.max(1e-9))
}
