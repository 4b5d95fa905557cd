//! Sensor profiles: what an optical tactile sensor is, how it is found
//! (USB ids, or words of its USB product or V4L2 card name), the modes it
//! streams, the physical size of its field of view (so the millimetres
//! per pixel of each mode are known) and what it can control.
//!
//! Built in: the DIGIT, the GelSight Mini, and a generic UVC camera whose
//! scale its owner gives. What is known and what is assumed is said per
//! profile; `docs/sensors.md` is the user's page.

/// One stream mode: size in the camera's own orientation, frames per second.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Mode {
    /// Width in pixels, as the camera streams.
    pub width: u32,
    /// Height in pixels, as the camera streams.
    pub height: u32,
    /// Frames per second the mode promises (a camera may deliver fewer).
    pub fps: f32,
}

impl std::str::FromStr for Mode {
    type Err = String;
    /// `640x480@30`: width x height (the camera's orientation) @ frames
    /// per second.
    fn from_str(s: &str) -> Result<Mode, String> {
        let bad = || format!("{s:?} is not a mode: give WIDTHxHEIGHT@FPS, e.g. 640x480@30");
        let (size, fps) = s.trim().split_once('@').ok_or_else(bad)?;
        let (w, h) = size.split_once(['x', 'X']).ok_or_else(bad)?;
        let width: u32 = w.trim().parse().map_err(|_| bad())?;
        let height: u32 = h.trim().parse().map_err(|_| bad())?;
        let fps: f32 = fps.trim().parse().map_err(|_| bad())?;
        if width == 0 || height == 0 || width > 8192 || height > 8192 {
            return Err(format!("{s:?}: a size of 1 to 8192 pixels each way"));
        }
        if !(fps.is_finite() && fps > 0.0 && fps <= 1000.0) {
            return Err(format!("{s:?}: a frame rate above 0 and at most 1000"));
        }
        Ok(Mode { width, height, fps })
    }
}

impl Mode {
    /// For people: `640x480 @ 30 fps` (the configuration's form is
    /// [`Mode`]'s `Display`, `640x480@30`).
    pub fn text(&self) -> String {
        format!("{}x{} @ {} fps", self.width, self.height, self.fps)
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}x{}@{}", self.width, self.height, self.fps)
    }
}

/// An optical tactile sensor (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorProfile {
    /// The name the configuration and the commands use (`digit`,
    /// `gelsight-mini`, `uvc`).
    pub name: &'static str,
    /// The name for people.
    pub label: &'static str,
    /// USB (vendor, product) ids, lower-case hex, that identify it.
    pub usb_ids: &'static [(&'static str, &'static str)],
    /// Words of the USB product string or the V4L2 card name that
    /// identify it (compared case-insensitively).
    pub names: &'static [&'static str],
    /// The modes it streams (empty: whatever the camera offers).
    pub modes: &'static [Mode],
    /// The camera streams landscape and frames are turned to portrait.
    pub landscape: bool,
    /// The field of view in millimetres, in the camera's own orientation
    /// (width, height); None: its owner gives `mm_per_px`.
    pub field_mm: Option<(f32, f32)>,
    /// It has LEDs the daemon can set.
    pub leds: bool,
}

/// The scale the shipped encoder was made for: millimetres per pixel of
/// the 240x320 frame (the simulator's DIGIT, `telextiles_sim`'s
/// `MM_PER_PX`).
pub const FRAME_MM_PER_PX: f32 = 0.08;

/// The DIGIT (Meta / GelSight): USB 2833:0209, QVGA at 60 or 30 fps and
/// VGA at 30 or 15 fps (digit-interface's modes), landscape, R/G/B LEDs.
/// Its field of view is taken as the simulator's and the encoder's scale,
/// 0.08 mm per QVGA pixel (25.6 x 19.2 mm); not yet measured on a unit.
pub const DIGIT: SensorProfile = SensorProfile {
    name: "digit",
    label: "DIGIT",
    usb_ids: &[("2833", "0209")],
    names: &["DIGIT"],
    modes: &[
        Mode {
            width: 320,
            height: 240,
            fps: 60.0,
        },
        Mode {
            width: 320,
            height: 240,
            fps: 30.0,
        },
        Mode {
            width: 640,
            height: 480,
            fps: 30.0,
        },
        Mode {
            width: 640,
            height: 480,
            fps: 15.0,
        },
    ],
    landscape: true,
    field_mm: Some((25.6, 19.2)),
    leds: true,
};

