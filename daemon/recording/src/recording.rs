//! The on-disk press format (shared with real capture) and the PyTouch layout.
//!
//! A press is a directory:
//! ```text
//! <dir>/press.json     metadata (format, version, textile, person, sensor, jig,
//!                      fps, timestamps_us, seed, source, params, frame names)
//! <dir>/000000.png     frame 0, RGB 8-bit, 240 wide x 320 tall
//! <dir>/000001.png     ...
//! ```
//! The frames may also be a camera's own images (another size, landscape)
//! when `sensor_profile` (and, for a camera its profile does not scale,
//! `mm_per_px`) say what they are: read back, every frame is mapped to the
//! 240x320 frame at its scale ([`crate::resample::FrameMap`]).
//! Writes are atomic: everything goes to `<dir>.tmp-<pid>-<n>` first, which
//! is renamed to `<dir>` when complete.
//!
//! Others' data is read in the PyTouch layout
//! `<root>/<class>/<serial>/<frame>.png` (or `.jpg`; or `<root>/<class>/
//! <frame>.png` with no serial level): one sequence per class and sensor,
//! frames in name order ([`find_recordings`]).

use crate::profile::SensorProfile;
use crate::resample::FrameMap;
use crate::{Press, PressMeta, HEIGHT, WIDTH};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Value of the `format` field in press.json.
pub const FORMAT: &str = "telextiles-press";
/// Current format version.
pub const FORMAT_VERSION: u32 = 1;
/// File name of the metadata.
pub const META_FILE: &str = "press.json";

/// Errors reading or writing presses; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: {msg}", path.display())]
    Invalid { path: PathBuf, msg: String },
}

impl RecordingError {
    /// The file or directory the error is about.
    pub fn path(&self) -> &Path {
        match self {
            RecordingError::Io { path, .. } | RecordingError::Invalid { path, .. } => path,
        }
    }
}

fn io_err(path: &Path) -> impl FnOnce(std::io::Error) -> RecordingError + '_ {
    move |source| RecordingError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn invalid(path: &Path, msg: impl Into<String>) -> RecordingError {
    RecordingError::Invalid {
        path: path.to_path_buf(),
        msg: msg.into(),
    }
}

#[derive(Serialize, Deserialize)]
struct PressFile {
    format: String,
    format_version: u32,
    width: u32,
    height: u32,
    frames: Vec<String>,
    #[serde(flatten)]
    meta: PressMeta,
}

