//! Generator 1 of catalogue 2: a textile is a bolt, not a patch.
//!
//! The cloth is a function of position on an unbounded bolt: everything
//! random (yarn positions, thickness, slubs, loops, tufts, fibres, pills) is
//! drawn from hashes of global yarn or cell indices, so any window of the
//! bolt can be rendered on its own and two windows far apart show different
//! cloth of the same construction. A press renders only the raster around
//! its window (`window`), in one of `SWATCHES` swatches (regions of the bolt,
//! each with its own stretch, shear, relief and wear).
//!
//! Wovens and knits are lattices bent by a large-scale bow (the weft is
//! never straight over centimetres) with per-yarn spacing, thickness, wander
//! and slubs, so the lattice's spectral peaks smear as on real cloth.

use crate::catalogue::{mix64, Family, Structure, Textile};
use crate::fabric::{blur, crown, fbm, hash2, smooth, warp_up, HeightField, MM_PER_PX};
use std::f32::consts::{PI, TAU};

/// A region of the bolt.
#[derive(Clone, Debug, PartialEq)]
pub struct Swatch {
    pub index: u32,
    /// Where the swatch lies on the bolt (px).
    pub origin: (f32, f32),
    /// In-plane stretch of the cloth (x, y), about +-5 %.
    pub stretch: [f32; 2],
    /// Shear (px per px).
    pub shear: f32,
    /// Relief scale of this region.
    pub relief_scale: f32,
    /// Pilling (worn region): pills per mm^2 scale, 0 = none.
    pub pilling: f32,
}

/// A light counter-based generator (splitmix64).
pub(crate) struct Sm(u64);

impl Sm {
    pub(crate) fn new(seed: u64) -> Sm {
        Sm(mix64(seed))
    }
    #[inline]
    pub(crate) fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(1);
        mix64(self.0)
    }
    #[inline]
    pub(crate) fn f(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
    #[inline]
    pub(crate) fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * self.f()
    }
    /// A count with mean `mean`.
    pub(crate) fn count(&mut self, mean: f32) -> usize {
        (mean + self.f()).floor().max(0.0) as usize
    }
}

/// Generator of cell (cx, cy) of layer `salt`.
pub(crate) fn cell_rng(seed: u64, salt: u64, cx: i64, cy: i64) -> Sm {
    Sm::new(seed ^ mix64(salt ^ mix64((cx as u64).wrapping_mul(0x9E37_79B9) ^ ((cy as u64) << 32))))
}

/// Uniform -1..1 from (seed, i).
#[inline]
fn dev(seed: u64, i: i64) -> f32 {
    hash2(seed, i, 0x51) * 2.0 - 1.0
}

/// 1D value noise, -1..1.
#[inline]
fn noise1(seed: u64, t: f32) -> f32 {
    let i = t.floor();
    let f = smooth(t - i);
    let a = hash2(seed, i as i64, 7);
    let b = hash2(seed, i as i64 + 1, 7);
    (a + (b - a) * f) * 2.0 - 1.0
}

/// Swatch `k` of a textile's bolt.
pub fn swatch(t: &Textile, k: u32) -> Swatch {
    let mut r = Sm::new(t.micro_seed ^ 0x5_a7c4 ^ (k as u64).wrapping_mul(0x1234_5679));
    let prone = matches!(
        t.fibre,
        crate::catalogue::Fibre::Wool
            | crate::catalogue::Fibre::Acrylic
            | crate::catalogue::Fibre::Cashmere
            | crate::catalogue::Fibre::Polyester
            | crate::catalogue::Fibre::Cotton
    );
    let wear = r.f().powi(2);
    Swatch {
        index: k,
        origin: (
            k as f32 * 3000.0 + r.range(0.0, 500.0),
            r.range(-3000.0, 3000.0),
        ),
        stretch: [1.0 + r.range(-0.05, 0.05), 1.0 + r.range(-0.05, 0.05)],
        shear: r.range(-0.04, 0.04),
        relief_scale: 1.0 + r.range(-0.12, 0.12),
        pilling: if prone { wear * t.fuzz } else { 0.0 },
    }
}

