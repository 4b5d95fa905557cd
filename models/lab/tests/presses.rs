//! The study on recorded presses (`--source presses:<dir>`), end to end on
//! a handful of simulated recordings written in the on-disk press format:
//! three textiles, four presses each, by different people on different
//! sensor units (different no-contact backgrounds), one textile recorded
//! at 25 fps.

use std::path::Path;

use telextiles_lab::methods::Method;
use telextiles_lab::recorded::{self, Split, StudyConfig, StudyReport};
use telextiles_sim::recording::write_press;
use telextiles_sim::{PressSpec, Simulator};

const TEXTILES: [&str; 3] = ["T001", "T040", "T090"];
/// Sensor unit of press k of every textile: four different backgrounds.
const SENSORS: [u32; 4] = [0, 4, 5, 2];
const FRAMES: usize = 72;

/// Writes the recordings to `<dir>/<textile>/press-<k>`; T090's are
/// relabelled as 25 fps captures (40 ms between frames).
fn write_set(dir: &Path) {
    let sim = Simulator::new().unwrap();
    for (ti, t) in TEXTILES.iter().enumerate() {
        for (k, &sensor) in SENSORS.iter().enumerate() {
            let mut p = sim
                .render_press(&PressSpec {
                    person: k as u32 + 1,
                    sensor,
                    frames: FRAMES,
                    ..PressSpec::new(*t, 100 * ti as u64 + k as u64)
                })
                .unwrap();
            if *t == "T090" {
                p.meta.fps = 25.0;
                p.meta.timestamps_us = (0..p.frames.len() as u64).map(|i| i * 40_000).collect();
            }
            write_press(&dir.join(t).join(format!("press-{k}")), &p).unwrap();
        }
    }
}

fn methods() -> Vec<Method> {
    let wanted = ["fft-radial-c64", "fft-radial-c64-bg", "lbp-riu2-c64 -bg"];
    let mut v: Vec<Method> = telextiles_lab::report::descriptor_methods()
        .unwrap()
        .into_iter()
        .filter(|m| wanted.contains(&m.name().as_str()))
        .collect();
    assert_eq!(v.len(), wanted.len());
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../encoder.onnx");
    v.push(Method::onnx("shipped", std::fs::read(shipped).unwrap()).unwrap());
    v
}

/// Structure and consistency of a report; `min_press`: the least top-1
/// per press of the shipped model and the power spectrum (chance: 1/3).
fn check(r: &StudyReport, queries: usize, min_press: f64) {
    for m in &r.methods {
        let s = &m.summary;
        assert_eq!(s.presses, queries, "{}", s.name);
        // Per class: the query counts add up, and so do the confusion rows.
        assert_eq!(m.per_class.len(), 3);
        assert_eq!(
            m.per_class.iter().map(|c| c.query_presses).sum::<usize>(),
            queries
        );
        for (c, row) in m.per_class.iter().zip(&m.confusion) {
            assert_eq!(row.iter().sum::<usize>(), c.query_presses, "{}", s.name);
        }
        let diag: usize = (0..3).map(|i| m.confusion[i][i]).sum();
        let right: usize = m.per_class.iter().map(|c| c.presses_correct).sum();
        assert_eq!(diag, right);
        assert!((s.press_top1 - right as f64 / queries as f64).abs() < 1e-12);
        assert_eq!(m.decisions.len(), queries);
        assert_eq!(
            m.decisions.iter().filter(|d| d.knn == d.truth).count(),
            right
        );
        let frames: usize = m.per_class.iter().map(|c| c.query_frames).sum();
        assert_eq!(frames, s.queries);
        // Accuracy against time: the running mean never has more than
        // every frame, so the last point is the whole press.
        let last = m.by_time.last().unwrap();
        assert!(last.0 * 1e-3 > (FRAMES as f64) / 25.0);
        assert!((last.1 - s.press_top1).abs() < 1e-12, "{}", s.name);
        assert!(m.first_frame_ms > 0.0 && m.first_frame_ms < 500.0);
        // The daemon's decider: decides most presses, not before two
        // frames of a leader after the detector's start (the second frame
        // over the threshold): 33 ms at 60 fps, at frame times of each
        // recording's own clock (40 ms apart at 25 fps).
        assert!(m.decided_presses <= queries && m.decided_presses * 2 > queries);
        assert!(m.first_decision_ms >= 33.0, "{}", m.first_decision_ms);
        let right = m.decisions.iter().filter(|d| d.decider == d.truth).count();
        assert!((m.press_top1_decider - right as f64 / queries as f64).abs() < 1e-12);
        // And against the index `index build --presses` makes (centroids
        // and per-press exemplars), right as counted.
        let right = m
            .decisions
            .iter()
            .filter(|d| d.decider_exemplars == d.truth)
            .count();
        assert!((m.press_top1_decider_exemplars - right as f64 / queries as f64).abs() < 1e-12);
        assert!(m.unknown_flagged <= queries && m.unknown_flagged_exemplars <= queries);
        for d in m.decisions.iter().filter(|d| d.truth == "T090") {
            if let Some(t) = d.first_decision_ms {
                assert!((t / 40.0 - (t / 40.0).round()).abs() < 1e-6, "{t}");
            }
        }
    }
    // The power spectrum and the shipped model tell three textiles apart
    // well above chance (1/3) on presses by other people on other units.
    for name in ["fft-radial-c64", "shipped"] {
        let m = r.methods.iter().find(|m| m.summary.name == name).unwrap();
        assert!(m.summary.press_top1 >= min_press, "{name}: {:?}", m.summary);
        assert!(m.summary.frame_top1 >= 0.8, "{name}: {:?}", m.summary);
        assert!(m.press_top1_decider >= min_press, "{name}: {m:?}");
    }
    for m in &r.methods {
        assert!(m.summary.frame_top1 > 0.5, "{:?}", m.summary);
    }
}

