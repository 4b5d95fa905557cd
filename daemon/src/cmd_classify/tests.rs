use super::*;
use std::path::Path;
use telextiles_index::{IndexBuilder, TextileRecord};
use telextiles_sensing::encoder::file_sha256;
use telextiles_session::MotionPolicy;
use telextiles_sim::Simulator;

const TEXTILES: [&str; 4] = ["T010", "T030", "T080", "T110"];

fn fixture_model() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("sensing/tests/fixtures/fixture_encoder.onnx")
}

/// An index of a few textiles built from one simulated press each (seed 1).
fn index_file(dir: &Path) -> PathBuf {
    let model = fixture_model();
    let sim = Simulator::new().unwrap();
    let mut enc = Encoder::open(&model, &EncoderOptions::default()).unwrap();
    let mut b = IndexBuilder::new(
        &file_sha256(&model).unwrap(),
        &enc.info().arch,
        enc.dim(),
        0,
    );
    b.roller_n = 4;
    for id in TEXTILES {
        let p = sim.render_press(&PressSpec::new(id, 1)).unwrap();
        // Every frame from first contact on, as `index build` takes
        // a press.
        let contact = p.meta.params.as_ref().unwrap().contact_frame as usize;
        let embeddings = p.frames[contact..]
            .iter()
            .map(|f| enc.encode(f).unwrap().to_vec())
            .collect();
        b.add(TextileRecord {
            id: id.into(),
            name: format!("textile {id}"),
            seen: true,
            structure: String::new(),
            attributes: Vec::new(),
            embeddings,
            exemplars: Vec::new(),
            press_frames: Vec::new(),
        })
        .unwrap();
    }
    let path = dir.join("index.tlxi");
    b.build().unwrap().write(&path).unwrap();
    path
}

fn args(model: PathBuf, index: PathBuf) -> Args {
    Args {
        press: Vec::new(),
        references: Vec::new(),
        fps: None,
        sim: None,
        seed: 2,
        person: 0,
        sensor: 0,
        no_jig: false,
        presses: 1,
        real_time: false,
        model,
        index,
        allow_encoder_mismatch: false,
        threads: 1,
        json: true,
        motions: Vec::new(),
        wheel_speed: roller_firmware::DEFAULT_MAX_SPEED,
        wheel_accel: roller_firmware::DEFAULT_ACCEL,
        felt_json: None,
        felt_svg: None,
        contact: Default::default(),
        decision: Default::default(),
        mix_sensors: false,
        sensor_opts: Default::default(),
    }
}

/// Each press drives the paper's wheel under every policy asked for,
/// from every starting sample: the wheel ends at the press's final
/// sample, the felt latency is at least the decision time (or 0 where
/// the wheel already was there), and the summary file has a figure per
/// policy.
#[test]
fn classify_reports_the_felt_latency_of_each_motion_policy() {
    let dir = tempfile::tempdir().unwrap();
    let index = index_file(dir.path());
    let felt_json = dir.path().join("felt.json");
    let slots = Index::read(&index).unwrap().roller.slots.len();
    assert!(slots >= 4);
    let mut out = Vec::new();
    run_to(
        Args {
            sim: Some("T030".into()),
            presses: 2,
            motions: vec![
                MotionPolicy::Every,
                "confident".parse().unwrap(),
                "lead:30".parse().unwrap(),
            ],
            felt_json: Some(felt_json.clone()),
            felt_svg: Some(dir.path().join("felt.svg")),
            ..args(fixture_model(), index.clone())
        },
        &mut out,
    )
    .unwrap();
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 2, "{lines:?}");
    for v in &lines {
        let felt = v["felt"].as_array().unwrap();
        assert_eq!(felt.len(), 3, "{v}");
        let decided = v["decision_ms"].as_f64().unwrap();
        for f in felt {
            // Every slot of the index's wheel; at least one starting
            // sample is elsewhere, so the worst case waits for the
            // decision and a move.
            assert_eq!(f["starts"], slots, "{f}");
            let worst = f["felt_max_ms"].as_f64().unwrap();
            let p50 = f["felt_p50_ms"].as_f64().unwrap();
            assert!(worst >= p50 && p50 > 0.0, "{f}");
            if f["policy"] != "lead:30" {
                assert!(worst > decided + 80.0, "{f} vs decided at {decided}");
            }
            assert!(f["targets"].as_u64().unwrap() >= 1, "{f}");
        }
    }
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&felt_json).unwrap()).unwrap();
    let policies = summary["policies"].as_array().unwrap();
    assert_eq!(policies.len(), 3);
    assert_eq!(policies[0]["policy"], "every");
    for p in policies {
        assert_eq!(p["summary"]["n"], 2 * slots, "{p}");
        assert_eq!(p["summary"]["right_at_rest_pct"], 100.0, "{p}");
        assert!(p["summary"]["felt_p50_ms"].as_f64().unwrap() > 50.0, "{p}");
    }
    assert_eq!(summary["wheel"]["max_speed"], 9600);
    let svg = std::fs::read_to_string(dir.path().join("felt.svg")).unwrap();
    assert!(
        svg.starts_with("<svg") && svg.contains("lead:30: p50"),
        "{svg}"
    );
}

