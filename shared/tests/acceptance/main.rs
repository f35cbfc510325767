//! The shared crate's acceptance tests, one test crate (one link, one lint exemption): the Allan accumulator
//! against Stable32 (`allan_stable32`), the golden output stream of the pipeline (`golden`).

// Test code may panic: a failed assertion or `unwrap` is how a test reports. The no-panic lints (`[lints]` in
// Cargo.toml) are for the code that flies.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects
)]

mod allan_stable32;
mod golden;
