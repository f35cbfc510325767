//! `sensor_drift`: one sensor that departs from the typical one only at long τ (its own random walk or ramp), found
//! per sensor and per τ — not through a median over all τ — and told apart from a shared process by its Allan
//! covariance with the other sensors, which stays null (spec: `docs/diagnose.md`).

use super::candidates::{AxisWork, Candidate, Row5, fit_subset};
use super::model::{Cross, Terms};
use super::prediction::{scan_statistic, scan_threshold};
use super::singles::{Half, octave_devs, weighted_mean};
use super::types::{Groups, Options};
use crate::allan::Analyzer;
use crate::allan::chi2_z;
use crate::stats::median;
use std::collections::BTreeMap;

/// One sensor's departure from the typical sensor at long τ, fitted on the first half.
#[derive(Clone, Debug)]
pub(super) struct Departure {
    /// Index of the sensor in its axis.
    pub(super) sensor: usize,
    /// Its level at short τ relative to the typical sensor (variance ratio).
    pub(super) level: f64,
    /// The scan statistic of its departure from both references (above its own level and above the cluster's
    /// prediction for it, the smaller z-score at each τ).
    pub(super) scan: f64,
    /// The threshold.
    pub(super) threshold: f64,
    /// First τ at which its z-score exceeds 2, s.
    pub(super) from_tau_s: f64,
    /// Allan correlation of the sensor with the mean of the others over the departing τ, and its null sd.
    pub(super) correlation: f64,
    /// Null standard deviation of that correlation.
    pub(super) correlation_sd: f64,
    /// The excess fitted with the slow terms (random walk, ramp) in Allan variance, unit².
    pub(super) part: Terms,
    /// The spread of parts in their slow terms the cluster's prediction allowed (variance of ln).
    pub(super) slow_spread: f64,
}

/// Per-τ z-scores of sensor `i`'s Allan variance against `reference[k] × typical`, with the typical sensor's own
/// scatter, the 3 % tolerance (in deviation) and `extra[k]` (a further variance of ln, e.g. the spread of parts)
/// in the denominator, as the cluster's z-scores.
fn sensor_z(hf: &Half, i: usize, reference: &[f64], extra: &[f64], tol: f64) -> Vec<f64> {
    (0..hf.len())
        .map(|k| {
            let nu = hf.single_edf[k];
            let s_meas = (2.0 / nu).sqrt();
            let s = (s_meas.powi(2)
                + hf.typical_sigma[k].powi(2)
                + (2.0 * tol).powi(2)
                + extra.get(k).copied().unwrap_or(0.0))
            .sqrt();
            let r = reference.get(k).copied().unwrap_or(1.0);
            chi2_z(hf.singles[i][k] / (r * hf.typical[k]).max(1e-300), nu) * s_meas / s
        })
        .collect()
}

/// Trigamma ψ′(x), x > 0: the variance of ln of a Gamma(x) variable, so `ψ′(ν/2)` is that of `ln(χ²_ν/ν)`
/// (recurrence to x ≥ 6, then the asymptotic series; relative error < 1e-9).
pub(super) fn trigamma(x: f64) -> f64 {
    if !(x.is_finite() && x > 0.0) {
        return f64::NAN;
    }
    let (mut x, mut acc) = (x, 0.0);
    while x < 6.0 {
        acc += 1.0 / (x * x);
        x += 1.0;
    }
    let x2 = 1.0 / (x * x);
    acc + 1.0 / x
        + x2 / 2.0
        + (x2 / x) * (1.0 / 6.0 - x2 * (1.0 / 30.0 - x2 * (1.0 / 42.0 - x2 / 30.0)))
}

