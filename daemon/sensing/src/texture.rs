//! Cheap texture features beside the encoder's embedding: rotation-invariant
//! uniform local binary patterns (LBP, Ojala et al. 2002, "riu2") of the
//! frame minus its no-contact reference, at two scales (8 samples at
//! radius 1, 16 at radius 2).
//!
//! They are computed on exactly what the encoder sees: the preprocessed
//! input (crop, resize, DIGIT normalisation, minus the reference's same),
//! averaged over its three colour planes, so the frame-minus-reference
//! contract and the one preprocessing hold for them too. For each pixel
//! (away from a 2-pixel border) the `P` samples on a circle of radius `R`
//! around it (bilinear, at angles `2πp/P`) are compared with the centre;
//! a pattern with at most two 0/1 changes around the circle counts its
//! ones (`0..=P`), every other pattern falls in one more bin. The two
//! histograms (10 + 18 bins) are normalised to sum 1 each, square-rooted
//! (so that Euclidean distance between them is the Hellinger distance)
//! and the whole vector scaled to unit length.
//!
//! Pure: no allocation per frame once built, no I/O.

/// Bins of the 8-sample histogram (`P + 2`).
const BINS_8: usize = 10;
/// Bins of the 16-sample histogram.
const BINS_16: usize = 18;
/// Length of the texture feature vector.
pub const LBP_DIM: usize = BINS_8 + BINS_16;
/// Pixels left out at each edge (the larger radius).
const BORDER: usize = 2;

/// One circle of samples: each sample's neighbours (offsets from the
/// centre, row-major) and their non-zero bilinear weights.
#[derive(Clone, Debug)]
struct Circle {
    taps: Vec<Vec<(isize, f32)>>,
}

impl Circle {
    fn new(p: usize, r: f32, width: usize) -> Circle {
        let taps = (0..p)
            .map(|k| {
                let a = 2.0 * std::f64::consts::PI * k as f64 / p as f64;
                // As scikit-image does: positions rounded so that the
                // cardinal samples fall exactly on pixels.
                let round = |v: f64| (v * 1e5).round() / 1e5;
                let y = round(-(r as f64) * a.sin());
                let x = round(r as f64 * a.cos());
                let (y0, x0) = (y.floor(), x.floor());
                let (fy, fx) = ((y - y0) as f32, (x - x0) as f32);
                let at =
                    |dy: f64, dx: f64| ((y0 + dy) as isize) * width as isize + (x0 + dx) as isize;
                [
                    (at(0.0, 0.0), (1.0 - fy) * (1.0 - fx)),
                    (at(0.0, 1.0), (1.0 - fy) * fx),
                    (at(1.0, 0.0), fy * (1.0 - fx)),
                    (at(1.0, 1.0), fy * fx),
                ]
                .into_iter()
                .filter(|&(_, w)| w != 0.0)
                .collect()
            })
            .collect();
        Circle { taps }
    }
}

/// Per-pixel state of one circle's patterns while its samples are taken
/// one after another over the whole image (rows at a time, which the
/// compiler vectorises): ones so far, 0/1 changes so far, the first and
/// the last bit.
#[derive(Clone, Debug, Default)]
struct Patterns {
    ones: Vec<u8>,
    changes: Vec<u8>,
    first: Vec<u8>,
    prev: Vec<u8>,
    sample: Vec<f32>,
}

/// The texture features of a square grey image of a fixed side.
#[derive(Clone, Debug)]
pub struct Lbp {
    side: usize,
    small: Circle,
    large: Circle,
    grey: Vec<f32>,
    state: Patterns,
}

impl Lbp {
    /// For images `side` x `side` (at least 5).
    pub fn new(side: usize) -> Lbp {
        let inner = side.saturating_sub(2 * BORDER);
        let row = vec![0u8; inner * inner];
        Lbp {
            side,
            small: Circle::new(8, 1.0, side),
            large: Circle::new(16, 2.0, side),
            grey: vec![0.0; side * side],
            state: Patterns {
                ones: row.clone(),
                changes: row.clone(),
                first: row.clone(),
                prev: row,
                sample: vec![0.0; inner],
            },
        }
    }

