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
//!    `outlier_sensor`); a process shared by all sensors, split into its fast terms (`common_mode`: quantisation,
//!    white, flicker) and its slow terms (`common_mode_drift`: random walk, ramp), each as a share of the typical
//!    variance; `block_common_mode` over blocks found by clustering the Allan correlation matrix; `thermal`
//!    (coefficients on the measured temperature) when `temp_c` exists.
//! 4. **Selection on the second half**: the gap of each τ point is turned into a z-score through the χ²
//!    distribution of the measured variance and the prediction's own scatter; while `Σ z²` over the axis exceeds
//!    the χ² quantile at `p_false`, the candidate that lowers `Σ z²` most is added if it removes at least
//!    `min_shrink` of the excess `Σ z² − n`.
//!
//! The test for independence, reported per τ: the held-out cluster variance against the same half's `Σ w_i² σ_i²`
//! (no prediction involved: its ratio minus one is the weighted mean cross-sensor Allan covariance, whose null
//! scatter shrinks with the N(N−1)/2 pairs relative to a single sensor's).

pub mod acov;
mod candidates;
pub mod model;
mod periodic;
mod prediction;
pub use prediction::{scan_statistic, scan_threshold};
pub(crate) use singles::median_to_mean;
pub mod quiet;
pub mod report;
mod selection;
mod sensors;
mod singles;
pub mod steps;
mod summary;
mod unexplained;

use crate::allan::edf_for_kind;
use crate::allan::{AnalysisPoint, Analyzer, DevKind, Options as AllanOptions, TauSpec};
use crate::formats::csv::{AXIS_NAMES, Recording, SensorKind};
use crate::noisefit::{self, NoiseFit};
use acov::AllanCov;
use model::{Cross, Model, Share, Terms};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};
use std::collections::BTreeMap;

use candidates::*;
use prediction::*;
use selection::*;
use sensors::*;
use singles::*;
use summary::*;

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
    /// False-alarm probability per axis of the test "the remaining gap of the axis is significant".
    pub p_false: f64,
    /// Significance (standard deviations of the null correlation) for merging sensors into a block.
    pub merge_z: f64,
    /// False-alarm probability of the second test of an axis without an effect, for the kinds found on the other
    /// axes of its sensor.
    pub p_sibling: f64,
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
    /// `sensor_drift` (one sensor's own slow drift), `bias_step` (one sensor's bias jump), `periodic` (a sinusoidal
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

/// Log-spread of sensor levels (deviation ratios) above which the others are not "homogeneous" and the effect is
/// unequal noise rather than outlier sensors.
const UNEQUAL_LN_SPREAD: f64 = 0.3;

/// Share of the best candidate's χ² reduction that `thermal` must reach to be preferred to it.
const THERMAL_PREFERENCE: f64 = 0.8;

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

