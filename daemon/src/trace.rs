//! Per-frame latency trace (`--latency-trace FILE`, a diagnostic for the
//! latency benchmark `daemon/benches/session_latency.rs`).
//!
//! One text line per record; every time is in microseconds of the
//! machine's `CLOCK_MONOTONIC`, which all processes on a machine share, so
//! the traces of two daemons on one machine join exactly on the sender's
//! sequence number. Lines are formatted on the hot path and written by a
//! thread of their own (no file I/O on the sensing thread).
//!
//! ```text
//! # telextilesd latency trace v1
//! tx SEQ PRESS CAPTURE CONTACT ENCODED QUANTISED SENT
//! rx SEQ PRESS RECEIVED HANDLED DECIDED CHANGED SLOT
//! serial SLOT WRITTEN
//! ```
//!
//! `tx`: a frame of this device's sensor: read from the source (CAPTURE),
//! contact detection done, encoder done, quantised and framed, handed to
//! QUIC. `rx`: a latent from the peer: datagram read, taken by the
//! receiver task, decision made and acted on; CHANGED is 1 when the decided
//! textile changed (the roller was given SLOT; else SLOT is -). `serial`: a
//! roller target command written to the serial port.
use std::io::Write;
use std::path::Path;
use std::sync::mpsc;

use anyhow::{Context, Result};

/// CLOCK_MONOTONIC in microseconds.
pub fn mono_us() -> u64 {
    let t = rustix::time::clock_gettime(rustix::time::ClockId::Monotonic);
    t.tv_sec as u64 * 1_000_000 + t.tv_nsec as u64 / 1000
}

/// A running trace. Dropping it lets the writer thread finish the file.
pub struct Trace {
    tx: mpsc::Sender<String>,
    /// `mono_us() - telextiles_link::now_us()`.
    offset: i64,
}

impl Trace {
    /// Creates (truncates) `path` and starts the writer thread.
    pub fn create(path: &Path) -> Result<Trace> {
        let file = std::fs::File::create(path)
            .with_context(|| format!("cannot create the latency trace {}", path.display()))?;
        let (tx, rx) = mpsc::channel::<String>();
        std::thread::Builder::new()
            .name("latency-trace".into())
            .spawn(move || {
                let mut w = std::io::BufWriter::with_capacity(1 << 16, file);
                let _ = writeln!(w, "# telextilesd latency trace v1");
                while let Ok(line) = rx.recv() {
                    let _ = w.write_all(line.as_bytes());
                    // Write out whenever the queue runs dry: a killed
                    // daemon loses at most the lines of its last moment.
                    while let Ok(line) = rx.try_recv() {
                        let _ = w.write_all(line.as_bytes());
                    }
                    let _ = w.flush();
                }
                let _ = w.flush();
            })?;
        let a = mono_us() as i64;
        let b = telextiles_link::now_us() as i64;
        let c = mono_us() as i64;
        Ok(Trace {
            tx,
            offset: (a + c) / 2 - b,
        })
    }

    /// A [`telextiles_link::now_us`] time on the shared clock.
    pub fn at(&self, now_us: u64) -> u64 {
        (now_us as i64 + self.offset).max(0) as u64
    }

    /// A frame of this device's sensor (times from `now_us`).
    pub fn tx(&self, seq: u64, press: u32, t: [u64; 5]) {
        let [a, b, c, d, e] = t.map(|x| self.at(x));
        let _ = self
            .tx
            .send(format!("tx {seq} {press} {a} {b} {c} {d} {e}\n"));
    }

    /// A latent from the peer (times from `now_us`); `commanded` is the
    /// roller slot when the decision changed.
    pub fn rx(&self, seq: u64, press: u32, t: [u64; 3], commanded: Option<usize>) {
        let [a, b, c] = t.map(|x| self.at(x));
        let (changed, slot) = commanded.map_or((0, "-".to_string()), |s| (1, s.to_string()));
        let _ = self
            .tx
            .send(format!("rx {seq} {press} {a} {b} {c} {changed} {slot}\n"));
    }

    /// A roller target written to the serial port at `at`.
    pub fn serial(&self, slot: Option<u16>, at: std::time::Instant) {
        let ago = at.elapsed().as_micros() as u64;
        let t = mono_us().saturating_sub(ago);
        let slot = slot.map_or("-".to_string(), |s| s.to_string());
        let _ = self.tx.send(format!("serial {slot} {t}\n"));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_are_written_on_the_shared_clock() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("t.txt");
        let before = mono_us();
        let t = Trace::create(&path).unwrap();
        let now = telextiles_link::now_us();
        t.tx(7, 2, [now, now + 1, now + 2, now + 3, now + 4]);
        t.rx(9, 3, [now, now + 10, now + 20], Some(5));
        t.serial(Some(5), std::time::Instant::now());
        drop(t);
        let after = mono_us();
        // The writer thread finishes once the sender is gone.
        let mut text = String::new();
        for _ in 0..200 {
            text = std::fs::read_to_string(&path).unwrap();
            if text.lines().count() == 4 {
                break;
            }
            std::thread::sleep(std::time::Duration::from_millis(10));
        }
        let lines: Vec<&str> = text.lines().collect();
        assert_eq!(lines.len(), 4, "{text}");
        let tx: Vec<u64> = lines[1]
            .split(' ')
            .skip(1)
            .map(|x| x.parse().unwrap())
            .collect();
        assert_eq!(&tx[..2], &[7, 2]);
        assert!(
            tx[2] >= before && tx[2] <= after,
            "{tx:?} not in {before}..{after}"
        );
        assert_eq!(tx[6] - tx[2], 4);
        assert!(lines[2].starts_with("rx 9 3 ") && lines[2].ends_with(" 1 5"));
        let s: Vec<&str> = lines[3].split(' ').collect();
        assert_eq!(s[1], "5");
        let w: u64 = s[2].parse().unwrap();
        assert!(w >= before && w <= after);
    }
}
