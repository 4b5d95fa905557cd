//! Latency benchmark of the live session: two `telextilesd run` daemons on
//! this machine, both pressing simulated textiles at 60 fps (latents flow
//! both ways at once), over loopback and through the userspace delay relay
//! (this kernel has no netem). Per-frame stage times come from the daemons'
//! latency traces on the shared CLOCK_MONOTONIC, joined on sequence numbers.
//!
//! Each daemon replays a set of `--replay N` different presses
//! (`--sensor replay:<dir>`; catalogue 1, held-out people, six sensor
//! units, every third press hand-held), so that contact -> first decision
//! is measured over many presses, not over one press pressed again and
//! again. `--replay 0`: each daemon's simulated DIGIT presses one textile
//! (A T012, B T047) again and again, as the runs before 2026-11-29 did.
//!
//! ```sh
//! cargo bench -p telextilesd --bench session_latency -- \
//!     [--seconds 30] [--replay 24] [--scenarios loopback,5:1,20:5,50:20] [--svg docs/session-latency.svg]
//! ```
//! Prints the markdown of docs/benchmarks.md's "Live session" section.
#[path = "../tests/harness/mod.rs"]
mod harness;

use harness::*;
use plotters::prelude::*;
use std::time::Duration;

struct Scenario {
    name: String,
    relay: Option<(u64, u64)>,
}

struct Result1 {
    name: String,
    ab: Stages,
    ba: Stages,
    cpu: [(f64, u64); 2],
    /// Sensor frames per second processed by A and B.
    fps: [f64; 2],
    finals_lost: usize,
}

fn parse_scenarios(s: &str) -> Vec<Scenario> {
    s.split(',')
        .map(|x| {
            if x == "loopback" {
                Scenario {
                    name: "loopback".into(),
                    relay: None,
                }
            } else {
                let (d, j) = x.split_once(':').unwrap_or((x, "0"));
                let (d, j): (u64, u64) =
                    (d.parse().expect("delay ms"), j.parse().expect("jitter ms"));
                Scenario {
                    name: format!("relay {d} ± {j} ms"),
                    relay: Some((d, j)),
                }
            }
        })
        .collect()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let opt = |k: &str| {
        args.iter()
            .position(|a| a == k)
            .and_then(|i| args.get(i + 1).cloned())
    };
    let seconds: u64 = opt("--seconds").map_or(30, |s| s.parse().expect("--seconds"));
    let scenarios =
        parse_scenarios(&opt("--scenarios").unwrap_or("loopback,5:1,20:5,50:20".into()));
    // Relative paths are taken from the workspace root (cargo runs benches
    // in the package directory).
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let svg = opt("--svg").map(|p| root.join(p).display().to_string());
    let replay: usize = opt("--replay").map_or(24, |s| s.parse().expect("--replay N"));
    let sets = tempfile::tempdir().expect("a temporary directory");
    let sensors = if replay == 0 {
        Setup::default().sensors
    } else {
        let a = sets.path().join("a");
        let b = sets.path().join("b");
        render_set(&a, replay, 0);
        render_set(&b, replay, 1);
        (
            format!("replay:{}", a.display()),
            format!("replay:{}", b.display()),
        )
    };
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    let mut results = Vec::new();
    for sc in &scenarios {
        eprintln!("{}: {seconds} s measured after 5 s warm-up", sc.name);
        let mut fps = [0.0; 2];
        let (pair, t0, t1) = rt.block_on(async {
            let pair = Pair::start(&Setup {
                relay: sc.relay,
                sensors: sensors.clone(),
                ..Default::default()
            })
            .await;
            tokio::time::sleep(Duration::from_secs(5)).await;
            let f0 = [
                counter(&pair.a, "frames").await,
                counter(&pair.b, "frames").await,
            ];
            let t0 = mono_us();
            tokio::time::sleep(Duration::from_secs(seconds)).await;
            let t1 = mono_us();
            let f1 = [
                counter(&pair.a, "frames").await,
                counter(&pair.b, "frames").await,
            ];
            let secs = (t1 - t0) as f64 / 1e6;
            fps = [(f1[0] - f0[0]) as f64 / secs, (f1[1] - f0[1]) as f64 / secs];
            (pair, t0, t1)
        });
        let (ta, tb, a, b) = pair.stop();
        let ab = stages(&ta, &tb, t0, t1);
        let ba = stages(&tb, &ta, t0, t1);
        let lost = lost_finals(&ta, &b, t0, t1).0.len() + lost_finals(&tb, &a, t0, t1).0.len();
        results.push(Result1 {
            name: sc.name.clone(),
            ab,
            ba,
            cpu: [usage(&a, t0, t1), usage(&b, t0, t1)],
            fps,
            finals_lost: lost,
        });
    }
    let ms = |v: f64| format!("{:.3}", v / 1000.0);
    if replay == 0 {
        println!("Sources: A's simulated DIGIT presses T012 and B's T047, again and again ({seconds} s per scenario).");
    } else {
        println!(
            "Sources: each daemon replays {replay} recorded presses, one after another and round again \
             (catalogue 1, held-out people 8-10, units 0-5, every third hand-held; A's and B's textiles differ; {seconds} s per scenario)."
        );
    }
    for r in &results {
        println!("\n#### {}\n", r.name);
        println!("| stage (both directions) | frames | p50 ms | p95 ms | p99 ms |\n|---|---:|---:|---:|---:|");
        for (i, name) in STAGES.iter().enumerate() {
            let v: Vec<f64> = r.ab.values[i]
                .iter()
                .chain(&r.ba.values[i])
                .copied()
                .collect();
            println!(
                "| {name} | {} | {} | {} | {} |",
                v.len(),
                ms(pct(&v, 50.0)),
                ms(pct(&v, 95.0)),
                ms(pct(&v, 99.0))
            );
        }
        let rows: [(&str, Vec<f64>); 4] = [
            (
                "**capture on one side → decision on the other**",
                cat(&r.ab.total_decided, &r.ba.total_decided),
            ),
            (
                "**software-added (all but the wire stage)**",
                cat(&r.ab.software, &r.ba.software),
            ),
            (
                "capture → roller command written (decision changes)",
                cat(&r.ab.total_serial, &r.ba.total_serial),
            ),
            (
                "press start (its first frame sent) → its first decision on the other side",
                cat(&r.ab.contact_to_decision, &r.ba.contact_to_decision),
            ),
        ];
        for (name, v) in rows {
            println!(
                "| {name} | {} | {} | {} | {} |",
                v.len(),
                ms(pct(&v, 50.0)),
                ms(pct(&v, 95.0)),
                ms(pct(&v, 99.0))
            );
        }
        println!(
            "\nLatents accepted (latest wins: a datagram overtaken by a newer one is dropped): A→B {} of {}, B→A {} of {}; \
             decision changes that needed no roller command (wheel already there): {}; presses without a final decision: {}.",
            r.ab.received, r.ab.sent, r.ba.received, r.ba.sent, r.ab.no_command + r.ba.no_command, r.finals_lost
        );
        println!(
            "Daemon A: {:.1} sensor frames/s, {:.1} % of one core, peak RSS {:.1} MB; daemon B: {:.1} frames/s, {:.1} % of one core, peak RSS {:.1} MB.",
            r.fps[0],
            100.0 * r.cpu[0].0,
            r.cpu[0].1 as f64 / 1e6,
            r.fps[1],
            100.0 * r.cpu[1].0,
            r.cpu[1].1 as f64 / 1e6
        );
    }
    if let Some(path) = svg {
        histogram(&results, &path).expect("write the SVG");
        eprintln!("wrote {path}");
    }
}

