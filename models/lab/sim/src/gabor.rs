//! Generator 2 of catalogue 2: an independent texture construction for the
//! cross-generator test set.
//!
//! Nothing here draws yarns: the cloth is sparse-convolution Gabor noise
//! (randomly placed, oriented and phased Gabor kernels whose orientations and
//! frequencies follow the textile's structure and counts), shaped by a
//! family-specific nonlinearity, plus spot noise of Gaussian bumps for
//! loops, tufts and pills, elongated Gaussian streaks for loose fibres and
//! nap, and a low-frequency Gabor layer for the cloth's undulation. A method
//! chosen on generator 1 (`bolt`) and reported on generator 2 has not seen
//! the way its test textures were made.

use crate::bolt::{cell_rng, Grid, Sm, Swatch};
use crate::catalogue::{Family, Structure, Textile};
use crate::fabric::{HeightField, MM_PER_PX};
use std::f32::consts::{PI, TAU};

/// One Gabor layer: orientations (radians, weight), frequency (cycles/px),
/// kernel radius (px), kernels overlapping a point.
struct Layer {
    orients: Vec<(f32, f32)>,
    freq: f32,
    radius: f32,
    overlap: f32,
    /// Orientation jitter (radians).
    jitter: f32,
    salt: u64,
}

/// Accumulate a sparse Gabor noise layer into `out` (zero-mean, unnormalised).
fn gabor_layer(g: &Grid, l: &Layer, out: &mut [f32]) {
    let n = g.n as i64;
    let rad = l.radius.max(2.0);
    let ri = rad.ceil() as i64;
    let sigma = rad / 2.5;
    let side = (2 * ri + 1) as usize;
    let env: Vec<f32> = (0..side * side)
        .map(|k| {
            let (dx, dy) = ((k % side) as f32 - ri as f32, (k / side) as f32 - ri as f32);
            let r2 = dx * dx + dy * dy;
            if r2 > rad * rad {
                0.0
            } else {
                (-r2 / (2.0 * sigma * sigma)).exp()
            }
        })
        .collect();
    let total_w: f32 = l.orients.iter().map(|o| o.1).sum::<f32>().max(1e-6);
    let cell = rad;
    let per = l.overlap * cell * cell / (PI * rad * rad);
    let mut ex = vec![(0f32, 0f32); side];
    let mut ey = vec![(0f32, 0f32); side];
    for (cx, cy) in g.cells(cell, rad) {
        let mut r = cell_rng(g.seed, l.salt, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell;
            let y = (cy as f32 + r.f()) * cell;
            let mut pick = r.f() * total_w;
            let mut th = l.orients[0].0;
            for &(o, w) in &l.orients {
                if pick < w {
                    th = o;
                    break;
                }
                pick -= w;
            }
            th += l.jitter * (r.f() + r.f() + r.f() - 1.5);
            let f = l.freq * (1.0 + 0.08 * (r.f() + r.f() - 1.0));
            let ph = r.range(0.0, TAU);
            let w = if r.f() < 0.5 { -1.0 } else { 1.0 } * r.range(0.5, 1.0);
            let (kx, ky) = (TAU * f * th.cos(), TAU * f * th.sin());
            let (lx, ly) = (x - g.ox as f32, y - g.oy as f32);
            let (px, py) = (lx.round() as i64, ly.round() as i64);
            if px + ri < 0 || py + ri < 0 || px - ri >= n || py - ri >= n {
                continue;
            }
            for k in 0..side {
                let d = (k as i64 - ri) as f32;
                let ax = kx * (px as f32 + d - lx);
                ex[k] = (ax.cos(), ax.sin());
                let ay = ky * (py as f32 + d - ly) + ph;
                ey[k] = (ay.cos(), ay.sin());
            }
            for (ky_, (cy_, sy_)) in ey.iter().enumerate() {
                let yy = py + ky_ as i64 - ri;
                if yy < 0 || yy >= n {
                    continue;
                }
                let row = &mut out[(yy * n) as usize..((yy + 1) * n) as usize];
                let erow = &env[ky_ * side..(ky_ + 1) * side];
                for (kx_, (cx_, sx_)) in ex.iter().enumerate() {
                    let xx = px + kx_ as i64 - ri;
                    if xx < 0 || xx >= n {
                        continue;
                    }
                    // Re(e^{i ax} e^{i ay})
                    let c = cx_ * cy_ - sx_ * sy_;
                    row[xx as usize] += w * erow[kx_] * c;
                }
            }
        }
    }
}

