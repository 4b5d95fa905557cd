//! The connection protocol as sans-IO state machines, in the manner of
//! quinn-proto and of the roller link (`telextiles-roller`'s `link.rs`):
//! every input carries `now` (µs on the caller's monotonic clock), outputs
//! are pulled with `poll`, and `poll_timeout` says when `handle_timeout` is
//! due. The tokio code in `session.rs` only moves bytes and time.
//!
//! * [`clock`]: ping/pong, the clock offset and one-way latency.

pub mod clock;

pub use clock::{ClockConfig, ClockStats, ClockSync, PongOutcome};

#[cfg(test)]
mod sim;
#[cfg(test)]
mod tests_clock;
