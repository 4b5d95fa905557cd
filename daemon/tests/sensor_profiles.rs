//! Every sensor profile through the commands a user runs
//! (docs/sensors.md), with the real binary and the shipped encoder: a
//! GelSight-Mini-shaped recording (320x240 landscape at 25 fps) and a
//! DIGIT VGA one (640x480 at 30 fps) go through `record --sensor replay:`,
//! `index build --presses` and `classify` with no conversion by hand; an
//! index keeps one sensor's presses unless told to mix them.

use std::path::Path;
use std::process::{Command, Output};

use telextiles_recording::profile::{Mode, SensorProfile, DIGIT, GELSIGHT_MINI};

const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");
const MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/encoder.onnx");
const INDEX: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/index.tlxi");
const TEXTILES: [&str; 3] = ["T030", "T080", "T110"];

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

fn fails(dir: &Path, args: &[&str]) -> String {
    let out = run(dir, args);
    assert!(!out.status.success(), "telextilesd {args:?} succeeded");
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// Jig presses of every textile with these seeds, as `profile`'s camera
/// streams them in `mode`, under `root/<textile>/<seed>/`.
fn recordings(root: &Path, seeds: &[u64], profile: &SensorProfile, mode: Mode) {
    let sim = telextiles_sim::Simulator::new().expect("simulator");
    for t in TEXTILES {
        for &seed in seeds {
            let press = sim
                .render_press(&telextiles_sim::PressSpec::new(t, seed))
                .expect("press");
            let cam = telextiles_sim::camera::as_camera(&press, profile, mode).expect("camera");
            telextiles_recording::recording::write_press(
                &root.join(t).join(seed.to_string()),
                &cam,
            )
            .expect("write");
        }
    }
}

/// The textile each `classify --json` report decided, with the fabric its
/// recording's path names.
fn decided(out: &str) -> Vec<(String, String)> {
    out.lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).expect("json line");
            let src = v["source"].as_str().unwrap_or_default().to_string();
            let truth = TEXTILES
                .iter()
                .find(|t| src.contains(*t))
                .map_or(String::new(), |t| t.to_string());
            (truth, v["textile"].as_str().unwrap_or_default().to_string())
        })
        .collect()
}

/// Index (seeds 1, 2) and query (seed 3) recordings in `profile`'s
/// geometry under `d/raw/`, re-recorded by `record --sensor replay:` into
/// `d/rec/`.
fn record_both(d: &Path, profile: &SensorProfile, mode: Mode) {
    recordings(&d.join("raw/index"), &[1, 2], profile, mode);
    recordings(&d.join("raw/query"), &[3], profile, mode);
    for part in ["index", "query"] {
        ok(
            d,
            &[
                "record",
                "--sensor",
                &format!("replay:raw/{part}"),
                "--out",
                &format!("rec/{part}"),
            ],
        );
    }
}

fn read_meta(dir: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(dir.join("press.json")).expect("press.json"))
        .expect("json")
}

