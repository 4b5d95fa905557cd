//! The sensing thread: frame source → the front end (contact detection,
//! the reference, encoding) → the sender core → the peer link. Blocking
//! (camera reads, ONNX inference), so a thread of its own; it sends
//! latents straight into the link (a datagram per frame, no queue).

use std::sync::atomic::Ordering;
use std::sync::mpsc as std_mpsc;
use std::sync::Arc;

use anyhow::Result;
use telextiles_control::{ContactPhase, Event};
use telextiles_link::now_us;
use telextiles_proto::peer::Control;
use telextiles_sensing::contact::ContactConfig;
use telextiles_sensing::encoder::Encoder;
use telextiles_sensing::frame::Frame;
use telextiles_sensing::front::{FrontEnd, References};
use telextiles_sensing::source::recorded::{Pace, RecordingsSource};
#[cfg(feature = "sim")]
use telextiles_sensing::source::sim::{SimCommand, SimHandle, SimSource};
use telextiles_sensing::source::{FrameSource, SourceError};
use telextiles_session::{EarlierFrame, SenderCore, Sensed, TxAction};

use super::{Counters, SessionOptions, State};
use crate::config::{Config, SensorSource};
use telextiles_recording::profile::{Mode, SensorProfile, DIGIT};
#[cfg(target_os = "linux")]
use telextiles_sensing::source::camera::CameraOptions;

/// Commands for the sensing thread.
#[derive(Debug)]
pub(crate) enum SensorCmd {
    /// Re-capture every reference the pipeline keeps.
    Recapture,
    /// Steer the simulated DIGIT.
    #[cfg(feature = "sim")]
    Sim(SimCommand),
    /// Set the DIGIT's LEDs (0..=15 each); the answer goes to `reply`.
    Led {
        r: u8,
        g: u8,
        b: u8,
        reply: tokio::sync::oneshot::Sender<Result<(), String>>,
    },
    /// Start or stop a recording (`record.start` / `record.stop`).
    Record(super::recording::RecordCtl),
    /// End the thread.
    Stop,
}

/// The frame source, the simulator's handle (when simulated), a
/// description for people and the sensor's profile.
pub(crate) struct OpenedSource {
    pub(crate) source: Box<dyn FrameSource>,
    pub(crate) sim: Option<Simulated>,
    pub(crate) desc: String,
    pub(crate) profile: &'static SensorProfile,
}

/// The simulated DIGIT: its steering handle and its simulator.
#[cfg(feature = "sim")]
pub(crate) struct Simulated {
    pub(crate) handle: SimHandle,
    pub(crate) simulator: Arc<telextiles_sim::Simulator>,
}

/// A build without the simulator has no simulated DIGIT.
#[cfg(not(feature = "sim"))]
pub(crate) enum Simulated {}

/// The no-contact frames given for replayed recordings that carry none
/// (`reference`), read and checked. They are for `sensor = replay:<dir>`
/// only: a live DIGIT or the simulator captures its own while idle, so
/// with any other sensor they are refused rather than silently unused.
pub(crate) fn given_references(cfg: &Config) -> Result<References> {
    if cfg.reference.is_empty() {
        return Ok(References::none());
    }
    if !matches!(cfg.sensor, SensorSource::Replay { .. }) {
        anyhow::bail!(
            "`reference` is for sensor = replay:<dir> (recordings that carry no no-contact frame); sensor {} captures its own while nothing touches it",
            cfg.sensor
        );
    }
    Ok(References::from_args_as(
        &cfg.reference,
        cfg.sensor_given(),
    )?)
}

/// The configured `replay_fps`, checked against the sensor: it is for
/// `sensor = replay:<dir>` only.
pub(crate) fn check_replay_fps(cfg: &Config) -> Result<()> {
    if cfg.replay_fps.is_some() && !matches!(cfg.sensor, SensorSource::Replay { .. }) {
        anyhow::bail!(
            "`replay_fps` is for sensor = replay:<dir> (recordings saved without timestamps); sensor {} gives its frames' own times",
            cfg.sensor
        );
    }
    Ok(())
}

