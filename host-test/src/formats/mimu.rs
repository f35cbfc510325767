//! Parser of the OpenShoe MIMU4444 stream (8 InvenSense MPU9150 IMUs at 62.5 Hz over Bluetooth), the real
//! array recordings of `shared/data/mimu4444` (H. Carlsson et al., MIT licence).
//!
//! # Stream format
//! A recording starts with a 4-byte command acknowledgement ([`ACK`] = `A0 28 00 C8`), then frames back to back.
//! A frame is [`FRAME_LEN`] = 106 bytes, big-endian:
//!
//! | bytes | field |
//! |---|---|
//! | 0 | [`HEADER`] `0xAA` |
//! | 1–2 | packet number, `u16`, +1 per frame, wraps at 2¹⁶ |
//! | 3 | payload size, `u8`, = [`PAYLOAD_LEN`] (100) |
//! | 4–7 | timestamp, `u32`, 64 MHz ticks ([`TICKS_PER_SAMPLE`] = 1 024 000 per sample), wraps at 2³² |
//! | 8–103 | 8 × `[acc x, y, z, gyro x, y, z]`, `i16` |
//! | 104–105 | checksum, `u16` = sum of bytes 0–103 modulo 2¹⁶ ([`checksum`]) |
//!
//! Scales (raw, uncalibrated): accelerometer ±16 g, [`ACCEL_LSB_PER_G`] = 2048; gyro ±2000 °/s,
//! [`GYRO_LSB_PER_DPS`] = 16.4.
//!
//! # Resynchronisation and errors
//! [`parse`] accepts a frame only where `0xAA`, the payload size and the checksum all agree; anything else is
//! skipped byte by byte up to the next plausible header. Nothing panics on any input. In the default (lenient)
//! mode every anomaly is counted in [`ParseStats`] and the first [`MAX_EVENTS`] are kept with their byte offsets;
//! the parse fails only when no frame is found or more than [`ParseOptions::max_skipped_fraction`] of the bytes
//! had to be skipped. [`ParseOptions::strict`] turns the first anomaly (skip, checksum failure, packet gap,
//! truncated frame, missing acknowledgement, timestamp jump) into an error carrying its offset.
//!
//! Packet numbers are checked for gaps (modulo 2¹⁶) and timestamps are unwrapped into a 64-bit tick count
//! ([`Recording::ticks`]); a gap of lost frames longer than one timestamp period (67 s) is unwrapped using the
//! packet-number gap.

use std::fmt;
use std::path::{Path, PathBuf};

/// Command acknowledgement at the start of a recording.
pub const ACK: [u8; 4] = [0xA0, 0x28, 0x00, 0xC8];
/// First byte of every frame.
pub const HEADER: u8 = 0xAA;
/// Payload size field of every frame (bytes of timestamp + IMU data).
pub const PAYLOAD_LEN: u8 = 100;
/// Length of one frame, bytes.
pub const FRAME_LEN: usize = 106;
/// IMUs in the array.
pub const IMUS: usize = 8;
/// Accelerometer sensitivity, counts per g (±16 g range).
pub const ACCEL_LSB_PER_G: f64 = 2048.0;
/// Gyro sensitivity, counts per °/s (±2000 °/s range).
pub const GYRO_LSB_PER_DPS: f64 = 16.4;
/// Timestamp counter frequency, Hz.
pub const TICK_HZ: f64 = 64.0e6;
/// Timestamp ticks per sample (64 MHz / 62.5 Hz).
pub const TICKS_PER_SAMPLE: u32 = 1_024_000;
/// Nominal sample rate, Hz.
pub const SAMPLE_RATE_HZ: f64 = 62.5;
/// Events kept with their offsets in [`ParseStats::events`]; later ones are only counted.
pub const MAX_EVENTS: usize = 64;

const CHECKSUM_AT: usize = FRAME_LEN - 2;

/// One IMU's raw reading in a frame (signed sensor words, counts).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ImuSample {
    /// Accelerometer x, y, z, counts ([`ACCEL_LSB_PER_G`] per g).
    pub acc: [i16; 3],
    /// Gyro x, y, z, counts ([`GYRO_LSB_PER_DPS`] per °/s).
    pub gyro: [i16; 3],
}

