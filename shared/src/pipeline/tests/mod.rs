use super::*;
use crate::calib::{AZ, board};
use crate::crc::crc32c;
use crate::telemetry::{
    Ack, AllanReport, CAL_CHUNK_MAX, Command, CommandEnvelope, FaultReport, FusedReport, NavReport,
    PROTOCOL_VERSION, Reject, TimeReport, encode,
};
use crate::testutil::{Rng, rms};
use crate::wire::FrameRepr;
use crate::wire::clock::FPGA_BASE_RATE_MILLIHZ;
use crate::wire::frame::RAW_PER_GROUP;

extern crate std;
use std::vec::Vec;

mod time_and_commands;

/// A frame of the nominal board seeing `rate_dps` and `accel_g`, plus white noise of `noise_counts` on every ADC
/// channel.
fn frame(
    seq: u16,
    dec: u16,
    rate_dps: [f64; 3],
    accel_g: [f64; 3],
    noise_counts: f64,
    rng: &mut Rng,
) -> FrameRepr {
    let codes = board::nominal_codes(rate_dps, accel_g);
    let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
    for group in raw.iter_mut() {
        for (c, &x) in group.iter_mut().zip(&codes) {
            *c = (x + noise_counts * rng.normal())
                .round()
                .clamp(1.0, 65_534.0) as u16;
        }
    }
    FrameRepr {
        seq,
        decimation: dec,
        temp_cdeg: Some(2_150),
        raw,
    }
}

fn stream(frames: &[FrameRepr]) -> Vec<u8> {
    frames.iter().flat_map(FrameRepr::to_bytes).collect()
}

type HostPipeline = Pipeline<std::boxed::Box<PipelineMemory>>;

impl HostPipeline {
    fn new_boxed(config: PipelineConfig) -> Self {
        Pipeline::new(config, std::boxed::Box::new(PipelineMemory::new()))
    }
}

/// Everything the pipeline has to say now: queued outputs, then dump reports.
fn drain(p: &mut HostPipeline) -> Vec<Output> {
    let mut out: Vec<Output> = core::iter::from_fn(|| p.poll()).collect();
    out.extend(core::iter::from_fn(|| p.poll_dump()).map(Output::Telemetry));
    out
}

/// Feeds all bytes, draining outputs as `push_link` asks.
fn run(p: &mut HostPipeline, bytes: &[u8]) -> Vec<Output> {
    let mut out = Vec::new();
    let mut input = bytes;
    loop {
        p.push_link(&mut input);
        while let Some(o) = p.poll() {
            out.push(o);
        }
        if input.is_empty() {
            return out;
        }
    }
}

fn fused(outputs: &[Output]) -> Vec<FusedReport> {
    outputs
        .iter()
        .filter_map(|o| match o {
            Output::Telemetry(Telemetry::Fused(r)) => Some(*r),
            _ => None,
        })
        .collect()
}

/// A command's replies (returned by the call), then everything else the pipeline has to say now.
fn command(p: &mut HostPipeline, tag: u16, cmd: Command) -> Vec<Output> {
    let mut buf = [0u8; 256];
    let mut out = p
        .handle_command(encode(&CommandEnvelope { tag, cmd }, &mut buf).unwrap())
        .to_vec();
    out.extend(drain(p));
    out
}

fn ack(outputs: &[Output]) -> Ack {
    match outputs.first() {
        Some(Output::Telemetry(Telemetry::Ack(a))) => *a,
        other => panic!("expected an ack first, got {other:?}"),
    }
}

