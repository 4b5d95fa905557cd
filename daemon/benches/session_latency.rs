//! Latency benchmark of the live session: two `telextilesd run` daemons on
//! this machine, both pressing simulated textiles at 60 fps (latents flow
//! both ways at once), over loopback and through the userspace delay relay
//! (this kernel has no netem), or (`nat-direct`, `nat-relayed`; root) each
//! behind a NAT router in network namespaces, meeting through
//! `telextilesd relay`: endpoint-independent NATs, measured once the path
//! went direct, or symmetric ones, where it stays relayed. Per-frame stage times come from the daemons'
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
//!     [--seconds 30] [--replay 24] [--scenarios loopback,5:1,20:5,50:20,nat-direct,nat-relayed] [--svg docs/session-latency.svg] \
//!     [--flags "--encode-run --commit-margin 0.02 ..."]
//! ```
//!
//! `--flags`: settings given to both daemons and to `classify` (the
//! decision-speed settings of docs/configuration.md), to measure them live.
//! Prints the markdown of docs/benchmarks.md's "Live session" section.
#[path = "../tests/harness/mod.rs"]
mod harness;

use harness::*;
use plotters::prelude::*;
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;
use telextiles_control::Event;
use telextiles_tests::nat::Mapping;

struct Scenario {
    name: String,
    relay: Option<(u64, u64)>,
    nat: Option<Mapping>,
}

struct Result1 {
    name: String,
    ab: Stages,
    ba: Stages,
    cpu: [(f64, u64); 2],
    /// Sensor frames per second processed by A and B.
    fps: [f64; 2],
    finals_lost: usize,
    /// Replayed sets only: each direction's presses, live against `classify`.
    presses: Vec<Compared>,
    /// Felt latency of the presses each side received (µs): contact on the
    /// sender → the receiver's wheel (the simulated roller, in real time)
    /// at rest at the press's final sample.
    felt: Vec<f64>,
}

