//! `ground diagnose`: where the sim-to-real gap of a cluster lies, which unmodelled effect causes it, and how far
//! it shrinks once the effect is modelled — checked on held-out data (spec, with every statistic: `docs/diagnose.md`).
//!
//! Per axis (gyro x y z, accel x y z):
//! 1. On each half of the record, at **every octave τ the half supports** (down to `min_blocks` averaging blocks,
//!    default 4): the overlapping Allan variance of every sensor and of the cluster mean, the cluster's EDF
//!    (Greenhall, for the noise type the typical sensor's model and the cluster's own curve identify — the smaller
//!    EDF of the two), and the **typical** single-sensor variance `V(τ)`: the median over the sensors, corrected for
//!    the median-to-mean bias of a χ² variable at the singles' EDF.
//! 2. **P0**, the √N model: N independent copies of the typical sensor, `V(τ)/N` for equal weights, with `V` taken
//!    from the half being predicted (the √N model has no other parameter).
//! 3. **Candidates**, all fitted on the first half only (`model`): per-sensor level factors (`unequal_noise`,
//!    `outlier_sensor`; one factor per sensor, and again as levels that vary with τ, `model::TermLevels`); a
//!    process shared by all sensors, split into its fast terms (`common_mode`: quantisation, white, flicker) and its
//!    slow terms (`common_mode_drift`: random walk, ramp), each as a share of the typical variance;
//!    `block_common_mode` over blocks found by clustering the Allan correlation matrix; `thermal` (coefficients on
//!    the measured temperature) when `temp_c` exists.
//! 4. **Selection on the second half**: the gap of each τ point is turned into a z-score through the χ²
//!    distribution of the measured variance and the prediction's own scatter; while `Σ z²` over the axis exceeds
//!    the χ² quantile at `p_false`, the candidate that lowers `Σ z²` most is added if it removes at least
//!    `min_shrink` of the excess `Σ z² − n`.
//!
//! The test for independence, reported per τ: the held-out cluster variance against the same half's `Σ w_i² σ_i²`
//! (no prediction involved: its ratio minus one is the weighted mean cross-sensor Allan covariance, whose null
//! scatter shrinks with the N(N−1)/2 pairs relative to a single sensor's).

mod analyse;
mod candidates;
pub(crate) use candidates::deviation_ratios;
pub mod model;
mod periodic;
mod prediction;
pub mod quiet;
pub mod report;
mod selection;
mod sensors;
mod singles;
pub mod steps;
mod summary;
mod types;
mod unexplained;

pub use analyse::diagnose;
pub use prediction::{scan_statistic, scan_threshold};
pub use types::{
    AxisCurves, AxisFit, AxisReport, DiagnoseError, Effect, Gain, Groups, HeldOut, Independence,
    MIN_SAMPLES, Measured, Options, Region, Report, TauRow, WeightRule,
};

#[cfg(test)]
mod tests;
