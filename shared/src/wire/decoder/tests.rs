use super::*;
use crate::wire::frame::{GROUPS, RAW_PER_GROUP};
use proptest::prelude::*;

extern crate std;
use std::vec::Vec;

/// A frame whose content is a deterministic function of `seed` (SplitMix64), so that frames differ everywhere.
fn frame(seq: u16, seed: u64) -> FrameRepr {
    let mut s = seed;
    let mut next = || {
        s = s.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = s;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        (z ^ (z >> 31)) as u16
    };
    let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
    raw.as_flattened_mut().iter_mut().for_each(|c| *c = next());
    FrameRepr {
        seq,
        decimation: 15,
        temp_cdeg: Some(next() as i16),
        raw,
    }
}

fn decode_all(dec: &mut FrameDecoder, stream: &[u8], chunks: &[usize]) -> Vec<Decoded> {
    let mut out = Vec::new();
    let mut rest = stream;
    let mut sizes = chunks.iter().cycle();
    while !rest.is_empty() {
        let n = (*sizes.next().unwrap_or(&1)).clamp(1, rest.len());
        let (mut chunk, tail) = rest.split_at(n);
        rest = tail;
        while let Some(d) = dec.decode(&mut chunk) {
            out.push(d);
        }
        assert!(chunk.is_empty());
    }
    out
}

/// `decode_with` lends a frame only when it accepts one: a partial frame, garbage and a damaged frame are not lent;
/// the lent view is the frame, whether it lay in the input or (split across calls) in the decoder's buffer.
#[test]
fn decode_with_lends_only_accepted_frames() {
    let (a, b) = (frame(1, 11).to_bytes(), frame(2, 22).to_bytes());
    let mut bad = frame(3, 33).to_bytes();
    bad[100] ^= 0x10;
    let mut dec = FrameDecoder::new();
    let mut lent = Vec::new();
    let mut push = |dec: &mut FrameDecoder, mut input: &[u8]| {
        while let Some(gap) = dec.decode_with(&mut input, |f| lent.push(FrameRepr::parse(f))) {
            assert_eq!(gap, SeqGap::default());
        }
        assert!(input.is_empty());
    };
    push(&mut dec, &a);
    push(&mut dec, &b[..100]);
    push(&mut dec, &[0x55u8; 300]);
    push(&mut dec, &bad);
    push(&mut dec, &b[..100]);
    push(&mut dec, &b[100..]);
    assert_eq!(lent, [Ok(frame(1, 11)), Ok(frame(2, 22))]);
    // The partial frame completed by the garbage, and the damaged frame.
    assert_eq!(dec.counters().crc_errors, 2);
}

#[test]
fn clean_stream_any_chunking() {
    let frames: Vec<FrameRepr> = (0..20).map(|i| frame(i, u64::from(i))).collect();
    let stream: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes()).collect();
    for chunk in [1, 2, 3, 7, 239, 240, 241, 480, 5000] {
        let mut dec = FrameDecoder::new();
        let got = decode_all(&mut dec, &stream, &[chunk]);
        assert_eq!(
            got.iter().map(|d| d.frame).collect::<Vec<_>>(),
            frames,
            "chunk {chunk}"
        );
        assert_eq!(
            dec.counters(),
            &LinkCounters {
                frames: 20,
                ..Default::default()
            }
        );
    }
}

#[test]
fn one_flipped_bit_costs_one_frame_and_is_counted() {
    let frames: Vec<FrameRepr> = (0..5).map(|i| frame(i, 100 + u64::from(i))).collect();
    let mut stream: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes()).collect();
    stream[2 * FRAME_LEN + 100] ^= 0x04; // payload of frame 2
    let mut dec = FrameDecoder::new();
    let got = decode_all(&mut dec, &stream, &[1]);
    let seqs: Vec<u16> = got.iter().map(|d| d.frame.seq).collect();
    assert_eq!(seqs, [0, 1, 3, 4]);
    assert_eq!(got[2].gap.missing_before, 1);
    let c = dec.counters();
    assert_eq!(
        (c.frames, c.crc_errors, c.resyncs, c.frames_dropped),
        (4, 1, 1, 1)
    );
    assert_eq!(c.bytes_skipped, FRAME_LEN as u32);
}