#[test]
fn a_gelsight_mini_recording_goes_through_record_index_and_classify() {
    let d = tempfile::tempdir().expect("tempdir");
    let d = d.path();
    let gs = GELSIGHT_MINI.modes[0];
    assert_eq!((gs.width, gs.height, gs.fps), (320, 240, 25.0));
    // Re-recorded as a user converts someone's recordings: each press
    // keeps its sensor, saved as frames at the frame's scale.
    record_both(d, &GELSIGHT_MINI, gs);
    let m = read_meta(&d.join("rec/index/T030/0001"));
    assert_eq!(m["sensor_profile"], "gelsight-mini", "{m}");
    assert_eq!(
        (m["width"].as_u64(), m["height"].as_u64()),
        (Some(240), Some(320)),
        "{m}"
    );
    assert!(
        (m["mm_per_px"].as_f64().unwrap() - 0.08).abs() < 1e-6,
        "{m}"
    );
    // 25 fps, from the recording's own timestamps.
    assert!((m["fps"].as_f64().unwrap() - 25.0).abs() < 0.5, "{m}");
    ok(
        d,
        &[
            "index",
            "build",
            "--model",
            MODEL,
            "--presses",
            "rec/index",
            "-o",
            "gs.tlxi",
        ],
    );
    let index = telextiles_index::Index::read(&d.join("gs.tlxi")).expect("index");
    assert_eq!(index.sensor.as_deref(), Some("gelsight-mini"));
    // The re-recorded presses and the camera's own recordings decide alike.
    for press in ["rec/query", "raw/query"] {
        let out = ok(
            d,
            &[
                "classify", "--model", MODEL, "--index", "gs.tlxi", "--json", "--press", press,
            ],
        );
        let got = decided(&out);
        assert_eq!(got.len(), TEXTILES.len(), "{out}");
        for (truth, textile) in &got {
            assert_eq!(truth, textile, "{press}: {got:?}");
        }
    }
    // A DIGIT's presses against it are refused by name; the shipped
    // index, a DIGIT's, refuses the GelSight's.
    recordings(&d.join("vga"), &[3], &DIGIT, DIGIT.modes[2]);
    let e = fails(
        d,
        &[
            "classify", "--model", MODEL, "--index", "gs.tlxi", "--press", "vga",
        ],
    );
    assert!(
        e.contains("gelsight-mini sensor") && e.contains("from a digit"),
        "{e}"
    );
    let e = fails(
        d,
        &[
            "classify",
            "--model",
            MODEL,
            "--index",
            INDEX,
            "--press",
            "rec/query",
        ],
    );
    assert!(
        e.contains("digit sensor") && e.contains("from a gelsight-mini"),
        "{e}"
    );
    // Both sensors' presses in one index: refused, unless mixed.
    recordings(&d.join("rec/index-vga"), &[1], &DIGIT, DIGIT.modes[2]);
    let e = fails(
        d,
        &[
            "index",
            "build",
            "--model",
            MODEL,
            "--presses",
            "rec",
            "-o",
            "mixed.tlxi",
        ],
    );
    assert!(
        e.contains("2 sensor profiles") && e.contains("--mix-sensors"),
        "{e}"
    );
    ok(
        d,
        &[
            "index",
            "build",
            "--model",
            MODEL,
            "--presses",
            "rec",
            "--mix-sensors",
            "-o",
            "mixed.tlxi",
        ],
    );
    let mixed = telextiles_index::Index::read(&d.join("mixed.tlxi")).expect("index");
    assert_eq!(mixed.sensor.as_deref(), Some("mixed:digit+gelsight-mini"));
}

#[test]
fn a_digit_vga_recording_goes_through_record_index_and_classify() {
    let d = tempfile::tempdir().expect("tempdir");
    let d = d.path();
    let vga = DIGIT.modes[2];
    assert_eq!((vga.width, vga.height, vga.fps), (640, 480, 30.0));
    record_both(d, &DIGIT, vga);
    let m = read_meta(&d.join("rec/query/T080/0001"));
    // A DIGIT's press, at 30 fps: nothing to say about its sensor.
    assert!(m.get("sensor_profile").is_none(), "{m}");
    assert!((m["fps"].as_f64().unwrap() - 30.0).abs() < 0.5, "{m}");
    ok(
        d,
        &[
            "index",
            "build",
            "--model",
            MODEL,
            "--presses",
            "rec/index",
            "-o",
            "vga.tlxi",
        ],
    );
    let index = telextiles_index::Index::read(&d.join("vga.tlxi")).expect("index");
    assert_eq!(index.sensor, None);
    // VGA presses against the VGA index, and against the shipped one
    // (a DIGIT's QVGA presses): the same fabric either way.
    for idx in ["vga.tlxi", INDEX] {
        let out = ok(
            d,
            &[
                "classify",
                "--model",
                MODEL,
                "--index",
                idx,
                "--json",
                "--press",
                "rec/query",
            ],
        );
        let got = decided(&out);
        assert_eq!(got.len(), TEXTILES.len(), "{out}");
        for (truth, textile) in &got {
            assert_eq!(truth, textile, "{idx}: {got:?}");
        }
    }
    // A sensor profile given for recordings that name their own is
    // refused, naming both.
    let e = fails(
        d,
        &[
            "classify",
            "--model",
            MODEL,
            "--index",
            "vga.tlxi",
            "--press",
            "raw/query",
            "--sensor-profile",
            "gelsight-mini",
        ],
    );
    assert!(
        e.contains("made by a DIGIT") && e.contains("GelSight Mini given"),
        "{e}"
    );
    let e = fails(
        d,
        &[
            "classify",
            "--model",
            MODEL,
            "--index",
            "vga.tlxi",
            "--press",
            "raw/query",
            "--sensor-profile",
            "uvc",
        ],
    );
    assert!(e.contains("--sensor-mm-per-px"), "{e}");
}
