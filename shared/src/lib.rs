//! Sans-IO core of the IMU cluster: everything between the FPGA's bytes and the telemetry's bytes, with no I/O,
//! no heap and no panics on any input. The firmware and the host replay run this same code.
//!
//! Data path, one module per stage:
//! [`wire`] (FPGA frames) → [`calib`] (fixed-point calibration) → [`fuse`] (cluster fusion) → [`allan`]
//! (streaming Allan accumulators) → [`telemetry`] (postcard messages) — tied together by [`pipeline`].
#![no_std]
#![deny(missing_docs)]
// Test code may panic: a failed assertion or `unwrap` is how a test reports, and it indexes fixtures of known
// size. The no-panic lints (`[lints]` in Cargo.toml) are for the code that flies, which is also checked without
// `cfg(test)`.
#![cfg_attr(
    test,
    allow(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing,
        clippy::arithmetic_side_effects
    )
)]

pub mod allan;
#[cfg(any(test, feature = "bench"))]
pub mod bench;
pub mod bus;
pub mod calib;
pub mod crc;
pub mod fuse;
pub mod nav;
pub mod pipeline;
pub mod serde_array;
pub mod storage;
pub mod telemetry;
#[cfg(test)]
mod testutil;
pub mod update;
pub mod wire;
