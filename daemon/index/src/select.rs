//! Which textiles go on the roller, and in what order around the wheel.

use crate::map;
use crate::vecmath::distance;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

/// How roller textiles are chosen.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum SelectionMethod {
    /// The paper's method: a 1D UMAP of the latent space, N textiles
    /// equidistant along it.
    Umap1d,
    /// Greedy farthest-point sampling (a 2-approximation of the k-centre
    /// problem: minimises the worst distance to the nearest slot).
    FarthestPoint,
    /// k-medoids (Voronoi iteration from a farthest-point start): minimises the
    /// mean distance to the nearest slot.
    KMedoids,
    /// Uniformly random textiles (the baseline).
    Random,
}

impl std::str::FromStr for SelectionMethod {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "umap1d" | "paper" => Ok(Self::Umap1d),
            "farthest" | "farthest-point" => Ok(Self::FarthestPoint),
            "kmedoids" | "k-medoids" => Ok(Self::KMedoids),
            "random" => Ok(Self::Random),
            _ => Err(format!(
                "unknown roller selection method {s:?} (expected umap1d, farthest, kmedoids or random)"
            )),
        }
    }
}

impl std::fmt::Display for SelectionMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Self::Umap1d => "umap1d",
            Self::FarthestPoint => "farthest",
            Self::KMedoids => "kmedoids",
            Self::Random => "random",
        })
    }
}

/// Choose `n` distinct points (indices into `points`) by `method`.
///
/// # Panics
/// If `n == 0` or `n > points.len()`.
pub fn select(points: &[Vec<f32>], n: usize, method: SelectionMethod, seed: u64) -> Vec<usize> {
    assert!(
        n > 0 && n <= points.len(),
        "cannot choose {n} of {}",
        points.len()
    );
    match method {
        SelectionMethod::Umap1d => umap1d(points, n, seed),
        SelectionMethod::FarthestPoint => farthest_point(points, n),
        SelectionMethod::KMedoids => k_medoids(points, n),
        SelectionMethod::Random => {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
            let mut idx: Vec<usize> = (0..points.len()).collect();
            idx.shuffle(&mut rng);
            idx.truncate(n);
            idx
        }
    }
}

fn umap1d(points: &[Vec<f32>], n: usize, seed: u64) -> Vec<usize> {
    let coords = map::umap(points, 1, seed);
    let xs: Vec<f32> = coords.iter().map(|c| c[0]).collect();
    let lo = xs.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = xs.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let mut taken = vec![false; points.len()];
    let mut out = Vec::with_capacity(n);
    for k in 0..n {
        let target = if n == 1 {
            (lo + hi) / 2.0
        } else {
            lo + (hi - lo) * k as f32 / (n - 1) as f32
        };
        let best = (0..points.len())
            .filter(|&i| !taken[i])
            .min_by(|&a, &b| {
                (xs[a] - target)
                    .abs()
                    .total_cmp(&(xs[b] - target).abs())
                    .then(a.cmp(&b))
            })
            .expect("n <= points");
        taken[best] = true;
        out.push(best);
    }
    out
}

fn medoid(points: &[Vec<f32>], members: &[usize]) -> usize {
    *members
        .iter()
        .min_by(|&&a, &&b| {
            let sa: f32 = members
                .iter()
                .map(|&m| distance(&points[a], &points[m]))
                .sum();
            let sb: f32 = members
                .iter()
                .map(|&m| distance(&points[b], &points[m]))
                .sum();
            sa.total_cmp(&sb).then(a.cmp(&b))
        })
        .expect("non-empty cluster")
}

fn farthest_point(points: &[Vec<f32>], n: usize) -> Vec<usize> {
    let all: Vec<usize> = (0..points.len()).collect();
    let mut chosen = vec![medoid(points, &all)];
    let mut near: Vec<f32> = points
        .iter()
        .map(|p| distance(p, &points[chosen[0]]))
        .collect();
    while chosen.len() < n {
        let next = (0..points.len())
            .max_by(|&a, &b| near[a].total_cmp(&near[b]).then(b.cmp(&a)))
            .expect("non-empty");
        chosen.push(next);
        for (i, p) in points.iter().enumerate() {
            near[i] = near[i].min(distance(p, &points[next]));
        }
    }
    chosen
}

