//! Live capture from a V4L2 camera of any sensor profile (the `v4l`
//! crate, memory-mapped buffers): a DIGIT, a GelSight Mini, or a generic
//! UVC camera whose scale its owner gives.
//!
//! No camera exists on the build machines: this file is build-checked; the
//! parts with logic (device matching, mode negotiation, decoding, the
//! mapping to the frame, LED values and their read-back) live in
//! [`super::sysfs`], [`super::yuv`], `telextiles_recording::resample` and
//! [`super::digit`] and are unit-tested.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use image::RgbImage;
use telextiles_recording::profile::{Mode, SensorProfile, DIGIT};
use telextiles_recording::resample::FrameMap;
use v4l::buffer::Type;
use v4l::control::{Control, Value};
use v4l::io::mmap::Stream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC, Fraction};

use super::digit::{set_led_checked, LedControl, LedError, LedIntensity, V4L2_CID_ZOOM_ABSOLUTE};
use super::sysfs::{find_camera, Camera};
use super::yuv::{decode_buffer, negotiate, Negotiated, OfferedFormat, PixelFormat};
use super::{FrameSource, SourceError};
use crate::frame::Frame;

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

/// Options for opening a camera.
#[derive(Clone, Debug)]
pub struct CameraOptions {
    /// Its sensor profile.
    pub profile: &'static SensorProfile,
    /// Its serial, device node or kernel name (`None`: the first of the
    /// profile's sensors found).
    pub select: Option<String>,
    /// The mode asked for (`None`: the profile's first the camera offers;
    /// see [`negotiate`]).
    pub mode: Option<Mode>,
    /// Millimetres per pixel of the mode, when its owner gives them (a
    /// generic camera must); else the profile's.
    pub mm_per_px: Option<f32>,
    /// LED intensity set on open (sensors with LEDs).
    pub led: LedIntensity,
    /// sysfs root (normally `/sys`).
    pub sysfs_root: PathBuf,
    /// Device node root (normally `/dev`).
    pub dev_root: PathBuf,
    /// A frame not arriving within this time counts as the device lost.
    pub timeout: Duration,
}

impl Default for CameraOptions {
    fn default() -> Self {
        CameraOptions {
            profile: &DIGIT,
            select: None,
            mode: None,
            mm_per_px: None,
            led: LedIntensity::MAX,
            sysfs_root: PathBuf::from("/sys"),
            dev_root: PathBuf::from("/dev"),
            timeout: Duration::from_secs(2),
        }
    }
}

/// An open, streaming camera.
pub struct CameraSource {
    info: Camera,
    profile: &'static SensorProfile,
    negotiated: Negotiated,
    /// Its images to the frame.
    map: FrameMap,
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

fn unavailable(what: &str, dev: &Camera, e: std::io::Error) -> SourceError {
    SourceError::Unavailable(format!(
        "{what} {} ({}): {e}",
        dev.node.display(),
        dev.serial
    ))
}

impl CameraSource {
    /// Find the profile's sensor in sysfs, open it, negotiate the stream,
    /// set the LEDs (sensors with LEDs) and start capturing. Absent or
    /// unplugged → [`SourceError::Unavailable`]; a mode or scale that
    /// cannot work → [`SourceError::Fatal`].
    pub fn open(opts: &CameraOptions) -> Result<CameraSource, SourceError> {
        let profile = opts.profile;
        let info = find_camera(
            &opts.sysfs_root,
            &opts.dev_root,
            profile,
            opts.select.as_deref(),
        )?;
        let device =
            Device::with_path(&info.node).map_err(|e| unavailable("cannot open", &info, e))?;
        let offered =
            enumerate(&device).map_err(|e| unavailable("cannot enumerate formats of", &info, e))?;
        let negotiated = negotiate(&offered, profile, opts.mode).map_err(SourceError::Fatal)?;
        let Mode {
            width: w,
            height: h,
            fps,
        } = negotiated.mode;
        let map = FrameMap::for_profile(profile, w, h, opts.mm_per_px)
            .map_err(|e| SourceError::Fatal(format!("{}: {e}", info.node.display())))?;
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
        let params = v4l::video::capture::Parameters::new(Fraction::new(1, fps.round() as u32));
        device
            .set_params(&params)
            .map_err(|e| unavailable("cannot set frame rate on", &info, e))?;
        if profile.leds {
            // A bad level is the caller's error; a device that will not
            // take it is reported and the stream goes on.
            match set_led_checked(&mut V4lLeds(&device), opts.led, info.revision) {
                Ok(()) => {}
                Err(LedError::Level(e)) => return Err(SourceError::Fatal(e)),
                Err(LedError::Device(e)) => {
                    tracing::warn!("{} on {}: {e}", profile.label, info.node.display())
                }
            }
        }
        let mut stream = Stream::with_buffers(&device, Type::VideoCapture, 4)
            .map_err(|e| unavailable("cannot map buffers of", &info, e))?;
        stream.set_timeout(opts.timeout);
        let notice = negotiated.note.clone();
        if let Some(n) = &notice {
            tracing::warn!("{} on {}: {n}", profile.label, info.node.display());
        }
        tracing::info!(
            "{} {} on {}: {}x{} @ {fps} fps {:?}, {} mm per pixel (frame field {}x{}){}",
            profile.label,
            info.serial,
            info.node.display(),
            w,
            h,
            negotiated.format,
            map.mm_per_px(),
            map.valid().w,
            map.valid().h,
            if profile.leds {
                format!(", LEDs {:?}", opts.led)
            } else {
                String::new()
            }
        );
        Ok(CameraSource {
            info,
            profile,
            negotiated,
            map,
            stream,
            device,
            scratch: Vec::new(),
            seq: 0,
            epoch: Instant::now(),
            fps: super::fps::FpsWatch::new(fps),
            notice,
        })
    }

