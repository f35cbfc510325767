//! One sensor axis: noise parameters, the analytic Allan variance of each term, and a streaming generator.
//!
//! # Model and Allan variances
//! The output is a sequence of point samples `y_k` at interval `Δt` (the FPGA decimator keeps one ADC data set
//! and discards the rest, so nothing averages between samples). With `τ = mΔt` and the non-overlapping Allan
//! variance of `m`-sample means, each term is simulated so that its AVAR is known exactly:
//!
//! | term | simulation | AVAR, exact for the simulation | IEEE 952 ideal |
//! |---|---|---|---|
//! | white N | iid `N(0, N²/Δt)` | `N²/τ` | same |
//! | flicker B | AR(1) sections at log-spaced `T_i` (see *Flicker synthesis*) | Σ_i AR(1)(α_i, T_i) below | `(2 ln2/π)·B²` (ADEV `0.664·B`) |
//! | rate random walk K | `x_{k+1} = x_k + K√Δt·w_k` | `K²Δt(2m²+1)/(6m) = K²τ/3 + K²Δt²/(6τ)` | `K²τ/3` |
//! | quantisation Q | `(e_{k+1} − e_k)/Δt`, `e` iid uniform of variance Q² | `3Q²/τ²` | same |
//! | Gauss–Markov σ, T | AR(1), `φ = e^{−Δt/T}`, stationary variance σ² | AR(1) below | continuous formula below |
//! | output rounding Δ | `Δ·round(y/Δ)` (physical output only) | `(Δ²/12)·Δt/τ` when the noise dithers (σ ≳ Δ) | same |
//! | constant bias | — | 0 | 0 |
//!
//! AR(1) point samples, variance σ², `a = Δt/T`, `φ = e^{−a}`, `u = 1−φ`, `v = 1−φ^m`:
//! `AVAR = σ²/m² · [m(1+φ)u − φv(2+v)] / u²`; for `m·a ≤ 10⁻³` (where that form cancels) the exact Taylor
//! series `σ²/(2m²) · Σ_p (−a)^p M_p / p!` with `M_1 = −2m(2m²+1)/3`, `M_2 = −2m⁴`,
//! `M_3 = −2m(21m⁴−5m²−1)/15`, `M_4 = −2m⁴(2m²−1)` (moments of the Allan filter's autocorrelation).
//! Continuous Gauss–Markov (the ideal, averaged over τ): `(2σ²T/τ)·[1 − (T/2τ)(3 − 4e^{−τ/T} + e^{−2τ/T})]`,
//! which tends to white `2σ²T/τ` for τ ≫ T and to a rate random walk `(2σ²/T)τ/3` for τ ≪ T.
//!
//! # Flicker synthesis
//! First-order Gauss–Markov (AR(1)) sections with correlation times `T_i = T_min·10^{i/per_decade}` up to at
//! least `T_max` ([`FlickerBand`]). Either way the output's autocovariance is `Σ_i α_i·e^{−|k|Δt/T_i}`, so its
//! exact AVAR is `Σ_i AR(1)(α_i, T_i)` and [`NoiseModel::expected_avar`] uses that sum, not the ideal floor.
//! - [`FlickerMethod::PoleZero`] (default): a cascade of first-order pole–zero sections (poles `1/T_i`, a zero at
//!   `√r/T_i` for all but the fastest pole, `r = 10^{1/per_decade}`; `|H|²` is a staircase around `1/f`),
//!   matched-z discretised, driven by ONE white noise: by partial fractions, a sum of AR(1) sections sharing one
//!   innovation with positive weights `c_i`, `α_i = c_i Σ_j c_j/(1 − a_i a_j)`. Gain set so that the exact AVAR
//!   equals `(2 ln2/π)B²` at the band's centre `τ = √(T_min·T_max)`. One normal draw per sample.
//! - [`FlickerMethod::IndependentGm`]: independent AR(1) sections of equal variance `B² ln10/(π·per_decade)`
//!   (in the continuum limit the one-sided PSD `(B²/π)/f`, AVAR exactly `2 ln2·B²/π`; no gain fitted). One
//!   normal draw per section and sample.
//!
//! Measured flatness (test `flicker_floor_flatness`: exact AVAR / ideal at Δt = 1/18.9 s, default band
//! `T_min = Δt/√2`, `T_max = 10 × the 8 h run` = 2.9·10⁵ s, 15 sections at 2 per decade):
//!
//! | | τ ∈ [3 s, T_max/50] | τ = Δt | 0.21 s | 0.85 s | 1.4·10⁴ s | 3.9·10⁴ s |
//! |---|---|---|---|---|---|---|
//! | pole–zero, 2/decade | 0.9998 … 1.0001 | 1.19 | 1.018 | 1.002 | 0.9994 | 0.997 |
//! | pole–zero, 1/decade | 0.967 … 1.006 | 1.42 | 1.014 | 1.010 | 0.986 | 0.980 |
//! | independent, 2/decade | 0.996 … 1.000 | 1.09 | 0.971 | 0.987 | 0.991 | 0.974 |
//! | independent, 1/decade | 0.979 … 1.020 | 1.50 | 1.057 | 1.033 | 0.995 | 0.982 |
//!
//! (ADEV deviations are half these.) At τ near Δt no sampled process is ideal flicker; the exact sum says by
//! how much.

