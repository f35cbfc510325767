//! Cluster fusion: per axis, one estimate from the G calibrated sensor groups (spec: `docs/fusion.md`).
//!
//! Per sample and axis:
//! 1. **Exclusion** (when `robust`): a sensor (the gyro or the accelerometer of a group) is left out while any of
//!    its raw channels is at an ADC rail (*saturated*) or has repeated the same code for `stuck_window` samples
//!    (*stuck*). Among the rest, an axis value is an *outlier* when its distance from the cluster median exceeds
//!    both `outlier_sigmas` robust standard deviations and the axis's absolute floor. The robust deviation is
//!    1.4826 × the cluster MAD averaged over the last 2^`SCALE_SHIFT` = 16 samples: one sample's MAD of 16 values
//!    scatters by ~43 % and let a 10σ outlier back in on 4.2 % of samples (measured), the average scatters by
//!    ~11 % and still follows a change of the spread (dynamics, scale-factor errors) within 26 ms at 604.8 Hz.
//!    Outlier tests need at least 3 candidates.
//! 2. **Noise estimates**: for every used sensor, the residual from the median is differenced sample to sample,
//!    which removes the common signal and the sensor's own bias, and `Δr²/2` is averaged over 2^`noise_shift`
//!    samples: an estimate of the sensor's white-noise variance. The squares are summed per block of
//!    `weight_interval` samples and each block moves an exponential average by `n / 2^noise_shift` (see `NoiseEst`).
//! 3. **Mean**: the equal-weight mean (the seed paper's), or the inverse-variance weighted mean with weights
//!    `w_i = 2¹⁶ · σ²_min / σ²_i` (Q16, the best sensor has 2¹⁶), recomputed every `weight_interval` samples once
//!    every sensor's estimate has settled; equal weights until then; or the calibration table's fixed weights
//!    (`FusionMode::Fixed`), renormalised over the sensors in use. Division rounds half away from zero.
//!
//! If no sensor is left for an axis, the axis is flagged invalid (`used = 0`, value 0): never a division by zero.
//! Changing weights move the fused bias between the sensors' residual biases; the slow estimator and the weight
//! interval keep that drift far below the noise, and `FusionMode::Equal` removes it entirely.

mod noise;
mod robust;
mod unroll;
mod watch;

use crate::calib::{AXES, CalibrationTable, RawCounts};
use core::num::NonZeroU64;
use noise::{AxisState, VAR_LIMIT_ROOT};
use robust::{AxisScale, MAD_TO_SIGMA_Q16, mad_sorted, median_sorted, sort_small};
use serde::{Deserialize, Serialize};
use watch::RawWatch;

/// Most groups a fusion can handle (fault masks are `u32` bitmasks).
pub const MAX_GROUPS: usize = 32;
/// How the used sensors are averaged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FusionMode {
    /// Equal weights: the seed paper's cluster mean.
    Equal,
    /// Inverse-variance weights from the running noise estimates.
    InverseVariance,
    /// The calibration table's fixed weights (`CalibrationTable::weights_q16`, chosen on the ground for a τ region),
    /// renormalised over the sensors in use: an excluded sensor's weight is shared among the others in proportion
    /// to theirs. Where those weights do not sum to a positive value, the equal-weight mean.
    Fixed,
}

/// Fusion parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FusionConfig {
    /// Averaging rule.
    pub mode: FusionMode,
    /// Leave out saturated, stuck and outlier sensors.
    pub robust: bool,
    /// Consecutive identical raw codes that make a channel stuck.
    pub stuck_window: u16,
    /// Outlier threshold in robust standard deviations, Q8 (6.0 = 1536).
    pub outlier_sigmas_q8: u16,
    /// Smallest distance from the median that can be an outlier: gyro µ°/s, accelerometer µg.
    pub outlier_floor: [i32; 2],
    /// Noise estimates average over 2^`noise_shift` samples.
    pub noise_shift: u8,
    /// Samples between recomputations of the weights.
    pub weight_interval: u16,
    /// Groups left out by hand (the ground's `ExcludeGroups`), bitmasks over groups per kind `[gyro, accel]`;
    /// applied whether or not `robust` is on.
    pub excluded: [u32; 2],
}

