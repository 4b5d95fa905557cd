//! Texture images shown when a textile is hovered: a simulated DIGIT frame of
//! the textile (rendered on demand by `telextiles-sim`) or a recorded one from
//! a directory. Encoded to PNG once and cached per textile.

use bytes::Bytes;
use image::{ImageFormat, RgbImage};
use std::collections::HashMap;
use std::io::Cursor;
use std::path::{Path, PathBuf};
#[cfg(feature = "sim")]
use std::sync::OnceLock;
use std::sync::{Arc, Mutex};
#[cfg(feature = "sim")]
use telextiles_sim::{PressSpec, Simulator};
use tokio::sync::Semaphore;

/// Where texture images come from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TextureSource {
    /// Simulated DIGIT frames (textiles of the built-in catalogue only).
    Simulated,
    /// A directory holding, per textile id, `<id>.png` / `<id>.jpg` or a
    /// recorded press directory `<id>/` (the frame in the middle of the hold
    /// is shown).
    Directory(PathBuf),
    /// No images (the page shows the text only).
    None,
}

/// Largest image file read from a texture directory.
const MAX_FILE_BYTES: u64 = 8 << 20;

/// Renders, loads and caches texture PNGs.
pub(crate) struct Textures {
    source: TextureSource,
    #[cfg(feature = "sim")]
    sim: OnceLock<Result<Arc<Simulator>, String>>,
    cache: Mutex<HashMap<String, Result<Bytes, String>>>,
    /// One render or load at a time: a burst of hovers must not take every
    /// core from the daemon's sensing.
    gate: Semaphore,
}

impl Textures {
    pub(crate) fn new(source: TextureSource) -> Textures {
        Textures {
            source,
            #[cfg(feature = "sim")]
            sim: OnceLock::new(),
            cache: Mutex::new(HashMap::new()),
            gate: Semaphore::new(1),
        }
    }

    pub(crate) fn enabled(&self) -> bool {
        self.source != TextureSource::None
    }

    fn cached(&self, id: &str) -> Option<Result<Bytes, String>> {
        self.cache
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(id)
            .cloned()
    }

    /// PNG of textile `id` (which the caller checked is in the index), or why
    /// there is none.
    pub(crate) async fn png(self: &Arc<Self>, id: &str) -> Result<Bytes, String> {
        if let Some(r) = self.cached(id) {
            return r;
        }
        let _permit = self.gate.acquire().await.map_err(|e| e.to_string())?;
        if let Some(r) = self.cached(id) {
            return r;
        }
        let me = self.clone();
        let key = id.to_string();
        let r = tokio::task::spawn_blocking(move || me.produce(&key))
            .await
            .unwrap_or_else(|e| Err(format!("texture task failed: {e}")));
        self.cache
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .insert(id.to_string(), r.clone());
        r
    }

    fn produce(&self, id: &str) -> Result<Bytes, String> {
        let img = match &self.source {
            TextureSource::None => return Err("texture images are off".into()),
            TextureSource::Simulated => self.simulate(id)?,
            TextureSource::Directory(dir) => load_from_dir(dir, id)?,
        };
        encode_png(&img)
    }

    #[cfg(not(feature = "sim"))]
    fn simulate(&self, _id: &str) -> Result<RgbImage, String> {
        Err("this build has no simulator (feature `sim`), so no simulated texture images: give a texture directory".into())
    }

    #[cfg(feature = "sim")]
    fn simulate(&self, id: &str) -> Result<RgbImage, String> {
        let sim = self
            .sim
            .get_or_init(|| {
                Simulator::new()
                    .map(Arc::new)
                    .map_err(|e| format!("simulator: {e}"))
            })
            .clone()?;
        if sim.catalogue().get(id).is_none() {
            return Err(format!(
                "textile {id} is not in the simulator's catalogue, so there is no simulated image"
            ));
        }
        let mut spec = PressSpec::new(id, 0);
        spec.release = Some(false);
        let meta = sim.press_meta(&spec).map_err(|e| e.to_string())?;
        let frame = meta
            .params
            .map(|p| p.hold_frame as usize + 15)
            .unwrap_or(spec.frames / 2)
            .min(spec.frames.saturating_sub(1));
        sim.render_frame(&spec, frame).map_err(|e| e.to_string())
    }
}