fn json_lines(out: &[u8]) -> Vec<serde_json::Value> {
    String::from_utf8(out.to_vec())
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

#[test]
fn classify_sim_and_recorded_presses_prints_one_json_object_per_press() {
    let dir = tempfile::tempdir().unwrap();
    let index = index_file(dir.path());
    let idx = Index::read(&index).unwrap();
    // --sim T030 --seed 2 --presses 2 --json
    let mut out = Vec::new();
    run_to(
        Args {
            sim: Some("T030".into()),
            presses: 2,
            ..args(fixture_model(), index.clone())
        },
        &mut out,
    )
    .unwrap();
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 2, "{lines:?}");
    for v in &lines {
        for key in [
            "textile",
            "first_textile",
            "slot",
            "distance",
            "decision_ms",
            "stages",
        ] {
            assert!(!v[key].is_null(), "{key} missing in {v}");
        }
        assert_eq!(v["textile"], "T030", "{v}");
        let entry = idx.entry_by_id("T030").unwrap();
        assert_eq!(v["slot"], idx.slot_of_entry(entry), "{v}");
        assert!(v["stages"]["encode"]["p50_ms"].as_f64().unwrap() > 0.0);
        assert!(v["decision_ms"].as_f64().unwrap() > 0.0);
    }
    // --press <tree>: recorded presses, found recursively.
    let sim = Simulator::new().unwrap();
    for id in ["T080", "T110"] {
        let p = sim.render_press(&PressSpec::new(id, 2)).unwrap();
        telextiles_recording::recording::write_press(&dir.path().join("presses").join(id), &p)
            .unwrap();
    }
    let mut out = Vec::new();
    run_to(
        Args {
            press: vec![dir.path().join("presses")],
            ..args(fixture_model(), index.clone())
        },
        &mut out,
    )
    .unwrap();
    let got: Vec<_> = json_lines(&out)
        .iter()
        .map(|v| v["textile"].as_str().unwrap().to_string())
        .collect();
    assert_eq!(got, ["T080", "T110"]);
    // Text output names the textile, slot and timings.
    let mut out = Vec::new();
    run_to(
        Args {
            json: false,
            press: vec![dir.path().join("presses/T080")],
            ..args(fixture_model(), index)
        },
        &mut out,
    )
    .unwrap();
    let text = String::from_utf8(out).unwrap();
    assert!(
        text.contains("T080")
            && text.contains("roller slot")
            && text.contains("press began at ")
            && text.contains(" ms later and stable from ")
            && text.contains("% of the gel")
            && !text.contains("partial contact")
            && text.contains("encode"),
        "{text}"
    );
    assert!(
        text.ends_with(
            "summary: 1 of 1 presses (100.0 %) decided as the fabric they are labelled with\n"
        ),
        "{text}"
    );
    // Over a fabric the index does not hold (U01) and a recording
    // that never touches: the summary says so.
    let u = sim.render_press(&PressSpec::new("U01", 2)).unwrap();
    telextiles_recording::recording::write_press(&dir.path().join("presses/U01"), &u).unwrap();
    let mut quiet = sim.render_press(&PressSpec::new("T030", 2)).unwrap();
    quiet.frames.truncate(20);
    quiet.meta.timestamps_us.truncate(20);
    quiet.meta.reference_frames = None;
    telextiles_recording::recording::write_press(&dir.path().join("presses/T030-quiet"), &quiet)
        .unwrap();
    let mut out = Vec::new();
    run_to(
        Args {
            json: false,
            press: vec![dir.path().join("presses")],
            ..args(fixture_model(), index_file(dir.path()))
        },
        &mut out,
    )
    .unwrap();
    let text = String::from_utf8(out).unwrap();
    // The quiet recording is a row of its own, with the reason.
    assert!(
        text.lines().any(|l| l.starts_with("press ")
            && l.contains("T030-quiet): not decided: no press detected")),
        "{text}"
    );
    let last = text.lines().last().unwrap();
    assert!(
        last.starts_with("summary: 2 of 2 presses (100.0 %) decided as the fabric they are labelled with; 1 press of fabrics the index does not hold (")
            && last.ends_with("; no press detected in 1 of 4 recordings"),
        "{text}"
    );
}

