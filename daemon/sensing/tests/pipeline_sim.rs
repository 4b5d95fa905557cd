//! Whole pipeline on simulated presses with the real ONNX Runtime and the
//! fixture encoder: replayed recordings → contact → encode → index → decide.

mod common;

use telextiles_sensing::decide::{FlatIndex, TextileIndex};
use telextiles_sensing::encoder::Encoder;
use telextiles_sensing::pipeline::{run_source, Pipeline, PipelineConfig, PressReport};
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
use telextiles_sim::{Press, PressSpec};

const TEXTILES: [&str; 6] = ["T010", "T030", "T040", "T050", "T080", "T110"];

/// Index from one press per textile: the embeddings of its frames from
/// first contact on, as `index build` takes a press (seed 1); queries are
/// other presses (seed 2).
fn build_index(enc: &mut Encoder) -> FlatIndex {
    let sim = common::sim();
    let mut textiles = Vec::new();
    for id in TEXTILES {
        let p = sim.render_press(&PressSpec::new(id, 1)).unwrap();
        let contact = p.meta.params.as_ref().unwrap().contact_frame as usize;
        let embs = p.frames[contact..]
            .iter()
            .map(|f| enc.encode(f).unwrap().to_vec())
            .collect();
        textiles.push((id.to_string(), embs));
    }
    FlatIndex::from_embeddings(&textiles).unwrap()
}

fn classify(pipeline: &mut Pipeline<FlatIndex>, press: Press) -> Vec<PressReport> {
    let mut src = RecordedSource::from_press(press, Pace::AsFastAsPossible, "test");
    let mut reports = Vec::new();
    run_source(pipeline, &mut src, None, |r| reports.push(r)).unwrap();
    reports
}

#[test]
fn replayed_presses_of_several_textiles_resolve_to_the_right_textile() {
    let sim = common::sim();
    let mut enc = common::fixture_encoder();
    let index = build_index(&mut enc);
    let mut pipeline = Pipeline::new(
        enc,
        index,
        PipelineConfig::default(),
        Some(&telextiles_sensing::front::pixels_of(&sim.background(0))),
    )
    .unwrap();
    let mut wrong = Vec::new();
    for id in TEXTILES {
        // Through the on-disk format, as `classify --press` reads it.
        let dir = tempfile::tempdir().unwrap();
        let press = sim.render_press(&PressSpec::new(id, 2)).unwrap();
        let pdir = dir.path().join(id);
        telextiles_sim::recording::write_press(&pdir, &press).unwrap();
        let mut src = RecordedSource::open(&pdir, Pace::AsFastAsPossible).unwrap();
        let mut reports = Vec::new();
        run_source(&mut pipeline, &mut src, None, |r| reports.push(r)).unwrap();
        assert_eq!(
            reports.len(),
            1,
            "{id}: one press expected, got {reports:?}"
        );
        let r = &reports[0];
        let decided = r
            .textile
            .as_deref()
            .unwrap_or_else(|| panic!("{id}: no decision: {r:?}"));
        let slot = r.slot.unwrap();
        assert_eq!(
            pipeline.index().id(slot),
            decided,
            "slot of the decided textile"
        );
        assert!(r.decision_ms.unwrap() > 0.0 && r.decision_ms.unwrap() < r.duration_ms);
        for stage in ["preprocess", "encode", "search", "decide"] {
            assert!(r.stages[stage].frames > 0, "{stage} timed");
        }
        if decided != id {
            wrong.push((id, decided.to_string()));
        }
    }
    assert!(wrong.is_empty(), "misclassified presses: {wrong:?}");
}

#[test]
fn no_contact_means_no_decision() {
    let sim = common::sim();
    let mut enc = common::fixture_encoder();
    let index = build_index(&mut enc);
    let mut pipeline = Pipeline::new(enc, index, PipelineConfig::default(), None).unwrap();
    // Three seconds of the untouched sensor with camera noise: frame 0 of a
    // press whose contact starts late, repeated, plus the clean background.
    let spec = PressSpec::new("T030", 5);
    let first = sim.render_frame(&spec, 0).unwrap();
    let frames: Vec<_> = (0..180)
        .map(|i| {
            if i % 2 == 0 {
                first.clone()
            } else {
                sim.background(0)
            }
        })
        .collect();
    let meta = sim
        .press_meta(&PressSpec {
            frames: 180,
            ..spec
        })
        .unwrap();
    let reports = classify(&mut pipeline, Press { meta, frames });
    assert!(reports.is_empty(), "decisions without contact: {reports:?}");
}

