//! Drives `link_node` processes (the test-support endpoint of
//! `src/bin/link_node.rs`) from the namespace tests: spawn one in a
//! namespace, wait for its event lines, stream presses between two.
#![allow(clippy::unwrap_used)]
use std::collections::VecDeque;
use std::io::{BufRead, BufReader, Write};
use std::path::Path;
use std::process::{Child, ChildStdin, Stdio};
use std::sync::{mpsc, Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use telextiles_certs::{Identity, PeerRecord, TrustStore};

use crate::netns::Netns;

/// Arguments as owned strings.
pub fn s(v: &[&str]) -> Vec<String> {
    v.iter().map(|x| x.to_string()).collect()
}

/// A running `link_node`; killed on drop.
pub struct Node {
    pub name: String,
    pub child: Child,
    stdin: ChildStdin,
    pub rx: mpsc::Receiver<String>,
    pub log: VecDeque<String>,
    /// Every `path` line with the time it arrived, whoever reads the rest.
    pub paths: Arc<Mutex<Vec<(Instant, String)>>>,
}

impl Node {
    /// Runs `exe` (the `link_node` binary) in `ns` with `node ARGS`.
    pub fn spawn_in(ns: &Netns, exe: &str, name: &str, args: &[String]) -> Node {
        let mut cmd = ns.command(exe);
        cmd.arg("node").args(args);
        Node::spawn_cmd(cmd, name)
    }

    pub fn spawn_cmd(mut cmd: std::process::Command, name: &str) -> Node {
        let mut child = cmd
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("spawn link_node");
        let stdout = child.stdout.take().unwrap();
        let stdin = child.stdin.take().unwrap();
        let (tx, rx) = mpsc::channel();
        let paths = Arc::new(Mutex::new(Vec::new()));
        let seen = paths.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { break };
                if line.starts_with("path ") {
                    seen.lock().unwrap().push((Instant::now(), line.clone()));
                }
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        Node {
            name: name.into(),
            child,
            stdin,
            rx,
            log: VecDeque::new(),
            paths,
        }
    }

    /// Next line starting with `prefix` (other lines are kept in the log).
    pub fn expect(&mut self, prefix: &str, timeout: Duration) -> String {
        self.try_expect(prefix, timeout).unwrap_or_else(|| {
            panic!(
                "{}: no `{prefix}` line within {timeout:?}; last lines:\n{}",
                self.name,
                self.log.iter().cloned().collect::<Vec<_>>().join("\n")
            )
        })
    }

    pub fn try_expect(&mut self, prefix: &str, timeout: Duration) -> Option<String> {
        let deadline = Instant::now() + timeout;
        loop {
            let left = deadline.checked_duration_since(Instant::now())?;
            let line = self.rx.recv_timeout(left).ok()?;
            if line.starts_with("fatal") {
                panic!("{}: {line}", self.name);
            }
            let hit = line.starts_with(prefix);
            if !line.starts_with("latent") {
                self.log.push_back(line.clone());
                if self.log.len() > 60 {
                    self.log.pop_front();
                }
            }
            if hit {
                return Some(line);
            }
        }
    }

    /// Every line that arrives within `d`.
    pub fn drain(&mut self, d: Duration) -> Vec<String> {
        let deadline = Instant::now() + d;
        let mut v = Vec::new();
        while let Some(left) = deadline.checked_duration_since(Instant::now()) {
            match self.rx.recv_timeout(left) {
                Ok(l) => v.push(l),
                Err(_) => break,
            }
        }
        v
    }

    /// When the first `path` line of `kind` (`direct`, `relay`) arrived,
    /// waiting at most until `deadline`.
    pub fn path_at(&self, kind: &str, deadline: Instant) -> Option<Instant> {
        loop {
            let hit = self
                .paths
                .lock()
                .unwrap()
                .iter()
                .find(|(_, l)| l.split_whitespace().nth(2) == Some(kind))
                .map(|(t, _)| *t);
            if hit.is_some() || Instant::now() >= deadline {
                return hit;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// Every `path` line so far.
    pub fn path_lines(&self) -> Vec<String> {
        self.paths
            .lock()
            .unwrap()
            .iter()
            .map(|(_, l)| l.clone())
            .collect()
    }

    pub fn send(&mut self, line: &str) {
        writeln!(self.stdin, "{line}").expect("write to node");
        self.stdin.flush().unwrap();
    }
}

impl Drop for Node {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Two data dirs with identities that already trust each other.
pub fn paired_dirs() -> (tempfile::TempDir, tempfile::TempDir) {
    let (da, db) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    let (ia, ib) = (Identity::generate().unwrap(), Identity::generate().unwrap());
    ia.save(da.path()).unwrap();
    ib.save(db.path()).unwrap();
    trust(da.path(), &ib, "bob");
    trust(db.path(), &ia, "alice");
    (da, db)
}

pub fn trust(dir: &Path, peer: &Identity, name: &str) {
    let mut st = TrustStore::load(dir).unwrap();
    st.insert(PeerRecord::new(peer.peer_key(), name, SystemTime::now()));
    st.save().unwrap();
}

/// `KEY@addr` of the device whose identity is in `d`: what `--connect`
/// takes.
pub fn key_at(d: &tempfile::TempDir, addr: &str) -> String {
    format!("{}@{addr}", Identity::load(d.path()).unwrap().peer_key())
}

pub fn dir_arg(d: &tempfile::TempDir) -> String {
    d.path().display().to_string()
}

/// Streams `presses` presses of known classes from `from` to `to`; every
/// final decision must name the pressed class. Returns (decisions right,
/// latents received, one-way latencies in µs).
pub fn presses(from: &mut Node, to: &mut Node, presses: u32, frames: u32) -> (u32, u64, Vec<i64>) {
    presses_numbered(from, to, 1..=presses, frames)
}

/// [`presses`] with the press IDs `ids` (a later batch takes new IDs).
pub fn presses_numbered(
    from: &mut Node,
    to: &mut Node,
    ids: std::ops::RangeInclusive<u32>,
    frames: u32,
) -> (u32, u64, Vec<i64>) {
    let mut right = 0;
    let mut latents = 0u64;
    let mut lat = Vec::new();
    for p in ids {
        let class = (p * 7) % 16;
        from.send(&format!("press {p} {class} {frames}"));
        let deadline = Instant::now() + Duration::from_secs(10);
        let decision = loop {
            let left = deadline
                .checked_duration_since(Instant::now())
                .unwrap_or_else(|| panic!("{}: no decision for press {p}", to.name));
            let line = to.rx.recv_timeout(left).unwrap_or_else(|_| {
                panic!("{}: no decision for press {p}; log {:?}", to.name, to.log)
            });
            let f: Vec<&str> = line.split_whitespace().collect();
            match f.as_slice() {
                ["latent", _, _, l] => {
                    latents += 1;
                    if let Ok(v) = l.parse() {
                        lat.push(v);
                    }
                }
                ["decision", id, c, _] if *id == p.to_string() => break c.to_string(),
                _ => {}
            }
        };
        assert_eq!(
            decision,
            class.to_string(),
            "press {p}: wrong final decision"
        );
        right += 1;
        from.expect(&format!("sent {p}"), Duration::from_secs(5));
    }
    // Datagrams and the stream are not ordered with each other: a press's
    // last latents may land just after its final decision. Count those of
    // the last press too (an earlier press's are counted by the next).
    let end = Instant::now() + Duration::from_millis(300);
    while let Some(left) = end.checked_duration_since(Instant::now()) {
        let Ok(line) = to.rx.recv_timeout(left) else {
            break;
        };
        let f: Vec<&str> = line.split_whitespace().collect();
        if let ["latent", _, _, l] = f.as_slice() {
            latents += 1;
            if let Ok(v) = l.parse() {
                lat.push(v);
            }
        } else {
            to.log.push_back(line);
        }
    }
    (right, latents, lat)
}

pub fn median(v: &mut [i64]) -> i64 {
    v.sort();
    v.get(v.len() / 2).copied().unwrap_or(-1)
}