    /// The image side this was built for.
    pub fn side(&self) -> usize {
        self.side
    }

    /// Features of a planar image of `planes` colour planes of `side` x
    /// `side` (the encoder's NCHW input for one frame), summed over the
    /// planes ([`grey_of`]), into `out` (`LBP_DIM` values, unit length).
    /// False, and `out` untouched, when `input` is not `planes` planes of
    /// that size, is not finite, or the image is too small.
    pub fn features(&mut self, input: &[f32], planes: usize, out: &mut [f32]) -> bool {
        let mut grey = std::mem::take(&mut self.grey);
        let ok = grey_of(input, planes, &mut grey) && self.features_of_grey(&grey, out);
        self.grey = grey;
        ok
    }

    /// [`Lbp::features`] of an image already summed over its planes
    /// (`side` x `side` finite values): what the encoder calls, once per
    /// frame for every texture feature.
    pub fn features_of_grey(&mut self, grey: &[f32], out: &mut [f32]) -> bool {
        if grey.len() != self.side * self.side || out.len() != LBP_DIM || self.side < 2 * BORDER + 1
        {
            return false;
        }
        let mut hist = [0u32; LBP_DIM];
        histogram(
            &self.small,
            grey,
            self.side,
            &mut self.state,
            &mut hist[..BINS_8],
        );
        histogram(
            &self.large,
            grey,
            self.side,
            &mut self.state,
            &mut hist[BINS_8..],
        );
        let inner = ((self.side - 2 * BORDER) * (self.side - 2 * BORDER)) as f32;
        for (o, &h) in out.iter_mut().zip(&hist) {
            *o = (h as f32 / inner).sqrt();
        }
        // Each histogram sums to 1, so each square-rooted half has unit
        // length and the whole √2.
        out.iter_mut().for_each(|v| *v /= std::f32::consts::SQRT_2);
        true
    }
}

/// The sum of an image's `planes` colour planes (`grey.len()` values
/// each) into `grey`: what the texture features see of the encoder's
/// input. False, and `grey` untouched, when `input` is not that many
/// planes of that size or is not finite.
pub fn grey_of(input: &[f32], planes: usize, grey: &mut [f32]) -> bool {
    let n = grey.len();
    if planes == 0 || n == 0 || input.len() != planes * n || input.iter().any(|v| !v.is_finite()) {
        return false;
    }
    grey.copy_from_slice(&input[..n]);
    for plane in input.chunks_exact(n).skip(1) {
        grey.iter_mut().zip(plane).for_each(|(g, v)| *g += v);
    }
    true
}

