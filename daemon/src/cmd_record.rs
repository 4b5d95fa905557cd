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
use std::str::FromStr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;

use anyhow::{bail, Context, Result};
use telextiles_progress::Progress;
use telextiles_sensing::contact::ContactDetector;
use telextiles_sensing::frame::Frame;
use telextiles_sensing::idle::{IdleCheck, IdleSummary};
use telextiles_sensing::record::{
    lead_with_reference, PressSummary, RecordEvent, RecordLabel, RecordedPress, Recorder,
    RecorderConfig,
};
use telextiles_sensing::source::recorded::{Pace, RecordedSource};
#[cfg(feature = "sim")]
use telextiles_sensing::source::sim::SimSource;
use telextiles_sensing::source::{FrameSource, SourceError};
#[cfg(feature = "sim")]
use telextiles_sim::{PressSpec, Simulator};

/// Where the frames come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SensorArg {
    /// A DIGIT (the first found, or this serial).
    Digit(Option<String>),
    /// The simulator.
    Sim,
    /// Re-record the presses found under a directory.
    Replay(PathBuf),
}

impl FromStr for SensorArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "digit" => Ok(SensorArg::Digit(None)),
            "sim" => Ok(SensorArg::Sim),
            _ => {
                if let Some(serial) = s.strip_prefix("digit:") {
                    if serial.is_empty() {
                        return Err("digit: needs a serial (digit:D20118), or say digit".into());
                    }
                    Ok(SensorArg::Digit(Some(serial.to_string())))
                } else if let Some(dir) = s.strip_prefix("replay:") {
                    if dir.is_empty() {
                        return Err("replay: needs a directory (replay:recordings/T030)".into());
                    }
                    Ok(SensorArg::Replay(PathBuf::from(dir)))
                } else {
                    Err(format!(
                        "unknown sensor {s:?}: say digit, digit:SERIAL, sim or replay:<dir>"
                    ))
                }
            }
        }
    }
}

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
    /// digit, digit:SERIAL, sim (simulated presses of --textile, unattended)
    /// or replay:<dir> (re-record the presses under <dir>).
    #[arg(long, default_value = "digit")]
    pub sensor: SensorArg,
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
}

/// A source and what its presses are labelled with.
struct Opened {
    frames: Frames,
    serial: Option<String>,
    sensor_unit: u32,
    jig: bool,
    source: &'static str,
    desc: String,
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
    if args.fps.is_some() && !matches!(args.sensor, SensorArg::Replay(_)) {
        bail!("--fps is for --sensor replay:<dir> (recordings saved without timestamps); a live sensor's frames carry their own");
    }
    if !args.references.is_empty() && !matches!(args.sensor, SensorArg::Replay(_)) {
        bail!("--reference is for --sensor replay:<dir> (recordings that carry no no-contact frames); a live sensor's is captured before each press");
    }
    match &args.sensor {
        SensorArg::Sim => open_sim(textile, presses, first_seed),
        SensorArg::Replay(dir) => {
            // The walk every command shares: press directories, else a
            // PyTouch-style dataset.
            let recordings = telextiles_recording::recording::find_recordings_at(dir, args.fps)
                .with_context(|| format!("no recordings to replay under {}", dir.display()))?;
            let references = telextiles_sensing::front::References::from_args(&args.references)?;
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
            })
        }
        SensorArg::Digit(serial) => open_digit(serial.clone()),
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
    })
}

#[cfg(not(feature = "sim"))]
fn open_sim(_textile: &str, _presses: Option<u32>, _first_seed: u64) -> Result<Opened> {
    Err(crate::sim_off("`record --sensor sim`"))
}

#[cfg(target_os = "linux")]
fn open_digit(serial: Option<String>) -> Result<Opened> {
    use telextiles_sensing::source::digit::{DigitOptions, DigitSource};
    let opts = DigitOptions {
        serial,
        ..Default::default()
    };
    let src = DigitSource::open(&opts).map_err(|e| {
        anyhow::anyhow!(
            "cannot open the DIGIT: {e}\n(plug the DIGIT in over USB, check `ls /dev/video*` and that you may read it (group video), or record without one: --sensor sim)"
        )
    })?;
    let info = src.info();
    let desc = format!("DIGIT {} on {}", info.serial, info.node.display());
    let serial = Some(info.serial.clone());
    Ok(Opened {
        frames: Frames::Live(Box::new(src), None),
        serial,
        sensor_unit: 0,
        jig: false,
        source: "digit",
        desc,
    })
}

#[cfg(not(target_os = "linux"))]
fn open_digit(_serial: Option<String>) -> Result<Opened> {
    bail!("the DIGIT is read over V4L2, which only Linux has; use --sensor sim or replay:<dir>")
}

fn check_id(id: &str) -> Result<()> {
    if id.is_empty()
        || id == "."
        || id == ".."
        || id.contains(['/', '\\'])
        || id.chars().any(|c| c.is_control())
    {
        bail!("textile id {id:?} cannot be a directory name: use letters, digits, - or _");
    }
    Ok(())
}

/// The next free press number in `dir` (1 when empty): one more than the
/// highest all-digit directory name.
pub fn next_number(dir: &Path) -> Result<u32> {
    let mut highest = 0u32;
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(1),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", dir.display())),
    };
    for e in rd {
        let name = e?.file_name().to_string_lossy().into_owned();
        if !name.is_empty() && name.bytes().all(|b| b.is_ascii_digit()) {
            if let Ok(n) = name.parse::<u32>() {
                highest = highest.max(n);
            }
        }
    }
    Ok(highest + 1)
}