/// A press's final decision is the index's nearest textile to the
/// press's whole depth-weighted mean, computed here independently of
/// the decider from the front end's embeddings and contact depths
/// (hand-held presses, which the switching rule can leave on another
/// textile), on every press of the set.
#[test]
fn every_final_decision_is_the_nearest_textile_to_the_whole_press() {
    use telextiles_sensing::contact::ContactEvent;
    use telextiles_sensing::decide::{contact_weight, DecideConfig, PressMean};
    use telextiles_sensing::front::{recording_reference, FrontEnd};
    let dir = tempfile::tempdir().unwrap();
    let index_path = index_file(dir.path());
    let index = Index::read(&index_path).unwrap();
    let sim = Simulator::new().unwrap();
    let mut recordings = Vec::new();
    for (k, id) in ["T010", "T030", "T080", "T110", "T030", "T080"]
        .iter()
        .enumerate()
    {
        let p = sim
            .render_press(&PressSpec {
                person: 8 + (k as u32 % 3),
                jig: false,
                ..PressSpec::new(*id, 40 + k as u64)
            })
            .unwrap();
        let d = dir.path().join("presses").join(id).join(format!("{k}"));
        telextiles_recording::recording::write_press(&d, &p).unwrap();
        recordings.push(p);
    }
    let mut out = Vec::new();
    run_to(
        Args {
            press: vec![dir.path().join("presses")],
            ..args(fixture_model(), index_path.clone())
        },
        &mut out,
    )
    .unwrap();
    let mut got: Vec<(String, String)> = json_lines(&out)
        .iter()
        .map(|v| {
            let src = v["source"].as_str().unwrap().to_string();
            (src, v["textile"].as_str().unwrap_or("-").to_string())
        })
        .collect();
    got.sort();
    // The same presses, decided offline by the rule.
    let cfg = DecideConfig::default();
    let mut front = FrontEnd::new(
        Encoder::open(&fixture_model(), &EncoderOptions::default()).unwrap(),
        Default::default(),
        None,
    );
    let mut want = Vec::new();
    for (k, p) in recordings.iter().enumerate() {
        front.reset(recording_reference(p).as_deref());
        let mut mean = PressMean::new(index.dim, cfg.depth_power);
        let mut in_press = false;
        for (i, (image, &t)) in p.frames.iter().zip(&p.meta.timestamps_us).enumerate() {
            let f = telextiles_sensing::frame::Frame::new(image.clone(), t, i as u64).unwrap();
            let o = front.process(&f).unwrap();
            match o.contact.event {
                Some(ContactEvent::PressStart { .. }) => in_press = true,
                Some(ContactEvent::PressEnd { .. }) => in_press = false,
                _ => {}
            }
            if let (true, Some(e)) = (in_press, o.embedding) {
                mean.add(e, contact_weight(o.contact.depth));
            }
        }
        let n = index.nearest(mean.sum()).expect("a press in contact");
        let src = dir
            .path()
            .join("presses")
            .join(&p.meta.textile)
            .join(format!("{k}"))
            .display()
            .to_string();
        want.push((src, index.entries[n.best].id.clone()));
    }
    want.sort();
    assert_eq!(got, want);
}