/// The GelSight Mini, found by its name (its USB ids are not listed
/// here: they are not documented to us). Its field of view, 18.9 x 14.2
/// mm, is Taxim's calibration of a real unit (0.0295 mm per pixel at
/// 640x480); the modes are the 640x480 and 320x240 frames GelSight's
/// tools deliver, at most 25 fps (often 15–18 on Linux).
pub const GELSIGHT_MINI: SensorProfile = SensorProfile {
    name: "gelsight-mini",
    label: "GelSight Mini",
    usb_ids: &[],
    names: &["GelSight Mini", "GelSight"],
    modes: &[
        Mode {
            width: 320,
            height: 240,
            fps: 25.0,
        },
        Mode {
            width: 640,
            height: 480,
            fps: 25.0,
        },
    ],
    landscape: true,
    field_mm: Some((18.88, 14.16)),
    leds: false,
};

/// Any other UVC camera behind a gel: its owner gives the scale
/// (`sensor.mm_per_px`) and the mode.
pub const UVC: SensorProfile = SensorProfile {
    name: "uvc",
    label: "UVC camera",
    usb_ids: &[],
    names: &[],
    modes: &[],
    landscape: true,
    field_mm: None,
    leds: false,
};

/// Every built-in profile, the generic one last.
pub const PROFILES: &[SensorProfile] = &[DIGIT, GELSIGHT_MINI, UVC];

/// The built-in profile called `name`.
pub fn by_name(name: &str) -> Result<&'static SensorProfile, String> {
    PROFILES.iter().find(|p| p.name == name).ok_or_else(|| {
        format!(
            "unknown sensor profile {name:?}; built in: {}",
            PROFILES
                .iter()
                .map(|p| p.name)
                .collect::<Vec<_>>()
                .join(", ")
        )
    })
}

impl SensorProfile {
    /// Whether a camera with these USB ids, USB product string and V4L2
    /// card name is this sensor.
    pub fn matches(&self, vendor: &str, product_id: &str, product: &str, card: &str) -> bool {
        let id = self
            .usb_ids
            .iter()
            .any(|(v, p)| v.eq_ignore_ascii_case(vendor) && p.eq_ignore_ascii_case(product_id));
        let name = self.names.iter().any(|n| {
            let n = n.to_ascii_lowercase();
            product.to_ascii_lowercase().contains(&n) || card.to_ascii_lowercase().contains(&n)
        });
        id || name
    }

    /// Millimetres per pixel of a `width`-pixel-wide stream (the
    /// camera's orientation), if the profile knows its field of view.
    pub fn mm_per_px(&self, width: u32) -> Option<f32> {
        self.field_mm
            .filter(|_| width > 0)
            .map(|(w, _)| w / width as f32)
    }
}

/// The profile of a camera: the first built-in one it matches, else the
/// generic UVC profile.
pub fn identify(
    vendor: &str,
    product_id: &str,
    product: &str,
    card: &str,
) -> &'static SensorProfile {
    PROFILES
        .iter()
        .find(|p| p.matches(vendor, product_id, product, card))
        .unwrap_or(&UVC)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cameras_are_identified_by_ids_or_names_else_generic() {
        assert_eq!(identify("2833", "0209", "", "").name, "digit");
        assert_eq!(identify("ffff", "0001", "DIGIT", "").name, "digit");
        assert_eq!(
            identify("1234", "5678", "", "GelSight Mini R0B 2BG8-LLT0: Ge").name,
            "gelsight-mini"
        );
        assert_eq!(
            identify("046d", "0825", "Webcam C270", "UVC Camera").name,
            "uvc"
        );
        assert_eq!(by_name("gelsight-mini").unwrap().label, "GelSight Mini");
        assert!(by_name("gelsight")
            .unwrap_err()
            .contains("digit, gelsight-mini, uvc"));
    }

    #[test]
    fn modes_are_written_and_read_as_width_x_height_at_fps() {
        let m: Mode = "640x480@30".parse().unwrap();
        assert_eq!(m, DIGIT.modes[2]);
        assert_eq!(m.to_string(), "640x480@30");
        assert_eq!(m.to_string().parse::<Mode>().unwrap(), m);
        for bad in ["640x480", "640*480@30", "0x480@30", "640x480@0", "axb@c"] {
            assert!(bad.parse::<Mode>().is_err(), "{bad}");
        }
    }

    #[test]
    fn the_scale_of_each_mode_follows_from_the_field_of_view() {
        // The DIGIT's QVGA pixel is the encoder's frame pixel; VGA is half.
        assert_eq!(DIGIT.mm_per_px(320), Some(FRAME_MM_PER_PX));
        assert!((DIGIT.mm_per_px(640).unwrap() - 0.04).abs() < 1e-6);
        // Taxim's GelSight Mini calibration: 0.0295 mm per pixel at 640.
        assert!((GELSIGHT_MINI.mm_per_px(640).unwrap() - 0.0295).abs() < 1e-4);
        assert!((GELSIGHT_MINI.mm_per_px(320).unwrap() - 0.059).abs() < 1e-3);
        // The generic camera's scale is its owner's to give.
        assert_eq!(UVC.mm_per_px(640), None);
        assert_eq!(DIGIT.mm_per_px(0), None);
    }
}
