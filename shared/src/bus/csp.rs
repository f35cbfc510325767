//! CSP (CubeSat Space Protocol) packets on a KISS link as libcsp sends them, header version 1 (libcsp 1.x, Yamcs'
//! CSP preprocessor) or 2 (libcsp 2.x's default), chosen per node ([`CspVersion`]; spec: `docs/bus.md`).
//!
//! ```text
//! v1 header, 32 bits, big-endian:  prio:2 | src:5 | dst:5 | dport:6 | sport:6 | flags:8
//! v2 header, 48 bits, big-endian:  prio:2 | dst:14 | src:14 | dport:6 | sport:6 | flags:6
//! packet in a KISS frame:           header (4 or 6) | payload | CRC-32C, big-endian (4)
//! ```
//! The trailing CRC is libcsp's KISS link CRC (present on every frame since libcsp 1.2, whatever the flags). We
//! send it over the payload only, as every libcsp 1.2+ does, and accept it over the payload or over header and
//! payload (what libcsp's `csp_crc32_verify` accepts, and what a libcsp 2.1 build sends). With the header's CRC
//! flag, the payload additionally ends in an end-to-end CRC-32C of the data before it (same two forms), which
//! [`CspPacket::parse`] also checks and strips. HMAC, XTEA, RDP and (v2) fragmentation are not supported.

use crate::crc::{Crc32c, crc32c};

/// Length of a v1 header.
pub const HEADER_LEN_V1: usize = 4;
/// Length of a v2 header.
pub const HEADER_LEN_V2: usize = 6;
/// Length of the longest header (v2).
pub const HEADER_LEN_MAX: usize = HEADER_LEN_V2;
/// Length of a CRC.
pub const CRC_LEN: usize = 4;
/// Flag: payload ends in a CRC-32C.
pub const FLAG_CRC32: u8 = 0x01;
/// Flag: reliable datagram protocol.
pub const FLAG_RDP: u8 = 0x02;
/// Flag: XTEA encryption (v1; reserved in v2).
pub const FLAG_XTEA: u8 = 0x04;
/// Flag: HMAC authentication.
pub const FLAG_HMAC: u8 = 0x08;
/// Flag: fragmentation (v2; reserved in v1).
pub const FLAG_FRAG: u8 = 0x10;
/// Standard port of the ping service (echo).
pub const PORT_PING: u8 = 1;

/// The CSP header version of a link: both ends must agree (libcsp: `csp_conf.version`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CspVersion {
    /// 32-bit header, 5-bit addresses (libcsp 1.x; libcsp 2.x with `version = 1`).
    #[default]
    V1,
    /// 48-bit header, 14-bit addresses (libcsp 2.x's default).
    V2,
}

/// `"1"` or `"2"`, as command lines and configuration files name the versions.
impl core::str::FromStr for CspVersion {
    type Err = &'static str;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim() {
            "1" => Ok(Self::V1),
            "2" => Ok(Self::V2),
            _ => Err("the CSP header version is 1 or 2"),
        }
    }
}

impl CspVersion {
    /// The version's number: 1 or 2.
    pub const fn number(self) -> u8 {
        match self {
            Self::V1 => 1,
            Self::V2 => 2,
        }
    }

    /// Header length, bytes.
    pub const fn header_len(self) -> usize {
        match self {
            Self::V1 => HEADER_LEN_V1,
            Self::V2 => HEADER_LEN_V2,
        }
    }

    /// Largest address (v1: 31, v2: 16383).
    pub const fn max_addr(self) -> u16 {
        match self {
            Self::V1 => 0x1F,
            Self::V2 => 0x3FFF,
        }
    }

    /// The flags that field can carry (v1: 8 bits, v2: 6 bits).
    const fn flags_mask(self) -> u8 {
        match self {
            Self::V1 => 0xFF,
            Self::V2 => 0x3F,
        }
    }

    /// Flags we refuse: HMAC, XTEA (v1), RDP, fragmentation (v2).
    const fn unsupported(self) -> u8 {
        match self {
            Self::V1 => FLAG_HMAC | FLAG_XTEA | FLAG_RDP,
            Self::V2 => FLAG_HMAC | FLAG_RDP | FLAG_FRAG,
        }
    }
}

/// A CSP header (either version; the version is the link's, see [`CspVersion`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CspHeader {
    /// Priority 0 (critical) … 3 (low).
    pub prio: u8,
    /// Source address (v1 0..=31, v2 0..=16383).
    pub src: u16,
    /// Destination address (v1 0..=31, 31 = broadcast; v2 0..=16383).
    pub dst: u16,
    /// Destination port, 0..=63.
    pub dport: u8,
    /// Source port, 0..=63.
    pub sport: u8,
    /// Flags (`FLAG_*`; v2 carries 6 bits).
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
    /// HMAC, XTEA, RDP or fragmentation requested.
    Unsupported(u8),
    /// A header field out of range, or the output buffer is too small.
    Invalid,
}

/// The bytes of an emitted header.
pub type HeaderBytes = heapless::Vec<u8, HEADER_LEN_MAX>;

