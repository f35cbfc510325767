//! The FPGA link frame: one simultaneous sample of the whole cluster (spec: `docs/fpga-link.md`).
//!
//! ```text
//! offset  size  field
//!      0     4  sync marker 1A CF FC 1D (CCSDS attached sync marker)
//!      4     2  sequence counter, u16, +1 per frame sent, wraps
//!      6     2  decimation N in force, u16: the FPGA keeps 1 ADC data set of every N + 1
//!      8     1  flags: bit 0 = temperature valid; bits 1..7 reserved, sent as 0, ignored on receipt
//!      9     1  reserved, sent as 0, ignored on receipt
//!     10   224  16 groups × 7 ADC codes, u16 each, group-major (order: RAW_* constants)
//!    234     2  board temperature, i16, 0.01 °C
//!    236     4  CRC-32C of bytes 0..236
//! ```
//! All multi-byte fields are little-endian.

use crate::crc::crc32c;

/// Sensor groups on the board.
pub const GROUPS: usize = 16;
/// ADC channels per group (2 dual-axis gyros + 1 three-axis accelerometer).
pub const RAW_PER_GROUP: usize = 7;
/// The sync marker that starts every frame.
pub const SYNC: [u8; 4] = [0x1A, 0xCF, 0xFC, 0x1D];
/// Frame length in bytes.
pub const FRAME_LEN: usize = field::CRC.end;

/// Index of gyro A's x output within a group's 7 ADC codes.
pub const RAW_GYRO_A_X: usize = 0;
/// Index of gyro A's z output (the first of the two z measurements).
pub const RAW_GYRO_A_Z: usize = 1;
/// Index of gyro B's y output.
pub const RAW_GYRO_B_Y: usize = 2;
/// Index of gyro B's z output (the redundant z measurement).
pub const RAW_GYRO_B_Z: usize = 3;
/// Index of the accelerometer's x output.
pub const RAW_ACCEL_X: usize = 4;
/// Index of the accelerometer's y output.
pub const RAW_ACCEL_Y: usize = 5;
/// Index of the accelerometer's z output.
pub const RAW_ACCEL_Z: usize = 6;

/// Flag bit: the temperature field holds a valid reading.
pub const FLAG_TEMP_VALID: u8 = 0x01;

mod field {
    use core::ops::Range;
    pub const SYNC: Range<usize> = 0..4;
    pub const SEQ: Range<usize> = 4..6;
    pub const DECIMATION: Range<usize> = 6..8;
    pub const FLAGS: usize = 8;
    pub const SAMPLES: Range<usize> = 10..234;
    pub const TEMP: Range<usize> = 234..236;
    pub const CRC: Range<usize> = 236..240;
}

/// Why bytes are not a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WireError {
    /// Fewer bytes than a frame.
    Truncated,
    /// The first four bytes are not the sync marker.
    BadSync,
    /// The CRC does not match the contents.
    BadCrc,
}

/// One group's 7 ADC codes, in `RAW_*` order.
pub type RawGroup = [u16; RAW_PER_GROUP];

/// ADC codes of the whole cluster for one frame.
pub type RawSample = [RawGroup; GROUPS];

/// A zero-copy view of a frame in a byte buffer.
#[derive(Debug, Clone, Copy)]
pub struct Frame<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> Frame<T> {
    /// Wraps a buffer of at least [`FRAME_LEN`] bytes, without checking sync or CRC.
    pub fn new_checked(buffer: T) -> Result<Self, WireError> {
        if buffer.as_ref().len() < FRAME_LEN {
            return Err(WireError::Truncated);
        }
        Ok(Self { buffer })
    }

    /// Consumes the view and returns the buffer.
    pub fn into_inner(self) -> T {
        self.buffer
    }

    fn bytes(&self) -> &[u8; FRAME_LEN] {
        // `new_checked` guaranteed the length; `first_chunk` cannot fail here but we avoid any panic path.
        match self.buffer.as_ref().first_chunk::<FRAME_LEN>() {
            Some(b) => b,
            None => &[0; FRAME_LEN],
        }
    }

    /// The little-endian `u16` at byte `at` (0 past the end: callers pass offsets inside the frame).
    fn u16_at(&self, at: usize) -> u16 {
        self.bytes()
            .get(at..)
            .and_then(<[u8]>::first_chunk)
            .map_or(0, |&pair| u16::from_le_bytes(pair))
    }

