//! Procedural fabric height fields at the sensor's physical scale.
//!
//! Every textile has one large patch (`PATCH` x `PATCH` samples at
//! `MM_PER_PX`, about 41 mm square) generated from its micro-structure seed;
//! a press looks at a rotated, shifted window of it, so two presses of one
//! textile show the same fabric at different places and angles.

use crate::catalogue::{mix64, Structure, Textile};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Sampling pitch of the height field and of the sensor image (mm per pixel).
/// DIGIT: about 19.2 mm x 25.6 mm sensing area over 240 x 320 pixels.
pub const MM_PER_PX: f32 = 0.08;
/// Side of the per-textile patch in samples.
pub const PATCH: usize = 512;

/// A height field in mm, row-major, `size` x `size`.
pub struct HeightField {
    pub size: usize,
    pub h: Vec<f32>,
}

impl HeightField {
    /// Bilinear sample at (x, y) in samples; clamps at the border.
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let n = self.size;
        let x = x.clamp(0.0, (n - 2) as f32);
        let y = y.clamp(0.0, (n - 2) as f32);
        let x0 = x as usize;
        let y0 = y as usize;
        let fx = x - x0 as f32;
        let fy = y - y0 as f32;
        let i = y0 * n + x0;
        let a = self.h[i] + (self.h[i + 1] - self.h[i]) * fx;
        let b = self.h[i + n] + (self.h[i + n + 1] - self.h[i + n]) * fx;
        a + (b - a) * fy
    }
}

#[inline]
pub(crate) fn smooth(t: f32) -> f32 {
    let t = t.clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// Elliptical yarn cross-section: 1 at the crown, 0 at the edge.
#[inline]
pub(crate) fn crown(d: f32) -> f32 {
    let q = 1.0 - d * d;
    if q > 0.0 {
        q.sqrt()
    } else {
        0.0
    }
}

/// Hash-based value noise in 1D and 2D (deterministic, seedable).
#[inline]
pub(crate) fn hash2(seed: u64, i: i64, j: i64) -> f32 {
    let h = mix64(seed ^ mix64((i as u64).wrapping_mul(0x9E37_79B9) ^ ((j as u64) << 32)));
    (h >> 40) as f32 / (1u64 << 24) as f32
}

pub(crate) fn value_noise(seed: u64, x: f32, y: f32) -> f32 {
    let xi = x.floor();
    let yi = y.floor();
    let fx = smooth(x - xi);
    let fy = smooth(y - yi);
    let (i, j) = (xi as i64, yi as i64);
    let a = hash2(seed, i, j);
    let b = hash2(seed, i + 1, j);
    let c = hash2(seed, i, j + 1);
    let d = hash2(seed, i + 1, j + 1);
    let top = a + (b - a) * fx;
    let bot = c + (d - c) * fx;
    (top + (bot - top) * fy) * 2.0 - 1.0
}

/// Fractal noise, roughly -1..1, lowest frequency 1/`scale` per sample.
pub(crate) fn fbm(seed: u64, x: f32, y: f32, scale: f32, octaves: u32) -> f32 {
    let mut s = 0.0;
    let mut amp = 1.0;
    let mut norm = 0.0;
    let mut f = 1.0 / scale;
    for o in 0..octaves {
        s += amp * value_noise(seed.wrapping_add(o as u64 * 7919), x * f, y * f);
        norm += amp;
        amp *= 0.5;
        f *= 2.0;
    }
    s / norm
}

/// Weave rule: is the warp (vertical yarn, column `i`) over the weft (row `j`)?
pub(crate) fn warp_up(s: &Structure, i: i64, j: i64) -> bool {
    let m = |a: i64, n: i64| a.rem_euclid(n);
    match *s {
        Structure::Plain | Structure::Ripstop { .. } | Structure::Crepe => m(i + j, 2) == 0,
        Structure::Twill { over, under } => m(i + j, (over + under) as i64) < over as i64,
        Structure::Herringbone { over, under, band } => {
            let r = (over + under) as i64;
            let b = band as i64;
            let dir = if m(i.div_euclid(b), 2) == 0 { 1 } else { -1 };
            m(dir * i + j, r) < over as i64
        }
        Structure::Satin { harness } => {
            let h = harness as i64;
            let step = if h == 5 { 2 } else { 3 };
            // warp-faced: warp down only at one position per repeat
            m(i * step - j, h) != 0
        }
        Structure::Basket { group } => {
            let g = group as i64;
            m(i.div_euclid(g) + j.div_euclid(g), 2) == 0
        }
        _ => m(i + j, 2) == 0,
    }
}

struct Ctx<'a> {
    t: &'a Textile,
    rng: ChaCha8Rng,
    seed: u64,
}