#[test]
fn presses_study_index_split_and_leave_one_out() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("recordings");
    write_set(&rec);
    let methods = methods();
    let out = dir.path().join("out");
    let mut cfg = StudyConfig::new(&rec, Split::IndexPresses(3));
    cfg.runs = 5;
    let r = telextiles_lab::recorded_report::run(&cfg, &methods, Some(&out)).unwrap();
    // Three queries: at least two right.
    check(&r, 3, 0.66);
    // The index: the first three recordings of each textile by path.
    for x in &r.recordings {
        let want = if x.path.ends_with("press-3") {
            "query"
        } else {
            "index"
        };
        assert_eq!(x.role, want, "{x:?}");
    }
    for f in [
        "bench.json",
        "report.md",
        "speed-accuracy.svg",
        "decision-time.svg",
    ] {
        assert!(out.join(f).is_file(), "{f}");
    }
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for h in [
        "## Methods",
        "## Accuracy against time since first contact",
        "## Per textile",
        "### Confusion, shipped",
        "## Per recording",
        "25 fps (4), 60 fps (8)",
    ] {
        assert!(md.contains(h), "{h} missing from\n{md}");
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("bench.json")).unwrap()).unwrap();
    assert_eq!(json["methods"].as_array().unwrap().len(), methods.len());

    // Leave one press out, from the same recordings.
    let cfg = StudyConfig {
        split: Split::Lopo,
        runs: 0,
        ..cfg
    };
    let r = telextiles_lab::recorded_report::run(&cfg, &methods, None).unwrap();
    check(&r, 12, 0.75);
    assert!(r.recordings.iter().all(|x| x.role == "both"));

    // `--encode-run`: the run of frames that starts each press is encoded
    // too, so every method's frames begin at the press's start, and no
    // method's first decision comes later.
    let on = StudyConfig {
        encode_run: true,
        ..cfg
    };
    let with_run = telextiles_lab::recorded_report::run(&on, &methods, None).unwrap();
    assert!(with_run.encode_run && !r.encode_run);
    for (a, b) in with_run.methods.iter().zip(&r.methods) {
        let name = &a.summary.name;
        assert_eq!(a.first_frame_ms, 0.0, "{name}");
        assert!(b.first_frame_ms > 0.0, "{name}");
        assert!(a.first_decision_ms <= b.first_decision_ms, "{name}");
        assert_eq!(a.summary.presses, 12, "{name}");
    }
    assert!(telextiles_lab::recorded_report::markdown(&with_run).contains("`--encode-run`"));
    assert!(!telextiles_lab::recorded_report::markdown(&r).contains("`--encode-run`"));
}

