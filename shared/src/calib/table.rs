//! The calibration table: what the ground uploads, the flash keeps and the pipeline applies.
//!
//! Encoded form (`encode`/`decode`): postcard of `(format_version: u16, groups: u8, table)` followed by the
//! CRC-32C of those bytes, 4 bytes little-endian. `decode` checks CRC, version, group count and bias range.
//! Version 2 added the thermal terms and the fixed fusion weights; a version-1 table (written before them) still
//! decodes, with neither.

use super::{ACCEL_RAW, AXES, GYRO_RAW, GroupCal, board};
use crate::crc::crc32c;
use serde::{Deserialize, Serialize};

/// Version of the encoded form; bumped on any change of layout or meaning.
pub const CAL_FORMAT_VERSION: u16 = 2;
/// The version before the thermal terms and weights (still decoded).
const CAL_FORMAT_V1: u16 = 1;

const CRC_LEN: usize = 4;

/// Upper bound of the encoded length of a table of `groups` groups (postcard varints at their longest).
pub const fn encoded_len_max(groups: usize) -> usize {
    // version (3) + group count (2) + id (5) + rails (2 × 5) + reference temperature (3) + per group 28 i32 of
    // the affine map, 14 of the thermal terms and 6 weights (5 bytes each) + CRC; saturating (no buffer is
    // `usize::MAX` bytes long)
    groups
        .saturating_mul((28 + 14 + AXES) * 5)
        .saturating_add(3 + 2 + 5 + 10 + 3 + CRC_LEN)
}

/// Why a calibration table could not be encoded or decoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalError {
    /// The output buffer is too small.
    BufferTooSmall,
    /// Fewer bytes than a header and a CRC.
    Truncated,
    /// The CRC does not match.
    Crc,
    /// Written by another format version.
    Version(u16),
    /// Made for an array with another number of groups.
    GroupCount(u8),
    /// CRC valid but the contents do not parse (or trailing bytes).
    Malformed,
    /// A bias outside ±65536 counts, where the fixed-point arithmetic is no longer exact.
    BiasOutOfRange,
    /// A fixed fusion weight outside ±2¹⁶ (Q16 ±1), or an axis whose fixed weights do not sum to a positive value.
    WeightOutOfRange,
}

/// Temperature dependence of one group's raw-channel biases: the bias in force at board temperature `T` is
/// `b + lin·ΔT + quad·ΔT²`, with `ΔT = T − t_ref` in centi-degrees (0.01 °C, the frame's unit). All zero: no
/// dependence. Q-formats chosen so that a typical MEMS coefficient keeps ≥ 20 significant bits (LPY410AL-class
/// gyro, 0.05 (°/s)/°C = 8 counts/°C ≈ 2.1·10⁷ LSB in Q28 per c°C; a quadratic 0.001 (°/s)/°C² ≈ 1.8·10⁵ LSB).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct GroupThermal {
    /// Linear coefficient of each raw gyro channel's bias, counts per 0.01 °C, Q4.28 (2⁻²⁸ counts per c°C).
    pub gyro_lin_q28: [i32; GYRO_RAW],
    /// Quadratic coefficient of each raw gyro channel's bias, counts per (0.01 °C)², Q40 (2⁻⁴⁰ counts per c°C²).
    pub gyro_quad_q40: [i32; GYRO_RAW],
    /// Linear coefficient of each raw accelerometer channel's bias, counts per 0.01 °C, Q28.
    pub accel_lin_q28: [i32; ACCEL_RAW],
    /// Quadratic coefficient of each raw accelerometer channel's bias, counts per (0.01 °C)², Q40.
    pub accel_quad_q40: [i32; ACCEL_RAW],
}

impl GroupThermal {
    /// No temperature dependence.
    pub const ZERO: Self = Self {
        gyro_lin_q28: [0; GYRO_RAW],
        gyro_quad_q40: [0; GYRO_RAW],
        accel_lin_q28: [0; ACCEL_RAW],
        accel_quad_q40: [0; ACCEL_RAW],
    };

    /// Whether any coefficient is non-zero.
    pub fn any(&self) -> bool {
        *self != Self::ZERO
    }
}

/// Calibration of an array of `G` groups (16 on our board; 8 for the MIMU4444 array).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CalibrationTable<const G: usize> {
    /// Identifier chosen by the ground (reported in health telemetry). 0 = factory default.
    pub cal_id: u32,
    /// Lowest raw reading that is not saturated (ADC rail; 0 for our unipolar ADCs).
    pub raw_min: i32,
    /// Highest raw reading that is not saturated (65535 for our ADCs).
    pub raw_max: i32,
    /// Per-group calibration.
    #[serde(with = "crate::serde_array")]
    pub groups: [GroupCal; G],
    /// Board temperature at which `groups`' biases hold, 0.01 °C (the reference of [`Self::thermal`]).
    pub t_ref_cdeg: i16,
    /// Per-group thermal terms of the biases (all zero: none; see [`GroupThermal`]).
    #[serde(with = "crate::serde_array")]
    pub thermal: [GroupThermal; G],
    /// Fixed fusion weights per group and axis, Q16 (65 536 = 1; signed, |w| ≤ 2¹⁶), used by
    /// `FusionMode::Fixed` instead of running inverse-variance weights; all zero: none.
    #[serde(with = "crate::serde_array")]
    pub weights_q16: [[i32; AXES]; G],
}

