//! `telextilesd index build|inspect`: make and look at the textile index.

use anyhow::{bail, Context, Result};
use clap::{Args as ClapArgs, Subcommand};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use telextiles_index::build::{MetricFit, Paired, SelfCheck};
use telextiles_index::Features;
use telextiles_index::{Index, IndexBuilder, SelectionMethod, TextileRecord};
use telextiles_progress::Progress;
use telextiles_recording::Press;
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sensing::front::{FrontEnd, References};
use telextiles_sensing::pipeline::{Deepest, PARTIAL_COVERAGE};

use crate::index_choice::*;
use crate::index_sim::{Books, Catalogue, SimSet};

/// `telextilesd index ...`
#[derive(Subcommand, Debug)]
pub enum Args {
    /// Build an index from recorded presses (or from simulated ones).
    Build(BuildArgs),
    /// Print an index file's contents and fingerprint.
    Inspect(InspectArgs),
    /// Check how well your presses tell your fabrics apart, with one model
    /// or several: each press left out and decided against an index of the
    /// others; with several, which model to use on your sensor.
    Check(CheckArgs),
}

/// `telextilesd index check`
#[derive(ClapArgs, Debug)]
pub struct CheckArgs {
    /// ONNX encoder to check (repeat it to compare): the first is the one
    /// in use, and another is recommended only when it is right on more of
    /// your presses by two standard errors of the paired difference.
    #[arg(long = "model", required = true)]
    pub models: Vec<PathBuf>,
    /// Directory of recorded presses, as for `index build --presses`
    /// (press directories, or a PyTouch-style dataset).
    #[arg(long)]
    pub presses: PathBuf,
    /// The sensor's no-contact frame, as for `index build --reference`.
    #[arg(long = "reference", value_name = "[SERIAL=]PNG")]
    pub references: Vec<String>,
    /// Frame rate of recordings saved without timestamps, as for `index
    /// build --fps`.
    #[arg(long, value_parser = telextiles_recording::recording::parse_fps)]
    pub fps: Option<f32>,
    /// One centroid per textile only (as `index build --no-exemplars`).
    #[arg(long)]
    pub no_exemplars: bool,
    /// Plain cosine distance (as `index build --no-metric`).
    #[arg(long)]
    pub no_metric: bool,
    /// How the distance is fitted, as for `index build --fit` [default:
    /// auto, every fit shown].
    #[arg(long, value_enum)]
    pub fit: Option<FitArg>,
    /// What the queries are made of, as for `index build --features`
    /// [default: auto, every kind shown].
    #[arg(long, value_enum)]
    pub features: Option<FeaturesArg>,
    /// Shrinkage of the learned distance towards plain cosine (0..=1), as
    /// for `index build`.
    #[arg(long, value_parser = parse_shrinkage)]
    pub metric_shrinkage: Option<f32>,
    /// Use every n-th contact frame.
    #[arg(long, default_value_t = 1)]
    pub stride: usize,
    /// Encoder threads.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
    /// Check presses of several sensor profiles together (as `index build
    /// --mix-sensors`).
    #[arg(long)]
    pub mix_sensors: bool,
    #[command(flatten)]
    pub contact: crate::config::ContactArgs,
    #[command(flatten)]
    pub sensor_opts: crate::config::SensorArgs,
}