#[test]
fn noiseless_frames_give_exact_physical_values() {
    let mut rng = Rng::new(1);
    // 12.5 °/s about x, −3 °/s about z, 1 g along −z: exactly representable codes (160 counts per °/s).
    let frames: Vec<FrameRepr> = (0..64)
        .map(|i| frame(i, 15, [12.5, 0.0, -3.0], [0.0, 0.0, -1.0], 0.0, &mut rng))
        .collect();
    let mut p = Pipeline::new_boxed(PipelineConfig {
        health_every: 0,
        ..PipelineConfig::DEFAULT
    });
    let reports = fused(&run(&mut p, &stream(&frames)));
    assert_eq!(reports.len(), 2);
    let r = reports[1];
    assert_eq!(r.rate_udps, [12_500_000, 0, -3_000_000]);
    // 4800 counts × 853333 / 4096 µg per count = 999 999.6 µg → rounds to 1 000 000.
    assert_eq!(r.accel_ug, [0, 0, -1_000_000]);
    assert_eq!(
        (r.seq, r.frames, r.used, r.temp_cdeg),
        (1, 32, [16; 6], Some(2_150))
    );
    // Frame 32 starts the second interval: 32 × 16 base periods of 1/9676.8 s = 52 910.05 µs.
    assert_eq!(r.t_us, 52_910);
}

#[test]
fn averaging_reduces_noise_by_sqrt_l() {
    // White noise on every channel; L = 16 averaged frames vs every 16th frame (what a decimator keeps).
    let mut rng = Rng::new(2);
    let n = 16 * 1500;
    let frames: Vec<FrameRepr> = (0..n)
        .map(|i| frame(i as u16, 15, [0.0; 3], [0.0, 0.0, -1.0], 40.0, &mut rng))
        .collect();
    let bytes = stream(&frames);
    let cfg = PipelineConfig {
        health_every: 0,
        fusion: FusionConfig {
            robust: false,
            mode: crate::fuse::FusionMode::Equal,
            ..FusionConfig::DEFAULT
        },
        ..PipelineConfig::DEFAULT
    };
    let every = fused(&run(
        &mut Pipeline::new_boxed(PipelineConfig {
            frames_per_output: 1,
            ..cfg
        }),
        &bytes,
    ));
    let averaged = fused(&run(
        &mut Pipeline::new_boxed(PipelineConfig {
            frames_per_output: 16,
            ..cfg
        }),
        &bytes,
    ));
    let gx = |r: &[FusedReport]| {
        r.iter()
            .map(|r| f64::from(r.rate_udps[0]))
            .collect::<Vec<_>>()
    };
    let decimated: Vec<f64> = gx(&every).into_iter().step_by(16).collect();
    let (s1, s16, sdec) = (rms(&gx(&every)), rms(&gx(&averaged)), rms(&decimated));
    // Single frame: 40 counts × 6250 µ°/s / √16 sensors = 62 500 µ°/s.
    assert!((s1 / 62_500.0 - 1.0).abs() < 0.03, "per-frame {s1}");
    assert!(
        (s1 / s16 / 4.0 - 1.0).abs() < 0.05,
        "averaging gain {}",
        s1 / s16
    );
    assert!(
        (s1 / sdec - 1.0).abs() < 0.08,
        "decimation gain {}",
        s1 / sdec
    );
}

#[test]
fn time_and_tau0_follow_the_sequence_counter_and_decimation() {
    let mut rng = Rng::new(3);
    let mut frames: Vec<FrameRepr> = (0..10)
        .map(|i| frame(i, 15, [0.0; 3], [0.0; 3], 5.0, &mut rng))
        .collect();
    frames.retain(|f| f.seq != 4 && f.seq != 5); // two frames lost
    let mut p = Pipeline::new_boxed(PipelineConfig {
        frames_per_output: 1,
        health_every: 0,
        ..PipelineConfig::DEFAULT
    });
    let r = fused(&run(&mut p, &stream(&frames)));
    assert_eq!(r.len(), 8);
    assert_eq!(r[4].t_us, (6 * 16 * 1_000_000_000u64) / 9_676_800); // frame 6 at 6 × 16 base periods
    assert_eq!(p.link_counters().frames_dropped, 2);
    assert_eq!(p.tau0_ps(), Some(1_653_439_153)); // 16 / 9676.8 Hz
    assert_eq!(p.allan().samples(), 8);
    // A new decimation restarts the statistics.
    let more: Vec<FrameRepr> = (10..13)
        .map(|i| frame(i, 7, [0.0; 3], [0.0; 3], 5.0, &mut rng))
        .collect();
    run(&mut p, &stream(&more));
    assert_eq!(p.allan().samples(), 3);
    assert_eq!(p.tau0_ps(), Some(826_719_576));
}

