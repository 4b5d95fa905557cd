//! The DIGIT's LEDs: what to write to its LED control, and a setting
//! checked by reading it back. The camera itself is read by
//! [`super::camera`].
//!
//! LED intensity: the DIGIT firmware exposes its LEDs through the UVC zoom
//! control (`V4L2_CID_ZOOM_ABSOLUTE`, OpenCV's `CAP_PROP_ZOOM`, which
//! `digit-interface` sets). Firmware revision >= 200 packs one 4-bit
//! intensity per colour: `(r << 8) | (g << 4) | b`, each 0..=15; older
//! firmware takes a single 0..=255 value. [`led_control_value`] computes it.

/// `V4L2_CID_ZOOM_ABSOLUTE` (`V4L2_CID_CAMERA_CLASS_BASE + 13`).
pub const V4L2_CID_ZOOM_ABSOLUTE: u32 = 0x009a_090d;

/// LED intensity per colour, each 0..=15.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LedIntensity {
    /// Red.
    pub r: u8,
    /// Green.
    pub g: u8,
    /// Blue.
    pub b: u8,
}

impl LedIntensity {
    /// All LEDs at full intensity (digit-interface's default on connect).
    pub const MAX: LedIntensity = LedIntensity {
        r: 15,
        g: 15,
        b: 15,
    };
    /// The same level on all three colours.
    pub fn uniform(level: u8) -> LedIntensity {
        LedIntensity {
            r: level,
            g: level,
            b: level,
        }
    }
}

/// The value to write to the zoom control for `led` on firmware `revision`.
/// Error if a level exceeds 15.
pub fn led_control_value(led: LedIntensity, revision: u32) -> Result<i64, String> {
    if led.r > 15 || led.g > 15 || led.b > 15 {
        return Err(format!(
            "LED intensities must be 0..=15, got r={} g={} b={}",
            led.r, led.g, led.b
        ));
    }
    if revision < 200 {
        // Old firmware: one global level 0..=255 (digit-interface scales by 17).
        let level = led.r.max(led.g).max(led.b) as i64;
        return Ok(level * 17);
    }
    Ok(((led.r as i64) << 8) | ((led.g as i64) << 4) | led.b as i64)
}

/// The DIGIT's LED control (V4L2's zoom control): the device, or a fake
/// in tests.
pub trait LedControl {
    /// Write the control.
    fn write(&mut self, value: i64) -> std::io::Result<()>;
    /// Read the control back.
    fn read(&mut self) -> std::io::Result<i64>;
}

/// Why the LEDs were not set.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LedError {
    /// A level out of range: nothing was written.
    #[error("{0}")]
    Level(String),
    /// The sensor would not take it, or could not be read back.
    #[error("{0}")]
    Device(String),
}

/// Set the LEDs to `led` and read the control back: a value that did not
/// take — the DIGIT libraries' users report LED settings failing silently
/// — is an error naming what was written and what reads back, never a
/// quiet success.
pub fn set_led_checked(
    ctl: &mut dyn LedControl,
    led: LedIntensity,
    revision: u32,
) -> Result<(), LedError> {
    let value = led_control_value(led, revision).map_err(LedError::Level)?;
    ctl.write(value)
        .map_err(|e| LedError::Device(format!("cannot set the LEDs: {e}")))?;
    let got = ctl.read().map_err(|e| {
        LedError::Device(format!(
            "set the LEDs but cannot read the control back: {e}"
        ))
    })?;
    if got != value {
        return Err(LedError::Device(format!(
            "the LEDs did not take: wrote {value} (r={} g={} b={}) to the LED control, it reads back {got}; the sensor's firmware (revision {revision}) may not support setting them",
            led.r, led.g, led.b
        )));
    }
    Ok(())
}