/// Generate the patch of one textile.
pub fn generate(t: &Textile) -> HeightField {
    let mut ctx = Ctx {
        t,
        rng: ChaCha8Rng::seed_from_u64(t.micro_seed),
        seed: t.micro_seed,
    };
    let mut h = match t.structure {
        Structure::Jersey | Structure::Rib { .. } => knit(&mut ctx),
        Structure::Velvet | Structure::Corduroy { .. } => pile(&mut ctx),
        Structure::Terry { loop_mm } => terry(&mut ctx, loop_mm),
        Structure::Fleece => fleece(&mut ctx),
        Structure::Felt => felt(&mut ctx),
        _ => woven(&mut ctx),
    };
    // Hairiness: loose fibres lying on the surface.
    let fuzz = t.fuzz;
    if fuzz > 0.02 && !matches!(t.structure, Structure::Felt | Structure::Fleece) {
        let n = (fuzz * 2.5 * (PATCH as f32 * MM_PER_PX).powi(2)) as usize;
        let top = t.relief_mm;
        for _ in 0..n {
            let len = ctx.rng.gen_range(0.4..2.0) / MM_PER_PX;
            let hgt = top * ctx.rng.gen_range(0.2..0.9);
            let r = 0.6 + fuzz * 0.5;
            draw_fibre(
                &mut h,
                &mut ctx.rng,
                len,
                hgt,
                r,
                0.25 + 0.5 * (1.0 - t.stiffness),
            );
        }
    }
    // Normalise: top of the fabric at 0, everything below negative.
    let max = h.iter().cloned().fold(f32::MIN, f32::max);
    for v in h.iter_mut() {
        *v -= max;
    }
    HeightField { size: PATCH, h }
}

fn woven(c: &mut Ctx) -> Vec<f32> {
    let t = c.t;
    let sx = 10.0 / t.warp_per_cm / MM_PER_PX; // warp spacing (px), warp runs along y
    let sy = 10.0 / t.weft_per_cm / MM_PER_PX; // weft spacing (px)
    let dw = t.yarn_diameter_mm / MM_PER_PX; // yarn width (px)
    let relief = t.relief_mm;
    let irr = t.irregularity;
    let seed = c.seed;
    let crepe = matches!(t.structure, Structure::Crepe);
    let ripstop = match t.structure {
        Structure::Ripstop { grid } => grid as i64,
        _ => 0,
    };
    let twist = if crepe { 0.9 } else { 0.35 };
    let mut h = vec![0f32; PATCH * PATCH];
    for y in 0..PATCH {
        for x in 0..PATCH {
            let (xf, yf) = (x as f32, y as f32);
            // yarn waviness / crepe pebbling: domain warp
            let warp_amp = if crepe { 0.35 } else { 0.12 + 0.2 * irr };
            let wx = xf + warp_amp * sx * fbm(seed ^ 1, xf, yf, 40.0, 2);
            let wy = yf + warp_amp * sy * fbm(seed ^ 2, xf, yf, 40.0, 2);
            // warp yarn i (vertical)
            let gi = wx / sx;
            let i = gi.floor() as i64;
            let u = gi - i as f32 - 0.5; // -0.5..0.5 across warp
            let gj = wy / sy;
            let j = gj.floor() as i64;
            let v = gj - j as f32 - 0.5; // -0.5..0.5 across weft
                                         // thickness variation along each yarn (slubs)
            let thick_w = 1.0
                + irr
                    * 0.35
                    * value_noise(
                        seed ^ (i as u64).wrapping_mul(31).wrapping_add(7),
                        yf / 25.0,
                        0.0,
                    );
            let thick_f = 1.0
                + irr
                    * 0.35
                    * value_noise(
                        seed ^ (j as u64).wrapping_mul(37).wrapping_add(11),
                        xf / 25.0,
                        0.0,
                    );
            let rip_w = if ripstop > 0 && i.rem_euclid(ripstop) == 0 {
                1.5
            } else {
                1.0
            };
            let rip_f = if ripstop > 0 && j.rem_euclid(ripstop) == 0 {
                1.5
            } else {
                1.0
            };
            // up-ness of warp i along y: interpolate between weft crossings
            let jn = if v < 0.0 { j - 1 } else { j + 1 };
            let up_here = warp_up(&t.structure, i, j) as i32 as f32;
            let up_next = warp_up(&t.structure, i, jn) as i32 as f32;
            let tv = smooth(v.abs() * 2.0 - 0.0) * 0.5; // 0 at centre .. 0.5 at boundary
            let up_w = up_here + (up_next - up_here) * tv;
            let im = if u < 0.0 { i - 1 } else { i + 1 };
            let fup_here = 1.0 - up_here;
            let fup_next = 1.0 - warp_up(&t.structure, im, j) as i32 as f32;
            let tu = smooth(u.abs() * 2.0) * 0.5;
            let up_f = fup_here + (fup_next - fup_here) * tu;
            let half_w = 0.5 * dw * thick_w * rip_w;
            let half_f = 0.5 * dw * thick_f * rip_f;
            let cw = crown(u * sx / half_w.max(0.5));
            let cf = crown(v * sy / half_f.max(0.5));
            // fibre twist striations along the yarn
            let tw_w =
                1.0 - 0.12 * (1.0 + ((yf + u * sx * twist) / (dw * 0.45).max(0.8)).sin()) * 0.5;
            let tw_f =
                1.0 - 0.12 * (1.0 + ((xf + v * sy * twist) / (dw * 0.45).max(0.8)).sin()) * 0.5;
            let hw =
                relief * (0.5 * (2.0 * up_w - 1.0)) + relief * 0.5 * cw * thick_w * rip_w * tw_w;
            let hf =
                relief * (0.5 * (2.0 * up_f - 1.0)) + relief * 0.5 * cf * thick_f * rip_f * tw_f;
            let mut z = hw.max(hf).max(-relief);
            if crepe {
                z += relief * 0.35 * fbm(seed ^ 3, xf, yf, 6.0, 2);
            }
            h[y * PATCH + x] = z;
        }
    }
    h
}

