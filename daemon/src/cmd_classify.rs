//! `telextilesd classify`: run the sensing pipeline (contact → encoder →
//! index → decision) on recorded or simulated presses and print, per press,
//! the decided textile, its roller slot, the time from contact to a stable
//! decision and per-stage timings.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::classify_felt::{Felts, PressFelt};
use anyhow::{bail, Context, Result};
use telextiles_index::Index;
use telextiles_sensing::encoder::{Encoder, EncoderOptions};
use telextiles_sensing::front::References;
use telextiles_sensing::pipeline::{run_source, Pipeline, PressReport, PARTIAL_COVERAGE};
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
#[cfg(feature = "sim")]
use telextiles_sensing::source::sim::SimSource;
#[cfg(feature = "sim")]
use telextiles_sim::PressSpec;

/// Options of `telextilesd classify`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Recorded press directory (or a tree of them, or a PyTouch-style
    /// dataset `<class>/<serial>/*.png` or `.jpg`); may be repeated.
    #[arg(long, required_unless_present = "sim")]
    pub press: Vec<PathBuf>,
    /// The sensor's no-contact frame (an RGB PNG or JPEG of the frames'
    /// geometry, taken with nothing touching the gel), for recordings that carry no reference (PyTouch
    /// data) and whose first frames are already in contact: `PNG` for
    /// every sensor, `SERIAL=PNG` for one (repeat it). A recording's own
    /// reference always wins.
    #[arg(
        long = "reference",
        value_name = "[SERIAL=]PNG",
        conflicts_with = "sim"
    )]
    pub references: Vec<String>,
    /// Frame rate of recordings saved without timestamps (PyTouch-style
    /// datasets) [default: the DIGIT's stream rate at the frames' size:
    /// 60 fps for 240x320 or 320x240, 30 for VGA]. Refused for press
    /// directories, which carry their own timestamps.
    #[arg(long, value_parser = telextiles_recording::recording::parse_fps, conflicts_with = "sim")]
    pub fps: Option<f32>,
    /// Simulate presses of this textile id instead (e.g. T030).
    #[arg(long, conflicts_with = "press")]
    pub sim: Option<String>,
    /// Seed of the first simulated press.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Simulated person.
    #[arg(long, default_value_t = 0)]
    pub person: u32,
    /// Simulated sensor unit.
    #[arg(long, default_value_t = 0)]
    pub sensor: u32,
    /// Simulated presses held by hand, without the jig.
    #[arg(long)]
    pub no_jig: bool,
    /// Number of simulated presses.
    #[arg(long, default_value_t = 1)]
    pub presses: u32,
    /// Replay at the recorded pace (60 fps) instead of as fast as possible.
    #[arg(long)]
    pub real_time: bool,
    /// Encoder (ONNX).
    #[arg(long, default_value = "models/encoder.onnx")]
    pub model: PathBuf,
    /// Textile index.
    #[arg(long, default_value = "models/index.tlxi")]
    pub index: PathBuf,
    /// Accept an index built with another encoder file.
    #[arg(long)]
    pub allow_encoder_mismatch: bool,
    /// Encoder threads.
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// One JSON object per press on its own line.
    #[arg(long)]
    pub json: bool,
    /// Also drive the simulated wheel through each press under this motion
    /// policy (`every`, `confident[:CONFIDENCE[:HOLD_MS]]`,
    /// `lead[:LEAD_MS]`; repeat to compare) and report the felt latency:
    /// contact -> the wheel at rest at the press's final sample, from every
    /// starting sample in turn [default: the daemon's policy].
    #[arg(long = "motion", value_name = "POLICY")]
    pub motions: Vec<telextiles_session::MotionPolicy>,
    /// The wheel's top speed, microsteps/s (the default is the paper's
    /// wheel's: 3 rev/s at 1/16 microstepping).
    #[arg(long, default_value_t = roller_firmware::DEFAULT_MAX_SPEED)]
    pub wheel_speed: u32,
    /// The wheel's acceleration, microsteps/s^2 (the default: 30 rev/s^2).
    #[arg(long, default_value_t = roller_firmware::DEFAULT_ACCEL)]
    pub wheel_accel: u32,
    /// Write the felt-latency summary of every policy to this JSON file.
    #[arg(long, value_name = "FILE")]
    pub felt_json: Option<PathBuf>,
    /// Draw the share of presses at rest at the right sample against time
    /// since contact, one line per policy, to this SVG file.
    #[arg(long, value_name = "FILE")]
    pub felt_svg: Option<PathBuf>,
    /// Classify presses of another sensor profile than the index's (to
    /// measure how far an index carries over to another sensor); refused
    /// without it.
    #[arg(long, conflicts_with = "sim")]
    pub mix_sensors: bool,
    #[command(flatten)]
    pub contact: crate::config::ContactArgs,
    #[command(flatten)]
    pub decision: crate::config::DecisionArgs,
    #[command(flatten)]
    pub sensor_opts: crate::config::SensorArgs,
}

