//! Streaming Allan variance: non-overlapping, octave averaging times τ = 2^k·τ₀, exactly the seed paper's
//! eqs. 14–15, in integers, with O(log T) memory and O(1) amortised work per sample.
//!
//! # Method
//! Level k sees consecutive, non-overlapping blocks of 2^k samples, kept as exact block *sums* `S` (no division,
//! no rounding). When a block completes, the squared difference to the previous block at that level is added to
//! that level's `Σ (S_j − S_{j−1})²`; every second block, the sum of the last two blocks is passed on as a block of
//! level k + 1 (eq. 15's pairing). Then, with m = 2^k and M − 1 = the number of differences,
//! `σ²(m·τ₀) = Σ (S_j − S_{j−1})² / (2 · (M − 1) · m²)` — eq. 14 on the block means `S/m`. The blocks are the same as
//! Stable32's non-overlapping ADEV (block j = samples j·m … (j+1)·m − 1), so the number of terms is
//! `⌊T/m⌋ − 1`; it is derived from the sample count T and not stored. A block and its predecessor are the two halves
//! of the next level's block exactly when the block index is odd, so one `prev` per level is all the state.
//!
//! # Why nothing overflows (inputs are any `i32`, up to `MAX_SAMPLES` = 2³² samples)
//! A level-k block sum satisfies |S| ≤ 2^k · 2³¹ = 2^(31+k) ≤ 2⁶², so `prev: i64` holds it for k ≤ 31 (we keep
//! `LEVELS` = 24). A difference |d| ≤ 2^(32+k), so d² ≤ 2^(64+2k) < 2¹²⁸ for k ≤ 31. Level k has fewer than T/2^k
//! differences, so `Σd² < (T/2^k) · 2^(64+2k) = T · 2^(64+k)`; a level has any term only when 2^(k+1) ≤ T, hence
//! `Σd² < T² · 2⁶³ ≤ 2¹²⁷` for T ≤ 2³². The 128-bit sums therefore cannot overflow for 2³² samples of full-scale
//! input (2²⁴ asked for; 82 days at 604.8 Hz); `push` refuses further samples (and says so) rather than wrap.
//! `tests::full_scale_extremes_do_not_overflow` drives the worst case of the deepest levels and checks against an
//! independent i128 computation. Since `LEVELS` ≤ 31, |d| ≤ 2⁶² fits in `i64`, and d² is one widening
//! 64 × 64 → 128-bit multiply (from 32-bit halves on 32-bit targets, one product while |d| < 2³²).

use serde::{Deserialize, Serialize};

/// Octave levels per channel: τ = τ₀ … 2²³·τ₀.
pub const LEVELS: usize = 24;
/// Samples an accumulator takes before it refuses more (the overflow bound above).
pub const MAX_SAMPLES: u64 = 1 << 32;
/// Differences of block sums, |d| ≤ 2^(32+k), are formed in `i64`: that needs k ≤ 30.
const DIFF_FITS_I64: () = assert!(LEVELS <= 31);

/// One octave level's statistics: what the telemetry carries; roots are taken on the ground.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AllanLevel {
    /// k: averaging factor m = 2^k, τ = m·τ₀.
    pub level: u8,
    /// Number of differences (M − 1 in eq. 14; Stable32's `#` column).
    pub count: u32,
    /// `Σ (S_j − S_{j−1})²` of block sums, in (input unit)².
    pub sum_sq: u128,
}

impl AllanLevel {
    /// Allan variance in (input unit)², or `None` without differences. f64: for the ground and tests.
    pub fn avar(&self) -> Option<f64> {
        if self.count == 0 || usize::from(self.level) >= 64 {
            return None;
        }
        let m = (1u64 << self.level) as f64;
        Some(self.sum_sq as f64 / (2.0 * f64::from(self.count) * m * m))
    }
}

/// 128-bit sum stored as two `u64` so that the state has the same size and alignment (8) on every target.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct Sum128 {
    lo: u64,
    hi: u64,
}

impl Sum128 {
    const ZERO: Self = Self { lo: 0, hi: 0 };

    fn get(self) -> u128 {
        (u128::from(self.hi) << 64) | u128::from(self.lo)
    }

    /// Adds `d²` (cannot wrap: see the module proof).
    fn add_square(&mut self, d: i64) {
        let (lo, hi) = square_wide(d.unsigned_abs());
        let s = self
            .get()
            .wrapping_add((u128::from(hi) << 64) | u128::from(lo));
        self.lo = s as u64;
        self.hi = (s >> 64) as u64;
    }
}

