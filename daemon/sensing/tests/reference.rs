//! The no-contact reference, live and on replay: captured on steady
//! frames, renewed after each release, re-captured after a lighting change
//! or when it was captured touched, shared by the contact detector and the
//! encoder, and never carried from one recording to the next.

mod common;

use image::RgbImage;
use telextiles_sensing::contact::{ContactConfig, ContactDetector, ContactEvent};
use telextiles_sensing::decide::FlatIndex;
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sensing::frame::Frame;
use telextiles_sensing::front::{pixels_of, recording_reference, FrontEnd};
use telextiles_sensing::pipeline::{run_source, Pipeline, PipelineConfig, PressReport};
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
use telextiles_sim::{Press, PressSpec};

const PERIOD: u64 = 16_667;

/// The default configuration with the lighting check on, on the plain
/// score (with gain compensation a lighting step scores as noise, and the
/// check has nothing to do).
fn lighting_on() -> ContactConfig {
    ContactConfig {
        lighting_check: true,
        gain_compensated: false,
        ..Default::default()
    }
}

/// Multiply each channel (an LED brighter or dimmer).
fn gain(img: &RgbImage, g: [f32; 3]) -> RgbImage {
    let mut out = img.clone();
    for p in out.pixels_mut() {
        for (v, g) in p.0.iter_mut().zip(g) {
            *v = (*v as f32 * g).round().clamp(0.0, 255.0) as u8;
        }
    }
    out
}

/// Feed frames, returning (frame number, event) for every event.
fn feed(det: &mut ContactDetector, frames: &[RgbImage], t: &mut u64) -> Vec<(usize, ContactEvent)> {
    let mut out = Vec::new();
    for (i, f) in frames.iter().enumerate() {
        *t += PERIOD;
        if let Some(e) = det.update(f, *t).event {
            out.push((i, e));
        }
    }
    out
}

fn starts(ev: &[(usize, ContactEvent)]) -> usize {
    ev.iter()
        .filter(|(_, e)| matches!(e, ContactEvent::PressStart { .. }))
        .count()
}

fn rejected(ev: &[(usize, ContactEvent)]) -> usize {
    ev.iter()
        .filter(|(_, e)| matches!(e, ContactEvent::ReferenceRejected { .. }))
        .count()
}

fn max_abs_diff(a: &[f32], b: &RgbImage) -> f32 {
    a.iter()
        .zip(b.as_raw())
        .map(|(x, &y)| (x - y as f32).abs())
        .fold(0.0, f32::max)
}

#[test]
fn a_lighting_step_recaptures_the_reference_instead_of_starting_a_press() {
    let sim = common::sim();
    let bg = sim.background(0);
    let mut det = ContactDetector::with_reference(lighting_on(), &bg);
    let mut t = 0;
    // The red LED 6 % brighter, the blue one 4 % dimmer: far above the
    // contact threshold as a raw difference.
    let g = [1.06, 1.0, 0.96];
    let lit = gain(&bg, g);
    assert!(det.score(&lit) > 1.0, "the step must look like contact");
    let ev = feed(&mut det, &vec![lit.clone(); 40], &mut t);
    assert_eq!(starts(&ev), 0, "{ev:?}");
    assert_eq!(rejected(&ev), 1, "{ev:?}");
    assert!(
        ev.iter()
            .any(|(_, e)| matches!(e, ContactEvent::ReferenceCaptured { .. })),
        "{ev:?}"
    );
    assert!(max_abs_diff(det.reference_pixels().unwrap(), &lit) < 1.0);
    // A real press under the new lighting still starts.
    let press = sim.render_press(&PressSpec::new("T030", 1)).unwrap();
    let frames: Vec<RgbImage> = press.frames.iter().map(|f| gain(f, g)).collect();
    let ev = feed(&mut det, &frames, &mut t);
    assert_eq!(starts(&ev), 1, "{ev:?}");
    assert_eq!(rejected(&ev), 0, "{ev:?}");
    // The shipped detector scores what a per-channel gain leaves: the step
    // is noise to it, nothing starts and nothing needs re-capturing, and
    // the press under the new lighting starts all the same.
    let mut det = ContactDetector::with_reference(ContactConfig::default(), &bg);
    // (what is left is rounding, and the few values clipped at 255)
    assert!(det.score(&lit) < 0.2, "{}", det.score(&lit));
    let mut t = 0;
    let ev = feed(&mut det, &vec![lit.clone(); 40], &mut t);
    assert_eq!(starts(&ev) + rejected(&ev), 0, "{ev:?}");
    let ev = feed(&mut det, &frames, &mut t);
    assert_eq!(starts(&ev), 1, "{ev:?}");
}

