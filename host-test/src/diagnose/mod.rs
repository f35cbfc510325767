//! `ground diagnose`: where the sim-to-real gap of a cluster lies, which unmodelled effect causes it, and how far
//! it shrinks once the effect is modelled — checked on held-out data (spec: `docs/diagnose.md`).
//!
//! Per axis (gyro x y z, accel x y z), on the first half of the record:
//! 1. every sensor's octave OADEV is measured and fitted with the four-term noise model (`noisefit`, reported with
//!    its misfit);
//! 2. predictions of the cluster mean's Allan variance, all exact for the weights used (`Model`), built from the
//!    sensors' **measured** first-half Allan variances at the same τ (not from the fitted models: where the
//!    four-term model misfits — the MIMU4444's MPU9150 gyros by up to 38 % in deviation, from their on-chip
//!    low-pass filter — a model-based prediction would report the misfit as a cluster gap):
//!    **P0** — N independent copies of the typical sensor (per τ, the median over the sensors): the seed paper's
//!    √N expectation made concrete; then candidate effects are added to it;
//! 3. candidates, each fitted on the first half: `unequal_noise` / `outlier_sensor` (every sensor its own measured
//!    curve), `common_mode` (a process shared by all sensors: white, flicker, quantisation terms of the mean
//!    off-diagonal Allan covariance), `common_mode_drift` (its random-walk term), `block_common_mode` (shared within
//!    a subset found from the leading eigenvector of the correlation matrix), `thermal` (bias ∝ temperature, one
//!    coefficient per sensor, when `temp_c` exists);
//! 4. candidates are added greedily by how much they shrink the gap **on the second half** (never by the fit on the
//!    first), while the remaining gap is significant — `Σ (gap/σ)²` over the axis's points exceeds the chi-squared
//!    quantile at `p_false` (one strong point counts as much as many weak ones: thermal and drift effects show only
//!    at the longest τ) — and the step shrinks it by at least `min_shrink`.
//!
//! The gap at one τ = m·τ₀ is `ln(measured / predicted)` of the deviation; it counts where the half holds at least
//! `min_blocks` independent averaging blocks (N/m). Its uncertainty is `√(σ²_meas + σ²_model)`: σ_meas =
//! 1/√(2·edf) with the conservative edf = 0.75·N/m (below the OADEV edf of every power-law noise type at these m;
//! per-point noise identification on few blocks can pick a type with a much larger edf by chance, which made chance
//! scatter look significant), σ_model = `model_tolerance`, the fit error allowed to a noise model. A point is
//! significant beyond `z` uncertainties. `gap` is the RMS over axes and points.

pub mod acov;
pub mod model;
pub mod report;

use crate::allan::{AnalysisPoint, Analyzer, DevKind, Options as AllanOptions, TauSpec};
use crate::formats::csv::{AXIS_NAMES, Recording, SensorKind};
use crate::noisefit::{self, NoiseFit};
use acov::AllanCov;
use model::{Cross, Model, Single};
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
    /// Points with fewer independent averaging blocks (N/m) are not counted in the gap.
    pub min_blocks: usize,
    /// Significance threshold in standard deviations.
    pub z: f64,
    /// Relative error allowed to a fitted noise model (deviation), added in quadrature to the CI.
    pub model_tolerance: f64,
    /// Smallest relative shrink of the held-out gap for an effect to be accepted.
    pub min_shrink: f64,
    /// False-alarm probability of the test "the remaining gap of an axis is significant".
    pub p_false: f64,
}

