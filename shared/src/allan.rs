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
//! independent i128 computation.

use serde::{Deserialize, Serialize};

/// Octave levels per channel: τ = τ₀ … 2²³·τ₀.
pub const LEVELS: usize = 24;
/// Samples an accumulator takes before it refuses more (the overflow bound above).
pub const MAX_SAMPLES: u64 = 1 << 32;

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

    fn add(&mut self, x: u128) {
        let s = self.get().wrapping_add(x); // cannot wrap: see the module proof
        self.lo = s as u64;
        self.hi = (s >> 64) as u64;
    }
}

/// Streaming non-overlapping octave Allan accumulator of one channel (see module docs).
#[derive(Clone, Debug)]
pub struct AllanAccumulator {
    samples: u64,
    prev: [i64; LEVELS],
    sum_sq: [Sum128; LEVELS],
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
            prev: [0; LEVELS],
            sum_sq: [Sum128::ZERO; LEVELS],
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
        let index = self.samples;
        self.samples += 1;
        let mut block = i64::from(x);
        for (k, (prev, sum_sq)) in self.prev.iter_mut().zip(self.sum_sq.iter_mut()).enumerate() {
            // This sample completes block number `index >> k` of level k.
            let block_index = index >> k;
            if block_index > 0 {
                let d = i128::from(block) - i128::from(*prev);
                sum_sq.add(d.unsigned_abs() * d.unsigned_abs());
            }
            let earlier = core::mem::replace(prev, block);
            if block_index & 1 == 0 {
                break;
            }
            // Odd block: it and its predecessor form the next level's block.
            block += earlier;
        }
        true
    }

    /// Statistics of level `k` (`None` for k ≥ [`LEVELS`]).
    pub fn level(&self, k: usize) -> Option<AllanLevel> {
        let sum_sq = self.sum_sq.get(k)?.get();
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
    fn state_size() {
        // 8 + 24 × (8 + 16) bytes, identical on thumbv7em (both align 8).
        assert_eq!(core::mem::size_of::<AllanAccumulator>(), 8 + LEVELS * 24);
    }
}
