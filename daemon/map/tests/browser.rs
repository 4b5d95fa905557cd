//! The map page in a real browser: headless Chromium (the system package)
//! driven by playwright-core (`web-test/map.test.mjs`) against a real server
//! on 127.0.0.1.
//!
//! Needs `node`, `/usr/bin/chromium` (or `$TELEXTILES_CHROMIUM`) and
//! `npm ci` run in `daemon/map/web-test` (`bash .ci/setup` does all three).
//! Missing any of them fails the test under CI (`CI` set) and skips it,
//! loudly, elsewhere.
//!
//! `TELEXTILES_MAP_SCREENSHOT=<path.png>` saves a screenshot (that is how
//! `docs/map.png` is made).

mod common;

use common::*;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::Arc;
use std::time::Duration;
use telextiles_index::Index;
use telextiles_map::{ContactPhase, MapEvent, TextureSource};
use tokio::io::{AsyncBufReadExt, AsyncWriteExt, BufReader};

const STEP: Duration = Duration::from_secs(60);

fn in_ci() -> bool {
    std::env::var("CI").is_ok_and(|v| !v.is_empty() && v != "0" && v != "false")
}

/// The tools the test needs, or why they are missing.
fn tools() -> Result<(PathBuf, PathBuf), String> {
    let web_test = Path::new(env!("CARGO_MANIFEST_DIR")).join("web-test");
    let chromium = std::env::var_os("TELEXTILES_CHROMIUM")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from("/usr/bin/chromium"));
    let node_ok = std::process::Command::new("node")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    let mut missing = Vec::new();
    if !node_ok {
        missing.push("`node` (Debian package nodejs)".to_string());
    }
    if !chromium.is_file() {
        missing.push(format!("{} (Debian package chromium)", chromium.display()));
    }
    if !web_test
        .join("node_modules/playwright-core/package.json")
        .is_file()
    {
        missing.push(format!(
            "playwright-core (run `npm ci` in {})",
            web_test.display()
        ));
    }
    if missing.is_empty() {
        Ok((chromium, web_test))
    } else {
        Err(format!(
            "the browser test needs {}; `bash .ci/setup` installs them",
            missing.join(", ")
        ))
    }
}

/// The entry whose map point is farthest from any other (easy to hover).
fn isolated(index: &Index) -> usize {
    let e = &index.entries;
    (0..e.len())
        .max_by(|&a, &b| {
            let gap = |i: usize| {
                (0..e.len())
                    .filter(|&j| j != i)
                    .map(|j| {
                        let (p, q) = (e[i].map_xy, e[j].map_xy);
                        (p[0] - q[0]).hypot(p[1] - q[1])
                    })
                    .fold(f32::INFINITY, f32::min)
            };
            gap(a).total_cmp(&gap(b))
        })
        .unwrap()
}

/// The touches of a simulated press sliding from textile `a` to `b`.
fn press(index: &Index, a: usize, b: usize, n: usize) -> Vec<Vec<f32>> {
    (1..=n)
        .map(|k| {
            let t = k as f32 / n as f32;
            let mut q: Vec<f32> = index.entries[a]
                .centroid
                .iter()
                .zip(&index.entries[b].centroid)
                .map(|(x, y)| (1.0 - t) * x + t * y)
                .collect();
            telextiles_index::l2_normalise(&mut q);
            q
        })
        .collect()
}

