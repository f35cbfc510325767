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
    let mut best: Option<(f64, [f64; K])> = None;
    for mask in 1u32..(1 << K.min(8)) {
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

/// Fits the four terms to Allan-variance points (points without a finite deviation are skipped).
pub fn fit(points: &[AnalysisPoint]) -> NoiseFit {
    let rows: Vec<([f64; 4], f64, f64)> = points
        .iter()
        .filter(|p| p.dev.is_finite() && p.dev > 0.0 && p.tau_s > 0.0)
        .map(|p| {
            let y = p.dev * p.dev;
            let edf = p
                .edf
                .filter(|e| e.is_finite() && *e > 0.0)
                .unwrap_or(p.n.max(1) as f64);
            (basis(p.tau_s), y, edf / 2.0 / (y * y))
        })
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
}
