//! The whole flight core (`shared::pipeline::Pipeline`) as one state machine.
//!
//! Input: a sequence of operations: arbitrary link bytes, valid-CRC frames (structured ADC codes, sequence
//! numbers, decimation, temperature), damaged frames, arbitrary command bytes, well-formed commands, complete
//! calibration uploads (optionally corrupted), polls, dumps, link bytes dropped by the platform.
//! Properties:
//! * never panics (overflow checks on);
//! * the link counters and the health report's counters (commands accepted/refused, invalid frames, dropped
//!   telemetry) never decrease (no wrap is reachable in one run);
//! * every PPS edge is counted once, as accepted or refused;
//! * every command is acknowledged: the call returns an ack with its tag before anything else it produced (a
//!   commit's comes after the platform's store);
//! * a complete, correct upload of a valid table is accepted: the table is in force, its source is `Uploaded`
//!   and `PersistCalibration` is returned (alone: the commit's ack waits for the store); a corrupted one leaves the
//!   calibration unchanged;
//! * every queued telemetry message encodes within `MAX_MESSAGE_LEN` and decodes back to itself.
#![no_main]

#[path = "common/mod.rs"]
mod common;

use arbitrary::Arbitrary;
use common::FrameSpec;
use libfuzzer_sys::fuzz_target;
use shared::calib::{CalibrationTable, encoded_len_max};
use shared::crc::crc32c;
use shared::fuse::FusionMode;
use shared::pipeline::{Output, Pipeline, PipelineConfig, PipelineMemory};
use shared::telemetry::{
    self, Ack, CAL_CHUNK_MAX, CalSource, Command, CommandEnvelope, MAX_MESSAGE_LEN, Telemetry,
};
use shared::wire::frame::{FRAME_LEN, GROUPS};

#[derive(Arbitrary, Debug, Clone)]
enum Cmd {
    Ping,
    SetDecimation(u16),
    SetOutputRate(u16),
    SetFusion { equal: bool, robust: bool },
    CalBegin { len: u16, crc: u32 },
    CalChunk { offset: u16, data: Vec<u8> },
    CalCommit,
    AllanRequest { first: u8, count: u8 },
    AllanReset,
    HealthRequest { detail: bool },
    SetMode { idle: bool },
    ExcludeGroups { gyro: u32, accel: u32 },
    SetTime { unix_us: u64 },
}

impl Cmd {
    fn command(&self) -> Command {
        match self.clone() {
            Cmd::Ping => Command::Ping,
            Cmd::SetDecimation(n) => Command::SetDecimation(n),
            Cmd::SetOutputRate(n) => Command::SetOutputRate(n),
            Cmd::SetFusion { equal, robust } => Command::SetFusion {
                mode: if equal {
                    FusionMode::Equal
                } else {
                    FusionMode::InverseVariance
                },
                robust,
            },
            Cmd::CalBegin { len, crc } => Command::CalBegin { len, crc },
            Cmd::CalChunk { offset, data } => Command::CalChunk {
                offset,
                data: heapless::Vec::from_slice(&data[..data.len().min(CAL_CHUNK_MAX)]).unwrap(),
            },
            Cmd::CalCommit => Command::CalCommit,
            Cmd::AllanRequest { first, count } => Command::AllanRequest { first, count },
            Cmd::AllanReset => Command::AllanReset,
            Cmd::HealthRequest { detail } => Command::HealthRequest { detail },
            Cmd::SetMode { idle } => Command::SetMode(if idle {
                telemetry::Mode::Idle
            } else {
                telemetry::Mode::Stream
            }),
            Cmd::ExcludeGroups { gyro, accel } => Command::ExcludeGroups { gyro, accel },
            Cmd::SetTime { unix_us } => Command::SetTime { unix_us },
        }
    }
}

#[derive(Arbitrary, Debug)]
struct Upload {
    cal_id: u32,
    group: u8,
    bias: i32,
    gain: i16,
    raw_min: i16,
    /// Chunk sizes (cycled; 0 counts as 1).
    chunk_sizes: Vec<u8>,
    /// Corrupt one uploaded byte (index mod len, xor).
    corrupt: Option<(u16, u8)>,
    tag: u16,
}

#[derive(Arbitrary, Debug)]
enum Op {
    Link(Vec<u8>),
    Frames {
        first: FrameSpec,
        count: u8,
        seq_step: u8,
        split: u8,
    },
    Damaged {
        frame: FrameSpec,
        at: u8,
        xor: u8,
    },
    CommandBytes(Vec<u8>),
    Command {
        tag: u16,
        cmd: Cmd,
    },
    Upload(Upload),
    Poll(u8),
    Dump(u8),
    /// The platform dropped its buffered link bytes (`link_discarded`).
    LinkDiscarded,
    /// Arrival stamp for the frames that follow (`set_arrival_us`).
    Arrival(u64),
    /// A PPS edge (`pps`): arbitrary times, before or after `SetTime`.
    Pps(u64),
}