/// Runs the diagnosis on a recording (all sensor columns; `temp_c` used when present). Phases: the axes
/// ([`axis_works`]), each axis measured and its candidates selected ([`analyse_axis`]), the second look at axes
/// without an effect ([`retest_quiet_axes`]), and each axis's report ([`report_axis`]).
pub fn diagnose(rec: &Recording, opts: &Options) -> Result<Report, DiagnoseError> {
    let tau0 = rec.sample_interval_s().ok_or(DiagnoseError::NoTimeBase)?;
    let n = rec.len();
    if n < MIN_SAMPLES {
        return Err(DiagnoseError::TooShort { samples: n });
    }
    let raw = axis_works(rec);
    if raw.is_empty() {
        return Err(DiagnoseError::NoAxis);
    }
    // One sensor's bias step, found against its neighbours and removed before anything else is measured.
    let found: Vec<Vec<steps::Step>> = raw
        .iter()
        .map(|w| steps::find(&w.series, opts.p_false))
        .collect();
    let fixed: Vec<Vec<Option<Vec<f64>>>> = raw
        .iter()
        .zip(&found)
        .map(|(w, st)| {
            (0..w.series.len())
                .map(|i| {
                    st.iter()
                        .find(|s| s.sensor == i)
                        .map(|s| steps::remove(w.series[i], s))
                })
                .collect()
        })
        .collect();
    let works: Vec<AxisWork> = raw
        .iter()
        .zip(&fixed)
        .map(|(w, f)| AxisWork {
            series: w
                .series
                .iter()
                .zip(f)
                .map(|(s, c)| c.as_deref().unwrap_or(s))
                .collect(),
            groups: w.groups.clone(),
            ..*w
        })
        .collect();
    let temp = rec
        .temp_c
        .as_deref()
        .filter(|t| t.len() >= n && t.iter().all(|x| x.is_finite()));
    let mut an = Analyzer::new();
    let mut thresholds: BTreeMap<(usize, u64), f64> = BTreeMap::new();
    let mut states: Vec<AxisState> = works
        .iter()
        .map(|w| analyse_axis(&mut an, w, tau0, temp, opts, &mut thresholds))
        .collect();
    retest_quiet_axes(&works, &mut states, opts, &mut thresholds);

    let mut out = Assembled::default();
    for (w, st) in works.iter().zip(states) {
        report_axis(&mut an, w, st, tau0, opts, &mut thresholds, &mut out);
    }
    let Assembled {
        axes,
        effects,
        curves,
        fitted,
        gaps,
        unexplained,
    } = out;
    Ok(Report {
        gap_before: rms(gaps.fit_before),
        gap_after: rms(gaps.fit_after),
        heldout: HeldOut {
            gap_before: rms(gaps.held_before),
            gap_after: rms(gaps.held_after),
            rms_before: rms(gaps.raw_before),
            rms_after: rms(gaps.raw_after),
        },
        effects: merge_effects(effects)
            .into_iter()
            .chain(step_effects(&works, &found, tau0))
            .chain(unexplained)
            .collect(),
        axes,
        samples: n,
        tau0_s: tau0,
        weights: opts.weights,
        temperature: temp.is_some(),
        min_blocks: opts.min_blocks,
        p_false: opts.p_false,
        disturbances: quiet::find(rec, opts.p_false),
        curves,
        fitted,
    })
}

/// The axes with at least two sensors, gyro x y z then accel x y z.
fn axis_works(rec: &Recording) -> Vec<AxisWork<'_>> {
    let mut works = Vec::new();
    for kind in [SensorKind::Gyro, SensorKind::Accel] {
        for axis in 0..3 {
            let cols: Vec<_> = rec
                .columns
                .iter()
                .filter(|c| c.kind == kind && c.axis == axis)
                .collect();
            if cols.len() >= 2 {
                works.push(AxisWork {
                    kind,
                    axis,
                    groups: cols.iter().map(|c| c.group).collect(),
                    series: cols.iter().map(|c| c.data.as_slice()).collect(),
                });
            }
        }
    }
    works
}

/// Weights of the cluster mean under `rule`, from the sensors' first-half noise fits.
fn weights(rule: WeightRule, singles: &[NoiseFit]) -> Vec<f64> {
    let ns = singles.len();
    match rule {
        WeightRule::Equal => vec![1.0 / ns as f64; ns],
        WeightRule::InverseVariance => {
            let inv: Vec<f64> = singles
                .iter()
                .map(|s| 1.0 / s.white.powi(2).max(1e-300))
                .collect();
            let sum: f64 = inv.iter().sum();
            inv.iter().map(|v| v / sum).collect()
        }
    }
}

