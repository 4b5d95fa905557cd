//! Classical texture descriptors (the fast end of the speed/accuracy chart):
//! downsampled pixels, rotation-invariant uniform LBP histograms and the
//! radially averaged FFT power spectrum, each on the raw frame or on the
//! frame minus the sensor's no-contact reference (background subtraction).
//!
//! Every descriptor looks at the centre `CROP` x `CROP` square of the image
//! it is given (a 240x320 DIGIT frame or the 240x240 centre canvas: the same
//! pixels; a smaller image, such as a 64x64 network-input cache, is used
//! whole, cut to a power of two) and returns an L2-normalised vector, so the same cosine kNN as for
//! the encoders applies.

use crate::knn::l2;
use std::f32::consts::PI;

/// Side of the centre square the descriptors look at (native resolution).
pub const CROP: usize = 128;

/// Which descriptor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum BaselineKind {
    /// 16x16 block means per channel (768-d), per-channel mean removed.
    Pixels,
    /// Rotation-invariant uniform LBP (P=8) at radii 1, 2, 3: 30 bins, Hellinger.
    Lbp,
    /// Radially averaged log power spectrum of the Hann-windowed grey crop (63 bins).
    Fft,
    /// The colour-whitened power spectrum: radial log bins and rotation-
    /// invariant angular harmonics ([`crate::wspec`]); on the image
    /// averaged over 2x2 blocks when it is large enough.
    WSpec,
    /// The same under a window centred on the contact
    /// ([`crate::wspec::Window::Contact`]).
    WSpecCw,
    /// The whitened spectrum (L2-normalised) followed by the whitened
    /// multiscale marginal statistics ([`crate::mstats`]), standardised,
    /// each weighted as this many values of the spectrum
    /// (× [`MSTATS_UNIT`]).
    WSpecM(u8),
    /// The marginal statistics alone, standardised (not L2-normalised).
    MStats,
}

/// The L2-normalised spectrum's mean per-value spread over the frames
/// [`crate::mstats::CENTRE`] was measured on: a standardised statistic
/// times this counts as much as one value of the spectrum.
pub const MSTATS_UNIT: f64 = 0.02087;

impl BaselineKind {
    /// A kind by its name: `pixels`, `lbp`, `fft`, `wspec`, `wspec-cw`,
    /// `mstats`, or `wspec-mW` (W: the statistics' weight, 0–255).
    pub fn parse(name: &str) -> Option<BaselineKind> {
        Some(match name {
            "pixels" => BaselineKind::Pixels,
            "lbp" => BaselineKind::Lbp,
            "fft" => BaselineKind::Fft,
            "wspec" => BaselineKind::WSpec,
            "wspec-cw" => BaselineKind::WSpecCw,
            "mstats" => BaselineKind::MStats,
            k => BaselineKind::WSpecM(k.strip_prefix("wspec-m")?.parse().ok()?),
        })
    }

    /// Where a `wspec` kind's window sits (`None`: not a `wspec` kind).
    pub fn wspec_window(self) -> Option<crate::wspec::Window> {
        match self {
            BaselineKind::WSpec => Some(crate::wspec::Window::Centre),
            BaselineKind::WSpecCw => Some(crate::wspec::Window::Contact),
            _ => None,
        }
    }
}

/// A descriptor and whether it sees background-subtracted frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct Baseline {
    /// Descriptor.
    pub kind: BaselineKind,
    /// Subtract the no-contact reference first.
    pub bgsub: bool,
}

impl Baseline {
    /// All six baselines.
    pub fn all() -> Vec<Baseline> {
        let mut v = Vec::new();
        for kind in [BaselineKind::Pixels, BaselineKind::Lbp, BaselineKind::Fft] {
            for bgsub in [false, true] {
                v.push(Baseline { kind, bgsub });
            }
        }
        v
    }

    /// Short name used in tables and charts.
    pub fn name(&self) -> String {
        let k = match self.kind {
            BaselineKind::Pixels => "pixels16",
            BaselineKind::Lbp => "lbp-riu2",
            BaselineKind::Fft => "fft-radial",
            BaselineKind::WSpec => "wspec",
            BaselineKind::WSpecCw => "wspec-cw",
            BaselineKind::WSpecM(w) => {
                return format!("wspec-m{w}{}", if self.bgsub { " -bg" } else { "" })
            }
            BaselineKind::MStats => "mstats",
        };
        if self.bgsub {
            format!("{k} -bg")
        } else {
            k.to_string()
        }
    }

