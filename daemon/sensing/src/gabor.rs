//! Gabor energies: how the frame-minus-reference's power spreads over
//! three scales, and how unevenly over orientation at each, in a form that
//! does not change when the sensor turns. A texture feature beside the
//! encoder's embedding and the LBP histograms ([`crate::texture`]).
//!
//! On exactly what the encoder sees (its preprocessed input averaged over
//! the colour planes), in blocks of `step` x `step` pixels so that it fits
//! a 64 x 64 grid, minus its mean, under a Hann window: the 2D power
//! spectrum by FFT, then the energy under 18 log-Gabor windows (centre
//! frequencies 3, 6 and 12 cycles per 64 samples, one octave wide; 6
//! orientations over half a turn, 30° apart). Per scale, with `E_o` its
//! energies over the orientations: the share of the three scales' total
//! (square-rooted), and the magnitudes of the orientations' first and
//! second circular harmonics over their sum — a turn of the texture
//! shifts `E_o` around the circle and leaves those magnitudes. Nine values,
//! scaled to unit length.
//!
//! Pure: no allocation per frame once built, no I/O.

/// Length of the feature vector.
pub const GABOR_DIM: usize = 9;
/// FFT side.
const N: usize = 64;
/// Centre frequencies (cycles per `N` samples).
const SCALES: [f32; 3] = [3.0, 6.0, 12.0];
/// Orientations over half a turn.
const ORIENTATIONS: usize = 6;
/// Filter weights below this are left out of the sums (the windows'
/// tails, well under a thousandth of their peak).
const MIN_WEIGHT: f32 = 1e-3;

/// The Gabor energies of a square image of a fixed side.
#[derive(Clone, Debug)]
pub struct Gabor {
    side: usize,
    step: usize,
    /// Side of the block-averaged image (at most `N`).
    h: usize,
    window: Vec<f32>,
    re: Vec<f32>,
    im: Vec<f32>,
    /// Per bin of the half plane (`N` rows x `N/2 + 1` columns, row-major)
    /// that some filter weighs by at least [`MIN_WEIGHT`]: the bin, and
    /// each such filter (scale-major) with its weight.
    taps: Vec<(usize, Vec<(usize, f32)>)>,
    /// Twiddles of the `N`-point FFT.
    cos: Vec<f32>,
    sin: Vec<f32>,
    grey: Vec<f32>,
}

impl Gabor {
    /// For images `side` x `side` (at least 8).
    pub fn new(side: usize) -> Gabor {
        let step = side.div_ceil(N).max(1);
        let h = side / step;
        let hann = |i: usize| {
            0.5 - 0.5 * (2.0 * std::f32::consts::PI * (i as f32 + 0.5) / h.max(1) as f32).cos()
        };
        let window = (0..h * h).map(|k| hann(k / h) * hann(k % h)).collect();
        let cols = N / 2 + 1;
        let sigma_r = std::f32::consts::LN_2 / 2.0;
        let sigma_t = std::f32::consts::PI / ORIENTATIONS as f32 / 2.0;
        let mut filters: Vec<Vec<f32>> = Vec::new();
        for &f in &SCALES {
            for o in 0..ORIENTATIONS {
                let theta_o = std::f32::consts::PI * o as f32 / ORIENTATIONS as f32;
                let mut w = vec![0.0f32; N * cols];
                for ky in 0..N {
                    let fy = if ky < N / 2 {
                        ky as f32
                    } else {
                        ky as f32 - N as f32
                    };
                    for kx in 0..cols {
                        let fx = kx as f32;
                        let r = (fx * fx + fy * fy).sqrt();
                        if r == 0.0 {
                            continue;
                        }
                        let radial = (-(r / f).ln().powi(2) / (2.0 * sigma_r * sigma_r)).exp();
                        let theta = fy.atan2(fx).rem_euclid(std::f32::consts::PI);
                        let mut d = (theta - theta_o).abs();
                        d = d.min(std::f32::consts::PI - d);
                        let angular = (-d * d / (2.0 * sigma_t * sigma_t)).exp();
                        w[ky * cols + kx] = radial * angular;
                    }
                }
                filters.push(w);
            }
        }
        let taps = (0..N * cols)
            .filter_map(|b| {
                let t: Vec<(usize, f32)> = filters
                    .iter()
                    .enumerate()
                    .map(|(k, w)| (k, w[b]))
                    .filter(|&(_, w)| w >= MIN_WEIGHT)
                    .collect();
                (!t.is_empty()).then_some((b, t))
            })
            .collect();
        let (cos, sin) = (0..N / 2)
            .map(|k| {
                let a = -2.0 * std::f32::consts::PI * k as f32 / N as f32;
                (a.cos(), a.sin())
            })
            .unzip();
        Gabor {
            side,
            step,
            h,
            window,
            re: vec![0.0; N * N],
            im: vec![0.0; N * N],
            taps,
            cos,
            sin,
            grey: vec![0.0; side * side],
        }
    }

