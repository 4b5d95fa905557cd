//! The map server over real TCP: pages, JSON, textures, the event stream,
//! bad requests, shutdown.

mod common;

use common::*;
use rand::{Rng, SeedableRng};
use std::time::Duration;
use telextiles_map::{ContactPhase, MapEvent, TextureSource};
use tokio::io::AsyncWriteExt;

#[tokio::test]
async fn page_assets_and_map_json() {
    let index = small_index(24, 6, 1);
    let srv = start("127.0.0.1:0", index.clone(), TextureSource::None).await;

    let page = get(srv.addr, "/").await;
    assert_eq!(page.status, 200);
    assert!(page
        .header("content-type")
        .unwrap()
        .starts_with("text/html"));
    assert!(page.text().contains("/vendor/plotly-basic.min.js"));
    assert!(page.header("content-security-policy").is_some());
    let js = get(srv.addr, "/vendor/plotly-basic.min.js").await;
    assert_eq!(js.status, 200);
    assert!(js.body.len() > 500_000, "plotly is embedded");
    assert!(js.text().contains("plotly.js (basic - minified) v4.1.1"));
    assert_eq!(get(srv.addr, "/map.js").await.status, 200);
    assert_eq!(get(srv.addr, "/map.css").await.status, 200);
    let lic = get(srv.addr, "/vendor/plotly-LICENSE.txt").await;
    assert!(lic.text().contains("MIT License"));

    let m = get(srv.addr, "/api/map").await;
    assert_eq!(m.status, 200);
    assert_eq!(m.header("content-type"), Some("application/json"));
    let m = m.json();
    assert_eq!(m["fingerprint"], index.fingerprint());
    let ts = m["textiles"].as_array().unwrap();
    assert_eq!(ts.len(), 24);
    for (i, (t, e)) in ts.iter().zip(&index.entries).enumerate() {
        assert_eq!(t["i"], i);
        assert_eq!(t["id"], e.id.as_str());
        assert_eq!(t["name"], e.name.as_str());
        assert_eq!(t["seen"], e.seen);
        assert_eq!(t["structure"], e.structure.as_str());
        assert_eq!(
            t["attributes"].as_array().unwrap().len(),
            e.attributes.len()
        );
        assert!((t["x"].as_f64().unwrap() - e.map_xy[0] as f64).abs() < 1e-6);
        assert!((t["y"].as_f64().unwrap() - e.map_xy[1] as f64).abs() < 1e-6);
        let slot = index.roller.slots.iter().position(|&s| s == i);
        assert_eq!(t["slot"].as_u64().map(|s| s as usize), slot);
        assert_eq!(t["nearest_slot"], index.slot_of_entry(i));
        assert!(t["texture"].is_null(), "textures are off");
    }
    assert_eq!(m["roller"]["n"], 6);
    assert!(ts.iter().any(|t| t["seen"] == false) && ts.iter().any(|t| t["seen"] == true));

    let h = raw(
        srv.addr,
        format!(
            "HEAD /api/map HTTP/1.1\r\nHost: localhost:{}\r\nConnection: close\r\n\r\n",
            srv.addr.port()
        )
        .as_bytes(),
    )
    .await;
    assert_eq!(h.status, 200);
    assert!(h.body.is_empty());
    srv.stop().await;
}

#[tokio::test]
async fn textures_rendered_by_the_simulator_and_bad_ids() {
    let index = small_index(12, 4, 2);
    let srv = start("127.0.0.1:0", index.clone(), TextureSource::Simulated).await;
    let m = get(srv.addr, "/api/map").await.json();
    let url = m["textiles"][3]["texture"].as_str().unwrap().to_string();
    assert!(
        url.starts_with(&format!("/api/texture/{}.png?v=", index.entries[3].id)),
        "{url}"
    );
    let r = get(srv.addr, &url).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("image/png"));
    let img = image::load_from_memory(&r.body).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (240, 320));
    // Cached: the same bytes again.
    assert_eq!(get(srv.addr, &url).await.body, r.body);
    // Two textiles give two different images.
    let other = get(
        srv.addr,
        &format!("/api/texture/{}.png", index.entries[4].id),
    )
    .await;
    assert_eq!(other.status, 200);
    assert_ne!(other.body, r.body);

    for (path, status) in [
        ("/api/texture/T999.png", 404),
        ("/api/texture/.png", 400),
        ("/api/texture/%zz.png", 400),
        ("/api/texture/%ff.png", 400),
        ("/api/texture/T001", 404),
        ("/api/texture/..%2F..%2Fetc%2Fpasswd.png", 404),
        ("/api/texture/a/b.png", 400),
        ("/nope", 404),
        ("/api", 404),
        ("/api/map/extra", 404),
    ] {
        let r = get(srv.addr, path).await;
        assert_eq!(r.status, status, "{path}: {}", r.text());
        assert!(!r.body.is_empty(), "{path}: errors say why");
    }
    srv.stop().await;
}

