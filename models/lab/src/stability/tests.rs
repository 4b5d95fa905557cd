use super::*;
#[allow(unused_imports)]
use crate::decision_curve::*;
#[allow(unused_imports)]
use crate::stability_charts::*;

fn curve(factor: Factor, pts: &[(f64, f64)]) -> FactorCurve {
    FactorCurve {
        factor,
        levels: pts
            .iter()
            .map(|&(value, acc)| LevelScore {
                value,
                press_top1: acc,
                frame_top1: acc,
                flip_rate: 0.0,
                attr_rank_median: None,
                press_top1_centroid: None,
                press_top1_exemplars: None,
                presses: 10,
            })
            .collect(),
    }
}

#[test]
fn failure_points_read_the_curves_outward_from_nominal() {
    let rot = curve(
        Factor::Rotation,
        &[
            (0.0, 1.0),
            (15.0, 0.95),
            (30.0, 0.8),
            (330.0, 0.85),
            (345.0, 0.97),
        ],
    );
    // 330° is 30° the other way; the first failure outward is at 30°.
    assert_eq!(failure_point(&rot, 0.9), "30°");
    let force = curve(
        Factor::Force,
        &[
            (1.0, 0.5),
            (2.0, 0.92),
            (4.0, 1.0),
            (6.0, 0.95),
            (10.0, 0.91),
        ],
    );
    assert_eq!(failure_point(&force, 0.9), "≤ 1 N / -");
    let noise = curve(Factor::Noise, &[(0.0, 0.99), (4.0, 0.95), (8.0, 0.95)]);
    assert_eq!(failure_point(&noise, 0.9), "never");
    let bad = curve(Factor::Noise, &[(0.0, 0.5), (4.0, 0.4)]);
    assert!(failure_point(&bad, 0.9).starts_with("below at nominal"));
    let sensors = curve(Factor::SensorSwap, &[(0.0, 1.0), (1.0, 0.5), (2.0, 0.95)]);
    assert_eq!(failure_point(&sensors, 0.9), "1 of 3 units (1)");
}

#[test]
fn post_processing_changes_frames_as_described() {
    let sim = Simulator::new().unwrap();
    let spec = base_spec("T010", 1);
    let f = sim.render_frame(&spec, 60).unwrap();
    let mut same = f.clone();
    apply_post(&sim, &mut same, Post::Shift(0), 0, 1);
    assert_eq!(same, f, "a zero shift changes nothing");
    let mut g = f.clone();
    apply_post(&sim, &mut g, Post::Gain(1.0), 0, 1);
    assert_eq!(g, f);
    apply_post(&sim, &mut g, Post::Gain(0.5), 0, 1);
    let mean = |i: &RgbImage| i.iter().map(|&v| v as f64).sum::<f64>() / i.len() as f64;
    assert!((mean(&g) / mean(&f) - 0.5).abs() < 0.01);
    let mut n = f.clone();
    apply_post(&sim, &mut n, Post::Noise(8.0), 0, 1);
    let sd = (n
        .iter()
        .zip(f.iter())
        .map(|(&a, &b)| (a as f64 - b as f64).powi(2))
        .sum::<f64>()
        / f.len() as f64)
        .sqrt();
    assert!((6.0..10.0).contains(&sd), "noise sd {sd}");
    // A shifted background: the frame minus the old background plus the
    // shifted one; the contact signal (frame - background) is kept.
    let mut s = f.clone();
    apply_post(&sim, &mut s, Post::Shift(4), 0, 1);
    assert_ne!(s, f);
    let bg = sim.background(0);
    let (x, y) = (120, 160);
    let want = f.get_pixel(x, y)[0] as i32 - bg.get_pixel(x, y)[0] as i32
        + bg.get_pixel(x - 4, y - 4)[0] as i32;
    assert_eq!(s.get_pixel(x, y)[0] as i32, want.clamp(0, 255));
}

