//! [`SenderCore`]: what this side's presses send to its peers.

use telextiles_press::decide::{contact_weight, DecideConfig, PressMean};
use telextiles_press::{ContactEvent, Deepest};

use crate::clock::CaptureClock;
use crate::latent::Latent;

/// One frame as the front end left it, for [`SenderCore::on_sensed`].
#[derive(Clone, Copy, Debug)]
pub struct Sensed<'a> {
    /// The frame's own timestamp, on the source's clock.
    pub timestamp_us: u64,
    /// When it arrived from the source, on the local clock.
    pub arrived_us: u64,
    /// It is the first frame of another recording (a replay): a press in
    /// progress ends, and the capture clock starts afresh.
    pub new_recording: bool,
    /// The contact detector's event on it (times on the source's clock).
    pub event: Option<ContactEvent>,
    /// The contact detector's state after it.
    pub in_contact: bool,
    /// Its contact score (the detector's, reported at a press's start and end).
    pub score: f32,
    /// Its contact depth, which weighs its latent.
    pub depth: f32,
    /// The share of the gel its contact changed.
    pub coverage: f32,
    /// Its embedding, if it was encoded.
    pub embedding: Option<&'a [f32]>,
}

/// One of the run's earlier frames, encoded on the frame that starts a
/// press ([`SenderCore::on_sensed`] sends them first, in order).
#[derive(Clone, Copy, Debug)]
pub struct EarlierFrame<'a> {
    /// Its timestamp, on the source's clock.
    pub t_us: u64,
    /// Its embedding.
    pub embedding: &'a [f32],
    /// Its contact depth.
    pub depth: f32,
}

/// A press started or ended on this side's sensor: what the wiring
/// reports on the control socket (`contact` events).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactChange {
    /// A press started (else it ended).
    pub started: bool,
    /// The detector's score on the frame (None: the press ended because
    /// another recording began).
    pub score: Option<f32>,
    /// At an end, the press's coverage: its deepest frame's.
    pub coverage: Option<f32>,
}

/// A message for the peers (the wiring sends controls on the reliable
/// stream and latents as datagrams).
#[derive(Clone, Debug, PartialEq)]
pub enum TxAction {
    /// A press started.
    PressStart {
        /// Press number (wrapping).
        press_id: u32,
        /// When the contact detector started it: the capture time of the
        /// first frame of the run that started it (local clock), whether
        /// or not that frame was encoded. The receiver times the press's
        /// decisions from it, as `classify` does from the detector's start.
        capture_us: u64,
    },
    /// The latent of one frame in contact.
    Latent {
        /// Its press.
        press_id: u32,
        /// Capture time of the frame.
        capture_us: u64,
        /// The frame's latent.
        latent: Latent,
    },
    /// The press ended; `final_latent` is the mean of all its latents,
    /// weighted as the decider weights them (so a receiver that lost
    /// datagrams still decides on the whole press).
    PressStop {
        /// Its press.
        press_id: u32,
        /// Capture time of the frame that ended it.
        capture_us: u64,
        /// Mean latent of the press (None: no frame was encoded).
        final_latent: Option<Latent>,
    },
}

/// The sending half of a session: fed the front end's output frame by
/// frame, it numbers presses and produces the messages for the peers.
#[derive(Clone, Debug)]
pub struct SenderCore {
    dim: usize,
    press_id: u32,
    in_press: bool,
    /// The press's mean latent, weighted as the decider weights it (the
    /// default `depth_power`, which the receiver's decider uses too).
    sum: PressMean,
    frames: u32,
    /// Frame timestamps onto the local clock ([`SenderCore::on_sensed`]).
    clock: CaptureClock,
    /// The press's deepest frame so far: its coverage goes with the end.
    deepest: Deepest,
}

impl SenderCore {
    /// A sender of `dim`-dimensional latents.
    pub fn new(dim: usize) -> SenderCore {
        SenderCore {
            dim,
            press_id: 0,
            in_press: false,
            sum: PressMean::new(dim, DecideConfig::default().depth_power),
            frames: 0,
            clock: CaptureClock::new(),
            deepest: Deepest::default(),
        }
    }

