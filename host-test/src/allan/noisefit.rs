//! Noise-term fit of an Allan variance curve (IEEE Std 952 / 1293 model):
//!
//! `σ²(τ) = 3Q²/τ² + N²/τ + (2 ln2/π)·B² + K²·τ/3`
//!
//! Q quantisation (unit·s), N white noise / angle or velocity random walk (unit/√Hz), B bias instability (unit; the
//! ADEV floor of pure flicker noise is 0.664·B), K rate random walk (unit·√Hz = unit/√s). "unit" is the unit of the
//! data (°/s or g). The four coefficients are fitted non-negative by weighted least squares on σ²: each point weighs
//! by its equivalent degrees of freedom over σ⁴ (the relative variance of an Allan variance estimate is 2/edf), and
//! every subset of terms is solved, keeping the best fit whose coefficients are all positive (exact NNLS for four
//! unknowns).

use crate::allan::AnalysisPoint;
use serde::Serialize;

/// 2 ln 2 / π: flicker floor of the Allan variance per B².
pub const FLICKER_AVAR: f64 = 2.0 * std::f64::consts::LN_2 / std::f64::consts::PI;

/// Fitted noise terms (0 where a term is absent). Units: see module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct NoiseFit {
    /// Quantisation Q, unit·s.
    pub quantization: f64,
    /// White noise N, unit/√Hz (ARW for gyros, VRW for accelerometers).
    pub white: f64,
    /// Bias instability B, unit.
    pub bias_instability: f64,
    /// Rate random walk K, unit/√s.
    pub random_walk: f64,
    /// Relative RMS misfit of the Allan *deviation* over the fitted points.
    pub rel_rms_misfit: f64,
}

impl NoiseFit {
    /// The model's Allan variance at `tau_s`.
    pub fn avar(&self, tau_s: f64) -> f64 {
        3.0 * self.quantization.powi(2) / (tau_s * tau_s)
            + self.white.powi(2) / tau_s
            + FLICKER_AVAR * self.bias_instability.powi(2)
            + self.random_walk.powi(2) * tau_s / 3.0
    }
}

fn basis(tau: f64) -> [f64; 4] {
    [1.0 / (tau * tau), 1.0 / tau, 1.0, tau]
}

/// Solves the weighted least squares on the terms in `mask`; `None` if singular.
/// Weighted least squares on the basis functions whose bit is set in `mask` (the others get 0): rows are (basis
/// values, observation, weight); `None` if the normal equations are singular.
pub fn solve<const K: usize>(rows: &[([f64; K], f64, f64)], mask: u32) -> Option<[f64; K]> {
    let idx: Vec<usize> = (0..K).filter(|i| mask & (1 << i) != 0).collect();
    let k = idx.len();
    let mut a = vec![vec![0.0; k + 1]; k];
    for (phi, y, w) in rows {
        for (r, &i) in idx.iter().enumerate() {
            for (c, &j) in idx.iter().enumerate() {
                a[r][c] += w * phi[i] * phi[j];
            }
            a[r][k] += w * phi[i] * y;
        }
    }
    // Gaussian elimination with partial pivoting.
    for col in 0..k {
        let piv = (col..k).max_by(|&x, &y| a[x][col].abs().total_cmp(&a[y][col].abs()))?;
        if a[piv][col].abs() < 1e-300 {
            return None;
        }
        a.swap(col, piv);
        let pivot_row = a[col].clone();
        for (r, row) in a.iter_mut().enumerate() {
            if r != col {
                let f = row[col] / pivot_row[col];
                for (x, p) in row.iter_mut().zip(&pivot_row).skip(col) {
                    *x -= f * p;
                }
            }
        }
    }
    let mut x = [0.0; K];
    for (r, &i) in idx.iter().enumerate() {
        x[i] = a[r][k] / a[r][r];
    }
    Some(x)
}

