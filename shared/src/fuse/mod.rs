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
//!    which removes the common signal and the sensor's own bias, and `Δr²/2` is averaged by an exponential moving
//!    average over 2^`noise_shift` samples: an estimate of the sensor's white-noise variance.
//! 3. **Mean**: the equal-weight mean (the seed paper's), or the inverse-variance weighted mean with weights
//!    `w_i = 2¹⁶ · σ²_min / σ²_i` (Q16, the best sensor has 2¹⁶), recomputed every `weight_interval` samples once
//!    every sensor's estimate has settled; equal weights until then. Division rounds half away from zero.
//!
//! If no sensor is left for an axis, the axis is flagged invalid (`used = 0`, value 0): never a division by zero.
//! Changing weights move the fused bias between the sensors' residual biases; the slow estimator and the weight
//! interval keep that drift far below the noise, and `FusionMode::Equal` removes it entirely.

use crate::calib::{AXES, CalibrationTable, RawCounts};
use core::num::NonZeroU64;
use serde::{Deserialize, Serialize};

/// Most groups a fusion can handle (fault masks are `u32` bitmasks).
pub const MAX_GROUPS: usize = 32;
/// 1.4826 · 2¹⁶: MAD → σ of a normal distribution, Q16.
const MAD_TO_SIGMA_Q16: u64 = 97_163;

/// How the used sensors are averaged.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FusionMode {
    /// Equal weights: the seed paper's cluster mean.
    Equal,
    /// Inverse-variance weights from the running noise estimates.
    InverseVariance,
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

/// Noise estimator of one sensor axis.
#[derive(Clone, Copy, Debug)]
struct NoiseEst {
    /// EWMA of Δr²/2, (output unit)².
    var: u64,
    /// Updates, saturating.
    updates: u32,
    /// Residual from the median in the last sample that used the sensor.
    last_resid: i32,
}

impl NoiseEst {
    const NEW: Self = Self {
        var: 0,
        updates: 0,
        last_resid: 0,
    };

    /// Averages in `Δr²/2` for the new residual `resid` (`last_resid` valid) with weight 2^−`shift`;
    /// `round` = 2^`shift` − 1 (`shift` ≤ 31).
    ///
    /// Plain arithmetic, so that builds with overflow checks keep checking the bound: `sample` ≤ [`VAR_LIMIT`] = 2⁴⁷,
    /// and `var` stays in [0, 2⁴⁷] (it starts at 0 and each update moves it toward a `sample`, not past it), so
    /// `diff`, `step` and the new `var` lie in [−2⁴⁷, 2⁴⁷] and `diff + round` < 2⁴⁸: nothing overflows `i64`.
    #[allow(clippy::arithmetic_side_effects)]
    fn update(&mut self, resid: i32, shift: u32, round: i64) {
        // min(d²/2, VAR_LIMIT) with VAR_LIMIT = 2⁴⁷ = (2²⁴)²/2 equals (min(|d|, 2²⁴))²/2: one 32 × 32 → 64-bit
        // multiply (UMULL on the Cortex-M4) instead of a 64-bit square and compare.
        let d = (i64::from(resid) - i64::from(self.last_resid))
            .unsigned_abs()
            .min(VAR_LIMIT_ROOT) as u32;
        let sample = u64::from(d) * u64::from(d) / 2;
        // var += (sample − var) / 2^shift, the quotient rounded toward zero (a negative dividend is biased by
        // 2^shift − 1 before the arithmetic shift); both terms ≤ 2⁴⁷, so everything fits in i64. Branch-free.
        let diff = sample as i64 - self.var as i64;
        let step = (diff + ((diff >> 63) & round)) >> shift;
        self.var = (self.var as i64 + step) as u64;
        self.updates = self.updates.saturating_add(1);
    }
}

/// Noise-estimator state of one axis of all `G` groups, with bitmasks over groups (bit g = group g).
#[derive(Clone, Copy, Debug)]
struct AxisState<const G: usize> {
    /// Per group.
    est: [NoiseEst; G],
    /// Groups whose `last_resid` is from the previous sample.
    resid_valid: u32,
    /// Weights, Q16.
    weight_q16: [u32; G],
}

impl<const G: usize> AxisState<G> {
    const NEW: Self = Self {
        est: [NoiseEst::NEW; G],
        resid_valid: 0,
        weight_q16: [1 << 16; G],
    };
}

