//! Whitened multiscale marginal statistics (`mstats`): what a power
//! spectrum cannot see.
//!
//! The whitened spectrum ([`crate::wspec`]) is a second-order description:
//! it keeps how much relief there is at each scale and orientation, and
//! nothing of how that relief is arranged. A cloth whose yarns are evenly
//! rough and one whose relief comes in rare, strong features (pills, slubs,
//! loops, a seam, hairs) can have the same spectrum. The classic texture
//! statistics of Portilla and Simoncelli add the *marginal* distributions
//! of band-pass responses and how their energies co-occur; the 30-line
//! baseline that real presses preferred to the first shipped pipeline kept
//! a histogram of gradient magnitude. This module computes the few such
//! statistics the sensor's optics allow without giving up the spectrum's
//! invariances:
//!
//! * **Bands**: an *à trous* (undecimated) pyramid of the difference
//!   frame − reference, smoothing with the binomial kernel `[1, 2, 1] / 4`
//!   at dilation `2^j`; band `j` is level `j` minus level `j + 1`
//!   ([`LEVELS`] bands, finest first).
//! * **Per pixel, per band, one mixing-invariant energy**: with `v` the
//!   three channels' band responses at a pixel and `Σ` their covariance
//!   over the band, `m = vᵀ Σ⁻¹ v`. Each channel of a DIGIT is about a
//!   directional derivative of the contact, so `m` is the local slope's
//!   squared magnitude in that band, whitened: any invertible mixing of the
//!   channels (a unit's colour layout, LED gains) and the contact's
//!   strength leave it unchanged, exactly as for the spectrum.
//! * **Statistics of `m`** (each invariant to those as well, and to
//!   rotation up to the lag's sampling): per band the log of the
//!   normalised second moment `E[m²] / E[m]²` (peaky relief raises it),
//!   the log of `E[√m] / √E[m]` (the same from below, less driven by the
//!   largest values), and the correlation of `m` with its four neighbours
//!   at the band's own scale (relief in patches against evenly spread);
//!   between neighbouring bands, the correlation of their `m` (edges and
//!   features that live across scales).
//!
//! Everything is taken over the interior of the window, [`MARGIN`] pixels
//! from its edges, where every band is computed without reaching past the
//! input. Output: [`DIM`] raw values, `f64`; [`standardised`] centres and
//! scales them by constants measured once on training presses.

/// Band-pass levels.
pub const LEVELS: usize = 3;
/// Values: three per band, one per pair of neighbouring bands.
pub const DIM: usize = LEVELS * 3 + (LEVELS - 1);
/// Pixels left out at each edge: the pyramid's reach (1 + 2 + 4) plus the
/// coarsest band's neighbour lag (4), rounded up.
pub const MARGIN: usize = 12;
/// Guards the ratios and logs of a blank difference.
pub const EPS: f64 = 1e-12;

/// One binomial smoothing of a plane at dilation `d`, edges clamped.
fn smooth(p: &[f64], n: usize, d: usize) -> Vec<f64> {
    let at = |i: isize| i.clamp(0, n as isize - 1) as usize;
    let mut tmp = vec![0f64; n * n];
    for y in 0..n {
        for x in 0..n {
            let xi = x as isize;
            tmp[y * n + x] = 0.25 * p[y * n + at(xi - d as isize)]
                + 0.5 * p[y * n + x]
                + 0.25 * p[y * n + at(xi + d as isize)];
        }
    }
    let mut out = vec![0f64; n * n];
    for y in 0..n {
        let yi = y as isize;
        for x in 0..n {
            out[y * n + x] = 0.25 * tmp[at(yi - d as isize) * n + x]
                + 0.5 * tmp[y * n + x]
                + 0.25 * tmp[at(yi + d as isize) * n + x];
        }
    }
    out
}

/// Pearson correlation of two equally long series (0 when either is flat).
fn corr(a: &[f64], b: &[f64]) -> f64 {
    let k = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / k, b.iter().sum::<f64>() / k);
    let (mut sab, mut saa, mut sbb) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(b) {
        let (dx, dy) = (x - ma, y - mb);
        sab += dx * dy;
        saa += dx * dx;
        sbb += dy * dy;
    }
    sab / ((saa * sbb).sqrt() + EPS)
}