#[test]
fn dropped_byte_keeps_the_next_frame() {
    let frames: Vec<FrameRepr> = (0..4).map(|i| frame(i, 7 + u64::from(i))).collect();
    let mut stream: Vec<u8> = frames.iter().flat_map(|f| f.to_bytes()).collect();
    stream.remove(FRAME_LEN + 50); // frame 1 becomes 239 bytes
    let mut dec = FrameDecoder::new();
    let seqs: Vec<u16> = decode_all(&mut dec, &stream, &[240])
        .iter()
        .map(|d| d.frame.seq)
        .collect();
    assert_eq!(seqs, [0, 2, 3]);
    assert_eq!(dec.counters().bytes_skipped, (FRAME_LEN - 1) as u32);
}

#[test]
fn leading_garbage_and_sequence_restart() {
    let mut stream = std::vec![0x1A, 0xCF, 0x00, 0x55];
    stream.extend(frame(10, 1).to_bytes());
    stream.extend(frame(11, 2).to_bytes());
    stream.extend(frame(2, 3).to_bytes()); // FPGA restarted
    stream.extend(frame(5, 4).to_bytes()); // 3 and 4 lost
    let mut dec = FrameDecoder::new();
    let got = decode_all(&mut dec, &stream, &[3]);
    assert_eq!(got.len(), 4);
    let c = dec.counters();
    assert_eq!(
        (c.bytes_skipped, c.resyncs, c.seq_restarts, c.frames_dropped),
        (4, 1, 1, 2)
    );
}

#[derive(Debug, Clone)]
enum Damage {
    None,
    Flip { at: usize, bit: u8 },
    Drop { at: usize },
    Insert { at: usize, byte: u8 },
    GarbageBefore(Vec<u8>),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        6 => Just(Damage::None),
        1 => (0..FRAME_LEN, 0u8..8).prop_map(|(at, bit)| Damage::Flip { at, bit }),
        1 => (0..FRAME_LEN).prop_map(|at| Damage::Drop { at }),
        1 => (0..=FRAME_LEN, any::<u8>()).prop_map(|(at, byte)| Damage::Insert { at, byte }),
        1 => proptest::collection::vec(any::<u8>(), 1..300).prop_map(Damage::GarbageBefore),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Every undamaged frame comes out, in order, and nothing else: the decoder loses only damaged frames.
    #[test]
    fn damaged_streams_lose_only_damaged_frames(
        seed in any::<u64>(),
        damages in proptest::collection::vec(damage(), 1..40),
        chunks in proptest::collection::vec(1usize..700, 1..8),
    ) {
        let mut stream = Vec::new();
        let mut frames = Vec::new();
        for (i, d) in damages.iter().enumerate() {
            let f = frame(i as u16, seed ^ i as u64);
            let mut bytes = f.to_bytes().to_vec();
            match d {
                Damage::None => {}
                Damage::Flip { at, bit } => bytes[*at] ^= 1 << bit,
                Damage::Drop { at } => _ = bytes.remove(*at),
                Damage::Insert { at, byte } => bytes.insert(*at, *byte),
                Damage::GarbageBefore(g) => stream.extend_from_slice(g),
            }
            frames.push(f);
            stream.extend(bytes);
        }
        // Expected: exactly the frames whose 240 bytes are intact, in order, in the stream. (Damage can cancel out:
        // a dropped first sync byte right after an inserted 0x1A leaves the frame whole.)
        let mut expected = Vec::new();
        let mut from = 0;
        for f in &frames {
            let b = f.to_bytes();
            if let Some(at) = stream[from..].windows(FRAME_LEN).position(|w| w == b) {
                expected.push(*f);
                from += at + FRAME_LEN;
            }
        }
        let mut dec = FrameDecoder::new();
        let got: Vec<FrameRepr> = decode_all(&mut dec, &stream, &chunks).into_iter().map(|d| d.frame).collect();
        prop_assert_eq!(got, expected.clone());
        prop_assert_eq!(dec.counters().frames as usize, expected.len());
    }
}

#[test]
fn damage_that_cancels_out_leaves_the_frame_whole() {
    // Frame 0 gains a trailing 0x1A, frame 1 loses its first byte (0x1A): frame 1's bytes are intact again.
    let frames: Vec<FrameRepr> = (0..3).map(|i| frame(i, 77 + u64::from(i))).collect();
    let mut stream = frames[0].to_bytes().to_vec();
    stream.push(0x1A);
    stream.extend_from_slice(&frames[1].to_bytes()[1..]);
    stream.extend_from_slice(&frames[2].to_bytes());
    let mut dec = FrameDecoder::new();
    let got: Vec<FrameRepr> = decode_all(&mut dec, &stream, &[7])
        .into_iter()
        .map(|d| d.frame)
        .collect();
    assert_eq!(got, frames);
}
