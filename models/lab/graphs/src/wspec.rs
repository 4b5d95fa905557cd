//! The colour-whitened power spectrum (`wspec`): a fixed texture
//! descriptor built around what a DIGIT's optics do, written once here as
//! an f64 reference and as the geometry tables its ONNX graph uses
//! ([`crate::graph`]), so the two cannot disagree.
//!
//! Three facts decide its design:
//!
//! * **Each LED colour sees a directional derivative of the contact.** A
//!   channel of frame − reference is, to first order, the gel's slope along
//!   that LED's direction. With three LEDs about 120° apart, a luma
//!   (weighted sum of the channels) cancels most of that linear signal,
//!   which is what the first descriptor (`fft-radial`, a luma spectrum)
//!   kept. Here every channel's spectrum is used.
//! * **Sensor units differ in their whole colour layout** (the two real
//!   no-contact frames do), i.e. by a mixing of the channels that no fixed
//!   weighting undoes. The descriptor whitens the colours of each frame by
//!   their own covariance: the power at frequency `k` is
//!   `P(k) = F(k)ᴴ Σ⁻¹ F(k)`, where `F(k)` holds the three channels' DFTs
//!   and `Σ` is the 3x3 colour covariance of the windowed difference. `P`
//!   is unchanged by any invertible linear mixing `A` of the channels
//!   (`F → AF`, `Σ → AΣAᵀ`), so per-channel LED gains, a swapped or turned
//!   LED ring and a unit's colour cast all drop out, and so does the
//!   contact's overall strength.
//! * **The fabric turns under the sensor.** The radial average of `P` is
//!   invariant to rotation; what it loses is how the power is arranged in
//!   angle (a plain weave's two orthogonal yarn systems, a twill's
//!   diagonal, a knit's wales). The magnitudes of the angular Fourier
//!   harmonics of `P` in each band keep that, and are invariant to
//!   rotation as well (a turn shifts the angular profile, which changes
//!   only the harmonics' phases).
//!
//! **Where the window sits.** A jig press touches the whole gel; a hand-held
//! press is often tilted, so the fabric touches one side or one corner and
//! the rest of the crop shows only camera noise. A window fixed at the
//! crop's centre then weighs the noise most and the fabric least. The
//! [`Window::Contact`] variant (`wspec-cw`) centres the same Hann window on
//! the contact instead: on the energy centroid of the difference (its
//! squared values summed over the channels, each channel's mean removed).
//! A press that touches the whole crop puts the centroid near the centre
//! and changes little; a tilted one moves the window onto the fabric. The
//! window keeps the crop's width, so its far side falls off the crop: a
//! shifted window is cut there, where the signal is weakest. Moving the
//! window moves only the phase of what it frames, and the descriptor keeps
//! magnitudes.
//!
//! Input: the deployment contract's difference, frame − reference, at
//! `n` x `n` (the graph takes the 240-px crop resized to 120, a 2x2 box
//! average: the camera's blur and block compression leave little above
//! half the sampling rate, and a larger window halves the spread of the
//! spectrum of an irregular cloth). Output (`dim(n)` values):
//!
//! 1. `n/2 − 1` radial bins of `log(P + ε)`, their mean removed
//!    (`floor(|k|)` = 1 .. n/2 − 1);
//! 2. [`BANDS`] radial bands x harmonics 1..=[`HARMONICS`] of the angular
//!    profile of `P` over [`SECTORS`] sectors of [0, π), each harmonic's
//!    magnitude over the band's total.

use std::f64::consts::PI;

/// Radial bands of the angular harmonics.
pub const BANDS: usize = 24;
/// Sectors of the half circle [0, π) (the power spectrum of a real image is
/// point-symmetric).
pub const SECTORS: usize = 16;
/// Angular harmonics kept per band (1..=HARMONICS; 0 is the band's total).
pub const HARMONICS: usize = 4;
/// Added to `P` before the log (`P` is scaled so its mean over the plane is
/// 3: one per whitened channel).
pub const LOG_EPS: f64 = 1e-4;
/// Added to a band's total before dividing a harmonic by it.
pub const HARM_EPS: f64 = 1e-6;
/// Ridge on the colour covariance: this share of its mean variance, plus
/// [`RIDGE_ABS`] (so a blank frame gives zeros, not NaN).
pub const RIDGE_REL: f64 = 1e-3;
pub const RIDGE_ABS: f64 = 1e-6;