/// The raster of a window of the bolt: `size` x `size` samples at
/// `MM_PER_PX`, sample (x, y) at bolt position (ox + x, oy + y) px.
pub fn window(t: &Textile, sw: &Swatch, ox: i64, oy: i64, size: usize) -> HeightField {
    let g = Grid {
        seed: t.micro_seed ^ 0x0b01_7000,
        ox,
        oy,
        n: size,
    };
    let mut h = match t.structure {
        Structure::Jersey | Structure::Rib { .. } => knit(t, &g),
        Structure::Velvet | Structure::Corduroy { .. } | Structure::Plush => pile(t, &g),
        Structure::Terry { loop_mm } => terry(t, &g, loop_mm),
        Structure::Boucle { loop_mm } => boucle(t, &g, loop_mm),
        Structure::Tufted { tuft_mm } => tufted(t, &g, tuft_mm),
        Structure::Fleece => fleece(t, &g),
        Structure::Felt => felt(t, &g),
        Structure::Blanket => blanket(t, &g),
        Structure::Padded => padded(t, &g),
        _ => woven(t, &g, t.relief_mm),
    };
    let fibrous = matches!(
        t.structure,
        Structure::Felt | Structure::Fleece | Structure::Blanket | Structure::Plush
    );
    if t.fuzz > 0.02 && !fibrous {
        hairiness(t, &g, &mut h);
    }
    if sw.pilling > 0.01 {
        pills(t, &g, &mut h, sw.pilling);
    }
    // Terry loops and tufts are bundles of soft fibres, not hard tubes:
    // their edges are rounded off.
    if matches!(
        t.structure,
        Structure::Terry { .. } | Structure::Tufted { .. }
    ) {
        blur(&mut h, size, 2);
    }
    // Irregular mm-scale relief of wovens and knits (uneven yarn packing,
    // fibre bundles, cockling): on real cloth it outweighs the lattice.
    if matches!(
        t.structure.family(),
        Family::Plain
            | Family::Twill
            | Family::Satin
            | Family::Basket
            | Family::Crepe
            | Family::Knit
            | Family::Rib
    ) {
        let a = t.relief_mm * (0.3 + 0.4 * t.irregularity);
        let field = coarse(&g, 2, |bx, by| fbm(g.seed ^ 79, bx, by, 28.0, 3));
        for (o, f) in h.iter_mut().zip(&field) {
            *o += a * f;
        }
    }
    // irregular low-frequency relief of the cloth lying on the gel
    let und = 0.12 * t.relief_mm;
    let field = coarse(&g, 8, |bx, by| fbm(g.seed ^ 77, bx, by, 110.0, 3));
    for (o, f) in h.iter_mut().zip(&field) {
        *o += und * f;
    }
    HeightField { size, h }
}

/// Where the raster lies on the bolt.
pub(crate) struct Grid {
    pub(crate) seed: u64,
    pub(crate) ox: i64,
    pub(crate) oy: i64,
    pub(crate) n: usize,
}