/// What the cluster's noise model predicts for each sensor of a half, and how well: for sensor i at τ_k the factor
/// `p_ik` on the typical variance `V_k` is `c_i f_k + (1 − f_k)`, with `f_k` the share of the typical model's fast
/// terms (quantisation, white) at τ_k and `c_i` the sensor's own level in them (the median of
/// `(σ²_ik/V_k − (1 − f_k))/f_k` over the τ where they dominate): its own fast terms, the typical slow terms
/// (flicker, random walk, ramp). Parts differ in their slow terms too; `slow_spread` is the variance of ln of a
/// part's slow level about the typical, pooled over the τ where the slow terms dominate from the robust spread of
/// `ln(σ²_jk/(p_jk V_k))` over the sensors less its χ² part ψ′(ν/2), each τ weighted by the inverse square of that
/// χ² part (a spread of ln measured at few EDF is mostly χ² scatter).
pub(super) struct ClusterPrediction {
    /// `p[i][k]`.
    pub(super) p: Vec<Vec<f64>>,
    /// `f_k`.
    fast: Vec<f64>,
    /// Variance of ln of a part's slow level.
    pub(super) slow_spread: f64,
}

impl ClusterPrediction {
    pub(super) fn of(hf: &Half, typ: &Terms) -> Self {
        let ns = hf.singles.len();
        let nk = hf.len();
        let fast: Vec<f64> = hf
            .tau_s
            .iter()
            .map(|&t| {
                let all = typ.avar(t);
                if all > 0.0 {
                    (typ.only(&[0, 1]).avar(t) / all).clamp(0.0, 1.0)
                } else {
                    1.0
                }
            })
            .collect();
        let ratio = |i: usize, k: usize| hf.singles[i][k] / hf.typical[k].max(1e-300);
        let p: Vec<Vec<f64>> = (0..ns)
            .map(|i| {
                let own: Vec<f64> = (0..nk)
                    .filter(|&k| fast[k] >= 0.5)
                    .map(|k| (ratio(i, k) - (1.0 - fast[k])) / fast[k])
                    .collect();
                let c = if own.is_empty() {
                    1.0
                } else {
                    median(&own).max(1e-3)
                };
                fast.iter().map(|f| c * f + (1.0 - f)).collect()
            })
            .collect();
        let (mut num, mut den) = (0.0, 0.0);
        for k in (0..nk).filter(|&k| fast[k] < 0.5) {
            let u: Vec<f64> = (0..ns)
                .map(|i| (ratio(i, k) / p[i][k]).max(1e-300).ln())
                .collect();
            let mid = median(&u);
            let dev: Vec<f64> = u.iter().map(|x| (x - mid).abs()).collect();
            let chi = trigamma(hf.single_edf[k] / 2.0);
            let v = (1.482_602_2 * median(&dev)).powi(2) - chi;
            if v.is_finite() && chi.is_finite() && chi > 0.0 {
                let wt = 1.0 / (chi * chi);
                num += wt * v;
                den += wt;
            }
        }
        let slow_spread = if den > 0.0 { (num / den).max(0.0) } else { 0.0 };
        Self {
            p,
            fast,
            slow_spread,
        }
    }

    /// The spread of parts as a variance of ln of sensor i's prediction at each τ: the slow terms' share of it.
    fn spread(&self, i: usize) -> Vec<f64> {
        self.fast
            .iter()
            .zip(&self.p[i])
            .map(|(f, p)| self.slow_spread * ((1.0 - f) / p).powi(2))
            .collect()
    }
}

/// The two per-τ z-scores of sensor i on a half: above its own short-τ level `level` at every τ (a uniformly
/// noisy part is `outlier_sensor`, not this), and above what the cluster's model predicts for it (`pred`, with the
/// spread of parts).
fn scans(hf: &Half, i: usize, level: f64, pred: &ClusterPrediction, tol: f64) -> [Vec<f64>; 2] {
    let nk = hf.len();
    [
        sensor_z(hf, i, &vec![level; nk], &[], tol),
        sensor_z(hf, i, &pred.p[i], &pred.spread(i), tol),
    ]
}

