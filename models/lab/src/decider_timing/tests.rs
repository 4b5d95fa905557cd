use super::*;

fn index() -> FlatIndex {
    FlatIndex::from_embeddings(&[
        ("A".into(), vec![vec![1.0, 0.0]]),
        ("B".into(), vec![vec![0.0, 1.0]]),
    ])
    .unwrap()
}

/// A press at 60 fps detected `detect_ms` after contact whose frames
/// point at `rows`.
fn trace(class: usize, detect_ms: f64, rows: &[[f32; 2]]) -> PressTrace {
    let mut emb = PressEmbedding {
        dim: 2,
        ..PressEmbedding::default()
    };
    for (k, r) in rows.iter().enumerate() {
        let n = (r[0] * r[0] + r[1] * r[1]).sqrt();
        emb.rows.extend([r[0] / n, r[1] / n]);
        emb.frames.push(k);
        emb.t_ms.push(k as f64 * 1000.0 / 60.0);
        emb.weights.push(1.0);
    }
    PressTrace {
        class,
        jig: true,
        detect_ms,
        emb,
    }
}

#[test]
fn the_shipped_timing_rules_are_a_candidate_and_the_first_is_the_old_pair() {
    // The shipped front end does not encode the run (off by default).
    let shipped = Timing::shipped();
    assert!(!shipped.run);
    assert!(candidates().contains(&shipped), "{}", shipped.label());
    assert_eq!(candidates()[0], t(50.0, 50.0, false));
    assert_eq!(
        candidates().len(),
        2 * PAIRS.len() + 2 * COMMIT_MARGINS.len() + DEPTH_GATES.len()
    );
    assert_eq!(
        config(&shipped).commit_margin,
        DecideConfig::default().commit_margin
    );
    assert_eq!(t(0.0, 50.0, false).commit_margin, None);
    assert_eq!(config(&t(0.0, 50.0, false)).commit_margin, f32::INFINITY);
}

#[test]
fn a_steady_press_commits_after_min_and_confirm_and_counts_from_then() {
    let p = trace(0, 33.3, &[[1.0, 0.1]; 40]);
    // Shipped pair: the first frame at 33 ms, bumping starts at 83 ms
    // (min 50), commits at 133 ms (confirm 50).
    let r = run_press(
        &index(),
        &config(&t(50.0, 50.0, false)),
        &p,
        false,
        &[100.0, 150.0],
    );
    assert_eq!(r.at, vec![None, Some(0)]);
    let (at, c) = r.first.unwrap();
    assert_eq!(c, 0);
    assert!((at - 133.3).abs() < 0.1, "first decision at {at}");
    // No minimum and a short confirmation commit by 100 ms.
    let r = run_press(&index(), &config(&t(0.0, 17.0, false)), &p, false, &[100.0]);
    assert_eq!(r.at, vec![Some(0)]);
    // bumping from the first frame (33 ms), confirmed 33 ms later.
    assert!((r.first.unwrap().0 - 66.7).abs() < 0.1);
    assert_eq!(r.switches, 0);
}

#[test]
fn an_early_wrong_lead_is_what_an_early_commit_pays_for() {
    // B leads the running mean for the first 2 frames, A after.
    let mut rows = vec![[0.1, 1.0]; 2];
    rows.extend(vec![[1.0, 0.0]; 40]);
    let p = trace(0, 33.3, &rows);
    let early = score(&index(), &[&p], "jig", &[t(0.0, 17.0, false)]);
    let late = score(&index(), &[&p], "jig", &[t(50.0, 50.0, false)]);
    assert_eq!(early[0].first_right, 0.0);
    assert_eq!(early[0].switches_per_100, 100.0);
    assert_eq!(late[0].first_right, 1.0);
    assert_eq!(late[0].switches_per_100, 0.0);
    assert_eq!(early[0].final_right, 1.0);
    assert_eq!(late[0].final_right, 1.0);
}