/// `img` with a ±`dn` checkerboard of 4 px squares in the 40 px square
/// whose corner is (`x0`, `y0`): a touch at one place.
fn touch_at(img: &RgbImage, x0: u32, y0: u32, dn: f32) -> RgbImage {
    let mut out = img.clone();
    for y in y0..y0 + 40 {
        for x in x0..x0 + 40 {
            let s = if (x / 4 + y / 4) % 2 == 0 { dn } else { -dn };
            for v in out.get_pixel_mut(x, y).0.iter_mut() {
                *v = (*v as f32 + s).round().clamp(0.0, 255.0) as u8;
            }
        }
    }
    out
}

#[test]
fn a_touch_in_one_place_starts_a_press_on_its_tile_and_is_not_taken_for_lighting() {
    let sim = common::sim();
    let bg = sim.background(0);
    let touch = touch_at(&bg, 120, 160, 4.0);
    // Over the whole frame the touch is a 48th of its change: under the
    // threshold, no press.
    let mut whole = ContactDetector::with_reference(ContactConfig::default(), &bg);
    assert!(whole.score(&touch) < 0.35, "{}", whole.score(&touch));
    let up = ContactDetector::with_reference(ContactConfig::default(), &bg).update(&touch, PERIOD);
    assert_eq!(up.depth, up.score);
    let mut t = 0;
    assert_eq!(
        starts(&feed(&mut whole, &vec![touch.clone(); 20], &mut t)),
        0
    );
    // Its 40 px tile holds all of it: a press, also with the lighting
    // check on (which must compare the same region: over the whole frame
    // the touch is small, and would pass for what a gain leaves).
    for cfg in [
        ContactConfig {
            tile: 10,
            ..Default::default()
        },
        ContactConfig {
            tile: 10,
            ..lighting_on()
        },
    ] {
        let mut det = ContactDetector::with_reference(cfg.clone(), &bg);
        assert!(det.score(&touch) > 3.0, "{cfg:?}: {}", det.score(&touch));
        // It scores high and is shallow: the weight of the frame in a
        // press's mean comes from the whole frame.
        let up = ContactDetector::with_reference(cfg.clone(), &bg).update(&touch, PERIOD);
        assert!(up.score > 3.0 && up.depth < 0.2, "{up:?}");
        let mut t = 0;
        let ev = feed(&mut det, &vec![touch.clone(); 20], &mut t);
        assert_eq!((starts(&ev), rejected(&ev)), (1, 0), "{cfg:?}: {ev:?}");
        // A lighting step is still nothing to the gain-compensated tile
        // score, and still a lighting change to the plain one's check.
        let mut det = ContactDetector::with_reference(cfg.clone(), &bg);
        let lit = gain(&bg, [1.06, 1.0, 0.96]);
        let ev = feed(&mut det, &vec![lit; 40], &mut t);
        assert_eq!(starts(&ev), 0, "{cfg:?}: {ev:?}");
        assert_eq!(
            rejected(&ev),
            cfg.lighting_check as usize,
            "{cfg:?}: {ev:?}"
        );
    }
}

#[test]
fn simulated_presses_are_never_taken_for_lighting_changes_or_touched_references() {
    // Jig and hand-held presses by several people on several units: every
    // one starts exactly once, none is rejected.
    let sim = common::sim();
    let mut n = 0;
    for (k, id) in [
        "T003", "T017", "T030", "T052", "T071", "T088", "T104", "T119",
    ]
    .iter()
    .enumerate()
    {
        for jig in [true, false] {
            let spec = PressSpec {
                person: k as u32 % 11,
                sensor: k as u32 % 6,
                jig,
                ..PressSpec::new(*id, 7 + k as u64)
            };
            let press = sim.render_press(&spec).unwrap();
            let reference = recording_reference(&press).unwrap();
            let mut det = ContactDetector::with_reference_pixels(lighting_on(), &reference);
            let mut t = 0;
            let ev = feed(&mut det, &press.frames, &mut t);
            assert_eq!(starts(&ev), 1, "{spec:?}: {ev:?}");
            assert_eq!(rejected(&ev), 0, "{spec:?}: {ev:?}");
            n += 1;
        }
    }
    assert_eq!(n, 16);
}