impl FusionConfig {
    /// Defaults for our board at 604.8 frames/s.
    pub const DEFAULT: Self = Self {
        mode: FusionMode::InverseVariance,
        robust: true,
        stuck_window: 64,
        outlier_sigmas_q8: 6 * 256,
        outlier_floor: [20_000, 2_000],
        noise_shift: 10,
        weight_interval: 256,
        excluded: [0; 2],
    };
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Groups left out of one sample, as bitmasks over groups (bit g = group g), for one sensor kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SensorFaults {
    /// A raw channel at an ADC rail.
    pub saturated: u32,
    /// A raw channel unchanged for `stuck_window` samples.
    pub stuck: u32,
    /// At least one axis too far from the cluster median.
    pub outlier: u32,
}

impl SensorFaults {
    /// Groups left out for any reason.
    pub fn any(&self) -> u32 {
        self.saturated | self.stuck | self.outlier
    }

    /// Accumulates (bitwise OR) another sample's faults.
    pub fn merge(&mut self, other: &Self) {
        self.saturated |= other.saturated;
        self.stuck |= other.stuck;
        self.outlier |= other.outlier;
    }

    /// This sample's faults of `group` as counts (0 or 1 each).
    pub fn counts_of(&self, group: u32) -> FaultCounts {
        let bit = |mask: u32| mask.checked_shr(group).unwrap_or(0) & 1;
        FaultCounts {
            saturated: bit(self.saturated),
            stuck: bit(self.stuck),
            outlier: bit(self.outlier),
        }
    }
}

/// Health of one fused sample: which groups were left out, per sensor kind.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HealthMask {
    /// Gyros.
    pub gyro: SensorFaults,
    /// Accelerometers.
    pub accel: SensorFaults,
}

impl HealthMask {
    /// No fault (usable in `const`).
    pub const NONE: Self = Self {
        gyro: SensorFaults {
            saturated: 0,
            stuck: 0,
            outlier: 0,
        },
        accel: SensorFaults {
            saturated: 0,
            stuck: 0,
            outlier: 0,
        },
    };
}

impl HealthMask {
    /// Accumulates another sample's health.
    pub fn merge(&mut self, other: &Self) {
        self.gyro.merge(&other.gyro);
        self.accel.merge(&other.accel);
    }
}

/// One fused sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FusedSample {
    /// Gyro x, y, z in µ°/s, then accelerometer x, y, z in µg (`calib::GX` … `AZ`); 0 where `used` is 0.
    pub axes: [i32; AXES],
    /// Sensors used per axis; 0 marks the axis invalid.
    pub used: [u8; AXES],
    /// Groups used per axis (bit g = group g).
    pub used_mask: [u32; AXES],
    /// Sensors left out.
    pub health: HealthMask,
}

impl FusedSample {
    /// Every axis had at least one sensor.
    pub fn valid(&self) -> bool {
        self.used.iter().all(|&u| u > 0)
    }
}

/// Per-group counts of samples in which a sensor was left out, by reason. Counters wrap modulo 2³².
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FaultCounts {
    /// Samples saturated.
    pub saturated: u32,
    /// Samples stuck.
    pub stuck: u32,
    /// Samples with at least one outlier axis.
    pub outlier: u32,
}

impl FaultCounts {
    /// Adds `other`, each counter modulo 2³².
    pub fn add(&mut self, other: &Self) {
        self.saturated = self.saturated.wrapping_add(other.saturated);
        self.stuck = self.stuck.wrapping_add(other.stuck);
        self.outlier = self.outlier.wrapping_add(other.outlier);
    }
}

/// Fusion state of an array of `G` groups (`G` ≤ 32).
#[derive(Clone, Debug)]
pub struct Fusion<const G: usize> {
    config: FusionConfig,
    axes: [AxisState<G>; AXES],
    scale: [AxisScale; AXES],
    raw: [RawWatch; G],
    /// `[group][0 = gyro, 1 = accel]`.
    faults: [[FaultCounts; 2]; G],
    samples: u32,
    weights_ready: bool,
}

/// Σ wᵢ·xᵢ and Σ wᵢ over the groups in `used` for axis `a`, with the table's weights (|w| ≤ 2¹⁶ in a decoded
/// table; wrapping beyond that, never a panic): |w·x| ≤ 2⁴⁷ and G ≤ 32 terms, so the sums stay below 2⁵³.
fn fixed_sums<const G: usize>(
    weights: &[[i32; AXES]; G],
    a: usize,
    x: &[i32; G],
    used: u32,
) -> (i64, i64) {
    let (mut num, mut den) = (0i64, 0i64);
    for (g, (row, &v)) in weights.iter().zip(x).enumerate() {
        let w = row.get(a).copied().unwrap_or(0) & ((used >> g) & 1).wrapping_neg() as i32;
        num = num.wrapping_add(i64::from(w).wrapping_mul(i64::from(v)));
        den = den.wrapping_add(i64::from(w));
    }
    (num, den)
}

