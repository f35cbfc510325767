//! Power-law noise identification: lag-1 autocorrelation (Riley & Greenhall 2004) with the
//! B1 / R(n) bias-ratio fallback that Stable32 uses when too few points are left.

use super::deviation::{DevKind, Phase};
use super::lanes;

/// Minimum number of τ-averaged frequency points for the lag-1 ACF method
/// (Stable32: "at least 30 analysis points"; allantools raises below 30).
pub const ACF_MIN_POINTS: usize = 30;

/// Variant of the lag-1 ACF noise identification.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum AcfFlavor {
    /// As Stable32: no detrending of the averaged data and the lag-1 autocorrelation scaled
    /// by `(n−1)/n`. Reproduces every Stable32 `Alpha` of the reference runs.
    #[default]
    Stable32,
    /// As allantools `autocorr_noise_id(data_type='freq')`: linear (frequency drift)
    /// detrend of the averaged data, unscaled lag-1 autocorrelation.
    Allantools,
}

/// How a noise type was obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NoiseIdMethod {
    /// Lag-1 autocorrelation of the τ-averaged frequency data.
    Acf,
    /// B1 bias ratio (standard variance / Allan variance).
    B1,
    /// B1 ratio said "white or flicker PM" and R(n) = MVAR/AVAR decided which.
    B1Rn,
    /// Copied from the previous (shorter) τ (Stable32 behaviour at long τ, see
    /// [`Options::stable32_carry`](super::Options::stable32_carry)).
    Carried,
    /// Supplied by the caller.
    Fixed,
}

/// Result of the lag-1 ACF method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AcfResult {
    /// `−round(2δ) − 2d` (ties to even, like numpy), not clamped.
    pub alpha_int: i32,
    /// Continuous estimate `p = −2(δ + d)`.
    pub alpha: f64,
    /// Number of differencing passes done.
    pub d: u32,
    /// `δ = r1 / (1 + r1)` of the final series (allantools calls it `rho`).
    pub delta: f64,
    /// Number of τ-averaged points the method started from (`floor(N/m)`).
    pub points: usize,
}

/// Result of the B1 (and R(n)) method.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct B1Result {
    /// Measured B1 = sample variance of the τ-averages / non-overlapping AVAR(τ).
    pub b1: f64,
    /// The `N` used for the theoretical B1(N, μ): the deviation's number of terms.
    pub n: usize,
    /// Identified Allan-variance τ-exponent μ ∈ {2, 1, 0, −1, −2}.
    pub mu: i32,
    /// R(n) = MVAR/AVAR when μ = −2 (white vs flicker PM).
    pub rn: Option<f64>,
    /// Resulting α (μ = 2 → −3, 1 → −2, 0 → −1, −1 → 0, −2 → 1 or 2), not clamped.
    pub alpha: i32,
}

/// Identified noise type at one τ.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NoiseId {
    /// α used for the EDF, clamped to the Allan-family range `[−2, 2]`
    /// (Greenhall's EDF needs α + 2d > 1, i.e. α ≥ −2 for d = 2).
    pub alpha: i32,
    /// α before clamping.
    pub alpha_raw: i32,
    /// Continuous α estimate (ACF method only).
    pub alpha_est: Option<f64>,
    /// Method used.
    pub method: NoiseIdMethod,
    /// ACF details, if the ACF method was used.
    pub acf: Option<AcfResult>,
    /// B1 details, if the B1 method was used.
    pub b1: Option<B1Result>,
}

impl NoiseId {
    pub(crate) fn carried(alpha: i32) -> NoiseId {
        NoiseId::simple(alpha, NoiseIdMethod::Carried)
    }

    pub(crate) fn fixed(alpha: i32) -> NoiseId {
        NoiseId::simple(alpha, NoiseIdMethod::Fixed)
    }

    fn simple(alpha: i32, method: NoiseIdMethod) -> NoiseId {
        NoiseId {
            alpha,
            alpha_raw: alpha,
            alpha_est: None,
            method,
            acf: None,
            b1: None,
        }
    }
}

/// Lag-1 autocorrelation noise identification (Riley & Greenhall 2004) of frequency data
/// `y` at averaging factor `m`.
///
/// The data are averaged in non-overlapping blocks of `m` (`floor(N/m)` points, at least
/// [`ACF_MIN_POINTS`]), optionally detrended ([`AcfFlavor`]), then differenced until
/// `δ = r1/(1+r1) < 0.25` or `d = dmax` (use `dmax = 2` for the Allan family).
/// `None` if `m = 0`, too few points, or a degenerate (constant) series.
pub fn acf_noise_id(y: &[f64], m: usize, flavor: AcfFlavor, dmax: u32) -> Option<AcfResult> {
    acf_noise_id_pyramid(y, m, flavor, dmax, &mut Vec::new(), &[])
}