/// A simulated DIGIT: pressing `textile` again and again, or (None)
/// lifted until `ctl sensor sim <textile>` asks for a press.
#[cfg(feature = "sim")]
fn sim_source(
    opts: &SessionOptions,
    index: &telextiles_index::Index,
    textile: Option<&str>,
    why: &str,
) -> Result<OpenedSource> {
    let simulator = Arc::new(super::models::simulator_for(index)?);
    let spec = telextiles_sim::PressSpec::new(textile.unwrap_or("T001"), 1);
    let (src, handle) = SimSource::new(
        simulator.clone(),
        spec,
        opts.sim_gap_frames.unwrap_or(60),
        Pace::RealTime,
    )?;
    let (src, desc) = match textile {
        Some(t) => (src, format!("simulated DIGIT pressing {t} repeatedly{why}")),
        None => (
            src.start_idle(),
            format!("simulated DIGIT, lifted until `telextilesd ctl sensor sim <textile>`{why}"),
        ),
    };
    Ok(OpenedSource {
        source: Box::new(src),
        sim: Some(Simulated { handle, simulator }),
        desc,
        profile: &DIGIT,
    })
}

#[cfg(not(feature = "sim"))]
fn sim_source(
    _opts: &SessionOptions,
    _index: &telextiles_index::Index,
    _textile: Option<&str>,
    why: &str,
) -> Result<OpenedSource> {
    Err(crate::sim_off(&format!("the simulated DIGIT{why}")))
}

/// What to open for a camera source: a DIGIT (`digit[:serial]`), or a
/// camera of the configured profile (`camera[:select]`; with no
/// `sensor_profile`, the profile found from the camera's USB ids and
/// name), in the configured mode and scale.
pub(crate) fn camera_options(
    source: &SensorSource,
    profile: Option<&'static SensorProfile>,
    mm_per_px: Option<f32>,
    mode: Option<Mode>,
) -> Result<CameraOptions> {
    let (profile, select) = match source {
        SensorSource::Digit { serial } => {
            if let Some(p) = profile.filter(|p| p.name != DIGIT.name) {
                anyhow::bail!(
                    "sensor = digit reads a DIGIT, but sensor_profile is {}: say sensor = camera (or camera:/dev/videoN) for another sensor",
                    p.name
                );
            }
            (&DIGIT, serial.clone())
        }
        SensorSource::Camera { select } => match profile {
            Some(p) => (p, select.clone()),
            None => {
                let defaults = CameraOptions::default();
                let cameras = telextiles_sensing::source::sysfs::find_cameras(
                    &defaults.sysfs_root,
                    &defaults.dev_root,
                );
                let (p, cam) =
                    telextiles_sensing::source::sysfs::identify_camera(&cameras, select.as_deref())
                        .map_err(anyhow::Error::msg)?;
                (p, Some(cam.node.display().to_string()))
            }
        },
        other => anyhow::bail!("{other} is not a camera"),
    };
    Ok(CameraOptions {
        profile,
        select,
        mode,
        mm_per_px,
        ..Default::default()
    })
}

/// Opens the configured frame source. A simulated DIGIT presses fabrics
/// of the index's simulator catalogue (so that its textile ids mean the
/// fabrics the index was built from). Frames of a sensor the index was
/// not built for are refused ([`telextiles_index::Index::check_sensor`]).
pub(crate) fn open_source(
    cfg: &Config,
    opts: &SessionOptions,
    index: &telextiles_index::Index,
) -> Result<OpenedSource> {
    let opened = open_frames(cfg, opts, index)?;
    index
        .check_sensor(opened.profile.name)
        .map_err(|e| anyhow::anyhow!("{}: {e}", opened.desc))?;
    Ok(opened)
}

fn open_frames(
    cfg: &Config,
    opts: &SessionOptions,
    index: &telextiles_index::Index,
) -> Result<OpenedSource> {
    let session = opts;
    let references = given_references(cfg)?;
    check_replay_fps(cfg)?;
    match &cfg.sensor {
        SensorSource::Sim { textile } => sim_source(session, index, textile.as_deref(), ""),
        SensorSource::Replay { dir } => {
            let src = RecordingsSource::open(dir, Pace::RealTime, references)?
                .assume_fps(cfg.replay_fps)?
                .assume_sensor(cfg.sensor_given())?
                .looping(true);
            let profiles = telextiles_recording::recording::profiles(src.recordings())?;
            let mut names = profiles.keys();
            let profile = match (names.next(), names.next()) {
                (Some(p), None) => {
                    telextiles_recording::profile::by_name(p).map_err(anyhow::Error::msg)?
                }
                (None, _) => &DIGIT,
                (Some(_), Some(_)) => {
                    // Each is checked against the index by name.
                    for (p, first) in &profiles {
                        index
                            .check_sensor(p)
                            .map_err(|e| anyhow::anyhow!("{}: {e}", first.display()))?;
                    }
                    &DIGIT
                }
            };
            let desc = src.describe();
            Ok(OpenedSource {
                source: Box::new(src),
                sim: None,
                desc,
                profile,
            })
        }
        SensorSource::Digit { .. } | SensorSource::Camera { .. } => {
            #[cfg(target_os = "linux")]
            {
                open_camera(cfg, session, index)
            }
            #[cfg(not(target_os = "linux"))]
            {
                anyhow::bail!("cameras are read over V4L2, which only Linux has; use sensor = sim or replay:<dir>")
            }
        }
    }
}

