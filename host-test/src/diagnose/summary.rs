//! The report's tables: per-τ rows and independence, regions, gains, and effects merged across axes.

use super::analyse::Acts;
use super::candidates::Candidate;
use super::model::{Model, Terms};
use super::prediction::PointGap;
use super::singles::{Half, octave, region_name, weighted_mean};
use super::types::{Effect, Gain, Groups, Independence, Region, TauRow};
use crate::allan::lanes;
use crate::allan::{AnalysisPoint, Analyzer};
use crate::formats::csv::{AXIS_NAMES, SensorKind};
use crate::stats::median;
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::collections::BTreeMap;

/// The per-τ table of the held-out half and the test for independence.
pub(super) fn tau_rows(
    h: &Half,
    w: &[f64],
    p0: &Model,
    model: &Model,
    before: &[PointGap],
    after: &[PointGap],
) -> (Vec<TauRow>, Independence) {
    let sw2: f64 = w.iter().map(|x| x * x).sum();
    let pair_w = w.iter().sum::<f64>().powi(2) - sw2;
    let mut rows = Vec::new();
    for k in 0..h.len() {
        let (t, v, th) = (h.tau_s[k], h.typical[k], h.temp[k]);
        let indep = h.independent(w, k);
        let cross_z = h.measured_cross_z(w, k);
        let dev = h.cluster[k].sqrt();
        let (dev_lo, dev_hi) =
            crate::allan::confidence_interval(dev, h.edf[k], crate::allan::ONE_SIGMA_CI)
                .unwrap_or((dev, dev));
        let (b, a) = (before[k], after[k]);
        let (v_after, sigma_after) = h.scale(model, w, k);
        rows.push(TauRow {
            tau_s: t,
            blocks: h.n / h.m[k].max(1),
            alpha: h.alpha[k],
            edf: h.edf[k],
            dev,
            dev_lo,
            dev_hi,
            predicted_before: p0.avar(w, t, h.scale(p0, w, k).0, th).max(0.0).sqrt(),
            predicted_after: model.avar(w, t, v_after, th).max(0.0).sqrt(),
            prediction_sigma_ln: 0.5 * sigma_after,
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
pub(super) fn regions(
    typ: &Terms,
    h: &Half,
    before: &[PointGap],
    after: &[PointGap],
    z: f64,
) -> Vec<Region> {
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
/// deviations of the whole record, as measured for the significance test; the one sensor whose interval is needed
/// is analysed in full here).
pub(super) fn gains(
    an: &mut Analyzer,
    series: &[&[f64]],
    singles: &[Vec<AnalysisPoint>],
    w: &[f64],
    tau0: f64,
) -> (Gain, Gain) {
    // Summed by eight partial sums (`allan::lanes`; a serial sum waits for each addition): two passes over each
    // sensor's and the mean's whole record, ≈ 4 % of the diagnosis's processor time when they were serial.
    let std = |x: &[f64]| {
        let m = lanes::sum(x) / x.len().max(1) as f64;
        let ss = lanes::sum3(x, x, x, |v, _, _| (v - m).powi(2));
        (ss / (x.len().max(2) - 1) as f64).sqrt()
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
    // Each sensor's lowest point (`singles` hold deviations only: the interval is taken below, for the one sensor
    // that needs it).
    let mins: Vec<(usize, AnalysisPoint)> = singles
        .iter()
        .enumerate()
        .filter_map(|(i, p)| Some((i, min(p)?)))
        .collect();
    let single_min = median(&mins.iter().map(|(_, p)| p.dev).collect::<Vec<_>>());
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
        // The sensor at the median of the lowest deviations; for an even count the lower of the two middle ones
        // (both are equally near the median in exact arithmetic, and "the nearer" was picked by rounding: 4 of the
        // six MIMU4444 records swapped it, and the interval moved 2–6 %, when the deviations changed by 1e-12).
        let mut by_dev: Vec<&(usize, AnalysisPoint)> = mins.iter().collect();
        by_dev.sort_by(|a, b| a.1.dev.total_cmp(&b.1.dev).then(a.0.cmp(&b.0)));
        let m = by_dev.get(by_dev.len().saturating_sub(1) / 2).copied();
        // That sensor's full analysis (noise type, EDF, interval) at its lowest point.
        let full = m.and_then(|(i, p)| {
            let s = series.get(*i)?;
            octave(an, s, tau0).into_iter().find(|q| q.m == p.m)
        });
        full.as_ref().map_or(0.0, half) / (mins.len().max(1) as f64).sqrt()
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
pub(super) fn merge_effects(found: Vec<(SensorKind, usize, Candidate, Acts)>) -> Vec<Effect> {
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
        let per_group = matches!(
            c.kind,
            "outlier_sensor" | "block_common_mode" | "sensor_drift" | "periodic"
        );
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