#[test]
fn coverage_indexes_grow_by_presses_and_the_first_two_are_the_suites_index() {
    // The plans: presses `first..end` of every textile, fresh seeds
    // from INDEX_SEED, the suite's conditions.
    let ts: Vec<String> = vec!["T001".into(), "T002".into()];
    let (plans, ks) = index_plans(&ts, 2, 5);
    assert_eq!(ks, vec![2, 3, 4, 2, 3, 4]);
    let seeds: Vec<u64> = plans.iter().map(|p| p.spec.seed).collect();
    assert_eq!(seeds, vec![7002, 7003, 7004, 7002, 7003, 7004]);
    assert_eq!(plans[3].class, 1);
    assert_eq!(plans[0].spec.textile, "T001");
    assert!(plans.iter().all(|p| p.spec.jig && p.spec.person == 0));
    // Sixteen presses of a catalogue-2 textile land on most of its 8
    // swatches: the index covers more of the bolt as it grows.
    let (sixteen, _) = index_plans(&ts[..1], 0, 16);
    let swatches: std::collections::BTreeSet<u32> = sixteen
        .iter()
        .map(|p| telextiles_sim::swatch_of(&p.spec))
        .collect();
    assert!(swatches.len() >= 5, "{swatches:?}");
    // An index's first k presses: only their rows, in order.
    let rows = [1.0, 0.0, 2.0, 0.0, 3.0, 0.0, 4.0, 0.0];
    let (index, labels, kept) = first_presses(&rows, &[0, 0, 1, 1], &[0, 1, 0, 1], 2, 1);
    assert_eq!(index, vec![1.0, 0.0, 3.0, 0.0]);
    assert_eq!(labels, vec![0, 1]);
    assert_eq!(kept, vec![0, 0]);
    assert_eq!(
        first_presses(&rows, &[0, 0, 1, 1], &[0, 1, 0, 1], 2, 2)
            .1
            .len(),
        4
    );
    // Exemplars: one normalised mean per press (label, number).
    let rows = [1.0, 0.0, 0.0, 1.0, 0.0, 2.0, 3.0, 0.0];
    let (x, xl) = press_exemplars(&rows, &[0, 0, 0, 1], &[0, 0, 1, 0], 2);
    let h = std::f32::consts::FRAC_1_SQRT_2;
    assert_eq!(xl, vec![0, 0, 1]);
    for (a, b) in x.iter().zip([h, h, 0.0, 1.0, 1.0, 0.0]) {
        assert!((a - b).abs() < 1e-6, "{x:?}");
    }

    // The suite: at two presses the coverage index is the suite's own,
    // so its jig queries score exactly as the nominal rotation.
    let sim = Simulator::with_options(2, 1).unwrap();
    let spec = crate::graph::DescriptorSpec {
        kind: crate::baselines::BaselineKind::Fft,
        crop: 64,
        input: 64,
        subtract: true,
        min_bin: 1,
        taper: 100,
    };
    let m = Method::onnx(spec.arch(), crate::graph::descriptor_model(&spec).unwrap()).unwrap();
    let cfg = SuiteConfig {
        textiles: Some(3),
        frames: 3,
        threads: 2,
        quick: true,
        factors: vec![Factor::Rotation, Factor::Coverage, Factor::CoverageHand],
        ..SuiteConfig::default()
    };
    let r = run_suite(&sim, &[m], &cfg, 1).unwrap();
    let curves = &r.methods[0].curves;
    let rot0 = &curves[0].levels[0];
    assert_eq!((curves[0].factor, rot0.value), (Factor::Rotation, 0.0));
    assert!(rot0.press_top1_centroid.is_none());
    for c in &curves[1..] {
        let values: Vec<f64> = c.levels.iter().map(|l| l.value).collect();
        assert_eq!(values, vec![1.0, 2.0, 4.0], "{:?}", c.factor);
        for l in &c.levels {
            assert_eq!(l.presses, 3);
            let cen = l.press_top1_centroid.expect("centroid figure");
            let ex = l.press_top1_exemplars.expect("exemplar figure");
            for x in [cen, ex, l.press_top1] {
                assert!((0.0..=1.0).contains(&x), "{l:?}");
            }
        }
    }
    let two = &curves[1].levels[1];
    assert_eq!(
        (two.press_top1, two.frame_top1, two.flip_rate),
        (rot0.press_top1, rot0.frame_top1, rot0.flip_rate)
    );
    assert!(failure_point(&curves[1], 0.9).contains("presses"));
    // Its chart: one line per method and index kind, in both panels.
    let dir = tempfile::tempdir().unwrap();
    let svg = dir.path().join("coverage.svg");
    let names = vec![r.methods[0].name.clone()];
    assert!(coverage_chart(&r, &names, &svg).unwrap());
    let text = std::fs::read_to_string(&svg).unwrap();
    assert!(text.starts_with("<svg"));
    for kind in [
        "nearest frame",
        "centroids (--sim)",
        "(--presses)",
        "hand-held",
    ] {
        assert!(text.contains(kind), "{kind}");
    }
    let none = StabilityReport {
        config: SuiteConfig {
            factors: vec![Factor::Rotation],
            ..cfg.clone()
        },
        ..r.clone()
    };
    assert!(!coverage_chart(&none, &names, &dir.path().join("no.svg")).unwrap());
    assert!(!dir.path().join("no.svg").exists());
    assert_eq!(Factor::parse("coverage").unwrap(), Factor::Coverage);
    assert_eq!(
        Factor::parse("coverage-hand").unwrap(),
        Factor::CoverageHand
    );
    assert_eq!(Factor::Coverage.nominal(), INDEX_PRESSES as f64);
    // The full suite asks three query presses of every textile.
    let full: Vec<u64> = (0..coverage_queries(false))
        .map(|j| {
            let p = level_plans_seeded(
                &sim,
                Factor::Coverage,
                0.0,
                &ts,
                &[],
                8,
                QUERY_SEED + 100 * j,
            );
            p.unwrap()[1].spec.seed
        })
        .collect();
    assert_eq!(full, vec![8000, 8100, 8200]);
}

