//! Equivalent degrees of freedom, C. A. Greenhall & W. J. Riley, "Uncertainty of
//! stability variances based on finite differences" (Proc. 35th PTTI, 2003), the
//! "combined" algorithm with its four cases, re-implemented from the published formulas.
//!
//! Notation: `d` = order of the phase difference (2 for the Allan family), `F` = filter
//! factor (`1` modified, `m` unmodified), `S` = stride factor (`m` overlapping, `1`
//! non-overlapping), `N` = number of **phase** points, `L = m/F + m·d`,
//! `M = 1 + floor(S·(N − L)/m)`, `J = min(M, (d+1)·S)`, `r = M/S`, `J_max = 100`.

use super::deviation::DevKind;

const J_MAX: f64 = 100.0;

/// Greenhall EDF for a variance of difference order `d` (1..=3) at averaging factor `m`
/// from `n_phase` phase points (= frequency samples + 1), noise type `alpha` (−4..=2).
///
/// Cases (as in the paper and allantools `edf_greenhall`; the `r > d+1` tests are strict,
/// like allantools):
/// 1. modified (F = 1), all α: exact sum if `J ≤ J_max`, else Table 1 if `r > d+1`,
///    else the sum with `J_max` terms and stride `m' = J_max/r`;
/// 2. unmodified, α ≤ 0: exact sum (with `F' = m` if `m(d+1) ≤ J_max`, else `F' = ∞`),
///    Table 2, or the `J_max` sum with `F = ∞`;
/// 3. unmodified, α = 1: as 2 with `F = m` and Table 3 `(b0 + b1 ln m)²` normalisation;
/// 4. unmodified, α = 2: `1/edf = (a0 − a1/r)/M` with `a0 = C(4d,2d)/C(2d,d)²`,
///    `a1 = d/2` when `ceil(r) > d`; otherwise the paper's short-record formula
///    `1/edf = [1 + 2 Σ_{k=1}^{K−1} (1 − k/r) C(2d,d−k)² / C(2d,d)²] / M`, `K = ceil(r)`
///    (allantools raises `NotImplementedError` there).
///
/// Returns `None` if the combination is undefined (`α + 2d ≤ 1`, α or d out of range,
/// `m = 0`, `M < 1`) or the result is not a positive finite number.
pub fn edf_greenhall(
    alpha: i32,
    d: u32,
    m: usize,
    n_phase: usize,
    overlapping: bool,
    modified: bool,
) -> Option<f64> {
    if !(1..=3).contains(&d) || !(-4..=2).contains(&alpha) || m == 0 {
        return None;
    }
    if alpha + 2 * d as i32 <= 1 {
        return None;
    }
    let mf = m as f64;
    let df = f64::from(d);
    let f = if modified { 1.0 } else { mf };
    let s = if overlapping { mf } else { 1.0 };
    let l = mf / f + mf * df;
    let big_m = 1.0 + (s * (n_phase as f64 - l) / mf).floor();
    if big_m.is_nan() || big_m < 1.0 {
        return None;
    }
    let j = big_m.min((df + 1.0) * s);
    let r = big_m / s;

    let inv_edf = if modified {
        // Case 1: modified variances, all alpha.
        let f = Filter::Finite(1.0);
        if j <= J_MAX {
            basic_sum(j, big_m, s, f, alpha, d) / (sz(0.0, f, alpha, d).powi(2) * big_m)
        } else if r > df + 1.0 {
            let (a0, a1) = table1(alpha, d)?;
            (a0 - a1 / r) / r
        } else {
            let m_prime = J_MAX / r;
            basic_sum(J_MAX, J_MAX, m_prime, f, alpha, d) / (sz(0.0, f, alpha, d).powi(2) * J_MAX)
        }
    } else if alpha <= 0 {
        // Case 2: unmodified variances, alpha <= 0.
        if j <= J_MAX {
            let fp = if mf * (df + 1.0) <= J_MAX {
                Filter::Finite(mf)
            } else {
                Filter::Infinite
            };
            basic_sum(j, big_m, s, fp, alpha, d) / (sz(0.0, fp, alpha, d).powi(2) * big_m)
        } else if r > df + 1.0 {
            let (a0, a1) = table2(alpha, d)?;
            (a0 - a1 / r) / r
        } else {
            let m_prime = J_MAX / r;
            let fi = Filter::Infinite;
            basic_sum(J_MAX, J_MAX, m_prime, fi, alpha, d) / (sz(0.0, fi, alpha, d).powi(2) * J_MAX)
        }
    } else if alpha == 1 {
        // Case 3: unmodified variances, alpha = 1 (flicker PM).
        let (b0, b1) = table3(d);
        let norm = b0 + b1 * mf.ln();
        if j <= J_MAX {
            let fm = Filter::Finite(mf);
            basic_sum(j, big_m, s, fm, 1, d) / (sz(0.0, fm, 1, d).powi(2) * big_m)
        } else if r > df + 1.0 {
            let (a0, a1) = table2(1, d)?;
            (a0 - a1 / r) / (norm * norm * r)
        } else {
            let m_prime = J_MAX / r;
            basic_sum(J_MAX, J_MAX, m_prime, Filter::Finite(m_prime), 1, d) / (norm * norm * J_MAX)
        }
    } else {
        // Case 4: unmodified variances, alpha = 2 (white PM).
        let k = r.ceil();
        let c2d_d = binomial(2 * d, d);
        if k <= df {
            let mut sum = 0.0;
            let mut kk = 1u32;
            while f64::from(kk) < k {
                let c = binomial(2 * d, d - kk);
                sum += (1.0 - f64::from(kk) / r) * c * c;
                kk += 1;
            }
            (1.0 + 2.0 * sum / (c2d_d * c2d_d)) / big_m
        } else {
            let a0 = binomial(4 * d, 2 * d) / (c2d_d * c2d_d);
            let a1 = df / 2.0;
            (a0 - a1 / r) / big_m
        }
    };
    let edf = 1.0 / inv_edf;
    (edf.is_finite() && edf > 0.0).then_some(edf)
}

