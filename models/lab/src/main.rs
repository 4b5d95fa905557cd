//! telextiles-lab: train, export, evaluate, benchmark.

use anyhow::{bail, ensure, Context, Result};
use clap::{Parser, Subcommand};
use std::path::{Path, PathBuf};
use std::time::Instant;

use telextiles_lab::augment::AugConfig;
use telextiles_lab::bench;
use telextiles_lab::data::{write_atomic, ImageSet};
use telextiles_lab::model::ArchConfig;
use telextiles_lab::onnx::{export_encoder, EncoderMeta, OrtEncoder};
use telextiles_lab::protocol::{self, SourceKind};
use telextiles_lab::recorded::Source;
use telextiles_lab::train::{embed_set, train_loop, LoopOptions, RunDir, TrainConfig, Trainer};

mod cli;
use cli::args::*;

#[derive(Parser)]
#[command(
    name = "telextiles-lab",
    about = "Telextiles encoder lab: train, export, evaluate, benchmark"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Render the frame caches of the paper protocol (training canvases, evaluation sets).
    Cache(CacheArgs),
    /// Train the encoder (MoCo v2 style) on a cache; checkpoints every epoch.
    Train(TrainArgs),
    /// Export a checkpoint to ONNX and verify it against burn in ONNX Runtime.
    Export(ExportArgs),
    /// Evaluate an ONNX encoder as in the paper (kNN top-1 tables).
    Eval(EvalArgs),
    /// Per-frame encode latency of an ONNX encoder through ONNX Runtime.
    BenchLatency(LatencyArgs),
    /// Time MoCo training steps of candidate architectures on this machine.
    BenchTrain(BenchTrainArgs),
    /// The speed-vs-accuracy study in one run: classical descriptors and
    /// ONNX models on the same held-out presses (table, Pareto frontier and
    /// knee), time to decision, the stability suite and the user test;
    /// JSON, markdown and SVG charts in --out.
    Bench(BenchArgs),
    /// Write a classical descriptor as an ONNX model with the encoder
    /// contract (the daemon runs it like a trained encoder).
    ExportDescriptor(ExportDescriptorArgs),
    /// int8 version of an ONNX model: ONNX Runtime static quantisation
    /// calibrated on the training people's DIGIT frames.
    Quantize(QuantizeArgs),
    /// Train the contrastive encoder with the robust recipe (issue 20):
    /// frame minus reference, physical augmentations, supervised
    /// contrastive positives across people, units, rotations and swatches;
    /// exports the best checkpoint (by validation) to ONNX.
    TrainSupcon(SupconArgs),
    /// Train a contrastive head on the shipped spectrum descriptor (the
    /// same data, positives and augmentations as train-supcon); writes the
    /// descriptor graph with the head as one ONNX model.
    TrainSpectral(SpectralArgs),
    /// Apply the written rule for the shipped default (docs/benchmarks.md)
    /// to a bench.json: the worst case over held-out people, units,
    /// hand-held, cross-generator, rotation, force and 100 ms, within 1 ms.
    Rule(RuleArgs),
    /// Write simulated presses in the on-disk press format, laid out as
    /// `telextilesd record` lays out recordings (`<out>/<textile>/<press>/`):
    /// a stand-in for your own recordings to try `--source presses:<dir>`.
    SimPresses(SimPressesArgs),
    /// When the decider commits: the daemon's front end and decider on whole
    /// simulated presses (jig and hand-held, held-out people), for candidate
    /// timing rules (min_ms, confirm_ms); committed decisions right against
    /// time after first contact, switches, and the written rule's pick.
    DeciderTiming(DeciderTimingArgs),
    /// False presses of candidate contact detectors on simulated idle
    /// footage (no contact), with extra LED flicker as a margin.
    ContactIdle(ContactIdleArgs),
    /// The contact detector by the written rule, from a `contact-idle`
    /// study and `decider-timing` studies run with each detector.
    ContactChoose(ContactChooseArgs),
    /// The switching rule across several `decider-timing` studies (e.g.
    /// both catalogues): the written rule over every group of every study.
    DeciderSwitch(DeciderSwitchArgs),
    /// Centre and spread of the marginal statistics (`mstats`) and the
    /// whitened spectrum's mean per-value spread, over the frames in contact
    /// of recorded presses: the constants `wspec-m` standardises with.
    MstatsScale(MstatsScaleArgs),
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::Cache(a) => {
            let p = a.data.protocol();
            protocol::load_or_build(&p, a.data.kind()?, &a.data.cache_dir, a.data.threads)?;
            Ok(())
        }
        Cmd::Train(a) => train(a),
        Cmd::TrainSupcon(a) => train_supcon(a),
        Cmd::Rule(a) => {
            let v: serde_json::Value = serde_json::from_slice(
                &std::fs::read(&a.bench)
                    .with_context(|| format!("cannot read {}", a.bench.display()))?,
            )
            .with_context(|| format!("{} is not JSON", a.bench.display()))?;
            let o = telextiles_lab::rule::apply(&v, &a.incumbent)?;
            print!("{}", telextiles_lab::rule::markdown(&o));
            Ok(())
        }
        Cmd::TrainSpectral(a) => {
            let mut cfg = telextiles_lab::spectral::SpectralConfig::new();
            cfg.data.presses_per_textile = a.presses_per_textile;
            cfg.data.frames_per_press = a.frames_per_press;
            cfg.data.ramp_frames = a.ramp_frames as usize;
            cfg.data.val_presses = a.val_presses;
            cfg.data.max_textiles = a.textiles;
            cfg.data.catalogue = a.catalogue;
            cfg.data.seed = a.seed;
            cfg.augs_per_frame = a.augs;
            cfg.front = a.front;
            cfg.taper = a.taper;
            cfg.steps = a.steps;
            cfg.hidden = a.hidden;
            cfg.out = a.dim;
            cfg.lr = a.lr;
            cfg.attr_weight = a.attr_weight;
            cfg.temperature = a.temperature;
            let (bytes, base, val) =
                telextiles_lab::spectral::train(&cfg, &a.run, &a.cache_dir, a.threads)?;
            write_atomic(&a.out, &bytes)?;
            println!(
                "wrote {} ({} bytes); validation top-1 per press {:.1}% (the descriptor alone {:.1}%)",
                a.out.display(),
                bytes.len(),
                100.0 * val,
                100.0 * base
            );
            Ok(())
        }
        Cmd::Bench(a) => bench_cmd(a),
        Cmd::ExportDescriptor(a) => export_descriptor(a),
        Cmd::Quantize(a) => quantize_cmd(a),
        Cmd::SimPresses(a) => sim_presses(a),
        Cmd::DeciderTiming(a) => decider_timing(a),
        Cmd::ContactIdle(a) => contact_idle(a),
        Cmd::ContactChoose(a) => contact_choose(a),
        Cmd::DeciderSwitch(a) => decider_switch(a),
        Cmd::MstatsScale(a) => mstats_scale(a),
        Cmd::Export(a) => export(a),
        Cmd::Eval(a) => eval(a),
        Cmd::BenchLatency(a) => {
            println!(
                "| model | threads | median ms/frame | p90 ms | runs |\n|---|---|---|---|---|"
            );
            let mut models = Vec::new();
            for m in &a.model {
                let bytes =
                    std::fs::read(m).with_context(|| format!("cannot read {}", m.display()))?;
                models.push((m.display().to_string(), bytes));
            }
            for name in &a.arch {
                let arch = ArchConfig::parse(name)?;
                let enc = arch.init_encoder(&burn::tensor::Device::flex());
                let meta = EncoderMeta {
                    arch: arch.clone(),
                    crop: arch.input as u32,
                    train_data_hash: "untrained".into(),
                    subtract: false,
                };
                models.push((
                    format!("{} (untrained)", arch.name()),
                    export_encoder(&enc, &meta)?,
                ));
            }
            ensure!(!models.is_empty(), "give --model and/or --arch");
            for (name, bytes) in &models {
                for &t in &a.threads {
                    let l = bench::time_latency(bytes, t, 30, a.runs)?;
                    println!(
                        "| {} | {} | {:.3} | {:.3} | {} |",
                        name, t, l.median_ms, l.p90_ms, l.runs
                    );
                }
            }
            Ok(())
        }
        Cmd::BenchTrain(a) => {
            println!(
                "| arch | encoder params | batch | median s/step | steps |\n|---|---|---|---|---|"
            );
            for name in &a.arch {
                let arch = ArchConfig::parse(name)?;
                let t = bench::time_train_steps(&arch, a.batch, a.steps)?;
                println!(
                    "| {} | {} | {} | {:.3} | {} |",
                    t.arch, t.encoder_params, t.batch, t.median_s, t.steps
                );
            }
            Ok(())
        }
    }
}

