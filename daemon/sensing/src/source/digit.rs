//! Live DIGIT capture over V4L2 (the `v4l` crate, memory-mapped buffers).
//!
//! No camera exists on the build machines: this file is build-checked; the
//! parts with logic (device matching, format negotiation, decoding and
//! rotation) live in [`super::sysfs`] and [`super::yuv`] and are unit-tested.
//!
//! LED intensity: the DIGIT firmware exposes its LEDs through the UVC zoom
//! control (`V4L2_CID_ZOOM_ABSOLUTE`, OpenCV's `CAP_PROP_ZOOM`, which
//! `digit-interface` sets). Firmware revision >= 200 packs one 4-bit
//! intensity per colour: `(r << 8) | (g << 4) | b`, each 0..=15; older
//! firmware takes a single 0..=255 value. [`led_control_value`] computes it.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use image::RgbImage;
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC, Fraction};

use super::sysfs::{find_digit, DigitDevice};
use super::yuv::{decode_buffer, negotiate, Negotiated, OfferedFormat, PixelFormat, StreamMode};
use super::{FrameSource, SourceError};
use crate::frame::Frame;

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

/// The LED control of an open V4L2 device.
struct V4lLeds<'a>(&'a Device);

impl LedControl for V4lLeds<'_> {
    fn write(&mut self, value: i64) -> std::io::Result<()> {
        self.0.set_control(Control {
            id: V4L2_CID_ZOOM_ABSOLUTE,
            value: Value::Integer(value),
        })
    }
    fn read(&mut self) -> std::io::Result<i64> {
        match self.0.control(V4L2_CID_ZOOM_ABSOLUTE)?.value {
            Value::Integer(v) => Ok(v),
            other => Err(std::io::Error::other(format!(
                "the LED control holds {other:?}, not an integer"
            ))),
        }
    }
}

/// Options for opening a DIGIT.
#[derive(Clone, Debug)]
pub struct DigitOptions {
    /// Serial to look for (`None`: the first DIGIT found).
    pub serial: Option<String>,
    /// Wanted mode (falls back as in [`StreamMode::fallbacks`]).
    pub mode: StreamMode,
    /// LED intensity set on open.
    pub led: LedIntensity,
    /// sysfs root (normally `/sys`).
    pub sysfs_root: PathBuf,
    /// Device node root (normally `/dev`).
    pub dev_root: PathBuf,
    /// A frame not arriving within this time counts as the device lost.
    pub timeout: Duration,
}

impl Default for DigitOptions {
    fn default() -> Self {
        DigitOptions {
            serial: None,
            mode: StreamMode::Qvga60,
            led: LedIntensity::MAX,
            sysfs_root: PathBuf::from("/sys"),
            dev_root: PathBuf::from("/dev"),
            timeout: Duration::from_secs(2),
        }
    }
}

/// An open, streaming DIGIT.
pub struct DigitSource {
    info: DigitDevice,
    negotiated: Negotiated,
    // Field order: the stream must drop before the device.
    stream: Stream<'static>,
    device: Device,
    scratch: Vec<u8>,
    seq: u64,
    epoch: Instant,
    /// Whether the camera keeps its mode's rate.
    fps: super::fps::FpsWatch,
    notice: Option<String>,
}

fn unavailable(what: &str, dev: &DigitDevice, e: std::io::Error) -> SourceError {
    SourceError::Unavailable(format!(
        "{what} {} ({}): {e}",
        dev.node.display(),
        dev.serial
    ))
}

