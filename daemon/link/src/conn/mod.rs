//! The connection protocol as sans-IO state machines, in the manner of
//! quinn-proto and of the roller link (`telextiles-roller`'s `link.rs`):
//! every input carries `now` (µs on the caller's monotonic clock), outputs
//! are pulled with `poll`, and `poll_timeout` says when `handle_timeout` is
//! due. The tokio code in `session.rs` only moves bytes and time.
//!
//! * [`clock`]: ping/pong, the clock offset and one-way latency.
//! * [`handshake`]: the hello/ack exchange of one connection.
//! * [`duplicate`]: which of two connections to one peer survives.
//! * [`pairing`]: the pairing exchange on the control stream around
//!   `telextiles_certs::PairingSession`.
//! * [`connection`]: one connection's life cycle (handshake, then the live
//!   session's pings, pongs and control messages).

pub mod clock;
pub mod connection;
pub mod duplicate;
pub mod handshake;
pub mod pairing;

pub use clock::{ClockConfig, ClockStats, ClockSync, PongOutcome};
pub use connection::{Action, Connection, Phase};
pub use handshake::{Handshake, HandshakeConfig, HsAction, HsError, HsState, Local, Role};

#[cfg(test)]
mod sim;
#[cfg(test)]
mod tests_clock;
#[cfg(test)]
mod tests_connection;
#[cfg(test)]
mod tests_handshake;
#[cfg(test)]
mod tests_pairing;
