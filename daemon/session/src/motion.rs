//! [`Motion`]: when the wheel moves, decided apart from what is decided.
//!
//! The receiving hand feels the wheel stop with a sample under the finger,
//! not a decision; a real wheel takes 90 to 270 ms to reach a sample (the
//! paper's wheel, `roller_firmware::Config::default`). A motion policy
//! turns what the decider knows after each frame of a press into roller
//! targets:
//!
//! - [`MotionPolicy::Every`]: go to every decision as it is made or
//!   changed.
//! - [`MotionPolicy::Confident`]: stay until the decision is confident
//!   (its confidence at least `confidence`, or held for `hold_ms`).
//! - [`MotionPolicy::Lead`]: set off before the first decision, towards
//!   the textile nearest the press's running mean once it has led for
//!   `lead_ms` (the wheel's slots follow the index's 1D layout, so a wrong
//!   early leader is usually a neighbour of the right one), then follow the
//!   decisions.
//! - [`MotionPolicy::Track`]: follow the textile nearest the press's
//!   running mean whenever it has led for `lead_ms`, decisions or not. A
//!   press ends on the textile nearest its whole mean (`Decider::press_end`),
//!   so the wheel heads for the final answer as soon as the mean settles,
//!   not at the release.
//!
//! Whatever the policy, a press ends with the wheel sent to its final
//! decision ([`Motion::press_end`]), a target already held is never sent
//! again, and the firmware goes the shorter way round from where it would
//! stop (never more than half a turn). Two slots whose lead alternates
//! frame by frame never make the wheel dither: a leader must lead for
//! `lead_ms` in a row, and decisions carry the decider's hysteresis.
//!
//! Pure: time comes with every input (the frames' capture times, on the
//! sender's clock), so a live session, `classify` and the benchmarks move
//! the wheel alike.

use std::fmt;
use std::str::FromStr;

use telextiles_press::decide::{DecideStep, TextileIndex};

/// How the wheel follows a press (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotionPolicy {
    /// Go to every decision as it is made or changed.
    Every,
    /// Go to a decision once it is confident.
    Confident {
        /// Confidence (`Decision::confidence`, 0..=1) enough to go at once.
        confidence: f32,
        /// Or: the decision has held this long (ms).
        hold_ms: f32,
    },
    /// Set off towards the running mean's nearest textile once it has led
    /// this long, before the first decision; then follow decisions.
    Lead {
        /// How long (ms of capture time) a leader must lead in a row.
        lead_ms: f32,
    },
    /// Follow the running mean's nearest textile once it has led this
    /// long, whatever the decisions say.
    Track {
        /// How long (ms of capture time) a leader must lead in a row.
        lead_ms: f32,
    },
}

impl MotionPolicy {
    /// Every policy with its default parameters, in the order studies list
    /// them.
    pub const ALL: [MotionPolicy; 4] = [
        MotionPolicy::Every,
        MotionPolicy::Confident {
            confidence: 0.25,
            hold_ms: 100.0,
        },
        MotionPolicy::Lead { lead_ms: 30.0 },
        MotionPolicy::Track { lead_ms: 60.0 },
    ];

    /// Its name in flags and reports.
    pub fn name(&self) -> &'static str {
        match self {
            MotionPolicy::Every => "every",
            MotionPolicy::Confident { .. } => "confident",
            MotionPolicy::Lead { .. } => "lead",
            MotionPolicy::Track { .. } => "track",
        }
    }
}

impl Default for MotionPolicy {
    /// Chosen by the rule of `docs/studies/2026-12-04-felt-latency.md`.
    fn default() -> Self {
        MotionPolicy::Every
    }
}

impl fmt::Display for MotionPolicy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            MotionPolicy::Every => write!(f, "every"),
            MotionPolicy::Confident {
                confidence,
                hold_ms,
            } => write!(f, "confident:{confidence}:{hold_ms}"),
            MotionPolicy::Lead { lead_ms } => write!(f, "lead:{lead_ms}"),
            MotionPolicy::Track { lead_ms } => write!(f, "track:{lead_ms}"),
        }
    }
}