impl Default for Options {
    fn default() -> Self {
        Self {
            weights: WeightRule::Equal,
            min_blocks: 256,
            z: 2.0,
            model_tolerance: 0.03,
            min_shrink: 0.2,
            p_false: 1e-3,
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
    /// 68 % bounds.
    pub lo: Vec<f64>,
    /// 68 % bounds.
    pub hi: Vec<f64>,
    /// Greenhall equivalent degrees of freedom (for the plotted intervals).
    pub edf: Vec<f64>,
    /// Uncertainty of ln(deviation) used for the gap (conservative, see module docs).
    pub sigma_ln: Vec<f64>,
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
    /// Groups concerned (0-based group numbers; all for cluster-wide effects).
    pub groups: Vec<usize>,
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
    /// RMS of ln(measured/predicted) on the held-out half, before and after.
    pub heldout_gap: [f64; 2],
    /// RMS gap on the first half, before and after.
    pub gap: [f64; 2],
    /// The gap per τ region.
    pub regions: Vec<Region>,
    /// Typical single-sensor noise model (fitted to the per-τ median of the sensors' curves).
    pub typical: NoiseFit,
    /// RMS over sensors and τ of ln(measured / fitted) single-sensor deviation: how well the four-term model
    /// describes these sensors (not used by the predictions).
    pub model_misfit: f64,
    /// Effects kept for this axis.
    pub effects: Vec<String>,
}

/// Gaps summary.
#[derive(Clone, Copy, Debug, Default, Serialize)]
pub struct HeldOut {
    /// Before (P0).
    pub gap_before: f64,
    /// After (final model).
    pub gap_after: f64,
}

/// The diagnosis.
#[derive(Clone, Debug, Serialize)]
pub struct Report {
    /// Gap of P0 on the first half.
    pub gap_before: f64,
    /// Gap of the final model on the first half.
    pub gap_after: f64,
    /// The same on the held-out half.
    pub heldout: HeldOut,
    /// Identified effects (empty list: none).
    pub effects: Vec<Effect>,
    /// Per axis.
    pub axes: Vec<AxisReport>,
    /// Samples, and sample interval s.
    pub samples: usize,
    /// Sample interval, s.
    pub tau0_s: f64,
    /// Weights of the cluster mean.
    pub weights: WeightRule,
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

/// Shortest record accepted (each half must hold a few octaves of averaging blocks).
pub const MIN_SAMPLES: usize = 1000;

/// Median of a slice (NaN if empty).
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
    (0..len)
        .map(|k| series.iter().zip(w).map(|(s, wi)| wi * s[k]).sum())
        .collect()
}

fn measure(
    an: &mut Analyzer,
    series: &[&[f64]],
    w: &[f64],
    tau0: f64,
    min_blocks: usize,
) -> Measured {
    let mean = weighted_mean(series, w);
    let mut m = Measured::default();
    for p in octave(an, &mean, tau0) {
        let blocks = mean.len() / p.m.max(1);
        if let (Some(lo), Some(hi)) = (p.dev_lo, p.dev_hi)
            && blocks >= min_blocks
            && p.dev > 0.0
        {
            m.tau_s.push(p.tau_s);
            m.dev.push(p.dev);
            m.lo.push(lo);
            m.hi.push(hi);
            m.edf.push(p.edf.unwrap_or(f64::NAN));
            m.sigma_ln.push(1.0 / (2.0 * 0.75 * blocks as f64).sqrt());
        }
    }
    m
}

/// Per point: (ln ratio, its uncertainty).
fn gap_points(
    m: &Measured,
    model: &Model,
    w: &[f64],
    temp: &dyn Fn(f64) -> Option<f64>,
    tol: f64,
) -> Vec<(f64, f64)> {
    (0..m.tau_s.len())
        .map(|k| {
            let pred = model
                .avar(w, m.tau_s[k], temp(m.tau_s[k]))
                .max(1e-300)
                .sqrt();
            let s_meas = m.sigma_ln[k];
            ((m.dev[k] / pred).ln(), (s_meas * s_meas + tol * tol).sqrt())
        })
        .collect()
}

fn rms(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x * x, n + 1));
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

/// Temperature Allan variance at octave τ of one half (for thermal terms).
fn temp_avar_fn(an: &mut Analyzer, temp: Option<&[f64]>, tau0: f64) -> Vec<(f64, f64)> {
    temp.map(|t| {
        octave(an, t, tau0)
            .iter()
            .map(|p| (p.tau_s, p.dev * p.dev))
            .collect()
    })
    .unwrap_or_default()
}

fn lookup(table: &[(f64, f64)], tau: f64) -> Option<f64> {
    table
        .iter()
        .find(|(t, _)| (t / tau - 1.0).abs() < 1e-9)
        .map(|(_, v)| *v)
}

/// A candidate effect of one axis.
#[derive(Clone, Debug)]
struct Candidate {
    kind: &'static str,
    /// Replaces the single-sensor models (heterogeneity) …
    singles: Option<Vec<Single>>,
    /// … or adds a cross term.
    cross: Option<Cross>,
    groups: Vec<usize>,
    params: serde_json::Value,
}

struct AxisWork<'a> {
    kind: SensorKind,
    axis: usize,
    groups: Vec<usize>,
    series: Vec<&'a [f64]>,
}

