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
//! `Σd² < T² · 2⁶³ ≤ 2¹²⁷` for T ≤ 2³² (level 0: fewer than T terms below 2⁶⁴, < 2⁹⁶, all that its sum keeps). The
//! sums therefore cannot overflow for 2³² samples of full-scale input (2²⁴ asked for; 82 days at 604.8 Hz); `push`
//! refuses further samples (and says so) rather than wrap.
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
    #[inline(always)]
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

/// Level 0 of one channel, which every sample touches, in 16 bytes instead of a [`Level`]'s 24: its block is the
/// sample itself and its `prev` the previous sample (`i32`), so |d| < 2³² and d² < 2⁶⁴ is one 32 × 32 → 64-bit
/// multiply; fewer than 2³² of them sum to < 2⁹⁶, held as 64 + 32 bits.
#[derive(Clone, Copy, Debug, Default)]
struct Level0 {
    sum_lo: u64,
    sum_hi: u32,
    prev: i32,
}

impl Level0 {
    const ZERO: Self = Self {
        sum_lo: 0,
        sum_hi: 0,
        prev: 0,
    };

    /// Adds `d²` of the difference to the previous sample (< 2⁹⁶ in all: cannot wrap).
    fn add_square(&mut self, x: i32) {
        let d = u64::from(x.abs_diff(self.prev));
        // As one 128-bit sum: written as a 64-bit sum and its carry, LLVM forms the low sum with `UMLAL` and
        // multiplies again for the carry.
        let s = self.sum_sq().wrapping_add(u128::from(d.wrapping_mul(d)));
        self.sum_lo = s as u64;
        self.sum_hi = (s >> 64) as u32;
    }

    fn sum_sq(&self) -> u128 {
        (u128::from(self.sum_hi) << 64) | u128::from(self.sum_lo)
    }
}

