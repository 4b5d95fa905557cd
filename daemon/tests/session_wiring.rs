//! The live session's wiring, run as a user runs it (`telextilesd run`,
//! real processes, loopback only, simulated sensor and roller): the
//! configured log level is honoured, LED control on a sensor without LEDs
//! is refused with a message that names the sensor, and the roller is set
//! to the index's slot count.
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");
const MODEL: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/encoder.onnx");
const INDEX: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../models/index.tlxi");

struct Daemon {
    child: Child,
    lines: mpsc::Receiver<String>,
    socket: std::path::PathBuf,
}

impl Drop for Daemon {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn start(dir: &Path, extra: &[&str], env: &[(&str, &str)]) -> Daemon {
    std::fs::write(dir.join("none.toml"), "").unwrap();
    let socket = dir.join("control.sock");
    let mut cmd = Command::new(BIN);
    cmd.arg("run")
        .arg("--config")
        .arg(dir.join("none.toml"))
        .args(["--state-dir", dir.join("state").to_str().unwrap()])
        .args(["--data-dir", dir.join("data").to_str().unwrap()])
        .args(["--runtime-dir", dir.to_str().unwrap()])
        .args(["--socket", socket.to_str().unwrap()])
        .args([
            "--sensor",
            "sim",
            "--roller",
            "sim",
            "--map=false",
            "--mdns=false",
        ])
        .args([
            "--listen",
            "127.0.0.1:0",
            "--model",
            MODEL,
            "--index",
            INDEX,
        ])
        .args(extra)
        .env_remove("RUST_LOG")
        .env_remove("TELEXTILESD_LOG")
        .env_remove("TELEXTILESD_CONFIG")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    for (k, v) in env {
        cmd.env(k, v);
    }
    let mut child = cmd.spawn().expect("start telextilesd");
    let (tx, rx) = mpsc::channel();
    for out in [
        Box::new(child.stdout.take().unwrap()) as Box<dyn std::io::Read + Send>,
        Box::new(child.stderr.take().unwrap()),
    ] {
        let tx = tx.clone();
        std::thread::spawn(move || {
            for l in BufReader::new(out).lines().map_while(Result::ok) {
                let _ = tx.send(l);
            }
        });
    }
    Daemon {
        child,
        lines: rx,
        socket,
    }
}

/// Lines until one contains `needle` (Some) or `within` passes (None).
fn wait_for(d: &Daemon, needle: &str, within: Duration) -> (Option<String>, Vec<String>) {
    let deadline = Instant::now() + within;
    let mut seen = Vec::new();
    while let Some(left) = deadline.checked_duration_since(Instant::now()) {
        match d.lines.recv_timeout(left) {
            Ok(l) => {
                if l.contains(needle) {
                    return (Some(l), seen);
                }
                seen.push(l);
            }
            Err(_) => break,
        }
    }
    (None, seen)
}

fn ctl(d: &Daemon, args: &[&str]) -> std::process::Output {
    let deadline = Instant::now() + Duration::from_secs(20);
    while !d.socket.exists() && Instant::now() < deadline {
        std::thread::sleep(Duration::from_millis(50));
    }
    Command::new(BIN)
        .arg("ctl")
        .args(["--socket", d.socket.to_str().unwrap()])
        .args(args)
        .output()
        .expect("run telextilesd ctl")
}

#[test]
fn the_configured_log_level_is_honoured() {
    // --log info: the roller's INFO line on connecting appears (it used to
    // be ignored: only RUST_LOG counted, and its default shows errors only).
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path(), &["--log", "info"], &[]);
    let (line, seen) = wait_for(&d, "INFO", Duration::from_secs(30));
    assert!(line.is_some(), "no INFO line with --log info: {seen:#?}");
    drop(d);
    // TELEXTILESD_LOG works the same way.
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path(), &[], &[("TELEXTILESD_LOG", "info")]);
    let (line, seen) = wait_for(&d, "INFO", Duration::from_secs(30));
    assert!(
        line.is_some(),
        "no INFO line with TELEXTILESD_LOG=info: {seen:#?}"
    );
    drop(d);
    // --log warn: the roller connects (the status says so) without an INFO line.
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path(), &["--log", "warn"], &[]);
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let out = ctl(&d, &["--json", "status"]);
        let text = String::from_utf8_lossy(&out.stdout);
        if text.contains("\"connected\":true") {
            break;
        }
        assert!(Instant::now() < deadline, "roller never connected: {text}");
        std::thread::sleep(Duration::from_millis(200));
    }
    let (line, _) = wait_for(&d, "INFO", Duration::from_millis(500));
    assert_eq!(line, None);
}

#[test]
fn led_control_on_a_sensor_without_leds_names_the_sensor() {
    let dir = tempfile::tempdir().unwrap();
    let d = start(dir.path(), &[], &[]);
    let out = ctl(&d, &["sensor", "led", "3", "4", "5"]);
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!out.status.success(), "{text}");
    assert!(
        text.contains("simulator") && text.contains("no LEDs"),
        "{text}"
    );
}

#[test]
fn a_missing_model_is_a_clear_error_not_a_fallback_into_the_build_tree() {
    // No model compiled in: the configured (here: the data directory's
    // default) model is the only one, and its absence says what to do.
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("none.toml"), "").unwrap();
    let out = Command::new(BIN)
        .arg("run")
        .arg("--config")
        .arg(dir.path().join("none.toml"))
        .args(["--state-dir", dir.path().join("state").to_str().unwrap()])
        .args(["--data-dir", dir.path().join("data").to_str().unwrap()])
        .args(["--runtime-dir", dir.path().to_str().unwrap()])
        .args([
            "--sensor",
            "sim",
            "--roller",
            "sim",
            "--map=false",
            "--mdns=false",
        ])
        .args(["--listen", "127.0.0.1:0"])
        .env_remove("TELEXTILESD_MODEL")
        .env_remove("TELEXTILESD_INDEX")
        .env_remove("TELEXTILESD_CONFIG")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{err}");
    assert!(
        err.contains("encoder model")
            && err.contains("data/encoder.onnx")
            && err.contains("not found")
            && err.contains("--model"),
        "{err}"
    );
}