/// Name of frame `i`.
pub fn frame_name(i: usize) -> String {
    format!("{i:06}.png")
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// Write a press to `dir` (which must not exist yet), atomically.
pub fn write_press(dir: &Path, press: &Press) -> Result<(), RecordingError> {
    if press.frames.len() != press.meta.timestamps_us.len() {
        return Err(invalid(
            dir,
            format!(
                "{} frames but {} timestamps",
                press.frames.len(),
                press.meta.timestamps_us.len()
            ),
        ));
    }
    let (fw, fh) = press
        .frames
        .first()
        .map_or((WIDTH, HEIGHT), |f| (f.width(), f.height()));
    let mut w = PressWriter::create_sized(dir, fw, fh)?;
    for f in &press.frames {
        w.push(f)?;
    }
    w.finish(&press.meta)
}

/// A press written frame by frame, for footage too long to hold in memory
/// (`telextilesd record --idle`): frames go to a temporary directory as
/// they come, and [`PressWriter::finish`] writes `press.json` and renames
/// it to the press's directory. Dropped unfinished (an error, Ctrl-C), the
/// temporary directory is removed: a press is there whole or not at all.
pub struct PressWriter {
    dir: PathBuf,
    tmp: PathBuf,
    names: Vec<String>,
    done: bool,
    /// Size of every frame.
    size: (u32, u32),
}

impl PressWriter {
    /// Start writing the press `dir` (which must not exist yet) of
    /// 240x320 frames.
    pub fn create(dir: &Path) -> Result<PressWriter, RecordingError> {
        PressWriter::create_sized(dir, WIDTH, HEIGHT)
    }

    /// [`PressWriter::create`] for frames of another size: a camera's own
    /// images, which the metadata's `sensor_profile` (and `mm_per_px`)
    /// must say how to map (checked by [`PressWriter::finish`]).
    pub fn create_sized(
        dir: &Path,
        width: u32,
        height: u32,
    ) -> Result<PressWriter, RecordingError> {
        if dir.exists() {
            return Err(invalid(dir, "already exists; refusing to overwrite"));
        }
        let name = dir
            .file_name()
            .ok_or_else(|| invalid(dir, "not a directory name"))?
            .to_string_lossy()
            .into_owned();
        let parent = match dir.parent() {
            Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(io_err(&parent))?;
        let tmp = parent.join(format!(
            "{name}.tmp-{}-{}",
            std::process::id(),
            TMP_COUNTER.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::create_dir(&tmp).map_err(io_err(&tmp))?;
        Ok(PressWriter {
            dir: dir.to_path_buf(),
            tmp,
            names: Vec::new(),
            done: false,
            size: (width, height),
        })
    }

    /// Frames written so far.
    pub fn len(&self) -> usize {
        self.names.len()
    }

    /// Whether no frame has been written.
    pub fn is_empty(&self) -> bool {
        self.names.is_empty()
    }

    /// Write the next frame (240 wide x 320 tall, or the size it was
    /// created for).
    pub fn push(&mut self, f: &image::RgbImage) -> Result<(), RecordingError> {
        let i = self.names.len();
        let (w, h) = self.size;
        if (f.width(), f.height()) != (w, h) {
            return Err(invalid(
                &self.dir,
                format!(
                    "frame {i} is {}x{}, expected {w}x{h}",
                    f.width(),
                    f.height()
                ),
            ));
        }
        let n = frame_name(i);
        let p = self.tmp.join(&n);
        f.save_with_format(&p, image::ImageFormat::Png)
            .map_err(|e| invalid(&p, format!("cannot write PNG: {e}")))?;
        self.names.push(n);
        Ok(())
    }

    /// Write `press.json` with `meta` (one timestamp per frame written) and
    /// put the press in place.
    pub fn finish(mut self, meta: &PressMeta) -> Result<(), RecordingError> {
        if meta.timestamps_us.len() != self.names.len() {
            return Err(invalid(
                &self.dir,
                format!(
                    "{} frames but {} timestamps",
                    self.names.len(),
                    meta.timestamps_us.len()
                ),
            ));
        }
        let (width, height) = self.size;
        frame_map(meta, width, height).map_err(|e| invalid(&self.dir, e))?;
        let file = PressFile {
            format: FORMAT.into(),
            format_version: FORMAT_VERSION,
            width,
            height,
            frames: std::mem::take(&mut self.names),
            meta: meta.clone(),
        };
        let p = self.tmp.join(META_FILE);
        let json = serde_json::to_vec_pretty(&file).map_err(|e| invalid(&p, e.to_string()))?;
        std::fs::write(&p, json).map_err(io_err(&p))?;
        std::fs::rename(&self.tmp, &self.dir).map_err(io_err(&self.dir))?;
        self.done = true;
        Ok(())
    }
}

impl Drop for PressWriter {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_dir_all(&self.tmp);
        }
    }
}

/// Every press directory (one holding `press.json`) at or under `root`,
/// in sorted path order. Symbolic links to directories are followed (each
/// directory is read once, so link loops end); unfinished writes
/// (`<name>.tmp-<pid>-<n>`) and hidden directories (`.git`) are not
/// searched.
pub fn find_presses(root: &Path) -> Result<Vec<PathBuf>, RecordingError> {
    fn walk(
        dir: &Path,
        depth: u32,
        seen: &mut std::collections::HashSet<PathBuf>,
        out: &mut Vec<PathBuf>,
    ) -> Result<(), RecordingError> {
        // A directory reached twice (through links) is read once.
        if !seen.insert(std::fs::canonicalize(dir).map_err(io_err(dir))?) {
            return Ok(());
        }
        if dir.join(META_FILE).is_file() {
            out.push(dir.to_path_buf());
            return Ok(());
        }
        if depth == 0 {
            return Ok(());
        }
        for p in sorted_dir(dir)? {
            let name = p.file_name().unwrap_or_default().to_string_lossy();
            if p.is_dir() && !name.contains(".tmp-") {
                walk(&p, depth - 1, seen, out)?;
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(root, 32, &mut Default::default(), &mut out)?;
    Ok(out)
}

/// Read only the metadata of a press directory.
pub fn read_meta(dir: &Path) -> Result<PressMeta, RecordingError> {
    Ok(read_file(dir)?.meta)
}

fn read_file(dir: &Path) -> Result<PressFile, RecordingError> {
    let p = dir.join(META_FILE);
    let bytes = std::fs::read(&p).map_err(io_err(&p))?;
    let file: PressFile = serde_json::from_slice(&bytes)
        .map_err(|e| invalid(&p, format!("malformed metadata: {e}")))?;
    if file.format != FORMAT {
        return Err(invalid(
            &p,
            format!("format is {:?}, expected {FORMAT:?}", file.format),
        ));
    }
    if file.format_version != FORMAT_VERSION {
        return Err(invalid(
            &p,
            format!(
                "format_version {} not supported (this build reads {FORMAT_VERSION})",
                file.format_version
            ),
        ));
    }
    frame_map(&file.meta, file.width, file.height).map_err(|e| invalid(&p, e))?;
    if file.frames.len() != file.meta.timestamps_us.len() {
        return Err(invalid(
            &p,
            format!(
                "{} frames but {} timestamps",
                file.frames.len(),
                file.meta.timestamps_us.len()
            ),
        ));
    }
    if !(file.meta.fps.is_finite() && file.meta.fps > 0.0) {
        return Err(invalid(
            &p,
            format!("fps {} is not positive", file.meta.fps),
        ));
    }
    if let Some(i) = file.meta.timestamps_us.windows(2).position(|w| w[1] < w[0]) {
        return Err(invalid(
            &p,
            format!(
                "timestamps go backwards at frame {} ({} us after {} us)",
                i + 1,
                file.meta.timestamps_us[i + 1],
                file.meta.timestamps_us[i]
            ),
        ));
    }
    if let Some(k) = file.meta.reference_frames {
        if k as usize > file.frames.len() {
            return Err(invalid(
                &p,
                format!(
                    "reference_frames {k} but the press has only {} frames",
                    file.frames.len()
                ),
            ));
        }
    }
    for n in &file.frames {
        if n.is_empty() || n.contains('/') || n.contains('\\') || n == ".." || n == "." {
            return Err(invalid(
                &p,
                format!("frame name {n:?} is not a plain file name"),
            ));
        }
    }
    Ok(file)
}

/// Decode one frame file of a recording, checking it is a 240x320 RGB
/// 8-bit PNG (what `telextilesd record` writes, read back bit-exact).
pub fn read_frame(path: &Path) -> Result<image::RgbImage, RecordingError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| invalid(path, format!("corrupt PNG: {e}")))?;
    checked_frame(path, img)
}

/// How a press's stored frames of `width` x `height` map to the frame: by
/// its profile (a DIGIT when none is recorded) and its `mm_per_px`.
pub fn frame_map(meta: &PressMeta, width: u32, height: u32) -> Result<FrameMap, String> {
    let profile = meta.profile()?;
    FrameMap::for_profile(profile, width, height, meta.mm_per_px)
        .map_err(|e| format!("frames of {width}x{height} ({} profile): {e}", profile.name))
}

/// Decode one frame file of a press directory (a PNG of the size its
/// press.json gives) and map it to the 240x320 frame with `map`.
pub fn read_frame_as(path: &Path, map: &mut FrameMap) -> Result<image::RgbImage, RecordingError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let img = image::load_from_memory_with_format(&bytes, image::ImageFormat::Png)
        .map_err(|e| invalid(path, format!("corrupt PNG: {e}")))?;
    let img = match img {
        image::DynamicImage::ImageRgb8(i) => i,
        other => {
            return Err(invalid(
                path,
                format!("expected 8-bit RGB, found {:?}", other.color()),
            ))
        }
    };
    let (w, h) = map.size();
    if (img.width(), img.height()) != (w, h) {
        return Err(invalid(
            path,
            format!(
                "frame is {}x{}, press.json says {w}x{h}",
                img.width(),
                img.height()
            ),
        ));
    }
    if (w, h) == (WIDTH, HEIGHT) && map.valid() == crate::resample::Rect::FULL && !map.turns() {
        // Already the frame (what `record` writes): as it is, bit-exact.
        return Ok(img);
    }
    let mut out = image::RgbImage::new(WIDTH, HEIGHT);
    map.map(img.as_raw(), &mut out)
        .map_err(|e| invalid(path, e))?;
    Ok(out)
}

/// Whether a file name is a frame image others' tools save: `.png`,
/// `.jpg` or `.jpeg`, any case.
fn is_frame_image(path: &Path) -> bool {
    path.extension().is_some_and(|e| {
        ["png", "jpg", "jpeg"]
            .iter()
            .any(|x| e.eq_ignore_ascii_case(x))
    })
}

/// Decode a frame saved by another tool (a PyTouch-style dataset, a
/// no-contact frame given with `--reference`): PNG or JPEG, told apart by
/// the content, not the name (many datasets store DIGIT frames as JPEG).
/// It must be an RGB 8-bit image of a size [`to_frame`] maps to the
/// 240x320 portrait frame (VGA, or the camera's landscape orientation),
/// mapped as the live DIGIT source maps the camera's stream.
pub fn read_image(path: &Path) -> Result<image::RgbImage, RecordingError> {
    read_image_as(
        path,
        Sensor {
            profile: &crate::profile::DIGIT,
            mm_per_px: None,
        },
    )
}

/// A frame image saved by another tool, as it is: PNG or JPEG (told
/// apart by the content), 8-bit RGB.
fn read_other_image(path: &Path) -> Result<image::RgbImage, RecordingError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    let format = match image::guess_format(&bytes) {
        Ok(f @ (image::ImageFormat::Png | image::ImageFormat::Jpeg)) => f,
        Ok(other) => {
            return Err(invalid(
                path,
                format!("a {other:?} image; expected PNG or JPEG"),
            ))
        }
        Err(_) => return Err(invalid(path, "neither a PNG nor a JPEG image")),
    };
    let img = image::load_from_memory_with_format(&bytes, format)
        .map_err(|e| invalid(path, format!("corrupt {format:?}: {e}")))?;
    match img {
        image::DynamicImage::ImageRgb8(i) => Ok(i),
        other => Err(invalid(
            path,
            format!("expected 8-bit RGB, found {:?}", other.color()),
        )),
    }
}

/// [`read_image`] for an image from `sensor`: mapped to the frame by its
/// profile and scale.
pub fn read_image_as(path: &Path, sensor: Sensor) -> Result<image::RgbImage, RecordingError> {
    let img = read_other_image(path)?;
    let mut map = sensor_map(sensor, img.width(), img.height()).map_err(|e| invalid(path, e))?;
    let mut out = image::RgbImage::new(WIDTH, HEIGHT);
    map.map(img.as_raw(), &mut out)
        .map_err(|e| invalid(path, e))?;
    Ok(out)
}

/// The map of `sensor`'s images of `width` x `height`: a DIGIT at its own
/// scale takes only its own sizes ([`FrameMap::digit`]).
pub fn sensor_map(sensor: Sensor, width: u32, height: u32) -> Result<FrameMap, String> {
    if sensor.profile.name == crate::profile::DIGIT.name && sensor.mm_per_px.is_none() {
        return FrameMap::digit(width, height);
    }
    FrameMap::for_profile(sensor.profile, width, height, sensor.mm_per_px)
}

/// The frame rate of `profile`'s images of `width` x `height` saved
/// without timestamps: its first mode of that size (either orientation),
/// else the DIGIT's rule ([`default_fps`]).
pub fn sensor_fps(profile: &SensorProfile, width: u32, height: u32) -> f32 {
    let (long, short) = (width.max(height), width.min(height));
    profile
        .modes
        .iter()
        .find(|m| (m.width.max(m.height), m.width.min(m.height)) == (long, short))
        .map_or_else(|| default_fps(width, height), |m| m.fps)
}

/// The frame rate of a sequence saved without timestamps, by the size its
/// frames were saved at: the DIGIT's own stream rate at that resolution
/// (digit-interface's defaults: QVGA, 240x320 or 320x240, at 60 fps; VGA,
/// 480x640 or 640x480, at 30 fps, the most the DIGIT streams VGA at).
pub fn default_fps(width: u32, height: u32) -> f32 {
    if width.max(height) >= 640 {
        30.0
    } else {
        crate::FPS
    }
}

/// Fastest frame rate `--fps` takes: far above any DIGIT mode (60 fps at
/// most): it refuses only a slip, such as a period in µs (16667).
pub const MAX_FPS: f32 = 1000.0;

/// Parse a frame rate given for recordings that carry no timestamps
/// (`--fps`): a number of frames per second above 0 and at most
/// [`MAX_FPS`].
pub fn parse_fps(s: &str) -> Result<f32, String> {
    let fps: f32 = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a frame rate (frames per second, e.g. 30)"))?;
    check_fps(fps)
}

/// A frame rate given as a number (a configuration file's): above 0 and
/// at most [`MAX_FPS`], as [`parse_fps`] takes it.
pub fn check_fps(fps: f32) -> Result<f32, String> {
    if !(fps.is_finite() && fps > 0.0 && fps <= MAX_FPS) {
        return Err(format!(
            "frame rate {fps} out of range (above 0 and at most {MAX_FPS} frames per second)"
        ));
    }
    Ok(fps)
}

/// Maps an RGB image from the DIGIT's camera, as it streams or as a tool
/// saved it, to the 240x320 portrait frame, into `out`: the DIGIT's
/// [`FrameMap`](crate::resample::FrameMap) (landscape QVGA turned 90
/// degrees counter-clockwise as digit-interface turns it, portrait taken as
/// it is, VGA averaged over 2x2 blocks). Any other size is an error naming
/// the sizes that map. Per-frame callers keep a `FrameMap`; this builds
/// one per call.
pub fn to_frame(
    rgb: &[u8],
    width: u32,
    height: u32,
    out: &mut image::RgbImage,
) -> Result<(), String> {
    crate::resample::FrameMap::digit(width, height)?.map(rgb, out)
}

fn checked_frame(path: &Path, img: image::DynamicImage) -> Result<image::RgbImage, RecordingError> {
    let img = match img {
        image::DynamicImage::ImageRgb8(i) => i,
        other => {
            return Err(invalid(
                path,
                format!("expected 8-bit RGB, found {:?}", other.color()),
            ));
        }
    };
    if img.width() != WIDTH || img.height() != HEIGHT {
        // The DIGIT's camera streams landscape; digit-interface turns it.
        let hint = if img.width() > img.height() {
            " (portrait, as digit-interface returns it: turn landscape camera frames 90 degrees counter-clockwise)"
        } else {
            ""
        };
        return Err(invalid(
            path,
            format!(
                "frame is {}x{}, expected {WIDTH}x{HEIGHT}{hint}",
                img.width(),
                img.height()
            ),
        ));
    }
    Ok(img)
}

/// Read a press directory back (bit-exact).
pub fn read_press(dir: &Path) -> Result<Press, RecordingError> {
    let file = read_file(dir)?;
    let mut map = frame_map(&file.meta, file.width, file.height).map_err(|e| invalid(dir, e))?;
    let frames = file
        .frames
        .iter()
        .map(|n| read_frame_as(&dir.join(n), &mut map))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Press {
        meta: file.meta,
        frames,
    })
}

