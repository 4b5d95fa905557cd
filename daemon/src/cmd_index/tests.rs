use super::*;
use crate::index_sim::sim_protocol;
use clap::Parser;
use telextiles_sim::Simulator;

/// `telextilesd index build`'s arguments alone.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    b: BuildArgs,
}

fn fixture_model() -> std::path::PathBuf {
    std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("sensing/tests/fixtures/fixture_encoder.onnx")
}

/// Rows of the report: (method, numbers).
fn rows(r: &str) -> Vec<(String, Vec<f32>)> {
    r.lines()
        .skip(2)
        .map(|l| {
            let mut w = l.split_whitespace();
            let m = w.next().unwrap().to_string();
            (m, w.filter_map(|x| x.parse().ok()).collect())
        })
        .collect()
}

/// The walk `index build --presses` and `index check` share names the
/// presses that touched less than half of the gel, with their coverage
/// as `classify` reports it; a press held flat is not named, and a long
/// list is cut after ten.
#[test]
fn partial_presses_are_named_with_their_coverage() {
    let dir = tempfile::tempdir().unwrap();
    let sim = Simulator::new().unwrap();
    for (name, tilt) in [("flat", 0.0), ("tilted", 5.0)] {
        let p = sim
            .render_press(&telextiles_sim::PressSpec {
                tilt_deg: Some([0.0, tilt]),
                ..telextiles_sim::PressSpec::new("T030", 4)
            })
            .unwrap();
        telextiles_recording::recording::write_press(&dir.path().join("T030").join(name), &p)
            .unwrap();
    }
    let enc = open_encoder(&fixture_model(), 1).unwrap();
    let mut fronts = [FrontEnd::new(enc, Default::default(), None)];
    let embedded = embed_recordings(
        &mut fronts,
        dir.path(),
        &References::none(),
        None,
        Sensors::default(),
        4,
        "test",
    )
    .unwrap();
    assert_eq!(embedded.presses, 2);
    assert_eq!(
        embedded.by_textile[0]["T030"].1.len(),
        2,
        "both presses kept"
    );
    assert_eq!(embedded.partial.len(), 1, "{:?}", embedded.partial);
    let (d, c) = &embedded.partial[0];
    assert!(
        d.ends_with("T030/tilted") && *c < PARTIAL_COVERAGE,
        "{d:?} {c}"
    );
    let note = partial_note(&embedded.partial, embedded.presses).unwrap();
    assert!(
        note.starts_with("note: 1 of 2 presses touched less than 50 % of the gel")
            && note.contains(&format!("tilted ({:.0} %)", 100.0 * c))
            && note.contains("press those fabrics again with the sensor flat"),
        "{note}"
    );
    assert!(partial_note(&[], 2).is_none());
    // The control socket's contact end event says "partial" at the same
    // coverage.
    assert_eq!(
        telextiles_control::format::PARTIAL_COVERAGE,
        PARTIAL_COVERAGE
    );
    let many: Vec<(PathBuf, f32)> = (0..12)
        .map(|k| (PathBuf::from(format!("p{k}")), 0.25))
        .collect();
    let note = partial_note(&many, 40).unwrap();
    assert!(
        note.contains("12 of 40 presses")
            && note.contains("p9 (25 %), and 2 more.")
            && !note.contains("p10"),
        "{note}"
    );
}

#[test]
fn simulated_index_presses_cover_every_person_on_every_sensor() {
    let parse = |args: &[&str]| {
        Cli::try_parse_from(
            ["index-build", "--model", "m.onnx", "--sim"]
                .iter()
                .chain(args),
        )
        .unwrap()
        .b
    };
    let cat = telextiles_sim::Catalogue::builtin();
    let a = parse(&["--people", "2", "--sensors", "0,3,5"]);
    assert_eq!(a.sensors, vec![0, 3, 5]);
    let p = sim_protocol(&sim_set(&a), Books::Training).unwrap();
    let specs: Vec<_> = p.specs(&cat).collect();
    assert_eq!(specs.len(), 119 * 2 * 3);
    let mut combos: Vec<(u32, u32)> = specs.iter().map(|s| (s.person, s.sensor)).collect();
    combos.sort_unstable();
    combos.dedup();
    assert_eq!(combos.len(), 6);
    assert!(specs.iter().all(|s| s.jig && s.textile.starts_with('T')));
    // The default: four units; unseen presses for coverage.
    assert_eq!(parse(&[]).sensors, vec![0, 1, 2, 3]);
    let d = parse(&["--sensors", "0"]);
    let u: Vec<_> = sim_protocol(&sim_set(&d), Books::Unseen)
        .unwrap()
        .specs(&cat)
        .collect();
    assert!(u
        .iter()
        .all(|s| s.textile.starts_with('U') && s.sensor == 0));
    let none = parse(&["--people", "0"]);
    assert!(sim_protocol(&sim_set(&none), Books::Both).is_err());
}

