//! The driver against the simulated roller over real pseudo-terminals.
//! The simulator's step count is the ground truth for every check.
use std::path::PathBuf;
use std::time::{Duration, Instant};
use telextiles_roller::*;
use tokio::sync::broadcast;

const ARRIVE: Duration = Duration::from_secs(10);

struct Rig {
    _dir: tempfile::TempDir,
    link: PathBuf,
    sim: SimRoller,
    driver: RollerDriver,
    events: broadcast::Receiver<RollerEvent>,
}

fn sim_config(link: &std::path::Path, speed: f64) -> SimConfig {
    SimConfig {
        speed,
        link: Some(link.to_path_buf()),
        ..SimConfig::default()
    }
}

fn driver_config(link: &std::path::Path) -> DriverConfig {
    DriverConfig {
        ack_timeout: Duration::from_millis(100),
        keepalive: Duration::from_millis(200),
        reconnect_min: Duration::from_millis(20),
        reconnect_max: Duration::from_millis(200),
        ..DriverConfig::path(link)
    }
}

async fn rig(speed: f64) -> Rig {
    rig_with(|c| c, speed).await
}

async fn rig_with(f: impl FnOnce(SimConfig) -> SimConfig, speed: f64) -> Rig {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("roller0");
    let sim = SimRoller::spawn(f(sim_config(&link, speed))).unwrap();
    let driver = RollerDriver::start(driver_config(&link));
    let events = driver.subscribe();
    let v = driver.wait_connected(Duration::from_secs(5)).await.unwrap();
    assert_eq!(v.steps_per_rev, 3200);
    Rig {
        _dir: dir,
        link,
        sim,
        driver,
        events,
    }
}

/// Goes to `t`, waits for arrival and checks the simulated wheel is there.
async fn go(r: &Rig, t: Target) -> i64 {
    let before = r.sim.absolute_steps();
    r.driver.set_target(t);
    let st = r.driver.wait_arrived(t, ARRIVE).await.unwrap();
    let want = t.steps(16, 3200);
    assert_eq!(st.position, want, "reported position for {t:?}");
    assert_eq!(r.sim.position_steps(), want, "simulated wheel for {t:?}");
    r.sim.absolute_steps() - before
}

