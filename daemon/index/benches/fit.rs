//! How long fitting an index's distance on an owner's presses takes: every
//! candidate of `MetricFit::CANDIDATES`, each press left out in turn with
//! the fit made again without it (`build::choose_fit`), then the index
//! built with the chosen fit, for 16 and 119 fabrics of 3 presses, 100
//! frames each, at the encoder's dimension (128) and with the LBP texture
//! features (156). Synthetic embeddings: the cost depends on the counts,
//! not on the values.
//!
//! ```text
//! cargo bench -p telextiles-index --bench fit
//! ```
//! Prints a markdown table (docs/studies/2026-12-04-fitted-metric.md).

use std::time::Instant;

use rand::{Rng, SeedableRng};
use telextiles_index::build::{choose_fit, press_data, MetricFit};
use telextiles_index::{IndexBuilder, TextileRecord};

fn main() {
    println!(
        "| fabrics x presses x frames | dim | choose among the fits (s) | build the index (s) |"
    );
    println!("|---|---:|---:|---:|");
    for fabrics in [16usize, 119] {
        for dim in [128usize, 156] {
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(fabrics as u64);
            let records: Vec<telextiles_index::build::FabricPresses> = (0..fabrics)
                .map(|_| {
                    let centre: Vec<f32> = (0..dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
                    let frames: Vec<Vec<Vec<f32>>> = (0..3)
                        .map(|_| {
                            (0..100)
                                .map(|_| {
                                    centre
                                        .iter()
                                        .map(|c| c + rng.gen_range(-0.5..0.5))
                                        .collect()
                                })
                                .collect()
                        })
                        .collect();
                    let means = frames
                        .iter()
                        .map(|f: &Vec<Vec<f32>>| {
                            let mut m = vec![0.0f32; dim];
                            for v in f {
                                m.iter_mut().zip(v).for_each(|(a, b)| *a += b);
                            }
                            m
                        })
                        .collect();
                    (means, frames)
                })
                .collect();
            let t = Instant::now();
            let data = press_data(&records, dim);
            let (chosen, _) = choose_fit(&data, dim, true, &MetricFit::CANDIDATES);
            let choose_s = t.elapsed().as_secs_f64();
            let t = Instant::now();
            let mut b = IndexBuilder::new("bench", "bench", dim, 0);
            for (k, (means, frames)) in records.into_iter().enumerate() {
                b.add(TextileRecord {
                    id: format!("F{k:03}"),
                    name: String::new(),
                    seen: true,
                    structure: String::new(),
                    attributes: vec![],
                    embeddings: frames.iter().flatten().cloned().collect(),
                    exemplars: means,
                    press_frames: frames,
                })
                .expect("a record");
            }
            b.roller_n = 16;
            b.metric = MetricFit::CANDIDATES[chosen];
            b.unknown_quantile = Some(0.9);
            b.build_report().expect("an index");
            let build_s = t.elapsed().as_secs_f64();
            println!("| {fabrics} x 3 x 100 | {dim} | {choose_s:.2} | {build_s:.2} |");
        }
    }
}