impl Grid {
    #[inline]
    pub(crate) fn at(&self, x: usize, y: usize) -> (f32, f32) {
        ((self.ox + x as i64) as f32, (self.oy + y as i64) as f32)
    }
    /// Cells of side `cell` px overlapping the raster plus `margin` px.
    pub(crate) fn cells(&self, cell: f32, margin: f32) -> impl Iterator<Item = (i64, i64)> {
        let x0 = ((self.ox as f32 - margin) / cell).floor() as i64;
        let x1 = ((self.ox as f32 + self.n as f32 + margin) / cell).floor() as i64;
        let y0 = ((self.oy as f32 - margin) / cell).floor() as i64;
        let y1 = ((self.oy as f32 + self.n as f32 + margin) / cell).floor() as i64;
        (y0..=y1).flat_map(move |cy| (x0..=x1).map(move |cx| (cx, cy)))
    }
    /// Max-composite a rounded stamp at bolt position (x, y).
    pub(crate) fn stamp(&self, h: &mut [f32], x: f32, y: f32, r: f32, z: f32) {
        let n = self.n as i64;
        let (lx, ly) = (x - self.ox as f32, y - self.oy as f32);
        let x0 = (lx - r).floor() as i64;
        let x1 = (lx + r).ceil() as i64;
        let y0 = (ly - r).floor() as i64;
        let y1 = (ly + r).ceil() as i64;
        if x1 < 0 || y1 < 0 || x0 >= n || y0 >= n {
            return;
        }
        for yy in y0.max(0)..=y1.min(n - 1) {
            for xx in x0.max(0)..=x1.min(n - 1) {
                let d = (((xx as f32 - lx).powi(2) + (yy as f32 - ly).powi(2)).sqrt()) / r;
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
    /// A curved fibre from bolt position (x, y).
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn fibre(
        &self,
        h: &mut [f32],
        rng: &mut Sm,
        mut x: f32,
        mut y: f32,
        len: f32,
        z: f32,
        r: f32,
        curl: f32,
    ) {
        let mut a = rng.range(0.0, TAU);
        let mut da = 0.0f32;
        let steps = (len / 0.7) as usize + 1;
        for _ in 0..steps {
            self.stamp(h, x, y, r, z);
            da = 0.8 * da + curl * MM_PER_PX * 0.7 * rng.range(-1.0, 1.0);
            a += da;
            x += 0.7 * a.cos();
            y += 0.7 * a.sin();
        }
    }
}

/// A smooth field evaluated every `step` px of the raster and interpolated
/// bilinearly (the low-frequency fields cost little this way).
fn coarse(g: &Grid, step: usize, f: impl Fn(f32, f32) -> f32) -> Vec<f32> {
    let n = g.n;
    let m = n / step + 2;
    let grid: Vec<f32> = (0..m * m)
        .map(|k| {
            let (i, j) = (k % m, k / m);
            f(
                (g.ox + (i * step) as i64) as f32,
                (g.oy + (j * step) as i64) as f32,
            )
        })
        .collect();
    let mut out = vec![0f32; n * n];
    let inv = 1.0 / step as f32;
    for y in 0..n {
        let (j, fy) = (y / step, (y % step) as f32 * inv);
        for x in 0..n {
            let (i, fx) = (x / step, (x % step) as f32 * inv);
            let a = grid[j * m + i] + (grid[j * m + i + 1] - grid[j * m + i]) * fx;
            let b =
                grid[(j + 1) * m + i] + (grid[(j + 1) * m + i + 1] - grid[(j + 1) * m + i]) * fx;
            out[y * n + x] = a + (b - a) * fy;
        }
    }
    out
}

/// Woven cloth with irregular yarns (also gauze, ripstop, crepe, satin ...).
fn woven(t: &Textile, g: &Grid, relief: f32) -> Vec<f32> {
    let n = g.n;
    let sx = 10.0 / t.warp_per_cm / MM_PER_PX;
    let sy = 10.0 / t.weft_per_cm / MM_PER_PX;
    let dw = t.yarn_diameter_mm / MM_PER_PX;
    let irr = t.irregularity;
    let seed = g.seed;
    let crepe = matches!(t.structure, Structure::Crepe);
    let gauze = matches!(t.structure, Structure::Gauze);
    let ripstop = match t.structure {
        Structure::Ripstop { grid } => grid as i64,
        _ => 0,
    };
    let rule = if gauze { Structure::Plain } else { t.structure };
    // bow of the lattice over centimetres, in px
    let open = if gauze { 0.35 } else { 1.0 };
    let bow_x = (sx * (0.5 + 1.5 * irr) * open + 2.0).min(14.0);
    let bow_y = (sy * (0.5 + 1.5 * irr) * open + 2.0).min(14.0);
    let sp_sd = 0.1 + 0.2 * irr;
    let th_sd = 0.08 + 0.25 * irr;
    let wander = 0.08 + 0.15 * irr;
    // yarn height varies from crossing to crossing (tension, packing)
    let cross_sd = if gauze { 0.1 } else { 0.25 + 0.35 * irr };
    let twist = if crepe { 0.9 } else { 0.35 };
    let floor = if gauze { -1.6 * relief } else { -relief };
    let mut h = vec![0f32; n * n];
    let mid_x = sx * (0.3 + 0.4 * irr) * open;
    let mid_y = sy * (0.3 + 0.4 * irr) * open;
    let bxf = coarse(g, 4, |bx, by| {
        bow_x * fbm(seed ^ 21, bx, by, 170.0, 2) + mid_x * fbm(seed ^ 23, bx, by, 45.0, 2)
    });
    let byf = coarse(g, 4, |bx, by| {
        bow_y * fbm(seed ^ 22, bx, by, 170.0, 2) + mid_y * fbm(seed ^ 24, bx, by, 45.0, 2)
    });
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            let xw = bx + bxf[y * n + x];
            let yw = by + byf[y * n + x];
            let gi = xw / sx;
            let gj = yw / sy;
            let (i0, j0) = (gi.floor() as i64, gj.floor() as i64);
            let v = gj - j0 as f32 - 0.5;
            let u = gi - i0 as f32 - 0.5;
            let mut best_w = f32::MIN;
            for i in i0 - 1..=i0 + 1 {
                let ci = (i as f32
                    + 0.5
                    + sp_sd * dev(seed ^ 31, i)
                    + wander * noise1(seed ^ 32 ^ (i as u64).wrapping_mul(7919), yw / 40.0))
                    * sx;
                let rip = if ripstop > 0 && i.rem_euclid(ripstop) == 0 {
                    1.5
                } else {
                    1.0
                };
                let th = (1.0 + th_sd * dev(seed ^ 33, i))
                    * (1.0
                        + irr
                            * 0.4
                            * noise1(seed ^ 34 ^ (i as u64).wrapping_mul(104_729), yw / 18.0))
                    * rip;
                let half = (0.5 * dw * th).max(0.5);
                let d = (xw - ci) / half;
                if d.abs() >= 1.0 {
                    continue;
                }
                let jn = if v < 0.0 { j0 - 1 } else { j0 + 1 };
                let up_here = warp_up(&rule, i, j0) as i32 as f32;
                let up_next = warp_up(&rule, i, jn) as i32 as f32;
                let tv = smooth(v.abs() * 2.0) * 0.5;
                let up = up_here + (up_next - up_here) * tv;
                let tw = 1.0
                    - 0.12 * (1.0 + ((yw + (xw - ci) * twist) / (dw * 0.45).max(0.8)).sin()) * 0.5;
                let cross = 1.0 + cross_sd * (hash2(seed ^ 35, i, j0) * 2.0 - 1.0);
                let hw =
                    relief * (0.5 * (2.0 * up - 1.0)) + relief * 0.5 * crown(d) * th * tw * cross;
                best_w = best_w.max(hw);
            }
            let mut best_f = f32::MIN;
            for j in j0 - 1..=j0 + 1 {
                let cj = (j as f32
                    + 0.5
                    + sp_sd * dev(seed ^ 41, j)
                    + wander * noise1(seed ^ 42 ^ (j as u64).wrapping_mul(7919), xw / 40.0))
                    * sy;
                let rip = if ripstop > 0 && j.rem_euclid(ripstop) == 0 {
                    1.5
                } else {
                    1.0
                };
                let th = (1.0 + th_sd * dev(seed ^ 43, j))
                    * (1.0
                        + irr
                            * 0.4
                            * noise1(seed ^ 44 ^ (j as u64).wrapping_mul(104_729), xw / 18.0))
                    * rip;
                let half = (0.5 * dw * th).max(0.5);
                let d = (yw - cj) / half;
                if d.abs() >= 1.0 {
                    continue;
                }
                let im = if u < 0.0 { i0 - 1 } else { i0 + 1 };
                let fup_here = 1.0 - warp_up(&rule, i0, j) as i32 as f32;
                let fup_next = 1.0 - warp_up(&rule, im, j) as i32 as f32;
                let tu = smooth(u.abs() * 2.0) * 0.5;
                let up = fup_here + (fup_next - fup_here) * tu;
                let tw = 1.0
                    - 0.12 * (1.0 + ((xw + (yw - cj) * twist) / (dw * 0.45).max(0.8)).sin()) * 0.5;
                let cross = 1.0 + cross_sd * (hash2(seed ^ 45, i0, j) * 2.0 - 1.0);
                let hf =
                    relief * (0.5 * (2.0 * up - 1.0)) + relief * 0.5 * crown(d) * th * tw * cross;
                best_f = best_f.max(hf);
            }
            let mut z = best_w.max(best_f).max(floor);
            if crepe {
                z += relief * 0.35 * fbm(seed ^ 3, bx, by, 6.0, 2);
            }
            h[y * n + x] = z;
        }
    }
    h
}

/// Knits with per-wale wander, per-stitch loop size and tension.
fn knit(t: &Textile, g: &Grid) -> Vec<f32> {
    let n = g.n;
    let sw = 10.0 / t.warp_per_cm / MM_PER_PX;
    let sc = 10.0 / t.weft_per_cm / MM_PER_PX;
    let hw = 0.5 * t.yarn_diameter_mm / MM_PER_PX;
    let relief = t.relief_mm;
    let (knit_n, purl_n) = match t.structure {
        Structure::Rib { knit, purl } => (knit as i64, purl as i64),
        _ => (1, 0),
    };
    let seed = g.seed;
    let irr = t.irregularity;
    let bow = (sw * (0.8 + 1.5 * irr) + 3.0).min(20.0);
    let loop_sd = 0.15 + 0.35 * irr;
    let mut h = vec![0f32; n * n];
    let mid_w = sw * (0.35 + 0.5 * irr);
    let mid_c = sc * (0.35 + 0.5 * irr);
    let bxf = coarse(g, 4, |bx, by| {
        bow * fbm(seed ^ 5, bx, by, 150.0, 2) + mid_w * fbm(seed ^ 7, bx, by, 40.0, 2)
    });
    let byf = coarse(g, 4, |bx, by| {
        bow * fbm(seed ^ 6, bx, by, 150.0, 2) + mid_c * fbm(seed ^ 8, bx, by, 40.0, 2)
    });
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            let xw = bx + bxf[y * n + x];
            let yw = by + byf[y * n + x];
            let gi = xw / sw;
            let i = gi.floor() as i64;
            let u =
                gi - i as f32 + 0.12 * noise1(seed ^ 51 ^ (i as u64).wrapping_mul(7919), yw / 30.0);
            let gj =
                yw / sc + 0.15 * noise1(seed ^ 55 ^ (i as u64).wrapping_mul(104_729), yw / 25.0);
            let j = gj.floor() as i64;
            let v = gj - j as f32;
            let period = knit_n + purl_n;
            let is_purl = purl_n > 0 && i.rem_euclid(period) >= knit_n;
            let stitch = hash2(seed ^ 52, i, j) * 2.0 - 1.0;
            let ls = 1.0 + loop_sd * stitch;
            let hf = 1.0 + 0.35 * (0.5 + irr) * (hash2(seed ^ 53, i, j) * 2.0 - 1.0);
            let shift = 0.15 * (hash2(seed ^ 56, i, j) * 2.0 - 1.0);
            let thick =
                1.0 + irr * 0.3 * noise1(seed ^ 54 ^ (j as u64).wrapping_mul(13), xw / 20.0);
            let z = if !is_purl {
                let off = (0.23 - 0.16 * v) * ls;
                let (ul, ur) = (0.5 + shift - off, 0.5 + shift + off);
                let dl = (u - ul).abs() * sw / (hw * thick).max(0.5);
                let dr = (u - ur).abs() * sw / (hw * thick).max(0.5);
                let leg = crown(dl).max(crown(dr));
                let dip = 0.75 + 0.25 * (PI * v).sin();
                relief * (leg * dip * hf - 0.2)
            } else {
                let dv = (v - 0.5).abs() * sc / (hw * thick).max(0.5);
                let du = ((u - 0.5) * 2.0).abs();
                relief * (0.75 * crown(dv) * (1.0 - 0.4 * du * du) * hf - 0.55)
            };
            h[y * n + x] = z;
        }
    }
    h
}