impl DigitSource {
    /// Find the DIGIT in sysfs, open it, negotiate the stream, set the LEDs
    /// and start capturing. Absent or unplugged → [`SourceError::Unavailable`].
    pub fn open(opts: &DigitOptions) -> Result<DigitSource, SourceError> {
        let info = find_digit(&opts.sysfs_root, &opts.dev_root, opts.serial.as_deref())?;
        let device =
            Device::with_path(&info.node).map_err(|e| unavailable("cannot open", &info, e))?;
        let offered =
            enumerate(&device).map_err(|e| unavailable("cannot enumerate formats of", &info, e))?;
        let negotiated = negotiate(&offered, opts.mode).map_err(SourceError::Fatal)?;
        let (w, h, fps) = negotiated.mode.geometry();
        let mut fmt = device
            .format()
            .map_err(|e| unavailable("cannot read format of", &info, e))?;
        fmt.width = w;
        fmt.height = h;
        fmt.fourcc = FourCC::new(&negotiated.format.fourcc());
        let got = device
            .set_format(&fmt)
            .map_err(|e| unavailable("cannot set format on", &info, e))?;
        if (got.width, got.height, got.fourcc.repr) != (w, h, negotiated.format.fourcc()) {
            return Err(SourceError::Fatal(format!(
                "{} refused {}x{} {}: driver chose {}x{} {}",
                info.node.display(),
                w,
                h,
                String::from_utf8_lossy(&negotiated.format.fourcc()),
                got.width,
                got.height,
                String::from_utf8_lossy(&got.fourcc.repr)
            )));
        }
        let params = v4l::video::capture::Parameters::new(Fraction::new(1, fps));
        device
            .set_params(&params)
            .map_err(|e| unavailable("cannot set frame rate on", &info, e))?;
        // A bad level is the caller's error; a device that will not take
        // it is reported and the stream goes on.
        match set_led_checked(&mut V4lLeds(&device), opts.led, info.revision) {
            Ok(()) => {}
            Err(LedError::Level(e)) => return Err(SourceError::Fatal(e)),
            Err(LedError::Device(e)) => {
                tracing::warn!("DIGIT {} on {}: {e}", info.serial, info.node.display())
            }
        }
        let mut stream = Stream::with_buffers(&device, Type::VideoCapture, 4)
            .map_err(|e| unavailable("cannot map buffers of", &info, e))?;
        stream.set_timeout(opts.timeout);
        tracing::info!(
            "DIGIT {} on {}: {}x{} @ {fps} fps {:?}, LEDs {:?}",
            info.serial,
            info.node.display(),
            w,
            h,
            negotiated.format,
            opts.led
        );
        Ok(DigitSource {
            info,
            negotiated,
            stream,
            device,
            scratch: Vec::new(),
            seq: 0,
            epoch: Instant::now(),
            fps: super::fps::FpsWatch::new(fps as f32),
            notice: None,
        })
    }

    /// Change the LED intensity while streaming, read back (a setting
    /// that did not take is an error, [`set_led_checked`]).
    pub fn set_led(&self, led: LedIntensity) -> Result<(), SourceError> {
        set_led_checked(&mut V4lLeds(&self.device), led, self.info.revision).map_err(|e| match e {
            LedError::Level(e) => SourceError::Fatal(e),
            LedError::Device(e) => SourceError::Unavailable(format!(
                "DIGIT {} on {}: {e}",
                self.info.serial,
                self.info.node.display()
            )),
        })
    }

    /// The device found in sysfs.
    pub fn info(&self) -> &DigitDevice {
        &self.info
    }
}

fn enumerate(device: &Device) -> std::io::Result<Vec<OfferedFormat>> {
    let mut out = Vec::new();
    for f in device.enum_formats()? {
        if PixelFormat::from_fourcc(f.fourcc.repr).is_none() {
            continue;
        }
        for size in device.enum_framesizes(f.fourcc)? {
            for d in size.size.to_discrete() {
                let mut fps = Vec::new();
                for iv in device.enum_frameintervals(f.fourcc, d.width, d.height)? {
                    if let v4l::frameinterval::FrameIntervalEnum::Discrete(fr) = iv.interval {
                        if fr.numerator > 0 {
                            fps.push((fr.denominator as f32 / fr.numerator as f32).round() as u32);
                        }
                    }
                }
                out.push(OfferedFormat {
                    fourcc: f.fourcc.repr,
                    width: d.width,
                    height: d.height,
                    fps,
                });
            }
        }
    }
    Ok(out)
}

impl FrameSource for DigitSource {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        let (buf, meta) = match self.stream.next() {
            Ok(x) => x,
            Err(e) => return Err(unavailable("lost", &self.info, e)),
        };
        let used = (meta.bytesused as usize).min(buf.len());
        let (w, h, _) = self.negotiated.mode.geometry();
        // time_t is i32 on some 32-bit targets.
        #[allow(clippy::unnecessary_cast)]
        let ts = meta.timestamp.sec as i64 * 1_000_000 + meta.timestamp.usec as i64;
        let (format, scratch) = (self.negotiated.format, &mut self.scratch);
        out.write(|image: &mut RgbImage| {
            decode_buffer(&buf[..used], format, w, h, scratch, image).map_err(SourceError::BadFrame)
        })?;
        let t = if ts > 0 {
            ts as u64
        } else {
            self.epoch.elapsed().as_micros() as u64
        };
        out.set_time(t, self.seq);
        if let Some(m) = self.fps.push(t) {
            let m = format!(
                "DIGIT {} on {}: {m}",
                self.info.serial,
                self.info.node.display()
            );
            tracing::warn!("{m}");
            self.notice = Some(m);
        }
        self.seq += 1;
        Ok(())
    }

    fn describe(&self) -> String {
        format!("DIGIT {} on {}", self.info.serial, self.info.node.display())
    }

    fn take_notice(&mut self) -> Option<String> {
        self.notice.take()
    }
    fn set_leds(&mut self, r: u8, g: u8, b: u8) -> Result<(), SourceError> {
        DigitSource::set_led(self, LedIntensity { r, g, b })
    }
}
