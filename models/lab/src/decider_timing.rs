//! The decider's timing rules measured on whole simulated presses
//! (`telextiles-lab decider-timing`, docs/benchmarks.md "When the decider
//! commits").
//!
//! The decision curve ([`crate::decision_curve::decision_curve`]) scores the
//! running mean of a press's first frames, with no contact detector and no
//! hysteresis: what a press *could* tell at a given time. The roller moves
//! on what the decider *commits* to. This study runs the daemon's own
//! per-frame path on every press, from its quiet frames before contact:
//! [`crate::recorded::Processor`] (the daemon's front end: contact
//! detector, the recording's reference, preprocessing, the ONNX encoder),
//! then the daemon's [`Decider`] against the textiles' centroids, once per
//! candidate pair of timing rules (`min_ms`, `confirm_ms`; the other rules
//! and the depth power as shipped), each with and without the run of
//! frames that starts a press encoded (`FrontEnd::set_encode_run`; one
//! pass with it, the candidates without it skip the run's rows). Time is counted from the press's true
//! first contact (the simulator's `contact_frame`), so the contact
//! detector's own delay is in every figure.
//!
//! For each candidate and each group of presses (jig, hand-held) it
//! reports: the share of presses whose *committed* decision is right at
//! each time after contact (no decision yet counts as not right), its mean
//! over the first 500 ms (the time a user feels the right fabric, as a
//! share of the first half second), the median time of the first
//! decision, how often that first decision is right, the share right at
//! the end of the window, and the changes of decision per 100 presses
//! (each one a roller move that was not needed). [`choose`] applies the
//! written rule.

use anyhow::{ensure, Context, Result};
use serde::{Deserialize, Serialize};

use telextiles_sensing::decide::{DecideConfig, Decider, FlatIndex, TextileIndex};

use crate::recorded::PressEmbedding;

/// Milliseconds after first contact at which the committed decisions are
/// tabled (the curve and its mean use every [`GRID_MS`]).
pub const TIMES_MS: [f64; 8] = [100.0, 133.0, 150.0, 167.0, 200.0, 250.0, 333.0, 500.0];

/// Step of the time grid of the curve, ms.
pub const GRID_MS: f64 = 5.0;

/// The committed-right curve is averaged over this much of a press, ms.
pub const MEAN_OVER_MS: f64 = 500.0;

/// How much of each press after first contact is rendered and decided
/// (ms): every press is scored on the same window, whatever its length.
pub const WINDOW_MS: f64 = 750.0;

/// Candidate `(min_ms, confirm_ms)` pairs; the first (50 / 50) is the
/// pair shipped before this study, the baseline of [`choose`]. At 60 fps
/// the rules act in whole frames: the confirmation needs a run of at least
/// two frames, so `confirm_ms` 16 commits on the second frame of a run, 33
/// on the third. The two longer confirmations (66 and 83 ms: five and six
/// frames) were added with the run encoding: with the run, they commit
/// 17 ms and 0 ms earlier than 0 / 50 without it, on more frames.
pub const PAIRS: [(f32, f32); 10] = [
    (50.0, 50.0),
    (33.0, 50.0),
    (0.0, 83.0),
    (0.0, 66.0),
    (0.0, 50.0),
    (33.0, 33.0),
    (17.0, 33.0),
    (0.0, 33.0),
    (17.0, 16.0),
    (0.0, 16.0),
];

/// Candidate switching rules `(switch_margin, switch_ms, switch_backoff)`,
/// scored at the shipped timing rules (`DecideConfig::default()`, the run
/// not encoded); the first is the rule shipped before this
/// study, the baseline of [`choose_switch`]. A challenger must be nearer
/// than the current decision by the margin (the index's distance,
/// Euclidean between unit vectors) for the time
/// (at least two frames) before the decision changes; each change within a
/// press multiplies the next one's time by the backoff. The last four (with
/// a backoff) were added after the first nine were scored: the first change
/// of a press (a correction, on catalogue 1) stays fast, the later ones (the
/// flicker between wrong textiles, on catalogue 2) wait.
pub const SWITCH_RULES: [(f32, f32, f32); 13] = [
    (0.02, 117.0, 1.0),
    (0.02, 233.0, 1.0),
    (0.02, 500.0, 1.0),
    (0.04, 117.0, 1.0),
    (0.04, 233.0, 1.0),
    (0.04, 500.0, 1.0),
    (0.08, 117.0, 1.0),
    (0.08, 233.0, 1.0),
    (0.08, 500.0, 1.0),
    (0.02, 117.0, 2.0),
    (0.02, 117.0, 4.0),
    (0.04, 117.0, 2.0),
    (0.04, 117.0, 4.0),
];

/// One candidate: the decider's timing rules, and whether the front end
/// encodes the run of frames that starts a press (`FrontEnd::set_encode_run`;
/// without it a press's embeddings begin on the frame the detector starts
/// it on, `min_enter_frames - 1` frames after the run's first).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Timing {
    pub min_ms: f32,
    pub confirm_ms: f32,
    /// The run that starts a press is encoded.
    pub run: bool,
    /// How much nearer a challenger must be to replace the decision.
    #[serde(default = "default_switch_margin")]
    pub switch_margin: f32,
    /// For how long (ms).
    #[serde(default = "default_switch_ms")]
    pub switch_ms: f32,
    /// Each change in a press multiplies the next one's time by this.
    #[serde(default = "default_switch_backoff")]
    pub switch_backoff: f32,
    /// `DecideConfig::commit_margin` (None: always confirm).
    #[serde(default)]
    pub commit_margin: Option<f32>,
    /// `DecideConfig::commit_weight` and `commit_weight_ms` (None: the
    /// first decision does not wait for the press's depth).
    #[serde(default)]
    pub gate: Option<(f32, f32)>,
}

