//! The sensing front end: the one per-frame path from a camera frame to an
//! embedding, shared by the live session, `telextilesd classify`, `index
//! build` and the benchmarks (through [`crate::pipeline::Pipeline`], which
//! adds the decider).
//!
//! Per frame: contact detection against the no-contact reference, then,
//! only while in contact, preprocessing (minus the reference for
//! background-subtracting models) and ONNX inference. The contact detector
//! owns the reference (captured, renewed after each release, following
//! drift, re-captured on command or when found stale or touched); the
//! encoder's copy is refreshed from it whenever its version changes, so the
//! two can never disagree and [`FrontEnd::recapture`] resets both.
//!
//! A press starts on the last frame of a run of `min_enter_frames` frames
//! over the detector's threshold, and its start is the run's first frame.
//! With [`FrontEnd::set_encode_run`] the front end holds the run's frames
//! as they come (copied into slots allocated once) and, on the frame that
//! starts the press, encodes them too ([`FrontOutput::earlier`], oldest
//! first, with their own timestamps): a press's embeddings begin at its
//! first frame over the threshold, not `min_enter_frames - 1` frames later
//! (one frame, 17 ms at 60 fps, with the shipped two).
//! Which frames start a press is the detector's alone, so this changes
//! when embeddings begin, never whether a press is seen. Off by default:
//! measured, it makes right decisions come sooner on catalogue 1 and costs
//! first decisions on catalogue 2's hand-held presses more than the
//! decider's written rule allows (`docs/benchmarks.md`, "Encoding the run
//! that starts a press").
//!
//! Replay: every recording starts from a clean front end
//! ([`FrontEnd::reset`]) with the recording's own reference
//! ([`recording_reference`]); nothing carries over from the previous
//! recording, so replaying N recordings in one run decides exactly as N
//! separate runs.

use std::time::Instant;

use telextiles_recording::Press;

use crate::contact::{mean_pixels, ContactConfig, ContactDetector, ContactEvent, ContactUpdate};
use crate::encoder::{Encoder, EncoderError};
use crate::frame::Frame;

/// The embedding of a frame of the run that started a press, encoded when
/// the press started (see [`FrontOutput::earlier`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EarlyEmbedding {
    /// The frame's timestamp.
    pub t_us: u64,
    /// Its contact depth ([`ContactUpdate::depth`]), which weights it.
    pub depth: f32,
    /// Its L2-normalised embedding.
    pub embedding: Vec<f32>,
}

/// What one frame produced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrontOutput<'a> {
    /// The contact detector's verdict.
    pub contact: ContactUpdate,
    /// On the frame that starts a press: the embeddings of the run's
    /// earlier frames (the detector needs `min_enter_frames` in a row over
    /// its threshold, so the press starts on a frame or two it has already
    /// seen), oldest first. They come before [`FrontOutput::embedding`],
    /// with their own timestamps. Empty on every other frame, and when
    /// run encoding is off ([`FrontEnd::set_encode_run`]).
    pub earlier: &'a [EarlyEmbedding],
    /// The L2-normalised embedding, for frames in contact (and not yet
    /// lifted) once a reference exists.
    pub embedding: Option<&'a [f32]>,
    /// Nanoseconds in contact detection (with reference upkeep).
    pub contact_ns: u64,
    /// Nanoseconds in preprocessing.
    pub preprocess_ns: u64,
    /// Nanoseconds in inference and normalisation.
    pub encode_ns: u64,
}

/// A frame of a run that may start a press, held until the detector
/// decides.
struct Held {
    image: image::RgbImage,
    t_us: u64,
    depth: f32,
}

/// Contact detector + encoder sharing one reference (see the module docs).
pub struct FrontEnd {
    contact: ContactDetector,
    encoder: Encoder,
    /// The detector's reference version the encoder holds (None: none).
    synced: Option<u64>,
    /// Encode the frames of the run that starts a press (default off).
    encode_run: bool,
    /// The current run's frames so far (`min_enter_frames - 1` slots,
    /// allocated once; the first `held_n` are the run's).
    held: Vec<Held>,
    held_n: usize,
    /// The run's embeddings on the frame that starts a press (slots
    /// allocated once; the first `early_n` are this frame's).
    early: Vec<EarlyEmbedding>,
    early_n: usize,
}