#[test]
fn a_press_never_started_counts_as_never_right() {
    let seen = trace(0, 33.3, &[[1.0, 0.1]; 40]);
    let never = PressTrace {
        detect_ms: f64::NAN,
        ..trace(1, 0.0, &[])
    };
    let s = &score(&index(), &[&seen, &never], "jig", &[t(0.0, 50.0, true)])[0];
    assert_eq!((s.presses, s.final_right, s.first_right), (2, 0.5, 1.0));
    assert_eq!(s.right(500.0), 0.5);
    assert_eq!(s.switches_per_100, 0.0);
}

fn t(min_ms: f32, confirm_ms: f32, run: bool) -> Timing {
    Timing::pair(min_ms, confirm_ms, run)
}

#[test]
fn the_encoded_run_starts_the_decision_two_frames_sooner() {
    // Two run frames before the frame the detector started the press
    // on; the press's start (the run's first frame) at 33 ms.
    let mut p = trace(0, 33.3, &[[1.0, 0.1]; 40]);
    p.emb.early = 2;
    let cfg = config(&t(0.0, 50.0, false));
    let with = run_press(&index(), &cfg, &p, true, &[100.0]);
    let without = run_press(&index(), &cfg, &p, false, &[100.0]);
    // With the run: bumping from 33 ms, committed 50 ms later. Without
    // it: the first embedding at 67 ms, committed at 117 ms.
    assert!(
        (with.first.unwrap().0 - 83.3).abs() < 0.1,
        "{:?}",
        with.first
    );
    assert!((without.first.unwrap().0 - 116.7).abs() < 0.1);
    assert_eq!((with.at[0], without.at[0]), (Some(0), None));
    // The score and the report keep the two apart.
    let sc = score(
        &index(),
        &[&p],
        "jig",
        &[t(0.0, 50.0, false), t(0.0, 50.0, true)],
    );
    assert_eq!((sc[0].right(100.0), sc[1].right(100.0)), (0.0, 1.0));
    assert!(!sc[0].timing.run && sc[1].timing.run);
    assert_eq!(sc[1].timing.label(), "0 / 50 + run");
}

fn s(pair: Timing, group: &str, mean: f64, first: f64, fin: f64) -> TimingScore {
    TimingScore {
        timing: pair,
        group: group.into(),
        presses: 100,
        right_at: vec![(100.0, mean)],
        decided_at: vec![(100.0, 1.0)],
        curve: vec![(100.0, mean)],
        mean_right: mean,
        first_ms_p50: 100.0,
        first_right: first,
        final_right: fin,
        switches_per_100: 0.0,
        from_right_per_100: 0.0,
    }
}

#[test]
fn the_report_marks_the_chosen_pair_and_draws_both_groups() {
    let p = trace(0, 33.3, &[[1.0, 0.1]; 40]);
    let cands = candidates();
    let mut scores = score(&index(), &[&p], "jig", &cands);
    scores.extend(score(&index(), &[&p], "hand-held", &cands));
    let chosen = cands[choose(&scores, &cands).unwrap()];
    // One steady press: every pair is right from its first decision, so
    // the earliest (0 / 16) has the best mean.
    // (The press has no run rows, so with the run encoded nothing
    // changes, and the tie goes to the earlier candidate.)
    assert_eq!(chosen, t(0.0, 16.0, false));
    let r = TimingReport {
        machine: "test".into(),
        date: "today".into(),
        command: "decider-timing".into(),
        source: "sim".into(),
        model: "m".into(),
        candidates: cands,
        scores,
        chosen,
        switch_candidates: Vec::new(),
        switch_scores: Vec::new(),
        switch_chosen: None,
        detect_ms_p50: vec![("jig".into(), 33.3)],
        undetected: vec![("jig".into(), 0), ("hand-held".into(), 0)],
        seconds: 0.0,
        contact: None,
    };
    let dir = tempfile::tempdir().unwrap();
    write(&r, dir.path()).unwrap();
    let md = std::fs::read_to_string(dir.path().join("report.md")).unwrap();
    assert!(md.contains("| **0 / 16** |"), "{md}");
    assert!(md.contains("## hand-held (1 presses)"), "{md}");
    for g in ["jig", "hand-held"] {
        let svg = std::fs::read_to_string(dir.path().join(format!("committed-{g}.svg"))).unwrap();
        assert!(
            svg.contains("min 0 / confirm 16 ms") && svg.contains(g),
            "{g}"
        );
    }
    let back: TimingReport =
        serde_json::from_slice(&std::fs::read(dir.path().join("timing.json")).unwrap()).unwrap();
    assert_eq!(back.chosen, chosen);
}