/// Leading eigenvector of a symmetric matrix (power iteration on M + I to keep it positive).
fn leading_eigenvector(m: &[f64], n: usize) -> Vec<f64> {
    let mut v = vec![1.0 / (n as f64).sqrt(); n];
    for _ in 0..200 {
        let mut u: Vec<f64> = (0..n)
            .map(|i| (0..n).map(|j| m[i * n + j] * v[j]).sum::<f64>() + v[i])
            .collect();
        let norm = u.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm == 0.0 {
            break;
        }
        u.iter_mut().for_each(|x| *x /= norm);
        v = u;
    }
    let max = v.iter().copied().fold(f64::MIN, f64::max);
    let min = v.iter().copied().fold(f64::MAX, f64::min);
    if -min > max {
        v.iter_mut().for_each(|x| *x = -*x);
    }
    v
}

/// Fits a shared process to the mean cross covariance of `members` over the levels of `ac`.
fn shared_fit(ac: &AllanCov, members: &[usize]) -> Option<NoiseFit> {
    let pts: Vec<AnalysisPoint> = (0..ac.tau_s.len())
        .filter_map(|l| {
            let c = ac.mean_cross(l, members);
            (c > 0.0 && ac.terms[l] >= 30).then(|| AnalysisPoint {
                m: 1 << l,
                tau_s: ac.tau_s[l],
                n: ac.terms[l],
                dev: c.sqrt(),
                noise: None,
                edf: Some(ac.terms[l] as f64),
                dev_lo: None,
                dev_hi: None,
            })
        })
        .collect();
    (pts.len() >= 3).then(|| noisefit::fit(&pts))
}

