//! Step planning: trapezoidal ramps, limits, re-targeting, timing.
use proptest::prelude::*;
use roller_firmware::motion::Planner;

/// Every step taken: (time, direction, speed squared after it).
struct Trace {
    steps: Vec<(u64, i8, u64)>,
}

fn run(p: &mut Planner, events: &[(u64, i64)]) -> Trace {
    let mut steps = Vec::new();
    let mut ev = events.iter().peekable();
    let mut now = 0;
    loop {
        let next_step = p.next_step_at();
        let next_ev = ev.peek().map(|e| e.0);
        match (next_step, next_ev) {
            (None, None) => break,
            (Some(s), Some(e)) if e < s => {
                now = e;
                p.set_target(ev.next().unwrap().1, now);
            }
            (None, Some(e)) => {
                now = now.max(e);
                p.set_target(ev.next().unwrap().1, now);
            }
            (Some(s), _) => {
                now = s;
                let st = p.step(now).expect("due step");
                assert_eq!(st.at, s);
                steps.push((st.at, st.dir, st.speed_squared));
                assert!(steps.len() < 5_000_000, "runaway");
            }
        }
    }
    Trace { steps }
}

/// The physical limits hold on every step: |dv^2| <= 2a, v <= vmax, and the
/// direction only changes at (almost) zero speed.
fn check_limits(t: &Trace, vmax: u32, accel: u32) {
    check_limits_from(t, vmax, accel, 0)
}

fn check_limits_from(t: &Trace, vmax: u32, accel: u32, v2_start: u64) {
    let two_a = 2 * accel as u64;
    let mut prev_v2 = v2_start;
    let mut prev_dir = 0i8;
    for (i, &(_, dir, v2)) in t.steps.iter().enumerate() {
        assert!(
            v2 <= (vmax as u64).pow(2),
            "step {i}: speed^2 {v2} above vmax^2"
        );
        if prev_dir != 0 && dir != prev_dir {
            assert!(
                prev_v2 <= two_a,
                "step {i}: reversed at speed^2 {prev_v2} (> 2a = {two_a})"
            );
            prev_v2 = 0;
        }
        let dv = v2.abs_diff(prev_v2);
        assert!(
            dv <= two_a,
            "step {i}: dv^2 {dv} > 2a {two_a}: {:?}",
            &t.steps[i.saturating_sub(3)..(i + 3).min(t.steps.len())]
        );
        prev_v2 = v2;
        prev_dir = dir;
    }
    assert!(prev_v2 <= two_a, "ended at speed^2 {prev_v2}");
}

#[test]
fn long_move_is_a_trapezoid_with_the_right_duration() {
    let mut p = Planner::new(3200, 6400);
    let t = run(&mut p, &[(0, 10_000)]);
    check_limits(&t, 3200, 6400);
    assert_eq!(t.steps.len(), 10_000);
    assert_eq!(p.position(), 10_000);
    assert!(!p.is_moving());
    // It reaches and holds full speed.
    let cruise = t.steps.iter().filter(|s| s.2 == 3200 * 3200).count();
    assert!(cruise > 7_000, "cruise steps {cruise}");
    // Ideal: D / vmax + vmax / a = 3.125 + 0.5 s.
    let dur = t.steps.last().unwrap().0;
    assert!((3_600_000..=3_650_000).contains(&dur), "{dur} us");
    // Symmetric ramps: the accelerating and decelerating phases are equally long.
    let accel_steps = t.steps.iter().take_while(|s| s.2 < 3200 * 3200).count();
    let decel_steps = t
        .steps
        .iter()
        .rev()
        .take_while(|s| s.2 < 3200 * 3200)
        .count();
    assert!(
        accel_steps.abs_diff(decel_steps) <= 2,
        "{accel_steps} vs {decel_steps}"
    );
    assert!((795..=805).contains(&accel_steps), "{accel_steps}"); // vmax^2 / 2a = 800
}

#[test]
fn short_move_is_triangular() {
    let mut p = Planner::new(3200, 6400);
    let t = run(&mut p, &[(0, -200)]);
    check_limits(&t, 3200, 6400);
    assert_eq!(p.position(), -200);
    assert!(t.steps.iter().all(|s| s.1 == -1));
    let peak = t.steps.iter().map(|s| s.2).max().unwrap();
    // Peak speed sqrt(a * D) = sqrt(6400 * 200) ~ 1131 steps/s.
    assert!((1100u64.pow(2)..=1140u64.pow(2)).contains(&peak), "{peak}");
    // Ideal 2 * sqrt(D / a) = 0.3536 s.
    let dur = t.steps.last().unwrap().0;
    assert!((345_000..=362_000).contains(&dur), "{dur}");
}

