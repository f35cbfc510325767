//! Time from the frames themselves: each frame advances time by N + 1 FPGA base periods (N = its decimation), and
//! a sequence gap advances it by the lost frames too. Used by the pipeline and by the ground tools, so that both
//! put the same time on the same frame.

use super::Decoded;

/// Frame time keeping (see module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameClock {
    base_ticks: u64,
    decimation: Option<u16>,
}

/// What [`FrameClock::advance`] says about a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tick {
    /// Time of this frame in FPGA base periods since the first frame.
    pub base_ticks: u64,
    /// The decimation changed with this frame (the sample rate changed).
    pub rate_changed: bool,
}

impl FrameClock {
    /// A clock before its first frame.
    pub const fn new() -> Self {
        Self {
            base_ticks: 0,
            decimation: None,
        }
    }

    /// Decimation of the last frame.
    pub fn decimation(&self) -> Option<u16> {
        self.decimation
    }

    /// Takes the next decoded frame; returns its time.
    pub fn advance(&mut self, d: &Decoded) -> Tick {
        let step = u64::from(d.frame.decimation) + 1;
        let rate_changed = match self.decimation {
            Some(n) if n == d.frame.decimation => {
                self.base_ticks += u64::from(d.missing_before) * step;
                false
            }
            Some(_) => true,
            None => false,
        };
        self.decimation = Some(d.frame.decimation);
        let tick = Tick {
            base_ticks: self.base_ticks,
            rate_changed,
        };
        self.base_ticks += step;
        tick
    }

    /// `ticks` base periods in µs, for a base rate in mHz (rounded down).
    pub fn ticks_to_us(ticks: u64, base_rate_mhz: u64) -> u64 {
        (u128::from(ticks) * 1_000_000_000 / u128::from(base_rate_mhz.max(1))) as u64
    }
}
