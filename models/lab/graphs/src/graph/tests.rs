use super::*;
use crate::baselines::Baseline;
use crate::ortrun::OrtEncoder;
use crate::preprocess::normalize_into;

fn l2(mut v: Vec<f32>) -> Vec<f32> {
    crate::knn::l2(&mut v);
    v
}

/// Pseudo-random textured RGB images of side `n`.
fn images(n: usize, count: usize) -> Vec<Vec<u8>> {
    (0..count)
        .map(|k| {
            (0..n * n * 3)
                .map(|i| {
                    let (x, y, c) = ((i / 3) % n, (i / 3) / n, i % 3);
                    let v = 120.0
                        + 50.0 * ((x as f32 * (0.3 + 0.1 * k as f32)) + y as f32 * 0.7).sin()
                        + 20.0 * c as f32
                        + ((i * 7919 + k * 104_729) % 13) as f32;
                    v.clamp(0.0, 255.0) as u8
                })
                .collect()
        })
        .collect()
}

#[test]
fn graphs_match_the_rust_descriptors_in_onnx_runtime() {
    for (kind, n) in [
        (BaselineKind::Fft, 64usize),
        (BaselineKind::Fft, 32),
        (BaselineKind::Pixels, 64),
    ] {
        let spec = DescriptorSpec {
            kind,
            crop: n as u32,
            input: n as u32,
            subtract: false,
            min_bin: 1,
            taper: 100,
        };
        let bytes = descriptor_model(&spec).unwrap();
        let mut enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
        assert_eq!(enc.dim, spec.dim());
        assert_eq!(enc.input_size, n);
        let imgs = images(n, 3);
        let mut x = Vec::new();
        for img in &imgs {
            normalize_into(img, n, &mut x);
        }
        let got = enc.embed(&x).unwrap();
        let base = Baseline { kind, bgsub: false };
        for (i, img) in imgs.iter().enumerate() {
            let want = base.features(img, n, n, None);
            let g = l2(got[i * spec.dim()..(i + 1) * spec.dim()].to_vec());
            let diff = g
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0f32, f32::max);
            // The graph's DFT is f32 matrix products; the Rust reference
            // is an f64 FFT. A pure grating over faint noise (these
            // images) spans the most decades: 4e-4 on one log bin.
            assert!(diff < 1e-3, "{kind:?} n={n} image {i}: max diff {diff}");
        }
        // A blank frame gives finite numbers (the daemon's dry run).
        let blank = vec![0f32; 3 * n * n];
        assert!(enc.embed(&blank).unwrap().iter().all(|v| v.is_finite()));
    }
}

/// The descriptor by direct f64 DFT (any even n): the reference for
/// sizes the Rust FFT does not take.
fn radial_reference(grey: &[f64], n: usize, r0: usize) -> Vec<f32> {
    let mean = grey.iter().sum::<f64>() / grey.len() as f64;
    let h = hann(n);
    let x: Vec<f64> = (0..n * n)
        .map(|i| (grey[i] - mean) * h[i / n] as f64 * h[i % n] as f64)
        .collect();
    let (cells, cnt) = radial_bins(n);
    let mut sum = vec![0f64; n / 2];
    for &(cell, r) in &cells {
        let (ky, kx) = (cell / n, cell % n);
        let (mut re, mut im) = (0f64, 0f64);
        for y in 0..n {
            for xx in 0..n {
                let a = -2.0 * PI * (((ky * y) % n) as f64 + ((kx * xx) % n) as f64) / n as f64;
                re += x[y * n + xx] * a.cos();
                im += x[y * n + xx] * a.sin();
            }
        }
        sum[r] += re * re + im * im;
    }
    let f: Vec<f64> = (r0..n / 2)
        .map(|r| (sum[r] / cnt[r] as f64 + 1e-3).ln())
        .collect();
    let m = f.iter().sum::<f64>() / f.len() as f64;
    l2(f.iter().map(|v| (v - m) as f32).collect())
}

fn grey_of(img: &[u8]) -> Vec<f64> {
    img.chunks(3)
        .map(|p| (0..3).map(|c| GREY[c] as f64 * p[c] as f64).sum())
        .collect()
}

