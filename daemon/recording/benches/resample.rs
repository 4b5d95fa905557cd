//! Cost of bringing one camera image to the frame's scale
//! ([`FrameMap::map`]) for every built-in profile's modes, on one thread.
//!
//! ```text
//! taskset -c 1 cargo bench -p telextiles-recording --bench resample
//! ```
//! Prints a markdown table (docs/results.md cites it).

use std::time::Instant;

use telextiles_recording::profile::{PROFILES, UVC};
use telextiles_recording::resample::FrameMap;

fn main() {
    let frames: usize = std::env::var("TELEXTILES_BENCH_FRAMES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000);
    println!("| profile | mode | mm/px | path | p50 ms | p90 ms |");
    println!("|---|---|---:|---|---:|---:|");
    let mut cases: Vec<(&str, u32, u32, FrameMap)> = Vec::new();
    for p in PROFILES.iter().filter(|p| p.name != UVC.name) {
        let mut seen = Vec::new();
        for m in p.modes {
            if seen.contains(&(m.width, m.height)) {
                continue;
            }
            seen.push((m.width, m.height));
            let map = FrameMap::for_profile(p, m.width, m.height, None).expect("profile mode");
            cases.push((p.name, m.width, m.height, map));
        }
    }
    // A generic camera at 1280x720, 0.02 mm per pixel (its owner's scale).
    let map = FrameMap::for_profile(&UVC, 1280, 720, Some(0.02)).expect("uvc");
    cases.push(("uvc", 1280, 720, map));
    for (name, w, h, mut map) in cases {
        // A textured image (not flat: nothing is skipped).
        let rgb: Vec<u8> = (0..(w * h * 3) as usize)
            .map(|i| ((i * 2654435761) >> 13) as u8)
            .collect();
        let mut out = image::RgbImage::new(240, 320);
        for _ in 0..20 {
            map.map(&rgb, &mut out).expect("map");
        }
        let mut t: Vec<f64> = (0..frames)
            .map(|_| {
                let t0 = Instant::now();
                map.map(std::hint::black_box(&rgb), &mut out).expect("map");
                t0.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        t.sort_by(f64::total_cmp);
        let q = |p: f64| t[((t.len() - 1) as f64 * p) as usize];
        let v = map.valid();
        let path = if (v.w, v.h) == (240, 320) && (w, h) == (320, 240) {
            "turn".to_string()
        } else {
            format!("resample, field {}x{} of 240x320", v.w, v.h)
        };
        println!(
            "| {name} | {w}x{h} | {:.4} | {path} | {:.3} | {:.3} |",
            map.mm_per_px(),
            q(0.5),
            q(0.9)
        );
    }
}
