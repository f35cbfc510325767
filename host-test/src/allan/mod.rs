//! Allan-variance family statistics in `f64`: ADEV, OADEV and MDEV with power-law
//! noise identification, Greenhall equivalent degrees of freedom and chi-squared
//! confidence intervals.
//!
//! Definitions follow IEEE Std 1139 and NIST SP 1065 (W. J. Riley, *Handbook of Frequency
//! Stability Analysis*); all numbers reproduce allantools (Python) and Stable32 on the
//! reference data, see the crate's tests and README section of the report.
//!
//! # Units and conventions
//! * Input `y` is a series of **fractional-frequency-like** samples taken every `tau0_s`
//!   seconds with no dead time. For an IMU this is the rate output (e.g. deg/s or m/s²);
//!   the deviations then carry the unit of `y` (ADEV of a gyro rate in deg/s is in deg/s).
//! * Averaging factor `m` (integer ≥ 1), averaging time `tau_s = m · tau0_s` in seconds.
//! * Internally the series is integrated once into "phase"
//!   `x[0] = 0, x[k] = tau0_s · Σ_{i<k} (y[i] − ȳ)` (unit of `y` × seconds, `N + 1`
//!   points for `N` samples); every deviation is an O(N) pass over `x` per `m`.
//! * Noise type is the exponent `alpha` of the frequency PSD `S_y(f) ∝ f^alpha`:
//!   `2` white PM, `1` flicker PM, `0` white FM, `-1` flicker FM, `-2` random-walk FM.
//!
//! # No panics
//! Bad input never panics: empty or non-finite data, `tau0_s <= 0`, `m = 0` or `m` too
//! large for the data give an empty `Vec` / `None`.
//!
//! # Quick start
//! ```
//! use host_test::allan::{analyze, DevKind, Options, TauSpec};
//! let y: Vec<f64> = (0..4096).map(|i| ((i * 7919 % 104729) as f64 / 104729.0) - 0.5).collect();
//! let pts = analyze(DevKind::Oadev, &y, 0.01, &TauSpec::Octave, &Options::default());
//! for p in &pts {
//!     println!("tau={} s n={} oadev={} alpha={:?} [{:?}, {:?}]",
//!              p.tau_s, p.n, p.dev, p.alpha(), p.dev_lo, p.dev_hi);
//! }
//! assert_eq!(pts[0].m, 1);
//! ```
//!
//! For many columns of the same length use one [`Analyzer`], which keeps its phase and
//! scratch buffers between calls (no per-τ allocation, one buffer per column).

pub mod acov;
mod analysis;
mod ci;
mod deviation;
mod edf;
pub(crate) mod lanes;
mod noise;
pub mod noisefit;
mod overlap;
pub mod recording;
mod taus;

pub use analysis::{AnalysisPoint, Analyzer, Halves, Options, analyze};
pub use ci::{ONE_SIGMA_CI, chi2_z, confidence_interval, median_to_mean};
pub use deviation::{DevKind, DevPoint, Phase, adev, deviation, mdev, oadev};
pub use edf::{edf_for_kind, edf_greenhall};
pub use noise::{
    ACF_MIN_POINTS, AcfFlavor, AcfResult, B1Result, NoiseId, NoiseIdMethod, acf_noise_id,
    b1_noise_id, detrend_linear, noise_id,
};
pub use taus::{TauSpec, averaging_factors};

/// A deviation kind or τ list named wrongly.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ParseError {
    /// Not `adev`, `oadev` or `mdev`.
    #[error("expected adev, oadev or mdev, found '{0}'")]
    Kind(String),
    /// Not `octave`, `decade`, `all` or a positive number.
    #[error("expected octave, decade, all or a number of points per decade, found '{0}'")]
    Taus(String),
}