/// Length of the descriptor for an `n` x `n` input.
pub fn dim(n: usize) -> usize {
    radial_bins(n) + BANDS * HARMONICS
}

/// Radial bins for an `n` x `n` input.
pub fn radial_bins(n: usize) -> usize {
    n / 2 - 1
}

/// One cell of the half-plane spectrum the graph computes: rows (vertical
/// frequency) `ky` = 0..=n/2, columns `kx` = 0..n; `cell = ky * n + kx`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell {
    pub cell: usize,
    /// 1 on rows 0 and n/2 (their mirror is in the same row), else 2.
    pub weight: f64,
    /// Radial bin, if the cell is in one.
    pub radial: Option<usize>,
    /// (band, sector), if the cell is in a band.
    pub angular: Option<(usize, usize)>,
}

/// The cells of the half plane with their bins (the one definition of the
/// geometry, for the reference and the graph).
pub fn cells(n: usize) -> Vec<Cell> {
    assert!(
        n.is_multiple_of(2) && n >= 16,
        "wspec needs an even n >= 16"
    );
    let h = n / 2;
    let top = h as f64; // radii in [1, n/2) are binned
    let mut out = Vec::with_capacity((h + 1) * n);
    for ky in 0..=h {
        for kx in 0..n {
            let fx = if kx <= h {
                kx as f64
            } else {
                kx as f64 - n as f64
            };
            let fy = ky as f64;
            let r = (fx * fx + fy * fy).sqrt();
            let inside = (1.0..top).contains(&r);
            let radial = inside.then(|| r.floor() as usize - 1);
            let angular = inside.then(|| {
                let band = (((r - 1.0) * BANDS as f64 / (top - 1.0)) as usize).min(BANDS - 1);
                let theta = fy.atan2(fx).rem_euclid(PI);
                let sector = ((theta / PI * SECTORS as f64) as usize) % SECTORS;
                (band, sector)
            });
            out.push(Cell {
                cell: ky * n + kx,
                weight: if ky == 0 || ky == h { 1.0 } else { 2.0 },
                radial,
                angular,
            });
        }
    }
    out
}

/// Sum of cell weights per radial bin and per (band, sector).
pub fn bin_weights(n: usize) -> (Vec<f64>, Vec<f64>) {
    let mut radial = vec![0.0; radial_bins(n)];
    let mut angular = vec![0.0; BANDS * SECTORS];
    for c in cells(n) {
        if let Some(r) = c.radial {
            radial[r] += c.weight;
        }
        if let Some((b, s)) = c.angular {
            angular[b * SECTORS + s] += c.weight;
        }
    }
    (radial, angular)
}

/// Where the 2D Hann window is centred.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Window {
    /// At the crop's centre (`wspec`).
    Centre,
    /// On the contact: the energy centroid of the difference (`wspec-cw`).
    Contact,
}

/// Added to the total energy (in the unit of the input, squared, summed
/// over the pixels) when the contact centroid is taken, with the crop's
/// centre as its position: a blank difference gets the centred window.
pub const CENTROID_EPS: f64 = 1e-6;

/// One axis of the Hann window of length `n` centred at `c`:
/// `0.5 + 0.5 cos(2π min(|i − c|, n/2) / n)`. At `c = n/2` this is the
/// periodic Hann window `0.5 − 0.5 cos(2π i / n)`.
pub fn hann_at(n: usize, c: f64) -> Vec<f64> {
    let half = n as f64 / 2.0;
    (0..n)
        .map(|i| 0.5 + 0.5 * (2.0 * PI * (i as f64 - c).abs().min(half) / n as f64).cos())
        .collect()
}