/// The statistics of `x`: planar `[3][n][n]` values of frame − reference
/// (any unit). [`DIM`] values: per band (finest first) `ln(E[m²]/E[m]²)`,
/// `ln(E[√m]/√E[m])`, the neighbour correlation of `m`; then the
/// correlation of `m` between bands 0–1, 1–2.
pub fn of_planar(x: &[f64], n: usize) -> Vec<f64> {
    assert_eq!(x.len(), 3 * n * n, "input size");
    assert!(n > 2 * MARGIN + 8, "mstats needs n > {}", 2 * MARGIN + 8);
    let plane = n * n;
    let inner: Vec<usize> = (MARGIN..n - MARGIN)
        .flat_map(|y| (MARGIN..n - MARGIN).map(move |xx| y * n + xx))
        .collect();
    let mut level: Vec<Vec<f64>> = (0..3)
        .map(|c| x[c * plane..(c + 1) * plane].to_vec())
        .collect();
    let mut energies: Vec<Vec<f64>> = Vec::with_capacity(LEVELS);
    let mut out = Vec::with_capacity(DIM);
    for j in 0..LEVELS {
        let d = 1usize << j;
        let next: Vec<Vec<f64>> = level.iter().map(|p| smooth(p, n, d)).collect();
        let band: Vec<Vec<f64>> = level
            .iter()
            .zip(&next)
            .map(|(a, b)| a.iter().zip(b).map(|(u, v)| u - v).collect())
            .collect();
        // Colour covariance of the band over the interior, with the ridge
        // of the spectrum.
        let k = inner.len() as f64;
        let means: Vec<f64> = band
            .iter()
            .map(|p| inner.iter().map(|&i| p[i]).sum::<f64>() / k)
            .collect();
        let mut cov = [[0f64; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                cov[a][b] = inner
                    .iter()
                    .map(|&i| (band[a][i] - means[a]) * (band[b][i] - means[b]))
                    .sum::<f64>()
                    / k;
            }
        }
        let ridge = crate::wspec::RIDGE_REL * (cov[0][0] + cov[1][1] + cov[2][2]) / 3.0
            + crate::wspec::RIDGE_ABS;
        for (a, row) in cov.iter_mut().enumerate() {
            row[a] += ridge;
        }
        let inv = crate::wspec::inverse3(&cov);
        // m over the whole plane (the neighbours reach past the interior).
        let m: Vec<f64> = (0..plane)
            .map(|i| {
                let v = [
                    band[0][i] - means[0],
                    band[1][i] - means[1],
                    band[2][i] - means[2],
                ];
                let mut s = 0.0;
                for a in 0..3 {
                    for b in 0..3 {
                        s += v[a] * inv[a][b] * v[b];
                    }
                }
                s.max(0.0)
            })
            .collect();
        let e1 = inner.iter().map(|&i| m[i]).sum::<f64>() / k;
        let e2 = inner.iter().map(|&i| m[i] * m[i]).sum::<f64>() / k;
        let eh = inner.iter().map(|&i| m[i].sqrt()).sum::<f64>() / k;
        out.push(((e2 + EPS) / (e1 * e1 + EPS)).ln());
        out.push(((eh + EPS) / (e1.sqrt() + EPS)).ln());
        let here: Vec<f64> = inner.iter().map(|&i| m[i]).collect();
        let around: Vec<f64> = inner
            .iter()
            .map(|&i| 0.25 * (m[i - d] + m[i + d] + m[i - d * n] + m[i + d * n]))
            .collect();
        out.push(corr(&here, &around));
        energies.push(here);
        level = next;
    }
    for j in 0..LEVELS - 1 {
        out.push(corr(&energies[j], &energies[j + 1]));
    }
    out
}

/// Typical value and spread of each statistic over the frames in contact
/// of catalogue-2 presses by training people on training units (3,635
/// frames of 118 presses, 59 textiles, people 1–6, units 1–3, hand-held
/// and jig; measured by `telextiles-lab mstats-scale`, see
/// `docs/benchmarks.md`).
pub const CENTRE: [f64; DIM] = [
    0.9511, -0.1320, 0.4885, 1.2158, -0.1809, 0.4842, 1.2367, -0.2003, 0.4553, 0.4601, 0.5557,
];
/// See [`CENTRE`].
pub const SPREAD: [f64; DIM] = [
    0.3303, 0.0411, 0.2182, 0.5102, 0.0782, 0.1680, 0.4871, 0.0921, 0.1574, 0.1185, 0.1501,
];