    /// Descriptor of the centre crop of an RGB image (`w` x `h`, HWC u8).
    /// `bg` is the no-contact reference of the same size (used when `bgsub`).
    pub fn features(&self, img: &[u8], w: usize, h: usize, bg: Option<&[u8]>) -> Vec<f32> {
        let bg = if self.bgsub { bg } else { None };
        let n = crop_side(w, h);
        let rgb = || centre_crop_f32(img, w, h, n, bg);
        let mut f = match self.kind {
            BaselineKind::Pixels => pixels(&rgb(), n),
            BaselineKind::Lbp => lbp(&grey(&rgb()), n),
            BaselineKind::Fft => fft_radial(&grey(&rgb()), n),
            BaselineKind::WSpec | BaselineKind::WSpecCw => {
                let (x, n) = wspec_input(img, w, h, bg);
                let window = self.kind.wspec_window().expect("a wspec kind");
                crate::wspec::reference_with(&x, n, window)
            }
            BaselineKind::MStats => {
                // Standardised, not L2-normalised.
                let (x, n) = wspec_input(img, w, h, bg);
                return crate::mstats::standardised(&crate::mstats::of_planar(&x, n), 1.0);
            }
            BaselineKind::WSpecM(weight) => {
                let (x, n) = wspec_input(img, w, h, bg);
                let mut f = crate::wspec::reference_with(&x, n, crate::wspec::Window::Centre);
                l2(&mut f);
                f.extend(crate::mstats::standardised(
                    &crate::mstats::of_planar(&x, n),
                    weight as f64 * MSTATS_UNIT,
                ));
                f
            }
        };
        l2(&mut f);
        f
    }
}

/// The difference the `wspec` kinds and the marginal statistics take from
/// a square image, and its side `n` (half the image's, at most 120, even).
fn wspec_input(img: &[u8], w: usize, h: usize, bg: Option<&[u8]>) -> (Vec<f64>, usize) {
    assert_eq!(w, h, "wspec takes a square image");
    let n = (w / 2).min(120) & !1;
    (crate::wspec::planar_of_image(img, w, bg, n), n)
}

/// Side of the square the descriptors use: `CROP`, or the largest power
/// of two that fits a smaller image (a network-input-sized frame cache).
pub fn crop_side(w: usize, h: usize) -> usize {
    let s = CROP.min(w).min(h);
    assert!(s >= 16, "image smaller than 16 px");
    1 << (usize::BITS - 1 - s.leading_zeros())
}

/// The centre `n`x`n` square as f32 RGB (HWC), minus `bg` if given.
fn centre_crop_f32(img: &[u8], w: usize, h: usize, n: usize, bg: Option<&[u8]>) -> Vec<f32> {
    assert_eq!(img.len(), w * h * 3, "image size");
    let (x0, y0) = ((w - n) / 2, (h - n) / 2);
    let mut out = Vec::with_capacity(n * n * 3);
    for y in 0..n {
        let row = ((y0 + y) * w + x0) * 3;
        let src = &img[row..row + n * 3];
        match bg {
            Some(b) => out.extend(
                src.iter()
                    .zip(&b[row..row + n * 3])
                    .map(|(&a, &r)| a as f32 - r as f32),
            ),
            None => out.extend(src.iter().map(|&a| a as f32)),
        }
    }
    out
}

fn grey(rgb: &[f32]) -> Vec<f32> {
    rgb.chunks_exact(3)
        .map(|p| 0.299 * p[0] + 0.587 * p[1] + 0.114 * p[2])
        .collect()
}

fn pixels(rgb: &[f32], n: usize) -> Vec<f32> {
    const G: usize = 16;
    let b = n / G;
    let mut f = vec![0f32; G * G * 3];
    for y in 0..n {
        for x in 0..n {
            let cell = (y / b) * G + x / b;
            for c in 0..3 {
                f[c * G * G + cell] += rgb[(y * n + x) * 3 + c];
            }
        }
    }
    for c in 0..3 {
        let ch = &mut f[c * G * G..(c + 1) * G * G];
        let m = ch.iter().sum::<f32>() / ch.len() as f32;
        ch.iter_mut().for_each(|v| *v -= m);
    }
    f
}