    /// The first four bytes equal [`SYNC`].
    pub fn sync_ok(&self) -> bool {
        self.bytes()[field::SYNC] == SYNC
    }

    /// Sequence counter.
    pub fn seq(&self) -> u16 {
        self.u16_at(field::SEQ.start)
    }

    /// Decimation N in force (1 ADC data set kept of every N + 1).
    pub fn decimation(&self) -> u16 {
        self.u16_at(field::DECIMATION.start)
    }

    /// Flag byte.
    pub fn flags(&self) -> u8 {
        self.bytes()[field::FLAGS]
    }

    /// ADC code of `group` (0..16), channel `ch` (0..7, `RAW_*`); `None` out of range.
    pub fn raw(&self, group: usize, ch: usize) -> Option<u16> {
        let (codes, _) = self.bytes().get(field::SAMPLES)?.as_chunks::<2>();
        let group_codes = codes.chunks_exact(RAW_PER_GROUP).nth(group)?;
        group_codes.get(ch).map(|&pair| u16::from_le_bytes(pair))
    }

    /// Board temperature in 0.01 °C as sent (meaningful only with [`FLAG_TEMP_VALID`]).
    pub fn temp_raw_cdeg(&self) -> i16 {
        self.u16_at(field::TEMP.start) as i16
    }

    /// Board temperature in 0.01 °C when the FPGA marked it valid.
    pub fn temp_cdeg(&self) -> Option<i16> {
        (self.flags() & FLAG_TEMP_VALID != 0).then(|| self.temp_raw_cdeg())
    }

    /// The ADC codes of every group in order, read from the bytes as they are needed (no copy of the frame).
    pub fn groups(&self) -> impl Iterator<Item = RawGroup> + '_ {
        let (groups, _) = self.bytes()[field::SAMPLES].as_chunks::<{ 2 * RAW_PER_GROUP }>();
        groups.iter().map(|bytes| {
            let (pairs, _) = bytes.as_chunks::<2>();
            let mut codes = [0u16; RAW_PER_GROUP];
            for (code, &pair) in codes.iter_mut().zip(pairs) {
                *code = u16::from_le_bytes(pair);
            }
            codes
        })
    }

    /// CRC field.
    pub fn crc(&self) -> u32 {
        let b = self.bytes();
        u32::from_le_bytes([b[236], b[237], b[238], b[239]])
    }

    /// The CRC field matches the CRC-32C of bytes 0..236.
    pub fn crc_ok(&self) -> bool {
        crc32c(&self.bytes()[..field::CRC.start]) == self.crc()
    }

    /// Sync and CRC both valid.
    pub fn check(&self) -> Result<(), WireError> {
        if !self.sync_ok() {
            return Err(WireError::BadSync);
        }
        if !self.crc_ok() {
            return Err(WireError::BadCrc);
        }
        Ok(())
    }
}

/// The meaning of a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameRepr {
    /// Sequence counter.
    pub seq: u16,
    /// Decimation N in force.
    pub decimation: u16,
    /// Board temperature in 0.01 °C, when the FPGA marked it valid.
    pub temp_cdeg: Option<i16>,
    /// ADC codes, `[group][RAW_*]`.
    pub raw: RawSample,
}

impl FrameRepr {
    /// Parses a checked view (sync and CRC verified here).
    pub fn parse<T: AsRef<[u8]>>(frame: &Frame<T>) -> Result<Self, WireError> {
        frame.check()?;
        let mut repr = Self::EMPTY;
        repr.fill_from(frame);
        Ok(repr)
    }

    /// A frame of zeros (sequence 0, decimation 0, no temperature).
    pub const EMPTY: Self = Self {
        seq: 0,
        decimation: 0,
        temp_cdeg: None,
        raw: [[0; RAW_PER_GROUP]; GROUPS],
    };

    /// Copies a view's fields into `self` without checking sync or CRC (the decoder checked them).
    pub(crate) fn fill_from<T: AsRef<[u8]>>(&mut self, frame: &Frame<T>) {
        for (codes, group) in self.raw.iter_mut().zip(frame.groups()) {
            *codes = group;
        }
        self.seq = frame.seq();
        self.decimation = frame.decimation();
        self.temp_cdeg = frame.temp_cdeg();
    }