fn k_medoids(points: &[Vec<f32>], n: usize) -> Vec<usize> {
    let mut medoids = farthest_point(points, n);
    for _ in 0..100 {
        let mut clusters = vec![Vec::new(); n];
        for (i, p) in points.iter().enumerate() {
            let c = nearest_of(p, points, &medoids).0;
            clusters[c].push(i);
        }
        let next: Vec<usize> = clusters
            .iter()
            .zip(&medoids)
            .map(|(c, &m)| if c.is_empty() { m } else { medoid(points, c) })
            .collect();
        if next == medoids {
            break;
        }
        medoids = next;
    }
    swap_improve(points, medoids)
}

/// PAM's swap phase: exchange a medoid for a non-medoid while that lowers
/// the total distance from every point to its nearest medoid. The
/// alternation above stops in local optima that farthest-point seeding
/// (which favours outliers) makes likely; swapping fixes most of them.
fn swap_improve(points: &[Vec<f32>], mut medoids: Vec<usize>) -> Vec<usize> {
    let m = points.len();
    let d: Vec<f32> = (0..m * m)
        .map(|k| distance(&points[k / m], &points[k % m]))
        .collect();
    let cost = |med: &[usize]| -> f32 {
        (0..m)
            .map(|i| {
                med.iter()
                    .map(|&c| d[i * m + c])
                    .fold(f32::INFINITY, f32::min)
            })
            .sum()
    };
    let mut best = cost(&medoids);
    for _ in 0..50 {
        let mut improved = false;
        for slot in 0..medoids.len() {
            for cand in 0..m {
                if medoids.contains(&cand) {
                    continue;
                }
                let old = medoids[slot];
                medoids[slot] = cand;
                let c = cost(&medoids);
                if c < best - 1e-6 {
                    best = c;
                    improved = true;
                } else {
                    medoids[slot] = old;
                }
            }
        }
        if !improved {
            break;
        }
    }
    medoids
}

/// Position in `chosen` of the point nearest to `p`, and its distance.
pub fn nearest_of(p: &[f32], points: &[Vec<f32>], chosen: &[usize]) -> (usize, f32) {
    chosen
        .iter()
        .enumerate()
        .map(|(k, &c)| (k, distance(p, &points[c])))
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
        .expect("at least one slot")
}

/// Order the chosen textiles around the wheel so that neighbours are similar:
/// a nearest-neighbour tour improved by 2-opt on the cyclic sum of latent
/// distances between adjacent slots. Deterministic; starts from `chosen[0]`.
pub fn order_wheel(points: &[Vec<f32>], chosen: &[usize]) -> Vec<usize> {
    let n = chosen.len();
    if n <= 3 {
        return chosen.to_vec();
    }
    let d = |a: usize, b: usize| distance(&points[a], &points[b]);
    let mut tour = vec![chosen[0]];
    let mut rest: Vec<usize> = chosen[1..].to_vec();
    while let Some(&last) = tour.last() {
        let Some((k, _)) = rest
            .iter()
            .enumerate()
            .min_by(|a, b| d(last, *a.1).total_cmp(&d(last, *b.1)))
        else {
            break;
        };
        tour.push(rest.remove(k));
    }
    loop {
        let mut improved = false;
        for i in 0..n - 1 {
            for j in i + 2..n {
                if i == 0 && j == n - 1 {
                    continue;
                }
                let (a, b, c, e) = (tour[i], tour[i + 1], tour[j], tour[(j + 1) % n]);
                if d(a, c) + d(b, e) + 1e-6 < d(a, b) + d(c, e) {
                    tour[i + 1..=j].reverse();
                    improved = true;
                }
            }
        }
        if !improved {
            break;
        }
    }
    tour
}

/// Sum of latent distances between adjacent slots around the wheel.
pub fn wheel_length(points: &[Vec<f32>], order: &[usize]) -> f32 {
    (0..order.len())
        .map(|i| distance(&points[order[i]], &points[order[(i + 1) % order.len()]]))
        .sum()
}

/// How well the roller covers a set of textiles.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Coverage {
    /// Mean distance from a textile to its nearest roller textile.
    pub mean: f32,
    /// Worst distance from a textile to its nearest roller textile.
    pub max: f32,
}

/// Coverage of `queries` by the roller textiles `slot_points`.
pub fn coverage(queries: &[Vec<f32>], slot_points: &[Vec<f32>]) -> Coverage {
    let mut sum = 0.0;
    let mut max: f32 = 0.0;
    for q in queries {
        let d = slot_points
            .iter()
            .map(|s| distance(q, s))
            .fold(f32::INFINITY, f32::min);
        sum += d;
        max = max.max(d);
    }
    Coverage {
        mean: if queries.is_empty() {
            0.0
        } else {
            sum / queries.len() as f32
        },
        max,
    }
}