fn knit(c: &mut Ctx) -> Vec<f32> {
    let t = c.t;
    let sw = 10.0 / t.warp_per_cm / MM_PER_PX; // wale spacing (px), wales run along y
    let sc = 10.0 / t.weft_per_cm / MM_PER_PX; // course spacing
    let hw = 0.5 * t.yarn_diameter_mm / MM_PER_PX;
    let relief = t.relief_mm;
    let (knit_n, purl_n) = match t.structure {
        Structure::Rib { knit, purl } => (knit as i64, purl as i64),
        _ => (1, 0),
    };
    let seed = c.seed;
    let irr = t.irregularity;
    let mut h = vec![0f32; PATCH * PATCH];
    for y in 0..PATCH {
        for x in 0..PATCH {
            let (xf, yf) = (x as f32, y as f32);
            let wx = xf + 0.15 * sw * fbm(seed ^ 5, xf, yf, 30.0, 2);
            let wy = yf + 0.15 * sc * fbm(seed ^ 6, xf, yf, 30.0, 2);
            let gi = wx / sw;
            let i = gi.floor() as i64;
            let u = gi - i as f32; // 0..1 across the wale
            let gj = wy / sc;
            let j = gj.floor() as i64;
            let v = gj - j as f32; // 0..1 along the course
            let period = knit_n + purl_n;
            let is_purl = purl_n > 0 && i.rem_euclid(period) >= knit_n;
            let thick =
                1.0 + irr * 0.3 * value_noise(seed ^ (j as u64).wrapping_mul(13), xf / 20.0, 0.0);
            let z = if !is_purl {
                // two legs of the V: centre lines tilted towards the wale centre
                let ul = 0.27 + 0.16 * v;
                let ur = 0.73 - 0.16 * v;
                let dl = (u - ul).abs() * sw / (hw * thick).max(0.5);
                let dr = (u - ur).abs() * sw / (hw * thick).max(0.5);
                let leg = crown(dl).max(crown(dr));
                // legs dip where they pass behind the previous loop head
                let dip = 0.75 + 0.25 * (std::f32::consts::PI * v).sin();
                relief * (leg * dip - 0.2)
            } else {
                // purl: horizontal loop heads (bumps across the wale), recessed
                let dv = (v - 0.5).abs() * sc / (hw * thick).max(0.5);
                let du = ((u - 0.5) * 2.0).abs();
                relief * (0.75 * crown(dv) * (1.0 - 0.4 * du * du) - 0.55)
            };
            h[y * PATCH + x] = z;
        }
    }
    h
}

