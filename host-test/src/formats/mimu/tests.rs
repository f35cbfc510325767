use super::*;
use proptest::prelude::*;

fn frame(packet: u16, timestamp: u32, seed: i16) -> Frame {
    Frame {
        packet,
        timestamp,
        imu: core::array::from_fn(|i| {
            let k = seed.wrapping_mul(31).wrapping_add(i as i16 * 7);
            ImuSample {
                acc: [k, k.wrapping_add(2048), k.wrapping_sub(-32768i16)],
                gyro: [-k, i16::MAX, i16::MIN],
            }
        }),
    }
}

/// `n` consecutive frames starting at `packet0`, `ts0`.
fn frames(n: usize, packet0: u16, ts0: u32) -> Vec<Frame> {
    (0..n)
        .map(|i| {
            frame(
                packet0.wrapping_add(i as u16),
                ts0.wrapping_add((i as u32).wrapping_mul(TICKS_PER_SAMPLE)),
                i as i16,
            )
        })
        .collect()
}

fn stream(frames: &[Frame]) -> Vec<u8> {
    let mut b = ACK.to_vec();
    for f in frames {
        b.extend_from_slice(&f.encode());
    }
    b
}

#[test]
fn encode_decode_roundtrip_and_field_layout() {
    let f = frame(0x1974, 0x6471_0878, -35);
    let b = f.encode();
    assert_eq!(b[0], 0xAA);
    assert_eq!(&b[1..3], &[0x19, 0x74]);
    assert_eq!(b[3], 100);
    assert_eq!(&b[4..8], &[0x64, 0x71, 0x08, 0x78]);
    assert_eq!(Frame::decode(&b), Ok(f));
    assert_eq!(
        u16::from_be_bytes([b[104], b[105]]),
        checksum(&b[..104]),
        "checksum = byte sum mod 2^16"
    );
}

#[test]
fn first_frame_of_exp1_decodes() {
    // The first 106 bytes after the acknowledgement of exp_1 (IMU 1 acc = [-35, -1970, 618]).
    let hex = "aa19746471087 85affddf84e026affe8fffcfffd075affdafd20ffff0000ffffffcef8770240ffe2ffe8000f\
               0783ffd5fcfb0018fffe001affcff8500293fff1fffbfffd0757ffd1fcee001d000e0001ffdaf86c024dffedffe4\
               fff9075effcbfcd50003fff600103eae";
    let hex: String = hex.chars().filter(|c| !c.is_whitespace()).collect();
    let bytes: Vec<u8> = (0..hex.len() / 2)
        .map(|i| u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).unwrap())
        .collect();
    assert_eq!(bytes.len(), FRAME_LEN);
    let f = Frame::decode(&bytes).unwrap();
    assert_eq!(f.packet, 6516);
    assert_eq!(f.timestamp, 1_896_380_506);
    assert_eq!(f.imu[0].acc, [-35, -1970, 618]);
    assert_eq!(f.imu[0].gyro, [-24, -4, -3]);
    assert_eq!(f.imu[1].acc, [1882, -38, -736]);
}

#[test]
fn frame_errors() {
    let b = frame(1, 2, 3).encode();
    assert_eq!(Frame::decode(&b[..50]), Err(FrameError::Short { len: 50 }));
    let mut c = b;
    c[0] = 0xAB;
    assert_eq!(Frame::decode(&c), Err(FrameError::Header { found: 0xAB }));
    let mut c = b;
    c[3] = 99;
    assert_eq!(
        Frame::decode(&c),
        Err(FrameError::PayloadSize { found: 99 })
    );
    let mut c = b;
    c[50] ^= 1;
    assert!(matches!(
        Frame::decode(&c),
        Err(FrameError::Checksum { .. })
    ));
}

#[test]
fn clean_stream_with_packet_and_timestamp_wraps() {
    let fs = frames(50, 65_530, u32::MAX - 3 * TICKS_PER_SAMPLE);
    let rec = parse(&stream(&fs)).unwrap();
    assert_eq!(rec.frames, fs);
    let s = &rec.stats;
    assert!(s.ack);
    assert_eq!(s.frames, 50);
    assert_eq!(s.bytes_skipped, 0);
    assert_eq!(s.packet_gaps, 0, "65535 → 0 is not a gap");
    assert_eq!(s.timestamp_wraps, 1);
    assert_eq!(s.timestamp_jumps, 0);
    assert!(s.events.is_empty());
    assert_eq!(rec.ticks[49], 49 * u64::from(TICKS_PER_SAMPLE));
    assert!((rec.duration_s() - 49.0 / 62.5).abs() < 1e-12);
    assert!(rec.discontinuity.iter().all(|&d| !d));
    assert_eq!(rec.offsets[1], 4 + FRAME_LEN);
}