/// Cut pile (velvet, corduroy) and long plush: random tips, crushed
/// patches, nap streaks along a wandering nap direction.
fn pile(t: &Textile, g: &Grid) -> Vec<f32> {
    let n = g.n;
    let seed = g.seed;
    let relief = t.relief_mm;
    let tuft = (10.0 / t.warp_per_cm / MM_PER_PX).max(1.5);
    let plush = matches!(t.structure, Structure::Plush);
    let mut tips = vec![-relief; n * n];
    let nap0 = hash2(seed, 3, 3) * TAU;
    let crush = |x: f32, y: f32| 1.0 - 0.45 * fbm(seed ^ 31, x, y, 90.0, 3).max(0.0);
    if plush {
        let cell = 24.0;
        for (cx, cy) in g.cells(cell, 40.0) {
            let mut r = cell_rng(seed, 0x9100, cx, cy);
            let k = r.count(cell * cell * MM_PER_PX * MM_PER_PX * 9.0);
            for _ in 0..k {
                let x = (cx as f32 + r.f()) * cell;
                let y = (cy as f32 + r.f()) * cell;
                let a = nap0 + 1.2 * fbm(seed ^ 33, x, y, 120.0, 2) + r.range(-0.3, 0.3);
                let len = r.range(0.8, 2.5) / MM_PER_PX;
                let z = relief * r.range(0.3, 1.0) * crush(x, y);
                let steps = (len / 0.8) as usize + 1;
                let (mut px, mut py) = (x, y);
                for s in 0..steps {
                    // fibres lie down: the free end is highest
                    let zz = z * (0.6 + 0.4 * s as f32 / steps as f32);
                    g.stamp(&mut tips, px, py, 1.1, zz);
                    px += 0.8 * a.cos();
                    py += 0.8 * a.sin();
                }
            }
        }
    } else {
        let cell = tuft * 1.3;
        let r_tip = (0.35 * tuft).clamp(0.7, 2.5);
        for (cx, cy) in g.cells(cell, 4.0) {
            let mut r = cell_rng(seed, 0x9200, cx, cy);
            let k = r.count(1.6 * 1.69);
            for _ in 0..k {
                let x = (cx as f32 + r.f()) * cell;
                let y = (cy as f32 + r.f()) * cell;
                let z = relief * r.range(0.3, 1.0) * crush(x, y);
                g.stamp(&mut tips, x, y, r_tip, z);
            }
        }
    }
    blur(&mut tips, n, 1);
    let wale = match t.structure {
        Structure::Corduroy { wale_mm } => Some(wale_mm / MM_PER_PX),
        _ => None,
    };
    let napf = coarse(g, 8, |bx, by| nap0 + 0.8 * fbm(seed ^ 35, bx, by, 200.0, 2));
    let walef = coarse(g, 8, |bx, by| fbm(seed ^ 36, bx, by, 200.0, 2));
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            let nap_dir = napf[y * n + x];
            let along = bx * nap_dir.cos() + by * nap_dir.sin();
            let across = -bx * nap_dir.sin() + by * nap_dir.cos();
            let nap = 0.35 * relief * fbm(seed ^ 9, along / 6.0, across, 8.0, 3);
            let mut z = tips[y * n + x] + nap;
            if let Some(w) = wale {
                let xw = bx + 0.15 * w * walef[y * n + x];
                let k = (xw / w).floor() as i64;
                let ww = 1.0 + 0.1 * dev(seed ^ 37, k);
                let p = (xw / w).fract();
                let ridge = crown((p - 0.5) * 2.0 / (0.85 * ww).min(0.98));
                z = z * (0.3 + 0.7 * ridge) + t.thickness_mm * 0.5 * (ridge - 1.0);
            }
            tips[y * n + x] = z;
        }
    }
    tips
}

