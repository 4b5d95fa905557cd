use super::*;
use crate::contact::{ContactConfig, ContactDetector};
use telextiles_sim::{PressSpec, Simulator};

fn frame(image: &RgbImage, t_us: u64, seq: u64) -> Frame {
    Frame::new(image.clone(), t_us, seq).expect("a 240x320 frame")
}

/// Feeds a detector and a recorder, collecting the events.
struct Rig {
    det: ContactDetector,
    rec: Recorder,
    seq: u64,
    period_us: u64,
    events: Vec<RecordEvent>,
}

impl Rig {
    fn new(cfg: RecorderConfig) -> Rig {
        Rig {
            det: ContactDetector::new(ContactConfig::default()),
            rec: Recorder::new(cfg, RecordLabel::new("T030", "sim")),
            seq: 0,
            period_us: 16_667,
            events: Vec::new(),
        }
    }
    fn feed(&mut self, image: &RgbImage) {
        let f = frame(image, self.seq * self.period_us, self.seq);
        self.seq += 1;
        let u = self.det.update(f.image(), f.timestamp_us());
        self.rec.push(&f, &u);
        while let Some(e) = self.rec.poll() {
            self.events.push(e);
        }
    }
    /// 40 untouched frames `bg`, the press's `frames`, then `after`
    /// untouched frames.
    fn feed_press(&mut self, bg: &RgbImage, frames: &[RgbImage], after: usize) {
        for _ in 0..40 {
            self.feed(bg);
        }
        for f in frames {
            self.feed(f);
        }
        for _ in 0..after {
            self.feed(bg);
        }
    }
    fn finish(&mut self) {
        self.rec.finish();
        while let Some(e) = self.rec.poll() {
            self.events.push(e);
        }
    }
    fn presses(&self) -> Vec<&RecordedPress> {
        self.events
            .iter()
            .filter_map(|e| match e {
                RecordEvent::PressComplete(p) => Some(&**p),
                _ => None,
            })
            .collect()
    }
    fn rejections(&self) -> Vec<&RecordWarning> {
        self.events
            .iter()
            .filter_map(|e| match e {
                RecordEvent::Rejected(w) => Some(w),
                _ => None,
            })
            .collect()
    }
}

fn sim_press(textile: &str, seed: u64) -> (Simulator, Press) {
    let sim = Simulator::new().expect("simulator");
    let spec = PressSpec {
        release: Some(true),
        ..PressSpec::new(textile, seed)
    };
    let p = sim.render_press(&spec).expect("render");
    (sim, p)
}

#[test]
fn a_given_reference_leads_the_press_as_its_reference_frames() {
    let sim = Simulator::new().unwrap();
    let press = sim.render_press(&PressSpec::new("T030", 3)).unwrap();
    let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
    // Cut to the press, as shared datasets are, at 30 fps, with no
    // reference of its own.
    let mut cut = Press {
        meta: press.meta.clone(),
        frames: press.frames[hold..].to_vec(),
    };
    cut.meta.fps = 30.0;
    cut.meta.reference_frames = None;
    cut.meta.timestamps_us = (0..cut.frames.len() as u64)
        .map(|i| 1_000 + i * 33_333)
        .collect();
    let bg = crate::front::pixels_of(&press.frames[0]);
    let led = lead_with_reference(&cut, &bg, 8);
    assert_eq!(led.frames.len(), cut.frames.len() + 8);
    assert_eq!(led.meta.reference_frames, Some(8));
    assert!(led.frames[..8].iter().all(|f| *f == press.frames[0]));
    assert_eq!(led.frames[8..], cut.frames[..]);
    // One period apart, the recording's own spacing kept after them.
    assert_eq!(
        &led.meta.timestamps_us[..9],
        &[0, 33_333, 66_666, 99_999, 133_332, 166_665, 199_998, 233_331, 266_664]
    );
    assert_eq!(
        led.meta.timestamps_us[9] - led.meta.timestamps_us[8],
        33_333
    );
    // Every reader now takes the given frame as its reference, exactly.
    assert_eq!(crate::front::recording_reference(&led), Some(bg.clone()));
    // And the recorder keeps a press from it, led by those frames.
    let mut det = ContactDetector::with_reference_pixels(ContactConfig::default(), &bg);
    let mut rec = Recorder::new(
        RecorderConfig {
            fps: Some(30.0),
            ..RecorderConfig::default()
        },
        RecordLabel::new("T030", "replay"),
    );
    for (i, (f, &t)) in led.frames.iter().zip(&led.meta.timestamps_us).enumerate() {
        let u = det.update(f, t);
        rec.push(&frame(f, t, i as u64), &u);
    }
    rec.finish();
    let mut kept = None;
    while let Some(e) = rec.poll() {
        if let RecordEvent::PressComplete(p) = e {
            kept = Some(p.press);
        }
    }
    let kept = kept.expect("a press");
    assert_eq!(kept.meta.reference_frames, Some(8));
    assert!(kept.frames[..8].iter().all(|f| *f == press.frames[0]));
}