/// `num / den` rounded half away from zero, saturated to `i32`; 0 for `den` ≤ 0 (callers pass `den` > 0).
pub(crate) fn div_round(num: i64, den: i64) -> i32 {
    let Some(den) = u64::try_from(den).ok().and_then(NonZeroU64::new) else {
        return 0;
    };
    let half = den.get() / 2;
    // Branch-free: divide |num|, then restore the sign (s = 0 or −1, (q ^ s) − s = ±q).
    let s = num >> 63;
    // |num| ≤ 2⁶³ and half < 2⁶³: the sum cannot wrap.
    let q = (num.unsigned_abs().wrapping_add(half) / den) as i64;
    crate::calib::saturate_i32((q ^ s).wrapping_sub(s))
}

impl<const G: usize> Fusion<G> {
    const FITS: () = assert!(G >= 1 && G <= MAX_GROUPS, "1 ≤ G ≤ 32");
    /// Bit g set for every group.
    const ALL: u32 = u32::MAX >> (32 - G);

    /// A fusion with no history.
    pub const fn new(config: FusionConfig) -> Self {
        let () = Self::FITS;
        Self {
            config,
            axes: [AxisState::NEW; AXES],
            scale: [AxisScale::NEW; AXES],
            raw: [RawWatch::NEW; G],
            faults: [[FaultCounts {
                saturated: 0,
                stuck: 0,
                outlier: 0,
            }; 2]; G],
            samples: 0,
            weights_ready: false,
        }
    }

    /// Forgets the history (as [`Self::new`] with the parameters in force), in place: no second fusion state is
    /// built on the stack.
    pub fn reset(&mut self) {
        self.axes.fill(AxisState::NEW);
        self.scale.fill(AxisScale::NEW);
        self.raw.fill(RawWatch::NEW);
        self.faults.fill(
            [FaultCounts {
                saturated: 0,
                stuck: 0,
                outlier: 0,
            }; 2],
        );
        self.samples = 0;
        self.weights_ready = false;
    }

    /// The parameters in force.
    pub fn config(&self) -> &FusionConfig {
        &self.config
    }

    /// Changes the parameters; the noise estimates are kept (their current blocks are folded in first, so that no
    /// block outlasts a `weight_interval`).
    pub fn set_config(&mut self, config: FusionConfig) {
        let shift = self.config.noise_shift;
        self.axes.iter_mut().for_each(|a| a.fold(shift));
        self.config = config;
    }

    /// Fault counts of `group`: `[gyro, accel]`.
    pub fn fault_counts(&self, group: usize) -> Option<[FaultCounts; 2]> {
        self.faults.get(group).copied()
    }

    /// Running white-noise variance estimate of `group`'s `axis`, (output unit)², once settled (2^`noise_shift`
    /// differences, at most 65 535, seen); it changes at the end of each block of `weight_interval` samples.
    pub fn noise_var(&self, group: usize, axis: usize) -> Option<u64> {
        let state = self.axes.get(axis)?;
        let e = state.est.get(group)?;
        (state.settled >> group & 1 != 0).then_some(e.var)
    }

    /// Current weight of `group`'s `axis`, Q16 (the best sensor has 2¹⁶).
    pub fn weight_q16(&self, group: usize, axis: usize) -> Option<u32> {
        self.axes.get(axis)?.weight_q16.get(group).copied()
    }

    /// Fuses one sample: `raw` as read (for rails and stuck channels), `axes` the groups' calibrated outputs.
    pub fn fuse(
        &mut self,
        raw: &[RawCounts; G],
        axes: &[[i32; AXES]; G],
        table: &CalibrationTable<G>,
    ) -> FusedSample {
        let mut out = FusedSample::default();
        self.fuse_into(raw, axes, table, &mut out);
        out
    }

