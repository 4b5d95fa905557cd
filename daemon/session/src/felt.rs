//! Felt latency: from the sender's contact until the wheel rests at the
//! sample the press ends on, the time the receiving hand waits.
//!
//! [`drive`] runs the roller's own firmware core (`roller_firmware::Roller`,
//! the code the ESP32 runs) in simulated time through a press's roller
//! targets, as [`crate::motion::Motion`] sends them, and measures what the
//! hand meets: when the wheel came to rest for good at the final sample,
//! how far it went, how often it turned back, and how long it stood still
//! at a sample the press did not end on. [`replay`] does it for a press
//! the pipeline decided offline (`classify`, the lab), from every starting
//! sample in turn: the previous press may have left the wheel anywhere.
//!
//! Time is the sender's capture clock: a target is sent at the capture time
//! of the frame that caused it. The link (capture → decision, about 2 ms on
//! a LAN) and the serial write (a few ms) are not in these figures; the
//! live session's are ([`LiveFelt`], fed by the receiving daemon with its
//! own clock and the roller's real arrivals).

use roller_firmware::{Config as WheelConfig, Roller};
use telextiles_press::decide::{DecideStep, TextileIndex};
use telextiles_proto::roller::{slot_to_steps, Command};

use crate::motion::{Motion, MotionPolicy};

/// What one press did to the wheel.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Felt {
    /// Contact → the wheel at rest at the final sample for good (ms); 0
    /// when it was there at contact and never left.
    pub felt_ms: f64,
    /// Distance travelled, in slots.
    pub travel_slots: f64,
    /// Changes of direction while moving.
    pub reversals: u32,
    /// Time at rest, after the wheel first set off in this press, at a
    /// sample the press did not end on (ms).
    pub wrong_rest_ms: f64,
    /// Targets sent to the wheel.
    pub targets: u32,
}

/// Drive the firmware core, from rest at `start_slot`, through `targets`
/// (`(time_us, slot)`, in time order, none before `contact_us`); the wheel
/// must end at `final_slot` (the last target, or `start_slot` when none).
/// Slots are the firmware's (`cfg.slots`).
pub fn drive(
    cfg: WheelConfig,
    start_slot: usize,
    contact_us: u64,
    targets: &[(u64, usize)],
) -> Felt {
    let slots = cfg.slots.max(1);
    let spr = cfg.steps_per_rev();
    let steps_per_slot = spr as f64 / slots as f64;
    let slot_steps = |s: usize| slot_to_steps(s as u16 % slots, slots, spr) as i64;
    let final_slot = targets.last().map_or(start_slot, |t| t.1);
    let mut felt = Felt {
        targets: targets.len() as u32,
        ..Felt::default()
    };
    let mut w = Run {
        fw: Roller::new(cfg).with_position(slot_steps(start_slot)),
        steps: 0,
        reversals: 0,
        last_dir: None,
        rest_since: None,
        arrived: contact_us,
        sink: [0; 512],
    };
    // Where the wheel is going.
    let mut heading = start_slot;
    let mut seq = 0u8;
    for &(t, slot) in targets {
        let t = t.max(contact_us);
        w.run_until(Some(t));
        seq = seq.wrapping_add(1);
        let cmd = Command::GotoSlot {
            slot: (slot % slots as usize) as u16,
        }
        .encode(seq);
        w.fw.receive(cmd.as_bytes(), t);
        w.fw.take_output(&mut w.sink);
        if w.fw.planner().is_moving() {
            if let Some(since) = w.rest_since.take() {
                if heading != final_slot {
                    felt.wrong_rest_ms += t.saturating_sub(since) as f64 / 1000.0;
                }
            }
        }
        heading = slot;
    }
    w.run_until(None);
    let fw = &w.fw;
    let (steps, arrived) = (w.steps, w.arrived);
    felt.reversals = w.reversals;
    debug_assert_eq!(
        fw.absolute_steps().rem_euclid(spr as i64),
        slot_steps(final_slot)
    );
    felt.felt_ms = arrived.saturating_sub(contact_us) as f64 / 1000.0;
    felt.travel_slots = steps as f64 / steps_per_slot;
    felt
}

/// The firmware core stepped in simulated time, and what its steps did.
struct Run {
    fw: Roller,
    steps: u64,
    reversals: u32,
    last_dir: Option<i8>,
    /// When the wheel last came to rest after a move.
    rest_since: Option<u64>,
    /// When the wheel last came to rest (contact, if it never moved).
    arrived: u64,
    sink: [u8; 512],
}