/// The summary's counts: right of decided, the fabrics taken for
/// others (most first), and every press not counted there.
#[test]
fn the_summary_counts_presses_as_the_index_self_check_does() {
    let dir = tempfile::tempdir().unwrap();
    let index = Index::read(&index_file(dir.path())).unwrap();
    let t = |id: &str| index.entry_by_id(id).unwrap();
    let tally = Tally {
        decided: vec![
            (t("T030"), t("T030")),
            (t("T080"), t("T010")),
            (t("T110"), t("T010")),
            (t("T080"), t("T010")),
            (t("T110"), t("T110")),
        ],
        known_flagged: 1,
        undecided: 2,
        recordings: 6,
        ..Tally::default()
    };
    assert_eq!(
        tally.line(&index),
        "summary: 2 of 5 presses (40.0 %) decided as the fabric they are labelled with; taken for another: T080 as T010 (2), T110 as T010 (1); 1 of them flagged unknown; 2 presses without a decision"
    );
    assert_eq!(
        Tally {
            foreign: 1,
            silent: 2,
            recordings: 3,
            ..Tally::default()
        }
        .line(&index),
        "summary: no press of a fabric the index holds was decided; 1 press of fabrics the index does not hold (0 flagged unknown); no press detected in 2 of 3 recordings"
    );
    assert_eq!(
        Tally {
            decided: vec![(t("T030"), t("T030")); 3],
            split: 1,
            recordings: 2,
            ..Tally::default()
        }
        .line(&index),
        "summary: 3 of 3 presses (100.0 %) decided as the fabric they are labelled with; more than one press in 1 of 2 recordings"
    );
    // Presses whose decision changed: where each went first counts.
    let report_covering = |last: &str, first: &str, coverage: Option<f32>| PressReport {
        textile: Some(last.into()),
        slot: Some(0),
        distance: Some(0.1),
        margin: Some(0.1),
        confidence: Some(1.0),
        unknown: false,
        start_ms: 400.0,
        decision_ms: Some(50.0),
        first_textile: Some(first.into()),
        stable_ms: Some(50.0),
        switches: u32::from(first != last),
        duration_ms: 900.0,
        frames: 40,
        coverage,
        ended: "released".into(),
        stages: Default::default(),
        frame_total: Default::default(),
        start_us: 400_000,
        end_us: 1_300_000,
        steps: Vec::new(),
    };
    let report = |last: &str, first: &str| report_covering(last, first, Some(0.8));
    let mut tally = Tally::default();
    // Right throughout; wrong, then right; right, then wrong; wrong
    // throughout.
    for (label, last, first) in [
        ("T030", "T030", "T030"),
        ("T080", "T080", "T010"),
        ("T110", "T010", "T110"),
        ("T010", "T030", "T030"),
    ] {
        tally.press(label, &report(last, first), &index);
    }
    assert_eq!((tally.first_right, tally.first_changed), (2, 2));
    assert_eq!(
        tally.line(&index),
        "summary: 2 of 4 presses (50.0 %) decided as the fabric they are labelled with; taken for another: T010 as T030 (1), T110 as T010 (1); first decided as their own fabric: 2 of 4 (the decision changed in 2)"
    );
    // Presses that touched less than half the gel are counted, with
    // how many of them were right; one exactly at the bound and one
    // with no frame in contact are not partial.
    let mut tally = Tally::default();
    for (label, last, coverage) in [
        ("T030", "T030", Some(0.3)),
        ("T080", "T010", Some(0.1)),
        ("T110", "T110", Some(PARTIAL_COVERAGE)),
        ("T010", "T010", None),
    ] {
        tally.press(label, &report_covering(last, last, coverage), &index);
    }
    assert_eq!((tally.partial, tally.partial_right), (2, 1));
    assert_eq!(
        tally.line(&index),
        "summary: 3 of 4 presses (75.0 %) decided as the fabric they are labelled with; taken for another: T080 as T010 (1); 2 presses touched less than 50 % of the gel (partial contact), 1 of them decided right"
    );
}