    /// Parses bytes (at least [`FRAME_LEN`]; extra bytes are ignored).
    pub fn parse_bytes(bytes: &[u8]) -> Result<Self, WireError> {
        Self::parse(&Frame::new_checked(bytes)?)
    }

    /// Writes the frame, CRC included, into `out[..FRAME_LEN]`.
    pub fn emit(&self, out: &mut [u8]) -> Result<(), WireError> {
        let out = out
            .first_chunk_mut::<FRAME_LEN>()
            .ok_or(WireError::Truncated)?;
        out[field::SYNC].copy_from_slice(&SYNC);
        out[field::SEQ].copy_from_slice(&self.seq.to_le_bytes());
        out[field::DECIMATION].copy_from_slice(&self.decimation.to_le_bytes());
        out[field::FLAGS] = if self.temp_cdeg.is_some() {
            FLAG_TEMP_VALID
        } else {
            0
        };
        out[field::FLAGS + 1] = 0;
        for (pair, code) in out[field::SAMPLES]
            .chunks_exact_mut(2)
            .zip(self.raw.as_flattened())
        {
            pair.copy_from_slice(&code.to_le_bytes());
        }
        out[field::TEMP].copy_from_slice(&self.temp_cdeg.unwrap_or(0).to_le_bytes());
        let crc = crc32c(&out[..field::CRC.start]);
        out[field::CRC].copy_from_slice(&crc.to_le_bytes());
        Ok(())
    }

    /// The emitted frame as an array.
    pub fn to_bytes(&self) -> [u8; FRAME_LEN] {
        let mut out = [0u8; FRAME_LEN];
        // Cannot fail: the buffer is exactly FRAME_LEN.
        let _ = self.emit(&mut out);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample_repr(seq: u16) -> FrameRepr {
        let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
        for (g, group) in raw.iter_mut().enumerate() {
            for (c, code) in group.iter_mut().enumerate() {
                *code = (g * 1000 + c * 7 + usize::from(seq)) as u16;
            }
        }
        FrameRepr {
            seq,
            decimation: 15,
            temp_cdeg: Some(-1234),
            raw,
        }
    }

    #[test]
    fn layout_is_as_documented() {
        assert_eq!(FRAME_LEN, 240);
        let bytes = sample_repr(0x0102).to_bytes();
        assert_eq!(&bytes[0..4], &[0x1A, 0xCF, 0xFC, 0x1D]);
        assert_eq!(&bytes[4..6], &[0x02, 0x01]);
        assert_eq!(&bytes[6..8], &[15, 0]);
        assert_eq!(bytes[8], FLAG_TEMP_VALID);
        // group 1, channel RAW_ACCEL_X = 1000 + 28 + 0x102 = 1286 = 0x0506 at 10 + 2 * (7 + 4)
        assert_eq!(&bytes[32..34], &[0x06, 0x05]);
        assert_eq!(&bytes[234..236], &(-1234i16).to_le_bytes());
        assert_eq!(
            u32::from_le_bytes(bytes[236..240].try_into().unwrap()),
            crc32c(&bytes[..236])
        );
    }

    #[test]
    fn parse_emit_round_trip() {
        for seq in [0, 1, 0xFFFF] {
            let repr = sample_repr(seq);
            let bytes = repr.to_bytes();
            assert_eq!(FrameRepr::parse_bytes(&bytes), Ok(repr));
            let view = Frame::new_checked(&bytes[..]).unwrap();
            assert_eq!(view.raw(1, RAW_ACCEL_X), Some(1028u16.wrapping_add(seq)));
            assert_eq!(view.raw(16, 0), None);
        }
        let mut no_temp = sample_repr(5);
        no_temp.temp_cdeg = None;
        assert_eq!(FrameRepr::parse_bytes(&no_temp.to_bytes()), Ok(no_temp));
    }

    #[test]
    fn damaged_frames_are_rejected() {
        let bytes = sample_repr(9).to_bytes();
        assert_eq!(
            FrameRepr::parse_bytes(&bytes[..FRAME_LEN - 1]),
            Err(WireError::Truncated)
        );
        for i in 0..FRAME_LEN {
            let mut b = bytes;
            b[i] ^= 0x10;
            let want = if i < 4 {
                WireError::BadSync
            } else {
                WireError::BadCrc
            };
            assert_eq!(FrameRepr::parse_bytes(&b), Err(want), "byte {i}");
        }
    }
}
