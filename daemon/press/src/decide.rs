//! Decisions: which textile is being touched, and which roller slot shows it.
//!
//! Within a press the decider keeps the running mean of the L2-normalised
//! embeddings (re-normalised) and looks it up in the index. Each frame
//! counts by its contact depth relative to the press's deepest frame so far
//! (`depth_power`, [`PressMean`]): during the ramp the newest, deepest
//! frame leads, in the hold every frame counts about the same. The first
//! decision is made once embeddings have come in for `min_ms` and the same
//! textile has been nearest for `confirm_ms` (and at least two frames) in a
//! row, or, sooner, on the second frame of its run when it is nearer than
//! the runner-up by `commit_margin` (a clear leader); with
//! `commit_weight` set (off by default), either waits until one of the
//! press's frames has touched that deep (or `commit_weight_ms` has passed).
//! After that the decision switches only when another textile is nearer
//! than the current one by at least `switch_margin` for `switch_ms` (and at
//! least two frames) in a row (hysteresis: no flip-flop between two close
//! textiles); each change within a press multiplies the time the next
//! challenger must lead by `switch_backoff` (a decider that has changed its
//! mind once needs more evidence to change it again). Durations, not frame
//! counts, so a 25 fps sensor decides as soon as a 60 fps one; timestamps
//! are the frames' own. A textile further than the unknown-textile distance
//! from everything (the index's own, calibrated on its presses, or
//! `unknown_distance`) is reported as its nearest known textile with
//! `unknown = true`.
//!
//! The press's final decision ([`Decider::press_end`]) is the textile
//! nearest the whole press's mean, whatever the switching rule held last:
//! the receiving daemon decides a press's end the same way from the
//! sender's final latent.
//!
//! Confidence is `(d2 - d1) / d2` in 0..=1, where `d1` is the distance to
//! the decided textile and `d2` to the nearest other one: 0 for a tie, 1 for
//! an exact match.
//!
//! Pure and deterministic: no clocks (timestamps are passed in), no I/O, and
//! nothing allocated per frame.

/// Nearest and second-nearest entry for a query.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Nearest2 {
    /// Nearest entry.
    pub best: usize,
    /// Its distance.
    pub best_dist: f32,
    /// Runner-up, if the index has two or more entries.
    pub second: Option<usize>,
    /// Its distance (`f32::INFINITY` if none).
    pub second_dist: f32,
}

/// What the decider needs from a textile index. Implemented for
/// [`telextiles_index::Index`] and for the in-memory [`FlatIndex`].
pub trait TextileIndex {
    /// Embedding dimension.
    fn dim(&self) -> usize;
    /// Number of textiles.
    fn len(&self) -> usize;
    /// Whether the index has no textiles.
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Textile id of an entry.
    fn id(&self, entry: usize) -> &str;
    /// Euclidean distance from an L2-normalised query to an entry.
    fn distance(&self, entry: usize, q: &[f32]) -> f32;
    /// Nearest roller slot for an entry.
    fn slot_of(&self, entry: usize) -> usize;
    /// The index's own unknown-textile distance (calibrated on its presses),
    /// if it has one; the decider's [`DecideConfig::unknown_distance`]
    /// otherwise.
    fn unknown_distance(&self) -> Option<f32> {
        None
    }
    /// What a query is made of (the encoder's embedding alone unless the
    /// index says otherwise): `telextiles_sensing::encoder::Encoder::set_features`.
    fn features(&self) -> telextiles_index::Features {
        telextiles_index::Features::Encoder
    }
    /// Nearest and second-nearest entries; None for a query of another
    /// dimension, a non-finite one, or an empty index.
    fn nearest2(&self, q: &[f32]) -> Option<Nearest2> {
        if q.len() != self.dim() || q.iter().any(|v| !v.is_finite()) {
            return None;
        }
        let mut best = (usize::MAX, f32::INFINITY);
        let mut second = (usize::MAX, f32::INFINITY);
        for i in 0..self.len() {
            let d = self.distance(i, q);
            if d < best.1 {
                second = best;
                best = (i, d);
            } else if d < second.1 {
                second = (i, d);
            }
        }
        (best.0 != usize::MAX).then_some(Nearest2 {
            best: best.0,
            best_dist: best.1,
            second: (second.0 != usize::MAX).then_some(second.0),
            second_dist: second.1,
        })
    }
}

