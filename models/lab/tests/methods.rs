//! The speed/accuracy harness end to end on procedural frames (seconds):
//! the paper protocol's caches, three classical descriptors and an ONNX
//! encoder through ONNX Runtime on the same held-out presses, the table, the
//! Pareto frontier and both SVG charts. The figures themselves come from
//! `telextiles-lab methods` on simulated presses (docs/benchmarks.md).

use telextiles_lab::baselines::{Baseline, BaselineKind};
use telextiles_lab::methods::{self, Method, MethodResult};
use telextiles_lab::model::ArchConfig;
use telextiles_lab::onnx::{export_encoder, EncoderMeta};
use telextiles_lab::protocol::{self, Protocol, SourceKind};

#[test]
fn harness_scores_times_and_charts_every_method() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = Protocol::paper(32, 48);
    p.max_textiles = Some(8);
    let sets = protocol::load_or_build(&p, SourceKind::Synth, dir.path(), 2).unwrap();
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
        },
    )
    .unwrap();
    let mut list: Vec<Method> = [BaselineKind::Pixels, BaselineKind::Lbp, BaselineKind::Fft]
        .into_iter()
        .map(|kind| Method::Baseline(Baseline { kind, bgsub: false }))
        .collect();
    list.push(Method::Onnx("untrained".into(), bytes));
    let results: Vec<MethodResult> = list
        .iter()
        .map(|m| methods::evaluate(m, &sets.train_index, &sets.heldout, &[1, 2], 20).unwrap())
        .collect();
    let chance = 1.0 / 8.0;
    for r in &results {
        assert!((0.0..=1.0).contains(&r.frame_top1), "{r:?}");
        assert_eq!(r.presses, 8 * 3, "{r:?}");
        assert_eq!(r.queries, sets.heldout.len());
        assert_eq!(r.by_frames.last().unwrap().1, r.press_top1);
        assert!(r.latency.iter().all(|l| l.1 > 0.0 && l.2 >= l.1), "{r:?}");
    }
    // Encoders are timed with each thread count, descriptors once.
    assert_eq!(results[3].latency.len(), 2);
    assert_eq!(results[0].latency.len(), 1);
    // Textiles of the synthetic source differ by their gratings' periods:
    // the power spectrum sees that far above chance.
    assert!(results[2].press_top1 > 3.0 * chance, "{:?}", results[2]);
    let front = methods::pareto(&results);
    assert!(!front.is_empty());
    let table = methods::markdown(&results);
    assert_eq!(table.lines().count(), 2 + results.len(), "{table}");
    let (a, b) = (dir.path().join("a.svg"), dir.path().join("b.svg"));
    methods::charts(&results, &a, &b).unwrap();
    for f in [a, b] {
        let svg = std::fs::read_to_string(&f).unwrap();
        assert!(
            svg.starts_with("<svg") && svg.contains("untrained"),
            "{}",
            f.display()
        );
    }
    assert!(std::fs::read_to_string(dir.path().join("a.svg"))
        .unwrap()
        .contains("Pareto frontier"));
}

fn result(name: &str, ms: f64, acc: f64) -> MethodResult {
    MethodResult {
        name: name.into(),
        dim: 1,
        latency: vec![(1, ms, ms)],
        frame_top1: acc,
        press_top1: acc,
        by_frames: vec![(1, acc)],
        queries: 1,
        presses: 1,
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