/// A texture directory entry for `id`; ids that could leave the directory are
/// refused.
fn load_from_dir(dir: &Path, id: &str) -> Result<RgbImage, String> {
    if id.is_empty()
        || id.starts_with('.')
        || id.contains(['/', '\\', '\0'])
        || Path::new(id).components().count() != 1
    {
        return Err(format!(
            "textile id {id:?} cannot name a file in the texture directory"
        ));
    }
    for ext in ["png", "jpg", "jpeg"] {
        let p = dir.join(format!("{id}.{ext}"));
        if p.is_file() {
            return read_image(&p);
        }
    }
    let press = dir.join(id);
    if press.is_dir() {
        let meta = telextiles_recording::recording::read_meta(&press)
            .map_err(|e| format!("recorded press {}: {e}", press.display()))?;
        let n = meta.timestamps_us.len();
        if n == 0 {
            return Err(format!("recorded press {} has no frames", press.display()));
        }
        let i = meta
            .params
            .map(|p| p.hold_frame as usize + 15)
            .unwrap_or(n / 2)
            .min(n - 1);
        let f = press.join(telextiles_recording::recording::frame_name(i));
        return telextiles_recording::recording::read_frame(&f)
            .map_err(|e| format!("recorded frame {}: {e}", f.display()));
    }
    Err(format!(
        "no image for textile {id} in {} (looked for {id}.png, {id}.jpg, {id}.jpeg and {id}/)",
        dir.display()
    ))
}

fn read_image(p: &Path) -> Result<RgbImage, String> {
    let len = std::fs::metadata(p)
        .map_err(|e| format!("{}: {e}", p.display()))?
        .len();
    if len > MAX_FILE_BYTES {
        return Err(format!(
            "{}: {len} bytes is larger than the {MAX_FILE_BYTES}-byte limit for texture images",
            p.display()
        ));
    }
    let bytes = std::fs::read(p).map_err(|e| format!("{}: {e}", p.display()))?;
    let img = image::load_from_memory(&bytes).map_err(|e| format!("{}: {e}", p.display()))?;
    Ok(img.to_rgb8())
}

fn encode_png(img: &RgbImage) -> Result<Bytes, String> {
    let mut out = Cursor::new(Vec::new());
    img.write_to(&mut out, ImageFormat::Png)
        .map_err(|e| format!("PNG encoding: {e}"))?;
    Ok(Bytes::from(out.into_inner()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn directory_refuses_escaping_ids() {
        let dir = tempfile::tempdir().unwrap();
        for id in ["../etc/passwd", "..", ".hidden", "a/b", "a\\b", ""] {
            let e = load_from_dir(dir.path(), id).unwrap_err();
            assert!(e.contains("cannot name a file"), "{id}: {e}");
        }
    }

    #[test]
    fn directory_png_and_missing() {
        let dir = tempfile::tempdir().unwrap();
        let img = RgbImage::from_pixel(4, 6, image::Rgb([10, 20, 30]));
        img.save(dir.path().join("T001.png")).unwrap();
        let got = load_from_dir(dir.path(), "T001").unwrap();
        assert_eq!(got, img);
        let e = load_from_dir(dir.path(), "T002").unwrap_err();
        assert!(e.contains("no image for textile T002"), "{e}");
        std::fs::write(dir.path().join("T003.png"), b"not a png").unwrap();
        assert!(load_from_dir(dir.path(), "T003").is_err());
    }

    #[test]
    fn directory_recorded_press() {
        let sim = Simulator::new().unwrap();
        let mut spec = PressSpec::new("T005", 3);
        spec.frames = 40;
        let press = sim.render_press(&spec).unwrap();
        let dir = tempfile::tempdir().unwrap();
        telextiles_recording::recording::write_press(&dir.path().join("T005"), &press).unwrap();
        let got = load_from_dir(dir.path(), "T005").unwrap();
        assert_eq!((got.width(), got.height()), (240, 320));
        assert!(press.frames.contains(&got));
    }
}