/// One sequence of a PyTouch-style dataset: a `<class>/<serial>`
/// directory, or the frames directly under `<class>` (`serial` empty).
#[derive(Clone, Debug, PartialEq)]
pub struct PytouchEntry {
    pub class: String,
    /// The sensor's serial (the directory's name), empty when not named.
    pub serial: String,
    /// Frame files, in [`frame_order`].
    pub files: Vec<PathBuf>,
}

/// The entries of a directory the walkers read, sorted by path. Hidden
/// entries (a name starting with `.`) are left out: `.git`,
/// `.ipynb_checkpoints` (a notebook's copies, which would read as one more
/// sensor) and the `._0001.png` files a Mac leaves beside each frame
/// copied to another file system (not PNGs at all) are never recordings.
fn sorted_dir(path: &Path) -> Result<Vec<PathBuf>, RecordingError> {
    let mut v = Vec::new();
    for e in std::fs::read_dir(path).map_err(io_err(path))? {
        let e = e.map_err(io_err(path))?;
        if !e.file_name().as_encoded_bytes().starts_with(b".") {
            v.push(e.path());
        }
    }
    v.sort();
    Ok(v)
}

/// The order of a sequence's frame files: by name, with each run of digits
/// compared as a number, so that `frame_2.png` comes before
/// `frame_10.png` (many tools number frames without zero padding, and a
/// plain sort would scramble the press). Zero-padded names keep their
/// plain order; equal numbers fall back to the plain name order.
pub fn frame_order(a: &str, b: &str) -> std::cmp::Ordering {
    use std::cmp::Ordering;
    let (mut x, mut y) = (a.as_bytes(), b.as_bytes());
    loop {
        match (x.first(), y.first()) {
            (None, None) => return a.cmp(b),
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(p), Some(q)) if p.is_ascii_digit() && q.is_ascii_digit() => {
                let dx = x.iter().take_while(|c| c.is_ascii_digit()).count();
                let dy = y.iter().take_while(|c| c.is_ascii_digit()).count();
                let (nx, ny) = (&x[..dx], &y[..dy]);
                // Compare as numbers of any length: without leading zeros,
                // the longer is larger, else digit by digit.
                let strip = |n: &[u8]| -> usize { n.iter().take_while(|&&c| c == b'0').count() };
                let (sx, sy) = (&nx[strip(nx)..], &ny[strip(ny)..]);
                let o = sx.len().cmp(&sy.len()).then_with(|| sx.cmp(sy));
                if o != Ordering::Equal {
                    return o;
                }
                x = &x[dx..];
                y = &y[dy..];
            }
            (Some(p), Some(q)) => {
                if p != q {
                    return p.cmp(q);
                }
                x = &x[1..];
                y = &y[1..];
            }
        }
    }
}