/// Terry: a bowed ground weave with standing loops of random size, squash,
/// orientation and height; some missing, some pulled.
fn terry(t: &Textile, g: &Grid, loop_mm: f32) -> Vec<f32> {
    let n = g.n;
    let relief = t.relief_mm;
    let seed = g.seed;
    let mut h = vec![0f32; n * n];
    let gs = 10.0 / 25.0 / MM_PER_PX;
    let wf = coarse(g, 8, |bx, by| 4.0 * fbm(seed ^ 61, bx, by, 120.0, 2));
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            let xw = bx + wf[y * n + x];
            let u = (xw / gs).fract() - 0.5;
            let v = (by / gs).fract() - 0.5;
            h[y * n + x] = -relief
                + 0.15 * relief * (crown(u * 2.0).max(crown(v * 2.0)))
                + 0.05 * relief * fbm(seed, bx, by, 20.0, 2);
        }
    }
    let spacing = 10.0 / t.warp_per_cm / MM_PER_PX;
    let yarn_r = (0.5 * t.yarn_diameter_mm / MM_PER_PX).max(1.0);
    let rad = 0.5 * loop_mm / MM_PER_PX;
    for (cx, cy) in g.cells(spacing, rad * 1.6 + 4.0) {
        let mut r = cell_rng(seed, 0x7e77, cx, cy);
        if r.f() > 0.88 {
            continue;
        }
        let pulled = r.f() < 0.05;
        let ccx = (cx as f32 + 0.5 + r.range(-0.45, 0.45)) * spacing;
        let ccy = (cy as f32 + 0.5 + r.range(-0.45, 0.45)) * spacing;
        let ang = r.range(0.0, PI);
        let squash = r.range(0.2, 0.9);
        let rr = rad * r.range(0.7, 1.3) * if pulled { 1.3 } else { 1.0 };
        let hgt = relief * r.range(0.45, 1.0) * if pulled { 1.3 } else { 1.0 };
        let steps = (TAU * rr / 0.7) as usize + 4;
        for s in 0..steps {
            let a = s as f32 / steps as f32 * TAU;
            let (lx, ly) = (rr * a.cos(), rr * squash * a.sin());
            let x = ccx + lx * ang.cos() - ly * ang.sin();
            let y = ccy + lx * ang.sin() + ly * ang.cos();
            let zz = -relief + (hgt + relief) * (0.55 + 0.45 * a.sin());
            g.stamp(&mut h, x, y, yarn_r, zz);
        }
    }
    h
}

