//! Fixed-point calibration of each sensor group (spec: `docs/calibration.md`).
//!
//! Per group, gyro `ω = M_g · (raw_g − b_g)` with `M_g` 3×4 (the two z outputs both contribute) and accelerometer
//! `a = M_a · (raw_a − b_a)` with a full 3×3 `M_a` (any mounting rotation). Outputs are integers in physical units:
//! µ°/s for rates, µg for specific force.
//!
//! Q-formats: matrix entries and biases are `i32` in Q19.12 (12 fractional bits): matrix entries in output units
//! per ADC count, biases in ADC counts. The difference `raw·2¹² − b` is formed in `i64`, multiplied by the matrix
//! entries and summed in `i64` (the Cortex-M4's single-cycle `SMLAL`), then rounded once, half away from zero, by
//! 2⁻²⁴ and saturated to `i32`. Bounds: with `|raw| ≤ 2¹⁶` and `|b| ≤ 2¹⁶` counts (checked when a table is
//! loaded) each product is below 2³¹·2²⁹ = 2⁶⁰ and a sum of four below 2⁶², so nothing overflows and the only
//! error is the final rounding: ≤ 0.5 output LSB, proven against an f64 reference in the tests.

mod table;
pub mod thermal;

pub use table::{
    CAL_FORMAT_VERSION, CalError, CalibrationTable, GroupThermal, WEIGHT_LIMIT_Q16, encoded_len_max,
};

use serde::{Deserialize, Serialize};

/// Fractional bits of matrix entries and biases.
pub const FRAC_BITS: u32 = 12;
/// Raw gyro channels per group (gyro A x, z; gyro B y, z).
pub const GYRO_RAW: usize = 4;
/// Raw accelerometer channels per group.
pub const ACCEL_RAW: usize = 3;
/// Calibrated axes per group: gyro x, y, z then accelerometer x, y, z.
pub const AXES: usize = 6;
/// Largest accepted bias magnitude, Q19.12 (65536 counts).
pub const BIAS_LIMIT_Q12: i32 = 1 << 28;
/// Largest raw magnitude for which the result is exact (see module docs).
pub const RAW_LIMIT: i32 = 1 << 16;

/// Index of gyro x in a calibrated axis array (µ°/s).
pub const GX: usize = 0;
/// Index of gyro y (µ°/s).
pub const GY: usize = 1;
/// Index of gyro z (µ°/s).
pub const GZ: usize = 2;
/// Index of accelerometer x (µg).
pub const AX: usize = 3;
/// Index of accelerometer y (µg).
pub const AY: usize = 4;
/// Index of accelerometer z (µg).
pub const AZ: usize = 5;

/// One group's raw readings in signed counts (ADC codes as read, or signed sensor words).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RawCounts {
    /// Gyro channels, in the order the group's matrix columns expect (on our board: A x, A z, B y, B z).
    pub gyro: [i32; GYRO_RAW],
    /// Accelerometer channels x, y, z as wired.
    pub accel: [i32; ACCEL_RAW],
}

impl RawCounts {
    /// All channels zero (`Default`, usable in `const`).
    pub const ZERO: Self = Self {
        gyro: [0; GYRO_RAW],
        accel: [0; ACCEL_RAW],
    };
}

impl RawCounts {
    /// The 7 ADC codes of an FPGA frame group (`wire::frame::RAW_*` order).
    pub fn from_adc(codes: &crate::wire::frame::RawGroup) -> Self {
        let [a, b, c, d, e, f, g] = codes.map(i32::from);
        Self {
            gyro: [a, b, c, d],
            accel: [e, f, g],
        }
    }

    /// The counts of every group of `frame`, read from its bytes (`Frame::groups`: no copy of the frame), into
    /// `out` (one per group, in order). Always inlined: it runs once per frame, in the frame loop.
    #[inline(always)]
    pub fn read_frame<T: AsRef<[u8]>>(
        frame: &crate::wire::Frame<T>,
        out: &mut [Self; crate::wire::frame::GROUPS],
    ) {
        for (r, codes) in out.iter_mut().zip(frame.groups()) {
            *r = Self::from_adc(&codes);
        }
    }
}

