//! Full per-τ analysis: deviation + noise type + EDF + confidence interval.

use super::ci::{ONE_SIGMA_CI, chi2_quantiles, interval_from_quantiles};
use super::deviation::{DevKind, DevPoint, Phase, oadev_point};
use super::edf::edf_for_kind;
use super::noise::{AcfFlavor, NoiseId, noise_id_pyramid};
use super::overlap::{second_difference_sums, straddling_sums};
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
    /// The second half's phase in [`Analyzer::analyze_halves`] (`phase` holds the first's).
    second: Phase,
    /// The whole's phase in [`Analyzer::analyze_halves`] (for `overlap::straddling_sums`).
    whole: Phase,
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
        let ms = averaging_factors(taus, kind, y.len());
        let devs = self.phase.deviations(kind, &ms);
        self.identify(kind, y, ms, devs, opts)
    }

    /// The rest of [`Self::analyze`] once `self.phase` holds `y`'s phase and `devs` its deviations at the factors
    /// `ms`: the noise identification, EDF and interval of each point.
    fn identify(
        &mut self,
        kind: DevKind,
        y: &[f64],
        ms: Vec<usize>,
        devs: Vec<Option<DevPoint>>,
        opts: &Options,
    ) -> Vec<AnalysisPoint> {
        let n_samples = y.len();
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
        devs.into_iter().flatten().map(bare).collect()
    }

    /// The overlapping Allan deviations of a series and of its two halves from one call: the first half
    /// `y[..y.len() / 2]` analysed in full (as [`Self::analyze`] with [`DevKind::Oadev`] gives it, bit for bit), the
    /// second half `y[y.len() / 2..]` and the whole `y` as [`Self::deviations`] gives them, the second half bit for
    /// bit. Each half's sums of squared second differences are computed once, and the whole's are the halves' plus
    /// the terms that straddle the boundary (at most `2m − 1` at factor `m`), so the whole costs no pass of its own over
    /// the data. The whole's deviations differ from a direct [`Self::deviations`] by rounding only: the halves'
    /// phases are integrated from their own means and their terms summed apart. The unit tests bound the relative
    /// difference by 1e-12 on white noise (up to 545,410 samples) and random walks (up to 65,535); on longer random
    /// walks the direct computation's own error passes 1e-12, and this one stays as near the exact value. Bad input
    /// gives empty parts, as the direct calls would: a half with a non-finite value is empty, and so is the whole
    /// then.
    pub fn analyze_halves(
        &mut self,
        y: &[f64],
        tau0_s: f64,
        taus: &TauSpec,
        opts: &Options,
    ) -> Halves {
        let kind = DevKind::Oadev;
        let (first, second) = y.split_at(y.len() / 2);
        let ms_whole = averaging_factors(taus, kind, y.len());
        let ms_first = averaging_factors(taus, kind, first.len());
        let ms_second = averaging_factors(taus, kind, second.len());
        let mut ms: Vec<usize> = ms_whole
            .iter()
            .chain(&ms_first)
            .chain(&ms_second)
            .copied()
            .collect();
        ms.sort_unstable();
        ms.dedup();
        // The sum of a factor is the same, bit for bit, whatever other factors are summed with it.
        let ok2 = self.second.set_frequency(second, tau0_s);
        let s2 = match ok2 {
            true => second_difference_sums(self.second.as_slice(), &ms),
            false => Vec::new(),
        };
        let ok1 = self.phase.set_frequency(first, tau0_s);
        let s1 = match ok1 {
            true => second_difference_sums(self.phase.as_slice(), &ms),
            false => Vec::new(),
        };
        let at =
            |sums: &[f64], m: usize| ms.binary_search(&m).ok().and_then(|k| sums.get(k).copied());
        let whole = match ok1 && ok2 {
            true => {
                // The straddling terms from the whole's own phase (integrated at once, the direct computation's
                // points bit for bit). Joining the halves' phases instead puts a kink at the boundary in the drift
                // that rounding gives the phase of quantised data with a fractional mean: measured on 545,410 integer
                // samples, 1e-11 from the exact deviation at the largest factor where the direct one is within 6e-13.
                let across = match self.whole.set_frequency(y, tau0_s) {
                    true => straddling_sums(self.whole.as_slice(), first.len(), &ms_whole),
                    false => vec![f64::NAN; ms_whole.len()],
                };
                ms_whole
                    .iter()
                    .zip(across)
                    .filter_map(|(&m, s3)| {
                        let total = at(&s1, m)? + at(&s2, m)? + s3;
                        oadev_point(total, m, y.len(), tau0_s).map(bare)
                    })
                    .collect()
            }
            false => Vec::new(),
        };
        let second_pts = ms_second
            .iter()
            .filter_map(|&m| oadev_point(at(&s2, m)?, m, second.len(), tau0_s))
            .map(bare)
            .collect();
        let first_pts = match ok1 {
            true => {
                let devs = ms_first
                    .iter()
                    .map(|&m| at(&s1, m).and_then(|s| oadev_point(s, m, first.len(), tau0_s)))
                    .collect();
                self.identify(kind, first, ms_first, devs, opts)
            }
            false => Vec::new(),
        };
        Halves {
            first: first_pts,
            second: second_pts,
            whole,
        }
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

/// A deviation as an analysis point without noise type, EDF or interval.
fn bare(p: DevPoint) -> AnalysisPoint {
    AnalysisPoint {
        m: p.m,
        tau_s: p.tau_s,
        n: p.n,
        dev: p.dev,
        noise: None,
        edf: None,
        dev_lo: None,
        dev_hi: None,
    }
}

/// [`Analyzer::analyze_halves`]'s parts.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Halves {
    /// The first half `y[..y.len() / 2]`, analysed in full.
    pub first: Vec<AnalysisPoint>,
    /// The second half `y[y.len() / 2..]`: τ and deviations only.
    pub second: Vec<AnalysisPoint>,
    /// The whole `y`: τ and deviations only.
    pub whole: Vec<AnalysisPoint>,
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

    /// Every point's `(m, n, τ bits, deviation bits)`.
    fn dev_bits(p: &[AnalysisPoint]) -> Vec<(usize, usize, u64, u64)> {
        p.iter()
            .map(|p| (p.m, p.n, p.tau_s.to_bits(), p.dev.to_bits()))
            .collect()
    }

    /// [`Analyzer::analyze_halves`] against the direct calls: the halves bit for bit, the whole's τ and counts
    /// exactly; returns the whole's points and the direct ones.
    fn halves_and_direct(y: &[f64], taus: &TauSpec) -> (Vec<AnalysisPoint>, Vec<AnalysisPoint>) {
        let (o, tau0) = (Options::default(), 0.05);
        let got = Analyzer::new().analyze_halves(y, tau0, taus, &o);
        let mut direct = Analyzer::new();
        let (first, second) = y.split_at(y.len() / 2);
        let len = y.len();
        assert_eq!(
            got.first,
            direct.analyze(DevKind::Oadev, first, tau0, taus, &o),
            "len {len}"
        );
        let held = direct.deviations(DevKind::Oadev, second, tau0, taus);
        assert_eq!(dev_bits(&got.second), dev_bits(&held), "len {len}");
        let whole = direct.deviations(DevKind::Oadev, y, tau0, taus);
        assert_eq!(got.whole.len(), whole.len(), "len {len}");
        assert!(!whole.is_empty(), "len {len}");
        for (g, w) in got.whole.iter().zip(&whole) {
            assert_eq!((g.m, g.n, g.tau_s.to_bits()), (w.m, w.n, w.tau_s.to_bits()));
            assert!(g.noise.is_none() && g.edf.is_none() && g.dev_lo.is_none());
        }
        (got.whole, whole)
    }

    #[test]
    fn halves_are_the_direct_analyses_and_the_whole_differs_by_rounding() {
        let mut rng = crate::testrng::TestRng::new(17);
        let mut worst: f64 = 0.0;
        let mut compared = 0;
        for len in [3, 4, 5, 64, 301, 302, 4097, 10_000, 65_535, 545_410] {
            let white = rng.normals(len, 1.0);
            // A random walk with a large offset (as a gyro's bias) and white noise on top.
            let mut acc = 0.0;
            let walk: Vec<f64> = rng
                .normals(len, 1.0)
                .into_iter()
                .zip(&white)
                .map(|(v, w)| {
                    acc += v;
                    250.0 + acc + 0.1 * w
                })
                .collect();
            // Every factor on the short records (the halves without a term at the largest), octaves on the long ones
            // (up to the largest, whose terms all straddle the boundary).
            let taus = match len {
                ..1000 => TauSpec::All,
                _ => TauSpec::Octave,
            };
            // A random walk of more samples than this is beyond the direct computation's own precision (below).
            let series = match len {
                ..=65_535 => vec![&white, &walk],
                _ => vec![&white],
            };
            for y in series {
                let (got, direct) = halves_and_direct(y, &taus);
                for (g, w) in got.iter().zip(&direct) {
                    let rel = (g.dev - w.dev).abs() / w.dev;
                    assert!(rel <= 1e-12, "len {len}, m {}: {} vs {}", g.m, g.dev, w.dev);
                    worst = worst.max(rel);
                    compared += 1;
                }
            }
        }
        assert!(compared > 300, "{compared}");
        // The whole is not computed the direct way (or this test would prove nothing about the straddling terms).
        assert!(worst > 0.0, "{worst}");
    }

    /// The overlapping deviations of integer samples at `m`, with the sums of squared second differences in exact
    /// integer arithmetic (rounded once at the end).
    fn exact_oadev(y: &[i64], m: usize, tau0: f64) -> f64 {
        let mut p = vec![0i128; y.len() + 1];
        for (i, v) in y.iter().enumerate() {
            p[i + 1] = p[i] + i128::from(*v);
        }
        let terms = y.len() + 1 - 2 * m;
        let s: i128 = (0..terms)
            .map(|i| {
                let d = p[i + 2 * m] - 2 * p[i + m] + p[i];
                d * d
            })
            .sum();
        let tau = m as f64 * tau0;
        (s as f64 * tau0 * tau0 / (2.0 * terms as f64 * tau * tau)).sqrt()
    }

    #[test]
    fn halves_of_quantised_records_are_as_near_the_exact_deviations_as_the_direct_ones() {
        // ADC-like integer samples with an offset (a fractional mean, whose rounding drifts the phase alike at every
        // sample), the seed record's length; white noise, and a random walk whose phase is large enough that the
        // direct computation itself is off by ≈ 1e-11.
        let mut rng = crate::testrng::TestRng::new(23);
        for len in [65_535, 545_410] {
            for walk in [false, true] {
                let mut acc = 0;
                let yi: Vec<i64> = (0..len)
                    .map(|_| {
                        let v = (rng.normal() * 1000.0).round() as i64;
                        acc += v;
                        250_000 + v / 10 + if walk { acc } else { 10 * v }
                    })
                    .collect();
                let y: Vec<f64> = yi.iter().map(|&v| v as f64).collect();
                let (got, direct) = halves_and_direct(&y, &TauSpec::Octave);
                for (g, w) in got.iter().zip(&direct) {
                    let exact = exact_oadev(&yi, g.m, 0.05);
                    let (eg, ew) = ((g.dev - exact).abs() / exact, (w.dev - exact).abs() / exact);
                    assert!(
                        eg <= 1e-12 || eg <= ew,
                        "len {len}, walk {walk}, m {}: {eg:.2e} vs the direct's {ew:.2e}",
                        g.m
                    );
                }
            }
        }
    }

    #[test]
    fn halves_of_bad_input_are_empty_as_the_direct_calls() {
        let o = Options::default();
        let mut an = Analyzer::new();
        for len in 0..3 {
            let got = an.analyze_halves(&vec![1.0; len], 1.0, &TauSpec::Octave, &o);
            assert_eq!(got, Halves::default(), "len {len}");
        }
        let mut y = crate::testrng::TestRng::new(3).normals(1000, 1.0);
        y[700] = f64::NAN;
        let got = an.analyze_halves(&y, 1.0, &TauSpec::Octave, &o);
        assert!(got.second.is_empty() && got.whole.is_empty());
        let direct = analyze(DevKind::Oadev, &y[..500], 1.0, &TauSpec::Octave, &o);
        assert!(direct.len() >= 8);
        assert_eq!(got.first, direct);
        assert_eq!(
            an.analyze_halves(&y, 0.0, &TauSpec::Octave, &o),
            Halves::default()
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
