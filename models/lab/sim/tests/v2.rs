//! Catalogue version 2: determinism, bolts and swatches, frame rates,
//! reference frames, presses, sensor units, camera noise, the second
//! generator and the validation statistics on a small sample.
use telextiles_sim::catalogue::Family;
use telextiles_sim::{
    bolt, recording, sensor_model_v2, stats, Catalogue, PressSpec, SimError, Simulator,
    FPS_CHOICES, V2_UNITS,
};

fn v2(id: &str, seed: u64) -> PressSpec {
    PressSpec {
        catalogue: Some(2),
        ..PressSpec::new(id, seed)
    }
}

fn mean_abs(a: &telextiles_sim::RgbImage, b: &telextiles_sim::RgbImage) -> f32 {
    let s: f64 = a
        .as_raw()
        .iter()
        .zip(b.as_raw())
        .map(|(x, y)| (*x as f64 - *y as f64).abs())
        .sum();
    (s / a.as_raw().len() as f64) as f32
}

#[test]
fn v2_is_deterministic_per_seed_and_differs_from_v1() {
    let spec = PressSpec {
        frames: 40,
        person: 4,
        jig: false,
        sensor: 5,
        ..PressSpec::new("T030", 11)
    };
    // the simulator's default catalogue and the spec's field select the same
    let a = Simulator::with_catalogue(2)
        .unwrap()
        .render_press(&spec)
        .unwrap();
    let sim = Simulator::new().unwrap();
    let b = sim
        .render_press(&PressSpec {
            catalogue: Some(2),
            ..spec.clone()
        })
        .unwrap();
    assert_eq!(a.frames, b.frames);
    assert_eq!(a.meta, b.meta);
    let p = a.meta.params.as_ref().unwrap();
    assert_eq!((p.catalogue_version, p.generator), (2, 1));
    assert_eq!(a.meta.sensor_serial.as_deref(), Some("SIM2-0005"));
    assert!(p.swatch.is_some());
    // another seed, another press; catalogue 1 renders something else
    let c = sim
        .render_frame(
            &PressSpec {
                seed: 12,
                catalogue: Some(2),
                ..spec.clone()
            },
            39,
        )
        .unwrap();
    assert_ne!(c, a.frames[39]);
    let v1 = sim.render_frame(&spec, 39).unwrap();
    assert_ne!(v1, a.frames[39]);
    assert_eq!(
        sim.press_meta(&spec)
            .unwrap()
            .params
            .unwrap()
            .catalogue_version,
        1
    );
}

#[test]
fn a_textile_is_a_bolt_and_presses_see_different_swatches() {
    let cat = Catalogue::version(2).unwrap();
    let t = cat.get("T001").unwrap();
    // two overlapping windows of one swatch show the same cloth on the overlap
    let sw = bolt::swatch(t, 3);
    let (ox, oy) = (sw.origin.0 as i64 / 8 * 8, sw.origin.1 as i64 / 8 * 8);
    let a = bolt::window(t, &sw, ox, oy, 128);
    let b = bolt::window(t, &sw, ox + 48, oy + 16, 128);
    let mut max_diff = 0f32;
    for y in 8..100 {
        for x in 8..70 {
            let va = a.h[(y + 16) * 128 + x + 48];
            let vb = b.h[y * 128 + x];
            max_diff = max_diff.max((va - vb).abs());
        }
    }
    assert!(max_diff < 1e-5, "overlap differs by {max_diff} mm");
    // another swatch of the same textile is other cloth
    let sw4 = bolt::swatch(t, 4);
    assert!((sw4.origin.0 - sw.origin.0).abs() > 1000.0);
    let other = bolt::window(t, &sw4, sw4.origin.0 as i64, sw4.origin.1 as i64, 128);
    let d: f32 =
        a.h.iter()
            .zip(&other.h)
            .map(|(x, y)| (x - y).abs())
            .sum::<f32>()
            / a.h.len() as f32;
    assert!(d > 0.1 * t.relief_mm, "swatches too alike: {d} mm");
    // presses by different people and seeds land on different swatches
    let sim = Simulator::with_catalogue(2).unwrap();
    let mut swatches = std::collections::BTreeSet::new();
    for k in 0..12u64 {
        let s = PressSpec {
            person: (k % 11) as u32,
            ..PressSpec::new("T001", k)
        };
        swatches.insert(telextiles_sim::swatch_of(&s));
    }
    assert!(swatches.len() >= 4, "{swatches:?}");
    // same pose, different swatch: different frames
    let pose = |seed: u64, person: u32| PressSpec {
        person,
        noise: false,
        rotation_deg: Some(0.0),
        offset_mm: Some([0.0, 0.0]),
        force: Some(4.0),
        tilt_deg: Some([0.0, 0.0]),
        ..PressSpec::new("T001", seed)
    };
    let (s1, s2) = (0..40u64)
        .flat_map(|a| (0..40u64).map(move |b| (a, b)))
        .map(|(a, b)| (pose(a, 0), pose(b, 1)))
        .find(|(x, y)| {
            telextiles_sim::swatch_of(x) != telextiles_sim::swatch_of(y)
                && sim
                    .press_meta(x)
                    .unwrap()
                    .params
                    .unwrap()
                    .features
                    .is_empty()
                && sim
                    .press_meta(y)
                    .unwrap()
                    .params
                    .unwrap()
                    .features
                    .is_empty()
        })
        .expect("two plain presses on different swatches");
    let bg = sim.background(0);
    let f1 = sim.render_frame(&s1, 120).unwrap();
    let f2 = sim.render_frame(&s2, 120).unwrap();
    assert!(
        mean_abs(&f1, &f2) > 0.5 * mean_abs(&f1, &bg),
        "{} vs {}",
        mean_abs(&f1, &f2),
        mean_abs(&f1, &bg)
    );
}