#[test]
fn any_even_size_and_background_subtraction_match_references() {
    // 48 is no power of two: against the direct f64 DFT.
    let n = 48;
    let spec = DescriptorSpec {
        kind: BaselineKind::Fft,
        crop: 48,
        input: 48,
        subtract: false,
        min_bin: 1,
        taper: 100,
    };
    let mut enc = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
    let imgs = images(n, 2);
    for img in &imgs {
        let mut x = Vec::new();
        normalize_into(img, n, &mut x);
        let got = l2(enc.embed(&x).unwrap());
        let want = radial_reference(&grey_of(img), n, 1);
        let d = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(d < 1e-3, "n=48: max diff {d}");
    }
    // Dropping the coarsest bins (min_bin 4): bins 4..24, centred anew.
    let spec = DescriptorSpec { min_bin: 4, ..spec };
    assert_eq!(spec.arch(), "fft-radial-c48-r4");
    let mut enc = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
    assert_eq!(enc.dim, 20);
    let mut x = Vec::new();
    normalize_into(&imgs[0], n, &mut x);
    let got = l2(enc.embed(&x).unwrap());
    let want = radial_reference(&grey_of(&imgs[0]), n, 4);
    let d = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    assert!(d < 1e-3, "min_bin 4: max diff {d}");
    // Background subtraction: the model fed normalise(frame) -
    // normalise(reference) computes the descriptor of frame - reference,
    // as the Rust descriptor with bgsub does.
    let n = 64;
    let spec = DescriptorSpec {
        kind: BaselineKind::Fft,
        crop: 64,
        input: 64,
        subtract: true,
        min_bin: 1,
        taper: 100,
    };
    let mut enc = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
    let imgs = images(n, 2);
    let (frame, reference) = (&imgs[0], &imgs[1]);
    let mut x = Vec::new();
    crate::preprocess::input_into(frame, Some(reference), n, &mut x);
    let got = l2(enc.embed(&x).unwrap());
    let want = Baseline {
        kind: BaselineKind::Fft,
        bgsub: true,
    }
    .features(frame, n, n, Some(reference));
    let d = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    assert!(d < 1e-3, "subtract: max diff {d}");
}

#[test]
fn a_head_on_the_descriptor_computes_the_mlp_of_its_spectrum() {
    let spec = DescriptorSpec {
        kind: BaselineKind::Fft,
        crop: 32,
        input: 32,
        subtract: true,
        min_bin: 1,
        taper: 100,
    };
    let (i, h, o) = (spec.dim(), 8, 5);
    let w = |n: usize, k: usize| -> Vec<f32> {
        (0..n)
            .map(|j| ((j * 31 + k) % 17) as f32 / 17.0 - 0.45)
            .collect()
    };
    let head = MlpHead {
        scale: w(i, 1).iter().map(|v| v + 1.0).collect(),
        w1: w(i * h, 2),
        b1: w(h, 3),
        w2: w(h * o, 4),
        b2: w(o, 5),
        input: i,
        hidden: h,
        out: o,
    };
    let bytes = descriptor_with_head(&spec, &head, "test").unwrap();
    let mut enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
    assert_eq!(enc.dim, o);
    assert_eq!(
        enc.meta.get("telextiles.arch").map(String::as_str),
        Some("fft-radial-c32-bg+mlp8-5")
    );
    let mut front = OrtEncoder::from_bytes(&descriptor_model(&spec).unwrap(), 1).unwrap();
    let imgs = images(32, 2);
    let mut x = Vec::new();
    crate::preprocess::input_into(&imgs[0], Some(&imgs[1]), 32, &mut x);
    let got = enc.embed(&x).unwrap();
    let spectrum = front.embed(&x).unwrap();
    let hidden: Vec<f32> = (0..h)
        .map(|k| {
            let v: f32 = (0..i)
                .map(|j| spectrum[j] * head.scale[j] * head.w1[j * h + k])
                .sum::<f32>()
                + head.b1[k];
            v.max(0.0)
        })
        .collect();
    for (k, g) in got.iter().enumerate().take(o) {
        let want: f32 = (0..h).map(|j| hidden[j] * head.w2[j * o + k]).sum::<f32>() + head.b2[k];
        assert!((g - want).abs() < 1e-3, "output {k}: {g} vs {want}");
    }
    // Shapes that do not fit are refused.
    let mut bad = head.clone();
    bad.b1.pop();
    assert!(descriptor_with_head(&spec, &bad, "test").is_err());
}