/// Boucle: a low ground covered in irregular curly loops of a thick yarn.
fn boucle(t: &Textile, g: &Grid, loop_mm: f32) -> Vec<f32> {
    let n = g.n;
    let relief = t.relief_mm;
    let seed = g.seed;
    let mut h = vec![0f32; n * n];
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            h[y * n + x] = -relief + 0.2 * relief * fbm(seed ^ 71, bx, by, 10.0, 3);
        }
    }
    let cell = loop_mm / MM_PER_PX;
    let yarn_r = (0.5 * t.yarn_diameter_mm / MM_PER_PX).clamp(1.0, 4.0);
    for (cx, cy) in g.cells(cell, cell * 2.5) {
        let mut r = cell_rng(seed, 0xb0c1, cx, cy);
        let k = r.count(1.4);
        for _ in 0..k {
            let mut x = (cx as f32 + r.f()) * cell;
            let mut y = (cy as f32 + r.f()) * cell;
            let rl = 0.5 * cell * r.range(0.5, 1.2);
            let turn = 0.7 / rl.max(1.0) * if r.f() < 0.5 { 1.0 } else { -1.0 };
            let len = TAU * rl * r.range(1.0, 2.5);
            let mut a = r.range(0.0, TAU);
            let hgt = relief * r.range(0.5, 1.0);
            let ph = r.range(0.0, TAU);
            let steps = (len / 0.7) as usize + 1;
            for s in 0..steps {
                let zz = -0.2 * relief
                    + (hgt + 0.2 * relief) * (0.6 + 0.4 * (ph + s as f32 * 0.08).sin());
                g.stamp(&mut h, x, y, yarn_r, zz);
                a += turn * (1.0 + 0.6 * r.range(-1.0, 1.0));
                x += 0.7 * a.cos();
                y += 0.7 * a.sin();
            }
        }
    }
    h
}

