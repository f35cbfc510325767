//! MCU → FPGA control messages (spec: `docs/fpga-link.md`), on the link's second direction.
//!
//! ```text
//! offset  size  field
//!      0     4  sync marker 1A CF FC 1D
//!      4     1  opcode (1 = set decimation, 2 = streaming on/off)
//!      5     2  argument, u16 little-endian
//!      7     4  CRC-32C of bytes 0..7, little-endian
//! ```

use super::frame::{SYNC, WireError};
use crate::crc::crc32c;

/// Length of a control message.
pub const CONTROL_LEN: usize = 11;

const OP_SET_DECIMATION: u8 = 1;
const OP_SET_STREAMING: u8 = 2;

/// A control message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FpgaControl {
    /// Keep one ADC data set of every N + 1.
    SetDecimation(u16),
    /// Start (`true`) or stop (`false`) the frame stream (argument 1 / 0).
    SetStreaming(bool),
}

/// Why bytes are not a control message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ControlError {
    /// Framing error (length, sync, CRC).
    Wire(WireError),
    /// Unknown opcode.
    Opcode(u8),
}

impl FpgaControl {
    /// The message's bytes.
    pub fn to_bytes(&self) -> [u8; CONTROL_LEN] {
        let (op, arg) = match *self {
            Self::SetDecimation(n) => (OP_SET_DECIMATION, n),
            Self::SetStreaming(on) => (OP_SET_STREAMING, u16::from(on)),
        };
        let mut b = [0u8; CONTROL_LEN];
        let [a0, a1] = arg.to_le_bytes();
        let [s0, s1, s2, s3] = SYNC;
        let head = [s0, s1, s2, s3, op, a0, a1];
        let [c0, c1, c2, c3] = crc32c(&head).to_le_bytes();
        for (dst, src) in b.iter_mut().zip(head.into_iter().chain([c0, c1, c2, c3])) {
            *dst = src;
        }
        b
    }

    /// Parses a control message (what the FPGA, or a simulator of it, does).
    pub fn parse(bytes: &[u8]) -> Result<Self, ControlError> {
        let b = bytes
            .first_chunk::<CONTROL_LEN>()
            .ok_or(ControlError::Wire(WireError::Truncated))?;
        let (head, crc) = b.split_at(7);
        if head.get(..4) != Some(&SYNC[..]) {
            return Err(ControlError::Wire(WireError::BadSync));
        }
        if crc32c(head).to_le_bytes() != crc {
            return Err(ControlError::Wire(WireError::BadCrc));
        }
        match (b[4], u16::from_le_bytes([b[5], b[6]])) {
            (OP_SET_DECIMATION, n) => Ok(Self::SetDecimation(n)),
            (OP_SET_STREAMING, a @ (0 | 1)) => Ok(Self::SetStreaming(a == 1)),
            (op, _) => Err(ControlError::Opcode(op)),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_rejections() {
        let m = FpgaControl::SetDecimation(511);
        let b = m.to_bytes();
        assert_eq!(&b[..7], &[0x1A, 0xCF, 0xFC, 0x1D, 1, 0xFF, 0x01]);
        assert_eq!(FpgaControl::parse(&b), Ok(m));
        assert_eq!(
            FpgaControl::parse(&b[..10]),
            Err(ControlError::Wire(WireError::Truncated))
        );
        let mut bad = b;
        bad[6] ^= 1;
        assert_eq!(
            FpgaControl::parse(&bad),
            Err(ControlError::Wire(WireError::BadCrc))
        );
        let mut op = [0x1A, 0xCF, 0xFC, 0x1D, 9, 0, 0, 0, 0, 0, 0];
        let crc = crc32c(&op[..7]).to_le_bytes();
        op[7..].copy_from_slice(&crc);
        assert_eq!(FpgaControl::parse(&op), Err(ControlError::Opcode(9)));
        for on in [false, true] {
            let b = FpgaControl::SetStreaming(on).to_bytes();
            assert_eq!(&b[..7], &[0x1A, 0xCF, 0xFC, 0x1D, 2, u8::from(on), 0]);
            assert_eq!(FpgaControl::parse(&b), Ok(FpgaControl::SetStreaming(on)));
        }
        // Streaming takes 0 or 1 only.
        let mut op = [0x1A, 0xCF, 0xFC, 0x1D, 2, 2, 0, 0, 0, 0, 0];
        let crc = crc32c(&op[..7]).to_le_bytes();
        op[7..].copy_from_slice(&crc);
        assert_eq!(FpgaControl::parse(&op), Err(ControlError::Opcode(2)));
    }
}