impl TextileIndex for telextiles_index::Index {
    fn dim(&self) -> usize {
        self.dim
    }
    fn len(&self) -> usize {
        self.entries.len()
    }
    fn id(&self, entry: usize) -> &str {
        &self.entries[entry].id
    }
    fn distance(&self, entry: usize, q: &[f32]) -> f32 {
        self.entry_distance(entry, q)
    }
    fn slot_of(&self, entry: usize) -> usize {
        self.slot_of_entry(entry)
    }
    fn unknown_distance(&self) -> Option<f32> {
        telextiles_index::Index::unknown_distance(self)
    }
    fn features(&self) -> telextiles_index::Features {
        self.features
    }
    fn nearest2(&self, q: &[f32]) -> Option<Nearest2> {
        self.nearest(q).map(|n| Nearest2 {
            best: n.best,
            best_dist: n.best_dist,
            second: n.second,
            second_dist: n.second_dist,
        })
    }
}

/// A minimal in-memory index: one L2-normalised centroid per textile and a
/// slot for each (tests, benchmarks, and indexes built on the fly).
#[derive(Clone, Debug, PartialEq)]
pub struct FlatIndex {
    dim: usize,
    ids: Vec<String>,
    centroids: Vec<Vec<f32>>,
    slots: Vec<usize>,
}

impl FlatIndex {
    /// From `(id, embeddings)` pairs: each textile's centroid is the
    /// normalised mean of its (normalised) embeddings; slot = position.
    pub fn from_embeddings(textiles: &[(String, Vec<Vec<f32>>)]) -> Result<FlatIndex, String> {
        let dim = textiles
            .first()
            .and_then(|(_, e)| e.first())
            .map(|e| e.len())
            .ok_or("no embeddings to build an index from")?;
        let mut ids = Vec::new();
        let mut centroids = Vec::new();
        for (id, embs) in textiles {
            if embs.is_empty() || embs.iter().any(|e| e.len() != dim) {
                return Err(format!("textile {id}: no embeddings or wrong dimension"));
            }
            let mut c = vec![0f32; dim];
            for e in embs {
                let n = norm(e).max(1e-12);
                for (a, v) in c.iter_mut().zip(e) {
                    *a += v / n;
                }
            }
            normalise(&mut c);
            ids.push(id.clone());
            centroids.push(c);
        }
        let slots = (0..ids.len()).collect();
        Ok(FlatIndex {
            dim,
            ids,
            centroids,
            slots,
        })
    }
    /// Override the slot of each entry.
    pub fn with_slots(mut self, slots: Vec<usize>) -> Result<FlatIndex, String> {
        if slots.len() != self.ids.len() {
            return Err(format!(
                "{} slots for {} textiles",
                slots.len(),
                self.ids.len()
            ));
        }
        self.slots = slots;
        Ok(self)
    }
    /// Entry index of an id.
    pub fn entry_by_id(&self, id: &str) -> Option<usize> {
        self.ids.iter().position(|i| i == id)
    }
    /// The (unit) centroid of an entry.
    pub fn centroid(&self, entry: usize) -> &[f32] {
        &self.centroids[entry]
    }
}

impl TextileIndex for FlatIndex {
    fn dim(&self) -> usize {
        self.dim
    }
    fn len(&self) -> usize {
        self.ids.len()
    }
    fn id(&self, entry: usize) -> &str {
        &self.ids[entry]
    }
    fn distance(&self, entry: usize, q: &[f32]) -> f32 {
        self.centroids[entry]
            .iter()
            .zip(q)
            .map(|(a, b)| (a - b) * (a - b))
            .sum::<f32>()
            .sqrt()
    }
    fn slot_of(&self, entry: usize) -> usize {
        self.slots[entry]
    }
}

fn norm(v: &[f32]) -> f32 {
    v.iter().map(|x| x * x).sum::<f32>().sqrt()
}

use telextiles_index::vecmath::l2_normalise as normalise;

