//! Each sensor's own terms when the diagnosis found its level to vary with τ (`AxisFit::level_terms`): the typical
//! terms `T` scaled term by term, with one factor per term group (quantisation, white, flicker with the
//! Gauss–Markov terms, random walk, ramp) for each sensor, so that its Allan variance follows its own curve at each τ
//! instead of `qᵢ·T`.
//!
//! A free fit per sensor copies its long-τ estimation error (a handful of blocks) into the twin, so the factors are
//! held to the sensor's one factor `qᵢ`: each is fitted by non-negative weighted least squares to the sensor's
//! octave points with a pull toward `qᵢ` worth ν₀ degrees of freedom (a pseudo-observation `fₖ = qᵢ`, relative
//! weight ν₀/2; the points weighted by the model's variance, reweighted three times, as a weight from the
//! observation favours the points that scatter low), and ν₀ — ∞ (the one factor), 32, 4 or 0 — is chosen per sensor on the record's own halves: fitted
//! on one half, scored on the other (`Σ ν/2·ln²(measured/model)`), both ways, the one factor kept unless another
//! scores lower by the 95th percentile of a χ² with the added parameters' degrees of freedom ([`gain_min`]); the
//! chosen factors are then refitted on the whole record. (Rescaling each group's factors to sum to `Σ qᵢ`, to keep
//! the model's mean sensor at `q̄·T`, was tried: the white and quantisation groups trade off, and on the MIMU4444
//! excerpt's gyro y it made every quiet sensor 20 % too loud in deviation; left out.)

use super::NoiseTerms;
use super::terms_fit::Obs;
use crate::allan::AnalysisPoint;
use crate::allan::noisefit::{LowPass, nnls};
use statrs::distribution::{ChiSquared, ContinuousCDF};

/// A sensor's factors of the five term groups relative to the typical terms.
pub(super) type Factors = [f64; 5];

/// The pulls toward the one factor offered besides the one factor itself (ν₀, pseudo degrees of freedom), strongest
/// first: on a tie the stronger pull is kept.
const PULLS: [f64; 3] = [32.0, 4.0, 0.0];

/// What the factors are fitted against: the typical terms, the sample interval and the axis's bandwidth.
pub(super) struct Typical<'a> {
    /// The typical terms `T`.
    pub terms: &'a NoiseTerms,
    /// Sample interval, s.
    pub tau0_s: f64,
    /// The axis's low-pass response, if the model keeps one.
    pub band: Option<&'a LowPass>,
}

impl Typical<'_> {
    /// Each term group's Allan variance at `tau_s`.
    fn groups(&self, tau_s: f64) -> [f64; 5] {
        [0, 1, 2, 3, 4].map(|k| {
            let mut f = [0.0; 5];
            f[k] = 1.0;
            self.terms
                .by_term_factors(&f)
                .avar(tau_s, self.tau0_s, self.band)
        })
    }

    /// The Allan variance of the terms scaled by `f` at `tau_s`.
    fn avar(&self, f: &Factors, tau_s: f64) -> f64 {
        self.groups(tau_s).iter().zip(f).map(|(g, f)| g * f).sum()
    }
}

/// One sensor's octave points as observations, less its own drift's Allan variance `drift` (coefficients of the
/// five terms, `sensor_drift`: added to its own terms afterwards); points left without a positive variance are
/// dropped.
fn observations(points: &[AnalysisPoint], drift: &[f64; 5], band: Option<&LowPass>) -> Vec<Obs> {
    Obs::of(points)
        .into_iter()
        .filter_map(|o| {
            let d: f64 = drift
                .iter()
                .zip(super::basis(o.tau_s, band))
                .map(|(c, b)| c * b)
                .sum();
            let avar = o.avar - d;
            (avar > 0.0 && avar.is_finite()).then(|| Obs {
                // The same relative weight, about the variance left.
                weight: o.weight * (o.avar / avar).powi(2),
                avar,
                ..o
            })
        })
        .collect()
}

/// Rounds of reweighting in [`fit`].
const IRLS_ROUNDS: usize = 3;