/// Rotation-invariant uniform LBP code (0..=9) of 8 neighbour signs.
fn riu2(bits: u8) -> usize {
    let transitions = (bits ^ bits.rotate_left(1)).count_ones();
    if transitions <= 2 {
        bits.count_ones() as usize
    } else {
        9
    }
}

fn lbp(g: &[f32], n: usize) -> Vec<f32> {
    let mut out = Vec::with_capacity(30);
    for r in 1..=3usize {
        // Bilinear taps of the 8 circular neighbours at radius r.
        let taps: Vec<(isize, isize, f32, f32)> = (0..8)
            .map(|p| {
                let a = 2.0 * PI * p as f32 / 8.0;
                let (dx, dy) = (r as f32 * a.cos(), -(r as f32) * a.sin());
                let (fx, fy) = (dx.floor(), dy.floor());
                (fx as isize, fy as isize, dx - fx, dy - fy)
            })
            .collect();
        let mut hist = [0f32; 10];
        let m = r + 1;
        for y in m..n - m {
            for x in m..n - m {
                let c = g[y * n + x];
                let mut bits = 0u8;
                for (p, &(ix, iy, wx, wy)) in taps.iter().enumerate() {
                    let (xx, yy) = ((x as isize + ix) as usize, (y as isize + iy) as usize);
                    let v00 = g[yy * n + xx];
                    let v01 = g[yy * n + xx + 1];
                    let v10 = g[(yy + 1) * n + xx];
                    let v11 = g[(yy + 1) * n + xx + 1];
                    let v = v00 * (1.0 - wx) * (1.0 - wy)
                        + v01 * wx * (1.0 - wy)
                        + v10 * (1.0 - wx) * wy
                        + v11 * wx * wy;
                    if v >= c - 1e-4 {
                        bits |= 1 << p;
                    }
                }
                hist[riu2(bits)] += 1.0;
            }
        }
        let total: f32 = hist.iter().sum::<f32>().max(1.0);
        out.extend(hist.iter().map(|h| (h / total).sqrt()));
    }
    out
}