impl Run {
    /// Takes every step due up to `until` (all of them: None).
    fn run_until(&mut self, until: Option<u64>) {
        while let Some(at) = self.fw.next_step_at() {
            if until.is_some_and(|u| at > u) {
                break;
            }
            if let Some(dir) = self.fw.step(at) {
                self.steps += 1;
                if self.last_dir.is_some_and(|d| d != dir) {
                    self.reversals += 1;
                }
                self.last_dir = Some(dir);
                if !self.fw.planner().is_moving() {
                    self.rest_since = Some(at);
                    self.arrived = at;
                }
            }
            // Replies (acks, status, arrival) are not read here.
            self.fw.take_output(&mut self.sink);
        }
    }
}

/// The roller targets a press sends under `policy`: the decider's state
/// after each frame (`steps`, with the frames' times), then its end at
/// `end_us` on `final_slot`.
pub fn targets<I: TextileIndex + ?Sized>(
    index: &I,
    policy: MotionPolicy,
    steps: &[(u64, DecideStep)],
    end_us: u64,
    final_slot: usize,
) -> Vec<(u64, usize)> {
    let mut m = Motion::new(policy);
    m.press_start();
    let mut out: Vec<(u64, usize)> = steps
        .iter()
        .filter_map(|(t, s)| m.on_step(index, *t, s).map(|slot| (*t, slot)))
        .collect();
    out.extend(m.press_end(final_slot).map(|s| (end_us, s)));
    out
}

/// A press decided offline, driven from every starting sample of the wheel
/// in turn (the previous press may have left it anywhere): one [`Felt`]
/// per starting slot.
pub fn replay<I: TextileIndex + ?Sized>(
    index: &I,
    policy: MotionPolicy,
    cfg: WheelConfig,
    steps: &[(u64, DecideStep)],
    contact_us: u64,
    end_us: u64,
    final_slot: usize,
) -> Vec<Felt> {
    let t = targets(index, policy, steps, end_us, final_slot);
    (0..cfg.slots.max(1) as usize)
        .map(|start| drive(cfg, start, contact_us, &t))
        .collect()
}

/// Felt figures over many presses (and starting samples).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FeltTally {
    felt_ms: Vec<f64>,
    wrong_rest_ms: Vec<f64>,
    reversals: Vec<u32>,
    /// Felt latency of the pairs whose final sample is the right one.
    right_felt_ms: Vec<f64>,
    travel: f64,
    /// Presses (times starting samples) whose wheel rested at the right
    /// textile's sample, where the right one is known.
    pub right: u64,
    /// Of how many with a known right textile.
    pub labelled: u64,
}

/// A summary of a [`FeltTally`].
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FeltSummary {
    /// How many (press, starting sample) pairs.
    pub n: usize,
    /// Contact → at rest at the final sample, median and 90th percentile.
    pub felt_p50_ms: f64,
    /// See `felt_p50_ms`.
    pub felt_p90_ms: f64,
    /// Right at rest (%), where labelled.
    pub right_at_rest_pct: Option<f64>,
    /// Reversals per press, 90th percentile.
    pub reversals_p90: u32,
    /// Time at rest at a wrong sample, 90th percentile (ms).
    pub wrong_rest_p90_ms: f64,
    /// Mean travel, slots.
    pub travel_mean_slots: f64,
}

/// Nearest-rank percentile of sorted values.
fn pct<T: Copy + Default>(sorted: &[T], p: f64) -> T {
    if sorted.is_empty() {
        return T::default();
    }
    let k = ((p / 100.0) * sorted.len() as f64).ceil() as usize;
    sorted[k.clamp(1, sorted.len()) - 1]
}

impl FeltTally {
    /// Count one press's figures; `right`: whether its final sample is the
    /// right textile's (None when unlabelled).
    pub fn add(&mut self, felt: &Felt, right: Option<bool>) {
        self.felt_ms.push(felt.felt_ms);
        self.wrong_rest_ms.push(felt.wrong_rest_ms);
        self.reversals.push(felt.reversals);
        self.travel += felt.travel_slots;
        if let Some(r) = right {
            self.labelled += 1;
            self.right += u64::from(r);
            if r {
                self.right_felt_ms.push(felt.felt_ms);
            }
        }
    }

    /// The share (%) of labelled pairs whose wheel is at rest at the right
    /// sample for good `t_ms` after contact (None when none is labelled):
    /// rises with the felt latency to the share right at rest.
    pub fn right_at_rest_by(&self, t_ms: f64) -> Option<f64> {
        (self.labelled > 0).then(|| {
            let n = self.right_felt_ms.iter().filter(|&&f| f <= t_ms).count();
            100.0 * n as f64 / self.labelled as f64
        })
    }

