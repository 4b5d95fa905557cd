//! `record --idle SECONDS`: the untouched sensor recorded as one
//! continuous recording `<out>/idle/NNNN/`, written frame by frame, while
//! the daemon's contact detector runs on every frame
//! ([`telextiles_sensing::idle::IdleCheck`]); the summary says whether it
//! started presses that nobody made, and how close its score came.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use anyhow::{bail, Context, Result};
use telextiles_progress::Progress;
use telextiles_sensing::frame::Frame;
use telextiles_sensing::idle::{IdleCheck, IdleSummary};
use telextiles_sensing::source::{FrameSource, SourceError};
#[cfg(feature = "sim")]
use telextiles_sim::{PressSpec, Simulator};

use crate::press_dir::*;

/// What `record --idle` was asked besides the source and the length.
pub(crate) struct IdleOptions {
    /// The recordings' root: the footage goes to `<out>/idle/NNNN/`.
    pub(crate) out: PathBuf,
    /// The contact detector checked on the footage.
    pub(crate) contact: telextiles_sensing::contact::ContactConfig,
    /// The summary as one JSON object.
    pub(crate) json: bool,
    /// The simulated sensor's seed (in the metadata when simulated).
    pub(crate) sim_seed: Option<u64>,
}

/// The longest `--idle` recording, seconds.
pub(crate) const MAX_IDLE_S: f64 = 600.0;

/// `--idle` with `--sensor sim`: the simulator's idle footage of unit 0.
#[cfg(feature = "sim")]
pub(crate) fn idle_sim(sim_seed: Option<u64>, seconds: f64) -> Result<IdleSource> {
    let sim = Simulator::new()?;
    let spec = PressSpec::new("T001", sim_seed.unwrap_or(1));
    let fps = sim.press_meta(&spec)?.fps as f64;
    let n = ((seconds * fps).round() as usize).max(1);
    let clip = sim.idle_clip(&PressSpec { frames: n, ..spec })?;
    let src = IdleSimSource { sim, clip, next: 0 };
    Ok(IdleSource {
        desc: src.describe(),
        frames: Box::new(src),
        serial: "SIM0000".to_string(),
        source: "sim",
        profile: &telextiles_recording::profile::DIGIT,
    })
}

#[cfg(not(feature = "sim"))]
pub(crate) fn idle_sim(_sim_seed: Option<u64>, _seconds: f64) -> Result<IdleSource> {
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
        out.set_image(
            self.sim
                .idle_frame(&self.clip, self.next)
                .map_err(|e| SourceError::Fatal(format!("simulator: {e}")))?,
        )?;
        out.set_time(self.clip.timestamps_us[self.next], self.next as u64);
        self.next += 1;
        Ok(())
    }
    fn describe(&self) -> String {
        "the simulated DIGIT (unit 0), untouched".into()
    }
}

/// An opened source of idle footage and what it is.
pub(crate) struct IdleSource {
    pub(crate) frames: Box<dyn FrameSource>,
    pub(crate) serial: String,
    pub(crate) source: &'static str,
    pub(crate) desc: String,
    /// The sensor's profile (the footage is saved with it).
    pub(crate) profile: &'static telextiles_recording::profile::SensorProfile,
}

/// Record `seconds` of `src` into `<out>/idle/NNNN/` with the idle check.
pub(crate) fn run_idle(
    args: &IdleOptions,
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
        profile,
    } = src;
    let contact = args.contact.clone();
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
        let t0 = *first.get_or_insert(frame.timestamp_us());
        let t = frame.timestamp_us().saturating_sub(t0);
        if t as f64 >= seconds * 1e6 {
            break;
        }
        let u = check.push(frame.image(), t);
        if let Some(telextiles_sensing::contact::ContactEvent::PressStart { t_us }) = u.event {
            progress.println(&format!(
                "a press started at {:.2} s on the untouched sensor",
                t_us as f64 / 1e6
            ));
        }
        writer
            .push(frame.image())
            .with_context(|| format!("cannot write {}", path.display()))?;
        if rest_n < NO_CONTACT_FRAMES {
            rest_sum
                .iter_mut()
                .zip(frame.image().as_raw())
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
        // Saved as frames: at the frame's scale, whatever the sensor.
        sensor_profile: telextiles_recording::profile_tag(profile),
        mm_per_px: (profile.name != telextiles_recording::profile::DIGIT.name)
            .then_some(telextiles_recording::profile::FRAME_MM_PER_PX),
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
    use telextiles_sensing::source::recorded::{Pace, RecordedSource};

    /// `record --idle` into `out` with the shipped detector.
    fn idle_args(out: &Path) -> IdleOptions {
        IdleOptions {
            out: out.to_path_buf(),
            contact: ContactConfig::default(),
            json: false,
            sim_seed: None,
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
            profile: &telextiles_recording::profile::DIGIT,
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
}