fn train(a: TrainArgs) -> Result<()> {
    let arch = ArchConfig::parse(&a.arch)?;
    ensure!(
        arch.input as u32 == a.data.input,
        "--arch input {} differs from --input {}",
        arch.input,
        a.data.input
    );
    let p = a.data.protocol();
    let sets = protocol::load_or_build(&p, a.data.kind()?, &a.data.cache_dir, a.data.threads)?;
    let run = RunDir(a.run.clone());
    let mut trainer = if a.resume {
        let latest = run
            .latest()
            .with_context(|| format!("--resume: no checkpoint in {}", a.run.display()))?;
        let mut t = Trainer::load(&latest)?;
        ensure!(
            t.cfg.arch == arch,
            "--resume: checkpoint is {}, not {}",
            t.cfg.arch.name(),
            arch.name()
        );
        t.cfg.epochs = a.epochs;
        eprintln!(
            "resumed {} at epoch {} step {}",
            latest.display(),
            t.epoch,
            t.step
        );
        t
    } else {
        if run.latest().is_some() {
            bail!(
                "{} already has checkpoints; pass --resume or use another --run",
                a.run.display()
            );
        }
        let mut cfg = TrainConfig::new(arch);
        cfg.batch = a.batch;
        cfg.queue = a.queue;
        cfg.lr = a.lr;
        cfg.temperature = a.temperature;
        cfg.key_momentum = a.key_momentum;
        cfg.bn_splits = a.bn_splits;
        cfg.epochs = a.epochs;
        cfg.steps_per_epoch = a.steps_per_epoch;
        cfg.seed = a.seed;
        cfg.aug = AugConfig::default();
        Trainer::new(cfg)
    };
    std::fs::create_dir_all(&a.run)?;
    write_atomic(
        &a.run.join("config.json"),
        serde_json::to_string_pretty(&trainer.cfg)?.as_bytes(),
    )?;
    let info = serde_json::json!({
        "train_images": sets.train.len(),
        "train_hash": sets.train.hash(),
        "heldout_images": sets.heldout.len(),
        "source": sets.train.source,
        "command": std::env::args().collect::<Vec<_>>().join(" "),
    });
    write_atomic(
        &a.run.join("data.json"),
        serde_json::to_string_pretty(&info)?.as_bytes(),
    )?;
    eprintln!(
        "training {} on {} canvases ({} steps/epoch, {} epochs), held-out {} frames",
        trainer.cfg.arch.name(),
        sets.train.len(),
        trainer.steps_per_epoch(telextiles_lab::train::presses(&sets.train).len()),
        trainer.cfg.epochs,
        sets.heldout.len()
    );
    let t0 = Instant::now();
    let opts = LoopOptions {
        progress_every: 1,
        max_steps: a.max_steps,
        keep: 3,
        eval_every: a.eval_every,
    };
    let losses = train_loop(&mut trainer, &sets.train, Some(&sets.heldout), &run, &opts)?;
    eprintln!(
        "done: {} steps in {:.0}s this process",
        losses.len(),
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

fn train_supcon(a: SupconArgs) -> Result<()> {
    use telextiles_lab::supcon::{self, SupConConfig};
    let arch = ArchConfig::parse(&a.arch)?;
    let mut cfg = SupConConfig::new(arch.clone());
    cfg.crop = a.crop;
    cfg.catalogue = a.catalogue;
    cfg.generator = a.generator;
    cfg.presses_per_textile = a.presses_per_textile;
    cfg.frames_per_press = a.frames_per_press;
    cfg.ramp_frames = a.ramp_frames as usize;
    cfg.val_presses = a.val_presses;
    cfg.max_textiles = a.textiles;
    cfg.steps = a.steps;
    cfg.eval_every = a.eval_every.max(1);
    cfg.classes_per_batch = a.classes_per_batch;
    cfg.views_per_class = a.views_per_class;
    cfg.lr = a.lr;
    cfg.max_seconds = a.max_minutes.map(|m| m * 60.0);
    cfg.seed = a.seed;
    cfg.warmup_steps = cfg.warmup_steps.min(cfg.steps / 5);
    let (encoder, val) = supcon::train(&cfg, &a.run, a.threads)?;
    let hash = {
        use sha2::Digest;
        let mut h = sha2::Sha256::new();
        h.update(serde_json::to_vec(&cfg)?);
        telextiles_lab::data::hex(&h.finalize())[..16].to_string()
    };
    let meta = EncoderMeta {
        arch: arch.clone(),
        crop: a.crop,
        train_data_hash: hash,
        subtract: true,
    };
    let bytes = export_encoder(&encoder, &meta)?;
    // ONNX Runtime must give what burn gives on real difference frames (a
    // few validation presses: 8 frames are compared).
    let probe_cfg = SupConConfig {
        max_textiles: Some(4),
        ..cfg.clone()
    };
    let probe = supcon::render_set(
        &probe_cfg,
        &[cfg.val_person],
        &[cfg.val_unit],
        1,
        77,
        a.threads,
        "export check",
    )?;
    let n = probe.len().min(8);
    let s = arch.input;
    let mut x = Vec::new();
    for i in 0..n {
        x.extend(supcon::centre_of(probe.image(i), probe.side, s));
    }
    let sub = supcon::DiffSet {
        side: s,
        data: x.clone(),
        class: probe.class[..n].to_vec(),
        press: probe.press[..n].to_vec(),
        classes: probe.classes.clone(),
    };
    let (want, _) = supcon::embed(&encoder, &sub, s)?;
    let mut ort = OrtEncoder::from_bytes(&bytes, 2)?;
    let mut got = ort.embed(&x)?;
    telextiles_lab::knn::normalize_rows(&mut got, ort.dim);
    let diff = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    ensure!(
        diff < 1e-3,
        "ONNX Runtime and burn differ by {diff}; not writing {}",
        a.out.display()
    );
    write_atomic(&a.out, &bytes)?;
    println!(
        "wrote {} ({} bytes, validation top-1 per press {:.1}%, ort vs burn {:.1e})",
        a.out.display(),
        bytes.len(),
        100.0 * val,
        diff
    );
    Ok(())
}

fn checkpoint_dir(p: &Path) -> Result<PathBuf> {
    if p.join("state.json").exists() {
        return Ok(p.to_path_buf());
    }
    RunDir(p.to_path_buf())
        .latest()
        .with_context(|| format!("no checkpoint found in {}", p.display()))
}

fn export(a: ExportArgs) -> Result<()> {
    let ck = checkpoint_dir(&a.run)?;
    let trainer = Trainer::load(&ck)?;
    let run_dir = if ck.join("state.json") == a.run.join("state.json") {
        ck.parent()
            .and_then(|p| p.parent())
            .unwrap_or(&ck)
            .to_path_buf()
    } else {
        a.run.clone()
    };
    let data: serde_json::Value = serde_json::from_slice(
        &std::fs::read(run_dir.join("data.json"))
            .with_context(|| format!("{}/data.json", run_dir.display()))?,
    )?;
    let hash = data["train_hash"]
        .as_str()
        .context("data.json lacks train_hash")?
        .to_string();
    let meta = EncoderMeta {
        arch: trainer.cfg.arch.clone(),
        crop: a.data.crop,
        train_data_hash: hash,
        subtract: false,
    };
    let encoder = trainer.encoder();
    let bytes = export_encoder(&encoder, &meta)?;
    // Verify against burn on real held-out frames (batch of 16 and of 1).
    let sets = protocol::load_or_build(
        &a.data.protocol(),
        a.data.kind()?,
        &a.data.cache_dir,
        a.data.threads,
    )?;
    let probe = sets
        .heldout
        .subset(&(0..16.min(sets.heldout.len())).collect::<Vec<_>>());
    let want = embed_set_raw(&encoder, &probe)?;
    let mut ort = OrtEncoder::from_bytes(&bytes, 2)?;
    let mut x = Vec::new();
    for i in 0..probe.len() {
        telextiles_lab::preprocess::normalize_into(probe.image(i), probe.side, &mut x);
    }
    let got = ort.embed(&x)?;
    let diff = got
        .iter()
        .zip(&want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0f32, f32::max);
    ensure!(
        diff < 1e-4,
        "ONNX Runtime and burn differ by {diff} (>= 1e-4); not writing {}",
        a.out.display()
    );
    write_atomic(&a.out, &bytes)?;
    use sha2::Digest;
    println!(
        "wrote {} ({} bytes, sha256 {}) from {} (epoch {}); ort vs burn max abs diff {:.2e} on {} frames",
        a.out.display(),
        bytes.len(),
        telextiles_lab::data::hex(&sha2::Sha256::digest(&bytes)),
        ck.display(),
        trainer.epoch,
        diff,
        probe.len()
    );
    Ok(())
}

/// Unnormalised burn embeddings of an input set.
fn embed_set_raw(encoder: &telextiles_lab::model::Encoder, set: &ImageSet) -> Result<Vec<f32>> {
    use burn::tensor::{Device, Tensor, TensorData};
    let device = Device::flex();
    let mut x = Vec::new();
    for i in 0..set.len() {
        telextiles_lab::preprocess::normalize_into(set.image(i), set.side, &mut x);
    }
    let s = set.side;
    let y = encoder.forward(Tensor::<4>::from_data(
        TensorData::new(x, [set.len(), 3, s, s]),
        &device,
    ));
    y.into_data()
        .try_to_vec::<f32>()
        .map_err(|e| anyhow::anyhow!("{e:?}"))
}

fn eval(mut a: EvalArgs) -> Result<()> {
    let bytes =
        std::fs::read(&a.model).with_context(|| format!("cannot read {}", a.model.display()))?;
    let m = telextiles_lab::methods::Method::onnx(a.model.display().to_string(), bytes)?;
    if let Source::Presses(dir) = &a.data.source {
        let mut cfg = a.recorded.study(dir)?;
        cfg.workers = a.ort_threads;
        cfg.time_threads = if a.ort_threads > 1 {
            vec![1, a.ort_threads]
        } else {
            vec![1]
        };
        cfg.runs = 100;
        let r = telextiles_lab::recorded_report::run(&cfg, std::slice::from_ref(&m), None)?;
        println!("{}", telextiles_lab::recorded_report::markdown(&r));
        if let Some(j) = a.json {
            write_atomic(&j, serde_json::to_string_pretty(&r)?.as_bytes())?;
        }
        return Ok(());
    }
    let metric = a.recorded.index_metric.take();
    a.recorded.refuse_unless_presses()?;
    // The model's own crop and input size (its metadata), whatever
    // --input/--crop say.
    let (crop, input) = m.view();
    let mut p = a.data.protocol();
    p.crop = crop;
    p.input = input;
    let sets = protocol::load_or_build(&p, a.data.kind()?, &a.data.cache_dir, a.data.threads)?;
    let report = telextiles_lab::paper_eval::evaluate_with(&m, &sets, &p, a.ort_threads, metric)?;
    println!("{}", report.markdown(&a.model));
    if let Some(j) = a.json {
        write_atomic(&j, serde_json::to_string_pretty(&report)?.as_bytes())?;
    }
    let _ = embed_set;
    Ok(())
}

fn bench_cmd(a: BenchArgs) -> Result<()> {
    use telextiles_lab::methods::Method;
    use telextiles_lab::report::{self, BenchConfig};
    use telextiles_lab::stability::{Factor, SuiteConfig};
    let mut list = if a.no_descriptors {
        Vec::new()
    } else {
        report::descriptor_methods()?
    };
    for d in &a.rust_descriptor {
        list.push(rust_descriptor(d)?);
    }
    let mut models = Vec::new();
    for m in &a.model {
        let (name, path) = match m.split_once('=') {
            Some((n, p)) => (n.to_string(), PathBuf::from(p)),
            None => {
                let p = PathBuf::from(m);
                let n = p
                    .file_stem()
                    .map_or("model".into(), |s| s.to_string_lossy().into_owned());
                (n, p)
            }
        };
        let bytes =
            std::fs::read(&path).with_context(|| format!("cannot read {}", path.display()))?;
        list.push(Method::onnx(name.clone(), bytes)?);
        models.push((name, path));
    }
    if let Source::Presses(dir) = &a.data.source {
        let mut cfg = a.recorded.study(dir)?;
        cfg.workers = a.data.threads;
        cfg.time_threads = a.time_threads.clone();
        cfg.runs = a.runs;
        let out = a
            .out
            .clone()
            .context("--out <dir> is required with --source presses:<dir>")?;
        let r = telextiles_lab::recorded_report::run(&cfg, &list, Some(&out))?;
        println!("{}", telextiles_lab::recorded_report::markdown(&r));
        eprintln!(
            "wrote bench.json, report.md and the charts in {}",
            out.display()
        );
        return Ok(());
    }
    let out = a.out.clone().unwrap_or_else(|| PathBuf::from("docs/bench"));
    a.recorded.refuse_unless_presses()?;
    let roller: Vec<String> = if a.roller.is_empty() {
        Vec::new()
    } else if a.roller.ends_with(".tlxi") || Path::new(&a.roller).exists() {
        let index = telextiles_index::Index::read(Path::new(&a.roller))
            .with_context(|| format!("--roller {}", a.roller))?;
        index
            .roller
            .slots
            .iter()
            .map(|&e| index.entries[e].id.clone())
            .collect()
    } else {
        a.roller.split(',').map(|s| s.trim().to_string()).collect()
    };
    let cfg = BenchConfig {
        source: a.data.kind()?,
        protocol: a.data.protocol(),
        cache_dir: a.data.cache_dir.clone(),
        threads: a.data.threads,
        models,
        time_threads: a.time_threads.clone(),
        runs: a.runs,
        stability: if a.no_stability {
            None
        } else {
            let mut sc = SuiteConfig {
                textiles: a.data.textiles,
                frames: a.stability_frames,
                threads: a.data.threads,
                quick: a.quick,
                index_stretch: a.index_stretch,
                ..SuiteConfig::default()
            };
            if !a.factors.is_empty() {
                sc.factors = a
                    .factors
                    .iter()
                    .map(|f| Factor::parse(f))
                    .collect::<Result<_>>()?;
            }
            Some(sc)
        },
        decision_frames: a.decision_frames,
        roller,
        cross_generator: a.cross_generator,
        out: out.clone(),
    };
    let r = report::run(&cfg, &list)?;
    println!("{}", report::markdown(&r));
    eprintln!(
        "wrote bench.json, report.md and the charts in {}",
        out.display()
    );
    Ok(())
}

fn decider_timing(a: DeciderTimingArgs) -> Result<()> {
    use telextiles_lab::decider_timing as dt;
    ensure!(
        a.data.kind()? == SourceKind::Sim,
        "decider-timing renders whole presses: it needs --source sim"
    );
    let bytes =
        std::fs::read(&a.model).with_context(|| format!("cannot read {}", a.model.display()))?;
    let m = telextiles_lab::methods::Method::onnx(a.model.display().to_string(), bytes)?;
    let cfg = dt::StudyConfig {
        protocol: a.data.protocol(),
        cache_dir: a.data.cache_dir.clone(),
        people: a.people,
        threads: a.data.threads,
        contact: contact_config(
            a.contact_enter,
            a.contact_exit,
            a.contact_frames,
            a.contact_gain,
            a.contact_tile,
        )?,
    };
    let r = dt::run(&cfg, &m)?;
    dt::write(&r, &a.out)?;
    println!("{}", dt::markdown(&r));
    eprintln!(
        "wrote timing.json, report.md and the charts in {}",
        a.out.display()
    );
    Ok(())
}

/// The shipped contact detector with the given entry threshold, exit
/// threshold and run length.
fn contact_config(
    enter: Option<f32>,
    exit: Option<f32>,
    frames: Option<u32>,
    gain: Option<bool>,
    tile: Option<u32>,
) -> Result<telextiles_sensing::contact::ContactConfig> {
    let shipped = telextiles_lab::contact_idle::Detector::shipped();
    let mut c = telextiles_lab::contact_idle::Detector {
        enter: enter.unwrap_or(shipped.enter),
        frames: frames.unwrap_or(shipped.frames),
        gain: gain.unwrap_or(shipped.gain),
        tile: tile.unwrap_or(shipped.tile),
    }
    .config()?;
    if let Some(x) = exit {
        ensure!(
            x > 0.0 && x < c.enter,
            "--contact-exit needs 0 < exit < enter ({})",
            c.enter
        );
        c.exit = x;
    }
    Ok(c)
}

fn contact_idle(a: ContactIdleArgs) -> Result<()> {
    use telextiles_lab::contact_idle as ci;
    let mut units = Vec::new();
    let default_units = ["1:0,4,5".to_string()];
    let unit_specs: &[String] = if a.units.is_empty() && a.footage.is_empty() {
        &default_units
    } else {
        &a.units
    };
    let mut footage = Vec::new();
    for f in &a.footage {
        let found = telextiles_sim::recording::find_presses(f)
            .with_context(|| format!("--footage {}", f.display()))?;
        ensure!(
            !found.is_empty(),
            "--footage {}: no recording (a directory holding press.json) there",
            f.display()
        );
        footage.extend(found);
    }
    for spec in unit_specs {
        let (c, list) = spec
            .split_once(':')
            .with_context(|| format!("--units {spec}: expected CATALOGUE:UNIT,UNIT,..."))?;
        let c: u32 = c
            .parse()
            .with_context(|| format!("--units {spec}: catalogue"))?;
        ensure!(c == 1 || c == 2, "--units {spec}: catalogue 1 or 2");
        for u in list.split(',') {
            units.push((
                c,
                u.trim()
                    .parse::<u32>()
                    .with_context(|| format!("--units {spec}: unit {u}"))?,
            ));
        }
    }
    let r = ci::run(&ci::IdleConfig {
        units,
        footage,
        seconds: a.seconds,
        stress: a.stress.clone(),
        threads: a.threads,
        seed: a.seed,
    })?;
    ci::write(&r, &a.out)?;
    println!("{}", ci::markdown(&r));
    eprintln!("wrote idle.json and idle.md in {}", a.out.display());
    Ok(())
}

fn contact_choose(a: ContactChooseArgs) -> Result<()> {
    use telextiles_lab::contact_idle as ci;
    let idle = ci::read(&a.idle)?;
    let timings = a
        .timing
        .iter()
        .map(|p| telextiles_lab::decider_timing::read(p))
        .collect::<Result<Vec<_>>>()?;
    let rows = ci::rows(&idle, &timings)?;
    let chosen = ci::choose(&rows)?;
    let md = ci::markdown_choice(
        &rows,
        chosen,
        &std::env::args().collect::<Vec<_>>().join(" "),
    );
    std::fs::create_dir_all(&a.out)
        .with_context(|| format!("cannot create {}", a.out.display()))?;
    write_atomic(&a.out.join("choice.md"), md.as_bytes())?;
    ci::chart(&rows, &a.out.join("right-at-100ms.svg"))?;
    println!("{md}");
    eprintln!(
        "wrote choice.md and right-at-100ms.svg in {}",
        a.out.display()
    );
    Ok(())
}

fn decider_switch(a: DeciderSwitchArgs) -> Result<()> {
    use telextiles_lab::decider_timing as dt;
    let reports = a
        .timing
        .iter()
        .map(|p| dt::read(p))
        .collect::<Result<Vec<_>>>()?;
    let md = dt::markdown_across(&reports, &std::env::args().collect::<Vec<_>>().join(" "))?;
    if let Some(out) = &a.out {
        write_atomic(out, md.as_bytes())?;
        eprintln!("wrote {}", out.display());
    }
    println!("{md}");
    Ok(())
}

fn quantize_cmd(a: QuantizeArgs) -> Result<()> {
    let bytes =
        std::fs::read(&a.model).with_context(|| format!("cannot read {}", a.model.display()))?;
    let m = telextiles_lab::methods::Method::onnx(a.model.display().to_string(), bytes.clone())?;
    let (crop, input) = m.view();
    let sets = protocol::load_base(
        &a.data.protocol(),
        a.data.kind()?,
        &a.data.cache_dir,
        a.data.threads,
    )?;
    let calib = protocol::view_set(&sets.train_index, crop, input)?;
    let compare = protocol::view_set(&sets.heldout, crop, input)?;
    let refs = protocol::view_set(&sets.backgrounds, crop, input)?;
    let (q, report) = telextiles_lab::quantize::quantize(
        &bytes,
        &calib,
        a.calibration_frames,
        &compare,
        &refs,
        a.allow_nonfinite,
    )?;
    write_atomic(&a.out, &q)?;
    println!(
        "wrote {} ({} bytes; float {} bytes): calibrated on {} frames; cosine to the float model on {} held-out frames: mean {:.4}, min {:.4}{}",
        a.out.display(),
        q.len(),
        bytes.len(),
        report.calibration_frames,
        report.compared_frames,
        report.cosine_mean,
        report.cosine_min,
        if report.nonfinite_frames > 0 {
            format!(
                "; NON-FINITE embeddings on {} frames (written because of --allow-nonfinite)",
                report.nonfinite_frames
            )
        } else {
            String::new()
        }
    );
    Ok(())
}

fn sim_presses(a: SimPressesArgs) -> Result<()> {
    use telextiles_sim::{PressSpec, Simulator};
    ensure!(
        !a.sensors.is_empty() && !a.people.is_empty(),
        "--sensors and --people need at least one value"
    );
    let sim =
        Simulator::with_options(a.catalogue, a.generator).map_err(|e| anyhow::anyhow!("{e}"))?;
    let textiles: Vec<String> = if a.textiles.is_empty() {
        sim.catalogue()
            .training()
            .take(a.first)
            .map(|t| t.id.clone())
            .collect()
    } else {
        a.textiles.clone()
    };
    let progress = telextiles_progress::Progress::new(
        "rendering presses",
        (textiles.len() * a.presses) as u64,
        "presses",
    );
    let mut written = 0;
    for (ti, t) in textiles.iter().enumerate() {
        for k in 0..a.presses {
            let (person, sensor) = (a.people[k % a.people.len()], a.sensors[k % a.sensors.len()]);
            let dir = a.out.join(t).join(format!("p{person}-s{sensor}-{k:03}"));
            if !dir.exists() {
                let seed = a.seed + 1000 * ti as u64 + k as u64;
                let press = sim
                    .render_press(&PressSpec {
                        person,
                        sensor,
                        jig: !a.hand,
                        frames: a.frames,
                        ..PressSpec::new(t.clone(), seed)
                    })
                    .map_err(|e| anyhow::anyhow!("{t}: {e}"))?;
                telextiles_sim::recording::write_press(&dir, &press)?;
                written += 1;
            }
            progress.inc(1);
        }
    }
    progress.finish();
    println!(
        "wrote {written} simulated presses under {} ({} textiles x {} presses; existing ones kept)",
        a.out.display(),
        textiles.len(),
        a.presses
    );
    Ok(())
}

/// A Rust descriptor method from `KIND[-bg]@CROP`.
fn rust_descriptor(d: &str) -> Result<telextiles_lab::methods::Method> {
    use telextiles_lab::baselines::{Baseline, BaselineKind};
    let (k, crop) = d
        .split_once('@')
        .with_context(|| format!("--rust-descriptor {d:?}: expected KIND[-bg]@CROP"))?;
    let crop: u32 = crop
        .parse()
        .with_context(|| format!("--rust-descriptor {d:?}: the crop is not a number"))?;
    let (k, bgsub) = match k.strip_suffix("-bg") {
        Some(k) => (k, true),
        None => (k, false),
    };
    let kind = BaselineKind::parse(k)
        .with_context(|| format!("--rust-descriptor {d:?}: unknown kind {k:?}"))?;
    ensure!(
        (16..=240).contains(&crop) && crop.is_multiple_of(2),
        "--rust-descriptor {d:?}: the crop must be even, 16 to 240"
    );
    Ok(telextiles_lab::methods::Method::Rust {
        base: Baseline { kind, bgsub },
        crop,
    })
}

fn mstats_scale(a: MstatsScaleArgs) -> Result<()> {
    let sc = telextiles_lab::mstats::scale_of_presses(&a.presses, a.every)?;
    println!("frames: {} of {} presses", sc.frames, sc.presses);
    println!("CENTRE: {:.4?}", sc.centre);
    println!("SPREAD: {:.4?}", sc.spread);
    println!(
        "spectrum (L2-normalised): mean per-value spread {:.5}",
        sc.spectrum_spread
    );
    Ok(())
}

fn export_descriptor(a: ExportDescriptorArgs) -> Result<()> {
    use telextiles_lab::baselines::BaselineKind;
    use telextiles_lab::graph::{descriptor_model, DescriptorSpec};
    let kind = match BaselineKind::parse(&a.kind) {
        Some(
            k @ (BaselineKind::Fft
            | BaselineKind::Pixels
            | BaselineKind::WSpec
            | BaselineKind::WSpecCw),
        ) => k,
        _ => bail!(
            "--kind {:?}: expected fft, wspec, wspec-cw or pixels",
            a.kind
        ),
    };
    let spec = DescriptorSpec {
        kind,
        crop: a.crop,
        input: a.input.unwrap_or(a.crop),
        subtract: a.subtract,
        min_bin: a.min_bin,
        taper: a.taper,
    };
    let bytes = descriptor_model(&spec)?;
    // Load it back through ONNX Runtime (the contract checks) before writing.
    let enc = OrtEncoder::from_bytes(&bytes, 1)?;
    ensure!(enc.dim == spec.dim(), "descriptor dimension mismatch");
    write_atomic(&a.out, &bytes)?;
    use sha2::Digest;
    println!(
        "wrote {} ({}, {} bytes, sha256 {}, {}-d)",
        a.out.display(),
        spec.arch(),
        bytes.len(),
        telextiles_lab::data::hex(&sha2::Sha256::digest(&bytes)),
        spec.dim()
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_contact_detectors_run_times_are_set_from_the_command_line() {
        use clap::Parser;
        let study = |extra: &[&str]| {
            let mut args = vec![
                "telextiles-lab",
                "bench",
                "--source",
                "presses:x",
                "--out",
                "o",
            ];
            args.extend_from_slice(extra);
            let super::Cmd::Bench(b) = super::Cli::try_parse_from(args).unwrap().cmd else {
                panic!("bench")
            };
            b.recorded.study(std::path::Path::new("x")).unwrap().contact
        };
        let daemon = telextiles_sensing::contact::ContactConfig::default();
        assert_eq!(study(&[]), daemon);
        let c = study(&["--contact-enter-ms", "0", "--contact-exit-ms", "0"]);
        assert_eq!((c.enter_ms, c.exit_ms), (0.0, 0.0));
        assert_eq!(c.min_enter_frames, daemon.min_enter_frames);
        let c = study(&["--contact-exit-ms", "0"]);
        assert_eq!((c.enter_ms, c.exit_ms), (daemon.enter_ms, 0.0));
        assert!(super::Cli::try_parse_from([
            "telextiles-lab",
            "bench",
            "--source",
            "presses:x",
            "--out",
            "o",
            "--contact-enter-ms",
            "-1",
        ])
        .is_err());
        assert!(super::Cli::try_parse_from([
            "telextiles-lab",
            "bench",
            "--source",
            "sim",
            "--out",
            "o",
            "--contact-enter-ms",
            "0",
        ])
        .map(|c| match c.cmd {
            super::Cmd::Bench(b) => b.recorded.refuse_unless_presses().is_err(),
            _ => false,
        })
        .unwrap());
    }

    #[test]
    fn decider_switch_reproduces_the_committed_pick_which_is_the_shipped_rule() {
        use std::path::Path;
        use telextiles_lab::decider_timing as dt;
        let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/bench-v2");
        let studies = vec![
            docs.join("decider-v1/timing.json"),
            docs.join("decider-v2/timing.json"),
        ];
        assert_decider_switch_reproduces(&studies, &docs.join("decider-switch.md"));
        let dir = tempfile::tempdir().unwrap();
        // The pick is what the daemon ships.
        let reports: Vec<dt::TimingReport> = studies.iter().map(|p| dt::read(p).unwrap()).collect();
        let (_, i) = dt::choose_switch_across(&reports).unwrap();
        let pick = reports[0].switch_candidates[i];
        let d = telextiles_sensing::decide::DecideConfig::default();
        assert_eq!(
            (pick.switch_margin, pick.switch_ms, pick.switch_backoff),
            (d.switch_margin, d.switch_ms, d.switch_backoff)
        );
        // A file that is not a study, or is missing: an error naming it,
        // and nothing written.
        let bad = dir.path().join("bad.json");
        std::fs::write(&bad, b"{}").unwrap();
        for f in [bad, dir.path().join("missing.json")] {
            let out = dir.path().join("not-written.md");
            let e = super::decider_switch(super::DeciderSwitchArgs {
                timing: vec![studies[0].clone(), f.clone()],
                out: Some(out.clone()),
            })
            .unwrap_err();
            assert!(format!("{e:#}").contains(&*f.to_string_lossy()), "{e:#}");
            assert!(!out.exists());
        }
    }

    /// `decider-switch` over `studies` writes `committed`, but for its
    /// first lines (the command).
    fn assert_decider_switch_reproduces(
        studies: &[std::path::PathBuf],
        committed: &std::path::Path,
    ) {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("across.md");
        super::decider_switch(super::DeciderSwitchArgs {
            timing: studies.to_vec(),
            out: Some(out.clone()),
        })
        .unwrap();
        let body = |p: &std::path::Path| {
            let s = std::fs::read_to_string(p).unwrap();
            s.lines().skip(3).collect::<Vec<_>>().join("\n")
        };
        assert_eq!(body(&out), body(committed));
    }

    /// The studies with the early-commit margins (docs/benchmarks.md "An
    /// early first decision when the leader is clear"): `decider-switch`
    /// reproduces the committed `across.md` (both catalogues, generator 1:
    /// the rule's choice) and `across-generators.md` (with generator 2's
    /// presses, the check), and both rules pick what the daemon ships in
    /// each.
    #[test]
    fn decider_switch_reproduces_the_committed_timing_pick_which_is_the_shipped_timing() {
        use std::path::Path;
        use telextiles_lab::decider_timing as dt;
        let docs =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/bench-v2/decider-commit-margin");
        let choice = vec![docs.join("v1/timing.json"), docs.join("v2/timing.json")];
        let mut check = choice.clone();
        check.push(docs.join("v2-generator2/timing.json"));
        for (studies, committed) in [(choice, "across.md"), (check, "across-generators.md")] {
            assert_decider_switch_reproduces(&studies, &docs.join(committed));
            let reports: Vec<dt::TimingReport> =
                studies.iter().map(|p| dt::read(p).unwrap()).collect();
            let (_, i) = dt::choose_timing_across(&reports).unwrap();
            assert_eq!(
                reports[0].candidates[i],
                dt::Timing::shipped(),
                "{committed}"
            );
            let (_, i) = dt::choose_switch_across(&reports).unwrap();
            let pick = reports[0].switch_candidates[i];
            let d = telextiles_sensing::decide::DecideConfig::default();
            assert_eq!(
                (pick.switch_margin, pick.switch_ms, pick.switch_backoff),
                (d.switch_margin, d.switch_ms, d.switch_backoff),
                "{committed}"
            );
        }
    }

    #[test]
    fn rust_descriptors_are_named_kind_bg_at_crop() {
        use telextiles_lab::baselines::{Baseline, BaselineKind};
        use telextiles_lab::methods::Method;
        let m = super::rust_descriptor("wspec-m2-bg@240").unwrap();
        let Method::Rust { base, crop } = m else {
            panic!("not a Rust method")
        };
        assert_eq!(
            (base, crop),
            (
                Baseline {
                    kind: BaselineKind::WSpecM(2),
                    bgsub: true
                },
                240
            )
        );
        let Method::Rust { base, crop } = super::rust_descriptor("lbp@64").unwrap() else {
            panic!("not a Rust method")
        };
        assert_eq!(
            (base.kind, base.bgsub, crop),
            (BaselineKind::Lbp, false, 64)
        );
        for bad in [
            "nope@240",
            "wspec-bg",
            "wspec@241",
            "wspec@abc",
            "wspec-m@240",
            "wspec@8",
        ] {
            let e = super::rust_descriptor(bad).err().unwrap().to_string();
            assert!(e.contains(bad), "{bad}: {e}");
        }
    }

    #[test]
    fn the_command_line_is_well_formed() {
        use clap::CommandFactory;
        super::Cli::command().debug_assert();
    }
}
