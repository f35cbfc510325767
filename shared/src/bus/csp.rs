//! CSP (CubeSat Space Protocol) version 1 packets as libcsp 1.x sends them on a KISS link (spec: `docs/bus.md`).
//!
//! ```text
//! header, 32 bits, big-endian:  prio:2 | src:5 | dst:5 | dport:6 | sport:6 | flags:8
//! packet in a KISS frame:        header (4) | payload | CRC-32C(payload), big-endian (4)
//! ```
//! The trailing CRC is libcsp's KISS link CRC (present on every frame since libcsp 1.2, whatever the flags) and
//! covers the payload only. With the header's CRC flag, the payload additionally ends in an end-to-end CRC-32C of
//! the data before it, which [`CspPacket::parse`] also checks and strips. HMAC, XTEA and RDP are not supported.

use crate::crc::crc32c;

/// Length of the header.
pub const HEADER_LEN: usize = 4;
/// Length of a CRC.
pub const CRC_LEN: usize = 4;
/// Flag: payload ends in a CRC-32C.
pub const FLAG_CRC32: u8 = 0x01;
/// Flag: reliable datagram protocol.
pub const FLAG_RDP: u8 = 0x02;
/// Flag: XTEA encryption.
pub const FLAG_XTEA: u8 = 0x04;
/// Flag: HMAC authentication.
pub const FLAG_HMAC: u8 = 0x08;
/// Standard port of the ping service (echo).
pub const PORT_PING: u8 = 1;

/// A CSP v1 header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CspHeader {
    /// Priority 0 (critical) … 3 (low).
    pub prio: u8,
    /// Source address, 0..=31.
    pub src: u8,
    /// Destination address, 0..=31 (31 = broadcast).
    pub dst: u8,
    /// Destination port, 0..=63.
    pub dport: u8,
    /// Source port, 0..=63.
    pub sport: u8,
    /// Flags (`FLAG_*`).
    pub flags: u8,
}

/// Why bytes are not a CSP packet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CspError {
    /// Shorter than a header and a link CRC.
    TooShort,
    /// The link CRC does not match.
    Crc,
    /// The CRC flag is set but the end-to-end CRC does not match (or is missing).
    InnerCrc,
    /// HMAC, XTEA or RDP requested.
    Unsupported(u8),
    /// A header field out of range, or the output buffer is too small.
    Invalid,
}

impl CspHeader {
    /// Parses the first 4 bytes.
    pub fn parse(bytes: &[u8]) -> Result<Self, CspError> {
        let id = u32::from_be_bytes(
            *bytes
                .first_chunk::<HEADER_LEN>()
                .ok_or(CspError::TooShort)?,
        );
        Ok(Self {
            prio: (id >> 30) as u8,
            src: ((id >> 25) & 0x1F) as u8,
            dst: ((id >> 20) & 0x1F) as u8,
            dport: ((id >> 14) & 0x3F) as u8,
            sport: ((id >> 8) & 0x3F) as u8,
            flags: id as u8,
        })
    }

    /// The 4 header bytes; fails if a field is out of range.
    pub fn emit(&self) -> Result<[u8; HEADER_LEN], CspError> {
        if self.prio > 3 || self.src > 31 || self.dst > 31 || self.dport > 63 || self.sport > 63 {
            return Err(CspError::Invalid);
        }
        let id = (u32::from(self.prio) << 30)
            | (u32::from(self.src) << 25)
            | (u32::from(self.dst) << 20)
            | (u32::from(self.dport) << 14)
            | (u32::from(self.sport) << 8)
            | u32::from(self.flags);
        Ok(id.to_be_bytes())
    }

    /// The header of the reply to this packet: addresses and ports swapped, priority and flags kept
    /// (what libcsp's service handler does for ping).
    pub fn reply(&self) -> Self {
        Self {
            src: self.dst,
            dst: self.src,
            dport: self.sport,
            sport: self.dport,
            ..*self
        }
    }
}

/// A parsed packet: header and payload (CRCs checked and removed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CspPacket<'a> {
    /// Header.
    pub header: CspHeader,
    /// Payload.
    pub payload: &'a [u8],
}

impl<'a> CspPacket<'a> {
    /// Parses the bytes of one KISS frame.
    pub fn parse(frame: &'a [u8]) -> Result<Self, CspError> {
        if frame.len() < HEADER_LEN + CRC_LEN {
            return Err(CspError::TooShort);
        }
        let header = CspHeader::parse(frame)?;
        let (body, crc) = frame
            .split_last_chunk::<CRC_LEN>()
            .ok_or(CspError::TooShort)?;
        let payload = body.get(HEADER_LEN..).unwrap_or(&[]);
        if crc32c(payload).to_be_bytes() != *crc {
            return Err(CspError::Crc);
        }
        let unsupported = header.flags & (FLAG_HMAC | FLAG_XTEA | FLAG_RDP);
        if unsupported != 0 {
            return Err(CspError::Unsupported(unsupported));
        }
        let payload = if header.flags & FLAG_CRC32 != 0 {
            let (data, inner) = payload
                .split_last_chunk::<CRC_LEN>()
                .ok_or(CspError::InnerCrc)?;
            if crc32c(data).to_be_bytes() != *inner {
                return Err(CspError::InnerCrc);
            }
            data
        } else {
            payload
        };
        Ok(Self { header, payload })
    }

    /// Writes the packet (header, payload with the end-to-end CRC if the flag asks for it, link CRC) as one KISS
    /// frame into `out`; returns its length.
    pub fn emit_kiss(
        header: &CspHeader,
        payload: &[u8],
        out: &mut [u8],
    ) -> Result<usize, CspError> {
        let head = header.emit()?;
        let inner = crc32c(payload).to_be_bytes();
        let inner: &[u8] = if header.flags & FLAG_CRC32 != 0 {
            &inner
        } else {
            &[]
        };
        let mut link = crate::crc::Crc32c::new();
        link.update(payload);
        link.update(inner);
        let link = link.finish().to_be_bytes();
        super::kiss::encode(&[&head, payload, inner, &link], out).map_err(|_| CspError::Invalid)
    }
}
