//! Frames for training and evaluation: where they come from
//! ([`FrameSource`]: the simulator, recorded presses on disk, or the
//! synthetic source used by the tests) and the in-memory/on-disk caches of
//! preprocessed images ([`ImageSet`]).

use anyhow::{bail, ensure, Context, Result};
use image::RgbImage;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::io::{Read, Write};
use std::path::Path;

use telextiles_graphs::preprocess::{centre_crop_resize, FRAME_W};

/// One press: who pressed which textile, how.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct PressKey {
    /// Textile id, e.g. `T001` or `U07`.
    pub textile: String,
    /// Person 0..11.
    pub person: u32,
    /// DIGIT sensor id.
    pub sensor: u32,
    /// Pressed with the spring jig (true) or hand-held (false).
    pub jig: bool,
    /// Seed of the press (simulator) or a running number (recordings).
    pub seed: u64,
}

/// Something that yields DIGIT frames (240 wide x 320 tall RGB) of presses.
pub trait FrameSource: Sync {
    /// Short description for logs and the training-data hash.
    fn describe(&self) -> String;
    /// Number of frames in one press (150 for 2.5 s at 60 fps).
    fn frames_per_press(&self) -> usize;
    /// Render or load the given frames of one press.
    fn frames(&self, press: &PressKey, indices: &[usize]) -> Result<Vec<RgbImage>>;
    /// Frames `[start, end)` of the press during which the sensor is in full
    /// contact (after the ramp, before any release).
    fn contact_range(&self, _press: &PressKey) -> Result<(usize, usize)> {
        Ok((0, self.frames_per_press()))
    }
    /// Training textiles (ids), in class order.
    fn training_textiles(&self) -> Vec<String>;
    /// Unseen textiles (ids).
    fn unseen_textiles(&self) -> Vec<String>;
    /// Ground-truth tactile attributes of a textile, if known.
    fn attributes(&self, _textile: &str) -> Option<Vec<f32>> {
        None
    }
    /// The no-contact reference frame of a sensor (what background
    /// subtraction subtracts), if the source has one.
    fn background(&self, _sensor: u32) -> Result<Option<RgbImage>> {
        Ok(None)
    }
}

/// What an [`ImageSet`] holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum ImageKind {
    /// Centre 240x240 square of the frame at native resolution (for augmentation).
    Canvas,
    /// The deployment preprocessing (centre crop, resize) at network input size.
    Input,
}

/// Metadata of one cached frame.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FrameMeta {
    /// Index into [`ImageSet::classes`].
    pub class: u32,
    /// Index of the press in the set (frames of one press share it).
    pub press: u32,
    /// Person who pressed.
    pub person: u32,
    /// Sensor used.
    pub sensor: u32,
    /// With the jig.
    pub jig: bool,
    /// Frame index within the press.
    pub frame: u32,
}

/// Square RGB u8 images with labels, all the same side.
#[derive(Clone, Debug, PartialEq)]
pub struct ImageSet {
    /// What the images are.
    pub kind: ImageKind,
    /// Side of each image in pixels.
    pub side: usize,
    /// Deployment crop (px of the frame) the images were made for.
    pub crop: u32,
    /// Class names (textile ids); `FrameMeta::class` indexes this.
    pub classes: Vec<String>,
    /// Per-image metadata.
    pub items: Vec<FrameMeta>,
    /// `items.len() * side * side * 3` bytes, HWC per image.
    pub pixels: Vec<u8>,
    /// Description of where the frames came from.
    pub source: String,
}

#[derive(Serialize, Deserialize)]
struct Header {
    kind: ImageKind,
    side: usize,
    crop: u32,
    classes: Vec<String>,
    items: Vec<FrameMeta>,
    source: String,
}

const MAGIC: &[u8; 8] = b"TXLIMG1\n";

impl ImageSet {
    /// The same set's description and items, with no pixels yet.
    pub fn clone_meta(&self) -> ImageSet {
        ImageSet {
            kind: self.kind,
            side: self.side,
            crop: self.crop,
            classes: self.classes.clone(),
            items: self.items.clone(),
            pixels: Vec::new(),
            source: self.source.clone(),
        }
    }

    /// Bytes of one image.
    pub fn image(&self, i: usize) -> &[u8] {
        let n = self.side * self.side * 3;
        &self.pixels[i * n..(i + 1) * n]
    }

    /// Number of images.
    pub fn len(&self) -> usize {
        self.items.len()
    }

    /// A new set with the given images only.
    pub fn subset(&self, idx: &[usize]) -> ImageSet {
        let mut s = ImageSet {
            items: Vec::new(),
            pixels: Vec::new(),
            ..self.clone_empty()
        };
        for &i in idx {
            s.items.push(self.items[i].clone());
            s.pixels.extend_from_slice(self.image(i));
        }
        s
    }

