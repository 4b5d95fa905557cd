//! `telextilesd record`: record labelled presses from the sensor into the
//! on-disk press format, one directory per press under `<out>/<textile>/`
//! (`0001`, `0002`, ...: the next free number; a second run adds presses),
//! each written atomically and never over an existing one.
//!
//! Presses are cut out of the frame stream by contact
//! (`telextiles_sensing::record::Recorder`): every press keeps the quiet
//! frames before contact as its own no-contact reference
//! (`meta.reference_frames`), plus margins before and after; the sensor's
//! serial and measured frame rate go into its metadata. `--name` is stored
//! in `<out>/<textile>/textile.json` (`{"id": .., "name": ..}`).
//!
//! Sources: `digit[:SERIAL]` (a DIGIT over V4L2), `sim` (simulated presses
//! of the catalogue textile `--textile`, one after another, as fast as they
//! render: unattended, for tests), `replay:<dir>` (re-record every press
//! found under `<dir>`, as fast as they read; without `--textile`, each
//! under its recording's own textile, so a whole dataset converts in one
//! command).
//!
//! `--idle SECONDS` records the untouched sensor instead: one continuous
//! recording `<out>/idle/NNNN/` (textile "idle", written frame by frame so
//! minutes fit in no memory), while the daemon's contact detector runs on
//! every frame ([`telextiles_sensing::idle::IdleCheck`]); the summary says
//! whether it started presses that nobody made, and how close its score
//! came. The detector's defaults were chosen on simulated idle footage;
//! this is the check on a real sensor.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use telextiles_progress::Progress;
use telextiles_sensing::contact::ContactDetector;
use telextiles_sensing::frame::Frame;
use telextiles_sensing::record::{
    lead_with_reference, PressSummary, RecordEvent, RecordLabel, Recorder, RecorderConfig,
};
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
#[cfg(feature = "sim")]
use telextiles_sensing::source::sim::SimSource;
use telextiles_sensing::source::{FrameSource, SourceError};
#[cfg(feature = "sim")]
use telextiles_sim::{PressSpec, Simulator};

use telextiles_recording::profile::{SensorProfile, DIGIT};

use crate::config::SensorSource;
use crate::press_dir::*;
use crate::record_idle::{idle_sim, run_idle, IdleOptions, IdleSource, MAX_IDLE_S};

/// Options of `telextilesd record`.
#[derive(clap::Args, Debug)]
pub struct Args {
    /// Textile id: the presses go into <out>/<id>/ and are labelled with
    /// it. With --sensor replay:<dir> it may be left out: each recording's
    /// presses then go under the recording's own textile (its press.json's,
    /// or its PyTouch class), with its sensor serial, so a whole dataset
    /// is converted in one command.
    #[arg(long)]
    pub textile: Option<String>,
    /// Human-readable name of the textile, stored in <out>/<id>/textile.json.
    #[arg(long)]
    pub name: Option<String>,
    /// Presses to record (in all). With --sensor replay:<dir> it may be
    /// left out: every press found.
    #[arg(long)]
    pub presses: Option<u32>,
    /// Directory of recordings (one sub-directory per textile).
    #[arg(long)]
    pub out: PathBuf,
    /// digit, digit:SERIAL, camera[:SERIAL|/dev/videoN] (a sensor of
    /// --sensor-profile, or found by its USB ids and name), sim (simulated
    /// presses of --textile, unattended) or replay:<dir> (re-record the
    /// presses under <dir>).
    #[arg(long, default_value = "digit")]
    pub sensor: SensorSource,
    /// With --sensor sim: seed of the first simulated press (default: its
    /// press number, so that a second run into the same directory records
    /// new presses); the next presses take the following seeds.
    #[arg(long)]
    pub sim_seed: Option<u64>,
    /// Seconds to hold each press before "release" is shown.
    #[arg(long, default_value_t = 1.5)]
    pub hold: f64,
    /// With --sensor replay: frame rate of recordings saved without
    /// timestamps (PyTouch-style datasets) [default: the DIGIT's stream
    /// rate at the frames' size: 60 fps for 240x320 or 320x240, 30 for
    /// VGA].
    #[arg(long, value_parser = telextiles_recording::recording::parse_fps)]
    pub fps: Option<f32>,
    /// With --sensor replay: the sensor's no-contact frame (an RGB PNG or
    /// JPEG, taken with nothing touching the gel) for recordings that
    /// carry no reference of their own (PyTouch data, often cut to the
    /// press): `PNG` for every sensor, `SERIAL=PNG` for one (repeat it).
    /// Each such recording is replayed against it, and each press saved
    /// from it starts with the image as its no-contact frames, so it
    /// carries its reference from then on.
    #[arg(long = "reference", value_name = "[SERIAL=]PNG")]
    pub references: Vec<String>,
    /// Record this many seconds (up to 600) of the sensor resting
    /// untouched, into <out>/idle/NNNN/, and check the contact detector on
    /// them: presses it started (each false), and how close its score came
    /// to starting one. Fails if it started any. About 7 MB per second of
    /// PNG frames. With --sensor digit[:SERIAL] or sim.
    #[arg(long, value_name = "SECONDS")]
    pub idle: Option<f64>,
    /// With --idle: the summary as one JSON object on the last line.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub contact: crate::config::ContactArgs,
    #[command(flatten)]
    pub sensor_opts: crate::config::SensorArgs,
}