/// [`acf_noise_id`] with a scratch buffer `z`, taking the block means of a power-of-two `m` from `pyramid` (level k = means of 2^k
/// samples, built by pairwise averaging) when it has that level: O(N/m) instead of O(N) per τ.
pub(crate) fn acf_noise_id_pyramid(
    y: &[f64],
    m: usize,
    flavor: AcfFlavor,
    dmax: u32,
    z: &mut Vec<f64>,
    pyramid: &[Vec<f64>],
) -> Option<AcfResult> {
    if m == 0 {
        return None;
    }
    let points = y.len() / m;
    if points < ACF_MIN_POINTS {
        return None;
    }
    // The block means: a level of the pyramid or `y` itself (m = 1), read in place; copied into `z` only when
    // they must change (detrending), or computed into `z`.
    let level = pyramid
        .get(m.trailing_zeros() as usize)
        .filter(|l| m.is_power_of_two() && l.len() == points)
        .map(Vec::as_slice)
        .or((m == 1).then_some(y));
    let mut in_z = flavor == AcfFlavor::Allantools || level.is_none();
    if in_z {
        match level {
            Some(l) => {
                z.clear();
                z.extend_from_slice(l);
            }
            None => block_averages(y, m, z),
        }
    }
    if flavor == AcfFlavor::Allantools {
        detrend_linear(z);
    }
    let mut d = 0u32;
    loop {
        let current: &[f64] = match level {
            Some(l) if !in_z => l,
            _ => z,
        };
        let r1 = lag1_autocorrelation(current, flavor == AcfFlavor::Stable32)?;
        let delta = r1 / (1.0 + r1);
        if !delta.is_finite() {
            return None;
        }
        if delta < 0.25 || d >= dmax {
            let alpha = -2.0 * (delta + f64::from(d));
            let alpha_int = -(2.0 * delta).round_ties_even() - 2.0 * f64::from(d);
            if alpha_int.is_nan() || alpha_int.abs() >= 1e6 {
                return None;
            }
            return Some(AcfResult {
                alpha_int: alpha_int as i32,
                alpha,
                d,
                delta,
                points,
            });
        }
        if current.len() < 3 {
            return None;
        }
        match level {
            Some(l) if !in_z => {
                z.clear();
                z.extend(l.windows(2).map(|w| w[1] - w[0]));
                in_z = true;
            }
            _ => {
                for i in 0..z.len() - 1 {
                    z[i] = z[i + 1] - z[i];
                }
                z.pop();
            }
        }
        d += 1;
    }
}

/// Non-overlapping block means of `m` samples (trailing partial block dropped).
fn block_averages(y: &[f64], m: usize, out: &mut Vec<f64>) {
    out.clear();
    if m == 1 {
        // x / 1 = x: a copy, not N divisions.
        out.extend_from_slice(y);
    } else {
        out.extend(y.chunks_exact(m).map(|c| lanes::sum(c) / m as f64));
    }
}

/// Removes the least-squares straight line `a + b·t`, `t = 0, 1, …`.
pub fn detrend_linear(z: &mut [f64]) {
    let n = z.len();
    if n < 2 {
        return;
    }
    let nf = n as f64;
    let t_mean = (nf - 1.0) / 2.0;
    let z_mean = lanes::sum(z) / nf;
    let (mut sxy, mut sxx) = (0.0, 0.0);
    for (i, &v) in z.iter().enumerate() {
        let dt = i as f64 - t_mean;
        sxy += dt * (v - z_mean);
        sxx += dt * dt;
    }
    let slope = sxy / sxx;
    let intercept = z_mean - slope * t_mean;
    for (i, v) in z.iter_mut().enumerate() {
        *v -= intercept + slope * i as f64;
    }
}