/// List a PyTouch layout `root/<class>/<serial>/*.{png,jpg}` without
/// decoding: the frames of a sequence are its PNG and JPEG files, in
/// [`frame_order`] (numbers in names compared as numbers). Frames directly
/// under a class directory (the image-folder layout `root/<class>/*.png`,
/// with no serial level) are the class's one sequence, from a sensor not
/// named (`serial` empty). A class directory holding both frames and
/// sensor directories with frames is refused, naming both: read as two
/// layouts at once, a stray image (a preview, a photo of the fabric)
/// would be taken for a press of that class.
pub fn pytouch_index(root: &Path) -> Result<Vec<PytouchEntry>, RecordingError> {
    let out = pytouch_entries(root)?;
    if out.is_empty() {
        return Err(invalid(
            root,
            "no <class>/<serial>/*.png or <class>/*.png (or .jpg) frames found (PyTouch layout)",
        ));
    }
    Ok(out)
}

/// [`pytouch_index`], empty where no frames are found.
fn pytouch_entries(root: &Path) -> Result<Vec<PytouchEntry>, RecordingError> {
    let name = |p: &Path| {
        p.file_name()
            .unwrap_or_default()
            .to_string_lossy()
            .into_owned()
    };
    let frames = |dir: &Path| -> Result<Vec<PathBuf>, RecordingError> {
        let mut files: Vec<PathBuf> = sorted_dir(dir)?
            .into_iter()
            .filter(|p| p.is_file() && is_frame_image(p))
            .collect();
        files.sort_by(|a, b| frame_order(&name(a), &name(b)));
        Ok(files)
    };
    let mut out = Vec::new();
    for class_dir in sorted_dir(root)? {
        if !class_dir.is_dir() {
            continue;
        }
        let class = name(&class_dir);
        let own = frames(&class_dir)?;
        let mut serials = Vec::new();
        for serial_dir in sorted_dir(&class_dir)? {
            if !serial_dir.is_dir() {
                continue;
            }
            let files = frames(&serial_dir)?;
            if !files.is_empty() {
                serials.push(PytouchEntry {
                    class: class.clone(),
                    serial: name(&serial_dir),
                    files,
                });
            }
        }
        if !own.is_empty() && !serials.is_empty() {
            let listed = |names: Vec<String>| {
                let n = names.len();
                let mut s = names.into_iter().take(3).collect::<Vec<_>>().join(", ");
                if n > 3 {
                    s.push_str(&format!(" and {} more", n - 3));
                }
                s
            };
            return Err(invalid(
                &class_dir,
                format!(
                    "holds both frames ({}) and sensor directories with frames ({}): a class directory is one sequence (<class>/*.png) or one per sensor (<class>/<serial>/*.png), not both; move what is not a recording out of it",
                    listed(own.iter().map(|p| name(p)).collect()),
                    listed(serials.iter().map(|e| format!("{}/", e.serial)).collect()),
                ),
            ));
        }
        if !own.is_empty() {
            out.push(PytouchEntry {
                class: class.clone(),
                serial: String::new(),
                files: own,
            });
        }
        out.extend(serials);
    }
    Ok(out)
}