#[test]
fn cloth_queries_press_the_index_swatch_at_a_moved_spot_or_another_swatch() {
    let sim = Simulator::with_options(2, 1).unwrap();
    let params = |spec: &PressSpec| sim.press_meta(spec).unwrap().params.unwrap();
    for t in ["T001", "T050", "T119"] {
        let first = params(&base_spec(t, INDEX_SEED));
        let second = params(&base_spec(t, INDEX_SEED + 1));
        for mm in [0.0, 4.0, 8.0] {
            let q = cloth_spec(&sim, Factor::Spot, mm, t, 8000).unwrap();
            let p = params(&q);
            assert_eq!(p.swatch, first.swatch, "{t} {mm}");
            assert_ne!(q.seed, INDEX_SEED, "a fresh press, not the index's");
            for a in 0..2 {
                let d = (p.offset_mm[a] - first.offset_mm[a]).abs();
                assert!((d - mm as f32).abs() < 1e-4, "{t} {mm}: {p:?}");
                assert!(p.offset_mm[a].abs() <= 8.0);
            }
            // The same press at every distance: only the spot moves.
            let q0 = cloth_spec(&sim, Factor::Spot, 0.0, t, 8000).unwrap();
            assert_eq!(q.seed, q0.seed);
        }
        let same = params(&cloth_spec(&sim, Factor::Swatch, 0.0, t, 8000).unwrap());
        let other = params(&cloth_spec(&sim, Factor::Swatch, 1.0, t, 8000).unwrap());
        assert_eq!(same.swatch, first.swatch);
        assert!(other.swatch != first.swatch && other.swatch != second.swatch);
    }
    // Catalogue 1 has no swatches: the factor is refused, by name.
    let v1 = Simulator::with_options(1, 1).unwrap();
    let cfg = SuiteConfig {
        textiles: Some(2),
        factors: vec![Factor::Swatch],
        quick: true,
        ..SuiteConfig::default()
    };
    let e = run_suite(&v1, &[], &cfg, 1).unwrap_err();
    assert!(format!("{e}").contains("catalogue 2"), "{e}");
    // A stretched index and the coverage indexes do not mix.
    let cfg = SuiteConfig {
        factors: vec![Factor::Coverage],
        index_stretch: 0.05,
        ..cfg
    };
    let e = run_suite(&v1, &[], &cfg, 1).unwrap_err();
    assert!(format!("{e}").contains("exclude each other"), "{e}");
    assert_eq!(Factor::parse("spot").unwrap(), Factor::Spot);
    assert_eq!(Factor::parse("swatch").unwrap(), Factor::Swatch);
}