#[tokio::test]
async fn textures_from_a_directory() {
    let dir = tempfile::tempdir().unwrap();
    let index = small_index(8, 4, 3);
    let img = image::RgbImage::from_pixel(30, 40, image::Rgb([1, 2, 3]));
    img.save(dir.path().join(format!("{}.png", index.entries[0].id)))
        .unwrap();
    let srv = start(
        "127.0.0.1:0",
        index.clone(),
        TextureSource::Directory(dir.path().into()),
    )
    .await;
    let r = get(
        srv.addr,
        &format!("/api/texture/{}.png", index.entries[0].id),
    )
    .await;
    assert_eq!(r.status, 200);
    assert_eq!(image::load_from_memory(&r.body).unwrap().to_rgb8(), img);
    let r = get(
        srv.addr,
        &format!("/api/texture/{}.png", index.entries[1].id),
    )
    .await;
    assert_eq!(r.status, 404);
    assert!(r.text().contains("no image for textile"), "{}", r.text());
    srv.stop().await;
}

#[tokio::test]
async fn bad_requests_get_4xx_and_the_server_survives() {
    let index = small_index(8, 4, 4);
    let srv = start("127.0.0.1:0", index, TextureSource::None).await;
    let a = srv.addr;
    let port = a.port();
    let cases: Vec<(Vec<u8>, u16)> = vec![
        (format!("POST / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 0\r\nConnection: close\r\n\r\n").into_bytes(), 405),
        (format!("DELETE /api/map HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n").into_bytes(), 405),
        (b"GET / HTTP/1.1\r\nHost: evil.example\r\nConnection: close\r\n\r\n".to_vec(), 421),
        (b"GET / HTTP/1.1\r\nConnection: close\r\n\r\n".to_vec(), 421),
        (format!("GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nContent-Length: 5\r\nConnection: close\r\n\r\nhello").into_bytes(), 413),
        (b"GARBAGE\r\n\r\n".to_vec(), 400),
        (b"GET / HTTP/9.9\r\n\r\n".to_vec(), 400),
        (format!("GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nX-Big: {}\r\n\r\n", "a".repeat(40_000)).into_bytes(), 431),
        (format!("GET /{} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n", "a".repeat(70_000)).into_bytes(), 414),
    ];
    for (req, want) in cases {
        let mut s = tokio::net::TcpStream::connect(a).await.unwrap();
        // The server may answer and close before a huge request is fully
        // written; that is fine.
        let _ = s.write_all(&req).await;
        let r = read_response(&mut s).await;
        let got = r.as_ref().map(|r| r.status);
        let head = String::from_utf8_lossy(&req[..req.len().min(60)]).into_owned();
        // hyper answers 414 for an over-long URI and 431 for over-long
        // headers; either way a 4xx, never a 5xx or a hang.
        assert!(
            got == Some(want) || (want == 414 && got == Some(431)),
            "{head:?}: got {got:?}, want {want}"
        );
    }

    // Random bytes: every connection gets a 4xx or is closed; no panic, no hang.
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    for _ in 0..150 {
        let n = rng.gen_range(0..600);
        let mut bytes: Vec<u8> = (0..n).map(|_| rng.gen()).collect();
        if rng.gen_bool(0.5) {
            let mut v = b"GET /".to_vec();
            v.append(&mut bytes);
            bytes = v;
        }
        bytes.extend_from_slice(b"\r\n\r\n");
        let mut s = tokio::net::TcpStream::connect(a).await.unwrap();
        let _ = s.write_all(&bytes).await;
        if let Some(r) = read_response(&mut s).await {
            assert!(
                (400..500).contains(&r.status),
                "status {} for random bytes",
                r.status
            );
        }
    }
    // A client that never finishes its request does not block others.
    let mut slow = tokio::net::TcpStream::connect(a).await.unwrap();
    slow.write_all(b"GET / HTTP/1.1\r\nHost: 127.0.0.1\r\n")
        .await
        .unwrap();
    assert_eq!(get(a, "/api/health").await.status, 200);
    drop(slow);
    srv.stop().await;
}

