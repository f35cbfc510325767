//! KISS framing, CSP v1 packets and the bus endpoint (`shared::bus`).
//!
//! Input: a node configuration, a stream of pieces (raw bytes, KISS frames of arbitrary bytes, CSP packets built
//! with `CspPacket::emit_kiss`) and a chunking.
//! Properties:
//! * `BusNode::receive` over arbitrary chunks gives the same events and counters as over the whole stream;
//! * KISS: `kiss::encode` then `KissDecoder` returns the frame unchanged (any bytes up to `MAX_FRAME`);
//! * CSP: a packet emitted with `emit_kiss` parses back to its header and payload (inner CRC flag included);
//! * a stream of well-formed packets only: every packet addressed to the node's command, ping or update port
//!   comes out as that event with its payload, every other one is counted as ignored, no errors;
//! * `encode_telemetry` → a node listening as the ground receives the payload; `encode_reply` → the requester
//!   receives the echoed payload.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use arbitrary::Arbitrary;
use common::chunks;
use libfuzzer_sys::fuzz_target;
use shared::bus::csp::{CspHeader, CspPacket, CspVersion, FLAG_CRC32, PORT_PING};
use shared::bus::kiss::{self, KissDecoder};
use shared::bus::{
    BusConfig, BusCounters, BusEvent, BusNode, MAX_FRAME, MAX_PAYLOAD, MAX_WIRE_FRAME,
};

#[derive(Arbitrary, Debug, Clone, Copy)]
struct Header {
    prio: u8,
    src: u16,
    dst: u16,
    dport: u8,
    sport: u8,
    crc32: bool,
}

impl Header {
    fn csp(&self, cfg: &BusConfig, to_node: Option<bool>) -> CspHeader {
        CspHeader {
            prio: self.prio & 3,
            src: self.src & cfg.version.max_addr(),
            dst: if to_node.is_some() {
                cfg.addr
            } else {
                self.dst & cfg.version.max_addr()
            },
            dport: match to_node {
                Some(true) => cfg.command_port,
                Some(false) => PORT_PING,
                None => self.dport & 63,
            },
            sport: self.sport & 63,
            flags: if self.crc32 { FLAG_CRC32 } else { 0 },
        }
    }
}

#[derive(Arbitrary, Debug)]
enum Piece {
    Raw(Vec<u8>),
    Kiss(Vec<u8>),
    /// A packet; `to_node`: Some(true) = our command port, Some(false) = our ping port, None = as given.
    Packet {
        header: Header,
        to_node: Option<bool>,
        payload: Vec<u8>,
    },
}

#[derive(Arbitrary, Debug)]
struct Input {
    v2: bool,
    addr: u16,
    ground: u16,
    tm_port: u8,
    cmd_port: u8,
    pieces: Vec<Piece>,
    sizes: Vec<u16>,
}

impl Input {
    /// The bytes as one raw piece on a node with the default configuration, in 1- and 13-byte chunks.
    fn raw(bytes: &[u8]) -> Self {
        let c = BusConfig::DEFAULT;
        Self {
            v2: false,
            addr: c.addr,
            ground: c.ground_addr,
            tm_port: c.telemetry_port,
            cmd_port: c.command_port,
            pieces: vec![Piece::Raw(bytes.to_vec())],
            sizes: vec![1, 13],
        }
    }
}

#[derive(Debug, PartialEq, Eq, Clone)]
enum Ev {
    Command(Vec<u8>),
    Ping(CspHeader, Vec<u8>),
    Update(CspHeader, Vec<u8>),
}

fn own(e: BusEvent<'_>) -> Ev {
    match e {
        BusEvent::Command(p) => Ev::Command(p.to_vec()),
        BusEvent::Ping { header, payload } => Ev::Ping(header, payload.to_vec()),
        BusEvent::Update { header, payload } => Ev::Update(header, payload.to_vec()),
    }
}

fn receive_all(node: &mut BusNode, chunks: &[&[u8]]) -> Vec<Ev> {
    let mut out = Vec::new();
    for c in chunks {
        let mut input: &[u8] = c;
        while let Some(e) = node.receive(&mut input) {
            out.push(own(e));
        }
        assert!(input.is_empty());
    }
    out
}

fuzz_target!(|data: &[u8]| {
    // Seeds from real encodings: 'R' ++ bytes is the raw form (see `Input::raw`).
    if let Some(input) = common::input(data, Input::raw) {
        check(input);
    }
});