/// One piece of a table as [`walk`] reads it.
enum Piece {
    /// `cal_id`, `raw_min`, `raw_max`, `t_ref_cdeg`.
    Head(u32, i32, i32, i16),
    Group(usize, GroupCal),
    Thermal(usize, GroupThermal),
    Weights(usize, [i32; AXES]),
}

/// One postcard value from the front of `rest`.
fn take<'a, T: Deserialize<'a>>(rest: &mut &'a [u8]) -> Result<T, CalError> {
    let (value, tail) = postcard::take_from_bytes::<T>(rest).map_err(|_| CalError::Malformed)?;
    *rest = tail;
    Ok(value)
}

/// Reads an encoded table piece by piece, handing each piece to `f` in order, and checks it as `decode` documents
/// (CRC, version, group count, no trailing bytes, biases, weights). The pieces are postcard's encoding of the
/// table's fields in order (a struct is its fields back to back, a `serde_array` its elements): the same bytes
/// `encode` writes. A version-1 table hands the pieces it lacks as zeros (no thermal terms, no weights). Where it
/// fails, `f` has seen a prefix of the pieces: [`CalibrationTable::decode_into`] checks first.
fn walk<const G: usize>(bytes: &[u8], mut f: impl FnMut(Piece)) -> Result<(), CalError> {
    let body_len = bytes
        .len()
        .checked_sub(CRC_LEN)
        .ok_or(CalError::Truncated)?;
    let (body, crc) = bytes.split_at(body_len);
    let crc = u32::from_le_bytes(crc.try_into().map_err(|_| CalError::Truncated)?);
    if crc32c(body) != crc {
        return Err(CalError::Crc);
    }
    let mut rest = body;
    let header: Header = take(&mut rest)?;
    let v1 = match header.format_version {
        CAL_FORMAT_V1 => true,
        CAL_FORMAT_VERSION => false,
        v => return Err(CalError::Version(v)),
    };
    if usize::from(header.groups) != G {
        return Err(CalError::GroupCount(header.groups));
    }
    let (cal_id, raw_min, raw_max) = (take(&mut rest)?, take(&mut rest)?, take(&mut rest)?);
    let mut groups_ok = true;
    for g in 0..G {
        let cal: GroupCal = take(&mut rest)?;
        groups_ok &= cal.biases_in_range();
        f(Piece::Group(g, cal));
    }
    let t_ref_cdeg = if v1 { 0 } else { take(&mut rest)? };
    f(Piece::Head(cal_id, raw_min, raw_max, t_ref_cdeg));
    for g in 0..G {
        f(Piece::Thermal(
            g,
            if v1 {
                GroupThermal::ZERO
            } else {
                take(&mut rest)?
            },
        ));
    }
    // Weights: each within ±1 and, if any is not zero, a positive sum per axis (G ≤ 255 terms of ≤ 2¹⁶: no wrap).
    let (mut in_range, mut any, mut sums) = (true, false, [0i64; AXES]);
    for g in 0..G {
        let w: [i32; AXES] = if v1 { [0; AXES] } else { take(&mut rest)? };
        for (sum, &x) in sums.iter_mut().zip(&w) {
            in_range &= x.unsigned_abs() <= WEIGHT_LIMIT_Q16 as u32;
            any |= x != 0;
            *sum = sum.wrapping_add(i64::from(x));
        }
        f(Piece::Weights(g, w));
    }
    if !rest.is_empty() {
        return Err(CalError::Malformed);
    }
    if !groups_ok {
        return Err(CalError::BiasOutOfRange);
    }
    if !in_range || (any && sums.iter().any(|&s| s <= 0)) {
        return Err(CalError::WeightOutOfRange);
    }
    Ok(())
}

/// Largest magnitude of a fixed weight, Q16 (= 1).
pub const WEIGHT_LIMIT_Q16: i32 = 1 << 16;

#[derive(Serialize, Deserialize)]
struct Header {
    format_version: u16,
    groups: u8,
}

impl<const G: usize> CalibrationTable<G> {
    /// The factory default of our board: nominal sensitivities and zero levels ([`board::NOMINAL`]), id 0.
    pub const fn factory() -> Self {
        Self {
            cal_id: 0,
            raw_min: 0,
            raw_max: u16::MAX as i32,
            groups: [board::NOMINAL; G],
            t_ref_cdeg: 0,
            thermal: [GroupThermal::ZERO; G],
            weights_q16: [[0; AXES]; G],
        }
    }