/// The row of a recording `classify` could not decide (no press
/// detected in it), with the reason: one row per recording at least, so a
/// press is never lost from a table of results.
fn print_undecided(
    out: &mut dyn Write,
    args: &Args,
    source: &str,
    n: usize,
    label: &str,
    why: &str,
) -> Result<()> {
    if args.json {
        let v = serde_json::json!({
            "source": source,
            "press": n,
            "label": label,
            "textile": null,
            "undecided": why,
        });
        writeln!(out, "{v}")?;
    } else {
        writeln!(out, "press {n} ({source}): not decided: {why}")?;
    }
    Ok(())
}

fn print(
    out: &mut dyn Write,
    args: &Args,
    source: &str,
    n: usize,
    r: &PressReport,
    index: &Index,
    felt: &[PressFelt],
) -> Result<()> {
    if args.json {
        let mut v = serde_json::to_value(r)?;
        if let Some(o) = v.as_object_mut() {
            o.insert("source".into(), source.into());
            o.insert("press".into(), n.into());
            o.insert("felt".into(), serde_json::to_value(felt)?);
            let name = r
                .textile
                .as_deref()
                .and_then(|id| index.entry_by_id(id))
                .map(|e| index.entries[e].name.clone());
            o.insert("name".into(), name.into());
        }
        writeln!(out, "{}", serde_json::to_string(&v)?)?;
        return Ok(());
    }
    match (&r.textile, r.slot) {
        (Some(id), Some(slot)) => {
            let name = index
                .entry_by_id(id)
                .map(|e| index.entries[e].name.as_str())
                .unwrap_or("");
            writeln!(
                out,
                "press {n} ({source}): {id} \"{name}\"{} -> roller slot {slot}; distance {:.3}, margin {:.3}, confidence {:.2}",
                if r.unknown { " (unknown textile: nearest known)" } else { "" },
                r.distance.unwrap_or(f32::NAN),
                r.margin.unwrap_or(f32::NAN),
                r.confidence.unwrap_or(f32::NAN),
            )?;
            // Where the roller went first, when the decision changed.
            let first = match r.first_textile.as_deref() {
                Some(f) if f != id => format!(" as {f}"),
                _ => String::new(),
            };
            writeln!(
                out,
                "  press began at {:.0} ms; decided {:.0} ms later{first} and stable from {:.0} ms after it ({} switches); press {:.0} ms, {} frames encoded, ended: {}{}",
                r.start_ms,
                r.decision_ms.unwrap_or(f64::NAN),
                r.stable_ms.unwrap_or(f64::NAN),
                r.switches,
                r.duration_ms,
                r.frames,
                r.ended,
                r.coverage
                    .map(|c| format!("; touched {:.0} % of the gel", 100.0 * c))
                    .unwrap_or_default()
            )?;
            if let Some(c) = r.coverage.filter(|&c| c < PARTIAL_COVERAGE) {
                writeln!(
                    out,
                    "  partial contact: the press touched {:.0} % of the gel (held tilted?); hold the sensor flat on the fabric, such presses are decided less reliably",
                    100.0 * c
                )?;
            }
        }
        _ => writeln!(
            out,
            "press {n} ({source}): no decision ({} frames encoded, {:.0} ms)",
            r.frames, r.duration_ms
        )?,
    }
    // The wheel's figures per press when a policy was asked for.
    for f in felt.iter().filter(|_| !args.motions.is_empty()) {
        writeln!(
            out,
            "  wheel ({}): at rest at the final sample {:.0} ms after contact (median over {} starting samples, worst {:.0}); {} targets, up to {} reversals",
            f.policy, f.felt_p50_ms, f.starts, f.felt_max_ms, f.targets, f.reversals_max
        )?;
    }
    let stages: Vec<String> = r
        .stages
        .iter()
        .filter(|(_, s)| s.frames > 0)
        .map(|(k, s)| format!("{k} {:.3}", s.p50_ms))
        .collect();
    writeln!(
        out,
        "  per-frame p50 ms: {}; whole frame {:.3} (p90 {:.3})",
        stages.join(", "),
        r.frame_total.p50_ms,
        r.frame_total.p90_ms
    )?;
    Ok(())
}