#[test]
fn a_press_held_at_start_up_is_not_taken_for_the_reference() {
    let sim = common::sim();
    let spec = PressSpec {
        release: Some(false),
        ..PressSpec::new("T088", 3)
    };
    let press = sim.render_press(&spec).unwrap();
    let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
    let bg = sim.background(0);
    let mut det = ContactDetector::new(ContactConfig::default());
    let mut t = 0;
    // The daemon starts while the fabric is held on the sensor: the
    // reference is captured from touched frames.
    let ev = feed(&mut det, &press.frames[hold..], &mut t);
    assert_eq!(starts(&ev), 0, "{ev:?}");
    assert!(det.reference_pixels().is_some());
    // Lifting it is not a press; the reference is re-captured untouched.
    let ev = feed(&mut det, &vec![bg.clone(); 30], &mut t);
    assert_eq!(starts(&ev), 0, "{ev:?}");
    assert_eq!(rejected(&ev), 1, "{ev:?}");
    assert!(max_abs_diff(det.reference_pixels().unwrap(), &bg) < 1.0);
    // The next press is a press.
    let next = sim.render_press(&PressSpec::new("T030", 4)).unwrap();
    let ev = feed(&mut det, &next.frames, &mut t);
    assert_eq!(starts(&ev), 1, "{ev:?}");
}

#[test]
fn a_capture_waits_for_the_sensor_to_be_still() {
    let sim = common::sim();
    let press = sim.render_press(&PressSpec::new("T030", 1)).unwrap();
    let c = press.meta.params.as_ref().unwrap().contact_frame as usize;
    let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
    let mut det = ContactDetector::new(ContactConfig::default());
    let mut t = 0;
    // Frames of a press ramping in: the capture restarts until they settle.
    let ramp = &press.frames[c..hold];
    assert!(ramp.len() > 8);
    let ev = feed(&mut det, ramp, &mut t);
    assert!(
        !ev.iter()
            .any(|(_, e)| matches!(e, ContactEvent::ReferenceCaptured { .. })),
        "captured while the gel was moving: {ev:?}"
    );
    assert!(det.capturing());
}

#[test]
fn the_reference_is_renewed_after_each_release() {
    let sim = common::sim();
    let bg = sim.background(0);
    let mut det = ContactDetector::with_reference(ContactConfig::default(), &bg);
    let v0 = det.reference_version();
    let mut t = 0;
    let spec = PressSpec {
        release: Some(true),
        ..PressSpec::new("T030", 2)
    };
    let press = sim.render_press(&spec).unwrap();
    let release = press.meta.params.as_ref().unwrap().release_frame.unwrap() as usize;
    let ev = feed(&mut det, &press.frames[..release], &mut t);
    assert_eq!(starts(&ev), 1);
    // After the release the untouched sensor looks slightly different (the
    // gel warmed up: 1 % less green), below the contact threshold.
    let after = gain(&bg, [1.0, 0.99, 1.0]);
    let ev = feed(&mut det, &vec![after.clone(); 60], &mut t);
    assert!(
        ev.iter()
            .any(|(_, e)| matches!(e, ContactEvent::PressEnd { .. })),
        "{ev:?}"
    );
    let captured: Vec<usize> = ev
        .iter()
        .filter(|(_, e)| matches!(e, ContactEvent::ReferenceCaptured { .. }))
        .map(|(i, _)| *i)
        .collect();
    assert_eq!(captured.len(), 1, "{ev:?}");
    assert!(!det.renewing());
    assert!(det.reference_version() > v0);
    // Replaced, not averaged in: the reference is the new look.
    assert!(max_abs_diff(det.reference_pixels().unwrap(), &after) < 1.0);
}

fn subtracting_encoder() -> Encoder {
    Encoder::open(
        &common::fixture("fixture_subtract.onnx"),
        &EncoderOptions::default(),
    )
    .unwrap()
}

