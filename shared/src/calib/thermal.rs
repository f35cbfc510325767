//! Thermal compensation: the raw-channel biases in force at the board temperature of each frame
//! (`CalibrationTable::thermal`, spec: `docs/calibration.md`).
//!
//! The biases depend on temperature only, so they are recomputed when the frame's temperature differs from the one
//! they were computed for, not every frame: the board's sensor reads in 0.01 °C and an orbit's ±8 °C cycle changes
//! that reading about once a second, so the recomputation (about 5 k Cortex-M4 instructions for 16 groups:
//! `mcu-bench`'s thermal rows, `docs/performance.md`) is paid on about one frame in 600.
//!
//! A frame without a valid temperature is calibrated at the last valid one (counted in `held`); before the first
//! valid temperature since the pipeline started, no stale value exists and the table's reference biases apply
//! (counted in `missing` too).

use super::{ACCEL_RAW, BIAS_LIMIT_Q12, CalibrationTable, GYRO_RAW, GroupCal, GroupThermal};

/// Largest |T − T_ref| applied, 0.01 °C (±200 °C, beyond any board's range): bounds the arithmetic below.
pub const DT_LIMIT_CDEG: i32 = 20_000;

/// One group's raw-channel biases in force, Q19.12 counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GroupBias {
    /// Gyro channels.
    pub gyro: [i32; GYRO_RAW],
    /// Accelerometer channels.
    pub accel: [i32; ACCEL_RAW],
}

impl GroupBias {
    /// All zero (usable in `const`).
    pub const ZERO: Self = Self {
        gyro: [0; GYRO_RAW],
        accel: [0; ACCEL_RAW],
    };

    /// The biases of `cal` at `dt_cdeg` from the reference temperature under `thermal`.
    pub fn at(cal: &GroupCal, thermal: &GroupThermal, dt_cdeg: i32) -> Self {
        let mut out = Self::ZERO;
        shift_all(
            &mut out.gyro,
            &cal.gyro_bias_q12,
            &thermal.gyro_lin_q28,
            &thermal.gyro_quad_q40,
            dt_cdeg,
        );
        shift_all(
            &mut out.accel,
            &cal.accel_bias_q12,
            &thermal.accel_lin_q28,
            &thermal.accel_quad_q40,
            dt_cdeg,
        );
        out
    }
}

fn shift_all<const N: usize>(
    out: &mut [i32; N],
    b: &[i32; N],
    lin: &[i32; N],
    quad: &[i32; N],
    dt: i32,
) {
    for (((o, &b), &lin), &quad) in out.iter_mut().zip(b).zip(lin).zip(quad) {
        *o = shifted(b, lin, quad, dt);
    }
}

/// `b + lin·ΔT + quad·ΔT²` in Q12 counts (`lin` Q28 and `quad` Q40 per c°C, see [`GroupThermal`]), rounded half
/// away from zero and kept within ±[`BIAS_LIMIT_Q12`], where the calibration stays exact.
///
/// Horner form `((lin·2¹² + quad·ΔT)·ΔT) / 2²⁸`: with |ΔT| ≤ 2·10⁴ < 2¹⁵, |quad·ΔT| < 2⁴⁶ and |lin·2¹²| < 2⁴³, so the
/// bracket is < 2⁴⁷ and the product < 2⁶²: no i64 wraps.
pub fn shifted(b: i32, lin: i32, quad: i32, dt_cdeg: i32) -> i32 {
    let dt = i64::from(dt_cdeg.clamp(-DT_LIMIT_CDEG, DT_LIMIT_CDEG));
    let inner = (i64::from(lin) << 12).wrapping_add(i64::from(quad).wrapping_mul(dt));
    let acc = inner.wrapping_mul(dt);
    // Round half away from zero by 2⁻²⁸ (as `round_q24_sat`): |acc| < 2⁶², no wrap.
    let q = acc.wrapping_add(1 << 27).wrapping_add(acc >> 63) >> 28;
    // |q| < 2³⁴ and |b| ≤ 2³¹: the sum fits i64; clamped to the exact domain.
    const LIMIT: i64 = BIAS_LIMIT_Q12 as i64;
    i64::from(b).wrapping_add(q).clamp(-LIMIT, LIMIT) as i32
}

/// Frames by temperature validity (reported in health).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TempCounts {
    /// Frames without a valid board temperature.
    pub missing: u32,
    /// Of those, frames calibrated at the last valid temperature (thermal terms in force).
    pub held: u32,
}

