//! Stable-toolchain fuzz harness shared by the fuzz crates' `tests/stable.rs`
//! (included with `#[path]`): runs each target body on its committed seed
//! corpus (`seeds/<target>/`), then on mutated seeds (bit flips, byte and
//! integer overwrites with boundary values, insertions, deletions,
//! duplications, splices, truncations) and random bytes until the time
//! budget is spent. A panic is the failure: the input is written to
//! `$CARGO_TARGET_TMPDIR/fuzz-artifacts/` and printed in hex.
//!
//! Environment: `FUZZ_SECONDS` (per target, default 2), `FUZZ_SEED`
//! (replay a run), `FUZZ_TARGET` (only this target).
#![allow(dead_code)]
use std::path::Path;
use std::time::{Duration, Instant};

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        let mut x = self.0;
        x ^= x >> 12;
        x ^= x << 25;
        x ^= x >> 27;
        self.0 = x;
        x.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            (self.next() % n as u64) as usize
        }
    }
}

const INTERESTING: &[u64] = &[
    0,
    1,
    0x7f,
    0x80,
    0xff,
    0x100,
    0x7fff,
    0x8000,
    0xffff,
    0x1_0000,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    0x7fff_ffff_ffff_ffff,
    0x8000_0000_0000_0000,
    u64::MAX,
];

fn mutate(base: &[u8], other: &[u8], rng: &mut Rng) -> Vec<u8> {
    if rng.below(16) == 0 {
        let n = rng.below(512);
        return (0..n).map(|_| rng.next() as u8).collect();
    }
    let mut b = base.to_vec();
    for _ in 0..1 + rng.below(8) {
        let len = b.len();
        match rng.below(9) {
            0 if len > 0 => {
                let i = rng.below(len);
                b[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = rng.below(len);
                b[i] = INTERESTING[rng.below(INTERESTING.len())] as u8;
            }
            2 if len > 0 => {
                let i = rng.below(len);
                b[i] = rng.next() as u8;
            }
            3 => {
                let width = [2usize, 4, 8][rng.below(3)];
                if len >= width {
                    let i = rng.below(len - width + 1);
                    let v = INTERESTING[rng.below(INTERESTING.len())];
                    b[i..i + width].copy_from_slice(&v.to_le_bytes()[..width]);
                }
            }
            4 => {
                let i = rng.below(len + 1);
                let n = 1 + rng.below(16);
                let ins: Vec<u8> = (0..n).map(|_| rng.next() as u8).collect();
                b.splice(i..i, ins);
            }
            5 if len > 0 => {
                let i = rng.below(len);
                let n = 1 + rng.below((len - i).min(32));
                b.drain(i..i + n);
            }
            6 if len > 0 => {
                let i = rng.below(len);
                let n = 1 + rng.below((len - i).min(64));
                let dup = b[i..i + n].to_vec();
                let at = rng.below(len + 1);
                b.splice(at..at, dup);
            }
            7 if !other.is_empty() => {
                let cut = rng.below(len + 1);
                let from = rng.below(other.len());
                b.truncate(cut);
                b.extend_from_slice(&other[from..]);
            }
            8 if len > 0 => b.truncate(rng.below(len)),
            _ => {}
        }
    }
    b.truncate(1 << 16);
    b
}

fn check(name: &str, body: fn(&[u8]), input: &[u8]) {
    if let Err(e) = std::panic::catch_unwind(|| body(input)) {
        let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("fuzz-artifacts");
        let _ = std::fs::create_dir_all(&dir);
        let file = dir.join(format!("{name}-crash-{:016x}", fnv(input)));
        let _ = std::fs::write(&file, input);
        let hex: String = input.iter().take(256).map(|b| format!("{b:02x}")).collect();
        eprintln!(
            "fuzz target {name} panicked on {} bytes (saved to {}; first 256 in hex): {hex}",
            input.len(),
            file.display()
        );
        std::panic::resume_unwind(e);
    }
}

fn fnv(b: &[u8]) -> u64 {
    b.iter().fold(0xcbf2_9ce4_8422_2325, |h, &x| {
        (h ^ u64::from(x)).wrapping_mul(0x100_0000_01b3)
    })
}

/// Runs every target on its seeds, then on mutations for the time budget.
pub fn run_all(targets: &[(&str, fn(&[u8]))], seeds_dir: &Path) {
    let secs: f64 = std::env::var("FUZZ_SECONDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2.0);
    let only = std::env::var("FUZZ_TARGET").ok();
    let seed: u64 = std::env::var("FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(1, |d| d.as_nanos() as u64)
        });
    for &(name, body) in targets {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        let dir = seeds_dir.join(name);
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap_or_else(|e| panic!("no seed corpus {}: {e}", dir.display()))
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        let seeds: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).unwrap()).collect();
        assert!(!seeds.is_empty(), "empty seed corpus {}", dir.display());
        for s in &seeds {
            check(name, body, s);
        }
        let mut rng = Rng(seed ^ fnv(name.as_bytes()) | 1);
        let start = Instant::now();
        let budget = Duration::from_secs_f64(secs);
        let mut n = 0u64;
        while start.elapsed() < budget {
            for _ in 0..64 {
                let base = &seeds[rng.below(seeds.len())];
                let other = &seeds[rng.below(seeds.len())];
                let input = mutate(base, other, &mut rng);
                check(name, body, &input);
                n += 1;
            }
        }
        println!(
            "fuzz {name}: {} seeds + {n} mutated inputs in {:.1} s (FUZZ_SEED={seed})",
            seeds.len(),
            start.elapsed().as_secs_f64()
        );
    }
}
