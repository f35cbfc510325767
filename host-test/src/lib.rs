//! Host side of the IMU cluster: replay of recorded frames through `shared`, ground decoding, and the `ground` tool.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod adev;
pub mod allan;
pub mod calibrate;
pub mod demo;
pub mod diagnose;
pub mod formats;
pub mod load;
pub mod mimu;
pub mod noisefit;
pub mod plot;
pub mod replay;
pub mod seedfit;
pub mod sim;
pub mod simcli;
pub mod stats;
pub mod testrng;
