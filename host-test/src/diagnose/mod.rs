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
pub mod model;
pub mod report;

use crate::allan::edf_for_kind;
use crate::allan::{AnalysisPoint, Analyzer, DevKind, Options as AllanOptions, TauSpec};
use crate::formats::csv::{AXIS_NAMES, Recording, SensorKind};
use crate::noisefit::{self, NoiseFit};
use acov::AllanCov;
use model::{Cross, Model, Share, Terms};
use serde::Serialize;
use statrs::distribution::{ChiSquared, ContinuousCDF, Normal};
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
    /// `common_mode`, `block_common_mode`, `common_mode_drift`, `thermal`, `outlier_sensor`, `unequal_noise`.
    pub kind: String,
    /// `gyro` or `accel`.
    pub sensor: String,
    /// Axes, e.g. `xyz` or `y`.
    pub axes: String,
    /// Groups concerned (0-based; all for cluster-wide effects; a list per block for `block_common_mode`).
    pub groups: Groups,
    /// Where it acts most: `quantization`, `white`, `flicker` or `random_walk` (the typical sensor's dominant term
    /// at `tau_at_max_s`).
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
    /// Curves for plots: per axis (label), the held-out measured curve and both predictions.
    #[serde(skip)]
    pub curves: Vec<AxisCurves>,
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

/// Median of the finite values of a slice (NaN if none).
fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    if s.is_empty() {
        return f64::NAN;
    }
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

fn octave(an: &mut Analyzer, y: &[f64], tau0: f64) -> Vec<AnalysisPoint> {
    an.analyze(
        DevKind::Oadev,
        y,
        tau0,
        &TauSpec::Octave,
        &AllanOptions::default(),
    )
}

fn weighted_mean(series: &[&[f64]], w: &[f64]) -> Vec<f64> {
    let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
    let mut out = vec![0.0; len];
    for (s, wi) in series.iter().zip(w) {
        for (o, x) in out.iter_mut().zip(s.iter()) {
            *o += wi * x;
        }
    }
    out
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

/// The typical model as five terms.
fn terms_of(f: &NoiseFit) -> Terms {
    Terms([
        3.0 * f.quantization.powi(2),
        f.white.powi(2),
        noisefit::FLICKER_AVAR * f.bias_instability.powi(2),
        f.random_walk.powi(2) / 3.0,
        0.0,
    ])
}

/// Noise type (α of the rate's PSD) of the term that dominates `t` at `tau_s`: quantisation 2 (white phase),
/// white 0, flicker −1, random walk and ramp −2.
fn dominant_alpha(t: &Terms, tau_s: f64) -> i32 {
    let b = Terms::basis(tau_s);
    let k = (0..5)
        .max_by(|&i, &j| (b[i] * t.0[i]).total_cmp(&(b[j] * t.0[j])))
        .unwrap_or(1);
    [2, 0, -1, -2, -2][k]
}

/// Region name of a τ under the typical model.
fn region_name(t: &Terms, tau_s: f64) -> &'static str {
    match dominant_alpha(t, tau_s) {
        2 => "quantization",
        0 => "white",
        -1 => "flicker",
        _ => "random_walk",
    }
}

/// EDF of an OADEV at factor `m` on `n` samples for noise type `alpha` (fallback: the white-FM count).
fn edf(alpha: i32, m: usize, n: usize) -> f64 {
    edf_for_kind(DevKind::Oadev, alpha, m, n)
        .unwrap_or_else(|| (1.5 * n as f64 / m.max(1) as f64).max(1.0))
}

/// `E[χ²_ν/ν] / median(χ²_ν/ν)`: corrects a median of variance estimates with `nu` EDF to their mean.
fn median_to_mean(nu: f64) -> f64 {
    ChiSquared::new(nu)
        .map(|c| nu / c.inverse_cdf(0.5))
        .ok()
        .filter(|x| x.is_finite() && *x > 0.0)
        .unwrap_or(1.0)
}

/// z-score of a χ²_ν/ν variable observed at `ratio`: Φ⁻¹(F_χ²ν(ν·ratio)), from the tail the value lies in (so
/// that z stays exact far out), clamped to ±30.
fn chi2_z(ratio: f64, nu: f64) -> f64 {
    let (Ok(c), Ok(n)) = (ChiSquared::new(nu), Normal::new(0.0, 1.0)) else {
        return 0.0;
    };
    let x = nu * ratio.max(0.0);
    let z = if ratio > 1.0 {
        -n.inverse_cdf(c.sf(x).max(1e-300))
    } else {
        n.inverse_cdf(c.cdf(x).max(1e-300))
    };
    if z.is_finite() {
        z.clamp(-30.0, 30.0)
    } else {
        0.0
    }
}

/// The statistics of one half of one axis at every octave τ it supports.
#[derive(Clone, Debug, Default)]
struct Half {
    n: usize,
    tau_s: Vec<f64>,
    m: Vec<usize>,
    /// Cluster Allan variance (weighted mean).
    cluster: Vec<f64>,
    /// Its EDF and noise type.
    edf: Vec<f64>,
    alpha: Vec<i32>,
    /// `singles[i][k]`: sensor i's Allan variance.
    singles: Vec<Vec<f64>>,
    /// Bias-corrected median of the singles.
    typical: Vec<f64>,
    /// Uncertainty of ln(typical) (variance scale).
    typical_sigma: Vec<f64>,
    /// EDF of one sensor's variance.
    single_edf: Vec<f64>,
    /// Temperature Allan variance, °C².
    temp: Vec<Option<f64>>,
}

impl Half {
    /// Measures one half: `series` the sensors, `w` the weights, `typ` the typical model (for noise types).
    #[allow(clippy::too_many_arguments)]
    fn measure(
        an: &mut Analyzer,
        series: &[&[f64]],
        w: &[f64],
        tau0: f64,
        min_blocks: usize,
        typ: &Terms,
        singles_pts: &[Vec<AnalysisPoint>],
        temp: Option<&[f64]>,
    ) -> Half {
        let n = series.iter().map(|s| s.len()).min().unwrap_or(0);
        let mean = weighted_mean(series, w);
        let cl = octave(an, &mean, tau0);
        let temp_pts = temp.map(|t| octave(an, t, tau0)).unwrap_or_default();
        let ns = series.len();
        let mut h = Half {
            n,
            singles: vec![Vec::new(); ns],
            ..Half::default()
        };
        for (k, p) in cl.iter().enumerate() {
            let m = p.m.max(1);
            let ok = n / m >= min_blocks
                && p.dev > 0.0
                && singles_pts
                    .iter()
                    .all(|s| s.get(k).is_some_and(|q| q.m == p.m));
            if !ok {
                continue;
            }
            // The noise type of the typical sensor's model (first half) sets the EDF: it is the type of the
            // cluster under the null hypothesis the z-scores test (the cluster's own curve at four blocks would
            // identify a type by chance).
            let a_typ = dominant_alpha(typ, p.tau_s);
            let alpha = a_typ;
            let nu = edf(alpha, m, n);
            let d: Vec<f64> = singles_pts.iter().map(|s| s[k].dev.powi(2)).collect();
            let nu_s = edf(a_typ, m, n);
            h.tau_s.push(p.tau_s);
            h.m.push(m);
            h.cluster.push(p.dev * p.dev);
            h.edf.push(nu);
            h.alpha.push(alpha);
            h.typical.push(median(&d) * median_to_mean(nu_s));
            // The median of N estimates has ≈ π/2 × the variance of their mean; ln of a variance estimate has
            // variance 2/ν.
            h.typical_sigma
                .push((std::f64::consts::FRAC_PI_2 * 2.0 / nu_s / ns.max(1) as f64).sqrt());
            h.single_edf.push(nu_s);
            for (hs, di) in h.singles.iter_mut().zip(&d) {
                hs.push(*di);
            }
            h.temp
                .push(temp_pts.iter().find(|q| q.m == p.m).map(|q| q.dev * q.dev));
        }
        h
    }