/// The typical sensor of the first half (per-τ median of the sensors' deviations) and its baseline noise model:
/// the four terms with its single-pole bandwidth when the curve shows one (`noisefit::fit_band_limited`); and the
/// sensors' RMS misfit to their own four-term and band-limited fits.
fn typical_sensor(
    pts_first: &[Vec<AnalysisPoint>],
    singles: &[NoiseFit],
    tau0: f64,
) -> (NoiseFit, Option<noisefit::LowPass>, Terms, [f64; 2]) {
    let typical_pts: Vec<AnalysisPoint> = (0..pts_first.iter().map(Vec::len).min().unwrap_or(0))
        .map(|k| {
            let devs: Vec<f64> = pts_first.iter().map(|p| p[k].dev).collect();
            AnalysisPoint {
                dev: median(&devs),
                ..pts_first[0][k]
            }
        })
        .collect();
    let (typical, bandwidth) = noisefit::fit_band_limited(&typical_pts, tau0);
    let typ_terms = terms_of(&typical);
    let misfit_of = |fits: &[(NoiseFit, Option<noisefit::LowPass>)]| {
        rms(pts_first.iter().zip(fits).flat_map(|(p, (f, lp))| {
            p.iter().filter(|q| q.dev > 0.0).map(move |q| {
                let cut =
                    f.white.powi(2) / q.tau_s * (1.0 - lp.map_or(1.0, |l| l.white_factor(q.tau_s)));
                (q.dev / (f.avar(q.tau_s) - cut).max(1e-300).sqrt()).ln()
            })
        }))
    };
    let four: Vec<(NoiseFit, Option<noisefit::LowPass>)> =
        singles.iter().map(|f| (*f, None)).collect();
    let banded: Vec<(NoiseFit, Option<noisefit::LowPass>)> = pts_first
        .iter()
        .map(|p| noisefit::fit_band_limited(p, tau0))
        .collect();
    let model_misfit = [misfit_of(&four), misfit_of(&banded)];
    (typical, bandwidth, typ_terms, model_misfit)
}

/// Adds what is named on one sensor's own evidence to `chosen`: a sensor's own drift, confirmed on the held-out
/// half, and a sensor's own line, found on the first half and confirmed at its period on the held-out half.
fn name_per_sensor(
    cands: &[Candidate],
    chosen: &mut Vec<usize>,
    hh: &Half,
    typ: &Terms,
    opts: &Options,
) {
    if let Some(c) = cands.iter().position(|c| c.kind == "sensor_drift")
        && !chosen.contains(&c)
        && cands[c].cross.iter().any(|x| match x {
            Cross::Own { sensor, .. } => confirmed(hh, typ, *sensor, opts),
            _ => false,
        })
    {
        chosen.push(c);
    }
    if let Some(c) = cands.iter().position(|c| {
        c.kind == "periodic" && c.cross.iter().any(|x| matches!(x, Cross::OwnSine { .. }))
    }) && !chosen.contains(&c)
    {
        chosen.push(c);
    }
}

/// Phase 1 of an axis: single sensors and the typical sensor, the three halves measured (first, held-out, whole),
/// the candidates fitted on the first half and selected on the held-out one.
fn analyse_axis(
    an: &mut Analyzer,
    w: &AxisWork,
    tau0: f64,
    temp: Option<&[f64]>,
    opts: &Options,
    thresholds: &mut BTreeMap<(usize, u64), f64>,
) -> AxisState {
    let half = w.series[0].len() / 2;
    let first: Vec<&[f64]> = w.series.iter().map(|s| &s[..half]).collect();
    let second: Vec<&[f64]> = w.series.iter().map(|s| &s[half..]).collect();

    // Single sensors of both halves, the typical sensor of the first.
    let pts_first: Vec<Vec<AnalysisPoint>> = first.iter().map(|s| octave(an, s, tau0)).collect();
    let pts_held: Vec<Vec<AnalysisPoint>> = second.iter().map(|s| octave(an, s, tau0)).collect();
    let pts_whole: Vec<Vec<AnalysisPoint>> = w.series.iter().map(|s| octave(an, s, tau0)).collect();
    let singles: Vec<NoiseFit> = pts_first.iter().map(|p| noisefit::fit(p)).collect();
    let (typical, bandwidth, typ_terms, model_misfit) = typical_sensor(&pts_first, &singles, tau0);
    let wts = weights(opts.weights, &singles);

    let mb = opts.min_blocks;
    let hf = Half::measure(
        an,
        &first,
        &wts,
        tau0,
        mb,
        &typ_terms,
        &pts_first,
        temp.map(|t| &t[..half]),
    );
    let hh = Half::measure(
        an,
        &second,
        &wts,
        tau0,
        mb,
        &typ_terms,
        &pts_held,
        temp.map(|t| &t[half..]),
    );
    let own = periodic::own_lines(&first, &second, tau0, opts.p_false);
    let cands = candidates(
        an,
        w,
        &first,
        &hf,
        tau0,
        temp.map(|t| &t[..half]),
        &typ_terms,
        opts,
        &own,
    );
    let hw = Half::measure(an, &w.series, &wts, tau0, mb, &typ_terms, &pts_whole, temp);
    let thr = threshold(thresholds, hw.len(), opts.p_false);
    let mut chosen = select(&cands, &hw, &hh, &wts, opts, thr, None);
    // Effects that together remove less than half of the held-out excess are not named: the gap is `unexplained`.
    let gave_up = !unexplained::enough(&cands, &chosen, &hh, &wts, opts);
    if gave_up {
        chosen.clear();
    }
    name_per_sensor(&cands, &mut chosen, &hh, &typ_terms, opts);
    AxisState {
        hf,
        hw,
        pts_whole,
        hh,
        cands,
        chosen,
        wts,
        typical,
        bandwidth,
        typ_terms,
        model_misfit,
        gave_up,
    }
}

