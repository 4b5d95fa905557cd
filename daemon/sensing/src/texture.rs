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

/// One circle of samples: each sample's four neighbours (offsets from the
/// centre, row-major) and bilinear weights.
#[derive(Clone, Debug)]
struct Circle {
    taps: Vec<[(isize, f32); 4]>,
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
            })
            .collect();
        Circle { taps }
    }

    /// The riu2 code of the pixel at `i` of `img`.
    fn code(&self, img: &[f32], i: usize) -> usize {
        let c = img[i];
        let p = self.taps.len();
        let mut ones = 0usize;
        let mut changes = 0usize;
        let mut first = false;
        let mut prev = false;
        for (k, taps) in self.taps.iter().enumerate() {
            let mut v = 0.0f32;
            for &(off, w) in taps {
                if w != 0.0 {
                    v += w * img[(i as isize + off) as usize];
                }
            }
            let bit = v >= c;
            ones += usize::from(bit);
            if k == 0 {
                first = bit;
            } else if bit != prev {
                changes += 1;
            }
            prev = bit;
        }
        if prev != first {
            changes += 1;
        }
        if changes <= 2 {
            ones
        } else {
            p + 1
        }
    }
}

/// The texture features of a square grey image of a fixed side.
#[derive(Clone, Debug)]
pub struct Lbp {
    side: usize,
    small: Circle,
    large: Circle,
    grey: Vec<f32>,
}

impl Lbp {
    /// For images `side` x `side` (at least 5).
    pub fn new(side: usize) -> Lbp {
        Lbp {
            side,
            small: Circle::new(8, 1.0, side),
            large: Circle::new(16, 2.0, side),
            grey: vec![0.0; side * side],
        }
    }

    /// The image side this was built for.
    pub fn side(&self) -> usize {
        self.side
    }

    /// Features of a planar image of `planes` colour planes of `side` x
    /// `side` (the encoder's NCHW input for one frame), averaged over the
    /// planes, into `out` (`LBP_DIM` values, unit length). False, and
    /// `out` untouched, when `input` is not `planes` planes of that size,
    /// is not finite, or the image is too small.
    pub fn features(&mut self, input: &[f32], planes: usize, out: &mut [f32]) -> bool {
        let n = self.side * self.side;
        if planes == 0
            || input.len() != planes * n
            || out.len() != LBP_DIM
            || self.side < 2 * BORDER + 1
            || input.iter().any(|v| !v.is_finite())
        {
            return false;
        }
        self.grey.copy_from_slice(&input[..n]);
        for plane in input.chunks_exact(n).skip(1) {
            self.grey.iter_mut().zip(plane).for_each(|(g, v)| *g += v);
        }
        let mut hist = [0u32; LBP_DIM];
        for y in BORDER..self.side - BORDER {
            for x in BORDER..self.side - BORDER {
                let i = y * self.side + x;
                hist[self.small.code(&self.grey, i)] += 1;
                hist[BINS_8 + self.large.code(&self.grey, i)] += 1;
            }
        }
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

    #[test]
    fn the_index_counts_as_many_texture_values_as_are_computed() {
        assert_eq!(telextiles_index::LBP_DIM, LBP_DIM);
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
