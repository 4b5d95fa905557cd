//! The live session beyond the LAN: two real `telextilesd run` daemons,
//! each on a home network behind an nftables NAT router, paired
//! beforehand, meeting through `telextilesd relay` on the lab's public
//! network (`telextiles_tests::nat`; all network namespaces, nothing on
//! the host's interfaces). Both press simulated textiles at 60 fps, so
//! latents flow both ways; per-frame traces give capture → decision.
//! B dials A by key alone: the relay is the only way it knows.
//!
//! Needs root; without it each test prints a loud SKIP (and fails under
//! CI). The `FIGURE` lines are the ones docs/results.md quotes:
//!   cargo nextest run -p telextilesd --test nat_session --no-capture
#[path = "harness/mod.rs"]
mod harness;

use harness::*;
use std::time::Duration;
use telextiles_control::Event;
use telextiles_tests::nat::Mapping;
use telextiles_tests::netns::available_or_skip;

/// Final decisions `side` made on its peer's presses inside `[t0, t1]`,
/// and how many of them named `textile`.
fn finals(side: &Side, textile: &str, t0: u64, t1: u64) -> (usize, usize) {
    let ev = side.events.lock().unwrap();
    let mut n = (0, 0);
    for (t, e) in ev.iter() {
        if let Event::Decision {
            textile: got,
            final_decision: true,
            peer: Some(_),
            ..
        } = e
        {
            if *t >= t0 && *t <= t1 {
                n.0 += 1;
                n.1 += usize::from(got == textile);
            }
        }
    }
    n
}

/// The pair behind NATs mapping as `mapping`: connected within 10 s, both
/// on the relay.
async fn start(mapping: Mapping) -> Pair {
    let pair = Pair::start(&Setup {
        nat: Some(mapping),
        ..Setup::default()
    })
    .await;
    assert!(
        pair.connected_after < Duration::from_secs(10),
        "connected after {:?}",
        pair.connected_after
    );
    relays_connected(&pair).await;
    pair
}