/// Greenhall EDF for a deviation `kind` at factor `m` on `n_samples` frequency samples
/// (`n_samples + 1` phase points, `d = 2`).
pub fn edf_for_kind(kind: DevKind, alpha: i32, m: usize, n_samples: usize) -> Option<f64> {
    let (d, overlapping, modified) = kind.greenhall_params();
    edf_greenhall(
        alpha,
        d,
        m,
        n_samples.checked_add(1)?,
        overlapping,
        modified,
    )
}

#[derive(Clone, Copy)]
enum Filter {
    Finite(f64),
    Infinite,
}

/// Eq. (7): generalized autocovariance kernel of the power-law phase noise.
/// (Overall signs per α are irrelevant: only ratios of squares of `sz` are used.)
fn sw(t: f64, alpha: i32) -> f64 {
    let a = t.abs();
    match alpha {
        2 => -a,
        1 if t != 0.0 => t * t * a.ln(),
        0 => a * a * a,
        -1 if t != 0.0 => (t * t) * (t * t) * a.ln(),
        -2 => (a * a) * (a * a) * a,
        -3 if t != 0.0 => (t * t) * (t * t) * (t * t) * a.ln(),
        -4 => (a * a) * (a * a) * (a * a) * a,
        _ => 0.0,
    }
}

/// Eq. (8): effect of the averaging filter; `F = ∞` means no filtering (α → α + 2).
fn sx(t: f64, f: Filter, alpha: i32) -> f64 {
    match f {
        Filter::Infinite => sw(t, alpha + 2),
        Filter::Finite(f) => {
            let h = 1.0 / f;
            f * f * (2.0 * sw(t, alpha) - sw(t - h, alpha) - sw(t + h, alpha))
        }
    }
}

/// Eq. (9): d-th order binomial difference `Σ_k (−1)^k C(2d, d+k) sx(t + k)`
/// (terms added in the order of the paper's explicit formulas).
fn sz(t: f64, f: Filter, alpha: i32, d: u32) -> f64 {
    let x = |k: f64| sx(t + k, f, alpha);
    match d {
        1 => 2.0 * x(0.0) - x(-1.0) - x(1.0),
        2 => 6.0 * x(0.0) - 4.0 * x(-1.0) - 4.0 * x(1.0) + x(-2.0) + x(2.0),
        _ => {
            20.0 * x(0.0) - 15.0 * x(-1.0) - 15.0 * x(1.0) + 6.0 * x(-2.0) + 6.0 * x(2.0)
                - x(-3.0)
                - x(3.0)
        }
    }
}

/// Eq. (10): `sz(0)² + (1 − J/M) sz(J/S)² + 2 Σ_{j=1}^{J−1} (1 − j/M) sz(j/S)²`.
fn basic_sum(j: f64, big_m: f64, s: f64, f: Filter, alpha: i32, d: u32) -> f64 {
    let first = sz(0.0, f, alpha, d).powi(2);
    let second = (1.0 - j / big_m) * sz(j / s, f, alpha, d).powi(2);
    let mut third = 0.0;
    let j_int = j as u64;
    for jj in 1..j_int {
        let jf = jj as f64;
        third += 2.0 * (1.0 - jf / big_m) * sz(jf / s, f, alpha, d).powi(2);
    }
    first + second + third
}

