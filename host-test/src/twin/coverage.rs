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
//!
//! A 68 % interval misses about a third of the time by design, so "inside at every τ" is met by no model, the true
//! one included. What a model of exactly the fitted family scores is measured instead ([`check`]: a parametric
//! bootstrap): records of the record's length played from the fitted model, diagnosed and fitted the same way, and
//! their counts of τ outside their own intervals set beside the record's, with the Monte Carlo p-value
//! `(1 + #{replicas with as large a share outside}) / (N + 1)`.

use super::{ClusterModel, NoiseTerms, PlayOptions, TwinError};
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

/// A model's coverage over all its axes: τ outside the record's 68 % interval, and τ compared.
pub fn count(model: &ClusterModel) -> (usize, usize) {
    model
        .axes
        .iter()
        .filter_map(|a| a.coverage.as_ref())
        .fold((0, 0), |(o, n), c| {
            (o + c.outside_s.len(), n + c.taus_s.len())
        })
}

/// The fitted model's coverage beside what records of its own family score ([`check`]).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct FitCheck {
    /// The record's: τ outside its 68 % interval, and τ compared.
    pub record: (usize, usize),
    /// Each replica's (played from the model, diagnosed and fitted the same way; those the diagnosis or the fit
    /// refused are left out).
    pub replicas: Vec<(usize, usize)>,
    /// The Monte Carlo p-value: `(1 + #{replicas with a share of τ outside at least the record's}) / (N + 1)`;
    /// `None` without replicas.
    pub p_value: Option<f64>,
}

impl FitCheck {
    /// One line: the record's count, and with replicas their median and range and the p-value.
    pub fn summary(&self) -> String {
        let (o, n) = self.record;
        let mut r: Vec<usize> = self.replicas.iter().map(|x| x.0).collect();
        r.sort_unstable();
        let head = format!("outside the record's 68 % interval at {o} of {n} octave τ");
        match (r.first(), r.last(), self.p_value) {
            (Some(lo), Some(hi), Some(p)) => format!(
                "{head} (records played from the model and fitted the same way: median {}, range {lo}–{hi}, of {} \
                 replicas; p = {})",
                r[r.len() / 2],
                r.len(),
                crate::figures::sig3(p)
            ),
            _ => head,
        }
    }
}

/// [`FitCheck`] of `model`, fitted on a record diagnosed with `opts`: one replica per seed of `seeds`, each played
/// for the model's record length, diagnosed with `opts` and fitted as `model` was.
pub fn check(
    model: &ClusterModel,
    seeds: &[u64],
    opts: &crate::diagnose::Options,
) -> Result<FitCheck, TwinError> {
    use rayon::prelude::*;
    let record = count(model);
    // In parallel (the order of `seeds` kept): the replicas are independent.
    let played: Vec<Option<(usize, usize)>> = seeds
        .par_iter()
        .map(|&seed| -> Result<_, TwinError> {
            let rec = super::play(
                model,
                &PlayOptions {
                    seed,
                    ..Default::default()
                },
            )?;
            Ok(crate::diagnose::diagnose(&rec, opts)
                .ok()
                .and_then(|report| super::fit(&rec, &report, "replica").ok())
                .map(|m| count(&m)))
        })
        .collect::<Result<_, _>>()?;
    let replicas: Vec<(usize, usize)> = played.into_iter().flatten().collect();
    let p_value = p_value(record, &replicas);
    Ok(FitCheck {
        record,
        replicas,
        p_value,
    })
}

/// The Monte Carlo p-value of `record`'s share of τ outside among `replicas`' ([`FitCheck::p_value`]).
fn p_value(record: (usize, usize), replicas: &[(usize, usize)]) -> Option<f64> {
    let share = |(o, n): (usize, usize)| o as f64 / n.max(1) as f64;
    let at_least = replicas
        .iter()
        .filter(|&&r| share(r) >= share(record))
        .count();
    (!replicas.is_empty()).then(|| (1 + at_least) as f64 / (replicas.len() + 1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The p-value counts the replicas with at least the record's share of τ outside, the record itself included
    /// (`(1 + k)/(N + 1)`), by share, not by count; none without replicas.
    #[test]
    fn the_p_value_counts_replicas_at_least_as_far_out() {
        assert_eq!(p_value((5, 10), &[(4, 10), (5, 10), (6, 10)]), Some(0.75));
        assert_eq!(p_value((5, 10), &[(4, 10), (4, 10), (4, 10)]), Some(0.25));
        // 9 of 20 is a smaller share than 5 of 10.
        assert_eq!(p_value((5, 10), &[(9, 20)]), Some(0.5));
        assert_eq!(p_value((5, 10), &[]), None);
    }
}