#[test]
fn a_tilted_press_is_kept_with_a_warning_that_it_touched_part_of_the_gel() {
    let sim = Simulator::new().unwrap();
    let bg = sim.background(0);
    let mut covered = Vec::new();
    for tilt in [0.0, 3.5] {
        let spec = PressSpec {
            release: Some(true),
            tilt_deg: Some([tilt, 0.0]),
            ..PressSpec::new("T030", 1)
        };
        let press = sim.render_press(&spec).unwrap();
        let mut rig = Rig::new(RecorderConfig::default());
        rig.feed_press(&bg, &press.frames, 40);
        let presses = rig.presses();
        assert_eq!(presses.len(), 1, "tilt {tilt}: {:?}", rig.rejections());
        let s = &presses[0].summary;
        covered.push(s.coverage);
        let partial: Vec<_> = s
            .warnings
            .iter()
            .filter(|w| w.code() == "partial")
            .collect();
        if tilt == 0.0 {
            assert!(s.coverage >= 0.7, "flat: {}", s.coverage);
            assert!(partial.is_empty(), "{:?}", s.warnings);
        } else {
            assert!(s.coverage < 0.5, "tilted: {}", s.coverage);
            assert_eq!(
                partial,
                [&RecordWarning::Partial {
                    coverage: s.coverage,
                    min: 0.5
                }]
            );
            assert!(
                partial[0].to_string().contains("hold the sensor flat"),
                "{}",
                partial[0]
            );
        }
    }
    // A stricter minimum warns about the flat press too; 0 never warns.
    let (_, press) = sim_press("T030", 1);
    for (min, warns) in [(1.01, true), (0.0, false)] {
        let mut rig = Rig::new(RecorderConfig {
            min_coverage: min,
            ..RecorderConfig::default()
        });
        rig.feed_press(&bg, &press.frames, 0);
        rig.finish();
        let p = rig.presses();
        let w = p[0].summary.warnings.iter().any(|w| w.code() == "partial");
        assert_eq!(w, warns, "min {min}: {:?} ({covered:?})", p[0].summary);
    }
}

#[test]
fn record_segments_a_simulated_press_with_its_reference_and_margins() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let mut rig = Rig::new(RecorderConfig::default());
    rig.feed_press(&bg, &press.frames, 40);
    let kinds: Vec<&str> = rig
        .events
        .iter()
        .map(|e| match e {
            RecordEvent::WaitingForReference => "waiting",
            RecordEvent::Ready => "ready",
            RecordEvent::PressStarted { .. } => "started",
            RecordEvent::Holding { .. } => "holding",
            RecordEvent::Released { .. } => "released",
            RecordEvent::PressComplete(_) => "complete",
            RecordEvent::Rejected(_) => "rejected",
        })
        .collect();
    let mut dedup = kinds.clone();
    dedup.dedup();
    assert_eq!(
        dedup,
        ["waiting", "ready", "started", "holding", "released", "complete", "ready"],
        "{kinds:?}"
    );
    let presses = rig.presses();
    let p = presses[0];
    let cfg = RecorderConfig::default();
    assert_eq!(p.summary.reference_frames as usize, cfg.pre_frames);
    assert_eq!(
        p.press.meta.reference_frames,
        Some(cfg.pre_frames as u32),
        "reference frames in the metadata"
    );
    assert_eq!(p.press.frames.len(), p.press.meta.timestamps_us.len());
    assert_eq!(p.press.meta.timestamps_us[0], 0);
    assert!(p.press.meta.timestamps_us.windows(2).all(|w| w[1] > w[0]));
    assert!(
        (p.press.meta.fps - 60.0).abs() < 0.05,
        "{}",
        p.press.meta.fps
    );
    assert_eq!(p.press.meta.textile, "T030");
    assert_eq!(p.press.meta.source, "sim");
    // The leading reference frames are the untouched sensor: they score
    // like camera noise against the background; the press frames do not.
    let mut det = ContactDetector::with_reference(ContactConfig::default(), &bg);
    let k = cfg.pre_frames;
    for f in &p.press.frames[..k] {
        assert!(
            det.score(f) < 0.6,
            "reference frame scores {}",
            det.score(f)
        );
    }
    let peak = p.press.frames[k..]
        .iter()
        .map(|f| det.score(f))
        .fold(0f32, f32::max);
    assert!(peak > 1.0, "peak {peak}");
    assert!(p.summary.peak > 1.0, "summary peak {}", p.summary.peak);
    // The press (minus the margins) is all of the rendered contact; the
    // margin after the release is there.
    let last = p.press.frames.last().expect("frames");
    assert!(det.score(last) < 0.6, "last frame is untouched again");
    assert!(p.summary.warnings.is_empty(), "{:?}", p.summary.warnings);
    assert!(p.summary.held_ms > cfg.min_press_ms);
    assert!(
        (p.summary.duration_ms - (p.press.frames.len() - 1) as f64 * 16.667).abs() < 1.0,
        "{}",
        p.summary.duration_ms
    );
}

