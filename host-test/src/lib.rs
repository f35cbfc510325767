//! Host side of the IMU cluster: replay of recorded frames through `shared`, ground decoding, simulation, calibration
//! and diagnosis: the library of the `ground` command line (crate `ground`) and of the Python package.
#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Each module names what it imports (a glob hides where a name comes from); preludes and `use super::*` in test
// modules are the lint's own exceptions.
#![warn(clippy::wildcard_imports)]

/// The FPGA base rate in Hz (9676.8), for the tools' options and the simulator: derived from
/// [`shared::wire::clock::FPGA_BASE_RATE_MILLIHZ`], the one definition (the same `f64` as the literal).
pub const FPGA_BASE_RATE_HZ: f64 = shared::wire::clock::FPGA_BASE_RATE_MILLIHZ as f64 / 1000.0;

pub mod allan;
pub mod calibrate;
pub mod demo;
pub mod diagnose;
pub mod figures;
pub mod file_error;
pub mod formats;
pub mod load;

pub mod plot;
pub mod recording;
pub mod replay;
pub mod seedfit;
pub mod sim;
pub mod stats;
pub mod testrng;
pub mod thermal_check;
pub mod tradeoff;
pub mod twin;
pub mod update;
