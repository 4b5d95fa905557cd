//! Building an index from per-textile embeddings.

use crate::map::{self, MapLayout};
use crate::metric::{Moments, Shrinkage};
use crate::select::{self, SelectionMethod};
use crate::vecmath::{distance, l2_normalise, normalised_mean};
use crate::{Entry, Index, IndexError, Metric, RollerLayout, UnknownDistance};

/// Everything known about one textile before it goes into the index.
#[derive(Clone, Debug)]
pub struct TextileRecord {
    /// Catalogue id or user label.
    pub id: String,
    /// Human-readable name.
    pub name: String,
    /// In the training book.
    pub seen: bool,
    /// Structure family.
    pub structure: String,
    /// Ground-truth tactile attributes.
    pub attributes: Vec<(String, f32)>,
    /// Embeddings of this textile's frames (any length; normalised here).
    pub embeddings: Vec<Vec<f32>>,
    /// Per-press mean embeddings (optional): kept as exemplars unless the
    /// builder's `keep_exemplars` is off, and what its metric is checked
    /// on (each press left out in turn).
    pub exemplars: Vec<Vec<f32>>,
    /// The frame embeddings of each press, in the order of `exemplars`
    /// (optional): what a metric fitted on frames learns from
    /// ([`MetricFit::Frames`]). Empty: each press is its mean alone.
    pub press_frames: Vec<Vec<Vec<f32>>>,
}

/// How an index's distance is fitted to its presses.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MetricFit {
    /// Plain cosine distance: nothing fitted.
    Cosine,
    /// Within-fabric whitening of the presses' mean embeddings at a fixed
    /// shrinkage (the index's learned distance before fits on frames).
    PressMeans(f32),
    /// Within-fabric whitening of every frame of the presses (a shrinkage
    /// LDA: the pooled scatter of each fabric's frames about the fabric's
    /// mean), shrunk by this much, or by the Ledoit–Wolf estimate (None).
    Frames(Option<f32>),
    /// Whichever of [`MetricFit::CANDIDATES`] decides the most presses
    /// right, each press left out in turn with the fit made again without
    /// it ([`left_out_fitted`]); ties go to the earlier, simpler one, so
    /// plain cosine wins unless a fit does better on the owner's own
    /// presses.
    Auto,
}

impl MetricFit {
    /// What [`MetricFit::Auto`] chooses among, simplest first.
    pub const CANDIDATES: [MetricFit; 5] = [
        MetricFit::Cosine,
        MetricFit::PressMeans(crate::metric::DEFAULT_SHRINKAGE),
        MetricFit::Frames(None),
        MetricFit::Frames(Some(0.1)),
        MetricFit::Frames(Some(0.3)),
    ];

    /// The fit from a shrinkage of press means (None: cosine): what an
    /// index learned before fits on frames.
    pub fn press_means(shrinkage: Option<f32>) -> MetricFit {
        shrinkage.map_or(MetricFit::Cosine, MetricFit::PressMeans)
    }

    /// In words, for tables and summaries.
    pub fn label(&self) -> String {
        match self {
            MetricFit::Cosine => "cosine".into(),
            MetricFit::PressMeans(a) => format!("press means, shrinkage {a}"),
            MetricFit::Frames(None) => "frames, Ledoit-Wolf shrinkage".into(),
            MetricFit::Frames(Some(a)) => format!("frames, shrinkage {a}"),
            MetricFit::Auto => "chosen on the presses".into(),
        }
    }

    /// A shrinkage outside 0..=1, as an error.
    fn check(&self) -> Result<(), IndexError> {
        match *self {
            MetricFit::PressMeans(a) | MetricFit::Frames(Some(a)) if !(0.0..=1.0).contains(&a) => {
                Err(IndexError::Invalid(format!(
                    "metric shrinkage {a} is outside 0..=1"
                )))
            }
            _ => Ok(()),
        }
    }

    /// The metric this fit makes of each fabric's presses (None: cosine,
    /// or nothing to learn from). [`MetricFit::Auto`] is not a fit of its
    /// own: it fits nothing here.
    pub fn fit(&self, fabrics: &[Vec<&PressData>], dim: usize) -> Option<Metric> {
        let (frames, shrinkage) = match *self {
            MetricFit::Cosine | MetricFit::Auto => return None,
            MetricFit::PressMeans(a) => (false, Shrinkage::Fixed(a)),
            MetricFit::Frames(a) => (true, a.map_or(Shrinkage::LedoitWolf, Shrinkage::Fixed)),
        };
        let mut presses = 0;
        let moments: Vec<Moments> = fabrics
            .iter()
            .map(|f| {
                let mut m = Moments::zero(dim);
                for p in f {
                    m.add(if frames { &p.frames } else { &p.mean_moments });
                }
                if (frames && m.n >= 2) || f.len() >= 2 {
                    presses += f.len();
                }
                m
            })
            .collect();
        Metric::from_moments(&moments, dim, shrinkage, presses)
    }
}