/// A source and what its presses are labelled with.
struct Opened {
    frames: Frames,
    serial: Option<String>,
    sensor_unit: u32,
    jig: bool,
    source: &'static str,
    desc: String,
    /// The sensor's profile (a replay's recordings say their own).
    profile: &'static SensorProfile,
}

enum Frames {
    /// One endless stream (a DIGIT, the simulator), with a frame budget.
    Live(Box<dyn FrameSource>, Option<u64>),
    /// Recordings, each replayed with its own reference, else the one
    /// given for its sensor.
    Replay(
        Vec<telextiles_recording::recording::Recording>,
        telextiles_sensing::front::References,
    ),
}

/// Frames between simulated presses: the contact detector's reference
/// capture, then enough quiet frames for the recorder's reference and ready.
#[cfg(feature = "sim")]
const SIM_GAP_FRAMES: usize = 48;

fn open(args: &Args, textile: &str, presses: Option<u32>, first_seed: u64) -> Result<Opened> {
    let replay = matches!(args.sensor, SensorSource::Replay { .. });
    let sensor = args.sensor_opts.sensor()?;
    if args.fps.is_some() && !replay {
        bail!("--fps is for --sensor replay:<dir> (recordings saved without timestamps); a live sensor's frames carry their own");
    }
    if !args.references.is_empty() && !replay {
        bail!("--reference is for --sensor replay:<dir> (recordings that carry no no-contact frames); a live sensor's is captured before each press");
    }
    match &args.sensor {
        SensorSource::Sim { textile: None } => open_sim(textile, presses, first_seed),
        SensorSource::Sim { textile: Some(t) } => bail!(
            "--sensor sim records the textile --textile names; say --sensor sim --textile {t}"
        ),
        SensorSource::Replay { dir } => {
            // The walk every command shares: press directories, else a
            // PyTouch-style dataset.
            let mut recordings = telextiles_recording::recording::find_recordings_at(dir, args.fps)
                .with_context(|| format!("no recordings to replay under {}", dir.display()))?;
            telextiles_recording::recording::assume_sensor(&mut recordings, sensor)?;
            let references =
                telextiles_sensing::front::References::from_args_as(&args.references, sensor)?;
            let desc = format!(
                "replay of {} recordings under {}",
                recordings.len(),
                dir.display()
            );
            Ok(Opened {
                frames: Frames::Replay(recordings, references),
                serial: None,
                sensor_unit: 0,
                jig: false,
                source: "replay",
                desc,
                profile: &DIGIT,
            })
        }
        SensorSource::Digit { .. } | SensorSource::Camera { .. } => open_camera(args),
    }
}

/// `--sensor sim`: the simulator pressing `textile` of the built-in
/// catalogue, as fast as it renders.
#[cfg(feature = "sim")]
fn open_sim(textile: &str, presses: Option<u32>, first_seed: u64) -> Result<Opened> {
    let sim = Arc::new(Simulator::new()?);
    if sim.catalogue().get(textile).is_none() {
        bail!(
            "--sensor sim presses textiles of the built-in catalogue (T001..T119, U01..U20), not {:?}",
            textile
        );
    }
    let spec = PressSpec::new(textile, first_seed);
    let per_press = (SIM_GAP_FRAMES + spec.frames) as u64;
    let (src, _handle) = SimSource::new(sim, spec, SIM_GAP_FRAMES, Pace::AsFastAsPossible)
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    // Every simulated press is accepted in practice; a few spare
    // presses, then give up rather than loop for ever.
    let budget = per_press * (presses.unwrap_or(1) as u64 * 2 + 2);
    Ok(Opened {
        frames: Frames::Live(Box::new(src), Some(budget)),
        serial: Some("SIM0000".into()),
        sensor_unit: 0,
        jig: true,
        source: "sim",
        desc: format!("simulated DIGIT pressing {textile}"),
        profile: &DIGIT,
    })
}

