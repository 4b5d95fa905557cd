//! `classify --motion`: the simulated wheel driven through every press
//! under each motion policy asked for, from every starting sample
//! ([`telextiles_session::felt`]), its figures per press and per policy.

use std::path::Path;

use anyhow::{Context, Result};
use telextiles_index::Index;
use telextiles_sensing::pipeline::PressReport;
use telextiles_session::felt::{self, FeltTally};
use telextiles_session::MotionPolicy;

/// One press's wheel under one motion policy, over every starting sample.
#[derive(Clone, Debug, serde::Serialize)]
pub(crate) struct PressFelt {
    pub(crate) policy: String,
    pub(crate) starts: usize,
    pub(crate) felt_p50_ms: f64,
    pub(crate) felt_max_ms: f64,
    pub(crate) reversals_max: u32,
    pub(crate) wrong_rest_max_ms: f64,
    pub(crate) travel_mean_slots: f64,
    pub(crate) targets: u32,
}

/// The simulated wheel driven through every press under each motion
/// policy asked for ([`telextiles_session::felt`]).
pub(crate) struct Felts {
    pub(crate) wheel: roller_firmware::Config,
    pub(crate) policies: Vec<(MotionPolicy, FeltTally)>,
}

impl Felts {
    /// The wheel of `index`'s roller at `max_speed` (microsteps/s) and
    /// `accel` (microsteps/s²), under each of `motions` (none: the
    /// default policy).
    pub(crate) fn new(
        motions: &[MotionPolicy],
        max_speed: u32,
        accel: u32,
        index: &Index,
    ) -> Felts {
        let policies = if motions.is_empty() {
            vec![MotionPolicy::default()]
        } else {
            motions.to_vec()
        };
        Felts {
            wheel: roller_firmware::Config {
                slots: index.roller.slots.len().clamp(1, u16::MAX as usize) as u16,
                max_speed,
                accel,
                ..Default::default()
            },
            policies: policies
                .into_iter()
                .map(|p| (p, FeltTally::default()))
                .collect(),
        }
    }

    /// Drive the wheel through a decided press; `label` is right when the
    /// index holds it.
    pub(crate) fn press(&mut self, label: &str, r: &PressReport, index: &Index) -> Vec<PressFelt> {
        let Some(slot) = r.slot else {
            return Vec::new();
        };
        let right = index
            .entry_by_id(label)
            .map(|e| index.slot_of_entry(e) == slot);
        let wheel = self.wheel;
        self.policies
            .iter_mut()
            .map(|(policy, tally)| {
                let all = felt::replay(index, *policy, wheel, &r.steps, r.start_us, r.end_us, slot);
                let mut one = FeltTally::default();
                for f in &all {
                    tally.add(f, right);
                    one.add(f, None);
                }
                let s = one.summary();
                PressFelt {
                    policy: policy.to_string(),
                    starts: all.len(),
                    felt_p50_ms: s.felt_p50_ms,
                    felt_max_ms: all.iter().map(|f| f.felt_ms).fold(0.0, f64::max),
                    reversals_max: all.iter().map(|f| f.reversals).max().unwrap_or(0),
                    wrong_rest_max_ms: all.iter().map(|f| f.wrong_rest_ms).fold(0.0, f64::max),
                    travel_mean_slots: s.travel_mean_slots,
                    targets: all.first().map_or(0, |f| f.targets),
                }
            })
            .collect()
    }

    pub(crate) fn lines(&self) -> Vec<String> {
        self.policies
            .iter()
            .filter(|(_, t)| !t.is_empty())
            .map(|(p, t)| format!("wheel ({p}): {}", t.summary().line()))
            .collect()
    }

    pub(crate) fn write_json(&self, path: &Path) -> Result<()> {
        let v = serde_json::json!({
            "wheel": {
                "slots": self.wheel.slots,
                "microsteps_per_rev": self.wheel.steps_per_rev(),
                "max_speed": self.wheel.max_speed,
                "accel": self.wheel.accel,
            },
            "policies": self.policies.iter().map(|(p, t)| serde_json::json!({
                "policy": p.to_string(),
                "summary": t.summary(),
            })).collect::<Vec<_>>(),
        });
        // Whole or not at all: written beside, then renamed over.
        let tmp = path.with_extension("part");
        std::fs::write(&tmp, format!("{v:#}\n"))
            .and_then(|()| std::fs::rename(&tmp, path))
            .with_context(|| format!("cannot write {}", path.display()))
    }
}