    /// How many added.
    pub fn len(&self) -> usize {
        self.felt_ms.len()
    }

    /// Whether none were added.
    pub fn is_empty(&self) -> bool {
        self.felt_ms.is_empty()
    }

    /// The figures.
    pub fn summary(&self) -> FeltSummary {
        let mut f = self.felt_ms.clone();
        f.sort_by(f64::total_cmp);
        let mut w = self.wrong_rest_ms.clone();
        w.sort_by(f64::total_cmp);
        let mut r = self.reversals.clone();
        r.sort_unstable();
        FeltSummary {
            n: f.len(),
            felt_p50_ms: pct(&f, 50.0),
            felt_p90_ms: pct(&f, 90.0),
            right_at_rest_pct: (self.labelled > 0)
                .then(|| 100.0 * self.right as f64 / self.labelled as f64),
            reversals_p90: pct(&r, 90.0),
            wrong_rest_p90_ms: pct(&w, 90.0),
            travel_mean_slots: if f.is_empty() {
                0.0
            } else {
                self.travel / f.len() as f64
            },
        }
    }
}

impl FeltSummary {
    /// One line for a person.
    pub fn line(&self) -> String {
        let right = self
            .right_at_rest_pct
            .map_or(String::new(), |r| format!(", right at rest {r:.1} %"));
        format!(
            "felt latency (contact -> wheel at rest at the final sample) p50 {:.0} ms, p90 {:.0} ms{right}; reversals p90 {}; at rest at a wrong sample p90 {:.0} ms; travel {:.2} slots per press ({} presses x starting samples)",
            self.felt_p50_ms,
            self.felt_p90_ms,
            self.reversals_p90,
            self.wrong_rest_p90_ms,
            self.travel_mean_slots,
            self.n
        )
    }
}

/// A live press's felt latency, measured where the wheel is.
#[derive(Clone, Debug, PartialEq)]
pub struct FeltEvent {
    /// Whose press.
    pub peer: String,
    /// Which press.
    pub press_id: u32,
    /// The sample it ended on.
    pub slot: usize,
    /// Contact on the peer's sensor → the wheel at rest at `slot` (ms).
    pub felt_ms: f64,
}

#[derive(Clone, Debug, PartialEq)]
struct Waiting {
    peer: String,
    press_id: u32,
    contact_us: u64,
    slot: usize,
}

/// Felt latency of live presses on the local clock: fed the press's final
/// decision (with when its contact was, on the local clock), the targets
/// sent to the wheel and the wheel's arrivals; says when a press's wheel
/// came to rest at its final sample. One wheel, so one press at a time is
/// followed: a newer final decision replaces a waiting one.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LiveFelt {
    /// The slot the wheel rests at, and since when (None while moving or
    /// unknown).
    at_rest: Option<(usize, u64)>,
    waiting: Option<Waiting>,
}

impl LiveFelt {
    /// A target was sent to the wheel at `now_us`.
    pub fn target(&mut self, slot: usize, _now_us: u64) {
        if self.at_rest.is_some_and(|(s, _)| s != slot) {
            self.at_rest = None;
        }
    }

    /// The wheel reported itself at rest at `slot` at `now_us`.
    pub fn arrived(&mut self, slot: usize, now_us: u64) -> Option<FeltEvent> {
        // A target it already stood at is "arrived" again at once: it
        // rests there since it first came.
        match self.at_rest {
            Some((s, _)) if s == slot => {}
            _ => self.at_rest = Some((slot, now_us)),
        }
        self.settle()
    }

    /// A press's final decision, made at `now_us`, sends the wheel to
    /// `slot`; its contact was at `contact_us` (local clock).
    pub fn final_decision(
        &mut self,
        peer: &str,
        press_id: u32,
        contact_us: u64,
        slot: usize,
    ) -> Option<FeltEvent> {
        self.waiting = Some(Waiting {
            peer: peer.to_string(),
            press_id,
            contact_us,
            slot,
        });
        self.settle()
    }