#[test]
fn backpressure_loses_nothing() {
    let mut rng = Rng::new(4);
    let frames: Vec<FrameRepr> = (0..100)
        .map(|i| frame(i, 15, [0.0; 3], [0.0; 3], 5.0, &mut rng))
        .collect();
    let mut p = Pipeline::new_boxed(PipelineConfig {
        frames_per_output: 1,
        health_every: 1,
        ..PipelineConfig::DEFAULT
    });
    let bytes = stream(&frames);
    let mut input = &bytes[..];
    p.push_link(&mut input);
    assert!(
        !input.is_empty(),
        "push_link must stop before the outbox overflows"
    );
    let mut outputs = Vec::new();
    loop {
        while let Some(o) = p.poll() {
            outputs.push(o);
        }
        if input.is_empty() {
            break;
        }
        p.push_link(&mut input);
    }
    let healths = outputs
        .iter()
        .filter(|o| matches!(o, Output::Telemetry(Telemetry::Health(_))))
        .count();
    assert_eq!((fused(&outputs).len(), healths), (100, 100));
    assert_eq!(p.health().telemetry_dropped, 0);
}

#[test]
fn more_than_65536_outputs_without_periodic_health() {
    // health_every == 0 (health only on request): the u16 count of outputs since the last health report used to
    // grow without reset and overflowed at output 65,536 (a panic in this overflow-checked test build).
    const OUTPUTS: u32 = 65_536 + 100;
    let mut p = Pipeline::new_boxed(PipelineConfig {
        frames_per_output: 1,
        health_every: 0,
        ..PipelineConfig::DEFAULT
    });
    let f = frame(0, 15, [0.0; 3], [0.0, 0.0, 1.0], 0.0, &mut Rng::new(9));
    let (mut fused_reports, mut healths) = (0u32, 0u32);
    for first in (0..OUTPUTS).step_by(4096) {
        let bytes: Vec<u8> = (first..(first + 4096).min(OUTPUTS))
            .flat_map(|i| {
                let mut g = f;
                g.seq = i as u16;
                g.to_bytes()
            })
            .collect();
        for o in run(&mut p, &bytes) {
            match o {
                Output::Telemetry(Telemetry::Fused(_)) => fused_reports += 1,
                Output::Telemetry(Telemetry::Health(_)) => healths += 1,
                _ => {}
            }
        }
    }
    assert_eq!((fused_reports, healths), (OUTPUTS, 0));
    assert_eq!(p.link_counters().frames_dropped, 0);
    // Health on request still works.
    let out = command(&mut p, 7, Command::HealthRequest { detail: false });
    assert!(
        out.iter()
            .any(|o| matches!(o, Output::Telemetry(Telemetry::Health(_))))
    );
}