fn binomial(n: u32, k: u32) -> f64 {
    if k > n {
        return 0.0;
    }
    let k = k.min(n - k);
    let mut c = 1.0;
    for i in 0..k {
        c = c * f64::from(n - i) / f64::from(i + 1);
    }
    c.round()
}

/// Table 1 (modified variances): `(a0, a1)` for rows α = 2..−4, columns d = 1..3.
fn table1(alpha: i32, d: u32) -> Option<(f64, f64)> {
    const NA: (f64, f64) = (f64::NAN, f64::NAN);
    const T: [[(f64, f64); 3]; 7] = [
        [
            (2.0 / 3.0, 1.0 / 3.0),
            (7.0 / 9.0, 1.0 / 2.0),
            (22.0 / 25.0, 2.0 / 3.0),
        ],
        [(0.840, 0.345), (0.997, 0.616), (1.141, 0.843)],
        [(1.079, 0.368), (1.033, 0.607), (1.184, 0.848)],
        [NA, (1.048, 0.534), (1.180, 0.816)],
        [NA, (1.302, 0.535), (1.175, 0.777)],
        [NA, NA, (1.194, 0.703)],
        [NA, NA, (1.489, 0.702)],
    ];
    lookup(&T, alpha, d)
}

/// Table 2 (unmodified variances): `(a0, a1)` for rows α = 2..−4, columns d = 1..3.
fn table2(alpha: i32, d: u32) -> Option<(f64, f64)> {
    const NA: (f64, f64) = (f64::NAN, f64::NAN);
    const T: [[(f64, f64); 3]; 7] = [
        [
            (3.0 / 2.0, 1.0 / 2.0),
            (35.0 / 18.0, 1.0),
            (231.0 / 100.0, 3.0 / 2.0),
        ],
        [(78.6, 25.2), (790.0, 410.0), (9950.0, 6520.0)],
        [
            (2.0 / 3.0, 1.0 / 6.0),
            (2.0 / 3.0, 1.0 / 3.0),
            (7.0 / 9.0, 1.0 / 2.0),
        ],
        [NA, (0.852, 0.375), (0.997, 0.617)],
        [NA, (1.079, 0.368), (1.033, 0.607)],
        [NA, NA, (1.053, 0.553)],
        [NA, NA, (1.302, 0.535)],
    ];
    lookup(&T, alpha, d)
}

/// Table 3 (unmodified, α = 1): `(b0, b1)` for d = 1..3.
fn table3(d: u32) -> (f64, f64) {
    match d {
        1 => (6.0, 4.0),
        2 => (15.23, 12.0),
        _ => (47.8, 40.0),
    }
}

fn lookup(t: &[[(f64, f64); 3]; 7], alpha: i32, d: u32) -> Option<(f64, f64)> {
    let row = usize::try_from(2 - alpha).ok()?;
    let col = usize::try_from(d.checked_sub(1)?).ok()?;
    let v = *t.get(row)?.get(col)?;
    v.0.is_finite().then_some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn white_fm_large_n_approaches_simple_formula() {
        // OADEV, white FM: edf ≈ (3(N−1)/(2m) − 2(N−2)/N) · 4m²/(4m²+5) (NIST SP 1065 Table 5)
        let n = 100_001usize;
        for m in [64usize, 128, 256] {
            let e = edf_greenhall(0, 2, m, n, true, false).unwrap();
            let (nf, mf) = ((n - 1) as f64, m as f64);
            let simple = (3.0 * (nf - 1.0) / (2.0 * mf) - 2.0 * (nf - 2.0) / nf)
                * (4.0 * mf * mf / (4.0 * mf * mf + 5.0));
            assert!((e / simple - 1.0).abs() < 0.02, "m={m}: {e} vs {simple}");
        }
    }

    #[test]
    fn invalid_combinations() {
        assert!(edf_greenhall(-3, 2, 4, 1000, true, false).is_none());
        assert!(edf_greenhall(0, 0, 4, 1000, true, false).is_none());
        assert!(edf_greenhall(0, 2, 0, 1000, true, false).is_none());
        assert!(edf_greenhall(0, 2, 600, 1000, false, false).is_none());
        assert!(edf_greenhall(3, 2, 4, 1000, true, false).is_none());
    }

    #[test]
    fn white_pm_short_record_branch_is_continuous() {
        // OADEV m = 300: N = 1200 phase points gives r = 2 (K = 2 <= d, short-record
        // formula), N = 1201 gives r just above 2 (K = 3, a0/a1 formula).
        let a = edf_greenhall(2, 2, 300, 1200, true, false).unwrap();
        let b = edf_greenhall(2, 2, 300, 1201, true, false).unwrap();
        assert!((a / b - 1.0).abs() < 0.01, "{a} vs {b}");
    }
}