use super::{SimError, check, stream};
use rand_xoshiro::Xoshiro256PlusPlus;
use std::f64::consts::{LN_2, LN_10, PI};

mod flicker;
mod gauss;
use flicker::FlickerSynth;
pub use flicker::{FlickerBand, FlickerMethod};
pub use gauss::normal;
pub(crate) use gauss::round_to_step;
use gauss::signed_unit;

/// `2 ln2 / π`: the IEEE 952 flicker floor AVAR per B² (ADEV floor `0.6643·B`).
pub const FLICKER_AVAR_PER_B2: f64 = 2.0 * LN_2 / PI;

/// Noise parameters of one sensor axis, in physical units: gyro in °/s, accelerometer in g ("u" below).
/// Zero switches a term off. IEEE 952 conventions; all densities continuous-time.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct NoiseParams {
    /// White noise density N (angle / velocity random walk): u/√Hz, i.e. (°/s)/√Hz = °/√s or g/√Hz.
    /// Per-sample standard deviation `N/√Δt`; AVAR `N²/τ`.
    pub white: f64,
    /// Bias instability B (flicker, 1/f rate noise), u: AVAR floor `(2 ln2/π)·B²`, ADEV floor `0.664·B`.
    pub flicker: f64,
    /// Rate random walk K, u/√s (= u·√Hz): (°/s)/√s or g/√s. AVAR `K²τ/3`.
    pub rrw: f64,
    /// Quantisation Q in the IEEE 952 sense (of the integrated output): ° for gyros, g·s for accelerometers.
    /// AVAR `3Q²/τ²`.
    pub quant: f64,
    /// Rounding step of the output, u (e.g. [`super::Channel::adc_step`]); 0 = none. Applied to the physical
    /// output only: the raw-frame path rounds to real ADC codes instead. AVAR ≈ `(Δ²/12)·Δt/τ` when dithered.
    pub rate_step: f64,
    /// Constant bias, u.
    pub bias: f64,
    /// Gauss–Markov standard deviation σ, u (stationary); 0 = off.
    pub gm_sigma: f64,
    /// Gauss–Markov correlation time T, s (used when `gm_sigma > 0`).
    pub gm_tau_s: f64,
}

impl NoiseParams {
    /// White noise only, of density `n` (u/√Hz).
    pub fn white(n: f64) -> Self {
        Self {
            white: n,
            ..Self::default()
        }
    }

    /// Checks that every field is finite and every level non-negative.
    pub fn validate(&self) -> Result<(), SimError> {
        let f = [
            ("white", self.white),
            ("flicker", self.flicker),
            ("rrw", self.rrw),
            ("quant", self.quant),
            ("rate_step", self.rate_step),
            ("gm_sigma", self.gm_sigma),
            ("gm_tau_s", self.gm_tau_s),
        ];
        for (name, v) in f {
            check(v.is_finite() && v >= 0.0, || {
                format!("{name} = {v} must be finite and ≥ 0")
            })?;
        }
        check(self.bias.is_finite(), || {
            format!("bias = {} must be finite", self.bias)
        })?;
        check(self.gm_sigma == 0.0 || self.gm_tau_s > 0.0, || {
            format!("gm_tau_s = {} must be > 0 when gm_sigma > 0", self.gm_tau_s)
        })
    }

    /// The same parameters with white, flicker and random-walk levels multiplied by `s`.
    pub fn scaled(&self, s: f64) -> Self {
        Self {
            white: self.white * s,
            flicker: self.flicker * s,
            rrw: self.rrw * s,
            ..*self
        }
    }
}