/// Contact depth (contact score, DN) at which a frame's weight reaches
/// 1 - 1/e.
pub const WEIGHT_DEPTH_DN: f32 = 4.0;

/// The weight of a frame in a press's running mean, from its contact depth
/// (the contact detector's score, mean |frame - reference| in DN):
/// `1 - exp(-score / WEIGHT_DEPTH_DN)`, in [0.001, 1]. Frames of the ramp,
/// where the fabric has barely touched the gel (a DN or two), count less
/// than frames in full contact (the decider raises it to its `depth_power`
/// relative to the press's largest weight so far); it saturates, so a frame
/// far from the reference (a dropped-out or overexposed frame) counts no
/// more than one in full contact. Measured in `docs/benchmarks.md` ("Simulator v2",
/// time to decision). The same function weights frames locally
/// (`telextiles_sensing::pipeline::Pipeline`), in the lab's decision curve and, as the
/// length of each streamed latent, on the receiving daemon.
pub fn contact_weight(score: f32) -> f32 {
    if score.is_finite() {
        (1.0 - (-score.max(0.0) / WEIGHT_DEPTH_DN).exp()).clamp(1e-3, 1.0)
    } else {
        1e-3
    }
}

/// The length of `emb` (dimension `dim`) if it can join a press's mean
/// with contact weight `weight`: finite and of non-zero length, the weight
/// finite and positive.
fn acceptable_norm(emb: &[f32], dim: usize, weight: f32) -> Option<f32> {
    if emb.len() != dim
        || emb.iter().any(|v| !v.is_finite())
        || !(weight.is_finite() && weight > 0.0)
    {
        return None;
    }
    let n = norm(emb);
    (n > 0.0 && n.is_finite()).then_some(n)
}

/// A press's running sum of embeddings, each counted by its contact weight
/// relative to the deepest frame so far: a frame of weight `w`
/// ([`contact_weight`]) counts `(w / w_max)^power`. Its direction is that
/// of `Σ w_i^power · e_i / |e_i|`; when a frame is the deepest yet the sum so
/// far is scaled down by `(w_max / w)^power` and the frame counts 1, so the
/// sum neither over- nor underflows whatever the weights' scale. The
/// decider's running mean, the sender's final latent and the lab's decision
/// curve are all this one type.
#[derive(Clone, Debug, PartialEq)]
pub struct PressMean {
    sum: Vec<f32>,
    max_weight: f32,
    power: i32,
}

impl PressMean {
    /// An empty mean of dimension `dim` with depth power `power` (see
    /// [`DecideConfig::depth_power`]; above 64 it is 64, where every frame
    /// but the deepest already counts nothing in f32).
    pub fn new(dim: usize, power: u32) -> PressMean {
        PressMean {
            sum: vec![0.0; dim],
            max_weight: 0.0,
            power: power.min(64) as i32,
        }
    }

    /// Forget every frame (a new press).
    pub fn clear(&mut self) {
        self.sum.iter_mut().for_each(|x| *x = 0.0);
        self.max_weight = 0.0;
    }

    /// Add `emb` (it counts by its direction) with contact weight `weight`.
    /// False, and nothing changes, for a vector of another dimension, with
    /// non-finite values or of zero length, or a weight that is not finite
    /// and positive.
    pub fn add(&mut self, emb: &[f32], weight: f32) -> bool {
        let Some(n) = acceptable_norm(emb, self.sum.len(), weight) else {
            return false;
        };
        let rel = if weight > self.max_weight {
            let k = (self.max_weight / weight).powi(self.power);
            self.sum.iter_mut().for_each(|s| *s *= k);
            self.max_weight = weight;
            1.0
        } else {
            (weight / self.max_weight).powi(self.power)
        };
        for (s, v) in self.sum.iter_mut().zip(emb) {
            *s += rel * v / n;
        }
        true
    }

    /// The sum (not normalised; all zeros before the first frame).
    pub fn sum(&self) -> &[f32] {
        &self.sum
    }

    /// The largest contact weight of a frame added so far (0 before the
    /// first).
    pub fn max_weight(&self) -> f32 {
        self.max_weight
    }
}