/// One decoded frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Frame {
    /// Packet number (wraps at 2¹⁶).
    pub packet: u16,
    /// Timestamp, 64 MHz ticks (wraps at 2³²).
    pub timestamp: u32,
    /// IMU 1 … 8 (index 0 … 7).
    pub imu: [ImuSample; IMUS],
}

/// Why a 106-byte block is not a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Fewer than [`FRAME_LEN`] bytes.
    #[error("only {len} of {FRAME_LEN} bytes")]
    Short {
        /// Bytes available.
        len: usize,
    },
    /// First byte is not [`HEADER`].
    #[error("header 0x{found:02X}, expected 0x{HEADER:02X}")]
    Header {
        /// Byte found.
        found: u8,
    },
    /// Payload size is not [`PAYLOAD_LEN`].
    #[error("payload size {found}, expected {PAYLOAD_LEN}")]
    PayloadSize {
        /// Size found.
        found: u8,
    },
    /// Checksum mismatch.
    #[error("checksum 0x{stored:04X} stored, 0x{computed:04X} computed")]
    Checksum {
        /// Checksum stored in the frame.
        stored: u16,
        /// Checksum of the bytes.
        computed: u16,
    },
}

/// Frame checksum: sum of the bytes modulo 2¹⁶.
pub fn checksum(bytes: &[u8]) -> u16 {
    bytes
        .iter()
        .fold(0u16, |acc, &b| acc.wrapping_add(u16::from(b)))
}

fn be_u16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

impl Frame {
    /// Decodes the first [`FRAME_LEN`] bytes of `bytes`, checking header, payload size and checksum.
    pub fn decode(bytes: &[u8]) -> Result<Self, FrameError> {
        let b = bytes
            .get(..FRAME_LEN)
            .ok_or(FrameError::Short { len: bytes.len() })?;
        if b[0] != HEADER {
            return Err(FrameError::Header { found: b[0] });
        }
        if b[3] != PAYLOAD_LEN {
            return Err(FrameError::PayloadSize { found: b[3] });
        }
        let stored = be_u16(b, CHECKSUM_AT);
        let computed = checksum(&b[..CHECKSUM_AT]);
        if stored != computed {
            return Err(FrameError::Checksum { stored, computed });
        }
        let word = |at: usize| be_u16(b, at) as i16;
        let imu = core::array::from_fn(|i| {
            let o = 8 + 12 * i;
            ImuSample {
                acc: [word(o), word(o + 2), word(o + 4)],
                gyro: [word(o + 6), word(o + 8), word(o + 10)],
            }
        });
        Ok(Self {
            packet: be_u16(b, 1),
            timestamp: u32::from_be_bytes([b[4], b[5], b[6], b[7]]),
            imu,
        })
    }

    /// The frame's bytes, with a valid checksum (for tests, fixtures and simulators).
    pub fn encode(&self) -> [u8; FRAME_LEN] {
        let mut b = [0u8; FRAME_LEN];
        b[0] = HEADER;
        b[1..3].copy_from_slice(&self.packet.to_be_bytes());
        b[3] = PAYLOAD_LEN;
        b[4..8].copy_from_slice(&self.timestamp.to_be_bytes());
        for (i, s) in self.imu.iter().enumerate() {
            let o = 8 + 12 * i;
            for (k, w) in s.acc.iter().chain(&s.gyro).enumerate() {
                b[o + 2 * k..o + 2 * k + 2].copy_from_slice(&w.to_be_bytes());
            }
        }
        let c = checksum(&b[..CHECKSUM_AT]);
        b[CHECKSUM_AT..].copy_from_slice(&c.to_be_bytes());
        b
    }
}