#[test]
fn retarget_behind_decelerates_then_reverses_smoothly() {
    let mut p = Planner::new(3200, 6400);
    // Heading for +1600; at 0.4 s (fast, clockwise) the target jumps to -400.
    let t = run(&mut p, &[(0, 1600), (400_000, -400)]);
    check_limits(&t, 3200, 6400);
    assert_eq!(p.position(), -400);
    let reversals = t.steps.windows(2).filter(|w| w[0].1 != w[1].1).count();
    assert_eq!(reversals, 1);
    // The furthest clockwise point is past where it was at 0.4 s by about
    // the stopping distance v^2 / 2a.
    let mut pos = 0i64;
    let mut max_pos = 0i64;
    let mut pos_at_retarget = 0;
    let mut v2_at_retarget = 0;
    for s in &t.steps {
        if s.0 <= 400_000 {
            pos_at_retarget = pos + s.1 as i64;
            v2_at_retarget = s.2;
        }
        pos += s.1 as i64;
        max_pos = max_pos.max(pos);
    }
    let stopping = (v2_at_retarget / 12_800) as i64;
    assert!(
        (max_pos - pos_at_retarget - stopping).abs() <= 2,
        "overran {} steps, stopping distance {stopping}",
        max_pos - pos_at_retarget
    );
}

#[test]
fn retarget_ahead_extends_the_move_without_stopping() {
    let mut p = Planner::new(3200, 6400);
    let t = run(&mut p, &[(0, 400), (200_000, 1200)]);
    check_limits(&t, 3200, 6400);
    assert_eq!(p.position(), 1200);
    assert!(t.steps.iter().all(|s| s.1 == 1));
    // It never came to rest in between.
    assert!(t.steps[..t.steps.len() - 1].iter().all(|s| s.2 > 0));
}

#[test]
fn stop_decelerates_at_the_set_rate() {
    let mut p = Planner::new(3200, 6400);
    p.set_target(100_000, 0);
    let mut now;
    loop {
        now = p.next_step_at().unwrap();
        p.step(now);
        if now >= 1_000_000 {
            break;
        }
    }
    let v2 = p.speed_squared();
    assert_eq!(v2, 3200 * 3200);
    let before = p.position();
    p.stop(now);
    let t = run(&mut p, &[]);
    check_limits_from(&t, 3200, 6400, v2);
    let travelled = p.position() - before;
    assert!((799..=802).contains(&travelled), "{travelled}"); // v^2 / 2a = 800
}

#[test]
fn lowering_the_speed_mid_move_decelerates() {
    let mut p = Planner::new(3200, 6400);
    p.set_target(20_000, 0);
    while p.speed_squared() < 3200 * 3200 {
        let now = p.next_step_at().unwrap();
        p.step(now);
    }
    p.set_motion(1000, 6400);
    let t = run(&mut p, &[]);
    check_limits_from(&t, 3200, 6400, 3200 * 3200);
    assert!(t
        .steps
        .iter()
        .rev()
        .skip(100)
        .take(1000)
        .all(|s| s.2 <= 1000 * 1000));
    assert_eq!(p.position(), 20_000);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, .. ProptestConfig::default() })]

    /// Random targets at random times with random limits: the limits hold
    /// on every step and the wheel always ends on the last target.
    #[test]
    fn random_retargets_end_on_the_last_target(
        vmax in 200u32..20_000,
        accel in 500u32..100_000,
        events in proptest::collection::vec((0u64..300_000, -3000i64..3000), 1..20),
    ) {
        let mut evs: Vec<(u64, i64)> = Vec::new();
        let mut t = 0;
        for (dt, target) in events {
            t += dt;
            evs.push((t, target));
        }
        let mut p = Planner::new(vmax, accel);
        let trace = run(&mut p, &evs);
        check_limits(&trace, vmax, accel);
        prop_assert_eq!(p.position(), evs.last().unwrap().1);
        prop_assert!(!p.is_moving());
    }
}