/// `telextilesd index build`
#[derive(ClapArgs, Debug)]
pub struct BuildArgs {
    /// The ONNX encoder the index is for.
    #[arg(long)]
    pub model: PathBuf,
    /// Directory of recorded presses (each a folder with press.json and
    /// frames), searched recursively, or a PyTouch-style dataset
    /// (`<class>/<serial>/*.png` or `.jpg`, one recording per sequence); presses are
    /// grouped by textile id (the class).
    #[arg(long, conflicts_with = "sim")]
    pub presses: Option<PathBuf>,
    /// The sensor's no-contact frame (an RGB PNG or JPEG of the frames'
    /// geometry, taken with nothing touching the gel), for recordings that carry no reference (PyTouch
    /// data) and whose first frames are already in contact: `PNG` for
    /// every sensor, `SERIAL=PNG` for one (repeat it). A recording's own
    /// reference always wins.
    #[arg(long = "reference", value_name = "[SERIAL=]PNG", requires = "presses")]
    pub references: Vec<String>,
    /// Frame rate of recordings saved without timestamps (PyTouch-style
    /// datasets) [default: the DIGIT's stream rate at the frames' size:
    /// 60 fps for 240x320 or 320x240, 30 for VGA]. Refused for press
    /// directories, which carry their own timestamps.
    #[arg(long, value_parser = telextiles_recording::recording::parse_fps, requires = "presses")]
    pub fps: Option<f32>,
    /// Use simulated presses of the built-in catalogue instead.
    #[arg(long)]
    pub sim: bool,
    /// The simulator catalogue (1 or 2, docs/simulator.md) whose presses
    /// --sim renders and whose textile ids (T001.., U01..) give names,
    /// structures and attributes; recordings of catalogue-2 presses
    /// (`telextiles-lab sim-presses --catalogue 2`) need 2 too.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=2))]
    pub catalogue: u32,
    /// Simulated people (0..N) whose presses build the index (with --sim).
    #[arg(long, default_value_t = 3)]
    pub people: u32,
    /// Simulated sensor units every person presses with (with --sim):
    /// several units make the index hold up on a DIGIT it has not seen.
    #[arg(long, value_delimiter = ',', default_value = "0,1,2,3")]
    pub sensors: Vec<u32>,
    /// Also index the unseen sample book (with --sim; off by default, so
    /// that unseen textiles stay unknown to the index).
    #[arg(long)]
    pub include_unseen: bool,
    /// Keep every press's mean embedding as an exemplar (a textile is then
    /// as near as its nearest press: different presses of a fabric see
    /// different cloth). The default with --presses (your own recordings);
    /// off by default with --sim.
    #[arg(long, conflicts_with = "no_exemplars")]
    pub exemplars: bool,
    /// One centroid per textile only, also with --presses.
    #[arg(long)]
    pub no_exemplars: bool,
    /// Learn a distance from the presses' means: how presses of one fabric
    /// differ (place on the cloth, hand, sensor unit) on your sensor counts
    /// less than how fabrics differ (within-fabric whitening; needs two or
    /// more presses of some fabric), as --fit press-means.
    #[arg(long, conflicts_with = "no_metric")]
    pub metric: bool,
    /// Plain cosine distance, also with --presses.
    #[arg(long)]
    pub no_metric: bool,
    /// How the distance is fitted [default: cosine, plain; with --metric
    /// or --metric-shrinkage: press-means]. `auto`: the fit that decides
    /// the most of your presses right, each left out in turn (`index
    /// check` shows every candidate on your presses).
    #[arg(long, value_enum)]
    pub fit: Option<FitArg>,
    /// What the index's queries are made of [default: encoder]. `auto`:
    /// chosen on your presses with the fit. Recorded in the index: both
    /// daemons of a session compute it.
    #[arg(long, value_enum)]
    pub features: Option<FeaturesArg>,
    /// Shrinkage of the learned distance towards plain cosine (0..=1; 1 is
    /// plain cosine) [default: 0.5 for press means, the Ledoit-Wolf
    /// estimate for frames]. With --presses and no --fit it asks for press
    /// means at that shrinkage, as before fits on frames.
    #[arg(long, value_parser = parse_shrinkage)]
    pub metric_shrinkage: Option<f32>,
    /// Calibrate the distance beyond which a press is of a fabric the index
    /// does not have on the presses themselves (how far each of your
    /// presses is from its fabric, with it left out; needs 4 such presses).
    /// The default with --presses; off by default with --sim, whose index
    /// keeps the decider's fixed distance.
    #[arg(long, conflicts_with = "no_calibrate_unknown")]
    pub calibrate_unknown: bool,
    /// Keep the decider's fixed unknown-textile distance, also with
    /// --presses.
    #[arg(long)]
    pub no_calibrate_unknown: bool,
    /// The share of your own presses that must count as known (0 < Q <= 1):
    /// higher flags fewer presses of known fabrics, and fewer of fabrics
    /// the index does not have.
    #[arg(long, default_value_t = telextiles_index::build::DEFAULT_UNKNOWN_QUANTILE, value_parser = telextiles_index::build::parse_quantile)]
    pub unknown_quantile: f32,
    /// Use every n-th contact frame [default: every frame with --presses,
    /// every 4th with --sim].
    #[arg(long)]
    pub stride: Option<usize>,
    /// Roller slots [default: 16, or the number of textiles when fewer].
    #[arg(long)]
    pub slots: Option<usize>,
    /// Roller selection: umap1d (the paper), farthest, kmedoids, random.
    #[arg(long, default_value = "kmedoids")]
    pub method: SelectionMethod,
    /// Seed of the map layout.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Encoder threads.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Output file.
    #[arg(long, short, default_value = "models/index.tlxi")]
    pub out: PathBuf,
    /// Build one index from presses of several sensor profiles (a DIGIT's
    /// and a GelSight Mini's, say): refused without it, as a fabric looks
    /// different through another sensor. The index then takes frames of
    /// any of them.
    #[arg(long, requires = "presses")]
    pub mix_sensors: bool,
    #[command(flatten)]
    pub contact: crate::config::ContactArgs,
    #[command(flatten)]
    pub sensor_opts: crate::config::SensorArgs,
}

/// `telextilesd index inspect`
#[derive(ClapArgs, Debug)]
pub struct InspectArgs {
    /// The index file.
    pub file: PathBuf,
    /// Check that the index matches this ONNX encoder.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Print JSON.
    #[arg(long)]
    pub json: bool,
}

pub fn run(args: Args) -> Result<()> {
    match args {
        Args::Build(a) => build(a),
        Args::Inspect(a) => inspect(a),
        Args::Check(a) => check(a),
    }
}

fn open_encoder(model: &Path, threads: usize) -> Result<Encoder> {
    Encoder::open(
        model,
        &EncoderOptions {
            threads,
            ..Default::default()
        },
    )
    .with_context(|| format!("cannot load the encoder {}", model.display()))
}