/// What happened at an offset of the byte stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum EventKind {
    /// The stream does not start with [`ACK`] (the first bytes are parsed as frames).
    MissingAck,
    /// `len` bytes starting at the offset belong to no valid frame and were skipped.
    Skipped {
        /// Bytes skipped.
        len: usize,
    },
    /// A candidate frame (header and size right) whose checksum does not match.
    Checksum {
        /// Checksum stored in the candidate.
        stored: u16,
        /// Checksum of its bytes.
        computed: u16,
    },
    /// The packet number jumped (frames lost, repeated or reordered).
    PacketGap {
        /// Packet number expected (previous + 1).
        expected: u16,
        /// Packet number found.
        found: u16,
    },
    /// The timestamp advanced by far more or less than the packet numbers imply (more than half a sample off).
    TimestampJump {
        /// Timestamp difference to the previous frame, modulo 2³², ticks.
        delta_ticks: u32,
        /// What the packet-number step implies, ticks.
        expected_ticks: u64,
    },
    /// The stream ends inside a frame.
    Truncated {
        /// Bytes of the unfinished frame.
        len: usize,
    },
}

/// An anomaly and the byte offset (from the start of the input) where it starts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ParseEvent {
    /// Byte offset from the start of the input.
    pub offset: usize,
    /// What happened.
    pub kind: EventKind,
}

impl fmt::Display for ParseEvent {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let o = self.offset;
        match self.kind {
            EventKind::MissingAck => write!(f, "byte {o}: no command acknowledgement A0 28 00 C8"),
            EventKind::Skipped { len } => write!(
                f,
                "bytes {o}..{}: {len} bytes skipped (no valid frame)",
                o + len
            ),
            EventKind::Checksum { stored, computed } => write!(
                f,
                "byte {o}: frame checksum 0x{stored:04X} stored, 0x{computed:04X} computed"
            ),
            EventKind::PacketGap { expected, found } => {
                write!(f, "byte {o}: packet {found}, expected {expected}")
            }
            EventKind::TimestampJump {
                delta_ticks,
                expected_ticks,
            } => write!(
                f,
                "byte {o}: timestamp advanced {delta_ticks} ticks, expected {expected_ticks}"
            ),
            EventKind::Truncated { len } => {
                write!(f, "byte {o}: stream ends {len} bytes into a frame")
            }
        }
    }
}

/// Counters of a parse.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ParseStats {
    /// Input length, bytes.
    pub bytes: usize,
    /// The input starts with [`ACK`].
    pub ack: bool,
    /// Valid frames decoded.
    pub frames: usize,
    /// Bytes in no valid frame (nor the acknowledgement), including a truncated final frame.
    pub bytes_skipped: usize,
    /// Runs of skipped bytes (each a resynchronisation).
    pub resyncs: usize,
    /// Candidate frames (header and payload size right) rejected by their checksum.
    pub checksum_failures: usize,
    /// Places where the packet number did not advance by exactly one.
    pub packet_gaps: usize,
    /// Frames missing according to the packet numbers (sum over gaps of the forward step − 1, modulo 2¹⁶).
    pub packets_missing: u64,
    /// Times the 32-bit timestamp wrapped (including wraps inside gaps of lost frames).
    pub timestamp_wraps: usize,
    /// Timestamp steps more than half a sample away from what the packet numbers imply.
    pub timestamp_jumps: usize,
    /// Bytes of an unfinished frame at the end (also counted in `bytes_skipped`).
    pub truncated_tail: usize,
    /// The first [`MAX_EVENTS`] anomalies with their offsets.
    pub events: Vec<ParseEvent>,
    /// Anomalies counted but not kept in `events`.
    pub events_dropped: usize,
}

impl ParseStats {
    fn push(&mut self, ev: ParseEvent) {
        if self.events.len() < MAX_EVENTS {
            self.events.push(ev);
        } else {
            self.events_dropped += 1;
        }
    }
}

/// Options of [`parse_with`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ParseOptions {
    /// Fail on the first anomaly (see [`EventKind`]) instead of counting it. Default `false`.
    pub strict: bool,
    /// Fail when more than this fraction of the input had to be skipped. Default 0.5.
    pub max_skipped_fraction: f64,
}

impl Default for ParseOptions {
    fn default() -> Self {
        Self {
            strict: false,
            max_skipped_fraction: 0.5,
        }
    }
}

