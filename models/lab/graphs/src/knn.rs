//! kNN evaluation on L2-normalised embeddings: top-1 with k=1 and the
//! temperature-weighted kNN of Wu et al. (2018) used by MoCo/lightly.

/// Result of a kNN evaluation.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct KnnScore {
    /// Top-1 accuracy of the single nearest neighbour.
    pub top1_k1: f64,
    /// Top-1 accuracy of the temperature-weighted kNN vote.
    pub top1_weighted: f64,
    /// Number of queries.
    pub queries: usize,
}

/// L2-normalise rows of `x` (row length `dim`) in place.
pub fn normalize_rows(x: &mut [f32], dim: usize) {
    for row in x.chunks_exact_mut(dim) {
        let n = row.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
        row.iter_mut().for_each(|v| *v /= n);
    }
}

/// Mean over dimensions of the per-dimension standard deviation of
/// L2-normalised embeddings. About `1/sqrt(dim)` for a healthy spread, 0 when
/// the representation has collapsed to a point.
pub fn embedding_std(x: &[f32], dim: usize) -> f64 {
    let n = x.len() / dim;
    if n < 2 {
        return 0.0;
    }
    let mut total = 0.0f64;
    for d in 0..dim {
        let mean = x
            .iter()
            .skip(d)
            .step_by(dim)
            .map(|&v| v as f64)
            .sum::<f64>()
            / n as f64;
        let var = x
            .iter()
            .skip(d)
            .step_by(dim)
            .map(|&v| (v as f64 - mean).powi(2))
            .sum::<f64>()
            / (n - 1) as f64;
        total += var.sqrt();
    }
    total / dim as f64
}

/// For each query, the `k` most similar index rows as (similarity, row),
/// best first. Rows must be L2-normalised.
pub fn top_k(index: &[f32], queries: &[f32], dim: usize, k: usize) -> Vec<Vec<(f32, usize)>> {
    let nq = queries.len() / dim;
    let threads = std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
        .min(nq.max(1));
    let chunk = nq.div_ceil(threads.max(1)).max(1);
    std::thread::scope(|s| {
        let hs: Vec<_> = queries
            .chunks(chunk * dim)
            .map(|qs| {
                s.spawn(move || {
                    qs.chunks_exact(dim)
                        .map(|q| {
                            let mut best: Vec<(f32, usize)> = Vec::with_capacity(k + 1);
                            for (i, row) in index.chunks_exact(dim).enumerate() {
                                let sim: f32 = q.iter().zip(row).map(|(a, b)| a * b).sum();
                                if best.len() < k || sim > best[best.len() - 1].0 {
                                    let pos = best.partition_point(|&(s, _)| s >= sim);
                                    best.insert(pos, (sim, i));
                                    best.truncate(k);
                                }
                            }
                            best
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        hs.into_iter()
            .flat_map(|h| h.join().expect("knn thread"))
            .collect()
    })
}

/// kNN top-1 accuracy (k=1 and weighted with `k`, temperature `tau`).
pub fn knn_score(
    index: &[f32],
    index_labels: &[u32],
    queries: &[f32],
    query_labels: &[u32],
    dim: usize,
    k: usize,
    tau: f32,
) -> KnnScore {
    let nq = query_labels.len();
    assert_eq!(queries.len(), nq * dim);
    assert_eq!(index.len(), index_labels.len() * dim);
    if nq == 0 || index_labels.is_empty() {
        return KnnScore {
            top1_k1: 0.0,
            top1_weighted: 0.0,
            queries: nq,
        };
    }
    let n_classes = index_labels
        .iter()
        .chain(query_labels)
        .max()
        .map_or(0, |m| *m as usize + 1);
    let nn = top_k(index, queries, dim, k.max(1));
    let (mut ok1, mut okw) = (0usize, 0usize);
    let mut votes = vec![0f64; n_classes];
    for (q, neigh) in nn.iter().enumerate() {
        if index_labels[neigh[0].1] == query_labels[q] {
            ok1 += 1;
        }
        votes.iter_mut().for_each(|v| *v = 0.0);
        for &(sim, i) in neigh {
            votes[index_labels[i] as usize] += ((sim / tau) as f64).exp();
        }
        let best = votes
            .iter()
            .enumerate()
            .max_by(|a, b| a.1.total_cmp(b.1))
            .map(|(c, _)| c as u32)
            .unwrap_or(0);
        if best == query_labels[q] {
            okw += 1;
        }
    }
    KnnScore {
        top1_k1: ok1 as f64 / nq as f64,
        top1_weighted: okw as f64 / nq as f64,
        queries: nq,
    }
}

/// L2-normalise in place (zero vectors stay zero).
pub fn l2(v: &mut [f32]) {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 1e-12 {
        v.iter_mut().for_each(|x| *x /= n);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn knn_finds_the_right_cluster() {
        // Two clusters on the unit circle.
        let index = [1.0, 0.0, 0.9, 0.1, 0.0, 1.0, 0.1, 0.9];
        let mut index = index.to_vec();
        normalize_rows(&mut index, 2);
        let labels = [0, 0, 1, 1];
        let mut q = vec![0.8, 0.2, 0.2, 0.8, 0.95, 0.05];
        normalize_rows(&mut q, 2);
        let s = knn_score(&index, &labels, &q, &[0, 1, 1], 2, 3, 0.1);
        assert!((s.top1_k1 - 2.0 / 3.0).abs() < 1e-9);
        assert!((s.top1_weighted - 2.0 / 3.0).abs() < 1e-9);
        let nn = top_k(&index, &q, 2, 2);
        assert_eq!(nn[0][0].1, 1);
        assert!(nn[0][0].0 >= nn[0][1].0);
    }

    #[test]
    fn std_detects_collapse() {
        let collapsed = [1.0f32, 0.0].repeat(10);
        assert_eq!(embedding_std(&collapsed, 2), 0.0);
        let spread = [1.0f32, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0, -1.0].repeat(3);
        assert!(embedding_std(&spread, 2) > 0.5);
    }
}