/// Thermal coefficients: per sensor, least squares of block means of the data on block means of temperature.
fn thermal_betas(series: &[&[f64]], temp: &[f64], block: usize) -> Vec<f64> {
    let blocks = temp.len() / block.max(1);
    let bm = |x: &[f64]| -> Vec<f64> {
        (0..blocks)
            .map(|b| x[b * block..(b + 1) * block].iter().sum::<f64>() / block as f64)
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
        .filter(|t| t.iter().all(|x| x.is_finite()));
    let mut an = Analyzer::new();
    let temp_fit = temp_avar_fn(&mut an, temp.map(|t| &t[..half]), tau0);
    let temp_held = temp_avar_fn(&mut an, temp.map(|t| &t[half..]), tau0);

    let mut axes = Vec::new();
    let mut all_effects: Vec<(SensorKind, usize, Candidate)> = Vec::new();
    let mut curves = Vec::new();
    let (mut g_before, mut g_after, mut h_before, mut h_after) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new());

    for w in &works {
        let ns = w.series.len();
        let first: Vec<&[f64]> = w.series.iter().map(|s| &s[..half]).collect();
        let second: Vec<&[f64]> = w.series.iter().map(|s| &s[half..]).collect();

        // 1. Single-sensor fits and the typical sensor.
        let singles_pts: Vec<Vec<AnalysisPoint>> =
            first.iter().map(|s| octave(&mut an, s, tau0)).collect();
        let singles: Vec<NoiseFit> = singles_pts.iter().map(|p| noisefit::fit(p)).collect();
        let typical_pts: Vec<AnalysisPoint> =
            (0..singles_pts.iter().map(Vec::len).min().unwrap_or(0))
                .map(|k| {
                    let devs: Vec<f64> = singles_pts.iter().map(|p| p[k].dev).collect();
                    AnalysisPoint {
                        dev: median(&devs),
                        ..singles_pts[0][k]
                    }
                })
                .collect();
        let typical = noisefit::fit(&typical_pts);
        let table = |p: &[AnalysisPoint]| {
            Single::Table(p.iter().map(|q| (q.tau_s, q.dev * q.dev)).collect())
        };
        let measured_singles: Vec<Single> = singles_pts.iter().map(|p| table(p)).collect();
        let typical_single = table(&typical_pts);
        let model_misfit = rms(singles_pts.iter().zip(&singles).flat_map(|(p, f)| {
            p.iter()
                .filter(|q| q.dev > 0.0)
                .map(move |q| (q.dev / f.avar(q.tau_s).max(1e-300).sqrt()).ln())
        }));

        // Weights.
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

        // 2. Measurements of both halves.
        let m_fit = measure(&mut an, &first, &wts, tau0, opts.min_blocks);
        let m_held = measure(&mut an, &second, &wts, tau0, opts.min_blocks);
        let tf = |t: f64| lookup(&temp_fit, t);
        let th = |t: f64| lookup(&temp_held, t);

        // 3. Candidates.
        let ac = AllanCov::compute(&first, tau0, 30);
        let mut cands: Vec<Candidate> = Vec::new();
        {
            // Heterogeneity: each sensor its own model. Outliers: white (or flicker) level ≥ 2× the typical.
            let ratio: Vec<f64> = singles_pts
                .iter()
                .map(|p| {
                    median(
                        &p.iter()
                            .zip(&typical_pts)
                            .map(|(a, b)| (a.dev / b.dev).ln())
                            .collect::<Vec<_>>(),
                    )
                    .exp()
                })
                .collect();
            let outliers: Vec<usize> = (0..ns).filter(|&i| ratio[i] >= 2.0).collect();
            let ln_spread = {
                let l: Vec<f64> = (0..ns)
                    .filter(|i| !outliers.contains(i))
                    .map(|i| ratio[i].ln())
                    .collect();
                let m = l.iter().sum::<f64>() / l.len().max(1) as f64;
                (l.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (l.len().max(2) - 1) as f64)
                    .sqrt()
            };
            // A few sensors (at most one in eight) far above an otherwise homogeneous rest are outliers; a broad
            // spread of levels is unequal noise.
            let few = !outliers.is_empty()
                && outliers.len() <= (ns / 8).max(1)
                && ln_spread < UNEQUAL_LN_SPREAD;
            let (kind, groups) = if few {
                (
                    "outlier_sensor",
                    outliers.iter().map(|&i| w.groups[i]).collect(),
                )
            } else {
                ("unequal_noise", w.groups.clone())
            };
            let params = serde_json::json!({
                "deviation_ratio_to_typical": (0..ns).map(|i| (w.groups[i].to_string(), ratio[i])).collect::<BTreeMap<_, _>>(),
                "ln_spread": ln_spread,
            });
            cands.push(Candidate {
                kind,
                singles: Some(measured_singles.clone()),
                cross: None,
                groups,
                params,
            });
        }
        let all: Vec<usize> = (0..ns).collect();
        if let Some(fit) = shared_fit(&ac, &all) {
            let typical_white = typical.white.powi(2) + 3.0 * typical.quantization.powi(2) / tau0;
            let fast = NoiseFit {
                random_walk: 0.0,
                ..fit
            };
            if fast.white > 0.0 || fast.bias_instability > 0.0 || fast.quantization > 0.0 {
                let rho_white = if typical_white > 0.0 {
                    (fast.white.powi(2) + 3.0 * fast.quantization.powi(2) / tau0) / typical_white
                } else {
                    0.0
                };
                let rho_flicker = if typical.bias_instability > 0.0 {
                    (fast.bias_instability / typical.bias_instability).powi(2)
                } else {
                    0.0
                };
                cands.push(Candidate {
                    kind: "common_mode",
                    singles: None,
                    cross: Some(Cross::Shared { members: all.clone(), fit: fast }),
                    groups: w.groups.clone(),
                    params: serde_json::json!({"rho_white": rho_white, "rho_flicker": rho_flicker, "shared": fast}),
                });
            }
            if fit.random_walk > 0.0 {
                let drift = NoiseFit {
                    random_walk: fit.random_walk,
                    ..NoiseFit::default()
                };
                cands.push(Candidate {
                    kind: "common_mode_drift",
                    singles: None,
                    cross: Some(Cross::Shared {
                        members: all.clone(),
                        fit: drift,
                    }),
                    groups: w.groups.clone(),
                    params: serde_json::json!({"shared_random_walk": fit.random_walk}),
                });
            }
        }
        {
            // Block: the correlation structure at levels with many terms.
            let levels: Vec<usize> = (0..ac.tau_s.len())
                .filter(|&l| ac.terms[l] >= 200)
                .collect();
            if !levels.is_empty() && ns >= 4 {
                let mut r = vec![0.0; ns * ns];
                for &l in &levels {
                    for (x, c) in r.iter_mut().zip(ac.correlation(l)) {
                        *x += c / levels.len() as f64;
                    }
                }
                for i in 0..ns {
                    r[i * ns + i] = 0.0;
                }
                let v = leading_eigenvector(&r, ns);
                let vmax = v.iter().copied().fold(f64::MIN, f64::max);
                let members: Vec<usize> = (0..ns).filter(|&i| v[i] > 0.5 * vmax).collect();
                if members.len() >= 2 && members.len() <= ns - 2 {
                    let inside = {
                        let (mut s, mut k) = (0.0, 0);
                        for (a, &i) in members.iter().enumerate() {
                            for &j in &members[a + 1..] {
                                s += r[i * ns + j];
                                k += 1;
                            }
                        }
                        s / k.max(1) as f64
                    };
                    if let Some(fit) = shared_fit(&ac, &members) {
                        cands.push(Candidate {
                            kind: "block_common_mode",
                            singles: None,
                            cross: Some(Cross::Shared {
                                members: members.clone(),
                                fit,
                            }),
                            groups: members.iter().map(|&i| w.groups[i]).collect(),
                            params: serde_json::json!({"rho_within": inside, "shared": fit}),
                        });
                    }
                }
            }
        }
        if let Some(t) = temp {
            let block = ((10.0 / tau0).round() as usize).max(1);
            let beta = thermal_betas(&first, &t[..half], block);
            let unit = if w.kind == SensorKind::Gyro {
                "deg/s/degC"
            } else {
                "g/degC"
            };
            cands.push(Candidate {
                kind: "thermal",
                singles: None,
                cross: Some(Cross::Thermal { beta: beta.clone() }),
                groups: w.groups.clone(),
                params: serde_json::json!({"beta": (0..ns).map(|i| (w.groups[i].to_string(), beta[i])).collect::<BTreeMap<_, _>>(), "unit": unit}),
            });
        }

        // 4. Greedy selection on the held-out half.
        let p0 = Model {
            singles: vec![typical_single.clone(); ns],
            cross: vec![],
        };
        let score = |m: &Model, meas: &Measured, t: &dyn Fn(f64) -> Option<f64>| {
            gap_points(meas, m, &wts, t, opts.model_tolerance)
        };
        let mut model = p0.clone();
        let mut chosen: Vec<Candidate> = Vec::new();
        loop {
            let pts = score(&model, &m_held, &th);
            let current = rms(pts.iter().map(|p| p.0));
            if !significant_gap(&pts, opts.p_false) {
                break;
            }
            let mut best: Option<(f64, usize, Model)> = None;
            for (i, c) in cands.iter().enumerate() {
                let mut m = model.clone();
                if let Some(s) = &c.singles {
                    m.singles = s.clone();
                }
                if let Some(x) = &c.cross {
                    m.cross.push(x.clone());
                }
                let g = rms(score(&m, &m_held, &th).iter().map(|p| p.0));
                if best.as_ref().is_none_or(|(b, _, _)| g < *b) {
                    best = Some((g, i, m));
                }
            }
            match best {
                Some((g, i, m)) if g <= current * (1.0 - opts.min_shrink) => {
                    model = m;
                    chosen.push(cands.remove(i));
                }
                _ => break,
            }
        }

        // Gaps, regions, gains.
        let before_fit = score(&p0, &m_fit, &tf);
        let after_fit = score(&model, &m_fit, &tf);
        let before_held = score(&p0, &m_held, &th);
        let after_held = score(&model, &m_held, &th);
        g_before.extend(before_fit.iter().map(|p| p.0));
        g_after.extend(after_fit.iter().map(|p| p.0));
        h_before.extend(before_held.iter().map(|p| p.0));
        h_after.extend(after_held.iter().map(|p| p.0));
        let label = axis_label(w.kind, w.axis);
        let regions = regions(&typical, &m_held, &before_held, &after_held, opts.z);
        let (rms_gain, bias_stability_gain) = gains(&mut an, &w.series, &wts, tau0);
        let white_tau = m_held.tau_s.first().copied().unwrap_or(tau0);
        let iv: Vec<f64> = {
            let inv: Vec<f64> = model
                .singles
                .iter()
                .map(|s| 1.0 / s.avar(white_tau).max(1e-300))
                .collect();
            let sum: f64 = inv.iter().sum();
            inv.iter().map(|v| v / sum).collect()
        };
        let eq = vec![1.0 / ns as f64; ns];
        let weighting_recovers = (model.avar(&eq, white_tau, th(white_tau))
            / model.avar(&iv, white_tau, th(white_tau)))
        .sqrt();
        curves.push(AxisCurves {
            axis: label.clone(),
            before: m_held
                .tau_s
                .iter()
                .map(|&t| p0.avar(&wts, t, th(t)).sqrt())
                .collect(),
            after: m_held
                .tau_s
                .iter()
                .map(|&t| model.avar(&wts, t, th(t)).sqrt())
                .collect(),
            measured: m_held.clone(),
        });
        axes.push(AxisReport {
            axis: label,
            sensors: ns,
            expected_gain: (ns as f64).sqrt(),
            rms_gain,
            bias_stability_gain,
            weighting_recovers,
            heldout_gap: [
                rms(before_held.iter().map(|p| p.0)),
                rms(after_held.iter().map(|p| p.0)),
            ],
            gap: [
                rms(before_fit.iter().map(|p| p.0)),
                rms(after_fit.iter().map(|p| p.0)),
            ],
            regions,
            typical,
            model_misfit,
            effects: chosen.iter().map(|c| c.kind.to_string()).collect(),
        });
        all_effects.extend(chosen.into_iter().map(|c| (w.kind, w.axis, c)));
    }

    Ok(Report {
        gap_before: rms(g_before.into_iter()),
        gap_after: rms(g_after.into_iter()),
        heldout: HeldOut {
            gap_before: rms(h_before.into_iter()),
            gap_after: rms(h_after.into_iter()),
        },
        effects: merge_effects(all_effects),
        axes,
        samples: n,
        tau0_s: tau0,
        weights: opts.weights,
        curves,
    })
}