fn default_switch_margin() -> f32 {
    SWITCH_RULES[0].0
}

fn default_switch_ms() -> f32 {
    SWITCH_RULES[0].1
}

fn default_switch_backoff() -> f32 {
    SWITCH_RULES[0].2
}

impl Timing {
    /// The shipped timing rules (`DecideConfig::default()`: `min_ms`,
    /// `confirm_ms`, `commit_margin`), the run not encoded, with the
    /// baseline switching rule.
    pub fn shipped() -> Timing {
        let d = DecideConfig::default();
        Timing {
            commit_margin: d.commit_margin.is_finite().then_some(d.commit_margin),
            gate: (d.commit_weight > 0.0 && d.commit_weight_ms > 0.0)
                .then_some((d.commit_weight, d.commit_weight_ms)),
            ..Timing::pair(d.min_ms, d.confirm_ms, false)
        }
    }

    /// A timing pair with the baseline switching rule.
    pub fn pair(min_ms: f32, confirm_ms: f32, run: bool) -> Timing {
        Timing {
            min_ms,
            confirm_ms,
            run,
            switch_margin: default_switch_margin(),
            switch_ms: default_switch_ms(),
            switch_backoff: default_switch_backoff(),
            commit_margin: None,
            gate: None,
        }
    }

    /// `min_ms / confirm_ms`, "+ run" when the run is encoded, and the
    /// switching rule when it is not the baseline's.
    pub fn label(&self) -> String {
        let sw = if (self.switch_margin, self.switch_ms, self.switch_backoff) == SWITCH_RULES[0] {
            String::new()
        } else {
            format!(
                ", switch {:.2} for {:.0} ms{}",
                self.switch_margin,
                self.switch_ms,
                self.backoff_suffix()
            )
        };
        format!(
            "{:.0} / {:.0}{}{}{}{sw}",
            self.min_ms,
            self.confirm_ms,
            self.commit_margin
                .map(|m| format!(" or margin {m:.2}"))
                .unwrap_or_default(),
            self.gate
                .map(|(w, ms)| format!(", depth {w:.2} (≤ {ms:.0} ms)"))
                .unwrap_or_default(),
            if self.run { " + run" } else { "" }
        )
    }

    /// The switching rule alone, `margin / ms`, and `, x backoff` when
    /// there is one.
    pub fn switch_label(&self) -> String {
        format!(
            "{:.2} / {:.0} ms{}",
            self.switch_margin,
            self.switch_ms,
            self.backoff_suffix()
        )
    }

    /// `, x B per change` for a backoff, nothing without one.
    fn backoff_suffix(&self) -> String {
        if self.switch_backoff == 1.0 {
            String::new()
        } else {
            format!(", x {} per change", self.switch_backoff)
        }
    }
}

/// `timing` with each of [`SWITCH_RULES`], the baseline rule first.
pub fn switch_candidates(timing: Timing) -> Vec<Timing> {
    SWITCH_RULES
        .iter()
        .map(|&(switch_margin, switch_ms, switch_backoff)| Timing {
            switch_margin,
            switch_ms,
            switch_backoff,
            ..timing
        })
        .collect()
}

/// Every candidate: each of [`PAIRS`] without the run encoded (the front
/// end as shipped), then each with it, then 0 / 50 with each of
/// [`COMMIT_MARGINS`], without the run and with it. The first, 50 / 50
/// without the run, is the baseline of [`choose`].
pub fn candidates() -> Vec<Timing> {
    let mut v: Vec<Timing> = [false, true]
        .into_iter()
        .flat_map(|run| {
            PAIRS
                .iter()
                .map(move |&(min_ms, confirm_ms)| Timing::pair(min_ms, confirm_ms, run))
        })
        .collect();
    for run in [false, true] {
        for m in COMMIT_MARGINS {
            v.push(Timing {
                commit_margin: Some(m),
                ..Timing::pair(0.0, 50.0, run)
            });
        }
    }
    let d = DecideConfig::default();
    for (w, ms) in DEPTH_GATES {
        v.push(Timing {
            gate: Some((w, ms)),
            switch_margin: d.switch_margin,
            switch_ms: d.switch_ms,
            switch_backoff: d.switch_backoff,
            ..Timing::shipped()
        });
    }
    v
}

/// Depth gates for the first decision (`DecideConfig::commit_weight`,
/// `commit_weight_ms`), each on the daemon's decider
/// (`DecideConfig::default()`, its switching rules too): the first
/// decision waits until a frame of the press has had that contact weight
/// (`contact_weight` of its whole-frame depth: 0.25, 0.5, 0.75 are 1.2,
/// 2.8 and 5.5 DN), or that long after the press's first embedding. The
/// first six were added with the most changed tile (`ContactConfig::tile`),
/// whose presses start on a one-place touch, before any was scored; the
/// last four (waiting up to 750 ms, the study's window) after them, when
/// the tile's catalogue-2 hand-held presses proved to start up to 26
/// frames before the whole frame's, longer than 200 ms.
pub const DEPTH_GATES: [(f32, f32); 10] = [
    (0.25, 100.0),
    (0.5, 100.0),
    (0.75, 100.0),
    (0.25, 200.0),
    (0.5, 200.0),
    (0.75, 200.0),
    (0.15, 750.0),
    (0.25, 750.0),
    (0.35, 750.0),
    (0.5, 750.0),
];

/// Margins for an early first decision (`DecideConfig::commit_margin`),
/// each with 0 / 50 without and with the run encoded: the leader commits
/// on the second frame of its run when it is nearer than the runner-up by
/// the margin (the index's distance), else after `confirm_ms`. Added
/// after [`PAIRS`], doubling from 0.01 (a third of the switching rule's
/// 0.02... up to where few presses qualify), before any was scored.
pub const COMMIT_MARGINS: [f32; 5] = [0.01, 0.02, 0.04, 0.08, 0.16];

