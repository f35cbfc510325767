//! Deterministic input for benchmarks of the core: the same frame stream for the host's criterion benchmarks and
//! profilers and for instruction counts on an emulated Cortex-M4 (`mcu-bench/`), so that their figures compare.

use crate::calib::board::nominal_codes;
use crate::wire::FrameRepr;
use crate::wire::frame::{FRAME_LEN, GROUPS, RAW_PER_GROUP};

/// Noise added to every code: uniform in ±`NOISE_CODES` (xorshift64).
pub const NOISE_CODES: u64 = 20;

/// An endless stream of plausible frames: every group at rest (nominal codes for 0 °/s and −1 g on z, the board's
/// nominal analog chain) plus independent uniform noise of ±[`NOISE_CODES`] codes on every channel, decimation 15,
/// 20.00 °C, consecutive sequence numbers.
#[derive(Clone, Debug)]
pub struct BenchFrames {
    state: u64,
    seq: u16,
    rest_codes: [f64; RAW_PER_GROUP],
}

impl Default for BenchFrames {
    fn default() -> Self {
        Self::new()
    }
}

impl BenchFrames {
    /// The stream from its fixed seed.
    pub fn new() -> Self {
        Self {
            state: 0x1234_5678_9abc_def0,
            seq: 0,
            rest_codes: nominal_codes([0.0; 3], [0.0, 0.0, -1.0]),
        }
    }

    /// The next frame.
    pub fn next_frame(&mut self) -> FrameRepr {
        let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
        for group in raw.iter_mut() {
            for (code, &rest) in group.iter_mut().zip(&self.rest_codes) {
                let s = &mut self.state;
                *s ^= *s << 13;
                *s ^= *s >> 7;
                *s ^= *s << 17;
                let noise = (*s % (2 * NOISE_CODES + 1)) as i64 - NOISE_CODES as i64;
                *code = (rest as i64 + noise).clamp(0, i64::from(u16::MAX)) as u16;
            }
        }
        let frame = FrameRepr {
            seq: self.seq,
            decimation: 15,
            temp_cdeg: Some(2000),
            raw,
        };
        self.seq = self.seq.wrapping_add(1);
        frame
    }

    /// The next frame's bytes.
    pub fn next_bytes(&mut self) -> [u8; FRAME_LEN] {
        self.next_frame().to_bytes()
    }
}