/// Separable box-ish blur (3 passes of a box approximate a Gaussian).
pub(crate) fn blur(h: &mut [f32], n: usize, r: usize) {
    if r == 0 {
        return;
    }
    let mut tmp = vec![0f32; h.len()];
    for _ in 0..2 {
        for y in 0..n {
            for x in 0..n {
                let lo = x.saturating_sub(r);
                let hi = (x + r).min(n - 1);
                let mut s = 0.0;
                for k in lo..=hi {
                    s += h[y * n + k];
                }
                tmp[y * n + x] = s / (hi - lo + 1) as f32;
            }
        }
        for y in 0..n {
            let lo = y.saturating_sub(r);
            let hi = (y + r).min(n - 1);
            for x in 0..n {
                let mut s = 0.0;
                for k in lo..=hi {
                    s += tmp[k * n + x];
                }
                h[y * n + x] = s / (hi - lo + 1) as f32;
            }
        }
    }
}

fn pile(c: &mut Ctx) -> Vec<f32> {
    let t = c.t;
    let seed = c.seed;
    let relief = t.relief_mm;
    let tuft = 10.0 / t.warp_per_cm / MM_PER_PX; // tuft spacing px
    let mut tips = vec![0f32; PATCH * PATCH];
    // fibre tips: jittered grid of small discs with random heights
    let n = ((PATCH as f32 / tuft).powi(2) * 1.6) as usize;
    for _ in 0..n {
        let x = c.rng.gen_range(0.0..PATCH as f32);
        let y = c.rng.gen_range(0.0..PATCH as f32);
        let hgt = relief * c.rng.gen_range(0.3..1.0);
        let r = (0.35 * tuft).clamp(0.7, 2.5);
        stamp(&mut tips, x, y, r, hgt);
    }
    blur(&mut tips, PATCH, 1);
    let wale = match t.structure {
        Structure::Corduroy { wale_mm } => Some(wale_mm / MM_PER_PX),
        _ => None,
    };
    let nap_dir = c.rng.gen_range(0.0..std::f32::consts::TAU);
    for y in 0..PATCH {
        for x in 0..PATCH {
            let (xf, yf) = (x as f32, y as f32);
            // crushed-nap streaks along the nap direction
            let along = xf * nap_dir.cos() + yf * nap_dir.sin();
            let across = -xf * nap_dir.sin() + yf * nap_dir.cos();
            let nap = 0.35 * relief * fbm(seed ^ 9, along / 6.0, across, 8.0, 3);
            let mut z = tips[y * PATCH + x] + nap;
            if let Some(w) = wale {
                let p = (xf / w).fract();
                // rounded wale with a narrow groove
                let ridge = crown((p - 0.5) * 2.0 / 0.85);
                z = z * (0.3 + 0.7 * ridge) + t.thickness_mm * 0.5 * (ridge - 1.0);
            }
            tips[y * PATCH + x] = z;
        }
    }
    tips
}

fn terry(c: &mut Ctx, loop_mm: f32) -> Vec<f32> {
    let t = c.t;
    let relief = t.relief_mm;
    let base_relief = relief * 0.15;
    let seed = c.seed;
    let mut h = vec![0f32; PATCH * PATCH];
    // ground weave
    let gs = 10.0 / 25.0 / MM_PER_PX;
    for y in 0..PATCH {
        for x in 0..PATCH {
            let u = (x as f32 / gs).fract() - 0.5;
            let v = (y as f32 / gs).fract() - 0.5;
            h[y * PATCH + x] = -relief
                + base_relief * (crown(u * 2.0).max(crown(v * 2.0)))
                + 0.05 * relief * fbm(seed, x as f32, y as f32, 20.0, 2);
        }
    }
    let spacing = 10.0 / t.warp_per_cm / MM_PER_PX;
    let yarn_r = (0.5 * t.yarn_diameter_mm / MM_PER_PX).max(1.0);
    let rad = 0.5 * loop_mm / MM_PER_PX;
    let cells = (PATCH as f32 / spacing) as usize + 2;
    for cj in 0..cells {
        for ci in 0..cells {
            let cx = (ci as f32 + c.rng.gen_range(-0.3..0.3)) * spacing;
            let cy = (cj as f32 + c.rng.gen_range(-0.3..0.3)) * spacing;
            let ang: f32 = c.rng.gen_range(0.0..std::f32::consts::PI);
            let squash = c.rng.gen_range(0.25..0.8); // loop seen obliquely
            let r = rad * c.rng.gen_range(0.8..1.2);
            let hgt = relief * c.rng.gen_range(0.6..1.0);
            let steps = (std::f32::consts::TAU * r / 0.7) as usize + 4;
            for s in 0..steps {
                let a = s as f32 / steps as f32 * std::f32::consts::TAU;
                let (lx, ly) = (r * a.cos(), r * squash * a.sin());
                let x = cx + lx * ang.cos() - ly * ang.sin();
                let y = cy + lx * ang.sin() + ly * ang.cos();
                // loop top is highest, its feet go into the ground
                let zz = -relief + (hgt + relief) * (0.55 + 0.45 * a.sin());
                stamp(&mut h, x, y, yarn_r, zz);
            }
        }
    }
    h
}

