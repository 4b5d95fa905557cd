//! The paper's data protocol on simulated (or synthetic) presses and the
//! frame caches built from it (the evaluation tables of
//! `docs/evaluation.md` are `paper_eval.rs`).
//!
//! People 0..8 are the training people (sensors 0..3), people 8, 9, 10 are
//! held out (sensors 0, 4, 5 — two of them sensors never seen in training).
//! Every press is split as in the paper: frames before 120 build the index,
//! frames from 120 on are queries; only frames in full contact are used.

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};
use std::path::Path;

use crate::data::{build_sets, hex, FrameSource, ImageSet, PressKey, PressPlan};
use crate::train::INDEX_FRAMES;

/// Which frame source to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum, Serialize, Deserialize)]
pub enum SourceKind {
    /// The DIGIT press simulator (`telextiles-sim`).
    Sim,
    /// Procedural gratings (tests, timing).
    Synth,
}

/// The protocol: who presses what, which frames are cached.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct Protocol {
    /// Network input size.
    pub input: u32,
    /// Deployment centre crop.
    pub crop: u32,
    /// People whose presses train the encoder.
    pub train_people: Vec<u32>,
    /// Held-out people and the sensor each uses.
    pub heldout: Vec<(u32, u32)>,
    /// Sensors of the training people are `person % train_sensors`.
    pub train_sensors: u32,
    /// Training canvases per press (spread over the contact frames).
    pub train_frames: usize,
    /// Index frames per press (frames < 120).
    pub index_frames: usize,
    /// Query frames per press (frames >= 120).
    pub query_frames: usize,
    /// Only the first N training textiles.
    pub max_textiles: Option<usize>,
    /// Simulator catalogue version (1 or 2). Left out of the cache key when
    /// 1, so version-1 caches keep their names.
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub catalogue: u32,
    /// Texture generator of catalogue 2 (1: training and method selection;
    /// 2: the independent cross-generator test set).
    #[serde(default = "one", skip_serializing_if = "is_one")]
    pub generator: u32,
}

fn one() -> u32 {
    1
}

fn is_one(v: &u32) -> bool {
    *v == 1
}

impl Protocol {
    /// The default protocol for a given input size and crop.
    pub fn paper(input: u32, crop: u32) -> Self {
        Protocol {
            input,
            crop,
            train_people: (0..8).collect(),
            heldout: vec![(8, 0), (9, 4), (10, 5)],
            train_sensors: 4,
            train_frames: 8,
            index_frames: 6,
            query_frames: 3,
            max_textiles: None,
            catalogue: 1,
            generator: 1,
        }
    }

    /// `n` held-out people (at least the paper's 3): persons 8, 9, 10, ...
    /// on sensor units 0, 4, 5 in turn, so that every group of the study
    /// (a training unit, the held-out units, hand-held presses) has more
    /// presses than 119 and a difference between methods can be told from
    /// noise. The first three are the paper's.
    pub fn with_heldout_people(&self, n: usize) -> Protocol {
        let units = [0, 4, 5];
        Protocol {
            heldout: (0..n.max(3))
                .map(|i| (8 + i as u32, units[i % 3]))
                .collect(),
            ..self.clone()
        }
    }

    /// Who presses by hand for the hand-held group: the held-out people on
    /// a training unit (the paper protocol: person 8 on unit 0).
    pub fn handheld_people(&self) -> Vec<(u32, u32)> {
        self.heldout
            .iter()
            .copied()
            .filter(|&(_, unit)| unit < self.train_sensors)
            .collect()
    }

    /// The same protocol on another texture generator (the cross-generator
    /// test set of catalogue 2).
    pub fn with_generator(&self, generator: u32) -> Protocol {
        Protocol {
            generator,
            ..self.clone()
        }
    }
}

/// All cached sets of a protocol.
pub struct Sets {
    /// Training canvases (training people, training textiles, jig).
    pub train: ImageSet,
    /// Index frames of the training presses at input size.
    pub train_index: ImageSet,
    /// Held-out people, training textiles, jig: index and query frames.
    pub heldout: ImageSet,
    /// First held-out person, hand-held presses.
    pub handheld: ImageSet,
    /// Held-out people pressing the unseen textiles.
    pub unseen: ImageSet,
    /// Ground-truth attributes per class (if the source knows them).
    pub attributes: Vec<Option<Vec<f32>>>,
    /// The no-contact reference frame of each sensor (`FrameMeta::sensor`),
    /// where the source has one.
    pub backgrounds: ImageSet,
}