#[derive(Arbitrary, Debug)]
struct Input {
    frames_per_output: u8,
    health_every: u8,
    ops: Vec<Op>,
}

impl Input {
    /// Raw form: `[n lo, n hi] ++ link bytes (n) ++ command message` on the default configuration.
    fn raw(bytes: &[u8]) -> Self {
        let (n, rest) = match bytes {
            [a, b, rest @ ..] => (
                usize::from(u16::from_le_bytes([*a, *b])).min(rest.len()),
                rest,
            ),
            _ => (0, bytes),
        };
        let (link, cmd) = rest.split_at(n);
        Self {
            frames_per_output: 32,
            health_every: 1,
            ops: vec![
                Op::Link(link.to_vec()),
                Op::CommandBytes(cmd.to_vec()),
                Op::Poll(255),
                Op::Dump(255),
            ],
        }
    }
}

struct Run {
    p: Pipeline<Box<PipelineMemory>>,
    last: [u64; 12],
}

impl Run {
    fn check_monotonic(&mut self) {
        let h = self.p.health();
        let l = h.link;
        let now = [
            l.frames,
            l.crc_errors,
            l.resyncs,
            l.bytes_skipped,
            l.frames_dropped,
            l.seq_restarts,
            l.overruns,
            h.commands[0],
            h.commands[1],
            h.invalid_frames,
            h.telemetry_dropped,
            0,
        ]
        .map(u64::from);
        for (i, (a, b)) in self.last.iter().zip(&now).enumerate() {
            assert!(b >= a, "counter {i} went back: {a} -> {b}");
        }
        self.last = now;
    }

    fn push_link(&mut self, bytes: &[u8]) {
        let mut input = bytes;
        // push_link stops when the outbox is nearly full; drain and continue (as the firmware does).
        let mut guard = 0;
        while !input.is_empty() {
            self.p.push_link(&mut input);
            self.drain(255);
            guard += 1;
            assert!(guard < 1 + 4 * bytes.len(), "push_link makes no progress");
        }
    }

    fn drain(&mut self, n: u8) -> Vec<Output> {
        let mut out = Vec::new();
        for _ in 0..n {
            let Some(o) = self.p.poll() else { break };
            if let Output::Telemetry(t) = &o {
                let mut buf = [0u8; MAX_MESSAGE_LEN];
                let enc = telemetry::encode(t, &mut buf).expect("telemetry fits MAX_MESSAGE_LEN");
                assert_eq!(telemetry::decode::<Telemetry>(enc), Ok(*t));
            }
            out.push(o);
        }
        out
    }

    /// Sends a command and checks that the first output is its ack; returns the ack's result and the outputs.
    fn command(&mut self, bytes: &[u8], tag: Option<u16>) -> (Ack, Vec<Output>) {
        let out: Vec<Output> = self.p.handle_command(bytes).to_vec();
        for o in &out {
            if let Output::Telemetry(t) = o {
                let mut buf = [0u8; MAX_MESSAGE_LEN];
                let enc = telemetry::encode(t, &mut buf).expect("telemetry fits MAX_MESSAGE_LEN");
                assert_eq!(telemetry::decode::<Telemetry>(enc), Ok(*t));
            }
        }
        let ack = match out.first().copied() {
            Some(Output::Telemetry(Telemetry::Ack(ack))) => ack,
            // A commit: its ack waits for the platform's store, which succeeds here.
            Some(Output::PersistCalibration { tag }) => {
                assert_eq!(
                    out.len(),
                    1,
                    "a commit asks for the store and nothing else: {out:?}"
                );
                self.p.calibration_persisted(tag, true)
            }
            _ => panic!("no ack first: {out:?}"),
        };
        if let Some(tag) = tag {
            assert_eq!(ack.tag, tag);
        }
        (ack, out)
    }

    fn send(&mut self, tag: u16, cmd: Command) -> (Ack, Vec<Output>) {
        let mut buf = [0u8; MAX_MESSAGE_LEN];
        let bytes = telemetry::encode(&CommandEnvelope { tag, cmd }, &mut buf)
            .expect("command fits")
            .to_vec();
        self.command(&bytes, Some(tag))
    }
}

fuzz_target!(|data: &[u8]| {
    // Seeds from real encodings: 'R' ++ bytes is the raw form (see `Input::raw`).
    if let Some(input) = common::input(data, Input::raw) {
        check(input);
    }
});