/// One press as the daemon saw it.
#[derive(Clone, Debug)]
pub struct PressTrace {
    /// Index class of the pressed textile.
    pub class: usize,
    /// Jig or hand-held.
    pub jig: bool,
    /// Milliseconds from the press's true first contact to the contact
    /// detector's press start (the time origin of `emb.t_ms`); NaN when the
    /// detector never started the press.
    pub detect_ms: f64,
    /// The embedded frames in contact, from the daemon's front end (none:
    /// never started, so never decided and never right).
    pub emb: PressEmbedding,
}

/// One candidate's figures on one group of presses.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct TimingScore {
    pub timing: Timing,
    /// "jig" or "hand-held".
    pub group: String,
    pub presses: usize,
    /// (ms after first contact, share of presses whose committed decision
    /// is right then).
    pub right_at: Vec<(f64, f64)>,
    /// (ms after first contact, share of presses with any decision then).
    pub decided_at: Vec<(f64, f64)>,
    /// Every [`GRID_MS`] from `GRID_MS` to [`WINDOW_MS`]: (ms, share right).
    pub curve: Vec<(f64, f64)>,
    /// Mean of `curve` over the first [`MEAN_OVER_MS`].
    pub mean_right: f64,
    /// Median ms from first contact to the first decision (decided
    /// presses).
    pub first_ms_p50: f64,
    /// Share of decided presses whose first decision was right.
    pub first_right: f64,
    /// Share of presses right at the end of the window.
    pub final_right: f64,
    /// Changes of decision after the first, per 100 presses.
    pub switches_per_100: f64,
    /// Of those, changes away from the pressed textile (a right decision
    /// replaced by a wrong one), per 100 presses.
    #[serde(default)]
    pub from_right_per_100: f64,
}

impl TimingScore {
    /// The committed share right at `t` ms (NaN if not scored).
    pub fn right(&self, t: f64) -> f64 {
        self.right_at
            .iter()
            .find(|(x, _)| (*x - t).abs() < 0.5)
            .map_or(f64::NAN, |p| p.1)
    }
}

/// The shipped decider configuration with a candidate's timing and
/// switching rules.
pub fn config(t: &Timing) -> DecideConfig {
    DecideConfig {
        min_ms: t.min_ms,
        confirm_ms: t.confirm_ms,
        switch_margin: t.switch_margin,
        switch_ms: t.switch_ms,
        switch_backoff: t.switch_backoff,
        commit_margin: t.commit_margin.unwrap_or(f32::INFINITY),
        commit_weight: t.gate.map_or(0.0, |g| g.0),
        commit_weight_ms: t.gate.map_or(0.0, |g| g.1),
        ..DecideConfig::default()
    }
}

/// The decider over one press: per time in `times` (ms after first
/// contact) the committed entry then, the first decision's time (ms after
/// contact) and entry, the entry at the end, and the switches.
pub struct PressRun {
    pub at: Vec<Option<usize>>,
    pub first: Option<(f64, usize)>,
    pub last: Option<usize>,
    pub switches: u32,
    /// Changes of decision away from the pressed textile.
    pub from_right: u32,
}

/// Runs the daemon's decider over a press's embeddings: all of them when
/// `run` (the front end encodes the run that starts a press),
/// else from the frame the detector started the press on
/// ([`PressEmbedding::early`] rows later).
pub fn run_press(
    index: &FlatIndex,
    cfg: &DecideConfig,
    p: &PressTrace,
    run: bool,
    times: &[f64],
) -> PressRun {
    let mut d = Decider::new(cfg.clone(), index.dim());
    let us = |ms: f64| (ms * 1000.0).round().max(0.0) as u64;
    // Absolute time: contact at 0, the detector's start at `detect_ms`.
    d.press_start(us(p.detect_ms));
    let mut at = vec![None; times.len()];
    let mut first = None;
    let mut current = None;
    let mut from_right = 0;
    let e = &p.emb;
    let from = if run { 0 } else { e.early.min(e.len()) };
    for k in from..e.len() {
        let t = p.detect_ms + e.t_ms[k];
        if t > WINDOW_MS {
            break;
        }
        let w = e.weights.get(k).copied().unwrap_or(1.0);
        // Decisions made by frames up to each time count at that time.
        for (i, &tt) in times.iter().enumerate() {
            if t > tt && at[i].is_none() {
                at[i] = Some(current);
            }
        }
        if let Some(step) = d.on_embedding_weighted(index, us(t), e.row(k), w) {
            let next = step.decision.map(|x| x.entry);
            from_right += (current == Some(p.class) && next.is_some() && next != current) as u32;
            current = next;
            if first.is_none() {
                first = current.map(|c| (t, c));
            }
        }
    }
    // The switching rule's changes within the window: what this study
    // measures (the press's end, which decides on the whole mean, is not
    // one of its frames).
    let switches = d.switches();
    d.press_end(index, us(WINDOW_MS));
    PressRun {
        at: at.into_iter().map(|a| a.unwrap_or(current)).collect(),
        first,
        last: current,
        switches,
        from_right,
    }
}

/// The curve's times: every [`GRID_MS`] up to [`WINDOW_MS`].
pub fn grid() -> Vec<f64> {
    (1..=(WINDOW_MS / GRID_MS) as usize)
        .map(|i| i as f64 * GRID_MS)
        .collect()
}