#[test]
fn wspec_graph_computes_its_reference_with_and_without_a_linear_head() {
    let n = 32;
    let spec = wspec_64_to_32(100);
    assert_eq!(spec.arch(), "wspec-c64-s32-bg");
    let imgs = images(n, 3);
    let (x, mut enc) = wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Centre);
    assert_eq!(enc.meta["telextiles.background"], "subtract");
    let got = enc.embed(&x).unwrap();
    let d = spec.dim();
    // A frame equal to its reference: zeros, not NaN.
    let mut blank = Vec::new();
    crate::preprocess::input_into(&imgs[0], Some(&imgs[0]), n, &mut blank);
    assert!(enc.embed(&blank).unwrap().iter().all(|v| *v == 0.0));
    // A linear head: y = W (x * scale) + b.
    let o = 6;
    let head = MlpHead {
        scale: (0..d).map(|j| 1.0 + (j % 5) as f32 * 0.1).collect(),
        w1: (0..d * o)
            .map(|j| ((j * 13) % 7) as f32 / 7.0 - 0.4)
            .collect(),
        b1: (0..o).map(|j| j as f32 * 0.01).collect(),
        w2: Vec::new(),
        b2: Vec::new(),
        input: d,
        hidden: 0,
        out: o,
    };
    let bytes = descriptor_with_head(&spec, &head, "test").unwrap();
    let mut lin = OrtEncoder::from_bytes(&bytes, 1).unwrap();
    assert_eq!(lin.dim, o);
    assert_eq!(lin.meta["telextiles.arch"], "wspec-c64-s32-bg+lin6");
    let y = lin.embed(&x[..3 * n * n]).unwrap();
    for (k, g) in y.iter().enumerate() {
        let want: f32 = (0..d)
            .map(|j| got[j] * head.scale[j] * head.w1[j * o + k])
            .sum::<f32>()
            + head.b1[k];
        assert!((g - want).abs() < 1e-3, "output {k}: {g} vs {want}");
    }
    // wspec is defined on frame minus reference only.
    let raw = DescriptorSpec {
        subtract: false,
        ..spec
    };
    assert!(descriptor_model(&raw).is_err());
}

/// `a − b` (HWC u8 images of side `n`) as planar `[3][n][n]` f64.
fn planar_diff(a: &[u8], b: &[u8], n: usize) -> Vec<f64> {
    let plane = n * n;
    let mut diff = vec![0f64; 3 * plane];
    for i in 0..plane {
        for c in 0..3 {
            diff[c * plane + i] = a[i * 3 + c] as f64 - b[i * 3 + c] as f64;
        }
    }
    diff
}

/// Runs `spec`'s graph on frame 0 − frame 1 and frame 2 − frame 0 of
/// `imgs` and checks it against the f64 reference with `window`;
/// returns the two inputs and the loaded graph.
fn wspec_matches_reference(
    spec: &DescriptorSpec,
    imgs: &[Vec<u8>],
    window: crate::wspec::Window,
) -> (Vec<f32>, OrtEncoder) {
    let n = spec.input as usize;
    let bytes = descriptor_model(spec).unwrap();
    let mut enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
    assert_eq!(enc.dim, crate::wspec::dim(n));
    let pairs = [(0, 1), (2, 0)];
    let mut x = Vec::new();
    for pair in pairs {
        crate::preprocess::input_into(&imgs[pair.0], Some(&imgs[pair.1]), n, &mut x);
    }
    let got = enc.embed(&x).unwrap();
    let d = spec.dim();
    for (k, pair) in pairs.into_iter().enumerate() {
        let diff = planar_diff(&imgs[pair.0], &imgs[pair.1], n);
        let want = crate::wspec::reference_tapered(&diff, n, window, spec.taper as f64 / 100.0);
        let err = got[k * d..(k + 1) * d]
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0f32, f32::max);
        assert!(err < 2e-3, "{}, frame {k}: max diff {err}", spec.arch());
    }
    (x, enc)
}

/// `wspec` of the 64-px crop at 32 px under a window of `taper` %.
fn wspec_64_to_32(taper: u32) -> DescriptorSpec {
    DescriptorSpec {
        kind: BaselineKind::WSpec,
        crop: 64,
        input: 32,
        subtract: true,
        min_bin: 1,
        taper,
    }
}

/// A Tukey window (`--taper 50`): the graph computes the f64 reference
/// under the same window, is named for it, differs from the Hann
/// window's, and is refused on the contact window and outside 1..=100.
#[test]
fn a_tapered_wspec_graph_computes_its_reference() {
    let n = 32;
    let spec = wspec_64_to_32(50);
    assert_eq!(spec.arch(), "wspec-c64-s32-t50-bg");
    let imgs = images(n, 3);
    let (x, mut enc) = wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Centre);
    assert_eq!(enc.meta["telextiles.arch"], "wspec-c64-s32-t50-bg");
    let tapered = enc.embed(&x).unwrap();
    let hann = DescriptorSpec { taper: 100, ..spec };
    let mut h = OrtEncoder::from_bytes(&descriptor_model(&hann).unwrap(), 1).unwrap();
    let plain = h.embed(&x).unwrap();
    let diff = tapered
        .iter()
        .zip(&plain)
        .map(|(a, b)| (a - b).abs())
        .fold(0f32, f32::max);
    assert!(diff > 1e-2, "the window changed nothing: {diff}");
    for (kind, taper) in [
        (BaselineKind::WSpecCw, 50),
        (BaselineKind::WSpec, 0),
        (BaselineKind::WSpec, 101),
    ] {
        let e = descriptor_model(&DescriptorSpec {
            kind,
            taper,
            ..spec
        })
        .unwrap_err();
        assert!(e.to_string().contains("taper"), "{e}");
    }
}