#[test]
fn recapture_resets_the_encoder_reference_with_the_detector_reference() {
    let sim = common::sim();
    let bg0 = sim.background(0);
    let bg4 = sim.background(4);
    let mut front = FrontEnd::new(
        subtracting_encoder(),
        ContactConfig::default(),
        Some(&pixels_of(&bg0)),
    );
    let press = sim
        .render_press(&PressSpec {
            sensor: 4,
            ..PressSpec::new("T030", 1)
        })
        .unwrap();
    let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
    let touched = &press.frames[hold + 10];
    // The reference of unit 4, as the encoder alone computes it.
    let mut alone = subtracting_encoder();
    alone.set_reference(&bg4).unwrap();
    let want = alone.encode(touched).unwrap().to_vec();
    alone.set_reference(&bg0).unwrap();
    let stale = alone.encode(touched).unwrap().to_vec();
    // The sensor was swapped: re-capture (from unit 4's untouched frames).
    front.recapture();
    let mut t = 0;
    for _ in 0..8 {
        t += PERIOD;
        front
            .process(&Frame::new(bg4.clone(), t, 0).unwrap())
            .unwrap();
    }
    assert!(max_abs_diff(front.contact().reference_pixels().unwrap(), &bg4) < 0.01);
    // Press: the embedding subtracts unit 4's reference.
    let mut got = None;
    for f in &press.frames {
        t += PERIOD;
        let out = front
            .process(&Frame::new(f.clone(), t, 0).unwrap())
            .unwrap();
        if let Some(e) = out.embedding {
            got = Some(e.to_vec());
        }
        if std::ptr::eq(f, touched) {
            break;
        }
    }
    let got = got.expect("embeddings in contact");
    // (Not bit-equal: the reference followed the untouched frames before
    // the contact, which carry camera noise.)
    let dist = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f32>();
    let (d_new, d_old) = (dist(&got, &want), dist(&got, &stale));
    assert!(d_new < 0.05 && d_new * 5.0 < d_old, "{d_new} vs {d_old}");
}

/// An index of a few textiles from their simulated presses, built with the
/// background-subtracting fixture model through the front end.
fn index(textiles: &[&str]) -> FlatIndex {
    let sim = common::sim();
    let mut front = FrontEnd::new(subtracting_encoder(), ContactConfig::default(), None);
    let mut rows = Vec::new();
    for id in textiles {
        let mut embs = Vec::new();
        for seed in [1, 2] {
            let p = sim.render_press(&PressSpec::new(*id, seed)).unwrap();
            front.reset(recording_reference(&p).as_deref());
            for (i, f) in p.frames.iter().enumerate() {
                let frame = Frame::new(f.clone(), p.meta.timestamps_us[i], i as u64).unwrap();
                if let Some(e) = front.process(&frame).unwrap().embedding {
                    embs.push(e.to_vec());
                }
            }
        }
        rows.push((id.to_string(), embs));
    }
    FlatIndex::from_embeddings(&rows).unwrap()
}

fn replay(p: &mut Pipeline<FlatIndex>, press: &Press) -> Vec<PressReport> {
    p.reset(recording_reference(press).as_deref());
    let mut src = RecordedSource::from_press(press.clone(), Pace::AsFastAsPossible, "test");
    let mut out = Vec::new();
    run_source(p, &mut src, None, |r| out.push(r)).unwrap();
    out
}

/// A knock of `n` frames of a press's hold between untouched frames.
fn knock(press: &Press, n: usize) -> Press {
    let sim = common::sim();
    let bg = sim.background(0);
    let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
    // 20 untouched frames, the knock, untouched again.
    let mut frames = vec![bg.clone(); 20];
    frames.extend(press.frames[hold..hold + n].iter().cloned());
    frames.extend(vec![bg.clone(); 40]);
    let len = frames.len() as u64;
    Press {
        meta: telextiles_sim::PressMeta {
            timestamps_us: (0..len).map(|i| i * PERIOD).collect(),
            reference_frames: Some(10),
            params: None,
            source: "digit".into(),
            ..press.meta.clone()
        },
        frames,
    }
}