/// How a model is turned into samples: the sample interval and the flicker synthesis band.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sampling {
    /// Sample interval Δt, s.
    pub dt_s: f64,
    /// Flicker synthesis band.
    pub flicker: FlickerBand,
}

impl Sampling {
    /// Sampling at `rate_hz` for a run of `duration_s`, with [`FlickerBand::for_run`].
    pub fn new(rate_hz: f64, duration_s: f64) -> Result<Self, SimError> {
        check(rate_hz.is_finite() && rate_hz > 0.0, || {
            format!("rate_hz = {rate_hz} must be > 0")
        })?;
        check(duration_s.is_finite() && duration_s > 0.0, || {
            format!("duration_s = {duration_s} must be > 0")
        })?;
        let s = Self {
            dt_s: 1.0 / rate_hz,
            flicker: FlickerBand::for_run(1.0 / rate_hz, duration_s),
        };
        s.validate()?;
        Ok(s)
    }

    /// Checks Δt and the band.
    pub fn validate(&self) -> Result<(), SimError> {
        check(self.dt_s.is_finite() && self.dt_s > 0.0, || {
            format!("dt_s = {} must be > 0", self.dt_s)
        })?;
        self.flicker.validate()?;
        check(self.flicker.tau_min_s >= self.dt_s / 20.0, || {
            "flicker tau_min_s must be ≥ Δt/20".into()
        })
    }
}

/// AVAR of each term at one τ, u².
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AvarTerms {
    /// White: `N²/τ`.
    pub white: f64,
    /// Flicker (exact AVAR of the synthesised Gauss–Markov sum).
    pub flicker: f64,
    /// Rate random walk (exact discrete).
    pub rrw: f64,
    /// Quantisation: `3Q²/τ²`.
    pub quant: f64,
    /// Output rounding: `(Δ²/12)·Δt/τ`.
    pub rate_step: f64,
    /// Gauss–Markov (exact discrete AR(1)).
    pub gm: f64,
}

impl AvarTerms {
    /// Sum of the terms.
    pub fn total(&self) -> f64 {
        self.white + self.flicker + self.rrw + self.quant + self.rate_step + self.gm
    }
}

/// Non-overlapping AVAR of AR(1) point samples (variance `var`, `a = Δt/T`) for `m`-sample means.
pub fn ar1_avar(var: f64, a: f64, m: f64) -> f64 {
    if var == 0.0 {
        return 0.0;
    }
    if m * a > 1e-3 {
        let phi = (-a).exp();
        let u = -(-a).exp_m1();
        let v = -(-m * a).exp_m1();
        var * (m * (1.0 + phi) * u - phi * v * (2.0 + v)) / (u * u * m * m)
    } else {
        let m2 = m * m;
        let moments = series_moments(m);
        let mut sum = 0.0;
        let mut coef = 1.0; // (−a)^p / p!
        for (p, mp) in moments.iter().enumerate() {
            coef *= -a / (p as f64 + 1.0);
            sum += coef * mp;
        }
        var * sum / (2.0 * m2)
    }
}

/// The lag moments of the Allan variance's series in powers of `−a` (first-order) or `−(a − iθ)` (narrow-band) at
/// `m`-sample means, shared by [`ar1_avar`] and [`line_avar`]: the sum `Σₚ (−s)^p/p! · momentₚ / 2m²` is the
/// Allan variance per unit variance for small `m·|s|`.
fn series_moments(m: f64) -> [f64; 4] {
    let m2 = m * m;
    let m4 = m2 * m2;
    [
        -2.0 * m * (2.0 * m2 + 1.0) / 3.0,
        -2.0 * m4,
        -2.0 * m * (21.0 * m4 - 5.0 * m2 - 1.0) / 15.0,
        -2.0 * m4 * (2.0 * m2 - 1.0),
    ]
}

