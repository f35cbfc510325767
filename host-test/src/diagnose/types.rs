//! The diagnosis's options and its report: what `diagnose` returns, `report` renders and the JSON holds.

use super::model::{Cross, TermLevels};
use super::quiet;
use crate::allan::noisefit;
use crate::allan::noisefit::NoiseFit;
use crate::formats::csv::SensorKind;
use serde::Serialize;
use std::collections::BTreeMap;

/// How the cluster mean weighs its sensors.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum WeightRule {
    /// Equal weights (the seed's mean).
    Equal,
    /// Inverse white-noise variance of each sensor's fitted model.
    InverseVariance,
}

/// Diagnosis parameters.
#[derive(Clone, Copy, Debug)]
pub struct Options {
    /// Weights of the cluster mean.
    pub weights: WeightRule,
    /// Octave τ whose half holds fewer averaging blocks (samples / m) are left out (default 4: every τ the
    /// overlapping estimator supports with a useful EDF).
    pub min_blocks: usize,
    /// A point is "significant" beyond `z` standard deviations; the excess gap counts what lies beyond.
    pub z: f64,
    /// Relative error allowed to a prediction (deviation), added in quadrature to each point's uncertainty.
    pub model_tolerance: f64,
    /// Smallest share of the excess `Σ z² − n` an effect must remove to be accepted.
    pub min_shrink: f64,
    /// False-alarm probability per axis of the test "the remaining gap of the axis is significant"; the bias-step
    /// and shared-disturbance scans take it for the whole record, shared by its axes.
    pub p_false: f64,
    /// Significance (standard deviations of the null correlation) for merging sensors into a block.
    pub merge_z: f64,
    /// False-alarm probability of the second test of an axis without an effect, for the kinds found on the other
    /// axes of its sensor.
    pub p_sibling: f64,
    /// False-alarm probability (one-sided) of the confirmation a shared process needs from the held-out half's own
    /// cross covariance before it is named (`selection::cross_confirmed`).
    pub p_cross: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            weights: WeightRule::Equal,
            min_blocks: 4,
            z: 2.0,
            model_tolerance: 0.03,
            min_shrink: 0.2,
            p_false: 2e-3,
            merge_z: 8.0,
            p_sibling: 0.02,
            p_cross: 0.01,
        }
    }
}

/// The measured cluster deviation of one half.
#[derive(Clone, Debug, Default, Serialize)]
pub struct Measured {
    /// τ, s.
    pub tau_s: Vec<f64>,
    /// OADEV of the weighted mean.
    pub dev: Vec<f64>,
    /// 68 % bounds (χ² at the EDF).
    pub lo: Vec<f64>,
    /// 68 % bounds.
    pub hi: Vec<f64>,
    /// Greenhall equivalent degrees of freedom of the cluster variance.
    pub edf: Vec<f64>,
    /// Uncertainty of ln(deviation) of the measurement alone, `1/√(2·edf)`.
    pub sigma_ln: Vec<f64>,
}

/// Groups an effect concerns: a flat list, or one list per block (`block_common_mode`).
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
#[serde(untagged)]
pub enum Groups {
    /// 0-based group numbers.
    List(Vec<usize>),
    /// One list of 0-based group numbers per block.
    Blocks(Vec<Vec<usize>>),
}

impl Groups {
    /// Every group named, in order.
    pub fn flat(&self) -> Vec<usize> {
        match self {
            Groups::List(v) => v.clone(),
            Groups::Blocks(b) => b.iter().flatten().copied().collect(),
        }
    }
}

impl std::fmt::Display for Groups {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Groups::List(v) => write!(f, "{v:?}"),
            Groups::Blocks(b) => write!(f, "{b:?}"),
        }
    }
}

/// One identified effect.
#[derive(Clone, Debug, Serialize)]
pub struct Effect {
    /// `common_mode`, `block_common_mode`, `common_mode_drift`, `thermal`, `outlier_sensor`, `unequal_noise`,
    /// `sensor_drift` (one sensor's own slow drift), `bias_step` (one sensor's bias jump), `warm_up` (steps of
    /// several sensors of an axis in the record's first quarter), `periodic` (a sinusoidal
    /// interference, shared or one sensor's own: `params.<axis>.period_s`, `amplitude`).
    pub kind: String,
    /// `gyro` or `accel`.
    pub sensor: String,
    /// Axes, e.g. `xyz` or `y`.
    pub axes: String,
    /// Groups concerned (0-based; all for cluster-wide effects; a list per block for `block_common_mode`).
    pub groups: Groups,
    /// Where it acts most: `quantization`, `white`, `flicker` or `random_walk` (the typical sensor's dominant term
    /// at `tau_at_max_s`), `periodic` for a sinusoid, `step` for a bias step.
    pub region: String,
    /// τ range, s, over which it accounts for at least half of its largest share of the cluster variance.
    pub tau_s: [f64; 2],
    /// τ of its largest share, s.
    pub tau_at_max_s: f64,
    /// Its largest share of the held-out cluster Allan variance (predicted with − without it, over with it).
    pub share: f64,
    /// Fitted parameters, per axis.
    pub params: BTreeMap<String, serde_json::Value>,
}

