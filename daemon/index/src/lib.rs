//! The textile index both peers hold.
//!
//! An [`Index`] names the encoder it was built for (hash of the ONNX file),
//! holds one L2-normalised centroid (and optional exemplars) per textile with
//! its metadata and 2D map position, and the roller layout: which textile sits
//! on which slot. Peers compare [`Index::fingerprint`] when they connect.
//!
//! An index built from several presses per fabric may carry a [`Metric`]
//! learned from them (within-fabric whitening, [`metric`]): then its vectors
//! live in the metric's space and every query method maps the query there
//! first, so callers always pass encoder embeddings. It may also carry the
//! distance beyond which a press is of a textile it does not know,
//! calibrated on those presses ([`Index::unknown`]).
//!
//! Pure: no I/O except [`Index::read`] / [`Index::write`], which write
//! atomically and reject truncated, corrupt or foreign files with a clear error.
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod build;
mod file;
pub mod map;
pub mod metric;
pub mod select;
pub mod vecmath;

pub use build::{IndexBuilder, TextileRecord};
pub use file::{from_bytes, to_bytes, IndexError, FORMAT_VERSION, MAGIC};
pub use map::MapLayout;
pub use metric::Metric;
pub use select::{Coverage, SelectionMethod};
// `Features` and `LBP_DIM` are defined below.
pub use vecmath::{distance, l2_normalise};

use serde::{Deserialize, Serialize};

/// One textile known to the index.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Entry {
    /// Catalogue id (`T001`, `U07`, or a user's own label).
    pub id: String,
    /// Human-readable name.
    pub name: String,
    /// In the training book (seen) or not.
    pub seen: bool,
    /// Structure family (plain, twill, ...), free text.
    pub structure: String,
    /// Ground-truth tactile attributes (name, value in 0..1), if known.
    pub attributes: Vec<(String, f32)>,
    /// L2-normalised mean embedding (in the index's metric space when it
    /// has a metric).
    pub centroid: Vec<f32>,
    /// Optional L2-normalised per-press exemplars (same space).
    pub exemplars: Vec<Vec<f32>>,
    /// Position on the 2D map.
    pub map_xy: [f32; 2],
}

/// Which textile sits on which slot of the roller.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RollerLayout {
    /// How the slots were chosen.
    pub method: SelectionMethod,
    /// Entry index carried by each slot, slot 0 first (clockwise order).
    pub slots: Vec<usize>,
    /// For every entry, the slot whose textile is nearest in latent space.
    pub entry_slot: Vec<usize>,
}

impl RollerLayout {
    /// Number of slots on the wheel.
    pub fn n(&self) -> usize {
        self.slots.len()
    }
}

/// The index file's content.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Index {
    /// Hex SHA-256 of the ONNX encoder the embeddings come from.
    pub encoder_hash: String,
    /// Encoder architecture label (from the model's metadata).
    pub encoder_arch: String,
    /// Embedding dimension.
    pub dim: usize,
    /// Textile catalogue version the entries came from (0 if user-recorded).
    pub catalogue_version: u32,
    /// The textiles.
    pub entries: Vec<Entry>,
    /// The roller.
    pub roller: RollerLayout,
    /// The 2D map.
    pub map: MapLayout,
    /// The distance learned from the index's presses, if any (file format
    /// version 2; encoded after the rest, see `file.rs`).
    #[serde(skip)]
    pub metric: Option<Metric>,
    /// The distance beyond which a press is of a textile the index does not
    /// know, calibrated on the index's own presses
    /// ([`IndexBuilder::unknown_quantile`]); None: the decider's fixed
    /// default. File format version 3, encoded after the rest.
    #[serde(skip)]
    pub unknown: Option<UnknownDistance>,
    /// What a query is made of ([`Features`]); the encoder's embedding
    /// alone unless the index says otherwise (file format version 4,
    /// encoded after the rest).
    #[serde(skip)]
    pub features: Features,
    /// The sensor profile its presses came from (`gelsight-mini`, `uvc`),
    /// or `mixed:<a>+<b>` when built from several on purpose; None: a
    /// DIGIT (every index made before profiles, and the simulator's).
    /// Presses of another profile are refused against it unless it is
    /// mixed (file format version 5, encoded after the rest).
    #[serde(skip)]
    pub sensor: Option<String>,
}

/// The profile family an index holding `sensor` ([`Index::sensor`]) is
/// of, for messages: `digit` when it names none.
pub fn sensor_family(sensor: Option<&str>) -> &str {
    sensor.unwrap_or("digit")
}

impl Index {
    /// Refuse queries from a sensor of `profile` (by name) unless the
    /// index's presses came from the same profile or it was built mixed.
    pub fn check_sensor(&self, profile: &str) -> Result<(), String> {
        let own = sensor_family(self.sensor.as_deref());
        if own == profile || own.starts_with("mixed:") {
            return Ok(());
        }
        Err(format!(
            "the index was built from presses of a {own} sensor, and these frames come from a {profile}: a fabric looks different through another sensor's gel, light and camera; build an index from presses of this sensor (`telextilesd index build --presses`), or one from both with --mix-sensors"
        ))
    }
}

