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
///
/// By selection (`select_nth_unstable`, linear time), not a full sort: the same values as sorting.
pub fn median(v: &[f64]) -> f64 {
    median_in(v, &mut Vec::new())
}

/// [`median`] with `scratch` as its working space (for many medians without an allocation each).
pub fn median_in(v: &[f64], scratch: &mut Vec<f64>) -> f64 {
    scratch.clear();
    scratch.extend(v.iter().copied().filter(|x| x.is_finite()));
    let s = scratch;
    let n = s.len();
    if n == 0 {
        return f64::NAN;
    }
    let mid = n / 2;
    let (below, &mut hi, _) = s.select_nth_unstable_by(mid, f64::total_cmp);
    if n % 2 == 1 {
        return hi;
    }
    // The lower middle value is the largest of those below the upper one.
    below
        .iter()
        .copied()
        .max_by(f64::total_cmp)
        .map_or(f64::NAN, |lo| 0.5 * (lo + hi))
}

/// For each `i`, `out[i]` = the [`median`] of the others (`v` without `v[i]`), the same values bit for bit, from one
/// sort of `v` (in `sorted`, working space) instead of a selection per `i`: the others' middle values are the sorted
/// values around the middle, one place further up where `v[i]` itself lies below them.
pub fn medians_of_others(v: &[f64], sorted: &mut Vec<f64>, out: &mut [f64]) {
    sorted.clear();
    sorted.extend(v.iter().copied().filter(|x| x.is_finite()));
    sorted.sort_unstable_by(f64::total_cmp);
    let s = &sorted[..];
    for (o, &x) in out.iter_mut().zip(v) {
        // Leaving out a non-finite value leaves the finite ones (which `median` keeps) as they are. A finite one
        // leaves out its first copy in the order (`total_cmp`: equal only when bit-identical).
        let (skip, m) = if x.is_finite() {
            (s.partition_point(|y| y.total_cmp(&x).is_lt()), s.len() - 1)
        } else {
            (s.len(), s.len())
        };
        let at = |j: usize| s.get(if j < skip { j } else { j + 1 }).copied();
        let mid = m / 2;
        *o = match (m, at(mid)) {
            (0, _) | (_, None) => f64::NAN,
            (_, Some(hi)) if m % 2 == 1 => hi,
            (_, Some(hi)) => mid
                .checked_sub(1)
                .and_then(at)
                .map_or(f64::NAN, |lo| 0.5 * (lo + hi)),
        };
    }
}

/// Sample standard deviation (divisor `n − 1`; NaN for fewer than two values).
pub fn std_dev(v: &[f64]) -> f64 {
    let m = mean(v);
    (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() as f64 - 1.0)).sqrt()
}

/// A least-squares sinusoid `sin·sin(ωt) + cos·cos(ωt)` (no offset) through `(t, y)` points ([`fit_sinusoid`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SineFit {
    /// Coefficient of `sin(ωt)`.
    pub sin: f64,
    /// Coefficient of `cos(ωt)`.
    pub cos: f64,
    /// The sum of squares the fit removes from the `y`.
    pub removed: f64,
}

impl SineFit {
    /// The amplitude, `√(sin² + cos²)`.
    pub fn amplitude(&self) -> f64 {
        self.sin.hypot(self.cos)
    }
}

