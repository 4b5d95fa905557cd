//! Speed against accuracy, measured in one run on the same held-out presses
//! (issue "Speed vs accuracy chart"): classical descriptors
//! ([`crate::baselines`]) and ONNX encoders, each timed per frame and scored
//! by kNN top-1 per frame, per press (the mean of a press's frame
//! embeddings) and against the number of frames aggregated (time to a
//! decision at 60 fps).
//!
//! Protocol: the across-people case of `docs/evaluation.md`: the index holds
//! the training people's index frames, the queries are every frame of the
//! held-out people's presses (their index and query frames; none of it was
//! seen in training).

use anyhow::Result;
use serde::Serialize;
use std::time::Instant;

use crate::baselines::Baseline;
use crate::bench::{median, quantile};
use crate::data::ImageSet;
use crate::knn::{normalize_rows, top_k};
use crate::onnx::OrtEncoder;
use crate::preprocess::normalize_into;

/// A method on the chart.
pub enum Method {
    /// A classical descriptor.
    Baseline(Baseline),
    /// An ONNX encoder (name, file bytes).
    Onnx(String, Vec<u8>),
}

impl Method {
    /// Name in tables and charts.
    pub fn name(&self) -> String {
        match self {
            Method::Baseline(b) => b.name(),
            Method::Onnx(n, _) => n.clone(),
        }
    }
}

/// One method's figures.
#[derive(Clone, Debug, Serialize)]
pub struct MethodResult {
    pub name: String,
    /// Descriptor or embedding length.
    pub dim: usize,
    /// Per-frame time, batch 1: (threads, p50 ms, p95 ms). Classical
    /// descriptors are single-threaded and timed once.
    pub latency: Vec<(usize, f64, f64)>,
    /// kNN top-1 (k = 1) per frame.
    pub frame_top1: f64,
    /// kNN top-1 of the mean embedding of each press's frames.
    pub press_top1: f64,
    /// (frames aggregated, top-1): the mean of a press's first n frames.
    pub by_frames: Vec<(usize, f64)>,
    pub queries: usize,
    pub presses: usize,
}

/// Embeds every image of `set` with `m` (L2-normalised rows); returns
/// (rows, dim).
pub fn embed(m: &Method, set: &ImageSet, threads: usize) -> Result<(Vec<f32>, usize)> {
    match m {
        Method::Baseline(b) => {
            let mut out = Vec::new();
            let mut dim = 0;
            for i in 0..set.len() {
                let f = b.features(set.image(i), set.side, set.side, None);
                dim = f.len();
                out.extend(f);
            }
            Ok((out, dim))
        }
        Method::Onnx(_, bytes) => {
            let mut enc = OrtEncoder::from_bytes(bytes, threads)?;
            anyhow::ensure!(
                enc.input_size == set.side,
                "encoder input {} differs from the frame cache's {}",
                enc.input_size,
                set.side
            );
            let emb = crate::protocol::embed_ort(&mut enc, set)?;
            Ok((emb, enc.dim))
        }
    }
}

/// Per-frame time of `m` on one image of `set`, batch 1.
pub fn time_method(
    m: &Method,
    set: &ImageSet,
    threads: &[usize],
    runs: usize,
) -> Result<Vec<(usize, f64, f64)>> {
    let img = set.image(0);
    let mut out = Vec::new();
    match m {
        Method::Baseline(b) => {
            let mut t = Vec::with_capacity(runs);
            for i in 0..runs + runs / 10 {
                let t0 = Instant::now();
                std::hint::black_box(b.features(img, set.side, set.side, None));
                if i >= runs / 10 {
                    t.push(t0.elapsed().as_secs_f64() * 1e3);
                }
            }
            out.push((1, median(&t), quantile(&t, 0.95)));
        }
        Method::Onnx(_, bytes) => {
            for &th in threads {
                let mut enc = OrtEncoder::from_bytes(bytes, th)?;
                let mut x = Vec::new();
                let mut t = Vec::with_capacity(runs);
                for i in 0..runs + runs / 10 {
                    let t0 = Instant::now();
                    // Preprocessing (normalisation) is part of the frame's cost.
                    x.clear();
                    normalize_into(img, set.side, &mut x);
                    std::hint::black_box(enc.embed(&x)?);
                    if i >= runs / 10 {
                        t.push(t0.elapsed().as_secs_f64() * 1e3);
                    }
                }
                out.push((th, median(&t), quantile(&t, 0.95)));
            }
        }
    }
    Ok(out)
}