/// Read a PyTouch layout: one `Press` per `<class>/<serial>` directory, with
/// the class as textile id, the serial as sensor serial, timestamps at the
/// DIGIT's stream rate for the frames' size ([`default_fps`]).
pub fn read_pytouch(root: &Path) -> Result<Vec<Press>, RecordingError> {
    find_recordings_pytouch(root)?
        .iter()
        .map(Recording::load)
        .collect()
}

/// A recording on disk, not loaded yet: a press directory, or one
/// `<class>/<serial>` sequence of a PyTouch-style dataset.
#[derive(Clone, Debug, PartialEq)]
pub enum Recording {
    /// A press directory (with press.json).
    Press(PathBuf),
    /// A PyTouch sequence, the number of its serial among the dataset's
    /// serials in sorted order (its sensor unit), and the frame rate it
    /// was given ([`Recording::assume_fps`]; None: by its frames' size,
    /// [`default_fps`]).
    ///
    /// Its sensor: the profile (and scale) it was given
    /// ([`Recording::assume_sensor`]; None: a DIGIT).
    Pytouch {
        entry: PytouchEntry,
        unit: u32,
        fps: Option<f32>,
        sensor: Option<Sensor>,
    },
}

/// A sensor profile, and the millimetres per pixel of its images when its
/// owner gives them (else the profile's own).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sensor {
    /// The profile.
    pub profile: &'static SensorProfile,
    /// Millimetres per pixel of its images, if given.
    pub mm_per_px: Option<f32>,
}

