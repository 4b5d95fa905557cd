use super::*;
use telextiles_sensing::contact::ContactConfig;

#[test]
fn the_baseline_and_the_shipped_detector_come_first_and_each_config_is_valid() {
    let c = candidates();
    assert_eq!(c[0], Detector::before());
    assert_eq!(c[1], Detector::shipped());
    assert_ne!(Detector::before(), Detector::shipped());
    assert_eq!(
        Detector::shipped().config().unwrap(),
        ContactConfig::default()
    );
    for d in &c {
        let cfg = d.config().unwrap();
        assert!(cfg.exit < cfg.enter, "{}", d.label());
    }
    // Two frames span 13.7 ms: never on one frame, not a frame late at 60 fps.
    let two = Detector {
        enter: 0.2,
        frames: 2,
        gain: false,
        tile: 0,
    }
    .config()
    .unwrap();
    assert!(two.enter_ms > 1.0 && two.enter_ms < 1000.0 / 60.0);
    assert!((two.exit - 0.12).abs() < 1e-6, "{}", two.exit);
    assert!(Detector {
        enter: 0.0,
        frames: 3,
        gain: false,
        tile: 0,
    }
    .config()
    .is_err());
    assert!(Detector {
        enter: 0.2,
        frames: 0,
        gain: false,
        tile: 0,
    }
    .config()
    .is_err());
}

