//! Building an index from per-textile embeddings.

use crate::map::{self, MapLayout};
use crate::select::{self, SelectionMethod};
use crate::vecmath::{l2_normalise, normalised_mean};
use crate::{Entry, Index, IndexError, Metric, RollerLayout};

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
    /// builder's `keep_exemplars` is off, and what its metric learns from.
    pub exemplars: Vec<Vec<f32>>,
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
    /// Learn a within-fabric metric from the records' per-press embeddings
    /// with this shrinkage ([`Metric::within_fabric`]); None (the default):
    /// plain cosine distance. Without two presses of some fabric there is
    /// nothing to learn and the index has no metric.
    pub metric_shrinkage: Option<f32>,
}

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
            metric_shrinkage: None,
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
            .find(|v| v.len() != self.dim)
        {
            return Err(IndexError::Invalid(format!(
                "textile {}: embedding of dimension {}, expected {}",
                record.id,
                v.len(),
                self.dim
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
        let dim = self.dim;
        let metric = match self.metric_shrinkage {
            Some(a) if !(0.0..=1.0).contains(&a) => {
                return Err(IndexError::Invalid(format!(
                    "metric shrinkage {a} is outside 0..=1"
                )))
            }
            Some(a) => {
                let presses: Vec<Vec<Vec<f32>>> =
                    self.records.iter().map(|r| r.exemplars.clone()).collect();
                Metric::within_fabric(&presses, dim, a)
            }
            None => None,
        };
        // Every vector in the metric's space (normalised either way).
        let map_in = |v: &[f32]| match &metric {
            Some(m) if v.len() == dim => m.apply(v),
            _ => {
                let mut v = v.to_vec();
                l2_normalise(&mut v);
                v
            }
        };
        let keep_exemplars = self.keep_exemplars;
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
        };
        for (e, p) in index.entries.iter_mut().zip(xy) {
            e.map_xy = [p[0], p[1]];
        }
        index.validate()?;
        Ok(index)
    }
}