/// `a²` as (low, high) 64-bit halves: one widening multiply on 64-bit targets.
#[cfg(target_pointer_width = "64")]
fn square_wide(a: u64) -> (u64, u64) {
    a.carrying_mul(a, 0)
}

/// `a²` as (low, high) 64-bit halves, from 32 × 32 → 64-bit products (`UMULL` on the Cortex-M4; a `u128`
/// multiply would call `__multi3`). One product when `a` < 2³², the usual case; three otherwise.
#[cfg(any(test, not(target_pointer_width = "64")))]
fn square_wide_halves(a: u64) -> (u64, u64) {
    let (hi, lo) = (a >> 32, a & 0xFFFF_FFFF);
    // hi, lo < 2³²: each product below is < 2⁶⁴ and cannot wrap.
    let lo2 = lo.wrapping_mul(lo);
    if hi == 0 {
        return (lo2, 0);
    }
    // a² = hi²·2⁶⁴ + 2·hi·lo·2³² + lo²; 2·hi·lo·2³² = mid·2³³ spans both halves.
    let mid = hi.wrapping_mul(lo);
    let (low, carry) = lo2.overflowing_add(mid << 33);
    // The sum is the high half of a² < 2¹²⁸, so it (and every partial sum) is < 2⁶⁴: cannot wrap.
    let high = hi
        .wrapping_mul(hi)
        .wrapping_add(mid >> 31)
        .wrapping_add(u64::from(carry));
    (low, high)
}

#[cfg(not(target_pointer_width = "64"))]
use square_wide_halves as square_wide;

/// What sample number `index` does: it completes block `index >> k` of level k for k = 0, 1, … while that
/// block index is odd, and for the first level where it is even (or the last level). Each completed block
/// but the first of its level has a predecessor to be differenced with.
#[derive(Clone, Copy, Debug)]
struct Step {
    /// Levels with a completed block: 1 ..= `LEVELS`.
    depth: usize,
    /// The block of the last of those levels has a predecessor (the others have: their block index is odd).
    last_has_prev: bool,
}

impl Step {
    fn new(index: u64) -> Self {
        // Levels below the last one touched: ≤ LEVELS − 1, so `+ 1` cannot wrap.
        let below = (index.trailing_ones() as usize).min(LEVELS - 1);
        Self {
            depth: below.wrapping_add(1),
            last_has_prev: index >> below > 0,
        }
    }
}

/// State of one octave level: the previous block sum and the sum of squared differences, side by side so that
/// the low levels, touched by most samples, share cache lines.
#[derive(Clone, Copy, Debug, Default)]
struct Level {
    prev: i64,
    sum_sq: Sum128,
}

impl Level {
    const ZERO: Self = Self {
        prev: 0,
        sum_sq: Sum128::ZERO,
    };
}

/// Adds sample `x` to `levels` = the levels its step completes (the last one differenced only if
/// `last_has_prev`). Inlined with a constant length, the loop unrolls.
///
/// Plain `+`/`−`, so that builds with overflow checks (the tests, also on i686) keep checking the bound: level k holds
/// block sums |S| ≤ 2^(31+k) (`levels` ≤ [`LEVELS`] = 24 long), so |d| ≤ 2^(32+k) < 2⁶³ and the next level's block,
/// a sum of two, ≤ 2^(32+k) too; the squares' sums are bounded in the module docs.
#[allow(clippy::arithmetic_side_effects)]
#[inline(always)]
fn push_into(levels: &mut [Level], x: i32, last_has_prev: bool) {
    let () = DIFF_FITS_I64;
    let Some((last, odd)) = levels.split_last_mut() else {
        return;
    };
    let mut block = i64::from(x);
    for level in odd {
        // |block|, |prev| ≤ 2^(31+k): |d| ≤ 2^(32+k) < 2⁶³ (`DIFF_FITS_I64`).
        level.sum_sq.add_square(block - level.prev);
        // An odd block and its predecessor form the next level's block.
        block += core::mem::replace(&mut level.prev, block);
    }
    if last_has_prev {
        last.sum_sq.add_square(block - last.prev);
    }
    last.prev = block;
}

/// Streaming non-overlapping octave Allan accumulator of one channel (see module docs).
#[derive(Clone, Debug)]
pub struct AllanAccumulator {
    samples: u64,
    levels: [Level; LEVELS],
}