/// Effects are shared by the axes of a sensor more often than not (a thermal bias, a common mode): an axis with no
/// effect of its own is tested again, at the looser `p_sibling`, for the kinds found on its siblings; and for any
/// kind when the sensor's axes together hold a significant gap (the scan of their summed z-scores, divided by
/// √axes, at `p_false`) that none of them shows alone.
fn retest_quiet_axes(
    works: &[AxisWork],
    states: &mut [AxisState],
    opts: &Options,
    thresholds: &mut BTreeMap<(usize, u64), f64>,
) {
    let pooled: Vec<bool> = works
        .iter()
        .map(|w| {
            let zs: Vec<Vec<f64>> = states
                .iter()
                .zip(works)
                .filter(|(_, x)| x.kind == w.kind)
                .map(|(st, _)| {
                    let p0 = Model::independent(st.wts.len());
                    evaluate(&p0, &st.hw, &st.wts, opts.model_tolerance)
                        .iter()
                        .map(|p| p.z)
                        .collect()
                })
                .collect();
            let n = zs.iter().map(Vec::len).min().unwrap_or(0);
            let k = zs.len() as f64;
            let sum: Vec<f64> = (0..n)
                .map(|t| zs.iter().map(|z| z[t]).sum::<f64>() / k.sqrt())
                .collect();
            n > 0 && scan_statistic(&sum) > threshold(thresholds, n, opts.p_false)
        })
        .collect();
    for i in 0..states.len() {
        if !states[i].chosen.is_empty() || states[i].gave_up {
            continue;
        }
        let kinds: Vec<&'static str> = states
            .iter()
            .zip(works)
            .filter(|(_, w)| w.kind == works[i].kind)
            .flat_map(|(st, _)| st.chosen.iter().map(|&c| st.cands[c].kind))
            .collect();
        if kinds.is_empty() && !pooled[i] {
            continue;
        }
        let st = &states[i];
        let chosen = if kinds.is_empty() {
            let thr = threshold(thresholds, st.hw.len(), opts.p_sibling);
            select(&st.cands, &st.hw, &st.hh, &st.wts, opts, thr, None)
        } else {
            sibling(st, &kinds, opts).into_iter().collect()
        };
        states[i].chosen = chosen;
    }
}

/// What the per-axis reports add up to.
#[derive(Default)]
struct Assembled {
    axes: Vec<AxisReport>,
    effects: Vec<(SensorKind, usize, Candidate, Acts)>,
    curves: Vec<AxisCurves>,
    fitted: Vec<AxisFit>,
    gaps: Gaps,
    unexplained: Vec<Effect>,
}