/// Renders `n` presses into `dir`, one recording each: catalogue-1 textiles
/// spread over the 119 (`side` shifts them, so the daemons press different
/// ones), held-out people 8-10, sensor units 0-5, every third press
/// hand-held, each with its no-contact frames and its release.
fn render_set(dir: &std::path::Path, n: usize, side: usize) {
    let sim = telextiles_sim::Simulator::new().expect("the simulator");
    for k in 0..n {
        let textile = format!("T{:03}", (k * 119 / n + side * 7) % 119 + 1);
        let spec = telextiles_sim::PressSpec {
            person: 8 + ((k + side) % 3) as u32,
            sensor: (k % 6) as u32,
            jig: k % 3 != 2,
            release: Some(true),
            catalogue: Some(1),
            ..telextiles_sim::PressSpec::new(textile.clone(), (1000 * side + k) as u64)
        };
        let press = sim.render_press(&spec).expect("render a press");
        telextiles_sim::recording::write_press(&dir.join(format!("{k:03}-{textile}")), &press)
            .expect("write a press");
        eprintln!(
            "rendered press {} of {n} for daemon {}",
            k + 1,
            ["A", "B"][side]
        );
    }
}

fn cat(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().chain(b).copied().collect()
}

/// Frequency polygons of capture → decision latency per scenario, log-x.
fn histogram(results: &[Result1], path: &str) -> Result<(), Box<dyn std::error::Error>> {
    let root = SVGBackend::new(path, (900, 480)).into_drawing_area();
    root.fill(&WHITE)?;
    let (lo, hi) = (0.1f64, 200.0f64);
    let bins = 60;
    let edge = |i: usize| lo * (hi / lo).powf(i as f64 / bins as f64);
    let series: Vec<(String, Vec<(f64, f64)>)> = results
        .iter()
        .map(|r| {
            let v = cat(&r.ab.total_decided, &r.ba.total_decided);
            let mut c = vec![0usize; bins];
            for x in &v {
                let ms = x / 1000.0;
                if ms >= lo && ms < hi {
                    let i = ((ms / lo).ln() / (hi / lo).ln() * bins as f64) as usize;
                    c[i.min(bins - 1)] += 1;
                }
            }
            let n = v.len().max(1) as f64;
            let pts = (0..bins)
                .map(|i| ((edge(i) * edge(i + 1)).sqrt(), 100.0 * c[i] as f64 / n))
                .collect();
            (r.name.clone(), pts)
        })
        .collect();
    let ymax = series
        .iter()
        .flat_map(|s| s.1.iter().map(|p| p.1))
        .fold(1.0, f64::max)
        * 1.1;
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Capture on one daemon -> decision on the other (60 fps, both directions at once)",
            ("sans-serif", 18),
        )
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d((lo..hi).log_scale(), 0.0..ymax)?;
    chart
        .configure_mesh()
        .x_desc("latency, ms (log scale)")
        .y_desc("% of frames per bin")
        .draw()?;
    for (i, (name, pts)) in series.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))?
            .label(name.clone())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()?;
    root.present()?;
    Ok(())
}
