//! Events the daemon feeds the map, and what the page receives.
//!
//! [`MapEvent`] is the input: the daemon sends them on a
//! `tokio::sync::broadcast` channel. Its JSON form (tag `"event"`) matches the
//! control socket's event lines for the kinds both have (`contact`,
//! `decision`, `peer_up`, `peer_down`, `roller_position`, `roller_arrived`,
//! `error`), so a control-socket event converts with
//! [`MapEvent::from_control_json`]; the map adds `touch`, which carries the
//! latent vector of the touch being felt.
//!
//! [`Live`] turns input events into the page's messages (a touch is placed on
//! the map and its nearest textiles named) and keeps the latest state, which a
//! newly connected page receives first.

use serde::{Deserialize, Serialize};
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::sync::Arc;
use telextiles_index::Index;

/// Contact phase of a sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ContactPhase {
    /// The sensor started touching a fabric.
    Start,
    /// The sensor was lifted.
    End,
}

/// One live update for the map.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum MapEvent {
    /// The latent of the touch being felt (L2-normalised, the index's
    /// dimension), local or from a peer. Placed on the map with
    /// [`Index::place_on_map`].
    Touch {
        latent: Vec<f32>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        peer: Option<String>,
    },
    /// Contact started or ended.
    Contact {
        phase: ContactPhase,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        score: Option<f32>,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        peer: Option<String>,
    },
    /// A textile was resolved and a roller slot chosen.
    Decision {
        textile: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        slot: u32,
        distance: f32,
        /// Farther from every textile of the index than its unknown-textile
        /// distance: a fabric the index does not have, `textile` only its
        /// nearest known one.
        #[serde(default, skip_serializing_if = "std::ops::Not::not")]
        unknown: bool,
        #[serde(default)]
        latency_ms: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        peer: Option<String>,
    },
    /// A peer connected.
    PeerUp {
        peer: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        addr: Option<String>,
    },
    /// A peer went away.
    PeerDown { peer: String, reason: String },
    /// The path to a peer changed: `direct` or `relay`, where to, its
    /// round-trip time.
    PeerPath {
        peer: String,
        path: String,
        addr: String,
        rtt_ms: f64,
    },
    /// The roller is moving.
    RollerPosition {
        angle_deg: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        target_slot: Option<u32>,
    },
    /// The roller reached a slot.
    RollerArrived { slot: u32, angle_deg: f64 },
    /// A received press's wheel came to rest at its final sample this long
    /// after the contact on the peer's sensor.
    Felt {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        peer: Option<String>,
        press: u32,
        slot: u32,
        felt_ms: f64,
    },
    /// A subsystem error worth showing.
    Error { source: String, message: String },
}

impl MapEvent {
    /// Convert one control-socket event line (JSON tagged by `"event"`).
    /// Kinds the map does not show (e.g. `dropped`) are an error.
    pub fn from_control_json(line: &str) -> Result<MapEvent, serde_json::Error> {
        serde_json::from_str(line.trim_end())
    }
}

/// Nearest textiles shown around a touch.
pub const TOUCH_NEAREST: usize = 3;

#[derive(Debug, Clone, Default)]
struct PeerInfo {
    addr: Option<String>,
    path: Option<String>,
    rtt_ms: Option<f64>,
}

/// The latest state, and the translation of input events into page messages.
pub struct Live {
    index: Arc<Index>,
    touch: Option<Value>,
    contact: Option<Value>,
    decision: Option<Value>,
    roller: Option<Value>,
    felt: Option<Value>,
    /// Connected peers: address, then path and round trip once known.
    peers: BTreeMap<String, PeerInfo>,
    last_error: Option<Value>,
}

impl Live {
    /// Empty state for `index`.
    pub fn new(index: Arc<Index>) -> Live {
        Live {
            index,
            touch: None,
            contact: None,
            decision: None,
            roller: None,
            felt: None,
            peers: BTreeMap::new(),
            last_error: None,
        }
    }

