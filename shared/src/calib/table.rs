//! The calibration table: what the ground uploads, the flash keeps and the pipeline applies.
//!
//! Encoded form (`encode`/`decode`): postcard of `(format_version: u16, groups: u8, table)` followed by the
//! CRC-32C of those bytes, 4 bytes little-endian. `decode` checks CRC, version, group count and bias range.

use super::{GroupCal, board};
use crate::crc::crc32c;
use serde::{Deserialize, Serialize};

/// Version of the encoded form; bumped on any change of layout or meaning.
pub const CAL_FORMAT_VERSION: u16 = 1;

const CRC_LEN: usize = 4;

/// Upper bound of the encoded length of a table of `groups` groups (postcard varints at their longest).
pub const fn encoded_len_max(groups: usize) -> usize {
    // version (3) + group count (2) + id (5) + rails (2 × 5) + 28 i32 per group (5 each) + CRC; saturating (no
    // buffer is `usize::MAX` bytes long)
    groups
        .saturating_mul(28 * 5)
        .saturating_add(3 + 2 + 5 + 10 + CRC_LEN)
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
}

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
        }
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

    /// Reads a table written by [`Self::encode`], checking CRC, version, group count and bias range.
    pub fn decode(bytes: &[u8]) -> Result<Self, CalError> {
        let body_len = bytes
            .len()
            .checked_sub(CRC_LEN)
            .ok_or(CalError::Truncated)?;
        let (body, crc) = bytes.split_at(body_len);
        let crc = u32::from_le_bytes(crc.try_into().map_err(|_| CalError::Truncated)?);
        if crc32c(body) != crc {
            return Err(CalError::Crc);
        }
        let (header, rest) =
            postcard::take_from_bytes::<Header>(body).map_err(|_| CalError::Malformed)?;
        if header.format_version != CAL_FORMAT_VERSION {
            return Err(CalError::Version(header.format_version));
        }
        if usize::from(header.groups) != G {
            return Err(CalError::GroupCount(header.groups));
        }
        let (table, rest) =
            postcard::take_from_bytes::<Self>(rest).map_err(|_| CalError::Malformed)?;
        if !rest.is_empty() {
            return Err(CalError::Malformed);
        }
        if !table.groups.iter().all(GroupCal::biases_in_range) {
            return Err(CalError::BiasOutOfRange);
        }
        Ok(table)
    }

    /// True when `raw` is at or beyond a rail.
    pub fn saturated(&self, raw: i32) -> bool {
        raw <= self.raw_min || raw >= self.raw_max
    }
}
