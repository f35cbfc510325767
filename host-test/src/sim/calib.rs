//! The true calibration of a group and its inverse application: sensor readings (physical units, per raw
//! channel) → ADC codes through `shared::calib::board::nominal_codes`.
//!
//! Model per group: the reading of raw channel `c` is `r_c = s_c · input + e_c` (`s_c` a row of the sensing
//! matrix: `(1 + scale error)` times the channel's unit direction tilted by two small misalignment angles; `e_c`
//! the channel's errors from the noise model), and its ADC code is the nominal chain applied to `r_c + b_c`
//! (`b_c` the zero offset a calibration removes), rounded and clamped to `u16`. The ideal calibration inverts this
//! exactly: `ω = S⁺ (r − …)`, with `S⁺ = (SᵀS)⁻¹Sᵀ` for the 4×3 gyro matrix (equal weight on the two z
//! channels) and `S⁻¹` for the accelerometer. [`TrueGroupCal::physical`] is that inverse without quantisation;
//! [`TrueGroupCal::to_group_cal`] is the same map in `shared`'s fixed-point form, i.e. what a perfect ground
//! calibration would upload.

use super::noise::normal;
use super::{SimError, check};
use rand_xoshiro::rand_core::Rng;
use shared::calib::{FRAC_BITS, GroupCal, board};

/// Nominal axis (0 = x, 1 = y, 2 = z) of each raw gyro channel (A x, A z, B y, B z).
const GYRO_AXIS: [usize; 4] = [0, 2, 1, 2];

/// Spread of the true calibration between groups (all standard deviations of normal draws; 0 = nominal).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CalSpread {
    /// Relative scale-factor error of each channel (e.g. 0.01 = 1 %).
    pub scale_sd: f64,
    /// Misalignment of each channel towards each of the two other axes, rad.
    pub misalign_sd_rad: f64,
    /// Zero-rate offset of each gyro channel, °/s.
    pub gyro_bias_sd_dps: f64,
    /// Zero-g offset of each accelerometer channel, g.
    pub accel_bias_sd_g: f64,
}

impl CalSpread {
    /// Ideal parts: every group nominal.
    pub const NONE: Self = Self {
        scale_sd: 0.0,
        misalign_sd_rad: 0.0,
        gyro_bias_sd_dps: 0.0,
        accel_bias_sd_g: 0.0,
    };

    /// Data-sheet-like spread: 1 % scale, 5 mrad misalignment, 1 °/s gyro and 30 mg accelerometer offsets.
    pub fn typical() -> Self {
        Self {
            scale_sd: 0.01,
            misalign_sd_rad: 0.005,
            gyro_bias_sd_dps: 1.0,
            accel_bias_sd_g: 0.03,
        }
    }

    /// Checks that every spread is finite, ≥ 0 and small enough for an invertible, in-range calibration.
    pub fn validate(&self) -> Result<(), SimError> {
        let f = [
            ("scale_sd", self.scale_sd, 0.1),
            ("misalign_sd_rad", self.misalign_sd_rad, 0.1),
            ("gyro_bias_sd_dps", self.gyro_bias_sd_dps, 20.0),
            ("accel_bias_sd_g", self.accel_bias_sd_g, 0.5),
        ];
        for (name, v, max) in f {
            check(v.is_finite() && (0.0..=max).contains(&v), || {
                format!("cal {name} = {v} must be in [0, {max}]")
            })?;
        }
        Ok(())
    }

    /// Draws one group's true calibration.
    pub(crate) fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> Result<TrueGroupCal, SimError> {
        let mut n = || normal(rng);
        let mut row = |axis: usize| {
            let k = 1.0 + self.scale_sd * n();
            let mut r = [0.0; 3];
            for (j, v) in r.iter_mut().enumerate() {
                *v = k * if j == axis {
                    1.0
                } else {
                    self.misalign_sd_rad * n()
                };
            }
            r
        };
        let gyro_sense = GYRO_AXIS.map(&mut row);
        let accel_sense = [0, 1, 2].map(&mut row);
        let gyro_bias = [(); 4].map(|_| self.gyro_bias_sd_dps * n());
        let accel_bias = [(); 3].map(|_| self.accel_bias_sd_g * n());
        TrueGroupCal::new(gyro_sense, gyro_bias, accel_sense, accel_bias)
    }
}

/// The true calibration of one group (what the ground calibration should recover).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrueGroupCal {
    gyro_sense: [[f64; 3]; 4],
    gyro_bias: [f64; 4],
    accel_sense: [[f64; 3]; 3],
    accel_bias: [f64; 3],
    gyro_pinv: [[f64; 4]; 3],
    accel_inv: [[f64; 3]; 3],
    /// Nominal chain per raw channel: code = off + slope · value; zero = code of a zero reading (off + slope·b).
    off: [f64; 7],
    slope: [f64; 7],
    zero: [f64; 7],
}