impl Default for AllanAccumulator {
    fn default() -> Self {
        Self::new()
    }
}

impl AllanAccumulator {
    /// An empty accumulator.
    pub const fn new() -> Self {
        Self {
            samples: 0,
            levels: [Level::ZERO; LEVELS],
        }
    }

    /// Forgets everything.
    pub fn reset(&mut self) {
        *self = Self::new();
    }

    /// Samples taken so far.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Adds one sample. Returns `false` (and ignores it) once [`MAX_SAMPLES`] have been taken.
    pub fn push(&mut self, x: i32) -> bool {
        if self.samples >= MAX_SAMPLES {
            return false;
        }
        let step = Step::new(self.samples);
        // < MAX_SAMPLES = 2³² (just checked): cannot wrap.
        self.samples = self.samples.wrapping_add(1);
        self.push_levels(x, step);
        true
    }

    /// Adds a sample whose [`Step`] is `step` (`samples` is already counted).
    #[inline(always)]
    fn push_levels(&mut self, x: i32, step: Step) {
        if let Some(levels) = self.levels.get_mut(..step.depth) {
            push_into(levels, x, step.last_has_prev);
        }
    }

    /// [`Self::push`] of `xs[c]` into `accs[c]` for every channel c (extra items of either are left alone);
    /// the per-sample bookkeeping is shared when all accumulators hold the same number of samples, as the
    /// pipeline's do.
    pub fn push_each(accs: &mut [Self], xs: &[i32]) {
        let Some(index) = accs.first().map(Self::samples) else {
            return;
        };
        let step = Step::new(index);
        if index < MAX_SAMPLES && accs.iter().all(|a| a.samples == index) {
            // One sample in two touches only level 0, one in four levels 0 and 1, …: those depths get a loop
            // over the channels with the levels unrolled (the same arithmetic as `push_levels`).
            match step.depth {
                1 => Self::push_all::<1>(accs, xs, step),
                2 => Self::push_all::<2>(accs, xs, step),
                3 => Self::push_all::<3>(accs, xs, step),
                _ => {
                    for (acc, &x) in accs.iter_mut().zip(xs) {
                        // index < MAX_SAMPLES (checked above): cannot wrap.
                        acc.samples = index.wrapping_add(1);
                        acc.push_levels(x, step);
                    }
                }
            }
        } else {
            for (acc, &x) in accs.iter_mut().zip(xs) {
                acc.push(x);
            }
        }
    }

    /// `push_levels` of every channel for a step of depth `D` (every accumulator holds `samples` < `MAX_SAMPLES`).
    #[inline(always)]
    fn push_all<const D: usize>(accs: &mut [Self], xs: &[i32], step: Step) {
        for (acc, &x) in accs.iter_mut().zip(xs) {
            // < MAX_SAMPLES (this function's precondition, checked by `push_each`): cannot wrap.
            acc.samples = acc.samples.wrapping_add(1);
            if let Some((levels, _)) = acc.levels.split_first_chunk_mut::<D>() {
                push_into(levels, x, step.last_has_prev);
            }
        }
    }

    /// Statistics of level `k` (`None` for k ≥ [`LEVELS`]).
    pub fn level(&self, k: usize) -> Option<AllanLevel> {
        let sum_sq = self.levels.get(k)?.sum_sq.get();
        let blocks = self.samples >> k;
        Some(AllanLevel {
            level: k as u8,
            count: blocks.saturating_sub(1) as u32,
            sum_sq,
        })
    }