#[test]
fn fps_is_honoured_and_drawn_from_the_choices() {
    let sim = Simulator::new().unwrap();
    for fps in [25.0f32, 60.0] {
        let m = sim
            .press_meta(&PressSpec {
                fps: Some(fps),
                frames: 30,
                ..v2("T010", 1)
            })
            .unwrap();
        assert_eq!(m.fps, fps);
        for (i, t) in m.timestamps_us.iter().enumerate() {
            assert_eq!(*t, (i as f64 * 1e6 / fps as f64).round() as u64);
        }
    }
    let drawn: std::collections::BTreeSet<u32> = (0..16u64)
        .map(|s| {
            let m = sim
                .press_meta(&PressSpec {
                    frames: 20,
                    ..v2("T010", s)
                })
                .unwrap();
            assert!(FPS_CHOICES.contains(&m.fps), "{}", m.fps);
            m.fps as u32
        })
        .collect();
    assert!(drawn.len() >= 2, "{drawn:?}");
    // catalogue 1 is 60 fps only; rates outside 25..60 are refused
    let e = sim.press_meta(&PressSpec {
        fps: Some(30.0),
        ..PressSpec::new("T010", 1)
    });
    assert!(matches!(e, Err(SimError::InvalidSpec(_))));
    let e = sim.press_meta(&PressSpec {
        fps: Some(100.0),
        ..v2("T010", 1)
    });
    assert!(matches!(e, Err(SimError::InvalidSpec(_))));
}

#[test]
fn reference_frames_are_the_untouched_frames_before_contact() {
    let sim = Simulator::with_catalogue(2).unwrap();
    let other = Simulator::new().unwrap();
    for (k, (id, jig, sensor)) in [("T005", true, 0u32), ("T082", false, 3), ("T109", false, 9)]
        .into_iter()
        .enumerate()
    {
        let spec = PressSpec {
            jig,
            sensor,
            person: 2 + k as u32,
            noise: false,
            frames: 60,
            fps: Some(30.0),
            ..PressSpec::new(id, 3 + k as u64)
        };
        let m = sim.press_meta(&spec).unwrap();
        let p = m.params.unwrap();
        let r = m.reference_frames.expect("reference frames") as usize;
        assert_eq!(r, p.contact_frame as usize);
        assert!(r >= 3, "{r}");
        let bg = sim.background(sensor);
        let spec2 = PressSpec {
            catalogue: Some(2),
            ..spec.clone()
        };
        assert_eq!(other.background_for(&spec2).unwrap(), bg);
        for i in 0..r {
            assert_eq!(sim.render_frame(&spec, i).unwrap(), bg, "{id} frame {i}");
        }
        let hold = sim.render_frame(&spec, p.hold_frame as usize).unwrap();
        assert!(mean_abs(&hold, &bg) > 0.3, "{id}: no contact at the hold");
    }
}

