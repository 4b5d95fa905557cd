//! Small vector helpers.

/// Euclidean distance.
pub fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f32>()
        .sqrt()
}

/// Scale `v` to unit length in place (left as is if it is all zeros).
pub fn l2_normalise(v: &mut [f32]) {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    if n > 0.0 && n.is_finite() {
        v.iter_mut().for_each(|x| *x /= n);
    }
}

/// Mean of vectors, L2-normalised.
pub fn normalised_mean(vs: &[Vec<f32>], dim: usize) -> Vec<f32> {
    let mut m = vec![0.0f32; dim];
    for v in vs {
        for (a, b) in m.iter_mut().zip(v) {
            *a += b;
        }
    }
    l2_normalise(&mut m);
    m
}
