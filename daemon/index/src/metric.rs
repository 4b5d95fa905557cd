//! A distance learned from the index's own presses: within-fabric
//! whitening.
//!
//! An index built from several presses of each fabric sees how presses of
//! one fabric differ (another place on the cloth, another hand, another
//! sensor unit) on the very sensor the index is for. `Metric` scales those
//! directions down: with `C` the within-fabric covariance of the presses'
//! mean embeddings (scaled to unit mean variance) and `a` the shrinkage,
//! `W = ((1 - a) C + a I)^(-1/2)` and a vector `v` maps to `W v / |W v|`.
//! `a = 1` is the identity (plain cosine distance); smaller values trust
//! the presses more. Everything in an index with a metric (centroids,
//! exemplars, map, roller) lives in the mapped space, and every query goes
//! through [`Metric::apply`] first (`Index::nearest` does it).

use serde::{Deserialize, Serialize};

/// Shrinkage used unless told otherwise (chosen on simulated hand-held
/// presses of catalogue 2, generator 1; `docs/recording.md`).
pub const DEFAULT_SHRINKAGE: f32 = 0.5;

/// A symmetric linear map applied to every embedding before distances.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Metric {
    /// Embedding dimension.
    pub dim: usize,
    /// `dim` x `dim`, row-major.
    pub matrix: Vec<f32>,
    /// Presses the within-fabric covariance came from.
    pub presses: usize,
    /// Fabrics with two or more presses among them.
    pub fabrics: usize,
    /// Shrinkage towards the identity (0..=1).
    pub shrinkage: f32,
}

/// Sums of a set of vectors, each L2-normalised first (one press's
/// frames, or a press's mean): how many, their sum and the sum of their
/// outer products. What a within-fabric scatter is made of: summing the
/// moments of a fabric's presses gives the fabric's, so cross-validation
/// over whole presses never goes back to the frames.
#[derive(Clone, Debug, PartialEq)]
pub struct Moments {
    /// Vectors summed.
    pub n: usize,
    /// Σ x (length `dim`).
    pub sum: Vec<f64>,
    /// Σ x xᵀ (`dim` x `dim`, row-major).
    pub outer: Vec<f64>,
}

impl Moments {
    /// No vectors yet, of dimension `dim`.
    pub fn zero(dim: usize) -> Moments {
        Moments {
            n: 0,
            sum: vec![0.0; dim],
            outer: vec![0.0; dim * dim],
        }
    }

    /// The moments of `vectors`, each normalised. None when one is of
    /// another dimension, not finite or of zero length.
    pub fn of<'a>(vectors: impl IntoIterator<Item = &'a [f32]>, dim: usize) -> Option<Moments> {
        let mut m = Moments::zero(dim);
        for v in vectors {
            if v.len() != dim || v.iter().any(|x| !x.is_finite()) {
                return None;
            }
            let u = unit_f64(v);
            if u.iter().all(|&x| x == 0.0) {
                return None;
            }
            for i in 0..dim {
                m.sum[i] += u[i];
                let row = &mut m.outer[i * dim..(i + 1) * dim];
                for (o, uj) in row.iter_mut().zip(&u) {
                    *o += u[i] * uj;
                }
            }
            m.n += 1;
        }
        Some(m)
    }

    /// Add another set's moments (of the same dimension).
    pub fn add(&mut self, other: &Moments) {
        self.n += other.n;
        self.sum
            .iter_mut()
            .zip(&other.sum)
            .for_each(|(a, b)| *a += b);
        self.outer
            .iter_mut()
            .zip(&other.outer)
            .for_each(|(a, b)| *a += b);
    }
}

/// How much a fitted metric is shrunk towards the identity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shrinkage {
    /// This much (0..=1).
    Fixed(f32),
    /// As much as the Ledoit–Wolf estimate says the data need: the
    /// shrinkage that minimises the expected squared error of the
    /// covariance, estimated from the vectors themselves (scikit-learn's
    /// `ledoit_wolf_shrinkage`, on the deviations from each fabric's mean).
    LedoitWolf,
}