/// `index build --model m.onnx` with these arguments, parsed.
fn parse(args: &[&str]) -> BuildArgs {
    Cli::try_parse_from(["index-build", "--model", "m.onnx"].iter().chain(args))
        .unwrap()
        .b
}

/// `index build --model <model> --presses <rec> -o <out>` with more
/// flags, run, and the index it wrote read back.
fn build_presses(
    model: &std::path::Path,
    rec: &std::path::Path,
    out: &std::path::Path,
    flags: &[&str],
) -> Index {
    let args = [
        "index-build",
        "--model",
        model.to_str().unwrap(),
        "--presses",
        rec.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    build(Cli::try_parse_from(args.iter().chain(flags)).unwrap().b).unwrap();
    Index::read(out).unwrap()
}

/// Whether `index build --model m.onnx` refuses these arguments.
fn refused(args: &[&str]) -> bool {
    Cli::try_parse_from(["index-build", "--model", "m.onnx"].iter().chain(args)).is_err()
}

/// A feature that is on by default with --presses and off with --sim:
/// `--off` turns it off with --presses, `--on` on with --sim, and the
/// two together are refused.
fn on_with_presses_only(feature: fn(&BuildArgs) -> bool, on: &str, off: &str) {
    assert!(feature(&parse(&["--presses", "r"])), "{on}");
    assert!(!feature(&parse(&["--presses", "r", off])), "{off}");
    assert!(!feature(&parse(&["--sim"])), "{on}");
    assert!(feature(&parse(&["--sim", on])), "{on}");
    assert!(refused(&["--presses", "r", on, off]), "{on} {off}");
}

#[test]
fn own_recordings_fit_what_is_asked_and_plain_cosine_by_default() {
    // The default, for an owner's presses too: plain cosine, the
    // encoder alone (docs/studies/2026-12-04-fitted-metric.md);
    // --fit and --features choose; a shrinkage or --metric asks for
    // press means, as before fits on frames.
    let fit = |args: &[&str]| build_fit(&parse(args));
    assert_eq!(fit(&["--presses", "r"]), MetricFit::Cosine);
    assert_eq!(fit(&["--presses", "r", "--fit", "auto"]), MetricFit::Auto);
    assert_eq!(
        fit(&["--presses", "r", "--metric-shrinkage", "0.3"]),
        MetricFit::PressMeans(0.3)
    );
    assert_eq!(fit(&["--sim", "--metric"]), MetricFit::PressMeans(0.5));
    assert_eq!(fit(&["--sim"]), MetricFit::Cosine);
    assert_eq!(
        fit(&["--presses", "r", "--no-metric", "--fit", "frames"]),
        MetricFit::Cosine
    );
    assert_eq!(
        fit(&["--presses", "r", "--fit", "frames"]),
        MetricFit::Frames(None)
    );
    assert_eq!(
        fit(&[
            "--presses",
            "r",
            "--fit",
            "frames",
            "--metric-shrinkage",
            "0.2"
        ]),
        MetricFit::Frames(Some(0.2))
    );
    assert_eq!(
        fit(&["--presses", "r", "--fit", "cosine"]),
        MetricFit::Cosine
    );
    let features = |args: &[&str]| features_asked(parse(args).features, Some(Features::Encoder));
    assert_eq!(features(&["--presses", "r"]), Some(Features::Encoder));
    assert_eq!(features(&["--presses", "r", "--features", "auto"]), None);
    assert_eq!(
        features(&["--presses", "r", "--features", "lbp"]),
        Some(Features::EncoderLbp)
    );
    for bad in ["-0.1", "1.5", "x"] {
        assert!(refused(&["--metric-shrinkage", bad]), "{bad}");
    }
    // Every frame of an owner's presses; every 4th simulated one.
    assert_eq!(stride(&parse(&["--presses", "r"])), 1);
    assert_eq!(stride(&parse(&["--sim"])), 4);
    assert_eq!(stride(&parse(&["--presses", "r", "--stride", "3"])), 3);
}

/// What `index build` takes from one encoding with every feature is,
/// once normalised, what an encoder set to those features computes:
/// the vectors the index holds are the latents a live sender streams.
#[test]
fn every_kind_of_features_taken_from_one_encoding_is_what_the_encoder_computes() {
    let sim = Simulator::new().unwrap();
    let frame = sim
        .render_frame(&telextiles_sim::PressSpec::new("T030", 3), 100)
        .unwrap();
    let mut all = open_encoder(&fixture_model(), 1).unwrap();
    let dim = all.dim();
    all.set_features(Features::EncoderLbpGabor);
    let v = all.encode(&frame).unwrap().to_vec();
    let unit = |mut v: Vec<f32>| {
        let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
        v.iter_mut().for_each(|x| *x /= n);
        v
    };
    for want in Features::ALL {
        let mut enc = open_encoder(&fixture_model(), 1).unwrap();
        enc.set_features(want);
        let direct = enc.encode(&frame).unwrap().to_vec();
        let taken = unit(part_of(&v, want, Features::EncoderLbpGabor, dim));
        assert_eq!(taken.len(), direct.len(), "{want:?}");
        for (a, b) in taken.iter().zip(&direct) {
            assert!((a - b).abs() < 1e-5, "{want:?}: {a} against {b}");
        }
    }
}

#[test]
fn own_recordings_calibrate_the_unknown_distance_by_default() {
    on_with_presses_only(
        calibrate_unknown,
        "--calibrate-unknown",
        "--no-calibrate-unknown",
    );
    assert_eq!(
        parse(&["--presses", "r"]).unknown_quantile,
        telextiles_index::build::DEFAULT_UNKNOWN_QUANTILE
    );
    for bad in ["0", "1.5", "x"] {
        assert!(refused(&["--unknown-quantile", bad]), "{bad}");
    }
}

#[test]
fn own_recordings_keep_per_press_exemplars_by_default() {
    on_with_presses_only(keep_exemplars, "--exemplars", "--no-exemplars");
}

/// From a user's own recordings: the roller gets one slot per fabric
/// when there are fewer than 16 (no --slots needed), and the names
/// `record --name` stored are the index's names.
#[test]
fn own_recordings_default_slots_and_names() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let sim = Simulator::new().unwrap();
    for (id, name) in [("denim", Some("blue denim")), ("wool", None)] {
        for seed in [1, 2] {
            let mut p = sim
                .render_press(&telextiles_sim::PressSpec {
                    frames: 40,
                    ..telextiles_sim::PressSpec::new(
                        if id == "denim" { "T030" } else { "T110" },
                        seed,
                    )
                })
                .unwrap();
            p.meta.textile = id.into();
            telextiles_recording::recording::write_press(
                &rec.join(id).join(format!("{seed:04}")),
                &p,
            )
            .unwrap();
        }
        if let Some(n) = name {
            std::fs::write(
                rec.join(id).join("textile.json"),
                serde_json::json!({"id": id, "name": n}).to_string(),
            )
            .unwrap();
        }
    }
    // Another fabric's file does not name this one.
    std::fs::write(
        rec.join("wool/textile.json"),
        r#"{"id": "silk", "name": "silk"}"#,
    )
    .unwrap();
    let model = fixture_model();
    let build_with =
        |name: &str, flags: &[&str]| build_presses(&model, &rec, &dir.path().join(name), flags);
    let index = build_with("my.tlxi", &[]);
    assert_eq!(index.roller.n(), 2);
    let names: Vec<(&str, &str)> = index
        .entries
        .iter()
        .map(|e| (e.id.as_str(), e.name.as_str()))
        .collect();
    assert_eq!(names, [("denim", "blue denim"), ("wool", "wool")]);
    assert!(index.entries.iter().all(|e| e.exemplars.len() == 2));
    // The features and distance are chosen on the presses; asked for,
    // a distance is learned from the two presses of each fabric (every
    // frame of them), and every query method maps an embedding into
    // its space.
    let fitted = build_with("fitted.tlxi", &["--fit", "frames", "--features", "lbp"]);
    assert_eq!(fitted.features, Features::EncoderLbp);
    assert_eq!(fitted.dim, 64 + telextiles_index::LBP_DIM);
    let m = fitted.metric.as_ref().expect("two presses per fabric");
    assert_eq!((m.presses, m.fabrics), (4, 2));
    assert!(m.shrinkage > 0.0 && m.shrinkage <= 1.0, "{m:?}");
    let q = fitted
        .project(&vec![1.0 / (fitted.dim as f32).sqrt(); fitted.dim])
        .into_owned();
    assert!((q.iter().map(|x| x * x).sum::<f32>() - 1.0).abs() < 1e-4);
    let means = build_with(
        "means.tlxi",
        &["--metric-shrinkage", "0.5", "--features", "encoder"],
    );
    let m = means.metric.as_ref().expect("two presses per fabric");
    assert_eq!((m.presses, m.fabrics, m.shrinkage), (4, 2, 0.5));
    assert_eq!(means.features, Features::Encoder);
    // The unknown-textile distance is calibrated on the four presses,
    // each with its fold left out (one press of each fabric).
    let u = index.unknown.expect("four presses of two fabrics");
    assert_eq!(
        (u.quantile, u.presses),
        (telextiles_index::build::DEFAULT_UNKNOWN_QUANTILE, 4)
    );
    assert!(u.distance > 0.0 && u.distance <= 2.0, "{u:?}");
    // --no-metric: plain cosine; --no-calibrate-unknown: the fixed
    // distance.
    let plain = build_with("plain.tlxi", &["--no-metric", "--no-calibrate-unknown"]);
    assert!(plain.metric.is_none() && plain.unknown.is_none());
    assert_eq!(plain.entries.len(), 2);
    let q = build_with("q.tlxi", &["--unknown-quantile", "0.5"]);
    assert_eq!(q.unknown.unwrap().quantile, 0.5);
    assert!(q.unknown.unwrap().distance <= u.distance);
}

