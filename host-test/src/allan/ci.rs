//! Chi-squared confidence intervals for a deviation.

use statrs::distribution::{ChiSquared, Continuous, ContinuousCDF, Normal};

/// Two-sided confidence of ±1 σ of a normal law, `erf(1/√2) = 0.682689…`
/// (allantools' default; Stable32 prints "Confidence Factor = 0.683").
pub const ONE_SIGMA_CI: f64 = 0.682_689_492_137_085_9;

/// Confidence interval `(dev_lo, dev_hi)` of a deviation `dev` with `edf` equivalent
/// degrees of freedom and two-sided confidence `ci` (e.g. [`ONE_SIGMA_CI`]), the form of
/// NIST SP 1065 eq. (45) as used by allantools `confidence_interval`:
///
/// ```text
/// p_lo = min(ci, 1 − ci)/2,  p_hi = 1 − p_lo
/// dev_lo = dev · sqrt(edf / χ²⁻¹(p_hi; edf)),  dev_hi = dev · sqrt(edf / χ²⁻¹(p_lo; edf))
/// ```
///
/// `dev_lo`/`dev_hi` are in the unit of `dev`. `None` if `dev` is negative or not finite,
/// `edf` not positive and finite, `ci` not strictly between 0 and 1, or the quantiles
/// are numerically degenerate.
pub fn confidence_interval(dev: f64, edf: f64, ci: f64) -> Option<(f64, f64)> {
    if !(dev.is_finite() && dev >= 0.0) {
        return None;
    }
    interval_from_quantiles(dev, edf, chi2_quantiles(edf, ci)?)
}

/// The χ² quantiles `(χ²⁻¹(p_lo; edf), χ²⁻¹(p_hi; edf))` of [`confidence_interval`]: they depend on `edf` and `ci`
/// only, so a caller with many deviations of the same EDF (the columns of one recording) can keep them. `None` as
/// for [`confidence_interval`].
pub(crate) fn chi2_quantiles(edf: f64, ci: f64) -> Option<(f64, f64)> {
    if !(edf.is_finite() && edf > 0.0) {
        return None;
    }
    if !(ci > 0.0 && ci < 1.0) {
        return None;
    }
    let p_lo = ci.min(1.0 - ci) / 2.0;
    let p_hi = 1.0 - p_lo;
    let chi2 = ChiSquared::new(edf).ok()?;
    let q_lo = chi2_quantile(&chi2, p_lo)?;
    let q_hi = chi2_quantile(&chi2, p_hi)?;
    (q_lo > 0.0 && q_hi.is_finite()).then_some((q_lo, q_hi))
}

/// [`confidence_interval`] of `dev` from the quantiles [`chi2_quantiles`] gives for `edf`.
pub(crate) fn interval_from_quantiles(
    dev: f64,
    edf: f64,
    (q_lo, q_hi): (f64, f64),
) -> Option<(f64, f64)> {
    if !(dev.is_finite() && dev >= 0.0) {
        return None;
    }
    let var = dev * dev;
    let (lo, hi) = ((edf * var / q_hi).sqrt(), (edf * var / q_lo).sqrt());
    // Degenerate edf (e.g. 1e-300) can make the quantiles meaningless: refuse.
    (lo.is_finite() && hi.is_finite() && lo <= dev && dev <= hi).then_some((lo, hi))
}

/// Chi-squared quantile: `statrs`' bracketed Newton solution, polished by up to three
/// further Newton steps (statrs stops once a step is below 1e-9 *absolute*, which leaves
/// ~1e-10 relative error for quantiles of order 1–10).
fn chi2_quantile(chi2: &ChiSquared, p: f64) -> Option<f64> {
    let mut x = chi2.inverse_cdf(p);
    for _ in 0..3 {
        let pdf = chi2.pdf(x);
        if !(x > 0.0 && x.is_finite() && pdf > 0.0) {
            break;
        }
        let step = (chi2.cdf(x) - p) / pdf;
        let next = x - step;
        if !(next > 0.0 && next.is_finite()) {
            break;
        }
        x = next;
        if step.abs() <= 1e-15 * x {
            break;
        }
    }
    (x > 0.0 && x.is_finite()).then_some(x)
}

/// `E[χ²_ν/ν] / median(χ²_ν/ν)`: corrects a median of variance estimates with `nu` EDF to their mean.
pub fn median_to_mean(nu: f64) -> f64 {
    ChiSquared::new(nu)
        .map(|c| nu / c.inverse_cdf(0.5))
        .ok()
        .filter(|x| x.is_finite() && *x > 0.0)
        .unwrap_or(1.0)
}

/// z-score of a χ²_ν/ν variable observed at `ratio`: Φ⁻¹(F_χ²ν(ν·ratio)), from the tail the value lies in (so
/// that z stays exact far out), clamped to ±30.
pub fn chi2_z(ratio: f64, nu: f64) -> f64 {
    let (Ok(c), Ok(n)) = (ChiSquared::new(nu), Normal::new(0.0, 1.0)) else {
        return 0.0;
    };
    let x = nu * ratio.max(0.0);
    let z = if ratio > 1.0 {
        -n.inverse_cdf(c.sf(x).max(1e-300))
    } else {
        n.inverse_cdf(c.cdf(x).max(1e-300))
    };
    if z.is_finite() {
        z.clamp(-30.0, 30.0)
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_sigma_constant() {
        // erf(1/sqrt 2) to 16 digits
        assert!((ONE_SIGMA_CI - 0.682_689_492_137_086).abs() < 1e-15);
    }

    #[test]
    fn interval_brackets_dev_and_shrinks_with_edf() {
        let (lo1, hi1) = confidence_interval(1.0, 10.0, ONE_SIGMA_CI).unwrap();
        let (lo2, hi2) = confidence_interval(1.0, 1000.0, ONE_SIGMA_CI).unwrap();
        assert!(lo1 < lo2 && lo2 < 1.0 && 1.0 < hi2 && hi2 < hi1);
        // large edf: relative half-width ≈ 1/sqrt(2 edf)
        assert!(((hi2 - lo2) / 2.0 - 1.0 / (2000f64).sqrt()).abs() < 1e-3);
    }

    #[test]
    fn bad_input() {
        assert!(confidence_interval(1.0, 0.0, 0.68).is_none());
        assert!(confidence_interval(1.0, f64::NAN, 0.68).is_none());
        assert!(confidence_interval(-1.0, 5.0, 0.68).is_none());
        assert!(confidence_interval(1.0, 5.0, 1.0).is_none());
        assert!(confidence_interval(1.0, 5.0, 0.0).is_none());
        assert_eq!(confidence_interval(0.0, 5.0, 0.68), Some((0.0, 0.0)));
    }
}