#[tokio::test]
async fn event_stream_places_touches_and_keeps_state() {
    let index = small_index(20, 5, 5);
    let srv = start("127.0.0.1:0", index.clone(), TextureSource::None).await;
    let mut sse = Sse::open(srv.addr).await;
    let hello = sse.next().await.unwrap();
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["fingerprint"], index.fingerprint());
    assert_eq!(hello["textiles"], 20);
    let state = sse.next().await.unwrap();
    assert_eq!(state["type"], "state");
    assert!(state["touch"].is_null());

    let ev = &srv.events;
    ev.send(MapEvent::PeerUp {
        peer: "alice".into(),
        addr: Some("[::1]:4433".into()),
    })
    .unwrap();
    ev.send(MapEvent::PeerPath {
        peer: "alice".into(),
        path: "relay".into(),
        addr: "relay https://relay.example:443/".into(),
        rtt_ms: 31.0,
    })
    .unwrap();
    ev.send(MapEvent::Contact {
        phase: ContactPhase::Start,
        score: Some(0.7),
        peer: Some("alice".into()),
    })
    .unwrap();
    // A latent of the wrong dimension and a non-finite one are dropped...
    ev.send(MapEvent::Touch {
        latent: vec![1.0; 3],
        peer: None,
    })
    .unwrap();
    ev.send(MapEvent::Touch {
        latent: vec![f32::NAN; index.dim],
        peer: None,
    })
    .unwrap();
    ev.send(MapEvent::Touch {
        latent: vec![0.0; index.dim],
        peer: None,
    })
    .unwrap();
    // ...and a good one is placed where the index puts it.
    let k = 7;
    let q = index.entries[k].centroid.clone();
    ev.send(MapEvent::Touch {
        latent: q.clone(),
        peer: Some("alice".into()),
    })
    .unwrap();
    ev.send(MapEvent::Decision {
        textile: index.entries[k].id.clone(),
        name: None,
        slot: index.slot_of_entry(k) as u32,
        distance: 0.01,
        unknown: false,
        latency_ms: 12.5,
        peer: Some("alice".into()),
    })
    .unwrap();
    ev.send(MapEvent::RollerPosition {
        angle_deg: 143.0,
        target_slot: Some(2),
    })
    .unwrap();
    ev.send(MapEvent::RollerArrived {
        slot: 2,
        angle_deg: 144.0,
    })
    .unwrap();

    let peer = sse.next().await.unwrap();
    assert_eq!(peer["type"], "peer");
    assert_eq!(peer["up"], true);
    let path = sse.next().await.unwrap();
    assert_eq!(
        (
            path["type"].as_str(),
            path["path"].as_str(),
            path["rtt_ms"].as_f64()
        ),
        (Some("peer"), Some("relay"), Some(31.0))
    );
    let contact = sse.next().await.unwrap();
    assert_eq!(
        (contact["type"].as_str(), contact["on"].as_bool()),
        (Some("contact"), Some(true))
    );
    let touch = sse.next().await.unwrap();
    assert_eq!(touch["type"], "touch", "bad touches were skipped: {touch}");
    let [x, y] = index.place_on_map(&q);
    assert!((touch["x"].as_f64().unwrap() - x as f64).abs() < 1e-6);
    assert!((touch["y"].as_f64().unwrap() - y as f64).abs() < 1e-6);
    let near = touch["nearest"].as_array().unwrap();
    assert_eq!(near.len(), telextiles_map::TOUCH_NEAREST);
    assert_eq!(near[0]["id"], index.entries[k].id.as_str());
    assert_eq!(near[0]["i"], k);
    assert_eq!(touch["peer"], "alice");
    let dec = sse.next().await.unwrap();
    assert_eq!(dec["type"], "decision");
    assert_eq!(dec["i"], k);
    assert_eq!(dec["unknown"], false, "{dec}");
    assert_eq!(
        dec["name"],
        index.entries[k].name.as_str(),
        "name filled in from the index"
    );
    let moving = sse.next().await.unwrap();
    assert_eq!(
        (moving["type"].as_str(), moving["arrived"].as_bool()),
        (Some("roller"), Some(false))
    );
    assert_eq!(
        moving["slot"], 2,
        "143 degrees is nearest slot 2 of 5 (144)"
    );
    let arrived = sse.next().await.unwrap();
    assert_eq!(arrived["arrived"], true);

    // A page that connects now starts from the latest state.
    let mut late = Sse::open(srv.addr).await;
    assert_eq!(late.next().await.unwrap()["type"], "hello");
    let st = late.next().await.unwrap();
    assert_eq!(st["type"], "state");
    assert_eq!(st["touch"], touch);
    assert_eq!(st["decision"], dec);
    assert_eq!(st["roller"], arrived);
    assert_eq!(st["contact"]["on"], true);
    assert_eq!(st["peers"][0]["peer"], "alice");
    assert_eq!(
        st["peers"][0]["path"], "relay",
        "the path outlives the page"
    );

    ev.send(MapEvent::PeerDown {
        peer: "alice".into(),
        reason: "closed".into(),
    })
    .unwrap();
    let down = late.next().await.unwrap();
    assert_eq!(
        (down["type"].as_str(), down["up"].as_bool()),
        (Some("peer"), Some(false))
    );

    // Stopping the server ends the streams.
    srv.stop().await;
    assert!(tokio::time::timeout(Duration::from_secs(5), async {
        while sse.next().await.is_some() {}
    })
    .await
    .is_ok());
}