#[cfg(not(feature = "sim"))]
fn open_sim(_textile: &str, _presses: Option<u32>, _first_seed: u64) -> Result<Opened> {
    Err(crate::sim_off("`record --sensor sim`"))
}

#[cfg(target_os = "linux")]
fn open_camera(args: &Args) -> Result<Opened> {
    use telextiles_sensing::source::camera::CameraSource;
    let o = &args.sensor_opts;
    let opts = crate::live::camera_options(
        &args.sensor,
        o.sensor_profile,
        o.sensor_mm_per_px,
        o.sensor_mode,
    )?;
    let src = CameraSource::open(&opts).map_err(|e| {
        anyhow::anyhow!(
            "cannot open the {}: {e}\n(plug it in over USB, check `telextilesd sensors` and that you may read it (group video), or record without one: --sensor sim)",
            opts.profile.label
        )
    })?;
    let desc = src.describe();
    let serial = Some(src.info().serial.clone()).filter(|s| !s.is_empty());
    let profile = src.profile();
    Ok(Opened {
        frames: Frames::Live(Box::new(src), None),
        serial,
        sensor_unit: 0,
        jig: false,
        source: if profile.name == DIGIT.name {
            "digit"
        } else {
            "camera"
        },
        desc,
        profile,
    })
}

#[cfg(not(target_os = "linux"))]
fn open_camera(_args: &Args) -> Result<Opened> {
    bail!("cameras are read over V4L2, which only Linux has; use --sensor sim or replay:<dir>")
}

/// The guide on the terminal: a bar (presses recorded, ETA, what to do now)
/// on a terminal, plain lines otherwise.
struct Guide {
    progress: Progress,
    /// Presses asked for (None: every press a replay holds).
    total: Option<u32>,
    hold_ms: f64,
    said_release: bool,
    last_hold_line: f64,
    plain: bool,
}

impl Guide {
    /// "/N" of "press k/N", or nothing when every press is recorded.
    fn of(&self) -> String {
        self.total.map(|t| format!("/{t}")).unwrap_or_default()
    }

    fn line(&self, s: &str) {
        self.progress.println(s);
    }

    fn say(&mut self, now: &str) {
        self.progress.set_message(now);
    }

    /// React to a recorder event; `k` is the number the next press will have.
    fn event(&mut self, e: &RecordEvent, k: u32, replay: bool) {
        match e {
            RecordEvent::WaitingForReference if !replay => {
                self.line("waiting for a no-contact reference: do not touch the sensor");
                self.say("waiting: do not touch the sensor");
            }
            RecordEvent::Ready if !replay => {
                self.line(&format!("press now ({k}{})", self.of()));
                self.say(&format!("press now ({k}{})", self.of()));
            }
            RecordEvent::PressStarted { .. } => {
                self.said_release = false;
                self.last_hold_line = 0.0;
                if !replay {
                    self.line(&format!("contact ({k}{})", self.of()));
                }
            }
            RecordEvent::Holding {
                held_ms,
                score,
                peak,
            } => {
                self.say(&format!(
                    "holding {:.1} s, contact {score:.1} (peak {peak:.1})",
                    held_ms / 1000.0
                ));
                if self.plain && !replay && held_ms - self.last_hold_line >= 500.0 {
                    self.last_hold_line = *held_ms;
                    self.line(&format!(
                        "  holding {:.1} s, contact {score:.1}",
                        held_ms / 1000.0
                    ));
                }
                if !self.said_release && *held_ms >= self.hold_ms && !replay {
                    self.said_release = true;
                    self.line("release");
                    self.say("release");
                }
            }
            RecordEvent::Released { held_ms, peak } if !replay => {
                self.line(&format!(
                    "released after {:.1} s (peak contact {peak:.1})",
                    held_ms / 1000.0
                ));
                self.say(&format!("released press {k}"));
            }
            RecordEvent::Rejected(w) => {
                self.line(&format!("press not kept: {w}"));
            }
            RecordEvent::PressComplete(p) => {
                for w in &p.summary.warnings {
                    self.line(&format!("warning (press {k} kept): {w}"));
                }
            }
            _ => {}
        }
    }

