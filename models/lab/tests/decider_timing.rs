//! `telextiles-lab decider-timing` end to end on three simulated textiles
//! with the shipped model (the committed figures come from the full run,
//! docs/benchmarks.md "When the decider commits"): whole presses rendered,
//! through the daemon's front end and decider, for every candidate pair.

use telextiles_lab::decider_timing::{self, candidates, StudyConfig, Timing};
use telextiles_lab::methods::Method;
use telextiles_lab::protocol::Protocol;

#[test]
fn the_timing_study_runs_end_to_end_on_simulated_presses() {
    let dir = tempfile::tempdir().unwrap();
    let mut p = Protocol::paper(64, 64);
    p.max_textiles = Some(3);
    let model = concat!(env!("CARGO_MANIFEST_DIR"), "/../encoder.onnx");
    let m = Method::onnx("shipped", std::fs::read(model).unwrap()).unwrap();
    let cfg = StudyConfig {
        protocol: p,
        cache_dir: dir.path().join("cache"),
        people: 1,
        threads: 2,
        contact: Default::default(),
    };
    let r = decider_timing::run(&cfg, &m).unwrap();
    assert_eq!(r.scores.len(), 2 * candidates().len());
    assert!(candidates().contains(&r.chosen));
    for (g, t) in &r.detect_ms_p50 {
        // The detector starts a press after its first contact, within the
        // ramp.
        assert!(*t > 0.0 && *t < 300.0, "{g}: {t}");
    }
    let get = |min_ms: f32, confirm_ms: f32, run: bool, g: &str| {
        let t = Timing::pair(min_ms, confirm_ms, run);
        r.scores
            .iter()
            .find(|s| s.timing == t && s.group == g)
            .unwrap()
    };
    for g in ["jig", "hand-held"] {
        let (old, new) = (get(50.0, 50.0, false, g), get(0.0, 50.0, false, g));
        assert_eq!((old.presses, new.presses), (3, 3));
        // Counting from the first frame never decides later: the run that
        // confirms after a 50 ms minimum confirms without it too.
        assert!(new.first_ms_p50 <= old.first_ms_p50, "{g}: {new:?} {old:?}");
        // The earliest possible first decision: the detector's start, its
        // second frame (17 ms), then 100 ms with the old pair.
        let detect = r.detect_ms_p50.iter().find(|x| x.0 == g).unwrap().1;
        assert!(
            old.first_ms_p50 >= detect + 17.0 + 100.0 - 1.0,
            "{g}: {old:?}"
        );
        assert_eq!(old.right(100.0), 0.0, "{g}: nothing commits within 100 ms");
        // With the run that starts a press encoded, embeddings begin at the
        // detector's start rather than two frames later: never a later
        // first decision, and never one before the start + 50 ms.
        let run = get(0.0, 50.0, true, g);
        assert!(run.first_ms_p50 <= new.first_ms_p50, "{g}: {run:?} {new:?}");
        assert!(run.first_ms_p50 >= detect + 50.0 - 1.0, "{g}: {run:?}");
        // An early commit on a clear lead never decides later than the
        // confirmation alone, and never before the second encoded frame
        // (the detector's start + 17 ms).
        let early = r
            .scores
            .iter()
            .find(|s| s.timing == Timing::shipped() && s.group == g)
            .unwrap();
        assert!(early.first_ms_p50 <= new.first_ms_p50, "{g}: {early:?}");
        assert!(early.first_ms_p50 >= detect + 16.0, "{g}: {early:?}");
    }
    // Three textiles in the jig: the shipped model tells them apart.
    assert!(get(0.0, 50.0, true, "jig").final_right >= 2.0 / 3.0);
    // The switching rules, scored at the shipped timing, the shipped one
    // first.
    let sw = decider_timing::switch_candidates(Timing::shipped());
    assert_eq!(r.switch_candidates, sw);
    assert_eq!(r.switch_scores.len(), 2 * sw.len());
    assert!(sw.contains(&r.switch_chosen.unwrap()));
    let md = decider_timing::markdown(&r);
    assert!(md.contains("## Switching rules at"), "{md}");
    assert!(
        md.contains("## jig (3 presses)") && md.contains("## hand-held (3 presses)"),
        "{md}"
    );
}
