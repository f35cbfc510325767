//! The prediction models of the diagnosis: per-sensor noise models under independence, plus cross terms for the
//! correlation effects. Everything is an Allan variance, so a model of the weighted mean is exact:
//! `σ²(τ) = Σ w_i² σ_i²(τ) + Σ_{i≠j} w_i w_j C_ij(τ)`.

use crate::noisefit::NoiseFit;

/// A cross term between sensors.
#[derive(Clone, Debug)]
pub enum Cross {
    /// A process shared by `members` (indices into the axis's sensors): `C_ij(τ) = fit.avar(τ)` for i ≠ j both in
    /// `members`.
    Shared {
        /// Sensors that share it.
        members: Vec<usize>,
        /// Allan variance of the shared process.
        fit: NoiseFit,
    },
    /// Bias following temperature: sensor i adds `beta_i · T(t)`, so `C_ij(τ) = β_i β_j σ²_T(τ)`.
    Thermal {
        /// Coefficient per sensor, unit/°C.
        beta: Vec<f64>,
    },
}

/// The Allan variance of one sensor: a fitted noise model, or measured values at given τ.
#[derive(Clone, Debug)]
pub enum Single {
    /// The four-term model.
    Fit(NoiseFit),
    /// Measured (τ s, Allan variance) pairs; looked up at exactly these τ (NaN elsewhere).
    Table(Vec<(f64, f64)>),
}

impl Single {
    /// Allan variance at `tau_s`.
    pub fn avar(&self, tau_s: f64) -> f64 {
        match self {
            Single::Fit(f) => f.avar(tau_s),
            Single::Table(t) => t
                .iter()
                .find(|(x, _)| (x / tau_s - 1.0).abs() < 1e-9)
                .map_or(f64::NAN, |p| p.1),
        }
    }
}

/// A prediction model of one axis.
#[derive(Clone, Debug)]
pub struct Model {
    /// Allan variance of each sensor.
    pub singles: Vec<Single>,
    /// Cross terms.
    pub cross: Vec<Cross>,
}

impl Model {
    /// Allan variance of `Σ w_i y_i` at τ; `temp_avar` is the temperature's Allan variance at τ (°C²) when a
    /// thermal term is present.
    pub fn avar(&self, w: &[f64], tau_s: f64, temp_avar: Option<f64>) -> f64 {
        let mut v: f64 = self
            .singles
            .iter()
            .zip(w)
            .map(|(s, wi)| wi * wi * s.avar(tau_s))
            .sum();
        for c in &self.cross {
            match c {
                Cross::Shared { members, fit } => {
                    let s: f64 = members
                        .iter()
                        .map(|&i| w.get(i).copied().unwrap_or(0.0))
                        .sum();
                    let s2: f64 = members
                        .iter()
                        .map(|&i| w.get(i).copied().unwrap_or(0.0).powi(2))
                        .sum();
                    v += (s * s - s2) * fit.avar(tau_s);
                }
                Cross::Thermal { beta } => {
                    let s: f64 = beta.iter().zip(w).map(|(b, wi)| b * wi).sum();
                    let s2: f64 = beta.iter().zip(w).map(|(b, wi)| (b * wi).powi(2)).sum();
                    v += (s * s - s2) * temp_avar.unwrap_or(0.0);
                }
            }
        }
        v
    }
}