    fn saved(&self, k: u32, path: &Path, s: &PressSummary) {
        self.line(&format!(
            "saved press {k}{}: {} frames, {:.1} s, peak contact {:.1}, touched {:.0} % of the gel ({}; reference {} frames, {:.1} fps)",
            self.of(),
            s.frames,
            s.duration_ms / 1000.0,
            s.peak,
            100.0 * s.coverage,
            path.display(),
            s.reference_frames,
            s.fps
        ));
        self.progress.inc(1);
    }
}

struct Session {
    guide: Guide,
    writer: Option<Writer>,
    submitted: u32,
    saved: u32,
    first_number: u32,
    errors: Vec<anyhow::Error>,
}

impl Session {
    fn collect(&mut self, results: Vec<Result<(u32, PathBuf, PressSummary)>>) {
        for r in results {
            match r {
                Ok((k, path, s)) => {
                    self.saved += 1;
                    self.guide.saved(k, &path, &s);
                }
                Err(e) => {
                    self.guide
                        .line(&format!("error: cannot save a press: {e:#}"));
                    self.errors.push(e);
                }
            }
        }
    }

    fn drain(&mut self, rec: &mut Recorder, replay: bool) {
        while let Some(e) = rec.poll() {
            let k = self.submitted + 1;
            self.guide.event(&e, k, replay);
            if let RecordEvent::PressComplete(p) = e {
                if self.guide.total.is_none_or(|t| self.submitted < t) {
                    self.submitted += 1;
                    if let Some(w) = &self.writer {
                        w.submit(self.submitted, p);
                    }
                }
            }
        }
        let ready = self.writer.as_ref().map(Writer::ready).unwrap_or_default();
        self.collect(ready);
    }

    /// Wait for every write handed to the writer.
    fn close(&mut self) {
        if let Some(w) = self.writer.take() {
            let results = w.close();
            self.collect(results);
        }
    }

    fn done(&self) -> bool {
        self.guide.total.is_some_and(|t| self.submitted >= t)
    }
}

/// Stops the loops on Ctrl-C (the press in progress is dropped; saved presses
/// are complete, since each is renamed into place only when written).
fn interrupt_flag() -> Arc<AtomicBool> {
    let flag = Arc::new(AtomicBool::new(false));
    let f = flag.clone();
    let started = Arc::new((std::sync::Mutex::new(false), std::sync::Condvar::new()));
    let s2 = started.clone();
    std::thread::spawn(move || {
        let Ok(rt) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        else {
            return;
        };
        rt.block_on(async move {
            let wait = tokio::signal::ctrl_c();
            tokio::pin!(wait);
            // Poll once so the handler is installed before we say so.
            let _ = futures_poll_once(&mut wait).await;
            {
                let (m, c) = &*s2;
                *m.lock().unwrap_or_else(|e| e.into_inner()) = true;
                c.notify_all();
            }
            if wait.await.is_ok() {
                f.store(true, Ordering::SeqCst);
            }
        });
    });
    let (m, c) = &*started;
    let guard = m.lock().unwrap_or_else(|e| e.into_inner());
    let _ = c.wait_timeout_while(guard, std::time::Duration::from_secs(2), |s| !*s);
    flag
}

/// Poll a future once (returns whether it was ready).
async fn futures_poll_once<F: std::future::Future + Unpin>(f: &mut F) -> bool {
    use std::task::Poll;
    std::future::poll_fn(|cx| {
        Poll::Ready(matches!(
            std::pin::Pin::new(&mut *f).poll(cx),
            Poll::Ready(_)
        ))
    })
    .await
}

/// Run the command.
pub fn run(args: Args) -> Result<()> {
    let mut out = crate::out::stdout();
    let stop = interrupt_flag();
    run_to(args, &mut out, &stop)
}

/// Run the command; the summary goes to `out`, the guide to standard error.
pub fn run_to(args: Args, out: &mut dyn Write, stop: &AtomicBool) -> Result<()> {
    if let Some(seconds) = args.idle {
        return record_idle(&args, seconds, out, stop);
    }
    if args.json {
        bail!("--json is for --idle (the idle check's summary)");
    }
    if args.presses == Some(0) {
        bail!("--presses must be at least 1");
    }
    let replay = matches!(args.sensor, SensorSource::Replay { .. });
    let Some(textile) = args.textile.clone() else {
        if !replay {
            bail!(
                "--textile is needed with --sensor {}: its presses are labelled with it (only --sensor replay:<dir> can leave it out, to save each recording's presses under the recording's own textile)",
                args.sensor
            );
        }
        if args.name.is_some() {
            bail!("--name names the --textile given; without --textile each recording keeps its own textile (name it in <out>/<id>/textile.json)");
        }
        return run_each_own_textile(&args, out, stop);
    };
    check_id(&textile)?;
    if !replay && args.presses.is_none() {
        bail!(
            "--presses is needed with --sensor {}: how many presses to record",
            args.sensor
        );
    }
    record_one(&args, &textile, args.presses, out, stop)
}