/// Calibration of one group. All fields Q19.12.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GroupCal {
    /// `M_g`, µ°/s per count, rows x, y, z; columns = raw gyro channels.
    pub gyro_matrix_q12: [[i32; GYRO_RAW]; 3],
    /// `b_g`, counts.
    pub gyro_bias_q12: [i32; GYRO_RAW],
    /// `M_a`, µg per count, rows x, y, z.
    pub accel_matrix_q12: [[i32; ACCEL_RAW]; 3],
    /// `b_a`, counts.
    pub accel_bias_q12: [i32; ACCEL_RAW],
}

/// `x` saturated to `i32`: the low word when, sign-extended, it gives `x` back (one comparison of the high word on
/// the Cortex-M4, where a two-sided 64-bit clamp is two 64-bit comparisons), else `i32::MIN` or `i32::MAX` by sign.
pub(crate) fn saturate_i32(x: i64) -> i32 {
    let narrow = x as i32;
    if i64::from(narrow) == x {
        narrow
    } else {
        ((x >> 63) as i32) ^ i32::MAX
    }
}

/// Rounds `acc / 2²⁴` (a Q12 × Q12 product sum) to the nearest integer, halves away from zero, saturating to
/// `i32`, for |acc| < 2⁶² (what [`affine`] can produce).
///
/// `(acc + 2²³ + s) >> 24` with s = −1 for acc < 0 and 0 otherwise: for acc ≥ 0 that is ⌊(acc + 2²³) / 2²⁴⌋, half
/// up; for acc = −a < 0 it is ⌊(2²³ − 1 − a) / 2²⁴⌋ = −⌈(a − 2²³ + 1) / 2²⁴⌉ = −⌊(a + 2²³) / 2²⁴⌋, the same rounding
/// of |acc| with the sign restored. Two 64-bit additions and a shift, no absolute value (on the Cortex-M4 half the
/// instructions of rounding |acc| and restoring the sign).
fn round_q24_sat(acc: i64) -> i32 {
    const HALF: i64 = 1 << (2 * FRAC_BITS - 1);
    // |acc| < 2⁶²: the sums stay within ±(2⁶² + 2²³), no wrap.
    let q = acc.wrapping_add(HALF).wrapping_add(acc >> 63) >> (2 * FRAC_BITS);
    saturate_i32(q)
}

fn affine<const N: usize>(m: &[[i32; N]; 3], b: &[i32; N], raw: &[i32; N]) -> [i32; 3] {
    // The sum of N products below stays under 2⁶³ for N ≤ 4 (4 raw gyro channels, 3 accelerometer channels).
    const { assert!(N <= 4) };
    // In 32 bits, so that every product is one 32 × 32 → 64-bit multiply (SMLAL on the Cortex-M4): ADC codes
    // (0 ≤ raw < 2¹⁶) give raw · 2¹² < 2²⁸, and a table's biases are within ±2²⁸ (`BIAS_LIMIT_Q12`, checked when a
    // table is decoded), so d = raw · 2¹² − b stays within (−2²⁸, 2²⁹) and nothing wraps. Outside that domain
    // (counts or biases no frame or table can carry) the result wraps instead of failing: a clamp in 64 bits would
    // cost every frame and never act on real input.
    let mut d = [0i32; N];
    for ((dj, &rj), &bj) in d.iter_mut().zip(raw).zip(b) {
        *dj = rj.wrapping_shl(FRAC_BITS).wrapping_sub(bj);
    }
    // |m_ij · d_j| ≤ 2³¹ · 2²⁹ = 2⁶⁰, and a sum of N ≤ 4 of them is < 2⁶²: cannot wrap.
    let dot = |row: &[i32; N]| {
        row.iter().zip(&d).fold(0i64, |acc, (&mij, &dj)| {
            acc.wrapping_add(i64::from(mij).wrapping_mul(i64::from(dj)))
        })
    };
    // Three named rows rather than `m.map(..)`, which copied the rows first (measured at opt-level "s").
    let [r0, r1, r2] = m;
    [
        round_q24_sat(dot(r0)),
        round_q24_sat(dot(r1)),
        round_q24_sat(dot(r2)),
    ]
}

