//! Robust statistics of one axis: the sorting network, median, MAD and its running average (see the module docs
//! of `fuse`).

use super::div_round;

/// 1.4826 · 2¹⁶: MAD → σ of a normal distribution, Q16.
pub(super) const MAD_TO_SIGMA_Q16: u64 = 97_163;

/// The cluster MAD is averaged over 2^SCALE_SHIFT samples (see module docs).
pub(super) const SCALE_SHIFT: u32 = 4;

/// Per-axis robust scale: EWMA of the cluster MAD, Q16 of output units.
#[derive(Clone, Copy, Debug)]
pub(super) struct AxisScale {
    pub(super) mad_q16: i64,
    pub(super) init: bool,
}

impl AxisScale {
    pub(super) const NEW: Self = Self {
        mad_q16: 0,
        init: false,
    };

    /// Averages `mad` in; returns the averaged scale (output units, rounded up).
    ///
    /// Plain arithmetic, so that builds with overflow checks keep checking the bound: `mad` is an `i32` MAD, so
    /// |x| < 2⁴⁷; `mad_q16` starts at such an x and each update moves it toward the next one, not past it, so it stays
    /// within ±2⁴⁷ and every sum here is < 2⁴⁹ in magnitude.
    #[allow(clippy::arithmetic_side_effects)]
    pub(super) fn update(&mut self, mad: i64) -> i64 {
        let x = mad << 16;
        if self.init {
            self.mad_q16 += (x - self.mad_q16) >> SCALE_SHIFT;
        } else {
            *self = Self {
                mad_q16: x,
                init: true,
            };
        }
        (self.mad_q16 + 0xFFFF) >> 16
    }
}

/// Median of a non-empty sorted slice (mean of the middle two for even length, rounded as `div_round`).
pub(super) fn median_sorted(v: &[i32]) -> i32 {
    let (below, above) = v.split_at_checked(v.len() / 2).unwrap_or((v, &[]));
    match (below.last(), above.first()) {
        // The sum of two `i32` cannot wrap in `i64`.
        (Some(&lo), Some(&hi)) if v.len().is_multiple_of(2) => {
            div_round(i64::from(lo).wrapping_add(i64::from(hi)), 2)
        }
        (_, Some(&hi)) => hi,
        (_, None) => 0,
    }
}

/// Median absolute deviation from `median` of the sorted `v[..n]` (`median` = `median_sorted(&v[..n])`, n ≤ G),
/// rounded as [`median_sorted`], each deviation saturated to `i32::MAX`; 0 for n = 0.
///
/// Selection instead of a second sort: with h = n/2, `v[..h]` lie at or below the median and `v[h..n]` at or
/// above it, so the deviations A_j = median − v[h−1−j] and B_j = v[h+j] − median are two ascending sequences. The
/// t = h + 1 smallest deviations are A_0..i and B_0..t−i for the smallest i with A_i ≥ B_{t−i−1} (a monotone
/// predicate: binary search); the largest two of them are the middle one and, for even n, the one before it.
/// Branch-free: every lookup loads from a clamped index and selects ±∞ past the ends.
///
/// Plain arithmetic, so that builds with overflow checks keep checking the bounds: indices are ≤ 2h + 1 ≤ n + 1 ≤ 33
/// (`n` ≤ G ≤ 32); in the subtractions j < h, half ≥ 1 and lo ≤ h < t. A_j and B_j are differences of two `i32`
/// (|·| ≤ 2³²) or ±∞, and ±∞ only enter comparisons: `cur` and `prev` are never −∞ (B is never −∞ where it is read,
/// and for even n ≥ 2 `prev` ≥ B_(h−1) when lo = 0), so the final sum adds two values in [−2³², 2³¹).
#[allow(clippy::arithmetic_side_effects)]
pub(super) fn mad_sorted<const G: usize>(v: &[i32; G], n: usize, median: i32) -> i32 {
    let n = n.min(G);
    if n == 0 {
        return 0;
    }
    let (h, m) = (n / 2, i64::from(median));
    let t = h + 1;
    // G ≥ 1 (`Fusion::FITS`): the clamped index is in range and the fallback is never used.
    let at = |i: usize| v.get(i.min(G - 1)).map_or(0, |&x| i64::from(x));
    // A_j and B_j, +∞ past their ends.
    let a = |j: usize| {
        if j < h {
            m - at(h.wrapping_sub(j + 1))
        } else {
            i64::MAX
        }
    };
    let b = |j: usize| if h + j < n { at(h + j) - m } else { i64::MAX };
    // f(j − back), −∞ for a negative index.
    pub(super) fn before(j: usize, back: usize, f: impl Fn(usize) -> i64) -> i64 {
        if j >= back {
            f(j.wrapping_sub(back))
        } else {
            i64::MIN
        }
    }
    let take_a = |i: usize| a(i) >= before(t, i + 1, b);
    // Smallest i in [t − (n − h), h] (clamped at 0) with take_a(i); take_a(h) holds (A_h = +∞). The answer stays in
    // [lo, lo + size); the number of steps depends on n only.
    let mut lo = (t + h).saturating_sub(n);
    let mut size = h.saturating_sub(lo) + 1;
    while size > 1 {
        let half = size / 2;
        // + half unless take_a(lo + half − 1); a conditional move, not a branch (a coin toss)
        lo += core::hint::select_unpredictable(take_a(lo + half - 1), 0, half);
        size -= half;
    }
    let (last_a, last_b) = (before(lo, 1, a), before(t - lo, 1, b));
    let cur = last_a.max(last_b);
    let sat = |d: i64| d.min(i64::from(i32::MAX));
    if n % 2 == 1 {
        return sat(cur) as i32;
    }
    let prev = last_a
        .min(last_b)
        .max(before(lo, 2, a))
        .max(before(t - lo, 2, b));
    div_round(sat(prev) + sat(cur), 2)
}