    /// [`Self::fuse`] into `out`, every field of which it writes (the pipeline's path: a returned `FusedSample` was
    /// zeroed, then copied twice, ≈ 0.2 k Cortex-M4 instructions per frame).
    pub fn fuse_into(
        &mut self,
        raw: &[RawCounts; G],
        axes: &[[i32; AXES]; G],
        table: &CalibrationTable<G>,
        out: &mut FusedSample,
    ) {
        out.health = HealthMask::default();
        // Sensor-level exclusion, bitmasks over groups per kind [gyro, accel].
        let stuck_repeats = self.config.stuck_window.max(2).saturating_sub(1);
        // code ≤ raw_min or code ≥ raw_max  ⇔  (code − raw_min − 1) mod 2³² ≥ span = max(raw_max − raw_min − 1, 0):
        // one subtraction and one unsigned comparison. For raw_min < code the difference is exact; for code ≤ raw_min
        // it wraps to 2³² + code − raw_min − 1, which is ≥ span because code ≥ −2³¹ > raw_max − 2³².
        let (raw_min, raw_max) = (table.raw_min, table.raw_max);
        let above_min = raw_min.wrapping_add(1);
        // Differences of two `i32` in `i64`: no wrap; the result is in [0, 2³² − 2].
        let span = u32::try_from(
            i64::from(raw_max)
                .wrapping_sub(i64::from(raw_min))
                .wrapping_sub(1)
                .max(0),
        )
        .unwrap_or(u32::MAX);
        let (mut sat, mut stuck) = ([0u32; 2], [0u32; 2]);
        for (g, (r, watch)) in raw.iter().zip(self.raw.iter_mut()).enumerate() {
            let [(gyro_sat, gyro_stuck), (accel_sat, accel_stuck)] =
                watch.update(r, above_min, span, stuck_repeats);
            sat[0] |= u32::from(gyro_sat) << g;
            sat[1] |= u32::from(accel_sat) << g;
            stuck[0] |= u32::from(gyro_stuck) << g;
            stuck[1] |= u32::from(accel_stuck) << g;
        }
        let fixed = (self.config.mode == FusionMode::Fixed).then_some(&table.weights_q16);
        let mut excluded = self.config.excluded;
        if self.config.robust {
            for (((faults, excluded), &sat), &stuck) in
                [&mut out.health.gyro, &mut out.health.accel]
                    .into_iter()
                    .zip(excluded.iter_mut())
                    .zip(&sat)
                    .zip(&stuck)
            {
                faults.saturated = sat;
                faults.stuck = stuck & !sat;
                *excluded |= sat | stuck;
            }
        }

        // Noise blocks end, and weights are recomputed, every `weight_interval` samples.
        let fold = self
            .samples
            .is_multiple_of(u32::from(self.config.weight_interval.max(1)));
        let mut outlier = [0u32; 2];
        for (a, ((value, used), used_mask)) in out
            .axes
            .iter_mut()
            .zip(out.used.iter_mut())
            .zip(out.used_mask.iter_mut())
            .enumerate()
        {
            // 0 = gyro, 1 = accelerometer: the `get`s below never miss (as `a` < AXES for `axes[g]`).
            let kind = usize::from(a >= 3);
            let candidates = Self::ALL & !excluded.get(kind).copied().unwrap_or(0);
            // The axis's column, and the candidates with padding that sorts after them, in one pass.
            let (mut column, mut sorted) = ([0i32; G], [0i32; G]);
            unroll::zip_each(&mut sorted, axes, |g, s, row| {
                let v = row.get(a).copied().unwrap_or(0);
                if let Some(c) = column.get_mut(g as usize) {
                    *c = v;
                }
                *s = if candidates >> g & 1 != 0 {
                    v
                } else {
                    i32::MAX
                };
            });
            let (n, fused, out_mask, mask) =
                self.fuse_axis(a, &column, sorted, candidates, kind, fold, fixed);
            (*value, *used, *used_mask) = (fused, n, mask);
            if let Some(o) = outlier.get_mut(kind) {
                *o |= out_mask;
            }
        }
        out.health.gyro.outlier = outlier[0];
        out.health.accel.outlier = outlier[1];

        for (kind, h) in [out.health.gyro, out.health.accel].iter().enumerate() {
            let mut any = h.any();
            while any != 0 {
                let g = any.trailing_zeros();
                // Clears the lowest set bit; `any` ≠ 0, so this cannot wrap.
                any &= any.wrapping_sub(1);
                if let Some(c) = self
                    .faults
                    .get_mut(g as usize)
                    .and_then(|c| c.get_mut(kind))
                {
                    c.add(&h.counts_of(g));
                }
            }
        }
        self.samples = self.samples.wrapping_add(1);
    }