/// Why a recording could not be parsed.
#[derive(Debug, thiserror::Error)]
pub enum MimuError {
    /// The file could not be read.
    #[error("{}: {source}", path.display())]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// No valid frame in the input.
    #[error("no valid MIMU4444 frame in {len} bytes{}", first_problem(first))]
    NoFrames {
        /// Input length, bytes.
        len: usize,
        /// First anomaly, if any.
        first: Option<ParseEvent>,
    },
    /// Too much of the input is not frames.
    #[error(
        "{skipped} of {len} bytes are not valid frames{}",
        first_problem(first)
    )]
    TooMuchSkipped {
        /// Bytes skipped.
        skipped: usize,
        /// Input length.
        len: usize,
        /// First anomaly.
        first: Option<ParseEvent>,
    },
    /// Strict mode: the first anomaly.
    #[error("malformed MIMU4444 stream at {0}")]
    Anomaly(ParseEvent),
}

/// `; first problem at …` when there is one.
fn first_problem(e: &Option<ParseEvent>) -> String {
    e.as_ref()
        .map_or(String::new(), |e| format!("; first problem at {e}"))
}

/// A parsed recording.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recording {
    /// Valid frames in stream order.
    pub frames: Vec<Frame>,
    /// Byte offset of each frame in the input.
    pub offsets: Vec<usize>,
    /// Unwrapped timestamp of each frame, ticks since the first frame.
    pub ticks: Vec<u64>,
    /// True where a frame does not directly follow the previous one (packet gap or skipped bytes before it):
    /// windows over samples must not span it. `false` for the first frame.
    pub discontinuity: Vec<bool>,
    /// Counters and anomalies.
    pub stats: ParseStats,
}

impl Recording {
    /// Time of frame `i` since the first frame, seconds (`None` out of range).
    pub fn time_s(&self, i: usize) -> Option<f64> {
        self.ticks.get(i).map(|&t| t as f64 / TICK_HZ)
    }

    /// Times of all frames since the first, seconds.
    pub fn times_s(&self) -> Vec<f64> {
        self.ticks.iter().map(|&t| t as f64 / TICK_HZ).collect()
    }

    /// Time from the first to the last frame, seconds.
    pub fn duration_s(&self) -> f64 {
        self.ticks.last().map_or(0.0, |&t| t as f64 / TICK_HZ)
    }
}

/// Parses a recording with the default (lenient) options.
pub fn parse(bytes: &[u8]) -> Result<Recording, MimuError> {
    parse_with(bytes, &ParseOptions::default())
}

/// Reads and parses a recording file (default options).
pub fn read(path: impl AsRef<Path>) -> Result<Recording, MimuError> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|source| MimuError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse(&bytes)
}

struct Parser<'a> {
    opts: &'a ParseOptions,
    rec: Recording,
    skip_start: Option<usize>,
    prev: Option<(u16, u32)>,
    tick: u64,
}