/// Catalogue-2 recordings take their names and attributes from
/// catalogue 2 with `--catalogue 2` (the same ids mean other fabrics
/// in catalogue 1), and the index says which catalogue it is of.
#[test]
fn catalogue_2_presses_are_labelled_from_catalogue_2() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("rec");
    let sim = Simulator::with_options(2, 1).unwrap();
    for id in ["T001", "T002"] {
        let p = sim
            .render_press(&telextiles_sim::PressSpec {
                frames: 40,
                ..telextiles_sim::PressSpec::new(id, 1)
            })
            .unwrap();
        telextiles_recording::recording::write_press(&rec.join(id).join("0001"), &p).unwrap();
    }
    let model = fixture_model();
    let build_with = |extra: &[&str]| {
        let out = dir.path().join(format!("i{}.tlxi", extra.len()));
        build_presses(&model, &rec, &out, extra)
    };
    let v2 = build_with(&["--catalogue", "2"]);
    let v1 = build_with(&[]);
    assert_eq!(v2.catalogue_version, 2);
    assert_eq!(v1.catalogue_version, 1);
    for (cat, index) in [(2, &v2), (1, &v1)] {
        let c = telextiles_sim::Catalogue::version(cat).unwrap();
        for e in &index.entries {
            let t = c.get(&e.id).unwrap();
            assert_eq!(e.name, t.name);
            let got: Vec<f32> = e.attributes.iter().map(|a| a.1).collect();
            assert_eq!(got, t.attributes.to_vec(), "{} in catalogue {cat}", e.id);
        }
    }
    assert_ne!(v1.entries[0].attributes, v2.entries[0].attributes);
    // --sim renders catalogue 2: every training textile, labelled
    // from it.
    let out = dir.path().join("sim.tlxi");
    build(
        Cli::try_parse_from([
            "index-build",
            "--model",
            model.to_str().unwrap(),
            "--sim",
            "--catalogue",
            "2",
            "--people",
            "1",
            "--sensors",
            "0",
            "--stride",
            "16",
            "-o",
            out.to_str().unwrap(),
        ])
        .unwrap()
        .b,
    )
    .unwrap();
    let sim_index = Index::read(&out).unwrap();
    assert_eq!(sim_index.catalogue_version, 2);
    let c2 = telextiles_sim::Catalogue::version(2).unwrap();
    assert_eq!(sim_index.entries.len(), c2.training().count());
    let e = &sim_index.entries[0];
    assert_eq!(e.name, c2.get(&e.id).unwrap().name);
    assert!(Cli::try_parse_from(["x", "--model", "m", "--sim", "--catalogue", "3"]).is_err());
}