    /// Features of a planar image of `planes` colour planes of `side` x
    /// `side` (the encoder's NCHW input for one frame) into `out`
    /// (`GABOR_DIM` values, unit length). False, and `out` untouched, when
    /// `input` is not `planes` planes of that size, is not finite, or the
    /// image is too small.
    pub fn features(&mut self, input: &[f32], planes: usize, out: &mut [f32]) -> bool {
        let mut grey = std::mem::take(&mut self.grey);
        let ok =
            crate::texture::grey_of(input, planes, &mut grey) && self.features_of_grey(&grey, out);
        self.grey = grey;
        ok
    }

    /// [`Gabor::features`] of an image already summed over its planes
    /// (`side` x `side` finite values, [`crate::texture::grey_of`]).
    pub fn features_of_grey(&mut self, grey: &[f32], out: &mut [f32]) -> bool {
        if grey.len() != self.side * self.side || out.len() != GABOR_DIM || self.h < 8 {
            return false;
        }
        // Blocks of step x step, minus their mean, windowed, into the grid.
        let (h, step) = (self.h, self.step);
        self.re.iter_mut().for_each(|v| *v = 0.0);
        self.im.iter_mut().for_each(|v| *v = 0.0);
        let mut mean = 0.0f32;
        for y in 0..h {
            for x in 0..h {
                let mut s = 0.0;
                for dy in 0..step {
                    let row = (y * step + dy) * self.side + x * step;
                    s += grey[row..row + step].iter().sum::<f32>();
                }
                self.re[y * N + x] = s;
                mean += s;
            }
        }
        mean /= (h * h) as f32;
        for y in 0..h {
            for x in 0..h {
                self.re[y * N + x] = (self.re[y * N + x] - mean) * self.window[y * h + x];
            }
        }
        // Rows, then columns.
        for y in 0..N {
            fft(&mut self.re, &mut self.im, y * N, 1, &self.cos, &self.sin);
        }
        for x in 0..N / 2 + 1 {
            fft(&mut self.re, &mut self.im, x, N, &self.cos, &self.sin);
        }
        let cols = N / 2 + 1;
        let mut flat = [0.0f32; SCALES.len() * ORIENTATIONS];
        for (b, taps) in &self.taps {
            let k = (b / cols) * N + b % cols;
            let p = self.re[k] * self.re[k] + self.im[k] * self.im[k];
            for &(f, w) in taps {
                flat[f] += p * w;
            }
        }
        let mut energy = [[0.0f64; ORIENTATIONS]; SCALES.len()];
        for (s, e) in energy.iter_mut().enumerate() {
            for (o, eo) in e.iter_mut().enumerate() {
                *eo = flat[s * ORIENTATIONS + o] as f64;
            }
        }
        let totals: Vec<f64> = energy.iter().map(|e| e.iter().sum()).collect();
        let all: f64 = totals.iter().sum();
        for (s, e) in energy.iter().enumerate() {
            out[s] = if all > 0.0 {
                (totals[s] / all).sqrt() as f32
            } else {
                (1.0 / SCALES.len() as f64).sqrt() as f32
            };
            for (j, harmonic) in [1.0f64, 2.0].iter().enumerate() {
                let (mut c, mut si) = (0.0f64, 0.0f64);
                for (o, &eo) in e.iter().enumerate() {
                    let a = 2.0 * std::f64::consts::PI * harmonic * o as f64 / ORIENTATIONS as f64;
                    c += eo * a.cos();
                    si += eo * a.sin();
                }
                out[SCALES.len() + 2 * s + j] = if totals[s] > 0.0 {
                    ((c * c + si * si).sqrt() / totals[s]) as f32
                } else {
                    0.0
                };
            }
        }
        let norm = out.iter().map(|v| v * v).sum::<f32>().sqrt();
        out.iter_mut().for_each(|v| *v /= norm);
        true
    }
}