/// Sorts 16 values with an optimal sorting network (60 compare-exchanges in 10 layers, M. W. Green; listed by
/// B. Dobbelaere): branch-free, no data-dependent control flow, the values in registers.
pub(super) fn sort16(v: &mut [i32; 16]) {
    let [
        mut v0,
        mut v1,
        mut v2,
        mut v3,
        mut v4,
        mut v5,
        mut v6,
        mut v7,
        mut v8,
        mut v9,
        mut v10,
        mut v11,
        mut v12,
        mut v13,
        mut v14,
        mut v15,
    ] = *v;
    // A compare-exchange: the minimum, then the maximum as `a ^ b ^ min` (one condition: `mov, cmp, it, mov, eor,
    // eor` on the Cortex-M4, where `(min, max)` compiles to two IT blocks of opposite conditions).
    macro_rules! layer {
        ($(($i:ident, $j:ident)),*) => { $({ let lo = $i.min($j); ($i, $j) = (lo, $i ^ $j ^ lo); })* };
    }
    layer!(
        (v0, v13),
        (v1, v12),
        (v2, v15),
        (v3, v14),
        (v4, v8),
        (v5, v6),
        (v7, v11),
        (v9, v10)
    );
    layer!(
        (v0, v5),
        (v1, v7),
        (v2, v9),
        (v3, v4),
        (v6, v13),
        (v8, v14),
        (v10, v15),
        (v11, v12)
    );
    layer!(
        (v0, v1),
        (v2, v3),
        (v4, v5),
        (v6, v8),
        (v7, v9),
        (v10, v11),
        (v12, v13),
        (v14, v15)
    );
    layer!(
        (v0, v2),
        (v1, v3),
        (v4, v10),
        (v5, v11),
        (v6, v7),
        (v8, v9),
        (v12, v14),
        (v13, v15)
    );
    layer!(
        (v1, v2),
        (v3, v12),
        (v4, v6),
        (v5, v7),
        (v8, v10),
        (v9, v11),
        (v13, v14)
    );
    layer!(
        (v1, v4),
        (v2, v6),
        (v5, v8),
        (v7, v10),
        (v9, v13),
        (v11, v14)
    );
    layer!((v2, v4), (v3, v6), (v9, v12), (v11, v13));
    layer!((v3, v5), (v6, v8), (v7, v9), (v10, v12));
    layer!((v3, v4), (v5, v6), (v7, v8), (v9, v10), (v11, v12));
    layer!((v6, v7), (v8, v9));
    *v = [
        v0, v1, v2, v3, v4, v5, v6, v7, v8, v9, v10, v11, v12, v13, v14, v15,
    ];
}

/// Sorts `v` ascending: the network for 16 values, the library sort otherwise.
pub(super) fn sort_small<const G: usize>(v: &mut [i32; G]) {
    match <&mut [i32; 16]>::try_from(v.as_mut_slice()) {
        Ok(v16) => sort16(v16),
        Err(_) => v.sort_unstable(),
    }
}