#[test]
fn the_rule_takes_the_best_worst_group_within_the_first_and_final_bounds() {
    let pairs = [
        t(50.0, 50.0, false),
        t(0.0, 50.0, false),
        t(0.0, 16.0, false),
        t(0.0, 50.0, true),
    ];
    let scores = vec![
        s(pairs[0], "jig", 0.5, 0.98, 0.98),
        s(pairs[0], "hand-held", 0.4, 0.86, 0.80),
        // better in both groups, within bounds
        s(pairs[1], "jig", 0.7, 0.97, 0.98),
        s(pairs[1], "hand-held", 0.6, 0.85, 0.80),
        // the best mean, but its first decisions on hand-held presses
        // are right 3 points less often
        s(pairs[2], "jig", 0.9, 0.97, 0.98),
        s(pairs[2], "hand-held", 0.8, 0.83, 0.80),
        // jig better than pair 1, hand-held (its worst group) worse
        s(pairs[3], "jig", 0.8, 0.98, 0.98),
        s(pairs[3], "hand-held", 0.55, 0.86, 0.80),
    ];
    assert_eq!(choose(&scores, &pairs).unwrap(), 1);
    // Losing presses at the end rules a pair out too.
    let mut worse = scores.clone();
    worse[2].final_right = 0.97;
    assert_eq!(choose(&worse, &pairs).unwrap(), 3);
    // A missing score is an error, not a silent pick.
    assert!(choose(&scores[..7], &pairs).is_err());
}

/// A press whose first 12 frames are nearer A and the rest B: the
/// running mean crosses to B about 8 frames after the change and its
/// lead then grows to about 0.9 (the index's distance, Euclidean
/// between unit vectors).
fn drifting(class: usize) -> PressTrace {
    let mut rows = vec![[1.0, 0.4]; 12];
    rows.extend(vec![[0.0, 1.0]; 33]);
    trace(class, 33.3, &rows)
}

#[test]
fn a_wider_margin_or_a_longer_wait_switches_less_and_away_from_right_is_counted() {
    let p = drifting(0);
    let cfg = |m: f32, ms: f32| {
        config(&Timing {
            switch_margin: m,
            switch_ms: ms,
            ..t(0.0, 50.0, false)
        })
    };
    let base = run_press(&index(), &cfg(0.02, 117.0), &p, false, &[]);
    // B never leads by 1.2; it leads by 0.02 for less than 500 ms
    // before the window ends.
    let wide = run_press(&index(), &cfg(1.2, 117.0), &p, false, &[]);
    let long = run_press(&index(), &cfg(0.02, 500.0), &p, false, &[]);
    assert_eq!((base.switches, wide.switches, long.switches), (1, 0, 0));
    // The first decision is A (right); the switch leaves it.
    assert_eq!(base.first.unwrap().1, 0);
    assert_eq!((base.from_right, base.last), (1, Some(1)));
    assert_eq!((wide.from_right, wide.last), (0, Some(0)));
    let sc = score(&index(), &[&p], "jig", &[t(0.0, 50.0, false)]);
    assert_eq!(sc[0].switches_per_100, 100.0 * base.switches as f64);
    assert_eq!(sc[0].from_right_per_100, 100.0 * base.from_right as f64);
}

