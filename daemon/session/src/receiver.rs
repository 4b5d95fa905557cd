//! [`ReceiverCore`]: what peers' presses do here.

use std::collections::BTreeMap;
use std::sync::Arc;

use telextiles_press::decide::{DecideConfig, Decider, TextileIndex};

use crate::latent::Latent;
use crate::motion::{Motion, MotionPolicy};

/// Receiver tuning.
#[derive(Clone, Debug, PartialEq)]
pub struct ReceiverConfig {
    /// Hysteresis of the per-press decisions.
    pub decide: DecideConfig,
    /// Every n-th latent of a peer is also a map touch (0 = none).
    pub touch_every: u64,
    /// Peers tracked at once (the least recently heard one is forgotten
    /// beyond this).
    pub max_peers: usize,
    /// When the wheel moves during a press ([`crate::motion`]).
    pub motion: MotionPolicy,
}

impl Default for ReceiverConfig {
    fn default() -> Self {
        ReceiverConfig {
            decide: DecideConfig::default(),
            touch_every: 6,
            max_peers: 64,
            motion: MotionPolicy::default(),
        }
    }
}

/// A message from a peer, as the link decoded it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RxInput<'a> {
    /// The peer's press started.
    PressStart {
        /// Its number.
        press_id: u32,
        /// Capture time of its first frame (peer's clock).
        capture_us: u64,
    },
    /// A frame's latent (a datagram: may be lost, late, duplicated).
    Latent {
        /// Its press.
        press_id: u32,
        /// Datagram sequence number.
        seq: u64,
        /// Capture time (peer's clock).
        capture_us: u64,
        /// The dequantised vector, unchecked.
        vector: &'a [f32],
        /// Capture there → receipt here, from the link's clock-offset
        /// estimate (None before the first pong).
        one_way_latency_us: Option<i64>,
    },
    /// The peer's press ended.
    PressStop {
        /// Its number.
        press_id: u32,
        /// Capture time of the frame that ended it (peer's clock).
        capture_us: u64,
        /// The press's mean latent, unchecked, with its capture time.
        final_latent: Option<(&'a [f32], u64)>,
    },
    /// The peer disconnected.
    PeerDown,
}

/// A decision about a peer's press.
#[derive(Clone, Debug, PartialEq)]
pub struct RxDecision {
    /// Whose press.
    pub peer: String,
    /// Which press.
    pub press_id: u32,
    /// Index entry decided.
    pub entry: usize,
    /// Its roller slot.
    pub slot: usize,
    /// Distance of the press's latent(s) to it.
    pub distance: f32,
    /// Further than the index's unknown-textile distance from every
    /// textile (`Decider::unknown_beyond`): the nearest known one.
    pub unknown: bool,
    /// Capture there → this decision, where the link knows the clock
    /// offset.
    pub latency_ms: Option<f64>,
    /// First contact there → this decision (the press's duration on the
    /// peer's clock plus the one-way latency).
    pub since_contact_ms: Option<f64>,
    /// The press ended: this is its final answer.
    pub final_decision: bool,
    /// The decided textile differs from this press's previous decision.
    pub changed: bool,
}

/// What the wiring must do.
#[derive(Clone, Debug, PartialEq)]
pub enum RxAction {
    /// A peer's press began here.
    PressStarted {
        /// Whose.
        peer: String,
        /// Which.
        press_id: u32,
    },
    /// A decision was made or changed, or a press's final answer.
    Decision(RxDecision),
    /// Turn the roller to this slot (latest target wins), as the motion
    /// policy says.
    RollerTarget {
        /// The slot.
        slot: usize,
    },
    /// Where a peer's touch falls on the map.
    Touch {
        /// Whose.
        peer: String,
        /// The latent.
        latent: Latent,
    },
    /// A message was refused (malformed); nothing else changed.
    Refused {
        /// From whom.
        peer: String,
        /// Why (for a rate-limited log).
        why: String,
    },
}

struct RxPress {
    press_id: u32,
    contact_capture_us: u64,
    decider: Decider,
    motion: Motion,
    decided: Option<usize>,
    latency_us: Option<i64>,
    latents: u64,
}

/// Finished presses remembered per peer (to ignore their late messages).
const FINISHED_KEPT: usize = 8;

#[derive(Default)]
struct PeerState {
    press: Option<RxPress>,
    /// The press before `press`, replaced before its stop came (the next
    /// press's datagrams overtook the stop on the control stream): its
    /// stop still gives its final answer.
    superseded: Option<RxPress>,
    finished: std::collections::VecDeque<u32>,
    heard: u64,
}

/// The receiving half of a session (see the crate docs).
pub struct ReceiverCore<I: TextileIndex> {
    index: Arc<I>,
    cfg: ReceiverConfig,
    peers: BTreeMap<String, PeerState>,
    tick: u64,
}

impl<I: TextileIndex> ReceiverCore<I> {
    /// A receiver deciding against `index`.
    pub fn new(index: Arc<I>, cfg: ReceiverConfig) -> Self {
        ReceiverCore {
            index,
            cfg,
            peers: BTreeMap::new(),
            tick: 0,
        }
    }

