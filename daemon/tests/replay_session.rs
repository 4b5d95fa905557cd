//! `--sensor replay:<dir>` in a live session (real `telextilesd run`
//! processes, real QUIC on loopback): A replays a directory of recordings,
//! one after another and round again, B decides them. Each recording is
//! one press, decided as its own fabric, in order: the front end starts
//! afresh on each recording with the recording's own reference, and a
//! recording that ends in contact ends its press there. The recordings
//! come from three sensor units, whose no-contact frames differ.
#[path = "harness/mod.rs"]
mod harness;

use harness::*;
use std::time::{Duration, Instant};
use telextiles_control::Event;

#[test]
fn a_directory_of_recordings_replays_as_one_press_each_in_order() {
    let sim = telextiles_sim::Simulator::new().unwrap();
    let rec = tempfile::tempdir().unwrap();
    // A held-out person's jig presses on three units; the second is cut
    // while still in contact (no release).
    let plan = [("T030", 0, true), ("T061", 1, false), ("T090", 2, true)];
    for (k, (textile, unit, release)) in plan.iter().enumerate() {
        let spec = telextiles_sim::PressSpec {
            person: 9,
            sensor: *unit,
            jig: true,
            release: Some(*release),
            ..telextiles_sim::PressSpec::new(*textile, 11 + k as u64)
        };
        let press = sim.render_press(&spec).unwrap();
        let dir = rec.path().join(format!("{k}-{textile}"));
        telextiles_sim::recording::write_press(&dir, &press).unwrap();
    }
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let setup = Setup {
        sensors: (
            format!("replay:{}", rec.path().display()),
            "sim:T047".into(),
        ),
        ..Setup::default()
    };
    let pair = rt.block_on(Pair::start(&setup));
    // B's final decisions of A's presses, in order, until two whole rounds
    // have come after the first T030 (the first may have gone before B
    // was connected).
    let want: Vec<&str> = plan.iter().chain(plan.iter()).map(|p| p.0).collect();
    let t0 = Instant::now();
    let finals = loop {
        let finals: Vec<String> = pair
            .b
            .events
            .lock()
            .unwrap()
            .iter()
            .filter_map(|(_, e)| match e {
                Event::Decision {
                    textile,
                    peer: Some(_),
                    final_decision: true,
                    ..
                } => Some(textile.clone()),
                _ => None,
            })
            .collect();
        let first = finals.iter().position(|t| t == "T030");
        if first.is_some_and(|i| finals.len() >= i + want.len()) {
            break finals[first.unwrap()..].to_vec();
        }
        assert!(
            t0.elapsed() < Duration::from_secs(90),
            "final decisions so far: {finals:?}\nA's log:\n{}",
            std::fs::read_to_string(&pair.a.log).unwrap_or_default()
        );
        std::thread::sleep(Duration::from_millis(200));
    };
    let (_, _, a, b) = pair.stop();
    assert_eq!(
        &finals[..want.len()],
        want.as_slice(),
        "one press per recording, each decided as its fabric, in order"
    );
    let sensor_errors: Vec<_> = errors(&a)
        .into_iter()
        .filter(|(_, m)| m.starts_with("sensor") || m.starts_with("encoder"))
        .collect();
    assert!(sensor_errors.is_empty(), "{sensor_errors:?}");
    drop(b);
}
