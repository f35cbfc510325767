//! The overlapping Allan variance's sums at many averaging factors in one pass over the phase.
//!
//! For each factor `m`: `Σ (x[i+2m] − 2x[i+m] + x[i])²` over `0 ≤ i < L − 2m`. The phase of an 8-h record at
//! 18.9 Hz (4.4 MB) does not fit in the L2 cache, so one pass per factor reads it from the L3 cache once per factor,
//! and up to three times per factor when `m` is large (the windows at `i`, `i + m` and `i + 2m` are then far apart).
//! Here the rows are taken in blocks of [`BLOCK`], and the terms of every factor in a block are summed before the next
//! block: the window at `i` is read once for all factors, the octave factors' windows share offsets (`2m` of one
//! factor is `m` of the next), and all the windows of a block stay in the L2 cache.
//!
//! Each factor's terms are added in exactly the order of `lanes::sum3` (lane `i mod 8` in increasing `i`, then the
//! remainder serially, then the lanes combined), so every sum is bit-identical to one pass per factor. The block loop
//! is also compiled for AVX2 and chosen at run time: the same operations on wider registers (no fused multiply-add,
//! which Rust never forms by itself), so the same bits.

use super::lanes::{self, LANES, combine};

/// Phase points per block (16 KiB): a block's ≈ 20 windows (octave factors) fill about a third of the L2 cache.
const BLOCK: usize = 2048;

/// `Σ (x[i+2m] − 2x[i+m] + x[i])²` over `0 ≤ i < x.len() − 2m` for every `m` of `ms`, each summed in the order of
/// `lanes::sum3` (bit-identical to it). A factor without a term (`m = 0`, or `x.len() < 2m + 1`) gives 0.
pub(super) fn second_difference_sums(x: &[f64], ms: &[usize]) -> Vec<f64> {
    let terms: Vec<usize> = ms
        .iter()
        .map(|&m| match m {
            0 => 0,
            _ => x.len().saturating_sub(m.saturating_mul(2)),
        })
        .collect();
    let mut acc = vec![[0.0; LANES]; ms.len()];
    lane_sums(x, ms, &terms, &mut acc);
    ms.iter()
        .zip(&terms)
        .zip(&acc)
        .map(|((&m, &n), lanes)| {
            let whole = n - n % LANES;
            let mut tail = 0.0;
            if n == 0 {
                // No term (and `2m` may not be an index).
                return combine(*lanes);
            }
            let (a, b, c) = (
                x.get(whole + 2 * m..n + 2 * m).unwrap_or(&[]),
                x.get(whole + m..n + m).unwrap_or(&[]),
                x.get(whole..n).unwrap_or(&[]),
            );
            for ((a, b), c) in a.iter().zip(b).zip(c) {
                let d = a - 2.0 * b + c;
                tail += d * d;
            }
            combine(*lanes) + tail
        })
        .collect()
}

/// The terms `(x[i+2m] − 2x[i+m] + x[i])²` of a whole phase `x` that straddle the point `h` (`x[..=h]` and `x[h..]`
/// being the phases of two consecutive parts of the series), summed at every factor of `ms`: those that neither
/// part's own [`second_difference_sums`] holds, at `max(0, h + 1 − 2m) ≤ i < min(h, x.len() − 2m)`, at most `2m − 1`.
/// Since a second difference does not see a straight line, the parts' phases may be integrated from their own means:
/// in exact arithmetic the whole's sum at `m` is the first part's + the second part's + this one. A factor without
/// such a term (`m = 0`, or `h` beyond the phase) gives 0.
pub(super) fn straddling_sums(x: &[f64], h: usize, ms: &[usize]) -> Vec<f64> {
    ms.iter()
        .map(|&m| {
            let Some(two_m) = m.checked_mul(2).filter(|_| m > 0) else {
                return 0.0;
            };
            let lo = (h + 1).saturating_sub(two_m);
            let hi = h.min(x.len().saturating_sub(two_m));
            match (
                x.get(lo + two_m..hi + two_m),
                x.get(lo + m..hi + m),
                x.get(lo..hi),
            ) {
                (Some(a), Some(b), Some(c)) if lo < hi => lanes::sum3(a, b, c, |a, b, c| {
                    let d = a - 2.0 * b + c;
                    d * d
                }),
                _ => 0.0,
            }
        })
        .collect()
}

