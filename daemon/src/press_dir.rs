//! A directory of presses as `record` and the live session's recording
//! write it: `<out>/<textile>/NNNN/` (the next free number, never over an
//! existing press), `textile.json` with the fabric's name, temporaries of
//! an interrupted run removed, and the writer thread that saves presses
//! while the sensor keeps streaming.

use std::path::{Path, PathBuf};
use std::sync::mpsc::{channel, Receiver, Sender};

use anyhow::{bail, Context, Result};
use telextiles_sensing::record::{PressSummary, RecordedPress};

pub(crate) fn check_id(id: &str) -> Result<()> {
    if id.is_empty()
        || id == "."
        || id == ".."
        || id.contains(['/', '\\'])
        || id.chars().any(|c| c.is_control())
    {
        bail!("textile id {id:?} cannot be a directory name: use letters, digits, - or _");
    }
    Ok(())
}

/// The next free press number in `dir` (1 when empty): one more than the
/// highest all-digit directory name.
pub fn next_number(dir: &Path) -> Result<u32> {
    let mut highest = 0u32;
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(1),
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", dir.display())),
    };
    for e in rd {
        let name = e?.file_name().to_string_lossy().into_owned();
        if !name.is_empty() && name.bytes().all(|b| b.is_ascii_digit()) {
            if let Ok(n) = name.parse::<u32>() {
                highest = highest.max(n);
            }
        }
    }
    Ok(highest + 1)
}

/// Remove the temporaries of writes interrupted by a crash or `kill -9`
/// (`NNNN.tmp-<pid>-<n>` whose process is gone); returns how many.
pub(crate) fn remove_stale_temporaries(dir: &Path) -> usize {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return 0;
    };
    let mut n = 0;
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some((_, rest)) = name.split_once(".tmp-") else {
            continue;
        };
        let pid = rest.split('-').next().unwrap_or("");
        let alive = pid
            .parse::<u32>()
            .is_ok_and(|p| p == std::process::id() || Path::new("/proc").join(pid).exists());
        if !alive && std::fs::remove_dir_all(e.path()).is_ok() {
            n += 1;
        }
    }
    n
}

/// What `textile.json` holds.
#[derive(serde::Serialize, serde::Deserialize, Debug, PartialEq)]
pub struct TextileInfo {
    /// The id (the directory name).
    pub id: String,
    /// Its human-readable name.
    pub name: String,
}

/// Write `<dir>/textile.json` atomically (temporary file, then rename).
pub(crate) fn write_textile_info(dir: &Path, info: &TextileInfo) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let path = dir.join("textile.json");
    let tmp = dir.join(format!(".textile.json.tmp-{}", std::process::id()));
    let json = serde_json::to_vec_pretty(info)?;
    std::fs::write(&tmp, json).with_context(|| format!("cannot write {}", tmp.display()))?;
    std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

/// Writes presses on a thread of its own, so that a live sensor keeps
/// streaming while PNGs are encoded.
pub(crate) struct Writer {
    tx: Option<Sender<(u32, Box<RecordedPress>)>>,
    done: Receiver<Result<(u32, PathBuf, PressSummary)>>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl Writer {
    pub(crate) fn new(dir: PathBuf, mut number: u32) -> Writer {
        let (tx, rx) = channel::<(u32, Box<RecordedPress>)>();
        let (dtx, done) = channel();
        let thread = std::thread::spawn(move || {
            for (k, p) in rx {
                // Another run writing into the same directory may take a
                // number first: write_press refuses, take the next one.
                let result = loop {
                    let path = dir.join(format!("{number:04}"));
                    number += 1;
                    if path.exists() {
                        continue;
                    }
                    match telextiles_recording::recording::write_press(&path, &p.press) {
                        Ok(()) => break Ok((k, path, p.summary.clone())),
                        Err(_) if path.exists() => continue,
                        Err(e) => break Err(anyhow::Error::new(e)),
                    }
                };
                if dtx.send(result).is_err() {
                    return;
                }
            }
        });
        Writer {
            tx: Some(tx),
            done,
            thread: Some(thread),
        }
    }

    pub(crate) fn submit(&self, k: u32, p: Box<RecordedPress>) {
        if let Some(tx) = &self.tx {
            let _ = tx.send((k, p));
        }
    }

    /// Results so far, without waiting.
    pub(crate) fn ready(&self) -> Vec<Result<(u32, PathBuf, PressSummary)>> {
        self.done.try_iter().collect()
    }

    /// Wait for every submitted write.
    pub(crate) fn close(mut self) -> Vec<Result<(u32, PathBuf, PressSummary)>> {
        drop(self.tx.take());
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        self.done.try_iter().collect()
    }
}

/// `<out>/<textile>/`: temporaries of an interrupted run removed, and
/// `textile.json` written when a name is given.
pub(crate) fn prepare_dir(out: &Path, textile: &str, name: Option<&str>) -> Result<PathBuf> {
    let dir = out.join(textile);
    let stale = remove_stale_temporaries(&dir);
    if stale > 0 {
        eprintln!(
            "removed {stale} unfinished press(es) left in {} by an interrupted run",
            dir.display()
        );
    }
    if let Some(name) = name {
        write_textile_info(
            &dir,
            &TextileInfo {
                id: textile.to_string(),
                name: name.to_string(),
            },
        )?;
    }
    Ok(dir)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn next_free_number_skips_temporaries_and_files() {
        let d = tempfile::tempdir().expect("tempdir");
        assert_eq!(next_number(&d.path().join("absent")).expect("n"), 1);
        std::fs::create_dir(d.path().join("0001")).expect("mkdir");
        std::fs::create_dir(d.path().join("0007")).expect("mkdir");
        std::fs::create_dir(d.path().join("0009.tmp-1-0")).expect("mkdir");
        std::fs::write(d.path().join("textile.json"), "{}").expect("write");
        assert_eq!(next_number(d.path()).expect("n"), 8);
    }

    #[test]
    fn textile_ids_must_be_directory_names() {
        assert!(check_id("T030").is_ok());
        assert!(check_id("my-denim_2").is_ok());
        for bad in ["", ".", "..", "a/b", "a\\b", "x\ny"] {
            assert!(check_id(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn stale_temporaries_of_dead_processes_are_removed() {
        let d = tempfile::tempdir().expect("tempdir");
        // pid 0 is never a process of ours; our own pid is alive.
        std::fs::create_dir(d.path().join("0003.tmp-0-0")).expect("mkdir");
        let mine = format!("0004.tmp-{}-0", std::process::id());
        std::fs::create_dir(d.path().join(&mine)).expect("mkdir");
        std::fs::create_dir(d.path().join("0002")).expect("mkdir");
        assert_eq!(remove_stale_temporaries(d.path()), 1);
        assert!(!d.path().join("0003.tmp-0-0").exists());
        assert!(d.path().join(&mine).exists());
        assert!(d.path().join("0002").exists());
    }
}