impl FromStr for MotionPolicy {
    type Err = String;

    /// `every`, `confident[:CONFIDENCE[:HOLD_MS]]`, `lead[:LEAD_MS]`,
    /// `track[:LEAD_MS]`.
    fn from_str(s: &str) -> Result<Self, String> {
        let mut parts = s.trim().split(':');
        let name = parts.next().unwrap_or_default();
        let mut num = |what: &str, lo: f32, hi: f32| -> Result<Option<f32>, String> {
            match parts.next() {
                None => Ok(None),
                Some(p) => match p.parse::<f32>() {
                    Ok(v) if (lo..=hi).contains(&v) => Ok(Some(v)),
                    _ => Err(format!(
                        "motion policy `{s}`: {what} must be a number from {lo} to {hi}, not `{p}`"
                    )),
                },
            }
        };
        let policy = match name {
            "every" => MotionPolicy::Every,
            "confident" => {
                let MotionPolicy::Confident {
                    confidence,
                    hold_ms,
                } = MotionPolicy::ALL[1]
                else {
                    unreachable!("ALL[1] is confident")
                };
                MotionPolicy::Confident {
                    confidence: num("the confidence", 0.0, 1.0)?.unwrap_or(confidence),
                    hold_ms: num("the hold (ms)", 0.0, 60_000.0)?.unwrap_or(hold_ms),
                }
            }
            "lead" => {
                let MotionPolicy::Lead { lead_ms } = MotionPolicy::ALL[2] else {
                    unreachable!("ALL[2] is lead")
                };
                MotionPolicy::Lead {
                    lead_ms: num("the lead (ms)", 0.0, 60_000.0)?.unwrap_or(lead_ms),
                }
            }
            "track" => {
                let MotionPolicy::Track { lead_ms } = MotionPolicy::ALL[3] else {
                    unreachable!("ALL[3] is track")
                };
                MotionPolicy::Track {
                    lead_ms: num("the lead (ms)", 0.0, 60_000.0)?.unwrap_or(lead_ms),
                }
            }
            _ => {
                return Err(format!(
                    "unknown motion policy `{s}`; expected every, confident[:CONFIDENCE[:HOLD_MS]], lead[:LEAD_MS] or track[:LEAD_MS]"
                ))
            }
        };
        if parts.next().is_some() {
            return Err(format!("motion policy `{s}`: too many parameters"));
        }
        Ok(policy)
    }
}

/// One press's wheel motion (see the module docs).
#[derive(Clone, Debug)]
pub struct Motion {
    policy: MotionPolicy,
    /// The last target sent in this press.
    target: Option<usize>,
    /// The running mean's nearest slot and when its run began.
    leader: Option<(usize, u64)>,
}

impl Motion {
    /// A motion following `policy`, before any press.
    pub fn new(policy: MotionPolicy) -> Motion {
        Motion {
            policy,
            target: None,
            leader: None,
        }
    }

    /// Its policy.
    pub fn policy(&self) -> MotionPolicy {
        self.policy
    }

    /// A press begins: nothing of the last one carries over.
    pub fn press_start(&mut self) {
        self.target = None;
        self.leader = None;
    }

