//! `telextilesd map`: the binary serves the map and `--demo` drives the live
//! point, over real TCP on 127.0.0.1.

use std::io::{BufRead, BufReader, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

struct Kill(Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn get(addr: &str, path: &str) -> (u16, Vec<u8>) {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET {path} HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut buf = Vec::new();
    s.read_to_end(&mut buf).unwrap();
    let end = buf.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let status = String::from_utf8_lossy(&buf[9..12]).parse().unwrap();
    (status, buf[end + 4..].to_vec())
}

#[test]
fn map_demo_serves_and_streams_simulated_presses() {
    let mut child = Command::new(env!("CARGO_BIN_EXE_telextilesd"))
        .args([
            "map",
            "--demo",
            "--bind",
            "127.0.0.1:0",
            "--textures",
            "none",
            "--seed",
            "3",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut out = BufReader::new(child.stdout.take().unwrap());
    let child = Kill(child);
    let mut line = String::new();
    out.read_line(&mut line).unwrap();
    let addr = line
        .strip_prefix("map: http://")
        .and_then(|r| r.split('/').next())
        .unwrap_or_else(|| panic!("first line: {line:?}"))
        .to_string();

    let (status, body) = get(&addr, "/api/map");
    assert_eq!(status, 200);
    let m: serde_json::Value = serde_json::from_slice(&body).unwrap();
    let cat = telextiles_sim::Catalogue::builtin();
    assert_eq!(m["textiles"].as_array().unwrap().len(), cat.textiles.len());
    assert_eq!(m["roller"]["n"], 16);
    assert_eq!(m["encoder_arch"], "demo-catalogue-features");

    // The demo's simulated presses arrive on the event stream.
    let mut s = TcpStream::connect(&addr).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    write!(s, "GET /api/events HTTP/1.0\r\nHost: {addr}\r\n\r\n").unwrap();
    let mut r = BufReader::new(s);
    let (mut touches, mut decisions, mut peer) = (0, 0, false);
    let t0 = Instant::now();
    while (touches < 10 || decisions < 1 || !peer) && t0.elapsed() < Duration::from_secs(20) {
        let mut l = String::new();
        if r.read_line(&mut l).unwrap() == 0 {
            break;
        }
        let Some(data) = l.strip_prefix("data: ") else {
            continue;
        };
        let v: serde_json::Value = serde_json::from_str(data).unwrap();
        match v["type"].as_str() {
            Some("touch") => {
                touches += 1;
                assert!(v["x"].as_f64().unwrap().abs() <= 1.0 + 1e-6);
                assert_eq!(v["nearest"].as_array().unwrap().len(), 3);
            }
            Some("decision") => decisions += 1,
            Some("state") => peer |= v["peers"][0]["peer"] == "demo-peer",
            Some("peer") => peer |= v["up"] == true,
            _ => {}
        }
    }
    assert!(
        touches >= 10 && decisions >= 1 && peer,
        "touches {touches}, decisions {decisions}, peer {peer}"
    );
    drop(child);
}

#[test]
fn map_refuses_bad_arguments_with_a_message() {
    let out = Command::new(env!("CARGO_BIN_EXE_telextilesd"))
        .arg("map")
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--index") && err.contains("--demo"), "{err}");

    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = taken.local_addr().unwrap().to_string();
    let out = Command::new(env!("CARGO_BIN_EXE_telextilesd"))
        .args(["map", "--demo", "--bind", &addr])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("cannot bind"), "{err}");

    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("index.bin");
    std::fs::write(&bad, b"not an index").unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_telextilesd"))
        .args(["map", "--index"])
        .arg(&bad)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("reading index"), "{err}");
}