#[cfg(target_os = "linux")]
fn open_camera(
    cfg: &Config,
    session: &SessionOptions,
    index: &telextiles_index::Index,
) -> Result<OpenedSource> {
    use telextiles_sensing::source::camera::CameraSource;
    let opts = camera_options(
        &cfg.sensor,
        cfg.sensor_profile,
        cfg.sensor_mm_per_px,
        cfg.sensor_mode,
    );
    let opts = match (opts, &cfg.sensor) {
        (Ok(o), _) => o,
        (Err(e), SensorSource::Camera { select: None }) => {
            eprintln!("{e}; using the simulated DIGIT");
            return sim_source(session, index, None, " (no camera found)");
        }
        (Err(e), _) => return Err(e),
    };
    let profile = opts.profile;
    match CameraSource::open(&opts) {
        Ok(src) => {
            let desc = src.describe();
            // The first open succeeded; later opens (after an unplug)
            // retry with backoff.
            let mut first = Some(src);
            let src = telextiles_sensing::source::Resilient::new(move || {
                if let Some(s) = first.take() {
                    return Ok(Box::new(s) as Box<dyn FrameSource>);
                }
                CameraSource::open(&opts).map(|s| Box::new(s) as Box<dyn FrameSource>)
            });
            Ok(OpenedSource {
                source: Box::new(src),
                sim: None,
                desc,
                profile,
            })
        }
        Err(e) if matches!(cfg.sensor, SensorSource::Digit { serial: None }) => {
            eprintln!("{e}; using the simulated DIGIT");
            sim_source(session, index, None, " (no DIGIT found)")
        }
        Err(e) => Err(e.into()),
    }
}

/// Run until `SensorCmd::Stop` or shutdown (Ok), or until the source fails
/// for good (Err: the session ends with it).
/// The sensing thread's front end: the one per-frame path (as `classify`
/// and `index build` run it), with the configured contact detector
/// (`contact_enter`, `contact_frames`, `contact_tile`), and the run that
/// starts a press encoded when `encode_run` (the `encode_run` setting).
pub(crate) fn front_end(encoder: Encoder, contact: ContactConfig, encode_run: bool) -> FrontEnd {
    let mut front = FrontEnd::new(encoder, contact, None);
    front.set_encode_run(encode_run);
    front
}