/// In-place iterative radix-2 complex FFT of length `re.len()` (a power of
/// two), in f64: the power spectrum of a textured crop spans many decades,
/// and f32 butterflies lose the weak bins (0.7 % error on a log bin).
pub fn fft(re: &mut [f64], im: &mut [f64]) {
    let n = re.len();
    assert!(n.is_power_of_two() && im.len() == n);
    let mut j = 0;
    for i in 1..n {
        let mut bit = n >> 1;
        while j & bit != 0 {
            j ^= bit;
            bit >>= 1;
        }
        j |= bit;
        if i < j {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let mut len = 2;
    while len <= n {
        let ang = -2.0 * std::f64::consts::PI / len as f64;
        for start in (0..n).step_by(len) {
            for k in 0..len / 2 {
                let (s, c) = (ang * k as f64).sin_cos();
                let (a, b) = (start + k, start + k + len / 2);
                let (tr, ti) = (re[b] * c - im[b] * s, re[b] * s + im[b] * c);
                re[b] = re[a] - tr;
                im[b] = im[a] - ti;
                re[a] += tr;
                im[a] += ti;
            }
        }
        len <<= 1;
    }
}

/// The DFT cells of an `n` x `n` spectrum (row-major index) that fall in
/// radius bins 1..n/2 (radius = rounded distance from DC, frequencies
/// wrapped to -n/2..n/2), with each bin's cell count (index = radius).
pub fn radial_bins(n: usize) -> (Vec<(usize, usize)>, Vec<u32>) {
    let bins = n / 2;
    let wrap = |k: usize| {
        if k < n / 2 {
            k as f32
        } else {
            k as f32 - n as f32
        }
    };
    let mut cells = Vec::new();
    let mut cnt = vec![0u32; bins];
    for ky in 0..n {
        for kx in 0..n {
            let (fx, fy) = (wrap(kx), wrap(ky));
            let r = (fx * fx + fy * fy).sqrt().round() as usize;
            if (1..bins).contains(&r) {
                cells.push((ky * n + kx, r));
                cnt[r] += 1;
            }
        }
    }
    (cells, cnt)
}

fn fft_radial(g: &[f32], n: usize) -> Vec<f32> {
    let mean = g.iter().map(|&v| v as f64).sum::<f64>() / g.len() as f64;
    let hann: Vec<f64> = (0..n)
        .map(|i| 0.5 - 0.5 * (2.0 * std::f64::consts::PI * i as f64 / n as f64).cos())
        .collect();
    let mut re: Vec<f64> = (0..n * n)
        .map(|i| (g[i] as f64 - mean) * hann[i / n] * hann[i % n])
        .collect();
    let mut im = vec![0f64; n * n];
    for row in 0..n {
        fft(
            &mut re[row * n..(row + 1) * n],
            &mut im[row * n..(row + 1) * n],
        );
    }
    let (mut cr, mut ci) = (vec![0f64; n], vec![0f64; n]);
    for col in 0..n {
        for r in 0..n {
            cr[r] = re[r * n + col];
            ci[r] = im[r * n + col];
        }
        fft(&mut cr, &mut ci);
        for r in 0..n {
            re[r * n + col] = cr[r];
            im[r * n + col] = ci[r];
        }
    }
    let bins = n / 2;
    let mut sum = vec![0f64; bins];
    let (cells, cnt) = radial_bins(n);
    for &(i, r) in &cells {
        sum[r] += re[i] * re[i] + im[i] * im[i];
    }
    let mut f: Vec<f32> = (1..bins)
        .map(|r| ((sum[r] / cnt[r].max(1) as f64) + 1e-3).ln() as f32)
        .collect();
    let m = f.iter().sum::<f32>() / f.len() as f32;
    f.iter_mut().for_each(|v| *v -= m);
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stripes(period: f32, angle_deg: f32, phase: f32) -> Vec<u8> {
        let (s, c) = angle_deg.to_radians().sin_cos();
        let mut v = Vec::with_capacity(240 * 240 * 3);
        for y in 0..240 {
            for x in 0..240 {
                let t = (x as f32 * c + y as f32 * s) * 2.0 * PI / period + phase;
                let g = (128.0 + 80.0 * t.sin()) as u8;
                v.extend([g, g, g]);
            }
        }
        v
    }

    #[test]
    fn fft_matches_a_direct_dft() {
        let x: Vec<f64> = (0..8).map(|i| ((i * 7) % 5) as f64 - 1.5).collect();
        let (mut re, mut im) = (x.clone(), vec![0.0; 8]);
        fft(&mut re, &mut im);
        for k in 0..8 {
            let (mut dr, mut di) = (0.0f64, 0.0f64);
            for (n, &v) in x.iter().enumerate() {
                let a = -2.0 * std::f64::consts::PI * (k * n) as f64 / 8.0;
                dr += v * a.cos();
                di += v * a.sin();
            }
            assert!((re[k] - dr).abs() < 1e-12 && (im[k] - di).abs() < 1e-12);
        }
    }

    #[test]
    fn riu2_codes() {
        assert_eq!(riu2(0), 0);
        assert_eq!(riu2(0xff), 8);
        assert_eq!(riu2(0b0000_0111), 3);
        assert_eq!(riu2(0b1000_0011), 3);
        assert_eq!(riu2(0b0101_0101), 9);
    }

    #[test]
    fn descriptors_tell_periods_apart_and_lbp_fft_ignore_rotation() {
        let cos = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
        // The power spectrum is radially averaged: any angle. LBP (P = 8)
        // is invariant to rotations that map its neighbour ring onto itself
        // on the pixel grid: quarter turns.
        for (kind, angle) in [(BaselineKind::Lbp, 90.0), (BaselineKind::Fft, 60.0)] {
            let b = Baseline { kind, bgsub: false };
            let f = |p, a, ph| b.features(&stripes(p, a, ph), 240, 240, None);
            let a0 = f(6.0, 0.0, 0.0);
            let a_rot = f(6.0, angle, 1.0);
            let other = f(17.0, 0.0, 0.0);
            assert!((a0.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-4);
            assert!(
                cos(&a0, &a_rot) > cos(&a0, &other),
                "{kind:?}: rotated {} vs other period {}",
                cos(&a0, &a_rot),
                cos(&a0, &other)
            );
        }
        // Background subtraction removes a shared reference exactly.
        let img = stripes(6.0, 0.0, 0.0);
        let b = Baseline {
            kind: BaselineKind::Pixels,
            bgsub: true,
        };
        assert!(b
            .features(&img, 240, 240, Some(&img))
            .iter()
            .all(|&v| v == 0.0));
        assert_eq!(b.features(&img, 240, 240, None).len(), 768);
    }

    /// The Rust-side `wspec` (the 240-px image averaged to 120 px): blind to
    /// per-channel gains of the contact up to the u8 rounding, and a turned
    /// contact stays nearer than another period.
    #[test]
    fn wspec_ignores_channel_gains_and_a_turned_contact_stays_nearer_than_another_period() {
        let bg = vec![100u8; 240 * 240 * 3];
        // A coloured contact on a flat reference: channel c sees the
        // stripes' profile times gains[c], with a phase per channel.
        let contact = |period: f32, angle: f32, gains: [f32; 3]| -> Vec<u8> {
            let (s, c) = angle.to_radians().sin_cos();
            let mut v = Vec::with_capacity(240 * 240 * 3);
            for y in 0..240 {
                for x in 0..240 {
                    let t = (x as f32 * c + y as f32 * s) * 2.0 * PI / period;
                    for (ch, g) in gains.iter().enumerate() {
                        let d = 40.0 * (t + ch as f32 * 2.1).sin();
                        v.push((100.0 + g * d).round() as u8);
                    }
                }
            }
            v
        };
        let b = Baseline {
            kind: BaselineKind::WSpec,
            bgsub: true,
        };
        let f = |img: &[u8]| b.features(img, 240, 240, Some(&bg));
        let cos = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>();
        let a = f(&contact(7.0, 0.0, [1.0, 1.0, 1.0]));
        assert_eq!(a.len(), crate::wspec::dim(120));
        assert!((a.iter().map(|v| v * v).sum::<f32>() - 1.0).abs() < 1e-4);
        let gains = f(&contact(7.0, 0.0, [0.5, 1.4, 0.8]));
        let turned = f(&contact(7.0, 60.0, [1.0, 1.0, 1.0]));
        let other = f(&contact(13.0, 0.0, [1.0, 1.0, 1.0]));
        // Gains change only the u8 rounding noise relative to the contact
        // (a weak channel's noise is whitened up): 0.985 here.
        assert!(cos(&a, &gains) > 0.97, "gains: {}", cos(&a, &gains));
        assert!(
            cos(&a, &turned) > cos(&a, &other),
            "turned {} vs other period {}",
            cos(&a, &turned),
            cos(&a, &other)
        );
    }

    #[test]
    fn wspec_m_is_the_normalised_spectrum_then_the_weighted_statistics() {
        // A coloured, uneven difference on a 96-px image (n = 48).
        let side = 96;
        let img: Vec<u8> = (0..side * side * 3)
            .map(|i| (128 + ((i * 37 + (i / 3) * (i / 3) % 11) % 60) as i32 - 30) as u8)
            .collect();
        let bg = vec![128u8; side * side * 3];
        let x = crate::wspec::planar_of_image(&img, side, Some(&bg), 48);
        let mut spec = crate::wspec::reference_with(&x, 48, crate::wspec::Window::Centre);
        l2(&mut spec);
        let stats = crate::mstats::of_planar(&x, 48);
        for w in [0u8, 2, 5] {
            let b = Baseline {
                kind: BaselineKind::WSpecM(w),
                bgsub: true,
            };
            assert_eq!(b.name(), format!("wspec-m{w} -bg"));
            let f = b.features(&img, side, side, Some(&bg));
            assert_eq!(f.len(), spec.len() + crate::mstats::DIM);
            let mut want = spec.clone();
            want.extend(crate::mstats::standardised(&stats, w as f64 * MSTATS_UNIT));
            l2(&mut want);
            for (a, e) in f.iter().zip(&want) {
                assert!((a - e).abs() < 1e-6, "W = {w}");
            }
        }
        // The statistics alone: standardised, not normalised.
        let m = Baseline {
            kind: BaselineKind::MStats,
            bgsub: true,
        };
        assert_eq!(
            m.features(&img, side, side, Some(&bg)),
            crate::mstats::standardised(&stats, 1.0)
        );
    }
}