#[test]
fn index_check_keeps_the_model_in_use_unless_another_is_ahead_on_the_same_presses() {
    let check = |right| SelfCheck {
        presses: 71,
        right,
        confusions: Vec::new(),
    };
    let pair = |first_only, second_only| {
        Some(Paired {
            presses: 71,
            first_only,
            second_only,
        })
    };
    // One model: itself.
    assert_eq!(choose_model(&[check(60)], &[None]), 0);
    // Ahead by 4 presses of 71 with none the other way: switch; by 3:
    // keep.
    assert_eq!(
        choose_model(&[check(60), check(64)], &[None, pair(0, 4)]),
        1
    );
    assert_eq!(
        choose_model(&[check(60), check(63)], &[None, pair(0, 3)]),
        0
    );
    // Of two that are ahead, the one right most often; one behind is
    // never chosen for its share alone.
    let checks = [check(50), check(60), check(70), check(71)];
    let paired = [None, pair(0, 10), pair(0, 20), pair(30, 51)];
    assert_eq!(choose_model(&checks, &paired), 3);
    let paired = [None, pair(0, 10), pair(0, 20), pair(30, 31)];
    assert_eq!(choose_model(&checks, &paired), 2);
    // Parsed: --model is required and repeatable, and takes
    // build's options for the distance and the exemplars.
    #[derive(clap::Parser)]
    struct CheckCli {
        #[command(flatten)]
        c: CheckArgs,
    }
    let a = CheckCli::try_parse_from([
        "index-check",
        "--presses",
        "r",
        "--model",
        "a.onnx",
        "--model",
        "b.onnx",
        "--no-metric",
    ])
    .unwrap()
    .c;
    assert_eq!(a.models.len(), 2);
    assert!(a.no_metric && !a.no_exemplars);
    assert!(CheckCli::try_parse_from(["index-check", "--presses", "r"]).is_err());
}