#[test]
fn presses_ramp_slow_and_fast_touch_partly_and_release() {
    let sim = Simulator::with_catalogue(2).unwrap();
    let mut feats = std::collections::BTreeMap::<String, usize>::new();
    let mut releases = 0;
    let n = 24u64;
    for s in 0..n {
        let m = sim
            .press_meta(&PressSpec {
                jig: false,
                person: (s % 11) as u32,
                frames: 150,
                ..PressSpec::new(format!("T{:03}", 1 + s * 4), s)
            })
            .unwrap();
        let p = m.params.unwrap();
        if let Some(r) = p.release_frame {
            releases += 1;
            assert!(r > p.hold_frame);
        }
        for f in p.features {
            *feats.entry(f).or_default() += 1;
        }
    }
    for f in ["slow-ramp", "fast-ramp"] {
        assert!(feats.get(f).copied().unwrap_or(0) >= 2, "{f}: {feats:?}");
    }
    let partial = feats.get("tilt").copied().unwrap_or(0) + feats.get("edge").copied().unwrap_or(0);
    assert!(partial >= 2, "{feats:?}");
    assert!(releases as u64 >= n / 3, "{releases} of {n} release");
}

#[test]
fn sixteen_sensor_units_with_their_own_colour_layout() {
    let sim = Simulator::new().unwrap();
    let bgs: Vec<_> = (0..V2_UNITS).map(|u| sim.background_of(2, u)).collect();
    for i in 0..bgs.len() {
        for j in i + 1..bgs.len() {
            let d = mean_abs(&bgs[i], &bgs[j]);
            assert!(d > 2.0, "units {i} and {j} differ by {d}");
        }
    }
    // units 0 and 1 are the two real frames through a camera
    assert!(mean_abs(&bgs[0], sim.real_background()) < 3.0);
    assert!(mean_abs(&bgs[1], sim.real_background_tvl()) < 3.0);
    let (mut turned, mut tvl) = (0, 0);
    for u in 0..V2_UNITS {
        let s = sensor_model_v2(u);
        for c in 0..3 {
            assert!((0.75..=1.3).contains(&s.led_gain[c]));
            let d = s.led_dir_deg[c] - if s.turned { 180.0 } else { 0.0 };
            assert!(d.abs() <= 25.0, "unit {u}: LED direction {d}");
        }
        assert!((0.6..=1.6).contains(&s.gel_thickness_mm));
        turned += s.turned as u32;
        tvl += (s.base_mix > 0.5) as u32;
    }
    assert!(
        turned >= 2 && (4..=12).contains(&tvl),
        "{turned} turned, {tvl} tvl-based"
    );
    // the unit-to-unit difference is of the order of the two real units'
    let real = stats::background_difference(sim.real_background(), sim.real_background_tvl());
    let v2 = stats::unit_background_difference(&sim, 2, V2_UNITS);
    let v1 = stats::unit_background_difference(&sim, 1, V2_UNITS);
    assert!(v2 > 0.6 * real && v2 < 2.0 * real, "v2 {v2}, real {real}");
    assert!(v2 > 1.5 * v1, "v2 {v2}, v1 {v1}");
}

#[test]
fn generator_2_is_a_different_construction() {
    let sim = Simulator::new().unwrap();
    let spec = PressSpec {
        frames: 30,
        noise: false,
        ..v2("T050", 2)
    };
    let g2 = PressSpec {
        generator: Some(2),
        ..spec.clone()
    };
    let m = sim.press_meta(&g2).unwrap();
    assert_eq!(m.params.as_ref().unwrap().generator, 2);
    let a = sim.render_frame(&g2, 29).unwrap();
    let b = Simulator::with_options(2, 2)
        .unwrap()
        .render_frame(&spec, 29)
        .unwrap();
    assert_eq!(a, b, "with_options(2, 2) is the default for the spec");
    let g1 = sim.render_frame(&spec, 29).unwrap();
    assert!(mean_abs(&a, &g1) > 0.3);
    assert!(matches!(
        sim.press_meta(&PressSpec {
            generator: Some(2),
            ..PressSpec::new("T050", 2)
        }),
        Err(SimError::InvalidSpec(_))
    ));
    assert!(Simulator::with_options(1, 2).is_err());
    assert!(Simulator::with_catalogue(3).is_err());
}

#[test]
fn spec_json_is_backward_compatible_and_v2_presses_round_trip() {
    let old = r#"{"textile":"T001","person":0,"sensor":0,"jig":true,"seed":3,"rotation_deg":null,"force":null,"offset_mm":null,"release":null,"frames":150,"noise":true}"#;
    let s = PressSpec::from_json(old).unwrap();
    assert_eq!(s, PressSpec::new("T001", 3));
    assert!(!PressSpec::new("T001", 3).to_json().contains("catalogue"));
    let v = PressSpec {
        generator: Some(2),
        fps: Some(25.0),
        ..v2("U03", 9)
    };
    assert_eq!(PressSpec::from_json(&v.to_json()).unwrap(), v);
    let sim = Simulator::new().unwrap();
    let press = sim
        .render_press(&PressSpec {
            frames: 4,
            ..v.clone()
        })
        .unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("p");
    recording::write_press(&dir, &press).unwrap();
    let back = recording::read_press(&dir).unwrap();
    assert_eq!(back, press);
    assert_eq!(back.meta.fps, 25.0);
}

