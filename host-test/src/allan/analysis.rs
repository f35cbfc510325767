//! Full per-τ analysis: deviation + noise type + EDF + confidence interval.

use super::ci::{ONE_SIGMA_CI, chi2_quantiles, interval_from_quantiles};
use super::deviation::{DevKind, Phase};
use super::edf::edf_for_kind;
use super::noise::{AcfFlavor, NoiseId, noise_id_pyramid};
use super::taus::{TauSpec, averaging_factors};

/// Options of [`analyze`] / [`Analyzer::analyze`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Options {
    /// Two-sided confidence of the interval (default [`ONE_SIGMA_CI`] = 0.6827).
    pub confidence: f64,
    /// Lag-1 ACF variant (default [`AcfFlavor::Stable32`]).
    pub acf_flavor: AcfFlavor,
    /// Stable32's long-τ rule (default `true`): when `m · 2 · stop_ratio > N`
    /// (ADEV: fewer than 10 τ-intervals, OADEV/MDEV: fewer than 8), the noise type is not
    /// re-identified but copied from the previous τ of the list. If `false`, every τ is
    /// identified on its own.
    pub stable32_carry: bool,
    /// Use this α at every τ instead of identifying it.
    pub fixed_alpha: Option<i32>,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            confidence: ONE_SIGMA_CI,
            acf_flavor: AcfFlavor::Stable32,
            stable32_carry: true,
            fixed_alpha: None,
        }
    }
}

/// One row of an analysis (like a Stable32 output line).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnalysisPoint {
    /// Averaging factor (τ = m·τ0).
    pub m: usize,
    /// Averaging time τ in seconds.
    pub tau_s: f64,
    /// Number of terms of the estimator (Stable32 `#`).
    pub n: usize,
    /// Deviation, in the unit of `y`.
    pub dev: f64,
    /// Identified (or carried / fixed) noise type, if any.
    pub noise: Option<NoiseId>,
    /// Greenhall equivalent degrees of freedom, if the noise type is known and valid.
    pub edf: Option<f64>,
    /// Lower confidence bound of the deviation (unit of `y`).
    pub dev_lo: Option<f64>,
    /// Upper confidence bound of the deviation (unit of `y`).
    pub dev_hi: Option<f64>,
}

impl AnalysisPoint {
    /// The α used for the EDF (PSD exponent of `y`), if known.
    pub fn alpha(&self) -> Option<i32> {
        self.noise.map(|n| n.alpha)
    }
}

/// Reusable workspace: keeps the phase buffer and a scratch buffer between calls, so
/// analysing many equally long columns allocates only the output vectors.
#[derive(Clone, Debug, Default)]
pub struct Analyzer {
    phase: Phase,
    scratch: Vec<f64>,
    /// Block means of the current series at m = 2^k (level k), built pairwise as needed.
    pyramid: Vec<Vec<f64>>,
    /// The χ² quantiles of the intervals met so far, by the bits of (EDF, confidence): columns of one recording
    /// share their EDFs (an EDF depends on the noise type, `m` and `N` only), and each quantile is an iterative
    /// solution of the incomplete gamma function.
    /// At most [`QUANTILES_KEPT`] of them (`--taus all` on a long record has an EDF per factor).
    quantiles: std::collections::HashMap<(u64, u64), Option<(f64, f64)>>,
}

/// How many χ² quantile pairs an [`Analyzer`] keeps (octave τs: ≤ 5 noise types × ≈ 20 factors per length).
const QUANTILES_KEPT: usize = 1024;

impl Analyzer {
    /// New empty workspace.
    pub fn new() -> Self {
        Self::default()
    }