#[test]
fn a_live_sim_source_follows_textile_changes_like_the_replayed_presses() {
    use telextiles_sensing::source::sim::SimSource;
    let sim = common::sim();
    let mut enc = common::fixture_encoder();
    let index = build_index(&mut enc);
    let mut pipeline = Pipeline::new(enc, index, PipelineConfig::default(), None).unwrap();
    let (mut src, handle) = SimSource::new(
        sim.clone(),
        PressSpec::new("T030", 2),
        20,
        Pace::AsFastAsPossible,
    )
    .unwrap();
    let mut live = Vec::new();
    let mut specs = vec![src.spec().clone()];
    // First press: 20 no-contact frames (the reference) + 150 press frames.
    run_source(&mut pipeline, &mut src, Some(170), |r| live.push(r)).unwrap();
    assert!(handle.set_textile("T110"));
    run_source(&mut pipeline, &mut src, Some(1), |r| live.push(r)).unwrap();
    specs.push(src.spec().clone());
    assert_eq!(specs[1].textile, "T110", "the change reached the source");
    run_source(&mut pipeline, &mut src, Some(169), |r| live.push(r)).unwrap();
    assert_eq!(live.len(), 2, "one press per textile: {live:#?}");
    // The same presses replayed from their recordings decide the same.
    let sim_bg = telextiles_sensing::front::pixels_of(&sim.background(0));
    for (spec, l) in specs.iter().zip(&live) {
        let mut enc = common::fixture_encoder();
        let index = build_index(&mut enc);
        let mut p = Pipeline::new(enc, index, PipelineConfig::default(), Some(&sim_bg)).unwrap();
        let r = classify(&mut p, sim.render_press(spec).unwrap());
        assert_eq!(r.len(), 1);
        assert_eq!(r[0].textile, l.textile, "live vs replayed {}", spec.textile);
    }
    assert_eq!(live[0].textile.as_deref(), Some("T030"));
    assert_eq!(live[1].textile.as_deref(), Some("T110"));
}

#[test]
fn injected_pixel_noise_does_not_make_the_decision_flip_flop() {
    use rand::{Rng, SeedableRng};
    let sim = common::sim();
    let mut enc = common::fixture_encoder();
    let index = build_index(&mut enc);
    let mut pipeline = Pipeline::new(
        enc,
        index,
        PipelineConfig::default(),
        Some(&telextiles_sensing::front::pixels_of(&sim.background(0))),
    )
    .unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for id in ["T030", "T110"] {
        let mut press = sim.render_press(&PressSpec::new(id, 2)).unwrap();
        // Heavy extra noise (+-8 grey levels) and two dropped-out frames.
        for f in press.frames.iter_mut() {
            for p in f.iter_mut() {
                *p = (*p as i32 + rng.gen_range(-8..=8)).clamp(0, 255) as u8;
            }
        }
        let n = press.frames.len();
        press.frames[n / 2] = image::RgbImage::new(240, 320);
        press.frames[n / 2 + 1] = image::RgbImage::new(240, 320);
        let reports = classify(&mut pipeline, press);
        // One press, decided once and never switched while it lasted; at
        // its end it may take the textile nearest its whole mean, once.
        // (Which textile: this much noise is beyond the fixture encoder,
        // whose high-pass front end amplifies pixel noise; it is not
        // asserted here.)
        assert_eq!(reports.len(), 1, "{id}: {reports:#?}");
        let r = &reports[0];
        assert!(r.textile.is_some(), "{id}: {reports:#?}");
        assert!(r.switches <= 1, "{id}: {reports:#?}");
        if r.switches == 1 {
            assert_eq!(r.stable_ms, Some(r.duration_ms), "{id}: {reports:#?}");
        }
    }
}

#[test]
fn an_idle_sim_source_presses_once_on_command_then_rests_and_lifts_on_command() {
    use telextiles_sensing::frame::Frame;
    use telextiles_sensing::source::sim::{SimCommand, SimSource};
    use telextiles_sensing::source::FrameSource;
    let sim = common::sim();
    let bg = sim.background(0);
    let (src, handle) = SimSource::new(
        sim.clone(),
        PressSpec::new("T030", 2),
        5,
        Pace::AsFastAsPossible,
    )
    .unwrap();
    let mut src = src.start_idle();
    let mut f = Frame::blank();
    // Resting: the sensor's own background give or take camera noise and
    // LED flicker (mean absolute difference under 4 levels); a press's
    // contact differs by far more.
    let mut is_bg = |src: &mut SimSource| {
        src.next_frame(&mut f).unwrap();
        let d: f64 = f
            .image()
            .as_raw()
            .iter()
            .zip(bg.as_raw())
            .map(|(a, b)| (*a as f64 - *b as f64).abs())
            .sum::<f64>()
            / bg.as_raw().len() as f64;
        d < 4.0
    };
    assert!((0..200).all(|_| is_bg(&mut src)), "idle: no contact at all");
    assert!(handle.send(SimCommand::PressOnce(PressSpec::new("T110", 3))));
    let frames: Vec<bool> = (0..400).map(|_| is_bg(&mut src)).collect();
    assert!(frames[..5].iter().all(|&b| b), "the gap comes first");
    let pressed = frames.iter().filter(|&&b| !b).count();
    assert!(pressed > 100, "the press happened ({pressed} frames)");
    assert!(
        frames[5 + 150..].iter().all(|&b| b),
        "then it rests, once only"
    );
    assert_eq!(src.presses(), 1);
    // A looping press is cut short by a lift.
    assert!(handle.set_textile("T030"));
    let _: Vec<bool> = (0..60).map(|_| is_bg(&mut src)).collect();
    assert!(handle.send(SimCommand::Lift));
    assert!((0..300).all(|_| is_bg(&mut src)), "lifted: rests");
}

