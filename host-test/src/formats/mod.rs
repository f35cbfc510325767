//! File formats the ground tool reads and writes: the interchange CSV, NumPy `.npy` arrays, the FPGA frame log, the
//! MIMU4444 stream and the telemetry stream. Readers report bad input with its position (line and column, row, or
//! byte offset) and what was expected; none panics on any input.

pub mod csv;
pub mod framelog;
pub mod mcap;
pub mod mimu;
pub mod npy;
pub mod telemetry;
