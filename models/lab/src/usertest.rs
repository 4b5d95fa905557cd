//! The paper's user test, reproduced against the simulator's ground truth:
//! for each query press, rank the roller's textiles by latent distance and by
//! ground-truth tactile-attribute distance, then compare the two rankings
//! (Top-K agreement, Spearman's rho per trial, one-sample t-test of rho = 0).

use anyhow::{ensure, Result};
use serde::Serialize;

use crate::data::ImageSet;
use crate::knn::normalize_rows;
use crate::methods::mean_rows;

/// Ranks (0 = best) of `scores` sorted ascending (smaller = closer).
pub fn ranks_ascending(scores: &[f64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..scores.len()).collect();
    order.sort_by(|&a, &b| scores[a].total_cmp(&scores[b]));
    let mut r = vec![0; scores.len()];
    for (rank, &i) in order.iter().enumerate() {
        r[i] = rank;
    }
    r
}

/// Spearman's rank correlation of two distance vectors (ties broken by
/// position; distances here are continuous).
pub fn spearman(a: &[f64], b: &[f64]) -> f64 {
    assert_eq!(a.len(), b.len());
    let n = a.len() as f64;
    if a.len() < 2 {
        return f64::NAN;
    }
    let (ra, rb) = (ranks_ascending(a), ranks_ascending(b));
    let d2: f64 = ra
        .iter()
        .zip(&rb)
        .map(|(&x, &y)| (x as f64 - y as f64).powi(2))
        .sum();
    1.0 - 6.0 * d2 / (n * (n * n - 1.0))
}