/// [`FrameSource::contact_range`] of every press of `keys`, in their order,
/// on up to `threads` threads (`done` is called once per press); the first
/// error in press order if any fails.
pub fn contact_ranges(
    source: &dyn FrameSource,
    keys: &[PressKey],
    threads: usize,
    done: &(dyn Fn() + Sync),
) -> Result<Vec<(usize, usize)>> {
    let threads = threads.clamp(1, keys.len().max(1));
    let next = std::sync::atomic::AtomicUsize::new(0);
    let mut found: Vec<(usize, Result<(usize, usize)>)> = std::thread::scope(|s| {
        let workers: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut mine = Vec::new();
                    loop {
                        let i = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                        let Some(key) = keys.get(i) else {
                            break;
                        };
                        mine.push((i, source.contact_range(key)));
                        done();
                    }
                    mine
                })
            })
            .collect();
        workers
            .into_iter()
            .flat_map(|w| w.join().expect("a contact-range worker panicked"))
            .collect()
    });
    found.sort_by_key(|(i, _)| *i);
    found.into_iter().map(|(_, r)| r).collect()
}

/// `n` frames spread evenly over `[lo, hi)`.
pub fn spread(lo: usize, hi: usize, n: usize) -> Vec<usize> {
    if hi <= lo || n == 0 {
        return Vec::new();
    }
    let mut v: Vec<usize> = (0..n)
        .map(|i| lo + ((i as f64 + 0.5) * (hi - lo) as f64 / n as f64) as usize)
        .collect();
    v.dedup();
    v
}

fn make_source(kind: SourceKind, p: &Protocol) -> Result<Box<dyn FrameSource>> {
    Ok(match kind {
        SourceKind::Sim => Box::new(crate::simsource::SimSource::with_options(
            p.catalogue,
            p.generator,
        )?),
        SourceKind::Synth => {
            anyhow::ensure!(
                p.catalogue == 1 && p.generator == 1,
                "the synth source has no catalogue versions or generators (--catalogue/--generator are for --source sim)"
            );
            Box::new(crate::synth::SynthSource)
        }
    })
}

/// Side of the cached frames: the centre 240x240 square of the 240x320
/// frame at native resolution. Every set is rendered once at this side and
/// each model's (crop, input size) view is cut from it ([`view_set`]), which
/// gives the same bytes as cropping and resizing the full frame directly.
pub const BASE_SIDE: u32 = crate::augment::CANVAS_SIDE;

/// One `crop` x `crop` centre crop of every image of a [`BASE_SIDE`] set,
/// resized to `input` x `input` as the deployment preprocessing does.
pub fn view_set(set: &ImageSet, crop: u32, input: u32) -> Result<ImageSet> {
    anyhow::ensure!(
        crop as usize <= set.side && crop > 0 && input > 0,
        "cannot cut a {crop}-px crop from {}-px cached frames",
        set.side
    );
    let mut out = ImageSet {
        kind: crate::data::ImageKind::Input,
        side: input as usize,
        crop,
        classes: set.classes.clone(),
        items: set.items.clone(),
        pixels: Vec::with_capacity(set.len() * (input * input * 3) as usize),
        source: set.source.clone(),
    };
    if crop as usize == set.side && input as usize == set.side {
        out.pixels.extend_from_slice(&set.pixels);
        return Ok(out);
    }
    let side = set.side as u32;
    for i in 0..set.len() {
        let img = image::RgbImage::from_raw(side, side, set.image(i).to_vec())
            .context("cached image has the wrong size")?;
        out.pixels.extend_from_slice(
            telextiles_graphs::preprocess::centre_crop_resize(&img, crop, input)?.as_raw(),
        );
    }
    Ok(out)
}

impl Sets {
    /// The sets as a model with this crop and input size sees them
    /// (consumes the [`BASE_SIDE`] sets; the training canvases stay canvases
    /// and only record the crop).
    pub fn into_view(self, crop: u32, input: u32) -> Result<Sets> {
        let mut train = self.train;
        train.crop = crop;
        Ok(Sets {
            train,
            train_index: view_set(&self.train_index, crop, input)?,
            heldout: view_set(&self.heldout, crop, input)?,
            handheld: view_set(&self.handheld, crop, input)?,
            unseen: view_set(&self.unseen, crop, input)?,
            backgrounds: view_set(&self.backgrounds, crop, input)?,
            attributes: self.attributes,
        })
    }

    /// The no-contact reference of `sensor` in the sets' view, if the
    /// source has one.
    pub fn background(&self, sensor: u32) -> Option<&[u8]> {
        let i = self
            .backgrounds
            .items
            .iter()
            .position(|m| m.sensor == sensor)?;
        Some(self.backgrounds.image(i))
    }
}