/// The riu2 histogram of one circle over the image's inner pixels: a
/// pattern with at most two 0/1 changes counts its ones, any other falls
/// in the last bin (`hist` has `P + 2` bins).
fn histogram(circle: &Circle, grey: &[f32], side: usize, st: &mut Patterns, hist: &mut [u32]) {
    let inner = side - 2 * BORDER;
    for (k, taps) in circle.taps.iter().enumerate() {
        for y in 0..inner {
            let row = (y + BORDER) * side + BORDER;
            let centre = &grey[row..row + inner];
            // This sample for the whole row: its weighted neighbours.
            st.sample.iter_mut().for_each(|v| *v = 0.0);
            for &(off, w) in taps {
                let from = (row as isize + off) as usize;
                st.sample
                    .iter_mut()
                    .zip(&grey[from..from + inner])
                    .for_each(|(v, g)| *v += w * g);
            }
            let at = y * inner..(y + 1) * inner;
            let bits = st.sample.iter().zip(centre).map(|(v, c)| u8::from(v >= c));
            if k == 0 {
                for (((o, f), p), b) in st.ones[at.clone()]
                    .iter_mut()
                    .zip(&mut st.first[at.clone()])
                    .zip(&mut st.prev[at.clone()])
                    .zip(bits)
                {
                    *o = b;
                    *f = b;
                    *p = b;
                }
                st.changes[at].iter_mut().for_each(|c| *c = 0);
            } else {
                for (((o, c), p), b) in st.ones[at.clone()]
                    .iter_mut()
                    .zip(&mut st.changes[at.clone()])
                    .zip(&mut st.prev[at])
                    .zip(bits)
                {
                    *o += b;
                    *c += *p ^ b;
                    *p = b;
                }
            }
        }
    }
    let p = circle.taps.len();
    for (((&o, &c), &f), &l) in st.ones.iter().zip(&st.changes).zip(&st.first).zip(&st.prev) {
        let changes = c + (f ^ l);
        hist[if changes <= 2 { o as usize } else { p + 1 }] += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn planar(side: usize, f: impl Fn(usize, usize) -> f32) -> Vec<f32> {
        let mut v = Vec::with_capacity(3 * side * side);
        for c in 0..3 {
            for y in 0..side {
                for x in 0..side {
                    v.push(f(y, x) + c as f32 * 0.1);
                }
            }
        }
        v
    }

    #[test]
    fn a_flat_image_is_all_uniform_patterns_of_all_ones() {
        let mut lbp = Lbp::new(16);
        let mut out = [0.0; LBP_DIM];
        assert!(lbp.features(&planar(16, |_, _| 0.5), 3, &mut out));
        // Every neighbour equals the centre: every sample counts as a one.
        let s = std::f32::consts::FRAC_1_SQRT_2;
        for (k, &v) in out.iter().enumerate() {
            let want = if k == 8 || k == BINS_8 + 16 { s } else { 0.0 };
            assert!((v - want).abs() < 1e-6, "bin {k}: {v}");
        }
    }

    #[test]
    fn features_are_unit_length_and_stay_when_the_texture_turns() {
        let side = 64;
        let wave = |u: usize| (u as f32 * 0.9).sin() + 0.3 * (u as f32 * 2.3).cos();
        let mut lbp = Lbp::new(side);
        let (mut a, mut b, mut c) = ([0.0; LBP_DIM], [0.0; LBP_DIM], [0.0; LBP_DIM]);
        // Stripes across, and the same stripes turned a quarter turn.
        assert!(lbp.features(&planar(side, |_, x| wave(x)), 3, &mut a));
        assert!(lbp.features(&planar(side, |y, _| wave(side - 1 - y)), 3, &mut b));
        // Another texture: a fine checkerboard.
        assert!(lbp.features(
            &planar(side, |y, x| ((x / 2 + y / 2) % 2) as f32),
            3,
            &mut c
        ));
        let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
        let dist = |p: &[f32], q: &[f32]| {
            p.iter()
                .zip(q)
                .map(|(x, y)| (x - y) * (x - y))
                .sum::<f32>()
                .sqrt()
        };
        for v in [&a, &b, &c] {
            assert!((norm(v) - 1.0).abs() < 1e-5);
        }
        // Rotated by a quarter turn, the stripes keep their histogram (the
        // codes are rotation invariant); the checkerboard is far from both.
        assert!(dist(&a, &b) < 1e-5, "{}", dist(&a, &b));
        assert!(dist(&a, &c) > 0.3, "{}", dist(&a, &c));
    }

    /// The riu2 histograms by their definition, one pixel at a time with
    /// the samples' bilinear values computed from their coordinates.
    fn naive(grey: &[f32], side: usize) -> Vec<f32> {
        let at = |y: f64, x: f64| -> f32 {
            let (y0, x0) = (y.floor(), x.floor());
            let (fy, fx) = ((y - y0) as f32, (x - x0) as f32);
            let g = |yy: f64, xx: f64| {
                let (yy, xx) = (yy as usize, xx as usize);
                if yy < side && xx < side {
                    grey[yy * side + xx]
                } else {
                    0.0
                }
            };
            (1.0 - fy) * (1.0 - fx) * g(y0, x0)
                + (1.0 - fy) * fx * g(y0, x0 + 1.0)
                + fy * (1.0 - fx) * g(y0 + 1.0, x0)
                + fy * fx * g(y0 + 1.0, x0 + 1.0)
        };
        let mut hist = [0u32; LBP_DIM];
        for (p, r, base) in [(8usize, 1.0f64, 0usize), (16, 2.0, BINS_8)] {
            for y in BORDER..side - BORDER {
                for x in BORDER..side - BORDER {
                    let c = grey[y * side + x];
                    let bits: Vec<bool> = (0..p)
                        .map(|k| {
                            let a = 2.0 * std::f64::consts::PI * k as f64 / p as f64;
                            let round = |v: f64| (v * 1e5).round() / 1e5;
                            let (dy, dx) = (round(-r * a.sin()), round(r * a.cos()));
                            at(y as f64 + dy, x as f64 + dx) >= c
                        })
                        .collect();
                    let changes = (0..p).filter(|&k| bits[k] != bits[(k + 1) % p]).count();
                    let ones = bits.iter().filter(|&&b| b).count();
                    hist[base + if changes <= 2 { ones } else { p + 1 }] += 1;
                }
            }
        }
        let inner = ((side - 2 * BORDER) * (side - 2 * BORDER)) as f32;
        hist.iter()
            .map(|&h| (h as f32 / inner).sqrt() / std::f32::consts::SQRT_2)
            .collect()
    }

    #[test]
    fn the_row_at_a_time_histograms_are_the_per_pixel_definition() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        for side in [5usize, 17, 64] {
            // Coarse values, so that ties (a sample equal to its centre)
            // are common, and smooth ones.
            let coarse: Vec<f32> = (0..side * side)
                .map(|_| rng.gen_range(0..4) as f32)
                .collect();
            let smooth: Vec<f32> = (0..side * side)
                .map(|i| ((i % side) as f32 * 0.3).sin() + rng.gen_range(-0.2..0.2))
                .collect();
            for grey in [coarse, smooth] {
                let mut lbp = Lbp::new(side);
                let mut out = [0.0; LBP_DIM];
                assert!(lbp.features(&grey, 1, &mut out));
                let want = naive(&grey, side);
                for (k, (a, b)) in out.iter().zip(&want).enumerate() {
                    assert!(
                        (a - b).abs() < 1e-6,
                        "side {side}, bin {k}: {a} against {b}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_index_counts_as_many_texture_values_as_are_computed() {
        assert_eq!(telextiles_index::LBP_DIM, LBP_DIM);
        assert_eq!(telextiles_index::GABOR_DIM, crate::gabor::GABOR_DIM);
        assert_eq!(
            telextiles_index::Features::EncoderLbpGabor.extra_dim(),
            LBP_DIM + crate::gabor::GABOR_DIM
        );
        assert_eq!(telextiles_index::Features::EncoderLbp.extra_dim(), LBP_DIM);
    }

    #[test]
    fn bad_input_is_refused_not_a_panic() {
        let mut lbp = Lbp::new(16);
        let mut out = [7.0; LBP_DIM];
        assert!(!lbp.features(&[0.0; 10], 3, &mut out));
        let mut nan = planar(16, |_, _| 0.0);
        nan[5] = f32::NAN;
        assert!(!lbp.features(&nan, 3, &mut out));
        assert!(!lbp.features(&planar(16, |_, _| 0.0), 0, &mut out));
        assert!(!lbp.features(&planar(16, |_, _| 0.0), 3, &mut [0.0; 3]));
        assert!(out.iter().all(|&v| v == 7.0));
        let mut tiny = Lbp::new(4);
        assert!(!tiny.features(&[0.0; 48], 3, &mut [0.0; LBP_DIM]));
    }
}