fn fleece(c: &mut Ctx) -> Vec<f32> {
    let t = c.t;
    let relief = t.relief_mm;
    let seed = c.seed;
    let mut h = vec![0f32; PATCH * PATCH];
    for y in 0..PATCH {
        for x in 0..PATCH {
            // pilled, brushed surface: soft bumps
            h[y * PATCH + x] =
                -relief + 0.6 * relief * (0.5 + 0.5 * fbm(seed, x as f32, y as f32, 14.0, 3));
        }
    }
    let area = (PATCH as f32 * MM_PER_PX).powi(2);
    let n = (area * 6.0 * (0.5 + t.fuzz)) as usize;
    for _ in 0..n {
        let len = c.rng.gen_range(1.0..4.0) / MM_PER_PX;
        let hgt = relief * c.rng.gen_range(-0.5..0.4);
        draw_fibre(&mut h, &mut c.rng, len, hgt, 0.9, 0.9);
    }
    h
}

fn felt(c: &mut Ctx) -> Vec<f32> {
    let t = c.t;
    let relief = t.relief_mm;
    let seed = c.seed;
    let mut h = vec![0f32; PATCH * PATCH];
    for y in 0..PATCH {
        for x in 0..PATCH {
            // uneven fibre density (clouds)
            h[y * PATCH + x] =
                -relief + 0.5 * relief * (0.5 + 0.5 * fbm(seed, x as f32, y as f32, 60.0, 4));
        }
    }
    let area = (PATCH as f32 * MM_PER_PX).powi(2);
    let n = (area * 10.0 * (0.4 + t.warp_per_cm / 100.0)) as usize;
    for _ in 0..n {
        let len = c.rng.gen_range(1.5..6.0) / MM_PER_PX;
        let hgt = relief * c.rng.gen_range(-0.7..0.0);
        draw_fibre(
            &mut h,
            &mut c.rng,
            len,
            hgt,
            0.7,
            0.15 + 0.3 * (1.0 - t.stiffness),
        );
    }
    // fibres are pressed into the mat: smooth the mat slightly
    blur(&mut h, PATCH, 1);
    h
}

/// Max-composite a rounded stamp of radius `r` px and crown height `z`.
fn stamp(h: &mut [f32], x: f32, y: f32, r: f32, z: f32) {
    let n = PATCH as i64;
    let x0 = (x - r).floor() as i64;
    let x1 = (x + r).ceil() as i64;
    let y0 = (y - r).floor() as i64;
    let y1 = (y + r).ceil() as i64;
    for yy in y0.max(0)..=y1.min(n - 1) {
        for xx in x0.max(0)..=x1.min(n - 1) {
            let d = (((xx as f32 - x).powi(2) + (yy as f32 - y).powi(2)).sqrt()) / r;
            if d < 1.0 {
                let v = z - (1.0 - crown(d)) * r * MM_PER_PX * 0.8;
                let cell = &mut h[(yy * n + xx) as usize];
                if v > *cell {
                    *cell = v;
                }
            }
        }
    }
}

/// A curved fibre: random start and heading, curvature `curl` rad/mm.
fn draw_fibre(h: &mut [f32], rng: &mut ChaCha8Rng, len: f32, z: f32, r: f32, curl: f32) {
    let mut x = rng.gen_range(0.0..PATCH as f32);
    let mut y = rng.gen_range(0.0..PATCH as f32);
    let mut a = rng.gen_range(0.0..std::f32::consts::TAU);
    let mut da = 0.0f32;
    let steps = (len / 0.7) as usize + 1;
    for _ in 0..steps {
        stamp(h, x, y, r, z);
        da = 0.8 * da + curl * MM_PER_PX * 0.7 * rng.gen_range(-1.0..1.0);
        a += da;
        x += 0.7 * a.cos();
        y += 0.7 * a.sin();
    }
}