    fn len(&self) -> usize {
        self.tau_s.len()
    }
}

/// The gap of one τ point.
#[derive(Clone, Copy, Debug, Default)]
struct PointGap {
    /// ln(measured / predicted) deviation.
    g: f64,
    /// Its total uncertainty.
    sigma: f64,
    /// z-score (χ² at the measured EDF, scaled for the other uncertainties).
    z: f64,
}

fn point_gap(measured: f64, predicted: f64, nu: f64, pred_sigma_var: f64, tol: f64) -> PointGap {
    let ratio = measured / predicted.max(1e-300);
    let s_meas = (1.0 / (2.0 * nu)).sqrt();
    let s_pred = 0.5 * pred_sigma_var;
    let sigma = (s_meas * s_meas + s_pred * s_pred + tol * tol).sqrt();
    PointGap {
        g: 0.5 * ratio.ln(),
        sigma,
        z: chi2_z(ratio, nu) * s_meas / sigma,
    }
}

fn evaluate(model: &Model, h: &Half, w: &[f64], tol: f64) -> Vec<PointGap> {
    (0..h.len())
        .map(|k| {
            let pred = model.avar(w, h.tau_s[k], h.typical[k], h.temp[k]);
            point_gap(h.cluster[k], pred, h.edf[k], h.typical_sigma[k], tol)
        })
        .collect()
}

fn chi2(p: &[PointGap]) -> f64 {
    p.iter().map(|x| x.z * x.z).sum()
}

/// MA(2) weights that give neighbouring octave z-scores the correlation measured on clean simulations (adjacent
/// ≈ 0.55, two apart ≈ 0.2; these weights give 0.61 and 0.20, on the safe side).
const OCTAVE_MA: [f64; 3] = [1.0, 0.8, 0.35];

/// Null correlation of z-scores `lag` octaves apart (1 at lag 0, 0 beyond the MA order).
fn octave_corr(lag: usize) -> f64 {
    let norm: f64 = OCTAVE_MA.iter().map(|x| x * x).sum();
    OCTAVE_MA
        .iter()
        .zip(OCTAVE_MA.iter().skip(lag))
        .map(|(a, b)| a * b)
        .sum::<f64>()
        / norm
}

/// The scan statistic of a run of z-scores (ordered by τ): the largest standardised sum over contiguous windows,
/// `max_{a ≤ b} Σ_{a..=b} z / √Var₀(Σ)`, with the null variance from [`octave_corr`]. One-sided, because every
/// effect the diagnosis models adds variance; over windows, because an effect acts over a band of τ — from the
/// first τ on (white-region effects), from some τ to the longest (drifts), or as a bump (a periodic temperature).
pub fn scan_statistic(z: &[f64]) -> f64 {
    let mut best = f64::NEG_INFINITY;
    for a in 0..z.len() {
        let (mut sum, mut var) = (0.0, 0.0);
        for (len, zk) in z[a..].iter().enumerate() {
            sum += zk;
            // Adding one point: its variance 1 plus twice its covariance with the (up to two) points before it.
            var += 1.0
                + 2.0
                    * (1..=len.min(OCTAVE_MA.len() - 1))
                        .map(octave_corr)
                        .sum::<f64>();
            best = best.max(sum / var.sqrt());
        }
    }
    best
}

/// The (1 − p) quantile of [`scan_statistic`] over `n` null z-scores (correlated as [`octave_corr`]), from 40,000
/// seeded Monte Carlo draws (deterministic).
pub fn scan_threshold(n: usize, p: f64) -> f64 {
    use rand_xoshiro::Xoshiro256PlusPlus;
    use rand_xoshiro::rand_core::SeedableRng;
    const DRAWS: usize = 40_000;
    if n == 0 {
        return f64::INFINITY;
    }
    let mut rng = Xoshiro256PlusPlus::seed_from_u64(0x5CA7_0000 + n as u64);
    let norm = OCTAVE_MA.iter().map(|x| x * x).sum::<f64>().sqrt();
    let mut e = vec![0.0; n + OCTAVE_MA.len()];
    let mut z = vec![0.0; n];
    let mut stats: Vec<f64> = (0..DRAWS)
        .map(|_| {
            e.iter_mut()
                .for_each(|x| *x = crate::sim::noise::normal(&mut rng));
            for (k, zk) in z.iter_mut().enumerate() {
                *zk = OCTAVE_MA
                    .iter()
                    .enumerate()
                    .map(|(j, w)| w * e[k + j])
                    .sum::<f64>()
                    / norm;
            }
            scan_statistic(&z)
        })
        .collect();
    stats.sort_by(f64::total_cmp);
    let k = ((1.0 - p) * DRAWS as f64).floor() as usize;
    stats[k.min(DRAWS - 1)]
}

/// Whether the remaining gap is significant: the scan statistic of the per-τ z-scores of the **whole record**
/// exceeds its null quantile. The whole record has twice each half's EDF at every τ and one octave more (T/4), where
/// slow effects are largest; once a model is fitted on the first half its z-scores there are conservative.
fn significant(whole: &[PointGap], threshold: f64) -> bool {
    let z: Vec<f64> = whole.iter().map(|p| p.z).collect();
    !z.is_empty() && scan_statistic(&z) > threshold
}

/// The part of a gap outside its ±z interval, in ln units: `σ·max(0, |z_score| − z)` (the z-score carries the χ²
/// skew of few-block estimates, so a low estimate at four blocks is not mistaken for a gap).
fn excess(p: &PointGap, z: f64) -> f64 {
    p.sigma * (p.z.abs() - z).max(0.0)
}

/// A candidate effect of one axis.
#[derive(Clone, Debug)]
struct Candidate {
    kind: &'static str,
    /// Replaces the per-sensor level factors (heterogeneity) …
    level: Option<Vec<f64>>,
    /// … and/or adds cross terms.
    cross: Vec<Cross>,
    groups: Groups,
    params: serde_json::Value,
}