impl Parser<'_> {
    fn event(&mut self, offset: usize, kind: EventKind) -> Result<(), MimuError> {
        let ev = ParseEvent { offset, kind };
        if self.opts.strict {
            return Err(MimuError::Anomaly(ev));
        }
        self.rec.stats.push(ev);
        Ok(())
    }

    fn end_skip(&mut self, at: usize) -> Result<bool, MimuError> {
        let Some(start) = self.skip_start.take() else {
            return Ok(false);
        };
        let len = at - start;
        self.rec.stats.bytes_skipped += len;
        self.rec.stats.resyncs += 1;
        self.event(start, EventKind::Skipped { len })?;
        Ok(true)
    }

    fn accept(&mut self, frame: Frame, offset: usize, after_skip: bool) -> Result<(), MimuError> {
        let mut discontinuity = after_skip;
        if let Some((prev_packet, prev_ts)) = self.prev {
            let expected = prev_packet.wrapping_add(1);
            let step = frame.packet.wrapping_sub(prev_packet);
            if frame.packet != expected {
                discontinuity = true;
                self.rec.stats.packet_gaps += 1;
                if (2..0x8000).contains(&step) {
                    self.rec.stats.packets_missing += u64::from(step - 1);
                }
                self.event(
                    offset,
                    EventKind::PacketGap {
                        expected,
                        found: frame.packet,
                    },
                )?;
            }
            // Unwrap: the step modulo 2^32, plus as many whole periods as make it closest to what the packet step
            // implies (only matters when more than 67 s of frames were lost).
            let delta = frame.timestamp.wrapping_sub(prev_ts);
            let expected_ticks = u64::from(step.max(1)) * u64::from(TICKS_PER_SAMPLE);
            let period = 1u64 << 32;
            let extra = expected_ticks.saturating_sub(u64::from(delta)) / period
                + u64::from(
                    (expected_ticks.saturating_sub(u64::from(delta)) % period) > period / 2,
                );
            let full = u64::from(delta) + extra * period;
            self.rec.stats.timestamp_wraps += ((u64::from(prev_ts) + full) / period) as usize;
            if full.abs_diff(expected_ticks) > u64::from(TICKS_PER_SAMPLE / 2) {
                self.rec.stats.timestamp_jumps += 1;
                self.event(
                    offset,
                    EventKind::TimestampJump {
                        delta_ticks: delta,
                        expected_ticks,
                    },
                )?;
            }
            self.tick = self.tick.saturating_add(full);
        }
        self.prev = Some((frame.packet, frame.timestamp));
        self.rec.frames.push(frame);
        self.rec.offsets.push(offset);
        self.rec.ticks.push(self.tick);
        self.rec
            .discontinuity
            .push(discontinuity && self.rec.frames.len() > 1);
        self.rec.stats.frames += 1;
        Ok(())
    }
}

/// Parses a recording (see the module docs for what is checked and counted).
pub fn parse_with(bytes: &[u8], opts: &ParseOptions) -> Result<Recording, MimuError> {
    let mut p = Parser {
        opts,
        rec: Recording::default(),
        skip_start: None,
        prev: None,
        tick: 0,
    };
    p.rec.stats.bytes = bytes.len();
    let mut pos = 0;
    if bytes.starts_with(&ACK) {
        p.rec.stats.ack = true;
        pos = ACK.len();
    } else {
        p.event(0, EventKind::MissingAck)?;
    }
    while pos < bytes.len() {
        let rest = &bytes[pos..];
        let plausible = rest[0] == HEADER && rest.get(3).is_none_or(|&s| s == PAYLOAD_LEN);
        if !plausible {
            p.skip_start.get_or_insert(pos);
            pos += 1;
            continue;
        }
        if rest.len() < FRAME_LEN {
            // An unfinished frame at the end of the stream.
            p.end_skip(pos)?;
            p.rec.stats.bytes_skipped += rest.len();
            p.rec.stats.truncated_tail = rest.len();
            p.event(pos, EventKind::Truncated { len: rest.len() })?;
            pos = bytes.len();
            break;
        }
        match Frame::decode(rest) {
            Ok(frame) => {
                let after_skip = p.end_skip(pos)?;
                p.accept(frame, pos, after_skip)?;
                pos += FRAME_LEN;
            }
            Err(e) => {
                if let FrameError::Checksum { stored, computed } = e {
                    p.rec.stats.checksum_failures += 1;
                    p.event(pos, EventKind::Checksum { stored, computed })?;
                }
                p.skip_start.get_or_insert(pos);
                pos += 1;
            }
        }
    }
    p.end_skip(pos)?;
    let rec = p.rec;
    // The first real problem (a missing acknowledgement alone says little).
    let first = rec
        .stats
        .events
        .iter()
        .find(|e| e.kind != EventKind::MissingAck)
        .or(rec.stats.events.first())
        .copied();
    if rec.frames.is_empty() {
        return Err(MimuError::NoFrames {
            len: bytes.len(),
            first,
        });
    }
    let skipped_fraction = rec.stats.bytes_skipped as f64 / bytes.len().max(1) as f64;
    if skipped_fraction > opts.max_skipped_fraction {
        return Err(MimuError::TooMuchSkipped {
            skipped: rec.stats.bytes_skipped,
            len: bytes.len(),
            first,
        });
    }
    Ok(rec)
}

#[cfg(test)]
mod tests;