#[test]
fn a_stretch_moves_the_cloth_and_keeps_the_reference() {
    let n = 240;
    let set_of = |px: Vec<u8>, sensor: u32| ImageSet {
        kind: ImageKind::Input,
        side: n,
        crop: n as u32,
        classes: vec!["A".into()],
        items: vec![FrameMeta {
            class: 0,
            press: 0,
            person: 0,
            sensor,
            jig: true,
            frame: 0,
        }],
        pixels: px,
        source: String::new(),
    };
    // A reference with structure, and a frame with one bright square
    // 40 px right of the centre.
    let bg: Vec<u8> = (0..n * n * 3).map(|i| (i % 97) as u8 + 40).collect();
    let mut img = bg.clone();
    for y in 118..122 {
        for x in 158..162 {
            for ch in 0..3 {
                img[(y * n + x) * 3 + ch] += 60;
            }
        }
    }
    let refs = set_of(bg.clone(), 3);
    let set = set_of(img.clone(), 3);
    // Stretch 1: the same image.
    assert_eq!(stretched(&set, &refs, 1.0, 1.0).unwrap().pixels, img);
    // Stretch 1.1 along x: the square's centre moves from 40 to 44 px
    // right of the centre, not along y; the reference stays where
    // there is no difference.
    let s = stretched(&set, &refs, 1.1, 1.0).unwrap();
    let diff =
        |p: &[u8], x: usize, y: usize| p[(y * n + x) * 3] as i32 - bg[(y * n + x) * 3] as i32;
    let mass = |p: &[u8]| {
        let (mut sx, mut sy, mut m) = (0.0, 0.0, 0.0);
        for y in 0..n {
            for x in 0..n {
                let d = diff(p, x, y).max(0) as f64;
                sx += d * x as f64;
                sy += d * y as f64;
                m += d;
            }
        }
        (sx / m, sy / m)
    };
    let (x0, y0) = mass(&img);
    let (x1, y1) = mass(&s.pixels);
    let c = (n as f64 - 1.0) / 2.0;
    assert!(((x1 - c) - 1.1 * (x0 - c)).abs() < 0.5, "{x0} -> {x1}");
    assert!((y1 - y0).abs() < 0.1, "{y0} -> {y1}");
    assert_eq!(diff(&s.pixels, 20, 20), 0);
    // Eight copies, none the identity; a bad stretch or a missing
    // reference is an error.
    let st = stretches(0.05);
    assert_eq!(st.len(), 8);
    assert!(!st.contains(&(1.0, 1.0)));
    assert!(stretched(&set, &refs, 0.0, 1.0).is_err());
    assert!(stretched(&set, &set_of(bg, 4), 1.1, 1.0).is_err());
}

#[test]
fn levels_start_from_the_nominal_conditions() {
    for f in Factor::ALL
        .into_iter()
        .chain([Factor::Spot, Factor::Swatch])
    {
        let full = f.levels(false);
        let quick = f.levels(true);
        assert!(!quick.is_empty() && quick.len() <= full.len());
        if f != Factor::HandHeld && f != Factor::Unseen {
            assert!(full.contains(&f.nominal()), "{f:?}");
        }
    }
    assert_eq!(Factor::Rotation.levels(false).len(), 24);
}