impl Recording {
    /// Its directory.
    pub fn path(&self) -> PathBuf {
        match self {
            Recording::Press(p) => p.clone(),
            Recording::Pytouch { entry, .. } => entry
                .files
                .first()
                .and_then(|f| f.parent())
                .map(Path::to_path_buf)
                .unwrap_or_default(),
        }
    }

    /// Give a PyTouch sequence its frame rate (its files carry no
    /// timestamps). A press directory has its own timestamps: refused.
    pub fn assume_fps(&mut self, fps: f32) -> Result<(), RecordingError> {
        match self {
            Recording::Press(p) => Err(invalid(
                p,
                "a press directory: its press.json gives its timestamps, so a frame rate given for recordings without them (--fps) does not apply",
            )),
            Recording::Pytouch { fps: f, .. } => {
                *f = Some(fps);
                Ok(())
            }
        }
    }

    /// The profile of the sensor that made it: its press.json's (a DIGIT
    /// when it names none), or the one a PyTouch sequence was given.
    pub fn profile(&self) -> Result<&'static SensorProfile, RecordingError> {
        match self {
            Recording::Press(p) => read_meta(p)?.profile().map_err(|e| invalid(p, e)),
            Recording::Pytouch { sensor, .. } => {
                Ok(sensor.map_or(&crate::profile::DIGIT, |s| s.profile))
            }
        }
    }

    /// Say which sensor made it: a PyTouch sequence's images are mapped
    /// to the frame by `sensor`'s profile and scale, and its frame rate
    /// (unless given) is the profile's mode for its size. A press
    /// directory's press.json names its own sensor (a DIGIT when it names
    /// none): another is refused, naming both.
    pub fn assume_sensor(&mut self, sensor: Sensor) -> Result<(), RecordingError> {
        match self {
            Recording::Press(p) => {
                let meta = read_meta(p)?;
                let own = meta.profile().map_err(|e| invalid(p, e))?;
                if own.name != sensor.profile.name
                    || sensor.mm_per_px.is_some_and(|s| Some(s) != meta.mm_per_px)
                {
                    return Err(invalid(
                        p,
                        format!(
                            "its press.json says it was made by a {} ({}), not the {} given ({}); set sensor_profile (and mm_per_px) in its press.json, or give no sensor profile for recordings that name their own",
                            own.label,
                            meta.mm_per_px.map_or("at its own scale".into(), |s| format!("{s} mm per pixel")),
                            sensor.profile.label,
                            sensor.mm_per_px.map_or("at its own scale".into(), |s| format!("{s} mm per pixel")),
                        ),
                    ));
                }
                Ok(())
            }
            Recording::Pytouch { sensor: s, .. } => {
                *s = Some(sensor);
                Ok(())
            }
        }
    }

    /// Load its frames. A PyTouch sequence has no no-contact reference and
    /// no timestamps: its frames are spaced at the rate it was given
    /// ([`Recording::assume_fps`]), else at the DIGIT's stream rate for
    /// the size they were saved at ([`default_fps`]).
    pub fn load(&self) -> Result<Press, RecordingError> {
        match self {
            Recording::Press(p) => read_press(p),
            Recording::Pytouch {
                entry,
                unit,
                fps,
                sensor,
            } => {
                let sensor = sensor.unwrap_or(Sensor {
                    profile: &crate::profile::DIGIT,
                    mm_per_px: None,
                });
                let mut size = None;
                let mut map: Option<FrameMap> = None;
                let frames = entry
                    .files
                    .iter()
                    .map(|f| {
                        let img = read_other_image(f)?;
                        let s = (img.width(), img.height());
                        size.get_or_insert(s);
                        if map.as_ref().is_none_or(|m| m.size() != s) {
                            map = Some(sensor_map(sensor, s.0, s.1).map_err(|e| invalid(f, e))?);
                        }
                        let mut out = image::RgbImage::new(WIDTH, HEIGHT);
                        if let Some(m) = map.as_mut() {
                            m.map(img.as_raw(), &mut out).map_err(|e| invalid(f, e))?;
                        }
                        Ok(out)
                    })
                    .collect::<Result<Vec<_>, RecordingError>>()?;
                let fps = fps.unwrap_or_else(|| {
                    let (w, h) = size.unwrap_or((WIDTH, HEIGHT));
                    sensor_fps(sensor.profile, w, h)
                });
                let n = frames.len() as u64;
                Ok(Press {
                    meta: PressMeta {
                        textile: entry.class.clone(),
                        person: 0,
                        sensor: *unit,
                        jig: false,
                        fps,
                        timestamps_us: (0..n)
                            .map(|i| (i as f64 * 1e6 / fps as f64).round() as u64)
                            .collect(),
                        seed: None,
                        source: "pytouch".into(),
                        sensor_serial: (!entry.serial.is_empty()).then(|| entry.serial.clone()),
                        params: None,
                        reference_frames: None,
                        sensor_profile: crate::profile_tag(sensor.profile),
                        mm_per_px: sensor.mm_per_px,
                    },
                    frames,
                })
            }
        }
    }
}