#[test]
fn across_studies_the_rule_must_hold_in_every_group_of_each() {
    let cands = switch_candidates(t(0.0, 50.0, false));
    let study = |source: &str, fin1: f64, sw: [f64; 3]| {
        let mut sc = Vec::new();
        for g in ["jig", "hand-held"] {
            for (i, &c) in cands.iter().enumerate() {
                // Candidate 1 loses a point at the end in `fin1`'s study.
                let fin = if i == 1 { fin1 } else { 0.6 };
                sc.push(TimingScore {
                    switches_per_100: sw[i.min(2)],
                    ..s(c, g, 0.5, 0.5, fin)
                });
            }
        }
        TimingReport {
            machine: String::new(),
            date: String::new(),
            command: format!("decider-timing {source}"),
            source: source.into(),
            model: String::new(),
            candidates: vec![],
            scores: vec![],
            chosen: t(0.0, 50.0, false),
            switch_candidates: cands.clone(),
            switch_scores: sc,
            switch_chosen: None,
            detect_ms_p50: vec![],
            undetected: vec![],
            seconds: 0.0,
            contact: None,
        }
    };
    // Alone, each study picks candidate 1 (fewest switches, no loss);
    // the other study excludes it, so the pick is the next fewest.
    let a = study("cat 1", 0.6, [10.0, 1.0, 5.0]);
    let b = study("cat 2", 0.59, [20.0, 2.0, 8.0]);
    assert_eq!(choose_switch(&a.switch_scores, &cands).unwrap(), 1);
    let (scores, i) = choose_switch_across(&[a.clone(), b.clone()]).unwrap();
    assert_eq!(i, 2);
    assert_eq!(scores.len(), 4 * cands.len());
    assert!(scores.iter().any(|x| x.group == "cat 2: hand-held"));
    let md = markdown_across(&[a.clone(), b.clone()], "decider-switch").unwrap();
    assert!(
        md.contains(&format!("picks **{}**", cands[2].switch_label())),
        "{md}"
    );
    // Other candidates, the same study twice, or none: errors.
    let mut c = b.clone();
    c.switch_candidates.pop();
    assert!(choose_switch_across(&[a.clone(), c]).is_err());
    assert!(choose_switch_across(&[a.clone(), a]).is_err());
    assert!(choose_switch_across(&[]).is_err());
}

#[test]
fn across_studies_the_timing_rule_must_hold_in_every_group_of_each() {
    let cands = vec![
        t(50.0, 50.0, false),
        t(0.0, 50.0, true),
        Timing {
            commit_margin: Some(0.08),
            ..t(0.0, 50.0, false)
        },
    ];
    // Means [base, run, margin]; first decisions right: the run loses
    // 3 points in `first1`'s study, within the bounds elsewhere.
    let study = |source: &str, mean: [f64; 3], first1: f64| {
        let mut sc = Vec::new();
        for g in ["jig", "hand-held"] {
            for (i, &c) in cands.iter().enumerate() {
                let first = if i == 1 && g == "hand-held" {
                    first1
                } else {
                    0.9
                };
                sc.push(s(c, g, mean[i], first, 0.9));
            }
        }
        TimingReport {
            machine: String::new(),
            date: String::new(),
            command: format!("decider-timing {source}"),
            source: source.into(),
            model: String::new(),
            candidates: cands.clone(),
            scores: sc,
            chosen: cands[0],
            switch_candidates: switch_candidates(cands[0]),
            switch_scores: switch_candidates(cands[0])
                .into_iter()
                .flat_map(|c| ["jig", "hand-held"].map(|g| s(c, g, 0.5, 0.5, 0.5)))
                .collect(),
            switch_chosen: None,
            detect_ms_p50: vec![],
            undetected: vec![],
            seconds: 0.0,
            contact: None,
        }
    };
    // Alone, catalogue 1 picks the run (the best mean, no loss); on
    // catalogue 2 the run loses 3 points of first decisions, so across
    // both the pick is the margin.
    let a = study("cat 1", [0.5, 0.7, 0.6], 0.9);
    let b = study("cat 2", [0.2, 0.3, 0.25], 0.87);
    assert_eq!(choose(&a.scores, &cands).unwrap(), 1);
    assert_eq!(choose(&b.scores, &cands).unwrap(), 2);
    let (scores, i) = choose_timing_across(&[a.clone(), b.clone()]).unwrap();
    assert_eq!(i, 2);
    assert_eq!(scores.len(), 4 * cands.len());
    let md = markdown_across(&[a.clone(), b.clone()], "decider-switch").unwrap();
    assert!(md.contains("# Timing rules across studies"), "{md}");
    assert!(
        md.contains(&format!("picks **{}**", cands[2].label())),
        "{md}"
    );
    assert!(cands[2].label().contains("or margin 0.08"));
    let mut c = b.clone();
    c.candidates.pop();
    assert!(choose_timing_across(&[a.clone(), c]).is_err());
    assert!(choose_timing_across(&[a.clone(), a]).is_err());
    assert!(choose_timing_across(&[]).is_err());
}

