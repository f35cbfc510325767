//! Averaging-factor (τ) lists.

use super::deviation::DevKind;

/// How to choose the averaging factors `m` (τ = m·τ0).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum TauSpec {
    /// `m = 1, 2, 4, 8, …` (allantools `"octave"`).
    Octave,
    /// `m = 1, 2, 4, 10, 20, 40, 100, …` (allantools / Stable32 `"decade"`).
    Decade,
    /// Every `m = 1, 2, 3, …` (allantools `"all"`; O(N²) in total, use with care).
    All,
    /// About `n` log-spaced factors per decade: `m_k = round(10^(k/n))`, `k = 0, 1, …`,
    /// duplicates removed (so below `m ≈ n/ln 10` every integer appears once).
    PerDecade(u32),
    /// Explicit factors (sorted, de-duplicated, invalid ones dropped).
    Factors(Vec<usize>),
}

impl TauSpec {
    /// The spec a user names: `octave`, `decade`, `all`, or a positive number of points per decade (`ground allan
    /// --taus`, the Python package's `taus`).
    pub fn parse(s: &str) -> Result<TauSpec, super::ParseError> {
        Ok(match s {
            "octave" => TauSpec::Octave,
            "decade" => TauSpec::Decade,
            "all" => TauSpec::All,
            n => TauSpec::PerDecade(
                n.parse()
                    .ok()
                    .filter(|&n: &u32| n > 0)
                    .ok_or_else(|| super::ParseError::Taus(n.to_owned()))?,
            ),
        })
    }
}

/// The averaging factors for `spec`, for a deviation of `kind` on `n_samples` frequency
/// samples, sorted ascending without duplicates.
///
/// The maximum-m rule is the one of allantools: a factor is kept only while the estimator
/// has at least two terms ([`DevKind::max_m`]): ADEV `m ≤ N/3`, OADEV `m ≤ (N−1)/2`,
/// MDEV `m ≤ N/3`. (allantools first generates octave/decade factors up to
/// `len(phase) = N + 1` and then drops the `n ≤ 1` results; the outcome is identical.)
/// Stable32 stops earlier (`m ≤ N / stop_ratio`, see [`DevKind::stable32_stop_ratio`]);
/// pass [`TauSpec::Factors`] to reproduce that.
pub fn averaging_factors(spec: &TauSpec, kind: DevKind, n_samples: usize) -> Vec<usize> {
    let max_m = kind.max_m(n_samples);
    if max_m == 0 {
        return Vec::new();
    }
    let mut out = Vec::new();
    match spec {
        TauSpec::Octave => {
            let mut m = 1usize;
            while m <= max_m {
                out.push(m);
                match m.checked_mul(2) {
                    Some(next) => m = next,
                    None => break,
                }
            }
        }
        TauSpec::Decade => {
            let mut p = 1usize;
            'outer: loop {
                for k in [1usize, 2, 4] {
                    match p.checked_mul(k) {
                        Some(m) if m <= max_m => out.push(m),
                        _ => break 'outer,
                    }
                }
                match p.checked_mul(10) {
                    Some(next) => p = next,
                    None => break,
                }
            }
        }
        TauSpec::All => out.extend(1..=max_m),
        TauSpec::PerDecade(n) => {
            if *n == 0 {
                return out;
            }
            let n = f64::from(*n);
            for k in 0u32.. {
                let mf = 10f64.powf(f64::from(k) / n).round();
                if mf.is_nan() || mf > max_m as f64 {
                    break;
                }
                let m = mf as usize;
                if out.last() != Some(&m) {
                    out.push(m);
                }
            }
        }
        TauSpec::Factors(ms) => {
            out.extend(ms.iter().copied().filter(|&m| m >= 1 && m <= max_m));
            out.sort_unstable();
            out.dedup();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn octave_and_decade() {
        let n = 19982;
        assert_eq!(
            averaging_factors(&TauSpec::Octave, DevKind::Adev, n).last(),
            Some(&4096)
        );
        assert_eq!(
            averaging_factors(&TauSpec::Octave, DevKind::Oadev, n).last(),
            Some(&8192)
        );
        assert_eq!(
            averaging_factors(&TauSpec::Decade, DevKind::Oadev, n),
            vec![1, 2, 4, 10, 20, 40, 100, 200, 400, 1000, 2000, 4000]
        );
        assert!(averaging_factors(&TauSpec::Octave, DevKind::Adev, 2).is_empty());
        assert_eq!(
            averaging_factors(&TauSpec::Octave, DevKind::Adev, 3),
            vec![1]
        );
    }

    #[test]
    fn per_decade() {
        let ms = averaging_factors(&TauSpec::PerDecade(10), DevKind::Oadev, 1000);
        assert_eq!(ms[..8], [1, 2, 3, 4, 5, 6, 8, 10]);
        assert_eq!(ms.last(), Some(&398));
        assert!(ms.windows(2).all(|w| w[0] < w[1]));
        assert!(averaging_factors(&TauSpec::PerDecade(0), DevKind::Oadev, 1000).is_empty());
    }

    #[test]
    fn explicit_factors_are_cleaned() {
        let ms = averaging_factors(&TauSpec::Factors(vec![5, 0, 3, 5, 100]), DevKind::Mdev, 30);
        assert_eq!(ms, vec![3, 5]);
    }
}
