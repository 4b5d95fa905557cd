//! Telextiles wire protocols, sans-IO: pure, deterministic types, codecs and
//! state machines. No tokio, no clocks, no sockets. `no_std` (with `alloc`)
//! so the roller firmware shares the same code.
#![cfg_attr(not(feature = "std"), no_std)]
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

extern crate alloc;

pub mod pairing;
pub mod peer;
pub mod roller;