#[test]
fn coverage_report_covers_every_method_and_beats_random() {
    let index = telextiles_map::demo::catalogue_index(Some(60), 8, 3).unwrap();
    let unseen: Vec<Vec<f32>> = index.entries[..10]
        .iter()
        .map(|e| e.centroid.clone())
        .collect();
    let r = coverage_report(&index, &unseen, 8, 0);
    let rows = rows(&r);
    assert_eq!(rows.len(), 4, "{r}");
    for (m, v) in &rows {
        assert_eq!(v.len(), 4, "{m}: {r}");
        assert!(v[0] <= v[1] && v[2] <= v[3], "mean <= max: {r}");
        assert!(v.iter().all(|x| x.is_finite() && *x >= 0.0), "{r}");
    }
    let get = |name: &str| rows.iter().find(|(m, _)| m == name).unwrap().1.clone();
    let random = get("random");
    // The coverage-optimal methods are no worse than random choice.
    assert!(get("kmedoids")[0] <= random[0], "{r}");
    assert!(get("farthest")[1] <= random[1], "{r}");
    // Without unseen presses their columns say so.
    let r2 = coverage_report(&index, &[], 8, 0);
    assert!(r2.lines().nth(2).unwrap().trim_end().ends_with('-'), "{r2}");
}

#[test]
fn presses_of_two_sensor_profiles_make_an_index_only_when_mixed_on_purpose() {
    let dir = tempfile::tempdir().unwrap();
    let frame = telextiles_sensing::frame::Frame::blank().into_image();
    let meta = |profile: Option<&str>| telextiles_recording::PressMeta {
        textile: "T001".into(),
        person: 0,
        sensor: 0,
        jig: false,
        fps: 25.0,
        timestamps_us: vec![0],
        seed: None,
        source: "test".into(),
        sensor_serial: None,
        params: None,
        reference_frames: None,
        mm_per_px: profile.map(|_| 0.08),
        sensor_profile: profile.map(str::to_string),
    };
    let write = |name: &str, profile: Option<&str>| {
        telextiles_recording::recording::write_press(
            &dir.path().join(name),
            &telextiles_recording::Press {
                meta: meta(profile),
                frames: vec![frame.clone()],
            },
        )
        .unwrap();
    };
    write("T001/0001", Some("gelsight-mini"));
    let found =
        |root: &std::path::Path| telextiles_recording::recording::find_recordings(root).unwrap();
    // One sensor: the index says which (a DIGIT's says nothing).
    assert_eq!(
        sensor_of(&found(dir.path()), false).unwrap().as_deref(),
        Some("gelsight-mini")
    );
    write("T002/0001", None);
    assert_eq!(
        sensor_of(&found(&dir.path().join("T002")), false).unwrap(),
        None
    );
    // Two: refused, naming each with a press, unless mixed.
    let e = sensor_of(&found(dir.path()), false)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("2 sensor profiles")
            && e.contains("digit (e.g.")
            && e.contains("T002/0001")
            && e.contains("gelsight-mini (e.g.")
            && e.contains("--mix-sensors"),
        "{e}"
    );
    assert_eq!(
        sensor_of(&found(dir.path()), true).unwrap().as_deref(),
        Some("mixed:digit+gelsight-mini")
    );
}
