//! Known-answer vectors computed from libcsp 1.x's sources (csp_if_kiss.c, csp_crc32.c, csp_types.h): see
//! `docs/bus.md`.
use super::csp::*;
use super::kiss::*;
use super::*;
use proptest::prelude::*;

extern crate std;
use std::vec::Vec;

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|h| u8::from_str_radix(h, 16).unwrap())
        .collect()
}

fn node() -> BusNode {
    BusNode::new(BusConfig {
        addr: 10,
        ..BusConfig::DEFAULT
    })
}

/// A header vector: ((prio, src, dst, dport, sport, flags), wire bytes).
type Vector = ((u8, u16, u16, u8, u8, u8), &'static str);

/// Each header emits as its wire bytes and parses back, in `version`.
fn check_vectors(version: CspVersion, cases: &[Vector]) {
    for &((prio, src, dst, dport, sport, flags), wire) in cases {
        let h = CspHeader {
            prio,
            src,
            dst,
            dport,
            sport,
            flags,
        };
        assert_eq!(h.emit(version).unwrap().to_vec(), hex(wire));
        assert_eq!(CspHeader::parse(&hex(wire), version), Ok(h));
    }
}

#[test]
fn header_vectors() {
    let cases = [
        ((2, 1, 10, 10, 33, 0x01), "82 A2 A1 01"),
        ((2, 1, 10, 1, 33, 0), "82 A0 61 00"),
        ((2, 10, 1, 33, 1, 0), "94 18 41 00"),
        ((3, 0, 1, 1, 56, 0), "C0 10 78 00"),
        ((2, 22, 10, 1, 57, 0x01), "AC A0 79 01"),
    ];
    check_vectors(CspVersion::V1, &cases);
    assert_eq!(
        CspHeader {
            prio: 4,
            src: 0,
            dst: 0,
            dport: 0,
            sport: 0,
            flags: 0
        }
        .emit(CspVersion::V1),
        Err(CspError::Invalid)
    );
}

/// v2: 48 bits, prio:2 | dst:14 | src:14 | dport:6 | sport:6 | flags:6 (libcsp 2.x `csp_id.c`, `csp_id2_prepend`).
#[test]
fn header_vectors_v2() {
    let cases = [
        ((2, 1, 10, 11, 40, FLAG_CRC32), "80 0A 00 04 BA 01"),
        ((2, 10, 1, 10, 11, 0), "80 01 00 28 A2 C0"),
        ((3, 0, 16383, 63, 0, 0), "FF FF 00 03 F0 00"),
        ((0, 16383, 0, 0, 63, 0x3F), "00 00 FF FC 0F FF"),
        ((2, 1, 5000, 1, 33, 0), "93 88 00 04 18 40"),
    ];
    check_vectors(CspVersion::V2, &cases);
    let h = header(0);
    // Out of a version's range: 14-bit addresses and 6-bit flags in v2, 5-bit addresses in v1.
    for bad in [
        CspHeader { src: 16384, ..h },
        CspHeader { dst: 16384, ..h },
        CspHeader { flags: 0x40, ..h },
        CspHeader { dport: 64, ..h },
    ] {
        assert_eq!(bad.emit(CspVersion::V2), Err(CspError::Invalid));
    }
    assert_eq!(
        CspHeader { dst: 32, ..h }.emit(CspVersion::V1),
        Err(CspError::Invalid)
    );
    assert_eq!(
        CspHeader::parse(&[0; 5], CspVersion::V2),
        Err(CspError::TooShort)
    );
}

/// The header of the tests: priority 2, node 1 port 40 to node 10 port 11, with `flags`.
fn header(flags: u8) -> CspHeader {
    CspHeader {
        prio: 2,
        src: 1,
        dst: 10,
        dport: 11,
        sport: 40,
        flags,
    }
}

/// libcsp's `csp_crc32_verify` accepts a CRC over the payload or over header and payload (a libcsp 2.1 build
/// sends the latter); so do we, for the link CRC and the end-to-end CRC, in both versions.
#[test]
fn crc_over_header_and_payload_is_accepted() {
    for version in [CspVersion::V1, CspVersion::V2] {
        let h = header(FLAG_CRC32);
        let head = h.emit(version).unwrap();
        let data = b"cmd";
        let mut inner = crate::crc::Crc32c::new();
        inner.update(&head);
        inner.update(data);
        let mut body = data.to_vec();
        body.extend_from_slice(&inner.finish().to_be_bytes());
        let mut link = crate::crc::Crc32c::new();
        link.update(&head);
        link.update(&body);
        let mut frame = head.to_vec();
        frame.extend_from_slice(&body);
        frame.extend_from_slice(&link.finish().to_be_bytes());
        let p = CspPacket::parse(&frame, version).unwrap();
        assert_eq!((p.header, p.payload), (h, &data[..]));
        // One bit off in the header: neither form matches any more.
        frame[1] ^= 0x01;
        assert_eq!(
            CspPacket::parse(&frame, version).unwrap_err(),
            CspError::Crc
        );
    }
}

/// A v2 node: commands and pings with 14-bit addresses, telemetry out; a v1 frame is not mistaken for one.
#[test]
fn a_v2_node_serves_commands_pings_and_telemetry() {
    let config = BusConfig {
        version: CspVersion::V2,
        addr: 5000,
        ground_addr: 12000,
        ..BusConfig::DEFAULT
    };
    let mut n = BusNode::new(config);
    let to_us = command_header(12000, 5000);
    assert_eq!(
        deliver(&mut n, &to_us, CspVersion::V2, b"cmd"),
        Some((None, b"cmd".to_vec()))
    );
    let ping = CspHeader {
        dport: PORT_PING,
        sport: 33,
        flags: FLAG_CRC32,
        ..to_us
    };
    let (header, payload) = deliver(&mut n, &ping, CspVersion::V2, &[7; MAX_PAYLOAD]).unwrap();
    let header = header.expect("a ping");
    let mut wire = [0u8; MAX_WIRE_FRAME];
    let len = n.encode_reply(&header, &payload, &mut wire).unwrap();
    let mut dec = KissDecoder::<MAX_FRAME>::new();
    let mut input = &wire[..len];
    let p = CspPacket::parse(dec.decode(&mut input).unwrap().unwrap(), CspVersion::V2).unwrap();
    assert_eq!((p.header, p.payload), (ping.reply(), &[7; MAX_PAYLOAD][..]));

    let len = n.encode_telemetry(b"tm", &mut wire).unwrap();
    let mut input = &wire[..len];
    let p = CspPacket::parse(dec.decode(&mut input).unwrap().unwrap(), CspVersion::V2).unwrap();
    assert_eq!(
        (p.header.src, p.header.dst, p.header.dport, p.payload),
        (5000, 12000, 10, &b"tm"[..])
    );
    // Fragmentation is refused in v2.
    let frag = CspHeader {
        flags: FLAG_FRAG,
        ..to_us
    };
    assert_eq!(deliver(&mut n, &frag, CspVersion::V2, b"x"), None);
    assert_eq!(n.counters().csp_errors, 1);
}

#[test]
fn crc_vectors() {
    // libcsp appends CRC-32C big-endian.
    assert_eq!(
        crate::crc::crc32c(&[0, 1, 2, 3]).to_be_bytes(),
        [0xD9, 0x33, 0x1A, 0xA3]
    );
    assert_eq!(crate::crc::crc32c(&[0]), 0x527D_5351);
}

/// A command from `src` to `dst` (the default command port 11, from port 40).
fn command_header(src: u16, dst: u16) -> CspHeader {
    CspHeader {
        prio: 2,
        src,
        dst,
        dport: 11,
        sport: 40,
        flags: 0,
    }
}

/// `payload` sent to `n` with header `h` in `version`: what `n` makes of it.
fn deliver(
    n: &mut BusNode,
    h: &CspHeader,
    version: CspVersion,
    payload: &[u8],
) -> Option<(Option<CspHeader>, Vec<u8>)> {
    let mut wire = [0u8; MAX_WIRE_FRAME];
    let len = CspPacket::emit_kiss(h, version, payload, &mut wire).unwrap();
    one_event(n, &wire[..len])
}

fn one_event(n: &mut BusNode, wire: &[u8]) -> Option<(Option<CspHeader>, Vec<u8>)> {
    let mut input = wire;
    let ev = n.receive(&mut input).map(|e| match e {
        BusEvent::Command(p) => (None, p.to_vec()),
        BusEvent::Ping { header, payload } | BusEvent::Update { header, payload } => {
            (Some(header), payload.to_vec())
        }
    });
    assert!(input.is_empty() || ev.is_some());
    ev
}

#[test]
fn ping_is_echoed_like_libcsp() {
    for (req, reply) in [
        (
            "C0 00 82 A0 61 00 00 01 02 03 D9 33 1A A3 C0",
            "C0 00 94 18 41 00 00 01 02 03 D9 33 1A A3 C0",
        ),
        (
            "C0 00 82 A0 61 01 00 01 02 03 D9 33 1A A3 03 B0 62 A6 C0",
            "C0 00 94 18 41 01 00 01 02 03 D9 33 1A A3 03 B0 62 A6 C0",
        ),
    ] {
        let mut n = node();
        let (header, payload) = one_event(&mut n, &hex(req)).unwrap();
        let header = header.expect("a ping");
        assert_eq!(payload, [0, 1, 2, 3]);
        let mut out = [0u8; MAX_WIRE_FRAME];
        let len = n.encode_reply(&header, &payload, &mut out).unwrap();
        assert_eq!(out[..len].to_vec(), hex(reply));
    }
}

/// A request to port 12 is an update event, answered to its source port like a ping.
#[test]
fn update_requests_are_routed_and_answered_to_their_source_port() {
    let mut n = node();
    let h = CspHeader {
        prio: 2,
        src: 1,
        dst: 10,
        dport: crate::update::PORT_UPDATE,
        sport: 33,
        flags: 0,
    };
    let mut wire = [0u8; MAX_WIRE_FRAME];
    let len = CspPacket::emit_kiss(&h, CspVersion::V1, &[5, 6], &mut wire).unwrap();
    let mut input = &wire[..len];
    let Some(BusEvent::Update { header, payload }) = n.receive(&mut input) else {
        panic!("not an update event")
    };
    assert_eq!((header, payload), (h, &[5u8, 6][..]));
    let mut out = [0u8; MAX_WIRE_FRAME];
    let len = n.encode_reply(&h, &[7], &mut out).unwrap();
    let mut dec = KissDecoder::<MAX_FRAME>::new();
    let mut input = &out[..len];
    let frame = dec.decode(&mut input).unwrap().unwrap();
    let reply = CspPacket::parse(frame, CspVersion::V1).unwrap();
    assert_eq!(
        (
            reply.header.src,
            reply.header.dst,
            reply.header.sport,
            reply.header.dport,
            reply.payload
        ),
        (10, 1, crate::update::PORT_UPDATE, 33, &[7u8][..])
    );
}

#[test]
fn escaping_and_empty_payload_vectors() {
    let h = CspHeader {
        prio: 3,
        src: 0,
        dst: 1,
        dport: 1,
        sport: 56,
        flags: 0,
    };
    let mut out = [0u8; 64];
    let n = CspPacket::emit_kiss(&h, CspVersion::V1, &[0xC0, 0xDB], &mut out).unwrap();
    assert_eq!(
        out[..n].to_vec(),
        hex("C0 00 DB DC 10 78 00 DB DC DB DD BF EF 01 BF C0")
    );
    let h = CspHeader {
        prio: 2,
        src: 1,
        dst: 10,
        dport: 10,
        sport: 33,
        flags: 0,
    };
    let n = CspPacket::emit_kiss(&h, CspVersion::V1, &[], &mut out).unwrap();
    assert_eq!(out[..n].to_vec(), hex("C0 00 82 A2 A1 00 00 00 00 00 C0"));
    // Decoding the escaped frame gives back header and payload.
    let mut dec = KissDecoder::<64>::new();
    let mut input = &hex("C0 00 DB DC 10 78 00 DB DC DB DD BF EF 01 BF C0")[..];
    let frame = dec.decode(&mut input).unwrap().unwrap();
    let p = CspPacket::parse(frame, CspVersion::V1).unwrap();
    assert_eq!((p.header.dport, p.payload), (1, &[0xC0, 0xDB][..]));
}

#[test]
fn commands_reach_us_and_telemetry_goes_to_the_ground() {
    let mut n = node();
    let to_us = command_header(1, 10);
    assert_eq!(
        deliver(&mut n, &to_us, CspVersion::V1, b"cmd"),
        Some((None, b"cmd".to_vec()))
    );
    let elsewhere = CspHeader { dst: 11, ..to_us };
    assert_eq!(deliver(&mut n, &elsewhere, CspVersion::V1, b"cmd"), None);
    assert_eq!(n.counters().ignored, 1);

    let mut wire = [0u8; MAX_WIRE_FRAME];
    let len = n.encode_telemetry(b"tm", &mut wire).unwrap();
    let mut dec = KissDecoder::<MAX_FRAME>::new();
    let mut input = &wire[..len];
    let p = CspPacket::parse(dec.decode(&mut input).unwrap().unwrap(), CspVersion::V1).unwrap();
    assert_eq!(
        (p.header.src, p.header.dst, p.header.dport, p.payload),
        (10, 1, 10, &b"tm"[..])
    );
    assert_eq!(
        n.encode_telemetry(&[0; MAX_PAYLOAD + 1], &mut wire),
        Err(CspError::Invalid)
    );
}

#[test]
fn bad_frames_give_typed_errors() {
    let mut dec = KissDecoder::<16>::new();
    let mut run = |s: &str| {
        let bytes = hex(s);
        let mut input = &bytes[..];
        let mut out = Vec::new();
        while let Some(r) = dec.decode(&mut input) {
            out.push(r.map(|f| f.to_vec()));
        }
        out
    };
    assert_eq!(run("C0 00 01 DB 55 02 C0"), [Err(KissError::BadEscape)]);
    assert_eq!(run("C0 06 01 02 C0"), [Err(KissError::Command(6))]);
    assert_eq!(
        run("C0 00 00 01 02 03 04 05 06 07 08 09 0A 0B 0C 0D 0E 0F 10 C0"),
        [Err(KissError::Oversize)]
    );
    assert_eq!(run("C0 C0 C0 00 07 C0"), [Ok(std::vec![7])]); // empty frames skipped
    assert_eq!(
        run("C0 00 01 DB C0 00 09 C0"),
        [Err(KissError::BadEscape), Ok(std::vec![9])]
    );
    assert_eq!(
        CspPacket::parse(&[1, 2, 3, 4, 5, 6, 7], CspVersion::V1),
        Err(CspError::TooShort)
    );
    assert_eq!(
        CspPacket::parse(&hex("82 A2 A1 00 00 00 00 01"), CspVersion::V1),
        Err(CspError::Crc)
    );
    assert_eq!(
        CspPacket::parse(&hex("82 A2 A1 01 00 00 00 00"), CspVersion::V1),
        Err(CspError::InnerCrc)
    );
    assert_eq!(
        CspPacket::parse(&hex("82 A2 A1 02 00 00 00 00"), CspVersion::V1),
        Err(CspError::Unsupported(FLAG_RDP))
    );
}

/// `encode_message` is `telemetry::encode` then `encode_telemetry`, and the frame decodes back to the message.
#[test]
fn a_message_goes_on_the_bus_as_postcard_in_csp_in_kiss() {
    use crate::telemetry::{Ack, Telemetry, decode, encode};
    let node = BusNode::new(BusConfig::DEFAULT);
    let msg = Telemetry::Ack(Ack {
        tag: 7,
        result: Ok(()),
    });
    let (mut payload, mut a, mut b) = ([0u8; 64], [0u8; MAX_WIRE_FRAME], [0u8; MAX_WIRE_FRAME]);
    let n = node.encode_message(&msg, &mut a).unwrap();
    let m = node
        .encode_telemetry(encode(&msg, &mut payload).unwrap(), &mut b)
        .unwrap();
    assert_eq!(a[..n], b[..m]);
    let mut kiss = KissDecoder::<MAX_FRAME>::new();
    let mut input = &a[..n];
    let frame = kiss.decode(&mut input).unwrap().unwrap();
    let packet = CspPacket::parse(frame, CspVersion::V1).unwrap();
    assert_eq!(decode::<Telemetry>(packet.payload), Ok(msg));
    // Too small an output: a typed error.
    assert_eq!(
        node.encode_message(&msg, &mut a[..4]),
        Err(CspError::Invalid)
    );
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Round trip of arbitrary payloads through the whole stack, with garbage around the frames.
    #[test]
    fn payloads_round_trip_through_kiss_and_csp(payload in proptest::collection::vec(any::<u8>(), 0..MAX_PAYLOAD),
                                               garbage in proptest::collection::vec(any::<u8>(), 0..40)) {
        let mut n = node();
        let to_us = CspHeader { prio: 1, src: 3, dst: 10, dport: 11, sport: 50, flags: FLAG_CRC32 };
        let mut wire = [0u8; MAX_WIRE_FRAME];
        let len = CspPacket::emit_kiss(&to_us, CspVersion::V1, &payload, &mut wire).unwrap();
        let mut stream: Vec<u8> = garbage.iter().copied().filter(|&b| b != FEND).collect();
        stream.extend_from_slice(&wire[..len]);
        stream.extend_from_slice(&garbage);
        prop_assert_eq!(one_event(&mut n, &stream), Some((None, payload)));
    }

    /// Any bytes: a typed outcome, never a panic, and a following good frame still arrives.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let mut n = node();
        let mut input = &bytes[..];
        while n.receive(&mut input).is_some() {}
        let _ = CspPacket::parse(&bytes, CspVersion::V1);
        let _ = CspPacket::parse(&bytes, CspVersion::V2);
        let mut wire = [0u8; MAX_WIRE_FRAME];
        let h = command_header(1, 10);
        let len = CspPacket::emit_kiss(&h, CspVersion::V1, b"after", &mut wire).unwrap();
        prop_assert_eq!(one_event(&mut n, &wire[..len]), Some((None, b"after".to_vec())));
    }
}