/// Whether the gap points reject "model right" at false-alarm probability `p`: `Σ (g/σ)² > χ²_{1−p}(n)`.
pub fn significant_gap(points: &[(f64, f64)], p: f64) -> bool {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    let n = points.len();
    if n == 0 {
        return false;
    }
    let stat: f64 = points.iter().map(|(g, s)| (g / s).powi(2)).sum();
    ChiSquared::new(n as f64)
        .map(|c| stat > c.inverse_cdf(1.0 - p))
        .unwrap_or(false)
}

/// The τ regions of an axis from the typical model, with the held-out gap in each.
fn regions(
    typical: &NoiseFit,
    m: &Measured,
    before: &[(f64, f64)],
    after: &[(f64, f64)],
    z: f64,
) -> Vec<Region> {
    let name = |tau: f64| {
        let terms = [
            (
                "quantization",
                3.0 * typical.quantization.powi(2) / (tau * tau),
            ),
            ("white", typical.white.powi(2) / tau),
            (
                "flicker",
                noisefit::FLICKER_AVAR * typical.bias_instability.powi(2),
            ),
            ("random_walk", typical.random_walk.powi(2) * tau / 3.0),
        ];
        terms
            .iter()
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map_or("white", |t| t.0)
    };
    let mut out: Vec<Region> = Vec::new();
    for k in 0..m.tau_s.len() {
        let r = name(m.tau_s[k]);
        if out.last().is_none_or(|l| l.region != r) {
            out.push(Region {
                region: r.into(),
                tau_s: [m.tau_s[k]; 2],
                gap_before: 0.0,
                gap_after: 0.0,
                significant_before: 0,
                significant_after: 0,
                points: 0,
            });
        }
        if let Some(l) = out.last_mut() {
            l.tau_s[1] = m.tau_s[k];
            l.points += 1;
            l.gap_before += before[k].0;
            l.gap_after += after[k].0;
            l.significant_before += usize::from(before[k].0.abs() > z * before[k].1);
            l.significant_after += usize::from(after[k].0.abs() > z * after[k].1);
        }
    }
    for l in &mut out {
        l.gap_before /= l.points as f64;
        l.gap_after /= l.points as f64;
    }
    out
}