impl FrontEnd {
    /// A front end; `reference`: known no-contact pixels (240x320x3 RGB,
    /// 0..255), else the first frames are captured as the reference.
    pub fn new(encoder: Encoder, cfg: ContactConfig, reference: Option<&[f32]>) -> FrontEnd {
        let slots = cfg.min_enter_frames.saturating_sub(1) as usize;
        let dim = encoder.dim();
        let mut f = FrontEnd {
            contact: ContactDetector::new(cfg),
            encoder,
            synced: None,
            encode_run: false,
            held: (0..slots)
                .map(|_| Held {
                    image: image::RgbImage::new(crate::frame::FRAME_W, crate::frame::FRAME_H),
                    t_us: 0,
                    depth: 0.0,
                })
                .collect(),
            held_n: 0,
            early: (0..slots)
                .map(|_| EarlyEmbedding {
                    t_us: 0,
                    depth: 0.0,
                    embedding: vec![0.0; dim],
                })
                .collect(),
            early_n: 0,
        };
        f.reset(reference);
        f
    }

    /// Start afresh (a new recording): a new contact detector with
    /// `reference` (or capturing one), and no reference in the encoder
    /// until the detector has one. Nothing of the previous frames remains.
    pub fn reset(&mut self, reference: Option<&[f32]>) {
        let cfg = self.contact.config().clone();
        self.contact = match reference {
            Some(px) if px.len() == crate::frame::FRAME_BYTES => {
                ContactDetector::with_reference_pixels(cfg, px)
            }
            _ => ContactDetector::new(cfg),
        };
        self.encoder.clear_reference();
        self.synced = None;
        self.held_n = 0;
        self.early_n = 0;
    }

    /// Whether the frames of the run that starts a press are encoded too
    /// (off by default: see the module docs). Off, a press's first
    /// embedding is the frame the detector starts it on,
    /// `min_enter_frames - 1` frames after its first; the lab measures both
    /// (`telextiles-lab decider-timing`).
    pub fn set_encode_run(&mut self, on: bool) {
        self.encode_run = on;
        self.held_n = 0;
    }

    /// Re-capture the reference from the next frames (on command): the
    /// detector's and, once captured, the encoder's.
    pub fn recapture(&mut self) {
        self.contact.recapture();
    }

    /// The frames stopped (end of a recording): forget a press in
    /// progress, keep the reference.
    pub fn end_of_frames(&mut self) {
        self.contact.reset();
        self.held_n = 0;
    }

    /// The contact detector.
    pub fn contact(&self) -> &ContactDetector {
        &self.contact
    }

    /// The encoder.
    pub fn encoder(&self) -> &Encoder {
        &self.encoder
    }

    /// Take the encoder back.
    pub fn into_encoder(self) -> Encoder {
        self.encoder
    }

    /// Process one frame (valid by construction: no size to check).
    pub fn process(&mut self, frame: &Frame) -> Result<FrontOutput<'_>, EncoderError> {
        let t0 = Instant::now();
        let up = self.contact.update(frame.image(), frame.timestamp_us());
        let version = self.contact.reference_version();
        if self.synced != Some(version) {
            if let Some(px) = self.contact.reference_pixels() {
                self.encoder.set_reference_pixels(px)?;
                self.synced = Some(version);
            }
        }
        let contact_ns = t0.elapsed().as_nanos() as u64;
        let (mut preprocess_ns, mut encode_ns) = (0, 0);
        // The press starts on the run's last frame: encode the ones before
        // it, held since they came, so the press's embeddings begin at its
        // first frame over the threshold rather than `min_enter_frames - 1`
        // frames later.
        self.early_n = 0;
        if let Some(ContactEvent::PressStart { t_us }) = up.event {
            if self.encode_run && self.encoder.has_reference() {
                for h in self.held[..self.held_n].iter().filter(|h| h.t_us >= t_us) {
                    let emb = encode(
                        &mut self.encoder,
                        &h.image,
                        &mut preprocess_ns,
                        &mut encode_ns,
                    )?;
                    let e = &mut self.early[self.early_n];
                    e.t_us = h.t_us;
                    e.depth = h.depth;
                    e.embedding.copy_from_slice(emb);
                    self.early_n += 1;
                }
            }
        }
        // Hold this frame if it is in a run that may yet start a press.
        let run = self.contact.pending_run() as usize;
        self.held_n = 0;
        if self.encode_run && run >= 1 && run <= self.held.len() {
            let h = &mut self.held[run - 1];
            h.image.copy_from_slice(frame.image().as_raw());
            h.t_us = frame.timestamp_us();
            h.depth = up.depth;
            self.held_n = run;
        }
        // Frames of the release run (already below the release threshold,
        // not yet enough of them to end the press) show no fabric: they are
        // not encoded.
        let touching = up.in_contact && up.score >= self.contact.release_threshold();
        let mut embedding = None;
        if touching && self.encoder.has_reference() {
            embedding = Some(encode(
                &mut self.encoder,
                frame.image(),
                &mut preprocess_ns,
                &mut encode_ns,
            )?);
        }
        Ok(FrontOutput {
            contact: up,
            earlier: &self.early[..self.early_n],
            embedding,
            contact_ns,
            preprocess_ns,
            encode_ns,
        })
    }
}

