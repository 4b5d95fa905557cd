//! The events a subscribed client receives (`subscribe`): what each
//! carries on the wire, their kinds and the filter a subscription names.
//! Pure data, no I/O; re-exported by [`crate::protocol`].

use serde::{Deserialize, Serialize};
use serde_json::Value;

fn is_false(b: &bool) -> bool {
    !*b
}

/// Contact phase reported by the sensing pipeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ContactPhase {
    /// The sensor started touching a fabric.
    Start,
    /// The sensor was lifted.
    End,
}

/// What a recording (`record.start`) is doing, in `record` events.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RecordPhase {
    /// Waiting for the sensor to be seen untouched (the no-contact reference).
    Waiting,
    /// Ready: press now.
    Ready,
    /// Contact: a press started.
    Contact,
    /// Hold progress (rate-limited).
    Holding,
    /// Held long enough: release.
    Release,
    /// The press ended.
    Released,
    /// All presses recorded.
    Done,
    /// Stopped (`record.stop`, a new `record.start`, the sensor lost, a
    /// write failed) before all presses were recorded.
    Stopped,
}

/// An event streamed to subscribers, tagged by `"event"`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "event", rename_all = "snake_case")]
pub enum Event {
    /// Contact detection on the local sensor.
    Contact {
        phase: ContactPhase,
        /// Contact score of the detector (difference to the background).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        score: Option<f32>,
        /// On `end`: how much of the gel the press touched, 0..=1 (its
        /// deepest frame's share of the gel, as `classify` and `record`
        /// report it); below 0.5 the press was partial (held tilted?).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        coverage: Option<f32>,
    },
    /// The receiver resolved a textile and chose a roller slot.
    Decision {
        /// Textile id, e.g. "T012".
        textile: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        name: Option<String>,
        slot: u32,
        /// Distance of the running latent to the textile's centroid.
        distance: f32,
        /// Further than the index's unknown-textile distance from every
        /// textile: `textile` is the nearest known one (omitted when false).
        #[serde(default, skip_serializing_if = "is_false")]
        unknown: bool,
        /// Milliseconds from the sender's frame capture to this decision.
        latency_ms: f64,
        /// The peer whose touch this is (None = local).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        peer: Option<String>,
        /// The sender's press number this decision belongs to.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        press: Option<u32>,
        /// The final decision of the press (from the sender's press mean,
        /// sent when the sensor is lifted), as opposed to a live update.
        #[serde(default, skip_serializing_if = "is_false")]
        final_decision: bool,
        /// Milliseconds from the press's first contact frame (on the
        /// sender's clock) to this decision.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        since_contact_ms: Option<f64>,
    },
    PeerUp {
        peer: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        addr: Option<String>,
    },
    PeerDown {
        peer: String,
        reason: String,
    },
    /// The path to a connected peer changed: `direct` (hole punched or on
    /// the LAN) or `relay`, the address it goes to, its round-trip time.
    PeerPath {
        peer: String,
        path: String,
        addr: String,
        rtt_ms: f64,
    },
    /// Roller position while moving (rate-limited by the daemon).
    RollerPosition {
        angle_deg: f64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        target_slot: Option<u32>,
    },
    RollerArrived {
        slot: u32,
        angle_deg: f64,
    },
    /// What the receiving hand felt of a peer's press: from contact on the
    /// peer's sensor until the wheel rested at the press's final sample
    /// (ms, the local clock through the link's clock-offset estimate).
    Felt {
        #[serde(default, skip_serializing_if = "Option::is_none")]
        peer: Option<String>,
        press: u32,
        slot: u32,
        felt_ms: f64,
    },
    /// A recording's state (`record.start`).
    Record {
        state: RecordPhase,
        textile: String,
        /// The press this is about (1-based within this recording).
        press: u32,
        /// Presses asked for.
        presses: u32,
        /// Time since contact (holding, release, released).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        held_ms: Option<f64>,
        /// Contact score now (holding), or the peak (released).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        score: Option<f32>,
        /// Why it stopped (stopped).
        #[serde(default, skip_serializing_if = "Option::is_none")]
        reason: Option<String>,
    },
    /// A recorded press was written.
    RecordSaved {
        textile: String,
        /// 1-based within this recording.
        press: u32,
        presses: u32,
        /// The press directory.
        path: String,
        frames: u32,
        duration_ms: f64,
        /// Peak contact score.
        peak: f32,
        /// Leading quiet frames (the recording's own reference).
        reference_frames: u32,
        fps: f32,
        /// Codes of warnings on this kept press (e.g. "too_weak").
        #[serde(default, skip_serializing_if = "Vec::is_empty")]
        warnings: Vec<String>,
    },
    /// A press was rejected, or kept with a warning.
    RecordWarning {
        textile: String,
        press: u32,
        /// "too_short", "too_weak", "partial", "no_quiet_before", "too_long",
        /// "interrupted", "not_released".
        code: String,
        message: String,
        /// The press was not kept.
        rejected: bool,
    },
    /// A subsystem error worth showing to a watcher.
    Error {
        source: String,
        message: String,
    },
    /// Sent by the server just before it drops a subscriber (never broadcast).
    Dropped {
        reason: String,
    },
}