/// A background-subtracting model in the pipeline: it learns the reference
/// from the untouched frames at the start of each recording (no reference
/// given) and then tells the textiles apart.
#[test]
fn a_background_subtracting_model_follows_the_untouched_frames() {
    let sim = common::sim();
    let open = || {
        Encoder::open(
            &common::fixture("fixture_subtract.onnx"),
            &telextiles_sensing::encoder::EncoderOptions::default(),
        )
        .unwrap()
    };
    let mut enc = open();
    let mut textiles = Vec::new();
    for id in TEXTILES {
        let p = sim.render_press(&PressSpec::new(id, 1)).unwrap();
        enc.set_reference(&p.frames[0]).unwrap();
        let contact = p.meta.params.as_ref().unwrap().contact_frame as usize;
        let embs = p.frames[contact..]
            .iter()
            .map(|f| enc.encode(f).unwrap().to_vec())
            .collect();
        textiles.push((id.to_string(), embs));
    }
    let index = FlatIndex::from_embeddings(&textiles).unwrap();
    let mut pipeline = Pipeline::new(open(), index, PipelineConfig::default(), None).unwrap();
    assert!(!pipeline.encoder().has_reference());
    let mut right = 0;
    for id in TEXTILES {
        let reports = classify(
            &mut pipeline,
            sim.render_press(&PressSpec::new(id, 2)).unwrap(),
        );
        assert!(pipeline.encoder().has_reference());
        assert_eq!(reports.len(), 1, "{id}: {reports:?}");
        right += (reports[0].textile.as_deref() == Some(id)) as usize;
    }
    assert!(right >= 5, "{right} of 6 right");
}

/// A live simulated sensor pressing one fabric after another (as the
/// demo's sender does: `PressOnce`, resting between) decides each press as
/// a fresh replay of that press does: the frames between presses look like
/// the resting sensor of the press (its noise and LED flicker), so nothing
/// of the lift or the last press reaches the next press's first decisions.
/// (With a noise-free background between presses, the first decisions of
/// the second and later presses were the previous fabric's.)
#[test]
fn the_frames_between_presses_look_like_the_presses_own() {
    use telextiles_sensing::source::sim::{SimCommand, SimSource};
    let sim = common::sim();
    let mut enc = common::fixture_encoder();
    let index = build_index(&mut enc);
    let specs: Vec<PressSpec> = ["T080", "T010", "T110", "T040"]
        .iter()
        .enumerate()
        .map(|(k, id)| PressSpec {
            person: k as u32,
            ..PressSpec::new(*id, 7 + 7919 * k as u64)
        })
        .collect();
    let first_of = |r: &[PressReport]| -> Vec<(Option<String>, Option<String>)> {
        r.iter()
            .map(|r| (r.first_textile.clone(), r.textile.clone()))
            .collect()
    };
    // One live source, resting between presses.
    let mut live = Vec::new();
    let (src, handle) =
        SimSource::new(sim.clone(), specs[0].clone(), 60, Pace::AsFastAsPossible).unwrap();
    let mut src = src.start_idle();
    let mut pipeline = Pipeline::new(enc, index.clone(), PipelineConfig::default(), None).unwrap();
    for spec in &specs {
        handle.send(SimCommand::PressOnce(spec.clone()));
        let frames = 60 + spec.frames as u64 + 120;
        run_source(&mut pipeline, &mut src, Some(frames), |r| live.push(r)).unwrap();
    }
    // Each press on its own, from a fresh source and pipeline.
    let mut fresh = Vec::new();
    let mut enc = Some(pipeline.into_encoder());
    for spec in &specs {
        let mut p = Pipeline::new(
            enc.take().unwrap(),
            index.clone(),
            PipelineConfig::default(),
            None,
        )
        .unwrap();
        let (mut s, _h) =
            SimSource::new(sim.clone(), spec.clone(), 20, Pace::AsFastAsPossible).unwrap();
        run_source(&mut p, &mut s, Some(20 + spec.frames as u64), |r| {
            fresh.push(r)
        })
        .unwrap();
        enc = Some(p.into_encoder());
    }
    assert_eq!(
        live.len(),
        specs.len(),
        "one press each: {:?}",
        first_of(&live)
    );
    assert_eq!(first_of(&live), first_of(&fresh));
    for (l, f) in live.iter().zip(&fresh) {
        let (a, b) = (l.decision_ms.unwrap(), f.decision_ms.unwrap());
        assert!((a - b).abs() < 0.01, "{:?}: {a} against {b} ms", l.textile);
    }
}