/// Tufted pile in wandering rows: clusters of cut tips, or loops (loop
/// pile), of random height per tuft.
fn tufted(t: &Textile, g: &Grid, tuft_mm: f32) -> Vec<f32> {
    let n = g.n;
    let relief = t.relief_mm;
    let seed = g.seed;
    let loop_pile = t.micro_seed & 1 == 1;
    let mut h = vec![-relief; n * n];
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            h[y * n + x] = -relief + 0.1 * relief * fbm(seed ^ 81, bx, by, 8.0, 2);
        }
    }
    let row = tuft_mm / MM_PER_PX;
    let along = row * 0.65;
    let tip_r = (0.5 * t.yarn_diameter_mm / MM_PER_PX).clamp(1.2, 3.0);
    let spread = row * 0.35;
    for (cx, cy) in g.cells(row, row) {
        // one row per cell row, tufts along it
        let mut r = cell_rng(seed, 0x7f7f, cx, cy);
        let per = (row / along).max(1.0);
        let k = r.count(per);
        for _ in 0..k {
            let tx = (cx as f32 + r.f()) * row;
            let ty = (cy as f32 + 0.5) * row
                + 0.2 * row * fbm(seed ^ 83, tx, cy as f32 * row, 80.0, 2)
                + r.range(-0.12, 0.12) * row;
            let th = relief * r.range(0.6, 1.0);
            if loop_pile {
                let rr = spread * r.range(0.6, 1.0);
                let sq = r.range(0.3, 0.8);
                let ang = r.range(0.0, PI);
                let steps = (TAU * rr / 0.8) as usize + 4;
                for s in 0..steps {
                    let a = s as f32 / steps as f32 * TAU;
                    let (lx, ly) = (rr * a.cos(), rr * sq * a.sin());
                    let x = tx + lx * ang.cos() - ly * ang.sin();
                    let y = ty + lx * ang.sin() + ly * ang.cos();
                    g.stamp(&mut h, x, y, tip_r, th * (0.7 + 0.3 * a.sin()));
                }
            } else {
                let tips = 5 + (r.f() * 8.0) as usize;
                for _ in 0..tips {
                    let a = r.range(0.0, TAU);
                    let d = spread * r.f().sqrt();
                    g.stamp(
                        &mut h,
                        tx + d * a.cos(),
                        ty + d * a.sin(),
                        tip_r * r.range(0.7, 1.2),
                        th * r.range(0.7, 1.0),
                    );
                }
            }
        }
    }
    blur(&mut h, n, 1);
    h
}

/// Fleece: brushed soft bumps and many curly fibres.
fn fleece(t: &Textile, g: &Grid) -> Vec<f32> {
    let n = g.n;
    let relief = t.relief_mm;
    let seed = g.seed;
    let mut h = vec![0f32; n * n];
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            h[y * n + x] = -relief + 0.6 * relief * (0.5 + 0.5 * fbm(seed, bx, by, 14.0, 3));
        }
    }
    let cell = 40.0;
    let per = cell * cell * MM_PER_PX * MM_PER_PX * 6.0 * (0.5 + t.fuzz);
    for (cx, cy) in g.cells(cell, 50.0) {
        let mut r = cell_rng(seed, 0xf1ee, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell;
            let y = (cy as f32 + r.f()) * cell;
            let len = r.range(1.0, 4.0) / MM_PER_PX;
            let hgt = relief * r.range(-0.5, 0.4);
            g.fibre(&mut h, &mut r, x, y, len, hgt, 0.9, 0.9);
        }
    }
    h
}