/// Load the protocol's caches from `cache_dir`, rendering them first if
/// needed, as a model with the protocol's crop and input size sees them.
pub fn load_or_build(
    p: &Protocol,
    kind: SourceKind,
    cache_dir: &Path,
    threads: usize,
) -> Result<Sets> {
    load_base(p, kind, cache_dir, threads)?.into_view(p.crop, p.input)
}

/// Load the protocol's caches at [`BASE_SIDE`] (whatever `p.input` and
/// `p.crop` say), rendering them first if needed.
pub fn load_base(p: &Protocol, kind: SourceKind, cache_dir: &Path, threads: usize) -> Result<Sets> {
    let source = make_source(kind, p)?;
    // One cache serves every crop and input size.
    let p = &Protocol {
        input: BASE_SIDE,
        crop: BASE_SIDE,
        ..p.clone()
    };
    let key = {
        use sha2::Digest;
        let mut h = sha2::Sha256::new();
        h.update(serde_json::to_vec(p)?);
        h.update(source.describe());
        h.update(b"cache-format-3");
        hex(&h.finalize())[..16].to_string()
    };
    let dir = cache_dir.join(format!("{kind:?}-base-{key}").to_lowercase());
    let names = [
        "train",
        "train_index",
        "heldout",
        "handheld",
        "unseen",
        "backgrounds",
    ];
    let mut training = source.training_textiles();
    if let Some(m) = p.max_textiles {
        training.truncate(m);
    }
    let unseen = source.unseen_textiles();
    let classes: Vec<String> = training.iter().chain(&unseen).cloned().collect();
    let attributes = classes.iter().map(|c| source.attributes(c)).collect();
    if names.iter().all(|n| dir.join(format!("{n}.bin")).exists()) {
        let r = |n: &str| ImageSet::read(&dir.join(format!("{n}.bin")));
        eprintln!("using cache {}", dir.display());
        return Ok(Sets {
            train: r("train")?,
            train_index: r("train_index")?,
            heldout: r("heldout")?,
            handheld: r("handheld")?,
            unseen: r("unseen")?,
            backgrounds: r("backgrounds")?,
            attributes,
        });
    }
    std::fs::create_dir_all(&dir).with_context(|| format!("cannot create {}", dir.display()))?;
    std::fs::write(dir.join("protocol.json"), serde_json::to_string_pretty(p)?)?;
    let nidx = |lo: usize, hi: usize| spread(lo, hi.min(INDEX_FRAMES as usize), p.index_frames);
    let nq = |lo: usize, hi: usize| spread(lo.max(INDEX_FRAMES as usize), hi, p.query_frames);
    #[allow(clippy::too_many_arguments)]
    let plan_for = |name: &str,
                    textiles: &[String],
                    class0: usize,
                    people: &[(u32, u32)],
                    jig: bool,
                    seed0: u64,
                    canvas: bool,
                    queries: bool|
     -> Result<Vec<PressPlan>> {
        let mut keys = Vec::new();
        for (ti, t) in textiles.iter().enumerate() {
            for &(person, sensor) in people {
                let key = PressKey {
                    textile: t.clone(),
                    person,
                    sensor,
                    jig,
                    seed: seed0 + person as u64,
                };
                keys.push(((class0 + ti) as u32, key));
            }
        }
        // Where each press is in contact (the simulator sets each press up
        // to say): minutes for a whole catalogue, so on every thread, with
        // progress.
        let bar = telextiles_progress::Progress::new(
            &format!("finding contact in {name}"),
            keys.len() as u64,
            "presses",
        );
        let only_keys: Vec<PressKey> = keys.iter().map(|(_, k)| k.clone()).collect();
        let ranges = contact_ranges(source.as_ref(), &only_keys, threads, &|| bar.inc(1))?;
        bar.finish();
        Ok(keys
            .into_iter()
            .zip(ranges)
            .map(|((class, key), (lo, hi))| {
                let mut input_frames = nidx(lo, hi);
                if queries {
                    input_frames.extend(nq(lo, hi));
                }
                PressPlan {
                    key,
                    class,
                    canvas_frames: if canvas {
                        spread(lo, hi, p.train_frames)
                    } else {
                        Vec::new()
                    },
                    input_frames,
                }
            })
            .collect())
    };
    let train_people: Vec<(u32, u32)> = p
        .train_people
        .iter()
        .map(|&q| (q, q % p.train_sensors.max(1)))
        .collect();
    let t0 = std::time::Instant::now();
    let build = |name: &str, plan: Vec<PressPlan>| -> Result<(ImageSet, ImageSet)> {
        // A bar with ETA on a terminal, plain lines every few seconds
        // otherwise.
        let bar = telextiles_progress::Progress::new(
            &format!("rendering {name}"),
            plan.len() as u64,
            "presses",
        );
        let progress = |_d: usize, _n: usize| bar.inc(1);
        let r = build_sets(
            source.as_ref(),
            classes.clone(),
            &plan,
            p.input,
            p.crop,
            threads,
            &progress,
        );
        bar.finish();
        r
    };
    let (train, train_index) = build(
        "train",
        plan_for(
            "train",
            &training,
            0,
            &train_people,
            true,
            1000,
            true,
            false,
        )?,
    )?;
    let (_, heldout) = build(
        "heldout",
        plan_for("heldout", &training, 0, &p.heldout, true, 2000, false, true)?,
    )?;
    let (_, handheld) = build(
        "handheld",
        plan_for(
            "handheld",
            &training,
            0,
            &p.handheld_people(),
            false,
            3000,
            false,
            true,
        )?,
    )?;
    let (_, unseen_set) = build(
        "unseen",
        plan_for(
            "unseen",
            &unseen,
            training.len(),
            &p.heldout,
            true,
            4000,
            false,
            true,
        )?,
    )?;
    // The no-contact reference of every sensor in the protocol.
    let mut sensors: Vec<u32> = train_people.iter().chain(&p.heldout).map(|x| x.1).collect();
    sensors.sort_unstable();
    sensors.dedup();
    let mut backgrounds = ImageSet {
        kind: crate::data::ImageKind::Input,
        side: BASE_SIDE as usize,
        crop: BASE_SIDE,
        classes: classes.clone(),
        items: Vec::new(),
        pixels: Vec::new(),
        source: source.describe(),
    };
    for s in sensors {
        if let Some(bg) = source.background(s)? {
            let img = crate::data::frame_to_image(
                &bg,
                crate::data::ImageKind::Input,
                BASE_SIDE,
                BASE_SIDE,
            )?;
            backgrounds.items.push(crate::data::FrameMeta {
                class: 0,
                press: 0,
                person: 0,
                sensor: s,
                jig: true,
                frame: 0,
            });
            backgrounds.pixels.extend_from_slice(img.as_raw());
        }
    }
    for (n, s) in names.iter().zip([
        &train,
        &train_index,
        &heldout,
        &handheld,
        &unseen_set,
        &backgrounds,
    ]) {
        s.write(&dir.join(format!("{n}.bin")))?;
    }
    eprintln!(
        "cached {} in {:.0}s",
        dir.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok(Sets {
        train,
        train_index,
        heldout,
        handheld,
        unseen: unseen_set,
        backgrounds,
        attributes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A source whose presses are in contact over `[seed, seed + person)`,
    /// and that fails on seed 13.
    struct Ranges;
    impl FrameSource for Ranges {
        fn describe(&self) -> String {
            "ranges".into()
        }
        fn frames_per_press(&self) -> usize {
            150
        }
        fn frames(&self, _: &PressKey, _: &[usize]) -> Result<Vec<image::RgbImage>> {
            Ok(Vec::new())
        }
        fn contact_range(&self, k: &PressKey) -> Result<(usize, usize)> {
            anyhow::ensure!(k.seed != 13, "press {} cannot be set up", k.seed);
            Ok((k.seed as usize, (k.seed + k.person as u64) as usize))
        }
        fn training_textiles(&self) -> Vec<String> {
            Vec::new()
        }
        fn unseen_textiles(&self) -> Vec<String> {
            Vec::new()
        }
    }

    /// Contact ranges found on several threads are those of one thread, in
    /// press order, each press counted once; a press that fails fails the
    /// whole, whichever thread meets it.
    #[test]
    fn contact_ranges_on_every_thread_keep_press_order() {
        let key = |seed: u64| PressKey {
            textile: "T001".into(),
            person: (seed % 5) as u32,
            sensor: 0,
            jig: true,
            seed,
        };
        let keys: Vec<PressKey> = (20..80).map(key).collect();
        let want: Vec<(usize, usize)> = keys
            .iter()
            .map(|k| (k.seed as usize, (k.seed + k.person as u64) as usize))
            .collect();
        for threads in [0, 1, 2, 3, 100] {
            let n = std::sync::atomic::AtomicUsize::new(0);
            let count = || {
                n.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            };
            let got = contact_ranges(&Ranges, &keys, threads, &count).unwrap();
            assert_eq!(got, want, "{threads} threads");
            assert_eq!(n.into_inner(), keys.len());
        }
        assert!(contact_ranges(&Ranges, &[], 2, &|| ()).unwrap().is_empty());
        let mut bad = keys.clone();
        bad[37] = key(13);
        let e = contact_ranges(&Ranges, &bad, 3, &|| ()).unwrap_err();
        assert!(e.to_string().contains("press 13"), "{e}");
    }
}