impl GroupCal {
    /// Calibrates one group: `[gx, gy, gz]` in µ°/s then `[ax, ay, az]` in µg (see `GX` … `AZ`).
    pub fn apply(&self, raw: &RawCounts) -> [i32; AXES] {
        let [gx, gy, gz] = affine(&self.gyro_matrix_q12, &self.gyro_bias_q12, &raw.gyro);
        let [ax, ay, az] = affine(&self.accel_matrix_q12, &self.accel_bias_q12, &raw.accel);
        [gx, gy, gz, ax, ay, az]
    }

    /// True when every bias is within [`BIAS_LIMIT_Q12`], the domain where [`Self::apply`] is exact.
    pub fn biases_in_range(&self) -> bool {
        self.gyro_bias_q12
            .iter()
            .chain(&self.accel_bias_q12)
            .all(|b| b.unsigned_abs() <= BIAS_LIMIT_Q12 as u32)
    }
}

/// Nominal analog chain of our board, the source of the factory-default calibration and of the simulator's
/// inverse calibration. ADS8332 (16 bit, unipolar, 4.096 V reference: 62.5 µV per count); LPY410AL gyros on their
/// 4× outputs (10 mV per °/s, zero rate at 1.23 V); ADXL335 accelerometer at 3.0 V (300 mV/g, zero g at 1.5 V).
pub mod board {
    use super::{FRAC_BITS, GroupCal};

    /// ADC resolution, µV per count.
    pub const ADC_UV_PER_COUNT: f64 = 62.5;
    /// Gyro sensitivity, µV per °/s.
    pub const GYRO_UV_PER_DPS: f64 = 10_000.0;
    /// Gyro zero-rate output, µV.
    pub const GYRO_ZERO_UV: f64 = 1_230_000.0;
    /// Accelerometer sensitivity, µV per g.
    pub const ACCEL_UV_PER_G: f64 = 300_000.0;
    /// Accelerometer zero-g output, µV.
    pub const ACCEL_ZERO_UV: f64 = 1_500_000.0;

    /// Nominal gyro scale: µ°/s per count (= 62.5 / 10000 °/s = 6250 µ°/s).
    pub const GYRO_UDPS_PER_COUNT: i32 = 6_250;
    /// Nominal accelerometer scale, Q19.12 µg per count (62.5 / 300000 g = 208.33 µg).
    pub const ACCEL_UG_PER_COUNT_Q12: i32 = 853_333;
    /// Nominal gyro zero-rate code, Q19.12 (1.23 V / 62.5 µV = 19680 counts).
    pub const GYRO_ZERO_Q12: i32 = 19_680 << FRAC_BITS;
    /// Nominal accelerometer zero-g code, Q19.12 (24000 counts).
    pub const ACCEL_ZERO_Q12: i32 = 24_000 << FRAC_BITS;

    /// ADC codes (unrounded) that the nominal chain produces for a true rate (°/s, sensor axes) and specific
    /// force (g), in `wire::frame::RAW_*` order: the inverse of [`NOMINAL`], for simulators and tests.
    pub fn nominal_codes(rate_dps: [f64; 3], accel_g: [f64; 3]) -> [f64; 7] {
        let g = |w: f64| (GYRO_ZERO_UV + w * GYRO_UV_PER_DPS) / ADC_UV_PER_COUNT;
        let a = |x: f64| (ACCEL_ZERO_UV + x * ACCEL_UV_PER_G) / ADC_UV_PER_COUNT;
        let [wx, wy, wz] = rate_dps;
        let [ax, ay, az] = accel_g;
        [g(wx), g(wz), g(wy), g(wz), a(ax), a(ay), a(az)]
    }

    const G: i32 = GYRO_UDPS_PER_COUNT << FRAC_BITS;
    const A: i32 = ACCEL_UG_PER_COUNT_Q12;

    /// The nominal calibration of one group: x from gyro A, y from gyro B, z the mean of both z outputs.
    pub const NOMINAL: GroupCal = GroupCal {
        gyro_matrix_q12: [[G, 0, 0, 0], [0, 0, G, 0], [0, G / 2, 0, G / 2]],
        gyro_bias_q12: [GYRO_ZERO_Q12; 4],
        accel_matrix_q12: [[A, 0, 0], [0, A, 0], [0, 0, A]],
        accel_bias_q12: [ACCEL_ZERO_Q12; 3],
    };
}

#[cfg(test)]
mod tests;
