//! The evaluation tables of `docs/evaluation.md` on the paper's data
//! protocol ([`crate::protocol`]): kNN across people, jig against
//! hand-held, unseen textiles mapped to the nearest known one.

use anyhow::{Context, Result};
use serde::Serialize;
use std::path::Path;

use crate::data::ImageSet;
use crate::knn::{knn_score, top_k, KnnScore};
use crate::train::INDEX_FRAMES;

use crate::protocol::{Protocol, Sets};

/// One row of a results table.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    /// What was evaluated.
    pub name: String,
    /// Index description.
    pub index: String,
    /// kNN scores.
    pub score: KnnScore,
}

/// Mapping of one unseen textile.
#[derive(Clone, Debug, Serialize)]
pub struct UnseenRow {
    /// Unseen textile id.
    pub textile: String,
    /// Most frequent nearest known textile over its query frames.
    pub nearest: String,
    /// Fraction of its frames mapped to `nearest`.
    pub agreement: f64,
    /// Mean cosine similarity to the nearest known frame.
    pub similarity: f64,
    /// Attribute distance to `nearest` (if attributes are known).
    pub attr_dist: Option<f64>,
    /// Rank of `nearest` among all known textiles by attribute distance (1 = closest).
    pub attr_rank: Option<usize>,
}

/// One press of an unseen textile, decided as the daemon decides a press:
/// its mean embedding against the known textiles' centroids.
#[derive(Clone, Debug, Serialize)]
pub struct UnseenPress {
    /// Unseen textile id.
    pub textile: String,
    /// The known textile whose centroid is nearest the press's mean.
    pub chosen: String,
    /// Attribute distance to `chosen` (if attributes are known).
    pub attr_dist: Option<f64>,
    /// Rank of `chosen` among all known textiles by attribute distance.
    pub attr_rank: Option<usize>,
}

/// Evaluation results.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Protocol used.
    pub protocol: Protocol,
    /// The learned distance every embedding was mapped by (`eval
    /// --index-metric`), in words; None: cosine.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metric: Option<String>,
    /// (a) across people.
    pub across_people: Vec<Row>,
    /// (b) one person, jig vs hand-held.
    pub jig_vs_handheld: Vec<Row>,
    /// (c) unseen textiles.
    pub unseen: Vec<UnseenRow>,
    /// (c) per press of an unseen textile, as the daemon decides.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unseen_presses: Vec<UnseenPress>,
    /// The attribute map fitted on the known textiles' index presses.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub attribute_map: Option<AttributeFit>,
    /// (c) per press of an unseen textile, decided by its predicted
    /// attributes (`crate::attrmap::AttributeMap::feels_like`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub unseen_presses_attr: Vec<UnseenPress>,
    /// Mean attribute distance between random pairs of known textiles.
    pub attr_dist_random: Option<f64>,
}

/// How an attribute map was fitted.
#[derive(Clone, Debug, Serialize)]
pub struct AttributeFit {
    pub lambda: f32,
    pub cv_rmse: f32,
    /// Per attribute (name, share of its variance predicted for left-out
    /// fabrics): how much of it the embedding carries.
    pub cv_r2: Vec<(String, f32)>,
    pub presses: u32,
    pub fabrics: u32,
}

fn sel(
    set: &ImageSet,
    emb: &[f32],
    dim: usize,
    f: impl Fn(&crate::data::FrameMeta) -> bool,
) -> (Vec<f32>, Vec<u32>) {
    let idx: Vec<usize> = (0..set.len()).filter(|&i| f(&set.items[i])).collect();
    (
        crate::train::rows(emb, dim, &idx),
        idx.iter().map(|&i| set.items[i].class).collect(),
    )
}

fn score(index: &(Vec<f32>, Vec<u32>), q: &(Vec<f32>, Vec<u32>), dim: usize) -> KnnScore {
    knn_score(&index.0, &index.1, &q.0, &q.1, dim, 20, 0.07)
}