#[test]
fn packet_gap_and_long_gap_unwrap() {
    // 10 frames, then 5000 lost frames (80 s, more than one timestamp period of 67 s), then 10 more.
    let mut fs = frames(10, 100, 7);
    let later = frames(
        10,
        100 + 5010,
        7u32.wrapping_add(5010u32.wrapping_mul(TICKS_PER_SAMPLE)),
    );
    fs.extend_from_slice(&later);
    let rec = parse(&stream(&fs)).unwrap();
    let s = &rec.stats;
    assert_eq!(s.packet_gaps, 1);
    assert_eq!(s.packets_missing, 5000);
    assert_eq!(s.timestamp_wraps, 1);
    assert_eq!(rec.ticks[10], 5010 * u64::from(TICKS_PER_SAMPLE));
    assert!(rec.discontinuity[10]);
    assert_eq!(
        s.events,
        vec![ParseEvent {
            offset: 4 + 10 * FRAME_LEN,
            kind: EventKind::PacketGap {
                expected: 110,
                found: 5110
            }
        }]
    );
}

#[test]
fn corrupted_byte_resyncs_with_offsets() {
    let fs = frames(6, 0, 0);
    let mut b = stream(&fs);
    let bad = 4 + 2 * FRAME_LEN + 40; // inside frame 2
    b[bad] ^= 0x5A;
    let rec = parse(&b).unwrap();
    let s = &rec.stats;
    assert_eq!(s.frames, 5);
    assert_eq!(s.checksum_failures, 1);
    assert_eq!(s.bytes_skipped, FRAME_LEN);
    assert_eq!(s.resyncs, 1);
    assert_eq!(s.packet_gaps, 1);
    assert_eq!(s.packets_missing, 1);
    assert_eq!(
        s.events[0],
        ParseEvent {
            offset: 4 + 2 * FRAME_LEN,
            kind: EventKind::Checksum {
                stored: u16::from_be_bytes([b[4 + 3 * FRAME_LEN - 2], b[4 + 3 * FRAME_LEN - 1]]),
                computed: checksum(&b[4 + 2 * FRAME_LEN..4 + 3 * FRAME_LEN - 2]),
            }
        }
    );
    assert_eq!(
        s.events[1],
        ParseEvent {
            offset: 4 + 2 * FRAME_LEN,
            kind: EventKind::Skipped { len: FRAME_LEN }
        }
    );
    assert!(rec.discontinuity[2]);
    // Strict mode reports the first problem with its offset.
    match parse_with(
        &b,
        &ParseOptions {
            strict: true,
            ..Default::default()
        },
    ) {
        Err(MimuError::Anomaly(ev)) => {
            assert_eq!(ev.offset, 4 + 2 * FRAME_LEN);
            assert!(ev.to_string().starts_with("byte 216: frame checksum"));
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn garbage_prefix_missing_ack_and_truncated_tail() {
    let fs = frames(4, 9, 9);
    let mut b = vec![0x00, 0xAA, 0x13, 0xAA, 0x00, 0x64, 0xFF];
    for f in &fs {
        b.extend_from_slice(&f.encode());
    }
    b.extend_from_slice(&fs[0].encode()[..83]);
    let rec = parse(&b).unwrap();
    let s = &rec.stats;
    assert!(!s.ack);
    assert_eq!(rec.frames, fs);
    assert_eq!(s.truncated_tail, 83);
    assert_eq!(s.bytes_skipped, 7 + 83);
    assert_eq!(s.events[0].kind, EventKind::MissingAck);
    assert_eq!(
        s.events[1],
        ParseEvent {
            offset: 0,
            kind: EventKind::Skipped { len: 7 }
        }
    );
    assert_eq!(
        s.events.last(),
        Some(&ParseEvent {
            offset: 7 + 4 * FRAME_LEN,
            kind: EventKind::Truncated { len: 83 }
        })
    );
    let strict = ParseOptions {
        strict: true,
        ..Default::default()
    };
    let err = parse_with(&b, &strict).unwrap_err();
    assert!(matches!(
        err,
        MimuError::Anomaly(ParseEvent {
            offset: 0,
            kind: EventKind::MissingAck
        })
    ));
}

#[test]
fn bad_files_give_errors_not_panics() {
    assert!(matches!(
        parse(&[]),
        Err(MimuError::NoFrames { len: 0, .. })
    ));
    assert!(matches!(
        parse(&ACK),
        Err(MimuError::NoFrames { len: 4, .. })
    ));
    let text = b"this is not a MIMU4444 recording\n".repeat(20);
    let e = parse(&text).unwrap_err();
    assert!(e.to_string().contains("no valid MIMU4444 frame"), "{e}");
    // One good frame in a lot of garbage: too much skipped.
    let mut b = vec![0u8; 1000];
    b.extend_from_slice(&frame(1, 1, 1).encode());
    let e = parse(&b).unwrap_err();
    assert!(
        matches!(e, MimuError::TooMuchSkipped { skipped: 1000, .. }),
        "{e}"
    );
    assert!(e.to_string().contains("bytes 0..1000"), "{e}");
    let e = read("/nonexistent/mimu.bin").unwrap_err();
    assert!(matches!(e, MimuError::Io { .. }));
}

#[test]
fn timestamp_jump_is_reported() {
    let mut fs = frames(5, 0, 0);
    fs[3].timestamp = fs[3].timestamp.wrapping_add(5 * TICKS_PER_SAMPLE);
    fs[4].timestamp = fs[4].timestamp.wrapping_add(5 * TICKS_PER_SAMPLE);
    let rec = parse(&stream(&fs)).unwrap();
    assert_eq!(rec.stats.timestamp_jumps, 1);
    assert!(matches!(
        rec.stats.events[0].kind,
        EventKind::TimestampJump { .. }
    ));
}

/// Brute force: every single-byte corruption (three values) of a short stream. Never panics, recovers every
/// frame but the one hit, and never invents a frame.
#[test]
fn every_single_byte_corruption() {
    let fs = frames(4, 500, 123_456);
    let clean = stream(&fs);
    for at in 0..clean.len() {
        for x in [0x01u8, 0x80, 0xFF] {
            let mut b = clean.clone();
            b[at] ^= x;
            let Ok(rec) = parse(&b) else {
                panic!("corruption at {at} lost everything")
            };
            assert!(
                rec.frames.len() >= 3,
                "at {at}: {} frames",
                rec.frames.len()
            );
            assert!(
                rec.frames.iter().all(|f| fs.contains(f)),
                "at {at}: invented a frame"
            );
            let s = &rec.stats;
            assert_eq!(
                usize::from(s.ack) * 4 + s.frames * FRAME_LEN + s.bytes_skipped,
                b.len(),
                "at {at}: byte accounting"
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Arbitrary bytes: never panics; when frames come out, the byte accounting holds.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2000)) {
        for strict in [false, true] {
            let opts = ParseOptions { strict, max_skipped_fraction: 1.0 };
            if let Ok(rec) = parse_with(&bytes, &opts) {
                let s = &rec.stats;
                prop_assert_eq!(usize::from(s.ack) * 4 + s.frames * FRAME_LEN + s.bytes_skipped, bytes.len());
                prop_assert_eq!(rec.frames.len(), rec.ticks.len());
            }
        }
    }

    /// A valid stream with random corruptions (overwrites, deletions, insertions): never panics, ticks never
    /// decrease, each edit costs at most two frames, and frames that are not original are at most one per two
    /// edits (a byte-sum checksum cannot see two compensating changes in one frame, e.g. +28 in one byte and −28
    /// in another; single edits never fool it, see `every_single_byte_corruption`).
    #[test]
    fn corrupted_stream_recovers(
        n in 1usize..30,
        edits in proptest::collection::vec((any::<u16>(), any::<u8>(), 0u8..3), 0..12),
        ts0 in any::<u32>(),
        p0 in any::<u16>(),
    ) {
        let fs = frames(n, p0, ts0);
        let mut b = stream(&fs);
        let n_edits = edits.len();
        for (at, v, kind) in edits {
            if b.is_empty() { break; }
            let at = usize::from(at) % b.len();
            match kind {
                0 => b[at] = v,
                1 => { b.remove(at); }
                _ => b.insert(at, v),
            }
        }
        if let Ok(rec) = parse_with(&b, &ParseOptions { strict: false, max_skipped_fraction: 1.0 }) {
            let invented = rec.frames.iter().filter(|f| !fs.contains(f)).count();
            prop_assert!(invented <= n_edits / 2, "{} invented frames from {} edits", invented, n_edits);
            prop_assert!(rec.frames.len() + 2 * n_edits >= n);
            let originals: Vec<&Frame> = rec.frames.iter().filter(|f| fs.contains(f)).collect();
            prop_assert!(originals.windows(2).all(|w| fs.iter().position(|g| g == w[0]) < fs.iter().position(|g| g == w[1])), "out of order");
            prop_assert!(rec.ticks.windows(2).all(|w| w[0] <= w[1]));
            let s = &rec.stats;
            prop_assert_eq!(usize::from(s.ack) * 4 + s.frames * FRAME_LEN + s.bytes_skipped, b.len());
        }
    }
}

/// The real recordings (skipped when `shared/data/mimu4444` is absent).
#[test]
fn real_recordings_parse_cleanly() {
    let Some(dir) = crate::calibrate::data::mimu4444_dir() else {
        eprintln!("skipped: MIMU4444 data not found");
        return;
    };
    for e in 1..=6 {
        let rec = read(dir.join(format!("exp_{e}/data.bin"))).unwrap();
        let s = &rec.stats;
        assert!(s.ack);
        assert!(
            (37_000..40_000).contains(&s.frames),
            "exp_{e}: {}",
            s.frames
        );
        assert_eq!(s.checksum_failures, 0);
        assert_eq!(s.packet_gaps, 0);
        assert_eq!(s.timestamp_wraps, 9, "exp_{e}");
        assert_eq!(s.timestamp_jumps, 0, "exp_{e}");
        assert_eq!(s.truncated_tail, if e == 1 { 83 } else { 0 }, "exp_{e}");
        assert_eq!(s.bytes_skipped, s.truncated_tail);
        let dur = rec.duration_s();
        assert!(
            (dur - (s.frames - 1) as f64 / SAMPLE_RATE_HZ).abs() < 0.1,
            "exp_{e}: {dur}"
        );
    }
}