/// Gain with its 68 % interval.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Gain {
    /// Value.
    pub value: f64,
    /// Lower bound.
    pub ci_lo: f64,
    /// Upper bound.
    pub ci_hi: f64,
}

/// A τ region of one axis.
#[derive(Clone, Debug, Serialize)]
pub struct Region {
    /// `quantization`, `white`, `flicker` or `random_walk`: the term of the typical model that dominates.
    pub region: String,
    /// τ range, s.
    pub tau_s: [f64; 2],
    /// Mean ln(measured/predicted) before (P0) and after (final model), held-out half.
    pub gap_before: f64,
    /// After.
    pub gap_after: f64,
    /// Points whose gap is significant, before and after.
    pub significant_before: usize,
    /// After.
    pub significant_after: usize,
    /// Points.
    pub points: usize,
}

/// One τ of an axis on the held-out half.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct TauRow {
    /// τ, s.
    pub tau_s: f64,
    /// Averaging blocks in the half (samples / m).
    pub blocks: usize,
    /// Noise type used for the EDF (α, PSD exponent of the rate: 0 white, −1 flicker, −2 random walk).
    pub alpha: i32,
    /// Greenhall EDF of the measured cluster variance.
    pub edf: f64,
    /// Measured cluster deviation and its 68 % interval.
    pub dev: f64,
    /// Lower bound.
    pub dev_lo: f64,
    /// Upper bound.
    pub dev_hi: f64,
    /// Predicted deviation, P0 and final model.
    pub predicted_before: f64,
    /// Final model.
    pub predicted_after: f64,
    /// Uncertainty of ln(predicted deviation) from the N sensors' estimates.
    pub prediction_sigma_ln: f64,
    /// ln(measured / predicted) deviation, before and after.
    pub gap_before: f64,
    /// After.
    pub gap_after: f64,
    /// Total uncertainty of the gap (measurement, prediction, tolerance).
    pub sigma_ln: f64,
    /// z-scores of the gap, before and after.
    pub z_before: f64,
    /// After.
    pub z_after: f64,
    /// Weighted mean cross-sensor Allan correlation (cross covariance over the typical variance).
    pub cross_correlation: f64,
    /// Its z-score against independence (same half, no prediction).
    pub cross_z: f64,
}

/// The test for independence of one axis on the held-out half: `Σ cross_z²` against χ²(points).
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct Independence {
    /// `Σ z²`.
    pub chi2: f64,
    /// Points.
    pub points: usize,
    /// Probability of a larger `Σ z²` for independent sensors.
    pub p_value: f64,
}

/// Everything about one axis.
#[derive(Clone, Debug, Serialize)]
pub struct AxisReport {
    /// `gx`, …, `az`.
    pub axis: String,
    /// Sensors.
    pub sensors: usize,
    /// √N.
    pub expected_gain: f64,
    /// RMS-noise gain: RMS over sensors of their standard deviations / the cluster's.
    pub rms_gain: Gain,
    /// Bias-stability gain: median over sensors of their ADEV minimum / the cluster's.
    pub bias_stability_gain: Gain,
    /// Predicted white-region deviation ratio equal-weight mean / inverse-variance mean under the final model
    /// (> 1: what weighting recovers).
    pub weighting_recovers: f64,
    /// Excess gap on the held-out half, before and after (see [`HeldOut`]).
    pub heldout_gap: [f64; 2],
    /// Excess gap on the first half, before and after.
    pub gap: [f64; 2],
    /// Whether the axis's gap is significant (scan test at `p_false`, both halves), before and after.
    pub significant: [bool; 2],
    /// The gap per τ region.
    pub regions: Vec<Region>,
    /// Every τ of the held-out half.
    pub taus: Vec<TauRow>,
    /// Test for independence (held-out half).
    pub independence: Independence,
    /// Typical single-sensor noise model (fitted to the per-τ median of the sensors' curves, first half).
    pub typical: NoiseFit,
    /// RMS over sensors and τ of ln(measured / fitted) single-sensor deviation: how well the four-term model
    /// describes these sensors (not used by the predictions).
    pub model_misfit: f64,
    /// The same with each sensor's single-pole bandwidth fitted too (`noisefit::fit_band_limited`; equal to
    /// `model_misfit` where no sensor shows one).
    pub model_misfit_band_limited: f64,
    /// The typical sensor's fitted bandwidth (single-pole cut-off, Hz) when its curve shows one, else `None`: part
    /// of the baseline noise model, not an effect.
    pub bandwidth_hz: Option<f64>,
    /// Effects kept for this axis.
    pub effects: Vec<String>,
}