/// Preprocess and encode one frame, adding the time each stage took to
/// `preprocess_ns` and `encode_ns`.
fn encode<'a>(
    encoder: &'a mut Encoder,
    image: &image::RgbImage,
    preprocess_ns: &mut u64,
    encode_ns: &mut u64,
) -> Result<&'a [f32], EncoderError> {
    let t1 = Instant::now();
    encoder.preprocess(image)?;
    let t2 = Instant::now();
    let emb = encoder.infer()?;
    *preprocess_ns += (t2 - t1).as_nanos() as u64;
    *encode_ns += t2.elapsed().as_nanos() as u64;
    Ok(emb)
}

/// The no-contact reference a recording carries: the mean of its first
/// `reference_frames` frames (`telextilesd record` keeps the quiet frames
/// before contact; simulated presses declare theirs; an older simulated
/// press without the field still has its first contact frame). None when
/// the recording does not say (PyTouch data, old captures): the front end
/// then captures one from the recording's first steady frames.
pub fn recording_reference(press: &Press) -> Option<Vec<f32>> {
    let k = press.meta.reference_frames.or_else(|| {
        (press.meta.source == "sim")
            .then(|| press.meta.params.as_ref().map(|p| p.contact_frame))
            .flatten()
    })? as usize;
    if k == 0 {
        return None;
    }
    mean_pixels(&press.frames[..k.min(press.frames.len())])
}

/// The name (before `-<SERIAL>` and `.png`) of a sensor's no-contact frame
/// kept beside an index or its recordings ([`References::add_beside`];
/// `telextilesd record --idle` writes one).
pub const NO_CONTACT: &str = "no-contact";

/// No-contact references given from outside the recordings, for those
/// that carry none (PyTouch data, old captures, recordings whose every
/// frame is in contact): one for every sensor, and one per sensor serial
/// (`--reference [SERIAL=]PNG` on the command line). A recording's own
/// reference always wins; a serial's reference wins over the one for
/// every sensor.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct References {
    any: Option<Vec<f32>>,
    by_serial: std::collections::BTreeMap<String, Vec<f32>>,
    /// The sensor the images are from (None: a DIGIT).
    sensor: Option<telextiles_recording::recording::Sensor>,
}

/// How a `[SERIAL=]PNG` value splits into serial and image path: a value
/// that names an existing file (`exists`, asked of the whole value) is a
/// path even with `=` in its name; else the part before the first `=` is
/// a serial. None when that `=` has an empty side. The one rule for
/// `--reference` and the daemon's `reference` key.
pub fn split_reference_arg(
    arg: &str,
    exists: impl Fn(&str) -> bool,
) -> Option<(Option<&str>, &str)> {
    match arg.split_once('=') {
        Some((s, p)) if !exists(arg) => (!s.is_empty() && !p.is_empty()).then_some((Some(s), p)),
        _ => Some((None, arg)),
    }
}

/// A `--reference` that cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ReferenceError {
    /// The value or its image cannot be used.
    #[error("--reference {arg}: {reason}")]
    Bad {
        /// The command-line value.
        arg: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A second reference for the same sensor (or for every sensor).
    #[error("--reference {arg}: a reference for {what} was already given")]
    Twice {
        /// The command-line value.
        arg: String,
        /// "every sensor" or "sensor <serial>".
        what: String,
    },
}

impl References {
    /// No references: recordings without their own capture one from their
    /// first steady frames.
    pub fn none() -> References {
        References::default()
    }

    /// From command-line values `[SERIAL=]PNG`: an existing file is a
    /// path, even with `=` in its name; else the part before the first `=`
    /// is a sensor serial. Each image (PNG or JPEG) must be an 8-bit RGB
    /// frame of the sensor (240x320 portrait), taken with nothing touching
    /// the gel.
    pub fn from_args<S: AsRef<str>>(args: &[S]) -> Result<References, ReferenceError> {
        References::from_args_as(args, None)
    }