/// One press as the index learns from it: its mean embedding and the
/// [`Moments`] of its mean and of its frames.
#[derive(Clone, Debug)]
pub struct PressData {
    /// Its mean embedding (encoder space, any length).
    pub mean: Vec<f32>,
    /// The moments of its mean alone.
    pub mean_moments: Moments,
    /// The moments of its frames (of its mean alone when they are not
    /// known).
    pub frames: Moments,
}

impl PressData {
    /// From a press's mean and its frames' embeddings (empty: its mean
    /// stands for them). None when a vector is of another dimension, not
    /// finite or of zero length.
    pub fn new(mean: &[f32], frames: &[Vec<f32>], dim: usize) -> Option<PressData> {
        let mean_moments = Moments::of([mean], dim)?;
        let frames = if frames.is_empty() {
            mean_moments.clone()
        } else {
            Moments::of(frames.iter().map(Vec::as_slice), dim)?
        };
        Some(PressData {
            mean: mean.to_vec(),
            mean_moments,
            frames,
        })
    }
}

/// One fabric's presses: each press's mean embedding, and each press's
/// frame embeddings (in the same order; may be empty).
pub type FabricPresses = (Vec<Vec<f32>>, Vec<Vec<Vec<f32>>>);

/// Each fabric's presses as [`PressData`] (presses of another dimension or
/// with non-finite values are left out, as [`left_out`] leaves them).
pub fn press_data(fabrics: &[FabricPresses], dim: usize) -> Vec<Vec<PressData>> {
    fabrics
        .iter()
        .map(|(means, frames)| presses_of(means, frames, dim))
        .collect()
}

/// One fabric's presses as [`PressData`]: press `i`'s mean `means[i]` and
/// frames `frames[i]` (none: its mean stands for them).
fn presses_of(means: &[Vec<f32>], frames: &[Vec<Vec<f32>>], dim: usize) -> Vec<PressData> {
    means
        .iter()
        .enumerate()
        .filter_map(|(i, m)| PressData::new(m, frames.get(i).map_or(&[][..], Vec::as_slice), dim))
        .collect()
}

/// A fit and how it did on the presses left out ([`left_out_fitted`]).
#[derive(Clone, Debug)]
pub struct FitCheck {
    /// The fit.
    pub fit: MetricFit,
    /// Every press left out and decided with the fit made without it.
    pub left: Vec<LeftOut>,
}

impl FitCheck {
    /// Presses decided right.
    pub fn right(&self) -> usize {
        self.left.iter().filter(|l| l.decided == l.fabric).count()
    }
}

/// Each fit checked on the same presses, and the one chosen: the most
/// presses right, the earlier (simpler) one on a tie.
pub fn choose_fit(
    fabrics: &[Vec<PressData>],
    dim: usize,
    exemplars: bool,
    fits: &[MetricFit],
) -> (usize, Vec<FitCheck>) {
    let checks: Vec<FitCheck> = fits
        .iter()
        .map(|&fit| FitCheck {
            fit,
            left: left_out_fitted(fabrics, dim, exemplars, fit),
        })
        .collect();
    let mut best = 0;
    for (k, c) in checks.iter().enumerate() {
        if c.right() > checks[best].right() {
            best = k;
        }
    }
    (best, checks)
}

/// Collects textiles, then lays out the roller and the map.
#[derive(Clone, Debug)]
pub struct IndexBuilder {
    encoder_hash: String,
    encoder_arch: String,
    dim: usize,
    catalogue_version: u32,
    records: Vec<TextileRecord>,
    /// Slots on the roller.
    pub roller_n: usize,
    /// How the roller's textiles are chosen.
    pub method: SelectionMethod,
    /// Seed for the UMAP layouts and random selection.
    pub seed: u64,
    /// Keep the records' per-press embeddings as exemplars (default: on).
    pub keep_exemplars: bool,
    /// How the index's distance is fitted to the records' presses
    /// ([`MetricFit`]); [`MetricFit::Cosine`] (the default): plain cosine
    /// distance. Without two presses (or frames) of some fabric there is
    /// nothing to learn and the index has no metric.
    pub metric: MetricFit,
    /// Calibrate the index's unknown-textile distance on the records'
    /// per-press embeddings: the share `q` (0 < q <= 1) of presses that
    /// should count as known, leaving each out in turn
    /// ([`press_distances`]); None (the default): no calibrated distance,
    /// the decider's fixed one. Without [`MIN_CALIBRATION_PRESSES`] presses
    /// of fabrics with two or more the index has none.
    pub unknown_quantile: Option<f32>,
    /// What the records' vectors are made of ([`crate::Features`]; the
    /// encoder's embedding alone by default): recorded in the index, so
    /// every daemon holding it makes its queries alike.
    pub features: crate::Features,
    /// The sensor profile the records came from ([`crate::Index::sensor`];
    /// None: a DIGIT).
    pub sensor: Option<String>,
}