/// The recordings under `root`: every press directory at any depth
/// ([`find_presses`]), in sorted path order; where there is none, the
/// PyTouch layout `root/<class>/<serial>/*.png` (or `.jpg`).
pub fn find_recordings(root: &Path) -> Result<Vec<Recording>, RecordingError> {
    if !root.is_dir() {
        return Err(invalid(root, "not a directory"));
    }
    let mut dirs = find_presses(root)?;
    if !dirs.is_empty() {
        dirs.sort();
        return Ok(dirs.into_iter().map(Recording::Press).collect());
    }
    let entries = pytouch_entries(root)?;
    if entries.is_empty() {
        return Err(invalid(
            root,
            "no press.json found below it, and not a PyTouch layout (<class>/<serial>/*.png, <class>/*.png, or .jpg) either",
        ));
    }
    Ok(recordings_of(entries))
}

fn find_recordings_pytouch(root: &Path) -> Result<Vec<Recording>, RecordingError> {
    let entries = pytouch_index(root)?;
    Ok(recordings_of(entries))
}

/// PyTouch sequences as recordings, each with its serial's number among the
/// dataset's serials in sorted order as its sensor unit.
fn recordings_of(entries: Vec<PytouchEntry>) -> Vec<Recording> {
    let mut serials: Vec<String> = entries.iter().map(|e| e.serial.clone()).collect();
    serials.sort();
    serials.dedup();
    entries
        .into_iter()
        .map(|entry| {
            let unit = serials.iter().position(|s| *s == entry.serial).unwrap_or(0) as u32;
            Recording::Pytouch {
                entry,
                unit,
                fps: None,
                sensor: None,
            }
        })
        .collect()
}

