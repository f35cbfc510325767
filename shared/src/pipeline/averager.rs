//! The output interval's running mean of the fused samples (see the pipeline's module docs: averaging, not
//! discarding).

use crate::calib::AXES;
use crate::fuse::{FusedSample, HealthMask, div_round};
use crate::telemetry::FusedReport;

/// Sums of one output interval.
#[derive(Clone, Copy, Debug)]
pub(super) struct Averager {
    sum: [i64; AXES],
    valid: [u16; AXES],
    used_min: [u8; AXES],
    health: HealthMask,
    temp_sum: i32,
    temp_n: u16,
    pub(super) frames: u16,
    t_us: u64,
}

impl Averager {
    pub(super) const NEW: Self = Self {
        sum: [0; AXES],
        valid: [0; AXES],
        used_min: [u8::MAX; AXES],
        health: HealthMask::NONE,
        temp_sum: 0,
        temp_n: 0,
        frames: 0,
        t_us: 0,
    };

    /// Adds one frame's fused sample.
    ///
    /// Plain arithmetic, so that builds with overflow checks keep checking the bound: an interval holds at most
    /// `frames_per_output` ≤ `u16::MAX` frames (`process` reports and resets it when it is full), so `frames`,
    /// `valid` and `temp_n` stay ≤ 65535, |`sum`| ≤ 65535 · 2³¹ < 2⁴⁸ and |`temp_sum`| ≤ 65535 · 2¹⁵ < 2³¹.
    #[allow(clippy::arithmetic_side_effects)]
    pub(super) fn add(&mut self, s: &FusedSample, temp_cdeg: Option<i16>, t_us: u64) {
        if self.frames == 0 {
            self.t_us = t_us;
        }
        self.frames += 1;
        for (((sum, valid), used_min), (&used, &x)) in self
            .sum
            .iter_mut()
            .zip(&mut self.valid)
            .zip(&mut self.used_min)
            .zip(s.used.iter().zip(&s.axes))
        {
            if used > 0 {
                *sum += i64::from(x);
                *valid += 1;
                *used_min = (*used_min).min(used);
            }
        }
        self.health.merge(&s.health);
        if let Some(t) = temp_cdeg {
            self.temp_sum += i32::from(t);
            self.temp_n += 1;
        }
    }

    /// The interval's report; `epoch_us` maps frame time to spacecraft time (`None`: not set).
    pub(super) fn report(&self, seq: u32, epoch_us: Option<u64>) -> FusedReport {
        let mut mean = [0i32; AXES];
        let mut used = [0u8; AXES];
        for ((((m, u), &sum), &valid), &used_min) in mean
            .iter_mut()
            .zip(&mut used)
            .zip(&self.sum)
            .zip(&self.valid)
            .zip(&self.used_min)
        {
            if valid > 0 {
                (*m, *u) = (div_round(sum, i64::from(valid)), used_min);
            }
        }
        let [rx, ry, rz, ax, ay, az] = mean;
        FusedReport {
            seq,
            t_us: self.t_us,
            frames: self.frames,
            rate_udps: [rx, ry, rz],
            accel_ug: [ax, ay, az],
            used,
            health: self.health,
            temp_cdeg: (self.temp_n > 0)
                .then(|| div_round(i64::from(self.temp_sum), i64::from(self.temp_n)) as i16),
            // Wrapping as in `Pipeline::time_report`: the epoch is a difference of two times modulo 2⁶⁴.
            unix_us: epoch_us.map(|e| self.t_us.wrapping_add(e)),
        }
    }
}