#[test]
fn the_contact_window_graph_computes_its_reference() {
    let n = 32;
    let spec = DescriptorSpec {
        kind: BaselineKind::WSpecCw,
        crop: 64,
        input: n as u32,
        subtract: true,
        min_bin: 1,
        taper: 100,
    };
    assert_eq!(spec.arch(), "wspec-cw-c64-s32-bg");
    // Whole-frame differences, and a contact in one corner (frame 0
    // differs from frame 1 only there), so the window moves far.
    let mut imgs = images(n, 3);
    wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Contact);
    let plane = n * n;
    for i in 0..plane {
        let (y, x) = (i / n, i % n);
        if y >= 10 || x >= 12 {
            for c in 0..3 {
                imgs[1][i * 3 + c] = imgs[0][i * 3 + c];
            }
        }
    }
    let (x, mut enc) = wspec_matches_reference(&spec, &imgs, crate::wspec::Window::Contact);
    let centred = crate::wspec::centred(&planar_diff(&imgs[0], &imgs[1], n), n);
    let (cy, cx) = crate::wspec::contact_centroid(&centred, n);
    assert!(cy < 9.0 && cx < 10.0, "centroid ({cy}, {cx})");
    // A blank difference: zeros, as with the centred window.
    assert!(enc.embed(&x).unwrap().iter().all(|v| v.is_finite()));
    let mut blank = Vec::new();
    crate::preprocess::input_into(&imgs[0], Some(&imgs[0]), n, &mut blank);
    assert!(enc.embed(&blank).unwrap().iter().all(|v| *v == 0.0));
}

#[test]
fn a_head_reads_back_and_rebuilds_the_same_bytes() {
    for (kind, crop, input, hidden) in [
        (BaselineKind::WSpec, 64, 32, 0),
        (BaselineKind::Fft, 32, 32, 4),
    ] {
        let spec = DescriptorSpec {
            kind,
            crop,
            input,
            subtract: true,
            min_bin: 1,
            taper: 100,
        };
        let (i, o) = (spec.dim(), 3);
        let first = if hidden == 0 { o } else { hidden };
        let v = |n: usize, k: usize| -> Vec<f32> {
            (0..n).map(|j| ((j * 7 + k) % 11) as f32 / 11.0).collect()
        };
        let head = MlpHead {
            scale: v(i, 1),
            w1: v(i * first, 2),
            b1: v(first, 3),
            w2: if hidden == 0 {
                Vec::new()
            } else {
                v(hidden * o, 4)
            },
            b2: if hidden == 0 { Vec::new() } else { v(o, 5) },
            input: i,
            hidden,
            out: o,
        };
        let bytes = descriptor_with_head(&spec, &head, "abc123").unwrap();
        let (back, hash) = read_head(&bytes).unwrap().expect("a head");
        assert_eq!(back, head);
        assert_eq!(hash, "abc123");
        assert_eq!(descriptor_with_head(&spec, &back, &hash).unwrap(), bytes);
    }
    // A descriptor without a head has none.
    let plain = descriptor_model(&DescriptorSpec {
        kind: BaselineKind::Fft,
        crop: 32,
        input: 32,
        subtract: true,
        min_bin: 1,
        taper: 100,
    })
    .unwrap();
    assert!(read_head(&plain).unwrap().is_none());
    assert!(read_head(b"not onnx").is_err());
}

#[test]
fn bad_specs_are_refused() {
    let spec = |kind, crop, input| DescriptorSpec {
        kind,
        crop,
        input,
        subtract: false,
        min_bin: 1,
        taper: 100,
    };
    let e = descriptor_model(&spec(BaselineKind::Fft, 64, 47)).unwrap_err();
    assert!(e.to_string().contains("even"), "{e}");
    assert!(descriptor_model(&spec(BaselineKind::Fft, 300, 64)).is_err());
    assert!(descriptor_model(&spec(BaselineKind::Lbp, 64, 64)).is_err());
    // Any even size works for the matrix DFT (the crop need not be a
    // power of two), and background subtraction is declared.
    let bytes = descriptor_model(&DescriptorSpec {
        subtract: true,
        min_bin: 1,
        ..spec(BaselineKind::Fft, 96, 96)
    })
    .unwrap();
    let enc = OrtEncoder::from_bytes(&bytes, 1).unwrap();
    assert_eq!(enc.dim, 47);
    assert_eq!(enc.meta["telextiles.background"], "subtract");
    assert_eq!(enc.meta["telextiles.arch"], "fft-radial-c96-bg");
}