fn cat(a: (Vec<f32>, Vec<u32>), b: (Vec<f32>, Vec<u32>)) -> (Vec<f32>, Vec<u32>) {
    (
        a.0.into_iter().chain(b.0).collect(),
        a.1.into_iter().chain(b.1).collect(),
    )
}

/// Run the whole evaluation with an ONNX model through ONNX Runtime (`sets`
/// in the model's view; a background-subtracting model gets each frame's
/// sensor reference from `sets.backgrounds`).
pub fn evaluate(
    model: &crate::methods::Method,
    sets: &Sets,
    p: &Protocol,
    threads: usize,
) -> Result<Report> {
    evaluate_with(model, sets, p, threads, None)
}

/// [`evaluate`], every embedding first mapped by the within-fabric
/// whitening (`telextiles_index::Metric`, shrinkage `metric`) learned from
/// the training people's index presses alone (the presses a `--sim` index
/// is built from; nothing of the held-out people, hand-held presses or
/// unseen textiles), as an index with a learned distance maps its
/// queries. `metric.report` says which.
pub fn evaluate_with(
    model: &crate::methods::Method,
    sets: &Sets,
    p: &Protocol,
    threads: usize,
    metric: Option<f32>,
) -> Result<Report> {
    let mut enc = crate::methods::Embedder::new(model, threads)?;
    let bg = |s: u32| sets.background(s);
    let (mut e_train, d) = enc.embed(&sets.train_index, bg)?;
    let (mut e_held, _) = enc.embed(&sets.heldout, bg)?;
    let (mut e_hand, _) = enc.embed(&sets.handheld, bg)?;
    let (mut e_unseen, _) = enc.embed(&sets.unseen, bg)?;
    let is_idx = |m: &crate::data::FrameMeta| m.frame < INDEX_FRAMES;
    let learned = match metric {
        Some(a) => {
            let m = learn_metric(&sets.train_index, &e_train, d, a, is_idx)
                .context("no training textile has two index presses to learn a distance from")?;
            for e in [&mut e_train, &mut e_held, &mut e_hand, &mut e_unseen] {
                apply_metric(&m, e, d);
            }
            Some(format!(
                "within-fabric whitening, shrinkage {a}, learned from {} training presses of {} textiles",
                m.presses, m.fabrics
            ))
        }
        None => None,
    };
    let is_q = |m: &crate::data::FrameMeta| m.frame >= INDEX_FRAMES;
    let mut across = Vec::new();
    let train_idx = sel(&sets.train_index, &e_train, d, is_idx);
    let all_q = sel(&sets.heldout, &e_held, d, is_q);
    across.push(Row {
        name: format!(
            "held-out people {:?} (queries: last 30 frames)",
            p.heldout.iter().map(|h| h.0).collect::<Vec<_>>()
        ),
        index: format!("training people {:?}, first 120 frames", p.train_people),
        score: score(&train_idx, &all_q, d),
    });
    let mut within_all = (Vec::new(), Vec::new());
    let mut within_q = (Vec::new(), Vec::new());
    let mut within_rows = Vec::new();
    for &(person, sensor) in &p.heldout {
        let q = sel(&sets.heldout, &e_held, d, |m| m.person == person && is_q(m));
        let own = sel(&sets.heldout, &e_held, d, |m| {
            m.person == person && is_idx(m)
        });
        across.push(Row {
            name: format!("person {person} (sensor {sensor})"),
            index: "training people, first 120 frames".into(),
            score: score(&train_idx, &q, d),
        });
        let others = sel(&sets.heldout, &e_held, d, |m| {
            m.person != person && is_idx(m)
        });
        across.push(Row {
            name: format!("person {person} (sensor {sensor})"),
            index: "the other held-out people, first 120 frames".into(),
            score: score(&others, &q, d),
        });
        within_rows.push(Row {
            name: format!("person {person} (sensor {sensor})"),
            index: "own press, first 120 frames (paper split)".into(),
            score: score(&own, &q, d),
        });
        within_all = cat(within_all, own);
        within_q = cat(within_q, q);
    }
    let _ = (within_all, within_q);
    across.extend(within_rows);
    // (b) one person: jig vs hand-held, per-press split (paper Table 2).
    let (person, sensor) = p.heldout[0];
    let mut jig_rows = Vec::new();
    let jig_idx = sel(&sets.heldout, &e_held, d, |m| {
        m.person == person && is_idx(m)
    });
    let jig_q = sel(&sets.heldout, &e_held, d, |m| m.person == person && is_q(m));
    let hand_idx = sel(&sets.handheld, &e_hand, d, is_idx);
    let hand_q = sel(&sets.handheld, &e_hand, d, is_q);
    jig_rows.push(Row {
        name: format!("person {person}, sensor {sensor}, jig"),
        index: "same presses, first 120 frames".into(),
        score: score(&jig_idx, &jig_q, d),
    });
    jig_rows.push(Row {
        name: format!("person {person}, sensor {sensor}, hand-held"),
        index: "same presses, first 120 frames".into(),
        score: score(&hand_idx, &hand_q, d),
    });
    jig_rows.push(Row {
        name: format!("person {person}, hand-held queries"),
        index: "jig presses of the same person".into(),
        score: score(&jig_idx, &hand_q, d),
    });
    jig_rows.push(Row {
        name: format!("person {person}, hand-held queries"),
        index: "training people (jig)".into(),
        score: score(&train_idx, &hand_q, d),
    });
    // (c) unseen textiles mapped to the nearest known one.
    let known = cat(train_idx.clone(), sel(&sets.heldout, &e_held, d, is_idx));
    let n_train_classes = sets.train.classes.len() - unseen_classes(sets);
    let mut unseen_rows = Vec::new();
    let mut uclasses: Vec<u32> = sets.unseen.items.iter().map(|m| m.class).collect();
    uclasses.sort_unstable();
    uclasses.dedup();
    let attr_dist = |a: usize, b: usize| -> Option<f64> {
        let (x, y) = (
            sets.attributes.get(a)?.as_ref()?,
            sets.attributes.get(b)?.as_ref()?,
        );
        Some(
            x.iter()
                .zip(y)
                .map(|(p, q)| ((p - q) as f64).powi(2))
                .sum::<f64>()
                .sqrt(),
        )
    };
    // Rank of a known textile at attribute distance `dist` from unseen
    // `uc`: 1 + the known textiles nearer it in attributes.
    let attr_rank = |uc: u32, dist: f64| {
        (0..n_train_classes)
            .filter(|&k| attr_dist(uc as usize, k).is_some_and(|x| x < dist))
            .count()
            + 1
    };
    for &uc in &uclasses {
        let q = sel(&sets.unseen, &e_unseen, d, |m| m.class == uc);
        let nn = top_k(&known.0, &q.0, d, 1);
        let mut counts = vec![0usize; n_train_classes];
        let mut sim = 0.0;
        for r in &nn {
            counts[known.1[r[0].1] as usize] += 1;
            sim += r[0].0 as f64;
        }
        let (best, cnt) = counts
            .iter()
            .enumerate()
            .max_by_key(|(_, c)| **c)
            .map(|(i, c)| (i, *c))
            .unwrap_or((0, 0));
        let ad = attr_dist(uc as usize, best);
        unseen_rows.push(UnseenRow {
            textile: sets.train.classes[uc as usize].clone(),
            nearest: sets.train.classes[best].clone(),
            agreement: cnt as f64 / nn.len().max(1) as f64,
            similarity: sim / nn.len().max(1) as f64,
            attr_dist: ad,
            attr_rank: ad.map(|dist| attr_rank(uc, dist)),
        });
    }
    // Per press, as the daemon decides one.
    let mut unseen_presses = Vec::new();
    for (uc, best) in press_choices(&known, n_train_classes, &sets.unseen.items, &e_unseen, d) {
        let ad = attr_dist(uc as usize, best);
        unseen_presses.push(UnseenPress {
            textile: sets.train.classes[uc as usize].clone(),
            chosen: sets.train.classes[best].clone(),
            attr_dist: ad,
            attr_rank: ad.map(|dist| attr_rank(uc, dist)),
        });
    }
    // Per press, by what it is predicted to feel like: a ridge map from a
    // press's mean embedding to the attributes of the known textiles (the
    // maker's sample book), fitted on the known textiles' index presses
    // alone; the chosen known textile is the one nearest in attributes.
    let known_presses: Vec<(u32, Vec<f32>)> =
        press_sums(&sets.train_index.items, &e_train, d, is_idx)
            .into_iter()
            .chain(press_sums(&sets.heldout.items, &e_held, d, is_idx))
            .filter(|((class, ..), _)| (*class as usize) < n_train_classes)
            .map(|((class, ..), (sum, _))| (class, sum))
            .collect();
    let targets: Vec<Option<Vec<f32>>> = (0..n_train_classes)
        .map(|k| sets.attributes.get(k).cloned().flatten())
        .collect();
    // The simulator's attributes (the only source of them here).
    let names: Vec<String> = telextiles_sim::catalogue::Attributes::NAMES
        .iter()
        .map(|n| n.to_string())
        .collect();
    let (attribute_map, chosen) = attribute_choices(
        &known_presses,
        &targets,
        &names,
        &sets.unseen.items,
        &e_unseen,
        d,
    );
    let unseen_presses_attr: Vec<UnseenPress> = chosen
        .into_iter()
        .map(|(class, best)| {
            let ad = attr_dist(class as usize, best);
            UnseenPress {
                textile: sets.train.classes[class as usize].clone(),
                chosen: sets.train.classes[best].clone(),
                attr_dist: ad,
                attr_rank: ad.map(|dist| attr_rank(class, dist)),
            }
        })
        .collect();
    let mut rd = (0.0, 0usize);
    for a in 0..n_train_classes {
        for b in 0..a {
            if let Some(x) = attr_dist(a, b) {
                rd.0 += x;
                rd.1 += 1;
            }
        }
    }
    Ok(Report {
        protocol: p.clone(),
        metric: learned,
        across_people: across,
        jig_vs_handheld: jig_rows,
        unseen: unseen_rows,
        unseen_presses,
        attribute_map: attribute_map.map(|m| AttributeFit {
            lambda: m.lambda,
            cv_rmse: m.cv_rmse,
            cv_r2: m
                .names
                .iter()
                .cloned()
                .zip(m.cv_r2.iter().copied())
                .collect(),
            presses: m.presses,
            fabrics: m.fabrics,
        }),
        unseen_presses_attr,
        attr_dist_random: (rd.1 > 0).then(|| rd.0 / rd.1 as f64),
    })
}