/// Scores every candidate on the presses of one group.
pub fn score(
    index: &FlatIndex,
    presses: &[&PressTrace],
    group: &str,
    candidates: &[Timing],
) -> Vec<TimingScore> {
    candidates
        .iter()
        .map(|&timing| {
            let cfg = config(&timing);
            let n = presses.len().max(1) as f64;
            let grid = grid();
            let times: Vec<f64> = TIMES_MS.iter().chain(&grid).copied().collect();
            let mut right = vec![0usize; times.len()];
            let mut decided = vec![0usize; times.len()];
            let (mut first_t, mut first_ok, mut fin, mut sw) = (Vec::new(), 0usize, 0usize, 0u64);
            let mut away = 0u64;
            for p in presses {
                let r = run_press(index, &cfg, p, timing.run, &times);
                for (i, a) in r.at.iter().enumerate() {
                    decided[i] += a.is_some() as usize;
                    right[i] += (*a == Some(p.class)) as usize;
                }
                if let Some((t, c)) = r.first {
                    first_t.push(t);
                    first_ok += (c == p.class) as usize;
                }
                fin += (r.last == Some(p.class)) as usize;
                sw += r.switches as u64;
                away += r.from_right as u64;
            }
            // (time, share of the presses) for counts at `times`.
            let shares = |times: &[f64], counts: &[usize]| -> Vec<(f64, f64)> {
                times
                    .iter()
                    .zip(counts)
                    .map(|(&t, &c)| (t, c as f64 / n))
                    .collect()
            };
            let curve = shares(&grid, &right[TIMES_MS.len()..]);
            let early: Vec<f64> = curve
                .iter()
                .filter(|x| x.0 <= MEAN_OVER_MS)
                .map(|x| x.1)
                .collect();
            TimingScore {
                timing,
                group: group.to_string(),
                presses: presses.len(),
                right_at: shares(&TIMES_MS, &right),
                decided_at: shares(&TIMES_MS, &decided),
                mean_right: early.iter().sum::<f64>() / early.len().max(1) as f64,
                curve,
                first_ms_p50: crate::bench::median(&first_t),
                first_right: if first_t.is_empty() {
                    f64::NAN
                } else {
                    first_ok as f64 / first_t.len() as f64
                },
                final_right: fin as f64 / n,
                switches_per_100: 100.0 * sw as f64 / n,
                from_right_per_100: 100.0 * away as f64 / n,
            }
        })
        .collect()
}

/// The groups of `scores`, sorted, each once.
fn groups(scores: &[TimingScore]) -> Vec<&str> {
    let mut g: Vec<&str> = scores.iter().map(|s| s.group.as_str()).collect();
    g.sort();
    g.dedup();
    g
}

/// The score of candidate `t` on group `g`; an error when it is missing.
fn score_of<'a>(scores: &'a [TimingScore], t: Timing, g: &str) -> Result<&'a TimingScore> {
    scores
        .iter()
        .find(|s| s.timing == t && s.group == g)
        .with_context(|| format!("no score for {} on {g}", t.label()))
}

/// The rule (docs/benchmarks.md): among the candidates whose first
/// decisions, in every group, are right at most [`MAX_FIRST_LOSS`] less
/// often than the first candidate's (50 / 50 without the run) and that
/// lose at most [`MAX_FINAL_LOSS`] of the presses right at the end of the
/// window, the one with the highest mean committed-right share over the
/// first [`MEAN_OVER_MS`] in its worst group; ties go to the fewer
/// switches, then the earlier candidate (the first one first). Returns the
/// index into `pairs`.
pub fn choose(scores: &[TimingScore], pairs: &[Timing]) -> Result<usize> {
    ensure!(!pairs.is_empty(), "no candidates");
    let groups = groups(scores);
    let get = |pair: Timing, g: &str| score_of(scores, pair, g);
    let mut best: Option<(usize, f64, f64)> = None;
    for (i, &pair) in pairs.iter().enumerate() {
        let mut ok = true;
        let (mut worst, mut sw) = (f64::INFINITY, 0.0f64);
        for g in &groups {
            let (s, base) = (get(pair, g)?, get(pairs[0], g)?);
            ok &= s.first_right >= base.first_right - MAX_FIRST_LOSS
                && s.final_right >= base.final_right - MAX_FINAL_LOSS;
            worst = worst.min(s.mean_right);
            sw = sw.max(s.switches_per_100);
        }
        if !ok {
            continue;
        }
        let better = match best {
            None => true,
            Some((_, w, s)) => worst > w + 1e-12 || ((worst - w).abs() <= 1e-12 && sw < s),
        };
        if better {
            best = Some((i, worst, sw));
        }
    }
    Ok(best.map_or(0, |b| b.0))
}

/// How much less often the first decision may be right than with the
/// baseline, 50 / 50 (a wrong first decision is a roller move to the wrong
/// fabric and back).
pub const MAX_FIRST_LOSS: f64 = 0.02;
/// Share of presses right at the end of the window the rule may lose.
pub const MAX_FINAL_LOSS: f64 = 0.005;
/// Share of the mean committed-right curve over the first
/// [`MEAN_OVER_MS`] that a stricter switching rule may cost (it delays
/// corrections of a wrong first decision).
pub const MAX_MEAN_LOSS: f64 = 0.01;

/// The switching rule (docs/benchmarks.md): among the candidates that, in
/// every group, lose at most [`MAX_FINAL_LOSS`] of the presses right at the
/// end of the window and at most [`MAX_MEAN_LOSS`] of the mean share right
/// over the first [`MEAN_OVER_MS`] against the first candidate (the
/// switching rule shipped before), the one with the fewest changes of
/// decision per 100 presses in its worst group; ties go to the earlier
/// candidate. Returns the index into `cands`.
pub fn choose_switch(scores: &[TimingScore], cands: &[Timing]) -> Result<usize> {
    ensure!(!cands.is_empty(), "no candidates");
    let groups = groups(scores);
    let get = |t: Timing, g: &str| score_of(scores, t, g);
    let mut best: Option<(usize, f64)> = None;
    for (i, &t) in cands.iter().enumerate() {
        let mut ok = true;
        let mut sw = 0.0f64;
        for g in &groups {
            let (s, base) = (get(t, g)?, get(cands[0], g)?);
            ok &= s.final_right >= base.final_right - MAX_FINAL_LOSS - 1e-12
                && s.mean_right >= base.mean_right - MAX_MEAN_LOSS - 1e-12;
            sw = sw.max(s.switches_per_100);
        }
        if ok && best.is_none_or(|(_, b)| sw < b - 1e-12) {
            best = Some((i, sw));
        }
    }
    Ok(best.map_or(0, |b| b.0))
}