    /// The index.
    pub fn index(&self) -> &I {
        &self.index
    }

    /// Peers with state here.
    pub fn peers(&self) -> usize {
        self.peers.len()
    }

    /// The press of `peer` in progress, if any.
    pub fn press_of(&self, peer: &str) -> Option<u32> {
        self.peers.get(peer)?.press.as_ref().map(|p| p.press_id)
    }

    /// The state of `peer` (made, evicting the least recently heard peer
    /// beyond `max_peers`, only the first time: no allocation per message).
    fn peer(&mut self, peer: &str) -> &mut PeerState {
        self.tick += 1;
        if !self.peers.contains_key(peer) {
            if self.peers.len() >= self.cfg.max_peers.max(1) {
                if let Some(oldest) = self
                    .peers
                    .iter()
                    .min_by_key(|(_, s)| s.heard)
                    .map(|(k, _)| k.clone())
                {
                    self.peers.remove(&oldest);
                }
            }
            self.peers.insert(peer.to_string(), PeerState::default());
        }
        let s = self.peers.get_mut(peer).expect("inserted above");
        s.heard = self.tick;
        s
    }

    /// A message of `peer`'s control stream, as the link delivers it:
    /// press starts and stops go in ([`ReceiverCore::handle`]); the link's
    /// own messages (hello, clock probes, pairing, errors) are not the
    /// session's and are left alone.
    pub fn on_control(
        &mut self,
        peer: &str,
        msg: &telextiles_proto::peer::Control,
        out: &mut Vec<RxAction>,
    ) {
        use telextiles_proto::peer::Control;
        match msg {
            Control::PressStart {
                press_id,
                capture_us,
            } => self.handle(
                peer,
                RxInput::PressStart {
                    press_id: *press_id,
                    capture_us: *capture_us,
                },
                out,
            ),
            Control::PressStop {
                press_id,
                capture_us,
                final_latent,
            } => {
                let fin = final_latent
                    .as_ref()
                    .map(|l| (l.vector.dequantize(), l.capture_us));
                self.handle(
                    peer,
                    RxInput::PressStop {
                        press_id: *press_id,
                        capture_us: *capture_us,
                        final_latent: fin.as_ref().map(|(v, t)| (v.as_slice(), *t)),
                    },
                    out,
                );
            }
            _ => {}
        }
    }

    /// One message from `peer`; actions go to `out`.
    pub fn handle(&mut self, peer: &str, input: RxInput<'_>, out: &mut Vec<RxAction>) {
        let dim = self.index.dim();
        match input {
            RxInput::PeerDown => {
                self.peers.remove(peer);
            }
            RxInput::PressStart {
                press_id,
                capture_us,
            } => {
                self.start(peer, press_id, capture_us, out);
            }
            RxInput::Latent {
                press_id,
                seq,
                capture_us,
                vector,
                one_way_latency_us,
            } => {
                let latent = match Latent::new(vector, dim) {
                    Ok(l) => l,
                    Err(e) => {
                        out.push(RxAction::Refused {
                            peer: peer.to_string(),
                            why: format!("latent of press {press_id}: {e}"),
                        });
                        return;
                    }
                };
                if !self.start(peer, press_id, capture_us, out) {
                    return;
                }
                let touch_every = self.cfg.touch_every;
                let index = self.index.clone();
                let st = self.peer(peer);
                let Some(p) = st.press.as_mut() else {
                    return;
                };
                p.latents += 1;
                if one_way_latency_us.is_some() {
                    p.latency_us = one_way_latency_us;
                }
                if touch_every > 0 && seq % touch_every == 0 {
                    out.push(RxAction::Touch {
                        peer: peer.to_string(),
                        latent: latent.clone(),
                    });
                }
                let Some(step) = p.decider.on_embedding_weighted(
                    &*index,
                    capture_us,
                    latent.as_slice(),
                    latent.weight(),
                ) else {
                    return;
                };
                if let Some(slot) = p.motion.on_step(&*index, capture_us, &step) {
                    out.push(RxAction::RollerTarget { slot });
                }
                if let (true, Some(d)) = (step.changed, step.decision) {
                    Self::decide(
                        &*index, peer, p, d.entry, d.distance, capture_us, false, true, out,
                    );
                }
            }
            RxInput::PressStop {
                press_id,
                capture_us,
                final_latent,
            } => {
                let checked = final_latent.map(|(v, t)| (Latent::new(v, dim), t));
                if let Some((Err(e), _)) = &checked {
                    out.push(RxAction::Refused {
                        peer: peer.to_string(),
                        why: format!("final latent of press {press_id}: {e}"),
                    });
                }
                let good = checked.and_then(|(l, t)| l.ok().map(|l| (l, t)));
                // The stop of a press that the next one already replaced:
                // its final answer still counts (events, records, the felt
                // log), but the roller stays with the press under the hand.
                let st = self.peer(peer);
                if st
                    .superseded
                    .as_ref()
                    .is_some_and(|p| p.press_id == press_id)
                {
                    let Some(mut p) = st.superseded.take() else {
                        return;
                    };
                    Self::finish(st, press_id);
                    let index = self.index.clone();
                    if let Some((entry, distance, t)) =
                        Self::final_answer(&*index, &mut p, &good, capture_us)
                    {
                        Self::decide(&*index, peer, &mut p, entry, distance, t, true, false, out);
                    }
                    return;
                }
                // A stop for a press never seen (its start and every latent
                // lost) still decides, from the final latent alone.
                let started_at = good.as_ref().map_or(capture_us, |(_, t)| *t);
                if !self.start(peer, press_id, started_at, out) {
                    return;
                }
                let index = self.index.clone();
                let st = self.peer(peer);
                let Some(mut p) = st.press.take() else {
                    return;
                };
                Self::finish(st, press_id);
                if let Some((entry, distance, t)) =
                    Self::final_answer(&*index, &mut p, &good, capture_us)
                {
                    Self::decide(&*index, peer, &mut p, entry, distance, t, true, true, out);
                }
            }
        }
    }