/// Every press `classify` decided, against the fabric it is labelled with
/// (a recording's `press.json` textile, a PyTouch class, the simulated
/// id): what a DIGIT owner checking an index on presses kept apart wants
/// to know, in the terms of `index build`'s self-check.
#[derive(Debug, Default)]
struct Tally {
    /// (label's index entry, decision's index entry) of each press of a
    /// fabric the index holds.
    decided: Vec<(usize, usize)>,
    /// Of those, flagged unknown.
    known_flagged: usize,
    /// Of those, first decided as their own fabric, and first decided as
    /// another fabric than their last decision (the roller moved twice).
    first_right: usize,
    first_changed: usize,
    /// Presses with no decision.
    undecided: usize,
    /// Decided presses of fabrics the index holds that touched less than
    /// [`PARTIAL_COVERAGE`] of the gel, and of them those decided right.
    partial: usize,
    partial_right: usize,
    /// Presses of fabrics the index does not hold, and of them flagged
    /// unknown.
    foreign: usize,
    foreign_flagged: usize,
    /// Recordings read, those in which no press was detected, and those in
    /// which more than one was (the sensor released and touched again
    /// within one recording).
    recordings: usize,
    silent: usize,
    split: usize,
}

impl Tally {
    fn press(&mut self, label: &str, r: &PressReport, index: &Index) {
        let decided = r.textile.as_deref().and_then(|id| index.entry_by_id(id));
        match (index.entry_by_id(label), decided) {
            (_, None) => self.undecided += 1,
            (None, Some(_)) => {
                self.foreign += 1;
                self.foreign_flagged += usize::from(r.unknown);
            }
            (Some(fabric), Some(d)) => {
                self.decided.push((fabric, d));
                self.known_flagged += usize::from(r.unknown);
                if r.coverage.is_some_and(|c| c < PARTIAL_COVERAGE) {
                    self.partial += 1;
                    self.partial_right += usize::from(fabric == d);
                }
                let first = r
                    .first_textile
                    .as_deref()
                    .and_then(|id| index.entry_by_id(id));
                self.first_right += usize::from(first == Some(fabric));
                self.first_changed += usize::from(first != Some(d));
            }
        }
    }

    /// One line: right of decided (the share), the fabrics taken for
    /// others, then what was not decided, if anything.
    fn line(&self, index: &Index) -> String {
        let check = telextiles_index::build::SelfCheck::of_pairs(self.decided.iter().copied());
        let mut text = if check.presses == 0 {
            "summary: no press of a fabric the index holds was decided".to_string()
        } else {
            let id = |e: usize| index.entries[e].id.as_str();
            format!(
                "summary: {} of {} presses ({:.1} %) decided as the fabric they are labelled with{}",
                check.right,
                check.presses,
                100.0 * check.right as f64 / check.presses as f64,
                crate::index_choice::confusions_text(&check, &id)
            )
        };
        if self.known_flagged > 0 {
            text += &format!("; {} of them flagged unknown", self.known_flagged);
        }
        if self.first_changed > 0 {
            text += &format!(
                "; first decided as their own fabric: {} of {} (the decision changed in {})",
                self.first_right, check.presses, self.first_changed
            );
        }
        let presses = |n: usize| match n {
            1 => "1 press".to_string(),
            n => format!("{n} presses"),
        };
        if self.partial > 0 {
            text += &format!(
                "; {} touched less than {:.0} % of the gel (partial contact), {} of them decided right",
                presses(self.partial),
                100.0 * PARTIAL_COVERAGE,
                self.partial_right
            );
        }
        if self.undecided > 0 {
            text += &format!("; {} without a decision", presses(self.undecided));
        }
        if self.foreign > 0 {
            text += &format!(
                "; {} of fabrics the index does not hold ({} flagged unknown)",
                presses(self.foreign),
                self.foreign_flagged
            );
        }
        if self.silent > 0 {
            text += &format!(
                "; no press detected in {} of {} recordings",
                self.silent, self.recordings
            );
        }
        if self.split > 0 {
            text += &format!(
                "; more than one press in {} of {} recordings",
                self.split, self.recordings
            );
        }
        text
    }
}