/// Spot noise: Gaussian bumps of radius `r` (px), heights 0.4..1, mean
/// `per_mm2` per mm^2, max-composited.
fn spots(g: &Grid, out: &mut [f32], r_px: f32, per_mm2: f32, salt: u64) {
    let n = g.n as i64;
    let cell = (3.0 * r_px).max(8.0);
    let per = per_mm2 * cell * cell * MM_PER_PX * MM_PER_PX;
    for (cx, cy) in g.cells(cell, 2.0 * r_px) {
        let mut r = cell_rng(g.seed, salt, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell - g.ox as f32;
            let y = (cy as f32 + r.f()) * cell - g.oy as f32;
            let rr = r_px * r.range(0.6, 1.4);
            let sq = r.range(0.4, 1.0);
            let ang = r.range(0.0, PI);
            let hgt = r.range(0.4, 1.0);
            let (sn, cs) = ang.sin_cos();
            let ext = (1.6 * rr).ceil() as i64;
            for yy in (y as i64 - ext).max(0)..=(y as i64 + ext).min(n - 1) {
                for xx in (x as i64 - ext).max(0)..=(x as i64 + ext).min(n - 1) {
                    let (dx, dy) = (xx as f32 - x, yy as f32 - y);
                    let (a, b) = (dx * cs + dy * sn, (-dx * sn + dy * cs) / sq);
                    let v = hgt * (-(a * a + b * b) / (2.0 * rr * rr * 0.35)).exp();
                    let o = &mut out[(yy * n + xx) as usize];
                    if v > *o {
                        *o = v;
                    }
                }
            }
        }
    }
}

/// Elongated Gaussian streaks (loose fibres, nap): length `len` px, mean
/// `per_mm2` per mm^2 around direction `dir` (None: any direction), added.
fn streaks(g: &Grid, out: &mut [f32], len: f32, per_mm2: f32, dir: Option<f32>, salt: u64) {
    let n = g.n as i64;
    let cell = 32.0;
    let per = per_mm2 * cell * cell * MM_PER_PX * MM_PER_PX;
    for (cx, cy) in g.cells(cell, len) {
        let mut r = cell_rng(g.seed, salt, cx, cy);
        for _ in 0..r.count(per) {
            let x = (cx as f32 + r.f()) * cell - g.ox as f32;
            let y = (cy as f32 + r.f()) * cell - g.oy as f32;
            let a = match dir {
                Some(d) => d + 0.3 * (r.f() - 0.5),
                None => r.range(0.0, PI),
            };
            let l = len * r.range(0.5, 1.5);
            let hgt = r.range(0.3, 1.0);
            let (sn, cs) = a.sin_cos();
            let ext = (l * 0.8).ceil() as i64;
            for yy in (y as i64 - ext).max(0)..=(y as i64 + ext).min(n - 1) {
                for xx in (x as i64 - ext).max(0)..=(x as i64 + ext).min(n - 1) {
                    let (dx, dy) = (xx as f32 - x, yy as f32 - y);
                    let along = dx * cs + dy * sn;
                    let across = -dx * sn + dy * cs;
                    if across.abs() > 2.5 {
                        continue;
                    }
                    let v = hgt
                        * (-(along * along) / (2.0 * (0.35 * l).powi(2))).exp()
                        * (-(across * across) / 1.2).exp();
                    out[(yy * n + xx) as usize] += v;
                }
            }
        }
    }
}

fn normalise(v: &mut [f32]) {
    let m = v.iter().sum::<f32>() / v.len() as f32;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f32>() / v.len() as f32;
    let s = 1.0 / var.sqrt().max(1e-9);
    for x in v.iter_mut() {
        *x = (*x - m) * s;
    }
}

