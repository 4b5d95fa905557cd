//! How a press's decision firms up frame by frame: the decision curve (the
//! share of presses right after each number of frames, by how the running
//! mean weighs frames, `depth_power`), the queries it is scored on, and the
//! depth-weighted mean.

use crate::data::ImageSet;
use crate::knn::normalize_rows;
use crate::methods::{background_of, mean_rows, Embedder, Method};
use crate::protocol::view_set;
use crate::stability::*;
use anyhow::Result;
use serde::Serialize;
use telextiles_sim::{PressSpec, Simulator};

/// Accuracy against time since first contact, across people: the held-out
/// people's jig presses (the same presses as the evaluation cache), each
/// method's running mean over the first n consecutive frames from the
/// first contact frame, against the training people's index.
#[derive(Clone, Debug, Serialize)]
pub struct DecisionCurve {
    pub name: String,
    /// (frames since first contact, top-1 of the running mean).
    pub top1: Vec<(usize, f64)>,
    /// The same with every frame weighted by its contact depth as the
    /// daemon's decider weights it (the `contact_weight` of the mean
    /// absolute difference from the reference in the method's view, what
    /// its contact detector scores, raised to the decider's default
    /// `depth_power` relative to the press's deepest frame so far): the
    /// ramp's shallow frames count less.
    #[serde(default)]
    pub weighted: Vec<(usize, f64)>,
    /// The weighted mean's top-1 for other values of the decider's
    /// `depth_power` ([`DEPTH_POWERS`]), at [`POWER_SCAN_FRAMES`]:
    /// (power, [(frames, top-1)]).
    #[serde(default)]
    pub by_power: Vec<(u32, Vec<(usize, f64)>)>,
}

/// The `depth_power` values the decision curve compares (1: each frame
/// by its contact weight as it is, as before `depth_power`).
pub const DEPTH_POWERS: [u32; 7] = [0, 1, 2, 4, 8, 12, 16];

/// Frames since first contact at which [`DecisionCurve::by_power`] is
/// measured (50, 100, 167, 250 and 500 ms at 60 fps).
pub const POWER_SCAN_FRAMES: [usize; 5] = [3, 6, 10, 15, 30];

/// Renders the held-out presses from first contact on (`frames` consecutive
/// frames).
pub fn decision_queries(
    sim: &Simulator,
    classes: &[String],
    textiles: &[String],
    heldout: &[(u32, u32)],
    frames: usize,
    threads: usize,
) -> Result<ImageSet> {
    let plans: Vec<Plan> = textiles
        .iter()
        .enumerate()
        .flat_map(|(c, t)| {
            heldout.iter().map(move |&(person, sensor)| Plan {
                spec: PressSpec {
                    person,
                    sensor,
                    jig: true,
                    ..PressSpec::new(t.as_str(), 2000 + person as u64)
                },
                class: c as u32,
                consecutive: Some(frames),
                from_contact: true,
                post: Post::None,
            })
        })
        .collect();
    render(sim, classes, &plans, 0, threads)
}

/// One method's accuracy against frames since first contact; `index` is the
/// training people's index in the method's view.
pub fn decision_curve(
    m: &Method,
    emb: &mut Embedder,
    queries: &ImageSet,
    index: &ImageSet,
    refs: &ImageSet,
) -> Result<DecisionCurve> {
    let (crop, input) = m.view();
    let iv = view_set(index, crop, input)?;
    let rv = view_set(refs, crop, input)?;
    let (ie, dim) = emb.embed(&iv, |s| background_of(&rv, s))?;
    let labels: Vec<u32> = iv.items.iter().map(|x| x.class).collect();
    let qv = view_set(queries, crop, input)?;
    let (qe, _) = emb.embed(&qv, |s| background_of(&rv, s))?;
    let mut presses: std::collections::BTreeMap<u32, Vec<usize>> = Default::default();
    for (i, it) in qv.items.iter().enumerate() {
        presses.entry(it.press).or_default().push(i);
    }
    let longest = presses.values().map(Vec::len).max().unwrap_or(0);
    // Contact depth of every query frame against its sensor's reference.
    let depth: Vec<f32> = (0..qv.len())
        .map(|i| {
            let img = qv.image(i);
            match background_of(&rv, qv.items[i].sensor) {
                // The daemon's weight of this depth.
                Some(r) => telextiles_sensing::decide::contact_weight(
                    img.iter()
                        .zip(r)
                        .map(|(&a, &b)| (a as f32 - b as f32).abs())
                        .sum::<f32>()
                        / img.len().max(1) as f32,
                ),
                None => 1.0,
            }
        })
        .collect();
    // Top-1 of every press's mean over its first `n` frames (`mean`: a
    // press's rows to their unnormalised mean).
    let score = |n: usize, mean: &dyn Fn(&[usize]) -> Vec<f32>| {
        let mut q = Vec::new();
        let mut ql = Vec::new();
        for rows in presses.values() {
            let rows = &rows[..n.min(rows.len())];
            q.extend(mean(rows));
            ql.push(qv.items[rows[0]].class);
        }
        normalize_rows(&mut q, dim);
        crate::methods::top1(&ie, &labels, &q, &ql, dim)
    };
    let weighted_at =
        |n: usize, p: u32| score(n, &|rows| depth_weighted_mean(&qe, dim, rows, &depth, p));
    let power = telextiles_sensing::decide::DecideConfig::default().depth_power;
    let top1 = (1..=longest)
        .map(|n| (n, score(n, &|rows| mean_rows(&qe, dim, rows))))
        .collect();
    let weighted = (1..=longest).map(|n| (n, weighted_at(n, power))).collect();
    let by_power = DEPTH_POWERS
        .iter()
        .map(|&p| {
            let scores = POWER_SCAN_FRAMES
                .iter()
                .filter(|&&n| n <= longest)
                .map(|&n| (n, weighted_at(n, p)))
                .collect();
            (p, scores)
        })
        .collect();
    Ok(DecisionCurve {
        name: m.name(),
        top1,
        weighted,
        by_power,
    })
}

/// The decider's running mean of `rows` of `e` (dimension `dim`), each row
/// with contact weight `weight[row]` and depth power `power`
/// ([`telextiles_sensing::decide::PressMean`]), not normalised.
pub fn depth_weighted_mean(
    e: &[f32],
    dim: usize,
    rows: &[usize],
    weight: &[f32],
    power: u32,
) -> Vec<f32> {
    let mut m = telextiles_sensing::decide::PressMean::new(dim, power);
    for &i in rows {
        m.add(&e[i * dim..(i + 1) * dim], weight[i]);
    }
    m.sum().to_vec()
}