    /// The decider's state after a frame captured at `t_us`; the slot to
    /// send the wheel to, if it changes.
    pub fn on_step<I: TextileIndex + ?Sized>(
        &mut self,
        index: &I,
        t_us: u64,
        step: &DecideStep,
    ) -> Option<usize> {
        let ms = |since: u64| t_us.saturating_sub(since) as f32 / 1000.0;
        match (self.policy, step.decision) {
            (MotionPolicy::Every, Some(d)) => self.go(d.slot),
            (
                MotionPolicy::Confident {
                    confidence,
                    hold_ms,
                },
                Some(d),
            ) => {
                if d.confidence >= confidence || ms(d.since_us) >= hold_ms {
                    self.go(d.slot)
                } else {
                    None
                }
            }
            (MotionPolicy::Lead { .. }, Some(d)) => self.go(d.slot),
            (MotionPolicy::Lead { lead_ms }, None) | (MotionPolicy::Track { lead_ms }, _) => {
                if step.nearest.best >= index.len() {
                    return None;
                }
                let slot = index.slot_of(step.nearest.best);
                let since = match self.leader {
                    Some((s, since)) if s == slot => since,
                    _ => t_us,
                };
                self.leader = Some((slot, since));
                if ms(since) >= lead_ms {
                    self.go(slot)
                } else {
                    None
                }
            }
            (_, None) => None,
        }
    }

    /// The press ended on `final_slot` (its final decision): where the
    /// wheel must go, if it is not already its target.
    pub fn press_end(&mut self, final_slot: usize) -> Option<usize> {
        self.leader = None;
        self.go(final_slot)
    }

