//! Textile catalogue, simulated DIGIT presses and the on-disk press format.
//!
//! ```no_run
//! use telextiles_sim::{PressSpec, Simulator};
//! let sim = Simulator::new().unwrap();
//! let press = sim.render_press(&PressSpec::new("T001", 7)).unwrap();
//! assert_eq!(press.frames.len(), 150);
//! assert_eq!((press.frames[0].width(), press.frames[0].height()), (240, 320));
//! ```
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod bolt;
pub mod calib;
pub mod camera;
pub mod catalogue;
pub mod dataset;
pub mod fabric;
pub mod gabor;
/// The on-disk press format lives in `telextiles-recording`.
pub use telextiles_recording::recording;
mod render;
mod render2;
mod sensor2;
pub mod sheet;
pub mod stats;

pub use catalogue::{Book, Catalogue, Textile};
pub use image::{ImageFormat, RgbImage};
pub use render::{person_style, sensor_model, IdleClip, PersonStyle, SensorModel, Simulator};
pub use render2::{sensor_model_v2, swatch_of, SensorModelV2, FPS_CHOICES, SWATCHES, V2_UNITS};

use serde::{Deserialize, Serialize};

pub use telextiles_recording::{Press, PressMeta, PressParams, FPS, HEIGHT, WIDTH};

/// Frames in one press (2.5 s at 60 fps).
pub const PRESS_FRAMES: usize = 150;
/// Number of simulated people in the paper protocol.
pub const PEOPLE: u32 = 11;
/// Catalogue versions the simulator renders (`PressSpec::catalogue`).
pub const CATALOGUE_VERSIONS: [u32; 2] = [1, 2];
/// Texture generators of catalogue 2 (`PressSpec::generator`): 1 is the
/// structural generator used for training and method selection, 2 an
/// independent construction (Gabor noise) for the cross-generator test set.
pub const GENERATORS: [u32; 2] = [1, 2];

/// Errors of the simulator.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("unknown textile id {0:?} (known: T001..T119, U01..U20)")]
    UnknownTextile(String),
    #[error("frame index {index} out of range (press has {frames} frames)")]
    FrameOutOfRange { index: usize, frames: usize },
    #[error("invalid press spec: {0}")]
    InvalidSpec(String),
    #[error("embedded DIGIT calibration: {0}")]
    Calibration(String),
}

/// What to render: one press of one textile by one person on one sensor.
/// Unset options are drawn from the person's style and the seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PressSpec {
    /// Textile id ("T001".."T119", "U01".."U20").
    pub textile: String,
    /// Simulated person 0..11 (any u32 works; each has a consistent style).
    pub person: u32,
    /// Simulated sensor unit (0 = the nominal real calibration/background).
    pub sensor: u32,
    /// Pressed with the spring jig (steady) rather than hand-held.
    pub jig: bool,
    /// Seed of this press; the same spec renders the same frames.
    pub seed: u64,
    /// In-plane rotation of the fabric under the sensor, degrees.
    pub rotation_deg: Option<f32>,
    /// Press force in newtons.
    pub force: Option<f32>,
    /// Lateral offset of the window on the fabric, mm.
    pub offset_mm: Option<[f32; 2]>,
    /// Tilt of the sensor about its x and y axes, degrees (default: drawn
    /// from the jig's or the person's steadiness). May be left out of JSON.
    #[serde(default)]
    pub tilt_deg: Option<[f32; 2]>,
    /// Whether the press releases before the end (default: person's habit).
    pub release: Option<bool>,
    /// Number of frames (default 150).
    pub frames: usize,
    /// Camera noise on (default true). In catalogue 2, off also turns off
    /// the exposure drift (the camera's blur and compression stay).
    pub noise: bool,
    /// Catalogue version 1 or 2 (None: the simulator's default, see
    /// `Simulator::with_catalogue`). Left out of JSON when None.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub catalogue: Option<u32>,
    /// Texture generator of catalogue 2: 1 or 2 (None: the simulator's
    /// default, 1 unless `Simulator::with_options` says otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator: Option<u32>,
    /// Frame rate in catalogue 2 (25..=60; None: drawn per press from
    /// `FPS_CHOICES`). Catalogue 1 is always 60 fps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fps: Option<f32>,
}

impl PressSpec {
    /// A jig press by person 0 on sensor 0, everything else drawn from `seed`.
    pub fn new(textile: impl Into<String>, seed: u64) -> PressSpec {
        PressSpec {
            textile: textile.into(),
            person: 0,
            sensor: 0,
            jig: true,
            seed,
            rotation_deg: None,
            force: None,
            offset_mm: None,
            tilt_deg: None,
            release: None,
            frames: PRESS_FRAMES,
            noise: true,
            catalogue: None,
            generator: None,
            fps: None,
        }
    }
}

impl PressSpec {
    /// One-line JSON (the `telextilesd sim dataset --stream` format).
    pub fn to_json(&self) -> String {
        serde_json::to_string(self).unwrap_or_default()
    }

    /// Parse a spec from JSON (fields missing from the line are an error).
    pub fn from_json(s: &str) -> Result<PressSpec, SimError> {
        serde_json::from_str(s).map_err(|e| SimError::InvalidSpec(e.to_string()))
    }
}

impl Default for PressSpec {
    fn default() -> Self {
        PressSpec::new("T001", 0)
    }
}
