//! Frames from the DIGIT press simulator (`telextiles-sim`).

use anyhow::{anyhow, Result};
use image::RgbImage;
use telextiles_sim::{PressSpec, Simulator};

use crate::data::{FrameSource, PressKey};

/// The simulator as a [`FrameSource`].
pub struct SimSource {
    sim: Simulator,
}

impl SimSource {
    /// Load the simulator (embedded calibration), catalogue 1.
    pub fn new() -> Result<Self> {
        Self::with_options(1, 1)
    }

    /// Catalogue `catalogue` (1 or 2) with texture generator `generator`
    /// (2, the cross-generator test set, needs catalogue 2).
    pub fn with_options(catalogue: u32, generator: u32) -> Result<Self> {
        Ok(SimSource {
            sim: Simulator::with_options(catalogue, generator)
                .map_err(|e| anyhow!("simulator: {e}"))?,
        })
    }

    fn spec(press: &PressKey) -> PressSpec {
        PressSpec {
            person: press.person,
            sensor: press.sensor,
            jig: press.jig,
            ..PressSpec::new(press.textile.clone(), press.seed)
        }
    }
}

impl FrameSource for SimSource {
    fn describe(&self) -> String {
        // Version 1 keeps its old description (and so its cache names).
        match self.sim.generator() {
            1 => format!("telextiles-sim catalogue v{}", self.sim.catalogue().version),
            g => format!(
                "telextiles-sim catalogue v{} generator {g}",
                self.sim.catalogue().version
            ),
        }
    }

    fn frames_per_press(&self) -> usize {
        telextiles_sim::PRESS_FRAMES
    }

    fn frames(&self, press: &PressKey, indices: &[usize]) -> Result<Vec<RgbImage>> {
        let spec = Self::spec(press);
        indices
            .iter()
            .map(|&i| {
                self.sim
                    .render_frame(&spec, i)
                    .map_err(|e| anyhow!("simulator: {e}"))
            })
            .collect()
    }

    fn contact_range(&self, press: &PressKey) -> Result<(usize, usize)> {
        let meta = self
            .sim
            .press_meta(&Self::spec(press))
            .map_err(|e| anyhow!("simulator: {e}"))?;
        let n = meta.timestamps_us.len();
        Ok(match meta.params {
            Some(p) => (
                p.hold_frame as usize,
                p.release_frame.map_or(n, |r| r as usize).min(n),
            ),
            None => (0, n),
        })
    }

    fn training_textiles(&self) -> Vec<String> {
        self.sim
            .catalogue()
            .training()
            .map(|t| t.id.clone())
            .collect()
    }

    fn unseen_textiles(&self) -> Vec<String> {
        self.sim
            .catalogue()
            .unseen()
            .map(|t| t.id.clone())
            .collect()
    }

    fn background(&self, sensor: u32) -> Result<Option<RgbImage>> {
        Ok(Some(self.sim.background(sensor)))
    }

    fn attributes(&self, textile: &str) -> Option<Vec<f32>> {
        self.sim
            .catalogue()
            .get(textile)
            .map(|t| t.attributes.to_vec().to_vec())
    }
}
