//! What an embedding says about how a fabric feels: a maker's attribute map.
//!
//! A maker knows the tactile attributes of the fabrics it indexes (measured
//! on its own sample book: roughness, density, softness, ...). An
//! [`AttributeMap`] is a ridge regression from a press's embedding to those
//! attributes, fitted on the known fabrics' presses alone. It answers two
//! questions of issue 20's item 4 (`telextiles-lab eval`, table (c)):
//!
//! * how much of each attribute an encoder's embedding carries at all
//!   ([`AttributeMap::cv_r2`]: the share of an attribute's variance it
//!   predicts for fabrics left out of the fit);
//! * whether a press of a fabric the index does not have is better given
//!   the known fabric nearest in predicted attributes
//!   ([`AttributeMap::feels_like`]) than the one nearest in embedding.
//!
//! The ridge strength is chosen by cross-validation over whole fabrics
//! (every fold leaves fabrics out), which is the question asked of it: how
//! well it predicts fabrics it was not fitted on. Measured, not shipped
//! (docs/benchmarks.md, "Unknown fabrics by what they feel like").
//!
//! Pure and deterministic.

/// Ridge strengths tried by [`AttributeMap::fit`], relative: each is a
/// multiple of the centred inputs' mean variance per dimension, so it means
/// the same whatever the embedding's dimension and spread.
pub const LAMBDAS: [f64; 9] = [1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0];

/// Folds of the fabric-level cross-validation.
pub const FOLDS: usize = 5;

/// A linear map from an embedding to tactile attributes.
#[derive(Clone, Debug, PartialEq)]
pub struct AttributeMap {
    /// Embedding dimension (input).
    pub dim: usize,
    /// Attribute names, in output order.
    pub names: Vec<String>,
    /// Row-major `names.len() x dim`.
    pub weights: Vec<f32>,
    /// One per attribute.
    pub bias: Vec<f32>,
    /// The ridge strength chosen (relative to the presses' total variance).
    pub lambda: f32,
    /// Cross-validated root mean square error per attribute over fabrics
    /// left out of the fit (the figure the strength was chosen on).
    pub cv_rmse: f32,
    /// Per attribute, the share of its variance over the presses predicted
    /// for fabrics left out of the fit, at the chosen strength (1: all of
    /// it; 0: no better than the mean; below 0: worse).
    pub cv_r2: Vec<f32>,
    /// Presses and fabrics it was fitted on.
    pub presses: u32,
    pub fabrics: u32,
}

/// One press for [`AttributeMap::fit`]: its fabric and embedding.
pub struct Sample<'a> {
    pub fabric: usize,
    pub embedding: &'a [f32],
}