/// The least-squares [`SineFit`] at angular frequency `omega` (rad per unit of `t`) through `points`; `None` when
/// sine and cosine cannot be told apart on these times (their normal matrix is singular: no points, or too few).
pub fn fit_sinusoid(points: impl IntoIterator<Item = (f64, f64)>, omega: f64) -> Option<SineFit> {
    let (mut ss, mut cc, mut sc, mut sy, mut cy) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for (t, y) in points {
        let (s, c) = (omega * t).sin_cos();
        ss += s * s;
        cc += c * c;
        sc += s * c;
        sy += s * y;
        cy += c * y;
    }
    let det = ss * cc - sc * sc;
    if det.abs() < 1e-300 {
        return None;
    }
    let sin = (cc * sy - sc * cy) / det;
    let cos = (ss * cy - sc * sy) / det;
    Some(SineFit {
        sin,
        cos,
        removed: sin * sy + cos * cy,
    })
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

    /// Each sensor's median of the others from one sort is `median` of the vector without it, bit for bit: random
    /// vectors of 1 to 20 values with ties, ±0, NaN and ±∞ mixed in.
    #[test]
    fn medians_of_others_are_the_medians_without_each() {
        let mut rng = crate::testrng::TestRng::new(12);
        let special = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 0.0, -0.0];
        let (mut sorted, mut out) = (Vec::new(), Vec::new());
        for trial in 0..2000 {
            let n = 1 + trial % 20;
            let v: Vec<f64> = (0..n)
                .map(|_| {
                    let u = rng.normal();
                    if u > 1.5 {
                        special[((u * 100.0) as usize) % special.len()]
                    } else {
                        (u * 3.0).round() * 0.5
                    }
                })
                .collect();
            out.resize(n, 0.0);
            medians_of_others(&v, &mut sorted, &mut out);
            for (i, got) in out.iter().enumerate() {
                let others: Vec<f64> = (0..n).filter(|&j| j != i).map(|j| v[j]).collect();
                let want = median(&others);
                assert_eq!(got.to_bits(), want.to_bits(), "{v:?} without {i}");
            }
        }
    }

    /// The median by selection equals the middle of the sorted values (the mean of the two middle ones for an even
    /// count), bit for bit, on random vectors with ties, of every length from 1 to 60.
    #[test]
    fn median_is_the_middle_of_the_sorted_values() {
        let mut rng = crate::testrng::TestRng::new(11);
        for n in 1..=60 {
            let v: Vec<f64> = (0..n).map(|_| (rng.normal() * 4.0).round()).collect();
            let mut s = v.clone();
            s.sort_by(f64::total_cmp);
            let want = if n % 2 == 1 {
                s[n / 2]
            } else {
                0.5 * (s[n / 2 - 1] + s[n / 2])
            };
            assert_eq!(median(&v).to_bits(), want.to_bits(), "{v:?}");
        }
    }

    /// An exact sinusoid plus a component at another frequency, on uneven times: the fit recovers the coefficients
    /// at its own frequency (to the leakage of the other, ≪ 5e-3), and what it removes is their energy; with no
    /// point, or one at t = 0, there is nothing to fit.
    #[test]
    fn sinusoid_fit() {
        let w = 0.37;
        let t: Vec<f64> = (0..4000)
            .map(|k| k as f64 * 0.5 + 0.01 * (k % 7) as f64)
            .collect();
        let y: Vec<f64> = t
            .iter()
            .map(|&t| 1.5 * (w * t).sin() - 0.25 * (w * t).cos() + 0.3 * (2.9 * t).sin())
            .collect();
        let fit = fit_sinusoid(t.iter().copied().zip(y.iter().copied()), w).unwrap();
        assert!((fit.sin - 1.5).abs() < 5e-3, "{fit:?}");
        assert!((fit.cos + 0.25).abs() < 5e-3, "{fit:?}");
        let pure: f64 = t
            .iter()
            .map(|&t| (1.5 * (w * t).sin() - 0.25 * (w * t).cos()).powi(2))
            .sum();
        assert!(
            (fit.removed / pure - 1.0).abs() < 5e-3,
            "{} vs {pure}",
            fit.removed
        );
        assert!((fit.amplitude() - 1.5f64.hypot(0.25)).abs() < 5e-3);
        assert_eq!(fit_sinusoid(std::iter::empty(), w), None);
        assert_eq!(
            fit_sinusoid([(0.0, 1.0)], w),
            None,
            "one point: the sine is 0 there"
        );
    }
}
