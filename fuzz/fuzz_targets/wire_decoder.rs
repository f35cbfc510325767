//! The streaming FPGA frame decoder (`shared::wire::FrameDecoder`).
//!
//! Input: a stream built from pieces (raw bytes, valid-CRC frames, damaged frames) and a chunking.
//! Properties:
//! * decoding the stream in arbitrary chunks gives the same frames (with their sequence gaps) and the same
//!   `LinkCounters` as decoding it in one call;
//! * byte accounting: frames·FRAME_LEN + bytes_skipped ≤ total, and less than one frame's worth is held back;
//! * every decoded frame re-emits to bytes that parse back to the same frame;
//! * a stream of clean frames only yields exactly those frames, in order, with no errors or skipped bytes.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use arbitrary::Arbitrary;
use common::{FrameSpec, chunks};
use libfuzzer_sys::fuzz_target;
use shared::wire::frame::{FRAME_LEN, FrameRepr};
use shared::wire::{Decoded, FrameDecoder, LinkCounters};

#[derive(Arbitrary, Debug)]
enum Piece {
    Raw(Vec<u8>),
    Frame(FrameSpec),
    /// A frame with one byte flipped (`xor` ≠ 0 makes it damaged) at `at` (mod FRAME_LEN).
    Damaged {
        frame: FrameSpec,
        at: u16,
        xor: u8,
    },
    /// The first `keep` bytes of a frame (a dropped tail).
    Truncated {
        frame: FrameSpec,
        keep: u8,
    },
}

#[derive(Arbitrary, Debug)]
struct Input {
    pieces: Vec<Piece>,
    sizes: Vec<u16>,
}

impl Input {
    /// The bytes as one raw piece, decoded one-shot and in 1-, 7- and 64-byte chunks.
    fn raw(bytes: &[u8]) -> Self {
        Self {
            pieces: vec![Piece::Raw(bytes.to_vec())],
            sizes: vec![1, 7, 64],
        }
    }
}

fn run(decoder: &mut FrameDecoder, chunks: &[&[u8]]) -> Vec<Decoded> {
    let mut out = Vec::new();
    for c in chunks {
        let mut input: &[u8] = c;
        while let Some(d) = decoder.decode(&mut input) {
            out.push(d);
        }
        assert!(input.is_empty(), "decode returned None with bytes left");
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
    let mut stream = Vec::new();
    let mut clean = Vec::new();
    let mut all_clean = true;
    for p in &input.pieces {
        match p {
            Piece::Raw(b) => {
                all_clean &= b.is_empty();
                stream.extend_from_slice(b);
            }
            Piece::Frame(f) => {
                let r = f.repr();
                stream.extend_from_slice(&r.to_bytes());
                clean.push(r);
            }
            Piece::Damaged { frame, at, xor } => {
                let mut b = frame.repr().to_bytes();
                b[usize::from(*at) % FRAME_LEN] ^= xor;
                all_clean &= *xor == 0;
                if *xor == 0 {
                    clean.push(frame.repr());
                }
                stream.extend_from_slice(&b);
            }
            Piece::Truncated { frame, keep } => {
                let b = frame.repr().to_bytes();
                let keep = usize::from(*keep).min(FRAME_LEN);
                all_clean &= keep == 0;
                stream.extend_from_slice(&b[..keep]);
            }
        }
    }

    let mut one = FrameDecoder::new();
    let whole = run(&mut one, &[&stream]);
    let mut many = FrameDecoder::new();
    let split = run(&mut many, &chunks(&stream, &input.sizes));
    assert_eq!(whole, split, "chunked decode differs from one-shot");
    assert_eq!(one.counters(), many.counters(), "counters differ");

    let c: LinkCounters = *one.counters();
    assert_eq!(c.frames as usize, whole.len());
    let consumed = whole.len() * FRAME_LEN + c.bytes_skipped as usize;
    assert!(consumed <= stream.len(), "more bytes accounted than given");
    assert!(
        stream.len() - consumed < FRAME_LEN,
        "a whole frame's worth of bytes held back"
    );

    for d in &whole {
        assert_eq!(FrameRepr::parse_bytes(&d.frame.to_bytes()), Ok(d.frame));
    }

    if all_clean {
        let frames: Vec<FrameRepr> = whole.iter().map(|d| d.frame).collect();
        assert_eq!(frames, clean, "clean frames lost or altered");
        assert_eq!(c.crc_errors, 0);
        assert_eq!(c.bytes_skipped, 0);
        assert_eq!(c.resyncs, 0);
    }
}