/// One press: class, press, person, sensor.
type PressId = (u32, u32, u32, u32);

/// `v` scaled to unit length; None for a zero or non-finite vector.
fn unit(v: &[f32]) -> Option<Vec<f32>> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    (n.is_finite() && n > 0.0).then(|| v.iter().map(|x| x / n).collect())
}

/// Per press (frames of `items` passing `keep`, rows of `emb`): the sum of
/// its frames' unit embeddings and how many there are (zero or non-finite
/// rows skipped).
fn press_sums(
    items: &[crate::data::FrameMeta],
    emb: &[f32],
    d: usize,
    keep: impl Fn(&crate::data::FrameMeta) -> bool,
) -> std::collections::BTreeMap<PressId, (Vec<f32>, usize)> {
    let mut sums: std::collections::BTreeMap<PressId, (Vec<f32>, usize)> = Default::default();
    for (m, row) in items.iter().zip(emb.chunks(d)) {
        let Some(v) = unit(row).filter(|_| keep(m)) else {
            continue;
        };
        let s = sums
            .entry((m.class, m.press, m.person, m.sensor))
            .or_insert_with(|| (vec![0.0; d], 0));
        s.0.iter_mut().zip(&v).for_each(|(a, b)| *a += b);
        s.1 += 1;
    }
    sums
}