/// The switching rule across several studies (the catalogues): the
/// union of their switching scores, each group named after its study's
/// source (`"sim, catalogue 2 (generator 1): hand-held"`), and
/// [`choose_switch`]'s pick over it, an index into the candidates. So the
/// pick keeps within the bounds in every group of every study and has the
/// fewest switches in the worst group of any. The studies must have scored
/// the same candidates, with different sources.
pub fn choose_switch_across(reports: &[TimingReport]) -> Result<(Vec<TimingScore>, usize)> {
    let (scores, cands) = union_across(reports, "switching", |r| {
        (&r.switch_candidates, &r.switch_scores)
    })?;
    let i = choose_switch(&scores, cands)?;
    Ok((scores, i))
}

/// The scores of the same candidates in several studies, as one list
/// whose groups are named after their study's source (`"sim, catalogue 2
/// (generator 1): hand-held"`), and the candidates. `part` picks the
/// candidates and scores of a study (the timing or the switching rules).
/// An error for no study, no candidates, studies that scored other
/// candidates, or a source given twice.
fn union_across<'a>(
    reports: &'a [TimingReport],
    what: &str,
    part: impl Fn(&'a TimingReport) -> (&'a Vec<Timing>, &'a Vec<TimingScore>),
) -> Result<(Vec<TimingScore>, &'a [Timing])> {
    let first = reports.first().context("no study to combine")?;
    let cands = part(first).0;
    ensure!(
        !cands.is_empty(),
        "{}: no {what} rules scored",
        first.source
    );
    let mut sources = Vec::new();
    let mut scores = Vec::new();
    for r in reports {
        let (c, sc) = part(r);
        ensure!(
            c == cands,
            "{} scored other {what} rules than {}",
            r.source,
            first.source
        );
        ensure!(!sources.contains(&&r.source), "{} given twice", r.source);
        sources.push(&r.source);
        scores.extend(sc.iter().map(|x| TimingScore {
            group: format!("{}: {}", r.source, x.group),
            ..x.clone()
        }));
    }
    Ok((scores, cands))
}

/// The timing rule across several studies: [`choose`] over the union of
/// their timing scores (groups named as in [`choose_switch_across`]), an
/// index into the candidates. So the pick keeps first decisions and the
/// presses right at the end within the bounds in every group of every
/// study, and has the highest mean share right in the worst group of any.
/// The studies must have scored the same candidates, with different
/// sources.
pub fn choose_timing_across(reports: &[TimingReport]) -> Result<(Vec<TimingScore>, usize)> {
    let (scores, cands) = union_across(reports, "timing", |r| (&r.candidates, &r.scores))?;
    let i = choose(&scores, cands)?;
    Ok((scores, i))
}

/// The markdown of [`choose_timing_across`] and [`choose_switch_across`]:
/// per candidate and group, the figures each rule reads, and its pick.
pub fn markdown_across(reports: &[TimingReport], command: &str) -> Result<String> {
    let timing = match reports.first() {
        Some(r) if !r.candidates.is_empty() => Some(choose_timing_across(reports)?),
        _ => None,
    };
    let (scores, i) = choose_switch_across(reports)?;
    let cands = &reports[0].switch_candidates;
    let mut s = format!(
        "# Switching rules across studies\n\nGenerated by `{command}` from the studies of {}.\n\n",
        reports
            .iter()
            .map(|r| format!("{} (`{}`, {})", r.source, r.command, r.date))
            .collect::<Vec<_>>()
            .join(", ")
    );
    s.push_str("| switch margin / for (x backoff per change) | group | mean over 0-500 ms | right at 750 ms | switches / 100 | away from right / 100 |\n|---|---|---:|---:|---:|---:|\n");
    for (k, c) in cands.iter().enumerate() {
        let mark = if k == i { "**" } else { "" };
        for x in scores.iter().filter(|x| x.timing == *c) {
            s.push_str(&format!(
                "| {mark}{}{mark} | {} | {:.1} | {:.1} | {:.1} | {:.1} |\n",
                c.switch_label(),
                x.group,
                100.0 * x.mean_right,
                100.0 * x.final_right,
                x.switches_per_100,
                x.from_right_per_100
            ));
        }
    }
    s.push_str(&format!(
        "\nThe rule (at most {:.1} points fewer presses right at 750 ms and at most {:.1} points less mean share right over the first {MEAN_OVER_MS:.0} ms than with {} in every group of every study; then the fewest switches per 100 presses in the worst group) picks **{}**.\n",
        100.0 * MAX_FINAL_LOSS,
        100.0 * MAX_MEAN_LOSS,
        cands[0].switch_label(),
        cands[i].switch_label()
    ));
    let Some((tscores, ti)) = timing else {
        return Ok(s);
    };
    let tc = &reports[0].candidates;
    s.push_str("\n# Timing rules across studies\n\n| min_ms / confirm_ms | group | right at 100 ms | right at 150 ms | mean over 0-500 ms | first decision right | right at 750 ms | switches / 100 |\n|---|---|---:|---:|---:|---:|---:|---:|\n");
    for (k, c) in tc.iter().enumerate() {
        let mark = if k == ti { "**" } else { "" };
        for x in tscores.iter().filter(|x| x.timing == *c) {
            s.push_str(&format!(
                "| {mark}{}{mark} | {} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |\n",
                c.label(),
                x.group,
                100.0 * x.right(100.0),
                100.0 * x.right(150.0),
                100.0 * x.mean_right,
                100.0 * x.first_right,
                100.0 * x.final_right,
                x.switches_per_100
            ));
        }
    }
    s.push_str(&format!(
        "\nThe rule (first decisions right at most {:.1} points less often, and at most {:.1} points fewer presses right at 750 ms, than with {} in every group of every study; then the highest mean share right over the first {MEAN_OVER_MS:.0} ms in the worst group) picks **{}**.\n",
        100.0 * MAX_FIRST_LOSS,
        100.0 * MAX_FINAL_LOSS,
        tc[0].label(),
        tc[ti].label()
    ));
    Ok(s)
}

