//! Local control socket for `telextilesd`: JSON lines over a Unix socket.
//!
//! - [`protocol`]: sans-IO request parser with typed arguments, replies,
//!   events and a bounded line framer (no tokio; fuzzed).
//! - [`format`]: human-friendly rendering for the CLI.
//! - [`socket`] (feature `server`): socket location, permissions, stale-socket handling.
//! - [`server`] (feature `server`): the tokio server; the daemon plugs in a [`Handler`]
//!   and a `tokio::sync::broadcast::Sender<Event>`.
//! - [`client`] (feature `server`): the tokio client used by `telextilesd ctl`.
//!
//! The wire protocol is documented in `docs/control-protocol.md`.
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod event;
pub mod format;
pub mod protocol;

#[cfg(feature = "server")]
pub mod client;
#[cfg(feature = "server")]
pub mod server;
#[cfg(feature = "server")]
pub mod socket;

pub use protocol::{
    Command, ContactPhase, CtlError, ErrorCode, Event, EventFilter, EventKind, GotoTarget, JogArgs,
    LedArgs, PairArgs, RecordPhase, RecordStartArgs, Reply, Request, RequestId, SimPressArgs,
    SubscribeArgs, UnpairArgs,
};

#[cfg(feature = "server")]
pub use client::Client;
#[cfg(feature = "server")]
pub use server::{Handler, HandlerFuture, Server, ServerConfig, ServerStats};
#[cfg(feature = "server")]
pub use socket::{Access, BindError, SocketSpec};