/// Non-negative weighted least squares for `K` ≤ 8 basis functions: rows are (basis values, observation, weight);
/// every subset of terms is solved and the cheapest all-non-negative solution kept (exact NNLS for a few terms).
/// `None` if no subset is solvable (no rows, or all-zero bases).
pub fn nnls<const K: usize>(rows: &[([f64; K], f64, f64)]) -> Option<[f64; K]> {
    nnls_first(rows, K.min(8))
}

/// [`nnls`] on the first `used` (≤ 10) basis functions of the rows (the others get 0): one row type serves fits
/// of different sizes at the cost of the size in use.
pub fn nnls_first<const K: usize>(rows: &[([f64; K], f64, f64)], used: usize) -> Option<[f64; K]> {
    let mut best: Option<(f64, [f64; K])> = None;
    for mask in 1u32..(1 << used.min(K).min(10)) {
        let Some(c) = solve(rows, mask) else {
            continue;
        };
        if c.iter().any(|&v| v < 0.0 || !v.is_finite()) {
            continue;
        }
        let cost: f64 = rows
            .iter()
            .map(|(phi, y, w)| {
                let m: f64 = phi.iter().zip(&c).map(|(p, c)| p * c).sum();
                w * (m - y).powi(2)
            })
            .sum();
        if best.is_none_or(|(b, _)| cost < b) {
            best = Some((cost, c));
        }
    }
    best.map(|(_, c)| c)
}

/// The points with a finite deviation as (τ, Allan variance y, weight): the weight is the inverse variance of y,
/// `ν/(2y²)` at the point's EDF ν (its block count where it has none).
fn weighted_rows(points: &[AnalysisPoint]) -> impl Iterator<Item = (f64, f64, f64)> + '_ {
    points
        .iter()
        .filter(|p| p.dev.is_finite() && p.dev > 0.0 && p.tau_s > 0.0)
        .map(|p| {
            let y = p.dev * p.dev;
            let edf = p
                .edf
                .filter(|e| e.is_finite() && *e > 0.0)
                .unwrap_or(p.n.max(1) as f64);
            (p.tau_s, y, edf / 2.0 / (y * y))
        })
}

/// Fits the four terms to Allan-variance points (points without a finite deviation are skipped).
pub fn fit(points: &[AnalysisPoint]) -> NoiseFit {
    let rows: Vec<([f64; 4], f64, f64)> = weighted_rows(points)
        .map(|(tau, y, w)| (basis(tau), y, w))
        .collect();
    let Some(c) = nnls(&rows) else {
        return NoiseFit::default();
    };
    let mut f = NoiseFit {
        quantization: (c[0] / 3.0).sqrt(),
        white: c[1].sqrt(),
        bias_instability: (c[2] / FLICKER_AVAR).sqrt(),
        random_walk: (3.0 * c[3]).sqrt(),
        rel_rms_misfit: 0.0,
    };
    let misfit: Vec<f64> = rows
        .iter()
        .map(|(phi, y, _)| {
            ((phi[0] * c[0] + phi[1] * c[1] + phi[2] * c[2] + phi[3] * c[3]) / y).sqrt() - 1.0
        })
        .collect();
    f.rel_rms_misfit =
        (misfit.iter().map(|e| e * e).sum::<f64>() / misfit.len().max(1) as f64).sqrt();
    f
}

/// A single-pole low-pass response (a sensor's bandwidth) on a record sampled every `tau0_s`: the sampled
/// first-order filter `y_k = φ·y_{k−1} + (1 − φ)·u_k`, `φ = exp(−2π f_c τ₀)` (unit gain at DC), the exact sampled
/// equivalent of a continuous pole at `f_c` (time constant `T_c = 1/(2π f_c)`) seen at the sampling instants.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LowPass {
    /// Cut-off f_c, Hz.
    pub cutoff_hz: f64,
    /// Sample interval τ₀, s.
    pub tau0_s: f64,
}

