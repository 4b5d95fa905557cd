//! What the texture features cost per frame, on one thread: the LBP
//! histograms and the Gabor energies of the encoder's preprocessed input
//! (`texture::Lbp`, `gabor::Gabor`, at the shipped model's 120x120 input), and a fitted metric's map of a query
//! (`telextiles_index::Metric::apply`) at the dimensions an index holds
//! with and without them.
//!
//! ```text
//! taskset -c 1 cargo bench -p telextiles-sensing --bench texture
//! ```
//! Prints a markdown table (docs/studies/2026-12-04-fitted-metric.md).

use std::time::Instant;

use rand::{Rng, SeedableRng};
use telextiles_sensing::texture::{Lbp, LBP_DIM};

/// Median of `rounds` timings of `per_round` calls, in milliseconds per
/// call.
fn median_ms(rounds: usize, per_round: usize, mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..rounds)
        .map(|_| {
            let s = Instant::now();
            for _ in 0..per_round {
                f();
            }
            s.elapsed().as_secs_f64() * 1e3 / per_round as f64
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[t.len() / 2]
}

fn main() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let side = 120;
    let input: Vec<f32> = (0..3 * side * side)
        .map(|_| rng.gen_range(-1.0..1.0))
        .collect();
    let mut lbp = Lbp::new(side);
    let mut out = [0.0f32; LBP_DIM];
    let lbp_ms = median_ms(21, 200, || {
        assert!(lbp.features(std::hint::black_box(&input), 3, &mut out));
    });
    let mut gabor = telextiles_sensing::gabor::Gabor::new(side);
    let mut gout = [0.0f32; telextiles_sensing::gabor::GABOR_DIM];
    let gabor_ms = median_ms(21, 200, || {
        assert!(gabor.features(std::hint::black_box(&input), 3, &mut gout));
    });
    println!("| per frame, one thread | median (ms) |");
    println!("|---|---:|");
    println!("| LBP histograms (8 at r=1, 16 at r=2) of a {side}x{side}x3 input | {lbp_ms:.3} |");
    println!(
        "| Gabor energies (3 scales x 6 orientations, 64x64 FFT) of the same | {gabor_ms:.3} |"
    );
    for dim in [
        128usize,
        128 + LBP_DIM,
        128 + LBP_DIM + telextiles_sensing::gabor::GABOR_DIM,
    ] {
        let fabrics: Vec<Vec<Vec<f32>>> = (0..8)
            .map(|_| {
                (0..4)
                    .map(|_| (0..dim).map(|_| rng.gen_range(-1.0..1.0)).collect())
                    .collect()
            })
            .collect();
        let m = telextiles_index::Metric::within_fabric(&fabrics, dim, 0.5).expect("a metric");
        let q: Vec<f32> = (0..dim).map(|_| rng.gen_range(-1.0..1.0)).collect();
        let ms = median_ms(21, 2000, || {
            std::hint::black_box(m.apply(std::hint::black_box(&q)));
        });
        println!("| a fitted metric's map of a {dim}-d query | {ms:.4} |");
    }
}
