//! `telextiles-lab bench`: every method of the speed-vs-accuracy study
//! measured in one run, with every result written where it is read:
//!
//! * the methods table and the accuracy-against-latency chart with the
//!   Pareto frontier and its knee ([`crate::methods`]);
//! * accuracy against time since first contact ([`crate::stability`]);
//! * the stability suite: accuracy and flip rate per factor, and where each
//!   method drops below 90 % ([`crate::stability`]);
//! * the paper's user test against ground truth ([`crate::usertest`]).
//!
//! Outputs in the `--out` directory: `bench.json` (everything), `report.md`
//! (the tables), `speed-accuracy.svg`, `decision-time.svg`,
//! `stability-accuracy.svg`, `stability-flips.svg`, `usertest.svg`.

use anyhow::{ensure, Context, Result};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::time::Instant;

use crate::baselines::{Baseline, BaselineKind};
use crate::data::write_atomic;
use crate::decision_curve::DecisionCurve;
use crate::graph::{descriptor_model, DescriptorSpec};
use crate::methods::{self, background_of, Embedder, Method, MethodResult, Views};
use crate::protocol::{self, Protocol, SourceKind};
use crate::stability::{self, Factor, StabilityReport, SuiteConfig};
use crate::usertest::{self, MethodUserTest};

/// What to run.
#[derive(Clone, Debug)]
pub struct BenchConfig {
    pub source: SourceKind,
    pub protocol: Protocol,
    pub cache_dir: PathBuf,
    /// Render threads.
    pub threads: usize,
    /// ONNX models (name, file): trained encoders and their int8 versions.
    pub models: Vec<(String, PathBuf)>,
    /// Thread counts to time ONNX models with.
    pub time_threads: Vec<usize>,
    /// Timed frames per method and thread count.
    pub runs: usize,
    /// The stability suite (simulator only; `None` skips it).
    pub stability: Option<SuiteConfig>,
    /// Consecutive frames from first contact for the time-to-decision
    /// curve (simulator only; 0 skips it).
    pub decision_frames: usize,
    /// Roller textiles (ids) for the user test; empty skips it.
    pub roller: Vec<String>,
    /// Also score every method on the same protocol rendered by texture
    /// generator 2 (catalogue 2 only): methods are chosen on generator 1
    /// and reported on an independent construction.
    pub cross_generator: bool,
    /// Where the results go.
    pub out: PathBuf,
}

/// The classical descriptors on the chart: the ONNX graphs (what the
/// daemon could ship) and, in Rust, LBP and the background-subtracted
/// variants.
pub fn descriptor_methods() -> Result<Vec<Method>> {
    let mut v = Vec::new();
    for (kind, crop, subtract) in [
        (BaselineKind::Pixels, 64, false),
        (BaselineKind::Pixels, 64, true),
        (BaselineKind::Fft, 32, false),
        (BaselineKind::Fft, 64, false),
        (BaselineKind::Fft, 64, true),
        (BaselineKind::Fft, 96, true),
        (BaselineKind::Fft, 128, false),
        (BaselineKind::Fft, 128, true),
        (BaselineKind::Fft, 160, true),
        (BaselineKind::Fft, 192, false),
        (BaselineKind::Fft, 192, true),
        (BaselineKind::Fft, 224, true),
        (BaselineKind::Fft, 240, true),
    ] {
        let spec = DescriptorSpec {
            kind,
            crop,
            input: crop,
            subtract,
            min_bin: 1,
            taper: 100,
        };
        v.push(Method::onnx(spec.arch(), descriptor_model(&spec)?)?);
    }
    // The colour-whitened spectrum: the whole 240-px width at 120 px (the
    // front end of the shipped model, here without its trained head).
    let wspec = DescriptorSpec {
        kind: BaselineKind::WSpec,
        crop: 240,
        input: 120,
        subtract: true,
        min_bin: 1,
        taper: 100,
    };
    v.push(Method::onnx(wspec.arch(), descriptor_model(&wspec)?)?);
    for bgsub in [false, true] {
        v.push(Method::Rust {
            base: Baseline {
                kind: BaselineKind::Lbp,
                bgsub,
            },
            crop: 64,
        });
    }
    Ok(v)
}