/// The scan statistic of a departure from both references at once: the one-sided scan of the per-τ smaller of the
/// two z-scores. A drift exceeds both references at the τ where it acts; the intersection–union test holds point by
/// point (`min(z₁, z₂) ≤ z_j` at every τ, so the scan of the minimum exceeds its threshold no more often than
/// either reference's own scan under that reference's null). Two scans taken apart were passed by a sensor above
/// one reference at some τ and above the other only at others: on null records with a Gauss–Markov bump a part
/// with quiet white noise was above its own short-τ level from the bump's τ on (the bump is as large on every
/// part) and above the cluster's prediction only at τ₀, where its white level is extrapolated from the τ that the
/// bump shares with the white noise.
fn joint_scan(z: &[Vec<f64>; 2]) -> f64 {
    let m: Vec<f64> = z[0].iter().zip(&z[1]).map(|(a, b)| a.min(*b)).collect();
    scan_statistic(&m)
}

/// Sensor i's short-τ level: the median ratio to the typical over the shorter half of the τ points.
fn short_level(hf: &Half, i: usize) -> f64 {
    let short: Vec<f64> = (0..hf.len() / 2)
        .map(|k| hf.singles[i][k] / hf.typical[k])
        .collect();
    median(&short)
}

/// The sensors of one axis that depart at long τ, on the first half (`first`, statistics `hf`, the typical model
/// `typ`), each with the slow terms of its excess. A sensor departs when its Allan variance exceeds, at the same τ,
/// both its own short-τ level and what the cluster's noise model predicts for it ([`ClusterPrediction`]: its own
/// fast terms, the typical slow terms, the spread of parts): the one-sided scan of the smaller z-score per τ
/// ([`joint_scan`]) at `p_false / sensors`;
/// a departure whose Allan correlation with the others' mean exceeds three null standard deviations is left to
/// the shared candidates.
pub(super) fn departures(
    an: &mut Analyzer,
    first: &[&[f64]],
    hf: &Half,
    typ: &Terms,
    tau0: f64,
    opts: &Options,
) -> Vec<Departure> {
    let ns = first.len();
    let nk = hf.len();
    if ns < 4 || nk < 4 {
        return Vec::new();
    }
    let thr = scan_threshold(nk, opts.p_false / ns as f64);
    let pred = ClusterPrediction::of(hf, typ);
    let mut out = Vec::new();
    for i in 0..ns {
        let level = short_level(hf, i);
        if !(level.is_finite() && level > 0.0) {
            continue;
        }
        let z = scans(hf, i, level, &pred, opts.model_tolerance);
        let scan = joint_scan(&z);
        let [z_own, z_cluster] = z;
        let Some(k0) = (nk / 2..nk).find(|&k| z_own[k] > 2.0 && z_cluster[k] > 2.0) else {
            continue;
        };
        if scan <= thr {
            continue;
        }
        let (correlation, correlation_sd) = correlation_with_others(an, first, hf, i, k0, tau0);
        if correlation > 3.0 * correlation_sd {
            continue;
        }
        let rows: Vec<Row5> = (0..nk)
            .map(|k| {
                let sd = hf.singles[i][k] * (2.0 / hf.single_edf[k]).sqrt();
                let e = hf.singles[i][k] - level.max(pred.p[i][k]) * hf.typical[k];
                (Terms::basis(hf.tau_s[k]), e, 1.0 / (sd * sd).max(1e-300))
            })
            .collect();
        let Some(part) = fit_subset(&rows, &[3, 4]) else {
            continue;
        };
        out.push(Departure {
            sensor: i,
            level,
            scan,
            threshold: thr,
            from_tau_s: hf.tau_s[k0],
            correlation,
            correlation_sd,
            part,
            slow_spread: pred.slow_spread,
        });
    }
    out
}