impl LowPass {
    /// The pole φ of the sampled filter, in [0, 1) (0 for a cut-off that is not positive and finite: no filter).
    pub fn pole(&self) -> f64 {
        let x = 2.0 * std::f64::consts::PI * self.cutoff_hz * self.tau0_s;
        if x.is_finite() && x > 0.0 {
            (-x).exp()
        } else {
            0.0
        }
    }

    /// The factor the filter applies to the Allan variance `N²/τ` of white noise at `τ = mτ₀`:
    ///
    /// `W(m) = 1 − φ(3 − 4φ^m + φ^{2m}) / (m(1 − φ²))`.
    ///
    /// Derivation: the filtered white noise is AR(1) with autocovariance `R(k) = R(0)·φ^|k|`,
    /// `R(0) = σ_u²(1 − φ)/(1 + φ)`. The variance of a sum of m samples is
    /// `V(m) = R(0)[m(1 + φ)/(1 − φ) − 2φ(1 − φ^m)/(1 − φ)²]`, two adjacent sums differ with variance
    /// `4V(m) − V(2m)`, and the Allan variance is that over `2m²`; with `σ_u²τ₀ = N²` this is `W(m)·N²/τ`.
    /// The continuous limit is `1 − (T_c/2τ)(3 − 4e^{−τ/T_c} + e^{−2τ/T_c})`; `W → 1` for `τ ≫ T_c`.
    pub fn white_factor(&self, tau_s: f64) -> f64 {
        let phi = self.pole();
        if phi <= 0.0 {
            return 1.0;
        }
        let m = (tau_s / self.tau0_s).round().max(1.0);
        let pm = phi.powf(m);
        (1.0 - phi * (3.0 - 4.0 * pm + pm * pm) / (m * (1.0 - phi * phi))).clamp(0.0, 1.0)
    }

    /// One sample through the filter of pole `phi`: `y = φ·state + (1 − φ)·x`, the state then `y`; the first
    /// sample (no state yet) passes unchanged, as if the filter had settled on it.
    pub fn step(phi: f64, state: &mut Option<f64>, x: f64) -> f64 {
        let y = state.map_or(x, |prev| phi * prev + (1.0 - phi) * x);
        *state = Some(y);
        y
    }

    /// `v` through the filter, in place ([`Self::step`] from a settled start).
    pub fn filter(&self, v: &mut [f64]) {
        let (phi, mut state) = (self.pole(), None);
        v.iter_mut()
            .for_each(|x| *x = Self::step(phi, &mut state, *x));
    }
}

/// Fewest χ² units (the fit's weighted cost) a low-pass response must gain over the four terms alone to be kept: a
/// fifth free parameter lowers the cost by about one on noise alone.
const BANDWIDTH_MIN_GAIN: f64 = 10.0;

/// Cut-offs tried, from the Nyquist frequency down, 40 per decade, over three decades.
const BANDWIDTH_GRID: usize = 120;

