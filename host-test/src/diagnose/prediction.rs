//! Prediction against measurement: the z-score of each τ point's gap, χ², the scan statistic and its threshold.

use super::model::Model;
use super::singles::Half;
use crate::allan::chi2_z;

/// The gap of one τ point.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct PointGap {
    /// ln(measured / predicted) deviation.
    pub(super) g: f64,
    /// Its total uncertainty.
    pub(super) sigma: f64,
    /// z-score (χ² at the measured EDF, scaled for the other uncertainties).
    pub(super) z: f64,
}

pub(super) fn point_gap(
    measured: f64,
    predicted: f64,
    nu: f64,
    pred_sigma_var: f64,
    tol: f64,
) -> PointGap {
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

pub(super) fn evaluate(model: &Model, h: &Half, w: &[f64], tol: f64) -> Vec<PointGap> {
    (0..h.len())
        .map(|k| {
            let (v, v_sigma) = h.scale(model, w, k);
            let pred = model.avar(w, h.tau_s[k], v, h.temp[k]);
            point_gap(h.cluster[k], pred, h.edf[k], v_sigma, tol)
        })
        .collect()
}

pub(super) fn chi2(p: &[PointGap]) -> f64 {
    p.iter().map(|x| x.z * x.z).sum()
}

/// MA(2) weights that give neighbouring octave z-scores the correlation measured on clean simulations (adjacent
/// ≈ 0.55, two apart ≈ 0.2; these weights give 0.61 and 0.20, on the safe side).
pub(super) const OCTAVE_MA: [f64; 3] = [1.0, 0.8, 0.35];

/// Null correlation of z-scores `lag` octaves apart (1 at lag 0, 0 beyond the MA order).
pub(super) fn octave_corr(lag: usize) -> f64 {
    let norm: f64 = OCTAVE_MA.iter().map(|x| x * x).sum();
    OCTAVE_MA
        .iter()
        .zip(OCTAVE_MA.iter().skip(lag))
        .map(|(a, b)| a * b)
        .sum::<f64>()
        / norm
}

/// The scan statistic of a run of z-scores (ordered by τ): the largest standardised sum over contiguous windows,
/// `max_{a ≤ b} Σ_{a..=b} z / √Var₀(Σ)`, with the null variance from `octave_corr`. One-sided, because every
/// effect the diagnosis models adds variance; over windows, because an effect acts over a band of τ — from the
/// first τ on (white-region effects), from some τ to the longest (drifts), or as a bump (a periodic temperature).
pub fn scan_statistic(z: &[f64]) -> f64 {
    // Adding one point to a window of `len` points: its variance 1 plus twice its covariance with the (up to two)
    // points before it.
    const LAGS: usize = OCTAVE_MA.len() - 1;
    let step: [f64; LAGS + 1] =
        std::array::from_fn(|len| 1.0 + 2.0 * (1..=len.min(LAGS)).map(octave_corr).sum::<f64>());
    let mut best = f64::NEG_INFINITY;
    for a in 0..z.len() {
        let (mut sum, mut var) = (0.0, 0.0);
        for (len, zk) in z[a..].iter().enumerate() {
            sum += zk;
            var += step[len.min(LAGS)];
            best = best.max(sum / var.sqrt());
        }
    }
    best
}

/// The (1 − p) quantile of [`scan_statistic`] over `n` null z-scores (correlated as `octave_corr`), from 40,000
/// seeded Monte Carlo draws (deterministic: computed once per `(n, p)` in a process and remembered).
pub fn scan_threshold(n: usize, p: f64) -> f64 {
    use std::collections::BTreeMap;
    use std::sync::{Mutex, OnceLock};
    static KNOWN: OnceLock<Mutex<BTreeMap<(usize, u64), f64>>> = OnceLock::new();
    let known = KNOWN.get_or_init(|| Mutex::new(BTreeMap::new()));
    let key = (n, p.to_bits());
    if let Some(t) = known.lock().ok().and_then(|m| m.get(&key).copied()) {
        return t;
    }
    let t = scan_threshold_drawn(n, p);
    if let Ok(mut m) = known.lock() {
        m.insert(key, t);
    }
    t
}

/// [`scan_threshold`] drawn.
fn scan_threshold_drawn(n: usize, p: f64) -> f64 {
    use rand_xoshiro::Xoshiro256PlusPlus;
    use rand_xoshiro::rand_core::SeedableRng;
    pub(super) const DRAWS: usize = 40_000;
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
pub(super) fn significant(whole: &[PointGap], threshold: f64) -> bool {
    let z: Vec<f64> = whole.iter().map(|p| p.z).collect();
    !z.is_empty() && scan_statistic(&z) > threshold
}

/// The part of a gap outside its ±z interval, in ln units: `σ·max(0, |z_score| − z)` (the z-score carries the χ²
/// skew of few-block estimates, so a low estimate at four blocks is not mistaken for a gap).
pub(super) fn excess(p: &PointGap, z: f64) -> f64 {
    p.sigma * (p.z.abs() - z).max(0.0)
}

/// Points of all axes for the report-wide gaps.
#[derive(Default)]
pub(super) struct Gaps {
    pub(super) fit_before: Vec<f64>,
    pub(super) fit_after: Vec<f64>,
    pub(super) held_before: Vec<f64>,
    pub(super) held_after: Vec<f64>,
    pub(super) raw_before: Vec<f64>,
    pub(super) raw_after: Vec<f64>,
}

impl Gaps {
    /// Appends the next axis's points (axis order kept).
    pub(super) fn append(&mut self, next: Gaps) {
        self.fit_before.extend(next.fit_before);
        self.fit_after.extend(next.fit_after);
        self.held_before.extend(next.held_before);
        self.held_after.extend(next.held_after);
        self.raw_before.extend(next.raw_before);
        self.raw_after.extend(next.raw_after);
    }

    pub(super) fn add(
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