    /// Change the LED intensity while streaming, read back (a setting
    /// that did not take is an error, [`set_led_checked`]).
    pub fn set_led(&self, led: LedIntensity) -> Result<(), SourceError> {
        if !self.profile.leds {
            return Err(SourceError::Unavailable(format!(
                "{} has no LEDs to control (LED control needs a DIGIT)",
                self.describe()
            )));
        }
        set_led_checked(&mut V4lLeds(&self.device), led, self.info.revision).map_err(|e| match e {
            LedError::Level(e) => SourceError::Fatal(e),
            LedError::Device(e) => SourceError::Unavailable(format!("{}: {e}", self.describe())),
        })
    }

    /// The device found in sysfs.
    pub fn info(&self) -> &Camera {
        &self.info
    }

    /// Its sensor profile.
    pub fn profile(&self) -> &'static SensorProfile {
        self.profile
    }

    /// The mode streaming.
    pub fn mode(&self) -> Mode {
        self.negotiated.mode
    }

    /// Millimetres per pixel of its images.
    pub fn mm_per_px(&self) -> f32 {
        self.map.mm_per_px()
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

impl FrameSource for CameraSource {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        let (buf, meta) = match self.stream.next() {
            Ok(x) => x,
            Err(e) => return Err(unavailable("lost", &self.info, e)),
        };
        let used = (meta.bytesused as usize).min(buf.len());
        // time_t is i32 on some 32-bit targets.
        #[allow(clippy::unnecessary_cast)]
        let ts = meta.timestamp.sec as i64 * 1_000_000 + meta.timestamp.usec as i64;
        let (format, scratch, map) = (self.negotiated.format, &mut self.scratch, &mut self.map);
        out.write(|image: &mut RgbImage| {
            decode_buffer(&buf[..used], format, map, scratch, image).map_err(SourceError::BadFrame)
        })?;
        let t = if ts > 0 {
            ts as u64
        } else {
            self.epoch.elapsed().as_micros() as u64
        };
        out.set_time(t, self.seq);
        if let Some(m) = self.fps.push(t) {
            let m = format!("{}: {m}", self.describe());
            tracing::warn!("{m}");
            self.notice = Some(m);
        }
        self.seq += 1;
        Ok(())
    }

    fn describe(&self) -> String {
        if self.info.serial.is_empty() {
            format!("{} on {}", self.profile.label, self.info.node.display())
        } else {
            format!(
                "{} {} on {}",
                self.profile.label,
                self.info.serial,
                self.info.node.display()
            )
        }
    }

    fn take_notice(&mut self) -> Option<String> {
        self.notice.take()
    }
    fn set_leds(&mut self, r: u8, g: u8, b: u8) -> Result<(), SourceError> {
        CameraSource::set_led(self, LedIntensity { r, g, b })
    }
}