/// The lane sums of the whole groups of [`LANES`] terms of every factor, block by block (`terms[j]`: the terms of
/// factor `ms[j]`; `acc[j]`: its lanes, added to).
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn lane_sums(x: &[f64], ms: &[usize], terms: &[usize], acc: &mut [[f64; LANES]]) {
    let longest = terms.iter().map(|n| n - n % LANES).max().unwrap_or(0);
    let mut lo = 0;
    while lo < longest {
        let hi = (lo + BLOCK).min(longest);
        for ((&m, &n), lanes) in ms.iter().zip(terms).zip(acc.iter_mut()) {
            let end = hi.min(n - n % LANES);
            if end <= lo {
                continue;
            }
            let (Some(a), Some(b), Some(c)) = (
                x.get(lo + 2 * m..end + 2 * m),
                x.get(lo + m..end + m),
                x.get(lo..end),
            ) else {
                continue;
            };
            let mut s = *lanes;
            for ((a, b), c) in a
                .chunks_exact(LANES)
                .zip(b.chunks_exact(LANES))
                .zip(c.chunks_exact(LANES))
            {
                for k in 0..LANES {
                    let d = a[k] - 2.0 * b[k] + c[k];
                    s[k] += d * d;
                }
            }
            *lanes = s;
        }
        lo = hi;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sums one factor at a time, through `lanes::sum3` (the order the blocked pass must keep).
    fn one_by_one(x: &[f64], m: usize) -> f64 {
        if m == 0 || x.len() <= m.saturating_mul(2) {
            return 0.0;
        }
        let n = x.len() - 2 * m;
        super::super::lanes::sum3(&x[2 * m..], &x[m..m + n], &x[..n], |a, b, c| {
            let d = a - 2.0 * b + c;
            d * d
        })
    }

    #[test]
    fn blocked_sums_are_bit_identical_to_one_pass_per_factor() {
        let mut rng = crate::testrng::TestRng::new(31);
        let mut acc = 0.0;
        // Lengths around the block and lane sizes; a random walk, so rounding differs with any change of order.
        for len in [
            0,
            1,
            2,
            3,
            9,
            17,
            2047,
            2048,
            2049,
            4096 + 13,
            3 * BLOCK + 7,
        ] {
            let x: Vec<f64> = (0..len)
                .map(|_| {
                    acc += rng.uniform() - 0.5;
                    acc
                })
                .collect();
            let mut ms = vec![0, 1, 2, 3, 5, 8, 1000, 1024, 2048, 4096, 5000, usize::MAX];
            ms.extend((0..20).map(|k| 1usize << k));
            let got = second_difference_sums(&x, &ms);
            for (&m, g) in ms.iter().zip(&got) {
                assert_eq!(g.to_bits(), one_by_one(&x, m).to_bits(), "len {len}, m {m}");
            }
        }
    }

    #[test]
    fn sums_match_a_serial_textbook_sum() {
        // Integer data: every sum is exact in f64 in any order, so this checks which terms are summed.
        let x: Vec<f64> = (0..5000).map(|i| f64::from((i * i) % 113) - 50.0).collect();
        for m in [1, 7, 64, 2048, 2499, 2500] {
            let want: f64 = (0..x.len().saturating_sub(2 * m))
                .map(|i| {
                    let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
                    d * d
                })
                .sum();
            assert_eq!(second_difference_sums(&x, &[m]), vec![want], "m {m}");
        }
    }
}
