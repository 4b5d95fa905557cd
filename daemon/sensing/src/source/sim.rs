//! The simulator as a live frame source: presses of one textile, one after
//! another, separated by no-contact frames; the textile, person, sensor and
//! jig can be changed while running through a [`SimHandle`].
//!
//! The no-contact frames (before each press, and while lifted) are the
//! resting sensor of the current press ([`Simulator::idle_clip`]): the same
//! unit, camera noise, LED flicker and drift as the press's own frames, so
//! the contact detector's reference matches what the press shows before
//! its contact. (A noise-free background there made every press start with
//! a jump the detector took for contact, and the first decisions of a live
//! session came from it: `the_frames_between_presses_look_like_the_presses_own`.)

use std::sync::mpsc::{channel, Receiver, Sender};
use std::sync::Arc;
use std::time::Instant;

use telextiles_sim::{PressSpec, Simulator};

use super::recorded::Pace;
use super::{FrameSource, SourceError};
use crate::frame::Frame;

/// A change to the simulated press.
#[derive(Clone, Debug, PartialEq)]
pub enum SimCommand {
    /// Press another textile.
    Textile(String),
    /// Another person.
    Person(u32),
    /// Another sensor unit.
    Sensor(u32),
    /// With or without the jig.
    Jig(bool),
    /// Replace the whole spec.
    Spec(PressSpec),
    /// Press this once (after the gap), then rest lifted.
    PressOnce(PressSpec),
    /// Lift the sensor now and rest (no-contact frames) until the next command.
    Lift,
}

/// Controls a running [`SimSource`] from any thread.
#[derive(Clone, Debug)]
pub struct SimHandle(Sender<SimCommand>);

impl SimHandle {
    /// Send a change; it takes effect at the next frame (the current press is
    /// abandoned, a no-contact gap follows, then the new press). False if the
    /// source is gone.
    pub fn send(&self, cmd: SimCommand) -> bool {
        self.0.send(cmd).is_ok()
    }
    /// Press another textile.
    pub fn set_textile(&self, id: &str) -> bool {
        self.send(SimCommand::Textile(id.to_string()))
    }
}

/// Live simulated frames (see the module docs).
pub struct SimSource {
    sim: Arc<Simulator>,
    spec: PressSpec,
    rx: Receiver<SimCommand>,
    gap_frames: usize,
    /// Position: `gap_frames` background frames, then the press frames.
    pos: usize,
    /// The resting sensor of the current press, and the next frame of it.
    resting: Option<telextiles_sim::IdleClip>,
    resting_pos: usize,
    pace: Pace,
    started: Option<Instant>,
    seq: u64,
    presses: u64,
    /// Lifted: deliver no-contact frames only.
    idle: bool,
    /// Rest after the current press instead of repeating it.
    once: bool,
}

/// Frame period at 60 fps, microseconds (rounded as the simulator does).
fn frame_time_us(seq: u64) -> u64 {
    (seq * 1_000_000 + 30) / 60
}

impl SimSource {
    /// Start with `spec`; each press is preceded by `gap_frames` no-contact frames.
    pub fn new(
        sim: Arc<Simulator>,
        spec: PressSpec,
        gap_frames: usize,
        pace: Pace,
    ) -> Result<(SimSource, SimHandle), SourceError> {
        sim.press_meta(&spec)
            .map_err(|e| SourceError::Fatal(format!("simulator: {e}")))?;
        let (tx, rx) = channel();
        Ok((
            SimSource {
                sim,
                spec,
                rx,
                gap_frames,
                pos: 0,
                resting: None,
                resting_pos: 0,
                pace,
                started: None,
                seq: 0,
                presses: 0,
                idle: false,
                once: false,
            },
            SimHandle(tx),
        ))
    }

    /// Start lifted (no-contact frames) until a command says what to press.
    pub fn start_idle(mut self) -> Self {
        self.idle = true;
        self
    }

    /// The press being (or last) simulated.
    pub fn spec(&self) -> &PressSpec {
        &self.spec
    }

    /// Presses completed so far.
    pub fn presses(&self) -> u64 {
        self.presses
    }

    fn apply(&mut self, cmd: SimCommand) -> Result<(), SourceError> {
        let mut spec = self.spec.clone();
        self.once = false;
        match cmd {
            SimCommand::Lift => {
                self.idle = true;
                self.pos = 0;
                return Ok(());
            }
            SimCommand::PressOnce(s) => {
                spec = s;
                self.once = true;
            }
            SimCommand::Textile(t) => spec.textile = t,
            SimCommand::Person(p) => spec.person = p,
            SimCommand::Sensor(s) => spec.sensor = s,
            SimCommand::Jig(j) => spec.jig = j,
            SimCommand::Spec(s) => spec = s,
        }
        match self.sim.press_meta(&spec) {
            Ok(_) => {
                tracing::info!(
                    "simulator: now pressing {} (person {}, sensor {}, jig {})",
                    spec.textile,
                    spec.person,
                    spec.sensor,
                    spec.jig
                );
                self.spec = spec;
                self.resting = None;
                self.pos = 0;
                self.idle = false;
                Ok(())
            }
            Err(e) => {
                tracing::warn!("simulator: change refused: {e}");
                Ok(())
            }
        }
    }
}

impl FrameSource for SimSource {
    fn next_frame(&mut self, out: &mut Frame) -> Result<(), SourceError> {
        while let Ok(cmd) = self.rx.try_recv() {
            self.apply(cmd)?;
        }
        let t = frame_time_us(self.seq);
        if self.pace == Pace::RealTime {
            super::sleep_until_due(&mut self.started, t);
        }
        if self.idle || self.pos < self.gap_frames {
            if self.resting.is_none() {
                let clip = self
                    .sim
                    .idle_clip(&self.spec)
                    .map_err(|e| SourceError::Fatal(format!("simulator: {e}")))?;
                self.resting = Some(clip);
            }
            let clip = self.resting.as_ref().expect("set above");
            out.set_image(
                self.sim
                    .idle_frame(clip, self.resting_pos % clip.len().max(1))
                    .map_err(|e| SourceError::Fatal(format!("simulator: {e}")))?,
            )?;
            self.resting_pos += 1;
        } else {
            let i = self.pos - self.gap_frames;
            out.set_image(
                self.sim
                    .render_frame(&self.spec, i)
                    .map_err(|e| SourceError::Fatal(format!("simulator: {e}")))?,
            )?;
        }
        out.set_time(t, self.seq);
        self.seq += 1;
        if self.idle {
            return Ok(());
        }
        self.pos += 1;
        if self.pos >= self.gap_frames + self.spec.frames {
            self.pos = 0;
            self.presses += 1;
            self.spec.seed = self.spec.seed.wrapping_add(1);
            self.resting = None;
            if self.once {
                self.idle = true;
                self.once = false;
            }
        }
        Ok(())
    }

    fn describe(&self) -> String {
        format!(
            "simulator ({} person {} sensor {} jig {})",
            self.spec.textile, self.spec.person, self.spec.sensor, self.spec.jig
        )
    }
}