/// Raw-channel watch of one group: the last code of each channel and how often it repeated since it changed
/// (saturating at `u16::MAX`). Eight lanes for the seven channels, so that the update is two 4-lane vector
/// operations where the target has them; lane 7 is padding, never reported.
#[derive(Clone, Copy, Debug)]
struct RawWatch {
    last: [i32; RAW_LANES],
    repeats: [u32; RAW_LANES],
}

impl RawWatch {
    const NEW: Self = Self {
        last: [i32::MIN; RAW_LANES],
        repeats: [0; RAW_LANES],
    };
}

/// The cluster MAD is averaged over 2^SCALE_SHIFT samples (see module docs).
const SCALE_SHIFT: u32 = 4;

/// Per-axis robust scale: EWMA of the cluster MAD, Q16 of output units.
#[derive(Clone, Copy, Debug)]
struct AxisScale {
    mad_q16: i64,
    init: bool,
}

impl AxisScale {
    const NEW: Self = Self {
        mad_q16: 0,
        init: false,
    };

    /// Averages `mad` in; returns the averaged scale (output units, rounded up).
    ///
    /// Plain arithmetic, so that builds with overflow checks keep checking the bound: `mad` is an `i32` MAD, so
    /// |x| < 2⁴⁷; `mad_q16` starts at such an x and each update moves it toward the next one, not past it, so it stays
    /// within ±2⁴⁷ and every sum here is < 2⁴⁹ in magnitude.
    #[allow(clippy::arithmetic_side_effects)]
    fn update(&mut self, mad: i64) -> i64 {
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

const RAW_CHANNELS: usize = crate::calib::GYRO_RAW + crate::calib::ACCEL_RAW;
/// Lanes of a [`RawWatch`]: the raw channels (an eighth padding lane cost 0.5 k Cortex-M4 instructions per frame).
const RAW_LANES: usize = RAW_CHANNELS;
/// Raw channels of the gyros, as bits over channels.
const GYRO_CHANNELS: u32 = (1 << crate::calib::GYRO_RAW) - 1;
/// Raw channels of the accelerometer.
const ACCEL_CHANNELS: u32 = ((1 << RAW_CHANNELS) - 1) & !GYRO_CHANNELS;
/// Largest noise variance kept, so that `var << 16` fits in `u64`.
const VAR_LIMIT: u64 = 1 << 47;
/// The difference whose `d²/2` is [`VAR_LIMIT`].
const VAR_LIMIT_ROOT: u64 = 1 << 24;
const _: () = assert!(VAR_LIMIT_ROOT * VAR_LIMIT_ROOT / 2 == VAR_LIMIT);

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
    (q ^ s)
        .wrapping_sub(s)
        .clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

/// Median of a non-empty sorted slice (mean of the middle two for even length, rounded as `div_round`).
fn median_sorted(v: &[i32]) -> i32 {
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
fn mad_sorted<const G: usize>(v: &[i32; G], n: usize, median: i32) -> i32 {
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
    fn before(j: usize, back: usize, f: impl Fn(usize) -> i64) -> i64 {
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
fn sort16(v: &mut [i32; 16]) {
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
    macro_rules! layer {
        ($(($i:ident, $j:ident)),*) => { $((($i, $j) = ($i.min($j), $i.max($j)));)* };
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
fn sort_small<const G: usize>(v: &mut [i32; G]) {
    match <&mut [i32; 16]>::try_from(v.as_mut_slice()) {
        Ok(v16) => sort16(v16),
        Err(_) => v.sort_unstable(),
    }
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

    /// The parameters in force.
    pub fn config(&self) -> &FusionConfig {
        &self.config
    }

    /// Changes the parameters; the noise estimates are kept.
    pub fn set_config(&mut self, config: FusionConfig) {
        self.config = config;
    }

    /// Fault counts of `group`: `[gyro, accel]`.
    pub fn fault_counts(&self, group: usize) -> Option<[FaultCounts; 2]> {
        self.faults.get(group).copied()
    }

    /// Running white-noise variance estimate of `group`'s `axis`, (output unit)², once settled.
    pub fn noise_var(&self, group: usize, axis: usize) -> Option<u64> {
        let e = self.axes.get(axis)?.est.get(group)?;
        (e.updates >= 1 << self.config.noise_shift.min(31)).then_some(e.var)
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
        // Sensor-level exclusion, bitmasks over groups per kind [gyro, accel].
        let stuck_repeats = u32::from(self.config.stuck_window.max(2)).saturating_sub(1);
        let (raw_min, raw_max) = (table.raw_min, table.raw_max);
        let (mut sat, mut stuck) = ([0u32; 2], [0u32; 2]);
        for (g, (r, watch)) in raw.iter().zip(self.raw.iter_mut()).enumerate() {
            let [g0, g1, g2, g3] = r.gyro;
            let [a0, a1, a2] = r.accel;
            // Bit ch per raw channel (gyro channels first).
            let (mut ch_sat, mut ch_stuck) = (0u32, 0u32);
            for (ch, ((&code, last), repeats)) in [g0, g1, g2, g3, a0, a1, a2]
                .iter()
                .zip(watch.last.iter_mut())
                .zip(watch.repeats.iter_mut())
                .enumerate()
            {
                // Branch-free: + 1 (saturating) where the code repeats, 0 where it changed. `repeats` ≤ u16::MAX (this
                // `min`, every sample): the increment cannot wrap.
                *repeats = repeats.wrapping_add(1).min(u16::MAX.into())
                    & u32::from(code == *last).wrapping_neg();
                *last = code;
                ch_stuck |= u32::from(*repeats >= stuck_repeats) << ch;
                // = table.saturated(code)
                ch_sat |= u32::from(code <= raw_min || code >= raw_max) << ch;
            }
            for ((sat, stuck), channels) in sat
                .iter_mut()
                .zip(stuck.iter_mut())
                .zip([GYRO_CHANNELS, ACCEL_CHANNELS])
            {
                *sat |= u32::from(ch_sat & channels != 0) << g;
                *stuck |= u32::from(ch_stuck & channels != 0) << g;
            }
        }
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

        let recompute = self.config.mode == FusionMode::InverseVariance
            && (!self.weights_ready
                || self
                    .samples
                    .is_multiple_of(u32::from(self.config.weight_interval.max(1))));
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
            let column: [i32; G] =
                core::array::from_fn(|g| axes.get(g).and_then(|x| x.get(a)).copied().unwrap_or(0));
            let candidates = Self::ALL & !excluded.get(kind).copied().unwrap_or(0);
            let (n, fused, out_mask, mask) =
                self.fuse_axis(a, &column, candidates, kind, recompute);
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
        out
    }

    /// One axis: `x` the groups' values, `candidates` the groups not excluded (bitmask); returns (sensors used,
    /// fused value, outlier mask, used mask).
    fn fuse_axis(
        &mut self,
        a: usize,
        x: &[i32; G],
        candidates: u32,
        kind: usize,
        recompute: bool,
    ) -> (u8, i32, u32, u32) {
        let Some(state) = self.axes.get_mut(a) else {
            return (0, 0, 0, 0);
        };
        let n = candidates.count_ones() as usize;
        if n == 0 {
            state.resid_valid = 0;
            return (0, 0, 0, 0);
        }
        // Candidates sorted, then padding that sorts after them.
        let mut sorted: [i32; G] = core::array::from_fn(|g| match x.get(g) {
            Some(&v) if candidates >> g & 1 != 0 => v,
            _ => i32::MAX,
        });
        sort_small(&mut sorted);
        let median = median_sorted(sorted.get(..n).unwrap_or(&[]));
        let med = i64::from(median);

        // Robust scale: MAD of the candidates.
        let mut outliers = 0u32;
        if self.config.robust && n >= 3 {
            let scale = self
                .scale
                .get_mut(a)
                .map_or(0, |s| s.update(i64::from(mad_sorted(&sorted, n, median))));
            // |x − med| > k · 1.4826 · scale  ⇔  |x − med| · 2²⁴ > k_q8 · scale · 1.4826_q16; for the limit L ≥ 0 and
            // integer distances that is |x − med| > ⌊L / 2²⁴⌋. The scale is a MAD: ≥ 0 and < 2³¹ (the clamp only
            // states it), so L < 2¹⁶ · 2³¹ · 2¹⁷ = 2⁶⁴ fits `u64` for every configuration: the products cannot wrap.
            let scale = scale.clamp(0, i64::from(i32::MAX)) as u64;
            let limit_q24 = u64::from(self.config.outlier_sigmas_q8)
                .wrapping_mul(scale)
                .wrapping_mul(MAD_TO_SIGMA_Q16);
            let floor = i64::from(self.config.outlier_floor.get(kind).copied().unwrap_or(0));
            // ⌊L / 2²⁴⌋ < 2⁴⁰: the cast is exact.
            let threshold = floor.max((limit_q24 >> 24) as i64);
            if threshold < 0 {
                outliers = candidates;
            } else {
                // |x − med| > t  ⇔  (x − med + t) ∉ [0, 2t]  ⇔  (x − med + t) as u64 > 2t, for t ≥ 0. Here
                // 0 ≤ t < 2⁴⁰ and |med|, |x| ≤ 2³¹: none of these sums wraps.
                let (offset, span) = (
                    threshold.wrapping_sub(med),
                    (threshold as u64).wrapping_mul(2),
                );
                for (g, &v) in x.iter().enumerate() {
                    outliers |= u32::from(i64::from(v).wrapping_add(offset) as u64 > span) << g;
                }
                outliers &= candidates;
            }
        }
        let used = candidates & !outliers;

        // Noise estimates of the sensors used.
        let shift = u32::from(self.config.noise_shift.min(31));
        // shift ≤ 31: 2^shift − 1 ≥ 0 cannot wrap.
        let (round, settled) = ((1i64 << shift).wrapping_sub(1), 1u32 << shift);
        let valid = state.resid_valid;
        // Whether every used estimate has settled matters only for weighted means.
        let weighted_mode = self.config.mode == FusionMode::InverseVariance;
        let mut all_settled = weighted_mode;
        let mut rest = used;
        while rest != 0 {
            let g = rest.trailing_zeros() as usize;
            // Clears the lowest set bit; `rest` ≠ 0, so this cannot wrap.
            rest &= rest.wrapping_sub(1);
            let (Some(e), Some(&v)) = (state.est.get_mut(g), x.get(g)) else {
                break;
            };
            // = (x − median) clamped to i32
            let resid = v.saturating_sub(median);
            if valid >> g & 1 != 0 {
                e.update(resid, shift, round);
            }
            e.last_resid = resid;
            all_settled &= e.updates >= settled;
        }
        state.resid_valid = used;
        // Weights (`recompute` implies the weighted mode).
        if recompute && all_settled {
            let var_min = state
                .est
                .iter()
                .enumerate()
                .filter(|&(g, _)| used >> g & 1 != 0)
                .fold(u64::MAX, |m, (_, e)| m.min(e.var.max(1)));
            for (g, (w, e)) in state.weight_q16.iter_mut().zip(&state.est).enumerate() {
                if candidates >> g & 1 != 0 {
                    let var = NonZeroU64::new(e.var).unwrap_or(NonZeroU64::MIN);
                    *w = ((var_min << 16) / var).clamp(1, 1 << 16) as u32;
                }
            }
            self.weights_ready = true;
        }

        // The mean over the used sensors.
        let (mut num, mut den) = (0i64, 0i64);
        if all_settled {
            // Plain arithmetic, so that builds with overflow checks keep checking the bound: every weight is in
            // [1, 2¹⁶] (set so above, or the initial 2¹⁶), so |w · x| ≤ 2⁴⁷ and the sums of G ≤ 32 terms are < 2⁵³.
            #[allow(clippy::arithmetic_side_effects)]
            for (g, (&v, &w)) in x.iter().zip(&state.weight_q16).enumerate() {
                // w ≤ 2¹⁶: w · x is an i32 × i32 product.
                let w = (w & (used >> g & 1).wrapping_neg()) as i32;
                num += i64::from(w) * i64::from(v);
                den += i64::from(w);
            }
        } else {
            for (g, &v) in x.iter().enumerate() {
                // G ≤ 32 values of `i32`: |num| ≤ 2³⁶, cannot wrap.
                num = num.wrapping_add(i64::from(v & (used >> g & 1).wrapping_neg() as i32));
            }
            den = i64::from(used.count_ones());
        }
        if den == 0 {
            return (0, 0, outliers, 0);
        }
        (used.count_ones() as u8, div_round(num, den), outliers, used)
    }
}

#[cfg(test)]
mod tests;
