//! The decider on synthetic embeddings: commits, hysteresis, back-off,
//! unknown textiles, malformed input, the press mean's weights.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use telextiles_press::decide::{DecideConfig, Decider, FlatIndex, PressOutcome, TextileIndex};

fn unit(v: &[f32]) -> Vec<f32> {
    let n = v.iter().map(|x| x * x).sum::<f32>().sqrt();
    v.iter().map(|x| x / n).collect()
}

/// Three textiles along orthogonal axes in 8-d.
fn toy_index() -> FlatIndex {
    let e = |k: usize| {
        let mut v = vec![0f32; 8];
        v[k] = 1.0;
        v
    };
    FlatIndex::from_embeddings(&[
        ("A".into(), vec![e(0)]),
        ("B".into(), vec![e(1)]),
        ("C".into(), vec![e(2)]),
    ])
    .unwrap()
    .with_slots(vec![3, 7, 11])
    .unwrap()
}

#[test]
fn no_decision_outside_a_press() {
    let idx = toy_index();
    // The confirmation rules alone: no early commit on a clear lead
    // (`a_clear_leader_commits_at_once...` below).
    let cfg = DecideConfig {
        commit_margin: f32::INFINITY,
        ..DecideConfig::default()
    };
    let mut d = Decider::new(cfg.clone(), 8);
    let a = unit(&[1.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    const P: u64 = 16_667; // 60 fps
    for k in 0..50 {
        assert_eq!(d.on_embedding(&idx, k * P, &a).unwrap().decision, None);
    }
    assert_eq!(d.press_end(&idx, 60 * P), None);
    d.press_start(100 * P);
    let mut first = None;
    for k in 100..130 {
        if let Some(dec) = d.on_embedding(&idx, k * P, &a).unwrap().decision {
            first.get_or_insert(k);
            assert_eq!((idx.id(dec.entry), dec.slot, dec.unknown), ("A", 3, false));
        }
    }
    // Counting starts min_ms after the first embedding (at once with the
    // default 0), and the textile must stay nearest for confirm_ms (50 ms:
    // from frame 100 to 103 at 60 fps).
    assert_eq!(cfg.min_ms, 0.0);
    assert_eq!(first, Some(103));
    let out = d.press_end(&idx, 130 * P).unwrap();
    assert_eq!(
        (out.first_decision_us, out.switches),
        (first.map(|k| k * P), 0)
    );
    // Never changed: the first decision is the final one.
    assert_eq!(out.first_entry, out.decision.map(|d| d.entry));
    // At 25 fps the same duration takes fewer frames: decided at frame 2
    // (80 ms), not after a fixed 3 frames (120 ms).
    const P25: u64 = 40_000;
    d.press_start(0);
    let mut first = None;
    for k in 0..20 {
        if d.on_embedding(&idx, k * P25, &a)
            .unwrap()
            .decision
            .is_some()
        {
            first.get_or_insert(k);
        }
    }
    assert_eq!(first, Some(2));
    // With a minimum the counting starts later: min_ms 50 and confirm_ms
    // 50 decide at frame 106 at 60 fps.
    let mut d = Decider::new(
        DecideConfig {
            min_ms: 50.0,
            ..cfg
        },
        8,
    );
    d.press_start(100 * P);
    let first =
        (100..130u64).find(|&k| d.on_embedding(&idx, k * P, &a).unwrap().decision.is_some());
    assert_eq!(first, Some(106));
}

/// `commit_margin`: a first decision whose leader is clearly nearest
/// commits on the second frame of its run; a close call still waits
/// `confirm_ms`; `f32::INFINITY` always waits. Only the first decision:
/// a change of decision keeps its own rule.
#[test]
fn a_clear_leader_commits_at_once_and_a_close_call_waits_for_confirmation() {
    let idx = toy_index();
    const P: u64 = 16_667; // 60 fps
    let first_at = |margin: f32, v: &[f32]| {
        let mut d = Decider::new(
            DecideConfig {
                commit_margin: margin,
                ..DecideConfig::default()
            },
            8,
        );
        d.press_start(0);
        (0..30u64).find(|&k| d.on_embedding(&idx, k * P, v).unwrap().decision.is_some())
    };
    // Clear: nearer A than B by about 1.2.
    let clear = unit(&[1.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    // Close: nearer A than B by about 0.05.
    let close = unit(&[1.0, 0.95, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let m = |v: &[f32]| {
        let n = idx.nearest2(v).unwrap();
        n.second_dist - n.best_dist
    };
    assert!(m(&clear) > 1.0 && (0.03..0.08).contains(&m(&close)));
    // The second frame of the run (16 ms), not the fourth (50 ms).
    assert_eq!(first_at(0.08, &clear), Some(1));
    assert_eq!(first_at(0.08, &close), Some(3));
    assert_eq!(first_at(0.04, &close), Some(1));
    assert_eq!(first_at(f32::INFINITY, &clear), Some(3));
    // Never on a single frame, however clear.
    assert_eq!(first_at(0.0, &clear), Some(1));
    // A later change of decision is not hurried by a clear lead: it
    // still waits `switch_ms`.
    let mut d = Decider::new(
        DecideConfig {
            commit_margin: 0.0,
            ..DecideConfig::default()
        },
        8,
    );
    d.press_start(0);
    let b = unit(&[0.0, 1.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0]);
    for k in 0..5u64 {
        d.on_embedding(&idx, k * P, &clear);
    }
    let switched = (5..60u64).find(|&k| {
        let s = d.on_embedding(&idx, k * P, &b).unwrap();
        s.changed && s.decision.is_some_and(|x| idx.id(x.entry) == "B")
    });
    let cfg = DecideConfig::default();
    let after_ms = (switched.unwrap() - 5) as f32 * P as f32 / 1000.0;
    assert!(after_ms >= cfg.switch_ms, "switched after {after_ms} ms");
}

/// `commit_weight`: the first decision waits for a frame of the press to
/// be that deep (contact weight), or for `commit_weight_ms`; the leader's
/// run counts meanwhile, so a clear leader commits on the frame the gate
/// opens. 0 (the default) waits for nothing.
#[test]
fn the_first_decision_waits_for_a_deep_frame_or_its_longest_wait() {
    let idx = toy_index();
    const P: u64 = 16_667; // 60 fps
    let clear = unit(&[1.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    // A ramp: shallow frames (weight 0.1), deep from frame 6 on (0.9).
    let ramp = |k: u64| if k < 6 { 0.1 } else { 0.9 };
    let first_at = |gate: (f32, f32), weight: &dyn Fn(u64) -> f32| {
        let mut d = Decider::new(
            DecideConfig {
                commit_weight: gate.0,
                commit_weight_ms: gate.1,
                ..DecideConfig::default()
            },
            8,
        );
        d.press_start(0);
        (0..40u64).find(|&k| {
            d.on_embedding_weighted(&idx, k * P, &clear, weight(k))
                .unwrap()
                .decision
                .is_some()
        })
    };
    // No gate: the clear leader's second frame.
    assert_eq!(first_at((0.0, 0.0), &ramp), Some(1));
    assert_eq!(
        (
            DecideConfig::default().commit_weight,
            DecideConfig::default().commit_weight_ms
        ),
        (0.0, 0.0)
    );
    // A gate of 0.5: the first deep frame (its run already long).
    assert_eq!(first_at((0.5, 200.0), &ramp), Some(6));
    // A gate the shallow frames pass: no wait.
    assert_eq!(first_at((0.05, 200.0), &ramp), Some(1));
    // A light press never gets deep: decided at the longest wait
    // (100 ms after the first embedding: frame 6 at 60 fps).
    assert_eq!(first_at((0.5, 100.0), &|_| 0.1), Some(6));
    assert_eq!(first_at((0.5, 200.0), &|_| 0.1), Some(12));
    // A wait of 0 is no gate.
    assert_eq!(first_at((0.5, 0.0), &|_| 0.1), Some(1));
}

/// Ten seconds of frames halfway between A and B (A very slightly nearer)
/// with heavy noise: the frames whose decision changed, and the outcome.
fn noisy_press(cfg: DecideConfig) -> (Vec<u64>, PressOutcome) {
    let idx = toy_index();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut d = Decider::new(cfg, 8);
    d.press_start(0);
    let mut changes = Vec::new();
    for t in 1..600u64 {
        let mut v: Vec<f32> = (0..8).map(|_| rng.gen_range(-0.6f32..0.6)).collect();
        v[0] += 1.0;
        v[1] += 0.97;
        if d.on_embedding(&idx, t * 16_667, &unit(&v)).unwrap().changed {
            changes.push(t);
        }
    }
    (changes, d.press_end(&idx, 600).unwrap())
}

#[test]
fn no_flip_flop_between_close_textiles_under_noise() {
    // The decider commits 50 ms after the first frame, on a mean of four
    // noisy frames, which may lean to B: then one correction, early, and
    // never again in ten seconds.
    let (changes, o) = noisy_press(DecideConfig::default());
    assert!(o.switches <= 1, "changes at frames {changes:?}");
    assert!(
        changes.iter().all(|&t| t < 60),
        "changes at frames {changes:?}"
    );
    assert_eq!(toy_index().id(o.decision.unwrap().entry), "A");
    // With a minimum of 50 ms before the first decision the mean has
    // settled: decided once, never switched.
    let (changes, o) = noisy_press(DecideConfig {
        min_ms: 50.0,
        ..DecideConfig::default()
    });
    assert_eq!((changes.len(), o.switches), (1, 0));
}

#[test]
fn a_real_change_of_textile_switches_after_k_frames() {
    let idx = toy_index();
    // 5 frames at 60 fps.
    let cfg = DecideConfig {
        switch_ms: 67.0,
        ..Default::default()
    };
    let mut d = Decider::new(cfg, 8);
    d.press_start(0);
    let a = unit(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let c = unit(&[0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    for t in 1..=20 {
        d.on_embedding(&idx, t * 16_667, &a);
    }
    let mut switched_at = None;
    for t in 21..=200 {
        let s = d.on_embedding(&idx, t * 16_667, &c).unwrap();
        if s.changed {
            switched_at = Some(t);
            assert_eq!(idx.id(s.decision.unwrap().entry), "C");
            break;
        }
    }
    // The running mean must first move past the midpoint (frame 40: 20 A + 20 C),
    // then lead by the margin for 5 frames.
    let t = switched_at.expect("switched");
    assert!(t > 40 && t <= 60, "switched at {t}");
    // The outcome keeps where the press went first, and where it ended.
    let o = d.press_end(&idx, 201 * 16_667).unwrap();
    let id = |e: Option<usize>| e.map(|e| idx.id(e));
    assert_eq!(
        (
            id(o.first_entry),
            id(o.decision.map(|d| d.entry)),
            o.switches
        ),
        (Some("A"), Some("C"), 1)
    );
    // A new press forgets it.
    d.press_start(300 * 16_667);
    assert_eq!(d.press_end(&idx, 301 * 16_667).unwrap().first_entry, None);
}

/// A press on A for 20 frames, then C, then B: the frames (60 fps) of
/// the changes of decision, and the decider after them.
fn a_then_c_then_b(backoff: f32) -> (Vec<u64>, Decider) {
    let idx = toy_index();
    let mut d = Decider::new(
        DecideConfig {
            switch_backoff: backoff,
            ..DecideConfig::default()
        },
        8,
    );
    d.press_start(0);
    let e = |k: usize| {
        let mut v = vec![0f32; 8];
        v[k] = 1.0;
        v
    };
    let mut changes = Vec::new();
    for t in 1..=400u64 {
        let v = match t {
            ..=20 => e(0),
            21..=120 => e(2),
            _ => e(1),
        };
        if d.on_embedding(&idx, t * 16_667, &v).unwrap().changed {
            changes.push(t);
        }
    }
    (changes, d)
}

#[test]
fn each_change_of_decision_makes_the_next_wait_longer_by_the_backoff() {
    // Without backoff: decided A, then C, then B, each change after the
    // challenger has led for switch_ms (117 ms, 8 frames).
    let (plain, _) = a_then_c_then_b(1.0);
    assert_eq!(plain.len(), 3, "{plain:?}");
    // With backoff 4 the first change (to C) is as fast; the second (to B)
    // waits 4 x 117 = 468 ms: 21 frames (351 ms) later.
    let (four, mut d) = a_then_c_then_b(4.0);
    assert_eq!(four.len(), 3, "{four:?}");
    assert_eq!(four[..2], plain[..2]);
    let later = four[2] - plain[2];
    assert!((20..=22).contains(&later), "{plain:?} {four:?}");
    // After two changes a third would wait 16 x 117 ms; a new press starts
    // over at 117 ms.
    assert_eq!(d.switch_wait_ms(), 16.0 * 117.0);
    d.press_end(&toy_index(), 400 * 16_667);
    d.press_start(500 * 16_667);
    assert_eq!(d.switch_wait_ms(), 117.0);
    // Infinite backoff: one change per press, then never again.
    assert_eq!(a_then_c_then_b(f32::INFINITY).0, plain[..2]);
    // Below 1 and NaN count as 1.
    assert_eq!(a_then_c_then_b(0.5).0, plain);
    assert_eq!(a_then_c_then_b(f32::NAN).0, plain);
}

#[test]
fn far_textiles_get_the_nearest_known_flagged_unknown() {
    let idx = toy_index();
    let mut d = Decider::new(DecideConfig::default(), 8);
    d.press_start(0);
    let far = unit(&[0.3, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
    let mut last = None;
    for t in 1..20 {
        last = d
            .on_embedding(&idx, t * 16_667, &far)
            .unwrap()
            .decision
            .or(last);
    }
    let dec = last.unwrap();
    assert_eq!(idx.id(dec.entry), "A");
    assert!(dec.unknown && dec.distance > 0.5, "{dec:?}");
    assert!(dec.confidence >= 0.0 && dec.confidence <= 1.0);
}

/// An index that carries its own unknown-textile distance (calibrated on
/// its presses) overrides the decider's fixed one, both ways.
#[test]
fn the_index_s_own_unknown_distance_overrides_the_fixed_one() {
    let mut b = telextiles_index::IndexBuilder::new("h", "test", 8, 0);
    for k in 0..4 {
        let mut v = vec![0f32; 8];
        v[k] = 1.0;
        b.add(telextiles_index::TextileRecord {
            id: format!("T{k}"),
            name: String::new(),
            seen: true,
            structure: String::new(),
            attributes: vec![],
            embeddings: vec![v],
            exemplars: vec![],
            press_frames: Vec::new(),
        })
        .unwrap();
    }
    b.roller_n = 4;
    let mut index = b.build().unwrap();
    let decide = |index: &telextiles_index::Index, q: &[f32]| {
        let mut d = Decider::new(DecideConfig::default(), 8);
        d.press_start(0);
        let mut last = None;
        for t in 1..20 {
            last = d
                .on_embedding(index, t * 16_667, q)
                .unwrap()
                .decision
                .or(last);
        }
        let dec = last.unwrap();
        assert_eq!(index.id(dec.entry), "T0");
        dec
    };
    // About 0.3 from T0: known under the fixed 0.5.
    let near = unit(&[1.0, 0.3, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    // About 0.8 from T0: unknown under the fixed 0.5.
    let far = unit(&[1.0, 0.9, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    assert!(!decide(&index, &near).unknown);
    assert!(decide(&index, &far).unknown);
    let calibrated = |distance| telextiles_index::UnknownDistance {
        distance,
        quantile: 0.95,
        presses: 20,
    };
    index.unknown = Some(calibrated(0.2));
    let dec = decide(&index, &near);
    assert!(
        dec.unknown && dec.distance > 0.2 && dec.distance < 0.5,
        "{dec:?}"
    );
    index.unknown = Some(calibrated(1.0));
    assert!(!decide(&index, &far).unknown);
}

/// Whatever a peer sends: an embedding of another dimension, with NaN or
/// infinity, or all zeros is refused (None) and leaves the press as it was;
/// decisions go on with the next good one.
#[test]
fn malformed_embeddings_are_refused_without_a_panic_and_change_nothing() {
    let idx = toy_index();
    let mut d = Decider::new(DecideConfig::default(), 8);
    d.press_start(0);
    let a = unit(&[1.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    d.on_embedding(&idx, 16_667, &a).unwrap();
    let mean = d.mean().to_vec();
    let mut nan = a.clone();
    nan[3] = f32::NAN;
    let mut inf = a.clone();
    inf[0] = f32::INFINITY;
    for bad in [
        vec![1.0; 7],
        vec![1.0; 9],
        Vec::new(),
        nan,
        inf,
        vec![0.0; 8],
    ] {
        assert!(d.on_embedding(&idx, 33_333, &bad).is_none(), "{bad:?}");
        assert!(d.accumulate(&bad).is_none());
        assert_eq!(d.mean(), &mean[..]);
        assert!(idx.nearest2(&bad).is_none() || bad.len() == 8 && bad.iter().all(|v| *v == 0.0));
    }
    let mut decided = false;
    for k in 2..20 {
        decided |= d
            .on_embedding(&idx, k * 16_667, &a)
            .unwrap()
            .decision
            .is_some();
    }
    assert!(decided);
}

/// Frames count in a press's mean by their contact depth: a few shallow
/// frames of the ramp that look like B do not outweigh deep frames of A,
/// which they do when every frame counts the same. Weights that are not
/// finite and positive are refused and change nothing.
#[test]
fn deep_frames_outweigh_shallow_ones_in_the_mean() {
    use telextiles_press::decide::contact_weight;
    let idx = toy_index();
    let a = unit(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let b = unit(&[0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    // Ramp: 4 frames like B at 0.3 DN of contact; then 2 deep frames like
    // A at 12 DN.
    let frames = [
        (&b, 0.3),
        (&b, 0.3),
        (&b, 0.3),
        (&b, 0.3),
        (&a, 12.0),
        (&a, 12.0),
    ];
    let nearest = |weighted: bool| {
        let mut d = Decider::new(DecideConfig::default(), 8);
        d.press_start(0);
        for (e, score) in frames {
            let w = if weighted { contact_weight(score) } else { 1.0 };
            d.accumulate_weighted(e, w).unwrap();
        }
        idx.nearest2(d.mean()).unwrap().best
    };
    assert_eq!(idx.id(nearest(false)), "B");
    assert_eq!(idx.id(nearest(true)), "A");
    // The weight function: rises with depth and saturates, so a frame far
    // from the reference (a dropout) weighs no more than full contact.
    assert!((contact_weight(4.0) - (1.0 - (-1.0f32).exp())).abs() < 1e-6);
    assert!(contact_weight(0.5) < contact_weight(2.0));
    assert!(contact_weight(20.0) > 0.99);
    assert_eq!(contact_weight(200.0), 1.0);
    assert_eq!(contact_weight(0.0), 1e-3);
    assert_eq!(contact_weight(-3.0), 1e-3);
    assert_eq!(contact_weight(f32::NAN), 1e-3);
    let mut d = Decider::new(DecideConfig::default(), 8);
    d.press_start(0);
    d.accumulate_weighted(&a, 0.5).unwrap();
    let mean = d.mean().to_vec();
    for w in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(d.accumulate_weighted(&b, w).is_none(), "{w}");
        assert!(
            d.on_embedding_weighted(&idx, 16_667, &b, w).is_none(),
            "{w}"
        );
        assert_eq!(d.mean(), &mean[..]);
    }
}

/// Within the ramp the newest frame is the deepest and the best view of the
/// fabric: with the default `depth_power` two frames of A near the end of a
/// ramp outweigh four shallower frames of B before them, which they do not
/// when frames count by their weight alone (`depth_power` 1). In the hold,
/// where the weights saturate, frames count about the same, and the
/// release's shallow frames hardly move the mean.
#[test]
fn the_ramps_newest_frames_lead_the_mean() {
    use telextiles_press::decide::contact_weight;
    let idx = toy_index();
    let a = unit(&[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let b = unit(&[0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
    let run = |power: u32, frames: &[(&Vec<f32>, f32)]| {
        let cfg = DecideConfig {
            depth_power: power,
            ..DecideConfig::default()
        };
        let mut d = Decider::new(cfg, 8);
        d.press_start(0);
        for (e, score) in frames {
            d.accumulate_weighted(e, contact_weight(*score)).unwrap();
        }
        d.mean().to_vec()
    };
    let ramp = [
        (&b, 0.8),
        (&b, 1.0),
        (&b, 1.3),
        (&b, 1.8),
        (&a, 2.3),
        (&a, 3.0),
    ];
    assert_eq!(idx.id(idx.nearest2(&run(1, &ramp)).unwrap().best), "B");
    let power = DecideConfig::default().depth_power;
    assert!(power > 1);
    assert_eq!(idx.id(idx.nearest2(&run(power, &ramp)).unwrap().best), "A");
    // Hold: six frames at 9-11 DN, three of each: the mean stays between
    // them (each side's share within 0.35..0.65).
    let hold = [
        (&a, 10.0),
        (&b, 11.0),
        (&a, 9.0),
        (&b, 10.0),
        (&a, 11.0),
        (&b, 9.0),
    ];
    let m = run(power, &hold);
    let share = m[0] / (m[0] + m[1]);
    assert!((0.35..0.65).contains(&share), "{share}");
    // Release: four frames of A in full contact, then six shallow frames of
    // B as the fabric lifts off: the mean stays on A.
    let release = [
        (&a, 10.0),
        (&a, 10.0),
        (&a, 10.0),
        (&a, 10.0),
        (&b, 2.0),
        (&b, 1.5),
        (&b, 1.0),
        (&b, 0.8),
        (&b, 0.6),
        (&b, 0.5),
    ];
    let m = run(power, &release);
    assert!(m[0] > 0.99, "{m:?}");
    // Counted the same (power 0), the release's six frames win.
    assert_eq!(idx.id(idx.nearest2(&run(0, &release)).unwrap().best), "B");
    // ... and A's share is larger the steeper the power.
    assert!(run(1, &release)[0] < m[0]);
}

/// `PressMean` keeps a running sum whose direction is that of
/// `Σ w_i^p e_i / |e_i|`, in any order of the weights, and stays finite and
/// non-zero for weights as small as a latent carries; it refuses what the
/// decider refuses.
#[test]
fn the_press_mean_is_the_powered_mean() {
    use telextiles_press::decide::PressMean;
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for power in [0u32, 1, 4, 8, 12] {
        let mut m = PressMean::new(4, power);
        let mut want = vec![0f64; 4];
        for _ in 0..40 {
            let w: f32 = if rng.gen_bool(0.2) {
                1e-3
            } else {
                rng.gen_range(0.05..1.0)
            };
            let e: Vec<f32> = (0..4).map(|_| rng.gen_range(-1.0..1.0)).collect();
            assert!(m.add(&e, w));
            let n = e.iter().map(|&x| (x as f64).powi(2)).sum::<f64>().sqrt();
            for k in 0..4 {
                want[k] += (w as f64).powi(power as i32) * e[k] as f64 / n;
            }
        }
        let unit = |v: Vec<f64>| {
            let l = v.iter().map(|x| x * x).sum::<f64>().sqrt();
            v.into_iter().map(|x| x / l).collect::<Vec<_>>()
        };
        let got = unit(m.sum().iter().map(|&x| x as f64).collect());
        let want = unit(want);
        for k in 0..4 {
            assert!(
                (got[k] - want[k]).abs() < 1e-4,
                "power {power}: {got:?} vs {want:?}"
            );
        }
    }
    // Only the smallest weight, at a high power: still a direction.
    let mut m = PressMean::new(2, 12);
    for _ in 0..10 {
        assert!(m.add(&[3.0, 0.0], 1e-3));
    }
    assert_eq!(m.sum(), [10.0, 0.0]);
    // Refused, and nothing changes.
    for (e, w) in [
        (&[1.0, 0.0][..], 0.0),
        (&[1.0, 0.0][..], f32::NAN),
        (&[1.0, 0.0][..], -1.0),
        (&[0.0, 0.0][..], 1.0),
        (&[f32::INFINITY, 0.0][..], 1.0),
        (&[1.0][..], 1.0),
    ] {
        assert!(!m.add(e, w));
        assert_eq!(m.sum(), [10.0, 0.0]);
    }
    m.clear();
    assert_eq!(m.sum(), [0.0, 0.0]);
    // Any power is safe: the deepest frame leads, the sum stays finite.
    let mut m = PressMean::new(2, u32::MAX);
    assert!(m.add(&[1.0, 0.0], 0.5));
    assert!(m.add(&[0.0, 1.0], 0.9));
    assert!(m.add(&[1.0, 0.0], 0.4));
    let s = m.sum();
    assert!(s[0].is_finite() && s[0] < 1e-15 && s[1] == 1.0, "{s:?}");
}
