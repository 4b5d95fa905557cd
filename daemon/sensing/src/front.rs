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
//! Replay: every recording starts from a clean front end
//! ([`FrontEnd::reset`]) with the recording's own reference
//! ([`recording_reference`]); nothing carries over from the previous
//! recording, so replaying N recordings in one run decides exactly as N
//! separate runs.

use std::time::Instant;

use telextiles_sim::Press;

use crate::contact::{mean_pixels, ContactConfig, ContactDetector, ContactUpdate};
use crate::encoder::{Encoder, EncoderError};
use crate::frame::Frame;

/// What one frame produced.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrontOutput<'a> {
    /// The contact detector's verdict.
    pub contact: ContactUpdate,
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

/// Contact detector + encoder sharing one reference (see the module docs).
pub struct FrontEnd {
    contact: ContactDetector,
    encoder: Encoder,
    /// The detector's reference version the encoder holds (None: none).
    synced: Option<u64>,
}

impl FrontEnd {
    /// A front end; `reference`: known no-contact pixels (240x320x3 RGB,
    /// 0..255), else the first frames are captured as the reference.
    pub fn new(encoder: Encoder, cfg: ContactConfig, reference: Option<&[f32]>) -> FrontEnd {
        let mut f = FrontEnd {
            contact: ContactDetector::new(cfg),
            encoder,
            synced: None,
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

    /// Process one frame (checked for size first).
    pub fn process(&mut self, frame: &Frame) -> Result<FrontOutput<'_>, EncoderError> {
        frame.check()?;
        let t0 = Instant::now();
        let up = self.contact.update(&frame.image, frame.timestamp_us);
        let version = self.contact.reference_version();
        if self.synced != Some(version) {
            if let Some(px) = self.contact.reference_pixels() {
                self.encoder.set_reference_pixels(px)?;
                self.synced = Some(version);
            }
        }
        let contact_ns = t0.elapsed().as_nanos() as u64;
        let mut out = FrontOutput {
            contact: up,
            embedding: None,
            contact_ns,
            preprocess_ns: 0,
            encode_ns: 0,
        };
        // Frames of the release run (already below the release threshold,
        // not yet enough of them to end the press) show no fabric: they are
        // not encoded.
        let touching = up.in_contact && up.score >= self.contact.release_threshold();
        if touching && self.encoder.has_reference() {
            let t1 = Instant::now();
            self.encoder.preprocess(&frame.image)?;
            let t2 = Instant::now();
            let emb = self.encoder.infer()?;
            out.preprocess_ns = (t2 - t1).as_nanos() as u64;
            out.encode_ns = t2.elapsed().as_nanos() as u64;
            out.embedding = Some(emb);
        }
        Ok(out)
    }
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

/// Full-resolution RGB values of an image, as [`FrontEnd::new`] takes a
/// reference.
pub fn pixels_of(image: &image::RgbImage) -> Vec<f32> {
    image.as_raw().iter().map(|&v| v as f32).collect()
}

/// A frame of a recording seen in contact.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactFrame {
    /// Index of the frame in the recording.
    pub index: usize,
    /// Its timestamp, microseconds from the recording's first frame.
    pub t_us: u64,
    /// Contact score (mean absolute difference from the reference, 0..255).
    pub score: f32,
    /// Start of the press it belongs to (microseconds).
    pub press_start_us: u64,
}

/// A recording as the front end sees it, without an encoder: its
/// reference and its frames in contact (for methods that are not ONNX
/// models, e.g. the lab's descriptors written in Rust).
#[derive(Clone, Debug, PartialEq)]
pub struct Segment {
    /// The reference in force at the first contact (240x320x3 RGB, 0..255).
    pub reference: Vec<f32>,
    /// Frames in contact, in order.
    pub contact: Vec<ContactFrame>,
}

/// Run the contact detector over a recording exactly as the front end
/// does (its own reference from [`recording_reference`], else captured from
/// its first steady frames). None when no reference could be formed or no
/// frame was in contact.
pub fn segment(press: &Press, cfg: &ContactConfig) -> Option<Segment> {
    let reference = recording_reference(press);
    let mut det = match &reference {
        Some(px) => ContactDetector::with_reference_pixels(cfg.clone(), px),
        None => ContactDetector::new(cfg.clone()),
    };
    let mut at_contact: Option<Vec<f32>> = None;
    let mut contact = Vec::new();
    let mut start = 0;
    for (i, (f, &t)) in press
        .frames
        .iter()
        .zip(&press.meta.timestamps_us)
        .enumerate()
    {
        let up = det.update(f, t);
        if let Some(crate::contact::ContactEvent::PressStart { t_us }) = up.event {
            start = t_us;
        }
        if up.in_contact {
            if at_contact.is_none() {
                at_contact = det.reference_pixels().map(<[f32]>::to_vec);
            }
            contact.push(ContactFrame {
                index: i,
                t_us: t,
                score: up.score,
                press_start_us: start,
            });
        }
    }
    Some(Segment {
        reference: at_contact?,
        contact,
    })
}