/// The four terms with a single-pole low-pass response on the white term (`N²/τ · W(τ)`, [`LowPass::white_factor`]):
/// the cut-off is searched on a grid of 40 per decade from the Nyquist frequency `1/(2τ₀)` down three decades, each
/// with the exact non-negative four-term fit, and kept (`Some`) when it lowers the weighted cost by at least
/// `BANDWIDTH_MIN_GAIN` against [`fit`]; otherwise the plain fit and `None`. The misfit is reported as in [`fit`].
pub fn fit_band_limited(points: &[AnalysisPoint], tau0_s: f64) -> (NoiseFit, Option<LowPass>) {
    let plain = fit(points);
    if !(tau0_s.is_finite() && tau0_s > 0.0) {
        return (plain, None);
    }
    let rows: Vec<(f64, f64, f64)> = weighted_rows(points).collect();
    let solve_with = |lp: Option<LowPass>| -> Option<(f64, [f64; 4])> {
        let r: Vec<([f64; 4], f64, f64)> = rows
            .iter()
            .map(|&(tau, y, w)| {
                let mut b = basis(tau);
                if let Some(l) = lp {
                    b[1] *= l.white_factor(tau);
                }
                (b, y, w)
            })
            .collect();
        let c = nnls(&r)?;
        let cost = r
            .iter()
            .map(|(b, y, w)| w * (b.iter().zip(&c).map(|(p, c)| p * c).sum::<f64>() - y).powi(2))
            .sum();
        Some((cost, c))
    };
    let Some((cost0, _)) = solve_with(None) else {
        return (plain, None);
    };
    let nyquist = 0.5 / tau0_s;
    let mut best: Option<(f64, [f64; 4], LowPass)> = None;
    for k in 0..=BANDWIDTH_GRID {
        let lp = LowPass {
            cutoff_hz: nyquist * 10f64.powf(-(k as f64) / 40.0),
            tau0_s,
        };
        if let Some((cost, c)) = solve_with(Some(lp))
            && best.as_ref().is_none_or(|b| cost < b.0)
        {
            best = Some((cost, c, lp));
        }
    }
    let Some((_, c, lp)) = best.filter(|b| b.0 + BANDWIDTH_MIN_GAIN < cost0) else {
        return (plain, None);
    };
    let misfit: Vec<f64> = rows
        .iter()
        .map(|&(tau, y, _)| {
            let b = basis(tau);
            let m = b[0] * c[0] + b[1] * lp.white_factor(tau) * c[1] + b[2] * c[2] + b[3] * c[3];
            (m / y).sqrt() - 1.0
        })
        .collect();
    let f = NoiseFit {
        quantization: (c[0] / 3.0).sqrt(),
        white: c[1].sqrt(),
        bias_instability: (c[2] / FLICKER_AVAR).sqrt(),
        random_walk: (3.0 * c[3]).sqrt(),
        rel_rms_misfit: (misfit.iter().map(|e| e * e).sum::<f64>() / misfit.len().max(1) as f64)
            .sqrt(),
    };
    (f, Some(lp))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn points(model: &NoiseFit) -> Vec<AnalysisPoint> {
        (0..20)
            .map(|k| {
                let tau = 0.01 * 2f64.powi(k);
                AnalysisPoint {
                    m: 1 << k,
                    tau_s: tau,
                    n: 1000,
                    dev: model.avar(tau).sqrt(),
                    noise: None,
                    edf: Some(100.0),
                    dev_lo: None,
                    dev_hi: None,
                }
            })
            .collect()
    }

    #[test]
    fn recovers_exact_terms() {
        let truth = NoiseFit {
            quantization: 1e-4,
            white: 0.01,
            bias_instability: 0.002,
            random_walk: 1e-4,
            rel_rms_misfit: 0.0,
        };
        let f = fit(&points(&truth));
        for (got, want) in [
            (f.quantization, 1e-4),
            (f.white, 0.01),
            (f.bias_instability, 0.002),
            (f.random_walk, 1e-4),
        ] {
            assert!((got / want - 1.0).abs() < 1e-6, "{got} vs {want}");
        }
        assert!(f.rel_rms_misfit < 1e-9);
    }

    #[test]
    fn absent_terms_are_zero_not_negative() {
        let truth = NoiseFit {
            white: 0.05,
            ..Default::default()
        };
        let f = fit(&points(&truth));
        assert!((f.white / 0.05 - 1.0).abs() < 1e-9);
        assert_eq!(
            (f.quantization, f.bias_instability, f.random_walk),
            (0.0, 0.0, 0.0)
        );
        assert_eq!(fit(&[]), NoiseFit::default());
    }

    /// Seeded normal draws, for the filtered-noise check.
    fn gauss(seed: u64) -> impl FnMut() -> f64 {
        let mut rng = crate::testrng::TestRng::new(seed);
        move || rng.normal()
    }

    #[test]
    fn low_pass_white_factor_matches_the_librarys_estimator_on_filtered_noise() {
        // Independent reference: white noise through the sampled pole, measured with the library's overlapping
        // estimator. 2^21 samples: the OADEV's relative sd is ≤ 0.3 % up to m = 64 and 1.2 % at m = 1024.
        let (tau0, fc, n) = (0.016, 5.0, 1usize << 21);
        let lp = LowPass {
            cutoff_hz: fc,
            tau0_s: tau0,
        };
        let phi = lp.pole();
        let mut g = gauss(20_261_126);
        let sigma_u = 0.3;
        let mut y = Vec::with_capacity(n);
        let mut state = sigma_u * g() * ((1.0 - phi) / (1.0 + phi)).sqrt();
        for _ in 0..n {
            state = phi * state + (1.0 - phi) * sigma_u * g();
            y.push(state);
        }
        let ms = [1usize, 2, 4, 8, 16, 64, 256, 1024];
        let pts = crate::allan::deviation(crate::allan::DevKind::Oadev, &y, tau0, &ms);
        assert_eq!(pts.len(), ms.len());
        let n2 = sigma_u * sigma_u * tau0;
        for p in &pts {
            let model = n2 / p.tau_s * lp.white_factor(p.tau_s);
            let measured = p.dev * p.dev;
            // 4 sd of an OADEV with ~n/m·(3/2) differences (white-ish at these m), in variance.
            let tol = 4.0 * 2.0 * (p.m as f64 / (1.5 * n as f64)).sqrt();
            assert!(
                (measured / model - 1.0).abs() < tol,
                "m {}: measured {measured:e} vs closed form {model:e} (tol {tol})",
                p.m
            );
        }
        // The filter matters where it should: at m = 1 the factor is far below 1 (≈ 0.41 at fc·τ0 = 0.08) …
        assert!(lp.white_factor(tau0) < 0.6, "{}", lp.white_factor(tau0));
        // … and the continuous limit holds for τ0 → 0.
        let fine = LowPass {
            cutoff_hz: fc,
            tau0_s: 1e-6,
        };
        let (tc, tau) = (1.0 / (2.0 * std::f64::consts::PI * fc), 0.05);
        let cont =
            1.0 - tc / (2.0 * tau) * (3.0 - 4.0 * (-tau / tc).exp() + (-2.0 * tau / tc).exp());
        assert!((fine.white_factor(tau) - cont).abs() < 1e-4);
        assert_eq!(
            LowPass {
                cutoff_hz: 0.0,
                tau0_s: tau0
            }
            .white_factor(tau0),
            1.0
        );
    }

    #[test]
    fn band_limited_fit_recovers_the_cut_off_and_leaves_white_noise_alone() {
        let tau0 = 0.016;
        let pts = |lp: Option<LowPass>| -> Vec<AnalysisPoint> {
            (0..10)
                .map(|k| {
                    let tau = tau0 * 2f64.powi(k);
                    let w = lp.map_or(1.0, |l| l.white_factor(tau));
                    AnalysisPoint {
                        m: 1 << k,
                        tau_s: tau,
                        n: 1000,
                        dev: (0.01 / tau * w + 1e-6).sqrt(),
                        noise: None,
                        edf: Some(200.0),
                        dev_lo: None,
                        dev_hi: None,
                    }
                })
                .collect()
        };
        let truth = LowPass {
            cutoff_hz: 4.2,
            tau0_s: tau0,
        };
        let (f, lp) = fit_band_limited(&pts(Some(truth)), tau0);
        let lp = lp.expect("a cut-off");
        // The grid has 40 steps per decade (±2.9 % at most).
        assert!((lp.cutoff_hz / 4.2 - 1.0).abs() < 0.03, "{lp:?}");
        assert!((f.white / 0.1 - 1.0).abs() < 0.03, "{f:?}");
        assert!(f.rel_rms_misfit < 0.01, "{f:?}");
        let (_, none) = fit_band_limited(&pts(None), tau0);
        assert!(none.is_none(), "{none:?}");
    }
}
