//! The `roller-sim` binary on a real pty: prints its slave path, creates the
//! link, answers Hello and moves the simulated wheel.
use std::io::{BufRead, BufReader, Write};
use std::process::{Command as Process, Stdio};
use std::time::{Duration, Instant};
use telextiles_proto::roller::*;

struct Child(std::process::Child);
impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn read_reply(port: &mut dyn serialport::SerialPort, dec: &mut FrameDecoder, want: u8) -> Reply {
    let t0 = Instant::now();
    let mut buf = [0u8; 64];
    loop {
        assert!(
            t0.elapsed() < Duration::from_secs(5),
            "no reply kind {want:#x}"
        );
        let n = match port.read(&mut buf) {
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            Err(e) => panic!("{e}"),
        };
        for f in dec.feed(&buf[..n]).flatten() {
            if f.kind == want {
                return Reply::from_frame(&f).unwrap();
            }
        }
    }
}

#[test]
fn roller_sim_binary_serves_a_pty() {
    let dir = tempfile::tempdir().unwrap();
    let link = dir.path().join("roller0");
    let mut child = Child(
        Process::new(env!("CARGO_BIN_EXE_roller-sim"))
            .args(["--slots", "8", "--speed", "10", "--link"])
            .arg(&link)
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut line = String::new();
    BufReader::new(child.0.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let slave = line.trim();
    assert!(slave.starts_with("/dev/pts/"), "{slave:?}");
    assert_eq!(std::fs::read_link(&link).unwrap().to_str(), Some(slave));

    let mut port = serialport::new(link.to_str().unwrap(), 115_200)
        .timeout(Duration::from_millis(50))
        .open()
        .unwrap();
    let mut dec = FrameDecoder::new();
    port.write_all(
        Command::Hello {
            protocol: PROTOCOL_VERSION,
        }
        .encode(1)
        .as_bytes(),
    )
    .unwrap();
    let Reply::Version(v) = read_reply(&mut *port, &mut dec, kind::VERSION) else {
        unreachable!()
    };
    assert_eq!((v.slots, v.steps_per_rev), (8, 3200));
    port.write_all(Command::GotoSlot { slot: 7 }.encode(2).as_bytes())
        .unwrap();
    let Reply::Arrived(s) = read_reply(&mut *port, &mut dec, kind::ARRIVED) else {
        unreachable!()
    };
    assert_eq!(s.position, 2800); // slot 7 of 8 = 315 degrees, counter-clockwise
}
