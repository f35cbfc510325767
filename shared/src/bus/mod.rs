//! The CubeSat bus: CSP packets (header version 1 or 2) in KISS frames, carrying the postcard messages of [`crate::telemetry`]
//! (spec: `docs/bus.md`). [`BusNode`] is the sans-IO endpoint: bus bytes in, command, ping and update events out;
//! telemetry payloads in, KISS frames out. The firmware only moves bytes.

pub mod csp;
pub mod kiss;

use csp::{CspError, CspHeader, CspPacket, CspVersion, PORT_PING};
use kiss::KissDecoder;

/// Largest CSP payload on the link, end-to-end CRC included: 248 bytes, what every libcsp 1.x accepts by default
/// (and well inside libcsp 2.x's 256-byte buffers).
pub const MAX_CSP_DATA: usize = 248;
/// Largest decoded KISS frame: header (6 bytes in v2, 4 in v1), [`MAX_CSP_DATA`], link CRC.
pub const MAX_FRAME: usize = csp::HEADER_LEN_MAX + MAX_CSP_DATA + csp::CRC_LEN;
/// Largest payload we send or accept (room left for an end-to-end CRC).
pub const MAX_PAYLOAD: usize = MAX_CSP_DATA - csp::CRC_LEN;
/// Largest encoded KISS frame on the wire.
pub const MAX_WIRE_FRAME: usize = kiss::encoded_len_max(MAX_FRAME);

/// Addresses and ports of this node.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusConfig {
    /// CSP header version of the link.
    pub version: CspVersion,
    /// Our CSP address (v1 ≤ 31, v2 ≤ 16383).
    pub addr: u16,
    /// The ground station's address (destination of telemetry).
    pub ground_addr: u16,
    /// Ground port that receives telemetry (acks included).
    pub telemetry_port: u8,
    /// Our port that receives commands.
    pub command_port: u8,
    /// Priority of telemetry packets.
    pub prio: u8,
}

impl BusConfig {
    /// Defaults: CSP v1; we are node 10, the ground node 1; telemetry to port 10, commands on port 11, normal
    /// priority.
    pub const DEFAULT: Self = Self {
        version: CspVersion::V1,
        addr: 10,
        ground_addr: 1,
        telemetry_port: 10,
        command_port: 11,
        prio: 2,
    };
}

/// What arrived for us.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BusEvent<'a> {
    /// A command message (payload for `Pipeline::handle_command`).
    Command(&'a [u8]),
    /// A ping: answer with [`BusNode::encode_reply`] and the same payload.
    Ping {
        /// The request's header.
        header: CspHeader,
        /// Its payload.
        payload: &'a [u8],
    },
    /// A request to the update service ([`crate::update::PORT_UPDATE`]): answer with [`BusNode::encode_reply`].
    Update {
        /// The request's header.
        header: CspHeader,
        /// Its payload (an `UpdateEnvelope`).
        payload: &'a [u8],
    },
}

/// Bus statistics: a telemetry type (reported in housekeeping), counted here.
pub use crate::telemetry::BusCounters;

/// The sans-IO bus endpoint.
#[derive(Clone, Debug)]
pub struct BusNode {
    config: BusConfig,
    kiss: KissDecoder<MAX_FRAME>,
    counters: BusCounters,
}

enum Kind {
    Command,
    Ping(CspHeader),
    Update(CspHeader),
}

impl BusNode {
    /// An endpoint with `config`.
    pub const fn new(config: BusConfig) -> Self {
        Self {
            config,
            kiss: KissDecoder::new(),
            counters: BusCounters {
                packets: 0,
                kiss_errors: 0,
                csp_errors: 0,
                ignored: 0,
            },
        }
    }

    /// Statistics.
    pub fn counters(&self) -> &BusCounters {
        &self.counters
    }

    /// Consumes bus bytes until an event for us (returned) or the end of `input` (`None`).
    pub fn receive<'a>(&'a mut self, input: &mut &[u8]) -> Option<BusEvent<'a>> {
        let kind = loop {
            let frame = match self.kiss.decode(input)? {
                Ok(frame) => frame,
                Err(_) => {
                    self.counters.kiss_errors = self.counters.kiss_errors.wrapping_add(1);
                    continue;
                }
            };
            match CspPacket::parse(frame, self.config.version) {
                Ok(p)
                    if p.header.dst == self.config.addr
                        && p.header.dport == self.config.command_port =>
                {
                    break Kind::Command;
                }
                Ok(p) if p.header.dst == self.config.addr && p.header.dport == PORT_PING => {
                    break Kind::Ping(p.header);
                }
                Ok(p)
                    if p.header.dst == self.config.addr
                        && p.header.dport == crate::update::PORT_UPDATE =>
                {
                    break Kind::Update(p.header);
                }
                Ok(_) => self.counters.ignored = self.counters.ignored.wrapping_add(1),
                Err(_) => self.counters.csp_errors = self.counters.csp_errors.wrapping_add(1),
            }
        };
        self.counters.packets = self.counters.packets.wrapping_add(1);
        // Parsed again from the decoder's buffer: the borrow above ended with the loop.
        let payload = CspPacket::parse(self.kiss.last_frame(), self.config.version)
            .map_or(&[][..], |p| p.payload);
        Some(match kind {
            Kind::Command => BusEvent::Command(payload),
            Kind::Ping(header) => BusEvent::Ping { header, payload },
            Kind::Update(header) => BusEvent::Update { header, payload },
        })
    }

    /// A telemetry message as it goes on the bus: postcard (the message, `telemetry::encode`), then CSP to the
    /// ground's telemetry port, then KISS, in `out`; returns its length. The one encoder of the firmware's bus task
    /// and the ground's replay.
    pub fn encode_message(
        &self,
        message: &crate::telemetry::Telemetry,
        out: &mut [u8],
    ) -> Result<usize, CspError> {
        let mut payload = [0u8; crate::telemetry::MAX_MESSAGE_LEN];
        // Every message fits `MAX_MESSAGE_LEN` (telemetry's tests); the error is the output's.
        let payload =
            crate::telemetry::encode(message, &mut payload).map_err(|_| CspError::Invalid)?;
        self.encode_telemetry(payload, out)
    }

    /// A telemetry packet (to the ground's telemetry port) as a KISS frame in `out`; returns its length.
    pub fn encode_telemetry(&self, payload: &[u8], out: &mut [u8]) -> Result<usize, CspError> {
        let c = &self.config;
        let header = CspHeader {
            prio: c.prio,
            src: c.addr,
            dst: c.ground_addr,
            dport: c.telemetry_port,
            sport: c.command_port,
            flags: 0,
        };
        self.encode(&header, payload, out)
    }

    /// The reply to `request` (a ping's echo, an update reply) as a KISS frame in `out`.
    pub fn encode_reply(
        &self,
        request: &CspHeader,
        payload: &[u8],
        out: &mut [u8],
    ) -> Result<usize, CspError> {
        self.encode(&request.reply(), payload, out)
    }

    fn encode(
        &self,
        header: &CspHeader,
        payload: &[u8],
        out: &mut [u8],
    ) -> Result<usize, CspError> {
        if payload.len() > MAX_PAYLOAD {
            return Err(CspError::Invalid);
        }
        CspPacket::emit_kiss(header, self.config.version, payload, out)
    }
}

#[cfg(test)]
mod tests;