#[test]
fn validation_statistics_on_a_small_sample() {
    let sim = Simulator::new().unwrap();
    let sample = |v: u32, fams: &[Family], per: usize| -> Vec<stats::PressStats> {
        stats::sample_specs(&sim, v, 1, per, V2_UNITS)
            .into_iter()
            .filter(|s| {
                let f = sim
                    .catalogue_of(v)
                    .get(&s.textile)
                    .unwrap()
                    .structure
                    .family();
                fams.contains(&f)
            })
            .map(|s| stats::press_stats(&sim, &PressSpec { frames: 90, ..s }).unwrap())
            .collect()
    };
    let med = |v: Vec<f32>| {
        let mut v = v;
        v.sort_by(|a, b| a.total_cmp(b));
        v[v.len() / 2]
    };
    // soft fabrics are genuinely hard: about half the contrast of terry,
    // loops and tufts
    let soft = sample(2, &[Family::Soft], 3);
    let rough = sample(2, &[Family::Terry, Family::Tuft], 2);
    let s = med(soft.iter().map(|r| r.contact_std).collect());
    let r = med(rough.iter().map(|r| r.contact_std).collect());
    assert!((0.8..=2.2).contains(&s), "soft {s}");
    assert!(r >= 2.2 && s < 0.75 * r, "soft {s} vs rough {r}");
    // camera noise: smooth and colour-correlated in v2, white in v1
    for p in soft.iter().chain(&rough) {
        assert!(
            (0.25..=0.9).contains(&p.noise_lag1),
            "{}: {}",
            p.textile,
            p.noise_lag1
        );
        assert!(p.noise_colour > 0.3, "{}: {}", p.textile, p.noise_colour);
    }
    let v1 = sample(1, &[Family::Plain, Family::Knit], 1);
    for p in &v1 {
        assert!(p.noise_lag1.abs() < 0.05 && p.noise_colour.abs() < 0.05);
    }
    // one frame's fine structure (5x5 residual) against the real frames':
    // v2 within their range, v1 twice as strong and white
    let real: Vec<(f32, f32)> = [sim.real_background(), sim.real_background_tvl()]
        .into_iter()
        .map(stats::residual_noise)
        .collect();
    let (lo_sd, hi_sd) = (real[0].0.min(real[1].0), real[0].0.max(real[1].0));
    let (lo_lag, hi_lag) = (real[0].1.min(real[1].1), real[0].1.max(real[1].1));
    let r2 = med(soft.iter().chain(&rough).map(|p| p.residual.0).collect());
    let l2 = med(soft.iter().chain(&rough).map(|p| p.residual.1).collect());
    assert!(
        r2 > 0.7 * lo_sd && r2 < 1.4 * hi_sd,
        "v2 residual {r2}, real {real:?}"
    );
    assert!(
        l2 > 0.7 * lo_lag && l2 < 1.3 * hi_lag,
        "v2 lag-1 {l2}, real {real:?}"
    );
    let r1 = med(v1.iter().map(|p| p.residual.0).collect());
    let l1 = med(v1.iter().map(|p| p.residual.1).collect());
    assert!(
        r1 > 1.5 * hi_sd && l1 < 0.5 * lo_lag,
        "v1 {r1} / {l1}, real {real:?}"
    );
    // periodicity of plain-cloth woven/knit presses: well below v1's
    let fams = [Family::Plain, Family::Satin, Family::Knit];
    let peaks = |rows: Vec<stats::PressStats>| -> Vec<f32> {
        rows.iter()
            .filter(|p| p.plain_cloth())
            .map(|p| p.peak_to_median as f32)
            .collect()
    };
    let p2 = peaks(sample(2, &fams, 2));
    let p1 = peaks(sample(1, &fams, 2));
    assert!(p2.len() >= 2 && p1.len() >= 4, "{p2:?} {p1:?}");
    let (m2, m1) = (med(p2.clone()), med(p1.clone()));
    assert!(m2 < 0.6 * m1, "v2 {p2:?} vs v1 {p1:?}");
    assert!(p2.iter().all(|p| *p <= 11_000.0), "{p2:?}");
}