async fn send_press(
    events: &tokio::sync::broadcast::Sender<MapEvent>,
    index: &Index,
    touches: &[Vec<f32>],
    unknown: bool,
) {
    let peer = Some("browser-test".to_string());
    let _ = events.send(MapEvent::PeerUp {
        peer: "browser-test".into(),
        addr: Some("[::1]:4433".into()),
    });
    let _ = events.send(MapEvent::PeerPath {
        peer: "browser-test".into(),
        path: "relay".into(),
        addr: "relay https://relay.example:443/".into(),
        rtt_ms: 23.4,
    });
    let _ = events.send(MapEvent::Contact {
        phase: ContactPhase::Start,
        score: Some(0.9),
        peer: peer.clone(),
    });
    for q in touches {
        let _ = events.send(MapEvent::Touch {
            latent: q.clone(),
            peer: peer.clone(),
        });
        tokio::time::sleep(Duration::from_millis(25)).await;
    }
    let last = touches.last().unwrap();
    let best = index.nearest(last).unwrap().best;
    let slot = index.slot_of_entry(best) as u32;
    let _ = events.send(MapEvent::Decision {
        textile: index.entries[best].id.clone(),
        name: None,
        slot,
        distance: index.nearest(last).unwrap().best_dist,
        unknown,
        latency_ms: 30.0,
        peer,
    });
    let angle = slot as f64 * 360.0 / index.roller.n() as f64;
    let _ = events.send(MapEvent::RollerPosition {
        angle_deg: angle / 2.0,
        target_slot: Some(slot),
    });
    let _ = events.send(MapEvent::RollerArrived {
        slot,
        angle_deg: angle,
    });
    let _ = events.send(MapEvent::Felt {
        peer: Some("browser-test".into()),
        press: 1,
        slot,
        felt_ms: 234.4,
    });
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn map_page_in_headless_chromium() {
    let (chromium, web_test) = match tools() {
        Ok(t) => t,
        Err(why) if in_ci() => panic!("CI: {why}"),
        Err(why) => {
            eprintln!("\n*** SKIPPED map_page_in_headless_chromium: {why} ***\n");
            return;
        }
    };

    let index = small_index(30, 8, 11);
    let index2 = small_index(40, 8, 12);
    assert_ne!(index.fingerprint(), index2.fingerprint());
    let srv = start("127.0.0.1:0", index.clone(), TextureSource::Simulated).await;
    let addr = srv.addr;

    let hover = isolated(&index);
    let hover2 = isolated(&index2);
    let (a, b) = (index.roller.slots[0], index.roller.slots[3]);
    let touches = press(&index, a, b, 20);
    let end = index.place_on_map(touches.last().unwrap());
    let nearest_name = index.entries[index.nearest(touches.last().unwrap()).unwrap().best]
        .name
        .clone();
    let touches2 = press(&index2, 0, 5, 20);
    let screenshot = std::env::var("TELEXTILES_MAP_SCREENSHOT").ok();

    let scenario = json!({
        "url": format!("http://127.0.0.1:{}/", addr.port()),
        "chromium": chromium,
        "points": index.entries.len(),
        "seen": index.entries.iter().filter(|e| e.seen).count(),
        "slots": index.roller.n(),
        "points2": index2.entries.len(),
        "hover": {"id": index.entries[hover].id, "name": index.entries[hover].name},
        "hover2": {"id": index2.entries[hover2].id, "name": index2.entries[hover2].name},
        "press_touches": touches.len(),
        "press_end": end,
        "press_nearest_name": nearest_name,
        "press_slot": index.slot_of_entry(index.nearest(touches.last().unwrap()).unwrap().best),
        "screenshot": screenshot,
        "step_ms": 30000,
    });
    let mut child = tokio::process::Command::new("node")
        .arg(web_test.join("map.test.mjs"))
        .arg(scenario.to_string())
        .current_dir(&web_test)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .kill_on_drop(true)
        .spawn()
        .expect("start node");
    let mut stdin = child.stdin.take().unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap()).lines();

    let mut srv = Some(srv);
    let mut presses = 0;
    let result: Value = loop {
        let line = tokio::time::timeout(STEP, out.next_line())
            .await
            .expect("the browser script answers within 60 s")
            .expect("read node output");
        let Some(line) = line else {
            let status = child.wait().await.unwrap();
            panic!("the browser script ended without a result ({status}); its log is above");
        };
        let msg: Value =
            serde_json::from_str(&line).unwrap_or_else(|_| panic!("node said: {line}"));
        match msg["need"].as_str() {
            Some("press") => {
                presses += 1;
                match &srv {
                    // The second press is of a fabric the index does not
                    // have: the page says so.
                    Some(s) if presses == 1 => send_press(&s.events, &index, &touches, false).await,
                    Some(s) => send_press(&s.events, &index2, &touches2, true).await,
                    None => unreachable!(),
                }
            }
            Some("restart") => {
                srv.take().unwrap().stop().await;
                // The page notices the daemon is gone before it comes back.
                tokio::time::sleep(Duration::from_millis(1500)).await;
                let port_addr = format!("127.0.0.1:{}", addr.port());
                srv = Some(start(&port_addr, index2.clone(), TextureSource::Simulated).await);
            }
            Some(other) => panic!("unknown request from the browser script: {other}"),
            None => break msg,
        }
        stdin.write_all(b"go\n").await.unwrap();
        stdin.flush().await.unwrap();
    };
    assert_eq!(result["ok"], true, "{result}");
    let status = tokio::time::timeout(STEP, child.wait())
        .await
        .unwrap()
        .unwrap();
    assert!(status.success(), "browser script: {status}");
    assert_eq!(presses, 2);
    srv.unwrap().stop().await;
    let _ = Arc::strong_count(&index);
}