/// `record` of one textile: `<out>/<textile>/` prepared, its source opened,
/// at most `limit` presses (None: every press of a replay) recorded.
fn record_one(
    args: &Args,
    textile: &str,
    limit: Option<u32>,
    out: &mut dyn Write,
    stop: &AtomicBool,
) -> Result<()> {
    let dir = prepare_dir(&args.out, textile, args.name.as_deref())?;
    let first = next_number(&dir)?;
    let opened = open(args, textile, limit, args.sim_seed.unwrap_or(first as u64))?;
    let job = Job {
        textile,
        dir: &dir,
        first,
        limit,
        part_of_all: false,
    };
    let done = record_textile(args, job, opened, out, stop, &mut false)?;
    done.check(limit)
}

/// The textile a recording is labelled with: its `press.json`'s, or its
/// PyTouch class.
fn textile_of(r: &telextiles_recording::recording::Recording) -> Result<String> {
    use telextiles_recording::recording::Recording;
    Ok(match r {
        Recording::Press(p) => {
            telextiles_recording::recording::read_meta(p)
                .with_context(|| format!("cannot replay {}", p.display()))?
                .textile
        }
        Recording::Pytouch { entry, .. } => entry.class.clone(),
    })
}

/// `record --sensor replay:<dir>` without `--textile`: the presses of each
/// recording saved under the recording's own textile, one textile after
/// another (in the order the walk finds them), each with its sensor's
/// serial, at most `--presses` in all.
fn run_each_own_textile(args: &Args, out: &mut dyn Write, stop: &AtomicBool) -> Result<()> {
    let opened = open(args, "", args.presses, 0)?;
    let Frames::Replay(recordings, references) = opened.frames else {
        unreachable!("only a replay records without --textile")
    };
    let mut groups: Vec<(String, Vec<telextiles_recording::recording::Recording>)> = Vec::new();
    for r in recordings {
        let t = textile_of(&r)?;
        check_id(&t).with_context(|| {
            format!(
                "{} is labelled {t:?}: record it with --textile and an id of your choosing",
                r.path().display()
            )
        })?;
        match groups.iter_mut().find(|(g, _)| *g == t) {
            Some((_, v)) => v.push(r),
            None => groups.push((t, vec![r])),
        }
    }
    eprintln!(
        "{}: {} textile{} ({}), each press saved under its recording's own",
        opened.desc,
        groups.len(),
        if groups.len() == 1 { "" } else { "s" },
        groups
            .iter()
            .map(|(t, _)| t.as_str())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let started = std::time::Instant::now();
    let mut saved = 0;
    let mut textiles = 0;
    let mut told_no_reference = false;
    for (textile, recordings) in groups {
        let left = args.presses.map(|p| p - saved);
        if left == Some(0) {
            break;
        }
        let dir = prepare_dir(&args.out, &textile, None)?;
        let first = next_number(&dir)?;
        let n = recordings.len();
        let one = Opened {
            frames: Frames::Replay(recordings, references.clone()),
            serial: None,
            sensor_unit: 0,
            jig: false,
            source: "replay",
            desc: format!("{n} of its recordings"),
            profile: &DIGIT,
        };
        let job = Job {
            textile: &textile,
            dir: &dir,
            first,
            limit: left,
            part_of_all: true,
        };
        let done = record_textile(args, job, one, out, stop, &mut told_no_reference)?;
        saved += done.saved;
        textiles += usize::from(done.saved > 0);
        if done.interrupted {
            bail!("interrupted: {saved} presses saved (the press in progress was dropped)");
        }
    }
    writeln!(
        out,
        "recorded {saved} presses of {textiles} textiles into {} in {:.1} s",
        args.out.display(),
        started.elapsed().as_secs_f64()
    )?;
    if let Some(p) = args.presses {
        if saved < p {
            bail!("only {saved} of {p} presses recorded: the recordings are all replayed");
        }
    }
    if saved == 0 {
        bail!("no press found in the recordings");
    }
    Ok(())
}

/// How a textile's recording ended.
struct Done {
    saved: u32,
    interrupted: bool,
    /// Why it stopped before its presses were all recorded.
    ran_out: Option<String>,
}

impl Done {
    /// The error for a run that was interrupted, or stopped short of the
    /// presses asked for.
    fn check(self, limit: Option<u32>) -> Result<()> {
        if self.interrupted {
            bail!(
                "interrupted: {} of {} presses saved (the press in progress was dropped)",
                self.saved,
                limit.map_or("the".into(), |l| l.to_string())
            );
        }
        match (self.ran_out, limit) {
            (Some(why), Some(l)) if self.saved < l => {
                bail!("only {} of {l} presses recorded: {why}", self.saved)
            }
            (Some(_), None) if self.saved == 0 => bail!("no press found in the recordings"),
            _ => Ok(()),
        }
    }
}

/// One textile's share of a `record` run.
struct Job<'a> {
    textile: &'a str,
    /// `<out>/<textile>/`.
    dir: &'a Path,
    /// The number of the first press saved.
    first: u32,
    /// At most this many presses (None: every one a replay holds).
    limit: Option<u32>,
    /// One textile of a run over several (`--presses` counts them all).
    part_of_all: bool,
}

