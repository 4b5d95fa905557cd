//! Rendering speed, single-threaded: frames per second per core.
//!
//! `cargo bench -p telextiles-sim --bench render` (release profile), or with
//! an argument `quick` for a short run. Prints medians over repeated presses.
use std::time::Instant;
use telextiles_sim::{PressSpec, Simulator};

/// CPU time of this thread in seconds (Linux `/proc/thread-self/schedstat`),
/// so the figures are per core even when other jobs share the machine; falls
/// back to wall time elsewhere.
struct Clock {
    wall: Instant,
    cpu: Option<f64>,
}

fn thread_cpu() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/thread-self/schedstat").ok()?;
    let ns: f64 = s.split_whitespace().next()?.parse().ok()?;
    Some(ns / 1e9)
}

impl Clock {
    fn start() -> Clock {
        Clock {
            wall: Instant::now(),
            cpu: thread_cpu(),
        }
    }
    /// (cpu seconds, wall seconds)
    fn elapsed(&self) -> (f64, f64) {
        let wall = self.wall.elapsed().as_secs_f64();
        let cpu = match (self.cpu, thread_cpu()) {
            (Some(a), Some(b)) => b - a,
            _ => wall,
        };
        (cpu, wall)
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let quick = std::env::args().any(|a| a == "quick");
    let reps = if quick { 3 } else { 9 };
    let t0 = Instant::now();
    let sim = Simulator::new().expect("simulator");
    let startup = t0.elapsed().as_secs_f64();
    let cat = sim.catalogue();
    // textiles of different families, each press on a cold fabric-patch cache
    let ids: Vec<String> = cat.training().step_by(10).map(|t| t.id.clone()).collect();
    let mut patch_ms = Vec::new();
    let mut setup_ms = Vec::new();
    let mut frame_us = Vec::new();
    let mut press_fps = Vec::new();
    let mut warm_press_fps = Vec::new();
    let mut wall_fps = Vec::new();
    for r in 0..reps {
        for (k, id) in ids.iter().enumerate() {
            let t = cat.get(id).expect("textile");
            let spec = PressSpec {
                jig: k % 2 == 0,
                person: (k % 11) as u32,
                ..PressSpec::new(id.as_str(), r as u64 * 100 + k as u64)
            };
            let a = Clock::start();
            let _ = telextiles_sim::fabric::generate(t);
            patch_ms.push(a.elapsed().0 * 1e3);
            // whole press (patch cached from the previous rep except rep 0)
            let a = Clock::start();
            let p = sim.render_press(&spec).expect("press");
            let (dt, wall) = a.elapsed();
            wall_fps.push(p.frames.len() as f64 / wall);
            if r > 0 {
                warm_press_fps.push(p.frames.len() as f64 / dt);
            } else {
                press_fps.push(p.frames.len() as f64 / dt);
            }
            // solve only (new seed), then per-frame cost on the solved press
            let spec2 = PressSpec {
                seed: spec.seed + 7,
                ..spec.clone()
            };
            let a = Clock::start();
            let _ = sim.render_frame(&spec2, 0).expect("frame");
            setup_ms.push(a.elapsed().0 * 1e3);
            let a = Clock::start();
            for i in 1..150 {
                std::hint::black_box(sim.render_frame(&spec2, i).expect("frame"));
            }
            frame_us.push(a.elapsed().0 * 1e6 / 149.0);
        }
    }
    println!("telextiles-sim render benchmark (1 thread, 240x320 RGB, 150-frame presses; thread CPU time)");
    println!(
        "  simulator start-up (calibration + background + catalogue): {:.1} ms",
        startup * 1e3
    );
    println!(
        "  fabric patch generation (512x512, once per textile): median {:.1} ms",
        median(patch_ms)
    );
    println!(
        "  press solve (contact at 6 depths + optics): median {:.1} ms",
        median(setup_ms.clone())
    );
    let f = median(frame_us.clone());
    println!(
        "  per frame on a solved press: median {:.0} us = {:.0} frames/s/core",
        f,
        1e6 / f
    );
    println!(
        "  whole press, cold patch: median {:.0} frames/s/core",
        median(press_fps)
    );
    println!(
        "  whole press, warm patch: median {:.0} frames/s/core",
        median(warm_press_fps)
    );
    println!(
        "  whole press, wall clock (depends on machine load): median {:.0} frames/s",
        median(wall_fps)
    );
    let s = median(setup_ms);
    println!(
        "  amortised over 150 frames: {:.0} frames/s/core",
        150.0 / (s / 1e3 + 150.0 * f / 1e6)
    );
    for generator in [1, 2] {
        catalogue_2(&sim, &ids, reps, generator);
    }
}

/// The same textile ids in catalogue 2 (each press renders its own bolt
/// raster: there is no patch cache to warm).
fn catalogue_2(sim: &Simulator, ids: &[String], reps: usize, generator: u32) {
    let (mut setup_ms, mut frame_us, mut press_fps) = (Vec::new(), Vec::new(), Vec::new());
    for r in 0..reps {
        for (k, id) in ids.iter().enumerate() {
            let spec = PressSpec {
                jig: k % 2 == 0,
                person: (k % 11) as u32,
                sensor: (k % 16) as u32,
                catalogue: Some(2),
                generator: Some(generator),
                ..PressSpec::new(id.as_str(), r as u64 * 100 + k as u64)
            };
            let a = Clock::start();
            let p = sim.render_press(&spec).expect("press");
            press_fps.push(p.frames.len() as f64 / a.elapsed().0);
            let spec2 = PressSpec {
                seed: spec.seed + 7,
                ..spec.clone()
            };
            let a = Clock::start();
            let _ = sim.render_frame(&spec2, 0).expect("frame");
            setup_ms.push(a.elapsed().0 * 1e3);
            let a = Clock::start();
            for i in 1..150 {
                std::hint::black_box(sim.render_frame(&spec2, i).expect("frame"));
            }
            frame_us.push(a.elapsed().0 * 1e6 / 149.0);
        }
    }
    let f = median(frame_us);
    println!("catalogue 2, generator {generator} (same ids, sensor units 0..11):");
    println!(
        "  press solve (bolt raster + contact at 6 depths + optics + camera): median {:.1} ms",
        median(setup_ms)
    );
    println!(
        "  per frame on a solved press: median {:.0} us = {:.0} frames/s/core",
        f,
        1e6 / f
    );
    println!(
        "  whole press: median {:.0} frames/s/core",
        median(press_fps)
    );
}