/// The factors fitted to `obs` with a pull of `nu0` degrees of freedom toward `q` (the one factor); term groups the
/// typical terms lack get `q`. `None` when the least squares fail (no point, or no positive `q`).
fn fit(obs: &[Obs], typical: &Typical, q: f64, nu0: f64) -> Option<Factors> {
    if !(q > 0.0 && q.is_finite()) {
        return None;
    }
    let rows0: Vec<([f64; 5], f64, f64)> = obs
        .iter()
        .map(|o| (typical.groups(o.tau_s), o.avar, o.weight))
        .collect();
    let active: Vec<usize> = (0..5)
        .filter(|&k| rows0.iter().any(|(g, _, _)| g[k] > 0.0))
        .collect();
    let mut rows: Vec<([f64; 5], f64, f64)> = rows0
        .into_iter()
        .map(|(g, y, w)| {
            // Only the active groups: a column of zeros makes every subset holding it singular.
            let mut b = [0.0; 5];
            active.iter().for_each(|&k| b[k] = g[k]);
            (b, y, w)
        })
        .collect();
    if nu0 > 0.0 {
        for &k in &active {
            let mut e = [0.0; 5];
            e[k] = 1.0;
            rows.push((e, q, nu0 / 2.0 / (q * q)));
        }
    }
    let mut f = nnls(&rows)?;
    // Weighted by the model's variance, not the observation's (`ν/2m²`, iterated): a weight from the observation
    // favours the points that scatter low, which at long τ (a handful of blocks) pulled the factors down.
    for _ in 0..IRLS_ROUNDS {
        for ((g, _, w), o) in rows.iter_mut().zip(obs) {
            let m: f64 = g.iter().zip(&f).map(|(g, f)| g * f).sum();
            if m > 0.0 && m.is_finite() {
                *w = o.weight * o.avar * o.avar / (m * m);
            }
        }
        f = nnls(&rows)?;
    }
    (0..5)
        .filter(|k| !active.contains(k))
        .for_each(|k| f[k] = q);
    Some(f)
}

/// `Σ ν/2·ln²(measured/model)` of the terms scaled by `f` against `obs` (∞ where the model is not positive).
fn score(obs: &[Obs], typical: &Typical, f: &Factors) -> f64 {
    obs.iter()
        .map(|o| {
            let m = typical.avar(f, o.tau_s);
            if m > 0.0 {
                o.weight * o.avar * o.avar * (o.avar / m).ln().powi(2)
            } else {
                f64::INFINITY
            }
        })
        .sum()
}

/// What a sensor's own factors must take off the one factor's held-out cost (a χ², the points weighted by their
/// inverse variance) to replace it: the 95th percentile of a χ² with as many degrees of freedom as they add
/// parameters (`active` term groups less one), as the count of Gauss–Markov terms is chosen (`terms_fit`). ∞ (the
/// one factor) with a single group.
fn gain_min(active: usize) -> f64 {
    match active.checked_sub(1) {
        Some(k) if k >= 1 => {
            ChiSquared::new(k as f64).map_or(f64::INFINITY, |c| c.inverse_cdf(0.95))
        }
        _ => f64::INFINITY,
    }
}

/// One axis's sensors as the factors see them.
pub(super) struct Sensors<'a> {
    /// Each sensor's octave points on the whole record.
    pub whole: &'a [Vec<AnalysisPoint>],
    /// … and on each half, when the halves are long enough to fit on.
    pub halves: Option<&'a [Vec<Vec<AnalysisPoint>>; 2]>,
    /// Each sensor's drift (`sensor_drift`) as Allan-variance coefficients, zero for most.
    pub drift: &'a [[f64; 5]],
}