/// Records `job`'s presses from `opened`; the summary line goes to `out`.
/// A press that could not be saved is an error. `told_no_reference`: a
/// replayed recording without a reference was already pointed out.
fn record_textile(
    args: &Args,
    job: Job<'_>,
    opened: Opened,
    out: &mut dyn Write,
    stop: &AtomicBool,
    told_no_reference: &mut bool,
) -> Result<Done> {
    let Job {
        textile,
        dir,
        first,
        limit,
        part_of_all,
    } = job;
    let label = RecordLabel {
        textile: textile.to_string(),
        source: opened.source.to_string(),
        sensor_serial: opened.serial.clone(),
        sensor: opened.sensor_unit,
        person: 0,
        jig: opened.jig,
        sensor_profile: telextiles_recording::profile_tag(opened.profile),
    };
    let asked = match limit {
        Some(n) if !part_of_all => format!("{n} press{}", if n == 1 { "" } else { "es" }),
        _ => "every press".into(),
    };
    eprintln!(
        "recording {asked} of {textile}{} from {} into {} (from {first:04})",
        args.name
            .as_deref()
            .map(|n| format!(" \"{n}\""))
            .unwrap_or_default(),
        opened.desc,
        dir.display()
    );
    let bar_len = match (&opened.frames, limit) {
        (_, Some(n)) => n as u64,
        (Frames::Replay(r, _), None) => r.len() as u64,
        (Frames::Live(..), None) => 0,
    };
    let progress = Progress::new(&format!("record {textile}"), bar_len, "presses");
    let plain = !std::io::IsTerminal::is_terminal(&std::io::stderr());
    let writer = Writer::new(dir.to_path_buf(), first);
    let mut s = Session {
        guide: Guide {
            progress,
            total: limit,
            hold_ms: args.hold * 1000.0,
            said_release: false,
            last_hold_line: 0.0,
            plain,
        },
        writer: Some(writer),
        submitted: 0,
        saved: 0,
        first_number: first,
        errors: Vec::new(),
    };
    let started = std::time::Instant::now();
    let mut frame = Frame::blank();
    let mut interrupted = false;
    let mut ran_out = None;
    match opened.frames {
        Frames::Live(mut src, budget) => {
            let mut det = ContactDetector::new(args.contact.contact()?);
            let mut rec = Recorder::new(RecorderConfig::default(), label);
            let mut n = 0u64;
            while !s.done() {
                if stop.load(Ordering::SeqCst) {
                    interrupted = true;
                    break;
                }
                if budget.is_some_and(|b| n >= b) {
                    ran_out = Some(format!(
                        "the simulator's presses were not accepted ({n} frames)"
                    ));
                    break;
                }
                n += 1;
                match src.next_frame(&mut frame) {
                    Ok(()) => {}
                    Err(SourceError::BadFrame(e)) => {
                        tracing::warn!("bad frame skipped: {e}");
                        continue;
                    }
                    Err(SourceError::Ended) => {
                        rec.finish();
                        s.drain(&mut rec, false);
                        ran_out = Some("the source ended".into());
                        break;
                    }
                    Err(e) => {
                        // Presses already handed to the writer are still saved.
                        s.close();
                        bail!(
                            "{e} ({} presses saved; the press in progress, if any, was not)",
                            s.saved
                        );
                    }
                }
                let u = det.update(frame.image(), frame.timestamp_us());
                rec.push(&frame, &u);
                s.drain(&mut rec, false);
            }
        }
        Frames::Replay(recordings, references) => {
            let cfg = RecorderConfig::default();
            for r in &recordings {
                let d = &r.path();
                if s.done() {
                    break;
                }
                if stop.load(Ordering::SeqCst) {
                    interrupted = true;
                    break;
                }
                let mut press = r
                    .load()
                    .with_context(|| format!("cannot replay {}", d.display()))?;
                // Each recording with its own reference, as every reader
                // takes it (`front::recording_reference`), else the one
                // given for its sensor, led in as its no-contact frames so
                // that the presses saved from it carry it, else captured
                // from its first frames.
                if telextiles_sensing::front::recording_reference(&press).is_none() {
                    if let Some(px) = references.given(press.meta.sensor_serial.as_deref()) {
                        press = lead_with_reference(&press, px, cfg.min_quiet_frames);
                    }
                }
                let meta = press.meta.clone();
                let press_ref = telextiles_sensing::front::recording_reference(&press);
                if press_ref.is_none() && !*told_no_reference {
                    // Its first frames become its reference, and the
                    // quiet frames saved before each press with it: say
                    // so (once, for the first such recording), since
                    // they may be pressed.
                    *told_no_reference = true;
                    s.guide.line(&format!(
                        "note: {}{}",
                        d.display(),
                        telextiles_sensing::front::no_reference_hint(false)
                    ));
                }
                let mut src = RecordedSource::from_press(
                    press,
                    Pace::AsFastAsPossible,
                    d.display().to_string(),
                );
                let mut det = match &press_ref {
                    Some(r) => ContactDetector::with_reference_pixels(args.contact.contact()?, r),
                    None => ContactDetector::new(args.contact.contact()?),
                };
                let mut rec = Recorder::new(
                    RecorderConfig {
                        fps: Some(meta.fps),
                        ..cfg.clone()
                    },
                    RecordLabel {
                        sensor_serial: meta.sensor_serial.clone(),
                        sensor: meta.sensor,
                        person: meta.person,
                        jig: meta.jig,
                        sensor_profile: meta
                            .profile()
                            .ok()
                            .and_then(telextiles_recording::profile_tag),
                        ..label.clone()
                    },
                );
                let before = s.submitted;
                loop {
                    match src.next_frame(&mut frame) {
                        Ok(()) => {}
                        Err(SourceError::Ended) => break,
                        Err(e) => bail!("{}: {e}", d.display()),
                    }
                    let u = det.update(frame.image(), frame.timestamp_us());
                    rec.push(&frame, &u);
                    s.drain(&mut rec, true);
                    if s.done() {
                        break;
                    }
                }
                rec.finish();
                s.drain(&mut rec, true);
                if s.submitted == before {
                    s.guide.line(&format!(
                        "{}: no press found in this recording",
                        d.display()
                    ));
                }
            }
            if !s.done() && !interrupted {
                ran_out = Some(format!(
                    "the {} recordings are all replayed",
                    recordings.len()
                ));
            }
        }
    }
    s.close();
    s.guide.progress.finish();
    let last = s.first_number + s.saved;
    writeln!(
        out,
        "recorded {}{} presses of {textile} into {} in {:.1} s{}",
        s.saved,
        match limit {
            Some(l) if !part_of_all => format!(" of {l}"),
            _ => String::new(),
        },
        dir.display(),
        started.elapsed().as_secs_f64(),
        if s.saved > 0 {
            format!(" ({:04}..{:04})", s.first_number, last - 1)
        } else {
            String::new()
        }
    )?;
    if let Some(e) = s.errors.into_iter().next() {
        return Err(e.context("a press could not be saved"));
    }
    Ok(Done {
        saved: s.saved,
        interrupted,
        ran_out,
    })
}