/// The energy centroid `(row, column)` of `centred` (planar `[3][n][n]`,
/// each channel's mean removed): `Σ e·i / Σ e` with `e` the squared values
/// summed over the channels, pulled to the centre `n/2` by
/// [`CENTROID_EPS`].
pub fn contact_centroid(centred: &[f64], n: usize) -> (f64, f64) {
    let plane = n * n;
    let (mut ey, mut ex) = (vec![0f64; n], vec![0f64; n]);
    for c in 0..3 {
        for (i, v) in centred[c * plane..(c + 1) * plane].iter().enumerate() {
            ey[i / n] += v * v;
            ex[i % n] += v * v;
        }
    }
    let tot: f64 = ey.iter().sum();
    let at = |e: &[f64]| {
        let s: f64 = e.iter().enumerate().map(|(i, v)| i as f64 * v).sum();
        (s + CENTROID_EPS * n as f64 / 2.0) / (tot + CENTROID_EPS)
    };
    (at(&ey), at(&ex))
}

/// `x` (planar `[3][n][n]`) with each channel's mean removed: what the
/// window and [`contact_centroid`] see.
pub fn centred(x: &[f64], n: usize) -> Vec<f64> {
    let plane = n * n;
    let mut w = x.to_vec();
    for ch in w.chunks_mut(plane) {
        let m = ch.iter().sum::<f64>() / plane as f64;
        ch.iter_mut().for_each(|v| *v -= m);
    }
    w
}

/// The periodic Tukey (tapered cosine) window of length `n` whose tapers
/// take `taper` of it (0 < taper <= 1): flat at 1 over the middle
/// `1 − taper`, a half cosine up and down over `taper / 2` at each end.
/// `taper = 1` is the periodic Hann window ([`hann_at`] at `n/2`).
///
/// Why a flatter window: of a crop of irregular cloth, the 2D Hann window
/// keeps an effective area (`(Σw)² / (n Σw²)` per axis, squared) of 44 % of
/// the crop; Tukey 0.5 keeps 67 %, Tukey 0.25 82 %, Tukey 0.1 93 %. The spectrum of a random texture is
/// then averaged over more of the cloth under the gel, which is what most
/// separates two presses of one fabric ("Where on the cloth",
/// docs/benchmarks.md), at the cost of some leakage from strong low
/// frequencies (the contact's own shape) into the rest.
pub fn tukey(n: usize, taper: f64) -> Vec<f64> {
    assert!(taper > 0.0 && taper <= 1.0, "taper in (0, 1]");
    let edge = taper / 2.0;
    (0..n)
        .map(|i| {
            let x = i as f64 / n as f64;
            let d = x.min(1.0 - x);
            if d >= edge {
                1.0
            } else {
                0.5 - 0.5 * (PI * d / edge).cos()
            }
        })
        .collect()
}

/// The descriptor of `x`: planar `[3][n][n]` values of frame − reference
/// (any consistent unit: the whitening removes scale), in f64, with the
/// window at the crop's centre (`wspec`).
pub fn reference(x: &[f64], n: usize) -> Vec<f32> {
    reference_with(x, n, Window::Centre)
}

/// [`reference`] with the window where `window` says.
pub fn reference_with(x: &[f64], n: usize, window: Window) -> Vec<f32> {
    reference_tapered(x, n, window, 1.0)
}