    /// Levels that have at least one difference.
    pub fn levels(&self) -> impl Iterator<Item = AllanLevel> + '_ {
        (0..LEVELS)
            .filter_map(|k| self.level(k))
            .filter(|l| l.count > 0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    extern crate std;
    use std::vec::Vec;

    /// Independent reference: explicit block sums and i128 differences, level by level.
    fn reference(x: &[i32], k: usize) -> (u32, u128) {
        let m = 1usize << k;
        let sums: Vec<i128> = x
            .chunks_exact(m)
            .map(|c| c.iter().map(|&v| i128::from(v)).sum())
            .collect();
        let sum_sq = sums
            .windows(2)
            .map(|w| (w[1] - w[0]).unsigned_abs().pow(2))
            .sum();
        (sums.len().saturating_sub(1) as u32, sum_sq)
    }

    #[test]
    fn matches_block_reference_on_arbitrary_data() {
        let mut s = 12345u64;
        let x: Vec<i32> = (0..5000)
            .map(|_| {
                s = s
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                (s >> 32) as i32
            })
            .collect();
        let mut acc = AllanAccumulator::new();
        x.iter().for_each(|&v| assert!(acc.push(v)));
        for k in 0..LEVELS {
            let (count, sum_sq) = reference(&x, k);
            assert_eq!(
                acc.level(k),
                Some(AllanLevel {
                    level: k as u8,
                    count,
                    sum_sq
                }),
                "level {k}"
            );
        }
        assert_eq!(acc.levels().count(), 12); // 2^12 = 4096 ≤ 5000 / 2 fails; 2^11 · 2 ≤ 5000 → k = 0 … 11
    }

    #[test]
    fn white_noise_avar_halves_per_octave() {
        // Alternating ±1000: σ²(τ₀) = (2000)² / 2 = 2e6; every longer level averages to 0.
        let mut acc = AllanAccumulator::new();
        (0..1024).for_each(|i| _ = acc.push(if i % 2 == 0 { 1000 } else { -1000 }));
        assert_eq!(acc.level(0).unwrap().avar(), Some(2.0e6));
        assert_eq!(acc.level(1).unwrap().avar(), Some(0.0));
        assert_eq!(acc.level(30), None);
        assert_eq!(AllanLevel::default().avar(), None);
    }

    #[test]
    fn full_scale_extremes_do_not_overflow() {
        // 2^24 samples of full-scale square waves; each period maximises |d| at one level.
        const T: usize = 1 << 24;
        for k in [0usize, 11, 22, 23] {
            let x: Vec<i32> = (0..T)
                .map(|i| {
                    if (i >> k) & 1 == 0 {
                        i32::MAX
                    } else {
                        i32::MIN
                    }
                })
                .collect();
            let mut acc = AllanAccumulator::new();
            x.iter().for_each(|&v| _ = acc.push(v));
            let (count, sum_sq) = reference(&x, k);
            let got = acc.level(k).unwrap();
            assert_eq!((got.count, got.sum_sq), (count, sum_sq), "level {k}");
            // Far beyond 64 bits: a u64 accumulator would have wrapped.
            assert!(got.sum_sq > u128::from(u64::MAX), "level {k}");
        }
    }

    #[test]
    fn refuses_samples_beyond_the_bound() {
        let mut acc = AllanAccumulator::new();
        acc.samples = MAX_SAMPLES - 1;
        assert!(acc.push(7));
        assert!(!acc.push(7));
        assert_eq!(acc.samples(), MAX_SAMPLES);
    }

    #[test]
    fn push_each_equals_push() {
        let mut s = 7u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 32) as i32
        };
        let mut each: Vec<AllanAccumulator> = (0..5).map(|_| AllanAccumulator::new()).collect();
        let mut one = each.clone();
        // Unequal sample counts, and one accumulator at its limit.
        for acc in [&mut each, &mut one] {
            acc[2].push(1);
            acc[4].samples = MAX_SAMPLES - 3;
        }
        for _ in 0..3000 {
            let xs: Vec<i32> = (0..5).map(|_| next()).collect();
            AllanAccumulator::push_each(&mut each, &xs);
            for (a, &x) in one.iter_mut().zip(&xs) {
                a.push(x);
            }
        }
        for (a, b) in each.iter().zip(&one) {
            assert_eq!(a.samples(), b.samples());
            assert!((0..LEVELS).all(|k| a.level(k) == b.level(k)));
        }
        assert_eq!(each[4].samples(), MAX_SAMPLES);
    }

    #[test]
    fn wide_squares_are_exact() {
        let mut s = 99u64;
        let mut values: Vec<u64> = (0..64)
            .flat_map(|b| [1u64 << b, (1u64 << b) - 1, (1u64 << b) + 1])
            .collect();
        values.extend((0..100_000).map(|i| {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            s >> (i % 64)
        }));
        values.extend([0, u64::from(u32::MAX), u64::MAX]);
        for a in values {
            let want = u128::from(a) * u128::from(a);
            let split = |(lo, hi): (u64, u64)| (u128::from(hi) << 64) | u128::from(lo);
            assert_eq!(split(square_wide_halves(a)), want, "{a}");
            assert_eq!(split(square_wide(a)), want, "{a}");
        }
    }

    #[test]
    fn state_size() {
        // 8 + 24 × (8 + 16) bytes, identical on thumbv7em (both align 8).
        assert_eq!(core::mem::size_of::<AllanAccumulator>(), 8 + LEVELS * 24);
    }
}