impl Metric {
    /// Within-fabric whitening from each fabric's press embeddings (any
    /// length; normalised here). None when no fabric has two presses (there
    /// is nothing to learn from), when the shrinkage is outside 0..=1, or
    /// when a vector is of another dimension or not finite.
    pub fn within_fabric(fabrics: &[Vec<Vec<f32>>], dim: usize, shrinkage: f32) -> Option<Metric> {
        let mut moments = Vec::with_capacity(fabrics.len());
        let mut presses = 0;
        for f in fabrics {
            let m = Moments::of(f.iter().map(Vec::as_slice), dim)?;
            if m.n >= 2 {
                presses += m.n;
            }
            moments.push(m);
        }
        Metric::from_moments(&moments, dim, Shrinkage::Fixed(shrinkage), presses)
    }

    /// Within-fabric whitening from each fabric's [`Moments`] (of its press
    /// means, or of every frame of its presses): the scatter of each
    /// fabric's vectors about their own mean, pooled over the fabrics with
    /// two vectors or more, scaled to unit mean variance and shrunk towards
    /// the identity. `presses` is recorded as what the metric came from.
    /// None when no fabric has two vectors, the shrinkage is outside 0..=1,
    /// a fabric's moments are of another dimension, or the shrunk scatter
    /// has no inverse (vectors that agree exactly, no shrinkage).
    pub fn from_moments(
        fabrics: &[Moments],
        dim: usize,
        shrinkage: Shrinkage,
        presses: usize,
    ) -> Option<Metric> {
        if dim == 0 {
            return None;
        }
        if let Shrinkage::Fixed(a) = shrinkage {
            if !(0.0..=1.0).contains(&a) {
                return None;
            }
        }
        let mut cov = vec![0.0f64; dim * dim];
        let (mut rows, mut used, mut fourth) = (0usize, 0usize, 0.0f64);
        for f in fabrics {
            if f.sum.len() != dim || f.outer.len() != dim * dim {
                return None;
            }
            if f.n < 2 {
                continue;
            }
            let n = f.n as f64;
            let mu: Vec<f64> = f.sum.iter().map(|s| s / n).collect();
            for i in 0..dim {
                for j in 0..dim {
                    cov[i * dim + j] += f.outer[i * dim + j] - n * mu[i] * mu[j];
                }
            }
            // Σ_k |x_k - μ|⁴ from the moments (|x_k| = 1):
            // |x_k - μ|² = c - 2 x_k·μ with c = 1 + |μ|².
            let c = 1.0 + mu.iter().map(|m| m * m).sum::<f64>();
            let s_mu: f64 = f.sum.iter().zip(&mu).map(|(s, m)| s * m).sum();
            let mut q_mu = 0.0;
            for i in 0..dim {
                let row: f64 = (0..dim).map(|j| f.outer[i * dim + j] * mu[j]).sum();
                q_mu += mu[i] * row;
            }
            fourth += (n * c * c - 4.0 * c * s_mu + 4.0 * q_mu).max(0.0);
            rows += f.n;
            used += 1;
        }
        if used == 0 {
            return None;
        }
        let trace: f64 = (0..dim).map(|i| cov[i * dim + i]).sum();
        let a = match shrinkage {
            Shrinkage::Fixed(a) => a as f64,
            Shrinkage::LedoitWolf => ledoit_wolf(&cov, dim, rows, fourth, trace),
        };
        let scale = if trace > 0.0 {
            (1.0 - a) * dim as f64 / trace
        } else {
            0.0
        };
        for (k, c) in cov.iter_mut().enumerate() {
            *c = *c * scale + if k % (dim + 1) == 0 { a } else { 0.0 };
        }
        // A fabric's presses that all agree leave C = 0: with no shrinkage
        // there is no inverse, so no metric.
        let (values, vectors) = jacobi_eigen(&cov, dim);
        if values.iter().any(|&l| l.is_nan() || l <= 1e-9) {
            return None;
        }
        let mut matrix = vec![0.0f32; dim * dim];
        for i in 0..dim {
            for j in 0..dim {
                let s: f64 = (0..dim)
                    .map(|k| vectors[i * dim + k] * vectors[j * dim + k] / values[k].sqrt())
                    .sum();
                matrix[i * dim + j] = s as f32;
            }
        }
        Some(Metric {
            dim,
            matrix,
            presses,
            fabrics: used,
            shrinkage: a as f32,
        })
    }

    /// `W v`, L2-normalised. `v` must be of the metric's dimension.
    pub fn apply(&self, v: &[f32]) -> Vec<f32> {
        let mut out: Vec<f32> = self
            .matrix
            .chunks_exact(self.dim)
            .map(|row| row.iter().zip(v).map(|(a, b)| a * b).sum())
            .collect();
        crate::l2_normalise(&mut out);
        out
    }

