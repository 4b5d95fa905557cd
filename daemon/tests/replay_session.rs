//! `--sensor replay:<dir>` in a live session (real `telextilesd run`
//! processes, real QUIC on loopback): A replays a directory of recordings,
//! one after another and round again, B decides them. Each recording is
//! one press, decided as its own fabric, in order: the front end starts
//! afresh on each recording with the recording's own reference, and a
//! recording that ends in contact ends its press there. The recordings
//! come from three sensor units, whose no-contact frames differ. A
//! recording that cannot be read is skipped, said, and counted as such
//! (`recordings_skipped`), not as bad frames.
#[path = "harness/mod.rs"]
mod harness;

use harness::*;
use std::time::{Duration, Instant};
use telextiles_control::Event;

#[test]
fn a_directory_of_recordings_replays_as_one_press_each_in_order() {
    let sim = telextiles_sim::Simulator::new().unwrap();
    let rec = tempfile::tempdir().unwrap();
    // A held-out person's jig presses on three units; the second is cut
    // while still in contact (no release).
    let plan = [("T030", 0, true), ("T061", 1, false), ("T090", 2, true)];
    for (k, (textile, unit, release)) in plan.iter().enumerate() {
        let spec = telextiles_sim::PressSpec {
            person: 9,
            sensor: *unit,
            jig: true,
            release: Some(*release),
            ..telextiles_sim::PressSpec::new(*textile, 11 + k as u64)
        };
        let press = sim.render_press(&spec).unwrap();
        let dir = rec.path().join(format!("{k}-{textile}"));
        telextiles_sim::recording::write_press(&dir, &press).unwrap();
    }
    // A recording that cannot be read, between the second and the third.
    let broken = rec.path().join("1a-broken");
    std::fs::create_dir_all(&broken).unwrap();
    std::fs::write(broken.join("press.json"), "{ not json").unwrap();
    let setup = Setup {
        sensors: (
            format!("replay:{}", rec.path().display()),
            "sim:T047".into(),
        ),
        ..Setup::default()
    };
    let textiles: Vec<&str> = plan.iter().map(|p| p.0).collect();
    replays_in_order(
        &setup,
        &textiles,
        &["1a-broken"],
        "one press per recording, each decided as its fabric, in order",
    );
}

/// A PyTouch-style dataset (`<class>/<serial>/*.png`) cut to the press,
/// as shared datasets are: no recording carries a no-contact frame, each
/// starts with the fabric held and ends before the release; one unit's
/// frames and no-contact frame are JPEG. With `--reference SERIAL=PNG` for each
/// sensor, as a DIGIT owner gives them, each sequence is replayed against
/// its own unit's frame and decided as its fabric. (Without them the front
/// end takes the pressed first frames as the reference and sees no press:
/// this test then times out with no final decision.)
#[test]
fn a_pytouch_dataset_cut_to_contact_replays_with_the_references_given_for_its_sensors() {
    let sim = telextiles_sim::Simulator::new().unwrap();
    let rec = tempfile::tempdir().unwrap();
    let data = rec.path().join("data");
    let plan = [("T030", 0), ("T061", 1), ("T090", 2)];
    let mut flags = Vec::new();
    for (k, (textile, unit)) in plan.iter().enumerate() {
        let spec = telextiles_sim::PressSpec {
            person: 9,
            sensor: *unit,
            jig: true,
            release: Some(false),
            ..telextiles_sim::PressSpec::new(*textile, 21 + k as u64)
        };
        let press = sim.render_press(&spec).unwrap();
        assert!(
            press.meta.reference_frames.unwrap() > 0,
            "the simulated press starts untouched"
        );
        // Cut to the press: from the frame the fabric is held at.
        let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
        let serial = format!("D0000{unit}");
        let dir = data.join(textile).join(&serial);
        std::fs::create_dir_all(&dir).unwrap();
        // The second unit's frames and reference are JPEG, as many
        // datasets store them.
        let ext = if *unit == 1 { "jpg" } else { "png" };
        for (i, frame) in press.frames[hold..].iter().enumerate() {
            frame.save(dir.join(format!("{i:04}.{ext}"))).unwrap();
        }
        // One untouched frame of the unit, as an owner would take it.
        let png = rec.path().join(format!("{serial}.{ext}"));
        press.frames[0].save(&png).unwrap();
        flags.extend([
            "--reference".to_string(),
            format!("{serial}={}", png.display()),
        ]);
    }
    let setup = Setup {
        sensors: (format!("replay:{}", data.display()), "sim:T047".into()),
        flags: (flags, Vec::new()),
        ..Setup::default()
    };
    let textiles: Vec<&str> = plan.iter().map(|p| p.0).collect();
    replays_in_order(
        &setup,
        &textiles,
        &[],
        "one press per sequence, each decided as its fabric against its unit's reference",
    );
}