/// Both daemons' `ctl status` lists the relay, connected, with no error
/// (within 5 s: the status follows the link's events).
async fn relays_connected(pair: &Pair) {
    let url = &pair.meet.as_ref().unwrap().url;
    for side in [&pair.a, &pair.b] {
        let mut c = connect(side).await;
        let t0 = std::time::Instant::now();
        let st = loop {
            let st = c
                .call(&telextiles_control::Command::Status)
                .await
                .unwrap()
                .unwrap();
            if st["relays"][0]["connected"] == true || t0.elapsed() > Duration::from_secs(5) {
                break st;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        };
        let r = &st["relays"][0];
        let got = r["url"].as_str().unwrap_or_default();
        assert_eq!(
            got.trim_end_matches('/'),
            url.trim_end_matches('/'),
            "{}: {st}",
            side.name
        );
        assert_eq!(r["connected"], true, "{}: {st}", side.name);
        assert!(r["error"].is_null(), "{}: {st}", side.name);
        assert!(r["since"].as_u64().is_some(), "{}: {st}", side.name);
    }
}

/// Streams for `seconds` and checks both directions: at least 99 % of
/// the latents sent inside the window arrive, final decisions come and
/// name the pressed textile. Returns A → B's stages.
async fn stream(
    pair: &Pair,
    seconds: u64,
    what: &str,
) -> (Stages, Stages, (usize, usize), (usize, usize)) {
    let t0 = mono_us();
    tokio::time::sleep(Duration::from_secs(seconds)).await;
    let t1 = mono_us();
    // Let the last latents of the window land before reading the traces.
    tokio::time::sleep(Duration::from_millis(500)).await;
    let ta = Traces::read(&pair.a.trace);
    let tb = Traces::read(&pair.b.trace);
    let ab = stages(&ta, &tb, t0, t1);
    let ba = stages(&tb, &ta, t0, t1);
    // A presses T012, B presses T047 (Setup::default()).
    let fb = finals(&pair.b, "T012", t0, t1 + 500_000);
    let fa = finals(&pair.a, "T047", t0, t1 + 500_000);
    for (dir, s) in [("A → B", &ab), ("B → A", &ba)] {
        assert!(
            s.sent >= 20 * seconds as usize,
            "{what} {dir}: only {} latents sent",
            s.sent
        );
        assert!(
            s.received * 100 >= s.sent * 99,
            "{what} {dir}: {} of {} latents arrived",
            s.received,
            s.sent
        );
    }
    for (dir, (n, right)) in [("on B", fb), ("on A", fa)] {
        assert!(n >= 2, "{what}: {n} final decisions {dir} in {seconds} s");
        assert!(
            right * 10 >= n * 9,
            "{what}: {right} of {n} final decisions {dir} right"
        );
    }
    (ab, ba, fa, fb)
}

fn figure(
    name: &str,
    pair: &Pair,
    direct: Option<Duration>,
    ab: &Stages,
    ba: &Stages,
    fa: (usize, usize),
    fb: (usize, usize),
) {
    let mut total: Vec<f64> = ab.total_decided.clone();
    total.extend_from_slice(&ba.total_decided);
    println!(
        "FIGURE {name} connected_ms {} direct_ms {} latents {}/{} capture_to_decision_us p50 {:.0} p99 {:.0} finals_right {}/{}",
        pair.connected_after.as_millis(),
        direct.map_or("never".to_string(), |d| d.as_millis().to_string()),
        ab.received + ba.received,
        ab.sent + ba.sent,
        pct(&total, 50.0),
        pct(&total, 99.0),
        fa.1 + fb.1,
        fa.0 + fb.0,
    );
}

/// Endpoint-independent NATs (most home routers): the session starts
/// relayed, goes direct on both sides, and decisions flow; the relay is
/// then killed and the session goes on over the direct path.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemons_behind_two_home_nats_go_direct_and_outlive_the_relay() {
    if !available_or_skip("daemons_behind_two_home_nats_go_direct_and_outlive_the_relay") {
        return;
    }
    let mut pair = start(Mapping::EndpointIndependent).await;
    let direct = pair.wait_path("direct", Duration::from_secs(15)).await;
    assert!(
        direct.is_some(),
        "no direct path within 15 s: A {:?}, B {:?}",
        Pair::path(&pair.a).await,
        Pair::path(&pair.b).await
    );
    let (ab, ba, fa, fb) = stream(&pair, 10, "direct").await;
    figure("nat_daemons_direct", &pair, direct, &ab, &ba, fa, fb);
    // The relay goes away: the direct path carries on, no reconnect.
    let meet = pair.meet.as_mut().unwrap();
    let killed_at = mono_us();
    meet.relay.kill().unwrap();
    meet.relay.wait().unwrap();
    let (ab, ba, fa, fb) = stream(&pair, 8, "after the relay was killed").await;
    assert_eq!(Pair::path(&pair.a).await.as_deref(), Some("direct"));
    let downs = pair
        .a
        .events
        .lock()
        .unwrap()
        .iter()
        .filter(|(t, e)| *t >= killed_at && matches!(e, Event::PeerDown { .. }))
        .count();
    // (Only after the kill: at the start both sides dial each other and
    // one connection may replace the other; see docs/results.md.)
    assert_eq!(downs, 0, "the session went down after the relay was killed");
    println!(
        "after the relay was killed: {}/{} latents, finals {}/{}",
        ab.received + ba.received,
        ab.sent + ba.sent,
        fa.1 + fb.1,
        fa.0 + fb.0
    );
    pair.stop();
}

/// Symmetric NATs on both sides: no hole can be punched, the session stays
/// on the relay, latents and decisions flow as on the LAN.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn daemons_behind_symmetric_nats_stay_relayed_and_decide() {
    if !available_or_skip("daemons_behind_symmetric_nats_stay_relayed_and_decide") {
        return;
    }
    let pair = start(Mapping::Symmetric).await;
    let relayed = pair.wait_path("relay", Duration::from_secs(5)).await;
    assert!(
        relayed.is_some(),
        "not on the relay: A {:?}",
        Pair::path(&pair.a).await
    );
    let (ab, ba, fa, fb) = stream(&pair, 10, "relayed").await;
    for side in [&pair.a, &pair.b] {
        assert_eq!(
            Pair::path(side).await.as_deref(),
            Some("relay"),
            "{}",
            side.name
        );
    }
    figure("nat_daemons_relayed", &pair, None, &ab, &ba, fa, fb);
    pair.stop();
}