/// What to run.
pub struct StudyConfig {
    /// The protocol whose training people's index frames build the index
    /// (their centroids, as `index build` makes it) and whose held-out
    /// people press the queries.
    pub protocol: crate::protocol::Protocol,
    pub cache_dir: std::path::PathBuf,
    /// Held-out (person, unit) pairs that press the queries (the first
    /// `people` of the protocol's).
    pub people: usize,
    /// Worker threads (one ONNX Runtime thread each).
    pub threads: usize,
    /// The contact detector that starts the presses.
    pub contact: telextiles_sensing::contact::ContactConfig,
}

/// Everything the study measured.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TimingReport {
    pub machine: String,
    pub date: String,
    pub command: String,
    pub source: String,
    pub model: String,
    /// The candidates scored, the baseline first.
    pub candidates: Vec<Timing>,
    pub scores: Vec<TimingScore>,
    /// The candidate [`choose`] picks.
    pub chosen: Timing,
    /// The switching rules scored at the shipped timing, the baseline
    /// first.
    #[serde(default)]
    pub switch_candidates: Vec<Timing>,
    #[serde(default)]
    pub switch_scores: Vec<TimingScore>,
    /// The one [`choose_switch`] picks.
    #[serde(default)]
    pub switch_chosen: Option<Timing>,
    /// Median ms from first contact to the contact detector's press
    /// start, per group.
    pub detect_ms_p50: Vec<(String, f64)>,
    /// Presses the contact detector never started, per group (counted
    /// as never right).
    pub undetected: Vec<(String, usize)>,
    pub seconds: f64,
    /// The contact detector that started the presses (None: the shipped
    /// one of the study's date; studies before 2026-11-29 do not say).
    #[serde(default)]
    pub contact: Option<crate::detector::Detector>,
}

/// Frames of a simulated press from a few quiet frames before its first
/// contact to [`WINDOW_MS`] after it, as a recording (the front end
/// captures the reference from the quiet frames), and the first contact's
/// timestamp.
fn press_window(
    sim: &telextiles_sim::Simulator,
    spec: &telextiles_sim::PressSpec,
) -> Result<(telextiles_sim::Press, u64)> {
    let sim_err = |e: telextiles_sim::SimError| anyhow::anyhow!("simulator: {e}");
    let mut meta = sim.press_meta(spec).map_err(sim_err)?;
    let mut params = meta
        .params
        .clone()
        .context("simulated press without params")?;
    let c = params.contact_frame as usize;
    let ts = meta.timestamps_us.clone();
    ensure!(c < ts.len(), "press without contact");
    let start = c.saturating_sub(12);
    let limit = ts[c] + (WINDOW_MS * 1000.0) as u64;
    let end = (c..ts.len())
        .find(|&i| ts[i] > limit)
        .map_or(ts.len(), |i| i + 1);
    let frames = (start..end)
        .map(|i| sim.render_frame(spec, i).map_err(sim_err))
        .collect::<Result<Vec<_>>>()?;
    let shift = |f: u32| f.saturating_sub(start as u32);
    params.contact_frame = shift(params.contact_frame);
    params.hold_frame = shift(params.hold_frame);
    params.release_frame = params.release_frame.map(shift);
    // The quiet frames before contact, in the window's numbering.
    meta.reference_frames = meta.reference_frames.map(|_| params.contact_frame);
    meta.params = Some(params);
    meta.timestamps_us = ts[start..end].to_vec();
    Ok((telextiles_sim::Press { meta, frames }, ts[c]))
}