#[test]
fn a_backoff_keeps_the_first_change_and_slows_the_next() {
    // A, then B, then A again: the shipped rule follows both changes;
    // with a backoff of 4 the first change is as fast, and the second
    // (which would need 468 ms) does not happen within the window.
    let mut rows = vec![[1.0, 0.0]; 6];
    rows.extend(vec![[0.0, 1.0]; 14]);
    rows.extend(vec![[1.0, 0.0]; 25]);
    let p = trace(0, 0.0, &rows);
    let cfg = |b: f32| {
        config(&Timing {
            switch_backoff: b,
            ..t(0.0, 50.0, false)
        })
    };
    let times: Vec<f64> = (0..45).map(|k| k as f64 * 1000.0 / 60.0 + 1.0).collect();
    let base = run_press(&index(), &cfg(1.0), &p, false, &times);
    let back = run_press(&index(), &cfg(4.0), &p, false, &times);
    assert_eq!(
        (base.switches, back.switches),
        (2, 1),
        "{:?} {:?}",
        base.at,
        back.at
    );
    assert_eq!((base.last, back.last), (Some(0), Some(1)));
    // The same decisions up to the second change.
    let second = base.at.iter().rposition(|a| *a == Some(1)).unwrap();
    assert_eq!(base.at[..=second], back.at[..=second]);
    assert_eq!(base.from_right, 1);
}

#[test]
fn the_switching_rule_takes_the_fewest_switches_within_the_final_and_mean_bounds() {
    let cands = switch_candidates(t(0.0, 50.0, false));
    assert_eq!(cands.len(), SWITCH_RULES.len());
    // The baseline is the rule shipped before the study (no backoff);
    // the shipped one is a candidate.
    let d = DecideConfig::default();
    assert_eq!(SWITCH_RULES[0], (0.02, 117.0, 1.0));
    assert!(
        SWITCH_RULES.contains(&(d.switch_margin, d.switch_ms, d.switch_backoff)),
        "the shipped rule is a candidate"
    );
    assert_eq!(
        cands[10].label(),
        "0 / 50, switch 0.02 for 117 ms, x 4 per change"
    );
    assert_eq!(cands[4].label(), "0 / 50, switch 0.04 for 233 ms");
    let with = |i: usize, g: &str, mean: f64, fin: f64, sw: f64| TimingScore {
        switches_per_100: sw,
        ..s(cands[i], g, mean, 0.5, fin)
    };
    let mut sc = Vec::new();
    for g in ["jig", "hand-held"] {
        sc.push(with(0, g, 0.50, 0.60, 20.0));
        // Fewest switches, but loses 1.5 points of the mean on one group.
        sc.push(with(1, g, if g == "jig" { 0.485 } else { 0.50 }, 0.60, 2.0));
        // Loses 1 point at the end.
        sc.push(with(2, g, 0.50, 0.59, 3.0));
        // Within both bounds: 0.5 points less at the end, 1 less mean.
        sc.push(with(3, g, 0.49, 0.595, 5.0));
        for i in 4..cands.len() {
            sc.push(with(i, g, 0.50, 0.60, 8.0));
        }
    }
    assert_eq!(choose_switch(&sc, &cands).unwrap(), 3);
    // A missing score is an error, not a silent pick.
    sc.retain(|x| !(x.timing == cands[5] && x.group == "jig"));
    assert!(choose_switch(&sc, &cands).is_err());
    // Nothing better than the baseline: the baseline.
    let flat: Vec<TimingScore> = ["jig", "hand-held"]
        .iter()
        .flat_map(|g| (0..cands.len()).map(move |i| (i, *g)))
        .map(|(i, g)| with(i, g, 0.5, 0.6, 10.0))
        .collect();
    assert_eq!(choose_switch(&flat, &cands).unwrap(), 0);
}