    /// [`References::from_args`] for frames of `sensor` (None: a DIGIT),
    /// each image mapped to the frame by its profile and scale, as are
    /// the no-contact frames [`References::add_beside`] adds later.
    pub fn from_args_as<S: AsRef<str>>(
        args: &[S],
        sensor: Option<telextiles_recording::recording::Sensor>,
    ) -> Result<References, ReferenceError> {
        let mut out = References {
            sensor,
            ..References::default()
        };
        for arg in args {
            let arg = arg.as_ref();
            let bad = |reason: String| ReferenceError::Bad {
                arg: arg.to_string(),
                reason,
            };
            let (serial, path) =
                split_reference_arg(arg, |whole| std::path::Path::new(whole).exists())
                    .ok_or_else(|| bad("expected [SERIAL=]PNG".into()))?;
            let serial = serial.map(str::to_string);
            let image = out
                .read(std::path::Path::new(path))
                .map_err(|e| bad(e.to_string()))?;
            let px = pixels_of(&image);
            let twice = |what: String| ReferenceError::Twice {
                arg: arg.to_string(),
                what,
            };
            match serial {
                Some(s) if out.by_serial.contains_key(&s) => {
                    return Err(twice(format!("sensor {s}")))
                }
                Some(s) => {
                    out.by_serial.insert(s, px);
                }
                None if out.any.is_some() => return Err(twice("every sensor".into())),
                None => out.any = Some(px),
            }
        }
        Ok(out)
    }

    /// Add the sensors' no-contact frames kept in `dir` (beside an index,
    /// or at the top of a directory of recordings): `no-contact.png` for
    /// every sensor and `no-contact-<SERIAL>.png` for one. A reference
    /// already given for the same sensor wins; a directory without them
    /// adds nothing; a file that cannot be used is an error naming it.
    /// Returns the files taken.
    pub fn add_beside(
        &mut self,
        dir: &std::path::Path,
    ) -> Result<Vec<std::path::PathBuf>, ReferenceError> {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return Ok(Vec::new());
        };
        let mut names: Vec<(String, std::path::PathBuf)> = entries
            .flatten()
            .filter_map(|e| Some((e.file_name().into_string().ok()?, e.path())))
            .filter(|(n, _)| n.starts_with(NO_CONTACT) && n.ends_with(".png"))
            .collect();
        names.sort();
        let mut taken = Vec::new();
        for (name, path) in names {
            let stem = &name[NO_CONTACT.len()..name.len() - ".png".len()];
            let serial = match stem {
                "" => None,
                s => match s.strip_prefix('-') {
                    Some(serial) if !serial.is_empty() => Some(serial.to_string()),
                    _ => continue,
                },
            };
            let bad = |reason: String| ReferenceError::Bad {
                arg: path.display().to_string(),
                reason,
            };
            let wanted = match &serial {
                Some(s) => !self.by_serial.contains_key(s),
                None => self.any.is_none(),
            };
            if !wanted {
                continue;
            }
            let image = self.read(&path).map_err(|e| bad(e.to_string()))?;
            let px = pixels_of(&image);
            match serial {
                Some(s) => {
                    self.by_serial.insert(s, px);
                }
                None => self.any = Some(px),
            }
            taken.push(path);
        }
        Ok(taken)
    }

    /// A no-contact image of the sensor, mapped to the frame.
    fn read(
        &self,
        path: &std::path::Path,
    ) -> Result<image::RgbImage, telextiles_recording::recording::RecordingError> {
        match self.sensor {
            Some(s) => telextiles_recording::recording::read_image_as(path, s),
            None => telextiles_recording::recording::read_image(path),
        }
    }

    /// Whether no reference was given.
    pub fn is_empty(&self) -> bool {
        self.any.is_none() && self.by_serial.is_empty()
    }

    /// The given reference for a recording from the sensor with this
    /// serial, if any.
    pub fn given(&self, serial: Option<&str>) -> Option<&[f32]> {
        serial
            .and_then(|s| self.by_serial.get(s))
            .or(self.any.as_ref())
            .map(Vec::as_slice)
    }

    /// The reference to replay a recording with: its own
    /// ([`recording_reference`]), else the one given for its sensor, else
    /// None (the front end captures one from its first steady frames).
    pub fn for_press(&self, press: &Press) -> Option<Vec<f32>> {
        recording_reference(press).or_else(|| {
            self.given(press.meta.sensor_serial.as_deref())
                .map(<[f32]>::to_vec)
        })
    }
}

