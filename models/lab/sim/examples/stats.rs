//! Validation statistics per press, with where the spectral peak is
//! (development aid; `telextilesd sim stats` prints the summary row):
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
        let meta = sim.press_meta(s).expect("meta");
        let p = meta.params.as_ref().expect("params");
        let mid = ((p.hold_frame + p.release_frame.unwrap_or(s.frames as u32)) / 2) as usize;
        let reference: Vec<f32> = sim
            .background_for(s)
            .expect("background")
            .as_raw()
            .iter()
            .map(|v| *v as f32)
            .collect();
        let sig = stats::centre_difference(&sim.render_frame(s, mid).expect("frame"), &reference);
        let (_, at) = stats::peak_to_median_at(&sig);
        println!(
            "{} {:?} unit {}: std {:.2} peak/med {:.0} at {:?} cycles/crop, lag1 {:.2} colour {:.2}, {} fps, {:?} ({:.0} ms)",
            r.textile,
            r.family,
            s.sensor,
            r.contact_std,
            r.peak_to_median,
            at,
            r.noise_lag1,
            r.noise_colour,
            meta.fps,
            p.features,
            t.elapsed().as_secs_f64() * 1e3
        );
        rows.push(r);
    }
    let s = stats::summarise(&rows, stats::unit_background_difference(&sim, v, 16));
    println!("{s:?}");
}
