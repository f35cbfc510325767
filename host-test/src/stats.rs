//! Small statistics on slices of `f64`, one implementation each: mean, RMS, median, sample standard deviation.

use std::borrow::Borrow;

/// Arithmetic mean (NaN for no values).
pub fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Root mean square about zero (0 for no values): of a slice (`rms(&v)`) or of any values (`rms(it)`).
pub fn rms<T: Borrow<f64>>(v: impl IntoIterator<Item = T>) -> f64 {
    let (s, n) = v.into_iter().fold((0.0, 0usize), |(s, n), x| {
        let x = *x.borrow();
        (s + x * x, n + 1)
    });
    if n == 0 { 0.0 } else { (s / n as f64).sqrt() }
}

/// Median of the finite values (NaN if there are none); the mean of the middle two for an even count.
pub fn median(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
    s.sort_by(f64::total_cmp);
    let mid = s.len() / 2;
    match (s.len() % 2, s.get(mid.wrapping_sub(1)), s.get(mid)) {
        (1, _, Some(&m)) => m,
        (0, Some(&lo), Some(&hi)) => 0.5 * (lo + hi),
        _ => f64::NAN,
    }
}

/// Sample standard deviation (divisor `n − 1`; NaN for fewer than two values).
pub fn std_dev(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_cases() {
        assert_eq!(mean(&[1.0, 2.0, 6.0]), 3.0);
        assert_eq!(rms([3.0, 4.0, 0.0, 0.0]), 2.5);
        assert_eq!(rms(Vec::<f64>::new()), 0.0);
        assert_eq!(median(&[3.0, f64::NAN, 1.0, 2.0]), 2.0);
        assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), 2.5);
        assert!(median(&[f64::NAN]).is_nan());
        assert_eq!(std_dev(&[1.0, 3.0]), 2f64.sqrt());
        assert!(std_dev(&[1.0]).is_nan());
    }
}