impl Event {
    /// The kind for filtering; `None` for [`Event::Dropped`], which is
    /// connection-local and always delivered.
    pub fn kind(&self) -> Option<EventKind> {
        Some(match self {
            Event::Contact { .. } => EventKind::Contact,
            Event::Decision { .. } => EventKind::Decision,
            Event::PeerUp { .. } => EventKind::PeerUp,
            Event::PeerDown { .. } => EventKind::PeerDown,
            Event::PeerPath { .. } => EventKind::PeerPath,
            Event::RollerPosition { .. } => EventKind::RollerPosition,
            Event::RollerArrived { .. } => EventKind::RollerArrived,
            Event::Felt { .. } => EventKind::Felt,
            Event::Error { .. } => EventKind::Error,
            Event::Record { .. } | Event::RecordSaved { .. } | Event::RecordWarning { .. } => {
                EventKind::Record
            }
            Event::Dropped { .. } => return None,
        })
    }

    /// The event as one `\n`-terminated JSON line.
    pub fn to_line(&self) -> String {
        let mut s = serde_json::to_string(self).unwrap_or_else(|e| {
            format!(
                "{{\"event\":\"error\",\"source\":\"control\",\"message\":{}}}",
                Value::from(format!("event not serialisable: {e}"))
            )
        });
        s.push('\n');
        s
    }
}

/// Filterable event kinds (the `events` argument of `subscribe`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EventKind {
    Contact,
    Decision,
    PeerUp,
    PeerDown,
    PeerPath,
    RollerPosition,
    RollerArrived,
    Error,
    /// `record`, `record_saved` and `record_warning` events.
    Record,
    Felt,
}

impl EventKind {
    pub const ALL: [EventKind; 10] = [
        EventKind::Contact,
        EventKind::Decision,
        EventKind::PeerUp,
        EventKind::PeerDown,
        EventKind::PeerPath,
        EventKind::RollerPosition,
        EventKind::RollerArrived,
        EventKind::Error,
        EventKind::Record,
        EventKind::Felt,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            EventKind::Contact => "contact",
            EventKind::Decision => "decision",
            EventKind::PeerUp => "peer_up",
            EventKind::PeerDown => "peer_down",
            EventKind::PeerPath => "peer_path",
            EventKind::RollerPosition => "roller_position",
            EventKind::RollerArrived => "roller_arrived",
            EventKind::Error => "error",
            EventKind::Record => "record",
            EventKind::Felt => "felt",
        }
    }

    pub fn parse(s: &str) -> Option<EventKind> {
        EventKind::ALL.iter().copied().find(|k| k.as_str() == s)
    }

    fn bit(self) -> u16 {
        1 << (self as u16)
    }
}

/// A set of event kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EventFilter(u16);

impl EventFilter {
    pub fn all() -> Self {
        Self::of(&EventKind::ALL)
    }
    pub fn none() -> Self {
        EventFilter(0)
    }
    pub fn of(kinds: &[EventKind]) -> Self {
        EventFilter(kinds.iter().fold(0, |acc, k| acc | k.bit()))
    }
    pub fn contains(self, kind: EventKind) -> bool {
        self.0 & kind.bit() != 0
    }
    /// Whether a subscriber with this filter receives `event`
    /// (`dropped` notices always pass).
    pub fn matches(self, event: &Event) -> bool {
        event.kind().is_none_or(|k| self.contains(k))
    }
    pub fn kinds(self) -> Vec<EventKind> {
        EventKind::ALL
            .iter()
            .copied()
            .filter(|k| self.contains(*k))
            .collect()
    }
}