    /// One frame through the front end, as the sensing thread has it: its
    /// timestamp mapped onto the local clock ([`CaptureClock`]: a press's
    /// frames keep the offset it began with, so its intervals are exactly
    /// the sensor's), a press in progress ended when another recording
    /// begins, the press's deepest frame kept for its coverage, the run's
    /// `earlier` frames sent first on the frame that starts a press (the
    /// press starting at the run's first frame), each latent weighted by
    /// its depth. Messages for the peers go to `out`, contact starts and
    /// ends to `contacts`; returns the frame's capture time (local clock).
    pub fn on_sensed(
        &mut self,
        f: &Sensed<'_>,
        earlier: &[EarlierFrame<'_>],
        out: &mut Vec<TxAction>,
        contacts: &mut Vec<ContactChange>,
    ) -> u64 {
        let capture_us = self.clock.stamp(f.timestamp_us, f.arrived_us);
        if f.new_recording {
            // Its frames owe nothing to the last recording's.
            self.clock.release();
            if self.in_press {
                self.stop(capture_us, out);
                contacts.push(ContactChange {
                    started: false,
                    score: None,
                    coverage: self.deepest.coverage(),
                });
            }
        }
        if matches!(f.event, Some(ContactEvent::PressStart { .. })) {
            self.deepest = Deepest::default();
        }
        if f.in_contact {
            self.deepest.add(f.depth, f.coverage);
        }
        let started = match f.event {
            Some(ContactEvent::PressStart { .. }) => Some(true),
            Some(ContactEvent::PressEnd { .. }) => Some(false),
            _ => None,
        };
        match started {
            Some(true) => self.clock.hold(),
            Some(false) => self.clock.release(),
            None => {}
        }
        if let Some(started) = started {
            contacts.push(ContactChange {
                started,
                score: Some(f.score),
                coverage: if started {
                    None
                } else {
                    self.deepest.coverage()
                },
            });
        }
        let mut event = f.event.map(|e| match e {
            ContactEvent::PressStart { t_us } => ContactEvent::PressStart {
                t_us: self.clock.map(t_us),
            },
            other => other,
        });
        for e in earlier {
            let t = self.clock.map(e.t_us);
            self.on_frame_weighted(
                t,
                event.take(),
                Some(e.embedding),
                contact_weight(e.depth),
                out,
            );
        }
        self.on_frame_weighted(capture_us, event, f.embedding, contact_weight(f.depth), out);
        capture_us
    }

    /// Whether a press is in progress.
    pub fn in_press(&self) -> bool {
        self.in_press
    }

    /// The current (or last) press number.
    pub fn press_id(&self) -> u32 {
        self.press_id
    }

    /// One frame: its capture time (local clock), the contact event it
    /// carried, and its embedding if it was encoded. Actions go to `out`.
    /// A `PressStart`'s `t_us` (the run's first frame) must be on the local
    /// clock too (the wiring maps it as it maps capture times); the press
    /// starts then, and never after the frame that reports it.
    /// An embedding that is not a valid latent (wrong dimension, non-finite,
    /// zero) is dropped and counted nowhere else: the encoder never makes one.
    pub fn on_frame(
        &mut self,
        capture_us: u64,
        event: Option<ContactEvent>,
        embedding: Option<&[f32]>,
        out: &mut Vec<TxAction>,
    ) {
        self.on_frame_weighted(capture_us, event, embedding, 1.0, out)
    }

    /// [`SenderCore::on_frame`] with the frame's weight in the press's mean
    /// (`telextiles_press::decide::contact_weight` of its contact score),
    /// which the latent carries as its length ([`Latent::wire`]).
    pub fn on_frame_weighted(
        &mut self,
        capture_us: u64,
        event: Option<ContactEvent>,
        embedding: Option<&[f32]>,
        weight: f32,
        out: &mut Vec<TxAction>,
    ) {
        match event {
            Some(ContactEvent::PressStart { t_us }) => {
                if self.in_press {
                    // Never two presses at once: close the open one first.
                    self.stop(capture_us, out);
                }
                self.press_id = self.press_id.wrapping_add(1);
                self.in_press = true;
                self.sum.clear();
                self.frames = 0;
                out.push(TxAction::PressStart {
                    press_id: self.press_id,
                    capture_us: t_us.min(capture_us),
                });
            }
            Some(ContactEvent::PressEnd { .. }) => self.stop(capture_us, out),
            _ => {}
        }
        if !self.in_press {
            return;
        }
        let Some(latent) = embedding.and_then(|e| Latent::new(e, self.dim).ok()) else {
            return;
        };
        let latent = latent.with_weight(weight);
        // Valid by construction: finite, unit length, weight in (0, 1].
        self.sum.add(latent.as_slice(), latent.weight());
        self.frames += 1;
        out.push(TxAction::Latent {
            press_id: self.press_id,
            capture_us,
            latent,
        });
    }

    /// End the press in progress, if any (also what the wiring calls when
    /// the sensor goes away mid-press).
    pub fn stop(&mut self, capture_us: u64, out: &mut Vec<TxAction>) {
        if !self.in_press {
            return;
        }
        self.in_press = false;
        let final_latent = (self.frames > 0)
            .then(|| Latent::new(self.sum.sum(), self.dim).ok())
            .flatten();
        out.push(TxAction::PressStop {
            press_id: self.press_id,
            capture_us,
            final_latent,
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn start(t: u64) -> Option<ContactEvent> {
        Some(ContactEvent::PressStart { t_us: t })
    }
    fn end(t: u64) -> Option<ContactEvent> {
        Some(ContactEvent::PressEnd {
            start_us: 0,
            t_us: t,
            reason: telextiles_press::EndReason::Released,
        })
    }

    #[test]
    fn latents_carry_their_contact_weight_and_the_final_mean_uses_it() {
        let mut s = SenderCore::new(2);
        let mut out = Vec::new();
        s.on_frame_weighted(20, start(20), Some(&[1.0, 0.0]), 0.9, &mut out);
        s.on_frame_weighted(30, None, Some(&[0.0, 1.0]), 0.1, &mut out);
        s.on_frame(40, end(40), None, &mut out);
        match &out[1] {
            TxAction::Latent { latent, .. } => {
                assert_eq!(latent.weight(), 0.9);
                assert_eq!(latent.wire(), vec![0.9, 0.0]);
            }
            other => panic!("{other:?}"),
        }
        match &out[3] {
            TxAction::PressStop {
                final_latent: Some(m),
                ..
            } => {
                // (1, 0) + (0.1 / 0.9)^p (0, 1), normalised: mostly the
                // deep frame, and the very mean a receiver's decider keeps
                // of these two latents.
                let p = DecideConfig::default().depth_power;
                assert!(p >= 1);
                let r = (0.1f32 / 0.9).powi(p as i32);
                let n = (1.0 + r * r).sqrt();
                assert!((m.as_slice()[0] - 1.0 / n).abs() < 1e-6, "{m:?}");
                let mut d = telextiles_press::decide::Decider::new(DecideConfig::default(), 2);
                d.press_start(20);
                for l in [&out[1], &out[2]] {
                    let TxAction::Latent { latent, .. } = l else {
                        panic!("{l:?}")
                    };
                    d.accumulate_weighted(latent.as_slice(), latent.weight());
                }
                assert_eq!(d.mean(), m.as_slice());
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn a_press_is_start_latents_and_stop_with_the_mean_latent() {
        let mut s = SenderCore::new(2);
        let mut out = Vec::new();
        s.on_frame(10, None, None, &mut out);
        assert!(out.is_empty());
        s.on_frame(20, start(20), Some(&[1.0, 0.0]), &mut out);
        s.on_frame(30, None, Some(&[0.0, 2.0]), &mut out);
        s.on_frame(35, None, Some(&[f32::NAN, 1.0]), &mut out);
        s.on_frame(36, None, Some(&[1.0, 1.0, 1.0]), &mut out);
        s.on_frame(40, end(40), None, &mut out);
        s.on_frame(50, None, Some(&[1.0, 0.0]), &mut out);
        assert_eq!(out.len(), 4, "{out:?}");
        assert!(matches!(
            out[0],
            TxAction::PressStart {
                press_id: 1,
                capture_us: 20
            }
        ));
        match &out[2] {
            TxAction::Latent {
                press_id: 1,
                capture_us: 30,
                latent,
            } => {
                assert_eq!(latent.as_slice(), &[0.0, 1.0])
            }
            other => panic!("{other:?}"),
        }
        match &out[3] {
            TxAction::PressStop {
                press_id: 1,
                capture_us: 40,
                final_latent: Some(m),
            } => {
                let h = std::f32::consts::FRAC_1_SQRT_2;
                assert!((m.as_slice()[0] - h).abs() < 1e-6 && (m.as_slice()[1] - h).abs() < 1e-6);
            }
            other => panic!("{other:?}"),
        }
        // A press with no encoded frame stops without a final latent; the
        // next press has the next number.
        out.clear();
        s.on_frame(60, start(60), None, &mut out);
        s.on_frame(70, end(70), None, &mut out);
        assert_eq!(
            out,
            [
                TxAction::PressStart {
                    press_id: 2,
                    capture_us: 60
                },
                TxAction::PressStop {
                    press_id: 2,
                    capture_us: 70,
                    final_latent: None
                }
            ]
        );
    }

    /// The detector starts a press on the last frame of a run over its
    /// threshold; the press begins at the run's first frame, as `classify`
    /// times it, whether that frame is encoded (`encode_run`) or not.
    #[test]
    fn a_press_begins_at_the_first_frame_of_the_run_that_started_it() {
        let mut s = SenderCore::new(1);
        let mut out = Vec::new();
        s.on_frame(16_667, None, None, &mut out);
        s.on_frame(33_333, start(16_667), Some(&[1.0]), &mut out);
        assert_eq!(
            out[0],
            TxAction::PressStart {
                press_id: 1,
                capture_us: 16_667
            }
        );
        assert!(matches!(
            out[1],
            TxAction::Latent {
                capture_us: 33_333,
                ..
            }
        ));
        // A start stamped after its frame (a clock mapped wrong) starts
        // at the frame.
        out.clear();
        s.on_frame(50_000, end(50_000), None, &mut out);
        s.on_frame(60_000, start(70_000), Some(&[1.0]), &mut out);
        assert_eq!(
            out[1],
            TxAction::PressStart {
                press_id: 2,
                capture_us: 60_000
            }
        );
    }

    #[test]
    fn a_start_during_a_press_closes_it_first_and_ids_wrap() {
        let mut s = SenderCore::new(1);
        s.press_id = u32::MAX;
        let mut out = Vec::new();
        s.on_frame(1, start(1), Some(&[1.0]), &mut out);
        s.on_frame(2, start(2), Some(&[1.0]), &mut out);
        let ids: Vec<_> = out
            .iter()
            .map(|a| match a {
                TxAction::PressStart { press_id, .. } => ("start", *press_id),
                TxAction::Latent { press_id, .. } => ("latent", *press_id),
                TxAction::PressStop { press_id, .. } => ("stop", *press_id),
            })
            .collect();
        assert_eq!(
            ids,
            [
                ("start", 0),
                ("latent", 0),
                ("stop", 0),
                ("start", 1),
                ("latent", 1)
            ]
        );
    }

    /// A frame of the test's source: timestamp `t` (source clock), arriving
    /// 0.5 s later on the local clock with `jitter` µs of delay on top.
    fn sensed(
        t: u64,
        jitter: u64,
        event: Option<ContactEvent>,
        depth: f32,
        coverage: f32,
    ) -> Sensed<'static> {
        const EMB: &[f32] = &[1.0, 0.0];
        Sensed {
            timestamp_us: t,
            arrived_us: t + 500_000 + jitter,
            new_recording: false,
            event,
            in_contact: depth > 0.0,
            score: depth,
            depth,
            coverage,
            embedding: (depth > 0.0).then_some(EMB),
        }
    }

    #[test]
    fn a_sensed_press_is_timed_by_its_frames_and_reports_its_deepest_coverage() {
        let mut s = SenderCore::new(2);
        let (mut out, mut contacts) = (Vec::new(), Vec::new());
        // Between presses: no message, and capture times the frames'
        // own, on the local clock (the least delay: 0.5 s).
        for k in 0..3u64 {
            let c = s.on_sensed(
                &sensed(k * 16_667, 3 * k, None, 0.0, 0.0),
                &[],
                &mut out,
                &mut contacts,
            );
            assert_eq!(c, k * 16_667 + 500_000);
        }
        assert!(out.is_empty() && contacts.is_empty());
        // The press starts on a frame whose run began two frames earlier:
        // both earlier frames go first, at their own times; the press
        // starts at the run's first frame.
        let earlier = [
            EarlierFrame {
                t_us: 50_000,
                embedding: &[0.0, 1.0],
                depth: 0.2,
            },
            EarlierFrame {
                t_us: 66_667,
                embedding: &[0.0, 1.0],
                depth: 0.4,
            },
        ];
        s.on_sensed(
            &sensed(83_333, 900, start(50_000), 0.6, 0.3),
            &earlier,
            &mut out,
            &mut contacts,
        );
        let times: Vec<u64> =
            out.iter()
                .map(|a| match a {
                    TxAction::PressStart { capture_us, .. }
                    | TxAction::Latent { capture_us, .. } => *capture_us,
                    other => panic!("{other:?}"),
                })
                .collect();
        assert_eq!(times, vec![550_000, 550_000, 566_667, 583_333]);
        assert_eq!(
            contacts,
            vec![ContactChange {
                started: true,
                score: Some(0.6),
                coverage: None
            }]
        );
        // Held: a frame of the press with more delay keeps the press's
        // offset, so the press's intervals are exactly the sensor's.
        out.clear();
        contacts.clear();
        let c = s.on_sensed(
            &sensed(100_000, 40_000, None, 0.9, 0.8),
            &[],
            &mut out,
            &mut contacts,
        );
        assert_eq!(c, 600_000);
        s.on_sensed(
            &sensed(116_667, 0, None, 0.5, 0.95),
            &[],
            &mut out,
            &mut contacts,
        );
        // The end reports the coverage of the deepest frame (0.9 deep),
        // not the widest.
        s.on_sensed(
            &sensed(133_333, 0, end(133_333), 0.0, 0.0),
            &[],
            &mut out,
            &mut contacts,
        );
        assert!(matches!(
            out.last(),
            Some(TxAction::PressStop {
                capture_us: 633_333,
                final_latent: Some(_),
                ..
            })
        ));
        assert_eq!(
            contacts,
            vec![ContactChange {
                started: false,
                score: Some(0.0),
                coverage: Some(0.8)
            }]
        );
    }

    #[test]
    fn another_recording_ends_the_press_in_progress() {
        let mut s = SenderCore::new(2);
        let (mut out, mut contacts) = (Vec::new(), Vec::new());
        s.on_sensed(
            &sensed(0, 0, start(0), 0.7, 0.6),
            &[],
            &mut out,
            &mut contacts,
        );
        s.on_sensed(
            &sensed(16_667, 0, None, 0.7, 0.6),
            &[],
            &mut out,
            &mut contacts,
        );
        contacts.clear();
        out.clear();
        // The next recording's first frame: its clock starts again at 0.
        let mut first = sensed(0, 0, None, 0.0, 0.0);
        first.new_recording = true;
        first.arrived_us = 2_000_000;
        s.on_sensed(&first, &[], &mut out, &mut contacts);
        assert!(!s.in_press());
        assert!(matches!(
            out.as_slice(),
            [TxAction::PressStop {
                press_id: 1,
                final_latent: Some(_),
                ..
            }]
        ));
        assert_eq!(
            contacts,
            vec![ContactChange {
                started: false,
                score: None,
                coverage: Some(0.6)
            }]
        );
        // Without another recording, nothing ends.
        let mut t = SenderCore::new(2);
        t.on_sensed(
            &sensed(0, 0, start(0), 0.7, 0.6),
            &[],
            &mut Vec::new(),
            &mut Vec::new(),
        );
        let (mut out2, mut c2) = (Vec::new(), Vec::new());
        t.on_sensed(&sensed(16_667, 0, None, 0.7, 0.6), &[], &mut out2, &mut c2);
        assert!(t.in_press() && c2.is_empty());
    }
}