/// Predicted white-region deviation ratio of the equal mean over the inverse-variance mean under `model`.
fn weighting_recovers(model: &Model, hh: &Half, ns: usize) -> f64 {
    if hh.len() == 0 {
        return 1.0;
    }
    let inv: Vec<f64> = model.level.iter().map(|q| 1.0 / q.max(1e-300)).collect();
    let sum: f64 = inv.iter().sum();
    let iv: Vec<f64> = inv.iter().map(|v| v / sum).collect();
    let eq = vec![1.0 / ns as f64; ns];
    let (t, v, th) = (hh.tau_s[0], hh.typical[0], hh.temp[0]);
    (model.avar(&eq, t, v, th) / model.avar(&iv, t, v, th).max(1e-300)).sqrt()
}

/// Where each chosen effect acts: its share of the held-out prediction, with − without it.
fn effects_of(
    w: &AxisWork,
    st: &AxisState,
    model: &Model,
) -> Vec<(SensorKind, usize, Candidate, Acts)> {
    let ns = w.series.len();
    let AxisState { cands, chosen, .. } = st;
    chosen
        .iter()
        .enumerate()
        .map(|(pos, &i)| {
            let others: Vec<&Candidate> = chosen
                .iter()
                .enumerate()
                .filter(|(p, _)| *p != pos)
                .map(|(_, &j)| &cands[j])
                .collect();
            let mut a = acts(
                cands[i].nature(),
                &st.hh,
                &st.wts,
                model,
                &build(ns, &others),
                &st.typ_terms,
            );
            if cands[i].kind == "periodic" {
                a.0 = "periodic".into();
            }
            (w.kind, w.axis, cands[i].clone(), a)
        })
        .collect()
}

/// Phase 3 of an axis: the final model evaluated on both halves, its rows, regions, gains and effects.
fn report_axis(
    an: &mut Analyzer,
    w: &AxisWork,
    st: AxisState,
    tau0: f64,
    opts: &Options,
    thresholds: &mut BTreeMap<(usize, u64), f64>,
    out: &mut Assembled,
) {
    let ns = w.series.len();
    let (hf, hw, hh, wts) = (&st.hf, &st.hw, &st.hh, &st.wts);
    let refs: Vec<&Candidate> = st.chosen.iter().map(|&i| &st.cands[i]).collect();
    let p0 = Model::independent(ns);
    let model = build(ns, &refs);
    let tol = opts.model_tolerance;

    let before_fit = evaluate(&p0, hf, wts, tol);
    let after_fit = evaluate(&model, hf, wts, tol);
    let before = evaluate(&p0, hh, wts, tol);
    let after = evaluate(&model, hh, wts, tol);
    // The excess gap counts on an axis whose remaining gap is significant (the selection's own test), so a chance
    // excursion of a few long-τ points on a clean axis is not reported as a gap.
    let thr = threshold(thresholds, hw.len(), opts.p_false);
    let sig = [
        significant(&evaluate(&p0, hw, wts, tol), thr),
        significant(&evaluate(&model, hw, wts, tol), thr),
    ];
    let ex = |p: &[PointGap], on: bool| {
        if on {
            rms(p.iter().map(|x| excess(x, opts.z)))
        } else {
            0.0
        }
    };
    out.gaps
        .add(&before_fit, &after_fit, &before, &after, opts.z, sig);

    let (taus, independence) = tau_rows(hh, wts, &p0, &model, &before, &after);
    let label = axis_label(w.kind, w.axis);
    let regions = regions(&st.typ_terms, hh, &before, &after, opts.z);
    let (rms_gain, bias_stability_gain) = gains(an, &w.series, &st.pts_whole, wts, tau0);
    let weighting_recovers = weighting_recovers(&model, hh, ns);
    out.effects.extend(effects_of(w, &st, &model));
    out.curves.push(AxisCurves {
        axis: label.clone(),
        before: taus.iter().map(|r| r.predicted_before).collect(),
        after: taus.iter().map(|r| r.predicted_after).collect(),
        measured: Measured {
            tau_s: taus.iter().map(|r| r.tau_s).collect(),
            dev: taus.iter().map(|r| r.dev).collect(),
            lo: taus.iter().map(|r| r.dev_lo).collect(),
            hi: taus.iter().map(|r| r.dev_hi).collect(),
            edf: taus.iter().map(|r| r.edf).collect(),
            sigma_ln: taus.iter().map(|r| 1.0 / (2.0 * r.edf).sqrt()).collect(),
        },
    });
    out.fitted.push(AxisFit {
        kind: w.kind,
        axis: w.axis,
        groups: w.groups.clone(),
        effects: refs.iter().map(|c| c.kind).collect(),
        level: refs.iter().rev().find_map(|c| c.level.clone()),
        cross: refs
            .iter()
            .flat_map(|c| c.cross.iter().map(move |x| (c.kind, x.clone())))
            .collect(),
        bandwidth: st.bandwidth,
    });
    let mut effects: Vec<String> = refs.iter().map(|c| c.kind.to_string()).collect();
    if sig[1] {
        let u = unexplained::effect(w, &st, &after, ex(&after, sig[1]), opts);
        effects.push(u.kind.clone());
        out.unexplained.push(u);
    }
    out.axes.push(AxisReport {
        axis: label,
        sensors: ns,
        expected_gain: (ns as f64).sqrt(),
        rms_gain,
        bias_stability_gain,
        weighting_recovers,
        heldout_gap: [ex(&before, sig[0]), ex(&after, sig[1])],
        gap: [ex(&before_fit, sig[0]), ex(&after_fit, sig[1])],
        significant: sig,
        regions,
        taus,
        independence,
        typical: st.typical,
        model_misfit: st.model_misfit[0],
        model_misfit_band_limited: st.model_misfit[1],
        bandwidth_hz: st.bandwidth.map(|l| l.cutoff_hz),
        effects,
    });
}