/// `raw` centred by [`CENTRE`] and divided by [`SPREAD`], times `weight`.
pub fn standardised(raw: &[f64], weight: f64) -> Vec<f32> {
    raw.iter()
        .zip(CENTRE.iter().zip(&SPREAD))
        .map(|(v, (c, s))| ((v - c) / s * weight) as f32)
        .collect()
}

/// What [`scale_of_presses`] measured.
#[derive(Clone, Debug, PartialEq)]
pub struct Scale {
    /// Mean of each statistic.
    pub centre: Vec<f64>,
    /// Its standard deviation.
    pub spread: Vec<f64>,
    /// Mean standard deviation of the values of the L2-normalised
    /// whitened spectrum over the same frames.
    pub spectrum_spread: f64,
    /// Frames measured, and presses they came from.
    pub frames: usize,
    pub presses: usize,
}

/// The constants of [`standardised`] and of the weight `wspec-mW` uses,
/// measured on recorded presses under `dir` (the press format, found
/// recursively): every `every`-th frame in contact of each, as the
/// daemon's contact detector finds them with the recording's own
/// reference, the 240-px crop at 120 px. Shows progress.
pub fn scale_of_presses(dir: &std::path::Path, every: usize) -> anyhow::Result<Scale> {
    use crate::preprocess::centre_crop_resize;
    use anyhow::ensure;
    let dirs = telextiles_sim::recording::find_presses(dir)?;
    ensure!(!dirs.is_empty(), "{}: no presses", dir.display());
    let cfg = telextiles_sensing::contact::ContactConfig::default();
    let bar = telextiles_progress::Progress::new("measuring", dirs.len() as u64, "presses");
    let (mut st, mut sp): (Vec<Vec<f64>>, Vec<Vec<f64>>) = (Vec::new(), Vec::new());
    let mut presses = 0;
    for d in &dirs {
        let press = telextiles_sim::recording::read_press(d)?;
        bar.inc(1);
        let Some(seg) = telextiles_sensing::front::segment(&press, &cfg) else {
            continue;
        };
        let rv = centre_crop_resize(
            &crate::preprocess::reference_image(&seg.reference)?,
            240,
            240,
        )?;
        let before = st.len();
        for c in seg
            .contact
            .iter()
            .filter(|c| !c.early)
            .step_by(every.max(1))
        {
            let fv = centre_crop_resize(&press.frames[c.index], 240, 240)?;
            let x = crate::wspec::planar_of_image(fv.as_raw(), 240, Some(rv.as_raw()), 120);
            st.push(of_planar(&x, 120));
            let mut f = crate::wspec::reference_with(&x, 120, crate::wspec::Window::Centre);
            crate::knn::l2(&mut f);
            sp.push(f.iter().map(|&v| v as f64).collect());
        }
        presses += (st.len() > before) as usize;
    }
    bar.finish();
    ensure!(
        st.len() > 1,
        "{}: fewer than two frames in contact",
        dir.display()
    );
    let k = st.len() as f64;
    let mean_sd = |rows: &[Vec<f64>], j: usize| {
        let m = rows.iter().map(|r| r[j]).sum::<f64>() / k;
        let v = rows.iter().map(|r| (r[j] - m).powi(2)).sum::<f64>() / (k - 1.0);
        (m, v.sqrt())
    };
    let (centre, spread): (Vec<f64>, Vec<f64>) = (0..DIM).map(|j| mean_sd(&st, j)).unzip();
    let n = sp[0].len();
    Ok(Scale {
        centre,
        spread,
        spectrum_spread: (0..n).map(|j| mean_sd(&sp, j).1).sum::<f64>() / n as f64,
        frames: st.len(),
        presses,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Three channels as directional derivatives (LEDs 120° apart) of a
    /// height field `h`.
    fn contact(n: usize, h: impl Fn(f64, f64) -> f64, gains: [f64; 3], mix: f64) -> Vec<f64> {
        let dirs = [
            0.0f64,
            2.0 * std::f64::consts::PI / 3.0,
            4.0 * std::f64::consts::PI / 3.0,
        ];
        let mut x = vec![0f64; 3 * n * n];
        for y in 0..n {
            for xx in 0..n {
                let (fx, fy) = (xx as f64, y as f64);
                let gx = h(fx + 0.5, fy) - h(fx - 0.5, fy);
                let gy = h(fx, fy + 0.5) - h(fx, fy - 0.5);
                let raw: Vec<f64> = dirs.iter().map(|d| gx * d.cos() + gy * d.sin()).collect();
                for c in 0..3 {
                    x[c * n * n + y * n + xx] = gains[c] * (raw[c] + mix * raw[(c + 1) % 3]);
                }
            }
        }
        x
    }

    fn weave(x: f64, y: f64) -> f64 {
        (x * 0.9).sin() + (y * 0.9).sin()
    }

    /// The same weave with rare strong bumps (pills).
    fn pilled(x: f64, y: f64) -> f64 {
        let mut h = weave(x, y);
        for (cx, cy) in [(30.0, 40.0), (70.0, 25.0), (55.0, 75.0), (85.0, 88.0)] {
            let r2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
            h += 6.0 * (-r2 / 8.0).exp();
        }
        h
    }

    #[test]
    fn invariant_to_mixing_the_colours_and_to_scale() {
        let n = 100;
        let a = of_planar(&contact(n, pilled, [1.0, 1.0, 1.0], 0.0), n);
        let b = of_planar(&contact(n, pilled, [3.0, 0.4, 1.7], 0.35), n);
        assert_eq!(a.len(), DIM);
        for (u, v) in a.iter().zip(&b) {
            assert!((u - v).abs() < 5e-3, "{a:?} vs {b:?}");
        }
    }

    #[test]
    fn rare_strong_relief_raises_the_peakiness() {
        let n = 100;
        let even = of_planar(&contact(n, weave, [1.0; 3], 0.0), n);
        let pills = of_planar(&contact(n, pilled, [1.0; 3], 0.0), n);
        // The normalised second moment rises in every band, most in the
        // coarse band, the pills' own scale.
        for j in 0..LEVELS {
            assert!(
                pills[3 * j] > even[3 * j] + 0.03,
                "band {j}: {even:?} vs {pills:?}"
            );
            // The square root's moment falls below that of even relief.
            assert!(
                pills[3 * j + 1] < even[3 * j + 1],
                "band {j}: {even:?} vs {pills:?}"
            );
        }
        assert!(pills[6] > even[6] + 0.2, "{even:?} vs {pills:?}");
        // Energies of neighbouring bands co-occur less than the weave's.
        assert!(pills[10] < even[10] - 0.1, "{even:?} vs {pills:?}");
    }

    #[test]
    fn a_blank_difference_gives_finite_values() {
        let n = 64;
        let v = of_planar(&vec![0.0; 3 * n * n], n);
        assert!(v.iter().all(|x| x.is_finite()), "{v:?}");
    }

    #[test]
    fn the_scale_is_measured_on_the_frames_in_contact_of_recorded_presses() {
        let dir = tempfile::tempdir().unwrap();
        let sim = telextiles_sim::Simulator::new().unwrap();
        for (k, t) in ["T001", "T050"].iter().enumerate() {
            let p = sim
                .render_press(&telextiles_sim::PressSpec {
                    frames: 60,
                    ..telextiles_sim::PressSpec::new(*t, k as u64)
                })
                .unwrap();
            telextiles_sim::recording::write_press(&dir.path().join(t).join("p"), &p).unwrap();
        }
        let all = scale_of_presses(dir.path(), 1).unwrap();
        let some = scale_of_presses(dir.path(), 5).unwrap();
        assert_eq!((all.presses, some.presses), (2, 2));
        assert!(
            all.frames > some.frames && some.frames >= 2,
            "{all:?} {some:?}"
        );
        assert_eq!((all.centre.len(), all.spread.len()), (DIM, DIM));
        assert!(
            all.spread.iter().all(|s| s.is_finite() && *s > 0.0),
            "{all:?}"
        );
        assert!(all.spectrum_spread > 0.0 && all.spectrum_spread < 1.0);
        // A directory without presses is an error that names it.
        let empty = tempfile::tempdir().unwrap();
        let e = scale_of_presses(empty.path(), 1).unwrap_err().to_string();
        assert!(e.contains(&empty.path().display().to_string()), "{e}");
    }
}