/// `r1 = Σ (z_i − z̄)(z_{i+1} − z̄) / Σ (z_i − z̄)²`, times `(n−1)/n` if `scaled`.
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn lag1_autocorrelation(z: &[f64], scaled: bool) -> Option<f64> {
    let n = z.len();
    if n < 2 {
        return None;
    }
    let mean = lanes::sum(z) / n as f64;
    // One pass for both sums: the squares of all but the last value with the lag-1 products, then the last square.
    let (den_head, num) = lanes::sum2_pair(z, z.get(1..).unwrap_or(&[]), |a, b| {
        let (da, db) = (a - mean, b - mean);
        (da * da, da * db)
    });
    let last = z.last().map_or(0.0, |v| (v - mean) * (v - mean));
    let den = den_head + last;
    let mut r1 = num / den;
    if scaled {
        r1 *= (n - 1) as f64 / n as f64;
    }
    r1.is_finite().then_some(r1)
}

/// Theoretical B1(N, μ) for dead-time ratio r = 1 (Barnes; Howe et al. 2000, Table 3).
fn b1_expected(n: f64, mu: i32) -> f64 {
    match mu {
        2 => n * (n + 1.0) / 6.0,
        1 => n / 2.0,
        0 => n * n.ln() / (2.0 * (n - 1.0) * std::f64::consts::LN_2),
        -1 => 1.0,
        -2 => (n * n - 1.0) / (1.5 * n * (n - 1.0)),
        _ => n * (1.0 - n.powi(mu)) / (2.0 * (n - 1.0) * (1.0 - 2f64.powi(mu))),
    }
}

/// Classifies a measured B1: the first μ (from 2 down) whose boundary with μ−1 it
/// exceeds; boundaries are geometric means of neighbouring theoretical values, except
/// the arithmetic mean between μ = 2 and μ = 1.
fn b1_classify(b1: f64, n: f64) -> i32 {
    for mu in [2, 1, 0, -1] {
        let hi = b1_expected(n, mu);
        let lo = b1_expected(n, mu - 1);
        let boundary = if mu == 2 {
            0.5 * (hi + lo)
        } else {
            (hi * lo).sqrt()
        };
        if b1 > boundary {
            return mu;
        }
    }
    -2
}

/// Expected R(n) = MVAR/AVAR for flicker PM, with the usual measurement bandwidth
/// `f_h = 1/(2τ0)` (NIST SP 1065 / IEEE 1139 power-law tables):
/// `AVAR ∝ 1.038 + 3 ln(2π f_h τ)`, `MVAR ∝ (3/2) ln(256/27)`.
fn rn_expected_flicker_pm(m: usize) -> f64 {
    let m = m as f64;
    1.5 * (256.0f64 / 27.0).ln() / (1.038 + 3.0 * (std::f64::consts::PI * m).ln())
}

/// B1-ratio noise identification at averaging factor `m` (the Stable32 method when fewer
/// than 30 τ-averaged points are left).
///
/// `B1 = s²/AVAR` where `s²` is the sample variance (n−1 divisor) of the `floor(N/m)`
/// block averages of `y` and AVAR the non-overlapping Allan variance at `m`. It is
/// compared with B1(N, μ) where — as in Stable32 — `N` is the number of terms of the
/// deviation being computed (`kind.n_terms`). If μ = −2 (white or flicker PM, which B1
/// cannot separate) the ratio R(n) = MVAR/AVAR is compared with the geometric mean of
/// its white-PM (`1/m`) and flicker-PM expectations.
///
/// `phase` must be the integral of `y` (see [`Phase::from_frequency`]).
pub fn b1_noise_id(kind: DevKind, y: &[f64], phase: &Phase, m: usize) -> Option<B1Result> {
    if m == 0 || phase.n_samples() != y.len() {
        return None;
    }
    let k = y.len() / m;
    if k < 2 {
        return None;
    }
    let n = kind.n_terms(y.len(), m);
    if n < 2 {
        return None;
    }
    // Sample variance of the block means (fewer than ACF_MIN_POINTS of them here), two-pass.
    let means: Vec<f64> = y
        .chunks_exact(m)
        .map(|c| lanes::sum(c) / m as f64)
        .collect();
    let grand = means.iter().sum::<f64>() / k as f64;
    let svar = means.iter().map(|v| (v - grand) * (v - grand)).sum::<f64>() / (k - 1) as f64;
    let avar = phase.avar_nonoverlapping(m)?;
    let b1 = svar / avar;
    if !b1.is_finite() {
        return None;
    }
    let mu = b1_classify(b1, n as f64);
    let (alpha, rn) = match mu {
        2 => (-3, None),
        1 => (-2, None),
        0 => (-1, None),
        -1 => (0, None),
        _ => {
            let rn = phase.mvar_any(m)? / avar;
            let boundary = (rn_expected_flicker_pm(m) / m as f64).sqrt();
            (if rn > boundary { 1 } else { 2 }, Some(rn))
        }
    };
    Some(B1Result {
        b1,
        n,
        mu,
        rn,
        alpha,
    })
}

