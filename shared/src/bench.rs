//! Deterministic input for benchmarks of the core: the same frame stream for the host's criterion benchmarks and
//! profilers and for instruction counts on an emulated Cortex-M4 (`mcu-bench/`), so that their figures compare.
//!
//! Built with the `bench` feature (and for the crate's tests): not part of the flight build.

use crate::calib::board::nominal_codes;
use crate::wire::FrameRepr;
use crate::wire::frame::{FRAME_LEN, GROUPS, RAW_PER_GROUP};

/// Noise added to every code: uniform in ±`NOISE_CODES` (xorshift64).
pub const NOISE_CODES: u32 = 20;

/// An endless stream of plausible frames: every group at rest (nominal codes for 0 °/s and −1 g on z, the board's
/// nominal analog chain) plus independent uniform noise of ±[`NOISE_CODES`] codes on every channel, decimation
/// [`FLIGHT_DECIMATION`](crate::wire::clock::FLIGHT_DECIMATION) (15), 20.00 °C, consecutive sequence numbers.
#[derive(Clone, Debug)]
pub struct BenchFrames {
    state: u64,
    seq: u16,
    rest_codes: [i64; RAW_PER_GROUP],
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
            rest_codes: nominal_codes([0.0; 3], [0.0, 0.0, -1.0]).map(|c| c as i64),
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
                // The high half, reduced in 32 bits (a hardware divide on the Cortex-M4, not a 64-bit library call).
                // In [0, 2·NOISE_CODES]: the subtraction cannot wrap; the sum saturates before the clamp.
                let noise = i64::from((*s >> 32) as u32 % (2 * NOISE_CODES + 1))
                    .wrapping_sub(i64::from(NOISE_CODES));
                *code = rest.saturating_add(noise).clamp(0, i64::from(u16::MAX)) as u16;
            }
        }
        let frame = FrameRepr {
            seq: self.seq,
            decimation: crate::wire::clock::FLIGHT_DECIMATION,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::wire::FrameDecoder;

    /// The stream decodes with valid CRCs and consecutive sequence numbers, every code within ±NOISE_CODES of the
    /// rest codes, the noise roughly uniform (all 41 values seen), and the same stream every time.
    #[test]
    fn frames_are_valid_bounded_and_repeatable() {
        let rest = nominal_codes([0.0; 3], [0.0, 0.0, -1.0]).map(|c| c as i64);
        let (mut a, mut b) = (BenchFrames::new(), BenchFrames::new());
        let mut decoder = FrameDecoder::new();
        let mut seen = [false; 2 * NOISE_CODES as usize + 1];
        for i in 0..500u16 {
            let bytes = a.next_bytes();
            assert_eq!(bytes, b.next_bytes());
            let d = decoder.decode(&mut &bytes[..]).expect("a valid frame");
            assert_eq!(d.frame.seq, i);
            for group in d.frame.raw {
                for (&code, &r) in group.iter().zip(&rest) {
                    let noise = i64::from(code) - r;
                    assert!(noise.unsigned_abs() <= u64::from(NOISE_CODES));
                    seen[(noise + i64::from(NOISE_CODES)) as usize] = true;
                }
            }
        }
        assert!(seen.iter().all(|&s| s));
        assert_eq!(decoder.counters().frames, 500);
    }
}