fn parse_scenarios(s: &str) -> Vec<Scenario> {
    s.split(',')
        .map(|x| {
            if x == "loopback" {
                Scenario {
                    name: "loopback".into(),
                    relay: None,
                    nat: None,
                }
            } else if x == "nat-direct" || x == "nat-relayed" {
                let (name, nat) = if x == "nat-direct" {
                    (
                        "behind two home NATs, direct path",
                        Mapping::EndpointIndependent,
                    )
                } else {
                    (
                        "behind two symmetric NATs, through the relay",
                        Mapping::Symmetric,
                    )
                };
                Scenario {
                    name: name.into(),
                    relay: None,
                    nat: Some(nat),
                }
            } else {
                let (d, j) = x.split_once(':').unwrap_or((x, "0"));
                let (d, j): (u64, u64) =
                    (d.parse().expect("delay ms"), j.parse().expect("jitter ms"));
                Scenario {
                    name: format!("relay {d} ± {j} ms"),
                    relay: Some((d, j)),
                    nat: None,
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
    let flags: Vec<String> = opt("--flags")
        .map(|s| s.split_whitespace().map(str::to_string).collect())
        .unwrap_or_default();
    let sets = tempfile::tempdir().expect("a temporary directory");
    // Each set as `classify` decides it offline (A's set, B's set).
    let mut offline: [Vec<Offline>; 2] = Default::default();
    let sensors = if replay == 0 {
        Setup::default().sensors
    } else {
        let a = sets.path().join("a");
        let b = sets.path().join("b");
        render_set(&a, replay, 0);
        render_set(&b, replay, 1);
        offline = [classify_set(&a, &flags), classify_set(&b, &flags)];
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
                nat: sc.nat,
                sensors: sensors.clone(),
                flags: (flags.clone(), flags.clone()),
            })
            .await;
            if sc.nat == Some(Mapping::EndpointIndependent) {
                let d = pair.wait_path("direct", Duration::from_secs(30)).await;
                let d = d.expect("the NAT pair found no direct path within 30 s");
                eprintln!(
                    "  connected after {:?}, direct after {d:?}",
                    pair.connected_after
                );
            } else if sc.nat.is_some() {
                eprintln!("  connected after {:?}", pair.connected_after);
            }
            tokio::time::sleep(Duration::from_secs(5)).await;
            if sc.nat.is_some() {
                let want = if sc.nat == Some(Mapping::Symmetric) {
                    "relay"
                } else {
                    "direct"
                };
                for side in [&pair.a, &pair.b] {
                    let path = Pair::path(side).await;
                    assert_eq!(path.as_deref(), Some(want), "{}'s path", side.name);
                }
            }
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
        let mut presses = Vec::new();
        if replay > 0 {
            presses.extend(compare(&ta, &b, &offline[0], t0, t1));
            presses.extend(compare(&tb, &a, &offline[1], t0, t1));
        }
        let felt = felt_in(&a, t0, t1)
            .into_iter()
            .chain(felt_in(&b, t0, t1))
            .collect();
        results.push(Result1 {
            felt,
            name: sc.name.clone(),
            ab,
            ba,
            cpu: [usage(&a, t0, t1), usage(&b, t0, t1)],
            fps,
            finals_lost: lost,
            presses,
        });
    }
    let ms = |v: f64| format!("{:.3}", v / 1000.0);
    if !flags.is_empty() {
        println!(
            "Settings of both daemons (and of `classify`): {}",
            flags.join(" ")
        );
    }
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
        let rows: [(&str, Vec<f64>); 5] = [
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
            (
                "**felt: press start → the other side's wheel at rest at the final sample**",
                r.felt.clone(),
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
    if replay > 0 {
        print_decisions(&results);
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

/// One recording of a replayed set as `classify` (the same per-frame
/// pipeline, model, index and settings as the daemons) decides it.
struct Offline {
    /// The fabric pressed (the recording's label).
    label: String,
    /// The true first contact, ms from the recording's first frame
    /// (simulated recordings carry it).
    contact_ms: f64,
    /// The contact detector's start, ms from the first frame.
    start_ms: f64,
    /// The first decision: textile, ms after the start.
    first: Option<(String, f64)>,
    /// The press's final decision, and its margin over the runner-up.
    last: Option<String>,
    margin: Option<f64>,
}

/// `telextilesd classify --json` over the set, one entry per recording in
/// the order the replay takes them (sorted names); panics unless each
/// recording is exactly one press.
fn classify_set(dir: &Path, flags: &[String]) -> Vec<Offline> {
    let out = std::process::Command::new(BIN)
        .args(["classify", "--model", MODEL, "--index", INDEX])
        .arg("--press")
        .arg(dir)
        .arg("--json")
        .args(flags)
        .output()
        .expect("run telextilesd classify");
    assert!(
        out.status.success(),
        "classify failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut rows: Vec<(String, Offline)> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| {
            let v: serde_json::Value = serde_json::from_str(l).expect("classify's JSON");
            let source = v["source"].as_str().expect("source").to_string();
            let meta: serde_json::Value = serde_json::from_str(
                &std::fs::read_to_string(Path::new(&source).join("press.json"))
                    .expect("press.json"),
            )
            .expect("press.json is JSON");
            let contact = meta["params"]["contact_frame"]
                .as_u64()
                .expect("contact_frame");
            let textile = |k: &str| v[k].as_str().map(str::to_string);
            let first = textile("first_textile").zip(v["decision_ms"].as_f64());
            (
                source,
                Offline {
                    label: meta["textile"].as_str().expect("textile").to_string(),
                    contact_ms: meta["timestamps_us"][contact as usize]
                        .as_f64()
                        .expect("timestamps_us")
                        / 1000.0,
                    start_ms: v["start_ms"].as_f64().expect("start_ms"),
                    first,
                    last: textile("textile"),
                    margin: v["margin"].as_f64(),
                },
            )
        })
        .collect();
    rows.sort_by(|a, b| a.0.cmp(&b.0));
    let n = std::fs::read_dir(dir).expect("the set").count();
    assert_eq!(
        rows.len(),
        n,
        "classify: one press per recording of {dir:?}"
    );
    assert!(
        rows.windows(2).all(|w| w[0].0 != w[1].0),
        "classify: two presses in one recording of {dir:?}"
    );
    rows.into_iter().map(|r| r.1).collect()
}

/// The felt latencies (µs) a side reported (`felt` events) in `[t0, t1)`.
fn felt_in(side: &Side, t0: u64, t1: u64) -> Vec<f64> {
    side.events
        .lock()
        .unwrap()
        .iter()
        .filter(|(t, _)| (t0..t1).contains(t))
        .filter_map(|(_, e)| match e {
            Event::Felt { felt_ms, .. } => Some(felt_ms * 1000.0),
            _ => None,
        })
        .collect()
}

/// One press replayed live, beside what `classify` made of its recording.
struct Compared {
    label: String,
    /// The detector's start after the true contact, ms.
    start_after_contact_ms: f64,
    /// The receiver's decisions of the press in order (textile, ms after
    /// the press's start as the receiver reckons it: the press on the
    /// sender's clock plus the link's latency); the last may be the final.
    live: Vec<(String, f64, bool)>,
    offline_first: Option<(String, f64)>,
    offline_last: Option<String>,
    offline_margin: Option<f64>,
}

/// The sender's presses that began in `[t0, t1 - 3 s)`, with the
/// receiver's decisions of each. Press `k` (numbered from 1 by the
/// sender) is recording `(k - 1) mod n` of the set: the replay takes the
/// recordings in order, one press each (`classify_set` checks the
/// latter; the final decisions against `classify`'s check the mapping).
fn compare(from: &Traces, to: &Side, set: &[Offline], t0: u64, t1: u64) -> Vec<Compared> {
    let mut start: BTreeMap<u32, u64> = BTreeMap::new();
    for (press, t) in from.tx.values() {
        start.entry(*press).or_insert(t[0]);
    }
    let mut live: BTreeMap<u32, Vec<(String, f64, bool)>> = BTreeMap::new();
    for (_, e) in to.events.lock().unwrap().iter() {
        if let Event::Decision {
            textile,
            peer: Some(_),
            press: Some(k),
            since_contact_ms: Some(ms),
            final_decision,
            ..
        } = e
        {
            live.entry(*k)
                .or_default()
                .push((textile.clone(), *ms, *final_decision));
        }
    }
    start
        .iter()
        .filter(|(_, &t)| t >= t0 && t + 3_000_000 < t1)
        .map(|(k, _)| {
            let o = &set[(*k as usize - 1) % set.len()];
            Compared {
                label: o.label.clone(),
                start_after_contact_ms: o.start_ms - o.contact_ms,
                // A press the receiver never decided counts, as undecided.
                live: live.remove(k).unwrap_or_default(),
                offline_first: o.first.clone(),
                offline_last: o.last.clone(),
                offline_margin: o.margin,
            }
        })
        .collect()
}

/// Live first decisions against `classify`'s on the same recordings, per
/// scenario, in the terms of the decision-time studies (times from the
/// true first contact).
fn print_decisions(results: &[Result1]) {
    println!(
        "\n#### First decisions, live and offline\n\n\
         Each press replayed live beside `classify` on its recording (the same pipeline, model, index and settings); \
         times from the press's true first contact.\n"
    );
    println!(
        "| scenario | presses | final decision as `classify`'s | first decision: live right | `classify` right | same textile as `classify` | \
         live ms after contact p50 / p90 | `classify` p50 / p90 | live − `classify` p50 / p95 ms | live: right 100 ms after contact |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let pc = |k: usize, n: usize| format!("{:.1} %", 100.0 * k as f64 / n.max(1) as f64);
    for r in results {
        let p = &r.presses;
        let n = p.len();
        let first = |c: &Compared| c.live.iter().find(|d| !d.2).cloned();
        let finals = p
            .iter()
            .filter(|c| {
                let last = c.live.iter().rev().find(|d| d.2).map(|d| &d.0);
                last.is_some() && last == c.offline_last.as_ref()
            })
            .count();
        let live_right = p
            .iter()
            .filter(|c| first(c).is_some_and(|d| d.0 == c.label))
            .count();
        let off_right = p
            .iter()
            .filter(|c| c.offline_first.as_ref().is_some_and(|d| d.0 == c.label))
            .count();
        let same = p
            .iter()
            .filter(|c| {
                first(c)
                    .zip(c.offline_first.as_ref())
                    .is_some_and(|(l, o)| l.0 == o.0)
            })
            .count();
        let live_ms: Vec<f64> = p
            .iter()
            .filter_map(|c| first(c).map(|d| c.start_after_contact_ms + d.1))
            .collect();
        let off_ms: Vec<f64> = p
            .iter()
            .filter_map(|c| {
                c.offline_first
                    .as_ref()
                    .map(|d| c.start_after_contact_ms + d.1)
            })
            .collect();
        let added: Vec<f64> = p
            .iter()
            .filter_map(|c| Some(first(c)?.1 - c.offline_first.as_ref()?.1))
            .collect();
        // The decision in effect 100 ms after contact: the last change
        // made by then (1 µs for the decimal milliseconds).
        let at_100 = p
            .iter()
            .filter(|c| {
                c.live
                    .iter()
                    .rfind(|d| !d.2 && c.start_after_contact_ms + d.1 <= 100.001)
                    .is_some_and(|d| d.0 == c.label)
            })
            .count();
        println!(
            "| {} | {n} | {} | {} | {} | {} | {:.0} / {:.0} | {:.0} / {:.0} | {:.1} / {:.1} | {} |",
            r.name,
            pc(finals, n),
            pc(live_right, n),
            pc(off_right, n),
            pc(same, n),
            pct(&live_ms, 50.0),
            pct(&live_ms, 90.0),
            pct(&off_ms, 50.0),
            pct(&off_ms, 90.0),
            pct(&added, 50.0),
            pct(&added, 95.0),
            pc(at_100, n),
        );
    }
    // Which presses ended otherwise than `classify` ended them, so a
    // difference can be looked into rather than only counted.
    for r in results {
        for c in &r.presses {
            let last = c.live.iter().rev().find(|d| d.2).map(|d| d.0.as_str());
            if last.is_none() || last != c.offline_last.as_deref() {
                println!(
                    "\n{}: a press of {} ended live as {}, by `classify` as {} (its margin over the runner-up {}).",
                    r.name,
                    c.label,
                    last.unwrap_or("no final decision"),
                    c.offline_last.as_deref().unwrap_or("no final decision"),
                    c.offline_margin
                        .map_or("not given".to_string(), |m| format!("{m:.4}")),
                );
            }
        }
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