/// `index check`: the self-check of `index build --presses` for each model,
/// on the same presses, and the model to use by the paired rule.
fn check(a: CheckArgs) -> Result<()> {
    let sensors = Sensors {
        given: a.sensor_opts.sensor()?,
        mix: a.mix_sensors,
    };
    let mut references = References::from_args_as(&a.references, sensors.given)?;
    references.add_beside(&a.presses)?;
    let asked_features = features_asked(a.features, None);
    let computed = features_computed(asked_features);
    let mut fronts = Vec::new();
    let mut encoder_dims = Vec::new();
    for m in &a.models {
        let mut enc = open_encoder(m, a.threads)?;
        encoder_dims.push(enc.dim());
        enc.set_features(computed);
        fronts.push(FrontEnd::new(enc, a.contact.contact()?, None));
    }
    let embedded = embed_recordings(
        &mut fronts,
        &a.presses,
        &references,
        a.fps,
        sensors,
        a.stride,
        "index check",
    )?;
    let ids: Vec<String> = embedded.by_textile[0].keys().cloned().collect();
    if ids.is_empty() {
        return Err(none_in_contact(&a.presses, "check"));
    }
    let exemplars = !a.no_exemplars;
    let asked = metric_fit(
        a.no_metric,
        false,
        a.fit,
        a.metric_shrinkage,
        MetricFit::Auto,
    );
    // Per model: every (features, fit) checked on the same presses, and
    // the chosen one.
    let per_model: Vec<Choice> = embedded
        .by_textile
        .iter()
        .zip(&encoder_dims)
        .map(|(by_textile, &dim)| {
            Choice::of(
                by_textile,
                &ids,
                computed,
                asked_features,
                asked,
                exemplars,
                dim,
            )
        })
        .collect();
    let left: Vec<&[telextiles_index::build::LeftOut]> =
        per_model.iter().map(|c| c.fit().left.as_slice()).collect();
    let checks: Vec<SelfCheck> = left.iter().map(|l| SelfCheck::of(l)).collect();
    if checks[0].presses == 0 {
        bail!(
            "no fabric under {} has two presses with contact: a press can only be checked against other presses of its fabric (press each fabric twice or more)",
            a.presses.display()
        );
    }
    let paired: Vec<Option<Paired>> = (0..left.len())
        .map(|k| (k > 0).then(|| Paired::of(left[0], left[k])))
        .collect();
    let choice = choose_model(&checks, &paired);
    let id = |i: usize| ids.get(i).map_or("?", String::as_str);
    let mut out = crate::out::stdout();
    if a.json {
        let models: Vec<serde_json::Value> = a
            .models
            .iter()
            .zip(&checks)
            .zip(&paired)
            .zip(&per_model)
            .map(|(((m, c), p), choice)| {
                serde_json::json!({
                    "model": m.display().to_string(),
                    "presses": c.presses,
                    "right": c.right,
                    "share": share(c),
                    "features": choice.features().label(),
                    "fit": choice.fit().fit.label(),
                    "fits": choice.checks.iter().map(|(k, f)| serde_json::json!({
                        "features": k.label(), "fit": f.fit.label(),
                        "presses": f.left.len(), "right": f.right(),
                    })).collect::<Vec<_>>(),
                    "confusions": c.confusions.iter().map(|&(f, d, n)| serde_json::json!({
                        "fabric": id(f), "as": id(d), "presses": n,
                    })).collect::<Vec<_>>(),
                    "against_first": p.map(|p| serde_json::json!({
                        "presses": p.presses,
                        "right_only_first": p.first_only,
                        "right_only_this": p.second_only,
                        "ahead": p.second_ahead(),
                    })),
                })
            })
            .collect();
        let v = serde_json::json!({
            "recordings": embedded.presses,
            "fabrics": ids.len(),
            "exemplars": exemplars,
            "fit": asked.label(),
            "features": asked_features.map_or("chosen on the presses", Features::label),
            "models": models,
            "choice": a.models[choice].display().to_string(),
            "partial": embedded.partial.iter().map(|(d, c)| serde_json::json!({
                "recording": d.display().to_string(), "coverage": c,
            })).collect::<Vec<_>>(),
        });
        writeln!(out, "{v}")?;
        return Ok(());
    }
    writeln!(
        out,
        "self-check of {} presses of {} fabrics: each left out and decided against an index of the other presses ({}, features {}, distance {})",
        checks[0].presses,
        ids.len(),
        if exemplars { "centroids and presses" } else { "centroids only" },
        asked_features.map_or("chosen on the presses", Features::label),
        asked.label(),
    )?;
    for (k, m) in a.models.iter().enumerate() {
        let c = &checks[k];
        let choice = &per_model[k];
        let mut line = format!(
            "  {}: {} of {} right ({:.1} %) with {}",
            m.display(),
            c.right,
            c.presses,
            100.0 * share(c),
            choice.label()
        );
        if let Some(p) = paired[k] {
            line += &format!(
                "; against the first, right on {} it missed and missed {} it got",
                p.second_only, p.first_only
            );
        }
        line += &confusions_text(c, &id);
        writeln!(out, "{line}")?;
        if choice.checks.len() > 1 {
            writeln!(out, "{}", fits_text(&choice.checks, choice.chosen))?;
        }
    }
    if a.models.len() > 1 {
        if choice == 0 {
            writeln!(
                out,
                "choice: keep {}: no other model is right on more of these presses by two standard errors of the paired difference",
                a.models[0].display()
            )?;
        } else {
            writeln!(
                out,
                "choice: {}: right on more of these presses than {} by two standard errors of the paired difference or more; use it on both sides of a session (`model`) and build the index with it",
                a.models[choice].display(),
                a.models[0].display()
            )?;
        }
    }
    if let Some(note) = partial_note(&embedded.partial, embedded.presses) {
        eprintln!("{note}");
    }
    Ok(())
}

/// Share of a self-check's presses decided right.
fn share(c: &SelfCheck) -> f64 {
    c.right as f64 / c.presses.max(1) as f64
}