/// What an index's query vectors are made of, which every daemon holding
/// the index computes the same way (the sender streams them as latents):
/// the encoder's embedding alone, or beside it the texture features of
/// the same preprocessed frame minus its reference
/// (`telextiles_sensing::texture`), each part of unit length and the whole
/// scaled to unit length.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub enum Features {
    /// The encoder's embedding alone.
    #[default]
    Encoder,
    /// The encoder's embedding, then rotation-invariant LBP histograms
    /// ([`LBP_DIM`] values).
    EncoderLbp,
    /// The encoder's embedding, then rotation-invariant Gabor energies
    /// ([`GABOR_DIM`] values).
    EncoderGabor,
    /// The encoder's embedding, the LBP histograms, then the Gabor
    /// energies.
    EncoderLbpGabor,
}

/// Values the LBP texture features add to a query
/// (`telextiles_sensing::texture::LBP_DIM`, which is tested equal).
pub const LBP_DIM: usize = 28;
/// Values the Gabor energies add to a query
/// (`telextiles_sensing::gabor::GABOR_DIM`, which is tested equal).
pub const GABOR_DIM: usize = 9;

impl Features {
    /// Every kind, simplest first.
    pub const ALL: [Features; 4] = [
        Features::Encoder,
        Features::EncoderLbp,
        Features::EncoderGabor,
        Features::EncoderLbpGabor,
    ];

    /// Whether the LBP histograms are a part, and the Gabor energies: in
    /// that order after the encoder's embedding.
    pub fn parts(self) -> (bool, bool) {
        match self {
            Features::Encoder => (false, false),
            Features::EncoderLbp => (true, false),
            Features::EncoderGabor => (false, true),
            Features::EncoderLbpGabor => (true, true),
        }
    }

    /// Values added to the encoder's embedding.
    pub fn extra_dim(self) -> usize {
        let (lbp, gabor) = self.parts();
        usize::from(lbp) * LBP_DIM + usize::from(gabor) * GABOR_DIM
    }

    /// In words.
    pub fn label(self) -> &'static str {
        match self {
            Features::Encoder => "encoder",
            Features::EncoderLbp => "encoder + LBP",
            Features::EncoderGabor => "encoder + Gabor",
            Features::EncoderLbpGabor => "encoder + LBP + Gabor",
        }
    }
}

/// An unknown-textile distance calibrated on an index's presses.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnknownDistance {
    /// Beyond this distance from every textile (in the index's space, after
    /// the metric) a press is of a textile the index does not have.
    pub distance: f32,
    /// The share of the index's own presses, each measured with its fold
    /// left out, within it ([`build::press_distances`]).
    pub quantile: f32,
    /// How many left-out press distances it was calibrated on.
    pub presses: u32,
}

/// Result of a nearest-textile query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest {
    /// Entry index of the nearest textile.
    pub best: usize,
    /// Euclidean distance between unit vectors (0..=2).
    pub best_dist: f32,
    /// Entry index of the runner-up, if the index has two or more entries.
    pub second: Option<usize>,
    /// Distance of the runner-up (`f32::INFINITY` if none).
    pub second_dist: f32,
}

impl Nearest {
    /// Distance margin between the runner-up and the best.
    pub fn margin(&self) -> f32 {
        self.second_dist - self.best_dist
    }
}

