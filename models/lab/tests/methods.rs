//! The speed/accuracy harness on procedural frames (seconds): the protocol's
//! base caches cut into each method's view, the classical descriptors (ONNX
//! graphs and Rust) and an encoder through ONNX Runtime on the same held-out
//! presses, the table, the Pareto frontier, its knee and the chart. The
//! figures themselves come from `telextiles-lab bench` on simulated presses
//! (docs/benchmarks.md); `tests/bench.rs` runs that end to end.

use telextiles_lab::methods::{self, Method, MethodResult, Views};
use telextiles_lab::model::ArchConfig;
use telextiles_lab::onnx::{export_encoder, EncoderMeta};
use telextiles_lab::protocol::{self, view_set, Protocol, SourceKind};
use telextiles_lab::report::descriptor_methods;

#[test]
fn harness_scores_times_and_charts_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = Protocol::paper(32, 48);
    p.max_textiles = Some(8);
    let sets = protocol::load_base(&p, SourceKind::Synth, dir.path(), 2).unwrap();
    assert_eq!(sets.heldout.side, 240);
    // The synthetic source has a flat reference for every sensor.
    assert!(sets.background(4).is_some());
    let arch = ArchConfig {
        blocks: [1, 1, 1, 1],
        width: 4,
        input: 32,
        embed_dim: Some(16),
    };
    let enc = arch.init_encoder(&burn::tensor::Device::flex());
    let bytes = export_encoder(
        &enc,
        &EncoderMeta {
            arch: arch.clone(),
            crop: 48,
            train_data_hash: "untrained".into(),
            subtract: false,
        },
    )
    .unwrap();
    let mut list = descriptor_methods().unwrap();
    list.push(Method::onnx("untrained", bytes).unwrap());
    assert_eq!(list.last().unwrap().view(), (48, 32));
    let mut views = Views::new(&sets);
    let results: Vec<MethodResult> = list
        .iter()
        .map(|m| methods::evaluate(m, &mut views, &[1, 2], 20).unwrap())
        .collect();
    let chance = 1.0 / 8.0;
    for (r, m) in results.iter().zip(&list) {
        assert!((0.0..=1.0).contains(&r.frame_top1), "{r:?}");
        assert_eq!(r.presses, 8 * 3, "{r:?}");
        assert_eq!(r.queries, sets.heldout.len());
        assert_eq!(r.by_frames.last().unwrap().1, r.press_top1);
        assert!(r.latency.iter().all(|l| l.1 > 0.0 && l.2 >= l.1), "{r:?}");
        assert_eq!(r.nonfinite_frames, 0, "{r:?}");
        // ONNX models are timed with each thread count, Rust descriptors once.
        assert_eq!(r.latency.len(), if m.runtime() == "ort" { 2 } else { 1 });
        assert_eq!((r.crop, r.input), m.view());
    }
    // Textiles of the synthetic source differ by their gratings' periods:
    // the power spectrum sees that far above chance.
    let fft = results.iter().find(|r| r.name == "fft-radial-c64").unwrap();
    assert!(fft.press_top1 > 3.0 * chance, "{fft:?}");
    // Decided as the daemon decides (textile centroids) too, every group.
    assert!(fft.press_top1_centroid > 3.0 * chance, "{fft:?}");
    for r in &results {
        assert!((0.0..=1.0).contains(&r.press_top1_centroid), "{r:?}");
        for g in &r.groups {
            assert!((0.0..=1.0).contains(&g.press_top1_centroid), "{g:?}");
        }
    }
    let front = methods::pareto(&results);
    assert!(!front.is_empty());
    let knee = methods::knee(&results).unwrap();
    assert!(front.contains(&knee));
    let table = methods::markdown(&results);
    assert_eq!(table.lines().count(), 2 + results.len(), "{table}");
    assert_eq!(table.matches("**knee**").count(), 1, "{table}");
    // Both decisions of every press are reported, each under its heading.
    let groups = telextiles_lab::report::groups_markdown(&results, &[]);
    let (knn, centroid) = groups
        .split_once("nearest textile centroid")
        .unwrap_or_else(|| panic!("{groups}"));
    let pct = |x: f64| format!("{:.1}%", 100.0 * x);
    assert!(
        knn.contains(&format!("| fft-radial-c64 | {} |", pct(fft.press_top1))),
        "{groups}"
    );
    assert!(
        centroid.contains(&format!(
            "| fft-radial-c64 | {} |",
            pct(fft.press_top1_centroid)
        )),
        "{groups}"
    );
    let svg_path = dir.path().join("a.svg");
    methods::chart(&results, &svg_path).unwrap();
    let svg = std::fs::read_to_string(&svg_path).unwrap();
    assert!(svg.starts_with("<svg") && svg.contains("untrained"));
    assert!(svg.contains("Pareto frontier") && svg.contains("knee"));
}