/// Adds sample `x` to the levels its step completes: level 0 (`zero`) and `higher` = levels 1, 2, … (the last one
/// touched is differenced only if `last_has_prev`). Inlined with a constant length, the loop unrolls.
///
/// Plain `+`/`−`, so that builds with overflow checks (the tests, also on i686) keep checking the bound: level k holds
/// block sums |S| ≤ 2^(31+k) (`higher` < [`LEVELS`] = 24 long), so |d| ≤ 2^(32+k) < 2⁶³ and the next level's block,
/// a sum of two, ≤ 2^(32+k) too; the squares' sums are bounded in the module docs.
#[allow(clippy::arithmetic_side_effects)]
#[inline(always)]
fn push_into(zero: &mut Level0, higher: &mut [Level], x: i32, last_has_prev: bool) {
    let () = DIFF_FITS_I64;
    let prev0 = zero.prev;
    let Some((last, odd)) = higher.split_last_mut() else {
        // Level 0 is the last touched: the first sample has no predecessor.
        if last_has_prev {
            zero.add_square(x);
        }
        zero.prev = x;
        return;
    };
    // Level 0 is not the last touched, so its block index is odd: it has a predecessor.
    zero.add_square(x);
    zero.prev = x;
    let mut block = i64::from(x) + i64::from(prev0);
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

/// Streaming non-overlapping octave Allan accumulators of `C` channels that take their samples together (see
/// module docs): one sample count and one step for all, so that the per-sample bookkeeping is paid once per sample,
/// not once per channel (the pipeline's 102 channels).
#[derive(Clone, Debug)]
pub struct AllanSet<const C: usize> {
    samples: u64,
    /// Level 0 of every channel, side by side.
    zero: [Level0; C],
    /// Levels 1 … `LEVELS` − 1 of every channel.
    higher: [[Level; LEVELS - 1]; C],
}

impl<const C: usize> Default for AllanSet<C> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const C: usize> AllanSet<C> {
    /// Empty accumulators.
    pub const fn new() -> Self {
        Self {
            samples: 0,
            zero: [Level0::ZERO; C],
            higher: [[Level::ZERO; LEVELS - 1]; C],
        }
    }

    /// Forgets everything, in place: the levels are zeroed where they lie. (`*self = Self::new()` would build the
    /// whole set on the stack first: 58 KB for the pipeline's bank, more than the MCU's stack.)
    pub fn reset(&mut self) {
        self.samples = 0;
        self.zero.fill(Level0::ZERO);
        self.higher.iter_mut().for_each(|h| h.fill(Level::ZERO));
    }

    /// Samples taken so far (by every channel).
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Adds one sample to every channel: `first` to channels 0, 1, …, then `second` to the channels after them.
    /// Returns `false` and takes nothing unless `first` and `second` hold exactly `C` values together, or once
    /// [`MAX_SAMPLES`] have been taken.
    pub fn push_parts(&mut self, first: &[i32], second: &[i32]) -> bool {
        if self.samples >= MAX_SAMPLES || first.len().checked_add(second.len()) != Some(C) {
            return false;
        }
        let step = Step::new(self.samples);
        // < MAX_SAMPLES = 2³² (just checked): cannot wrap.
        self.samples = self.samples.wrapping_add(1);
        let split = first.len().min(C);
        let (zero_a, zero_b) = self.zero.split_at_mut(split);
        let (higher_a, higher_b) = self.higher.split_at_mut(split);
        // One sample in two touches only level 0, one in four levels 0 and 1, …: those depths get a loop over the
        // channels with the levels unrolled (`H` = levels above 0).
        match step.depth {
            1 => {
                push_all::<0>(zero_a, higher_a, first, step);
                push_all::<0>(zero_b, higher_b, second, step);
            }
            2 => {
                push_all::<1>(zero_a, higher_a, first, step);
                push_all::<1>(zero_b, higher_b, second, step);
            }
            3 => {
                push_all::<2>(zero_a, higher_a, first, step);
                push_all::<2>(zero_b, higher_b, second, step);
            }
            depth => {
                let above = depth.saturating_sub(1);
                for ((zero, higher), &x) in zero_a
                    .iter_mut()
                    .zip(higher_a.iter_mut())
                    .zip(first)
                    .chain(zero_b.iter_mut().zip(higher_b.iter_mut()).zip(second))
                {
                    if let Some(higher) = higher.get_mut(..above) {
                        push_into(zero, higher, x, step.last_has_prev);
                    }
                }
            }
        }
        true
    }

    /// Statistics of level `k` of `channel` (`None` for channel ≥ `C` or k ≥ [`LEVELS`]).
    pub fn level(&self, channel: usize, k: usize) -> Option<AllanLevel> {
        let sum_sq = match k.checked_sub(1) {
            None => self.zero.get(channel)?.sum_sq(),
            Some(above) => self.higher.get(channel)?.get(above)?.sum_sq.get(),
        };
        let blocks = self.samples >> k;
        Some(AllanLevel {
            level: k as u8,
            count: blocks.saturating_sub(1) as u32,
            sum_sq,
        })
    }

    /// Levels of `channel` that have at least one difference.
    pub fn levels(&self, channel: usize) -> impl Iterator<Item = AllanLevel> + '_ {
        (0..LEVELS)
            .filter_map(move |k| self.level(channel, k))
            .filter(|l| l.count > 0)
    }
}

/// `push_into` of level 0 and the first `H` higher levels of every channel, for one step of depth `H` + 1.
#[inline(always)]
fn push_all<const H: usize>(
    zero: &mut [Level0],
    higher: &mut [[Level; LEVELS - 1]],
    xs: &[i32],
    step: Step,
) {
    for ((zero, higher), &x) in zero.iter_mut().zip(higher).zip(xs) {
        if let Some((higher, _)) = higher.split_first_chunk_mut::<H>() {
            push_into(zero, higher, x, step.last_has_prev);
        }
    }
}

/// Streaming non-overlapping octave Allan accumulator of one channel (see module docs): an [`AllanSet`] of one.
#[derive(Clone, Debug, Default)]
pub struct AllanAccumulator(AllanSet<1>);

impl AllanAccumulator {
    /// An empty accumulator.
    pub const fn new() -> Self {
        Self(AllanSet::new())
    }