    /// Apply an event; the page message to broadcast (a JSON object with a
    /// `"type"`), or `None` if the event is unusable (logged by the caller).
    pub fn apply(&mut self, ev: &MapEvent) -> Result<Value, String> {
        let idx = &self.index;
        let msg = match ev {
            MapEvent::Touch { latent, peer } => {
                if latent.len() != idx.dim {
                    return Err(format!(
                        "touch latent has dimension {}, the index has {}",
                        latent.len(),
                        idx.dim
                    ));
                }
                if latent.iter().any(|v| !v.is_finite()) {
                    return Err("touch latent has a non-finite value".into());
                }
                let mut q = latent.clone();
                telextiles_index::l2_normalise(&mut q);
                if q.iter().all(|v| *v == 0.0) {
                    return Err("touch latent is all zeros".into());
                }
                let [x, y] = idx.place_on_map(&q);
                let nearest: Vec<Value> = idx
                    .k_nearest(&q, TOUCH_NEAREST)
                    .into_iter()
                    .map(|(i, d)| {
                        let e = &idx.entries[i];
                        json!({"i": i, "id": e.id, "name": e.name, "d": d,
                               "slot": idx.slot_of_entry(i)})
                    })
                    .collect();
                let m = json!({"type": "touch", "x": x, "y": y, "nearest": nearest, "peer": peer});
                self.touch = Some(m.clone());
                m
            }
            MapEvent::Contact { phase, score, peer } => {
                let m = json!({"type": "contact", "on": *phase == ContactPhase::Start,
                               "score": score, "peer": peer});
                self.contact = Some(m.clone());
                m
            }
            MapEvent::Decision {
                textile,
                name,
                slot,
                distance,
                unknown,
                latency_ms,
                peer,
            } => {
                let i = idx.entry_by_id(textile);
                let name = name
                    .clone()
                    .or_else(|| i.map(|i| idx.entries[i].name.clone()));
                let m = json!({"type": "decision", "i": i, "id": textile, "name": name,
                               "slot": slot, "distance": distance, "unknown": unknown,
                               "latency_ms": latency_ms, "peer": peer});
                self.decision = Some(m.clone());
                m
            }
            MapEvent::PeerUp { peer, addr } => {
                self.peers.insert(
                    peer.clone(),
                    PeerInfo {
                        addr: addr.clone(),
                        ..PeerInfo::default()
                    },
                );
                json!({"type": "peer", "peer": peer, "up": true, "addr": addr})
            }
            MapEvent::PeerDown { peer, reason } => {
                self.peers.remove(peer);
                json!({"type": "peer", "peer": peer, "up": false, "reason": reason})
            }
            MapEvent::PeerPath {
                peer,
                path,
                addr,
                rtt_ms,
            } => {
                let p = self.peers.entry(peer.clone()).or_default();
                p.addr = Some(addr.clone());
                p.path = Some(path.clone());
                p.rtt_ms = Some(*rtt_ms);
                json!({"type": "peer", "peer": peer, "up": true, "addr": addr,
                       "path": path, "rtt_ms": rtt_ms})
            }
            MapEvent::RollerPosition {
                angle_deg,
                target_slot,
            } => {
                let m = json!({"type": "roller", "angle_deg": angle_deg,
                               "slot": self.slot_at(*angle_deg), "target_slot": target_slot,
                               "arrived": false});
                self.roller = Some(m.clone());
                m
            }
            MapEvent::RollerArrived { slot, angle_deg } => {
                let m = json!({"type": "roller", "angle_deg": angle_deg, "slot": slot,
                               "target_slot": slot, "arrived": true});
                self.roller = Some(m.clone());
                m
            }
            MapEvent::Felt {
                peer,
                press,
                slot,
                felt_ms,
            } => {
                let m = json!({"type": "felt", "peer": peer, "press": press, "slot": slot,
                               "felt_ms": felt_ms});
                self.felt = Some(m.clone());
                m
            }
            MapEvent::Error { source, message } => {
                let m = json!({"type": "error", "source": source, "message": message});
                self.last_error = Some(m.clone());
                m
            }
        };
        Ok(msg)
    }

    /// Slot under the window at a roller angle (slot k sits at k x 360/N).
    fn slot_at(&self, angle_deg: f64) -> Option<usize> {
        let n = self.index.roller.n();
        if n == 0 || !angle_deg.is_finite() {
            return None;
        }
        let step = 360.0 / n as f64;
        Some(((angle_deg.rem_euclid(360.0) / step).round() as usize) % n)
    }

    /// The state a newly connected page starts from.
    pub fn snapshot(&self) -> Value {
        let peers: Vec<Value> = self
            .peers
            .iter()
            .map(|(p, i)| json!({"peer": p, "addr": i.addr, "path": i.path, "rtt_ms": i.rtt_ms}))
            .collect();
        json!({"type": "state", "touch": self.touch, "contact": self.contact,
               "decision": self.decision, "roller": self.roller, "felt": self.felt,
               "peers": peers,
               "error": self.last_error})
    }
}