impl CspHeader {
    /// Parses the first [`CspVersion::header_len`] bytes.
    pub fn parse(bytes: &[u8], version: CspVersion) -> Result<Self, CspError> {
        match version {
            CspVersion::V1 => {
                let id = u32::from_be_bytes(*bytes.first_chunk::<4>().ok_or(CspError::TooShort)?);
                Ok(Self {
                    prio: (id >> 30) as u8,
                    src: ((id >> 25) & 0x1F) as u16,
                    dst: ((id >> 20) & 0x1F) as u16,
                    dport: ((id >> 14) & 0x3F) as u8,
                    sport: ((id >> 8) & 0x3F) as u8,
                    flags: id as u8,
                })
            }
            CspVersion::V2 => {
                let b = bytes.first_chunk::<6>().ok_or(CspError::TooShort)?;
                let [b0, b1, b2, b3, b4, b5] = *b;
                let id = u64::from_be_bytes([0, 0, b0, b1, b2, b3, b4, b5]);
                Ok(Self {
                    prio: ((id >> 46) & 0x3) as u8,
                    dst: ((id >> 32) & 0x3FFF) as u16,
                    src: ((id >> 18) & 0x3FFF) as u16,
                    dport: ((id >> 12) & 0x3F) as u8,
                    sport: ((id >> 6) & 0x3F) as u8,
                    flags: (id & 0x3F) as u8,
                })
            }
        }
    }

    /// The header's bytes in `version`; fails if a field is out of that version's range.
    pub fn emit(&self, version: CspVersion) -> Result<HeaderBytes, CspError> {
        let max = version.max_addr();
        if self.prio > 3
            || self.src > max
            || self.dst > max
            || self.dport > 63
            || self.sport > 63
            || self.flags & !version.flags_mask() != 0
        {
            return Err(CspError::Invalid);
        }
        let mut out = HeaderBytes::new();
        let r = match version {
            CspVersion::V1 => {
                let id = (u32::from(self.prio) << 30)
                    | (u32::from(self.src) << 25)
                    | (u32::from(self.dst) << 20)
                    | (u32::from(self.dport) << 14)
                    | (u32::from(self.sport) << 8)
                    | u32::from(self.flags);
                out.extend_from_slice(&id.to_be_bytes())
            }
            CspVersion::V2 => {
                let id = (u64::from(self.prio) << 46)
                    | (u64::from(self.dst) << 32)
                    | (u64::from(self.src) << 18)
                    | (u64::from(self.dport) << 12)
                    | (u64::from(self.sport) << 6)
                    | u64::from(self.flags);
                let b = id.to_be_bytes();
                out.extend_from_slice(b.get(2..).unwrap_or(&[]))
            }
        };
        r.map_err(|_| CspError::Invalid)?;
        Ok(out)
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

/// Whether `body` ends in a CRC-32C of the rest, over `data` alone or `head` + `data` (libcsp accepts both); the
/// data without the CRC if so.
fn strip_crc<'a>(head: &[u8], body: &'a [u8]) -> Option<&'a [u8]> {
    let (data, crc) = body.split_last_chunk::<CRC_LEN>()?;
    let crc = u32::from_be_bytes(*crc);
    if crc32c(data) == crc {
        return Some(data);
    }
    let mut with_head = Crc32c::new();
    with_head.update(head);
    with_head.update(data);
    (with_head.finish() == crc).then_some(data)
}

impl<'a> CspPacket<'a> {
    /// Parses the bytes of one KISS frame of a `version` link.
    pub fn parse(frame: &'a [u8], version: CspVersion) -> Result<Self, CspError> {
        let header = CspHeader::parse(frame, version)?;
        let (head, body) = frame
            .split_at_checked(version.header_len())
            .ok_or(CspError::TooShort)?;
        if body.len() < CRC_LEN {
            return Err(CspError::TooShort);
        }
        let payload = strip_crc(head, body).ok_or(CspError::Crc)?;
        let unsupported = header.flags & version.unsupported();
        if unsupported != 0 {
            return Err(CspError::Unsupported(unsupported));
        }
        let payload = if header.flags & FLAG_CRC32 != 0 {
            strip_crc(head, payload).ok_or(CspError::InnerCrc)?
        } else {
            payload
        };
        Ok(Self { header, payload })
    }

    /// Writes the packet (header, payload with the end-to-end CRC if the flag asks for it, link CRC; both CRCs over
    /// the payload only) as one KISS frame of a `version` link into `out`; returns its length.
    pub fn emit_kiss(
        header: &CspHeader,
        version: CspVersion,
        payload: &[u8],
        out: &mut [u8],
    ) -> Result<usize, CspError> {
        let head = header.emit(version)?;
        let inner = crc32c(payload).to_be_bytes();
        let inner: &[u8] = if header.flags & FLAG_CRC32 != 0 {
            &inner
        } else {
            &[]
        };
        let mut link = Crc32c::new();
        link.update(payload);
        link.update(inner);
        let link = link.finish().to_be_bytes();
        super::kiss::encode(&[&head, payload, inner, &link], out).map_err(|_| CspError::Invalid)
    }
}