    /// Forgets everything.
    pub fn reset(&mut self) {
        self.0.reset();
    }

    /// Samples taken so far.
    pub fn samples(&self) -> u64 {
        self.0.samples()
    }

    /// Adds one sample. Returns `false` (and ignores it) once [`MAX_SAMPLES`] have been taken.
    pub fn push(&mut self, x: i32) -> bool {
        self.0.push_parts(&[x], &[])
    }

    /// Statistics of level `k` (`None` for k ≥ [`LEVELS`]).
    pub fn level(&self, k: usize) -> Option<AllanLevel> {
        self.0.level(0, k)
    }

    /// Levels that have at least one difference.
    pub fn levels(&self) -> impl Iterator<Item = AllanLevel> + '_ {
        self.0.levels(0)
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

    /// `reset` in place forgets everything: after it, the same samples give what a new set gives (levels written
    /// by the first run at every depth, so a level the reset missed would show).
    #[test]
    fn reset_in_place_equals_a_new_set() {
        let xs: Vec<i32> = (0..3000i32)
            .map(|i| i.wrapping_mul(7919) % 10_007 - 5_000)
            .collect();
        let mut used = AllanSet::<3>::new();
        for &x in &xs {
            assert!(used.push_parts(&[x, -x], &[x / 3]));
        }
        used.reset();
        assert_eq!(used.samples(), 0);
        assert_eq!(used.levels(0).count(), 0);
        let mut fresh = AllanSet::<3>::new();
        for &x in xs.iter().rev().take(1500) {
            assert!(used.push_parts(&[x, 2 * x], &[-x]));
            assert!(fresh.push_parts(&[x, 2 * x], &[-x]));
        }
        for ch in 0..3 {
            for k in 0..LEVELS {
                assert_eq!(
                    used.level(ch, k),
                    fresh.level(ch, k),
                    "channel {ch} level {k}"
                );
            }
        }
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
        acc.0.samples = MAX_SAMPLES - 1;
        assert!(acc.push(7));
        assert!(!acc.push(7));
        assert_eq!(acc.samples(), MAX_SAMPLES);
    }

    #[test]
    fn set_equals_single_channels() {
        let mut s = 7u64;
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 32) as i32
        };
        let mut set = AllanSet::<5>::new();
        let mut one: Vec<AllanAccumulator> = (0..5).map(|_| AllanAccumulator::new()).collect();
        // Wrong lengths take nothing.
        assert!(!set.push_parts(&[1, 2], &[3, 4]));
        assert!(!set.push_parts(&[1, 2, 3], &[4, 5, 6]));
        assert_eq!(set.samples(), 0);
        for i in 0..3000 {
            let xs: Vec<i32> = (0..5).map(|_| next()).collect();
            // The split between the parts does not matter.
            let (a, b) = xs.split_at(i % 6);
            assert!(set.push_parts(a, b));
            for (acc, &x) in one.iter_mut().zip(&xs) {
                assert!(acc.push(x));
            }
        }
        for (c, acc) in one.iter().enumerate() {
            assert_eq!(set.samples(), acc.samples());
            assert!((0..LEVELS).all(|k| set.level(c, k) == acc.level(k)));
            assert!(set.levels(c).eq(acc.levels()));
        }
        assert_eq!(set.level(5, 0), None);
        // At the limit the whole set refuses.
        set.samples = MAX_SAMPLES - 1;
        assert!(set.push_parts(&[1; 5], &[]));
        assert!(!set.push_parts(&[1; 5], &[]));
        assert_eq!(set.samples(), MAX_SAMPLES);
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
        // The sample count, then per channel level 0 in 16 bytes and 23 levels of 8 + 16 bytes; identical on
        // thumbv7em (align 8).
        let channel = 16 + (LEVELS - 1) * 24;
        assert_eq!(core::mem::size_of::<AllanAccumulator>(), 8 + channel);
        assert_eq!(core::mem::size_of::<AllanSet<102>>(), 8 + 102 * channel);
    }
}