/// Which of the checked models to use: the first (the one in use) unless
/// another is right on more of the same presses by two standard errors of
/// the paired difference (`paired[k]`: model k against the first); of
/// those, the one right on the largest share.
fn choose_model(checks: &[SelfCheck], paired: &[Option<Paired>]) -> usize {
    (1..checks.len().min(paired.len()))
        .filter(|&k| paired[k].is_some_and(|p| p.second_ahead()))
        .max_by(|&x, &y| share(&checks[x]).total_cmp(&share(&checks[y])))
        .unwrap_or(0)
}

/// Embeddings of the in-contact frames of a press (every `stride`-th),
/// through the same front end as the live session and `classify`, reset
/// for this press with its own no-contact reference (the quiet frames it
/// starts with; captured from its first steady frames where it does not say).
pub fn press_embeddings(
    front: &mut FrontEnd,
    press: &Press,
    stride: usize,
) -> Result<Vec<Vec<f32>>> {
    let reference = telextiles_sensing::front::recording_reference(press);
    Ok(embeddings_with(front, press, reference.as_deref(), stride)?.0)
}

/// [`press_embeddings`] with the reference to replay the press with
/// (`References::for_press`; None: captured from its first steady frames),
/// and how much of the gel the press touched: its deepest frame's coverage
/// (None when it was never in contact), as `classify` reports it.
fn embeddings_with(
    front: &mut FrontEnd,
    press: &Press,
    reference: Option<&[f32]>,
    stride: usize,
) -> Result<(Vec<Vec<f32>>, Option<f32>)> {
    front.reset(reference);
    let mut out = Vec::new();
    let mut deepest = Deepest::default();
    let mut k = 0usize;
    for (i, (image, &t)) in press
        .frames
        .iter()
        .zip(&press.meta.timestamps_us)
        .enumerate()
    {
        let frame = telextiles_sensing::frame::Frame::new(image.clone(), t, i as u64)?;
        let o = front.process(&frame)?;
        if o.contact.in_contact {
            deepest.add(o.contact.depth, o.contact.coverage);
        }
        let earlier = o.earlier.iter().map(|e| e.embedding.as_slice());
        for e in earlier.chain(o.embedding) {
            if k.is_multiple_of(stride.max(1)) {
                out.push(e.to_vec());
            }
            k += 1;
        }
    }
    Ok((out, deepest.coverage()))
}

fn record(
    cat: &Catalogue,
    id: &str,
    name: Option<&str>,
    embeddings: Vec<Vec<f32>>,
    exemplars: Vec<Vec<f32>>,
) -> TextileRecord {
    // A user's own fabric: seen by definition; its name from `telextilesd
    // record --name` (textile.json), else its id. A catalogue textile: as
    // the catalogue describes it.
    let mut r = TextileRecord {
        id: id.to_string(),
        name: name.unwrap_or(id).to_string(),
        seen: true,
        structure: String::new(),
        attributes: Vec::new(),
        embeddings,
        exemplars,
        press_frames: Vec::new(),
    };
    cat.describe(&mut r);
    r
}

/// How well the index tells the owner's fabrics apart: its presses, each
/// left out of it and decided against the others (as `classify` decides a
/// press at its end), and the fabrics most often taken for others.
fn self_check_line(index: &Index, left: &[telextiles_index::build::LeftOut]) -> String {
    let check = SelfCheck::of(left);
    if check.presses == 0 {
        return "self-check: no fabric has two presses with contact, so the index cannot be checked against presses it does not hold".into();
    }
    let id = |i: usize| index.entries.get(i).map_or("?", |e| e.id.as_str());
    format!(
        "self-check: {} of {} presses ({:.1} %) decided as their own fabric by an index of the other presses{}",
        check.right,
        check.presses,
        100.0 * share(&check),
        confusions_text(&check, &id)
    )
}

/// A press's frame embeddings and their mean into its textile's entry
/// (nothing for a press never in contact).
fn add_press(
    by_textile: &mut BTreeMap<String, FrameAndPressEmbeddings>,
    id: &str,
    embs: Vec<Vec<f32>>,
) {
    if embs.is_empty() {
        return;
    }
    let slot = by_textile.entry(id.to_string()).or_default();
    slot.1.push(mean(&embs));
    slot.0.push(embs);
}

/// The recordings under a directory, embedded by each front end (one per
/// model; each recording is read once).
struct Embedded {
    /// Per front end: textile id -> (each press's frame embeddings, each
    /// press's mean).
    by_textile: Vec<BTreeMap<String, FrameAndPressEmbeddings>>,
    /// Names of the owner's fabrics (`telextilesd record --name`).
    names: BTreeMap<String, String>,
    /// Recordings read.
    presses: usize,
    /// Recordings in contact that touched less than [`PARTIAL_COVERAGE`]
    /// of the gel (the first front end's detector, shared by all), with
    /// their coverage, in the order read.
    partial: Vec<(PathBuf, f32)>,
    /// The sensor profile of the recordings, as an index records it
    /// ([`telextiles_index::Index::sensor`]).
    sensor: Option<String>,
}

/// Where the recordings' frames come from and whether several sensor
/// profiles may be mixed.
#[derive(Clone, Copy, Debug, Default)]
struct Sensors {
    /// Given for recordings that do not say (PyTouch sequences).
    given: Option<telextiles_recording::recording::Sensor>,
    /// Several profiles may be mixed (`--mix-sensors`).
    mix: bool,
}