/// A live pair of GelSight Mini owners (docs/sensors.md): both daemons
/// hold an index built from GelSight-Mini-shaped presses (320x240
/// landscape at 25 fps, as the camera streams them) and A replays such
/// recordings, with no conversion by hand; B decides each as its fabric,
/// in order. The same for a DIGIT streaming VGA at 30 fps.
#[test]
fn a_live_pair_of_other_sensors_decides_their_presses() {
    use telextiles_recording::profile::{DIGIT, GELSIGHT_MINI};
    let sim = telextiles_sim::Simulator::new().unwrap();
    let textiles = ["T030", "T061", "T090"];
    for (profile, mode) in [
        (&GELSIGHT_MINI, GELSIGHT_MINI.modes[0]),
        (&DIGIT, DIGIT.modes[2]),
    ] {
        let work = tempfile::tempdir().unwrap();
        for (k, t) in textiles.iter().enumerate() {
            for seed in [1u64, 2, 40 + k as u64] {
                let press = sim
                    .render_press(&telextiles_sim::PressSpec::new(*t, seed))
                    .unwrap();
                let cam = telextiles_sim::camera::as_camera(&press, profile, mode).unwrap();
                // Seeds 1 and 2 build the index; the third is replayed.
                let dir = if seed < 40 {
                    work.path().join("index").join(t).join(seed.to_string())
                } else {
                    work.path().join("replay").join(format!("{k}-{t}"))
                };
                telextiles_sim::recording::write_press(&dir, &cam).unwrap();
            }
        }
        let index = work.path().join("index.tlxi");
        let out = std::process::Command::new(harness::BIN)
            .args(["index", "build", "--model", harness::MODEL, "--presses"])
            .arg(work.path().join("index"))
            .arg("-o")
            .arg(&index)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let replay = format!("replay:{}", work.path().join("replay").display());
        let flags = vec!["--index".to_string(), index.display().to_string()];
        let setup = Setup {
            sensors: (replay.clone(), replay),
            flags: (flags.clone(), flags),
            ..Setup::default()
        };
        replays_in_order(
            &setup,
            &textiles,
            &[],
            &format!(
                "{} {mode} recordings, decided by B against their own index",
                profile.label
            ),
        );
    }
}

/// A live pair whose index holds texture features beside the encoder's
/// embedding (`index build --features lbp-gabor`, as an owner builds one):
/// both daemons compute them because the index says so, the latents carry
/// them, and B decides each of A's presses as the fabric A presses.
#[test]
fn a_live_pair_decides_with_an_index_of_texture_features() {
    let sim = telextiles_sim::Simulator::new().unwrap();
    let work = tempfile::tempdir().unwrap();
    let presses = work.path().join("presses");
    for id in ["T012", "T047", "T030", "T080"] {
        for seed in [1u64, 2] {
            let p = sim
                .render_press(&telextiles_sim::PressSpec::new(id, seed))
                .unwrap();
            telextiles_sim::recording::write_press(&presses.join(id).join(format!("{seed}")), &p)
                .unwrap();
        }
    }
    let index = work.path().join("features.tlxi");
    let out = std::process::Command::new(harness::BIN)
        .args(["index", "build", "--model", harness::MODEL, "--presses"])
        .arg(&presses)
        .args(["--features", "lbp-gabor", "-o"])
        .arg(&index)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let built = telextiles_index::Index::read(&index).unwrap();
    assert_eq!(built.features, telextiles_index::Features::EncoderLbpGabor);
    let flags = vec!["--index".to_string(), index.display().to_string()];
    let setup = Setup {
        flags: (flags.clone(), flags),
        ..Setup::default()
    };
    replays_in_order(
        &setup,
        &["T012"],
        &[],
        "A's simulated presses of T012, decided by B against an index of texture features",
    );
}