#[test]
fn record_presses_follow_one_another_and_memory_stays_bounded() {
    let (sim, a) = sim_press("T030", 1);
    let (_, b) = sim_press("T080", 2);
    let bg = sim.background(0);
    let cfg = RecorderConfig::default();
    let bound = 2 * (cfg.pre_frames + cfg.approach_frames + 1) + 150 + cfg.post_frames;
    let mut rig = Rig::new(cfg);
    let mut most = 0;
    for p in [&a, &b, &a] {
        for _ in 0..30 {
            rig.feed(&bg);
            most = most.max(rig.rec.frames_held());
        }
        for f in &p.frames {
            rig.feed(f);
            most = most.max(rig.rec.frames_held());
        }
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    assert_eq!(rig.presses().len(), 3, "{:?}", rig.rejections());
    assert!(most <= bound, "held {most} frames (bound {bound})");
    let readies = rig
        .events
        .iter()
        .filter(|e| matches!(e, RecordEvent::Ready))
        .count();
    assert_eq!(
        readies, 4,
        "press now before every press, and after the last"
    );
}

#[test]
fn record_rejects_a_press_without_quiet_frames_before_it() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    // The detector knows the background, but the recorder has seen no
    // quiet frame: the press starts straight away.
    let mut rig = Rig::new(RecorderConfig::default());
    rig.det = ContactDetector::with_reference(ContactConfig::default(), &bg);
    let touched = &press.frames[press.frames.len() / 2];
    for _ in 0..30 {
        rig.feed(touched);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    assert!(rig.presses().is_empty());
    assert!(
        matches!(
            rig.rejections()[..],
            [RecordWarning::NoQuietBefore {
                quiet_frames: 0,
                needed: 8
            }]
        ),
        "{:?}",
        rig.rejections()
    );
    // After the release the sensor is quiet again: ready for the next one.
    assert!(matches!(rig.events.last(), Some(RecordEvent::Ready)));
}

#[test]
fn record_rejects_a_tap_and_warns_about_a_weak_press() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let touched = press.frames[press.frames.len() / 2].clone();
    let mut rig = Rig::new(RecorderConfig::default());
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for _ in 0..6 {
        rig.feed(&touched);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    assert!(rig.presses().is_empty());
    assert!(
        matches!(rig.rejections()[..], [RecordWarning::TooShort { .. }]),
        "{:?}",
        rig.rejections()
    );
    // The same press long enough but with a peak under a high minimum: kept, flagged.
    let mut rig = Rig::new(RecorderConfig {
        min_peak: 1000.0,
        ..RecorderConfig::default()
    });
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for _ in 0..40 {
        rig.feed(&touched);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    let p = rig.presses();
    assert_eq!(p.len(), 1);
    assert!(
        matches!(p[0].summary.warnings[..], [RecordWarning::TooWeak { .. }]),
        "{:?}",
        p[0].summary.warnings
    );
    assert_eq!(p[0].summary.warnings[0].code(), "too_weak");
}

#[test]
fn record_rejects_a_press_held_too_long_and_recovers() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let touched = press.frames[press.frames.len() / 2].clone();
    let cfg = RecorderConfig {
        max_press_frames: 50,
        ..RecorderConfig::default()
    };
    let mut rig = Rig::new(cfg.clone());
    for _ in 0..30 {
        rig.feed(&bg);
    }
    let mut most = 0;
    for _ in 0..200 {
        rig.feed(&touched);
        most = most.max(rig.rec.frames_held());
    }
    assert!(most <= 2 * (cfg.pre_frames + cfg.approach_frames + 1) + 52);
    for _ in 0..30 {
        rig.feed(&bg);
    }
    assert!(
        matches!(
            rig.rejections()[..],
            [RecordWarning::TooLong { max_frames: 50 }]
        ),
        "{:?}",
        rig.rejections()
    );
    // And the next (shorter) press records normally.
    for _ in 0..40 {
        rig.feed(&touched);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    let tail: Vec<_> = rig
        .events
        .iter()
        .filter(|e| !matches!(e, RecordEvent::Holding { .. }))
        .collect();
    assert_eq!(rig.presses().len(), 1, "{tail:?}");
}

#[test]
fn record_keeps_a_press_cut_off_by_the_end_of_the_frames() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let touched = press.frames[press.frames.len() / 2].clone();
    let mut rig = Rig::new(RecorderConfig::default());
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for _ in 0..40 {
        rig.feed(&touched);
    }
    rig.finish();
    let p = rig.presses();
    assert_eq!(p.len(), 1);
    assert_eq!(p[0].summary.warnings, [RecordWarning::NotReleased]);
    assert_eq!(p[0].press.frames.len(), 30 + 40);
}

#[test]
fn record_interrupted_press_is_rejected() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let touched = press.frames[press.frames.len() / 2].clone();
    let mut rig = Rig::new(RecorderConfig::default());
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for _ in 0..20 {
        rig.feed(&touched);
    }
    rig.det.recapture();
    rig.feed(&bg);
    assert_eq!(rig.rejections(), [&RecordWarning::Interrupted]);
    assert_eq!(rig.rec.state(), RecordState::Waiting);
}