/// Non-overlapping AVAR of a **narrow-band** Gauss–Markov process point-sampled every Δt: autocovariance
/// `var·e^{−k·a}·cos(kθ)` at lag k (`a = Δt/T`, `θ = 2π·f·Δt`), the real part of a complex AR(1)
/// `c ← e^{−a+iθ}·c + w` (a line of frequency f whose amplitude and phase wander with correlation time T), for
/// `m`-sample means. At θ = 0 it is [`ar1_avar`] (which stays the real computation, bit for bit).
///
/// The Allan variance is linear in the autocovariance, so it is [`ar1_avar`]'s expression at the complex
/// `a − iθ`, real part taken: `(m(1+z)(1−z) − z·v(2+v)) / (m²(1−z)²)` with `z = e^{−a+iθ}`, `v = 1 − z^m`, and
/// where `m·|a − iθ| ≤ 10⁻²` its series in powers of `a − iθ` (the same moments), `1 − z` from an exact `expm1`.
pub fn line_avar(var: f64, a: f64, theta: f64, m: f64) -> f64 {
    use nalgebra::Complex;
    if var == 0.0 {
        return 0.0;
    }
    let s = Complex::new(a, -theta); // z = e^{−s}
    // 1 − e^{−x} for complex x, without cancellation: −(e^{−re}·(cos im' + i sin im') − 1).
    let one_minus_exp = |x: Complex<f64>| {
        let (re, im) = (-x.re, -x.im);
        let half = (im / 2.0).sin();
        -Complex::new(
            re.exp_m1() * im.cos() - 2.0 * half * half,
            re.exp() * im.sin(),
        )
    };
    let g = if m * s.norm() > 1e-2 {
        let z = (-s).exp();
        let u = one_minus_exp(s);
        let v = one_minus_exp(s * m);
        (u * m * (z + 1.0) - z * v * (v + 2.0)) / (u * u * (m * m))
    } else {
        let m2 = m * m;
        let moments = series_moments(m);
        let mut sum = Complex::new(0.0, 0.0);
        let mut coef = Complex::new(1.0, 0.0); // (−s)^p / p!
        for (p, mp) in moments.iter().enumerate() {
            coef *= -s / (p as f64 + 1.0);
            sum += coef * *mp;
        }
        sum / (2.0 * m2)
    };
    var * g.re
}

/// AVAR of a continuous first-order Gauss–Markov process (σ², correlation time `t`) averaged over τ.
pub fn gm_avar_continuous(var: f64, t: f64, tau: f64) -> f64 {
    if var == 0.0 {
        return 0.0;
    }
    let x = tau / t;
    let bracket = if x > 1e-2 {
        1.0 - (3.0 - 4.0 * (-x).exp() + (-2.0 * x).exp()) / (2.0 * x)
    } else {
        // −½ Σ_{p≥3} (−1)^p (2^p − 4) x^{p−1} / p!
        let mut s = 0.0;
        let mut xp = x * x; // x^{p−1}
        let mut fact = 6.0;
        for p in 3..10 {
            let sign = if p % 2 == 0 { 1.0 } else { -1.0 };
            s += -0.5 * sign * (2f64.powi(p) - 4.0) * xp / fact;
            xp *= x;
            fact *= f64::from(p + 1);
        }
        s
    };
    2.0 * var * bracket / x
}

/// A validated model of one sensor axis with its sampling: analytic Allan variances.
#[derive(Clone, Debug, PartialEq)]
pub struct NoiseModel {
    params: NoiseParams,
    sampling: Sampling,
    /// Flicker synthesis (empty without flicker).
    flicker: FlickerSynth,
}