#[test]
fn views_cut_from_the_base_cache_equal_the_direct_crop() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = Protocol::paper(32, 48);
    p.max_textiles = Some(2);
    let base = protocol::load_base(&p, SourceKind::Synth, dir.path(), 2).unwrap();
    // Render the same frames directly at (input 32, crop 48) with the
    // pre-base-cache path: centre crop of the 240x320 frame, resize.
    use telextiles_lab::data::FrameSource;
    let src = telextiles_lab::synth::SynthSource;
    let view = view_set(&base.heldout, 48, 32).unwrap();
    for i in [0, 5, view.len() - 1] {
        let m = &view.items[i];
        let key = telextiles_lab::data::PressKey {
            textile: view.classes[m.class as usize].clone(),
            person: m.person,
            sensor: m.sensor,
            jig: m.jig,
            seed: 2000 + m.person as u64,
        };
        // The synthetic source draws per-frame jitter in request order:
        // ask for the press's cached frames, as the cache did.
        let rows: Vec<usize> = (0..view.len())
            .filter(|&j| view.items[j].press == m.press)
            .collect();
        let frames: Vec<usize> = rows.iter().map(|&j| view.items[j].frame as usize).collect();
        let rendered = src.frames(&key, &frames).unwrap();
        for (&j, frame) in rows.iter().zip(&rendered) {
            let direct = telextiles_lab::preprocess::centre_crop_resize(frame, 48, 32).unwrap();
            assert_eq!(view.image(j), direct.as_raw().as_slice(), "image {j}");
        }
    }
    // The training canvases keep their side and record the crop, so the
    // training-data hash is what it was before the base cache.
    let sets = base.into_view(48, 32).unwrap();
    assert_eq!((sets.train.side, sets.train.crop), (240, 48));
    assert_eq!(sets.heldout.side, 32);
    assert!(view_set(&sets.heldout, 64, 32).is_err());
}

#[test]
fn centroids_are_the_normalised_means_and_can_disagree_with_the_nearest_frame() {
    let at = |deg: f32| [deg.to_radians().cos(), deg.to_radians().sin()];
    // Textile 0: frames at ±20° (centroid at 0°); textile 1: frames at 50°
    // and 170° (centroid at 110°).
    let index: Vec<f32> = [20.0, -20.0, 50.0, 170.0]
        .into_iter()
        .flat_map(at)
        .collect();
    let labels = [0, 0, 1, 1];
    let (c, l) = methods::centroids(&index, &labels, 2);
    assert_eq!(l, vec![0, 1]);
    let close =
        |got: &[f32], want: [f32; 2]| got.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-5);
    assert!(close(&c[..2], at(0.0)), "{c:?}");
    assert!(close(&c[2..], at(110.0)), "{c:?}");
    // A query at 40° is nearest textile 1's frame at 50°, and nearest
    // textile 0's centroid.
    let q = at(40.0);
    assert_eq!(methods::top1(&index, &labels, &q, &[0], 2), 0.0);
    assert_eq!(methods::top1(&c, &l, &q, &[0], 2), 1.0);
}

fn result(name: &str, ms: f64, acc: f64) -> MethodResult {
    MethodResult {
        name: name.into(),
        runtime: "ort".into(),
        crop: 64,
        input: 64,
        dim: 1,
        model_bytes: None,
        latency: vec![(1, ms, ms)],
        frame_top1: acc,
        press_top1: acc,
        press_top1_centroid: acc,
        by_frames: vec![(1, acc)],
        queries: 1,
        presses: 1,
        nonfinite_frames: 0,
        groups: Vec::new(),
    }
}

#[test]
fn pareto_keeps_only_methods_nothing_beats() {
    let r = [
        result("fast-poor", 0.1, 0.2),
        result("slow-good", 10.0, 0.9),
        result("dominated", 5.0, 0.1),
        result("middle", 1.0, 0.5),
        result("tie-slower", 1.5, 0.5),
    ];
    assert_eq!(methods::pareto(&r), vec![0, 1, 3]);
}

#[test]
fn the_knee_is_where_accuracy_stops_coming_cheaply() {
    // Most of the accuracy by 0.1 ms; 10 ms more buys 8 points, less than
    // the 60 % of the frame budget they cost.
    let r = [
        result("a", 0.01, 0.10),
        result("b", 0.1, 0.70),
        result("c", 1.0, 0.75),
        result("d", 10.0, 0.78),
    ];
    assert_eq!(methods::knee(&r), Some(1));
    // 4 ms (24 % of the budget) for 2 points: not worth it; 0.9 ms (5 %)
    // for 20 points: worth it.
    let r1 = [
        result("a", 0.1, 0.70),
        result("b", 1.0, 0.90),
        result("c", 5.0, 0.92),
    ];
    assert_eq!(methods::knee(&r1), Some(1));
    // Over the 16.7 ms budget does not count, however accurate.
    let r2 = [
        result("a", 0.01, 0.10),
        result("b", 0.1, 0.70),
        result("huge", 40.0, 0.99),
    ];
    assert_eq!(methods::knee(&r2), Some(1));
    // Dominated methods are never the knee.
    let r3 = [
        result("a", 0.01, 0.10),
        result("dominated", 0.2, 0.05),
        result("c", 1.0, 0.90),
    ];
    assert_eq!(methods::knee(&r3), Some(2));
    assert_eq!(methods::knee(&[]), None);
}