/// The quantile `telextilesd index build --presses` calibrates at by
/// default (docs/recording.md, "Telling a fabric the index does not have").
pub const DEFAULT_UNKNOWN_QUANTILE: f32 = 0.9;

/// A quantile for [`IndexBuilder::unknown_quantile`] from text (command
/// lines): a number in (0, 1], or an error that says why not.
pub fn parse_quantile(s: &str) -> Result<f32, String> {
    let q: f32 = s.parse().map_err(|e| format!("{s}: {e}"))?;
    if is_quantile(q) {
        Ok(q)
    } else {
        Err(format!("{q} is outside (0, 1]"))
    }
}

/// Whether `q` is a share of presses an unknown-textile distance can be
/// calibrated at: 0 < q <= 1 (NaN is not).
pub fn is_quantile(q: f32) -> bool {
    q > 0.0 && q <= 1.0
}

/// A vector in the space of an index with `metric`: mapped by it, or only
/// L2-normalised without one.
fn in_space(metric: Option<&Metric>, v: &[f32]) -> Vec<f32> {
    match metric {
        Some(m) => m.apply(v),
        None => {
            let mut v = v.to_vec();
            l2_normalise(&mut v);
            v
        }
    }
}

/// The fewest left-out press distances an unknown-textile distance is
/// calibrated on.
pub const MIN_CALIBRATION_PRESSES: usize = 4;

impl IndexBuilder {
    /// A builder for embeddings of dimension `dim` from the encoder whose
    /// ONNX file hashes to `encoder_hash`.
    pub fn new(encoder_hash: &str, encoder_arch: &str, dim: usize, catalogue_version: u32) -> Self {
        IndexBuilder {
            encoder_hash: encoder_hash.to_string(),
            encoder_arch: encoder_arch.to_string(),
            dim,
            catalogue_version,
            records: Vec::new(),
            roller_n: 16,
            method: SelectionMethod::KMedoids,
            seed: 0,
            keep_exemplars: true,
            metric: MetricFit::Cosine,
            unknown_quantile: None,
            features: crate::Features::Encoder,
            sensor: None,
        }
    }

    /// Add a textile.
    pub fn add(&mut self, record: TextileRecord) -> Result<(), IndexError> {
        if record.embeddings.is_empty() {
            return Err(IndexError::Invalid(format!(
                "textile {} has no embeddings",
                record.id
            )));
        }
        if let Some(v) = record
            .embeddings
            .iter()
            .chain(&record.exemplars)
            .chain(record.press_frames.iter().flatten())
            .find(|v| v.len() != self.dim)
        {
            return Err(IndexError::Invalid(format!(
                "textile {}: embedding of dimension {}, expected {}",
                record.id,
                v.len(),
                self.dim
            )));
        }
        if !record.press_frames.is_empty() && record.press_frames.len() != record.exemplars.len() {
            return Err(IndexError::Invalid(format!(
                "textile {}: frames of {} presses for {} press means",
                record.id,
                record.press_frames.len(),
                record.exemplars.len()
            )));
        }
        if self.records.iter().any(|r| r.id == record.id) {
            return Err(IndexError::Invalid(format!(
                "textile {} added twice",
                record.id
            )));
        }
        self.records.push(record);
        Ok(())
    }

    /// Lay out roller and map. Roller textiles are chosen among the seen ones
    /// (the physical samples come from the training book), or among all if
    /// none is marked seen.
    pub fn build(self) -> Result<Index, IndexError> {
        let measure = self.unknown_quantile.is_some();
        self.build_inner(measure).map(|r| r.index)
    }

    /// [`IndexBuilder::build`], also returning the left-out press distances
    /// the unknown-textile distance is (or would be) calibrated on, sorted
    /// ([`press_distances`]; computed whether or not `unknown_quantile` is
    /// set, so a study can try several quantiles on one build).
    pub fn build_calibrated(self) -> Result<(Index, Vec<f32>), IndexError> {
        self.build_inner(true)
            .map(|r| (r.index, sorted_distances(&r.left)))
    }

