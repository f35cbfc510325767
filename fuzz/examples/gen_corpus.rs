//! Writes the seed corpus `corpus/<target>/seed-*` from real encoded messages and frames.
//!
//! Run from `fuzz/`: `cargo run --release --example gen_corpus`. The byte-level targets (`messages`,
//! `mimu_reader`, `csv_reader`) get the encodings themselves; the structured targets (`arbitrary` inputs) get
//! `'R' ++ bytes`, their raw form (a link/bus stream, a flash image, link bytes and a command), which libFuzzer
//! then mutates into structured inputs as well.
//! The `update` target's seeds (`seed-fuzzed-*`) are not written here: they are inputs a fuzzing run reached
//! (opened, erased, chunks written), kept in git because that target's `arbitrary` input has no raw form.

use host_test::formats::csv::{Column, Recording, SensorKind};
use host_test::formats::mimu::{ACK, Frame, ImuSample, TICKS_PER_SAMPLE};
use shared::bus::csp::{CspHeader, CspPacket, FLAG_CRC32, PORT_PING};
use shared::bus::{BusConfig, MAX_WIRE_FRAME};
use shared::calib::{CalibrationTable, encoded_len_max};
use shared::fuse::{FaultCounts, FusionMode};
use shared::telemetry::{
    self, Ack, CalSource, Command, CommandEnvelope, FaultReport, FusedReport, HealthReport,
    MAX_MESSAGE_LEN, Reject, Telemetry,
};
use shared::wire::LinkCounters;
use shared::wire::frame::{FrameRepr, GROUPS, RAW_PER_GROUP};
use std::fs;
use std::path::Path;

fn put(target: &str, name: &str, bytes: &[u8]) {
    let dir = Path::new("corpus").join(target);
    fs::create_dir_all(&dir).unwrap();
    fs::write(dir.join(format!("seed-{name}")), bytes).unwrap();
}

fn raw(bytes: &[u8]) -> Vec<u8> {
    let mut v = vec![b'R'];
    v.extend_from_slice(bytes);
    v
}

fn enc<T: serde::Serialize>(m: &T) -> Vec<u8> {
    let mut buf = [0u8; MAX_MESSAGE_LEN];
    telemetry::encode(m, &mut buf).unwrap().to_vec()
}

fn frame(seq: u16) -> FrameRepr {
    let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
    for (g, codes) in raw.iter_mut().enumerate() {
        for (ch, c) in codes.iter_mut().enumerate() {
            *c = if ch < 4 { 19_680 } else { 24_000 } + (g * 7 + ch) as u16;
        }
    }
    FrameRepr {
        seq,
        decimation: 15,
        temp_cdeg: Some(2150),
        raw,
    }
}

fn main() {
    let table = messages();
    let frames = wire_decoder();
    bus();
    storage(&table);
    pipeline(&frames);
    mimu_reader();
    csv_reader();
}

/// `messages`: `[kind] ++` an encoded telemetry message, command or calibration table; returns the table's bytes.
fn messages() -> Vec<u8> {
    let fused = Telemetry::Fused(FusedReport {
        seq: 7,
        t_us: 1_000_000,
        frames: 32,
        rate_udps: [1, -2, 3],
        accel_ug: [0, 0, 1_000_000],
        used: [16; 6],
        health: Default::default(),
        temp_cdeg: Some(2150),
        unix_us: Some(1_795_996_800_000_000),
    });
    let health = Telemetry::Health(HealthReport {
        uptime_ms: 123_456,
        link: LinkCounters {
            frames: 1000,
            crc_errors: 2,
            ..Default::default()
        },
        cal_id: 5,
        cal_source: CalSource::Uploaded,
        decimation: Some(15),
        frames_per_output: 32,
        fusion: FusionMode::InverseVariance,
        robust: true,
        faults: [FaultCounts::default(); 2],
        invalid_frames: 0,
        allan_samples: 4096,
        telemetry_dropped: 0,
        commands: [3, 1],
        temp: Default::default(),
        thermal_at_cdeg: Some(2_150),
    });
    let faults = Telemetry::Faults(FaultReport {
        group: 3,
        gyro: FaultCounts {
            saturated: 1,
            stuck: 0,
            outlier: 2,
        },
        accel: FaultCounts::default(),
    });
    let ack = Telemetry::Ack(Ack {
        tag: 300,
        result: Err(Reject::CalOffset(192)),
    });
    for (i, t) in [fused, health, faults, ack].iter().enumerate() {
        let mut b = vec![0];
        b.extend(enc(t));
        put("messages", &format!("telemetry-{i}"), &b);
    }
    let table = {
        let mut t = CalibrationTable::<GROUPS>::factory();
        t.cal_id = 42;
        t.groups[3].gyro_bias_q12[1] = -12_345;
        t
    };
    let mut tbuf = [0u8; encoded_len_max(GROUPS)];
    let tbytes = table.encode(&mut tbuf).unwrap().to_vec();
    let cmds = [
        Command::Ping,
        Command::SetDecimation(15),
        Command::SetOutputRate(32),
        Command::SetFusion {
            mode: FusionMode::Equal,
            robust: false,
        },
        Command::CalBegin {
            len: tbytes.len() as u16,
            crc: shared::crc::crc32c(&tbytes),
        },
        Command::CalChunk {
            offset: 0,
            data: heapless::Vec::from_slice(&tbytes[..64]).unwrap(),
        },
        Command::CalCommit,
        Command::AllanRequest { first: 0, count: 6 },
        Command::AllanReset,
        Command::HealthRequest { detail: true },
    ];
    for (i, c) in cmds.iter().enumerate() {
        let mut b = vec![1];
        b.extend(enc(&CommandEnvelope {
            tag: i as u16 + 1,
            cmd: c.clone(),
        }));
        put("messages", &format!("command-{i}"), &b);
    }
    let mut b = vec![3];
    b.extend(&tbytes);
    put("messages", "caltable", &b);
    tbytes
}