    fn clone_empty(&self) -> ImageSet {
        ImageSet {
            kind: self.kind,
            side: self.side,
            crop: self.crop,
            classes: self.classes.clone(),
            items: Vec::new(),
            pixels: Vec::new(),
            source: self.source.clone(),
        }
    }

    /// True when there are no images.
    pub fn is_empty(&self) -> bool {
        self.items.is_empty()
    }

    /// Content hash (hex sha256 of header and pixels).
    pub fn hash(&self) -> String {
        let mut h = Sha256::new();
        h.update(self.header_bytes());
        h.update(&self.pixels);
        hex(&h.finalize())
    }

    fn header_bytes(&self) -> Vec<u8> {
        serde_json::to_vec(&Header {
            kind: self.kind,
            side: self.side,
            crop: self.crop,
            classes: self.classes.clone(),
            items: self.items.clone(),
            source: self.source.clone(),
        })
        .expect("header serialises")
    }

    /// Write atomically (temp file + rename).
    pub fn write(&self, path: &Path) -> Result<()> {
        let header = self.header_bytes();
        let mut buf = Vec::with_capacity(16 + header.len() + self.pixels.len());
        buf.extend_from_slice(MAGIC);
        buf.extend_from_slice(&(header.len() as u64).to_le_bytes());
        buf.extend_from_slice(&header);
        buf.extend_from_slice(&self.pixels);
        write_atomic(path, &buf)
    }

    /// Read a file written by [`ImageSet::write`].
    pub fn read(path: &Path) -> Result<ImageSet> {
        let mut f = std::fs::File::open(path)
            .with_context(|| format!("cannot open image cache {}", path.display()))?;
        let mut buf = Vec::new();
        f.read_to_end(&mut buf)?;
        ensure!(
            buf.len() >= 16 && &buf[..8] == MAGIC,
            "{} is not a telextiles-lab image cache",
            path.display()
        );
        let hlen = u64::from_le_bytes(buf[8..16].try_into().expect("an 8-byte slice")) as usize;
        ensure!(
            buf.len() >= 16 + hlen,
            "{}: truncated header",
            path.display()
        );
        let h: Header = serde_json::from_slice(&buf[16..16 + hlen])
            .with_context(|| format!("{}: corrupt header", path.display()))?;
        let pixels = buf[16 + hlen..].to_vec();
        ensure!(
            pixels.len() == h.items.len() * h.side * h.side * 3,
            "{}: {} pixel bytes for {} images of side {} (truncated?)",
            path.display(),
            pixels.len(),
            h.items.len(),
            h.side
        );
        ensure!(
            h.items.iter().all(|m| (m.class as usize) < h.classes.len()),
            "{}: class index out of range",
            path.display()
        );
        Ok(ImageSet {
            kind: h.kind,
            side: h.side,
            crop: h.crop,
            classes: h.classes,
            items: h.items,
            pixels,
            source: h.source,
        })
    }
}

/// Atomic file write: temp file in the same directory, fsync, rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let dir = path
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let tmp = dir.join(format!(
        ".{}.tmp{}",
        path.file_name().and_then(|n| n.to_str()).unwrap_or("out"),
        std::process::id()
    ));
    {
        let mut f = std::fs::File::create(&tmp)
            .with_context(|| format!("cannot create {}", tmp.display()))?;
        f.write_all(bytes)?;
        f.sync_all()?;
    }
    std::fs::rename(&tmp, path)
        .with_context(|| format!("cannot rename {} to {}", tmp.display(), path.display()))?;
    Ok(())
}

/// Lower-case hex.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// A press and the frame indices to take from it.
#[derive(Clone, Debug)]
pub struct PressPlan {
    /// The press.
    pub key: PressKey,
    /// Class index of its textile.
    pub class: u32,
    /// Frames to cache as augmentation canvases (training).
    pub canvas_frames: Vec<usize>,
    /// Frames to cache at network input size (evaluation).
    pub input_frames: Vec<usize>,
}

/// Convert one frame into a cached image of the given kind.
pub fn frame_to_image(frame: &RgbImage, kind: ImageKind, size: u32, crop: u32) -> Result<RgbImage> {
    match kind {
        ImageKind::Input => centre_crop_resize(frame, crop, size),
        ImageKind::Canvas => {
            let _ = (size, crop);
            centre_crop_resize(frame, FRAME_W, FRAME_W)
        }
    }
}

type Part = Vec<(usize, Vec<FrameMeta>, Vec<u8>, Vec<FrameMeta>, Vec<u8>)>;