    /// [`IndexBuilder::build`], also returning every press left out of the
    /// index and decided against the rest ([`left_out`], in the records'
    /// order of fabrics; the same presses the unknown distance is
    /// calibrated on): how well the index tells its own fabrics apart.
    pub fn build_checked(self) -> Result<(Index, Vec<LeftOut>), IndexError> {
        self.build_inner(true).map(|r| (r.index, r.left))
    }

    /// [`IndexBuilder::build_checked`], with every fit that was checked
    /// (with [`MetricFit::Auto`], each candidate's left-out presses) and the
    /// one chosen.
    pub fn build_report(self) -> Result<BuildReport, IndexError> {
        self.build_inner(true)
    }

    fn build_inner(self, measure: bool) -> Result<BuildReport, IndexError> {
        let dim = self.dim;
        if let Some(q) = self.unknown_quantile {
            if !is_quantile(q) {
                return Err(IndexError::Invalid(format!(
                    "unknown-textile quantile {q} is outside (0, 1]"
                )));
            }
        }
        self.metric.check()?;
        // Each fabric's presses: what the metric learns from and the
        // calibration measures.
        let presses: Vec<Vec<PressData>> = self
            .records
            .iter()
            .map(|r| presses_of(&r.exemplars, &r.press_frames, dim))
            .collect();
        let keep_exemplars = self.keep_exemplars;
        // The fit: the one asked for, or the best of the candidates on the
        // presses left out in turn.
        let (chosen_fit, fits) = match self.metric {
            MetricFit::Auto => choose_fit(&presses, dim, keep_exemplars, &MetricFit::CANDIDATES),
            fit if measure => (
                0,
                vec![FitCheck {
                    fit,
                    left: left_out_fitted(&presses, dim, keep_exemplars, fit),
                }],
            ),
            fit => (
                0,
                vec![FitCheck {
                    fit,
                    left: Vec::new(),
                }],
            ),
        };
        let fit = fits[chosen_fit].fit;
        let all: Vec<Vec<&PressData>> = presses.iter().map(|f| f.iter().collect()).collect();
        let metric = fit.fit(&all, dim);
        // Every vector in the metric's space (normalised either way).
        let map_in = |v: &[f32]| in_space(metric.as_ref().filter(|_| v.len() == dim), v);
        let left = fits[chosen_fit].left.clone();
        let press_d = sorted_distances(&left);
        let unknown = self.unknown_quantile.and_then(|q| {
            Some(UnknownDistance {
                distance: calibrated_distance(&press_d, q)?,
                quantile: q,
                presses: press_d.len() as u32,
            })
        });
        let entries: Vec<Entry> = self
            .records
            .into_iter()
            .map(|r| {
                let normed: Vec<Vec<f32>> = r.embeddings.iter().map(|v| map_in(v)).collect();
                let exemplars = if keep_exemplars {
                    r.exemplars.iter().map(|v| map_in(v)).collect()
                } else {
                    Vec::new()
                };
                Entry {
                    centroid: normalised_mean(&normed, dim),
                    id: r.id,
                    name: r.name,
                    seen: r.seen,
                    structure: r.structure,
                    attributes: r.attributes,
                    exemplars,
                    map_xy: [0.0, 0.0],
                }
            })
            .collect();
        let mut candidates: Vec<usize> = (0..entries.len()).filter(|&i| entries[i].seen).collect();
        if candidates.is_empty() {
            candidates = (0..entries.len()).collect();
        }
        if self.roller_n == 0 || self.roller_n > candidates.len() {
            return Err(IndexError::Invalid(format!(
                "a roller of {} slots needs at least that many textiles; the index has {}",
                self.roller_n,
                candidates.len()
            )));
        }
        let cand_points: Vec<Vec<f32>> = candidates
            .iter()
            .map(|&i| entries[i].centroid.clone())
            .collect();
        let chosen = select::select(&cand_points, self.roller_n, self.method, self.seed);
        let ordered = select::order_wheel(&cand_points, &chosen);
        let slots: Vec<usize> = ordered.iter().map(|&k| candidates[k]).collect();
        let all: Vec<Vec<f32>> = entries.iter().map(|e| e.centroid.clone()).collect();
        let entry_slot = all
            .iter()
            .map(|p| select::nearest_of(p, &all, &slots).0)
            .collect();
        let mut xy = map::umap(&all, 2, self.seed);
        map::normalise_layout(&mut xy);
        let mut index = Index {
            encoder_hash: self.encoder_hash,
            encoder_arch: self.encoder_arch,
            dim,
            catalogue_version: self.catalogue_version,
            entries,
            roller: RollerLayout {
                method: self.method,
                slots,
                entry_slot,
            },
            map: MapLayout {
                method: "umap".into(),
                seed: self.seed,
                place_k: 3,
            },
            metric,
            unknown,
            features: self.features,
            sensor: self.sensor,
        };
        for (e, p) in index.entries.iter_mut().zip(xy) {
            e.map_xy = [p[0], p[1]];
        }
        index.validate()?;
        Ok(BuildReport {
            index,
            left,
            fits,
            chosen: chosen_fit,
        })
    }
}