    /// One axis: `x` the groups' values, `sorted` the candidates' values and `i32::MAX` for the others,
    /// `candidates` the groups not excluded (bitmask), `fixed` the table's weights in `FusionMode::Fixed`; returns
    /// (sensors used, fused value, outlier mask, used mask). Its phases are the helpers below, each inlined into it
    /// (the flight hot path: the same code as when they were written out here).
    #[allow(clippy::too_many_arguments)]
    fn fuse_axis(
        &mut self,
        a: usize,
        x: &[i32; G],
        mut sorted: [i32; G],
        candidates: u32,
        kind: usize,
        fold: bool,
        fixed: Option<&[[i32; AXES]; G]>,
    ) -> (u8, i32, u32, u32) {
        let Some(state) = self.axes.get_mut(a) else {
            return (0, 0, 0, 0);
        };
        let n = candidates.count_ones() as usize;
        if n == 0 {
            state.resid_valid = 0;
            if fold {
                state.fold(self.config.noise_shift);
            }
            return (0, 0, 0, 0);
        }
        // Candidates sorted, then the padding.
        sort_small(&mut sorted);
        let median = median_sorted(sorted.get(..n).unwrap_or(&[]));

        let outliers = if self.config.robust && n >= 3 {
            let scale = self.scale.get_mut(a);
            outlier_mask(&self.config, scale, x, &sorted, n, median, candidates, kind)
        } else {
            0
        };
        let used = candidates & !outliers;

        state.add_differences(x, median, used);
        let weighted_mode = self.config.mode == FusionMode::InverseVariance;
        if fold {
            state.fold(self.config.noise_shift);
        }
        // Whether every used estimate has settled matters only for weighted means.
        let all_settled = weighted_mode && used & !state.settled == 0;
        // Weights, at the end of a block, or every sample until the first weights are in use.
        if weighted_mode && (fold || !self.weights_ready) && all_settled {
            state.set_weights(used, candidates);
            self.weights_ready = true;
        }

        let (num, den) = mean_sums(state, a, x, used, fixed, all_settled);
        if den == 0 {
            return (0, 0, outliers, 0);
        }
        (used.count_ones() as u8, div_round(num, den), outliers, used)
    }
}

/// The outliers among `candidates` (n ≥ 3 of them, `sorted` with the padding last, `median` theirs): the values
/// farther from the median than both `outlier_sigmas` robust deviations (the axis's MAD, averaged in `scale`) and
/// the floor of `kind`. Part of [`Fusion::fuse_axis`].
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn outlier_mask<const G: usize>(
    config: &FusionConfig,
    scale: Option<&mut AxisScale>,
    x: &[i32; G],
    sorted: &[i32; G],
    n: usize,
    median: i32,
    candidates: u32,
    kind: usize,
) -> u32 {
    let med = i64::from(median);
    let scale = scale.map_or(0, |s| s.update(i64::from(mad_sorted(sorted, n, median))));
    // |x − med| > k · 1.4826 · scale  ⇔  |x − med| · 2²⁴ > k_q8 · scale · 1.4826_q16; for the limit L ≥ 0 and
    // integer distances that is |x − med| > ⌊L / 2²⁴⌋. The scale is a MAD: ≥ 0 and < 2³¹ (the clamp only
    // states it), so L < 2¹⁶ · 2³¹ · 2¹⁷ = 2⁶⁴ fits `u64` for every configuration: the products cannot wrap.
    let scale = scale.clamp(0, i64::from(i32::MAX)) as u64;
    let limit_q24 = u64::from(config.outlier_sigmas_q8)
        .wrapping_mul(scale)
        .wrapping_mul(MAD_TO_SIGMA_Q16);
    let floor = i64::from(config.outlier_floor.get(kind).copied().unwrap_or(0));
    // ⌊L / 2²⁴⌋ < 2⁴⁰: the cast is exact.
    let threshold = floor.max((limit_q24 >> 24) as i64);
    if threshold < 0 {
        return candidates;
    }
    // |x − med| > t  ⇔  (x − med + t) ∉ [0, 2t]  ⇔  (x − med + t) as u64 > 2t, for t ≥ 0. Here
    // 0 ≤ t < 2⁴⁰ and |med|, |x| ≤ 2³¹: none of these sums wraps.
    let (offset, span) = (
        threshold.wrapping_sub(med),
        (threshold as u64).wrapping_mul(2),
    );
    let mut outliers = 0u32;
    unroll::each(x, |g, v| {
        outliers |= u32::from(i64::from(v).wrapping_add(offset) as u64 > span) << g;
    });
    outliers & candidates
}