/// Full-resolution RGB values of an image, as [`FrontEnd::new`] takes a
/// reference.
pub fn pixels_of(image: &image::RgbImage) -> Vec<f32> {
    image.as_raw().iter().map(|&v| v as f32).collect()
}

/// The inverse of [`pixels_of`]: reference pixels (240x320x3 RGB, 0..255)
/// as an image, each value rounded; None when they are not 240x320x3.
pub fn image_of(pixels: &[f32]) -> Option<image::RgbImage> {
    image::RgbImage::from_raw(
        crate::frame::FRAME_W,
        crate::frame::FRAME_H,
        pixels
            .iter()
            .map(|&v| v.round().clamp(0.0, 255.0) as u8)
            .collect(),
    )
}

/// A frame of a recording seen in contact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactFrame {
    /// Index of the frame in the recording.
    pub index: usize,
    /// Its timestamp, microseconds from the recording's first frame.
    pub t_us: u64,
    /// Contact depth (the whole frame's mean absolute difference from the
    /// reference, 0..255; [`ContactUpdate::depth`]), which weights the frame.
    pub depth: f32,
    /// Start of the press it belongs to (microseconds).
    pub press_start_us: u64,
    /// A frame of the run that started the press, before the frame the
    /// detector started it on: what [`FrontOutput::earlier`] encodes.
    pub early: bool,
}

/// A recording as the front end sees it, without an encoder: its
/// reference and its frames in contact (for methods that are not ONNX
/// models, e.g. the lab's descriptors written in Rust).
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// The reference in force at the first contact (240x320x3 RGB, 0..255).
    pub reference: Vec<f32>,
    /// The frames the front end encodes, in order: each press's run
    /// before the detector started it ([`ContactFrame::early`]), then its
    /// frames in contact.
    pub contact: Vec<ContactFrame>,
}

/// Run the contact detector over a recording exactly as the front end
/// does (its own reference from [`recording_reference`], else captured from
/// its first steady frames). None when no reference could be formed or no
/// frame was in contact.
pub fn segment(press: &Press, cfg: &ContactConfig) -> Option<Segment> {
    segment_with(press, cfg, recording_reference(press).as_deref())
}

/// [`segment`] with the reference to replay the recording with
/// ([`References::for_press`]; None: captured from its first steady
/// frames).
pub fn segment_with(
    press: &Press,
    cfg: &ContactConfig,
    reference: Option<&[f32]>,
) -> Option<Segment> {
    let mut det = match reference {
        Some(px) => ContactDetector::with_reference_pixels(cfg.clone(), px),
        None => ContactDetector::new(cfg.clone()),
    };
    let mut at_contact: Option<Vec<f32>> = None;
    let mut contact = Vec::new();
    // The frames of the run that may start a press, as the front end
    // holds them.
    let mut run: Vec<ContactFrame> = Vec::new();
    let mut start = 0;
    for (i, (f, &t)) in press
        .frames
        .iter()
        .zip(&press.meta.timestamps_us)
        .enumerate()
    {
        let up = det.update(f, t);
        if let Some(ContactEvent::PressStart { t_us }) = up.event {
            start = t_us;
            contact.extend(
                run.drain(..)
                    .filter(|c| c.t_us >= t_us)
                    .map(|c| ContactFrame {
                        press_start_us: t_us,
                        ..c
                    }),
            );
        }
        if up.in_contact {
            if at_contact.is_none() {
                at_contact = det.reference_pixels().map(<[f32]>::to_vec);
            }
            contact.push(ContactFrame {
                index: i,
                t_us: t,
                depth: up.depth,
                press_start_us: start,
                early: false,
            });
        }
        if det.pending_run() <= 1 {
            run.clear();
        }
        if det.pending_run() >= 1 {
            run.push(ContactFrame {
                index: i,
                t_us: t,
                depth: up.depth,
                press_start_us: 0,
                early: true,
            });
        }
    }
    Some(Segment {
        reference: at_contact?,
        contact,
    })
}
/// What to add to "no contact detected" for a recording replayed without
/// a reference (neither its own nor one given for its sensor,
/// `References::for_press`): the way out, since its first frames, maybe
/// in contact, became the reference.
pub fn no_reference_hint(has_reference: bool) -> &'static str {
    if has_reference {
        ""
    } else {
        " (the recording carries no no-contact reference, so its first frames became one: if they are in contact, give the sensor's no-contact frame with --reference, or keep it beside the index as no-contact.png or no-contact-<SERIAL>.png; `telextilesd record --idle` writes one)"
    }
}
