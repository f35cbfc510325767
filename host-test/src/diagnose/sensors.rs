//! `sensor_drift`: one sensor that departs from the typical one only at long τ (its own random walk or ramp), found
//! per sensor and per τ — not through a median over all τ — and told apart from a shared process by its Allan
//! covariance with the other sensors, which stays null (spec: `docs/diagnose.md`).

use super::*;

/// One sensor's departure from the typical sensor at long τ, fitted on the first half.
#[derive(Clone, Debug)]
pub(super) struct Departure {
    /// Index of the sensor in its axis.
    pub(super) sensor: usize,
    /// Its level at short τ relative to the typical sensor (variance ratio).
    pub(super) level: f64,
    /// Scan statistic of its per-τ z-scores above `level × typical`, and the threshold it passed.
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
}

/// Per-τ z-scores of sensor `i`'s Allan variance against `level × typical`, with the typical sensor's own scatter
/// and the 3 % tolerance (in deviation) in the denominator, as the cluster's z-scores.
fn sensor_z(hf: &Half, i: usize, level: f64, tol: f64) -> Vec<f64> {
    (0..hf.len())
        .map(|k| {
            let nu = hf.single_edf[k];
            let s_meas = (2.0 / nu).sqrt();
            let s = (s_meas.powi(2) + hf.typical_sigma[k].powi(2) + (2.0 * tol).powi(2)).sqrt();
            chi2_z(hf.singles[i][k] / (level * hf.typical[k]).max(1e-300), nu) * s_meas / s
        })
        .collect()
}

/// The sensors of one axis that depart from the typical one at long τ on the first half (`first`, statistics
/// `hf`), each with the slow terms of its excess. A sensor is tested for departure above its own short-τ level
/// (the median ratio over the shorter half of the τ points: a noisy sensor is `outlier_sensor`, not this), by the
/// one-sided scan of its z-scores at `p_false / sensors`; a departure whose Allan correlation with the others' mean
/// exceeds three null standard deviations is left to the shared candidates.
pub(super) fn departures(
    an: &mut Analyzer,
    first: &[&[f64]],
    hf: &Half,
    tau0: f64,
    opts: &Options,
) -> Vec<Departure> {
    let ns = first.len();
    let nk = hf.len();
    if ns < 4 || nk < 4 {
        return Vec::new();
    }
    let thr = scan_threshold(nk, opts.p_false / ns as f64);
    let mut out = Vec::new();
    for i in 0..ns {
        let short: Vec<f64> = (0..nk / 2)
            .map(|k| hf.singles[i][k] / hf.typical[k])
            .collect();
        let level = median(&short);
        if !(level.is_finite() && level > 0.0) {
            continue;
        }
        let z = sensor_z(hf, i, level, opts.model_tolerance);
        let scan = scan_statistic(&z);
        let Some(k0) = (nk / 2..nk).find(|&k| z[k] > 2.0) else {
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
                let e = hf.singles[i][k] - level * hf.typical[k];
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
    let pm = octave(an, &m, tau0);
    let ps = octave(an, &sum, tau0);
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
                }),
            )
        })
        .collect();
    Some(Candidate {
        kind: "sensor_drift",
        level: None,
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

/// Whether sensor `i` departs from the typical sensor on the held-out half `hh` as well (the same one-sided scan
/// at `p_false / sensors`, above its own short-τ level there): one sensor's drift is reported on this per-sensor
/// evidence even when the cluster's gap alone is not significant (it adds only `w_i²` of its variance to the mean).
pub(super) fn confirmed(hh: &Half, i: usize, opts: &Options) -> bool {
    let (ns, nk) = (hh.singles.len(), hh.len());
    if ns < 4 || nk < 4 {
        return false;
    }
    let short: Vec<f64> = (0..nk / 2)
        .map(|k| hh.singles[i][k] / hh.typical[k])
        .collect();
    let level = median(&short);
    level.is_finite()
        && level > 0.0
        && scan_statistic(&sensor_z(hh, i, level, opts.model_tolerance))
            > scan_threshold(nk, opts.p_false / ns as f64)
}