impl<const G: usize> AxisState<G> {
    /// Noise estimates of the sensors `used`: a difference where the sensor was also used in the previous sample.
    /// Branch-free over all groups (the usual case uses them all). Part of [`Fusion::fuse_axis`].
    #[inline(always)]
    fn add_differences(&mut self, x: &[i32; G], median: i32, used: u32) {
        let diffs = self.resid_valid & used;
        unroll::zip_each(&mut self.est, x, |g, e, &v| {
            // = (x − median) clamped to i32
            let resid = v.saturating_sub(median);
            let take = diffs >> g & 1;
            // |Δr| < 2³², clamped to 2²⁴ (`VAR_LIMIT_ROOT`): the square is one 32 × 32 → 64-bit multiply.
            let d = resid.abs_diff(e.last_resid).min(VAR_LIMIT_ROOT as u32) & take.wrapping_neg();
            // ≤ 2⁴⁸ per term and ≤ `weight_interval` ≤ 65 535 terms per block (`fold` resets both): no wrap.
            e.block_sum = e
                .block_sum
                .wrapping_add(u64::from(d).wrapping_mul(u64::from(d)));
            e.block_n = e.block_n.wrapping_add(take as u16);
            // Read next sample only if the sensor is used now (`resid_valid` below).
            e.last_resid = resid;
        });
        self.resid_valid = used;
    }

    /// The inverse-variance weights of the `candidates`, relative to the least variance among the sensors `used`.
    /// Part of [`Fusion::fuse_axis`].
    #[inline(always)]
    fn set_weights(&mut self, used: u32, candidates: u32) {
        let var_min = self
            .est
            .iter()
            .enumerate()
            .filter(|&(g, _)| used >> g & 1 != 0)
            .fold(u64::MAX, |m, (_, e)| m.min(e.var.max(1)));
        for (g, (w, e)) in self.weight_q16.iter_mut().zip(&self.est).enumerate() {
            if candidates >> g & 1 != 0 {
                let var = NonZeroU64::new(e.var).unwrap_or(NonZeroU64::MIN);
                *w = ((var_min << 16) / var).clamp(1, 1 << 16) as u32;
            }
        }
    }
}

/// Σ wᵢ·xᵢ and Σ wᵢ of the mean over the sensors `used`: the table's fixed weights where they sum to a positive
/// value, else the running inverse-variance weights once `all_settled`, else equal weights. Part of
/// [`Fusion::fuse_axis`].
#[inline(always)]
fn mean_sums<const G: usize>(
    state: &mut AxisState<G>,
    a: usize,
    x: &[i32; G],
    used: u32,
    fixed: Option<&[[i32; AXES]; G]>,
    all_settled: bool,
) -> (i64, i64) {
    let (mut num, mut den) = fixed
        .map(|w| fixed_sums(w, a, x, used))
        .filter(|&(_, den)| den > 0)
        .unwrap_or((0, 0));
    if den > 0 {
        // Fixed weights.
    } else if all_settled {
        // Plain arithmetic, so that builds with overflow checks keep checking the bound: every weight is in
        // [1, 2¹⁶] (set so above, or the initial 2¹⁶), so |w · x| ≤ 2⁴⁷ and the sums of G ≤ 32 terms are < 2⁵³.
        #[allow(clippy::arithmetic_side_effects)]
        unroll::zip_each(&mut state.weight_q16, x, |g, &mut w, &v| {
            // w ≤ 2¹⁶: w · x is an i32 × i32 product.
            let w = (w & (used >> g & 1).wrapping_neg()) as i32;
            num += i64::from(w) * i64::from(v);
            den += i64::from(w);
        });
    } else {
        unroll::each(x, |g, v| {
            // G ≤ 32 values of `i32`: |num| ≤ 2³⁶, cannot wrap.
            num = num.wrapping_add(i64::from(v & (used >> g & 1).wrapping_neg() as i32));
        });
        den = i64::from(used.count_ones());
    }
    (num, den)
}

#[cfg(test)]
mod tests;