    /// An encoder-space direction that [`Metric::apply`] maps onto `v`
    /// (normalised; solves `W x = v`): how to make a query that lands on a
    /// vector of the index (the map's demo does). None if `v` is of another
    /// dimension or the map is singular.
    pub fn preimage(&self, v: &[f32]) -> Option<Vec<f32>> {
        let n = self.dim;
        if v.len() != n || self.matrix.len() != n * n {
            return None;
        }
        // Gaussian elimination with partial pivoting on [W | v].
        let mut a: Vec<f64> = self.matrix.iter().map(|&x| x as f64).collect();
        let mut b: Vec<f64> = v.iter().map(|&x| x as f64).collect();
        for c in 0..n {
            let p = (c..n).max_by(|&i, &j| a[i * n + c].abs().total_cmp(&a[j * n + c].abs()))?;
            if a[p * n + c].is_nan() || a[p * n + c].abs() <= 1e-12 {
                return None;
            }
            if p != c {
                for k in 0..n {
                    a.swap(p * n + k, c * n + k);
                }
                b.swap(p, c);
            }
            for r in c + 1..n {
                let f = a[r * n + c] / a[c * n + c];
                if f != 0.0 {
                    for k in c..n {
                        a[r * n + k] -= f * a[c * n + k];
                    }
                    b[r] -= f * b[c];
                }
            }
        }
        let mut x = vec![0.0f64; n];
        for r in (0..n).rev() {
            let s: f64 = (r + 1..n).map(|k| a[r * n + k] * x[k]).sum();
            x[r] = (b[r] - s) / a[r * n + r];
        }
        let mut out: Vec<f32> = x.into_iter().map(|x| x as f32).collect();
        crate::l2_normalise(&mut out);
        out.iter().all(|x| x.is_finite()).then_some(out)
    }

    /// Dimensions agree and every coefficient is finite.
    pub fn is_valid(&self, dim: usize) -> bool {
        self.dim == dim
            && self.matrix.len() == dim * dim
            && self.matrix.iter().all(|x| x.is_finite())
            && (0.0..=1.0).contains(&self.shrinkage)
    }
}

/// The Ledoit–Wolf shrinkage (0..=1) of the scatter `cov` (the sum of
/// `rows` deviations' outer products, trace `trace`; `fourth` = Σ |d|⁴ of
/// the deviations), as scikit-learn's `ledoit_wolf_shrinkage` computes it
/// for centred data: with `S = cov / rows` and `μ = tr S / p`,
/// `δ = |S - μI|²_F / p`, `β = (Σ|d|⁴ / rows - |S|²_F) / (p · rows)`, and the
/// shrinkage `min(β, δ) / δ`. Frames of one press are not independent
/// draws, so this tends to shrink too little; the index's choice among fits
/// ([`crate::build::MetricFit`]) is made on whole presses left out.
fn ledoit_wolf(cov: &[f64], dim: usize, rows: usize, fourth: f64, trace: f64) -> f64 {
    if rows == 0 || trace <= 0.0 {
        return 1.0;
    }
    let (n, p) = (rows as f64, dim as f64);
    let s2: f64 = cov.iter().map(|c| (c / n) * (c / n)).sum();
    let tr = trace / n;
    let mu = tr / p;
    let delta = (s2 - 2.0 * mu * tr + p * mu * mu) / p;
    if delta.is_nan() || delta <= 0.0 {
        return 1.0;
    }
    let beta = ((fourth / n - s2) / (p * n)).clamp(0.0, delta);
    (beta / delta).clamp(0.0, 1.0)
}

fn unit_f64(v: &[f32]) -> Vec<f64> {
    let n = v.iter().map(|x| (*x as f64).powi(2)).sum::<f64>().sqrt();
    v.iter()
        .map(|x| if n > 0.0 { *x as f64 / n } else { 0.0 })
        .collect()
}

