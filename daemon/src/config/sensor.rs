//! The sensor settings (`docs/sensors.md`): the daemon's keys
//! `sensor_profile`, `sensor_mm_per_px`, `sensor_mode` and the same
//! options of the commands that read frames, parsed and checked one way.

use telextiles_recording::profile::{Mode, SensorProfile};

/// The sensor options of the commands that read frames (`record`, `index
/// build`, `index check`, `classify`), as the daemon's `sensor_profile`,
/// `sensor_mm_per_px` and `sensor_mode` (docs/sensors.md).
#[derive(clap::Args, Debug, Clone, Default, PartialEq)]
pub struct SensorArgs {
    /// Sensor profile of the frames: digit, gelsight-mini or uvc, as the
    /// daemon's `sensor_profile` [default: recordings say their own, a
    /// camera is found by its USB ids and name, else digit]
    #[arg(long, value_name = "PROFILE", value_parser = parse_profile)]
    pub sensor_profile: Option<&'static SensorProfile>,
    /// Millimetres per pixel of the sensor's images (a uvc camera needs
    /// it), as the daemon's `sensor_mm_per_px`
    #[arg(long, value_name = "MM", value_parser = parse_mm_per_px)]
    pub sensor_mm_per_px: Option<f32>,
    /// Camera mode to ask for, WIDTHxHEIGHT@FPS (e.g. 640x480@30), as the
    /// daemon's `sensor_mode`
    #[arg(long, value_name = "MODE")]
    pub sensor_mode: Option<Mode>,
}

impl SensorArgs {
    /// The sensor given (None: recordings say their own, else a DIGIT),
    /// checked as the daemon checks its keys.
    pub fn sensor(&self) -> anyhow::Result<Option<telextiles_recording::recording::Sensor>> {
        check_sensor(
            self.sensor_profile,
            self.sensor_mm_per_px,
            ("--sensor-profile", "--sensor-mm-per-px"),
        )
        .map_err(anyhow::Error::msg)?;
        Ok(self
            .sensor_profile
            .map(|profile| telextiles_recording::recording::Sensor {
                profile,
                mm_per_px: self.sensor_mm_per_px,
            }))
    }
}

pub(super) fn parse_profile(s: &str) -> Result<&'static SensorProfile, String> {
    telextiles_recording::profile::by_name(s.trim())
}

pub(super) fn parse_mm_per_px(s: &str) -> Result<f32, String> {
    let v: f32 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number of millimetres per pixel (e.g. 0.03)"))?;
    check_mm_per_px(v)
}

pub(super) fn check_mm_per_px(v: f32) -> Result<f32, String> {
    // A tactile sensor's pixel: from a micrometre to a millimetre.
    if !(v.is_finite() && (0.001..=1.0).contains(&v)) {
        return Err(format!(
            "{v} mm per pixel is out of range (0.001 to 1: a tactile sensor's pixel)"
        ));
    }
    Ok(v)
}

/// A scale needs the profile it belongs to; a generic camera needs its
/// scale. `names`: what the profile and the scale are called where they
/// were given (the keys, or the flags).
pub(super) fn check_sensor(
    profile: Option<&SensorProfile>,
    mm: Option<f32>,
    (profile_name, mm_name): (&str, &str),
) -> Result<(), String> {
    match (profile, mm) {
        (None, Some(_)) => Err(format!(
            "{mm_name} is given without {profile_name}: say which sensor it is the scale of"
        )),
        (Some(p), None) if p.field_mm.is_none() => Err(format!(
            "{profile_name} {} needs {mm_name}: the millimetres per pixel of its images (docs/sensors.md says how to measure them)",
            p.name
        )),
        _ => Ok(()),
    }
}
