//! Selection on the held-out half: which candidates act, added while they shrink the excess χ².

use super::analyse::{Acts, THERMAL_PREFERENCE};
use super::candidates::{Candidate, build};
use super::model::{Cross, Model, Terms};
use super::prediction::{chi2, evaluate, octave_corr, significant};
use super::singles::{Half, region_name};
use super::types::Options;
use crate::allan::AnalysisPoint;
use crate::allan::noisefit;
use crate::allan::noisefit::NoiseFit;
use crate::formats::csv::{AXIS_NAMES, SensorKind};
use statrs::distribution::{ContinuousCDF, Normal};

pub(super) fn axis_label(kind: SensorKind, axis: usize) -> String {
    format!(
        "{}{}",
        kind.prefix(),
        AXIS_NAMES.get(axis).copied().unwrap_or('?')
    )
}

/// Where a chosen effect acts on the held-out half: (region, τ range, τ of max, max share). The region is the
/// dominant term of the effect's own shape (`nature`, shared processes) or else of the typical sensor, at the τ of
/// its largest share.
pub(super) fn acts(
    nature: Option<Terms>,
    h: &Half,
    w: &[f64],
    full: &Model,
    without: &Model,
    typ: &Terms,
) -> Acts {
    let share: Vec<f64> = (0..h.len())
        .map(|k| {
            let a = full.avar(w, h.tau_s[k], h.scale(full, w, k).0, h.temp[k]);
            let b = without.avar(w, h.tau_s[k], h.scale(without, w, k).0, h.temp[k]);
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

/// What phase 1 keeps of an axis for the sibling pass and the report.
pub(super) struct AxisState {
    pub(super) hf: Half,
    pub(super) hw: Half,
    /// The sensors' octave OADEV of the whole record (deviations only: `octave_devs`).
    pub(super) pts_whole: Vec<Vec<AnalysisPoint>>,
    pub(super) hh: Half,
    pub(super) cands: Vec<Candidate>,
    pub(super) chosen: Vec<usize>,
    pub(super) wts: Vec<f64>,
    pub(super) typical: NoiseFit,
    /// The typical sensor's single-pole bandwidth, when fitted.
    pub(super) bandwidth: Option<noisefit::LowPass>,
    pub(super) typ_terms: Terms,
    /// RMS ln misfit of the sensors' four-term fits, and with their bandwidths.
    pub(super) model_misfit: [f64; 2],
    /// The effects selected removed less than [`unexplained::NAME_SHARE`] of the held-out excess and were dropped.
    pub(super) gave_up: bool,
}

/// Greedy selection on the held-out half: while the remaining gap is significant (scan statistic above `thr`),
/// add the candidate (of the `allowed` kinds) that lowers the held-out `Σ z²` most, if it removes at least
/// `min_shrink` of the excess over the point count.
pub(super) fn select(
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
                || !cross_confirmed(c, &refs, hh, wts, opts)
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
pub(super) fn sibling(st: &AxisState, kinds: &[&str], opts: &Options) -> Option<usize> {
    let ns = st.wts.len();
    let p0 = evaluate(
        &Model::independent(ns),
        &st.hh,
        &st.wts,
        opts.model_tolerance,
    );
    let current = chi2(&p0);
    let excess_now = (current - p0.len() as f64).max(0.0);
    let z_crit = upper_z(opts.p_sibling);
    let z0: Vec<f64> = p0.iter().map(|a| a.z).collect();
    let mut best: Option<(f64, usize)> = None;
    for (i, c) in st.cands.iter().enumerate() {
        if !kinds.contains(&c.kind) || !cross_confirmed(c, &[], &st.hh, &st.wts, opts) {
            continue;
        }
        let with = evaluate(&build(ns, &[c]), &st.hh, &st.wts, opts.model_tolerance);
        let shift: Vec<f64> = p0.iter().zip(&with).map(|(a, b)| a.z - b.z).collect();
        let x = chi2(&with);
        if projection(&z0, &shift).is_some_and(|t| t > z_crit)
            && x <= current - opts.min_shrink * excess_now
            && best.is_none_or(|(bx, _)| x < bx)
        {
            best = Some((x, i));
        }
    }
    best.map(|(_, i)| i)
}

/// Whether the held-out half's own cross covariance confirms a candidate that adds a shared process (`Cross::Shared`:
/// `common_mode`, `common_mode_drift`, `block_common_mode`; any other candidate passes). The gap test compares the
/// cluster with a prediction from the sensors' first-half models, so on unequal parts, or where the prediction
/// scatters, a shared process can lower the held-out `Σ z²` without the sensors being correlated at all. The
/// cross-covariance z of each held-out point ([`Half::cross_z`], the cluster against the same half's
/// `Σ w_i² σ̂_i²`, no prediction involved) is projected on what the candidate predicts for it over the model already
/// chosen (`refs`): `T = Σ r_k s_k / √(sᵀRs)`, `r` the measured z less the chosen model's, `s` the candidate's
/// predicted shift, `R` the octave points' null correlation. Under independence `T` is N(0, 1); the candidate is
/// kept at `T > z(1 − p_cross)`.
pub(super) fn cross_confirmed(
    c: &Candidate,
    refs: &[&Candidate],
    h: &Half,
    w: &[f64],
    opts: &Options,
) -> bool {
    if !c.cross.iter().any(|x| matches!(x, Cross::Shared { .. })) {
        return true;
    }
    let ns = w.len();
    let mut with = refs.to_vec();
    with.push(c);
    let full = build(ns, &with);
    let before = build(ns, refs);
    let alone = Model {
        cross: Vec::new(),
        ..full.clone()
    };
    let mut resid = Vec::with_capacity(h.len());
    let mut shift = Vec::with_capacity(h.len());
    for k in 0..h.len() {
        let (t, v, th) = (h.tau_s[k], h.typical[k], h.temp[k]);
        let indep = alone.avar(w, t, v, th);
        if indep.is_nan() || indep <= 0.0 {
            continue;
        }
        let z0 = h.cross_z(w, k, before.avar(w, t, v, th) / indep);
        resid.push(h.measured_cross_z(w, k) - z0);
        shift.push(h.cross_z(w, k, full.avar(w, t, v, th) / indep) - z0);
    }
    projection(&resid, &shift).is_some_and(|t| t > upper_z(opts.p_cross))
}

/// The projection of the held-out z-scores `r` on the shift `s` a candidate predicts for them,
/// `T = Σ r_k s_k / √(sᵀRs)` (R the null correlation of neighbouring octaves, `octave_corr`): N(0, 1) when `r` is
/// null noise, whatever `s`. `None` when `sᵀRs` is not positive (the candidate predicts no shift).
fn projection(r: &[f64], s: &[f64]) -> Option<f64> {
    let num: f64 = r.iter().zip(s).map(|(r, s)| r * s).sum();
    let mut var = 0.0;
    for (a, sa) in s.iter().enumerate() {
        for (b, sb) in s.iter().enumerate() {
            var += sa * sb * octave_corr(a.abs_diff(b));
        }
    }
    (var > 0.0).then(|| num / var.sqrt())
}

/// The one-sided normal quantile `z(1 − p)` (infinite where it cannot be computed: nothing passes).
fn upper_z(p: f64) -> f64 {
    Normal::new(0.0, 1.0)
        .map(|n| n.inverse_cdf(1.0 - p))
        .unwrap_or(f64::INFINITY)
}