#[test]
fn record_is_deterministic_and_records_hand_held_presses() {
    let sim = Simulator::new().expect("simulator");
    let bg = sim.background(0);
    let run = || {
        let mut rig = Rig::new(RecorderConfig::default());
        for person in [0, 3, 7] {
            let spec = PressSpec {
                jig: false,
                person,
                release: Some(true),
                ..PressSpec::new("T080", 10 + person as u64)
            };
            let press = sim.render_press(&spec).expect("render");
            for _ in 0..30 {
                rig.feed(&bg);
            }
            for f in &press.frames {
                rig.feed(f);
            }
        }
        for _ in 0..30 {
            rig.feed(&bg);
        }
        rig.presses().into_iter().cloned().collect::<Vec<_>>()
    };
    let a = run();
    assert_eq!(a.len(), 3, "every hand-held press is recorded");
    assert_eq!(a, run(), "same frames, same recordings");
}

#[test]
fn record_a_second_press_inside_the_margin_ends_the_first() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let touched = press.frames[press.frames.len() / 2].clone();
    let mut rig = Rig::new(RecorderConfig::default());
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for _ in 0..40 {
        rig.feed(&touched);
    }
    // Released (5 quiet frames end the press), then pressed again at once.
    for _ in 0..8 {
        rig.feed(&bg);
    }
    for _ in 0..40 {
        rig.feed(&touched);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    let p = rig.presses();
    assert_eq!(p.len(), 1);
    // The first press kept what it had of its margin: fewer than 20 frames.
    let k = p[0].summary.reference_frames as usize;
    assert!(
        p[0].press.frames.len() < k + 40 + 20,
        "{}",
        p[0].press.frames.len()
    );
    assert!(
        matches!(rig.rejections()[..], [RecordWarning::NoQuietBefore { .. }]),
        "{:?}",
        rig.rejections()
    );
}

#[test]
fn record_given_fps_and_measured_fps() {
    assert_eq!(measured_fps(26, 1_000_000), 25.0);
    assert_eq!(measured_fps(1, 0), 60.0);
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let mut rig = Rig::new(RecorderConfig {
        fps: Some(30.0),
        ..RecorderConfig::default()
    });
    rig.period_us = 40_000; // the frames come at 25 fps, the config says 30
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for f in &press.frames {
        rig.feed(f);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    assert_eq!(rig.presses()[0].press.meta.fps, 30.0);
    let mut rig = Rig::new(RecorderConfig::default());
    rig.period_us = 40_000;
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for f in &press.frames {
        rig.feed(f);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    let p = rig.presses()[0];
    assert_eq!(p.press.meta.fps, 25.0);
    assert_eq!(p.press.meta.timestamps_us[1], 40_000);
}

#[test]
fn record_written_press_reads_back_with_its_reference() {
    let (sim, press) = sim_press("T030", 1);
    let bg = sim.background(0);
    let mut rig = Rig::new(RecorderConfig::default());
    for _ in 0..30 {
        rig.feed(&bg);
    }
    for f in &press.frames {
        rig.feed(f);
    }
    for _ in 0..30 {
        rig.feed(&bg);
    }
    let p = rig.presses()[0].press.clone();
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path().join("T030").join("0001");
    telextiles_recording::recording::write_press(&d, &p).expect("write");
    let back = telextiles_recording::recording::read_press(&d).expect("read");
    assert_eq!(back, p);
    assert!(telextiles_recording::recording::write_press(&d, &p).is_err());
}