/// A 2-frame bump (33 ms) starts a press on its second frame, which ends
/// before the decider has two frames of a leader: no decision while it
/// lasts, and at its end the textile nearest its one frame, as the
/// receiving daemon decides it from the sender's final latent. A 5-frame
/// knock (83 ms) at full force is, to the sensor, the start of a press, and
/// is decided while it lasts (the default detector starts a press on the
/// second frame of contact; the roller then shows the fabric that was
/// touched).
#[test]
fn a_short_bump_is_decided_only_at_its_end() {
    let sim = common::sim();
    let textiles = ["T010", "T030", "T110"];
    let mut p = Pipeline::new(
        subtracting_encoder(),
        index(&textiles),
        PipelineConfig::default(),
        None,
    )
    .unwrap();
    let press = sim.render_press(&PressSpec::new("T030", 5)).unwrap();
    let reports = replay(&mut p, &knock(&press, 2));
    assert_eq!(reports.len(), 1, "{reports:?}");
    let r = &reports[0];
    assert_eq!((r.frames, r.switches), (1, 0), "{reports:?}");
    assert_eq!(r.textile.as_deref(), Some("T030"), "{reports:?}");
    // Its first decision is its end.
    assert_eq!(r.decision_ms, Some(r.duration_ms), "{reports:?}");
    let reports = replay(&mut p, &knock(&press, 5));
    assert_eq!(reports.len(), 1, "{reports:?}");
    assert_eq!(reports[0].textile.as_deref(), Some("T030"), "{reports:?}");
}

#[test]
fn replaying_recordings_with_different_backgrounds_in_one_run_decides_as_separate_runs() {
    let sim = common::sim();
    let textiles = ["T010", "T030", "T110"];
    let idx = index(&textiles);
    // Recordings on three sensor units and one with a shifted LED: their
    // untouched frames differ in their whole colour layout.
    let mut recordings = Vec::new();
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
            p.frames = p.frames.iter().map(|f| gain(f, [0.9, 1.05, 1.1])).collect();
        }
        recordings.push(p);
    }
    let one_run: Vec<Vec<PressReport>> = {
        let mut p = Pipeline::new(
            subtracting_encoder(),
            idx.clone(),
            PipelineConfig::default(),
            None,
        )
        .unwrap();
        recordings.iter().map(|r| replay(&mut p, r)).collect()
    };
    let separate: Vec<Vec<PressReport>> = recordings
        .iter()
        .map(|r| {
            let mut p = Pipeline::new(
                subtracting_encoder(),
                idx.clone(),
                PipelineConfig::default(),
                None,
            )
            .unwrap();
            replay(&mut p, r)
        })
        .collect();
    let key = |r: &PressReport| {
        (
            r.textile.clone(),
            r.slot,
            r.distance.map(f32::to_bits),
            r.decision_ms.map(f64::to_bits),
            r.switches,
            r.frames,
        )
    };
    for (a, b) in one_run.iter().zip(&separate) {
        assert_eq!(a.len(), 1);
        assert_eq!(
            a.iter().map(key).collect::<Vec<_>>(),
            b.iter().map(key).collect::<Vec<_>>()
        );
    }
    let right = one_run
        .iter()
        .zip(&recordings)
        .filter(|(r, p)| r[0].textile.as_deref() == Some(p.meta.textile.as_str()))
        .count();
    assert!(right >= 3, "{right} of 4 right: {one_run:?}");
}

/// A weak press whose change is mostly a brightness shift with a little
/// texture (a soft fabric pressed flat) is still a press with the default
/// configuration (the lighting check, which would take it for an LED step,
/// is off by default; the check is tested above).
#[test]
fn a_weak_press_that_is_partly_a_brightness_shift_is_still_a_press() {
    let sim = common::sim();
    let bg = sim.background(0);
    let press = sim.render_press(&PressSpec::new("T030", 1)).unwrap();
    let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
    let touched = &press.frames[hold + 5];
    // Blend: 5 % darker everywhere plus a tenth of the fabric's relief.
    let weak = |k: f32| {
        let mut out = bg.clone();
        for ((o, b), t) in out.iter_mut().zip(bg.iter()).zip(touched.iter()) {
            let v = *b as f32 * (1.0 - 0.05 * k) + 0.1 * k * (*t as f32 - *b as f32);
            *o = v.round().clamp(0.0, 255.0) as u8;
        }
        out
    };
    let mut det = ContactDetector::with_reference(ContactConfig::default(), &bg);
    let mut frames: Vec<RgbImage> = vec![bg.clone(); 5];
    frames.extend((1..=10).map(|k| weak(k as f32 / 10.0)));
    frames.extend(vec![weak(1.0); 30]);
    let mut t = 0;
    let ev = feed(&mut det, &frames, &mut t);
    assert_eq!(starts(&ev), 1, "{ev:?}");
    assert_eq!(rejected(&ev), 0, "{ev:?}");
    // Why the lighting check is off by default: on the plain score it
    // would lose this press.
    let mut det = ContactDetector::with_reference(lighting_on(), &bg);
    let ev = feed(&mut det, &frames, &mut t);
    assert_eq!(starts(&ev), 0, "{ev:?}");
    assert_eq!(rejected(&ev), 1, "{ev:?}");
}