/// What [`IndexBuilder::build_report`] returns.
#[derive(Clone, Debug)]
pub struct BuildReport {
    /// The index.
    pub index: Index,
    /// The chosen fit's left-out presses (what the unknown distance is
    /// calibrated on, and the index's self-check).
    pub left: Vec<LeftOut>,
    /// Every fit checked (one unless [`MetricFit::Auto`]).
    pub fits: Vec<FitCheck>,
    /// Which of `fits` the index uses.
    pub chosen: usize,
}

/// How many folds [`press_distances`] leaves out in turn, at most.
pub const MAX_CALIBRATION_FOLDS: usize = 4;

/// A press left out of the index and decided against the rest
/// ([`left_out`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LeftOut {
    /// Its fabric (position in the input).
    pub fabric: usize,
    /// Its position among its fabric's presses in the input.
    pub press: usize,
    /// The fabric whose entry it is nearest to.
    pub decided: usize,
    /// Its distance to its own fabric's entry.
    pub own_distance: f32,
}

/// A fabric's entry in one fold of [`left_out`]: its centroid and its
/// presses (in the metric's space).
type FoldEntry = (Vec<f32>, Vec<Vec<f32>>);

/// Every press of a fabric with another press, left out of the index and
/// decided against an index of the others: what a new press of a known
/// fabric is likely to be, measured on the owner's own presses.
/// `fabrics`: each fabric's per-press embeddings (encoder space); with
/// their frames, [`left_out_fitted`].
/// The presses are dealt into folds (press `i` of a fabric into fold
/// `i mod F`, `F` = the most presses of a fabric, at most
/// [`MAX_CALIBRATION_FOLDS`]); for each fold the index is made again without
/// it, its metric learned again with `shrinkage` when given (a metric
/// learned with the press in it would flatter it: whitening shrinks the
/// directions its own presses vary in). Each fabric's entry is the
/// normalised mean of its remaining presses, or (with `exemplars`) the
/// nearest of that and the remaining presses; a fabric with none left in
/// has no entry in that fold. (The entry's real centroid is the mean of
/// its frames, not of its presses' means; with presses of equal frame
/// counts the two agree.) Presses with a non-finite distance are left out.
pub fn left_out(
    fabrics: &[Vec<Vec<f32>>],
    dim: usize,
    exemplars: bool,
    shrinkage: Option<f32>,
) -> Vec<LeftOut> {
    // Each fabric's usable presses, with their positions in the input.
    let data: Vec<Vec<(usize, PressData)>> = fabrics
        .iter()
        .map(|f| {
            f.iter()
                .enumerate()
                .filter_map(|(i, v)| Some((i, PressData::new(v, &[], dim)?)))
                .collect()
        })
        .collect();
    let folds = fabrics.iter().map(Vec::len).max().unwrap_or(0);
    left_out_indexed(
        &data,
        folds,
        dim,
        exemplars,
        MetricFit::press_means(shrinkage),
    )
}

/// [`left_out`] for presses with their frames, the metric fitted by `fit`
/// on the presses kept in each fold ([`MetricFit::fit`]; `Auto` is
/// cosine). A press's `press` is its position in `fabrics`.
pub fn left_out_fitted(
    fabrics: &[Vec<PressData>],
    dim: usize,
    exemplars: bool,
    fit: MetricFit,
) -> Vec<LeftOut> {
    let data: Vec<Vec<(usize, PressData)>> = fabrics
        .iter()
        .map(|f| f.iter().cloned().enumerate().collect())
        .collect();
    let folds = fabrics.iter().map(Vec::len).max().unwrap_or(0);
    left_out_indexed(&data, folds, dim, exemplars, fit)
}

