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
use serde::{Deserialize, Serialize};

/// Most groups a fusion can handle (fault masks are `u32` bitmasks).
pub const MAX_GROUPS: usize = 32;
/// 1.4826 · 2¹⁶: MAD → σ of a normal distribution, Q16.
const MAD_TO_SIGMA_Q16: i64 = 97_163;

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

#[derive(Clone, Copy, Debug)]
struct AxisState {
    /// EWMA of Δr²/2, (output unit)².
    noise_var: u64,
    /// Noise estimate updates, saturating.
    updates: u32,
    last_resid: i32,
    resid_valid: bool,
    weight_q16: u32,
}

impl AxisState {
    const NEW: Self = Self {
        noise_var: 0,
        updates: 0,
        last_resid: 0,
        resid_valid: false,
        weight_q16: 1 << 16,
    };
}

#[derive(Clone, Copy, Debug)]
struct RawWatch {
    last: i32,
    repeats: u16,
}

impl RawWatch {
    const NEW: Self = Self {
        last: i32::MIN,
        repeats: 0,
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
/// Largest noise variance kept, so that `var << 16` fits in `u64`.
const VAR_LIMIT: u64 = 1 << 47;

/// Fusion state of an array of `G` groups (`G` ≤ 32).
#[derive(Clone, Debug)]
pub struct Fusion<const G: usize> {
    config: FusionConfig,
    axes: [[AxisState; AXES]; G],
    scale: [AxisScale; AXES],
    raw: [[RawWatch; RAW_CHANNELS]; G],
    /// `[group][0 = gyro, 1 = accel]`.
    faults: [[FaultCounts; 2]; G],
    samples: u32,
    weights_ready: bool,
}

/// `num / den` rounded half away from zero, saturated to `i32`; `den` > 0.
pub(crate) fn div_round(num: i64, den: i64) -> i32 {
    let half = den / 2;
    let q = if num >= 0 {
        (num + half) / den
    } else {
        -((half - num) / den)
    };
    q.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
}

/// Median of a non-empty sorted slice (mean of the middle two for even length, rounded as `div_round`).
fn median_sorted(v: &[i32]) -> i32 {
    let n = v.len();
    match (v.get(n / 2), n % 2) {
        (Some(&hi), 1) => hi,
        (Some(&hi), _) => div_round(
            i64::from(v.get(n / 2 - 1).copied().unwrap_or(hi)) + i64::from(hi),
            2,
        ),
        (None, _) => 0,
    }
}

impl<const G: usize> Fusion<G> {
    const FITS: () = assert!(G >= 1 && G <= MAX_GROUPS, "1 ≤ G ≤ 32");

    /// A fusion with no history.
    pub const fn new(config: FusionConfig) -> Self {
        let () = Self::FITS;
        Self {
            config,
            axes: [[AxisState::NEW; AXES]; G],
            scale: [AxisScale::NEW; AXES],
            raw: [[RawWatch::NEW; RAW_CHANNELS]; G],
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
        let s = self.axes.get(group)?.get(axis)?;
        (s.updates >= 1 << self.config.noise_shift.min(31)).then_some(s.noise_var)
    }

    /// Current weight of `group`'s `axis`, Q16 (the best sensor has 2¹⁶).
    pub fn weight_q16(&self, group: usize, axis: usize) -> Option<u32> {
        Some(self.axes.get(group)?.get(axis)?.weight_q16)
    }

    /// Fuses one sample: `raw` as read (for rails and stuck channels), `axes` the groups' calibrated outputs.
    pub fn fuse(
        &mut self,
        raw: &[RawCounts; G],
        axes: &[[i32; AXES]; G],
        table: &CalibrationTable<G>,
    ) -> FusedSample {
        let mut out = FusedSample::default();
        // Sensor-level exclusion: [gyro, accel] per group.
        let mut excluded = [[false; 2]; G];
        for (g, ((r, watch), ex)) in raw
            .iter()
            .zip(self.raw.iter_mut())
            .zip(excluded.iter_mut())
            .enumerate()
        {
            let bit = 1u32 << g;
            let channels = r.gyro.iter().chain(&r.accel);
            let mut stuck = [false; 2];
            let mut sat = [false; 2];
            for (ch, (&code, w)) in channels.zip(watch.iter_mut()).enumerate() {
                let kind = usize::from(ch >= crate::calib::GYRO_RAW);
                if code == w.last {
                    w.repeats = w.repeats.saturating_add(1);
                } else {
                    *w = RawWatch {
                        last: code,
                        repeats: 0,
                    };
                }
                stuck[kind] |=
                    u32::from(w.repeats) + 1 >= u32::from(self.config.stuck_window.max(2));
                sat[kind] |= table.saturated(code);
            }
            if !self.config.robust {
                continue;
            }
            for (kind, faults) in [&mut out.health.gyro, &mut out.health.accel]
                .into_iter()
                .enumerate()
            {
                if sat[kind] {
                    faults.saturated |= bit;
                } else if stuck[kind] {
                    faults.stuck |= bit;
                }
                ex[kind] = sat[kind] || stuck[kind];
            }
        }

        let recompute = self.config.mode == FusionMode::InverseVariance
            && (!self.weights_ready
                || self
                    .samples
                    .is_multiple_of(u32::from(self.config.weight_interval.max(1))));
        let mut outlier = [0u32; 2];
        for (a, (value, used)) in out.axes.iter_mut().zip(out.used.iter_mut()).enumerate() {
            let kind = usize::from(a >= 3);
            let (n, fused, out_mask, used_mask) =
                self.fuse_axis(a, axes, &excluded, kind, recompute);
            *value = fused;
            *used = n;
            outlier[kind] |= out_mask;
            if let Some(m) = out.used_mask.get_mut(a) {
                *m = used_mask;
            }
        }
        out.health.gyro.outlier = outlier[0];
        out.health.accel.outlier = outlier[1];

        for (g, counts) in self.faults.iter_mut().enumerate() {
            let bit = 1u32 << g;
            for (c, h) in counts.iter_mut().zip([&out.health.gyro, &out.health.accel]) {
                let bump = |x: &mut u32, mask: u32| *x = x.wrapping_add(u32::from(mask & bit != 0));
                bump(&mut c.saturated, h.saturated);
                bump(&mut c.stuck, h.stuck);
                bump(&mut c.outlier, h.outlier);
            }
        }
        self.samples = self.samples.wrapping_add(1);
        out
    }

    /// One axis: returns (sensors used, fused value, outlier mask, used mask).
    fn fuse_axis(
        &mut self,
        a: usize,
        axes: &[[i32; AXES]; G],
        excluded: &[[bool; 2]; G],
        kind: usize,
        recompute: bool,
    ) -> (u8, i32, u32, u32) {
        // Candidates: value and group, in a fixed-size buffer.
        let mut vals = [0i32; G];
        let mut n = 0;
        for (v, ex) in axes.iter().zip(excluded) {
            if let (false, Some(slot), Some(&x)) = (ex[kind], vals.get_mut(n), v.get(a)) {
                *slot = x;
                n += 1;
            }
        }
        if n == 0 {
            self.forget_residuals(a);
            return (0, 0, 0, 0);
        }
        let mut sorted = vals;
        let sorted = sorted.get_mut(..n).unwrap_or(&mut []);
        sorted.sort_unstable();
        let median = median_sorted(sorted);

        // Robust scale: MAD of the candidates.
        let mut outliers = 0u32;
        if self.config.robust && n >= 3 {
            let mut dev = [0i32; G];
            for (d, &x) in dev.iter_mut().zip(sorted.iter()) {
                *d = (i64::from(x) - i64::from(median))
                    .unsigned_abs()
                    .min(i32::MAX as u64) as i32;
            }
            let dev = dev.get_mut(..n).unwrap_or(&mut []);
            dev.sort_unstable();
            let scale = self
                .scale
                .get_mut(a)
                .map_or(0, |s| s.update(i64::from(median_sorted(dev))));
            // |x − med| > k · 1.4826 · scale  ⇔  |x − med| · 2²⁴ > k_q8 · scale · 1.4826_q16
            let limit_q24 = i64::from(self.config.outlier_sigmas_q8) * scale * MAD_TO_SIGMA_Q16;
            let floor = i64::from(self.config.outlier_floor.get(kind).copied().unwrap_or(0));
            for (g, (v, ex)) in axes.iter().zip(excluded).enumerate() {
                let Some(&x) = v.get(a) else { continue };
                let dist = (i64::from(x) - i64::from(median)).abs();
                if !ex[kind] && dist > floor && (dist << 24) > limit_q24 {
                    outliers |= 1 << g;
                }
            }
        }

        // Noise estimates and weights of the sensors used.
        let shift = u32::from(self.config.noise_shift.min(31));
        let settled = 1u32 << shift;
        let mut var_min = u64::MAX;
        let mut all_settled = true;
        for (g, (v, ex)) in axes.iter().zip(excluded).enumerate() {
            let Some(state) = self.axes.get_mut(g).and_then(|s| s.get_mut(a)) else {
                continue;
            };
            let used = !ex[kind] && outliers & (1 << g) == 0;
            let Some(&x) = v.get(a) else { continue };
            if !used {
                state.resid_valid = false;
                continue;
            }
            let resid = (i64::from(x) - i64::from(median))
                .clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
            if state.resid_valid {
                let d = i64::from(resid) - i64::from(state.last_resid);
                let sample = (d.unsigned_abs().saturating_mul(d.unsigned_abs()) / 2).min(VAR_LIMIT);
                if sample >= state.noise_var {
                    state.noise_var += (sample - state.noise_var) >> shift;
                } else {
                    state.noise_var -= (state.noise_var - sample) >> shift;
                }
                state.updates = state.updates.saturating_add(1);
            }
            state.last_resid = resid;
            state.resid_valid = true;
            all_settled &= state.updates >= settled;
            var_min = var_min.min(state.noise_var.max(1));
        }
        if recompute && all_settled {
            for (state, ex) in self.axes.iter_mut().map(|s| s.get_mut(a)).zip(excluded) {
                if let (Some(state), false) = (state, ex[kind]) {
                    state.weight_q16 =
                        ((var_min << 16) / state.noise_var.max(1)).clamp(1, 1 << 16) as u32;
                }
            }
            self.weights_ready = true;
        }

        // The mean over the used sensors.
        let weighted = self.config.mode == FusionMode::InverseVariance && all_settled;
        let (mut num, mut den, mut used, mut mask) = (0i64, 0i64, 0u8, 0u32);
        for (g, (v, ex)) in axes.iter().zip(excluded).enumerate() {
            let (Some(&x), Some(state)) = (v.get(a), self.axes.get(g).and_then(|s| s.get(a)))
            else {
                continue;
            };
            if ex[kind] || outliers & (1 << g) != 0 {
                continue;
            }
            let w = if weighted {
                i64::from(state.weight_q16)
            } else {
                1
            };
            num += w * i64::from(x);
            den += w;
            used += 1;
            mask |= 1 << g;
        }
        if den == 0 {
            return (0, 0, outliers, 0);
        }
        (used, div_round(num, den), outliers, mask)
    }

    fn forget_residuals(&mut self, a: usize) {
        for s in self.axes.iter_mut().filter_map(|s| s.get_mut(a)) {
            s.resid_valid = false;
        }
    }
}

#[cfg(test)]
mod tests;
