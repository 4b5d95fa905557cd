//! The roller as the receiving daemon uses it: a live stream of slot
//! decisions (60 per second, with chatter) through the real driver, over a
//! real pty, to the simulated firmware; and repeated link drops. The
//! simulated wheel's step count is the ground truth.
use std::time::{Duration, Instant};
use telextiles_roller::{DriverConfig, RollerDriver, SimConfig, SimRoller, Target};

fn config(link: &std::path::Path) -> DriverConfig {
    DriverConfig {
        ack_timeout: Duration::from_millis(100),
        keepalive: Duration::from_millis(200),
        reconnect_min: Duration::from_millis(20),
        reconnect_max: Duration::from_millis(200),
        ..DriverConfig::path(link)
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn roller_follows_a_live_decision_stream_without_pile_up() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("roller");
    let sim = SimRoller::spawn(SimConfig {
        speed: 4.0,
        link: Some(link.clone()),
        ..SimConfig::default()
    })
    .unwrap();
    let driver = RollerDriver::start(config(&link));
    driver.wait_connected(Duration::from_secs(5)).await.unwrap();
    let (bytes0, _) = sim.traffic();
    // 90 decisions at 60 Hz: slot 3, then chatter between 11 and 12, then 5.
    let mut decisions = 0;
    let mut tick = tokio::time::interval(Duration::from_micros(16_667));
    for i in 0..90u32 {
        tick.tick().await;
        let slot = match i {
            0..=29 => 3,
            30..=69 => 11 + (i % 2) as u16,
            _ => 5,
        };
        driver.set_target(Target::Slot(slot));
        decisions += 1;
    }
    let t_last = Instant::now();
    let st = driver
        .wait_arrived(Target::Slot(5), Duration::from_secs(10))
        .await
        .unwrap();
    let latency = t_last.elapsed();
    assert_eq!(st.position, 1000);
    assert_eq!(sim.position_steps(), 1000);
    // Commands on the line: far fewer than decisions (at most one in flight,
    // only the latest target is sent). Goto frames are 9-11 bytes,
    // keepalives 7.
    let (bytes1, _) = sim.traffic();
    let frames = (bytes1 - bytes0) / 7;
    assert!(
        frames < decisions as u64,
        "{frames} frames for {decisions} decisions"
    );
    // The last decision is acted on promptly: from wherever the chatter left
    // the wheel, slot 5 is at most half a turn away (1 s at 1x, 0.25 s at 4x).
    assert!(latency < Duration::from_secs(2), "{latency:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn roller_survives_repeated_link_drops() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("roller");
    // A slow wheel (1 rev/s, 2 rev/s²): each move outlasts the drop made
    // during it, so every drop happens mid-move and is noticed. With the
    // paper's fast wheel at 8x a move can end before its drop, and a drop
    // on an idle link may pass unseen until the next command.
    let sim = SimRoller::spawn(SimConfig {
        speed: 8.0,
        max_speed: 3200,
        accel: 6400,
        link: Some(link.clone()),
        ..SimConfig::default()
    })
    .unwrap();
    let driver = RollerDriver::start(config(&link));
    driver.wait_connected(Duration::from_secs(5)).await.unwrap();
    let targets = [9u16, 2, 14, 7, 0];
    for (i, &slot) in targets.iter().enumerate() {
        driver.set_target(Target::Slot(slot));
        tokio::time::sleep(Duration::from_millis(10 + 7 * i as u64)).await;
        sim.disconnect();
        tokio::time::sleep(Duration::from_millis(60)).await;
        sim.reconnect().unwrap();
        let st = driver
            .wait_arrived(Target::Slot(slot), Duration::from_secs(10))
            .await
            .unwrap();
        assert_eq!(st.position, slot as u32 * 200, "round {i}");
        assert_eq!(sim.position_steps(), slot as u32 * 200, "round {i}");
    }
    assert!(driver.state().reconnects >= targets.len() as u32);
}