/// The decision-speed settings reach a live pair as `classify` replays
/// them: A replays recordings with `--encode-run`, B decides with
/// `--commit-margin 2`, and B's first decision of each press (its
/// textile, and its time after the press's start in capture time,
/// `since_contact_ms - latency_ms`) is the one `classify --encode-run
/// --commit-margin 2` gives on the same recordings, which neither setting
/// alone gives.
#[test]
fn the_decision_speed_settings_reach_a_live_pair_as_classify_replays_them() {
    // A margin of 2 never commits early: B waits for the timing rules,
    // which A's encoded run starts a frame sooner. Each setting alone
    // gives other decisions, so the pair's match shows both arrived.
    live_first_decisions_as_classify(
        (
            vec!["--encode-run".into()],
            vec!["--commit-margin".into(), "2".into()],
        ),
        &["--encode-run", "--commit-margin", "2"],
        &[&[], &["--encode-run"], &["--commit-margin", "2"]],
    );
}

/// With the shipped settings the run that starts a press is not encoded,
/// and the press still begins at its first frame: B times its decisions
/// from there, as `classify` does. (Before, the press began at the frame
/// the detector fired on, and every live decision was a frame sooner
/// after the start than `classify` said: 16.7 ms at 60 fps.)
#[test]
fn with_the_shipped_settings_live_decisions_are_timed_from_the_detectors_start_as_classify_times_them(
) {
    live_first_decisions_as_classify((Vec::new(), Vec::new()), &[], &[]);
}