/// [`reference_with`] under a Tukey window of the given `taper`
/// ([`tukey`]; 1 is the Hann window every `wspec` model so far used). A
/// window on the contact is a Hann window only.
pub fn reference_tapered(x: &[f64], n: usize, window: Window, taper: f64) -> Vec<f32> {
    assert_eq!(x.len(), 3 * n * n, "input size");
    let plane = n * n;
    // Per channel: mean removed, then windowed.
    let mut w = centred(x, n);
    let (wy, wx) = match window {
        Window::Centre if taper < 1.0 => (tukey(n, taper), tukey(n, taper)),
        Window::Centre => (hann_at(n, n as f64 / 2.0), hann_at(n, n as f64 / 2.0)),
        Window::Contact => {
            assert!(taper == 1.0, "a window on the contact is a Hann window");
            let (cy, cx) = contact_centroid(&w, n);
            (hann_at(n, cy), hann_at(n, cx))
        }
    };
    for c in 0..3 {
        for i in 0..plane {
            w[c * plane + i] *= wy[i / n] * wx[i % n];
        }
    }
    // Colour covariance of the windowed difference, with the ridge.
    let mut cov = [[0f64; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            cov[i][j] = (0..plane)
                .map(|p| w[i * plane + p] * w[j * plane + p])
                .sum::<f64>()
                / plane as f64;
        }
    }
    let ridge = RIDGE_REL * (cov[0][0] + cov[1][1] + cov[2][2]) / 3.0 + RIDGE_ABS;
    for (i, row) in cov.iter_mut().enumerate() {
        row[i] += ridge;
    }
    let inv = inverse3(&cov);
    // Half-plane DFT of each channel (direct, any even n).
    let h = n / 2 + 1;
    let tw: Vec<(f64, f64)> = (0..n)
        .map(|k| {
            let a = -2.0 * PI * k as f64 / n as f64;
            (a.cos(), a.sin())
        })
        .collect();
    let mut re = vec![0f64; 3 * h * n];
    let mut im = vec![0f64; 3 * h * n];
    for c in 0..3 {
        // Along rows (kx), then along columns for ky = 0..=n/2.
        let (mut rr, mut ri) = (vec![0f64; plane], vec![0f64; plane]);
        for y in 0..n {
            for kx in 0..n {
                let (mut sr, mut si) = (0.0, 0.0);
                for xx in 0..n {
                    let (tc, ts) = tw[(kx * xx) % n];
                    let v = w[c * plane + y * n + xx];
                    sr += v * tc;
                    si += v * ts;
                }
                rr[y * n + kx] = sr;
                ri[y * n + kx] = si;
            }
        }
        for ky in 0..h {
            for kx in 0..n {
                let (mut sr, mut si) = (0.0, 0.0);
                for y in 0..n {
                    let (tc, ts) = tw[(ky * y) % n];
                    let (a, b) = (rr[y * n + kx], ri[y * n + kx]);
                    sr += a * tc - b * ts;
                    si += a * ts + b * tc;
                }
                re[c * h * n + ky * n + kx] = sr;
                im[c * h * n + ky * n + kx] = si;
            }
        }
    }
    // P(k) = F(k)^H inv F(k), scaled by 1/n^2.
    let scale = 1.0 / plane as f64;
    let p: Vec<f64> = (0..h * n)
        .map(|k| {
            let mut s = 0.0;
            for i in 0..3 {
                for j in 0..3 {
                    s += inv[i][j]
                        * (re[i * h * n + k] * re[j * h * n + k]
                            + im[i * h * n + k] * im[j * h * n + k]);
                }
            }
            s * scale
        })
        .collect();
    bin(&p, n)
}

/// Radial log bins and angular harmonics of a half-plane power `p`
/// (`(n/2 + 1) * n` values).
pub fn bin(p: &[f64], n: usize) -> Vec<f32> {
    let (rw, aw) = bin_weights(n);
    let mut radial = vec![0f64; rw.len()];
    let mut ang = vec![0f64; aw.len()];
    for c in cells(n) {
        if let Some(r) = c.radial {
            radial[r] += c.weight * p[c.cell];
        }
        if let Some((b, s)) = c.angular {
            ang[b * SECTORS + s] += c.weight * p[c.cell];
        }
    }
    let logs: Vec<f64> = radial
        .iter()
        .zip(&rw)
        .map(|(s, w)| (s / w + LOG_EPS).ln())
        .collect();
    let mean = logs.iter().sum::<f64>() / logs.len() as f64;
    let mut out: Vec<f32> = logs.iter().map(|v| (v - mean) as f32).collect();
    for b in 0..BANDS {
        let a: Vec<f64> = (0..SECTORS)
            .map(|s| {
                let w = aw[b * SECTORS + s];
                if w > 0.0 {
                    ang[b * SECTORS + s] / w
                } else {
                    0.0
                }
            })
            .collect();
        let total: f64 = a.iter().sum();
        for m in 1..=HARMONICS {
            let (mut hr, mut hi) = (0.0, 0.0);
            for (s, v) in a.iter().enumerate() {
                let t = -2.0 * PI * (m * s) as f64 / SECTORS as f64;
                hr += v * t.cos();
                hi += v * t.sin();
            }
            out.push(((hr * hr + hi * hi).sqrt() / (total + HARM_EPS)) as f32);
        }
    }
    out
}

