//! Noise estimates per sensor axis and the inverse-variance weights' state (see the module docs of `fuse`).

use core::num::NonZeroU64;

/// Largest noise variance kept, so that `var << 16` fits in `u64`.
pub(super) const VAR_LIMIT: u64 = 1 << 47;
/// The difference whose `d²/2` is [`VAR_LIMIT`].
pub(super) const VAR_LIMIT_ROOT: u64 = 1 << 24;
const _: () = assert!(VAR_LIMIT_ROOT * VAR_LIMIT_ROOT / 2 == VAR_LIMIT);

/// Noise estimator of one sensor axis.
///
/// Per sample only a sum grows: `block_sum += min(|Δr|, 2²⁴)²` (one `UMLAL` on the Cortex-M4). Every
/// `weight_interval` samples the block is folded into the exponential average: the block's mean `Δr²/2` moves `var`
/// by the fraction `n / 2^shift` of the way (n = the block's differences, at most the whole way), which weighs every
/// difference as a per-sample average over 2^shift samples would, to first order, without the per-sample average's
/// 64-bit subtraction, run-time 64-bit shift and saturating counter (costs: `docs/performance.md`, Cortex-M4 cost
/// sections).
#[derive(Clone, Copy, Debug)]
pub(super) struct NoiseEst {
    /// Exponential average of Δr²/2, (output unit)², ≤ [`VAR_LIMIT`].
    pub(super) var: u64,
    /// Σ min(|Δr|, 2²⁴)² of the current block: ≤ 65 535 terms of ≤ 2⁴⁸, < 2⁶⁴.
    pub(super) block_sum: u64,
    /// Residual from the median in the last sample (read only when the sensor was used in it).
    pub(super) last_resid: i32,
    /// Differences folded into `var`, saturating.
    pub(super) updates: u16,
    /// Differences in the current block (≤ `weight_interval` ≤ 65 535).
    pub(super) block_n: u16,
}

impl NoiseEst {
    pub(super) const NEW: Self = Self {
        var: 0,
        block_sum: 0,
        last_resid: 0,
        updates: 0,
        block_n: 0,
    };

    /// Folds the current block into `var` with weight `block_n / 2^shift` (at most 1) and starts a new block.
    ///
    /// Plain arithmetic, so that builds with overflow checks keep checking the bounds: the block mean is
    /// `block_sum / (2 · block_n)` ≤ 2⁴⁸ / 2 = [`VAR_LIMIT`]; `var` stays in [0, VAR_LIMIT] (it moves toward a mean,
    /// not past it), so `diff` ∈ [−2⁴⁷, 2⁴⁷] and `diff · n` < 2⁴⁷ · 2³¹ = 2⁷⁸ fits `i128`.
    #[allow(clippy::arithmetic_side_effects)]
    pub(super) fn fold(&mut self, shift: u32) {
        let n = u64::from(self.block_n);
        let Some(den) = NonZeroU64::new(2 * n) else {
            return;
        };
        let mean = self.block_sum / den;
        let diff = i128::from(mean) - i128::from(self.var);
        // n ≥ 2^shift: the block alone is the estimate; otherwise move by n / 2^shift, rounded toward zero.
        let step = if n >> shift != 0 {
            diff
        } else {
            diff * i128::from(n) / (1i128 << shift)
        };
        self.var = (i128::from(self.var) + step) as u64;
        self.updates = self.updates.saturating_add(self.block_n);
        (self.block_sum, self.block_n) = (0, 0);
    }
}

/// Noise-estimator state of one axis of all `G` groups, with bitmasks over groups (bit g = group g).
#[derive(Clone, Copy, Debug)]
pub(super) struct AxisState<const G: usize> {
    /// Per group.
    pub(super) est: [NoiseEst; G],
    /// Groups whose `last_resid` is from the previous sample.
    pub(super) resid_valid: u32,
    /// Groups whose estimate has settled (seen 2^`noise_shift` differences, at most 65 535).
    pub(super) settled: u32,
    /// Weights, Q16.
    pub(super) weight_q16: [u32; G],
}

impl<const G: usize> AxisState<G> {
    /// Ends every estimator's block (see [`NoiseEst`]) with the configuration's `noise_shift` and updates
    /// `settled`.
    pub(super) fn fold(&mut self, noise_shift: u8) {
        let shift = u32::from(noise_shift.min(31));
        let settled_at = (1u32 << shift).min(u32::from(u16::MAX));
        let mut settled = 0;
        for (g, e) in self.est.iter_mut().enumerate() {
            e.fold(shift);
            settled |= u32::from(u32::from(e.updates) >= settled_at) << g;
        }
        self.settled = settled;
    }

    pub(super) const NEW: Self = Self {
        est: [NoiseEst::NEW; G],
        resid_valid: 0,
        settled: 0,
        weight_q16: [1 << 16; G],
    };
}