/// A press held tilted touches part of the gel: `classify` says so for
/// the press (text and JSON) and in its summary; the same press held
/// flat is not flagged.
#[test]
fn a_tilted_press_is_reported_as_a_partial_contact() {
    let dir = tempfile::tempdir().unwrap();
    let index = index_file(dir.path());
    let sim = Simulator::new().unwrap();
    for (name, tilt) in [("flat", 0.0), ("tilted", 5.0)] {
        let p = sim
            .render_press(&PressSpec {
                tilt_deg: Some([0.0, tilt]),
                ..PressSpec::new("T030", 4)
            })
            .unwrap();
        telextiles_recording::recording::write_press(&dir.path().join(name).join("T030"), &p)
            .unwrap();
    }
    let classify = |name: &str, json: bool| {
        let mut out = Vec::new();
        run_to(
            Args {
                json,
                press: vec![dir.path().join(name)],
                ..args(fixture_model(), index.clone())
            },
            &mut out,
        )
        .unwrap();
        String::from_utf8(out).unwrap()
    };
    let coverage = |name: &str| {
        let v = json_lines(classify(name, true).as_bytes());
        assert_eq!(v.len(), 1, "{v:?}");
        v[0]["coverage"].as_f64().unwrap()
    };
    let (flat, tilted) = (coverage("flat"), coverage("tilted"));
    assert!(flat >= 0.7 && tilted < 0.5, "{flat} {tilted}");
    let text = classify("flat", false);
    assert!(!text.contains("partial contact"), "{text}");
    let text = classify("tilted", false);
    let pct = format!("{:.0} % of the gel", 100.0 * tilted);
    assert!(
        text.contains(&format!("; touched {pct}"))
            && text.contains(&format!(
                "partial contact: the press touched {pct} (held tilted?)"
            ))
            && text.contains("1 press touched less than 50 % of the gel (partial contact)"),
        "{text}"
    );
}

/// A recording in which the sensor was pressed, released and pressed
/// again: two presses, each decided on its own (as the live daemon
/// decides them), and the summary says which recordings held more
/// than one.
#[test]
fn a_recording_pressed_twice_is_two_presses_and_the_summary_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let index = index_file(dir.path());
    let sim = Simulator::new().unwrap();
    let press = |seed| {
        sim.render_press(&PressSpec {
            release: Some(true),
            ..PressSpec::new("T030", seed)
        })
        .unwrap()
    };
    let (once, second) = (press(5), press(6));
    assert!(once.meta.params.as_ref().unwrap().release_frame.is_some());
    let mut twice = once.clone();
    let ts = &once.meta.timestamps_us;
    let (last, step) = (ts[ts.len() - 1], ts[1] - ts[0]);
    let t0 = second.meta.timestamps_us[0];
    twice.meta.timestamps_us.extend(
        second
            .meta
            .timestamps_us
            .iter()
            .map(|t| t - t0 + last + step),
    );
    twice.frames.extend(second.frames.iter().cloned());
    let root = dir.path().join("presses");
    telextiles_recording::recording::write_press(&root.join("once"), &once).unwrap();
    telextiles_recording::recording::write_press(&root.join("twice"), &twice).unwrap();
    let mut out = Vec::new();
    run_to(
        Args {
            press: vec![root.clone()],
            ..args(fixture_model(), index.clone())
        },
        &mut out,
    )
    .unwrap();
    let lines = json_lines(&out);
    let from = |name: &str| {
        lines
            .iter()
            .filter(|v| v["source"].as_str().unwrap().ends_with(name))
            .map(|v| v["textile"].as_str().map(str::to_string))
            .collect::<Vec<_>>()
    };
    assert_eq!(from("once").len(), 1, "{lines:?}");
    let parts = from("twice");
    assert_eq!(parts.len(), 2, "{lines:?}");
    assert!(parts.iter().all(Option::is_some), "{lines:?}");
    // The same presses, as text: the summary names the split recording.
    let mut out = Vec::new();
    run_to(
        Args {
            press: vec![root],
            json: false,
            ..args(fixture_model(), index)
        },
        &mut out,
    )
    .unwrap();
    let text = String::from_utf8(out).unwrap();
    let summary = text.lines().last().unwrap();
    assert!(summary.starts_with("summary: "), "{text}");
    assert!(
        summary.ends_with("; more than one press in 1 of 2 recordings"),
        "{summary}"
    );
    assert!(!summary.contains("without a decision"), "{summary}");
}