pub(crate) fn sensing_thread(
    state: Arc<State>,
    mut source: Box<dyn FrameSource>,
    encoder: Encoder,
    contact: ContactConfig,
    encode_run: bool,
    cmds: std_mpsc::Receiver<SensorCmd>,
) -> Result<(), String> {
    let mut front = front_end(encoder, contact, encode_run);
    // The session's sending half: the capture clock, the press's deepest
    // frame and its numbering are the core's; this thread reads, runs the
    // front end and carries out what the core says.
    let mut sender = SenderCore::new(front.encoder().dim());
    let mut frame = Frame::blank();
    let mut actions = Vec::new();
    let mut contacts = Vec::new();
    // A recording asked for over the control socket, fed below.
    let mut recording: Option<super::recording::LiveRecording> = None;
    loop {
        while let Ok(cmd) = cmds.try_recv() {
            match cmd {
                SensorCmd::Recapture => front.recapture(),
                #[cfg(feature = "sim")]
                SensorCmd::Sim(c) => {
                    if let Some(sim) = &state.sim {
                        sim.handle.send(c);
                    }
                }
                SensorCmd::Led { r, g, b, reply } => {
                    let r = source.set_leds(r, g, b).map_err(|e| e.to_string());
                    if r.is_ok() {
                        // The sensor looks different now: new references.
                        front.recapture();
                    }
                    let _ = reply.send(r);
                }
                SensorCmd::Record(c) => c.apply(&mut recording, &mut |e| {
                    let _ = state.events.send(e);
                }),
                SensorCmd::Stop => return Ok(()),
            }
        }
        if *state.shutdown.borrow() {
            return Ok(());
        }
        if let Err(e) = source.next_frame(&mut frame) {
            let _ = state.events.send(Event::Error {
                source: "sensor".into(),
                message: e.to_string(),
            });
            {
                let c = &state.counters;
                match e {
                    // A recording of a replay, not a frame: the replay
                    // goes on with the next.
                    SourceError::Skipped(_) => {
                        Counters::bump(&c.recordings_skipped);
                    }
                    SourceError::Fatal(_) | SourceError::Ended => {}
                    _ => {
                        Counters::bump(&c.bad_frames);
                    }
                }
            }
            if matches!(e, SourceError::Fatal(_) | SourceError::Ended) {
                // Tell the peers the press is over before going.
                sender.stop(now_us(), &mut actions);
                let t = now_us();
                send(&state, &mut actions, [t, t, t]);
                return Err(format!("sensor: {e}"));
            }
            continue;
        }
        let arrived_us = now_us();
        if let Some(notice) = source.take_notice() {
            // Something the owner should know about the stream (a camera
            // below its mode's rate): on the control socket too.
            let _ = state.events.send(Event::Error {
                source: "sensor".into(),
                message: notice,
            });
        }
        let new_recording = source.new_recording();
        if let Some(rec) = &new_recording {
            // Another recording: the front end starts afresh with its own
            // reference (the sender core ends a press still in progress).
            tracing::debug!(recording = %rec.name, "replaying the next recording");
            front.reset(rec.reference.as_deref());
        }
        Counters::bump(&state.counters.frames);
        let out = match front.process(&frame) {
            Ok(o) => o,
            Err(e) => {
                Counters::bump(&state.counters.bad_frames);
                let _ = state.events.send(Event::Error {
                    source: "encoder".into(),
                    message: e.to_string(),
                });
                continue;
            }
        };
        let up = out.contact;
        if let Some(r) = recording.as_mut() {
            if r.push(&frame, &up, &mut |e| {
                let _ = state.events.send(e);
            }) {
                recording = None;
            }
        }
        let contact_us = arrived_us + out.contact_ns / 1000;
        let earlier: Vec<EarlierFrame<'_>> = out
            .earlier
            .iter()
            .map(|e| EarlierFrame {
                t_us: e.t_us,
                embedding: &e.embedding,
                depth: e.depth,
            })
            .collect();
        let sensed = Sensed {
            timestamp_us: frame.timestamp_us(),
            arrived_us,
            new_recording: new_recording.is_some(),
            event: up.event,
            in_contact: up.in_contact,
            score: up.score,
            depth: up.depth,
            coverage: up.coverage,
            embedding: out.embedding,
        };
        sender.on_sensed(&sensed, &earlier, &mut actions, &mut contacts);
        for c in contacts.drain(..) {
            state.in_contact.store(c.started, Ordering::Relaxed);
            let _ = state.events.send(Event::Contact {
                phase: if c.started {
                    ContactPhase::Start
                } else {
                    ContactPhase::End
                },
                score: c.score,
                coverage: c.coverage,
            });
        }
        let encoded_us = contact_us + (out.preprocess_ns + out.encode_ns) / 1000;
        // The trace times the daemon's stages from the frame's arrival
        // (the latents carry its capture time).
        send(&state, &mut actions, [arrived_us, contact_us, encoded_us]);
    }
}