/// The raster of a window of the textile by generator 2 (same contract as
/// `bolt::window`).
pub fn window(t: &Textile, sw: &Swatch, ox: i64, oy: i64, size: usize) -> HeightField {
    let g = Grid {
        seed: t.micro_seed ^ 0x6ab0_0002 ^ (sw.index as u64).wrapping_mul(0x0001_0000_0001),
        ox,
        oy,
        n: size,
    };
    let mut base = Sm::new(t.micro_seed ^ 0x6ab0);
    let th0 = base.range(0.0, PI);
    let sx = 10.0 / t.warp_per_cm / MM_PER_PX;
    let sy = 10.0 / t.weft_per_cm / MM_PER_PX;
    let relief = t.relief_mm;
    let fam = t.structure.family();
    let n2 = size * size;
    let mut tex = vec![0f32; n2];
    let cross = |wx: f32, wy: f32| vec![(th0, wx), (th0 + PI / 2.0, wy)];
    // (layer, nonlinearity gain: 0 = linear), relief share
    let (layers, sharp, share): (Vec<Layer>, f32, f32) = match (fam, t.structure) {
        (Family::Plain | Family::Basket | Family::Satin | Family::Twill | Family::Crepe, s) => {
            let group = match s {
                Structure::Basket { group } => group as f32,
                _ => 1.0,
            };
            let mut ls = vec![
                Layer {
                    orients: vec![(th0, 1.0)],
                    freq: 1.0 / (2.0 * sx * group),
                    radius: 3.0 * sx * group,
                    overlap: 10.0,
                    jitter: 0.12 + 0.2 * t.irregularity,
                    salt: 1,
                },
                Layer {
                    orients: vec![(th0 + PI / 2.0, 1.0)],
                    freq: 1.0 / (2.0 * sy * group),
                    radius: 3.0 * sy * group,
                    overlap: 10.0,
                    jitter: 0.12 + 0.2 * t.irregularity,
                    salt: 2,
                },
            ];
            match s {
                Structure::Twill { .. } | Structure::Herringbone { .. } => ls.push(Layer {
                    orients: vec![(th0 + PI / 4.0, 1.0)],
                    freq: 1.0 / (1.6 * sx.max(sy)),
                    radius: 4.0 * sx.max(sy),
                    overlap: 14.0,
                    jitter: 0.1,
                    salt: 3,
                }),
                Structure::Crepe => {
                    ls.push(Layer {
                        orients: (0..6).map(|k| (k as f32 * PI / 6.0, 1.0)).collect(),
                        freq: 1.0 / (3.0 * sx),
                        radius: 1.5 * 3.0 * sx,
                        overlap: 16.0,
                        jitter: 0.5,
                        salt: 4,
                    });
                }
                _ => {}
            }
            let gauze = matches!(s, Structure::Gauze);
            (ls, if gauze { 3.0 } else { 1.5 }, 0.35)
        }
        (Family::Knit | Family::Rib, s) => {
            let mut ls = vec![Layer {
                orients: vec![(th0 + PI / 2.0 - 0.45, 1.0), (th0 + PI / 2.0 + 0.45, 1.0)],
                freq: 1.0 / (0.6 * sx),
                radius: 2.5 * sx,
                overlap: 10.0,
                jitter: 0.15 + 0.2 * t.irregularity,
                salt: 5,
            }];
            if let Structure::Rib { knit, purl } = s {
                ls.push(Layer {
                    orients: vec![(th0, 1.0)],
                    freq: 1.0 / ((knit + purl) as f32 * sx),
                    radius: 3.0 * (knit + purl) as f32 * sx,
                    overlap: 12.0,
                    jitter: 0.08,
                    salt: 6,
                });
            }
            (ls, 1.2, 0.35)
        }
        (Family::Soft, Structure::Padded) => (
            vec![Layer {
                orients: cross(1.0, 1.0),
                freq: 1.0 / (2.0 * sx),
                radius: 3.0 * sx,
                overlap: 8.0,
                jitter: 0.2,
                salt: 7,
            }],
            0.0,
            0.25,
        ),
        (Family::Soft, _) | (Family::Fleece, _) | (Family::Felt, _) => (
            vec![Layer {
                orients: (0..8).map(|k| (k as f32 * PI / 8.0, 1.0)).collect(),
                freq: 1.0 / 28.0,
                radius: 30.0,
                overlap: 8.0,
                jitter: 0.4,
                salt: 8,
            }],
            0.0,
            0.3,
        ),
        _ => (
            // pile, terry, loops, tufts: a broadband isotropic ground
            vec![Layer {
                orients: (0..8).map(|k| (k as f32 * PI / 8.0, 1.0)).collect(),
                freq: 1.0 / (3.0 * sx.max(2.0)),
                radius: 6.0 * sx.max(2.0),
                overlap: 8.0,
                jitter: 0.4,
                salt: 9,
            }],
            0.0,
            0.2,
        ),
    };
    for l in &layers {
        gabor_layer(&g, l, &mut tex);
    }
    normalise(&mut tex);
    if sharp > 0.0 {
        for v in tex.iter_mut() {
            *v = (sharp * *v).tanh();
        }
    }
    let mut h: Vec<f32> = tex.iter().map(|v| relief * share * v).collect();
    // bumps: loops, tufts, pile tips, pills
    let mut bumps = vec![0f32; n2];
    let bump = match t.structure {
        Structure::Terry { loop_mm } => Some((
            0.5 * loop_mm / MM_PER_PX,
            0.6 * t.warp_per_cm * t.warp_per_cm / 100.0,
            0.9,
        )),
        Structure::Boucle { loop_mm } => {
            Some((0.4 * loop_mm / MM_PER_PX, 40.0 / (loop_mm * loop_mm), 0.9))
        }
        Structure::Tufted { tuft_mm } => {
            Some((0.3 * tuft_mm / MM_PER_PX, 2.0 / (tuft_mm * tuft_mm), 1.0))
        }
        Structure::Velvet | Structure::Corduroy { .. } | Structure::Plush => Some((
            (0.4 / t.warp_per_cm * 10.0 / MM_PER_PX).max(1.2),
            t.warp_per_cm * t.warp_per_cm / 100.0 * 0.8,
            0.7,
        )),
        Structure::Fleece => Some((4.0, 1.5, 0.4)),
        _ => None,
    };
    if let Some((r, per, amp)) = bump {
        spots(&g, &mut bumps, r, per, 0x5b07);
        for (o, b) in h.iter_mut().zip(&bumps) {
            *o += relief * amp * (b - 0.5);
        }
    }
    // corduroy wales: a smooth cosine ridge pattern (not a yarn model)
    if let Structure::Corduroy { wale_mm } = t.structure {
        let w = wale_mm / MM_PER_PX;
        let (sn, cs) = th0.sin_cos();
        for y in 0..size {
            for x in 0..size {
                let (bx, by) = g.at(x, y);
                let p = (bx * cs + by * sn) / w;
                h[y * size + x] += 0.5 * t.thickness_mm * 0.5 * ((TAU * p).cos() - 1.0);
            }
        }
    }
    // loose fibres and nap streaks
    let mut st = vec![0f32; n2];
    let (slen, sper, sdir, samp) = match fam {
        Family::Fleece | Family::Felt | Family::Soft => (2.0 / MM_PER_PX, 3.0, None, 0.3),
        Family::Pile => (1.2 / MM_PER_PX, 6.0, Some(th0 + 1.0), 0.25),
        _ => (1.0 / MM_PER_PX, 2.0 * t.fuzz, None, 0.5),
    };
    if sper > 0.02 {
        streaks(&g, &mut st, slen, sper, sdir, 0x57e4);
        for (o, s) in h.iter_mut().zip(&st) {
            *o += relief * samp * s.min(1.5);
        }
    }
    // pills of a worn swatch
    if sw.pilling > 0.01 {
        let mut p = vec![0f32; n2];
        spots(&g, &mut p, 4.0, sw.pilling * 0.3, 0x9111);
        for (o, b) in h.iter_mut().zip(&p) {
            *o += relief * 1.2 * b;
        }
    }
    // low-frequency undulation
    let mut und = vec![0f32; n2];
    gabor_layer(
        &g,
        &Layer {
            orients: (0..4).map(|k| (k as f32 * PI / 4.0, 1.0)).collect(),
            freq: 1.0 / 160.0,
            radius: 120.0,
            overlap: 6.0,
            jitter: 0.8,
            salt: 0xa11,
        },
        &mut und,
    );
    normalise(&mut und);
    for (o, u) in h.iter_mut().zip(&und) {
        *o += 0.08 * relief * u;
    }
    HeightField { size, h }
}