/// [`left_out`] over each fabric's usable presses (with their positions in
/// the input), in `folds` folds at most [`MAX_CALIBRATION_FOLDS`].
fn left_out_indexed(
    fabrics: &[Vec<(usize, PressData)>],
    folds: usize,
    dim: usize,
    exemplars: bool,
    fit: MetricFit,
) -> Vec<LeftOut> {
    let folds = folds.min(MAX_CALIBRATION_FOLDS);
    let mut out = Vec::new();
    for fold in 0..folds {
        let kept: Vec<Vec<&PressData>> = fabrics
            .iter()
            .map(|f| {
                f.iter()
                    .enumerate()
                    .filter(|&(i, _)| i % folds != fold)
                    .map(|(_, (_, p))| p)
                    .collect()
            })
            .collect();
        let metric = fit.fit(&kept, dim);
        let map_in = |v: &[f32]| in_space(metric.as_ref(), v);
        // Each fabric's entry in this fold: its centroid, then its presses.
        let entries: Vec<Option<FoldEntry>> = kept
            .iter()
            .map(|k| {
                (!k.is_empty()).then(|| {
                    let others: Vec<Vec<f32>> = k.iter().map(|p| map_in(&p.mean)).collect();
                    (normalised_mean(&others, dim), others)
                })
            })
            .collect();
        let to_entry = |p: &[f32], (centroid, others): &FoldEntry| {
            let mut d = distance(p, centroid);
            if exemplars {
                for o in others {
                    d = d.min(distance(p, o));
                }
            }
            d
        };
        for (fabric, f) in fabrics.iter().enumerate() {
            let Some(own) = &entries[fabric] else {
                continue;
            };
            for (_, (press, p)) in f.iter().enumerate().filter(|&(i, _)| i % folds == fold) {
                let p = map_in(&p.mean);
                let own_distance = to_entry(&p, own);
                if !own_distance.is_finite() {
                    continue;
                }
                // Another fabric as near as its own takes it: a tie is
                // not a press told apart.
                let mut decided = (fabric, own_distance);
                for (g, e) in entries.iter().enumerate() {
                    if let (Some(e), true) = (e, g != fabric) {
                        let d = to_entry(&p, e);
                        if d <= decided.1 {
                            decided = (g, d);
                        }
                    }
                }
                out.push(LeftOut {
                    fabric,
                    press: *press,
                    decided: decided.0,
                    own_distance,
                });
            }
        }
    }
    out
}

/// The left-out presses' distances to their own fabric's entry, sorted
/// ([`left_out`]): what the unknown-textile distance is calibrated on.
pub fn press_distances(
    fabrics: &[Vec<Vec<f32>>],
    dim: usize,
    exemplars: bool,
    shrinkage: Option<f32>,
) -> Vec<f32> {
    sorted_distances(&left_out(fabrics, dim, exemplars, shrinkage))
}

/// How well an index tells its own fabrics apart: its presses, each left
/// out and decided against the rest ([`left_out`]).
#[derive(Clone, Debug, PartialEq)]
pub struct SelfCheck {
    /// Presses left out and decided.
    pub presses: usize,
    /// Of them, decided as their own fabric.
    pub right: usize,
    /// (fabric, decided as, presses), most presses first, then by fabric.
    pub confusions: Vec<(usize, usize, usize)>,
}

impl SelfCheck {
    /// Count the left-out presses.
    pub fn of(left: &[LeftOut]) -> SelfCheck {
        SelfCheck::of_pairs(left.iter().map(|l| (l.fabric, l.decided)))
    }

    /// Count presses given as (fabric, decided as) pairs (`classify`'s
    /// presses against the fabrics they are labelled with).
    pub fn of_pairs(decided: impl IntoIterator<Item = (usize, usize)>) -> SelfCheck {
        let (mut presses, mut right) = (0, 0);
        let mut pairs = std::collections::BTreeMap::new();
        for (fabric, as_) in decided {
            presses += 1;
            if as_ == fabric {
                right += 1;
            } else {
                *pairs.entry((fabric, as_)).or_insert(0usize) += 1;
            }
        }
        let mut confusions: Vec<(usize, usize, usize)> =
            pairs.into_iter().map(|((f, d), n)| (f, d, n)).collect();
        confusions.sort_by(|a, b| b.2.cmp(&a.2).then((a.0, a.1).cmp(&(b.0, b.1))));
        SelfCheck {
            presses,
            right,
            confusions,
        }
    }
}

/// Two self-checks of the same presses (two models' embeddings of them),
/// paired press by press: only presses both decided count.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Paired {
    /// Presses both decided.
    pub presses: usize,
    /// Of them, right by the first only.
    pub first_only: usize,
    /// Right by the second only.
    pub second_only: usize,
}