/// The `bias_step` effects, one per sensor and axis: time and size of the step, its score and threshold.
fn step_effects(works: &[AxisWork], found: &[Vec<steps::Step>], tau0: f64) -> Vec<Effect> {
    let mut out = Vec::new();
    for (w, st) in works.iter().zip(found) {
        for s in st {
            let ax = AXIS_NAMES.get(w.axis).copied().unwrap_or('?').to_string();
            let window = s.window as f64 * tau0;
            let n = w.series[s.sensor].len();
            let mut params = BTreeMap::new();
            params.insert(
                ax.clone(),
                serde_json::json!({
                    "at_s": s.at as f64 * tau0,
                    "at_fraction": s.at as f64 / n as f64,
                    "size": s.size,
                    "z": s.z,
                    "threshold_z": s.threshold,
                    "window_s": window,
                }),
            );
            out.push(Effect {
                kind: "bias_step".into(),
                sensor: w.kind.name().into(),
                axes: ax,
                groups: Groups::List(vec![w.groups[s.sensor]]),
                region: "step".into(),
                tau_s: [window, window],
                tau_at_max_s: window,
                share: step_share(s, n),
                params,
            });
        }
    }
    out
}

/// The step's share of its own sensor's overlapping Allan variance at the detection window τ = mτ₀, from the
/// closed form of a step Δ in n samples, `Δ²·m/(3(n − 2m))` (the 2m straddling differences, triangular), against
/// the noise that made its score: `Δ²/z²` is `2σ²_A`.
fn step_share(s: &steps::Step, n: usize) -> f64 {
    let m = s.window as f64;
    let step = s.size.powi(2) * m / (3.0 * (n as f64 - 2.0 * m).max(1.0));
    let noise = 0.5 * s.size.powi(2) / s.z.powi(2).max(1e-300);
    step / (step + noise)
}

/// Region, τ range, τ of max and max share of an effect (see [`acts`]).
type Acts = (String, [f64; 2], f64, f64);

#[cfg(test)]
mod tests;