#[test]
fn presses_one_run_equals_each_recording_alone() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("recordings");
    write_set(&rec);
    let methods = methods();
    let mut cfg = StudyConfig::new(&rec, Split::IndexPresses(3));
    // Two recordings at a time, in whatever order the workers take them.
    cfg.workers = 2;
    let (refs, together) = recorded::embed_all(&cfg, &methods).unwrap();
    assert_eq!(refs.len(), 12);
    // The recordings really differ in background: the references of the
    // first recording (unit 0) and the second (unit 4) are far apart.
    let r0 = telextiles_sensing::front::recording_reference(&refs[0].load().unwrap()).unwrap();
    let r1 = telextiles_sensing::front::recording_reference(&refs[1].load().unwrap()).unwrap();
    let mad = r0.iter().zip(&r1).map(|(a, b)| (a - b).abs()).sum::<f32>() / r0.len() as f32;
    assert!(mad > 2.0, "backgrounds differ by only {mad}");
    // Each recording alone, in a fresh processor, in reverse order.
    let mut alone = Vec::new();
    for (r, t) in refs.iter().zip(&together).rev() {
        let mut p = recorded::Processor::new(&methods, 1, Default::default()).unwrap();
        let a = p
            .process(&r.path.display().to_string(), r.load().unwrap())
            .unwrap();
        assert_eq!(&a, t, "{}", r.path.display());
        assert!(a.methods.iter().all(|m| !m.is_empty()));
        alone.push(a);
    }
    alone.reverse();
    // Times come from the recording's own timestamps: 40 ms apart at 25 fps.
    for (r, p) in refs.iter().zip(&together) {
        let step = if r.textile == "T090" {
            40.0
        } else {
            1000.0 / 60.0
        };
        for m in &p.methods {
            for w in m.t_ms.windows(2).zip(m.frames.windows(2)) {
                let want = (w.1[1] - w.1[0]) as f64 * step;
                assert!((w.0[1] - w.0[0] - want).abs() < 0.01, "{w:?}");
            }
        }
    }
    // And so are the per-press decisions scored from them.
    let cfg = StudyConfig { runs: 0, ..cfg };
    let a = telextiles_lab::recorded_score::score_all(&cfg, &methods, &refs, &together).unwrap();
    let b = telextiles_lab::recorded_score::score_all(&cfg, &methods, &refs, &alone).unwrap();
    for (x, y) in a.methods.iter().zip(&b.methods) {
        let dx: Vec<_> = x
            .decisions
            .iter()
            .map(|d| (&d.knn, &d.centroid, &d.decider, d.first_decision_ms))
            .collect();
        let dy: Vec<_> = y
            .decisions
            .iter()
            .map(|d| (&d.knn, &d.centroid, &d.decider, d.first_decision_ms))
            .collect();
        assert_eq!(dx, dy);
    }
}