fn drain(rx: &mut broadcast::Receiver<RollerEvent>) -> Vec<RollerEvent> {
    let mut v = Vec::new();
    while let Ok(e) = rx.try_recv() {
        v.push(e);
    }
    v
}

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn shortest_path_both_ways_and_across_zero() {
    let mut r = rig(20.0).await;
    // 0 -> slot 15: counter-clockwise one slot, across zero.
    assert_eq!(go(&r, Target::Slot(15)).await, -200);
    // 15 -> 2: clockwise across zero, three slots.
    assert_eq!(go(&r, Target::Slot(2)).await, 600);
    // 2 -> 9: clockwise 7 slots (shorter than 9 back).
    assert_eq!(go(&r, Target::Slot(9)).await, 1400);
    // 9 -> 1: exactly half a turn goes counter-clockwise.
    assert_eq!(go(&r, Target::Slot(1)).await, -1600);
    // Angles and raw steps.
    assert_eq!(go(&r, Target::AngleMdeg(350_000)).await, -289);
    assert_eq!(go(&r, Target::Steps(100)).await, 189);
    let ev = drain(&mut r.events);
    let arrived = ev
        .iter()
        .filter(|e| matches!(e, RollerEvent::Arrived { .. }))
        .count();
    assert_eq!(arrived, 6);
    // Each new target's command was reported written once, before its arrival.
    let written: Vec<Target> = ev
        .iter()
        .filter_map(|e| match e {
            RollerEvent::TargetWritten { target, .. } => Some(*target),
            _ => None,
        })
        .collect();
    assert_eq!(
        written,
        [
            Target::Slot(15),
            Target::Slot(2),
            Target::Slot(9),
            Target::Slot(1),
            Target::AngleMdeg(350_000),
            Target::Steps(100)
        ]
    );
    assert!(ev.iter().any(|e| matches!(
        e,
        RollerEvent::Position {
            slot: Some(9),
            moving: false,
            ..
        }
    )));
    assert!(ev
        .iter()
        .any(|e| matches!(e, RollerEvent::Position { moving: true, .. })));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hundred_random_targets_always_end_right() {
    let r = rig(40.0).await;
    let mut rng = Rng(0x5eed_1234_abcd_0001);
    let mut last = Target::Slot(0);
    for i in 0..100 {
        let t = match rng.below(3) {
            0 => Target::Slot(rng.below(16) as u16),
            1 => Target::AngleMdeg(rng.below(360_000) as u32),
            _ => Target::Steps(rng.below(3200) as u32),
        };
        r.driver.set_target(t);
        last = t;
        if rng.below(2) == 0 {
            // Let it arrive and check.
            r.driver.wait_arrived(t, ARRIVE).await.unwrap();
            assert_eq!(
                r.sim.position_steps(),
                t.steps(16, 3200),
                "target {i}: {t:?}"
            );
        } else {
            // Replace it soon, maybe mid-move.
            tokio::time::sleep(Duration::from_millis(rng.below(15))).await;
        }
    }
    let st = r.driver.wait_arrived(last, ARRIVE).await.unwrap();
    assert_eq!(st.position, last.steps(16, 3200));
    assert_eq!(r.sim.position_steps(), last.steps(16, 3200));
    assert!(!r.sim.is_moving());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn retarget_mid_move_only_the_latest_arrives() {
    let mut r = rig(4.0).await;
    r.driver.set_target(Target::Slot(6)); // 1200 steps clockwise, ~0.2 s at 4x
    let t0 = Instant::now();
    while r.sim.absolute_steps() < 300 {
        assert!(t0.elapsed() < Duration::from_secs(5));
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    assert!(r.sim.is_moving());
    r.driver.set_target(Target::Slot(13)); // behind: reverse through zero
    let st = r
        .driver
        .wait_arrived(Target::Slot(13), ARRIVE)
        .await
        .unwrap();
    assert_eq!(st.position, 2600);
    assert_eq!(r.sim.position_steps(), 2600);
    let ev = drain(&mut r.events);
    let arrived: Vec<_> = ev
        .iter()
        .filter_map(|e| match e {
            RollerEvent::Arrived { target, .. } => Some(*target),
            _ => None,
        })
        .collect();
    assert_eq!(arrived, vec![Target::Slot(13)]);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_targets_does_not_pile_up() {
    let r = rig(20.0).await;
    let (in0, _) = r.sim.traffic();
    for i in 0..500u32 {
        r.driver.set_target(Target::Steps(i * 7 % 3200));
    }
    let last = Target::Steps(499 * 7 % 3200);
    r.driver.wait_arrived(last, ARRIVE).await.unwrap();
    assert_eq!(r.sim.position_steps(), 499 * 7 % 3200);
    // 500 targets in a burst became a handful of frames, not 500.
    let (in1, _) = r.sim.traffic();
    let frames = (in1 - in0) / 11;
    assert!(frames < 20, "{frames} frames on the line");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn garbage_and_corruption_on_the_line_resync() {
    let r = rig(20.0).await;
    let mut rng = Rng(77);
    r.sim.set_noise(Some(Noise {
        corrupt_per_byte: 0.01,
        seed: 42,
    }));
    for i in 0..25 {
        let t = Target::Slot(rng.below(16) as u16);
        let mut junk = vec![0u8; rng.below(80) as usize];
        for b in junk.iter_mut() {
            *b = match rng.below(4) {
                0 => 0xA5,
                1 => 0x5A,
                _ => rng.next() as u8,
            };
        }
        r.sim.inject_to_host(&junk);
        r.sim.inject_to_firmware(&junk);
        r.driver.set_target(t);
        r.driver.wait_arrived(t, ARRIVE).await.unwrap();
        assert_eq!(r.sim.position_steps(), t.steps(16, 3200), "target {i}");
    }
    assert!(r.sim.bad_frames() > 0, "the noise reached the firmware");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn disconnect_mid_move_then_reconnect_reaches_the_final_target() {
    let mut r = rig(4.0).await;
    r.driver.set_target(Target::Slot(8)); // half turn, ~0.25 s at 4x
    tokio::time::sleep(Duration::from_millis(60)).await;
    assert!(r.sim.is_moving());
    r.sim.disconnect();
    // The driver notices and says why.
    let reason = loop {
        match tokio::time::timeout(Duration::from_secs(5), r.events.recv()).await {
            Ok(Ok(RollerEvent::Disconnected { reason })) => break reason,
            Ok(Ok(_)) => continue,
            other => panic!("no Disconnected event: {other:?}"),
        }
    };
    assert!(reason.contains("roller0"), "{reason}");
    // A new decision while the link is down: the latest wins after reconnect.
    r.driver.set_target(Target::Slot(3));
    tokio::time::sleep(Duration::from_millis(150)).await;
    assert!(!r.driver.state().connected);
    r.sim.reconnect().unwrap();
    let st = r
        .driver
        .wait_arrived(Target::Slot(3), ARRIVE)
        .await
        .unwrap();
    assert_eq!(st.position, 600);
    assert_eq!(r.sim.position_steps(), 600);
    assert!(r.driver.state().reconnects >= 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn watchdog_stop_during_a_long_outage_is_recovered() {
    let mut r = rig_with(
        |c| SimConfig {
            watchdog: Duration::from_millis(150),
            max_speed: 800,
            ..c
        },
        2.0,
    )
    .await;
    r.driver.set_target(Target::Slot(8)); // 1600 steps at 800/s / 2x: ~1 s
    tokio::time::sleep(Duration::from_millis(100)).await;
    r.sim.disconnect();
    tokio::time::sleep(Duration::from_millis(400)).await;
    // The firmware's watchdog stopped the silent move short of the target.
    assert!(!r.sim.is_moving());
    assert!(r.sim.with_firmware(|f| f.watchdog_tripped()));
    assert_ne!(r.sim.position_steps(), 1600);
    r.sim.reconnect().unwrap();
    r.driver
        .wait_arrived(Target::Slot(8), ARRIVE)
        .await
        .unwrap();
    assert_eq!(r.sim.position_steps(), 1600);
    assert!(drain(&mut r.events)
        .iter()
        .any(|e| matches!(e, RollerEvent::Disconnected { .. })));
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn simulator_restart_on_the_same_link_resyncs() {
    let r = rig(4.0).await;
    let Rig {
        _dir,
        link,
        sim,
        driver,
        ..
    } = r;
    driver.set_target(Target::Slot(4));
    tokio::time::sleep(Duration::from_millis(40)).await;
    // The firmware restarts where the wheel physically is (mid-move).
    let where_ = sim.absolute_steps();
    sim.shutdown();
    tokio::time::sleep(Duration::from_millis(100)).await;
    let sim = SimRoller::spawn(SimConfig {
        initial_steps: where_,
        ..sim_config(&link, 4.0)
    })
    .unwrap();
    // The new firmware knows nothing of the target; the driver resends it.
    driver.wait_arrived(Target::Slot(4), ARRIVE).await.unwrap();
    assert_eq!(sim.position_steps(), 800);
}

// Current-thread runtime: the driver task cannot run (and send its first
// Error, which is reported once) before the test has subscribed. On the
// multi-threaded runtime it could, and the test then waited in vain (seen
// once under load).
#[tokio::test(flavor = "current_thread")]
async fn missing_port_is_reported_and_retried_until_it_appears() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("late-roller");
    let driver = RollerDriver::start(driver_config(&link));
    let mut events = driver.subscribe();
    driver.set_target(Target::Slot(2));
    let msg = match tokio::time::timeout(Duration::from_secs(5), events.recv()).await {
        Ok(Ok(RollerEvent::Error { message })) => message,
        other => panic!("{other:?}"),
    };
    assert!(
        msg.contains("cannot open roller port") && msg.contains("late-roller"),
        "{msg}"
    );
    tokio::time::sleep(Duration::from_millis(200)).await;
    let sim = SimRoller::spawn(sim_config(&link, 20.0)).unwrap();
    driver.wait_arrived(Target::Slot(2), ARRIVE).await.unwrap();
    assert_eq!(sim.position_steps(), 400);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_refused_target_is_reported_not_retried_forever() {
    let mut r = rig(20.0).await;
    r.driver.set_target(Target::Slot(40));
    let msg = loop {
        match tokio::time::timeout(Duration::from_secs(5), r.events.recv()).await {
            Ok(Ok(RollerEvent::Error { message })) => break message,
            Ok(Ok(_)) => continue,
            other => panic!("{other:?}"),
        }
    };
    assert!(msg.contains("argument out of range"), "{msg}");
    let (in0, _) = r.sim.traffic();
    tokio::time::sleep(Duration::from_millis(600)).await;
    let (in1, _) = r.sim.traffic();
    // Only keepalives (8-byte QueryStatus frames) since: no retry storm.
    assert!(in1 - in0 <= 8 * 5, "{} bytes", in1 - in0);
    // And a valid target afterwards works.
    go(&r, Target::Slot(1)).await;
}