/// A recording whose every frame is in contact (a PyTouch sequence cut to
/// the press) carries no reference and has no quiet frames to capture one
/// from: given the sensor's no-contact frame (`--reference`), it is
/// replayed as the whole recording was.
#[test]
fn a_given_reference_replays_a_recording_that_has_none() {
    use telextiles_sensing::front::{segment, segment_with, References};
    let sim = common::sim();
    let press = sim.render_press(&PressSpec::new("T030", 1)).unwrap();
    let whole = segment(&press, &ContactConfig::default()).expect("the whole recording");
    let own = recording_reference(&press).unwrap();
    // Cut to the frames in contact, without the quiet frames in front.
    let first = whole.contact.iter().find(|c| !c.early).unwrap().index;
    let mut cut = press.clone();
    cut.frames.drain(..first);
    cut.meta.timestamps_us.drain(..first);
    cut.meta.reference_frames = None;
    cut.meta.source = "pytouch".into();
    cut.meta.sensor_serial = Some("D20001".into());
    let contact = |s: &Option<telextiles_sensing::front::Segment>| {
        s.as_ref()
            .map_or(0, |s| s.contact.iter().filter(|c| !c.early).count())
    };
    // Without a reference the first frames, in contact, become one: most
    // of the press is lost.
    let alone = segment(&cut, &ContactConfig::default());
    let n = contact(&Some(whole.clone()));
    assert!(contact(&alone) < n / 2, "{} of {n}", contact(&alone));

    // The sensor's no-contact frame, as a user has it: a PNG.
    let dir = tempfile::tempdir().unwrap();
    let png = dir.path().join("bg.png");
    let mut img = RgbImage::new(240, 320);
    for (v, o) in img.as_mut().iter_mut().zip(&own) {
        *v = o.round() as u8;
    }
    img.save(&png).unwrap();
    let arg = png.to_str().unwrap().to_string();
    let refs = References::from_args(std::slice::from_ref(&arg)).unwrap();
    let given = refs.for_press(&cut).expect("the given reference");
    let replayed = segment_with(&cut, &ContactConfig::default(), Some(&given)).unwrap();
    let m = contact(&Some(replayed.clone()));
    assert!(m + 3 >= n && m <= n, "{m} of {n}");
    // A recording's own reference wins over a given one.
    let other = References::from_args(&[format!("D20001={arg}")]).unwrap();
    assert_eq!(other.for_press(&press), Some(own.clone()));
    // A serial's reference applies to its sensor only, and wins over the
    // one for every sensor.
    let mut black = RgbImage::new(240, 320);
    black.as_mut().fill(0);
    let png2 = dir.path().join("black.png");
    black.save(&png2).unwrap();
    let both =
        References::from_args(&[png2.to_str().unwrap().to_string(), format!("D20001={arg}")])
            .unwrap();
    assert_eq!(both.given(Some("D20001")), other.given(Some("D20001")));
    assert!(both
        .given(Some("D20002"))
        .unwrap()
        .iter()
        .all(|&v| v == 0.0));
    assert!(other.given(Some("D20002")).is_none());
    assert!(References::none().for_press(&cut).is_none());
    assert!(References::none().is_empty() && !both.is_empty());

    // Bad references: each refused with what is wrong.
    let small = dir.path().join("small.png");
    RgbImage::new(300, 200).save(&small).unwrap();
    let gray = dir.path().join("gray.png");
    image::GrayImage::new(240, 320).save(&gray).unwrap();
    for (args, msg) in [
        (
            vec![small.to_str().unwrap().to_string()],
            "cannot map a 300x200 image to the 240x320 frame",
        ),
        (
            vec![gray.to_str().unwrap().to_string()],
            "expected 8-bit RGB",
        ),
        (
            vec!["/nonexistent/bg.png".to_string()],
            "/nonexistent/bg.png",
        ),
        (vec![format!("={arg}")], "expected [SERIAL=]PNG"),
        (
            vec![arg.clone(), arg.clone()],
            "every sensor was already given",
        ),
        (
            vec![format!("D1={arg}"), format!("D1={arg}")],
            "sensor D1 was already given",
        ),
    ] {
        let e = References::from_args(&args).unwrap_err().to_string();
        assert!(e.contains(msg), "{args:?}: {e}");
    }
}