/// Runs the study with one model.
pub fn run(cfg: &StudyConfig, model: &crate::methods::Method) -> Result<TimingReport> {
    use crate::methods::{background_of, Embedder};
    let t0 = std::time::Instant::now();
    let p = &cfg.protocol;
    let sim = telextiles_sim::Simulator::with_options(p.catalogue, p.generator)
        .map_err(|e| anyhow::anyhow!("simulator: {e}"))?;
    // The index: centroids of the training people's index frames.
    let sets = crate::protocol::load_base(
        p,
        crate::protocol::SourceKind::Sim,
        &cfg.cache_dir,
        cfg.threads,
    )?;
    let (crop, input) = model.view();
    let iv = crate::protocol::view_set(&sets.train_index, crop, input)?;
    let rv = crate::protocol::view_set(&sets.backgrounds, crop, input)?;
    let (ie, dim) = Embedder::new(model, cfg.threads)?.embed(&iv, |s| background_of(&rv, s))?;
    let mut per: Vec<Vec<Vec<f32>>> = vec![Vec::new(); iv.classes.len()];
    for (i, it) in iv.items.iter().enumerate() {
        per[it.class as usize].push(ie[i * dim..(i + 1) * dim].to_vec());
    }
    let entries: Vec<(String, Vec<Vec<f32>>)> = iv
        .classes
        .iter()
        .cloned()
        .zip(per)
        .filter(|(_, v)| !v.is_empty())
        .collect();
    let index = FlatIndex::from_embeddings(&entries).map_err(|e| anyhow::anyhow!("index: {e}"))?;
    drop(sets);
    // The queries: every training textile pressed by the held-out people,
    // in the jig and by hand.
    // (The index holds the protocol's training textiles, `--textiles` of
    // them when given.)
    let textiles: Vec<(usize, String)> = sim
        .catalogue()
        .training()
        .filter_map(|t| Some((index.entry_by_id(&t.id)?, t.id.clone())))
        .collect();
    ensure!(!textiles.is_empty(), "no training textile in the index");
    let mut plans = Vec::new();
    for (class, t) in &textiles {
        for &(person, sensor) in p.heldout.iter().take(cfg.people.max(1)) {
            for jig in [true, false] {
                plans.push((
                    *class,
                    telextiles_sim::PressSpec {
                        person,
                        sensor,
                        jig,
                        ..telextiles_sim::PressSpec::new(t.as_str(), 2000 + person as u64)
                    },
                ));
            }
        }
    }
    let bar = telextiles_progress::Progress::new(
        "rendering and embedding",
        plans.len() as u64,
        "presses",
    );
    let threads = cfg.threads.max(1);
    let parts: Vec<Result<Vec<(usize, PressTrace)>>> = std::thread::scope(|s| {
        let hs: Vec<_> = (0..threads)
            .map(|w| {
                let (plans, sim, bar) = (&plans, &sim, &bar);
                s.spawn(move || -> Result<Vec<(usize, PressTrace)>> {
                    let mut proc = crate::recorded::Processor::new(
                        std::slice::from_ref(model),
                        1,
                        cfg.contact.clone(),
                    )?;
                    // Every candidate from one pass: those without the run
                    // skip its rows.
                    proc.set_encode_run(true);
                    let mut out = Vec::new();
                    for (i, (class, spec)) in plans.iter().enumerate().skip(w).step_by(threads) {
                        let (press, contact_us) = press_window(sim, spec)?;
                        let ts = press.meta.timestamps_us.clone();
                        let done = proc.process(&spec.textile, press)?;
                        bar.inc(1);
                        let emb = done.methods.into_iter().next().unwrap_or_default();
                        let detect_ms = match emb.frames.first() {
                            Some(&f) => (ts[f] as f64 - contact_us as f64) / 1e3 - emb.t_ms[0],
                            None => f64::NAN,
                        };
                        out.push((
                            i,
                            PressTrace {
                                class: *class,
                                jig: spec.jig,
                                detect_ms,
                                emb,
                            },
                        ));
                    }
                    Ok(out)
                })
            })
            .collect();
        hs.into_iter()
            .map(|h| h.join().expect("worker panicked"))
            .collect()
    });
    bar.finish();
    let mut traces = Vec::new();
    for part in parts {
        traces.extend(part?);
    }
    traces.sort_by_key(|x| x.0);
    let traces: Vec<PressTrace> = traces.into_iter().map(|x| x.1).collect();
    let cands = candidates();
    let mut scores = Vec::new();
    let mut detect = Vec::new();
    let mut undetected = Vec::new();
    for (group, jig) in [("jig", true), ("hand-held", false)] {
        // A press the detector never started has no frames: it counts
        // against every candidate, as never right.
        let g: Vec<&PressTrace> = traces.iter().filter(|t| t.jig == jig).collect();
        scores.extend(score(&index, &g, group, &cands));
        let d: Vec<f64> = g
            .iter()
            .map(|t| t.detect_ms)
            .filter(|t| t.is_finite())
            .collect();
        undetected.push((group.to_string(), g.len() - d.len()));
        detect.push((group.to_string(), crate::bench::median(&d)));
    }
    let chosen = cands[choose(&scores, &cands)?];
    // The switching rules at the shipped timing (the front end as
    // shipped: the run that starts a press not encoded).
    let sw_cands = switch_candidates(Timing::shipped());
    let mut sw_scores = Vec::new();
    for (group, jig) in [("jig", true), ("hand-held", false)] {
        let g: Vec<&PressTrace> = traces.iter().filter(|t| t.jig == jig).collect();
        sw_scores.extend(score(&index, &g, group, &sw_cands));
    }
    let switch_chosen = sw_cands[choose_switch(&sw_scores, &sw_cands)?];
    Ok(TimingReport {
        machine: crate::report::machine(),
        date: crate::report::today(),
        command: std::env::args().collect::<Vec<_>>().join(" "),
        source: format!("sim, catalogue {} (generator {})", p.catalogue, p.generator),
        model: model.name(),
        candidates: cands,
        scores,
        chosen,
        switch_candidates: sw_cands,
        switch_scores: sw_scores,
        switch_chosen: Some(switch_chosen),
        detect_ms_p50: detect,
        undetected,
        seconds: t0.elapsed().as_secs_f64(),
        contact: Some(crate::detector::Detector::of(&cfg.contact)),
    })
}