/// Decider tuning.
#[derive(Clone, Debug, PartialEq)]
pub struct DecideConfig {
    /// Milliseconds of embeddings (from the press's first) before the
    /// first decision.
    pub min_ms: f32,
    /// Milliseconds the same textile must stay nearest for the first
    /// decision.
    pub confirm_ms: f32,
    /// A press's first decision commits as soon as its leader has led for
    /// two frames if the leader is nearer than the runner-up by at least
    /// this (the index's distance), without waiting `confirm_ms`.
    /// `f32::INFINITY`: always wait.
    pub commit_margin: f32,
    /// Distance lead a challenger needs over the current decision.
    pub switch_margin: f32,
    /// Milliseconds the challenger must lead by `switch_margin` for the
    /// first change of decision in a press.
    pub switch_ms: f32,
    /// Each change of decision within a press multiplies the time the next
    /// challenger must lead by this factor: the `k`-th change after the
    /// first decision waits `switch_ms * switch_backoff^(k-1)`. 1: every
    /// change waits `switch_ms`. Values below 1 (and NaN) count as 1; infinity
    /// allows one change per press.
    pub switch_backoff: f32,
    /// Beyond this distance the nearest known textile is flagged unknown,
    /// unless the index has its own ([`TextileIndex::unknown_distance`],
    /// calibrated on the presses it was built from).
    pub unknown_distance: f32,
    /// How steeply the running mean favours the press's deepest frames: a
    /// frame of weight `w` ([`contact_weight`]) counts `(w / w_max)^depth_power`,
    /// `w_max` the largest weight in the press so far. During the ramp the
    /// newest frame is the deepest and the shallow ones before it fade out;
    /// in the hold the weights saturate and every frame counts about the
    /// same; the release's shallow frames count little. 1: the weight as it
    /// is; 0: every frame the same.
    pub depth_power: u32,
    /// The first decision of a press waits until one of its frames has had
    /// at least this contact weight ([`contact_weight`] of its whole-frame
    /// depth), or until `commit_weight_ms` after the press's first
    /// embedding, whichever comes first: a press that has touched the gel
    /// in one place only (a tilted, hand-held one) is not decided from that
    /// place. The leader's run is counted meanwhile, so a clear leader
    /// commits on the frame the gate opens. 0: no wait.
    pub commit_weight: f32,
    /// The longest the first decision waits for `commit_weight` (ms after
    /// the press's first embedding); a light press that never gets that
    /// deep is decided then.
    pub commit_weight_ms: f32,
}

impl Default for DecideConfig {
    fn default() -> Self {
        DecideConfig {
            // The textile nearest the running mean from the first encoded
            // frame on, confirmed over 50 ms (4 frames at 60 fps): chosen
            // by the written rule on whole simulated presses, catalogue 1,
            // and checked on catalogue 2 (`telextiles-lab decider-timing`,
            // docs/benchmarks.md "When the decider commits"). 50 / 50
            // before.
            min_ms: 0.0,
            confirm_ms: 50.0,
            // ... unless the leader is nearer than the runner-up by 0.08
            // on two frames in a row: then at once (16 ms at 60 fps).
            // Chosen by the same rule over both catalogues, where it
            // costs no first decision and no switch
            // (`telextiles-lab decider-timing`, docs/benchmarks.md "An
            // early first decision when the leader is clear"). Never
            // before (INFINITY).
            commit_margin: 0.08,
            // 8 frames at 60 fps for the first change of a press, four
            // times as long for each later one: the written rule over both
            // catalogues (`telextiles-lab decider-switch`, docs/benchmarks.md
            // "A switching rule that backs off"). 1 (no backoff) before.
            switch_margin: 0.02,
            switch_ms: 117.0,
            switch_backoff: 4.0,
            unknown_distance: 0.5,
            // Chosen on catalogue 1's held-out people, checked on
            // catalogue 2 (docs/benchmarks.md, "Deciding from the ramp").
            depth_power: 8,
            commit_weight: 0.0,
            commit_weight_ms: 0.0,
        }
    }
}