/// Stable32's noise identification at one τ for deviation `kind`: the lag-1 ACF method
/// if at least [`ACF_MIN_POINTS`] τ-averages are available, otherwise the B1 ratio
/// (with R(n) for white/flicker PM). `phase` must be the integral of `y`.
/// The returned [`NoiseId::alpha`] is clamped to `[−2, 2]`.
pub fn noise_id(
    kind: DevKind,
    y: &[f64],
    phase: &Phase,
    m: usize,
    flavor: AcfFlavor,
) -> Option<NoiseId> {
    noise_id_pyramid(kind, y, phase, m, flavor, &mut Vec::new(), &[])
}

/// [`noise_id`] with a scratch buffer and a pyramid of block means (see [`acf_noise_id_pyramid`]).
pub(crate) fn noise_id_pyramid(
    kind: DevKind,
    y: &[f64],
    phase: &Phase,
    m: usize,
    flavor: AcfFlavor,
    scratch: &mut Vec<f64>,
    pyramid: &[Vec<f64>],
) -> Option<NoiseId> {
    if m == 0 {
        return None;
    }
    if y.len() / m >= ACF_MIN_POINTS {
        let (dmax, _, _) = kind.greenhall_params();
        let r = acf_noise_id_pyramid(y, m, flavor, dmax, scratch, pyramid)?;
        Some(NoiseId {
            alpha: r.alpha_int.clamp(-2, 2),
            alpha_raw: r.alpha_int,
            alpha_est: Some(r.alpha),
            method: NoiseIdMethod::Acf,
            acf: Some(r),
            b1: None,
        })
    } else {
        let r = b1_noise_id(kind, y, phase, m)?;
        Some(NoiseId {
            alpha: r.alpha.clamp(-2, 2),
            alpha_raw: r.alpha,
            alpha_est: None,
            method: if r.rn.is_some() {
                NoiseIdMethod::B1Rn
            } else {
                NoiseIdMethod::B1
            },
            acf: None,
            b1: Some(r),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn synth(alpha: i32, n: usize) -> Vec<f64> {
        let w = crate::testrng::TestRng::new(7).normals(n + 1, 1.0);
        match alpha {
            2 => w.windows(2).map(|p| p[1] - p[0]).collect(), // white PM: y = diff(white x)
            0 => w[..n].to_vec(),                             // white FM
            -2 => w[..n]
                .iter()
                .scan(0.0, |s, v| {
                    *s += v;
                    Some(*s)
                })
                .collect(), // random-walk FM
            _ => unreachable!(),
        }
    }

    #[test]
    fn acf_identifies_basic_noises() {
        for alpha in [2, 0, -2] {
            let y = synth(alpha, 40_000);
            for m in [1, 4, 16] {
                for flavor in [AcfFlavor::Stable32, AcfFlavor::Allantools] {
                    let r = acf_noise_id(&y, m, flavor, 2).unwrap();
                    assert_eq!(r.alpha_int, alpha, "alpha={alpha} m={m} {flavor:?} {r:?}");
                }
            }
        }
    }

    #[test]
    fn b1_identifies_basic_noises() {
        for (alpha, m) in [(0, 200), (-2, 200), (2, 150)] {
            let y = synth(alpha, 4000);
            let ph = Phase::from_frequency(&y, 1.0).unwrap();
            let r = b1_noise_id(DevKind::Adev, &y, &ph, m).unwrap();
            assert_eq!(r.alpha, alpha, "{r:?}");
        }
    }

    #[test]
    fn degenerate_input() {
        let y = vec![1.0; 100];
        assert!(acf_noise_id(&y, 1, AcfFlavor::Stable32, 2).is_none());
        assert!(acf_noise_id(&y, 0, AcfFlavor::Stable32, 2).is_none());
        assert!(acf_noise_id(&y[..29], 1, AcfFlavor::Stable32, 2).is_none());
        let ph = Phase::from_frequency(&y, 1.0).unwrap();
        assert!(b1_noise_id(DevKind::Adev, &y, &ph, 30).is_none());
        assert!(noise_id(DevKind::Oadev, &y, &ph, 1000, AcfFlavor::Stable32).is_none());
    }
}
