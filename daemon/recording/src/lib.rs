//! The on-disk press format and the frame geometry, shared by the
//! simulator, the live camera path, the recorder and the offline tools: a
//! press ([`Press`]: [`PressMeta`] and its frames), the press directory and
//! the PyTouch layout ([`recording`]), and the frame every source delivers
//! ([`WIDTH`] x [`HEIGHT`] RGB, portrait, as digit-interface returns DIGIT
//! frames). No renderer, calibration or camera here.
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

use serde::{Deserialize, Serialize};

pub mod profile;
pub mod recording;
pub mod resample;

/// Frames per second of a DIGIT press.
pub const FPS: f32 = 60.0;
/// Frame width (columns), as digit-interface delivers frames.
pub const WIDTH: u32 = 240;
/// Frame height (rows).
pub const HEIGHT: u32 = 320;

/// The physical parameters a simulated press was rendered with.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PressParams {
    pub rotation_deg: f32,
    pub force_n: f32,
    pub offset_mm: [f32; 2],
    /// Sensor tilt about the x and y axes, degrees.
    pub tilt_deg: [f32; 2],
    /// Indentation of the gel at full force, mm.
    pub indentation_mm: f32,
    pub gel_thickness_mm: f32,
    /// First frame with contact.
    pub contact_frame: u32,
    /// First frame of the hold (ramp done).
    pub hold_frame: u32,
    /// First frame of the release, if the press releases.
    pub release_frame: Option<u32>,
    /// Lateral slip during the hold, mm.
    pub slip_mm: [f32; 2],
    /// Relative force wobble amplitude during the hold.
    pub wobble: f32,
    pub noise: bool,
    pub catalogue_version: u32,
    /// Texture generator (catalogue 2; 1 when absent).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub generator: u32,
    /// Region of the bolt this press saw (catalogue 2): presses with another
    /// swatch see other cloth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub swatch: Option<u32>,
    /// Catalogue 2: what else is in the window ("crease", "fold", "seam",
    /// "hem", "edge", "tilt") and the ramp ("slow-ramp", "fast-ramp").
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub features: Vec<String>,
}

fn one() -> u32 {
    1
}

fn is_one(v: &u32) -> bool {
    *v == 1
}

/// Metadata of a press (simulated or captured).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PressMeta {
    /// Textile id (or, for PyTouch data, the class directory name).
    pub textile: String,
    pub person: u32,
    pub sensor: u32,
    pub jig: bool,
    pub fps: f32,
    /// Per-frame timestamps in microseconds from the first frame.
    pub timestamps_us: Vec<u64>,
    /// Seed of a simulated press; None for captured data.
    pub seed: Option<u64>,
    /// "sim", "digit" (live capture) or "pytouch".
    pub source: String,
    /// Serial number of the physical sensor, if known.
    pub sensor_serial: Option<String>,
    /// Simulator parameters of a simulated press.
    pub params: Option<PressParams>,
    /// The first `reference_frames` frames show the sensor untouched: their
    /// mean is this recording's own no-contact reference (`telextilesd
    /// record` keeps the quiet frames before contact). None: not recorded
    /// (older recordings, PyTouch data); readers capture a reference from
    /// the recording's first quiet frames instead.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_frames: Option<u32>,
    /// The sensor profile it was captured with ([`profile::PROFILES`]:
    /// `digit`, `gelsight-mini`, `uvc`). None: a DIGIT (recordings made
    /// before profiles existed).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sensor_profile: Option<String>,
    /// Millimetres per pixel of the frames as stored. None: the profile's
    /// own scale at their size (a DIGIT's 240x320 frame: 0.08, the scale
    /// every frame is mapped to, [`profile::FRAME_MM_PER_PX`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mm_per_px: Option<f32>,
}

/// How press.json names the sensor of `profile`: not at all for a DIGIT
/// (as every recording made before profiles), else by its profile's name.
pub fn profile_tag(profile: &profile::SensorProfile) -> Option<String> {
    (profile.name != profile::DIGIT.name).then(|| profile.name.to_string())
}

impl PressMeta {
    /// The profile it was captured with ([`PressMeta::sensor_profile`];
    /// a DIGIT when none is recorded).
    pub fn profile(&self) -> Result<&'static profile::SensorProfile, String> {
        match &self.sensor_profile {
            None => Ok(&profile::DIGIT),
            Some(n) => profile::by_name(n),
        }
    }
}

/// One press: metadata and frames. Read back, its frames are 240 wide x
/// 320 tall RGB at the frame's scale, whatever the sensor; to be written,
/// they may also be a camera's own images of the size and scale its
/// metadata gives (a simulated press in another sensor's geometry).
#[derive(Clone, Debug, PartialEq)]
pub struct Press {
    pub meta: PressMeta,
    pub frames: Vec<image::RgbImage>,
}