/// The current decision.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Decision {
    /// Index entry decided.
    pub entry: usize,
    /// Its roller slot.
    pub slot: usize,
    /// Distance from the press's mean embedding.
    pub distance: f32,
    /// Distance to the nearest other textile minus `distance` (negative while
    /// a challenger leads but has not yet taken over).
    pub margin: f32,
    /// `(d2 - d1) / d2`, clamped to 0..=1.
    pub confidence: f32,
    /// Further than the unknown-textile distance (the index's own, or
    /// `unknown_distance`) from every known textile.
    pub unknown: bool,
    /// When this decision was first made (frame timestamp).
    pub since_us: u64,
}

/// Result of feeding one embedding.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DecideStep {
    /// The nearest entry to the running mean on this frame (before hysteresis).
    pub nearest: Nearest2,
    /// The decision after this frame, if one has been made.
    pub decision: Option<Decision>,
    /// Whether the decision was made or changed on this frame.
    pub changed: bool,
}

/// Summary of a finished press.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PressOutcome {
    /// Press start (contact) timestamp.
    pub start_us: u64,
    /// Press end timestamp.
    pub end_us: u64,
    /// Final decision: the textile nearest the whole press's mean (None
    /// only for a press with no embedding).
    pub decision: Option<Decision>,
    /// Timestamp of the first decision.
    pub first_decision_us: Option<u64>,
    /// Index entry of the first decision (where the roller went first;
    /// the final one's when the decision never changed).
    pub first_entry: Option<usize>,
    /// Timestamp of the last change of decision.
    pub stable_since_us: Option<u64>,
    /// How many times the decision changed after the first one (the
    /// press's end counts when its final textile is not the one held).
    pub switches: u32,
    /// Embeddings seen.
    pub frames: u32,
}

/// The decider (see the module docs).
#[derive(Clone, Debug)]
pub struct Decider {
    cfg: DecideConfig,
    sum: PressMean,
    mean: Vec<f32>,
    frames: u32,
    start_us: u64,
    /// Timestamp of the press's first embedding.
    first_us: Option<u64>,
    in_press: bool,
    current: Option<Decision>,
    /// Candidate entry, frames in its run, timestamp of the run's first.
    challenger: Option<(usize, u32, u64)>,
    first_decision_us: Option<u64>,
    first_entry: Option<usize>,
    switches: u32,
}

impl Decider {
    /// A decider for embeddings of dimension `dim`.
    pub fn new(cfg: DecideConfig, dim: usize) -> Decider {
        Decider {
            sum: PressMean::new(dim, cfg.depth_power),
            cfg,
            mean: vec![0.0; dim],
            frames: 0,
            start_us: 0,
            first_us: None,
            in_press: false,
            current: None,
            challenger: None,
            first_decision_us: None,
            first_entry: None,
            switches: 0,
        }
    }

    /// The configuration.
    pub fn config(&self) -> &DecideConfig {
        &self.cfg
    }

    /// The distance beyond which a decision against `index` is of a
    /// textile the index does not know: the index's own (calibrated on its
    /// presses), else [`DecideConfig::unknown_distance`].
    pub fn unknown_beyond<I: TextileIndex + ?Sized>(&self, index: &I) -> f32 {
        index
            .unknown_distance()
            .unwrap_or(self.cfg.unknown_distance)
    }

    /// Start a new press (forgets the previous one).
    pub fn press_start(&mut self, t_us: u64) {
        self.sum.clear();
        self.frames = 0;
        self.start_us = t_us;
        self.first_us = None;
        self.in_press = true;
        self.current = None;
        self.challenger = None;
        self.first_decision_us = None;
        self.first_entry = None;
        self.switches = 0;
    }

    /// Whether a press is in progress.
    pub fn in_press(&self) -> bool {
        self.in_press
    }

    /// The decision so far in this press.
    pub fn current(&self) -> Option<Decision> {
        self.current
    }

    /// Changes of decision so far in this press, after the first (the
    /// switching rule's; [`Decider::press_end`] may add the press's end).
    pub fn switches(&self) -> u32 {
        self.switches
    }

    /// The running mean (L2-normalised) of this press's embeddings.
    pub fn mean(&self) -> &[f32] {
        &self.mean
    }