#[tokio::test]
async fn too_many_event_streams_get_503() {
    let index = small_index(8, 4, 6);
    let srv = start("127.0.0.1:0", index, TextureSource::None).await;
    let mut open = Vec::new();
    for _ in 0..telextiles_map::MAX_EVENT_STREAMS {
        open.push(Sse::open(srv.addr).await);
    }
    let r = get(srv.addr, "/api/events").await;
    assert_eq!(r.status, 503);
    assert!(r.header("retry-after").is_some());
    // Closing one frees its place.
    drop(open.pop());
    let mut ok = false;
    for _ in 0..50 {
        tokio::time::sleep(Duration::from_millis(20)).await;
        let mut s = tokio::net::TcpStream::connect(srv.addr).await.unwrap();
        s.write_all(
            format!(
                "GET /api/events HTTP/1.0\r\nHost: 127.0.0.1:{}\r\n\r\n",
                srv.addr.port()
            )
            .as_bytes(),
        )
        .await
        .unwrap();
        let mut head = [0u8; 12];
        use tokio::io::AsyncReadExt;
        s.read_exact(&mut head).await.unwrap();
        if &head == b"HTTP/1.0 200" {
            ok = true;
            break;
        }
    }
    assert!(ok, "a stream slot is freed when a page goes away");
    srv.stop().await;
}