impl Candidate {
    /// The Allan-variance shape of what it adds (shared processes), for naming its region.
    fn nature(&self) -> Option<Terms> {
        self.cross.iter().find_map(|c| match c {
            Cross::Shared { share, .. } => Some(share.part),
            Cross::Thermal { .. } => None,
        })
    }

    fn apply(&self, m: &mut Model) {
        if let Some(l) = &self.level {
            m.level = l.clone();
        }
        m.cross.extend(self.cross.iter().cloned());
    }
}

fn build(n: usize, chosen: &[&Candidate]) -> Model {
    let mut m = Model::independent(n);
    for c in chosen {
        c.apply(&mut m);
    }
    m
}

struct AxisWork<'a> {
    kind: SensorKind,
    axis: usize,
    groups: Vec<usize>,
    series: Vec<&'a [f64]>,
}

/// A weighted least-squares row on the five terms: (basis, observation, weight).
type Row5 = ([f64; 5], f64, f64);

/// The shared terms fitted (non-negative) with only the terms in `subset`; `None` if all come out zero.
fn fit_subset(rows: &[Row5], subset: &[usize]) -> Option<Terms> {
    let masked: Vec<Row5> = rows
        .iter()
        .map(|(b, y, w)| (Terms(*b).only(subset).0, *y, *w))
        .collect();
    let t = Terms(noisefit::nnls(&masked)?);
    t.0.iter().any(|&c| c > 0.0).then_some(t)
}

/// The shared and independent parts of the sensors `members` on the first half: the mean cross Allan covariance
/// per τ from the members' mean (`|M|²σ²_mean − Σσ²_i` over the |M|(|M|−1) pairs) as rows for the five terms,
/// weighted by its χ² scatter (fitted by [`fit_subset`]), and the rest of the typical member variance fitted with
/// four terms.
fn shared_fit(
    an: &mut Analyzer,
    first: &[&[f64]],
    h: &Half,
    members: &[usize],
    tau0: f64,
) -> Option<(Vec<Row5>, Terms)> {
    let k_m = members.len();
    if k_m < 2 {
        return None;
    }
    let sub: Vec<&[f64]> = members
        .iter()
        .filter_map(|&i| first.get(i).copied())
        .collect();
    let w = vec![1.0 / k_m as f64; k_m];
    let mean = weighted_mean(&sub, &w);
    let pts = octave(an, &mean, tau0);
    let mut shared_rows = Vec::new();
    let mut indep_rows = Vec::new();
    let km = k_m as f64;
    for k in 0..h.len() {
        let Some(p) = pts.iter().find(|p| p.m == h.m[k]) else {
            continue;
        };
        let a = p.dev * p.dev;
        let d: Vec<f64> = members.iter().map(|&i| h.singles[i][k]).collect();
        let sum_d: f64 = d.iter().sum();
        let c = (km * km * a - sum_d) / (km * (km - 1.0));
        let sd = a * (2.0 / h.edf[k]).sqrt() * km / (km - 1.0);
        if sd > 0.0 {
            shared_rows.push((Terms::basis(h.tau_s[k]), c, 1.0 / (sd * sd)));
        }
        let typ = median(&d) * median_to_mean(h.single_edf[k]);
        let e = typ - c.max(0.0);
        if e > 0.0 {
            let b = Terms::basis(h.tau_s[k]);
            indep_rows.push((
                [b[0], b[1], b[2], b[3]],
                e,
                h.single_edf[k] * km / 2.0 / (e * e),
            ));
        }
    }
    let e = noisefit::nnls(&indep_rows)?;
    Some((shared_rows, Terms([e[0], e[1], e[2], e[3], 0.0])))
}

/// Blocks of sensors from the Allan correlation matrix averaged over `levels` (level, weight): average-linkage
/// clustering, merging two clusters while their mean cross correlation exceeds `merge_z` times its null standard
/// deviation `√(Σ w_l²·1.5/T_l)·√(D_A D_B/(|A||B|))` (w normalised, T_l the level's differences; 1.5 accounts for
/// adjacent differences' correlation; `D = 1 + (|A|−1)ρ̄_A` the design effect of a cluster whose members share a
/// process).
fn blocks(ac: &AllanCov, levels: &[(usize, f64)], merge_z: f64) -> Vec<Vec<usize>> {
    let n = ac.n;
    let total: f64 = levels.iter().map(|&(_, w)| w).sum();
    let mut clusters: Vec<Vec<usize>> = (0..n).map(|i| vec![i]).collect();
    if total <= 0.0 || n < 2 {
        return clusters;
    }
    let mut r = vec![0.0; n * n];
    let mut var = 0.0;
    for &(l, w) in levels {
        let wl = w / total;
        for (x, c) in r.iter_mut().zip(ac.correlation(l)) {
            *x += wl * c;
        }
        var += wl * wl * 1.5 / ac.terms.get(l).copied().unwrap_or(1).max(1) as f64;
    }
    let sd = var.sqrt();
    // Mean correlation within a cluster (0 for a single sensor).
    let within = |c: &[usize]| -> f64 {
        let (mut s, mut k) = (0.0, 0usize);
        for (x, &i) in c.iter().enumerate() {
            for &j in &c[x + 1..] {
                s += r[i * n + j];
                k += 1;
            }
        }
        if k == 0 { 0.0 } else { (s / k as f64).max(0.0) }
    };
    loop {
        let mut best: Option<(f64, usize, usize)> = None;
        for a in 0..clusters.len() {
            for b in a + 1..clusters.len() {
                let (ca, cb) = (&clusters[a], &clusters[b]);
                let mut s = 0.0;
                for &i in ca {
                    for &j in cb {
                        s += r[i * n + j];
                    }
                }
                let (na, nb) = (ca.len() as f64, cb.len() as f64);
                // The pairs' estimates are not independent when each side shares a process: the design effect
                // (1 + (n−1)ρ) of each side multiplies the variance of their mean.
                let deff = (1.0 + (na - 1.0) * within(ca)) * (1.0 + (nb - 1.0) * within(cb));
                let z = s / (na * nb) / (sd * (deff / (na * nb)).sqrt());
                if best.is_none_or(|(bz, _, _)| z > bz) {
                    best = Some((z, a, b));
                }
            }
        }
        match best {
            Some((z, a, b)) if z > merge_z => {
                let moved = clusters.remove(b);
                clusters[a].extend(moved);
                clusters[a].sort_unstable();
            }
            _ => break,
        }
    }
    clusters
}