    /// Feed one L2-normalised embedding taken at `t_us`: [`Decider::accumulate`],
    /// the index search, then [`Decider::decide`]. Outside a press (before
    /// [`Decider::press_start`]) nothing is decided. None for an embedding
    /// of the wrong dimension or with non-finite values: it is refused and
    /// changes nothing.
    pub fn on_embedding<I: TextileIndex + ?Sized>(
        &mut self,
        index: &I,
        t_us: u64,
        emb: &[f32],
    ) -> Option<DecideStep> {
        self.on_embedding_weighted(index, t_us, emb, 1.0)
    }

    /// [`Decider::on_embedding`] with the frame's weight in the running
    /// mean ([`contact_weight`] of its contact score): the ramp's shallow
    /// frames count less than the deep ones. None also for a weight that is
    /// not finite and positive.
    pub fn on_embedding_weighted<I: TextileIndex + ?Sized>(
        &mut self,
        index: &I,
        t_us: u64,
        emb: &[f32],
        weight: f32,
    ) -> Option<DecideStep> {
        if !(weight.is_finite() && weight > 0.0) {
            return None;
        }
        if !self.in_press {
            let nearest = index.nearest2(emb)?;
            return Some(DecideStep {
                nearest,
                decision: None,
                changed: false,
            });
        }
        self.accumulate_weighted(emb, weight)?;
        let nearest = index.nearest2(&self.mean)?;
        Some(self.decide(index, t_us, nearest))
    }

    /// Add an embedding to the press's running mean; returns the mean
    /// (L2-normalised). Outside a press the mean is returned unchanged.
    /// None (and nothing changes) for an embedding of the wrong dimension,
    /// with non-finite values, or of zero length.
    pub fn accumulate(&mut self, emb: &[f32]) -> Option<&[f32]> {
        self.accumulate_weighted(emb, 1.0)
    }

    /// [`Decider::accumulate`] with the frame's weight in the mean (see
    /// [`contact_weight`]); None (and nothing changes) also for a weight
    /// that is not finite and positive.
    pub fn accumulate_weighted(&mut self, emb: &[f32], weight: f32) -> Option<&[f32]> {
        if self.in_press {
            // `add` checks the embedding and the weight, once.
            if !self.sum.add(emb, weight) {
                return None;
            }
            self.frames += 1;
            self.mean.copy_from_slice(self.sum.sum());
            normalise(&mut self.mean);
        } else if acceptable_norm(emb, self.mean.len(), weight).is_none() {
            return None;
        }
        Some(&self.mean)
    }

    /// Apply the hysteresis rules given the index's answer for the current
    /// mean (`nearest = index.nearest2(self.mean())`).
    pub fn decide<I: TextileIndex + ?Sized>(
        &mut self,
        index: &I,
        t_us: u64,
        nearest: Nearest2,
    ) -> DecideStep {
        assert_eq!(index.dim(), self.mean.len(), "index dimension");
        let mut changed = false;
        let first = *self.first_us.get_or_insert(t_us);
        let ms = |a: u64, b: u64| a.saturating_sub(b) as f32 / 1000.0;
        if self.in_press && self.frames > 0 && ms(t_us, first) >= self.cfg.min_ms {
            match self.current {
                None => {
                    let (run, since) = self.bump(nearest.best, true, t_us);
                    let sure = nearest.second_dist - nearest.best_dist >= self.cfg.commit_margin;
                    let deep = self.sum.max_weight() >= self.cfg.commit_weight
                        || ms(t_us, first) >= self.cfg.commit_weight_ms;
                    if deep && run >= 2 && (sure || ms(t_us, since) >= self.cfg.confirm_ms) {
                        self.current = Some(self.make(index, nearest.best, t_us, &nearest));
                        self.first_decision_us = Some(t_us);
                        self.first_entry = Some(nearest.best);
                        self.challenger = None;
                        changed = true;
                    }
                }
                Some(cur) if nearest.best == cur.entry => self.challenger = None,
                Some(cur) => {
                    let d_cur = index.distance(cur.entry, &self.mean);
                    let leads = d_cur - nearest.best_dist >= self.cfg.switch_margin;
                    let (run, since) = self.bump(nearest.best, leads, t_us);
                    if run >= 2 && ms(t_us, since) >= self.switch_wait_ms() {
                        self.current = Some(self.make(index, nearest.best, t_us, &nearest));
                        self.challenger = None;
                        self.switches += 1;
                        changed = true;
                    }
                }
            }
            if !changed {
                if let Some(cur) = self.current {
                    let since = cur.since_us;
                    self.current = Some(self.make(index, cur.entry, since, &nearest));
                }
            }
        }
        DecideStep {
            nearest,
            decision: self.current,
            changed,
        }
    }