/// [`find_recordings`], with `fps` (when given) as the frame rate of
/// sequences saved without timestamps ([`Recording::assume_fps`]). A
/// frame rate given for press directories, which carry their own
/// timestamps, is refused rather than ignored.
pub fn find_recordings_at(root: &Path, fps: Option<f32>) -> Result<Vec<Recording>, RecordingError> {
    let mut recordings = find_recordings(root)?;
    assume_fps(&mut recordings, fps)?;
    Ok(recordings)
}

/// [`Recording::assume_fps`] for each of `recordings`, when a rate is
/// given; the first press directory among them refuses it.
pub fn assume_fps(recordings: &mut [Recording], fps: Option<f32>) -> Result<(), RecordingError> {
    if let Some(fps) = fps {
        for r in recordings {
            r.assume_fps(fps)?;
        }
    }
    Ok(())
}

/// [`Recording::assume_sensor`] for each of `recordings`, when a sensor
/// is given.
pub fn assume_sensor(
    recordings: &mut [Recording],
    sensor: Option<Sensor>,
) -> Result<(), RecordingError> {
    if let Some(sensor) = sensor {
        for r in recordings {
            r.assume_sensor(sensor)?;
        }
    }
    Ok(())
}

/// The profiles of `recordings`' sensors ([`Recording::profile`]), by
/// name, each with the first recording of it. A recording whose metadata
/// cannot be read (a profile it names unknown among them) is left to its
/// reader: a replay skips it, naming it; `index build` refuses it when it
/// loads it.
pub fn profiles(
    recordings: &[Recording],
) -> Result<std::collections::BTreeMap<&'static str, PathBuf>, RecordingError> {
    let mut out = std::collections::BTreeMap::new();
    for r in recordings {
        let profile = match r {
            Recording::Press(p) => match read_meta(p) {
                Ok(meta) => meta.profile().map_err(|e| invalid(p, e))?,
                Err(_) => continue,
            },
            other => other.profile()?,
        };
        out.entry(profile.name).or_insert_with(|| r.path());
    }
    Ok(out)
}