/// The known textile each press of `items` is decided as, the way the
/// daemon decides a press: the press's mean embedding (frames grouped by
/// class, press, person and sensor; each frame normalised) against each
/// known textile's centroid (the normalised mean of its `known` frames,
/// classes below `n_known`). (press class, chosen class) in press order.
fn press_choices(
    known: &(Vec<f32>, Vec<u32>),
    n_known: usize,
    items: &[crate::data::FrameMeta],
    emb: &[f32],
    d: usize,
) -> Vec<(u32, usize)> {
    let mut centroids = vec![vec![0f32; d]; n_known];
    for (row, &c) in known.0.chunks(d).zip(&known.1) {
        if let (Some(v), Some(cen)) = (unit(row), centroids.get_mut(c as usize)) {
            cen.iter_mut().zip(&v).for_each(|(a, b)| *a += b);
        }
    }
    let centroids: Vec<Option<Vec<f32>>> = centroids.iter().map(|c| unit(c)).collect();
    let sums = press_sums(items, emb, d, |_| true);
    sums.into_iter()
        .filter_map(|((class, ..), (sum, _))| {
            let q = unit(&sum)?;
            let best = centroids
                .iter()
                .enumerate()
                .filter_map(|(k, c)| {
                    let c = c.as_ref()?;
                    Some((k, c.iter().zip(&q).map(|(a, b)| a * b).sum::<f32>()))
                })
                .max_by(|a, b| a.1.total_cmp(&b.1))?
                .0;
            Some((class, best))
        })
        .collect()
}