/// Felt: cloudy density and straight-ish fibres pressed into the mat.
fn felt(t: &Textile, g: &Grid) -> Vec<f32> {
    let n = g.n;
    let relief = t.relief_mm;
    let seed = g.seed;
    let mut h = vec![0f32; n * n];
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            h[y * n + x] = -relief + 0.5 * relief * (0.5 + 0.5 * fbm(seed, bx, by, 60.0, 4));
        }
    }
    let cell = 48.0;
    let per = cell * cell * MM_PER_PX * MM_PER_PX * 10.0 * (0.4 + t.warp_per_cm / 100.0);
    for (cx, cy) in g.cells(cell, 40.0) {
        let mut r = cell_rng(seed, 0xfe17, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell;
            let y = (cy as f32 + r.f()) * cell;
            let len = r.range(1.5, 6.0) / MM_PER_PX;
            let hgt = relief * r.range(-0.7, 0.0);
            g.fibre(
                &mut h,
                &mut r,
                x,
                y,
                len,
                hgt,
                0.7,
                0.15 + 0.3 * (1.0 - t.stiffness),
            );
        }
    }
    blur(&mut h, n, 1);
    h
}

/// A brushed blanket: a dense, even mat of fine fibres over soft bumps; under
/// the gel almost nothing shows.
fn blanket(t: &Textile, g: &Grid) -> Vec<f32> {
    let n = g.n;
    let relief = t.relief_mm;
    let seed = g.seed;
    let mut h = vec![0f32; n * n];
    for y in 0..n {
        for x in 0..n {
            let (bx, by) = g.at(x, y);
            h[y * n + x] = -relief + 0.5 * relief * fbm(seed ^ 91, bx, by, 35.0, 3);
        }
    }
    let cell = 40.0;
    let per = cell * cell * MM_PER_PX * MM_PER_PX * 4.0;
    for (cx, cy) in g.cells(cell, 40.0) {
        let mut r = cell_rng(seed, 0xb1a7, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell;
            let y = (cy as f32 + r.f()) * cell;
            let len = r.range(1.0, 3.0) / MM_PER_PX;
            let hgt = relief * r.range(-0.6, 0.1);
            g.fibre(&mut h, &mut r, x, y, len, hgt, 0.8, 0.8);
        }
    }
    blur(&mut h, n, 2);
    h
}

/// A fine woven cover over soft padding: a faint weave and slow undulation.
fn padded(t: &Textile, g: &Grid) -> Vec<f32> {
    let n = g.n;
    let mut h = woven(t, g, t.relief_mm);
    let seed = g.seed;
    let f = coarse(g, 4, |bx, by| fbm(seed ^ 95, bx, by, 60.0, 3));
    for (o, v) in h.iter_mut().zip(&f) {
        *o += 0.6 * t.relief_mm * v;
    }
    let _ = n;
    h
}

/// Loose fibres on wovens and knits: count from fuzz, curl from stiffness.
fn hairiness(t: &Textile, g: &Grid, h: &mut [f32]) {
    let cell = 40.0;
    let per = t.fuzz * 2.5 * cell * cell * MM_PER_PX * MM_PER_PX;
    let top = t.relief_mm;
    let rad = 0.6 + t.fuzz * 0.5;
    let curl = 0.25 + 0.5 * (1.0 - t.stiffness);
    for (cx, cy) in g.cells(cell, 2.0 / MM_PER_PX) {
        let mut r = cell_rng(g.seed, 0x4a1e, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell;
            let y = (cy as f32 + r.f()) * cell;
            let len = r.range(0.4, 2.0) / MM_PER_PX;
            let hgt = top * r.range(0.2, 0.9);
            g.fibre(h, &mut r, x, y, len, hgt, rad, curl);
        }
    }
}

/// Pills: small balls of tangled fibre on worn regions.
fn pills(t: &Textile, g: &Grid, h: &mut [f32], pilling: f32) {
    let cell = 64.0;
    let per = pilling * 0.3 * cell * cell * MM_PER_PX * MM_PER_PX;
    let top = t.relief_mm;
    for (cx, cy) in g.cells(cell, 8.0) {
        let mut r = cell_rng(g.seed, 0x9111, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell;
            let y = (cy as f32 + r.f()) * cell;
            let rad = r.range(2.5, 6.0);
            let z = top * r.range(0.8, 1.4) + rad * MM_PER_PX * 0.5;
            g.stamp(h, x, y, rad, z);
            for _ in 0..3 {
                let len = r.range(0.3, 0.8) / MM_PER_PX;
                g.fibre(h, &mut r, x, y, len, z * 0.8, 0.6, 1.0);
            }
        }
    }
}