/// Everything the bench measured.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub machine: String,
    pub date: String,
    pub command: String,
    pub source: String,
    pub methods: Vec<MethodResult>,
    /// The same methods on the cross-generator test set (accuracy only;
    /// empty unless asked for).
    #[serde(default)]
    pub cross_generator: Vec<MethodResult>,
    pub pareto: Vec<String>,
    pub knee: Option<String>,
    pub decision: Vec<DecisionCurve>,
    pub stability: Option<StabilityReport>,
    pub roller: Vec<String>,
    pub usertest: Vec<MethodUserTest>,
    /// Wall seconds per part.
    pub seconds: Vec<(String, f64)>,
}

/// "AMD EPYC, 2 cores".
pub fn machine() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|m| m.trim().to_string())
        })
        .unwrap_or_else(|| "unknown CPU".into());
    let n = std::thread::available_parallelism().map_or(1, |n| n.get());
    format!("{cpu}, {n} cores, ONNX Runtime 1.31.1")
}

/// The date and time now, UTC.
pub fn today() -> String {
    std::process::Command::new("date")
        .args(["-u", "+%Y-%m-%d %H:%M UTC"])
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_default()
}

/// Runs the bench and writes its files.
pub fn run(cfg: &BenchConfig, methods: &[Method]) -> Result<BenchReport> {
    ensure!(!methods.is_empty(), "no methods to measure");
    ensure!(
        !cfg.cross_generator
            || (cfg.source == SourceKind::Sim
                && cfg.protocol.catalogue == 2
                && cfg.protocol.generator == 1),
        "the cross-generator set needs --source sim --catalogue 2 (and generator 1 for the main study)"
    );
    let mut seconds = Vec::new();
    let t = Instant::now();
    let sets = protocol::load_base(&cfg.protocol, cfg.source, &cfg.cache_dir, cfg.threads)?;
    seconds.push(("frame caches".to_string(), t.elapsed().as_secs_f64()));
    let threads_max = cfg.time_threads.iter().copied().max().unwrap_or(1);

    // 1. Speed against accuracy.
    let t = Instant::now();
    let mut views = Views::new(&sets);
    let mut results = Vec::new();
    let bar =
        telextiles_progress::Progress::new("speed and accuracy", methods.len() as u64, "methods");
    for m in methods {
        let t0 = Instant::now();
        bar.set_message(&m.name());
        let r = methods::evaluate(m, &mut views, &cfg.time_threads, cfg.runs)
            .with_context(|| format!("method {}", m.name()))?;
        bar.println(&format!(
            "{}: {:.3} ms/frame, top-1 per frame {:.2}%, per press {:.2}% ({:.0} s)",
            r.name,
            r.ms(),
            100.0 * r.frame_top1,
            100.0 * r.press_top1,
            t0.elapsed().as_secs_f64()
        ));
        bar.inc(1);
        results.push(r);
    }
    bar.finish();
    let pareto: Vec<String> = methods::pareto(&results)
        .into_iter()
        .map(|i| results[i].name.clone())
        .collect();
    let knee = methods::knee(&results).map(|i| results[i].name.clone());
    seconds.push(("speed and accuracy".to_string(), t.elapsed().as_secs_f64()));

    // 1b. The cross-generator test set: the same protocol, textures from
    // the independent generator; nothing was chosen on it.
    let mut cross = Vec::new();
    if cfg.cross_generator {
        let t = Instant::now();
        let p2 = cfg.protocol.with_generator(2);
        let sets2 = protocol::load_base(&p2, cfg.source, &cfg.cache_dir, cfg.threads)?;
        let mut views2 = Views::new(&sets2);
        let bar = telextiles_progress::Progress::new(
            "cross-generator set",
            methods.len() as u64,
            "methods",
        );
        for m in methods {
            bar.set_message(&m.name());
            let r = methods::evaluate(m, &mut views2, &[], 0)
                .with_context(|| format!("method {} on the cross-generator set", m.name()))?;
            bar.println(&format!(
                "{} on generator 2: top-1 per press {:.2}%",
                r.name,
                100.0 * r.press_top1
            ));
            bar.inc(1);
            cross.push(r);
        }
        bar.finish();
        seconds.push(("cross-generator set".to_string(), t.elapsed().as_secs_f64()));
    }

    // 2. The user test on the roller textiles.
    let t = Instant::now();
    let mut user = Vec::new();
    if !cfg.roller.is_empty() {
        let roller: Vec<u32> = cfg
            .roller
            .iter()
            .map(|id| {
                sets.train
                    .classes
                    .iter()
                    .position(|c| c == id)
                    .map(|p| p as u32)
                    .with_context(|| format!("roller textile {id} is not in the frame caches"))
            })
            .collect::<Result<_>>()?;
        for m in methods {
            let (crop, input) = m.view();
            let v = views.get(crop, input)?;
            let mut e = Embedder::new(m, threads_max)?;
            let bg = |s| background_of(&v.backgrounds, s);
            let (ie, dim) = e.embed(&v.train_index, bg)?;
            let (he, _) = e.embed(&v.heldout, bg)?;
            let (ue, _) = e.embed(&v.unseen, bg)?;
            let seen = usertest::trials(
                &v.train_index,
                &ie,
                &v.heldout,
                &he,
                dim,
                &roller,
                &sets.attributes,
            )?;
            let unseen = usertest::trials(
                &v.train_index,
                &ie,
                &v.unseen,
                &ue,
                dim,
                &roller,
                &sets.attributes,
            )?;
            user.push(MethodUserTest {
                name: m.name(),
                seen: usertest::evaluate(&seen),
                unseen: usertest::evaluate(&unseen),
            });
        }
    }
    seconds.push(("user test".to_string(), t.elapsed().as_secs_f64()));
    drop(views);

    // 3. Time to decision and 4. the stability suite (simulator only).
    let mut decision = Vec::new();
    let mut stab = None;
    if cfg.source == SourceKind::Sim {
        let sim =
            telextiles_sim::Simulator::with_options(cfg.protocol.catalogue, cfg.protocol.generator)
                .map_err(|e| anyhow::anyhow!("{e}"))?;
        if cfg.decision_frames > 0 {
            let t = Instant::now();
            let training: Vec<String> = sets
                .train
                .classes
                .iter()
                .filter(|c| c.starts_with('T'))
                .cloned()
                .collect();
            let q = crate::decision_curve::decision_queries(
                &sim,
                &sets.train.classes,
                &training,
                &cfg.protocol.heldout,
                cfg.decision_frames,
                cfg.threads,
            )?;
            for m in methods {
                let mut e = Embedder::new(m, threads_max)?;
                decision.push(crate::decision_curve::decision_curve(
                    m,
                    &mut e,
                    &q,
                    &sets.train_index,
                    &sets.backgrounds,
                )?);
            }
            seconds.push(("time to decision".to_string(), t.elapsed().as_secs_f64()));
        }
        drop(sets);
        if let Some(sc) = &cfg.stability {
            let t = Instant::now();
            stab = Some(stability::run_suite(&sim, methods, sc, threads_max)?);
            seconds.push(("stability suite".to_string(), t.elapsed().as_secs_f64()));
        }
    }

    let report = BenchReport {
        machine: machine(),
        date: today(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        source: match (cfg.source, cfg.protocol.catalogue) {
            (SourceKind::Sim, c) if c != 1 => format!("sim, catalogue {c}"),
            (s, _) => format!("{s:?}").to_lowercase(),
        },
        methods: results,
        cross_generator: cross,
        pareto,
        knee,
        decision,
        stability: stab,
        roller: cfg.roller.clone(),
        usertest: user,
        seconds,
    };
    write(&report, &cfg.out)?;
    Ok(report)
}

/// Methods drawn in the per-factor charts: the Pareto frontier, the best
/// trained encoder and the largest model (the paper's).
pub fn charted(report: &BenchReport) -> Vec<String> {
    let mut names = report.pareto.clone();
    let encoders: Vec<&MethodResult> = report
        .methods
        .iter()
        .filter(|r| r.runtime == "ort" && !is_descriptor(&r.name))
        .collect();
    if let Some(best) = encoders
        .iter()
        .max_by(|a, b| a.press_top1.total_cmp(&b.press_top1))
    {
        names.push(best.name.clone());
    }
    if let Some(big) = encoders.iter().max_by(|a, b| a.ms().total_cmp(&b.ms())) {
        names.push(big.name.clone());
    }
    let mut seen = std::collections::HashSet::new();
    names.retain(|n| seen.insert(n.clone()));
    names
}

/// Whether a method is one of the classical descriptors.
pub fn is_descriptor(name: &str) -> bool {
    ["fft-radial", "pixels16", "lbp-riu2"]
        .iter()
        .any(|p| name.starts_with(p))
}

/// Writes bench.json, report.md and the SVG charts into `out`.
pub fn write(report: &BenchReport, out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    write_atomic(
        &out.join("bench.json"),
        serde_json::to_string_pretty(report)?.as_bytes(),
    )?;
    methods::chart(&report.methods, &out.join("speed-accuracy.svg"))?;
    let names = charted(report);
    if !report.decision.is_empty() {
        let shown: Vec<DecisionCurve> = report
            .decision
            .iter()
            .filter(|d| names.contains(&d.name))
            .cloned()
            .collect();
        crate::stability_charts::decision_chart(&shown, &out.join("decision-time.svg"))?;
    }
    if let Some(s) = &report.stability {
        crate::stability_charts::charts(
            s,
            &names,
            &out.join("stability-accuracy.svg"),
            &out.join("stability-flips.svg"),
        )?;
        crate::stability_charts::coverage_chart(s, &names, &out.join("coverage.svg"))?;
    }
    if !report.usertest.is_empty() {
        usertest_chart(report, &names, &out.join("usertest.svg"))?;
    }
    write_atomic(&out.join("report.md"), markdown(report).as_bytes())?;
    Ok(())
}

fn pct(x: f64) -> String {
    if x.is_finite() {
        format!("{:.1}%", 100.0 * x)
    } else {
        "-".into()
    }
}

/// Per-press top-1 by group of queries (held-out people on training
/// units, on held-out units, hand-held) and on the cross-generator set:
/// the nearest index frame (the paper's kNN, what the rule reads), then
/// the nearest textile centroid (how the daemon decides).
pub fn groups_markdown(results: &[MethodResult], cross: &[MethodResult]) -> String {
    let knn = groups_table(
        results,
        cross,
        "## Across people, sensor units, hand-held presses and generators (top-1 per press)\n\nEvery column uses the same index (the training people's jig presses). Each press's mean embedding is decided by the nearest index frame (kNN, k = 1: the paper's protocol, and what `telextiles-lab rule` reads).\n\n",
        |r| r.press_top1,
        |g| g.press_top1,
    );
    if knn.is_empty() {
        return knn;
    }
    let centroid = groups_table(
        results,
        cross,
        "### The same presses decided as the daemon decides (nearest textile centroid)\n\nThe index holds one centroid per textile (the normalised mean of its index frames, as `index build` makes it and the decider searches it).\n\n",
        |r| r.press_top1_centroid,
        |g| g.press_top1_centroid,
    );
    format!("{knn}{centroid}")
}

/// One table of [`groups_markdown`]: `whole` of a method, `group` of one
/// of its groups.
fn groups_table(
    results: &[MethodResult],
    cross: &[MethodResult],
    heading: &str,
    whole: impl Fn(&MethodResult) -> f64,
    group_value: impl Fn(&crate::methods::GroupScore) -> f64,
) -> String {
    let mut names: Vec<String> = Vec::new();
    for r in results {
        for g in &r.groups {
            if !names.contains(&g.name) {
                names.push(g.name.clone());
            }
        }
    }
    if names.is_empty() && cross.is_empty() {
        return String::new();
    }
    let mut s = format!("{heading}| method | all held-out |");
    for n in &names {
        s.push_str(&format!(" {n} |"));
    }
    if !cross.is_empty() {
        s.push_str(" cross-generator (all held-out) | cross-generator, held-out units | cross-generator, hand-held |");
    }
    let cols = 1 + names.len() + if cross.is_empty() { 0 } else { 3 };
    s.push_str(&format!("\n|---|{}\n", "---:|".repeat(cols)));
    let pct = |v: f64| {
        if v.is_nan() {
            "-".to_string()
        } else {
            format!("{:.1}%", 100.0 * v)
        }
    };
    let group = |r: &MethodResult, n: &str| {
        r.groups
            .iter()
            .find(|g| g.name == n)
            .map_or(f64::NAN, &group_value)
    };
    for r in results {
        s.push_str(&format!("| {} | {} |", r.name, pct(whole(r))));
        for n in &names {
            s.push_str(&format!(" {} |", pct(group(r, n))));
        }
        if !cross.is_empty() {
            match cross.iter().find(|c| c.name == r.name) {
                Some(c) => s.push_str(&format!(
                    " {} | {} | {} |",
                    pct(whole(c)),
                    pct(group(c, "held-out people, held-out units")),
                    pct(group(c, "hand-held queries, jig index"))
                )),
                None => s.push_str(" - | - | - |"),
            }
        }
        s.push('\n');
    }
    if let Some(n) = results.first().map(|r| &r.groups) {
        let counts: Vec<String> = n
            .iter()
            .map(|g| format!("{}: {} presses", g.name, g.presses))
            .collect();
        s.push_str(&format!(
            "\nQuery presses per group: {}.\n",
            counts.join("; ")
        ));
    }
    s.push('\n');
    s
}

/// The report's tables.
pub fn markdown(r: &BenchReport) -> String {
    let mut s = String::new();
    s.push_str(&format!(
        "# Speed against accuracy: measured results\n\nGenerated by `{}` on {} ({}), frames from `{}`.\n\n",
        r.command, r.date, r.machine, r.source
    ));
    s.push_str("## Methods (held-out people; index: training people)\n\n");
    s.push_str(&methods::markdown(&r.methods));
    s.push_str(&format!(
        "\nPareto frontier: {}. Knee: **{}** (the shipped default is chosen by `telextiles-lab rule`, docs/benchmarks.md).\n\n",
        r.pareto.join(", "),
        r.knee.as_deref().unwrap_or("-")
    ));
    s.push_str(&groups_markdown(&r.methods, &r.cross_generator));
    if !r.decision.is_empty() {
        s.push_str("## Accuracy against time since first contact\n\nTop-1 of the running mean of a press's frames from first contact (60 fps); after the slash, every frame weighted by its contact depth.\n\n| method | 50 ms (3 frames) | 100 ms (6) | 250 ms (15) | 500 ms (30) | best |\n|---|---:|---:|---:|---:|---:|\n");
        for d in &r.decision {
            let at = |v: &[(usize, f64)], n: usize| {
                v.iter().find(|x| x.0 == n).map_or("-".into(), |x| pct(x.1))
            };
            let both = |n: usize| {
                if d.weighted.is_empty() {
                    at(&d.top1, n)
                } else {
                    format!("{} / {}", at(&d.top1, n), at(&d.weighted, n))
                }
            };
            let best = d.top1.iter().map(|x| x.1).fold(0.0, f64::max);
            s.push_str(&format!(
                "| {} | {} | {} | {} | {} | {} |\n",
                d.name,
                both(3),
                both(6),
                both(15),
                both(30),
                pct(best)
            ));
        }
        s.push('\n');
        if r.decision.iter().any(|d| !d.by_power.is_empty()) {
            s.push_str(&format!(
                "### The decider's depth power\n\nThe weighted mean above with each frame counted `(w / w_max)^p` (w: its contact weight, w_max: the press's largest so far; the decider's `depth_power`, default {}; 0: every frame the same, 1: by the weight as it is).\n\n| method | p |",
                telextiles_sensing::decide::DecideConfig::default().depth_power
            ));
            for n in crate::decision_curve::POWER_SCAN_FRAMES {
                s.push_str(&format!(" {:.0} ms ({n}) |", n as f64 * 1000.0 / 60.0));
            }
            s.push_str("\n|---|---:|");
            s.push_str(&"---:|".repeat(crate::decision_curve::POWER_SCAN_FRAMES.len()));
            s.push('\n');
            for d in &r.decision {
                for (p, scores) in &d.by_power {
                    s.push_str(&format!("| {} | {p} |", d.name));
                    for n in crate::decision_curve::POWER_SCAN_FRAMES {
                        let v = scores.iter().find(|x| x.0 == n);
                        s.push_str(&format!(" {} |", v.map_or("-".into(), |x| pct(x.1))));
                    }
                    s.push('\n');
                }
            }
            s.push('\n');
        }
    }
    if let Some(st) = &r.stability {
        s.push_str(&format!(
            "## Stability: where each method drops below 90 % (top-1 per press)\n\n{} textiles, {} consecutive frames per query press; index: person 0, sensor 0, jig, 0°, 4 N. Rendering {:.0} s, embedding {:.0} s.\n\n",
            st.textiles, st.config.frames, st.render_s, st.embed_s
        ));
        let factors: Vec<Factor> = st.config.factors.clone();
        s.push_str("| method | nominal |");
        for f in &factors {
            s.push_str(&format!(" {} |", f.label()));
        }
        s.push_str("\n|---|---:|");
        for _ in &factors {
            s.push_str("---|");
        }
        s.push('\n');
        for m in &st.methods {
            let nominal = m
                .curves
                .iter()
                .find(|c| c.factor == Factor::Rotation)
                .and_then(|c| c.levels.iter().find(|l| l.value == 0.0))
                .map_or("-".into(), |l| pct(l.press_top1));
            s.push_str(&format!("| {} | {} |", m.name, nominal));
            for f in &factors {
                let cell = m
                    .curves
                    .iter()
                    .find(|c| c.factor == *f)
                    .map_or("-".into(), |c| {
                        crate::stability_charts::failure_point(c, 0.9)
                    });
                s.push_str(&format!(" {cell} |"));
            }
            s.push('\n');
        }
        s.push_str("\nPer level (top-1 per press / flip rate), every method:\n\n");
        for f in &factors {
            let Some(first) = st
                .methods
                .first()
                .and_then(|m| m.curves.iter().find(|c| c.factor == *f))
            else {
                continue;
            };
            s.push_str(&format!("### {}\n\n", f.label()));
            if f.is_coverage() {
                s.push_str("Top-1 per press against the nearest index frame / flip rate / against the nearest textile centroid (the index `index build --sim` makes) / against the nearest of each textile's centroid and its presses' means (the index `index build --presses` makes). The same query presses at every level; the index holds the first n presses of every textile, each at a random spot and swatch.\n\n");
            }
            s.push_str("| method |");
            for l in &first.levels {
                s.push_str(&format!(" {} |", l.value));
            }
            s.push_str("\n|---|");
            for _ in &first.levels {
                s.push_str("---|");
            }
            s.push('\n');
            for m in &st.methods {
                if let Some(c) = m.curves.iter().find(|c| c.factor == *f) {
                    s.push_str(&format!("| {} |", m.name));
                    for l in &c.levels {
                        s.push_str(&format!(
                            " {:.0} / {:.0}",
                            100.0 * l.press_top1,
                            100.0 * l.flip_rate
                        ));
                        for c in [l.press_top1_centroid, l.press_top1_exemplars]
                            .into_iter()
                            .flatten()
                        {
                            s.push_str(&format!(" / {:.0}", 100.0 * c));
                        }
                        s.push_str(" |");
                    }
                    s.push('\n');
                }
            }
            s.push('\n');
        }
    }
    if !r.usertest.is_empty() {
        s.push_str(&format!(
            "## The paper's user test against ground truth\n\nRoller ({} textiles): {}. Per query press, the roller textiles ranked by latent distance vs by ground-truth attribute distance. Seen: held-out people's presses of training textiles not on the roller; unseen: their presses of the 20 unseen textiles.\n\n| method | set | trials | Top-1 in Top-1 | Top-1 in Top-3 | Top-K agreement K=1 / 3 / 5 | mean Spearman ρ (sd) | t | p |\n|---|---|---:|---:|---:|---|---:|---:|---:|\n",
            r.roller.len(),
            r.roller.join(", ")
        ));
        for u in &r.usertest {
            for (set, x) in [("seen", &u.seen), ("unseen", &u.unseen)] {
                let a = |k: usize| x.topk_agreement.get(k - 1).copied().unwrap_or(f64::NAN);
                let h = |k: usize| x.top1_in_topk.get(k - 1).copied().unwrap_or(f64::NAN);
                s.push_str(&format!(
                    "| {} | {} | {} | {} | {} | {} / {} / {} | {:.3} ({:.3}) | {:.2} | {:.3} |\n",
                    u.name,
                    set,
                    x.trials,
                    pct(h(1)),
                    pct(h(3)),
                    pct(a(1)),
                    pct(a(3)),
                    pct(a(5)),
                    x.spearman_mean,
                    x.spearman_sd,
                    x.t,
                    x.p
                ));
            }
        }
        s.push('\n');
    }
    s.push_str("## Run time\n\n| part | s |\n|---|---:|\n");
    for (p, t) in &r.seconds {
        s.push_str(&format!("| {p} | {t:.0} |\n"));
    }
    s
}

/// Top-K agreement against K, seen and unseen panels.
fn usertest_chart(report: &BenchReport, names: &[String], svg: &Path) -> Result<()> {
    use plotters::prelude::*;
    let e = |x: Box<dyn std::error::Error + '_>| anyhow::anyhow!("chart: {x}");
    let root = SVGBackend::new(svg, (1200, 520)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(Box::new(x)))?;
    let panels = root.split_evenly((1, 2));
    for (pi, (panel, unseen)) in panels.iter().zip([false, true]).enumerate() {
        let n = report.roller.len().max(2);
        let mut c = ChartBuilder::on(panel)
            .caption(
                if unseen {
                    "User test, unseen textiles: Top-K agreement"
                } else {
                    "User test, seen textiles: Top-K agreement"
                },
                ("sans-serif", 16),
            )
            .margin(10)
            .x_label_area_size(35)
            .y_label_area_size(45)
            .build_cartesian_2d(1usize..n, 0.0..100.0)
            .map_err(|x| e(Box::new(x)))?;
        c.configure_mesh()
            .x_desc("K (of the roller's textiles)")
            .y_desc("|TopK(latent) ∩ TopK(truth)| / K, %")
            .draw()
            .map_err(|x| e(Box::new(x)))?;
        // Chance: K / N.
        c.draw_series(LineSeries::new(
            (1..=n).map(|k| (k, 100.0 * k as f64 / n as f64)),
            BLACK.mix(0.4).stroke_width(1),
        ))
        .map_err(|x| e(Box::new(x)))?
        .label("chance (K/N)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], BLACK.mix(0.4)));
        for (mi, u) in report
            .usertest
            .iter()
            .filter(|u| names.contains(&u.name))
            .enumerate()
        {
            let x = if unseen { &u.unseen } else { &u.seen };
            let color = Palette99::pick(mi).to_rgba();
            let s = c
                .draw_series(LineSeries::new(
                    x.topk_agreement
                        .iter()
                        .enumerate()
                        .map(|(k, a)| (k + 1, 100.0 * a)),
                    color.stroke_width(2),
                ))
                .map_err(|x| e(Box::new(x)))?;
            if pi == 0 {
                s.label(u.name.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], color.stroke_width(2))
                });
            }
        }
        if pi == 0 {
            c.configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .position(SeriesLabelPosition::LowerRight)
                .draw()
                .map_err(|x| e(Box::new(x)))?;
        }
    }
    root.present().map_err(|x| e(Box::new(x)))?;
    Ok(())
}