/// The known textile each press of `items` feels most like, by a maker's
/// attribute map: a ridge map from a press's mean embedding to the
/// attributes `targets` (per known class; None: not measured), fitted on the
/// `known` presses (class, summed embedding) alone; each press goes to the
/// known class nearest in predicted attributes. The map (None when it cannot
/// be fitted, and then no choices) and (press class, chosen class) in press
/// order.
fn attribute_choices(
    known: &[(u32, Vec<f32>)],
    targets: &[Option<Vec<f32>>],
    names: &[String],
    items: &[crate::data::FrameMeta],
    emb: &[f32],
    d: usize,
) -> (Option<crate::attrmap::AttributeMap>, Vec<(u32, usize)>) {
    let samples: Vec<crate::attrmap::Sample> = known
        .iter()
        .map(|(c, v)| crate::attrmap::Sample {
            fabric: *c as usize,
            embedding: v,
        })
        .collect();
    let Some(map) = crate::attrmap::AttributeMap::fit(&samples, targets, names, d) else {
        return (None, Vec::new());
    };
    let cands: Vec<(usize, &[f32])> = targets
        .iter()
        .enumerate()
        .filter_map(|(k, a)| Some((k, a.as_deref()?)))
        .collect();
    let chosen = press_sums(items, emb, d, |_| true)
        .into_iter()
        .filter_map(|((class, ..), (sum, _))| {
            Some((class, map.feels_like(&sum, cands.iter().copied())?.0))
        })
        .collect();
    (Some(map), chosen)
}

/// Within-fabric whitening learned from `set`'s presses (frames passing
/// `keep`): each press's mean embedding, grouped by textile.
fn learn_metric(
    set: &ImageSet,
    emb: &[f32],
    dim: usize,
    shrinkage: f32,
    keep: impl Fn(&crate::data::FrameMeta) -> bool,
) -> Option<telextiles_index::Metric> {
    let sums = press_sums(&set.items, emb, dim, keep);
    let mut fabrics: std::collections::BTreeMap<u32, Vec<Vec<f32>>> = Default::default();
    for ((class, ..), (sum, k)) in sums {
        fabrics
            .entry(class)
            .or_default()
            .push(sum.into_iter().map(|x| x / k as f32).collect());
    }
    let fabrics: Vec<Vec<Vec<f32>>> = fabrics.into_values().collect();
    telextiles_index::Metric::within_fabric(&fabrics, dim, shrinkage)
}