/// Inverse of a symmetric positive definite 3x3 matrix (adjugate / det).
pub fn inverse3(m: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let (a, b, c) = (m[0][0], m[0][1], m[0][2]);
    let (d, e, f) = (m[1][1], m[1][2], m[2][2]);
    let adj = [
        [d * f - e * e, c * e - b * f, b * e - c * d],
        [c * e - b * f, a * f - c * c, b * c - a * e],
        [b * e - c * d, b * c - a * e, a * d - b * b],
    ];
    let det = a * adj[0][0] + b * adj[0][1] + c * adj[0][2];
    let mut out = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            out[i][j] = adj[i][j] / det;
        }
    }
    out
}

/// The descriptor of an RGB u8 image (HWC, `side` x `side`, minus `bg` if
/// given), as the graph sees it: the centre `2n` square averaged over 2x2
/// blocks to `n` x `n` when the image is that large, else the centre `n`
/// square. For the lab's Rust-side callers and tests.
pub fn of_image(img: &[u8], side: usize, bg: Option<&[u8]>, n: usize) -> Vec<f32> {
    of_image_with(img, side, bg, n, Window::Centre)
}

/// [`of_image`] with the window where `window` says.
pub fn of_image_with(
    img: &[u8],
    side: usize,
    bg: Option<&[u8]>,
    n: usize,
    window: Window,
) -> Vec<f32> {
    reference_with(&planar_of_image(img, side, bg, n), n, window)
}

