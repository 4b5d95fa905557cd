//! Pure parts of camera capture: stream-format negotiation by sensor
//! profile, decoding of YUYV and MJPG buffers, and the mapping to the
//! portrait frames `digit-interface` returns (any other sensor's through
//! its [`FrameMap`]).
//!
//! Orientation: the DIGIT's image sensor streams landscape (320x240 QVGA).
//! `digit-interface` `get_frame()` applies `cv2.transpose` then
//! `cv2.flip(frame, 0)` (flip about the horizontal axis), i.e. a rotation by
//! 90 degrees counter-clockwise: output pixel (x, y) = sensor pixel
//! (W-1-y, x), giving 240 wide x 320 tall. VGA (640x480) is rotated the same
//! way and then averaged 2x2 down to 240x320 so the rest of the pipeline sees
//! one geometry.

use image::RgbImage;

use telextiles_recording::profile::{Mode, SensorProfile};
use telextiles_recording::resample::FrameMap;

use crate::frame::{FrameError, FRAME_H, FRAME_W};

/// Pixel formats we can decode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// Packed 4:2:2 `YUYV` (Y0 U Y1 V), BT.601 limited range.
    Yuyv,
    /// Motion JPEG, one baseline JPEG per buffer.
    Mjpg,
}

impl PixelFormat {
    /// The V4L2 fourcc.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            PixelFormat::Yuyv => *b"YUYV",
            PixelFormat::Mjpg => *b"MJPG",
        }
    }
    /// From a V4L2 fourcc.
    pub fn from_fourcc(f: [u8; 4]) -> Option<PixelFormat> {
        match &f {
            b"YUYV" => Some(PixelFormat::Yuyv),
            b"MJPG" => Some(PixelFormat::Mjpg),
            _ => None,
        }
    }
}

/// One (format, size) the device offers, with its frame rates.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct OfferedFormat {
    /// V4L2 fourcc.
    pub fourcc: [u8; 4],
    /// Width in pixels (sensor orientation).
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// Frame rates (whole fps) offered at this size.
    pub fps: Vec<u32>,
}

/// What to ask the driver for.
#[derive(Clone, Debug, PartialEq)]
pub struct Negotiated {
    /// Pixel format.
    pub format: PixelFormat,
    /// Size (the camera's orientation) and frame rate.
    pub mode: Mode,
    /// Set when the mode asked for is not the one chosen: what the owner
    /// should be told (the camera does not offer it).
    pub note: Option<String>,
}

/// Pick a format for `profile`'s camera: the mode asked for (`want`) if
/// the camera offers it, else the profile's modes in order, else (a
/// generic profile, which lists none) the first mode offered; YUYV
/// preferred over MJPG (no decode cost, no compression artefacts). A mode
/// asked for and not offered is not an error, but the result's `note`
/// says so and what was chosen instead (a DIGIT that refuses VGA). Error
/// if the camera offers none of them in a format we decode.
pub fn negotiate(
    offered: &[OfferedFormat],
    profile: &SensorProfile,
    want: Option<Mode>,
) -> Result<Negotiated, String> {
    let mut candidates: Vec<Mode> = want
        .into_iter()
        .chain(profile.modes.iter().copied())
        .collect();
    if profile.modes.is_empty() {
        for o in offered {
            if PixelFormat::from_fourcc(o.fourcc).is_some() {
                if let Some(&fps) = o.fps.iter().max() {
                    candidates.push(Mode {
                        width: o.width,
                        height: o.height,
                        fps: fps as f32,
                    });
                }
            }
        }
    }
    for mode in &candidates {
        let fps = mode.fps.round() as u32;
        for format in [PixelFormat::Yuyv, PixelFormat::Mjpg] {
            let ok = offered.iter().any(|o| {
                o.fourcc == format.fourcc()
                    && (o.width, o.height) == (mode.width, mode.height)
                    && o.fps.contains(&fps)
            });
            if ok {
                let note = want.filter(|w| w != mode).map(|w| {
                    format!(
                        "the {} does not offer {} (it offers {}); streaming {} instead",
                        profile.label,
                        w.text(),
                        offered_text(offered),
                        mode.text()
                    )
                });
                return Ok(Negotiated {
                    format,
                    mode: *mode,
                    note,
                });
            }
        }
    }
    Err(format!(
        "the camera offers none of the {} modes ({} in YUYV or MJPG); it offers: {}",
        profile.label,
        candidates
            .iter()
            .map(Mode::text)
            .collect::<Vec<_>>()
            .join(", "),
        offered_text(offered)
    ))
}

fn offered_text(offered: &[OfferedFormat]) -> String {
    let list: Vec<String> = offered
        .iter()
        .map(|o| {
            format!(
                "{} {}x{} @ {:?} fps",
                String::from_utf8_lossy(&o.fourcc),
                o.width,
                o.height,
                o.fps
            )
        })
        .collect();
    if list.is_empty() {
        "nothing".to_string()
    } else {
        list.join("; ")
    }
}

#[inline]
fn clamp_u8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

#[inline]
fn yuv_to_rgb(y: u8, u: u8, v: u8) -> [u8; 3] {
    // BT.601 limited range, 16.16 fixed point (as OpenCV's YUV2RGB_YUYV).
    let c = (y as i32 - 16).max(0) * 76284; // 1.164
    let d = u as i32 - 128;
    let e = v as i32 - 128;
    let r = (c + 104595 * e + 32768) >> 16; // 1.596
    let g = (c - 25625 * d - 53281 * e + 32768) >> 16; // 0.391, 0.813
    let b = (c + 132252 * d + 32768) >> 16; // 2.018
    [clamp_u8(r), clamp_u8(g), clamp_u8(b)]
}