#[test]
fn missing_files_and_foreign_indexes_are_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    let mut out = Vec::new();
    let e = run_to(
        Args {
            sim: Some("T030".into()),
            ..args(dir.path().join("none.onnx"), dir.path().join("i"))
        },
        &mut out,
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("none.onnx") && e.to_string().contains("not found"),
        "{e}"
    );
    let e = run_to(
        Args {
            sim: Some("T030".into()),
            ..args(fixture_model(), dir.path().join("none.tlxi"))
        },
        &mut out,
    )
    .unwrap_err();
    assert!(e.to_string().contains("none.tlxi"), "{e}");
    // An index built for another encoder file.
    let index = index_file(dir.path());
    let other = dir.path().join("copy.onnx");
    let bytes = std::fs::read(fixture_model()).unwrap();
    std::fs::write(&other, &bytes).unwrap();
    let mut idx = Index::read(&index).unwrap();
    idx.encoder_hash = "ab".repeat(32);
    let foreign = dir.path().join("foreign.tlxi");
    idx.write(&foreign).unwrap();
    let e = run_to(
        Args {
            sim: Some("T030".into()),
            ..args(other, foreign)
        },
        &mut out,
    )
    .unwrap_err();
    assert!(e.to_string().contains("built for encoder"), "{e}");
}

/// `classify --press` over recordings from different sensor units (and
/// one with a shifted LED) in one run decides each exactly as a run of
/// its own: every recording is replayed against its own reference. (It
/// used to keep the first recording's background for all of them.)
#[test]
fn one_run_over_recordings_with_different_backgrounds_decides_as_separate_runs() {
    let dir = tempfile::tempdir().unwrap();
    let model = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("sensing/tests/fixtures/fixture_subtract.onnx");
    let sim = Simulator::new().unwrap();
    // An index of three textiles, built through `index build`'s path.
    let enc = Encoder::open(&model, &EncoderOptions::default()).unwrap();
    let mut b = IndexBuilder::new(
        &file_sha256(&model).unwrap(),
        &enc.info().arch,
        enc.dim(),
        0,
    );
    b.roller_n = 3;
    let mut front = telextiles_sensing::front::FrontEnd::new(
        enc,
        telextiles_sensing::contact::ContactConfig::default(),
        None,
    );
    for id in ["T010", "T030", "T110"] {
        let mut embeddings = Vec::new();
        for (seed, sensor) in [(1, 0), (2, 1), (3, 2)] {
            let p = sim
                .render_press(&PressSpec {
                    sensor,
                    ..PressSpec::new(id, seed)
                })
                .unwrap();
            embeddings.extend(crate::cmd_index::press_embeddings(&mut front, &p, 2).unwrap());
        }
        b.add(TextileRecord {
            id: id.into(),
            name: id.into(),
            seen: true,
            structure: String::new(),
            attributes: Vec::new(),
            embeddings,
            exemplars: Vec::new(),
            press_frames: Vec::new(),
        })
        .unwrap();
    }
    let index = dir.path().join("index.tlxi");
    b.build().unwrap().write(&index).unwrap();
    // Four recordings: units 4, 5 and 0, and unit 3 with its LEDs shifted.
    let root = dir.path().join("presses");
    for (k, (id, sensor)) in [("T030", 4), ("T110", 5), ("T010", 0), ("T030", 3)]
        .into_iter()
        .enumerate()
    {
        let mut p = sim
            .render_press(&PressSpec {
                sensor,
                ..PressSpec::new(id, 20 + k as u64)
            })
            .unwrap();
        if k == 3 {
            for f in p.frames.iter_mut() {
                for px in f.pixels_mut() {
                    px.0[0] = (px.0[0] as f32 * 0.9) as u8;
                    px.0[2] = (px.0[2] as f32 * 1.1).min(255.0) as u8;
                }
            }
        }
        telextiles_recording::recording::write_press(&root.join(format!("{k}-{id}")), &p).unwrap();
    }
    let decide = |press: Vec<PathBuf>| {
        let mut out = Vec::new();
        run_to(
            Args {
                press,
                ..args(model.clone(), index.clone())
            },
            &mut out,
        )
        .unwrap();
        json_lines(&out)
            .into_iter()
            .map(|v| {
                (
                    v["textile"].clone(),
                    v["distance"].clone(),
                    v["decision_ms"].clone(),
                    v["switches"].clone(),
                    v["frames"].clone(),
                )
            })
            .collect::<Vec<_>>()
    };
    let together = decide(vec![root.clone()]);
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap()
        .map(|e| e.unwrap().path())
        .collect();
    dirs.sort();
    let separate: Vec<_> = dirs.into_iter().flat_map(|d| decide(vec![d])).collect();
    assert_eq!(together.len(), 4);
    assert_eq!(together, separate);
    let right = together
        .iter()
        .zip(["T030", "T110", "T010", "T030"])
        .filter(|(v, id)| v.0 == *id)
        .count();
    assert!(right >= 3, "{right} of 4 right: {together:?}");
}