    /// Analyses frequency data `y` (interval `tau0_s` s) at the factors of `taus`
    /// (see [`averaging_factors`]): deviation, noise identification (ACF if at least 30
    /// τ-averages, else B1/R(n), long-τ carry per [`Options::stable32_carry`]),
    /// Greenhall EDF and confidence interval. Bad input gives an empty `Vec`.
    pub fn analyze(
        &mut self,
        kind: DevKind,
        y: &[f64],
        tau0_s: f64,
        taus: &TauSpec,
        opts: &Options,
    ) -> Vec<AnalysisPoint> {
        if !self.phase.set_frequency(y, tau0_s) {
            return Vec::new();
        }
        let n_samples = y.len();
        let ms = averaging_factors(taus, kind, n_samples);
        // Level k of the pyramid holds the means of blocks of 2^k samples (for the ACF noise identification).
        let top = ms
            .iter()
            .filter(|m| m.is_power_of_two())
            .map(|m| m.trailing_zeros() as usize)
            .max();
        // Level 0 is `y` itself and stays empty here (the noise identification falls back to `y`).
        self.pyramid.resize_with(top.map_or(0, |t| t + 1), Vec::new);
        for k in 0..self.pyramid.len() {
            let (lower, upper) = self.pyramid.split_at_mut(k);
            let level = &mut upper[0];
            level.clear();
            let prev = match (k, lower.last()) {
                (0, _) | (_, None) => continue,
                (1, _) => y,
                (_, Some(prev)) => prev.as_slice(),
            };
            pair_means(prev, level);
        }
        let carry_limit = 2 * kind.stable32_stop_ratio();
        let mut out = Vec::with_capacity(ms.len());
        let mut prev_alpha: Option<i32> = None;
        let devs = self.phase.deviations(kind, &ms);
        for (m, dev) in ms.into_iter().zip(devs) {
            let Some(p) = dev else {
                continue;
            };
            let noise = match opts.fixed_alpha {
                Some(a) => Some(NoiseId::fixed(a)),
                None => {
                    let long_tau = opts.stable32_carry && m.saturating_mul(carry_limit) > n_samples;
                    match prev_alpha {
                        Some(a) if long_tau => Some(NoiseId::carried(a)),
                        _ => noise_id_pyramid(
                            kind,
                            y,
                            &self.phase,
                            m,
                            opts.acf_flavor,
                            &mut self.scratch,
                            &self.pyramid,
                        )
                        .or_else(|| prev_alpha.map(NoiseId::carried)),
                    }
                }
            };
            if let Some(nz) = noise {
                prev_alpha = Some(nz.alpha);
            }
            let edf = noise.and_then(|nz| edf_for_kind(kind, nz.alpha, m, n_samples));
            let ci = edf.and_then(|e| {
                let q = self.quantiles(e, opts.confidence)?;
                interval_from_quantiles(p.dev, e, q)
            });
            out.push(AnalysisPoint {
                m,
                tau_s: p.tau_s,
                n: p.n,
                dev: p.dev,
                noise,
                edf,
                dev_lo: ci.map(|c| c.0),
                dev_hi: ci.map(|c| c.1),
            });
        }
        out
    }
}

impl Analyzer {
    /// [`Self::analyze`]'s points without the noise identification, EDF and interval (`noise`, `edf`, `dev_lo`,
    /// `dev_hi` are `None`): the same τ and deviations, bit for bit, at about half the cost, for callers that read
    /// nothing else.
    pub fn deviations(
        &mut self,
        kind: DevKind,
        y: &[f64],
        tau0_s: f64,
        taus: &TauSpec,
    ) -> Vec<AnalysisPoint> {
        if !self.phase.set_frequency(y, tau0_s) {
            return Vec::new();
        }
        let ms = averaging_factors(taus, kind, y.len());
        let devs = self.phase.deviations(kind, &ms);
        ms.into_iter()
            .zip(devs)
            .filter_map(|(m, d)| {
                d.map(|p| AnalysisPoint {
                    m,
                    tau_s: p.tau_s,
                    n: p.n,
                    dev: p.dev,
                    noise: None,
                    edf: None,
                    dev_lo: None,
                    dev_hi: None,
                })
            })
            .collect()
    }

    /// [`chi2_quantiles`], kept for the next series.
    fn quantiles(&mut self, edf: f64, confidence: f64) -> Option<(f64, f64)> {
        let key = (edf.to_bits(), confidence.to_bits());
        if let Some(q) = self.quantiles.get(&key) {
            return *q;
        }
        let q = chi2_quantiles(edf, confidence);
        if self.quantiles.len() < QUANTILES_KEPT {
            self.quantiles.insert(key, q);
        }
        q
    }
}

/// Appends to `out` the means of the pairs of `prev` (an odd last value dropped). Compiled also for AVX2 and chosen
/// at run time (the same operations: the same bits).
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn pair_means(prev: &[f64], out: &mut Vec<f64>) {
    out.extend(prev.chunks_exact(2).map(|p| 0.5 * (p[0] + p[1])));
}

/// One-shot [`Analyzer::analyze`].
pub fn analyze(
    kind: DevKind,
    y: &[f64],
    tau0_s: f64,
    taus: &TauSpec,
    opts: &Options,
) -> Vec<AnalysisPoint> {
    Analyzer::new().analyze(kind, y, tau0_s, taus, opts)
}

#[cfg(test)]
mod tests {
    use super::super::ci::confidence_interval;
    use super::*;