#[test]
fn commands_are_acknowledged_or_rejected_with_a_reason() {
    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    assert_eq!(
        ack(&command(&mut p, 1, Command::Ping)),
        Ack {
            tag: 1,
            result: Ok(())
        }
    );
    let out = command(&mut p, 2, Command::SetDecimation(511));
    assert_eq!(ack(&out).result, Ok(()));
    assert_eq!(out[1], Output::Fpga(FpgaControl::SetDecimation(511)));
    // The 2 Mbaud link carries 240-byte frames (2400 bits) up to 833 frames/s: N = 11 (806.4 /s) fits, N = 10
    // (879.7 /s) does not, and nothing goes to the FPGA.
    let out = command(&mut p, 2, Command::SetDecimation(11));
    assert_eq!(ack(&out).result, Ok(()));
    let out = command(&mut p, 2, Command::SetDecimation(10));
    assert_eq!(ack(&out).result, Err(Reject::BadArgument));
    assert_eq!(out.len(), 1);
    assert_eq!(
        ack(&command(&mut p, 2, Command::SetDecimation(0))).result,
        Err(Reject::BadArgument)
    );
    assert_eq!(
        ack(&command(&mut p, 3, Command::SetOutputRate(0))).result,
        Err(Reject::BadArgument)
    );
    assert_eq!(
        ack(&command(
            &mut p,
            4,
            Command::AllanRequest {
                first: 102,
                count: 1
            }
        ))
        .result,
        Err(Reject::BadArgument)
    );
    assert_eq!(
        ack(&command(&mut p, 5, Command::CalCommit)).result,
        Err(Reject::CalNotStarted)
    );
    assert_eq!(
        p.handle_command(&[9, 1, 2]).as_slice(),
        [Output::Telemetry(Telemetry::Ack(Ack {
            tag: 1,
            result: Err(Reject::Version(9))
        }))]
    );
    assert_eq!(
        p.handle_command(&[PROTOCOL_VERSION, 6, 77]).as_slice(),
        [Output::Telemetry(Telemetry::Ack(Ack {
            tag: 6,
            result: Err(Reject::Malformed)
        }))]
    );
    assert_eq!(
        p.poll(),
        None,
        "a command's replies never go through the outbox"
    );
    let h = p.health();
    assert_eq!(h.commands, [3, 7]);
    let out = command(&mut p, 7, Command::HealthRequest { detail: true });
    assert_eq!(out.len(), 2 + GROUPS);
    assert!(matches!(
        out[GROUPS + 1],
        Output::Telemetry(Telemetry::Faults(FaultReport { group: 15, .. }))
    ));
}

fn upload(p: &mut HostPipeline, bytes: &[u8], crc: u32) -> Vec<Output> {
    assert_eq!(
        ack(&command(
            p,
            10,
            Command::CalBegin {
                len: bytes.len() as u16,
                crc
            }
        ))
        .result,
        Ok(())
    );
    for (i, chunk) in bytes.chunks(CAL_CHUNK_MAX).enumerate() {
        let data = heapless::Vec::from_slice(chunk).unwrap();
        let cmd = Command::CalChunk {
            offset: (i * CAL_CHUNK_MAX) as u16,
            data,
        };
        assert_eq!(ack(&command(p, 11, cmd)).result, Ok(()));
    }
    command(p, 12, Command::CalCommit)
}

#[test]
fn calibration_upload_in_chunks() {
    let mut table = CalibrationTable::<GROUPS>::factory();
    table.cal_id = 42;
    table.groups[0].gyro_bias_q12[0] += 160 << 12; // group 0's gyro A x zero moves by 1 °/s
    let mut buf = [0u8; CAL_UPLOAD_MAX];
    let bytes = table.encode(&mut buf).unwrap().to_vec();
    assert!(bytes.len() > 2 * CAL_CHUNK_MAX);

    let mut p = Pipeline::new_boxed(PipelineConfig::DEFAULT);
    // Out of order, overflow and a wrong announced CRC are refused.
    command(
        &mut p,
        1,
        Command::CalBegin {
            len: bytes.len() as u16,
            crc: crc32c(&bytes),
        },
    );
    let late = Command::CalChunk {
        offset: 5,
        data: heapless::Vec::from_slice(&bytes[5..10]).unwrap(),
    };
    assert_eq!(
        ack(&command(&mut p, 2, late)).result,
        Err(Reject::CalOffset(0))
    );
    assert_eq!(
        ack(&command(&mut p, 3, Command::CalCommit)).result,
        Err(Reject::CalIncomplete)
    );
    let out = upload(&mut p, &bytes, crc32c(&bytes) ^ 1);
    assert_eq!(ack(&out).result, Err(Reject::CalIncomplete));
    // A damaged table with a matching upload CRC is refused by the table's own check.
    let mut damaged = bytes.clone();
    damaged[20] ^= 0x40;
    let out = upload(&mut p, &damaged, crc32c(&damaged));
    assert_eq!(
        ack(&out).result,
        Err(Reject::Cal(crate::calib::CalError::Crc))
    );
    assert_eq!(p.calibration_source(), CalSource::Factory);

    // A good commit: the table is in force at once, but the ack waits for the platform's store.
    let commands_before = p.health().commands;
    let out = upload(&mut p, &bytes, crc32c(&bytes));
    assert_eq!(out, [Output::PersistCalibration { tag: 12 }]);
    assert_eq!(p.calibration(), &table);
    let h = p.health();
    assert_eq!((h.cal_id, h.cal_source), (42, CalSource::Uploaded));
    // Begin and chunks counted, the commit not yet.
    let begin_and_chunks = 1 + bytes.len().div_ceil(CAL_CHUNK_MAX) as u32;
    assert_eq!(
        h.commands,
        [commands_before[0] + begin_and_chunks, commands_before[1]],
        "the commit is counted once the store is done"
    );
    assert_eq!(
        p.calibration_persisted(12, true),
        Ack {
            tag: 12,
            result: Ok(())
        }
    );
    assert_eq!(
        p.calibration_persisted(12, false).result,
        Err(Reject::Storage)
    );
    let h = p.health();
    assert_eq!(
        h.commands,
        [
            commands_before[0] + begin_and_chunks + 1,
            commands_before[1] + 1
        ]
    );
}

