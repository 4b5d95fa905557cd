//! One contact detector's settings as the studies name them (entry
//! threshold, frames in a row, gain compensation, tile), shared by the
//! idle study (`contact_idle`) and the decider's timing (`decider_timing`).

use anyhow::{ensure, Result};
use serde::{Deserialize, Serialize};
use telextiles_sensing::contact::ContactConfig;

/// One contact detector: entry threshold (above the noise floor) and the
/// frames in a row over it that start a press.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Detector {
    pub enter: f32,
    pub frames: u32,
    /// `ContactConfig::gain_compensated`: the score is what is left after
    /// the best per-channel gain.
    #[serde(default)]
    pub gain: bool,
    /// `ContactConfig::tile`: the score is the most changed tile's, of
    /// `tile` x `tile` blocks of 4 px (0 = the whole frame's).
    #[serde(default, skip_serializing_if = "is_zero")]
    pub tile: u32,
}

fn is_zero(v: &u32) -> bool {
    *v == 0
}

impl Detector {
    /// The shipped detector's.
    pub fn shipped() -> Detector {
        let c = ContactConfig::default();
        Detector {
            enter: c.enter,
            frames: c.min_enter_frames,
            gain: c.gain_compensated,
            tile: c.tile,
        }
    }

    /// The detector the daemon shipped before this study (2026-11-29): the
    /// rule's baseline, and the detector of every `decider-timing` study
    /// that does not name one.
    pub fn before() -> Detector {
        Detector {
            enter: 0.35,
            frames: 3,
            gain: false,
            tile: 0,
        }
    }

    /// Of a contact configuration.
    pub fn of(c: &ContactConfig) -> Detector {
        Detector {
            enter: c.enter,
            frames: c.min_enter_frames,
            gain: c.gain_compensated,
            tile: c.tile,
        }
    }

    pub fn label(&self) -> String {
        format!(
            "{} DN × {}{}{}",
            self.enter,
            self.frames,
            if self.gain { ", gain-compensated" } else { "" },
            if self.tile > 0 {
                format!(", worst {} px tile", self.tile * 4)
            } else {
                String::new()
            }
        )
    }

    /// The shipped detector with this threshold and run
    /// ([`ContactConfig::with_entry`], as a user sets them in the daemon)
    /// and score.
    pub fn config(&self) -> Result<ContactConfig> {
        let mut c = ContactConfig::with_entry(self.enter, self.frames)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        c.gain_compensated = self.gain;
        let c = c.with_tile(self.tile).map_err(|e| anyhow::anyhow!("{e}"))?;
        ensure!(
            c.exit > 0.0 && c.exit < c.enter,
            "the contact detector needs 0 < exit ({}) < enter ({})",
            c.exit,
            c.enter
        );
        Ok(c)
    }
}
