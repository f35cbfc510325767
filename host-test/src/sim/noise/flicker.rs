//! Flicker noise from first-order Gauss–Markov sections: the band of correlation times and how it is synthesised
//! (see *Flicker synthesis* in the parent module).

use super::{FLICKER_AVAR_PER_B2, ar1_avar};
use crate::sim::{SimError, check};
use std::f64::consts::{LN_10, PI};

/// How flicker noise is synthesised from first-order Gauss–Markov (AR(1)) sections.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FlickerMethod {
    /// A cascade of first-order pole–zero sections (poles at `1/T_i`, a zero at `√r/T_i` for every pole but the
    /// fastest, `r = 10^{1/per_decade}`), matched-z discretised and driven by one white noise: by partial
    /// fractions, a sum of AR(1) processes sharing one innovation with positive weights `c_i`. One normal draw
    /// per sample. The default.
    #[default]
    PoleZero,
    /// A sum of independent AR(1) processes of equal variance `B² ln10/(π·per_decade)`: one normal draw per
    /// component and sample.
    IndependentGm,
}

/// Correlation times of the Gauss–Markov sections that synthesise flicker noise, and the method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FlickerBand {
    /// Shortest correlation time, s (≥ Δt/20).
    pub tau_min_s: f64,
    /// Longest correlation time is the first of the log-spaced grid at or above this, s.
    pub tau_max_s: f64,
    /// Sections per decade of correlation time.
    pub per_decade: f64,
    /// Synthesis method.
    pub method: FlickerMethod,
}

impl FlickerBand {
    /// The default band for a run of `duration_s` at interval `dt_s`: `Δt/√2 … 10·duration`, 2 per decade,
    /// pole–zero.
    pub fn for_run(dt_s: f64, duration_s: f64) -> Self {
        Self {
            tau_min_s: dt_s / 2f64.sqrt(),
            tau_max_s: (10.0 * duration_s).max(10.0 * dt_s),
            per_decade: 2.0,
            method: FlickerMethod::PoleZero,
        }
    }

    /// Checks the band (positive, ordered, at most 400 sections).
    pub fn validate(&self) -> Result<(), SimError> {
        check(self.tau_min_s.is_finite() && self.tau_min_s > 0.0, || {
            format!("flicker tau_min_s = {} must be > 0", self.tau_min_s)
        })?;
        check(
            self.tau_max_s.is_finite() && self.tau_max_s >= self.tau_min_s,
            || format!("flicker tau_max_s = {} must be ≥ tau_min_s", self.tau_max_s),
        )?;
        check(
            self.per_decade.is_finite() && self.per_decade >= 0.5 && self.per_decade <= 20.0,
            || {
                format!(
                    "flicker per_decade = {} must be in [0.5, 20]",
                    self.per_decade
                )
            },
        )?;
        check(self.count() <= 400, || {
            "flicker band needs more than 400 sections".into()
        })
    }

    /// Number of sections (saturates at 10⁶ for an invalid band).
    pub fn count(&self) -> usize {
        let decades = (self.tau_max_s / self.tau_min_s).log10();
        let n = (self.per_decade * decades - 1e-9).ceil();
        if n.is_nan() {
            1
        } else {
            n.clamp(0.0, 1e6) as usize + 1
        }
    }

    /// Correlation times `T_i`, s.
    pub fn correlation_times(&self) -> Vec<f64> {
        (0..self.count())
            .map(|i| self.tau_min_s * 10f64.powf(i as f64 / self.per_decade))
            .collect()
    }

    /// The synthesis of bias instability `b` at interval `dt`: AR(1) sections and their AVAR weights.
    pub(super) fn synthesis(&self, dt: f64, b: f64) -> FlickerSynth {
        let la: Vec<f64> = self.correlation_times().iter().map(|t| dt / t).collect();
        match self.method {
            FlickerMethod::IndependentGm => {
                let var = b * b * LN_10 / (PI * self.per_decade);
                FlickerSynth {
                    alpha: vec![var; la.len()],
                    la,
                    weights: None,
                }
            }
            FlickerMethod::PoleZero => {
                // Zeros (rate ×dt) above every pole but the fastest.
                let r_half = 10f64.powf(0.5 / self.per_decade);
                let lz: Vec<f64> = la[1..].iter().map(|l| l * r_half).collect();
                // Residues c_i = Π_k (1 − b_k/a_i) / Π_{k≠i} (1 − a_k/a_i), in logs (a = e^{−la}, b = e^{−lz}).
                let c: Vec<f64> = (0..la.len())
                    .map(|i| {
                        let (mut log, mut sign) = (0.0, 1.0);
                        let mut acc = |x: f64, num: bool| {
                            let f = -(-x).exp_m1();
                            sign *= f.signum();
                            log += if num { f.abs().ln() } else { -f.abs().ln() };
                        };
                        for &z in &lz {
                            acc(z - la[i], true);
                        }
                        for (k, &p) in la.iter().enumerate() {
                            if k != i {
                                acc(p - la[i], false);
                            }
                        }
                        sign * log.exp()
                    })
                    .collect();
                // Autocovariance Σ_i α_i a_i^|k| with α_i = c_i Σ_j c_j / (1 − a_i a_j).
                let alpha: Vec<f64> = (0..la.len())
                    .map(|i| {
                        c[i] * c
                            .iter()
                            .zip(&la)
                            .map(|(cj, lj)| cj / -(-(la[i] + lj)).exp_m1())
                            .sum::<f64>()
                    })
                    .collect();
                // Gain: the exact AVAR equals the ideal floor at the band's centre.
                let tau_ref = (self.tau_min_s * self.tau_max_s).sqrt().max(dt);
                let unit: f64 = alpha
                    .iter()
                    .zip(&la)
                    .map(|(&a, &l)| ar1_avar(a, l, tau_ref / dt))
                    .sum();
                let g2 = FLICKER_AVAR_PER_B2 * b * b / unit;
                FlickerSynth {
                    alpha: alpha.iter().map(|a| a * g2).collect(),
                    weights: Some(c.iter().map(|c| c * g2.sqrt()).collect()),
                    la,
                }
            }
        }
    }
}

/// AR(1) sections of a flicker synthesis: `la_i = Δt/T_i`, AVAR weights `α_i` (the output's autocovariance is
/// `Σ α_i e^{−la_i|k|}`), and for the pole–zero method the weights of the shared-innovation sections.
#[derive(Clone, Debug, PartialEq)]
pub(super) struct FlickerSynth {
    pub(super) la: Vec<f64>,
    pub(super) alpha: Vec<f64>,
    pub(super) weights: Option<Vec<f64>>,
}
