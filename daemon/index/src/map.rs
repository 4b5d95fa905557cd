//! The 2D map: a deterministic UMAP (or PCA) of the textile centroids, and the
//! placement of new queries from their nearest textiles.

use crate::vecmath::distance;
use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

/// How the map was made and how queries are placed on it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MapLayout {
    /// "umap" or "pca".
    pub method: String,
    /// Seed of the layout.
    pub seed: u64,
    /// Number of nearest textiles a query's position is interpolated from.
    pub place_k: usize,
}

/// Principal components of `points` (rows), projected to `k` dimensions.
/// Power iteration with deflation, deterministic.
pub fn pca(points: &[Vec<f32>], k: usize) -> Vec<Vec<f32>> {
    let n = points.len();
    let dim = points.first().map_or(0, Vec::len);
    let mut mean = vec![0.0f64; dim];
    for p in points {
        for (m, x) in mean.iter_mut().zip(p) {
            *m += *x as f64 / n as f64;
        }
    }
    let x: Vec<Vec<f64>> = points
        .iter()
        .map(|p| p.iter().zip(&mean).map(|(a, m)| *a as f64 - m).collect())
        .collect();
    let mut comps: Vec<Vec<f64>> = Vec::new();
    for c in 0..k {
        let mut v: Vec<f64> = (0..dim)
            .map(|i| 1.0 + ((i * 7 + c * 13) % 11) as f64 * 0.1)
            .collect();
        for _ in 0..200 {
            // w = X^T X v, minus projections on earlier components.
            let xv: Vec<f64> = x.iter().map(|r| dot(r, &v)).collect();
            let mut w = vec![0.0; dim];
            for (r, s) in x.iter().zip(&xv) {
                for (wi, ri) in w.iter_mut().zip(r) {
                    *wi += ri * s;
                }
            }
            for u in &comps {
                let p = dot(&w, u);
                for (wi, ui) in w.iter_mut().zip(u) {
                    *wi -= p * ui;
                }
            }
            let norm = dot(&w, &w).sqrt();
            if norm < 1e-12 {
                break;
            }
            w.iter_mut().for_each(|a| *a /= norm);
            v = w;
        }
        // Fix the sign so the layout is reproducible.
        if v.iter().copied().sum::<f64>() < 0.0 {
            v.iter_mut().for_each(|a| *a = -*a);
        }
        comps.push(v);
    }
    x.iter()
        .map(|r| comps.iter().map(|u| dot(r, u) as f32).collect())
        .collect()
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// A small, deterministic UMAP (McInnes et al. 2018): fuzzy k-nearest-
/// neighbour graph, PCA initialisation, SGD with negative sampling
/// (min_dist 0.1, spread 1). Good for the few hundred points of an index.
#[allow(clippy::needless_range_loop)] // index arithmetic over pairs reads clearer
pub fn umap(points: &[Vec<f32>], dim_out: usize, seed: u64) -> Vec<Vec<f32>> {
    let n = points.len();
    if n < 3 {
        return pca(points, dim_out);
    }
    let k = 15.min(n - 1);
    // Fuzzy simplicial set.
    let mut w = vec![vec![0.0f32; n]; n];
    for i in 0..n {
        let mut d: Vec<(usize, f32)> = (0..n)
            .filter(|&j| j != i)
            .map(|j| (j, distance(&points[i], &points[j])))
            .collect();
        d.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        d.truncate(k);
        let rho = d.iter().map(|x| x.1).find(|&x| x > 0.0).unwrap_or(0.0);
        let target = (k as f32).log2();
        let (mut lo, mut hi, mut sigma) = (0.0f32, f32::INFINITY, 1.0f32);
        for _ in 0..64 {
            let s: f32 = d
                .iter()
                .map(|x| (-(x.1 - rho).max(0.0) / sigma).exp())
                .sum();
            if (s - target).abs() < 1e-5 {
                break;
            }
            if s > target {
                hi = sigma;
                sigma = (lo + hi) / 2.0;
            } else {
                lo = sigma;
                sigma = if hi.is_infinite() {
                    sigma * 2.0
                } else {
                    (lo + hi) / 2.0
                };
            }
        }
        for (j, dist) in d {
            w[i][j] = (-(dist - rho).max(0.0) / sigma.max(1e-6)).exp();
        }
    }
    let mut edges = Vec::new();
    for i in 0..n {
        for j in i + 1..n {
            let (a, b) = (w[i][j], w[j][i]);
            let s = a + b - a * b;
            if s > 0.0 {
                edges.push((i, j, s));
            }
        }
    }
    // Initialise from PCA, scaled to [-10, 10].
    let mut y = pca(points, dim_out);
    let m = y
        .iter()
        .flatten()
        .fold(0.0f32, |m, v| m.max(v.abs()))
        .max(1e-6);
    y.iter_mut().flatten().for_each(|v| *v *= 10.0 / m);
    let (a, b) = (1.577f32, 0.8951f32);
    let epochs = 500;
    let wmax = edges.iter().map(|e| e.2).fold(0.0f32, f32::max);
    let per_sample: Vec<f32> = edges.iter().map(|e| wmax / e.2).collect();
    let mut next_at = per_sample.clone();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let clip = |g: f32| g.clamp(-4.0, 4.0);
    for epoch in 0..epochs {
        let alpha = 1.0 - epoch as f32 / epochs as f32;
        for (e, &(i, j, _)) in edges.iter().enumerate() {
            if next_at[e] > epoch as f32 {
                continue;
            }
            next_at[e] += per_sample[e];
            let d2: f32 = (0..dim_out).map(|c| (y[i][c] - y[j][c]).powi(2)).sum();
            if d2 > 0.0 {
                let g = -2.0 * a * b * d2.powf(b - 1.0) / (1.0 + a * d2.powf(b));
                for c in 0..dim_out {
                    let step = clip(g * (y[i][c] - y[j][c])) * alpha;
                    y[i][c] += step;
                    y[j][c] -= step;
                }
            }
            for _ in 0..5 {
                let kk = rng.gen_range(0..n);
                if kk == i {
                    continue;
                }
                let d2: f32 = (0..dim_out).map(|c| (y[i][c] - y[kk][c]).powi(2)).sum();
                let g = 2.0 * b / ((0.001 + d2) * (1.0 + a * d2.powf(b)));
                for c in 0..dim_out {
                    let step = if g > 0.0 {
                        clip(g * (y[i][c] - y[kk][c]))
                    } else {
                        4.0
                    };
                    y[i][c] += step * alpha;
                }
            }
        }
    }
    y
}

/// Inverse-distance-weighted position from the nearest textiles
/// (`(entry, distance)` pairs, nearest first).
pub fn interpolate(near: &[(usize, f32)], xy: impl Fn(usize) -> [f32; 2]) -> [f32; 2] {
    let mut acc = [0.0f32; 2];
    let mut wsum = 0.0;
    for &(i, d) in near {
        let w = 1.0 / (d * d + 1e-4);
        let p = xy(i);
        acc[0] += w * p[0];
        acc[1] += w * p[1];
        wsum += w;
    }
    if wsum > 0.0 {
        [acc[0] / wsum, acc[1] / wsum]
    } else {
        [0.0, 0.0]
    }
}

/// Scale coordinates into [-1, 1] on each axis (keeps the map's aspect).
pub fn normalise_layout(y: &mut [Vec<f32>]) {
    let dims = y.first().map_or(0, Vec::len);
    for c in 0..dims {
        let lo = y.iter().map(|p| p[c]).fold(f32::INFINITY, f32::min);
        let hi = y.iter().map(|p| p[c]).fold(f32::NEG_INFINITY, f32::max);
        let mid = (lo + hi) / 2.0;
        let half = ((hi - lo) / 2.0).max(1e-6);
        for p in y.iter_mut() {
            p[c] = (p[c] - mid) / half;
        }
    }
}