/// `classify` alone, with these arguments, parsed.
#[derive(clap::Parser)]
struct Cli {
    #[command(flatten)]
    a: Args,
}

/// `classify --commit-margin` and `--encode-run` decide replayed
/// presses as a daemon pair with those settings does: the parsed flags
/// give the pipeline the receiving daemon's decider
/// (`Config::decide`) and the sending daemon's front end, checked as
/// the daemon checks them.
#[test]
fn classify_decides_with_the_daemons_commit_margin_and_encode_run() {
    let parse = |flags: &[&str]| {
        <Cli as clap::Parser>::try_parse_from(["classify", "--sim", "T030"].iter().chain(flags))
            .map(|c| c.a)
    };
    let a = parse(&["--commit-margin", "0.02", "--encode-run"]).unwrap();
    assert_eq!(
        a.decision,
        crate::config::DecisionArgs {
            commit_margin: Some(0.02),
            encode_run: Some(true),
        }
    );
    // (`config::tests::the_decision_speed_is_set_from_flag_env_or_file_and_checked`
    // checks these against a daemon's configuration.)
    let contact = telextiles_sensing::contact::ContactConfig::default();
    let pcfg = a.decision.pipeline(contact.clone());
    assert_eq!(
        pcfg.decide,
        telextiles_sensing::decide::DecideConfig {
            commit_margin: 0.02,
            ..Default::default()
        }
    );
    assert!(pcfg.encode_run);
    // Unset: the shipped pipeline, as the daemons' defaults.
    let shipped = parse(&[]).unwrap();
    assert_eq!(
        shipped.decision.pipeline(contact),
        telextiles_sensing::pipeline::PipelineConfig::default()
    );
    let off = parse(&["--encode-run=false"]).unwrap();
    assert_eq!(off.decision.encode_run, Some(false));
    // Out of range or not a number: refused, naming the flag.
    for bad in [["--commit-margin", "3"], ["--commit-margin", "x"]] {
        let e = parse(&bad).err().unwrap().to_string();
        assert!(e.contains("--commit-margin"), "{e}");
    }
    assert!(parse(&["--encode-run=maybe"]).is_err());

    // The same recorded presses, replayed with each setting.
    let dir = tempfile::tempdir().unwrap();
    let index = index_file(dir.path());
    let sim = Simulator::new().unwrap();
    // The true first contact of each press (ms from its first frame).
    let mut contact_ms = Vec::new();
    for (k, id) in TEXTILES.iter().enumerate() {
        let p = sim
            .render_press(&PressSpec::new(*id, 30 + k as u64))
            .unwrap();
        let frame = p.meta.params.as_ref().unwrap().contact_frame as usize;
        contact_ms.push(p.meta.timestamps_us[frame] as f64 / 1000.0);
        telextiles_recording::recording::write_press(&dir.path().join("presses").join(id), &p)
            .unwrap();
    }
    let run = |decision: crate::config::DecisionArgs| {
        let mut out = Vec::new();
        run_to(
            Args {
                press: vec![dir.path().join("presses")],
                decision,
                ..args(fixture_model(), index.clone())
            },
            &mut out,
        )
        .unwrap();
        json_lines(&out)
    };
    let with = |commit_margin: Option<f32>, encode_run: Option<bool>| {
        run(crate::config::DecisionArgs {
            commit_margin,
            encode_run,
        })
    };
    let base = with(None, None);
    assert_eq!(base.len(), TEXTILES.len());
    // Each press starts (`start_ms`, the recording's clock) at or a few
    // frames after its true first contact: decision times plus it are
    // times since the recording began, comparable across detectors.
    for (b, c) in base.iter().zip(&contact_ms) {
        let start = b["start_ms"].as_f64().unwrap();
        assert!(
            start >= c - 1.0 && start <= c + 250.0,
            "contact {c} ms: {b}"
        );
    }
    // The run that starts a press encoded: one more frame (the default
    // detector's run is two frames) in every press.
    let run_encoded = with(None, Some(true));
    for (b, r) in base.iter().zip(&run_encoded) {
        // The same start: the detector alone decides it.
        assert_eq!(r["start_ms"], b["start_ms"]);
        assert_eq!(
            r["frames"].as_u64().unwrap(),
            b["frames"].as_u64().unwrap() + 1,
            "{b}\n{r}"
        );
    }
    // A margin of 0 commits on the leader's second frame; one of 2
    // (no lead is that large) leaves the first decision to the timing
    // rules: never later, and sooner in some press.
    let ms = |v: &[serde_json::Value]| -> Vec<f64> {
        v.iter()
            .map(|p| p["decision_ms"].as_f64().unwrap())
            .collect()
    };
    let (soon, late) = (ms(&with(Some(0.0), None)), ms(&with(Some(2.0), None)));
    assert!(
        soon.iter().zip(&late).all(|(s, l)| s <= l) && soon.iter().zip(&late).any(|(s, l)| s < l),
        "margin 0: {soon:?}, margin 2: {late:?}"
    );
}