    #[test]
    fn empty_and_bad_input() {
        let o = Options::default();
        assert!(analyze(DevKind::Oadev, &[], 1.0, &TauSpec::Octave, &o).is_empty());
        assert!(analyze(DevKind::Oadev, &[1.0, 2.0], 1.0, &TauSpec::Octave, &o).is_empty());
        assert!(analyze(DevKind::Adev, &[1.0; 10], -1.0, &TauSpec::All, &o).is_empty());
        let huge = TauSpec::Factors(vec![1_000_000]);
        assert!(analyze(DevKind::Mdev, &[1.0, 2.0, 4.0, 3.0, 5.0], 1.0, &huge, &o).is_empty());
    }

    #[test]
    fn deviations_only_are_the_analysis_deviations() {
        // A random walk plus white noise, octave and all-τ lists, both kinds with a noise identification.
        let mut rng = crate::testrng::TestRng::new(5);
        let mut acc = 0.0;
        let y: Vec<f64> = rng
            .normals(5000, 1.0)
            .into_iter()
            .map(|v| {
                acc += 0.01 * v;
                acc + v
            })
            .collect();
        let mut an = Analyzer::new();
        for (kind, taus) in [
            (DevKind::Oadev, TauSpec::Octave),
            (DevKind::Mdev, TauSpec::Octave),
            (DevKind::Adev, TauSpec::All),
        ] {
            let full = an.analyze(kind, &y, 0.1, &taus, &Options::default());
            let devs = an.deviations(kind, &y, 0.1, &taus);
            assert!(full.len() > 5, "{kind:?}");
            assert_eq!(full.len(), devs.len(), "{kind:?}");
            for (f, d) in full.iter().zip(&devs) {
                assert_eq!((f.m, f.n), (d.m, d.n));
                assert_eq!(f.dev.to_bits(), d.dev.to_bits());
                assert_eq!(f.tau_s.to_bits(), d.tau_s.to_bits());
                assert!(f.edf.is_some() && d.edf.is_none() && d.noise.is_none());
            }
        }
        assert!(
            an.deviations(DevKind::Oadev, &[1.0], 1.0, &TauSpec::Octave)
                .is_empty()
        );
    }

    #[test]
    fn constant_data_has_zero_dev_and_no_noise_id() {
        let y = vec![3.0; 200];
        let pts = analyze(
            DevKind::Oadev,
            &y,
            1.0,
            &TauSpec::Octave,
            &Options::default(),
        );
        assert!(!pts.is_empty());
        for p in pts {
            assert_eq!(p.dev, 0.0);
            assert!(p.noise.is_none() && p.edf.is_none() && p.dev_lo.is_none());
        }
    }

    #[test]
    fn a_reused_analyzer_gives_the_same_bits_as_fresh_ones() {
        // Two series of the same length (the second re-uses the first's kept quantiles), then one of another length.
        let series: Vec<Vec<f64>> = [(5000, 1), (5000, 2), (3001, 3)]
            .into_iter()
            .map(|(n, seed)| crate::testrng::TestRng::new(seed).normals(n, 1.0))
            .collect();
        let o = Options::default();
        let mut reused = Analyzer::new();
        for y in &series {
            let again = reused.analyze(DevKind::Oadev, y, 0.1, &TauSpec::Octave, &o);
            let fresh = analyze(DevKind::Oadev, y, 0.1, &TauSpec::Octave, &o);
            let bits = |p: &[AnalysisPoint]| -> Vec<_> {
                p.iter()
                    .map(|p| {
                        (
                            p.m,
                            p.dev.to_bits(),
                            p.edf.map(f64::to_bits),
                            p.dev_lo.map(f64::to_bits),
                            p.dev_hi.map(f64::to_bits),
                        )
                    })
                    .collect()
            };
            assert_eq!(bits(&again), bits(&fresh));
            assert!(fresh.iter().filter(|p| p.dev_lo.is_some()).count() >= 8);
            // The intervals are those of the public one-shot function.
            for p in &fresh {
                let ci = p
                    .edf
                    .and_then(|e| confidence_interval(p.dev, e, o.confidence));
                assert_eq!(ci, p.dev_lo.zip(p.dev_hi));
            }
        }
        assert!(!reused.quantiles.is_empty());
    }

    #[test]
    fn fixed_alpha_gives_intervals() {
        let y: Vec<f64> = (0..1000).map(|i| ((i * 37 % 101) as f64).sin()).collect();
        let o = Options {
            fixed_alpha: Some(0),
            ..Options::default()
        };
        let pts = analyze(DevKind::Mdev, &y, 0.5, &TauSpec::Decade, &o);
        assert!(
            pts.iter()
                .all(|p| p.dev_lo.unwrap() < p.dev && p.dev < p.dev_hi.unwrap())
        );
        assert_eq!(pts[3].tau_s, 5.0);
    }
}