impl TrueGroupCal {
    /// A nominal group: unit sensing, no offsets.
    pub fn nominal() -> Self {
        let mut g = [[0.0; 3]; 4];
        for (row, &a) in g.iter_mut().zip(&GYRO_AXIS) {
            row[a] = 1.0;
        }
        let a = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        // Cannot fail: the nominal matrices are well conditioned.
        Self::new(g, [0.0; 4], a, [0.0; 3]).unwrap_or_else(|_| unreachable!())
    }

    /// A calibration from its parts. `gyro_sense`: rows = raw gyro channels (A x, A z, B y, B z), columns = body
    /// x, y, z, dimensionless (reading per unit rate); `gyro_bias`: zero-rate offsets, °/s per channel;
    /// `accel_sense`, `accel_bias` (g) likewise for the accelerometer. Fails on non-finite or ill-conditioned
    /// input.
    pub fn new(
        gyro_sense: [[f64; 3]; 4],
        gyro_bias: [f64; 4],
        accel_sense: [[f64; 3]; 3],
        accel_bias: [f64; 3],
    ) -> Result<Self, SimError> {
        let all = gyro_sense
            .iter()
            .flatten()
            .chain(&gyro_bias)
            .chain(accel_sense.iter().flatten())
            .chain(&accel_bias);
        check(all.copied().all(f64::is_finite), || {
            "calibration entries must be finite".into()
        })?;
        // S⁺ = (SᵀS)⁻¹ Sᵀ
        let mut sts = [[0.0; 3]; 3];
        for (i, row) in sts.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = gyro_sense.iter().map(|r| r[i] * r[j]).sum();
            }
        }
        let sts_inv = inv3(&sts).ok_or_else(|| SimError::Singular("gyro sensing matrix".into()))?;
        let mut gyro_pinv = [[0.0; 4]; 3];
        for (i, row) in gyro_pinv.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = (0..3).map(|k| sts_inv[i][k] * gyro_sense[c][k]).sum();
            }
        }
        let accel_inv = inv3(&accel_sense)
            .ok_or_else(|| SimError::Singular("accelerometer sensing matrix".into()))?;
        let off = board::nominal_codes([0.0; 3], [0.0; 3]);
        let one = board::nominal_codes([1.0; 3], [1.0; 3]);
        let slope: [f64; 7] = core::array::from_fn(|c| one[c] - off[c]);
        let bias = [
            gyro_bias[0],
            gyro_bias[1],
            gyro_bias[2],
            gyro_bias[3],
            accel_bias[0],
            accel_bias[1],
            accel_bias[2],
        ];
        let zero = core::array::from_fn(|c| off[c] + slope[c] * bias[c]);
        Ok(Self {
            gyro_sense,
            gyro_bias,
            accel_sense,
            accel_bias,
            gyro_pinv,
            accel_inv,
            off,
            slope,
            zero,
        })
    }

    /// Gyro sensing matrix (rows A x, A z, B y, B z; columns x, y, z).
    pub fn gyro_sense(&self) -> &[[f64; 3]; 4] {
        &self.gyro_sense
    }
    /// Gyro zero-rate offsets, °/s per raw channel.
    pub fn gyro_bias(&self) -> &[f64; 4] {
        &self.gyro_bias
    }
    /// Accelerometer sensing matrix (rows = channels x, y, z).
    pub fn accel_sense(&self) -> &[[f64; 3]; 3] {
        &self.accel_sense
    }
    /// Accelerometer zero-g offsets, g per channel.
    pub fn accel_bias(&self) -> &[f64; 3] {
        &self.accel_bias
    }

    /// ADC codes per unit reading of each raw channel (the nominal chain's slope, frame order).
    pub fn slope(&self) -> &[f64; 7] {
        &self.slope
    }

    /// Readings of the 7 raw channels (°/s, g) for a true rate (°/s) and specific force (g), without errors.
    pub fn readings(&self, rate_dps: [f64; 3], accel_g: [f64; 3]) -> [f64; 7] {
        let dot = |r: &[f64; 3], v: &[f64; 3]| r[0] * v[0] + r[1] * v[1] + r[2] * v[2];
        let mut out = [0.0; 7];
        for (o, r) in out.iter_mut().zip(&self.gyro_sense) {
            *o = dot(r, &rate_dps);
        }
        for (o, r) in out[4..].iter_mut().zip(&self.accel_sense) {
            *o = dot(r, &accel_g);
        }
        out
    }

    /// Unrounded ADC codes of raw-channel readings `r` (°/s, g, `RAW_*` order): nominal chain of `r + bias`.
    pub fn codes_f64(&self, r: &[f64; 7]) -> [f64; 7] {
        core::array::from_fn(|c| self.zero[c] + self.slope[c] * r[c])
    }

    /// ADC codes of readings `r`: [`Self::codes_f64`] clamped to `0..=65535` and rounded to nearest (halves up).
    pub fn codes(&self, r: &[f64; 7]) -> [u16; 7] {
        // `as` truncates: +0.5 then truncation rounds the non-negative clamped value (no libm call).
        self.codes_f64(r)
            .map(|x| (x.clamp(0.0, 65535.0) + 0.5) as u16)
    }

    /// The ideally calibrated output of readings `r`: `[gx, gy, gz]` = S⁺·gyro readings (°/s), `[ax, ay, az]` =
    /// S⁻¹·accelerometer readings (g).
    pub fn physical(&self, r: &[f64; 7]) -> [f64; 6] {
        let mut out = [0.0; 6];
        for (o, row) in out.iter_mut().zip(&self.gyro_pinv) {
            *o = row[0] * r[0] + row[1] * r[1] + row[2] * r[2] + row[3] * r[3];
        }
        for (o, row) in out[3..].iter_mut().zip(&self.accel_inv) {
            *o = row[0] * r[4] + row[1] * r[5] + row[2] * r[6];
        }
        out
    }

    /// The calibration in physical units per ADC count: `output = M · (code − zero)`.
    pub fn matrices(&self) -> CalMatrices {
        let z = self.zero;
        CalMatrices {
            gyro: self
                .gyro_pinv
                .map(|row| core::array::from_fn(|c| row[c] / self.slope[c])),
            gyro_zero: [z[0], z[1], z[2], z[3]],
            accel: self
                .accel_inv
                .map(|row| core::array::from_fn(|c| row[c] / self.slope[4 + c])),
            accel_zero: [z[4], z[5], z[6]],
        }
    }

    /// This calibration in `shared`'s fixed-point form (µ°/s and µg per count, Q19.12), as a perfect ground
    /// calibration would produce it.
    pub fn to_group_cal(&self) -> Result<GroupCal, SimError> {
        let m = self.matrices();
        let q = |x: f64| -> Result<i32, SimError> {
            let v = (x * f64::from(1u32 << FRAC_BITS)).round();
            check(v.abs() < 2f64.powi(31), || {
                format!("calibration entry {x} out of Q19.12 range")
            })?;
            Ok(v as i32)
        };
        let mut cal = GroupCal::default();
        for (dst, src) in cal.gyro_matrix_q12.iter_mut().zip(&m.gyro) {
            for (d, s) in dst.iter_mut().zip(src) {
                *d = q(s * 1e6)?;
            }
        }
        for (dst, src) in cal.accel_matrix_q12.iter_mut().zip(&m.accel) {
            for (d, s) in dst.iter_mut().zip(src) {
                *d = q(s * 1e6)?;
            }
        }
        for (d, s) in cal.gyro_bias_q12.iter_mut().zip(&m.gyro_zero) {
            *d = q(*s)?;
        }
        for (d, s) in cal.accel_bias_q12.iter_mut().zip(&m.accel_zero) {
            *d = q(*s)?;
        }
        check(cal.biases_in_range(), || {
            "calibration bias out of range".into()
        })?;
        Ok(cal)
    }
}