/// `wire_decoder`: three frames, clean and damaged; returns the clean ones. (The structured targets take
/// `'R' ++ bytes` as their raw form: see each target's `Input::raw`.)
fn wire_decoder() -> Vec<u8> {
    let frames: Vec<u8> = (0..3u16).flat_map(|s| frame(s).to_bytes()).collect();
    put("wire_decoder", "three-frames", &raw(&frames));
    let mut noisy = vec![0x55; 10];
    noisy.extend(&frames);
    noisy[40] ^= 0xFF;
    put("wire_decoder", "damaged", &raw(&noisy));
    frames
}

/// `bus`: KISS-framed CSP packets (a command, a ping with CRC, another port).
fn bus() {
    let cfg = BusConfig::DEFAULT;
    let mut out = [0u8; MAX_WIRE_FRAME];
    let mut bus = Vec::new();
    for (dport, flags, payload) in [
        (
            cfg.command_port,
            0,
            enc(&CommandEnvelope {
                tag: 1,
                cmd: Command::Ping,
            }),
        ),
        (PORT_PING, FLAG_CRC32, b"ping".to_vec()),
        (20, 0, b"other port".to_vec()),
    ] {
        let h = CspHeader {
            prio: 2,
            src: cfg.ground_addr,
            dst: cfg.addr,
            dport,
            sport: 30,
            flags,
        };
        let n = CspPacket::emit_kiss(&h, cfg.version, &payload, &mut out).unwrap();
        bus.extend_from_slice(&out[..n]);
    }
    put("bus", "packets", &raw(&bus));
}

/// `storage`: a flash image whose slot A holds record seq u32::MAX - 1 and slot B record seq u32::MAX (the next
/// store wraps to 0), both of the calibration table `tbytes`.
fn storage(tbytes: &[u8]) {
    // A flash image: slot A holds record seq u32::MAX - 1, slot B record seq u32::MAX (the next store wraps to 0).
    let mut image = vec![0xFF; 2 * 3 * 1024];
    for (slot, seq) in [(0usize, u32::MAX - 1), (1, u32::MAX)] {
        let mut rec = Vec::new();
        rec.extend(shared::storage::MAGIC.to_le_bytes());
        rec.extend(seq.to_le_bytes());
        rec.extend((tbytes.len() as u32).to_le_bytes());
        rec.extend(tbytes);
        let crc = shared::crc::crc32c(&rec);
        rec.extend(crc.to_le_bytes());
        let base = slot * 3 * 1024;
        image[base..base + rec.len()].copy_from_slice(&rec);
    }
    // Trailing erased bytes are implied: keep the seed small.
    let used = image.iter().rposition(|&b| b != 0xFF).map_or(0, |i| i + 1);
    put("storage", "two-records-at-wrap", &raw(&image[..used]));
}

/// `pipeline`: frames, then a command.
fn pipeline(frames: &[u8]) {
    let mut pipe = (frames.len() as u16).to_le_bytes().to_vec();
    pipe.extend(frames);
    pipe.extend(enc(&CommandEnvelope {
        tag: 9,
        cmd: Command::HealthRequest { detail: true },
    }));
    put("pipeline", "frames-and-command", &raw(&pipe));
}

/// `mimu_reader`: the MIMU4444's acknowledgement, then consecutive frames.
fn mimu_reader() {
    let mut mimu = ACK.to_vec();
    for k in 0..4u16 {
        let f = Frame {
            packet: 100 + k,
            timestamp: 5_000 + u32::from(k) * TICKS_PER_SAMPLE,
            imu: core::array::from_fn(|i| ImuSample {
                acc: [i as i16, -(i as i16), 2048],
                gyro: [k as i16, 3, -4],
            }),
        };
        mimu.extend(f.encode());
    }
    put("mimu_reader", "ack-and-frames", &raw(&mimu));
}

/// `csv_reader`: interchange CSV written by the ground tool's own writer, and columns in another order.
fn csv_reader() {
    let rec = Recording {
        t_s: vec![0.0, 0.016, 0.032],
        temp_c: Some(vec![21.5, 21.5, 21.51]),
        columns: vec![
            Column {
                group: 0,
                kind: SensorKind::Gyro,
                axis: 0,
                data: vec![0.1, -0.2, 0.3],
            },
            Column {
                group: 0,
                kind: SensorKind::Accel,
                axis: 2,
                data: vec![1.0, 0.999, 1.001],
            },
            Column {
                group: 3,
                kind: SensorKind::Gyro,
                axis: 1,
                data: vec![-1e-6, 0.0, 2.5],
            },
        ],
    };
    let tmp = std::env::temp_dir().join("gen-corpus.csv");
    rec.write(&tmp).unwrap();
    put("csv_reader", "written", &fs::read(&tmp).unwrap());
    put(
        "csv_reader",
        "reordered",
        b"a00z,t,foo,g00x,temp_c\n1.5,0,7,0.25,20\n-1,0.1,8,0.5,20.5\n",
    );
}
