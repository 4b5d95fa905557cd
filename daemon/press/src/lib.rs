//! A press, without I/O: what the contact detector says of it
//! ([`ContactEvent`], [`EndReason`]), its deepest frame ([`Deepest`]), the
//! decider that names the textile ([`decide`]) and the embedding that
//! crosses between peers ([`latent::Latent`]).
//!
//! Pure and deterministic, with no clock, camera, ONNX Runtime, async
//! runtime or simulator in its dependency tree: the live session's core
//! (`telextiles-session`), the sensing pipeline (`telextiles-sensing`) and
//! the lab all decide presses with this one crate. Its only dependency of
//! ours is the textile index it decides against (`telextiles-index`), whose
//! [`telextiles_index::vecmath::l2_normalise`] is the one L2 normalisation
//! of a press's vectors.
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod decide;
pub mod latent;

pub use latent::{Latent, LatentError};

/// Why a press ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EndReason {
    /// The score fell below `exit`.
    Released,
    /// The reference was re-captured on command during the press.
    Recapture,
    /// The contact looked like a stale reference and the reference was re-captured.
    StaleReference,
}

/// Events from the contact detector (`telextiles_sensing::contact`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ContactEvent {
    /// A reference was captured (at start, on command, or after a stale one).
    ReferenceCaptured {
        /// Timestamp of the last frame averaged.
        t_us: u64,
    },
    /// A press started.
    PressStart {
        /// Timestamp of the first frame over `enter` in the run that started it.
        t_us: u64,
    },
    /// A would-be press showed that the reference had been captured while
    /// the sensor was touched: no press started, the reference is being
    /// re-captured.
    ReferenceRejected {
        /// Timestamp of the frame that showed it.
        t_us: u64,
    },
    /// A press ended.
    PressEnd {
        /// When the press started.
        start_us: u64,
        /// Timestamp of the frame that ended it.
        t_us: u64,
        /// Why.
        reason: EndReason,
    },
}

/// The deepest frame of a press so far: its depth and coverage (a press's
/// coverage in `telextiles_sensing::pipeline::PressReport`, in the recorder's summary and in `index
/// build`'s and `index check`'s note on partial presses).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Deepest {
    depth: f32,
    coverage: Option<f32>,
}

impl Deepest {
    /// A frame in contact of depth `depth` and coverage `coverage`.
    pub fn add(&mut self, depth: f32, coverage: f32) {
        if self.coverage.is_none() || depth > self.depth {
            *self = Deepest {
                depth,
                coverage: Some(coverage),
            };
        }
    }

    /// The deepest frame's coverage (None before a frame was added).
    pub fn coverage(&self) -> Option<f32> {
        self.coverage
    }
}