/// The calibration in force for a table with thermal terms, kept in step with the frames' temperature: each
/// group's affine map with the biases of the temperature (a whole `GroupCal` per group, so that the frame's
/// calibration is the same code with or without thermal terms, and no separate bias step on the frame path).
#[derive(Clone, Copy, Debug)]
pub struct ThermalComp<const G: usize> {
    groups: [GroupCal; G],
    /// The table has thermal terms (else the biases are the table's and never change).
    active: bool,
    /// Temperature the biases were computed at (`None`: the reference biases, as loaded).
    applied_cdeg: Option<i16>,
    /// Last valid temperature since the pipeline started.
    last_valid_cdeg: Option<i16>,
    counts: TempCounts,
}

impl<const G: usize> ThermalComp<G> {
    /// The factory table in force (usable in `const`).
    pub const fn new() -> Self {
        Self {
            groups: [super::board::NOMINAL; G],
            active: false,
            applied_cdeg: None,
            last_valid_cdeg: None,
            counts: TempCounts {
                missing: 0,
                held: 0,
            },
        }
    }

    /// A new table is in force: its reference biases now; its thermal terms from the next frame on. The last valid
    /// temperature is kept (it is not stale: the board did not restart).
    pub fn load(&mut self, table: &CalibrationTable<G>) {
        self.groups.clone_from(&table.groups);
        self.active = table.has_thermal();
        self.applied_cdeg = None;
    }

    /// One frame's temperature (`None`: not valid): brings the biases in step with it.
    #[inline]
    pub fn update(&mut self, table: &CalibrationTable<G>, temp_cdeg: Option<i16>) {
        let t = match temp_cdeg {
            Some(t) => {
                self.last_valid_cdeg = Some(t);
                t
            }
            None => {
                self.counts.missing = self.counts.missing.wrapping_add(1);
                match self.last_valid_cdeg {
                    Some(t) if self.active => {
                        self.counts.held = self.counts.held.wrapping_add(1);
                        t
                    }
                    _ => return,
                }
            }
        };
        if self.active && self.applied_cdeg != Some(t) {
            self.recompute(table, t);
        }
    }

    #[inline(never)]
    fn recompute(&mut self, table: &CalibrationTable<G>, t_cdeg: i16) {
        let dt = i32::from(t_cdeg).wrapping_sub(i32::from(table.t_ref_cdeg));
        for ((out, cal), th) in self
            .groups
            .iter_mut()
            .zip(&table.groups)
            .zip(&table.thermal)
        {
            let b = GroupBias::at(cal, th, dt);
            (out.gyro_bias_q12, out.accel_bias_q12) = (b.gyro, b.accel);
        }
        self.applied_cdeg = Some(t_cdeg);
    }

    /// The calibration in force, one per group: the table's, with the biases of [`Self::applied_cdeg`].
    pub fn groups(&self) -> &[GroupCal; G] {
        &self.groups
    }

    /// Whether [`Self::groups`] is what `table` gives at [`Self::applied_cdeg`] (the RAM check: the copy is not
    /// covered by the table's CRC).
    pub fn consistent_with(&self, table: &CalibrationTable<G>) -> bool {
        let dt = self
            .applied_cdeg
            .map(|t| i32::from(t).wrapping_sub(i32::from(table.t_ref_cdeg)));
        self.groups
            .iter()
            .zip(&table.groups)
            .zip(&table.thermal)
            .all(|((mine, cal), th)| {
                let b = dt.map_or(
                    GroupBias {
                        gyro: cal.gyro_bias_q12,
                        accel: cal.accel_bias_q12,
                    },
                    |dt| GroupBias::at(cal, th, dt),
                );
                mine.gyro_matrix_q12 == cal.gyro_matrix_q12
                    && mine.accel_matrix_q12 == cal.accel_matrix_q12
                    && (mine.gyro_bias_q12, mine.accel_bias_q12) == (b.gyro, b.accel)
            })
    }

    /// The temperature the biases were computed at (`None`: the table's reference biases).
    pub fn applied_cdeg(&self) -> Option<i16> {
        self.applied_cdeg
    }

    /// Frames by temperature validity.
    pub fn counts(&self) -> TempCounts {
        self.counts
    }
}

impl<const G: usize> Default for ThermalComp<G> {
    fn default() -> Self {
        Self::new()
    }
}