/// Map every row of `emb` by the metric (unit rows out; non-finite rows
/// stay as they are).
fn apply_metric(m: &telextiles_index::Metric, emb: &mut [f32], dim: usize) {
    for row in emb.chunks_mut(dim) {
        if row.iter().all(|x| x.is_finite()) {
            let v = m.apply(row);
            row.copy_from_slice(&v);
        }
    }
}

/// The number of unseen classes of `sets` (those after the training ones).
fn unseen_classes(sets: &Sets) -> usize {
    let mut c: Vec<u32> = sets.unseen.items.iter().map(|m| m.class).collect();
    c.sort_unstable();
    c.dedup();
    let min = c
        .first()
        .copied()
        .unwrap_or(sets.train.classes.len() as u32) as usize;
    sets.train.classes.len() - min
}

impl Report {
    /// Markdown tables.
    pub fn markdown(&self, model: &Path) -> String {
        let mut s = String::new();
        let pct = |x: f64| format!("{:.2}%", 100.0 * x);
        s.push_str(&format!("Model: `{}`\n\n", model.display()));
        if let Some(m) = &self.metric {
            s.push_str(&format!(
                "Distance: {m} (`--index-metric`), every embedding mapped by it.\n\n"
            ));
        }
        let rows = |s: &mut String, rows: &[Row]| {
            for r in rows {
                s.push_str(&format!(
                    "| {} | {} | {} | {} | {} |\n",
                    r.name,
                    r.index,
                    pct(r.score.top1_k1),
                    pct(r.score.top1_weighted),
                    r.score.queries
                ));
            }
        };
        s.push_str("### (a) Across people\n\n| queries | index | kNN top-1 (k=1) | weighted kNN top-1 (k=20, T=0.07) | queries |\n|---|---|---|---|---|\n");
        rows(&mut s, &self.across_people);
        s.push_str("\n### (b) One person, jig vs hand-held (shape of the paper's Table 2)\n\n| queries | index | kNN top-1 (k=1) | weighted kNN top-1 | queries |\n|---|---|---|---|---|\n");
        rows(&mut s, &self.jig_vs_handheld);
        s.push_str("\n### (c) Unseen textiles mapped to the nearest known textile\n\n| unseen | nearest known | frames agreeing | mean cosine | attribute distance | attribute rank of nearest (of known) |\n|---|---|---|---|---|---|\n");
        for u in &self.unseen {
            s.push_str(&format!(
                "| {} | {} | {} | {:.3} | {} | {} |\n",
                u.textile,
                u.nearest,
                pct(u.agreement),
                u.similarity,
                u.attr_dist.map_or("-".into(), |x| format!("{x:.3}")),
                u.attr_rank.map_or("-".into(), |x| x.to_string())
            ));
        }
        if let Some(r) = self.attr_dist_random {
            let mean = self.unseen.iter().filter_map(|u| u.attr_dist).sum::<f64>()
                / self.unseen.len().max(1) as f64;
            let ranks: Vec<f64> = self
                .unseen
                .iter()
                .filter_map(|u| u.attr_rank.map(|x| x as f64))
                .collect();
            s.push_str(&format!(
                "\nMean attribute distance unseen -> nearest known: {mean:.3}; between random known pairs: {r:.3}; median attribute rank of the nearest: {}.\n",
                crate::bench::median(&ranks)
            ));
            for (p, how) in [
                (&self.unseen_presses, "as the daemon decides one (each press's mean embedding against the known textiles' centroids"),
                (&self.unseen_presses_attr, "by what it feels like (the known textile nearest in attributes to the press's attributes as predicted by a ridge map from its mean embedding, fitted on the known textiles' index presses"),
            ] {
                if p.is_empty() {
                    continue;
                }
                let mean = p.iter().filter_map(|u| u.attr_dist).sum::<f64>() / p.len() as f64;
                let ranks: Vec<f64> = p
                    .iter()
                    .filter_map(|u| u.attr_rank.map(|x| x as f64))
                    .collect();
                let within = |k: f64| ranks.iter().filter(|&&x| x <= k).count();
                s.push_str(&format!(
                    "\nPer press, {how}; {} presses of {} unseen textiles): median attribute rank of the chosen known textile {}, mean attribute distance {mean:.3}; rank 1: {} presses, rank <= 5: {}, rank <= 10: {}.\n",
                    p.len(),
                    self.unseen.len(),
                    crate::bench::median(&ranks),
                    within(1.0),
                    within(5.0),
                    within(10.0),
                ));
            }
            if let Some(f) = &self.attribute_map {
                let r2: Vec<String> = f.cv_r2.iter().map(|(n, r)| format!("{n} {r:.2}")).collect();
                s.push_str(&format!(
                    "\nAttribute map: ridge, strength {} chosen by {}-fold cross-validation over whole fabrics (held-out RMSE per attribute {:.3}), fitted on {} presses of {} known textiles. Share of each attribute's variance it predicts for fabrics left out of the fit (R²): {}.\n",
                    f.lambda,
                    crate::attrmap::FOLDS,
                    f.cv_rmse,
                    f.presses,
                    f.fabrics,
                    r2.join(", ")
                ));
            }
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::data::{FrameMeta, ImageKind, ImageSet};

    /// A press of an unseen class goes to the known class nearest in the
    /// attributes its embedding predicts, which need not be the one nearest
    /// in embedding: known classes on a circle whose attribute is their
    /// angle's cosine, plus a direction of their own that means nothing to
    /// the touch.
    #[test]
    fn unseen_presses_go_to_the_known_class_nearest_in_predicted_attributes() {
        let d = 16;
        let n = 12;
        let press = |class: usize, jitter: f32| {
            let a = std::f32::consts::TAU * class as f32 / n as f32;
            let mut v = vec![0.0f32; d];
            v[0] = a.cos();
            v[1] = a.sin();
            v[2 + class % (d - 2)] += 2.0 + jitter;
            v
        };
        let known: Vec<(u32, Vec<f32>)> = (0..n)
            .flat_map(|c| [0.0, 0.2, -0.2].map(|j| (c as u32, press(c, j))))
            .collect();
        let targets: Vec<Option<Vec<f32>>> = (0..n)
            .map(|c| {
                let a = std::f32::consts::TAU * c as f32 / n as f32;
                Some(vec![0.5 + 0.4 * a.cos(), 0.5 + 0.4 * a.sin()])
            })
            .collect();
        let names = vec!["roughness".to_string(), "softness".to_string()];
        // Unseen class 12: at known class 3's angle, but with class 7's own
        // direction, so its embedding lies nearest class 7's presses.
        let mut v = press(3, 0.0);
        v[2 + 3] = 0.0;
        v[2 + 7] = 2.0;
        let cos = |a: &[f32], b: &[f32]| {
            let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
            dot / (a.iter().map(|x| x * x).sum::<f32>() * b.iter().map(|x| x * x).sum::<f32>())
                .sqrt()
        };
        let nearest = (0..n)
            .max_by(|&a, &b| cos(&v, &press(a, 0.0)).total_cmp(&cos(&v, &press(b, 0.0))))
            .unwrap();
        assert_eq!(nearest, 7, "nearest in embedding");
        let items = vec![FrameMeta {
            class: 12,
            press: 0,
            person: 9,
            sensor: 4,
            jig: true,
            frame: 0,
        }];
        let (map, chosen) = attribute_choices(&known, &targets, &names, &items, &v, d);
        let map = map.expect("a map");
        assert_eq!(map.fabrics, 12);
        // Class 3 or a neighbour on the circle (the fit is of 12 classes),
        // never class 7, a third of the circle away.
        assert_eq!(chosen.len(), 1);
        assert!([2, 3, 4].contains(&chosen[0].1), "{chosen:?}");
        assert_eq!(chosen[0].0, 12);
        // Without attributes there is no map and no choice.
        let none = vec![None; n];
        assert_eq!(
            attribute_choices(&known, &none, &names, &items, &v, d).1,
            vec![]
        );
    }

    /// Each press is decided by its mean against the known centroids: a
    /// press whose frames straddle two textiles goes to the one its mean
    /// is nearer, whatever a single frame says.
    #[test]
    fn unseen_presses_are_decided_by_their_mean_against_the_centroids() {
        // Known: class 0 along x, class 1 along y (two frames each).
        let known = (
            vec![1.0, 0.0, 1.0, 0.1, 0.0, 1.0, 0.1, 1.0],
            vec![0, 0, 1, 1],
        );
        let meta = |class, press| FrameMeta {
            class,
            press,
            person: 9,
            sensor: 4,
            jig: true,
            frame: 0,
        };
        // Unseen class 2: press 0's frames lean x (one of them y), press 1's
        // y; a zero frame is skipped.
        let items = vec![meta(2, 0), meta(2, 0), meta(2, 0), meta(2, 1), meta(2, 1)];
        let emb = vec![1.0, 0.2, 0.9, 0.0, 0.0, 1.0, 0.2, 1.0, 0.0, 0.0];
        assert_eq!(
            press_choices(&known, 2, &items, &emb, 2),
            vec![(2, 0), (2, 1)]
        );
    }

    /// Two textiles whose presses differ along the second axis more than
    /// the textiles differ along the third: the whitening learned from the
    /// index presses (only those `keep` passes) brings a press of b that
    /// leans the way a's presses do back to b.
    #[test]
    fn the_metric_is_learned_from_the_index_presses_and_maps_every_row() {
        let press = |class: u32, press: u32, v: [f32; 3]| {
            (0..4).map(move |frame| {
                (
                    FrameMeta {
                        class,
                        press,
                        person: press,
                        sensor: 0,
                        jig: true,
                        frame,
                    },
                    v,
                )
            })
        };
        // a's presses lean +y, b's -y; b differs from a along z.
        let rows: Vec<(FrameMeta, [f32; 3])> = press(0, 0, [1.0, 1.0, 0.0])
            .chain(press(0, 1, [1.0, 0.2, 0.0]))
            .chain(press(1, 2, [1.0, -0.2, 0.3]))
            .chain(press(1, 3, [1.0, -1.0, 0.3]))
            // Frames `keep` leaves out: they must not count.
            .chain(press(1, 4, [0.0, 0.0, 5.0]).map(|(mut m, v)| {
                m.frame += 200;
                (m, v)
            }))
            .collect();
        let set = ImageSet {
            kind: ImageKind::Input,
            side: 1,
            crop: 1,
            classes: vec!["a".into(), "b".into()],
            items: rows.iter().map(|r| r.0.clone()).collect(),
            pixels: Vec::new(),
            source: "test".into(),
        };
        let emb: Vec<f32> = rows.iter().flat_map(|r| r.1).collect();
        let m = learn_metric(&set, &emb, 3, 0.1, |f| f.frame < 100).unwrap();
        assert_eq!((m.presses, m.fabrics), (4, 2));
        // A press of b leaning far along the nuisance: cosine puts it
        // nearer a's centroid, the learned distance nearer b's.
        let unit = |v: [f32; 3]| {
            let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
            v.map(|x| x / n)
        };
        let (a, b, q) = (
            unit([1.0, 0.6, 0.0]),
            unit([1.0, -0.6, 0.3]),
            unit([1.0, 0.6, 0.3]),
        );
        let dist = |x: &[f32], y: &[f32]| {
            x.iter()
                .zip(y)
                .map(|(p, q)| (p - q) * (p - q))
                .sum::<f32>()
                .sqrt()
        };
        let mut rows = [a, b, q].concat();
        assert!(dist(&q, &a) < dist(&q, &b));
        apply_metric(&m, &mut rows, 3);
        let (a, b, q) = (&rows[0..3], &rows[3..6], &rows[6..9]);
        assert!(dist(q, b) < dist(q, a), "{rows:?}");
        assert!(rows
            .chunks(3)
            .all(|r| (dist(r, &[0.0; 3]) - 1.0).abs() < 1e-4));
        // No textile with two presses: nothing to learn.
        assert!(learn_metric(&set, &emb, 3, 0.1, |f| f.press == 0).is_none());
    }
}