/// Remove the temporaries of writes interrupted by a crash or `kill -9`
/// (`NNNN.tmp-<pid>-<n>` whose process is gone); returns how many.
fn remove_stale_temporaries(dir: &Path) -> usize {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut n = 0;
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((_, rest)) = name.split_once(".tmp-") else {
            continue;
        };
        let pid = rest.split('-').next().unwrap_or("");
        let alive = pid
            .parse::<u32>()
            .is_ok_and(|p| p == std::process::id() || Path::new("/proc").join(pid).exists());
        if !alive && std::fs::remove_dir_all(e.path()).is_ok() {
            n += 1;
        }
    }
    n
}

/// What `textile.json` holds.
#[derive(serde::Serialize, serde::Deserialize, Debug, PartialEq)]
pub struct TextileInfo {
    /// The id (the directory name).
    pub id: String,
    /// Its human-readable name.
    pub name: String,
}

/// Write `<dir>/textile.json` atomically (temporary file, then rename).
fn write_textile_info(dir: &Path, info: &TextileInfo) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("textile.json");
    let tmp = dir.join(format!(".textile.json.tmp-{}", std::process::id()));
    let json = serde_json::to_vec_pretty(info)?;
    std::fs::write(&tmp, json).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Writes presses on a thread of its own, so that a live sensor keeps