/// Allan correlation of sensor `i` with the mean of the others over the τ points from `k0` on, weighted by their
/// EDF: `C = (σ²(y_i + m) − σ²_i − σ²_m)/2` over `√(σ²_i σ²_m)`, and its null standard deviation `1/√Σν`.
fn correlation_with_others(
    an: &mut Analyzer,
    first: &[&[f64]],
    hf: &Half,
    i: usize,
    k0: usize,
    tau0: f64,
) -> (f64, f64) {
    let ns = first.len();
    let others: Vec<&[f64]> = (0..ns).filter(|&j| j != i).map(|j| first[j]).collect();
    let m = weighted_mean(&others, &vec![1.0 / (ns - 1) as f64; ns - 1]);
    let sum: Vec<f64> = m.iter().zip(first[i]).map(|(a, b)| a + b).collect();
    let pm = octave_devs(an, &m, tau0);
    let ps = octave_devs(an, &sum, tau0);
    let (mut num, mut wsum) = (0.0, 0.0);
    for k in k0..hf.len() {
        let (Some(a), Some(s)) = (
            pm.iter().find(|p| p.m == hf.m[k]),
            ps.iter().find(|p| p.m == hf.m[k]),
        ) else {
            continue;
        };
        let (vm, vs, vi) = (a.dev * a.dev, s.dev * s.dev, hf.singles[i][k]);
        let rho = 0.5 * (vs - vi - vm) / (vi * vm).sqrt().max(1e-300);
        let nu = hf.single_edf[k];
        num += nu * rho;
        wsum += nu;
    }
    if wsum > 0.0 {
        (num / wsum, 1.0 / wsum.sqrt())
    } else {
        (0.0, f64::INFINITY)
    }
}

/// The `sensor_drift` candidate: every departing sensor's own slow terms.
pub(super) fn drift_candidate(w: &AxisWork, deps: &[Departure]) -> Option<Candidate> {
    if deps.is_empty() {
        return None;
    }
    let per: BTreeMap<String, serde_json::Value> = deps
        .iter()
        .map(|d| {
            (
                w.groups[d.sensor].to_string(),
                serde_json::json!({
                    "random_walk": (3.0 * d.part.0[3]).sqrt(),
                    "ramp": (2.0 * d.part.0[4]).sqrt(),
                    "short_tau_level": d.level,
                    "departs_from_tau_s": d.from_tau_s,
                    "scan": d.scan,
                    "threshold": d.threshold,
                    "correlation_with_others": d.correlation,
                    "correlation_null_sd": d.correlation_sd,
                    "slow_spread_ln": d.slow_spread.sqrt(),
                }),
            )
        })
        .collect();
    Some(Candidate {
        kind: "sensor_drift",
        level: None,
        level_terms: None,
        cross: deps
            .iter()
            .map(|d| Cross::Own {
                sensor: d.sensor,
                part: d.part,
            })
            .collect(),
        groups: Groups::List(deps.iter().map(|d| w.groups[d.sensor]).collect()),
        params: serde_json::json!({ "sensors": per }),
    })
}

/// Whether sensor `i` departs on the held-out half `hh` as well (the same joint scan at `p_false / sensors`, with the
/// cluster's prediction measured there; `typ` the typical model): one sensor's drift is reported on this
/// per-sensor evidence even when the cluster's gap alone is not significant (it adds only `w_i²` of its variance
/// to the mean).
pub(super) fn confirmed(hh: &Half, typ: &Terms, i: usize, opts: &Options) -> bool {
    let (ns, nk) = (hh.singles.len(), hh.len());
    if ns < 4 || nk < 4 || i >= ns {
        return false;
    }
    let level = short_level(hh, i);
    if !(level.is_finite() && level > 0.0) {
        return false;
    }
    let pred = ClusterPrediction::of(hh, typ);
    let thr = scan_threshold(nk, opts.p_false / ns as f64);
    joint_scan(&scans(hh, i, level, &pred, opts.model_tolerance)) > thr
}