/// Decode a YUYV buffer of `width` x `height` (sensor orientation) into
/// `rgb` (resized to `width*height*3`, reused between calls).
pub fn decode_yuyv(
    buf: &[u8],
    width: u32,
    height: u32,
    rgb: &mut Vec<u8>,
) -> Result<(), FrameError> {
    let (w, h) = (width as usize, height as usize);
    if w == 0 || h == 0 || w % 2 != 0 {
        return Err(FrameError::Decode(format!(
            "YUYV needs an even, non-zero width, got {width}x{height}"
        )));
    }
    let need = w * h * 2;
    // Drivers may pad the buffer; shorter is a truncated frame.
    if buf.len() < need {
        return Err(FrameError::Decode(format!(
            "YUYV buffer holds {} bytes, a {width}x{height} frame needs {need}",
            buf.len()
        )));
    }
    rgb.resize(w * h * 3, 0);
    for (src, dst) in buf[..need].chunks_exact(4).zip(rgb.chunks_exact_mut(6)) {
        let (y0, u, y1, v) = (src[0], src[1], src[2], src[3]);
        dst[..3].copy_from_slice(&yuv_to_rgb(y0, u, v));
        dst[3..].copy_from_slice(&yuv_to_rgb(y1, u, v));
    }
    Ok(())
}

/// Decode one MJPG buffer (a JPEG) into `rgb`; checks it is `width` x `height`.
/// Truncated frames (a known UVC failure: the JPEG decoder would fill the
/// missing part with grey) are rejected by checking the end-of-image marker.
pub fn decode_mjpg(
    buf: &[u8],
    width: u32,
    height: u32,
    rgb: &mut Vec<u8>,
) -> Result<(), FrameError> {
    if !buf.starts_with(&[0xff, 0xd8]) {
        return Err(FrameError::Decode(
            "MJPG buffer does not start with a JPEG start-of-image marker".into(),
        ));
    }
    // Some cameras pad the buffer with zeros after the end-of-image marker.
    let end = buf.iter().rposition(|&b| b != 0).map_or(0, |i| i + 1);
    if end < 4 || buf[end - 2..end] != [0xff, 0xd9] {
        return Err(FrameError::Decode(
            "truncated MJPG frame (no JPEG end-of-image marker)".into(),
        ));
    }
    let img = image::load_from_memory_with_format(buf, image::ImageFormat::Jpeg)
        .map_err(|e| FrameError::Decode(format!("MJPG buffer is not a valid JPEG: {e}")))?;
    if (img.width(), img.height()) != (width, height) {
        return Err(FrameError::Decode(format!(
            "MJPG frame is {}x{}, the stream was negotiated at {width}x{height}",
            img.width(),
            img.height()
        )));
    }
    let img = img.into_rgb8();
    rgb.clear();
    rgb.extend_from_slice(img.as_raw());
    Ok(())
}

/// Map a DIGIT's landscape RGB buffer (`width` x `height`) to the
/// 240x320 portrait frame: 90 degrees counter-clockwise (digit-interface's
/// transpose + vertical flip), VGA averaged over 2x2 blocks
/// ([`FrameMap::digit`], which the reader of others' saved frames
/// shares); a stream must be landscape. Per-frame callers keep a
/// [`FrameMap`] and call [`decode_buffer`].
pub fn rotate_to_frame(
    rgb: &[u8],
    width: u32,
    height: u32,
    out: &mut RgbImage,
) -> Result<(), FrameError> {
    if width < height {
        return Err(FrameError::Decode(format!(
            "cannot map a {width}x{height} sensor frame to {FRAME_W}x{FRAME_H}: the camera streams landscape"
        )));
    }
    FrameMap::digit(width, height)
        .and_then(|mut m| m.map(rgb, out))
        .map_err(FrameError::Decode)
}

/// Decode a captured buffer of `map`'s size and map it into `out` (the
/// frame at its scale). `scratch` is reused.
pub fn decode_buffer(
    buf: &[u8],
    format: PixelFormat,
    map: &mut FrameMap,
    scratch: &mut Vec<u8>,
    out: &mut RgbImage,
) -> Result<(), FrameError> {
    let (width, height) = map.size();
    match format {
        PixelFormat::Yuyv => decode_yuyv(buf, width, height, scratch)?,
        PixelFormat::Mjpg => decode_mjpg(buf, width, height, scratch)?,
    }
    map.map(scratch, out).map_err(FrameError::Decode)
}

/// Encode an RGB buffer as YUYV (BT.601 limited range); the inverse of
/// [`decode_yuyv`] up to rounding and chroma subsampling. Used to make
/// synthetic capture buffers for tests and benchmarks.
pub fn encode_yuyv(rgb: &[u8], width: u32, height: u32) -> Vec<u8> {
    let (w, h) = (width as usize, height as usize);
    let mut out = Vec::with_capacity(w * h * 2);
    let yuv = |p: &[u8]| {
        let (r, g, b) = (p[0] as f32, p[1] as f32, p[2] as f32);
        let y = 16.0 + 0.257 * r + 0.504 * g + 0.098 * b;
        let u = 128.0 - 0.148 * r - 0.291 * g + 0.439 * b;
        let v = 128.0 + 0.439 * r - 0.368 * g - 0.071 * b;
        (y, u, v)
    };
    for px in rgb.chunks_exact(6).take(w * h / 2) {
        let (y0, u0, v0) = yuv(&px[..3]);
        let (y1, u1, v1) = yuv(&px[3..]);
        let q = |x: f32| x.round().clamp(0.0, 255.0) as u8;
        out.extend_from_slice(&[q(y0), q((u0 + u1) / 2.0), q(y1), q((v0 + v1) / 2.0)]);
    }
    out
}