/// The report's markdown.
pub fn markdown(r: &TimingReport) -> String {
    let mut s = format!(
        "# When the decider commits: timing rules on whole presses\n\nGenerated by `{}` on {} ({}), frames from `{}`, model `{}`, in {:.0} s.\n\n",
        r.command, r.date, r.machine, r.source, r.model, r.seconds
    );
    s.push_str("Every press runs through the daemon's front end (contact detector, the press's own reference, the encoder) and its decider against the training people's centroids, from quiet frames before contact to 750 ms after it. Times are ms after the true first contact; the contact detector's press start comes ");
    s.push_str(
        &r.detect_ms_p50
            .iter()
            .map(|(g, t)| format!("{t:.0} ms after it ({g}, median)"))
            .collect::<Vec<_>>()
            .join(", "),
    );
    s.push_str(". Presses the detector never started (counted as never right): ");
    s.push_str(
        &r.undetected
            .iter()
            .map(|(g, n)| format!("{n} ({g})"))
            .collect::<Vec<_>>()
            .join(", "),
    );
    s.push_str(". \"right at T\": the decision committed by T is the pressed textile (no decision yet: not right). \"switches\": changes of decision after the first, per 100 presses.\n\n");
    for group in ["jig", "hand-held"] {
        let g: Vec<&TimingScore> = r.scores.iter().filter(|x| x.group == group).collect();
        let Some(first) = g.first() else { continue };
        s.push_str(&format!(
            "## {group} ({} presses)\n\n| min_ms / confirm_ms (+ run: the run that starts a press encoded) |",
            first.presses
        ));
        for (t, _) in &first.right_at {
            s.push_str(&format!(" right at {t:.0} ms |"));
        }
        s.push_str(" mean over 0-500 ms | first decision (p50) | first decision right | right at 750 ms | switches / 100 |\n|---|");
        for _ in &first.right_at {
            s.push_str("---:|");
        }
        s.push_str("---:|---:|---:|---:|---:|\n");
        for x in g {
            let mark = if x.timing == r.chosen { "**" } else { "" };
            s.push_str(&format!("| {mark}{}{mark} |", x.timing.label()));
            for (_, v) in &x.right_at {
                s.push_str(&format!(" {:.1} |", 100.0 * v));
            }
            s.push_str(&format!(
                " {:.1} | {:.0} ms | {:.1} | {:.1} | {:.1} |\n",
                100.0 * x.mean_right,
                x.first_ms_p50,
                100.0 * x.first_right,
                100.0 * x.final_right,
                x.switches_per_100
            ));
        }
        s.push('\n');
    }
    s.push_str(&format!(
        "The rule (first decisions right at most {:.1} points less often, and at most {:.1} points fewer presses right at 750 ms, than with {} in every group; then the highest mean share right over the first {MEAN_OVER_MS:.0} ms in the worst group) picks **{}**.\n",
        100.0 * MAX_FIRST_LOSS,
        100.0 * MAX_FINAL_LOSS,
        r.candidates.first().map_or_else(String::new, Timing::label),
        r.chosen.label()
    ));
    if let (Some(base), Some(chosen)) = (r.switch_candidates.first(), r.switch_chosen) {
        s.push_str(&format!(
            "\n## Switching rules at {}\n\nHow much nearer (the index's distance: Euclidean between unit vectors) a challenger must be than the committed decision, and for how long, before the decision changes; with a backoff, each change in a press multiplies the next one's time. \"away from right\": changes that replace the pressed textile by another, per 100 presses.\n\n| switch margin / for (x backoff per change) | group | mean over 0-500 ms | right at 250 ms | right at 750 ms | switches / 100 | away from right / 100 |\n|---|---|---:|---:|---:|---:|---:|\n",
            Timing {
                switch_margin: base.switch_margin,
                switch_ms: base.switch_ms,
                switch_backoff: base.switch_backoff,
                ..chosen
            }
            .label()
        ));
        for group in ["jig", "hand-held"] {
            for x in r.switch_scores.iter().filter(|x| x.group == group) {
                let mark = if x.timing == chosen { "**" } else { "" };
                s.push_str(&format!(
                    "| {mark}{}{mark} | {group} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |\n",
                    x.timing.switch_label(),
                    100.0 * x.mean_right,
                    100.0 * x.right(250.0),
                    100.0 * x.final_right,
                    x.switches_per_100,
                    x.from_right_per_100
                ));
            }
        }
        s.push_str(&format!(
            "\nThe rule (at most {:.1} points fewer presses right at 750 ms and at most {:.1} points less mean share right over the first {MEAN_OVER_MS:.0} ms than with {} in every group; then the fewest switches per 100 presses in the worst group) picks **{}**.\n",
            100.0 * MAX_FINAL_LOSS,
            100.0 * MAX_MEAN_LOSS,
            base.switch_label(),
            chosen.switch_label()
        ));
    }
    s
}

/// Committed-right against time, one line per candidate (the chosen one
/// thicker), one chart per group.
pub fn chart(r: &TimingReport, group: &str, svg: &std::path::Path) -> Result<()> {
    let series: Vec<crate::stability_charts::Line> = r
        .scores
        .iter()
        .filter(|x| x.group == group)
        .map(|x| crate::stability_charts::Line {
            label: format!(
                "min {:.0} / confirm {:.0} ms{}",
                x.timing.min_ms,
                x.timing.confirm_ms,
                if x.timing.run { ", run encoded" } else { "" }
            ),
            points: x.curve.iter().map(|&(t, a)| (t, 100.0 * a)).collect(),
            width: if x.timing == r.chosen { 4 } else { 2 },
        })
        .collect();
    crate::stability_charts::line_chart(
        svg,
        &format!("Committed decisions right against time after first contact ({group})"),
        (
            "ms after first contact",
            "presses whose committed decision is right, %",
        ),
        0.0..WINDOW_MS,
        &series,
    )
}

/// Reads a study's `timing.json` (as [`write`] writes it).
pub fn read(path: &std::path::Path) -> Result<TimingReport> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_slice(&bytes)
        .with_context(|| format!("{} is not a decider-timing study", path.display()))
}

/// Writes `timing.json`, `report.md` and the charts into `out`.
pub fn write(r: &TimingReport, out: &std::path::Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    std::fs::write(out.join("timing.json"), serde_json::to_string_pretty(r)?)?;
    std::fs::write(out.join("report.md"), markdown(r))?;
    chart(r, "jig", &out.join("committed-jig.svg"))?;
    chart(r, "hand-held", &out.join("committed-hand-held.svg"))?;
    Ok(())
}

#[cfg(test)]
mod tests;
