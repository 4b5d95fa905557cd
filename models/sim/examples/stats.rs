//! Validation statistics per press (development aid):
//! `cargo run --profile dev -p telextiles-sim --example stats -- <catalogue> [generator] [per_family]`
use telextiles_sim::{stats, Simulator};

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let v: u32 = a.get(1).and_then(|s| s.parse().ok()).unwrap_or(2);
    let g: u32 = a.get(2).and_then(|s| s.parse().ok()).unwrap_or(1);
    let k: usize = a.get(3).and_then(|s| s.parse().ok()).unwrap_or(2);
    let sim = Simulator::new().expect("simulator");
    let specs = stats::sample_specs(&sim, v, g, k, 16);
    let mut rows = Vec::new();
    for s in &specs {
        let t = std::time::Instant::now();
        let r = stats::press_stats(&sim, s).expect("press");
        let meta = sim.press_meta(s).unwrap();
        let q = telextiles_sim::PressSpec {
            noise: false,
            ..s.clone()
        };
        let mid = {
            let p = meta.params.as_ref().unwrap();
            ((p.hold_frame + p.release_frame.unwrap_or(s.frames as u32)) / 2) as usize
        };
        let f = sim.render_frame(&q, mid).unwrap();
        let bg = sim.background_of(v, s.sensor);
        let abs: Vec<f32> = f
            .pixels()
            .zip(bg.pixels())
            .map(|(a, b)| (0..3).map(|c| (a.0[c] as f32 - b.0[c] as f32).abs()).sum())
            .collect();
        let (x0, y0) = ((240 - 128) / 2, (320 - 128) / 2);
        let crop: Vec<f32> = (0..128 * 128)
            .map(|k| abs[(y0 + k / 128) * 240 + x0 + k % 128])
            .collect();
        let signed: Vec<f32> = {
            let r: Vec<f32> = bg.as_raw().iter().map(|v| *v as f32).collect();
            stats::centre_difference(&f, &r)
        };
        let sig = stats::centre_difference(
            &sim.render_frame(s, mid).unwrap(),
            &sim.background_of(v, s.sensor)
                .as_raw()
                .iter()
                .map(|v| *v as f32)
                .collect::<Vec<_>>(),
        );
        println!(
            "   {} peak at {:?}",
            s.textile,
            stats::peak_to_median_at(&sig)
        );
        println!(
            "   quiet: abs-sum peak/med {:.0}, signed {:.0}",
            stats::peak_to_median(&crop),
            stats::peak_to_median(&signed)
        );
        println!(
            "{} {:?} std {:.2} peak/med {:.0} lag1 {:.2} col {:.2} fps {} feats {:?} ({:.0} ms)",
            r.textile,
            r.family,
            r.contact_std,
            r.peak_to_median,
            r.noise_lag1,
            r.noise_colour,
            meta.fps,
            meta.params.as_ref().unwrap().features,
            t.elapsed().as_secs_f64() * 1e3
        );
        rows.push(r);
    }
    let s = stats::summarise(&rows, stats::unit_background_difference(&sim, v, 16));
    println!("{s:?}");
}