    fn settle(&mut self) -> Option<FeltEvent> {
        let (slot, since) = self.at_rest?;
        if self.waiting.as_ref()?.slot != slot {
            return None;
        }
        let w = self.waiting.take()?;
        Some(FeltEvent {
            peer: w.peer,
            press_id: w.press_id,
            slot,
            felt_ms: since.saturating_sub(w.contact_us) as f64 / 1000.0,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn live_felt_waits_for_the_wheel_at_the_final_sample() {
        let mut l = LiveFelt::default();
        // Contact at 1.0 s; the wheel set off for 3, then 5.
        l.target(3, 1_100_000);
        assert_eq!(l.arrived(3, 1_250_000), None);
        l.target(5, 1_300_000);
        // The final decision (5) comes before the wheel is there.
        assert_eq!(l.final_decision("a", 7, 1_000_000, 5), None);
        let e = l.arrived(5, 1_480_000).unwrap();
        assert_eq!((e.press_id, e.slot, e.felt_ms), (7, 5, 480.0));
        // Once only.
        assert_eq!(l.arrived(5, 1_500_000), None);
        // Next press: the wheel already rests at its final sample (since
        // 1.48 s, before this contact): felt at once.
        let e = l.final_decision("a", 8, 2_000_000, 5).unwrap();
        assert_eq!(e.felt_ms, 0.0);
        // A press whose wheel got there during it: from contact to then.
        l.target(2, 3_050_000);
        l.arrived(2, 3_200_000);
        let e = l.final_decision("b", 1, 3_000_000, 2).unwrap();
        assert_eq!((e.peer.as_str(), e.felt_ms), ("b", 200.0));
        // Re-sending the target it stands at keeps the time it came.
        l.target(2, 3_400_000);
        assert_eq!(l.arrived(2, 3_410_000), None);
        let e = l.final_decision("b", 2, 3_100_000, 2).unwrap();
        assert_eq!(e.felt_ms, 100.0);
    }

    fn wheel() -> WheelConfig {
        WheelConfig::default()
    }

    #[test]
    fn already_there_is_felt_at_once() {
        let f = drive(wheel(), 3, 1_000, &[(50_000, 3)]);
        assert_eq!(f.felt_ms, 0.0);
        assert_eq!(f.travel_slots, 0.0);
        assert_eq!((f.reversals, f.wrong_rest_ms), (0, 0.0));
    }

    #[test]
    fn one_target_is_the_decision_time_plus_the_move() {
        // Decided 85 ms after contact, four slots away: 85 + 183 ms.
        let f = drive(wheel(), 0, 1_000_000, &[(1_085_000, 4)]);
        assert!((f.felt_ms - 267.6).abs() < 3.0, "{f:?}");
        assert_eq!(f.travel_slots, 4.0);
        assert_eq!(f.reversals, 0);
        // The shorter way round: from 2 to 14 is four slots back.
        let f = drive(wheel(), 2, 0, &[(0, 14)]);
        assert_eq!(f.travel_slots, 4.0);
    }

    #[test]
    fn a_change_of_mind_after_arriving_counts_the_wrong_rest_and_the_reversal() {
        // To slot 2 at 0 (arrives at ~129 ms), then back to 1 at 400 ms.
        let f = drive(wheel(), 0, 0, &[(0, 2), (400_000, 1)]);
        assert!((f.wrong_rest_ms - 271.0).abs() < 3.0, "{f:?}");
        assert_eq!(f.reversals, 1);
        assert_eq!(f.travel_slots, 3.0);
        assert!((f.felt_ms - 491.3).abs() < 3.0, "{f:?}");
    }

    #[test]
    fn a_change_of_mind_while_moving_turns_without_resting() {
        let f = drive(wheel(), 0, 0, &[(0, 4), (50_000, 6)]);
        assert_eq!(f.wrong_rest_ms, 0.0);
        assert_eq!(f.reversals, 0);
        assert_eq!(f.travel_slots, 6.0);
        // Sooner than going to 4, then on to 6.
        let two_moves = drive(wheel(), 0, 0, &[(0, 4), (400_000, 6)]);
        assert!(f.felt_ms < two_moves.felt_ms - 100.0, "{f:?} {two_moves:?}");
    }

    #[test]
    fn the_tally_reports_percentiles() {
        let mut t = FeltTally::default();
        for i in 1..=10 {
            let f = Felt {
                felt_ms: i as f64 * 100.0,
                travel_slots: 2.0,
                reversals: u32::from(i == 10),
                wrong_rest_ms: if i >= 9 { 50.0 } else { 0.0 },
                targets: 1,
            };
            t.add(&f, Some(i <= 8));
        }
        let s = t.summary();
        assert_eq!(t.right_at_rest_by(0.0), Some(0.0));
        assert_eq!(t.right_at_rest_by(250.0), Some(20.0));
        assert_eq!(t.right_at_rest_by(10_000.0), Some(80.0));
        assert_eq!((s.felt_p50_ms, s.felt_p90_ms), (500.0, 900.0));
        assert_eq!(s.right_at_rest_pct, Some(80.0));
        assert_eq!((s.reversals_p90, s.wrong_rest_p90_ms), (0, 50.0));
        assert_eq!(s.travel_mean_slots, 2.0);
        assert!(s.line().contains("p50 500 ms"));
    }
}
