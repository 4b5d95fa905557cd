//! The round trip a user runs with their own fabrics (docs/recording.md),
//! through the real binary: `record --sensor sim` -> `index build --presses`
//! -> `classify`, plus `record --sensor replay:` and the errors a user meets.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");

fn model() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("sensing/tests/fixtures/fixture_encoder.onnx")
}

fn run(dir: &Path, args: &[&str]) -> Output {
    let out = Command::new(BIN)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "0")
        .args(args)
        .output()
        .expect("run telextilesd");
    eprintln!(
        "$ telextilesd {}\n{}{}",
        args.join(" "),
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn ok(dir: &Path, args: &[&str]) -> String {
    let out = run(dir, args);
    assert!(out.status.success(), "telextilesd {args:?} failed");
    String::from_utf8(out.stdout).expect("utf-8")
}

/// Run a command that must fail; its standard error.
fn fails(dir: &Path, args: &[&str]) -> String {
    let out = run(dir, args);
    assert!(!out.status.success(), "telextilesd {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn meta(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("press.json")).expect("press.json");
    serde_json::from_str(&text).expect("json")
}

/// The press reports of `classify --json` on one query press of T030 and
/// one of T080: two, each decided as the fabric its path names.
/// The objects `classify --json` printed, one per press.
fn reports(out: &str) -> Vec<serde_json::Value> {
    out.lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| serde_json::from_str(l).expect("json line"))
        .collect()
}

/// `index build` of one simulated press (seed 10) each of T030 and T080,
/// saved as press directories under `d/index`, into `d/<out>`.
fn two_textile_index(d: &Path, model: &str, out: &str) {
    let sim = telextiles_sim::Simulator::new().expect("simulator");
    for t in ["T030", "T080"] {
        let p = sim
            .render_press(&telextiles_sim::PressSpec::new(t, 10))
            .expect("press");
        telextiles_sim::recording::write_press(&d.join("index").join(t).join("0001"), &p)
            .expect("write");
    }
    ok(
        d,
        &[
            "index",
            "build",
            "--model",
            model,
            "--presses",
            "index",
            "-o",
            out,
        ],
    );
}

fn each_press_right(out: &str) -> Vec<serde_json::Value> {
    each_of_n_presses_right(out, 2)
}

/// The press reports of `classify --json` on `n` query presses of T030
/// and T080: `n`, each decided as the fabric its path names.
fn each_of_n_presses_right(out: &str, n: usize) -> Vec<serde_json::Value> {
    let reports = reports(out);
    assert_eq!(reports.len(), n, "{out}");
    for r in &reports {
        let source = r["source"].as_str().expect("source");
        let truth = if source.contains("T030") {
            "T030"
        } else {
            "T080"
        };
        assert_eq!(r["textile"], truth, "{r}");
    }
    reports
}

#[test]
fn record_index_classify_round_trip_as_a_user_runs_it() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let model = model();
    let model = model.to_str().expect("utf-8 path");
    let t0 = std::time::Instant::now();

    // Record two textiles (the simulated DIGIT presses unattended).
    let out = ok(
        d,
        &[
            "record",
            "--textile",
            "T030",
            "--name",
            "my twill",
            "--presses",
            "2",
            "--out",
            "recordings",
            "--sensor",
            "sim",
        ],
    );
    assert!(
        out.contains("recorded 2 of 2 presses of T030"),
        "stdout: {out}"
    );
    // A second run adds presses after the first ones.
    ok(
        d,
        &[
            "record",
            "--textile",
            "T030",
            "--presses",
            "1",
            "--out",
            "recordings",
            "--sensor",
            "sim",
        ],
    );
    ok(
        d,
        &[
            "record",
            "--textile",
            "T080",
            "--presses",
            "3",
            "--out",
            "recordings",
            "--sensor",
            "sim",
        ],
    );
    for t in ["T030", "T080"] {
        for n in ["0001", "0002", "0003"] {
            let p = d.join("recordings").join(t).join(n);
            let m = meta(&p);
            assert_eq!(m["textile"], t);
            assert_eq!(m["source"], "sim");
            assert_eq!(m["sensor_serial"], "SIM0000");
            assert!((m["fps"].as_f64().expect("fps") - 60.0).abs() < 0.1, "{m}");
            let k = m["reference_frames"].as_u64().expect("reference_frames");
            assert!(k >= 8, "{k} reference frames");
            let frames = m["frames"].as_array().expect("frames").len();
            assert!(frames > k as usize + 60, "{frames} frames");
            assert_eq!(m["timestamps_us"][0], 0);
        }
        assert!(!d.join("recordings").join(t).join("0004").exists());
    }
    // Different seeds: the second run's press is not a copy of the first.
    let a = std::fs::read(d.join("recordings/T030/0001/000060.png")).expect("png");
    let c = std::fs::read(d.join("recordings/T030/0003/000060.png")).expect("png");
    assert_ne!(a, c);
    let info = std::fs::read_to_string(d.join("recordings/T030/textile.json")).expect("json");
    let info: serde_json::Value = serde_json::from_str(&info).expect("json");
    assert_eq!(info["id"], "T030");
    assert_eq!(info["name"], "my twill");

    // Query presses the index has not seen (other seeds).
    for t in ["T030", "T080"] {
        ok(
            d,
            &[
                "record",
                "--textile",
                t,
                "--presses",
                "1",
                "--out",
                "queries",
                "--sensor",
                "sim",
                "--sim-seed",
                "100",
            ],
        );
    }

    // The index from the recordings; two textiles, two roller slots.
    let out = ok(
        d,
        &[
            "index",
            "build",
            "--model",
            model,
            "--presses",
            "recordings",
            "--slots",
            "2",
            "-o",
            "my.tlxi",
        ],
    );
    assert!(
        out.contains("2 textiles from 6 presses"),
        "index build: {out}"
    );
    // It checks itself: each of the six presses left out and decided
    // against the other five.
    assert!(out.contains("self-check: "), "index build: {out}");
    assert!(out.contains(" of 6 presses ("), "index build: {out}");
    // The note on thinly covered fabrics (fewer than 8 presses).
    let thin = |args: &[&str]| {
        let o = run(d, args);
        assert!(o.status.success(), "{o:?}");
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let build = |presses: &str, out: &str| {
        thin(&[
            "index",
            "build",
            "--model",
            model,
            "--presses",
            presses,
            "-o",
            out,
        ])
    };
    // Eight presses of each (copies of the three recorded: a directory
    // reached twice through links is one press): no note. Three of each:
    // both fabrics are named. The one-press query set: both, and the index
    // is still written.
    for t in ["T030", "T080"] {
        for k in 0..8 {
            let from = d
                .join("recordings")
                .join(t)
                .join(format!("000{}", k % 3 + 1));
            let to = d.join("eight").join(t).join(format!("{k:04}"));
            std::fs::create_dir_all(&to).expect("mkdir");
            for f in std::fs::read_dir(&from).expect("press dir") {
                let f = f.expect("entry").path();
                assert!(f.is_file(), "{}", f.display());
                std::fs::copy(&f, to.join(f.file_name().expect("name"))).expect("copy");
            }
        }
    }
    let err = build("eight", "eight.tlxi");
    assert!(!err.contains("fewer than 8 presses"), "{err}");
    // Copies of one press cannot calibrate the unknown distance, and the
    // note says why.
    assert!(
        err.contains("presses identical to another press of their fabric")
            && !err.contains("fewer than 4"),
        "{err}"
    );
    let err = build("recordings", "again.tlxi");
    assert!(
        err.contains("2 of 2 fabrics have fewer than 8 presses with contact: T030 (3), T080 (3)"),
        "{err}"
    );
    let err = build("queries", "thin.tlxi");
    assert!(
        err.contains("2 of 2 fabrics have fewer than 8 presses with contact: T030 (1), T080 (1)"),
        "{err}"
    );
    assert!(err.contains("press each fabric 8 times or more"), "{err}");
    assert!(d.join("thin.tlxi").exists());

    // Classify the queries: each decided as the textile it is.
    let out = ok(
        d,
        &[
            "classify", "--model", model, "--index", "my.tlxi", "--press", "queries", "--json",
        ],
    );
    for r in &each_press_right(&out) {
        assert_eq!(r["unknown"], false, "{r}");
    }
    eprintln!("round trip took {:.1} s", t0.elapsed().as_secs_f64());
}

#[test]
fn record_replay_re_records_presses_with_their_own_reference() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    ok(
        d,
        &[
            "record",
            "--textile",
            "T050",
            "--presses",
            "2",
            "--out",
            "orig",
            "--sensor",
            "sim",
        ],
    );
    let out = ok(
        d,
        &[
            "record",
            "--textile",
            "wool",
            "--presses",
            "2",
            "--out",
            "again",
            "--sensor",
            "replay:orig",
        ],
    );
    assert!(out.contains("recorded 2 of 2 presses of wool"), "{out}");
    for n in ["0001", "0002"] {
        let m = meta(&d.join("again/wool").join(n));
        assert_eq!(m["textile"], "wool");
        assert_eq!(m["source"], "replay");
        assert_eq!(m["sensor_serial"], "SIM0000");
        let k = m["reference_frames"].as_u64().expect("reference");
        assert!(k >= 8, "{k}");
    }
    // Asking for more presses than the recordings hold: the ones found are
    // saved, and the command says it fell short.
    let out = run(
        d,
        &[
            "record",
            "--textile",
            "wool",
            "--presses",
            "5",
            "--out",
            "again",
            "--sensor",
            "replay:orig",
        ],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("only 2 of 5 presses recorded"), "{err}");
    assert!(d.join("again/wool/0004").is_dir());
    assert!(!d.join("again/wool/0005").exists());
    // A PyTouch-style dataset (<class>/<serial>/*.png, quiet frames first)
    // is read by the same walk: its sequence is re-recorded as a press with
    // its sensor's serial and its own reference.
    let seq = d.join("pytouch/wool/SIM0000");
    std::fs::create_dir_all(&seq).unwrap();
    let first = d.join("orig/T050/0001");
    let mut frames: Vec<_> = std::fs::read_dir(&first)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "png"))
        .collect();
    frames.sort();
    for f in &frames {
        std::fs::copy(f, seq.join(f.file_name().unwrap())).unwrap();
    }
    let out = ok(
        d,
        &[
            "record",
            "--textile",
            "wool2",
            "--presses",
            "1",
            "--out",
            "again",
            "--sensor",
            "replay:pytouch",
        ],
    );
    assert!(out.contains("recorded 1 of 1 presses of wool2"), "{out}");
    let m = meta(&d.join("again/wool2/0001"));
    assert_eq!(m["sensor_serial"], "SIM0000");
    assert!(
        m["reference_frames"].as_u64().expect("reference") >= 8,
        "{m}"
    );
    // Nothing to replay: said, naming the directory.
    std::fs::create_dir_all(d.join("empty")).unwrap();
    let out = run(
        d,
        &[
            "record",
            "--textile",
            "wool",
            "--presses",
            "1",
            "--out",
            "again",
            "--sensor",
            "replay:empty",
        ],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no recordings to replay under empty"), "{err}");
}