fn top1(index: &[f32], labels: &[u32], q: &[f32], qlabels: &[u32], dim: usize) -> f64 {
    if qlabels.is_empty() {
        return f64::NAN;
    }
    let nn = top_k(index, q, dim, 1);
    let right = nn
        .iter()
        .zip(qlabels)
        .filter(|(r, &l)| labels[r[0].1] == l)
        .count();
    right as f64 / qlabels.len() as f64
}

/// Scores `m`: the index from `train_index` (frames before 120), queries
/// from `heldout`.
pub fn evaluate(
    m: &Method,
    train_index: &ImageSet,
    heldout: &ImageSet,
    threads: &[usize],
    runs: usize,
) -> Result<MethodResult> {
    let (ie, dim) = embed(m, train_index, threads.iter().copied().max().unwrap_or(1))?;
    let idx: Vec<usize> = (0..train_index.len())
        .filter(|&i| train_index.items[i].frame < crate::train::INDEX_FRAMES)
        .collect();
    let index = crate::train::rows(&ie, dim, &idx);
    let labels: Vec<u32> = idx.iter().map(|&i| train_index.items[i].class).collect();
    let (qe, _) = embed(m, heldout, threads.iter().copied().max().unwrap_or(1))?;
    let qlabels: Vec<u32> = heldout.items.iter().map(|x| x.class).collect();
    let frame_top1 = top1(&index, &labels, &qe, &qlabels, dim);
    // Presses: frames in capture order.
    let mut presses: std::collections::BTreeMap<(u32, u32, u32), Vec<usize>> = Default::default();
    for (i, it) in heldout.items.iter().enumerate() {
        presses
            .entry((it.person, it.press, it.class))
            .or_default()
            .push(i);
    }
    for v in presses.values_mut() {
        v.sort_by_key(|&i| heldout.items[i].frame);
    }
    let longest = presses.values().map(Vec::len).max().unwrap_or(0);
    let mean_of = |frames: &[usize]| -> Vec<f32> {
        let mut m = vec![0f32; dim];
        for &i in frames {
            for (s, v) in m.iter_mut().zip(&qe[i * dim..(i + 1) * dim]) {
                *s += v;
            }
        }
        m
    };
    let mut by_frames = Vec::new();
    for n in 1..=longest {
        let mut q = Vec::new();
        let mut ql = Vec::new();
        for (&(_, _, class), frames) in &presses {
            q.extend(mean_of(&frames[..n.min(frames.len())]));
            ql.push(class);
        }
        normalize_rows(&mut q, dim);
        by_frames.push((n, top1(&index, &labels, &q, &ql, dim)));
    }
    let press_top1 = by_frames.last().map_or(f64::NAN, |x| x.1);
    Ok(MethodResult {
        name: m.name(),
        dim,
        latency: time_method(m, heldout, threads, runs)?,
        frame_top1,
        press_top1,
        by_frames,
        queries: qlabels.len(),
        presses: presses.len(),
    })
}

/// Indices of the Pareto-optimal results (no other is both faster, by the
/// one-thread median, and at least as accurate per press).
pub fn pareto(results: &[MethodResult]) -> Vec<usize> {
    let lat = |r: &MethodResult| r.latency.first().map_or(f64::INFINITY, |l| l.1);
    (0..results.len())
        .filter(|&i| {
            !results.iter().enumerate().any(|(j, o)| {
                j != i
                    && lat(o) <= lat(&results[i])
                    && o.press_top1 >= results[i].press_top1
                    && (lat(o) < lat(&results[i]) || o.press_top1 > results[i].press_top1)
            })
        })
        .collect()
}

/// The markdown table.
pub fn markdown(results: &[MethodResult]) -> String {
    let front = pareto(results);
    let mut s = String::from(
        "| method | dim | ms/frame p50 (1 thread) | p95 | ms p50 (2 threads) | top-1 per frame | top-1 per press | Pareto |\n|---|---:|---:|---:|---:|---:|---:|---|\n",
    );
    for (i, r) in results.iter().enumerate() {
        let l1 = r
            .latency
            .first()
            .copied()
            .unwrap_or((1, f64::NAN, f64::NAN));
        let l2 = r
            .latency
            .iter()
            .find(|l| l.0 == 2)
            .map_or("-".to_string(), |l| format!("{:.3}", l.1));
        s.push_str(&format!(
            "| {} | {} | {:.3} | {:.3} | {} | {:.2}% | {:.2}% | {} |\n",
            r.name,
            r.dim,
            l1.1,
            l1.2,
            l2,
            100.0 * r.frame_top1,
            100.0 * r.press_top1,
            if front.contains(&i) { "yes" } else { "" }
        ));
    }
    s
}