    /// Remember `press_id` as finished (its late messages are ignored).
    fn finish(st: &mut PeerState, press_id: u32) {
        if st.finished.len() >= FINISHED_KEPT {
            st.finished.pop_front();
        }
        st.finished.push_back(press_id);
    }

    /// The final answer of press `p`: the sender's mean of the whole press
    /// decides it, so lost datagrams never change it; without a usable
    /// one, the mean of the latents that arrived does, by the same rule
    /// (`Decider::press_end`).
    fn final_answer(
        index: &I,
        p: &mut RxPress,
        good: &Option<(Latent, u64)>,
        capture_us: u64,
    ) -> Option<(usize, f32, u64)> {
        match good {
            Some((l, t)) => index
                .nearest2(l.as_slice())
                .map(|n| (n.best, n.best_dist, *t)),
            None => p
                .decider
                .press_end(index, capture_us)
                .and_then(|o| o.decision)
                .map(|d| (d.entry, d.distance, capture_us)),
        }
    }

    /// Make sure `peer`'s press `press_id` is the current one, starting it
    /// if it is new. False when the message belongs to a finished press, or
    /// to one captured before the current press began (a late datagram):
    /// ignore it. Press ids are only compared for equality (a peer that
    /// restarts numbers from 1 again); order comes from the peer's capture
    /// clock, which is monotonic.
    fn start(
        &mut self,
        peer: &str,
        press_id: u32,
        capture_us: u64,
        out: &mut Vec<RxAction>,
    ) -> bool {
        let cfg = self.cfg.decide.clone();
        let policy = self.cfg.motion;
        let dim = self.index.dim();
        let st = self.peer(peer);
        if st.finished.contains(&press_id) {
            return false;
        }
        if let Some(p) = &mut st.press {
            if p.press_id == press_id {
                // A latent may come before its press's start (datagrams
                // and the control stream race): the press began no later
                // than the earliest capture any of its messages carries,
                // and its start message carries when it began.
                p.contact_capture_us = p.contact_capture_us.min(capture_us);
                return true;
            }
            if capture_us < p.contact_capture_us {
                return false;
            }
        }
        // A press replaced before its stop came keeps its place for that
        // stop (one press back: stops are seconds apart, reordering
        // milliseconds).
        if let Some(old) = st.press.take() {
            st.superseded = Some(old);
        }
        let mut decider = Decider::new(cfg, dim);
        decider.press_start(capture_us);
        let mut motion = Motion::new(policy);
        motion.press_start();
        st.press = Some(RxPress {
            press_id,
            contact_capture_us: capture_us,
            decider,
            motion,
            decided: None,
            latency_us: None,
            latents: 0,
        });
        out.push(RxAction::PressStarted {
            peer: peer.to_string(),
            press_id,
        });
        true
    }

    #[allow(clippy::too_many_arguments)]
    fn decide(
        index: &I,
        peer: &str,
        p: &mut RxPress,
        entry: usize,
        distance: f32,
        capture_us: u64,
        final_decision: bool,
        move_roller: bool,
        out: &mut Vec<RxAction>,
    ) {
        let changed = p.decided != Some(entry);
        if !changed && !final_decision {
            return;
        }
        p.decided = Some(entry);
        let slot = index.slot_of(entry);
        if final_decision && move_roller {
            if let Some(slot) = p.motion.press_end(slot) {
                out.push(RxAction::RollerTarget { slot });
            }
        }
        let latency_ms = p.latency_us.map(|l| l.max(0) as f64 / 1000.0);
        let pressed_ms = capture_us.saturating_sub(p.contact_capture_us) as f64 / 1000.0;
        out.push(RxAction::Decision(RxDecision {
            peer: peer.to_string(),
            press_id: p.press_id,
            entry,
            slot,
            distance,
            unknown: distance > p.decider.unknown_beyond(index),
            latency_ms,
            since_contact_ms: latency_ms.map(|l| pressed_ms + l),
            final_decision,
            changed,
        }));
    }
}