/// Gaps summary. The **excess gap** is the RMS over axes and τ points of `σ·max(0, |z| − z_thr)`, the part of
/// g = ln(measured / predicted) cluster deviation outside its ±z_thr interval (σ its uncertainty, z its χ²-exact
/// score), counted on the axes whose gap is significant: ≈ 0 when the model is right, at every number of blocks.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct HeldOut {
    /// Excess gap before (P0).
    pub gap_before: f64,
    /// Excess gap after (final model).
    pub gap_after: f64,
    /// Plain RMS of g before (as v1; noise included).
    pub rms_before: f64,
    /// Plain RMS of g after.
    pub rms_after: f64,
}

/// The diagnosis.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Excess gap of P0 on the first half.
    pub gap_before: f64,
    /// Excess gap of the final model on the first half.
    pub gap_after: f64,
    /// The same on the held-out half.
    pub heldout: HeldOut,
    /// Identified effects (empty list: none).
    pub effects: Vec<Effect>,
    /// Per axis.
    pub axes: Vec<AxisReport>,
    /// Samples.
    pub samples: usize,
    /// Sample interval, s.
    pub tau0_s: f64,
    /// Weights of the cluster mean.
    pub weights: WeightRule,
    /// Whether `temp_c` was available.
    pub temperature: bool,
    /// Fewest averaging blocks of a τ counted.
    pub min_blocks: usize,
    /// False-alarm probability per axis of the significance test.
    pub p_false: f64,
    /// Shared disturbances ([`quiet`]): transients every sensor saw, which the √N model of stationary noise does
    /// not describe; the diagnosis includes them (use [`quiet::longest_quiet`] to leave them out).
    pub disturbances: Vec<quiet::Disturbance>,
    /// Curves for plots: per axis (label), the held-out measured curve and both predictions.
    #[serde(skip)]
    pub curves: Vec<AxisCurves>,
    /// What was fitted, typed, per axis (for the twin: `crate::twin`).
    #[serde(skip)]
    pub fitted: Vec<AxisFit>,
}

/// What the diagnosis fitted on one axis, typed: the chosen effects' per-sensor level factors and cross terms (the
/// report's `params` are their JSON for people). Fitted on the first half, as the selection used them.
#[derive(Clone, Debug)]
pub struct AxisFit {
    /// Gyro or accelerometer.
    pub kind: SensorKind,
    /// 0, 1, 2.
    pub axis: usize,
    /// The axis's sensors' groups, in the order of `level` and the cross terms' indices.
    pub groups: Vec<usize>,
    /// The chosen effects' kinds.
    pub effects: Vec<&'static str>,
    /// Variance factor of each sensor relative to the typical one, when a level effect (`unequal_noise`,
    /// `outlier_sensor`) was chosen.
    pub level: Option<Vec<f64>>,
    /// The level's form that varies with τ (each sensor's first-half fit over the typical's), when the selection
    /// chose it over the one factor per sensor (`params.level_varies_with_tau`); `None` with the one factor or
    /// without a level effect.
    pub level_terms: Option<TermLevels>,
    /// The chosen effects' cross terms, with the kind of the effect each belongs to.
    pub cross: Vec<(&'static str, Cross)>,
    /// The sensors' low-pass response, when the band-limited noise model fitted one (the report's `bandwidth_hz`).
    pub bandwidth: Option<noisefit::LowPass>,
}

/// Curves of one axis for plotting (held-out half).
#[derive(Clone, Debug)]
pub struct AxisCurves {
    /// Axis label.
    pub axis: String,
    /// Measured.
    pub measured: Measured,
    /// P0 deviation at the measured τ.
    pub before: Vec<f64>,
    /// Final model.
    pub after: Vec<f64>,
}
/// Shortest record accepted (each half must hold a few octaves of averaging blocks).
pub const MIN_SAMPLES: usize = 1000;

/// Why a recording cannot be diagnosed.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum DiagnoseError {
    /// No sample interval: fewer than two samples, or `t` not increasing.
    #[error("fewer than two samples, or time not increasing")]
    NoTimeBase,
    /// Fewer than [`MIN_SAMPLES`] samples.
    #[error(
        "{samples} samples: too short for a diagnosis (at least {MIN_SAMPLES}; hours are better)"
    )]
    TooShort {
        /// Samples in the record.
        samples: usize,
    },
    /// No axis has two sensors to compare.
    #[error("no axis has at least two sensors")]
    NoAxis,
}