/// A PyTouch sequence cut to the press (its first frame already pressed,
/// no reference of its own), re-recorded with `--reference` for its
/// sensor: replayed against that frame, and saved as a press that starts
/// with it as its no-contact frames, so it carries its reference from then
/// on (`classify` finds the press with no `--reference`). Without one the
/// command says that its first frames became its reference; with a live
/// sensor the flag is refused.
#[test]
fn record_replay_gives_a_cut_sequence_the_reference_given_for_its_sensor() {
    use telextiles_sim::{PressSpec, Simulator};
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let model = model();
    let model = model.to_str().expect("utf-8 path");
    let sim = Simulator::new().expect("simulator");
    let press = sim
        .render_press(&PressSpec {
            release: Some(true),
            ..PressSpec::new("T050", 31)
        })
        .expect("press");
    let hold = press.meta.params.as_ref().expect("params").hold_frame as usize;
    let seq = d.join("cut/wool/D00001");
    std::fs::create_dir_all(&seq).expect("mkdir");
    for (i, f) in press.frames[hold..].iter().enumerate() {
        f.save(seq.join(format!("{i:04}.png"))).expect("png");
    }
    press.frames[0].save(d.join("bg.png")).expect("png");
    // A second sensor's sequence after it (the same frames).
    let seq2 = d.join("cut/wool/D00002");
    std::fs::create_dir_all(&seq2).expect("mkdir");
    for e in std::fs::read_dir(&seq).expect("read") {
        let p = e.expect("entry").path();
        std::fs::copy(&p, seq2.join(p.file_name().expect("name"))).expect("copy");
    }
    let record = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "record",
            "--textile",
            "wool",
            "--out",
            out,
            "--sensor",
            "replay:cut",
        ];
        if !extra.contains(&"--presses") {
            args.extend(["--presses", "1"]);
        }
        args.extend_from_slice(extra);
        run(d, &args)
    };
    // Without the reference its first, pressed frames become the
    // reference (what it then sees is the fabric shifting and the
    // release, not the press): said, with the way out.
    // Said once, naming the first such recording, however many follow.
    let o = record("plain", &["--presses", "5"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("note: cut/wool/D00001 (the recording carries no no-contact reference, so its first frames became one: if they are in contact, give the sensor's no-contact frame with --reference, or keep it beside the index as no-contact.png or no-contact-<SERIAL>.png; `telextilesd record --idle` writes one)"),
        "{err}"
    );
    assert_eq!(err.matches("note: ").count(), 1, "{err}");
    // With it (for its serial, or for every sensor): one press, led by the
    // given frame as its reference frames, bit-exact.
    for (out, arg) in [("given", "D00001=bg.png"), ("any", "bg.png")] {
        let o = record(out, &["--reference", arg]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let saved = d.join(out).join("wool/0001");
        let m = meta(&saved);
        assert_eq!(m["sensor_serial"], "D00001", "{m}");
        let k = m["reference_frames"].as_u64().expect("reference frames");
        assert_eq!(k, 8, "{m}");
        let names = m["frames"].as_array().expect("frames");
        for name in &names[..k as usize] {
            let f =
                telextiles_sim::recording::read_frame(&saved.join(name.as_str().expect("name")))
                    .expect("frame");
            assert!(f == press.frames[0], "{name} is the given frame");
        }
        let f = telextiles_sim::recording::read_frame(
            &saved.join(names[k as usize].as_str().expect("name")),
        )
        .expect("frame");
        assert!(f != press.frames[0], "the press follows its reference");
    }
    // The saved press needs no --reference any more.
    two_textile_index(d, model, "i.tlxi");
    let out = ok(
        d,
        &[
            "classify", "--model", model, "--index", "i.tlxi", "--press", "given", "--json",
        ],
    );
    let reports = reports(&out);
    assert_eq!(reports.len(), 1, "{out}");
    assert!(reports[0]["frames"].as_u64().expect("frames") > 30, "{out}");
    // A live sensor's reference is its own: the flag is refused.
    let err = fails(
        d,
        &[
            "record",
            "--textile",
            "T050",
            "--presses",
            "1",
            "--out",
            "live",
            "--sensor",
            "sim",
            "--reference",
            "bg.png",
        ],
    );
    assert!(
        err.contains("--reference is for --sensor replay:<dir>"),
        "{err}"
    );
    assert!(!d.join("live").exists());
}

/// A whole PyTouch dataset converted in one command, as a DIGIT owner
/// would take in a shared one: `record --sensor replay:<dataset>` without
/// `--textile` saves each sequence's press under its own class, with its
/// sensor's serial and the reference given for that sensor, and without
/// `--presses` takes every press. The converted presses are then read like
/// the owner's own (`classify` with no `--reference` decides each as its
/// class). `--presses` caps the total; asking for more than the dataset
/// holds fails after saving what it found. Press directories are grouped
/// by their own label; a label that is no textile id is refused before
/// anything is written.
#[test]
fn record_replay_without_a_textile_converts_a_whole_dataset_under_its_classes() {
    use telextiles_sim::{PressSpec, Simulator};
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let model = model();
    let model = model.to_str().expect("utf-8 path");
    let sim = Simulator::new().expect("simulator");
    // <class>/<serial>/*.png, cut to the press; two units, whose
    // no-contact frames differ, each given as its serial's reference.
    for (unit, serial) in [(0, "D00001"), (1, "D00002")] {
        for (k, textile) in ["T030", "T080"].into_iter().enumerate() {
            let press = sim
                .render_press(&PressSpec {
                    sensor: unit,
                    release: Some(true),
                    ..PressSpec::new(textile, 40 + k as u64 + 10 * unit as u64)
                })
                .expect("press");
            let hold = press.meta.params.as_ref().expect("params").hold_frame as usize;
            let seq = d.join("ds").join(textile).join(serial);
            std::fs::create_dir_all(&seq).expect("mkdir");
            for (i, f) in press.frames[hold..].iter().enumerate() {
                f.save(seq.join(format!("{i:04}.png"))).expect("png");
            }
            press.frames[0]
                .save(d.join(format!("bg-{serial}.png")))
                .expect("png");
        }
    }
    let refs = [
        "--reference",
        "D00001=bg-D00001.png",
        "--reference",
        "D00002=bg-D00002.png",
    ];
    let record = |out: &str, extra: &[&str]| {
        let mut args = vec!["record", "--out", out, "--sensor", "replay:ds"];
        args.extend_from_slice(&refs);
        args.extend_from_slice(extra);
        run(d, &args)
    };
    let o = record("conv", &[]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(
        stdout.contains("recorded 4 presses of 2 textiles into conv"),
        "{stdout}"
    );
    for textile in ["T030", "T080"] {
        let mut serials = Vec::new();
        for n in ["0001", "0002"] {
            let m = meta(&d.join("conv").join(textile).join(n));
            assert_eq!(m["textile"], textile, "{m}");
            assert_eq!(m["reference_frames"], 8, "{m}");
            serials.push(m["sensor_serial"].as_str().expect("serial").to_string());
        }
        assert_eq!(serials, ["D00001", "D00002"], "{textile}");
        assert!(!d.join("conv").join(textile).join("0003").exists());
    }
    // Read like the owner's own presses: no --reference needed any more.
    two_textile_index(d, model, "i.tlxi");
    let out = ok(
        d,
        &[
            "classify", "--model", model, "--index", "i.tlxi", "--press", "conv", "--json",
        ],
    );
    each_of_n_presses_right(&out, 4);
    // --presses caps the total: the first class's two, then one.
    let o = record("three", &["--presses", "3"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(d.join("three/T030/0002").exists() && d.join("three/T080/0001").exists());
    assert!(!d.join("three/T080/0002").exists());
    // More than the dataset holds: what it holds is saved, then it fails.
    let o = record("nine", &["--presses", "9"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("only 4 of 9 presses recorded: the recordings are all replayed"),
        "{err}"
    );
    assert!(d.join("nine/T080/0002").exists());
    // --name names a --textile; a live sensor needs both flags.
    let err = String::from_utf8_lossy(&record("named", &["--name", "Wool"]).stderr).into_owned();
    assert!(err.contains("--name names the --textile given"), "{err}");
    for (args, want) in [
        (
            vec![
                "record",
                "--presses",
                "1",
                "--out",
                "live",
                "--sensor",
                "sim",
            ],
            "--textile is needed with --sensor sim",
        ),
        (
            vec![
                "record",
                "--textile",
                "T030",
                "--out",
                "live",
                "--sensor",
                "sim",
            ],
            "--presses is needed with --sensor sim",
        ),
    ] {
        let err = fails(d, &args);
        assert!(err.contains(want), "{err}");
    }
    assert!(!d.join("named").exists() && !d.join("live").exists());
    // Press directories are grouped by their press.json's textile: the
    // converted presses re-recorded land under the same ids.
    let o = run(d, &["record", "--out", "again", "--sensor", "replay:conv"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    for textile in ["T030", "T080"] {
        assert_eq!(
            meta(&d.join("again").join(textile).join("0002"))["textile"],
            textile
        );
    }
    // A label that cannot be a directory name: refused, naming the
    // recording, before any press is written.
    let bad = d.join("pd/x/0001");
    std::fs::create_dir_all(d.join("pd/x")).expect("mkdir");
    std::fs::rename(d.join("again/T080/0001"), &bad).expect("move");
    let mut m = meta(&bad);
    m["textile"] = "wool/felt".into();
    std::fs::write(bad.join("press.json"), m.to_string()).expect("write");
    std::fs::rename(d.join("again/T030/0001"), d.join("pd/x/0000")).expect("move");
    let o = run(d, &["record", "--out", "bad", "--sensor", "replay:pd"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("pd/x/0001 is labelled \"wool/felt\": record it with --textile"),
        "{err}"
    );
    assert!(!d.join("bad").exists(), "nothing written");
}

#[test]
fn record_errors_say_what_to_do() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    // No DIGIT with this serial on this machine.
    let out = run(
        d,
        &[
            "record",
            "--textile",
            "T030",
            "--presses",
            "1",
            "--out",
            "rec",
            "--sensor",
            "digit:NO-SUCH-SERIAL",
        ],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cannot open the DIGIT"), "{err}");
    assert!(err.contains("--sensor sim"), "{err}");
    assert!(!d
        .join("rec/T030")
        .read_dir()
        .is_ok_and(|mut r| r.next().is_some()));
    // The simulator only presses catalogue textiles.
    let out = run(
        d,
        &[
            "record",
            "--textile",
            "my-denim",
            "--presses",
            "1",
            "--out",
            "rec",
            "--sensor",
            "sim",
        ],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("built-in catalogue"), "{err}");
    // Not a directory name.
    let out = run(
        d,
        &[
            "record",
            "--textile",
            "../x",
            "--presses",
            "1",
            "--out",
            "rec",
            "--sensor",
            "sim",
        ],
    );
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("cannot be a directory name"));
}

#[test]
fn record_ctrl_c_leaves_only_complete_presses() {
    use std::io::{BufRead, BufReader};
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let mut child = Command::new(BIN)
        .current_dir(d)
        .env("RUST_BACKTRACE", "0")
        .args([
            "record",
            "--textile",
            "T030",
            "--presses",
            "1000",
            "--out",
            "rec",
            "--sensor",
            "sim",
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("spawn");
    let mut err = BufReader::new(child.stderr.take().expect("stderr"));
    let mut seen = String::new();
    let mut line = String::new();
    while !seen.contains("saved press 2/1000") {
        line.clear();
        if err.read_line(&mut line).expect("read") == 0 {
            panic!("record ended early: {seen}");
        }
        seen.push_str(&line);
    }
    let pid = child.id().to_string();
    let killed = Command::new("kill")
        .args(["-INT", &pid])
        .status()
        .expect("kill");
    assert!(killed.success());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut err, &mut rest).expect("read");
    let status = child.wait().expect("wait");
    assert!(!status.success(), "interrupted is not success");
    assert!(
        rest.contains("interrupted:") && rest.contains("presses saved"),
        "{seen}{rest}"
    );
    let mut n = 0;
    for e in std::fs::read_dir(d.join("rec/T030")).expect("dir") {
        let e = e.expect("entry");
        let name = e.file_name().to_string_lossy().into_owned();
        assert!(!name.contains(".tmp-"), "half-written press left: {name}");
        telextiles_sim::recording::read_press(&e.path()).expect("a complete press");
        n += 1;
    }
    assert!(n >= 2, "{n} presses");
}

/// A PyTouch-style dataset (`<class>/<serial>/*.png`) whose sequences are
/// cut to the press: no reference, no quiet frames. `index build` and
/// `classify` read it; given each sensor's no-contact frame
/// (`--reference SERIAL=PNG`) they decide it as the press-format round
/// trip does, and without it they say what is missing.
#[test]
fn pytouch_data_cut_to_the_press_needs_and_takes_a_reference() {
    use telextiles_sim::{PressSpec, Simulator};
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let model = model();
    let model = model.to_str().expect("utf-8 path");
    let sim = Simulator::new().expect("simulator");
    let serials = ["D20001", "D20002"];
    let units = [0u32, 1];
    let write = |set: &str, t: &str, seed: u64, k: usize| {
        let p = sim
            .render_press(&PressSpec {
                sensor: units[k],
                release: Some(false),
                ..PressSpec::new(t, seed)
            })
            .expect("press");
        let from = p.meta.params.as_ref().expect("params").hold_frame as usize;
        let dir = d.join(set).join(t).join(serials[k]);
        std::fs::create_dir_all(&dir).expect("mkdir");
        for (i, f) in p.frames[from..].iter().enumerate() {
            f.save(dir.join(telextiles_sim::recording::frame_name(i)))
                .expect("png");
        }
    };
    for t in ["T030", "T080"] {
        for k in 0..2 {
            write("index", t, 10 + k as u64, k);
        }
        write("queries", t, 100, 1);
    }
    let mut refs = Vec::new();
    for (serial, unit) in serials.iter().zip(units) {
        let png = d.join(format!("{serial}.png"));
        sim.background(unit).save(&png).expect("png");
        refs.push("--reference".to_string());
        refs.push(format!("{serial}={}", png.display()));
    }
    let with_refs = |args: &[&str]| -> Vec<String> {
        args.iter()
            .map(|s| s.to_string())
            .chain(refs.iter().cloned())
            .collect()
    };
    fn strs(v: &[String]) -> Vec<&str> {
        v.iter().map(String::as_str).collect()
    }

    // Without a reference: every sequence is skipped, and the warning says
    // what to give; with nothing in contact there is no index.
    let build = [
        "index",
        "build",
        "--model",
        model,
        "--presses",
        "index",
        "-o",
        "p.tlxi",
    ];
    let o = run(d, &build);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert_eq!(
        err.matches("give the sensor's no-contact frame with --reference")
            .count(),
        4,
        "{err}"
    );
    assert!(
        err.contains("no press under index was seen in contact: nothing to index"),
        "{err}"
    );
    assert!(!d.join("p.tlxi").exists());

    // With them: two fabrics from four sequences, and the queries decided.
    let out = ok(d, &strs(&with_refs(&build)));
    assert!(out.contains("2 textiles from 4 presses"), "{out}");
    let classify = with_refs(&[
        "classify", "--model", model, "--index", "p.tlxi", "--press", "queries", "--json",
    ]);
    let out = ok(d, &strs(&classify));
    each_press_right(&out);
    // classify without them: no press detected, and why.
    let o = run(
        d,
        &[
            "classify", "--model", model, "--index", "p.tlxi", "--press", "queries",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!(
        err.matches("no press detected (the recording carries no no-contact reference")
            .count(),
        2,
        "{err}"
    );
    // A reference that is not a frame of the sensor is refused up front.
    std::fs::write(d.join("bad.png"), b"not a png").expect("write");
    let o = run(
        d,
        &[
            "classify",
            "--model",
            model,
            "--index",
            "p.tlxi",
            "--press",
            "queries",
            "--reference",
            "bad.png",
        ],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success());
    assert!(
        err.contains("--reference bad.png") && err.contains("neither a PNG nor a JPEG"),
        "{err}"
    );
}

/// A PyTouch-style dataset carries no timestamps. Its frames are timed at
/// the DIGIT's stream rate for the size they were saved at (VGA streams at
/// 30 fps, QVGA at 60), or at the rate `--fps` gives; a rate given for
/// press directories, which carry their own timestamps, is refused, and
/// so is one for a live sensor.
#[test]
fn sequences_saved_without_timestamps_are_timed_at_the_streams_rate_or_the_one_given() {
    use telextiles_sim::{PressSpec, Simulator};
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let model = model();
    let model = model.to_str().expect("utf-8 path");
    let sim = Simulator::new().expect("simulator");
    // Whole presses (quiet frames first, so each takes its reference from
    // them), at the DIGIT's 240x320 or as VGA 480x640 (each pixel
    // doubled: averaged back, the very same frames).
    let write = |set: &str, t: &str, seed: u64, vga: bool| {
        let p = sim.render_press(&PressSpec::new(t, seed)).expect("press");
        let dir = d.join(set).join(t).join("D20001");
        std::fs::create_dir_all(&dir).expect("mkdir");
        for (i, f) in p.frames.iter().enumerate() {
            let img = if vga {
                telextiles_sim::RgbImage::from_fn(480, 640, |x, y| *f.get_pixel(x / 2, y / 2))
            } else {
                f.clone()
            };
            img.save(dir.join(format!("frame_{i}.png"))).expect("png");
        }
    };
    two_textile_index(d, model, "p.tlxi");
    write("qvga", "T030", 100, false);
    write("vga", "T030", 100, true);
    let classify = |set: &str, extra: &[&str]| -> serde_json::Value {
        let mut args = vec![
            "classify", "--model", model, "--index", "p.tlxi", "--press", set, "--json",
        ];
        args.extend_from_slice(extra);
        let out = ok(d, &args);
        let reports = reports(&out);
        assert_eq!(reports.len(), 1, "{out}");
        assert_eq!(reports[0]["textile"], "T030", "{out}");
        reports[0].clone()
    };
    let ms = |r: &serde_json::Value| r["duration_ms"].as_f64().expect("duration_ms");
    let qvga = classify("qvga", &[]);
    let vga = classify("vga", &[]);
    // The same frames, twice as far apart: the press lasts twice as long.
    // The detector starts a press on the second frame over the threshold
    // at either rate (the same first frame, so the same start), and both
    // encode the same frames. Its leader is clear (a lead over the
    // runner-up beyond `commit_margin`), so it is decided on the second
    // encoded frame: two frame periods after the start, 67 ms at 30 fps
    // and 33 ms at 60.
    assert_eq!(vga["frames"].as_u64(), qvga["frames"].as_u64());
    assert!(
        qvga["margin"].as_f64().expect("margin")
            >= telextiles_sensing::decide::DecideConfig::default().commit_margin as f64,
        "{qvga}"
    );
    assert_eq!(qvga["decision_ms"].as_f64().map(f64::round), Some(33.0));
    assert_eq!(vga["decision_ms"].as_f64().map(f64::round), Some(67.0));
    assert!(ms(&qvga) > 500.0, "{qvga}");
    assert!(
        (ms(&vga) - 2.0 * ms(&qvga)).abs() < 1.0,
        "{vga} against {qvga}"
    );
    // Given the rate: as given.
    let at_60 = classify("vga", &["--fps", "60"]);
    assert_eq!(at_60["frames"], qvga["frames"]);
    assert!(
        (ms(&at_60) - ms(&qvga)).abs() < 1.0,
        "{at_60} against {qvga}"
    );
    let at_15 = classify("qvga", &["--fps", "15"]);
    assert!(
        (ms(&at_15) - 4.0 * ms(&qvga)).abs() < 1.0,
        "{at_15} against {qvga}"
    );

    // Press directories have timestamps: --fps is refused, not ignored.
    ok(
        d,
        &[
            "record",
            "--sensor",
            "replay:vga",
            "--textile",
            "T030",
            "--presses",
            "1",
            "--out",
            "rec",
        ],
    );
    let press = d.join("rec/T030/0001");
    assert_eq!(meta(&press)["fps"], 30.0);
    // A rate for press directories, for a live sensor, or out of range:
    // refused, and nothing written.
    let refused = [
        (
            "classify --model M --index p.tlxi --press rec --fps 30",
            "press.json gives its timestamps",
        ),
        (
            "index build --model M --presses rec --fps 30 -o q.tlxi",
            "press.json gives its timestamps",
        ),
        (
            "record --sensor sim --textile T030 --presses 1 --out rec2 --fps 30",
            "--fps is for --sensor replay:<dir>",
        ),
        (
            "classify --model M --index p.tlxi --press vga --fps 0",
            "out of range",
        ),
    ];
    for (line, want) in refused {
        let args: Vec<&str> = line
            .split(' ')
            .map(|a| if a == "M" { model } else { a })
            .collect();
        let err = fails(d, &args);
        assert!(err.contains(want), "{line}: {err}");
        if want.contains("press.json") {
            assert!(err.contains("0001"), "{err}");
        }
    }
    assert!(!d.join("q.tlxi").exists() && !d.join("rec2").exists());
    // A stray image beside a class's sensor directories is not a press of
    // that class: the dataset is refused, naming it.
    std::fs::copy(
        d.join("qvga/T030/D20001/frame_0.png"),
        d.join("qvga/T030/preview.png"),
    )
    .expect("copy");
    let err = fails(
        d,
        &[
            "classify", "--model", model, "--index", "p.tlxi", "--press", "qvga",
        ],
    );
    assert!(
        err.contains(
            "holds both frames (preview.png) and sensor directories with frames (D20001/)"
        ),
        "{err}"
    );
}

/// `index check` on an owner's presses with the two shipped models (the
/// trained model and its untrained front end, the fallback): each press
/// left out and decided against the others, paired press by press, and
/// the model in use kept unless the other is ahead by the paired rule.
#[test]
fn index_check_compares_the_shipped_models_on_the_owners_presses() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let models = Path::new(env!("CARGO_MANIFEST_DIR")).join("../models");
    let shipped = models.join("encoder.onnx");
    let fallback = models.join("descriptor.onnx");
    let (shipped, fallback) = (shipped.to_str().unwrap(), fallback.to_str().unwrap());
    for t in ["T030", "T080"] {
        ok(
            d,
            &[
                "record",
                "--textile",
                t,
                "--presses",
                "3",
                "--out",
                "recordings",
                "--sensor",
                "sim",
            ],
        );
    }
    let check = |extra: &[&str]| {
        let mut args = vec![
            "index",
            "check",
            "--presses",
            "recordings",
            "--model",
            shipped,
            "--model",
            fallback,
        ];
        args.extend_from_slice(extra);
        ok(d, &args)
    };
    let v: serde_json::Value = serde_json::from_str(check(&["--json"]).trim()).expect("json");
    assert_eq!(v["recordings"], 6, "{v}");
    assert_eq!(v["fabrics"], 2, "{v}");
    assert_eq!(v["exemplars"], true, "{v}");
    assert_eq!(v["fit"], "chosen on the presses", "{v}");
    let m = v["models"].as_array().expect("models");
    assert_eq!(m.len(), 2);
    for (k, path) in [shipped, fallback].iter().enumerate() {
        assert_eq!(m[k]["model"], *path);
        // Two fabrics far apart: every press told apart by either model.
        assert_eq!(
            (m[k]["presses"].as_u64(), m[k]["right"].as_u64()),
            (Some(6), Some(6)),
            "{v}"
        );
        assert!(m[k]["confusions"]
            .as_array()
            .expect("confusions")
            .is_empty());
    }
    assert!(m[0]["against_first"].is_null());
    assert_eq!(
        m[1]["against_first"],
        serde_json::json!({"presses": 6, "right_only_first": 0, "right_only_this": 0, "ahead": false})
    );
    assert_eq!(v["choice"], shipped);
    // As text: each model's line and the choice, said.
    let text = check(&[]);
    assert!(
        text.contains("self-check of 6 presses of 2 fabrics"),
        "{text}"
    );
    assert!(text.contains("6 of 6 right (100.0 %)"), "{text}");
    assert!(text.contains(&format!("choice: keep {shipped}")), "{text}");
    // One press per fabric cannot be checked; a model that does not load
    // is named.
    ok(
        d,
        &[
            "record",
            "--textile",
            "T030",
            "--presses",
            "1",
            "--out",
            "single",
            "--sensor",
            "sim",
        ],
    );
    let out = run(
        d,
        &["index", "check", "--presses", "single", "--model", shipped],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("no fabric under single has two presses with contact"),
        "{err}"
    );
    let out = run(
        d,
        &[
            "index",
            "check",
            "--presses",
            "recordings",
            "--model",
            "nope.onnx",
        ],
    );
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cannot load the encoder nope.onnx"), "{err}");
}

/// `record --idle` through the binary, as an owner checks a resting
/// sensor: the footage saved as a recording, the check's summary (and its
/// JSON), and `classify` on the footage finding no press either.
#[test]
fn record_idle_checks_the_contact_detector_on_a_resting_sensor() {
    let tmp = tempfile::tempdir().expect("tempdir");
    let d = tmp.path();
    let out = ok(
        d,
        &[
            "record", "--idle", "2", "--sensor", "sim", "--out", "rest", "--json",
        ],
    );
    assert!(
        out.contains("saved 120 frames (2.0 s at 60.0 fps) in rest/idle/0001"),
        "{out}"
    );
    assert!(out.contains("0 false press(es)"), "{out}");
    assert!(out.contains("ok: no press started at rest"), "{out}");
    let json: serde_json::Value =
        serde_json::from_str(out.lines().last().expect("json line")).expect("json");
    assert_eq!(json["frames"], 120);
    assert_eq!(json["false_presses"], 0);
    assert_eq!(json["run_frames"], 2);
    assert!(json["margin"].as_f64().expect("margin") > 0.0, "{json}");
    let m = meta(&d.join("rest/idle/0001"));
    assert_eq!(m["textile"], "idle");
    assert_eq!(m["frames"].as_array().map(Vec::len), Some(120));
    let model = model();
    let model = model.to_str().expect("utf-8");
    two_textile_index(d, model, "p.tlxi");
    let out = run(
        d,
        &[
            "classify",
            "--press",
            "rest/idle/0001",
            "--model",
            model,
            "--index",
            "p.tlxi",
            "--json",
        ],
    );
    assert!(out.status.success());
    // No press: one row that says so, with no textile.
    let rows = reports(&String::from_utf8_lossy(&out.stdout));
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert!(rows[0]["textile"].is_null(), "{rows:?}");
    assert!(
        rows[0]["undecided"]
            .as_str()
            .is_some_and(|w| w.starts_with("no press detected")),
        "{rows:?}"
    );
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no press detected"), "{err}");
    // The resting sensor's no-contact frame is kept, and a recording that
    // begins in contact (no quiet frames, no reference of its own) is
    // decided with it when it lies beside the index; without it, the
    // recording is a row that says why.
    let serial = m["sensor_serial"].as_str().expect("serial").to_string();
    let png = d.join(format!("rest/no-contact-{serial}.png"));
    assert!(png.is_file(), "{}", png.display());
    let sim = telextiles_sim::Simulator::new().expect("simulator");
    let mut p = sim
        .render_press(&telextiles_sim::PressSpec::new("T030", 12))
        .expect("press");
    let hold = p.meta.params.as_ref().expect("params").hold_frame as usize;
    p.frames.drain(..hold);
    p.meta.timestamps_us.drain(..hold);
    p.meta.reference_frames = None;
    p.meta.params = None;
    p.meta.source = "digit".into();
    p.meta.sensor_serial = Some(serial.clone());
    telextiles_sim::recording::write_press(&d.join("incontact/T030/0001"), &p).expect("write");
    let classify = |d: &Path| {
        run(
            d,
            &[
                "classify",
                "--press",
                "incontact",
                "--model",
                model,
                "--index",
                "p.tlxi",
                "--json",
            ],
        )
    };
    let rows = reports(&String::from_utf8_lossy(&classify(d).stdout));
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert!(rows[0]["textile"].is_null(), "{rows:?}");
    std::fs::copy(&png, d.join(format!("no-contact-{serial}.png"))).expect("copy");
    let out = classify(d);
    let rows = reports(&String::from_utf8_lossy(&out.stdout));
    assert_eq!(rows.len(), 1, "{rows:?}");
    assert_eq!(rows[0]["textile"], "T030", "{rows:?}");
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("no-contact frame: "),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // `index inspect` says what an index's queries are made of.
    let features = |index: &str| {
        let v: serde_json::Value =
            serde_json::from_str(ok(d, &["index", "inspect", "--json", index]).trim())
                .expect("json");
        (v["features"].clone(), v["dim"].clone())
    };
    assert_eq!(features("p.tlxi"), ("encoder".into(), 64.into()));
    ok(
        d,
        &[
            "index",
            "build",
            "--model",
            model,
            "--presses",
            "index",
            "--features",
            "lbp-gabor",
            "-o",
            "lbp.tlxi",
        ],
    );
    assert_eq!(
        features("lbp.tlxi"),
        ("encoder + LBP + Gabor".into(), (64 + 28 + 9).into())
    );
    // A threshold far too low for this sensor (as a user may set it, the
    // same flag as the daemon's `contact_enter`): presses on nothing, a
    // failed check, and the footage kept for a report.
    let err = fails(
        d,
        &[
            "record",
            "--idle",
            "3",
            "--sensor",
            "sim",
            "--out",
            "rest",
            "--contact-enter",
            "0.0005",
        ],
    );
    assert!(err.contains("press(es) on the untouched sensor"), "{err}");
    assert!(d.join("rest/idle/0002/press.json").is_file());
    // Errors a user meets.
    let err = fails(
        d,
        &[
            "record",
            "--idle",
            "2",
            "--sensor",
            "sim",
            "--out",
            "rest",
            "--contact-frames",
            "0",
        ],
    );
    assert!(err.contains("out of range"), "{err}");
    let err = fails(
        d,
        &["record", "--idle", "0", "--sensor", "sim", "--out", "rest"],
    );
    assert!(err.contains("0 < SECONDS <= 600"), "{err}");
    let err = fails(
        d,
        &[
            "record",
            "--idle",
            "2",
            "--sensor",
            "replay:rest",
            "--out",
            "x",
        ],
    );
    assert!(err.contains("--idle records a live sensor"), "{err}");
}
