//! Time from the frames themselves: each frame advances time by N + 1 FPGA base periods (N = its decimation), and
//! a sequence gap advances it by the lost frames too. Used by the pipeline and by the ground tools, so that both
//! put the same time on the same frame.
//!
//! The tick count wraps modulo 2⁶⁴, as any free-running counter: after 60 million years at the nominal rate, or
//! after 2³³ frames (164 days at 604.8 frames/s) of the worst a link can send (every frame reporting 2¹⁵ − 1 lost
//! frames at N = 65535).

use super::Decoded;
use core::num::{NonZeroU64, NonZeroU128};

/// The FPGA's data-set rate before decimation, in millihertz: 9676.8 Hz. A frame of decimation N comes every N + 1
/// base periods (N = 15: 604.8 frames/s). The one definition of this rate; everything else derives from it.
pub const FPGA_BASE_RATE_MILLIHZ: u64 = 9_676_800;

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
        self.advance_by(d.frame.decimation, d.missing_before)
    }

    /// Takes the next frame, of decimation `decimation`, after `missing_before` lost frames (the decoder's count,
    /// or the platform's from arrival times); returns its time.
    pub fn advance_by(&mut self, decimation: u16, missing_before: u32) -> Tick {
        // ≤ 2¹⁶: cannot wrap.
        let step = u64::from(decimation).wrapping_add(1);
        let rate_changed = match self.decimation {
            Some(n) if n == decimation => {
                // The product is < 2³² · 2¹⁶ (cannot wrap); the sum wraps modulo 2⁶⁴ (module docs).
                let lost = u64::from(missing_before).wrapping_mul(step);
                self.base_ticks = self.base_ticks.wrapping_add(lost);
                false
            }
            Some(_) => true,
            None => false,
        };
        self.decimation = Some(decimation);
        let tick = Tick {
            base_ticks: self.base_ticks,
            rate_changed,
        };
        self.base_ticks = self.base_ticks.wrapping_add(step);
        tick
    }

    /// `ticks` base periods in µs, for a base rate in millihertz (rounded down).
    pub fn ticks_to_us(ticks: u64, base_rate_millihz: u64) -> u64 {
        // < 2⁶⁴ · 2³⁰: the product cannot wrap; a rate of 0 counts as 1 millihertz.
        let rate = NonZeroU128::from(NonZeroU64::new(base_rate_millihz).unwrap_or(NonZeroU64::MIN));
        (u128::from(ticks).wrapping_mul(1_000_000_000) / rate) as u64
    }
}