#[test]
fn allan_dump_reports_every_filled_level() {
    let mut rng = Rng::new(5);
    let frames: Vec<FrameRepr> = (0..300)
        .map(|i| frame(i, 15, [0.0; 3], [0.0; 3], 30.0, &mut rng))
        .collect();
    let mut p = Pipeline::new_boxed(PipelineConfig {
        health_every: 0,
        ..PipelineConfig::DEFAULT
    });
    run(&mut p, &stream(&frames));
    let out = command(
        &mut p,
        9,
        Command::AllanRequest {
            first: FUSED_CHANNEL0 as u8,
            count: 200,
        },
    );
    let reports: Vec<AllanReport> = out
        .iter()
        .filter_map(|o| match o {
            Output::Telemetry(Telemetry::Allan(r)) => Some(*r),
            _ => None,
        })
        .collect();
    // 300 samples: levels 0..=6 have differences (2^7 · 2 = 256 ≤ 300 → also 7): ⌊300/2^k⌋ ≥ 2 for k ≤ 7.
    assert_eq!(reports.len(), AXES * 8);
    let r = reports
        .iter()
        .find(|r| r.channel as usize == FUSED_CHANNEL0 + AZ && r.level.level == 3)
        .unwrap();
    assert_eq!(r.level, p.allan().level(FUSED_CHANNEL0 + AZ, 3).unwrap());
    assert_eq!(
        (r.samples, r.tau0_ps, r.level.count),
        (300, 1_653_439_153, 300 / 8 - 1)
    );
}

mod no_panic {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(300))]

        /// Any link bytes, any command bytes, any valid frames with arbitrary ADC codes (rails and extremes
        /// included): the pipeline never panics and keeps answering.
        #[test]
        fn arbitrary_input_never_panics(
            link in proptest::collection::vec(any::<u8>(), 0..2000),
            commands in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..80), 0..6),
            codes in proptest::collection::vec(any::<u16>(), RAW_PER_GROUP * GROUPS),
            decimation in any::<u16>(),
            fpo in 1u16..8,
        ) {
            let mut p = Pipeline::new_boxed(PipelineConfig { frames_per_output: fpo, health_every: 1, ..PipelineConfig::DEFAULT });
            let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
            raw.as_flattened_mut().copy_from_slice(&codes);
            let mut bytes = link.clone();
            for seq in 0..3u16 {
                bytes.extend_from_slice(&FrameRepr { seq, decimation, temp_cdeg: None, raw }.to_bytes());
            }
            bytes.extend_from_slice(&link);
            run(&mut p, &bytes);
            for c in &commands {
                let replies = p.handle_command(c);
                let first_is_ack = matches!(
                    replies.first(),
                    Some(Output::Telemetry(Telemetry::Ack(_)) | Output::PersistCalibration { .. })
                );
                prop_assert!(first_is_ack, "{:?}", replies);
                drain(&mut p);
            }
            command(&mut p, 1, Command::AllanRequest { first: 0, count: u8::MAX });
            prop_assert_eq!(ack(&command(&mut p, 2, Command::Ping)), Ack { tag: 2, result: Ok(()) });
        }
    }
}