    /// Makes this the factory default, in place (no table-sized temporary).
    pub fn set_factory(&mut self) {
        (self.cal_id, self.raw_min, self.raw_max, self.t_ref_cdeg) = (0, 0, u16::MAX as i32, 0);
        self.groups.fill(board::NOMINAL);
        self.thermal.fill(GroupThermal::ZERO);
        self.weights_q16.fill([0; AXES]);
    }

    /// Whether any group has thermal terms.
    pub fn has_thermal(&self) -> bool {
        self.thermal.iter().any(GroupThermal::any)
    }

    /// Whether the table carries fixed fusion weights (any non-zero).
    pub fn has_weights(&self) -> bool {
        self.weights_q16.iter().flatten().any(|&w| w != 0)
    }

    /// Writes the encoded table (with CRC) into `buf`; returns the used part.
    pub fn encode<'a>(&self, buf: &'a mut [u8]) -> Result<&'a [u8], CalError> {
        let header = Header {
            format_version: CAL_FORMAT_VERSION,
            groups: G as u8,
        };
        let head_len = postcard::to_slice(&header, &mut *buf)
            .map_err(|_| CalError::BufferTooSmall)?
            .len();
        let tail = buf.get_mut(head_len..).ok_or(CalError::BufferTooSmall)?;
        let body_len = postcard::to_slice(self, tail)
            .map_err(|_| CalError::BufferTooSmall)?
            .len()
            .checked_add(head_len)
            .ok_or(CalError::BufferTooSmall)?;
        let crc = crc32c(buf.get(..body_len).ok_or(CalError::BufferTooSmall)?);
        let len = body_len
            .checked_add(CRC_LEN)
            .ok_or(CalError::BufferTooSmall)?;
        buf.get_mut(body_len..len)
            .ok_or(CalError::BufferTooSmall)?
            .copy_from_slice(&crc.to_le_bytes());
        buf.get(..len).ok_or(CalError::BufferTooSmall)
    }

    /// Reads a table written by [`Self::encode`], checking CRC, version, group count, bias and weight ranges.
    /// Returns the table by value: for the host. The MCU decodes in place ([`Self::decode_into`]).
    pub fn decode(bytes: &[u8]) -> Result<Self, CalError> {
        let mut table = Self::factory();
        table.decode_into(bytes)?;
        Ok(table)
    }

    /// Checks `bytes` as [`Self::decode`] does, keeping nothing.
    pub fn check(bytes: &[u8]) -> Result<(), CalError> {
        walk::<G>(bytes, |_| {})
    }

    /// Decodes `bytes` into `self`, in place; on error `self` is unchanged (the bytes are checked in full first).
    ///
    /// Piece by piece (a group's affine map, thermal terms or weights at a time), never a whole table as a
    /// temporary: a by-value decode of the 3.1 KB table held it two or three times in one stack frame (measured in
    /// the firmware's ELF: 9.3 KB in `decode`, 6.3 KB in postcard's `take_from_bytes`, over the 8 KiB limit per
    /// frame, `docs/firmware.md`).
    pub fn decode_into(&mut self, bytes: &[u8]) -> Result<(), CalError> {
        Self::check(bytes)?;
        walk::<G>(bytes, |piece| self.set(piece))
    }

    /// Whether `bytes` decode to exactly this table (compared piece by piece, as [`Self::decode_into`] reads).
    pub fn encodes_as(&self, bytes: &[u8]) -> bool {
        let mut equal = true;
        walk::<G>(bytes, |piece| equal &= self.has(&piece)).is_ok() && equal
    }

    /// The table's scalar fields, as [`Piece::Head`] carries them.
    fn head(&self) -> (u32, i32, i32, i16) {
        (self.cal_id, self.raw_min, self.raw_max, self.t_ref_cdeg)
    }

    fn set(&mut self, piece: Piece) {
        match piece {
            Piece::Head(id, min, max, t_ref) => {
                (self.cal_id, self.raw_min, self.raw_max, self.t_ref_cdeg) = (id, min, max, t_ref)
            }
            Piece::Group(g, cal) => {
                if let Some(slot) = self.groups.get_mut(g) {
                    *slot = cal;
                }
            }
            Piece::Thermal(g, th) => {
                if let Some(slot) = self.thermal.get_mut(g) {
                    *slot = th;
                }
            }
            Piece::Weights(g, w) => {
                if let Some(slot) = self.weights_q16.get_mut(g) {
                    *slot = w;
                }
            }
        }
    }

    fn has(&self, piece: &Piece) -> bool {
        match *piece {
            Piece::Head(id, min, max, t_ref) => self.head() == (id, min, max, t_ref),
            Piece::Group(g, ref cal) => self.groups.get(g) == Some(cal),
            Piece::Thermal(g, ref th) => self.thermal.get(g) == Some(th),
            Piece::Weights(g, ref w) => self.weights_q16.get(g) == Some(w),
        }
    }

    /// True when `raw` is at or beyond a rail.
    pub fn saturated(&self, raw: i32) -> bool {
        raw <= self.raw_min || raw >= self.raw_max
    }
}