/// The difference an image gives the descriptor: planar `[3][n][n]` f64
/// values of the centre `2n` square averaged over 2x2 blocks when the image
/// is that large, else of the centre `n` square, minus `bg` if given.
pub fn planar_of_image(img: &[u8], side: usize, bg: Option<&[u8]>, n: usize) -> Vec<f64> {
    assert_eq!(img.len(), side * side * 3, "image size");
    let k = if side >= 2 * n { 2 } else { 1 };
    assert!(side >= k * n, "image smaller than the descriptor's window");
    let o = (side - k * n) / 2;
    let mut x = vec![0f64; 3 * n * n];
    for y in 0..n {
        for xx in 0..n {
            for c in 0..3 {
                let mut s = 0.0;
                for dy in 0..k {
                    for dx in 0..k {
                        let i = ((o + y * k + dy) * side + o + xx * k + dx) * 3 + c;
                        let v = img[i] as f64 - bg.map_or(0.0, |b| b[i] as f64);
                        s += v;
                    }
                }
                x[c * n * n + y * n + xx] = s / (k * k) as f64;
            }
        }
    }
    x
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A synthetic contact: a height field of two yarn systems at `angle`,
    /// seen by three LEDs as directional derivatives with per-LED gains.
    fn contact(n: usize, angle: f64, period: f64, gains: [f64; 3], mix: f64) -> Vec<f64> {
        let dirs = [0.0f64, 2.0 * PI / 3.0, 4.0 * PI / 3.0];
        let mut x = vec![0f64; 3 * n * n];
        let (s, c) = angle.sin_cos();
        for y in 0..n {
            for xx in 0..n {
                let (u, v) = (
                    xx as f64 * c + y as f64 * s,
                    -(xx as f64) * s + y as f64 * c,
                );
                let k = 2.0 * PI / period;
                // gradient of sin(k u) + 0.6 sin(k v / 1.7) in frame axes
                let gu = k * (k * u).cos();
                let gv = 0.6 * k / 1.7 * (k * v / 1.7).cos();
                let (gx, gy) = (gu * c - gv * s, gu * s + gv * c);
                let raw: Vec<f64> = dirs.iter().map(|d| gx * d.cos() + gy * d.sin()).collect();
                for ch in 0..3 {
                    // a colour cast mixes the channels
                    let m = raw[ch] + mix * raw[(ch + 1) % 3];
                    x[ch * n * n + y * n + xx] = gains[ch] * m;
                }
            }
        }
        x
    }

    fn cos(a: &[f32], b: &[f32]) -> f32 {
        let d: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
        let na: f32 = a.iter().map(|x| x * x).sum::<f32>().sqrt();
        let nb: f32 = b.iter().map(|x| x * x).sum::<f32>().sqrt();
        d / (na * nb)
    }

    #[test]
    fn geometry_bins_every_radius_once_and_weights_the_mirror() {
        let n = 32;
        let cs = cells(n);
        assert_eq!(cs.len(), (n / 2 + 1) * n);
        let (rw, aw) = bin_weights(n);
        assert_eq!(rw.len(), n / 2 - 1);
        assert!(rw.iter().all(|&w| w > 0.0));
        // Over the full plane, radius in [1, n/2): the half plane with its
        // weights counts every cell once.
        let full = (0..n * n)
            .filter(|i| {
                let w = |k: usize| {
                    if k <= n / 2 {
                        k as f64
                    } else {
                        k as f64 - n as f64
                    }
                };
                let (fy, fx) = (w(i / n), w(i % n));
                let r = (fx * fx + fy * fy).sqrt();
                (1.0..(n / 2) as f64).contains(&r)
            })
            .count() as f64;
        // Rows ky = n/2 alias with -n/2: count them as the full plane does.
        assert!((rw.iter().sum::<f64>() - full).abs() <= n as f64, "{full}");
        assert!((aw.iter().sum::<f64>() - rw.iter().sum::<f64>()).abs() < 1e-9);
        assert_eq!(dim(120), 59 + BANDS * HARMONICS);
    }

    /// Tukey 1 is the Hann window; Tukey 0.5 is flat over the middle half,
    /// symmetric about n/2, and keeps more of the crop (the effective area
    /// its doc quotes).
    #[test]
    fn a_tukey_window_is_hann_at_one_and_flat_in_the_middle_below() {
        let n = 120;
        let hann = hann_at(n, n as f64 / 2.0);
        let t1 = tukey(n, 1.0);
        assert!(t1.iter().zip(&hann).all(|(a, b)| (a - b).abs() < 1e-12));
        let t = tukey(n, 0.5);
        assert_eq!(t[0], 0.0);
        assert!(t[30..=90].iter().all(|&v| v == 1.0), "{:?}", &t[28..33]);
        assert!(t[1..30].windows(2).all(|w| w[0] < w[1]));
        for i in 1..n {
            assert!((t[i] - t[n - i]).abs() < 1e-12, "{i}");
        }
        let area = |w: &[f64]| {
            let s: f64 = w.iter().sum();
            let q: f64 = w.iter().map(|v| v * v).sum();
            (s * s / q / w.len() as f64).powi(2)
        };
        assert!((area(&hann) - 0.444).abs() < 0.01, "{}", area(&hann));
        assert!((area(&t) - 0.67).abs() < 0.01, "{}", area(&t));
        let t25 = tukey(n, 0.25);
        assert!((area(&t25) - 0.82).abs() < 0.01, "{}", area(&t25));
        let t10 = tukey(n, 0.1);
        assert!((area(&t10) - 0.93).abs() < 0.01, "{}", area(&t10));
        // The whitened spectrum under it is still blind to colour mixing.
        let a = reference_tapered(
            &contact(32, 0.3, 5.0, [1.0; 3], 0.0),
            32,
            Window::Centre,
            0.5,
        );
        let b = reference_tapered(
            &contact(32, 0.3, 5.0, [0.4, 2.5, 1.3], 0.35),
            32,
            Window::Centre,
            0.5,
        );
        assert!(cos(&a, &b) > 0.9999, "{}", cos(&a, &b));
        assert!(cos(&a, &reference(&contact(32, 0.3, 5.0, [1.0; 3], 0.0), 32)) < 0.9999);
    }

    #[test]
    fn invariant_to_mixing_the_colours_and_to_scale() {
        let n = 32;
        let a = reference(&contact(n, 0.3, 5.0, [1.0, 1.0, 1.0], 0.0), n);
        let b = reference(&contact(n, 0.3, 5.0, [0.4, 2.5, 1.3], 0.35), n);
        let d = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0f32, f32::max);
        assert!(d < 1e-3, "colour mixing changed the descriptor by {d}");
        // The luma of the same contact is nearly blind: three LEDs at 120°
        // cancel in the sum.
        let x = contact(n, 0.3, 5.0, [1.0, 1.0, 1.0], 0.0);
        let plane = n * n;
        let luma: f64 = (0..plane)
            .map(|i| (x[i] + x[plane + i] + x[2 * plane + i]).powi(2))
            .sum();
        let chan: f64 = x.iter().map(|v| v * v).sum();
        assert!(luma < 1e-6 * chan, "luma {luma} vs channels {chan}");
    }

    #[test]
    fn a_quarter_turn_leaves_it_and_other_periods_differ() {
        let n = 48;
        let a = reference(&contact(n, 0.2, 6.0, [1.0, 0.8, 1.2], 0.1), n);
        let turned = reference(&contact(n, 0.2 + PI / 2.0, 6.0, [1.0, 0.8, 1.2], 0.1), n);
        let other = reference(&contact(n, 0.2, 11.0, [1.0, 0.8, 1.2], 0.1), n);
        assert!(cos(&a, &turned) > 0.99, "turned: {}", cos(&a, &turned));
        assert!(
            cos(&a, &other) < cos(&a, &turned) - 0.05,
            "other period {} vs turned {}",
            cos(&a, &other),
            cos(&a, &turned)
        );
    }

    #[test]
    fn a_blank_frame_gives_zeros() {
        let n = 16;
        for window in [Window::Centre, Window::Contact] {
            let f = reference_with(&vec![0.0; 3 * n * n], n, window);
            assert_eq!(f.len(), dim(n));
            assert!(f.iter().all(|v| *v == 0.0), "{window:?}: {f:?}");
        }
    }

    #[test]
    fn the_window_at_the_centre_is_the_periodic_hann_window() {
        let n = 32;
        let w = hann_at(n, n as f64 / 2.0);
        for (i, v) in w.iter().enumerate() {
            let hann = 0.5 - 0.5 * (2.0 * PI * i as f64 / n as f64).cos();
            assert!((v - hann).abs() < 1e-12, "{i}: {v} vs {hann}");
        }
        // Moved, it keeps its shape and is zero beyond half its length.
        let m = hann_at(n, 6.0);
        assert_eq!(m[6], 1.0);
        assert!((m[6 + 5] - m[6 - 5]).abs() < 1e-12);
        assert!(m[6 + 16..].iter().all(|&v| v < 1e-12), "{m:?}");
    }

    /// Deterministic noise in [-a, a].
    fn noise(len: usize, a: f64, seed: u64) -> Vec<f64> {
        let mut s = seed;
        (0..len)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                ((s >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0) * a
            })
            .collect()
    }

    #[test]
    fn the_contact_window_follows_a_corner_contact_and_leaves_a_whole_one() {
        let n = 64;
        let plane = n * n;
        let full = contact(n, 0.4, 5.0, [1.0, 0.8, 1.2], 0.1);
        let bg = noise(3 * plane, 0.15, 7);
        let whole: Vec<f64> = full.iter().zip(&bg).map(|(a, b)| a + b).collect();
        // A tilted press: the fabric touches the top-left corner only.
        let corner: Vec<f64> = (0..3 * plane)
            .map(|i| {
                let (y, x) = ((i % plane) / n, i % n);
                let touch = if y < 24 && x < 28 { 1.0 } else { 0.0 };
                full[i] * touch + bg[i]
            })
            .collect();
        let (cy, cx) = contact_centroid(&centred(&corner, n), n);
        assert!(cy < 16.0 && cx < 18.0, "corner centroid ({cy}, {cx})");
        let (wy, wx) = contact_centroid(&centred(&whole, n), n);
        assert!(
            (wy - 31.5).abs() < 3.0 && (wx - 31.5).abs() < 3.0,
            "whole-contact centroid ({wy}, {wx})"
        );
        // A whole contact: both windows describe it alike.
        let a = reference_with(&whole, n, Window::Centre);
        let b = reference_with(&whole, n, Window::Contact);
        assert!(cos(&a, &b) > 0.99, "whole contact: {}", cos(&a, &b));
        // A corner contact: the contact window's descriptor is nearer the
        // whole contact's than the centred window's.
        let fixed = cos(&reference_with(&corner, n, Window::Centre), &a);
        let moved = cos(&reference_with(&corner, n, Window::Contact), &a);
        assert!(
            moved > fixed + 0.02,
            "contact window {moved} vs centred {fixed}"
        );
    }
}
