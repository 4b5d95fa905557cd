//! Shared helpers for the cross-crate integration tests in `tests/tests/`.
#![forbid(unsafe_code)]
#![cfg_attr(not(test), deny(clippy::unwrap_used))]

pub mod nat;
pub mod netns;
pub mod node;
pub mod relay;