/// Carry out the sender core's actions on the link, in order; `stages`
/// (arrival from the source, contact, encoded; local clock) go into the
/// latency trace.
fn send(state: &State, actions: &mut Vec<TxAction>, stages: [u64; 3]) {
    for a in actions.drain(..) {
        match a {
            TxAction::PressStart {
                press_id,
                capture_us,
            } => {
                Counters::bump(&state.counters.presses_sent);
                let _ = state.link.send_control(Control::PressStart {
                    press_id,
                    capture_us,
                });
            }
            TxAction::Latent {
                press_id,
                capture_us,
                latent,
            } => {
                if let Ok(sent) =
                    state
                        .link
                        .send_latent_timed(press_id, &latent.wire(), capture_us, false)
                {
                    let sent_us = now_us();
                    Counters::bump(&state.counters.latents_sent);
                    if let Some(t) = &state.trace {
                        let [c, k, e] = stages;
                        t.tx(sent.seq, press_id, [c, k, e, sent.encoded_us, sent_us]);
                    }
                }
            }
            TxAction::PressStop {
                press_id,
                capture_us,
                final_latent,
            } => {
                let _ = state.link.send_press_stop(
                    press_id,
                    final_latent.as_ref().map(|l| l.as_slice()),
                    capture_us,
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ConfigArgs;
    use telextiles_sensing::contact::ContactEvent;
    use telextiles_sim::RgbImage;

    fn config(sensor: &str, reference: &[String]) -> Config {
        let args = ConfigArgs {
            sensor: Some(sensor.parse().unwrap()),
            reference: Some(reference.to_vec()),
            runtime_dir: Some("/r".into()),
            config: Some("/dev/null".into()),
            ..ConfigArgs::default()
        };
        Config::resolve(&args, &|k| (k == "HOME").then(|| "/h".into())).unwrap()
    }

    #[test]
    fn given_references_are_read_for_a_replay_and_refused_for_any_other_sensor() {
        let dir = tempfile::tempdir().unwrap();
        let png = dir.path().join("bg.png");
        let blank = RgbImage::from_raw(240, 320, [40u8, 60, 80].repeat(240 * 320)).unwrap();
        blank.save(&png).unwrap();
        let one = [format!("D20001={}", png.display())];
        let refs = given_references(&config("replay:data", &one)).unwrap();
        assert_eq!(
            refs.given(Some("D20001")),
            Some(telextiles_sensing::front::pixels_of(&blank).as_slice())
        );
        assert_eq!(refs.given(Some("D20002")), None);
        assert!(given_references(&config("replay:data", &[]))
            .unwrap()
            .is_empty());
        assert!(given_references(&config("sim", &[])).unwrap().is_empty());
        for sensor in ["sim:T030", "digit", "digit:D20001"] {
            let err = given_references(&config(sensor, &one))
                .unwrap_err()
                .to_string();
            assert!(
                err.contains("`reference` is for sensor = replay:<dir>")
                    && err.contains(&format!("sensor {sensor} captures its own")),
                "{err}"
            );
        }
        // A frame of the wrong size, a missing file, two for one sensor.
        let small = dir.path().join("small.png");
        RgbImage::new(8, 8).save(&small).unwrap();
        for (bad, want) in [
            (vec![small.display().to_string()], "small.png"),
            (
                vec!["D1=/nonexistent/bg.png".to_string()],
                "/nonexistent/bg.png",
            ),
            (vec![one[0].clone(), one[0].clone()], "already given"),
        ] {
            let err = given_references(&config("replay:data", &bad))
                .unwrap_err()
                .to_string();
            assert!(err.contains("--reference") && err.contains(want), "{err}");
        }
    }

    /// The `encode_run` setting reaches the front end: on the frame that
    /// starts a press, the run's earlier frame comes encoded with it
    /// (the shipped detector starts a press on its second frame over the
    /// threshold), and without the setting it does not.
    #[test]
    fn the_encode_run_setting_encodes_the_run_that_starts_a_press() {
        let model = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("sensing/tests/fixtures/fixture_encoder.onnx");
        let sim = telextiles_sim::Simulator::new().unwrap();
        let press = sim
            .render_press(&telextiles_sim::PressSpec::new("T030", 1))
            .unwrap();
        let earlier_at_start = |encode_run: bool| {
            let enc = telextiles_sensing::encoder::Encoder::open(
                &model,
                &telextiles_sensing::encoder::EncoderOptions::default(),
            )
            .unwrap();
            let mut front = front_end(enc, ContactConfig::default(), encode_run);
            for (i, (image, &t)) in press
                .frames
                .iter()
                .zip(&press.meta.timestamps_us)
                .enumerate()
            {
                let frame = Frame::new(image.clone(), t, i as u64).unwrap();
                let out = front.process(&frame).unwrap();
                if matches!(out.contact.event, Some(ContactEvent::PressStart { .. })) {
                    assert!(out.embedding.is_some());
                    return out.earlier.len();
                }
            }
            panic!("no press started");
        };
        assert_eq!(earlier_at_start(false), 0);
        assert_eq!(
            earlier_at_start(true),
            ContactConfig::default().min_enter_frames as usize - 1
        );
    }

    #[test]
    fn a_replay_rate_is_for_a_replay_only() {
        let with_fps = |sensor: &str| Config {
            replay_fps: Some(30.0),
            ..config(sensor, &[])
        };
        check_replay_fps(&with_fps("replay:data")).unwrap();
        check_replay_fps(&config("digit", &[])).unwrap();
        for sensor in ["sim", "digit:D20001"] {
            let err = check_replay_fps(&with_fps(sensor)).unwrap_err().to_string();
            assert!(
                err.contains("`replay_fps` is for sensor = replay:<dir>")
                    && err.contains(&format!("sensor {sensor} gives")),
                "{err}"
            );
        }
    }
}
