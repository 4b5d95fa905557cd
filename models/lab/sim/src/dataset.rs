//! The paper's data-collection protocol as a stream of press specs, and a
//! writer that puts it on disk.
//!
//! Paper: 11 people x 119 training textiles x 1 press (150 frames) each; the
//! 20 unseen textiles; with and without the jig. We add several sensor units
//! so models see unit-to-unit variation. Nothing has to be stored: iterate
//! `Protocol::specs` and render each spec on the fly.

use crate::catalogue::{hash_str, mix64, Book, Catalogue};
use crate::recording::{self, RecordingError};
use crate::{PressSpec, Simulator, PEOPLE, PRESS_FRAMES};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Which presses to generate.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Protocol {
    /// People 0..people.
    pub people: u32,
    /// Sensor units.
    pub sensors: Vec<u32>,
    /// Jig modes (true = jig, false = hand-held).
    pub jig: Vec<bool>,
    /// Sample books.
    pub books: Vec<Book>,
    /// Presses per (sensor, jig, person, textile).
    pub presses: u32,
    /// Base seed; every press seed is derived from it.
    pub seed: u64,
    /// Frames per press.
    pub frames: usize,
}

impl Protocol {
    /// The paper protocol: 11 people x (119 + 20) textiles x 1 press, with
    /// and without jig, on 3 sensor units.
    pub fn paper() -> Protocol {
        Protocol {
            people: PEOPLE,
            sensors: vec![0, 1, 2],
            jig: vec![true, false],
            books: vec![Book::Training, Book::Unseen],
            presses: 1,
            seed: 0,
            frames: PRESS_FRAMES,
        }
    }

    /// Number of presses the protocol yields.
    pub fn len(&self, cat: &Catalogue) -> usize {
        let textiles = cat
            .textiles
            .iter()
            .filter(|t| self.books.contains(&t.book))
            .count();
        self.sensors.len()
            * self.jig.len()
            * self.people as usize
            * textiles
            * self.presses as usize
    }

    /// Whether the protocol yields nothing.
    pub fn is_empty(&self, cat: &Catalogue) -> bool {
        self.len(cat) == 0
    }

    /// Stream the press specs (sensor, jig, person, textile, press order).
    /// Specs of a catalogue other than version 1 carry its version.
    pub fn specs<'a>(&'a self, cat: &'a Catalogue) -> impl Iterator<Item = PressSpec> + 'a {
        let textiles: Vec<&'a str> = cat
            .textiles
            .iter()
            .filter(|t| self.books.contains(&t.book))
            .map(|t| t.id.as_str())
            .collect();
        self.sensors.iter().flat_map(move |&sensor| {
            let textiles = textiles.clone();
            self.jig.iter().flat_map(move |&jig| {
                let textiles = textiles.clone();
                (0..self.people).flat_map(move |person| {
                    let textiles = textiles.clone();
                    textiles.into_iter().flat_map(move |id| {
                        (0..self.presses).map(move |k| {
                            let seed = mix64(
                                self.seed
                                    ^ hash_str(id)
                                    ^ mix64(
                                        ((sensor as u64) << 40)
                                            ^ ((person as u64) << 20)
                                            ^ ((jig as u64) << 16)
                                            ^ k as u64,
                                    ),
                            );
                            PressSpec {
                                person,
                                sensor,
                                jig,
                                frames: self.frames,
                                // a version-2 catalogue's specs name it (v1
                                // specs stay as they were)
                                catalogue: (cat.version != 1).then_some(cat.version),
                                ..PressSpec::new(id, seed)
                            }
                        })
                    })
                })
            })
        })
    }
}

/// Directory of a press inside a dataset: `<textile>/p<person>-s<sensor>-<jig|hand>-<seed>`.
pub fn press_path(root: &Path, spec: &PressSpec) -> PathBuf {
    root.join(&spec.textile).join(format!(
        "p{:02}-s{}-{}-{:016x}",
        spec.person,
        spec.sensor,
        if spec.jig { "jig" } else { "hand" },
        spec.seed
    ))
}

/// Errors of the dataset writer.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    #[error(transparent)]
    Sim(#[from] crate::SimError),
    #[error(transparent)]
    Recording(#[from] RecordingError),
}

/// Render and write presses under `root` (skipping presses already there, so
/// an interrupted run resumes). Returns the number written.
pub fn write<I: IntoIterator<Item = PressSpec>>(
    sim: &Simulator,
    specs: I,
    root: &Path,
    progress: impl FnMut(usize, &PressSpec),
) -> Result<usize, DatasetError> {
    write_as(sim, specs, root, None, progress)
}

/// [`write`], each press seen by `camera`'s profile in its mode
/// ([`crate::camera::as_camera`]; None: the simulated DIGIT's frames).
pub fn write_as<I: IntoIterator<Item = PressSpec>>(
    sim: &Simulator,
    specs: I,
    root: &Path,
    camera: Option<(
        &telextiles_recording::profile::SensorProfile,
        telextiles_recording::profile::Mode,
    )>,
    mut progress: impl FnMut(usize, &PressSpec),
) -> Result<usize, DatasetError> {
    let mut n = 0;
    for spec in specs {
        let dir = press_path(root, &spec);
        if dir.join(recording::META_FILE).exists() {
            continue;
        }
        let mut press = sim.render_press(&spec)?;
        if let Some((profile, mode)) = camera {
            press = crate::camera::as_camera(&press, profile, mode)?;
        }
        recording::write_press(&dir, &press)?;
        n += 1;
        progress(n, &spec);
    }
    Ok(n)
}
