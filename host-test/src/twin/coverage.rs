//! Does the fitted noise model follow the record? (issue 40, item 1.) At every octave τ of an axis, the model's
//! Allan deviation of the mean sensor — the mean over the axis's sensors of each one's own terms (its independent
//! terms plus the processes it shares), through the axis's bandwidth — against the record's: the mean over the
//! sensors of their overlapping Allan variance, the series as the fit saw them (thermal part, steps, sinusoids and
//! a warm-up taken out), with its 68 % interval: χ² at the Satterthwaite EDF of the sum,
//! `ν = (Σ aᵢ)² / Σ (aᵢ²/νᵢ)` (each sensor's Greenhall EDF νᵢ, the sensors' estimates independent).
//!
//! Computed by [`super::fit()`] on the record it fits (the empirical interval is that of the very record, so a miss
//! is a shape the terms cannot follow, not a held-out error) and kept in [`super::AxisModel::coverage`]; it is not
//! written to the model file.

use super::NoiseTerms;
use crate::allan::noisefit::LowPass;
use crate::allan::{AnalysisPoint, ONE_SIGMA_CI, confidence_interval};
use serde::Serialize;

/// One axis's model against its record's 68 % intervals.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Coverage {
    /// Octave τ compared, s.
    pub taus_s: Vec<f64>,
    /// The τ where the model's deviation lies outside the record's 68 % interval, s.
    pub outside_s: Vec<f64>,
    /// The largest miss, `ln(model/record)` over the interval's half-width on that side (≤ 1 inside).
    pub worst: f64,
}

impl Coverage {
    /// `k of n τ inside`, and the τ outside.
    pub fn summary(&self) -> String {
        let n = self.taus_s.len();
        let inside = n - self.outside_s.len();
        if self.outside_s.is_empty() {
            return format!("inside the 68 % interval at {inside} of {n} τ");
        }
        let outside: Vec<String> = self
            .outside_s
            .iter()
            .map(|t| crate::figures::sig3(*t))
            .collect();
        format!(
            "inside the 68 % interval at {inside} of {n} τ; outside at {} s (worst {}× the half-width)",
            outside.join(", "),
            crate::figures::sig3(self.worst)
        )
    }
}

/// The coverage of `own` (each sensor's whole terms) on `points` (each sensor's octave points of its series).
pub fn coverage(
    points: &[Vec<AnalysisPoint>],
    own: &[NoiseTerms],
    tau0_s: f64,
    band: Option<&LowPass>,
) -> Coverage {
    let k = points.iter().map(Vec::len).min().unwrap_or(0);
    let mut c = Coverage::default();
    for j in 0..k {
        let at: Vec<&AnalysisPoint> = points.iter().filter_map(|p| p.get(j)).collect();
        let Some(tau) = at.first().map(|p| p.tau_s) else {
            continue;
        };
        let Some((mean, nu)) = pooled(&at) else {
            continue;
        };
        let n = at.len() as f64;
        let record = mean.sqrt();
        let Some((lo, hi)) = confidence_interval(record, nu, ONE_SIGMA_CI) else {
            continue;
        };
        let model = (own.iter().map(|t| t.avar(tau, tau0_s, band)).sum::<f64>() / n).sqrt();
        let miss = if model < record {
            (model / record).ln() / (lo / record).ln()
        } else {
            (model / record).ln() / (hi / record).ln()
        };
        c.taus_s.push(tau);
        if !(lo..=hi).contains(&model) {
            c.outside_s.push(tau);
        }
        c.worst = c.worst.max(miss);
    }
    c
}

/// The sensors' mean Allan variance at one τ (`at`: each sensor's point there) and its Satterthwaite EDF
/// `ν = (Σ aᵢ)² / Σ (aᵢ²/νᵢ)` (each sensor's Greenhall EDF νᵢ, the sensors' estimates independent); `None` when the
/// points give no positive variance.
pub fn pooled(at: &[&AnalysisPoint]) -> Option<(f64, f64)> {
    let a: Vec<f64> = at.iter().map(|p| p.dev * p.dev).collect();
    let sum: f64 = a.iter().sum();
    let var_terms: f64 = at
        .iter()
        .zip(&a)
        .map(|(p, a)| a * a / super::terms_fit::edf(p))
        .sum();
    (sum > 0.0 && var_terms > 0.0 && sum.is_finite())
        .then(|| (sum / a.len() as f64, sum * sum / var_terms))
}