    /// How long (ms) a challenger must lead for the next change of
    /// decision: `switch_ms`, times `switch_backoff` per change made in
    /// this press.
    pub fn switch_wait_ms(&self) -> f32 {
        // Below 1 (or NaN) counts as 1; infinite: never a second change.
        let b = if self.cfg.switch_backoff >= 1.0 {
            self.cfg.switch_backoff
        } else {
            1.0
        };
        let w = self.cfg.switch_ms * b.powi(self.switches.min(64) as i32);
        if w.is_finite() {
            w
        } else {
            f32::MAX
        }
    }

    /// Count a run of frames for a challenger (reset when `counts` is false
    /// or the challenger changes). Returns the run's length in frames and
    /// the timestamp of its first frame.
    fn bump(&mut self, entry: usize, counts: bool, t_us: u64) -> (u32, u64) {
        if !counts {
            self.challenger = None;
            return (0, t_us);
        }
        let (run, since) = match self.challenger {
            Some((e, r, since)) if e == entry => (r + 1, since),
            _ => (1, t_us),
        };
        self.challenger = Some((entry, run, since));
        (run, since)
    }

    fn make<I: TextileIndex + ?Sized>(
        &self,
        index: &I,
        entry: usize,
        since_us: u64,
        n: &Nearest2,
    ) -> Decision {
        let d1 = if entry == n.best {
            n.best_dist
        } else {
            index.distance(entry, &self.mean)
        };
        let d2 = if entry == n.best {
            n.second_dist
        } else {
            n.best_dist
        };
        let margin = d2 - d1;
        let confidence = if d2.is_finite() && d2 > 0.0 {
            (margin / d2).clamp(0.0, 1.0)
        } else {
            1.0
        };
        Decision {
            entry,
            slot: index.slot_of(entry),
            distance: d1,
            margin: if margin.is_finite() { margin } else { f32::MAX },
            confidence,
            unknown: d1 > self.unknown_beyond(index),
            since_us,
        }
    }

    /// End the press; returns its outcome (None if no press was in
    /// progress). The press's final decision is the textile nearest the
    /// mean of the whole press, whatever the switching rule still held:
    /// the answer the receiving daemon gives from the sender's final
    /// latent, so `classify`, the lab and a live pair end every press
    /// alike. A final textile other than the one held counts as a change
    /// (made at `t_us`); a press that ended before its first decision is
    /// decided then, from every frame it had.
    pub fn press_end<I: TextileIndex + ?Sized>(
        &mut self,
        index: &I,
        t_us: u64,
    ) -> Option<PressOutcome> {
        if !self.in_press {
            return None;
        }
        self.in_press = false;
        let nearest = (self.frames > 0)
            .then(|| index.nearest2(&self.mean))
            .flatten();
        if let Some(n) = nearest {
            match self.current {
                Some(cur) if cur.entry == n.best => {
                    self.current = Some(self.make(index, cur.entry, cur.since_us, &n));
                }
                Some(_) => {
                    self.current = Some(self.make(index, n.best, t_us, &n));
                    self.switches += 1;
                }
                None => {
                    self.current = Some(self.make(index, n.best, t_us, &n));
                    self.first_decision_us = Some(t_us);
                    self.first_entry = Some(n.best);
                }
            }
        }
        Some(PressOutcome {
            start_us: self.start_us,
            end_us: t_us,
            decision: self.current,
            first_decision_us: self.first_decision_us,
            first_entry: self.first_entry,
            stable_since_us: self.current.map(|c| c.since_us),
            switches: self.switches,
            frames: self.frames,
        })
    }
}