/// ln Gamma(x) for x > 0 (Lanczos, g = 7, 9 terms).
pub fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        let pi = std::f64::consts::PI;
        return (pi / (pi * x).sin()).ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    let t = x + 7.5;
    for (i, &c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

/// Continued fraction of the incomplete beta function (Numerical Recipes).
fn betacf(a: f64, b: f64, x: f64) -> f64 {
    let (qab, qap, qam) = (a + b, a + 1.0, a - 1.0);
    let tiny = 1e-300;
    let mut c = 1.0;
    let mut d = 1.0 - qab * x / qap;
    if d.abs() < tiny {
        d = tiny;
    }
    d = 1.0 / d;
    let mut h = d;
    for m in 1..300 {
        let m = m as f64;
        let m2 = 2.0 * m;
        let aa = m * (b - m) * x / ((qam + m2) * (a + m2));
        d = 1.0 + aa * d;
        if d.abs() < tiny {
            d = tiny;
        }
        c = 1.0 + aa / c;
        if c.abs() < tiny {
            c = tiny;
        }
        d = 1.0 / d;
        h *= d * c;
        let aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
        d = 1.0 + aa * d;
        if d.abs() < tiny {
            d = tiny;
        }
        c = 1.0 + aa / c;
        if c.abs() < tiny {
            c = tiny;
        }
        d = 1.0 / d;
        let del = d * c;
        h *= del;
        if (del - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

/// Regularised incomplete beta function I_x(a, b).
pub fn betai(a: f64, b: f64, x: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let bt = (ln_gamma(a + b) - ln_gamma(a) - ln_gamma(b) + a * x.ln() + b * (1.0 - x).ln()).exp();
    if x < (a + 1.0) / (a + b + 2.0) {
        bt * betacf(a, b, x) / a
    } else {
        1.0 - bt * betacf(b, a, 1.0 - x) / b
    }
}

/// Two-sided p-value of Student's t with `df` degrees of freedom.
pub fn t_two_sided_p(t: f64, df: f64) -> f64 {
    if !t.is_finite() {
        return if t.is_nan() { f64::NAN } else { 0.0 };
    }
    betai(df / 2.0, 0.5, df / (df + t * t))
}

/// One-sample t-test of mean = 0: (t, df, two-sided p).
pub fn one_sample_t(v: &[f64]) -> (f64, f64, f64) {
    let n = v.len() as f64;
    if v.len() < 2 {
        return (f64::NAN, 0.0, f64::NAN);
    }
    let m = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (n - 1.0);
    let t = m / (var / n).sqrt();
    (t, n - 1.0, t_two_sided_p(t, n - 1.0))
}

/// One trial: a query's latent and ground-truth distances to every roller slot.
pub struct Trial {
    /// Latent (cosine) distance to each roller textile.
    pub latent: Vec<f64>,
    /// Ground-truth attribute distance to each roller textile.
    pub truth: Vec<f64>,
}

/// Summary of a set of trials.
#[derive(Clone, Debug, Serialize)]
pub struct UserTestResult {
    /// Number of trials.
    pub trials: usize,
    /// Mean |TopK(latent) ∩ TopK(truth)| / K for K = 1..=N.
    pub topk_agreement: Vec<f64>,
    /// Share of trials whose ground-truth closest roller textile is in the
    /// latent Top-K, K = 1..=N (K = 1: the roller turns to the perceptually
    /// closest textile).
    pub top1_in_topk: Vec<f64>,
    /// Mean Spearman rho over trials.
    pub spearman_mean: f64,
    /// Standard deviation of rho over trials.
    pub spearman_sd: f64,
    /// One-sample t statistic of rho (H0: mean rho = 0).
    pub t: f64,
    /// Degrees of freedom.
    pub df: f64,
    /// Two-sided p-value.
    pub p: f64,
}

/// Evaluate trials.
pub fn evaluate(trials: &[Trial]) -> UserTestResult {
    let n = trials.first().map_or(0, |t| t.latent.len());
    let mut agree = vec![0.0; n];
    let mut hit = vec![0.0; n];
    let mut rhos = Vec::with_capacity(trials.len());
    for t in trials {
        let rl = ranks_ascending(&t.latent);
        let rt = ranks_ascending(&t.truth);
        for k in 1..=n {
            let inter = (0..n).filter(|&i| rl[i] < k && rt[i] < k).count();
            agree[k - 1] += inter as f64 / k as f64;
            let best = (0..n).find(|&i| rt[i] == 0).unwrap_or(0);
            if rl[best] < k {
                hit[k - 1] += 1.0;
            }
        }
        rhos.push(spearman(&t.latent, &t.truth));
    }
    let m = trials.len().max(1) as f64;
    agree.iter_mut().for_each(|v| *v /= m);
    hit.iter_mut().for_each(|v| *v /= m);
    let (t, df, p) = one_sample_t(&rhos);
    let mean = rhos.iter().sum::<f64>() / m;
    let sd = (rhos.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / (m - 1.0).max(1.0)).sqrt();
    UserTestResult {
        trials: trials.len(),
        topk_agreement: agree,
        top1_in_topk: hit,
        spearman_mean: mean,
        spearman_sd: sd,
        t,
        df,
        p,
    }
}

/// One method's user test: seen textiles (the training book, roller
/// textiles themselves left out) and unseen ones.
#[derive(Clone, Debug, Serialize)]
pub struct MethodUserTest {
    pub name: String,
    pub seen: UserTestResult,
    pub unseen: UserTestResult,
}

/// Ground-truth attribute distance between two classes.
pub fn attr_distance(attrs: &[Option<Vec<f32>>], a: u32, b: u32) -> Option<f64> {
    let (x, y) = (
        attrs.get(a as usize)?.as_ref()?,
        attrs.get(b as usize)?.as_ref()?,
    );
    Some(
        x.iter()
            .zip(y)
            .map(|(p, q)| ((p - q) as f64).powi(2))
            .sum::<f64>()
            .sqrt(),
    )
}

/// The trials of one method: every query press (mean of its frames'
/// embeddings) against the roller textiles' centroids (mean of the
/// training people's index embeddings), latent distance `1 - cos`;
/// ground truth: attribute distance. `index`/`ie` are the training people's
/// frames and embeddings, `queries`/`qe` the presses to test.
#[allow(clippy::too_many_arguments)]
pub fn trials(
    index: &ImageSet,
    ie: &[f32],
    queries: &ImageSet,
    qe: &[f32],
    dim: usize,
    roller: &[u32],
    attrs: &[Option<Vec<f32>>],
) -> Result<Vec<Trial>> {
    let mut centroids = Vec::new();
    for &r in roller {
        let rows: Vec<usize> = (0..index.len())
            .filter(|&i| index.items[i].class == r)
            .collect();
        ensure!(
            !rows.is_empty(),
            "roller textile {} has no index frames",
            index.classes.get(r as usize).map_or("?", |s| s.as_str())
        );
        centroids.extend(mean_rows(ie, dim, &rows));
    }
    normalize_rows(&mut centroids, dim);
    let mut presses: std::collections::BTreeMap<(u32, u32), Vec<usize>> = Default::default();
    for (i, m) in queries.items.iter().enumerate() {
        if !roller.contains(&m.class) {
            presses.entry((m.press, m.class)).or_default().push(i);
        }
    }
    let mut out = Vec::new();
    for (&(_, class), rows) in &presses {
        let mut q = mean_rows(qe, dim, rows);
        normalize_rows(&mut q, dim);
        let latent: Vec<f64> = centroids
            .chunks_exact(dim)
            .map(|c| 1.0 - c.iter().zip(&q).map(|(a, b)| (a * b) as f64).sum::<f64>())
            .collect();
        let truth: Option<Vec<f64>> = roller
            .iter()
            .map(|&r| attr_distance(attrs, class, r))
            .collect();
        let Some(truth) = truth else {
            anyhow::bail!("the frame source has no ground-truth attributes");
        };
        out.push(Trial { latent, truth });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn t_distribution_matches_tables() {
        // Critical values: t_{0.975, df}.
        for (t, df) in [(12.706, 1.0), (2.776, 4.0), (2.228, 10.0), (1.960, 1e6)] {
            let p = t_two_sided_p(t, df);
            assert!((p - 0.05).abs() < 1e-3, "df {df}: p {p}");
        }
        assert!((t_two_sided_p(0.0, 7.0) - 1.0).abs() < 1e-12);
        assert!((ln_gamma(5.0) - 24f64.ln()).abs() < 1e-10);
        assert!((betai(2.0, 3.0, 0.4) - 0.5248).abs() < 1e-4);
    }

    #[test]
    fn spearman_and_topk() {
        assert_eq!(spearman(&[1.0, 2.0, 3.0], &[10.0, 20.0, 30.0]), 1.0);
        assert_eq!(spearman(&[1.0, 2.0, 3.0], &[3.0, 2.0, 1.0]), -1.0);
        let same = Trial {
            latent: vec![0.1, 0.5, 0.3, 0.9],
            truth: vec![1.0, 5.0, 3.0, 9.0],
        };
        // Latent order exactly reversed against the truth.
        let rev = Trial {
            latent: vec![0.9, 0.1, 0.5, 0.3],
            truth: vec![1.0, 9.0, 3.0, 5.0],
        };
        let r = evaluate(&[same, rev]);
        assert_eq!(r.trials, 2);
        assert_eq!(r.topk_agreement[0], 0.5);
        assert_eq!(r.topk_agreement[3], 1.0);
        assert_eq!(r.top1_in_topk[0], 0.5);
        assert_eq!(r.top1_in_topk[3], 1.0);
        assert_eq!(r.spearman_mean, 0.0);
        let (t, df, p) = one_sample_t(&[0.5, 0.6, 0.4, 0.55]);
        assert!(t > 5.0 && df == 3.0 && p < 0.01);
    }
}