/// RMS-noise and bias-stability gains of the whole record, with 68 % intervals.
fn gains(an: &mut Analyzer, series: &[&[f64]], w: &[f64], tau0: f64) -> (Gain, Gain) {
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
    let singles: Vec<AnalysisPoint> = series
        .iter()
        .filter_map(|s| min(&octave(an, s, tau0)))
        .collect();
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

/// One entry per (effect kind, sensor, groups), with the axes it was found on.
fn merge_effects(found: Vec<(SensorKind, usize, Candidate)>) -> Vec<Effect> {
    let mut out: Vec<Effect> = Vec::new();
    for (kind, axis, c) in found {
        let ax = AXIS_NAMES[axis].to_string();
        let same = out.iter_mut().find(|e| {
            e.kind == c.kind
                && e.sensor == kind.name()
                && (e.groups == c.groups
                    || c.kind != "outlier_sensor" && c.kind != "block_common_mode")
        });
        match same {
            Some(e) => {
                e.axes.push_str(&ax);
                if c.kind == "block_common_mode" || c.kind == "outlier_sensor" {
                    for g in &c.groups {
                        if !e.groups.contains(g) {
                            e.groups.push(*g);
                        }
                    }
                }
                e.params.insert(ax, c.params);
            }
            None => {
                let mut params = BTreeMap::new();
                params.insert(ax.clone(), c.params);
                out.push(Effect {
                    kind: c.kind.into(),
                    sensor: kind.name().into(),
                    axes: ax,
                    groups: c.groups,
                    params,
                });
            }
        }
    }
    for e in &mut out {
        let mut a: Vec<char> = e.axes.chars().collect();
        a.sort_unstable();
        a.dedup();
        e.axes = a.into_iter().collect();
        e.groups.sort_unstable();
    }
    out
}

#[cfg(test)]
mod tests;