#[test]
fn flicker_scales_each_channel_by_its_own_gain_and_tilt() {
    let f = image::RgbImage::from_pixel(5, 4, image::Rgb([100, 100, 100]));
    assert_eq!(flicker(&f, 0.0, 1), f);
    let g = flicker(&f, 5.0, 1);
    // One gain per channel and column; the centre column has no tilt.
    for x in 0..5 {
        assert!((0..4).all(|y| g.get_pixel(x, y) == g.get_pixel(x, 0)));
    }
    let p = g.get_pixel(2, 0).0;
    assert!(p[0] != p[1] || p[1] != p[2], "{p:?}");
    assert_ne!(g.get_pixel(0, 0), g.get_pixel(4, 0), "tilted");
    // Over many frames the centre's gains spread by about the given %.
    let v: Vec<f64> = (0..400)
        .map(|s| flicker(&f, 5.0, s).get_pixel(2, 0).0[0] as f64 - 100.0)
        .collect();
    let sd = (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt();
    assert!((4.0..6.0).contains(&sd), "{sd}");
}

#[test]
fn exposure_drift_starts_presses_that_gain_compensation_does_not_and_a_tilt_defeats_low_thresholds()
{
    // Catalogue 2's unit 9 wanders in exposure (its camera's gain
    // drifts by about 1 % over seconds).
    let cfg = IdleConfig {
        units: vec![(2, 9)],
        footage: Vec::new(),
        seconds: 10.0,
        stress: vec![0.0, 1.0],
        threads: 1,
        seed: 1,
    };
    let r = run(&cfg).unwrap();
    assert_eq!(r.scores.len(), 2 * candidates().len());
    let d = |enter: f32, gain: bool| Detector {
        enter,
        frames: 3,
        gain,
        tile: 0,
    };
    let (n, h) = false_per_hour(&r, Detector::before(), 0.0).unwrap();
    assert!((h - 10.0 / 3600.0).abs() < 0.0005, "{h}");
    assert!(n > 0, "the drift starts presses with the plain score");
    assert!(contact_share(&r, Detector::before(), 0.0) > 0.3);
    // Taking out the best per-channel gain leaves the drift as noise.
    for st in [0.0, 1.0] {
        assert_eq!(
            false_per_hour(&r, d(0.35, true), st).unwrap().0,
            0,
            "+{st} %"
        );
        assert_eq!(contact_share(&r, d(0.35, true), st), 0.0);
    }
    // What a gain does not explain (the flicker's left-right tilt)
    // starts presses at a low threshold.
    assert_eq!(false_per_hour(&r, d(0.1, true), 0.0).unwrap().0, 0);
    assert!(false_per_hour(&r, d(0.1, true), 1.0).unwrap().0 > 0);
    let md = markdown(&r);
    assert!(
        md.contains(
            "| 0.35 DN × 3, gain-compensated | 0 (0.0/h, 0.0 % in contact, 0.0 % capturing) |"
        ),
        "{md}"
    );
}

#[test]
fn recorded_footage_is_read_frame_by_frame_and_reported_as_catalogue_0() {
    // 4 s of the simulator's idle footage of unit 0, as `telextilesd
    // record --idle` saves it, with a touch (a press's hold) from 3 s.
    let sim = telextiles_sim::Simulator::new().unwrap();
    let spec = telextiles_sim::PressSpec {
        frames: 240,
        ..telextiles_sim::PressSpec::new("T030", 3)
    };
    let clip = sim.idle_clip(&spec).unwrap();
    let press = sim
        .render_press(&telextiles_sim::PressSpec::new("T030", 3))
        .unwrap();
    let hold = press.meta.params.as_ref().unwrap().hold_frame as usize;
    let frames = (0..240)
        .map(|i| {
            if (180..210).contains(&i) {
                press.frames[hold + i - 180].clone()
            } else {
                sim.idle_frame(&clip, i).unwrap()
            }
        })
        .collect();
    let d = tempfile::tempdir().unwrap();
    let dir = d.path().join("idle/0001");
    let footage = telextiles_sim::Press {
        meta: telextiles_sim::PressMeta {
            textile: "idle".into(),
            // A real sensor's clock: the first frame is not at 0.
            timestamps_us: clip.timestamps_us.iter().map(|t| t + 5_000_000).collect(),
            params: None,
            ..press.meta.clone()
        },
        frames,
    };
    telextiles_sim::recording::write_press(&dir, &footage).unwrap();
    let cfg = IdleConfig {
        units: Vec::new(),
        footage: vec![dir.clone()],
        seconds: 1.0,
        stress: vec![0.0],
        threads: 2,
        seed: 1,
    };
    let r = run(&cfg).unwrap();
    assert_eq!(r.footage, [dir.display().to_string()]);
    assert!(
        (r.footage_hours - 4.0 / 3600.0).abs() < 1e-5,
        "{}",
        r.footage_hours
    );
    // The touch is the one press every detector starts (whole footage
    // read: `seconds` does not cut it).
    for det in [Detector::shipped(), Detector::before()] {
        let (n, h) = false_per_hour(&r, det, 0.0).unwrap();
        assert_eq!(n, 1, "{}", det.label());
        assert!((h - 4.0 / 3600.0).abs() < 1e-5);
    }
    assert!(r.scores.iter().all(|s| s.catalogue == 0));
    let md = markdown(&r);
    assert!(md.contains("1 recorded clip (0.001 h"), "{md}");
    assert!(md.contains("| 0 (recorded) | 0 % |"), "{md}");
    // A simulated press is not idle footage.
    let p = d.path().join("press");
    telextiles_sim::recording::write_press(&p, &press).unwrap();
    let err = run(&IdleConfig {
        footage: vec![p],
        ..cfg
    })
    .unwrap_err();
    assert!(
        format!("{err:#}").contains("not footage of a resting sensor"),
        "{err:#}"
    );
}

fn idle_of(counts: &[(Detector, [u64; 3])]) -> IdleReport {
    // (no time spent capturing)
    let stress = vec![0.0, MARGIN_STRESS, 0.5];
    let mut scores = Vec::new();
    for (d, n) in counts {
        for (k, &st) in stress.iter().enumerate() {
            scores.push(IdleScore {
                detector: *d,
                catalogue: 1,
                stress: st,
                hours: 0.5,
                false_presses: n[k],
                contact_s: 0.0,
                capturing_s: 0.0,
            });
        }
    }
    IdleReport {
        machine: String::new(),
        date: String::new(),
        command: String::new(),
        units: vec![(1, 0)],
        footage: Vec::new(),
        footage_hours: 0.0,
        seconds_per_clip: 1800.0,
        detectors: counts.iter().map(|x| x.0).collect(),
        stress,
        scores,
        run_peaks: vec![],
        seconds: 0.0,
    }
}

/// A timing study of `source` with detector `d`: the daemon decider's
/// right at 100 ms and first decisions right, per group.
fn timing_of(
    source: &str,
    d: Option<Detector>,
    at100: [f64; 2],
    first: [f64; 2],
) -> crate::decider_timing::TimingReport {
    use crate::decider_timing::{TimingReport, TimingScore};
    let scores = ["jig", "hand-held"]
        .iter()
        .enumerate()
        .map(|(k, g)| TimingScore {
            timing: daemon_timing(),
            group: g.to_string(),
            presses: 100,
            right_at: vec![(100.0, at100[k])],
            decided_at: vec![],
            curve: vec![],
            mean_right: 0.0,
            first_ms_p50: 120.0,
            first_right: first[k],
            final_right: 0.9,
            switches_per_100: 0.0,
            from_right_per_100: 0.0,
        })
        .collect();
    TimingReport {
        machine: String::new(),
        date: String::new(),
        command: format!("decider-timing {source}"),
        source: source.into(),
        model: String::new(),
        candidates: vec![],
        scores: vec![],
        chosen: daemon_timing(),
        switch_candidates: vec![],
        switch_scores: scores,
        switch_chosen: None,
        detect_ms_p50: vec![],
        undetected: vec![("jig".into(), 0), ("hand-held".into(), 0)],
        seconds: 0.0,
        contact: d,
    }
}

/// Adds the daemon decider's scores with depth gate `gate` to `t`.
fn with_gate(
    mut t: crate::decider_timing::TimingReport,
    gate: (f32, f32),
    at100: [f64; 2],
    first: [f64; 2],
) -> crate::decider_timing::TimingReport {
    let g = timing_of(&t.source, t.contact, at100, first);
    t.scores.extend(g.switch_scores.into_iter().map(|mut s| {
        s.timing.gate = Some(gate);
        s
    }));
    t
}

#[test]
fn a_detector_with_a_depth_gate_is_a_row_of_its_own_and_can_be_the_pick() {
    let before = Detector::before();
    let tile = Detector {
        enter: 0.6,
        frames: 2,
        gain: false,
        tile: 10,
    };
    let gate = crate::decider_timing::DEPTH_GATES[0];
    let idle = idle_of(&[(before, [0, 0, 0]), (tile, [0, 0, 0])]);
    // The tile alone loses hand-held first decisions; with the gate it
    // keeps them and is still the faster.
    let timings = vec![
        timing_of("cat 1", None, [0.40, 0.20], [0.96, 0.85]),
        with_gate(
            timing_of("cat 1", Some(tile), [0.70, 0.40], [0.96, 0.83]),
            gate,
            [0.65, 0.35],
            [0.96, 0.845],
        ),
    ];
    let r = rows(&idle, &timings).unwrap();
    assert_eq!(r.len(), 3, "before; the tile; the tile with the gate");
    assert_eq!((r[0].detector, r[0].gate), (before, None));
    let c = choose(&r).unwrap();
    assert_eq!((r[c].detector, r[c].gate), (tile, Some(gate)));
    assert!(r[c]
        .label()
        .contains("first decision at depth 0.25 (≤ 100 ms)"));
    let md = markdown_choice(&r, c, "contact-choose");
    assert!(md.contains(&format!("**{}**", r[c].label())), "{md}");
    // Without the gate's scores (a study from before), no gated row,
    // and the tile alone fails the rule: the detector before stays.
    let r = rows(
        &idle,
        &[
            timings[0].clone(),
            timing_of("cat 1", Some(tile), [0.70, 0.40], [0.96, 0.83]),
        ],
    )
    .unwrap();
    assert_eq!(r.len(), 2);
    assert_eq!(choose(&r).unwrap(), 0);
    // A gate whose scores are in one source's study but not the
    // other's is left out.
    let mut t = timings.clone();
    t.push(timing_of("cat 2", None, [0.2, 0.1], [0.5, 0.37]));
    t.push(timing_of("cat 2", Some(tile), [0.3, 0.15], [0.5, 0.37]));
    let r = rows(&idle, &t).unwrap();
    assert!(r.iter().all(|x| x.gate.is_none()));
}

#[test]
fn the_rule_takes_the_fastest_detector_that_starts_nothing_idle_and_keeps_first_decisions() {
    let before = Detector::before();
    let two = Detector {
        enter: 0.35,
        frames: 2,
        gain: false,
        tile: 0,
    };
    let low = Detector {
        enter: 0.2,
        frames: 3,
        gain: false,
        tile: 0,
    };
    let lower = Detector {
        enter: 0.1,
        frames: 2,
        gain: false,
        tile: 0,
    };
    let idle = idle_of(&[
        (before, [0, 0, 0]),
        (two, [0, 0, 3]),
        (low, [0, 0, 0]),
        (lower, [0, 2, 9]),
    ]);
    let timings = vec![
        // The study from before detectors were recorded: the detector
        // before.
        timing_of("cat 1", None, [0.10, 0.10], [0.96, 0.85]),
        timing_of("cat 1", Some(two), [0.45, 0.24], [0.96, 0.852]),
        timing_of("cat 1", Some(low), [0.27, 0.19], [0.96, 0.849]),
        timing_of("cat 1", Some(lower), [0.80, 0.50], [0.96, 0.85]),
        timing_of("cat 2", Some(before), [0.18, 0.10], [0.50, 0.37]),
        timing_of("cat 2", Some(two), [0.30, 0.12], [0.50, 0.37]),
        timing_of("cat 2", Some(low), [0.25, 0.11], [0.50, 0.37]),
        timing_of("cat 2", Some(lower), [0.60, 0.30], [0.50, 0.37]),
    ];
    let all = rows(&idle, &timings).unwrap();
    assert_eq!(all.len(), 4);
    assert_eq!(all[0].detector, before);
    assert_eq!(baseline(&all).unwrap(), 0, "safe: the detector before");
    assert_eq!(all[0].groups.len(), 4, "two studies, two groups");
    // `lower` starts presses at the margin's flicker: out, however
    // fast. `two` is the fastest left (worst group 0.12 > 0.11); its
    // 3 false presses at +0.5 % are beyond the margin.
    assert_eq!(all[choose(&all).unwrap()].detector, two);
    // A first decision right 1.1 points less often in one group rules
    // it out.
    let mut t = timings.clone();
    t[5] = timing_of("cat 2", Some(two), [0.30, 0.12], [0.50, 0.359]);
    let r = rows(&idle, &t).unwrap();
    assert_eq!(r[choose(&r).unwrap()].detector, low);
    // A detector without a study of every source is left out; without
    // the baseline's there is nothing to compare with.
    let r = rows(&idle, &timings[..7]).unwrap();
    assert!(r.iter().all(|x| x.detector != lower));
    assert!(rows(&idle, &timings[1..]).is_err());
    // The detector before starts presses at rest: its counterpart with
    // the gain taken out is the baseline. `two` loses 1.1 points of
    // first decisions against the one before but not against it.
    let gained = Detector {
        gain: true,
        ..before
    };
    let idle2 = idle_of(&[(before, [5, 5, 5]), (gained, [0, 0, 0]), (two, [0, 0, 3])]);
    let mut t2 = t.clone();
    t2.push(timing_of("cat 1", Some(gained), [0.09, 0.09], [0.96, 0.85]));
    t2.push(timing_of(
        "cat 2",
        Some(gained),
        [0.15, 0.09],
        [0.50, 0.365],
    ));
    let r = rows(&idle2, &t2).unwrap();
    let b = baseline(&r).unwrap();
    assert_eq!(r[b].detector, gained);
    assert_eq!(r[choose(&r).unwrap()].detector, two);
    let md = markdown_choice(&r, choose(&r).unwrap(), "contact-choose");
    assert!(md.contains("| 0.35 DN × 3 (before) |"), "{md}");
    assert!(
        md.contains("| 0.35 DN × 3, gain-compensated (baseline) |"),
        "{md}"
    );
    // Neither safe: an error, not a pick.
    let noisy = idle_of(&[(before, [1, 1, 1]), (gained, [0, 1, 0]), (two, [0, 0, 3])]);
    let r = rows(&noisy, &t2).unwrap();
    assert!(baseline(&r).is_err());
    assert!(choose(&r).is_err());
    // Nothing measured with the gain taken out: an error too.
    let r = rows(&idle_of(&[(before, [1, 1, 1]), (two, [0, 0, 3])]), &timings).unwrap();
    assert!(choose(&r).is_err());
    let md = markdown_choice(&all, 1, "contact-choose");
    assert!(
        md.contains(
            "| **0.35 DN × 2** | 0 (0.0/h) / 0 (0.0/h) / 3 (6.0/h) | 45.0 / 96.0 / 120 ms |"
        ),
        "{md}"
    );
    assert!(md.contains("It picks **0.35 DN × 2**"), "{md}");
    let dir = tempfile::tempdir().unwrap();
    chart(&all, &dir.path().join("c.svg")).unwrap();
    assert!(std::fs::read_to_string(dir.path().join("c.svg"))
        .unwrap()
        .contains("<svg"));
}