/// Eigenvalues and eigenvectors (columns of the row-major result) of a
/// symmetric matrix by cyclic Jacobi rotations.
fn jacobi_eigen(a: &[f64], n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut a = a.to_vec();
    let mut v = vec![0.0f64; n * n];
    for i in 0..n {
        v[i * n + i] = 1.0;
    }
    let total: f64 = a.iter().map(|x| x * x).sum::<f64>().max(f64::MIN_POSITIVE);
    for _sweep in 0..50 {
        let off: f64 = (0..n)
            .flat_map(|i| (0..n).filter(move |&j| j != i).map(move |j| (i, j)))
            .map(|(i, j)| a[i * n + j].powi(2))
            .sum();
        if off <= 1e-22 * total {
            break;
        }
        for p in 0..n {
            for q in p + 1..n {
                let apq = a[p * n + q];
                if apq.abs() < 1e-300 {
                    continue;
                }
                let theta = (a[q * n + q] - a[p * n + p]) / (2.0 * apq);
                let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
                let t = if theta == 0.0 { 1.0 } else { t };
                let c = 1.0 / (t * t + 1.0).sqrt();
                let s = t * c;
                for k in 0..n {
                    let akp = a[k * n + p];
                    let akq = a[k * n + q];
                    a[k * n + p] = c * akp - s * akq;
                    a[k * n + q] = s * akp + c * akq;
                }
                for k in 0..n {
                    let apk = a[p * n + k];
                    let aqk = a[q * n + k];
                    a[p * n + k] = c * apk - s * aqk;
                    a[q * n + k] = s * apk + c * aqk;
                }
                for k in 0..n {
                    let vkp = v[k * n + p];
                    let vkq = v[k * n + q];
                    v[k * n + p] = c * vkp - s * vkq;
                    v[k * n + q] = s * vkp + c * vkq;
                }
            }
        }
    }
    ((0..n).map(|i| a[i * n + i]).collect(), v)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn v(x: &[f32]) -> Vec<f32> {
        x.to_vec()
    }

    #[test]
    fn eigen_decomposition_reconstructs_the_matrix() {
        let n = 4;
        let a: Vec<f64> = vec![
            4.0, 1.0, 0.5, 0.0, //
            1.0, 3.0, 0.2, 0.1, //
            0.5, 0.2, 2.0, 0.3, //
            0.0, 0.1, 0.3, 1.0,
        ];
        let (l, q) = jacobi_eigen(&a, n);
        for i in 0..n {
            for j in 0..n {
                let r: f64 = (0..n).map(|k| q[i * n + k] * l[k] * q[j * n + k]).sum();
                assert!((r - a[i * n + j]).abs() < 1e-9, "({i},{j}) {r}");
            }
        }
    }

    #[test]
    fn whitening_scales_down_the_direction_presses_of_one_fabric_vary_in() {
        // Two fabrics in 3-d; their presses vary along z (a nuisance), the
        // fabrics differ along x and y.
        let fabrics = vec![
            vec![
                v(&[1.0, 0.2, 0.5]),
                v(&[1.0, 0.2, -0.5]),
                v(&[1.0, 0.2, 0.4]),
            ],
            vec![v(&[0.2, 1.0, 0.45]), v(&[0.2, 1.0, -0.55])],
        ];
        let m = Metric::within_fabric(&fabrics, 3, 0.2).unwrap();
        assert_eq!((m.presses, m.fabrics, m.dim), (5, 2, 3));
        assert!(m.is_valid(3));
        // Symmetric.
        for i in 0..3 {
            for j in 0..3 {
                assert!((m.matrix[i * 3 + j] - m.matrix[j * 3 + i]).abs() < 1e-5);
            }
        }
        // A query of fabric 0 pressed with a large nuisance: nearer to
        // fabric 1's nuisance-laden press in plain cosine, nearer to its
        // own fabric's clean press after the metric.
        let q = v(&[0.6, 0.5, 0.9]);
        let own = v(&[1.0, 0.2, 0.0]);
        let other = v(&[0.2, 1.0, 0.6]);
        let n = |x: &[f32]| {
            let mut x = x.to_vec();
            crate::l2_normalise(&mut x);
            x
        };
        let d = crate::distance;
        assert!(d(&n(&q), &n(&other)) < d(&n(&q), &n(&own)));
        let (mq, mo, mt) = (m.apply(&q), m.apply(&own), m.apply(&other));
        assert!(d(&mq, &mo) < d(&mq, &mt), "{} {}", d(&mq, &mo), d(&mq, &mt));
        assert!((mq.iter().map(|x| x * x).sum::<f32>() - 1.0).abs() < 1e-5);
        // The preimage of a vector of the index's space maps back onto it.
        let back = m.apply(&m.preimage(&mo).unwrap());
        assert!(d(&back, &mo) < 1e-5, "{back:?} {mo:?}");
        assert!(m.preimage(&[1.0, 0.0]).is_none());
    }

    #[test]
    fn full_shrinkage_is_the_identity_and_nothing_to_learn_is_no_metric() {
        let fabrics = vec![vec![v(&[1.0, 0.0]), v(&[0.8, 0.6])], vec![v(&[0.0, 1.0])]];
        let m = Metric::within_fabric(&fabrics, 2, 1.0).unwrap();
        for (k, x) in m.matrix.iter().enumerate() {
            let want = if k % 3 == 0 { 1.0 } else { 0.0 };
            assert!((x - want).abs() < 1e-6, "{:?}", m.matrix);
        }
        // One press per fabric: no within-fabric spread to learn.
        assert!(
            Metric::within_fabric(&[vec![v(&[1.0, 0.0])], vec![v(&[0.0, 1.0])]], 2, 0.5).is_none()
        );
        // Presses that agree exactly, no shrinkage: no inverse.
        assert!(Metric::within_fabric(&[vec![v(&[1.0, 0.0]), v(&[1.0, 0.0])]], 2, 0.0).is_none());
        // Bad input is refused, not a panic or a NaN matrix.
        assert!(Metric::within_fabric(&fabrics, 2, 1.5).is_none());
        assert!(
            Metric::within_fabric(&[vec![v(&[1.0, 0.0]), v(&[f32::NAN, 0.0])]], 2, 0.5).is_none()
        );
        assert!(Metric::within_fabric(&[vec![v(&[1.0, 0.0]), v(&[1.0])]], 2, 0.5).is_none());
    }

    #[test]
    fn ledoit_wolf_shrinkage_is_scikit_learns() {
        // Two fabrics' vectors (normalised here); scikit-learn 1.x on the
        // deviations from each fabric's mean:
        // ledoit_wolf_shrinkage(D, assume_centered=True) = 0.20636690752737308.
        let fabrics = [
            vec![
                v(&[1.0, 0.2, 0.5, 0.1]),
                v(&[0.9, 0.3, -0.4, 0.0]),
                v(&[1.1, 0.1, 0.2, -0.2]),
                v(&[1.0, 0.25, -0.1, 0.3]),
            ],
            vec![
                v(&[0.1, 1.0, 0.45, 0.2]),
                v(&[0.2, 0.9, -0.55, -0.1]),
                v(&[0.0, 1.1, 0.1, 0.0]),
            ],
        ];
        let moments: Vec<Moments> = fabrics
            .iter()
            .map(|f| Moments::of(f.iter().map(Vec::as_slice), 4).unwrap())
            .collect();
        let m = Metric::from_moments(&moments, 4, Shrinkage::LedoitWolf, 7).unwrap();
        assert!((m.shrinkage - 0.206_366_9).abs() < 1e-5, "{}", m.shrinkage);
        assert_eq!((m.presses, m.fabrics), (7, 2));
        // The same scatter at that shrinkage, fixed, is the same metric.
        let fixed = Metric::from_moments(&moments, 4, Shrinkage::Fixed(m.shrinkage), 7).unwrap();
        for (a, b) in m.matrix.iter().zip(&fixed.matrix) {
            assert!((a - b).abs() < 1e-5);
        }
        // Moments add up: two halves of a fabric are the fabric.
        let mut half = Moments::of(fabrics[0][..2].iter().map(Vec::as_slice), 4).unwrap();
        half.add(&Moments::of(fabrics[0][2..].iter().map(Vec::as_slice), 4).unwrap());
        assert_eq!(half.n, moments[0].n);
        for (a, b) in half.outer.iter().zip(&moments[0].outer) {
            assert!((a - b).abs() < 1e-12);
        }
        // Bad vectors are refused, not a NaN matrix.
        assert!(Moments::of([&[1.0, f32::NAN, 0.0, 0.0][..]], 4).is_none());
        assert!(Moments::of([&[0.0; 4][..]], 4).is_none());
        assert!(Moments::of([&[1.0; 3][..]], 4).is_none());
        assert!(Metric::from_moments(&moments, 3, Shrinkage::LedoitWolf, 7).is_none());
    }
}
