//! `unexplained`: a significant gap that no candidate explains. The diagnosis names an effect only when it removes
//! at least half of the axis's held-out excess `Σ z² − n` ([`NAME_SHARE`]); when the gap stays significant after
//! the chosen effects (or none qualified), the axis reports `unexplained` with where and how large the gap is and
//! the closest candidate with how little it explains — never a wrong name (spec: `docs/diagnose.md`).

use super::candidates::{AxisWork, Candidate, build};
use super::model::Model;
use super::prediction::{PointGap, chi2, evaluate};
use super::selection::AxisState;
use super::singles::{Half, region_name};
use super::types::{Effect, Groups, Options};
use crate::formats::csv::AXIS_NAMES;
use std::collections::BTreeMap;

/// Share of the P0 held-out excess `Σ z² − n` the chosen effects together must remove to be named.
pub(super) const NAME_SHARE: f64 = 0.5;

/// Share of the held-out excess of `base` that the model `with` removes (may be negative; 0 without an excess).
fn removes(base: &[PointGap], with: &[PointGap]) -> f64 {
    let excess = chi2(base) - base.len() as f64;
    if excess > 0.0 {
        (chi2(base) - chi2(with)) / excess
    } else {
        0.0
    }
}

/// Whether the effects `chosen` (of `cands`) together remove at least [`NAME_SHARE`] of the axis's P0 held-out
/// excess. An empty choice passes (nothing is named).
pub(super) fn enough(
    cands: &[Candidate],
    chosen: &[usize],
    hh: &Half,
    wts: &[f64],
    opts: &Options,
) -> bool {
    if chosen.is_empty() {
        return true;
    }
    let ns = wts.len();
    let tol = opts.model_tolerance;
    let p0 = evaluate(&Model::independent(ns), hh, wts, tol);
    let refs: Vec<&Candidate> = chosen.iter().filter_map(|&i| cands.get(i)).collect();
    let with = evaluate(&build(ns, &refs), hh, wts, tol);
    chi2(&p0) <= p0.len() as f64 || removes(&p0, &with) >= NAME_SHARE
}

/// The `unexplained` effect of an axis whose gap is still significant under its final model (`after`, held-out
/// half): the τ range where the held-out z-scores exceed `opts.z`, the region of the typical sensor at the largest,
/// the share of the measured cluster variance the model misses there, the axis's excess gap, and the closest
/// candidate not chosen with the share of the remaining excess it would remove.
pub(super) fn effect(
    w: &AxisWork,
    st: &AxisState,
    after: &[PointGap],
    excess_gap: f64,
    opts: &Options,
) -> Effect {
    let ns = st.wts.len();
    let tol = opts.model_tolerance;
    let refs: Vec<&Candidate> = st.chosen.iter().map(|&i| &st.cands[i]).collect();
    let closest = st
        .cands
        .iter()
        .enumerate()
        .filter(|(i, c)| {
            let same_kind = refs.iter().any(|r| r.kind == c.kind);
            let second_level = c.level.is_some() && refs.iter().any(|r| r.level.is_some());
            !(st.chosen.contains(i) || same_kind || second_level)
        })
        .map(|(_, c)| {
            let mut with = refs.clone();
            with.push(c);
            (
                c.kind,
                removes(after, &evaluate(&build(ns, &with), &st.hh, &st.wts, tol)),
            )
        })
        .max_by(|a, b| a.1.total_cmp(&b.1));
    let h = &st.hh;
    let out: Vec<usize> = (0..after.len().min(h.len()))
        .filter(|&k| after[k].z.abs() > opts.z)
        .collect();
    let kmax = (0..after.len().min(h.len()))
        .max_by(|&a, &b| after[a].z.abs().total_cmp(&after[b].z.abs()))
        .unwrap_or(0);
    let tau = |k: usize| h.tau_s.get(k).copied().unwrap_or(0.0);
    let lo = out.first().map_or(tau(kmax), |&k| tau(k));
    let hi = out.last().map_or(tau(kmax), |&k| tau(k));
    // The model's miss at the largest gap: 1 − predicted/measured variance (negative: it predicts too much).
    let g = after.get(kmax).map_or(0.0, |p| p.g);
    let share = 1.0 - (-2.0 * g).exp();
    let ax = AXIS_NAMES.get(w.axis).copied().unwrap_or('?').to_string();
    let mut params = BTreeMap::new();
    params.insert(
        ax.clone(),
        serde_json::json!({
            "excess_gap": excess_gap,
            "largest_gap_ln": g,
            "largest_z": after.get(kmax).map_or(0.0, |p| p.z),
            "closest": closest.map(|c| c.0),
            "closest_explains": closest.map_or(0.0, |c| c.1),
            "after": st.chosen.iter().map(|&i| st.cands[i].kind).collect::<Vec<_>>(),
        }),
    );
    Effect {
        kind: "unexplained".into(),
        sensor: w.kind.name().into(),
        axes: ax,
        groups: Groups::List(w.groups.clone()),
        region: region_name(&st.typ_terms, tau(kmax)).into(),
        tau_s: [lo, hi],
        tau_at_max_s: tau(kmax),
        share,
        params,
    }
}