impl Paired {
    /// Pair two sets of left-out presses by (fabric, press).
    pub fn of(first: &[LeftOut], second: &[LeftOut]) -> Paired {
        let right = |l: &[LeftOut]| -> std::collections::BTreeMap<(usize, usize), bool> {
            l.iter()
                .map(|l| ((l.fabric, l.press), l.decided == l.fabric))
                .collect()
        };
        let (a, b) = (right(first), right(second));
        let mut p = Paired {
            presses: 0,
            first_only: 0,
            second_only: 0,
        };
        for (k, &ra) in &a {
            if let Some(&rb) = b.get(k) {
                p.presses += 1;
                p.first_only += usize::from(ra && !rb);
                p.second_only += usize::from(rb && !ra);
            }
        }
        p
    }

    /// Whether the second is right more often by at least two standard
    /// errors of the paired difference (the presses one got right and the
    /// other did not: what one model's advantage on these presses rests
    /// on).
    pub fn second_ahead(&self) -> bool {
        let n = self.presses as f64;
        let (b, c) = (self.second_only as f64, self.first_only as f64);
        if self.presses == 0 || b <= c {
            return false;
        }
        let d = (b - c) / n;
        let se = (((b + c) / n - d * d) / n).max(0.0).sqrt();
        d >= 2.0 * se
    }
}

fn sorted_distances(left: &[LeftOut]) -> Vec<f32> {
    let mut out: Vec<f32> = left.iter().map(|l| l.own_distance).collect();
    out.sort_by(f32::total_cmp);
    out
}