/// Thermal coefficients: per sensor, least squares of block means of the data on block means of temperature.
fn thermal_betas(series: &[&[f64]], temp: &[f64], block: usize) -> Vec<f64> {
    let block = block.max(1);
    let blocks = temp.len() / block;
    let bm = |x: &[f64]| -> Vec<f64> {
        x.chunks_exact(block)
            .take(blocks)
            .map(|c| c.iter().sum::<f64>() / block as f64)
            .collect()
    };
    let t = bm(temp);
    let tm = t.iter().sum::<f64>() / t.len().max(1) as f64;
    let stt: f64 = t.iter().map(|x| (x - tm).powi(2)).sum();
    series
        .iter()
        .map(|s| {
            let y = bm(s);
            let ym = y.iter().sum::<f64>() / y.len().max(1) as f64;
            let sty: f64 = t.iter().zip(&y).map(|(a, b)| (a - tm) * (b - ym)).sum();
            if stt > 0.0 { sty / stt } else { 0.0 }
        })
        .collect()
}

fn axis_label(kind: SensorKind, axis: usize) -> String {
    format!(
        "{}{}",
        kind.prefix(),
        AXIS_NAMES.get(axis).copied().unwrap_or('?')
    )
}

/// Where a chosen effect acts on the held-out half: (region, τ range, τ of max, max share). The region is the
/// dominant term of the effect's own shape (`nature`, shared processes) or else of the typical sensor, at the τ of
/// its largest share.
fn acts(
    nature: Option<Terms>,
    h: &Half,
    w: &[f64],
    full: &Model,
    without: &Model,
    typ: &Terms,
) -> Acts {
    let share: Vec<f64> = (0..h.len())
        .map(|k| {
            let a = full.avar(w, h.tau_s[k], h.typical[k], h.temp[k]);
            let b = without.avar(w, h.tau_s[k], h.typical[k], h.temp[k]);
            if a > 0.0 { ((a - b) / a).abs() } else { 0.0 }
        })
        .collect();
    let Some(kmax) = (0..share.len()).max_by(|&a, &b| share[a].total_cmp(&share[b])) else {
        return ("white".into(), [0.0; 2], 0.0, 0.0);
    };
    let top = share[kmax];
    let inside: Vec<usize> = (0..share.len())
        .filter(|&k| share[k] >= 0.5 * top)
        .collect();
    let lo = inside.first().map_or(h.tau_s[kmax], |&k| h.tau_s[k]);
    let hi = inside.last().map_or(h.tau_s[kmax], |&k| h.tau_s[k]);
    (
        region_name(nature.as_ref().unwrap_or(typ), h.tau_s[kmax]).into(),
        [lo, hi],
        h.tau_s[kmax],
        top,
    )
}

/// Memoised [`scan_threshold`].
fn threshold(cache: &mut BTreeMap<(usize, u64), f64>, n: usize, p: f64) -> f64 {
    *cache
        .entry((n, p.to_bits()))
        .or_insert_with(|| scan_threshold(n, p))
}

/// What phase 1 keeps of an axis for the sibling pass and the report.
struct AxisState {
    hf: Half,
    hw: Half,
    /// The sensors' octave OADEV of the whole record.
    pts_whole: Vec<Vec<AnalysisPoint>>,
    hh: Half,
    cands: Vec<Candidate>,
    chosen: Vec<usize>,
    wts: Vec<f64>,
    typical: NoiseFit,
    typ_terms: Terms,
    model_misfit: f64,
}

/// Greedy selection on the held-out half: while the remaining gap is significant (scan statistic above `thr`),
/// add the candidate (of the `allowed` kinds) that lowers the held-out `Σ z²` most, if it removes at least
/// `min_shrink` of the excess over the point count.
fn select(
    cands: &[Candidate],
    hw: &Half,
    hh: &Half,
    wts: &[f64],
    opts: &Options,
    thr: f64,
    allowed: Option<&[&str]>,
) -> Vec<usize> {
    let ns = wts.len();
    let mut chosen: Vec<usize> = Vec::new();
    loop {
        let refs: Vec<&Candidate> = chosen.iter().map(|&i| &cands[i]).collect();
        let m = build(ns, &refs);
        let pts = evaluate(&m, hh, wts, opts.model_tolerance);
        if !significant(&evaluate(&m, hw, wts, opts.model_tolerance), thr) {
            break;
        }
        let current = chi2(&pts);
        let excess_now = (current - pts.len() as f64).max(0.0);
        let mut scored: Vec<(f64, usize)> = Vec::new();
        for (i, c) in cands.iter().enumerate() {
            if chosen.contains(&i)
                || refs.iter().any(|r| r.kind == c.kind)
                || allowed.is_some_and(|a| !a.contains(&c.kind))
                || (c.level.is_some() && refs.iter().any(|r| r.level.is_some()))
            {
                continue;
            }
            let mut with = refs.clone();
            with.push(c);
            let x = chi2(&evaluate(&build(ns, &with), hh, wts, opts.model_tolerance));
            if x <= current - opts.min_shrink * excess_now && x < current {
                scored.push((x, i));
            }
        }
        let best = scored.iter().copied().min_by(|a, b| a.0.total_cmp(&b.0));
        // A measured cause beats an anonymous drift that explains the same: with the temperature recorded,
        // `thermal` is taken when it removes at least `THERMAL_PREFERENCE` of what the best candidate removes.
        let thermal = scored
            .iter()
            .copied()
            .find(|&(_, i)| cands[i].kind == "thermal");
        match (best, thermal) {
            (Some((xb, _)), Some((xt, i)))
                if current - xt >= THERMAL_PREFERENCE * (current - xb) =>
            {
                chosen.push(i);
            }
            (Some((_, i)), _) => chosen.push(i),
            _ => break,
        }
    }
    chosen
}

/// The sibling test of an axis for the kinds found on the other axes of its sensor: each such candidate (fitted on
/// the first half) predicts how much it lowers every held-out z-score, `s_k`; the projection of the held-out P0
/// z-scores on that shape, `T = Σ z_k s_k / √(sᵀ R s)` (R the null correlation of neighbouring octaves), is N(0, 1)
/// without an effect, whatever the candidate, because the halves are independent. The best candidate with
/// `T > z(1 − p_sibling)` that also passes the shrink rule is taken.
fn sibling(st: &AxisState, kinds: &[&str], opts: &Options) -> Option<usize> {
    let ns = st.wts.len();
    let p0 = evaluate(
        &Model::independent(ns),
        &st.hh,
        &st.wts,
        opts.model_tolerance,
    );
    let current = chi2(&p0);
    let excess_now = (current - p0.len() as f64).max(0.0);
    let z_crit = Normal::new(0.0, 1.0)
        .map(|n| n.inverse_cdf(1.0 - opts.p_sibling))
        .unwrap_or(f64::INFINITY);
    let mut best: Option<(f64, usize)> = None;
    for (i, c) in st.cands.iter().enumerate() {
        if !kinds.contains(&c.kind) {
            continue;
        }
        let with = evaluate(&build(ns, &[c]), &st.hh, &st.wts, opts.model_tolerance);
        let shift: Vec<f64> = p0.iter().zip(&with).map(|(a, b)| a.z - b.z).collect();
        let num: f64 = p0.iter().zip(&shift).map(|(a, s)| a.z * s).sum();
        let mut var = 0.0;
        for (a, sa) in shift.iter().enumerate() {
            for (b, sb) in shift.iter().enumerate() {
                var += sa * sb * octave_corr(a.abs_diff(b));
            }
        }
        let x = chi2(&with);
        if var > 0.0
            && num / var.sqrt() > z_crit
            && x <= current - opts.min_shrink * excess_now
            && best.is_none_or(|(bx, _)| x < bx)
        {
            best = Some((x, i));
        }
    }
    best.map(|(_, i)| i)
}