/// streaming while PNGs are encoded.
struct Writer {
    tx: Option<Sender<(u32, Box<RecordedPress>)>>,
    done: Receiver<Result<(u32, PathBuf, PressSummary)>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Writer {
    fn new(dir: PathBuf, mut number: u32) -> Writer {
        let (tx, rx) = channel::<(u32, Box<RecordedPress>)>();
        let (dtx, done) = channel();
        let thread = std::thread::spawn(move || {
            for (k, p) in rx {
                // Another run writing into the same directory may take a
                // number first: write_press refuses, take the next one.
                let result = loop {
                    let path = dir.join(format!("{number:04}"));
                    number += 1;
                    if path.exists() {
                        continue;
                    }
                    match telextiles_recording::recording::write_press(&path, &p.press) {
                        Ok(()) => break Ok((k, path, p.summary.clone())),
                        Err(_) if path.exists() => continue,
                        Err(e) => break Err(anyhow::Error::new(e)),
                    }
                };
                if dtx.send(result).is_err() {
                    return;
                }
            }
        });
        Writer {
            tx: Some(tx),
            done,
            thread: Some(thread),
        }
    }

    fn submit(&self, k: u32, p: Box<RecordedPress>) {
        if let Some(tx) = &self.tx {
            let _ = tx.send((k, p));
        }
    }

    /// Results so far, without waiting.
    fn ready(&self) -> Vec<Result<(u32, PathBuf, PressSummary)>> {
        self.done.try_iter().collect()
    }

    /// Wait for every submitted write.
    fn close(mut self) -> Vec<Result<(u32, PathBuf, PressSummary)>> {
        drop(self.tx.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.done.try_iter().collect()
    }
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
    let replay = matches!(args.sensor, SensorArg::Replay(_));
    let Some(textile) = args.textile.clone() else {
        if !replay {
            bail!(
                "--textile is needed with --sensor {}: its presses are labelled with it (only --sensor replay:<dir> can leave it out, to save each recording's presses under the recording's own textile)",
                sensor_name(&args.sensor)
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
            sensor_name(&args.sensor)
        );
    }
    record_one(&args, &textile, args.presses, out, stop)
}

fn sensor_name(s: &SensorArg) -> String {
    match s {
        SensorArg::Digit(None) => "digit".into(),
        SensorArg::Digit(Some(serial)) => format!("digit:{serial}"),
        SensorArg::Sim => "sim".into(),
        SensorArg::Replay(d) => format!("replay:{}", d.display()),
    }
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

/// `<out>/<textile>/`: temporaries of an interrupted run removed, and
/// `textile.json` written when a name is given.
fn prepare_dir(out: &Path, textile: &str, name: Option<&str>) -> Result<PathBuf> {
    let dir = out.join(textile);
    let stale = remove_stale_temporaries(&dir);
    if stale > 0 {
        eprintln!(
            "removed {stale} unfinished press(es) left in {} by an interrupted run",
            dir.display()
        );
    }
    if let Some(name) = name {
        write_textile_info(
            &dir,
            &TextileInfo {
                id: textile.to_string(),
                name: name.to_string(),
            },
        )?;
    }
    Ok(dir)
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
                let u = det.update(&frame.image, frame.timestamp_us);
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
                    let u = det.update(&frame.image, frame.timestamp_us);
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

/// A recording started over the control socket (`record.start`): the
/// live session's sensing thread feeds it every frame with its contact
/// update ([`LiveRecording::push`]); it writes presses on a thread of its
/// own and reports on the control socket's event channel.
pub struct LiveRecording {
    rec: Recorder,
    writer: Option<Writer>,
    textile: String,
    total: u32,
    submitted: u32,
    saved: u32,
    hold_ms: f64,
    /// Next hold-progress event due at this many ms held.
    next_hold_ms: f64,
    said_release: bool,
    failed: Option<String>,
}

impl std::fmt::Debug for LiveRecording {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LiveRecording")
            .field("textile", &self.textile)
            .field("presses", &self.total)
            .field("saved", &self.saved)
            .finish_non_exhaustive()
    }
}

/// What the control handler asks of the sensing thread.
#[derive(Debug)]
pub enum RecordCtl {
    /// Start this recording (stopping one that runs).
    Start(Box<LiveRecording>),
    /// Stop the recording; the answer is how many presses it saved (None:
    /// none was running).
    Stop(tokio::sync::oneshot::Sender<Option<u32>>),
}

impl RecordCtl {
    /// Apply to the sensing thread's recording slot.
    pub fn apply(
        self,
        slot: &mut Option<LiveRecording>,
        send: &mut dyn FnMut(telextiles_control::Event),
    ) {
        match self {
            RecordCtl::Start(new) => {
                if let Some(old) = slot.take() {
                    old.stop("replaced by a new record.start", send);
                }
                *slot = Some(*new);
            }
            RecordCtl::Stop(answer) => {
                let saved = slot.take().map(|r| r.stop("record.stop", send));
                let _ = answer.send(saved);
            }
        }
    }
}

/// Hold-progress events over the socket are sent this often (ms held).
pub const LIVE_HOLD_EVERY_MS: f64 = 250.0;

/// What the sensor is, for the metadata of presses recorded by the daemon:
/// ("sim" | "replay" | "digit", serial) from the session's description of
/// its source ("DIGIT D20118 on /dev/video0", "simulated DIGIT ...",
/// "replay of ...").
pub fn label_from_description(desc: &str) -> (&'static str, Option<String>) {
    if desc.starts_with("simulated") {
        ("sim", Some("SIM0000".into()))
    } else if desc.starts_with("replay") {
        ("replay", None)
    } else {
        let serial = desc
            .strip_prefix("DIGIT ")
            .and_then(|r| r.split_whitespace().next())
            .map(str::to_string);
        ("digit", serial)
    }
}

impl LiveRecording {
    /// Prepare a recording of `args` (checks the id, creates
    /// `<out>/<textile>/`, writes textile.json for a name, finds the next
    /// free number); `source`/`serial` label the presses. The reply data
    /// for `record.start` comes with it.
    pub fn start(
        args: &telextiles_control::RecordStartArgs,
        source: &str,
        serial: Option<String>,
    ) -> Result<(LiveRecording, serde_json::Value)> {
        check_id(&args.textile)?;
        if args.presses == 0 {
            bail!("presses must be at least 1");
        }
        let dir = Path::new(&args.out).join(&args.textile);
        std::fs::create_dir_all(&dir)
            .with_context(|| format!("cannot create {}", dir.display()))?;
        remove_stale_temporaries(&dir);
        let first = next_number(&dir)?;
        if let Some(name) = &args.name {
            write_textile_info(
                &dir,
                &TextileInfo {
                    id: args.textile.clone(),
                    name: name.clone(),
                },
            )?;
        }
        let label = RecordLabel {
            textile: args.textile.clone(),
            source: source.to_string(),
            sensor_serial: serial,
            sensor: 0,
            person: 0,
            jig: false,
        };
        let reply = serde_json::json!({
            "textile": args.textile,
            "presses": args.presses,
            "dir": dir.display().to_string(),
            "first": format!("{first:04}"),
        });
        Ok((
            LiveRecording {
                rec: Recorder::new(RecorderConfig::default(), label),
                writer: Some(Writer::new(dir.clone(), first)),
                textile: args.textile.clone(),
                total: args.presses,
                submitted: 0,
                saved: 0,
                hold_ms: 1500.0,
                next_hold_ms: 0.0,
                said_release: false,
                failed: None,
            },
            reply,
        ))
    }

    fn state(
        &self,
        state: telextiles_control::RecordPhase,
        held_ms: Option<f64>,
        score: Option<f32>,
        reason: Option<String>,
    ) -> telextiles_control::Event {
        telextiles_control::Event::Record {
            state,
            textile: self.textile.clone(),
            press: (self.submitted + 1).min(self.total),
            presses: self.total,
            held_ms,
            score,
            reason,
        }
    }

    /// Feed one frame and its contact update; events go to `send`. True
    /// when the recording is over (all presses written, or a write failed).
    pub fn push(
        &mut self,
        frame: &Frame,
        update: &telextiles_sensing::contact::ContactUpdate,
        send: &mut dyn FnMut(telextiles_control::Event),
    ) -> bool {
        if self.submitted < self.total {
            self.rec.push(frame, update);
        }
        self.pump(send)
    }

    fn pump(&mut self, send: &mut dyn FnMut(telextiles_control::Event)) -> bool {
        use telextiles_control::{Event, RecordPhase as P};
        while let Some(e) = self.rec.poll() {
            if self.submitted >= self.total {
                continue;
            }
            match e {
                RecordEvent::WaitingForReference => send(self.state(P::Waiting, None, None, None)),
                RecordEvent::Ready => send(self.state(P::Ready, None, None, None)),
                RecordEvent::PressStarted { .. } => {
                    self.next_hold_ms = LIVE_HOLD_EVERY_MS;
                    self.said_release = false;
                    send(self.state(P::Contact, Some(0.0), None, None));
                }
                RecordEvent::Holding { held_ms, score, .. } => {
                    if held_ms >= self.next_hold_ms {
                        self.next_hold_ms = (held_ms / LIVE_HOLD_EVERY_MS).floor()
                            * LIVE_HOLD_EVERY_MS
                            + LIVE_HOLD_EVERY_MS;
                        send(self.state(P::Holding, Some(held_ms), Some(score), None));
                    }
                    if !self.said_release && held_ms >= self.hold_ms {
                        self.said_release = true;
                        send(self.state(P::Release, Some(held_ms), Some(score), None));
                    }
                }
                RecordEvent::Released { held_ms, peak } => {
                    send(self.state(P::Released, Some(held_ms), Some(peak), None))
                }
                RecordEvent::Rejected(w) => send(Event::RecordWarning {
                    textile: self.textile.clone(),
                    press: self.submitted + 1,
                    code: w.code().into(),
                    message: w.to_string(),
                    rejected: true,
                }),
                RecordEvent::PressComplete(p) => {
                    self.submitted += 1;
                    for w in &p.summary.warnings {
                        send(Event::RecordWarning {
                            textile: self.textile.clone(),
                            press: self.submitted,
                            code: w.code().into(),
                            message: w.to_string(),
                            rejected: false,
                        });
                    }
                    if let Some(w) = &self.writer {
                        w.submit(self.submitted, p);
                    }
                }
            }
        }
        let results = self.writer.as_ref().map(Writer::ready).unwrap_or_default();
        self.report(results, send);
        if self.failed.is_some() {
            return true;
        }
        if self.saved >= self.total {
            if let Some(w) = self.writer.take() {
                let rest = w.close();
                self.report(rest, send);
            }
            send(Event::Record {
                state: P::Done,
                textile: self.textile.clone(),
                press: self.total,
                presses: self.total,
                held_ms: None,
                score: None,
                reason: None,
            });
            return true;
        }
        false
    }

    fn report(
        &mut self,
        results: Vec<Result<(u32, PathBuf, PressSummary)>>,
        send: &mut dyn FnMut(telextiles_control::Event),
    ) {
        for r in results {
            match r {
                Ok((k, path, s)) => {
                    self.saved += 1;
                    send(telextiles_control::Event::RecordSaved {
                        textile: self.textile.clone(),
                        press: k,
                        presses: self.total,
                        path: path.display().to_string(),
                        frames: s.frames as u32,
                        duration_ms: s.duration_ms,
                        peak: s.peak,
                        reference_frames: s.reference_frames,
                        fps: s.fps,
                        warnings: s.warnings.iter().map(|w| w.code().to_string()).collect(),
                    });
                }
                Err(e) => {
                    let why = format!("cannot save a press: {e:#}");
                    send(telextiles_control::Event::Error {
                        source: "record".into(),
                        message: why.clone(),
                    });
                    send(self.state(
                        telextiles_control::RecordPhase::Stopped,
                        None,
                        None,
                        Some(why.clone()),
                    ));
                    self.failed = Some(why);
                }
            }
        }
    }

    /// Stop (`record.stop`, a new `record.start`, the session ending): the
    /// press in progress is dropped, presses already complete are written;
    /// a `stopped` event says why.
    /// Returns the presses saved.
    pub fn stop(mut self, reason: &str, send: &mut dyn FnMut(telextiles_control::Event)) -> u32 {
        if let Some(w) = self.writer.take() {
            let rest = w.close();
            self.report(rest, send);
        }
        if self.failed.is_none() {
            send(self.state(
                telextiles_control::RecordPhase::Stopped,
                None,
                None,
                Some(format!(
                    "{reason} ({} of {} presses saved)",
                    self.saved, self.total
                )),
            ));
        }
        self.saved
    }
}

/// The longest `--idle` recording, seconds.
pub const MAX_IDLE_S: f64 = 600.0;

/// `--idle` with `--sensor sim`: the simulator's idle footage of unit 0.
#[cfg(feature = "sim")]
fn idle_sim(args: &Args, seconds: f64) -> Result<IdleSource> {
    let sim = Simulator::new()?;
    let spec = PressSpec::new("T001", args.sim_seed.unwrap_or(1));
    let fps = sim.press_meta(&spec)?.fps as f64;
    let n = ((seconds * fps).round() as usize).max(1);
    let clip = sim.idle_clip(&PressSpec { frames: n, ..spec })?;
    let src = IdleSimSource { sim, clip, next: 0 };
    Ok(IdleSource {
        desc: src.describe(),
        frames: Box::new(src),
        serial: "SIM0000".to_string(),
        source: "sim",
    })
}

#[cfg(not(feature = "sim"))]
fn idle_sim(_args: &Args, _seconds: f64) -> Result<IdleSource> {
    Err(crate::sim_off("`record --idle --sensor sim`"))
}

/// The simulator's idle footage of a unit as a frame source (as fast as
/// it renders; `Ended` after the clip).
#[cfg(feature = "sim")]
struct IdleSimSource {
    sim: Simulator,
    clip: telextiles_sim::IdleClip,
    next: usize,
}

#[cfg(feature = "sim")]
impl FrameSource for IdleSimSource {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        if self.next >= self.clip.len() {
            return Err(SourceError::Ended);
        }
        out.image = self
            .sim
            .idle_frame(&self.clip, self.next)
            .map_err(|e| SourceError::Fatal(format!("simulator: {e}")))?;
        out.timestamp_us = self.clip.timestamps_us[self.next];
        out.seq = self.next as u64;
        self.next += 1;
        Ok(())
    }
    fn describe(&self) -> String {
        "the simulated DIGIT (unit 0), untouched".into()
    }
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
        SensorArg::Replay(_) => bail!(
            "--idle records a live sensor (--sensor digit[:SERIAL], or sim): footage of a resting sensor, not presses to replay"
        ),
        SensorArg::Sim => idle_sim(args, seconds)?,
        SensorArg::Digit(serial) => {
            let opened = open_digit(serial.clone())?;
            let Frames::Live(src, _) = opened.frames else {
                bail!("a DIGIT is a live source");
            };
            IdleSource {
                frames: src,
                serial: opened.serial.unwrap_or_default(),
                source: "digit",
                desc: opened.desc,
            }
        }
    };
    run_idle(args, seconds, src, out, stop)
}

/// An opened source of idle footage and what it is.
struct IdleSource {
    frames: Box<dyn FrameSource>,
    serial: String,
    source: &'static str,
    desc: String,
}

/// Record `seconds` of `src` into `<out>/idle/NNNN/` with the idle check.
fn run_idle(
    args: &Args,
    seconds: f64,
    src: IdleSource,
    out: &mut dyn Write,
    stop: &AtomicBool,
) -> Result<()> {
    let IdleSource {
        mut frames,
        serial,
        source,
        desc,
    } = src;
    let contact = args.contact.contact()?;
    let dir = args.out.join("idle");
    remove_stale_temporaries(&dir);
    let number = next_number(&dir)?;
    let path = dir.join(format!("{number:04}"));
    eprintln!(
        "recording {seconds} s of {desc} into {}: do not touch the sensor",
        path.display()
    );
    let mut writer = telextiles_recording::recording::PressWriter::create(&path)?;
    let mut check = IdleCheck::new(contact);
    let progress = Progress::new("idle", seconds.ceil() as u64, "s");
    let mut frame = Frame::blank();
    let mut timestamps = Vec::new();
    let mut first = None;
    let mut shown = 0u64;
    let mut interrupted = false;
    // The first frames' mean: the sensor's no-contact frame, kept beside
    // the recordings if the check finds the sensor at rest.
    let mut rest_sum = vec![0.0f32; telextiles_sensing::frame::FRAME_BYTES];
    let mut rest_n = 0u32;
    loop {
        if stop.load(Ordering::SeqCst) {
            interrupted = true;
            break;
        }
        match frames.next_frame(&mut frame) {
            Ok(()) => {}
            Err(SourceError::BadFrame(e)) => {
                tracing::warn!("bad frame skipped: {e}");
                continue;
            }
            Err(SourceError::Ended) => break,
            Err(e) => bail!(
                "{e}: the sensor stopped after {} frames; nothing saved",
                timestamps.len()
            ),
        }
        let t0 = *first.get_or_insert(frame.timestamp_us);
        let t = frame.timestamp_us.saturating_sub(t0);
        if t as f64 >= seconds * 1e6 {
            break;
        }
        let u = check.push(&frame.image, t);
        if let Some(telextiles_sensing::contact::ContactEvent::PressStart { t_us }) = u.event {
            progress.println(&format!(
                "a press started at {:.2} s on the untouched sensor",
                t_us as f64 / 1e6
            ));
        }
        writer
            .push(&frame.image)
            .with_context(|| format!("cannot write {}", path.display()))?;
        if rest_n < NO_CONTACT_FRAMES {
            rest_sum
                .iter_mut()
                .zip(frame.image.as_raw())
                .for_each(|(a, &v)| *a += v as f32);
            rest_n += 1;
        }
        timestamps.push(t);
        let s = t / 1_000_000;
        if s > shown {
            progress.inc(s - shown);
            shown = s;
        }
    }
    progress.finish();
    if timestamps.is_empty() {
        bail!("no frame was recorded (interrupted at once); nothing saved");
    }
    let summary = check.summary();
    let meta = telextiles_recording::PressMeta {
        textile: "idle".into(),
        person: 0,
        sensor: 0,
        jig: false,
        fps: summary.fps as f32,
        timestamps_us: timestamps,
        seed: (source == "sim").then(|| args.sim_seed.unwrap_or(1)),
        source: source.into(),
        sensor_serial: Some(serial.clone()),
        params: None,
        // The whole clip is untouched.
        reference_frames: None,
    };
    writer
        .finish(&meta)
        .with_context(|| format!("cannot write {}", path.display()))?;
    write_idle_summary(out, &summary, &path, interrupted)?;
    if summary.ok() {
        rest_sum.iter_mut().for_each(|v| *v /= rest_n.max(1) as f32);
        let png = args.out.join(format!(
            "{}-{serial}.png",
            telextiles_sensing::front::NO_CONTACT
        ));
        write_no_contact(&png, &rest_sum)?;
        writeln!(
            out,
            "no-contact frame of sensor {serial}: {} (keep it beside your index or your recordings: classify and index build use it for recordings that begin in contact)",
            png.display()
        )?;
    }
    if args.json {
        writeln!(out, "{}", serde_json::to_string(&summary)?)?;
    }
    if !summary.ok() {
        bail!(
            "the contact detector started {} press(es) on the untouched sensor: check that nothing touched it and that the LEDs are steady, and keep {} for a report",
            summary.false_presses,
            path.display()
        );
    }
    Ok(())
}

/// Frames averaged into the no-contact frame `record --idle` keeps.
const NO_CONTACT_FRAMES: u32 = 30;

/// Write a no-contact frame (240x320 RGB values) as a PNG, atomically.
fn write_no_contact(path: &Path, pixels: &[f32]) -> Result<()> {
    let image =
        telextiles_sensing::front::image_of(pixels).context("a no-contact frame is 240x320 RGB")?;
    // A hidden temporary beside it (no reader takes a dot file), renamed
    // over it once whole.
    let name = path.file_name().context("not a file path")?;
    let tmp = path.with_file_name(format!(".{}.tmp.png", name.to_string_lossy()));
    let written = image
        .save(&tmp)
        .map_err(anyhow::Error::from)
        .and_then(|()| std::fs::rename(&tmp, path).map_err(anyhow::Error::from));
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.with_context(|| format!("cannot write {}", path.display()))
}

fn write_idle_summary(
    out: &mut dyn Write,
    s: &IdleSummary,
    path: &Path,
    interrupted: bool,
) -> Result<()> {
    writeln!(
        out,
        "saved {} frames ({:.1} s at {:.1} fps{}) in {}",
        s.frames,
        s.seconds,
        s.fps,
        if interrupted { ", interrupted" } else { "" },
        path.display()
    )?;
    let starts = if s.press_starts_s.is_empty() {
        String::new()
    } else {
        format!(
            " (at {} s)",
            s.press_starts_s
                .iter()
                .map(|t| format!("{t:.2}"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    };
    writeln!(
        out,
        "contact detector at rest: {} false press(es){starts}, {:.1} % of the time in contact, {:.1} % re-capturing the reference",
        s.false_presses,
        100.0 * s.in_contact_share,
        100.0 * s.capturing_share
    )?;
    writeln!(
        out,
        "noise floor {:.2}; highest score above it held {} frames in a row: {:.3}, against {:.2} to start a press (margin {:.3})",
        s.floor, s.run_frames, s.peak_run, s.enter, s.margin
    )?;
    writeln!(
        out,
        "{}",
        if s.ok() {
            "ok: no press started at rest"
        } else {
            "FAILED: the detector started presses on the untouched sensor"
        }
    )?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use telextiles_sensing::contact::ContactConfig;

    #[test]
    fn sensor_argument_parses() {
        assert_eq!("digit".parse(), Ok(SensorArg::Digit(None)));
        assert_eq!(
            "digit:D20118".parse(),
            Ok(SensorArg::Digit(Some("D20118".into())))
        );
        assert_eq!("sim".parse(), Ok(SensorArg::Sim));
        assert_eq!(
            "replay:rec/T030".parse(),
            Ok(SensorArg::Replay(PathBuf::from("rec/T030")))
        );
        assert!("digit:".parse::<SensorArg>().is_err());
        assert!("replay:".parse::<SensorArg>().is_err());
        assert!("webcam".parse::<SensorArg>().is_err());
    }

    #[test]
    fn next_free_number_skips_temporaries_and_files() {
        let d = tempfile::tempdir().expect("tempdir");
        assert_eq!(next_number(&d.path().join("absent")).expect("n"), 1);
        std::fs::create_dir(d.path().join("0001")).expect("mkdir");
        std::fs::create_dir(d.path().join("0007")).expect("mkdir");
        std::fs::create_dir(d.path().join("0009.tmp-1-0")).expect("mkdir");
        std::fs::write(d.path().join("textile.json"), "{}").expect("write");
        assert_eq!(next_number(d.path()).expect("n"), 8);
    }

    #[test]
    fn textile_ids_must_be_directory_names() {
        assert!(check_id("T030").is_ok());
        assert!(check_id("my-denim_2").is_ok());
        for bad in ["", ".", "..", "a/b", "a\\b", "x\ny"] {
            assert!(check_id(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn stale_temporaries_of_dead_processes_are_removed() {
        let d = tempfile::tempdir().expect("tempdir");
        // pid 0 is never a process of ours; our own pid is alive.
        std::fs::create_dir(d.path().join("0003.tmp-0-0")).expect("mkdir");
        let mine = format!("0004.tmp-{}-0", std::process::id());
        std::fs::create_dir(d.path().join(&mine)).expect("mkdir");
        std::fs::create_dir(d.path().join("0002")).expect("mkdir");
        assert_eq!(remove_stale_temporaries(d.path()), 1);
        assert!(!d.path().join("0003.tmp-0-0").exists());
        assert!(d.path().join(&mine).exists());
        assert!(d.path().join("0002").exists());
    }

    /// `record --idle` arguments into `out`.
    fn idle_args(out: &Path) -> Args {
        Args {
            textile: None,
            name: None,
            presses: None,
            out: out.to_path_buf(),
            sensor: SensorArg::Sim,
            sim_seed: None,
            hold: 1.5,
            fps: None,
            references: Vec::new(),
            idle: Some(10.0),
            json: false,
            contact: Default::default(),
        }
    }

    /// Idle footage of the simulator's unit 0 with, from frame `touch_at`,
    /// `touch_len` frames of a press's hold between (a hand on the sensor),
    /// as a live source.
    fn touched_idle(frames: usize, touch_at: usize, touch_len: usize) -> IdleSource {
        let sim = Simulator::new().expect("simulator");
        let spec = PressSpec {
            frames,
            ..PressSpec::new("T030", 3)
        };
        let clip = sim.idle_clip(&spec).expect("clip");
        let press = sim.render_press(&PressSpec::new("T030", 3)).expect("press");
        let hold = press.meta.params.as_ref().expect("params").hold_frame as usize;
        let images = (0..frames)
            .map(|i| {
                if (touch_at..touch_at + touch_len).contains(&i) {
                    press.frames[hold + i - touch_at].clone()
                } else {
                    sim.idle_frame(&clip, i).expect("frame")
                }
            })
            .collect();
        let footage = telextiles_recording::Press {
            meta: telextiles_recording::PressMeta {
                timestamps_us: clip.timestamps_us.clone(),
                params: None,
                ..press.meta.clone()
            },
            frames: images,
        };
        IdleSource {
            frames: Box::new(RecordedSource::from_press(
                footage,
                Pace::AsFastAsPossible,
                "test",
            )),
            serial: "D00001".into(),
            source: "digit",
            desc: "a test DIGIT".into(),
        }
    }

    #[test]
    fn idle_footage_with_a_touch_fails_the_check_and_is_kept_whole() {
        let d = tempfile::tempdir().expect("tempdir");
        let mut out = Vec::new();
        let stop = AtomicBool::new(false);
        // 4 s at 60 fps, touched for half a second from 2 s.
        let err = run_idle(
            &idle_args(d.path()),
            10.0,
            touched_idle(240, 120, 30),
            &mut out,
            &stop,
        )
        .expect_err("a touch is a press");
        let text = String::from_utf8(out).expect("utf-8");
        assert!(
            err.to_string().contains("started 1 press(es)"),
            "{err}\n{text}"
        );
        assert!(text.contains("1 false press(es) (at 2."), "{text}");
        assert!(text.contains("FAILED"), "{text}");
        // The footage is kept, every frame, for a report.
        let kept =
            telextiles_recording::recording::read_press(&d.path().join("idle/0001")).expect("kept");
        assert_eq!(kept.frames.len(), 240);
        assert_eq!(kept.meta.textile, "idle");
        assert_eq!(kept.meta.sensor_serial.as_deref(), Some("D00001"));
        assert_eq!(kept.meta.timestamps_us[0], 0);
        // A second run goes next to it, and untouched footage passes.
        let mut out = Vec::new();
        run_idle(
            &idle_args(d.path()),
            2.0,
            touched_idle(240, 1000, 0),
            &mut out,
            &stop,
        )
        .expect("untouched passes");
        let text = String::from_utf8(out).expect("utf-8");
        assert!(
            text.contains("saved 120 frames (2.0 s at 60.0 fps)"),
            "{text}"
        );
        assert!(
            text.contains("0 false press(es)") && text.contains("ok:"),
            "{text}"
        );
        assert!(d.path().join("idle/0002/press.json").is_file());
    }

    /// How a [`CutShort`] source ends.
    enum Then {
        /// The DIGIT is unplugged.
        Unplugged,
        /// Ctrl-C is pressed (sets [`STOP`]); the frames go on.
        CtrlC,
    }
    static STOP: AtomicBool = AtomicBool::new(false);
    /// A source that delivers `n` frames of another, then ends as `Then` says.
    struct CutShort(Box<dyn FrameSource>, usize, Then);
    impl FrameSource for CutShort {
        fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
            if self.1 == 0 {
                match self.2 {
                    Then::Unplugged => {
                        return Err(SourceError::Unavailable("DIGIT unplugged".into()))
                    }
                    Then::CtrlC => STOP.store(true, Ordering::SeqCst),
                }
            } else {
                self.1 -= 1;
            }
            self.0.next_frame(out)
        }
        fn describe(&self) -> String {
            "cut short".into()
        }
    }

    /// [`touched_idle`] (untouched), cut short.
    fn cut_short(frames: usize, after: usize, then: Then) -> IdleSource {
        let inner = touched_idle(frames, frames, 0);
        IdleSource {
            frames: Box::new(CutShort(inner.frames, after, then)),
            ..inner
        }
    }

    #[test]
    fn idle_recording_cut_short_by_the_sensor_or_at_once_leaves_nothing() {
        let d = tempfile::tempdir().expect("tempdir");
        let stop = AtomicBool::new(false);
        let src = cut_short(60, 30, Then::Unplugged);
        let err = run_idle(&idle_args(d.path()), 5.0, src, &mut Vec::new(), &stop)
            .expect_err("unplugged");
        let msg = err.to_string();
        assert!(
            msg.contains("unplugged") && msg.contains("after 30 frames; nothing saved"),
            "{msg}"
        );
        // Interrupted before the first frame: nothing either.
        let stop = AtomicBool::new(true);
        let err = run_idle(
            &idle_args(d.path()),
            5.0,
            touched_idle(60, 100, 0),
            &mut Vec::new(),
            &stop,
        )
        .expect_err("interrupted");
        assert!(err.to_string().contains("nothing saved"), "{err}");
        let left: Vec<_> = std::fs::read_dir(d.path().join("idle"))
            .expect("idle dir")
            .collect();
        assert!(left.is_empty(), "{left:?}");
    }

    #[test]
    fn idle_recording_interrupted_keeps_and_checks_what_it_recorded() {
        let d = tempfile::tempdir().expect("tempdir");
        let src = cut_short(200, 90, Then::CtrlC);
        let mut out = Vec::new();
        run_idle(&idle_args(d.path()), 10.0, src, &mut out, &STOP).expect("saved");
        let text = String::from_utf8(out).expect("utf-8");
        assert!(
            text.contains("saved 91 frames (1.5 s at 60.0 fps, interrupted)"),
            "{text}"
        );
        assert!(text.contains("ok:"), "{text}");
        let kept =
            telextiles_recording::recording::read_press(&d.path().join("idle/0001")).expect("kept");
        assert_eq!(kept.frames.len(), 91);
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
        assert!(run(&|a| a.sensor = SensorArg::Replay("x".into())).contains("live sensor"));
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

    fn sim_frames(textile: &str) -> SimSource {
        let sim = Arc::new(Simulator::new().expect("simulator"));
        SimSource::new(
            sim,
            PressSpec::new(textile, 1),
            SIM_GAP_FRAMES,
            Pace::AsFastAsPossible,
        )
        .expect("sim source")
        .0
    }

    #[test]
    fn live_recording_reports_events_and_writes_presses() {
        use telextiles_control::{Event, RecordPhase, RecordStartArgs};
        let d = tempfile::tempdir().expect("tempdir");
        std::fs::create_dir_all(d.path().join("T030/0001")).expect("mkdir");
        let args = RecordStartArgs {
            textile: "T030".into(),
            name: Some("twill".into()),
            presses: 2,
            out: d.path().to_str().expect("utf-8").into(),
        };
        let (mut live, reply) =
            LiveRecording::start(&args, "sim", Some("SIM0000".into())).expect("start");
        assert_eq!(reply["first"], "0002");
        assert_eq!(reply["presses"], 2);
        let mut src = sim_frames("T030");
        let mut det = ContactDetector::new(ContactConfig::default());
        let mut frame = Frame::blank();
        let mut events = Vec::new();
        let mut finished = false;
        for _ in 0..3000 {
            src.next_frame(&mut frame).expect("frame");
            let u = det.update(&frame.image, frame.timestamp_us);
            if live.push(&frame, &u, &mut |e| events.push(e)) {
                finished = true;
                break;
            }
        }
        assert!(finished, "{events:?}");
        let states: Vec<RecordPhase> = events
            .iter()
            .filter_map(|e| match e {
                Event::Record { state, .. } => Some(*state),
                _ => None,
            })
            .collect();
        assert_eq!(states.first(), Some(&RecordPhase::Waiting));
        assert_eq!(states.last(), Some(&RecordPhase::Done));
        for want in [
            RecordPhase::Ready,
            RecordPhase::Contact,
            RecordPhase::Holding,
            RecordPhase::Release,
            RecordPhase::Released,
        ] {
            assert!(states.contains(&want), "{want:?} missing: {states:?}");
        }
        // Hold progress is rate-limited (every 250 ms of a ~2 s press).
        let holding = states
            .iter()
            .filter(|s| **s == RecordPhase::Holding)
            .count();
        assert!((4..=30).contains(&holding), "{holding} holding events");
        let saved: Vec<(u32, String)> = events
            .iter()
            .filter_map(|e| match e {
                Event::RecordSaved { press, path, .. } => Some((*press, path.clone())),
                _ => None,
            })
            .collect();
        assert_eq!(saved.len(), 2, "{events:?}");
        assert_eq!(saved[0].0, 1);
        assert!(saved[0].1.ends_with("T030/0002"), "{}", saved[0].1);
        assert!(saved[1].1.ends_with("T030/0003"), "{}", saved[1].1);
        let m = telextiles_recording::recording::read_meta(Path::new(&saved[0].1)).expect("meta");
        assert_eq!(m.source, "sim");
        assert_eq!(m.sensor_serial.as_deref(), Some("SIM0000"));
        assert_eq!(m.reference_frames, Some(30));
        let info = std::fs::read_to_string(d.path().join("T030/textile.json")).expect("json");
        assert!(info.contains("twill"));
        assert_eq!(live.saved, 2);
    }

    #[test]
    fn live_recording_stop_drops_the_press_in_progress() {
        use telextiles_control::{Event, RecordPhase, RecordStartArgs};
        let d = tempfile::tempdir().expect("tempdir");
        let args = RecordStartArgs {
            textile: "T030".into(),
            name: None,
            presses: 3,
            out: d.path().to_str().expect("utf-8").into(),
        };
        let (mut live, _) = LiveRecording::start(&args, "digit", None).expect("start");
        let mut src = sim_frames("T030");
        let mut det = ContactDetector::new(ContactConfig::default());
        let mut frame = Frame::blank();
        let mut events = Vec::new();
        // Into the first press, not out of it.
        for _ in 0..(SIM_GAP_FRAMES + 80) {
            src.next_frame(&mut frame).expect("frame");
            let u = det.update(&frame.image, frame.timestamp_us);
            assert!(!live.push(&frame, &u, &mut |e| events.push(e)));
        }
        let mut slot = Some(live);
        let (tx, mut rx) = tokio::sync::oneshot::channel();
        RecordCtl::Stop(tx).apply(&mut slot, &mut |e| events.push(e));
        assert!(slot.is_none());
        assert_eq!(rx.try_recv(), Ok(Some(0)));
        // Nothing running: the answer says so.
        let (tx, mut rx) = tokio::sync::oneshot::channel();
        RecordCtl::Stop(tx).apply(&mut slot, &mut |_| panic!("no event"));
        assert_eq!(rx.try_recv(), Ok(None));
        match events.last() {
            Some(Event::Record {
                state: RecordPhase::Stopped,
                reason: Some(r),
                ..
            }) => assert_eq!(r, "record.stop (0 of 3 presses saved)"),
            other => panic!("{other:?}"),
        }
        assert!(!events
            .iter()
            .any(|e| matches!(e, Event::RecordSaved { .. })));
        assert_eq!(next_number(&d.path().join("T030")).expect("n"), 1);
    }

    #[test]
    fn session_descriptions_label_presses() {
        assert_eq!(
            label_from_description("DIGIT D20118 on /dev/video0"),
            ("digit", Some("D20118".into()))
        );
        assert_eq!(
            label_from_description("simulated DIGIT pressing T030 repeatedly"),
            ("sim", Some("SIM0000".into()))
        );
        assert_eq!(
            label_from_description("replay of rec/0001"),
            ("replay", None)
        );
    }
}