/// The nearest-rank `q` quantile of sorted left-out distances, as an
/// unknown-textile distance: None with fewer than
/// [`MIN_CALIBRATION_PRESSES`] distances, for `q` outside (0, 1], or when
/// the quantile is 0 (presses that do not differ at all say nothing about
/// how far a new one may be).
pub fn calibrated_distance(sorted: &[f32], q: f32) -> Option<f32> {
    if sorted.len() < MIN_CALIBRATION_PRESSES || !is_quantile(q) {
        return None;
    }
    let rank = ((q as f64 * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    let t = sorted[rank - 1];
    (t > 0.0 && t <= 2.0).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(a: f32) -> Vec<f32> {
        vec![a.cos(), a.sin()]
    }

    #[test]
    fn left_out_distances_measure_each_press_from_the_others() {
        // Three presses of one fabric at -0.1, 0 and 0.1 rad; a fabric with
        // one press adds nothing.
        let d = press_distances(
            &[vec![unit(-0.1), unit(0.0), unit(0.1)], vec![unit(2.0)]],
            2,
            false,
            None,
        );
        assert_eq!(d.len(), 3);
        // The middle press is at the others' mean; each outer one is 0.15 rad
        // from the mean of the middle and the other outer (0.05 rad).
        let chord = |a: f32| 2.0 * (a / 2.0).sin();
        assert!(d[0].abs() < 1e-6, "{d:?}");
        assert!(
            (d[1] - chord(0.15)).abs() < 1e-5 && (d[2] - chord(0.15)).abs() < 1e-5,
            "{d:?}"
        );
        // With exemplars, each outer press is 0.1 rad from the middle one.
        let e = press_distances(&[vec![unit(-0.1), unit(0.0), unit(0.1)]], 2, true, None);
        assert!((e[2] - chord(0.1)).abs() < 1e-5, "{e:?}");
    }

    #[test]
    fn left_out_presses_are_decided_against_the_rest() {
        // Fabric 0 at 0 rad (three presses, the last straying to 0.9 rad),
        // fabric 1 at 1.2 rad (two presses), fabric 2 at 3 rad (one press:
        // never left out alone, an entry in the folds it is kept in).
        let fabrics = vec![
            vec![unit(0.0), unit(0.05), unit(0.9)],
            vec![unit(1.2), unit(1.25)],
            vec![unit(3.0)],
        ];
        let left = left_out(&fabrics, 2, false, None);
        // Three folds: fold 0 leaves out press 0 of every fabric (fabric 2
        // then has no entry, and its press is not decided); fold 1 press 1;
        // fold 2 press 2 (fabric 0's stray press).
        let got: Vec<(usize, usize, usize)> = left
            .iter()
            .map(|l| (l.fabric, l.press, l.decided))
            .collect();
        assert_eq!(
            got,
            vec![(0, 0, 0), (1, 0, 1), (0, 1, 0), (1, 1, 1), (0, 2, 1)]
        );
        // Its own distances are the calibration's.
        let mut own: Vec<f32> = left.iter().map(|l| l.own_distance).collect();
        own.sort_by(f32::total_cmp);
        assert_eq!(own, press_distances(&fabrics, 2, false, None));
        let check = SelfCheck::of(&left);
        assert_eq!((check.presses, check.right), (5, 4));
        assert_eq!(check.confusions, vec![(0, 1, 1)]);
        // With exemplars the stray press is still nearer fabric 1's presses
        // (0.3 rad) than fabric 0's (0.85 rad).
        let check = SelfCheck::of(&left_out(&fabrics, 2, true, None));
        assert_eq!(check.confusions, vec![(0, 1, 1)]);
        // Presses that all look the same tell nothing apart: a tie is
        // another fabric's.
        let same = vec![vec![unit(0.0); 2], vec![unit(0.0); 2]];
        let check = SelfCheck::of(&left_out(&same, 2, true, None));
        assert_eq!((check.presses, check.right), (4, 0));
        // A press of the wrong dimension is skipped, and the others keep
        // their positions.
        let odd = vec![
            vec![vec![1.0, 0.0, 0.0], unit(0.0), unit(0.1)],
            vec![unit(2.0), unit(2.1)],
        ];
        let presses: Vec<(usize, usize)> = left_out(&odd, 2, false, None)
            .iter()
            .map(|l| (l.fabric, l.press))
            .collect();
        assert_eq!(presses, vec![(0, 1), (1, 0), (0, 2), (1, 1)]);
        // Confusions are ordered by count, then by fabric.
        let l = |fabric, decided| LeftOut {
            fabric,
            press: 0,
            decided,
            own_distance: 0.1,
        };
        let check = SelfCheck::of(&[l(2, 0), l(1, 0), l(1, 0), l(0, 0), l(0, 2)]);
        assert_eq!(check.confusions, vec![(1, 0, 2), (0, 2, 1), (2, 0, 1)]);
        assert_eq!((check.presses, check.right), (5, 1));
    }

    #[test]
    fn two_self_checks_are_compared_press_by_press() {
        let l = |fabric, press, right: bool| LeftOut {
            fabric,
            press,
            decided: if right { fabric } else { fabric + 1 },
            own_distance: 0.1,
        };
        // 71 presses both decided; the second right on 4 the first missed,
        // the first on none the second missed: 4 / 71 = 5.6 points, two
        // standard errors 5.5: ahead. With 3 it is not (4.2 against 4.8).
        let first: Vec<LeftOut> = (0..71).map(|i| l(i % 12, i / 12, i >= 4)).collect();
        let mut second: Vec<LeftOut> = (0..71).map(|i| l(i % 12, i / 12, true)).collect();
        // A press only one of them decided does not count.
        second.push(l(0, 99, true));
        let p = Paired::of(&first, &second);
        assert_eq!(
            p,
            Paired {
                presses: 71,
                first_only: 0,
                second_only: 4
            }
        );
        assert!(p.second_ahead());
        let three: Vec<LeftOut> = (0..71).map(|i| l(i % 12, i / 12, i >= 3)).collect();
        assert!(!Paired::of(&three, &second).second_ahead());
        // The other way round, or level: never ahead.
        assert!(!Paired::of(&second, &first).second_ahead());
        assert!(!Paired::of(&first, &first).second_ahead());
        assert!(!Paired::of(&[], &first).second_ahead());
        // Wins on both sides weigh against each other: 10 against 4 of 71
        // is 8.5 points, two standard errors 10.3.
        let mixed: Vec<LeftOut> = (0..71)
            .map(|i| l(i % 12, i / 12, !(10..20).contains(&i)))
            .collect();
        let p = Paired::of(&mixed, &first);
        assert_eq!((p.first_only, p.second_only), (4, 10));
        assert!(!p.second_ahead());
    }

    #[test]
    fn the_calibrated_distance_is_a_nearest_rank_quantile() {
        let d: Vec<f32> = (1..=20).map(|i| i as f32 / 100.0).collect();
        assert_eq!(calibrated_distance(&d, 0.95), Some(0.19));
        assert_eq!(calibrated_distance(&d, 1.0), Some(0.2));
        assert_eq!(calibrated_distance(&d, 0.5), Some(0.1));
        assert_eq!(calibrated_distance(&d, 0.001), Some(0.01));
        assert_eq!(calibrated_distance(&d, 0.0), None);
        assert_eq!(calibrated_distance(&d, 1.5), None);
        assert_eq!(calibrated_distance(&d, f32::NAN), None);
        assert_eq!(calibrated_distance(&d[..3], 0.95), None);
        assert_eq!(calibrated_distance(&[0.0; 8], 0.95), None);
    }

    #[test]
    fn quantiles_parse_within_zero_to_one() {
        assert_eq!(parse_quantile("0.9"), Ok(0.9));
        assert_eq!(parse_quantile("1"), Ok(1.0));
        for bad in ["0", "-0.5", "1.01", "NaN", "x", ""] {
            assert!(parse_quantile(bad).is_err(), "{bad}");
        }
    }
}