fn check(input: Input) {
    let config = PipelineConfig {
        frames_per_output: u16::from(input.frames_per_output % 8).max(1),
        health_every: u16::from(input.health_every % 4),
        ..PipelineConfig::DEFAULT
    };
    let mut run = Run {
        p: Pipeline::new(config, Box::new(PipelineMemory::new())),
        last: [0; 12],
    };
    for op in input.ops.iter().take(64) {
        match op {
            Op::Link(b) => run.push_link(b),
            Op::Frames {
                first,
                count,
                seq_step,
                split,
            } => {
                let mut bytes = Vec::new();
                let mut f = *first;
                for _ in 0..(count % 16) {
                    bytes.extend_from_slice(&f.repr().to_bytes());
                    f.seq = f.seq.wrapping_add(u16::from(*seq_step % 4));
                }
                let cut = usize::from(*split) % (bytes.len() + 1);
                run.push_link(&bytes[..cut]);
                run.push_link(&bytes[cut..]);
            }
            Op::Damaged { frame, at, xor } => {
                let mut b = frame.repr().to_bytes();
                b[usize::from(*at) % FRAME_LEN] ^= xor;
                run.push_link(&b);
            }
            Op::CommandBytes(b) => {
                let (ack, _) = run.command(b, None);
                assert_eq!(ack.tag, telemetry::peek_tag(b));
            }
            Op::Command { tag, cmd } => {
                let _ = run.send(*tag, cmd.command());
            }
            Op::Upload(u) => upload(&mut run, u),
            Op::Poll(n) => {
                run.drain(*n);
            }
            Op::Dump(n) => {
                for _ in 0..*n {
                    let Some(t) = run.p.poll_dump() else { break };
                    let mut buf = [0u8; MAX_MESSAGE_LEN];
                    let enc = telemetry::encode(&t, &mut buf).expect("dump fits MAX_MESSAGE_LEN");
                    assert_eq!(telemetry::decode::<Telemetry>(enc), Ok(t));
                }
            }
            Op::LinkDiscarded => run.p.link_discarded(),
            Op::Arrival(us) => run.p.set_arrival_us(*us),
            Op::Pps(us) => {
                let before = run.p.pps_report();
                let accepted = run.p.pps(*us).is_some();
                let after = run.p.pps_report();
                // Every edge is counted once, as accepted or refused.
                let expected = (
                    before.accepted.wrapping_add(u32::from(accepted)),
                    before.rejected.wrapping_add(u32::from(!accepted)),
                );
                assert_eq!((after.accepted, after.rejected), expected);
            }
        }
        run.check_monotonic();
    }
}

/// A calibration table uploaded in chunks, perhaps corrupted: committed exactly when it is valid, and then in
/// force and to be persisted; otherwise the calibration in force is unchanged.
fn upload(run: &mut Run, u: &Upload) {
    let mut table = CalibrationTable::<GROUPS>::factory();
    table.cal_id = u.cal_id;
    table.raw_min = i32::from(u.raw_min);
    let g = &mut table.groups[usize::from(u.group) % GROUPS];
    g.gyro_bias_q12[usize::from(u.group) % 4] = u.bias;
    g.accel_matrix_q12[usize::from(u.group) % 3][0] += i32::from(u.gain);
    let mut buf = [0u8; encoded_len_max(GROUPS)];
    let mut bytes = table.encode(&mut buf).unwrap().to_vec();
    let crc = crc32c(&bytes);
    if let Some((at, x)) = u.corrupt {
        let n = bytes.len();
        bytes[usize::from(at) % n] ^= x;
    }
    let before = *run.p.calibration();
    let before_source = run.p.calibration_source();
    let (ack, _) = run.send(
        u.tag,
        Command::CalBegin {
            len: bytes.len() as u16,
            crc,
        },
    );
    assert_eq!(ack.result, Ok(()), "CalBegin of a table");
    let sizes: Vec<usize> = if u.chunk_sizes.is_empty() {
        vec![CAL_CHUNK_MAX]
    } else {
        u.chunk_sizes
            .iter()
            .map(|&s| usize::from(s).clamp(1, CAL_CHUNK_MAX))
            .collect()
    };
    let mut off = 0;
    let mut i = 0;
    while off < bytes.len() {
        let n = sizes[i % sizes.len()].min(bytes.len() - off);
        let data = heapless::Vec::from_slice(&bytes[off..off + n]).unwrap();
        let (ack, _) = run.send(
            u.tag,
            Command::CalChunk {
                offset: off as u16,
                data,
            },
        );
        assert_eq!(ack.result, Ok(()), "CalChunk at {off}");
        off += n;
        i += 1;
    }
    let (ack, out) = run.send(u.tag, Command::CalCommit);
    let corrupted = u.corrupt.is_some_and(|(_, x)| x != 0);
    let valid = !corrupted && CalibrationTable::<GROUPS>::decode(&bytes).is_ok();
    if valid {
        assert_eq!(ack.result, Ok(()), "commit of a valid table");
        assert_eq!(*run.p.calibration(), table);
        assert_eq!(run.p.calibration_source(), CalSource::Uploaded);
        assert_eq!(out, [Output::PersistCalibration { tag: u.tag }]);
    } else {
        assert!(
            ack.result.is_err(),
            "commit of a corrupted/invalid table accepted"
        );
        assert_eq!(*run.p.calibration(), before);
        assert_eq!(run.p.calibration_source(), before_source);
        assert!(
            !out.iter()
                .any(|o| matches!(o, Output::PersistCalibration { .. }))
        );
    }
}