/// A replays three hand-held recordings to B with `flags` (A's, B's); B's
/// first decision of every press in two whole rounds (its textile, and its
/// time after the press's start in capture time, `since_contact_ms -
/// latency_ms`) is the one `classify` gives with `classify_flags`, to
/// 2 µs; `classify` with each of `others` gives other first decisions.
fn live_first_decisions_as_classify(
    flags: (Vec<String>, Vec<String>),
    classify_flags: &[&str],
    others: &[&[&str]],
) {
    let sim = telextiles_sim::Simulator::new().unwrap();
    let rec = tempfile::tempdir().unwrap();
    // Hand-held presses on three units, each released.
    let plan = [("T030", 0), ("T061", 1), ("T090", 2)];
    for (k, (textile, unit)) in plan.iter().enumerate() {
        let spec = telextiles_sim::PressSpec {
            person: 9,
            sensor: *unit,
            jig: false,
            release: Some(true),
            ..telextiles_sim::PressSpec::new(*textile, 31 + k as u64)
        };
        let press = sim.render_press(&spec).unwrap();
        telextiles_sim::recording::write_press(&rec.path().join(format!("{k}-{textile}")), &press)
            .unwrap();
    }
    // Each press's first decision and its ms after the press's start.
    let classify = |flags: &[&str]| -> Vec<(String, f64)> {
        let out = std::process::Command::new(BIN)
            .args([
                "classify", "--model", MODEL, "--index", INDEX, "--json", "--press",
            ])
            .arg(rec.path())
            .args(flags)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout)
            .unwrap()
            .lines()
            .map(|l| {
                let v: serde_json::Value = serde_json::from_str(l).unwrap();
                (
                    v["first_textile"].as_str().unwrap().to_string(),
                    v["decision_ms"].as_f64().unwrap(),
                )
            })
            .collect()
    };
    let want = classify(classify_flags);
    assert_eq!(want.len(), plan.len(), "{want:?}");
    for other in others {
        assert_ne!(
            want,
            classify(other),
            "{other:?} changes these presses' first decisions"
        );
    }
    let setup = Setup {
        sensors: (
            format!("replay:{}", rec.path().display()),
            "sim:T047".into(),
        ),
        flags,
        ..Setup::default()
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let pair = rt.block_on(Pair::start(&setup));
    let same = |a: &[(String, f64)], b: &[(String, f64)]| {
        a.len() == b.len()
            && a.iter()
                .zip(b)
                .all(|(x, y)| x.0 == y.0 && (x.1 - y.1).abs() < 0.002)
    };
    let t0 = Instant::now();
    let live = loop {
        // B's first decision of each of A's presses, in press order.
        let mut firsts = std::collections::BTreeMap::new();
        for (_, e) in pair.b.events.lock().unwrap().iter() {
            if let Event::Decision {
                textile,
                peer: Some(_),
                press: Some(id),
                final_decision: false,
                since_contact_ms: Some(since),
                latency_ms,
                ..
            } = e
            {
                firsts
                    .entry(*id)
                    .or_insert((textile.clone(), since - latency_ms));
            }
        }
        let firsts: Vec<(String, f64)> = firsts.into_values().collect();
        // Two whole rounds of the replay after the first press B saw (which
        // may have begun before B was connected), from the first press of
        // a round on: every one as classify decides it, to the µs. (With
        // the sensing thread's arrival times as capture times, one press in
        // three came a frame later.)
        let start = firsts
            .iter()
            .skip(1)
            .position(|f| f.0 == want[0].0)
            .map(|i| i + 1);
        if let Some(k) = start.filter(|k| firsts.len() >= k + 2 * want.len()) {
            let rounds = &firsts[k..k + 2 * want.len()];
            assert!(
                rounds.chunks(want.len()).all(|r| same(r, &want)),
                "live first decisions {rounds:?}, classify {want:?}"
            );
            break firsts;
        }
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "live first decisions {firsts:?}, classify {want:?}\nA's log:\n{}",
            std::fs::read_to_string(&pair.a.log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    eprintln!("live first decisions {live:?}\nclassify {classify_flags:?}: {want:?}");
    let (_, _, _a, _b) = pair.stop();
}

/// Runs the pair until B has decided two whole rounds of A's replay, and
/// checks that B's final decisions are `textiles` twice, in order, and
/// that A's sensor and encoder raised no error but the skipping of the
/// recordings named in `skipped` (each round), counted as skipped
/// recordings and not as bad frames.
fn replays_in_order(setup: &Setup, textiles: &[&str], skipped: &[&str], why: &str) {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let pair = rt.block_on(Pair::start(setup));
    let want: Vec<&str> = textiles.iter().chain(textiles).copied().collect();
    let finals = finals_from(&pair, &want);
    let (n_skipped, bad_frames) = rt.block_on(async {
        (
            counter(&pair.a, "recordings_skipped").await,
            counter(&pair.a, "bad_frames").await,
        )
    });
    let (_, _, a, b) = pair.stop();
    assert_eq!(finals, want, "{why}");
    // Two whole rounds went by, so each was skipped twice at least.
    assert!(
        n_skipped >= 2 * skipped.len() as u64 && (n_skipped == 0) == skipped.is_empty(),
        "{n_skipped} recordings skipped, {skipped:?} expected"
    );
    assert_eq!(bad_frames, 0, "a skipped recording is not a bad frame");
    let sensor_errors: Vec<_> = errors(&a)
        .into_iter()
        .filter(|(_, m)| m.starts_with("sensor") || m.starts_with("encoder"))
        .collect();
    let (said, other): (Vec<_>, Vec<_>) = sensor_errors.iter().partition(|(_, m)| {
        m.starts_with("sensor: skipping recording ") && skipped.iter().any(|k| m.contains(k))
    });
    assert!(other.is_empty(), "{other:?}");
    assert_eq!(said.is_empty(), skipped.is_empty(), "each skip is said");
    drop(b);
}

/// B's final decisions of A's presses from the first `want[0]` on, once
/// `want.len()` of them have come (the first may have gone before B was
/// connected); fails after 90 s with what came and A's log.
fn finals_from(pair: &Pair, want: &[&str]) -> Vec<String> {
    let t0 = Instant::now();
    loop {
        let finals: Vec<String> = pair
            .b
            .events
            .lock()
            .unwrap()
            .iter()
            .filter_map(|(_, e)| match e {
                Event::Decision {
                    textile,
                    peer: Some(_),
                    final_decision: true,
                    ..
                } => Some(textile.clone()),
                _ => None,
            })
            .collect();
        let first = finals.iter().position(|t| t == want[0]);
        if let Some(i) = first.filter(|i| finals.len() >= i + want.len()) {
            return finals[i..i + want.len()].to_vec();
        }
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "final decisions so far: {finals:?}\nA's log:\n{}",
            std::fs::read_to_string(&pair.a.log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    }
}
