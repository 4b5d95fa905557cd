//! `telextilesd pair` end to end on 127.0.0.1 (real processes, real QUIC,
//! mDNS off): one side shows a code, the other passes it with --code; both
//! print the same verification code and go live. A wrong code ends the
//! showing side and is one failed attempt on the entering side.
use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

const BIN: &str = env!("CARGO_BIN_EXE_telextilesd");

/// An empty configuration file in `dir` (so the host's is never read).
fn none_toml(dir: &std::path::Path) -> std::path::PathBuf {
    let p = dir.join("none.toml");
    std::fs::write(&p, "").unwrap();
    p
}

struct Proc {
    child: Child,
    rx: mpsc::Receiver<String>,
    seen: Vec<String>,
}

/// `telextilesd pair <args>` with everything of its own under `dir`.
fn pair_command(args: &[&str], dir: &std::path::Path) -> Command {
    let mut c = Command::new(BIN);
    c.arg("pair")
        .args(args)
        .args(["--state-dir", dir.to_str().unwrap(), "--mdns=false"])
        .args([
            "--data-dir",
            dir.to_str().unwrap(),
            "--runtime-dir",
            dir.to_str().unwrap(),
        ])
        // Nothing of the host: no configuration file, no camera, no
        // serial port; the shipped model and index.
        .arg("--config")
        .arg(none_toml(dir))
        .args(["--sensor", "sim", "--roller", "sim", "--map=false"])
        .args([
            "--model",
            concat!(env!("CARGO_MANIFEST_DIR"), "/../models/encoder.onnx"),
        ])
        .args([
            "--index",
            concat!(env!("CARGO_MANIFEST_DIR"), "/../models/index.tlxi"),
        ])
        .env_remove("TELEXTILESD_CONFIG")
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    c
}

impl Proc {
    fn spawn(args: &[&str], dir: &std::path::Path) -> Proc {
        let mut child = pair_command(args, dir).spawn().expect("run telextilesd");
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
        Proc {
            child,
            rx,
            seen: Vec::new(),
        }
    }

    fn expect(&mut self, needle: &str) -> String {
        let deadline = Instant::now() + Duration::from_secs(15);
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match self.rx.recv_timeout(left) {
                Ok(l) => {
                    self.seen.push(l.clone());
                    if l.contains(needle) {
                        return l;
                    }
                }
                Err(_) => break,
            }
        }
        panic!(
            "no line containing {needle:?}; output:\n{}",
            self.seen.join("\n")
        );
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn free_port() -> u16 {
    std::net::UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn show(dir: &std::path::Path) -> (Proc, String, String) {
    let addr = format!("127.0.0.1:{}", free_port());
    let mut a = Proc::spawn(&["--name", "alice", "--listen", &addr], dir);
    let key = a.expect("This device's key: ");
    let key = key.split("key: ").nth(1).unwrap().trim().to_string();
    let line = a.expect("Pairing code: ");
    let code = line.split_whitespace().nth(2).unwrap().to_string();
    // What the user on the other device types after --connect.
    (a, code, format!("{key}@{addr}"))
}

#[test]
fn pair_then_live_session() {
    let (da, db) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let (mut a, code, addr) = show(da.path());
    let b_listen = format!("127.0.0.1:{}", free_port());
    let mut b = Proc::spawn(
        &[
            "--name",
            "bob",
            "--listen",
            &b_listen,
            "--connect",
            &addr,
            "--code",
            &code,
        ],
        db.path(),
    );
    let va = a.expect("Verification code: ");
    let vb = b.expect("Verification code: ");
    let code_of = |l: &str| l.split("Verification code: ").nth(1).unwrap()[..7].to_string();
    assert_eq!(code_of(&va), code_of(&vb));
    assert!(a.expect("Peer up: ").contains("bob"));
    assert!(b.expect("Peer up: ").contains("alice"));
}

#[test]
fn wrong_code_fails_on_both_sides() {
    let (da, db) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let (mut a, code, addr) = show(da.path());
    // Same digits with the first two swapped keeps the format but is another
    // code; fix the check digit by trying all ten last digits.
    let digits: String = code.chars().filter(|c| c.is_ascii_digit()).collect();
    let wrong = (0..10)
        .map(|d| format!("{}{}", &digits[..7], d))
        .chain((0..10).map(|d| {
            format!(
                "{}{}{}",
                (digits.as_bytes()[0] - b'0' + 1) % 10,
                &digits[1..7],
                d
            )
        }))
        .find(|c| *c != digits && c.parse::<telextiles_certs::PairingCode>().is_ok())
        .expect("some valid code differs");
    let b_listen = format!("127.0.0.1:{}", free_port());
    let mut b = Proc::spawn(
        &["--listen", &b_listen, "--connect", &addr, "--code", &wrong],
        db.path(),
    );
    // b, entering the code, judged a's confirmation itself: one failed
    // attempt (a device that proved no code cannot end `pair --code`; it
    // keeps looking until the code's lifetime has passed). a, showing the
    // code, used it up: its pairing fails and the command ends.
    let eb = b.expect("did not match");
    assert!(eb.contains("still looking"), "{eb}");
    a.expect("did not match");
    a.expect("pairing failed");
    let status = a.child.wait().unwrap();
    assert!(!status.success());
    std::thread::sleep(Duration::from_secs(1));
    assert!(
        b.child.try_wait().unwrap().is_none(),
        "pair --code ended on a failed attempt"
    );
}

/// Devices that prove no code never end `pair --code`, so its deadline
/// must: with nothing answering at the given address it gives up once the
/// code's lifetime has passed (shortened here), says why and fails.
#[test]
fn entering_a_code_gives_up_after_the_code_lifetime() {
    // Both front ends: pairing only, and pairing before a live session.
    for no_session in [true, false] {
        gives_up(no_session);
    }
}

fn gives_up(no_session: bool) {
    let d = tempfile::tempdir().unwrap();
    let nobody = format!(
        "{}@127.0.0.1:{}",
        telextiles_certs::Identity::generate().unwrap().peer_key(),
        free_port()
    );
    let listen = format!("127.0.0.1:{}", free_port());
    let code = (0..10)
        .map(|d| format!("1234567{d}"))
        .find(|c| c.parse::<telextiles_certs::PairingCode>().is_ok())
        .expect("one check digit fits");
    let t0 = Instant::now();
    let mut args = vec!["--listen", &listen, "--connect", &nobody, "--code", &code];
    if no_session {
        args.push("--no-session");
    }
    let mut child = pair_command(&args, d.path())
        .env("TELEXTILESD_PAIRING_TTL_MS", "1500")
        .spawn()
        .unwrap();
    // Give it up to 30 s (a loaded machine), then look at what it said.
    let deadline = Instant::now() + Duration::from_secs(30);
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if Instant::now() > deadline {
            let _ = child.kill();
            panic!("pair --code did not give up");
        }
        std::thread::sleep(Duration::from_millis(100));
    };
    let out = child.wait_with_output().unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(!status.success(), "no_session {no_session}: {text}");
    assert!(
        text.contains("no device proved the code within 1.5 s"),
        "{text}"
    );
    assert!(t0.elapsed() >= Duration::from_millis(1500), "{text}");
}