/// The sensor an index of `recordings` records: None for a DIGIT's, the
/// profile's name, or `mixed:<a>+<b>` when told to mix them; presses of
/// several profiles unmixed are refused, naming each with a recording.
fn sensor_of(
    recordings: &[telextiles_recording::recording::Recording],
    mix: bool,
) -> Result<Option<String>> {
    let profiles = telextiles_recording::recording::profiles(recordings)?;
    let names: Vec<&str> = profiles.keys().copied().collect();
    match names.as_slice() {
        [] => Ok(None),
        [one] => Ok((*one != telextiles_recording::profile::DIGIT.name).then(|| one.to_string())),
        _ if mix => Ok(Some(format!("mixed:{}", names.join("+")))),
        _ => bail!(
            "these presses come from {} sensor profiles: {}. A fabric looks different through another sensor's gel, light and camera, so an index takes one sensor's presses; give each sensor its own index, or say --mix-sensors to build one from all",
            names.len(),
            profiles
                .iter()
                .map(|(p, first)| format!("{p} (e.g. {})", first.display()))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Read every recording under `root` (the walk every command shares) and
/// embed its frames in contact with each front end; a recording never in
/// contact is named in a warning.
fn embed_recordings(
    fronts: &mut [FrontEnd],
    root: &Path,
    references: &References,
    fps: Option<f32>,
    sensors: Sensors,
    stride: usize,
    what: &str,
) -> Result<Embedded> {
    let mut recordings = telextiles_recording::recording::find_recordings_at(root, fps)?;
    telextiles_recording::recording::assume_sensor(&mut recordings, sensors.given)?;
    let sensor = sensor_of(&recordings, sensors.mix)?;
    let progress = Progress::new(what, recordings.len() as u64, "presses");
    let mut out = Embedded {
        by_textile: vec![BTreeMap::new(); fronts.len()],
        names: BTreeMap::new(),
        presses: 0,
        partial: Vec::new(),
        sensor,
    };
    for rec in recordings {
        let d = rec.path();
        let press = rec.load()?;
        if let Some(name) = textile_name(&d, &press.meta.textile) {
            out.names.insert(press.meta.textile.clone(), name);
        }
        let reference = references.for_press(&press);
        for (k, front) in fronts.iter_mut().enumerate() {
            let (embs, coverage) = embeddings_with(front, &press, reference.as_deref(), stride)?;
            // Contact is the front end's detector's, the same for every
            // model: warn once, note once.
            if embs.is_empty() && k == 0 {
                progress.println(&format!(
                    "warning: {}: no contact detected, press skipped{}",
                    d.display(),
                    telextiles_sensing::front::no_reference_hint(reference.is_some())
                ));
            }
            let partial = coverage.filter(|&c| k == 0 && c < PARTIAL_COVERAGE && !embs.is_empty());
            if let Some(c) = partial {
                out.partial.push((d.clone(), c));
            }
            add_press(&mut out.by_textile[k], &press.meta.textile, embs);
        }
        out.presses += 1;
        progress.inc(1);
    }
    progress.finish();
    Ok(out)
}

/// The error when no recording under `root` was in contact.
fn none_in_contact(root: &Path, to: &str) -> anyhow::Error {
    anyhow::anyhow!(
        "no press under {} was seen in contact: nothing to {to} (see the warnings above)",
        root.display()
    )
}

/// Recordings named in full in [`partial_note`]; the rest are counted.
const PARTIAL_NAMED: usize = 10;

/// The note on presses that touched less than [`PARTIAL_COVERAGE`] of the
/// gel (None when there are none): `index build --presses` and `index
/// check` keep them, as the live daemon decides such presses too, but an
/// owner building an index wants to know which to press again.
fn partial_note(partial: &[(PathBuf, f32)], presses: usize) -> Option<String> {
    if partial.is_empty() {
        return None;
    }
    let mut named: Vec<String> = partial
        .iter()
        .take(PARTIAL_NAMED)
        .map(|(d, c)| format!("{} ({:.0} %)", d.display(), 100.0 * c))
        .collect();
    if partial.len() > PARTIAL_NAMED {
        named.push(format!("and {} more", partial.len() - PARTIAL_NAMED));
    }
    Some(format!(
        "note: {} of {presses} presses touched less than {:.0} % of the gel (partial contact: held tilted?): {}. They are kept, but a partial press shows the encoder less cloth and is decided right less often; press those fabrics again with the sensor flat on them (docs/recording.md)",
        partial.len(),
        100.0 * PARTIAL_COVERAGE,
        named.join(", ")
    ))
}

fn mean(vs: &[Vec<f32>]) -> Vec<f32> {
    let mut m = vec![0.0; vs[0].len()];
    for v in vs {
        m.iter_mut()
            .zip(v)
            .for_each(|(a, b)| *a += b / vs.len() as f32);
    }
    m
}

fn build(a: BuildArgs) -> Result<()> {
    let mut enc = open_encoder(&a.model, a.threads)?;
    let info = enc.info().clone();
    let asked_features = features_asked(a.features, Some(Features::Encoder));
    let computed = features_computed(asked_features);
    enc.set_features(computed);
    let mut front = FrontEnd::new(enc, a.contact.contact()?, None);
    let cat = Catalogue::open(a.catalogue)?;
    // textile id -> (each press's frame embeddings, each press's mean)
    let mut by_textile: BTreeMap<String, FrameAndPressEmbeddings> = BTreeMap::new();
    // Names of the user's own fabrics (`telextilesd record --name`).
    let mut names: BTreeMap<String, String> = BTreeMap::new();
    let presses;
    // The sensor profile of the presses (None: a DIGIT, the simulator's).
    let mut sensor = None;
    // The owner's presses that touched only part of the gel.
    let mut partial = Vec::new();
    if let Some(root) = &a.presses {
        // The sensors' no-contact frames kept at the top of the
        // recordings, or beside the index being written.
        let sensors = Sensors {
            given: a.sensor_opts.sensor()?,
            mix: a.mix_sensors,
        };
        let mut references = References::from_args_as(&a.references, sensors.given)?;
        references.add_beside(root)?;
        if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
            references.add_beside(dir)?;
        }
        let mut embedded = embed_recordings(
            std::slice::from_mut(&mut front),
            root,
            &references,
            a.fps,
            sensors,
            stride(&a),
            "index build",
        )?;
        sensor = embedded.sensor;
        by_textile = embedded.by_textile.remove(0);
        names = embedded.names;
        presses = embedded.presses;
        partial = embedded.partial;
        if by_textile.is_empty() {
            return Err(none_in_contact(root, "index"));
        }
    } else if a.sim {
        let books = if a.include_unseen {
            Books::Both
        } else {
            Books::Training
        };
        presses =
            crate::index_sim::for_each_press(&cat, &sim_set(&a), books, true, &mut |id, press| {
                let embs = press_embeddings(&mut front, press, stride(&a))?;
                add_press(&mut by_textile, id, embs);
                Ok(())
            })?;
    } else {
        bail!("say where the presses come from: --presses <dir> or --sim");
    }
    let asked_fit = build_fit(&a);
    // An owner's presses choose the features and the fit (each press left
    // out in turn); simulated ones take what is asked.
    let fit_start = std::time::Instant::now();
    let chooses = asked_features.is_none() || asked_fit == MetricFit::Auto;
    let choice = (a.presses.is_some() && chooses).then(|| {
        let ids: Vec<String> = by_textile.keys().cloned().collect();
        Choice::of(
            &by_textile,
            &ids,
            computed,
            asked_features,
            asked_fit,
            keep_exemplars(&a),
            info.dim,
        )
    });
    let (features, fit) = match &choice {
        Some(c) => (c.features(), c.fit().fit),
        None => (computed, asked_fit),
    };
    if features != computed {
        by_textile = textiles_as(&by_textile, features, computed, info.dim);
    }
    let dim = info.dim + features.extra_dim();
    let mut builder = IndexBuilder::new(&info.sha256, &info.arch, dim, cat.version);
    builder.features = features;
    builder.sensor = sensor;
    let slots = a.slots.unwrap_or_else(|| by_textile.len().min(16));
    builder.roller_n = slots;
    builder.method = a.method;
    builder.seed = a.seed;
    builder.keep_exemplars = keep_exemplars(&a);
    builder.metric = fit;
    builder.unknown_quantile = calibrate_unknown(&a).then_some(a.unknown_quantile);
    // Presses of fabrics pressed twice or more: what the unknown distance
    // is calibrated on.
    let pressed_twice: usize = by_textile
        .values()
        .map(|(_, means)| means.len())
        .filter(|&n| n >= 2)
        .sum();
    // Fabrics with few presses: an index press covers only the few
    // millimetres of cloth it touched (docs/benchmarks.md, "Where on the
    // cloth").
    let thin: Vec<String> = by_textile
        .iter()
        .filter(|(_, (_, means))| means.len() < RECOMMENDED_PRESSES)
        .map(|(id, (_, means))| format!("{id} ({})", means.len()))
        .collect();
    for (id, (frames, means)) in by_textile {
        let mut r = record(
            &cat,
            &id,
            names.get(&id).map(String::as_str),
            frames.iter().flatten().cloned().collect(),
            means,
        );
        r.press_frames = frames;
        builder.add(r)?;
    }
    // An index of the owner's presses checks itself: each press left out
    // and decided against the others.
    let report = if a.presses.is_some() {
        builder.build_report()?
    } else {
        // A simulated index checks nothing against itself.
        telextiles_index::build::BuildReport {
            index: builder.build()?,
            left: Vec::new(),
            fits: Vec::new(),
            chosen: 0,
        }
    };
    let (index, left) = (&report.index, &report.left);
    let fit_time = fit_start.elapsed();
    if let Some(dir) = a.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    }
    index.write(&a.out)?;
    writeln!(
        crate::out::stdout(),
        "wrote {} ({} textiles from {presses} presses, dim {} ({}), roller {} slots by {}, distance {}, unknown beyond {}, fingerprint {})",
        a.out.display(),
        index.entries.len(),
        index.dim,
        index.features.label(),
        index.roller.n(),
        index.roller.method,
        metric_summary(index),
        unknown_summary(index),
        &index.fingerprint()[..16]
    )?;
    if let Some(c) = choice.as_ref().filter(|c| c.checks.len() > 1) {
        writeln!(
            crate::out::stdout(),
            "features and distance chosen on your presses, each left out in turn with the fit made again without it (chosen and built in {:.1} s):\n{}",
            fit_time.as_secs_f64(),
            fits_text(&c.checks, c.chosen)
        )?;
    }
    if a.presses.is_some() {
        writeln!(crate::out::stdout(), "{}", self_check_line(index, left))?;
        if choice.is_none() {
            eprintln!(
                "note: `--fit auto --features auto` chooses a distance fitted on every frame of your presses, and texture features, by leaving each press out in turn; `index check` shows what each would do on your presses"
            );
        }
    }
    if a.presses.is_some() && !thin.is_empty() {
        eprintln!(
            "note: {} of {} fabrics have fewer than {RECOMMENDED_PRESSES} presses with contact: {}. A press tells the index only about the few millimetres of cloth it touched; press each fabric {RECOMMENDED_PRESSES} times or more, each at a different place (docs/recording.md)",
            thin.len(),
            index.entries.len(),
            thin.join(", ")
        );
    }
    if let Some(note) = partial_note(&partial, presses) {
        eprintln!("{note}");
    }
    if matches!(fit, MetricFit::PressMeans(_) | MetricFit::Frames(_)) && index.metric.is_none() {
        eprintln!(
            "note: no fabric has two presses with contact, so the index keeps plain cosine distance"
        );
    }
    if calibrate_unknown(&a) && index.unknown.is_none() {
        if pressed_twice < telextiles_index::build::MIN_CALIBRATION_PRESSES {
            eprintln!(
                "note: fewer than {} presses of fabrics pressed twice or more, so the index keeps the decider's fixed unknown-textile distance",
                telextiles_index::build::MIN_CALIBRATION_PRESSES
            );
        } else {
            eprintln!(
                "note: the calibration quantile of the presses' distances is 0 (presses identical to another press of their fabric: copies of one recording?), which says nothing about how far a new press may be, so the index keeps the decider's fixed unknown-textile distance"
            );
        }
    }
    // Unseen textiles (not in the index) as the roller has to cover them:
    // one jig press of each by each simulated person, mean embedding.
    let mut unseen = Vec::new();
    if a.sim && !a.include_unseen {
        crate::index_sim::for_each_press(&cat, &sim_set(&a), Books::Unseen, false, &mut |_, p| {
            unseen.extend(mean_normalised(&press_embeddings(
                &mut front,
                p,
                stride(&a),
            )?));
            Ok(())
        })?;
    }
    write!(
        crate::out::stdout(),
        "{}",
        coverage_report(index, &unseen, slots, a.seed)
    )?;
    Ok(())
}

/// The L2-normalised mean of L2-normalised vectors (None when empty).
fn mean_normalised(v: &[Vec<f32>]) -> Option<Vec<f32>> {
    let first = v.first()?;
    let mut m = vec![0.0f32; first.len()];
    for x in v {
        let n = x.iter().map(|a| a * a).sum::<f32>().sqrt().max(1e-12);
        m.iter_mut().zip(x).for_each(|(s, a)| *s += a / n);
    }
    telextiles_index::l2_normalise(&mut m);
    Some(m)
}

/// The name `telextilesd record --name` stored for textile `id` next to
/// its presses (`<out>/<id>/textile.json`), if any.
fn textile_name(press_dir: &std::path::Path, id: &str) -> Option<String> {
    let p = press_dir.parent()?.join("textile.json");
    let v: serde_json::Value = serde_json::from_slice(&std::fs::read(p).ok()?).ok()?;
    (v["id"] == id).then(|| v["name"].as_str().map(str::to_string))?
}

/// Presses per fabric below which `index build --presses` says the fabric
/// is thinly covered: the fewest index presses whose figure on simulated
/// cloth is within 5 points of sixteen's, for jig and hand-held queries
/// both (docs/benchmarks.md, "How many presses a fabric needs";
/// `docs/bench-v2/coverage`).
const RECOMMENDED_PRESSES: usize = 8;

/// The frame stride (see `--stride`): every frame of an owner's presses,
/// every 4th simulated one.
fn stride(a: &BuildArgs) -> usize {
    a.stride
        .unwrap_or(if a.presses.is_some() { 1 } else { 4 })
        .max(1)
}

/// The fit `index build` makes: as asked, else plain cosine, for an
/// owner's presses too (the rule of docs/studies/2026-12-04-fitted-metric.md,
/// written before its figures, on held-out simulated sets).
fn build_fit(a: &BuildArgs) -> MetricFit {
    metric_fit(
        a.no_metric,
        a.metric,
        a.fit,
        a.metric_shrinkage,
        MetricFit::Cosine,
    )
}

/// How the index measures distance, in words.
fn metric_summary(index: &Index) -> String {
    match &index.metric {
        Some(m) => format!(
            "learned from {} presses of {} fabrics (shrinkage {:.3})",
            m.presses, m.fabrics, m.shrinkage
        ),
        None => "cosine".into(),
    }
}

/// Whether the index calibrates its unknown-textile distance (see
/// `--calibrate-unknown`).
fn calibrate_unknown(a: &BuildArgs) -> bool {
    a.calibrate_unknown || (a.presses.is_some() && !a.no_calibrate_unknown)
}

/// Where the index's unknown textiles begin, in words.
fn unknown_summary(index: &Index) -> String {
    match index.unknown {
        Some(u) => format!(
            "{:.3} (calibrated: {:.0} % of {} presses of known fabrics within it)",
            u.distance,
            100.0 * u.quantile,
            u.presses
        ),
        None => format!(
            "{} (the decider's fixed distance)",
            telextiles_sensing::decide::DecideConfig::default().unknown_distance
        ),
    }
}

/// Whether the index keeps per-press exemplars (see `--exemplars`).
/// The simulated people and sensor units of `--sim`.
fn sim_set(a: &BuildArgs) -> SimSet {
    SimSet {
        people: a.people,
        sensors: a.sensors.clone(),
    }
}

fn keep_exemplars(a: &BuildArgs) -> bool {
    a.exemplars || (a.presses.is_some() && !a.no_exemplars)
}

/// Roller coverage of every selection method: mean and worst Euclidean
/// distance (of L2-normalised embeddings) from a textile (the index's centroids; the unseen presses) to
/// its nearest roller textile. `random` is the mean of 20 seeds.
pub fn coverage_report(index: &Index, unseen: &[Vec<f32>], slots: usize, seed: u64) -> String {
    use std::fmt::Write;
    use telextiles_index::select::{coverage, select};
    let pts: Vec<Vec<f32>> = index.entries.iter().map(|e| e.centroid.clone()).collect();
    // Unseen presses are encoder embeddings: into the index's space.
    let unseen: Vec<Vec<f32>> = unseen
        .iter()
        .filter(|u| u.len() == index.dim)
        .map(|u| index.project(u).into_owned())
        .collect();
    let unseen = &unseen[..];
    let slots = slots.min(pts.len());
    let mut out = String::new();
    let _ = writeln!(
        out,
        "roller coverage ({slots} slots; Euclidean distance between L2-normalised embeddings, to the nearest roller textile; {} indexed textiles, {} unseen presses)",
        pts.len(),
        unseen.len()
    );
    let _ = writeln!(
        out,
        "  method     indexed mean  indexed max  unseen mean  unseen max"
    );
    for m in [
        SelectionMethod::Umap1d,
        SelectionMethod::FarthestPoint,
        SelectionMethod::KMedoids,
        SelectionMethod::Random,
    ] {
        let runs: Vec<u64> = if m == SelectionMethod::Random {
            (0..20).map(|k| seed + k).collect()
        } else {
            vec![seed]
        };
        let (mut sm, mut sx, mut um, mut ux) = (0.0, 0.0, 0.0, 0.0);
        for &s in &runs {
            let chosen: Vec<Vec<f32>> = select(&pts, slots, m, s)
                .into_iter()
                .map(|i| pts[i].clone())
                .collect();
            let c = coverage(&pts, &chosen);
            let u = coverage(unseen, &chosen);
            sm += c.mean;
            sx += c.max;
            um += u.mean;
            ux += u.max;
        }
        let n = runs.len() as f32;
        let unseen_cols = if unseen.is_empty() {
            format!("{:>12} {:>11}", "-", "-")
        } else {
            format!("{:>12.4} {:>11.4}", um / n, ux / n)
        };
        let _ = writeln!(
            out,
            "  {:<10} {:>12.4} {:>12.4} {unseen_cols}",
            m.to_string(),
            sm / n,
            sx / n
        );
    }
    out
}

fn inspect(a: InspectArgs) -> Result<()> {
    let index = Index::read(&a.file)?;
    if let Some(model) = &a.model {
        let hash = telextiles_sensing::encoder::file_sha256(model)
            .with_context(|| format!("cannot read {}", model.display()))?;
        index.check_encoder(&hash)?;
    }
    let fp = index.fingerprint();
    let mut out = crate::out::stdout();
    if a.json {
        let v = serde_json::json!({
            "file": a.file,
            "fingerprint": fp,
            "encoder_hash": index.encoder_hash,
            "encoder_arch": index.encoder_arch,
            "dim": index.dim,
            "features": index.features.label(),
            "catalogue_version": index.catalogue_version,
            "metric": index.metric.as_ref().map(|m| serde_json::json!({
                "presses": m.presses, "fabrics": m.fabrics, "shrinkage": m.shrinkage,
            })),
            "unknown": index.unknown.map(|u| serde_json::json!({
                "distance": u.distance, "quantile": u.quantile, "presses": u.presses,
            })),
            "textiles": index.entries.iter().map(|e| serde_json::json!({
                "id": e.id, "name": e.name, "seen": e.seen, "structure": e.structure,
                "exemplars": e.exemplars.len(), "map": e.map_xy,
            })).collect::<Vec<_>>(),
            "roller": {
                "method": index.roller.method.to_string(),
                "slots": index.roller.slots.iter().map(|&i| &index.entries[i].id).collect::<Vec<_>>(),
            },
        });
        writeln!(out, "{v}")?;
        return Ok(());
    }
    writeln!(out, "index        {}", a.file.display())?;
    writeln!(out, "fingerprint  {fp}")?;
    writeln!(
        out,
        "encoder      {} ({})",
        index.encoder_hash, index.encoder_arch
    )?;
    writeln!(
        out,
        "dimension    {} ({})",
        index.dim,
        index.features.label()
    )?;
    writeln!(out, "catalogue    v{}", index.catalogue_version)?;
    writeln!(out, "distance     {}", metric_summary(&index))?;
    writeln!(out, "unknown      beyond {}", unknown_summary(&index))?;
    let seen = index.entries.iter().filter(|e| e.seen).count();
    writeln!(
        out,
        "textiles     {} ({} seen, {} unseen)",
        index.entries.len(),
        seen,
        index.entries.len() - seen
    )?;
    writeln!(
        out,
        "roller       {} slots, chosen by {}",
        index.roller.n(),
        index.roller.method
    )?;
    for (slot, &i) in index.roller.slots.iter().enumerate() {
        let e = &index.entries[i];
        writeln!(
            out,
            "  slot {slot:>2} {:>6.1} deg  {:<6} {}",
            slot as f32 * 360.0 / index.roller.n() as f32,
            e.id,
            e.name
        )?;
    }
    Ok(())
}

#[cfg(test)]
mod tests;