/// Each sensor's term factors (see the module docs), given the one factors `q` of the whole record
/// ([`super::fit::levels`]); `None` without halves or levels to choose on, or with a sensor count that does not match.
pub(super) fn term_factors(s: &Sensors, q: &[f64], typical: &Typical) -> Option<Vec<Factors>> {
    let ns = q.len();
    let halves = s.halves?;
    if s.whole.len() != ns || s.drift.len() != ns || halves.iter().any(|h| h.len() != ns) {
        return None;
    }
    let q_half = [
        super::fit::levels(&halves[0])?,
        super::fit::levels(&halves[1])?,
    ];
    let band = typical.band;
    // The term groups the typical terms give some variance at the record's τ: the factors' count.
    let active = (0..5)
        .filter(|&k| {
            s.whole
                .iter()
                .flatten()
                .any(|p| typical.groups(p.tau_s)[k] > 0.0)
        })
        .count();
    let gain_min = gain_min(active);
    let f: Vec<Factors> = (0..ns)
        .map(|i| {
            let obs = |p: &[Vec<AnalysisPoint>]| observations(&p[i], &s.drift[i], band);
            let half_obs = [obs(&halves[0]), obs(&halves[1])];
            // Fitted on one half, scored on the other, both ways.
            let held_out = |nu0: Option<f64>| -> f64 {
                [(0, 1), (1, 0)]
                    .iter()
                    .map(|&(a, b)| {
                        let Some(&qa) = q_half[a].get(i) else {
                            return f64::INFINITY;
                        };
                        let fa = match nu0 {
                            None => Some([qa; 5]),
                            Some(nu0) => fit(&half_obs[a], typical, qa, nu0),
                        };
                        fa.map_or(f64::INFINITY, |fa| score(&half_obs[b], typical, &fa))
                    })
                    .sum()
            };
            let one = held_out(None);
            let mut best = (one - gain_min, None);
            for nu0 in PULLS {
                let sc = held_out(Some(nu0));
                if sc < best.0 {
                    best = (sc, Some(nu0));
                }
            }
            best.1
                .and_then(|nu0| fit(&obs(s.whole), typical, q[i], nu0))
                .unwrap_or([q[i]; 5])
        })
        .collect();
    Some(f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::allan::{Analyzer, DevKind, Options as AllanOptions, TauSpec};
    use crate::testrng::TestRng;

    /// Eight sensors whose parts differ term by term — four with 4× the typical white variance and ¼ its random
    /// walk, four the other way round — are given each its own factors: within 10 % of what was injected on the
    /// white term, 25 % on the random walk where it dominates and a factor 2 where it hides under 4× the white noise
    /// up to the last octaves (measured: ≤ 1 %, 16 %, 45 %); their one factor (1.5–1.8, 0.47–0.55) is off by more
    /// than 2× on one of the two.
    #[test]
    fn term_factors_follow_parts_that_differ_term_by_term() {
        let (n, dt) = (1 << 15, 0.1);
        let (white, rw) = (0.01f64, 1e-3f64);
        let injected: Vec<[f64; 2]> = (0..8)
            .map(|i| if i < 4 { [4.0, 0.25] } else { [0.25, 4.0] })
            .collect();
        let mut an = Analyzer::new();
        let mut octave = |s: &[f64]| {
            an.analyze(
                DevKind::Oadev,
                s,
                dt,
                &TauSpec::Octave,
                &AllanOptions::default(),
            )
        };
        let (mut whole, mut halves) = (Vec::new(), [Vec::new(), Vec::new()]);
        for (i, [a, b]) in injected.iter().enumerate() {
            let mut r = TestRng::new(70 + i as u64);
            let mut x = 0.0;
            let s: Vec<f64> = (0..n)
                .map(|_| {
                    x += rw * b.sqrt() * dt.sqrt() * r.normal();
                    white * a.sqrt() / dt.sqrt() * r.normal() + x
                })
                .collect();
            whole.push(octave(&s));
            halves[0].push(octave(&s[..n / 2]));
            halves[1].push(octave(&s[n / 2..]));
        }
        let typical = NoiseTerms {
            white,
            random_walk: rw,
            ..NoiseTerms::default()
        };
        let q = super::super::fit::levels(&whole).unwrap();
        let drift = vec![[0.0; 5]; 8];
        let sensors = Sensors {
            whole: &whole,
            halves: Some(&halves),
            drift: &drift,
        };
        let t = Typical {
            terms: &typical,
            tau0_s: dt,
            band: None,
        };
        let f = term_factors(&sensors, &q, &t).unwrap();
        for (i, (f, [a, b])) in f.iter().zip(&injected).enumerate() {
            assert!(
                (f[1] / a).ln().abs() < 0.1f64.ln_1p(),
                "{i}: white {} against {a}",
                f[1]
            );
            // A random walk of ¼ the typical's lies under 4× its white noise up to 70 s, the last octaves.
            let tol: f64 = if *b > 1.0 { 0.25 } else { 1.0 };
            assert!(
                (f[3] / b).ln().abs() < tol.ln_1p(),
                "{i}: random walk {} against {b}",
                f[3]
            );
            // The one factor cannot follow both: it is off by 2× or more on one of the two terms.
            assert!(
                (q[i] / a).max(a / q[i]).max((q[i] / b).max(b / q[i])) > 2.0,
                "{i}: q {}",
                q[i]
            );
        }
    }
}
