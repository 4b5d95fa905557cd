//! How hard is the simulated benchmark? A rotation-invariant hand-made
//! baseline (radially averaged power spectrum of the contact signal +
//! nearest centroid) on the mid-hold frame, in the paper's setting:
//! centroids from jig presses of people 0..5, tested on people 6..10 with
//! the jig and hand-held. Also the weave-family accuracy.
//!
//! `cargo run --release -p telextiles-sim --example baseline [n_textiles [catalogue [generator]]]`
//! (catalogue 1 uses frame 100 as always; catalogue 2 the mid-hold frame,
//! since its presses run at 25..60 fps and release at varying times)
use telextiles_sim::{PressSpec, RgbImage, Simulator};

const CROP: usize = 96;

fn feature(f: &RgbImage, bg: &RgbImage) -> Vec<f32> {
    let (w, h) = (240usize, 320usize);
    let (x0, y0) = ((w - CROP) / 2, (h - CROP) / 2);
    let mut img = vec![0f32; CROP * CROP];
    for y in 0..CROP {
        for x in 0..CROP {
            let a = f.get_pixel((x0 + x) as u32, (y0 + y) as u32).0;
            let b = bg.get_pixel((x0 + x) as u32, (y0 + y) as u32).0;
            img[y * CROP + x] = (0..3).map(|c| (a[c] as f32 - b[c] as f32).abs()).sum();
        }
    }
    let m = img.iter().sum::<f32>() / img.len() as f32;
    img.iter_mut().for_each(|v| *v -= m);
    // separable DFT power spectrum
    let n = CROP;
    let mut re = vec![0f32; n * n];
    let mut im = vec![0f32; n * n];
    let tw: Vec<(f32, f32)> = (0..n)
        .map(|k| {
            let a = -2.0 * std::f32::consts::PI * k as f32 / n as f32;
            (a.cos(), a.sin())
        })
        .collect();
    for y in 0..n {
        for k in 0..n {
            let (mut sr, mut si) = (0.0, 0.0);
            for x in 0..n {
                let (c, s) = tw[(k * x) % n];
                sr += img[y * n + x] * c;
                si += img[y * n + x] * s;
            }
            re[y * n + k] = sr;
            im[y * n + k] = si;
        }
    }
    let bins = 20;
    let mut acc = vec![0f64; bins];
    let mut cnt = vec![0u32; bins];
    for kx in 0..n {
        for ky in 0..n {
            let (mut sr, mut si) = (0.0, 0.0);
            for y in 0..n {
                let (c, s) = tw[(ky * y) % n];
                let (a, b) = (re[y * n + kx], im[y * n + kx]);
                sr += a * c - b * s;
                si += a * s + b * c;
            }
            let fx = if kx > n / 2 {
                kx as f64 - n as f64
            } else {
                kx as f64
            };
            let fy = if ky > n / 2 {
                ky as f64 - n as f64
            } else {
                ky as f64
            };
            let r = (fx * fx + fy * fy).sqrt();
            if r >= 1.0 && r < (n / 2) as f64 {
                let b = ((r - 1.0) / ((n / 2) as f64 - 1.0) * bins as f64) as usize;
                acc[b] += (sr * sr + si * si) as f64;
                cnt[b] += 1;
            }
        }
    }
    let v: Vec<f32> = acc
        .iter()
        .zip(&cnt)
        .map(|(a, c)| ((a / (*c).max(1) as f64) + 1e-6).ln() as f32)
        .collect();
    let mean = v.iter().sum::<f32>() / v.len() as f32;
    v.iter().map(|x| x - mean).collect()
}

fn dist(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(40);
    let arg = |i: usize, d: u32| {
        std::env::args()
            .nth(i)
            .and_then(|s| s.parse().ok())
            .unwrap_or(d)
    };
    let (version, generator) = (arg(2, 1), arg(3, 1));
    let sim = Simulator::with_options(version, generator).expect("simulator");
    let cat = sim.catalogue();
    let step = (119 / n).max(1);
    let ids: Vec<String> = cat
        .training()
        .step_by(step)
        .take(n)
        .map(|t| t.id.clone())
        .collect();
    let feat = |id: &str, person: u32, jig: bool| {
        let spec = PressSpec {
            person,
            jig,
            ..PressSpec::new(id, 1000 + person as u64)
        };
        let frame = if version == 1 {
            100
        } else {
            let p = sim.press_meta(&spec).expect("meta").params.expect("params");
            ((p.hold_frame + p.release_frame.unwrap_or(spec.frames as u32)) / 2) as usize
        };
        let f = sim.render_frame(&spec, frame).expect("frame");
        feature(&f, &sim.background(0))
    };
    let mut centroids = Vec::new();
    for id in &ids {
        let fs: Vec<Vec<f32>> = (0..6).map(|p| feat(id, p, true)).collect();
        let mut m = vec![0f32; fs[0].len()];
        for f in &fs {
            for (a, b) in m.iter_mut().zip(f) {
                *a += b / fs.len() as f32;
            }
        }
        centroids.push(m);
    }
    let fam = |i: usize| cat.get(&ids[i]).expect("id").structure.family();
    for jig in [true, false] {
        let (mut ok, mut fam_ok, mut total) = (0, 0, 0);
        for (i, id) in ids.iter().enumerate() {
            for p in 6..11 {
                let f = feat(id, p, jig);
                let best = (0..ids.len())
                    .min_by(|a, b| dist(&centroids[*a], &f).total_cmp(&dist(&centroids[*b], &f)))
                    .expect("non-empty");
                ok += (best == i) as usize;
                fam_ok += (fam(best) == fam(i)) as usize;
                total += 1;
            }
        }
        println!(
            "catalogue {version} generator {generator}, {} textiles, test {}: textile top-1 {ok}/{total} = {:.1}%, family {:.1}% (chance {:.1}%)",
            ids.len(),
            if jig { "jig      " } else { "hand-held" },
            100.0 * ok as f32 / total as f32,
            100.0 * fam_ok as f32 / total as f32,
            100.0 / ids.len() as f32
        );
    }
}