impl AttributeMap {
    /// Fit on `samples` (press embeddings, any length: normalised here) whose
    /// fabric `f` has attributes `targets[f]` (None: not measured; its
    /// presses are left out). None when fewer than `FOLDS` fabrics have
    /// attributes and presses, when attribute vectors differ in length, or
    /// when anything is not finite or of another dimension.
    pub fn fit(
        samples: &[Sample<'_>],
        targets: &[Option<Vec<f32>>],
        names: &[String],
        dim: usize,
    ) -> Option<AttributeMap> {
        let m = names.len();
        if dim == 0 || m == 0 {
            return None;
        }
        let mut x: Vec<Vec<f64>> = Vec::new();
        let mut y: Vec<Vec<f64>> = Vec::new();
        let mut fab: Vec<usize> = Vec::new();
        for s in samples {
            let Some(Some(t)) = targets.get(s.fabric) else {
                continue;
            };
            if t.len() != m || s.embedding.len() != dim {
                return None;
            }
            if t.iter().chain(s.embedding).any(|v| !v.is_finite()) {
                return None;
            }
            let n = s
                .embedding
                .iter()
                .map(|v| (*v as f64).powi(2))
                .sum::<f64>()
                .sqrt();
            if n <= 0.0 {
                continue;
            }
            x.push(s.embedding.iter().map(|v| *v as f64 / n).collect());
            y.push(t.iter().map(|v| *v as f64).collect());
            fab.push(s.fabric);
        }
        let mut fabrics: Vec<usize> = fab.clone();
        fabrics.sort_unstable();
        fabrics.dedup();
        if fabrics.len() < FOLDS {
            return None;
        }
        // Fold of each fabric: dealt in order of fabric number.
        let fold_of = |f: usize| fabrics.binary_search(&f).map(|i| i % FOLDS).unwrap_or(0);
        // Per strength: the summed squared error of each attribute over the
        // presses of left-out fabrics.
        let mut best: Option<(f64, f64, Vec<f64>)> = None;
        for &lambda in &LAMBDAS {
            let mut se = vec![0.0; m];
            let mut count = 0usize;
            let mut every_fold = true;
            for k in 0..FOLDS {
                let train: Vec<usize> = (0..x.len()).filter(|&i| fold_of(fab[i]) != k).collect();
                let test: Vec<usize> = (0..x.len()).filter(|&i| fold_of(fab[i]) == k).collect();
                // A strength whose fit fails on a fold is not judged on the
                // other folds alone (R² would count only their presses).
                let Some((w, b)) = ridge(&x, &y, &train, dim, lambda) else {
                    every_fold = false;
                    break;
                };
                for &i in &test {
                    let p = predict_f64(&w, &b, &x[i], dim);
                    for (e, (a, t)) in se.iter_mut().zip(p.iter().zip(&y[i])) {
                        *e += (a - t).powi(2);
                    }
                    count += 1;
                }
            }
            if !every_fold || count == 0 {
                continue;
            }
            let rmse = (se.iter().sum::<f64>() / (count * m) as f64).sqrt();
            if best.as_ref().is_none_or(|(_, r, _)| rmse < *r) {
                best = Some((lambda, rmse, se));
            }
        }
        let (lambda, cv_rmse, se) = best?;
        let cv_r2 = (0..m)
            .map(|j| {
                let mean = y.iter().map(|t| t[j]).sum::<f64>() / y.len() as f64;
                let total: f64 = y.iter().map(|t| (t[j] - mean).powi(2)).sum();
                if total > 0.0 {
                    (1.0 - se[j] / total) as f32
                } else {
                    0.0
                }
            })
            .collect();
        let all: Vec<usize> = (0..x.len()).collect();
        let (w, b) = ridge(&x, &y, &all, dim, lambda)?;
        Some(AttributeMap {
            dim,
            names: names.to_vec(),
            weights: w.iter().map(|v| *v as f32).collect(),
            bias: b.iter().map(|v| *v as f32).collect(),
            lambda: lambda as f32,
            cv_rmse: cv_rmse as f32,
            cv_r2,
            presses: x.len() as u32,
            fabrics: fabrics.len() as u32,
        })
    }

    /// The attributes predicted for an embedding (normalised first; a zero
    /// vector gives the bias). `v` must be of the map's dimension.
    pub fn predict(&self, v: &[f32]) -> Vec<f32> {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        let s = if n > 0.0 && n.is_finite() {
            1.0 / n
        } else {
            0.0
        };
        self.weights
            .chunks_exact(self.dim)
            .zip(&self.bias)
            .map(|(row, b)| b + s * row.iter().zip(v).map(|(w, x)| w * x).sum::<f32>())
            .collect()
    }

    /// Of `candidates` (index, attributes; those of another length are
    /// skipped), the one nearest in attributes to what `v` is predicted to
    /// feel like, with that distance.
    pub fn feels_like<'a, I>(&self, v: &[f32], candidates: I) -> Option<(usize, f32)>
    where
        I: IntoIterator<Item = (usize, &'a [f32])>,
    {
        let p = self.predict(v);
        candidates
            .into_iter()
            .filter(|(_, a)| a.len() == p.len())
            .map(|(i, a)| (i, distance(&p, a)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }
}

/// Ridge regression on the rows `rows` of `x`, `y`, centred: weights
/// (`m x dim`, row-major) and bias. `lambda` is relative to the centred
/// inputs' total variance per dimension.
fn ridge(
    x: &[Vec<f64>],
    y: &[Vec<f64>],
    rows: &[usize],
    dim: usize,
    lambda: f64,
) -> Option<(Vec<f64>, Vec<f64>)> {
    let n = rows.len();
    if n == 0 {
        return None;
    }
    let m = y[rows[0]].len();
    let mut mx = vec![0.0; dim];
    let mut my = vec![0.0; m];
    for &i in rows {
        mx.iter_mut()
            .zip(&x[i])
            .for_each(|(a, b)| *a += b / n as f64);
        my.iter_mut()
            .zip(&y[i])
            .for_each(|(a, b)| *a += b / n as f64);
    }
    let mut a = vec![0.0; dim * dim];
    let mut rhs = vec![0.0; dim * m];
    let mut xc = vec![0.0; dim];
    for &i in rows {
        xc.iter_mut()
            .zip(x[i].iter().zip(&mx))
            .for_each(|(c, (v, mu))| *c = v - mu);
        for p in 0..dim {
            if xc[p] == 0.0 {
                continue;
            }
            for q in p..dim {
                a[p * dim + q] += xc[p] * xc[q];
            }
            for (j, (t, mu)) in y[i].iter().zip(&my).enumerate() {
                rhs[p * m + j] += xc[p] * (t - mu);
            }
        }
    }
    for p in 0..dim {
        for q in 0..p {
            a[p * dim + q] = a[q * dim + p];
        }
    }
    let trace: f64 = (0..dim).map(|p| a[p * dim + p]).sum();
    // lambda times the mean variance per dimension, so that it means the
    // same whatever the embedding's dimension and spread.
    let ridge = lambda * trace.max(1e-12) / dim as f64;
    for p in 0..dim {
        a[p * dim + p] += ridge;
    }
    let l = cholesky(&a, dim)?;
    // Solve A W = rhs, column by column.
    let mut w = vec![0.0; m * dim];
    let mut col = vec![0.0; dim];
    for j in 0..m {
        for p in 0..dim {
            col[p] = rhs[p * m + j];
        }
        let sol = cholesky_solve(&l, dim, &col);
        w[j * dim..(j + 1) * dim].copy_from_slice(&sol);
    }
    let b: Vec<f64> = (0..m)
        .map(|j| my[j] - (0..dim).map(|p| w[j * dim + p] * mx[p]).sum::<f64>())
        .collect();
    Some((w, b))
}

fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

fn predict_f64(w: &[f64], b: &[f64], v: &[f64], dim: usize) -> Vec<f64> {
    w.chunks_exact(dim)
        .zip(b)
        .map(|(row, b)| b + row.iter().zip(v).map(|(a, x)| a * x).sum::<f64>())
        .collect()
}

/// Lower-triangular `L` with `L Lᵀ = a` (row-major, `n x n`); None if `a`
/// is not positive definite.
fn cholesky(a: &[f64], n: usize) -> Option<Vec<f64>> {
    let mut l = vec![0.0; n * n];
    for i in 0..n {
        for j in 0..=i {
            let s: f64 = (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum();
            if i == j {
                let d = a[i * n + i] - s;
                if d.is_nan() || d <= 0.0 {
                    return None;
                }
                l[i * n + i] = d.sqrt();
            } else {
                l[i * n + j] = (a[i * n + j] - s) / l[j * n + j];
            }
        }
    }
    Some(l)
}

fn cholesky_solve(l: &[f64], n: usize, b: &[f64]) -> Vec<f64> {
    let mut z = vec![0.0; n];
    for i in 0..n {
        let s: f64 = (0..i).map(|k| l[i * n + k] * z[k]).sum();
        z[i] = (b[i] - s) / l[i * n + i];
    }
    let mut x = vec![0.0; n];
    for i in (0..n).rev() {
        let s: f64 = (i + 1..n).map(|k| l[k * n + i] * x[k]).sum();
        x[i] = (z[i] - s) / l[i * n + i];
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    fn l2_normalise(v: &mut [f32]) {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.iter_mut().for_each(|x| *x /= n);
    }

    /// A tiny deterministic generator for the tests' vectors.
    fn lcg(seed: &mut u64) -> f32 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((*seed >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }

    /// Presses (fabric, embedding) and each fabric's attributes.
    type Book = (Vec<(usize, Vec<f32>)>, Vec<Option<Vec<f32>>>);

    /// Fabrics whose two attributes are linear in a unit embedding's first
    /// two coordinates, presses scattered around each fabric's direction.
    fn book(fabrics: usize, presses: usize, noise: f32) -> Book {
        let dim = 8;
        let mut seed = 7u64;
        let mut centres = Vec::new();
        let mut targets = Vec::new();
        for _ in 0..fabrics {
            let mut c: Vec<f32> = (0..dim).map(|_| lcg(&mut seed)).collect();
            l2_normalise(&mut c);
            targets.push(Some(vec![0.5 + 0.4 * c[0], 0.5 - 0.3 * c[1]]));
            centres.push(c);
        }
        let mut samples = Vec::new();
        for (f, c) in centres.iter().enumerate() {
            for _ in 0..presses {
                let mut v: Vec<f32> = c.iter().map(|x| x + noise * lcg(&mut seed)).collect();
                l2_normalise(&mut v);
                samples.push((f, v));
            }
        }
        (samples, targets)
    }

    fn names() -> Vec<String> {
        vec!["roughness".into(), "softness".into()]
    }

    fn fit(samples: &[(usize, Vec<f32>)], targets: &[Option<Vec<f32>>]) -> Option<AttributeMap> {
        let s: Vec<Sample> = samples
            .iter()
            .map(|(f, v)| Sample {
                fabric: *f,
                embedding: v,
            })
            .collect();
        AttributeMap::fit(&s, targets, &names(), 8)
    }

    #[test]
    fn a_linear_relation_is_recovered_for_fabrics_it_was_not_fitted_on() {
        let (samples, targets) = book(40, 4, 0.02);
        // Fit on fabrics 0..30, predict fabrics 30..40.
        let train: Vec<(usize, Vec<f32>)> =
            samples.iter().filter(|(f, _)| *f < 30).cloned().collect();
        let map = fit(&train, &targets).expect("fits");
        assert_eq!((map.fabrics, map.presses), (30, 120));
        assert!(map.cv_rmse < 0.05, "cross-validated error {}", map.cv_rmse);
        // Both attributes are carried by the embedding.
        assert!(map.cv_r2.iter().all(|r| *r > 0.9), "{:?}", map.cv_r2);
        for (f, v) in samples.iter().filter(|(f, _)| *f >= 30) {
            let p = map.predict(v);
            let t = targets[*f].as_ref().unwrap();
            for (a, b) in p.iter().zip(t) {
                assert!(
                    (a - b).abs() < 0.06,
                    "fabric {f}: predicted {p:?}, measured {t:?}"
                );
            }
        }
        // The prediction does not depend on the embedding's length.
        let (_, v) = &samples[0];
        let long: Vec<f32> = v.iter().map(|x| 3.0 * x).collect();
        for (a, b) in map.predict(v).iter().zip(map.predict(&long)) {
            assert!((a - b).abs() < 1e-5);
        }
        // The same data give the same bytes.
        assert_eq!(fit(&train, &targets), Some(map));
    }

    #[test]
    fn the_fabric_that_feels_nearest_is_chosen_by_attributes_not_by_embedding() {
        let (samples, targets) = book(40, 4, 0.02);
        let map = fit(&samples, &targets).unwrap();
        let cands: Vec<(usize, &[f32])> =
            vec![(3, &[0.9, 0.9][..]), (5, &[0.1, 0.1][..]), (9, &[0.5][..])];
        // An embedding predicted at about (0.9, 0.2) lies nearer (0.9, 0.9)
        // than (0.1, 0.1); the candidate with one attribute is skipped.
        let mut v = vec![0.0f32; 8];
        v[0] = 1.0;
        v[1] = 1.0;
        let p = map.predict(&v);
        let (k, dist) = map.feels_like(&v, cands.iter().copied()).unwrap();
        assert_eq!(k, 3, "predicted {p:?}");
        assert!((dist - distance(&p, &[0.9, 0.9])).abs() < 1e-6);
        assert_eq!(map.feels_like(&v, std::iter::empty()), None);
    }

    #[test]
    fn too_few_fabrics_or_bad_input_fit_nothing_and_noise_is_not_carried() {
        let (samples, mut targets) = book(40, 3, 0.02);
        let few: Vec<(usize, Vec<f32>)> = samples
            .iter()
            .filter(|(f, _)| *f < FOLDS - 1)
            .cloned()
            .collect();
        assert_eq!(fit(&few, &targets), None);
        // Fabrics without measured attributes are left out, not guessed.
        for t in targets.iter_mut().skip(FOLDS - 1) {
            *t = None;
        }
        assert_eq!(fit(&samples, &targets), None);
        let (mut samples, targets) = book(40, 3, 0.02);
        samples[4].1[2] = f32::NAN;
        assert_eq!(fit(&samples, &targets), None);
        let (mut samples, targets) = book(40, 3, 0.02);
        samples[4].1.pop();
        assert_eq!(fit(&samples, &targets), None);
        let (samples, mut targets) = book(40, 3, 0.02);
        targets[2] = Some(vec![0.5]);
        assert_eq!(fit(&samples, &targets), None);
        // An attribute the embedding does not carry (drawn at random per
        // fabric) is predicted no better than its mean, the other still is.
        let (samples, mut targets) = book(40, 4, 0.02);
        let mut seed = 5u64;
        for t in targets.iter_mut().flatten() {
            t[1] = 0.5 + 0.4 * lcg(&mut seed);
        }
        let map = fit(&samples, &targets).unwrap();
        assert!(map.cv_r2[0] > 0.9 && map.cv_r2[1] < 0.1, "{:?}", map.cv_r2);
    }
}