impl Index {
    /// A query (an encoder embedding, L2-normalised) in the space of the
    /// index's vectors: through the metric when there is one, else as is.
    /// The query must be of the index's dimension.
    pub fn project<'a>(&self, q: &'a [f32]) -> std::borrow::Cow<'a, [f32]> {
        match &self.metric {
            Some(m) => std::borrow::Cow::Owned(m.apply(q)),
            None => std::borrow::Cow::Borrowed(q),
        }
    }

    /// An encoder embedding whose query lands on `v`, a vector of the
    /// index's space (a centroid, an exemplar): `v` itself without a metric,
    /// its preimage with one (None if there is none).
    pub fn query_for(&self, v: &[f32]) -> Option<Vec<f32>> {
        match &self.metric {
            Some(m) => m.preimage(v),
            None => (v.len() == self.dim).then(|| v.to_vec()),
        }
    }

    /// Distance from an L2-normalised query to entry `i`: the nearest of its
    /// centroid and exemplars (after the metric, if any).
    pub fn entry_distance(&self, i: usize, q: &[f32]) -> f32 {
        match &self.metric {
            Some(m) => self.projected_distance(i, &m.apply(q)),
            None => self.projected_distance(i, q),
        }
    }

    fn projected_distance(&self, i: usize, q: &[f32]) -> f32 {
        let e = &self.entries[i];
        let mut d = distance(&e.centroid, q);
        for x in &e.exemplars {
            d = d.min(distance(x, q));
        }
        d
    }

    /// Nearest and second-nearest textile to an L2-normalised query; None
    /// for a query that is not of the index's dimension or not finite
    /// (whatever a peer sends, no answer rather than a panic).
    pub fn nearest(&self, q: &[f32]) -> Option<Nearest> {
        if q.len() != self.dim || self.entries.is_empty() || q.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let q = self.project(q);
        let mut best = (usize::MAX, f32::INFINITY);
        let mut second = (usize::MAX, f32::INFINITY);
        for i in 0..self.entries.len() {
            let d = self.projected_distance(i, &q);
            if d < best.1 {
                second = best;
                best = (i, d);
            } else if d < second.1 {
                second = (i, d);
            }
        }
        (best.0 != usize::MAX).then_some(Nearest {
            best: best.0,
            best_dist: best.1,
            second: (second.0 != usize::MAX).then_some(second.0),
            second_dist: second.1,
        })
    }

    /// The `k` nearest entries to a query, nearest first, with distances.
    pub fn k_nearest(&self, q: &[f32], k: usize) -> Vec<(usize, f32)> {
        if q.len() != self.dim {
            return Vec::new();
        }
        let q = self.project(q);
        let mut all: Vec<(usize, f32)> = (0..self.entries.len())
            .map(|i| (i, self.projected_distance(i, &q)))
            .collect();
        all.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
        all.truncate(k);
        all
    }

    /// The calibrated unknown-textile distance, if the index has one.
    pub fn unknown_distance(&self) -> Option<f32> {
        self.unknown.map(|u| u.distance)
    }

    /// Roller slot whose textile is nearest to entry `entry`.
    pub fn slot_of_entry(&self, entry: usize) -> usize {
        self.roller.entry_slot[entry]
    }

    /// Entry index of a textile id.
    pub fn entry_by_id(&self, id: &str) -> Option<usize> {
        self.entries.iter().position(|e| e.id == id)
    }

    /// Place a query on the 2D map from its nearest textiles.
    pub fn place_on_map(&self, q: &[f32]) -> [f32; 2] {
        let near = self.k_nearest(q, self.map.place_k.max(1));
        map::interpolate(&near, |i| self.entries[i].map_xy)
    }

    /// Hex content hash that peers compare at connection time.
    pub fn fingerprint(&self) -> String {
        file::fingerprint(self)
    }

    /// Check internal consistency (dimensions, slot and entry references).
    pub fn validate(&self) -> Result<(), IndexError> {
        let bad = |m: String| Err(IndexError::Invalid(m));
        if self.entries.is_empty() {
            return bad("the index has no textiles".into());
        }
        if let Some(s) = &self.sensor {
            if s.is_empty() || s.len() > 64 || s == "digit" {
                return bad(format!(
                    "sensor {s:?} is not a sensor profile name (a DIGIT's index names none)"
                ));
            }
        }
        if self.dim <= self.features.extra_dim() {
            return bad(format!(
                "embedding dimension {} leaves nothing of the encoder's beside {} features",
                self.dim,
                self.features.label()
            ));
        }
        for e in &self.entries {
            if e.centroid.len() != self.dim || e.exemplars.iter().any(|x| x.len() != self.dim) {
                return bad(format!(
                    "textile {} has an embedding of the wrong dimension (index dim {})",
                    e.id, self.dim
                ));
            }
            if e.centroid
                .iter()
                .chain(e.exemplars.iter().flatten())
                .any(|v| !v.is_finite())
            {
                return bad(format!("textile {} has a non-finite embedding", e.id));
            }
        }
        if let Some(u) = self.unknown {
            // Distances between unit vectors lie in 0..=2.
            let t = u.distance;
            if !(t.is_finite() && t > 0.0 && t <= 2.0) {
                return bad(format!(
                    "the unknown-textile distance {t} is outside (0, 2]"
                ));
            }
            if !build::is_quantile(u.quantile) {
                return bad(format!(
                    "the unknown-textile distance's quantile {} is outside (0, 1]",
                    u.quantile
                ));
            }
        }
        if let Some(m) = &self.metric {
            if !m.is_valid(self.dim) {
                return bad(format!(
                    "the metric is not a finite {0} x {0} map",
                    self.dim
                ));
            }
        }
        let n = self.entries.len();
        if self.roller.slots.is_empty() {
            return bad("the roller has no slots".into());
        }
        if let Some(s) = self.roller.slots.iter().find(|&&s| s >= n) {
            return bad(format!(
                "roller slot refers to textile #{s}, but there are {n}"
            ));
        }
        let mut seen = self.roller.slots.clone();
        seen.sort_unstable();
        seen.dedup();
        if seen.len() != self.roller.slots.len() {
            return bad("a textile appears on two roller slots".into());
        }
        if self.roller.entry_slot.len() != n
            || self.roller.entry_slot.iter().any(|&s| s >= self.roller.n())
        {
            return bad("the textile-to-slot table does not match the roller".into());
        }
        Ok(())
    }
}