/// A GelSight-Mini-shaped recording (320x240 landscape at 25 fps, as the
/// camera streams) is read through its profile; against an index of a
/// DIGIT's presses it is refused by name, unless mixing is asked for.
#[test]
fn a_recording_of_another_sensor_is_mapped_and_refused_against_a_digits_index() {
    let dir = tempfile::tempdir().unwrap();
    let index = index_file(dir.path());
    let sim = Simulator::new().unwrap();
    let press = sim.render_press(&PressSpec::new("T030", 2)).unwrap();
    let gs = &telextiles_recording::profile::GELSIGHT_MINI;
    let cam = telextiles_sim::camera::as_camera(&press, gs, gs.modes[0]).unwrap();
    let rec = dir.path().join("gs/T030");
    telextiles_recording::recording::write_press(&rec, &cam).unwrap();
    let e = run_to(
        Args {
            press: vec![rec.clone()],
            ..args(fixture_model(), index.clone())
        },
        &mut Vec::new(),
    )
    .unwrap_err();
    let e = format!("{e:#}");
    assert!(
        e.contains("built from presses of a digit sensor")
            && e.contains("gelsight-mini")
            && e.contains("--mix-sensors"),
        "{e}"
    );
    let mut out = Vec::new();
    run_to(
        Args {
            press: vec![rec],
            mix_sensors: true,
            ..args(fixture_model(), index)
        },
        &mut out,
    )
    .unwrap();
    let lines = json_lines(&out);
    assert_eq!(lines.len(), 1, "{lines:?}");
    assert!(lines[0]["textile"].is_string(), "{}", lines[0]);
}