/// `record --idle SECONDS`: the resting sensor recorded and the contact
/// detector checked on it (see the module docs).
fn record_idle(args: &Args, seconds: f64, out: &mut dyn Write, stop: &AtomicBool) -> Result<()> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= MAX_IDLE_S) {
        bail!("--idle takes 0 < SECONDS <= {MAX_IDLE_S} (the footage is about 7 MB a second)");
    }
    if args.textile.is_some() || args.presses.is_some() || args.name.is_some() {
        bail!("--idle records the sensor untouched, not presses of a textile: leave out --textile, --name and --presses");
    }
    if args.fps.is_some() || !args.references.is_empty() {
        bail!("--fps and --reference are for --sensor replay:<dir>; --idle records a live sensor");
    }
    // Idle footage is not a textile: keep it out of a directory of presses,
    // where `index build --presses` would take "idle" for one.
    if let Ok(rd) = std::fs::read_dir(&args.out) {
        for e in rd.flatten() {
            let p = e.path();
            if e.file_name() != "idle"
                && p.is_dir()
                && !telextiles_recording::recording::find_presses(&p)
                    .unwrap_or_default()
                    .is_empty()
            {
                bail!(
                    "{} holds presses of textiles ({}); give the idle footage a directory of its own (`index build --presses` would take it for a textile)",
                    args.out.display(),
                    p.display()
                );
            }
        }
    }
    let src = match &args.sensor {
        SensorSource::Replay { .. } => bail!(
            "--idle records a live sensor (--sensor digit[:SERIAL], or sim): footage of a resting sensor, not presses to replay"
        ),
        SensorSource::Sim { textile: None } => idle_sim(args.sim_seed, seconds)?,
        SensorSource::Sim { textile: Some(_) } => {
            bail!("--idle records the sensor untouched: say --sensor sim, no textile")
        }
        SensorSource::Digit { .. } | SensorSource::Camera { .. } => {
            let opened = open_camera(args)?;
            let Frames::Live(src, _) = opened.frames else {
                bail!("a camera is a live source");
            };
            IdleSource {
                frames: src,
                serial: opened.serial.unwrap_or_default(),
                source: opened.source,
                desc: opened.desc,
                profile: opened.profile,
            }
        }
    };
    let opts = IdleOptions {
        out: args.out.clone(),
        contact: args.contact.contact()?,
        json: args.json,
        sim_seed: args.sim_seed,
    };
    run_idle(&opts, seconds, src, out, stop)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_simulated_press_records_the_textile_given_once() {
        let d = tempfile::tempdir().expect("tempdir");
        let mut args = idle_args(d.path());
        args.idle = None;
        args.sensor = "sim:T001".parse().expect("a source");
        let e = open(&args, "T001", Some(1), 1)
            .err()
            .expect("refused")
            .to_string();
        assert!(e.contains("--sensor sim --textile T001"), "{e}");
    }

    /// `record --idle` arguments into `out`.
    fn idle_args(out: &Path) -> Args {
        Args {
            textile: None,
            name: None,
            presses: None,
            out: out.to_path_buf(),
            sensor: SensorSource::Sim { textile: None },
            sim_seed: None,
            hold: 1.5,
            fps: None,
            references: Vec::new(),
            idle: Some(10.0),
            json: false,
            contact: Default::default(),
            sensor_opts: Default::default(),
        }
    }

    #[test]
    fn idle_arguments_are_checked_before_anything_is_opened() {
        let d = tempfile::tempdir().expect("tempdir");
        let run = |f: &dyn Fn(&mut Args)| {
            let mut a = idle_args(d.path());
            f(&mut a);
            run_to(a, &mut Vec::new(), &AtomicBool::new(false))
                .expect_err("refused")
                .to_string()
        };
        assert!(run(&|a| a.idle = Some(0.0)).contains("0 < SECONDS <= 600"));
        assert!(run(&|a| a.idle = Some(601.0)).contains("0 < SECONDS <= 600"));
        assert!(run(&|a| a.idle = Some(f64::NAN)).contains("0 < SECONDS"));
        assert!(run(&|a| a.textile = Some("T001".into())).contains("leave out --textile"));
        assert!(run(&|a| a.presses = Some(3)).contains("leave out --textile"));
        assert!(
            run(&|a| a.sensor = SensorSource::Replay { dir: "x".into() }).contains("live sensor")
        );
        assert!(run(&|a| {
            a.idle = None;
            a.textile = Some("T001".into());
            a.presses = Some(1);
            a.json = true;
        })
        .contains("--json is for --idle"));
        // A directory of presses is refused: "idle" would become a textile.
        let p = telextiles_sim::Simulator::new()
            .expect("sim")
            .render_press(&PressSpec {
                frames: 5,
                ..PressSpec::new("T001", 1)
            })
            .expect("press");
        telextiles_recording::recording::write_press(&d.path().join("T001/0001"), &p)
            .expect("write");
        assert!(run(&|_| {}).contains("holds presses of textiles"));
        assert!(!d.path().join("idle").exists());
    }
}