/// Accuracy (per press) against per-frame latency, log-x, the Pareto
/// frontier joined, the 60 fps budget marked; and accuracy against frames
/// aggregated. Two SVG files.
pub fn charts(
    results: &[MethodResult],
    speed_svg: &std::path::Path,
    frames_svg: &std::path::Path,
) -> Result<()> {
    use plotters::prelude::*;
    let e = |x: Box<dyn std::error::Error + '_>| anyhow::anyhow!("chart: {x}");
    let lat = |r: &MethodResult| r.latency.first().map_or(f64::NAN, |l| l.1);
    {
        let root = SVGBackend::new(speed_svg, (900, 560)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(Box::new(x)))?;
        let xmax = results.iter().map(lat).fold(20.0, f64::max) * 2.0;
        let xmin = results.iter().map(lat).fold(1.0, f64::min).max(1e-4) / 2.0;
        let mut c = ChartBuilder::on(&root)
            .caption(
                "Accuracy against speed (held-out people, kNN top-1 per press)",
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d((xmin..xmax).log_scale(), 0.0..100.0)
            .map_err(|x| e(Box::new(x)))?;
        c.configure_mesh()
            .x_desc("ms per frame, one thread, batch 1 (log scale)")
            .y_desc("top-1 per press, %")
            .draw()
            .map_err(|x| e(Box::new(x)))?;
        c.draw_series(LineSeries::new(
            [(16.7, 0.0), (16.7, 100.0)],
            RED.mix(0.6).stroke_width(2),
        ))
        .map_err(|x| e(Box::new(x)))?
        .label("16.7 ms: one frame at 60 fps")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.mix(0.6).stroke_width(2)));
        let mut front: Vec<(f64, f64)> = pareto(results)
            .into_iter()
            .map(|i| (lat(&results[i]), 100.0 * results[i].press_top1))
            .collect();
        front.sort_by(|a, b| a.0.total_cmp(&b.0));
        c.draw_series(LineSeries::new(front, BLUE.stroke_width(2)))
            .map_err(|x| e(Box::new(x)))?
            .label("Pareto frontier")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        for r in results {
            let p = (lat(r), 100.0 * r.press_top1);
            c.draw_series(std::iter::once(Circle::new(p, 5, BLACK.filled())))
                .map_err(|x| e(Box::new(x)))?;
            c.draw_series(std::iter::once(Text::new(
                r.name.clone(),
                (p.0 * 1.08, p.1 + 1.5),
                ("sans-serif", 13),
            )))
            .map_err(|x| e(Box::new(x)))?;
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()
            .map_err(|x| e(Box::new(x)))?;
        root.present().map_err(|x| e(Box::new(x)))?;
    }
    {
        let root = SVGBackend::new(frames_svg, (900, 520)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(Box::new(x)))?;
        let n = results
            .iter()
            .map(|r| r.by_frames.len())
            .max()
            .unwrap_or(1)
            .max(2);
        let mut c = ChartBuilder::on(&root)
            .caption(
                "Accuracy against frames aggregated (time to decision)",
                ("sans-serif", 18),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(1usize..n, 0.0..100.0)
            .map_err(|x| e(Box::new(x)))?;
        c.configure_mesh()
            .x_desc("frames of the press averaged (one frame = 16.7 ms at 60 fps)")
            .y_desc("top-1 per press, %")
            .draw()
            .map_err(|x| e(Box::new(x)))?;
        for (i, r) in results.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            c.draw_series(LineSeries::new(
                r.by_frames.iter().map(|&(k, a)| (k, 100.0 * a)),
                color.stroke_width(2),
            ))
            .map_err(|x| e(Box::new(x)))?
            .label(r.name.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
        }
        c.configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()
            .map_err(|x| e(Box::new(x)))?;
        root.present().map_err(|x| e(Box::new(x)))?;
    }
    Ok(())
}
