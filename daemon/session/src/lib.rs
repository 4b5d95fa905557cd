//! The live session's core, without I/O (as quinn-proto is to quinn): pure,
//! deterministic state machines fed explicit time and inputs, returning
//! actions for the daemon's thin tokio wiring (`daemon/src/live.rs`) to
//! carry out.
//!
//! - [`latent::Latent`]: an embedding that is valid by construction (the
//!   dimension agreed in the peers' hello, finite, unit length). Everything
//!   a peer sends crosses into the core through [`latent::Latent::new`].
//! - [`sender::SenderCore`]: the front end's per-frame output (contact
//!   events, embeddings) → messages for the peers: press start, a latent
//!   per frame, press stop with the press's final (mean) latent.
//! - [`receiver::ReceiverCore`]: messages from peers → per-peer presses,
//!   decisions, roller targets and map touches. One press per peer, so two
//!   peers pressing at once never reset each other; reordered, duplicated,
//!   lost or malformed messages never panic it and never stop decisions.
//!
//! - [`motion::Motion`]: when the wheel moves (a policy apart from the
//!   decision): the decider's state per frame → roller targets.
//! - [`felt`]: what the receiving hand feels — contact → the wheel at rest
//!   at the press's final sample, driving the roller's firmware core in
//!   simulated time.
//!
//! - [`clock::CaptureClock`]: a frame's capture time on the local clock,
//!   spaced as the sensor spaced its frames (its own timestamps), so that
//!   the peers' deciders time presses as the offline tools do.
//!
//! Clocks: a peer's `capture_us` is on the peer's clock and is only ever
//! compared with other timestamps of the same peer (durations within a
//! press); the link's `one_way_latency_us` (from its clock-offset estimate)
//! is the only bridge to the local clock.
#![forbid(unsafe_code)]
#![warn(missing_docs)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod clock;
pub mod felt;
/// [`Latent`] lives in `telextiles-press`.
pub use telextiles_press::latent;
pub mod motion;
pub mod receiver;
pub mod sender;

pub use latent::{Latent, LatentError};
pub use motion::{Motion, MotionPolicy};
pub use receiver::{ReceiverConfig, ReceiverCore, RxAction, RxDecision, RxInput};
pub use sender::{ContactChange, EarlierFrame, SenderCore, Sensed, TxAction};
