//! The MIMU4444 stream reader of the ground tool (`host_test::formats::mimu::parse_with`, the byte-level reader behind
//! `host_test::formats::mimu::read`, which only adds the file read).
//!
//! Input: a stream built from pieces (the command acknowledgement, valid frames, damaged frames, raw bytes) and the
//! options.
//! Properties:
//! * never panics, in lenient and strict mode;
//! * on success: one offset, tick and discontinuity flag per frame; offsets strictly increase by at least a
//!   frame; the bytes at each offset decode to that frame; ticks never decrease and start at 0; the first frame
//!   is not a discontinuity; `stats.frames` counts the frames; `stats.bytes` is the input length;
//! * strict mode succeeds only when lenient mode does, with the same frames;
//! * a stream of the acknowledgement and valid consecutive frames parses to exactly those frames.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use arbitrary::Arbitrary;
use host_test::formats::mimu::{
    self, ACK, FRAME_LEN, Frame, ImuSample, ParseOptions, TICKS_PER_SAMPLE,
};
use libfuzzer_sys::fuzz_target;

#[derive(Arbitrary, Debug)]
enum Piece {
    Ack,
    Raw(Vec<u8>),
    /// A valid frame: packet number, timestamp, a seed for the IMU words.
    Frame {
        packet: u16,
        timestamp: u32,
        seed: u16,
    },
    /// The next consecutive frame (packet + 1, timestamp + one sample period).
    Next {
        seed: u16,
    },
    Damaged {
        at: u8,
        xor: u8,
    },
    Truncated {
        keep: u8,
    },
}

#[derive(Arbitrary, Debug)]
struct Input {
    pieces: Vec<Piece>,
    max_skipped: u8,
}

fn frame(packet: u16, timestamp: u32, seed: u16) -> Frame {
    let mut s = u32::from(seed) | 1;
    let mut w = || {
        s ^= s << 13;
        s ^= s >> 17;
        s ^= s << 5;
        s as i16
    };
    Frame {
        packet,
        timestamp,
        imu: core::array::from_fn(|_| ImuSample {
            acc: [w(), w(), w()],
            gyro: [w(), w(), w()],
        }),
    }
}

fuzz_target!(|data: &[u8]| {
    // Seeds from real recordings: 'R' ++ bytes is the raw form.
    let raw = |rest: &[u8]| Input {
        pieces: vec![Piece::Raw(rest.to_vec())],
        max_skipped: 128,
    };
    if let Some(input) = common::input(data, raw) {
        check(input);
    }
});

fn check(input: Input) {
    let mut bytes = Vec::new();
    let mut last = frame(0, 0, 0);
    let mut clean = true;
    let mut expected = Vec::new();
    for (i, p) in input.pieces.iter().take(256).enumerate() {
        match p {
            Piece::Ack => {
                clean &= i == 0;
                bytes.extend_from_slice(&ACK);
            }
            Piece::Raw(b) => {
                clean &= b.is_empty();
                bytes.extend_from_slice(b);
            }
            Piece::Frame {
                packet,
                timestamp,
                seed,
            } => {
                last = frame(*packet, *timestamp, *seed);
                clean &= expected.is_empty();
                expected.push(last);
                bytes.extend_from_slice(&last.encode());
            }
            Piece::Next { seed } => {
                last = frame(
                    last.packet.wrapping_add(1),
                    last.timestamp.wrapping_add(TICKS_PER_SAMPLE),
                    *seed,
                );
                clean &= !expected.is_empty();
                expected.push(last);
                bytes.extend_from_slice(&last.encode());
            }
            Piece::Damaged { at, xor } => {
                let mut b = last.encode();
                b[usize::from(*at) % FRAME_LEN] ^= xor;
                clean = false;
                bytes.extend_from_slice(&b);
            }
            Piece::Truncated { keep } => {
                let b = last.encode();
                clean = false;
                bytes.extend_from_slice(&b[..usize::from(*keep) % FRAME_LEN]);
            }
        }
    }
    let lenient_opts = ParseOptions {
        strict: false,
        max_skipped_fraction: f64::from(input.max_skipped) / 255.0,
    };
    let lenient = mimu::parse_with(&bytes, &lenient_opts);
    let strict = mimu::parse_with(
        &bytes,
        &ParseOptions {
            strict: true,
            ..lenient_opts
        },
    );
    for r in [&lenient, &strict] {
        let Ok(rec) = r else { continue };
        let n = rec.frames.len();
        assert!(n > 0);
        assert_eq!(rec.offsets.len(), n);
        assert_eq!(rec.ticks.len(), n);
        assert_eq!(rec.discontinuity.len(), n);
        assert_eq!(rec.stats.frames, n);
        assert_eq!(rec.stats.bytes, bytes.len());
        assert_eq!(rec.ticks[0], 0);
        assert!(!rec.discontinuity[0]);
        for w in rec.offsets.windows(2) {
            assert!(w[1] >= w[0] + FRAME_LEN, "overlapping frames at {w:?}");
        }
        for w in rec.ticks.windows(2) {
            assert!(w[1] >= w[0], "ticks went back");
        }
        for (f, &o) in rec.frames.iter().zip(&rec.offsets) {
            assert_eq!(Frame::decode(&bytes[o..]).as_ref(), Ok(f), "frame at {o}");
        }
    }
    if let Ok(s) = &strict {
        let l = lenient.as_ref().expect("strict succeeded, lenient failed");
        assert_eq!(s.frames, l.frames);
    }
    if clean && !expected.is_empty() {
        let rec = mimu::parse(&bytes).expect("a clean stream parses");
        assert_eq!(rec.frames, expected, "clean frames lost or altered");
    }
}