#[test]
fn control_socket_event_lines_convert() {
    // Lines as telextiles-control writes them (Event::to_line).
    let lines = [
        r#"{"event":"contact","phase":"start","score":0.4}"#,
        r#"{"event":"decision","textile":"T012","slot":3,"distance":0.2,"latency_ms":41.0,"peer":"bob"}"#,
        r#"{"event":"peer_up","peer":"bob","addr":"[::1]:1"}"#,
        r#"{"event":"peer_down","peer":"bob","reason":"timeout"}"#,
        r#"{"event":"roller_position","angle_deg":10.5}"#,
        r#"{"event":"roller_arrived","slot":1,"angle_deg":22.5}"#,
        r#"{"event":"error","source":"roller","message":"stalled"}"#,
    ];
    for l in lines {
        let ev =
            MapEvent::from_control_json(&format!("{l}\n")).unwrap_or_else(|e| panic!("{l}: {e}"));
        let back = serde_json::to_value(&ev).unwrap();
        assert_eq!(
            back["event"],
            serde_json::from_str::<serde_json::Value>(l).unwrap()["event"]
        );
    }
    assert!(matches!(
        MapEvent::from_control_json(lines[1]).unwrap(),
        MapEvent::Decision { slot: 3, ref peer, .. } if peer.as_deref() == Some("bob")
    ));
    assert!(MapEvent::from_control_json(r#"{"event":"dropped","reason":"slow"}"#).is_err());
    assert!(MapEvent::from_control_json("not json").is_err());
}

#[test]
fn every_control_event_converts_except_dropped() {
    use telextiles_control::protocol::{ContactPhase as Cp, Event};
    let events = vec![
        Event::Contact {
            phase: Cp::Start,
            score: Some(0.5),
            coverage: None,
        },
        Event::Contact {
            phase: Cp::End,
            score: None,
            coverage: Some(0.8),
        },
        Event::Decision {
            textile: "T012".into(),
            name: Some("denim".into()),
            slot: 3,
            distance: 0.25,
            unknown: false,
            latency_ms: 41.5,
            peer: Some("bob".into()),
            press: None,
            final_decision: false,
            since_contact_ms: None,
        },
        // A fabric the index does not have: flagged on the map too.
        Event::Decision {
            textile: "T047".into(),
            name: None,
            slot: 5,
            distance: 0.71,
            unknown: true,
            latency_ms: 40.0,
            peer: None,
            press: Some(4),
            final_decision: true,
            since_contact_ms: Some(180.0),
        },
        Event::PeerUp {
            peer: "bob".into(),
            addr: Some("[::1]:1".into()),
        },
        Event::PeerDown {
            peer: "bob".into(),
            reason: "timeout".into(),
        },
        Event::PeerPath {
            peer: "bob".into(),
            path: "direct".into(),
            addr: "direct 198.18.2.2:7000".into(),
            rtt_ms: 12.5,
        },
        Event::RollerPosition {
            angle_deg: 10.5,
            target_slot: Some(1),
        },
        Event::RollerArrived {
            slot: 1,
            angle_deg: 22.5,
        },
        Event::Felt {
            peer: Some("bob".into()),
            press: 4,
            slot: 1,
            felt_ms: 240.5,
        },
        Event::Error {
            source: "roller".into(),
            message: "stalled".into(),
        },
    ];
    for ev in &events {
        let line = ev.to_line();
        let m = MapEvent::from_control_json(&line).unwrap_or_else(|e| panic!("{line}: {e}"));
        let ok = match (ev, &m) {
            (
                Event::Contact { phase, score, .. },
                MapEvent::Contact {
                    phase: p,
                    score: s,
                    peer: None,
                },
            ) => (*phase == Cp::Start) == (*p == ContactPhase::Start) && score == s,
            (
                Event::Decision {
                    textile,
                    name,
                    slot,
                    distance,
                    unknown,
                    latency_ms,
                    peer,
                    ..
                },
                MapEvent::Decision {
                    textile: t,
                    name: n,
                    slot: s,
                    distance: d,
                    unknown: u,
                    latency_ms: l,
                    peer: p,
                },
            ) => {
                textile == t
                    && name == n
                    && slot == s
                    && distance == d
                    && unknown == u
                    && latency_ms == l
                    && peer == p
            }
            (Event::PeerUp { peer, addr }, MapEvent::PeerUp { peer: p, addr: a }) => {
                peer == p && addr == a
            }
            (Event::PeerDown { peer, reason }, MapEvent::PeerDown { peer: p, reason: r }) => {
                peer == p && reason == r
            }
            (
                Event::PeerPath {
                    peer,
                    path,
                    addr,
                    rtt_ms,
                },
                MapEvent::PeerPath {
                    peer: p,
                    path: h,
                    addr: a,
                    rtt_ms: r,
                },
            ) => peer == p && path == h && addr == a && rtt_ms == r,
            (
                Event::RollerPosition {
                    angle_deg,
                    target_slot,
                },
                MapEvent::RollerPosition {
                    angle_deg: a,
                    target_slot: t,
                },
            ) => angle_deg == a && target_slot == t,
            (
                Event::RollerArrived { slot, angle_deg },
                MapEvent::RollerArrived {
                    slot: s,
                    angle_deg: a,
                },
            ) => slot == s && angle_deg == a,
            (
                Event::Felt {
                    peer,
                    press,
                    slot,
                    felt_ms,
                },
                MapEvent::Felt {
                    peer: p,
                    press: r,
                    slot: s,
                    felt_ms: f,
                },
            ) => peer == p && press == r && slot == s && felt_ms == f,
            (
                Event::Error { source, message },
                MapEvent::Error {
                    source: s,
                    message: m,
                },
            ) => source == s && message == m,
            _ => false,
        };
        assert!(ok, "{line} became {m:?}");
    }
    let dropped = Event::Dropped {
        reason: "slow".into(),
    }
    .to_line();
    assert!(MapEvent::from_control_json(&dropped).is_err());
}

#[test]
fn a_decision_on_a_fabric_the_index_does_not_have_reaches_the_page_flagged() {
    let index = small_index(12, 4, 5);
    let id = index.entries[2].id.clone();
    let mut live = telextiles_map::Live::new(index);
    // As the control socket writes it: `unknown` only when true.
    let flagged = format!(
        r#"{{"event":"decision","textile":"{id}","slot":1,"distance":0.8,"unknown":true,"latency_ms":40.0}}"#
    );
    let msg = live
        .apply(&MapEvent::from_control_json(&flagged).unwrap())
        .unwrap();
    assert_eq!(
        (msg["type"].as_str(), msg["i"].as_u64()),
        (Some("decision"), Some(2))
    );
    assert_eq!(msg["unknown"], true, "{msg}");
    assert_eq!(live.snapshot()["decision"]["unknown"], true);
    let known = format!(
        r#"{{"event":"decision","textile":"{id}","slot":1,"distance":0.1,"latency_ms":40.0}}"#
    );
    let msg = live
        .apply(&MapEvent::from_control_json(&known).unwrap())
        .unwrap();
    assert_eq!(msg["unknown"], false, "{msg}");
    assert_eq!(live.snapshot()["decision"]["unknown"], false);
}