/// Render/load the planned frames (in `threads` threads) into a canvas set and
/// an input set (either may be empty). `progress` gets (presses done, total).
#[allow(clippy::too_many_arguments)]
pub fn build_sets(
    source: &dyn FrameSource,
    classes: Vec<String>,
    plan: &[PressPlan],
    size: u32,
    crop: u32,
    threads: usize,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<(ImageSet, ImageSet)> {
    let threads = threads.max(1);
    let done = std::sync::atomic::AtomicUsize::new(0);
    let parts: Vec<Result<Part>> = std::thread::scope(|s| {
        let handles: Vec<_> = (0..threads)
            .map(|t| {
                let done = &done;
                s.spawn(move || -> Result<Part> {
                    let mut out = Vec::new();
                    for (pi, p) in plan.iter().enumerate().skip(t).step_by(threads) {
                        let mut all: Vec<usize> = p
                            .canvas_frames
                            .iter()
                            .chain(&p.input_frames)
                            .copied()
                            .collect();
                        all.sort_unstable();
                        all.dedup();
                        let frames = source
                            .frames(&p.key, &all)
                            .with_context(|| format!("rendering press {:?}", p.key))?;
                        ensure!(frames.len() == all.len(), "source returned too few frames");
                        let meta = |fi: usize| FrameMeta {
                            class: p.class,
                            press: pi as u32,
                            person: p.key.person,
                            sensor: p.key.sensor,
                            jig: p.key.jig,
                            frame: fi as u32,
                        };
                        let (mut cm, mut cp, mut im, mut ip) =
                            (Vec::new(), Vec::new(), Vec::new(), Vec::new());
                        for (img, &fi) in frames.iter().zip(&all) {
                            if p.canvas_frames.contains(&fi) {
                                cp.extend_from_slice(
                                    frame_to_image(img, ImageKind::Canvas, size, crop)?.as_raw(),
                                );
                                cm.push(meta(fi));
                            }
                            if p.input_frames.contains(&fi) {
                                ip.extend_from_slice(
                                    frame_to_image(img, ImageKind::Input, size, crop)?.as_raw(),
                                );
                                im.push(meta(fi));
                            }
                        }
                        out.push((pi, cm, cp, im, ip));
                        let d = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                        progress(d, plan.len());
                    }
                    Ok(out)
                })
            })
            .collect();
        handles
            .into_iter()
            .map(|h| h.join().expect("render thread panicked"))
            .collect()
    });
    let mut all: Part = Vec::new();
    for p in parts {
        all.extend(p?);
    }
    all.sort_by_key(|x| x.0);
    let mk = |kind: ImageKind, side: usize| ImageSet {
        kind,
        side,
        crop,
        classes: classes.clone(),
        items: Vec::new(),
        pixels: Vec::new(),
        source: source.describe(),
    };
    let mut canvas = mk(ImageKind::Canvas, crate::augment::CANVAS_SIDE as usize);
    let mut input = mk(ImageKind::Input, size as usize);
    for (_, cm, cp, im, ip) in all {
        canvas.items.extend(cm);
        canvas.pixels.extend(cp);
        input.items.extend(im);
        input.pixels.extend(ip);
    }
    if canvas.is_empty() && input.is_empty() {
        bail!("no frames planned");
    }
    Ok((canvas, input))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn image_set_round_trips_and_rejects_corruption() {
        let dir = tempfile::tempdir().unwrap();
        let set = ImageSet {
            kind: ImageKind::Input,
            side: 2,
            crop: 168,
            classes: vec!["T001".into(), "T002".into()],
            items: vec![
                FrameMeta {
                    class: 0,
                    press: 0,
                    person: 1,
                    sensor: 0,
                    jig: true,
                    frame: 3,
                },
                FrameMeta {
                    class: 1,
                    press: 1,
                    person: 2,
                    sensor: 0,
                    jig: false,
                    frame: 4,
                },
            ],
            pixels: (0..24).collect(),
            source: "test".into(),
        };
        let p = dir.path().join("s.bin");
        set.write(&p).unwrap();
        let back = ImageSet::read(&p).unwrap();
        assert_eq!(back, set);
        assert_eq!(back.image(1), &(12..24).collect::<Vec<u8>>()[..]);
        let bytes = std::fs::read(&p).unwrap();
        std::fs::write(&p, &bytes[..bytes.len() - 1]).unwrap();
        assert!(ImageSet::read(&p)
            .unwrap_err()
            .to_string()
            .contains("truncated"));
        std::fs::write(&p, b"garbage").unwrap();
        assert!(ImageSet::read(&p).is_err());
    }
}