/// A group's calibration in physical units per ADC count (`output = M · (code − zero)`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalMatrices {
    /// Gyro matrix, °/s per count, rows x, y, z; columns raw gyro channels (A x, A z, B y, B z).
    pub gyro: [[f64; 4]; 3],
    /// Gyro zero-rate codes, counts.
    pub gyro_zero: [f64; 4],
    /// Accelerometer matrix, g per count.
    pub accel: [[f64; 3]; 3],
    /// Accelerometer zero-g codes, counts.
    pub accel_zero: [f64; 3],
}

/// Inverse of a 3×3 matrix; `None` if singular or badly conditioned (|det| < 1e-9 · product of row norms).
fn inv3(m: &[[f64; 3]; 3]) -> Option<[[f64; 3]; 3]> {
    let c = |i: usize, j: usize| {
        let (i1, i2, j1, j2) = ((i + 1) % 3, (i + 2) % 3, (j + 1) % 3, (j + 2) % 3);
        m[i1][j1] * m[i2][j2] - m[i1][j2] * m[i2][j1]
    };
    let det = m[0][0] * c(0, 0) + m[0][1] * c(0, 1) + m[0][2] * c(0, 2);
    let norms: f64 = m
        .iter()
        .map(|r| r.iter().map(|x| x * x).sum::<f64>().sqrt())
        .product();
    if det.is_nan() || det.abs() <= 1e-9 * norms {
        return None;
    }
    Some(core::array::from_fn(|i| {
        core::array::from_fn(|j| c(j, i) / det)
    }))
}