#[test]
fn presses_from_the_command_line() {
    let dir = tempfile::tempdir().unwrap();
    let rec = dir.path().join("recordings");
    write_set(&rec);
    let lab = env!("CARGO_BIN_EXE_telextiles-lab");
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../encoder.onnx");
    let source = format!("presses:{}", rec.display());
    let run = |args: &[&str]| std::process::Command::new(lab).args(args).output().unwrap();
    let out = dir.path().join("out");
    let o = run(&[
        "bench",
        "--source",
        &source,
        "--index-presses",
        "3",
        "--no-descriptors",
        "--model",
        &format!("shipped={}", shipped.display()),
        "--runs",
        "5",
        "--time-threads",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{stderr}");
    // Not a terminal: plain progress lines.
    assert!(stderr.contains("12/12 recordings (100 %)"), "{stderr}");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("| shipped |"), "{md}");
    assert!(md.contains("### Confusion, shipped"), "{md}");
    // eval: one model, leave one press out, JSON.
    let json = dir.path().join("eval.json");
    let o = run(&[
        "eval",
        "--source",
        &source,
        "--split",
        "lopo",
        "--model",
        shipped.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let j: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(j["split"], "Lopo");
    assert_eq!(j["methods"][0]["summary"]["presses"], 12);
    assert!(
        String::from_utf8_lossy(&o.stdout).contains("## Accuracy against time since first contact")
    );
    // Misuse is refused with a message.
    for (args, msg) in [
        (
            vec!["bench", "--source", source.as_str()],
            "--out <dir> is required",
        ),
        (
            vec!["cache", "--source", source.as_str()],
            "works with `eval` and `bench`",
        ),
        (
            vec![
                "bench",
                "--source",
                source.as_str(),
                "--split",
                "lopo",
                "--index-presses",
                "2",
                "--out",
                "x",
            ],
            "exclude each other",
        ),
        (vec!["bench", "--source", "presses:"], "needs a directory"),
        // A reference is for recordings; the simulator would ignore it.
        (
            vec![
                "bench",
                "--source",
                "sim",
                "--reference",
                "bg.png",
                "--out",
                "x",
            ],
            "--reference/--fps/--sensor-profile are for --source presses:<dir>",
        ),
        // So is a frame rate; and one out of range is refused.
        (
            vec!["bench", "--source", "sim", "--fps", "30", "--out", "x"],
            "--fps/--sensor-profile are for --source presses:<dir>",
        ),
        (
            vec![
                "bench",
                "--source",
                source.as_str(),
                "--fps",
                "0",
                "--out",
                "x",
            ],
            "out of range",
        ),
    ] {
        let o = run(&args);
        assert!(!o.status.success(), "{args:?}");
        let e = String::from_utf8_lossy(&o.stderr);
        assert!(e.contains(msg), "{args:?}: {e}");
    }
}

#[test]
fn presses_in_the_pytouch_layout() {
    // root/<class>/<serial>/*.png: one recording per class and serial.
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("pytouch");
    let sim = Simulator::new().unwrap();
    for (ci, class) in ["T001", "T090"].iter().enumerate() {
        for (k, serial) in ["D20001", "D20002", "D20003"].iter().enumerate() {
            let p = sim
                .render_press(&PressSpec {
                    sensor: [0, 4, 5][k],
                    frames: 60,
                    ..PressSpec::new(*class, 10 * ci as u64 + k as u64)
                })
                .unwrap();
            // A PyTouch sequence carries no reference: ten more quiet
            // frames in front (the press's own first, untouched, frame) let
            // the contact detector capture one.
            assert!(p.meta.reference_frames.unwrap() > 0);
            let frames: Vec<_> = std::iter::repeat_n(p.frames[0].clone(), 10)
                .chain(p.frames)
                .collect();
            let d = root.join(class).join(serial);
            std::fs::create_dir_all(&d).unwrap();
            for (i, f) in frames.iter().enumerate() {
                f.save(d.join(telextiles_sim::recording::frame_name(i)))
                    .unwrap();
            }
        }
    }
    let refs = recorded::list_recordings(&root, None, None).unwrap();
    assert_eq!(refs.len(), 6);
    assert!(refs.iter().all(|r| r.layout == recorded::Layout::Pytouch));
    // No timestamps: 60 fps for these 240x320 frames, or the rate given
    // (`bench --fps`).
    assert_eq!(refs[0].load().unwrap().meta.fps, 60.0);
    let at_30 = recorded::list_recordings(&root, Some(30.0), None).unwrap();
    let m = at_30[0].load().unwrap().meta;
    assert_eq!((m.fps, m.timestamps_us[1]), (30.0, 33_333));
    // Said to be another sensor's (`--sensor-profile`), the same images
    // are mapped and named by its profile: a generic camera at 0.05 mm
    // per pixel (the frames are 240x320 portrait, 12 x 16 mm).
    let uvc = telextiles_sim::recording::Sensor {
        profile: &telextiles_recording::profile::UVC,
        mm_per_px: Some(0.05),
    };
    let as_uvc = recorded::list_recordings(&root, None, Some(uvc)).unwrap();
    let p = as_uvc[0].load().unwrap();
    assert_eq!(p.meta.sensor_profile.as_deref(), Some("uvc"));
    assert_eq!((p.frames[0].width(), p.frames[0].height()), (240, 320));
    assert_ne!(p.frames[20], refs[0].load().unwrap().frames[20]);
    let mut cfg = StudyConfig::new(&root, Split::IndexPresses(2));
    cfg.runs = 0;
    let methods: Vec<Method> = methods()
        .into_iter()
        .filter(|m| m.name() == "shipped")
        .collect();
    let r = telextiles_lab::recorded_report::run(&cfg, &methods, None).unwrap();
    assert_eq!(r.layout, "pytouch");
    assert_eq!(r.fps, vec![(60.0, 6)]);
    let roles: Vec<&str> = r.recordings.iter().map(|x| x.role.as_str()).collect();
    assert_eq!(
        roles,
        ["index", "index", "query", "index", "index", "query"]
    );
    assert_eq!(r.recordings[2].sensor, "D20003");
    // No recorded reference: the front end captured one from the first
    // quiet frames, and the two queries are decided.
    assert!(r.recordings.iter().all(|x| !x.own_reference));
    let m = &r.methods[0];
    assert_eq!(m.summary.presses, 2);
    assert_eq!(m.confusion.iter().flatten().sum::<usize>(), 2);
}

/// PyTouch sequences cut to the press: every frame in contact, no
/// reference and no quiet frames to capture one from. Given each sensor's
/// no-contact frame (`--reference SERIAL=PNG`), every recording is
/// replayed against it and decided; without, the study says why it cannot.
#[test]
fn presses_in_the_pytouch_layout_without_quiet_frames_need_a_reference() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("pytouch");
    let sim = Simulator::new().unwrap();
    let serials = ["D20001", "D20002", "D20003"];
    let units = [0u32, 4, 5];
    let mut in_contact = 0;
    for (ci, class) in ["T001", "T090"].iter().enumerate() {
        for (k, serial) in serials.iter().enumerate() {
            let p = sim
                .render_press(&PressSpec {
                    sensor: units[k],
                    frames: 60,
                    release: Some(false),
                    ..PressSpec::new(*class, 10 * ci as u64 + k as u64)
                })
                .unwrap();
            let from = p.meta.params.as_ref().unwrap().hold_frame as usize;
            let d = root.join(class).join(serial);
            std::fs::create_dir_all(&d).unwrap();
            for (i, f) in p.frames[from..].iter().enumerate() {
                f.save(d.join(telextiles_sim::recording::frame_name(i)))
                    .unwrap();
            }
            in_contact += p.frames.len() - from;
        }
    }
    // Each sensor's no-contact frame, as its owner has it.
    let mut refs = Vec::new();
    for (serial, unit) in serials.iter().zip(units) {
        let png = dir.path().join(format!("{serial}.png"));
        sim.background(unit).save(&png).unwrap();
        refs.push(format!("{serial}={}", png.display()));
    }
    let lab = env!("CARGO_BIN_EXE_telextiles-lab");
    let shipped = Path::new(env!("CARGO_MANIFEST_DIR")).join("../encoder.onnx");
    let source = format!("presses:{}", root.display());
    let bench = |extra: &[String], out: &Path| {
        let mut args: Vec<String> = [
            "bench",
            "--source",
            &source,
            "--index-presses",
            "2",
            "--no-descriptors",
            "--model",
            &format!("shipped={}", shipped.display()),
            "--runs",
            "0",
            "--out",
            out.to_str().unwrap(),
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        for r in extra {
            args.push("--reference".into());
            args.push(r.clone());
        }
        std::process::Command::new(lab)
            .args(&args)
            .output()
            .unwrap()
    };
    let json = |out: &Path| -> serde_json::Value {
        serde_json::from_str(&std::fs::read_to_string(out.join("bench.json")).unwrap()).unwrap()
    };
    let with = dir.path().join("with");
    let o = bench(&refs, &with);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = json(&with);
    let recs = r["recordings"].as_array().unwrap();
    assert_eq!(recs.len(), 6);
    let mut used = 0;
    for x in recs {
        assert_eq!(x["own_reference"], false, "{x}");
        assert_eq!(x["given_reference"], true, "{x}");
        assert!(x["skipped"].is_null(), "{x}");
        used += x["contact_frames"].as_u64().unwrap() as usize;
    }
    // Nearly every frame is seen in contact (the detector starts a press
    // on its third frame over the threshold).
    assert!(
        used + 6 * 3 >= in_contact && used <= in_contact,
        "{used} of {in_contact}"
    );
    let md = std::fs::read_to_string(with.join("report.md")).unwrap();
    assert!(md.contains("6 of 6 recordings carry no reference"), "{md}");
    // Without the references no recording has a reference to be replayed
    // against: each is skipped with the way out, and the study has no
    // usable recording.
    let without = dir.path().join("without");
    let o = bench(&[], &without);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    let hint = "could be captured from its first frames (give the sensor's no-contact frame with --reference)";
    assert_eq!(stderr.matches(hint).count(), 6, "{stderr}");
    assert!(stderr.contains("0 usable recordings"), "{stderr}");
    // A reference that is not a sensor frame is refused before any work.
    let o = bench(
        &[format!(
            "D20001={}",
            dir.path().join("missing.png").display()
        )],
        &dir.path().join("bad"),
    );
    assert!(!o.status.success());
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(
        stderr.contains("--reference D20001=") && stderr.contains("missing.png"),
        "{stderr}"
    );
    assert!(!dir.path().join("bad").exists());
}

#[test]
fn presses_front_end_embeddings_match_the_lab_embedder() {
    // The recorded study runs ONNX models through the daemon's front end;
    // the simulator study through the lab's own preprocessing. On the same
    // frames in contact and the same reference they agree.
    let dir = tempfile::tempdir().unwrap();
    let sim = Simulator::new().unwrap();
    let p = sim
        .render_press(&PressSpec {
            sensor: 4,
            frames: FRAMES,
            ..PressSpec::new("T040", 7)
        })
        .unwrap();
    let path = dir.path().join("press");
    write_press(&path, &p).unwrap();
    let methods: Vec<Method> = telextiles_lab::report::descriptor_methods()
        .unwrap()
        .into_iter()
        .filter(|m| ["fft-radial-c64-bg", "pixels16-c64"].contains(&m.name().as_str()))
        .collect();
    assert_eq!(methods.len(), 2);
    let press = telextiles_sim::recording::read_press(&path).unwrap();
    let seg = telextiles_sensing::front::segment(&press, &Default::default()).unwrap();
    let mut proc = recorded::Processor::new(&methods, 1, Default::default()).unwrap();
    let got = proc.process("press", press.clone()).unwrap();
    let reference: Vec<u8> = seg
        .reference
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    let reference = image::RgbImage::from_raw(240, 320, reference).unwrap();
    for (m, e) in methods.iter().zip(&got.methods) {
        let (crop, input) = m.view();
        // The processor, like the daemon, does not encode the run that
        // starts the press (segment flags it as early).
        let frames: Vec<usize> = seg
            .contact
            .iter()
            .filter(|c| !c.early)
            .map(|c| c.index)
            .collect();
        assert_eq!(e.frames, frames, "{}", m.name());
        let mut set = telextiles_lab::data::ImageSet {
            kind: telextiles_lab::data::ImageKind::Input,
            side: input as usize,
            crop,
            classes: vec!["T040".into()],
            items: Vec::new(),
            pixels: Vec::new(),
            source: "test".into(),
        };
        for &i in &frames {
            let v = telextiles_lab::preprocess::centre_crop_resize(&press.frames[i], crop, input)
                .unwrap();
            set.pixels.extend_from_slice(v.as_raw());
            set.items.push(telextiles_lab::data::FrameMeta {
                class: 0,
                press: 0,
                person: 0,
                sensor: 4,
                jig: true,
                frame: i as u32,
            });
        }
        let rv = telextiles_lab::preprocess::centre_crop_resize(&reference, crop, input).unwrap();
        let mut emb = telextiles_lab::methods::Embedder::new(m, 1).unwrap();
        let (want, dim) = emb.embed(&set, |_| Some(rv.as_raw())).unwrap();
        assert_eq!(dim, e.dim);
        for (k, (a, b)) in want.chunks(dim).zip(e.rows.chunks(dim)).enumerate() {
            let cos: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
            assert!(cos > 0.999, "{} frame {k}: cosine {cos}", m.name());
        }
    }
    // With the run that starts the press encoded, its frames lead, counted
    // as early, and the rows after them are the same as without.
    proc.set_encode_run(true);
    let with_run = proc.process("press", press.clone()).unwrap();
    let all: Vec<usize> = seg.contact.iter().map(|c| c.index).collect();
    let early = seg.contact.iter().filter(|c| c.early).count();
    let enter = telextiles_sensing::contact::ContactConfig::default().min_enter_frames;
    assert_eq!(early, enter as usize - 1, "min_enter_frames - 1");
    for (a, b) in with_run.methods.iter().zip(&got.methods) {
        assert_eq!((a.frames.clone(), a.early), (all.clone(), early));
        assert_eq!(a.rows[early * a.dim..], b.rows[..]);
        assert_eq!(a.t_ms[0], 0.0, "the run's first frame is the press's start");
    }
}
