//! `telextiles-lab bench` end to end on a few simulated textiles (the reduced
//! run CI does; the committed figures come from the full run, see
//! docs/benchmarks.md): frame caches, every classical descriptor and an
//! encoder, Pareto frontier and knee, time to decision, the stability suite
//! (two levels per factor), the user test, and every output file.

use telextiles_lab::methods::Method;
use telextiles_lab::model::ArchConfig;
use telextiles_lab::onnx::{export_encoder, EncoderMeta};
use telextiles_lab::protocol::{Protocol, SourceKind};
use telextiles_lab::report::{self, BenchConfig};
use telextiles_lab::stability::{Factor, SuiteConfig};

#[test]
fn the_bench_runs_end_to_end_on_simulated_presses() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut p = Protocol::paper(64, 64);
    p.max_textiles = Some(3);
    let arch = ArchConfig {
        blocks: [1, 1, 1, 1],
        width: 4,
        input: 32,
        embed_dim: Some(8),
    };
    let enc = arch.init_encoder(&burn::tensor::Device::flex());
    let bytes = export_encoder(
        &enc,
        &EncoderMeta {
            arch,
            crop: 32,
            train_data_hash: "untrained".into(),
            subtract: false,
        },
    )
    .unwrap();
    let mut methods = report::descriptor_methods().unwrap();
    methods.push(Method::onnx("tiny-encoder", bytes).unwrap());
    let cfg = BenchConfig {
        source: SourceKind::Sim,
        protocol: p,
        cache_dir: dir.path().join("cache"),
        threads: 2,
        models: vec![],
        time_threads: vec![1, 2],
        runs: 5,
        stability: Some(SuiteConfig {
            textiles: Some(3),
            frames: 3,
            threads: 2,
            quick: true,
            ..SuiteConfig::default()
        }),
        decision_frames: 4,
        roller: vec!["T001".into(), "T002".into()],
        cross_generator: false,
        out: out.clone(),
    };
    let r = report::run(&cfg, &methods).unwrap();
    assert_eq!(r.methods.len(), methods.len());
    let knee = r.knee.clone().expect("a knee");
    assert!(r.pareto.contains(&knee), "{:?} {knee}", r.pareto);
    // Three textiles: the power spectrum tells them apart across people
    // well above chance (1/3).
    let fft = r
        .methods
        .iter()
        .find(|m| m.name == "fft-radial-c64")
        .unwrap();
    assert!(fft.press_top1 > 0.5, "{fft:?}");
    // Time to decision: one curve per method, `decision_frames` long.
    assert_eq!(r.decision.len(), methods.len());
    assert!(r.decision.iter().all(|d| d.top1.len() == 4));
    // Stability: every factor, two levels (one for unseen), every method;
    // at the nominal conditions the power spectrum is right on 3 textiles.
    let st = r.stability.as_ref().unwrap();
    assert_eq!(st.methods.len(), methods.len());
    for m in &st.methods {
        assert_eq!(m.curves.len(), Factor::ALL.len());
        for c in &m.curves {
            let want = c.factor.levels(true).len();
            assert!(want >= 1);
            assert_eq!(c.levels.len(), want, "{} {:?}", m.name, c.factor);
            for l in &c.levels {
                assert!((0.0..=1.0).contains(&l.press_top1) && (0.0..=1.0).contains(&l.flip_rate));
                let presses = if c.factor == Factor::Unseen { 20 } else { 3 };
                assert_eq!(l.presses, presses, "{} {:?}", m.name, c.factor);
            }
        }
    }
    let fft_st = st
        .methods
        .iter()
        .find(|m| m.name == "fft-radial-c64")
        .unwrap();
    let nominal = &fft_st.curves[0].levels[0];
    assert_eq!(nominal.value, 0.0);
    assert!(nominal.press_top1 > 0.6, "{nominal:?}");
    let unseen = fft_st
        .curves
        .iter()
        .find(|c| c.factor == Factor::Unseen)
        .unwrap();
    assert!(unseen.levels[0].attr_rank_median.is_some());
    // User test: seen trials are the held-out presses of the textiles not
    // on the roller (1 textile x 3 people), unseen ones 20 x 3.
    assert_eq!(r.usertest.len(), methods.len());
    for u in &r.usertest {
        assert_eq!(u.seen.trials, 3, "{}", u.name);
        assert_eq!(u.unseen.trials, 60, "{}", u.name);
        assert_eq!(u.seen.topk_agreement.len(), 2);
        assert_eq!(u.unseen.top1_in_topk[1], 1.0);
    }
    for f in [
        "bench.json",
        "report.md",
        "speed-accuracy.svg",
        "decision-time.svg",
        "stability-accuracy.svg",
        "stability-flips.svg",
        "usertest.svg",
    ] {
        let s = std::fs::read_to_string(out.join(f)).unwrap_or_else(|e| panic!("{f}: {e}"));
        assert!(s.len() > 200, "{f}");
        if f.ends_with(".svg") {
            assert!(s.starts_with("<svg"), "{f}");
        }
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for section in [
        "## Methods",
        "**knee**",
        "## Accuracy against time since first contact",
        "## Stability",
        "## The paper's user test",
    ] {
        assert!(md.contains(section), "report.md lacks {section}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap();
    assert_eq!(json["knee"], serde_json::Value::String(knee));
}

/// A bench of accuracy per group only (no stability suite, decision
/// curve or user test; 3 timed runs), writing under `dir`.
fn accuracy_only(protocol: Protocol, dir: &std::path::Path) -> BenchConfig {
    BenchConfig {
        source: SourceKind::Sim,
        protocol,
        cache_dir: dir.join("cache"),
        threads: 2,
        models: vec![],
        time_threads: vec![1],
        runs: 3,
        stability: None,
        decision_frames: 0,
        roller: vec![],
        cross_generator: false,
        out: dir.join("out"),
    }
}

/// Catalogue 2 (issue 18): the bench renders v2 caches (their own cache
/// directory, v1's untouched), scores every method per group of queries
/// (held-out people on training units, on held-out units, hand-held) and
/// on the cross-generator set rendered by the other texture generator.
#[test]
fn the_bench_reports_catalogue_2_by_group_and_across_generators() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    let mut p = Protocol::paper(64, 64);
    p.max_textiles = Some(3);
    p.catalogue = 2;
    let methods: Vec<Method> = report::descriptor_methods()
        .unwrap()
        .into_iter()
        .filter(|m| ["fft-radial-c64-bg", "pixels16-c64"].contains(&m.name().as_str()))
        .collect();
    assert_eq!(methods.len(), 2);
    let cfg = BenchConfig {
        cross_generator: true,
        ..accuracy_only(p.clone(), dir.path())
    };
    let r = report::run(&cfg, &methods).unwrap();
    assert_eq!(r.source, "sim, catalogue 2");
    assert_eq!(r.cross_generator.len(), 2);
    for m in r.methods.iter().chain(&r.cross_generator) {
        let names: Vec<&str> = m.groups.iter().map(|g| g.name.as_str()).collect();
        assert_eq!(
            names,
            [
                "held-out people, training units",
                "held-out people, held-out units",
                "hand-held queries, jig index"
            ],
            "{}",
            m.name
        );
        // 3 textiles: person 8 on unit 0; persons 9, 10 on units 4, 5;
        // person 8 hand-held.
        let presses: Vec<usize> = m.groups.iter().map(|g| g.presses).collect();
        assert_eq!(presses, [3, 6, 3], "{}", m.name);
        for g in &m.groups {
            assert!((0.0..=1.0).contains(&g.press_top1), "{g:?}");
        }
    }
    // Two cache directories: generator 1 and generator 2 render different
    // frames of the same protocol.
    let caches: Vec<_> = std::fs::read_dir(dir.path().join("cache"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    assert_eq!(caches.len(), 2, "{caches:?}");
    let a = std::fs::read(caches[0].join("heldout.bin")).unwrap();
    let b = std::fs::read(caches[1].join("heldout.bin")).unwrap();
    assert_ne!(a, b);
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("cross-generator (all held-out)"), "{md}");
    assert!(md.contains("held-out people, held-out units"), "{md}");
    // Generator 2 without catalogue 2 is refused with a clear error.
    let mut bad = cfg.clone();
    bad.protocol.catalogue = 1;
    let e = report::run(&bad, &methods).unwrap_err();
    assert!(format!("{e:#}").contains("--catalogue 2"), "{e:#}");
}

/// Version-1 caches keep their names: the new protocol fields stay out of
/// the cache key at their defaults.
#[test]
fn catalogue_1_protocol_serialises_as_before() {
    let p = Protocol::paper(64, 168);
    let j = serde_json::to_string(&p).unwrap();
    assert!(!j.contains("catalogue") && !j.contains("generator"), "{j}");
    let mut p2 = p.clone();
    p2.catalogue = 2;
    let j2 = serde_json::to_string(&p2).unwrap();
    assert!(j2.contains("\"catalogue\":2"), "{j2}");
    let back: Protocol = serde_json::from_str(&j).unwrap();
    assert_eq!(back, p);
}

/// More held-out people (`--heldout-people`) give every group of the study
/// more presses (persons 8, 9, 10, 11, ... on units 0, 4, 5 in turn;
/// hand-held presses by those on the training unit), while the paper's
/// three stay the default with the same cache key.
#[test]
fn more_heldout_people_enlarge_every_group() {
    let paper = Protocol::paper(64, 64);
    assert_eq!(paper.with_heldout_people(3), paper);
    assert_eq!(paper.handheld_people(), [(8, 0)]);
    let six = paper.with_heldout_people(6);
    assert_eq!(
        six.heldout,
        [(8, 0), (9, 4), (10, 5), (11, 0), (12, 4), (13, 5)]
    );
    assert_eq!(six.handheld_people(), [(8, 0), (11, 0)]);
    assert_ne!(
        serde_json::to_string(&six).unwrap(),
        serde_json::to_string(&paper).unwrap()
    );

    let dir = tempfile::tempdir().unwrap();
    let mut p = six;
    p.max_textiles = Some(2);
    p.catalogue = 2;
    let methods: Vec<Method> = report::descriptor_methods()
        .unwrap()
        .into_iter()
        .filter(|m| m.name() == "fft-radial-c64-bg")
        .collect();
    let cfg = accuracy_only(p, dir.path());
    let r = report::run(&cfg, &methods).unwrap();
    let m = &r.methods[0];
    // 2 textiles: persons 8 and 11 on unit 0; 9, 10, 12, 13 on units 4, 5;
    // 8 and 11 hand-held.
    let presses: Vec<usize> = m.groups.iter().map(|g| g.presses).collect();
    assert_eq!(presses, [4, 8, 4]);
    assert_eq!(m.presses, 12);
}