/// In-place radix-2 FFT of the `N` complex values at `start`, `start +
/// stride`, ...
fn fft(re: &mut [f32], im: &mut [f32], start: usize, stride: usize, cos: &[f32], sin: &[f32]) {
    let at = |i: usize| start + i * stride;
    // Bit-reversed order.
    let bits = N.trailing_zeros();
    for i in 0..N {
        let j = i.reverse_bits() >> (usize::BITS - bits);
        if j > i {
            re.swap(at(i), at(j));
            im.swap(at(i), at(j));
        }
    }
    let mut len = 2;
    while len <= N {
        let half = len / 2;
        let tw = N / len;
        for base in (0..N).step_by(len) {
            for k in 0..half {
                let (c, s) = (cos[k * tw], sin[k * tw]);
                let (a, b) = (at(base + k), at(base + k + half));
                let (xr, xi) = (re[b] * c - im[b] * s, re[b] * s + im[b] * c);
                re[b] = re[a] - xr;
                im[b] = im[a] - xi;
                re[a] += xr;
                im[a] += xi;
            }
        }
        len *= 2;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_fft_is_the_discrete_fourier_transform() {
        let (cos, sin): (Vec<f32>, Vec<f32>) = (0..N / 2)
            .map(|k| {
                let a = -2.0 * std::f32::consts::PI * k as f32 / N as f32;
                (a.cos(), a.sin())
            })
            .unzip();
        let x: Vec<f32> = (0..N).map(|i| ((i * 7 % 11) as f32 - 5.0) * 0.3).collect();
        let (mut re, mut im) = (x.clone(), vec![0.0f32; N]);
        fft(&mut re, &mut im, 0, 1, &cos, &sin);
        for k in 0..N {
            let (mut r, mut i) = (0.0f64, 0.0f64);
            for (n, &v) in x.iter().enumerate() {
                let a = -2.0 * std::f64::consts::PI * (k * n) as f64 / N as f64;
                r += v as f64 * a.cos();
                i += v as f64 * a.sin();
            }
            assert!(
                (re[k] as f64 - r).abs() < 1e-3 && (im[k] as f64 - i).abs() < 1e-3,
                "{k}"
            );
        }
    }

    fn planar(side: usize, f: impl Fn(usize, usize) -> f32) -> Vec<f32> {
        (0..3)
            .flat_map(|c| (0..side * side).map(move |k| (k, c)))
            .map(|(k, c)| f(k / side, k % side) + c as f32 * 0.1)
            .collect()
    }

    #[test]
    fn energies_are_unit_length_the_same_turned_and_tell_textures_apart() {
        let side = 120;
        let mut g = Gabor::new(side);
        let wave = |u: usize| (u as f32 * 0.5).sin();
        let (mut a, mut b, mut c, mut d) = (
            [0.0; GABOR_DIM],
            [0.0; GABOR_DIM],
            [0.0; GABOR_DIM],
            [0.0; GABOR_DIM],
        );
        // Stripes across, the same turned a quarter turn, finer stripes,
        // and a blank frame.
        assert!(g.features(&planar(side, |_, x| wave(x)), 3, &mut a));
        assert!(g.features(&planar(side, |y, _| wave(side - 1 - y)), 3, &mut b));
        assert!(g.features(&planar(side, |_, x| (x as f32 * 1.6).sin()), 3, &mut c));
        assert!(g.features(&planar(side, |_, _| 0.0), 3, &mut d));
        let norm = |v: &[f32]| v.iter().map(|x| x * x).sum::<f32>().sqrt();
        let dist = |p: &[f32], q: &[f32]| {
            p.iter()
                .zip(q)
                .map(|(x, y)| (x - y) * (x - y))
                .sum::<f32>()
                .sqrt()
        };
        for v in [&a, &b, &c, &d] {
            assert!((norm(v) - 1.0).abs() < 1e-5, "{v:?}");
        }
        assert!(dist(&a, &b) < 0.02, "{a:?} {b:?}");
        assert!(dist(&a, &c) > 0.3, "{a:?} {c:?}");
        // Stripes are all at one orientation: a strong first harmonic.
        assert!(a[SCALES.len()..].iter().any(|&v| v > 0.2), "{a:?}");
    }

    #[test]
    fn bad_input_is_refused_not_a_panic() {
        let mut g = Gabor::new(32);
        let mut out = [7.0; GABOR_DIM];
        assert!(!g.features(&[0.0; 10], 3, &mut out));
        let mut nan = planar(32, |_, _| 0.0);
        nan[3] = f32::INFINITY;
        assert!(!g.features(&nan, 3, &mut out));
        assert!(!g.features(&planar(32, |_, _| 0.0), 3, &mut [0.0; 2]));
        assert!(out.iter().all(|&v| v == 7.0));
        assert!(!Gabor::new(6).features(&[0.0; 108], 3, &mut [0.0; GABOR_DIM]));
        // A larger input is averaged in blocks to fit the grid.
        let mut big = Gabor::new(224);
        assert!(big.features(&planar(224, |y, x| ((x + y) % 5) as f32), 3, &mut out));
    }
}