    fn go(&mut self, slot: usize) -> Option<usize> {
        if self.target == Some(slot) {
            return None;
        }
        self.target = Some(slot);
        Some(slot)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use telextiles_press::decide::{Decision, FlatIndex, Nearest2};

    fn index() -> FlatIndex {
        let t: Vec<(String, Vec<Vec<f32>>)> = (0..4)
            .map(|i| {
                let mut v = vec![0.0; 4];
                v[i] = 1.0;
                (format!("T{i}"), vec![v])
            })
            .collect();
        FlatIndex::from_embeddings(&t).unwrap()
    }

    fn step(best: usize, decision: Option<(usize, f32, u64)>) -> DecideStep {
        DecideStep {
            nearest: Nearest2 {
                best,
                best_dist: 0.1,
                second: Some((best + 1) % 4),
                second_dist: 0.2,
            },
            decision: decision.map(|(entry, confidence, since_us)| Decision {
                entry,
                slot: entry,
                distance: 0.1,
                margin: 0.1,
                confidence,
                unknown: false,
                since_us,
            }),
            changed: false,
        }
    }

    /// Frames 1/60 s apart from `t0`.
    fn at(i: u64) -> u64 {
        1_000_000 + i * 16_667
    }

    #[test]
    fn every_goes_to_each_decision_once_and_to_the_final_one() {
        let idx = index();
        let mut m = Motion::new(MotionPolicy::Every);
        m.press_start();
        assert_eq!(m.on_step(&idx, at(0), &step(2, None)), None);
        assert_eq!(
            m.on_step(&idx, at(1), &step(2, Some((2, 0.1, at(1))))),
            Some(2)
        );
        assert_eq!(
            m.on_step(&idx, at(2), &step(2, Some((2, 0.1, at(1))))),
            None
        );
        assert_eq!(
            m.on_step(&idx, at(3), &step(3, Some((3, 0.1, at(3))))),
            Some(3)
        );
        assert_eq!(m.press_end(3), None);
        assert_eq!(m.press_end(1), Some(1));
    }

    #[test]
    fn confident_waits_for_confidence_or_the_hold() {
        let idx = index();
        let policy = MotionPolicy::Confident {
            confidence: 0.5,
            hold_ms: 100.0,
        };
        let mut m = Motion::new(policy);
        m.press_start();
        // Unsure, held 0..83 ms: stays.
        for i in 1..=6 {
            assert_eq!(
                m.on_step(&idx, at(i), &step(1, Some((1, 0.2, at(1))))),
                None
            );
        }
        // Held 100 ms: goes.
        assert_eq!(
            m.on_step(&idx, at(7), &step(1, Some((1, 0.2, at(1))))),
            Some(1)
        );
        // A new decision that is sure goes at once.
        assert_eq!(
            m.on_step(&idx, at(8), &step(2, Some((2, 0.6, at(8))))),
            Some(2)
        );
        // A press that ends undecided by the policy still ends there.
        let mut m = Motion::new(policy);
        m.press_start();
        assert_eq!(
            m.on_step(&idx, at(1), &step(3, Some((3, 0.1, at(1))))),
            None
        );
        assert_eq!(m.press_end(3), Some(3));
    }

    #[test]
    fn lead_sets_off_before_the_decision_and_then_follows_it() {
        let idx = index();
        let mut m = Motion::new(MotionPolicy::Lead { lead_ms: 30.0 });
        m.press_start();
        assert_eq!(m.on_step(&idx, at(0), &step(2, None)), None);
        assert_eq!(m.on_step(&idx, at(1), &step(2, None)), None);
        // Led 33 ms: sets off.
        assert_eq!(m.on_step(&idx, at(2), &step(2, None)), Some(2));
        assert_eq!(m.on_step(&idx, at(3), &step(2, None)), None);
        // The decision, elsewhere, is followed at once.
        assert_eq!(
            m.on_step(&idx, at(4), &step(1, Some((1, 0.1, at(4))))),
            Some(1)
        );
        assert_eq!(m.press_end(1), None);
        // The next press starts afresh.
        m.press_start();
        assert_eq!(m.on_step(&idx, at(0), &step(1, None)), None);
    }

    #[test]
    fn track_follows_the_running_mean_whatever_the_decision() {
        let idx = index();
        let mut m = Motion::new(MotionPolicy::Track { lead_ms: 30.0 });
        m.press_start();
        assert_eq!(m.on_step(&idx, at(0), &step(1, None)), None);
        assert_eq!(m.on_step(&idx, at(2), &step(1, None)), Some(1));
        // The decision (still 1) holds while the mean's nearest is 3 for
        // 33 ms: the wheel follows the mean.
        assert_eq!(
            m.on_step(&idx, at(3), &step(3, Some((1, 0.1, at(2))))),
            None
        );
        assert_eq!(
            m.on_step(&idx, at(4), &step(3, Some((1, 0.1, at(2))))),
            None
        );
        assert_eq!(
            m.on_step(&idx, at(5), &step(3, Some((1, 0.1, at(2))))),
            Some(3)
        );
        // The press ends on the whole mean's nearest: already there.
        assert_eq!(m.press_end(3), None);
        // Alternating leaders never move it.
        m.press_start();
        for i in 0..60 {
            assert_eq!(
                m.on_step(&idx, at(i), &step(1 + (i as usize % 2), None)),
                None
            );
        }
    }

    #[test]
    fn a_leader_that_alternates_every_frame_never_moves_the_wheel() {
        let idx = index();
        let mut m = Motion::new(MotionPolicy::Lead { lead_ms: 30.0 });
        m.press_start();
        for i in 0..60 {
            assert_eq!(
                m.on_step(&idx, at(i), &step(1 + (i as usize % 2), None)),
                None
            );
        }
        assert_eq!(m.press_end(2), Some(2));
    }

    #[test]
    fn policies_parse_and_print_back() {
        for p in MotionPolicy::ALL {
            assert_eq!(p.to_string().parse::<MotionPolicy>(), Ok(p));
            assert_eq!(p.name().parse::<MotionPolicy>(), Ok(p));
        }
        assert_eq!(
            "confident:0.4".parse(),
            Ok(MotionPolicy::Confident {
                confidence: 0.4,
                hold_ms: 100.0
            })
        );
        assert_eq!("lead:0".parse(), Ok(MotionPolicy::Lead { lead_ms: 0.0 }));
        assert_eq!(
            "track:90".parse(),
            Ok(MotionPolicy::Track { lead_ms: 90.0 })
        );
        for bad in ["", "fast", "lead:x", "confident:2", "every:1", "lead:1:2"] {
            let e = bad.parse::<MotionPolicy>().unwrap_err();
            assert!(e.contains("motion policy"), "{bad}: {e}");
        }
    }
}