/// Runs the diagnosis on a recording (all sensor columns; `temp_c` used when present).
pub fn diagnose(rec: &Recording, opts: &Options) -> Result<Report, String> {
    let tau0 = rec
        .sample_interval_s()
        .ok_or("fewer than two samples, or time not increasing")?;
    let n = rec.len();
    if n < MIN_SAMPLES {
        return Err(format!(
            "{n} samples: too short for a diagnosis (at least {MIN_SAMPLES}; hours are better)"
        ));
    }
    let half = n / 2;
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
    if works.is_empty() {
        return Err("no axis has at least two sensors".into());
    }
    let temp = rec
        .temp_c
        .as_deref()
        .filter(|t| t.len() >= n && t.iter().all(|x| x.is_finite()));
    let mut an = Analyzer::new();

    let mut axes = Vec::new();
    let mut all_effects: Vec<(SensorKind, usize, Candidate, Acts)> = Vec::new();
    let mut curves = Vec::new();
    let mut gaps = Gaps::default();
    let mut thresholds: BTreeMap<(usize, u64), f64> = BTreeMap::new();
    let mut states: Vec<AxisState> = Vec::new();

    for w in &works {
        let ns = w.series.len();
        let first: Vec<&[f64]> = w.series.iter().map(|s| &s[..half]).collect();
        let second: Vec<&[f64]> = w.series.iter().map(|s| &s[half..]).collect();

        // Single sensors of both halves, the typical sensor of the first.
        let pts_first: Vec<Vec<AnalysisPoint>> =
            first.iter().map(|s| octave(&mut an, s, tau0)).collect();
        let pts_held: Vec<Vec<AnalysisPoint>> =
            second.iter().map(|s| octave(&mut an, s, tau0)).collect();
        let pts_whole: Vec<Vec<AnalysisPoint>> =
            w.series.iter().map(|s| octave(&mut an, s, tau0)).collect();
        let singles: Vec<NoiseFit> = pts_first.iter().map(|p| noisefit::fit(p)).collect();
        let typical_pts: Vec<AnalysisPoint> =
            (0..pts_first.iter().map(Vec::len).min().unwrap_or(0))
                .map(|k| {
                    let devs: Vec<f64> = pts_first.iter().map(|p| p[k].dev).collect();
                    AnalysisPoint {
                        dev: median(&devs),
                        ..pts_first[0][k]
                    }
                })
                .collect();
        let typical = noisefit::fit(&typical_pts);
        let typ_terms = terms_of(&typical);
        let model_misfit = rms(pts_first.iter().zip(&singles).flat_map(|(p, f)| {
            p.iter()
                .filter(|q| q.dev > 0.0)
                .map(move |q| (q.dev / f.avar(q.tau_s).max(1e-300).sqrt()).ln())
        }));

        let wts: Vec<f64> = match opts.weights {
            WeightRule::Equal => vec![1.0 / ns as f64; ns],
            WeightRule::InverseVariance => {
                let inv: Vec<f64> = singles
                    .iter()
                    .map(|s| 1.0 / s.white.powi(2).max(1e-300))
                    .collect();
                let sum: f64 = inv.iter().sum();
                inv.iter().map(|v| v / sum).collect()
            }
        };

        let hf = Half::measure(
            &mut an,
            &first,
            &wts,
            tau0,
            opts.min_blocks,
            &typ_terms,
            &pts_first,
            temp.map(|t| &t[..half]),
        );
        let hh = Half::measure(
            &mut an,
            &second,
            &wts,
            tau0,
            opts.min_blocks,
            &typ_terms,
            &pts_held,
            temp.map(|t| &t[half..]),
        );

        let cands = candidates(
            &mut an,
            w,
            &first,
            &hf,
            tau0,
            temp.map(|t| &t[..half]),
            &typ_terms,
            opts,
        );
        let hw = Half::measure(
            &mut an,
            &w.series,
            &wts,
            tau0,
            opts.min_blocks,
            &typ_terms,
            &pts_whole,
            temp,
        );
        let thr = threshold(&mut thresholds, hw.len(), opts.p_false);
        let chosen = select(&cands, &hw, &hh, &wts, opts, thr, None);
        states.push(AxisState {
            hf,
            hw,
            pts_whole,
            hh,
            cands,
            chosen,
            wts,
            typical,
            typ_terms,
            model_misfit,
        });
    }

    // Effects are shared by the axes of a sensor more often than not (a thermal bias, a common mode): an axis
    // with no effect of its own is tested again, at the looser `p_sibling`, for the kinds found on its siblings;
    // and for any kind when the sensor's axes together hold a significant gap (the scan of their summed z-scores,
    // divided by √axes, at `p_false`) that none of them shows alone.
    let pooled: Vec<bool> = works
        .iter()
        .map(|w| {
            let zs: Vec<Vec<f64>> = states
                .iter()
                .zip(&works)
                .filter(|(_, x)| x.kind == w.kind)
                .map(|(st, _)| {
                    evaluate(
                        &Model::independent(st.wts.len()),
                        &st.hw,
                        &st.wts,
                        opts.model_tolerance,
                    )
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
            n > 0 && scan_statistic(&sum) > threshold(&mut thresholds, n, opts.p_false)
        })
        .collect();
    for i in 0..states.len() {
        if !states[i].chosen.is_empty() {
            continue;
        }
        let kinds: Vec<&'static str> = states
            .iter()
            .zip(&works)
            .filter(|(_, w)| w.kind == works[i].kind)
            .flat_map(|(st, _)| st.chosen.iter().map(|&c| st.cands[c].kind))
            .collect();
        if kinds.is_empty() && !pooled[i] {
            continue;
        }
        let st = &states[i];
        let chosen = if kinds.is_empty() {
            let thr = threshold(&mut thresholds, st.hw.len(), opts.p_sibling);
            select(&st.cands, &st.hw, &st.hh, &st.wts, opts, thr, None)
        } else {
            sibling(st, &kinds, opts).into_iter().collect()
        };
        states[i].chosen = chosen;
    }

    for (w, st) in works.iter().zip(states) {
        let AxisState {
            hf,
            hw,
            pts_whole,
            hh,
            cands,
            chosen,
            wts,
            typical,
            typ_terms,
            model_misfit,
        } = st;
        let ns = w.series.len();
        let refs: Vec<&Candidate> = chosen.iter().map(|&i| &cands[i]).collect();
        let p0 = Model::independent(ns);
        let model = build(ns, &refs);

        let before_fit = evaluate(&p0, &hf, &wts, opts.model_tolerance);
        let after_fit = evaluate(&model, &hf, &wts, opts.model_tolerance);
        let before = evaluate(&p0, &hh, &wts, opts.model_tolerance);
        let after = evaluate(&model, &hh, &wts, opts.model_tolerance);
        // The excess gap counts on an axis whose remaining gap is significant (the selection's own test), so a
        // chance excursion of a few long-τ points on a clean axis is not reported as a gap.
        let thr = threshold(&mut thresholds, hw.len(), opts.p_false);
        let sig = [
            significant(&evaluate(&p0, &hw, &wts, opts.model_tolerance), thr),
            significant(&evaluate(&model, &hw, &wts, opts.model_tolerance), thr),
        ];
        let ex = |p: &[PointGap], on: bool| {
            if on {
                rms(p.iter().map(|x| excess(x, opts.z)))
            } else {
                0.0
            }
        };
        gaps.add(&before_fit, &after_fit, &before, &after, opts.z, sig);

        let (taus, independence) = tau_rows(&hh, &wts, &p0, &model, &before, &after);
        let label = axis_label(w.kind, w.axis);
        let regions = regions(&typ_terms, &hh, &before, &after, opts.z);
        let (rms_gain, bias_stability_gain) = gains(&mut an, &w.series, &pts_whole, &wts, tau0);
        let weighting_recovers = if hh.len() > 0 {
            let inv: Vec<f64> = model.level.iter().map(|q| 1.0 / q.max(1e-300)).collect();
            let sum: f64 = inv.iter().sum();
            let iv: Vec<f64> = inv.iter().map(|v| v / sum).collect();
            let eq = vec![1.0 / ns as f64; ns];
            let (t, v, th) = (hh.tau_s[0], hh.typical[0], hh.temp[0]);
            (model.avar(&eq, t, v, th) / model.avar(&iv, t, v, th).max(1e-300)).sqrt()
        } else {
            1.0
        };
        for (pos, &i) in chosen.iter().enumerate() {
            let others: Vec<&Candidate> = chosen
                .iter()
                .enumerate()
                .filter(|(p, _)| *p != pos)
                .map(|(_, &j)| &cands[j])
                .collect();
            let a = acts(
                cands[i].nature(),
                &hh,
                &wts,
                &model,
                &build(ns, &others),
                &typ_terms,
            );
            all_effects.push((w.kind, w.axis, cands[i].clone(), a));
        }
        curves.push(AxisCurves {
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
        axes.push(AxisReport {
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
            typical,
            model_misfit,
            effects: refs.iter().map(|c| c.kind.to_string()).collect(),
        });
    }

    Ok(Report {
        gap_before: rms(gaps.fit_before.into_iter()),
        gap_after: rms(gaps.fit_after.into_iter()),
        heldout: HeldOut {
            gap_before: rms(gaps.held_before.into_iter()),
            gap_after: rms(gaps.held_after.into_iter()),
            rms_before: rms(gaps.raw_before.into_iter()),
            rms_after: rms(gaps.raw_after.into_iter()),
        },
        effects: merge_effects(all_effects),
        axes,
        samples: n,
        tau0_s: tau0,
        weights: opts.weights,
        temperature: temp.is_some(),
        min_blocks: opts.min_blocks,
        p_false: opts.p_false,
        curves,
    })
}

/// Region, τ range, τ of max and max share of an effect (see [`acts`]).
type Acts = (String, [f64; 2], f64, f64);

/// Points of all axes for the report-wide gaps.
#[derive(Default)]
struct Gaps {
    fit_before: Vec<f64>,
    fit_after: Vec<f64>,
    held_before: Vec<f64>,
    held_after: Vec<f64>,
    raw_before: Vec<f64>,
    raw_after: Vec<f64>,
}

impl Gaps {
    fn add(
        &mut self,
        fb: &[PointGap],
        fa: &[PointGap],
        hb: &[PointGap],
        ha: &[PointGap],
        z: f64,
        significant: [bool; 2],
    ) {
        let ex = |p: &PointGap, on: bool| if on { excess(p, z) } else { 0.0 };
        self.fit_before
            .extend(fb.iter().map(|p| ex(p, significant[0])));
        self.fit_after
            .extend(fa.iter().map(|p| ex(p, significant[1])));
        self.held_before
            .extend(hb.iter().map(|p| ex(p, significant[0])));
        self.held_after
            .extend(ha.iter().map(|p| ex(p, significant[1])));
        self.raw_before.extend(hb.iter().map(|p| p.g));
        self.raw_after.extend(ha.iter().map(|p| p.g));
    }
}

/// The candidates of one axis, all fitted on the first half.
#[allow(clippy::too_many_arguments)] // the first half's data, statistics and model, each used; no natural bundle
fn candidates(
    an: &mut Analyzer,
    w: &AxisWork,
    first: &[&[f64]],
    hf: &Half,
    tau0: f64,
    temp: Option<&[f64]>,
    typ: &Terms,
    opts: &Options,
) -> Vec<Candidate> {
    let ns = first.len();
    let mut cands = Vec::new();
    // Heterogeneity: each sensor's level relative to the typical one (median over τ of the deviation ratio).
    let ratio: Vec<f64> = (0..ns)
        .map(|i| {
            let l: Vec<f64> = (0..hf.len())
                .map(|k| 0.5 * (hf.singles[i][k] / hf.typical[k]).ln())
                .collect();
            median(&l).exp()
        })
        .collect();
    if ratio.iter().all(|r| r.is_finite() && *r > 0.0) {
        let outliers: Vec<usize> = (0..ns).filter(|&i| ratio[i] >= 2.0).collect();
        let rest: Vec<f64> = (0..ns)
            .filter(|i| !outliers.contains(i))
            .map(|i| ratio[i].ln())
            .collect();
        let rest_mean = rest.iter().sum::<f64>() / rest.len().max(1) as f64;
        let ln_spread = (rest.iter().map(|x| (x - rest_mean).powi(2)).sum::<f64>()
            / (rest.len().max(2) - 1) as f64)
            .sqrt();
        // A few sensors (at most one in sixteen) far above an otherwise homogeneous rest — by a factor 2 and by four
        // times the rest's log-spread — are outliers; a broad spread of levels is unequal noise.
        let few = !outliers.is_empty()
            && outliers.len() <= (ns / 16).max(1)
            && ln_spread < UNEQUAL_LN_SPREAD
            && outliers.iter().all(|&i| {
                ratio[i].ln() - rest_mean > (4.0 * ln_spread).max(std::f64::consts::LN_2)
            });
        let (kind, groups) = if few {
            (
                "outlier_sensor",
                outliers.iter().map(|&i| w.groups[i]).collect(),
            )
        } else {
            ("unequal_noise", w.groups.clone())
        };
        cands.push(Candidate {
            kind,
            level: Some(ratio.iter().map(|r| r * r).collect()),
            cross: Vec::new(),
            groups: Groups::List(groups),
            params: serde_json::json!({
                "deviation_ratio_to_typical": (0..ns).map(|i| (w.groups[i].to_string(), ratio[i])).collect::<BTreeMap<_, _>>(),
                "ln_spread": ln_spread,
            }),
        });
    }

    // Blocks: clusters of the Allan correlation matrix that are not the whole cluster.
    // With equal weights a set of blocks and one cluster-wide process of the same total cross covariance predict
    // the same cluster variance, so the held-out gap cannot tell them apart: the structure decides which is offered.
    // Two bands: every level weighted by its differences (the white region dominates), then, if no sensors
    // cluster there, the flicker and random-walk levels weighted equally (a block sharing only a slow process).
    let cl: Vec<Vec<usize>> = if ns >= 4 {
        let ac = AllanCov::compute(first, tau0, 30);
        let all: Vec<(usize, f64)> = (0..ac.tau_s.len())
            .filter(|&l| ac.terms[l] >= 30)
            .map(|l| (l, ac.terms[l] as f64))
            .collect();
        let slow: Vec<(usize, f64)> = all
            .iter()
            .filter(|&&(l, _)| matches!(region_name(typ, ac.tau_s[l]), "flicker" | "random_walk"))
            .map(|&(l, _)| (l, 1.0))
            .collect();
        let found = |levels: &[(usize, f64)]| -> Vec<Vec<usize>> {
            blocks(&ac, levels, opts.merge_z)
                .into_iter()
                .filter(|c| c.len() >= 2)
                .collect()
        };
        let fast = found(&all);
        if fast.is_empty() && !slow.is_empty() {
            found(&slow)
        } else {
            fast
        }
    } else {
        Vec::new()
    };
    let partial = !cl.is_empty() && cl.iter().all(|c| c.len() <= ns - 2);
    {
        if partial {
            let mut cross = Vec::new();
            let mut per_block = Vec::new();
            for c in &cl {
                if let Some((rows, e)) = shared_fit(an, first, hf, c, tau0)
                    && let Some(s) = fit_subset(&rows, &[0, 1, 2, 3, 4])
                {
                    cross.push(Cross::Shared {
                        members: c.clone(),
                        share: Share {
                            part: s,
                            independent: e,
                        },
                    });
                    per_block.push(serde_json::json!({
                        "groups": c.iter().map(|&i| w.groups[i]).collect::<Vec<_>>(),
                        "shared": s.physical(),
                    }));
                }
            }
            if cross.len() == cl.len() {
                cands.push(Candidate {
                    kind: "block_common_mode",
                    level: None,
                    cross,
                    groups: Groups::Blocks(
                        cl.iter()
                            .map(|c| c.iter().map(|&i| w.groups[i]).collect())
                            .collect(),
                    ),
                    params: serde_json::json!({ "blocks": per_block }),
                });
            }
        }
    }

    // A process shared by all sensors, fitted in each shape on its own so that the held-out check, not the first
    // half's noise, decides between them: fast (quantisation + white), flicker, or both (`common_mode`), and slow
    // (random walk + ramp, `common_mode_drift`). (A flicker + slow shape, tried, took shared flicker for a drift.)
    let all: Vec<usize> = (0..ns).collect();
    if let Some((rows, e)) = shared_fit(an, first, hf, &all, tau0) {
        let subsets: [&[usize]; 4] = [&[0, 1], &[2], &[0, 1, 2], &[3, 4]];
        for subset in subsets {
            let Some(part) = fit_subset(&rows, subset) else {
                continue;
            };
            let slow = subset.contains(&3);
            if partial && !slow {
                continue;
            }
            let white = |t: &Terms| t.0[0] / tau0 + t.0[1];
            let tot = Terms(std::array::from_fn(|k| part.0[k] + e.0[k]));
            let rho_white = if white(&tot) > 0.0 {
                white(&part) / white(&tot)
            } else {
                0.0
            };
            let rho_flicker = if tot.0[2] > 0.0 {
                part.0[2] / tot.0[2]
            } else {
                0.0
            };
            let mut params = serde_json::json!({
                "rho_white": rho_white,
                "rho_flicker": rho_flicker,
                "shared_random_walk": (3.0 * part.0[3]).sqrt(),
                "shared_ramp": (2.0 * part.0[4]).sqrt(),
                "shared": part.physical(),
            });
            if slow
                && temp.is_none()
                && let Some(o) = params.as_object_mut()
            {
                o.insert(
                    "temperature".into(),
                    "not recorded: a thermal cause cannot be separated from other shared drifts"
                        .into(),
                );
            }
            cands.push(Candidate {
                kind: if slow {
                    "common_mode_drift"
                } else {
                    "common_mode"
                },
                level: None,
                cross: vec![Cross::Shared {
                    members: all.clone(),
                    share: Share {
                        part,
                        independent: e,
                    },
                }],
                groups: Groups::List(w.groups.clone()),
                params,
            });
        }
    }

    if let Some(t) = temp {
        let block = ((10.0 / tau0).round() as usize).max(1);
        let beta = thermal_betas(first, t, block);
        let unit = if w.kind == SensorKind::Gyro {
            "deg/s/degC"
        } else {
            "g/degC"
        };
        let mean = beta.iter().sum::<f64>() / beta.len().max(1) as f64;
        cands.push(Candidate {
            kind: "thermal",
            level: None,
            cross: vec![Cross::Thermal { beta: beta.clone() }],
            groups: Groups::List(w.groups.clone()),
            params: serde_json::json!({
                "beta": (0..ns).map(|i| (w.groups[i].to_string(), beta[i])).collect::<BTreeMap<_, _>>(),
                "shared_beta": mean,
                "unit": unit,
            }),
        });
    }
    cands
}

/// The per-τ table of the held-out half and the test for independence.
fn tau_rows(
    h: &Half,
    w: &[f64],
    p0: &Model,
    model: &Model,
    before: &[PointGap],
    after: &[PointGap],
) -> (Vec<TauRow>, Independence) {
    let sw2: f64 = w.iter().map(|x| x * x).sum();
    let sw4: f64 = w.iter().map(|x| x.powi(4)).sum();
    let pair_w = w.iter().sum::<f64>().powi(2) - sw2;
    let mut rows = Vec::new();
    for k in 0..h.len() {
        let (t, v, th) = (h.tau_s[k], h.typical[k], h.temp[k]);
        let indep: f64 = h.singles.iter().zip(w).map(|(s, wi)| wi * wi * s[k]).sum();
        let ratio = h.cluster[k] / indep.max(1e-300);
        // Σ w_i² σ̂_i² has relative variance ≈ (2/ν_s)·Σw⁴/(Σw²)².
        let s_m = (2.0 / h.edf[k]).sqrt();
        let s_i = (2.0 / h.single_edf[k] * sw4).sqrt() / sw2.max(1e-300);
        let cross_z = chi2_z(ratio, h.edf[k]) * s_m / (s_m * s_m + s_i * s_i).sqrt();
        let dev = h.cluster[k].sqrt();
        let (dev_lo, dev_hi) =
            crate::allan::confidence_interval(dev, h.edf[k], crate::allan::ONE_SIGMA_CI)
                .unwrap_or((dev, dev));
        let (b, a) = (before[k], after[k]);
        rows.push(TauRow {
            tau_s: t,
            blocks: h.n / h.m[k].max(1),
            alpha: h.alpha[k],
            edf: h.edf[k],
            dev,
            dev_lo,
            dev_hi,
            predicted_before: p0.avar(w, t, v, th).max(0.0).sqrt(),
            predicted_after: model.avar(w, t, v, th).max(0.0).sqrt(),
            prediction_sigma_ln: 0.5 * h.typical_sigma[k],
            gap_before: b.g,
            gap_after: a.g,
            sigma_ln: b.sigma,
            z_before: b.z,
            z_after: a.z,
            cross_correlation: if pair_w > 0.0 && v > 0.0 {
                (h.cluster[k] - indep) / pair_w / v
            } else {
                0.0
            },
            cross_z,
        });
    }
    let chi2: f64 = rows.iter().map(|r| r.cross_z * r.cross_z).sum();
    let p_value = ChiSquared::new(rows.len().max(1) as f64)
        .map(|c| 1.0 - c.cdf(chi2))
        .unwrap_or(1.0);
    (
        rows,
        Independence {
            chi2,
            points: h.len(),
            p_value,
        },
    )
}

/// The τ regions of an axis from the typical model, with the held-out gap in each.
fn regions(typ: &Terms, h: &Half, before: &[PointGap], after: &[PointGap], z: f64) -> Vec<Region> {
    let mut out: Vec<Region> = Vec::new();
    for k in 0..h.len() {
        let r = region_name(typ, h.tau_s[k]);
        if out.last().is_none_or(|l| l.region != r) {
            out.push(Region {
                region: r.into(),
                tau_s: [h.tau_s[k]; 2],
                gap_before: 0.0,
                gap_after: 0.0,
                significant_before: 0,
                significant_after: 0,
                points: 0,
            });
        }
        if let Some(l) = out.last_mut() {
            l.tau_s[1] = h.tau_s[k];
            l.points += 1;
            l.gap_before += before[k].g;
            l.gap_after += after[k].g;
            l.significant_before += usize::from(before[k].z.abs() > z);
            l.significant_after += usize::from(after[k].z.abs() > z);
        }
    }
    for l in &mut out {
        l.gap_before /= l.points as f64;
        l.gap_after /= l.points as f64;
    }
    out
}

/// RMS-noise and bias-stability gains of the whole record, with 68 % intervals (`singles`: the sensors' octave
/// OADEV of the whole record, as measured for the significance test).
fn gains(
    an: &mut Analyzer,
    series: &[&[f64]],
    singles: &[Vec<AnalysisPoint>],
    w: &[f64],
    tau0: f64,
) -> (Gain, Gain) {
    let std = |x: &[f64]| {
        let m = x.iter().sum::<f64>() / x.len().max(1) as f64;
        (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len().max(2) - 1) as f64).sqrt()
    };
    let mean = weighted_mean(series, w);
    let single_rms =
        (series.iter().map(|s| std(s).powi(2)).sum::<f64>() / series.len().max(1) as f64).sqrt();
    let cluster = octave(an, &mean, tau0);
    let rms_value = single_rms / std(&mean);
    // The standard deviation of n samples of (nearly) white noise has relative uncertainty 1/√(2(n−1)).
    let u = 1.0 / (2.0 * (mean.len().max(2) - 1) as f64).sqrt();
    let rms_gain = Gain {
        value: rms_value,
        ci_lo: rms_value * (-u).exp(),
        ci_hi: rms_value * u.exp(),
    };
    let min = |p: &[AnalysisPoint]| {
        p.iter()
            .filter(|q| q.dev.is_finite())
            .min_by(|a, b| a.dev.total_cmp(&b.dev))
            .cloned()
    };
    let singles: Vec<AnalysisPoint> = singles.iter().filter_map(|p| min(p)).collect();
    let single_min = median(&singles.iter().map(|p| p.dev).collect::<Vec<_>>());
    let Some(c) = min(&cluster) else {
        return (rms_gain, Gain::default());
    };
    let value = single_min / c.dev;
    let half = |p: &AnalysisPoint| {
        p.dev_lo
            .zip(p.dev_hi)
            .map_or(0.0, |(lo, hi)| 0.5 * (hi / lo).ln())
    };
    let s_single = {
        let m = singles.iter().min_by(|a, b| {
            (a.dev - single_min)
                .abs()
                .total_cmp(&(b.dev - single_min).abs())
        });
        m.map_or(0.0, half) / (singles.len().max(1) as f64).sqrt()
    };
    let s = (half(&c).powi(2) + s_single.powi(2)).sqrt();
    (
        rms_gain,
        Gain {
            value,
            ci_lo: value * (-s).exp(),
            ci_hi: value * s.exp(),
        },
    )
}

/// One entry per (effect kind, sensor, groups), with the axes it was found on; region and share from the axis
/// where it is largest.
fn merge_effects(found: Vec<(SensorKind, usize, Candidate, Acts)>) -> Vec<Effect> {
    let mut out: Vec<Effect> = Vec::new();
    for (kind, axis, c, (region, tau, tau_max, share)) in found {
        let ax = AXIS_NAMES.get(axis).copied().unwrap_or('?').to_string();
        let mut params = c.params.clone();
        if let Some(o) = params.as_object_mut() {
            o.insert(
                "acts".into(),
                serde_json::json!({"region": region, "tau_s": tau, "tau_at_max_s": tau_max, "share_of_cluster_avar": share}),
            );
        }
        let per_group = c.kind == "outlier_sensor" || c.kind == "block_common_mode";
        let same = out.iter_mut().find(|e| {
            e.kind == c.kind && e.sensor == kind.name() && (!per_group || e.groups == c.groups)
        });
        match same {
            Some(e) => {
                e.axes.push_str(&ax);
                e.params.insert(ax, params);
                if share > e.share {
                    (e.region, e.tau_s, e.tau_at_max_s, e.share) = (region, tau, tau_max, share);
                }
            }
            None => {
                let mut p = BTreeMap::new();
                p.insert(ax.clone(), params);
                out.push(Effect {
                    kind: c.kind.into(),
                    sensor: kind.name().into(),
                    axes: ax,
                    groups: c.groups,
                    region,
                    tau_s: tau,
                    tau_at_max_s: tau_max,
                    share,
                    params: p,
                });
            }
        }
    }
    for e in &mut out {
        let mut a: Vec<char> = e.axes.chars().collect();
        a.sort_unstable();
        a.dedup();
        e.axes = a.into_iter().collect();
        if let Groups::List(g) = &mut e.groups {
            g.sort_unstable();
        }
    }
    out
}

#[cfg(test)]
mod tests;