fn check(input: Input) {
    let version = if input.v2 {
        CspVersion::V2
    } else {
        CspVersion::V1
    };
    let cfg = BusConfig {
        version,
        addr: input.addr & version.max_addr(),
        ground_addr: input.ground & version.max_addr(),
        telemetry_port: input.tm_port & 63,
        command_port: input.cmd_port & 63,
        prio: 2,
    };
    let mut stream = Vec::new();
    let mut expected = Vec::new();
    let mut expected_ignored = 0u32;
    let mut well_formed = true;
    let mut out = [0u8; MAX_WIRE_FRAME];
    for p in &input.pieces {
        match p {
            Piece::Raw(b) => {
                well_formed &= b.is_empty();
                stream.extend_from_slice(b);
            }
            Piece::Kiss(frame) => {
                // KISS round trip on its own decoder.
                let frame = &frame[..frame.len().min(MAX_FRAME)];
                let n = kiss::encode(&[frame], &mut out)
                    .expect("a MAX_FRAME frame fits MAX_WIRE_FRAME");
                let mut d = KissDecoder::<MAX_FRAME>::new();
                let mut wire: &[u8] = &out[..n];
                let got = d.decode(&mut wire);
                if frame.is_empty() {
                    assert_eq!(got, None, "empty frames are skipped");
                } else {
                    assert_eq!(got, Some(Ok(frame)), "KISS round trip");
                }
                assert!(wire.is_empty(), "bytes after the closing FEND");
                well_formed = false; // arbitrary bytes are not necessarily a valid CSP packet
                stream.extend_from_slice(&out[..n]);
            }
            Piece::Packet {
                header,
                to_node,
                payload,
            } => {
                let h = header.csp(&cfg, *to_node);
                let payload = &payload[..payload.len().min(MAX_PAYLOAD)];
                let n = CspPacket::emit_kiss(&h, cfg.version, payload, &mut out)
                    .expect("a MAX_PAYLOAD packet fits");
                // CSP round trip through the KISS decoder.
                let mut d = KissDecoder::<MAX_FRAME>::new();
                let mut wire: &[u8] = &out[..n];
                let frame = d
                    .decode(&mut wire)
                    .expect("a frame")
                    .expect("a valid KISS frame");
                let p = CspPacket::parse(frame, cfg.version).expect("an emitted packet parses");
                assert_eq!(p.header, h);
                assert_eq!(p.payload, payload);
                stream.extend_from_slice(&out[..n]);
                if h.dst == cfg.addr && h.dport == cfg.command_port {
                    expected.push(Ev::Command(payload.to_vec()));
                } else if h.dst == cfg.addr && h.dport == PORT_PING {
                    expected.push(Ev::Ping(h, payload.to_vec()));
                } else if h.dst == cfg.addr && h.dport == shared::update::PORT_UPDATE {
                    expected.push(Ev::Update(h, payload.to_vec()));
                } else {
                    expected_ignored += 1;
                }
            }
        }
    }

    let mut one = BusNode::new(cfg);
    let whole = receive_all(&mut one, &[&stream]);
    let mut many = BusNode::new(cfg);
    let split = receive_all(&mut many, &chunks(&stream, &input.sizes));
    assert_eq!(whole, split, "chunked receive differs");
    assert_eq!(one.counters(), many.counters());
    let c: BusCounters = *one.counters();
    assert_eq!(c.packets as usize, whole.len());

    if well_formed {
        assert_eq!(whole, expected, "well-formed packets lost or altered");
        assert_eq!(c.ignored, expected_ignored);
        assert_eq!((c.kiss_errors, c.csp_errors), (0, 0));
    }

    replies(&cfg, &stream, &whole);
}

/// Telemetry to the ground (the start of `stream` as its payload) round trips, and every ping in `whole` gets its
/// reply.
fn replies(cfg: &BusConfig, stream: &[u8], whole: &[Ev]) {
    let mut out = [0u8; MAX_WIRE_FRAME];
    let payload: Vec<u8> = stream.iter().copied().take(MAX_PAYLOAD).collect();
    let node = BusNode::new(*cfg);
    let n = node
        .encode_telemetry(&payload, &mut out)
        .expect("telemetry fits");
    let mut ground = BusNode::new(BusConfig {
        version: cfg.version,
        addr: cfg.ground_addr,
        ground_addr: cfg.addr,
        telemetry_port: cfg.command_port,
        command_port: cfg.telemetry_port,
        prio: cfg.prio,
    });
    let mut wire: &[u8] = &out[..n];
    let got = ground.receive(&mut wire).map(own);
    assert_eq!(
        got,
        Some(Ev::Command(payload.clone())),
        "telemetry round trip"
    );
    for e in whole {
        if let Ev::Ping(h, p) = e {
            let n = node.encode_reply(h, p, &mut out).expect("reply fits");
            let mut d = KissDecoder::<MAX_FRAME>::new();
            let mut wire: &[u8] = &out[..n];
            let frame = d.decode(&mut wire).unwrap().unwrap();
            let r = CspPacket::parse(frame, cfg.version).expect("reply parses");
            assert_eq!(r.header, h.reply());
            assert_eq!(r.payload, &p[..]);
        }
    }
}