impl NoiseModel {
    /// Validates `params` and `sampling` and prepares the flicker components.
    pub fn new(params: &NoiseParams, sampling: &Sampling) -> Result<Self, SimError> {
        params.validate()?;
        sampling.validate()?;
        let flicker = if params.flicker > 0.0 {
            sampling.flicker.synthesis(sampling.dt_s, params.flicker)
        } else {
            FlickerSynth {
                la: Vec::new(),
                alpha: Vec::new(),
                weights: None,
            }
        };
        Ok(Self {
            params: *params,
            sampling: *sampling,
            flicker,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &NoiseParams {
        &self.params
    }

    /// The sampling.
    pub fn sampling(&self) -> &Sampling {
        &self.sampling
    }

    /// Each term's AVAR at `tau_s` (u²), exact for the simulated process at `τ = mΔt`, m ≥ 1 (non-integer m
    /// interpolates the same closed forms).
    pub fn terms(&self, tau_s: f64) -> AvarTerms {
        let p = &self.params;
        let dt = self.sampling.dt_s;
        let m = tau_s / dt;
        AvarTerms {
            white: p.white * p.white / tau_s,
            flicker: self
                .flicker
                .alpha
                .iter()
                .zip(&self.flicker.la)
                .map(|(&v, &a)| ar1_avar(v, a, m))
                .sum(),
            rrw: p.rrw * p.rrw * dt * (2.0 * m * m + 1.0) / (6.0 * m),
            quant: 3.0 * p.quant * p.quant / (tau_s * tau_s),
            rate_step: p.rate_step * p.rate_step / 12.0 * dt / tau_s,
            gm: if p.gm_sigma > 0.0 {
                ar1_avar(p.gm_sigma * p.gm_sigma, dt / p.gm_tau_s, m)
            } else {
                0.0
            },
        }
    }

    /// Expected AVAR at `tau_s` of the simulated process, u² (sum of [`Self::terms`]).
    pub fn expected_avar(&self, tau_s: f64) -> f64 {
        self.terms(tau_s).total()
    }

    /// The IEEE 952 ideal AVAR at `tau_s`, u²: `N²/τ + (2ln2/π)B² + K²τ/3 + 3Q²/τ² + (Δ²/12)Δt/τ` + continuous
    /// Gauss–Markov. Differs from [`Self::expected_avar`] by the flicker synthesis and the sampling of RRW and GM.
    pub fn ideal_avar(&self, tau_s: f64) -> f64 {
        let p = &self.params;
        let gm = if p.gm_sigma > 0.0 {
            gm_avar_continuous(p.gm_sigma * p.gm_sigma, p.gm_tau_s, tau_s)
        } else {
            0.0
        };
        p.white * p.white / tau_s
            + FLICKER_AVAR_PER_B2 * p.flicker * p.flicker
            + p.rrw * p.rrw * tau_s / 3.0
            + 3.0 * p.quant * p.quant / (tau_s * tau_s)
            + p.rate_step * p.rate_step / 12.0 * self.sampling.dt_s / tau_s
            + gm
    }

    /// Standard deviation (u²) of the non-overlapping AVAR estimate at `tau_s` from `k` τ-averages (`k − 1` Allan
    /// differences `d_j`), for a record of this model: `√(Var Σd²)/(2(k−1))` with `Var Σd² = 2 Σ_ij Cov(d_i, d_j)²`
    /// for Gaussian terms, the covariances exact for each term — white (lag 1: −½), rate random walk (lag 1 only),
    /// quantisation (lags 1, 2) and AR(1) (geometric in the lag, so flicker's slow components correlate far) —
    /// plus the fourth-cumulant term of the uniform quantisation and rounding errors. For white noise alone this
    /// is `AVAR·√(3/(k−1))`, i.e. 2(k−1)/3 degrees of freedom. Infinite for `k < 2`.
    pub fn avar_estimate_sd(&self, tau_s: f64, k: usize) -> f64 {
        if k < 2 {
            return f64::INFINITY;
        }
        let p = &self.params;
        let dt = self.sampling.dt_s;
        let m = tau_s / dt;
        let (mut c0, mut c1, mut c2) = (0.0, 0.0, 0.0);
        let w = p.white * p.white / tau_s + p.rate_step * p.rate_step / 12.0 * dt / tau_s;
        (c0, c1) = (c0 + 2.0 * w, c1 - w);
        let q = p.rrw * p.rrw * dt;
        let av = q * (2.0 * m * m + 1.0) / (6.0 * m);
        (c0, c1) = (c0 + 2.0 * av, c1 + 0.5 * q * m - av);
        let qq = p.quant * p.quant / (tau_s * tau_s);
        (c0, c1, c2) = (c0 + 6.0 * qq, c1 - 4.0 * qq, c2 + qq);
        // AR(1): covariance of block means s ≥ 1 apart is C·r^{s−1}, C = σ²φ(G_m/m)², r = φ^m.
        let mut tails = Vec::new(); // (g, r): lag L ≥ 2 contributes g·r^{L−2}
        let gm = (p.gm_sigma > 0.0).then(|| (p.gm_sigma * p.gm_sigma, dt / p.gm_tau_s));
        let fl = self
            .flicker
            .alpha
            .iter()
            .copied()
            .zip(self.flicker.la.iter().copied());
        for (var, a) in fl.chain(gm) {
            let (u, v) = (-(-a).exp_m1(), -(-m * a).exp_m1());
            let c = var * (-a).exp() * (v / (u * m)).powi(2);
            let av = ar1_avar(var, a, m);
            (c0, c1) = (c0 + 2.0 * av, c1 + c * v - av);
            tails.push((-c * v * v, 1.0 - v));
        }
        let n = (k - 1) as f64;
        // Non-Gaussian part: uniform quantisation errors (4th cumulant −1.2·variance²) of the IEEE Q term
        // (d_j ∝ second difference of e) and of the output rounding (white).
        let (q4, s4) = (
            -1.2 * qq * qq,
            -1.2 * (p.rate_step * p.rate_step / 12.0).powi(2) / m.powi(3),
        );
        let k4 = q4 * (18.0 * n + 16.0 * (n - 1.0).max(0.0) + 2.0 * (n - 2.0).max(0.0))
            + s4 * (2.0 * n + 2.0 * (n - 1.0).max(0.0));
        let mut s = n * c0 * c0;
        if k > 2 {
            s += 2.0 * (n - 1.0) * c1 * c1;
        }
        let mut pow: Vec<f64> = vec![1.0; tails.len()];
        for lag in 2..k - 1 {
            let mut c = if lag == 2 { c2 } else { 0.0 };
            for ((g, r), pw) in tails.iter().zip(pow.iter_mut()) {
                c += g * *pw;
                *pw *= r;
            }
            if c == 0.0 && tails.is_empty() {
                break;
            }
            s += 2.0 * (n - lag as f64) * c * c;
        }
        (2.0 * s + k4).max(0.0).sqrt() / (2.0 * n)
    }

    /// Minimum of the expected ADEV over `τ ∈ [lo, hi]` (s): `(τ_min, ADEV_min)` in (s, u). Coarse log grid
    /// (20 per decade) refined by golden-section search.
    pub fn min_adev(&self, lo: f64, hi: f64) -> (f64, f64) {
        let (l0, l1) = (lo.max(self.sampling.dt_s).ln(), hi.max(lo).ln());
        let n = (((l1 - l0) / LN_10) * 20.0).ceil().max(1.0) as usize;
        let f = |l: f64| self.expected_avar(l.exp());
        let (mut best, mut best_v) = (l0, f(l0));
        for i in 1..=n {
            let l = l0 + (l1 - l0) * i as f64 / n as f64;
            let v = f(l);
            if v < best_v {
                (best, best_v) = (l, v);
            }
        }
        let step = (l1 - l0) / n as f64;
        let (mut a, mut b) = ((best - step).max(l0), (best + step).min(l1));
        let g = (5f64.sqrt() - 1.0) / 2.0;
        for _ in 0..60 {
            let (c, d) = (b - g * (b - a), a + g * (b - a));
            if f(c) < f(d) { b = d } else { a = c }
        }
        let l = 0.5 * (a + b);
        let (l, v) = if f(l) < best_v {
            (l, f(l))
        } else {
            (best, best_v)
        };
        (l.exp(), v.sqrt())
    }
}

/// Expected AVAR (u²) at `tau_s` of a sensor with `params` simulated with `sampling`: the sum of the exact
/// per-term formulas of this module (see [`NoiseModel::terms`]). `tau_s` must be ≥ Δt.
pub fn expected_avar(
    params: &NoiseParams,
    sampling: &Sampling,
    tau_s: f64,
) -> Result<f64, SimError> {
    check(tau_s.is_finite() && tau_s >= sampling.dt_s, || {
        format!("tau_s = {tau_s} must be ≥ Δt")
    })?;
    Ok(NoiseModel::new(params, sampling)?.expected_avar(tau_s))
}

/// One AR(1) process with its own random stream.
#[derive(Clone, Debug)]
struct Ar1 {
    phi: f64,
    sd: f64,
    x: f64,
    rng: Xoshiro256PlusPlus,
}

impl Ar1 {
    fn new(var: f64, a: f64, mut rng: Xoshiro256PlusPlus) -> Self {
        let x = var.sqrt() * normal(&mut rng); // stationary start
        Self {
            phi: (-a).exp(),
            sd: (var * -(-2.0 * a).exp_m1()).sqrt(),
            x,
            rng,
        }
    }

    fn add_to(&mut self, out: &mut [f64]) {
        let (phi, sd, mut x) = (self.phi, self.sd, self.x);
        for o in out {
            *o += x;
            x = phi * x + sd * normal(&mut self.rng);
        }
        self.x = x;
    }
}

/// Adds to `out` a narrow-band Gauss–Markov process ([`line_avar`]'s: variance `var`, `a = Δt/T`, `θ = 2π·f·Δt`),
/// exactly discretised: the real part of the complex AR(1) `c ← e^{−a}·e^{iθ}·c + w`, both parts of `w` of
/// variance `var·(1 − e^{−2a})`, started stationary; its own stream of `seed`.
pub fn add_line(out: &mut [f64], var: f64, a: f64, theta: f64, seed: u64) {
    let mut rng = stream(seed, 5);
    let sd0 = var.sqrt();
    let (mut re, mut im) = (sd0 * normal(&mut rng), sd0 * normal(&mut rng));
    let r = (-a).exp();
    let (c, s) = (r * theta.cos(), r * theta.sin());
    let sd = (var * -(-2.0 * a).exp_m1()).sqrt();
    for o in out {
        *o += re;
        let (wr, wi) = (sd * normal(&mut rng), sd * normal(&mut rng));
        (re, im) = (c * re - s * im + wr, s * re + c * im + wi);
    }
}

/// AR(1) sections `y_i ← a_i·y_i + w` sharing one unit innovation `w`, output `Σ c_i·y_i` (the pole–zero
/// flicker synthesis), in lanes of 4 (padding: a = c = 0).
#[derive(Clone, Debug)]
struct PoleZeroGen {
    a: Vec<[f64; 4]>,
    c: Vec<[f64; 4]>,
    y: Vec<[f64; 4]>,
    rng: Xoshiro256PlusPlus,
}

impl PoleZeroGen {
    fn new(la: &[f64], c: &[f64], mut rng: Xoshiro256PlusPlus) -> Self {
        let n = la.len();
        // Stationary start: y ~ N(0, P), P_ij = 1/(1 − a_i a_j), by a Cholesky factor that drops pivots below
        // 1e-14 of the diagonal (P is a near-singular Cauchy matrix when many sections are slow).
        let p = |i: usize, j: usize| 1.0 / -(-(la[i] + la[j])).exp_m1();
        let mut l = vec![0.0; n * n];
        for j in 0..n {
            let d = p(j, j) - (0..j).map(|k| l[j * n + k] * l[j * n + k]).sum::<f64>();
            if d <= 1e-14 * p(j, j) {
                continue;
            }
            let sd = d.sqrt();
            l[j * n + j] = sd;
            for i in j + 1..n {
                l[i * n + j] =
                    (p(i, j) - (0..j).map(|k| l[i * n + k] * l[j * n + k]).sum::<f64>()) / sd;
            }
        }
        let z: Vec<f64> = (0..n).map(|_| normal(&mut rng)).collect();
        let y0: Vec<f64> = (0..n)
            .map(|i| (0..=i).map(|k| l[i * n + k] * z[k]).sum())
            .collect();
        let lanes = |v: &dyn Fn(usize) -> f64| -> Vec<[f64; 4]> {
            (0..n.div_ceil(4))
                .map(|q| core::array::from_fn(|l| if 4 * q + l < n { v(4 * q + l) } else { 0.0 }))
                .collect()
        };
        Self {
            a: lanes(&|i| (-la[i]).exp()),
            c: lanes(&|i| c[i]),
            y: lanes(&|i| y0[i]),
            rng,
        }
    }

    fn add_to(&mut self, out: &mut [f64]) {
        for o in out {
            let w = normal(&mut self.rng);
            let mut acc = [0.0; 4];
            for ((a, c), y) in self.a.iter().zip(&self.c).zip(self.y.iter_mut()) {
                for l in 0..4 {
                    y[l] = a[l] * y[l] + w;
                    acc[l] += c[l] * y[l];
                }
            }
            *o += (acc[0] + acc[1]) + (acc[2] + acc[3]);
        }
    }
}

/// Four AR(1) processes in one pass (independent dependency chains for instruction-level parallelism).
fn add_ar1_quad(q: &mut [Ar1], out: &mut [f64]) {
    let [a, b, c, d] = q else { return };
    let (mut xa, mut xb, mut xc, mut xd) = (a.x, b.x, c.x, d.x);
    for o in out {
        *o += (xa + xb) + (xc + xd);
        xa = a.phi * xa + a.sd * normal(&mut a.rng);
        xb = b.phi * xb + b.sd * normal(&mut b.rng);
        xc = c.phi * xc + c.sd * normal(&mut c.rng);
        xd = d.phi * xd + d.sd * normal(&mut d.rng);
    }
    (a.x, b.x, c.x, d.x) = (xa, xb, xc, xd);
}

/// Streaming generator of one sensor's noise (all terms of [`NoiseParams`] but the output rounding, which
/// [`Self::fill_rounded`] adds). Each term draws from its own stream, so the output does not depend on how the
/// caller splits it into chunks.
#[derive(Clone, Debug)]
pub struct SensorNoise {
    bias: f64,
    rate_step: f64,
    white: Option<(f64, Xoshiro256PlusPlus)>,
    ar1: Vec<Ar1>,
    pole_zero: Option<PoleZeroGen>,
    /// (step sd K√Δt, current value, stream)
    rrw: Option<(f64, f64, Xoshiro256PlusPlus)>,
    /// (half width √3·Q, previous error, 1/Δt, stream)
    quant: Option<(f64, f64, f64, Xoshiro256PlusPlus)>,
}

impl SensorNoise {
    /// A generator for `params` with `sampling`, seeded by `seed`.
    pub fn new(params: &NoiseParams, sampling: &Sampling, seed: u64) -> Result<Self, SimError> {
        let model = NoiseModel::new(params, sampling)?;
        let p = &model.params;
        let dt = sampling.dt_s;
        let fl = &model.flicker;
        let mut ar1 = Vec::new();
        let mut pole_zero = None;
        match &fl.weights {
            None => {
                for (i, (&var, &a)) in fl.alpha.iter().zip(&fl.la).enumerate() {
                    ar1.push(Ar1::new(var, a, stream(seed, 16 + i as u64)));
                }
            }
            Some(c) => pole_zero = Some(PoleZeroGen::new(&fl.la, c, stream(seed, 4))),
        }
        if p.gm_sigma > 0.0 {
            ar1.push(Ar1::new(
                p.gm_sigma * p.gm_sigma,
                dt / p.gm_tau_s,
                stream(seed, 3),
            ));
        }
        let quant = (p.quant > 0.0).then(|| {
            let h = 3f64.sqrt() * p.quant;
            let mut rng = stream(seed, 2);
            let e0 = h * signed_unit(&mut rng);
            (h, e0, 1.0 / dt, rng)
        });
        Ok(Self {
            bias: p.bias,
            rate_step: p.rate_step,
            white: (p.white > 0.0).then(|| (p.white / dt.sqrt(), stream(seed, 0))),
            ar1,
            pole_zero,
            rrw: (p.rrw > 0.0).then(|| (p.rrw * dt.sqrt(), 0.0, stream(seed, 1))),
            quant,
        })
    }

    /// Overwrites `out` with the next `out.len()` samples, u (no output rounding).
    pub fn fill(&mut self, out: &mut [f64]) {
        match &mut self.white {
            Some((sd, rng)) => {
                for o in out.iter_mut() {
                    *o = self.bias + *sd * normal(rng);
                }
            }
            None => out.fill(self.bias),
        }
        let mut quads = self.ar1.chunks_exact_mut(4);
        for q in &mut quads {
            add_ar1_quad(q, out);
        }
        for c in quads.into_remainder() {
            c.add_to(out);
        }
        if let Some(pz) = &mut self.pole_zero {
            pz.add_to(out);
        }
        if let Some((sd, x, rng)) = &mut self.rrw {
            for o in out.iter_mut() {
                *o += *x;
                *x += *sd * normal(rng);
            }
        }
        if let Some((h, prev, inv_dt, rng)) = &mut self.quant {
            for o in out.iter_mut() {
                let e = *h * signed_unit(rng);
                *o += (e - *prev) * *inv_dt;
                *prev = e;
            }
        }
    }

    /// [`Self::fill`], then rounds to multiples of `rate_step` if it is set.
    pub fn fill_rounded(&mut self, out: &mut [f64]) {
        self.fill(out);
        round_to_step(out, self.rate_step);
    }

    /// Convenience: `n` samples (rounded as [`Self::fill_rounded`]) of a fresh generator.
    pub fn series(
        params: &NoiseParams,
        sampling: &Sampling,
        n: usize,
        seed: u64,
    ) -> Result<Vec<f64>, SimError> {
        let mut g = Self::new(params, sampling, seed)?;
        let mut v = vec![0.0; n];
        g.fill_rounded(&mut v);
        Ok(v)
    }
}