/// Run the command, printing to stdout.
pub fn run(args: Args) -> Result<()> {
    run_to(args, &mut crate::out::stdout())
}

/// Run the command, printing to `out`.
pub fn run_to(args: Args, out: &mut dyn Write) -> Result<()> {
    if !args.model.is_file() {
        bail!(
            "encoder model {} not found (train one with telextiles-lab, or pass --model)",
            args.model.display()
        );
    }
    if !args.index.is_file() {
        bail!(
            "textile index {} not found (build one with `telextilesd index build`, or pass --index)",
            args.index.display()
        );
    }
    let opts = EncoderOptions {
        threads: args.threads.max(1),
        ..Default::default()
    };
    let enc = Encoder::open(&args.model, &opts)?;
    let index = Index::read(&args.index)
        .with_context(|| format!("cannot read index {}", args.index.display()))?;
    if index.encoder_hash != enc.info().sha256 && !args.allow_encoder_mismatch {
        bail!(
            "index {} was built for encoder {}, but {} is {} (rebuild the index, or --allow-encoder-mismatch)",
            args.index.display(),
            index.encoder_hash,
            args.model.display(),
            enc.info().sha256
        );
    }
    let pace = if args.real_time {
        Pace::RealTime
    } else {
        Pace::AsFastAsPossible
    };
    let mut n = 0usize;
    if let Some(id) = &args.sim {
        return classify_simulated(out, &args, id, enc, &index, pace);
    }
    let sensor = args.sensor_opts.sensor()?;
    let mut references = References::from_args_as(&args.references, sensor)?;
    // The sensors' no-contact frames kept beside the index, for recordings
    // that carry none and begin in contact.
    let beside = args
        .index
        .parent()
        .filter(|d| !d.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    for f in references.add_beside(beside)? {
        eprintln!("no-contact frame: {}", f.display());
    }
    let mut recordings = Vec::new();
    for p in &args.press {
        recordings.extend(telextiles_recording::recording::find_recordings_at(
            p, args.fps,
        )?);
    }
    telextiles_recording::recording::assume_sensor(&mut recordings, sensor)?;
    if !args.mix_sensors {
        for (profile, first) in telextiles_recording::recording::profiles(&recordings)? {
            index.check_sensor(profile).map_err(|e| {
                anyhow::anyhow!(
                    "{}: {e} (or --mix-sensors to classify them anyway)",
                    first.display()
                )
            })?;
        }
    }
    // One pipeline, reset for every recording with the recording's own
    // reference (else the one given for its sensor): nothing carries over
    // from one recording to the next.
    let pcfg = args.decision.pipeline(args.contact.contact()?);
    let mut pipeline = Pipeline::new(enc, index.clone(), pcfg, None).map_err(anyhow::Error::msg)?;
    let progress =
        telextiles_progress::Progress::new("classify", recordings.len() as u64, "presses");
    let mut tally = Tally::default();
    let mut felts = Felts::new(&args.motions, args.wheel_speed, args.wheel_accel, &index);
    for rec in recordings {
        let name = rec.path().display().to_string();
        let press = rec
            .load()
            .with_context(|| format!("cannot replay {name}"))?;
        let reference = references.for_press(&press);
        let hint = telextiles_sensing::front::no_reference_hint(reference.is_some());
        pipeline.reset(reference.as_deref());
        let label = press.meta.textile.clone();
        let mut src = RecordedSource::from_press(press, pace, name.clone());
        let mut err = Ok(());
        let before = n;
        run_source(&mut pipeline, &mut src, None, |r| {
            n += 1;
            tally.press(&label, &r, &index);
            let felt = felts.press(&label, &r, &index);
            if err.is_ok() {
                err = print(out, &args, &name, n, &r, &index, &felt);
            }
        })
        .map_err(anyhow::Error::msg)?;
        err?;
        tally.recordings += 1;
        if n == before {
            // Never left out: a row that says why it has no decision.
            tally.silent += 1;
            n += 1;
            let why = format!("no press detected{hint}");
            progress.println(&format!("warning: {name}: {why}"));
            print_undecided(out, &args, &name, n, &label, &why)?;
        } else if n - before > 1 {
            // Each is decided on its own, as the live daemon would: the
            // contact was released and made again within the recording.
            tally.split += 1;
            progress.println(&format!(
                "note: {name}: {} presses (the contact was released and made again within the recording; each is decided on its own)",
                n - before
            ));
        }
        progress.inc(1);
    }
    progress.finish();
    summarise(out, &args, &tally, &felts, &index)
}

/// `--sim <textile>`: presses of the index's simulator catalogue, through
/// the same pipeline as recordings.
#[cfg(feature = "sim")]
fn classify_simulated(
    out: &mut dyn Write,
    args: &Args,
    id: &str,
    enc: Encoder,
    index: &Index,
    pace: Pace,
) -> Result<()> {
    use std::sync::Arc;
    let mut n = 0usize;
    // The fabrics of the index's simulator catalogue.
    let sim = Arc::new(crate::live::models::simulator_for(index)?);
    let spec = PressSpec {
        person: args.person,
        sensor: args.sensor,
        jig: !args.no_jig,
        ..PressSpec::new(id, args.seed)
    };
    let frames = spec.frames;
    let gap = 20;
    let (mut src, _handle) =
        SimSource::new(sim, spec, gap, pace).map_err(|e| anyhow::anyhow!("{e}"))?;
    let pcfg = args.decision.pipeline(args.contact.contact()?);
    let mut pipeline = Pipeline::new(enc, index.clone(), pcfg, None).map_err(anyhow::Error::msg)?;
    let total = (gap + frames) as u64 * args.presses as u64;
    let mut err = Ok(());
    let mut tally = Tally::default();
    let mut felts = Felts::new(&args.motions, args.wheel_speed, args.wheel_accel, index);
    run_source(&mut pipeline, &mut src, Some(total), |r| {
        n += 1;
        tally.press(id, &r, index);
        let felt = felts.press(id, &r, index);
        if err.is_ok() {
            err = print(out, args, &format!("sim {id}"), n, &r, index, &felt);
        }
    })
    .map_err(anyhow::Error::msg)?;
    err?;
    summarise(out, args, &tally, &felts, index)
}

#[cfg(not(feature = "sim"))]
fn classify_simulated(
    _out: &mut dyn Write,
    _args: &Args,
    _id: &str,
    _enc: Encoder,
    _index: &Index,
    _pace: Pace,
) -> Result<()> {
    Err(crate::sim_off("`classify --sim`"))
}

/// The summary line: after the presses on standard output, or, with
/// `--json` (one object per press there, nothing else), on standard error.
fn summarise(
    out: &mut dyn Write,
    args: &Args,
    tally: &Tally,
    felts: &Felts,
    index: &Index,
) -> Result<()> {
    // The recognition summary last (scripts take the last line).
    for line in felts.lines().into_iter().chain([tally.line(index)]) {
        if args.json {
            eprintln!("{line}");
        } else {
            writeln!(out, "{line}")?;
        }
    }
    if let Some(path) = &args.felt_json {
        felts.write_json(path)?;
    }
    if let Some(path) = &args.felt_svg {
        let what = if let Some(id) = &args.sim {
            format!("simulated {id}")
        } else {
            args.press
                .iter()
                .map(|p| p.display().to_string())
                .collect::<Vec<_>>()
                .join(", ")
        };
        let title = format!(
            "{what}: wheel at rest at the right sample ({} slots, {:.0} rev/s, {:.0} rev/s^2)",
            felts.wheel.slots,
            felts.wheel.max_speed as f64 / felts.wheel.steps_per_rev() as f64,
            felts.wheel.accel as f64 / felts.wheel.steps_per_rev() as f64
        );
        crate::felt_chart::draw(path, &title, &felts.policies)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests;
