//! A recording started over the control socket (`record.start`), fed by
//! the sensing thread and written by `press_dir`'s writer.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use telextiles_sensing::frame::Frame;
use telextiles_sensing::record::{
    PressSummary, RecordEvent, RecordLabel, Recorder, RecorderConfig,
};

use crate::press_dir::*;

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
        profile: &telextiles_recording::profile::SensorProfile,
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
            sensor_profile: telextiles_recording::profile_tag(profile),
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

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;
    use telextiles_sensing::contact::{ContactConfig, ContactDetector};
    use telextiles_sensing::source::recorded::Pace;
    use telextiles_sensing::source::sim::SimSource;
    use telextiles_sensing::source::FrameSource;
    use telextiles_sim::{PressSpec, Simulator};

    /// Frames between simulated presses (as `record --sensor sim` has them).
    const SIM_GAP_FRAMES: usize = 48;

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
        let (mut live, reply) = LiveRecording::start(
            &args,
            "sim",
            Some("SIM0000".into()),
            &telextiles_recording::profile::DIGIT,
        )
        .expect("start");
        assert_eq!(reply["first"], "0002");
        assert_eq!(reply["presses"], 2);
        let mut src = sim_frames("T030");
        let mut det = ContactDetector::new(ContactConfig::default());
        let mut frame = Frame::blank();
        let mut events = Vec::new();
        let mut finished = false;
        for _ in 0..3000 {
            src.next_frame(&mut frame).expect("frame");
            let u = det.update(frame.image(), frame.timestamp_us());
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
        let (mut live, _) =
            LiveRecording::start(&args, "digit", None, &telextiles_recording::profile::DIGIT)
                .expect("start");
        let mut src = sim_frames("T030");
        let mut det = ContactDetector::new(ContactConfig::default());
        let mut frame = Frame::blank();
        let mut events = Vec::new();
        // Into the first press, not out of it.
        for _ in 0..(SIM_GAP_FRAMES + 80) {
            src.next_frame(&mut frame).expect("frame");
            let u = det.update(frame.image(), frame.timestamp_us());
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
